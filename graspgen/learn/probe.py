"""The learnability probe: split by object, train the evaluator, score the held-out objects beside the baselines.
Needs torch and scikit-learn."""

from __future__ import annotations

try:
    import torch
except ImportError:  # one clear error naming the install, not a bare ModuleNotFoundError
    from graspgen.learn import require_torch

    require_torch()
    raise

from graspgen.errors import InputError
from graspgen.learn.baselines import baselines
from graspgen.learn.probe_settings import ProbeParams
from graspgen.learn.report import score_report
from graspgen.learn.sources import split_by_object
from graspgen.learn.train import TrainedModel, TrainParams, train_evaluator
from graspgen.validation import check_instance, check_int

__all__ = ["ProbeParams", "run_probe"]


def run_probe(sets, params: ProbeParams, *, seed: int) -> tuple[TrainedModel, dict]:
    """Split ``sets`` by object, train the evaluator on the training objects, report on the held-out ones.

    Parameters
    ----------
    sets : list of ObjectGraspSet
        Labelled grasp sets of one gripper (:mod:`graspgen.learn.sources`).
    params : ProbeParams
        The split (``valid_fraction``, ``salt``), the training (``epochs``, ``batch_size``, ``learning_rate``;
        one thread) and the network's input (``num_points``, ``num_surface_points``).
    seed : int
        Seed (>= 0) of every draw: the training's (weights, batches, surface points) and the baselines'.

    Returns
    -------
    model : TrainedModel
    report : dict
        ``split``, ``network``, ``baselines`` and ``train``; wall-clock only under ``train`` (``seconds``,
        ``cpu_seconds``).

    Raises
    ------
    InputError
        The sets are of more than one gripper (or none).
    """
    check_instance("params", params, ProbeParams)
    seed = check_int("seed", seed, low=0)
    grippers = sorted({s.gripper for s in sets})
    if len(grippers) != 1:
        raise InputError(f"probe sets: expected one gripper, got {grippers}")
    train, valid = split_by_object(sets, params.valid_fraction, params.salt)
    # one network: the probe's held-out AUC measures what the data teaches, which an ensemble would not change
    train_params = TrainParams(epochs=params.epochs, batch_size=params.batch_size, learning_rate=params.learning_rate,
                               seed=seed, threads=1, members=1)
    model = train_evaluator(train, train_params, params.features, gripper=grippers[0])
    report = {
        "split": {"train_objects": [s.name for s in train], "valid_objects": [s.name for s in valid],
                  "train_grasps": int(sum(len(s.label) for s in train)),
                  "valid_grasps": int(sum(len(s.label) for s in valid)),
                  "valid_fraction": params.valid_fraction, "salt": params.salt},
        "network": score_report(valid, model.score(valid, seed=seed)),
        "baselines": baselines(train, valid, params.features, seed),
        "train": {"epochs": params.epochs, "grasps": model.train_info["grasps"],
                  "seconds": model.train_info["seconds"], "cpu_seconds": model.train_info["cpu_seconds"],
                  "torch": torch.__version__},
    }
    return model, report
