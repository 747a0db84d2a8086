"""A gripper alone, posed open or closed, as MuJoCo renders it or as the outlines of its collision geoms: the numbers
behind :func:`graspgen.viz.gripper_picture.gripper_picture`. Lengths in m, images uint8 RGB.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from graspgen.grippers import GripperSpec
from graspgen.sim.camera import Camera
from graspgen.sim.gripper_model import attach_gripper, build_gripper
from graspgen.sim.gripper_state import gripper_geom_ids, set_gripper_pose, set_gripper_width
from graspgen.sim.render import SceneRenderer

__all__ = ["gripper_geom_points", "render_gripper"]


def render_gripper(
    spec: GripperSpec, pose: np.ndarray, widths: Sequence[float], cameras: Sequence[Camera], px: int
) -> dict[tuple[float, int], np.ndarray]:
    """MuJoCo renders of the gripper with its TCP at ``pose (4, 4)`` (world), opened to each of ``widths`` (m), from
    each of ``cameras`` (``px`` x ``px``; a headlight and one directional light).

    Returns
    -------
    dict
        ``{(width, camera index): (px, px, 3) uint8 RGB}``.

    Raises
    ------
    RenderError
        No OpenGL back end can render in this process.
    """
    world = mujoco.MjSpec()
    world.visual.global_.offwidth = px
    world.visual.global_.offheight = px
    light = world.worldbody.add_light()
    light.pos = [0.3, -0.6, 0.8]
    light.dir = [-0.3, 0.6, -0.8]
    attach_gripper(world, spec)
    model = world.compile()
    data = mujoco.MjData(model)
    out = {}
    with SceneRenderer(model, px, px) as renderer:
        for width in widths:
            set_gripper_pose(model, data, pose)
            set_gripper_width(model, data, width, instant=True)
            for k, camera in enumerate(cameras):
                out[width, k] = renderer.render(data, camera, rgb=True).rgb
    return out


def gripper_geom_points(
    spec: GripperSpec, pose: np.ndarray, widths: Sequence[float]
) -> dict[float, list[tuple[np.ndarray, np.ndarray]]]:
    """The gripper's collision geoms with its TCP at ``pose (4, 4)`` (world), opened to each of ``widths`` (m).

    Returns
    -------
    dict
        ``{width: [(points (k, 3) float64 world m, rgb (3,) float32 in [0, 1]), ...]}``, one entry per geom: a mesh
        geom's vertices, a box's eight corners.
    """
    model = build_gripper(spec).compile()
    data = mujoco.MjData(model)
    roles = gripper_geom_ids(model)
    out: dict[float, list[tuple[np.ndarray, np.ndarray]]] = {}
    for width in widths:
        set_gripper_pose(model, data, pose)
        set_gripper_width(model, data, width, instant=True)
        geoms = []
        for g in roles["all"]:
            R, p = data.geom_xmat[g].reshape(3, 3), data.geom_xpos[g]
            if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
                m = model.geom_dataid[g]
                local = model.mesh_vert[model.mesh_vertadr[m]:model.mesh_vertadr[m] + model.mesh_vertnum[m]]
            else:
                local = np.array(np.meshgrid(*[[-h, h] for h in model.geom_size[g]])).reshape(3, -1).T
            geoms.append((local @ R.T + p, np.array(model.geom_rgba[g][:3])))
        out[width] = geoms
    return out
