"""The learnability probe: split by object, train the evaluator, score the held-out objects beside the baselines.
Needs torch and scikit-learn."""

from __future__ import annotations

import dataclasses

try:
    import torch
except ImportError:  # one clear error naming the install, not a bare ModuleNotFoundError
    from graspgen.learn import require_torch

    require_torch()
    raise

from graspgen.errors import InputError
from graspgen.learn.baselines import baselines
from graspgen.learn.features import FeatureParams
from graspgen.learn.report import score_report
from graspgen.learn.sources import split_by_object
from graspgen.learn.train import TrainedModel, TrainParams, train_evaluator
from graspgen.validation import check_instance, check_number

__all__ = ["ProbeParams", "run_probe"]


@dataclasses.dataclass(frozen=True)
class ProbeParams:
    """Settings of :func:`run_probe`."""

    valid_fraction: float = 0.3
    """Share of the objects (by hash of their group) held out."""
    salt: str = "probe"
    """Salt of the split's hash."""
    train: TrainParams = dataclasses.field(default_factory=TrainParams)
    """Training settings."""
    features: FeatureParams = dataclasses.field(default_factory=FeatureParams)
    """The network's input."""

    def __post_init__(self) -> None:
        check_number("valid_fraction", self.valid_fraction, low=0.0, high=1.0, low_open=True, high_open=True)
        check_instance("train", self.train, TrainParams)
        check_instance("features", self.features, FeatureParams)


def run_probe(sets, params: ProbeParams) -> tuple[TrainedModel, dict]:
    """Train on the training objects, report on the held-out ones (contract layout; wall-clock only under
    ``train``: ``seconds``, ``cpu_seconds``)."""
    grippers = sorted({s.gripper for s in sets})
    if len(grippers) != 1:
        raise InputError(f"probe sets: expected one gripper, got {grippers}")
    train, valid = split_by_object(sets, params.valid_fraction, params.salt)
    model = train_evaluator(train, params.train, params.features, gripper=grippers[0])
    seed = params.train.seed
    report = {
        "split": {"train_objects": [s.name for s in train], "valid_objects": [s.name for s in valid],
                  "train_grasps": int(sum(len(s.label) for s in train)),
                  "valid_grasps": int(sum(len(s.label) for s in valid)),
                  "valid_fraction": params.valid_fraction, "salt": params.salt},
        "network": score_report(valid, model.score(valid, seed=seed)),
        "baselines": baselines(train, valid, params.features, seed),
        "train": {"epochs": params.train.epochs, "grasps": model.train_info["grasps"],
                  "seconds": model.train_info["seconds"], "cpu_seconds": model.train_info["cpu_seconds"],
                  "torch": torch.__version__},
    }
    return model, report
