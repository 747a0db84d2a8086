"""Where a run's tasks execute: joblib's backend for local processes (loky), a dask.distributed cluster, or ray.

:func:`parallel_backend` sets the backend for the duration of a run; the optional packages (dask, ray) are
imported only when the config asks for them, and a missing one is a one-line :class:`~pipeline.errors.ConfigError`.
"""

from __future__ import annotations

import contextlib
import os
import re
import warnings
from collections.abc import Iterator
from typing import Any

import joblib

from pipeline.config import RunConfig
from pipeline.errors import ConfigError, GenError

BACKENDS = ("loky", "dask", "ray")


def resolve_jobs(jobs: int) -> int:
    """0 -> number of usable cores."""
    if jobs > 0:
        return jobs
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def lost_worker(exc: BaseException, stages: list[str], unfinished: int) -> GenError | None:
    """The one-line error for ``exc`` when it says one of the run's own worker processes died (loky's
    ``TerminatedWorkerError``: a crash in native code, the out-of-memory killer, a ``kill -9``) while ``stages``
    had ``unfinished`` tasks; None for any other exception."""
    from joblib.externals.loky.process_executor import TerminatedWorkerError

    if not isinstance(exc, TerminatedWorkerError):
        return None
    found = re.search(r"exit codes of the workers are \{([^}]*)\}", str(exc))
    how = f" (exit {found.group(1)})" if found else ""
    return GenError(
        f"{', '.join(stages)}: a worker process died{how} while running one of {unfinished} unfinished tasks: a "
        "crash in native code or the out-of-memory killer. Finished tasks are kept; run the same command again to "
        "resume"
    )


DASK_CONNECT_TIMEOUT = 10
"""Seconds to wait for ``run.dask_address`` to answer before giving up with a one-line error."""


@contextlib.contextmanager
def parallel_backend(run: RunConfig, jobs: int) -> Iterator[None]:
    """Set joblib's backend for the run: local processes (loky), a dask.distributed cluster, or ray."""
    if run.backend == "loky":
        with warnings.catch_warnings(), joblib.parallel_config(backend="loky"):
            # loky replaces a worker whose memory grew by 300 MB since its first task (its guard against leaks;
            # a stage that imports torch or holds a large scene does it) and says so with this warning, though no
            # task is lost. A worker that crashes raises TerminatedWorkerError instead.
            warnings.filterwarnings("ignore", "A worker stopped while some jobs were given", UserWarning)
            yield
        return
    if run.backend == "dask":
        with _dask_backend(run, jobs):
            yield
        return
    if run.backend == "ray":
        with _ray_backend(jobs):
            yield
        return
    raise ConfigError(f"run.backend: must be one of {', '.join(BACKENDS)}, got {run.backend!r}")


@contextlib.contextmanager
def _dask_backend(run: RunConfig, jobs: int) -> Iterator[None]:
    """joblib on dask: the cluster at ``run.dask_address``, else a local cluster of ``jobs`` one-thread workers."""
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

    try:
        with joblib.parallel_config(backend=_failing_dask_backend(client)):
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


def _gave_up(exc: BaseException, calls: Any) -> GenError:
    """One line for a batch dask gave up on, naming its tasks when they are ``execute_task`` calls."""
    from distributed import KilledWorker

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


SENT_ONCE_BYTES = 1000
"""An argument dask's ``sizeof`` puts above this is sent to a cluster once per run, not pickled into each task
(joblib's own limit for its scatter)."""


def _held(value: Any) -> Any:
    """The task whose result is an argument sent once (:func:`_failing_dask_backend`)."""
    return value


class _FailedBatch:
    """What the completion callback gets for a batch whose dask future failed."""

    def __init__(self, error: GenError):
        self.error = error


def _failing_dask_backend(client: Any) -> Any:
    """joblib's dask backend on ``client``, except that a batch dask gives up on fails the joblib call, and large
    arguments go to the cluster once.

    A worker that dies is survived by dask itself (its tasks run again elsewhere); but a task whose workers die
    ``distributed.scheduler.allowed-failures`` + 1 times (4 by default: it crashes them, or runs them out of memory)
    gets a ``KilledWorker`` error, which joblib's backend sets on the batch's future and never reports to its
    completion callback: the call, waiting on the callbacks, would wait forever. And a large argument (a stage's
    upstream view) is sent once per run as a task's result, which a worker's death cannot lose
    (``Backend._send_once``). The class is made here because its base needs dask, an optional package.
    """
    from dask.sizeof import sizeof
    from joblib._dask import DaskDistributedBackend

    class Backend(DaskDistributedBackend):
        def submit(self, func: Any, callback: Any = None) -> Any:
            self._send_once(func)
            future = super().submit(func, callback)

            def done(f: Any) -> None:
                if callback is not None and not f.cancelled() and f.exception() is not None:
                    callback(_FailedBatch(_gave_up(f.exception(), func)))

            future.add_done_callback(done)
            return future

        def _send_once(self, func: Any) -> None:
            """Send each large argument of ``func``'s calls (over :data:`SENT_ONCE_BYTES` by dask's ``sizeof``: a
            stage's upstream view) to the cluster once per run, as the result of a task that holds it; joblib's
            calls then refer to that future (its ``data_futures``). joblib alone would ``scatter`` it, and a
            worker that died holding the only copy would take it with it: the scheduler forgets scattered data it
            cannot recompute, and every task waiting on it with it. A task's result is made again instead."""
            for _, args, kwargs in func.items:
                for arg in (*args, *kwargs.values()):
                    if id(arg) in self.data_futures or sizeof(arg) <= SENT_ONCE_BYTES:
                        continue
                    self._scatter.append(arg)  # holds it, so that its id names it while the future is in use
                    self.data_futures[id(arg)] = self.client.submit(_held, arg, pure=False)

        def retrieve_result_callback(self, out: Any) -> Any:
            if isinstance(out, _FailedBatch):
                raise out.error
            return super().retrieve_result_callback(out)

    return Backend(client=client)


@contextlib.contextmanager
def _ray_backend(jobs: int) -> Iterator[None]:
    """joblib on ray: the ray instance already started in this process, else a local one with ``jobs`` CPUs."""
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
