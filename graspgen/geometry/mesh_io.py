"""Step 1 of mesh preparation: read a mesh file and reject anything that is not a usable triangle mesh.

:func:`load_mesh` reads OBJ, STL, PLY, GLB/GLTF and OFF files (:data:`SUPPORTED_SUFFIXES`) and raises
:class:`~graspgen.errors.InputError` naming the file when it is missing, empty, garbage, NaN, degenerate or flat.
Nothing is repaired or scaled here: vertices stay in file units (:mod:`graspgen.geometry.units` brings them to m).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import trimesh

from graspgen.errors import InputError, SettingsError
from graspgen.validation import check_instance

__all__ = ["SUPPORTED_SUFFIXES", "load_mesh"]


SUPPORTED_SUFFIXES = (".obj", ".stl", ".ply", ".glb", ".gltf", ".off")
"""File name endings :func:`load_mesh` accepts (case-insensitive)."""

# A face counts as degenerate when its area is below this fraction of (largest extent)^2: a purely absolute
# threshold would call every face of a millimetre-scale mesh given in metres degenerate, or none of a huge one.
_DEGENERATE_AREA_RATIO = 1e-14

# Vertices whose smallest principal spread is below this fraction of the largest lie in one plane.
_FLAT_RATIO = 1e-9


def _check_mesh(mesh: object, name: str) -> None:
    check_instance(name, mesh, trimesh.Trimesh, what="trimesh.Trimesh")
    if len(mesh.faces) == 0:
        raise SettingsError(f"{name}: has no faces")


def _label(mesh: trimesh.Trimesh) -> str:
    """How messages name a mesh: its file name when :func:`load_mesh` recorded one."""
    metadata = getattr(mesh, "metadata", None) or {}
    return str(metadata.get("file_name") or metadata.get("file_path") or "mesh")


def load_mesh(path: str | os.PathLike) -> trimesh.Trimesh:
    """Read a triangle mesh file, rejecting anything that is not a usable mesh.

    Scenes (GLB, multi-object OBJ) are merged into one mesh with each node's transform applied. Nothing is
    repaired here (``process=False``): :func:`~graspgen.geometry.repair.repair_mesh` does that and reports it.

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
