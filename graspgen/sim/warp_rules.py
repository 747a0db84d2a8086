"""The in-phase rules of :class:`graspgen.sim.lift.LiftSimulator`, vectorised over the worlds of a MJWarp batch.

Each function is the CPU backend's function of the same meaning applied to ``nworld`` states at once (same formulas;
``tests/graspgen/sim/test_warp_backend.py`` and ``test_warp_table.py`` check them against the CPU ones on the same
states): :func:`jaws_on` is :func:`graspgen.sim.lift_rules.jaws_on`, :func:`relative_poses` is
:meth:`LiftSimulator.relative <graspgen.sim.lift_state.LiftState.relative>`, :func:`live_codes` is
:func:`graspgen.sim.lift_rules.live_code` (with no static code), :func:`moved_objects` is ``LiftState._moved`` and
:func:`slipped` is ``LiftState._slipped`` (without its drift bookkeeping). The batched rotation angles and
quaternion products are :func:`graspgen.geometry.poses.rotation_angles` and :func:`~graspgen.geometry.poses.quat_mul`.
"""

from __future__ import annotations

import numpy as np

from graspgen.sim.lift_rules import LEFT, RIGHT, TARGET

__all__ = ["NO_CODE", "jaws_on", "live_codes", "moved_objects", "relative_poses", "slipped"]

NO_CODE = 127
"""What :func:`live_codes` gives a world without such a contact (above every outcome code)."""


def jaws_on(geom: np.ndarray, world: np.ndarray, nworld: int, geom_side: np.ndarray,
            roles: np.ndarray) -> np.ndarray:
    """``(nworld, 2) bool``: (left jaw, right jaw) touches the target, per world.

    Parameters
    ----------
    geom : (k, 2) int
        Geom pairs of the batch's contacts (all worlds).
    world : (k,) int
        World of each contact.
    nworld : int
        Worlds in the batch.
    geom_side : (ngeom,) int8
        0 left jaw, 1 right jaw, 2 palm, -1 not the gripper (``LiftSimulator.index.geom_side``).
    roles : (ngeom,) or (nworld, ngeom) int8
        Geom roles for the target (``LiftSimulator.target_roles``), one row per world when the worlds grasp
        different objects.
    """
    out = np.zeros((nworld, 2), dtype=bool)
    if len(geom) == 0:
        return out
    side = geom_side[geom]
    on_target = _roles_of(roles, geom, world) == TARGET
    for col, jaw in ((0, LEFT), (1, RIGHT)):
        hit = ((side[:, 0] == jaw) & on_target[:, 1]) | ((side[:, 1] == jaw) & on_target[:, 0])
        out[world[hit], col] = True
    return out


def _roles_of(roles: np.ndarray, geom: np.ndarray, world: np.ndarray) -> np.ndarray:
    """``(k, 2)`` roles of the contacts' geoms ``geom (k, 2)`` in their worlds ``world (k,)``."""
    return roles[geom] if roles.ndim == 1 else roles[world[:, None], geom]


def relative_poses(xipos_t: np.ndarray, xmat_t: np.ndarray, xpos_b: np.ndarray,
                   xmat_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Target centre of mass ``(n, 3)`` and rotation ``(n, 3, 3)`` in the TCP frame, per world, from the target's
    ``xipos (n, 3)``, ``xmat (n, 3, 3)`` and the hand base's ``xpos (n, 3)``, ``xmat (n, 3, 3)`` (world frame)."""
    p = np.einsum("ni,nij->nj", xipos_t - xpos_b, xmat_b)  # R_tcp^T (x - x_tcp)
    R = np.einsum("nji,njk->nik", xmat_b, xmat_t)
    return p, R


def live_codes(geom: np.ndarray, world: np.ndarray, nworld: int, geom_is_gripper: np.ndarray,
               roles: np.ndarray) -> np.ndarray:
    """``(nworld,) int``: per world, the lowest role (0 support, 2 clutter) of the gripper's contacts with anything
    but the target, :data:`NO_CODE` when none (:func:`graspgen.sim.lift_rules.live_code` of each world).

    Parameters
    ----------
    geom : (k, 2) int
        Geom pairs of the batch's contacts (all worlds).
    world : (k,) int
        World of each contact.
    nworld : int
        Worlds in the batch.
    geom_is_gripper : (ngeom,) bool
        Gripper geoms (``LiftSimulator.index.geom_is_gripper``).
    roles : (ngeom,) or (nworld, ngeom) int8
        Geom roles for the target (one row per world when the worlds grasp different objects).
    """
    out = np.full(nworld, NO_CODE, dtype=np.int64)
    if len(geom) == 0:
        return out
    grip = geom_is_gripper[geom]
    other = np.where(grip[:, 0], geom[:, 1], geom[:, 0])
    codes = (roles[other] if roles.ndim == 1 else roles[world, other]).astype(np.int64)
    keep = (grip[:, 0] != grip[:, 1]) & (codes != TARGET)
    np.minimum.at(out, world[keep], codes[keep])
    return out


def moved_objects(xipos: np.ndarray, xquat: np.ndarray, pos0: np.ndarray, quat0: np.ndarray, shift2: float,
                  cos_half_turn: float) -> np.ndarray:
    """``(n, m) bool``: which of ``m`` objects in each of ``n`` worlds moved more than ``sqrt(shift2)`` m or turned
    more than ``2 acos(cos_half_turn)`` rad since ``pos0 (n, m, 3)``, ``quat0 (n, m, 4)``; ``xipos (n, m, 3)`` and
    ``xquat (n, m, 4)`` are their centres of mass and orientations now."""
    dp = xipos - pos0
    cos_half = np.abs(np.einsum("nij,nij->ni", xquat, quat0))  # |<q, q0>| = cos(turn / 2)
    return (np.einsum("nij,nij->ni", dp, dp) > shift2) | (cos_half < cos_half_turn)


def slipped(p: np.ndarray, R: np.ndarray, p0: np.ndarray, R0: np.ndarray, slip2: float, cos_slip: float) -> np.ndarray:
    """``(n,) bool``: the target moved more than ``sqrt(slip2)`` m or turned more than ``acos(cos_slip)`` rad in the
    TCP frame, from ``p0 (n, 3)``, ``R0 (n, 3, 3)`` to ``p (n, 3)``, ``R (n, 3, 3)``."""
    dp = p - p0
    return (np.einsum("ni,ni->n", dp, dp) > slip2) | ((np.einsum("nij,nij->n", R0, R) - 1.0) / 2.0 < cos_slip)
