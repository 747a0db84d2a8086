"""Contact-level noise of a grasp's epsilon (``pfc_contact``, ``epsilon_robust``) and the metrics settings.

Contact noise (``pfc_contact``, ``epsilon_robust``; :func:`perturb_contacts`). Dex-Net style (Mahler et al. 2017):
the grasp's contact set is perturbed ``num_contact_samples`` times and the epsilon recomputed, at no extra
simulation. Each perturbed set moves each pad's contacts (all contacts with one ``finger`` label) together:

* a shift ``t ~ N(0, contact_position_sigma^2 I)`` (m) with its component along the pad's mean normal removed, so
  the patch slides in its tangent plane (along the surface to first order: exact on a flat face; a shift past an
  edge is not projected back onto the mesh, so falling off an edge is not modelled);
* a tilt of its normals by the rotation vector ``w ~ N(0, contact_normal_sigma^2 I)`` (rad) with its component
  along the pad's mean normal removed (a spin about the normal leaves the normal unchanged);
* one friction coefficient per set, ``N(friction, friction_sigma^2)`` truncated to > 0 (inverse-CDF sampling).

These are contact-level errors only: unlike the ``robustness`` stage's ``pfc`` (perturbed rollouts, the contacts
found anew by the physics), a perturbed set never loses or gains contacts. Randomness: the stage draws all noise
for a scene up front from the task's generator, ``(grasps, num_contact_samples, 13)`` values in grasp order (for
every grasp, with contacts or not; :func:`contact_noise_draws`), so a grasp's noise depends only on the task key
and its row; with all sigmas 0 the perturbed sets equal the nominal one and ``epsilon_robust == epsilon``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.special import ndtr, ndtri

from graspgen.quality.epsilon import EpsilonParams, ObjectGeometry
from graspgen.validation import check, check_instance, check_number, check_positive_int

__all__ = [
    "CONTACT_NOISE_DRAWS",
    "MetricsParams",
    "contact_noise_draws",
    "contact_robustness",
    "perturb_contacts",
]


@dataclasses.dataclass(frozen=True)
class MetricsParams:
    """Settings of the ``metrics`` stage (config section ``metrics``)."""

    epsilon: EpsilonParams = dataclasses.field(default_factory=EpsilonParams)
    """The contact model, friction and ray casting of the epsilon (shared with the robustness stage)."""
    closure_frictions: tuple[float, ...] = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
    """Friction coefficients tried for the GraspNet-style label ``min_closure_friction``."""
    num_contact_samples: int = 10
    """Perturbed contact sets per grasp for ``pfc_contact`` and ``epsilon_robust`` (each costs one epsilon)."""
    contact_position_sigma: float = 0.005
    """Standard deviation (m) of each pad's contact shift (per axis, then projected onto the pad's tangent plane).
    5 mm: the translation sigma of Dex-Net's grasp and object pose noise, and the robustness stage's
    ``translation_sigma``."""
    contact_normal_sigma: float = math.radians(5.0)
    """Standard deviation (rad) of each component of each pad's normal tilt (a rotation vector, its component
    along the normal removed). 5 degrees: a physical choice (the scale of a meshed surface's normal error on a
    curved object, and the robustness stage's ``rotation_sigma``), not a Dex-Net value."""
    friction_sigma: float = 0.1
    """Standard deviation of the friction coefficient (truncated to > 0): Dex-Net's ``sigma_mu`` (0.1 about its
    nominal 0.5)."""
    epsilon_delta: float = 0.0
    """``pfc_contact`` counts perturbed sets with epsilon > this (0: the probability of force closure itself)."""

    def __post_init__(self) -> None:
        check_instance("epsilon", self.epsilon, EpsilonParams)
        check("closure_frictions", len(self.closure_frictions) > 0, "list at least one coefficient",
              self.closure_frictions)
        for i, f in enumerate(self.closure_frictions):
            check_number(f"closure_frictions[{i}]", f, low=0.0, low_open=True)
        check_positive_int("num_contact_samples", self.num_contact_samples)
        for name in ("contact_position_sigma", "contact_normal_sigma", "friction_sigma", "epsilon_delta"):
            check_number(name, getattr(self, name), low=0.0)


CONTACT_NOISE_DRAWS = 13
"""Values drawn per perturbed contact set: per pad (finger 0, then 1) a shift (3) and a tilt (3) standard normal,
then one uniform for the friction."""


def contact_noise_draws(rng: np.random.Generator, n: int, k: int) -> np.ndarray:
    """The contact noise of ``n`` grasps, ``k`` sets each: ``(n, k, 13)`` float, drawn in one call order (standard
    normals ``(n, k, 12)``, then uniforms ``(n, k)``) so a grasp's values depend only on the generator and its row."""
    z = rng.standard_normal((n, k, 12))
    u = rng.random((n, k))
    return np.concatenate([z, u[..., None]], axis=2)


def _rotation(w: np.ndarray) -> np.ndarray:
    """The rotation matrix of the rotation vector ``w`` (rad), Rodrigues' formula."""
    theta = math.sqrt(float(w @ w))
    if theta == 0.0:
        return np.eye(3)
    x, y, z = w / theta
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(theta) * K + (1.0 - math.cos(theta)) * (K @ K)


def perturb_contacts(
    points: np.ndarray, normals: np.ndarray, finger: np.ndarray, friction: float, draws: np.ndarray, *,
    position_sigma: float, normal_sigma: float, friction_sigma: float,
) -> tuple[np.ndarray, np.ndarray, float]:
    """One perturbed copy of a contact set (module docstring, Contact noise).

    Parameters
    ----------
    points : (k, 3) float, m; normals : (k, 3) float, unit, into the object; finger : (k,) int, 0 or 1
    friction : float, the nominal Coulomb coefficient
    draws : (13,) float, one row of :func:`contact_noise_draws`
    position_sigma : m; normal_sigma : rad; friction_sigma : unit-free

    Returns
    -------
    (points (k, 3), normals (k, 3), friction); a sigma of 0 leaves its part exactly as it was.
    """
    points = np.array(points, dtype=np.float64).reshape(-1, 3)
    normals = np.array(normals, dtype=np.float64).reshape(-1, 3)
    finger = np.asarray(finger).reshape(-1)
    if position_sigma > 0.0 or normal_sigma > 0.0:
        for f in (0, 1):
            sel = finger == f
            if not sel.any():
                continue
            axis = normals[sel].sum(axis=0)
            norm = math.sqrt(float(axis @ axis))
            axis = axis / norm if norm > 1e-9 else np.zeros(3)
            z = draws[6 * f : 6 * f + 6]
            if position_sigma > 0.0:
                t = position_sigma * z[:3]
                points[sel] += t - (t @ axis) * axis
            if normal_sigma > 0.0:
                w = normal_sigma * z[3:]
                normals[sel] = normals[sel] @ _rotation(w - (w @ axis) * axis).T
    mu = float(friction)
    if friction_sigma > 0.0:
        low = float(ndtr(-mu / friction_sigma))  # P(N(mu, sigma^2) <= 0): the mass cut off
        mu = max(mu + friction_sigma * float(ndtri(low + float(draws[12]) * (1.0 - low))), 1e-9)
    return points, normals, mu


def contact_robustness(
    points: np.ndarray, normals: np.ndarray, finger: np.ndarray, geometry: ObjectGeometry, friction: float,
    draws: np.ndarray, params: MetricsParams,
) -> tuple[float, float]:
    """``(pfc_contact, epsilon_robust)`` of a contact set (mesh frame) over the perturbed sets ``draws``
    (``(K, 13)``, rows of :func:`contact_noise_draws`): the fraction with epsilon > ``params.epsilon_delta`` and
    the mean epsilon."""
    eps = np.empty(len(draws))
    for j, row in enumerate(draws):
        p, n, mu = perturb_contacts(points, normals, finger, friction, row,
                                    position_sigma=params.contact_position_sigma,
                                    normal_sigma=params.contact_normal_sigma, friction_sigma=params.friction_sigma)
        eps[j] = params.epsilon.epsilon(p, n, finger, geometry, mu)
    # the mean as an offset from the first value: exactly that value when all are equal (zero noise)
    return float(np.mean(eps > params.epsilon_delta)), float(eps[0] + (eps - eps[0]).mean())
