"""Tests of the pose helpers: graspgen/geometry/poses.py (numpy) and graspgen/sim/poses_mj.py (MuJoCo's conversions),
against MuJoCo's own quaternion functions and analytic rotations."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from graspgen.errors import SettingsError
from graspgen.geometry.poses import pose_from_pos_mat, quat_mul, rotation_angle, rotation_angles
from graspgen.sim.motion import shake_quats, shake_wave
from graspgen.sim.poses_mj import pos_quat, pose_from_pos_quat


def _unit_quats(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.standard_normal((n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def test_quat_mul_is_mujocos_product_for_one_and_for_many_left_factors():
    rng = np.random.default_rng(0)
    q, Q, r = _unit_quats(rng, 1)[0], _unit_quats(rng, 30), _unit_quats(rng, 30)
    ref_one, ref_rows = np.empty((30, 4)), np.empty((30, 4))
    for i in range(30):
        mujoco.mju_mulQuat(ref_one[i], q, r[i])
        mujoco.mju_mulQuat(ref_rows[i], Q[i], r[i])
    np.testing.assert_allclose(quat_mul(q, r), ref_one, rtol=0, atol=1e-15)
    np.testing.assert_allclose(quat_mul(Q, r), ref_rows, rtol=0, atol=1e-15)
    # one left factor is the same float operations as that factor repeated on every row
    assert quat_mul(q, r).tobytes() == quat_mul(np.repeat(q[None], 30, axis=0), r).tobytes()


def test_rotation_angle_of_known_turns_and_precise_near_zero():
    rng = np.random.default_rng(1)
    for angle in (0.0, 1e-9, 1e-4, 0.3, 2.0, math.pi - 1e-6):
        Ra = pose_from_pos_quat(np.zeros(3), _unit_quats(rng, 1)[0])[:3, :3]
        Rb = Ra @ _rot_x(angle)
        assert rotation_angle(Ra, Rb) == pytest.approx(angle, rel=1e-6, abs=1e-15)
    Ra = np.array([pose_from_pos_quat(np.zeros(3), q)[:3, :3] for q in _unit_quats(rng, 20)])
    Rb = np.array([pose_from_pos_quat(np.zeros(3), q)[:3, :3] for q in _unit_quats(rng, 20)])
    np.testing.assert_allclose(rotation_angles(Ra, Rb), [rotation_angle(a, b) for a, b in zip(Ra, Rb)],
                               rtol=0, atol=1e-14)


def test_pos_quat_and_pose_from_pos_quat_invert_each_other():
    rng = np.random.default_rng(2)
    for q in _unit_quats(rng, 10):
        pos = rng.uniform(-1.0, 1.0, 3)
        T = pose_from_pos_quat(pos, q)
        assert T.shape == (4, 4) and np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0])
        p2, q2 = pos_quat(T, "T")
        assert np.array_equal(p2, pos)
        # a quaternion and its negative are one rotation
        assert min(np.abs(q2 - q).max(), np.abs(q2 + q).max()) < 1e-12
        np.testing.assert_allclose(pose_from_pos_quat(p2, q2), T, rtol=0, atol=1e-15)
        assert pos_quat(T)[1].tobytes() == q2.tobytes()  # unchecked: the same bits


def test_pose_from_pos_mat_takes_mujocos_row_major_layout():
    mat = np.arange(9.0)
    T = pose_from_pos_mat([1.0, 2.0, 3.0], mat)
    np.testing.assert_array_equal(T[:3, :3], mat.reshape(3, 3))
    np.testing.assert_array_equal(T[:3, 3], [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(T[3], [0.0, 0.0, 0.0, 1.0])


def test_pos_quat_checks_the_transform_only_when_named():
    sheared = np.eye(4)
    sheared[0, 1] = 0.5
    with pytest.raises(SettingsError, match=r"^T_tcp: "):
        pos_quat(sheared, "T_tcp")
    pos_quat(sheared)  # unchecked: reads it as it is


def test_shake_quats_turn_about_x_by_the_shake_wave():
    dt = 0.002
    quats = shake_quats(0.15, 4.0, 2, dt)
    angles = shake_wave(0.15, 4.0, 2, dt)
    assert quats.shape == (len(angles), 4)
    for q, angle in zip(quats[::25], angles[::25]):
        R = pose_from_pos_quat(np.zeros(3), q)[:3, :3]
        np.testing.assert_allclose(R, _rot_x(angle), rtol=0, atol=1e-15)
