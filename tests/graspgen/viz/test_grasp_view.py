"""Tests of stages/grasp_view.py and ``gen show grasps``: marker geometry, projection, labels, choice, the PNG."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from PIL import Image
from typer.testing import CliRunner

from graspgen.grippers import load_gripper
from graspgen.io.arrow import fixed_list
from graspgen.sim.camera import Camera
from graspgen.viz import grasp_view as V
from graspgen_cli.app import app, find_shard
from pipeline.cli import load
from stages.project import PROJECT
from tests.paths import REPO

ROOT = REPO
GRIPPER = load_gripper("box_jaw")  # pad length 0.04 m: round numbers below
W, H, F, CX, CY = 160, 120, 100.0, 80.0, 60.0


def _down_camera(height: float = 1.0) -> Camera:
    """A camera at (0, 0, height) looking straight down: image right = world +x, image down = world -y."""
    T = np.eye(4)
    T[:3, :3] = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]  # columns: x, y, z of the camera
    T[:3, 3] = (0.0, 0.0, height)
    return Camera(np.array([[F, 0.0, CX], [0.0, F, CY], [0.0, 0.0, 1.0]]), T, W, H)


def _top_down_grasp(x: float = 0.0, y: float = 0.0, z: float = 0.52) -> np.ndarray:
    """TCP pose approaching straight down (z = -world z), closing along world x."""
    T = np.eye(4)
    T[:3, :3] = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]  # x = +x, y = z cross x = -y, z = -z
    T[:3, 3] = (x, y, z)
    return T


def _pixel(p_world) -> tuple[float, float]:
    """Expected (u, v) of a world point under _down_camera(1.0)."""
    depth = 1.0 - p_world[2]
    return CX + F * p_world[0] / depth, CY - F * p_world[1] / depth


# ---------------------------------------------------------------------------------------------------------------
# Geometry and projection
# ---------------------------------------------------------------------------------------------------------------


def test_marker_segments_of_a_known_pose():
    T = _top_down_grasp(0.1, 0.2, 0.52)
    seg = V.grasp_marker_segments(T[None], np.array([0.1]), GRIPPER)
    assert seg.shape == (1, V.MARKER_SEGMENTS, 2, 3)
    # Finger tips 0.02 m ahead of the TCP along the approach (world -z), backs 0.02 m behind; x = -+0.05.
    expected = np.array([
        [[0.05, 0.2, 0.50], [0.05, 0.2, 0.54]],  # left finger (TCP -x side; TCP x = world x): tip, back
        [[0.15, 0.2, 0.50], [0.15, 0.2, 0.54]],  # right finger
        [[0.05, 0.2, 0.54], [0.15, 0.2, 0.54]],  # palm bar
        [[0.10, 0.2, 0.54], [0.10, 0.2, 0.58]],  # stem, one pad length back
    ])
    np.testing.assert_allclose(seg[0], expected, atol=1e-15)
    # A rotated pose rotates the local marker: closing along world y now.
    R = np.eye(4)
    R[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    seg_r = V.grasp_marker_segments((R @ T)[None], np.array([0.1]), GRIPPER)
    np.testing.assert_allclose(seg_r[0], expected @ R[:3, :3].T, atol=1e-15)
    assert V.grasp_marker_segments(np.zeros((0, 4, 4)), np.zeros(0), GRIPPER).shape == (0, 4, 2, 3)
    with pytest.raises(ValueError, match="^open_width: "):
        V.grasp_marker_segments(T[None], np.array([0.1, 0.2]), GRIPPER)


def test_marker_projects_to_the_expected_pixels():
    cam = _down_camera()
    seg = V.grasp_marker_segments(_top_down_grasp()[None], np.array([0.1]), GRIPPER)
    uv, visible = V.segment_pixels(cam, seg)
    assert visible.all()
    # Tips at depth 0.5: u = 80 -+ 100 * 0.05 / 0.5; backs at depth 0.46.
    np.testing.assert_allclose(uv[0, 0], [[70.0, 60.0], [80.0 - 5.0 / 0.46, 60.0]], atol=1e-12)
    np.testing.assert_allclose(uv[0, 1], [[90.0, 60.0], [80.0 + 5.0 / 0.46, 60.0]], atol=1e-12)
    for k in range(V.MARKER_SEGMENTS):
        for e in range(2):
            np.testing.assert_allclose(uv[0, k, e], _pixel(seg[0, k, e]), atol=1e-12)
    # Upscaled coordinates: pixel centres stay at integers, u' = s (u + 0.5) - 0.5.
    uv3, _ = V.segment_pixels(cam, seg, scale=3)
    np.testing.assert_allclose(uv3, 3 * (uv + 0.5) - 0.5, atol=1e-12)
    # World +y is image up (v decreases).
    uv_y, _ = V.segment_pixels(cam, V.grasp_marker_segments(_top_down_grasp(y=0.1)[None], np.array([0.1]), GRIPPER))
    np.testing.assert_allclose(uv_y[0, 0, 0], [70.0, 40.0], atol=1e-12)


def test_segments_behind_the_camera_are_clipped_or_dropped():
    cam = _down_camera()
    crossing = np.array([[[0.1, 0.0, 0.5], [0.1, 0.0, 1.5]]])  # depth 0.5 .. -0.5: crosses the camera plane
    behind = np.array([[[0.0, 0.0, 1.2], [0.1, 0.0, 1.5]]])
    uv, visible = V.segment_pixels(cam, np.stack([crossing, behind]))
    assert visible.tolist() == [[True], [False]]
    np.testing.assert_allclose(uv[0, 0, 0], [100.0, 60.0])
    # The far end is moved to the near plane (depth NEAR_CLIP) along the segment: x there is 0.1.
    np.testing.assert_allclose(uv[0, 0, 1], [CX + F * 0.1 / V.NEAR_CLIP, CY], rtol=1e-9)
    assert np.isnan(uv[1]).all()


def test_draw_grasps_colours_the_projected_pixels():
    cam = _down_camera()
    seg = V.grasp_marker_segments(_top_down_grasp()[None], np.array([0.1]), GRIPPER)
    black = np.zeros((H, W, 3), dtype=np.uint8)
    img = np.asarray(V.draw_grasps(black, cam, seg, [(0, 255, 0)], scale=1, line_width=1, outline=False))
    assert img.shape == (H, W, 3)
    green = (img == (0, 255, 0)).all(axis=2)
    # Seen from straight above the whole marker lies on row 60: finger tips at u = 70 and 90, the palm bar from
    # u = 80 - 10.87 to 80 + 10.87 (pixels 69..91, PIL rounds the float end points), the stem at u = 80.
    rows, cols = np.nonzero(green)
    assert set(rows.tolist()) == {60}
    assert set(range(70, 91)) <= set(cols.tolist()) <= set(range(69, 92))
    # From the side (camera at y = -1 looking along +y, image down = world -z) the fork shows: fingers at
    # u = 80 -+ 5 from the tips (v = 62) to the palm bar (v = 58), the stem up to v = 54. Integer end points, so the
    # 1-pixel lines are exactly these pixels.
    T_side = np.eye(4)
    T_side[:3, :3] = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]  # columns: x = +x, y = -z, z = +y
    T_side[:3, 3] = (0.0, -1.0, 0.52)
    side = Camera(cam.K, T_side, W, H)
    img = np.asarray(V.draw_grasps(black, side, seg, [(0, 255, 0)], scale=1, line_width=1, outline=False))
    expected = {(75, v) for v in range(58, 63)} | {(85, v) for v in range(58, 63)}
    expected |= {(u, 58) for u in range(75, 86)} | {(80, v) for v in range(54, 59)}
    rows, cols = np.nonzero((img == (0, 255, 0)).all(axis=2))
    assert set(zip(cols.tolist(), rows.tolist())) == expected
    big = V.draw_grasps(black, cam, seg, [(0, 255, 0)], scale=3)
    assert big.size == (3 * W, 3 * H)
    arr = np.asarray(big)
    assert (arr[3 * 60 + 1, 3 * 70 + 1] == (0, 255, 0)).all()  # tip pixel centre, upscaled
    assert ((arr == (0, 0, 0)).all(axis=2)).sum() > 0.9 * arr.shape[0] * arr.shape[1]
    with pytest.raises(ValueError, match="^camera: "):
        V.draw_grasps(np.zeros((H + 1, W, 3), dtype=np.uint8), cam, seg, [(0, 255, 0)])
    with pytest.raises(ValueError, match="^colours: "):
        V.draw_grasps(black, cam, seg, [(0, 255, 0), (1, 2, 3)])
    assert V.draw_grasps(black, cam, np.zeros((0, 4, 2, 3)), [], scale=2).size == (2 * W, 2 * H)


# ---------------------------------------------------------------------------------------------------------------
# Labels and choice
# ---------------------------------------------------------------------------------------------------------------


def test_label_colours():
    out, pre = V.LABELS["rollouts"], V.LABELS["prefilter"]
    assert list(out) == [5, 4, 3, 0, 1, 2] and list(pre) == [-1, 0, 1, 2]
    assert out[5][0] == "success" and pre[-1][0] == "free"
    r, g, b = out[5][1]
    assert g > 1.5 * max(r, b)  # green
    r, g, b = out[4][1]
    assert r > g > b and g > 60  # orange
    r, g, b = out[3][1]
    assert min(r, g) > 200 and b < 60  # yellow
    for code in (0, 1, 2):
        r, g, b = out[code][1]
        assert r > 1.5 * max(g, b) and out[code][1] == pre[code][1]  # red shades, the same for both sources
    assert len({out[c][1] for c in (0, 1, 2)}) == 3
    r, g, b = pre[-1][1]
    assert b > 1.5 * max(r, g)  # blue
    # Every colour is distinct within a source.
    for labels in (out, pre):
        assert len({c for _, c in labels.values()}) == len(labels)


def _tables(prefilter, outcome=None, simulated=None):
    n = len(prefilter)
    T = np.broadcast_to(_top_down_grasp(), (n, 4, 4)).reshape(n, 16)
    grasps = pa.table({
        "grasp_id": pa.array(np.arange(n, dtype=np.int32)),
        "gripper": pa.array(["box_jaw"] * n),
        "pose_world": fixed_list(T, 16),
        "open_width": pa.array(np.full(n, 0.1)),
        "prefilter_code": pa.array(np.asarray(prefilter, dtype=np.int8)),
    })
    if outcome is None:
        return grasps, None
    rollouts = pa.table({
        "grasp_id": pa.array(np.arange(n, dtype=np.int32)),
        "outcome": pa.array(np.asarray(outcome, dtype=np.int8)),
        "simulated": pa.array(np.asarray(simulated, dtype=bool)),
    })
    return grasps, rollouts


def test_grasp_labels_by_rollout_else_prefilter():
    grasps, rollouts = _tables([-1, 0, -1, 1, 2], [5, 0, 4, 1, 2], [True, False, True, False, False])
    codes, source = V.grasp_labels(grasps, rollouts)
    assert source == "rollouts" and codes.tolist() == [5, 0, 4, 1, 2]
    codes, source = V.grasp_labels(grasps)
    assert source == "prefilter" and codes.tolist() == [-1, 0, -1, 1, 2]
    # Rollouts of other grasps: not used.
    _, other = _tables([-1, 0, -1, 1, 2], [5, 1, 4, 1, 2], [True, False, True, False, False])
    assert V.rollouts_match(grasps, rollouts) and not V.rollouts_match(grasps, other)
    with pytest.raises(ValueError, match="^rollouts: "):
        V.grasp_labels(grasps, other)
    _, short = _tables([-1, 0], [5, 0], [True, False])
    assert not V.rollouts_match(grasps, short)


def test_choose_grasps_spreads_evenly_over_labels_and_rows():
    codes = np.array([5] * 3 + [0] * 20 + [1] * 10)
    pick = V.choose_grasps(codes, 9, [5, 4, 3, 0, 1, 2])
    # 3 slots each; within a label evenly spaced over its rows (floor(x + 0.5) of linspace).
    assert pick.tolist() == [0, 1, 2, 3, 13, 22, 23, 28, 32]
    # A label with fewer grasps than its share gives the rest to the others.
    pick = V.choose_grasps(codes, 13, [5, 4, 3, 0, 1, 2])
    assert np.sum(codes[pick] == 5) == 3 and np.sum(codes[pick] == 0) == 5 and np.sum(codes[pick] == 1) == 5
    assert len(np.unique(pick)) == 13
    # Priority decides who gets the odd slot; unlisted codes come last.
    assert codes[V.choose_grasps(codes, 1, [1, 0, 5])].tolist() == [1]
    assert codes[V.choose_grasps(codes, 2, [5])].tolist() == [5, 0]
    assert V.choose_grasps(codes, 100, [5]).tolist() == list(range(len(codes)))
    assert V.choose_grasps(codes, 0, [5]).tolist() == []
    assert V.choose_grasps(np.zeros(0, dtype=int), 5, [5]).tolist() == []
    # Deterministic and never repeats a row, whatever the counts.
    for n in range(1, 34):
        p = V.choose_grasps(codes, n, [5, 0, 1])
        assert len(p) == len(np.unique(p)) == n
        np.testing.assert_array_equal(p, V.choose_grasps(codes, n, [5, 0, 1]))


def test_grasp_picture_draws_markers_in_label_colours_with_a_legend():
    grasps, rollouts = _tables([-1, 0, -1], [5, 0, 4], [True, False, True])
    scene = SimpleNamespace(scene_id="scene_x", rgb=np.full((1, H, W, 3), 128, dtype=np.uint8),
                            cameras=[_down_camera()])
    pic = V.grasp_picture(scene, grasps, rollouts, n=1, scale=2)
    assert pic.width == 2 * W and pic.height > 2 * H
    top = np.asarray(pic)[: 2 * H]
    present = {c for c in map(tuple, top.reshape(-1, 3))}
    assert V.LABELS["rollouts"][5][1] in present  # n=1: the success is drawn first
    assert V.LABELS["rollouts"][0][1] not in present
    pic = V.grasp_picture(scene, grasps, None, n=3, scale=2, gripper=dataclasses.replace(GRIPPER))
    present = {c for c in map(tuple, np.asarray(pic)[: 2 * H].reshape(-1, 3))}
    assert V.LABELS["prefilter"][-1][1] in present
    with pytest.raises(ValueError, match="^view: "):
        V.grasp_picture(scene, grasps, view=1)
    with pytest.raises(ValueError, match="no RGB images"):
        V.grasp_picture(SimpleNamespace(scene_id="s", rgb=None, cameras=[]), grasps)


# ---------------------------------------------------------------------------------------------------------------
# gen show grasps
# ---------------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def smoke_out(tmp_path_factory):
    root = tmp_path_factory.mktemp("show_grasps")
    return root / "out", ["--set", f"run.cache_dir={root / 'cache'}", "--set", "run.jobs=1"]


def _invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def _label_colours_drawn(png: Path, height: int, source: str) -> set[int]:
    with Image.open(png) as image:
        pixels = {tuple(c) for c in np.asarray(image.convert("RGB"))[:height].reshape(-1, 3)}
    return {code for code, (_, colour) in V.LABELS[source].items() if colour in pixels}


def test_gen_show_grasps_prefilter_then_rollouts(smoke_out):
    out, sets = smoke_out
    config = ROOT / "configs" / "smoke.yaml"
    run = _invoke("run", "grasps", "--config", config, "--out", out, *sets)
    assert run.exit_code == 0, run.output
    width, height = 160, 120  # smoke camera size
    # Grasps only: coloured by the pre-filter.
    result = _invoke("show", "grasps", "scene_000000", "--config", config, "--out", out, *sets)
    assert result.exit_code == 0, result.output
    png = Path(result.stdout.strip())
    assert png == out / "show" / "scene_000000_grasps_view0.png"
    with Image.open(png) as image:
        assert image.format == "PNG" and image.width == 3 * width and image.height > 3 * height
    drawn = _label_colours_drawn(png, 3 * height, "prefilter")
    assert drawn and drawn <= set(V.LABELS["prefilter"])
    # After the rollouts: coloured by outcome, at the asked size and path.
    run = _invoke("run", "rollouts", "--config", config, "--out", out, *sets)
    assert run.exit_code == 0, run.output
    custom = out.parent / "g.png"
    result = _invoke("show", "grasps", "scene_000001", "-n", 12, "--scale", 2, "-o", custom, "--config", config,
                     "--out", out, *sets)
    assert result.exit_code == 0, result.output
    assert Path(result.stdout.strip()) == custom and "note:" not in result.output
    with Image.open(custom) as image:
        assert image.width == 2 * width and image.height > 2 * height
    cfg = load(PROJECT, config, [s for s in sets if s != "--set"], out=out)
    outcomes = pq.read_table(find_shard(PROJECT, cfg, "rollouts", "scene_000001")[0]).column("outcome").to_numpy()
    drawn = _label_colours_drawn(custom, 2 * height, "rollouts")
    assert drawn and drawn <= set(outcomes.tolist())
    if (outcomes == 5).any():
        assert 5 in drawn  # successes are served first
    # Errors: a scene that does not exist, a view out of range.
    missing = _invoke("show", "grasps", "scene_000099", "--config", config, "--out", out, *sets)
    assert missing.exit_code == 2 and "no scenes shard for 'scene_000099'" in " ".join(missing.output.split())
    bad_view = _invoke("show", "grasps", "scene_000000", "--view", 3, "--config", config, "--out", out, *sets)
    assert bad_view.exit_code == 2 and "has views 0..0, got 3" in " ".join(bad_view.output.split())


def test_segments_far_outside_the_image_are_cut_before_drawing():
    cam = _down_camera()
    # From a point in view to one 1 mm in front of the camera, far off to the side: projects ~1e5 pixels away.
    seg = np.array([[[[0.0, 0.0, 0.5], [0.2, 0.0, 0.999]]]])
    black = np.zeros((H, W, 3), dtype=np.uint8)
    img = np.asarray(V.draw_grasps(black, cam, seg, [(0, 255, 0)], scale=1, line_width=1, outline=False))
    rows, cols = np.nonzero((img == (0, 255, 0)).all(axis=2))
    assert set(rows.tolist()) == {60} and cols.min() == 80 and cols.max() == W - 1
    uv, inside = V._clip_segments(np.array([[[0.0, 0.0], [1e9, 0.0]], [[1e9, 1e9], [2e9, 1e9]]]), 100.0)
    assert inside.tolist() == [True, False]
    np.testing.assert_allclose(uv[0], [[0.0, 0.0], [100.0, 0.0]])
