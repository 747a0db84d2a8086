"""Tests for graspgen/quality/wrench.py and closure.py: grasp matrix, Ferrari-Canny epsilon, force closure.

Every check compares against something computed another way: closed forms, np.cross, an analytic separating
hyperplane, a brute-force polar vertex enumeration (no qhull) for epsilon, and the LP force-closure test.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.spatial import ConvexHull

import graspgen.quality.closure as closure
from graspgen.quality.closure import (
    ferrari_canny,
    ferrari_canny_from_wrenches,
    force_closure,
    force_closure_from_wrenches,
)
from graspgen.quality.wrench import friction_cone_edges, grasp_matrix, tangent_basis

ORIGIN = np.zeros(3)


# ----------------------------------------------------------------------------------------------------------------
# helpers


def unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def cube_rotations() -> list[np.ndarray]:
    """The 24 proper rotations that map coordinate axes to coordinate axes (signed permutation matrices)."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            r = np.zeros((3, 3))
            r[np.arange(3), perm] = signs
            if np.linalg.det(r) > 0:
                out.append(r)
    assert len(out) == 24
    return out


def polar_vertex_epsilon(w: np.ndarray) -> float:
    """Slow exact reference for epsilon, without qhull.

    For the origin strictly inside K = conv(columns of w), the ball B(0, r) lies in K iff the polar body
    P = {v : w_j . v <= 1 for all j} lies in B(0, 1/r). |v| is convex, so its maximum over the polytope P is at a
    vertex; the vertices are the feasible solutions of the 6x6 systems w_S^T v = 1 over all 6-subsets S of the
    columns. So epsilon = 1 / max |vertex|. Brute force over all subsets, batched.
    """
    pts = np.ascontiguousarray(w.T)
    n = pts.shape[0]
    combos = np.array(list(itertools.combinations(range(n), 6)))
    best = 0.0
    for start in range(0, len(combos), 50_000):
        a = pts[combos[start : start + 50_000]]  # (c, 6, 6), rows = chosen wrenches
        # Keep well-posed systems: |det| against Hadamard's bound (product of row norms).
        hadamard = np.prod(np.linalg.norm(a, axis=2), axis=1)
        ok = np.abs(np.linalg.det(a)) > 1e-9 * hadamard
        v = np.linalg.solve(a[ok], np.ones((int(ok.sum()), 6, 1)))[..., 0]
        feasible = (v @ pts.T).max(axis=1) <= 1.0 + 1e-9
        if feasible.any():
            best = max(best, float(np.linalg.norm(v[feasible], axis=1).max()))
    assert best > 0.0
    return 1.0 / best


def support(w: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Support function h(u) = max_j u . w_j for unit directions u (q, 6)."""
    return (u @ w).max(axis=1)


def box_contact(rng, half):
    """A random point on the surface of an axis-aligned box and its inward normal."""
    face = rng.integers(3)
    sign = rng.choice((-1.0, 1.0))
    p = rng.uniform(-half, half)
    p[face] = sign * half[face]
    n = np.zeros(3)
    n[face] = -sign
    return p, n


def random_grasp(rng):
    """2-5 contacts on a unit sphere or a box; normals inward, or random; random friction/torsion/com."""
    k = int(rng.integers(2, 6))
    if rng.random() < 0.5:
        p = unit(rng.normal(size=(k, 3)))
        n_in = -p
        torque_scale = 1.0
    else:
        half = rng.uniform(0.3, 1.0, size=3)
        p, n_in = map(np.array, zip(*(box_contact(rng, half) for _ in range(k)), strict=True))
        torque_scale = float(np.linalg.norm(half))
    n_random = unit(rng.normal(size=(k, 3)))
    use_random = rng.random(k) < rng.choice((0.0, 0.3, 0.7))
    n = np.where(use_random[:, None], n_random, n_in)
    kw = dict(
        friction=float(rng.uniform(0.2, 1.0)),
        torque_scale=torque_scale,
        torsional_friction=0.0 if rng.random() < 0.5 else float(rng.uniform(0.01, 0.3)) * torque_scale,
    )
    com = rng.uniform(-0.2, 0.2, size=3)
    return p, n, com, kw


# ----------------------------------------------------------------------------------------------------------------
# construction


def test_friction_cone_edges_geometry():
    rng = np.random.default_rng(1)
    n = unit(rng.normal(size=(20, 3)))
    n[0] = [0.0, 0.0, 1.0]
    n[1] = [1.0, 0.0, 0.0]
    mu, m = 0.7, 8
    f = friction_cone_edges(n, mu, m)
    assert f.shape == (20, m, 3)
    t1, t2 = tangent_basis(n)
    # orthonormal, right-handed (t1 x t2 = n)
    for a, b in ((t1, t2), (t1, n), (t2, n)):
        np.testing.assert_allclose(np.einsum("ij,ij->i", a, b), 0.0, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(t1, axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(t2, axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(np.cross(t1, t2), n, atol=1e-15)
    # unit normal component, tangential part of length mu at angles 2 pi j / m from t1
    np.testing.assert_allclose(np.einsum("kmi,ki->km", f, n), 1.0, atol=1e-14)
    tangential = f - n[:, None, :]
    np.testing.assert_allclose(np.linalg.norm(tangential, axis=2), mu, atol=1e-14)
    angle = np.arctan2(np.einsum("kmi,ki->km", tangential, t2), np.einsum("kmi,ki->km", tangential, t1))
    expected = np.angle(np.exp(2j * np.pi * np.arange(m) / m))
    np.testing.assert_allclose(np.angle(np.exp(1j * (angle - expected))), 0.0, atol=1e-14)
    # deterministic
    np.testing.assert_array_equal(friction_cone_edges(n, mu, m), f)


def test_grasp_matrix_columns():
    rng = np.random.default_rng(2)
    p = rng.normal(size=(3, 3))
    n = unit(rng.normal(size=(3, 3)))
    c = rng.normal(size=3)
    mu, scale, gamma, m = 0.4, 0.3, 0.05, 6
    f = friction_cone_edges(n, mu, m)
    hard = grasp_matrix(p, n, c, friction=mu, torque_scale=scale, num_cone_edges=m)
    assert hard.shape == (6, 3 * m)
    soft = grasp_matrix(p, n, c, friction=mu, torque_scale=scale, num_cone_edges=m, torsional_friction=gamma)
    assert soft.shape == (6, 3 * m + 6)
    for i in range(3):
        for j in range(m):
            col = hard[:, i * m + j]
            np.testing.assert_allclose(col[:3], f[i, j], atol=1e-15)
            np.testing.assert_allclose(col[3:], np.cross(p[i] - c, f[i, j]) / scale, atol=1e-14)
        np.testing.assert_allclose(soft[:, 3 * m + 2 * i], np.r_[0, 0, 0, gamma * n[i] / scale], atol=1e-15)
        np.testing.assert_allclose(soft[:, 3 * m + 2 * i + 1], np.r_[0, 0, 0, -gamma * n[i] / scale], atol=1e-15)
    np.testing.assert_array_equal(soft[:, : 3 * m], hard)


def test_no_contacts():
    empty = np.zeros((0, 3))
    assert grasp_matrix(empty, empty, ORIGIN, friction=0.5, torque_scale=1.0).shape == (6, 0)
    assert ferrari_canny(empty, empty, ORIGIN, friction=0.5, torque_scale=1.0) == 0.0
    assert force_closure(empty, empty, ORIGIN, friction=0.5, torque_scale=1.0) is False


# ----------------------------------------------------------------------------------------------------------------
# 1. two antipodal contacts on a box


def test_two_antipodal_box_contacts(monkeypatch):
    half = np.array([0.05, 0.03, 0.02])
    p = np.array([[half[0], 0.01, 0.005], [-half[0], 0.01, 0.005]])
    n = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    com = np.array([0.001, -0.002, 0.0])
    kw = dict(friction=0.5, torque_scale=float(np.linalg.norm(half)))

    # Independent truth: torque about the line through the contacts is unresistable, so rank 5 -> flat.
    w = grasp_matrix(p, n, com, **kw)
    assert np.linalg.matrix_rank(w) == 5

    # A flat set must not reach qhull.
    def no_hull(*args, **kwargs):
        raise AssertionError("ConvexHull called on a flat wrench set")

    with monkeypatch.context() as mp:
        mp.setattr(closure, "ConvexHull", no_hull)
        assert ferrari_canny(p, n, com, **kw) == 0.0
    assert force_closure(p, n, com, **kw) is False

    soft = dict(kw, torsional_friction=0.005)
    assert np.linalg.matrix_rank(grasp_matrix(p, n, com, **soft)) == 6
    eps = ferrari_canny(p, n, com, **soft)
    assert eps > 1e-3
    assert force_closure(p, n, com, **soft) is True


# ----------------------------------------------------------------------------------------------------------------
# 2. agreement with a slow independent computation


SPHERE_CASES = [
    # (name, points on the unit sphere, friction, num_cone_edges, torsional_friction)
    ("tripod-hard", unit([[1.0, 0.0, -0.3], [-0.5, 0.87, -0.3], [-0.5, -0.87, -0.3]]), 0.6, 8, 0.0),
    ("tripod-irregular-soft", unit([[1.0, 0.2, -0.1], [-0.4, 0.9, 0.2], [-0.6, -0.7, -0.4]]), 0.5, 8, 0.05),
    ("tetra-hard", unit([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]]), 0.5, 6, 0.0),
    (
        "four-irregular-soft",
        unit([[1.0, 0.1, 0.3], [-0.2, 1.0, -0.4], [-0.8, -0.5, 0.6], [0.1, -0.3, -1]]),
        0.4,
        4,
        0.1,
    ),
]


@pytest.mark.parametrize("name, p, mu, m, gamma", SPHERE_CASES, ids=[c[0] for c in SPHERE_CASES])
def test_epsilon_matches_polar_vertex_enumeration(name, p, mu, m, gamma):
    com = np.array([0.05, -0.03, 0.02])
    kw = dict(friction=mu, torque_scale=1.0, num_cone_edges=m, torsional_friction=gamma)
    assert force_closure(p, -p, com, **kw)  # the reference is valid only for an interior origin
    w = grasp_matrix(p, -p, com, **kw)
    reference = polar_vertex_epsilon(w)
    eps = ferrari_canny(p, -p, com, **kw)
    assert eps == pytest.approx(reference, abs=1e-9)
    # and the ball of that radius is consistent with the support function in many directions
    rng = np.random.default_rng(3)
    u = unit(rng.normal(size=(20_000, 6)))
    assert support(w, u).min() >= eps - 1e-12


# ----------------------------------------------------------------------------------------------------------------
# 3. tilting one normal away from antipodal


def test_tilting_a_normal_lowers_epsilon():
    radius, mu = 0.04, 0.5
    p = np.array([[0.0, 0.0, radius], [0.0, 0.0, -radius]])
    kw = dict(friction=mu, torque_scale=radius, torsional_friction=0.2 * radius)

    def normals(theta):
        return np.array([[0.0, np.sin(theta), -np.cos(theta)], [0.0, 0.0, 1.0]])

    inside_deg = [0, 5, 10, 15, 20, 24]  # atan(mu cos(pi/8)) = 24.8 deg: joining line inside the polygonal cone
    eps_inside = [ferrari_canny(p, normals(np.radians(d)), ORIGIN, **kw) for d in inside_deg]
    assert all(e > 0 for e in eps_inside)
    assert all(a > b for a, b in zip(eps_inside[:-1], eps_inside[1:], strict=True)), eps_inside
    assert all(force_closure(p, normals(np.radians(d)), ORIGIN, **kw) for d in inside_deg)

    for deg in (30, 45, 90):  # beyond atan(mu) = 26.6 deg: contact 1 cannot push along the joining line
        n = normals(np.radians(deg))
        # Independent truth, a separating hyperplane: u = (0, -1, 0, s/R, 0, 0) has u . w <= 0 on every column
        # (contact 2's force_y and torque_x cancel; contact 1 gives -2 f_y <= 0 as all its edges have f_y > 0).
        u = np.array([0.0, -1.0, 0.0, kw["torque_scale"] / radius, 0.0, 0.0])
        assert (u @ grasp_matrix(p, n, ORIGIN, **kw)).max() <= 1e-12
        assert ferrari_canny(p, n, ORIGIN, **kw) == 0.0
        assert force_closure(p, n, ORIGIN, **kw) is False


def test_contact_outside_its_cone_lowers_epsilon_three_contacts():
    p = unit([[1.0, 0.0, -0.3], [-0.5, 0.87, -0.3], [-0.5, -0.87, -0.3]])
    kw = dict(friction=0.5, torque_scale=1.0)
    base = ferrari_canny(p, -p, ORIGIN, **kw)
    assert base > 0
    # tilt contact 0's normal about the axis (p0 x z) by 10 deg (inside the cone) and by 40 deg (outside)
    axis = unit(np.cross(p[0], [0.0, 0.0, 1.0]))
    values = []
    for deg in (10, 40):
        t = np.radians(deg)
        n0 = -p[0]
        n0 = n0 * np.cos(t) + np.cross(axis, n0) * np.sin(t) + axis * (axis @ n0) * (1 - np.cos(t))
        n = -p.copy()
        n[0] = n0
        values.append(ferrari_canny(p, n, ORIGIN, **kw))
    assert base > values[0] > values[1] >= 0.0


# ----------------------------------------------------------------------------------------------------------------
# 4. epsilon > 0 exactly when the LP says force closure


def test_epsilon_positive_iff_force_closure_random():
    rng = np.random.default_rng(20240607)
    counts = {True: 0, False: 0}
    borderline = 0
    for _ in range(1000):
        p, n, com, kw = random_grasp(rng)
        eps = ferrari_canny(p, n, com, **kw)
        fc = force_closure(p, n, com, **kw)
        if 0.0 < eps < 1e-7:
            borderline += 1  # too close to the boundary for the two tolerances to be compared
            continue
        assert (eps > 0.0) == fc, (p, n, com, kw, eps, fc)
        counts[fc] += 1
    assert borderline <= 5
    assert counts[True] >= 100 and counts[False] >= 100, counts


def test_fast_hull_path_matches_merged_hull():
    """The unmerged ('Q0') hull used for speed gives the epsilon of qhull's default merged 6-D hull ('Qx')."""
    rng = np.random.default_rng(7)
    compared = 0
    for _ in range(300):
        p, n, com, kw = random_grasp(rng)
        w = grasp_matrix(p, n, com, **kw)
        if np.linalg.matrix_rank(w) < 6:
            continue
        eq = ConvexHull(w.T, qhull_options="Qx").equations
        merged = max(0.0, -float(eq[:, -1].max()))
        assert ferrari_canny_from_wrenches(w) == pytest.approx(merged, abs=1e-10)
        compared += 1
    assert compared >= 100


def test_fast_hull_failures_fall_back_to_merged_hull(monkeypatch):
    """A failing or inconsistent unmerged hull is not trusted; the merged hull decides."""
    p = unit([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]])
    kw = dict(friction=0.5, torque_scale=1.0, num_cone_edges=6)
    w = grasp_matrix(p, -p, ORIGIN, **kw)
    truth = polar_vertex_epsilon(w)
    real_hull = closure.ConvexHull

    class BogusHull:  # the true facets plus a plane at half the true distance that cuts off column 0
        def __init__(self, pts, qhull_options=None):
            eq = real_hull(pts, qhull_options="Qx").equations
            a = unit(pts[0])
            self.equations = np.vstack([eq, np.r_[a, -0.5 * truth]])

    def fake(pts, qhull_options=None):
        if qhull_options == closure._QHULL_FAST:
            return BogusHull(pts)
        return real_hull(pts, qhull_options=qhull_options)

    monkeypatch.setattr(closure, "ConvexHull", fake)
    assert ferrari_canny_from_wrenches(w) == pytest.approx(truth, abs=1e-9)

    def failing(pts, qhull_options=None):
        if qhull_options == closure._QHULL_FAST:
            raise closure.QhullError("simulated precision error")
        return real_hull(pts, qhull_options=qhull_options)

    monkeypatch.setattr(closure, "ConvexHull", failing)
    assert ferrari_canny_from_wrenches(w) == pytest.approx(truth, abs=1e-9)

    def always_failing(pts, qhull_options=None):
        raise closure.QhullError("simulated precision error")

    monkeypatch.setattr(closure, "ConvexHull", always_failing)
    assert ferrari_canny_from_wrenches(w) == 0.0


# ----------------------------------------------------------------------------------------------------------------
# 5. invariance


def _fc_grasps(rng, count):
    out = []
    while len(out) < count:
        p, n, com, kw = random_grasp(rng)
        if ferrari_canny(p, n, com, **kw) > 1e-3:
            out.append((p, n, com, kw))
    return out


def test_translation_invariance():
    rng = np.random.default_rng(11)
    for p, n, com, kw in _fc_grasps(rng, 20):
        shift = rng.uniform(-5.0, 5.0, size=3)
        assert ferrari_canny(p + shift, n, com + shift, **kw) == pytest.approx(ferrari_canny(p, n, com, **kw), abs=1e-9)


def test_rotation_invariance_axis_rotations():
    """Exact for the 24 rotations permuting the axes (they map each cone's edge set onto itself, m even)."""
    rng = np.random.default_rng(12)
    for p, n, com, kw in _fc_grasps(rng, 5):
        eps = ferrari_canny(p, n, com, **kw)
        for r in cube_rotations():
            assert ferrari_canny(p @ r.T, n @ r.T, com @ r.T, **kw) == pytest.approx(eps, abs=1e-9)
            assert force_closure(p @ r.T, n @ r.T, com @ r.T, **kw)


def test_rotation_invariance_of_the_wrench_hull():
    """Rotating the grasp rotates force and torque rows alike: an orthogonal map of R^6 keeps epsilon."""
    rng = np.random.default_rng(13)
    for p, n, com, kw in _fc_grasps(rng, 10):
        w = grasp_matrix(p, n, com, **kw)
        r = random_rotation(rng)
        big = np.zeros((6, 6))
        big[:3, :3] = r
        big[3:, 3:] = r
        assert ferrari_canny_from_wrenches(big @ w) == pytest.approx(ferrari_canny_from_wrenches(w), abs=1e-9)


def test_rotation_arbitrary_bounded_by_cone_approximation():
    """Under a general rotation the polygonal cones turn about their normals; epsilon stays between the values
    for the cones inscribed in and circumscribing the true cone (mu cos(pi/m) and mu / cos(pi/m))."""
    rng = np.random.default_rng(14)
    for p, n, com, kw in _fc_grasps(rng, 10):
        m = 8
        r = random_rotation(rng)
        eps_rot = ferrari_canny(p @ r.T, n @ r.T, com @ r.T, **kw)
        shrink = np.cos(np.pi / m)
        lower = ferrari_canny(p, n, com, **dict(kw, friction=kw["friction"] * shrink))
        upper = ferrari_canny(p, n, com, **dict(kw, friction=kw["friction"] / shrink))
        assert lower - 1e-12 <= eps_rot <= upper + 1e-12


# ----------------------------------------------------------------------------------------------------------------
# 6. scaling


@pytest.mark.parametrize("s", [1e-3, 0.37, 25.0])
def test_scaling_invariance(s):
    rng = np.random.default_rng(15)
    for p, n, com, kw in _fc_grasps(rng, 10):
        scaled = dict(kw, torque_scale=kw["torque_scale"] * s, torsional_friction=kw["torsional_friction"] * s)
        assert ferrari_canny(p * s, n, com * s, **scaled) == pytest.approx(ferrari_canny(p, n, com, **kw), abs=1e-9)


def test_epsilon_depends_on_torque_scale():
    # not vacuous: torque_scale alone does change epsilon
    p = unit([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]])
    kw = dict(friction=0.5, num_cone_edges=6)
    assert ferrari_canny(p, -p, ORIGIN, torque_scale=1.0, **kw) != pytest.approx(
        ferrari_canny(p, -p, ORIGIN, torque_scale=3.0, **kw), abs=1e-6
    )


# ----------------------------------------------------------------------------------------------------------------
# 7. argument checks


GOOD = dict(
    points=np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]),
    normals=np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]),
    center_of_mass=np.zeros(3),
    friction=0.5,
    torque_scale=1.0,
    num_cone_edges=8,
    torsional_friction=0.1,
)

BAD = [
    ("points", np.zeros((2, 2))),
    ("points", np.zeros(3)),
    ("points", np.array([[0.0, 0.0, np.nan], [0.0, 0.0, -1.0]])),
    ("normals", np.array([[0.0, 0.0, -1.0]])),  # row count differs from points
    ("normals", np.array([[0.0, 0.0, -2.0], [0.0, 0.0, 1.0]])),  # not unit
    ("normals", np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]])),
    ("normals", np.zeros((2, 4))),
    ("center_of_mass", np.zeros(2)),
    ("center_of_mass", np.array([0.0, np.inf, 0.0])),
    ("friction", 0.0),
    ("friction", -0.3),
    ("friction", float("nan")),
    ("friction", "0.5"),
    ("friction", [0.5]),
    ("torque_scale", 0.0),
    ("torque_scale", -1.0),
    ("torque_scale", float("inf")),
    ("num_cone_edges", 2),
    ("num_cone_edges", 8.0),
    ("num_cone_edges", True),
    ("torsional_friction", -0.01),
    ("torsional_friction", float("nan")),
]


@pytest.mark.parametrize("func", [grasp_matrix, ferrari_canny, force_closure])
@pytest.mark.parametrize("arg, value", BAD, ids=[f"{a}={v!r}" for a, v in BAD])
def test_argument_checks(func, arg, value):
    kwargs = dict(GOOD, **{arg: value})
    p, n, c = kwargs.pop("points"), kwargs.pop("normals"), kwargs.pop("center_of_mass")
    with pytest.raises(ValueError, match=rf"^{arg}\b"):
        func(p, n, c, **kwargs)


@pytest.mark.parametrize(
    "kwargs, arg",
    [
        (dict(normals=np.zeros((2, 2)), friction=0.5), "normals"),
        (dict(normals=[[0.0, 0.0, 3.0]], friction=0.5), "normals"),
        (dict(normals=[[0.0, 0.0, 1.0]], friction=0.0), "friction"),
        (dict(normals=[[0.0, 0.0, 1.0]], friction=0.5, num_cone_edges=2), "num_cone_edges"),
    ],
)
def test_friction_cone_edges_argument_checks(kwargs, arg):
    with pytest.raises(ValueError, match=rf"^{arg}\b"):
        friction_cone_edges(**kwargs)


@pytest.mark.parametrize("func", [ferrari_canny_from_wrenches, force_closure_from_wrenches])
@pytest.mark.parametrize("value", [np.zeros((5, 10)), np.zeros(6), np.full((6, 10), np.nan)])
def test_wrench_argument_checks(func, value):
    with pytest.raises(ValueError, match=r"^wrenches\b"):
        func(value)


def test_nearly_unit_normals_are_renormalised():
    p = unit([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]])
    kw = dict(friction=0.5, torque_scale=1.0)
    wobble = 1.0 + np.array([3e-6, -3e-6, 1e-6, 0.0])[:, None]
    assert ferrari_canny(p, -p * wobble, ORIGIN, **kw) == pytest.approx(ferrari_canny(p, -p, ORIGIN, **kw), abs=1e-12)
