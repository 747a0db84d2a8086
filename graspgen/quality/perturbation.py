"""The perturbation model of the robustness labels: what a perturbed copy of a grasp changes, and how; pure numpy.

- TCP pose ``T`` (world) -> ``T @ [R(w) | t]`` (:func:`perturbed_poses`), ``t ~ N(0, translation_sigma^2 I)`` m and
  ``w ~ N(0, rotation_sigma^2 I)`` rad in the TCP frame; the width stays nominal.
- With ``object_noise``, a planar object error at placement (:func:`planar_object_noise`): world x, y and yaw about
  the centre of mass, so it rests in the same stable pose.
- The target's mass scaled by ``exp(mass_sigma z)``, its centre of mass moved by ``N(0, com_sigma^2 I)`` m and held
  over its support (:func:`graspgen.quality.resting.resting_com_offset`), its friction from ``N(mu,
  friction_sigma^2)`` truncated to ``> 0`` (:func:`truncated_friction`).

Every copy takes :data:`DRAWS_PER_COPY` standard normals in a fixed order, each drawn whether used or not. The
rollouts of the copies are in :mod:`graspgen.workflows.robustness`.
"""

from __future__ import annotations

import dataclasses
import math
from statistics import NormalDist

import numpy as np

from graspgen.errors import SettingsError
from graspgen.validation import check_bool, check_int, check_number, check_positive_int, check_transform

__all__ = [
    "DRAWS_PER_COPY",
    "RobustnessParams",
    "perturbed_poses",
    "planar_object_noise",
    "rotvec_to_matrix",
    "truncated_friction",
]

DRAWS_PER_COPY = 14
"""Standard normals drawn per perturbed copy, in this order: TCP translation (3), TCP rotation vector (3), object
x, y, yaw (3), mass scale (1), centre-of-mass offset (3), friction (1). All are drawn whatever the settings."""


@dataclasses.dataclass(frozen=True)
class RobustnessParams:
    """Settings of the ``robustness`` stage (config section ``robustness``); the protocol is the rollouts'
    (``physics``, ``rollouts.protocol``) and the copies' epsilon follows ``metrics.epsilon``, both in this stage's
    key."""

    num_perturbations: int = 20
    """Perturbed copies rolled out per successful grasp."""
    translation_sigma: float = 0.005
    """Standard deviation (m) of the TCP translation error along each TCP axis; compare with the jaws' clearance,
    ``physics.table.width_margin / 2`` per side: larger errors put a finger on the target (code 1)."""
    rotation_sigma: float = math.radians(5.0)
    """Standard deviation (rad) of each component of the TCP rotation error (a rotation vector in the TCP frame)."""
    object_noise: bool = False
    """Also move the target at placement (planar: world x, y, yaw). Off by default: to the hand it repeats the TCP error
    and mostly pushes the object into neighbours; turn it on to model a perception error among clutter."""
    object_translation_sigma: float = 0.005
    """Standard deviation (m) of the object's x and y error (with ``object_noise``)."""
    object_rotation_sigma: float = math.radians(5.0)
    """Standard deviation (rad) of the object's yaw error (with ``object_noise``)."""
    mass_sigma: float = 0.2
    """Standard deviation of the log of the target's mass scale (dimensionless; 0.2 is about +-20% at one sigma, median
    1): the record's mass assumes a density, which spreads by tens of percent within a kind of object. 0 turns it
    off."""
    com_sigma: float = 0.005
    """Standard deviation (m, >= 0) of the target's centre-of-mass offset along each mesh axis (Dex-Net's
    ``sigma_obj_com``); 0 turns it off. The horizontal part is held inside the support polygon so the object stays at
    rest (docs/decisions/2026-11-29-perturbation-com-projection.md)."""
    friction_sigma: float = 0.1
    """Standard deviation of the target's sliding friction coefficient (dimensionless, absolute), truncated to ``> 0``;
    0.1 is Dex-Net's friction uncertainty."""
    epsilon_delta: float = 0.0
    """``pfc`` counts copies with epsilon > this (0: the probability of force closure itself)."""
    radius: bool = False
    """Also bisect the robustness radius along each TCP axis (12 bisections per grasp: costly)."""
    radius_max_translation: float = 0.02
    """Largest translation (m) the radius search tries."""
    radius_max_rotation: float = 0.5
    """Largest rotation (rad) the radius search tries."""
    radius_iterations: int = 5
    """Halvings per bisection (resolution: the maximum / 2^iterations)."""

    def __post_init__(self) -> None:
        check_positive_int("num_perturbations", self.num_perturbations)
        for name in ("translation_sigma", "rotation_sigma", "object_translation_sigma", "object_rotation_sigma",
                     "com_sigma", "friction_sigma", "epsilon_delta"):
            check_number(name, getattr(self, name), low=0.0)
        # a log scale: exp(2) = 7.4 at one sigma is already no longer the same object
        check_number("mass_sigma", self.mass_sigma, low=0.0, high=2.0)
        check_bool("object_noise", self.object_noise)
        check_bool("radius", self.radius)
        check_number("radius_max_translation", self.radius_max_translation, low=0.0, low_open=True)
        check_number("radius_max_rotation", self.radius_max_rotation, low=0.0, low_open=True, high=math.pi)
        check_int("radius_iterations", self.radius_iterations, low=1, high=30)


def rotvec_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrices of rotation vectors (axis times angle, rad): ``(n, 3) -> (n, 3, 3)`` (Rodrigues)."""
    v = np.asarray(rotvec, dtype=np.float64).reshape(-1, 3)
    theta2 = np.einsum("ij,ij->i", v, v)
    theta = np.sqrt(theta2)
    small = theta < 1e-6
    safe = np.where(small, 1.0, theta)
    # sin(t)/t and (1 - cos t)/t^2, with their Taylor series near 0 (where the closed forms lose precision).
    a = np.where(small, 1.0 - theta2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    K = np.zeros((len(v), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return np.eye(3) + a[:, None, None] * K + b[:, None, None] * (K @ K)


def perturbed_poses(T: np.ndarray, translation: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """``T @ [R(rotation_i) | translation_i]`` (n, 4, 4): the pose ``T`` (4, 4) perturbed in its own frame by
    ``translation`` (n, 3) m and rotation vectors ``rotation`` (n, 3) rad about its origin."""
    T = check_transform("T", T)
    t = np.asarray(translation, dtype=np.float64).reshape(-1, 3)
    w = np.asarray(rotation, dtype=np.float64).reshape(-1, 3)
    if len(t) != len(w):
        raise SettingsError(f"rotation: expected {len(t)} rows (as translation), got {len(w)}")
    D = np.zeros((len(t), 4, 4))
    D[:, :3, :3] = rotvec_to_matrix(w)
    D[:, :3, 3] = t
    D[:, 3, 3] = 1.0
    return T @ D


def planar_object_noise(T_world_object: np.ndarray, center_of_mass: np.ndarray, dx: float, dy: float,
                        yaw: float) -> np.ndarray:
    """The object pose ``T_world_object (4, 4)`` turned by ``yaw`` (rad) about the vertical line through its centre
    of mass (``center_of_mass (3,)``, mesh frame, m) and shifted by ``(dx, dy)`` m in the world x/y plane."""
    T = np.asarray(T_world_object, dtype=np.float64)
    c, s = math.cos(yaw), math.sin(yaw)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    com_world = T[:3, :3] @ center_of_mass + T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = Rz @ T[:3, :3]
    out[:3, 3] = Rz @ (T[:3, 3] - com_world) + com_world + (dx, dy, 0.0)
    return out


_NORMAL = NormalDist()


def truncated_friction(mu: float, sigma: float, z: float) -> float:
    """A friction coefficient from ``N(mu, sigma^2)`` truncated to ``> 0``, by inverse CDF of one standard normal ``z``
    (one draw per copy whatever the truncation); ``sigma = 0`` gives ``mu``."""
    if sigma == 0.0:
        return float(mu)
    a = _NORMAL.cdf(-mu / sigma)
    u = a + _NORMAL.cdf(float(z)) * (1.0 - a)
    u = min(max(u, 1e-15), 1.0 - 1e-15)
    # Round-off can leave the value at or just below 0 when the draw sits at the truncation point.
    return max(mu + sigma * _NORMAL.inv_cdf(u), 1e-6 * mu)
