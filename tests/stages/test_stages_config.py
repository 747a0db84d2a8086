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
        (["object_grasps.collision_share=0.5"], "object_grasps.collision_share: key 'collision_share' was renamed "
                                                "'collision_share_of_negatives'"),
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


# ------------------------------------------------------------------------------------------- one meaning per key name

OBJECT_GRASPS_KEYS = {
    # params_digest of the object_grasps stage's params when the key was still called collision_share (commit
    # 93320c1): the defaults, and object_grasps.collision_share: 0.5.
    0.25: "3e86f56838a6bdd9d400d2c93331d9e14461877c13dfd13227c540c1abed1156",
    0.5: "9e6bfc41a7e933b3eecf3425643d1554b7c748ffdb6c462c604e72138599b88c",
}


def test_a_user_config_with_the_former_object_grasps_key_names_the_new_one(tmp_path):
    """``object_grasps.collision_share`` (a share of the kept negatives) was renamed; ``grasps.collision_share`` (a
    share of all rows) keeps its name: each name has one meaning."""
    path = tmp_path / "old.yaml"
    path.write_text("object_grasps:\n  collision_share: 0.5\n")
    with pytest.raises(ConfigError) as err:
        load_config(Config, path, [])
    assert str(err.value) == (f"{path}: object_grasps.collision_share: key 'collision_share' was renamed "
                              "'collision_share_of_negatives'")


def test_grasps_collision_share_keeps_its_name():
    cfg = load_config(Config, None, ["grasps.collision_share=0.3", "object_grasps.collision_share_of_negatives=0.5"])
    assert (cfg.grasps.collision_share, cfg.object_grasps.collision_share_of_negatives) == (0.3, 0.5)
    with pytest.raises(ConfigError, match="grasps.collision_share_of_negatives: unknown key"):
        load_config(Config, None, ["grasps.collision_share_of_negatives=0.3"])


@pytest.mark.parametrize("share", sorted(OBJECT_GRASPS_KEYS))
def test_the_rename_keeps_the_object_grasps_key_and_draws(share):
    """The stage's params hash under the former name (content keys and seed keys both hash them): the same digest as
    before the rename, for the default and a set value; the whole-config hash of the ``dataset`` task likewise."""
    from pipeline.keys import canonical_json, params_digest
    from stages.dataset import DatasetStage
    from stages.object_grasps import ObjectGraspsStage

    cfg = load_config(Config, None, [f"object_grasps.collision_share_of_negatives={share}"])
    params = ObjectGraspsStage().params(cfg)
    assert params_digest(params) == OBJECT_GRASPS_KEYS[share]
    assert f'"collision_share":{share}' in canonical_json(params) and "of_negatives" not in canonical_json(params)
    assert "of_negatives" not in canonical_json(DatasetStage().params(cfg))


def test_config_show_writes_each_key_under_its_own_name(tmp_path, monkeypatch):
    """``gen config show`` prints the new name under object_grasps and the kept one under grasps; a file with the
    former key is one error line naming the new key."""
    import yaml
    from typer.testing import CliRunner

    from graspgen_cli.app import app

    monkeypatch.chdir(tmp_path)
    shown = CliRunner().invoke(app, ["config", "show", "--all", "--no-comments"])
    assert shown.exit_code == 0, shown.output
    cfg = yaml.safe_load(shown.output)
    assert cfg["object_grasps"]["collision_share_of_negatives"] == 0.25 and cfg["grasps"]["collision_share"] == 0.2
    assert "collision_share" not in cfg["object_grasps"] and "collision_share_of_negatives" not in cfg["grasps"]
    (tmp_path / "old.yaml").write_text("object_grasps:\n  collision_share: 0.5\n")
    failed = CliRunner().invoke(app, ["config", "show", "--config", "old.yaml"])
    assert failed.exit_code == 2
    assert failed.output.strip() == ("error: old.yaml: object_grasps.collision_share: key 'collision_share' was "
                                     "renamed 'collision_share_of_negatives'")
