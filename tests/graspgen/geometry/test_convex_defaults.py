"""CoACD's settings on the two paths: ``gen evaluate`` keeps the setting the hull-slack study chose (every search
field given, so the objects stage's defaults can change without moving its parts or the calibration labels), and the
objects stage's defaults carry the smaller MCTS budget of issue 24."""

from __future__ import annotations

import dataclasses

from graspgen.geometry.convex import CoacdParams, coacd_cache_key
from graspgen.workflows.evaluate_settings import CHEAP_COACD, EvaluateParams
from stages.objects import ObjectsParams
from tests.shapes import l_shape


def test_evaluate_setting_does_not_follow_the_objects_stage_defaults():
    # studies/hull_slack.py's t05_h32_r60, with issue 24's part merge and search budget: what the calibration is
    # measured with
    chosen = {"threshold": 0.05, "max_convex_hull": 32, "preprocess_resolution": 60, "resolution": 1000,
              "mcts_iterations": 10, "mcts_depth": 3, "mcts_nodes": 5, "refine_excess": 0.01,
              "free_merge_depth": 2.5e-4}
    assert EvaluateParams().coacd == CHEAP_COACD
    assert {k: getattr(CHEAP_COACD, k) for k in chosen} == chosen
    defaults = CoacdParams()
    assert any(getattr(defaults, k) != v for k, v in chosen.items())  # not merely equal to the defaults


def test_objects_stage_uses_the_defaults_and_its_own_cache_key():
    mesh = l_shape()
    stage = ObjectsParams().coacd
    assert stage == CoacdParams()
    assert (stage.mcts_iterations, stage.mcts_nodes) == (10, 5)
    before = dataclasses.replace(stage, mcts_iterations=20, mcts_nodes=10)  # the objects stage's before the part merge
    assert coacd_cache_key(mesh, stage) != coacd_cache_key(mesh, before)  # cached parts of the old budget miss
