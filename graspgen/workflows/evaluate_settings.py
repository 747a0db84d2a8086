"""Settings of :func:`graspgen.workflows.evaluate.evaluate_grasps`: how the object is built, the grasps rolled out."""

from __future__ import annotations

import dataclasses

from graspgen.geometry.convex import CoacdParams
from graspgen.sim.protocols import LiftParams
from graspgen.sim.support import SupportParams
from graspgen.validation import check_instance, check_number, check_positive_int

__all__ = ["CHEAP_COACD", "EvaluateParams"]

CHEAP_COACD = CoacdParams(threshold=0.05, max_convex_hull=32, preprocess_resolution=60, resolution=1000,
                          mcts_iterations=10, mcts_depth=3, mcts_nodes=5, refine_excess=0.01, free_merge_depth=2.5e-4)
"""CoACD settings of ``gen evaluate`` (threshold 0.05, 32 parts, preprocess resolution 60, the objects stage's search
and refinement). Every field is given, so a change to :class:`CoacdParams`' defaults (the objects stage's) leaves
``gen evaluate``'s parts and labels as they are. Why these: the tightest hull slack (p95 <= 1 mm asked, on every
calibration object) within 600 s of CoACD per object (docs/decisions/2026-11-22-evaluate-coacd-settings.md)."""


@dataclasses.dataclass(frozen=True)
class EvaluateParams:
    """How :func:`graspgen.workflows.evaluate.evaluate_grasps` builds the object and rolls the grasps out."""

    lift: LiftParams = dataclasses.field(default_factory=LiftParams)
    """The protocol and its settings (``lift.protocol``: ``table`` or ``acronym``; for ``table`` its
    ``gravity_until_closed`` is set by the mode: on in free space, else off)."""
    friction: float = 0.5
    """Sliding friction coefficient of the object (dimensionless; the object's value governs gripper contacts)."""
    density: float = 700.0
    """Density (kg/m^3) the mass is computed from when ``mass`` is None."""
    mass: float | None = None
    """Object mass (kg), e.g. ACRONYM's ``object/mass``; the inertia is rescaled with it (uniform density)."""
    coacd: CoacdParams = CHEAP_COACD
    """Convex decomposition of the object (cached by mesh hash and these settings)."""
    support: SupportParams = dataclasses.field(default_factory=SupportParams)
    """The table of the support-plane protocol (its top is z = 0)."""
    rays_per_side: int = 3
    """Ray-cast width finding: rays per pad edge (``rays_per_side ** 2`` per pad)."""
    max_extent: float = 1.0
    """Largest accepted object extent after scaling, m (ACRONYM has furniture-sized objects up to ~1 m)."""

    def __post_init__(self) -> None:
        check_instance("lift", self.lift, LiftParams)
        check_instance("coacd", self.coacd, CoacdParams)
        check_instance("support", self.support, SupportParams)
        for key in ("friction", "density", "max_extent"):
            check_number(key, getattr(self, key), low=0.0, low_open=True)
        if self.mass is not None:
            check_number("mass", self.mass, low=0.0, low_open=True)
        check_positive_int("rays_per_side", self.rays_per_side)
