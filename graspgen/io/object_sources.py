"""Which objects the ``objects`` stage makes: its settings (:class:`ObjectsParams`, config section ``objects``) and
the list they select (:func:`object_sources`): the bundled set (``assets/objects`` and its catalog), mesh files
matched by globs, the rows of an object manifest (:func:`graspgen.io.objects.read_object_manifest`) and procedural
objects (:mod:`graspgen.geometry.procedural`), each with its own density or mass, scale, friction and category.

A selection that cannot be used raises :class:`ObjectSelectionError`, whose message starts with the config key
(``objects.paths``, ``objects.manifest``, ``objects.include``, ...) and says what to change.
"""

from __future__ import annotations

import dataclasses
import glob
import json
from pathlib import Path
from typing import Any

from graspgen.errors import InputError, SettingsError
from graspgen.geometry.convex import CoacdParams
from graspgen.geometry.procedural import ProceduralParams, ProceduralShape, draw_shapes
from graspgen.geometry.stable_poses import StablePoseParams
from graspgen.io.objects import read_object_manifest
from graspgen.validation import check, check_number
from shared_utils.keys import KEY_OMIT_DEFAULT

__all__ = [
    "ASSETS",
    "MESH_SUFFIXES",
    "ObjectSelectionError",
    "ObjectSource",
    "ObjectsParams",
    "catalog",
    "left_out_by_include",
    "manifest_sources",
    "object_sources",
    "procedural_sources",
    "user_meshes",
]


class ObjectSelectionError(SettingsError):
    """The objects a config selects cannot be listed: a glob matching nothing, two files with one name, a manifest
    that cannot be used, a name taken twice, an ``include`` name not found. The message starts with the config key."""


ASSETS = Path(__file__).resolve().parents[2] / "assets" / "objects"
"""The bundled objects and their catalog (name, file, density)."""

MESH_SUFFIXES = (".obj", ".stl", ".ply", ".glb", ".gltf", ".off")


@dataclasses.dataclass(frozen=True)
class ObjectsParams:
    """Settings of the ``objects`` stage (config section ``objects``)."""

    paths: tuple[str, ...] = ()
    """Glob patterns of extra mesh files (OBJ/STL/PLY/GLB/OFF), relative to the current directory."""
    bundled: bool = True
    """Include the bundled objects of ``assets/objects``."""
    manifest: str | None = None
    """Object manifest: a CSV or YAML file listing objects, one per row (relative to the current directory; the mesh
    paths in it are relative to its own folder). Columns: ``path``, optional ``name`` (default: file stem),
    ``scale`` (m per mesh unit; empty: ``scale`` below), ``mass`` (kg) or ``density`` (kg/m^3), ``friction``
    (sliding friction in simulation; empty: drawn from ``scenes.friction``), ``category``. Null: none."""
    include: tuple[str, ...] = ()
    """Keep only the objects with these names (file stems, manifest names); empty keeps all."""
    scale: float | None = None
    """Metres per mesh unit for every file without its own (a manifest row's ``scale``); null detects
    millimetres/centimetres from the size, with a warning."""
    min_extent: float = 0.005
    """Smallest plausible largest-extent after unit handling, m; smaller meshes are rejected."""
    max_extent: float = 0.5
    """Largest plausible largest-extent after unit handling, m; larger meshes are rejected."""
    density: float = 700.0
    """Density for objects that have none of their own, kg/m^3 (bundled objects carry theirs in the catalog)."""
    densities: dict[str, float] = dataclasses.field(default_factory=dict)
    """Per-object density overrides by name, kg/m^3 (a manifest row's own ``mass`` or ``density`` wins)."""
    coacd: CoacdParams = dataclasses.field(default_factory=CoacdParams)
    """Convex decomposition settings (CoACD)."""
    stable_poses: StablePoseParams = dataclasses.field(default_factory=StablePoseParams)
    """Stable pose search and its physics check."""
    procedural: ProceduralParams | None = dataclasses.field(default=None, metadata={KEY_OMIT_DEFAULT: True})
    """Procedurally generated objects besides the files (``{count, families, seed, size_range, max_grasp_width}``,
    :class:`graspgen.geometry.procedural.ProceduralParams`), named ``<family>_s<seed>_<index>``; density
    ``density`` (or ``densities`` by name). Null: none."""

    def __post_init__(self) -> None:
        # check_number first: a finite real number, not a bool (as every library settings class); then the range.
        if self.manifest is not None:
            check("manifest", bool(self.manifest.strip()), "be a file path (or null for none)", self.manifest)
        if self.scale is not None:
            check_number("scale", self.scale)
            check("scale", self.scale > 0, "be > 0 (or null to detect)", self.scale)
        check_number("min_extent", self.min_extent)
        check("min_extent", self.min_extent > 0, "be > 0", self.min_extent)
        check_number("max_extent", self.max_extent)
        check("max_extent", self.max_extent > self.min_extent, "be > min_extent", self.max_extent)
        check_number("density", self.density)
        check("density", self.density > 0, "be > 0", self.density)
        for name, rho in self.densities.items():
            check_number(f"densities.{name}", rho)
            check(f"densities.{name}", rho > 0, "be > 0", rho)


def catalog() -> dict[str, dict[str, Any]]:
    """The bundled objects' catalog by name: ``{"file", "density", "description"}``."""
    entries = json.loads((ASSETS / "catalog.json").read_text())
    return {e["name"]: e for e in entries}


@dataclasses.dataclass(frozen=True)
class ObjectSource:
    """One object the ``objects`` stage makes, with the settings of its own (from the catalog or its manifest row)."""

    name: str
    """Object name: the task id (file stem, or the manifest's ``name``)."""
    path: Path
    """The mesh file."""
    origin: str
    """Where it was listed, for messages: ``bundled``, ``objects.paths`` or ``objects.manifest <file> row <n>``."""
    density: float | None
    """Density, kg/m^3; None when ``mass`` is given instead."""
    mass: float | None = None
    """Mass, kg (a manifest's ``mass``); None: from ``density``."""
    scale: float | None = None
    """The object's own metres per mesh unit (a manifest's ``scale``); None: ``objects.scale``."""
    friction: float | None = None
    """The object's own sliding friction coefficient (a manifest's ``friction``); None: none."""
    category: str | None = None
    """The object's category (a manifest's ``category``); None: none."""
    shape: ProceduralShape | None = None
    """A procedural object's shape (``path`` is then only its notional file name, not a file); None: a mesh file."""

    def payload(self) -> dict[str, Any]:
        """The task payload (it enters the key): ``density`` (or ``mass``) and the file suffix, plus the object's
        own ``scale``, ``friction`` and ``category`` where it has them (so an object without any keeps its key),
        and a procedural object's shape spec (``procedural``)."""
        out: dict[str, Any] = {"mass": self.mass} if self.mass is not None else {"density": self.density}
        out["suffix"] = self.path.suffix.lower()
        for field in ("scale", "friction", "category"):
            if getattr(self, field) is not None:
                out[field] = getattr(self, field)
        if self.shape is not None:
            out["procedural"] = self.shape.spec()
        return out

    def inputs(self) -> tuple[str, ...]:
        """The task's input files: the mesh file; none for a procedural object (its payload says it all)."""
        return () if self.shape is not None else (str(self.path),)


def object_sources(params: ObjectsParams) -> list[ObjectSource]:
    """Every object the params select (bundled, ``objects.paths``, ``objects.manifest``, ``objects.procedural``),
    sorted by name.

    Raises
    ------
    ObjectSelectionError
        A glob matching nothing, two files with one name, a manifest that cannot be used (the message names its
        file, row and column), a manifest name already taken, an ``include`` name that is not found.
    """
    found: dict[str, ObjectSource] = {}

    def add(source: ObjectSource) -> None:
        name, path = source.name, source.path
        if name in found and found[name].path != path:
            raise ObjectSelectionError(
                f"objects.paths: two meshes are both named {name!r}: {found[name].path} and {path}; rename one"
            )
        found[name] = source

    if params.bundled:
        for name, entry in catalog().items():
            density = params.densities.get(name, float(entry["density"]))
            add(ObjectSource(name, ASSETS / entry["file"], "bundled", density))
    for path in user_meshes(params):
        add(ObjectSource(path.stem, path, "objects.paths", params.densities.get(path.stem, params.density)))
    for source in manifest_sources(params):
        if source.name in found:
            other = found[source.name]
            raise ObjectSelectionError(
                f"{source.origin}, column 'name': the name {source.name!r} is already taken by {other.path} "
                f"({other.origin}); names must be unique: set another in the name column"
            )
        found[source.name] = source
    for source in procedural_sources(params):
        if source.name in found:
            raise ObjectSelectionError(f"objects.procedural: the name {source.name!r} is already taken by "
                              f"{found[source.name].path} ({found[source.name].origin}); rename that file")
        found[source.name] = source
    if params.include:
        missing = sorted(set(params.include) - set(found))
        if missing:
            raise ObjectSelectionError(f"objects.include: no object named {missing[0]!r}; available: "
                                       f"{', '.join(sorted(found))}")
        found = {n: v for n, v in found.items() if n in params.include}
    if not found:
        raise ObjectSelectionError("objects: no objects selected (bundled is false, paths and manifest are empty and "
                          "procedural is null)")
    return [found[name] for name in sorted(found)]


def manifest_sources(params: ObjectsParams) -> list[ObjectSource]:
    """The objects of ``objects.manifest`` (none when it is null), in file order: the row's own mass or density
    (else ``objects.densities`` by name, else ``objects.density``), scale, friction and category.

    Raises
    ------
    ObjectSelectionError
        The manifest cannot be used: ``objects.manifest: <file>: row <n> (line <l>), column '<c>': why``.
    """
    if params.manifest is None:
        return []
    manifest = Path(params.manifest)
    try:
        entries = read_object_manifest(manifest)
    except InputError as exc:
        raise ObjectSelectionError(f"objects.manifest: {exc}") from None
    sources = []
    for e in entries:
        density = None if e.mass is not None else e.density or params.densities.get(e.name, params.density)
        origin = f"objects.manifest: {manifest}: row {e.row}"
        sources.append(ObjectSource(e.name, e.path, origin, density, e.mass, e.scale, e.friction, e.category))
    return sources


def procedural_sources(params: ObjectsParams) -> list[ObjectSource]:
    """The objects of ``objects.procedural`` (none when it is null), by index: density ``objects.densities`` by
    name, else ``objects.density``; scale 1 (the meshes are made in metres)."""
    if params.procedural is None:
        return []
    return [
        ObjectSource(shape.name, Path(f"{shape.name}.obj"), f"objects.procedural[{shape.index}]",
                     params.densities.get(shape.name, params.density), scale=1.0, shape=shape)
        for shape in draw_shapes(params.procedural)
    ]


def user_meshes(params: ObjectsParams) -> list[Path]:
    """The mesh files ``objects.paths`` matches, pattern by pattern (before ``objects.include``).

    Raises
    ------
    ObjectSelectionError
        A pattern matching no mesh file.
    """
    found = []
    for i, pattern in enumerate(params.paths):
        matches = sorted(Path(p) for p in glob.glob(pattern, recursive=True))
        meshes = [p for p in matches if p.is_file() and p.suffix.lower() in MESH_SUFFIXES]
        if not meshes:
            raise ObjectSelectionError(f"objects.paths[{i}]: {pattern!r} matches no mesh file "
                                       f"({', '.join(MESH_SUFFIXES)})")
        found.extend(meshes)
    return found


def left_out_by_include(params: ObjectsParams) -> list[Path]:
    """The meshes ``objects.paths`` matches that ``objects.include`` leaves out (sorted, each once)."""
    if not params.include or not params.paths:
        return []
    return sorted({p for p in user_meshes(params) if p.stem not in params.include})
