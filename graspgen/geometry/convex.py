"""Step 5 of mesh preparation: convex decomposition with CoACD (MuJoCo collides convex hulls), and its cache.

:func:`convex_decomposition` splits a mesh in m into convex parts, each ``(vertices (v, 3) float64 m, faces
(f, 3) int32)`` in the mesh frame. Decompositions can be cached on disk as ``coacd-<sha256>.npz``, keyed by the
mesh bytes, the :class:`CoacdParams` and the CoACD version.

:func:`hull_slack` (:mod:`graspgen.geometry.slack`, re-exported here) measures how far the union of the parts reaches
beyond the true surface (what MuJoCo collides with that the mesh does not have), to choose CoACD settings by
(``studies/hull_slack.py``).
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
from graspgen.geometry.slack import HullSlack, hull_slack, outward_slack_p95
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
    """Settings of the CoACD convex decomposition (passed straight to ``coacd.run_coacd``). The defaults are the
    objects stage's; ``gen evaluate`` uses :data:`graspgen.workflows.evaluate_settings.CHEAP_COACD`."""

    threshold: float = 0.08
    """Concavity threshold, dimensionless in (0, 1], relative to half the mesh's largest extent (CoACD normalises
    the mesh to its bounding box): lower gives more, tighter parts."""

    max_convex_hull: int = 16
    """Upper bound on the number of parts; -1 means no limit."""

    preprocess_resolution: int = 30
    """Voxel resolution (cells per axis) of the manifold pre-processing of non-watertight input."""

    resolution: int = 1000
    """Number of surface samples CoACD uses to measure concavity (CoACD takes at least 1000 where it scales them by
    area, so fewer saves little)."""

    mcts_iterations: int = 20
    """Monte-Carlo tree search iterations per cut: CoACD's search budget, which its time is about proportional to.
    20 of ``mcts_nodes`` 10 since issue 24 (50 of 20 before), judged by the hull-slack criterion on 17
    ../shared/learn meshes (``bench/bench_prep.py`` reports each mesh's p95 slack beside its time): as many meshes
    meet ``slack_p95`` as before (per mesh the randomised search moves p95 both ways, -0.5 to +1.4 mm), at 35-40 %
    less CoACD time on the refined bowls and 11 % less in all."""

    mcts_depth: int = 3
    """Maximum depth of the Monte-Carlo tree search (cuts looked ahead)."""

    mcts_nodes: int = 10
    """Child nodes expanded per Monte-Carlo tree search node (candidate cutting planes); 10 since issue 24 (20
    before), with ``mcts_iterations``."""

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
    return outward_slack_p95(mesh, parts, params.slack_samples, np.random.default_rng(params.seed))


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
