"""Running stages: plan by key, skip what is committed, fan the rest out through joblib, commit results.

The parent process is the only writer of a manifest. Workers write their own shards (atomically, in the stage
folder) and return an :class:`~pipeline.store.Entry`; the parent appends it. So a kill at any moment leaves
either a committed shard or nothing, and the next run picks up exactly the tasks that are not committed.
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import errno
import functools
import gc
import multiprocessing
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import joblib

from pipeline.config import RunConfig, to_yaml
from pipeline.errors import ConfigError, GenError, StageError
from pipeline.fingerprint import stage_fingerprint
from pipeline.keys import (
    changed_parts,
    key_parts,
    params_digest,
    rng_for_key,
    seed_key,
    sha256_file,
    task_key,
    upstream_digest,
)
from pipeline.stage import RunContext, Stage, Task, Upstream, stage_waves, topological_order
from pipeline.store import (
    Entry,
    Manifest,
    RunLock,
    atomic_path,
    remove_stray_temps,
    run_config_path,
    shard_path,
    stage_dir,
    write_text_atomic,
)

BACKENDS = ("loky", "dask", "ray")


@dataclasses.dataclass(frozen=True)
class Project:
    """A pipeline: its config schema (a dataclass with a ``run: RunConfig`` field) and its stages."""

    name: str
    schema: type
    stages: tuple[Stage, ...]
    user_errors: tuple[type[BaseException], ...] = ()
    """Exception types (besides :class:`~pipeline.errors.GenError`) the command line reports in one line."""

    def stage(self, name: str) -> Stage:
        for s in self.stages:
            if s.name == name:
                return s
        raise StageError(f"unknown stage {name!r}; choose one of: {', '.join(s.name for s in self.stages)}")


@dataclasses.dataclass(frozen=True)
class PlannedTask:
    task: Task
    key: str
    parts: dict[str, str]
    seed: str
    """The seed key (:func:`pipeline.keys.seed_key`): the task's random generator comes from it."""


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


# --------------------------------------------------------------------------------------------------------------
# Planning


def committed(out: Path, stage: str, *, verify_hash: bool = True) -> dict[str, Entry]:
    """Successful, intact entries of a stage folder, by key."""
    manifest = Manifest(stage_dir(out, stage))
    return {k: e for k, e in manifest.entries().items() if shard_ok(manifest, e, verify_hash=verify_hash)}


_checked: dict[tuple[Any, ...], bool] | None = None
"""The shard checks of the run (or status) in progress, by file and expected hash; None outside one."""


@contextlib.contextmanager
def one_check_per_shard() -> Iterator[None]:
    """Within the block, :func:`shard_ok` hashes each shard file once: a run looks at a stage's shards when it
    plans the stage, plans each stage below it and publishes. A check is keyed by the file's path, size, mtime,
    inode and the expected sha256, so a shard the run writes (a new file) is checked anew."""
    global _checked
    saved, _checked = _checked, {}
    try:
        yield
    finally:
        _checked = saved


def shard_ok(manifest: Manifest, entry: Entry, *, verify_hash: bool = True) -> bool:
    """:meth:`Manifest.shard_ok`, done once per shard file inside :func:`one_check_per_shard`."""
    if _checked is None or not verify_hash or entry.status != "ok" or entry.file is None:
        return manifest.shard_ok(entry, verify_hash=verify_hash)
    path = manifest.stage_dir / entry.file
    try:
        st = path.stat()
    except OSError:
        return False
    key = (str(path), st.st_size, st.st_mtime_ns, st.st_ino, st.st_dev, entry.bytes, entry.sha256)
    if key not in _checked:
        _checked[key] = manifest.shard_ok(entry)
    return _checked[key]


def upstream_view(out: Path, stage: Stage, current: dict[str, set[str]], *, verify_hash: bool = True) -> Upstream:
    """The committed shards of ``stage``'s inputs whose keys are current, by task id.

    ``current`` maps each upstream stage to the keys its tasks have under the present config (the scheduler
    plans stages in order, so it knows them). Shards of older configs stay on disk but are invisible here.
    """
    entries: dict[str, dict[str, Entry]] = {}
    for dep in stage.inputs:
        keys = current.get(dep, set())
        entries[dep] = {e.task: e for k, e in committed(out, dep, verify_hash=verify_hash).items() if k in keys}
    return Upstream(out, entries)


def view_entries(view: Upstream, stage: str) -> dict[str, Entry]:
    """``{task_id: Entry}`` of one stage in an upstream view."""
    return {tid: view.entry(stage, tid) for tid in view.ids(stage)}


def plan(stage: Stage, params: Any, upstream: Upstream, *, seed: int = 0) -> list[PlannedTask]:
    """The stage's tasks with their content keys; ``seed`` is the run's (``config.run.seed``, see
    :func:`pipeline.keys.key_parts`): 0 leaves the keys as they were before the seed existed."""
    tasks = stage.tasks(params, upstream)
    seen: dict[str, Task] = {}
    for t in tasks:
        if t.id in seen:
            raise StageError(f"{stage.name}: two tasks share the id {t.id!r}; task ids must be unique")
        seen[t.id] = t
    file_hashes: dict[str, str] = {}
    code = stage_fingerprint(type(stage).__module__)
    params_hash = params_digest(params)  # the same for every task: hashed once, not once per task
    planned = []
    every: tuple[str, str] | None = None  # the upstream digests of a task that reads everything: the same for all
    for t in tasks:
        if t.needs is not None:
            up = (upstream_digest(upstream.keys(t.needs)), upstream_digest(upstream.seeds(t.needs)))
        else:
            every = every or (upstream_digest(upstream.keys(None)), upstream_digest(upstream.seeds(None)))
            up = every
        hashes = {}
        for i, path in enumerate(t.inputs):
            if path not in file_hashes:
                file_hashes[path] = sha256_file(path)
            hashes[str(i)] = file_hashes[path]
        parts = key_parts(
            stage=stage.name,
            version=stage.version,
            params=params,
            params_hash=params_hash,
            task_id=t.id,
            payload=t.payload,
            upstream=None,
            upstream_hash=up[0],
            input_hashes=hashes,
            code=code,
            seed=seed,
        )
        planned.append(PlannedTask(t, task_key(parts), parts, seed_key(parts, None, upstream_seeds_hash=up[1])))
    return planned


# --------------------------------------------------------------------------------------------------------------
# Executing one task (in a worker)


OUT_OF_SPACE = (errno.ENOSPC, errno.EDQUOT)
"""Write errors that are the disk's, not the task's: the run stops, and a resume redoes the task."""
ABORTED = "aborted"
"""Status of an entry the scheduler never commits: the task could not write its shard (disk full)."""


class DiskFullError(GenError):
    """The output folder's disk is full (or over quota). Finished tasks are kept; free space and run again."""


def out_of_space(exc: OSError) -> bool:
    """Whether a write failed for lack of space. HDF5 and Arrow do not always set ``errno``: read the text too."""
    return exc.errno in OUT_OF_SPACE or any(os.strerror(e) in str(exc) for e in OUT_OF_SPACE)


def _find_malloc_trim() -> Any:
    """The C library's ``malloc_trim`` (glibc), or None where it has none (macOS, musl)."""
    try:
        return ctypes.CDLL(None).malloc_trim
    except (AttributeError, OSError):
        return None


_MALLOC_TRIM = _find_malloc_trim()


GC_MARGIN = 100 * 2**20
"""Bytes of resident growth over a worker's first settled size after which it also collects garbage."""

_settled_rss: int | None = None
"""This worker's resident size after its first task (and a collection), or None before it."""


def resident_bytes() -> int | None:
    """This process's resident set size in bytes (Linux ``/proc``), or None where it cannot be read cheaply."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return None


def return_freed_memory() -> bool:
    """Give the heap pages freed since back to the OS, and collect garbage when the worker has grown; False where
    the C library cannot trim.

    Why: glibc keeps freed blocks in its heap, so a worker's resident size climbs to the highest peak any of its
    tasks reached and stays there. loky reads that as a leak (300 MB above the worker's size after its first task),
    restarts the worker and warns "A worker stopped while some jobs were given to the executor ... memory leak"
    (seen in ``make dataset``, in the robustness stage). Measured on ten of the default dataset's robustness tasks
    in one process: 290-390 MB resident after each with ``gc.collect()`` alone, 255-264 MB after this.

    The trim costs microseconds; a full ``gc.collect()`` costs 40 ms in a worker that imported the grasp library
    (bench/bench_engine.py: it was most of the engine's per-task overhead), so it runs only after the first task
    and when the worker stands more than :data:`GC_MARGIN` above its settled size (Python's own generational
    collection still runs as usual)."""
    global _settled_rss
    trimmed = _trim_heap()
    rss = resident_bytes()
    if rss is None or _settled_rss is None or rss > _settled_rss + GC_MARGIN:
        gc.collect()
        trimmed = _trim_heap()
        rss = resident_bytes()
        if _settled_rss is None:
            _settled_rss = rss
    return trimmed


def _trim_heap() -> bool:
    if _MALLOC_TRIM is None:
        return False
    _MALLOC_TRIM(0)
    return True


def execute_task(
    stage: Stage, planned: PlannedTask, params: Any, upstream: Upstream, stage_dir: Path, ctx: RunContext
) -> Entry:
    """Run one task and write its shard; never raises (a failure becomes a ``failed`` entry)."""
    in_worker = multiprocessing.parent_process() is not None
    if in_worker and threading.current_thread() is threading.main_thread():
        # Ctrl-C reaches the whole process group: the parent reports it once and stops; workers stay quiet.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        return _execute_task(stage, planned, params, upstream, stage_dir, ctx)
    finally:
        if in_worker:
            return_freed_memory()


def _execute_task(
    stage: Stage, planned: PlannedTask, params: Any, upstream: Upstream, stage_dir: Path, ctx: RunContext
) -> Entry:
    start, cpu_start = time.perf_counter(), time.process_time()
    task, key = planned.task, planned.key
    final = shard_path(stage_dir, key, stage.ext)
    try:
        rng = rng_for_key(planned.seed)
        with atomic_path(final) as tmp:
            meta = stage.run(task, params, upstream, rng, tmp, ctx) or {}
        return Entry(
            key=key,
            task=task.id,
            status="ok",
            file=str(final.relative_to(stage_dir)),
            sha256=sha256_file(final),
            bytes=final.stat().st_size,
            seconds=round(time.perf_counter() - start, 4),
            cpu_seconds=round(time.process_time() - cpu_start, 4),
            parts=planned.parts,
            meta=meta,
            seed=planned.seed,
        )
    except OSError as exc:
        if not out_of_space(exc):
            return _failed_entry(stage, planned, exc, start)
        # Not the task's fault: nothing is recorded, so the task runs again once space is freed.
        return Entry(key=key, task=task.id, status=ABORTED, error=f"{exc.strerror or exc} while writing {final}")
    except Exception as exc:  # noqa: BLE001 - any task error is recorded, and the run goes on
        return _failed_entry(stage, planned, exc, start)


def _failed_entry(stage: Stage, planned: PlannedTask, exc: BaseException, start: float) -> Entry:
    """The manifest entry of a task that raised: the error in one line for a user error, with the end of the
    traceback for anything else (a bug)."""
    text = f"{type(exc).__name__}: {exc}"
    if not _is_user_error(exc, stage):
        text += "\n" + "".join(traceback.format_exception(exc)[-3:])
    return Entry(
        key=planned.key,
        task=planned.task.id,
        status="failed",
        seconds=round(time.perf_counter() - start, 4),
        parts=planned.parts,
        error=text.strip(),
    )


def _is_user_error(exc: BaseException, stage: Stage) -> bool:
    from pipeline.errors import GenError

    return isinstance(exc, (GenError, *stage.user_errors))


# --------------------------------------------------------------------------------------------------------------
# Running


def resolve_jobs(jobs: int) -> int:
    """0 -> number of usable cores."""
    if jobs > 0:
        return jobs
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


DASK_CONNECT_TIMEOUT = 10
"""Seconds to wait for ``run.dask_address`` to answer before giving up with a one-line error."""


@contextlib.contextmanager
def parallel_backend(run: RunConfig, jobs: int) -> Iterator[None]:
    """Set joblib's backend for the run: local processes (loky), a dask.distributed cluster, or ray."""
    if run.backend == "loky":
        with joblib.parallel_config(backend="loky"):
            yield
        return
    if run.backend == "dask":
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError:
            raise ConfigError("run.backend: 'dask' needs the dask[distributed] package installed") from None
        if run.dask_address:
            try:
                client = Client(run.dask_address, timeout=DASK_CONNECT_TIMEOUT)
            except (OSError, TimeoutError) as exc:
                raise ConfigError(
                    f"run.dask_address: cannot reach a dask scheduler at {run.dask_address} within "
                    f"{DASK_CONNECT_TIMEOUT} s ({type(exc).__name__}: {exc}); start one (dask scheduler) or fix "
                    "the address"
                ) from None
            cluster = None
        else:
            cluster = LocalCluster(
                n_workers=jobs, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=40
            )
            client = Client(cluster)
        import concurrent.futures

        from distributed import KilledWorker
        from joblib._dask import DaskDistributedBackend

        def gave_up(exc: BaseException, calls: Any) -> GenError:
            """One line for a batch dask gave up on, naming its tasks when they are ``execute_task`` calls."""
            try:
                names = ", ".join(f"{args[0].name}/{args[1].task.id}" for _, args, _ in calls.items)
            except (AttributeError, IndexError, TypeError):
                names = ""
            if not isinstance(exc, KilledWorker):
                text = (str(exc).splitlines() or [""])[0]
                return GenError(f"{names or 'a task'}: dask could not run it ({type(exc).__name__}: {text})")
            return GenError(
                f"{names or 'a task'}: every dask worker that ran it died ({exc.allowed_failures + 1} of them, the "
                f"last {getattr(exc.last_worker, 'address', exc.last_worker)}): it crashes them or runs them out "
                "of memory, see the workers' logs. Finished tasks are kept; run the same command again to resume"
            )

        class Failed:
            """What the completion callback gets for a batch whose dask future failed."""

            def __init__(self, error: GenError):
                self.error = error

        class Backend(DaskDistributedBackend):
            """joblib's dask backend, except that a batch dask gives up on fails the joblib call. A worker that
            dies is survived by dask itself (its tasks run again elsewhere); but a task whose workers die
            ``distributed.scheduler.allowed-failures`` + 1 times (4 by default: it crashes them, or runs them out
            of memory) gets a ``KilledWorker`` error, which joblib's backend sets on the batch's future and never
            reports to its completion callback: the call, waiting on the callbacks, would wait forever."""

            def submit(self, func: Any, callback: Any = None) -> Any:
                future = super().submit(func, callback)

                def done(f: Any) -> None:
                    if callback is not None and not f.cancelled() and f.exception() is not None:
                        callback(Failed(gave_up(f.exception(), func)))

                future.add_done_callback(done)
                return future

            def retrieve_result_callback(self, out: Any) -> Any:
                if isinstance(out, Failed):
                    raise out.error
                return super().retrieve_result_callback(out)

        try:
            with joblib.parallel_config(backend=Backend(client=client)):
                yield
        except concurrent.futures.CancelledError as exc:
            if getattr(exc, "reason", None) != "scheduler-connection-lost":
                raise
            raise GenError(
                f"lost the dask scheduler at {client.scheduler.address} mid-run (it stopped, or the network failed); "
                "finished tasks are kept: start it again and run the same command again to resume"
            ) from None
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
        return
    if run.backend == "ray":
        try:
            import ray
            from ray.util.joblib import register_ray
        except ImportError:
            raise ConfigError(
                "run.backend: 'ray' needs the ray package installed (pip install 'ray[default]')"
            ) from None
        register_ray()
        if not ray.is_initialized():
            ray.init(num_cpus=jobs, include_dashboard=False, log_to_driver=False)
        with joblib.parallel_config(backend="ray"):
            yield
        return
    raise ConfigError(f"run.backend: must be one of {', '.join(BACKENDS)}, got {run.backend!r}")


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
    for stage in order:
        stage.check(stage.params(config))
    with RunLock(out), parallel_backend(run, jobs), one_check_per_shard():
        remove_stray_temps(out)
        write_text_atomic(run_config_path(out), to_yaml(config, comments=False))
        for index, wave in enumerate(stage_waves(order)):
            for stage_run in _run_wave(wave, config, out, ctx, jobs, retry_failed, notify, current, warned):
                current[stage_run.stage.name] = stage_run.keys
                stage_run.report.wave = index
                reports[stage_run.stage.name] = stage_run.report
    return [reports[s.name] for s in order]


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


def _start_stage(
    stage: Stage, params: Any, out: Path, retry_failed: bool, current: dict[str, set[str]], seed: int = 0
) -> _StageRun:
    """Plan a stage (with the run's ``seed``) and sort its tasks into committed (skipped), remembered failures and
    pending."""
    manifest = Manifest(stage_dir(out, stage.name))
    upstream = upstream_view(out, stage, current)
    planned = plan(stage, params, upstream, seed=seed)
    report = StageReport(stage.name, total=len(planned))
    entries = manifest.entries()
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
) -> list[_StageRun]:
    """Run the pending tasks of stages that do not read each other through one pool of workers.

    Tasks go out longest first (:attr:`Task.cost`; stable, so equal costs keep stage and task order), and a
    stage is published and reported as soon as its last task is committed, while the others go on.
    """
    start = time.perf_counter()
    runs = [_start_stage(stage, stage.params(config), out, retry_failed, current, config.run.seed) for stage in wave]
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
        calls = [
            joblib.delayed(execute_task)(
                r.stage, p, r.params, r.upstream.subset(p.task.needs), stage_dir(out, r.stage.name), ctx
            )
            for r, p in work
        ]
        for entry in _finished(calls, min(jobs, len(work))):
            r = owner[entry.key]
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
            notify("task_done", stage=r.stage.name, task=entry.task, ok=entry.status == "ok")
            left[r.stage.name] -= 1
            if left[r.stage.name] == 0:
                _finish_stage(r, out, current, start, notify, warned)
    return runs


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
    own = {e.task: e for e in Manifest(stage_dir(out, stage.name)).entries().values() if e.key in r.keys}
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
        found = entry.meta.get("warnings") if entry.status == "ok" and isinstance(entry.meta, dict) else None
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


# --------------------------------------------------------------------------------------------------------------
# Status


@dataclasses.dataclass
class StageStatus:
    """Where a stage stands against the current config."""

    stage: str
    state: str
    """``done``, ``missing`` (some tasks not committed, or their shards missing or damaged), ``stale`` (committed
    under old keys), ``failed``, ``waiting`` (an input stage has new work first), ``damaged`` (the shards are
    done but output the stage published is missing or damaged: :meth:`Stage.publish_status`)."""
    total: int = 0
    done: int = 0
    failed: int = 0
    missing: int = 0
    reasons: list[str] = dataclasses.field(default_factory=list)




DAMAGED_SHARD = "its shard is missing or damaged"
"""Status reason of a task whose entry is current but whose shard fails the run's check (size and sha256)."""


def status(project: Project, config: Any, targets: Sequence[str] | None = None) -> list[StageStatus]:
    """done / missing / stale / failed / waiting / damaged for each stage, with the reasons: what ``gen run`` with
    the same config would do.

    Shards are checked as the run checks them (size and sha256). A current shard that is missing or damaged is
    remade by the run with the same key, so the stages below it are planned as the run will plan them (not
    ``waiting``). A stage with no new work (and no failed task) is asked what its publish step would repair
    (:meth:`Stage.publish_status`): those lines appear as ``published: ...`` reasons.
    """
    with one_check_per_shard():
        return _status(project, config, targets)


def _status(project: Project, config: Any, targets: Sequence[str] | None) -> list[StageStatus]:
    out = Path(config.run.out)
    result = []
    not_done: set[str] = set()
    current: dict[str, set[str]] = {}
    intact: dict[str, dict[str, Entry]] = {}
    """Per stage, the current shards that pass the check, by task id: what the run and its publish see."""
    redo: dict[str, dict[str, Entry]] = {}
    """Per stage, the current entries whose shard is missing or damaged: remade by the run with the same key."""
    for stage in topological_order(project.stages, targets):
        waiting = [d for d in stage.inputs if d in not_done]
        if waiting:
            result.append(StageStatus(stage.name, "waiting", reasons=[f"needs {', '.join(waiting)} first"]))
            not_done.add(stage.name)
            continue
        manifest = Manifest(stage_dir(out, stage.name))
        entries = manifest.entries()
        by_task: dict[str, Entry] = {}
        for e in entries.values():
            by_task[e.task] = e
        params = stage.params(config)
        after_run = {d: {**intact.get(d, {}), **redo.get(d, {})} for d in stage.inputs}
        planned = plan(stage, params, Upstream(out, after_run), seed=config.run.seed)
        current[stage.name] = {p.key for p in planned}
        st = StageStatus(stage.name, "done", total=len(planned))
        reasons: dict[str, list[str]] = {}
        own_intact: dict[str, Entry] = {}
        own_redo: dict[str, Entry] = {}
        new_work = False
        for p in planned:
            entry = entries.get(p.key)
            if entry is not None and entry.status == "ok":
                ok = shard_ok(manifest, entry)  # size and sha256, as the run checks
                st.done += ok
                (own_intact if ok else own_redo)[p.task.id] = entry
            elif entry is not None and entry.status == "failed":
                st.failed += 1
            else:
                new_work = True
                old = by_task.get(p.task.id)
                for r in (changed_parts(old.parts, p.parts) or ["its key changed"]) if old is not None else []:
                    reasons.setdefault(r, []).append(p.task.id)
        intact[stage.name], redo[stage.name] = own_intact, own_redo
        st.missing = len(planned) - st.done - st.failed
        st.reasons = [f"{len(ids)} task(s): {r}" for r, ids in sorted(reasons.items())]
        if own_redo:
            st.reasons.append(f"{len(own_redo)} task(s): {DAMAGED_SHARD} ({_some(sorted(own_redo))})")
        if new_work:
            st.state = "stale" if reasons else "missing"
            not_done.add(stage.name)
        elif own_redo:
            st.state = "missing"
        elif st.failed:
            st.state = "failed"
        if not new_work and not st.failed:
            view = Upstream(out, {**{d: intact.get(d, {}) for d in stage.inputs}, stage.name: own_intact})
            problems = [f"published: {line}" for line in stage.publish_status(params, view, out)]
            st.reasons += problems
            if problems and st.state == "done":
                st.state = "damaged"
        result.append(st)
    return result


def _some(names: Sequence[str], shown: int = WARNING_TASKS_SHOWN) -> str:
    """``a, b, c`` or ``a, b, c and 4 more``."""
    more = f" and {len(names) - shown} more" if len(names) > shown else ""
    return ", ".join(names[:shown]) + more


def print_error(message: str) -> None:
    print(f"error: {message}", file=sys.stderr)
