"""Tests of stages/show.py and `gen show rollout`: a re-run rollout gives the stored outcome, frames are picked
across the phases, and the PNG strip / GIF hold the expected number of frames."""

from __future__ import annotations

import numpy as np
import pyarrow.parquet as pq
import pytest
from PIL import Image
from typer.testing import CliRunner

from graspgen.io.arrow import column_array
from graspgen.io.objects import read_object
from graspgen.sim.scene_model import object_body_name
from graspgen.viz.rollout_movie import Frame, pick_frames, record_rollout, side_cameras
from graspgen.workflows.rollouts import scene_simulator
from graspgen_cli.app import app, find_shard
from pipeline.config import load_config
from pipeline.scheduler import run_pipeline
from stages.project import PROJECT
from tests.paths import REPO

SMOKE = REPO / "configs" / "smoke.yaml"
runner = CliRunner()


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """One smoke scene rolled out: (config, the --set overrides for the CLI)."""
    root = tmp_path_factory.mktemp("show")
    sets = [f"run.out={root / 'out'}", f"run.cache_dir={root / 'cache'}", "run.jobs=1", "scenes.num_scenes=1"]
    cfg = load_config(PROJECT.schema, SMOKE, sets)
    reports = run_pipeline(PROJECT, cfg, ["rollouts"])
    assert all(r.failed == 0 for r in reports), [r.failures for r in reports]
    return cfg, [a for s in sets for a in ("--set", s)]


def tables(cfg):
    grasps = pq.read_table(find_shard(PROJECT, cfg, "grasps", "scene_000000")[0])
    rollouts = pq.read_table(find_shard(PROJECT, cfg, "rollouts", "scene_000000")[0])
    return grasps, rollouts


def show(sets, *args):
    result = runner.invoke(app, ["show", "rollout", *[str(a) for a in args], "--config", str(SMOKE), *sets])
    return result, " ".join(result.output.split())


def test_rerun_with_the_observer_gives_every_stored_outcome(run):
    cfg, _ = run
    grasps, rollouts = tables(cfg)
    simulated = np.flatnonzero(rollouts.column("simulated").to_numpy(zero_copy_only=False))
    assert len(simulated) > 0
    scene, sim = scene_simulator(find_shard(PROJECT, cfg, "scenes", "scene_000000")[0],
                                 lambda n: read_object(find_shard(PROJECT, cfg, "objects", n)[0]),
                                 grasps.column("gripper")[0].as_py(), cfg.rollouts.lift)
    poses = column_array(grasps, "pose_world", (4, 4))
    for i in simulated:
        index = int(grasps.column("object_index")[int(i)].as_py())
        result, frames = record_rollout(sim.cpu, poses[i], grasps.column("width")[int(i)].as_py(),
                                        object_body_name(index, scene.object_names[index]))
        assert result.code == rollouts.column("outcome")[int(i)].as_py()
        assert result.steps == rollouts.column("steps")[int(i)].as_py()
        assert frames[0].phase == "placement" and frames[0].step == 0 and frames[-1].step == result.steps
        assert [f.step for f in frames] == sorted(f.step for f in frames)


def test_gen_show_rollout_writes_a_png_strip_and_a_gif(run, tmp_path):
    cfg, sets = run
    grasps, rollouts = tables(cfg)
    outcome = rollouts.column("outcome").to_numpy()
    simulated = rollouts.column("simulated").to_numpy(zero_copy_only=False)
    gid = int(rollouts.column("grasp_id")[int(np.flatnonzero(simulated & (outcome == 5))[0])].as_py())
    png = tmp_path / "r.png"
    result, text = show(sets, "scene_000000", gid, "-o", png)
    assert result.exit_code == 0, result.output
    assert result.stdout.strip().endswith("r.png")
    assert "outcome 5 success (stored: 5); 6 frames" in text
    with Image.open(png) as image:
        assert image.text["frames"] == "6" and image.text["outcome"] == "5"
        assert f"grasp {gid}" in image.text["title"] and "success (5)" in image.text["title"]
        assert image.size == (6 * (320 + 4) + 4, 18 + 240 + 14 + 2 * 4)
        # the frames are rendered, not blank: the middle of the strip has many colours
        pixels = np.asarray(image.convert("RGB").crop((4, 22, 4 + 320, 22 + 240))).reshape(-1, 3)
        assert len(np.unique(pixels, axis=0)) > 50
    gif = tmp_path / "r.gif"
    result, text = show(sets, "scene_000000", gid, "-o", gif, "--frames", 4)
    assert result.exit_code == 0, result.output
    with Image.open(gif) as image:
        assert image.n_frames == 4 and image.size == (320, 18 + 240 + 14)


def test_a_prefilter_label_is_named_in_the_title(run, tmp_path):
    cfg, sets = run
    _, rollouts = tables(cfg)
    row = int(np.flatnonzero(~rollouts.column("simulated").to_numpy(zero_copy_only=False))[0])
    gid = rollouts.column("grasp_id")[row].as_py()
    result, text = show(sets, "scene_000000", gid, "-o", tmp_path / "p.png")
    assert result.exit_code == 0, result.output
    with Image.open(tmp_path / "p.png") as image:
        assert "dataset label from the pre-filter: collision_with" in image.text["title"]


def test_show_rollout_errors(run, tmp_path):
    _, sets = run
    result, text = show(sets, "scene_000000", 999, "-o", tmp_path / "x.png")
    assert result.exit_code == 2 and "the scene has no grasp 999 (its grasp ids: 0.." in text
    result, text = show(sets, "scene_000000", 0, "-o", tmp_path / "x.jpg")
    assert result.exit_code == 2 and "unsupported image type '.jpg'; use .png or .gif" in text
    result, text = show(sets, "scene_000042", 0)
    assert result.exit_code == 2 and "no scenes shard for 'scene_000042'" in text


def _frames(phases: list[tuple[str, int]]) -> list[Frame]:
    out, step = [], 0
    for phase, count in phases:
        for _ in range(count):
            out.append(Frame(phase, step, step * 0.002, np.zeros(1)))
            step += 10
    return out


def test_pick_frames_keeps_the_start_and_every_phase_end():
    frames = _frames([("placement", 1), ("approach", 8), ("closing", 5), ("lifting", 25), ("holding", 10)])
    picked = pick_frames(frames, 6)
    assert len(picked) == 6 and picked[0] is frames[0] and picked[-1] is frames[-1]
    ends = [frames[i] for i in (8, 13, 38)]  # last approach, closing, lifting frame
    assert all(any(p is e for p in picked) for e in ends)
    extra = [p for p in picked if p is not frames[0] and p is not frames[-1] and not any(p is e for e in ends)]
    assert len(extra) == 1 and extra[0].phase == "lifting"  # the largest gap in time is in the lift
    assert pick_frames(frames[:3], 6) == frames[:3]  # fewer states than asked: all of them
    few = pick_frames(frames, 3)  # more phase ends than room: first, last, one in between
    assert len(few) == 3 and few[0] is frames[0] and few[-1] is frames[-1]
    with pytest.raises(ValueError, match="n: must be >= 1"):
        pick_frames(frames, 0)


def test_side_cameras_look_along_the_tcp_y_axis_first():
    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, -1, 0], [0, 0, -1]]  # top-down: approach -z, closing +x, so TCP y = -y (world)
    T[:3, 3] = [0.1, 0.2, 0.05]
    cameras = side_cameras(T, 0.2)
    assert len(cameras) == 2  # the approach axis is vertical: no views along it
    for camera, sign in zip(cameras, (-1.0, 1.0)):
        forward = camera.T_world_camera[:3, 2]
        assert forward[1] == pytest.approx(sign * np.cos(np.radians(15)), abs=1e-9)  # along -+y, 15 deg down
        assert forward[2] == pytest.approx(-np.sin(np.radians(15)), abs=1e-9)
        # aimed at the grasp point raised by half the lift
        eye = camera.T_world_camera[:3, 3]
        np.testing.assert_allclose(eye + 0.55 * forward, [0.1, 0.2, 0.15], atol=1e-12)
    side = T.copy()
    side[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]  # approach +y, closing +x: TCP y is vertical
    assert len(side_cameras(side, 0.2)) == 2  # only the two views along the approach axis
