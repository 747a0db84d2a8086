"""Antipodal grasp candidates on a triangle mesh: pure geometry (numpy + trimesh rays), usable from a notebook.

One call of :func:`sample_antipodal`:

1. ``num_surface_points`` points uniformly by area (drawn from ``rng``), each ``p1`` with inward normal ``n1``.
2. ``rays_per_point`` directions ``d`` uniform inside the friction cone (half-angle ``atan(mu)``) about ``n1``.
3. Each ray starts ``surface_offset`` inside the object; its first hit must be an exit face, ``p2``, else the ray
   is rejected as ``no_exit`` (open or inconsistently wound mesh).
4. Checks, counted under the first failed (:class:`RejectCounts`): ``outside_cone`` (the line ``p1 -> p2`` in both
   friction cones), ``width_too_small`` (``width >= max(gripper.min_width, surface_offset)``), ``width_too_large``
   (``width + min_clearance <= gripper.max_width``; the gripper opens to ``min(width + width_margin, max_width)``).
5. ``num_orientations`` approach axes ``z`` about ``x = (p2 - p1) / width`` (``p1`` the left pad's contact, on -x),
   from a random phase; ``y = z x x``.
6. Approach filter on the world approach axis: ``"above"`` (angle to straight down ``<= max_approach_angle``),
   ``"hemisphere"`` (``z_w[2] < 0``) or ``"any"``.
7. ``num_depths`` TCP set-backs ``d`` along ``-z`` (:func:`grasp_depths`), so the contacts lie at
   ``(-+width / 2, 0, d)`` in the TCP frame, on the pad faces.

Without ``embreex`` trimesh's ray casting is about 1000x slower, and this module warns.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
import trimesh

from graspgen.errors import SettingsError
from graspgen.grippers import GripperSpec
from graspgen.validation import (
    check,
    check_choice,
    check_instance,
    check_number,
    check_positive_int,
    check_rng,
    check_transform,
)

__all__ = [
    "APPROACH_MODES",
    "AntipodalParams",
    "RejectCounts",
    "AntipodalCandidates",
    "sample_antipodal",
    "grasp_depths",
    "narrowest_width",
    "uses_embree",
]

APPROACH_MODES = ("above", "hemisphere", "any")
"""Accepted values of :attr:`AntipodalParams.approach`."""


def _check_mesh(mesh: object) -> None:
    check_instance("mesh", mesh, trimesh.Trimesh, what="trimesh.Trimesh")
    check("mesh", len(mesh.faces) > 0 and float(mesh.area) > 0, "have faces of positive area", mesh)


def narrowest_width(vertices: np.ndarray) -> float:
    """The object's width at its narrowest, m: the smallest extent of its convex hull along a hull face normal (0 for a
    flat or degenerate point set). An object wider than a gripper's opening here can only be pinched at thin parts."""
    try:
        hull = trimesh.convex.convex_hull(np.asarray(vertices, dtype=np.float64))
    except Exception:  # noqa: BLE001 - qhull refuses flat sets: no width to speak of
        return 0.0
    if len(hull.faces) == 0:
        return 0.0
    extents = np.ptp(hull.vertices @ hull.face_normals.T, axis=0)
    return float(extents.min())


def uses_embree(mesh: trimesh.Trimesh) -> bool:
    """Whether ``mesh.ray`` is trimesh's Embree intersector (fast) rather than the pure-Python fallback."""
    return type(mesh.ray).__module__.endswith("ray_pyembree")


# ---------------------------------------------------------------------------------------------------------------
# Data
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class AntipodalParams:
    """Settings of the antipodal sampler (the opening range comes from the :class:`GripperSpec`)."""

    num_surface_points: int = 256
    """Surface points ``p1`` drawn per call (uniform by area)."""
    rays_per_point: int = 4
    """Rays cast from each surface point, uniform by solid angle inside its friction cone."""
    friction: float = 0.5
    """Coulomb friction coefficient mu (dimensionless, > 0); the friction cone's half-angle is ``atan(mu)``."""
    num_orientations: int = 8
    """Approach axes per contact pair, evenly spaced about the contact line (random phase per pair)."""
    approach: str = "hemisphere"
    """Approach filter in the world frame: ``"above"`` (within ``max_approach_angle`` of straight down),
    ``"hemisphere"`` (any downward component: world z of the approach axis < 0) or ``"any"`` (no filter)."""
    max_approach_angle: float = math.pi / 4
    """Largest angle (rad, in (0, pi/2)) between the approach axis and straight down for ``approach="above"``."""
    width_margin: float = 0.02
    """Opening margin (m, >= 0): the gripper opens to ``min(width + width_margin, gripper.max_width)`` before
    approaching (``width_margin / 2`` of clearance per side where the stroke allows)."""
    min_clearance: float = 0.01
    """Smallest opening beyond the contact width (m, in ``[0, width_margin]``): pairs with ``width + min_clearance <=
    gripper.max_width`` are kept, so a wide object is still graspable although ``width + width_margin`` exceeds the
    stroke."""
    surface_offset: float = 1e-5
    """How far (m, > 0) inside the surface each ray starts, so that it does not hit its own face; widths below it are
    rejected as too small."""
    num_depths: int = 3
    """Grasp depths per oriented contact pair (>= 1), evenly spaced in ``[0, pad_length / 2 - depth_margin]`` (1: the
    TCP at the contacts' midpoint). Why 3: docs/decisions/2026-11-22-grasp-depths.md."""
    depth_margin: float = 0.005
    """Smallest distance (m, >= 0) between the contact line and the pad tips at the largest depth, so the pads
    still cover the contact with some face to spare (docs/decisions/2026-11-22-grasp-depths.md)."""

    def __post_init__(self) -> None:
        check_positive_int("num_surface_points", self.num_surface_points)
        check_positive_int("rays_per_point", self.rays_per_point)
        check_number("friction", self.friction, low=0.0, low_open=True)
        check_positive_int("num_orientations", self.num_orientations)
        check_choice("approach", self.approach, APPROACH_MODES)
        check_number("max_approach_angle", self.max_approach_angle, low=0.0, high=math.pi / 2, low_open=True,
                     high_open=True)
        check_number("width_margin", self.width_margin, low=0.0)
        check_number("min_clearance", self.min_clearance, low=0.0, high=self.width_margin)
        check_number("surface_offset", self.surface_offset, low=0.0, low_open=True)
        check_positive_int("num_depths", self.num_depths)
        check_number("depth_margin", self.depth_margin, low=0.0)

    @property
    def cone_half_angle(self) -> float:
        """Half-angle (rad) of the friction cone: ``atan(friction)``."""
        return math.atan(self.friction)


@dataclass(frozen=True)
class RejectCounts:
    """Why sampled rays and oriented candidates were dropped, for one call of :func:`sample_antipodal`.

    Every ray is counted exactly once: ``rays = no_exit + outside_cone + width_too_small + width_too_large +
    pairs``; every accepted pair gives ``num_orientations * num_depths`` candidates: ``pairs * num_orientations *
    num_depths = approach + kept``.
    """

    rays: int
    """Rays cast (``num_surface_points * rays_per_point``)."""
    no_exit: int
    """Rays that hit nothing, or first hit a face facing against the ray (the start was not inside the object)."""
    outside_cone: int
    """Rays whose contact line ``p1 -> p2`` is outside the friction cone at the second (or, by round-off, the
    first) contact."""
    width_too_small: int
    """Rays with ``width < max(gripper.min_width, surface_offset)``."""
    width_too_large: int
    """Rays with ``width + width_margin > gripper.max_width``."""
    pairs: int
    """Rays that passed every check: accepted contact pairs."""
    approach: int
    """Candidates (pairs x orientations x depths) dropped by the approach filter (it drops all depths of an
    orientation together)."""
    kept: int
    """Oriented candidates kept: the length of the :class:`AntipodalCandidates`."""

    def as_dict(self) -> dict[str, int]:
        """The counts by name (plain ints, for logs and shard metadata)."""
        return {k: int(getattr(self, k)) for k in self.__dataclass_fields__}


def _frozen(array: np.ndarray) -> np.ndarray:
    array = np.ascontiguousarray(array)
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class AntipodalCandidates:
    """``n`` antipodal grasp candidates on one object; arrays read-only, row ``i`` of each is candidate ``i``, in runs
    of at most ``num_orientations * num_depths`` sharing a contact pair (``ray_index``), increasing."""

    p1: np.ndarray
    """``(n, 3) float64`` first contact (m, object frame): the surface point the ray started from; the left pad's
    contact (TCP -x side)."""
    p2: np.ndarray
    """``(n, 3) float64`` second contact (m, object frame): where the ray leaves the object; the right pad's
    contact (TCP +x side)."""
    n1: np.ndarray
    """``(n, 3) float64`` unit inward normal at ``p1`` (object frame): the direction that finger pushes."""
    n2: np.ndarray
    """``(n, 3) float64`` unit inward normal at ``p2`` (object frame)."""
    face1: np.ndarray
    """``(n,) int64`` mesh face of ``p1``."""
    face2: np.ndarray
    """``(n,) int64`` mesh face of ``p2``."""
    width: np.ndarray
    """``(n,) float64`` pad separation at contact ``|p2 - p1|`` (m)."""
    pose_object: np.ndarray
    """``(n, 4, 4) float64`` TCP pose in the object frame (origin ``depth`` behind the contacts' midpoint along
    -z, x along ``p2 - p1``, z the approach axis)."""
    pose_world: np.ndarray
    """``(n, 4, 4) float64`` TCP pose in the world frame: ``object_pose @ pose_object``."""
    approach_angle: np.ndarray
    """``(n,) float64`` angle (rad, [0, pi]) between the world-frame approach axis and straight down."""
    depth: np.ndarray
    """``(n,) float64`` grasp depth (m, >= 0): how far the contact line lies ahead of the TCP along its z axis (the
    contacts are at ``(-+width / 2, 0, depth)`` in the TCP frame)."""
    ray_index: np.ndarray
    """``(n,) int64`` which ray (``point * rays_per_point + k``) gave the contact pair."""
    object_pose: np.ndarray
    """``(4, 4) float64`` the object's pose in the world used for ``pose_world`` and the approach filter."""
    rejected: RejectCounts = field(repr=False)
    """Bookkeeping of what was dropped and why."""

    def __len__(self) -> int:
        return int(self.width.shape[0])


# ---------------------------------------------------------------------------------------------------------------
# Sampling
# ---------------------------------------------------------------------------------------------------------------


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _perpendicular_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``(a, b)`` with ``(a, b, axis)`` right-handed orthonormal, for unit ``axis (m, 3)``;
    deterministic."""
    e = np.zeros_like(axis)
    e[np.arange(len(axis)), np.argmin(np.abs(axis), axis=1)] = 1.0
    a = _unit(np.cross(axis, e))
    b = np.cross(axis, a)
    return a, b


def _sample_surface(mesh: trimesh.Trimesh, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``count`` points uniform by area on ``mesh``: (points (count, 3), face indices (count,) int64)."""
    cdf = np.cumsum(mesh.area_faces)
    # searchsorted on the unnormalised CDF avoids a division whose round-off could make the last bin unreachable.
    faces = np.searchsorted(cdf, rng.random(count) * cdf[-1], side="right")
    faces = np.minimum(faces, len(cdf) - 1).astype(np.int64)
    uv = rng.random((count, 2))
    # Fold the unit square onto the triangle u + v <= 1 (uniform on the triangle).
    fold = uv.sum(axis=1) > 1.0
    uv[fold] = 1.0 - uv[fold]
    tri = mesh.triangles[faces]
    points = tri[:, 0] + uv[:, :1] * (tri[:, 1] - tri[:, 0]) + uv[:, 1:] * (tri[:, 2] - tri[:, 0])
    return points, faces


def _cone_directions(axis: np.ndarray, per_axis: int, cos_max: float, rng: np.random.Generator) -> np.ndarray:
    """``per_axis`` unit directions per unit ``axis (m, 3)``, uniform by solid angle within ``acos(cos_max)`` of
    it: ``(m, per_axis, 3)``. Uniform ``cos(theta)`` in ``[cos_max, 1]`` is uniform on the spherical cap."""
    draws = rng.random((len(axis), per_axis, 2))
    cos_t = 1.0 - draws[..., 0] * (1.0 - cos_max)
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * np.pi * draws[..., 1]
    t1, t2 = _perpendicular_basis(axis)
    lateral = np.cos(phi)[..., None] * t1[:, None, :] + np.sin(phi)[..., None] * t2[:, None, :]
    return cos_t[..., None] * axis[:, None, :] + sin_t[..., None] * lateral


def grasp_depths(gripper: GripperSpec, params: AntipodalParams) -> np.ndarray:
    """The grasp depths (m) of every oriented contact pair: ``(num_depths,) float64`` evenly spaced from 0 to
    ``pad_length / 2 - depth_margin`` (``pad_length = gripper.pad_size[2]``); ``[0]`` for one depth.

    Raises
    ------
    ValueError
        ``num_depths > 1`` while ``depth_margin >= pad_length / 2``.
    """
    if params.num_depths == 1:
        return np.zeros(1)
    deepest = gripper.pad_size[2] / 2.0 - params.depth_margin
    if not deepest > 0.0:
        raise SettingsError(f"params.depth_margin: {params.depth_margin} m leaves no depth range on the pads of "
                            f"gripper {gripper.name!r} (pad length {gripper.pad_size[2]} m); use num_depths 1 or a "
                            "smaller margin")
    return np.linspace(0.0, deepest, params.num_depths)


def sample_antipodal(mesh: trimesh.Trimesh, gripper: GripperSpec, params: AntipodalParams,
                     rng: np.random.Generator, *, object_pose=None) -> AntipodalCandidates:
    """Antipodal grasp candidates on ``mesh`` for ``gripper`` (algorithm: the module docstring).

    Parameters
    ----------
    mesh
        The object's surface in its object frame (m), watertight with outward normals; reuse one mesh object across
        calls (its ray intersector is cached on it).
    gripper
        Gives the opening range ``[min_width, max_width]`` and the pad size.
    params
        Sampler settings.
    rng
        The only source of randomness, drawn in a fixed order whatever is accepted: the same seed gives bitwise
        identical arrays.
    object_pose
        (4, 4) pose of the object frame in the world (default identity): gives ``pose_world`` and the approach filter.

    Returns
    -------
    AntipodalCandidates
        The kept candidates (possibly none) and :class:`RejectCounts`.

    Raises
    ------
    SettingsError
        A wrong argument type or shape, or margins leaving no usable opening or depth range for ``gripper``.
    """
    _check_mesh(mesh)
    check_instance("gripper", gripper, GripperSpec)
    check_instance("params", params, AntipodalParams)
    check_rng("rng", rng)
    T_world = np.eye(4) if object_pose is None else check_transform("object_pose", object_pose)
    min_width = max(gripper.min_width, params.surface_offset)
    max_width = gripper.max_width - params.min_clearance
    if max_width < min_width:
        raise SettingsError(f"params.min_clearance: {params.min_clearance} m leaves no opening for gripper "
                            f"{gripper.name!r} (max_width {gripper.max_width} m)")
    depths = grasp_depths(gripper, params)
    if not uses_embree(mesh):
        warnings.warn("trimesh has no Embree ray intersector (install embreex): antipodal sampling will be ~1000x "
                      "slower", RuntimeWarning, stacklevel=2)

    rays = _draw_rays(mesh, params, rng)
    hits = _second_contacts(mesh, rays, params.surface_offset)
    checks = _pair_checks(rays, hits, min_width, max_width, _cos_friction(params.friction))
    keep_rays = checks["keep_rays"]
    pair, orient, cos_t, sin_t, a, b, approach_angle, keep = _orientations(
        hits["x_axis"][keep_rays], rays["phase"][keep_rays], T_world, params)
    mid = (rays["p1"][keep_rays] + hits["p2"][keep_rays]) / 2.0
    n_depth = len(depths)
    pair, orient = np.repeat(pair, n_depth), np.repeat(orient, n_depth)
    depth = np.tile(depths, len(pair) // n_depth)
    pose_obj = _tcp_poses(hits["x_axis"][keep_rays], a, b, mid, cos_t, sin_t, pair, orient, depth)
    pose_world = np.matmul(T_world, pose_obj)
    approach_angle = approach_angle[pair, orient]
    rows = keep_rays[pair]
    counts = _reject_counts(rays, hits, checks, keep, n_depth, len(rows))
    return AntipodalCandidates(
        p1=_frozen(rays["p1"][rows]),
        p2=_frozen(hits["p2"][rows]),
        n1=_frozen(rays["n1"][rows]),
        n2=_frozen(hits["n2"][rows]),
        face1=_frozen(rays["face1"][rows]),
        face2=_frozen(hits["hit"][rows]),
        width=_frozen(hits["width"][rows]),
        pose_object=_frozen(pose_obj),
        pose_world=_frozen(pose_world),
        approach_angle=_frozen(approach_angle),
        depth=_frozen(depth),
        ray_index=_frozen(rows.astype(np.int64)),
        object_pose=_frozen(T_world.copy()),
        rejected=counts,
    )


def _reject_counts(rays: dict, hits: dict, checks: dict, keep: np.ndarray, n_depth: int, kept: int) -> RejectCounts:
    return RejectCounts(
        rays=len(rays["d"]),
        no_exit=int(np.count_nonzero(~hits["exit_ok"])),
        outside_cone=int(np.count_nonzero(checks["fail_cone"])),
        width_too_small=int(np.count_nonzero(checks["fail_small"])),
        width_too_large=int(np.count_nonzero(checks["fail_large"])),
        pairs=int(len(checks["keep_rays"])),
        approach=int((keep.size - np.count_nonzero(keep)) * n_depth),
        kept=int(kept),
    )


def _cos_friction(friction: float) -> float:
    """cos(atan(mu)): the cosine of the friction cone's half angle."""
    return 1.0 / math.sqrt(1.0 + friction ** 2)


def _draw_rays(mesh: trimesh.Trimesh, params: AntipodalParams, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """All random draws up front, in a fixed order: contacts ``p1`` (r, 3) on ``face1`` with inward normals ``n1``, cone
    directions ``d`` (r, 3), orientation phases (r,)."""
    n_rays_per = params.rays_per_point
    p1, face1 = _sample_surface(mesh, params.num_surface_points, rng)
    n1 = -mesh.face_normals[face1]
    d = _cone_directions(n1, n_rays_per, _cos_friction(params.friction), rng).reshape(-1, 3)
    phase = rng.random(len(d)) * (2.0 * np.pi / params.num_orientations)
    ray_point = np.repeat(np.arange(len(p1)), n_rays_per)
    return {"p1": p1[ray_point], "face1": face1[ray_point], "n1": n1[ray_point], "d": d, "phase": phase}


def _second_contacts(mesh: trimesh.Trimesh, rays: dict[str, np.ndarray], surface_offset: float) -> dict:
    """Second contact of each ray: the first face hit from just inside. ``exit_ok`` ``(r,)`` marks rays leaving
    through an exit face; ``p2``, ``n2``, ``width`` and the closing axis ``x_axis`` are per ray."""
    p1, d = rays["p1"], rays["d"]
    face_normals = mesh.face_normals
    origins = p1 + surface_offset * d
    hit = np.asarray(mesh.ray.intersects_first(origins, d), dtype=np.int64)
    exit_ok = hit >= 0
    hit_safe = np.where(exit_ok, hit, 0)
    fn2 = face_normals[hit_safe]
    denom = np.einsum("ij,ij->i", d, fn2)
    exit_ok &= denom > 0.0  # an exit face faces along the ray
    # Exact float64 hit point on the hit face's plane (Embree works in float32 and returns only the face).
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("ij,ij->i", mesh.triangles[hit_safe, 0] - origins, fn2) / denom
    exit_ok &= np.isfinite(t)
    t = np.where(exit_ok, np.maximum(t, 0.0), 0.0)
    p2 = origins + t[:, None] * d
    delta = p2 - p1
    width = np.linalg.norm(delta, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_axis = delta / width[:, None]
    return {"hit": hit, "exit_ok": exit_ok, "p2": p2, "n2": -fn2, "width": width, "x_axis": x_axis}


def _pair_checks(rays: dict, hits: dict, min_width: float, max_width: float, cos_max: float) -> dict:
    """The pair checks, each ray counted under the first it fails; ``keep_rays`` the indices of those passing."""
    x_axis, exit_ok, width = hits["x_axis"], hits["exit_ok"], hits["width"]
    in_cone = ((np.einsum("ij,ij->i", x_axis, rays["n1"]) >= cos_max)
               & (np.einsum("ij,ij->i", -x_axis, hits["n2"]) >= cos_max))
    fail_cone = exit_ok & ~in_cone
    alive = exit_ok & in_cone
    fail_small = alive & (width < min_width)
    alive &= ~fail_small
    fail_large = alive & (width > max_width)
    alive &= ~fail_large
    return {"fail_cone": fail_cone, "fail_small": fail_small, "fail_large": fail_large,
            "keep_rays": np.flatnonzero(alive)}


def _orientations(x: np.ndarray, phase: np.ndarray, T_world: np.ndarray, params: AntipodalParams):
    """Orientations about each contact line ``x`` (k, 3) and the approach filter: kept ``(pair, orient)`` indices,
    ``cos_t``/``sin_t`` (k, K), basis ``a``, ``b`` (k, 3), ``approach_angle`` (k, K), ``keep``."""
    # With (a, b, x) right-handed orthonormal, z = cos(t) a + sin(t) b gives y = z x x = sin(t) a - cos(t) b: no
    # cross products; the approach filter needs only the world z components of a and b.
    n_orient = params.num_orientations
    a, b = _perpendicular_basis(x)
    theta = phase[:, None] + (2.0 * np.pi / n_orient) * np.arange(n_orient)  # (k, K)
    cos_t, sin_t = np.cos(theta), np.sin(theta)
    # World z component of the approach axis (row 2 of R_world @ z), for the filter before building any pose.
    z_world_z = cos_t * (a @ T_world[2, :3])[:, None] + sin_t * (b @ T_world[2, :3])[:, None]  # (k, K)
    approach_angle = np.arccos(np.clip(-z_world_z, -1.0, 1.0))
    if params.approach == "above":
        keep = approach_angle <= params.max_approach_angle
    elif params.approach == "hemisphere":
        keep = z_world_z < 0.0
    else:
        keep = np.ones(z_world_z.shape, dtype=bool)
    pair, orient = np.nonzero(keep)
    return pair, orient, cos_t, sin_t, a, b, approach_angle, keep


def _tcp_poses(x, a, b, mid, cos_t, sin_t, pair, orient, depth) -> np.ndarray:
    """``(m, 4, 4)`` TCP poses in the object frame: each kept orientation at each depth (innermost), the TCP set
    back along -z from the contacts' midpoint."""
    cos_k, sin_k = cos_t[pair, orient, None], sin_t[pair, orient, None]
    a_k, b_k = a[pair], b[pair]
    z_k = cos_k * a_k + sin_k * b_k
    pose_obj = np.zeros((len(pair), 4, 4))
    pose_obj[:, :3, 0] = x[pair]
    pose_obj[:, :3, 1] = sin_k * a_k - cos_k * b_k
    pose_obj[:, :3, 2] = z_k
    pose_obj[:, :3, 3] = mid[pair] - depth[:, None] * z_k
    pose_obj[:, 3, 3] = 1.0
    return pose_obj
