"""Grasp-wrench maths for the Ferrari-Canny epsilon quality metric.

Pure numpy/scipy; usable without the pipeline.

Model
-----
Contact ``i`` has a point ``p_i`` (metres) and a unit normal ``n_i`` pointing INTO the object (the direction the
finger pushes). Its Coulomb friction cone is approximated by ``m`` edges

    f_ij = n_i + mu * (t1_i cos(2 pi j / m) + t2_i sin(2 pi j / m)),   j = 0 .. m-1,

with ``(t1_i, t2_i)`` a deterministic orthonormal tangent basis of ``n_i`` (:func:`tangent_basis`). Each edge gives
the wrench column ``[f_ij; (p_i - c) x f_ij / torque_scale]`` (``c`` the centre of mass; ``torque_scale`` a length
in metres that makes torques commensurate with forces; normal force is unit, so wrenches are dimensionless). With
``torsional_friction = gamma > 0`` (soft finger; gamma in metres = torsional moment per unit normal force) each
contact adds ``[0; +gamma n_i / torque_scale]`` and ``[0; -gamma n_i / torque_scale]``.

The grasp wrench space is ``conv(columns)`` (total normal force bounded by 1) and the Ferrari-Canny epsilon is the
radius of the largest origin-centred ball inside it; 0 when the origin is not strictly inside.

Why the rank check: two point contacts cannot resist torque about the line joining them, so their wrenches lie in
a 5-D subspace of R^6. Qhull cannot build a 6-D hull of a flat set, and joggling (option ``QJ``) only hides that by
fabricating a thin hull. So the rank is tested first and a flat set scores 0.0; ``QJ`` is never used.

Two independent decisions are offered and agree (``tests/test_wrench.py`` checks it on 1,000 random grasps):

* :func:`ferrari_canny` -- exact epsilon from the hull facets (``scipy.spatial.ConvexHull``);
* :func:`force_closure` -- a linear program (``scipy.optimize.linprog``), no hull: the origin is strictly inside
  ``conv(W)`` iff ``rank W = 6`` and some strictly positive ``lambda`` has ``W lambda = 0``.

Tolerances
----------
* Normals whose length differs from 1 by more than :data:`NORMAL_TOL` are rejected (``ValueError``); within it they
  are renormalised, so float32 round-off upstream is harmless while un-normalised input is caught.
* A wrench matrix is flat (rank < 6) when ``sigma_min <= RANK_RTOL * sigma_max``. Since ``epsilon <= sigma_min``
  (the set's half-width along the last left singular vector is at most ``sigma_min``) and ``sigma_max >= 1`` (every
  force column has norm >= 1), this only discards sets whose epsilon would be negligible anyway.
* Epsilons at or below :data:`EPSILON_TOL` are reported as exactly 0.0.

Speed
-----
The 6-D hull is the cost. It is first built without qhull's facet merging (option ``Q0``, about 3x faster on these
inputs), and that result is accepted only if every input point lies inside every reported facet plane (within
:data:`_VERIFY_TOL`); a plane that supports the set can only over-, never under-state its distance, and qhull
stops with an error when unmerged precision problems break the hull. On any error or failed check the hull is
rebuilt with qhull's default merging for 6-D (``Qx``), whose failure means the input is degenerate: epsilon 0.0.
"""

from __future__ import annotations

import functools

import numpy as np
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, QhullError

from graspgen.validation import check_int, check_number

__all__ = [
    "EPSILON_TOL",
    "NORMAL_TOL",
    "RANK_RTOL",
    "LP_MARGIN_TOL",
    "tangent_basis",
    "friction_cone_edges",
    "grasp_matrix",
    "ferrari_canny",
    "ferrari_canny_from_wrenches",
    "force_closure",
    "force_closure_from_wrenches",
]

#: Allowed deviation of a normal's length from 1 before it is rejected (within it, normals are renormalised).
NORMAL_TOL = 1e-5
#: A wrench matrix with ``sigma_min <= RANK_RTOL * sigma_max`` is treated as rank-deficient (flat).
RANK_RTOL = 1e-12
#: Epsilon values at or below this are reported as 0.0 (origin on or outside the hull boundary).
EPSILON_TOL = 1e-12
#: force_closure needs the LP margin ``t = min_j lambda_j`` (with ``sum lambda = 1``) above this.
LP_MARGIN_TOL = 1e-10

# Fast attempt: no merging ('Q0'); scipy always adds 'Qt'. Fallback: qhull's own default for 5-D and up ('Qx',
# exact pre-merges). Never 'QJ': it would fabricate a hull for a flat set.
_QHULL_FAST = "Q0"
_QHULL_SAFE = "Qx"
# How far (relative to the largest wrench norm) an input point may lie outside a facet of the fast hull.
_VERIFY_TOL = 1e-9

_LP_OPTIONS = {"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10}


# ----------------------------------------------------------------------------------------------------------------
# argument checks


def _check_vectors(name: str, value, k: int | None = None) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (k, 3), got {np.shape(value)}")
    if k is not None and arr.shape[0] != k:
        raise ValueError(f"{name}: expected {k} rows (one per contact, as in points), got {arr.shape[0]}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name}: contains NaN or infinite values")
    return arr


def _check_points(points) -> np.ndarray:
    return _check_vectors("points", points)


def _check_normals(normals, k: int | None = None) -> np.ndarray:
    arr = _check_vectors("normals", normals, k)
    length = np.sqrt(np.einsum("ij,ij->i", arr, arr))
    bad = np.abs(length - 1.0) > NORMAL_TOL
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(
            f"normals: must be unit vectors (|length - 1| <= {NORMAL_TOL}); row {i} has length {length[i]:.9g}"
        )
    return arr / length[:, None]


def _check_center_of_mass(center_of_mass) -> np.ndarray:
    arr = np.asarray(center_of_mass, dtype=float)
    if arr.shape != (3,):
        raise ValueError(f"center_of_mass: expected shape (3,), got {np.shape(center_of_mass)}")
    if not np.isfinite(arr).all():
        raise ValueError("center_of_mass: contains NaN or infinite values")
    return arr


def _check_wrenches(wrenches) -> np.ndarray:
    arr = np.asarray(wrenches, dtype=float)
    if arr.ndim != 2 or arr.shape[0] != 6:
        raise ValueError(f"wrenches: expected shape (6, n), got {np.shape(wrenches)}")
    if not np.isfinite(arr).all():
        raise ValueError("wrenches: contains NaN or infinite values")
    return arr


# ----------------------------------------------------------------------------------------------------------------
# wrench construction (private parts take validated arrays)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` along the last axis, broadcasting (cheaper than np.cross for small arrays)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


@functools.lru_cache(maxsize=64)
def _cone_angles(m: int) -> tuple[np.ndarray, np.ndarray]:
    angle = 2.0 * np.pi * np.arange(m) / m
    c, s = np.cos(angle), np.sin(angle)
    c.flags.writeable = False
    s.flags.writeable = False
    return c, s


def _tangent_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    axis = np.argmin(np.abs(n), axis=1)
    e = np.zeros_like(n)
    e[np.arange(n.shape[0]), axis] = 1.0
    t1 = _cross(n, e)
    t1 /= np.sqrt(np.einsum("ij,ij->i", t1, t1))[:, None]
    return t1, _cross(n, t1)


def _cone_edges(n: np.ndarray, mu: float, m: int) -> np.ndarray:
    t1, t2 = _tangent_basis(n)
    c, s = _cone_angles(m)
    return n[:, None, :] + mu * (c[None, :, None] * t1[:, None, :] + s[None, :, None] * t2[:, None, :])


def _wrenches(p: np.ndarray, n: np.ndarray, c: np.ndarray, mu: float, scale: float, m: int, gamma: float):
    k = p.shape[0]
    edges = _cone_edges(n, mu, m)  # (k, m, 3)
    nt = k * m + (2 * k if gamma > 0.0 else 0)
    w = np.zeros((nt, 6))
    w[: k * m, :3] = edges.reshape(k * m, 3)
    w[: k * m, 3:] = (_cross((p - c)[:, None, :], edges) * (1.0 / scale)).reshape(k * m, 3)
    if gamma > 0.0:
        tors = n * (gamma / scale)
        w[k * m :: 2, 3:] = tors
        w[k * m + 1 :: 2, 3:] = -tors
    return w.T


def tangent_basis(normals) -> tuple[np.ndarray, np.ndarray]:
    """Deterministic orthonormal tangent basis of each normal.

    ``t1 = normalise(n x e_a)`` with ``e_a`` the coordinate axis least aligned with ``n`` (the first such axis on
    ties), ``t2 = n x t1``; ``(t1, t2, n)`` is right-handed and ``|n x e_a| >= sqrt(2/3)``, so it is well
    conditioned. It is equivariant under the 24 rotations that permute the coordinate axes up to sign (up to a
    half-turn about ``n``, which maps a cone with an even number of edges onto itself), but not under arbitrary
    rotations: no continuous choice from ``n`` alone can be.

    Parameters
    ----------
    normals : (k, 3) float
        Unit normals (dimensionless), renormalised within :data:`NORMAL_TOL`.

    Returns
    -------
    t1, t2 : (k, 3) float
        Unit tangents, orthogonal to each other and to the normal.
    """
    return _tangent_basis(_check_normals(normals))


def friction_cone_edges(normals, friction, num_cone_edges=8) -> np.ndarray:
    """Edges of the polyhedral friction cone at each contact (vertices on the true cone).

    ``f_ij = n_i + mu * (t1_i cos(2 pi j / m) + t2_i sin(2 pi j / m))`` with the tangent basis of
    :func:`tangent_basis`. Every edge has unit normal component and ``|f_ij| = sqrt(1 + mu^2)``.

    Parameters
    ----------
    normals : (k, 3) float
        Unit contact normals pointing INTO the object (the direction the finger pushes), dimensionless.
    friction : float
        Coulomb friction coefficient ``mu > 0``, dimensionless.
    num_cone_edges : int, default 8
        Number of cone edges ``m >= 3``.

    Returns
    -------
    (k, m, 3) float
        Cone edge forces per unit normal force, dimensionless.

    Raises
    ------
    ValueError
        On a bad shape, a non-finite value, non-unit normals, ``friction <= 0`` or ``num_cone_edges < 3``; the
        message starts with the argument's name.
    """
    n = _check_normals(normals)
    mu = check_number("friction", friction, low=0.0, low_open=True)
    m = check_int("num_cone_edges", num_cone_edges, low=3)
    return _cone_edges(n, mu, m)


def _checked_wrenches(points, normals, center_of_mass, friction, torque_scale, num_cone_edges, torsional_friction):
    p = _check_points(points)
    n = _check_normals(normals, p.shape[0])
    c = _check_center_of_mass(center_of_mass)
    mu = check_number("friction", friction, low=0.0, low_open=True)
    scale = check_number("torque_scale", torque_scale, low=0.0, low_open=True)
    m = check_int("num_cone_edges", num_cone_edges, low=3)
    gamma = check_number("torsional_friction", torsional_friction, low=0.0)
    return _wrenches(p, n, c, mu, scale, m, gamma)


def grasp_matrix(
    points,
    normals,
    center_of_mass,
    *,
    friction,
    torque_scale,
    num_cone_edges=8,
    torsional_friction=0.0,
) -> np.ndarray:
    """Primitive contact wrenches as the columns of a (6, n) matrix.

    Columns ``[f_ij; (p_i - c) x f_ij / torque_scale]``, contact-major (contact 0's ``m`` edges first, in the
    order of :func:`friction_cone_edges`). When ``torsional_friction > 0`` the ``2k`` soft-finger columns follow,
    contact-major: ``[0; +gamma n_i / torque_scale]`` then ``[0; -gamma n_i / torque_scale]``.

    Parameters
    ----------
    points : (k, 3) float, metres
        Contact points (k may be 0).
    normals : (k, 3) float
        Unit contact normals pointing INTO the object, dimensionless.
    center_of_mass : (3,) float, metres
        Torque reference point.
    friction : float
        Coulomb friction coefficient ``mu > 0``.
    torque_scale : float, metres
        Length dividing torques (e.g. the object's largest distance from the centre of mass), ``> 0``.
    num_cone_edges : int, default 8
        Friction-cone edges per contact, ``>= 3``.
    torsional_friction : float, metres, default 0.0
        Soft-finger torsional friction ``gamma >= 0`` (torsional moment per unit normal force); 0 = point contact.

    Returns
    -------
    (6, k*m) or (6, k*m + 2k) float
        Dimensionless wrenches: rows 0-2 force, rows 3-5 torque / torque_scale.

    Raises
    ------
    ValueError
        On a bad argument; the message starts with the argument's name.
    """
    return _checked_wrenches(
        points, normals, center_of_mass, friction, torque_scale, num_cone_edges, torsional_friction
    )


# ----------------------------------------------------------------------------------------------------------------
# quality


def _is_flat(w: np.ndarray) -> bool:
    """True when the columns of ``w`` (6, n) do not span R^6 (up to :data:`RANK_RTOL`)."""
    if w.shape[1] < 6:
        return True
    sv = np.linalg.svd(w, compute_uv=False)
    return bool(sv[-1] <= RANK_RTOL * sv[0])


def _hull_equations(pts: np.ndarray) -> np.ndarray | None:
    """Facet equations ``[normal, offset]`` of the hull of ``pts`` (n, 6); None if qhull cannot build it."""
    try:
        eq = ConvexHull(pts, qhull_options=_QHULL_FAST).equations
    except QhullError:
        eq = None
    if eq is not None:
        # Accept the unmerged hull only if every facet plane supports the point set.
        tol = _VERIFY_TOL * max(1.0, float(np.sqrt(np.einsum("ij,ij->i", pts, pts).max())))
        if float((pts @ eq[:, :-1].T + eq[:, -1]).max()) <= tol:
            return eq
    try:
        return ConvexHull(pts, qhull_options=_QHULL_SAFE).equations
    except QhullError:
        return None


def _epsilon(w: np.ndarray) -> float:
    if _is_flat(w):
        return 0.0
    eq = _hull_equations(np.ascontiguousarray(w.T))
    if eq is None:
        return 0.0
    # equations: [unit normal, offset] with normal . x + offset <= 0 inside, so the origin's distance is -offset.
    eps = -float(eq[:, -1].max())
    return eps if eps > EPSILON_TOL else 0.0


def ferrari_canny_from_wrenches(wrenches) -> float:
    """Ferrari-Canny epsilon of a wrench set: radius of the largest origin-centred ball inside its convex hull.

    Parameters
    ----------
    wrenches : (6, n) float
        Wrench columns, e.g. from :func:`grasp_matrix`, dimensionless.

    Returns
    -------
    float
        ``epsilon >= 0``, in the wrenches' units. 0.0 when the columns are flat (rank < 6; qhull is not called),
        when the origin is not strictly inside the hull, when epsilon <= :data:`EPSILON_TOL`, or when qhull
        reports the input degenerate even with merging (only near-flat sets, whose epsilon is negligible).

    Notes
    -----
    Invariant under any orthogonal map of R^6 applied to all columns.
    """
    return _epsilon(_check_wrenches(wrenches))


def ferrari_canny(
    points,
    normals,
    center_of_mass,
    *,
    friction,
    torque_scale,
    num_cone_edges=8,
    torsional_friction=0.0,
) -> float:
    """Ferrari-Canny epsilon of a grasp (the L1 variant: total normal force bounded by 1).

    The radius of the largest origin-centred ball inside the convex hull of the columns of :func:`grasp_matrix`;
    parameters as there.

    Returns
    -------
    float
        Dimensionless ``epsilon >= 0``: the largest wrench (torque divided by ``torque_scale``) that the grasp can
        resist in every direction with unit total normal force. 0.0 when not in force closure; see
        :func:`ferrari_canny_from_wrenches`.

    Raises
    ------
    ValueError
        On a bad argument; the message starts with the argument's name.

    Notes
    -----
    Invariant under translating points and centre of mass together, and under scaling points, centre of mass,
    ``torque_scale`` and ``torsional_friction`` by the same factor. Under a rotation of the whole grasp it is
    exactly invariant only for the 24 rotations that map coordinate axes to coordinate axes, with an even
    ``num_cone_edges`` (see :func:`tangent_basis`). Under other rotations each polygonal cone turns about its
    normal, and epsilon stays between its values for friction ``mu cos(pi/m)`` and ``mu / cos(pi/m)`` (the
    polygonal cones inscribed in and circumscribing the true cone).
    """
    return _epsilon(
        _checked_wrenches(points, normals, center_of_mass, friction, torque_scale, num_cone_edges, torsional_friction)
    )


def _force_closure(w: np.ndarray) -> bool:
    if _is_flat(w):
        return False
    nw = w.shape[1]
    # Variables x = [lambda_1 .. lambda_n, t]; maximise t.
    cost = np.zeros(nw + 1)
    cost[-1] = -1.0
    a_eq = np.zeros((7, nw + 1))
    a_eq[:6, :nw] = w
    a_eq[6, :nw] = 1.0
    b_eq = np.zeros(7)
    b_eq[6] = 1.0
    a_ub = np.concatenate([-np.eye(nw), np.ones((nw, 1))], axis=1)  # t - lambda_j <= 0
    b_ub = np.zeros(nw)
    bounds = [(0.0, None)] * nw + [(None, 1.0)]
    res = linprog(cost, A_ub=a_ub, b_ub=b_ub, A_eq=a_eq, b_eq=b_eq, bounds=bounds, method="highs", options=_LP_OPTIONS)
    if res.status == 2:  # infeasible: the origin is not in the hull at all
        return False
    if res.status != 0:
        raise RuntimeError(f"force_closure: linprog failed (status {res.status}): {res.message}")
    return bool(-res.fun > LP_MARGIN_TOL)


def force_closure_from_wrenches(wrenches) -> bool:
    """Whether the origin is strictly inside the convex hull of the wrench columns; a linear program, no hull.

    Formulation: the origin is in the interior of ``conv(w_1..w_n)`` iff ``rank W = 6`` and some strictly positive
    ``lambda`` has ``W lambda = 0``. (All-positive barycentric weights put the origin in the relative interior, and
    the affine hull of a set containing the origin is its span, R^6 at rank 6. Conversely, an interior origin is a
    convex combination of the points and of a small negative multiple of their centroid, whose weights are all
    positive.) Positivity is measured by the margin LP

        maximise t  subject to  W lambda = 0,  sum(lambda) = 1,  lambda_j >= t,  t <= 1,

    solved by HiGHS at 1e-10 feasibility tolerances; force closure iff ``rank W = 6`` (same test as
    :func:`ferrari_canny_from_wrenches`) and ``t* > LP_MARGIN_TOL``.

    Parameters
    ----------
    wrenches : (6, n) float
        Wrench columns.

    Returns
    -------
    bool

    Raises
    ------
    ValueError
        On a bad ``wrenches`` array.
    RuntimeError
        If the LP solver fails (neither optimal nor infeasible).
    """
    return _force_closure(_check_wrenches(wrenches))


def force_closure(
    points,
    normals,
    center_of_mass,
    *,
    friction,
    torque_scale,
    num_cone_edges=8,
    torsional_friction=0.0,
) -> bool:
    """Whether the grasp is in force closure, decided by a linear program (independently of the hull).

    Parameters as in :func:`grasp_matrix`; the formulation is described in :func:`force_closure_from_wrenches`.
    Agrees with ``ferrari_canny(...) > 0`` except within numerical tolerance of the boundary.

    Returns
    -------
    bool

    Raises
    ------
    ValueError
        On a bad argument; the message starts with the argument's name.
    """
    return _force_closure(
        _checked_wrenches(points, normals, center_of_mass, friction, torque_scale, num_cone_edges, torsional_friction)
    )
