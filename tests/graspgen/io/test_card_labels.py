"""The card's label statistics in bounded memory (graspgen.io.card_labels): exact below the cap, past it the streamed
figures against numpy on every row, the sampled ones against numpy and scipy on the sample, the sample against a
full sort of the row hashes, whatever the row-group split or the order of merges, and the rows held counted."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import scipy.stats

from graspgen.io.card_labels import LabelTally, Moments, binned_counts, count_quantiles, row_hash
from graspgen.io.card_render import _label_lines
from graspgen.io.card_stats import CORRELATED, LABEL_COLUMNS, QUANTILES, CardSettings, _num, card_stats, label_summary
from graspgen.io.dataset_table import float_values
from graspgen.viz.plots import draw_plots
from tests.graspgen.io.test_dataset_streaming import BINS, dataset  # noqa: F401 - its fixture, shared

LABELS = list(LABEL_COLUMNS)


def _labels_table(rng, n, scenes=7):
    """``n`` rows of a few scenes with the label columns (a discrete robustness, continuous epsilon with NaNs)."""
    sid = np.asarray([f"scene_{i:03d}" for i in rng.integers(0, scenes, n)], dtype=object)
    eps = rng.gamma(2.0, 0.02, n)
    eps[rng.random(n) < 0.1] = np.nan
    return {"scene_id": pa.array(sid.tolist()), "grasp_id": np.arange(n, dtype=np.int64),
            "outcome": rng.integers(0, 6, n).astype(np.int8),
            "robustness": np.where(rng.random(n) < 0.5, rng.integers(0, 6, n) / 5, np.nan), "epsilon": eps}


def _feed(tally, t, bounds):
    """Add table ``t`` to ``tally`` in the row groups ``[a, b)`` of ``bounds``."""
    h = row_hash(t["scene_id"], t["grasp_id"])
    for a, b in zip(bounds[:-1], bounds[1:]):
        tally.add(h[a:b], t["outcome"][a:b], {c: t[c][a:b] for c in ("robustness", "epsilon")})


def test_row_hash_is_a_function_of_the_two_ids_alone():
    sid = pa.chunked_array([pa.array(["a", "b"]), pa.array(["a", "c", None])])
    gid = np.array([0, 0, 1, 0, 0])
    h = row_hash(sid, gid)
    assert h.dtype == np.uint64 and len(set(h.tolist())) == 5
    again = np.concatenate([row_hash(pa.array(["a", "b", "a"]), gid[:3]), row_hash(pa.array(["c", ""]), gid[3:])])
    assert np.array_equal(h, again)  # chunks, batches and a null (read as "") do not matter


@pytest.mark.parametrize("split", [1, 37, 1000, 20_000])
def test_the_sample_is_the_bottom_k_of_the_hashes_whatever_the_split(split):
    rng = np.random.default_rng(3)
    t = _labels_table(rng, 20_000)
    tally = LabelTally(["robustness", "epsilon"], exact_rows=3000, sample_rows=1500)
    _feed(tally, t, [*range(0, 20_000, split), 20_000])
    order = np.argsort(row_hash(t["scene_id"], t["grasp_id"]))[:1500]  # the truth: a full sort
    assert tally.sampled and tally.rows == 20_000
    assert np.array_equal(tally.hashes, row_hash(t["scene_id"], t["grasp_id"])[order])
    for c in ("robustness", "epsilon"):
        assert np.array_equal(tally.values(c), t[c][order], equal_nan=True)
    assert np.array_equal(tally.outcome, t["outcome"][order])


def test_merged_tallies_give_the_sample_of_one_whatever_the_order():
    rng = np.random.default_rng(4)
    t = _labels_table(rng, 12_000)
    one = LabelTally(["robustness", "epsilon"], exact_rows=2000, sample_rows=1000)
    _feed(one, t, [0, 12_000])
    parts = []
    for a, b in ((0, 500), (500, 7000), (7000, 12_000)):  # one exact, two sampled
        part = LabelTally(["robustness", "epsilon"], exact_rows=2000, sample_rows=1000)
        _feed(part, t, [a, b])
        parts.append(part)
    for order in ((0, 1, 2), (2, 0, 1), (1, 2, 0)):
        merged = LabelTally(["robustness", "epsilon"], exact_rows=2000, sample_rows=1000)
        for i in order:
            merged.merge(parts[i])
        assert merged.rows == one.rows and np.array_equal(merged.hashes, one.hashes)
        assert np.array_equal(merged.values("epsilon"), one.values("epsilon"), equal_nan=True)
        assert np.array_equal(merged.pairs, one.pairs)
        assert merged.moments["epsilon"].mean == pytest.approx(one.moments["epsilon"].mean, rel=1e-12)


def test_the_rows_held_stay_bounded_as_the_table_grows():
    """Memory by what the tally holds (not by the clock): at most the cap while exact, twice the sample past it,
    the sample's size at the end; the streamed figures are a fixed number per label."""
    rng = np.random.default_rng(5)
    tally = LabelTally(["robustness", "epsilon"], exact_rows=4000, sample_rows=1000)
    held = []
    for i in range(60):  # 60,000 rows, 15 times the cap
        t = _labels_table(rng, 1000)
        t["grasp_id"] = t["grasp_id"] + 1000 * i
        _feed(tally, t, [0, 1000])
        held.append(tally.held_rows)
        assert tally.held_rows <= 4000 if not tally.sampled else tally.held_rows < 2 * 1000
        assert tally.nbytes <= tally.held_rows * (8 + 1 + 2 * 8)
    assert max(held[10:]) < 2000 and len(tally.values("epsilon")) == 1000
    assert all(m.distinct is None or len(m.distinct) <= 32 for m in tally.moments.values())


def test_below_the_cap_every_row_is_held_in_file_order():
    rng = np.random.default_rng(6)
    t = _labels_table(rng, 3000)
    tally = LabelTally(["robustness", "epsilon"], exact_rows=3000, sample_rows=10)
    _feed(tally, t, [0, 1000, 2999, 3000])
    assert not tally.sampled and np.array_equal(tally.values("epsilon"), t["epsilon"], equal_nan=True)


def test_moments_merged_per_part_equal_numpy_on_all_values():
    rng = np.random.default_rng(8)
    v = rng.normal(3.0, 0.5, 10_000)
    m = Moments()
    for part in np.array_split(v, [1, 2, 500, 501, 7000]):
        m.add(part)
    assert m.n == len(v) and m.mean == pytest.approx(v.mean(), rel=1e-13)
    assert m.std == pytest.approx(v.std(), rel=1e-12) and (m.lo, m.hi) == (v.min(), v.max())
    assert m.distinct is None
    const = Moments()
    for part in np.array_split(np.full(1000, 0.1), 7):
        const.add(part)
    assert const.m2 == 0.0 and const.std == 0.0 and const.distinct == {0.1: 1000}


def test_quantiles_from_value_counts_equal_numpys_of_the_values_spelled_out():
    rng = np.random.default_rng(9)
    for _ in range(50):
        values = np.sort(rng.choice(np.arange(32) / 31, int(rng.integers(1, 32)), replace=False))
        counts = rng.integers(1, 40, len(values))
        qs = [*QUANTILES, 0.0, 1.0, float(rng.random())]
        assert np.array_equal(count_quantiles(values, counts, qs), np.quantile(np.repeat(values, counts), qs))


def test_binned_counts_per_part_equal_the_whole_columns_histogram():
    rng = np.random.default_rng(10)
    v = np.r_[rng.random(5000), np.arange(21) / 20, np.nan]
    whole = label_summary(v, BINS, unit_range=True)["histogram"]["counts"]
    assert binned_counts(np.array_split(v, 9), 0.0, 1.0, BINS).tolist() == whole


def test_past_the_cap_the_card_is_exact_where_it_can_be_and_says_what_is_sampled(dataset):  # noqa: F811
    """Capped at 300 of ~1,400 rows: n, mean, std, min, max, histograms and discrete labels' quantiles against
    numpy on every row; epsilon's quantiles against numpy, the correlations against scipy, on the sample's rows
    (the bottom 200 by a full sort of the hashes); the card says which."""
    root, files = dataset
    stats, table = card_stats(root, files, CardSettings(plots=False, histogram_bins=BINS), exact_rows=300,
                              sample_rows=200)
    full = pq.read_table(root / "grasps.parquet")
    exact, _ = card_stats(root, files, CardSettings(plots=False, histogram_bins=BINS))
    assert "label_sample" not in exact and table.sampled
    sample = stats["label_sample"]
    assert (sample["rows"], sample["sampled"], sample["exact_up_to"]) == (len(full), 200, 300)
    assert sample["from_sample"] == ["epsilon quantiles", "correlation coefficients"]
    rows = np.argsort(row_hash(full.column("scene_id"), full.column("grasp_id").to_numpy()))[:200]
    assert np.array_equal(table.hashes, np.sort(row_hash(full.column("scene_id"),
                                                         full.column("grasp_id").to_numpy()))[:200])
    for c in LABELS:
        got, want = dict(stats["labels"][c]), dict(exact["labels"][c])
        assert got.pop("sample", None) == (int(np.isfinite(float_values(full.column(c)).take(rows)).sum())
                                           if c == "epsilon" else None)
        for k in ("n", "min", "max", "histogram"):
            assert got[k] == want[k], (c, k)
        for k in ("mean", "std"):
            assert got[k] == pytest.approx(want[k], rel=2e-6), (c, k)
        if c == "epsilon":
            v = float_values(full.column(c).take(pa.array(rows)))
            want = dict(zip(("p05", "median", "p95"), np.quantile(v[np.isfinite(v)], QUANTILES)))
        for k in ("p05", "median", "p95"):
            assert got[k] == _num(want[k]), (c, k)
    corr = stats["correlation"]
    assert corr["n"] == exact["correlation"]["n"] and corr["sample_rows"] == 200
    picked = full.take(pa.array(rows))
    for i, a in enumerate(corr["columns"]):
        for j, b in enumerate(corr["columns"]):
            x, y = float_values(picked.column(a)), float_values(picked.column(b))
            ok = np.isfinite(x) & np.isfinite(y)
            if ok.sum() < 3 or np.ptp(x[ok]) == 0 or np.ptp(y[ok]) == 0:
                assert corr["spearman"][i][j] is None
                continue
            assert corr["pearson"][i][j] == pytest.approx(scipy.stats.pearsonr(x[ok], y[ok]).statistic, rel=1e-5)
            assert corr["spearman"][i][j] == pytest.approx(scipy.stats.spearmanr(x[ok], y[ok]).statistic, rel=1e-5)
    assert corr["columns"] == [c for c in CORRELATED if c in LABELS]


def test_past_the_cap_the_card_renders_and_plots(dataset, tmp_path):  # noqa: F811
    root, files = dataset
    settings = CardSettings(histogram_bins=BINS, example_scenes=0)
    stats, table = card_stats(root, files, settings, exact_rows=300, sample_rows=200)
    drawn = draw_plots(tmp_path, table, stats, settings)
    assert {"plots/epsilon.png", "plots/correlation.png"} <= set(drawn)
    card = {"labels": stats["labels"], "correlation": stats["correlation"], "label_sample": stats["label_sample"]}
    text = "\n".join(_label_lines(json.loads(json.dumps(card))))
    assert "from a sample of 200 of its" in text and "epsilon quantiles, correlation coefficients" in text
