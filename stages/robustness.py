"""Stage 5, ``robustness``: every successful grasp rolled out again from perturbed copies (TCP pose, optionally the
object's planar pose, the object's mass, centre of mass and friction).

One task per scene; the work is :func:`graspgen.workflows.robustness.scene_robustness` (see there for what is
perturbed and the columns: ``robustness``, and ``grip_robustness`` over the copies not stopped by a collision).
Version 2: 14 draws per copy (mass, centre of mass, friction), the ``grip_robustness`` columns. Version 3: the
centre-of-mass offset is on by default (5 mm) and held over the object's support (``resting_com_offset``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from graspgen.io.files import write_parquet
from graspgen.io.objects import ObjectRecord, read_object
from graspgen.workflows.robustness import RobustnessTaskParams, scene_robustness
from graspgen.workflows.rollouts import scene_simulator
from pipeline.stage import RunContext, Task, Upstream
from stages.base import GraspStage


class RobustnessStage(GraspStage):
    name = "robustness"
    inputs = ("rollouts", "grasps", "scenes", "objects")
    version = 3
    ext = "parquet"

    def params(self, config: Any) -> RobustnessTaskParams:
        """Its own section plus what the copies share with other stages: the rollout protocol
        (``rollouts.lift``) and the epsilon model (``metrics.epsilon``). All three enter the key."""
        return RobustnessTaskParams(robustness=config.robustness, lift=config.rollouts.lift,
                                    epsilon=config.metrics.epsilon)

    def tasks(self, params: RobustnessTaskParams, upstream: Upstream) -> list[Task]:
        library = upstream.ids("objects")
        # Only successful grasps are perturbed, so a scene's work grows with its successes.
        return [
            Task(
                id=sid,
                needs={"rollouts": [sid], "grasps": [sid], "scenes": [sid], "objects": library},
                cost=float(upstream.meta("rollouts", sid).get("outcomes", {}).get("success", 0)),
            )
            for sid in upstream.ids("rollouts")
        ]

    def run(
        self,
        task: Task,
        params: RobustnessTaskParams,
        upstream: Upstream,
        rng: np.random.Generator,
        out: Path,
        ctx: RunContext,
    ) -> dict[str, Any]:
        grasps = pq.read_table(upstream.path("grasps", task.id))
        rollouts = pq.read_table(upstream.path("rollouts", task.id))
        records: dict[str, ObjectRecord] = {}

        def load(name: str) -> ObjectRecord:
            if name not in records:
                records[name] = read_object(upstream.path("objects", name))
            return records[name]

        gripper = grasps.column("gripper")[0].as_py() if len(grasps) else "robotiq_2f85"
        scene, simulator = scene_simulator(upstream.path("scenes", task.id), load, gripper, params.lift)
        table, meta = scene_robustness(grasps, rollouts, simulator.cpu, scene.object_names, scene.friction, records,
                                       params, rng)
        write_parquet(out, table)
        return meta
