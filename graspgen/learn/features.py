"""A grasp's input to the evaluator: the object's surface points near the closing region and near the hand's
body, in the TCP frame.

TCP frame (ARCHITECTURE.md "Conventions"): origin midway between the pads, z approach, x closing, y = z x x.
The closing volume is the box swept by the open pads: centred on the TCP, half-extents ``(max_width / 2,
pad_width / 2, pad_length / 2)`` (:func:`closing_volume`). The hand's body is the union of the palm's boxes and the
two fingers' bounding boxes with the jaws fully open (:func:`hand_boxes`): a surface point inside it is a collision
at placement. Per grasp the ``K`` surface points nearest the closing volume, then the ``K_h`` nearest the hand's
body, are kept (Euclidean distance to the box or union, 0 inside; ties by point index; each group's rows ordered by
distance); a kept point farther than ``margin`` from its region is dropped and its row is all zeros (a real point at
the origin is inside the closing volume, so a zero row with both flags 0 is unambiguous padding). Why the hand: a
grasp whose palm or finger sits in the object fails however well the pads would close, and the closing region alone
cannot show it. Numpy only.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from graspgen.errors import SettingsError
from graspgen.validation import check_int, check_number

__all__ = ["CHANNELS", "FEATURE_VERSION", "FeatureParams", "closing_volume", "grasp_features", "hand_boxes",
           "object_rng", "set_features", "surface_points"]

FEATURE_VERSION = 2
"""Bumped whenever the features change; stored in model files and checked on load."""

CHANNELS = 5
"""Values per row: x, y, z (TCP frame, m), inside the closing volume (1/0), inside the hand's body (1/0)."""

_CHUNK = 512  # grasps per batch: (512, n, 3) float64 is 25 MB at n = 2048


@dataclasses.dataclass(frozen=True)
class FeatureParams:
    """How grasps become network inputs."""

    num_surface_points: int = 2048
    """Points sampled on each object's surface (area-weighted, with the given rng)."""
    num_points: int = 64
    """K: points nearest the closing region kept per grasp."""
    hand_points: int = 32
    """K_h: points nearest the hand's body (:func:`hand_boxes`) kept per grasp after the K; 0 keeps none."""
    margin: float = 0.01
    """m: how far outside its region (closing volume or hand) a kept point may lie; farther ones become zero rows."""

    def __post_init__(self) -> None:
        check_int("num_surface_points", self.num_surface_points, low=1)
        check_int("num_points", self.num_points, low=1)
        check_int("hand_points", self.hand_points, low=0)
        check_number("margin", self.margin, low=0.0)
        for key in ("num_points", "hand_points"):
            if getattr(self, key) > self.num_surface_points:
                raise SettingsError(f"{key}: must be <= num_surface_points ({self.num_surface_points}), "
                                    f"got {getattr(self, key)}")

    @property
    def rows(self) -> int:
        """Rows per grasp: ``num_points + hand_points``."""
        return self.num_points + self.hand_points


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


def hand_boxes(gripper) -> np.ndarray:
    """(b, 2, 3) float64 lowest and highest corners (m, TCP frame) of the boxes whose union is the hand's body with
    the jaws fully open: each palm box (``palm_boxes``, the bounding boxes of ``palm_geoms`` where given) and each
    finger's bounding box. A finger's box starts at the pad's contact face (``x = max_width / 2``) and reaches out
    through the finger link (``finger_size`` x; with ``finger_geoms`` that extent includes the pad, else the link
    sits behind a ``pad_size`` x thick pad); it is ``max(finger, pad)`` wide along y and runs along z from the pad's
    tip (``pad_length / 2``) back ``finger_size`` z. The left finger mirrors the right one (x -> -x)."""
    half = gripper.max_width / 2.0
    pad_t, pad_w, pad_l = gripper.pad_size
    fin_t, fin_w, fin_l = gripper.finger_size
    outer = half + (fin_t if gripper.finger_geoms else pad_t + fin_t)
    y = max(fin_w, pad_w) / 2.0
    boxes = [np.array([[half, -y, pad_l / 2 - fin_l], [outer, y, pad_l / 2]]),
             np.array([[-outer, -y, pad_l / 2 - fin_l], [-half, y, pad_l / 2]])]
    boxes += [np.stack(b.bounds) for b in gripper.palm_boxes]
    return np.stack(boxes).astype(np.float64)


def _box_distance(local: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """(c, n) Euclidean distance of points ``local`` (c, 3, n) to the box [low, high] (3,), 0 inside."""
    gap = np.maximum(np.maximum(low[:, None] - local, local - high[:, None]), 0.0)
    gap *= gap
    return np.sqrt(gap[:, 0] + gap[:, 1] + gap[:, 2])


def _rows(local: np.ndarray, dist: np.ndarray, k: int, margin: float, flags: tuple[np.ndarray, np.ndarray]):
    """(c, k, 5) rows of the ``k`` points nearest by ``dist`` (c, n): coordinates and the two (c, n) flags; a point
    farther than ``margin`` is a zero row."""
    idx = _nearest(dist, k)
    near = np.take_along_axis(local, idx[:, None, :], axis=2).transpose(0, 2, 1)
    cols = [np.take_along_axis(f, idx, axis=1)[..., None].astype(np.float64) for f in flags]
    block = np.concatenate([near, *cols], axis=2)
    block[np.take_along_axis(dist, idx, axis=1) > margin] = 0.0
    return block


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
    feats : (m, K + K_h, 5) float32
        Per grasp the K points nearest the closing volume, then the K_h nearest the hand's body (module docstring):
        x, y, z in the TCP frame (m), 1.0 if inside the closing volume else 0.0, 1.0 if inside the hand's body else
        0.0; each group's rows by distance to its region (ties by point index); rows of points farther than
        ``margin`` from their region are zeros.
    width : (m,) float32, m.
    """
    P = np.asarray(points, dtype=np.float64)
    T = np.asarray(T_tcp, dtype=np.float64).reshape(-1, 4, 4)
    w = np.asarray(width, dtype=np.float64).reshape(-1)
    if len(w) != len(T):
        raise SettingsError(f"width: expected {len(T)} values (one per pose), got {len(w)}")
    k, kh = params.num_points, params.hand_points
    if len(P) < max(k, kh):
        raise SettingsError(f"points: need at least num_points = {k} and hand_points = {kh}, got {len(P)}")
    half = closing_volume(gripper)
    boxes = hand_boxes(gripper)
    out = np.zeros((len(T), k + kh, CHANNELS), dtype=np.float32)
    for s in range(0, len(T), _CHUNK):
        Rt = T[s : s + _CHUNK, :3, :3].transpose(0, 2, 1)
        # R^T (p - t), coordinates along axis 1: (c, 3, n) keeps each coordinate contiguous (fast reductions)
        local = Rt @ P.T - (Rt @ T[s : s + _CHUNK, :3, 3:4])
        closing = _box_distance(local, -half, half)
        hand = np.min([_box_distance(local, lo, hi) for lo, hi in boxes], axis=0)
        flags = (closing <= 0.0, hand <= 0.0)
        out[s : s + _CHUNK, :k] = _rows(local, closing, k, params.margin, flags)
        if kh:
            out[s : s + _CHUNK, k:] = _rows(local, hand, kh, params.margin, flags)
    return out, w.astype(np.float32)


def object_rng(seed: int, name: str) -> np.random.Generator:
    """The generator of one object's surface points: from ``seed`` and a sha256 of its name (order-independent)."""
    import hashlib

    return np.random.default_rng([int(seed), int(hashlib.sha256(name.encode()).hexdigest()[:8], 16)])


def set_features(sets, gripper, params: FeatureParams, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`grasp_features` of every grasp of ``sets`` (ObjectGraspSet list), concatenated in order: (N, K + K_h,
    5) float32 and (N,) float32. Each object's surface points come from :func:`object_rng` (``seed``, its name)."""
    feats, widths = [], []
    for s in sets:
        pts = surface_points(s.vertices, s.faces, params.num_surface_points, object_rng(seed, s.name))
        f, w = grasp_features(pts, s.T_tcp, s.width, gripper, params)
        feats.append(f)
        widths.append(w)
    if not feats:
        return np.zeros((0, params.rows, CHANNELS), np.float32), np.zeros(0, np.float32)
    return np.concatenate(feats), np.concatenate(widths)
