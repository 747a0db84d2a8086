"""The project's config schema: the run settings plus one section per stage."""

from __future__ import annotations

import dataclasses

from graspgen.errors import SettingsError
from graspgen.grippers import load_gripper
from graspgen.io.object_sources import ObjectsParams
from graspgen.learn.probe_settings import ProbeParams
from graspgen.quality.contact_noise import MetricsParams
from graspgen.quality.perturbation import RobustnessParams
from graspgen.validation import check
from graspgen.workflows.scene_params import ScenesParams
from pipeline.config import RunConfig
from stages.dataset import DatasetParams
from stages.physics import PhysicsParams
from stages.sections import GraspsSection, ObjectGraspsSection, PlacedGraspsSection, RolloutsSection


@dataclasses.dataclass(frozen=True)
class Config:
    """A whole config file. Each section's keys are documented in its dataclass (``gen config show --all``)."""

    run: RunConfig = dataclasses.field(default_factory=RunConfig)
    """Where and how to run (output folder, workers, backend). Never enters a content key."""
    objects: ObjectsParams = dataclasses.field(default_factory=ObjectsParams)
    """Stage 1: mesh preparation."""
    object_grasps: ObjectGraspsSection = dataclasses.field(default_factory=ObjectGraspsSection)
    """Object-centric grasp sets (ACRONYM / GraspGen style): each object alone in free space, grasps over the whole
    sphere labelled by a free-space protocol until the positive and negative targets are met."""
    scenes: ScenesParams = dataclasses.field(default_factory=ScenesParams)
    """Stage 2: random settled scenes on a support, with rendered camera views."""
    grasps: GraspsSection = dataclasses.field(default_factory=GraspsSection)
    """Stage 3: antipodal grasp candidates with a collision pre-filter."""
    placed_grasps: PlacedGraspsSection = dataclasses.field(default_factory=PlacedGraspsSection)
    """Object-level grasp sets placed into every scene and checked against the support and the neighbours
    (ACRONYM's scenes: no new rollouts; optional re-simulation of a few per scene)."""
    rollouts: RolloutsSection = dataclasses.field(default_factory=RolloutsSection)
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

    physics: PhysicsParams = dataclasses.field(default_factory=PhysicsParams)
    """The simulation every rollout shares and the protocols' settings, once; ``rollouts``, ``object_grasps`` and
    ``placed_grasps`` name a protocol and may override keys for themselves."""

    def __post_init__(self) -> None:
        # Each rolling-out stage's LiftParams from physics, its protocol and its overrides; the pre-filter and the
        # sampler open and approach as the rollouts do.
        for name in ("rollouts", "object_grasps", "placed_grasps"):
            section = getattr(self, name)
            try:
                lift = self.physics.lift(section.protocol, section.overrides)
            except SettingsError as exc:
                raise SettingsError(f"{name}.{exc}") from None
            object.__setattr__(self, name, dataclasses.replace(section, lift=lift))
        lift, grasps = self.rollouts.lift, self.grasps
        object.__setattr__(self, "grasps", dataclasses.replace(
            grasps, sampler=dataclasses.replace(grasps.sampler, width_margin=lift.width_margin),
            prefilter=dataclasses.replace(grasps.prefilter, approach_distance=lift.approach_distance,
                                          width_margin=lift.width_margin)))
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
