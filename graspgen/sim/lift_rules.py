"""The rules and readings of one rollout's state, shared by :class:`graspgen.sim.lift.LiftSimulator` and the MuJoCo
Warp backend (:mod:`graspgen.sim.warp_backend`, whose batched versions are :mod:`graspgen.sim.warp_rules`).

Geom roles and hand sides are small integer codes (:data:`SUPPORT` ... :data:`GRIPPER` index the outcome code of a
gripper touching such a geom at placement; :data:`LEFT` ... :data:`NOT_GRIPPER` the side of the hand).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from graspgen.errors import SettingsError
from graspgen.geometry.poses import rotation_angle
from graspgen.sim.protocols import OUTCOME_NAMES, LiftParams, Outcome, RolloutResult
from graspgen.validation import check_number

__all__ = [
    "CLUTTER", "GRIPPER", "LEFT", "NOT_GRIPPER", "PALM", "RIGHT", "SUPPORT", "TARGET",
    "Drift", "batch_arguments", "both_jaws", "closing_tolerance", "jaw_contacts", "jaws_on", "live_code", "no_contacts",
    "rollout_result",
]

#: Geom roles (index = outcome code for a gripper contact with such a geom during placement/approach).
SUPPORT, TARGET, CLUTTER, GRIPPER = 0, 1, 2, 3
#: Gripper geom sides.
LEFT, RIGHT, PALM, NOT_GRIPPER = 0, 1, 2, -1


class Drift:
    """The target's largest displacement (m) and rotation (rad) in the TCP frame since a reference pose
    ``p0 (3,)``, ``R0 (3, 3)``, over the poses given to :meth:`update` (read-only bookkeeping: it never touches the
    simulation)."""

    def __init__(self, p0: np.ndarray, R0: np.ndarray) -> None:
        self.p0, self.R0 = p0.copy(), R0.copy()
        self.translation = 0.0
        self.rotation = 0.0

    def update(self, p: np.ndarray, R: np.ndarray) -> None:
        """Take the pose ``p (3,)``, ``R (3, 3)`` into the maxima."""
        dp = p - self.p0
        self.translation = max(self.translation, math.sqrt(float(dp @ dp)))
        self.rotation = max(self.rotation, rotation_angle(self.R0, R))


def no_contacts() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The empty record of :func:`jaw_contacts` (a rollout that did not reach the end of closing)."""
    return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int8)


def jaw_contacts(m: mujoco.MjModel, d: mujoco.MjData, geom_side: np.ndarray, roles: np.ndarray, f6: np.ndarray):
    """Jaw-target contacts in ``d`` now.

    Parameters
    ----------
    m, d
        The simulator's model and data.
    geom_side : (ngeom,) int8
        Side of the hand of each geom (:attr:`graspgen.sim.lift_model.LiftIndex.geom_side`).
    roles : (ngeom,) int8
        Geom roles for the target.
    f6 : (6,) float64
        Scratch buffer for ``mj_contactForce``.

    Returns
    -------
    points : (k, 3) float64
        World contact positions, m.
    normals : (k, 3) float64
        Unit normals into the target.
    forces : (k,) float64
        Normal forces, N.
    jaws : (k,) int8
        0 left, 1 right.
    """
    points, normals, forces, jaws = [], [], [], []
    if d.ncon:
        con = d.contact
        geom, pos, frame = con.geom, con.pos, con.frame  # each attribute access copies all contacts: once
        side = geom_side[geom]
        for i in range(d.ncon):
            g1, g2 = int(geom[i, 0]), int(geom[i, 1])
            if side[i, 0] in (LEFT, RIGHT) and roles[g2] == TARGET:
                jaw, sign = int(side[i, 0]), 1.0  # frame[0:3] points from geom1 (jaw) to geom2 (target)
            elif side[i, 1] in (LEFT, RIGHT) and roles[g1] == TARGET:
                jaw, sign = int(side[i, 1]), -1.0
            else:
                continue
            mujoco.mj_contactForce(m, d, i, f6)
            points.append(pos[i])
            normals.append(sign * frame[i, :3])
            forces.append(float(f6[0]))
            jaws.append(jaw)
    k = len(forces)
    return (np.array(points, dtype=float).reshape(k, 3), np.array(normals, dtype=float).reshape(k, 3),
            np.array(forces, dtype=float).reshape(k), np.array(jaws, dtype=np.int8).reshape(k))


def both_jaws(contacts) -> bool:
    """The closing rule: both jaws touch the target (``contacts`` from :func:`jaw_contacts`)."""
    return bool(np.any(contacts[3] == LEFT) and np.any(contacts[3] == RIGHT))


def jaws_on(d: mujoco.MjData, geom_side: np.ndarray, roles: np.ndarray) -> tuple[bool, bool]:
    """(left jaw touches the target, right jaw touches the target) in ``d`` now; no contact forces (cheap)."""
    if d.ncon == 0:
        return False, False
    geom = d.contact.geom
    side = geom_side[geom]
    on_target = roles[geom] == TARGET
    hits = np.concatenate([side[:, 0][on_target[:, 1]], side[:, 1][on_target[:, 0]]])
    return bool(np.any(hits == LEFT)), bool(np.any(hits == RIGHT))


def live_code(d: mujoco.MjData, geom_is_gripper: np.ndarray, roles: np.ndarray, code: int | None) -> int | None:
    """``code`` lowered to the lowest role (0 support, 2 clutter) of the gripper's live contacts in ``d`` with
    anything but the target (a pushed target yields: its live contacts do not count); ``code`` when none."""
    if d.ncon == 0:
        return code
    geom = d.contact.geom
    grip = geom_is_gripper[geom]
    mask = grip[:, 0] != grip[:, 1]
    if not mask.any():
        return code
    codes = roles[np.where(grip[:, 0], geom[:, 1], geom[:, 0])[mask]]
    codes = codes[codes != TARGET]
    if len(codes) and (code is None or codes.min() < code):
        code = int(codes.min())
    return code


def closing_tolerance(params: LiftParams, interval: float) -> float:
    """Width change (m) per check interval below which the closing jaws count as stopped (``close_speed_tol``
    averaged over a check interval of ``interval`` s)."""
    return check_number("close_speed_tol", params.close_speed_tol, low=0.0) * interval


def rollout_result(params: LiftParams, code, phase: str, steps: int, dt: float, closed_width: float,
                   lift_gain: float, relative, contacts, motion_closing, motion_shaking, pose_closed,
                   drift) -> RolloutResult:
    """The :class:`RolloutResult` every protocol and backend returns.

    ``relative`` and ``drift`` are (translation m, rotation rad) of the target in the hand since closing ended,
    ``drift`` the largest over the disturbance; ``contacts`` is :func:`jaw_contacts`' record; ``motion_*`` are
    (m, rad) in the world frame; the firm label is derived here from ``params``' tolerances.
    """
    firm = bool(code == Outcome.SUCCESS and drift[0] <= params.firm_translation and drift[1] <= params.firm_rotation)
    return RolloutResult(
        code=int(code), name=OUTCOME_NAMES[code], decided_in=phase, steps=steps,
        sim_time=steps * dt, closed_width=closed_width, lift_gain=lift_gain,
        rel_translation=relative[0], rel_rotation=relative[1], contact_points=contacts[0],
        contact_normals=contacts[1], contact_forces=contacts[2], contact_fingers=contacts[3],
        motion_closing_linear=motion_closing[0], motion_closing_angular=motion_closing[1],
        motion_shaking_linear=motion_shaking[0], motion_shaking_angular=motion_shaking[1],
        target_pose_closed=pose_closed, max_rel_translation=drift[0], max_rel_rotation=drift[1], firm=firm)


def batch_arguments(T_world_tcp, widths, target_body, *, widths_needed_by: str | None):
    """The arguments of a batch of rollouts, checked: ``(T (n, 4, 4) float, widths, bodies (n,) list of str)``.

    ``widths``: ``(n,)`` finite pad separations >= 0 (m) when ``widths_needed_by`` names what needs them (None
    raises, naming it); passed through unchecked otherwise. ``target_body``: one body name or ``n`` of them.
    Raises SettingsError naming the argument."""
    T = np.asarray(T_world_tcp, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise SettingsError(f"T_world_tcp: expected (n, 4, 4) poses, got shape {T.shape}")
    if widths_needed_by is not None:
        if widths is None:
            raise SettingsError(f"widths: {widths_needed_by} needs one pad separation (m) per grasp, got None")
        widths = np.asarray(widths, dtype=float).reshape(-1)
        if len(widths) != len(T) or not (np.isfinite(widths).all() and (widths >= 0).all()):
            raise SettingsError(f"widths: expected {len(T)} finite widths >= 0 m, got {widths.tolist()[:8]}")
    bodies = [target_body] * len(T) if isinstance(target_body, str) else list(target_body)
    if len(bodies) != len(T):
        raise SettingsError(f"target_body: expected a body name or {len(T)} of them, got {len(bodies)}")
    return T, widths, bodies
