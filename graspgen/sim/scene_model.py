"""Scenes as MuJoCo models: objects resting on a support (the naming, and building the :class:`mujoco.MjSpec`).

Shared by the stages that work in a scene (scenes, grasp collision pre-filter, rollouts), so everything here is a
plain function of its arguments: no globals, no randomness. The support is :mod:`graspgen.sim.support`, reading and
writing the objects' state in a compiled model :mod:`graspgen.sim.scene_state`, the settle loop
:mod:`graspgen.sim.settle`, cameras :mod:`graspgen.sim.camera` and images :mod:`graspgen.sim.render`.

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
(:func:`graspgen.sim.scene_state.geom_labels` maps any geom to its object index, :data:`SEG_SUPPORT` or
:data:`SEG_GROUND`). Collision parts are in group 3, which MuJoCo's viewer and renderer hide by default, so images
show the true visual mesh.

Physics: :class:`graspgen.sim.physics.PhysicsOptions` (2 ms, elliptic cones, impratio 10, implicitfast); mass,
centre of mass and inertia come from the object record (``inertiafromgeom`` is off), never from the geoms.
Friction: objects carry their own sliding friction; support geoms carry ``SupportParams.friction``. MuJoCo has
no per-pair friction: at equal priority it uses the *larger* of the two geoms' coefficients.

Segmentation images (:mod:`graspgen.sim.render`) hold the object index (0..n-1) for objects and the negative codes
:data:`SEG_BACKGROUND` (-1, nothing), :data:`SEG_SUPPORT` (-2) and :data:`SEG_GROUND` (-3).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import mujoco
import numpy as np

from graspgen.errors import SettingsError
from graspgen.sim.physics import PhysicsOptions
from graspgen.sim.poses_mj import pos_quat
from graspgen.sim.support import GROUND_NAME, SUPPORT_PREFIX, SupportParams, support_boxes
from graspgen.validation import check, check_instance, check_number, check_transform

__all__ = [
    "GROUP_COLLISION",
    "GROUP_SUPPORT",
    "GROUP_VISUAL",
    "OBJECT_PREFIX",
    "SEG_BACKGROUND",
    "SEG_GROUND",
    "SEG_SUPPORT",
    "PlacedObject",
    "build_scene_spec",
    "free_space_spec",
    "object_body_name",
    "placed_object",
    "scene_spec",
]

GROUP_SUPPORT = 0
"""Geom group of the support boxes and the ground plane (rendered and colliding)."""
GROUP_VISUAL = 1
"""Geom group of the objects' visual meshes (rendered, no contacts)."""
GROUP_COLLISION = 3
"""Geom group of the objects' convex collision parts (colliding, hidden by MuJoCo's default render options)."""

OBJECT_PREFIX = "obj/"
"""Name prefix of the object bodies and their geoms."""

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
        Largest image a :class:`graspgen.sim.render.SceneRenderer` may render of the model (MuJoCo's offscreen
        buffer size).

    Returns
    -------
    mujoco.MjSpec
        Compile with ``spec.compile()``; attach a gripper to it with :func:`graspgen.sim.gripper_model.attach_gripper`.
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
    free-space protocols (``acronym``, ``graspdatagen``; ``table`` with ``gravity_until_closed``) used by
    :func:`graspgen.workflows.evaluate.evaluate_grasps` and :mod:`graspgen.workflows.object_grasps`.

    Parameters
    ----------
    obj : PlacedObject
        The object; ``pose`` places its mesh frame in the world (the identity keeps world = mesh frame).
    physics : PhysicsOptions, optional
        Timestep, cones, impratio, integrator, gravity; default ``PhysicsOptions()``.

    Returns
    -------
    mujoco.MjSpec
        Compile with ``spec.compile()``; attach a gripper with :func:`graspgen.sim.gripper_model.attach_gripper`.
    """
    spec = build_scene_spec([obj], SupportParams(), physics)
    for geom in list(spec.geoms):
        if geom.name == GROUND_NAME or geom.name.startswith(SUPPORT_PREFIX):
            spec.delete(geom)
    return spec


def _add_object(spec: mujoco.MjSpec, index: int, obj: PlacedObject) -> None:
    name = object_body_name(index, obj.name)
    pos, quat = pos_quat(obj.pose)
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


def scene_spec(
    scene: Any,
    records: Mapping[str, Any],
    physics: PhysicsOptions | None = None,
    *,
    visual: bool = True,
) -> mujoco.MjSpec:
    """The MuJoCo spec of a scene at its settled poses.

    ``scene`` is a :class:`graspgen.io.scenes.SceneRecord` (``read_scene``), ``records`` the object records by
    name (:func:`graspgen.io.objects.read_object`); ``visual=False`` leaves out the visual meshes (faster to
    compile).
    """
    missing = sorted(set(scene.object_names) - set(records))
    if missing:
        raise SettingsError(f"records: no object record for {missing[0]!r} (scene {scene.scene_id})")
    objs = [
        placed_object(records[name], pose, float(mu), visual=visual)
        for name, pose, mu in zip(scene.object_names, scene.poses, scene.friction)
    ]
    size = (scene.cameras[0].width, scene.cameras[0].height) if scene.cameras else (640, 480)
    return build_scene_spec(objs, scene.support, physics, image_size=size)
