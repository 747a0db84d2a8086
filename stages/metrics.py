"""Analytic grasp quality: Ferrari-Canny epsilon of a parallel-jaw grasp's contacts, and friction labels.

The wrench maths lives in :mod:`stages.wrench`; this module turns the contacts a grasp produces (from a rollout
or from :func:`stages.contacts.closing_contacts`) into the contact model the metric uses.

Contact models (``contact_model``):

``"pad"`` (default)
    Each pad's contact patch becomes one soft-finger contact at the patch centroid with the mean inward normal.
    Its torsional friction is ``max(torsional_friction, 2/3 * friction * r)`` with ``r`` the patch radius (the
    largest distance of a contact from the centroid, in the tangent plane): the torsional moment a uniformly
    pressed disc of radius ``r`` resists per unit normal force. This keeps the wrench set full-rank for a
    two-pad grasp (two point contacts alone can never resist torque about the line joining them) and costs one
    20-point hull per grasp.
``"points"``
    Every contact point is its own contact with ``torsional_friction``. Slower (a hull of ``k * m`` points).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from stages.wrench import ferrari_canny, ferrari_canny_from_wrenches, force_closure, grasp_matrix

__all__ = [
    "CONTACT_MODELS",
    "ferrari_canny",
    "force_closure",
    "grasp_epsilon",
    "min_closure_friction",
    "pad_contacts",
]

CONTACT_MODELS = ("pad", "points")


def pad_contacts(
    points: np.ndarray, normals: np.ndarray, finger: np.ndarray, *, friction: float, torsional_friction: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One soft-finger contact per pad from its contact patch.

    Parameters
    ----------
    points : (k, 3) float, m
    normals : (k, 3) float, unit, pointing into the object
    finger : (k,) int, pad label of each contact
    friction : float, Coulomb coefficient
    torsional_friction : float, m, the floor of each pad's torsional coefficient

    Returns
    -------
    centroids : (p, 3) float, normals : (p, 3) float (unit), gammas : (p,) float, m; ``p`` = pads that touch.
    """
    centroids, mean_normals, gammas = [], [], []
    for f in np.unique(finger):
        sel = finger == f
        c = points[sel].mean(axis=0)
        n = normals[sel].mean(axis=0)
        norm = np.linalg.norm(n)
        if norm < 1e-9:  # opposite normals on one pad: no meaningful patch normal
            continue
        n = n / norm
        offsets = points[sel] - c
        tangential = offsets - np.outer(offsets @ n, n)
        radius = float(np.linalg.norm(tangential, axis=1).max()) if len(tangential) else 0.0
        centroids.append(c)
        mean_normals.append(n)
        gammas.append(max(torsional_friction, 2.0 / 3.0 * friction * radius))
    return np.array(centroids).reshape(-1, 3), np.array(mean_normals).reshape(-1, 3), np.array(gammas)


def grasp_epsilon(
    points: np.ndarray,
    normals: np.ndarray,
    finger: np.ndarray,
    center_of_mass: np.ndarray,
    *,
    friction: float,
    torque_scale: float,
    torsional_friction: float = 0.0,
    num_cone_edges: int = 8,
    contact_model: str = "pad",
) -> float:
    """Ferrari-Canny epsilon of a grasp's contacts under ``contact_model`` (see the module docstring).

    Parameters
    ----------
    points : (k, 3) float, m, contact points
    normals : (k, 3) float, unit, pointing into the object
    finger : (k,) int, which pad made each contact
    center_of_mass : (3,) float, m, same frame as ``points``
    friction, torque_scale, torsional_friction, num_cone_edges
        As in :func:`stages.wrench.ferrari_canny`.

    Returns
    -------
    float, unit-free: 0 when the contacts are not in force closure (fewer than two pads touching included).
    """
    if contact_model not in CONTACT_MODELS:
        raise ValueError(f"contact_model: must be one of {', '.join(CONTACT_MODELS)}, got {contact_model!r}")
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    finger = np.asarray(finger).reshape(-1)
    if len(points) == 0:
        return 0.0
    if contact_model == "points":
        return ferrari_canny(
            points,
            normals,
            center_of_mass,
            friction=friction,
            torque_scale=torque_scale,
            num_cone_edges=num_cone_edges,
            torsional_friction=torsional_friction,
        )
    centroids, mean_normals, gammas = pad_contacts(
        points, normals, finger, friction=friction, torsional_friction=torsional_friction
    )
    if len(centroids) < 2:
        return 0.0
    columns = [
        grasp_matrix(
            c[None],
            n[None],
            center_of_mass,
            friction=friction,
            torque_scale=torque_scale,
            num_cone_edges=num_cone_edges,
            torsional_friction=g,
        )
        for c, n, g in zip(centroids, mean_normals, gammas)
    ]
    return ferrari_canny_from_wrenches(np.hstack(columns))


def min_closure_friction(
    points: np.ndarray,
    normals: np.ndarray,
    finger: np.ndarray,
    center_of_mass: np.ndarray,
    frictions: Sequence[float],
    *,
    torque_scale: float,
    torsional_friction: float = 0.0,
    num_cone_edges: int = 8,
    contact_model: str = "pad",
) -> float:
    """GraspNet-style label: the smallest friction in ``frictions`` at which the grasp has epsilon > 0.

    Returns NaN when it is not in force closure at any of them.
    """
    for mu in sorted(frictions):
        eps = grasp_epsilon(
            points,
            normals,
            finger,
            center_of_mass,
            friction=mu,
            torque_scale=torque_scale,
            torsional_friction=torsional_friction,
            num_cone_edges=num_cone_edges,
            contact_model=contact_model,
        )
        if eps > 0.0:
            return float(mu)
    return float("nan")
