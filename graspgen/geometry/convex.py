"""Step 5 of mesh preparation: convex decomposition with CoACD (MuJoCo collides convex hulls), and its cache.

:func:`convex_decomposition` splits a mesh in m into convex parts, each ``(vertices (v, 3) float64 m, faces
(f, 3) int32)`` in the mesh frame. Decompositions can be cached on disk as ``coacd-<sha256>.npz``, keyed by the
mesh bytes, the :class:`CoacdParams` and the CoACD version.

:func:`hull_slack` measures how far the union of the parts reaches beyond the true surface (what MuJoCo collides
with that the mesh does not have), to choose CoACD settings by (``studies/hull_slack.py``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.metadata
import json
import logging
import os
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import coacd
import numpy as np
import trimesh
from scipy.spatial import QhullError

from graspgen.geometry.mesh_io import _check_mesh, _label
from graspgen.validation import check, check_choice, check_instance, check_number, check_positive_int

__all__ = ["CoacdParams", "HullSlack", "cached_convex_decomposition", "coacd_cache_key", "convex_decomposition",
           "hull_slack", "write_parts"]

_log = logging.getLogger(__name__)


# Bumped whenever the post-processing of CoACD output changes, so that stale cache entries miss.
_COACD_CACHE_FORMAT = 2  # 2: pre-processing skipped for watertight meshes, near-convex skip, slack-judged refine

# A mesh whose volume is within this fraction of its hull's volume is treated as convex.
_CONVEX_VOLUME_TOLERANCE = 1e-6

# CoACD parts below this fraction of the hull volume are slivers that only make MuJoCo's mesh compiler complain.
_MIN_PART_VOLUME_RATIO = 1e-6


_PREPROCESS_MODES = ("unless_watertight", "auto", "on", "off")


def _is_int(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


@dataclass(frozen=True)
class CoacdParams:
    """Settings of the CoACD convex decomposition (passed straight to ``coacd.run_coacd``)."""

    threshold: float = 0.08
    """Concavity threshold, dimensionless in (0, 1]: lower gives more, tighter parts."""

    max_convex_hull: int = 16
    """Upper bound on the number of parts; -1 means no limit."""

    preprocess_resolution: int = 30
    """Voxel resolution (cells per axis) of the manifold pre-processing of non-watertight input."""

    resolution: int = 1000
    """Number of surface samples CoACD uses to measure concavity."""

    mcts_iterations: int = 50
    """Monte-Carlo tree search iterations per cut."""

    mcts_depth: int = 3
    """Maximum depth of the Monte-Carlo tree search (cuts looked ahead)."""

    mcts_nodes: int = 20
    """Child nodes expanded per Monte-Carlo tree search node."""

    seed: int = 0
    """CoACD's own random seed; the decomposition is a pure function of mesh, settings and this seed."""

    refine_excess: float = 0.1
    """If the parts' total volume exceeds the mesh's by more than this fraction, they may bridge a concavity the
    gripper could reach (a thin-walled cup or bowl: parts filling its cavity make every grasp on its rim collide);
    if their hull slack (p95, :func:`hull_slack`) is also over ``slack_p95``, the mesh is decomposed once more with
    a quarter of the threshold and four times ``max_convex_hull``, and the result of lower slack kept. 0 turns
    this off."""

    preprocess_mode: str = "unless_watertight"
    """CoACD's manifold pre-processing (rebuilding the mesh as a level set on a voxel grid of
    ``preprocess_resolution`` cells, which dilates it by about half a cell and, measured on ShapeNet mugs and
    bottles, costs 75-95 % of the decomposition's time): ``"unless_watertight"`` skips it for a mesh that is
    watertight with consistent winding after repair (already a closed 2-manifold, as CoACD's authors advise
    for such input) and leaves it to CoACD's own check (``"auto"``) otherwise; ``"auto"``, ``"on"`` and
    ``"off"`` are passed to CoACD as they are."""

    slack_p95: float = 1e-3
    """Hull-slack criterion in m (95th percentile of how far the parts' union stands out of the surface,
    :func:`hull_slack`; half the fingers' 2 mm touch allowance, ``studies/hull_slack.py``): a near-convex mesh
    whose own convex hull meets it is not decomposed, and a decomposition meeting it is not refined."""

    near_convex_excess: float = 0.05
    """A watertight mesh whose convex hull exceeds its volume by at most this fraction is tested as near-convex:
    its hull alone is used if its slack meets ``slack_p95``. 0 only skips exactly convex meshes (1e-6)."""

    slack_samples: int = 4000
    """Area samples of each hull-slack measurement taken by the decision rules above (seeded from the
    settings' ``seed``: deterministic)."""

    def __post_init__(self) -> None:
        check_number("threshold", self.threshold, low=0.0, high=1.0, low_open=True)
        check_number("refine_excess", self.refine_excess, low=0.0)
        check_choice("preprocess_mode", self.preprocess_mode, _PREPROCESS_MODES)
        check_number("slack_p95", self.slack_p95, low=0.0, low_open=True)
        check_number("near_convex_excess", self.near_convex_excess, low=0.0)
        check_positive_int("slack_samples", self.slack_samples)
        hulls = self.max_convex_hull
        check("max_convex_hull", _is_int(hulls) and (hulls >= 1 or hulls == -1), "be a positive integer or -1", hulls)
        check_positive_int("preprocess_resolution", self.preprocess_resolution)
        check_positive_int("resolution", self.resolution)
        check_positive_int("mcts_iterations", self.mcts_iterations)
        check_positive_int("mcts_depth", self.mcts_depth)
        check_positive_int("mcts_nodes", self.mcts_nodes)
        check("seed", _is_int(self.seed) and 0 <= self.seed < 2**31, "be an integer in [0, 2**31)", self.seed)

    def to_json(self) -> str:
        """Canonical JSON of the settings (sorted keys), used in the CoACD cache key."""
        return json.dumps(dataclasses.asdict(self), sort_keys=True)


def convex_decomposition(mesh: trimesh.Trimesh, params: CoacdParams) -> list[tuple[np.ndarray, np.ndarray]]:
    """Split a mesh into convex parts for collision.

    A watertight mesh whose volume equals its convex hull's within 1e-6 (relative) is already convex, and one
    whose hull exceeds its volume by at most ``params.near_convex_excess`` and stands out of it by at most
    ``params.slack_p95`` (p95 hull slack, :func:`hull_slack`) is convex as far as a gripper can tell; CoACD would
    only re-approximate either, so its hull is returned as the single part. Otherwise CoACD runs with ``params``
    (its manifold pre-processing as ``params.preprocess_mode`` says); each part is replaced by its own convex hull
    (CoACD's output is not always exactly convex and MuJoCo needs it to be), parts below 1e-6 of the hull volume
    are dropped, and the rest are sorted by centroid (x, then y, then z) and vertex count so that the order does
    not depend on CoACD internals. If every part is dropped, the mesh's convex hull is the single part. Parts
    exceeding the volume by more than ``params.refine_excess`` with a slack over ``params.slack_p95`` are
    refined once (see :class:`CoacdParams`).

    Parameters
    ----------
    mesh
        Repaired mesh in m.
    params
        CoACD settings.

    Returns
    -------
    list of (vertices, faces)
        ``vertices (v, 3) float64`` in m, mesh frame; ``faces (f, 3) int32``, outward-wound.
    """
    _check_mesh(mesh, "mesh")
    check_instance("params", params, CoacdParams)
    hull = mesh.convex_hull
    closed = _is_closed(mesh)
    if closed and (_is_convex(mesh, hull) or _near_convex(mesh, hull, params)):
        return [_part_arrays(hull)]
    result, excess = _decompose(mesh, hull, params, closed)
    if params.refine_excess > 0 and excess > params.refine_excess:
        slack = _slack_p95(mesh, result, params)
        if slack > params.slack_p95:
            finer = dataclasses.replace(
                params,
                threshold=params.threshold / 4,
                max_convex_hull=-1 if params.max_convex_hull == -1 else 4 * params.max_convex_hull,
                refine_excess=0.0,
            )
            refined, _ = _decompose(mesh, hull, finer, closed)
            refined_slack = _slack_p95(mesh, refined, params)
            _log.info("%s: parts exceed the volume by %.0f%%, slack p95 %.2f mm; refined: %.2f mm", _label(mesh),
                      100 * excess, 1e3 * slack, 1e3 * refined_slack)
            if refined_slack < slack:
                return refined
    return result


def _decompose(mesh: trimesh.Trimesh, hull: trimesh.Trimesh, params: CoacdParams,
               closed: bool) -> tuple[list[tuple[np.ndarray, np.ndarray]], float]:
    """CoACD's parts as sorted convex hulls (slivers dropped; the mesh's hull if none is left), and their volume
    excess over the mesh (:func:`_volume_excess`)."""
    raw = _run_coacd(mesh, params, closed)
    parts = [_convex_part(vertices, faces) for vertices, faces in raw]
    min_volume = _MIN_PART_VOLUME_RATIO * hull.volume
    kept = [part for part in parts if part is not None and part.volume > min_volume]
    if not kept:
        _log.warning("%s: CoACD returned no usable part, using the convex hull", _label(mesh))
        return [_part_arrays(hull)], 0.0
    return [_part_arrays(part) for part in _sorted_parts(kept)], _volume_excess(mesh, kept)


def _is_closed(mesh: trimesh.Trimesh) -> bool:
    """Watertight, consistently wound and of positive volume: a closed 2-manifold surface (up to self-contact)."""
    return bool(mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0)


def _near_convex(mesh: trimesh.Trimesh, hull: trimesh.Trimesh, params: CoacdParams) -> bool:
    """Whether the hull alone is within the slack criterion (tested only when its volume excess is small: the
    slack measurement costs about as much as a cheap decomposition)."""
    if params.near_convex_excess <= 0 or hull.volume > (1.0 + params.near_convex_excess) * mesh.volume:
        return False
    return _slack_p95(mesh, [_part_arrays(hull)], params) <= params.slack_p95


def _slack_p95(mesh: trimesh.Trimesh, parts: list[tuple[np.ndarray, np.ndarray]], params: CoacdParams) -> float:
    """p95 hull slack (m) of the parts, from a generator seeded by the settings (the same parts: the same value)."""
    return hull_slack(mesh, parts, params.slack_samples, np.random.default_rng(params.seed)).p95


def _volume_excess(mesh: trimesh.Trimesh, parts: list[trimesh.Trimesh]) -> float:
    """How much the parts' summed volume exceeds the mesh's, as a fraction (0 for an open mesh: not measurable)."""
    if not mesh.is_watertight or mesh.volume <= 0:
        return 0.0
    return float(sum(p.volume for p in parts) / mesh.volume - 1.0)


def _is_convex(mesh: trimesh.Trimesh, hull: trimesh.Trimesh) -> bool:
    return abs(hull.volume - mesh.volume) <= _CONVEX_VOLUME_TOLERANCE * abs(hull.volume)


def _run_coacd(mesh: trimesh.Trimesh, params: CoacdParams, closed: bool) -> list:
    # CoACD logs every iteration to stdout by default, which would drown the pipeline's own output.
    coacd.set_log_level("error")
    mode = params.preprocess_mode
    if mode == "unless_watertight":
        mode = "off" if closed else "auto"
    return coacd.run_coacd(
        coacd.Mesh(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int32)),
        threshold=params.threshold,
        max_convex_hull=params.max_convex_hull,
        preprocess_mode=mode,
        preprocess_resolution=params.preprocess_resolution,
        resolution=params.resolution,
        mcts_nodes=params.mcts_nodes,
        mcts_iterations=params.mcts_iterations,
        mcts_max_depth=params.mcts_depth,
        seed=params.seed,
    )


def _convex_part(vertices: np.ndarray, faces: np.ndarray) -> trimesh.Trimesh | None:
    """The convex hull of one CoACD part, or None when qhull cannot make one.

    A flat or collinear part does not raise (trimesh retries qhull with joggle, ``QJ``, and returns a hull of no
    volume, which the caller drops with the other slivers); qhull still raises ``QhullError`` on points it cannot
    handle (an infinite coordinate) and scipy a ``ValueError`` on NaN. Anything else is a bug and propagates.
    """
    if len(vertices) < 4:
        return None
    try:
        return trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(faces), process=False).convex_hull
    except (QhullError, ValueError) as exc:
        _log.debug("dropping a CoACD part with no convex hull (%s: %s)", type(exc).__name__, exc)
        return None


def _sorted_parts(parts: list[trimesh.Trimesh]) -> list[trimesh.Trimesh]:
    centroids = np.array([part.vertices.mean(axis=0) for part in parts])
    counts = np.array([len(part.vertices) for part in parts])
    order = np.lexsort((counts, centroids[:, 2], centroids[:, 1], centroids[:, 0]))
    return [parts[i] for i in order]


def _part_arrays(part: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    return (
        np.ascontiguousarray(part.vertices, dtype=np.float64),
        np.ascontiguousarray(part.faces, dtype=np.int32),
    )


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
    """The other way round: largest distance from the union of a point of the mesh's surface outside every part
    (sampled points and the mesh's vertices), i.e. how far the parts fall short of the surface; 0 when they
    cover it."""
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


def hull_slack(
    mesh: trimesh.Trimesh,
    convex_parts: list[tuple[np.ndarray, np.ndarray]] | tuple[tuple[np.ndarray, np.ndarray], ...],
    n_samples: int,
    rng: np.random.Generator,
) -> HullSlack:
    """How far the union of ``convex_parts`` extends beyond the surface of ``mesh`` (and falls short of it).

    MuJoCo collides the parts, not the mesh, so wherever the union stands out of the mesh a gripper touches what
    is not there (a coarse hull thickening a thin wall, or bridging a cavity). Measured on the union's boundary,
    the surface a gripper coming from outside meets first: ``n_samples`` points are drawn uniformly by area over
    all the parts' faces (``rng``), and a point is dropped when a step of 10 um along its face's outward normal
    lands strictly inside another part (that face is buried in the union, e.g. the cut between two parts). Each
    kept point's slack is its unsigned distance to the mesh surface if it lies outside the mesh, else 0; inside
    vs outside by the generalised winding number of the mesh (robust also for a mesh with small holes). The
    maximum also takes the parts' vertices that are on the boundary (a hull's corners are where it usually stands
    out furthest); the 95th percentile is over the area samples only. The maximum of a sample falls short of the
    true one by up to about the samples' spacing where the farthest point is not a vertex (the middle of a hull's
    face bridging a cavity).

    The converse (``short_*``): ``n_samples`` points drawn by area over the mesh's surface, with its vertices for
    the maximum; a point inside a part is covered (0), else its distance to the union is its distance to the
    nearest part's surface. Parts falling short let a finger into the object by that much. (Gaps between parts
    deep inside the object do not count: they are not on the surface.)

    Parameters
    ----------
    mesh
        The true surface (m), e.g. the repaired mesh the parts were made from.
    convex_parts
        ``(vertices (v, 3), faces (f, 3))`` per part, outward-wound convex hulls (:func:`convex_decomposition`).
    n_samples
        Area samples over all parts, and as many over the mesh (e.g. 20,000: the percentiles' sampling error is
        then well below 0.1 mm on objects of grasping size).
    rng
        Random generator of the sample points.

    Returns
    -------
    HullSlack
    """
    _check_mesh(mesh, "mesh")
    check_positive_int("n_samples", n_samples)
    check("convex_parts", len(convex_parts) > 0, "hold at least one part", len(convex_parts))
    parts = [(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)) for v, f in convex_parts]
    planes = [_face_planes(v, f) for v, f in parts]

    tri = np.concatenate([v[f] for v, f in parts])  # (F, 3, 3) all the parts' triangles
    owner = np.concatenate([np.full(len(f), i) for i, (_, f) in enumerate(parts)])
    normal = np.concatenate([n for n, _ in planes])
    points, pick = _area_samples(tri, n_samples, rng)
    keep = ~_inside_parts(points + _SLACK_STEP * normal[pick], planes, owner[pick])
    points = points[keep]
    corners = np.concatenate([v for v, _ in parts])
    corner_owner = np.concatenate([np.full(len(v), i) for i, (v, _) in enumerate(parts)])
    corners = corners[~_inside_parts(corners, planes, corner_owner)]
    slack = np.maximum(_outside_distance(mesh, np.concatenate([points, corners])), 0.0)

    surface, _ = _area_samples(np.asarray(mesh.triangles, dtype=np.float64), n_samples, rng)
    surface = np.concatenate([surface, np.asarray(mesh.vertices, dtype=np.float64)])
    short = np.zeros(len(surface))
    bare = np.flatnonzero(~_inside_parts(surface, planes, None, tolerance=-_INSIDE_TOLERANCE))
    if len(bare):  # outside every part: the distance to the union is the distance to the nearest part's surface
        union = trimesh.Trimesh(tri.reshape(-1, 3), np.arange(3 * len(tri)).reshape(-1, 3), process=False)
        short[bare] = _surface_distance(union, surface[bare])

    return HullSlack(
        max=float(np.max(slack, initial=0.0)),
        p95=float(np.percentile(slack[: len(points)], 95)) if len(points) else 0.0,
        short_max=float(np.max(short, initial=0.0)),
        short_p95=float(np.percentile(short[:n_samples], 95)),
        samples=int(len(points)),
    )


def _area_samples(tri: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points uniform by area on the triangles ``(F, 3, 3)``, and the triangle of each."""
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
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


def _inside_parts(points: np.ndarray, planes: list[tuple[np.ndarray, np.ndarray]], owner: np.ndarray | None,
                  tolerance: float = _INSIDE_TOLERANCE) -> np.ndarray:
    """Whether each point lies inside some part by more than ``tolerance`` (a negative one: within it of a part),
    not counting its own part (``owner``; None: any part counts)."""
    inside = np.zeros(len(points), dtype=bool)
    for j, (n, d) in enumerate(planes):
        others = np.ones(len(points), dtype=bool) if owner is None else owner != j
        if others.any():
            inside[others] |= np.max(points[others] @ n.T - d, axis=1) < -tolerance
    return inside


def _outside_distance(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Distance of each point from the mesh surface, positive outside the mesh, negative inside."""
    distance = _surface_distance(mesh, points)
    off = np.flatnonzero(distance > 1e-9)  # on the surface the sign does not matter
    inside = np.abs(_winding_number(mesh, points[off])) > 0.5
    distance[off[inside]] *= -1.0
    return distance


def _surface_distance(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Unsigned distance of each point from the mesh surface (exact: the nearest of the candidate triangles).

    Not ``trimesh.proximity.closest_point``: it treats two candidates whose *squared* distances differ by less than
    1e-8 as a tie and may keep the farther one, which at millimetres (squared: 1e-6 m^2) is an error of percents.
    """
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


def coacd_cache_key(mesh: trimesh.Trimesh, params: CoacdParams) -> str:
    """The hex sha256 naming a decomposition in the cache: the mesh's vertices and faces, the settings and the
    cache format."""
    digest = hashlib.sha256()
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int32)
    header = {
        "format": _COACD_CACHE_FORMAT,
        "coacd": _package_version("coacd"),
        "vertices": list(vertices.shape),
        "faces": list(faces.shape),
    }
    digest.update(json.dumps(header, sort_keys=True).encode())
    digest.update(vertices.tobytes())
    digest.update(faces.tobytes())
    digest.update(params.to_json().encode())
    return digest.hexdigest()


def _package_version(name: str) -> str:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def cached_convex_decomposition(
    mesh: trimesh.Trimesh, params: CoacdParams, cache_dir: Path | None
) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`convex_decomposition` through the cache in ``cache_dir`` (keyed by :func:`coacd_cache_key`; None
    disables it); a corrupt entry is recomputed and overwritten. Returns ``[(vertices (v, 3), faces (f, 3)), ...]``."""
    if cache_dir is None:
        return convex_decomposition(mesh, params)
    path = cache_dir / f"coacd-{coacd_cache_key(mesh, params)}.npz"
    parts = _read_parts(path)
    if parts is not None:
        return parts
    parts = convex_decomposition(mesh, params)
    write_parts(path, parts)
    return parts


def _read_parts(path: Path) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """Parts stored at ``path``, or None when absent or unreadable (a bad entry is recomputed, not fatal)."""
    if not path.is_file():
        return None
    try:
        # Our own handle: np.load leaks the one it opens when the zip is damaged (a ResourceWarning).
        with open(path, "rb") as f, np.load(f, allow_pickle=False) as data:
            count = int(data["count"])
            return [
                (data[f"vertices_{i}"].astype(np.float64), data[f"faces_{i}"].astype(np.int32)) for i in range(count)
            ]
    except _UNREADABLE_CACHE as exc:
        _log.warning("%s: unreadable CoACD cache entry, recomputing (%s: %s)", path, type(exc).__name__, exc)
        return None


_UNREADABLE_CACHE = (OSError, EOFError, ValueError, KeyError, TypeError, zipfile.BadZipFile)
"""What ``np.load`` and the reads above raise on a damaged entry: OSError (unreadable), EOFError (empty),
BadZipFile (truncated, or a failed CRC), ValueError (not an npz: it looks like pickled data), KeyError (a part
missing), TypeError (a plain .npy, or a ``count`` that is not a scalar)."""


def write_parts(path: Path, parts: list[tuple[np.ndarray, np.ndarray]]) -> None:
    """Write convex parts ``[(vertices (v, 3), faces (f, 3)), ...]`` to the ``.npz`` cache file ``path``
    atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, np.ndarray] = {"count": np.array(len(parts))}
    for i, (vertices, faces) in enumerate(parts):
        arrays[f"vertices_{i}"] = vertices
        arrays[f"faces_{i}"] = faces
    # Same folder as the target so os.replace is an atomic rename: a concurrent reader sees all or nothing.
    handle = tempfile.NamedTemporaryFile(dir=path.parent, prefix=path.name + ".", suffix=".tmp", delete=False)
    try:
        with handle:
            np.savez(handle, **arrays)
        os.replace(handle.name, path)
    except BaseException:
        Path(handle.name).unlink(missing_ok=True)
        raise
