"""The in-phase rules of :class:`graspgen.sim.lift.LiftSimulator`, vectorised over the worlds of a MJWarp batch.

Each function is the CPU backend's function of the same meaning applied to ``nworld`` states at once (same formulas;
``tests/graspgen/sim/test_warp_backend.py`` checks them against the CPU ones on the same states): :func:`jaws_on` is
:func:`graspgen.sim.lift_rules.jaws_on`, :func:`relative_poses` is :meth:`LiftSimulator.relative
<graspgen.sim.lift_state.LiftState.relative>`. The batched rotation angles and quaternion products are
:func:`graspgen.geometry.poses.rotation_angles` and :func:`~graspgen.geometry.poses.quat_mul`.
"""

from __future__ import annotations

import numpy as np

from graspgen.sim.lift_rules import LEFT, RIGHT, TARGET

__all__ = ["jaws_on", "relative_poses"]


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
    roles : (ngeom,) int8
        Geom roles for the target (``LiftSimulator.target_roles``).
    """
    out = np.zeros((nworld, 2), dtype=bool)
    if len(geom) == 0:
        return out
    side = geom_side[geom]
    on_target = roles[geom] == TARGET
    for col, jaw in ((0, LEFT), (1, RIGHT)):
        hit = ((side[:, 0] == jaw) & on_target[:, 1]) | ((side[:, 1] == jaw) & on_target[:, 0])
        out[world[hit], col] = True
    return out


def relative_poses(xipos_t: np.ndarray, xmat_t: np.ndarray, xpos_b: np.ndarray,
                   xmat_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Target centre of mass ``(n, 3)`` and rotation ``(n, 3, 3)`` in the TCP frame, per world, from the target's
    ``xipos (n, 3)``, ``xmat (n, 3, 3)`` and the hand base's ``xpos (n, 3)``, ``xmat (n, 3, 3)`` (world frame)."""
    p = np.einsum("ni,nij->nj", xipos_t - xpos_b, xmat_b)  # R_tcp^T (x - x_tcp)
    R = np.einsum("nji,njk->nik", xmat_b, xmat_t)
    return p, R
