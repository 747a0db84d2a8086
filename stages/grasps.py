"""Stage 3, ``grasps``: antipodal grasp candidates on every object of a scene, checked by the collision pre-filter.

One task per scene; the work is :func:`graspgen.sim.scene_grasps.sample_scene_grasps` (see there for the table's
columns). This module fans it out and writes the Parquet shard. A target object of the scene that gets no
candidate at all is named in the task's warnings (:func:`ungraspable`), with the reason when its size says it:
wider at its narrowest than the gripper can close on.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import trimesh

from graspgen.io.files import write_parquet
from graspgen.io.objects import ObjectRecord, read_object
from graspgen.sim.grippers import gripper_files, load_gripper
from graspgen.sim.scene_grasps import GraspsParams, sample_scene_grasps
from pipeline.errors import ConfigError
from pipeline.stage import RunContext, Task, Upstream
from stages.base import GraspStage


class GraspsStage(GraspStage):
    name = "grasps"
    inputs = ("scenes", "objects")
    version = 1
    ext = "parquet"

    def tasks(self, params: GraspsParams, upstream: Upstream) -> list[Task]:
        library = upstream.ids("objects")
        unknown = sorted(set(params.targets) - set(library))
        if unknown:
            raise ConfigError(f"grasps.targets: no object named {unknown[0]!r}; available: {', '.join(library)}")
        gripper = gripper_files(params.gripper)  # a gripper file's bytes (and its meshes') enter the keys
        return [Task(id=sid, needs={"scenes": [sid], "objects": library}, inputs=gripper)
                for sid in upstream.ids("scenes")]

    def run(
        self,
        task: Task,
        params: GraspsParams,
        upstream: Upstream,
        rng: np.random.Generator,
        out: Path,
        ctx: RunContext,
    ) -> dict[str, Any]:
        records: dict[str, ObjectRecord] = {}

        def load(name: str) -> ObjectRecord:
            records[name] = read_object(upstream.path("objects", name))
            return records[name]

        table, meta = sample_scene_grasps(upstream.path("scenes", task.id), load, params, rng)
        write_parquet(out, table)
        warnings = ungraspable(table, records, params)
        return {**meta, "warnings": warnings} if warnings else meta


def narrowest_width(vertices: np.ndarray) -> float:
    """The object's width at its narrowest, m: the smallest extent of its convex hull along a hull face normal
    (the exact minimum or slightly above it). 0 for a flat or degenerate point set."""
    try:
        hull = trimesh.convex.convex_hull(np.asarray(vertices, dtype=np.float64))
    except Exception:  # noqa: BLE001 - qhull refuses flat sets: no width to speak of
        return 0.0
    if len(hull.faces) == 0:
        return 0.0
    extents = np.ptp(hull.vertices @ hull.face_normals.T, axis=0)
    return float(extents.min())


def ungraspable(table: pa.Table, records: Mapping[str, ObjectRecord], params: GraspsParams) -> list[str]:
    """Warnings naming each target object of a scene that got no grasp candidate, and the gripper.

    ``records`` are the scene's objects by name, ``table`` its grasp table. When the object is wider at its
    narrowest (:func:`narrowest_width`) than the gripper closes on (its stroke less ``sampler.min_clearance``) the
    warning says so; otherwise, when rejected candidates are kept (``keep_rejected``), that no contact pair passed
    the sampler's checks. With ``keep_rejected`` false an object without rows may just have had every candidate in
    collision: no warning then. The texts do not name the scene, so the engine lists a warning once with the
    scenes that give it.
    """
    have = set(table.column("object_name").to_pylist())
    gripper = load_gripper(params.gripper)
    opening = gripper.max_width - params.sampler.min_clearance
    out = []
    for name in sorted(records):
        if name in have or (params.targets and name not in params.targets):
            continue
        width = narrowest_width(records[name].vertices)
        if width > opening:
            out.append(
                f"gripper {params.gripper} cannot grasp object {name!r}: it is {1000 * width:.0f} mm across at its "
                f"narrowest, the gripper closes on at most {1000 * opening:.0f} mm ({1000 * gripper.max_width:.0f} "
                f"mm stroke less grasps.sampler.min_clearance)"
            )
        elif params.keep_rejected:
            out.append(
                f"gripper {params.gripper} found no grasp on object {name!r}: no contact pair passed the sampler's "
                "checks (friction cone, width, approach direction: grasps.sampler)"
            )
    return out
