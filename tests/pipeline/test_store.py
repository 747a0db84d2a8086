"""Atomic writes, the manifest as commit point, the run lock."""

from __future__ import annotations

import multiprocessing
import os
import signal

import pytest

from pipeline.errors import LockError
from pipeline.store import Entry, Manifest, RunLock, atomic_path, remove_stray_temps


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


@pytest.mark.parametrize(("umask", "mode"), [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_atomic_files_honour_the_umask(tmp_path, umask, mode):
    old = os.umask(umask)
    try:
        with atomic_path(tmp_path / "shard.h5") as tmp:
            tmp.write_text("x")
    finally:
        os.umask(old)
    assert (tmp_path / "shard.h5").stat().st_mode & 0o777 == mode


def test_stray_temp_files_of_a_killed_write_are_removed(tmp_path):
    stage = tmp_path / "shards" / "objects" / "ab"
    stage.mkdir(parents=True)
    stray = stage / ".abc.h5.k2j3.tmp"
    stray.write_bytes(b"")  # what a write killed before its os.replace leaves
    keep = [stage / "abc.h5", tmp_path / "notes.tmp"]  # a shard; a user's file that is not ours
    for path in keep:
        path.write_text("x")
    assert remove_stray_temps(tmp_path) == [stray]
    assert not stray.exists() and all(p.exists() for p in keep)
