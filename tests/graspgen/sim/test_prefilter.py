"""Tests of stages/prefilter.py: analytic collision cases and agreement with an independent full MuJoCo check."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from graspgen.geometry import antipodal as A
from graspgen.grippers import load_gripper
from graspgen.sim import prefilter as P
from graspgen.sim.gripper_model import attach_gripper

GRIPPER = load_gripper("robotiq_2f85")
TARGET = "obj/0_box"
NEIGHBOUR = "obj/1_block"
TARGET_EXTENTS = (0.05, 0.07, 0.12)
TARGET_POS = (0.0, 0.0, 0.06)  # resting on the ground
NEIGHBOUR_EXTENTS = (0.06, 0.06, 0.10)
NEIGHBOUR_POS = (0.13, 0.0, 0.05)
DOWN = np.diag([1.0, -1.0, -1.0])  # TCP rotation with the approach axis pointing straight down, x along world x


pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")


def _add_mesh_body(spec: mujoco.MjSpec, name: str, mesh: trimesh.Trimesh, pos) -> None:
    asset = spec.add_mesh()
    asset.name = f"{name}_mesh"
    asset.uservert = mesh.vertices.ravel().tolist()
    asset.userface = mesh.faces.ravel().tolist()
    body = spec.worldbody.add_body()
    body.name = name
    body.pos = list(pos)
    body.add_freejoint()
    geom = body.add_geom()
    geom.type = mujoco.mjtGeom.mjGEOM_MESH
    geom.meshname = asset.name


def _world(*, visual_only: bool = False) -> mujoco.MjSpec:
    """Ground plane, a 5 x 7 x 12 cm target box and a neighbouring block, both as mesh geoms resting on it."""
    spec = mujoco.MjSpec()
    ground = spec.worldbody.add_geom()
    ground.name = "ground"
    ground.type = mujoco.mjtGeom.mjGEOM_PLANE
    ground.size = [1.0, 1.0, 0.1]
    _add_mesh_body(spec, TARGET, trimesh.creation.box(TARGET_EXTENTS), TARGET_POS)
    _add_mesh_body(spec, NEIGHBOUR, trimesh.creation.box(NEIGHBOUR_EXTENTS), NEIGHBOUR_POS)
    if visual_only:  # a decoration the gripper must ignore: contype = conaffinity = 0
        deco = spec.worldbody.add_geom()
        deco.name = "support/decoration"
        deco.type = mujoco.mjtGeom.mjGEOM_SPHERE
        deco.size = [0.05, 0, 0]
        deco.pos = [-0.2, 0.0, 0.2]
        deco.contype = 0
        deco.conaffinity = 0
    return spec


def _pose(R, pos) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = pos
    return T


# ---------------------------------------------------------------------------------------------------------------
# Reference: a fresh model per pose, the gripper placed through the MjSpec, mj_forward, every contact listed
# ---------------------------------------------------------------------------------------------------------------


def _reference_codes(world: mujoco.MjSpec, T: np.ndarray, opening: float, target: str, margin: float) -> set[int]:
    """Codes of every gripper contact closer than ``margin`` with the gripper at TCP pose ``T`` opened to ``opening``
    (a finger's contact with the target: closer than ``margin - TARGET_TOUCH_DEPTH``).

    Independent of the checker: the gripper is attached to a frame placed at ``T`` (so the free joint's qpos0 is the
    pose), the jaws are placed by their body positions and joint references in the spec, contacts come from a full
    ``mj_forward`` of the unmodified contact masks, and geoms are classified by walking up the body tree by name.
    """
    spec = world.copy()
    frame = attach_gripper(spec, GRIPPER)  # the attachment frame carries the whole gripper
    frame.pos = list(T[:3, 3])
    xyzw = Rotation.from_matrix(T[:3, :3]).as_quat()
    frame.quat = [xyzw[3], xyzw[0], xyzw[1], xyzw[2]]
    for side, sign in (("left", -1.0), ("right", 1.0)):
        spec.body(f"gripper/{side}_jaw").pos = [sign * opening / 2, 0.0, 0.0]
        spec.joint(f"gripper/{side}_slide").ref = opening / 2
    for geom in spec.geoms:
        if geom.name.startswith("gripper/"):
            geom.margin = max(margin, 0.0)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)

    def root_name(body: int) -> str:
        while model.body_parentid[body] != 0:
            body = model.body_parentid[body]
        return mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, body) or ""

    codes = set()
    for i in range(data.ncon):
        con = data.contact[i]
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or "" for g in con.geom]
        is_gripper = [n.startswith("gripper/") for n in names]
        if is_gripper[0] == is_gripper[1] or not con.dist < margin:
            continue
        other = int(con.geom[1] if is_gripper[0] else con.geom[0])
        root = root_name(int(model.geom_bodyid[other]))
        code = 1 if root == target else 2 if root.startswith("obj/") else 0
        # The touch rule: a finger (a jaw's pad or finger link, by name) may press TARGET_TOUCH_DEPTH into the target.
        finger = (names[0] if is_gripper[0] else names[1]).startswith(("gripper/left_", "gripper/right_"))
        if code == 1 and finger and not con.dist < margin - P.TARGET_TOUCH_DEPTH:
            continue
        codes.add(code)
    return codes


def _random_candidates(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """TCP poses around the target (some through the table, in the neighbour, inside the target, free)."""
    rng = np.random.default_rng(seed)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    T[:, :3, 3] = rng.uniform([-0.12, -0.12, 0.0], [0.2, 0.12, 0.26], (n, 3))
    widths = rng.uniform(0.0, GRIPPER.max_width, n)
    return T, widths


# ---------------------------------------------------------------------------------------------------------------
# Parameters and arguments
# ---------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("key, value", [
    ("approach_distance", -0.01), ("approach_distance", float("inf")), ("num_approach_samples", 0),
    ("num_approach_samples", 1.5), ("margin", float("nan")), ("width_margin", -0.001),
])
def test_params_reject_bad_values_naming_the_key(key, value):
    with pytest.raises(ValueError, match=f"^{key}: "):
        P.PrefilterParams(**{key: value})


def test_approach_offsets_run_from_pre_grasp_to_grasp():
    np.testing.assert_allclose(P.approach_offsets(P.PrefilterParams(approach_distance=0.1, num_approach_samples=3)),
                               [0.1, 0.05, 0.0])
    np.testing.assert_array_equal(P.approach_offsets(P.PrefilterParams(num_approach_samples=1)), [0.0])


def test_bad_arguments():
    checker = P.CollisionChecker(_world(), GRIPPER)
    T = _pose(DOWN, (0.0, 0.0, 0.5))[None]
    with pytest.raises(ValueError, match="^target_body_name: "):
        checker.check(T, [0.05], "obj/9_nothing")
    with pytest.raises(ValueError, match="^target_body_name: "):
        checker.check(T, [0.05], "gripper/base")
    with pytest.raises(ValueError, match="^T_world_tcp: "):
        checker.check(T[0], [0.05], TARGET)
    with pytest.raises(ValueError, match=r"^T_world_tcp\[0\]: the rotation block is not a proper rotation"):
        checker.check(T * 2, [0.05], TARGET)
    with pytest.raises(ValueError, match="^widths: "):
        checker.check(T, [0.05, 0.05], TARGET)
    with pytest.raises(ValueError, match="^world: "):
        P.CollisionChecker("scene.xml", GRIPPER)
    assert checker.check(np.zeros((0, 4, 4)), [], TARGET).shape == (0,)


def test_world_spec_is_not_modified():
    world = _world()
    before = (len(world.bodies), len(world.geoms))
    P.CollisionChecker(world, GRIPPER)
    assert (len(world.bodies), len(world.geoms)) == before


# ---------------------------------------------------------------------------------------------------------------
# Analytic cases
# ---------------------------------------------------------------------------------------------------------------


def test_gripper_through_the_table_hits_the_ground():
    checker = P.CollisionChecker(_world(), GRIPPER, P.PrefilterParams(num_approach_samples=1))
    T = _pose(DOWN, (-0.3, 0.3, 0.01))  # away from both boxes; finger tips 9 mm below the table top
    assert checker.check(T[None], [0.04], TARGET).tolist() == [P.GROUND]
    T = _pose(DOWN, (-0.3, 0.3, 0.025))  # tips 6 mm above the table
    assert checker.check(T[None], [0.04], TARGET).tolist() == [P.FREE]


def test_palm_inside_the_neighbour_is_clutter():
    checker = P.CollisionChecker(_world(), GRIPPER, P.PrefilterParams(num_approach_samples=1))
    # Side approach along world +x, closing along world -z (R_y(90)). The palm (TCP z -0.14 .. -0.075) is centred
    # 0.1075 m behind the TCP: put that at the neighbour's centre. The nearly closed fingers (TCP z -0.075 .. 0.019)
    # then lie at world x 0.1625 .. 0.256, just beyond the neighbour (x 0.10 .. 0.16), and above the table.
    side = Rotation.from_euler("y", 90, degrees=True).as_matrix()
    T = _pose(side, (NEIGHBOUR_POS[0] + 0.1075, 0.0, 0.055))
    assert checker.check(T[None], [0.0], TARGET).tolist() == [P.CLUTTER]
    # 8 cm further back the palm's far end (TCP z -0.14) clears the neighbour's face at x = 0.16.
    T = _pose(side, (NEIGHBOUR_POS[0] + 0.1075 + 0.08, 0.0, 0.055))
    assert checker.check(T[None], [0.0], TARGET).tolist() == [P.FREE]


def test_closed_fingers_inside_the_target_hit_the_target():
    checker = P.CollisionChecker(_world(), GRIPPER, P.PrefilterParams(num_approach_samples=1, width_margin=0.0))
    T = _pose(DOWN, (0.0, 0.0, 0.10))  # pads 2 cm deep into the box's top, closed
    assert checker.check(T[None], [0.0], TARGET).tolist() == [P.TARGET]
    # The same pose named with the neighbour as target: now the box is clutter.
    assert checker.check(T[None], [0.0], NEIGHBOUR).tolist() == [P.CLUTTER]


def test_well_placed_open_gripper_above_a_box_is_free():
    params = P.PrefilterParams(approach_distance=0.1, num_approach_samples=11, width_margin=0.01)
    checker = P.CollisionChecker(_world(), GRIPPER, params)
    top = 2 * TARGET_POS[2]
    # Top-down grasp across the 5 cm side, pads 1.5 cm below the top face, opened to 6 cm.
    T = _pose(DOWN, (0.0, 0.0, top - 0.015))
    codes, steps = checker.check(T[None], [TARGET_EXTENTS[0]], TARGET, return_steps=True)
    assert codes.tolist() == [P.FREE] and steps.tolist() == [-1]
    # Opened too little (3 cm + 1 cm < 5 cm): the pads' tips (TCP z + 0.01875) reach into the box's top face as soon
    # as the TCP is below z = 0.13875, first at the sample 0.03 m before the grasp pose (index 7 of 0.1, 0.09, ...).
    codes, steps = checker.check(T[None], [0.03], TARGET, return_steps=True)
    assert codes.tolist() == [P.TARGET] and steps.tolist() == [7]
    # Rotated 90 degrees about the approach: the 7 cm side does not fit a 6 cm opening.
    T90 = _pose(DOWN @ Rotation.from_euler("z", 90, degrees=True).as_matrix(), (0.0, 0.0, top - 0.015))
    assert checker.check(T90[None], [TARGET_EXTENTS[0]], TARGET).tolist() == [P.TARGET]


def test_collision_along_the_approach_is_reported_at_its_first_pose():
    params = P.PrefilterParams(approach_distance=0.2, num_approach_samples=21)
    checker = P.CollisionChecker(_world(), GRIPPER, params)
    # Side grasp across the target's 7 cm (world y) side at mid-height, approaching along world +x from the free
    # side: columns x = world y, y = z cross x = world z, z = world x.
    from_free_side = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    T = _pose(from_free_side, (0.0, 0.0, 0.06))
    assert checker.check(T[None], [0.07], TARGET).tolist() == [P.FREE]
    # The same grasp approached along world -x: the palm sweeps through the neighbour (x 0.10 .. 0.16) once the TCP
    # is closer than x = 0.085, i.e. from sample 12 of 0.2, 0.19, ...; the grasp pose itself also collides.
    from_neighbour = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    T = _pose(from_neighbour, (0.0, 0.0, 0.06))
    codes, steps = checker.check(T[None], [0.07], TARGET, return_steps=True)
    assert codes.tolist() == [P.CLUTTER] and steps.tolist() == [12]


def test_margin_demands_clearance():
    T = _pose(DOWN, (-0.3, 0.3, 0.025))  # finger tips 6.25 mm above the table
    for margin, expected in ((0.0, P.FREE), (0.005, P.FREE), (0.008, P.GROUND), (-0.01, P.FREE)):
        checker = P.CollisionChecker(_world(), GRIPPER, P.PrefilterParams(num_approach_samples=1, margin=margin))
        assert checker.check(T[None], [0.04], TARGET).tolist() == [expected], margin
    T = _pose(DOWN, (-0.3, 0.3, 0.015))  # tips 3.75 mm into the table: tolerated only with margin < -3.75 mm
    for margin, expected in ((0.0, P.GROUND), (-0.003, P.GROUND), (-0.005, P.FREE)):
        checker = P.CollisionChecker(_world(), GRIPPER, P.PrefilterParams(num_approach_samples=1, margin=margin))
        assert checker.check(T[None], [0.04], TARGET).tolist() == [expected], margin


def test_supports_nested_object_bodies_and_a_pre_attached_gripper():
    """A ``support/...`` box is ground, a child body of an ``obj/`` body is that object, and a world that already
    holds the gripper is used as it is."""
    world = _world()
    table = world.worldbody.add_geom()
    table.name = "support/table"
    table.type = mujoco.mjtGeom.mjGEOM_BOX
    table.size = [0.1, 0.1, 0.01]
    table.pos = [-0.3, -0.3, 0.01]
    handle = world.body(NEIGHBOUR).add_body()
    handle.name = "obj/1_block/handle"
    handle.pos = [0.0, 0.1, 0.0]
    knob = handle.add_geom()
    knob.type = mujoco.mjtGeom.mjGEOM_SPHERE
    knob.size = [0.02, 0, 0]
    attach_gripper(world, GRIPPER)
    checker = P.CollisionChecker(world, GRIPPER, P.PrefilterParams(num_approach_samples=1))
    assert checker.model.nbody == mujoco.MjSpec.compile(_world()).nbody + 4 + 1  # one gripper, one handle
    on_table = _pose(DOWN, (-0.3, -0.3, 0.035))  # tips 3.75 mm into the 2 cm table top
    on_knob = _pose(DOWN, (NEIGHBOUR_POS[0], 0.1, NEIGHBOUR_POS[2] + 0.03))  # tips into the knob
    codes = checker.check(np.stack([on_table, on_knob]), [0.0, 0.0], TARGET)
    assert codes.tolist() == [P.GROUND, P.CLUTTER]
    assert checker.check(on_knob[None], [0.0], "obj/1_block/handle").tolist() == [P.TARGET]
    assert checker.check(on_knob[None], [0.0], NEIGHBOUR).tolist() == [P.TARGET]


def test_visual_only_geoms_are_ignored():
    checker = P.CollisionChecker(_world(visual_only=True), GRIPPER, P.PrefilterParams(num_approach_samples=1))
    T = _pose(DOWN, (-0.2, 0.0, 0.25))  # fingers inside the decoration sphere
    assert checker.check(T[None], [0.04], TARGET).tolist() == [P.FREE]


# ---------------------------------------------------------------------------------------------------------------
# Agreement with a full MuJoCo contact check
# ---------------------------------------------------------------------------------------------------------------


def test_agrees_with_a_full_mujoco_contact_check_on_random_poses():
    world = _world()
    checker = P.CollisionChecker(world, GRIPPER, P.PrefilterParams(num_approach_samples=1))
    T, widths = _random_candidates(240, seed=5)
    codes = checker.check(T, widths, TARGET)
    openings = checker.opening(widths)
    expected = []
    for i in range(len(T)):
        found = _reference_codes(world, T[i], openings[i], TARGET, margin=0.0)
        expected.append(min(found) if found else P.FREE)
    expected = np.array(expected)
    mismatch = np.flatnonzero(codes != expected)
    assert mismatch.size == 0, f"poses {mismatch.tolist()}: checker {codes[mismatch]} vs reference {expected[mismatch]}"
    counts = {code: int(np.sum(expected == code)) for code in (P.FREE, P.GROUND, P.TARGET, P.CLUTTER)}
    assert min(counts.values()) >= 10, counts  # every outcome is exercised


def test_agrees_with_the_reference_along_the_approach_with_a_margin():
    world = _world()
    params = P.PrefilterParams(approach_distance=0.08, num_approach_samples=3, margin=0.004)
    checker = P.CollisionChecker(world, GRIPPER, params)
    T, widths = _random_candidates(60, seed=11)
    codes, steps = checker.check(T, widths, TARGET, return_steps=True)
    openings = checker.opening(widths)
    for i in range(len(T)):
        expected, expected_step = P.FREE, -1
        for k, offset in enumerate(P.approach_offsets(params)):
            Tk = T[i].copy()
            Tk[:3, 3] -= offset * Tk[:3, 2]
            found = _reference_codes(world, Tk, openings[i], TARGET, margin=params.margin)
            if found:
                expected, expected_step = min(found), k
                break
        assert (codes[i], steps[i]) == (expected, expected_step), i


def test_free_antipodal_grasps_on_the_target_exist():
    """End to end: sample on the target in its world pose, pre-filter, and find free top grasps."""
    mesh = trimesh.creation.box(TARGET_EXTENTS)
    pose = _pose(np.eye(3), TARGET_POS)
    cands = A.sample_antipodal(mesh, GRIPPER, A.AntipodalParams(num_surface_points=100, approach="above"),
                               np.random.default_rng(0), object_pose=pose)
    checker = P.CollisionChecker(_world(), GRIPPER)
    codes = checker.check(cands.pose_world, cands.width, TARGET)
    assert np.sum(codes == P.FREE) > 10
    assert set(np.unique(codes)) <= {P.FREE, P.GROUND, P.TARGET, P.CLUTTER}
