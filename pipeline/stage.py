"""What a stage is, and what it sees of its upstream stages.

A :class:`Stage` declares its ``name``, its upstream ``inputs``, a hand-bumped ``version``, the shard extension
it writes, how its work fans out (:meth:`Stage.tasks`) and how one task runs (:meth:`Stage.run`). The engine
(:mod:`pipeline.scheduler`) does everything else: keys, skipping finished work, parallelism, atomic writes,
the manifest. A stage knows nothing about scheduling; the engine knows nothing about the domain.
"""

from __future__ import annotations

import abc
import dataclasses
import graphlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import StageError
from pipeline.store import Entry, stage_dir


@dataclasses.dataclass(frozen=True)
class Task:
    """One unit of work of a stage; its output is one shard."""

    id: str
    """Unique within the stage (e.g. an object name, ``scene_000012``). Also the name a user sees."""
    payload: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    """Small JSON-able data the task needs (enters the key)."""
    inputs: tuple[str, ...] = ()
    """Raw input files the task reads; their bytes (not their paths) enter the key."""
    needs: Mapping[str, Sequence[str]] | None = None
    """Upstream shards the task reads, ``{stage: [task ids]}``; None means every shard of every input stage."""
    cost: float = 0.0
    """Relative work estimate (any unit, larger = longer). The scheduler hands out costly tasks first so that
    workers do not idle behind one long straggler; it never enters the key and never changes a shard."""


@dataclasses.dataclass(frozen=True)
class RunContext:
    """Where a task may keep things that are not its output. Nothing here may change a shard's bytes."""

    out: Path
    """The run's output folder."""
    cache_dir: Path
    """Folder for caches keyed by content (e.g. convex decompositions), kept across ``gen clean``."""


ENTRY_BYTES = 300
"""Memory an :class:`Upstream` view is taken to hold per entry (a compact entry pickles to 150-450 bytes)."""


class Upstream:
    """Read access to the committed shards of upstream stages.

    Parameters
    ----------
    out : Path
        The run's output folder.
    entries : dict
        ``{stage: {task_id: Entry}}`` of successful, verified shards.
    warnings : dict, optional
        ``{stage: [text]}``: the warnings the engine collected for stages of this run (given to ``publish``).
    """

    def __init__(
        self,
        out: Path,
        entries: Mapping[str, Mapping[str, Entry]],
        warnings: Mapping[str, Sequence[str]] | None = None,
    ):
        self.out = Path(out)
        self._entries = {stage: dict(by_id) for stage, by_id in entries.items()}
        self._warnings = {stage: list(w) for stage, w in (warnings or {}).items()}

    def __sizeof__(self) -> int:
        """Bytes held, estimated as :data:`ENTRY_BYTES` per entry.

        Why: dask's ``sizeof`` reads this, and joblib's dask backend scatters an argument to the cluster once
        (instead of pickling it into every task) only when that says over 1 kB
        (docs/decisions/2026-12-03-engine-at-scale.md)."""
        return object.__sizeof__(self) + ENTRY_BYTES * sum(len(by_id) for by_id in self._entries.values())

    def warnings(self, stage: str) -> list[str]:
        """Warnings of ``stage`` in this run (unit guesses, inputs left out, ...); empty when none or not known."""
        return list(self._warnings.get(stage, []))

    def stages(self) -> list[str]:
        return sorted(self._entries)

    def ids(self, stage: str) -> list[str]:
        """Task ids of ``stage`` that have a shard, sorted."""
        return sorted(self._by_stage(stage))

    def entry(self, stage: str, task_id: str) -> Entry:
        by_id = self._by_stage(stage)
        if task_id not in by_id:
            raise StageError(f"{stage}: no finished shard for task {task_id!r}")
        return by_id[task_id]

    def path(self, stage: str, task_id: str) -> Path:
        """Path of the shard of ``task_id`` in ``stage``."""
        entry = self.entry(stage, task_id)
        assert entry.file is not None
        return stage_dir(self.out, stage) / entry.file

    def key(self, stage: str, task_id: str) -> str:
        return self.entry(stage, task_id).key

    def meta(self, stage: str, task_id: str) -> dict[str, Any]:
        """The small metadata the task stored in the manifest."""
        return self.entry(stage, task_id).meta_dict()

    def keys(self, needs: Mapping[str, Sequence[str]] | None) -> dict[str, dict[str, str]]:
        """``{stage: {task_id: key}}`` for what a task reads: this enters the task's own key."""
        return {stage: {tid: self.key(stage, tid) for tid in sorted(ids)} for stage, ids in self._needs(needs).items()}

    def seeds(self, needs: Mapping[str, Sequence[str]] | None) -> dict[str, dict[str, str]]:
        """``{stage: {task_id: seed key}}`` for what a task reads: this enters the task's own seed key."""
        return {
            stage: {tid: self.entry(stage, tid).seed or self.key(stage, tid) for tid in sorted(ids)}
            for stage, ids in self._needs(needs).items()
        }

    def subset(self, needs: Mapping[str, Sequence[str]] | None) -> Upstream:
        """The part of this view a task reads (what gets shipped to its worker)."""
        return Upstream(self.out, {s: {t: self.entry(s, t) for t in ids} for s, ids in self._needs(needs).items()})

    def _needs(self, needs: Mapping[str, Sequence[str]] | None) -> dict[str, Sequence[str]]:
        if needs is None:
            return {stage: self.ids(stage) for stage in self._entries}
        unknown = sorted(set(needs) - set(self._entries))
        if unknown:
            raise StageError(f"task needs stage {unknown[0]!r}, which is not an input; inputs: {self.stages()}")
        return dict(needs)

    def _by_stage(self, stage: str) -> dict[str, Entry]:
        if stage not in self._entries:
            raise StageError(f"{stage!r} is not an input of this stage; inputs: {', '.join(self.stages()) or 'none'}")
        return self._entries[stage]


class Stage(abc.ABC):
    """A pipeline stage. Subclasses set the class attributes and implement :meth:`tasks` and :meth:`run`."""

    name: str = ""
    """Stage name; also its config section and its output folder."""
    inputs: tuple[str, ...] = ()
    """Names of the upstream stages whose shards it reads."""
    version: int = 1
    """Bump by hand when the stage's semantics or output format change: its outputs become stale."""
    ext: str = "h5"
    """Shard file extension (``h5`` or ``parquet``)."""
    published: tuple[str, ...] = ()
    """Paths, relative to the output folder, that :meth:`publish` writes (``gen clean`` removes them with the
    stage's shards)."""
    user_errors: tuple[type[BaseException], ...] = ()
    """Exception types (besides :class:`~pipeline.errors.GenError`) that mean bad input rather than a bug: a task
    failing with one is reported in one line, without a traceback."""

    def params(self, config: Any) -> Any:
        """This stage's params: the config section named like the stage."""
        return getattr(config, self.name)

    def check(self, params: Any) -> None:  # noqa: B027 - optional hook
        """Optional: raise if the stage cannot run here with these params (a missing library, a missing file), so
        the run stops before any work. Called once, before the run's first task, for every stage of the run that
        may still run (in order); not for a stage whose tasks are all committed, so a run with nothing to do
        calls none, and a check may be costly (import a library) without slowing a no-op rerun."""

    @abc.abstractmethod
    def tasks(self, params: Any, upstream: Upstream) -> list[Task]:
        """How the work fans out, given the params and the finished upstream shards."""

    @abc.abstractmethod
    def run(
        self, task: Task, params: Any, upstream: Upstream, rng: np.random.Generator, out: Path, ctx: RunContext
    ) -> dict[str, Any]:
        """Do one task: write its shard to ``out`` (a temp path the engine moves into place).

        Returns small JSON-able metadata for the manifest (row counts, warnings). Raise to fail the task; the
        message should name the input at fault.
        """

    def publish(self, params: Any, shards: Upstream, dest: Path) -> list[str] | None:  # noqa: B027 - optional
        """Optional: lay out this stage's committed shards for people somewhere under ``dest`` (the run's output
        folder). Runs in the parent process after the stage's tasks are committed, on every run, so it must be
        cheap, idempotent and write files atomically; it only reads shards, so it cannot change any key.

        ``shards`` is an :class:`Upstream` view holding this stage's own current shards plus its inputs' (by stage
        name; their shards are verified by sha256 in this run) and the warnings of this run's stages
        (:meth:`Upstream.warnings`). The default does nothing.

        It may return lines saying what it repaired in output published earlier (``"replaced scenes/x.h5
        (damaged)"``): the engine puts them on the stage's report. None or an empty list: nothing to say.
        """

    def publish_status(self, params: Any, shards: Upstream, dest: Path) -> list[str]:
        """Optional: what :meth:`publish` would repair in the output it published earlier, one line per file that
        is missing or damaged (``"scenes/x.h5 damaged (will be replaced)"``); empty when it is intact.

        ``gen status`` calls it when the stage has no new work (its shards are current, or will be remade with
        the same keys), with the view :meth:`publish` would get minus the shards that are missing or damaged now
        (those will be remade, so output linked to them is damaged too). It must be read-only and fast (file
        stats; read a file only when its stats say it changed). The default reports nothing.
        """
        return []

    def plan_warnings(self, params: Any, upstream: Upstream) -> list[str]:
        """Optional: warnings about how the work fans out (inputs a setting leaves out, ...), shown at the end of
        ``gen run`` with the warnings the tasks return in their metadata (``meta["warnings"]``). The default
        has none."""
        return []


def topological_order(stages: Sequence[Stage], targets: Sequence[str] | None = None) -> list[Stage]:
    """Stages in dependency order, restricted to ``targets`` and everything they need (all when None)."""
    by_name = {s.name: s for s in stages}
    for s in stages:
        for dep in s.inputs:
            if dep not in by_name:
                raise StageError(f"stage {s.name!r} needs unknown stage {dep!r}")
    wanted: set[str] = set()
    todo = list(targets) if targets else list(by_name)
    while todo:
        name = todo.pop()
        if name not in by_name:
            raise StageError(f"unknown stage {name!r}; choose one of: {', '.join(by_name)}")
        if name not in wanted:
            wanted.add(name)
            todo.extend(by_name[name].inputs)
    sorter = graphlib.TopologicalSorter({n: by_name[n].inputs for n in by_name})
    try:
        order = list(sorter.static_order())
    except graphlib.CycleError as exc:
        raise StageError(f"stages form a cycle: {exc.args[1]}") from None
    # Keep the declared order among independent stages, so runs and listings read the same every time.
    declared = [s.name for s in stages]
    order.sort(key=lambda n: (_depth(n, by_name), declared.index(n)))
    return [by_name[n] for n in order if n in wanted]


def stage_waves(order: Sequence[Stage]) -> list[list[Stage]]:
    """Split a :func:`topological_order` into waves: stages whose inputs all lie in earlier waves.

    The stages of one wave do not read each other, so their tasks can share the workers.
    """
    by_name = {s.name: s for s in order}
    waves: dict[int, list[Stage]] = {}
    for s in order:
        waves.setdefault(_depth(s.name, by_name), []).append(s)
    return [waves[d] for d in sorted(waves)]


def _depth(name: str, by_name: Mapping[str, Stage]) -> int:
    deps = [d for d in by_name[name].inputs if d in by_name]
    return 0 if not deps else 1 + max(_depth(d, by_name) for d in deps)
