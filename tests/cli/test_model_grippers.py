"""Grippers given as robot models everywhere a gripper file goes: the smoke config's stages, `gen evaluate`'s
library call and `gen show gripper` (the example models need the 'grippers' extra; skipped without it)."""

from __future__ import annotations

import numpy as np
import pyarrow.parquet as pq
import pytest
import trimesh
from PIL import Image
from typer.testing import CliRunner

from graspgen.workflows.evaluate import evaluate_grasps
from graspgen.workflows.evaluate_settings import EvaluateParams
from graspgen_cli.app import app, find_shard
from pipeline.config import load_config
from pipeline.scheduler import run_pipeline
from stages.project import PROJECT
from tests.model_grippers import model_gripper
from tests.paths import REPO
from tests.shapes import top_down

pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")
SMOKE = REPO / "configs" / "smoke.yaml"


def test_the_smoke_config_runs_every_grasp_stage_with_a_model_gripper(tmp_path):
    gripper = model_gripper("schunk_egk40")
    sets = [f"run.out={tmp_path / 'out'}", f"run.cache_dir={tmp_path / 'cache'}", "run.jobs=1",
            "scenes.num_scenes=1", f"grasps.gripper={gripper}", f"object_grasps.gripper={gripper}"]
    cfg = load_config(PROJECT.schema, SMOKE, sets)
    reports = run_pipeline(PROJECT, cfg, ["rollouts", "placed_grasps"])
    assert all(r.failed == 0 for r in reports), [r.failures for r in reports]
    rollouts = pq.read_table(find_shard(PROJECT, cfg, "rollouts", "scene_000000")[0])
    grasps = pq.read_table(find_shard(PROJECT, cfg, "grasps", "scene_000000")[0])
    assert set(grasps.column("gripper").to_pylist()) == {gripper}
    assert 5 in rollouts.column("outcome").to_pylist()  # the hand lifts something


@pytest.mark.parametrize("name", ["robotiq_2f85_urdf", "panda_urdf"])
def test_evaluate_lifts_a_box_with_a_model_gripper_and_not_an_oversized_one(name, tmp_path):
    gripper = model_gripper(name)
    for size, path in ((0.04, "small.obj"), (0.2, "large.obj")):
        trimesh.creation.box(extents=(size, 0.04, 0.04)).export(tmp_path / path)
    poses = top_down(0.0, 0.0, 0.0)[None]
    small, large = (evaluate_grasps(tmp_path / p, 1.0, poses, None, gripper, EvaluateParams(), protocol="acronym",
                                    cache_dir=tmp_path / "cache") for p in ("small.obj", "large.obj"))
    assert small.column("outcome").to_pylist() == [5]
    assert large.column("outcome").to_pylist() != [5]  # 200 mm does not fit between the pads


def test_gen_show_gripper_draws_a_model_gripper(tmp_path):
    gripper = model_gripper("schunk_egk40")
    out = tmp_path / "egk40.png"
    result = CliRunner().invoke(app, ["show", "gripper", gripper, "-o", str(out)])
    assert result.exit_code == 0, result.output
    image = np.asarray(Image.open(out))
    assert image.shape[0] > 100 and image.std() > 10
