"""Ensembles of evaluators: the mean probability against a float64 reference, member 0 is the single network, the
same bytes for any number of workers, model files of several members, no ties at confident scores."""

from __future__ import annotations

import io

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("sklearn")

from graspgen.learn.model import EvaluatorEnsemble, PointNetEvaluator  # noqa: E402
from graspgen.learn.train import (  # noqa: E402
    ENSEMBLE_FORMAT,
    TrainParams,
    load_model,
    member_seed,
    save_model,
    train_evaluator,
)
from tests.graspgen.learn.test_learn_train import SMALL, _boxes  # noqa: E402


class _Fixed(PointNetEvaluator):
    """A member whose logits are given: forward returns them whatever the input."""

    def __init__(self, logits, dtype=torch.float32):
        super().__init__()
        self.logits = torch.as_tensor(logits, dtype=dtype)

    def forward(self, points, width):
        return self.logits


def _mean_probability_logit(logits: np.ndarray) -> np.ndarray:
    """Slow reference in float64: logit(mean(sigmoid(l))) per column."""
    out = []
    for column in logits.T:
        p = np.mean([1.0 / (1.0 + np.exp(-float(x))) for x in column])
        q = np.mean([1.0 / (1.0 + np.exp(float(x))) for x in column])
        out.append(np.log(p) - np.log(q))
    return np.asarray(out)


def test_ensemble_logit_is_the_logit_of_the_mean_probability():
    logits = np.array([[-3.0, 0.0, 2.0, 5.0, -8.0], [1.0, 0.5, -2.0, 4.0, -7.5], [0.2, -0.1, 0.0, 6.0, -9.0]])
    ens = EvaluatorEnsemble([_Fixed(row) for row in logits])
    got = ens(torch.zeros(5, 3, 5), torch.zeros(5)).double().numpy()
    np.testing.assert_allclose(got, _mean_probability_logit(logits), rtol=1e-5, atol=1e-5)


def test_confident_scores_do_not_tie():
    # members at logits 30 and 40: in float32 both sigmoids are 1.0; the ensemble's logit keeps them apart
    ens = EvaluatorEnsemble([_Fixed([30.0, 40.0, 20.0]), _Fixed([31.0, 41.0, 20.0])])
    got = ens(torch.zeros(3, 3, 5), torch.zeros(3)).numpy()
    assert np.all(np.isfinite(got)) and got[1] > got[0] > got[2]


def test_an_ensemble_needs_two_members():
    with pytest.raises(ValueError, match="at least 2"):
        EvaluatorEnsemble([PointNetEvaluator()])


def test_member_zero_is_the_single_network_and_seeds_differ():
    assert member_seed(7, 0) == 7
    assert len({member_seed(7, i) for i in range(5)}) == 5 and member_seed(7, 1) != member_seed(8, 1)
    sets = _boxes(4, 16)
    single = train_evaluator(sets, TrainParams(epochs=2, batch_size=16, seed=3, members=1), SMALL)
    pair = train_evaluator(sets, TrainParams(epochs=2, batch_size=16, seed=3, members=2), SMALL)
    assert isinstance(pair.module, EvaluatorEnsemble) and pair.train_info["members"] == 2
    for k, v in single.module.state_dict().items():
        assert torch.equal(pair.module.members[0].state_dict()[k], v)
    assert not torch.equal(pair.module.members[1].head[0].weight, single.module.head[0].weight)


def test_same_bytes_for_any_number_of_workers_and_a_round_trip(tmp_path):
    sets = _boxes(4, 16)
    params = TrainParams(epochs=2, batch_size=16, seed=5, members=3)
    blobs = []
    for jobs in (1, 2):
        buf = io.BytesIO()
        save_model(train_evaluator(sets, params, SMALL, jobs=jobs), buf)
        blobs.append(buf.getvalue())
    assert blobs[0] == blobs[1]
    model = train_evaluator(sets, params, SMALL)
    path = tmp_path / "ens.pt"
    save_model(model, path)
    assert path.read_bytes() == blobs[0]
    back = load_model(path)
    assert isinstance(back.module, EvaluatorEnsemble) and len(back.module.members) == 3
    assert back.train_info["members"] == 3
    blob = torch.load(path, map_location="cpu", weights_only=True)
    assert ENSEMBLE_FORMAT in blob["meta"]
    for a, b in zip(model.score(sets), back.score(sets)):
        assert np.array_equal(a, b)
    # the ensemble's score is the mean of its members' probabilities
    members = [load_model(path) for _ in range(3)]
    for i, m in enumerate(members):
        m.module = back.module.members[i]
    mean = np.mean([m.score(sets[:1])[0] for m in members], axis=0)
    np.testing.assert_allclose(back.score(sets[:1])[0], mean, rtol=1e-5)


def test_members_setting_is_checked():
    with pytest.raises(Exception, match="members"):
        TrainParams(members=0)
