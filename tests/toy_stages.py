"""A tiny two-stage pipeline with no domain code, to test the engine on its own.

``numbers`` writes one HDF5 shard per id (random draws from the task rng); ``sums`` reads them all and writes
their sum. A task whose id starts with ``bad`` raises, to exercise failure handling.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from pipeline.config import RunConfig, check
from pipeline.errors import InputError
from pipeline.io import read_h5, write_h5
from pipeline.scheduler import Project
from pipeline.stage import RunContext, Stage, Task, Upstream


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

    def __post_init__(self) -> None:
        check("size", self.size > 0, "be > 0", self.size)


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

    def tasks(self, params: NumbersParams, upstream: Upstream) -> list[Task]:
        inputs = (params.input_file,) if params.input_file else ()
        # Longer ids claim more work, so tests can see the scheduler's longest-first order.
        return [Task(id=i, inputs=inputs, cost=len(i)) for i in params.ids]

    def run(self, task, params, upstream, rng, out: Path, ctx: RunContext):
        if task.id.startswith("bad"):
            raise InputError(f"{task.id}: this input is broken on purpose")
        time.sleep(params.sleep)
        write_h5(out, {"x": rng.normal(size=params.size), "@attrs": {"id": task.id}})
        return {"n": params.size}


class SumsStage(Stage):
    name = "sums"
    inputs = ("numbers",)
    version = 1

    def tasks(self, params: SumsParams, upstream: Upstream) -> list[Task]:
        return [Task(id="total")]

    def run(self, task, params, upstream, rng, out: Path, ctx: RunContext):
        total = sum(float(read_h5(upstream.path("numbers", i))["x"].sum()) for i in upstream.ids("numbers"))
        write_h5(out, {"total": np.float64(total * params.scale)})
        return {"inputs": len(upstream.ids("numbers"))}

    def publish(self, params, shards: Upstream, dest: Path) -> None:
        total = float(read_h5(shards.path("sums", "total"))["total"])
        (dest / "published").mkdir(exist_ok=True)
        (dest / "published" / "total.txt").write_text(f"{total!r} from {len(shards.ids('numbers'))} shards\n")


TOY = Project(name="toy", schema=ToyConfig, stages=(SumsStage(), NumbersStage()))
