"""``run.seed``: another seed, another dataset; the same seed, the same bytes; seed 0, the keys of before."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.config import RunConfig, field_docs, load_config
from pipeline.errors import ConfigError
from pipeline.keys import key_parts, rng_for_key, seed_key, task_key
from pipeline.repro import shard_hashes
from pipeline.scheduler import run_pipeline
from pipeline.status import status
from tests.paths import REPO
from tests.toy_stages import TOY

ROOT = REPO

# One fixed set of key inputs, and the content key and seed key that `pipeline.keys` gave for them before
# `run.seed` existed (computed with that code, kept here as literals): seed 0 must reproduce them bit for bit.
INPUTS = dict(
    stage="scenes",
    version=3,
    params={"a": 1.5, "b": [1, 2]},
    task_id="scene_000001",
    payload={"i": 1},
    upstream={"objects": {"box": "ab" * 32}},
    input_hashes={"0": "cd" * 32},
    code={"code:stages/x.py": "ef" * 32, "package:numpy": "2.0"},
)
UPSTREAM_SEEDS = {"objects": {"box": "12" * 32}}
KEY_BEFORE_SEED = "75aae35da74bbd84ed2b05f90f70f30762d281411a5665f02642fcfe095d4ab8"
SEED_KEY_BEFORE_SEED = "1633fb3859257f59df374518dff667316ed82e5e816832d6a02d063440149e91"


def test_seed_zero_keeps_the_keys_of_before():
    for parts in (key_parts(**INPUTS), key_parts(**INPUTS, seed=0)):
        assert "seed" not in parts
        assert task_key(parts) == KEY_BEFORE_SEED
        assert seed_key(parts, UPSTREAM_SEEDS) == SEED_KEY_BEFORE_SEED


def test_a_seed_changes_the_content_key_and_the_draws():
    keys = {0: KEY_BEFORE_SEED}
    seeds = {0: SEED_KEY_BEFORE_SEED}
    for s in (1, 2, -1, 2**40):
        parts = key_parts(**INPUTS, seed=s)
        assert parts["seed"] == str(s)
        keys[s], seeds[s] = task_key(parts), seed_key(parts, UPSTREAM_SEEDS)
    assert len(set(keys.values())) == len(keys) and len(set(seeds.values())) == len(seeds)
    draws = {s: tuple(rng_for_key(k).random(4)) for s, k in seeds.items()}
    assert len(set(draws.values())) == len(draws)
    # the seed key still leaves the code out: a code change keeps the draws of a seeded run
    other_code = key_parts(**{**INPUTS, "code": {"code:stages/x.py": "00" * 32}}, seed=1)
    assert task_key(other_code) != keys[1] and seed_key(other_code, UPSTREAM_SEEDS) == seeds[1]


def test_run_seed_is_a_documented_integer():
    assert RunConfig().seed == 0
    assert load_config(TOY.schema, None, ["run.seed=7"]).run.seed == 7
    with pytest.raises(ConfigError, match=r"run.seed: must be int, got 1.5"):
        load_config(TOY.schema, None, ["run.seed=1.5"])
    doc = field_docs(RunConfig)["seed"]
    assert "0" in doc and "stale" in doc
    assert "None of these change what is computed" not in (RunConfig.__doc__ or "")


def _toy(out: Path, *sets: str):
    return load_config(TOY.schema, None, [f"run.out={out}", *sets])


def test_toy_pipeline_seed_changes_bytes_same_seed_same_bytes(tmp_path):
    run_pipeline(TOY, _toy(tmp_path / "default", "run.jobs=1"))
    run_pipeline(TOY, _toy(tmp_path / "zero", "run.jobs=1", "run.seed=0"))
    run_pipeline(TOY, _toy(tmp_path / "one", "run.jobs=1", "run.seed=1"))
    run_pipeline(TOY, _toy(tmp_path / "one_again", "run.jobs=2", "run.seed=1"))
    run_pipeline(TOY, _toy(tmp_path / "two", "run.jobs=2", "run.seed=2"))
    h = {name: shard_hashes(tmp_path / name) for name in ("default", "zero", "one", "one_again", "two")}
    assert len(h["default"]) == 5
    assert h["zero"] == h["default"]
    assert h["one"] == h["one_again"]
    for task in h["default"]:  # every task draws anew: no shard is shared between the seeds
        assert len({h["default"][task], h["one"][task], h["two"][task]}) == 3, task


def test_status_after_a_seed_change_is_stale_and_says_why(tmp_path):
    run_pipeline(TOY, _toy(tmp_path / "o", "run.jobs=1", "run.seed=1"))
    assert {s.stage: s.state for s in status(TOY, _toy(tmp_path / "o", "run.seed=1"))} == {
        "numbers": "done",
        "sums": "done",
    }
    rows = {s.stage: s for s in status(TOY, _toy(tmp_path / "o", "run.seed=2"))}
    assert rows["numbers"].state == "stale" and rows["numbers"].missing == 4
    assert rows["numbers"].reasons == ["4 task(s): run.seed changed"]
    assert rows["sums"].state == "waiting"
    rows = {s.stage: s for s in status(TOY, _toy(tmp_path / "o"))}  # back to 0: the seed part goes away
    assert rows["numbers"].state == "stale" and rows["numbers"].reasons == ["4 task(s): run.seed changed"]


def gen(*args):
    exe = Path(sys.executable).with_name("gen")
    env = {**os.environ, "COLUMNS": "200"}
    return subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True, cwd=ROOT, env=env, timeout=300)


def test_smoke_scenes_differ_by_seed_and_repeat_for_the_same_seed(tmp_path):
    def run(name: str, seed: int, jobs: int) -> dict[str, str]:
        result = gen(
            "run", "--config", "configs/smoke.yaml", "--out", tmp_path / name, "--jobs", jobs,
            "--set", f"run.seed={seed}", "--set", f"run.cache_dir={tmp_path / 'cache'}", "scenes",
        )  # fmt: skip
        assert result.returncode == 0, result.stdout + result.stderr
        return shard_hashes(tmp_path / name)

    one, one_again, two = run("one", 1, 1), run("one_again", 1, 2), run("two", 2, 2)
    scenes = sorted(k for k in one if k.startswith("scenes/"))
    assert len(scenes) == 3 and len(one) == 7  # 4 objects + 3 scenes
    assert one == one_again
    assert all(one[k] != two[k] for k in scenes)
    result = gen("status", "--config", "configs/smoke.yaml", "--out", tmp_path / "one", "--set", "run.seed=2")
    text = " ".join(result.stdout.split())
    assert "stale" in text and "run.seed changed" in text, result.stdout + result.stderr

