"""Near misses of the object-centric sets: a copy of a grasp that held, shifted in the plane of its pads or tilted
about its TCP just far enough that the grasp the sampler meant is no longer there
(:mod:`graspgen.workflows.object_grasps`, "Candidates")."""

from __future__ import annotations

import math

import numpy as np

from graspgen.errors import SettingsError
from graspgen.grippers import GripperSpec
from graspgen.quality.perturbation import rotvec_to_matrix

__all__ = ["near_miss_draws", "near_miss_offsets"]


def near_miss_draws(rng: np.random.Generator, n: int) -> np.ndarray:
    """The random part of ``n`` near misses: ``(n, 2)`` uniforms in [0, 1): the kind (< 0.5 shifted, else tilted)
    and the direction (an angle, ``2 pi u``)."""
    return rng.random((n, 2))


def near_miss_offsets(depth: np.ndarray, draws: np.ndarray, gripper: GripperSpec, overhang: float,
                      tilt: float) -> np.ndarray:
    """The near misses' offsets in their parents' TCP frames: ``T_near = T_parent @ D``.

    Parameters
    ----------
    depth : (n,) float, m
        The parents' grasp depths (their contacts at ``(-+width / 2, 0, depth)`` in the TCP frame).
    draws : (n, 2) float in [0, 1)
        :func:`near_miss_draws`: kind (< 0.5 shifted) and direction angle ``phi = 2 pi u``.
    gripper : GripperSpec
        Its ``pad_size`` (width along y, length along z) bounds the pad face, centred on the TCP's y-z origin.
    overhang : float, m
        Shifted: the contact point ends this far beyond the pad face's edge, along the shift.
    tilt : float, rad
        Tilted: the rotation angle.

    Returns
    -------
    D : (n, 4, 4) float
        Shifted: no rotation, a translation ``s (0, cos phi, sin phi)`` with ``s`` such that the parent's contact
        point, which moves by ``-s (0, cos phi, sin phi)`` relative to the pads, crosses the pad face's edge at ``s
        - overhang``. Tilted: no translation, a rotation by ``tilt`` about ``(cos phi, sin phi, 0)`` (through the
        TCP, perpendicular to the approach).
    """
    depth = np.asarray(depth, dtype=np.float64).reshape(-1)
    draws = np.asarray(draws, dtype=np.float64).reshape(-1, 2)
    if len(draws) != len(depth):
        raise SettingsError(f"draws: expected {len(depth)} rows (one per depth), got {len(draws)}")
    n = len(depth)
    phi = 2.0 * math.pi * draws[:, 1]
    c, s = np.cos(phi), np.sin(phi)
    shifted = draws[:, 0] < 0.5
    half_y, half_z = gripper.pad_size[1] / 2.0, gripper.pad_size[2] / 2.0
    # The contact (y, z) = (0, depth) moves along -(c, s) relative to the pads; the distance to the face's edge:
    with np.errstate(divide="ignore"):
        to_y = np.where(np.abs(c) > 1e-12, half_y / np.abs(c), np.inf)
        to_z = np.where(s < -1e-12, (half_z - depth) / -s, np.where(s > 1e-12, (half_z + depth) / s, np.inf))
    distance = np.maximum(np.minimum(to_y, to_z), 0.0) + overhang
    D = np.tile(np.eye(4), (n, 1, 1))
    D[shifted, 1, 3] = (distance * c)[shifted]
    D[shifted, 2, 3] = (distance * s)[shifted]
    axes = np.stack([c, s, np.zeros(n)], axis=1)
    tilted = ~shifted
    if tilted.any():
        D[tilted, :3, :3] = rotvec_to_matrix(tilt * axes[tilted])
    return D
