"""Which contacts a grasp's epsilon is computed from, in the target object's mesh frame (:func:`contact_set`).

The metrics table (:mod:`graspgen.workflows.metrics`) and the robustness copies
(:mod:`graspgen.workflows.robustness`) pick one contact set per grasp, in the target object's mesh frame:

* ``rollout``: the rollout's contacts at the end of closing, when the grasp was simulated and both jaws touched
  the target. MuJoCo reports one to four contacts per pad and convex part: four (the patch corners) when the pad
  lies flat on a face, one when it meets the face at an angle (then the pad model sees a point contact with the
  ``torsional_friction`` floor, where the ray casts may see a patch). They are stored in the world frame at the end
  of closing, and the rollouts table does not record where the object was then; they are taken to the object frame
  with the object's settled scene pose. The error is the object's motion between placement and the end of closing:
  at most ``physics.max_target_shift`` / ``max_target_turn`` during the approach (more is labelled a
  collision), plus the push of the first pad before the second one touches (about the grasp's offset from the
  object's centre line, a few mm). A push along the closing axis moves both patches along their normals, which
  leaves the normal forces' moments unchanged; only the friction edges see it. The robustness stage, which runs its
  own rollouts, records the object pose at the end of closing and converts exactly.
* ``raycast``: otherwise (not simulated: rejected by the pre-filter; or simulated but a jaw missed), the contacts
  of closing both pads onto the mesh along the TCP x axis (:func:`graspgen.geometry.contacts.closing_contacts`) at the
  grasp's ``pose_object``, when both pads touch.
* ``none``: neither gives contacts on both pads: epsilon 0, no friction label.

Centre of mass from the object record; ``torque_scale`` = the largest distance of a mesh vertex from it (so epsilon
is unit-free, ARCHITECTURE.md, Conventions). Friction: ``epsilon.friction``, or the object's friction in the scene when
null (the coefficient the simulation used for gripper-object contacts). The GraspNet-style label is the smallest
coefficient of ``closure_frictions`` at which the grasp is in force closure (epsilon > 0).
"""

from __future__ import annotations

import numpy as np

from graspgen.geometry.contacts import ClosingContacts

__all__ = ["CONTACT_SOURCES", "contact_set", "world_to_object"]

CONTACT_SOURCES = ("rollout", "raycast", "none")
"""Where a grasp's contacts came from (column ``contact_source``)."""


def world_to_object(points: np.ndarray, normals: np.ndarray, T_world_object: np.ndarray):
    """Contacts ``points (k, 3)`` m and ``normals (k, 3)`` from the world to the frame of the object at pose
    ``T_world_object (4, 4)`` (mesh frame to world). Returns ``(points, normals)`` in the mesh frame."""
    T = np.asarray(T_world_object, dtype=np.float64)
    R = T[:3, :3]
    return (np.asarray(points, dtype=np.float64) - T[:3, 3]) @ R, np.asarray(normals, dtype=np.float64) @ R


def contact_set(
    rollout: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
    T_world_object: np.ndarray,
    raycast: ClosingContacts | None,
) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    """The contacts a grasp's epsilon is computed from, by the rule of the module docstring.

    Parameters
    ----------
    rollout : (points (k, 3) m, normals (k, 3), fingers (k,)) in the world frame, or None when not simulated
    T_world_object : (4, 4) float
        The object's pose the rollout contacts are converted with (mesh frame to world).
    raycast : ClosingContacts or None
        Ray-cast contacts in the mesh frame (used when the rollout's are missing or touch one pad only).

    Returns
    -------
    (source, points (k, 3), normals (k, 3), fingers (k,) int8), mesh frame; ``k = 0`` for source ``none``.
    """
    if rollout is not None:
        points, normals, fingers = rollout
        fingers = np.asarray(fingers, dtype=np.int8).reshape(-1)
        if np.isin((0, 1), fingers).all():
            p, n = world_to_object(np.reshape(points, (-1, 3)), np.reshape(normals, (-1, 3)), T_world_object)
            return "rollout", p, n, fingers
    if raycast is not None and raycast.both_fingers:
        return "raycast", raycast.points, raycast.normals, np.asarray(raycast.finger, dtype=np.int8)
    return "none", np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=np.int8)
