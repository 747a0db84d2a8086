"""Stage 3, ``grasps``: antipodal grasp candidates on every object of a scene, checked by the collision pre-filter.

One task per scene; the work is :func:`graspgen.sim.scene_grasps.sample_scene_grasps` (see there for the table's
columns). This module fans it out and writes the Parquet shard.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from graspgen.io.files import write_parquet
from graspgen.io.objects import read_object
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
        return [Task(id=sid, needs={"scenes": [sid], "objects": library}) for sid in upstream.ids("scenes")]

    def run(
        self,
        task: Task,
        params: GraspsParams,
        upstream: Upstream,
        rng: np.random.Generator,
        out: Path,
        ctx: RunContext,
    ) -> dict[str, Any]:
        table, meta = sample_scene_grasps(
            upstream.path("scenes", task.id), lambda name: read_object(upstream.path("objects", name)), params, rng
        )
        write_parquet(out, table)
        return meta
