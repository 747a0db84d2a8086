"""Step 6 of mesh preparation, the geometry: the poses in which an object rests on a table.

:func:`pose_candidates` takes the quasi-static resting faces of the convex hull and groups them into pose classes;
:func:`merge_settled` replaces each candidate by the face it settled onto in a drop and merges equal ones;
:func:`resting_poses` turns resting-face normals into poses. The drop itself is MuJoCo's, in
:mod:`graspgen.sim.stable_poses`, whose :func:`~graspgen.sim.stable_poses.stable_poses` chains the three.
Lengths in m, angles in rad, times in s, speeds in m/s and rad/s; poses are 4x4 mesh-frame-to-world transforms
resting on z = 0. Randomness only ever comes from the ``numpy.random.Generator`` passed in.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import trimesh
import trimesh.poses

from graspgen.errors import InputError, SettingsError
from graspgen.geometry.mass import MassProperties
from graspgen.geometry.mesh_io import _check_mesh, _label
from graspgen.validation import check_bool, check_instance, check_number, check_positive_int, check_rng

__all__ = ["StablePoseParams", "check_parts", "merge_settled", "pose_candidates", "resting_poses", "resting_transform"]

_log = logging.getLogger(__name__)


# Candidate normals from different centre-of-mass samples closer than this are the same face; trimesh itself
# rounds normals to 3 decimals for the same purpose.
_SAME_FACE_ANGLE = 1e-3  # rad
# Candidate poses whose centre of mass rests at heights within this are one pose class (see
# _select_pose_classes): a cylinder's side facets, a box's opposite faces.
_SAME_HEIGHT = 5e-4  # m


def check_parts(parts: object, name: str) -> None:
    """Raise :class:`~graspgen.errors.SettingsError` unless ``parts`` is a non-empty sequence of convex parts
    ``(vertices (v, 3), faces (f, 3))``; ``name`` is used in the message."""
    if len(parts) == 0:
        raise SettingsError(f"{name}: needs at least one convex part")
    for i, part in enumerate(parts):
        vertices, faces = part
        if np.ndim(vertices) != 2 or np.shape(vertices)[1] != 3 or np.ndim(faces) != 2 or np.shape(faces)[1] != 3:
            raise SettingsError(f"{name}[{i}]: must be (vertices (v, 3), faces (f, 3))")


@dataclass(frozen=True)
class StablePoseParams:
    """Settings of the stable-pose search and of its MuJoCo settle check."""

    min_probability: float = 0.02
    """Pose classes less probable than this (quasi-static probability, in [0, 1)) are ignored; a class is the candidates
    with the same centre-of-mass height, so a finely faceted cylinder keeps its side pose."""

    max_poses: int = 8
    """At most this many poses are returned, the most probable first."""

    settle_check: bool = True
    """Drop every candidate 1 mm onto a plane in MuJoCo and keep the pose it settles into."""

    settle_time: float = 1.0
    """Simulated time of one settle check, in s."""

    max_tilt: float = 0.1
    """Angle in rad: a settled pose within this of a candidate (or of another pose) is the same pose."""

    timestep: float = 0.002
    """MuJoCo timestep of the settle check, in s."""

    friction: float = 0.8
    """Sliding friction coefficient (dimensionless) between object and plane in the settle check."""

    com_sigma: float = 0.0
    """Standard deviation in m of a Gaussian perturbation of the centre of mass for the quasi-static analysis
    (models uncertain density). 0 uses the exact centre of mass and draws nothing from ``rng``."""

    com_samples: int = 1
    """Number of perturbed centres of mass averaged when ``com_sigma > 0``."""

    def __post_init__(self) -> None:
        check_number("min_probability", self.min_probability, low=0.0, high=1.0, high_open=True)
        check_positive_int("max_poses", self.max_poses)
        check_bool("settle_check", self.settle_check)
        check_number("settle_time", self.settle_time, low=0.0, low_open=True)
        check_number("max_tilt", self.max_tilt, low=0.0, high=math.pi, low_open=True)
        check_number("timestep", self.timestep, low=0.0, high=0.1, low_open=True)
        if self.settle_time < self.timestep:
            raise SettingsError(f"settle_time: must be at least timestep ({self.timestep}), got {self.settle_time}")
        check_number("friction", self.friction, low=0.0, low_open=True)
        check_number("com_sigma", self.com_sigma, low=0.0)
        check_positive_int("com_samples", self.com_samples)


def resting_transform(hull_vertices: np.ndarray, center_of_mass: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """(4, 4) float64 mesh-to-world transform resting the object on z = 0 on the hull face with outward ``normal`` (3,):
    rotation by trimesh's convention (z = -normal), centre of mass ``center_of_mass`` (3,) above the origin, lowest of
    ``hull_vertices`` (v, 3) on z = 0; all mesh frame, m."""
    z = -np.asarray(normal, dtype=np.float64)
    z = z / np.linalg.norm(z)
    x = np.array([-z[1], z[0], 0.0])
    if np.linalg.norm(x) < 1e-9:
        x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    y = y / np.linalg.norm(y)
    rotation = np.array([x, y, z])
    transform = np.eye(4)
    transform[:3, :3] = rotation
    com = rotation @ np.asarray(center_of_mass, dtype=np.float64)
    lowest = float((np.asarray(hull_vertices, dtype=np.float64) @ rotation[2]).min())
    transform[:3, 3] = (-com[0], -com[1], -lowest)
    return transform


def pose_candidates(
    mesh: trimesh.Trimesh, mass: MassProperties, params: StablePoseParams, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """The candidate resting faces of the object before any settle check, most probable first.

    Trimesh's quasi-static toppling analysis of the convex hull; with ``params.com_sigma > 0`` the centre of mass is
    perturbed ``com_samples`` times from ``rng`` (its only use) and the probabilities averaged. Candidates are grouped
    into classes of equal centre-of-mass height, classes below ``min_probability`` dropped (the most probable kept if
    all are) and at most ``max_poses`` kept round-robin over the classes.

    Returns
    -------
    normals : (k, 3) float64
        Outward normals (mesh frame) of the resting hull faces, k >= 1.
    probabilities : (k,) float64
        Their probabilities (not renormalised).

    Raises
    ------
    InputError
        The centre of mass is not inside the convex hull.
    SettingsError
        ``mesh``, ``params`` or ``rng`` of the wrong kind.
    """
    _check_mesh(mesh, "mesh")
    check_rng("rng", rng)
    check_instance("params", params, StablePoseParams)
    hull = mesh.convex_hull
    com = np.asarray(mass.center_of_mass, dtype=np.float64)
    normals, probs = _candidate_normals(mesh, hull, com, params, rng)
    return _select_pose_classes(hull, com, normals, probs, params)


def resting_poses(
    hull: trimesh.Trimesh, mass: MassProperties, normals: np.ndarray, probs: np.ndarray, params: StablePoseParams
) -> tuple[np.ndarray, np.ndarray]:
    """At most ``params.max_poses`` poses resting on the faces with outward ``normals`` (k, 3), most probable first:
    transforms (n, 4, 4) float64 (:func:`resting_transform`) and probabilities (n,) renormalised to sum to 1."""
    com = np.asarray(mass.center_of_mass, dtype=np.float64)
    order = _descending(normals, probs)[: params.max_poses]
    normals, probs = normals[order], probs[order]
    transforms = np.stack([resting_transform(hull.vertices, com, n) for n in normals])
    return transforms, probs / probs.sum()


def _candidate_normals(
    mesh: trimesh.Trimesh,
    hull: trimesh.Trimesh,
    com: np.ndarray,
    params: StablePoseParams,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Outward resting-face normals ``(k, 3)`` and their probabilities ``(k,)`` averaged over COM samples."""
    samples = _com_samples(hull, com, params, rng, _label(mesh))
    normals: list[np.ndarray] = []
    probs: list[np.ndarray] = []
    for sample in samples:
        transforms, sample_probs = trimesh.poses.compute_stable_poses(
            mesh, center_mass=sample, sigma=0.0, n_samples=1, threshold=0.0, seed=0
        )
        normals.append(-np.asarray(transforms, dtype=np.float64).reshape(-1, 4, 4)[:, 2, :3])
        probs.append(np.asarray(sample_probs, dtype=np.float64) / len(samples))
    normals_all, probs_all = np.concatenate(normals), np.concatenate(probs)
    if len(samples) == 1:
        return normals_all, probs_all  # trimesh has already merged equal faces
    order = _descending(normals_all, probs_all)
    return _merge_close(normals_all[order], probs_all[order], _SAME_FACE_ANGLE)


def _com_samples(
    hull: trimesh.Trimesh, com: np.ndarray, params: StablePoseParams, rng: np.random.Generator, label: str
) -> list[np.ndarray]:
    if not _inside_hull(hull, com):
        # compute_stable_poses rejection-samples until the COM is strictly inside and would never return.
        raise InputError(f"{label}: centre of mass {com} is not inside the convex hull")
    if params.com_sigma == 0.0:
        return [com]
    samples: list[np.ndarray] = []
    for _ in range(100 * params.com_samples):
        candidate = com + rng.normal(0.0, params.com_sigma, size=3)
        if _inside_hull(hull, candidate):
            samples.append(candidate)
            if len(samples) == params.com_samples:
                break
    return samples or [com]


def _inside_hull(hull: trimesh.Trimesh, point: np.ndarray) -> bool:
    # The same strict test compute_stable_poses uses, so a point passing here is accepted there.
    dots = np.einsum("ij,ij->i", point - hull.triangles_center, hull.face_normals)
    return bool(np.all(dots < 0.0))


def _select_pose_classes(
    hull: trimesh.Trimesh, com: np.ndarray, normals: np.ndarray, probs: np.ndarray, params: StablePoseParams
) -> tuple[np.ndarray, np.ndarray]:
    """Keep the candidates of probable pose classes (equal centre-of-mass height within ``_SAME_HEIGHT``), at most
    ``max_poses`` round-robin over the classes; each kept pose carries its class's probability over its kept members,
    so the distribution over classes stays the quasi-static one."""
    order = _descending(normals, probs)
    normals, probs = normals[order], probs[order]
    heights = (hull.vertices @ normals.T).max(axis=0) - normals @ com
    labels = np.round(heights / _SAME_HEIGHT).astype(np.int64)
    classes: dict[int, list[int]] = {}
    for i, label in enumerate(labels):  # probability order, so each class lists its members best first
        classes.setdefault(int(label), []).append(i)
    ranked = sorted(classes.values(), key=lambda members: (-probs[members].sum(), members[0]))
    kept = [m for m in ranked if probs[m].sum() >= params.min_probability] or ranked[:1]
    picked: list[list[int]] = [[] for _ in kept]
    for depth in range(max(len(m) for m in kept)):
        for slot, members in enumerate(kept):
            if depth < len(members) and sum(map(len, picked)) < params.max_poses:
                picked[slot].append(members[depth])
    index = [i for slot in picked for i in slot]
    share = [probs[kept[slot]].sum() / len(p) for slot, p in enumerate(picked) for _ in p]
    return normals[index], np.asarray(share, dtype=np.float64)


def _descending(normals: np.ndarray, probs: np.ndarray) -> np.ndarray:
    """Indices sorting by probability, descending; ties broken by the normal so the order is total."""
    return np.lexsort((normals[:, 2], normals[:, 1], normals[:, 0], -probs))


def merge_settled(
    hull: trimesh.Trimesh,
    normals: np.ndarray,
    probs: np.ndarray,
    rotations: np.ndarray,
    at_rest: np.ndarray,
    params: StablePoseParams,
    label: str,
) -> tuple[np.ndarray, np.ndarray]:
    """The candidates replaced by the faces they settled onto, unrested ones dropped, equal ones merged.

    A candidate that came to rest (``at_rest`` (k,)) is replaced by the hull face pointing down under its final
    rotation (``rotations`` (k, 3, 3), non-finite: diverged); settled normals within ``params.max_tilt`` are merged,
    probabilities added. If every candidate is dropped, the first one's settled face is returned alone with
    probability 1. ``normals`` (k, 3) and ``probs`` (k,) come from :func:`pose_candidates`; ``label`` names the object
    in log messages.

    Returns
    -------
    normals : (m, 3) float64
    probabilities : (m,) float64
        m >= 1.
    """
    settled_normals: list[np.ndarray] = []
    settled_probs: list[float] = []
    first_settled: np.ndarray | None = None
    for normal, prob, rotation, rest in zip(normals, probs, rotations, at_rest, strict=True):
        settled = _resting_face_normal(hull, rotation) if np.isfinite(rotation).all() else normal
        if first_settled is None:
            first_settled = settled
        if not rest:
            _log.debug("%s: pose %s did not come to rest, dropped", label, normal)
            continue
        if _angle(settled, normal) > params.max_tilt:
            _log.debug("%s: pose %s settled into %s", label, normal, settled)
        settled_normals.append(settled)
        settled_probs.append(float(prob))
    if not settled_normals:
        return first_settled[None, :], np.ones(1)
    return _merge_close(np.array(settled_normals), np.array(settled_probs), params.max_tilt)


def _resting_face_normal(hull: trimesh.Trimesh, rotation: np.ndarray) -> np.ndarray:
    """Outward normal (mesh frame) of the hull face pointing most nearly straight down under ``rotation``."""
    down = -rotation[2]  # world -z expressed in the mesh frame
    return np.array(hull.face_normals[int(np.argmax(hull.face_normals @ down))], dtype=np.float64)


def _merge_close(normals: np.ndarray, probs: np.ndarray, angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Merge ``normals`` (k, 3) within ``angle`` (rad) of an earlier one, greedily in order, adding their probabilities:
    representatives (m, 3) and summed probabilities (m,)."""
    unit = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    cos_limit = math.cos(angle)
    group = np.full(len(unit), -1)
    representatives: list[int] = []
    for i in range(len(unit)):
        if group[i] >= 0:
            continue
        close = (group < 0) & (unit @ unit[i] >= cos_limit)
        close[i] = True
        group[close] = len(representatives)
        representatives.append(i)
    summed = np.zeros(len(representatives))
    np.add.at(summed, group, probs)
    return normals[representatives], summed


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    cos = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return math.acos(min(1.0, max(-1.0, cos)))
