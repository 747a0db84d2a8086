"""Turn one object mesh file into everything the later stages need: the steps of mesh preparation, in order.

:func:`prepare_object` runs the steps, each in its own module of :mod:`graspgen.geometry` (the MuJoCo drop of the
last in :mod:`graspgen.sim.stable_poses`), and returns a :class:`~graspgen.geometry.prepare.PreparedObject`:

1. :func:`~graspgen.geometry.mesh_io.load_mesh` reads OBJ/STL/PLY/GLB/OFF and rejects broken files with an
   :class:`~graspgen.errors.InputError`.
2. :func:`~graspgen.geometry.repair.repair_mesh` merges vertices, drops degenerate/duplicate faces, fixes winding
   and fills small holes.
3. :func:`~graspgen.geometry.units.normalize_units` brings the mesh to metres (explicit scale, or a documented
   guess) and rejects absurd sizes.
4. :func:`~graspgen.geometry.mass.mass_properties` integrates mass, centre of mass and inertia for a given density
   (or for the density that gives a given mass).
5. :func:`~graspgen.geometry.convex.convex_decomposition` splits the mesh into convex parts with CoACD (MuJoCo
   collides convex hulls), cached on disk.
6. :func:`~graspgen.sim.stable_poses.stable_poses` finds resting poses on a table and checks them in a short
   MuJoCo drop.

Units: m, kg, s (density in kg/m^3). Every function is deterministic: the same inputs and the same ``rng`` seed
give bitwise identical arrays. Randomness only ever comes from the ``numpy.random.Generator`` passed in.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from graspgen.errors import SettingsError
from graspgen.geometry.convex import CoacdParams, cached_convex_decomposition
from graspgen.geometry.mass import mass_properties
from graspgen.geometry.mesh_io import load_mesh
from graspgen.geometry.prepare import PreparedObject
from graspgen.geometry.repair import repair_mesh
from graspgen.geometry.stable_poses import StablePoseParams
from graspgen.geometry.units import normalize_units
from graspgen.sim.stable_poses import stable_poses
from graspgen.validation import check_number, check_rng

__all__ = ["REPAIR_NOT_WARNED", "PreparedObject", "object_warnings", "prepare_object"]


def _check_weight(density: float | None, mass: float | None) -> None:
    if (density is None) == (mass is None):
        raise SettingsError(f"density, mass: give exactly one, got density={density!r}, mass={mass!r}")
    if mass is not None:
        check_number("mass", mass, low=0.0, low_open=True)
    else:
        check_number("density", density, low=0.0, low_open=True)


def prepare_object(
    path: str | os.PathLike,
    *,
    density: float | None = None,
    mass: float | None = None,
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
        Mesh file (see :func:`~graspgen.geometry.mesh_io.load_mesh`).
    density
        Density in kg/m^3. Give it or ``mass``, not both.
    mass
        Mass in kg: the density becomes ``mass / volume`` (the volume after repair and unit scaling, of the convex
        hull for a mesh that is not watertight), so the object weighs exactly this.
    scale, min_extent, max_extent
        Unit handling, see :func:`~graspgen.geometry.units.normalize_units`.
    coacd
        Convex decomposition settings; None means ``CoacdParams()``.
    poses
        Stable-pose settings; None means ``StablePoseParams()``.
    rng
        Random generator for :func:`~graspgen.sim.stable_poses.stable_poses`.
    coacd_cache_dir
        Folder for cached decompositions, keyed by the sha256 of the repaired mesh and the CoACD settings;
        None disables caching. A corrupt entry is recomputed and overwritten.

    Raises
    ------
    InputError
        The file cannot be used; the message names it and says why.
    """
    _check_weight(density, mass)
    check_rng("rng", rng)
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
    if density is None:
        unit = mass_properties(mesh, 1.0, watertight=report.watertight)
        density = float(mass) / unit.volume
    props = mass_properties(mesh, density, watertight=report.watertight)
    if props.from_convex_hull:
        warnings.append(f"{path.name}: mesh is not watertight, mass and inertia taken from its convex hull")
    cache_dir = None if coacd_cache_dir is None else Path(coacd_cache_dir)
    parts = cached_convex_decomposition(mesh, coacd, cache_dir)
    transforms, probabilities = stable_poses(mesh, props, parts, poses, rng)
    return PreparedObject(
        name=path.stem,
        source_path=str(path),
        vertices=np.ascontiguousarray(mesh.vertices, dtype=np.float64),
        faces=np.ascontiguousarray(mesh.faces, dtype=np.int32),
        scale=used_scale,
        repair=report,
        mass=props,
        convex_parts=tuple(parts),
        stable_transforms=transforms,
        stable_probabilities=probabilities,
        warnings=tuple(warnings),
    )


REPAIR_NOT_WARNED = ("duplicate vertices", "not watertight after repair")
"""Repair notes that are no warning: merging duplicate vertices changes no geometry (STL files store every
triangle's corners apart), and a mesh left open already gets the convex-hull mass warning."""


def object_warnings(path: Path, warnings: Sequence[str], repair_notes: Sequence[str]) -> list[str]:
    """What a user should hear about one prepared mesh: the unit guess and mass notes of mesh preparation, and
    the repairs that changed its geometry, each naming the file."""
    out = list(warnings)
    repairs = [n for n in repair_notes if not any(skip in n for skip in REPAIR_NOT_WARNED)]
    if repairs:
        out.append(f"{path.name}: mesh repaired: {'; '.join(repairs)}")
    return out
