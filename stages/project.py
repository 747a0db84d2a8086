"""This project's pipeline: its config schema and its ten stages."""

from __future__ import annotations

from graspgen.errors import GraspGenError
from pipeline.errors import GenError
from pipeline.plan import Project
from stages.config import Config
from stages.dataset import OBJECT_SETS, PROBE, DatasetStage
from stages.grasps import GraspsStage
from stages.metrics import MetricsStage
from stages.object_grasps import ObjectGraspsStage
from stages.objects import ObjectsStage
from stages.placed_grasps import PlacedGraspsStage
from stages.probe import ProbeStage
from stages.robustness import RobustnessStage
from stages.rollouts import RolloutsStage
from stages.scenes import ScenesStage

PROJECT = Project(
    name="gen",
    schema=Config,
    stages=(
        ObjectsStage(),
        ObjectGraspsStage(),
        ScenesStage(),
        GraspsStage(),
        PlacedGraspsStage(),
        RolloutsStage(),
        RobustnessStage(),
        MetricsStage(),
        ProbeStage(),
        DatasetStage(tables=("grasps", "rollouts", "robustness", "metrics"), object_sets=OBJECT_SETS, probe=PROBE),
    ),
    user_errors=(GraspGenError,),
)
"""The stages in their declared order; the scheduler sorts them by dependency."""

USER_ERRORS = (GenError, GraspGenError)
"""Every error a user can cause, from the engine or the library: printed in one line, never as a traceback."""
