"""Stage 1, ``objects``: turn mesh files into simulation-ready objects.

One task per mesh file (the bundled set in ``assets/objects``, the globs in ``objects.paths`` and the rows of the
object manifest ``objects.manifest``: :func:`graspgen.io.objects.read_object_manifest`) and per procedural object
(``objects.procedural``: :mod:`graspgen.geometry.procedural`). Each task
loads, fixes units, repairs, computes mass properties, decomposes into convex parts (CoACD, cached) and finds
physics-checked stable poses (:mod:`graspgen.workflows.prepare`), then writes one HDF5 shard::

    /mesh/vertices (v, 3) float64 m         /mesh/faces (f, 3) int32
    /convex/vertices (V, 3) float64 m        /convex/faces (F, 3) int32   (all parts, concatenated)
    /convex/vertex_offsets (p + 1,) int64    /convex/face_offsets (p + 1,) int64
    /mass/center_of_mass (3,) m              /mass/inertia (3, 3) kg m^2 about the COM, mesh frame
    /stable_poses/transforms (n, 4, 4)       /stable_poses/probabilities (n,)
    attributes: name, source_file, source_sha256, scale, density, mass, volume, watertight,
                from_convex_hull, repair_notes, warnings, params,
                friction, category (only for an object whose manifest row gives them)

A manifest row's own values (scale, mass or density, friction, category) enter its task's payload, so its key: a
changed friction makes that object stale, not the others. An object without them has the payload (and the shard)
it had before manifests existed.

A procedural object has no input file: its payload holds its shape's whole spec (family, seed, index, extents and the
drawn family parameters, :meth:`~graspgen.geometry.procedural.ProceduralShape.spec`), so the same seed gives the same
keys, and its task builds the mesh from that spec alone, writes it as ``<name>.obj`` (exact floats) into a temporary
folder and prepares that file like any other (scale 1: the mesh is in metres).

A broken file fails its own task with a message naming the file and the reason; the other objects go on.
"""

from __future__ import annotations

import dataclasses
import glob
import json
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from graspgen.errors import InputError
from graspgen.geometry.convex import CoacdParams
from graspgen.geometry.procedural import ProceduralParams, ProceduralShape, build_mesh, draw_shapes, shape_from_spec
from graspgen.geometry.stable_poses import StablePoseParams
from graspgen.io.acronym import obj_text
from graspgen.io.files import write_h5
from graspgen.io.objects import object_tree, read_object_manifest
from graspgen.validation import check
from graspgen.workflows.prepare import prepare_object
from pipeline.config import to_dict
from pipeline.errors import ConfigError
from pipeline.keys import KEY_OMIT_DEFAULT
from pipeline.stage import RunContext, Task, Upstream
from stages.base import GraspStage

ASSETS = Path(__file__).resolve().parent.parent / "assets" / "objects"
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
        if self.manifest is not None:
            check("manifest", bool(self.manifest.strip()), "be a file path (or null for none)", self.manifest)
        if self.scale is not None:
            check("scale", self.scale > 0, "be > 0 (or null to detect)", self.scale)
        check("min_extent", self.min_extent > 0, "be > 0", self.min_extent)
        check("max_extent", self.max_extent > self.min_extent, "be > min_extent", self.max_extent)
        check("density", self.density > 0, "be > 0", self.density)
        for name, rho in self.densities.items():
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


def discover(params: ObjectsParams) -> list[tuple[str, Path, float | None]]:
    """(name, path, density) of every object the params select, sorted by name; the density is None for a
    manifest object given by its mass (:func:`object_sources` has everything).

    Raises
    ------
    ConfigError
        See :func:`object_sources`.
    """
    return [(s.name, s.path, s.density) for s in object_sources(params)]


def object_sources(params: ObjectsParams) -> list[ObjectSource]:
    """Every object the params select (bundled, ``objects.paths``, ``objects.manifest``, ``objects.procedural``),
    sorted by name.

    Raises
    ------
    ConfigError
        A glob matching nothing, two files with one name, a manifest that cannot be used (the message names its
        file, row and column), a manifest name already taken, an ``include`` name that is not found.
    """
    found: dict[str, ObjectSource] = {}

    def add(source: ObjectSource) -> None:
        name, path = source.name, source.path
        if name in found and found[name].path != path:
            raise ConfigError(
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
            raise ConfigError(
                f"{source.origin}, column 'name': the name {source.name!r} is already taken by {other.path} "
                f"({other.origin}); names must be unique: set another in the name column"
            )
        found[source.name] = source
    for source in procedural_sources(params):
        if source.name in found:
            raise ConfigError(f"objects.procedural: the name {source.name!r} is already taken by "
                              f"{found[source.name].path} ({found[source.name].origin}); rename that file")
        found[source.name] = source
    if params.include:
        missing = sorted(set(params.include) - set(found))
        if missing:
            raise ConfigError(f"objects.include: no object named {missing[0]!r}; available: {', '.join(sorted(found))}")
        found = {n: v for n, v in found.items() if n in params.include}
    if not found:
        raise ConfigError("objects: no objects selected (bundled is false, paths and manifest are empty and "
                          "procedural is null)")
    return [found[name] for name in sorted(found)]


def manifest_sources(params: ObjectsParams) -> list[ObjectSource]:
    """The objects of ``objects.manifest`` (none when it is null), in file order: the row's own mass or density
    (else ``objects.densities`` by name, else ``objects.density``), scale, friction and category.

    Raises
    ------
    ConfigError
        The manifest cannot be used: ``objects.manifest: <file>: row <n> (line <l>), column '<c>': why``.
    """
    if params.manifest is None:
        return []
    manifest = Path(params.manifest)
    try:
        entries = read_object_manifest(manifest)
    except InputError as exc:
        raise ConfigError(f"objects.manifest: {exc}") from None
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
    ConfigError
        A pattern matching no mesh file.
    """
    found = []
    for i, pattern in enumerate(params.paths):
        matches = sorted(Path(p) for p in glob.glob(pattern, recursive=True))
        meshes = [p for p in matches if p.is_file() and p.suffix.lower() in MESH_SUFFIXES]
        if not meshes:
            raise ConfigError(f"objects.paths[{i}]: {pattern!r} matches no mesh file ({', '.join(MESH_SUFFIXES)})")
        found.extend(meshes)
    return found


def left_out_by_include(params: ObjectsParams) -> list[Path]:
    """The meshes ``objects.paths`` matches that ``objects.include`` leaves out (sorted, each once)."""
    if not params.include or not params.paths:
        return []
    return sorted({p for p in user_meshes(params) if p.stem not in params.include})


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


class ObjectsStage(GraspStage):
    name = "objects"
    inputs = ()
    version = 1
    ext = "h5"

    def tasks(self, params: ObjectsParams, upstream: Upstream) -> list[Task]:
        return [
            Task(id=source.name, payload=source.payload(), inputs=source.inputs())
            for source in object_sources(params)
        ]

    def plan_warnings(self, params: ObjectsParams, upstream: Upstream) -> list[str]:
        left = left_out_by_include(params)
        if not left:
            return []
        names = ", ".join(str(p) for p in left)
        return [
            f"objects.include leaves out {len(left)} mesh(es) that objects.paths matches: {names} "
            "(add their names to objects.include to use them)"
        ]

    def run(
        self,
        task: Task,
        params: ObjectsParams,
        upstream: Upstream,
        rng: np.random.Generator,
        out: Path,
        ctx: RunContext,
    ) -> dict[str, Any]:
        payload = task.payload
        if "procedural" in payload:
            with tempfile.TemporaryDirectory(prefix="graspgen-procedural-") as tmp:
                return self._prepare(task, params, rng, out, ctx, _write_procedural(payload["procedural"], Path(tmp)))
        return self._prepare(task, params, rng, out, ctx, Path(task.inputs[0]))

    def _prepare(
        self, task: Task, params: ObjectsParams, rng: np.random.Generator, out: Path, ctx: RunContext, path: Path
    ) -> dict[str, Any]:
        payload = task.payload
        try:
            prepared = prepare_object(
                path,
                density=payload.get("density"),
                mass=payload.get("mass"),
                scale=payload["scale"] if "scale" in payload else params.scale,
                min_extent=params.min_extent,
                max_extent=params.max_extent,
                coacd=params.coacd,
                poses=params.stable_poses,
                rng=rng,
                coacd_cache_dir=ctx.cache_dir / "coacd",
            )
        except InputError as exc:
            raise InputError(_with_path(str(exc), path)) from None
        tree = object_tree(
            task.id, path, prepared, to_dict(params), friction=payload.get("friction"), category=payload.get("category")
        )
        write_h5(out, tree)
        return {
            "mass": prepared.mass.mass,
            "parts": len(prepared.convex_parts),
            "stable_poses": int(len(prepared.stable_probabilities)),
            "warnings": object_warnings(path, prepared.warnings, prepared.repair.notes),
        }


def _write_procedural(spec: dict[str, Any], folder: Path) -> Path:
    """Build a procedural object's mesh from its spec and write it as ``folder/<name>.obj``; returns the path (the
    shard records the file name and its bytes' sha256, both fixed by the spec)."""
    shape = shape_from_spec(spec)
    mesh = build_mesh(shape)
    path = folder / f"{shape.name}.obj"
    path.write_text(obj_text(mesh.vertices, mesh.faces), encoding="utf-8")
    return path


def _with_path(message: str, path: Path) -> str:
    """The message naming the file by its path: mesh preparation names it by file name only (what it stores in
    shards must not depend on where the input lives), but a user fixing inputs wants the folder too."""
    if message.startswith(str(path)):
        return message
    short = f"{path.name}: "
    return f"{path}: {message[len(short):] if message.startswith(short) else message}"


