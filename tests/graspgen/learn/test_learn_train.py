"""graspgen.learn training: a geometric toy problem learnt on held-out objects, same bytes twice, model files,
the missing-torch error, the probe's report."""

from __future__ import annotations

import dataclasses
import io

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("sklearn")

import trimesh  # noqa: E402

from graspgen.errors import InputError, MissingDependencyError  # noqa: E402
from graspgen.learn.features import FeatureParams  # noqa: E402
from graspgen.learn.sources import ObjectGraspSet, split_by_object  # noqa: E402
from graspgen.learn.train import TrainParams, load_model, save_model, train_evaluator  # noqa: E402

SMALL = FeatureParams(num_surface_points=384, num_points=32, margin=0.01)


def _boxes(n_objects=24, per=48, seed=0):
    """Boxes 3-11 cm along x, 4 cm along y, z; grasps closing along x at height dz in [-5, 5] cm. Success (from
    geometry): the pads hold the box (|dz| < 2 cm + 3 mm: half the box plus part of the pad) and it fits in the
    open Panda (x-extent < 8 cm)."""
    rng = np.random.default_rng(seed)
    sets = []
    for i in range(n_objects):
        ex = rng.uniform(0.03, 0.11)
        box = trimesh.creation.box(extents=(ex, 0.04, 0.04))
        dz = rng.uniform(-0.05, 0.05, per)
        T = np.repeat(np.eye(4)[None], per, axis=0)
        T[:, 2, 3] = dz
        label = (np.abs(dz) < 0.023) & (ex < 0.08)
        sets.append(ObjectGraspSet(name=f"box{i}", group=f"box{i}", vertices=box.vertices, faces=box.faces,
                                   T_tcp=T, width=np.full(per, min(ex, 0.08)), label=label, gripper="panda",
                                   source="flex"))
    return sets


def test_learns_a_geometric_rule_on_held_out_objects():
    from graspgen.learn.report import score_report

    train, valid = split_by_object(_boxes(), 0.3, salt="t")
    model = train_evaluator(train, TrainParams(epochs=12, batch_size=64, seed=1, members=1), SMALL)
    report = score_report(valid, model.score(valid))
    assert report["auc"] > 0.9, report["auc"]
    assert report["top_k"]["success"] > report["top_k"]["random"]
    assert model.train_info["loss"][-1] < model.train_info["loss"][0]


def test_same_data_and_settings_give_the_same_bytes(tmp_path):
    sets = _boxes(4, 16)
    params = TrainParams(epochs=2, batch_size=16, seed=3, members=1)
    blobs = []
    for _ in range(2):
        buf = io.BytesIO()
        save_model(train_evaluator(sets, params, SMALL), buf)
        blobs.append(buf.getvalue())
    assert blobs[0] == blobs[1]
    other = io.BytesIO()
    save_model(train_evaluator(sets, TrainParams(epochs=2, batch_size=16, seed=4, members=1), SMALL), other)
    assert other.getvalue() != blobs[0]
    path = tmp_path / "m.pt"
    save_model(train_evaluator(sets, params, SMALL), path)
    assert path.read_bytes() == blobs[0]  # the file name does not enter the bytes


def test_the_model_records_the_physics_its_sets_share():
    from graspgen.learn.train import physics_summary

    sets = _boxes(3, 4)
    same = {"label": "firm", "protocol": "acronym", "friction": 1.0, "density": 150.0, "mass": None}
    sets = [dataclasses.replace(s, physics={**same, "mass": 0.1 * (i + 1)}) for i, s in enumerate(sets)]
    assert physics_summary(sets) == same  # masses differ by more than 1 %: None
    near = [dataclasses.replace(s, physics={**same, "density": 150.0 * (1 + 0.005 * i)}) for i, s in enumerate(sets)]
    assert physics_summary(near)["density"] == pytest.approx(150.75)  # within 1 %: the median
    mixed = [dataclasses.replace(sets[0], physics={**same, "label": "held"}), *sets[1:]]
    assert physics_summary(mixed)["label"] is None
    assert physics_summary([dataclasses.replace(sets[0], physics=None)]) == dict.fromkeys(same)


def test_load_model_round_trip_and_errors(tmp_path, monkeypatch):
    sets = _boxes(3, 12)
    physics = {"label": "firm", "protocol": "acronym", "friction": 1.0, "density": 150.0, "mass": None}
    sets = [dataclasses.replace(s, physics=physics) for s in sets]
    model = train_evaluator(sets, TrainParams(epochs=1, batch_size=8, members=1), SMALL)
    path = tmp_path / "m.pt"
    save_model(model, path)
    back = load_model(path)
    assert back.gripper == "panda" and back.feature_params == SMALL and back.train_info["epochs"] == 1
    assert back.physics == model.physics == physics
    for a, b in zip(model.score(sets), back.score(sets)):
        assert np.array_equal(a, b)
    n_params = sum(p.numel() for p in model.module.parameters())
    assert n_params == 74881  # as the model's docstring states (5 channels)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"no model")
    with pytest.raises(InputError, match="junk.pt"):
        load_model(junk)
    with pytest.raises(InputError, match="nothing.pt"):
        load_model(tmp_path / "nothing.pt")
    monkeypatch.setattr("graspgen.learn.train.FEATURE_VERSION", 999)
    with pytest.raises(InputError, match="m.pt.*version"):
        load_model(path)


def test_one_class_training_set_is_refused():
    sets = _boxes(2, 8)
    sets = [ObjectGraspSet(**{**s.__dict__, "label": np.zeros(len(s.label), bool)}) for s in sets]
    with pytest.raises(InputError, match="successes and failures"):
        train_evaluator(sets, TrainParams(epochs=1, batch_size=8), SMALL)


def test_missing_torch_names_the_install(monkeypatch):
    import importlib

    import graspgen.learn as learn

    real = importlib.import_module

    def fake(name, *a, **k):
        if name == "torch":
            raise ImportError("No module named 'torch'")
        return real(name, *a, **k)

    monkeypatch.setattr(learn.importlib, "import_module", fake)
    with pytest.raises(MissingDependencyError) as err:
        learn.require_torch()
    assert isinstance(err.value, ImportError)
    assert str(err.value) == learn.INSTALL_MESSAGE and "pip install -e '.[learn]'" in str(err.value)


def test_importing_the_torch_modules_without_torch_names_the_install():
    import subprocess
    import sys

    code = "import sys; sys.modules['torch'] = None; import graspgen.learn.train"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode != 0
    assert "MissingDependencyError: graspgen.learn needs torch and scikit-learn" in done.stderr


def test_run_probe_report():
    from graspgen.learn.probe import ProbeParams, run_probe

    sets = _boxes(10, 20)
    # SMALL's features and TrainParams(epochs=2, batch_size=32) with its defaults (seed 0, one thread)
    params = ProbeParams(valid_fraction=0.5, salt="t", num_surface_points=SMALL.num_surface_points,
                         num_points=SMALL.num_points, epochs=2, batch_size=32)
    assert params.features == SMALL
    model, report = run_probe(sets, params, seed=0)
    split = report["split"]
    assert set(split["train_objects"]).isdisjoint(split["valid_objects"])
    assert split["train_grasps"] + split["valid_grasps"] == 200
    assert set(report["baselines"]) == {"base_rate", "object_rate", "gbt"}
    assert report["baselines"]["base_rate"]["auc"] == 0.5
    assert report["baselines"]["object_rate"]["mean_object_auc"] in (0.5, None)
    assert report["train"]["grasps"] == split["train_grasps"] and report["network"]["n"] == split["valid_grasps"]
