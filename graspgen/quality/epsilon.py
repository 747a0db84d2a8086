"""Analytic grasp quality: Ferrari-Canny epsilon of a parallel-jaw grasp's contacts, friction labels, and stage 6,
``metrics``.

The wrench maths lives in :mod:`graspgen.quality.wrench`; this module turns the contacts a grasp produces (from a
rollout or from :func:`graspgen.geometry.contacts.closing_contacts`) into the contact model the metric uses.

Contact models (``contact_model``):

``"pad"`` (default)
    Each pad's contact patch becomes one soft-finger contact at the patch centroid with the mean inward normal.
    Its torsional friction is ``max(torsional_friction, 2/3 * friction * r)`` with ``r`` the patch radius (the
    largest distance of a contact from the centroid, in the tangent plane): the torsional moment a uniformly
    pressed disc of radius ``r`` resists per unit normal force. This keeps the wrench set full-rank for a
    two-pad grasp (two point contacts alone can never resist torque about the line joining them) and costs one
    20-point hull per grasp.
``"points"``
    Every contact point is its own contact with ``torsional_friction``. Slower (a hull of ``k * m`` points).

Stage ``metrics`` (one task per scene; inputs rollouts, grasps, scenes, objects). For every grasp of the grasps
table it picks one contact set, in the target object's mesh frame:

* ``rollout``: the rollout's contacts at the end of closing, when the grasp was simulated and both jaws touched
  the target. MuJoCo reports one to four contacts per pad and convex part: four (the patch corners) when the pad
  lies flat on a face, one when it meets the face at an angle (then the pad model sees a point contact with the
  ``torsional_friction`` floor, where the ray casts may see a patch). They are stored in the world frame at the end
  of closing, and the rollouts table does not record where the object was then; they are taken to the object frame
  with the object's settled scene pose. The error is the object's motion between placement and the end of closing:
  at most ``rollouts.lift.max_target_shift`` / ``max_target_turn`` during the approach (more is labelled a
  collision), plus the push of the first pad before the second one touches (about the grasp's offset from the
  object's centre line, a few mm). A push along the closing axis moves both patches along their normals, which
  leaves the normal forces' moments unchanged; only the friction edges see it. The robustness stage, which runs its
  own rollouts, records the object pose at the end of closing and converts exactly.
* ``raycast``: otherwise (not simulated: rejected by the pre-filter; or simulated but a jaw missed), the contacts
  of closing both pads onto the mesh along the TCP x axis (:func:`graspgen.geometry.contacts.closing_contacts`) at the
  grasp's ``pose_object``, when both pads touch.
* ``none``: neither gives contacts on both pads: epsilon 0, no friction label.

Centre of mass from the object record; ``torque_scale`` = the largest distance of a mesh vertex from it (so epsilon
is unit-free, ARCHITECTURE.md, Conventions). Friction: ``epsilon.friction``, or the object's friction in the scene when
null (the coefficient the simulation used for gripper-object contacts). The GraspNet-style label is the smallest
coefficient of ``closure_frictions`` at which the grasp is in force closure (epsilon > 0).

Output per scene: one Parquet table, one row per grasp of the grasps table, joined on ``(scene_id, grasp_id)``:

====================  ========  ================================================================================
column                type      meaning
====================  ========  ================================================================================
scene_id, grasp_id    string,   the grasp
                      int32
epsilon               float64   Ferrari-Canny epsilon (unit-free, L1: unit total normal force); 0 when not in
                                force closure
contact_source        string    ``rollout``, ``raycast`` or ``none`` (see above)
num_contacts          int32     contact points the epsilon was computed from (0 for ``none``)
friction              float64   Coulomb coefficient of the friction cones
min_closure_friction  float64   smallest of ``closure_frictions`` with epsilon > 0; NaN when none is
torque_scale          float64   the object's largest vertex distance from its centre of mass, m
pfc_contact           float64   fraction of the ``num_contact_samples`` perturbed contact sets with epsilon >
                                ``epsilon_delta``, in [0, 1]; 0 for ``none``
epsilon_robust        float64   mean epsilon over the perturbed contact sets (Dex-Net's robust epsilon); 0 for
                                ``none``
====================  ========  ================================================================================

Contact noise (``pfc_contact``, ``epsilon_robust``; :func:`perturb_contacts`). Dex-Net style (Mahler et al. 2017):
the grasp's contact set is perturbed ``num_contact_samples`` times and the epsilon recomputed, at no extra
simulation. Each perturbed set moves each pad's contacts (all contacts with one ``finger`` label) together:

* a shift ``t ~ N(0, contact_position_sigma^2 I)`` (m) with its component along the pad's mean normal removed, so
  the patch slides in its tangent plane (along the surface to first order: exact on a flat face; a shift past an
  edge is not projected back onto the mesh, so falling off an edge is not modelled);
* a tilt of its normals by the rotation vector ``w ~ N(0, contact_normal_sigma^2 I)`` (rad) with its component
  along the pad's mean normal removed (a spin about the normal leaves the normal unchanged);
* one friction coefficient per set, ``N(friction, friction_sigma^2)`` truncated to > 0 (inverse-CDF sampling).

These are contact-level errors only: unlike the ``robustness`` stage's ``pfc`` (perturbed rollouts, the contacts
found anew by the physics), a perturbed set never loses or gains contacts. Randomness: the stage draws all noise
for a scene up front from the task's generator, ``(grasps, num_contact_samples, 13)`` values in grasp order (for
every grasp, with contacts or not; :func:`contact_noise_draws`), so a grasp's noise depends only on the task key
and its row; with all sigmas 0 the perturbed sets equal the nominal one and ``epsilon_robust == epsilon``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Literal

import numpy as np
import pyarrow as pa
import trimesh
from scipy.special import ndtr, ndtri

from graspgen.errors import InputError
from graspgen.geometry.contacts import ClosingContacts, closing_contacts
from graspgen.io.arrow import column_array, list_rows
from graspgen.io.objects import ObjectRecord
from graspgen.io.scenes import SceneRecord
from graspgen.quality.wrench import (
    _check_center_of_mass,
    _epsilon,
    _wrenches,
    ferrari_canny,
    force_closure,
)
from graspgen.sim.grippers import GripperSpec, load_gripper
from graspgen.validation import check, check_choice, check_int, check_number

__all__ = [
    "CONTACT_MODELS",
    "CONTACT_SOURCES",
    "check_joined",
    "contact_noise_draws",
    "contact_robustness",
    "EpsilonParams",
    "MetricsParams",
    "ObjectGeometry",
    "SCHEMA",
    "contact_set",
    "ferrari_canny",
    "force_closure",
    "grasp_epsilon",
    "min_closure_friction",
    "object_geometry",
    "pad_contacts",
    "perturb_contacts",
    "scene_metrics",
    "world_to_object",
]

CONTACT_MODELS = ("pad", "points")
CONTACT_SOURCES = ("rollout", "raycast", "none")
"""Where a grasp's contacts came from (column ``contact_source``)."""


def pad_contacts(
    points: np.ndarray, normals: np.ndarray, finger: np.ndarray, *, friction: float, torsional_friction: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One soft-finger contact per pad from its contact patch.

    Parameters
    ----------
    points : (k, 3) float, m
    normals : (k, 3) float, unit, pointing into the object
    finger : (k,) int, pad label of each contact
    friction : float, Coulomb coefficient
    torsional_friction : float, m, the floor of each pad's torsional coefficient

    Returns
    -------
    centroids : (p, 3) float, normals : (p, 3) float (unit), gammas : (p,) float, m; ``p`` = pads that touch, in
    ascending pad label order.
    """
    centroids, mean_normals, gammas = [], [], []
    # sorted(set(...)) rather than np.unique: same order, a few microseconds less on these tiny arrays (this runs
    # once per epsilon evaluation, ARCHITECTURE.md, Performance bars, asks for >= 2,000 per second).
    for f in sorted(set(np.asarray(finger).tolist())):
        sel = finger == f
        pts = points[sel]
        k = len(pts)
        c = pts.sum(axis=0) / k  # = mean(axis=0) bit for bit (add.reduce, then divide), without its overhead
        n = normals[sel].sum(axis=0) / k
        norm = math.sqrt(float(n @ n))
        if norm < 1e-9:  # opposite normals on one pad: no meaningful patch normal
            continue
        n = n / norm
        offsets = pts - c
        tangential = offsets - np.outer(offsets @ n, n)
        radius = math.sqrt(float(np.einsum("ij,ij->i", tangential, tangential).max()))
        centroids.append(c)
        mean_normals.append(n)
        gammas.append(max(torsional_friction, 2.0 / 3.0 * friction * radius))
    return np.array(centroids).reshape(-1, 3), np.array(mean_normals).reshape(-1, 3), np.array(gammas)


def _pad_wrenches(
    centroids: np.ndarray, normals: np.ndarray, gammas: np.ndarray, com: np.ndarray, mu: float, scale: float, m: int
) -> np.ndarray:
    """The grasp matrix of the pad model, (6, p*m + 2 * (pads with gamma > 0)).

    The same columns in the same order as ``np.hstack([grasp_matrix(c_i, n_i, ..., torsional_friction=g_i)])``
    over the pads (each pad's ``m`` cone edges, then its two torsional columns), built in one vectorised call:
    the per-pad calls and their argument checks cost more than the wrenches themselves.
    """
    edges = _wrenches(centroids, normals, com, mu, scale, m, 0.0)  # (6, p*m), pad-major
    p = len(centroids)
    blocks = []
    for i in range(p):
        blocks.append(edges[:, i * m : (i + 1) * m])
        if gammas[i] > 0.0:
            tors = np.zeros((6, 2))
            tors[3:, 0] = normals[i] * (gammas[i] / scale)
            tors[3:, 1] = -tors[3:, 0]
            blocks.append(tors)
    return np.concatenate(blocks, axis=1)


def grasp_epsilon(
    points: np.ndarray,
    normals: np.ndarray,
    finger: np.ndarray,
    center_of_mass: np.ndarray,
    *,
    friction: float,
    torque_scale: float,
    torsional_friction: float = 0.0,
    num_cone_edges: int = 8,
    contact_model: str = "pad",
) -> float:
    """Ferrari-Canny epsilon of a grasp's contacts under ``contact_model`` (see the module docstring).

    Parameters
    ----------
    points : (k, 3) float, m, contact points
    normals : (k, 3) float, unit, pointing into the object
    finger : (k,) int, which pad made each contact
    center_of_mass : (3,) float, m, same frame as ``points``
    friction, torque_scale, torsional_friction, num_cone_edges
        As in :func:`graspgen.quality.wrench.ferrari_canny`.

    Returns
    -------
    float, unit-free: 0 when the contacts are not in force closure (fewer than two pads touching included).
    """
    check_choice("contact_model", contact_model, CONTACT_MODELS)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    finger = np.asarray(finger).reshape(-1)
    if len(points) == 0:
        return 0.0
    if contact_model == "points":
        return ferrari_canny(
            points,
            normals,
            center_of_mass,
            friction=friction,
            torque_scale=torque_scale,
            num_cone_edges=num_cone_edges,
            torsional_friction=torsional_friction,
        )
    if len(normals) != len(points) or len(finger) != len(points):
        raise ValueError(f"normals, finger: expected {len(points)} rows (one per contact, as in points)")
    if not (np.isfinite(points).all() and np.isfinite(normals).all()):
        raise ValueError("points, normals: contain NaN or infinite values")
    com = _check_center_of_mass(center_of_mass)
    mu = check_number("friction", friction, low=0.0, low_open=True)
    scale = check_number("torque_scale", torque_scale, low=0.0, low_open=True)
    m = check_int("num_cone_edges", num_cone_edges, low=3)
    gamma = check_number("torsional_friction", torsional_friction, low=0.0)
    centroids, mean_normals, gammas = pad_contacts(points, normals, finger, friction=mu, torsional_friction=gamma)
    if len(centroids) < 2:
        return 0.0
    return _epsilon(_pad_wrenches(centroids, mean_normals, gammas, com, mu, scale, m))


def min_closure_friction(
    points: np.ndarray,
    normals: np.ndarray,
    finger: np.ndarray,
    center_of_mass: np.ndarray,
    frictions: Sequence[float],
    *,
    torque_scale: float,
    torsional_friction: float = 0.0,
    num_cone_edges: int = 8,
    contact_model: str = "pad",
) -> float:
    """GraspNet-style label: the smallest friction in ``frictions`` at which the grasp has epsilon > 0.

    Returns NaN when it is not in force closure at any of them.
    """
    for mu in sorted(frictions):
        eps = grasp_epsilon(
            points,
            normals,
            finger,
            center_of_mass,
            friction=mu,
            torque_scale=torque_scale,
            torsional_friction=torsional_friction,
            num_cone_edges=num_cone_edges,
            contact_model=contact_model,
        )
        if eps > 0.0:
            return float(mu)
    return float("nan")


# ---------------------------------------------------------------------------------------------------------------
# The metrics stage
# ---------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class EpsilonParams:
    """How a grasp's contacts become an epsilon (config ``metrics.epsilon``; the robustness stage uses the same
    settings for its perturbed copies, so both labels share one contact model)."""

    friction: float | None = None
    """Coulomb coefficient of the friction cones; null uses the target object's friction in the scene (the
    coefficient the simulation used for gripper-object contacts, :mod:`graspgen.sim.grippers`)."""
    torsional_friction: float = 0.005
    """Soft-finger torsional coefficient, m (torsional moment per unit normal force): the floor of each pad's
    coefficient (``pad`` model) or every contact's (``points``). 0.005 m is the pads' torsional friction in the
    simulation."""
    num_cone_edges: int = 8
    """Edges of the polygonal friction cones."""
    contact_model: Literal["pad", "points"] = "pad"
    """``pad``: one soft-finger contact per pad patch (fast); ``points``: every contact point (slow)."""
    rays_per_side: int = 3
    """Ray-cast contacts: rays per pad edge (each pad casts ``rays_per_side ** 2`` rays along the TCP x axis)."""
    ray_tolerance: float = 5e-4
    """Ray-cast contacts: rays hitting within this distance (m) of a pad's stop are contacts."""

    def __post_init__(self) -> None:
        if self.friction is not None:
            check("friction", self.friction > 0 and math.isfinite(self.friction), "be > 0 (or null)", self.friction)
        check("torsional_friction", 0 <= self.torsional_friction < math.inf, "be >= 0", self.torsional_friction)
        check("num_cone_edges", self.num_cone_edges >= 3, "be >= 3", self.num_cone_edges)
        check_choice("contact_model", self.contact_model, CONTACT_MODELS)
        check("rays_per_side", self.rays_per_side >= 1, "be >= 1", self.rays_per_side)
        check("ray_tolerance", 0 <= self.ray_tolerance < math.inf, "be >= 0", self.ray_tolerance)

    def epsilon(self, points, normals, finger, geometry: ObjectGeometry, friction: float) -> float:
        """Epsilon of contacts in the object's mesh frame (shapes as in :func:`grasp_epsilon`) at ``friction``."""
        return grasp_epsilon(points, normals, finger, geometry.center_of_mass, friction=friction,
                             torque_scale=geometry.torque_scale, torsional_friction=self.torsional_friction,
                             num_cone_edges=self.num_cone_edges, contact_model=self.contact_model)


@dataclasses.dataclass(frozen=True)
class MetricsParams:
    """Settings of the ``metrics`` stage (config section ``metrics``)."""

    epsilon: EpsilonParams = dataclasses.field(default_factory=EpsilonParams)
    """The contact model, friction and ray casting of the epsilon (shared with the robustness stage)."""
    closure_frictions: tuple[float, ...] = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
    """Friction coefficients tried for the GraspNet-style label ``min_closure_friction``."""
    num_contact_samples: int = 10
    """Perturbed contact sets per grasp for ``pfc_contact`` and ``epsilon_robust`` (each costs one epsilon)."""
    contact_position_sigma: float = 0.005
    """Standard deviation (m) of each pad's contact shift (per axis, then projected onto the pad's tangent plane).
    5 mm: the translation sigma of Dex-Net's grasp and object pose noise, and the robustness stage's
    ``translation_sigma``."""
    contact_normal_sigma: float = math.radians(5.0)
    """Standard deviation (rad) of each component of each pad's normal tilt (a rotation vector, its component
    along the normal removed). 5 degrees: a physical choice (the scale of a meshed surface's normal error on a
    curved object, and the robustness stage's ``rotation_sigma``), not a Dex-Net value."""
    friction_sigma: float = 0.1
    """Standard deviation of the friction coefficient (truncated to > 0): Dex-Net's ``sigma_mu`` (0.1 about its
    nominal 0.5)."""
    epsilon_delta: float = 0.0
    """``pfc_contact`` counts perturbed sets with epsilon > this (0: the probability of force closure itself)."""

    def __post_init__(self) -> None:
        check("closure_frictions", len(self.closure_frictions) > 0, "list at least one coefficient",
              self.closure_frictions)
        check("closure_frictions", all(0 < f < math.inf for f in self.closure_frictions), "all be > 0",
              self.closure_frictions)
        check("num_contact_samples", self.num_contact_samples >= 1, "be >= 1", self.num_contact_samples)
        for name in ("contact_position_sigma", "contact_normal_sigma", "friction_sigma", "epsilon_delta"):
            value = getattr(self, name)
            check(name, 0 <= value < math.inf, "be >= 0", value)


@dataclasses.dataclass(frozen=True, eq=False)
class ObjectGeometry:
    """What the epsilon needs of an object: its mesh and mass centre in the mesh frame, and the torque scale."""

    mesh: trimesh.Trimesh
    """The visual mesh, mesh frame, m (ray casts)."""
    center_of_mass: np.ndarray
    """(3,) float, m, mesh frame."""
    torque_scale: float
    """The largest distance (m) of a mesh vertex from the centre of mass."""


def object_geometry(record: ObjectRecord) -> ObjectGeometry:
    """:class:`ObjectGeometry` of an object record (:func:`graspgen.io.objects.read_object`)."""
    vertices = np.asarray(record.vertices, dtype=np.float64)
    com = np.asarray(record.center_of_mass, dtype=np.float64).reshape(3)
    d = vertices - com
    scale = math.sqrt(float(np.einsum("ij,ij->i", d, d).max()))
    if not scale > 0:
        raise InputError(f"{record.name}: torque scale is 0 (all vertices at the centre of mass)")
    return ObjectGeometry(trimesh.Trimesh(vertices, np.asarray(record.faces), process=False), com, scale)


def world_to_object(points: np.ndarray, normals: np.ndarray, T_world_object: np.ndarray):
    """Contacts ``points (k, 3)`` m and ``normals (k, 3)`` from the world to the frame of the object at pose
    ``T_world_object (4, 4)`` (mesh frame to world). Returns ``(points, normals)`` in the mesh frame."""
    T = np.asarray(T_world_object, dtype=np.float64)
    R = T[:3, :3]
    return (np.asarray(points, dtype=np.float64) - T[:3, 3]) @ R, np.asarray(normals, dtype=np.float64) @ R


def contact_set(
    rollout: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
    T_world_object: np.ndarray,
    raycast: ClosingContacts | None,
) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    """The contacts a grasp's epsilon is computed from, by the rule of the module docstring.

    Parameters
    ----------
    rollout : (points (k, 3) m, normals (k, 3), fingers (k,)) in the world frame, or None when not simulated
    T_world_object : (4, 4) float
        The object's pose the rollout contacts are converted with (mesh frame to world).
    raycast : ClosingContacts or None
        Ray-cast contacts in the mesh frame (used when the rollout's are missing or touch one pad only).

    Returns
    -------
    (source, points (k, 3), normals (k, 3), fingers (k,) int8), mesh frame; ``k = 0`` for source ``none``.
    """
    if rollout is not None:
        points, normals, fingers = rollout
        fingers = np.asarray(fingers, dtype=np.int8).reshape(-1)
        if np.isin((0, 1), fingers).all():
            p, n = world_to_object(np.reshape(points, (-1, 3)), np.reshape(normals, (-1, 3)), T_world_object)
            return "rollout", p, n, fingers
    if raycast is not None and raycast.both_fingers:
        return "raycast", raycast.points, raycast.normals, np.asarray(raycast.finger, dtype=np.int8)
    return "none", np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=np.int8)


SCHEMA = pa.schema(
    [
        ("scene_id", pa.string()),
        ("grasp_id", pa.int32()),
        ("epsilon", pa.float64()),
        ("contact_source", pa.string()),
        ("num_contacts", pa.int32()),
        ("friction", pa.float64()),
        ("min_closure_friction", pa.float64()),
        ("torque_scale", pa.float64()),
        ("pfc_contact", pa.float64()),
        ("epsilon_robust", pa.float64()),
    ]
)
"""The metrics table's schema (see the module docstring)."""


CONTACT_NOISE_DRAWS = 13
"""Values drawn per perturbed contact set: per pad (finger 0, then 1) a shift (3) and a tilt (3) standard normal,
then one uniform for the friction."""


def contact_noise_draws(rng: np.random.Generator, n: int, k: int) -> np.ndarray:
    """The contact noise of ``n`` grasps, ``k`` sets each: ``(n, k, 13)`` float, drawn in one call order (standard
    normals ``(n, k, 12)``, then uniforms ``(n, k)``) so a grasp's values depend only on the generator and its row."""
    z = rng.standard_normal((n, k, 12))
    u = rng.random((n, k))
    return np.concatenate([z, u[..., None]], axis=2)


def _rotation(w: np.ndarray) -> np.ndarray:
    """The rotation matrix of the rotation vector ``w`` (rad), Rodrigues' formula."""
    theta = math.sqrt(float(w @ w))
    if theta == 0.0:
        return np.eye(3)
    x, y, z = w / theta
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(theta) * K + (1.0 - math.cos(theta)) * (K @ K)


def perturb_contacts(
    points: np.ndarray, normals: np.ndarray, finger: np.ndarray, friction: float, draws: np.ndarray, *,
    position_sigma: float, normal_sigma: float, friction_sigma: float,
) -> tuple[np.ndarray, np.ndarray, float]:
    """One perturbed copy of a contact set (module docstring, Contact noise).

    Parameters
    ----------
    points : (k, 3) float, m; normals : (k, 3) float, unit, into the object; finger : (k,) int, 0 or 1
    friction : float, the nominal Coulomb coefficient
    draws : (13,) float, one row of :func:`contact_noise_draws`
    position_sigma : m; normal_sigma : rad; friction_sigma : unit-free

    Returns
    -------
    (points (k, 3), normals (k, 3), friction); a sigma of 0 leaves its part exactly as it was.
    """
    points = np.array(points, dtype=np.float64).reshape(-1, 3)
    normals = np.array(normals, dtype=np.float64).reshape(-1, 3)
    finger = np.asarray(finger).reshape(-1)
    if position_sigma > 0.0 or normal_sigma > 0.0:
        for f in (0, 1):
            sel = finger == f
            if not sel.any():
                continue
            axis = normals[sel].sum(axis=0)
            norm = math.sqrt(float(axis @ axis))
            axis = axis / norm if norm > 1e-9 else np.zeros(3)
            z = draws[6 * f : 6 * f + 6]
            if position_sigma > 0.0:
                t = position_sigma * z[:3]
                points[sel] += t - (t @ axis) * axis
            if normal_sigma > 0.0:
                w = normal_sigma * z[3:]
                normals[sel] = normals[sel] @ _rotation(w - (w @ axis) * axis).T
    mu = float(friction)
    if friction_sigma > 0.0:
        low = float(ndtr(-mu / friction_sigma))  # P(N(mu, sigma^2) <= 0): the mass cut off
        mu = max(mu + friction_sigma * float(ndtri(low + float(draws[12]) * (1.0 - low))), 1e-9)
    return points, normals, mu


def contact_robustness(
    points: np.ndarray, normals: np.ndarray, finger: np.ndarray, geometry: ObjectGeometry, friction: float,
    draws: np.ndarray, params: MetricsParams,
) -> tuple[float, float]:
    """``(pfc_contact, epsilon_robust)`` of a contact set (mesh frame) over the perturbed sets ``draws``
    (``(K, 13)``, rows of :func:`contact_noise_draws`): the fraction with epsilon > ``params.epsilon_delta`` and
    the mean epsilon."""
    eps = np.empty(len(draws))
    for j, row in enumerate(draws):
        p, n, mu = perturb_contacts(points, normals, finger, friction, row,
                                    position_sigma=params.contact_position_sigma,
                                    normal_sigma=params.contact_normal_sigma, friction_sigma=params.friction_sigma)
        eps[j] = params.epsilon.epsilon(p, n, finger, geometry, mu)
    # the mean as an offset from the first value: exactly that value when all are equal (zero noise)
    return float(np.mean(eps > params.epsilon_delta)), float(eps[0] + (eps - eps[0]).mean())


def check_joined(grasps: pa.Table, other: pa.Table, stage: str) -> None:
    """Raise InputError unless ``other`` has one row per grasp of ``grasps``, in the same order."""
    if other.column("grasp_id").to_pylist() != grasps.column("grasp_id").to_pylist():
        sid = grasps.column("scene_id")[0].as_py() if len(grasps) else "?"
        raise InputError(f"{stage} table of {sid}: its grasp ids do not match the grasps table's")


def raycast_contacts(
    grasps: pa.Table, rows: Sequence[int], geometries: Mapping[str, ObjectGeometry], gripper: GripperSpec,
    params: EpsilonParams,
) -> dict[int, ClosingContacts]:
    """Ray-cast closing contacts (mesh frame) of the grasps ``rows``, batched per object: ``{row: contacts}``."""
    if not rows:
        return {}
    names = grasps.column("object_name").to_pylist()
    poses = column_array(grasps, "pose_object", (4, 4))
    out: dict[int, ClosingContacts] = {}
    for name in sorted({names[i] for i in rows}):
        idx = [i for i in rows if names[i] == name]
        found = closing_contacts(geometries[name].mesh, poses[idx], gripper, rays_per_side=params.rays_per_side,
                                 tolerance=params.ray_tolerance)
        out.update(zip(idx, found))
    return out


def scene_metrics(
    grasps: pa.Table, rollouts: pa.Table, scene: SceneRecord, records: Mapping[str, ObjectRecord],
    params: MetricsParams, rng: np.random.Generator,
) -> pa.Table:
    """The metrics table of one scene (module docstring): one row per grasp of ``grasps``.

    Parameters
    ----------
    grasps, rollouts : pyarrow.Table
        The scene's grasps and rollouts tables (one rollouts row per grasp, same order).
    scene : SceneRecord
        Gives the objects' settled poses and frictions.
    records : mapping
        Object records by name, for every object the grasps target.
    params : MetricsParams
    rng : numpy.random.Generator
        The contact noise's only source (:func:`contact_noise_draws`, drawn before anything else is computed).
    """
    check_joined(grasps, rollouts, "rollouts")
    n = len(grasps)
    draws = contact_noise_draws(rng, n, params.num_contact_samples)
    if n == 0:
        return SCHEMA.empty_table()
    ep = params.epsilon
    gripper = load_gripper(grasps.column("gripper")[0].as_py())
    names = grasps.column("object_name").to_pylist()
    index = grasps.column("object_index").to_numpy()
    geometries = {name: object_geometry(records[name]) for name in sorted(set(names))}
    simulated = rollouts.column("simulated").to_numpy(zero_copy_only=False)
    points = list_rows(rollouts, "contact_points", 3, np.float64)
    normals = list_rows(rollouts, "contact_normals", 3, np.float64)
    fingers = list_rows(rollouts, "contact_fingers", 0, np.int8)
    has_rollout = [bool(simulated[i]) and bool(np.isin((0, 1), fingers[i]).all()) for i in range(n)]
    closed_poses = (column_array(rollouts, "target_pose_closed", (4, 4))
                    if "target_pose_closed" in rollouts.column_names else None)
    rays = raycast_contacts(grasps, [i for i in range(n) if not has_rollout[i]], geometries, gripper, ep)
    cols: dict[str, list] = {name: [] for name in SCHEMA.names[2:]}
    for i in range(n):
        geometry = geometries[names[i]]
        mu = float(scene.friction[index[i]]) if ep.friction is None else ep.friction
        rollout = (points[i], normals[i], fingers[i]) if simulated[i] else None
        # The contacts were taken when closing ended: map them with the object's pose then, not the settled one
        # (the jaws may have pushed it by millimetres and degrees).
        at_closing = closed_poses[i] if closed_poses is not None and np.isfinite(closed_poses[i]).all() else None
        source, p, nrm, f = contact_set(rollout, scene.poses[index[i]] if at_closing is None else at_closing,
                                        rays.get(i))
        if source == "none":
            eps, label, pfc, robust = 0.0, math.nan, 0.0, 0.0
        else:
            pfc, robust = contact_robustness(p, nrm, f, geometry, mu, draws[i], params)
            eps = ep.epsilon(p, nrm, f, geometry, mu)
            label = min_closure_friction(p, nrm, f, geometry.center_of_mass, params.closure_frictions,
                                         torque_scale=geometry.torque_scale, torsional_friction=ep.torsional_friction,
                                         num_cone_edges=ep.num_cone_edges, contact_model=ep.contact_model)
        cols["epsilon"].append(eps)
        cols["contact_source"].append(source)
        cols["num_contacts"].append(len(p))
        cols["friction"].append(mu)
        cols["min_closure_friction"].append(label)
        cols["torque_scale"].append(geometry.torque_scale)
        cols["pfc_contact"].append(pfc)
        cols["epsilon_robust"].append(robust)
    arrays = {"scene_id": grasps.column("scene_id"), "grasp_id": grasps.column("grasp_id")}
    arrays.update({name: pa.array(values, SCHEMA.field(name).type) for name, values in cols.items()})
    return pa.table(arrays, schema=SCHEMA)


