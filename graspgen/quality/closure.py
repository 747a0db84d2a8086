"""Whether a grasp's wrenches hold: the Ferrari-Canny epsilon from their convex hull, and force closure by a linear
program; pure numpy/scipy.

The wrench columns come from :func:`graspgen.quality.wrench.grasp_matrix` (the contact model is there). Epsilon is
the radius of the largest origin-centred ball inside ``conv(columns)`` (total normal force bounded by 1): 0.0 when
the columns are flat (rank < 6, tested before qhull), when the origin is not strictly inside, or at or below
:data:`EPSILON_TOL`. :func:`force_closure` decides independently, without a hull; the two agree but within tolerance
of the boundary. Why rank first, the checked fast hull and the LP: docs/decisions/2026-11-22-epsilon-hull.md.
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
    """Ferrari-Canny epsilon (>= 0, in the wrenches' units) of ``wrenches`` (6, n): the radius of the largest
    origin-centred ball inside their convex hull; 0.0 as the module docstring says, or when qhull finds the input
    degenerate even with merging. Invariant under any orthogonal map of R^6."""
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
    """Ferrari-Canny epsilon of a grasp (the L1 variant: total normal force bounded by 1); parameters as in
    :func:`~graspgen.quality.wrench.grasp_matrix`.

    Returns
    -------
    float
        Dimensionless ``epsilon >= 0``: the largest wrench (torque over ``torque_scale``) the grasp resists in every
        direction with unit total normal force; 0.0 when not in force closure.

    Raises
    ------
    SettingsError
        On a bad argument; the message starts with the argument's name.

    Notes
    -----
    Invariant under translating points and centre of mass together and under scaling lengths together; under rotations
    only for the 24 axis-permuting ones with even ``num_cone_edges``, else bounded by the values for friction
    ``mu cos(pi/m)`` and ``mu / cos(pi/m)``.
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
    """Whether the origin is strictly inside the convex hull of ``wrenches`` (6, n): rank 6 and a margin LP over
    strictly positive weights ``lambda`` with ``W lambda = 0`` (``t* > LP_MARGIN_TOL``); no hull.

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
    """Whether the grasp is in force closure, by the linear program of :func:`force_closure_from_wrenches`; parameters
    as in :func:`~graspgen.quality.wrench.grasp_matrix`. Raises :class:`SettingsError` on a bad argument."""
    return _force_closure(
        _checked_wrenches(points, normals, center_of_mass, friction, torque_scale, num_cone_edges, torsional_friction)
    )
