"""Posing and reading a compiled gripper model (:mod:`graspgen.sim.gripper_model`): the TCP pose and its mocap
target, the jaw opening, the linkage's driven joints, and the gripper's geoms by role.

MuJoCo note: with :meth:`mujoco.MjSpec.attach` the order of actuators/joints/geoms depends on the order of attachment,
so every helper here looks elements up by *name* (``prefix`` + local name), never by index. A name that is not in
the model (a wrong ``prefix``) is a :class:`~graspgen.errors.NotFoundError` (also a ``KeyError``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import mujoco
import numpy as np

from graspgen.errors import NotFoundError
from graspgen.sim.poses_mj import pos_quat

__all__ = [
    "set_gripper_target",
    "set_gripper_pose",
    "gripper_pose",
    "set_gripper_width",
    "gripper_width",
    "LinkageCouplings",
    "linkage_couplings",
    "pad_geom_ids",
    "gripper_geom_ids",
]


def _id(model: mujoco.MjModel, objtype, name: str) -> int:
    idx = mujoco.mj_name2id(model, objtype, name)
    if idx < 0:
        kind = mujoco.mjtObj(objtype).name.removeprefix("mjOBJ_").lower()
        raise NotFoundError(f"no {kind} named {name!r} in the model (wrong gripper name_prefix?)")
    return idx


def set_gripper_target(model: mujoco.MjModel, data: mujoco.MjData, T_tcp, *, prefix: str = "gripper/") -> None:
    """Move only the mocap target to TCP pose ``T_tcp`` (4x4, world); the weld pulls the gripper there while
    stepping. Use for smooth motions (approach, lift)."""
    pos, quat = pos_quat(T_tcp, "T_tcp")
    mocap_id = model.body_mocapid[_id(model, mujoco.mjtObj.mjOBJ_BODY, f"{prefix}mocap")]
    data.mocap_pos[mocap_id] = pos
    data.mocap_quat[mocap_id] = quat


def set_gripper_pose(model: mujoco.MjModel, data: mujoco.MjData, T_tcp, *, prefix: str = "gripper/") -> None:
    """Teleport the gripper: put the TCP frame (free joint) AND the mocap target at ``T_tcp`` (4x4, world), zero the
    base velocity, and run ``mj_forward``. Jaw joints are left as they are."""
    pos, quat = pos_quat(T_tcp, "T_tcp")
    set_gripper_target(model, data, T_tcp, prefix=prefix)
    jid = _id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{prefix}free")
    qadr, vadr = model.jnt_qposadr[jid], model.jnt_dofadr[jid]
    data.qpos[qadr:qadr + 3] = pos
    data.qpos[qadr + 3:qadr + 7] = quat
    data.qvel[vadr:vadr + 6] = 0.0
    mujoco.mj_forward(model, data)


def gripper_pose(model: mujoco.MjModel, data: mujoco.MjData, *, prefix: str = "gripper/") -> np.ndarray:
    """Current 4x4 world pose of the TCP frame (needs ``mj_forward``/``mj_step`` to have run)."""
    bid = _id(model, mujoco.mjtObj.mjOBJ_BODY, f"{prefix}base")
    T = np.eye(4)
    T[:3, :3] = data.xmat[bid].reshape(3, 3)
    T[:3, 3] = data.xpos[bid]
    return T


def set_gripper_width(model: mujoco.MjModel, data: mujoco.MjData, width: float, *, prefix: str = "gripper/",
                      instant: bool = False) -> float:
    """Command pad separation ``width`` (m), clipped to ``[min_width, max_width]`` (the actuator's ctrlrange).
    With ``instant=True`` also put the jaws there at once (qpos, zero velocity, ``mj_forward``) -- for opening the
    gripper before it is placed, not for closing on an object. Returns the clipped command."""
    aid = _id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, f"{prefix}width")
    lo, hi = model.actuator_ctrlrange[aid]
    w = float(np.clip(float(width), lo, hi))
    data.ctrl[aid] = w
    if instant:
        for side in ("left", "right"):
            jid = _id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{prefix}{side}_slide")
            data.qpos[model.jnt_qposadr[jid]] = w / 2.0
            data.qvel[model.jnt_dofadr[jid]] = 0.0
        couplings = linkage_couplings(model, prefix=prefix)
        couplings.apply(data.qpos)
        data.qvel[couplings.dofadr] = 0.0
        mujoco.mj_forward(model, data)
    return w


@dataclass(frozen=True)
class LinkageCouplings:
    """The joints a gripper's linkage drives from its jaw slides (the equalities ``<side>_<joint>_coupling``), read
    from a compiled model, to pose them by hand: whoever sets the jaw slides' ``qpos`` directly (placing an open
    gripper, the collision pre-filter) calls :meth:`apply` so that the pads and links sit where the linkage puts
    them. Empty (``apply`` does nothing) for a gripper without a linkage."""

    qposadr: np.ndarray
    """(k,) int: qpos address of each driven joint."""
    dofadr: np.ndarray
    """(k,) int: dof address of each driven joint."""
    slide_qposadr: np.ndarray
    """(k,) int: qpos address of the jaw slide that drives it."""
    ref: np.ndarray
    """(k,) float: each driven joint's reference (``qpos0``; m or rad)."""
    slide_ref: np.ndarray
    """(k,) float: the driving slide's reference (``qpos0``, m)."""
    coef: np.ndarray
    """(k, 5) float: quartic coefficients, ``q - ref = sum coef[j] (q_slide - slide_ref)^j``."""

    def apply(self, qpos: np.ndarray) -> None:
        """Set the driven joints in ``qpos`` (modified in place) from the jaw slides' values there."""
        if len(self.qposadr):
            d = qpos[self.slide_qposadr] - self.slide_ref
            qpos[self.qposadr] = self.ref + self.coef[:, 0] + d * (self.coef[:, 1] + d * (
                self.coef[:, 2] + d * (self.coef[:, 3] + d * self.coef[:, 4])))


def linkage_couplings(model: mujoco.MjModel, *, prefix: str = "gripper/") -> LinkageCouplings:
    """The :class:`LinkageCouplings` of the gripper named ``prefix`` in ``model`` (found by equality names)."""
    rows = []
    for eq in range(model.neq):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_EQUALITY, eq) or ""
        local = name[len(prefix):] if name.startswith(prefix) else ""
        if model.eq_type[eq] != mujoco.mjtEq.mjEQ_JOINT or not re.fullmatch(r"(left|right)_\w+_coupling", local):
            continue
        j1, j2 = int(model.eq_obj1id[eq]), int(model.eq_obj2id[eq])
        q1, q2 = int(model.jnt_qposadr[j1]), int(model.jnt_qposadr[j2])
        rows.append((q1, int(model.jnt_dofadr[j1]), q2, float(model.qpos0[q1]), float(model.qpos0[q2]),
                     np.array(model.eq_data[eq][:5], dtype=float)))
    cols = list(zip(*rows)) if rows else [(), (), (), (), (), ()]
    return LinkageCouplings(
        qposadr=np.array(cols[0], dtype=np.int64), dofadr=np.array(cols[1], dtype=np.int64),
        slide_qposadr=np.array(cols[2], dtype=np.int64), ref=np.array(cols[3], dtype=float),
        slide_ref=np.array(cols[4], dtype=float), coef=np.array(cols[5], dtype=float).reshape(len(rows), 5))


def gripper_width(model: mujoco.MjModel, data: mujoco.MjData, *, prefix: str = "gripper/") -> float:
    """Current pad separation (m): distance between the pads' contact faces along the TCP x axis, from the jaw
    bodies' poses (each jaw's frame is its pad's contact face; needs ``mj_forward``/``mj_step`` to have run)."""
    left = _id(model, mujoco.mjtObj.mjOBJ_BODY, f"{prefix}left_jaw")
    right = _id(model, mujoco.mjtObj.mjOBJ_BODY, f"{prefix}right_jaw")
    x_axis = gripper_pose(model, data, prefix=prefix)[:3, 0]
    return float(np.dot(data.xpos[right] - data.xpos[left], x_axis))


_FINGER_PIECE = re.compile(r"(left|right)_finger_[0-9]+")


def pad_geom_ids(model: mujoco.MjModel, *, prefix: str = "gripper/") -> tuple[tuple[int, ...], tuple[int, ...]]:
    """Geom ids of the (left, right) contact pads, looked up by name."""
    roles = gripper_geom_ids(model, prefix=prefix)
    return roles["left_pad"], roles["right_pad"]


def gripper_geom_ids(model: mujoco.MjModel, *, prefix: str = "gripper/") -> dict[str, tuple[int, ...]]:
    """Geom ids of the gripper by role: ``left_pad``, ``right_pad``, ``pad`` (both), ``finger`` (every piece of both
    finger links), ``palm``, ``all``. Found by name (``<prefix>left_pad``, ``<prefix>left_finger``,
    ``<prefix>left_finger_<k>``, ``<prefix>palm_<k>`` ...), so it works however the gripper was attached."""
    out: dict[str, list[int]] = {"left_pad": [], "right_pad": [], "finger": [], "palm": []}
    for gid in range(model.ngeom):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, gid) or ""
        if not name.startswith(prefix):
            continue
        local = name[len(prefix):]
        if local in ("left_pad", "right_pad"):
            out[local].append(gid)
        elif local in ("left_finger", "right_finger") or _FINGER_PIECE.fullmatch(local):
            out["finger"].append(gid)
        elif local.startswith("palm_"):
            out["palm"].append(gid)
    if not out["left_pad"] or not out["right_pad"]:
        raise NotFoundError(f"no gripper pads named {prefix}left_pad / {prefix}right_pad in the model")
    res = {k: tuple(v) for k, v in out.items()}
    res["pad"] = res["left_pad"] + res["right_pad"]
    res["all"] = res["pad"] + res["finger"] + res["palm"]
    return res
