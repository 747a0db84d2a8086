"""A scene of placed objects on a support, built and settled in MuJoCo and seen by cameras, behind plain functions.

:func:`settle_scene` compiles the scene (:func:`graspgen.sim.scene_model.build_scene_spec`, default
:class:`~graspgen.sim.physics.PhysicsOptions`) and settles it (:func:`graspgen.sim.settle.settle`);
:func:`rest_poses` stops the objects where they are; :func:`object_rgba` and :func:`render_views` read the colours
and render the cameras. :class:`SettledScene` carries the compiled model and its state between them, so callers
outside :mod:`graspgen.sim` handle arrays and never MuJoCo. Lengths in m, times in s.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence

import mujoco
import numpy as np

from graspgen.sim.camera import Camera
from graspgen.sim.physics import PhysicsOptions
from graspgen.sim.render import RenderedView, SceneRenderer
from graspgen.sim.scene_model import PlacedObject, build_scene_spec
from graspgen.sim.scene_state import set_object_poses
from graspgen.sim.settle import SettleParams, SettleResult, settle
from graspgen.sim.support import SupportParams

__all__ = ["SettledScene", "object_rgba", "render_views", "rest_poses", "settle_scene"]


@dataclasses.dataclass(frozen=True, eq=False)
class SettledScene:
    """A compiled scene after :func:`settle_scene`: the model, its state and what the settle did."""

    model: mujoco.MjModel
    """The compiled scene (objects by scene index, support, ground; offscreen buffer of the image size)."""
    data: mujoco.MjData
    """Its state at the end of the settle (velocities as the settle left them until :func:`rest_poses`)."""
    result: SettleResult
    """Simulated time, rest flag, speeds and final poses ``(n, 4, 4)`` of the objects."""


def settle_scene(
    objects: Sequence[PlacedObject], support: SupportParams, params: SettleParams, image_size: tuple[int, int]
) -> SettledScene:
    """Build ``objects`` on ``support`` with the default physics and settle them under ``params``.

    Parameters
    ----------
    objects
        The objects at their placed poses, by scene index.
    support
        The table.
    params
        When the scene counts as settled.
    image_size
        ``(width, height)`` px of the offscreen buffer, for :func:`render_views`.

    Raises
    ------
    SimulationError
        The simulation diverged.
    """
    model = build_scene_spec(objects, support, PhysicsOptions(), image_size=image_size).compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return SettledScene(model, data, settle(model, data, params))


def rest_poses(scene: SettledScene) -> np.ndarray:
    """The objects' poses ``(n, 4, 4) float64`` (mesh frame to world), set again at rest: velocities zeroed,
    ``mj_forward`` run (as a downstream stage loads the scene)."""
    poses = scene.result.poses
    set_object_poses(scene.model, scene.data, poses)
    return poses


def object_rgba(scene: SettledScene, names: Sequence[str]) -> np.ndarray:
    """``(n, 4)`` float32 colour of each object's visual geom, by scene index; ``names`` are the objects' names."""
    model = scene.model
    rgba = np.array([model.geom_rgba[model.geom(f"obj/{i}_{name}/visual").id] for i, name in enumerate(names)])
    return rgba.astype(np.float32).reshape(len(names), 4)


def render_views(
    scene: SettledScene, width: int, height: int, cameras: Sequence[Camera]
) -> tuple[list[RenderedView], float, float]:
    """RGB, depth and segmentation of every camera (``width`` x ``height`` px) in the scene's current state.

    Returns
    -------
    views : list of RenderedView
        One per camera, in order.
    setup_seconds, render_seconds : float
        Wall-clock seconds to set the renderer up and to render the views.

    Raises
    ------
    RenderError
        No OpenGL back end can render in this process.
    """
    t0 = time.perf_counter()
    with SceneRenderer(scene.model, width, height) as renderer:
        t1 = time.perf_counter()
        views = [renderer.render(scene.data, cam) for cam in cameras]
        t_render = time.perf_counter() - t1
    return views, time.perf_counter() - t0 - t_render, t_render
