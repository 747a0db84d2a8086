"""Tests of graspgen/viz/grasp_glb.py and `gen show grasps --3d`: the GLB loads back with trimesh and holds the
mesh(es) plus one marker per grasp at the grasp's pose, coloured by its label; the bytes are deterministic."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import trimesh
from typer.testing import CliRunner

from graspgen.grippers import load_gripper
from graspgen.io.arrow import column_array
from graspgen.viz.grasp_glb import FAILURE_COLOUR, SUCCESS_COLOUR, grasps_glb, marker_mesh
from graspgen.viz.grasp_view import LABELS
from graspgen_cli.app import app, find_shard
from pipeline.config import load_config
from pipeline.scheduler import run_pipeline
from stages.project import PROJECT
from tests.paths import REPO

SMOKE = REPO / "configs" / "smoke.yaml"


def load_glb(data: bytes) -> trimesh.Scene:
    scene = trimesh.load(io.BytesIO(data), file_type="glb")
    assert isinstance(scene, trimesh.Scene)
    return scene


def nodes(scene: trimesh.Scene) -> dict[str, tuple[np.ndarray, str]]:
    """Node name -> (world transform, geometry name)."""
    return {n: scene.graph[n] for n in scene.graph.nodes_geometry}


def colour_of(scene: trimesh.Scene, geometry: str) -> tuple[int, ...]:
    colours = np.unique(np.asarray(scene.geometry[geometry].visual.vertex_colors), axis=0)
    assert len(colours) == 1, f"{geometry} has several colours"
    return tuple(int(c) for c in colours[0])


def test_glb_holds_the_mesh_and_one_marker_per_grasp_at_its_pose_in_its_colour(random_poses):
    box = trimesh.creation.box((0.05, 0.07, 0.12))
    T = random_poses(9)
    success = np.array([True, False, False, True, True, False, True, False, False])
    ids = np.arange(9) * 7 + 3
    data = grasps_glb(box.vertices, box.faces, T, success, gripper="panda", grasp_ids=ids, name="box")
    assert data[:4] == b"glTF"
    scene = load_glb(data)
    found = nodes(scene)
    assert set(found) == {"box", *(f"grasp_{i}" for i in ids)}
    pose, geometry = found["box"]
    np.testing.assert_allclose(pose, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(scene.geometry[geometry].vertices, box.vertices, atol=1e-7)  # float32 in the file
    np.testing.assert_array_equal(scene.geometry[geometry].faces, box.faces)
    for i, gid in enumerate(ids):
        pose, geometry = found[f"grasp_{gid}"]
        np.testing.assert_allclose(pose, T[i], atol=1e-6)
        assert colour_of(scene, geometry) == (SUCCESS_COLOUR if success[i] else FAILURE_COLOUR)
    assert SUCCESS_COLOUR[:3] == (40, 200, 60) and FAILURE_COLOUR[:3] == (235, 30, 30)  # green, red
    # markers of one label share one mesh
    assert len(scene.geometry) == 3
    # the same arguments give the same bytes
    assert grasps_glb(box.vertices, box.faces, T, success, gripper="panda", grasp_ids=ids, name="box") == data


def test_marker_is_the_open_fork_from_the_pad_tips_back_to_the_hand_base():
    panda = load_gripper("panda")
    mesh = marker_mesh(panda)
    t = 0.08 / 40  # bar thickness: max_width / 40
    lo, hi = mesh.bounds
    # fingers at the Panda's full 80 mm opening, tips at the pad tips, the stem back to the hand base 0.1034 m
    np.testing.assert_allclose([lo[0], hi[0]], [-0.04 - t, 0.04 + t], atol=1e-12)
    np.testing.assert_allclose([lo[1], hi[1]], [-t / 2, t / 2], atol=1e-12)
    np.testing.assert_allclose([lo[2], hi[2]], [-0.1034, panda.pad_size[2] / 2], atol=1e-12)
    # the opening is free: no marker vertex strictly between the fingers' inner faces at the pad height
    at_pads = np.abs(mesh.vertices[:, 2]) < panda.pad_size[2] / 2 - 1e-9
    assert not np.any(np.abs(mesh.vertices[at_pads, 0]) < 0.04 - 1e-9)
    # fingers as long as the gripper's: beside the opening, vertices only at the tips, a finger length behind them
    # (where the palm bar starts) and the palm bar's back face
    tip = panda.pad_size[2] / 2
    side = np.unique(np.round(mesh.vertices[np.abs(mesh.vertices[:, 0]) > 0.04 - 1e-9, 2], 12))
    np.testing.assert_allclose(side, [tip - 0.0537173 - t, tip - 0.0537173, tip], atol=1e-12)
    robotiq = marker_mesh("robotiq_2f85")
    assert robotiq.bounds[0][2] == pytest.approx(-0.14) and robotiq.bounds[1][0] == pytest.approx(0.0425 + 0.085 / 40)


def test_glb_argument_errors(random_poses):
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    with pytest.raises(ValueError, match="labels: expected 2 labels"):
        grasps_glb(box.vertices, box.faces, random_poses(2), [True])
    with pytest.raises(ValueError, match="success: must be booleans"):
        grasps_glb(box.vertices, box.faces, random_poses(2), [0.5, 1.0])
    with pytest.raises(ValueError, match="grasp_ids: expected 2 distinct ids"):
        grasps_glb(box.vertices, box.faces, random_poses(2), [True, False], grasp_ids=[4, 4])
    with pytest.raises(ValueError, match=r"faces must be \(f, 3\) integer indices into the 8 vertices"):
        grasps_glb(box.vertices, box.faces + 10, random_poses(2), [True, False])
    empty = load_glb(grasps_glb(box.vertices, box.faces, np.zeros((0, 4, 4)), np.zeros(0, dtype=bool)))
    assert set(nodes(empty)) == {"object"}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """One smoke scene rolled out: (config, the --set overrides for the CLI)."""
    root = tmp_path_factory.mktemp("glb")
    sets = [f"run.out={root / 'out'}", f"run.cache_dir={root / 'cache'}", "run.jobs=1", "scenes.num_scenes=1"]
    cfg = load_config(PROJECT.schema, SMOKE, sets)
    reports = run_pipeline(PROJECT, cfg, ["rollouts"])
    assert all(r.failed == 0 for r in reports), [r.failures for r in reports]
    return cfg, [a for s in sets for a in ("--set", s)]


def show(sets, *args):
    result = CliRunner().invoke(app, ["show", "grasps", *[str(a) for a in args], "--config", str(SMOKE), *sets])
    return result, " ".join(result.output.split())


def test_gen_show_grasps_3d_of_a_scene_puts_objects_and_grasps_in_the_world_frame(run, tmp_path):
    cfg, sets = run
    out = tmp_path / "scene.glb"
    result, text = show(sets, "scene_000000", "--3d", "-n", 1000, "-o", out)
    assert result.exit_code == 0, text
    assert result.stdout.strip().endswith("scene.glb") and "note:" not in text
    grasps = pq.read_table(find_shard(PROJECT, cfg, "grasps", "scene_000000")[0])
    rollouts = pq.read_table(find_shard(PROJECT, cfg, "rollouts", "scene_000000")[0])
    from graspgen.io.scenes import read_scene

    scene_record = read_scene(find_shard(PROJECT, cfg, "scenes", "scene_000000")[0])
    scene = load_glb(out.read_bytes())
    found = nodes(scene)
    names = [f"{i}_{n}" for i, n in enumerate(scene_record.object_names)]
    assert set(found) == {"support", *names, *(f"grasp_{g}" for g in grasps.column("grasp_id").to_pylist())}
    for name, pose in zip(names, scene_record.poses):
        np.testing.assert_allclose(found[name][0], pose, atol=1e-6)
    T = column_array(grasps, "pose_world", (4, 4))
    outcome = rollouts.column("outcome").to_numpy()
    assert len(np.unique(outcome)) >= 2, "the check needs markers of several colours"
    for i, gid in enumerate(grasps.column("grasp_id").to_pylist()):
        pose, geometry = found[f"grasp_{gid}"]
        np.testing.assert_allclose(pose, T[i], atol=1e-6)
        assert colour_of(scene, geometry)[:3] == LABELS["rollouts"][int(outcome[i])][1]
    # the default: at most 30 markers, the default path under OUT/show
    result, text = show(sets, "scene_000000", "--3d")
    assert result.exit_code == 0, text
    default = Path(result.stdout.strip())
    assert default == Path(cfg.run.out) / "show" / "scene_000000_grasps.glb"
    assert sum(n.startswith("grasp_") for n in nodes(load_glb(default.read_bytes()))) == min(30, len(grasps))


def test_gen_show_grasps_3d_errors(run, tmp_path):
    _, sets = run
    result, text = show(sets, "scene_000000", "--3d", "-o", tmp_path / "x.png")
    assert result.exit_code == 2 and "x.png: --3d writes a GLB file; use a .glb path" in text
    result, text = show(sets, "nothing_here", "--3d", "-o", tmp_path / "x.glb")
    assert result.exit_code == 2
    assert "'nothing_here' is neither an object with a grasp set" in text
    assert "no scenes shard for 'nothing_here'" in text


def test_gen_show_grasps_3d_of_an_object_draws_its_grasp_set(run, tmp_path):
    """Needs the object_grasps stage (graspgen.workflows.object_grasps); skipped until it is registered."""
    cfg, sets = run
    if "object_grasps" not in {s.name for s in PROJECT.stages}:
        pytest.skip("the object_grasps stage is not registered yet")
    reports = run_pipeline(PROJECT, cfg, ["object_grasps"])
    assert all(r.failed == 0 for r in reports), [r.failures for r in reports]
    name = "box"
    table = pq.read_table(find_shard(PROJECT, cfg, "object_grasps", name)[0])
    out = tmp_path / "box.glb"
    result, text = show(sets, name, "--3d", "-n", 100000, "-o", out)
    assert result.exit_code == 0, text
    scene = load_glb(out.read_bytes())
    found = nodes(scene)
    assert set(found) == {name, *(f"grasp_{g}" for g in table.column("grasp_id").to_pylist())}
    T = column_array(table, "pose_object", (4, 4))
    success = table.column("success").to_numpy(zero_copy_only=False)
    for i, gid in enumerate(table.column("grasp_id").to_pylist()):
        pose, geometry = found[f"grasp_{gid}"]
        np.testing.assert_allclose(pose, T[i], atol=1e-6)
        assert colour_of(scene, geometry) == (SUCCESS_COLOUR if success[i] else FAILURE_COLOUR)
