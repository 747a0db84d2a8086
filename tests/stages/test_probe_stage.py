"""The probe stage: trained on the object-centric sets before the dataset is published, its model and report
published with the dataset and rendered on the card; the same bytes for one and two workers; off without torch only
by saying so; skipped with a warning when a config leaves nothing to hold out."""

from __future__ import annotations

import json

import pytest

from graspgen.errors import MissingDependencyError
from graspgen.io.card_render import render_card
from graspgen.io.probe_files import MODEL, REPORT, read_probe_shard
from graspgen.learn.sources import held_out
from pipeline.config import load_config
from pipeline.errors import ConfigError
from pipeline.keys import sha256_file
from pipeline.plan import committed
from pipeline.scheduler import run_pipeline
from pipeline.stage import Upstream
from pipeline.store import Entry, stage_dir
from stages.dataset import validate
from stages.probe import ProbeParams, ProbeStage
from stages.project import PROJECT

# Three objects (the hash split with salt "probe" holds cylinder out), one scene: the probe in a few seconds.
SMALL = ["objects.include=[box, cylinder, wedge]", "scenes.num_scenes=1", "probe.epochs=2"]


def config(out, cache, jobs, *sets):
    return load_config(PROJECT.schema, "configs/smoke.yaml",
                       [f"run.out={out}", f"run.cache_dir={cache}", f"run.jobs={jobs}", *SMALL, *sets])


def probe_shard(out):
    (entry,) = committed(out, "probe").values()
    return stage_dir(out, "probe") / entry.file


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The small config run with one worker and, into another folder, with two: (out1, out2)."""
    root = tmp_path_factory.mktemp("probe")
    outs = []
    for jobs in (1, 2):
        out = root / f"out{jobs}"
        reports = run_pipeline(PROJECT, config(out, root / "cache", jobs))
        assert all(r.failed == 0 for r in reports), [r.failures for r in reports]
        outs.append(out)
    return outs


def test_the_model_and_report_are_published_and_listed_on_the_card(runs):
    out = runs[0]
    d = out / "dataset"
    model, report = read_probe_shard(probe_shard(out))
    assert (d / MODEL).read_bytes() == model and json.loads((d / REPORT).read_text()) == report
    assert sorted(p.name for p in (d / "probe").iterdir()) == ["model.pt", "report.json"]
    card = json.loads((d / "card.json").read_text())
    for rel in (MODEL, REPORT):
        assert card["files"][rel]["sha256"] == sha256_file(d / rel)
    assert card["learnability"]["status"] == "run" and card["learnability"]["report"] == report
    assert "probe" in card["stages"]
    # The split is by name: cylinder held out, the others trained on; every held-out grasp scored.
    split = report["split"]
    assert split["valid_objects"] == ["cylinder"] and split["train_objects"] == ["box", "wedge"]
    # The rule tasks() skips on (held_out of each name) is the split's.
    assert [n for n in ("box", "cylinder", "wedge") if held_out(n, 0.3, "probe")] == split["valid_objects"]
    sets = {o: card["object_sets"]["objects"][o]["grasps"] for o in ("box", "cylinder", "wedge")}
    assert split["valid_grasps"] == report["network"]["n"] == sets["cylinder"]
    assert split["train_grasps"] == sets["box"] + sets["wedge"]
    assert "seconds" not in report["train"]  # wall-clock times stay out of the shard (manifest meta has them)
    (entry,) = committed(out, "probe").values()
    assert entry.meta["seconds"] >= 0 and entry.meta["grasps"] == sum(sets.values())
    text = (d / "card.md").read_text()
    assert text == render_card(card) and "## Learnability" in text and "| network |" in text
    assert "mean per-object AUC" in text and "| cylinder |" in text
    assert validate(out)[0] == []


def test_the_model_loads_and_is_of_the_object_sets_gripper(runs):
    from graspgen.learn.train import load_model

    model = load_model(runs[0] / "dataset" / MODEL)
    assert model.gripper == "panda"


def test_one_and_two_workers_give_the_same_bytes(runs):
    a, b = runs
    assert sha256_file(probe_shard(a)) == sha256_file(probe_shard(b))
    for rel in (MODEL, REPORT, "card.json"):
        assert sha256_file(a / "dataset" / rel) == sha256_file(b / "dataset" / rel), rel


def test_disabled_the_dataset_has_no_probe_files_and_the_card_says_so(runs, tmp_path):
    out = runs[1]
    reports = run_pipeline(PROJECT, config(out, out.parent / "cache", 1, "probe.enabled=false"))
    ran = {r.stage: r.ran for r in reports}
    assert ran["probe"] == 0 and ran["objects"] == 0 and ran["object_grasps"] == 0  # nothing else is redone
    d = out / "dataset"
    assert not (d / "probe").exists() or not any((d / "probe").iterdir())
    card = json.loads((d / "card.json").read_text())
    assert not any(rel.startswith("probe/") for rel in card["files"])
    assert card["learnability"] == {"status": "not run", "reason": "probe.enabled: false"}
    assert "Learnability: not run (probe.enabled: false)." in (d / "card.md").read_text()
    assert validate(out)[0] == []


def test_without_torch_an_enabled_probe_stops_the_run_with_one_line(monkeypatch):
    def missing():
        raise MissingDependencyError("graspgen.learn needs torch and scikit-learn, which are not installed: pip "
                                     "install -e '.[learn]'")

    monkeypatch.setattr("stages.probe.require_torch", missing)
    with pytest.raises(ConfigError) as err:
        ProbeStage().check(ProbeParams())
    text = str(err.value)
    assert "\n" not in text and "pip install -e '.[learn]'" in text and "probe.enabled: false" in text
    ProbeStage().check(ProbeParams(enabled=False))  # off: no torch needed


def fake_upstream(tmp_path, counts):
    """An upstream view of ``objects`` and ``object_grasps`` shards with ``{name: grasps}`` in their meta."""
    entries = {"objects": {}, "object_grasps": {}}
    for name, n in counts.items():
        entries["objects"][name] = Entry(key=f"o{name}", task=name, status="ok", file="x.h5")
        entries["object_grasps"][name] = Entry(key=f"g{name}", task=name, status="ok", file="x.parquet",
                                               meta={"positives": n // 2, "negatives": n - n // 2})
    return Upstream(tmp_path, entries)


def test_a_split_with_an_empty_side_skips_the_probe_with_a_warning(tmp_path):
    stage = ProbeStage()
    both_trained = fake_upstream(tmp_path, {"box": 12, "wedge": 12})  # salt "probe": both on the training side
    assert stage.tasks(ProbeParams(), both_trained) == []
    (warning,) = stage.plan_warnings(ProbeParams(), both_trained)
    assert "held-out side empty" in warning and "probe.salt" in warning
    one = fake_upstream(tmp_path, {"box": 12, "cylinder": 0})  # an object without grasps does not count
    assert stage.tasks(ProbeParams(), one) == [] and "1 object(s)" in stage.plan_warnings(ProbeParams(), one)[0]
    (task,) = stage.tasks(ProbeParams(), fake_upstream(tmp_path, {"box": 12, "cylinder": 8, "wedge": 4}))
    assert task.payload["objects"] == ["box", "cylinder", "wedge"]
    assert stage.tasks(ProbeParams(enabled=False), both_trained) == []
    assert stage.plan_warnings(ProbeParams(enabled=False), both_trained) == []


def test_the_card_says_why_the_probe_did_not_run(tmp_path):
    from graspgen.io.card_learn import learnability, learnability_lines

    skipped = "probe: not run: the split of 2 objects (probe.valid_fraction 0.3, probe.salt 'probe') leaves ..."
    got = learnability(tmp_path, {}, {"probe": {"enabled": True}}, ["objects: a unit guess", skipped])
    assert got == {"status": "not run", "reason": skipped.removeprefix("probe: not run: ")}
    assert learnability(tmp_path, {}, {"probe": {"enabled": False}})["reason"] == "probe.enabled: false"
    assert learnability(tmp_path, {}, {})["reason"] == "this pipeline has no probe stage"
    assert learnability_lines(got)[2] == f"Learnability: not run ({got['reason']})."
    assert learnability_lines(None) == []  # a card made before the section existed
