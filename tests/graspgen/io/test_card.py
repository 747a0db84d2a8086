"""The dataset card (graspgen/io/card_stats.py, card_render.py): label summaries, ranks, the shard-key digest, its
settings and their keys in the dataset section."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from graspgen.errors import SettingsError
from graspgen.io.card_render import keys_digest
from graspgen.io.card_stats import CardSettings, label_summary
from pipeline.config import load_config, to_dict, to_yaml
from pipeline.errors import ConfigError
from pipeline.keys import canonical_json
from stages.dataset import DatasetParams


@dataclasses.dataclass(frozen=True)
class Schema:
    """A config schema of the dataset section alone."""

    dataset: DatasetParams = dataclasses.field(default_factory=DatasetParams)


def test_label_summary_discrete_and_binned():
    s = label_summary(np.array([0.0, 0.25, 0.25, 1.0, np.nan]), bins=4, unit_range=True)
    assert s["n"] == 4 and s["histogram"] == {"values": [0.0, 0.25, 1.0], "counts": [1, 2, 1]}
    s = label_summary(np.linspace(0, 1, 101), bins=4, unit_range=True)
    assert s["histogram"]["edges"] == [0.0, 0.25, 0.5, 0.75, 1.0] and sum(s["histogram"]["counts"]) == 101
    # k/40 fractions: those on an edge go up, never to the neighbour below through rounding
    s = label_summary(np.arange(41) / 40, bins=20, unit_range=True)
    assert s["histogram"]["counts"] == [2] * 19 + [3]
    assert label_summary(np.array([np.nan]), bins=4, unit_range=False) == {"n": 0}


def test_ranks_average_ties_like_scipy():
    from scipy.stats import rankdata

    from graspgen.io.card_stats import _ranks

    rng = np.random.default_rng(0)
    for n in (1, 2, 7, 40):
        x = rng.integers(0, 4, size=n).astype(float)
        np.testing.assert_allclose(_ranks(x), rankdata(x))


def test_keys_digest_is_the_sha256_of_the_engines_canonical_json():
    import hashlib

    from pipeline.keys import canonical_json

    keys = {"scene_000001": "b" * 64, "scene_000000": "a" * 64, "\u00e9": "c"}
    assert keys_digest(keys) == hashlib.sha256(canonical_json(keys).encode()).hexdigest()[:16]
    assert keys_digest({}) == hashlib.sha256(b"{}").hexdigest()[:16]


def test_card_settings_check_their_fields():
    with pytest.raises(SettingsError, match=r"histogram_bins: must be an integer in \[1, 1000\], got 0"):
        CardSettings(histogram_bins=0)
    with pytest.raises(SettingsError, match=r"example_grasps: must be an integer in \[0, inf\), got -1"):
        CardSettings(example_grasps=-1)
    with pytest.raises(SettingsError, match="plots: must be a bool, got 1"):
        CardSettings(plots=1)


def test_the_dataset_section_takes_the_card_keys_at_its_own_level():
    """DatasetParams embeds CardSettings (FLATTEN): the config file, to_dict, the YAML and the key JSON all keep the
    card's keys beside the section's own, as they were before the card had a settings class of its own."""
    cfg = load_config(Schema, None, ["dataset.plots=false", "dataset.histogram_bins=7", "dataset.acronym=false"])
    assert cfg.dataset.card == CardSettings(plots=False, histogram_bins=7) and cfg.dataset.acronym is False
    flat = ["row_group_rows", "acronym", "graspgen", "contact_graspnet", "plots", "histogram_bins", "example_scenes",
            "example_grasps"]
    assert list(to_dict(cfg.dataset)) == flat
    assert [line.split(":")[0] for line in to_yaml(cfg.dataset).splitlines() if not line.startswith("#")] == flat
    assert json.loads(canonical_json(cfg.dataset)) == to_dict(cfg.dataset)
    with pytest.raises(ConfigError, match="dataset.card: unknown key"):
        load_config(Schema, None, ["dataset.card.plots=false"])
    with pytest.raises(ConfigError, match=r"dataset.histogram_bins: must be an integer in \[1, 1000\]"):
        load_config(Schema, None, ["dataset.histogram_bins=0"])


def test_stray_files_are_the_unlisted_files_of_the_dataset_folders(tmp_path):
    from graspgen.io.card import MANAGED, stray_files

    for rel in ("grasps.parquet", "notes.txt", "scenes/a.h5", "scenes/b.h5", "scenes/.hidden", "plots/old.png",
                "acronym/meshes/x.obj", "other/y.txt"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_bytes(b"x")
    (tmp_path / "plots" / "link.png").symlink_to(tmp_path / "notes.txt")
    listed = {"grasps.parquet": {}, "scenes/a.h5": {}}
    # Only the card's folders are scanned (not the top level, not other folders); hidden files stay; a folder
    # inside a managed folder is no stray; a link counts as the file it points to.
    assert "acronym/meshes" in MANAGED
    assert stray_files(tmp_path, listed) == ["scenes/b.h5", "acronym/meshes/x.obj", "plots/link.png",
                                             "plots/old.png"]
    assert stray_files(tmp_path / "nothing", listed) == []


def test_the_scene_grasps_total_counts_scenes_not_object_scene_pairs():
    from graspgen.io.card_grasps import scene_grasp_counts, scene_grasps_lines

    def entry(name):
        return {"object_name": name, "tried": 5, "unreachable": {"ground": 0, "target": 0},
                "prefilter": {"collision_with_ground": 0, "collision_with_target": 0, "collision_with_clutter": 0},
                "kept": {"free": 2, "collisions": 0}, "stopped": "target"}

    section = scene_grasp_counts([{"objects": [entry("a"), entry("b")]}, {"objects": [entry("a")]}, {}])
    assert section["objects"]["a"]["scenes"] == 2 and section["objects"]["b"]["scenes"] == 1
    assert section["total"]["scenes"] == 2 and section["total"]["object_scenes"] == 3
    assert any(line.startswith("| all | 2 | 15 |") for line in scene_grasps_lines(section))
