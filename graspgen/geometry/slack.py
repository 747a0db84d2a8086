"""Hull slack: how far a union of convex parts stands out of a mesh's surface (and falls short of it), in m.

:func:`hull_slack` measures both ways (:class:`HullSlack`); :func:`outward_slack_p95` only the outward p95 that
:func:`graspgen.geometry.convex.convex_decomposition` decides by (the same value for the same generator state).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from graspgen.geometry.mesh_io import _check_mesh
from graspgen.validation import check, check_positive_int

__all__ = ["HullSlack", "hull_slack", "outward_slack_p95", "rough_parts"]


@dataclass(frozen=True)
class HullSlack:
    """How far a union of convex parts and a mesh's surface stand out of each other (:func:`hull_slack`), m."""

    max: float
    """Largest distance from the mesh of a point of the union's boundary outside the mesh (sampled points and the
    parts' vertices); 0 when the whole boundary is on or inside the mesh."""
    p95: float
    """95th percentile of that distance over the union's boundary, area-weighted (points on or inside the mesh
    count as 0): 5 % of the boundary area stands further out than this."""
    short_max: float
    """The other way round: largest distance from the union of a point of the mesh's surface outside every part (how far
    the parts fall short); 0 when they cover it."""
    short_p95: float
    """95th percentile of that distance over the mesh's surface, area-weighted (covered points count as 0)."""
    samples: int
    """Boundary points ``p95`` is taken over (area samples left after dropping those buried in another part)."""


_SLACK_STEP = 1e-5
"""Step (m) off a part's face used to tell the union's boundary from faces buried in another part (10 um: far below
any slack that matters, far above float round-off at object scale)."""

_INSIDE_TOLERANCE = 1e-9
"""How far (m) inside a part a point must be to count as inside it: a vertex of one part lying on a face of
another is on the boundary, whatever the round-off."""

_BOX_MARGIN = 1e-6
"""How far (m) outside a part's bounding box a point is still tested against its planes (round-off in the planes,
and the corners of a part grown by a negative tolerance, reach beyond the box by far less)."""


def hull_slack(
    mesh: trimesh.Trimesh,
    convex_parts: list[tuple[np.ndarray, np.ndarray]] | tuple[tuple[np.ndarray, np.ndarray], ...],
    n_samples: int,
    rng: np.random.Generator,
) -> HullSlack:
    """How far the union of ``convex_parts`` extends beyond the surface of ``mesh`` (and falls short of it), m.

    MuJoCo collides the parts, not the mesh, so where the union stands out a gripper touches what is not there.
    Outward: ``n_samples`` points by area over the parts' faces (``rng``), those buried in another part dropped; a
    point's slack is its distance to the mesh surface if outside the mesh (generalised winding number), else 0; the
    maximum also takes the parts' boundary vertices. Short: as many points over the mesh's surface, plus its vertices;
    0 inside a part, else the distance to the nearest part.

    Parameters
    ----------
    mesh
        The true surface (m), e.g. the repaired mesh the parts were made from.
    convex_parts
        ``(vertices (v, 3), faces (f, 3))`` per part, outward-wound convex hulls.
    n_samples
        Area samples over the parts, and as many over the mesh (20,000 keeps the percentiles' error below 0.1 mm at
        grasping size).
    rng
        Source of the sample points.
    """
    _check_mesh(mesh, "mesh")
    check_positive_int("n_samples", n_samples)
    check("convex_parts", len(convex_parts) > 0, "hold at least one part", len(convex_parts))
    union = _Union.of(convex_parts)
    points = _boundary_samples(union, n_samples, rng)
    corners = np.concatenate([v for v, _ in union.parts])
    corner_owner = np.concatenate([np.full(len(v), i) for i, (v, _) in enumerate(union.parts)])
    corners = corners[~_inside_parts(corners, union, corner_owner)]
    slack = np.maximum(_outside_distance(mesh, np.concatenate([points, corners])), 0.0)

    surface, _ = _area_samples(np.asarray(mesh.triangles, dtype=np.float64), n_samples, rng)
    surface = np.concatenate([surface, np.asarray(mesh.vertices, dtype=np.float64)])
    short = np.zeros(len(surface))
    bare = np.flatnonzero(~_inside_parts(surface, union, None, tolerance=-_INSIDE_TOLERANCE))
    if len(bare):  # outside every part: the distance to the union is the distance to the nearest part's surface
        tri = union.triangles
        whole = trimesh.Trimesh(tri.reshape(-1, 3), np.arange(3 * len(tri)).reshape(-1, 3), process=False)
        short[bare] = _surface_distance(whole, surface[bare])

    return HullSlack(
        max=float(np.max(slack, initial=0.0)),
        p95=float(np.percentile(slack[: len(points)], 95)) if len(points) else 0.0,
        short_max=float(np.max(short, initial=0.0)),
        short_p95=float(np.percentile(short[:n_samples], 95)),
        samples=int(len(points)),
    )


def outward_slack_p95(
    mesh: trimesh.Trimesh,
    convex_parts: list[tuple[np.ndarray, np.ndarray]] | tuple[tuple[np.ndarray, np.ndarray], ...],
    n_samples: int,
    rng: np.random.Generator,
) -> float:
    """``hull_slack(mesh, convex_parts, n_samples, rng).p95`` (m) without the rest: the same value for the same ``rng``
    state, at a fraction of the cost."""
    _check_mesh(mesh, "mesh")
    check_positive_int("n_samples", n_samples)
    check("convex_parts", len(convex_parts) > 0, "hold at least one part", len(convex_parts))
    points = _boundary_samples(_Union.of(convex_parts), n_samples, rng)
    if not len(points):
        return 0.0
    return float(np.percentile(_top_outward(mesh, points, len(points) - int(np.floor(0.95 * (len(points) - 1)))), 95))


def rough_parts(
    mesh: trimesh.Trimesh,
    convex_parts: list[tuple[np.ndarray, np.ndarray]] | tuple[tuple[np.ndarray, np.ndarray], ...],
    depth: float,
    share: float,
    n_samples: int,
    rng: np.random.Generator,
    area_limit: float = 1.0,
) -> np.ndarray | None:
    """Which of ``convex_parts`` stand more than ``depth`` (m) outside the closed ``mesh`` on more than ``share`` (in
    [0, 1)) of their ``n_samples`` area samples: (p,) bool (False for a part no sample fell on), or None as soon as the
    rough parts hold more than ``area_limit`` (in (0, 1]) of the parts' area."""
    _check_mesh(mesh, "mesh")
    check_positive_int("n_samples", n_samples)
    check("convex_parts", len(convex_parts) > 0, "hold at least one part", len(convex_parts))
    check("share", 0.0 <= share < 1.0, "be in [0, 1)", share)
    check("area_limit", 0.0 < area_limit <= 1.0, "be in (0, 1]", area_limit)
    union = _Union.of(convex_parts)
    count = len(union.parts)
    owner = np.concatenate([np.full(len(f), i) for i, (_, f) in enumerate(union.parts)])
    triangles = union.triangles
    area = np.bincount(owner, weights=_triangle_areas(triangles), minlength=count)
    points, pick = _area_samples(triangles, n_samples, rng)
    owner = owner[pick]
    distance = _surface_distance(mesh, points)
    needed = np.floor(share * np.bincount(owner, minlength=count)).astype(np.int64) + 1
    far = np.flatnonzero(distance > depth)
    far = far[np.argsort(-distance[far], kind="stable")]
    settled = np.zeros(len(far), dtype=bool)
    left = np.bincount(owner[far], minlength=count)  # far points not yet settled
    found = np.zeros(count, dtype=np.int64)  # far points found outside
    open_parts = (found < needed) & (found + left >= needed)
    while open_parts.any():
        take = np.flatnonzero(~settled & open_parts[owner[far]])[:_SIGN_BATCH]
        settled[take] = True
        batch = far[take]
        outside = np.abs(_winding_number(mesh, points[batch])) <= 0.5
        np.add.at(found, owner[batch[outside]], 1)
        np.subtract.at(left, owner[batch], 1)
        if area[found >= needed].sum() > area_limit * area.sum():
            return None
        open_parts = (found < needed) & (found + left >= needed)
    rough = found >= needed
    return None if area[rough].sum() > area_limit * area.sum() else rough


def _triangle_areas(triangles: np.ndarray) -> np.ndarray:
    """``(F,)`` the areas of ``(F, 3, 3)`` triangles."""
    return 0.5 * np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1)


_SIGN_BATCH = 256
"""Points whose side of the mesh :func:`_top_outward` settles at a time: a batch's winding numbers are the costly
part, so few are computed past the points the percentile needs (docs/decisions/2026-12-03-coacd-decomposition.md)."""


def _top_outward(mesh: trimesh.Trimesh, points: np.ndarray, count: int) -> np.ndarray:
    """``max(_outside_distance(mesh, points), 0)`` (n,), exact in its ``count`` largest values and no larger elsewhere:
    what a percentile needs, settling points farthest first."""
    distance = _surface_distance(mesh, points)
    outward = np.where(distance > 1e-9, 0.0, distance)  # on the surface the sign does not matter
    order = np.argsort(-distance, kind="stable")
    order = order[distance[order] > 1e-9]
    found = 0
    for start in range(0, len(order), _SIGN_BATCH):
        batch = order[start:start + _SIGN_BATCH]
        outside = batch[np.abs(_winding_number(mesh, points[batch])) <= 0.5]
        outward[outside] = distance[outside]
        found += len(outside)
        if found >= count:
            break
    return outward


@dataclass(frozen=True)
class _Union:
    """Convex parts as the slack measurements use them."""

    parts: list[tuple[np.ndarray, np.ndarray]]
    """``(vertices (v, 3) float64, faces (f, 3) int64)`` per part."""
    planes: list[tuple[np.ndarray, np.ndarray]]
    """Per part, its faces' unit outward normals ``(f, 3)`` and offsets ``(f,)`` (:func:`_face_planes`)."""
    boxes: np.ndarray
    """``(p, 2, 3)`` per part, the low and high corners of its vertices' bounding box, m."""

    @classmethod
    def of(cls, convex_parts) -> _Union:
        parts = [(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)) for v, f in convex_parts]
        boxes = np.array([(v.min(axis=0), v.max(axis=0)) for v, _ in parts])
        return cls(parts, [_face_planes(v, f) for v, f in parts], boxes)

    @property
    def triangles(self) -> np.ndarray:
        """``(F, 3, 3)`` all the parts' triangles."""
        return np.concatenate([v[f] for v, f in self.parts])


def _boundary_samples(union: _Union, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points drawn by area over all the parts' faces, less those whose face is buried in another part (a step
    of :data:`_SLACK_STEP` along the face's normal lands inside another part): ``(k, 3)``, k <= n."""
    owner = np.concatenate([np.full(len(f), i) for i, (_, f) in enumerate(union.parts)])
    normal = np.concatenate([n for n, _ in union.planes])
    points, pick = _area_samples(union.triangles, n, rng)
    return points[~_inside_parts(points + _SLACK_STEP * normal[pick], union, owner[pick])]


def _area_samples(tri: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points uniform by area on the triangles ``(F, 3, 3)``, and the triangle of each."""
    area = _triangle_areas(tri)
    pick = rng.choice(len(tri), size=n, p=area / area.sum())
    u, w = rng.random(n), rng.random(n)
    flip = u + w > 1.0
    u[flip], w[flip] = 1.0 - u[flip], 1.0 - w[flip]
    t = tri[pick]
    return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + w[:, None] * (t[:, 2] - t[:, 0]), pick


def _face_planes(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit outward normals (f, 3) and offsets (f,) of a convex part's faces: inside is ``n . x < d``. A face of no
    area has no plane; it is given its neighbours' (a normal of 0 would make every point lie on it)."""
    t = vertices[faces]
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    length = np.linalg.norm(n, axis=1)
    flat = length <= 1e-300
    if flat.all():  # no area: nothing is inside it
        return np.zeros((len(faces), 3)), np.full(len(faces), -np.inf)
    n = n / np.where(flat, 1.0, length)[:, None]
    n[flat] = n[~flat][0]  # a duplicate of a real plane: a no-op in the max
    d = np.einsum("ij,ij->i", n, t[:, 0])
    d[flat] = d[~flat][0]
    return n, d


def _inside_parts(points: np.ndarray, union: _Union, owner: np.ndarray | None,
                  tolerance: float = _INSIDE_TOLERANCE) -> np.ndarray:
    """Whether each point (n, 3) lies inside some part by more than ``tolerance`` (negative: within it of a part), not
    counting its own part ``owner`` (n,) (None: any part counts); tested only near each part's bounding box."""
    inside = np.zeros(len(points), dtype=bool)
    margin = max(0.0, -tolerance) + _BOX_MARGIN
    for j, (n, d) in enumerate(union.planes):
        low, high = union.boxes[j]
        test = ~inside & np.all((points >= low - margin) & (points <= high + margin), axis=1)
        if owner is not None:
            test &= owner != j
        idx = np.flatnonzero(test)
        if len(idx):
            inside[idx] = np.max(points[idx] @ n.T - d, axis=1) < -tolerance
    return inside


def _outside_distance(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Distance of each point from the mesh surface, positive outside the mesh, negative inside."""
    distance = _surface_distance(mesh, points)
    off = np.flatnonzero(distance > 1e-9)  # on the surface the sign does not matter
    inside = np.abs(_winding_number(mesh, points[off])) > 0.5
    distance[off[inside]] *= -1.0
    return distance


def _surface_distance(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Exact unsigned distance of each point from the mesh surface. Not ``trimesh.proximity.closest_point``: its 1e-8
    squared-distance tie rule may keep the farther triangle, an error of percents at millimetres."""
    candidates = trimesh.proximity.nearby_faces(mesh, points)  # a superset of each point's nearest triangles
    counts = np.array([len(c) for c in candidates])
    which = np.concatenate(candidates).astype(np.int64)
    query = np.repeat(points, counts, axis=0)
    nearest = trimesh.triangles.closest_point(np.asarray(mesh.triangles)[which], query)
    squared = np.einsum("ij,ij->i", query - nearest, query - nearest)
    return np.sqrt(np.minimum.reduceat(squared, np.concatenate([[0], np.cumsum(counts)[:-1]])))


def _winding_number(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Generalised winding number of the mesh at each point (1 inside a closed outward-wound mesh, 0 outside;
    Van Oosterom and Strackee's solid angle of each triangle, summed; chunked to bound memory)."""
    tri = np.asarray(mesh.triangles, dtype=np.float64)
    out = np.empty(len(points))
    chunk = max(1, 200_000 // max(len(tri), 1))
    for start in range(0, len(points), chunk):
        p = points[start:start + chunk]
        a, b, c = (tri[None, :, k, :] - p[:, None, :] for k in range(3))
        la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
        det = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("pfi,pfi->pf", a, b) * lc + np.einsum("pfi,pfi->pf", b, c) * la
               + np.einsum("pfi,pfi->pf", c, a) * lb)
        out[start:start + chunk] = np.arctan2(det, den).sum(axis=1) / (2.0 * np.pi)
    return out
