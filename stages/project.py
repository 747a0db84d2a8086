"""This project's pipeline: its config schema and its seven stages."""

from __future__ import annotations

from graspgen.errors import GraspGenError
from pipeline.errors import GenError
from pipeline.scheduler import Project
from stages.config import Config
from stages.dataset import DatasetStage
from stages.grasps import GraspsStage
from stages.metrics import MetricsStage
from stages.objects import ObjectsStage
from stages.robustness import RobustnessStage
from stages.rollouts import RolloutsStage
from stages.scenes import ScenesStage

PROJECT = Project(
    name="gen",
    schema=Config,
    stages=(
        ObjectsStage(),
        ScenesStage(),
        GraspsStage(),
        RolloutsStage(),
        RobustnessStage(),
        MetricsStage(),
        DatasetStage(tables=("grasps", "rollouts", "robustness", "metrics")),
    ),
    user_errors=(GraspGenError,),
)
"""The stages in their declared order; the scheduler sorts them by dependency."""

USER_ERRORS = (GenError, GraspGenError)
"""Every error a user can cause, from the engine or the library: printed in one line, never as a traceback."""
