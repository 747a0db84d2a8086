"""Scene grasps sampled until enough pass the pre-filter (graspgen.workflows.scene_grasps, graspgen.sim.reach,
graspgen.workflows.candidate_pool): kept free candidates really are free, the collision share holds, the counts add up,
an object wider than the stroke gives one warning and no rows, the reach screen agrees with analytic cases, and the
same seed gives the same bytes."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import trimesh

from graspgen.errors import SettingsError
from graspgen.geometry.antipodal import AntipodalParams
from graspgen.grippers import load_gripper
from graspgen.io.files import write_h5
from graspgen.io.objects import ObjectRecord
from graspgen.io.scenes import read_scene
from graspgen.sim.prefilter import CollisionChecker
from graspgen.sim.reach import ReachParams, clearance_boxes, reachable, surface_points
from graspgen.sim.scene_model import object_body_name, scene_spec
from graspgen.sim.support import SupportParams
from graspgen.validation import settings_dict
from graspgen.workflows.candidate_pool import collision_cap
from graspgen.workflows.scene_grasps import GraspsParams, sample_scene_grasps

GRIPPER = "robotiq_2f85_mesh"
BOX = (0.05, 0.07, 0.12)  # 5 x 7 cm across, 12 cm tall: graspable across x and y, not along z (85 mm stroke)
SAMPLER = AntipodalParams(num_surface_points=64, approach="above", max_approach_angle=1.0)


pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")


def record(name: str, mesh: trimesh.Trimesh, height: float, density: float = 700.0) -> ObjectRecord:
    """An object record of a convex mesh centred at its origin, resting with its bottom at z = 0."""
    v, f = np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int32)
    mass = density * float(mesh.volume)
    rest = np.eye(4)
    rest[2, 3] = height / 2
    return ObjectRecord(name, v, f, [(v, f)], mass, np.zeros(3), np.asarray(mesh.moment_inertia) * density, rest[None],
                        np.array([1.0]), {})


def write_scene(path: Path, names, poses) -> Path:
    n = len(names)
    write_h5(path, {
        "@attrs": {"scene_id": "scene_000000", "object_names": list(names), "object_keys": ["k"] * n,
                   "support": settings_dict(SupportParams())},
        "objects": {"poses": np.asarray(poses, dtype=np.float64).reshape(n, 4, 4), "friction": np.full(n, 0.5)},
        "cameras": {"@attrs": {"width": 160, "height": 120}, "K": np.zeros((0, 3, 3)),
                    "T_world_camera": np.zeros((0, 4, 4))},
    })
    return path


def on_table(height: float, x: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = (x, 0.0, height / 2)
    return T


@pytest.fixture(scope="module")
def box_scene(tmp_path_factory):
    path = write_scene(tmp_path_factory.mktemp("scene") / "scene.h5", ["box"], [on_table(BOX[2])])
    return path, {"box": record("box", trimesh.creation.box(BOX), BOX[2])}


def run(scene, seed: int = 0, **kw):
    path, records = scene
    params = GraspsParams(gripper=GRIPPER, sampler=SAMPLER, **kw)
    return sample_scene_grasps(path, records.__getitem__, params, np.random.default_rng(seed))


def test_box_across_faces_keeps_free_candidates_that_pass_an_independent_prefilter(box_scene):
    table, meta = run(box_scene, max_per_object=10, collision_share=0.2)
    codes = table.column("prefilter_code").to_numpy()
    assert (codes == -1).sum() == 10 and meta["objects"][0]["stopped"] == "target"
    # Contacts on opposite faces of the box: across x (5 cm) or y (7 cm), never z (12 cm: wider than the stroke).
    c1 = np.array(table.column("contact1").to_pylist())
    c2 = np.array(table.column("contact2").to_pylist())
    half = np.asarray(BOX) / 2
    opposite = np.isclose(np.abs(c1), half, atol=1e-6) & np.isclose(c1, -c2, atol=1e-6)
    assert opposite[:, :2].any(axis=1).all() and not opposite[:, 2].any()
    width = table.column("width").to_numpy()
    # A checker built here from the scene file alone gives the same codes: free rows are free.
    path, records = box_scene
    scene = read_scene(path)
    checker = CollisionChecker(scene_spec(scene, records, visual=False), load_gripper(GRIPPER))
    poses = np.array(table.column("pose_world").to_pylist()).reshape(-1, 4, 4)
    assert np.array_equal(checker.check(poses, width, object_body_name(0, "box")), codes)


@pytest.mark.parametrize("share", [0.0, 0.2, 0.5])
def test_collision_share_is_respected_and_the_counts_add_up(box_scene, share):
    table, meta = run(box_scene, max_per_object=8, collision_share=share, reach=ReachParams(enabled=False))
    codes = table.column("prefilter_code").to_numpy()
    cap = collision_cap(share / (1 - share), 8)
    o = meta["objects"][0]
    assert (codes >= 0).sum() == o["kept"]["collisions"] <= cap
    assert (codes == -1).sum() == o["kept"]["free"] == 8
    if o["prefilter"]["collision_with_ground"] + o["prefilter"]["collision_with_target"] >= cap:
        assert o["kept"]["collisions"] == cap  # collisions are kept until the cap, not fewer
    checked = sum(o["prefilter"].values())
    assert o["tried"] == checked + sum(o["unreachable"].values()) and sum(o["unreachable"].values()) == 0
    assert meta["tried"] == o["tried"] and meta["grasps"] == len(table)


def test_keep_rejected_false_keeps_only_free_candidates(box_scene):
    table, _ = run(box_scene, max_per_object=6, keep_rejected=False)
    assert (table.column("prefilter_code").to_numpy() == -1).all() and len(table) == 6


def test_a_budget_too_small_stops_with_one_warning_saying_how_far_it_got(box_scene):
    table, meta = run(box_scene, max_per_object=40, max_candidates=20, batch_size=8)
    o = meta["objects"][0]
    assert o["stopped"] == "max_candidates" and o["tried"] == 20 and o["kept"]["free"] < 40
    codes = table.column("prefilter_code").to_numpy()
    assert (codes >= 0).sum() == o["kept"]["collisions"] <= collision_cap(0.25, (codes == -1).sum())
    assert meta["warnings"] == [f"object 'box': {o['kept']['free']} of 40 collision-free grasp candidates after 20 "
                                "tried (grasps.max_candidates)"]


def test_an_object_wider_than_the_stroke_gives_one_warning_and_no_rows(tmp_path):
    can = trimesh.creation.cylinder(radius=0.051, height=0.12, sections=48)  # 102 mm across, 85 mm stroke
    path = write_scene(tmp_path / "scene.h5", ["can", "box"], [on_table(0.12), on_table(BOX[2], x=0.2)])
    records = {"can": record("can", can, 0.12), "box": record("box", trimesh.creation.box(BOX), BOX[2])}
    table, meta = run((path, records), max_per_object=4)
    assert set(table.column("object_name").to_pylist()) == {"box"}
    assert len(meta["warnings"]) == 1 and "cannot grasp object 'can': it is 102 mm across" in meta["warnings"][0]
    can_meta = meta["objects"][0]
    assert can_meta["wide"] and can_meta["kept"] == {"free": 0, "collisions": 0}


def test_same_seed_same_bytes_other_seed_other_table(box_scene):
    def parquet_bytes(table):
        sink = io.BytesIO()
        pq.write_table(table, sink)
        return sink.getvalue()

    a, meta_a = run(box_scene, seed=5, max_per_object=6)
    b, meta_b = run(box_scene, seed=5, max_per_object=6)
    c, _ = run(box_scene, seed=6, max_per_object=6)
    assert parquet_bytes(a) == parquet_bytes(b) and meta_a == meta_b
    assert parquet_bytes(a) != parquet_bytes(c)


def down_grasp(z_contacts: float, depth: float, height: float = BOX[2]) -> tuple[np.ndarray, np.ndarray]:
    """A grasp straight down across the box's 5 cm faces, contacts at height ``z_contacts`` above the table, the
    TCP ``depth`` behind them: (pose in the object frame, pose in the world)."""
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # closing along x, approach along -z (down)
    T[:3, 3] = (0.0, 0.0, z_contacts - height / 2 + depth)
    return T, on_table(height) @ T


def test_reach_screen_on_analytic_cases():
    gripper = load_gripper(GRIPPER)
    mesh = trimesh.creation.box(BOX)
    points = surface_points(mesh.vertices, mesh.faces, 2048, np.random.default_rng(0))
    boxes = clearance_boxes(gripper, 17)
    cases = {
        "near the top": (down_grasp(BOX[2] - 0.012, 0.0), -1),  # pads straddle the top, palm above it: reachable
        "deep in the box": (down_grasp(BOX[2] - 0.06, 0.0), 1),  # the palm and knuckles would be inside the box
        "tips in the table": (down_grasp(0.004, 0.0, height=0.03), 0),  # a 3 cm box: 19 mm of pad below contacts
    }
    for name, ((T_obj, T_world), expected) in cases.items():
        height = 0.03 if name == "tips in the table" else BOX[2]
        pts = points if height == BOX[2] else surface_points(*_box_vf((BOX[0], BOX[1], 0.03)), 2048,
                                                            np.random.default_rng(0))
        T_world = on_table(height) @ T_obj
        ok, why = reachable(T_obj[None], T_world[None], np.array([0.05]), pts, boxes, gripper, 0.02, 0.05,
                            ReachParams())
        assert why[0] == expected, name
        assert ok[0] == (expected == -1), name


def _box_vf(extents):
    m = trimesh.creation.box(extents)
    return m.vertices, m.faces


def test_settings_are_checked():
    with pytest.raises(SettingsError, match="collision_share"):
        GraspsParams(collision_share=1.0)
    with pytest.raises(SettingsError, match="max_candidates"):
        GraspsParams(max_candidates=0)
    with pytest.raises(SettingsError, match="tolerance"):
        ReachParams(tolerance=-1.0)
    assert collision_cap(0.3, 10) == 3 and collision_cap(0.25, 12 / 0.75 * 0.75) == 3


def test_card_counts_sum_the_shards_per_object():
    from graspgen.io.card_grasps import scene_grasp_counts, scene_grasps_lines

    def entry(name, tried, free, coll, stopped="target"):
        return {"object_name": name, "tried": tried, "unreachable": {"ground": 2, "target": 1},
                "prefilter": {"free": free, "collision_with_ground": 1, "collision_with_target": 3,
                              "collision_with_clutter": 0}, "kept": {"free": free, "collisions": coll},
                "stopped": stopped}

    metas = [{"objects": [entry("a", 10, 4, 1), entry("b", 7, 2, 0, "max_candidates")]},
             {"objects": [entry("a", 6, 4, 2)]}, {}]
    section = scene_grasp_counts(metas)
    a = section["objects"]["a"]
    assert a["scenes"] == 2 and a["tried"] == 16 and a["kept"] == {"free": 8, "collisions": 3} and a["short"] == 0
    assert a["unreachable"] == {"ground": 4, "target": 2} and a["rejected"]["collision_with_target"] == 6
    assert a["tried_per_kept"] == round(16 / 11, 3)
    assert section["total"]["tried"] == 23 and section["total"]["short"] == 1
    lines = scene_grasps_lines(section)
    assert lines[0] == "## Scene grasps" and any(line.startswith("| a | 2 | 16 | 4 | 2 | 2 | 6 | 0 | 8 | 3 | 0 | 1.5 |")
                                                for line in lines)
    assert scene_grasp_counts([{}]) == {"objects": {}, "total": None} and scene_grasps_lines(None) == []
