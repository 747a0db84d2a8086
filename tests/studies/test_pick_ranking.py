"""studies/pick_ranking.py: its ensemble score is the library's, its top-10 rate is the rate of the 10 best."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from studies.pick_ranking import TOP, ensemble_score, top_rate  # noqa: E402


def test_ensemble_score_matches_the_library_ensemble():
    from graspgen.learn.model import EvaluatorEnsemble
    from tests.graspgen.learn.test_learn_ensemble import _Fixed

    logits = np.random.default_rng(0).normal(0.0, 8.0, size=(5, 40))
    members = [_Fixed(row, dtype=torch.float64) for row in logits]
    library = EvaluatorEnsemble(members)(torch.zeros(1), torch.zeros(1)).numpy()
    np.testing.assert_allclose(ensemble_score(logits), library, rtol=1e-9, atol=1e-9)
    # the ensemble's order is the order of the mean probability
    mean_p = (1.0 / (1.0 + np.exp(-logits))).mean(0)
    assert np.array_equal(np.argsort(-ensemble_score(logits)), np.argsort(-mean_p))


def test_top_rate_is_the_label_rate_of_the_best_scored():
    score = np.arange(30, dtype=float)
    label = np.zeros(30, bool)
    label[-TOP:] = True
    assert top_rate(score, label) == 1.0
    assert top_rate(-score, label) == 0.0
    label[-1] = False
    assert top_rate(score, label) == pytest.approx((TOP - 1) / TOP)
    assert top_rate(score, label, np.arange(15)) == 0.0  # only the first 15 candidates: none of the labelled ones
