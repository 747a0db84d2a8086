"""The project's config schema: the run settings plus one section per stage."""

from __future__ import annotations

import dataclasses

from graspgen.grippers import load_gripper
from graspgen.io.object_sources import ObjectsParams
from graspgen.learn.probe_settings import ProbeParams
from graspgen.quality.contact_noise import MetricsParams
from graspgen.quality.perturbation import RobustnessParams
from graspgen.validation import check
from graspgen.workflows.object_grasps_settings import ObjectGraspsParams
from graspgen.workflows.placed_grasps import PlacedGraspsParams
from graspgen.workflows.rollouts import RolloutsParams
from graspgen.workflows.scene_grasps import GraspsParams
from graspgen.workflows.scene_params import ScenesParams
from pipeline.config import RunConfig
from stages.dataset import DatasetParams


@dataclasses.dataclass(frozen=True)
class Config:
    """A whole config file. Each section's keys are documented in its dataclass (``gen config show``)."""

    run: RunConfig = dataclasses.field(default_factory=RunConfig)
    """Where and how to run (output folder, workers, backend). Never enters a content key."""
    objects: ObjectsParams = dataclasses.field(default_factory=ObjectsParams)
    """Stage 1: mesh preparation."""
    object_grasps: ObjectGraspsParams = dataclasses.field(default_factory=ObjectGraspsParams)
    """Object-centric grasp sets (ACRONYM / GraspGen style): each object alone in free space, grasps over the whole
    sphere labelled by a free-space protocol until the positive and negative targets are met."""
    scenes: ScenesParams = dataclasses.field(default_factory=ScenesParams)
    """Stage 2: random settled scenes on a support, with rendered camera views."""
    grasps: GraspsParams = dataclasses.field(default_factory=GraspsParams)
    """Stage 3: antipodal grasp candidates with a collision pre-filter."""
    placed_grasps: PlacedGraspsParams = dataclasses.field(default_factory=PlacedGraspsParams)
    """Object-level grasp sets placed into every scene and checked against the support and the neighbours
    (ACRONYM's scenes: no new rollouts; optional re-simulation of a few per scene)."""
    rollouts: RolloutsParams = dataclasses.field(default_factory=RolloutsParams)
    """Stage 4: grasp-and-lift in MuJoCo, outcome codes 0-5."""
    robustness: RobustnessParams = dataclasses.field(default_factory=RobustnessParams)
    """Stage 5: success rate of perturbed copies of each successful grasp (Wilson interval), their epsilon and pfc."""
    metrics: MetricsParams = dataclasses.field(default_factory=MetricsParams)
    """Stage 6: Ferrari-Canny epsilon per grasp and the minimum friction for force closure."""
    probe: ProbeParams = dataclasses.field(default_factory=ProbeParams)
    """Learnability check: a small grasp evaluator trained on the object-centric sets of most objects and scored on
    the held-out ones (needs torch and scikit-learn); the dataset publishes its model and report and the card's
    Learnability section."""
    dataset: DatasetParams = dataclasses.field(default_factory=DatasetParams)
    """Stage 7: the published dataset (merged grasps.parquet, scenes, objects, ACRONYM export, card and plots)."""

    def __post_init__(self) -> None:
        # The pre-filter stands in for the rollout's approach: it must check the path the rollout will take.
        lift, prefilter = self.rollouts.lift, self.grasps.prefilter
        check(
            "grasps.prefilter.approach_distance",
            prefilter.approach_distance == lift.approach_distance,
            f"equal rollouts.lift.approach_distance ({lift.approach_distance}): the pre-filter checks the approach the "
            "rollout takes",
            prefilter.approach_distance,
        )
        check(
            "grasps.prefilter.width_margin",
            prefilter.width_margin == lift.width_margin,
            f"equal rollouts.lift.width_margin ({lift.width_margin}): the pre-filter checks the jaws as the rollout "
            "opens them",
            prefilter.width_margin,
        )
        self._check_procedural_fits()

    def _check_procedural_fits(self) -> None:
        # Procedural objects are sized for a gripper: their thinnest extent must fit between the open jaws of every
        # gripper the config grasps them with.
        procedural = self.objects.procedural
        if procedural is None:
            return
        widths = {g: load_gripper(g).max_width for g in (self.grasps.gripper, self.object_grasps.gripper)}
        gripper, width = min(widths.items(), key=lambda item: item[1])
        check(
            "objects.procedural.max_grasp_width",
            procedural.max_grasp_width < width,
            f"be < the largest opening of {gripper} ({width} m, grasps.gripper / object_grasps.gripper), so every "
            "object fits between the open jaws",
            procedural.max_grasp_width,
        )
