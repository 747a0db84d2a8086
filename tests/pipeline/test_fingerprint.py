"""Code-aware keys: what a stage's fingerprint covers, what does not count, and a real code change end to end."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from pipeline import fingerprint
from pipeline.fingerprint import stage_fingerprint
from pipeline.keys import changed_parts, key_parts, seed_key, task_key
from pipeline.plan import committed
from tests.paths import REPO

ROOT = REPO


@pytest.fixture
def package(tmp_path, monkeypatch):
    """A tiny project package ``fpkg`` on sys.path; returns a writer ``(name, source)`` for its modules."""
    (tmp_path / "fpkg").mkdir()
    monkeypatch.syspath_prepend(str(tmp_path))

    def write(name: str, source: str) -> Path:
        path = tmp_path / "fpkg" / name
        path.write_text(textwrap.dedent(source))
        for cache in (stage_fingerprint, fingerprint._module_info, fingerprint._project_root,
                      fingerprint._project_file, fingerprint._project_modules):
            cache.cache_clear()  # a new process would read the files afresh
        return path

    write("__init__.py", "")
    return write


def test_covers_the_module_what_it_imports_transitively_and_their_packages(package):
    package("stage.py", """
        import numpy as np
        from fpkg import helpers

        def run():
            from fpkg.lazy import LATE  # imported inside a function: still code the stage runs
            return helpers.twice(np.ones(2)) + LATE
    """)
    package("helpers.py", "from .deep import K\n\ndef twice(x):\n    return 2 * x * K\n")
    package("deep.py", "import scipy\nK = 1\n")
    package("lazy.py", "LATE = 3\n")
    package("unused.py", "import trimesh\n")
    parts = stage_fingerprint("fpkg.stage")
    code = sorted(k for k in parts if k.startswith("code:"))
    assert code == [f"code:fpkg/{m}.py" for m in ("__init__", "deep", "helpers", "lazy", "stage")]
    packages = {k.split(":", 1)[1]: v for k, v in parts.items() if k.startswith("package:")}
    assert {"numpy", "scipy", "python"} <= set(packages) and "trimesh" not in packages
    import numpy

    assert packages["numpy"] == numpy.__version__


def test_formatting_comments_and_docstrings_do_not_count_but_a_constant_does(package):
    path = package("stage.py", '"""Doc."""\nX = 1\n\n\ndef f(a, b):\n    return a + b\n')
    before = stage_fingerprint("fpkg.stage")
    package("stage.py", '"""Other doc."""\n# a comment\nX = (\n    1\n)\ndef f(a,b):\n    "doc"\n    return a+b\n')
    assert stage_fingerprint("fpkg.stage") == before
    package("stage.py", path.read_text().replace("X = (\n    1\n)", "X = 2"))
    after = stage_fingerprint("fpkg.stage")
    assert changed_parts(before, after) == ["code: fpkg/stage.py"]


def _fresh(module: str) -> dict[str, str]:
    for cache in (stage_fingerprint, fingerprint._module_info, fingerprint._project_file,
                  fingerprint._project_modules):
        cache.cache_clear()
    return stage_fingerprint(module)


def test_the_module_cache_answers_only_for_the_bytes_it_was_computed_from(package, tmp_path):
    path = package("stage.py", "from fpkg import helpers\nX = 1\n")
    package("helpers.py", "import numpy\n")
    plain = _fresh("fpkg.stage")
    with fingerprint.module_cache(tmp_path / "cache"):
        assert _fresh("fpkg.stage") == plain  # computed, then written
        files = sorted(p.name for p in (tmp_path / "cache" / "fingerprints").iterdir())
        assert files == ["fpkg.helpers.json", "fpkg.json", "fpkg.stage.json"]
        assert _fresh("fpkg.stage") == plain  # read back
        entry = tmp_path / "cache" / "fingerprints" / "fpkg.stage.json"
        data = json.loads(entry.read_text())
        entry.write_text(json.dumps({**data, "digest": "planted"}))
        assert _fresh("fpkg.stage")["code:fpkg/stage.py"] == "planted"  # the same bytes: the cache is what answers
        path.write_text("from fpkg import helpers\nX = 2\n")
        edited = _fresh("fpkg.stage")
        assert edited["code:fpkg/stage.py"] not in ("planted", plain["code:fpkg/stage.py"])
        entry.write_text("{ not json")
        assert _fresh("fpkg.stage") == edited  # a damaged file is ignored...
        assert json.loads(entry.read_text())["digest"] == edited["code:fpkg/stage.py"]  # ...and rewritten
    path.write_text("from fpkg import helpers\nX = 1\n")
    assert _fresh("fpkg.stage") == plain  # outside the block: computed from the source


def test_changed_parts_name_the_file_and_the_package_versions():
    old = {"params": "a", "code:graspgen/sim/lift.py": "1", "package:mujoco": "3.3.7", "code:gone.py": "x"}
    new = {"params": "b", "code:graspgen/sim/lift.py": "2", "package:mujoco": "4.0.0", "code:new.py": "y"}
    assert changed_parts(old, new) == [
        "its params changed",
        "code: gone.py (gone)",
        "code: graspgen/sim/lift.py",
        "code: new.py (new)",
        "package: mujoco 3.3.7 -> 4.0.0",
    ]


def test_the_stages_see_the_library_modules_they_run():
    rollouts = stage_fingerprint("stages.rollouts")
    grasps = stage_fingerprint("stages.grasps")
    assert "code:graspgen/sim/lift.py" in rollouts and "code:stages/rollouts.py" in rollouts
    assert "code:graspgen/sim/lift.py" not in grasps  # sampling does not run the grasp-and-lift protocol
    assert "package:mujoco" in rollouts and "package:coacd" in stage_fingerprint("stages.objects")
    assert not any(k.startswith("code:graspgen_cli") for k in rollouts)  # the CLI is above the stages


def _gen(tree: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(tree), "COLUMNS": "300"}  # one table row per line
    return subprocess.run([sys.executable, "-m", "graspgen_cli.app", *args], cwd=tree, env=env, capture_output=True,
                          text=True, timeout=600)


def test_a_changed_constant_in_the_lift_module_makes_rollouts_and_downstream_stale(tmp_path):
    tree = tmp_path / "tree"
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT, capture_output=True,
                           text=True, check=True).stdout.split()
    for rel in files:
        if (ROOT / rel).is_file():
            (tree / rel).parent.mkdir(parents=True, exist_ok=True)
            (tree / rel).write_bytes((ROOT / rel).read_bytes())
    out = tmp_path / "out"
    common = ["--config", "configs/smoke.yaml", "--out", str(out), "--set", f"run.cache_dir={tmp_path / 'cache'}"]
    first = _gen(tree, "run", *common, "--jobs", "2")
    assert first.returncode == 0, first.stderr
    before = {(s, e.task): e for s in ("rollouts", "robustness") for e in committed(out, s).values()}
    lift = tree / "graspgen" / "sim" / "lift.py"
    lift.write_text(lift.read_text() + "\n_ONE_MORE_CONSTANT = 1\n")
    status = _gen(tree, "status", *common)
    assert status.returncode == 0, status.stderr
    rows = {line.split()[1]: " ".join(line.split()) for line in status.stdout.splitlines() if line.startswith("│")}
    for stage in ("objects", "scenes", "grasps"):
        assert " done " in rows[stage], rows[stage]
    assert " stale " in rows["rollouts"] and "3 task(s): code: graspgen/sim/lift.py" in rows["rollouts"]
    for stage in ("robustness", "metrics", "dataset"):  # downstream of a stale stage: it waits for it
        assert " waiting " in rows[stage] or " stale " in rows[stage], rows[stage]
    again = _gen(tree, "run", *common, "--jobs", "2")
    assert again.returncode == 0, again.stderr
    ran = {line.split(":")[0]: line for line in again.stderr.splitlines() if " tasks, ran " in line}
    assert all("ran 0," in ran[s] for s in ("objects", "scenes", "grasps")), ran
    assert all("ran 0," not in ran[s] for s in ("rollouts", "robustness", "metrics", "dataset")), ran
    # New keys, the same random draws (seed keys leave code out): a change that alters nothing gives the same bytes.
    after = {(s, e.task): e for s in ("rollouts", "robustness") for e in committed(out, s).values()
             if e.key not in {b.key for b in before.values()}}
    assert sorted(after) == sorted(before)
    assert all(after[k].sha256 == before[k].sha256 and after[k].seed == before[k].seed for k in before)


def test_the_seed_key_leaves_code_and_packages_out():
    base = key_parts(stage="s", version=1, params={"a": 1}, task_id="t", payload={}, upstream={}, input_hashes={},
                     code={"code:m.py": "1", "package:numpy": "2.0"})
    edited = {**base, "code:m.py": "2", "package:numpy": "2.1"}
    assert task_key(base) != task_key(edited)
    assert seed_key(base, {}) == seed_key(edited, {})
    assert seed_key(base, {"up": {"x": "k1"}}) != seed_key(base, {"up": {"x": "k2"}})
    other_params = key_parts(stage="s", version=1, params={"a": 2}, task_id="t", payload={}, upstream={},
                             input_hashes={})
    assert seed_key(other_params, {}) != seed_key(base, {})


def test_a_package_upgrade_makes_the_stages_that_import_it_stale_and_says_so(tmp_path, monkeypatch):
    from pipeline.config import load_config
    from pipeline.scheduler import run_pipeline
    from pipeline.status import status
    from tests.toy_stages import TOY

    cfg = load_config(TOY.schema, None, [f"run.out={tmp_path / 'o'}", "run.jobs=1"])
    run_pipeline(TOY, cfg)
    assert all(s.state == "done" for s in status(TOY, cfg))
    real = fingerprint._distribution_versions
    monkeypatch.setattr(fingerprint, "_distribution_versions",
                        lambda top: {"numpy": "99.0"} if top == "numpy" else real(top))
    stage_fingerprint.cache_clear()
    import numpy

    rows = {s.stage: s for s in status(TOY, cfg)}
    assert rows["numbers"].state == "stale"
    assert f"4 task(s): package: numpy {numpy.__version__} -> 99.0" in rows["numbers"].reasons
    stage_fingerprint.cache_clear()
