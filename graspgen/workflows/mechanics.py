"""Mechanics cases: small worlds where Coulomb friction knows whether a grasp holds, and the label the simulator
gives there.

Each case is one object built as :func:`graspgen.workflows.evaluation_world.evaluation_world` builds ``gen
evaluate``'s (a mesh file, prepared, decomposed and placed exactly as the labels' path does), one bundled gripper and
one protocol
(``acronym``, ``graspdatagen``, ``table``), a variable swept across an analytic threshold by bisection, and the
threshold itself (:mod:`graspgen.quality.mechanics_theory`). Grasp frame: the TCP at the object's centre (or ``d``
from it), closing along the object's x, approach along its -z; the table protocol takes the object resting on its
largest (z) face and grasps it from above. A case reports where the simulator's success label flips and where its
*firm* hold (:attr:`graspgen.sim.protocols.RolloutResult.firm`: still in the hand and never moved 5 mm / 5 degrees in
it) flips.

The free-space protocols' success label does not look at rotation in the hand, so for ``pivot`` it flips only
through the firm hold. What the cases measured besides the thresholds (box pads' extra torsion, the firm
tolerance): docs/decisions/2026-12-07-mechanics-caveats.md; why the 2F-85 linkage hands' slip cases measure their
inner knuckles, not their pads: docs/decisions/2026-12-07-2f85-knuckle-slip.md.

Cases (``kind``): ``slip`` (a box pulled along the pads by gravity and the protocol's peak acceleration: holds iff
m (g + a) <= 2 mu F), ``heavy`` (the same box with the disturbance off: holds iff m g <= 2 mu F), ``pivot`` (a
400 mm bar, mass per :data:`BAR_REST_OFFSET`, grasped d from its centre of mass: holds iff the moment about the
closing axis stays within the pads' torsional limit 2 mu F r_mean), ``wedge`` (a wedge of half-angle alpha
widening away from the palm: squeezed out iff tan(alpha) > mu, shifted by the load along the approach).
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
from pathlib import Path

import numpy as np
import trimesh

from graspgen.errors import SimulationError
from graspgen.grippers import load_gripper
from graspgen.quality import mechanics_theory as theory
from graspgen.sim.protocol_phases import protocol_of
from graspgen.sim.protocols import LiftParams
from graspgen.workflows.evaluate_settings import EvaluateParams
from graspgen.workflows.evaluation_world import EvaluationWorld, evaluation_world

__all__ = ["CASES", "CaseResult", "bar_mass", "box_mesh", "wedge_mesh", "protocol_params", "run_case"]

#: Case kinds, in report order.
CASES = ("slip", "heavy", "pivot", "wedge")
#: Object sizes (m): x = closing width, y, z = height (z is the largest face's normal, so the table protocol finds
#: it lying on that face and grasps it from above, the pads' tips clear of the table).
BOX = (0.06, 0.06, 0.055)
BAR = (0.06, 0.4, 0.05)
#: Offset (m) at which the bar's weight alone reaches the pads' torsional limit: its mass is chosen per gripper and
#: grip force so (0.4 kg for the Panda's 70 N at friction 0.5), leaving room either side on the bar.
BAR_REST_OFFSET = 0.12
WEDGE_HEIGHT = 0.05
WEDGE_WIDTH = 0.035
WEDGE_MASS = 0.05
#: Friction per case: 0.5 for the bar and cube; 0.3 for the wedge (threshold 16.7 degrees).
FRICTION = {"slip": 0.5, "heavy": 0.5, "pivot": 0.5, "wedge": 0.3}


@dataclasses.dataclass(frozen=True)
class CaseResult:
    """One case's sweep: analytic threshold and where the labels flipped (units of ``variable``)."""

    kind: str
    """``slip``, ``heavy``, ``pivot`` or ``wedge``."""
    gripper: str
    """Bundled gripper name (or a gripper file's path)."""
    protocol: str
    """``acronym``, ``graspdatagen`` or ``table``."""
    variable: str
    """What was swept and its unit: ``mass kg``, ``offset m`` or ``half-angle rad``."""
    analytic: float
    """Threshold from Coulomb friction (:mod:`graspgen.quality.mechanics_theory`): holds below it, fails above."""
    label: float
    """Simulated threshold of the success label (code 5), bisected; ``inf`` when it held over the whole range,
    ``-inf`` when it failed at its low end."""
    firm: float
    """Simulated threshold of the firm hold."""
    analytic_rest: float
    """The same threshold with the protocol's disturbance off (gravity or the tug alone; the table protocol's
    lift acceleration kept): where the firm label should flip if the shake were not there."""
    grip_force: float
    """Force (N) each pad presses with."""
    rollouts: int
    """Rollouts the two bisections took."""

    @property
    def error(self) -> tuple[float, float]:
        """Relative error (label, firm) against ``analytic``."""
        a = self.analytic
        return tuple((v - a) / a if a else math.nan for v in (self.label, self.firm))

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "error_label": self.error[0], "error_firm": self.error[1]}


def bar_mass(mu: float, force: float, arm: float) -> float:
    """Mass (kg) of the pivot case's bar: its weight alone turns it in the pads at :data:`BAR_REST_OFFSET`
    (``2 mu F r_mean = m g d``, the limit surface's small sliding term left out)."""
    return 2.0 * mu * force * arm / (theory.G * BAR_REST_OFFSET)


def box_mesh(size, path: Path) -> Path:
    """A box of full extents ``size`` (m), centred at the origin, written as OBJ to ``path``."""
    trimesh.creation.box(extents=size).export(path)
    return path


def wedge_mesh(alpha: float, path: Path) -> Path:
    """A wedge prism (OBJ at ``path``), centred at the origin: width along x ``WEDGE_WIDTH - 2 z tan(alpha)`` for z
    in +-WEDGE_HEIGHT / 2, depth 0.04 m along y. A grasp approaching along -z has its wide end away from the palm,
    where squeezing pushes it (towards its wide end)."""
    h, w, t = WEDGE_HEIGHT / 2.0, WEDGE_WIDTH / 2.0, math.tan(alpha)
    xz = [(-(w + h * t), -h), (w + h * t, -h), (w - h * t, h), (-(w - h * t), h)]
    verts = [(x, y, z) for y in (-0.02, 0.02) for x, z in xz]
    faces = [(0, 1, 2), (0, 2, 3), (4, 6, 5), (4, 7, 6), (0, 4, 5), (0, 5, 1), (1, 5, 6), (1, 6, 2), (2, 6, 7),
             (2, 7, 3), (3, 7, 4), (3, 4, 0)]
    trimesh.Trimesh(verts, faces, process=True).export(path)
    return path


def protocol_params(protocol: str, kind: str) -> LiftParams:
    """The protocol's default settings; ``heavy`` turns the disturbance off (acronym: no shake; table: no shake)."""
    lift = LiftParams().with_protocol(protocol)
    return protocol_of(lift).calm(lift) if kind == "heavy" else lift


def _grasp(offset_y: float, R_world=None) -> np.ndarray:
    """TCP in the object frame, at (0, offset_y, 0): closing along the object's x, approach along its -z; with the
    object's world rotation ``R_world`` (a box resting on a table on any face), approach straight down along the
    object axis that is vertical and closing along x (z if x is the vertical one)."""
    T = np.eye(4)
    T[1, 3] = offset_y
    approach, closing = np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0])
    if R_world is not None:
        k = int(np.argmax(np.abs(R_world[2])))
        if k == 1:
            raise SimulationError("the object rests on its y face (the grasp needs y horizontal)")
        approach = -np.sign(R_world[2, k]) * np.eye(3)[k]
        closing = np.eye(3)[2 if k == 0 else 0]
    T[:3, 0], T[:3, 1], T[:3, 2] = closing, np.cross(approach, closing), approach
    return T


class _Case:
    """One object, gripper and protocol; :meth:`outcome` rolls one grasp out at a value of the variable."""

    def __init__(self, kind, gripper, protocol, mesh, mass, cache_dir):
        self.kind, self.protocol = kind, protocol
        self.lift = protocol_params(protocol, kind)
        params = EvaluateParams(lift=self.lift, friction=FRICTION[kind], mass=mass)
        self.world: EvaluationWorld = evaluation_world(mesh, 1.0, _grasp(0.0)[None], None, gripper, params,
                                                       free_space=protocol_of(protocol).free_space,
                                                       cache_dir=cache_dir)
        self.R = None if protocol_of(protocol).free_space else self.world.world.obj.pose[:3, :3]
        self.mass = mass
        self.rollouts = 0

    def outcome(self, value: float) -> tuple[bool, bool]:
        """(success label, firm hold) at ``value`` of the case's variable."""
        world = self.world
        offset = 0.0
        if self.kind in ("slip", "heavy"):
            obj = world.world.obj
            obj = dataclasses.replace(obj, mass=value, inertia=np.asarray(obj.inertia) * (value / obj.mass))
            world = dataclasses.replace(world, world=dataclasses.replace(world.world, obj=obj))
        elif self.kind == "pivot":
            offset = value
        sim = world.simulator()
        T = world.world.obj.pose @ _grasp(offset, self.R)
        r = sim.rollout(T, float(world.width[0]), world.target_body)
        self.rollouts += 1
        firm = getattr(r, "firm", None)
        if firm is None:  # before RolloutResult.firm: the same rule from the end-of-rollout motion
            firm = r.success and r.rel_translation <= 0.005 and r.rel_rotation <= math.radians(5.0)
        return bool(r.success), bool(firm)


def _bisect(holds, lo: float, hi: float, rel_tol: float) -> float:
    """Where ``holds`` (True below, False above) flips in [lo, hi] to ``rel_tol`` of the value; inf / -inf when it
    does not flip in the range."""
    if holds(hi):
        return math.inf
    if not holds(lo):
        return -math.inf
    while hi - lo > rel_tol * max(abs(hi), abs(lo), 1e-9):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if holds(mid) else (lo, mid)
    return 0.5 * (lo + hi)


def _cached(case):
    memo = {}

    def outcome(value):
        if value not in memo:
            memo[value] = case.outcome(value)
        return memo[value]
    return outcome


def run_case(kind: str, gripper: str, protocol: str, *, cache_dir: str | Path | None = None,
             rel_tol: float = 0.03) -> CaseResult:
    """Sweep one case across its analytic threshold (module docstring) and bisect both labels' flips."""
    spec = load_gripper(gripper)
    lift = protocol_params(protocol, kind)
    rest = protocol_params(protocol, "heavy")
    force = theory.grip_force(lift, spec)
    mu = FRICTION[kind]
    arm = theory.torsion_arm(spec)
    with tempfile.TemporaryDirectory() as tmp:
        if kind in ("slip", "heavy"):
            inertia = (BOX[1] ** 2 + BOX[2] ** 2) / 12.0
            analytic, analytic_rest = (theory.slip_mass(p, mu, force, arm=arm, inertia_per_kg=inertia)
                                       for p in (lift, rest))
            case = _Case(kind, gripper, protocol, box_mesh(BOX, Path(tmp) / "box.obj"), 1.0, cache_dir)
            lo, hi, variable = 0.25 * analytic, 2.5 * analytic, "mass kg"
        elif kind == "pivot":
            mass = bar_mass(mu, force, arm)
            analytic, analytic_rest = (theory.pivot_offset(p, mu, force, arm, mass, BAR) for p in (lift, rest))
            case = _Case(kind, gripper, protocol, box_mesh(BAR, Path(tmp) / "bar.obj"), mass, cache_dir)
            lo, hi, variable = 0.0, BAR[1] / 2.0 - spec.pad_size[1], "offset m"
        else:
            return _wedge(gripper, protocol, spec, lift, force, mu, cache_dir, rel_tol, Path(tmp))
        outcome = _cached(case)
        label = _bisect(lambda v: outcome(v)[0], lo, hi, rel_tol)
        firm = _bisect(lambda v: outcome(v)[1], lo, hi, rel_tol)
    return CaseResult(kind, gripper, protocol, variable, analytic, label, firm, analytic_rest, force, case.rollouts)


def _wedge(gripper, protocol, spec, lift, force, mu, cache_dir, rel_tol, tmp: Path) -> CaseResult:
    """The wedge: each half-angle is its own mesh (and object world)."""
    analytic = theory.wedge_angle(lift, mu, force, WEDGE_MASS)
    rest = theory.wedge_angle(protocol_params(protocol, "heavy"), mu, force, WEDGE_MASS)
    count = [0]
    memo = {}

    def outcome(alpha):
        if alpha not in memo:
            case = _Case("wedge", gripper, protocol, wedge_mesh(alpha, tmp / f"wedge_{alpha:.6f}.obj"), WEDGE_MASS,
                         cache_dir)
            memo[alpha] = case.outcome(alpha)
            count[0] += 1
        return memo[alpha]
    lo, hi = math.radians(3.0), math.radians(30.0)
    label = _bisect(lambda a: outcome(a)[0], lo, hi, rel_tol)
    firm = _bisect(lambda a: outcome(a)[1], lo, hi, rel_tol)
    return CaseResult("wedge", gripper, protocol, "half-angle rad", analytic, label, firm, rest, force, count[0])
