"""Grasp epsilon from pad contacts, and the minimum-friction label, on analytic cases."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from graspgen.geometry.contacts import closing_contacts
from graspgen.quality.epsilon import grasp_epsilon, min_closure_friction, pad_contacts
from graspgen.quality.wrench import ferrari_canny, force_closure
from graspgen.sim.grippers import load_gripper

GRIPPER = load_gripper("robotiq_2f85")
BOX = trimesh.creation.box((0.05, 0.07, 0.12))


def top_down(x=0.0, z=0.0):
    T = np.eye(4)
    T[:3, 0] = (1.0, 0.0, 0.0)
    T[:3, 2] = (0.0, 0.0, -1.0)
    T[:3, 1] = np.cross(T[:3, 2], T[:3, 0])
    T[:3, 3] = (x, 0.0, z)
    return T


def box_contacts(**pose):
    (c,) = closing_contacts(BOX, top_down(**pose), GRIPPER)
    return c


def test_pad_patch_becomes_one_soft_contact():
    c = box_contacts()
    centroids, normals, gammas = pad_contacts(c.points, c.normals, c.finger, friction=0.5, torsional_friction=0.0)
    np.testing.assert_allclose(centroids, [[-0.025, 0, 0], [0.025, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(normals, [[1, 0, 0], [-1, 0, 0]], atol=1e-12)
    radius = np.hypot(0.45 * GRIPPER.pad_size[1], 0.45 * GRIPPER.pad_size[2])  # corner ray of the 3x3 grid
    np.testing.assert_allclose(gammas, 2 / 3 * 0.5 * radius, rtol=1e-9)


def test_pad_model_equals_soft_finger_epsilon_by_hand():
    c = box_contacts()
    com = np.zeros(3)
    eps = grasp_epsilon(c.points, c.normals, c.finger, com, friction=0.5, torque_scale=0.07)
    _, _, gammas = pad_contacts(c.points, c.normals, c.finger, friction=0.5, torsional_friction=0.0)
    by_hand = ferrari_canny(
        np.array([[-0.025, 0, 0], [0.025, 0, 0]]),
        np.array([[1.0, 0, 0], [-1.0, 0, 0]]),
        com,
        friction=0.5,
        torque_scale=0.07,
        torsional_friction=gammas[0],
    )
    assert eps == pytest.approx(by_hand, rel=1e-12) and eps > 0


def test_points_model_and_pad_model_agree_on_closure():
    c = box_contacts()
    kw = dict(friction=0.5, torque_scale=0.07)
    assert grasp_epsilon(c.points, c.normals, c.finger, np.zeros(3), contact_model="points", **kw) > 0
    assert force_closure(c.points, c.normals, np.zeros(3), **kw)


def test_one_pad_touching_is_not_a_grasp():
    c = box_contacts()
    left = c.finger == 0
    assert grasp_epsilon(c.points[left], c.normals[left], c.finger[left], np.zeros(3), friction=1, torque_scale=1) == 0


def test_off_centre_grasp_has_lower_epsilon():
    # closing 4 cm off the centre of mass: every contact force now has a moment about it, the wrench set is
    # no longer centred on the origin, and the ball that fits inside shrinks
    com = np.zeros(3)
    centre = box_contacts()
    edge = box_contacts(z=0.04)
    kw = dict(friction=0.5, torque_scale=0.07)
    e_centre = grasp_epsilon(centre.points, centre.normals, centre.finger, com, **kw)
    e_edge = grasp_epsilon(edge.points, edge.normals, edge.finger, com, **kw)
    assert 0 < e_edge < e_centre


def test_min_closure_friction_of_tilted_contacts():
    # Two point contacts whose normals are tilted 20 degrees from the line joining them: closure needs
    # friction > tan(20 deg) = 0.364, whatever the torsional friction.
    a = np.deg2rad(20)
    points = np.array([[-0.02, 0, 0], [0.02, 0, 0]])
    normals = np.array([[np.cos(a), np.sin(a), 0], [-np.cos(a), np.sin(a), 0]])
    finger = np.array([0, 1])
    mu = min_closure_friction(
        points, normals, finger, np.zeros(3), [0.1, 0.2, 0.3, 0.4, 0.5], torque_scale=0.05, torsional_friction=0.005
    )
    assert mu == 0.4
    assert np.isnan(
        min_closure_friction(
            points, normals, finger, np.zeros(3), [0.1, 0.3], torque_scale=0.05, torsional_friction=0.005
        )
    )


def test_bad_contact_model():
    c = box_contacts()
    with pytest.raises(ValueError, match="contact_model: must be one of pad, points"):
        grasp_epsilon(c.points, c.normals, c.finger, np.zeros(3), friction=1, torque_scale=1, contact_model="x")
