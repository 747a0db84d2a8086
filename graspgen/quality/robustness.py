"""Stage 5, ``robustness``: how often a successful grasp still succeeds when it is placed with error.

One task per scene (inputs rollouts, grasps, scenes, objects). The scene and the gripper are compiled once per
task (:func:`graspgen.sim.rollouts.scene_simulator`, the rollouts stage's protocol ``rollouts.lift``). For every grasp
whose rollout succeeded (outcome 5), ``num_perturbations`` perturbed copies are rolled out in that same model:

* the TCP pose ``T`` (world) becomes ``T @ [R(w) | t]``: a translation ``t ~ N(0, translation_sigma^2 I)`` (m) and a
  rotation by the rotation vector ``w ~ N(0, rotation_sigma^2 I)`` (rad), both in the TCP frame (x closing,
  z approach), the rotation about the TCP origin. The width (and so the opening) stays the nominal one: the
  controller does not know the error;
* with ``object_noise``, the target object is also moved at placement by a planar error: ``N(0,
  object_translation_sigma^2)`` along world x and y and a yaw ``N(0, object_rotation_sigma^2)`` about the vertical
  line through its centre of mass. Planar, so the object still rests on its support in the same stable pose. A moved
  object can start touching a neighbour; the physics resolves that and the rules may then label the copy 1 or 2.
* the target's physics: its mass (and inertia) scaled by ``exp(mass_sigma z)`` (log-normal, median 1: uniform
  density scaling, so the centre of mass and the inertia's shape stay), its centre of mass moved by
  ``N(0, com_sigma^2 I)`` (m, mesh frame; the inertia is kept about the new centre) and then held over the
  object's support (:func:`resting_com_offset`: the object is where it was seen, at rest, so its centre of mass is
  above what it rests on; a horizontal shift that would tip or roll it is pulled back inside the support polygon),
  and its sliding friction
  coefficient (which governs the gripper-target contacts) drawn from ``N(mu, friction_sigma^2)`` truncated to
  ``> 0`` (one draw, by inverse CDF). The copy's epsilon uses its own centre of mass and (unless
  ``metrics.epsilon.friction`` fixes one) its own friction.

  A copy with any object perturbation builds its own :class:`graspgen.sim.lift.LiftSimulator` (a copy of the
  compiled model, ~1 ms); with every object sigma 0 and no ``object_noise`` the copies share the nominal model.

Labels per grasp: ``robustness`` = successes / n, the fraction of copies with outcome 5 (never an average of outcome
codes), with its Wilson score 95% interval (:func:`wilson_interval`); ``grip_robustness`` = successes / the copies
that reached the grip (outcome 3-5: not stopped by a collision with the ground, the target or clutter during
placement or approach), with its Wilson interval: how well the grasp holds when the hand gets there, apart from
whether a misplaced hand can get there (NaN when no copy got there); every copy's outcome code
(``copy_outcomes``, the failure cause of each copy); the epsilon of every copy (its contacts, by
the rule of :mod:`stages.metrics`: the copy's rollout contacts when both jaws touched, taken to the object frame with
the object's pose recorded at the end of closing, so exactly; else ray-cast closing contacts at the copy's pose
relative to the object; the contact model of ``metrics.epsilon``); ``pfc`` = the fraction of copies with epsilon >
``epsilon_delta`` (probability of force closure, Weisz and Allen). Grasps that did not succeed get ``n = 0`` and NaN
labels: a robustness of 0 would read as "tried and failed", which was not measured (filter on outcome 5).

Optional robustness radius (``radius: true``): along each of the six TCP axes (translation along x, y, z in m;
rotation about x, y, z in rad), the largest offset that still succeeds, by bisection on ``[0, radius_max_*]`` in each
direction (``radius_iterations`` halvings after a first try at the maximum; a copy succeeding at the maximum gives
the maximum). The column holds the smaller of the two directions. Bisection finds *a* boundary: where success is
not monotone along the axis the radius is one of the edges, not necessarily the first. No randomness.

Randomness: all draws for a scene are made up front from the task's generator, ``(grasps, n, 14)`` standard normals
(:data:`DRAWS_PER_COPY`, in a fixed order per copy, each drawn whether used or not) in grasp order (for every
grasp, successful or not), so a grasp's perturbations depend only on the task key and its row, never on
scheduling, worker count or the other grasps' outcomes.

Output per scene: one Parquet table, one row per grasp of the grasps table, joined on ``(scene_id, grasp_id)``:

==================  ==============  =========================================================================
column              type            meaning
==================  ==============  =========================================================================
scene_id, grasp_id  string, int32   the grasp
n                   int32           perturbed copies rolled out (0 unless the grasp's outcome is 5)
successes           int32           copies with outcome 5
robustness          float64         successes / n, in [0, 1]; NaN when n = 0
robustness_lo/_hi   float64         Wilson score 95% interval of the success rate; NaN when n = 0
grip_robustness     float64         successes / copies with outcome 3-5 (that reached the grip); NaN when none
grip_robustness_lo  float64         Wilson score 95% interval of grip_robustness (``_lo``, ``_hi``); NaN when
/_hi                                none
pfc                 float64         fraction of copies with epsilon > ``epsilon_delta``; NaN when n = 0
copy_outcomes       list<int8>      outcome code 0-5 of each copy (its failure cause), n values
copy_epsilon        list<float64>   epsilon of each copy, n values
radius_x/_y/_z      float64         robustness radius along the TCP axes, m; NaN when off or n = 0
radius_rx/_ry/_rz   float64         robustness radius about the TCP axes, rad; NaN when off or n = 0
==================  ==============  =========================================================================
"""

from __future__ import annotations

import copy
import dataclasses
import math
from statistics import NormalDist
from typing import Any

import mujoco
import numpy as np
import pyarrow as pa
from scipy.optimize import nnls
from scipy.spatial import ConvexHull, QhullError

from graspgen.geometry.contacts import closing_contacts
from graspgen.io.arrow import column_array, variable_list
from graspgen.io.objects import ObjectRecord
from graspgen.quality.epsilon import (
    CONTACT_SOURCES,
    EpsilonParams,
    ObjectGeometry,
    check_joined,
    contact_set,
    object_geometry,
)
from graspgen.sim.grippers import GripperSpec, load_gripper
from graspgen.sim.lift import OUTCOME_NAMES, LiftParams, LiftSimulator, Outcome, RolloutResult
from graspgen.sim.scene_model import object_body_name
from graspgen.validation import check, check_int, check_number, check_transform

__all__ = [
    "DRAWS_PER_COPY",
    "GRIP_CODES",
    "RADIUS_AXES",
    "RobustnessParams",
    "RobustnessTaskParams",
    "GraspRobustness",
    "SCHEMA",
    "wilson_interval",
    "rotvec_to_matrix",
    "perturbed_poses",
    "truncated_friction",
    "support_points",
    "resting_com_offset",
    "grasp_robustness",
    "robustness_radius",
    "scene_robustness",
]

RADIUS_AXES = ("x", "y", "z", "rx", "ry", "rz")
"""Axes of the robustness radius: translation along the TCP x, y, z axes, then rotation about them."""

DRAWS_PER_COPY = 14
"""Standard normals drawn per perturbed copy, in this order: TCP translation (3), TCP rotation vector (3), object
x, y, yaw (3), mass scale (1), centre-of-mass offset (3), friction (1). All are drawn whatever the settings."""

GRIP_CODES = (Outcome.NO_CONTACT_ESTABLISHED, Outcome.SLIPPED_DURING_LIFTING, Outcome.SUCCESS)
"""Outcome codes of copies that reached the grip (``grip_robustness``'s denominator): not stopped by a collision
during placement or approach (codes 0-2)."""


@dataclasses.dataclass(frozen=True)
class RobustnessParams:
    """Settings of the ``robustness`` stage (config section ``robustness``).

    The rollout protocol is the rollouts stage's (``rollouts.lift``) and the epsilon of the copies follows
    ``metrics.epsilon``: both enter this stage's key."""

    num_perturbations: int = 20
    """Perturbed copies rolled out per successful grasp."""
    translation_sigma: float = 0.005
    """Standard deviation (m) of the TCP translation error along each TCP axis. Compare it with the jaws' clearance,
    ``rollouts.lift.width_margin / 2`` per side (10 mm by default; less for widths near the stroke): a copy offset
    by more than that along the closing axis lands a finger on the target at placement (code 1) or pushes it during
    the approach (code 1 beyond ``rollouts.lift.max_target_shift``)."""
    rotation_sigma: float = math.radians(5.0)
    """Standard deviation (rad) of each component of the TCP rotation error (a rotation vector in the TCP frame)."""
    object_noise: bool = False
    """Also move the target object at placement (planar: world x, y and yaw about its centre of mass). Off by
    default: what a grasp feels is the hand's pose relative to the object, and the TCP error already perturbs it in
    all six dimensions (a planar object error is, to the hand, a TCP error in x, y and yaw); turning this on adds
    that error a second time and mostly moves the object into its neighbours (codes 1-2, left out of
    ``grip_robustness`` anyway). Turn it on to model a perception error of the object's position among clutter."""
    object_translation_sigma: float = 0.005
    """Standard deviation (m) of the object's x and y error (with ``object_noise``)."""
    object_rotation_sigma: float = math.radians(5.0)
    """Standard deviation (rad) of the object's yaw error (with ``object_noise``)."""
    mass_sigma: float = 0.2
    """Standard deviation of the log of the target's mass scale (dimensionless): the copy's mass and inertia are the
    nominal ones times ``exp(mass_sigma z)``, so 0.2 is about +-20% at one sigma, median 1. Physical argument: the
    record's mass is the mesh volume times an assumed density (or a catalogue mass), and the density of household
    objects of one kind spreads by tens of percent (a full or half-empty bottle, wood versus plastic). Dex-Net 2.0
    perturbs no mass (its metric is quasi-static); 0 turns it off."""
    com_sigma: float = 0.005
    """Standard deviation (m) of the target's centre-of-mass offset along each mesh axis. The record's centre of
    mass assumes uniform density; contents (liquid, a battery) move it by millimetres to a centimetre on
    hand-sized objects, so about 5 mm is the physical size of the error (Dex-Net's object random variable has such
    a term, ``sigma_obj_com`` in ``dexnet/grasping/random_variables.py``). The copy's object stays in its observed
    resting pose, so the offset is made consistent with it (:func:`resting_com_offset`): its horizontal part is
    pulled back inside the support polygon (a cylinder on its side keeps only the shift along its axis and the
    vertical). Without that a shifted centre sets the object moving on its own (a cylinder on its side rolls) and
    the rules label the copy 1 although the hand never touched it (measured on ``configs/smoke.yaml`` at 5 mm
    before the projection: the cylinder's copies went from 1-4 to 16 of 20 code 1). 0 turns it off."""
    friction_sigma: float = 0.1
    """Standard deviation of the target's sliding friction coefficient (dimensionless, absolute), truncated to
    ``> 0``: the copy's coefficient is drawn from ``N(mu, friction_sigma^2)`` restricted to ``(0, inf)``. 0.1 is
    Dex-Net's friction uncertainty (coefficient ~ N(0.5, 0.1^2) in Dex-Net 1.0 / 2.0's robust metrics, Mahler et al.
    2016, 2017), and about the spread of measured coefficients of one material pair."""
    epsilon_delta: float = 0.0
    """``pfc`` counts copies with epsilon > this (0: the probability of force closure itself)."""
    radius: bool = False
    """Also bisect the robustness radius along each TCP axis (12 bisections per grasp: costly)."""
    radius_max_translation: float = 0.02
    """Largest translation (m) the radius search tries."""
    radius_max_rotation: float = 0.5
    """Largest rotation (rad) the radius search tries."""
    radius_iterations: int = 5
    """Halvings per bisection (resolution: the maximum / 2^iterations)."""

    def __post_init__(self) -> None:
        check("num_perturbations", self.num_perturbations >= 1, "be >= 1", self.num_perturbations)
        for name in ("translation_sigma", "rotation_sigma", "object_translation_sigma", "object_rotation_sigma",
                     "mass_sigma", "com_sigma", "friction_sigma", "epsilon_delta"):
            value = getattr(self, name)
            check(name, 0 <= value < math.inf, "be >= 0", value)
        check("mass_sigma", self.mass_sigma <= 2.0, "be <= 2 (a log scale: exp(2) = 7.4 at one sigma)",
              self.mass_sigma)
        check("radius_max_translation", 0 < self.radius_max_translation < math.inf, "be > 0",
              self.radius_max_translation)
        check("radius_max_rotation", 0 < self.radius_max_rotation <= math.pi, "be in (0, pi] rad",
              self.radius_max_rotation)
        check("radius_iterations", 1 <= self.radius_iterations <= 30, "be in [1, 30]", self.radius_iterations)


@dataclasses.dataclass(frozen=True)
class RobustnessTaskParams:
    """Everything a robustness task depends on (what enters its key): its own section, the rollout protocol and
    the epsilon model. Built by :meth:`RobustnessStage.params` from the config."""

    robustness: RobustnessParams = dataclasses.field(default_factory=RobustnessParams)
    lift: LiftParams = dataclasses.field(default_factory=LiftParams)
    epsilon: EpsilonParams = dataclasses.field(default_factory=EpsilonParams)


# ---------------------------------------------------------------------------------------------------------------
# Maths
# ---------------------------------------------------------------------------------------------------------------


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion.

    Parameters
    ----------
    successes : int
        Successes, ``0 <= successes <= n``.
    n : int
        Trials, ``>= 0``.
    z : float
        Standard normal quantile (1.96: 95% two-sided).

    Returns
    -------
    (lo, hi) : floats in [0, 1]; ``(nan, nan)`` when ``n = 0`` (no trials: no information).

    Notes
    -----
    ``(p + z^2 / 2n -+ z sqrt(p (1 - p) / n + z^2 / 4n^2)) / (1 + z^2 / n)`` with ``p = successes / n``. Unlike the
    normal (Wald) interval it stays inside [0, 1] and does not collapse to a point at 0/n or n/n: for 0/n it is
    ``[0, z^2 / (n + z^2)]``.
    """
    successes, n = check_int("successes", successes, low=0), check_int("n", n, low=0)
    check("successes", successes <= n, f"be <= n ({n})", successes)
    check_number("z", z, low=0.0, low_open=True)
    if n == 0:
        return math.nan, math.nan
    p = successes / n
    z2 = z * z
    denom = 1.0 + z2 / n
    centre = (p + z2 / (2 * n)) / denom
    half = z * math.sqrt(p * (1.0 - p) / n + z2 / (4.0 * n * n)) / denom
    # Clamp: at 0/n and n/n the bound is 0 or 1 up to round-off.
    lo = 0.0 if successes == 0 else max(0.0, centre - half)
    hi = 1.0 if successes == n else min(1.0, centre + half)
    return lo, hi


def rotvec_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrices of rotation vectors (axis times angle, rad): ``(n, 3) -> (n, 3, 3)`` (Rodrigues)."""
    v = np.asarray(rotvec, dtype=np.float64).reshape(-1, 3)
    theta2 = np.einsum("ij,ij->i", v, v)
    theta = np.sqrt(theta2)
    small = theta < 1e-6
    safe = np.where(small, 1.0, theta)
    # sin(t)/t and (1 - cos t)/t^2, with their Taylor series near 0 (where the closed forms lose precision).
    a = np.where(small, 1.0 - theta2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    K = np.zeros((len(v), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return np.eye(3) + a[:, None, None] * K + b[:, None, None] * (K @ K)


def perturbed_poses(T: np.ndarray, translation: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """``T @ [R(rotation_i) | translation_i]`` for each row: poses perturbed in their own (TCP) frame.

    Parameters
    ----------
    T : (4, 4) float
        The nominal pose (e.g. TCP to world).
    translation : (n, 3) float, m
        Offsets of the origin, along T's own axes.
    rotation : (n, 3) float, rad
        Rotation vectors in T's own frame (the rotation is about T's origin, applied before the offset moves it).

    Returns
    -------
    (n, 4, 4) float
    """
    T = check_transform("T", T)
    t = np.asarray(translation, dtype=np.float64).reshape(-1, 3)
    w = np.asarray(rotation, dtype=np.float64).reshape(-1, 3)
    if len(t) != len(w):
        raise ValueError(f"rotation: expected {len(t)} rows (as translation), got {len(w)}")
    D = np.zeros((len(t), 4, 4))
    D[:, :3, :3] = rotvec_to_matrix(w)
    D[:, :3, 3] = t
    D[:, 3, 3] = 1.0
    return T @ D


def planar_object_noise(T_world_object: np.ndarray, center_of_mass: np.ndarray, dx: float, dy: float,
                        yaw: float) -> np.ndarray:
    """The object pose ``T_world_object (4, 4)`` turned by ``yaw`` (rad) about the vertical line through its centre
    of mass (``center_of_mass (3,)``, mesh frame, m) and shifted by ``(dx, dy)`` m in the world x/y plane."""
    T = np.asarray(T_world_object, dtype=np.float64)
    c, s = math.cos(yaw), math.sin(yaw)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    com_world = T[:3, :3] @ center_of_mass + T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = Rz @ T[:3, :3]
    out[:3, 3] = Rz @ (T[:3, 3] - com_world) + com_world + (dx, dy, 0.0)
    return out


_NORMAL = NormalDist()


def truncated_friction(mu: float, sigma: float, z: float) -> float:
    """A friction coefficient from ``N(mu, sigma^2)`` truncated to ``> 0``, by inverse CDF of one standard normal
    ``z`` (so one draw per copy, whatever the truncation): ``mu + sigma Phi^-1(a + Phi(z) (1 - a))`` with
    ``a = Phi(-mu / sigma)``. ``sigma = 0`` gives ``mu``."""
    if sigma == 0.0:
        return float(mu)
    a = _NORMAL.cdf(-mu / sigma)
    u = a + _NORMAL.cdf(float(z)) * (1.0 - a)
    u = min(max(u, 1e-15), 1.0 - 1e-15)
    # Round-off can leave the value at or just below 0 when the draw sits at the truncation point.
    return max(mu + sigma * _NORMAL.inv_cdf(u), 1e-6 * mu)


# ---------------------------------------------------------------------------------------------------------------
# Rolling out perturbed copies
# ---------------------------------------------------------------------------------------------------------------


def _pose(pos: np.ndarray, mat: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.asarray(mat, dtype=np.float64).reshape(3, 3)
    T[:3, 3] = pos
    return T


def _free_qadr(model: mujoco.MjModel, body: int) -> int:
    """qpos address of the free joint of ``body`` (an object of the scene)."""
    jnt = int(model.body_jntadr[body])
    if jnt < 0 or model.jnt_type[jnt] != mujoco.mjtJoint.mjJNT_FREE:
        raise ValueError(f"target_body: body {body} has no free joint")
    return int(model.jnt_qposadr[jnt])


def initial_object_pose(simulator: LiftSimulator, target_body: str) -> np.ndarray:
    """(4, 4) pose (mesh frame to world) of ``target_body`` in the model's ``qpos0``: the scene at rest for a
    simulator built by :func:`graspgen.sim.rollouts.scene_simulator` (object noise is applied to this pose)."""
    m = simulator.model
    bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, target_body)
    if bid < 0:
        raise ValueError(f"target_body: no body named {target_body!r}")
    a = _free_qadr(m, bid)
    mat = np.empty(9)
    mujoco.mju_quat2Mat(mat, m.qpos0[a + 3 : a + 7])
    return _pose(m.qpos0[a : a + 3], mat)


def _with_object_pose(simulator: LiftSimulator, target_body: str, T_world_object: np.ndarray | None,
                      mass_scale: float = 1.0, com_offset: np.ndarray | None = None,
                      friction: float | None = None) -> LiftSimulator:
    """A simulator of the same scene whose initial configuration has ``target_body`` at ``T_world_object`` (None:
    where it is), with the target's mass and inertia times ``mass_scale``, its centre of mass moved by
    ``com_offset (3,)`` m (body frame = mesh frame) and the sliding friction of its geoms set to ``friction``."""
    m = copy.deepcopy(simulator.model)
    bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, target_body)
    a = _free_qadr(m, bid)
    qpos = m.qpos0.copy()
    if T_world_object is not None:
        qpos[a : a + 3] = T_world_object[:3, 3]
        quat = np.empty(4)
        mujoco.mju_mat2Quat(quat, np.ascontiguousarray(T_world_object[:3, :3]).reshape(-1))
        qpos[a + 3 : a + 7] = quat
    m.body_mass[bid] *= mass_scale
    m.body_inertia[bid] *= mass_scale
    if com_offset is not None and np.any(com_offset):
        m.body_ipos[bid] += com_offset
        # A body compiled with its inertial frame on its own frame is flagged simple; the moved centre breaks that.
        m.body_simple[bid] = 0
        m.body_sameframe[bid] = 0
    if friction is not None:
        m.geom_friction[m.geom_bodyid == bid, 0] = friction
    # Constants that depend on the masses (the constraint solver's inverse weights, subtree masses), recomputed at
    # the model's qpos0 as at compile time.
    mujoco.mj_setConst(m, mujoco.MjData(m))
    # The simulator's model already carries the protocol's physics and grip force; applying them again is a no-op.
    return LiftSimulator(m, simulator.params, qpos=qpos, prefix=simulator.prefix)


SUPPORT_TOLERANCE = 5e-5
"""Height (m) over the target's lowest collision vertex within which a vertex counts as resting on what holds it up
(:func:`support_points`). The settle leaves a face lying flat level to a few micrometres, while the next vertex
line of a faceted cylinder on its side stands 0.12 mm up (a 64-gon of 25 mm radius): counting it would widen the
support to a facet the cylinder does not rest on, and centres moved over it roll the cylinder (measured: up to
2.6 mm of drift at 0.2 mm, none over 0.12 mm at this value). Too small a value only shrinks the polygon, which
keeps less of the drawn offsets: the safe side."""

TIPPING_MARGIN_FLOOR = math.radians(10.0)
"""A copy's centre of mass keeps the object at least as hard to tip as the nominal one, or this hard (rad), whichever
is less (:func:`resting_com_offset`). The tipping angle about a support edge is ``atan(d / h)``: ``d`` the centre's
horizontal distance inside that edge, ``h`` its height over the support. 10 degrees is far above what the settle
and the contact solver's softness tilt a resting object (well under a degree) and what a brushing finger does; a
nominal object resting with less (a cylinder on its side: a facet of a few mm, ~3 degrees) keeps its own."""

def support_points(simulator: LiftSimulator, target_body: str) -> np.ndarray:
    """Where ``target_body`` rests on what holds it up, in the simulator's initial configuration ``model.qpos0`` (the
    scene at rest): the vertices of its collision meshes within :data:`SUPPORT_TOLERANCE` of its lowest one, when
    something other than the gripper touches it there. Taken from the geometry, not from MuJoCo's contact points:
    those of a convex mesh on a box are a few points placed by the collision routine, not the supporting face.

    Returns
    -------
    (k, 3) float
        Points, m, in the target's body frame (the mesh frame); ``k = 0`` when nothing holds it up from below (an
        object in free space).
    """
    m = simulator.model
    bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, target_body)
    if bid < 0:
        raise ValueError(f"target_body: no body named {target_body!r}")
    d = mujoco.MjData(m)
    d.qpos[:] = m.qpos0
    mujoco.mj_forward(m, d)
    vertices = []
    for g in np.flatnonzero((m.geom_bodyid == bid) & (m.geom_type == mujoco.mjtGeom.mjGEOM_MESH)
                            & ((m.geom_contype != 0) | (m.geom_conaffinity != 0))):
        mesh = int(m.geom_dataid[g])
        start, count = int(m.mesh_vertadr[mesh]), int(m.mesh_vertnum[mesh])
        local = m.mesh_vert[start:start + count].astype(np.float64)
        vertices.append(local @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g])
    if not vertices:
        return np.zeros((0, 3))
    world = np.concatenate(vertices)
    low = float(world[:, 2].min())
    held = False
    for c in d.contact[: d.ncon]:
        b1, b2 = int(m.geom_bodyid[c.geom1]), int(m.geom_bodyid[c.geom2])
        other = b2 if b1 == bid else b1 if b2 == bid else -1
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, other) if other >= 0 else None
        if other >= 0 and other != bid and not (name or "").startswith(simulator.prefix) \
                and c.pos[2] <= low + SUPPORT_TOLERANCE + 1e-3:
            held = True
            break
    if not held:
        return np.zeros((0, 3))
    bottom = world[world[:, 2] <= low + SUPPORT_TOLERANCE]
    R, t = d.xmat[bid].reshape(3, 3), d.xpos[bid]
    return (bottom - t) @ R


def _support_halfplanes(polygon: np.ndarray) -> tuple[np.ndarray, np.ndarray] | tuple[np.ndarray, np.ndarray, float,
                                                                                      float]:
    """The support polygon ``(k, 2)`` as half-planes or, when it has no area, as a segment.

    Returns ``(normals (e, 2), offsets (e,))``, inward unit normals of the convex hull's edges (inside is ``normals @ x
    - offsets >= 0``, that value being the distance inside each edge); or, for collinear points (a cylinder on its
    side resting on one line of vertices) or a single point, ``(centre (2,), direction (2,), lo, hi)``: the segment
    ``centre + s direction`` for ``s`` in ``[lo, hi]``."""
    centre = polygon.mean(axis=0)
    spread = polygon - centre
    _, sv, vt = np.linalg.svd(spread, full_matrices=False)
    flat = len(polygon) < 3 or sv[0] == 0.0 or sv[1] <= 1e-6 * sv[0]
    if not flat:
        try:
            hull = ConvexHull(polygon)
        except QhullError:  # nearly collinear beyond the tolerance above
            flat = True
    if flat:
        u = vt[0] if sv[0] > 0 else np.array([1.0, 0.0])
        along = spread @ u
        return centre, u, float(along.min()), float(along.max())
    return -hull.equations[:, :2], hull.equations[:, 2]  # qhull's normals are outward and unit


def resting_com_offset(offset: np.ndarray, support: np.ndarray, T_world_object: np.ndarray,
                       center_of_mass: np.ndarray) -> np.ndarray:
    """A centre-of-mass offset consistent with the object resting, stably, where it was seen.

    An object seen at rest has its centre of mass over its support polygon (the convex hull of where it touches what
    holds it, seen from above), and it stays put when nudged. A drawn offset that breaks either would tip or roll the
    object before the hand arrives: a different scene, not a heavier side of this one. So the shifted centre ``c``
    must keep, on every support edge, a tipping angle ``atan(d_e(c) / h(c))`` (``d_e`` its horizontal distance
    inside edge ``e``, ``h`` its height over the support) of at least ``min(nominal angle,``
    :data:`TIPPING_MARGIN_FLOOR` ``)``. These are linear constraints on ``c`` (a convex polyhedron holding the nominal
    centre); the drawn centre is replaced by the nearest point in it at the same height (a least-distance program),
    or, where no point at that height qualifies, by the nearest point in it. A box flat on a face
    keeps millimetre offsets whole; a cylinder on its side (resting on a line of its facets) keeps the shift along its
    axis and the vertical one, not the one across (which would roll it). No support (free space): the offset as given. A
    nominal centre not over its support (the object leans on a neighbour, the polygon says nothing of its balance):
    the offset without its horizontal part.

    Parameters
    ----------
    offset : (3,) float
        Drawn offset, m, mesh frame.
    support : (k, 3) float
        :func:`support_points`, mesh frame.
    T_world_object : (4, 4) float
        The object's pose (mesh frame to world) at rest.
    center_of_mass : (3,) float
        Nominal centre of mass, m, mesh frame.

    Returns
    -------
    (3,) float
        The offset, m, mesh frame.
    """
    offset = np.asarray(offset, dtype=np.float64).reshape(3)
    support = np.asarray(support, dtype=np.float64).reshape(-1, 3)
    if len(support) == 0 or not offset.any():
        return offset.copy()
    T = np.asarray(T_world_object, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    points = support @ R.T + t
    c0 = R @ np.asarray(center_of_mass, dtype=np.float64).reshape(3) + t
    w = R @ offset
    z_support = float(points[:, 2].mean())
    h0 = c0[2] - z_support
    support_2d = _support_halfplanes(points[:, :2])
    if len(support_2d) == 4:  # a line: the centre stays on it, within its ends
        centre, u, lo, hi = support_2d
        across = np.array([-u[1], u[0]]) @ (c0[:2] - centre)
        if abs(across) > 1e-6 or h0 <= 0.0:
            w[:2] = 0.0  # leaning on something: the support line does not decide its balance
            return R.T @ w
        along = float(np.clip(u @ (c0[:2] + w[:2] - centre), lo, hi))
        w[:2] = centre + across * np.array([-u[1], u[0]]) + along * u - c0[:2]
        return R.T @ w
    normals, offsets = support_2d
    inside = normals @ c0[:2] - offsets
    if inside.min() < -1e-6 or h0 <= 0.0:
        w[:2] = 0.0  # leaning on something: the support polygon does not decide its balance
        return R.T @ w
    slope = min(max(float(inside.min()), 0.0) / h0, math.tan(TIPPING_MARGIN_FLOOR))  # tan of the tipping angle
    # Constraints a_e . c >= b_e: d_e(c) - slope * (c_z - z_support) >= 0.
    A = np.column_stack([normals, np.full(len(normals), -slope)])
    b = offsets - slope * z_support
    c = c0 + w
    if np.all(A @ c - b >= -1e-12):
        return offset.copy()
    try:  # the drawn height kept, the horizontal position pulled back
        c[:2] = _project_onto_halfspaces(c[:2], normals, offsets + slope * (c[2] - z_support))
    except ValueError:  # raised so far that no position keeps the margin: the height gives way too
        c = _project_onto_halfspaces(c, A, b)
    return R.T @ (c - c0)


def _project_onto_halfspaces(x: np.ndarray, A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The point of ``{y : A @ y >= b}`` (non-empty) nearest ``x (n,)``: least-distance programming by non-negative
    least squares (Lawson and Hanson, "Solving Least Squares Problems", 1974, ch. 23): with ``G = A``,
    ``h = b - A x``, minimise ``|E u - f|`` over ``u >= 0`` for ``E = [G^T; h^T]``, ``f = (0, ..., 0, 1)``; the
    residual ``r = E u - f`` gives the step ``z = -r[:n] / r[n]``. Exact up to round-off, no iteration count."""
    h = b - A @ x
    if np.all(h <= 0.0):
        return x.copy()
    E = np.vstack([A.T, h[None, :]])
    f = np.zeros(len(x) + 1)
    f[-1] = 1.0
    u, _ = nnls(E, f)
    r = E @ u - f
    if abs(r[-1]) < 1e-12:
        raise ValueError("A, b: the constraints have no common point")
    y = x - r[:-1] / r[-1]
    if np.any(A @ y - b < -1e-9 * max(1.0, float(np.abs(b).max()))):
        raise ValueError("A, b: the constraints have no common point (or are too ill-conditioned to tell)")
    return y


def _target_friction(simulator: LiftSimulator, target_body: str) -> float:
    """Sliding friction of the target's colliding geoms in the simulator's model (the largest, should they differ;
    visual-only geoms keep MuJoCo's default 1 and do not count)."""
    m = simulator.model
    bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, target_body)
    colliding = (m.geom_bodyid == bid) & ((m.geom_contype != 0) | (m.geom_conaffinity != 0))
    if not colliding.any():
        raise ValueError(f"target_body: body {target_body!r} has no colliding geom")
    return float(m.geom_friction[colliding, 0].max())


class _TargetPoses:
    """Rollout observer that keeps the target's pose at placement and at the last check of the closing phase. The
    latter is the state the rollout's contacts are read from (no step happens between that check and the contact
    read-out), so contacts and pose come from the same ``mj_step`` (its collision detection and its ``xpos``/``xmat``).
    """

    def __init__(self, data: mujoco.MjData, body: int) -> None:
        self.data, self.body = data, body
        self.placed: np.ndarray | None = None
        self.closed: np.ndarray | None = None

    def __call__(self, phase: str, steps: int) -> None:
        if phase == "closing":
            self.closed = _pose(self.data.xpos[self.body], self.data.xmat[self.body])
        elif phase == "placement":
            self.placed = _pose(self.data.xpos[self.body], self.data.xmat[self.body])


def rollout_with_object_pose(
    simulator: LiftSimulator, T_tcp_world: np.ndarray, width: float, target_body: str
) -> tuple[RolloutResult, np.ndarray, np.ndarray | None]:
    """Roll out one grasp and also return the target's poses (4, 4), mesh frame to world: at placement (before any
    step), and when the contacts were recorded (the end of closing; None when the rollout ended before closing)."""
    bid = mujoco.mj_name2id(simulator.model, mujoco.mjtObj.mjOBJ_BODY, target_body)
    observer = _TargetPoses(simulator.data, bid)
    result = simulator.rollout(T_tcp_world, width, target_body, observer=observer)
    assert observer.placed is not None  # the protocol reports the placement before anything can stop it
    return result, observer.placed, observer.closed


@dataclasses.dataclass(frozen=True, eq=False)
class GraspRobustness:
    """The robustness labels of one grasp (see the module docstring)."""

    n: int
    successes: int
    robustness: float
    """successes / n."""
    interval: tuple[float, float]
    """Wilson score 95% interval."""
    grip_n: int
    """Copies that reached the grip (outcome in :data:`GRIP_CODES`)."""
    grip_robustness: float
    """successes / grip_n; NaN when grip_n = 0."""
    grip_interval: tuple[float, float]
    """Wilson score 95% interval of grip_robustness."""
    pfc: float
    """Fraction of copies with epsilon > delta."""
    outcomes: np.ndarray
    """(n,) int8 outcome codes of the copies."""
    epsilons: np.ndarray
    """(n,) float64 epsilon of the copies."""
    sources: tuple[str, ...]
    """Where each copy's contacts came from (``rollout``, ``raycast``, ``none``)."""
    radius: np.ndarray
    """(6,) float64 robustness radius along/about the TCP axes (:data:`RADIUS_AXES`); NaN when not computed."""


def grasp_robustness(
    simulator: LiftSimulator,
    T_tcp_world: np.ndarray,
    width: float,
    target_body: str,
    geometry: ObjectGeometry,
    friction: float,
    draws: np.ndarray,
    params: RobustnessParams,
    epsilon: EpsilonParams,
    gripper: GripperSpec,
    epsilon_friction_follows: bool = True,
) -> GraspRobustness:
    """Roll out the perturbed copies of one grasp and label it.

    Parameters
    ----------
    simulator : LiftSimulator
        The compiled scene with the gripper (its initial configuration = the scene at rest).
    T_tcp_world : (4, 4) float
        The nominal grasp (TCP to world).
    width : float
        Nominal pad separation, m.
    target_body : str
        The target's body name, ``obj/<i>_<name>``.
    geometry : ObjectGeometry
        The target's mesh, centre of mass and torque scale (epsilon of the copies).
    friction : float
        Coulomb coefficient of the epsilon's friction cones.
    draws : (n, 14) float
        Standard normals per copy (:data:`DRAWS_PER_COPY`): TCP translation, TCP rotation vector, object x, y, yaw
        (used only with ``params.object_noise``), mass scale, centre-of-mass offset, friction. ``n`` copies are
        rolled out.
    epsilon_friction_follows : bool
        Whether the copies' epsilon uses each copy's perturbed friction (True: ``friction`` is the target's
        simulated friction) or ``friction`` as given (a fixed ``metrics.epsilon.friction``).
    params : RobustnessParams
    epsilon : EpsilonParams
    gripper : GripperSpec
        The gripper (its pads for the ray-cast contacts).

    Returns
    -------
    GraspRobustness
    """
    draws = np.asarray(draws, dtype=np.float64)
    if draws.ndim != 2 or draws.shape[1] != DRAWS_PER_COPY or len(draws) == 0:
        raise ValueError(f"draws: expected shape (n >= 1, {DRAWS_PER_COPY}), got {draws.shape}")
    poses = perturbed_poses(T_tcp_world, params.translation_sigma * draws[:, 0:3],
                            params.rotation_sigma * draws[:, 3:6])
    T_obj0 = initial_object_pose(simulator, target_body) if params.object_noise or params.com_sigma > 0 else None
    support = support_points(simulator, target_body) if params.com_sigma > 0 else np.zeros((0, 3))
    physics = params.mass_sigma > 0 or params.com_sigma > 0 or params.friction_sigma > 0
    mu_sim = _target_friction(simulator, target_body)
    n = len(draws)
    outcomes = np.zeros(n, dtype=np.int8)
    results: list[tuple[RolloutResult, np.ndarray | None, np.ndarray]] = []
    coms = np.tile(np.asarray(geometry.center_of_mass, dtype=np.float64), (n, 1))
    mus = np.full(n, float(friction))
    for j in range(n):
        sim = simulator
        if params.object_noise or physics:
            T_obj = None
            if params.object_noise:
                dx, dy, yaw = draws[j, 6:9] * (params.object_translation_sigma, params.object_translation_sigma,
                                               params.object_rotation_sigma)
                T_obj = planar_object_noise(T_obj0, geometry.center_of_mass, dx, dy, yaw)
            mass_scale = math.exp(params.mass_sigma * draws[j, 9])
            offset = resting_com_offset(params.com_sigma * draws[j, 10:13], support,
                                        T_obj0 if T_obj is None else T_obj, geometry.center_of_mass)
            mu = truncated_friction(mu_sim, params.friction_sigma, draws[j, 13])
            coms[j] += offset
            if epsilon_friction_follows:
                mus[j] = mu
            sim = _with_object_pose(simulator, target_body, T_obj, mass_scale, offset, mu)
        result, T_placed, T_closed = rollout_with_object_pose(sim, poses[j], width, target_body)
        outcomes[j] = result.code
        results.append((result, T_closed, T_placed))
    # Ray casts only where the copy's own contacts do not touch both pads, at the copy's pose relative to the object
    # as placed; batched: one call per grasp.
    need = [j for j, (r, _, _) in enumerate(results) if not np.isin((0, 1), r.contact_fingers).all()]
    rays = {}
    if need:
        rel = np.stack([np.linalg.inv(results[j][2]) @ poses[j] for j in need])
        found = closing_contacts(geometry.mesh, rel, gripper, rays_per_side=epsilon.rays_per_side,
                                 tolerance=epsilon.ray_tolerance)
        rays = dict(zip(need, found))
    epsilons = np.zeros(n)
    sources = []
    for j, (r, T_closed, _) in enumerate(results):
        rollout = (r.contact_points, r.contact_normals, r.contact_fingers)
        source, p, nrm, f = contact_set(rollout, T_closed if T_closed is not None else np.eye(4), rays.get(j))
        sources.append(source)
        if source != "none":
            g = geometry if not params.com_sigma else dataclasses.replace(geometry, center_of_mass=coms[j])
            epsilons[j] = epsilon.epsilon(p, nrm, f, g, float(mus[j]))
    successes = int((outcomes == Outcome.SUCCESS).sum())
    grip_n = int(np.isin(outcomes, GRIP_CODES).sum())
    radius = np.full(len(RADIUS_AXES), np.nan)
    if params.radius:
        radius = robustness_radius(simulator, T_tcp_world, width, target_body, params)
    return GraspRobustness(
        n=n, successes=successes, robustness=successes / n, interval=wilson_interval(successes, n),
        grip_n=grip_n, grip_robustness=successes / grip_n if grip_n else math.nan,
        grip_interval=wilson_interval(successes, grip_n),
        pfc=float(np.mean(epsilons > params.epsilon_delta)), outcomes=outcomes, epsilons=epsilons,
        sources=tuple(sources), radius=radius,
    )


def robustness_radius(
    simulator: LiftSimulator, T_tcp_world: np.ndarray, width: float, target_body: str, params: RobustnessParams
) -> np.ndarray:
    """Robustness radius of a successful grasp along/about each TCP axis (:data:`RADIUS_AXES`), by bisection.

    For each axis and direction: a copy offset by the maximum (``radius_max_translation`` m or
    ``radius_max_rotation`` rad) is rolled out; if it succeeds the direction's radius is the maximum, else
    ``radius_iterations`` halvings of ``[0, maximum]`` (0 is the nominal grasp, assumed successful). The axis's
    radius is the smaller of its two directions. ``(6,)`` float: m for the translations, rad for the rotations.
    """
    out = np.zeros(len(RADIUS_AXES))
    for axis in range(len(RADIUS_AXES)):
        top = params.radius_max_translation if axis < 3 else params.radius_max_rotation
        edges = []
        for sign in (1.0, -1.0):
            if _offset_succeeds(simulator, T_tcp_world, width, target_body, axis, sign * top):
                edges.append(top)
                continue
            lo, hi = 0.0, top
            for _ in range(params.radius_iterations):
                mid = 0.5 * (lo + hi)
                ok = _offset_succeeds(simulator, T_tcp_world, width, target_body, axis, sign * mid)
                lo, hi = (mid, hi) if ok else (lo, mid)
            edges.append(lo)
        out[axis] = min(edges)
    return out


def _offset_succeeds(simulator: LiftSimulator, T_tcp_world: np.ndarray, width: float, target_body: str, axis: int,
                     amount: float) -> bool:
    """Whether the grasp offset by ``amount`` along/about TCP axis ``axis`` (0-2 m, 3-5 rad) succeeds."""
    offset = np.zeros(6)
    offset[axis] = amount
    (T,) = perturbed_poses(T_tcp_world, offset[None, :3], offset[None, 3:])
    return simulator.rollout(T, width, target_body).code == Outcome.SUCCESS


# ---------------------------------------------------------------------------------------------------------------
# The stage
# ---------------------------------------------------------------------------------------------------------------

SCHEMA = pa.schema(
    [
        ("scene_id", pa.string()),
        ("grasp_id", pa.int32()),
        ("n", pa.int32()),
        ("successes", pa.int32()),
        ("robustness", pa.float64()),
        ("robustness_lo", pa.float64()),
        ("robustness_hi", pa.float64()),
        ("grip_robustness", pa.float64()),
        ("grip_robustness_lo", pa.float64()),
        ("grip_robustness_hi", pa.float64()),
        ("pfc", pa.float64()),
        ("copy_outcomes", pa.list_(pa.int8())),
        ("copy_epsilon", pa.list_(pa.float64())),
        *[(f"radius_{a}", pa.float64()) for a in RADIUS_AXES],
    ]
)
"""The robustness table's schema (see the module docstring)."""


def scene_robustness(
    grasps: pa.Table,
    rollouts: pa.Table,
    simulator: LiftSimulator,
    object_names: list[str],
    friction: np.ndarray,
    records: dict[str, ObjectRecord],
    params: RobustnessTaskParams,
    rng: np.random.Generator,
) -> tuple[pa.Table, dict[str, Any]]:
    """The robustness table of one scene (module docstring) and metadata (copies rolled out, their outcomes).

    Parameters
    ----------
    grasps, rollouts : pyarrow.Table
        The scene's grasps and rollouts tables (one rollouts row per grasp, same order).
    simulator : LiftSimulator
        The scene compiled with the gripper (:func:`graspgen.sim.rollouts.scene_simulator`).
    object_names : list of str
        Object names by scene index; ``friction (n_objects,)`` their friction in the scene.
    records : dict
        Object records by name.
    params : RobustnessTaskParams
    rng : numpy.random.Generator
        The task's generator: every draw is made up front, ``(grasps, num_perturbations, DRAWS_PER_COPY)``.
    """
    check_joined(grasps, rollouts, "rollouts")
    p, ep = params.robustness, params.epsilon
    n_grasps, n_copies = len(grasps), p.num_perturbations
    draws = rng.standard_normal((n_grasps, n_copies, DRAWS_PER_COPY))
    outcome = rollouts.column("outcome").to_numpy()
    poses = column_array(grasps, "pose_world", (4, 4))
    widths = grasps.column("width").to_numpy()
    index = grasps.column("object_index").to_numpy()
    gripper = load_gripper(grasps.column("gripper")[0].as_py()) if n_grasps else None
    geometries: dict[str, ObjectGeometry] = {}
    nan = math.nan
    rows: list[GraspRobustness | None] = []
    for i in range(n_grasps):
        if outcome[i] != Outcome.SUCCESS:
            rows.append(None)
            continue
        k = int(index[i])
        name = object_names[k]
        if name not in geometries:
            geometries[name] = object_geometry(records[name])
        mu = float(friction[k]) if ep.friction is None else ep.friction
        rows.append(grasp_robustness(simulator, poses[i], float(widths[i]), object_body_name(k, name),
                                     geometries[name], mu, draws[i], p, ep, gripper,
                                     epsilon_friction_follows=ep.friction is None))

    def num(get) -> pa.Array:
        return pa.array([get(r) if r is not None else nan for r in rows], pa.float64())

    arrays = {
        "scene_id": grasps.column("scene_id"),
        "grasp_id": grasps.column("grasp_id"),
        "n": pa.array([r.n if r is not None else 0 for r in rows], pa.int32()),
        "successes": pa.array([r.successes if r is not None else 0 for r in rows], pa.int32()),
        "robustness": num(lambda r: r.robustness),
        "robustness_lo": num(lambda r: r.interval[0]),
        "robustness_hi": num(lambda r: r.interval[1]),
        "grip_robustness": num(lambda r: r.grip_robustness),
        "grip_robustness_lo": num(lambda r: r.grip_interval[0]),
        "grip_robustness_hi": num(lambda r: r.grip_interval[1]),
        "pfc": num(lambda r: r.pfc),
        "copy_outcomes": variable_list([r.outcomes if r is not None else () for r in rows], pa.int8()),
        "copy_epsilon": variable_list([r.epsilons if r is not None else () for r in rows], pa.float64()),
    }
    for a, axis in enumerate(RADIUS_AXES):
        arrays[f"radius_{axis}"] = num(lambda r, a=a: r.radius[a])
    table = pa.table(arrays, schema=SCHEMA)
    done = [r for r in rows if r is not None]
    copy_outcomes = np.concatenate([r.outcomes for r in done]) if done else np.zeros(0, np.int8)
    sources = [s for r in done for s in r.sources]
    meta = {
        "grasps": n_grasps,
        "evaluated": len(done),
        "copies": int(len(copy_outcomes)),
        "copy_successes": int((copy_outcomes == Outcome.SUCCESS).sum()),
        "copy_outcomes": {name: int((copy_outcomes == code).sum()) for code, name in enumerate(OUTCOME_NAMES)},
        "copy_grip_reached": int(np.isin(copy_outcomes, GRIP_CODES).sum()),
        "copy_contacts": {s: sources.count(s) for s in CONTACT_SOURCES},
    }
    return table, meta


