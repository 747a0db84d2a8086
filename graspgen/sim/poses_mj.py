"""Pose <-> (position, quaternion) conversions by MuJoCo's own ``mju_mat2Quat`` / ``mju_quat2Mat``, so a pose
written into ``qpos`` or a mocap target has exactly the bits MuJoCo would compute. The numpy pose helpers are in
:mod:`graspgen.geometry.poses`.
"""

from __future__ import annotations

import mujoco
import numpy as np

from graspgen.geometry.poses import pose_from_pos_mat
from graspgen.validation import check_transform

__all__ = ["pos_quat", "pose_from_pos_quat"]


def pos_quat(T, name: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Position and MuJoCo quaternion of a pose.

    Parameters
    ----------
    T : array-like, (4, 4)
        The pose.
    name : str, optional
        When given, ``T`` is checked as a rigid transform first (``graspgen.validation.check_transform``), and a
        :class:`graspgen.errors.SettingsError` names ``name``; when None, ``T`` is only read as float64.

    Returns
    -------
    pos : (3,) float64
        A copy of the translation, m.
    quat : (4,) float64
        Unit quaternion (w, x, y, z) of the rotation block, by ``mujoco.mju_mat2Quat``.
    """
    T = np.asarray(T, dtype=np.float64) if name is None else check_transform(name, T)
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(T[:3, :3]).reshape(-1))
    return T[:3, 3].copy(), quat


def pose_from_pos_quat(pos, quat) -> np.ndarray:
    """The pose with translation ``pos (3,)`` m and the rotation of quaternion ``quat (4,)`` (w, x, y, z, taken as
    unit: normalise it first where it may not be), by ``mujoco.mju_quat2Mat``; ``(4, 4) float64``."""
    mat = np.empty(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, dtype=np.float64))
    return pose_from_pos_mat(pos, mat)
