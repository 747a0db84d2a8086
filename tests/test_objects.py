"""The objects stage through the real `gen` CLI and the engine: discovery, broken inputs, shard contents."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from graspgen.io.objects import read_object
from pipeline.config import load_config
from pipeline.errors import ConfigError
from pipeline.scheduler import committed, run_pipeline
from pipeline.store import stage_dir
from stages.objects import ObjectsParams, catalog, discover
from stages.project import PROJECT

CHEAP = [
    "objects.coacd.threshold=0.2",
    "objects.coacd.resolution=300",
    "objects.coacd.mcts_iterations=10",
    "objects.coacd.preprocess_resolution=20",
]


def gen(*args, cwd=None):
    """Run the installed console script as a user would."""
    exe = Path(sys.executable).with_name("gen")
    env = {**os.environ, "COLUMNS": "200"}
    return subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True, cwd=cwd, env=env, timeout=300)


def write_obj(path: Path, vertices, faces) -> None:
    lines = [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in vertices] + [
        f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces
    ]
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture
def broken_folder(tmp_path):
    """Good and broken meshes side by side."""
    d = tmp_path / "meshes"
    d.mkdir()
    box = trimesh.creation.box((0.04, 0.05, 0.06))
    write_obj(d / "good_box.obj", box.vertices, box.faces)
    mm = trimesh.creation.cylinder(radius=20.0, height=90.0, sections=24)  # millimetres
    write_obj(d / "good_mm_cylinder.obj", mm.vertices, mm.faces)
    (d / "empty.obj").write_text("")
    (d / "garbage.stl").write_bytes(bytes(range(256)) * 8)
    nan = box.vertices.copy()
    nan[3, 1] = np.nan
    write_obj(d / "nan_vertices.obj", nan, box.faces)
    write_obj(d / "one_triangle.obj", [[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0]], [[0, 1, 2]])
    tall = trimesh.creation.box((100.0, 100.0, 1000.0))
    write_obj(d / "tall_1000_units.obj", tall.vertices, tall.faces)
    return d


def test_broken_files_are_named_and_the_good_ones_processed(broken_folder, tmp_path):
    out = tmp_path / "out"
    result = gen(
        "run",
        "objects",
        "--out",
        out,
        "--jobs",
        2,
        "--set",
        "objects.bundled=false",
        "--set",
        f"objects.paths=['{broken_folder}/*']",
        "--set",
        f"run.cache_dir={tmp_path / 'cache'}",
        *[a for s in CHEAP for a in ("--set", s)],
    )
    assert result.returncode == 1, result.stdout + result.stderr
    text = " ".join(result.stderr.split())  # rich wraps long lines
    assert "5 task(s) failed" in text
    for name, reason in [
        ("empty", "empty.obj"),
        ("garbage", "garbage.stl"),
        ("nan_vertices", "NaN"),
        ("one_triangle", "flat mesh with zero volume"),
        ("tall_1000_units", "absurd size"),
    ]:
        line = next((ln for ln in result.stderr.splitlines() if f"objects/{name}:" in ln), None)
        assert line is not None, f"{name} not reported:\n{result.stderr}"
        assert reason in " ".join(result.stderr.split()), f"{name}: no '{reason}' in the report"
        assert f"objects/{name}: InputError: {broken_folder}/{name}." in text, f"{name}: path not in the report"
    done = {e.task for e in committed(out, "objects").values()}
    assert done == {"good_box", "good_mm_cylinder"}
    cyl = read_object(_shard(out, "good_mm_cylinder"))
    assert cyl.attrs["scale"] == pytest.approx(0.001)
    assert any("millimetres" in w for w in cyl.attrs["warnings"])
    assert np.ptp(cyl.vertices[:, 2]) == pytest.approx(0.09, rel=1e-6)


def _shard(out: Path, name: str) -> Path:
    (entry,) = [e for e in committed(out, "objects").values() if e.task == name]
    return stage_dir(out, "objects") / entry.file


def test_config_typo_fails_fast_naming_the_key(tmp_path):
    cfg = tmp_path / "typo.yaml"
    cfg.write_text("objects:\n  pahts: ['*.obj']\n")
    result = gen("run", "--config", cfg, "--out", tmp_path / "o")
    assert result.returncode == 2
    assert "objects.pahts: unknown key; valid keys: bundled, coacd, densities, density, include" in " ".join(
        result.stderr.split()
    )
    assert not (tmp_path / "o").exists()


def test_discover_errors_name_the_key(tmp_path):
    with pytest.raises(ConfigError, match=r"objects.include: no object named 'teapot'; available: bottle, bowl"):
        discover(ObjectsParams(include=("teapot",)))
    with pytest.raises(ConfigError, match=r"objects.paths\[0\]: '.*nothing/\*.obj' matches no mesh file"):
        discover(ObjectsParams(bundled=False, paths=(str(tmp_path / "nothing/*.obj"),)))
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    write_obj(tmp_path / "a" / "box.obj", box.vertices, box.faces)
    write_obj(tmp_path / "b" / "box.obj", box.vertices, box.faces)
    with pytest.raises(ConfigError, match="two meshes are both named 'box'"):
        discover(ObjectsParams(bundled=False, paths=(str(tmp_path / "*/box.obj"),)))
    with pytest.raises(ConfigError, match="objects.density: must be > 0"):
        load_config(PROJECT.schema, None, ["objects.density=0"])


def test_bundled_box_shard_matches_its_geometry(tmp_path):
    cfg = load_config(
        PROJECT.schema,
        None,
        [
            f"run.out={tmp_path / 'o'}",
            f"run.cache_dir={tmp_path / 'c'}",
            "run.jobs=1",
            "objects.include=[box, l_bracket]",
            *CHEAP,
        ],
    )
    (report,) = run_pipeline(PROJECT, cfg, ["objects"])
    assert (report.ran, report.failed) == (2, 0)
    box = read_object(_shard(tmp_path / "o", "box"))
    density = catalog()["box"]["density"]
    mesh = trimesh.Trimesh(box.vertices, box.faces)
    assert mesh.is_watertight
    assert box.mass == pytest.approx(density * 0.05 * 0.07 * 0.12, rel=1e-9)
    a, b, c = 0.05, 0.07, 0.12
    np.testing.assert_allclose(
        np.diag(box.inertia), box.mass / 12 * np.array([b * b + c * c, a * a + c * c, a * a + b * b]), rtol=1e-9
    )
    assert len(box.convex_parts) == 1
    assert box.stable_probabilities.sum() == pytest.approx(1.0)
    # the most probable pose rests on one of the two largest faces (0.07 x 0.12): the 0.05 side is vertical
    lowest = trimesh.transform_points(box.vertices, box.stable_poses[0])
    assert lowest[:, 2].min() == pytest.approx(0.0, abs=1e-9)
    assert np.ptp(lowest[:, 2]) == pytest.approx(0.05, abs=1e-9)
    bracket = read_object(_shard(tmp_path / "o", "l_bracket"))
    assert len(bracket.convex_parts) >= 2  # an L is not convex
    hull_volume = sum(trimesh.Trimesh(v, f).volume for v, f in bracket.convex_parts)
    assert hull_volume == pytest.approx(bracket.attrs["volume"], rel=0.15)
    assert bracket.attrs["source_sha256"] and bracket.attrs["params"]["coacd"]["threshold"] == 0.2
