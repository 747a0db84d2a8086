"""Tests of graspgen.geometry.part_merge: the bridge depth against a slow reference on boxes, and the merge's rules
(free merges, the cap, parts that touch nothing, determinism)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import trimesh
from scipy.spatial import ConvexHull

from graspgen.geometry import part_merge
from graspgen.geometry.part_merge import bridge_depth, convex_part, merge_convex_parts


def box(low, high) -> np.ndarray:
    """The 8 corners ``(8, 3)`` of the axis-aligned box ``[low, high]``."""
    return np.array(list(itertools.product(*zip(low, high))), dtype=np.float64)


def planes(points: np.ndarray) -> np.ndarray:
    return ConvexHull(points).equations


def reference_depth(points: np.ndarray, boxes: list[tuple], samples: int = 20_000) -> float:
    """Slow reference: the largest exact distance from dense area samples of the hull's surface to the nearest
    axis-aligned box."""
    hull = trimesh.convex.convex_hull(points)
    probes, _ = trimesh.sample.sample_surface(hull, samples, seed=0)
    nearest = np.full(len(probes), np.inf)
    for low, high in boxes:
        gap = np.maximum(np.maximum(np.asarray(low) - probes, probes - np.asarray(high)), 0.0)
        nearest = np.minimum(nearest, np.linalg.norm(gap, axis=1))
    return float(nearest.max())


def test_touching_boxes_in_line_have_no_bridge():
    a, b = box((0, 0, 0), (1, 1, 1)), box((1, 0, 0), (3, 1, 1))
    assert bridge_depth(np.vstack([a, b]), [planes(a), planes(b)]) == pytest.approx(0.0, abs=1e-12)


def test_l_shape_bridge_is_below_and_near_the_exact_depth():
    # Two boxes in an L: the hull's diagonal face bridges the inner corner; the deepest point is the middle of the
    # diagonal edge, 0.5 from both boxes.
    lows_highs = [((0, 0, 0), (2, 1, 1)), ((0, 1, 0), (1, 2, 1))]
    a, b = (box(*lh) for lh in lows_highs)
    depth = bridge_depth(np.vstack([a, b]), [planes(a), planes(b)])
    exact = reference_depth(np.vstack([a, b]), lows_highs)
    assert exact == pytest.approx(0.5, abs=0.02)
    assert 0.6 * exact <= depth <= exact + 1e-12  # probes are a lower bound, on each face of the hull


def test_free_merges_join_what_costs_nothing_and_leave_the_rest():
    line = [box((0, 0, 0), (1, 1, 1)), box((1, 0, 0), (2, 1, 1)), box((2, 0, 0), (3, 1, 1))]
    corner = box((0, 1, 0), (1, 2, 1))  # with the first, an L: its bridge is ~0.33-0.5 deep
    merged = merge_convex_parts(line + [corner], max_parts=-1, free_depth=1e-9)
    volumes = sorted(trimesh.convex.convex_hull(p).volume for p in merged)
    assert volumes == pytest.approx([1.0, 3.0])  # the line is one box, the corner stays apart
    (whole,) = merge_convex_parts(line + [corner], max_parts=-1, free_depth=1.0)
    assert trimesh.convex.convex_hull(whole).volume == pytest.approx(5.0)  # the line, the corner, the bridge: 3 + 1 + 1


def test_cap_forces_the_shallowest_merge_first():
    # A row of four unit boxes with a box on top of its first: capped at 2, the row merges (no bridge) before
    # anything bridges the corner.
    row = [box((i, 0, 0), (i + 1, 1, 1)) for i in range(4)]
    corner = box((0, 1, 0), (1, 2, 1))
    merged = merge_convex_parts(row + [corner], max_parts=2, free_depth=0.0)
    volumes = sorted(trimesh.convex.convex_hull(p).volume for p in merged)
    assert volumes == pytest.approx([1.0, 4.0])


def test_parts_that_touch_nothing_still_obey_the_cap():
    far = [box((10 * i, 0, 0), (10 * i + 1, 1, 1)) for i in range(3)]
    assert len(merge_convex_parts(far, max_parts=-1, free_depth=1.0)) == 3  # no neighbours: nothing to merge
    assert len(merge_convex_parts(far, max_parts=2, free_depth=0.0)) == 2


def test_merge_is_deterministic():
    rng = np.random.default_rng(4)
    pieces = [box(c, c + 0.2 + rng.random(3)) for c in rng.random((12, 3)) * 2]
    first = merge_convex_parts(pieces, max_parts=5, free_depth=1e-3)
    second = merge_convex_parts(pieces, max_parts=5, free_depth=1e-3)
    assert len(first) == 5
    assert [p.tobytes() for p in first] == [p.tobytes() for p in second]


def test_convex_part_is_the_hull_wound_outward():
    rng = np.random.default_rng(7)
    points = rng.normal(size=(200, 3))
    part = convex_part(points)
    reference = trimesh.convex.convex_hull(points)
    assert part.volume == pytest.approx(reference.volume, rel=1e-12)
    np.testing.assert_array_equal(np.sort(part.vertices, axis=0), np.sort(reference.vertices, axis=0))
    mesh = trimesh.Trimesh(part.vertices, part.faces, process=False)
    assert mesh.is_winding_consistent and mesh.volume == pytest.approx(part.volume, rel=1e-12)  # > 0: outward
    assert part.faces.dtype == np.int32 and part.faces.max() == len(part.vertices) - 1


def _pieces_of_a_curved_shell(rng: np.random.Generator, count: int) -> list[np.ndarray]:
    """``count`` convex pieces tiling a thick, randomly bumped half-cylinder shell (cut like CoACD cuts a bowl's wall):
    each ``(v, 3)`` vertices, neighbours sharing their cut faces."""
    edges = np.linspace(0.0, np.pi, count + 1)
    pieces = []
    for a, b in zip(edges[:-1], edges[1:]):
        angles = np.linspace(a, b, 4)
        radius = 1.0 + 0.05 * rng.random(4)
        ring = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        section = np.concatenate([ring * radius[:, None], ring * (radius[:, None] - 0.1)])
        pieces.append(np.concatenate([np.c_[section, np.zeros(8)], np.c_[section, np.full(8, 0.5)]]))
    return pieces


@pytest.mark.parametrize("batch", [1, 64])
def test_bridge_depth_with_owners_is_the_same_bits_as_against_every_piece(monkeypatch, batch):
    # The corners' pieces only bound each probe's distance: the answer must be exactly the full measurement's (probes
    # measured in full one at a time too, where a bound that is not one would stop the search early).
    monkeypatch.setattr(part_merge, "_EXACT_BATCH", batch)
    rng = np.random.default_rng(11)
    for count in (3, 6, 12, 24):
        pieces = _pieces_of_a_curved_shell(rng, count)
        for first, last in ((0, count), (0, count // 2), (count // 3, count)):
            chosen = pieces[first:last]
            hulls = [ConvexHull(p) for p in chosen]
            points = np.vstack([p[h.vertices] for p, h in zip(chosen, hulls)])
            owners = np.concatenate([np.full(len(h.vertices), i) for i, h in enumerate(hulls)])
            equations = [h.equations for h in hulls]
            full = bridge_depth(points, equations)
            assert full > 0.0  # the shell's chord bridges its inside
            assert bridge_depth(points, equations, owners) == full


def test_merge_of_many_pieces_matches_a_plane_by_plane_reference(monkeypatch):
    # merge_convex_parts measures with owners and deduplicated planes; the result must not depend on it.
    rng = np.random.default_rng(12)
    pieces = _pieces_of_a_curved_shell(rng, 30)
    merged = merge_convex_parts(pieces, max_parts=6, free_depth=1e-3)
    assert len(merged) == 6
    monkeypatch.setattr(part_merge, "bridge_depth", lambda points, planes, owners=None: bridge_depth(points, planes))
    reference = merge_convex_parts(pieces, max_parts=6, free_depth=1e-3)
    assert [p.tobytes() for p in merged] == [p.tobytes() for p in reference]
