"""The project's config schema: the shipped configs load, each physical setting is set once (``physics``) and the
stages' rollout settings, the pre-filter's opening and approach are derived from it; former keys name the new."""

from __future__ import annotations

import dataclasses

import pytest

from graspgen.sim.protocols import LiftParams
from pipeline.config import load_config, to_yaml
from pipeline.errors import ConfigError
from stages.config import Config
from tests.paths import REPO

ROOT = REPO


@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "configs").glob("*.yaml")))
def test_shipped_configs_load(name):
    cfg = load_config(Config, ROOT / "configs" / name, [])
    assert cfg.grasps.prefilter.approach_distance == cfg.rollouts.lift.approach_distance
    assert cfg.grasps.prefilter.width_margin == cfg.grasps.sampler.width_margin == cfg.rollouts.lift.width_margin


def test_default_lift_params_are_the_library_defaults():
    """The stages see the LiftParams they saw when each section held a copy (so their keys stay)."""
    cfg = load_config(Config, None, [])
    assert cfg.rollouts.lift == LiftParams() == cfg.placed_grasps.lift
    assert cfg.object_grasps.lift == LiftParams(protocol="acronym")


def test_physics_is_shared_and_overrides_are_per_stage():
    cfg = load_config(Config, None, ["physics.timestep=0.001", "physics.table.grip_force=40",
                                     "physics.acronym.shake_angle=0.1", "rollouts.overrides={grip_force: 50}"])
    assert cfg.rollouts.lift.timestep == cfg.object_grasps.lift.timestep == cfg.placed_grasps.lift.timestep == 0.001
    assert (cfg.rollouts.lift.grip_force, cfg.placed_grasps.lift.grip_force) == (50.0, 40.0)
    assert cfg.object_grasps.lift.acronym.shake_angle == 0.1
    acronym = load_config(Config, None, ["object_grasps.overrides={grip_force: 60, timestep: 0.004}"]).object_grasps
    assert (acronym.lift.acronym.grip_force, acronym.lift.timestep, acronym.lift.grip_force) == (60.0, 0.004, 30.0)


def test_opening_and_approach_are_derived_from_the_rollouts():
    cfg = load_config(Config, None, ["physics.table.width_margin=0.03", "rollouts.overrides={approach_distance: 0.08}"])
    assert cfg.grasps.sampler.width_margin == cfg.grasps.prefilter.width_margin == 0.03
    assert cfg.grasps.prefilter.approach_distance == 0.08 == cfg.rollouts.lift.approach_distance
    assert cfg.placed_grasps.lift.approach_distance == 0.05


@pytest.mark.parametrize(
    ("sets", "message"),
    [
        (["rollouts.lift.timestep=0.001"], "rollouts.lift.timestep: moved to physics.timestep, or "
                                           "rollouts.overrides.timestep for this stage"),
        (["object_grasps.lift.acronym.shake_angle=0.1"], "object_grasps.lift.acronym.shake_angle: moved to "
                                                         "physics.acronym.shake_angle"),
        (["placed_grasps.lift.graspgen.tug_time=1"], "moved to physics.graspdatagen.tug_time"),
        (["rollouts.lift.grip_force=40"], "rollouts.lift.grip_force: moved to physics.table.grip_force"),
        (["object_grasps.lift.protocol=acronym"], "object_grasps.lift.protocol: moved to object_grasps.protocol"),
        (["grasps.prefilter.approach_distance=0.1"], "grasps.prefilter.approach_distance: not a setting: derived "
                                                     "from the rollouts' approach_distance"),
        (["grasps.sampler.width_margin=0.03"], "grasps.sampler.width_margin: not a setting: derived"),
        (["rollouts.overrides={lift_hieght: 1}"], "rollouts.overrides.lift_hieght: unknown key"),
        (["object_grasps.overrides={lift_height: 1}"], "object_grasps.overrides.lift_height: unknown key"),
        (["rollouts.overrides={grip_force: -1}"], "rollouts.overrides.grip_force: must be"),
        (["physics.table.grip_force=-1"], "physics.table.grip_force: must be"),
        (["physics.timestep=0"], "physics.timestep: must be"),
        (["placed_grasps.protocol=acronym"], "placed_grasps.protocol: must be one of table"),
        (["rollouts.protocol=graspgen"], "rollouts.protocol: protocol 'graspgen' was renamed 'graspdatagen'"),
    ],
)
def test_bad_or_former_keys_name_the_key(sets, message):
    with pytest.raises(ConfigError) as err:
        load_config(Config, None, sets)
    assert message in str(err.value)


def test_shown_config_loads_again(tmp_path):
    """What ``gen config show --all`` prints (and the dataset's config.yaml) is a config that loads to the same."""
    cfg = load_config(Config, ROOT / "configs" / "smoke.yaml", ["rollouts.overrides={grip_force: 50}"])
    path = tmp_path / "shown.yaml"
    path.write_text(to_yaml(cfg))
    again = load_config(Config, path, [])
    assert again == cfg
    assert dataclasses.asdict(again.rollouts.lift) == dataclasses.asdict(cfg.rollouts.lift)
