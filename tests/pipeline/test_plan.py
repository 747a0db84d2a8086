"""The planner's shared-text upstream digests and manifest reading, against the plain definitions."""

from __future__ import annotations

import dataclasses
import json
import pickle

import numpy as np
import pytest

from pipeline.errors import StageError
from pipeline.keys import upstream_digest
from pipeline.plan import UpstreamDigests, read_entries
from pipeline.stage import Upstream
from pipeline.store import Entry, Manifest


def _view(tmp_path, rng: np.random.Generator) -> Upstream:
    """Two stages of entries with random keys; every third entry has no seed key (the key stands in for it)."""
    entries = {}
    for stage, n in (("objects", 12), ("scenes", 5)):
        entries[stage] = {
            f"{stage[:-1]}_{i:02d}": Entry(
                key=f"{rng.integers(2**62):016x}", task=f"{stage[:-1]}_{i:02d}", status="ok", file=f"{i}.h5",
                seed=None if i % 3 == 0 else f"{rng.integers(2**62):016x}",
                parts={"code": "c" * 64, "params": f"{i}"}, meta={"rows": i},
            )
            for i in range(n)
        }
    return Upstream(tmp_path, entries)


def test_upstream_digests_equal_the_plain_digest(tmp_path):
    rng = np.random.default_rng(7)
    view = _view(tmp_path, rng)
    digests = UpstreamDigests(view)
    objects, scenes = view.ids("objects"), view.ids("scenes")
    for _ in range(40):
        needs = {"objects": list(rng.choice(objects, size=rng.integers(1, len(objects) + 1), replace=False))}
        if rng.random() < 0.5:
            needs["scenes"] = list(rng.choice(scenes, size=rng.integers(1, len(scenes) + 1), replace=False))
        assert digests.keys(needs) == upstream_digest(view.keys(needs))
        assert digests.seeds(needs) == upstream_digest(view.seeds(needs))
    whole = {"objects": objects, "scenes": scenes}
    assert digests.keys(whole) == upstream_digest(view.keys(whole))
    assert digests.keys({}) == upstream_digest(view.keys({}))


def test_upstream_digests_seed_differs_from_key_when_seeds_are_set(tmp_path):
    view = _view(tmp_path, np.random.default_rng(1))
    digests = UpstreamDigests(view)
    needs = {"objects": ["object_01"]}  # has its own seed key
    assert digests.keys(needs) != digests.seeds(needs)
    needs = {"objects": ["object_00"]}  # no seed key: the key stands in
    assert digests.keys(needs) == digests.seeds(needs)


def test_upstream_digests_name_the_unknown_stage(tmp_path):
    digests = UpstreamDigests(_view(tmp_path, np.random.default_rng(2)))
    with pytest.raises(StageError, match="'grasps'.*inputs: \\['objects', 'scenes'\\]"):
        digests.keys({"grasps": ["g"]})
    with pytest.raises(StageError, match="object_99"):
        digests.keys({"objects": ["object_99"]})


def test_read_entries_are_the_manifest_compact(tmp_path):
    manifest = Manifest(tmp_path)
    for i in range(3):
        manifest.append(Entry(key=f"k{i}", task=f"t{i}", status="ok", file=f"{i}.h5", meta={"n": i, "w": ["x"]},
                              parts={"code": "d" * 64, "params": str(i), "stage": "s@1"}))
    manifest.append(Entry(key="k1", task="t1", status="failed", error="boom", parts={"stage": "s@1"}))
    plain, compact = manifest.entries(), read_entries(manifest)
    assert list(plain) == list(compact) and compact["k1"].status == "failed"
    for key, entry in compact.items():
        assert entry.parts == {"stage": "s@1"} and entry.meta == plain[key].meta
        assert entry.meta_dict() == plain[key].meta and entry.meta.get("n") == plain[key].meta.get("n")
        assert dataclasses.replace(entry, parts=plain[key].parts, meta=plain[key].meta) == plain[key]
        assert Entry(**json.loads(entry.to_json())).meta == plain[key].meta  # writes the plain dict back
        assert pickle.loads(pickle.dumps(entry)) == entry  # shipped to workers
    assert compact["k0"].parts is compact["k2"].parts  # one dict per stage part
    assert manifest.parts(["k0", "k1"]) == {"k0": plain["k0"].parts, "k1": {"stage": "s@1"}}


def test_planned_keys_equal_the_plain_task_key(tmp_path):
    from pipeline.keys import task_key
    from pipeline.plan import _task_key, plan
    from tests.toy_stages import TOY

    stage = TOY.stages[0]
    cfg_params = stage.params(TOY.schema())
    planned = plan(stage, cfg_params, Upstream(tmp_path, {d: {} for d in stage.inputs}))
    assert planned and all(p.key == task_key(p.parts) for p in planned)
    odd = {"a": "1", "b": 2}  # not all strings: the general walk, the same answer
    assert _task_key(odd) == task_key(odd)
    rng = np.random.default_rng(0)
    parts = {f"code:m{i}.py": f"{rng.integers(2**62):x}" for i in range(50)} | {"task": "t\u00e9", "z": "\"q\""}
    assert _task_key(parts) == task_key(parts)
