"""Analytic thresholds of the mechanics cases (:mod:`graspgen.workflows.mechanics`), from Coulomb friction and each
protocol's disturbance.

Contact model: each pad presses with the grip force F (N); its friction resists a tangential force f_t and a moment m
about its normal together within the ellipsoidal limit surface ``(f_t / mu)^2 + (m / gamma)^2 <= F^2`` (Howe &
Cutkosky 1996, "Practical force-motion models for sliding manipulation", IJRR 15(6); Goyal, Ruina & Papadopoulos
1991), with ``gamma = mu r_mean`` for uniform pressure over the pad face (r_mean: :func:`torsion_arm`, by quadrature,
independent of the closed form :func:`graspgen.sim.gripper_model.pad_torsion_arm` the model uses).
Two pads share a load evenly. A grasp holds iff at every instant of the protocol the load fits:
``m sqrt((a_t / (2 mu))^2 + (M / (2 gamma m))^2) <= F`` with a_t the tangential acceleration the grip must give the
object (gravity and the hand's acceleration, per unit mass) and M the moment about the closing axis.

Disturbances (per unit mass; g = 9.81 m/s^2, ``gen evaluate``'s gravity):

* ``acronym``: gravity along the approach, then the hand moves ``A sin(2 pi f t) sin^2(pi t / T)`` along it (load
  ``g - a(t)``), then turns ``theta(t)`` (the same wave, amplitude ``shake_angle``) about the closing axis through
  the TCP (load: gravity, ``g`` in the pads' plane; moment ``I_g alpha(t) + m g d cos(theta)``).
* ``table``: the same shake after a lift that accelerates at ``lift_acceleration``; gravity along the approach
  (a top-down grasp).
* ``graspdatagen``: no gravity; the object's weight (``force_scale`` x m g) pulls along the approach and four
  directions tilted from it: the approach tug is the largest load in the pads' plane and about the closing axis.
"""

from __future__ import annotations

import math

import numpy as np

from graspgen.grippers import GripperSpec
from graspgen.sim.protocol_phases import protocol_of
from graspgen.sim.protocols import LiftParams

__all__ = ["G", "grip_force", "torsion_arm", "shake_profiles", "slip_mass", "pivot_offset", "wedge_angle"]

G = 9.81
"""Gravity (m/s^2) of ``gen evaluate``'s worlds."""
_DT = 1e-4


def grip_force(lift: LiftParams, spec: GripperSpec) -> float:
    """Force (N) each pad presses with under ``lift``'s protocol."""
    own = {"acronym": lift.acronym.grip_force, "graspdatagen": lift.graspdatagen.grip_force}.get(lift.protocol,
                                                                                         lift.grip_force)
    return float(spec.force_limit if own is None else own)


def torsion_arm(spec: GripperSpec, n: int = 400) -> float:
    """Mean distance (m) of the pad face (``pad_size`` y x z) from its centroid, the torsional friction arm under
    uniform pressure, by the midpoint rule on an ``n x n`` grid (error ~1e-6 relative)."""
    u = (np.arange(n) + 0.5) / n - 0.5
    y, z = np.meshgrid(u * spec.pad_size[1], u * spec.pad_size[2])
    return float(np.mean(np.hypot(y, z)))


def _wave(amplitude: float, frequency: float, cycles: int) -> tuple[np.ndarray, np.ndarray]:
    """The protocols' shake ``A sin(2 pi f t) sin^2(pi t / T)``, ``T = cycles / f``: (value, second derivative),
    each ``(n,)`` on a 0.1 ms grid."""
    total = cycles / frequency
    t = np.arange(0.0, total + _DT / 2, _DT)
    x = amplitude * np.sin(2.0 * math.pi * frequency * t) * np.sin(math.pi * t / total) ** 2
    return x, np.gradient(np.gradient(x, _DT), _DT)


def shake_profiles(lift: LiftParams) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """The protocol's load phases, each ``(a_t, a_n, theta, alpha)`` arrays ``(n,)``: the tangential acceleration
    (m/s^2) the grip gives the object along the approach, the acceleration along the approach that the moment arm
    d sees (m/s^2: its gravity moment is ``m a_n d cos(theta)``), the hand's rotation about the closing axis (rad)
    and its angular acceleration (rad/s^2)."""
    zero = np.zeros(1)
    spec = protocol_of(lift).load(lift, G)
    g = spec.gravity
    phases = [(np.array([g + spec.lift_acceleration]), np.array([g + spec.lift_acceleration]), zero, zero)]
    if spec.shake is not None:
        amp, ang, freq, cyc = spec.shake
        _, a = _wave(amp, freq, cyc)
        load = g + spec.shake_sign * a
        phases.append((load, load, np.zeros_like(a), np.zeros_like(a)))
        theta, alpha = _wave(ang, freq, cyc)
        phases.append((np.full_like(theta, g), g * np.cos(theta), theta, alpha))
    return phases


def _normal_needed(lift: LiftParams, mu: float, arm: float, mass: float, inertia: float, d: float) -> float:
    """Largest normal force (N) one pad needs over the protocol for an object of ``mass`` (kg), moment of inertia
    ``inertia`` (kg m^2) about the closing axis through its centre of mass, held ``d`` (m) from it."""
    gamma = mu * arm
    i_g = inertia + mass * d * d
    need = 0.0
    for a_t, a_n, theta, alpha in shake_profiles(lift):
        moment = np.abs(i_g * alpha) + mass * np.abs(a_n) * d * np.cos(theta)
        per_pad = np.sqrt((mass * a_t / (2.0 * mu)) ** 2 + (moment / (2.0 * gamma)) ** 2)
        need = max(need, float(per_pad.max()))
    return need


def slip_mass(lift: LiftParams, mu: float, force: float, *, arm: float | None = None,
              inertia_per_kg: float = 0.0) -> float:
    """Largest mass (kg) a box held at its centre keeps: ``2 mu F / max(a_t)`` (the limit surface's moment term
    added when ``arm`` and ``inertia_per_kg`` (m^2) are given)."""
    if arm is None:
        return 2.0 * mu * force / max(float(p[0].max()) for p in shake_profiles(lift))
    return force / _normal_needed(lift, mu, arm, 1.0, inertia_per_kg, 0.0)


def pivot_offset(lift: LiftParams, mu: float, force: float, arm: float, mass: float, size) -> float:
    """Largest offset d (m) from the centre of mass at which a bar of ``mass`` (kg) and full extents ``size`` (x
    closing, y along the offset, z approach; m) keeps still; 0 when it turns even when held at its centre."""
    inertia = mass * (size[1] ** 2 + size[2] ** 2) / 12.0
    if _normal_needed(lift, mu, arm, mass, inertia, 0.0) > force:
        return 0.0
    lo, hi = 0.0, float(size[1]) / 2.0
    if _normal_needed(lift, mu, arm, mass, inertia, hi) <= force:
        return hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _normal_needed(lift, mu, arm, mass, inertia, mid) <= force else (lo, mid)
    return 0.5 * (lo + hi)


def wedge_angle(lift: LiftParams, mu: float, force: float, mass: float) -> float:
    """Largest half-angle (rad) of a wedge widening away from the palm that the pads keep: squeezed with F per pad
    and loaded with ``m a`` towards its wide end, it holds iff ``cos(a) (F - m a tan(al) / 2) (mu cos(al) -
    sin(al)) >= m a / 2`` (force balance of the two inclined faces with friction at its limit), i.e. ``tan(al) <=
    mu`` without load."""
    a = max(float(p[0].max()) for p in shake_profiles(lift))

    def holds(al: float) -> bool:
        normal = math.cos(al) * (force - 0.5 * mass * a * math.tan(al))
        return normal * (mu * math.cos(al) - math.sin(al)) >= 0.5 * mass * a

    lo, hi = 0.0, math.atan(mu)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if holds(mid) else (lo, mid)
    return 0.5 * (lo + hi)
