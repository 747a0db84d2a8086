"""Mechanics cases against Coulomb friction: the pads' derived torsional friction and the labels where the answer is
known analytically (graspgen/sim/mechanics.py; the full matrix is studies/mechanics.py)."""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import pytest

from graspgen.grippers import GRIPPERS, load_gripper
from graspgen.quality import mechanics_theory
from graspgen.sim.gripper_model import attach_gripper, pad_torsion_arm
from graspgen.workflows import mechanics
from tests.model_grippers import model_gripper_params


@pytest.mark.parametrize("name", [*sorted(GRIPPERS), *model_gripper_params()])
def test_torsion_arm_is_the_mean_distance_of_the_pad_face(name):
    spec = load_gripper(name)
    assert pad_torsion_arm(spec) == pytest.approx(mechanics_theory.torsion_arm(spec), rel=1e-5)


def test_torsion_arm_of_a_square_and_the_panda():
    # mean distance of a square of side s from its centre: s (sqrt(2) + ln(1 + sqrt(2))) / 6 = 0.3826 s
    spec = load_gripper("panda")
    assert pad_torsion_arm(spec) == pytest.approx(0.0067, abs=5e-5)  # 17.4 x 17.6 mm face
    square = dataclasses.replace(spec, pad_size=(0.01, 0.02, 0.02))
    assert pad_torsion_arm(square) == pytest.approx(0.02 * (math.sqrt(2) + math.log(1 + math.sqrt(2))) / 6, rel=1e-9)


def test_pad_torsion_scales_with_each_objects_friction():
    world = mujoco.MjSpec()
    for k, mu in enumerate((0.3, 0.9)):
        body = world.worldbody.add_body(name=f"o{k}", pos=[k, 0, 0])
        body.add_freejoint()
        body.add_geom(name=f"g{k}", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.02] * 3, friction=[mu, 0.005, 1e-4])
    world.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1, 1, 1], friction=[1, 0.005, 0])
    spec = load_gripper("panda")
    attach_gripper(world, spec)
    model = world.compile()
    arm = pad_torsion_arm(spec)

    def friction(name):
        return model.geom_friction[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name)]
    np.testing.assert_allclose(friction("g0")[:2], [0.3, 0.3 * arm])
    np.testing.assert_allclose(friction("g1")[:2], [0.9, 0.9 * arm])
    np.testing.assert_allclose(friction("floor")[:2], [1.0, 0.005])  # static geoms keep theirs
    for side in ("left", "right"):  # 0 on the pads: the object's value is the larger (MuJoCo's rule)
        assert friction(f"gripper/{side}_pad")[1] == 0.0
    assert model.npair == 0


#: Box pads: MuJoCo 4 (multiccd) puts a contact at each corner of the pad face, whose sliding friction alone resists
#: ~24 % more torsion than uniform pressure over the face (measured with gamma = 0), ~35-40 % with the derived gamma:
#: no gamma >= 0 reaches the patch's limit. A known defect of the box-pad contact (assets/grippers/README.md), kept
#: visible: strict, so the test fails once it is fixed and the mark must go.
_BOX_PAD_TORSION = pytest.mark.xfail(strict=True, reason="box pads' corner contacts over-resist torsion")


#: The grippers given as robot models (assets/model_grippers) all have box pads (their URDFs' fingertip boxes, the
#: EGK40's box fingers), so they carry the same mark.
_MODEL_BOX_PADS = {name: [_BOX_PAD_TORSION] for name in ("robotiq_2f85_urdf", "panda_urdf", "schunk_egk40")}


@pytest.mark.parametrize("name", [n if n == "panda" else pytest.param(n, marks=_BOX_PAD_TORSION)
                                  for n in sorted(GRIPPERS)] + model_gripper_params(marks=_MODEL_BOX_PADS))
def test_pivot_threshold_within_10_percent(name, tmp_path):
    r = mechanics.run_case("pivot", name, "graspdatagen", cache_dir=tmp_path, rel_tol=0.03)
    assert math.isfinite(r.firm), r
    assert abs(r.firm - r.analytic) <= 0.1 * r.analytic, r


def test_linear_slip_threshold_within_10_percent(tmp_path):
    r = mechanics.run_case("slip", "panda", "graspdatagen", cache_dir=tmp_path, rel_tol=0.03)
    assert abs(r.label - r.analytic) <= 0.1 * r.analytic, r
    assert r.analytic == pytest.approx(2 * 0.5 * 70.0 / 9.81, rel=0.01)  # 7.1 kg, m g <= 2 mu F


#: The 2F-85's linkage lets the box slip early under the graspdatagen tug (-39 % measured, studies/mechanics.py; the
#: bundled robotiq_2f85_mesh holds nothing of this case at all): kept visible, strict.
_LINKAGE_SLIP = pytest.mark.xfail(strict=True, reason="the 2F-85 linkage slips early under the graspdatagen tug")


@pytest.mark.parametrize("name", model_gripper_params(marks={"robotiq_2f85_urdf": [_LINKAGE_SLIP]}))
def test_linear_slip_threshold_of_model_grippers_within_10_percent(name, tmp_path):
    r = mechanics.run_case("slip", name, "graspdatagen", cache_dir=tmp_path, rel_tol=0.03)
    assert abs(r.label - r.analytic) <= 0.1 * r.analytic, r
    assert r.analytic == pytest.approx(2 * 0.5 * load_gripper(name).force_limit / 9.81, rel=0.01)
