"""How deep the gripper's pads sink into a squeezed object, and the contact time constant that bounds it.

MuJoCo's contacts are soft, and their softness is normalised by mass: a contact pressed by a steady force ``f``
comes to rest at a depth ``r`` where

    r = f * A * (1 - d) / d**2 * dmax**2 * (timeconst * dampratio)**2

(MuJoCo's reference acceleration ``-k r`` with ``k = d / (dmax * timeconst * dampratio)**2`` balancing its
regulariser ``R = (1 - d) / d * A``; ``A`` is the contact's inverse effective mass as MuJoCo approximates it, the two
bodies' ``body_invweight0``; ``d`` the impedance ``solimp`` gives at depth ``r``). A gram-light part squeezed at a
parallel gripper's tens of newtons makes ``A * f`` thousands of times a heavy object's, so at the gripper's time
constant the pads sink through it: the pads meet inside a thin plate or squeeze a knife out of the hand.

:func:`bounded_contact` shortens the gripper's time constant for such an object until the sink stays within the
gripper's impedance width (``solimp[2]``, the depth over which the pad stiffens to ``dmax``: its compliance), and
divides the timestep so MuJoCo keeps two steps per time constant, the shortest it accepts. Heavier objects keep the
model as it is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

__all__ = ["BoundedContact", "bounded_contact", "impedance", "steady_sink", "time_constant_for_sink"]


def impedance(depth: float, solimp) -> float:
    """MuJoCo's constraint impedance ``d`` at penetration ``depth`` (m) for ``solimp`` (dmin, dmax, width m,
    midpoint, power)."""
    dmin, dmax, width, mid, power = (float(v) for v in solimp)
    x = depth / width if width > 0 else 1.0
    if x >= 1.0:
        return dmax
    if x <= 0.0:
        return dmin
    if x <= mid:
        y = x ** power / mid ** (power - 1.0)
    else:
        y = 1.0 - (1.0 - x) ** power / (1.0 - mid) ** (power - 1.0)
    return dmin + y * (dmax - dmin)


def _sink_factor(d: float, dmax: float) -> float:
    return (1.0 - d) / (d * d) * dmax * dmax


def steady_sink(force: float, inv_mass: float, solref, solimp) -> float:
    """Depth (m) at which one contact pressed by a steady normal ``force`` (N) comes to rest, for a contact of
    inverse effective mass ``inv_mass`` (1/kg) with MuJoCo softness ``solref`` (time constant s, damping ratio) and
    ``solimp`` (module docstring; the impedance depends on the depth, so the depth is found by bisection)."""
    timeconst, dampratio = (float(v) for v in solref)
    dmax = float(solimp[1])
    load = force * inv_mass * (timeconst * dampratio) ** 2

    def excess(r: float) -> float:
        return r - load * _sink_factor(impedance(r, solimp), dmax)

    hi = max(float(solimp[2]), 1e-9)
    while excess(hi) < 0.0:  # the right side only falls with depth, so one root
        hi *= 2.0
    lo = 0.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if excess(mid) < 0.0 else (lo, mid)
    return 0.5 * (lo + hi)


def time_constant_for_sink(depth: float, force: float, inv_mass: float, dampratio: float, solimp) -> float:
    """The contact time constant (s) at which ``force`` (N) on a contact of inverse effective mass ``inv_mass``
    (1/kg) comes to rest at ``depth`` (m) (:func:`steady_sink` solved for the time constant)."""
    d = impedance(depth, solimp)
    return math.sqrt(depth / (force * inv_mass * _sink_factor(d, float(solimp[1])))) / dampratio


@dataclass(frozen=True)
class BoundedContact:
    """The gripper contact :func:`bounded_contact` chose for one scene."""

    timeconst: float
    """Time constant (s) of the gripper geoms' contacts (their ``solref[0]``)."""
    substeps: int
    """The model's timestep is the base timestep divided by this (1: unchanged); the rules keep their checks at
    the same simulated times (every ``check_interval * substeps`` steps)."""
    sink: float
    """Depth (m) one pad would sink into the lightest object under the grip force, pressing at one point, with
    this contact."""


def _inverse_mass(m: mujoco.MjModel, gripper_geoms: np.ndarray, objects: np.ndarray) -> float:
    """The largest inverse effective mass (1/kg) of a gripper-object contact, as MuJoCo's ``diagApprox`` takes it
    for a contact's normal: the translational ``body_invweight0`` of the two bodies' weld roots."""
    weld = m.body_weldid
    grip = max(float(m.body_invweight0[weld[b], 0]) for b in np.unique(m.geom_bodyid[gripper_geoms]))
    return grip + max(float(m.body_invweight0[weld[b], 0]) for b in objects)


def bounded_contact(m: mujoco.MjModel, gripper_geoms: np.ndarray, objects: np.ndarray,
                    grip_force: float) -> BoundedContact:
    """Shorten the gripper's contact time constant in ``m`` (and its timestep) so a pad pressing ``grip_force``
    (N) at one point into the lightest of ``objects`` (body ids) sinks no deeper than the gripper's impedance width
    (module docstring). ``gripper_geoms``: ``(k,) int`` the gripper's geom ids. Writes ``m`` only when the object is
    light enough to need it; a model with direct (negative) solref or no object is left as it is.

    Returns
    -------
    BoundedContact
        The time constant and timestep division now in ``m``.
    """
    solref = m.geom_solref[gripper_geoms]
    solimp = m.geom_solimp[gripper_geoms[0]]
    timeconst, dampratio = float(solref[:, 0].min()), float(solref[0, 1])
    if len(objects) == 0 or timeconst <= 0.0 or dampratio <= 0.0 or grip_force <= 0.0:
        return BoundedContact(timeconst, 1, math.nan)
    inv_mass = _inverse_mass(m, gripper_geoms, objects)
    needed = time_constant_for_sink(float(solimp[2]), grip_force, inv_mass, dampratio, solimp)
    if needed >= timeconst:
        return BoundedContact(timeconst, 1, steady_sink(grip_force, inv_mass, (timeconst, dampratio), solimp))
    dt = float(m.opt.timestep)
    substeps = max(1, math.ceil(2.0 * dt / needed - 1e-9))  # MuJoCo takes a time constant >= 2 timesteps
    m.opt.timestep = dt / substeps
    m.geom_solref[gripper_geoms, 0] = needed
    return BoundedContact(needed, substeps, steady_sink(grip_force, inv_mass, (needed, dampratio), solimp))
