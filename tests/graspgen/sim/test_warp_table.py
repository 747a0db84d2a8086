"""Tests of the ``table`` protocol on the warp backend (graspgen/sim/warp_table.py): its batched approach and slip
rules against the CPU backend's on the same states, and (with the warp extra) the CPU backend's analytic cases of
``tests/graspgen/sim/test_lift.py`` labelled alike on Warp's CPU device: lifted, fingers in the table at placement
and on the approach, closing on air, pads landing on the target, a palm hitting a neighbour, a frictionless box
slipping out, objects moving during the approach."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from graspgen.sim import lift as L
from graspgen.sim import protocols as P
from graspgen.sim.lift_rules import Drift, live_code
from graspgen.sim.warp_rules import NO_CODE, live_codes, moved_objects, slipped
from tests.graspgen.sim.test_lift import HALF, TABLE_TOP, _top_down, _world

pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")

THIN = {"half": (0.02, 0.01, HALF)}  # thin in y: the fingers pass a close neighbour
TALL = {"half": (0.02, 0.015, 0.06), "xy": (0.0, 0.035)}  # its top 2 cm above the palm at the grasp pose


# ------------------------------------------------------------------------------------ rules against the CPU's


def _placed(model, T, width=2 * HALF, target="obj/0_box"):
    """A CPU simulator with the open hand placed at ``T`` itself (no approach offset), its roles and target."""
    sim = L.LiftSimulator(model)
    target_id, roles, _ = sim.target_roles(target)
    pos, quat = T[:3, 3], np.empty(4)
    mujoco.mju_mat2Quat(quat, T[:3, :3].reshape(-1))
    sim.place(pos, quat, width)
    return sim, roles, target_id


def test_batched_live_codes_are_the_cpu_rule_world_by_world():
    cases = [(_world(), _top_down(z=TABLE_TOP - 0.01), 0),  # fingertips in the table: support
             (_world([THIN, TALL]), _top_down(), 2),  # the palm in the tall neighbour: clutter
             (_world(), _top_down(z=TABLE_TOP + 0.2), None)]  # in the air: nothing
    for model, T, expected in cases:
        sim, roles, _ = _placed(model, T, width=0.04)
        cpu = live_code(sim.data, sim.index.geom_is_gripper, roles, None)
        assert cpu == expected
        geom = sim.data.contact.geom.astype(np.int64)
        # world 0 holds the contacts, world 1 none
        got = live_codes(geom, np.zeros(len(geom), dtype=np.int64), 2, sim.index.geom_is_gripper, roles)
        assert got.tolist() == [NO_CODE if cpu is None else cpu, NO_CODE]


def test_batched_object_motion_and_slip_are_the_cpu_formulas():
    model = _world([{}, {"xy": (0.2, 0.0)}])
    sim = L.LiftSimulator(model)
    target, _, _ = sim.target_roles("obj/0_box")
    sim.place(np.array([0.0, 0.0, 0.8]), np.array([0.0, 1.0, 0.0, 0.0]), 0.08)
    objects = sim.index.objects
    pos0, quat0 = sim.data.xipos[objects].copy(), sim.data.xquat[objects].copy()
    p0, R0 = sim.relative(target)
    d = sim.data
    rng = np.random.default_rng(1)
    seen = set()
    for shift, turn in ((0.0, 0.0), (0.004, 0.0), (0.006, 0.0), (0.0, 0.08), (0.0, 0.1), (0.003, 0.2), (0.03, 0.0),
                        (0.0, 0.6)):
        for b in range(2):  # move each object in turn
            adr = model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"obj/{b}_box/free")]
            sim.place(np.array([0.0, 0.0, 0.8]), np.array([0.0, 1.0, 0.0, 0.0]), 0.08)
            axis = rng.standard_normal(3)
            axis /= np.linalg.norm(axis)
            d.qpos[adr:adr + 3] += shift * axis
            dq = np.empty(4)
            mujoco.mju_axisAngle2Quat(dq, axis, turn)
            mujoco.mju_mulQuat(d.qpos[adr + 3:adr + 7], dq, d.qpos[adr + 3:adr + 7].copy())
            mujoco.mj_kinematics(model, d)
            cpu_moved = sim._moved(pos0, quat0)
            got = moved_objects(d.xipos[objects][None], d.xquat[objects][None], pos0[None], quat0[None],
                                sim._shift2, sim._cos_half_turn)[0]
            assert got.tolist() == cpu_moved.tolist()
            p, R = sim.relative(target)
            cpu_slip = sim._slipped(target, p0, R0, Drift(p0, R0))
            assert slipped(p[None], R[None], p0[None], R0[None], sim._slip2, sim._cos_slip).tolist() == [cpu_slip]
            seen.add((bool(cpu_moved.any()), cpu_slip))
    assert seen == {(False, False), (True, False), (True, True)}  # both sides of both rules were tried


# ------------------------------------------------------------------------------------ on Warp's CPU device


def _both(model, poses, widths, params=None, qpos=None, target="obj/0_box", nworld=None):
    """(CPU results, warp results) of the same grasps."""
    pytest.importorskip("mujoco_warp")
    from graspgen.sim import warp_backend as W

    params = params or P.LiftParams()
    cpu = L.LiftSimulator(model, params, qpos=qpos)
    ref = [cpu.rollout(T, w, target) for T, w in zip(poses, widths)]
    warp = W.WarpLiftSimulator(model, params, W.WarpParams(device="cpu", nworld=nworld or len(poses)), qpos=qpos)
    return ref, warp.rollouts(np.array(poses), target, np.array(widths))


@pytest.mark.warp
def test_table_protocol_cases_are_labelled_alike_on_the_cpu_device():
    poses = [_top_down(), _top_down(z=TABLE_TOP + 0.005), _top_down(z=TABLE_TOP - 0.05), _top_down(x=0.10),
             _top_down()]
    widths = [2 * HALF, 2 * HALF, 2 * HALF, 2 * HALF, 0.0]
    ref, got = _both(_world(), poses, widths)
    # the analytic truth (test_lift.py): lifted; fingertips in the table on the approach / at placement; closing on
    # air; jaws opened to 1 cm landing on the box's top
    expected = [(5, "end"), (0, "approach"), (0, "placement"), (3, "closing"), (1, "approach")]
    assert [(r.code, r.decided_in) for r in ref] == expected
    assert [(r.code, r.decided_in) for r in got] == expected
    check = P.LiftParams().check_interval
    for a, b in zip(ref, got):
        assert abs(a.steps - b.steps) <= check  # the same schedule; closing may stop one check apart (float32)
    assert got[0].firm and got[0].lift_gain == pytest.approx(0.2, abs=2e-3)
    assert got[0].closed_width == pytest.approx(ref[0].closed_width, abs=1e-4)
    assert len(got[0].contact_forces) == len(ref[0].contact_forces) > 0
    assert got[0].motion_shaking_linear == pytest.approx(ref[0].motion_shaking_linear, abs=1e-4)
    assert math.isnan(got[3].lift_gain) and got[3].closed_width == pytest.approx(0.0, abs=1e-3)


@pytest.mark.warp
def test_table_slip_clutter_and_moving_objects_are_labelled_alike_on_the_cpu_device():
    ref, got = _both(_world([{"friction": 1e-3}]), [_top_down()], [2 * HALF])
    assert [(r.code, r.decided_in) for r in ref] == [(r.code, r.decided_in) for r in got] == [(4, "lifting")]
    assert got[0].rel_translation > P.LiftParams().slip_tolerance
    ref, got = _both(_world([THIN, TALL]), [_top_down()], [0.04])
    assert [(r.code, r.decided_in) for r in ref] == [(r.code, r.decided_in) for r in got] == [(2, "approach")]
    model = _world([{}, {"xy": (0.2, 0.0)}])
    for i, code in ((0, P.Outcome.COLLISION_WITH_TARGET), (1, P.Outcome.COLLISION_WITH_CLUTTER)):
        falling = model.qpos0.copy()
        adr = model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"obj/{i}_box/free")]
        falling[adr + 2] += 0.03  # 3 cm in the air: it falls while the gripper approaches
        ref, got = _both(model, [_top_down()], [2 * HALF], qpos=falling)
        assert [(r.code, r.decided_in) for r in ref] == [(r.code, r.decided_in) for r in got] == [(code, "approach")]


@pytest.mark.warp
def test_table_protocol_needs_the_widths():
    pytest.importorskip("mujoco_warp")
    from graspgen.errors import SettingsError
    from graspgen.sim import warp_backend as W

    sim = W.WarpLiftSimulator(_world(), P.LiftParams(), W.WarpParams(device="cpu", nworld=1))
    with pytest.raises(SettingsError, match="widths"):
        sim.rollouts(np.array([_top_down()]), "obj/0_box")
    with pytest.raises(SettingsError, match="widths"):
        sim.rollouts(np.array([_top_down()]), "obj/0_box", [-1.0])
