"""Scale: the same config at 12, 100 and 1,000 procedural objects, on loky and on a Dask cluster, and what it says
about ACRONYM's size.

For each object count N the config is ``configs/procedural.yaml`` with ``objects.procedural.count = N``,
``scenes.num_scenes = ceil(N / 2)`` and the smaller per-object targets of :data:`SMALL`, run with
``gen`` in a fresh output folder and a fresh cache, in three phases, each a separate ``gen`` process:

1. ``gen run STAGE`` for each stage but ``dataset`` that no other reads (so every input of ``dataset`` is made);
2. ``gen run dataset`` (the streaming publish: its peak memory is the figure that must not grow with N);
3. ``gen status`` and a no-op ``gen run`` (everything skipped after its shard's sha256 is checked).

Measured per phase: wall time; CPU seconds of the ``gen`` process and every process below it (``RUSAGE_CHILDREN``
of this script, which reaps them); peak resident memory (``VmHWM``) of each process, sampled from ``/proc`` every
0.2 s and grouped as the scheduler (``gen``), its loky workers, or the Dask workers. From the manifests: each
stage's task CPU seconds (``Entry.cpu_seconds``) per object. Scheduler overhead: the CPU of the run's processes not
spent inside a task (start-up, planning, keys, sha256 checks, dispatch, manifests, publish), as a share of task
CPU: the CPU of phases 1 and 2 (every process, exact) minus the task CPU the manifests record; phase 3 is timed
apart. The same samples of ``/proc`` give each process's CPU, so the overhead is also split by process
(:func:`outside_by_role`). Published size: bytes under ``OUT/dataset``.

With ``--backend dask`` (or ``both``) the same runs go to a cluster started here as separate processes:
``dask scheduler`` on 127.0.0.1 and ``dask worker`` processes (``--jobs`` of them, one thread each), named in the
config by ``run.backend: dask`` and ``run.dask_address``, with dask's monitoring turned down for a batch run
(:data:`BATCH_DASK_CONFIG`, as docs/cluster.md advises; ``--dask-defaults`` keeps dask's own). Their CPU is counted
when they are stopped.

The cost model printed at the end extrapolates the largest run to ACRONYM's 8,872 objects x 2,000 grasps: per-object
CPU of the object stages as measured (preparation does not depend on the grasp count), the grasp stages' CPU scaled
by 2,000 / the run's grasps per object, peak memory as the largest measured (flat in N when the streaming holds).

Run: ``python -m bench.bench_scale [--sizes 12 100 1000] [--jobs 2] [--backend loky|dask|both] [--dask-defaults]
[--work DIR]``;
writes ``bench/results_scale.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import resource
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import yaml

from pipeline.store import MANIFEST, Manifest

ROOT = Path(__file__).resolve().parent.parent
GEN = [sys.executable, "-m", "graspgen_cli.app"]
ACRONYM_OBJECTS = 8872
ACRONYM_GRASPS = 2000
OBJECT_STAGES = ("objects",)
"""Stages whose cost per object does not grow with the grasps per object."""
OBJECT_SET_STAGES = ("object_grasps", "probe")
"""Stages whose cost grows with the object-centric grasps per object (ACRONYM's 2,000)."""


def _descendants(root: int) -> list[int]:
    children: dict[int, list[int]] = {}
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            with open(f"/proc/{entry.name}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        children.setdefault(ppid, []).append(int(entry.name))
    found, todo = [], [root]
    while todo:
        pid = todo.pop()
        found.append(pid)
        todo.extend(children.get(pid, []))
    return found


_TICK = os.sysconf("SC_CLK_TCK")


def _peak_kb(pid: int) -> tuple[int, str, float] | None:
    """(peak resident kB, command line, CPU seconds so far) of a live process, from ``/proc``; None once gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            hwm = next(int(line.split()[1]) for line in f if line.startswith("VmHWM:"))
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            cmd = f.read().replace(b"\0", b" ").decode(errors="replace")
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        cpu = (int(fields[11]) + int(fields[12])) / _TICK  # utime + stime
    except (OSError, StopIteration, ValueError, IndexError):
        return None
    return hwm, cmd, cpu


def _role(cmd: str, root_pid: int, pid: int, cluster: bool) -> str:
    if pid == root_pid:
        return "scheduler"
    if "loky" in cmd:
        return "loky_worker"
    if cluster:  # the cluster's processes: dask's scheduler, the nanny, and the worker processes it spawns
        if "dask scheduler" in cmd:
            return "dask_scheduler"
        return "dask_nanny" if "dask worker" in cmd else "dask_worker"
    return "other"


class PeakMemory:
    """Samples the peak resident memory and the CPU seconds of a process tree (and of extra pids) until stopped,
    by role. A process's CPU is its last sample: the last 0.2 s of each process can be missed, so the roles' CPU
    sums to a little less than the tree's (``RUSAGE_CHILDREN``, which :func:`run_gen` reports as the total). The
    ``extra`` processes (a cluster's, which outlive one ``gen`` process) count from their CPU when sampling starts."""

    def __init__(self, root_pid: int, extra: tuple[int, ...] = ()):
        self.root_pid, self.extra = root_pid, extra
        self.peaks: dict[int, tuple[int, str]] = {}
        self.cpu: dict[int, float] = {}
        self.cpu_before: dict[int, float] = {}
        for pid in extra:
            for child in _descendants(pid):
                got = _peak_kb(child)
                if got is not None:
                    self.cpu_before[child] = got[2]
        self.in_cluster: set[int] = set()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while not self._stop.is_set():
            for pid in {*_descendants(self.root_pid), *self.extra}:
                for child in _descendants(pid) if pid in self.extra else [pid]:
                    got = _peak_kb(child)
                    if got is not None:
                        self.cpu[child] = max(self.cpu.get(child, 0.0), got[2])
                    if got is not None and got[0] >= self.peaks.get(child, (0, ""))[0]:
                        self.peaks[child] = got[:2]
                    if pid in self.extra:
                        self.in_cluster.add(child)
            self._stop.wait(0.2)

    def stop(self) -> tuple[dict[str, float], dict[str, float]]:
        """(peak MB of the largest process, CPU seconds of all processes), each by role."""
        self._stop.set()
        self._thread.join()
        by_role: dict[str, float] = {}
        cpu: dict[str, float] = {}
        for pid, (kb, cmd) in self.peaks.items():
            role = _role(cmd, self.root_pid, pid, pid in self.in_cluster)
            by_role[role] = max(by_role.get(role, 0.0), round(kb / 1024, 1))
            spent = self.cpu.get(pid, 0.0) - self.cpu_before.get(pid, 0.0)
            cpu[role] = round(cpu.get(role, 0.0) + spent, 2)
        return by_role, cpu


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_gen(args: list[str], extra_pids: tuple[int, ...] = ()) -> dict:
    """One ``gen`` process: wall, CPU of it and its descendants, peak memory by role."""
    cpu0, wall0 = _children_cpu(), time.perf_counter()
    proc = subprocess.Popen([*GEN, *args], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    peaks = PeakMemory(proc.pid, extra_pids)
    stdout, stderr = proc.communicate()
    memory, cpu_by_role = peaks.stop()
    if proc.returncode != 0:
        raise SystemExit(f"gen {' '.join(args)} failed ({proc.returncode}):\n{stderr[-3000:]}")
    return {"wall_s": round(time.perf_counter() - wall0, 2), "cpu_s": round(_children_cpu() - cpu0, 2),
            "cpu_s_by_role": cpu_by_role, "peak_mb": memory, "stdout": (stdout + stderr)[-4000:]}


SMALL = {
    "object_grasps": {"target_grasps": 16, "max_candidates": 160},
    "grasps": {"max_per_object": 8},
    "robustness": {"num_perturbations": 2},
}
"""Per-object targets of the benchmark, over configs/procedural.yaml's, so 1,000 objects fit a couple of hours on
two cores."""


def bench_config() -> dict:
    """configs/procedural.yaml with :data:`SMALL` over it."""
    config = yaml.safe_load((ROOT / "configs" / "procedural.yaml").read_text())
    for section, values in SMALL.items():
        config.setdefault(section, {}).update(values)
    return config


def write_config(n: int, out: Path, cache: Path, jobs: int, dask_address: str | None) -> Path:
    config = bench_config()
    config["objects"]["procedural"]["count"] = n
    config.setdefault("scenes", {})["num_scenes"] = max(1, math.ceil(n / 2))
    config["run"] = {"out": str(out), "jobs": jobs, "cache_dir": str(cache)}
    if dask_address:
        config["run"].update(backend="dask", dask_address=dask_address)
    path = out.parent / f"{out.name}.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def stage_task_cpu(out: Path) -> dict[str, dict[str, float]]:
    """Per stage: tasks, their CPU seconds (from the manifests, latest entry per key), wall seconds."""
    result = {}
    for manifest in sorted((out / "shards").glob(f"*/{MANIFEST}")):
        ok = [e for e in Manifest(manifest.parent).entries().values() if e.status == "ok"]
        result[manifest.parent.name] = {"tasks": len(ok), "cpu_s": round(sum(e.cpu_seconds for e in ok), 2),
                                        "wall_s": round(sum(e.seconds for e in ok), 2)}
    return result


def _du(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


BATCH_DASK_CONFIG = {
    "DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED": "False",
    "DASK_DISTRIBUTED__ADMIN__TICK__INTERVAL": "1s",
    "DASK_DISTRIBUTED__ADMIN__SYSTEM_MONITOR__INTERVAL": "5s",
    "DASK_DISTRIBUTED__ADMIN__SYSTEM_MONITOR__GIL__ENABLED": "False",
    "DASK_DISTRIBUTED__WORKER__MEMORY__MONITOR_INTERVAL": "1s",
}
"""dask.distributed settings of the cluster's processes for a batch run (docs/cluster.md): its defaults sample every
worker's stack every 10 ms (the profiler behind the dashboard), check the event loop every 20 ms, poll the system
every 500 ms and the nanny's child every 100 ms, which the processes pay all the time they are up. ``--dask-defaults``
keeps dask's own."""


class DaskCluster:
    """``dask scheduler`` and ``dask worker`` processes on 127.0.0.1, started and stopped here (with
    :data:`BATCH_DASK_CONFIG` unless ``defaults``)."""

    def __init__(self, workers: int, work: Path, defaults: bool = False):
        port = _free_port()
        self.address = f"tcp://127.0.0.1:{port}"
        dask = str(Path(sys.executable).parent / "dask")
        log = open(work / "dask.log", "a")  # noqa: SIM115 - closed in stop()
        self._log = log
        env = {**os.environ, **({} if defaults else BATCH_DASK_CONFIG)}
        self.procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port),
                                        "--no-dashboard"], stdout=log, stderr=log, cwd=ROOT, env=env)]
        time.sleep(3)
        self.procs.append(subprocess.Popen(
            [dask, "worker", self.address, "--nworkers", str(workers), "--nthreads", "1", "--no-dashboard",
             "--memory-limit", "0", "--local-directory", str(work / "dask-worker")],
            stdout=log, stderr=log, cwd=ROOT, env={**env, "PYTHONPATH": str(ROOT)}))
        time.sleep(5)

    @property
    def pids(self) -> tuple[int, ...]:
        return tuple(p.pid for p in self.procs)

    def stop(self) -> None:
        for p in reversed(self.procs):
            p.terminate()
        for p in self.procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        self._log.close()


def measure(n: int, jobs: int, backend: str, work: Path, dask_defaults: bool = False) -> dict:
    out = work / f"{backend}_n{n}"
    cache = work / f"cache_{backend}_n{n}"
    shutil.rmtree(out, ignore_errors=True)
    shutil.rmtree(cache, ignore_errors=True)
    cluster = DaskCluster(jobs, work, dask_defaults) if backend == "dask" else None
    cpu_cluster0 = _children_cpu()
    try:
        config = write_config(n, out, cache, jobs, cluster.address if cluster else None)
        extra = cluster.pids if cluster else ()
        phases = {
            "stages": _sum_phases([run_gen(["run", leaf, "--config", str(config)], extra) for leaf in _leaves()]),
            "dataset": run_gen(["run", "dataset", "--config", str(config)], extra),
            "status": run_gen(["status", "--config", str(config)]),
            "noop_rerun": run_gen(["run", "--config", str(config)], extra),
        }
    finally:
        if cluster:
            cluster.stop()
    cluster_cpu = _children_cpu() - cpu_cluster0 - sum(p["cpu_s"] for p in phases.values()) if cluster else 0.0
    tasks = stage_task_cpu(out)
    task_cpu = sum(t["cpu_s"] for t in tasks.values())
    run_cpu = phases["stages"]["cpu_s"] + phases["dataset"]["cpu_s"] + cluster_cpu
    # A no-op rerun that ran something means the keys moved between phases (the code was edited meanwhile).
    noop_clean = "Nothing to do" in phases["noop_rerun"]["stdout"]
    for p in phases.values():
        p.pop("stdout")
    return {
        "objects": n,
        "backend": backend,
        "jobs": jobs,
        "phases": phases,
        "stages": tasks,
        "task_cpu_s": round(task_cpu, 1),
        "task_cpu_s_per_object": round(task_cpu / n, 2),
        "stage_cpu_s_per_object": {s: round(t["cpu_s"] / n, 3) for s, t in tasks.items()},
        "outside_tasks_cpu_s": round(run_cpu - task_cpu, 1),
        "outside_tasks_by_role": outside_by_role(phases, task_cpu, run_cpu),
        "overhead_share": round((run_cpu - task_cpu) / task_cpu, 4) if task_cpu else None,
        "wall_s": round(phases["stages"]["wall_s"] + phases["dataset"]["wall_s"], 1),
        "status_s": phases["status"]["wall_s"],
        "noop_rerun_s": phases["noop_rerun"]["wall_s"],
        "noop_ran_nothing": noop_clean,
        "published_mb": round(_du(out / "dataset") / 2**20, 1),
    }


def outside_by_role(phases: dict, task_cpu: float, run_cpu: float) -> dict[str, float]:
    """The CPU of the run's two phases by process, around the task CPU: ``scheduler``, the ``gen`` processes'
    CPU (start-up, planning, keys, shard checks, dispatch, manifests, publish, and the tasks of a wave that has
    one task to run, e.g. the probe's: joblib runs a single call in the calling process); ``workers_outside_tasks``,
    the workers' CPU minus all task CPU (start-up and imports, unpickling, per-task upkeep; smaller by the tasks
    that ran in the scheduler); ``unsampled``, what the 0.2 s samples of ``/proc`` missed (the last moments of
    each process). They add up to ``outside_tasks_cpu_s``, whose total is exact (``RUSAGE_CHILDREN``)."""
    sampled: dict[str, float] = {}
    for phase in ("stages", "dataset"):
        for role, seconds in phases[phase]["cpu_s_by_role"].items():
            sampled[role] = sampled.get(role, 0.0) + seconds
    workers = sum(v for r, v in sampled.items() if r in ("loky_worker", "dask_worker"))
    split = {"scheduler": sampled.get("scheduler", 0.0), "workers_outside_tasks": workers - task_cpu}
    split["other_processes"] = sum(v for r, v in sampled.items() if r not in ("scheduler", "loky_worker",
                                                                               "dask_worker"))
    split["unsampled"] = run_cpu - sum(sampled.values())
    return {k: round(v, 1) for k, v in split.items()}


def _leaves() -> list[str]:
    """The stages but ``dataset`` that no other of them reads: running them runs everything ``dataset`` needs."""
    from stages.project import PROJECT

    stages = [s for s in PROJECT.stages if s.name != "dataset"]
    read = {d for s in stages for d in s.inputs}
    return [s.name for s in stages if s.name not in read]


def _sum_phases(parts: list[dict]) -> dict:
    peaks: dict[str, float] = {}
    cpu: dict[str, float] = {}
    for p in parts:
        for role, mb in p["peak_mb"].items():
            peaks[role] = max(peaks.get(role, 0.0), mb)
        for role, seconds in p["cpu_s_by_role"].items():
            cpu[role] = round(cpu.get(role, 0.0) + seconds, 2)
    return {"wall_s": round(sum(p["wall_s"] for p in parts), 2), "cpu_s": round(sum(p["cpu_s"] for p in parts), 2),
            "cpu_s_by_role": cpu, "peak_mb": peaks, "stdout": parts[-1]["stdout"]}


def cost_model(row: dict) -> dict:
    """ACRONYM's size from one run (see the module docstring for the assumptions)."""
    og = bench_config().get("object_grasps", {})
    grasps = og.get("target_grasps", 0)
    scale = ACRONYM_GRASPS / grasps
    per_stage = row["stage_cpu_s_per_object"]
    overhead = 1 + (row["overhead_share"] or 0.0)
    object_sets = sum(cpu if s in OBJECT_STAGES else cpu * scale for s, cpu in per_stage.items()
                      if s in (*OBJECT_STAGES, *OBJECT_SET_STAGES)) * overhead
    scenes = sum(cpu for s, cpu in per_stage.items() if s not in (*OBJECT_STAGES, *OBJECT_SET_STAGES)) * overhead
    peak = max(v for p in row["phases"].values() for v in p["peak_mb"].values())
    return {
        "objects": ACRONYM_OBJECTS,
        "grasps_per_object": ACRONYM_GRASPS,
        "measured_grasps_per_object": grasps,
        "object_sets_cpu_s_per_object": round(object_sets, 1),
        "object_sets_core_hours": round(object_sets * ACRONYM_OBJECTS / 3600, 1),
        "scene_path_cpu_s_per_object": round(scenes, 1),
        "scene_path_core_hours": round(scenes * ACRONYM_OBJECTS / 3600, 1),
        "peak_process_mb": peak,
        "assumptions": (
            "ACRONYM's product is the object-centric sets: the objects stage at its measured CPU per object "
            f"(preparation does not depend on the grasp count), object_grasps and probe scaled by {ACRONYM_GRASPS}/"
            f"{grasps} grasps per object (their work is per grasp); the scene path (scenes, grasps, placed grasps, "
            "rollouts, robustness, metrics, dataset) at the measured scene density, per object, unscaled; the "
            "measured share of CPU outside tasks added; peak memory of any one process as the largest measured (flat "
            "in N when streaming holds); procedural objects prepare faster than ShapeNet meshes (bench/bench_prep.py "
            "measures those)"
        ),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[12, 100, 1000], help="object counts")
    parser.add_argument("--jobs", type=int, default=2, help="workers (loky processes or dask workers)")
    parser.add_argument("--backend", choices=("loky", "dask", "both"), default="loky")
    parser.add_argument("--work", type=Path, default=None, help="work folder (default: a temp folder, removed)")
    parser.add_argument("--json", type=Path, default=ROOT / "bench" / "results_scale.json")
    parser.add_argument("--dask-defaults", action="store_true",
                        help="start the dask cluster with dask's own settings, not BATCH_DASK_CONFIG")
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="bench_scale_"))
    work.mkdir(parents=True, exist_ok=True)
    backends = ("loky", "dask") if args.backend == "both" else (args.backend,)
    rows = []
    for backend in backends:
        for n in args.sizes:
            rows.append(measure(n, args.jobs, backend, work, args.dask_defaults))
            print(json.dumps({k: v for k, v in rows[-1].items() if k != "stages"}), flush=True)
            args.json.write_text(json.dumps({"machine": platform.platform(), "rows": rows}, indent=2) + "\n")
    cols = ("backend", "objects", "task_cpu_s_per_object", "overhead_share", "wall_s", "status_s", "noop_rerun_s",
            "published_mb")
    print("\n" + " | ".join(cols) + " | peak MB (dataset phase) | peak MB (status)")
    for r in rows:
        print(" | ".join(str(r[c]) for c in cols), "|", r["phases"]["dataset"]["peak_mb"], "|",
              r["phases"]["status"]["peak_mb"])
    model = cost_model(rows[-1])
    print("\nACRONYM-size cost model:", json.dumps(model, indent=2))
    args.json.write_text(json.dumps({"machine": platform.platform(), "rows": rows, "cost_model": model},
                                    indent=2) + "\n")
    if args.work is None:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
