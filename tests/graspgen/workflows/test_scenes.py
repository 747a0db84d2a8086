"""The scenes stage: settled scenes at rest, no interpenetration, clouds on their objects, same key same bytes,
config errors, bounded retries, the contact sheet and ``gen show scene``."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
import trimesh
from PIL import Image
from typer.testing import CliRunner

from graspgen.errors import InputError, SettingsError, SimulationError
from graspgen.io.files import write_h5
from graspgen.io.objects import ObjectRecord, read_object
from graspgen.io.scenes import read_scene
from graspgen.sim.camera import transform_points
from graspgen.sim.scene_model import SEG_GROUND, SEG_SUPPORT, scene_spec
from graspgen.sim.scene_state import geom_labels, object_poses, set_object_poses
from graspgen.sim.support import SupportParams
from graspgen.viz.scenes import colorize_depth, contact_sheet
from graspgen.workflows.scene_placement import choose_objects
from graspgen.workflows.scenes import CameraParams, DepthNoiseParams, ScenesParams, make_scene
from graspgen_cli.app import app
from pipeline.config import load_config
from pipeline.errors import ConfigError, StageError
from pipeline.plan import committed
from pipeline.repro import shard_hashes
from pipeline.scheduler import run_pipeline
from pipeline.stage import Upstream
from stages.project import PROJECT
from stages.scenes import ScenesStage

OBJECTS = ["box", "cylinder", "l_bracket", "wedge"]
CHEAP = [
    f"objects.include=[{', '.join(OBJECTS)}]",
    "objects.coacd.threshold=0.2",
    "objects.coacd.resolution=300",
    "objects.coacd.mcts_iterations=10",
    "objects.coacd.preprocess_resolution=20",
    "objects.stable_poses.max_poses=4",
    "objects.stable_poses.settle_time=0.5",
]
SMALL = ["scenes.num_scenes=2", "scenes.cameras.width=160", "scenes.cameras.height=120", "scenes.cameras.num_views=2"]


def config(out: Path, cache: Path, *sets: str):
    return load_config(PROJECT.schema, None, [f"run.out={out}", f"run.cache_dir={cache}", "run.jobs=1", *CHEAP, *sets])


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    """The objects stage run once on four bundled objects: (output folder, CoACD cache)."""
    root = tmp_path_factory.mktemp("library")
    out, cache = root / "out", root / "cache"
    (report,) = run_pipeline(PROJECT, config(out, cache), ["objects"])
    assert (report.ran, report.failed) == (len(OBJECTS), 0)
    return out, cache


@pytest.fixture(scope="module")
def upstream(library):
    out, _ = library
    return Upstream(out, {"objects": {e.task: e for e in committed(out, "objects").values()}})


@pytest.fixture(scope="module")
def records(upstream):
    return {name: read_object(upstream.path("objects", name)) for name in upstream.ids("objects")}


def scene(params: ScenesParams, upstream, seed: int, folder: Path, name: str = "scene"):
    """Make a scene with ``rng = default_rng(seed)``, write its shard to ``folder`` and read it back."""
    made = make_scene(
        f"scene_{seed:06d}",
        params,
        upstream.ids("objects"),
        lambda name: read_object(upstream.path("objects", name)),
        lambda name: upstream.key("objects", name),
        np.random.default_rng(seed),
    )
    path = folder / f"{name}_{seed}.h5"
    write_h5(path, made.tree)
    return read_scene(path), made.meta


CLUTTER = ScenesParams(objects_per_scene=(4, 6), replace=True, gap=0.0, support=SupportParams(area=(0.22, 0.22)))
"""Crowded scenes: objects may touch after settling, so rest and interpenetration are really tested."""


def rebuilt(record, records):
    model = scene_spec(record, records).compile()
    data = mujoco.MjData(model)
    set_object_poses(model, data, record.poses)
    return model, data


# --------------------------------------------------------------------------------------------------------------
# The four checks of the issue


@pytest.mark.parametrize("kind", ["table", "bin", "shelf"])
def test_settled_poses_are_at_rest(kind, upstream, records, tmp_path):
    """Re-simulating 0.5 s from the stored poses moves no point of any object more than 1 mm."""
    params = dataclasses.replace(CLUTTER, support=dataclasses.replace(CLUTTER.support, kind=kind))
    for seed in range(3):
        record, meta = scene(params, upstream, seed, tmp_path)
        assert len(record.object_names) >= 4
        model, data = rebuilt(record, records)
        mujoco.mj_step(model, data, nstep=int(round(0.5 / model.opt.timestep)))
        after = object_poses(model, data)
        for i, name in enumerate(record.object_names):
            pts = np.concatenate([v for v, _ in records[name].convex_parts])
            moved = np.linalg.norm(transform_points(after[i], pts) - transform_points(record.poses[i], pts), axis=1)
            assert moved.max() < 1e-3, f"{kind} seed {seed}: {name} moved {moved.max() * 1e3:.2f} mm"
        assert meta["settle_time"] <= params.settle.max_time


def min_object_distance(model, data) -> tuple[float, int]:
    """Smallest signed distance between collision parts of two different objects (< 0: overlap), and the
    number of object pairs in contact."""
    labels = geom_labels(model)
    parts = [g for g in range(model.ngeom) if labels[g] >= 0 and model.geom_contype[g]]
    smallest, touching = math.inf, set()
    fromto = np.zeros(6)
    for i, a in enumerate(parts):
        for b in parts[i + 1 :]:
            if labels[a] != labels[b]:
                d = mujoco.mj_geomDistance(model, data, a, b, 0.01, fromto)
                smallest = min(smallest, d)
                if d < 1e-4:
                    touching.add((labels[a], labels[b]))
    return smallest, len(touching)


def test_no_two_objects_interpenetrate(wobbly_library, tmp_path):
    """Crowded scenes where toppling boxes fall against their neighbours (kept: max_tilt = pi)."""
    library = {n: read_object(wobbly_library.path("objects", n)) for n in wobbly_library.ids("objects")}
    params = dataclasses.replace(CLUTTER, objects=("wobbly", "cylinder", "box", "l_bracket"), max_tilt=math.pi)
    touching = 0
    for seed in range(4):
        record, _ = scene(params, wobbly_library, seed, tmp_path)
        model, data = rebuilt(record, library)
        smallest, pairs = min_object_distance(model, data)
        touching += pairs
        assert smallest > -1e-3, f"seed {seed}: objects overlap by {-smallest * 1e3:.2f} mm"
        for c in data.contact[: data.ncon]:  # nor does any object sink into the support
            assert c.dist > -1e-3
    assert touching > 0  # objects do lean on each other in these scenes: the check is not vacuous


def test_backprojected_points_lie_on_the_object_their_id_names(upstream, records, tmp_path):
    record, _ = scene(ScenesParams(), upstream, 7, tmp_path)
    assert len(record.cameras) == 3
    seen = set()
    for view in range(len(record.cameras)):
        points, ids = record.cloud(view, "world")
        assert points.dtype == np.float32 and ids.dtype == np.int16 and len(points) == len(ids)
        assert not np.any(ids == SEG_GROUND)  # clouds hold objects and support only
        for i, name in enumerate(record.object_names):
            sel = points[ids == i]
            if len(sel) == 0:
                continue
            seen.add(i)
            local = transform_points(np.linalg.inv(record.poses[i]), sel)
            mesh = trimesh.Trimesh(records[name].vertices, records[name].faces, process=False)
            _, dist, _ = trimesh.proximity.closest_point(mesh, local)
            assert dist.max() < 2e-3, f"view {view}: {name} points up to {dist.max() * 1e3:.2f} mm off its mesh"
        table = points[ids == SEG_SUPPORT] - record.tree["support"]["box_centers"][0]
        half = record.tree["support"]["box_sizes"][0] / 2
        assert len(table) > 0 and np.max(np.abs(np.abs(table) - half).min(axis=1)) < 1e-3  # on the table's faces
        assert (np.abs(table[:, 2] - half[2]) < 1e-3).mean() > 0.5  # mostly its top, z = 0
        # the camera-frame cloud is the same points, in front of the camera
        cam_points, cam_ids = record.cloud(view, "camera")
        assert np.array_equal(ids, cam_ids) and np.all(cam_points[:, 2] > 0)
        np.testing.assert_allclose(transform_points(record.cameras[view].T_world_camera, cam_points), points, atol=1e-5)
    assert seen == set(range(len(record.object_names)))


def test_same_key_gives_the_same_bytes(library, tmp_path):
    _, cache = library
    hashes = []
    for name, jobs in [("a", 1), ("b", 1), ("c", 2)]:
        out = tmp_path / name
        cfg = config(out, cache, *SMALL, f"run.jobs={jobs}")
        run_pipeline(PROJECT, cfg, ["objects"])
        reports = {r.stage: r for r in run_pipeline(PROJECT, cfg, ["scenes"])}
        assert reports["scenes"].ran == 2 and reports["scenes"].failed == 0
        hashes.append({k: v for k, v in shard_hashes(out).items() if k.startswith("scenes/")})
    assert len(hashes[0]) == 2 and hashes[0] == hashes[1] == hashes[2]
    assert len(set(hashes[0].values())) == 2  # each scene its own draw
    # and a changed param changes the scenes
    out = tmp_path / "d"
    cfg = config(out, cache, *SMALL, "scenes.friction=[0.3, 0.9]")
    run_pipeline(PROJECT, cfg, ["scenes"])
    other = {k: v for k, v in shard_hashes(out).items() if k.startswith("scenes/")}
    assert set(other.values()).isdisjoint(hashes[0].values())


# --------------------------------------------------------------------------------------------------------------
# Shard contents and options


def test_shard_layout_and_conventions(upstream, tmp_path):
    params = ScenesParams(friction=(0.4, 0.9), cameras=dataclasses.replace(ScenesParams().cameras, clouds="both"))
    record, meta = scene(params, upstream, 3, tmp_path)
    tree, n, v = record.tree, len(record.object_names), 3
    assert tree["objects"]["poses"].shape == (n, 4, 4) and tree["objects"]["placed_poses"].shape == (n, 4, 4)
    assert np.all((record.friction >= 0.4) & (record.friction <= 0.9)) and len(set(record.friction)) == n
    assert record.object_keys == [upstream.key("objects", name) for name in record.object_names]
    assert tree["cameras"]["K"].shape == (v, 3, 3) and tree["cameras"]["T_world_camera"].shape == (v, 4, 4)
    images = tree["images"]
    assert images["rgb"].shape == (v, 240, 320, 3) and images["rgb"].dtype == np.uint8
    assert images["depth"].dtype == np.float32 and images["segmentation"].dtype == np.int16
    assert "depth_noisy" not in images
    clouds = tree["clouds"]
    assert clouds["view_offsets"][-1] == len(clouds["points_world"]) == len(clouds["points_camera"])
    assert tree["support"]["@attrs"]["box_names"] == ["support/table"]
    assert record.support == SupportParams()
    for cam in record.cameras:
        # the scene centre is in front of every camera (OpenCV: +z forward)
        centre = transform_points(np.linalg.inv(cam.T_world_camera), record.poses[:, :3, 3].mean(0))
        assert centre[2] > 0.3
    counts = tree["@attrs"]["counts"]
    assert counts["placement_tries"] >= n and meta["placement_tries"] == counts["placement_tries"]


def test_depth_noise_is_stored_apart_and_clean_depth_kept(upstream, tmp_path):
    cams = ScenesParams().cameras
    noisy = ScenesParams(
        cameras=dataclasses.replace(cams, depth_noise=dataclasses.replace(cams.depth_noise, enabled=True))
    )
    clean, _ = scene(ScenesParams(), upstream, 5, tmp_path, "clean")
    with_noise, _ = scene(noisy, upstream, 5, tmp_path, "noisy")
    assert np.array_equal(clean.depth, with_noise.depth)  # the noise is drawn last: nothing else changes
    assert clean.depth_noisy is None and with_noise.depth_noisy.shape == clean.depth.shape
    valid = clean.depth > 0
    assert np.all(with_noise.depth_noisy[~valid] == 0)
    z = clean.depth[valid].astype(float)
    dropped = with_noise.depth_noisy[valid] == 0
    noise = cams.depth_noise
    normalised = (with_noise.depth_noisy[valid] - z)[~dropped] / (
        noise.sigma + noise.sigma_quadratic * z[~dropped] ** 2
    )
    assert dropped.mean() == pytest.approx(noise.dropout, rel=0.2)
    assert abs(normalised.mean()) < 0.02 and np.std(normalised) == pytest.approx(1.0, rel=0.02)


def test_without_rendering_no_images_and_no_gl_needed(upstream, tmp_path):
    params = ScenesParams(cameras=dataclasses.replace(ScenesParams().cameras, render=False))
    record, meta = scene(params, upstream, 1, tmp_path)
    assert record.rgb is None and record.clouds is None and len(record.cameras) == 3
    assert meta["seconds_render_per_view"] == 0.0
    with pytest.raises(InputError, match="no images"):
        contact_sheet(record)


def test_fixed_and_weighted_choice():
    rng = np.random.default_rng(0)
    fixed = ScenesParams(choice="fixed", objects=("wedge", "box", "wedge"))
    assert choose_objects(fixed, OBJECTS, rng) == ["wedge", "box", "wedge"]
    weighted = ScenesParams(objects_per_scene=(1, 2), weights={"box": 0.0, "wedge": 0.0})
    drawn = [n for _ in range(50) for n in choose_objects(weighted, OBJECTS, rng)]
    assert set(drawn) == {"cylinder", "l_bracket"}
    many = ScenesParams(objects_per_scene=5, replace=True, objects=("box",))
    assert choose_objects(many, OBJECTS, rng) == ["box"] * 5


def test_fixed_list_places_exactly_those_objects(upstream, tmp_path):
    record, _ = scene(ScenesParams(choice="fixed", objects=("wedge", "box")), upstream, 2, tmp_path)
    assert record.object_names == ["wedge", "box"]


# --------------------------------------------------------------------------------------------------------------
# Errors and bounded retries


@pytest.mark.parametrize(
    "override, message",
    [
        ("scenes.cameras.width=0", r"scenes.cameras.width: must be an integer in \[8, 8192\], got 0"),
        ("scenes.friction=[0.9, 0.3]", r"scenes.friction: must be > 0 \(or \[lo, hi\] with 0 < lo <= hi\)"),
        ("scenes.objects_per_scene=[3, 1]", "scenes.objects_per_scene: must be a number >= 1 or"),
        ("scenes.support.kind=floor", "scenes.support.kind: must be one of 'table', 'bin', 'shelf', got 'floor'"),
        ("scenes.cameras.fx=300", "scenes.cameras.fx: must be given together with fy, cx, cy"),
        ("scenes.cameras.elevation=[0.2, 2.0]", r"scenes.cameras.elevation: must lie in \[-1.5708, 1.5708\]"),
        ("scenes.cameras.depth_noise.dropout=2", r"scenes.cameras.depth_noise.dropout: must be in \[0, 1\]"),
        ("scenes.settle.max_time=0", r"scenes.settle.max_time: must be in \(0, inf\)"),
        ("scenes.choice=fixed", "scenes.objects: must list the objects of every scene when choice is fixed"),
    ],
)
def test_bad_config_values_name_the_key(override, message):
    with pytest.raises(ConfigError, match=message):
        load_config(PROJECT.schema, None, [override])


@pytest.mark.parametrize(
    "cls, kwargs, message",
    [
        (ScenesParams, {"replace": 1}, "replace: must be a bool, got 1"),
        (ScenesParams, {"gap": math.inf}, "gap: must be finite, got inf"),
        (ScenesParams, {"objects_per_scene": 2.5}, "objects_per_scene: must be an integer, got 2.5"),
        (ScenesParams, {"friction": (0.2, "x")}, r"friction\[1\]: must be a number, got 'x'"),
        (ScenesParams, {"weights": {"box": -1}}, r"weights.box: must be in \[0, inf\), got -1"),
        (ScenesParams, {"on_unstable": "ignore"}, "on_unstable: must be one of remove, retry, got 'ignore'"),
        (ScenesParams, {"cameras": None}, "cameras: must be a CameraParams, got NoneType"),
        (CameraParams, {"num_views": True}, "num_views: must be an integer, got True"),
        (CameraParams, {"clouds": "all"}, "clouds: must be one of world, camera, both, none, got 'all'"),
        (DepthNoiseParams, {"enabled": 1}, "enabled: must be a bool, got 1"),
    ],
)
def test_scene_settings_are_type_checked_by_field(cls, kwargs, message):
    with pytest.raises(SettingsError, match=message):
        cls(**kwargs)


def test_task_planning_errors(upstream):
    stage = ScenesStage()
    tasks = stage.tasks(ScenesParams(num_scenes=3), upstream)
    assert [t.id for t in tasks] == ["scene_000000", "scene_000001", "scene_000002"]
    assert tasks[0].needs == {"objects": OBJECTS}
    listed = stage.tasks(ScenesParams(objects=("wedge", "box"), objects_per_scene=2), upstream)
    assert listed[0].needs == {"objects": ["box", "wedge"]}  # only what a scene may draw enters its key
    with pytest.raises(ConfigError, match="scenes.objects: no object named 'teapot' in the library; available: box"):
        stage.tasks(ScenesParams(objects=("teapot",), objects_per_scene=1), upstream)
    with pytest.raises(ConfigError, match="up to 5 objects per scene, but only 4 objects can be drawn"):
        stage.tasks(ScenesParams(objects_per_scene=5), upstream)
    with pytest.raises(StageError, match="no objects to build scenes from"):
        stage.tasks(ScenesParams(), Upstream(upstream.out, {"objects": {}}))


def test_a_scene_that_cannot_be_placed_is_reported_not_retried_forever(upstream, tmp_path):
    crowded = ScenesParams(
        objects_per_scene=12, replace=True, max_tries=5, max_scene_tries=3, support=SupportParams(area=(0.1, 0.1))
    )
    with pytest.raises(SimulationError, match=r"scene_000000: no scene could be made in 3 draws \(objects left out"):
        scene(crowded, upstream, 0, tmp_path)


def _record_tree(record: ObjectRecord) -> dict:
    """An objects-stage shard of ``record`` (the layout of :func:`graspgen.io.objects.object_tree`)."""
    v_off = np.cumsum([0] + [len(v) for v, _ in record.convex_parts])
    f_off = np.cumsum([0] + [len(f) for _, f in record.convex_parts])
    return {
        "@attrs": {**record.attrs, "name": record.name},
        "mesh": {"vertices": record.vertices, "faces": record.faces},
        "convex": {
            "vertices": np.concatenate([v for v, _ in record.convex_parts]),
            "faces": np.concatenate([f for _, f in record.convex_parts]),
            "vertex_offsets": v_off,
            "face_offsets": f_off,
        },
        "mass": {"center_of_mass": record.center_of_mass, "inertia": record.inertia},
        "stable_poses": {"transforms": record.stable_poses, "probabilities": record.stable_probabilities},
    }


@pytest.fixture
def wobbly_library(upstream, records, tmp_path):
    """The library plus ``wobbly``: the box with one 'stable pose' that is not (on an edge, 40 degrees tilted)."""
    pose = np.eye(4)
    c, s = math.cos(math.radians(40)), math.sin(math.radians(40))
    pose[:3, :3] = [[1, 0, 0], [0, c, -s], [0, s, c]]
    pose[2, 3] = -transform_points(pose, records["box"].vertices)[:, 2].min()
    wobbly = dataclasses.replace(
        records["box"], name="wobbly", stable_poses=pose[None], stable_probabilities=np.ones(1)
    )
    folder = tmp_path / "objects"
    folder.mkdir()
    write_h5(folder / "wobbly.h5", _record_tree(wobbly))
    entries = {e.task: e for e in committed(upstream.out, "objects").values()}
    entries = {n: dataclasses.replace(e, file=str(upstream.path("objects", n))) for n, e in entries.items()}
    entries["wobbly"] = dataclasses.replace(entries["box"], task="wobbly", key="0" * 64, file=str(folder / "wobbly.h5"))
    return Upstream(tmp_path, {"objects": entries})  # absolute files: out / stage / file is the file


def test_unstable_objects_are_removed_and_counted(wobbly_library, tmp_path):
    params = ScenesParams(objects=("box", "wobbly"), objects_per_scene=(1, 2))
    removed = 0
    for seed in range(8):
        record, meta = scene(params, wobbly_library, seed, tmp_path)
        assert record.object_names == ["box"]  # the toppling one never survives
        assert meta["unstable_fallen"] == meta["unstable_moving"] == 0  # it topples: tipped, not fallen off
        removed += meta["unstable_tipped"]
        assert record.attrs["counts"]["unstable_tipped"] == meta["unstable_tipped"]
    assert removed > 0  # ... and was removed (not only never drawn)


def test_on_unstable_retry_draws_the_scene_again(wobbly_library, tmp_path):
    params = ScenesParams(objects=("box", "wobbly"), objects_per_scene=(1, 2), on_unstable="retry")
    retries = 0
    for seed in range(8):
        record, meta = scene(params, wobbly_library, seed, tmp_path)
        assert record.object_names == ["box"]
        assert meta["unstable_tipped"] <= meta["scene_retries"]  # each tipped draw was redrawn
        retries += meta["scene_retries"]
    assert retries > 0
    always = ScenesParams(choice="fixed", objects=("box", "wobbly"), max_scene_tries=2)
    with pytest.raises(SimulationError, match=r"unstable \(fallen/tipped/moving\): 0/2/0"):
        scene(always, wobbly_library, 0, tmp_path)


# --------------------------------------------------------------------------------------------------------------
# Looking at a scene


def test_contact_sheet_and_gen_show_scene(library, tmp_path):
    _, cache = library
    out = tmp_path / "out"
    cfg_file = tmp_path / "c.yaml"
    cfg_file.write_text(f"run:\n  jobs: 1\n  cache_dir: {cache}\n")
    sets = [a for s in (*CHEAP, *SMALL) for a in ("--set", s)]
    runner = CliRunner()
    result = runner.invoke(app, ["run", "scenes", "--config", str(cfg_file), "--out", str(out), *sets])
    assert result.exit_code == 0, result.output
    png = tmp_path / "sheet.png"
    result = runner.invoke(
        app, ["show", "scene", "scene_000001", "--config", str(cfg_file), "--out", str(out), "-o", str(png), *sets]
    )
    assert result.exit_code == 0, result.output
    assert result.stdout.strip().endswith("sheet.png")
    with Image.open(png) as image:
        size = image.size
    assert size == (3 * 160 + 4 * 4, 2 * (120 + 16 + 4) + 4)  # 3 columns, one row per view
    one = runner.invoke(
        app, ["show", "scene", "scene_000000", "--view", "1", "--out", str(out), *sets, "--config", str(cfg_file)]
    )
    assert one.exit_code == 0, one.output
    assert Path(one.stdout.strip()) == out / "show" / "scene_000000_view1.png"
    with Image.open(one.stdout.strip()) as image:
        assert image.size[1] == 120 + 16 + 2 * 4
    missing = runner.invoke(app, ["show", "scene", "scene_000099", "--out", str(out), *sets, "--config", str(cfg_file)])
    assert missing.exit_code == 2 and "no scenes shard for 'scene_000099'" in " ".join(missing.output.split())
    bad_view = runner.invoke(
        app, ["show", "scene", "scene_000000", "--view", "7", "--out", str(out), *sets, "--config", str(cfg_file)]
    )
    assert bad_view.exit_code == 2 and "has views 0..1, got 7" in " ".join(bad_view.output.split())


def test_colorize_depth_is_near_bright_far_dark():
    depth = np.array([[0.0, 0.5, 1.0, 9.0]], dtype=np.float32)
    focus = np.array([[False, True, True, False]])
    img = colorize_depth(depth, focus)
    assert img[0, 0].tolist() == [0, 0, 0]  # no return is black
    assert img[0, 1].sum() > img[0, 2].sum()  # near is brighter
    assert img[0, 3].tolist() == img[0, 2].tolist()  # beyond the focus range: clipped to the far colour


def test_a_scene_made_in_process_from_a_loaded_config_stores_its_params(upstream, tmp_path):
    # A loaded config holds read-only mappings (MappingProxyType), which dataclasses.asdict cannot copy: a scene
    # task run in the main process (--jobs 1, or one task left) failed with "cannot pickle 'mappingproxy'".
    params = load_config(PROJECT.schema, None, ["scenes.weights={box: 2.0}", "scenes.cameras.render=false"]).scenes
    record, _ = scene(params, upstream, 4, tmp_path)
    assert record.attrs["params"]["weights"] == {"box": 2.0}
