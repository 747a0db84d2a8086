"""The engine at 10k+ tasks: what the scheduler, the manifests, ``status`` and a no-op rerun cost per shard.

The engine tests' toy pipeline (``tests/toy_stages.py``, no domain code): ``numbers`` has N tasks
(``numbers.count``), each spinning for ``--work-ms`` of CPU and writing a 2 kB shard from its rng; ``sums`` has one
task that reads every ``numbers`` shard (as the dataset stage reads its inputs) and publishes a one-line file. For
each N it measures, in one process (the scheduler's) with ``--jobs`` loky workers:

- the cold run: wall time, the tasks' own CPU seconds, and the engine's overhead per task in CPU seconds (so a
  loaded machine does not inflate it): the scheduler process's CPU plus the workers' CPU outside the tasks
  (dispatch, unpickling, keys, atomic writes, sha256, start-up), divided by N; also in wall terms,
  ``(wall * workers - task seconds) / N``;
- a baseline in the same process: ``joblib.Parallel`` over the same N task functions, no keys, no manifest, no
  shards, so the ratio says what the engine adds over bare joblib;
- ``Manifest.entries()`` (parsing one stage's manifest), ``status`` (with sha256 checks of every shard, as
  ``gen status`` does) and the no-op rerun (every task skipped after its shard is checked);
- peak resident memory of the scheduler process (``ru_maxrss``), sampled after each N.

Run: ``python -m bench.bench_engine [--sizes 1000 10000] [--jobs 2] [--work-ms 5]``; prints a table and writes
``bench/results_engine.json``. Linear means: per-task figures flat across N.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import shutil
import tempfile
import time
from pathlib import Path

import joblib
import numpy as np

from pipeline.config import RunConfig
from pipeline.scheduler import run_pipeline
from pipeline.status import status
from pipeline.store import Manifest, stage_dir
from tests.toy_stages import TOY, NumbersParams, ToyConfig, spin

SHARD_DRAWS = 100
"""Draws per shard: about 2 kB of JSON."""


def _bare_task(i: int, work_ms: float) -> float:
    rng = np.random.default_rng(i)
    spin(work_ms / 1000.0)
    return float(rng.normal(size=SHARD_DRAWS).sum())


def _timed(fn) -> tuple[float, float, object]:
    wall, cpu = time.perf_counter(), time.process_time()
    result = fn()
    return time.perf_counter() - wall, time.process_time() - cpu, result


def measure(n: int, jobs: int, work_ms: float, root: Path) -> dict:
    """One size: cold run, baseline, manifest read, status, no-op rerun."""
    out = root / f"n{n}"
    config = ToyConfig(
        run=RunConfig(out=str(out), jobs=jobs, cache_dir=str(root / "cache")),
        numbers=NumbersParams(count=n, work_ms=work_ms, size=SHARD_DRAWS),
    )
    cold_wall, cold_cpu, reports = _timed(lambda: run_pipeline(TOY, config))
    numbers = next(r for r in reports if r.stage == "numbers")
    assert numbers.ran == n, numbers
    entries = Manifest(stage_dir(out, "numbers")).entries()
    task_seconds = sum(e.seconds for e in entries.values())
    task_cpu = sum(e.meta["cpu"] for e in entries.values())
    worker_cpu: dict[int, float] = {}
    for e in entries.values():
        worker_cpu[e.meta["pid"]] = max(worker_cpu.get(e.meta["pid"], 0.0), e.meta["worker_cpu"])
    # A worker's clock includes its start-up (imports): counted as overhead, as a run pays it too.
    overhead_cpu = (sum(worker_cpu.values()) - task_cpu + cold_cpu) / n
    base_wall, _, _ = _timed(
        lambda: joblib.Parallel(n_jobs=jobs)(joblib.delayed(_bare_task)(i, work_ms) for i in range(n))
    )
    manifest_wall, _, _ = _timed(lambda: Manifest(stage_dir(out, "numbers")).entries())
    status_wall, status_cpu, states = _timed(lambda: status(TOY, config))
    assert all(s.state == "done" for s in states), states
    noop_wall, noop_cpu, again = _timed(lambda: run_pipeline(TOY, config))
    numbers = next(r for r in again if r.stage == "numbers")
    assert numbers.ran == 0 and numbers.skipped == n, numbers
    overhead = (cold_wall * jobs - task_seconds) / n
    return {
        "tasks": n,
        "jobs": jobs,
        "work_ms": work_ms,
        "cold_wall_s": round(cold_wall, 3),
        "cold_scheduler_cpu_s": round(cold_cpu, 3),
        "task_seconds": round(task_seconds, 3),
        "task_cpu_s": round(task_cpu, 3),
        "workers": len(worker_cpu),
        "overhead_wall_ms_per_task": round(1000 * overhead, 3),
        "overhead_cpu_ms_per_task": round(1000 * overhead_cpu, 3),
        "overhead_cpu_share_of_task": round(overhead_cpu / (task_cpu / n), 4),
        "scheduler_cpu_ms_per_task": round(1000 * cold_cpu / n, 3),
        "baseline_joblib_wall_s": round(base_wall, 3),
        "engine_over_joblib": round(cold_wall / base_wall, 3),
        "manifest_read_s": round(manifest_wall, 4),
        "status_s": round(status_wall, 3),
        "status_ms_per_shard": round(1000 * status_wall / n, 4),
        "noop_rerun_s": round(noop_wall, 3),
        "noop_ms_per_shard": round(1000 * noop_wall / n, 4),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000], help="task counts (default 1000 10000)")
    parser.add_argument("--jobs", type=int, default=2, help="loky workers (default 2)")
    parser.add_argument("--work-ms", type=float, default=5.0, help="CPU ms per task (default 5)")
    parser.add_argument("--json", default="bench/results_engine.json", help="where to write the results")
    args = parser.parse_args()
    root = Path(tempfile.mkdtemp(prefix="bench_engine_"))
    rows = []
    try:
        for n in args.sizes:
            rows.append(measure(n, args.jobs, args.work_ms, root))
            print(json.dumps(rows[-1]), flush=True)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    cols = ["tasks", "cold_wall_s", "overhead_cpu_ms_per_task", "overhead_cpu_share_of_task", "engine_over_joblib",
            "manifest_read_s", "status_s", "noop_rerun_s", "peak_rss_mb"]
    print("\n" + " | ".join(cols))
    for row in rows:
        print(" | ".join(str(row[c]) for c in cols))
    Path(args.json).write_text(json.dumps({"machine": platform.platform(), "rows": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main()
