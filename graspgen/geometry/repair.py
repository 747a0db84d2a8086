"""Step 2 of mesh preparation: repair a loaded mesh so that its volume, inertia and hull are meaningful.

:func:`repair_mesh` merges vertices, drops zero-area and duplicate faces, fills small holes and fixes the
winding, and says what it did in a :class:`RepairReport`. Units are left as they are (file units); the
zero-area threshold is relative to the mesh's largest extent, so it holds in any unit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from graspgen.geometry.mesh_io import _DEGENERATE_AREA_RATIO, _check_mesh, _face_areas

__all__ = ["RepairReport", "repair_mesh"]


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
