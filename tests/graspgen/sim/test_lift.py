"""Tests of stages/lift.py: the grasp-and-lift protocol, its outcome rules, the recorded contacts, determinism."""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import pytest

from graspgen.grippers import load_gripper
from graspgen.sim import lift as L
from graspgen.sim import protocols as P
from graspgen.sim.gripper_model import attach_gripper
from graspgen.sim.motion import trapezoid
from graspgen.sim.physics import physics_options

TABLE_TOP = 0.4  # m
HALF = 0.025  # half side (m) of the default 5 cm target box


pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")


def _world(objects=None, *, table: bool = True, scene_actuator: bool = False,
           gripper: str = "robotiq_2f85") -> mujoco.MjModel:
    """Ground plane + table box ``support/table`` (top at TABLE_TOP) + free boxes ``obj/<i>_box`` + the gripper.

    ``objects``: list of dicts with ``half`` (3 half sizes, m), ``xy`` (m), ``yaw`` (rad), ``mass`` (kg),
    ``friction``; default one 5 cm, 1 kg box at friction 0.5 in the middle. Boxes rest on the table (or float at
    z = 0.5 without it).
    """
    if objects is None:
        objects = [{}]
    spec = mujoco.MjSpec()
    physics_options(spec)
    world = spec.worldbody
    if table:
        world.add_geom(name="ground", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1])
        world.add_geom(name="support/table", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.4, 0.4, TABLE_TOP / 2],
                       pos=[0, 0, TABLE_TOP / 2])
    for i, o in enumerate(objects):
        half = o.get("half", (HALF, HALF, HALF))
        x, y = o.get("xy", (0.0, 0.0))
        z = TABLE_TOP + half[2] if table else 0.5
        yaw = o.get("yaw", 0.0)
        body = world.add_body(name=f"obj/{i}_box", pos=[x, y, z], quat=[math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)])
        body.add_freejoint(name=f"obj/{i}_box/free")
        body.add_geom(name=f"obj/{i}_box/geom", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(half),
                      mass=o.get("mass", 1.0), friction=[o.get("friction", 0.5), 0.005, 0.0001])
    if scene_actuator:  # a scene actuator that exists before the gripper's (ids must be found by name)
        slider = world.add_body(name="slider", pos=[1.0, 1.0, 0.05])
        slider.add_joint(name="slide", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1, 0, 0])
        slider.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.01], mass=0.1)
        act = spec.add_actuator(name="scene_act", target="slide", trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_position(kp=10.0)
    attach_gripper(spec, load_gripper(gripper))
    return spec.compile()


def _top_down(x: float = 0.0, y: float = 0.0, z: float = TABLE_TOP + HALF, yaw: float = 0.0) -> np.ndarray:
    """TCP pose approaching straight down (z = world -z), closing along world x rotated by ``yaw`` about z."""
    c, s = math.cos(yaw), math.sin(yaw)
    T = np.eye(4)
    T[:3, 0] = [c, s, 0.0]  # closing
    T[:3, 2] = [0.0, 0.0, -1.0]  # approach
    T[:3, 1] = np.cross(T[:3, 2], T[:3, 0])
    T[:3, 3] = [x, y, z]
    return T


def _rollout(model, T=None, width: float = 2 * HALF, target: str = "obj/0_box", params=None, **kw):
    return L.LiftSimulator(model, params, **kw).rollout(_top_down() if T is None else T, width, target)


# ------------------------------------------------------------------------------------------------- outcomes


def test_box_grasped_across_its_faces_from_above_is_lifted():
    res = _rollout(_world())
    assert (res.code, res.name, res.decided_in) == (5, "success", "end") and res.success
    assert res.lift_gain == pytest.approx(0.2, abs=2e-3)  # rose with the gripper
    assert res.rel_translation < 1e-3 and res.rel_rotation < 1e-2
    assert res.closed_width == pytest.approx(2 * HALF, abs=1e-3)
    assert res.sim_time == pytest.approx(res.steps * 0.002)
    # Steps at 2 ms, the default shake included: approach 5 cm at 0.5 m/s, 10 m/s^2 (0.05 s ramps, 0.05 s cruise)
    # = 75; lift 20 cm at 0.5 m/s, 5 m/s^2 (0.1 s ramps, 0.3 s cruise) = 250; hold 0.2 s = 100; shake 2 axes x
    # 2 cycles / 4 Hz = 2 x 250: 925 in all, plus closing: the 2F-85 closes 7 -> 5 cm at 0.15 m/s in >= 67 steps,
    # and the jaws are seen to stop within a few check intervals (10 steps) after that.
    assert 925 + 67 <= res.steps <= 925 + 67 + 5 * 10


def test_frictionless_box_slips_out():
    res = _rollout(_world([{"friction": 1e-3}]))
    assert (res.code, res.name) == (4, "slipped_during_lifting")
    assert res.decided_in == "lifting"  # stopped as soon as it slipped, not after the hold
    assert res.rel_translation > P.LiftParams().slip_tolerance
    assert res.steps < _rollout(_world()).steps


def test_default_params_hold_1kg_at_friction_05_and_let_3kg_at_friction_03_slip():
    assert _rollout(_world([{"mass": 1.0, "friction": 0.5}])).code == P.Outcome.SUCCESS
    assert _rollout(_world([{"mass": 3.0, "friction": 0.3}])).code == P.Outcome.SLIPPED_DURING_LIFTING
    # It is the grip force that decides: the 2F-85 model's own 100 N force limit holds the 3 kg box, through the
    # default shake too (Coulomb: 3 kg x (9.81 + 9.9 m/s^2 at the shake's peak) / (2 x 0.3) = 98.6 N).
    held = _rollout(_world([{"mass": 3.0, "friction": 0.3}]), params=P.LiftParams(grip_force=None))
    assert held.code == P.Outcome.SUCCESS


def test_fingers_starting_inside_the_table_is_a_ground_collision():
    model = _world()
    # Pre-grasp 5 cm above the grasp: the pads' tips (1.9 cm below the TCP) are still 1.9 cm inside the table.
    res = _rollout(model, _top_down(z=TABLE_TOP - 0.05))
    assert (res.code, res.name, res.decided_in, res.steps) == (0, "collision_with_ground", "placement", 0)
    # A grasp too deep for the box: the approach starts clear and ends with the fingertips in the table.
    res = _rollout(model, _top_down(z=TABLE_TOP + 0.005))
    assert (res.code, res.decided_in) == (0, "approach")


def test_pads_missing_the_object_establish_no_contact():
    res = _rollout(_world(), _top_down(x=0.10))
    assert (res.code, res.name, res.decided_in) == (3, "no_contact_established", "closing")
    assert res.closed_width == pytest.approx(0.0, abs=1e-3)  # closed fully on air
    assert len(res.contact_forces) == 0


def test_palm_hitting_a_neighbour_is_a_clutter_collision():
    target = {"half": (0.02, 0.01, HALF)}  # thin in y, so the fingers (11 mm half-width) pass a close neighbour
    tall = {"half": (0.02, 0.015, 0.06), "xy": (0.0, 0.035)}  # its top is 2 cm above the palm at the grasp pose
    short = {"half": (0.02, 0.015, 0.03), "xy": (0.0, 0.035)}  # below the palm
    res = _rollout(_world([target, tall]), width=0.04)
    assert (res.code, res.name, res.decided_in) == (2, "collision_with_clutter", "approach")
    assert _rollout(_world([target, short]), width=0.04).code == P.Outcome.SUCCESS


def test_pushing_into_the_target_with_a_narrow_width_is_a_target_collision():
    res = _rollout(_world(), width=0.0)  # jaws open to 1 cm: the pads land on the box's top
    assert (res.code, res.name, res.decided_in) == (1, "collision_with_target", "approach")


def test_a_finger_brushing_the_target_on_the_way_down_is_not_a_collision_by_default():
    # Opened to exactly the box's width (no margin): both pads slide down the box's faces, touching them.
    # (Shifted 1 mm sideways, a pad drags the box past the 5 deg turn limit: that is code 1 either way.)
    T = _top_down(x=0.0001)
    brushing = P.LiftParams(width_margin=0.0)
    res = _rollout(_world(), T, params=brushing)
    assert res.code == 5, res
    strict = P.LiftParams(width_margin=0.0, target_touch_fails=True)
    res = _rollout(_world(), T, params=strict)
    assert (res.code, res.decided_in) == (1, "approach")


def test_target_already_touching_at_pre_grasp_is_decided_at_placement():
    # The pre-grasp pose 5 cm above a grasp 5 cm down into a 15 cm tall box still has the pads on the box.
    model = _world([{"half": (HALF, HALF, 0.075)}])
    res = _rollout(model, _top_down(z=TABLE_TOP + 0.1), width=0.0)
    assert (res.code, res.decided_in, res.steps) == (1, "placement", 0)


def test_objects_moving_during_the_approach_are_collisions_without_contact():
    model = _world([{}, {"xy": (0.2, 0.0)}])
    qpos = model.qpos0.copy()
    sim = L.LiftSimulator(model)
    for i, code in ((0, P.Outcome.COLLISION_WITH_TARGET), (1, P.Outcome.COLLISION_WITH_CLUTTER)):
        falling = qpos.copy()
        adr = model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"obj/{i}_box/free")]
        falling[adr + 2] += 0.03  # 3 cm in the air: it falls while the gripper approaches
        res = L.LiftSimulator(model, qpos=falling).rollout(_top_down(), 2 * HALF, "obj/0_box")
        assert (res.code, res.decided_in) == (code, "approach")
    assert sim.rollout(_top_down(), 2 * HALF, "obj/0_box").code == P.Outcome.SUCCESS


def test_free_space_mode_lifts_a_floating_box_grasped_from_the_side():
    model = _world(table=False)  # no ground, no table: the box floats at z = 0.5
    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]  # approach along world +y, closing along world x
    T[:3, 3] = [0.0, 0.0, 0.5]
    free = P.LiftParams(gravity_until_closed=True)
    res = L.LiftSimulator(model, free).rollout(T, 2 * HALF, "obj/0_box")
    assert (res.code, res.decided_in) == (5, "end"), res
    assert res.lift_gain == pytest.approx(0.2, abs=3e-3)
    # With gravity on from the start the box falls away before the gripper arrives.
    sim = L.LiftSimulator(model)
    assert sim.rollout(T, 2 * HALF, "obj/0_box").code == P.Outcome.COLLISION_WITH_TARGET
    np.testing.assert_array_equal(sim.model.opt.gravity, [0, 0, -9.81])  # gravity restored after every rollout
    sim_free = L.LiftSimulator(model, free)
    assert sim_free.rollout(_top_down(z=0.53), 0.0, "obj/0_box").decided_in == "approach"  # gravity restored too
    np.testing.assert_array_equal(sim_free.model.opt.gravity, [0, 0, -9.81])


def test_shake_keeps_a_firm_grasp_and_costs_steps():
    model = _world()
    # shake=False explicitly: the lift alone, to compare with the default (shaken) rollout.
    plain = _rollout(model, params=P.LiftParams(shake=False))
    shaken = _rollout(model)  # the shake is on by default
    assert P.LiftParams().shake
    assert shaken.code == P.Outcome.SUCCESS and shaken.rel_translation < 2e-3
    n_shake = 2 * round(P.LiftParams().shake_cycles / P.LiftParams().shake_frequency / 0.002)
    assert n_shake == 500  # 2 axes x 2 cycles / 4 Hz = 1 s at 2 ms
    assert shaken.steps == plain.steps + n_shake
    # A weak grip (18 N; the lift needs 14.8 N) survives the plain lift (shake=False explicitly: that is what is
    # tested here) but loses the box in a hard vertical shake (0.03 m at 4 Hz: peak ~2 g, measured 19.9 m/s^2 on the
    # sampled wave; it would need 1 kg x (9.81 + 19.9) / (2 x 0.5) = 30 N).
    weak = P.LiftParams(grip_force=18.0, shake=False)
    assert _rollout(model, params=weak).code == P.Outcome.SUCCESS
    res = _rollout(model, params=dataclasses.replace(weak, shake=True, shake_amplitude=0.03,
                                                     shake_frequency=4.0))
    assert (res.code, res.decided_in) == (4, "shaking")


def test_default_shake_loads_the_grip_with_about_1g_on_top_of_gravity():
    # The default shake peaks at 1.05 x 0.015 m x (2 pi 4 Hz)^2 = 9.9 m/s^2, so by Coulomb the 1 kg box at friction
    # 0.5 needs 1 kg x (9.81 + 9.9) / (2 x 0.5) = 19.7 N per jaw to ride it without sliding (the lift alone: 14.8 N).
    model = _world()
    below, above = 17.0, 22.0  # 0.86x and 1.12x that grip
    plain = _rollout(model, params=P.LiftParams(grip_force=below, shake=False))  # the lift alone (shake off)
    assert plain.code == P.Outcome.SUCCESS and plain.rel_translation < 2e-4
    slid = _rollout(model, params=P.LiftParams(grip_force=below))
    assert slid.motion_shaking_linear > 1e-3  # slides in the hand during the shake (less than slip_tolerance)
    held = _rollout(model, params=P.LiftParams(grip_force=above))
    assert held.code == P.Outcome.SUCCESS and held.motion_shaking_linear < 2e-4


# ------------------------------------------------------------------------------------------------- contacts


def test_contacts_point_into_the_object_with_left_right_labels():
    yaw = 0.3  # box and grasp turned about world z: TCP x is not a world axis
    model = _world([{"yaw": yaw}])
    T = _top_down(yaw=yaw)
    sim = L.LiftSimulator(model)
    res = sim.rollout(T, 2 * HALF, "obj/0_box")
    assert res.code == P.Outcome.SUCCESS
    k = len(res.contact_forces)
    assert k >= 2 and res.contact_points.shape == (k, 3) and res.contact_normals.shape == (k, 3)
    assert res.contact_fingers.dtype == np.int8 and set(res.contact_fingers.tolist()) == {0, 1}
    np.testing.assert_allclose(np.linalg.norm(res.contact_normals, axis=1), 1.0, atol=1e-9)
    centre = np.array([0.0, 0.0, TABLE_TOP + HALF])
    into = np.einsum("ij,ij->i", res.contact_normals, centre - res.contact_points)
    assert (into > 0).all()
    x_tcp = T[:3, 0]
    side = (res.contact_points - T[:3, 3]) @ x_tcp  # left jaw on -x, right jaw on +x
    left, right = res.contact_fingers == 0, res.contact_fingers == 1
    assert (side[left] < 0).all() and (side[right] > 0).all()
    # The left jaw pushes along +x, the right along -x; each presses with the grip force in total.
    np.testing.assert_allclose(res.contact_normals[left] @ x_tcp, 1.0, atol=0.02)
    np.testing.assert_allclose(res.contact_normals[right] @ x_tcp, -1.0, atol=0.02)
    assert (res.contact_forces >= 0).all()
    assert res.contact_forces[left].sum() == pytest.approx(30.0, rel=0.05)
    assert res.contact_forces[right].sum() == pytest.approx(30.0, rel=0.05)


# ------------------------------------------------------------------------------------------------- determinism


def test_same_inputs_give_bit_identical_results_whatever_ran_before():
    model = _world([{}, {"xy": (0.15, 0.0)}])
    sim = L.LiftSimulator(model)
    first = sim.rollout(_top_down(yaw=0.1), 2 * HALF, "obj/0_box")
    assert first.success
    sim.rollout(_top_down(x=0.15), 0.0, "obj/1_box")  # a collision, another target
    sim.rollout(_top_down(x=-0.10), 2 * HALF, "obj/0_box")  # a miss: closes fully
    assert sim.rollout(_top_down(x=0.15), 2 * HALF, "obj/1_box").success  # lifts the other box
    again = sim.rollout(_top_down(yaw=0.1), 2 * HALF, "obj/0_box")
    assert again == first
    assert again.contact_points.tobytes() == first.contact_points.tobytes()
    fresh = L.LiftSimulator(_world([{}, {"xy": (0.15, 0.0)}])).rollout(_top_down(yaw=0.1), 2 * HALF, "obj/0_box")
    assert fresh == first
    other = sim.rollout(_top_down(yaw=0.1 + 1e-6), 2 * HALF, "obj/0_box")
    assert other != first  # equality really compares bits


# ------------------------------------------------------------------------------------------------- API


def test_ids_by_name_and_callers_model_untouched():
    model = _world(scene_actuator=True)
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(model.nu)]
    assert set(names) == {"scene_act", "gripper/width"}
    before = (model.actuator_forcerange.copy(), model.dof_damping.copy(), model.opt.impratio)
    sim = L.LiftSimulator(model)
    assert sim.rollout(_top_down(), 2 * HALF, "obj/0_box").success
    assert sim.object_names == ("obj/0_box", "slider")
    assert sim.data.ctrl[names.index("scene_act")] == 0.0
    np.testing.assert_array_equal(model.actuator_forcerange, before[0])  # the simulator works on a copy
    np.testing.assert_array_equal(model.dof_damping, before[1])
    act = names.index("gripper/width")
    np.testing.assert_array_equal(sim.model.actuator_forcerange[act], [-30.0, 30.0])
    assert sim.closing_speed == pytest.approx(load_gripper("robotiq_2f85").closing_speed)
    assert (sim.min_width, sim.max_width) == (0.0, 0.085) and sim.grip_force == 30.0


def test_other_grippers_work_too():
    for name in ("panda", "box_jaw"):
        assert _rollout(_world(gripper=name)).success, name


def test_observer_sees_every_phase_in_order():
    seen = []
    sim = L.LiftSimulator(_world(), P.LiftParams(shake=True))
    res = sim.rollout(_top_down(), 2 * HALF, "obj/0_box", observer=lambda phase, steps: seen.append((phase, steps)))
    phases = [p for i, (p, _) in enumerate(seen) if i == 0 or seen[i - 1][0] != p]
    assert phases == ["placement", "approach", "closing", "lifting", "holding", "shaking"]
    assert seen[0] == ("placement", 0) and seen[-1][1] == res.steps
    assert all(b[1] - a[1] <= P.LiftParams().check_interval for a, b in zip(seen, seen[1:]))


def test_bad_arguments_name_themselves():
    model = _world()
    sim = L.LiftSimulator(model)
    with pytest.raises(ValueError, match="target_body"):
        sim.rollout(_top_down(), 0.05, "obj/9_nothing")
    with pytest.raises(ValueError, match="target_body"):
        sim.rollout(_top_down(), 0.05, "gripper/base")
    with pytest.raises(ValueError, match="T_world_tcp"):
        sim.rollout(np.diag([1.0, 1.0, -1.0, 1.0]), 0.05, "obj/0_box")  # a reflection
    with pytest.raises(ValueError, match="T_world_tcp"):
        sim.rollout(np.eye(3), 0.05, "obj/0_box")
    with pytest.raises(ValueError, match="width"):
        sim.rollout(_top_down(), -0.01, "obj/0_box")
    with pytest.raises(ValueError, match="qpos"):
        L.LiftSimulator(model, qpos=np.zeros(3))
    with pytest.raises(ValueError, match="model"):
        L.LiftSimulator(model, prefix="hand/")


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"approach_distance": -0.01}, "approach_distance"),
        ({"approach_speed": 0.0}, "approach_speed"),
        ({"grip_force": 0.0}, "grip_force"),
        ({"close_timeout": float("nan")}, "close_timeout"),
        ({"lift_height": "0.2"}, "lift_height"),
        ({"min_lift_fraction": 1.5}, "min_lift_fraction"),
        ({"shake": 1}, "shake"),
        ({"shake_cycles": 0}, "shake_cycles"),
        ({"check_interval": 2.5}, "check_interval"),
        ({"noslip_iterations": -1}, "noslip_iterations"),
        ({"cone": "round"}, "cone"),
        ({"integrator": "verlet"}, "integrator"),
        ({"impratio": 0.5}, "impratio"),
        ({"timestep": 0.0}, "timestep"),
    ],
)
def test_params_validation_names_the_field(change, field):
    with pytest.raises(ValueError, match=field):
        P.LiftParams(**change)


def test_params_and_result_are_frozen_and_plain():
    params = P.LiftParams()
    with pytest.raises(dataclasses.FrozenInstanceError):
        params.lift_height = 0.1  # type: ignore[misc]
    assert params.to_dict()["lift_height"] == 0.2 and params.to_dict()["cone"] == "elliptic"
    res = _rollout(_world())
    with pytest.raises(ValueError):
        res.contact_forces[0] = 1.0  # read-only
    row = res.to_dict()
    assert row["code"] == 5 and isinstance(row["contact_points"], list)
    assert P.OUTCOME_NAMES == ("collision_with_ground", "collision_with_target", "collision_with_clutter",
                               "no_contact_established", "slipped_during_lifting", "success")


def test_trapezoid_profile_is_rest_to_rest_and_bounded():
    dt = 0.002
    for distance, speed, accel in ((0.2, 0.5, 5.0), (0.05, 0.5, 10.0), (0.001, 1.0, 1.0)):
        s = trapezoid(distance, speed, accel, dt)
        assert s[-1] == distance and (np.diff(s) >= 0).all()
        v = np.diff(np.concatenate([[0.0], s])) / dt
        assert v.max() <= speed * (1 + 1e-9)
        assert np.abs(np.diff(np.concatenate([[0.0], v]))).max() / dt <= accel * (1 + 1e-6) + 1e-9
    assert len(trapezoid(0.0, 1.0, 1.0, dt)) == 0
