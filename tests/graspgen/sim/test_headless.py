"""Headless anywhere: with no libEGL and no libOSMesa, nothing needs OpenGL to start.

Each check runs ``gen`` in a subprocess whose Python cannot load libEGL or libOSMesa: a ``sitecustomize.py`` on
PYTHONPATH (inherited by the run's worker processes) makes ``ctypes.util.find_library`` return None and
``ctypes.CDLL`` raise OSError for those names, which is how PyOpenGL (and so MuJoCo) loads them; MUJOCO_GL and
any display are unset. The first test shows that this really reproduces the original failure (MUJOCO_GL=egl
kills ``import mujoco``), so the others can fail.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.paths import REPO

ROOT = REPO
SMOKE = ROOT / "configs" / "smoke.yaml"

HIDE = '''\
"""Test helper: this Python cannot load libEGL or libOSMesa (as on a machine without them)."""
import ctypes
import ctypes.util

_HIDDEN = ("egl", "osmesa")


def _hidden(name):
    return name is not None and any(h in str(name).lower() for h in _HIDDEN)


_find_library = ctypes.util.find_library


def find_library(name):
    return None if _hidden(name) else _find_library(name)


_cdll_init = ctypes.CDLL.__init__


def __init__(self, name, *args, **kwargs):
    if _hidden(name):
        raise OSError(f"{name}: cannot open shared object file: No such file or directory")
    _cdll_init(self, name, *args, **kwargs)


ctypes.util.find_library = find_library
ctypes.CDLL.__init__ = __init__
'''

_UNSET = ("MUJOCO_GL", "PYOPENGL_PLATFORM", "DISPLAY", "WAYLAND_DISPLAY", "GRASPGEN_MUJOCO_GL_UNUSABLE")


@pytest.fixture(scope="module")
def no_gl(tmp_path_factory) -> dict[str, str]:
    """Environment of a process that cannot load libEGL or libOSMesa, with MUJOCO_GL and any display unset."""
    site = tmp_path_factory.mktemp("no_gl_site")
    (site / "sitecustomize.py").write_text(HIDE)
    env = {k: v for k, v in os.environ.items() if k not in _UNSET}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(site), env.get("PYTHONPATH")]))
    return env


def python(env: dict[str, str], code: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], env=env, cwd=cwd, capture_output=True, text=True, timeout=120)


def gen(env: dict[str, str], cwd: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "graspgen_cli.app", *args],
        env=env,
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=300,
    )


def run_args(out: Path, cache: Path, *sets: str) -> list[str]:
    """`gen run` of the smoke config cut to two objects and two scenes (the physics, the workers and every stage
    still run), so a cold CoACD cache costs seconds."""
    args = ["run", "--config", str(SMOKE), "--out", str(out), "--jobs", "2", "--set", f"run.cache_dir={cache}"]
    for s in ("objects.include=[box,wedge]", "scenes.num_scenes=2", *sets):
        args += ["--set", s]
    return args


@pytest.fixture(scope="module")
def made(no_gl, tmp_path_factory) -> tuple[Path, Path]:
    """The smoke config run without images, headless: (output folder, cache folder)."""
    work = tmp_path_factory.mktemp("headless")
    out, cache = work / "out", work / "cache"
    r = gen(no_gl, work, *run_args(out, cache, "scenes.cameras.render=false"))
    assert r.returncode == 0, r.stdout + r.stderr
    return out, cache


def test_the_hiding_reproduces_the_original_crash(no_gl, tmp_path):
    hidden = python(
        no_gl,
        "import ctypes, ctypes.util\n"
        "assert ctypes.util.find_library('EGL') is None and ctypes.util.find_library('OSMesa') is None\n"
        "for name in ('libEGL.so.1', 'libEGL.so', 'libOSMesa.so.8', 'libOSMesa.so.6'):\n"
        "    try:\n"
        "        ctypes.CDLL(name)\n"
        "    except OSError:\n"
        "        continue\n"
        "    raise SystemExit(name + ' loaded')\n",
        tmp_path,
    )
    assert hidden.returncode == 0, hidden.stderr
    # What every `gen` command did before: MUJOCO_GL=egl, then `import mujoco` dies in PyOpenGL's EGL
    # (AttributeError: 'NoneType' object has no attribute 'eglQueryString').
    crash = python({**no_gl, "MUJOCO_GL": "egl"}, "import mujoco", tmp_path)
    assert crash.returncode != 0
    assert "Traceback" in crash.stderr


def test_the_library_imports_and_says_what_is_missing(no_gl, tmp_path):
    r = python(
        no_gl,
        "import graspgen.sim.scene_model, graspgen.sim.render, graspgen.workflows.scenes, graspgen.viz.rollout_movie\n"
        "from graspgen.sim.gl import render_problem\n"
        "print(render_problem())\n",
        tmp_path,
    )
    assert r.returncode == 0, r.stderr
    assert "libEGL" in r.stdout and "libOSMesa" in r.stdout


def test_an_explicit_mujoco_gl_whose_library_is_missing_does_not_kill_the_import(no_gl, tmp_path):
    r = python(
        {**no_gl, "MUJOCO_GL": "egl"},
        "import graspgen.sim.render\nfrom graspgen.sim.gl import render_problem\nprint(render_problem())\n",
        tmp_path,
    )
    assert r.returncode == 0, r.stderr
    assert "MUJOCO_GL=egl but libEGL cannot be loaded" in r.stdout


def test_help_works_without_opengl(no_gl, tmp_path):
    r = gen(no_gl, tmp_path, "--help")
    assert r.returncode == 0, r.stderr
    assert "run" in r.stdout


def test_run_without_images_then_validate_report_and_evaluate(no_gl, made, tmp_path):
    out, cache = made
    assert (out / "dataset" / "grasps.parquet").is_file()
    for command in ("validate", "report"):
        r = gen(no_gl, tmp_path, command, str(out))
        assert r.returncode == 0, command + ": " + r.stdout + r.stderr
    acronym = out / "dataset" / "acronym"
    r = gen(
        no_gl,
        tmp_path,
        "evaluate",
        "--grasps",
        str(acronym / "box.h5"),
        "--gripper",
        "robotiq_2f85",
        "--mesh-root",
        str(acronym),
        "-o",
        str(tmp_path / "labels.parquet"),
        "--config",
        str(SMOKE),
        "--set",
        f"run.cache_dir={cache}",
    )
    assert r.returncode == 0, r.stdout + r.stderr
    assert (tmp_path / "labels.parquet").is_file()


def test_asking_for_images_fails_in_one_line_naming_the_library_and_the_ways_out(no_gl, made, tmp_path):
    _, cache = made
    r = gen(no_gl, tmp_path, *run_args(tmp_path / "out", cache))
    text = r.stdout + r.stderr
    assert r.returncode in (1, 2), text
    assert "Traceback" not in text
    lines = [line for line in text.splitlines() if "libEGL" in line or "OSMesa" in line]
    assert len(lines) == 1, text
    assert "libOSMesa" in lines[0] and "scenes.cameras.render: false" in lines[0]
    assert "apt install libegl1" in lines[0]
    assert not list((tmp_path / "out").glob("shards/scenes/*/*.h5")), "no scene should have been made"
