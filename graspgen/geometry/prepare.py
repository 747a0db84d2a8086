"""The record of one prepared object mesh: :class:`PreparedObject`, what
:func:`graspgen.workflows.prepare.prepare_object` derives from a mesh file (repaired mesh, scale, mass properties,
convex parts, stable poses). Units: m, kg; arrays read-only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graspgen.geometry.mass import MassProperties, _freeze
from graspgen.geometry.repair import RepairReport

__all__ = ["PreparedObject"]


@dataclass(frozen=True, eq=False)
class PreparedObject:
    """Everything :func:`graspgen.workflows.prepare.prepare_object` derives from one mesh file. Arrays are read-only."""

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
