"""Stage ``probe``: can a network learn these labels? A small grasp evaluator trained on the object-centric sets.

One task (``probe``) reads what the dataset publishes of the object-centric sets: every object's mesh (``objects``)
and its labelled grasps (``object_grasps``: TCP pose in the object frame, width, and the set's label: ``firm`` or
``success``). It splits the objects
by a hash of their name (:func:`graspgen.learn.sources.split_by_object`: ``valid_fraction``, ``salt``), trains
:class:`graspgen.learn.model.PointNetEvaluator` on the training objects and scores the held-out ones, beside three
baselines (base rate, per-object rate, gradient-boosted trees): :func:`graspgen.learn.probe.run_probe`. The shard
(HDF5, :func:`graspgen.io.probe_files.write_probe_shard`) holds the model file's bytes and the report without its
timings (those go to the manifest meta); the ``dataset`` stage publishes both (``probe/model.pt``,
``probe/report.json``) and renders the card's "Learnability" section from the report. It runs before ``dataset``
so that the card lists both files with their sha256 in the same publish.

Without torch (and scikit-learn) a run with ``probe.enabled: true`` stops before any work with one line naming the
install and ``probe.enabled: false`` as the way out (:meth:`ProbeStage.check`). It does not quietly skip itself: the
same config must give the same dataset on every machine, and a dataset whose card lacks the check because one
machine lacked a package would differ from the one made elsewhere with the same config. What a config decides is
skipped with a warning instead, the same everywhere: fewer than two objects with grasps, or a split that leaves no
object on one side (the card says why it did not run).

Training runs on one thread with seeded draws (the task's generator seeds ``TrainParams.seed``), so the same config
gives the same bytes for any number of workers, on this machine's torch build.
"""

from __future__ import annotations

import io
import time
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from graspgen.errors import MissingDependencyError
from graspgen.io.objects import read_object
from graspgen.io.probe_files import clean_report, write_probe_shard
from graspgen.learn import require_torch
from graspgen.learn.probe_settings import ProbeParams
from graspgen.learn.sources import ObjectGraspSet, held_out, label_column, record_physics
from pipeline.errors import ConfigError
from pipeline.stage import RunContext, Task, Upstream
from stages.base import GraspStage

__all__ = ["ProbeParams", "ProbeStage", "object_set"]

TASK = "probe"
"""The stage's one task (and the dataset stage's name for it)."""


def object_set(name: str, upstream: Upstream) -> ObjectGraspSet:
    """The object-centric set of ``name`` from its ``objects`` and ``object_grasps`` shards (split group: its name,
    as for a published dataset), labelled by the set's own label (``object_grasps.label``: ``firm`` or ``held``)."""
    record = read_object(upstream.path("objects", name))
    meta = upstream.meta("object_grasps", name)
    column = label_column(meta.get("label"))
    table = pq.read_table(upstream.path("object_grasps", name), columns=["pose_object", "width", column, "gripper"])
    n = len(table)
    poses = np.asarray(table.column("pose_object").to_pylist(), dtype=np.float64).reshape(n, 4, 4)
    grippers = sorted(set(table.column("gripper").to_pylist()))
    return ObjectGraspSet(
        name=name,
        group=name,
        vertices=np.asarray(record.vertices, dtype=np.float64),
        faces=np.asarray(record.faces, dtype=np.int64),
        T_tcp=poses,
        width=table.column("width").to_numpy().astype(np.float64),
        label=table.column(column).to_numpy(zero_copy_only=False).astype(bool),
        gripper=grippers[0] if grippers else "",
        source="dataset",
        physics=record_physics(record, meta.get("label") or "held", meta.get("protocol", "acronym"),
                               meta.get("friction")),
    )


class ProbeStage(GraspStage):
    name = "probe"
    inputs = ("objects", "object_grasps")
    version = 1
    ext = "h5"

    def check(self, params: ProbeParams) -> None:
        if not params.enabled:
            return
        try:
            require_torch()
        except MissingDependencyError as exc:
            raise ConfigError(f"probe.enabled: true, but {exc}; or set probe.enabled: false to make the dataset "
                              "without its learnability check") from None

    def _plan(self, params: ProbeParams, upstream: Upstream) -> tuple[list[str], str | None]:
        """The objects the probe reads (those with labelled grasps, sorted), or why it does not run."""
        if not params.enabled:
            return [], None
        have = set(upstream.ids("objects"))
        names = [n for n in upstream.ids("object_grasps") if n in have and _rows(upstream, n) > 0]
        if len(names) < 2:
            return [], (f"not run: {len(names)} object(s) with object-centric grasps; it needs two, one to train on "
                        "and one to hold out (or set probe.enabled: false)")
        valid = [n for n in names if held_out(n, params.valid_fraction, params.salt)]  # group: the name
        if not valid or len(valid) == len(names):
            side = "held-out" if not valid else "training"
            return [], (f"not run: the split of {len(names)} objects (probe.valid_fraction {params.valid_fraction}, "
                        f"probe.salt {params.salt!r}) leaves the {side} side empty; change probe.salt or "
                        "probe.valid_fraction (or set probe.enabled: false)")
        return names, None

    def tasks(self, params: ProbeParams, upstream: Upstream) -> list[Task]:
        names, _ = self._plan(params, upstream)
        if not names:
            return []
        grasps = sum(_rows(upstream, n) for n in names)
        return [Task(id=TASK, payload={"objects": names}, needs={"objects": names, "object_grasps": names},
                     cost=float(grasps))]

    def plan_warnings(self, params: ProbeParams, upstream: Upstream) -> list[str]:
        _, why = self._plan(params, upstream)
        return [why] if why else []

    def run(
        self,
        task: Task,
        params: ProbeParams,
        upstream: Upstream,
        rng: np.random.Generator,
        out: Path,
        ctx: RunContext,
    ) -> dict[str, Any]:
        from graspgen.learn.probe import run_probe
        from graspgen.learn.train import save_model

        sets = [object_set(name, upstream) for name in task.payload["objects"]]
        seed = int(rng.integers(0, 2**31 - 1))
        start = time.perf_counter()
        model, report = run_probe(sets, params, seed=seed)
        buffer = io.BytesIO()
        save_model(model, buffer)  # the same model -> the same bytes, in any process (graspgen.io.probe_files)
        model_bytes = buffer.getvalue()
        report, timings = clean_report(report)
        write_probe_shard(out, model_bytes, report)
        net = report.get("network", {})
        return {"objects": len(sets), "grasps": int(sum(len(s.label) for s in sets)),
                "train_objects": len(report["split"]["train_objects"]),
                "valid_objects": len(report["split"]["valid_objects"]),
                "auc": net.get("auc"), "mean_object_auc": net.get("mean_object_auc"),
                "model_bytes": len(model_bytes), **timings, "task_seconds": time.perf_counter() - start}


def _rows(upstream: Upstream, name: str) -> int:
    """Grasps kept in an object's set, from its task's manifest meta (no read)."""
    meta = upstream.meta("object_grasps", name)
    return int(meta.get("positives", 0)) + int(meta.get("negatives", 0))
