"""graspgen.learn.report: exact AUC / AP against slow references (pairs; thresholds), and the report layout."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from graspgen.learn.report import average_precision, roc_auc, score_report, top_k_success


def _slow_auc(y, s):
    pos, neg = s[y], s[~y]
    return np.mean([(p > n) + 0.5 * (p == n) for p in pos for n in neg])


def _slow_ap(y, s):
    ap, prev_recall = 0.0, 0.0
    for thr in sorted(set(s.tolist()), reverse=True):
        pred = s >= thr
        tp = (pred & y).sum()
        recall, precision = tp / y.sum(), tp / pred.sum()
        ap += (recall - prev_recall) * precision
        prev_recall = recall
    return ap


@pytest.mark.parametrize("seed", range(5))
def test_auc_and_ap_match_slow_references(seed):
    rng = np.random.default_rng(seed)
    n = 60
    y = rng.random(n) < 0.4
    s = np.round(rng.random(n) + 0.5 * y, 1)  # rounding makes ties
    assert np.isclose(roc_auc(y, s), _slow_auc(y, s))
    assert np.isclose(average_precision(y, s), _slow_ap(y, s))
    from sklearn.metrics import average_precision_score, roc_auc_score

    assert np.isclose(roc_auc(y, s), roc_auc_score(y, s))
    assert np.isclose(average_precision(y, s), average_precision_score(y, s))


def test_one_class_gives_none():
    assert roc_auc(np.ones(4, bool), np.arange(4.0)) is None
    assert average_precision(np.zeros(4, bool), np.arange(4.0)) is None


class _S:
    def __init__(self, name, label):
        self.name, self.label = name, np.asarray(label, bool)


def test_score_report_layout_and_top_k():
    a = _S("a", [1] * 5 + [0] * 15)
    b = _S("b", [1] * 20)  # one class: auc None, skipped in the mean
    sa = np.r_[np.ones(5), np.zeros(15)]
    r = score_report([a, b], [sa, np.zeros(20)])
    assert r["n"] == 40 and r["base_rate"] == 25 / 40
    assert r["per_object"][0] == {"name": "a", "n": 20, "positives": 5, "auc": 1.0}
    assert r["per_object"][1]["auc"] is None and r["mean_object_auc"] == 1.0
    assert r["top_k"] == {"k": 10, "success": (5 / 10 + 1.0) / 2, "random": (0.25 + 1.0) / 2, "objects": 2}


def test_top_k_breaks_ties_at_their_expected_value():
    y = np.array([0] * 12 + [1] * 8, bool)  # positives last: a trial-order tie-break would score 0 for a constant
    assert top_k_success(y, np.zeros(20)) == pytest.approx(8 / 20)
    assert top_k_success(y[::-1], np.zeros(20)) == pytest.approx(8 / 20)  # order does not matter
    # three best (2 positives), then a tie of 10 with 4 positives for the 7 places left: (2 + 7 * 4 / 10) / 10
    s = np.r_[np.full(10, 0.5), [0.9, 0.9, 0.9], np.zeros(7)]
    lab = np.r_[[1, 1, 1, 1] + [0] * 6, [1, 1, 0], [1] * 7].astype(bool)
    assert top_k_success(lab, s) == pytest.approx((2 + 7 * 4 / 10) / 10)
    assert top_k_success(lab[:3], s[:3], k=10) == pytest.approx(1.0) and top_k_success([], [], k=10) is None
    # brute force: the mean over every order of the tied grasps
    rng = np.random.default_rng(0)
    for _ in range(20):
        sc = rng.integers(0, 3, 9).astype(float)
        lb = rng.random(9) < 0.5
        orders = [np.lexsort((rng.permutation(9), -sc))[:4] for _ in range(4000)]
        assert top_k_success(lb, sc, k=4) == pytest.approx(np.mean([lb[o].mean() for o in orders]), abs=0.02)


def test_numpy_modules_do_not_import_torch():
    code = ("import sys, graspgen.learn, graspgen.learn.features, graspgen.learn.sources, graspgen.learn.report; "
            "assert 'torch' not in sys.modules and 'sklearn' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)
