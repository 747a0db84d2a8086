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

import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from graspgen.errors import InputError
from graspgen.geometry.procedural import build_mesh, shape_from_spec
from graspgen.io.acronym import obj_text
from graspgen.io.files import write_h5
from graspgen.io.object_sources import (  # ASSETS, ObjectsParams and catalog: re-exported for the config and tests
    ASSETS,
    ObjectSelectionError,
    ObjectSource,
    ObjectsParams,
    catalog,
    left_out_by_include,
    object_sources,
)
from graspgen.io.objects import object_tree
from graspgen.workflows.prepare import object_warnings, prepare_object
from pipeline.config import to_dict
from pipeline.errors import ConfigError
from pipeline.stage import RunContext, Task, Upstream
from stages.base import GraspStage

__all__ = ["ASSETS", "ObjectsParams", "ObjectsStage", "catalog", "discover", "left_out_by_include", "object_warnings",
           "selected_objects"]


def selected_objects(params: ObjectsParams) -> list[ObjectSource]:
    """Every object the params select, sorted by name: :func:`graspgen.io.object_sources.object_sources` with the
    engine's error.

    Raises
    ------
    ConfigError
        The selection cannot be used (the library's :class:`~graspgen.io.object_sources.ObjectSelectionError`,
        same message).
    """
    try:
        return object_sources(params)
    except ObjectSelectionError as exc:
        raise ConfigError(str(exc)) from None


def discover(params: ObjectsParams) -> list[tuple[str, Path, float | None]]:
    """(name, path, density) of every object the params select, sorted by name; the density is None for a
    manifest object given by its mass (:func:`selected_objects` has everything).

    Raises
    ------
    ConfigError
        See :func:`selected_objects`.
    """
    return [(s.name, s.path, s.density) for s in selected_objects(params)]


class ObjectsStage(GraspStage):
    name = "objects"
    inputs = ()
    version = 1
    ext = "h5"

    def tasks(self, params: ObjectsParams, upstream: Upstream) -> list[Task]:
        return [
            Task(id=source.name, payload=source.payload(), inputs=source.inputs())
            for source in selected_objects(params)
        ]

    def plan_warnings(self, params: ObjectsParams, upstream: Upstream) -> list[str]:
        try:
            left = left_out_by_include(params)
        except ObjectSelectionError as exc:
            raise ConfigError(str(exc)) from None
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


