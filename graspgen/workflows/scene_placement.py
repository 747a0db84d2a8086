"""Where the objects of a scene go: which objects a scene draws and their non-overlapping resting placements on
the support (all randomness from the ``rng`` passed in; the draw order is part of the published bytes).

A placement is a stable pose of the object (drawn by its probability), a uniform yaw and an x/y position in
``support.area``; it is rejected when its footprint (the union of its convex parts' x/y hulls) comes closer than
``gap`` to an earlier object, leaves the support's free region or reaches the shelf board.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import numpy as np
from scipy.spatial import ConvexHull

from graspgen.errors import SettingsError
from graspgen.io.objects import ObjectRecord
from graspgen.sim.support import free_region
from graspgen.workflows.scene_params import ScenesParams

__all__ = ["Placement", "SceneCounts", "choose_objects", "place_objects"]


@dataclasses.dataclass(frozen=True, eq=False)
class _Footprint:
    """An object's shape in one stable pose, for placement tests (world frame of the pose, before yaw/shift)."""

    hulls: tuple[np.ndarray, ...]
    """x/y convex hull (k, 2) of every convex part."""
    top: float
    """Highest point above the support, m."""


def _footprint(record: ObjectRecord, pose: np.ndarray) -> _Footprint:
    hulls = []
    top = -math.inf
    for vertices, _ in record.convex_parts:
        world = vertices @ pose[:3, :3].T + pose[:3, 3]
        top = max(top, float(world[:, 2].max()))
        xy = world[:, :2]
        try:
            hulls.append(xy[ConvexHull(xy).vertices])
        except Exception:  # noqa: BLE001 - a flat part (all points on a line) has no 2-D hull: use its extremes
            hulls.append(xy[[int(xy[:, 0].argmin()), int(xy[:, 0].argmax())]])
    return _Footprint(tuple(hulls), top)


def _rotate(points: np.ndarray, yaw: float, shift: np.ndarray) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return points @ np.array([[c, s], [-s, c]]) + shift


def _separated(a: np.ndarray, b: np.ndarray, gap: float) -> bool:
    """True when convex polygons a, b (k, 2) are at least ``gap`` apart along one of their edge normals.

    (Separation along any axis bounds the true distance from below, so this never accepts closer polygons; it
    may reject a few that are slightly further than ``gap`` apart near a corner.)
    """
    for poly in (a, b):
        edges = np.roll(poly, -1, axis=0) - poly
        normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
        lengths = np.linalg.norm(normals, axis=1)
        normals = normals[lengths > 1e-12] / lengths[lengths > 1e-12, None]
        if len(normals) == 0:
            continue
        pa, pb = a @ normals.T, b @ normals.T
        if np.any(pa.max(0) + gap <= pb.min(0)) or np.any(pb.max(0) + gap <= pa.min(0)):
            return True
    return False


def _overlaps(parts_a: Sequence[np.ndarray], parts_b: Sequence[np.ndarray], gap: float) -> bool:
    for a in parts_a:
        for b in parts_b:
            if a[:, 0].max() + gap <= b[:, 0].min() or b[:, 0].max() + gap <= a[:, 0].min():
                continue
            if a[:, 1].max() + gap <= b[:, 1].min() or b[:, 1].max() + gap <= a[:, 1].min():
                continue
            if not _separated(a, b, gap):
                return True
    return False


@dataclasses.dataclass
class SceneCounts:
    """What one scene's making tried and threw away (stored in the shard's ``counts`` and the manifest)."""

    placement_tries: int = 0
    placement_failed: int = 0
    unstable_fallen: int = 0
    unstable_tipped: int = 0
    unstable_moving: int = 0
    scene_retries: int = 0


@dataclasses.dataclass(frozen=True, eq=False)
class Placement:
    """One object placed on the support, before settling."""

    name: str
    pose_index: int
    pose: np.ndarray
    friction: float


def choose_objects(params: ScenesParams, library: Sequence[str], rng: np.random.Generator) -> list[str]:
    """Names of the objects of one scene draw (see :class:`ScenesParams`), drawn with ``rng``."""
    if params.choice == "fixed":
        return list(params.objects)
    pool = sorted(set(params.objects)) if params.objects else sorted(library)
    weights = np.array([params.weights.get(n, 1.0) for n in pool], dtype=float)
    if weights.sum() <= 0:
        raise SettingsError("weights: every object has weight 0")
    lo, hi = params.count_range
    k = int(rng.integers(lo, hi + 1))
    picks = rng.choice(len(pool), size=k, replace=params.replace, p=weights / weights.sum())
    return [pool[i] for i in picks]


def place_objects(
    names: Sequence[str],
    records: Mapping[str, ObjectRecord],
    params: ScenesParams,
    rng: np.random.Generator,
    counts: SceneCounts,
) -> list[Placement]:
    """Non-overlapping resting placements of ``names`` on the support (objects that do not fit are left out)."""
    lo_region, hi_region, z_max = free_region(params.support)
    area = np.asarray(params.support.area, dtype=float) / 2
    gap = params.gap
    footprints: dict[tuple[str, int], _Footprint] = {}
    placed: list[tuple[Placement, list[np.ndarray]]] = []
    flo, fhi = params.friction_range
    for name in names:
        record = records[name]
        probs = np.asarray(record.stable_probabilities, dtype=float)
        probs = probs / probs.sum()
        for _ in range(params.max_tries):
            counts.placement_tries += 1
            s = int(rng.choice(len(probs), p=probs))
            yaw = float(rng.uniform(-math.pi, math.pi))
            if params.placement == "uniform":
                xy = rng.uniform(-area, area)
            else:
                xy = np.clip(rng.normal(0.0, params.placement_sigma, size=2), -area, area)
            key = (name, s)
            if key not in footprints:
                footprints[key] = _footprint(record, record.stable_poses[s])
            fp = footprints[key]
            if fp.top + gap > z_max:
                continue
            hulls = [_rotate(h, yaw, xy) for h in fp.hulls]
            pts = np.concatenate(hulls)
            if np.any(pts.min(0) < lo_region + gap) or np.any(pts.max(0) > hi_region - gap):
                continue
            if any(_overlaps(hulls, other, gap) for _, other in placed):
                continue
            c, s_ = math.cos(yaw), math.sin(yaw)
            shift = np.eye(4)
            shift[:3, :3] = [[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]]
            shift[:3, 3] = [xy[0], xy[1], params.settle.drop_height]
            friction = float(rng.uniform(flo, fhi)) if fhi > flo else flo
            own = record.attrs.get("friction")  # the object's own (manifest) friction wins over the drawn one
            if own is not None:
                friction = float(own)
            placed.append((Placement(name, s, shift @ record.stable_poses[s], friction), hulls))
            break
        else:
            counts.placement_failed += 1
    return [p for p, _ in placed]
