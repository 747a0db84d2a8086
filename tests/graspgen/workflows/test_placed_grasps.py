"""Placed grasps (graspgen.workflows.placed_grasps, stage ``placed_grasps``): object-level grasp sets moved into scenes
and checked against the support and the neighbours, ACRONYM's scene labels, the optional scene re-simulation, same
inputs same bytes, and the stage in the smoke pipeline."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import trimesh

from graspgen.errors import InputError, SettingsError
from graspgen.geometry.antipodal import AntipodalParams, sample_antipodal
from graspgen.grippers import load_gripper
from graspgen.io.arrow import column_array, fixed_list
from graspgen.io.files import write_h5, write_parquet
from graspgen.io.objects import ObjectRecord
from graspgen.io.scenes import read_scene
from graspgen.sim import prefilter as P
from graspgen.sim.protocols import LiftParams
from graspgen.sim.scene_model import scene_spec
from graspgen.sim.support import SupportParams
from graspgen.validation import settings_dict
from graspgen.workflows.evaluate import evaluate_grasps
from graspgen.workflows.placed_grasps import SCHEMA, PlacedGraspsParams, place_object_grasps
from graspgen.workflows.rollouts import scene_simulator
from tests.paths import REPO

GRIPPER = "robotiq_2f85"
BOX = (0.05, 0.07, 0.12)  # target: 5 cm along x, 7 cm along y, 12 cm tall, resting on the table top (z = 0)
BLOCK = (0.04, 0.06, 0.12)  # neighbour, its near face 1 cm beside the target's +x face
BLOCK_X = 0.025 + 0.01 + BLOCK[0] / 2
DOWN_X = np.diag([1.0, -1.0, -1.0])  # approach straight down (-z), closing along x
DOWN_Y = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # approach down, closing along y
UP_X = np.eye(3)  # approach straight up (+z), closing along x


pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")


def box_record(name: str, extents, density: float = 700.0) -> ObjectRecord:
    """A box's object record, exact: one convex part (the box), mass and inertia of a uniform solid, one stable
    pose (resting on its bottom face)."""
    mesh = trimesh.creation.box(extents)
    ex = np.asarray(extents, dtype=float)
    mass = density * float(np.prod(ex))
    inertia = mass / 12 * np.diag([ex[1] ** 2 + ex[2] ** 2, ex[0] ** 2 + ex[2] ** 2, ex[0] ** 2 + ex[1] ** 2])
    rest = np.eye(4)
    rest[2, 3] = ex[2] / 2
    v, f = np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int32)
    return ObjectRecord(name, v, f, [(v, f)], mass, np.zeros(3), inertia, rest[None], np.array([1.0]), {})


def pose(R, p) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T


def write_scene(path: Path, names, poses, scene_id: str = "scene_000000") -> Path:
    """A scene shard as the scenes stage writes it (no cameras), objects at the given mesh-to-world poses."""
    n = len(names)
    tree = {
        "@attrs": {"scene_id": scene_id, "object_names": list(names), "object_keys": ["k"] * n,
                   "support": settings_dict(SupportParams())},
        "objects": {"poses": np.asarray(poses, dtype=np.float64).reshape(n, 4, 4),
                    "friction": np.full(n, 0.5)},
        "cameras": {"@attrs": {"width": 160, "height": 120}, "K": np.zeros((0, 3, 3)),
                    "T_world_camera": np.zeros((0, 4, 4))},
    }
    write_h5(path, tree)
    return path


def object_set(name: str, mesh_path: Path, T_obj: np.ndarray, widths: np.ndarray) -> pa.Table:
    """An object grasp set in the ``object_grasps`` schema, labelled by the ``acronym`` protocol in free space."""
    res = evaluate_grasps(mesh_path, 1.0, T_obj, widths, GRIPPER, protocol="acronym")
    n = len(T_obj)
    outcome = res.column("outcome").to_numpy()
    return pa.table({
        "object_name": pa.array([name] * n, pa.string()),
        "grasp_id": pa.array(np.arange(n, dtype=np.int32)),
        "candidate": pa.array([f"c{i}" for i in range(n)], pa.string()),
        "gripper": pa.array([GRIPPER] * n, pa.string()),
        "protocol": pa.array(["acronym"] * n, pa.string()),
        "pose_object": fixed_list(T_obj.reshape(n, 16), 16),
        "width": pa.array(widths, pa.float64()),
        "open_width": res.column("width"),  # acronym: the opening the protocol used (fully open)
        "outcome": pa.array(outcome, pa.int8()),
        "outcome_name": res.column("outcome_name"),
        "decided_in": res.column("decided_in"),
        "success": pa.array(outcome == 5, pa.bool_()),
        "closed_width": res.column("closed_width"),
    })


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """The box and block records, and the box's grasp set: four hand-made grasps (top across x, top across y,
    from below across x, top across x pushed 7.5 cm deeper: the 2F-85's housing, 7.4 cm behind its TCP,
    enters the box) and 60 antipodal samples, labelled in free space."""
    root = tmp_path_factory.mktemp("placed")
    box, block = box_record("box", BOX), box_record("block", BLOCK)
    mesh = trimesh.Trimesh(box.vertices, box.faces, process=False)
    mesh_path = root / "box.obj"
    mesh.export(mesh_path)
    top = BOX[2] / 2 - 0.015  # TCP 15 mm below the top face, in the object frame
    hand = np.array([pose(DOWN_X, (0, 0, top)), pose(DOWN_Y, (0, 0, top)), pose(UP_X, (0, 0, -top)),
                     pose(DOWN_X, (0, 0, top - 0.075))])
    hand_widths = np.array([BOX[0], BOX[1], BOX[0], BOX[0]])
    cands = sample_antipodal(mesh, load_gripper(GRIPPER), AntipodalParams(num_surface_points=64),
                             np.random.default_rng(0))
    pick = np.sort(np.random.default_rng(1).choice(len(cands.width), size=60, replace=False))
    T_obj = np.concatenate([hand, cands.pose_object[pick]])
    widths = np.concatenate([hand_widths, cands.width[pick]])
    table = object_set("box", mesh_path, T_obj, widths)
    return {"root": root, "records": {"box": box, "block": block}, "box": table}


def place(world, scene: Path, params: PlacedGraspsParams | None = None, seed: int = 0):
    sets = {"box": world["box"]}
    return place_object_grasps(scene, world["records"].__getitem__, sets.get, params or PlacedGraspsParams(),
                               np.random.default_rng(seed))


def on_table(record: ObjectRecord, x: float = 0.0, y: float = 0.0) -> np.ndarray:
    T = np.array(record.stable_poses[0])
    T[0, 3], T[1, 3] = x, y
    return T


@pytest.fixture(scope="module")
def alone(world):
    return write_scene(world["root"] / "alone.h5", ["box"], [on_table(world["records"]["box"])])


@pytest.fixture(scope="module")
def crowded(world):
    r = world["records"]
    return write_scene(world["root"] / "crowded.h5", ["box", "block"],
                       [on_table(r["box"]), on_table(r["block"], x=BLOCK_X)])


# ---------------------------------------------------------------------------------------------------------------
# Analytic cases


def test_free_space_labels_of_the_hand_made_grasps(world):
    """The object-level labels the scene cases rely on: top and bottom grasps hold the box in free space (one is the
    other turned upside down), the deep grasp puts the palm into it."""
    outcome = world["box"].column("outcome").to_numpy()[:4]
    assert list(outcome[:3]) == [5, 5, 5]
    assert outcome[3] == 1  # collision_with_target: judged at object level


def test_top_grasp_free_grasp_from_below_hits_the_support(world, alone):
    table, meta = place(world, alone)
    assert table.schema == SCHEMA and len(table) == len(world["box"]) == meta["grasps"]
    code = table.column("scene_code").to_numpy()
    success = table.column("success").to_numpy(zero_copy_only=False)
    assert list(code[:3]) == [P.FREE, P.FREE, P.GROUND]
    assert list(success[:3]) == [True, True, False]  # from below: a held grasp, but the table is in the way
    # The deep grasp's palm is inside the box: the target is not the scene check's business, the label already says
    assert code[3] == P.FREE and not success[3]
    # Every grasp whose TCP frame has its gripper below the table top is a support collision: the TCP of a grasp
    # approaching upwards sits below z = BOX[2] and its palm further down, at a negative height.
    T = column_array(table, "pose_world", (4, 4))
    palm_z = T[:, 2, 3] - 0.10 * T[:, 2, 2]  # 10 cm back along the approach: well inside the 2F-85's body
    assert (code[palm_z < -0.005] == P.GROUND).all()
    assert meta["scene_codes"]["collision_with_clutter"] == 0  # no neighbour


def test_a_neighbour_across_the_fingers_is_clutter(world, crowded):
    table, meta = place(world, crowded)
    box = table.filter(table.column("object_index").to_numpy() == 0)
    code = box.column("scene_code").to_numpy()
    assert code[0] == P.CLUTTER  # closing along x: the +x finger opens into the block
    assert code[1] == P.FREE  # the same grasp turned 90 degrees closes along y: clear of it
    assert code[2] == P.GROUND
    assert code[3] == P.CLUTTER  # palm in the target, finger in the block: the target does not hide the block
    assert meta["objects_without_grasps"] == ["block"] and len(box) == len(table)


def test_ignore_target_reports_the_clutter_the_target_hid(world, crowded):
    """The checker's option: with the target counted, the deep grasp is a target collision (smallest code wins)."""
    scene = read_scene(crowded)
    checker = P.CollisionChecker(scene_spec(scene, world["records"], visual=False), load_gripper(GRIPPER),
                                 P.PrefilterParams(approach_distance=0.0, num_approach_samples=1, width_margin=0.0))
    T = scene.poses[0] @ column_array(world["box"], "pose_object", (4, 4))[3]
    assert checker.check(T[None], [0.085], "obj/0_box")[0] == P.TARGET
    assert checker.check(T[None], [0.085], "obj/0_box", ignore_target=True)[0] == P.CLUTTER


def test_scene_codes_match_a_world_without_the_target(world, crowded):
    """Independent truth for every row: the code equals the checker's code in the scene with the target deleted
    (the block, named as the target there, reports 1: clutter), and the label is object success and free."""
    table, _ = place(world, crowded)
    scene = read_scene(crowded)
    spec = scene_spec(scene, world["records"], visual=False)
    spec.delete(spec.body("obj/0_box"))
    checker = P.CollisionChecker(spec, load_gripper(GRIPPER),
                                 P.PrefilterParams(approach_distance=0.0, num_approach_samples=1, width_margin=0.0))
    T = column_array(table, "pose_world", (4, 4))
    ref = checker.check(T, table.column("open_width").to_numpy(), "obj/1_block")
    ref = np.where(ref == P.TARGET, P.CLUTTER, ref)
    code = table.column("scene_code").to_numpy()
    assert (code == ref).all()
    assert {-1, 0, 2} <= set(code.tolist())  # every code occurs, so the comparison means something
    obj = table.column("object_success").to_numpy(zero_copy_only=False)
    assert (table.column("success").to_numpy(zero_copy_only=False) == (obj & (code == P.FREE))).all()
    # The object-level columns are the set's rows, and the world pose is the object pose moved with the box.
    gid = table.column("object_grasp_id").to_numpy()
    src = world["box"]
    assert (gid == np.arange(len(src))).all()
    assert np.array_equal(table.column("object_outcome").to_numpy(), src.column("outcome").to_numpy())
    assert np.allclose(np.linalg.inv(scene.poses[0]) @ T, column_array(src, "pose_object", (4, 4)), atol=1e-12)


def test_a_moved_object_takes_its_grasps_along(world, tmp_path):
    """The box yawed by 90 degrees and shifted: the same codes as in place (nothing else in the scene), the world
    poses are the rotated ones, and the top grasp's TCP is where the box's top is."""
    r = world["records"]
    T = on_table(r["box"], 0.05, -0.03)
    T[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    moved, _ = place(world, write_scene(tmp_path / "moved.h5", ["box"], [T]))
    still, _ = place(world, write_scene(tmp_path / "still.h5", ["box"], [on_table(r["box"])]))
    assert (moved.column("scene_code").to_numpy() == still.column("scene_code").to_numpy()).all()
    top = column_array(moved, "pose_world", (4, 4))[0]
    assert np.allclose(top[:3, 3], [0.05, -0.03, BOX[2] - 0.015], atol=1e-12)
    assert np.allclose(top[:3, 0], [0.0, 1.0, 0.0], atol=1e-12)  # closing along the box's x, now world y


def test_checking_the_approach_only_adds_collisions(world, crowded):
    """With the approach line the grasp pose is still checked (last sample): a collision stays a collision, and
    more grasps can only be lost."""
    base = place(world, crowded)[0].column("scene_code").to_numpy()
    line = place(world, crowded, PlacedGraspsParams(approach_distance=0.05))[0].column("scene_code").to_numpy()
    assert (line[base != P.FREE] != P.FREE).all()
    assert (line == P.FREE).sum() <= (base == P.FREE).sum()


# ---------------------------------------------------------------------------------------------------------------
# Subsample, re-simulation, determinism, errors


def test_max_per_object_is_a_seeded_subsample(world, crowded):
    table, _ = place(world, crowded, PlacedGraspsParams(max_per_object=10), seed=3)
    gid = table.column("object_grasp_id").to_numpy()
    assert len(gid) == 10 and (np.diff(gid) > 0).all() and gid.max() < len(world["box"])
    other, _ = place(world, crowded, PlacedGraspsParams(max_per_object=10), seed=4)
    assert not np.array_equal(gid, other.column("object_grasp_id").to_numpy())


def test_rescene_rolls_out_free_grasps_in_the_scene(world, alone, tmp_path):
    """All free grasps of the lone box re-simulated with the table protocol: the top grasps lift the box (5); the
    table rows agree with the same rollout run independently, and the meta counts follow from the rows."""
    free = int((place(world, alone)[0].column("scene_code").to_numpy() == P.FREE).sum())
    lift = LiftParams()
    table, meta = place(world, alone, PlacedGraspsParams(rescene_check=8), seed=5)
    out = table.column("rescene_outcome").to_numpy()
    done = out >= 0
    assert done.sum() == meta["rescene"]["simulated"] == min(8, free)
    assert (table.column("scene_code").to_numpy()[done] == P.FREE).all()
    rs = table.column("rescene_success")
    assert rs.null_count == len(table) - done.sum()
    assert (np.array(rs.to_pylist())[done] == (out[done] == 5)).all()
    scene, sim = scene_simulator(alone, world["records"].__getitem__, GRIPPER, lift)
    T = column_array(table, "pose_world", (4, 4))
    width = table.column("width").to_numpy()
    for i in np.flatnonzero(done):
        assert sim.rollout(T[i], float(width[i]), "obj/0_box").code == out[i]
    obj = table.column("object_success").to_numpy(zero_copy_only=False)[done]
    r = meta["rescene"]
    assert r["success_to_failure"] == int((obj & (out[done] != 5)).sum())
    assert r["failure_to_success"] == int((~obj & (out[done] == 5)).sum())
    assert r["agree"] == int((obj == (out[done] == 5)).sum())
    # The two hand-made top grasps, drawn or not, lift the box in the scene.
    for i in (0, 1):
        assert sim.rollout(T[i], float(width[i]), "obj/0_box").code == 5


def test_same_inputs_same_bytes(world, crowded, tmp_path):
    params = PlacedGraspsParams(max_per_object=30, rescene_check=2)
    paths = []
    for k in range(2):
        table, _ = place(world, crowded, params, seed=11)
        paths.append(tmp_path / f"t{k}.parquet")
        write_parquet(paths[-1], table)
    assert paths[0].read_bytes() == paths[1].read_bytes()


def test_errors_name_the_setting_and_the_object(world, alone):
    with pytest.raises(SettingsError, match="lift.protocol"):
        PlacedGraspsParams(lift=LiftParams(protocol="acronym"))
    with pytest.raises(SettingsError, match="max_per_object"):
        PlacedGraspsParams(max_per_object=-1)
    bad = world["box"].drop_columns(["open_width"])
    with pytest.raises(InputError, match="'box'.*open_width"):
        place_object_grasps(alone, world["records"].__getitem__, {"box": bad}.get, PlacedGraspsParams(),
                            np.random.default_rng(0))


# ---------------------------------------------------------------------------------------------------------------
# The stage in the smoke pipeline


def test_stage_in_the_smoke_pipeline(tmp_path):
    pytest.importorskip("stages.object_grasps", reason="the object_grasps stage is not there yet")
    from pipeline.config import load_config
    from pipeline.plan import committed
    from pipeline.scheduler import run_pipeline
    from stages.project import PROJECT

    root = REPO
    cfg = load_config(PROJECT.schema, root / "configs" / "smoke.yaml",
                      [f"run.out={tmp_path / 'out'}", f"run.cache_dir={tmp_path / 'cache'}", "run.jobs=1",
                       "placed_grasps.rescene_check=2"])
    reports = run_pipeline(PROJECT, cfg, ["placed_grasps"])
    assert all(r.failed == 0 for r in reports), reports
    out = tmp_path / "out"
    entries = committed(out, "placed_grasps")
    scenes = committed(out, "scenes")
    assert {e.task for e in entries.values()} == {e.task for e in scenes.values()}
    from pipeline.store import stage_dir

    for e in entries.values():
        table = pq.read_table(stage_dir(out, "placed_grasps") / e.file)
        assert table.schema.equals(SCHEMA, check_metadata=False)
        code = table.column("scene_code").to_numpy()
        obj = table.column("object_success").to_numpy(zero_copy_only=False)
        assert (table.column("success").to_numpy(zero_copy_only=False) == (obj & (code == -1))).all()
        assert int((table.column("rescene_outcome").to_numpy() >= 0).sum()) == min(2, int((code == -1).sum()))
        assert e.meta["grasps"] == len(table)

