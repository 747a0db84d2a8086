"""The protocols as objects (graspgen.sim.protocol_phases): one per name, their attributes, the simulator asks them."""

from __future__ import annotations

import dataclasses

import pytest

from graspgen.errors import SettingsError
from graspgen.sim import protocol_phases as PP
from graspgen.sim import protocols as P
from graspgen.sim.lift import LiftSimulator
from tests.graspgen.sim.test_lift import _top_down, _world

pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")


def test_every_protocol_has_one_object_registered_under_its_name():
    assert tuple(PP.ROLLOUT_PROTOCOLS) == P.PROTOCOLS
    for name, protocol in PP.ROLLOUT_PROTOCOLS.items():
        assert isinstance(protocol, PP.RolloutProtocol) and protocol.name == name
        assert PP.protocol_of(name) is protocol is PP.protocol_of(P.LiftParams(protocol=name))


def test_an_unknown_protocol_names_the_choices():
    with pytest.raises(SettingsError, match="protocol: must be one of table, acronym, graspdatagen, got 'flex'"):
        PP.protocol_of("flex")


def test_what_the_outside_asks_of_a_protocol():
    lift = P.LiftParams()
    table, acronym, tugs = (PP.protocol_of(n) for n in P.PROTOCOLS)
    assert (table.free_space, table.lifts) == (False, True)
    assert (acronym.free_space, acronym.lifts) == (True, False) == (tugs.free_space, tugs.lifts)
    assert table.settings(lift) is None
    assert acronym.settings(lift) is lift.acronym and tugs.settings(lift) is lift.graspdatagen
    assert table.calm(lift) == dataclasses.replace(lift, shake=False)
    assert acronym.calm(lift).acronym.shake_amplitude == 0.0 == acronym.calm(lift).acronym.shake_angle
    assert tugs.calm(lift) is lift  # nothing to switch off: the tugs are the test
    shake = (lift.shake_amplitude, lift.shake_angle, lift.shake_frequency, lift.shake_cycles)
    assert table.load(lift, 9.81) == PP.Load(9.81, lift.lift_acceleration, shake, 1.0)
    assert acronym.load(lift, 9.81).shake_sign == -1.0 and acronym.load(lift, 9.81).lift_acceleration == 0.0
    assert tugs.load(lift, 9.81) == PP.Load(9.81 * lift.graspdatagen.force_scale, 0.0, None, 1.0)


@pytest.mark.parametrize("name", P.PROTOCOLS)
def test_the_simulator_runs_the_protocol_object_of_its_params(name, monkeypatch):
    sim = LiftSimulator(_world(table=False), P.LiftParams(protocol=name, gravity_until_closed=True))
    assert sim.protocol is PP.protocol_of(name)
    calls = []
    cls = type(sim.protocol)
    monkeypatch.setattr(cls, "rollout", lambda self, *args: calls.append(self.name) or "ran")
    assert sim.rollout(_top_down(z=0.5), 0.05, "obj/0_box") == "ran" and calls == [name]
