"""CoACD in a child process, so that a crash in its native code fails one mesh instead of the process that asked.

:func:`run_coacd` runs each call in a ``python -m graspgen.geometry.coacd_process`` child (one OpenMP thread), which
reads meshes on stdin and writes their pieces on stdout, one length-prefixed ``.npz`` request and answer at a time;
a child that dies raises :class:`CoacdCrash` naming how, and the next call starts a new one. The calls within
:func:`shared_process` and those of one :func:`run_coacd_each` share one child. Children are waited for, so their CPU
time counts in ``RUSAGE_CHILDREN``. Why: docs/decisions/2026-12-03-coacd-child-process.md.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import struct
import subprocess
import sys
from collections.abc import Iterator
from typing import Any, BinaryIO

import numpy as np

from graspgen.errors import InputError

__all__ = ["CoacdCrash", "run_coacd", "run_coacd_each", "shared_process"]

_CHILD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

_FRAME = struct.Struct("<Q")
"""The length of each request and answer, before its bytes."""

Pieces = list[tuple[np.ndarray, np.ndarray]]


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


def _write_frame(out: BinaryIO, data: bytes) -> None:
    out.write(_FRAME.pack(len(data)) + data)
    out.flush()


def _read_frame(source: BinaryIO) -> bytes | None:
    """The next frame, or None at the end of the stream (or a frame cut short: the writer died)."""
    head = source.read(_FRAME.size)
    if len(head) < _FRAME.size:
        return None
    (size,) = _FRAME.unpack(head)
    data = source.read(size)
    return data if len(data) == size else None


class _Child:
    """One ``python -m graspgen.geometry.coacd_process``, asked one mesh at a time."""

    def __init__(self) -> None:
        # The child imports this very module: it gets this process's import path, whatever set it up.
        env = {**os.environ, **_CHILD_ENV, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
        self.proc = subprocess.Popen([sys.executable, "-m", "graspgen.geometry.coacd_process"],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)

    def ask(self, vertices: np.ndarray, faces: np.ndarray, kwargs: dict[str, Any]) -> Pieces | InputError:
        """The pieces of one mesh, CoACD's error, or :class:`CoacdCrash` if the child died (it is then reaped)."""
        request = _pack({"vertices": np.ascontiguousarray(vertices, dtype=np.float64),
                         "faces": np.ascontiguousarray(faces, dtype=np.int32), "kwargs": _bytes(json.dumps(kwargs))})
        try:
            _write_frame(self.proc.stdin, request)
            answer = _read_frame(self.proc.stdout)
        except BrokenPipeError:
            answer = None
        if answer is None:
            return CoacdCrash(_how_it_ended(self.close()))
        return _answer(_unpack(answer))

    def close(self) -> int:
        """Ends the child (closing its input ends its loop) and waits for it: its exit code."""
        with contextlib.suppress(BrokenPipeError):
            self.proc.stdin.close()
        code = self.proc.wait()
        self.proc.stdout.close()
        return code


_shared: list[_Child | None] = []
"""The child of each open :func:`shared_process`, innermost last (None until its first call)."""


@contextlib.contextmanager
def shared_process() -> Iterator[None]:
    """Within it, every CoACD call shares one child process (started at the first call, and again after a crash;
    ended and waited for on leaving)."""
    _shared.append(None)
    try:
        yield
    finally:
        child = _shared.pop()
        if child is not None:
            child.close()


def run_coacd(vertices: np.ndarray, faces: np.ndarray, **kwargs: Any) -> Pieces:
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
    (answer,) = run_coacd_each([(vertices, faces, kwargs)])
    if isinstance(answer, InputError):
        raise answer
    return answer


def run_coacd_each(requests: list[tuple[np.ndarray, np.ndarray, dict[str, Any]]]) -> list[Pieces | InputError]:
    """:func:`run_coacd` of each ``(vertices (v, 3) float64, faces (f, 3) int32, kwargs)`` of ``requests``, in one
    child process (the :func:`shared_process`'s if one is open), and a new one after each crash.

    Returns
    -------
    list
        Per request, in order: its pieces as :func:`run_coacd` returns them, or the error it would raise
        (:class:`CoacdCrash` or :class:`InputError`, not raised: the others' pieces stand).
    """
    with contextlib.ExitStack() as stack:
        if not _shared:
            stack.enter_context(shared_process())
        answers = []
        for vertices, faces, kwargs in requests:
            if _shared[-1] is None:
                _shared[-1] = _Child()
            answers.append(_shared[-1].ask(vertices, faces, kwargs))
            if isinstance(answers[-1], CoacdCrash):  # reaped: the next request gets a new child
                _shared[-1] = None
        return answers


def _answer(answer: dict[str, np.ndarray]) -> Pieces | InputError:
    if "error" in answer:
        return InputError(f"CoACD failed on it ({_text(answer['error'])})")
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
    """The child: decompose each mesh read from stdin, writing each answer to stdout before reading the next."""
    # The answers get their own copy of stdout; file descriptor 1 goes to stderr, so that nothing CoACD's native code
    # prints (it logs to stdout) can land in them.
    answer_fd = os.dup(1)
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    import coacd

    coacd.set_log_level("error")
    with os.fdopen(answer_fd, "wb") as out:
        while (data := _read_frame(sys.stdin.buffer)) is not None:
            request = _unpack(data)
            try:
                mesh = coacd.Mesh(request["vertices"], request["faces"])
                pieces = coacd.run_coacd(mesh, **json.loads(_text(request["kwargs"])))
            except Exception as exc:  # CoACD's own errors go back to the caller as text
                answer = {"error": _bytes(f"{type(exc).__name__}: {exc}")}
            else:
                answer = {"count": np.array(len(pieces))}
                for j, (v, f) in enumerate(pieces):
                    answer[f"vertices_{j}"] = np.asarray(v, dtype=np.float64)
                    answer[f"faces_{j}"] = np.asarray(f, dtype=np.int32)
            _write_frame(out, _pack(answer))


if __name__ == "__main__":
    _serve()
