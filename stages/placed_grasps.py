"""Stage ``placed_grasps``: every scene's objects given their object-level grasp sets, as ACRONYM builds its scenes.

One task per scene; the work is :func:`graspgen.workflows.placed_grasps.place_object_grasps` (see there for the check,
the label and the table's columns). A task reads its scene, and the object records and object grasp sets (stage
``object_grasps``, one shard per object, task id = object name) of the objects the scenes stage's manifest says the
scene holds (every object when the manifest does not say). An object without a grasp set stays an obstacle and gets
no rows; the task's warnings name it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from graspgen.io.files import write_parquet
from graspgen.io.objects import read_object
from graspgen.workflows.placed_grasps import PlacedGraspsParams, place_object_grasps
from pipeline.stage import RunContext, Task, Upstream
from stages.base import GraspStage


class PlacedGraspsStage(GraspStage):
    name = "placed_grasps"
    inputs = ("object_grasps", "scenes", "objects")
    version = 1
    ext = "parquet"

    def params(self, config: Any) -> PlacedGraspsParams:
        """The library's settings of the ``placed_grasps`` section (its derived keys filled in)."""
        return config.placed_grasps.library_params()

    def tasks(self, params: PlacedGraspsParams, upstream: Upstream) -> list[Task]:
        library = upstream.ids("objects")
        with_sets = set(upstream.ids("object_grasps"))
        tasks = []
        for sid in upstream.ids("scenes"):
            names = upstream.meta("scenes", sid).get("objects")
            names = sorted(set(names)) if names else library
            sets = [n for n in names if n in with_sets]
            tasks.append(Task(id=sid, needs={"scenes": [sid], "objects": names, "object_grasps": sets},
                              cost=float(len(sets))))
        return tasks

    def run(
        self,
        task: Task,
        params: PlacedGraspsParams,
        upstream: Upstream,
        rng: np.random.Generator,
        out: Path,
        ctx: RunContext,
    ) -> dict[str, Any]:
        assert task.needs is not None
        with_sets = set(task.needs["object_grasps"])

        def load_grasps(name: str) -> pa.Table | None:
            return pq.read_table(upstream.path("object_grasps", name)) if name in with_sets else None

        table, meta = place_object_grasps(
            upstream.path("scenes", task.id),
            lambda name: read_object(upstream.path("objects", name)),
            load_grasps,
            params,
            rng,
        )
        write_parquet(out, table)
        missing = meta["objects_without_grasps"]
        if missing:
            meta["warnings"] = [f"object {n!r} has no object grasp set: it is an obstacle only" for n in missing]
        return meta
