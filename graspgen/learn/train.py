"""Seeded, single-threaded training of :class:`graspgen.learn.model.PointNetEvaluator`; model files. Needs torch.

Reproducibility: one ``torch.Generator`` seeded from ``TrainParams.seed`` draws the initial weights, the batch
order and the augmentation; ``torch.set_num_threads(threads)`` and deterministic algorithms are set for the run
(and restored after). The same sets and settings give the same weights and the same model-file bytes.
"""

from __future__ import annotations

import dataclasses
import io
import json
import time
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np

try:
    import torch
except ImportError:  # one clear error naming the install, not a bare ModuleNotFoundError
    from graspgen.learn import require_torch

    require_torch()
    raise

from graspgen.errors import InputError, SettingsError
from graspgen.io.atomic import atomic_path
from graspgen.learn.features import CHANNELS, FEATURE_VERSION, FeatureParams, set_features
from graspgen.learn.model import EvaluatorEnsemble, PointNetEvaluator
from graspgen.validation import check_bool, check_int, check_number

__all__ = ["BalancedBatches", "GraspDataset", "TrainParams", "TrainedModel", "load_model", "save_model",
           "train_evaluator"]

MODEL_FORMAT = "graspgen.learn.PointNetEvaluator/1"
"""``format`` of a model file's metadata (one network)."""
ENSEMBLE_FORMAT = "graspgen.learn.EvaluatorEnsemble/1"
"""``format`` of a model file of several members (its metadata says how many)."""


@dataclasses.dataclass(frozen=True)
class TrainParams:
    """How the evaluator is trained."""

    epochs: int = 10
    """Passes; one pass has ceil(grasps / batch_size) balanced batches."""
    batch_size: int = 256
    """Grasps per batch, half successes, half failures (even)."""
    learning_rate: float = 1e-3
    """Adam's learning rate."""
    weight_decay: float = 1e-4
    """Adam's L2 weight decay."""
    seed: int = 0
    """Seeds the torch.Generator (initial weights, batch order, augmentation) and the surface points."""
    threads: int = 1
    """torch intra-op threads during training."""
    augment: bool = True
    """Rotate half the grasps by pi about the approach axis (z): (x, y) -> (-x, -y), a symmetry of a parallel
    jaw."""
    members: int = 5
    """Networks trained on the same grasps from independent draws (initial weights, batch order, augmentation);
    more than one makes an ensemble whose score is their mean probability (training costs ``members`` times one
    network's; docs/decisions/2026-12-07-pick-ensemble.md). Member 0 draws from ``seed``, so ``members=1`` is the
    single network of that seed."""

    def __post_init__(self) -> None:
        check_int("epochs", self.epochs, low=1)
        check_int("batch_size", self.batch_size, low=2)
        if self.batch_size % 2:
            raise SettingsError(f"batch_size: must be even (half successes, half failures), got {self.batch_size}")
        check_number("learning_rate", self.learning_rate, low=0.0, low_open=True)
        check_number("weight_decay", self.weight_decay, low=0.0)
        check_int("seed", self.seed, low=0)
        check_int("threads", self.threads, low=1)
        check_bool("augment", self.augment)
        check_int("members", self.members, low=1)


class GraspDataset(torch.utils.data.Dataset):
    """The featurised grasps of a list of ObjectGraspSet: item i = (points (rows, 5), width (), label ()) tensors."""

    def __init__(self, sets, gripper, feature_params: FeatureParams, seed: int = 0) -> None:
        feats, widths = set_features(sets, gripper, feature_params, seed)
        self.points = torch.from_numpy(feats)
        self.width = torch.from_numpy(widths)
        self.label = torch.from_numpy(np.concatenate([np.asarray(s.label, bool) for s in sets]).astype(np.float32)
                                      if sets else np.zeros(0, np.float32))

    def __len__(self) -> int:
        return len(self.label)

    def __getitem__(self, i):
        return self.points[i], self.width[i], self.label[i]


class BalancedBatches:
    """Batches of indices, half positives and half negatives, each class cycled through seeded permutations;
    ceil(n / batch_size) batches per epoch."""

    def __init__(self, label: torch.Tensor, batch_size: int, generator: torch.Generator) -> None:
        self.pos = torch.nonzero(label > 0.5).squeeze(1)
        self.neg = torch.nonzero(label <= 0.5).squeeze(1)
        if len(self.pos) == 0 or len(self.neg) == 0:
            raise InputError(f"training grasps: need successes and failures, got {len(self.pos)} successes and "
                             f"{len(self.neg)} failures")
        self.n, self.half, self.g = len(label), batch_size // 2, generator
        self._queues = {"pos": torch.empty(0, dtype=torch.long), "neg": torch.empty(0, dtype=torch.long)}

    def _take(self, key: str, pool: torch.Tensor) -> torch.Tensor:
        q = self._queues[key]
        while len(q) < self.half:
            q = torch.cat([q, pool[torch.randperm(len(pool), generator=self.g)]])
        self._queues[key] = q[self.half :]
        return q[: self.half]

    def epoch(self):
        for _ in range(-(-self.n // (2 * self.half))):
            yield torch.cat([self._take("pos", self.pos), self._take("neg", self.neg)])


@dataclasses.dataclass
class TrainedModel:
    """A trained evaluator and what it needs to score grasps."""

    module: PointNetEvaluator | EvaluatorEnsemble
    feature_params: FeatureParams
    gripper: str
    """Gripper name the features were made for."""
    train_info: dict = dataclasses.field(default_factory=dict)
    """epochs, grasps, objects, seed, final loss; ``seconds`` / ``cpu_seconds`` (wall-clock, not saved)."""
    physics: dict = dataclasses.field(default_factory=dict)
    """What the training labels were made at (:func:`physics_summary`): ``label``, ``protocol``, ``friction``,
    ``density`` (kg/m^3), ``mass`` (kg); a value is None where the sets disagree or did not say."""

    def score(self, sets, seed: int = 0) -> list[np.ndarray]:
        """(m,) float64 success probabilities per set (surface points from ``seed``)."""
        from graspgen.grippers import load_gripper

        spec = load_gripper(self.gripper)
        out = []
        self.module.eval()
        with torch.no_grad():
            for s in sets:
                f, w = set_features([s], spec, self.feature_params, seed)
                # float64 before the sigmoid: in float32 every logit above ~17 is 1.0, a tie for the ranking
                p = [torch.sigmoid(self.module(torch.from_numpy(f[i : i + 4096]),
                                               torch.from_numpy(w[i : i + 4096])).double())
                     for i in range(0, len(w), 4096)]
                out.append(torch.cat(p).double().numpy() if p else np.zeros(0))
        return out


def _augment(points: torch.Tensor, g: torch.Generator) -> torch.Tensor:
    flip = torch.rand(len(points), generator=g) < 0.5
    sign = torch.ones(len(points), 1, points.shape[-1])
    sign[flip, :, :2] = -1.0
    return points * sign


def member_seed(seed: int, member: int) -> int:
    """The seed of ensemble member ``member``: ``seed`` itself for member 0, else a SeedSequence of both."""
    if member == 0:
        return int(seed)
    return int(np.random.SeedSequence([int(seed), int(member)]).generate_state(1, np.uint64)[0] >> 2)


def _train_member(data: GraspDataset, held: GraspDataset | None, params: TrainParams, seed: int,
                  length_scale: float) -> tuple[PointNetEvaluator, list[float], list[float]]:
    """One network from the draws of ``seed``: (module, training loss per epoch, held-out loss per epoch)."""
    threads, determ = torch.get_num_threads(), torch.are_deterministic_algorithms_enabled()
    torch.set_num_threads(params.threads)
    torch.use_deterministic_algorithms(True)
    try:
        g = torch.Generator().manual_seed(seed)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(int(torch.randint(0, 2**62, (1,), generator=g)))  # nn.Linear init draws globally
            module = PointNetEvaluator(length_scale=length_scale, channels=CHANNELS)
        opt = torch.optim.Adam(module.parameters(), lr=params.learning_rate, weight_decay=params.weight_decay)
        loss_fn = torch.nn.BCEWithLogitsLoss()
        batches = BalancedBatches(data.label, params.batch_size, g)
        losses, valid_losses = [], []
        for _ in range(params.epochs):
            module.train()
            total, count = 0.0, 0
            for idx in batches.epoch():
                pts = data.points[idx]
                if params.augment:
                    pts = _augment(pts, g)
                loss = loss_fn(module(pts, data.width[idx]), data.label[idx])
                opt.zero_grad()
                loss.backward()
                opt.step()
                total, count = total + float(loss.detach()), count + 1
            losses.append(total / count)
            if held is not None and len(held):
                module.eval()
                with torch.no_grad():
                    valid_losses.append(float(loss_fn(module(held.points, held.width), held.label)))
    finally:
        torch.set_num_threads(threads)
        torch.use_deterministic_algorithms(determ)
    return module.eval(), losses, valid_losses


def train_evaluator(sets, params: TrainParams, feature_params: FeatureParams | None = None, *, gripper=None,
                    valid=None, jobs: int = 1) -> TrainedModel:
    """Train on ``sets`` (ObjectGraspSet list, one gripper). ``valid`` (optional): its loss per epoch goes into
    ``train_info["valid_loss"]`` (reported only; nothing is chosen by it). ``jobs``: worker processes training the
    members of an ensemble (each with ``params.threads`` threads; the weights do not depend on it)."""
    from graspgen.grippers import load_gripper

    feature_params = feature_params or FeatureParams()
    jobs = check_int("jobs", jobs, low=1)
    names = sorted({s.gripper for s in sets})
    gripper = gripper or (names[0] if len(names) == 1 else None)
    if gripper is None or names not in ([], [gripper]):
        raise InputError(f"training sets: expected one gripper, got {names}")
    spec = load_gripper(gripper)
    start, cpu = time.perf_counter(), time.process_time()
    data = GraspDataset(sets, spec, feature_params, params.seed)
    held = GraspDataset(valid, spec, feature_params, params.seed) if valid else None
    BalancedBatches(data.label, params.batch_size, torch.Generator())  # a one-class set fails before any training
    feat_seconds = time.perf_counter() - start
    seeds = [member_seed(params.seed, i) for i in range(params.members)]
    if jobs > 1 and len(seeds) > 1:
        from joblib import Parallel, delayed

        trained = Parallel(n_jobs=min(jobs, len(seeds)))(
            delayed(_train_member)(data, held, params, s, spec.max_width / 2) for s in seeds)
    else:
        trained = [_train_member(data, held, params, s, spec.max_width / 2) for s in seeds]
    modules = [t[0] for t in trained]
    module = modules[0] if len(modules) == 1 else EvaluatorEnsemble(modules)
    info = {"epochs": params.epochs, "grasps": len(data), "objects": len(sets), "seed": params.seed,
            "loss": [float(np.mean(v)) for v in zip(*(t[1] for t in trained))],
            "valid_loss": [float(np.mean(v)) for v in zip(*(t[2] for t in trained))], "torch": torch.__version__,
            "featurize_seconds": feat_seconds, "seconds": time.perf_counter() - start,
            "cpu_seconds": time.process_time() - cpu}
    if len(modules) > 1:
        info["members"] = len(modules)
    return TrainedModel(module.eval(), feature_params, gripper, info, physics_summary(sets))


PHYSICS_KEYS = ("label", "protocol", "friction", "density", "mass")
"""Keys of :attr:`TrainedModel.physics`."""


def physics_summary(sets) -> dict:
    """The physics every set of ``sets`` shares (:attr:`ObjectGraspSet.physics`): per key its one value, the
    median of a numeric key's values within 1 % of each other, else None."""
    out: dict = {}
    for key in PHYSICS_KEYS:
        values = [(s.physics or {}).get(key) for s in sets]
        if any(v is None for v in values) or not values:
            out[key] = None
        elif isinstance(values[0], str):
            out[key] = values[0] if len(set(values)) == 1 else None
        else:
            v = np.asarray(values, dtype=np.float64)
            out[key] = float(np.median(v)) if v.max() <= 1.01 * v.min() else None
    return out


_SAVED_INFO = ("epochs", "grasps", "objects", "seed", "loss", "members")  # no wall-clock: the file must be reproducible


def save_model(model: TrainedModel, path) -> None:
    """Write ``model`` (a path, written atomically, or a binary file object): torch.save of an OrderedDict of CPU
    tensors and a JSON metadata string, without torch's process-dependent ``serialization_id`` record (same model
    -> same bytes, whatever the archive's file name)."""
    from graspgen.io.probe_files import canonical_torch_zip

    members = len(model.module.members) if isinstance(model.module, EvaluatorEnsemble) else 1
    meta = {"format": MODEL_FORMAT if members == 1 else ENSEMBLE_FORMAT, "feature_version": FEATURE_VERSION,
            "feature_params": dataclasses.asdict(model.feature_params), "gripper": model.gripper,
            "length_scale": model.module.length_scale, "physics": model.physics,
            "train_info": {k: model.train_info[k] for k in _SAVED_INFO if k in model.train_info}}
    if members > 1:
        meta["members"] = members
    state = OrderedDict((k, v.detach().cpu().contiguous()) for k, v in model.module.state_dict().items())
    buf = io.BytesIO()
    torch.save(OrderedDict([("meta", json.dumps(meta, sort_keys=True)), ("state", state)]), buf)
    data = canonical_torch_zip(buf.getvalue())
    if hasattr(path, "write"):
        path.write(data)
        return
    with atomic_path(Path(path)) as tmp:
        tmp.write_bytes(data)


def load_model(path) -> TrainedModel:
    """Read a :func:`save_model` file; InputError naming the file when it is not one, or its features are of
    another :data:`FEATURE_VERSION`."""
    where = getattr(path, "name", str(path))
    try:
        blob: Any = torch.load(path, map_location="cpu", weights_only=True)
        meta = json.loads(blob["meta"])
        if meta.get("format") not in (MODEL_FORMAT, ENSEMBLE_FORMAT):
            raise ValueError(f"format {meta.get('format')!r}")
    except FileNotFoundError:
        raise InputError(f"{where}: no such model file") from None
    except Exception as exc:  # torch raises many kinds on a file that is not its archive
        raise InputError(f"{where}: not a graspgen.learn model file ({type(exc).__name__}: {exc})") from None
    if meta["feature_version"] != FEATURE_VERSION:
        raise InputError(f"{where}: features of version {meta['feature_version']}, this graspgen makes version "
                         f"{FEATURE_VERSION}; train the model again")
    members = [PointNetEvaluator(length_scale=meta["length_scale"], channels=CHANNELS)
               for _ in range(int(meta.get("members", 1)))]
    module = members[0] if len(members) == 1 else EvaluatorEnsemble(members)
    module.load_state_dict(blob["state"])
    return TrainedModel(module.eval(), FeatureParams(**meta["feature_params"]), meta["gripper"],
                        dict(meta["train_info"]), dict(meta.get("physics") or {}))
