"""Step 4 of mesh preparation: mass, centre of mass and inertia of a uniformly dense solid.

:func:`mass_properties` integrates a mesh in m at a density in kg/m^3 into :class:`MassProperties` (mass in kg,
volume in m^3, centre of mass in m, inertia in kg m^2 about the centre of mass, mesh frame), using the convex
hull for a mesh that is not watertight.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from graspgen.errors import InputError
from graspgen.geometry.mesh_io import _check_mesh, _label
from graspgen.geometry.units import _format_length
from graspgen.validation import check_number

__all__ = ["MassProperties", "mass_properties"]


# Volumes below this fraction of (largest extent)^3 are "zero": a thin plate 1/1000 as thick as it is wide is
# still 1e-3, so this only catches flat or inside-out meshes.
_ZERO_VOLUME_RATIO = 1e-9

# Numerical noise in the integrated inertia (a flat plate sits exactly on the triangle inequality) is repaired
# up to this fraction of the trace; anything larger means the mesh itself is inconsistent.
_INERTIA_FIX_TOLERANCE = 1e-6


def _freeze(*arrays: np.ndarray) -> None:
    for array in arrays:
        if isinstance(array, np.ndarray):
            array.setflags(write=False)


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
    check_number("density", density, low=0.0, low_open=True)
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
