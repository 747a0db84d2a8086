"""Where a perturbed copy's centre of mass may go: a resting object's centre stays over its support.

A copy's centre-of-mass offset (:mod:`graspgen.quality.perturbation`) is drawn freely and then made consistent with
the object resting, stably, where it was seen (:func:`resting_com_offset`): the support polygon (from the
support points, :func:`graspgen.sim.perturbed_copies.support_points`) as half-planes, the tipping margin as
linear constraints, and the nearest admissible centre by least-distance programming. Pure numpy and scipy.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import nnls
from scipy.spatial import ConvexHull, QhullError

from graspgen.errors import SettingsError

__all__ = ["TIPPING_MARGIN_FLOOR", "resting_com_offset"]

TIPPING_MARGIN_FLOOR = math.radians(10.0)
"""A copy's centre of mass keeps the object at least as hard to tip as the nominal one, or this hard (rad), whichever
is less (:func:`resting_com_offset`). The tipping angle about a support edge is ``atan(d / h)``: ``d`` the centre's
horizontal distance inside that edge, ``h`` its height over the support. 10 degrees is far above what the settle
and the contact solver's softness tilt a resting object (well under a degree) and what a brushing finger does; a
nominal object resting with less (a cylinder on its side: a facet of a few mm, ~3 degrees) keeps its own."""


def _support_halfplanes(polygon: np.ndarray) -> tuple[np.ndarray, np.ndarray] | tuple[np.ndarray, np.ndarray, float,
                                                                                      float]:
    """The support polygon ``(k, 2)`` as half-planes or, when it has no area, as a segment.

    Returns ``(normals (e, 2), offsets (e,))``, inward unit normals of the convex hull's edges (inside is ``normals @ x
    - offsets >= 0``, that value being the distance inside each edge); or, for collinear points (a cylinder on its
    side resting on one line of vertices) or a single point, ``(centre (2,), direction (2,), lo, hi)``: the segment
    ``centre + s direction`` for ``s`` in ``[lo, hi]``."""
    centre = polygon.mean(axis=0)
    spread = polygon - centre
    _, sv, vt = np.linalg.svd(spread, full_matrices=False)
    flat = len(polygon) < 3 or sv[0] == 0.0 or sv[1] <= 1e-6 * sv[0]
    if not flat:
        try:
            hull = ConvexHull(polygon)
        except QhullError:  # nearly collinear beyond the tolerance above
            flat = True
    if flat:
        u = vt[0] if sv[0] > 0 else np.array([1.0, 0.0])
        along = spread @ u
        return centre, u, float(along.min()), float(along.max())
    return -hull.equations[:, :2], hull.equations[:, 2]  # qhull's normals are outward and unit


def resting_com_offset(offset: np.ndarray, support: np.ndarray, T_world_object: np.ndarray,
                       center_of_mass: np.ndarray) -> np.ndarray:
    """A centre-of-mass offset consistent with the object resting, stably, where it was seen.

    An object seen at rest has its centre of mass over its support polygon (the convex hull of where it touches what
    holds it, seen from above), and it stays put when nudged. A drawn offset that breaks either would tip or roll the
    object before the hand arrives: a different scene, not a heavier side of this one. So the shifted centre ``c``
    must keep, on every support edge, a tipping angle ``atan(d_e(c) / h(c))`` (``d_e`` its horizontal distance
    inside edge ``e``, ``h`` its height over the support) of at least ``min(nominal angle,``
    :data:`TIPPING_MARGIN_FLOOR` ``)``. These are linear constraints on ``c`` (a convex polyhedron holding the nominal
    centre); the drawn centre is replaced by the nearest point in it at the same height (a least-distance program),
    or, where no point at that height qualifies, by the nearest point in it. A box flat on a face
    keeps millimetre offsets whole; a cylinder on its side (resting on a line of its facets) keeps the shift along its
    axis and the vertical one, not the one across (which would roll it). No support (free space): the offset as given. A
    nominal centre not over its support (the object leans on a neighbour, the polygon says nothing of its balance):
    the offset without its horizontal part.

    Parameters
    ----------
    offset : (3,) float
        Drawn offset, m, mesh frame.
    support : (k, 3) float
        :func:`graspgen.sim.perturbed_copies.support_points`, mesh frame.
    T_world_object : (4, 4) float
        The object's pose (mesh frame to world) at rest.
    center_of_mass : (3,) float
        Nominal centre of mass, m, mesh frame.

    Returns
    -------
    (3,) float
        The offset, m, mesh frame.
    """
    offset = np.asarray(offset, dtype=np.float64).reshape(3)
    support = np.asarray(support, dtype=np.float64).reshape(-1, 3)
    if len(support) == 0 or not offset.any():
        return offset.copy()
    T = np.asarray(T_world_object, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    points = support @ R.T + t
    c0 = R @ np.asarray(center_of_mass, dtype=np.float64).reshape(3) + t
    w = R @ offset
    z_support = float(points[:, 2].mean())
    h0 = c0[2] - z_support
    support_2d = _support_halfplanes(points[:, :2])
    if len(support_2d) == 4:  # a line: the centre stays on it, within its ends
        centre, u, lo, hi = support_2d
        across = np.array([-u[1], u[0]]) @ (c0[:2] - centre)
        if abs(across) > 1e-6 or h0 <= 0.0:
            w[:2] = 0.0  # leaning on something: the support line does not decide its balance
            return R.T @ w
        along = float(np.clip(u @ (c0[:2] + w[:2] - centre), lo, hi))
        w[:2] = centre + across * np.array([-u[1], u[0]]) + along * u - c0[:2]
        return R.T @ w
    normals, offsets = support_2d
    inside = normals @ c0[:2] - offsets
    if inside.min() < -1e-6 or h0 <= 0.0:
        w[:2] = 0.0  # leaning on something: the support polygon does not decide its balance
        return R.T @ w
    slope = min(max(float(inside.min()), 0.0) / h0, math.tan(TIPPING_MARGIN_FLOOR))  # tan of the tipping angle
    # Constraints a_e . c >= b_e: d_e(c) - slope * (c_z - z_support) >= 0.
    A = np.column_stack([normals, np.full(len(normals), -slope)])
    b = offsets - slope * z_support
    c = c0 + w
    if np.all(A @ c - b >= -1e-12):
        return offset.copy()
    try:  # the drawn height kept, the horizontal position pulled back
        c[:2] = _project_onto_halfspaces(c[:2], normals, offsets + slope * (c[2] - z_support))
    except SettingsError:  # raised so far that no position keeps the margin: the height gives way too
        c = _project_onto_halfspaces(c, A, b)
    return R.T @ (c - c0)


def _project_onto_halfspaces(x: np.ndarray, A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The point of ``{y : A @ y >= b}`` (non-empty) nearest ``x (n,)``: least-distance programming by non-negative
    least squares (Lawson and Hanson, "Solving Least Squares Problems", 1974, ch. 23): with ``G = A``,
    ``h = b - A x``, minimise ``|E u - f|`` over ``u >= 0`` for ``E = [G^T; h^T]``, ``f = (0, ..., 0, 1)``; the
    residual ``r = E u - f`` gives the step ``z = -r[:n] / r[n]``. Exact up to round-off, no iteration count."""
    h = b - A @ x
    if np.all(h <= 0.0):
        return x.copy()
    E = np.vstack([A.T, h[None, :]])
    f = np.zeros(len(x) + 1)
    f[-1] = 1.0
    u, _ = nnls(E, f)
    r = E @ u - f
    if abs(r[-1]) < 1e-12:
        raise SettingsError("A, b: the constraints have no common point")
    y = x - r[:-1] / r[-1]
    if np.any(A @ y - b < -1e-9 * max(1.0, float(np.abs(b).max()))):
        raise SettingsError("A, b: the constraints have no common point (or are too ill-conditioned to tell)")
    return y
