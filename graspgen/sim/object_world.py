"""One object alone in MuJoCo, in free space or on a table, with a gripper: the world
:func:`graspgen.workflows.evaluate.evaluate_grasps` rolls grasps out in.

:class:`ObjectWorld` holds plain arrays and settings (cheap to pickle to workers, unlike a compiled model);
:func:`world_spec` builds its MuJoCo model, :func:`world_simulator` and :func:`world_warp_simulator` its simulators,
:func:`settled_object_pose` the pose the object settles into on the table. Lengths in m.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from graspgen.grippers import load_gripper
from graspgen.sim.gripper_model import attach_gripper
from graspgen.sim.lift import LiftSimulator
from graspgen.sim.protocols import LiftParams
from graspgen.sim.scene_model import PlacedObject, build_scene_spec, free_space_spec
from graspgen.sim.scene_state import object_poses
from graspgen.sim.settle import SettleParams, settle
from graspgen.sim.support import SupportParams
from graspgen.sim.warp_backend import WarpLiftSimulator, WarpParams

__all__ = ["ObjectWorld", "settled_object_pose", "world_simulator", "world_spec", "world_warp_simulator"]


@dataclasses.dataclass(frozen=True, eq=False)
class ObjectWorld:
    """What a worker needs to build its model (plain arrays: cheap to pickle, unlike a compiled model)."""

    obj: PlacedObject
    """The object, placed (its pose: the identity in free space, else settled on the support)."""
    support: SupportParams | None
    """The table; None: free space."""
    gripper: str
    """A bundled gripper name or the path of a gripper file (what :func:`load_gripper` takes)."""
    lift: LiftParams
    """The protocol and its settings."""


def _object_spec(obj: PlacedObject, support: SupportParams | None, lift: LiftParams) -> mujoco.MjSpec:
    """The object (and table) as an MjSpec; without a support, the ground and table are removed: free space."""
    physics = lift.physics_options((0.0, 0.0, -9.81))
    if support is None:
        return free_space_spec(obj, physics)
    return build_scene_spec([obj], support, physics)


def settled_object_pose(obj: PlacedObject, support: SupportParams, lift: LiftParams) -> np.ndarray:
    """``(4, 4) float64`` pose (mesh frame to world) of ``obj`` after settling on ``support`` from ``obj.pose`` under
    ``lift``'s physics and the default :class:`~graspgen.sim.settle.SettleParams` (without the gripper: it starts at
    the origin, which the object's resting place may overlap).

    Raises
    ------
    SimulationError
        The simulation diverged.
    """
    model = _object_spec(obj, support, lift).compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    settle(model, data, SettleParams())
    return object_poses(model, data)[0]


def world_spec(world: ObjectWorld, visual: tuple[np.ndarray, np.ndarray] | None = None) -> mujoco.MjSpec:
    """The world as an MjSpec with the gripper attached; ``visual`` ``(vertices (v, 3) m, faces (f, 3))`` adds the
    object's visual mesh (drawn only: the physics and the joints are those of the model without it)."""
    obj = world.obj if visual is None else dataclasses.replace(world.obj, visual=visual)
    spec = _object_spec(obj, world.support, world.lift)
    attach_gripper(spec, load_gripper(world.gripper))
    return spec


def world_simulator(world: ObjectWorld) -> LiftSimulator:
    """The world compiled with the gripper, in a fresh model: one grasp at a time, on the CPU."""
    return LiftSimulator(world_spec(world).compile(), world.lift)


def world_warp_simulator(world: ObjectWorld, warp: WarpParams | None = None) -> WarpLiftSimulator:
    """The world compiled with the gripper on the MuJoCo Warp backend (batches of ``warp.nworld`` grasps).

    Raises
    ------
    MissingDependencyError
        ``mujoco_warp`` or ``warp`` is not installed.
    """
    return WarpLiftSimulator(world_spec(world).compile(), world.lift, warp)
