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
from graspgen.workflows.evaluate_settings import EvaluateParams
from graspgen.workflows.evaluation_world import evaluation_world
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


#: The 2F-85's inner knuckles, not its pads, close on the slip box (docs/decisions/2026-12-07-2f85-knuckle-slip.md):
#: the 55 mm box reaches 10 mm below the pads' lower ends, the knuckles stop the jaws at 61.6 mm, 0.8 mm short of the
#: pads, and press on the box's palm-side edges through faces tilted 25.7 degrees, which at mu 0.5 hold the box with a
#: margin of 0.017 of their normal force. The tug slides the box out along them; the pads catch it only after
#: 3-4 mm: label -39 %, firm -48 % (studies/mechanics.py; +12 % / +8 % with the knuckles out of collision, as the
#: closed-loop MJCF hand). The URDF's geometry and kinematics, reproduced to 0.02 mm, not a bug: strict, kept visible.
_LINKAGE_SLIP = pytest.mark.xfail(strict=True, reason="the 2F-85 URDF's inner knuckles, not its pads, hold the box's "
                                  "palm-side edges (25.7 deg faces, friction margin 0.017): it slides out under the "
                                  "tug before the pads catch it")


@pytest.mark.parametrize("name", model_gripper_params(marks={"robotiq_2f85_urdf": [_LINKAGE_SLIP]}))
def test_linear_slip_threshold_of_model_grippers_within_10_percent(name, tmp_path):
    r = mechanics.run_case("slip", name, "graspdatagen", cache_dir=tmp_path, rel_tol=0.03)
    assert abs(r.label - r.analytic) <= 0.1 * r.analytic, r
    assert r.analytic == pytest.approx(2 * 0.5 * load_gripper(name).force_limit / 9.81, rel=0.01)


@pytest.mark.parametrize("name", [pytest.param("robotiq_2f85_mesh", id="robotiq_2f85_mesh"),
                                  *model_gripper_params(("robotiq_2f85_urdf",))])
def test_2f85_knuckles_close_on_the_slip_box(name, tmp_path):
    """Pins the cause of the 2F-85 slip xfail: its jaws stop on the box's palm-side edges, on knuckle faces tilted
    ~25.7 degrees from the closing axis that barely hold by friction, with the pads short of the box's faces."""
    mu = mechanics.FRICTION["slip"]
    params = EvaluateParams(lift=mechanics.protocol_params("graspdatagen", "slip"), friction=mu, mass=1.0)
    grasp = np.diag([1.0, -1.0, -1.0, 1.0])  # TCP at the box's centre, closing along x, approach along -z
    world = evaluation_world(mechanics.box_mesh(mechanics.BOX, tmp_path / "box.obj"), 1.0, grasp[None], None, name,
                             params, free_space=True, cache_dir=tmp_path)
    T = world.world.obj.pose @ grasp
    r = world.simulator().rollout(T, float(world.width[0]), world.target_body)
    assert r.closed_width - mechanics.BOX[0] > 1e-3, r.closed_width  # the pads stop > 0.5 mm off each face
    z = ((r.contact_points - T[:3, 3]) @ T[:3, 2])
    assert len(z) and np.all(z < -mechanics.BOX[2] / 2 + 0.002), z  # all at the box's palm-side edges
    cos = np.abs(r.contact_normals @ T[:3, 0])
    margin = mu * cos - np.sqrt(1.0 - cos ** 2)  # friction left when the squeeze alone pushes the box out
    assert np.all((margin > 0.0) & (margin < 0.05)), np.degrees(np.arccos(cos))


#: Light, thin parts: MuJoCo's contact softness is mass-normalised, and at the gripper model's 4 ms time constant a
#: Panda's 70 N squeeze sank the pads through a few-gram plate (a 4 mm plate of 0.6-3.8 g ended with the pads
#: 0.07-0.26 mm apart; an 8 mm one of 1.1 g was squeezed out). ``LiftParams.pad_sink="bounded"`` (the default,
#: graspgen/sim/pad_sink.py) bounds the sink by the pads' impedance width; the light plates below are its cases.
@pytest.mark.parametrize(("thickness", "density"), [
    (0.008, 1000.0), (0.016, 150.0), (0.004, 1000.0), (0.004, 150.0), (0.008, 150.0), (0.002, 150.0)])
def test_face_on_grasp_of_a_plate_holds_firm_with_the_pads_outside_it(thickness, density, tmp_path):
    """A rigid plate squeezed face-on at its centre between parallel pads (mu 1, grip force >> its weight) is in
    force closure with no moment: it must hold, firm, and each pad must stop within its compliance of the plate's
    face (its impedance width, solimp[2] = 1 mm), so the pads never meet inside it."""
    from graspgen.sim.protocols import Outcome
    from graspgen.workflows.evaluate import evaluate_grasps

    mesh = mechanics.box_mesh((thickness, 0.014, 0.067), tmp_path / "plate.obj")
    grasp = np.eye(4)
    grasp[:3, :3] = np.column_stack([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # close along x
    params = dataclasses.replace(EvaluateParams(), density=density, friction=1.0)
    row = evaluate_grasps(mesh, 1.0, grasp[None], np.array([thickness]), "panda", params, protocol="acronym",
                          cache_dir=tmp_path).to_pylist()[0]
    assert row["outcome"] == Outcome.SUCCESS and row["firm"], row
    assert row["closed_width"] > thickness - 2 * 0.001, row["closed_width"]
