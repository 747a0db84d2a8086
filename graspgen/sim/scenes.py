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
3. **Settles** them in MuJoCo (:func:`graspgen.sim.scene_model.settle`). Objects that fell (centre of mass lower by
   more than 2 cm or off the table top), tipped (their up axis turned by more than ``max_tilt``) or still move at
   ``settle.max_time`` are removed and the rest settled again (``on_unstable: remove``), or the scene is drawn
   again (``on_unstable: retry``). At most ``max_scene_tries`` draws; a scene that cannot be made fails its
   task with a message saying why (never an endless loop). Every removal and retry is counted.
4. **Renders** ``cameras.num_views`` views from a spherical cap around the objects' bounding-box centre (depth,
   segmentation, RGB; MuJoCo offscreen, see :mod:`graspgen.sim.scene_model` for ``MUJOCO_GL``) and back-projects
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
:func:`read_scene`; rebuild its MuJoCo model with :func:`scene_spec`; look at it with ``gen show scene``.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Literal

from graspgen.sim.gl import require_rendering, select_backend

select_backend()  # MuJoCo picks its GL backend at its first import: choose a headless one (graspgen.sim.gl).

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from scipy.spatial import ConvexHull  # noqa: E402

from graspgen.errors import InputError, SettingsError, SimulationError  # noqa: E402
from graspgen.io.objects import ObjectRecord  # noqa: E402
from graspgen.io.scenes import SceneRecord  # noqa: E402
from graspgen.sim.grippers import PhysicsOptions  # noqa: E402
from graspgen.sim.scene_model import (  # noqa: E402
    SEG_GROUND,
    Camera,
    SceneRenderer,
    SettleParams,
    SupportParams,
    backproject,
    build_scene_spec,
    camera_on_sphere,
    depth_noise,
    free_region,
    intrinsics_from_fov,
    object_poses,
    placed_object,
    set_object_poses,
    settle,
    support_boxes,
    transform_points,
)
from graspgen.validation import check, check_range, settings_dict  # noqa: E402

_FALL_DEPTH = 0.005
"""An object whose centre of mass ends below the support's top surface by more than this (m) has fallen off."""

# ---------------------------------------------------------------------------------------------------------------
# Config
# ---------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class DepthNoiseParams:
    """Optional depth sensor noise, stored as ``images/depth_noisy`` next to the clean depth."""

    enabled: bool = False
    """Store a noisy copy of every depth image (drawn from the task's rng)."""
    sigma: float = 0.001
    """Standard deviation of the Gaussian depth noise at zero range, m."""
    sigma_quadratic: float = 0.0025
    """Growth of the standard deviation with range: sigma + sigma_quadratic * z^2, 1/m (0.0025 gives 1 mm more at
    0.63 m; typical of structured-light sensors)."""
    dropout: float = 0.01
    """Probability that a pixel returns no depth (set to 0)."""

    def __post_init__(self) -> None:
        check("sigma", self.sigma >= 0, "be >= 0", self.sigma)
        check("sigma_quadratic", self.sigma_quadratic >= 0, "be >= 0", self.sigma_quadratic)
        check("dropout", 0 <= self.dropout <= 1, "be in [0, 1]", self.dropout)


@dataclasses.dataclass(frozen=True)
class CameraParams:
    """Camera views of each scene (config section ``scenes.cameras``). Angles in rad, lengths in m."""

    num_views: int = 3
    """Views per scene."""
    distance: tuple[float, float] = (0.55, 0.8)
    """Range of the camera's distance to the scene centre (the objects' bounding-box centre), m."""
    elevation: tuple[float, float] = (0.6, 1.2)
    """Range of the angle above the table plane, rad (0.6-1.2 is about 35-70 degrees; pi/2 looks straight down)."""
    azimuth: tuple[float, float] = (-math.pi, math.pi)
    """Range of the angle about the world z axis, from +x towards +y, rad."""
    roll: tuple[float, float] = (0.0, 0.0)
    """Range of the in-plane rotation about the optical axis, rad (0: world up is image up)."""
    width: int = 320
    """Image width, pixels."""
    height: int = 240
    """Image height, pixels."""
    fov_y: float = 0.785
    """Vertical field of view, rad (0.785 = 45 degrees); square pixels, centred principal point. Ignored when
    fx, fy, cx, cy are given."""
    fx: float | None = None
    """Focal length along x, pixels; give all of fx, fy, cx, cy or none."""
    fy: float | None = None
    """Focal length along y, pixels."""
    cx: float | None = None
    """Principal point column, pixels (pixel centres at integer coordinates)."""
    cy: float | None = None
    """Principal point row, pixels."""
    render: bool = True
    """Render images and clouds. False makes scenes without images (no OpenGL needed); camera poses are still
    sampled and stored."""
    clouds: Literal["world", "camera", "both", "none"] = "world"
    """Which point-cloud frames to store. The clouds hold the object and support points of every view (ground
    and empty pixels are left out; the depth images keep them). A frame that is not stored is one call away
    (:meth:`SceneRecord.cloud`). Clouds are most of a shard: ~0.45 MB per view and frame at 320 x 240 (float32
    coordinates hardly compress), against ~20 kB for the depth image they come from; ``none`` keeps shards small."""
    depth_noise: DepthNoiseParams = dataclasses.field(default_factory=DepthNoiseParams)
    """Optional depth noise (off by default)."""

    def __post_init__(self) -> None:
        check("num_views", self.num_views >= 0, "be >= 0", self.num_views)
        check_range("distance", self.distance, low=1e-3)
        check_range("elevation", self.elevation, low=-math.pi / 2, high=math.pi / 2)
        check_range("azimuth", self.azimuth, low=-4 * math.pi, high=4 * math.pi)
        check_range("roll", self.roll, low=-math.pi, high=math.pi)
        check("width", 8 <= self.width <= 8192, "be in [8, 8192] pixels", self.width)
        check("height", 8 <= self.height <= 8192, "be in [8, 8192] pixels", self.height)
        check("fov_y", 0 < self.fov_y < math.pi, "be in (0, pi) rad", self.fov_y)
        given = [v is not None for v in (self.fx, self.fy, self.cx, self.cy)]
        check("fx", all(given) or not any(given), "be given together with fy, cx, cy (or none of them)", self.fx)
        if all(given):
            check("fx", self.fx > 0, "be > 0", self.fx)
            check("fy", self.fy > 0, "be > 0", self.fy)

    def intrinsics(self) -> np.ndarray:
        """(3, 3) K from fx, fy, cx, cy when given, else from ``fov_y``."""
        if self.fx is not None:
            return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])
        return intrinsics_from_fov(self.width, self.height, self.fov_y)


@dataclasses.dataclass(frozen=True)
class ScenesParams:
    """Settings of the ``scenes`` stage (config section ``scenes``)."""

    num_scenes: int = 4
    """Number of scenes (tasks ``scene_000000`` ...)."""
    objects_per_scene: int | tuple[int, int] = 3
    """Objects per scene: a number, or [min, max] drawn uniformly per scene. Ignored with ``choice: fixed``."""
    choice: Literal["random", "fixed"] = "random"
    """``random``: draw the objects of each scene from ``objects`` (or the library); ``fixed``: every scene holds
    exactly the objects listed in ``objects``, in that order."""
    objects: tuple[str, ...] = ()
    """Object names (objects-stage task ids) to use; empty means every object of the library."""
    weights: dict[str, float] = dataclasses.field(default_factory=dict)
    """Relative probability of drawing each object by name (names not listed weigh 1); random choice only."""
    replace: bool = False
    """Allow one object to appear more than once in a scene (random choice)."""
    placement: Literal["uniform", "gaussian"] = "uniform"
    """How x/y positions are drawn in ``support.area``: uniform, or Gaussian around its centre (clipped to it)."""
    placement_sigma: float = 0.08
    """Standard deviation of Gaussian placement, m."""
    gap: float = 0.005
    """Smallest clearance between two objects' footprints, and to the support's edges and walls, at placement, m."""
    friction: float | tuple[float, float] = 0.8
    """Sliding friction of each object: a value, or [lo, hi] drawn uniformly per object. An object with its own
    friction (``friction`` in its object manifest row: ``ObjectRecord.friction``) keeps its own; its draw is still
    made, so the other objects' draws stay what they were."""
    max_tries: int = 100
    """Placements tried per object before it is left out of the scene."""
    max_scene_tries: int = 10
    """Scene draws before the task fails (a draw fails when too few objects fit or, with ``on_unstable: retry``,
    when one is unstable)."""
    on_unstable: Literal["remove", "retry"] = "remove"
    """What to do with objects that fall, tip or keep moving while settling: remove them and settle the rest
    again, or draw the scene again."""
    max_tilt: float = 0.35
    """An object whose up axis turns by more than this while settling has tipped over, rad (0.35 = 20 degrees)."""
    support: SupportParams = dataclasses.field(default_factory=SupportParams)
    """What the objects stand on."""
    settle: SettleParams = dataclasses.field(default_factory=SettleParams)
    """When a scene is at rest."""
    cameras: CameraParams = dataclasses.field(default_factory=CameraParams)
    """Camera views and rendering."""

    def __post_init__(self) -> None:
        check("num_scenes", self.num_scenes >= 0, "be >= 0", self.num_scenes)
        lo, hi = self.count_range
        check(
            "objects_per_scene",
            1 <= lo <= hi,
            "be a number >= 1 or [min, max] with 1 <= min <= max",
            self.objects_per_scene,
        )
        if self.choice == "fixed":
            check(
                "objects", len(self.objects) > 0, "list the objects of every scene when choice is fixed", self.objects
            )
        if not self.replace and self.choice == "random" and self.objects:
            check(
                "objects_per_scene",
                hi <= len(set(self.objects)),
                f"be at most the {len(set(self.objects))} listed objects (or set replace: true)",
                self.objects_per_scene,
            )
        for name, w in self.weights.items():
            check(f"weights.{name}", w >= 0 and math.isfinite(w), "be >= 0", w)
        check("placement_sigma", self.placement_sigma > 0, "be > 0", self.placement_sigma)
        check("gap", 0 <= self.gap <= 0.1, "be in [0, 0.1] m", self.gap)
        flo, fhi = self.friction_range
        check("friction", 0 < flo <= fhi, "be > 0 (or [lo, hi] with 0 < lo <= hi)", self.friction)
        check("max_tries", self.max_tries >= 1, "be >= 1", self.max_tries)
        check("max_scene_tries", self.max_scene_tries >= 1, "be >= 1", self.max_scene_tries)
        check("max_tilt", 0 < self.max_tilt <= math.pi, "be in (0, pi] rad", self.max_tilt)

    @property
    def count_range(self) -> tuple[int, int]:
        """(min, max) objects per scene."""
        n = self.objects_per_scene
        return (n, n) if isinstance(n, int) else (int(n[0]), int(n[1]))

    @property
    def friction_range(self) -> tuple[float, float]:
        """(lo, hi) of the per-object friction."""
        f = self.friction
        return (float(f), float(f)) if isinstance(f, (int, float)) else (float(f[0]), float(f[1]))


# ---------------------------------------------------------------------------------------------------------------
# Placement
# ---------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class _Footprint:
    """An object's shape in one stable pose, for placement tests (world frame of the pose, before yaw/shift)."""

    hulls: tuple[np.ndarray, ...]
    """x/y convex hull (k, 2) of every convex part."""
    top: float
    """Highest point above the support, m."""


def _footprint(record: ObjectRecord, pose: np.ndarray) -> _Footprint:
    hulls = []
    top = -math.inf
    for vertices, _ in record.convex_parts:
        world = vertices @ pose[:3, :3].T + pose[:3, 3]
        top = max(top, float(world[:, 2].max()))
        xy = world[:, :2]
        try:
            hulls.append(xy[ConvexHull(xy).vertices])
        except Exception:  # noqa: BLE001 - a flat part (all points on a line) has no 2-D hull: use its extremes
            hulls.append(xy[[int(xy[:, 0].argmin()), int(xy[:, 0].argmax())]])
    return _Footprint(tuple(hulls), top)


def _rotate(points: np.ndarray, yaw: float, shift: np.ndarray) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return points @ np.array([[c, s], [-s, c]]) + shift


def _separated(a: np.ndarray, b: np.ndarray, gap: float) -> bool:
    """True when convex polygons a, b (k, 2) are at least ``gap`` apart along one of their edge normals.

    (Separation along any axis bounds the true distance from below, so this never accepts closer polygons; it
    may reject a few that are slightly further than ``gap`` apart near a corner.)
    """
    for poly in (a, b):
        edges = np.roll(poly, -1, axis=0) - poly
        normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
        lengths = np.linalg.norm(normals, axis=1)
        normals = normals[lengths > 1e-12] / lengths[lengths > 1e-12, None]
        if len(normals) == 0:
            continue
        pa, pb = a @ normals.T, b @ normals.T
        if np.any(pa.max(0) + gap <= pb.min(0)) or np.any(pb.max(0) + gap <= pa.min(0)):
            return True
    return False


def _overlaps(parts_a: Sequence[np.ndarray], parts_b: Sequence[np.ndarray], gap: float) -> bool:
    for a in parts_a:
        for b in parts_b:
            if a[:, 0].max() + gap <= b[:, 0].min() or b[:, 0].max() + gap <= a[:, 0].min():
                continue
            if a[:, 1].max() + gap <= b[:, 1].min() or b[:, 1].max() + gap <= a[:, 1].min():
                continue
            if not _separated(a, b, gap):
                return True
    return False


@dataclasses.dataclass
class _Counts:
    placement_tries: int = 0
    placement_failed: int = 0
    unstable_fallen: int = 0
    unstable_tipped: int = 0
    unstable_moving: int = 0
    scene_retries: int = 0


@dataclasses.dataclass(frozen=True, eq=False)
class _Placement:
    name: str
    pose_index: int
    pose: np.ndarray
    friction: float


def choose_objects(params: ScenesParams, library: Sequence[str], rng: np.random.Generator) -> list[str]:
    """Names of the objects of one scene draw (see :class:`ScenesParams`), drawn with ``rng``."""
    if params.choice == "fixed":
        return list(params.objects)
    pool = sorted(set(params.objects)) if params.objects else sorted(library)
    weights = np.array([params.weights.get(n, 1.0) for n in pool], dtype=float)
    if weights.sum() <= 0:
        raise SettingsError("weights: every object has weight 0")
    lo, hi = params.count_range
    k = int(rng.integers(lo, hi + 1))
    picks = rng.choice(len(pool), size=k, replace=params.replace, p=weights / weights.sum())
    return [pool[i] for i in picks]


def place_objects(
    names: Sequence[str],
    records: Mapping[str, ObjectRecord],
    params: ScenesParams,
    rng: np.random.Generator,
    counts: _Counts,
) -> list[_Placement]:
    """Non-overlapping resting placements of ``names`` on the support (objects that do not fit are left out)."""
    lo_region, hi_region, z_max = free_region(params.support)
    area = np.asarray(params.support.area, dtype=float) / 2
    gap = params.gap
    footprints: dict[tuple[str, int], _Footprint] = {}
    placed: list[tuple[_Placement, list[np.ndarray]]] = []
    flo, fhi = params.friction_range
    for name in names:
        record = records[name]
        probs = np.asarray(record.stable_probabilities, dtype=float)
        probs = probs / probs.sum()
        for _ in range(params.max_tries):
            counts.placement_tries += 1
            s = int(rng.choice(len(probs), p=probs))
            yaw = float(rng.uniform(-math.pi, math.pi))
            if params.placement == "uniform":
                xy = rng.uniform(-area, area)
            else:
                xy = np.clip(rng.normal(0.0, params.placement_sigma, size=2), -area, area)
            key = (name, s)
            if key not in footprints:
                footprints[key] = _footprint(record, record.stable_poses[s])
            fp = footprints[key]
            if fp.top + gap > z_max:
                continue
            hulls = [_rotate(h, yaw, xy) for h in fp.hulls]
            pts = np.concatenate(hulls)
            if np.any(pts.min(0) < lo_region + gap) or np.any(pts.max(0) > hi_region - gap):
                continue
            if any(_overlaps(hulls, other, gap) for _, other in placed):
                continue
            c, s_ = math.cos(yaw), math.sin(yaw)
            shift = np.eye(4)
            shift[:3, :3] = [[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]]
            shift[:3, 3] = [xy[0], xy[1], params.settle.drop_height]
            friction = float(rng.uniform(flo, fhi)) if fhi > flo else flo
            own = record.attrs.get("friction")  # the object's own (manifest) friction wins over the drawn one
            if own is not None:
                friction = float(own)
            placed.append((_Placement(name, s, shift @ record.stable_poses[s], friction), hulls))
            break
        else:
            counts.placement_failed += 1
    return [p for p, _ in placed]


# ---------------------------------------------------------------------------------------------------------------
# Settling
# ---------------------------------------------------------------------------------------------------------------


def _unstable(
    placements: Sequence[_Placement],
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
    placements: list[_Placement],
    records: Mapping[str, ObjectRecord],
    params: ScenesParams,
    counts: _Counts,
    image_size: tuple[int, int],
) -> tuple[list[_Placement], mujoco.MjModel, mujoco.MjData, float] | None:
    """Settle ``placements``; remove unstable objects and settle again until all rest (None: retry the scene)."""
    lo, _ = params.count_range
    minimum = len(params.objects) if params.choice == "fixed" else lo
    while True:
        objs = [placed_object(records[p.name], p.pose, p.friction) for p in placements]
        model = build_scene_spec(objs, params.support, PhysicsOptions(), image_size=image_size).compile()
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        result = settle(model, data, params.settle)
        poses = object_poses(model, data)
        bad = _unstable(placements, records, poses, result.moving(params.settle), params)
        if not bad:
            return placements, model, data, result.time
        for reason in bad.values():
            setattr(counts, f"unstable_{reason}", getattr(counts, f"unstable_{reason}") + 1)
        if params.on_unstable == "retry":
            return None
        placements = [p for i, p in enumerate(placements) if i not in bad]
        if len(placements) < max(minimum, 1):
            return None


# ---------------------------------------------------------------------------------------------------------------
# The stage
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
    counts = _Counts()
    cams = params.cameras
    image_size = (cams.width, cams.height)
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
    placements, model, data, settle_time = settled
    poses = object_poses(model, data)
    set_object_poses(model, data, poses)  # at rest: zero velocities, as a downstream stage will load it
    t_sample = time.perf_counter() - t0 - t_settle

    # Cameras look at the centre of the settled objects' bounding box.
    corners = np.concatenate([transform_points(pose, records[p.name].vertices) for p, pose in zip(placements, poses)])
    target = (corners.min(0) + corners.max(0)) / 2
    K = cams.intrinsics()
    cameras = []
    for _ in range(cams.num_views):
        d = rng.uniform(*cams.distance)
        el = rng.uniform(*cams.elevation)
        az = rng.uniform(*cams.azimuth)
        roll = rng.uniform(*cams.roll)
        cameras.append(Camera(K, camera_on_sphere(target, d, el, az, roll), cams.width, cams.height))

    t_setup = t_render = 0.0
    views = []
    if cams.render and cameras:
        t2 = time.perf_counter()
        with SceneRenderer(model, cams.width, cams.height) as renderer:
            t3 = time.perf_counter()
            views = [renderer.render(data, cam) for cam in cameras]
            t_render = time.perf_counter() - t3
        t_setup = time.perf_counter() - t2 - t_render

    n, v = len(placements), len(cameras)
    rgba = np.array([model.geom_rgba[model.geom(f"obj/{i}_{p.name}/visual").id] for i, p in enumerate(placements)])
    boxes = support_boxes(params.support)
    tree: dict[str, Any] = {
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
            "rgba": rgba.astype(np.float32).reshape(n, 4),
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
    if views:
        images: dict[str, Any] = {
            "rgb": np.stack([view.rgb for view in views]),
            "depth": np.stack([view.depth for view in views]),
            "segmentation": np.stack([view.segmentation for view in views]),
        }
        if cams.depth_noise.enabled:
            dn = cams.depth_noise
            images["depth_noisy"] = np.stack(
                [
                    depth_noise(view.depth, rng, sigma=dn.sigma, sigma_quadratic=dn.sigma_quadratic, dropout=dn.dropout)
                    for view in views
                ]
            )
        tree["images"] = images
        if cams.clouds != "none":
            tree["clouds"] = _clouds(views, cameras, cams.clouds)
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


def _clouds(views: Sequence[Any], cameras: Sequence[Camera], frames: str) -> dict[str, np.ndarray]:
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


# ---------------------------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------------------------


def scene_spec(
    scene: SceneRecord,
    records: Mapping[str, ObjectRecord],
    physics: PhysicsOptions | None = None,
    *,
    visual: bool = True,
) -> mujoco.MjSpec:
    """The MuJoCo spec of a scene at its settled poses (``records``: object records by name, e.g. from
    :func:`graspgen.io.objects.read_object`). ``visual=False`` leaves out the visual meshes (faster to compile)."""
    missing = sorted(set(scene.object_names) - set(records))
    if missing:
        raise ValueError(f"records: no object record for {missing[0]!r} (scene {scene.scene_id})")
    objs = [
        placed_object(records[name], pose, float(mu), visual=visual)
        for name, pose, mu in zip(scene.object_names, scene.poses, scene.friction)
    ]
    size = (scene.cameras[0].width, scene.cameras[0].height) if scene.cameras else (640, 480)
    return build_scene_spec(objs, scene.support, physics, image_size=size)


# ---------------------------------------------------------------------------------------------------------------
# Looking at a scene
# ---------------------------------------------------------------------------------------------------------------


