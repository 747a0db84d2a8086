"""Whether a grasp's wrenches hold: the Ferrari-Canny epsilon from their convex hull, and force closure by a linear
program.

The wrench columns come from :func:`graspgen.quality.wrench.grasp_matrix` (the contact model is there). Pure
numpy/scipy; usable without the pipeline.

The grasp wrench space is ``conv(columns)`` (total normal force bounded by 1) and the Ferrari-Canny epsilon is the
radius of the largest origin-centred ball inside it; 0 when the origin is not strictly inside.

Why the rank check: two point contacts cannot resist torque about the line joining them, so their wrenches lie in
a 5-D subspace of R^6. Qhull cannot build a 6-D hull of a flat set, and joggling (option ``QJ``) only hides that by
fabricating a thin hull. So the rank is tested first and a flat set scores 0.0; ``QJ`` is never used.

Two independent decisions are offered and agree (``tests/graspgen/quality/test_wrench.py`` checks it on 1,000
random grasps):

* :func:`ferrari_canny` -- exact epsilon from the hull facets (``scipy.spatial.ConvexHull``);
* :func:`force_closure` -- a linear program (``scipy.optimize.linprog``), no hull: the origin is strictly inside
  ``conv(W)`` iff ``rank W = 6`` and some strictly positive ``lambda`` has ``W lambda = 0``.

Tolerances
----------
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

import numpy as np
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, QhullError

from graspgen.errors import GraspGenError
from graspgen.quality.wrench import _check_wrenches, _checked_wrenches

__all__ = [
    "EPSILON_TOL",
    "RANK_RTOL",
    "LP_MARGIN_TOL",
    "ferrari_canny",
    "ferrari_canny_from_wrenches",
    "force_closure",
    "force_closure_from_wrenches",
]

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
        Wrench columns, e.g. from :func:`~graspgen.quality.wrench.grasp_matrix`, dimensionless.

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

    The radius of the largest origin-centred ball inside the convex hull of the columns of
    :func:`~graspgen.quality.wrench.grasp_matrix`; parameters as there.

    Returns
    -------
    float
        Dimensionless ``epsilon >= 0``: the largest wrench (torque divided by ``torque_scale``) that the grasp can
        resist in every direction with unit total normal force. 0.0 when not in force closure; see
        :func:`ferrari_canny_from_wrenches`.

    Raises
    ------
    SettingsError
        On a bad argument; the message starts with the argument's name.

    Notes
    -----
    Invariant under translating points and centre of mass together, and under scaling points, centre of mass,
    ``torque_scale`` and ``torsional_friction`` by the same factor. Under a rotation of the whole grasp it is
    exactly invariant only for the 24 rotations that map coordinate axes to coordinate axes, with an even
    ``num_cone_edges`` (see :func:`~graspgen.quality.wrench.tangent_basis`). Under other rotations each polygonal cone
    turns about its normal, and epsilon stays between its values for friction ``mu cos(pi/m)`` and ``mu / cos(pi/m)``
    (the polygonal cones inscribed in and circumscribing the true cone).
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
        raise GraspGenError(f"force_closure: linprog failed (status {res.status}): {res.message}")
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
    SettingsError
        On a bad ``wrenches`` array.
    GraspGenError
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

    Parameters as in :func:`~graspgen.quality.wrench.grasp_matrix`; the formulation is described in
    :func:`force_closure_from_wrenches`. Agrees with ``ferrari_canny(...) > 0`` except within numerical tolerance of the
    boundary.

    Returns
    -------
    bool

    Raises
    ------
    SettingsError
        On a bad argument; the message starts with the argument's name.
    """
    return _force_closure(
        _checked_wrenches(points, normals, center_of_mass, friction, torque_scale, num_cone_edges, torsional_friction)
    )
