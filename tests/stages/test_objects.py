"""The objects stage through the real `gen` CLI and the engine: discovery, broken inputs, shard contents."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from graspgen.io.objects import read_object
from graspgen.workflows.scene_grasps import GraspsParams
from pipeline.config import load_config
from pipeline.errors import ConfigError
from pipeline.plan import committed
from pipeline.scheduler import run_pipeline
from pipeline.store import stage_dir
from stages.objects import ObjectsParams, ObjectsStage, catalog, discover, left_out_by_include, object_warnings
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


# ---------------------------------------------------------------------------------------------------------------
# Warnings: unit guesses, repairs, meshes left out by objects.include, objects the gripper cannot grasp.


def test_object_warnings_name_the_file_and_skip_merges():
    path = Path("somewhere/mug.obj")
    assert object_warnings(path, ["mug.obj: largest extent 95.0 units, assumed millimetres"], []) == [
        "mug.obj: largest extent 95.0 units, assumed millimetres"
    ]
    notes = ["merged 12 duplicate vertices", "removed 2 zero-area faces", "fixed face winding / orientation",
             "mesh is not watertight after repair"]
    assert object_warnings(path, [], notes) == [
        "mug.obj: mesh repaired: removed 2 zero-area faces; fixed face winding / orientation"
    ]
    assert object_warnings(path, [], ["merged 12 duplicate vertices"]) == []  # an STL's shared corners: no repair


def test_include_leaving_out_meshes_of_paths_is_a_warning(tmp_path):
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    for name in ("keep", "drop1", "drop2"):
        write_obj(tmp_path / f"{name}.obj", box.vertices, box.faces)
    params = ObjectsParams(bundled=True, paths=(str(tmp_path / "*.obj"),), include=("keep", "box"))
    assert left_out_by_include(params) == [tmp_path / "drop1.obj", tmp_path / "drop2.obj"]
    (warning,) = ObjectsStage().plan_warnings(params, None)
    assert warning.startswith("objects.include leaves out 2 mesh(es) that objects.paths matches: ")
    assert f"{tmp_path / 'drop1.obj'}, {tmp_path / 'drop2.obj'}" in warning
    assert left_out_by_include(ObjectsParams(include=("box",))) == []  # bundled ones left out: what include is for
    assert left_out_by_include(ObjectsParams(bundled=False, paths=params.paths)) == []


def test_run_prints_the_warnings_and_the_card_lists_them(tmp_path):
    d = tmp_path / "meshes"
    d.mkdir()
    mm = trimesh.creation.cylinder(radius=20.0, height=90.0, sections=24)  # millimetres
    write_obj(d / "mm_cylinder.obj", mm.vertices, mm.faces)
    box = trimesh.creation.box((0.04, 0.05, 0.06))
    write_obj(d / "inside_out_box.obj", box.vertices, box.faces[:, ::-1])  # every face wound the wrong way
    big = trimesh.creation.box((0.2, 0.2, 0.2))  # wider than the 2F-85 opens, every way
    write_obj(d / "big_box.obj", big.vertices, big.faces)
    write_obj(d / "extra.obj", box.vertices, box.faces)
    cfg = tmp_path / "w.yaml"
    cfg.write_text(
        "objects:\n  bundled: false\n  paths: ['meshes/*.obj']\n  include: [big_box, inside_out_box, mm_cylinder]\n"
        "  stable_poses: {max_poses: 2, settle_time: 0.5}\n"
        "scenes:\n  num_scenes: 1\n  choice: fixed\n  objects: [big_box, mm_cylinder, inside_out_box]\n"
        "  cameras: {num_views: 1, width: 160, height: 120}\n"
        "grasps:\n  max_per_object: 8\n  sampler: {num_surface_points: 64}\n"
        "robustness:\n  num_perturbations: 3\n"
        "object_grasps:\n  target_grasps: 6\n  max_candidates: 200\n  batch_size: 16\n"
        "  sampler: {num_surface_points: 64}\n"
    )
    args = ["run", "--config", cfg, "--out", tmp_path / "out", "--jobs", 2,
            "--set", f"run.cache_dir={tmp_path / 'cache'}", *[a for s in CHEAP for a in ("--set", s)]]
    result = gen(*args, cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    expected = [
        "objects: objects.include leaves out 1 mesh(es) that objects.paths matches: meshes/extra.obj (add their "
        "names to objects.include to use them)",
        "objects: inside_out_box: inside_out_box.obj: mesh repaired: fixed face winding / orientation",
        "objects: mm_cylinder: mm_cylinder.obj: largest extent 90.0 units, assumed millimetres, scaled by 0.001",
        "object_grasps: big_box: object 'big_box': 0 of 6 collision-free grasps after 0 candidates: the "
        "sampler found no more antipodal pairs the gripper opens around (object_grasps.sampler, object_grasps.gripper)",
        f"grasps: scene_000000: gripper {GraspsParams().gripper} cannot grasp object 'big_box': it is 200 mm across "
        "at its "
        "narrowest, the gripper closes on at most 75 mm (85 mm stroke less grasps.sampler.min_clearance), and no "
        "thin part of it (rim, handle) gave a candidate that passes the pre-filter",
    ]
    lines = result.stderr.splitlines()
    start = lines.index("5 warning(s):")
    assert [line.strip() for line in lines[start + 1:start + 6]] == expected  # one a line: not wrapped
    card = json.loads((tmp_path / "out" / "dataset" / "card.json").read_text())
    assert sorted(card["warnings"]) == sorted(expected)  # the card lists them by the dataset stage's inputs
    assert "## Warnings" in (tmp_path / "out" / "dataset" / "card.md").read_text()
    again = gen(*args, cwd=tmp_path)  # nothing runs, the warnings are still told
    assert again.returncode == 0 and "Nothing to do" in again.stderr and "5 warning(s):" in again.stderr
