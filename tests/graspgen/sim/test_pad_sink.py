"""The pads' sink into light objects (graspgen.sim.pad_sink): the steady-depth formula against MuJoCo's own contacts,
and the bounded contact a light object's scene gets."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

from graspgen.grippers import load_gripper
from graspgen.sim import protocols as P
from graspgen.sim.gripper_model import attach_gripper
from graspgen.sim.lift import LiftSimulator
from graspgen.sim.pad_sink import bounded_contact, impedance, steady_sink, time_constant_for_sink
from graspgen.sim.physics import physics_options

pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")

SOLIMP = (0.95, 0.99, 0.001, 0.5, 2.0)


def _ball_on_plane(mass: float, solref, solimp=SOLIMP, radius: float = 0.01) -> mujoco.MjModel:
    xml = f"""<mujoco><option timestep="0.0005" cone="elliptic" impratio="10"/><worldbody>
      <geom type="plane" size="1 1 .1"/>
      <body pos="0 0 {radius}"><freejoint/><geom type="sphere" size="{radius}" mass="{mass}"
        solref="{solref[0]} {solref[1]}" solimp="{' '.join(map(str, solimp))}" solmix="1e6"/></body>
    </worldbody></mujoco>"""
    return mujoco.MjModel.from_xml_string(xml)


@pytest.mark.parametrize(("mass", "solref"), [(1.0, (0.02, 1.0)), (0.001, (0.004, 1.0)), (0.1, (0.01, 0.7))])
def test_steady_sink_is_where_a_resting_ball_comes_to_rest(mass, solref):
    """One contact point pressed by the ball's weight: its depth after settling is the formula's."""
    m = _ball_on_plane(mass, solref)
    d = mujoco.MjData(m)
    mujoco.mj_step(m, d, nstep=20000)  # 10 s: many time constants
    sink = 0.01 - float(d.qpos[2])
    predicted = steady_sink(mass * 9.81, float(m.body_invweight0[1, 0]), solref, SOLIMP)
    assert sink == pytest.approx(predicted, rel=1e-4)


@pytest.mark.parametrize("depth", [0.0001, 0.0004, 0.0007, 0.002])
def test_impedance_is_mujocos_at_the_contacts_depth(depth):
    m = _ball_on_plane(1.0, (0.02, 1.0))
    d = mujoco.MjData(m)
    d.qpos[2] = 0.01 - depth
    mujoco.mj_forward(m, d)
    assert d.ncon == 1
    assert impedance(depth, SOLIMP) == pytest.approx(float(d.efc_KBIP[0, 2]), rel=1e-6)


def test_time_constant_for_sink_inverts_steady_sink():
    for depth in (0.0003, 0.001, 0.003):
        tc = time_constant_for_sink(depth, 70.0, 1400.0, 1.0, SOLIMP)
        assert steady_sink(70.0, 1400.0, (tc, 1.0), SOLIMP) == pytest.approx(depth, rel=1e-6)


def _gripper_and_box(mass: float) -> mujoco.MjModel:
    spec = mujoco.MjSpec()
    physics_options(spec)
    body = spec.worldbody.add_body(name="obj/0_box", pos=[0, 0, 0.5])
    body.add_freejoint()
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.002, 0.007, 0.03], mass=mass)
    attach_gripper(spec, load_gripper("panda"))
    return spec.compile()


def test_a_light_object_gets_a_shorter_time_constant_and_divided_timestep():
    m = _gripper_and_box(0.0007)  # a knife's mass at ACRONYM's 150 kg/m^3
    sim = LiftSimulator(m, P.LiftParams(protocol="acronym"))
    grip = np.flatnonzero(sim.index.geom_is_gripper)
    contact = sim.contact
    assert contact.substeps > 1
    assert sim.model.opt.timestep == pytest.approx(0.002 / contact.substeps)
    assert contact.timeconst >= 2 * sim.model.opt.timestep - 1e-12
    assert np.allclose(sim.model.geom_solref[grip, 0], contact.timeconst)
    assert contact.sink == pytest.approx(SOLIMP[2], rel=1e-6)  # exactly the impedance width
    assert sim.check_interval == P.LiftParams().check_interval * contact.substeps
    assert m.opt.timestep == 0.002  # the caller's model is untouched


def test_a_heavy_object_keeps_the_gripper_models_contact_bit_for_bit():
    m = _gripper_and_box(0.2)
    bounded = LiftSimulator(m, P.LiftParams(protocol="acronym"))
    model = LiftSimulator(m, dataclasses.replace(P.LiftParams(protocol="acronym"), pad_sink="model"))
    assert bounded.contact.substeps == 1 and bounded.contact.sink < SOLIMP[2]
    assert bounded.model.opt.timestep == model.model.opt.timestep == 0.002
    assert np.array_equal(bounded.model.geom_solref, model.model.geom_solref)


def test_pad_sink_model_leaves_a_light_objects_contact_as_the_gripper_has_it():
    m = _gripper_and_box(0.0007)
    sim = LiftSimulator(m, dataclasses.replace(P.LiftParams(protocol="acronym"), pad_sink="model"))
    assert sim.contact.substeps == 1 and sim.model.opt.timestep == 0.002
    assert sim.contact.timeconst == pytest.approx(0.004)


def test_bounded_contact_leaves_a_model_without_objects_alone():
    m = _gripper_and_box(0.001)
    before = m.geom_solref.copy()
    out = bounded_contact(m, np.arange(m.ngeom), np.array([], dtype=np.int64), 70.0)
    assert out.substeps == 1 and np.array_equal(m.geom_solref, before)


def test_pad_sink_rejects_an_unknown_choice():
    with pytest.raises(ValueError, match="pad_sink.*bounded.*model"):
        P.LiftParams(pad_sink="soft")
