"""``object_grasps.backend`` (graspgen/workflows/object_grasps.py, stages/object_grasps.py): the CPU backend keeps
its keys, ``warp`` joins the key, a missing extra stops the run in one line, and (with the warp extra) a box's set
labelled batch by batch on Warp's CPU device keeps the rows the CPU backend keeps."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from graspgen.errors import SettingsError
from graspgen.io.objects import ObjectRecord
from graspgen.sim import simulator as simulator_module
from graspgen.sim.protocols import PROTOCOL_KEYS
from graspgen.sim.warp_backend import WarpParams
from graspgen.workflows.object_grasps import label_object_grasps
from graspgen.workflows.object_grasps_settings import ObjectGraspsParams
from pipeline.config import load_config
from pipeline.keys import canonical_json
from shared_utils.keys import KEY_NAME
from stages import object_grasps as stage_module
from stages.config import Config

pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")

VERSIONS = {"mujoco-warp": "4.0.0", "warp-lang": "1.19.0"}


def _without_backend(section: ObjectGraspsParams) -> str:
    """The section's canonical JSON as it was before ``backend`` and ``warp`` existed (a renamed protocol or key
    hashed as it was named then, :data:`shared_utils.keys.KEY_VALUES`, :data:`~shared_utils.keys.KEY_NAME`)."""
    plain = {f.metadata.get(KEY_NAME, f.name): getattr(section, f.name) for f in dataclasses.fields(section)
             if f.name not in ("backend", "warp")}
    plain["protocol"] = PROTOCOL_KEYS.get(section.protocol, section.protocol)
    return canonical_json(plain)


def test_the_cpu_backend_keeps_the_object_grasps_keys():
    stage = stage_module.ObjectGraspsStage()
    for sets in ([], ["object_grasps.protocol=graspdatagen"], ["object_grasps.warp.nworld=8"]):
        config = load_config(Config, None, sets)
        assert canonical_json(stage.params(config)) == _without_backend(config.object_grasps.library_params())
    default = load_config(Config, None, []).object_grasps  # the dataset stage hashes the section itself
    assert canonical_json(default) == _without_backend(default.library_params())  # overrides: out while unset


def test_the_warp_backend_joins_the_object_grasps_key_and_needs_its_extra(monkeypatch):
    stage = stage_module.ObjectGraspsStage()
    monkeypatch.setattr(simulator_module, "warp_versions", lambda: dict(VERSIONS))
    default = canonical_json(stage.params(load_config(Config, None, [])))
    warp = stage.params(load_config(Config, None, ["object_grasps.backend=warp"]))
    key = canonical_json(warp)
    assert key != default and '"backend":"warp"' in key and '"mujoco-warp":"4.0.0"' in key
    stage.check(warp)
    monkeypatch.setattr(simulator_module, "warp_versions", lambda: None)
    missing = stage.params(load_config(Config, None, ["object_grasps.backend=warp"]))
    with pytest.raises(SettingsError, match=r"object_grasps.backend: 'warp' needs mujoco-warp .*pip install"):
        stage.check(missing)
    with pytest.raises(SettingsError, match="backend"):
        ObjectGraspsParams(backend="gpu")


def _box() -> ObjectRecord:
    """A 40 x 50 x 60 mm box of 500 kg/m^3 centred on its mesh frame (as tests/graspgen/workflows/
    test_object_grasps.py's)."""
    mesh = trimesh.creation.box(extents=[0.04, 0.05, 0.06])
    mesh.density = 500.0
    v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int32)
    return ObjectRecord(name="box", vertices=v, faces=f, convex_parts=[(v, f)], mass=float(mesh.mass),
                        center_of_mass=np.zeros(3), inertia=np.asarray(mesh.moment_inertia),
                        stable_poses=np.eye(4)[None], stable_probabilities=np.ones(1), attrs={})


@pytest.mark.warp
def test_a_box_set_on_the_warp_backend_keeps_the_cpu_backends_rows():
    pytest.importorskip("mujoco_warp")
    box = _box()
    # antipodal candidates only (near misses sit on the edge of the rules by design); the targets stop the loop in
    # the middle of the first batch
    balanced = {"selection": "balanced", "label": "held", "batch_size": 12, "near_miss_fraction": 0.0,
                "max_candidates": 12, "target_positives": 3, "target_negatives": 1}
    natural = {"batch_size": 12, "max_candidates": 12, "target_grasps": 4}  # the default selection
    for settings in (balanced, natural):
        cpu, cpu_meta = label_object_grasps(box, ObjectGraspsParams(**settings), np.random.default_rng(3))
        warp, meta = label_object_grasps(box, ObjectGraspsParams(**settings, backend="warp",
                                                                 warp=WarpParams(device="cpu")),
                                         np.random.default_rng(3))
        assert cpu.column("outcome").to_pylist() == warp.column("outcome").to_pylist()
        assert cpu.column("pose_object").to_pylist() == warp.column("pose_object").to_pylist()
        assert meta["tried"] == cpu_meta["tried"] and meta["stopped"] == cpu_meta["stopped"]
        assert meta["backend"] == "warp" and meta["device_rollouts"] == 12 and "backend" not in cpu_meta
