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
"""CoACD settings for one-off evaluation (every CoACD field given, so a change to :class:`CoacdParams`' defaults, the
objects stage's, leaves ``gen evaluate``'s parts and the calibration labels as they are), chosen by hull slack
(``studies/hull_slack.py``): how far the parts MuJoCo collides stand out of the true surface, which ACRONYM checks the
open hand against. Criterion, fixed before any agreement with FleX was looked at: slack p95 <= 1 mm (half the fingers' 2
mm touch allowance, :data:`graspgen.sim.prefilter.TARGET_TOUCH_DEPTH`, which is meant in the object: slack eats it; the
palm has none) on every calibration object, within 600 s of CoACD on one core each; none meets it on all six (the 0.35 m
hat: 1.64 mm at best), so the tightest worst case in time. p95 / max slack, mm, now (before: threshold 0.1, 8 hulls,
preprocess resolution 30): example mug 0.67 / 2.07 (2.34 / 3.55), mug 187859 0.36 / 1.61 (2.08 / 4.40), bowl 4b93a8 0.64
/ 1.12 (2.16 / 3.27), knife 0.40 / 1.09 (1.01 / 2.19), hat 1.64 / 2.82 (3.72 / 6.31), bottle 3ae3a9 1.28 / 2.33 (the
same). Cost: 571 s of one core for the six (before: 54 s), 389 s of it the example mug, whose self-intersecting mesh
CoACD first rebuilds on a grid of that many cells (at 30, with the same threshold: p95 1.20 mm); cached after the first
run. Since issue 24's part merge (:mod:`graspgen.geometry.part_merge`; CoACD's own merge off, the refinement's finer cut
only where CoACD made few enough pieces) the search budget is the objects stage's, 10 iterations of 5 nodes (30 of 20
before), and ``refine_excess`` 0.01 is given too; the calibration agreement before and after is in docs/cluster.md."""


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
