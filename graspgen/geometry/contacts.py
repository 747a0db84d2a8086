"""Contacts of a parallel-jaw grasp found by closing the pads onto a mesh with ray casts (no simulation).

Used for grasps that were not simulated (rejected by the pre-filter, perturbed copies) so every grasp can get an
epsilon label from contacts of the same kind: each pad is a grid of rays cast along the closing direction from
its open position; the pad stops at its nearest hit, and every ray hitting within ``tolerance`` of that stop is a
contact point (several per pad on a flat face, one on a sphere). The object is held fixed while the pads close,
so this is the contact set a quasi-static closing would reach, not what a simulation would settle into.

Frames: TCP frame as in :mod:`graspgen.grippers` (z approach, x closing; the right pad on +x, the left on -x).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import trimesh

from graspgen.grippers import GripperSpec
from graspgen.validation import check_positive_int, check_transforms

LEFT, RIGHT = 0, 1
"""Finger labels: the left pad sits on -x of the TCP frame and closes along +x; the right pad the reverse."""


@dataclasses.dataclass(frozen=True)
class ClosingContacts:
    """Contacts of one grasp, in the mesh (object) frame."""

    points: np.ndarray
    """(k, 3) float, m: contact points on the mesh surface."""
    normals: np.ndarray
    """(k, 3) float: unit surface normals pointing INTO the object (the direction the pad pushes)."""
    finger: np.ndarray
    """(k,) int8: :data:`LEFT` or :data:`RIGHT`."""
    width: float
    """Pad separation when both pads touch, m; NaN when a pad touches nothing."""

    @property
    def both_fingers(self) -> bool:
        """True when each pad has at least one contact."""
        return bool(np.isin([LEFT, RIGHT], self.finger).all())


def pad_ray_grid(gripper: GripperSpec, rays_per_side: int) -> tuple[np.ndarray, np.ndarray]:
    """Ray origins on both open pad faces and their closing directions, in the TCP frame.

    Returns
    -------
    origins : (2 * r * r, 3) float
        Left pad's grid first (x = -max_width / 2), then the right pad's (x = +max_width / 2), spread over the pad
        face (y over its width, z over its length, centred on the TCP plane).
    directions : (2 * r * r, 3) float
        +x for the left pad, -x for the right pad.
    """
    check_positive_int("rays_per_side", rays_per_side)
    _, pad_w, pad_l = gripper.pad_size
    frac = np.linspace(-0.45, 0.45, rays_per_side) if rays_per_side > 1 else np.zeros(1)
    yy, zz = np.meshgrid(frac * pad_w, frac * pad_l, indexing="ij")
    grid = np.stack([np.zeros(yy.size), yy.ravel(), zz.ravel()], axis=1)
    half = gripper.max_width / 2
    left = grid + (-half, 0.0, 0.0)
    right = grid + (half, 0.0, 0.0)
    n = len(grid)
    directions = np.concatenate([np.tile((1.0, 0.0, 0.0), (n, 1)), np.tile((-1.0, 0.0, 0.0), (n, 1))])
    return np.concatenate([left, right]), directions


def closing_contacts(
    mesh: trimesh.Trimesh,
    T_tcp: np.ndarray,
    gripper: GripperSpec,
    *,
    rays_per_side: int = 3,
    tolerance: float = 5e-4,
) -> list[ClosingContacts]:
    """Close both pads of each grasp onto ``mesh`` and return where they touch.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The object in its own frame, m (watertight, outward normals).
    T_tcp : (4, 4) or (n, 4, 4) float
        TCP poses in the mesh frame.
    gripper : GripperSpec
        Gives the open width and the pad face size.
    rays_per_side : int
        Rays per pad edge: each pad casts ``rays_per_side ** 2`` rays.
    tolerance : float
        m: rays hitting within this of the pad's stopping distance are contacts (a flat face gives several).

    Returns
    -------
    list of ClosingContacts, one per grasp. A ray whose first hit is a back face started inside the object (the
    open pad is already in the object); such rays are ignored.
    """
    T = check_transforms("T_tcp", T_tcp, allow_single=True)
    origins_tcp, dirs_tcp = pad_ray_grid(gripper, rays_per_side)
    m = len(origins_tcp)
    origins = np.einsum("nij,kj->nki", T[:, :3, :3], origins_tcp) + T[:, None, :3, 3]
    dirs = np.einsum("nij,kj->nki", T[:, :3, :3], dirs_tcp)
    hits, ray_idx, tri_idx = mesh.ray.intersects_location(
        origins.reshape(-1, 3), dirs.reshape(-1, 3), multiple_hits=False
    )
    dist = np.full(len(T) * m, np.inf)
    point = np.zeros((len(T) * m, 3))
    normal = np.zeros((len(T) * m, 3))
    flat_dirs = dirs.reshape(-1, 3)
    outward = mesh.face_normals[tri_idx]
    front = np.einsum("ij,ij->i", outward, flat_dirs[ray_idx]) < 0.0
    travel = np.einsum("ij,ij->i", hits - origins.reshape(-1, 3)[ray_idx], flat_dirs[ray_idx])
    ok = front & (travel <= gripper.max_width / 2 + 1e-9) & (travel >= 0.0)
    dist[ray_idx[ok]] = travel[ok]
    point[ray_idx[ok]] = hits[ok]
    normal[ray_idx[ok]] = -outward[ok]
    dist, point, normal = dist.reshape(len(T), m), point.reshape(len(T), m, 3), normal.reshape(len(T), m, 3)
    finger_of_ray = np.repeat(np.array([LEFT, RIGHT], dtype=np.int8), m // 2)
    out = []
    for i in range(len(T)):
        keep = np.zeros(m, dtype=bool)
        stops = []
        for f in (LEFT, RIGHT):
            rays = finger_of_ray == f
            stop = dist[i, rays].min()
            stops.append(stop)
            if np.isfinite(stop):
                keep |= rays & (dist[i] <= stop + tolerance)
        width = gripper.max_width - sum(stops) if all(np.isfinite(stops)) else float("nan")
        out.append(ClosingContacts(point[i, keep], normal[i, keep], finger_of_ray[keep], float(width)))
    return out
