"""Tests of graspgen.geometry.convex.hull_slack (how far a union of convex parts stands out of the true surface)
against analytic gaps. Meshes are built inline; no CoACD run."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from graspgen.geometry.convex import hull_slack
from graspgen.geometry.repair import repair_mesh
from tests.shapes import l_shape

N = 40_000  # area samples: the percentile's sampling error is ~0.3 mm on the shapes below


def rng() -> np.random.Generator:
    return np.random.default_rng(7)


def part(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    hull = mesh.convex_hull
    return np.asarray(hull.vertices), np.asarray(hull.faces)


def clip(points: np.ndarray, normal, offset: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The convex hull of ``points`` cut by the plane ``normal . x = offset``, the side ``normal . x <= offset``."""
    hull = trimesh.convex.convex_hull(points)
    v, edges = hull.vertices, hull.edges_unique
    side = v @ np.asarray(normal, float) - offset
    a, b = side[edges[:, 0]], side[edges[:, 1]]
    crossing = edges[(a < 0) != (b < 0)]
    t = side[crossing[:, 0]] / (side[crossing[:, 0]] - side[crossing[:, 1]])
    cut = v[crossing[:, 0]] + t[:, None] * (v[crossing[:, 1]] - v[crossing[:, 0]])
    return part(trimesh.PointCloud(np.concatenate([v[side <= 0], cut])))



def cup(outer: float, inner: float, height: float, bottom: float) -> trimesh.Trimesh:
    """A thin-walled open cup: a solid of revolution of the wall's profile (radius, z), closed on the axis."""
    profile = np.array([[0, 0], [outer, 0], [outer, height], [inner, height], [inner, bottom], [0, bottom]], float)
    mesh, _ = repair_mesh(trimesh.creation.revolve(profile, sections=128))
    assert mesh.is_watertight and mesh.volume > 0
    return mesh


def test_box_decomposed_as_itself_has_no_slack():
    box = trimesh.creation.box((0.05, 0.07, 0.12))
    slack = hull_slack(box, [part(box)], N, rng())
    assert slack.max == pytest.approx(0.0, abs=1e-9)
    assert slack.p95 == pytest.approx(0.0, abs=1e-9)
    assert slack.short_max == pytest.approx(0.0, abs=1e-9) and slack.short_p95 == pytest.approx(0.0, abs=1e-9)
    assert slack.samples == N  # one part: nothing is buried


def test_box_split_in_two_has_no_slack_and_its_cut_is_buried():
    box = trimesh.creation.box((0.05, 0.07, 0.12))
    halves = [clip(box.vertices, (0, 0, s)) for s in (1, -1)]
    slack = hull_slack(box, halves, N, rng())
    assert slack.max == pytest.approx(0.0, abs=1e-9) and slack.p95 == pytest.approx(0.0, abs=1e-9)
    assert slack.short_max == pytest.approx(0.0, abs=1e-9)
    # The cut (two faces of 0.05 x 0.07) is inside the union: only the box's own surface is sampled.
    surface = 2 * (0.05 * 0.07 + 0.05 * 0.12 + 0.07 * 0.12)
    expected = N * surface / (surface + 2 * 0.05 * 0.07)
    assert slack.samples == pytest.approx(expected, rel=0.03)


def test_grown_box_stands_out_by_the_growth_and_its_corners_by_root_three():
    box = trimesh.creation.box((0.05, 0.07, 0.12))
    grow = 0.002
    big = trimesh.creation.box((0.05 + 2 * grow, 0.07 + 2 * grow, 0.12 + 2 * grow))
    slack = hull_slack(box, [part(big)], N, rng())
    assert slack.max == pytest.approx(grow * math.sqrt(3), rel=1e-9)  # a corner: a vertex of the part
    # Every face point is >= 2 mm out; only the 2 mm border strips are further (up to 2.8 mm at the edges).
    assert grow - 1e-9 <= slack.p95 <= grow * math.sqrt(2)
    assert slack.short_max == 0.0 and slack.short_p95 == 0.0


def test_shrunk_box_has_no_slack_but_falls_short_by_the_shrink_and_root_three_at_corners():
    box = trimesh.creation.box((0.05, 0.07, 0.12))
    small = trimesh.creation.box((0.05 - 0.002, 0.07 - 0.002, 0.12 - 0.002))
    slack = hull_slack(box, [part(small)], N, rng())
    assert slack.max == 0.0 and slack.p95 == 0.0
    assert slack.short_max == pytest.approx(0.001 * math.sqrt(3), rel=1e-9)  # the box's corner: a vertex
    # Every face point is >= 1 mm from the part; only the 1 mm border strips are further (up to 1.4 mm at edges).
    assert 0.001 - 1e-9 <= slack.short_p95 <= 0.001 * math.sqrt(2)


def l_hull_p95(arm: float = 0.1, bar: float = 0.02) -> float:
    """95th percentile of the L's hull slack, analytically.

    The hull adds a prism over the right triangle (bar, bar), (arm, bar), (bar, arm) (legs g = arm - bar). On it a
    point (x, y) is min(x, y) - bar from the L, so on the top and bottom triangles the area further than t is a
    right triangle with legs g - 2t (two of them: (g - 2t)^2), and on the slanted face (length g sqrt 2, height
    bar) a fraction (g - 2t) / g of it. Everything else on the hull is the L's own surface (slack 0).
    """
    g = arm - bar
    slant = g * math.sqrt(2) * bar
    total = 2 * (arm * arm - g * g / 2) + 2 * arm * bar + 2 * bar * bar + slant
    # (g - 2t)^2 + slant (g - 2t) / g = 0.05 total, a quadratic in u = g - 2t
    b, c = slant / g, -0.05 * total
    u = (-b + math.sqrt(b * b - 4 * c)) / 2
    return (g - u) / 2


def test_l_shape_as_one_hull_stands_out_by_the_bridged_corner():
    mesh = l_shape()
    slack = hull_slack(mesh, [part(mesh)], N, rng())
    # Farthest: the middle of the slanted face, (0.06, 0.06), 0.04 m from both bars ((arm - bar) / 2).
    assert slack.max == pytest.approx(0.04, abs=0.001)
    assert slack.max <= 0.04 + 1e-9
    assert slack.p95 == pytest.approx(l_hull_p95(), abs=0.001)
    assert slack.short_max == pytest.approx(0.0, abs=1e-9)


def test_l_hull_cut_in_two_measures_the_union_not_the_cut():
    mesh = l_shape()
    hull = mesh.convex_hull
    # Cut along x = y: the cut face crosses the bridged corner (up to 0.04 m from the L), but it is inside the union.
    halves = [clip(hull.vertices, (s, -s, 0)) for s in (1, -1)]
    whole = hull_slack(mesh, [part(mesh)], N, rng())
    cut = hull_slack(mesh, halves, N, rng())
    assert cut.max == pytest.approx(whole.max, abs=0.001)
    assert cut.p95 == pytest.approx(l_hull_p95(), abs=0.001)


def test_thin_walled_cup_as_one_hull_stands_out_by_its_inner_radius():
    outer, inner, height, bottom = 0.040, 0.037, 0.100, 0.005  # a 3 mm wall
    mesh = cup(outer, inner, height, bottom)
    slack = hull_slack(mesh, [part(mesh)], N, rng())
    # The hull's lid over the opening: at radius r < inner it is inner - r from the wall (the cavity, 95 mm deep,
    # is deeper than wide, so the wall is nearer than the floor); the rest of the hull is the cup's own surface.
    # The farthest point is the lid's centre, one point: the sampled maximum falls short by about the samples'
    # spacing there (sqrt(area / N) ~ 1 mm).
    assert inner - 0.0015 <= slack.max <= inner + 1e-9
    total = 2 * math.pi * outer * height + 2 * math.pi * outer**2
    p95 = inner - math.sqrt(0.05 * total / math.pi)  # pi (inner - t)^2 = 5 % of the hull's area
    assert slack.p95 == pytest.approx(p95, abs=0.001)
    assert slack.short_max == pytest.approx(0.0, abs=1e-9)


def test_cup_wall_thickened_by_a_coarse_part_stands_out_by_the_thickening():
    """A wall of 3 mm covered by a hull 5 mm thick (the parts of a coarse decomposition): 2 mm of slack inside."""
    outer, inner, height, bottom = 0.040, 0.037, 0.100, 0.005
    mesh = cup(outer, inner, height, bottom)
    sectors = []  # 64 sectors, each a wall slab from (inner - 2 mm) to outer and a floor wedge, as convex hulls
    for k in range(64):
        angles = 2 * math.pi * (2 * k + np.arange(3)) / 128  # on the revolved mesh's own vertices
        ring = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        wall = [np.column_stack([r * ring, np.full(3, z)]) for r in (inner - 0.002, outer) for z in (bottom, height)]
        floor = [np.column_stack([outer * ring, np.full(3, z)]) for z in (0.0, bottom)]
        sectors.append(part(trimesh.PointCloud(np.concatenate(wall))))
        sectors.append(part(trimesh.PointCloud(np.concatenate([*floor, [[0, 0, 0], [0, 0, bottom]]]))))
    slack = hull_slack(mesh, sectors, N, rng())
    # A flat chord of a sector stands in by at most r (1 - cos(pi / 64)) = 0.04 mm: the inner face is 2 mm out.
    assert slack.max == pytest.approx(0.002, abs=0.0002)
    assert slack.p95 == pytest.approx(0.002, abs=0.0002)
    assert slack.short_max == pytest.approx(0.0, abs=1e-5)  # the sectors cover the cup (to round-off of angles)


def test_half_a_box_falls_short_by_the_other_half():
    box = trimesh.creation.box((0.05, 0.07, 0.12))
    slack = hull_slack(box, [clip(box.vertices, (0, 0, 1))], N, rng())
    assert slack.max == pytest.approx(0.0, abs=1e-9)
    assert slack.short_max == pytest.approx(0.06, rel=1e-9)  # the top corners, 60 mm above the half
    # Uncovered: the top, all 60 mm away, is 10 % of the surface (0.0035 of 0.0346 m^2), so it holds the p95.
    assert (0.05 * 0.07) / (2 * (0.05 * 0.07 + 0.05 * 0.12 + 0.07 * 0.12)) > 0.05
    assert slack.short_p95 == pytest.approx(0.06, rel=1e-9)


def test_a_zero_area_face_changes_nothing():
    mesh = l_shape()
    halves = [clip(mesh.convex_hull.vertices, (s, -s, 0)) for s in (1, -1)]
    v, f = halves[0]
    padded = [(v, np.vstack([f, [f[0, 0], f[0, 0], f[0, 1]]])), halves[1]]  # a sliver face: no plane of its own
    plain = hull_slack(mesh, halves, 5000, rng())
    assert hull_slack(mesh, padded, 5000, rng()) == plain


def test_arguments_are_checked():
    box = trimesh.creation.box((0.05, 0.07, 0.12))
    with pytest.raises(ValueError, match="n_samples"):
        hull_slack(box, [part(box)], 0, rng())
    with pytest.raises(ValueError, match="convex_parts"):
        hull_slack(box, [], 100, rng())
