"""Grasp-wrench maths for the Ferrari-Canny epsilon: friction cones and the grasp matrix; pure numpy. The decisions on a
wrench set are in :mod:`graspgen.quality.closure`.

Contact ``i`` has a point ``p_i`` (m) and a unit normal ``n_i`` pointing into the object (the finger's push). Its
friction cone has ``m`` edges ``f_ij = n_i + mu (t1_i cos(2 pi j / m) + t2_i sin(2 pi j / m))`` over the tangent
basis of :func:`tangent_basis`; each edge gives the dimensionless wrench ``[f_ij; (p_i - c) x f_ij / torque_scale]``
(``c`` the centre of mass). A soft finger (``torsional_friction`` gamma > 0, m) adds ``[0; +-gamma n_i /
torque_scale]`` per contact. Normals more than :data:`NORMAL_TOL` from unit length raise :class:`SettingsError`;
within it they are renormalised.
"""

from __future__ import annotations

import functools

import numpy as np

from graspgen.errors import SettingsError
from graspgen.validation import check_int, check_number

__all__ = [
    "NORMAL_TOL",
    "tangent_basis",
    "friction_cone_edges",
    "grasp_matrix",
]

#: Allowed deviation of a normal's length from 1 before it is rejected (within it, normals are renormalised).
NORMAL_TOL = 1e-5


# ----------------------------------------------------------------------------------------------------------------
# argument checks


def _check_vectors(name: str, value, k: int | None = None) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise SettingsError(f"{name}: expected shape (k, 3), got {np.shape(value)}")
    if k is not None and arr.shape[0] != k:
        raise SettingsError(f"{name}: expected {k} rows (one per contact, as in points), got {arr.shape[0]}")
    if not np.isfinite(arr).all():
        raise SettingsError(f"{name}: contains NaN or infinite values")
    return arr


def _check_points(points) -> np.ndarray:
    return _check_vectors("points", points)


def _check_normals(normals, k: int | None = None) -> np.ndarray:
    arr = _check_vectors("normals", normals, k)
    length = np.sqrt(np.einsum("ij,ij->i", arr, arr))
    bad = np.abs(length - 1.0) > NORMAL_TOL
    if bad.any():
        i = int(np.argmax(bad))
        raise SettingsError(
            f"normals: must be unit vectors (|length - 1| <= {NORMAL_TOL}); row {i} has length {length[i]:.9g}"
        )
    return arr / length[:, None]


def _check_center_of_mass(center_of_mass) -> np.ndarray:
    arr = np.asarray(center_of_mass, dtype=float)
    if arr.shape != (3,):
        raise SettingsError(f"center_of_mass: expected shape (3,), got {np.shape(center_of_mass)}")
    if not np.isfinite(arr).all():
        raise SettingsError("center_of_mass: contains NaN or infinite values")
    return arr


def _check_wrenches(wrenches) -> np.ndarray:
    arr = np.asarray(wrenches, dtype=float)
    if arr.ndim != 2 or arr.shape[0] != 6:
        raise SettingsError(f"wrenches: expected shape (6, n), got {np.shape(wrenches)}")
    if not np.isfinite(arr).all():
        raise SettingsError("wrenches: contains NaN or infinite values")
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
    """Deterministic orthonormal tangents ``t1, t2`` (k, 3) of unit ``normals`` (k, 3): ``t1 = normalise(n x e_a)`` with
    ``e_a`` the coordinate axis least aligned with ``n``, ``t2 = n x t1``, right-handed. Equivariant only under the 24
    axis-permuting rotations; no continuous choice from ``n`` alone can be under all."""
    return _tangent_basis(_check_normals(normals))


def friction_cone_edges(normals, friction, num_cone_edges=8) -> np.ndarray:
    """Edges of the polyhedral friction cone at each contact (vertices on the true cone): (k, m, 3) float forces per
    unit normal force, each with ``|f_ij| = sqrt(1 + mu^2)``, for unit ``normals`` (k, 3) pointing into the object,
    ``friction`` mu > 0 and ``num_cone_edges`` m >= 3.

    Raises
    ------
    SettingsError
        A bad shape, a non-finite value, non-unit normals, ``friction <= 0`` or ``num_cone_edges < 3``.
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
    """Primitive contact wrenches as the columns of a (6, k m) matrix, or (6, k m + 2k) with ``torsional_friction``.

    Columns ``[f_ij; (p_i - c) x f_ij / torque_scale]``, contact-major in the order of :func:`friction_cone_edges`, then
    the soft-finger columns ``[0; +gamma n_i / torque_scale]``, ``[0; -gamma n_i / torque_scale]`` per contact.

    Parameters
    ----------
    points : (k, 3) float
        Contact points, m (k may be 0).
    normals : (k, 3) float
        Unit contact normals pointing into the object.
    center_of_mass : (3,) float
        Torque reference point, m.
    friction : float
        Coulomb coefficient ``mu > 0``.
    torque_scale : float
        Length dividing torques (e.g. the object's largest radius from the centre of mass), m, ``> 0``.
    num_cone_edges : int
        Cone edges per contact, ``>= 3``.
    torsional_friction : float
        Soft-finger torsional friction ``gamma >= 0`` (m: moment per unit normal force); 0 = point contact.

    Raises
    ------
    SettingsError
        On a bad argument; the message starts with the argument's name.
    """
    return _checked_wrenches(
        points, normals, center_of_mass, friction, torque_scale, num_cone_edges, torsional_friction
    )
