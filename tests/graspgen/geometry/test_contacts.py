"""Closing the pads onto a mesh: analytic box and sphere cases."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from graspgen.geometry.contacts import LEFT, RIGHT, closing_contacts
from graspgen.grippers import load_gripper

GRIPPER = load_gripper("robotiq_2f85")


def top_down(x=0.0, y=0.0, z=0.0, yaw=0.0):
    """TCP pose approaching straight down (z -> -world z), closing along world x rotated by yaw."""
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, 0] = (c, s, 0.0)
    T[:3, 2] = (0.0, 0.0, -1.0)
    T[:3, 1] = np.cross(T[:3, 2], T[:3, 0])
    T[:3, 3] = (x, y, z)
    return T


def test_box_across_its_faces():
    box = trimesh.creation.box((0.05, 0.07, 0.12))
    (c,) = closing_contacts(box, top_down(), GRIPPER, rays_per_side=3)
    assert c.both_fingers and c.width == pytest.approx(0.05, abs=1e-9)
    left, right = c.finger == LEFT, c.finger == RIGHT
    assert left.sum() == right.sum() == 9  # the whole pad face touches a flat face
    np.testing.assert_allclose(c.points[left, 0], -0.025, atol=1e-9)
    np.testing.assert_allclose(c.points[right, 0], 0.025, atol=1e-9)
    np.testing.assert_allclose(c.normals[left], np.tile([1.0, 0, 0], (9, 1)), atol=1e-12)  # pushing into the box
    np.testing.assert_allclose(c.normals[right], np.tile([-1.0, 0, 0], (9, 1)), atol=1e-12)


def test_box_rotated_gives_the_other_width():
    box = trimesh.creation.box((0.05, 0.07, 0.12))
    (c,) = closing_contacts(box, top_down(yaw=np.pi / 2), GRIPPER)
    assert c.width == pytest.approx(0.07, abs=1e-9)


def test_sphere_touches_once_per_pad_on_the_axis():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.03)
    (c,) = closing_contacts(sphere, top_down(), GRIPPER, rays_per_side=3)
    assert c.both_fingers
    for f in (LEFT, RIGHT):
        pts = c.points[c.finger == f]
        assert len(pts) >= 1
        np.testing.assert_allclose(np.abs(pts[:, 0]), 0.03, atol=2e-3)
        assert np.abs(pts[:, 1:]).max() < 0.005
    assert c.width == pytest.approx(0.06, abs=2e-3)


def test_missing_the_object_and_object_too_wide():
    box = trimesh.creation.box((0.05, 0.07, 0.12))
    (miss,) = closing_contacts(box, top_down(x=0.2), GRIPPER)
    assert not miss.both_fingers and np.isnan(miss.width) and len(miss.points) == 0
    wide = trimesh.creation.box((0.2, 0.07, 0.12))  # wider than the 85 mm opening: pads start inside
    (inside,) = closing_contacts(wide, top_down(), GRIPPER)
    assert not inside.both_fingers


def test_batch_equals_one_by_one():
    box = trimesh.creation.box((0.05, 0.07, 0.12))
    poses = np.stack([top_down(yaw=a, z=dz) for a, dz in [(0.0, 0.0), (0.3, 0.01), (1.2, -0.02)]])
    batch = closing_contacts(box, poses, GRIPPER)
    for T, b in zip(poses, batch):
        (one,) = closing_contacts(box, T, GRIPPER)
        np.testing.assert_array_equal(one.points, b.points)
        assert one.width == b.width


def test_bad_pose_shape():
    with pytest.raises(ValueError, match=r"T_tcp: must have shape \(4, 4\) or \(n, 4, 4\)"):
        closing_contacts(trimesh.creation.box((0.05, 0.05, 0.05)), np.eye(3), GRIPPER)
