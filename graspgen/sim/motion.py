"""The motion profiles of the grasp-and-lift protocols (:mod:`graspgen.sim.protocols`) and their step counts.

A profile is sampled at the end of each simulation step, so a rollout writes one row per step into the mocap
target: :func:`trapezoid` (the approach and the lift: rest to rest), :func:`shake_wave` (ACRONYM's shake: a sine
under a Hann window, starting and ending at rest) and :func:`shake_quats` (the rotational shake as quaternions).
:func:`base_schedule` turns a :class:`graspgen.sim.protocols.LiftParams` into the profiles and step counts every
protocol shares; each protocol's ``schedule`` (:mod:`graspgen.sim.protocol_phases`) adds its own, into the
:class:`Schedule` one :class:`graspgen.sim.lift.LiftSimulator` uses, and its ``segments`` cut it into the
:class:`Segment` s the MuJoCo Warp backend replays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from graspgen.sim.protocols import LiftParams

__all__ = ["Schedule", "Segment", "base_schedule", "shake_quats", "shake_wave", "trapezoid"]


def trapezoid(distance: float, speed: float, accel: float, dt: float) -> np.ndarray:
    """Distance travelled at the end of each step of a rest-to-rest trapezoidal speed profile.

    A triangle when the distance is too short to reach ``speed``.

    Parameters
    ----------
    distance : float
        Path length, m.
    speed : float
        Peak speed, m/s.
    accel : float
        Acceleration and deceleration, m/s^2.
    dt : float
        Step, s.

    Returns
    -------
    (n,) float64
        Distance (m) after each step; the last entry is exactly ``distance``; empty for ``distance <= 0``.
    """
    if distance <= 0.0:
        return np.zeros(0)
    t_acc = speed / accel
    if accel * t_acc * t_acc > distance:  # never reaches the peak speed: triangle
        t_acc = math.sqrt(distance / accel)
        speed = accel * t_acc
    t_cruise = (distance - accel * t_acc * t_acc) / speed
    total = 2.0 * t_acc + t_cruise
    n = max(1, math.ceil(total / dt - 1e-9))
    t = np.minimum(dt * np.arange(1, n + 1), total)
    d_acc = 0.5 * accel * t_acc * t_acc
    t_dec = np.maximum(t - t_acc - t_cruise, 0.0)
    s = np.where(t < t_acc, 0.5 * accel * t * t,
                 np.where(t < t_acc + t_cruise, d_acc + speed * (t - t_acc),
                          d_acc + speed * t_cruise + speed * t_dec - 0.5 * accel * t_dec * t_dec))
    s[-1] = distance
    return s


def shake_wave(amplitude: float, frequency: float, cycles: int, dt: float) -> np.ndarray:
    """``amplitude * sin(2 pi f t) * sin^2(pi t / T)`` at the end of each step over ``T = cycles / f``: a sine under
    a Hann window, so position and velocity start and end at zero (no velocity jump).

    Parameters
    ----------
    amplitude : float
        Peak value (m for a displacement, rad for an angle).
    frequency : float
        Hz.
    cycles : int
        Oscillations.
    dt : float
        Step, s.

    Returns
    -------
    (n,) float64
        ``n = ceil(T / dt)`` samples (at least one).
    """
    total = cycles / frequency
    n = max(1, math.ceil(total / dt - 1e-9))
    t = np.minimum(dt * np.arange(1, n + 1), total)
    return amplitude * np.sin(2.0 * math.pi * frequency * t) * np.sin(math.pi * t / total) ** 2


def shake_quats(angle: float, frequency: float, cycles: int, dt: float) -> np.ndarray:
    """The rotational shake about the TCP x axis as quaternions (w, x, y, z), ``(n, 4)``: the rotation by
    :func:`shake_wave` ``(angle, frequency, cycles, dt)`` rad at each step (multiply the grasp's quaternion by it
    on the right: a turn about the hand's own x axis)."""
    half = 0.5 * shake_wave(angle, frequency, cycles, dt)
    return np.stack([np.cos(half), np.sin(half), np.zeros_like(half), np.zeros_like(half)], 1)


@dataclass(frozen=True, eq=False)
class Schedule:
    """The profiles and step counts of one protocol at one timestep (:func:`base_schedule` and the
    protocol's ``schedule``)."""

    dt: float
    """Timestep (s)."""
    approach: np.ndarray
    """``(n,)`` distance (m) along the approach after each approach step (``table``)."""
    lift_offsets: np.ndarray
    """``(n, 3)`` TCP offset (m, world, only z non-zero) after each lift step (``table``)."""
    hold_steps: int
    """Steps of the hold at the top (``table``)."""
    close_max_steps: int
    """Most steps closing may take (the timeout; the free-space protocols: at least 1.25x a full close)."""
    shake_z: np.ndarray | None
    """``(n,)`` linear shake (m) per step; None when the protocol does not shake."""
    shake_qx: np.ndarray | None
    """``(n, 4)`` rotational shake per step (:func:`shake_quats`); None likewise."""
    open_width: float | None
    """Pad separation (m) the free-space protocols open to at placement; None for ``table`` (from the grasp)."""
    settle_steps: int = 0
    """Steps of the hold after the shake (``acronym``)."""
    tug_steps: int = 0
    """Steps of each tug (``graspdatagen``)."""
    tug_dirs: np.ndarray | None = None
    """``(5, 3)`` unit tug directions in the TCP frame (``graspdatagen``; :meth:`GraspDataGenParams.directions`)."""


def base_schedule(params: LiftParams, dt: float) -> Schedule:
    """The profiles and step counts every protocol's schedule starts from: the approach, the lift, the hold and the
    closing timeout of ``params`` at timestep ``dt`` (s), no shake, no opening of its own. A protocol's
    ``schedule`` (:meth:`graspgen.sim.protocol_phases.RolloutProtocol.schedule`) adds its own parts."""
    approach = trapezoid(params.approach_distance, params.approach_speed, params.approach_acceleration, dt)
    lift_s = trapezoid(params.lift_height, params.lift_speed, params.lift_acceleration, dt)
    lift_offsets = np.zeros((len(lift_s), 3))
    lift_offsets[:, 2] = lift_s
    hold_steps = int(round(params.hold_time / dt))
    close_max_steps = max(1, math.ceil(params.close_timeout / dt - 1e-9))
    return Schedule(dt=dt, approach=approach, lift_offsets=lift_offsets, hold_steps=hold_steps,
                    close_max_steps=close_max_steps, shake_z=None, shake_qx=None, open_width=None)


class Segment:
    """One stretch of a protocol (a CPU ``_move`` or ``_wait`` call) as the MuJoCo Warp backend replays it
    (:class:`graspgen.sim.warp_batch.BatchRun`): ``n`` steps under phase name ``phase``; ``kind`` is ``pos`` (mocap
    at the grasp plus ``table[k]`` m along the approach axis), ``zpos`` (mocap at the grasp plus ``table[k]`` m along
    world z), ``quat`` (mocap at the grasp plus ``lift`` m along world z, turned by the quaternion ``table[k]``),
    ``wait`` (targets unchanged) or ``tug`` (a wait with the object pulled by its weight along the TCP-frame
    direction ``table (3,)``). ``mark``: the object's world pose is taken when the segment starts (the reference of
    ``motion_shaking_*``)."""

    def __init__(self, phase: str, n: int, kind: str, table: np.ndarray | None = None, *, lift: float = 0.0,
                 mark: bool = False) -> None:
        self.phase, self.n, self.kind, self.table = phase, int(n), kind, table
        self.lift, self.mark = float(lift), bool(mark)
