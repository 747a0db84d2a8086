"""CoACD in a child process: the same pieces as CoACD run here, and a child that dies fails its call in one line
while the caller lives on."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import threading

import coacd
import numpy as np
import pytest

from graspgen.errors import InputError
from graspgen.geometry.coacd_process import CoacdCrash, run_coacd, run_coacd_each
from tests.paths import TESTS
from tests.shapes import l_shape

KWARGS = {"threshold": 0.05, "max_convex_hull": -1, "merge": False, "preprocess_mode": "off", "resolution": 300,
          "mcts_iterations": 20, "mcts_nodes": 10, "mcts_max_depth": 3, "seed": 0}


def _mesh():
    mesh = l_shape()
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int32)


def test_pieces_are_those_of_coacd_run_here():
    vertices, faces = _mesh()
    coacd.set_log_level("error")
    here = coacd.run_coacd(coacd.Mesh(vertices, faces), **KWARGS)
    there = run_coacd(vertices, faces, **KWARGS)
    assert len(there) == len(here) > 1
    for (v1, f1), (v2, f2) in zip(here, there, strict=True):
        assert np.asarray(v1, dtype=np.float64).tobytes() == v2.tobytes()
        assert np.asarray(f1, dtype=np.int32).tobytes() == f2.tobytes()


def test_a_child_that_dies_fails_that_call_in_one_line_and_the_next_call_works(monkeypatch):
    """Killed while it works: what a segfault in CoACD's native code does to it."""
    vertices, faces = _mesh()
    started: list[subprocess.Popen] = []
    popen = subprocess.Popen

    def watched(*args, **kwargs):
        proc = popen(*args, **kwargs)
        started.append(proc)
        threading.Timer(0.3, os.kill, (proc.pid, signal.SIGKILL)).start()
        return proc

    monkeypatch.setattr(subprocess, "Popen", watched)
    with pytest.raises(CoacdCrash, match=r"^CoACD crashed \(SIGKILL\) while decomposing it$"):
        run_coacd(vertices, faces, **{**KWARGS, "threshold": 0.005, "resolution": 5000})
    assert len(started) == 1
    monkeypatch.undo()
    assert len(run_coacd(vertices, faces, **KWARGS)) > 1


def test_coacd_s_own_error_comes_back_as_an_input_error():
    vertices, faces = _mesh()
    with pytest.raises(InputError, match=r"^CoACD failed on it \("):
        run_coacd(vertices, faces, **{**KWARGS, "threshold": "not a number"})


def test_a_mesh_coacd_1_0_14_segfaults_on_fails_alone():
    """A closed 426-triangle piece of an ACRONYM bowl (cut out of it by a manifold intersection) on which CoACD
    1.0.14 segfaults, every time, with these settings: one failed call, not a dead caller. A CoACD that no longer
    crashes on it passes too, if the pieces come back."""
    with np.load(TESTS / "data" / "coacd_segfault.npz") as data:
        vertices, faces = data["vertices"], data["faces"]
        kwargs = json.loads(data["kwargs"].tobytes().decode())
    try:
        pieces = run_coacd(vertices, faces, **kwargs)
    except CoacdCrash as crash:
        assert str(crash) == "CoACD crashed (SIGSEGV) while decomposing it"
    else:
        assert len(pieces) >= 1
    assert len(run_coacd(*_mesh(), **KWARGS)) > 1


def test_many_meshes_in_one_child_each_failing_alone(monkeypatch):
    """The crasher between good meshes and one CoACD rejects: each answer in its place, the good ones as a call of
    their own gives them, in one child (two if the crasher still crashes)."""
    with np.load(TESTS / "data" / "coacd_segfault.npz") as data:
        crasher = (data["vertices"], data["faces"], json.loads(data["kwargs"].tobytes().decode()))
    good = (*_mesh(), KWARGS)
    children = []
    popen = subprocess.Popen

    def counted(*args, **kwargs):
        children.append(args)
        return popen(*args, **kwargs)

    monkeypatch.setattr(subprocess, "Popen", counted)
    answers = run_coacd_each([good, crasher, (*_mesh(), {**KWARGS, "threshold": "not a number"}), good])
    alone = run_coacd(*_mesh(), **KWARGS)
    assert isinstance(answers[2], InputError) and not isinstance(answers[2], CoacdCrash)
    for answer in (answers[0], answers[3]):
        assert [(v.tobytes(), f.tobytes()) for v, f in answer] == [(v.tobytes(), f.tobytes()) for v, f in alone]
    if isinstance(answers[1], CoacdCrash):
        assert str(answers[1]) == "CoACD crashed (SIGSEGV) while decomposing it"
        assert len(children) == 3  # one until the crash, one for the rest, one for the call alone
    else:
        assert len(answers[1]) >= 1 and len(children) == 2
