"""graspgen.learn.pick's hand check: the open Panda's boxes against analytic placements, and the top group drawn
from the clear candidates only."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from graspgen.grippers import load_gripper
from graspgen.learn.features import hand_boxes, surface_points
from graspgen.learn.pick import PickParams, hand_hits, pick
from tests.shapes import top_down

PANDA = load_gripper("panda")
BOXES = hand_boxes(PANDA)  # fingers' inner faces at x = +-0.04 m, the palm from 37 mm behind the TCP


def _points(extents, at=(0.0, 0.0, 0.0), n=4000):
    box = trimesh.creation.box(extents=extents)
    box.apply_translation(at)
    return surface_points(box.vertices, box.faces, n, np.random.default_rng(0))


def test_a_block_between_the_open_pads_is_clear_and_a_wider_one_hits_the_fingers():
    T = top_down(0.0, 0.0, 0.0)[None]
    assert not hand_hits(_points((0.04, 0.02, 0.02)), T, BOXES)[0]  # 20 mm from each pad face, short of the palm
    assert hand_hits(_points((0.10, 0.02, 0.02)), T, BOXES)[0]      # 0.10 m wide: through the 0.08 m opening


def test_the_palm_strikes_a_block_reaching_up_behind_the_tcp():
    # top_down approaches along -z, so the palm lies above the TCP (world +z); a block from z 0 to 60 mm reaches it
    tall = _points((0.04, 0.02, 0.06), at=(0.0, 0.0, 0.03))
    short = _points((0.04, 0.02, 0.02), at=(0.0, 0.0, 0.0))
    T = np.stack([top_down(0.0, 0.0, 0.0), top_down(0.3, 0.0, 0.0)])  # the second pose is far from both
    assert hand_hits(tall, T, BOXES).tolist() == [True, False]
    assert hand_hits(short, T, BOXES).tolist() == [False, False]


class _Scores:
    """A stand-in evaluator: the Panda, scores given per candidate."""

    gripper = "panda"

    def __init__(self, scores):
        self.scores = np.asarray(scores, dtype=np.float64)

    def score(self, sets, seed=0):
        return [self.scores[: len(sets[0].width)]]


def test_the_top_group_is_the_best_scored_clear_candidates(tmp_path):
    mesh = tmp_path / "mug_like.obj"
    # a hollow box open at the top: many antipodal candidates put a finger or the palm into a wall
    outer = trimesh.creation.box(extents=(0.07, 0.07, 0.08))
    inner = trimesh.creation.box(extents=(0.06, 0.06, 0.08))
    inner.apply_translation((0.0, 0.0, 0.006))
    outer.difference(inner).export(mesh)
    params = PickParams(candidates=200, top=10, scale=1.0, hand_check_points=5000)
    scores = np.random.default_rng(1).random(200)
    got = pick(_Scores(scores), mesh, params, np.random.default_rng(3))
    plain = pick(_Scores(scores), mesh, PickParams(candidates=200, top=10, scale=1.0, hand_check_points=0),
                 np.random.default_rng(3))
    assert np.array_equal(got.candidates.T_tcp, plain.candidates.T_tcp)
    assert plain.clear is None and np.array_equal(plain.top, np.argsort(-scores, kind="stable")[:10])
    # most candidates put a finger or the palm into a wall; the clear ones agree with the check run alone
    points = surface_points(got.candidates.vertices, got.candidates.faces, 5000, np.random.default_rng(0))
    assert 0 < got.clear.sum() < 200
    assert got.clear.sum() == pytest.approx((~hand_hits(points, got.candidates.T_tcp, BOXES)).sum(), abs=3)
    clear_ids, hit_ids = np.flatnonzero(got.clear), np.flatnonzero(~got.clear)
    # the clear ones by score, best first; only if fewer than 10 are clear, then the others by score
    expected = np.concatenate([clear_ids[np.argsort(-scores[clear_ids], kind="stable")],
                               hit_ids[np.argsort(-scores[hit_ids], kind="stable")]])[:10]
    assert np.array_equal(got.top, expected)
    assert set(got.random_clear.tolist()) <= set(clear_ids.tolist())
    assert len(set(got.random_clear.tolist())) == min(10, len(clear_ids))
