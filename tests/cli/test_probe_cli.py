"""``gen probe train | eval | pick``: help texts, one-line errors (exit 2), and a train / eval round trip on tiny
ACRONYM files of a box whose labels follow a rule the geometry shows (closing across the short side holds)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from typer.testing import CliRunner

from graspgen.errors import MissingDependencyError
from graspgen.geometry.antipodal import AntipodalParams, sample_antipodal
from graspgen.grippers import load_gripper
from graspgen.io.acronym import write_acronym
from graspgen_cli.app import app


def invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def one_line_error(result, *words):
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    for word in words:
        assert word in lines[0], (word, lines[0])


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Two ACRONYM files of boxes (OBJ meshes beside them), 60 grasps each; success = the hand approaches along the
    box's long axis (mesh z), a rule the surface points around the jaws show (about half of the candidates)."""
    root = tmp_path_factory.mktemp("acronym")
    rng = np.random.default_rng(0)
    panda = load_gripper("panda")
    for name, extents in (("Box_a_0.01", (0.05, 0.07, 0.12)), ("Box_b_0.01", (0.05, 0.075, 0.1))):
        mesh = trimesh.creation.box(extents=extents)
        mesh.export(root / f"{name}.obj")
        cands = sample_antipodal(mesh, panda, AntipodalParams(approach="any", num_surface_points=64), rng)
        pick = rng.choice(len(cands), size=60, replace=False)
        success = np.abs(cands.pose_object[pick, 2, 2]) > 0.7
        write_acronym(root / f"{name}.h5", cands.pose_object[pick], success, object_file=f"{name}.obj",
                      object_density=150.0, object_friction=0.8)
    return root


def test_help_texts():
    for args in (["probe", "--help"], ["probe", "train", "--help"], ["probe", "eval", "--help"],
                 ["probe", "pick", "--help"]):
        result = invoke(*args)
        assert result.exit_code == 0, result.output
    assert "--valid-fraction" in invoke("probe", "train", "--help").output
    assert "--candidates" in invoke("probe", "pick", "--help").output


def test_train_members_writes_an_ensemble(files, tmp_path):
    from graspgen.learn.model import EvaluatorEnsemble
    from graspgen.learn.train import TrainParams, load_model

    help_text = " ".join(invoke("probe", "train", "--help").output.split())
    assert f"TrainParams.members, {TrainParams().members})" in help_text.replace("│ ", "")
    model = tmp_path / "e.pt"
    result = invoke("probe", "train", "--grasps", files, "--labels", "flex", "--epochs", "2", "--members", "2",
                    "--jobs", "2", "--out", model)
    assert result.exit_code == 0, result.output
    back = load_model(model)
    assert isinstance(back.module, EvaluatorEnsemble) and len(back.module.members) == 2


def test_train_then_eval_round_trip(files, tmp_path):
    model = tmp_path / "m.pt"
    result = invoke("probe", "train", "--grasps", files, "--labels", "flex", "--epochs", "3", "--out", model)
    assert result.exit_code == 0, result.output
    assert "trained on 120 grasps of 2 objects (panda), 5 networks" in result.output and model.is_file()
    report = tmp_path / "r.json"
    result = invoke("probe", "eval", "--model", model, "--grasps", files / "Box_a_0.01.h5", "--grasps",
                    files / "Box_b_0.01.h5", "--labels", "flex", "--json", report)
    assert result.exit_code == 0, result.output
    got = json.loads(report.read_text())
    assert got["n"] == 120 and [o["name"] for o in got["per_object"]] == ["Box_a_0.01", "Box_b_0.01"]
    assert all(o["n"] == 60 for o in got["per_object"])
    # What eval reports is the library's report of the model's scores (an independent AUC from the same scores).
    from sklearn.metrics import roc_auc_score

    from graspgen.learn.sources import acronym_sets
    from graspgen.learn.train import load_model

    sets = acronym_sets([files], labels="flex")
    scores = load_model(model).score(sets, seed=0)
    labels = np.concatenate([s.label for s in sets])
    assert got["auc"] == pytest.approx(roc_auc_score(labels, np.concatenate(scores)))
    assert got["base_rate"] == pytest.approx(labels.mean())
    assert f"auc {got['auc']:.3f}" in result.output


def test_one_line_errors(files, tmp_path, monkeypatch):
    model = tmp_path / "m.pt"
    one_line_error(invoke("probe", "train", "--grasps", tmp_path / "nothing.h5", "--out", model), "nothing.h5")
    # a missing mesh: the file names a mesh that is not there
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "Box_a_0.01.h5").write_bytes((files / "Box_a_0.01.h5").read_bytes())
    one_line_error(invoke("probe", "train", "--grasps", broken, "--out", model), "Box_a_0.01")
    # an empty split: two objects, and a valid fraction that holds out neither
    one_line_error(invoke("probe", "train", "--grasps", files, "--valid-fraction", "0.01", "--out", model))
    # a model of another gripper; a file that is no model
    assert invoke("probe", "train", "--grasps", files, "--epochs", "1", "--out", model).exit_code == 0
    not_model = tmp_path / "x.pt"
    not_model.write_bytes(b"not a model")
    one_line_error(invoke("probe", "eval", "--model", not_model, "--grasps", files, "--json", tmp_path / "r.json"),
                   "x.pt")
    other = tmp_path / "other"
    other.mkdir()
    T = np.tile(np.eye(4), (4, 1, 1))
    T[:, 2, 3] = 0.2
    (other / "Box_c_0.01.obj").write_text((files / "Box_a_0.01.obj").read_text())
    write_acronym(other / "Box_c_0.01.h5", T, [1, 0, 1, 0], object_file="Box_c_0.01.obj", gripper="robotiq_2f85")
    one_line_error(invoke("probe", "eval", "--model", model, "--grasps", other, "--json", tmp_path / "r.json"),
                   "gripper")
    one_line_error(invoke("probe", "pick", "--model", model, "--mesh", tmp_path / "no.obj", "--json",
                          tmp_path / "p.json"), "no.obj")
    one_line_error(invoke("probe", "train", "--grasps", files, "--labels", "magic", "--out", model), "--labels")

    def missing():
        raise MissingDependencyError("graspgen.learn needs torch and scikit-learn, which are not installed: pip "
                                     "install -e '.[learn]'")

    monkeypatch.setattr("graspgen.learn.require_torch", missing)
    for args in (["train", "--grasps", files, "--out", model],
                 ["eval", "--model", model, "--grasps", files, "--json", tmp_path / "r.json"],
                 ["pick", "--model", model, "--mesh", files / "Box_a_0.01.obj", "--json", tmp_path / "p.json"]):
        one_line_error(invoke("probe", *args), "pip install -e '.[learn]'")


def test_pick_chooses_the_best_scored_and_a_seeded_random_group(files, tmp_path):
    from graspgen.learn.pick import PickParams, pick
    from graspgen.learn.train import load_model

    model_path = tmp_path / "m.pt"
    assert invoke("probe", "train", "--grasps", files, "--epochs", "1", "--out", model_path).exit_code == 0
    model = load_model(model_path)
    params = PickParams(candidates=40, top=3)
    got = pick(model, files / "Box_a_0.01.obj", params, np.random.default_rng(3))
    assert len(got.scores) == len(got.candidates.width) == 40
    clear = got.scores[got.clear]  # the hand check (tests/graspgen/learn/test_learn_pick.py) leaves most of a box
    assert len(clear) >= 3
    assert sorted(got.scores[got.top]) == sorted(np.sort(clear)[-3:])  # the three best clear ones, best first
    assert list(got.scores[got.top]) == sorted(got.scores[got.top], reverse=True)
    assert len(set(got.random.tolist())) == 3
    again = pick(model, files / "Box_a_0.01.obj", params, np.random.default_rng(3))
    assert np.array_equal(again.candidates.T_tcp, got.candidates.T_tcp) and np.array_equal(again.random, got.random)
    # Rigid TCP poses in the box's frame (metres: the OBJ is in metres), within 20 mm of the box (the TCP sits up to
    # half a pad behind the contacts' midpoint).
    R = got.candidates.T_tcp[:, :3, :3]
    assert np.allclose(R @ R.transpose(0, 2, 1), np.eye(3), atol=1e-9) and got.candidates.scale == 1.0
    assert (np.abs(got.candidates.T_tcp[:, :3, 3]) <= np.array([0.025, 0.035, 0.06]) + 0.02).all()
    out = tmp_path / "p.json"
    result = invoke("probe", "pick", "--model", model_path, "--mesh", files / "Box_a_0.01.obj", "--candidates", 40,
                    "--top", 3, "--seed", 3, "--json", out)
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert data["n_top"] == data["n_random"] == 3 and data["candidates"] == 40
    assert data["top_success"] == np.mean(np.asarray(data["top_outcomes"]) == 5)
    assert data["random_success"] == np.mean(np.asarray(data["random_outcomes"]) == 5)
    assert data["clear_candidates"] == int(got.clear.sum()) and "clear of the open hand" in result.output
    assert data["random_clear_success"] == np.mean(np.asarray(data["random_clear_outcomes"]) == 5)
    assert data["top_scores"] == pytest.approx(got.scores[got.top].tolist())
    # The rollouts run at the physics the model learned (the files' density and friction) unless told otherwise.
    assert model.physics == {"label": "flex", "protocol": "acronym", "friction": 0.8, "density": 150.0, "mass": None}
    assert (data["density"], data["friction"]) == (150.0, 0.8)
    assert 0.0 <= data["top_firm"] <= data["top_success"] and "density 150" in result.output
    result = invoke("probe", "pick", "--model", model_path, "--mesh", files / "Box_a_0.01.obj", "--candidates", 40,
                    "--top", 3, "--seed", 3, "--density", 700, "--friction", 1.0, "--json", out)
    assert result.exit_code == 0, result.output
    assert (json.loads(out.read_text())["density"], json.loads(out.read_text())["friction"]) == (700.0, 1.0)
