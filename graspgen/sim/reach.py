"""Which grasp candidates the real hand can reach: a cheap screen from the gripper's own geometry.

The antipodal sampler knows only the contact pair and the pads; the hand also has finger links, knuckles (the
2F-85's 4-bar linkage) and a palm, and it comes in along its approach axis from ``approach_distance`` back. The
exact test is the collision pre-filter (:class:`graspgen.sim.prefilter.CollisionChecker`: MuJoCo on every geom at
11 poses, ~1-2 ms a candidate); this screen rejects, before it, the candidates whose hand would plainly run into
the target or below the support, so the pre-filter's time goes to candidates that can pass it. It only screens:
every row of the grasp table is still labelled by the pre-filter.

The gripper's collision geometry (:func:`clearance_boxes`): the gripper is compiled alone, its jaws set to each of
``num_openings`` openings evenly spaced over its stroke (linkage joints following the jaws), and every colliding
geom is taken as the 26-DOP around its vertices in the TCP frame (the polytope of 26 faces, normal to the axes and
the edge and corner diagonals, that just holds the geom: exact for the pads' boxes, a few mm loose around the
knuckles' slanted links): the pads, the finger links, the knuckles and the palm as MuJoCo has them. A candidate
uses the grid opening nearest its own (``width + width_margin`` clipped to the stroke).

A candidate (TCP pose ``T`` in the object frame, opening ``o``) is **unreachable** (:func:`reachable` false) when

* ``target``: a point of the object's surface lies inside a piece swept along the approach (the gripper moves
  along +z from ``approach_distance`` back to the grasp pose), the piece shrunk on every side by ``tolerance``
  (not by the pre-filter's 2 mm touch allowance of the jaws: shrunk by that, a 6 mm finger is too thin to catch
  surface points a few mm apart); or
* ``ground``: a vertex of a piece, at the grasp pose or the pre-grasp pose, lies below the support's top
  (world z = 0) by more than ``tolerance``.

The surface points are drawn once per object (uniform by area, from the task's generator). A screen that is too
strict would drop grasps the pre-filter passes: points are tested, not the surface between them, and the
pieces are MuJoCo's own, so it is never stricter than the pre-filter by more than ``tolerance`` at a sampled
point and the sampled approach line (the pre-filter checks 11 poses on it; the screen the whole segment).
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache

import mujoco
import numpy as np
from scipy.spatial import ConvexHull

from graspgen.grippers import GripperSpec, jaw_opening
from graspgen.sim.gripper_model import attach_gripper
from graspgen.sim.gripper_state import linkage_couplings
from graspgen.validation import check_number, check_positive_int

__all__ = ["ReachParams", "ClearanceBoxes", "clearance_boxes", "reachable", "surface_points"]

_PREFIX = "gripper/"

_DIRECTIONS = np.array([(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1) if x or y or z], float)
_DIRECTIONS /= np.linalg.norm(_DIRECTIONS, axis=1, keepdims=True)
"""The 26 face normals of the bounding polytope of each piece (a 26-DOP: axes, edge and corner diagonals)."""


@dataclasses.dataclass(frozen=True)
class ReachParams:
    """Settings of the reachability screen (module docstring)."""

    enabled: bool = True
    """Screen candidates before the pre-filter; false sends every candidate to it."""
    num_points: int = 2048
    """Surface points of the object the hand's pieces are tested against (uniform by area; ~2 mm apart on a 4 cm
    cube, ~3.5 mm on a 10 cm bowl, inside and out)."""
    num_openings: int = 17
    """Openings over the stroke at which the gripper's pieces are computed (the candidate uses the nearest: 5 mm
    apart for the 2F-85)."""
    tolerance: float = 0.001
    """How far (m, >= 0) a surface point may be inside a piece, or a vertex below the
    support, before the candidate is screened out: slack, so the screen stays looser than the pre-filter."""

    def __post_init__(self) -> None:
        check_positive_int("num_points", self.num_points)
        check_positive_int("num_openings", self.num_openings)
        check_number("tolerance", self.tolerance, low=0.0)


@dataclasses.dataclass(frozen=True, eq=False)
class ClearanceBoxes:
    """The gripper's colliding geoms as convex pieces (half-space sets) in the TCP frame at a grid of openings."""

    openings: np.ndarray
    """``(m,) float`` jaw openings (m), increasing."""
    planes: np.ndarray
    """``(m, b, f, 4) float`` each piece's faces ``(a, c)``: inside where ``a . x + c <= 0`` (``a`` unit, m);
    pieces with fewer faces are padded with ``(0, 0, 0, -1)`` (always satisfied)."""
    corners: np.ndarray
    """``(m, b, v, 3) float`` each piece's vertices (m, TCP frame), padded by repeating the first."""


def _geom_vertices(model: mujoco.MjModel, data: mujoco.MjData, g: int) -> np.ndarray:
    """The vertices of geom ``g`` in the world (= TCP) frame: a mesh's own, a box's corners, else its bounding
    box's corners."""
    R, x = data.geom_xmat[g].reshape(3, 3), data.geom_xpos[g]
    if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
        mesh = model.geom_dataid[g]
        start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        local = model.mesh_vert[start:start + count].astype(float)
    else:
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
        half = model.geom_size[g] if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX else model.geom_aabb[g, 3:]
        centre = np.zeros(3) if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX else model.geom_aabb[g, :3]
        local = centre + signs * half
    return x + local @ R.T


@lru_cache(maxsize=8)
def clearance_boxes(gripper: GripperSpec, num_openings: int) -> ClearanceBoxes:
    """The gripper's colliding geoms as convex pieces in the TCP frame at ``num_openings`` openings over its
    stroke (module docstring). Cached per gripper."""
    spec = mujoco.MjSpec()
    attach_gripper(spec, gripper, name_prefix=_PREFIX)
    model = spec.compile()
    data = mujoco.MjData(model)
    geoms = [g for g in range(model.ngeom) if (model.geom_contype[g] or model.geom_conaffinity[g])
             and (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or "").startswith(_PREFIX)]
    couplings = linkage_couplings(model, prefix=_PREFIX)
    adr = [int(model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{_PREFIX}{s}_slide")])
           for s in ("left", "right")]
    openings = np.linspace(gripper.min_width, gripper.max_width, num_openings)
    pieces: list[list[tuple[np.ndarray, np.ndarray]]] = []
    for opening in openings:
        data.qpos[:] = model.qpos0  # the free joint at qpos0: the TCP frame is the world frame
        data.qpos[adr[0]] = data.qpos[adr[1]] = opening / 2.0  # jaw joint = half the pad separation
        couplings.apply(data.qpos)
        mujoco.mj_kinematics(model, data)
        row = []
        for g in geoms:
            v = _geom_vertices(model, data, g)
            hull = v[ConvexHull(v).vertices]
            row.append((np.concatenate([_DIRECTIONS, -(hull @ _DIRECTIONS.T).max(axis=0)[:, None]], axis=1), hull))
        pieces.append(row)
    f = max(len(e) for row in pieces for e, _ in row)
    nv = max(len(v) for row in pieces for _, v in row)
    planes = np.zeros((num_openings, len(geoms), f, 4))
    planes[..., 3] = -1.0
    corners = np.zeros((num_openings, len(geoms), nv, 3))
    for i, row in enumerate(pieces):
        for j, (eq, v) in enumerate(row):
            planes[i, j, :len(eq)] = eq
            corners[i, j] = v[np.minimum(np.arange(nv), len(v) - 1)]
    return ClearanceBoxes(openings, planes, corners)


def surface_points(vertices: np.ndarray, faces: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """``(count, 3) float`` points uniform by area on the triangles ``vertices[faces]`` (draws: ``3 count``)."""
    tri = np.asarray(vertices, dtype=float)[np.asarray(faces)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    cdf = np.cumsum(area)
    face = np.minimum(np.searchsorted(cdf, rng.random(count) * cdf[-1], side="right"), len(cdf) - 1)
    uv = rng.random((count, 2))
    fold = uv.sum(axis=1) > 1.0
    uv[fold] = 1.0 - uv[fold]
    t = tri[face]
    return t[:, 0] + uv[:, :1] * (t[:, 1] - t[:, 0]) + uv[:, 1:] * (t[:, 2] - t[:, 0])


def reachable(pose_object: np.ndarray, pose_world: np.ndarray, widths: np.ndarray, points: np.ndarray,
              boxes: ClearanceBoxes, gripper: GripperSpec, width_margin: float, approach_distance: float,
              params: ReachParams) -> tuple[np.ndarray, np.ndarray]:
    """Which candidates pass the screen (module docstring).

    Parameters
    ----------
    pose_object, pose_world : (n, 4, 4) float
        TCP poses in the object frame and in the world.
    widths : (n,) float
        Contact widths (m); the jaws open to ``width + width_margin`` clipped to the stroke.
    points : (p, 3) float
        Surface points of the object, object frame (m).
    boxes : ClearanceBoxes
    gripper : GripperSpec
    width_margin, approach_distance : float
        The pre-filter's (m).
    params : ReachParams

    Returns
    -------
    (ok (n,) bool, why (n,) int8): ``why`` 0 ground, 1 target, -1 reachable.
    """
    n = len(widths)
    why = np.full(n, -1, dtype=np.int8)
    if n == 0:
        return why < 0, why
    opening = jaw_opening(widths, width_margin, gripper.min_width, gripper.max_width)
    k = np.abs(opening[:, None] - boxes.openings[None, :]).argmin(axis=1)
    planes, corners = boxes.planes[k], boxes.corners[k]  # (n, b, f, 4), (n, b, v, 3)
    tol = params.tolerance
    # Ground: the lowest vertex of every piece at the grasp pose and at the pre-grasp pose (z is linear between).
    R, t = pose_world[:, :3, :3], pose_world[:, :3, 3]
    lowest = (np.einsum("nbvj,nj->nbv", corners, R[:, 2, :]).min(axis=(1, 2)) + t[:, 2])
    lowest = np.minimum(lowest, lowest - approach_distance * R[:, 2, 2])  # back along -z of the TCP
    why[lowest < -tol] = 0
    # Target: a surface point inside a piece swept along the approach (shrunk by the tolerance): the gripper
    # moved back by s in [0, D] sees the point at q + s z, so each face bounds s on one side.
    live = np.flatnonzero(why < 0)  # only candidates still reachable need the (dearer) target test
    if len(live) == 0:
        return why < 0, why
    Ro, to = pose_object[live, :3, :3], pose_object[live, :3, 3]
    q = np.einsum("npj,nji->npi", points[None] - to[:, None, :], Ro)  # (m, p, 3) TCP frame
    qx, qy, qz = (np.ascontiguousarray(q[..., i]) for i in range(3))
    planes = planes[live]
    box_lo, box_hi = boxes.corners.min(axis=2)[k[live]] + tol, boxes.corners.max(axis=2)[k[live]] - tol  # (m, b, 3)
    box_lo[..., 2] -= approach_distance
    hit = np.zeros(len(live), dtype=bool)
    for b in range(planes.shape[1]):
        # Cheap first: the points inside the piece's swept bounding box; the 26 faces only for those.
        lo, hi = box_lo[:, b], box_hi[:, b]
        box = (qx >= lo[:, :1]) & (qx <= hi[:, :1]) & (qy >= lo[:, 1:2]) & (qy <= hi[:, 1:2])
        box &= (qz >= lo[:, 2:]) & (qz <= hi[:, 2:])
        cand, pt = np.nonzero(box)
        if len(cand) == 0:
            continue
        a, c = planes[cand, b, :, :3], planes[cand, b, :, 3] + tol  # (k, f, 3), (k, f)
        r = -(np.einsum("kj,kfj->kf", q[cand, pt], a) + c)  # need s a_z <= r on every face
        az = a[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = r / az
        s_hi = np.where(az > 1e-12, bound, np.inf).min(axis=1)
        s_lo = np.where(az < -1e-12, bound, -np.inf).max(axis=1)
        flat_ok = np.where(np.abs(az) <= 1e-12, r >= 0, True).all(axis=1)
        inside = flat_ok & (np.maximum(s_lo, 0.0) <= np.minimum(s_hi, approach_distance))
        hit[cand[inside]] = True
    why[live[hit]] = 1
    return why < 0, why
