"""Stage 4, ``rollouts``: every collision-free grasp of a scene grasped and lifted in MuJoCo (outcome codes 0-5).

One task per scene; the work is :func:`graspgen.workflows.rollouts.roll_out_table` (see there for the columns).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from graspgen.io.files import write_parquet
from graspgen.io.objects import read_object
from graspgen.sim.protocols import OUTCOME_NAMES
from graspgen.workflows.rollouts import RolloutsParams, roll_out_table, scene_simulator
from pipeline.stage import RunContext, Task, Upstream
from stages.base import GraspStage


class RolloutsStage(GraspStage):
    name = "rollouts"
    inputs = ("grasps", "scenes", "objects")
    version = 1
    ext = "parquet"

    def tasks(self, params: RolloutsParams, upstream: Upstream) -> list[Task]:
        library = upstream.ids("objects")
        # The pre-filter's free grasps are the ones simulated (the rest cost nothing unless simulate_rejected).
        return [
            Task(
                id=sid,
                needs={"grasps": [sid], "scenes": [sid], "objects": library},
                cost=float(upstream.meta("grasps", sid).get("prefilter", {}).get("free", 0)),
            )
            for sid in upstream.ids("grasps")
        ]

    def run(
        self,
        task: Task,
        params: RolloutsParams,
        upstream: Upstream,
        rng: np.random.Generator,
        out: Path,
        ctx: RunContext,
    ) -> dict[str, Any]:
        grasps = pq.read_table(upstream.path("grasps", task.id))
        scene, simulator = scene_simulator(
            upstream.path("scenes", task.id),
            lambda name: read_object(upstream.path("objects", name)),
            grasps.column("gripper")[0].as_py() if len(grasps) else "robotiq_2f85",
            params.lift,
        )
        table = roll_out_table(scene, simulator, grasps, params)
        write_parquet(out, table)
        outcomes = table.column("outcome").to_numpy()
        return {
            "grasps": len(table),
            "simulated": int(np.sum(table.column("simulated").to_numpy(zero_copy_only=False))),
            "outcomes": {name: int((outcomes == c).sum()) for c, name in enumerate(OUTCOME_NAMES)},
            "steps": int(np.sum(table.column("steps").to_numpy())),
        }
