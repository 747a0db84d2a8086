"""Pose and quaternion helpers in numpy: the one place for them (the MuJoCo-backed conversions between rotation
matrices and quaternions are in :mod:`graspgen.sim.poses_mj`, since ``mujoco.mju_mat2Quat``'s bits are what the
simulator's states are made of).

Conventions: a pose is a ``(4, 4)`` rigid transform (rotation block and translation, last row ``0 0 0 1``);
quaternions are MuJoCo's ``(w, x, y, z)``; angles in radians, positions in metres.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["pose_from_pos_mat", "quat_mul", "rotation_angle", "rotation_angles"]


def pose_from_pos_mat(pos, mat) -> np.ndarray:
    """The pose with translation ``pos`` and rotation ``mat``.

    Parameters
    ----------
    pos : (3,) float
        Translation, m.
    mat : (9,) or (3, 3) float
        Rotation matrix, row-major (MuJoCo's ``xmat`` layout).

    Returns
    -------
    (4, 4) float64
        A new array.
    """
    pose = np.eye(4)
    pose[:3, :3] = np.asarray(mat, dtype=np.float64).reshape(3, 3)
    pose[:3, 3] = pos
    return pose


def quat_mul(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Hamilton products ``q * r`` of quaternions (w, x, y, z).

    Parameters
    ----------
    q : (4,) or (n, 4) float
        Left factor: one quaternion for every row of ``r``, or one per row.
    r : (n, 4) float
        Right factors.

    Returns
    -------
    (n, 4) float64
        ``q * r[i]`` (or ``q[i] * r[i]``), row by row; not renormalised.
    """
    w0, x0, y0, z0 = q.T
    w1, x1, y1, z1 = r.T
    return np.stack([w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1,
                     w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1,
                     w0 * y1 - x0 * z1 + y0 * w1 + z0 * x1,
                     w0 * z1 + x0 * y1 - y0 * x1 + z0 * w1], axis=1)


def rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Rotation angle between two rotation matrices.

    atan2(sin, cos) of ``R = Ra^T Rb``, not acos of the trace alone: acos loses all precision near 0 (an angle
    below ~1e-8 rad reads as exactly 0, one of 1e-4 rad is off by percent).

    Parameters
    ----------
    Ra, Rb : (3, 3) float
        Rotation matrices.

    Returns
    -------
    float
        The angle in ``[0, pi]``, rad.
    """
    R = Ra.T @ Rb
    c = (R[0, 0] + R[1, 1] + R[2, 2] - 1.0) / 2.0
    s = 0.5 * math.sqrt((R[2, 1] - R[1, 2]) ** 2 + (R[0, 2] - R[2, 0]) ** 2 + (R[1, 0] - R[0, 1]) ** 2)
    return math.atan2(s, c)


def rotation_angles(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """:func:`rotation_angle` of many pairs at once (same formula; the batched products may differ from it in the
    last bits, to ~1e-14 rad).

    Parameters
    ----------
    Ra, Rb : (n, 3, 3) float
        Rotation matrices.

    Returns
    -------
    (n,) float64
        The angles in ``[0, pi]``, rad.
    """
    R = np.einsum("nji,njk->nik", Ra, Rb)
    c = (R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2] - 1.0) / 2.0
    s = 0.5 * np.sqrt((R[:, 2, 1] - R[:, 1, 2]) ** 2 + (R[:, 0, 2] - R[:, 2, 0]) ** 2 + (R[:, 1, 0] - R[:, 0, 1]) ** 2)
    return np.arctan2(s, c)
