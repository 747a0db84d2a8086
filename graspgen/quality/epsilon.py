"""Analytic grasp quality: Ferrari-Canny epsilon of a parallel-jaw grasp's contacts, and the friction label.

Turns a grasp's contacts into the metric's contact model (wrench maths: :mod:`graspgen.quality.wrench`,
:mod:`graspgen.quality.closure`). ``contact_model`` ``"pad"`` (default): each pad's patch is one soft-finger contact
at its centroid with the mean inward normal and torsional friction ``max(torsional_friction, 2/3 friction r)``
(``r`` the patch radius: a uniformly pressed disc), so two pads give a full-rank wrench set; ``"points"``: every
contact point is its own contact (slower). :class:`ObjectGeometry` gives the centre of mass and the torque scale
(largest vertex distance from it, so epsilon is unit-free). :func:`min_closure_friction` is the GraspNet-style label.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Literal

import numpy as np
import trimesh

from graspgen.errors import SettingsError
from graspgen.quality.closure import _epsilon, ferrari_canny
from graspgen.quality.wrench import _check_center_of_mass, _wrenches
from graspgen.validation import check_choice, check_int, check_number, check_positive_int

__all__ = [
    "CONTACT_MODELS",
    "EpsilonParams",
    "ObjectGeometry",
    "grasp_epsilon",
    "min_closure_friction",
    "pad_contacts",
]

CONTACT_MODELS = ("pad", "points")
"""The contact models of the epsilon (module docstring)."""


def pad_contacts(
    points: np.ndarray, normals: np.ndarray, finger: np.ndarray, *, friction: float, torsional_friction: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One soft-finger contact per touching pad, in ascending pad order, from contact ``points`` (k, 3) m, inward unit
    ``normals`` (k, 3) and pad labels ``finger`` (k,): centroids (p, 3), unit normals (p, 3), torsional coefficients
    (p,) m, floored at ``torsional_friction``."""
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
    """The pad model's grasp matrix (6, p m + 2 (pads with gamma > 0)): the columns of per-pad
    :func:`~graspgen.quality.wrench.grasp_matrix` calls, stacked, built in one vectorised call."""
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
    """Ferrari-Canny epsilon (unit-free) of contacts ``points`` (k, 3) m with inward unit ``normals`` (k, 3) and pads
    ``finger`` (k,) under ``contact_model``; ``center_of_mass`` (3,) m in the same frame; the other parameters as in
    :func:`graspgen.quality.closure.ferrari_canny`. 0 when not in force closure (fewer than two pads touching
    included)."""
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
        raise SettingsError(f"normals, finger: expected {len(points)} rows (one per contact, as in points)")
    if not (np.isfinite(points).all() and np.isfinite(normals).all()):
        raise SettingsError("points, normals: contain NaN or infinite values")
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
    """GraspNet-style label: the smallest of ``frictions`` at which epsilon > 0; NaN if none."""
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


@dataclasses.dataclass(frozen=True, eq=False)
class ObjectGeometry:
    """What the epsilon needs of an object: its mesh and mass centre in the mesh frame, and the torque scale."""

    mesh: trimesh.Trimesh
    """The visual mesh, mesh frame, m (ray casts)."""
    center_of_mass: np.ndarray
    """(3,) float, m, mesh frame."""
    torque_scale: float
    """The largest distance (m) of a mesh vertex from the centre of mass."""


@dataclasses.dataclass(frozen=True)
class EpsilonParams:
    """How a grasp's contacts become an epsilon (config ``metrics.epsilon``; the robustness stage uses the same
    settings for its perturbed copies, so both labels share one contact model)."""

    friction: float | None = None
    """Coulomb coefficient of the friction cones; null uses the target object's friction in the scene (the
    coefficient the simulation used for gripper-object contacts, :mod:`graspgen.sim.grippers`)."""
    torsional_friction: float = 0.005
    """Soft-finger torsional coefficient, m (moment per unit normal force): the floor of each pad's (``pad``) or every
    contact's (``points``); 0.005 m is the pads' torsional friction in the simulation."""
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
            check_number("friction", self.friction, low=0.0, low_open=True)
        check_number("torsional_friction", self.torsional_friction, low=0.0)
        check_int("num_cone_edges", self.num_cone_edges, low=3)
        check_choice("contact_model", self.contact_model, CONTACT_MODELS)
        check_positive_int("rays_per_side", self.rays_per_side)
        check_number("ray_tolerance", self.ray_tolerance, low=0.0)

    def epsilon(self, points, normals, finger, geometry: ObjectGeometry, friction: float) -> float:
        """Epsilon of contacts in the object's mesh frame (shapes as in :func:`grasp_epsilon`) at ``friction``."""
        return grasp_epsilon(points, normals, finger, geometry.center_of_mass, friction=friction,
                             torque_scale=geometry.torque_scale, torsional_friction=self.torsional_friction,
                             num_cone_edges=self.num_cone_edges, contact_model=self.contact_model)
