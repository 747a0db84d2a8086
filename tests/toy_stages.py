"""A tiny two-stage pipeline with no domain code, to test the engine on its own.

``numbers`` writes one JSON shard per id (random draws from the task rng); ``sums`` reads them all and writes
their sum. A task whose id starts with ``bad`` raises, to exercise failure handling. The engine benchmark
(``python -m bench.bench_engine``) runs the same pipeline at 10k+ tasks (``numbers.count``, ``numbers.work_ms``).
``WARN_TOY`` is the same pipeline with stages that warn and a published ``total.txt`` that is checked and repaired
(the scheduler's and the CLI's warning and publish-status tests). ``CRASHY`` is one stage whose ``crash`` task ends
its worker process, as a segfault or the out-of-memory killer would (the scheduler's and the cluster's fault tests).
"""

from __future__ import annotations

import dataclasses
import errno
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from pipeline.config import RunConfig
from pipeline.errors import GenError
from pipeline.plan import Project
from pipeline.stage import RunContext, Stage, Task, Upstream


class InputError(GenError):
    """A toy input that cannot be used."""


def write_json(path: Path, tree: dict) -> None:
    path.write_text(json.dumps(tree, sort_keys=True))


def read_json(path: Path) -> dict:
    return json.loads(Path(path).read_text())


def spin(seconds: float) -> float:
    """Burn ``seconds`` of CPU; returns a checksum."""
    end = time.process_time() + seconds
    acc = 0.0
    while time.process_time() < end:
        acc += sum(i * 0.5 for i in range(200))
    return acc


@dataclasses.dataclass(frozen=True)
class NumbersParams:
    ids: tuple[str, ...] = ("a", "b", "c", "d")
    """Task ids."""
    size: int = 5
    """Draws per task."""
    sleep: float = 0.0
    """Seconds each task sleeps (to give a killer time)."""
    input_file: str | None = None
    """Optional raw input whose bytes enter every key."""
    disk_full_while: str | None = None
    """While this file exists, writing a shard fails as on a full disk (ENOSPC), after a partial write."""
    count: int = 0
    """When > 0, this many tasks ``n000000``, ``n000001``, ... instead of ``ids`` (10k ids in the params would be
    pickled into every task)."""
    work_ms: float = 0.0
    """CPU milliseconds each task burns (not sleep: a sleeping task would hide contention); when > 0 its entry's
    meta also holds the task's CPU seconds, its process id and that process's CPU clock after it."""

    def __post_init__(self) -> None:
        if self.size <= 0:
            raise ValueError(f"size: must be > 0, got {self.size!r}")


@dataclasses.dataclass(frozen=True)
class SumsParams:
    scale: float = 1.0
    """Multiplier of the sum."""


@dataclasses.dataclass(frozen=True)
class ToyConfig:
    run: RunConfig = dataclasses.field(default_factory=RunConfig)
    numbers: NumbersParams = dataclasses.field(default_factory=NumbersParams)
    sums: SumsParams = dataclasses.field(default_factory=SumsParams)


class NumbersStage(Stage):
    name = "numbers"
    version = 1
    ext = "json"

    def tasks(self, params: NumbersParams, upstream: Upstream) -> list[Task]:
        inputs = (params.input_file,) if params.input_file else ()
        ids = [f"n{i:06d}" for i in range(params.count)] if params.count > 0 else params.ids
        # Longer ids claim more work, so tests can see the scheduler's longest-first order.
        return [Task(id=i, inputs=inputs, cost=len(i)) for i in ids]

    def run(self, task, params, upstream, rng, out: Path, ctx: RunContext):
        if task.id.startswith("bad"):
            raise InputError(f"{task.id}: this input is broken on purpose")
        start = time.process_time()
        time.sleep(params.sleep)
        spin(params.work_ms / 1000.0)
        if params.disk_full_while and Path(params.disk_full_while).exists():
            out.write_text('{"x": [0.1, ')  # what got onto the disk before it filled up
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        write_json(out, {"x": rng.normal(size=params.size).tolist(), "id": task.id})
        if params.work_ms <= 0:
            return {"n": params.size}
        # The worker's CPU clock after the task: its largest value per pid is that worker's whole CPU time, so the
        # workers' CPU outside the tasks can be told apart from the tasks' own, whatever the machine's load.
        cpu = time.process_time()
        return {"n": params.size, "cpu": cpu - start, "pid": os.getpid(), "worker_cpu": cpu}


class SumsStage(Stage):
    name = "sums"
    inputs = ("numbers",)
    version = 1
    ext = "json"
    published = ("published",)

    def tasks(self, params: SumsParams, upstream: Upstream) -> list[Task]:
        return [Task(id="total")]

    def run(self, task, params, upstream, rng, out: Path, ctx: RunContext):
        total = sum(sum(read_json(upstream.path("numbers", i))["x"]) for i in upstream.ids("numbers"))
        write_json(out, {"total": total * params.scale})
        return {"inputs": len(upstream.ids("numbers"))}

    def publish(self, params, shards: Upstream, dest: Path) -> None:
        total = float(read_json(shards.path("sums", "total"))["total"])
        (dest / "published").mkdir(exist_ok=True)
        (dest / "published" / "total.txt").write_text(f"{total!r} from {len(shards.ids('numbers'))} shards\n")


TOY = Project(name="toy", schema=ToyConfig, stages=(SumsStage(), NumbersStage()))


class WarningNumbers(NumbersStage):
    """Numbers whose planning leaves out ids starting with ``x`` (and says so), and whose tasks warn: every task
    the same text, ids with a ``w`` one of their own."""

    def tasks(self, params, upstream):
        return [t for t in super().tasks(params, upstream) if not t.id.startswith("x")]

    def plan_warnings(self, params, upstream):
        dropped = [i for i in params.ids if i.startswith("x")]
        return [f"left out {', '.join(dropped)} [ids starting with x]"] if dropped else []

    def run(self, task, params, upstream, rng, out, ctx):
        meta = super().run(task, params, upstream, rng, out, ctx)
        return {**meta, "warnings": ["draws look odd"] + ([f"{task.id} is special"] if "w" in task.id else [])}


class CheckedSums(SumsStage):
    """Sums whose published total.txt is checked: publish_status names it when it is missing or not what publish
    writes (or when its shard is being remade), publish rewrites it and says so; the warnings it sees are kept."""

    seen_warnings: dict = {}

    @staticmethod
    def text(shards):
        total = float(read_json(shards.path("sums", "total"))["total"])
        return f"{total!r} from {len(shards.ids('numbers'))} shards\n"

    def publish_status(self, params, shards, dest):
        path = dest / "published" / "total.txt"
        if not path.exists():
            return ["total.txt missing (will be replaced)"]
        if "total" not in shards.ids("sums") or path.read_text() != self.text(shards):
            return ["total.txt damaged (will be replaced)"]
        return []

    def publish(self, params, shards, dest):
        CheckedSums.seen_warnings = {s: shards.warnings(s) for s in ("numbers", "sums")}
        path = dest / "published" / "total.txt"
        before = path.read_text() if path.exists() else None
        super().publish(params, shards, dest)
        if before is not None and before != path.read_text():
            return ["replaced total.txt (damaged)"]
        return None


WARN_TOY = Project(name="toy", schema=TOY.schema, stages=(CheckedSums(), WarningNumbers()))


# A one-stage pipeline with a task that ends its worker process (workers import it from here).


@dataclasses.dataclass(frozen=True)
class CrashParams:
    ids: tuple[str, ...] = ("a", "b", "crash")
    """Task ids; ``crash`` ends its process at once, ``slow`` takes a minute, ``child`` spends 0.3 s of CPU in a
    child process."""
    crash_once: str | None = None
    """A file path: when given, ``crash`` ends its process only if the file is not there, and makes it."""


@dataclasses.dataclass(frozen=True)
class CrashConfig:
    run: RunConfig = dataclasses.field(default_factory=RunConfig)
    numbers: CrashParams = dataclasses.field(default_factory=CrashParams)


class CrashStage(Stage):
    name = "numbers"
    version = 1
    ext = "txt"

    def tasks(self, params: CrashParams, upstream) -> list[Task]:
        return [Task(id=i) for i in params.ids]

    def run(self, task, params, upstream, rng, out: Path, ctx):
        if task.id == "crash" and not (params.crash_once and os.path.exists(params.crash_once)):
            if params.crash_once:
                Path(params.crash_once).touch()
            os._exit(70)  # no exception, no cleanup: what a segfault or the OOM killer does to the worker
        if task.id == "slow":
            time.sleep(60)
        if task.id == "child":  # 0.3 s of CPU in a child process it waits for
            busy = "import time\nstart = time.process_time()\nwhile time.process_time() - start < 0.3: pass"
            subprocess.run([sys.executable, "-c", busy], check=True)
        out.write_text(task.id)


CRASHY = Project(name="crashy", schema=CrashConfig, stages=(CrashStage(),))
