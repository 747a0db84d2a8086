"""The motion profiles of the grasp-and-lift protocols (:mod:`graspgen.sim.protocols`) and their step counts.

A profile is sampled at the end of each simulation step, so a rollout writes one row per step into the mocap
target: :func:`trapezoid` (the approach and the lift: rest to rest), :func:`shake_wave` (ACRONYM's shake: a sine
under a Hann window, starting and ending at rest) and :func:`shake_quats` (the rotational shake as quaternions).
:func:`rollout_schedule` turns a :class:`graspgen.sim.protocols.LiftParams` into every profile and step count one
:class:`graspgen.sim.lift.LiftSimulator` uses (and the MuJoCo Warp backend replays).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from graspgen.sim.protocol_phases import protocol_of
from graspgen.sim.protocols import LiftParams

__all__ = ["Schedule", "rollout_schedule", "shake_quats", "shake_wave", "trapezoid"]


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
    """The profiles and step counts of one protocol at one timestep (:func:`rollout_schedule`)."""

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


def rollout_schedule(params: LiftParams, dt: float, min_width: float, max_width: float,
                     closing_speed: float) -> Schedule:
    """Every profile and step count of ``params``' protocol.

    Parameters
    ----------
    params : LiftParams
        The protocol and its settings.
    dt : float
        Timestep, s.
    min_width, max_width : float
        The gripper's pad separation range, m.
    closing_speed : float
        Width rate (m/s) of the closing jaws (after the protocol's grip settings).

    Returns
    -------
    Schedule
    """
    approach = trapezoid(params.approach_distance, params.approach_speed, params.approach_acceleration, dt)
    lift_s = trapezoid(params.lift_height, params.lift_speed, params.lift_acceleration, dt)
    lift_offsets = np.zeros((len(lift_s), 3))
    lift_offsets[:, 2] = lift_s
    hold_steps = int(round(params.hold_time / dt))
    close_max_steps = max(1, math.ceil(params.close_timeout / dt - 1e-9))
    shake_z = shake_qx = open_width = tug_dirs = None
    settle_steps = tug_steps = 0
    if params.shake:
        shake_z = shake_wave(params.shake_amplitude, params.shake_frequency, params.shake_cycles, dt)
        shake_qx = shake_quats(params.shake_angle, params.shake_frequency, params.shake_cycles, dt)
    free = protocol_of(params).settings(params)
    if free is not None:  # a free-space protocol: its own opening
        open_width = float(np.clip(max_width if free.open_width is None else free.open_width, min_width, max_width))
        # From fully open to fully closed takes (open - min) / closing_speed: never stop closing before that.
        full_close = 1.25 * (open_width - min_width) / closing_speed
        close_max_steps = max(close_max_steps, math.ceil(full_close / dt - 1e-9))
    if params.protocol == "graspdatagen":
        tug_steps = max(1, int(round(params.graspdatagen.tug_time / dt)))
        tug_dirs = params.graspdatagen.directions()
    if params.protocol == "acronym":
        acr = params.acronym
        shake_z = shake_wave(acr.shake_amplitude, acr.shake_frequency, acr.shake_cycles, dt)
        shake_qx = shake_quats(acr.shake_angle, acr.shake_frequency, acr.shake_cycles, dt)
        settle_steps = int(round(acr.settle_time / dt))
    return Schedule(dt=dt, approach=approach, lift_offsets=lift_offsets, hold_steps=hold_steps,
                    close_max_steps=close_max_steps, shake_z=shake_z, shake_qx=shake_qx, open_width=open_width,
                    settle_steps=settle_steps, tug_steps=tug_steps, tug_dirs=tug_dirs)
