"""A real dask cluster and real faults: a scheduler and two worker processes on the loopback interface.

1. The smoke config run against them with ``--backend dask``, one worker killed with SIGKILL (its whole process
   group: nanny and worker) while it holds a task: the run finishes on the survivor and gives the same shards and
   the same ``grasps.parquet`` as a local ``--jobs 2`` run.
2. A task that kills every worker that runs it (as a segfault or the OOM killer would): dask gives up on it after
   ``distributed.scheduler.allowed-failures`` + 1 deaths, and the run stops with one line naming the task instead
   of waiting forever.
3. The scheduler killed mid-run: the run stops with one line, finished tasks kept.

Every process is started in its own session and its process group is killed at the end, pass or fail; every wait
is bounded.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipeline.keys import sha256_file
from pipeline.plan import committed
from pipeline.repro import shard_hashes
from pipeline.store import MANIFEST, SHARDS
from tests.paths import REPO

distributed = pytest.importorskip("distributed")

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="process groups and SIGKILL are POSIX")

DASK = Path(sys.executable).parent / "dask"
START_TIMEOUT = 30.0
"""Seconds for the scheduler and both workers to register."""
RUN_TIMEOUT = 120.0
"""Seconds for one `gen run` of the smoke config (5-10 s on 2 idle cores)."""


# --------------------------------------------------------------------------------------------------------------
# Helpers


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def tail(path: Path, n: int = 3000) -> str:
    return path.read_text(errors="replace")[-n:] if path.exists() else ""


def env() -> dict[str, str]:
    return {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "PYTHONUNBUFFERED": "1"}


def kill_group(proc: subprocess.Popen) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=10)


def manifest_lines(out: Path) -> dict[str, int]:
    """Committed manifest lines per stage."""
    return {m.parent.name: len(m.read_text().splitlines()) for m in out.glob(f"{SHARDS}/*/{MANIFEST}")}


def task_keys(out: Path) -> dict[str, str]:
    """``{"stage/task": key}`` of the committed entries of every stage."""
    keys = {}
    for m in out.glob(f"{SHARDS}/*/{MANIFEST}"):
        keys.update({f"{m.parent.name}/{e.task}": k for k, e in committed(out, m.parent.name).items()})
    return keys


def gen_run(out: Path, cache: Path, *args: str) -> list[str]:
    return [sys.executable, "-m", "graspgen_cli.app", "run", "--config", str(REPO / "configs" / "smoke.yaml"),
            "--out", str(out), "--set", f"run.cache_dir={cache}", *args]


def wait_run(proc: subprocess.Popen, deadline: float, log: Path) -> int:
    try:
        return proc.wait(timeout=max(1.0, deadline - time.monotonic()))
    except subprocess.TimeoutExpired:
        raise AssertionError(f"the run did not end within {RUN_TIMEOUT} s:\n{tail(log)}") from None


@pytest.fixture
def cluster(tmp_path):
    """``(address, {name: process}, logs folder)``: a dask ``scheduler`` and two one-thread workers ``w0``, ``w1``
    (each with its nanny), loopback only (their HTTP servers too), started but not waited for (:func:`connect`
    waits)."""
    if not DASK.exists():
        pytest.skip(f"no dask command next to {sys.executable}")
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    local = ["--no-dashboard", "--dashboard-address", "127.0.0.1:0"]
    procs: dict[str, subprocess.Popen] = {}

    def start(name: str, args: list[str]) -> None:
        with open(tmp_path / f"{name}.log", "w") as log:
            procs[name] = subprocess.Popen([str(DASK), *args], stdout=log, stderr=subprocess.STDOUT, cwd=REPO,
                                           env=env(), start_new_session=True)

    try:
        start("scheduler", ["scheduler", "--host", "127.0.0.1", "--port", str(port), *local])
        for name in ("w0", "w1"):
            start(name, ["worker", address, "--nworkers", "1", "--nthreads", "1", "--host", "127.0.0.1", "--name",
                         name, "--local-directory", str(tmp_path / name), *local])
        yield address, procs, tmp_path
    finally:
        for proc in reversed(procs.values()):
            kill_group(proc)


@contextlib.contextmanager
def connect(address: str, logs: Path):
    """A client of the cluster once both workers have registered."""
    with distributed.Client(address, timeout=START_TIMEOUT) as client:
        deadline = time.monotonic() + START_TIMEOUT
        while len(client.scheduler_info()["workers"]) < 2:
            if time.monotonic() > deadline:
                raise AssertionError(f"2 dask workers did not register in {START_TIMEOUT} s:\n" +
                                     "\n".join(tail(logs / f"{w}.log", 800) for w in ("scheduler", "w0", "w1")))
            time.sleep(0.1)
        yield client


# --------------------------------------------------------------------------------------------------------------
# Tests


def test_worker_killed_mid_run_gives_the_same_bytes_as_loky(cluster, tmp_path):
    address, workers, logs = cluster
    cache = tmp_path / "cache"
    # The local reference first (the cluster starts meanwhile); it fills the CoACD cache the dask run reuses.
    loky = tmp_path / "loky"
    ref = subprocess.run(gen_run(loky, cache, "--jobs", "2"), cwd=REPO, env=env(), capture_output=True, text=True,
                         timeout=RUN_TIMEOUT)
    assert ref.returncode == 0, ref.stdout[-3000:] + ref.stderr[-3000:]
    tasks = manifest_lines(loky)
    several = {stage for stage, n in tasks.items() if n >= 2}
    assert several, tasks

    out = tmp_path / "dask"
    log = tmp_path / "run.log"
    killed = None
    with connect(address, logs) as client:
        with open(log, "w") as f:
            run = subprocess.Popen(
                gen_run(out, cache, "--jobs", "2", "--backend", "dask", "--set", f"run.dask_address={address}"),
                cwd=REPO, env=env(), stdout=f, stderr=subprocess.STDOUT, start_new_session=True,
            )
        try:
            deadline = time.monotonic() + RUN_TIMEOUT
            # Kill a worker that holds a task, once a stage of several tasks has committed some but not all.
            while killed is None and run.poll() is None and time.monotonic() < deadline:
                lines = manifest_lines(out)
                mid = sorted(s for s in several if 1 <= lines.get(s, 0) < tasks[s])
                if mid:
                    names = {addr: w["name"] for addr, w in client.scheduler_info()["workers"].items()}
                    busy = {names.get(addr): keys for addr, keys in client.processing().items() if keys}
                    victim = next((name for name in ("w0", "w1") if busy.get(name)), None)
                    if victim is not None:
                        os.killpg(workers[victim].pid, signal.SIGKILL)
                        killed = f"worker {victim} holding {len(busy[victim])} task(s) in stage {mid[0]}"
                time.sleep(0.02)
            assert killed is not None, f"the run ended before a worker could be killed mid-stage:\n{tail(log)}"
            rc = wait_run(run, deadline, log)
            assert rc == 0, f"killed {killed}; the dask run exited {rc}:\n{tail(log)}"
            # The death was real: the scheduler dropped the worker, and the rest ran on the survivor.
            assert len(client.scheduler_info()["workers"]) == 1
        finally:
            kill_group(run)
    print(f"killed {killed}; the run finished")
    assert "Remove worker" in tail(logs / "scheduler.log", 100_000)
    # Same content keys first (else the code or config changed between the two runs), then the same bytes.
    assert task_keys(out) == task_keys(loky)
    assert shard_hashes(out) == shard_hashes(loky)
    assert sha256_file(out / "dataset" / "grasps.parquet") == sha256_file(loky / "dataset" / "grasps.parquet")


def crashy_run(out: Path, address: str, *sets: str) -> list[str]:
    gen = "from tests.toy_stages import CRASHY; from pipeline.cli import build_app; build_app(CRASHY)()"
    return [sys.executable, "-c", gen, "run", "--out", str(out), "--jobs", "2", "--backend", "dask", "--set",
            f"run.dask_address={address}", *(a for s in sets for a in ("--set", s))]


def test_task_that_kills_every_worker_stops_the_run_in_one_line(cluster, tmp_path):
    address, _, logs = cluster
    out = tmp_path / "out"
    with connect(address, logs):
        # The crashing task alone: dask suspects every task a dying worker held, so a neighbour could share its fate.
        result = subprocess.run(crashy_run(out, address, "numbers.ids=[crash]"), cwd=REPO, env=env(),
                                capture_output=True, text=True, timeout=RUN_TIMEOUT)
    text = " ".join((result.stdout + result.stderr).split())  # undo line wrapping
    assert result.returncode == 2, text
    assert re.search(r"error: numbers/crash: every dask worker that ran it died \(\d+ of them", text), text
    assert "Traceback" not in text
    assert not committed(out, "numbers")


def test_scheduler_killed_mid_run_stops_the_run_in_one_line(cluster, tmp_path):
    address, procs, logs = cluster
    out = tmp_path / "out"
    log = tmp_path / "run.log"
    with connect(address, logs):
        with open(log, "w") as f:
            run = subprocess.Popen(crashy_run(out, address, "numbers.ids=[a, b, slow]"), cwd=REPO, env=env(),
                                   stdout=f, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            deadline = time.monotonic() + RUN_TIMEOUT
            while manifest_lines(out).get("numbers", 0) < 2 and run.poll() is None and time.monotonic() < deadline:
                time.sleep(0.02)
            assert run.poll() is None, tail(log)
            os.killpg(procs["scheduler"].pid, signal.SIGKILL)  # once two tasks are committed and one runs
            rc = wait_run(run, deadline, log)
        finally:
            kill_group(run)
    text = tail(log)
    assert rc == 2, text
    # dask's client logs its failed reconnection (a traceback) first; the run's own word is its last line
    last = text.strip().splitlines()[-1]
    assert last.startswith(f"error: lost the dask scheduler at {address} mid-run"), text
    assert {e.task for e in committed(out, "numbers").values()} == {"a", "b"}
