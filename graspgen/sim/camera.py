"""Pinhole cameras in the OpenCV convention, in numpy only: intrinsics, poses on a sphere, projection,
back-projection and depth noise (no MuJoCo: :mod:`graspgen.sim.render` renders through these cameras).

A :class:`Camera` is intrinsics ``K`` (3, 3) and extrinsics ``T_world_camera`` (4, 4, camera-to-world) in the
**OpenCV camera frame: x right, y down, z forward** (the optical axis). Pixel (u, v) = (column, row) has its
centre at integer coordinates, so the image spans u in [-0.5, width - 0.5]. A point p_c in the camera frame
projects to ``K @ p_c / p_c[2]``. (MuJoCo's own cameras look along -z with y up;
:class:`graspgen.sim.render.SceneRenderer` sets the OpenGL camera directly from ``K`` and ``T_world_camera``, so
no MuJoCo camera element is involved and any fx, fy, cx, cy is rendered exactly.)

Depth images are float32 metres along the optical axis (the camera-frame z, not the ray length), **0 where
nothing was hit**.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from graspgen.errors import SettingsError
from graspgen.validation import check, check_number, check_positive_int, check_transform

__all__ = [
    "Camera",
    "backproject",
    "camera_on_sphere",
    "depth_noise",
    "intrinsics_from_fov",
    "project",
    "transform_points",
]


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
        raise SettingsError(f"depth: must be an (H, W) image, got shape {depth.shape}")
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
    check_number("sigma", sigma, low=0.0)
    check_number("sigma_quadratic", sigma_quadratic, low=0.0)
    check_number("dropout", dropout, low=0.0, high=1.0)
    valid = depth > 0
    std = sigma + sigma_quadratic * depth.astype(np.float64) ** 2
    noisy = depth + (rng.standard_normal(depth.shape) * std).astype(np.float32)
    drop = rng.random(depth.shape) < dropout
    noisy[~valid | drop | (noisy <= 0)] = 0.0
    return noisy.astype(np.float32)
