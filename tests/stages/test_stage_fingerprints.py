"""The simulation stages do not depend on the picture libraries.

A stage's content key holds the versions of the third-party packages its code imports, transitively
(:func:`pipeline.fingerprint.stage_fingerprint`), so a stage that imports Pillow or matplotlib anywhere below it --
even inside a function that only draws a picture -- re-runs its simulations when either is upgraded. The pictures
live in :mod:`graspgen.viz` (the gripper's: :mod:`graspgen.viz.gripper_picture`), which no simulation stage
imports; the ``dataset`` stage draws the card's plots and so must have both, which also shows that the walk sees
them.
"""

from __future__ import annotations

import pytest

from pipeline.fingerprint import PACKAGE_PREFIX, stage_fingerprint
from stages.project import PROJECT

SIMULATION_STAGES = ("scenes", "grasps", "rollouts", "robustness", "metrics", "object_grasps", "placed_grasps")
PICTURE_PACKAGES = {"pillow", "matplotlib"}


def _stage_module(name: str) -> str:
    modules = {stage.name: type(stage).__module__ for stage in PROJECT.stages}
    assert name in modules, f"no stage {name!r} in the project (stages: {', '.join(sorted(modules))})"
    return modules[name]


def _packages(module: str) -> set[str]:
    return {key[len(PACKAGE_PREFIX):].lower() for key in stage_fingerprint(module) if key.startswith(PACKAGE_PREFIX)}


@pytest.mark.parametrize("name", SIMULATION_STAGES)
def test_simulation_stage_fingerprint_has_no_picture_packages(name):
    packages = _packages(_stage_module(name))
    assert "mujoco" in packages and "numpy" in packages, packages  # the walk reached the library's packages
    assert not packages & PICTURE_PACKAGES, (
        f"stage {name!r} imports {sorted(packages & PICTURE_PACKAGES)} somewhere below it: upgrading them would "
        "re-run its simulations; keep picture code in graspgen.viz")


def test_dataset_stage_fingerprint_has_the_plot_packages():
    packages = _packages(_stage_module("dataset"))
    assert PICTURE_PACKAGES <= packages, f"the dataset stage draws plots; its packages: {sorted(packages)}"


def test_function_level_picture_imports_count(tmp_path, monkeypatch):
    """The rule the stage tests lean on: an import inside a function is in the fingerprint too."""
    (tmp_path / "picture_probe_pkg").mkdir()
    (tmp_path / "picture_probe_pkg" / "__init__.py").write_text("")
    (tmp_path / "picture_probe_pkg" / "drawing.py").write_text(
        "def draw():\n    from PIL import Image\n    import matplotlib.pyplot as plt\n    return Image, plt\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert PICTURE_PACKAGES <= _packages("picture_probe_pkg.drawing")


def test_gripper_data_needs_no_mujoco_and_no_pictures():
    """graspgen.grippers (specs, files, the bundled grippers) sits below graspgen.sim: numpy, trimesh and yaml only."""
    packages = _packages("graspgen.grippers") - {"python"}
    assert packages == {"numpy", "pyyaml", "trimesh"}, sorted(packages)
