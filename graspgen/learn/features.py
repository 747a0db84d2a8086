"""A grasp's input to the evaluator: the object's surface points near the closing region, in the TCP frame.

TCP frame (ARCHITECTURE.md "Conventions"): origin midway between the pads, z approach, x closing, y = z x x.
The closing volume is the box swept by the open pads: centred on the TCP, half-extents ``(max_width / 2,
pad_width / 2, pad_length / 2)`` (:func:`closing_volume`). Per grasp the ``K`` surface points nearest that box
(Euclidean distance to the box, 0 inside; ties by point index; rows ordered by distance) are kept; a kept point
farther than ``margin`` from the box is dropped and its row is all zeros (a real point at the origin is inside,
so a zero row with flag 0 is unambiguous padding). Numpy only.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from graspgen.errors import SettingsError
from graspgen.validation import check_int, check_number

__all__ = ["FEATURE_VERSION", "FeatureParams", "closing_volume", "grasp_features", "object_rng", "set_features",
           "surface_points"]

FEATURE_VERSION = 1
"""Bumped whenever the features change; stored in model files and checked on load."""

_CHUNK = 512  # grasps per batch: (512, n, 3) float64 is 25 MB at n = 2048


@dataclasses.dataclass(frozen=True)
class FeatureParams:
    """How grasps become network inputs."""

    num_surface_points: int = 2048
    """Points sampled on each object's surface (area-weighted, with the given rng)."""
    num_points: int = 64
    """K: points nearest the closing region kept per grasp."""
    margin: float = 0.01
    """m: how far outside the closing volume a kept point may lie; farther ones become zero rows."""

    def __post_init__(self) -> None:
        check_int("num_surface_points", self.num_surface_points, low=1)
        check_int("num_points", self.num_points, low=1)
        check_number("margin", self.margin, low=0.0)
        if self.num_points > self.num_surface_points:
            from graspgen.errors import SettingsError

            raise SettingsError(f"num_points: must be <= num_surface_points ({self.num_surface_points}), "
                                f"got {self.num_points}")


def surface_points(vertices: np.ndarray, faces: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points drawn uniformly over a triangle mesh's area.

    Parameters
    ----------
    vertices : (v, 3) float, m.  faces : (f, 3) int.  n : int.  rng : numpy.random.Generator

    Returns
    -------
    (n, 3) float64 points on the surface, m.
    """
    v = np.asarray(vertices, dtype=np.float64)
    tri = v[np.asarray(faces, dtype=np.int64)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if not area.sum() > 0:
        raise SettingsError("surface_points: the mesh has no area")
    face = rng.choice(len(tri), size=n, p=area / area.sum())
    u, w = rng.random(n), rng.random(n)
    flip = u + w > 1.0  # fold the unit square onto the triangle: uniform over its area
    u[flip], w[flip] = 1.0 - u[flip], 1.0 - w[flip]
    t = tri[face]
    return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + w[:, None] * (t[:, 2] - t[:, 0])


def closing_volume(gripper) -> np.ndarray:
    """(3,) float64 half-extents (m) of the box between the open pads, TCP frame: x half the open width, y half the
    pad's width, z half the pad's length (pads are centred on the TCP plane, as the ray casts of
    :func:`graspgen.geometry.contacts.pad_ray_grid` assume)."""
    _, pad_w, pad_l = gripper.pad_size
    return np.array([gripper.max_width / 2, pad_w / 2, pad_l / 2], dtype=np.float64)


def _nearest(dist: np.ndarray, k: int) -> np.ndarray:
    """(c, k) indices of the k smallest of each row of ``dist`` (c, n), ordered by (distance, index)."""
    kth = np.partition(dist, k - 1, axis=1)[:, k - 1 : k]
    less = dist < kth
    tie = dist == kth
    need = k - less.sum(axis=1, keepdims=True)
    chosen = less | (tie & (np.cumsum(tie, axis=1) <= need))  # ties at the k-th distance: the lowest indices
    idx = np.nonzero(chosen)[1].reshape(len(dist), k)  # row-major: each row's indices ascending
    order = np.argsort(np.take_along_axis(dist, idx, axis=1), axis=1, kind="stable")
    return np.take_along_axis(idx, order, axis=1)


def grasp_features(points: np.ndarray, T_tcp: np.ndarray, width: np.ndarray, gripper,
                   params: FeatureParams) -> tuple[np.ndarray, np.ndarray]:
    """The network's input of each grasp.

    Parameters
    ----------
    points : (n, 3) float
        Surface points of the object, its mesh frame, m (:func:`surface_points`); n >= ``params.num_points``.
    T_tcp : (m, 4, 4) float
        TCP poses in the mesh frame.
    width : (m,) float
        Pad separation per grasp, m.
    gripper : GripperSpec
        Gives the closing volume (:func:`closing_volume`).
    params : FeatureParams

    Returns
    -------
    feats : (m, K, 4) float32
        Per grasp the K points nearest the closing volume: x, y, z in the TCP frame (m) and 1.0 if inside the
        closing volume else 0.0; rows by distance to the volume (ties by point index); rows of points farther
        than ``margin`` are zeros.
    width : (m,) float32, m.
    """
    P = np.asarray(points, dtype=np.float64)
    T = np.asarray(T_tcp, dtype=np.float64).reshape(-1, 4, 4)
    w = np.asarray(width, dtype=np.float64).reshape(-1)
    if len(w) != len(T):
        raise SettingsError(f"width: expected {len(T)} values (one per pose), got {len(w)}")
    k = params.num_points
    if len(P) < k:
        raise SettingsError(f"points: need at least num_points = {k}, got {len(P)}")
    half = closing_volume(gripper)
    out = np.zeros((len(T), k, 4), dtype=np.float32)
    for s in range(0, len(T), _CHUNK):
        Rt = T[s : s + _CHUNK, :3, :3].transpose(0, 2, 1)
        # R^T (p - t), coordinates along axis 1: (c, 3, n) keeps each coordinate contiguous (fast reductions)
        local = Rt @ P.T - (Rt @ T[s : s + _CHUNK, :3, 3:4])
        outside = np.maximum(np.abs(local) - half[:, None], 0.0)
        outside *= outside
        dist = np.sqrt(outside[:, 0] + outside[:, 1] + outside[:, 2])
        idx = _nearest(dist, k)
        near = np.take_along_axis(local, idx[:, None, :], axis=2).transpose(0, 2, 1)
        d = np.take_along_axis(dist, idx, axis=1)
        keep = d <= params.margin
        block = np.concatenate([near, (d <= 0.0)[..., None].astype(np.float64)], axis=2)
        block[~keep] = 0.0
        out[s : s + _CHUNK] = block
    return out, w.astype(np.float32)


def object_rng(seed: int, name: str) -> np.random.Generator:
    """The generator of one object's surface points: from ``seed`` and a sha256 of its name (order-independent)."""
    import hashlib

    return np.random.default_rng([int(seed), int(hashlib.sha256(name.encode()).hexdigest()[:8], 16)])


def set_features(sets, gripper, params: FeatureParams, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`grasp_features` of every grasp of ``sets`` (ObjectGraspSet list), concatenated in order: (N, K, 4)
    float32 and (N,) float32. Each object's surface points come from :func:`object_rng` (``seed``, its name)."""
    feats, widths = [], []
    for s in sets:
        pts = surface_points(s.vertices, s.faces, params.num_surface_points, object_rng(seed, s.name))
        f, w = grasp_features(pts, s.T_tcp, s.width, gripper, params)
        feats.append(f)
        widths.append(w)
    if not feats:
        return np.zeros((0, params.num_points, 4), np.float32), np.zeros(0, np.float32)
    return np.concatenate(feats), np.concatenate(widths)
