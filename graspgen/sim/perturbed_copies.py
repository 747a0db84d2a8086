"""Perturbed copies of a scene's simulator: the target moved, made heavier or lighter, its centre of mass moved and
its friction changed (:func:`with_object_pose`), where it rests (:func:`support_points`), and a rollout that also
reports where the target was (:func:`rollout_with_object_pose`).

The copies share the compiled scene of :func:`graspgen.workflows.rollouts.scene_simulator`; each perturbed one is a deep
copy of its ``MjModel`` (~1 ms) with its mass-dependent constants recomputed. The perturbation model itself (what is
drawn) is :mod:`graspgen.quality.perturbation`.
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np

from graspgen.errors import SettingsError
from graspgen.geometry.poses import pose_from_pos_mat
from graspgen.sim.lift import LiftSimulator
from graspgen.sim.poses_mj import pos_quat, pose_from_pos_quat
from graspgen.sim.protocols import RolloutResult

__all__ = [
    "SUPPORT_TOLERANCE",
    "initial_object_pose",
    "rollout_with_object_pose",
    "support_points",
    "target_friction",
    "with_object_pose",
]


def _free_qadr(model: mujoco.MjModel, body: int) -> int:
    """qpos address of the free joint of ``body`` (an object of the scene)."""
    jnt = int(model.body_jntadr[body])
    if jnt < 0 or model.jnt_type[jnt] != mujoco.mjtJoint.mjJNT_FREE:
        raise SettingsError(f"target_body: body {body} has no free joint")
    return int(model.jnt_qposadr[jnt])


def initial_object_pose(simulator: LiftSimulator, target_body: str) -> np.ndarray:
    """(4, 4) pose (mesh frame to world) of ``target_body`` in the model's ``qpos0``: the scene at rest for a
    simulator built by :func:`graspgen.workflows.rollouts.scene_simulator` (object noise is applied to this pose)."""
    m = simulator.model
    bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, target_body)
    if bid < 0:
        raise SettingsError(f"target_body: no body named {target_body!r}")
    a = _free_qadr(m, bid)
    return pose_from_pos_quat(m.qpos0[a : a + 3], m.qpos0[a + 3 : a + 7])


def with_object_pose(simulator: LiftSimulator, target_body: str, T_world_object: np.ndarray | None,
                      mass_scale: float = 1.0, com_offset: np.ndarray | None = None,
                      friction: float | None = None) -> LiftSimulator:
    """A simulator of the same scene whose initial configuration has ``target_body`` at ``T_world_object`` (None:
    where it is), with the target's mass and inertia times ``mass_scale``, its centre of mass moved by
    ``com_offset (3,)`` m (body frame = mesh frame) and the sliding friction of its geoms set to ``friction``."""
    m = copy.deepcopy(simulator.model)
    bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, target_body)
    a = _free_qadr(m, bid)
    qpos = m.qpos0.copy()
    if T_world_object is not None:
        qpos[a : a + 3], qpos[a + 3 : a + 7] = pos_quat(T_world_object)
    m.body_mass[bid] *= mass_scale
    m.body_inertia[bid] *= mass_scale
    if com_offset is not None and np.any(com_offset):
        m.body_ipos[bid] += com_offset
        # A body compiled with its inertial frame on its own frame is flagged simple; the moved centre breaks that.
        m.body_simple[bid] = 0
        m.body_sameframe[bid] = 0
    if friction is not None:
        m.geom_friction[m.geom_bodyid == bid, 0] = friction
    # Constants that depend on the masses (the constraint solver's inverse weights, subtree masses), recomputed at
    # the model's qpos0 as at compile time.
    mujoco.mj_setConst(m, mujoco.MjData(m))
    # The simulator's model already carries the protocol's physics and grip force; applying them again is a no-op.
    return LiftSimulator(m, simulator.params, qpos=qpos, prefix=simulator.prefix)


SUPPORT_TOLERANCE = 5e-5
"""Height (m) over the target's lowest collision vertex within which a vertex counts as resting on what holds it up
(:func:`support_points`). The settle leaves a face lying flat level to a few micrometres, while the next vertex
line of a faceted cylinder on its side stands 0.12 mm up (a 64-gon of 25 mm radius): counting it would widen the
support to a facet the cylinder does not rest on, and centres moved over it roll the cylinder (measured: up to
2.6 mm of drift at 0.2 mm, none over 0.12 mm at this value). Too small a value only shrinks the polygon, which
keeps less of the drawn offsets: the safe side."""

def support_points(simulator: LiftSimulator, target_body: str) -> np.ndarray:
    """Where ``target_body`` rests on what holds it up, in the simulator's initial configuration ``model.qpos0`` (the
    scene at rest): the vertices of its collision meshes within :data:`SUPPORT_TOLERANCE` of its lowest one, when
    something other than the gripper touches it there. Taken from the geometry, not from MuJoCo's contact points:
    those of a convex mesh on a box are a few points placed by the collision routine, not the supporting face.

    Returns
    -------
    (k, 3) float
        Points, m, in the target's body frame (the mesh frame); ``k = 0`` when nothing holds it up from below (an
        object in free space).
    """
    m = simulator.model
    bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, target_body)
    if bid < 0:
        raise SettingsError(f"target_body: no body named {target_body!r}")
    d = mujoco.MjData(m)
    d.qpos[:] = m.qpos0
    mujoco.mj_forward(m, d)
    vertices = []
    for g in np.flatnonzero((m.geom_bodyid == bid) & (m.geom_type == mujoco.mjtGeom.mjGEOM_MESH)
                            & ((m.geom_contype != 0) | (m.geom_conaffinity != 0))):
        mesh = int(m.geom_dataid[g])
        start, count = int(m.mesh_vertadr[mesh]), int(m.mesh_vertnum[mesh])
        local = m.mesh_vert[start:start + count].astype(np.float64)
        vertices.append(local @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g])
    if not vertices:
        return np.zeros((0, 3))
    world = np.concatenate(vertices)
    low = float(world[:, 2].min())
    held = False
    for c in d.contact[: d.ncon]:
        b1, b2 = int(m.geom_bodyid[c.geom1]), int(m.geom_bodyid[c.geom2])
        other = b2 if b1 == bid else b1 if b2 == bid else -1
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, other) if other >= 0 else None
        if other >= 0 and other != bid and not (name or "").startswith(simulator.prefix) \
                and c.pos[2] <= low + SUPPORT_TOLERANCE + 1e-3:
            held = True
            break
    if not held:
        return np.zeros((0, 3))
    bottom = world[world[:, 2] <= low + SUPPORT_TOLERANCE]
    R, t = d.xmat[bid].reshape(3, 3), d.xpos[bid]
    return (bottom - t) @ R


def target_friction(simulator: LiftSimulator, target_body: str) -> float:
    """Sliding friction of the target's colliding geoms in the simulator's model (the largest, should they differ;
    visual-only geoms keep MuJoCo's default 1 and do not count)."""
    m = simulator.model
    bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, target_body)
    colliding = (m.geom_bodyid == bid) & ((m.geom_contype != 0) | (m.geom_conaffinity != 0))
    if not colliding.any():
        raise SettingsError(f"target_body: body {target_body!r} has no colliding geom")
    return float(m.geom_friction[colliding, 0].max())


class _TargetPoses:
    """Rollout observer that keeps the target's pose at placement and at the last check of the closing phase. The
    latter is the state the rollout's contacts are read from (no step happens between that check and the contact
    read-out), so contacts and pose come from the same ``mj_step`` (its collision detection and its ``xpos``/``xmat``).
    """

    def __init__(self, data: mujoco.MjData, body: int) -> None:
        self.data, self.body = data, body
        self.placed: np.ndarray | None = None
        self.closed: np.ndarray | None = None

    def __call__(self, phase: str, steps: int) -> None:
        if phase == "closing":
            self.closed = pose_from_pos_mat(self.data.xpos[self.body], self.data.xmat[self.body])
        elif phase == "placement":
            self.placed = pose_from_pos_mat(self.data.xpos[self.body], self.data.xmat[self.body])


def rollout_with_object_pose(
    simulator: LiftSimulator, T_world_tcp: np.ndarray, width: float, target_body: str
) -> tuple[RolloutResult, np.ndarray, np.ndarray | None]:
    """Roll out one grasp and also return the target's poses (4, 4), mesh frame to world: at placement (before any
    step), and when the contacts were recorded (the end of closing; None when the rollout ended before closing)."""
    bid = mujoco.mj_name2id(simulator.model, mujoco.mjtObj.mjOBJ_BODY, target_body)
    observer = _TargetPoses(simulator.data, bid)
    result = simulator.rollout(T_world_tcp, width, target_body, observer=observer)
    assert observer.placed is not None  # the protocol reports the placement before anything can stop it
    return result, observer.placed, observer.closed
