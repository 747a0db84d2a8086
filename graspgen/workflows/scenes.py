"""Stage 2, ``scenes``: random, physically settled scenes of library objects on a support, seen by cameras.

One task per scene (``scene_000000``, ``scene_000001``, ...). Each task may read every object shard of the
``objects`` stage that it can draw (all of them, or those listed in ``objects``; their keys enter its key) and,
with the task's ``rng`` only:

1. **Chooses objects**: k in ``objects_per_scene``, drawn from ``objects`` (or the whole library), weighted by
   ``weights``; or exactly the listed objects with ``choice: fixed``. Friction per object from ``friction``, except
   for an object with its own (``ObjectRecord.friction``, from its manifest row), which keeps that one.
2. **Places them** one by one: a stable pose drawn by its probability, a uniform yaw, x/y uniform (or Gaussian)
   in ``support.area``. A placement whose footprint (the union of its convex parts' x/y hulls) comes closer than
   ``gap`` to an earlier object or leaves the support (or hits the shelf board) is rejected; after ``max_tries``
   rejections that object is left out. Fewer than the minimum count placed: the scene is drawn again.
3. **Settles** them in MuJoCo (:func:`graspgen.sim.settle.settle`). Objects that fell (centre of mass lower by
   more than 2 cm or off the table top), tipped (their up axis turned by more than ``max_tilt``) or still move at
   ``settle.max_time`` are removed and the rest settled again (``on_unstable: remove``), or the scene is drawn
   again (``on_unstable: retry``). At most ``max_scene_tries`` draws; a scene that cannot be made fails its
   task with a message saying why (never an endless loop). Every removal and retry is counted.
4. **Renders** ``cameras.num_views`` views from a spherical cap around the objects' bounding-box centre (depth,
   segmentation, RGB; MuJoCo offscreen, see :mod:`graspgen.sim.render` for ``MUJOCO_GL``) and back-projects
   each depth image to a point cloud.

Conventions (details in :mod:`graspgen.sim.scene_model`): world z up, metres, the support's top surface is z = 0 and
the ground is at z = -``support.height``; object poses map the object's mesh frame (as in its object shard) to
the world; cameras are OpenCV (x right, y down, z forward), ``T_world_camera`` is camera-to-world; depth is
metres along the optical axis, 0 = no return; segmentation / point ids are the object's scene index (0..n-1),
-1 nothing, -2 support, -3 ground.

Shard layout (HDF5, one per scene; n objects, v views, H x W images, N cloud points)::

    /objects/poses (n, 4, 4) float64           settled mesh-to-world poses (at rest; start state downstream)
    /objects/placed_poses (n, 4, 4) float64    poses as placed before settling (lifted by settle.drop_height)
    /objects/friction (n,) float64             sliding friction of each object
    /objects/stable_pose_index (n,) int32      which stable pose of the object shard it was placed in
    /objects/rgba (n, 4) float32               colour it is rendered in
    /support/box_centers (b, 3) float64 m      static support boxes (world frame, axis-aligned) ...
    /support/box_sizes (b, 3) float64 m        ... full extents; names in the group's attrs ``box_names``
    /cameras/K (v, 3, 3) float64               intrinsics (pixels)
    /cameras/T_world_camera (v, 4, 4) float64  camera-to-world, OpenCV camera frame
    /images/rgb (v, H, W, 3) uint8             (only with cameras.render)
    /images/depth (v, H, W) float32 m          clean depth, 0 = no return
    /images/depth_noisy (v, H, W) float32 m    only with cameras.depth_noise.enabled (clean depth is kept)
    /images/segmentation (v, H, W) int16       object index, -1 nothing, -2 support, -3 ground
    /clouds/points_world (N, 3) float32 m      object and support pixels (not ground), all views concatenated
    /clouds/points_camera (N, 3) float32 m     the same points in their view's camera frame (clouds: both/camera)
    /clouds/ids (N,) int16                     segmentation id of each point
    /clouds/pixel (N,) int32                   row * W + column of each point in its view
    /clouds/view_offsets (v + 1,) int64        points of view k are [view_offsets[k], view_offsets[k + 1])
    attributes: scene_id, object_names, object_keys (the objects stage's shard keys, by scene index),
                counts (placement_tries, placement_failed, unstable_fallen, unstable_tipped, unstable_moving,
                scene_retries), settle_time, support (SupportParams), conventions, params

Which cloud frames are stored is ``cameras.clouds`` (world by default; camera, both, none). Read a shard with
:func:`graspgen.io.scenes.read_scene`; rebuild its MuJoCo model with :func:`graspgen.sim.scene_model.scene_spec`;
look at it with ``gen show scene``. The settings are :mod:`graspgen.workflows.scene_params`, the object draw and
placement :mod:`graspgen.workflows.scene_placement`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from graspgen.errors import InputError, SimulationError
from graspgen.io.objects import ObjectRecord
from graspgen.sim.camera import Camera, backproject, camera_on_sphere, depth_noise, transform_points
from graspgen.sim.gl import require_rendering
from graspgen.sim.render import RenderedView
from graspgen.sim.scene_model import SEG_GROUND, placed_object
from graspgen.sim.scene_world import SettledScene, object_rgba, render_views, rest_poses, settle_scene
from graspgen.sim.support import support_boxes
from graspgen.validation import settings_dict
from graspgen.workflows.scene_params import CameraParams, DepthNoiseParams, ScenesParams
from graspgen.workflows.scene_placement import Placement, SceneCounts, choose_objects, place_objects

__all__ = ["CameraParams", "DepthNoiseParams", "MadeScene", "ScenesParams", "check_rendering", "make_scene"]

_FALL_DEPTH = 0.005
"""An object whose centre of mass ends below the support's top surface by more than this (m) has fallen off."""


# ---------------------------------------------------------------------------------------------------------------
# Settling
# ---------------------------------------------------------------------------------------------------------------


def _unstable(
    placements: Sequence[Placement],
    records: Mapping[str, ObjectRecord],
    poses: np.ndarray,
    moving: np.ndarray,
    params: ScenesParams,
) -> dict[int, str]:
    """``{scene index: reason}`` of objects that fell, tipped or still move after a settle."""
    half = np.asarray(params.support.size, dtype=float) / 2
    bad: dict[int, str] = {}
    for i, (p, pose) in enumerate(zip(placements, poses)):
        com = np.asarray(records[p.name].center_of_mass, dtype=float)
        after = pose[:3, :3] @ com + pose[:3, 3]
        up_before = p.pose[:3, :3].T[:, 2]  # the world's up axis seen in the object's frame
        up_after = pose[:3, :3].T[:, 2]
        tilt = math.acos(float(np.clip(up_before @ up_after, -1.0, 1.0)))
        if after[2] < -_FALL_DEPTH or np.any(np.abs(after[:2]) > half):
            bad[i] = "fallen"
        elif tilt > params.max_tilt:
            bad[i] = "tipped"
        elif moving[i]:
            bad[i] = "moving"
    return bad


def _settled_scene(
    placements: list[Placement],
    records: Mapping[str, ObjectRecord],
    params: ScenesParams,
    counts: SceneCounts,
    image_size: tuple[int, int],
) -> tuple[list[Placement], SettledScene] | None:
    """Settle ``placements``; remove unstable objects and settle again until all rest (None: retry the scene)."""
    lo, _ = params.count_range
    minimum = len(params.objects) if params.choice == "fixed" else lo
    while True:
        objs = [placed_object(records[p.name], p.pose, p.friction) for p in placements]
        settled = settle_scene(objs, params.support, params.settle, image_size)
        result = settled.result
        bad = _unstable(placements, records, result.poses, result.moving(params.settle), params)
        if not bad:
            return placements, settled
        for reason in bad.values():
            setattr(counts, f"unstable_{reason}", getattr(counts, f"unstable_{reason}") + 1)
        if params.on_unstable == "retry":
            return None
        placements = [p for i, p in enumerate(placements) if i not in bad]
        if len(placements) < max(minimum, 1):
            return None


# ---------------------------------------------------------------------------------------------------------------
# The scene
# ---------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class MadeScene:
    """What :func:`make_scene` returns: the shard tree and the manifest metadata."""

    tree: dict[str, Any]
    meta: dict[str, Any]


def check_rendering(params: ScenesParams) -> None:
    """Raise :class:`~graspgen.errors.RenderError` (one line: the missing library and the ways out) when ``params``
    ask for images and no OpenGL back end can render in this process; cheap, so call it before any work."""
    if params.cameras.render and params.cameras.num_views > 0:
        require_rendering()


def make_scene(
    scene_id: str,
    params: ScenesParams,
    library: Sequence[str],
    load_object: Callable[[str], ObjectRecord],
    object_key: Callable[[str], str],
    rng: np.random.Generator,
) -> MadeScene:
    """Build one scene (sample, settle, render); all randomness from ``rng``.

    Parameters
    ----------
    scene_id : str
        The scene's name (``scene_000012``), stored in it and used in messages.
    params : ScenesParams
        How objects are chosen, placed, settled and seen.
    library : sequence of str
        Names of the objects the scene may draw from (sorted, for reproducible draws).
    load_object : callable
        ``name -> ObjectRecord``; called once per drawn object.
    object_key : callable
        ``name -> str``, the provenance key of that object's record (stored in the scene as ``object_keys``).
    rng : numpy.random.Generator
        The only source of randomness.
    """
    t0 = time.perf_counter()
    if not library:
        raise InputError(f"{scene_id}: no objects to build the scene from")
    check_rendering(params)  # before placing and settling: without OpenGL that work would be thrown away
    records: dict[str, ObjectRecord] = {}
    counts = SceneCounts()
    cams = params.cameras
    settled, t_settle = _draw_settled(scene_id, params, library, load_object, rng, records, counts)
    placements, scene = settled
    settle_time = scene.result.time
    poses = rest_poses(scene)  # at rest: zero velocities, as a downstream stage will load it
    t_sample = time.perf_counter() - t0 - t_settle
    cameras = _draw_cameras(cams, [records[p.name] for p in placements], poses, rng)
    views, t_setup, t_render = _render_views(scene, cams, cameras)
    rgba = object_rgba(scene, [p.name for p in placements])
    tree = _scene_tree(scene_id, params, placements, poses, rgba, cameras, counts, settle_time, object_key)
    if views:
        tree["images"] = _images(views, cams.depth_noise, rng)
        if cams.clouds != "none":
            tree["clouds"] = _clouds(views, cameras, cams.clouds)
    v = len(cameras)
    meta = {
        "objects": [p.name for p in placements],
        **dataclasses.asdict(counts),
        "settle_time": round(settle_time, 4),
        "views": v,
        "seconds_sampling": round(t_sample, 4),
        "seconds_settle": round(t_settle, 4),
        "seconds_render_setup": round(t_setup, 4),
        "seconds_render_per_view": round(t_render / v, 4) if views else 0.0,
    }
    return MadeScene(tree, meta)


def _draw_settled(
    scene_id: str,
    params: ScenesParams,
    library: Sequence[str],
    load_object: Callable[[str], ObjectRecord],
    rng: np.random.Generator,
    records: dict[str, ObjectRecord],
    counts: SceneCounts,
) -> tuple[tuple[list[Placement], SettledScene], float]:
    """Draw, place and settle the scene until a draw holds (at most ``max_scene_tries``): (the settled scene, the
    seconds spent settling). Loads each drawn object into ``records`` once; SimulationError when no draw holds."""
    image_size = (params.cameras.width, params.cameras.height)
    t_settle = 0.0
    settled = None
    for attempt in range(params.max_scene_tries):
        if attempt:
            counts.scene_retries += 1
        names = choose_objects(params, library, rng)
        for name in names:
            if name not in records:
                records[name] = load_object(name)
        placements = place_objects(names, records, params, rng, counts)
        lo, _ = params.count_range
        minimum = len(names) if params.choice == "fixed" else lo
        if len(placements) < minimum:
            continue
        t1 = time.perf_counter()
        settled = _settled_scene(placements, records, params, counts, image_size)
        t_settle += time.perf_counter() - t1
        if settled is not None:
            break
    if settled is None:
        raise SimulationError(
            f"{scene_id}: no scene could be made in {params.max_scene_tries} draws (objects left out for lack of "
            f"room: {counts.placement_failed}; unstable (fallen/tipped/moving): {counts.unstable_fallen}/"
            f"{counts.unstable_tipped}/{counts.unstable_moving}). Lower scenes.objects_per_scene, enlarge "
            "scenes.support.area or raise scenes.max_tries"
        )
    return settled, t_settle


def _draw_cameras(
    cams: CameraParams, records: Sequence[ObjectRecord], poses: np.ndarray, rng: np.random.Generator
) -> list[Camera]:
    """``cams.num_views`` cameras drawn on the spherical cap around the settled objects (``records`` and
    ``poses`` by scene index), looking at the centre of their bounding box."""
    corners = np.concatenate([transform_points(pose, record.vertices) for record, pose in zip(records, poses)])
    target = (corners.min(0) + corners.max(0)) / 2
    K = cams.intrinsics()
    cameras = []
    for _ in range(cams.num_views):
        d = rng.uniform(*cams.distance)
        el = rng.uniform(*cams.elevation)
        az = rng.uniform(*cams.azimuth)
        roll = rng.uniform(*cams.roll)
        cameras.append(Camera(K, camera_on_sphere(target, d, el, az, roll), cams.width, cams.height))
    return cameras


def _render_views(
    scene: SettledScene, cams: CameraParams, cameras: Sequence[Camera]
) -> tuple[list[RenderedView], float, float]:
    """(the views of ``cameras``, seconds to set the renderer up, seconds rendering); nothing without
    ``cams.render``."""
    if cams.render and cameras:
        return render_views(scene, cams.width, cams.height, cameras)
    return [], 0.0, 0.0


def _scene_tree(
    scene_id: str,
    params: ScenesParams,
    placements: Sequence[Placement],
    poses: np.ndarray,
    rgba: np.ndarray,
    cameras: Sequence[Camera],
    counts: SceneCounts,
    settle_time: float,
    object_key: Callable[[str], str],
) -> dict[str, Any]:
    """The shard tree without images and clouds: attributes, objects, support and cameras (module docstring)."""
    cams = params.cameras
    n, v = len(placements), len(cameras)
    boxes = support_boxes(params.support)
    return {
        "@attrs": {
            "scene_id": scene_id,
            "object_names": [p.name for p in placements],
            "object_keys": [object_key(p.name) for p in placements],
            "counts": dataclasses.asdict(counts),
            "settle_time": settle_time,
            "support": settings_dict(params.support),
            "conventions": {
                "world": "z up, metres; support top surface z = 0; ground z = -support.height",
                "poses": "object mesh frame (as in its object shard) to world",
                "camera": "OpenCV: x right, y down, z forward; T_world_camera maps camera to world",
                "depth": "float32 metres along the optical axis; 0 = no return",
                "ids": "object scene index 0..n-1; -1 nothing, -2 support, -3 ground",
            },
            "params": settings_dict(params),
        },
        "objects": {
            "poses": poses.astype(np.float64),
            "placed_poses": np.array([p.pose for p in placements], dtype=np.float64).reshape(n, 4, 4),
            "friction": np.array([p.friction for p in placements], dtype=np.float64),
            "stable_pose_index": np.array([p.pose_index for p in placements], dtype=np.int32),
            "rgba": rgba,
        },
        "support": {
            "@attrs": {
                "kind": params.support.kind,
                "box_names": [b.name for b in boxes],
                "ground_z": -params.support.height,
            },
            "box_centers": np.array([b.center for b in boxes], dtype=np.float64),
            "box_sizes": np.array([b.size for b in boxes], dtype=np.float64),
        },
        "cameras": {
            "@attrs": {"width": cams.width, "height": cams.height, "convention": "opencv"},
            "K": np.array([c.K for c in cameras], dtype=np.float64).reshape(v, 3, 3),
            "T_world_camera": np.array([c.T_world_camera for c in cameras], dtype=np.float64).reshape(v, 4, 4),
        },
    }


def _images(views: Sequence[RenderedView], dn: DepthNoiseParams, rng: np.random.Generator) -> dict[str, Any]:
    """The ``images`` group: rgb, depth and segmentation of every view, and noisy depth (drawn from ``rng``) when
    ``dn.enabled``."""
    images: dict[str, Any] = {
        "rgb": np.stack([view.rgb for view in views]),
        "depth": np.stack([view.depth for view in views]),
        "segmentation": np.stack([view.segmentation for view in views]),
    }
    if dn.enabled:
        images["depth_noisy"] = np.stack(
            [
                depth_noise(view.depth, rng, sigma=dn.sigma, sigma_quadratic=dn.sigma_quadratic, dropout=dn.dropout)
                for view in views
            ]
        )
    return images


def _clouds(views: Sequence[RenderedView], cameras: Sequence[Camera], frames: str) -> dict[str, np.ndarray]:
    cam_pts, world_pts, ids, pixels, offsets = [], [], [], [], [0]
    for view, cam in zip(views, cameras):
        valid = (view.depth > 0) & (view.segmentation != SEG_GROUND)
        p_cam = backproject(view.depth, cam.K)[valid]
        cam_pts.append(p_cam.astype(np.float32))
        world_pts.append(transform_points(cam.T_world_camera, p_cam).astype(np.float32))
        ids.append(view.segmentation[valid].astype(np.int16))
        pixels.append(np.flatnonzero(valid.ravel()).astype(np.int32))
        offsets.append(offsets[-1] + int(valid.sum()))
    out = {
        "ids": np.concatenate(ids),
        "pixel": np.concatenate(pixels),
        "view_offsets": np.array(offsets, dtype=np.int64),
    }
    if frames in ("both", "world"):
        out["points_world"] = np.concatenate(world_pts).reshape(-1, 3)
    if frames in ("both", "camera"):
        out["points_camera"] = np.concatenate(cam_pts).reshape(-1, 3)
    return out
