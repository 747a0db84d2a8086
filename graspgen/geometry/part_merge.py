"""Merging convex parts by how far the merged hull bridges beyond them (the last step of the convex decomposition).

CoACD cuts a mesh into convex pieces and then, to stay under ``max_convex_hull``, merges them again by a concavity
cost it computes for every pair of pieces: on ShapeNet bowls and mugs that all-pairs merge is about 40 % of CoACD's
time, and the pairs it picks are no better for a gripper than the ones chosen here (``bench/bench_prep.py``). Here
only pieces whose bounding boxes touch are candidates, and a pair is judged by its *bridge depth*: how far the convex
hull of the two stands outside the pieces they were made of, the same quantity (in m) as the hull slack the
decomposition is judged by (:mod:`graspgen.geometry.slack`), since the pieces themselves follow the surface.
Pairs are merged shallowest first while the depth is within ``free_depth`` (merging them costs the gripper nothing)
or while more than ``max_parts`` parts are left.
"""

from __future__ import annotations

import heapq
from typing import NamedTuple

import numpy as np
from scipy.spatial import ConvexHull

__all__ = ["ConvexPart", "bridge_depth", "convex_part", "merge_convex_parts"]

_FACE_POINTS = np.array([[1 / 3, 1 / 3, 1 / 3], [2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3]])
"""Barycentric weights of the points each face of a merged hull is probed at (its centroid and the three points
halfway between it and the corners): deterministic, and dense enough on the large faces a bridge is made of."""

_TOUCH_GAP = 1e-3
"""How far apart (m) two parts' bounding boxes may be and still count as neighbours. CoACD's pieces share their
cut faces, so neighbours touch; the margin covers round-off and pieces meeting at an edge."""


class ConvexPart(NamedTuple):
    """A convex part as its hull: what the decomposition keeps of each piece (lighter than a ``trimesh.Trimesh``,
    which the hundreds of pieces of a fine cut would each build and cache)."""

    vertices: np.ndarray
    """``(v, 3) float64`` the hull's vertices, m."""
    faces: np.ndarray
    """``(f, 3) int32`` its triangles, wound outward (counter-clockwise seen from outside)."""
    volume: float
    """Its volume, m^3."""


def convex_part(points: np.ndarray) -> ConvexPart:
    """The convex hull of ``(n, 3) float`` points (qhull), vertices renumbered from 0 and faces wound outward.
    Raises scipy's ``QhullError`` on points with no volume (fewer than 4, or all in a plane) or ``ValueError`` on
    NaN."""
    hull = ConvexHull(np.asarray(points, dtype=np.float64))
    index = np.full(len(hull.points), -1, dtype=np.int64)
    index[hull.vertices] = np.arange(len(hull.vertices))
    faces = index[hull.simplices]
    vertices = hull.points[hull.vertices]
    corners = vertices[faces]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    inward = np.einsum("ij,ij->i", normals, hull.equations[:, :3]) < 0
    faces[inward] = faces[inward][:, ::-1]
    return ConvexPart(np.ascontiguousarray(vertices), faces.astype(np.int32), float(hull.volume))


def bridge_depth(points: np.ndarray, pieces: list[np.ndarray]) -> float:
    """How far the convex hull of ``points`` stands outside the union of convex ``pieces``, m.

    Parameters
    ----------
    points
        ``(n, 3) float`` points whose hull is judged (the pieces' vertices).
    pieces
        The pieces as their hulls' plane equations, each ``(k, 4) float`` rows ``[normal, offset]`` with
        ``normal @ x + offset <= 0`` inside (scipy's ``ConvexHull.equations``).

    Returns
    -------
    float
        The largest, over four points on each face of the hull, of the distance to the nearest piece, each distance
        taken as the largest plane violation (exact where the nearest feature of the piece is a face, short of the
        Euclidean distance near its edges and corners). 0 when every probe lies in a piece.
    """
    hull = ConvexHull(points)
    triangles = points[hull.simplices]
    probes = np.einsum("kj,fjd->fkd", _FACE_POINTS, triangles).reshape(-1, 3)
    nearest = np.full(len(probes), np.inf)
    for planes in pieces:
        outside = np.maximum((probes @ planes[:, :3].T + planes[:, 3]).max(axis=1), 0.0)
        nearest = np.minimum(nearest, outside)
    return float(nearest.max())


class _Parts:
    """The parts while merging: hull points, the planes of the pieces each was made of, and bounding boxes (room for
    every part a merge can make: ``2 n - 1`` in all)."""

    def __init__(self, vertices: list[np.ndarray]):
        hulls = [ConvexHull(v) for v in vertices]
        self.points = [v[h.vertices] for v, h in zip(vertices, hulls)]
        self.pieces = [[h.equations] for h in hulls]
        room = max(2 * len(hulls) - 1, 1)
        self.alive = np.zeros(room, dtype=bool)
        self.alive[: len(hulls)] = True
        self.low = np.zeros((room, 3))
        self.high = np.zeros((room, 3))
        for i, p in enumerate(self.points):
            self.low[i], self.high[i] = p.min(axis=0), p.max(axis=0)

    def neighbours(self, index: int, start: int, stop: int) -> np.ndarray:
        """Indices in ``[start, stop)`` of live parts whose bounding boxes touch part ``index``'s."""
        low, high = self.low[start:stop], self.high[start:stop]
        touch = (self.alive[start:stop] & np.all(low <= self.high[index] + _TOUCH_GAP, axis=1)
                 & np.all(high >= self.low[index] - _TOUCH_GAP, axis=1))
        return np.flatnonzero(touch) + start

    def depth(self, i: int, j: int) -> float:
        return bridge_depth(np.vstack([self.points[i], self.points[j]]), self.pieces[i] + self.pieces[j])

    def merge(self, i: int, j: int) -> int:
        both = np.vstack([self.points[i], self.points[j]])
        k = len(self.points)
        self.points.append(both[ConvexHull(both).vertices])
        self.pieces.append(self.pieces[i] + self.pieces[j])
        self.low[k], self.high[k] = self.points[k].min(axis=0), self.points[k].max(axis=0)
        self.alive[[i, j]] = False
        self.alive[k] = True
        return k

    def live(self) -> list[int]:
        return [int(i) for i in np.flatnonzero(self.alive)]


def merge_convex_parts(vertices: list[np.ndarray], max_parts: int, free_depth: float) -> list[np.ndarray]:
    """Merge neighbouring convex parts, shallowest bridge first (:func:`bridge_depth`).

    Parameters
    ----------
    vertices
        Each part's ``(v, 3) float`` vertices (convex, of positive volume), m.
    max_parts
        Merge until at most this many parts are left; -1 for no bound.
    free_depth
        Also merge while the shallowest pair's bridge depth is at most this, m.

    Returns
    -------
    list of (v, 3) float
        The merged parts' hull vertices, in the order they were made (the parts left as they were first). The result
        is a pure function of the input: ties are broken by the parts' indices.
    """
    parts = _Parts([np.asarray(v, dtype=np.float64) for v in vertices])
    count = len(parts.points)
    heap = [(parts.depth(i, int(j)), i, int(j)) for i in range(count) for j in parts.neighbours(i, i + 1, count)]
    heapq.heapify(heap)
    while heap and count > 1:
        depth, i, j = heapq.heappop(heap)
        if not (parts.alive[i] and parts.alive[j]):
            continue
        if depth > free_depth and (max_parts == -1 or count <= max_parts):
            break
        k = parts.merge(i, j)
        count -= 1
        for m in parts.neighbours(k, 0, k):
            heapq.heappush(heap, (parts.depth(int(m), k), int(m), k))
    if max_parts != -1 and count > max_parts:
        # Parts no neighbour touches (CoACD leaves none, but an input may): the nearest pairs by bounding box go.
        return _merge_isolated(parts, max_parts)
    return [parts.points[i] for i in parts.live()]


def _merge_isolated(parts: _Parts, max_parts: int) -> list[np.ndarray]:
    live = parts.live()
    while len(live) > max_parts:
        centres = (parts.low[live] + parts.high[live]) / 2
        gaps = np.linalg.norm(centres[:, None] - centres[None], axis=-1) + np.diag(np.full(len(live), np.inf))
        a, b = np.unravel_index(int(np.argmin(gaps)), gaps.shape)
        parts.merge(live[a], live[b])
        live = parts.live()
    return [parts.points[i] for i in live]
