"""Tests of graspgen.geometry.slack's shortcuts: the bounding-box test in front of each part's planes gives the same
inside/outside answer as testing every plane, and ``outward_slack_p95`` is ``hull_slack(...).p95`` for the same
generator state. Parts are cut from a cup's and an L-shape's surface inline; no CoACD run."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from graspgen.geometry import slack
from graspgen.geometry.convex import hull_slack
from graspgen.geometry.slack import outward_slack_p95
from tests.shapes import l_shape


def sliced_parts(mesh: trimesh.Trimesh, count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """The convex hulls of ``count`` slabs of the mesh's surface points along x (overlapping by a tenth of a slab):
    convex parts that cover the surface, bridge its concavities and overlap their neighbours."""
    points = mesh.sample(8000, seed=1) if hasattr(mesh, "sample") else None
    points = np.concatenate([points, mesh.vertices])
    low, high = points[:, 0].min(), points[:, 0].max()
    width = (high - low) / count
    out = []
    for k in range(count):
        inside = np.abs(points[:, 0] - (low + (k + 0.5) * width)) <= 0.55 * width
        hull = trimesh.convex.convex_hull(points[inside])
        out.append((np.asarray(hull.vertices), np.asarray(hull.faces)))
    return out


def brute_inside(points, union, owner, tolerance):
    """Every point against every other part's planes, no shortcut (the definition)."""
    inside = np.zeros(len(points), dtype=bool)
    for j, (n, d) in enumerate(union.planes):
        others = np.ones(len(points), dtype=bool) if owner is None else owner != j
        inside[others] |= np.max(points[others] @ n.T - d, axis=1) < -tolerance
    return inside


@pytest.mark.parametrize("tolerance", [slack._INSIDE_TOLERANCE, -slack._INSIDE_TOLERANCE])
def test_box_prefilter_answers_as_every_plane(tolerance):
    mesh = l_shape()
    union = slack._Union.of(sliced_parts(mesh, 6))
    rng = np.random.default_rng(2)
    low, high = mesh.bounds
    points = np.concatenate([rng.uniform(low - 0.01, high + 0.01, size=(4000, 3)),
                             np.concatenate([v for v, _ in union.parts])])  # the corners: on a face of their own
    owner = rng.integers(0, len(union.parts), size=len(points))
    for who in (owner, None):
        fast = slack._inside_parts(points, union, who, tolerance=tolerance)
        np.testing.assert_array_equal(fast, brute_inside(points, union, who, tolerance))
    assert 0 < fast.sum() < len(points)  # both answers occur


@pytest.mark.parametrize("count", [1, 5])
def test_outward_p95_is_hull_slack_p95(count):
    mesh = l_shape()
    parts = sliced_parts(mesh, count)
    full = hull_slack(mesh, parts, 3000, np.random.default_rng(5))
    assert outward_slack_p95(mesh, parts, 3000, np.random.default_rng(5)) == full.p95
    assert full.p95 > 1e-3  # the parts bridge the L's inner corner: a real value, not 0 == 0


@pytest.mark.parametrize("count, batch", [(1, 7), (5, 7), (5, 100_000)])
def test_outward_p95_settles_sides_lazily_with_the_same_value(monkeypatch, count, batch):
    # The p95 from winding numbers of the farthest points only equals the p95 of every point's signed distance,
    # whatever the batch (7: dozens of batches; 100,000: one).
    monkeypatch.setattr(slack, "_SIGN_BATCH", batch)
    mesh = l_shape()
    parts = sliced_parts(mesh, count)
    points = slack._boundary_samples(slack._Union.of(parts), 3000, np.random.default_rng(2))
    every = np.percentile(np.maximum(slack._outside_distance(mesh, points), 0.0), 95)
    assert outward_slack_p95(mesh, parts, 3000, np.random.default_rng(2)) == every


def _box(low, high) -> tuple[np.ndarray, np.ndarray]:
    box = trimesh.creation.box(bounds=[low, high])
    return np.asarray(box.vertices), np.asarray(box.faces)


def _brute_shares(mesh, parts, depth, n, seed):
    """Every sample's side settled (the definition): each part's share of samples over ``depth`` outside."""
    union = slack._Union.of(parts)
    owner = np.concatenate([np.full(len(f), i) for i, (_, f) in enumerate(union.parts)])
    points, pick = slack._area_samples(union.triangles, n, np.random.default_rng(seed))
    outside = slack._outside_distance(mesh, points) > depth
    counts = np.bincount(owner[pick], minlength=len(parts))
    return np.bincount(owner[pick], weights=outside, minlength=len(parts)) / np.maximum(counts, 1)


def test_rough_parts_of_an_exact_half_and_a_half_reaching_5_mm_out():
    """A 0.1 x 0.06 x 0.04 m box in two halves along x: the left one exact (nothing outside), the right one 5 mm
    longer. Of the right one's surface, its end face and the last 4 mm of its sides stand more than 1 mm out (a point
    of a side t beyond the box's end is t from it): (0.06 * 0.04 + 0.2 * 0.004) / its area 0.0158 m^2 = 0.2025."""
    mesh = trimesh.creation.box((0.1, 0.06, 0.04))
    parts = [_box((-0.05, -0.03, -0.02), (0.0, 0.03, 0.02)), _box((0.0, -0.03, -0.02), (0.055, 0.03, 0.02))]
    shares = _brute_shares(mesh, parts, 1e-3, 40_000, 0)
    assert shares[0] == 0.0
    assert shares[1] == pytest.approx(0.0032 / 0.0158, abs=0.01)
    for share, expected in ((0.05, [False, True]), (0.19, [False, True]), (0.22, [False, False])):
        rough = slack.rough_parts(mesh, parts, 1e-3, share, 40_000, np.random.default_rng(0))
        assert rough.tolist() == expected
    assert slack.rough_parts(mesh, parts, 6e-3, 0.0, 4000, np.random.default_rng(0)).tolist() == [False, False]
    # The rough half holds 0.0158 of the 0.0306 m^2 of the two: 52 %.
    assert slack.rough_parts(mesh, parts, 1e-3, 0.05, 4000, np.random.default_rng(0), area_limit=0.5) is None
    limited = slack.rough_parts(mesh, parts, 1e-3, 0.05, 4000, np.random.default_rng(0), area_limit=0.53)
    assert limited.tolist() == [False, True]


@pytest.mark.parametrize("count, share", [(3, 0.05), (3, 0.5), (6, 0.6), (12, 0.65)])
def test_rough_parts_settles_sides_lazily_with_the_answer_of_every_side(count, share):
    """Slabs of a cup's surface (they bridge its cavity: part of each stands out, part is buried in the wall)."""
    outer = trimesh.creation.cylinder(radius=0.03, height=0.06, sections=24)
    inner = trimesh.creation.cylinder(radius=0.027, height=0.06, sections=24)
    inner.apply_translation((0, 0, 0.004))
    cup = outer.difference(inner, engine="manifold")
    parts = sliced_parts(cup, count)
    expected = _brute_shares(cup, parts, 1e-3, 4000, 5) > share
    rough = slack.rough_parts(cup, parts, 1e-3, share, 4000, np.random.default_rng(5))
    assert rough.tolist() == expected.tolist()
    areas = np.array([trimesh.Trimesh(v, f).area for v, f in parts])
    rough_area = areas[expected].sum() / areas.sum()
    limited = slack.rough_parts(cup, parts, 1e-3, share, 4000, np.random.default_rng(5), area_limit=0.5)
    assert (limited is None) == (rough_area > 0.5)
    assert share < 0.1 or 0 < expected.sum() < count  # the larger shares split the slabs
