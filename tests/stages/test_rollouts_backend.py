"""``rollouts.backend`` (stages/rollouts.py, graspgen/workflows/rollouts.py): the CPU backend keeps the keys it had,
``warp`` joins the key with its settings and package versions, a missing extra stops the run in one line, and (with
the warp extra) a scene's grasps table rolled out on Warp's CPU device is labelled as on the CPU."""

from __future__ import annotations

import types

import numpy as np
import pyarrow as pa
import pytest

from graspgen.errors import SettingsError
from graspgen.sim import simulator as simulator_module
from graspgen.sim import warp_backend
from graspgen.sim.simulator import make_simulator
from graspgen.sim.warp_backend import WarpParams
from graspgen.workflows.rollouts import RolloutsParams, roll_out_table, warp_batch
from pipeline.config import load_config
from pipeline.errors import ConfigError
from pipeline.fingerprint import stage_fingerprint
from pipeline.keys import KEY_OMIT_DEFAULT, canonical_json
from stages import rollouts as stage_module
from stages.config import Config
from tests.graspgen.sim.test_lift import HALF, _top_down, _world

pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")

VERSIONS = {"mujoco-warp": "4.0.0", "warp-lang": "1.19.0"}


def test_the_cpu_backend_keeps_the_keys_of_the_section_before_the_backend_existed():
    stage = stage_module.RolloutsStage()
    for sets in ([], ["rollouts.simulate_rejected=true", "rollouts.protocol=acronym"],
                 ["rollouts.backend=mujoco", "rollouts.warp.nworld=8"]):  # warp settings unused by mujoco
        config = load_config(Config, None, sets)
        before = canonical_json({"lift": config.rollouts.lift, "simulate_rejected": config.rollouts.simulate_rejected})
        assert canonical_json(stage.params(config)) == before  # the rollouts stage's key
    # the dataset stage hashes every section: the default section hashes as it did
    default = load_config(Config, None, []).rollouts
    assert canonical_json(default) == canonical_json({"lift": default.lift, "simulate_rejected": False})
    assert warp_backend.KEY_OMIT_DEFAULT == KEY_OMIT_DEFAULT  # the library's copy of the engine's flag


def test_the_warp_backend_its_settings_and_versions_are_in_the_key(monkeypatch):
    monkeypatch.setattr(simulator_module, "warp_versions", lambda: dict(VERSIONS))
    stage = stage_module.RolloutsStage()
    default = canonical_json(stage.params(load_config(Config, None, [])))
    warp = stage.params(load_config(Config, None, ["rollouts.backend=warp", "rollouts.warp.device=cpu"]))
    assert warp.rollouts == RolloutsParams(backend="warp", warp=WarpParams(device="cpu"))
    assert warp.warp_packages == VERSIONS
    key = canonical_json(warp)
    assert key != default and '"backend":"warp"' in key and '"device":"cpu"' in key and '"warp-lang":"1.19.0"' in key
    monkeypatch.setattr(simulator_module, "warp_versions", lambda: {**VERSIONS, "warp-lang": "1.20.0"})
    upgraded = stage.params(load_config(Config, None, ["rollouts.backend=warp", "rollouts.warp.device=cpu"]))
    assert canonical_json(upgraded) != key  # a new Warp re-runs the warp shards


def test_the_warp_packages_never_enter_the_code_fingerprint():
    # the stage imports the warp backend's modules, but not the warp packages by an import statement: with or
    # without the extra installed, the CPU backend's keys are the same
    parts = stage_fingerprint("stages.rollouts")
    assert "code:graspgen/sim/warp_backend.py" in parts
    assert not [k for k in parts if k.startswith("package:") and "warp" in k]


def test_a_bad_backend_is_a_config_error_and_a_missing_extra_stops_the_run(monkeypatch):
    with pytest.raises(ConfigError, match="rollouts.backend: must be one of mujoco, warp"):
        load_config(Config, None, ["rollouts.backend=gpu"])
    with pytest.raises(ConfigError, match="rollouts.warp.nworld"):
        load_config(Config, None, ["rollouts.backend=warp", "rollouts.warp.nworld=0"])
    monkeypatch.setattr(simulator_module, "warp_versions", lambda: None)
    stage = stage_module.RolloutsStage()
    params = stage.params(load_config(Config, None, ["rollouts.backend=warp"]))
    with pytest.raises(SettingsError, match=r"rollouts.backend: 'warp' needs mujoco-warp .*pip install") as err:
        stage.check(params)
    assert "\n" not in str(err.value)
    stage.check(stage.params(load_config(Config, None, [])))  # the CPU backend needs nothing more


def _grasps() -> tuple[types.SimpleNamespace, pa.Table]:
    """A scene of two boxes (0 at the origin, 1 at x = 0.2 m) and its grasps table: lifted, closing on air, a
    pre-filter rejection (not simulated), lifted on the second box: one batch, two objects."""
    poses = [_top_down(), _top_down(x=0.10), _top_down(), _top_down(x=0.2)]
    table = pa.table({
        "scene_id": ["s"] * 4, "grasp_id": pa.array([0, 1, 2, 3], pa.int32()),
        "pose_world": [T.reshape(-1).tolist() for T in poses], "width": [2 * HALF] * 4,
        "prefilter_code": pa.array([-1, -1, 1, -1], pa.int8()), "object_index": pa.array([0, 0, 0, 1], pa.int32()),
    })
    return types.SimpleNamespace(object_names=("box", "box")), table


def test_warp_batch_is_sized_to_the_grasps_simulated():
    _, grasps = _grasps()
    assert warp_batch(grasps, RolloutsParams()).nworld == 3  # the CPU backend ignores it
    assert warp_batch(grasps, RolloutsParams(backend="warp")).nworld == 3  # row 2 is rejected by the pre-filter
    assert warp_batch(grasps, RolloutsParams(backend="warp", simulate_rejected=True)).nworld == 4
    assert warp_batch(grasps, RolloutsParams(backend="warp", warp=WarpParams(nworld=2))).nworld == 2


@pytest.mark.warp
def test_a_grasps_table_on_the_warp_backend_is_labelled_as_on_the_cpu():
    pytest.importorskip("mujoco_warp")
    scene, grasps = _grasps()
    model = _world([{}, {"xy": (0.2, 0.0)}])
    cpu = roll_out_table(scene, make_simulator(model), grasps, RolloutsParams())
    params = RolloutsParams(backend="warp", warp=WarpParams(device="cpu"))
    warp = roll_out_table(scene, make_simulator(model, params.lift, "warp", warp_batch(grasps, params)), grasps,
                          params)
    assert cpu.schema == warp.schema
    assert cpu.column("outcome").to_pylist() == warp.column("outcome").to_pylist() == [5, 3, 1, 5]
    assert warp.column("simulated").to_pylist() == [True, True, False, True]
    assert np.allclose(cpu.column("lift_gain").to_numpy()[[0, 3]], warp.column("lift_gain").to_numpy()[[0, 3]],
                       atol=2e-3)
