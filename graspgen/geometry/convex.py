"""Step 5 of mesh preparation: convex decomposition with CoACD (MuJoCo collides convex hulls), and its cache.

:func:`convex_decomposition` splits a mesh in m into convex parts, each ``(vertices (v, 3) float64 m, faces
(f, 3) int32)`` in the mesh frame; the cache ``coacd-<sha256>.npz`` is keyed by the mesh bytes, the
:class:`CoacdParams` and the CoACD version. :func:`hull_slack` is re-exported from :mod:`graspgen.geometry.slack`.
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

import numpy as np
import trimesh
from scipy.spatial import QhullError

from graspgen.errors import InputError
from graspgen.geometry import coacd_process
from graspgen.geometry.mesh_io import _check_mesh, _label
from graspgen.geometry.part_merge import ConvexPart, convex_part, merge_convex_parts
from graspgen.geometry.slack import HullSlack, hull_slack, outward_slack_p95, rough_parts
from graspgen.validation import check, check_choice, check_instance, check_number, check_positive_int

__all__ = ["CoacdParams", "HullSlack", "cached_convex_decomposition", "coacd_cache_key", "convex_decomposition",
           "hull_slack", "write_parts"]

_log = logging.getLogger(__name__)


# Bumped whenever the post-processing of CoACD output changes, so that stale cache entries miss (what each version
# changed: docs/decisions/2026-12-03-coacd-decomposition.md).
_COACD_CACHE_FORMAT = 5

# A mesh whose volume is within this fraction of its hull's volume is treated as convex.
_CONVEX_VOLUME_TOLERANCE = 1e-6

# CoACD parts below this fraction of the hull volume are slivers that only make MuJoCo's mesh compiler complain.
_MIN_PART_VOLUME_RATIO = 1e-6


_PREPROCESS_MODES = ("unless_watertight", "auto", "on", "off")

# The refinement's finer cut (CoacdParams.refine_excess), by how many pieces the first cut made per allowed part: a
# finer cut multiplies the pieces (docs/decisions/2026-12-03-coacd-decomposition.md), and beyond about four times the
# cap the merge back down to it bridges again what the cut separated.
_QUARTER_CUT_PIECES = 2
_HALF_CUT_PIECES = 4

# A piece of the first cut is rough when more of its surface than this stands over ``slack_p95`` outside the mesh:
# the share the p95 criterion allows the whole union, asked of each piece.
_ROUGH_SHARE = 0.05

# The refinement cuts the rough pieces alone where they hold at most this share of the first cut's area, else the whole
# mesh again: cheaper while they are a minority (docs/decisions/2026-12-03-coacd-child-process.md).
_ROUGH_AREA = 0.5


def _is_int(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


@dataclass(frozen=True)
class CoacdParams:
    """Settings of the CoACD convex decomposition (passed straight to ``coacd.run_coacd``). The defaults are the
    objects stage's; ``gen evaluate`` uses :data:`graspgen.workflows.evaluate_settings.CHEAP_COACD`."""

    threshold: float = 0.08
    """Concavity threshold, dimensionless in (0, 1], relative to half the mesh's largest extent (CoACD normalises
    the mesh to its bounding box): lower gives more, tighter parts."""

    max_convex_hull: int = 16
    """Upper bound on the number of parts (CoACD's pieces are merged down to it,
    :func:`graspgen.geometry.part_merge.merge_convex_parts`); -1 means no limit."""

    preprocess_resolution: int = 30
    """Voxel resolution (cells per axis) of the manifold pre-processing of non-watertight input."""

    resolution: int = 1000
    """Number of surface samples CoACD uses to measure concavity (CoACD takes at least 1000 where it scales them by
    area, so fewer saves little)."""

    mcts_iterations: int = 10
    """Monte-Carlo tree search iterations per cut (CoACD's search budget, >= 1). Why 10 of ``mcts_nodes`` 5: about
    the same slack as a larger search in less time (docs/decisions/2026-12-03-coacd-decomposition.md)."""

    mcts_depth: int = 3
    """Maximum depth of the Monte-Carlo tree search (cuts looked ahead, >= 1). Why not 2: its cuts leave more slack,
    so more meshes are refined (docs/decisions/2026-12-03-coacd-decomposition.md)."""

    mcts_nodes: int = 5
    """Child nodes expanded per Monte-Carlo tree search node (candidate cutting planes, >= 1); see
    ``mcts_iterations``."""

    seed: int = 0
    """CoACD's own random seed; the decomposition is a pure function of mesh, settings and this seed."""

    refine_excess: float = 0.01
    """Fraction (>= 0; 0: off) by which the parts' total volume may exceed the mesh's before, with a hull slack p95 over
    ``slack_p95``, the parts are refined: the rough pieces cut again alone, or the whole mesh cut at a finer threshold,
    keeping the parts of lowest slack. Parts bridging a concavity (a cup's cavity) make grasps on its rim collide
    (docs/decisions/2026-12-03-coacd-decomposition.md)."""

    preprocess_mode: str = "unless_watertight"
    """CoACD's manifold pre-processing (a voxel rebuild that dilates the mesh by about half a cell and is slow):
    ``"unless_watertight"`` skips it for a mesh watertight with consistent winding after repair and uses ``"auto"``
    otherwise; ``"auto"``, ``"on"`` and ``"off"`` are passed to CoACD. Another value raises :class:`SettingsError`."""

    slack_p95: float = 1e-3
    """Hull-slack criterion in m (p95 of how far the parts stand out of the surface, :func:`hull_slack`; half the
    fingers' 2 mm touch allowance): a near-convex mesh whose hull meets it is not decomposed, a decomposition meeting it
    is not refined."""

    near_convex_excess: float = 0.05
    """A watertight mesh whose convex hull exceeds its volume by at most this fraction is tested as near-convex:
    its hull alone is used if its slack meets ``slack_p95``. 0 only skips exactly convex meshes (1e-6)."""

    free_merge_depth: float = 2.5e-4
    """CoACD's neighbouring pieces are merged, shallowest first, while a pair's hull stands at most this far (m) outside
    its pieces (:func:`graspgen.geometry.part_merge.bridge_depth`), even below ``max_convex_hull``."""

    slack_samples: int = 4000
    """Area samples of each hull-slack measurement taken by the decision rules above (seeded from the
    settings' ``seed``: deterministic)."""

    def __post_init__(self) -> None:
        check_number("threshold", self.threshold, low=0.0, high=1.0, low_open=True)
        check_number("refine_excess", self.refine_excess, low=0.0)
        check_choice("preprocess_mode", self.preprocess_mode, _PREPROCESS_MODES)
        check_number("slack_p95", self.slack_p95, low=0.0, low_open=True)
        check_number("near_convex_excess", self.near_convex_excess, low=0.0)
        check_number("free_merge_depth", self.free_merge_depth, low=0.0)
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
    """Split a repaired mesh (m) into convex parts for collision.

    A convex mesh, or a near-convex one (hull volume excess <= ``near_convex_excess`` and hull slack p95 <=
    ``slack_p95``), gives its convex hull as the single part. Otherwise CoACD cuts it (its own merge off), each piece is
    replaced by its convex hull, slivers below 1e-6 of the hull volume dropped, and the pieces merged by bridge depth
    (:func:`graspgen.geometry.part_merge.merge_convex_parts`) to ``max_convex_hull`` and further while a merge costs at
    most ``free_merge_depth``; then refined as :attr:`CoacdParams.refine_excess` says. Parts are sorted by centroid and
    vertex count, independent of CoACD's internals; if every piece is dropped, the hull is the single part.

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
    with coacd_process.shared_process():  # the first cut and the refinement's: one CoACD process to start
        pieces = _coacd_pieces(mesh, hull, params, closed)
        if not pieces:
            _log.warning("%s: CoACD returned no usable part, using the convex hull", _label(mesh))
            return [_part_arrays(hull)]
        parts = _merged(pieces, params.max_convex_hull, params)
        if params.refine_excess > 0 and _volume_excess(mesh, parts) > params.refine_excess:
            slack = _slack_p95(mesh, parts, params)
            if slack > params.slack_p95:
                parts = _refined(mesh, hull, closed, pieces, (parts, slack), params)
    return [_part_arrays(part) for part in _sorted_parts(parts)]


def _refined(mesh: trimesh.Trimesh, hull: trimesh.Trimesh, closed: bool, pieces: list[ConvexPart],
             first: tuple[list[ConvexPart], float], params: CoacdParams) -> list[ConvexPart]:
    """The parts of lower slack of ``first`` (parts, slack p95) and the refinement tries (rough pieces recut, or the
    whole mesh cut at a quarter or half of the threshold, or the pieces merged again), each merged down to four times
    ``max_convex_hull``."""
    cap = -1 if params.max_convex_hull == -1 else 4 * params.max_convex_hull
    tries = {"first": first}
    if cap == -1 or len(pieces) <= _HALF_CUT_PIECES * params.max_convex_hull:
        rough = rough_parts(mesh, [_part_arrays(p) for p in pieces], params.slack_p95, _ROUGH_SHARE,
                            params.slack_samples, np.random.default_rng(params.seed), area_limit=_ROUGH_AREA)
        if rough is not None and rough.any():
            recut = _merged(_rough_pieces_recut(mesh, pieces, rough, params), cap, params)
            tries[f"{rough.sum()} rough of {len(pieces)} cut at 1/4"] = (recut, _slack_p95(mesh, recut, params))
        if min(slack for _, slack in tries.values()) > params.slack_p95:
            divisor = 4 if cap == -1 or len(pieces) <= _QUARTER_CUT_PIECES * params.max_convex_hull else 2
            finer = _coacd_pieces(mesh, hull, dataclasses.replace(params, threshold=params.threshold / divisor),
                                  closed)
            if finer:
                recut = _merged(finer, cap, params)
                tries[f"cut at 1/{divisor}"] = (recut, _slack_p95(mesh, recut, params))
    elif len(pieces) > params.max_convex_hull:
        # Only where no finer cut is affordable: a finer cut leaves less slack
        # (docs/decisions/2026-12-03-coacd-decomposition.md).
        remerged = _merged(pieces, cap, params)
        tries["merged again"] = (remerged, _slack_p95(mesh, remerged, params))
    best = min(tries, key=lambda name: tries[name][1])  # the first of equals: dicts keep their order
    _log.info("%s: %d pieces exceed the volume by %.0f%%, slack p95 %.2f mm; refined: %s, %.2f mm (of %s)",
              _label(mesh), len(pieces), 100 * _volume_excess(mesh, first[0]), 1e3 * first[1], best,
              1e3 * tries[best][1], ", ".join(tries))
    return tries[best][0]


def _rough_pieces_recut(mesh: trimesh.Trimesh, pieces: list[ConvexPart], rough: np.ndarray,
                        params: CoacdParams) -> list[ConvexPart]:
    """``pieces`` with each rough one (``rough (p,) bool``) replaced by CoACD's pieces of the mesh inside it, cut at the
    absolute concavity of a whole-mesh cut at a quarter of the threshold, in one CoACD process; a piece whose inside is
    empty or fails in CoACD is kept (logged)."""
    half_extent = float(np.max(np.ptp(mesh.vertices, axis=0))) / 2
    which, requests = [], []
    for i in np.flatnonzero(rough):
        inside = _mesh_inside(mesh, pieces[i])
        if inside is None:
            continue
        threshold = min(1.0, params.threshold / 4 * half_extent / (float(np.max(np.ptp(inside.vertices, axis=0))) / 2))
        which.append(i)
        requests.append((np.asarray(inside.vertices, dtype=np.float64), np.asarray(inside.faces, dtype=np.int32),
                         _coacd_kwargs(dataclasses.replace(params, threshold=threshold), closed=True)))
    recut = {i: answer for i, answer in zip(which, coacd_process.run_coacd_each(requests))}
    hull_volume = mesh.convex_hull.volume
    out = []
    for i, piece in enumerate(pieces):
        answer = recut.get(i)
        if isinstance(answer, InputError):
            _log.warning("%s: rough piece %d kept as it is: %s", _label(mesh), i, answer)
        out += (_usable(answer, hull_volume) if isinstance(answer, list) else []) or [piece]
    return out


def _mesh_inside(mesh: trimesh.Trimesh, piece: ConvexPart) -> trimesh.Trimesh | None:
    """The closed mesh of what of ``mesh`` lies inside the convex ``piece``, or None where that has no volume."""
    inside = trimesh.boolean.intersection(
        [mesh, trimesh.Trimesh(piece.vertices, piece.faces, process=False)], engine="manifold")
    if inside.is_empty or not inside.volume > 0:
        return None
    return inside


def _coacd_pieces(mesh: trimesh.Trimesh, hull: trimesh.Trimesh, params: CoacdParams,
                  closed: bool) -> list[ConvexPart]:
    """CoACD's pieces as convex hulls, slivers dropped (:func:`_usable`)."""
    return _usable(_run_coacd(mesh, params, closed), hull.volume)


def _usable(pieces: list, hull_volume: float) -> list[ConvexPart]:
    """CoACD's ``(vertices, faces)`` pieces as convex hulls, those with none or below 1e-6 of ``hull_volume`` (the
    mesh's hull's, m^3) dropped."""
    hulls = [_convex_part(vertices, faces) for vertices, faces in pieces]
    return [h for h in hulls if h is not None and h.volume > _MIN_PART_VOLUME_RATIO * hull_volume]


def _merged(pieces: list[ConvexPart], cap: int, params: CoacdParams) -> list[ConvexPart]:
    """``pieces`` merged down to ``cap`` parts (-1: no bound) and while a merge costs at most
    ``params.free_merge_depth``, each part as its convex hull."""
    merged = merge_convex_parts([p.vertices for p in pieces], cap, params.free_merge_depth)
    return [convex_part(points) for points in merged]


def _is_closed(mesh: trimesh.Trimesh) -> bool:
    """Watertight, consistently wound and of positive volume: a closed 2-manifold surface (up to self-contact)."""
    return bool(mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0)


def _near_convex(mesh: trimesh.Trimesh, hull: trimesh.Trimesh, params: CoacdParams) -> bool:
    """Whether the hull alone is within the slack criterion (tested only when its volume excess is small: the
    slack measurement costs about as much as a cheap decomposition)."""
    if params.near_convex_excess <= 0 or hull.volume > (1.0 + params.near_convex_excess) * mesh.volume:
        return False
    return _slack_p95(mesh, [_part_arrays(hull)], params) <= params.slack_p95


def _slack_p95(mesh: trimesh.Trimesh, parts: list, params: CoacdParams) -> float:
    """p95 hull slack (m) of the parts (``(vertices, faces)`` pairs or :class:`ConvexPart`), from a generator seeded
    by the settings (the same parts: the same value)."""
    arrays = [_part_arrays(p) if isinstance(p, ConvexPart) else p for p in parts]
    return outward_slack_p95(mesh, arrays, params.slack_samples, np.random.default_rng(params.seed))


def _volume_excess(mesh: trimesh.Trimesh, parts: list[ConvexPart]) -> float:
    """How much the parts' summed volume exceeds the mesh's, as a fraction (0 for an open mesh: not measurable)."""
    if not mesh.is_watertight or mesh.volume <= 0:
        return 0.0
    return float(sum(p.volume for p in parts) / mesh.volume - 1.0)


def _is_convex(mesh: trimesh.Trimesh, hull: trimesh.Trimesh) -> bool:
    return abs(hull.volume - mesh.volume) <= _CONVEX_VOLUME_TOLERANCE * abs(hull.volume)


def _run_coacd(mesh: trimesh.Trimesh, params: CoacdParams, closed: bool) -> list:
    try:
        return coacd_process.run_coacd(np.asarray(mesh.vertices, dtype=np.float64),
                                       np.asarray(mesh.faces, dtype=np.int32), **_coacd_kwargs(params, closed))
    except InputError as exc:
        raise type(exc)(f"{_label(mesh)}: {exc}") from None


def _coacd_kwargs(params: CoacdParams, closed: bool) -> dict:
    """``coacd.run_coacd``'s keyword arguments for ``params`` and a mesh that is ``closed`` or not."""
    mode = params.preprocess_mode
    if mode == "unless_watertight":
        mode = "off" if closed else "auto"
    return dict(
        threshold=params.threshold,
        max_convex_hull=-1,
        merge=False,  # merge_convex_parts merges, at a fraction of the cost of CoACD's all-pairs merge
        preprocess_mode=mode,
        preprocess_resolution=params.preprocess_resolution,
        resolution=params.resolution,
        mcts_nodes=params.mcts_nodes,
        mcts_iterations=params.mcts_iterations,
        mcts_max_depth=params.mcts_depth,
        seed=params.seed,
    )


def _convex_part(vertices: np.ndarray, faces: np.ndarray) -> ConvexPart | None:
    """The convex hull of one CoACD piece, or None when qhull cannot make one (flat, collinear, infinite or NaN points);
    anything else propagates."""
    if len(vertices) < 4:
        return None
    try:
        return convex_part(vertices)
    except (QhullError, ValueError) as exc:
        _log.debug("dropping a CoACD piece with no convex hull (%s: %s)", type(exc).__name__, exc)
        return None


def _sorted_parts(parts: list[ConvexPart]) -> list[ConvexPart]:
    centroids = np.array([part.vertices.mean(axis=0) for part in parts])
    counts = np.array([len(part.vertices) for part in parts])
    order = np.lexsort((counts, centroids[:, 2], centroids[:, 1], centroids[:, 0]))
    return [parts[i] for i in order]


def _part_arrays(part: trimesh.Trimesh | ConvexPart) -> tuple[np.ndarray, np.ndarray]:
    return (
        np.ascontiguousarray(part.vertices, dtype=np.float64),
        np.ascontiguousarray(part.faces, dtype=np.int32),
    )


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
"""What ``np.load`` and the reads above raise on a damaged cache entry."""


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
