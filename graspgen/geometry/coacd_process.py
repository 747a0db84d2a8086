"""CoACD in a child process, so that a crash in its native code fails one mesh instead of the process that asked.

CoACD 1.0.14 segfaults on some closed meshes (an out-of-bounds read in ``CDT::Triangulation::insertEdgeIteration``;
single-threaded too, and every time on the same input: ``tests/data/coacd_segfault.npz``). Run in the calling
process, that takes the worker, and with it the run, down, and a rerun stops at the same mesh without naming it.
:func:`run_coacd` runs each call in a new ``python -m graspgen.geometry.coacd_process`` (one OpenMP thread: the run's
workers are its parallelism), which reads the mesh on stdin and writes the pieces on stdout, each an ``.npz``; a
child that dies raises :class:`CoacdCrash` naming how. The child is waited for, so its CPU time counts in the
caller's ``RUSAGE_CHILDREN`` (the engine adds it to the task's). Its start costs about 0.15 CPU s (mostly numpy's
import), once per CoACD call.
"""

from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
from typing import Any

import numpy as np

from graspgen.errors import InputError

__all__ = ["CoacdCrash", "run_coacd"]

_CHILD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


class CoacdCrash(InputError):
    """CoACD's process died while decomposing a mesh (a crash in its native code, or it was killed)."""


def _pack(arrays: dict[str, np.ndarray]) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def _unpack(data: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(data), allow_pickle=False) as npz:
        return {name: npz[name] for name in npz.files}


def _text(array: np.ndarray) -> str:
    return array.tobytes().decode()


def _bytes(text: str) -> np.ndarray:
    return np.frombuffer(text.encode(), dtype=np.uint8)


def run_coacd(vertices: np.ndarray, faces: np.ndarray, **kwargs: Any) -> list[tuple[np.ndarray, np.ndarray]]:
    """``coacd.run_coacd(coacd.Mesh(vertices, faces), **kwargs)`` in a child process.

    Parameters
    ----------
    vertices : (v, 3) float64
    faces : (f, 3) int32
    **kwargs
        ``coacd.run_coacd``'s keyword arguments (JSON-able).

    Returns
    -------
    list of (vertices (n, 3) float64, faces (m, 3) int32), CoACD's pieces.

    Raises
    ------
    CoacdCrash
        The child died (its message says how; the caller adds which mesh).
    InputError
        CoACD raised an error (its text).
    """
    request = _pack({"vertices": np.ascontiguousarray(vertices, dtype=np.float64),
                     "faces": np.ascontiguousarray(faces, dtype=np.int32), "kwargs": _bytes(json.dumps(kwargs))})
    # The child imports this very module: it gets this process's import path, whatever set it up.
    env = {**os.environ, **_CHILD_ENV, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    done = subprocess.run([sys.executable, "-m", "graspgen.geometry.coacd_process"], input=request,
                          stdout=subprocess.PIPE, env=env, check=False)
    if done.returncode != 0 or not done.stdout:
        raise CoacdCrash(_how_it_ended(done.returncode))
    answer = _unpack(done.stdout)
    if "error" in answer:
        raise InputError(f"CoACD failed on it ({_text(answer['error'])})")
    return [(answer[f"vertices_{i}"], answer[f"faces_{i}"]) for i in range(int(answer["count"]))]


def _how_it_ended(code: int) -> str:
    if code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        return f"CoACD crashed ({name}) while decomposing it"
    return f"CoACD's process ended (exit {code}) while decomposing it"


def _serve() -> None:
    """The child: decompose the mesh read from stdin, write the answer to stdout."""
    # The answer gets its own copy of stdout; file descriptor 1 goes to stderr, so that nothing CoACD's native code
    # prints (it logs to stdout) can land in it.
    answer_fd = os.dup(1)
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    import coacd

    coacd.set_log_level("error")
    request = _unpack(sys.stdin.buffer.read())
    kwargs = json.loads(_text(request["kwargs"]))
    try:
        pieces = coacd.run_coacd(coacd.Mesh(request["vertices"], request["faces"]), **kwargs)
    except Exception as exc:  # CoACD's own errors go back to the caller as text
        answer = {"error": _bytes(f"{type(exc).__name__}: {exc}")}
    else:
        answer = {"count": np.array(len(pieces))}
        for i, (v, f) in enumerate(pieces):
            answer[f"vertices_{i}"] = np.asarray(v, dtype=np.float64)
            answer[f"faces_{i}"] = np.asarray(f, dtype=np.int32)
    with os.fdopen(answer_fd, "wb") as out:
        out.write(_pack(answer))


if __name__ == "__main__":
    _serve()
