"""graspgen.learn.features on analytic cases: a box's points between open pads, hand-computed TCP coordinates."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from graspgen.grippers import load_gripper
from graspgen.learn.features import FeatureParams, closing_volume, grasp_features, hand_boxes, surface_points

PANDA = load_gripper("panda")


def _rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def test_surface_points_lie_on_the_box_and_follow_area():
    box = trimesh.creation.box(extents=(0.1, 0.02, 0.02))
    p = surface_points(box.vertices, box.faces, 4000, np.random.default_rng(0))
    assert p.shape == (4000, 3)
    assert np.all(np.abs(p) <= np.array([0.05, 0.01, 0.01]) + 1e-12)
    on_face = np.isclose(np.abs(p), [0.05, 0.01, 0.01]).any(axis=1)
    assert on_face.all()
    # the two 0.02 x 0.02 end faces hold 0.0008 / 0.0088 of the area
    ends = np.isclose(np.abs(p[:, 0]), 0.05).mean()
    assert abs(ends - 0.0008 / 0.0088) < 0.03
    q = surface_points(box.vertices, box.faces, 4000, np.random.default_rng(0))
    assert np.array_equal(p, q)


def test_closing_volume_is_the_open_pads_box():
    h = closing_volume(PANDA)
    assert np.allclose(h, [PANDA.max_width / 2, PANDA.pad_size[1] / 2, PANDA.pad_size[2] / 2])


def test_inside_flags_are_exactly_the_points_between_the_pads():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-0.06, 0.06, size=(3000, 3))
    R = _rot_z(0.7) @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0.0]])  # some rotation
    t = np.array([0.01, -0.02, 0.03])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    params = FeatureParams(num_surface_points=3000, num_points=3000, hand_points=0, margin=1.0)
    feats, w = grasp_features(pts, T[None], np.array([0.05]), PANDA, params)
    assert feats.shape == (1, 3000, 5) and feats.dtype == np.float32 and w.tolist() == [np.float32(0.05)]
    local = (pts - t) @ R  # hand computed: R^T (p - t) per point
    h = closing_volume(PANDA)
    inside = np.all(np.abs(local) <= h, axis=1)
    # all points kept (K = n, margin 1 m): rows match points up to order; check as sets of rows
    got = feats[0]
    order = np.lexsort(got[:, :3].T)
    lo, hi = hand_boxes(PANDA)[:, 0], hand_boxes(PANDA)[:, 1]
    in_hand = np.any(np.all((local[:, None] >= lo) & (local[:, None] <= hi), axis=2), axis=1)
    want = np.concatenate([local, inside[:, None], in_hand[:, None]], axis=1).astype(np.float32)
    order_w = np.lexsort(want[:, :3].T)
    assert np.allclose(got[order], want[order_w], atol=1e-6)
    assert got[:, 4].sum() == in_hand.sum() > 0
    assert got[:, 3].sum() == inside.sum() > 0


def test_box_grasped_across_its_faces():
    """A 4 cm cube grasped across x at its centre: the points between the pads are those with |y|, |z| under half
    the pad; a grasp 10 cm off the object keeps no point (zero rows)."""
    box = trimesh.creation.box(extents=(0.04, 0.04, 0.04))
    pts = surface_points(box.vertices, box.faces, 2048, np.random.default_rng(2))
    T_on = np.eye(4)
    T_off = np.eye(4)
    T_off[:3, 3] = (0.0, 0.0, 0.2)
    params = FeatureParams(num_points=64, hand_points=0, margin=0.01)
    feats, _ = grasp_features(pts, np.stack([T_on, T_off]), np.array([0.04, 0.08]), PANDA, params)
    h = closing_volume(PANDA)
    truly_inside = np.all(np.abs(pts) <= h, axis=1)
    n_in = int(truly_inside.sum())
    k = min(64, n_in)
    assert feats[0, :k, 3].sum() == k  # nearest first: the inside points come first
    if n_in < 64:
        assert feats[0, :, 3].sum() == n_in
    assert np.all(np.abs(feats[0, feats[0, :, 3] > 0, :3]) <= h + 1e-6)
    assert np.all(feats[1] == 0.0)


def test_ties_are_broken_by_index_and_rows_are_sorted():
    """Ten points inside the volume (distance 0: all tie) and one outside listed first: the K = 4 kept are the
    lowest-index inside points, in index order."""
    h = closing_volume(PANDA)
    pts = np.zeros((11, 3))
    pts[1:, 1] = np.arange(10) * 1e-4  # inside, marked by y
    pts[0] = (0.0, 0.0, h[2] + 0.002)  # 2 mm outside along z
    feats, _ = grasp_features(pts, np.eye(4)[None], np.array([0.01]), PANDA,
                              FeatureParams(num_surface_points=11, num_points=4, hand_points=0))
    assert np.allclose(feats[0, :, 1], [0.0, 1e-4, 2e-4, 3e-4])
    assert feats[0, :, 3].tolist() == [1, 1, 1, 1]
    feats, _ = grasp_features(pts[:3], np.eye(4)[None], np.array([0.01]), PANDA,
                              FeatureParams(num_surface_points=3, num_points=3, hand_points=0))
    assert np.allclose(feats[0, :, 1], [0.0, 1e-4, 0.0]) and feats[0, :, 3].tolist() == [1, 1, 0]
    assert np.isclose(feats[0, 2, 2], h[2] + 0.002)  # the outside point last, within the margin


def test_width_length_is_checked():
    with pytest.raises(ValueError, match="width"):
        grasp_features(np.zeros((100, 3)), np.eye(4)[None], np.array([0.01, 0.02]), PANDA, FeatureParams(
            num_surface_points=100, num_points=8))


def test_hand_boxes_of_the_panda_hand():
    """Fingers: from the open pads' faces (x = +-4 cm) out through the finger link, as wide as the finger, from the
    pad's tip back the finger's length; the palm box as the gripper file gives it."""
    b = hand_boxes(PANDA)
    half, (_, pad_w, pad_l), (fin_t, fin_w, fin_l) = PANDA.max_width / 2, PANDA.pad_size, PANDA.finger_size
    assert b.shape == (2 + len(PANDA.palm_boxes), 2, 3)
    assert np.allclose(b[0], [[half, -max(fin_w, pad_w) / 2, pad_l / 2 - fin_l], [half + fin_t, max(fin_w, pad_w) / 2,
                                                                                   pad_l / 2]])
    assert np.allclose(b[1, 0], -b[0, 1] * [1, 1, 0] + [0, 0, b[0, 0, 2]])
    assert np.allclose(b[1, 1, 0], -half)
    assert np.allclose(b[2], np.stack(PANDA.palm_boxes[0].bounds))


def test_hand_rows_see_a_point_in_the_palm_and_one_in_a_finger():
    """Hand-computed: a point 5 cm behind the TCP (in the palm box), one in the right finger, one 5 mm beside the
    finger (near, not inside), one far away (dropped). The hand rows list them by distance to the hand."""
    half, fin_t = PANDA.max_width / 2, PANDA.finger_size[0]
    palm = (0.0, 0.0, -0.05)
    finger = (half + fin_t / 2, 0.0, 0.0)
    beside = (half + fin_t + 0.005, 0.0, 0.0)
    far = (0.0, 0.3, 0.0)
    pts = np.array([far, beside, finger, palm])
    T = np.eye(4)
    T[:3, 3] = (0.01, 0.02, 0.03)
    feats, _ = grasp_features(pts + T[:3, 3], T[None], np.array([0.02]), PANDA,
                              FeatureParams(num_surface_points=4, num_points=1, hand_points=4, margin=0.01))
    hand = feats[0, 1:]
    assert np.allclose(hand[0], [*finger, 0, 1]) and np.allclose(hand[1], [*palm, 0, 1])  # ties: lower index first
    assert np.allclose(hand[2], [*beside, 0, 0], atol=1e-7)
    assert np.all(hand[3] == 0.0)
    assert feats.shape == (1, 5, 5)
