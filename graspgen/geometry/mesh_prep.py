"""Turn one object mesh file into everything the later stages need.

The steps, in the order :func:`prepare_object` runs them:

1. :func:`load_mesh` reads OBJ/STL/PLY/GLB/OFF and rejects broken files with an :class:`InputError`.
2. :func:`repair_mesh` merges vertices, drops degenerate/duplicate faces, fixes winding and fills small holes.
3. :func:`normalize_units` brings the mesh to metres (explicit scale, or a documented guess) and rejects
   absurd sizes.
4. :func:`mass_properties` integrates mass, centre of mass and inertia for a given density.
5. :func:`convex_decomposition` splits the mesh into convex parts with CoACD (MuJoCo collides convex hulls).
6. :func:`stable_poses` finds resting poses on a table and checks them in a short MuJoCo drop.

Every function is deterministic: the same inputs and the same ``rng`` seed give bitwise identical arrays.
Randomness only ever comes from the ``numpy.random.Generator`` passed in.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.metadata
import json
import logging
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import coacd
import mujoco
import numpy as np
import trimesh
import trimesh.poses

from graspgen.errors import InputError

__all__ = [
    "CoacdParams",
    "StablePoseParams",
    "RepairReport",
    "MassProperties",
    "PreparedObject",
    "SUPPORTED_SUFFIXES",
    "load_mesh",
    "repair_mesh",
    "normalize_units",
    "mass_properties",
    "convex_decomposition",
    "build_settle_model",
    "settle_pose",
    "resting_transform",
    "stable_poses",
    "prepare_object",
]

_log = logging.getLogger(__name__)

SUPPORTED_SUFFIXES = (".obj", ".stl", ".ply", ".glb", ".gltf", ".off")
"""File name endings :func:`load_mesh` accepts (case-insensitive)."""

# Bumped whenever the post-processing of CoACD output changes, so that stale cache entries miss.
_COACD_CACHE_FORMAT = 1

# A face counts as degenerate when its area is below this fraction of (largest extent)^2: a purely absolute
# threshold would call every face of a millimetre-scale mesh given in metres degenerate, or none of a huge one.
_DEGENERATE_AREA_RATIO = 1e-14

# Volumes below this fraction of (largest extent)^3 are "zero": a thin plate 1/1000 as thick as it is wide is
# still 1e-3, so this only catches flat or inside-out meshes.
_ZERO_VOLUME_RATIO = 1e-9

# Vertices whose smallest principal spread is below this fraction of the largest lie in one plane.
_FLAT_RATIO = 1e-9

# Numerical noise in the integrated inertia (a flat plate sits exactly on the triangle inequality) is repaired
# up to this fraction of the trace; anything larger means the mesh itself is inconsistent.
_INERTIA_FIX_TOLERANCE = 1e-6

# A mesh whose volume is within this fraction of its hull's volume is treated as convex.
_CONVEX_VOLUME_TOLERANCE = 1e-6

# CoACD parts below this fraction of the hull volume are slivers that only make MuJoCo's mesh compiler complain.
_MIN_PART_VOLUME_RATIO = 1e-6

# Drop height for the settle check: enough that no contact starts in penetration, small enough not to bounce.
_SETTLE_DROP_HEIGHT = 1e-3  # m

# After settling, an object moving slower than this has not toppled. The limits are loose on purpose: a
# faceted solid of revolution on its side (a can, a cone) keeps rolling slowly after the 1 mm drop because
# nothing but facet edges resists rolling, yet it is resting on its side; its settled face is taken as its pose.
# A body still faster than this after settle_time is tumbling off its pose.
_REST_LINEAR_SPEED = 2e-2  # m/s
_REST_ANGULAR_SPEED = 0.3  # rad/s

# Candidate normals from different centre-of-mass samples closer than this are the same face; trimesh itself
# rounds normals to 3 decimals for the same purpose.
_SAME_FACE_ANGLE = 1e-3  # rad
# Candidate poses whose centre of mass rests at heights within this are one pose class (see
# _select_pose_classes): a cylinder's side facets, a box's opposite faces.
_SAME_HEIGHT = 5e-4  # m


# ---------------------------------------------------------------------------------------------------------------
# Argument checks (programmer errors -> ValueError naming the argument)
# ---------------------------------------------------------------------------------------------------------------


def _is_int(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _check_positive_int(name: str, value: object) -> None:
    if not _is_int(value) or value < 1:
        raise ValueError(f"{name}: must be a positive integer, got {value!r}")


def _check_number(
    name: str,
    value: object,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
) -> None:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name}: must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{name}: must be finite, got {value!r}")
    too_low = low is not None and (value <= low if low_open else value < low)
    too_high = high is not None and (value >= high if high_open else value > high)
    if too_low or too_high:
        left = "(" if low_open else "["
        right = ")" if high_open else "]"
        low_text = "-inf" if low is None else f"{low:g}"
        high_text = "inf" if high is None else f"{high:g}"
        raise ValueError(f"{name}: must be in {left}{low_text}, {high_text}{right}, got {value!r}")


def _check_mesh(mesh: object, name: str) -> None:
    if not isinstance(mesh, trimesh.Trimesh):
        raise ValueError(f"{name}: must be a trimesh.Trimesh, got {type(mesh).__name__}")
    if len(mesh.faces) == 0:
        raise ValueError(f"{name}: has no faces")


def _check_rng(rng: object) -> None:
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng: must be a numpy.random.Generator, got {type(rng).__name__}")


def _check_parts(parts: object, name: str) -> None:
    if len(parts) == 0:
        raise ValueError(f"{name}: needs at least one convex part")
    for i, part in enumerate(parts):
        vertices, faces = part
        if np.ndim(vertices) != 2 or np.shape(vertices)[1] != 3 or np.ndim(faces) != 2 or np.shape(faces)[1] != 3:
            raise ValueError(f"{name}[{i}]: must be (vertices (v, 3), faces (f, 3))")


def _freeze(*arrays: np.ndarray) -> None:
    for array in arrays:
        if isinstance(array, np.ndarray):
            array.setflags(write=False)


def _label(mesh: trimesh.Trimesh) -> str:
    """How messages name a mesh: its file name when :func:`load_mesh` recorded one."""
    metadata = getattr(mesh, "metadata", None) or {}
    return str(metadata.get("file_name") or metadata.get("file_path") or "mesh")


# ---------------------------------------------------------------------------------------------------------------
# Settings
# ---------------------------------------------------------------------------------------------------------------


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
    """If the parts' total volume exceeds the mesh's by more than this fraction, they bridge a concavity the
    gripper could reach (a thin-walled cup or bowl: parts filling its cavity make every grasp on its rim collide),
    so the mesh is decomposed once more with a quarter of the threshold and four times ``max_convex_hull``, and
    the tighter result kept. 0 turns this off."""

    def __post_init__(self) -> None:
        _check_number("threshold", self.threshold, low=0.0, high=1.0, low_open=True)
        _check_number("refine_excess", self.refine_excess, low=0.0)
        if not _is_int(self.max_convex_hull) or (self.max_convex_hull < 1 and self.max_convex_hull != -1):
            raise ValueError(f"max_convex_hull: must be a positive integer or -1, got {self.max_convex_hull!r}")
        _check_positive_int("preprocess_resolution", self.preprocess_resolution)
        _check_positive_int("resolution", self.resolution)
        _check_positive_int("mcts_iterations", self.mcts_iterations)
        _check_positive_int("mcts_depth", self.mcts_depth)
        _check_positive_int("mcts_nodes", self.mcts_nodes)
        if not _is_int(self.seed) or not 0 <= self.seed < 2**31:
            raise ValueError(f"seed: must be an integer in [0, 2**31), got {self.seed!r}")

    def to_json(self) -> str:
        """Canonical JSON of the settings (sorted keys), used in the CoACD cache key."""
        return json.dumps(dataclasses.asdict(self), sort_keys=True)


@dataclass(frozen=True)
class StablePoseParams:
    """Settings of the stable-pose search and of its MuJoCo settle check."""

    min_probability: float = 0.02
    """Pose classes less probable than this (quasi-static drop probability, in [0, 1)) are ignored. A class is
    the candidates with the same centre-of-mass height (a cylinder's side facets), so symmetric shapes keep
    their probable poses however finely they are faceted."""

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
        _check_number("min_probability", self.min_probability, low=0.0, high=1.0, high_open=True)
        _check_positive_int("max_poses", self.max_poses)
        if not isinstance(self.settle_check, (bool, np.bool_)):
            raise ValueError(f"settle_check: must be a bool, got {self.settle_check!r}")
        _check_number("settle_time", self.settle_time, low=0.0, low_open=True)
        _check_number("max_tilt", self.max_tilt, low=0.0, high=math.pi, low_open=True)
        _check_number("timestep", self.timestep, low=0.0, high=0.1, low_open=True)
        if self.settle_time < self.timestep:
            raise ValueError(f"settle_time: must be at least timestep ({self.timestep}), got {self.settle_time}")
        _check_number("friction", self.friction, low=0.0, low_open=True)
        _check_number("com_sigma", self.com_sigma, low=0.0)
        _check_positive_int("com_samples", self.com_samples)


# ---------------------------------------------------------------------------------------------------------------
# Results
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RepairReport:
    """What :func:`repair_mesh` found and did."""

    watertight: bool
    """The repaired mesh is closed and consistently wound, so its volume integral is meaningful."""

    merged_vertices: int
    """Vertices removed by merging duplicates."""

    removed_degenerate_faces: int
    """Zero-area faces removed."""

    removed_duplicate_faces: int
    """Faces removed because another face used the same three vertices."""

    removed_unreferenced_vertices: int
    """Vertices removed because no face used them."""

    filled_holes: bool
    """Small (triangle or quad) holes were filled."""

    fixed_normals: bool
    """Face winding or the overall orientation was changed."""

    notes: tuple[str, ...]
    """One human-readable line per change, in the order they were made."""


@dataclass(frozen=True, eq=False)
class MassProperties:
    """Rigid-body mass properties of an object, in its mesh frame."""

    mass: float
    """Mass in kg."""

    volume: float
    """Volume in m^3."""

    center_of_mass: np.ndarray
    """``(3,) float64`` centre of mass in m, mesh frame."""

    inertia: np.ndarray
    """``(3, 3) float64`` inertia tensor in kg m^2 about the centre of mass, axes of the mesh frame."""

    from_convex_hull: bool
    """The mesh was not watertight, so all of the above belong to its convex hull."""

    def __post_init__(self) -> None:
        _freeze(self.center_of_mass, self.inertia)


@dataclass(frozen=True, eq=False)
class PreparedObject:
    """Everything :func:`prepare_object` derives from one mesh file. Arrays are read-only."""

    name: str
    """Object name: the file name without its suffix."""

    source_path: str
    """The mesh file it came from."""

    vertices: np.ndarray
    """``(n, 3) float64`` repaired vertices in m (after unit scaling)."""

    faces: np.ndarray
    """``(f, 3) int32`` repaired triangles, indices into ``vertices``."""

    scale: float
    """Factor that turned file units into metres."""

    repair: RepairReport
    """What the repair step did."""

    mass: MassProperties
    """Mass, centre of mass and inertia in the mesh frame."""

    convex_parts: tuple[tuple[np.ndarray, np.ndarray], ...]
    """Convex collision parts, each ``(vertices (v, 3) float64 m, faces (g, 3) int32)`` in the mesh frame."""

    stable_transforms: np.ndarray
    """``(p, 4, 4) float64`` mesh-frame-to-world transforms that rest the object on the plane z = 0."""

    stable_probabilities: np.ndarray
    """``(p,) float64`` probability of each pose, summing to 1, most probable first."""

    warnings: tuple[str, ...]
    """Things the user should know (unit guess, mass taken from the convex hull, ...)."""

    def __post_init__(self) -> None:
        _freeze(self.vertices, self.faces, self.stable_transforms, self.stable_probabilities)
        for part_vertices, part_faces in self.convex_parts:
            _freeze(part_vertices, part_faces)


# ---------------------------------------------------------------------------------------------------------------
# Loading
# ---------------------------------------------------------------------------------------------------------------


def load_mesh(path: str | os.PathLike) -> trimesh.Trimesh:
    """Read a triangle mesh file, rejecting anything that is not a usable mesh.

    Scenes (GLB, multi-object OBJ) are merged into one mesh with each node's transform applied. Nothing is
    repaired here (``process=False``): :func:`repair_mesh` does that and reports it.

    Parameters
    ----------
    path
        An OBJ, STL, PLY, GLB/GLTF or OFF file.

    Returns
    -------
    trimesh.Trimesh
        The mesh as stored in the file, in file units. ``metadata["file_path"]`` holds ``path`` so that later
        messages can name the file.

    Raises
    ------
    InputError
        The file is missing, unreadable, empty, of an unsupported type, not parseable as a triangle mesh, has no
        faces, has NaN/infinite vertices or out-of-range face indices, or all its faces have zero area.
    """
    path = Path(path)
    _check_readable_file(path)
    loaded = _read_with_trimesh(path)
    mesh = _as_single_mesh(loaded, path)
    _check_mesh_contents(mesh, path)
    mesh.metadata["file_path"] = str(path)
    mesh.metadata["file_name"] = path.name
    return mesh


def _check_readable_file(path: Path) -> None:
    if not path.exists():
        raise InputError(f"{path}: file not found")
    if not path.is_file():
        raise InputError(f"{path}: not a regular file")
    if path.suffix.lower() not in SUPPORTED_SUFFIXES:
        raise InputError(
            f"{path}: unsupported mesh format {path.suffix or '(no suffix)'!r}, "
            f"expected one of {', '.join(SUPPORTED_SUFFIXES)}"
        )
    try:
        size = path.stat().st_size
        with path.open("rb") as handle:
            handle.read(1)
    except OSError as exc:
        raise InputError(f"{path}: cannot read file ({exc.strerror or exc})") from exc
    if size == 0:
        raise InputError(f"{path}: empty file (0 bytes)")


def _read_with_trimesh(path: Path) -> trimesh.parent.Geometry:
    file_type = path.suffix.lower().lstrip(".")
    try:
        return trimesh.load(str(path), file_type=file_type, process=False)
    except (UnicodeError, ImportError) as exc:
        # trimesh falls back to guessing a text encoding (and an optional package) only for bytes that are
        # neither valid binary nor UTF-8 text; the missing package is not the user's problem, the bytes are.
        raise InputError(f"{path}: not a valid {file_type.upper()} file (garbage or non-text bytes)") from exc
    except Exception as exc:  # trimesh raises anything from ValueError to IndexError on garbage bytes
        raise InputError(f"{path}: not a readable {file_type.upper()} mesh ({type(exc).__name__}: {exc})") from exc


def _as_single_mesh(loaded: object, path: Path) -> trimesh.Trimesh:
    if isinstance(loaded, trimesh.Scene):
        meshes = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh) and len(g.faces) > 0]
        if not meshes:
            raise InputError(f"{path}: not a mesh (the file holds no triangle geometry)")
        # dump() has already applied each node's transform, so concatenating keeps the layout.
        loaded = trimesh.util.concatenate(meshes) if len(meshes) > 1 else meshes[0]
    if not isinstance(loaded, trimesh.Trimesh):
        what = type(loaded).__name__
        count = len(getattr(loaded, "vertices", ()))
        raise InputError(f"{path}: not a mesh (got a {what} with {count} points and no faces)")
    return loaded


def _check_mesh_contents(mesh: trimesh.Trimesh, path: Path) -> None:
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces)
    if len(faces) == 0:
        raise InputError(f"{path}: empty mesh (no faces, {len(vertices)} vertices)")
    bad = ~np.isfinite(vertices).all(axis=1)
    if bad.any():
        raise InputError(f"{path}: {int(bad.sum())} of {len(vertices)} vertices are NaN or infinite")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError(f"{path}: face indices out of range (mesh has {len(vertices)} vertices)")
    areas = _face_areas(vertices, faces)
    size = float(np.ptp(vertices[faces.ravel()], axis=0).max())
    if size == 0.0 or np.all(areas <= _DEGENERATE_AREA_RATIO * size**2):
        raise InputError(f"{path}: degenerate mesh (all {len(faces)} faces have zero area)")
    used = vertices[np.unique(faces)]
    spread = np.linalg.svd(used - used.mean(axis=0), compute_uv=False)
    if len(used) < 4 or spread[-1] <= _FLAT_RATIO * spread[0]:
        # A single triangle or a flat sheet: no volume, no mass, nothing a gripper can close on.
        raise InputError(f"{path}: flat mesh with zero volume (all {len(used)} vertices lie in one plane)")


def _face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    triangles = vertices[faces]
    return 0.5 * np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1)


# ---------------------------------------------------------------------------------------------------------------
# Repair
# ---------------------------------------------------------------------------------------------------------------


def repair_mesh(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, RepairReport]:
    """Clean a mesh so that its volume, inertia and hull are meaningful.

    Steps: merge duplicate vertices, remove zero-area and duplicate faces, remove unreferenced vertices, fill
    small (triangle/quad) holes, make the winding consistent and outward per connected body. The input is
    not modified.

    Parameters
    ----------
    mesh
        The mesh as loaded (any units).

    Returns
    -------
    mesh : trimesh.Trimesh
        The repaired copy; ``metadata`` is carried over.
    report : RepairReport
        What was done and whether the result is watertight.
    """
    _check_mesh(mesh, "mesh")
    fixed = trimesh.Trimesh(
        vertices=np.array(mesh.vertices, dtype=np.float64),
        faces=np.array(mesh.faces, dtype=np.int64),
        process=False,
        metadata=dict(mesh.metadata),
    )
    notes: list[str] = []
    merged = _merge_vertices(fixed)
    degenerate = _remove_degenerate_faces(fixed)
    duplicate = _remove_duplicate_faces(fixed)
    unreferenced = _remove_unreferenced_vertices(fixed)
    filled = _fill_holes(fixed)
    flipped = _fix_normals(fixed)
    for count, what in (
        (merged, "merged {} duplicate vertices"),
        (degenerate, "removed {} zero-area faces"),
        (duplicate, "removed {} duplicate faces"),
        (unreferenced, "removed {} unreferenced vertices"),
    ):
        if count:
            notes.append(what.format(count))
    if filled:
        notes.append("filled small holes")
    if flipped:
        notes.append("fixed face winding / orientation")
    watertight = bool(fixed.is_watertight and fixed.is_winding_consistent)
    if not watertight:
        notes.append("mesh is not watertight after repair")
    report = RepairReport(
        watertight=watertight,
        merged_vertices=merged,
        removed_degenerate_faces=degenerate,
        removed_duplicate_faces=duplicate,
        removed_unreferenced_vertices=unreferenced,
        filled_holes=filled,
        fixed_normals=flipped,
        notes=tuple(notes),
    )
    return fixed, report


def _merge_vertices(mesh: trimesh.Trimesh) -> int:
    before = len(mesh.vertices)
    mesh.merge_vertices()
    return before - len(mesh.vertices)


def _remove_degenerate_faces(mesh: trimesh.Trimesh) -> int:
    size = float(mesh.extents.max())
    keep = _face_areas(mesh.vertices, mesh.faces) > _DEGENERATE_AREA_RATIO * size**2
    mesh.update_faces(keep)
    return int((~keep).sum())


def _remove_duplicate_faces(mesh: trimesh.Trimesh) -> int:
    keep = mesh.unique_faces()
    mesh.update_faces(keep)
    return int((~keep).sum())


def _remove_unreferenced_vertices(mesh: trimesh.Trimesh) -> int:
    before = len(mesh.vertices)
    mesh.remove_unreferenced_vertices()
    return before - len(mesh.vertices)


def _fill_holes(mesh: trimesh.Trimesh) -> bool:
    if mesh.is_watertight:
        return False
    before = len(mesh.faces)
    trimesh.repair.fill_holes(mesh)
    return len(mesh.faces) != before


def _fix_normals(mesh: trimesh.Trimesh) -> bool:
    before = np.array(mesh.faces)
    # multibody: a mug's separately modelled handle must be oriented on its own, not relative to the cup.
    trimesh.repair.fix_normals(mesh, multibody=True)
    return bool(before.shape != mesh.faces.shape or np.any(before != mesh.faces))


# ---------------------------------------------------------------------------------------------------------------
# Units
# ---------------------------------------------------------------------------------------------------------------

# Tried in this order when no scale is given: metres win when plausible, then millimetres (CAD and scanner
# exports), then centimetres.
_UNIT_GUESSES = ((1.0, "metres"), (0.001, "millimetres"), (0.01, "centimetres"))


def normalize_units(
    mesh: trimesh.Trimesh,
    *,
    scale: float | None = None,
    min_extent: float = 0.005,
    max_extent: float = 0.5,
    source: str | None = None,
) -> tuple[trimesh.Trimesh, float, str | None]:
    """Bring a mesh to metres and reject sizes no graspable object has.

    Rule when ``scale`` is None, with ``E`` the largest extent (bounding-box side) of the referenced vertices
    in file units: the first of metres (x1), millimetres (x0.001), centimetres (x0.01) that puts ``E`` in
    ``[min_extent, max_extent]`` wins. Metres need no warning; a guess of mm or cm returns a warning. With the
    defaults (5 mm .. 0.5 m): ``E`` = 0.1 stays 0.1 m; ``E`` = 95 is a 95 mm mug; ``E`` = 2 is 2 cm;
    ``E`` = 1000 would be 1 km, 1 m or 10 m and is rejected, since no 3-20 cm object is a metre tall.

    Parameters
    ----------
    mesh
        Mesh in file units.
    scale
        Metres per file unit; when given it is applied as is (no guessing, no warning) and the size is checked.
    min_extent, max_extent
        Accepted range of the largest extent after scaling, in m.
    source
        Name used in messages; defaults to the file name :func:`load_mesh` stored in ``mesh.metadata``.

    Returns
    -------
    mesh : trimesh.Trimesh
        A scaled copy (the input is returned unchanged when the scale is exactly 1).
    scale : float
        The factor applied.
    warning : str or None
        What was assumed, e.g. ``"mug.obj: largest extent 95.0 units, assumed millimetres, scaled by 0.001"``.

    Raises
    ------
    InputError
        The size after unit handling is outside ``[min_extent, max_extent]`` ("absurd size ...").
    """
    _check_mesh(mesh, "mesh")
    _check_number("min_extent", min_extent, low=0.0, low_open=True)
    _check_number("max_extent", max_extent, low=min_extent, low_open=True)
    if scale is not None:
        _check_number("scale", scale, low=0.0, low_open=True)
    label = source or _label(mesh)
    extent = _largest_extent(mesh)
    if scale is not None:
        _check_size(label, extent * scale, min_extent, max_extent, f"largest extent {extent:g} units x scale {scale:g}")
        return _scaled(mesh, float(scale)), float(scale), None
    for factor, unit in _UNIT_GUESSES:
        if min_extent <= extent * factor <= max_extent:
            warning = None
            if factor != 1.0:
                warning = f"{label}: largest extent {extent:.1f} units, assumed {unit}, scaled by {factor:g}"
            return _scaled(mesh, factor), factor, warning
    readings = ", ".join(f"{_format_length(extent * f)} as {u}" for f, u in _UNIT_GUESSES)
    raise InputError(
        f"{label}: absurd size after unit handling: largest extent {extent:g} units is {readings}; expected "
        f"{_format_length(min_extent)} to {_format_length(max_extent)} (give an explicit scale if this is right)"
    )


def _largest_extent(mesh: trimesh.Trimesh) -> float:
    # Only referenced vertices count: a stray unused vertex must not decide the unit.
    used = np.asarray(mesh.vertices)[np.unique(np.asarray(mesh.faces))]
    return float(np.ptp(used, axis=0).max())


def _check_size(label: str, size: float, min_extent: float, max_extent: float, how: str) -> None:
    if not min_extent <= size <= max_extent:
        raise InputError(
            f"{label}: absurd size after unit handling: {how} = {_format_length(size)}; expected "
            f"{_format_length(min_extent)} to {_format_length(max_extent)}"
        )


def _scaled(mesh: trimesh.Trimesh, factor: float) -> trimesh.Trimesh:
    if factor == 1.0:
        return mesh
    return trimesh.Trimesh(
        vertices=np.asarray(mesh.vertices, dtype=np.float64) * factor,
        faces=np.array(mesh.faces),
        process=False,
        metadata=dict(mesh.metadata),
    )


def _format_length(metres: float) -> str:
    """Human-readable length, e.g. ``1.0 km``, ``95.0 mm``."""
    for unit, size in (("km", 1e3), ("m", 1.0), ("mm", 1e-3)):
        if abs(metres) >= size:
            return f"{metres / size:.1f} {unit}"
    return f"{metres / 1e-6:.1f} µm"


# ---------------------------------------------------------------------------------------------------------------
# Mass properties
# ---------------------------------------------------------------------------------------------------------------


def mass_properties(mesh: trimesh.Trimesh, density: float, *, watertight: bool) -> MassProperties:
    """Mass, centre of mass and inertia of a uniformly dense solid.

    A mesh that is not watertight encloses no well-defined volume, so its convex hull is integrated instead and
    ``from_convex_hull`` is set (the caller should warn). The inertia is symmetrised; principal moments that
    are slightly negative or break the triangle inequality ``I1 <= I2 + I3`` by at most 1e-6 of the trace
    (rounding in the integral, e.g. for flat plates where it holds with equality) are clamped onto the valid
    set and the tensor rebuilt from its eigenvectors. A tensor that is clean is returned bit for bit as
    integrated.

    Parameters
    ----------
    mesh
        Mesh in m.
    density
        Density in kg/m^3.
    watertight
        Whether ``mesh`` is closed and consistently wound (``RepairReport.watertight``).

    Raises
    ------
    InputError
        Zero or negative volume, or an inertia tensor that is not physical beyond rounding.
    """
    _check_mesh(mesh, "mesh")
    _check_number("density", density, low=0.0, low_open=True)
    solid = mesh if watertight else mesh.convex_hull
    with np.errstate(divide="ignore", invalid="ignore"):  # a zero volume is reported below, not as a warning
        props = trimesh.triangles.mass_properties(solid.triangles, density=float(density))
    label = _label(mesh)
    size = float(mesh.extents.max())
    if not np.isfinite(props.volume) or props.volume <= _ZERO_VOLUME_RATIO * size**3:
        raise InputError(f"{label}: zero volume ({props.volume:.3g} m^3 for a {_format_length(size)} object)")
    inertia = _physical_inertia(np.asarray(props.inertia, dtype=np.float64), label)
    return MassProperties(
        mass=float(props.mass),
        volume=float(props.volume),
        center_of_mass=np.array(props.center_mass, dtype=np.float64),
        inertia=inertia,
        from_convex_hull=not watertight,
    )


def _physical_inertia(inertia: np.ndarray, label: str) -> np.ndarray:
    """Return a symmetric positive definite inertia obeying the triangle inequality, or raise."""
    sym = 0.5 * (inertia + inertia.T)
    moments, axes = np.linalg.eigh(sym)
    trace = float(moments.sum())
    if not np.isfinite(trace) or trace <= 0.0:
        raise InputError(f"{label}: inertia is not physical (principal moments {moments})")
    tolerance = _INERTIA_FIX_TOLERANCE * trace
    excess = moments - (trace - moments)  # I_i - (I_j + I_k)
    if moments.min() < -tolerance or excess.max() > tolerance:
        raise InputError(
            f"{label}: inertia is not physical (principal moments {moments}); is the mesh self-intersecting?"
        )
    if moments.min() > 0.0 and excess.max() <= 0.0:
        return sym
    floor = 1e-12 * trace
    clamped = np.maximum(moments, floor)
    for i in range(3):
        others = clamped.sum() - clamped[i]
        clamped[i] = min(clamped[i], others)
    fixed = (axes * clamped) @ axes.T
    return 0.5 * (fixed + fixed.T)


# ---------------------------------------------------------------------------------------------------------------
# Convex decomposition
# ---------------------------------------------------------------------------------------------------------------


def convex_decomposition(mesh: trimesh.Trimesh, params: CoacdParams) -> list[tuple[np.ndarray, np.ndarray]]:
    """Split a mesh into convex parts for collision.

    A watertight mesh whose volume equals its convex hull's within 1e-6 (relative) is already convex; CoACD
    would only re-approximate it, so its hull is returned as the single part. Otherwise CoACD runs with
    ``params``; each part is replaced by its own convex hull (CoACD's output is not always exactly convex and
    MuJoCo needs it to be), parts below 1e-6 of the hull volume are dropped, and the rest are sorted by
    centroid (x, then y, then z) and vertex count so that the order does not depend on CoACD internals. If
    every part is dropped, the mesh's convex hull is the single part.

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
    if not isinstance(params, CoacdParams):
        raise ValueError(f"params: must be a CoacdParams, got {type(params).__name__}")
    hull = mesh.convex_hull
    if _is_convex(mesh, hull):
        return [_part_arrays(hull)]
    raw = _run_coacd(mesh, params)
    parts = [_convex_part(vertices, faces) for vertices, faces in raw]
    min_volume = _MIN_PART_VOLUME_RATIO * hull.volume
    kept = [part for part in parts if part is not None and part.volume > min_volume]
    if not kept:
        _log.warning("%s: CoACD returned no usable part, using the convex hull", _label(mesh))
        return [_part_arrays(hull)]
    result = [_part_arrays(part) for part in _sorted_parts(kept)]
    excess = _volume_excess(mesh, kept)
    if params.refine_excess > 0 and excess > params.refine_excess:
        finer = dataclasses.replace(
            params,
            threshold=params.threshold / 4,
            max_convex_hull=-1 if params.max_convex_hull == -1 else 4 * params.max_convex_hull,
            refine_excess=0.0,
        )
        refined = convex_decomposition(mesh, finer)
        refined_excess = _volume_excess(mesh, [trimesh.Trimesh(v, f) for v, f in refined])
        _log.info("%s: parts exceed the volume by %.0f%%; refined: %.0f%%", _label(mesh), 100 * excess,
                  100 * refined_excess)
        if refined_excess < excess:
            return refined
    return result


def _volume_excess(mesh: trimesh.Trimesh, parts: list[trimesh.Trimesh]) -> float:
    """How much the parts' summed volume exceeds the mesh's, as a fraction (0 for an open mesh: not measurable)."""
    if not mesh.is_watertight or mesh.volume <= 0:
        return 0.0
    return float(sum(p.volume for p in parts) / mesh.volume - 1.0)


def _is_convex(mesh: trimesh.Trimesh, hull: trimesh.Trimesh) -> bool:
    if not (mesh.is_watertight and mesh.is_winding_consistent):
        return False
    return abs(hull.volume - mesh.volume) <= _CONVEX_VOLUME_TOLERANCE * abs(hull.volume)


def _run_coacd(mesh: trimesh.Trimesh, params: CoacdParams) -> list:
    # CoACD logs every iteration to stdout by default, which would drown the pipeline's own output.
    coacd.set_log_level("error")
    return coacd.run_coacd(
        coacd.Mesh(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int32)),
        threshold=params.threshold,
        max_convex_hull=params.max_convex_hull,
        preprocess_mode="auto",
        preprocess_resolution=params.preprocess_resolution,
        resolution=params.resolution,
        mcts_nodes=params.mcts_nodes,
        mcts_iterations=params.mcts_iterations,
        mcts_max_depth=params.mcts_depth,
        seed=params.seed,
    )


def _convex_part(vertices: np.ndarray, faces: np.ndarray) -> trimesh.Trimesh | None:
    if len(vertices) < 4:
        return None
    try:
        return trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(faces), process=False).convex_hull
    except Exception:  # qhull rejects flat point sets; such a part has no volume anyway
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


# ---------------------------------------------------------------------------------------------------------------
# CoACD cache
# ---------------------------------------------------------------------------------------------------------------


def _coacd_cache_key(mesh: trimesh.Trimesh, params: CoacdParams) -> str:
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


def _cached_convex_decomposition(
    mesh: trimesh.Trimesh, params: CoacdParams, cache_dir: Path | None
) -> list[tuple[np.ndarray, np.ndarray]]:
    if cache_dir is None:
        return convex_decomposition(mesh, params)
    path = cache_dir / f"coacd-{_coacd_cache_key(mesh, params)}.npz"
    parts = _read_parts(path)
    if parts is not None:
        return parts
    parts = convex_decomposition(mesh, params)
    _write_parts(path, parts)
    return parts


def _read_parts(path: Path) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """Parts stored at ``path``, or None when absent or unreadable (a bad entry is recomputed, not fatal)."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            count = int(data["count"])
            return [
                (data[f"vertices_{i}"].astype(np.float64), data[f"faces_{i}"].astype(np.int32)) for i in range(count)
            ]
    except Exception as exc:
        _log.warning("%s: unreadable CoACD cache entry, recomputing (%s)", path, exc)
        return None


def _write_parts(path: Path, parts: list[tuple[np.ndarray, np.ndarray]]) -> None:
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


# ---------------------------------------------------------------------------------------------------------------
# Stable poses
# ---------------------------------------------------------------------------------------------------------------


def resting_transform(hull_vertices: np.ndarray, center_of_mass: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Transform that rests an object on z = 0 on the hull face with outward ``normal``.

    The rotation follows trimesh's convention (rows x, y, z with z = -normal), so a pose depends only on its
    resting face. The translation puts the centre of mass above the world origin and the lowest hull vertex
    on z = 0.

    Parameters
    ----------
    hull_vertices
        ``(v, 3) float`` convex hull vertices, mesh frame, m.
    center_of_mass
        ``(3,) float`` centre of mass, mesh frame, m.
    normal
        ``(3,) float`` outward normal (mesh frame) of the face the object rests on.

    Returns
    -------
    (4, 4) float64
        Mesh-frame-to-world homogeneous transform.
    """
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


def build_settle_model(
    parts: list[tuple[np.ndarray, np.ndarray]] | tuple, mass: MassProperties, params: StablePoseParams
) -> mujoco.MjModel:
    """MuJoCo model of the object as a free body of convex mesh geoms above a ground plane.

    Mass and inertia come from ``mass`` (not from the geoms), so the dynamics match the analysis. The body
    frame is the mesh frame. Options: ``params.timestep``, elliptic friction cones, impratio 10.
    """
    _check_parts(parts, "parts")
    spec = mujoco.MjSpec()
    spec.modelname = "settle"
    spec.option.timestep = params.timestep
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = 10.0
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    friction = [params.friction, 0.005, 0.0001]
    spec.worldbody.add_geom(name="ground", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0.0, 0.0, 1.0], friction=friction)
    body = spec.worldbody.add_body(name="object")
    body.add_freejoint(name="free")
    body.explicitinertial = True
    body.mass = mass.mass
    body.ipos = mass.center_of_mass
    inertia = mass.inertia
    body.fullinertia = [inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2]]
    for i, (vertices, faces) in enumerate(parts):
        spec.add_mesh(
            name=f"part_{i}",
            uservert=np.asarray(vertices, dtype=np.float64).ravel().tolist(),
            userface=np.asarray(faces, dtype=np.int32).ravel().tolist(),
        )
        body.add_geom(name=f"part_{i}", type=mujoco.mjtGeom.mjGEOM_MESH, meshname=f"part_{i}", friction=friction)
    return spec.compile()


@dataclass(frozen=True, eq=False)
class SettleResult:
    """Outcome of one MuJoCo drop (see :func:`settle_pose`)."""

    rotation: np.ndarray
    """``(3, 3) float64`` final mesh-to-world rotation."""

    position: np.ndarray
    """``(3,) float64`` final position of the mesh-frame origin, m."""

    linear_speed: float
    """Final speed of the mesh-frame origin, m/s."""

    angular_speed: float
    """Final angular speed, rad/s."""

    @property
    def at_rest(self) -> bool:
        """The object stopped moving and the state is finite."""
        return bool(
            np.isfinite(self.rotation).all()
            and self.linear_speed < _REST_LINEAR_SPEED
            and self.angular_speed < _REST_ANGULAR_SPEED
        )


def settle_pose(
    model: mujoco.MjModel, transform: np.ndarray, params: StablePoseParams, data: mujoco.MjData | None = None
) -> SettleResult:
    """Drop the object from ``transform`` lifted by 1 mm and simulate ``params.settle_time``.

    Parameters
    ----------
    model
        From :func:`build_settle_model`.
    transform
        ``(4, 4) float`` mesh-to-world pose resting on z = 0.
    params
        Only ``settle_time`` is read here (timestep and friction are baked into ``model``).
    data
        Reused scratch state; it is fully reset, so reuse never changes the result.
    """
    data = mujoco.MjData(model) if data is None else data
    mujoco.mj_resetData(model, data)
    transform = np.asarray(transform, dtype=np.float64)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(transform[:3, :3]).ravel())
    data.qpos[:3] = transform[:3, 3] + (0.0, 0.0, _SETTLE_DROP_HEIGHT)
    data.qpos[3:7] = quat
    steps = max(1, int(round(params.settle_time / model.opt.timestep)))
    mujoco.mj_step(model, data, nstep=steps)
    body = model.body("object").id
    return SettleResult(
        rotation=np.array(data.xmat[body], dtype=np.float64).reshape(3, 3),
        position=np.array(data.xpos[body], dtype=np.float64),
        linear_speed=float(np.linalg.norm(data.qvel[:3])),
        angular_speed=float(np.linalg.norm(data.qvel[3:6])),
    )


def stable_poses(
    mesh: trimesh.Trimesh,
    mass: MassProperties,
    parts: list[tuple[np.ndarray, np.ndarray]] | tuple,
    params: StablePoseParams,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Poses in which the object rests on a table, with the probability of landing in each.

    Candidates come from trimesh's quasi-static toppling analysis of the convex hull
    (``trimesh.poses.compute_stable_poses`` with ``sigma=0, n_samples=1`` and a fixed seed, which draws
    nothing random). With ``params.com_sigma > 0`` the centre of mass is perturbed ``com_samples`` times using
    ``rng`` (the only use of ``rng``) and the probabilities averaged. Candidates are grouped into classes of
    equal centre-of-mass height (one physical pose split over the facets of a faceted solid of revolution);
    classes below ``min_probability`` are ignored (if all are, the most probable is kept) and at most
    ``max_poses`` candidates are kept round-robin over the classes (:func:`_select_pose_classes`).

    Settle rule (``settle_check``): each candidate is dropped 1 mm in MuJoCo (convex ``parts``, mass and
    inertia from ``mass``) and the hull face it ends up resting on is found. A candidate that does not come to
    rest within ``settle_time`` is dropped. One that settles is *replaced by its settled pose*: if that tilts
    more than ``max_tilt`` from the candidate, the candidate was not really stable and its probability moves
    to where it went. Settled poses whose resting normals are within ``max_tilt`` of each other are merged
    (probabilities add, the more probable one's pose is kept), so an unstable candidate that topples onto
    another pose adds to it. If every candidate is dropped, the settled pose of the most probable one is
    returned alone. One MuJoCo model is compiled per call and reset per candidate.

    At most ``max_poses`` poses are returned, most probable first, probabilities renormalised to sum to 1.

    Parameters
    ----------
    mesh
        Repaired mesh in m.
    mass
        Its mass properties.
    parts
        Convex parts from :func:`convex_decomposition` (only used by the settle check).
    params
        Settings.
    rng
        Random generator; only drawn from when ``params.com_sigma > 0``.

    Returns
    -------
    transforms : (n, 4, 4) float64
        Mesh-to-world transforms resting the object on z = 0 (lowest hull vertex at z = 0, centre of mass above
        the origin), n >= 1.
    probabilities : (n,) float64
        Sum to 1, descending.
    """
    _check_mesh(mesh, "mesh")
    _check_rng(rng)
    if not isinstance(params, StablePoseParams):
        raise ValueError(f"params: must be a StablePoseParams, got {type(params).__name__}")
    hull = mesh.convex_hull
    com = np.asarray(mass.center_of_mass, dtype=np.float64)
    normals, probs = _candidate_normals(mesh, hull, com, params, rng)
    normals, probs = _select_pose_classes(hull, com, normals, probs, params)
    if params.settle_check:
        normals, probs = _settle_and_merge(hull, mass, parts, normals, probs, params, _label(mesh))
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
    """Keep the candidates of probable pose *classes*, at most ``max_poses``, with class-faithful probabilities.

    A faceted solid of revolution splits one physical pose over many hull faces: a 64-sided cylinder lying on
    its side gets 64 candidates of ~1 % each, so a per-face threshold would keep only its two end caps and say
    it always stands upright. Candidates whose centre of mass sits at the same height above the table
    (within ``_SAME_HEIGHT``) form one class; the threshold applies to a class's total probability, and the
    ``max_poses`` slots are filled round-robin over the classes, most probable first. Each kept pose carries
    its class's probability divided by the number of its members kept, so the distribution over classes is
    exactly the quasi-static one.
    """
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


def _settle_and_merge(
    hull: trimesh.Trimesh,
    mass: MassProperties,
    parts: list[tuple[np.ndarray, np.ndarray]] | tuple,
    normals: np.ndarray,
    probs: np.ndarray,
    params: StablePoseParams,
    label: str,
) -> tuple[np.ndarray, np.ndarray]:
    model = build_settle_model(parts, mass, params)
    data = mujoco.MjData(model)
    com = np.asarray(mass.center_of_mass)
    settled_normals: list[np.ndarray] = []
    settled_probs: list[float] = []
    first_settled: np.ndarray | None = None
    for normal, prob in zip(normals, probs, strict=True):
        result = settle_pose(model, resting_transform(hull.vertices, com, normal), params, data)
        settled = _resting_face_normal(hull, result.rotation) if np.isfinite(result.rotation).all() else normal
        if first_settled is None:
            first_settled = settled
        if not result.at_rest:
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
    """Merge normals within ``angle`` (rad) of an earlier one, adding their probabilities.

    Greedy in the given order, so with ``normals (k, 3)`` sorted most probable first each group is represented
    by its most probable member. Returns the representatives ``(m, 3)`` and summed probabilities ``(m,)``.
    """
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


# ---------------------------------------------------------------------------------------------------------------
# Whole object
# ---------------------------------------------------------------------------------------------------------------


def prepare_object(
    path: str | os.PathLike,
    *,
    density: float,
    scale: float | None = None,
    min_extent: float = 0.005,
    max_extent: float = 0.5,
    coacd: CoacdParams | None = None,
    poses: StablePoseParams | None = None,
    rng: np.random.Generator,
    coacd_cache_dir: str | os.PathLike | None = None,
) -> PreparedObject:
    """Load, repair, scale, weigh, decompose and find resting poses of one mesh file.

    Parameters
    ----------
    path
        Mesh file (see :func:`load_mesh`).
    density
        Density in kg/m^3.
    scale, min_extent, max_extent
        Unit handling, see :func:`normalize_units`.
    coacd
        Convex decomposition settings; None means ``CoacdParams()``.
    poses
        Stable-pose settings; None means ``StablePoseParams()``.
    rng
        Random generator for :func:`stable_poses`.
    coacd_cache_dir
        Folder for cached decompositions, keyed by the sha256 of the repaired mesh and the CoACD settings;
        None disables caching. A corrupt entry is recomputed and overwritten.

    Raises
    ------
    InputError
        The file cannot be used; the message names it and says why.
    """
    _check_number("density", density, low=0.0, low_open=True)
    _check_rng(rng)
    coacd = CoacdParams() if coacd is None else coacd
    poses = StablePoseParams() if poses is None else poses
    path = Path(path)
    warnings: list[str] = []
    loaded = load_mesh(path)
    repaired, report = repair_mesh(loaded)
    mesh, used_scale, unit_warning = normalize_units(
        repaired, scale=scale, min_extent=min_extent, max_extent=max_extent
    )
    if unit_warning:
        warnings.append(unit_warning)
    mass = mass_properties(mesh, density, watertight=report.watertight)
    if mass.from_convex_hull:
        warnings.append(f"{path.name}: mesh is not watertight, mass and inertia taken from its convex hull")
    cache_dir = None if coacd_cache_dir is None else Path(coacd_cache_dir)
    parts = _cached_convex_decomposition(mesh, coacd, cache_dir)
    transforms, probabilities = stable_poses(mesh, mass, parts, poses, rng)
    return PreparedObject(
        name=path.stem,
        source_path=str(path),
        vertices=np.ascontiguousarray(mesh.vertices, dtype=np.float64),
        faces=np.ascontiguousarray(mesh.faces, dtype=np.int32),
        scale=used_scale,
        repair=report,
        mass=mass,
        convex_parts=tuple(parts),
        stable_transforms=transforms,
        stable_probabilities=probabilities,
        warnings=tuple(warnings),
    )
