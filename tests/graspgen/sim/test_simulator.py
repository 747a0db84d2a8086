"""The batch-first simulator interface and its one factory (graspgen.sim.simulator)."""

from __future__ import annotations

import numpy as np
import pytest

from graspgen.errors import SettingsError
from graspgen.sim import protocols as P
from graspgen.sim import simulator as S
from graspgen.sim.lift import LiftSimulator
from graspgen.sim.warp_backend import WarpParams
from tests.graspgen.sim.test_lift import HALF, _top_down, _world

pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")


def _grasps():
    """Three grasps on box 0 (held, pads beside it, too narrow) and one on box 1: ``(T (4, 4, 4), widths (4,),
    bodies)``."""
    T = np.array([_top_down(), _top_down(y=0.06), _top_down(), _top_down(x=0.2)])
    return T, np.array([2 * HALF, 2 * HALF, 0.01, 2 * HALF]), ["obj/0_box"] * 3 + ["obj/1_box"]


def test_the_cpu_batch_is_a_loop_of_single_rollouts_bit_for_bit():
    model = _world([{}, {"xy": (0.2, 0.0)}])
    T, widths, bodies = _grasps()
    simulator = S.make_simulator(model)
    assert isinstance(simulator, S.CpuSimulator) and simulator.backend == "mujoco"
    assert isinstance(simulator.cpu, LiftSimulator) and simulator.params == P.LiftParams()
    batch = simulator.rollouts(T, widths, bodies)
    single = LiftSimulator(model)
    loop = [single.rollout(T[i], float(widths[i]), bodies[i]) for i in range(len(T))]
    assert batch == loop  # RolloutResult ==: bit-identical in every field
    assert [r.code for r in batch] == [P.Outcome.SUCCESS, P.Outcome.NO_CONTACT_ESTABLISHED,
                                       P.Outcome.COLLISION_WITH_TARGET, P.Outcome.SUCCESS]
    assert simulator.rollout(T[0], widths[0], bodies[0]) == loop[0]
    assert simulator.meta() == {}


def test_iter_rollouts_stops_when_the_caller_stops():
    simulator = S.make_simulator(_world())
    T, widths, _ = _grasps()
    results = simulator.iter_rollouts(T[:3], widths[:3], "obj/0_box")
    first = next(results)
    assert first.code == P.Outcome.SUCCESS and first.steps > 0
    assert simulator.cpu.steps == first.steps  # the third (decided at placement, 0 steps) has not run


def test_unknown_backend_and_bad_batches_name_the_choices_and_the_argument():
    model = _world()
    with pytest.raises(SettingsError, match="backend: must be one of mujoco, warp, got 'cuda'"):
        S.make_simulator(model, backend="cuda")
    with pytest.raises(SettingsError, match="backend"):
        S.backend_key("cuda", WarpParams())
    simulator = S.make_simulator(model)
    with pytest.raises(SettingsError, match="T_world_tcp"):
        simulator.rollouts(np.eye(4), [0.05], "obj/0_box")
    with pytest.raises(SettingsError, match="widths"):
        simulator.rollouts(np.eye(4)[None], [-1.0], "obj/0_box")
    with pytest.raises(SettingsError, match="target_body"):
        simulator.rollouts(np.eye(4)[None], [0.05], ["obj/0_box"] * 2)


def test_every_backend_has_a_simulator_and_the_cpu_one_runs_every_protocol():
    assert S.BACKENDS == tuple(S.SIMULATORS) == ("mujoco", "warp")
    assert all(issubclass(cls, S.Simulator) and cls.backend == name for name, cls in S.SIMULATORS.items())
    assert [S.check_backend("mujoco", p) for p in P.PROTOCOLS] == ["mujoco"] * len(P.PROTOCOLS)
    assert [S.check_backend("warp", p) for p in P.PROTOCOLS] == ["warp"] * len(P.PROTOCOLS)


def test_the_key_holds_warp_settings_only_for_the_warp_backend(monkeypatch):
    monkeypatch.setattr(S, "warp_versions", lambda: {"mujoco-warp": "1", "warp-lang": "2"})
    mine = WarpParams(nworld=8)
    assert S.backend_key("mujoco", mine) == (WarpParams(), None)
    assert S.backend_key("warp", mine) == (mine, {"mujoco-warp": "1", "warp-lang": "2"})


@pytest.mark.warp
def test_the_warp_simulator_labels_the_batch_as_the_cpu_does():
    pytest.importorskip("mujoco_warp")
    model = _world([{}, {"xy": (0.2, 0.0)}])
    T, widths, bodies = _grasps()
    simulator = S.make_simulator(model, backend="warp", warp=WarpParams(device="cpu", nworld=4))
    assert isinstance(simulator, S.WarpSimulator) and simulator.cpu.params == P.LiftParams()
    got = simulator.rollouts(T, widths, bodies)
    assert [r.code for r in got] == [r.code for r in S.make_simulator(model).rollouts(T, widths, bodies)]
    assert simulator.meta() == {"backend": "warp", "warp": WarpParams(device="cpu", nworld=4).to_dict(),
                                "device_rollouts": 4}
