"""End to end: the whole default config, cold and warm, one and two workers (ARCHITECTURE.md, Performance bars).

Runs, each in a fresh Python process (``--child`` mode of this script, which calls
:func:`pipeline.scheduler.run_pipeline`) into its own output folder under ``build/bench_e2e``:

1. ``cold``: a fresh output folder and a fresh CoACD cache, ``--jobs 2``: what a first ``make dataset`` costs;
2. ``warm``: the same command again: every task is skipped (what a second ``make dataset`` costs);
3. ``jobs1`` and ``jobs2``: a fresh output folder with the CoACD cache of run 1, ``--jobs 1`` and ``--jobs 2``:
   the compute of the pipeline without the decomposition; their wall-time ratio is the scaling of 2 workers
   (ARCHITECTURE.md, Performance bars: at least 1.8x). ``--rounds R`` (default 2) repeats this pair R times,
   interleaved, and keeps each one's best (the machine is shared; the minimum is the least disturbed);
4. ``dask`` (unless ``--no-dask``): like ``jobs2`` on a dask.distributed LocalCluster of 2 worker processes.

Reported: per-stage seconds (each stage's wall time in the run, publish included for ``dataset``), grasps labelled
per core-hour (rows of the published grasps.parquet / (wall seconds x workers / 3600); every row has an outcome
and, for successes, robustness from its perturbed copies) and simulated rollouts per core-hour (grasp-and-lift
rollouts of the rollouts stage plus the robustness stage's perturbed copies), the scaling ratio, and the peak
resident memory of the run's processes: the parent (scheduling, publish) and the largest worker. Memory is the
kernel's high-water mark ``VmHWM`` of each process (``/proc/<pid>/status``), sampled every 0.1 s over the run's
process tree (the mark only grows, so sampling misses at most a process's last 0.1 s). Also checked: the
published grasps.parquet has the same sha256 in every run (workers and backend do not change bytes).

Also measured: how many cores each run got (CPU seconds of its process tree / its lifetime) and, before and
after, how much work two spinning processes do compared with one on this machine: on a shared machine other
jobs take cores, and the pipeline cannot scale better than the machine does. And the scaling the task sizes allow:
the 1-worker run's task times dealt in task order to 2 workers, wave by wave (stages that do not read each other
run as one wave and are one row of the table), plus each wave's remaining time (planning, publish), against the
1-worker wall time: a long task dispatched last caps the speedup whatever the machine (also given: the same with
each wave's tasks dealt longest first, which the scheduler approximates with its tasks' cost estimates).

Run: ``python -m bench.bench_e2e [--config configs/default.yaml] [--rounds 2] [--no-dask]``; prints a table and
writes ``bench/results.json``. Linux only (``/proc``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = Path(__file__).resolve().parent / "results.json"
WORK = ROOT / "build" / "bench_e2e"


# --------------------------------------------------------------------------------------------------------------
# The child: one pipeline run


def child(args: argparse.Namespace) -> None:
    from graspgen.sim.gl import select_backend

    select_backend()
    import pyarrow.parquet as pq

    from pipeline.config import load_config
    from pipeline.keys import sha256_file
    from pipeline.scheduler import run_pipeline
    from stages.project import PROJECT

    sets = [f"run.out={args.out}", f"run.cache_dir={args.cache}", f"run.jobs={args.jobs}",
            f"run.backend={args.backend}"]
    from pipeline.stage import stage_waves, topological_order
    from pipeline.store import stage_dir

    cfg = load_config(PROJECT.schema, args.config, sets)
    start, start_time = time.perf_counter(), time.time()
    reports = run_pipeline(PROJECT, cfg)
    wall = time.perf_counter() - start
    published = Path(args.out) / "dataset" / "grasps.parquet"
    t = pq.read_table(published, columns=["outcome", "simulated", "robustness_n"])
    result = {
        "wall_s": wall,
        "waves": [[st.name for st in wave] for wave in stage_waves(topological_order(PROJECT.stages))],
        "stages": [
            {"stage": r.stage, "tasks": r.total, "ran": r.ran, "skipped": r.skipped, "failed": r.failed,
             "seconds": r.seconds, "task_seconds": _task_seconds(stage_dir(args.out, r.stage), start_time)}
            for r in reports
        ],
        "grasps": len(t),
        "successes": int((t.column("outcome").to_numpy() == 5).sum()),
        "rollouts": int(sum(t.column("simulated").to_pylist())) + int(sum(t.column("robustness_n").to_pylist())),
        "grasps_sha256": sha256_file(published),
    }
    Path(args.result).write_text(json.dumps(result))


def _task_seconds(folder: Path, since: float) -> list[float]:
    """Seconds of each task this run committed in the stage folder ``folder`` (manifest order = dispatch order,
    roughly: tasks are dispatched in the stage's task order); none when it ran nothing."""
    from pipeline.store import Manifest

    manifest = Manifest(folder)
    if not manifest.path.exists() or manifest.path.stat().st_mtime < since:
        return []
    # The stage's tasks in their declared order (sorted ids here: objects by name, scenes by id).
    entries = sorted((e for e in manifest.entries().values() if e.status == "ok"), key=lambda e: e.task)
    return [e.seconds for e in entries]


def makespan(seconds: list[float], workers: int) -> float:
    """Finish time of ``seconds`` run in order, each on the first free of ``workers`` (how joblib hands them out)."""
    free = [0.0] * workers
    for s in seconds:
        i = free.index(min(free))
        free[i] += s
    return max(free, default=0.0)


# --------------------------------------------------------------------------------------------------------------
# The parent: run children, watch their memory


def _hwm_kb(pid: int) -> int | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def _descendants(pid: int) -> list[int]:
    import psutil

    try:
        return [p.pid for p in psutil.Process(pid).children(recursive=True)]
    except psutil.Error:
        return []


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def run_child(name: str, config: str, out: Path, cache: Path, jobs: int, backend: str = "loky") -> dict:
    """One pipeline run in a fresh process; returns its result plus peak memory of parent and workers (MB)."""
    result_path = WORK / f"{name}.json"
    cmd = [sys.executable, "-m", "bench.bench_e2e", "--child", "--config", config, "--out", str(out),
           "--cache", str(cache), "--jobs", str(jobs), "--backend", backend, "--result", str(result_path)]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    peaks: dict[int, int] = {}
    kinds: dict[int, str] = {}
    done = threading.Event()

    def watch() -> None:
        while not done.is_set():
            for pid in [proc.pid, *_descendants(proc.pid)]:
                hwm = _hwm_kb(pid)
                if hwm is not None:
                    peaks[pid] = max(peaks.get(pid, 0), hwm)
                    if pid not in kinds:
                        kinds[pid] = "parent" if pid == proc.pid else _cmdline(pid)
            time.sleep(0.1)

    thread = threading.Thread(target=watch, daemon=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    thread.start()
    output, _ = proc.communicate()
    lifetime = time.perf_counter() - t0
    done.set()
    thread.join()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        sys.stdout.write(output)
        raise SystemExit(f"bench_e2e: run {name} failed with exit code {proc.returncode}")
    result = json.loads(result_path.read_text())
    # Helper processes (loky's resource tracker, multiprocessing's) hold no task data: not workers.
    workers = [kb for pid, kb in peaks.items() if kinds[pid] != "parent" and "resource_tracker" not in kinds[pid]]
    result["peak_rss_parent_mb"] = round(peaks.get(proc.pid, 0) / 1024, 1)
    result["peak_rss_worker_mb"] = round(max(workers, default=0) / 1024, 1)
    result["workers_seen"] = len(workers)
    # CPU seconds of the whole process tree (workers are reaped by the run, so they count): cpu / wall is how many
    # cores the run actually got.
    result["cpu_s"] = round(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, 2)
    result["process_s"] = round(lifetime, 2)
    result["cores_used"] = round(result["cpu_s"] / lifetime, 2)
    result["jobs"], result["backend"], result["name"] = jobs, backend, name
    return result


def _spin(seconds: float) -> int:
    n, end = 0, time.perf_counter() + seconds
    while time.perf_counter() < end:
        n += 1
    return n


def machine_speedup(seconds: float = 3.0) -> float:
    """Throughput of 2 busy processes over 1 (a pure-Python spin loop): 2.0 on two idle cores, less when other
    work shares the machine. The pipeline's own 2-worker speedup cannot exceed it."""
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(2) as pool:
        list(pool.map(_spin, [0.2, 0.2]))  # start both workers first
        one = pool.submit(_spin, seconds).result()
        two = sum(pool.map(_spin, [seconds, seconds]))
    return round(two / one, 2)


def _per_core_hour(count: int, wall: float, jobs: int) -> float:
    return count / (wall * jobs / 3600.0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="configs/default.yaml")
    parser.add_argument("--rounds", type=int, default=2, help="jobs1/jobs2 pairs (best of each is kept)")
    parser.add_argument("--no-dask", action="store_true", help="skip the dask.distributed run")
    parser.add_argument("--results", type=Path, default=RESULTS)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    parser.add_argument("--cache", help=argparse.SUPPRESS)
    parser.add_argument("--jobs", type=int, default=2, help=argparse.SUPPRESS)
    parser.add_argument("--backend", default="loky", help=argparse.SUPPRESS)
    parser.add_argument("--result", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        child(args)
        return 0

    if WORK.exists():
        shutil.rmtree(WORK)
    WORK.mkdir(parents=True)
    cache = WORK / "cache"
    runs = {}
    print(f"bench_e2e: {args.config} on {os.cpu_count()} cores ({platform.processor() or platform.machine()})",
          flush=True)
    calibration = [machine_speedup()]
    print(f"  machine: 2 spinning processes do {calibration[0]}x the work of one", flush=True)
    runs["cold"] = run_child("cold", args.config, WORK / "out_cold", cache, 2)
    print(f"  cold   {runs['cold']['wall_s']:6.1f} s", flush=True)
    runs["warm"] = run_child("warm", args.config, WORK / "out_cold", cache, 2)
    print(f"  warm   {runs['warm']['wall_s']:6.1f} s", flush=True)
    for r in range(args.rounds):
        for jobs in (1, 2):
            name = f"jobs{jobs}"
            out = WORK / f"out_{name}_{r}"
            res = run_child(f"{name}_{r}", args.config, out, cache, jobs)
            shutil.rmtree(out)
            print(f"  {name} round {r}: {res['wall_s']:6.1f} s", flush=True)
            if name not in runs or res["wall_s"] < runs[name]["wall_s"]:
                runs[name] = res
    if not args.no_dask:
        runs["dask"] = run_child("dask", args.config, WORK / "out_dask", cache, 2, backend="dask")
        print(f"  dask   {runs['dask']['wall_s']:6.1f} s", flush=True)

    calibration.append(machine_speedup())
    print(f"  machine: 2 spinning processes do {calibration[1]}x the work of one", flush=True)
    one, two = runs["jobs1"], runs["jobs2"]
    # Stages of one wave share the workers and each reports seconds from the wave's start: a wave is one row.
    waves = one["waves"]
    rows = {"+".join(w): w for w in waves}

    def wave_seconds(run: str, wave: list[str]) -> float:
        return max(s["seconds"] for s in runs[run]["stages"] if s["stage"] in wave)

    def wave_tasks(run: str, wave: list[str]) -> list[float]:
        return [t for s in runs[run]["stages"] if s["stage"] in wave for t in s["task_seconds"]]

    per_stage = {name: {run: wave_seconds(run, wave) for run in runs} for name, wave in rows.items()}
    stage_names = list(rows)
    parallel = [n for n, w in rows.items() if sum(s["tasks"] for s in one["stages"] if s["stage"] in w) > 1]
    par1 = sum(per_stage[n]["jobs1"] for n in parallel)
    par2 = sum(per_stage[n]["jobs2"] for n in parallel)
    # What the task sizes allow: each wave's 1-worker task times dealt in order to 2 workers, plus the rest of the
    # wave's time (planning, publish) as it was; 2 idle cores and free worker start-up assumed.
    bound_wall = bound_lpt = 0.0
    for name, wave in rows.items():
        tasks = wave_tasks("jobs1", wave)
        rest = max(per_stage[name]["jobs1"] - sum(tasks), 0.0)
        bound_wall += makespan(tasks, 2) + rest
        bound_lpt += makespan(sorted(tasks, reverse=True), 2) + rest
    summary = {
        "scaling_2_vs_1": round(one["wall_s"] / two["wall_s"], 3),
        "scaling_bound_from_task_order": round(one["wall_s"] / bound_wall, 3),
        "scaling_bound_longest_first": round(one["wall_s"] / bound_lpt, 3),
        "scaling_2_vs_1_multi_task_stages": round(par1 / par2, 3),
        "grasps": two["grasps"],
        "successes": two["successes"],
        "simulated_rollouts": two["rollouts"],
        "grasps_per_core_hour_jobs1": round(_per_core_hour(one["grasps"], one["wall_s"], 1)),
        "grasps_per_core_hour_jobs2": round(_per_core_hour(two["grasps"], two["wall_s"], 2)),
        "grasps_per_core_hour_cold": round(_per_core_hour(runs["cold"]["grasps"], runs["cold"]["wall_s"], 2)),
        "rollouts_per_core_hour_jobs2": round(_per_core_hour(two["rollouts"], two["wall_s"], 2)),
        "peak_rss_worker_mb": max(r["peak_rss_worker_mb"] for r in runs.values()),
        "peak_rss_parent_mb": max(r["peak_rss_parent_mb"] for r in runs.values()),
        "same_grasps_parquet": len({r["grasps_sha256"] for r in runs.values()}) == 1,
        "machine_speedup_2_vs_1": calibration,
        "cores_used_jobs1": one["cores_used"],
        "cores_used_jobs2": two["cores_used"],
    }

    cols = list(runs)
    width = max(11, *(len(n) + 1 for n in stage_names))
    header = f"{'stage':<{width}}" + "".join(f"{c:>9}" for c in cols) + f"{'1/2 ratio':>11}"
    print()
    print(header)
    print("-" * len(header))
    for name in stage_names:
        cells = "".join(f"{per_stage[name][c]:9.1f}" for c in cols)
        ratio = per_stage[name]["jobs1"] / per_stage[name]["jobs2"] if per_stage[name]["jobs2"] > 0 else float("nan")
        print(f"{name:<{width}}{cells}{ratio:11.2f}")
    print("-" * len(header))
    walls = "".join(f"{runs[c]['wall_s']:9.1f}" for c in cols)
    print(f"{'wall':<{width}}" + walls + f"{summary['scaling_2_vs_1']:11.2f}")
    print(f"{'peak worker':<{width}}" + "".join(f"{runs[c]['peak_rss_worker_mb']:8.0f}M" for c in cols))
    print(f"{'peak parent':<{width}}" + "".join(f"{runs[c]['peak_rss_parent_mb']:8.0f}M" for c in cols))
    print(f"{'cores used':<{width}}" + "".join(f"{runs[c]['cores_used']:9.2f}" for c in cols))
    print()
    print(f"grasps: {summary['grasps']} ({summary['successes']} successes), simulated rollouts (incl. perturbed "
          f"copies): {summary['simulated_rollouts']}")
    print(f"grasps labelled per core-hour: {summary['grasps_per_core_hour_jobs1']} (1 worker), "
          f"{summary['grasps_per_core_hour_jobs2']} (2 workers), {summary['grasps_per_core_hour_cold']} (cold, 2 "
          f"workers, CoACD included); rollouts per core-hour (2 workers): {summary['rollouts_per_core_hour_jobs2']}")
    print(f"scaling 2 vs 1 worker: {summary['scaling_2_vs_1']}x whole run, "
          f"{summary['scaling_2_vs_1_multi_task_stages']}x in the waves with more than one task "
          f"({', '.join(parallel)})")
    print(f"what the task sizes and their order allow on 2 idle cores: {summary['scaling_bound_from_task_order']}x "
          f"(longest task first: {summary['scaling_bound_longest_first']}x)")
    print(f"the machine itself: 2 processes did {calibration[0]}x / {calibration[1]}x the work of one (before / after; "
          "2.0 = two idle cores)")
    print(f"peak RSS per worker: {summary['peak_rss_worker_mb']} MB (parent {summary['peak_rss_parent_mb']} MB)")
    print(f"grasps.parquet identical in every run: {summary['same_grasps_parquet']}")
    payload = {
        "config": args.config,
        "machine": {"cores": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()},
        "summary": summary,
        "per_stage_seconds": per_stage,
        "runs": runs,
    }
    args.results.write_text(json.dumps(payload, indent=2) + "\n")
    print(f"wrote {args.results}")
    return 0 if summary["same_grasps_parquet"] else 1


if __name__ == "__main__":
    sys.exit(main())
