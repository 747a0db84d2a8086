"""The project's config schema: the shipped configs load, and settings that must agree across stages are checked."""

from __future__ import annotations

import pytest

from pipeline.config import load_config
from pipeline.errors import ConfigError
from stages.config import Config
from tests.paths import REPO

ROOT = REPO


@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "configs").glob("*.yaml")))
def test_shipped_configs_load(name):
    cfg = load_config(Config, ROOT / "configs" / name, [])
    assert cfg.grasps.prefilter.approach_distance == cfg.rollouts.lift.approach_distance


@pytest.mark.parametrize(
    ("sets", "message"),
    [
        (["grasps.prefilter.approach_distance=0.1"], "grasps.prefilter.approach_distance: must equal "
                                                     "rollouts.lift.approach_distance (0.05)"),
        (["rollouts.lift.width_margin=0.03"], "grasps.prefilter.width_margin: must equal rollouts.lift.width_margin "
                                              "(0.03)"),
        (["grasps.prefilter.width_margin=0.03"], "prefilter.width_margin: must equal sampler.width_margin"),
    ],
)
def test_prefilter_must_check_what_the_rollout_does(sets, message):
    with pytest.raises(ConfigError) as err:
        load_config(Config, None, sets)
    assert message in str(err.value)


def test_changed_together_is_fine():
    sets = ["grasps.prefilter.approach_distance=0.08", "rollouts.lift.approach_distance=0.08"]
    assert load_config(Config, None, sets).rollouts.lift.approach_distance == 0.08
