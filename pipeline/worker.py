"""Executing one task, in a worker process: run the stage, write its shard atomically, return its entry.

A task never raises here: an error becomes a ``failed`` entry (one line for a user error, the end of the
traceback for a bug), and a full disk an ``aborted`` one that the scheduler never commits. Between tasks the
worker gives freed memory back to the OS (:func:`return_freed_memory`).
"""

from __future__ import annotations

import collections
import ctypes
import dataclasses
import errno
import gc
import multiprocessing
import os
import pickle
import resource
import signal
import threading
import time
import traceback
import uuid
from pathlib import Path
from typing import Any

from pipeline.errors import GenError
from pipeline.keys import rng_for_key, sha256_file
from pipeline.plan import PlannedTask
from pipeline.stage import RunContext, Stage, Upstream
from pipeline.store import Entry, atomic_path, shard_path

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
"""Bytes of resident growth since a worker's last garbage collection after which it collects again."""

_collect_above: int | None = None
"""Resident size over which this worker collects garbage after a task: :data:`GC_MARGIN` above its size right
after its last collection; None before its first task."""


def resident_bytes() -> int | None:
    """This process's resident set size in bytes (Linux ``/proc``), or None where it cannot be read cheaply."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return None


def return_freed_memory() -> bool:
    """Give the heap pages freed since back to the OS, and collect garbage when the worker has grown more than
    :data:`GC_MARGIN` since its last collection (and after its first task); False where the C library cannot trim.

    Why: glibc keeps freed blocks, so a worker's resident size stays at its tasks' highest peak, which loky reads
    as a leak and answers by restarting the worker (docs/decisions/2026-11-29-worker-memory.md)."""
    global _collect_above
    trimmed = _trim_heap()
    rss = resident_bytes()
    if rss is None or _collect_above is None or rss > _collect_above:
        gc.collect()
        trimmed = _trim_heap()
        rss = resident_bytes()
        _collect_above = None if rss is None else rss + GC_MARGIN
    return trimmed


def _trim_heap() -> bool:
    if _MALLOC_TRIM is None:
        return False
    _MALLOC_TRIM(0)
    return True


VIEWS_KEPT = 8
"""Upstream views a worker keeps unpickled (:class:`SharedView`): at least the stages of one wave."""

_views: collections.OrderedDict[str, dict[str, dict[str, Entry]]] = collections.OrderedDict()
"""This process's unpickled views, by token, most recent last."""


class SharedView:
    """A stage's upstream view as its tasks are shipped it: pickled once by the scheduler, unpickled once per worker.

    Why: a scene's task reads its scene and the whole object library, so a view pickled per task costs ``scenes x
    objects`` entries per stage, quadratic in N (docs/decisions/2026-12-03-engine-at-scale.md). Each task carries
    the view's pickled bytes (a copy, not a walk) and its ``needs``; a worker unpickles a view the first time it
    sees its token and builds each task's view from that.
    """

    def __init__(self, out: Path, entries: dict[str, dict[str, Entry]]):
        self.out = Path(out)
        self.token = uuid.uuid4().hex
        self.data = pickle.dumps(entries, protocol=pickle.HIGHEST_PROTOCOL)

    def task_view(self, needs: Any) -> TaskView:
        """What one task is shipped: this view and the upstream shards the task reads (``Task.needs``)."""
        return TaskView(self.out, self.token, self.data, needs)


@dataclasses.dataclass(frozen=True)
class TaskView:
    """One task's share of a :class:`SharedView`, turned into its :class:`~pipeline.stage.Upstream` in the worker
    (:meth:`upstream`)."""

    out: Path
    token: str
    data: bytes
    needs: Any

    def upstream(self) -> Upstream:
        """The task's view: ``Upstream.subset(needs)`` of the shared view, unpickled once per process."""
        entries = _views.get(self.token)
        if entries is None:
            entries = _views[self.token] = pickle.loads(self.data)
            while len(_views) > VIEWS_KEPT:
                _views.popitem(last=False)
        else:
            _views.move_to_end(self.token)
        return Upstream(self.out, entries).subset(self.needs)


def execute_task(
    stage: Stage, planned: PlannedTask, params: Any, upstream: Upstream | TaskView, stage_dir: Path, ctx: RunContext
) -> Entry:
    """Run one task and write its shard; never raises (a failure becomes a ``failed`` entry). ``upstream`` is a
    :class:`TaskView` or an :class:`~pipeline.stage.Upstream` (a stage's whole view, from a cluster), made into the
    task's view (``Upstream.subset(task.needs)``) here."""
    in_worker = multiprocessing.parent_process() is not None
    if in_worker and threading.current_thread() is threading.main_thread():
        # Ctrl-C reaches the whole process group: the parent reports it once and stops; workers stay quiet.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        return _execute_task(stage, planned, params, upstream, stage_dir, ctx)
    finally:
        if in_worker:
            return_freed_memory()


def task_cpu_seconds() -> float:
    """CPU seconds of this process and of the child processes it has waited for (a stage may run native code in a
    child, as the objects stage does CoACD, so that a crash there fails one task): a task's CPU is the difference."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def _execute_task(
    stage: Stage, planned: PlannedTask, params: Any, upstream: Upstream | TaskView, stage_dir: Path, ctx: RunContext
) -> Entry:
    start, cpu_start = time.perf_counter(), task_cpu_seconds()
    task, key = planned.task, planned.key
    final = shard_path(stage_dir, key, stage.ext)
    try:
        # A cluster ships the stage's whole view: what the task reads is cut here (idempotent on a cut view).
        upstream = upstream.upstream() if isinstance(upstream, TaskView) else upstream.subset(task.needs)
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
            cpu_seconds=round(task_cpu_seconds() - cpu_start, 4),
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
    return isinstance(exc, (GenError, *stage.user_errors))
