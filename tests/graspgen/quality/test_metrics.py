"""Grasp epsilon from pad contacts, and the minimum-friction label, on analytic cases."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from graspgen.geometry.contacts import closing_contacts
from graspgen.grippers import load_gripper
from graspgen.quality.closure import ferrari_canny, force_closure
from graspgen.quality.contact_noise import MetricsParams, contact_noise_draws, contact_robustness, perturb_contacts
from graspgen.quality.epsilon import ObjectGeometry, grasp_epsilon, min_closure_friction, pad_contacts

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


# ------------------------------------------------------------------------------------------------ contact noise

BOX_GEOMETRY = ObjectGeometry(BOX, np.zeros(3), 0.07)
NO_NOISE = dict(contact_position_sigma=0.0, contact_normal_sigma=0.0, friction_sigma=0.0)


@pytest.mark.parametrize("friction", [0.5, 0.3])
def test_zero_noise_gives_the_nominal_labels(friction):
    # a clean box grasp (in closure) and two tilted point contacts needing friction > tan(20 deg) (not at 0.3)
    a = np.deg2rad(20)
    tilted = (np.array([[-0.02, 0, 0], [0.02, 0, 0]]),
              np.array([[np.cos(a), np.sin(a), 0], [-np.cos(a), np.sin(a), 0]]), np.array([0, 1]))
    c = box_contacts()
    for points, normals, finger in [(c.points, c.normals, c.finger), tilted]:
        for delta in (0.0, 0.05):
            params = MetricsParams(num_contact_samples=4, epsilon_delta=delta, **NO_NOISE)
            eps = params.epsilon.epsilon(points, normals, finger, BOX_GEOMETRY, friction)
            draws = contact_noise_draws(np.random.default_rng(7), 1, 4)[0]
            pfc, robust = contact_robustness(points, normals, finger, BOX_GEOMETRY, friction, draws, params)
            assert robust == eps
            assert pfc == (1.0 if eps > delta else 0.0)
    assert grasp_epsilon(*tilted, np.zeros(3), friction=0.3, torque_scale=0.07) == 0  # both kinds were exercised


def test_perturbed_pads_slide_in_their_tangent_plane_and_friction_stays_positive():
    c = box_contacts()
    draws = contact_noise_draws(np.random.default_rng(1), 1, 200)[0]
    for row in draws:
        p, n, mu = perturb_contacts(c.points, c.normals, c.finger, 0.05, row, position_sigma=0.005,
                                    normal_sigma=0.1, friction_sigma=0.1)
        np.testing.assert_allclose(p[:, 0], c.points[:, 0], atol=1e-15)  # box faces x = -/+0.025: no move along x
        for f in (0, 1):  # each pad moves rigidly
            shift = p[c.finger == f] - c.points[c.finger == f]
            np.testing.assert_allclose(shift, shift[:1].repeat(len(shift), 0), atol=1e-15)
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, rtol=1e-12)
        assert mu > 0
    frictions = [perturb_contacts(c.points, c.normals, c.finger, 0.5, row, position_sigma=0, normal_sigma=0,
                                  friction_sigma=0.1)[2] for row in draws]
    assert np.mean(frictions) == pytest.approx(0.5, abs=0.03) and np.std(frictions) == pytest.approx(0.1, rel=0.2)


def test_centre_grasp_is_more_robust_to_contact_noise_than_an_edge_grasp():
    # the box is 12 cm tall: closing at its centre vs 6 cm up (the pads half over its top edge: a smaller patch, a
    # longer moment arm about the centre of mass)
    params = MetricsParams(num_contact_samples=50, epsilon_delta=0.04)
    draws = contact_noise_draws(np.random.default_rng(0), 1, 50)[0]
    centre, edge = box_contacts(), box_contacts(z=0.06)
    pfc_c, rob_c = contact_robustness(centre.points, centre.normals, centre.finger, BOX_GEOMETRY, 0.5, draws, params)
    pfc_e, rob_e = contact_robustness(edge.points, edge.normals, edge.finger, BOX_GEOMETRY, 0.5, draws, params)
    assert pfc_c > pfc_e and rob_c > rob_e > 0


def test_same_rng_same_values():
    c = box_contacts(z=0.03)
    params = MetricsParams()

    def labels(seed):
        draws = contact_noise_draws(np.random.default_rng(seed), 3, params.num_contact_samples)[1]
        return contact_robustness(c.points, c.normals, c.finger, BOX_GEOMETRY, 0.5, draws, params)

    assert labels(5) == labels(5)
    assert labels(5) != labels(6)
