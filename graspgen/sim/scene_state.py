"""The objects' state in a compiled scene model: which bodies and geoms are which, and the object poses and
speeds read from (and written to) ``qpos`` / ``qvel``.

The names and geom groups are those of :mod:`graspgen.sim.scene_model`: object bodies ``obj/<i>_<name>`` with a
free joint, numbered 0..n-1 by scene index; support geoms ``support/...``; the ground plane ``ground``. Poses are
(4, 4) mesh-to-world transforms; quaternions go through MuJoCo's own conversions
(:mod:`graspgen.sim.poses_mj`), so a pose written and read back keeps MuJoCo's bits.
"""

from __future__ import annotations

import mujoco
import numpy as np

from graspgen.errors import SettingsError
from graspgen.sim.poses_mj import pos_quat, pose_from_pos_quat
from graspgen.sim.scene_model import (
    GROUP_COLLISION,
    GROUP_VISUAL,
    OBJECT_PREFIX,
    SEG_BACKGROUND,
    SEG_GROUND,
    SEG_SUPPORT,
)
from graspgen.sim.support import GROUND_NAME, SUPPORT_PREFIX
from graspgen.validation import check_transforms

__all__ = [
    "geom_labels",
    "object_bodies",
    "object_geom_ids",
    "object_poses",
    "object_speeds",
    "set_object_poses",
    "support_geom_ids",
]


def object_bodies(model: mujoco.MjModel) -> list[tuple[int, str, int]]:
    """``(scene index, object name, body id)`` of every ``obj/`` body, sorted by scene index."""
    found = []
    for b in range(model.nbody):
        name = model.body(b).name
        if name.startswith(OBJECT_PREFIX) and "/" not in name[len(OBJECT_PREFIX) :]:
            index, _, obj_name = name[len(OBJECT_PREFIX) :].partition("_")
            found.append((int(index), obj_name, b))
    found.sort()
    if [i for i, _, _ in found] != list(range(len(found))):
        raise SettingsError(f"model: object bodies must be numbered 0..n-1, got {[i for i, _, _ in found]}")
    return found


def _free_joint_adr(model: mujoco.MjModel, body: int) -> tuple[int, int]:
    jnt = model.body_jntadr[body]
    if jnt < 0 or model.jnt_type[jnt] != mujoco.mjtJoint.mjJNT_FREE:
        raise SettingsError(f"model: body {model.body(body).name!r} has no free joint")
    return int(model.jnt_qposadr[jnt]), int(model.jnt_dofadr[jnt])


def object_poses(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """(n, 4, 4) float64 mesh-to-world poses of the scene's objects, by scene index, from ``data.qpos``.

    Read from the free joints (not ``xpos``/``xmat``), so no ``mj_forward`` is needed after setting ``qpos``.
    """
    poses = []
    for _, _, body in object_bodies(model):
        q, _ = _free_joint_adr(model, body)
        quat = data.qpos[q + 3 : q + 7] / np.linalg.norm(data.qpos[q + 3 : q + 7])
        poses.append(pose_from_pos_quat(data.qpos[q : q + 3], quat))
    return np.array(poses, dtype=np.float64).reshape(-1, 4, 4)


def set_object_poses(model: mujoco.MjModel, data: mujoco.MjData, poses: np.ndarray) -> None:
    """Put the objects at ``poses`` ((n, 4, 4), by scene index) at rest (zero velocity); then ``mj_forward``."""
    poses = np.asarray(poses, dtype=float)
    bodies = object_bodies(model)
    if poses.shape != (len(bodies), 4, 4):
        raise SettingsError(f"poses: must have shape ({len(bodies)}, 4, 4) for this model, got {poses.shape}")
    check_transforms("poses", poses)
    for (_, _, body), pose in zip(bodies, poses):
        q, v = _free_joint_adr(model, body)
        pos, quat = pos_quat(pose)
        data.qpos[q : q + 3] = pos
        data.qpos[q + 3 : q + 7] = quat
        data.qvel[v : v + 6] = 0.0
    mujoco.mj_forward(model, data)


def object_speeds(model: mujoco.MjModel, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
    """Linear speed (m/s, of the mesh-frame origin) and angular speed (rad/s) of each object, (n,) each."""
    lin, ang = [], []
    for _, _, body in object_bodies(model):
        _, v = _free_joint_adr(model, body)
        lin.append(np.linalg.norm(data.qvel[v : v + 3]))
        ang.append(np.linalg.norm(data.qvel[v + 3 : v + 6]))
    return np.array(lin), np.array(ang)


def geom_labels(model: mujoco.MjModel) -> np.ndarray:
    """(ngeom,) int32: each geom's object index, or :data:`SEG_SUPPORT`, :data:`SEG_GROUND`, or
    :data:`SEG_BACKGROUND` for geoms that are none of these (e.g. an attached gripper)."""
    labels = np.full(model.ngeom, SEG_BACKGROUND, dtype=np.int32)
    index_of_body = {body: index for index, _, body in object_bodies(model)}
    for g in range(model.ngeom):
        name = model.geom(g).name
        body = int(model.geom_bodyid[g])
        if body in index_of_body and name.startswith(OBJECT_PREFIX):
            labels[g] = index_of_body[body]
        elif name.startswith(SUPPORT_PREFIX):
            labels[g] = SEG_SUPPORT
        elif name == GROUND_NAME:
            labels[g] = SEG_GROUND
    return labels


def object_geom_ids(model: mujoco.MjModel, index: int, *, collision: bool = True) -> tuple[int, ...]:
    """Geom ids of the object with scene index ``index``: its collision parts (default) or its visual geoms."""
    group = GROUP_COLLISION if collision else GROUP_VISUAL
    labels = geom_labels(model)
    return tuple(int(g) for g in np.flatnonzero(labels == index) if model.geom_group[g] == group)


def support_geom_ids(model: mujoco.MjModel, *, ground: bool = True) -> tuple[int, ...]:
    """Geom ids of the support boxes, and of the ground plane unless ``ground=False``."""
    labels = geom_labels(model)
    wanted = (SEG_SUPPORT, SEG_GROUND) if ground else (SEG_SUPPORT,)
    return tuple(int(g) for g in np.flatnonzero(np.isin(labels, wanted)))
