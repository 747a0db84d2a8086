"""Merging convex parts by how far the merged hull bridges beyond them (the last step of the convex decomposition).

Only pieces whose bounding boxes touch are candidates; a pair is judged by its bridge depth (m), how far the hull of
the two stands outside the pieces, the same quantity as the hull slack (:mod:`graspgen.geometry.slack`). Pairs are
merged shallowest first while the depth is within ``free_depth`` or more than ``max_parts`` parts are left. Why not
CoACD's own merge: docs/decisions/2026-12-03-coacd-decomposition.md.
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


def bridge_depth(points: np.ndarray, pieces: list[np.ndarray], owners: np.ndarray | None = None) -> float:
    """How far the convex hull of ``points`` (n, 3) stands outside the union of convex ``pieces``, m.

    ``pieces`` are their hulls' plane equations, each (k, 4) ``[normal, offset]`` with ``normal @ x + offset <= 0``
    inside; ``owners`` (n,) int, the piece each point belongs to, only saves time (the result is the same). Returns the
    largest, over four probes on each hull face, of the distance to the nearest piece as its largest plane violation
    (exact against a face, short near edges and corners); 0 when every probe lies in a piece.
    """
    hull = ConvexHull(points)
    probes = np.einsum("kj,fjd->fkd", _FACE_POINTS, points[hull.simplices]).reshape(-1, 3)
    planes = np.vstack(pieces)
    starts = np.cumsum([0] + [len(p) for p in pieces[:-1]])
    if owners is None or len(pieces) <= _FEW_PIECES:
        return float(_nearest_piece_distance(probes, planes, starts).max())
    corners = np.repeat(np.asarray(owners)[hull.simplices], len(_FACE_POINTS), axis=0)
    upper = np.full(len(probes), np.inf)
    for piece in np.unique(corners):
        rows = np.flatnonzero((corners == piece).any(axis=1))
        upper[rows] = np.minimum(upper[rows], _piece_distance(probes[rows], pieces[piece]))
    deepest = 0.0
    order = np.argsort(-upper, kind="stable")
    for start in range(0, len(order), _EXACT_BATCH):
        batch = order[start:start + _EXACT_BATCH]
        if upper[batch[0]] <= deepest:  # the bound of every probe left: none of them is deeper
            break
        deepest = max(deepest, float(_nearest_piece_distance(probes[batch], planes, starts).max()))
    return deepest


_FEW_PIECES = 4
"""Up to this many pieces, every probe is measured against all of them at once (the bounds cost more than they save)."""

_EXACT_BATCH = 64
"""Probes measured against every piece at once, deepest bound first, until the bound of the next is no deeper."""


def _violations(probes: np.ndarray, planes: np.ndarray) -> np.ndarray:
    """(p, k) signed distances of (p, 3) probes to (k, 4) planes, in a fixed order of operations so each distance has
    the same bits whichever other probes and planes it is measured with."""
    return (probes[:, 0:1] * planes[:, 0] + probes[:, 1:2] * planes[:, 1] + probes[:, 2:3] * planes[:, 2]
            + planes[:, 3])


def _piece_distance(probes: np.ndarray, planes: np.ndarray) -> np.ndarray:
    """``(p,)`` each probe's largest violation of one piece's planes, 0 inside it."""
    return np.maximum(_violations(probes, planes).max(axis=1), 0.0)


def _nearest_piece_distance(probes: np.ndarray, planes: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """``(p,)`` each probe's :func:`_piece_distance` to the nearest of the pieces whose planes start at rows
    ``starts`` of ``planes``."""
    per_piece = np.maximum.reduceat(_violations(probes, planes), starts, axis=1)
    return np.maximum(per_piece.min(axis=1), 0.0)


class _Parts:
    """The parts while merging: hull points, the planes of the pieces each was made of, which of them each point is a
    corner of, and bounding boxes (room for every part a merge can make: ``2 n - 1`` in all)."""

    def __init__(self, vertices: list[np.ndarray]):
        hulls = [ConvexHull(v) for v in vertices]
        self.points = [v[h.vertices] for v, h in zip(vertices, hulls)]
        # qhull's triangles of one flat facet (a cut face: many) repeat its plane: once does for a largest violation
        self.pieces = [[np.unique(h.equations, axis=0)] for h in hulls]
        self.owners = [np.zeros(len(p), dtype=np.int64) for p in self.points]
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
        points, owners = self._joined(i, j)
        return bridge_depth(points, self.pieces[i] + self.pieces[j], owners)

    def _joined(self, i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        """Both parts' points, and the piece of ``pieces[i] + pieces[j]`` each is a corner of."""
        return (np.vstack([self.points[i], self.points[j]]),
                np.concatenate([self.owners[i], self.owners[j] + len(self.pieces[i])]))

    def merge(self, i: int, j: int) -> int:
        both, owners = self._joined(i, j)
        k = len(self.points)
        corners = ConvexHull(both).vertices
        self.points.append(both[corners])
        self.owners.append(owners[corners])
        self.pieces.append(self.pieces[i] + self.pieces[j])
        self.low[k], self.high[k] = self.points[k].min(axis=0), self.points[k].max(axis=0)
        self.alive[[i, j]] = False
        self.alive[k] = True
        return k

    def live(self) -> list[int]:
        return [int(i) for i in np.flatnonzero(self.alive)]


def merge_convex_parts(vertices: list[np.ndarray], max_parts: int, free_depth: float) -> list[np.ndarray]:
    """Merge neighbouring convex parts (each (v, 3) vertices, m, of positive volume), shallowest bridge first, until at
    most ``max_parts`` are left (-1: no bound) and while the shallowest bridge is at most ``free_depth`` m. Returns the
    merged parts' hull vertices in the order made (untouched parts first); ties broken by index, so a pure function of
    the input."""
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
