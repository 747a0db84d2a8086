"""Settling a scene in MuJoCo: simulate until every object rests (mean speeds over check windows) or time runs out.

Rest is judged on *mean* speeds over a window, not on instantaneous velocities (see :class:`SettleParams`); the
same model and state settle to the same bits.
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from graspgen.errors import SimulationError
from graspgen.sim.scene_state import object_bodies, object_poses
from graspgen.validation import check, check_number

__all__ = ["SettleParams", "SettleResult", "settle"]


@dataclasses.dataclass(frozen=True)
class SettleParams:
    """When a scene counts as settled (config section ``scenes.settle``).

    Rest is judged on *mean* speeds over a check window (displacement / ``check_every``), not on instantaneous
    velocities: a long object resting on the facets of its convex parts chatters at a few mm/s and several
    0.01 rad/s in MuJoCo's soft contacts while going nowhere (measured: a bottle on its side, position constant
    to 0.1 mm over 4 s).
    """

    max_time: float = 3.0
    """Longest simulated settle, s; objects still moving then are treated as unstable."""
    min_time: float = 0.3
    """Shortest simulated settle, s: an object slowly starting to topple is still slow at first."""
    linear_speed: float = 0.001
    """At rest below this mean speed of every object's centre of mass over a check window, m/s."""
    angular_speed: float = 0.01
    """At rest below this mean angular speed of every object over a check window, rad/s."""
    check_every: float = 0.1
    """Length of a check window, s; two calm windows in a row (after ``min_time``) end the settle."""
    drop_height: float = 0.001
    """Objects start this far above their resting height, m (so they do not start in contact)."""

    def __post_init__(self) -> None:
        check_number("max_time", self.max_time, low=0.0, low_open=True)
        check_number("min_time", self.min_time)
        check("min_time", 0 <= self.min_time <= self.max_time, "be in [0, max_time]", self.min_time)
        check_number("linear_speed", self.linear_speed, low=0.0, low_open=True)
        check_number("angular_speed", self.angular_speed, low=0.0, low_open=True)
        check_number("check_every", self.check_every)
        check("check_every", 0 < self.check_every <= self.max_time, "be in (0, max_time]", self.check_every)
        check_number("drop_height", self.drop_height, low=0.0, high=0.05)


@dataclasses.dataclass(frozen=True, eq=False)
class SettleResult:
    """What a settle did: :func:`settle` (a scene, ``n`` objects) or
    :func:`graspgen.sim.stable_poses.settle_pose` (one object dropped onto a plane, ``n = 1``)."""

    time: float
    """Simulated time, s."""
    at_rest: bool
    """Every object is at rest: for :func:`settle` calm in the last two check windows, for ``settle_pose`` finite
    and slower than its rest limits at the last step."""
    linear_speed: np.ndarray
    """(n,) speed of each object, m/s: for :func:`settle` the mean speed of its centre of mass over the last check
    window, for ``settle_pose`` the speed of its mesh-frame origin at the last step."""
    angular_speed: np.ndarray
    """(n,) angular speed of each object, rad/s: for :func:`settle` the mean over the last check window (rotation
    angle / window), for ``settle_pose`` at the last step."""
    poses: np.ndarray
    """(n, 4, 4) float64 each object's pose (mesh frame to world) at the end, m."""

    def moving(self, params: SettleParams) -> np.ndarray:
        """(n,) bool: objects not calm in the last window under ``params``' thresholds."""
        return (self.linear_speed >= params.linear_speed) | (self.angular_speed >= params.angular_speed)


def _com_and_rotation(model: mujoco.MjModel, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    bodies = [b for _, _, b in object_bodies(model)]
    com = np.einsum("nij,nj->ni", poses[:, :3, :3], model.body_ipos[bodies]) + poses[:, :3, 3]
    return com, poses[:, :3, :3]


def settle(model: mujoco.MjModel, data: mujoco.MjData, params: SettleParams) -> SettleResult:
    """Simulate from the current state until every object is at rest or ``params.max_time`` has passed.

    At rest: in two consecutive windows of ``check_every`` every object's centre of mass moved less than
    ``linear_speed * check_every`` and it turned less than ``angular_speed * check_every``; and at least
    ``min_time`` was simulated.

    Deterministic: the same model and state give the same result. The state is left at the end of the settle
    (velocities not zeroed: read the poses with :func:`~graspgen.sim.scene_state.object_poses`, zero them with
    :func:`~graspgen.sim.scene_state.set_object_poses`).
    """
    steps_per_check = max(1, int(round(params.check_every / model.opt.timestep)))
    window = steps_per_check * model.opt.timestep
    max_checks = max(1, int(math.ceil(params.max_time / window - 1e-9)))
    calm = 0
    poses = object_poses(model, data)
    com, rot = _com_and_rotation(model, poses)
    lin = ang = np.zeros(len(com))
    for _ in range(max_checks):
        mujoco.mj_step(model, data, nstep=steps_per_check)
        if not (np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))):
            raise SimulationError("scene simulation diverged (non-finite state); check the object masses and meshes")
        poses = object_poses(model, data)
        new_com, new_rot = _com_and_rotation(model, poses)
        lin = np.linalg.norm(new_com - com, axis=1) / window
        cos = (np.einsum("nij,nij->n", new_rot, rot) - 1) / 2  # trace(R_new R_old^T) = 1 + 2 cos(angle)
        ang = np.arccos(np.clip(cos, -1.0, 1.0)) / window
        com, rot = new_com, new_rot
        calm = calm + 1 if np.all(lin < params.linear_speed) and np.all(ang < params.angular_speed) else 0
        if calm >= 2 and data.time >= params.min_time - 1e-9:
            break
    return SettleResult(time=float(data.time), at_rest=calm >= 2, linear_speed=lin, angular_speed=ang, poses=poses)
