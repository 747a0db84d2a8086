"""Running stages: plan by key, skip what is committed, fan the rest out through joblib, commit results.

The parent process is the only writer of a manifest. Workers write their own shards (atomically, in the stage
folder) and return an :class:`~pipeline.store.Entry`; the parent appends it. So a kill at any moment leaves
either a committed shard or nothing, and the next run picks up exactly the tasks that are not committed.

The run's parts: planning (:mod:`pipeline.plan`), one task in a worker (:mod:`pipeline.worker`), where the
workers are (:mod:`pipeline.backends`); ``gen status`` is :mod:`pipeline.status`.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import joblib

from pipeline.backends import lost_worker, parallel_backend, resolve_jobs
from pipeline.config import RunConfig, to_yaml
from pipeline.fingerprint import module_cache
from pipeline.plan import (
    PlannedTask,
    Project,
    check_shards,
    committed,
    one_check_per_shard,
    plan,
    read_entries,
    shard_ok,
    upstream_view,
    view_entries,
)
from pipeline.stage import RunContext, Stage, Upstream, stage_waves, topological_order
from pipeline.store import Entry, Manifest, RunLock, remove_stray_temps, run_config_path, stage_dir, write_text_atomic
from pipeline.worker import ABORTED, DiskFullError, SharedView, TaskView, execute_task, out_of_space


@dataclasses.dataclass
class StageReport:
    """What one stage did in a run."""

    stage: str
    total: int = 0
    ran: int = 0
    skipped: int = 0
    failed: int = 0
    seconds: float = 0.0
    """From the start of the stage's wave to its publish: stages of one wave run side by side, so theirs overlap."""
    wave: int = 0
    """Index of the wave the stage ran in (stages of one wave do not read each other and share the workers)."""
    failures: list[tuple[str, str]] = dataclasses.field(default_factory=list)
    """(task id, error text) of every failed task, new or remembered."""
    warnings: list[str] = dataclasses.field(default_factory=list)
    """What the user should know about the stage's current output (:func:`stage_warnings`): planning warnings
    (:meth:`Stage.plan_warnings`), then the ``meta["warnings"]`` of its current shards, run now or earlier."""
    repaired: list[str] = dataclasses.field(default_factory=list)
    """What :meth:`Stage.publish` repaired in the output it had published earlier (damaged or missing files)."""


def run_pipeline(
    project: Project,
    config: Any,
    targets: Sequence[str] | None = None,
    *,
    retry_failed: bool = False,
    progress: Any = None,
) -> list[StageReport]:
    """Run ``targets`` (and what they need) into ``config.run.out``.

    Parameters
    ----------
    project : Project
        The stages and schema.
    config : dataclass
        A loaded config; ``config.run`` says where and how.
    targets : sequence of str, optional
        Stage names; all stages when None.
    retry_failed : bool
        Run again the tasks the manifest records as failed (by default they are reported, not retried: the same
        key fails the same way).
    progress : callable, optional
        ``progress(event, **info)`` hook for a progress display (see :mod:`pipeline.cli`).

    Returns
    -------
    list of StageReport, in run order.
    """
    run: RunConfig = config.run
    out = Path(run.out)
    ctx = RunContext(out=out.resolve(), cache_dir=Path(run.cache_dir).resolve())
    jobs = resolve_jobs(run.jobs)
    order = topological_order(project.stages, targets)
    notify = progress or (lambda event, **info: None)
    reports: dict[str, StageReport] = {}
    current: dict[str, set[str]] = {}
    warned: dict[str, list[str]] = {}
    checks = _Checks(config, list(order))
    with RunLock(out), parallel_backend(run, jobs), one_check_per_shard(), module_cache(ctx.cache_dir):
        remove_stray_temps(out)
        write_text_atomic(run_config_path(out), to_yaml(config, comments=False))
        for index, wave in enumerate(stage_waves(order)):
            for stage_run in _run_wave(wave, config, out, ctx, jobs, retry_failed, notify, current, warned, checks):
                current[stage_run.stage.name] = stage_run.keys
                stage_run.report.wave = index
                reports[stage_run.stage.name] = stage_run.report
    return [reports[s.name] for s in order]


@dataclasses.dataclass
class _Checks:
    """The stages' :meth:`Stage.check` calls of a run: made once, just before its first task is handed out, for
    the stages of that wave that have tasks to run and for every stage of the later waves (not planned yet, so
    they may run). A stage planned complete (every task committed or a remembered failure) runs nothing and is not
    checked, so a no-op rerun checks nothing.

    Why not check every stage up front: a check may be costly for what it guards (the probe's imports torch and
    scikit-learn into the scheduler process of every ``gen run``, though the probe's own task imports them where it
    runs; docs/decisions/2026-12-03-engine-at-scale.md). The promise stays: no task starts before every stage that
    may run is checked."""

    config: Any
    unplanned: list[Stage]
    done: bool = False

    def planning(self, wave: list[Stage]) -> None:
        """The stages of ``wave`` are being planned: from now on a check covers them only if they have work."""
        names = {s.name for s in wave}
        self.unplanned = [s for s in self.unplanned if s.name not in names]

    def before_work(self, runs: list[_StageRun]) -> None:
        """Check the stages that may still run, once, before the first task of the run."""
        if self.done:
            return
        self.done = True
        for stage in [r.stage for r in runs if r.pending] + self.unplanned:
            stage.check(stage.params(self.config))


def _finished(calls: list[Any], n_jobs: int) -> Iterator[Any]:
    """Run joblib ``calls`` and yield their results as they finish, so each shard is committed at once.

    A backend that cannot stream results (joblib's ray backend only returns lists) gets the calls in chunks of
    a few per worker: a killed run then loses at most one chunk of uncommitted work.
    """
    backend = joblib.parallel.get_active_backend()[0]
    if getattr(backend, "supports_return_generator", False):
        yield from joblib.Parallel(n_jobs=n_jobs, return_as="generator_unordered")(calls)
        return
    chunk = 4 * n_jobs
    for start in range(0, len(calls), chunk):
        yield from joblib.Parallel(n_jobs=n_jobs, return_as="list")(calls[start : start + chunk])


@dataclasses.dataclass
class _StageRun:
    """One stage's share of a wave: what it plans, what is left to run, and its report."""

    stage: Stage
    params: Any
    planned: list[PlannedTask]
    pending: list[PlannedTask]
    report: StageReport
    manifest: Manifest
    upstream: Upstream

    @functools.cached_property
    def keys(self) -> frozenset[str]:
        """The planned keys (computed once: a stage's finish tests every manifest entry against them)."""
        return frozenset(p.key for p in self.planned)

    @functools.cached_property
    def slim(self) -> dict[str, dict[str, Entry]]:
        """The upstream entries as tasks get them: compact, as the engine holds them (:func:`read_entries`: a
        scene's task gets the whole object library, 1,000 entries at 1,000 objects)."""
        return {s: dict(view_entries(self.upstream, s)) for s in self.upstream.stages()}

    @functools.cached_property
    def shared(self) -> SharedView:
        """:attr:`slim` pickled once, for the run's own workers (:class:`~pipeline.worker.SharedView`)."""
        return SharedView(self.upstream.out, self.slim)

    @functools.cached_property
    def slim_view(self) -> Upstream:
        """:attr:`slim` as an :class:`Upstream`, for a cluster's workers."""
        return Upstream(self.upstream.out, self.slim)

    def shipped(self, task: PlannedTask, own_workers: bool) -> Upstream | TaskView:
        """What ``task`` is shipped: a :class:`~pipeline.worker.TaskView` of the shared view to the run's own
        workers (loky's processes, started by this process from the same code); to a cluster's (dask, ray), the
        stage's one :attr:`slim_view`, which the worker cuts to the task's ``needs``
        (:func:`~pipeline.worker.execute_task`). Cluster workers live on between runs and may hold an older
        ``pipeline.worker``, and an ``Upstream`` is read by every version.

        Why one object for every task: joblib's dask backend scatters an argument to the cluster once per call
        when dask's ``sizeof`` says it is over 1 kB (:meth:`Upstream.__sizeof__`), and otherwise pickles it into
        every task, through the ``dask scheduler``; the stage's one view is sent once, and a task ships only a
        reference to it."""
        if own_workers:
            return self.shared.task_view(task.task.needs)
        return self.slim_view


def _start_stage(
    stage: Stage, params: Any, out: Path, retry_failed: bool, current: dict[str, set[str]], seed: int = 0
) -> _StageRun:
    """Plan a stage (with the run's ``seed``) and sort its tasks into committed (skipped), remembered failures and
    pending."""
    manifest = Manifest(stage_dir(out, stage.name))
    upstream = upstream_view(out, stage, current)
    planned = plan(stage, params, upstream, seed=seed)
    report = StageReport(stage.name, total=len(planned))
    entries = read_entries(manifest)
    check_shards(manifest, [entries[p.key] for p in planned if p.key in entries])
    pending: list[PlannedTask] = []
    for p in planned:
        entry = entries.get(p.key)
        if entry is not None and shard_ok(manifest, entry):
            report.skipped += 1
        elif entry is not None and entry.status == "failed" and not retry_failed:
            report.failed += 1
            report.failures.append((p.task.id, entry.error or "failed"))
        else:
            pending.append(p)
    return _StageRun(stage, params, planned, pending, report, manifest, upstream)


def _run_wave(
    wave: list[Stage],
    config: Any,
    out: Path,
    ctx: RunContext,
    jobs: int,
    retry_failed: bool,
    notify: Any,
    current: dict[str, set[str]],
    warned: dict[str, list[str]] | None = None,
    checks: _Checks | None = None,
) -> list[_StageRun]:
    """Run the pending tasks of stages that do not read each other through one pool of workers.

    Tasks go out longest first (:attr:`Task.cost`; stable, so equal costs keep stage and task order), and a
    stage is published and reported as soon as its last task is committed, while the others go on. ``checks``
    (:class:`_Checks`) run before the first task of the run.
    """
    start = time.perf_counter()
    checks = checks or _Checks(config, list(wave))
    checks.planning(wave)
    runs = [_start_stage(stage, stage.params(config), out, retry_failed, current, config.run.seed) for stage in wave]
    if any(r.pending for r in runs):
        checks.before_work(runs)
    left = {r.stage.name: len(r.pending) for r in runs}
    for r in runs:
        notify("stage_start", stage=r.stage.name, total=len(r.planned), skipped=r.report.skipped,
               remembered=r.report.failed)
    for r in runs:
        if not r.pending:
            _finish_stage(r, out, current, start, notify, warned)
    work = [(r, p) for r in runs for p in r.pending]
    if work:
        work.sort(key=lambda rp: -rp[1].task.cost)
        owner = {p.key: r for r, p in work}
        for r in runs:
            if r.pending:
                stage_dir(out, r.stage.name).mkdir(parents=True, exist_ok=True)
        own = _own_workers()
        calls = [
            joblib.delayed(execute_task)(r.stage, p, r.params, r.shipped(p, own), stage_dir(out, r.stage.name), ctx)
            for r, p in work
        ]
        try:
            for entry in _finished(calls, min(jobs, len(work))):
                r = owner[entry.key]
                _commit(r, entry)
                notify("task_done", stage=r.stage.name, task=entry.task, ok=entry.status == "ok")
                left[r.stage.name] -= 1
                if left[r.stage.name] == 0:
                    _finish_stage(r, out, current, start, notify, warned)
        except Exception as exc:
            error = lost_worker(exc, [name for name, n in left.items() if n > 0], sum(left.values()))
            if error is None:
                raise
            raise error from None
    return runs


def _own_workers() -> bool:
    """Whether the run's tasks go to processes this one starts (joblib's loky, or this process itself)."""
    backend = joblib.parallel.get_active_backend()[0]
    return type(backend).__name__ in ("LokyBackend", "SequentialBackend")


def _commit(r: _StageRun, entry: Entry) -> None:
    """Append a finished task's entry to its stage's manifest and count it; a full disk stops the run."""
    if entry.status == ABORTED:
        raise DiskFullError(
            f"{r.stage.name}/{entry.task}: {entry.error}. Free some space and run the same command again: "
            "finished tasks are kept, this one and the rest will run then"
        )
    try:
        r.manifest.append(entry)
    except OSError as exc:
        if not out_of_space(exc):
            raise
        raise DiskFullError(
            f"{r.manifest.path}: {exc.strerror}; free some space and run the same command again"
        ) from None
    if entry.status == "ok":
        r.report.ran += 1
    else:
        r.report.failed += 1
        r.report.failures.append((entry.task, entry.error or "failed"))


def _finish_stage(
    r: _StageRun,
    out: Path,
    current: dict[str, set[str]],
    start: float,
    notify: Any,
    warned: dict[str, list[str]] | None = None,
) -> None:
    """Collect the warnings of a stage whose tasks are all settled, publish it, and report it."""
    stage = r.stage
    warned = {} if warned is None else warned
    own = {e.task: e for e in read_entries(Manifest(stage_dir(out, stage.name))).values() if e.key in r.keys}
    r.report.warnings = stage_warnings(stage, r.params, r.upstream, own)
    # What publish sees also names the failed tasks: their inputs are left out of what it lays out.
    warned[stage.name] = r.report.warnings + [
        f"{task}: left out: {error.splitlines()[0] if error else 'failed'}" for task, error in sorted(r.report.failures)
    ]
    if type(stage).publish is not Stage.publish:
        view = upstream_view(out, stage, current)
        own = {e.task: e for k, e in committed(out, stage.name).items() if k in r.keys}
        shards = Upstream(
            out,
            {**{d: view_entries(view, d) for d in stage.inputs}, stage.name: own},
            warnings={s: warned[s] for s in (*stage.inputs, stage.name) if s in warned},
        )
        r.report.repaired = list(stage.publish(r.params, shards, out) or [])
    r.report.seconds = time.perf_counter() - start
    r.report.failures.sort()
    notify("stage_end", stage=stage.name, report=r.report)


WARNING_TASKS_SHOWN = 3
"""A warning that several tasks give is shown once, naming this many of them and counting the rest."""


def stage_warnings(stage: Stage, params: Any, upstream: Upstream, entries: Mapping[str, Entry]) -> list[str]:
    """A stage's warnings: :meth:`Stage.plan_warnings`, then the ``meta["warnings"]`` (list of str) of its
    successful ``entries`` (by task id), each as ``"<task>: <text>"``; a text that several tasks give is listed
    once, as ``"<text> (<n> tasks: a, b, c and 2 more)"``."""
    plan = [str(w) for w in stage.plan_warnings(params, upstream)]
    by_text: dict[str, list[str]] = {}
    for task_id in sorted(entries):
        entry = entries[task_id]
        found = entry.meta.get("warnings") if entry.status == "ok" and isinstance(entry.meta, Mapping) else None
        for text in found if isinstance(found, list) else []:
            tasks = by_text.setdefault(str(text), [])
            if task_id not in tasks:
                tasks.append(task_id)
    lines = []
    for text, tasks in by_text.items():
        if len(tasks) == 1:
            lines.append(f"{tasks[0]}: {text}")
        else:
            named = ", ".join(tasks[:WARNING_TASKS_SHOWN])
            more = f" and {len(tasks) - WARNING_TASKS_SHOWN} more" if len(tasks) > WARNING_TASKS_SHOWN else ""
            lines.append(f"{text} ({len(tasks)} tasks: {named}{more})")
    return list(dict.fromkeys(plan + lines))
