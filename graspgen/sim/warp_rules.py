"""The in-phase rules of :class:`graspgen.sim.lift.LiftSimulator`, vectorised over the worlds of a MJWarp batch.

Each function is the CPU backend's method of the same meaning applied to ``nworld`` states at once (same formulas;
``tests/test_warp_backend.py`` checks them against the CPU methods on the same states): :func:`jaws_on` is
``LiftSimulator._jaws_on``, :func:`relative_poses` is ``_relative``, :func:`angles` is ``graspgen.sim.lift._angle``,
:func:`quat_mul_rows` is ``graspgen.sim.lift._quat_mul`` row by row.
"""

from __future__ import annotations

import numpy as np

from graspgen.sim.lift import _LEFT, _RIGHT, _TARGET

__all__ = ["angles", "jaws_on", "quat_mul_rows", "relative_poses"]


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
        0 left jaw, 1 right jaw, 2 palm, -1 not the gripper (``LiftSimulator._geom_side``).
    roles : (ngeom,) int8
        Geom roles for the target (``LiftSimulator._target_roles``).
    """
    out = np.zeros((nworld, 2), dtype=bool)
    if len(geom) == 0:
        return out
    side = geom_side[geom]
    on_target = roles[geom] == _TARGET
    for col, jaw in ((0, _LEFT), (1, _RIGHT)):
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


def angles(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """``(n,)`` rotation angles (rad) between ``Ra (n, 3, 3)`` and ``Rb (n, 3, 3)``: atan2(sin, cos) of
    ``Ra^T Rb`` (precise near 0)."""
    R = np.einsum("nji,njk->nik", Ra, Rb)
    c = (R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2] - 1.0) / 2.0
    s = 0.5 * np.sqrt((R[:, 2, 1] - R[:, 1, 2]) ** 2 + (R[:, 0, 2] - R[:, 2, 0]) ** 2 + (R[:, 1, 0] - R[:, 0, 1]) ** 2)
    return np.arctan2(s, c)


def quat_mul_rows(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Hamilton products ``q[i] * r[i]`` of quaternions ``(n, 4)`` (w, x, y, z), row by row
    (``graspgen.sim.lift._quat_mul`` pairs one ``q`` with many ``r``)."""
    w0, x0, y0, z0 = q.T
    w1, x1, y1, z1 = r.T
    return np.stack([w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1,
                     w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1,
                     w0 * y1 - x0 * z1 + y0 * w1 + z0 * x1,
                     w0 * z1 + x0 * y1 - y0 * x1 + z0 * w1], axis=1)
