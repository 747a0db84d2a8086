"""The dataset card (graspgen/io/card.py): label summaries, ranks, the shard-key digest, its settings."""

from __future__ import annotations

import numpy as np
import pytest

from graspgen.errors import SettingsError
from graspgen.io.card import CardSettings, keys_digest, label_summary


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

    from graspgen.io.card import _ranks

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


def test_card_settings_check_like_the_dataset_section():
    with pytest.raises(SettingsError, match=r"histogram_bins: must be in \[1, 1000\], got 0"):
        CardSettings(histogram_bins=0)
    with pytest.raises(SettingsError, match="example_grasps: must be >= 0"):
        CardSettings(example_grasps=-1)
