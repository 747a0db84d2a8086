"""The public API (``from graspgen import ...``): what it exports, that it imports light, and the README's examples."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest

import graspgen
from tests.paths import REPO

ROOT = REPO


def _readme_examples() -> dict[str, str]:
    """The README's Python API examples by the name they show, e.g. ``{"open_dataset": "import os ..."}``."""
    section = (ROOT / "README.md").read_text().split("## Python API", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    examples = {}
    for code in blocks:
        (name,) = set(re.findall(r"from graspgen import (\w+)", code))
        examples[name] = code
    return examples


def _run(code: str, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={**os.environ, **env})


def test_the_public_names_are_the_documented_ones():
    assert sorted(graspgen.__all__) == ["evaluate_grasps", "load_gripper", "open_dataset"]
    assert sorted(_readme_examples()) == sorted(graspgen.__all__)  # one README example each
    with pytest.raises(AttributeError, match="public names: evaluate_grasps, load_gripper, open_dataset"):
        graspgen.read_everything  # noqa: B018


def test_the_reader_imports_without_the_simulator():
    code = "import sys\nfrom graspgen import open_dataset\nprint(sorted({'mujoco', 'trimesh'} & set(sys.modules)))"
    result = _run(code)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


def test_readme_evaluate_grasps_example_labels_the_box():
    result = _run(_readme_examples()["evaluate_grasps"])
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == str(["success"] * 3 + ["no_contact_established"])


def test_readme_load_gripper_example_builds_the_hand():
    result = _run(_readme_examples()["load_gripper"])
    assert result.returncode == 0, result.stderr
    first, second = result.stdout.strip().splitlines()
    assert first.startswith("robotiq_2f85 stroke 0.0-0.085 m")
    assert int(second.split()[0]) >= 3  # base and two fingers at least


def test_readme_open_dataset_example_reads_a_run(tmp_path):
    from pipeline.config import load_config
    from pipeline.scheduler import run_pipeline
    from stages.project import PROJECT

    out = tmp_path / "out"
    config = load_config(PROJECT.schema, ROOT / "configs" / "smoke.yaml",
                         [f"run.out={out}", f"run.cache_dir={tmp_path / 'cache'}", "run.jobs=1"])
    run_pipeline(PROJECT, config)
    result = _run(_readme_examples()["open_dataset"], OUT=str(out))
    assert result.returncode == 0, result.stderr
    n, _, _, objects, _, _, scenes, _ = result.stdout.split()
    assert int(n) > 0 and int(objects) >= 1 and int(scenes) >= 1
