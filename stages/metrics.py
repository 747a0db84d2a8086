"""Stage 6, ``metrics``: Ferrari-Canny epsilon, force closure, minimum closure friction, and the probability of
force closure and robust epsilon under contact noise (``pfc_contact``, ``epsilon_robust``) of every grasp.

One task per scene; the work is :func:`graspgen.workflows.metrics.scene_metrics` (see there for the columns). The
task's ``rng`` is the contact noise's only source.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from graspgen.io.files import write_parquet
from graspgen.io.objects import read_object
from graspgen.io.scenes import read_scene
from graspgen.quality.contact_noise import MetricsParams
from graspgen.quality.contact_set import CONTACT_SOURCES
from graspgen.workflows.metrics import scene_metrics
from pipeline.stage import RunContext, Task, Upstream
from stages.base import GraspStage


class MetricsStage(GraspStage):
    name = "metrics"
    inputs = ("rollouts", "grasps", "scenes", "objects")
    version = 1
    ext = "parquet"

    def tasks(self, params: MetricsParams, upstream: Upstream) -> list[Task]:
        library = upstream.ids("objects")
        return [
            Task(id=sid, needs={"rollouts": [sid], "grasps": [sid], "scenes": [sid], "objects": library})
            for sid in upstream.ids("rollouts")
        ]

    def run(
        self,
        task: Task,
        params: MetricsParams,
        upstream: Upstream,
        rng: np.random.Generator,
        out: Path,
        ctx: RunContext,
    ) -> dict[str, Any]:
        grasps = pq.read_table(upstream.path("grasps", task.id))
        rollouts = pq.read_table(upstream.path("rollouts", task.id))
        scene = read_scene(upstream.path("scenes", task.id))
        records = {n: read_object(upstream.path("objects", n)) for n in sorted(set(scene.object_names))}
        table = scene_metrics(grasps, rollouts, scene, records, params, rng)
        write_parquet(out, table)
        sources = table.column("contact_source").to_pylist()
        eps = table.column("epsilon").to_numpy()
        pfc = table.column("pfc_contact").to_numpy()
        return {
            "grasps": len(table),
            "contact_source": {s: sources.count(s) for s in CONTACT_SOURCES},
            "force_closure": int((eps > 0).sum()),
            "mean_pfc_contact": round(float(pfc.mean()), 6) if len(pfc) else None,
        }
