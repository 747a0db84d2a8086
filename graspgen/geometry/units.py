"""Step 3 of mesh preparation: bring a mesh to metres and reject sizes no graspable object has.

:func:`normalize_units` applies an explicit scale (metres per file unit) or guesses metres, millimetres or
centimetres from the largest extent, and raises :class:`~graspgen.errors.InputError` when the largest extent
in m falls outside ``[min_extent, max_extent]``.
"""

from __future__ import annotations

import numpy as np
import trimesh

from graspgen.errors import InputError
from graspgen.geometry.mesh_io import _check_mesh, _label
from graspgen.validation import check_number

__all__ = ["normalize_units"]


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
        Name used in messages; defaults to the file name :func:`~graspgen.geometry.mesh_io.load_mesh` stored in
        ``mesh.metadata``.

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
    check_number("min_extent", min_extent, low=0.0, low_open=True)
    check_number("max_extent", max_extent, low=min_extent, low_open=True)
    if scale is not None:
        check_number("scale", scale, low=0.0, low_open=True)
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
