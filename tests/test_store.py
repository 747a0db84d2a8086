"""Atomic writes, the manifest as commit point, the run lock."""

from __future__ import annotations

import multiprocessing
import os
import signal

import pytest

from pipeline.errors import LockError
from pipeline.store import Entry, Manifest, RunLock, atomic_path


def test_atomic_path_leaves_nothing_on_error(tmp_path):
    final = tmp_path / "x" / "shard.h5"
    with pytest.raises(RuntimeError):
        with atomic_path(final) as tmp:
            tmp.write_text("partial")
            raise RuntimeError("task died")
    assert not final.exists()
    assert list(final.parent.iterdir()) == []
    with atomic_path(final) as tmp:
        assert tmp.parent == final.parent
        tmp.write_text("done")
    assert final.read_text() == "done"


def test_manifest_later_line_wins_and_cut_lines_are_ignored(tmp_path):
    m = Manifest(tmp_path)
    m.append(Entry(key="k1", task="a", status="failed", error="boom"))
    m.append(Entry(key="k1", task="a", status="ok", file="k1.h5", sha256="00", bytes=3))
    with open(m.path, "a") as f:
        f.write('{"key": "k2", "task": "b", "sta')
    entries = m.entries()
    assert list(entries) == ["k1"] and entries["k1"].status == "ok"


def _hold_lock(path, ready):
    lock = RunLock(path)
    lock.__enter__()
    ready.set()
    signal.pause()


def test_lock_is_released_when_its_holder_is_killed(tmp_path):
    ctx = multiprocessing.get_context("fork")
    ready = ctx.Event()
    proc = ctx.Process(target=_hold_lock, args=(tmp_path, ready))
    proc.start()
    assert ready.wait(10)
    with pytest.raises(LockError, match=f"pid {proc.pid}"):
        with RunLock(tmp_path):
            pass
    os.kill(proc.pid, signal.SIGKILL)
    proc.join()
    with RunLock(tmp_path):
        pass
