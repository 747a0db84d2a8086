"""Scenes as MuJoCo models: objects resting on a support, a settle loop, pinhole cameras and a headless renderer.

Shared by the stages that work in a scene (scenes, grasp collision pre-filter, rollouts), so everything here is a
plain function of its arguments: no globals, no randomness except through an ``rng`` argument.

Frames and units
----------------
* World frame: z up, metres. **The support's top surface is the plane z = 0**: the table top (and the floor of
  a bin) is at z = 0, the table body is a box below it, and the ground plane lies at z = -``SupportParams.height``.
  Objects resting on the table therefore have exactly the stable poses of the objects stage (which rest on z = 0),
  up to a yaw and an x/y shift.
* Object poses are 4x4 transforms of the object's *mesh frame* (the frame of its object shard) to the world. The
  MuJoCo body of an object *is* its mesh frame (its inertial frame sits at the centre of mass), so a body's
  ``xpos``/``xmat`` is the object pose.

Naming and geom groups (so a later stage can tell support, target and clutter apart by name)
--------------------------------------------------------------------------------------------
* object body (free joint): ``obj/<i>_<name>``, i = the object's index in the scene (0-based);
* its collision parts (mesh geoms, group 3, collide, hidden in images): ``obj/<i>_<name>/part_<k>``;
* its visual mesh (group 1, rendered, no contacts, no mass): ``obj/<i>_<name>/visual``;
* support boxes (static, group 0): ``support/table``, ``support/wall_px|nx|py|ny`` (bin),
  ``support/shelf_board``, ``support/shelf_post_px|nx`` (shelf);
* ground plane (static, group 0, 5 m x 5 m): ``ground``, at z = -table height.

Which object is the *target* of a grasp is a choice of the grasp stage; every other ``obj/`` geom is clutter
(:func:`geom_labels` maps any geom to its object index, :data:`SEG_SUPPORT` or :data:`SEG_GROUND`). Collision
parts are in group 3, which MuJoCo's viewer and renderer hide by default, so images show the true visual mesh.

Physics: :class:`graspgen.sim.grippers.PhysicsOptions` (2 ms, elliptic cones, impratio 10, implicitfast); mass,
centre of mass and inertia come from the object record (``inertiafromgeom`` is off), never from the geoms.
Friction: objects carry their own sliding friction; support geoms carry ``SupportParams.friction``. MuJoCo has
no per-pair friction: at equal priority it uses the *larger* of the two geoms' coefficients.

Cameras (OpenCV convention)
---------------------------
A :class:`Camera` is intrinsics ``K`` (3, 3) and extrinsics ``T_world_camera`` (4, 4, camera-to-world) in the
**OpenCV camera frame: x right, y down, z forward** (the optical axis). Pixel (u, v) = (column, row) has its
centre at integer coordinates, so the image spans u in [-0.5, width - 0.5]. A point p_c in the camera frame
projects to ``K @ p_c / p_c[2]``. (MuJoCo's own cameras look along -z with y up; :class:`SceneRenderer` sets the
OpenGL camera directly from ``K`` and ``T_world_camera``, so no MuJoCo camera element is involved and any
fx, fy, cx, cy is rendered exactly.)

Images: depth is float32 metres along the optical axis (the camera-frame z, not the ray length), **0 where
nothing was hit**; segmentation is int16 with the object index (0..n-1) for objects and the negative codes
:data:`SEG_BACKGROUND` (-1, nothing), :data:`SEG_SUPPORT` (-2) and :data:`SEG_GROUND` (-3).

Headless rendering
------------------
Shadows and reflections are off; lighting is a headlight plus one directional light. MuJoCo picks its OpenGL
backend from the environment variable ``MUJOCO_GL`` when it is first imported:
``egl`` (needs ``libEGL`` and Mesa: Debian/Ubuntu ``libegl1 libgl1-mesa-dri``; Mesa's llvmpipe renders on the
CPU, no GPU needed) or ``osmesa`` (``libosmesa6``). :func:`graspgen.sim.gl.select_backend` chooses it before
this module imports mujoco (``egl`` when libEGL loads, else ``osmesa`` when libOSMesa loads, else nothing), so
importing this module never needs OpenGL; :class:`SceneRenderer` raises :class:`RenderError` in one line when
no back end can render. Image bytes are deterministic for one GL implementation (Mesa
llvmpipe here: the same view renders to the same bytes whatever was rendered before, in any process); another
driver (a GPU's EGL) may differ in the last bit of some pixels, and so in the shard bytes.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Sequence
from typing import Any, Literal

from graspgen.sim.gl import HOW_TO_FIX, backend_in_use, render_problem, select_backend

select_backend()  # MuJoCo reads MUJOCO_GL once, at its first import: choose a headless back end before that.

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from graspgen.errors import RenderError, SimulationError  # noqa: E402
from graspgen.sim.grippers import PhysicsOptions  # noqa: E402
from graspgen.validation import (  # noqa: E402
    check,
    check_instance,
    check_number,
    check_positive_int,
    check_transform,
    check_transforms,
)

__all__ = [
    "GROUP_SUPPORT",
    "GROUP_VISUAL",
    "GROUP_COLLISION",
    "OBJECT_PREFIX",
    "SUPPORT_PREFIX",
    "GROUND_NAME",
    "SEG_BACKGROUND",
    "SEG_SUPPORT",
    "SEG_GROUND",
    "SupportParams",
    "SupportBox",
    "PlacedObject",
    "SettleParams",
    "SettleResult",
    "Camera",
    "RenderedView",
    "RenderError",
    "SceneRenderer",
    "support_boxes",
    "free_region",
    "placed_object",
    "object_body_name",
    "build_scene_spec",
    "free_space_spec",
    "object_bodies",
    "object_poses",
    "set_object_poses",
    "object_speeds",
    "geom_labels",
    "object_geom_ids",
    "support_geom_ids",
    "settle",
    "pose_to_pos_quat",
    "intrinsics_from_fov",
    "camera_on_sphere",
    "project",
    "backproject",
    "transform_points",
    "depth_noise",
]

GROUP_SUPPORT = 0
"""Geom group of the support boxes and the ground plane (rendered and colliding)."""
GROUP_VISUAL = 1
"""Geom group of the objects' visual meshes (rendered, no contacts)."""
GROUP_COLLISION = 3
"""Geom group of the objects' convex collision parts (colliding, hidden by MuJoCo's default render options)."""

OBJECT_PREFIX = "obj/"
SUPPORT_PREFIX = "support/"
GROUND_NAME = "ground"

SEG_BACKGROUND = -1
"""Segmentation id of pixels where nothing was hit (depth 0 there)."""
SEG_SUPPORT = -2
"""Segmentation id of the support (table top, bin walls, shelf)."""
SEG_GROUND = -3
"""Segmentation id of the ground plane."""

_OBJECT_FRICTION_EXTRA = (0.005, 0.0001)
"""Torsional (m) and rolling (m) friction of object and support geoms (only used with condim > 3)."""
_SUPPORT_RGBA = {"table": (0.72, 0.58, 0.42, 1.0), "wall": (0.45, 0.55, 0.65, 1.0), "shelf": (0.6, 0.48, 0.35, 1.0)}
_GROUND_RGBA = (0.3, 0.3, 0.32, 1.0)
_GROUND_HALF_SIZE = 2.5
"""Half extent of the ground plane, m."""
_PALETTE = (
    (0.90, 0.30, 0.25),
    (0.25, 0.55, 0.90),
    (0.30, 0.75, 0.35),
    (0.95, 0.75, 0.20),
    (0.65, 0.40, 0.80),
    (0.20, 0.75, 0.75),
    (0.95, 0.55, 0.65),
    (0.55, 0.55, 0.20),
)
"""Object colours by scene index (cycled): images are for looking at, so only distinctness matters."""


# ---------------------------------------------------------------------------------------------------------------
# Support
# ---------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class SupportParams:
    """What the objects stand on (config section ``scenes.support``). Lengths in m; the top surface is z = 0."""

    kind: Literal["table", "bin", "shelf"] = "table"
    """``table``: a table top; ``bin``: the table plus four walls around the placement area; ``shelf``: the table
    plus a board above it, carried by two posts at the table's x ends."""
    size: tuple[float, float] = (0.6, 0.6)
    """Table top extents along x and y, m."""
    height: float = 0.75
    """Table height, m: the ground plane is at z = -height."""
    area: tuple[float, float] = (0.3, 0.3)
    """Placement area (x, y extents, m), centred on the table: object positions are drawn in it. For a bin, the
    inner size of the bin."""
    wall_height: float = 0.08
    """Bin wall height above the table top, m."""
    wall_thickness: float = 0.01
    """Bin wall (and shelf post) thickness, m."""
    shelf_height: float = 0.3
    """Clear height between the table top and the underside of the shelf board, m."""
    shelf_thickness: float = 0.02
    """Shelf board thickness, m."""
    friction: float = 0.8
    """Sliding friction of the support and the ground (MuJoCo uses the larger of the two geoms' values)."""

    def __post_init__(self) -> None:
        check("kind", self.kind in ("table", "bin", "shelf"), "be one of table, bin, shelf", self.kind)
        check("size", len(self.size) == 2 and all(s > 0 for s in self.size), "be two lengths > 0", self.size)
        check("height", self.height > 0, "be > 0", self.height)
        check("area", len(self.area) == 2 and all(a > 0 for a in self.area), "be two lengths > 0", self.area)
        check("area", all(a <= s for a, s in zip(self.area, self.size)), f"fit on the table top {self.size}", self.area)
        check("wall_height", self.wall_height > 0, "be > 0", self.wall_height)
        check("wall_thickness", self.wall_thickness > 0, "be > 0", self.wall_thickness)
        check("shelf_height", self.shelf_height > 0, "be > 0", self.shelf_height)
        check("shelf_thickness", self.shelf_thickness > 0, "be > 0", self.shelf_thickness)
        check("friction", self.friction > 0, "be > 0", self.friction)
        if self.kind == "bin":
            outer = [a + 2 * self.wall_thickness for a in self.area]
            check(
                "area", all(o <= s for o, s in zip(outer, self.size)), "plus the bin walls fit on the table", self.area
            )
        if self.kind == "shelf":
            inner = self.size[0] - 2 * self.wall_thickness
            check("area", self.area[0] <= inner, f"fit between the shelf posts ({inner:.3f} m along x)", self.area)


@dataclasses.dataclass(frozen=True)
class SupportBox:
    """One static box of the support."""

    name: str
    """Geom name, ``support/<what>``."""
    center: tuple[float, float, float]
    """Box centre in the world frame, m."""
    size: tuple[float, float, float]
    """Full extents along world x, y, z, m (not MuJoCo's half sizes)."""


def support_boxes(support: SupportParams) -> list[SupportBox]:
    """The static boxes of ``support`` (axis-aligned, world frame); the ground plane is not included."""
    sx, sy = support.size
    h = support.height
    boxes = [SupportBox(f"{SUPPORT_PREFIX}table", (0.0, 0.0, -h / 2), (sx, sy, h))]
    t = support.wall_thickness
    if support.kind == "bin":
        ax, ay = support.area
        wh = support.wall_height
        boxes += [
            SupportBox(f"{SUPPORT_PREFIX}wall_px", (ax / 2 + t / 2, 0.0, wh / 2), (t, ay + 2 * t, wh)),
            SupportBox(f"{SUPPORT_PREFIX}wall_nx", (-ax / 2 - t / 2, 0.0, wh / 2), (t, ay + 2 * t, wh)),
            SupportBox(f"{SUPPORT_PREFIX}wall_py", (0.0, ay / 2 + t / 2, wh / 2), (ax, t, wh)),
            SupportBox(f"{SUPPORT_PREFIX}wall_ny", (0.0, -ay / 2 - t / 2, wh / 2), (ax, t, wh)),
        ]
    elif support.kind == "shelf":
        sh, st = support.shelf_height, support.shelf_thickness
        boxes += [
            SupportBox(f"{SUPPORT_PREFIX}shelf_board", (0.0, 0.0, sh + st / 2), (sx, sy, st)),
            SupportBox(f"{SUPPORT_PREFIX}shelf_post_px", (sx / 2 - t / 2, 0.0, sh / 2), (t, sy, sh)),
            SupportBox(f"{SUPPORT_PREFIX}shelf_post_nx", (-sx / 2 + t / 2, 0.0, sh / 2), (t, sy, sh)),
        ]
    return boxes


def free_region(support: SupportParams) -> tuple[np.ndarray, np.ndarray, float]:
    """Where an object's footprint may lie on the support: the x/y box ``[lo, hi]`` and the highest z it may reach.

    Table: the table top, no height limit. Bin: inside the walls. Shelf: between the posts, below the board.

    Returns
    -------
    lo, hi : (2,) float
        Corners of the allowed footprint region, m.
    z_max : float
        Highest allowed point of an object, m (``inf`` when unbounded).
    """
    half = np.asarray(support.size, dtype=float) / 2
    if support.kind == "bin":
        half = np.asarray(support.area, dtype=float) / 2
        return -half, half, math.inf
    if support.kind == "shelf":
        half = half - np.array([support.wall_thickness, 0.0])
        return -half, half, support.shelf_height
    return -half, half, math.inf


# ---------------------------------------------------------------------------------------------------------------
# Objects
# ---------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class PlacedObject:
    """An object at a pose in a scene: what :func:`build_scene_spec` needs of it."""

    name: str
    """Object name (the objects stage's task id); part of the body name."""
    convex_parts: Sequence[tuple[np.ndarray, np.ndarray]]
    """Convex collision parts, each (vertices (v, 3) float m, faces (f, 3) int), mesh frame."""
    mass: float
    """kg."""
    center_of_mass: np.ndarray
    """(3,) float, m, mesh frame."""
    inertia: np.ndarray
    """(3, 3) float, kg m^2 about the centre of mass, mesh frame axes."""
    pose: np.ndarray
    """(4, 4) float, mesh frame to world."""
    friction: float
    """Sliding friction coefficient (dimensionless)."""
    visual: tuple[np.ndarray, np.ndarray] | None = None
    """Visual mesh (vertices (v, 3) float m, faces (f, 3) int), mesh frame; None renders the convex parts."""
    rgba: tuple[float, float, float, float] | None = None
    """Colour; None picks one from a fixed palette by scene index."""

    def __post_init__(self) -> None:
        check_transform(f"{self.name}.pose", self.pose)
        check(f"{self.name}.convex_parts", len(self.convex_parts) > 0, "hold at least one part", self.convex_parts)
        check_number(f"{self.name}.mass", self.mass, low=0.0, low_open=True)
        check_number(f"{self.name}.friction", self.friction, low=0.0, low_open=True)


def placed_object(record: Any, pose: np.ndarray, friction: float, *, rgba=None, visual: bool = True) -> PlacedObject:
    """A :class:`PlacedObject` from an :class:`graspgen.io.objects.ObjectRecord` (``read_object``) at ``pose``."""
    return PlacedObject(
        name=record.name,
        convex_parts=record.convex_parts,
        mass=float(record.mass),
        center_of_mass=np.asarray(record.center_of_mass, dtype=float),
        inertia=np.asarray(record.inertia, dtype=float),
        pose=np.asarray(pose, dtype=float),
        friction=float(friction),
        visual=(record.vertices, record.faces) if visual else None,
        rgba=rgba,
    )


def object_body_name(index: int, name: str) -> str:
    """Body name of the object with scene index ``index``: ``obj/<index>_<name>``."""
    return f"{OBJECT_PREFIX}{index}_{name}"


def pose_to_pos_quat(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(position (3,), MuJoCo quaternion w, x, y, z (4,)) of a (4, 4) transform."""
    pose = np.asarray(pose, dtype=float)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(pose[:3, :3]).ravel())
    return pose[:3, 3].copy(), quat


def _pose_from_pos_mat(pos: np.ndarray, xmat: np.ndarray) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = np.asarray(xmat, dtype=float).reshape(3, 3)
    pose[:3, 3] = pos
    return pose


# ---------------------------------------------------------------------------------------------------------------
# The model
# ---------------------------------------------------------------------------------------------------------------


def build_scene_spec(
    objects: Sequence[PlacedObject],
    support: SupportParams,
    physics: PhysicsOptions | None = None,
    *,
    image_size: tuple[int, int] = (640, 480),
) -> mujoco.MjSpec:
    """An :class:`mujoco.MjSpec` of ``objects`` at their poses on ``support`` (see the module docstring).

    Each object is a free body ``obj/<i>_<name>`` at ``pose`` (so ``qpos0`` is the given pose) with explicit
    mass, centre of mass and inertia, one mesh geom per convex part (group 3, contacts) and, when it has one, its
    visual mesh (group 1, no contacts). The support is static boxes ``support/...`` (group 0) above a ground
    plane ``ground``. Two lights (a headlight and a directional light from above) without shadows.

    Parameters
    ----------
    objects : sequence of PlacedObject
        In scene-index order; the index is part of each body name.
    support : SupportParams
        The table / bin / shelf.
    physics : PhysicsOptions, optional
        Timestep, cones, impratio, integrator, gravity; default ``PhysicsOptions()``.
    image_size : (width, height)
        Largest image a :class:`SceneRenderer` may render of the model (MuJoCo's offscreen buffer size).

    Returns
    -------
    mujoco.MjSpec
        Compile with ``spec.compile()``; attach a gripper to it with :func:`graspgen.sim.grippers.attach_gripper`.
    """
    check_instance("support", support, SupportParams)
    spec = mujoco.MjSpec()
    spec.modelname = "scene"
    (physics or PhysicsOptions()).apply(spec)
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    spec.visual.global_.offwidth = int(image_size[0])
    spec.visual.global_.offheight = int(image_size[1])
    spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
    spec.visual.headlight.diffuse = [0.45, 0.45, 0.45]
    spec.visual.headlight.specular = [0.1, 0.1, 0.1]
    # Near/far clip planes as fractions of the model extent: 1 cm .. 10 m for a scene of ~1 m.
    spec.visual.map.znear = 0.01
    spec.visual.map.zfar = 10.0
    light = spec.worldbody.add_light(name="sun", pos=[0.3, -0.4, 2.0], dir=[-0.15, 0.2, -1.0])
    light.type = mujoco.mjtLightType.mjLIGHT_DIRECTIONAL
    light.castshadow = False
    light.diffuse = [0.5, 0.5, 0.5]

    friction = [support.friction, *_OBJECT_FRICTION_EXTRA]
    spec.worldbody.add_geom(
        name=GROUND_NAME,
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        # Finite (5 m x 5 m): MuJoCo draws an infinite plane around the previous frame's camera, so its depth
        # would depend on what was rendered before (measured: 1-ulp differences on ground pixels).
        size=[_GROUND_HALF_SIZE, _GROUND_HALF_SIZE, 0.25],
        pos=[0.0, 0.0, -support.height],
        friction=friction,
        rgba=list(_GROUND_RGBA),
        group=GROUP_SUPPORT,
    )
    for box in support_boxes(support):
        kind = box.name[len(SUPPORT_PREFIX) :].split("_")[0]
        spec.worldbody.add_geom(
            name=box.name,
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[s / 2 for s in box.size],
            pos=list(box.center),
            friction=friction,
            rgba=list(_SUPPORT_RGBA.get(kind, _SUPPORT_RGBA["table"])),
            group=GROUP_SUPPORT,
        )
    for index, obj in enumerate(objects):
        _add_object(spec, index, obj)
    return spec


def free_space_spec(obj: PlacedObject, physics: PhysicsOptions | None = None) -> mujoco.MjSpec:
    """One object alone in free space: :func:`build_scene_spec` of ``[obj]`` with the ground and the support removed.

    The object is the free body ``obj/0_<name>`` at ``obj.pose`` and nothing else can be touched: the world of the
    free-space protocols (``acronym``, ``graspgen``; ``table`` with ``gravity_until_closed``) used by
    :func:`graspgen.evaluate.evaluate_grasps` and :mod:`graspgen.sim.object_grasps`.

    Parameters
    ----------
    obj : PlacedObject
        The object; ``pose`` places its mesh frame in the world (the identity keeps world = mesh frame).
    physics : PhysicsOptions, optional
        Timestep, cones, impratio, integrator, gravity; default ``PhysicsOptions()``.

    Returns
    -------
    mujoco.MjSpec
        Compile with ``spec.compile()``; attach a gripper with :func:`graspgen.sim.grippers.attach_gripper`.
    """
    spec = build_scene_spec([obj], SupportParams(), physics)
    for geom in list(spec.geoms):
        if geom.name == GROUND_NAME or geom.name.startswith(SUPPORT_PREFIX):
            spec.delete(geom)
    return spec


def _add_object(spec: mujoco.MjSpec, index: int, obj: PlacedObject) -> None:
    name = object_body_name(index, obj.name)
    pos, quat = pose_to_pos_quat(obj.pose)
    body = spec.worldbody.add_body(name=name, pos=pos.tolist(), quat=quat.tolist())
    body.add_freejoint(name=f"{name}/free")
    body.explicitinertial = True
    body.mass = float(obj.mass)
    body.ipos = np.asarray(obj.center_of_mass, dtype=float).tolist()
    i = np.asarray(obj.inertia, dtype=float)
    body.fullinertia = [i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]]
    rgba = list(obj.rgba) if obj.rgba is not None else [*_PALETTE[index % len(_PALETTE)], 1.0]
    friction = [obj.friction, *_OBJECT_FRICTION_EXTRA]
    for k, (vertices, faces) in enumerate(obj.convex_parts):
        mesh = f"{name}/part_{k}"
        spec.add_mesh(
            name=mesh,
            uservert=np.asarray(vertices, dtype=np.float64).ravel().tolist(),
            userface=np.asarray(faces, dtype=np.int32).ravel().tolist(),
        )
        body.add_geom(
            name=mesh,
            type=mujoco.mjtGeom.mjGEOM_MESH,
            meshname=mesh,
            friction=friction,
            group=GROUP_COLLISION,
            rgba=rgba,
        )
    if obj.visual is not None:
        mesh = f"{name}/visual"
        vertices, faces = obj.visual
        spec.add_mesh(
            name=mesh,
            uservert=np.asarray(vertices, dtype=np.float64).ravel().tolist(),
            userface=np.asarray(faces, dtype=np.int32).ravel().tolist(),
        )
        # No contacts and no mass: the visual mesh is only drawn (its convex hull would be a worse collider
        # than the CoACD parts, and a non-watertight mesh has no meaningful volume).
        body.add_geom(
            name=mesh,
            type=mujoco.mjtGeom.mjGEOM_MESH,
            meshname=mesh,
            contype=0,
            conaffinity=0,
            group=GROUP_VISUAL,
            rgba=rgba,
            mass=0.0,
        )
    else:
        # Nothing else to draw: show the collision parts in the visual group instead.
        for k in range(len(obj.convex_parts)):
            mesh = f"{name}/part_{k}"
            body.add_geom(
                name=f"{name}/visual_{k}",
                type=mujoco.mjtGeom.mjGEOM_MESH,
                meshname=mesh,
                contype=0,
                conaffinity=0,
                group=GROUP_VISUAL,
                rgba=rgba,
                mass=0.0,
            )


# ---------------------------------------------------------------------------------------------------------------
# Reading and writing object state
# ---------------------------------------------------------------------------------------------------------------


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
        raise ValueError(f"object bodies must be numbered 0..n-1, got {[i for i, _, _ in found]}")
    return found


def _free_joint_adr(model: mujoco.MjModel, body: int) -> tuple[int, int]:
    jnt = model.body_jntadr[body]
    if jnt < 0 or model.jnt_type[jnt] != mujoco.mjtJoint.mjJNT_FREE:
        raise ValueError(f"body {model.body(body).name!r} has no free joint")
    return int(model.jnt_qposadr[jnt]), int(model.jnt_dofadr[jnt])


def object_poses(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """(n, 4, 4) float64 mesh-to-world poses of the scene's objects, by scene index, from ``data.qpos``.

    Read from the free joints (not ``xpos``/``xmat``), so no ``mj_forward`` is needed after setting ``qpos``.
    """
    poses = []
    for _, _, body in object_bodies(model):
        q, _ = _free_joint_adr(model, body)
        mat = np.zeros(9)
        mujoco.mju_quat2Mat(mat, data.qpos[q + 3 : q + 7] / np.linalg.norm(data.qpos[q + 3 : q + 7]))
        poses.append(_pose_from_pos_mat(data.qpos[q : q + 3], mat))
    return np.array(poses, dtype=np.float64).reshape(-1, 4, 4)


def set_object_poses(model: mujoco.MjModel, data: mujoco.MjData, poses: np.ndarray) -> None:
    """Put the objects at ``poses`` ((n, 4, 4), by scene index) at rest (zero velocity); then ``mj_forward``."""
    poses = np.asarray(poses, dtype=float)
    bodies = object_bodies(model)
    if poses.shape != (len(bodies), 4, 4):
        raise ValueError(f"poses: must have shape ({len(bodies)}, 4, 4) for this model, got {poses.shape}")
    check_transforms("poses", poses)
    for (_, _, body), pose in zip(bodies, poses):
        q, v = _free_joint_adr(model, body)
        pos, quat = pose_to_pos_quat(pose)
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


# ---------------------------------------------------------------------------------------------------------------
# Settling
# ---------------------------------------------------------------------------------------------------------------


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
        check("max_time", self.max_time > 0, "be > 0", self.max_time)
        check("min_time", 0 <= self.min_time <= self.max_time, "be in [0, max_time]", self.min_time)
        check("linear_speed", self.linear_speed > 0, "be > 0", self.linear_speed)
        check("angular_speed", self.angular_speed > 0, "be > 0", self.angular_speed)
        check("check_every", 0 < self.check_every <= self.max_time, "be in (0, max_time]", self.check_every)
        check("drop_height", 0 <= self.drop_height <= 0.05, "be in [0, 0.05] m", self.drop_height)


@dataclasses.dataclass(frozen=True, eq=False)
class SettleResult:
    """What :func:`settle` did."""

    time: float
    """Simulated time, s."""
    at_rest: bool
    """Every object was calm in the last two check windows."""
    linear_speed: np.ndarray
    """(n,) mean speed of each object's centre of mass over the last check window, m/s."""
    angular_speed: np.ndarray
    """(n,) mean angular speed of each object over the last check window (rotation angle / window), rad/s."""

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
    (velocities not zeroed: read the poses with :func:`object_poses`, zero them with :func:`set_object_poses`).
    """
    steps_per_check = max(1, int(round(params.check_every / model.opt.timestep)))
    window = steps_per_check * model.opt.timestep
    max_checks = max(1, int(math.ceil(params.max_time / window - 1e-9)))
    calm = 0
    com, rot = _com_and_rotation(model, object_poses(model, data))
    lin = ang = np.zeros(len(com))
    for _ in range(max_checks):
        mujoco.mj_step(model, data, nstep=steps_per_check)
        if not (np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))):
            raise SimulationError("scene simulation diverged (non-finite state); check the object masses and meshes")
        new_com, new_rot = _com_and_rotation(model, object_poses(model, data))
        lin = np.linalg.norm(new_com - com, axis=1) / window
        cos = (np.einsum("nij,nij->n", new_rot, rot) - 1) / 2  # trace(R_new R_old^T) = 1 + 2 cos(angle)
        ang = np.arccos(np.clip(cos, -1.0, 1.0)) / window
        com, rot = new_com, new_rot
        calm = calm + 1 if np.all(lin < params.linear_speed) and np.all(ang < params.angular_speed) else 0
        if calm >= 2 and data.time >= params.min_time - 1e-9:
            break
    return SettleResult(time=float(data.time), at_rest=calm >= 2, linear_speed=lin, angular_speed=ang)


# ---------------------------------------------------------------------------------------------------------------
# Cameras
# ---------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera in the OpenCV convention (x right, y down, z forward)."""

    K: np.ndarray
    """(3, 3) float intrinsics [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], pixels (pixel centres at integers)."""
    T_world_camera: np.ndarray
    """(4, 4) float camera-to-world transform (the camera's pose in the world)."""
    width: int
    """Image width, pixels."""
    height: int
    """Image height, pixels."""

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=float)
        pinhole = K.shape == (3, 3) and K[0, 0] > 0 and K[1, 1] > 0 and np.allclose(K[2], [0, 0, 1])
        check("K", pinhole, "be a (3, 3) pinhole matrix with fx, fy > 0", K.tolist())
        check_transform("T_world_camera", self.T_world_camera)
        check_positive_int("width", self.width)
        check_positive_int("height", self.height)


def intrinsics_from_fov(width: int, height: int, fov_y: float) -> np.ndarray:
    """(3, 3) K of a camera with vertical field of view ``fov_y`` (rad), square pixels, centred principal point.

    fy = fx = (height / 2) / tan(fov_y / 2); cx = (width - 1) / 2, cy = (height - 1) / 2 (pixel centres at
    integer coordinates, so the image centre lies between pixels for even sizes).
    """
    check_number("fov_y", fov_y, low=0.0, high=math.pi, low_open=True, high_open=True)
    f = (height / 2) / math.tan(fov_y / 2)
    return np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])


def camera_on_sphere(
    target: np.ndarray, distance: float, elevation: float, azimuth: float, roll: float = 0.0
) -> np.ndarray:
    """(4, 4) camera-to-world pose (OpenCV frame) of a camera on a sphere around ``target``, looking at it.

    The camera sits at ``target + distance * (cos(el) cos(az), cos(el) sin(az), sin(el))``; with ``roll = 0``
    its x axis (image right) is horizontal, so the world's up points up in the image; ``roll`` (rad) turns the
    image about the optical axis (positive: the scene turns clockwise in the image). Elevation may reach pi/2
    (straight down): the right vector comes from the azimuth, so nothing degenerates.
    """
    target = np.asarray(target, dtype=float)
    ce, se = math.cos(elevation), math.sin(elevation)
    ca, sa = math.cos(azimuth), math.sin(azimuth)
    eye = target + distance * np.array([ce * ca, ce * sa, se])
    z = (target - eye) / distance
    x = np.array([-sa, ca, 0.0])  # horizontal and perpendicular to the viewing direction
    y = np.cross(z, x)
    cr, sr = math.cos(roll), math.sin(roll)
    x, y = cr * x + sr * y, -sr * x + cr * y
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, y, z, eye
    return pose


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply the (4, 4) transform ``T`` to points (..., 3); returns the same shape, float64."""
    points = np.asarray(points, dtype=float)
    return points @ np.asarray(T, dtype=float)[:3, :3].T + np.asarray(T, dtype=float)[:3, 3]


def project(K: np.ndarray, points_camera: np.ndarray) -> np.ndarray:
    """Pixel coordinates (..., 2) (u = column, v = row) of camera-frame points (..., 3) with z > 0."""
    p = np.asarray(points_camera, dtype=float)
    uvw = p @ np.asarray(K, dtype=float).T
    return uvw[..., :2] / uvw[..., 2:3]


def backproject(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Camera-frame points (H, W, 3) float64 of a depth image (H, W) (metres along z; 0 gives the origin).

    The pixel in row v, column u with depth z becomes ((u - cx) z / fx, (v - cy) z / fy, z).
    """
    depth = np.asarray(depth, dtype=float)
    if depth.ndim != 2:
        raise ValueError(f"depth: must be an (H, W) image, got shape {depth.shape}")
    K = np.asarray(K, dtype=float)
    v, u = np.indices(depth.shape, dtype=float)
    x = (u - K[0, 2]) * depth / K[0, 0]
    y = (v - K[1, 2]) * depth / K[1, 1]
    return np.stack([x, y, depth], axis=-1)


def depth_noise(
    depth: np.ndarray, rng: np.random.Generator, *, sigma: float, sigma_quadratic: float = 0.0, dropout: float = 0.0
) -> np.ndarray:
    """A noisy copy of a depth image (float32): Gaussian noise and random dropout; 0 (no return) stays 0.

    Noise standard deviation at depth z is ``sigma + sigma_quadratic * z**2`` (m; structured-light and
    time-of-flight sensors grow roughly with z^2); each valid pixel is independently set to 0 with probability
    ``dropout``. The clean image is never modified.
    """
    depth = np.asarray(depth, dtype=np.float32)
    if sigma < 0 or sigma_quadratic < 0 or not 0 <= dropout <= 1:
        raise ValueError(
            f"depth_noise: need sigma >= 0, sigma_quadratic >= 0, 0 <= dropout <= 1; got {sigma}, "
            f"{sigma_quadratic}, {dropout}"
        )
    valid = depth > 0
    std = sigma + sigma_quadratic * depth.astype(np.float64) ** 2
    noisy = depth + (rng.standard_normal(depth.shape) * std).astype(np.float32)
    drop = rng.random(depth.shape) < dropout
    noisy[~valid | drop | (noisy <= 0)] = 0.0
    return noisy.astype(np.float32)


# ---------------------------------------------------------------------------------------------------------------
# Rendering
# ---------------------------------------------------------------------------------------------------------------


def _gl_backend_note() -> str:
    """What MUJOCO_GL says and which backend mujoco actually loaded (it reads the variable once, at import)."""
    env = os.environ.get("MUJOCO_GL")
    used = backend_in_use()
    if used != (env or "").lower().strip():
        return (
            f"MUJOCO_GL={env!r} now, but mujoco was imported when it was {used or 'unset'!r} and uses that "
            "backend: set MUJOCO_GL in the environment before Python starts"
        )
    return f"MUJOCO_GL={env!r}"


@dataclasses.dataclass(frozen=True, eq=False)
class RenderedView:
    """Images of one camera view."""

    rgb: np.ndarray | None
    """(H, W, 3) uint8, or None when not asked for."""
    depth: np.ndarray
    """(H, W) float32 metres along the optical axis; 0 where nothing was hit."""
    segmentation: np.ndarray
    """(H, W) int16: object index, or SEG_BACKGROUND / SEG_SUPPORT / SEG_GROUND."""


class SceneRenderer:
    """Renders RGB, depth and segmentation of a scene model from arbitrary :class:`Camera` s, headless.

    One OpenGL context per instance; use it as a context manager (or call :meth:`close`). Shadows and
    reflections are off (they cost more than the rest of a frame and carry no information for learning).

    Parameters
    ----------
    model : mujoco.MjModel
        From :func:`build_scene_spec` (its offscreen buffer must be at least ``width`` x ``height``).
    width, height : int
        Image size, pixels.

    Raises
    ------
    RenderError
        When no offscreen OpenGL context can be made; the message says what to install or set.
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int):
        self.model = model
        self.width, self.height = int(width), int(height)
        self._renderer = None
        problem = render_problem()  # no usable back end: say so before mujoco tries (it may crash without one)
        if problem is not None:
            raise RenderError(problem)
        try:
            self._renderer = mujoco.Renderer(model, self.height, self.width)
        except ValueError:
            raise  # image larger than the model's offscreen buffer: a programming error, keep MuJoCo's message
        except Exception as exc:  # noqa: BLE001 - GL failures surface as many types (ImportError, FatalError...)
            detail = " ".join(f"{type(exc).__name__}: {exc}".split())  # one line
            raise RenderError(
                f"cannot create an offscreen OpenGL context ({_gl_backend_note()}): {detail}; {HOW_TO_FIX}"
            ) from exc
        scene = self._renderer.scene
        scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        self._option = mujoco.MjvOption()  # default: groups 0-2 visible, so the collision parts (3) are hidden
        self._labels = geom_labels(model)

    def __enter__(self) -> SceneRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if getattr(self, "_renderer", None) is not None:
            self._renderer.close()
            self._renderer = None

    def render(self, data: mujoco.MjData, camera: Camera, *, rgb: bool = True) -> RenderedView:
        """Images of the state ``data`` (``mj_forward`` must have run) seen by ``camera``."""
        if (camera.width, camera.height) != (self.width, self.height):
            raise ValueError(
                f"camera: image size {camera.width}x{camera.height} differs from the renderer's "
                f"{self.width}x{self.height}"
            )
        r = self._renderer
        r.update_scene(data, camera=-1, scene_option=self._option)
        self._set_gl_camera(camera)
        r.enable_segmentation_rendering()
        seg = r.render()
        r.enable_depth_rendering()
        depth = r.render()
        r.disable_depth_rendering()
        color = r.render().copy() if rgb else None
        hit = seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)
        ids = np.where(hit, seg[..., 0], 0)
        labels = np.where(hit, self._labels[np.clip(ids, 0, len(self._labels) - 1)], SEG_BACKGROUND)
        depth = np.where(seg[..., 0] >= 0, depth, 0.0).astype(np.float32)
        return RenderedView(rgb=color, depth=depth, segmentation=labels.astype(np.int16))

    def _set_gl_camera(self, camera: Camera) -> None:
        """Point MuJoCo's OpenGL camera(s) along ``camera`` and set the frustum from its K exactly.

        OpenGL looks along -z with y up: forward = OpenCV z, up = -OpenCV y. The frustum at the near plane n
        spans u in [-0.5, W - 0.5] and v in [-0.5, H - 0.5] (pixel edges), v growing downwards.
        """
        T = np.asarray(camera.T_world_camera, dtype=float)
        K = np.asarray(camera.K, dtype=float)
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        extent = self.model.stat.extent
        near = self.model.vis.map.znear * extent  # the renderer's depth conversion assumes these planes
        far = self.model.vis.map.zfar * extent
        left = near * (-0.5 - cx) / fx
        right = near * (self.width - 0.5 - cx) / fx
        top = near * (cy + 0.5) / fy
        bottom = -near * (self.height - 0.5 - cy) / fy
        # Both eyes identical: mjr_render averages the stereo pair, which would otherwise be offset by +-ipd/2.
        for gl in self._renderer.scene.camera:
            gl.pos[:] = T[:3, 3]
            gl.forward[:] = T[:3, 2]
            gl.up[:] = -T[:3, 1]
            gl.frustum_near = near
            gl.frustum_far = far
            gl.frustum_center = (left + right) / 2
            gl.frustum_width = (right - left) / 2
            gl.frustum_top = top
            gl.frustum_bottom = bottom
            gl.orthographic = 0
