"""A gripper derived from a robot model file (URDF or MJCF): :func:`derive_spec` turns a
:class:`~graspgen.grippers.model_ref.ModelRef` (a gripper file's ``model:``, ``pads:``, ``joints:``, ``actuator:``,
``body:``) into a :class:`~graspgen.grippers.GripperSpec` that every stage, ``gen evaluate`` and ``gen show`` use.

What is derived, from the model's own kinematics at the closing joints' values from open to closed (401 samples):

* **Closing joints**: ``joints:``, else the MJCF actuator's joints, else the subtree's moving joints that mimic no
  other; mimic joints (URDF ``<mimic>``, MJCF joint equalities) follow them. Each goes from the end of its range
  where the pads are farther apart (open) to the other (closed), all together.
* **Closing direction** (TCP x): from the left pad's centre to the right one's, open. **Approach** (TCP z): from the
  hand's base (the ``body:`` or root frame) towards the pads, square to x. y = z x x.
* **Pad faces and stroke**: each pad's face is its piece's extreme point towards the other pad along x; the width
  is their distance, ``max_width`` open and ``min_width`` closed (where the faces would pass each other, where they
  meet). ``max_width`` / ``min_width`` given in the file narrow the stroke to them.
* **TCP**: midway between the faces along x, at the pads' mean y, and along z halfway along the part of the pad
  faces that faces the TCP at every width (the bundled 2F-85's rule: pads that rise while closing share less);
  ``pad_size`` is that part of the face. ``tcp_offset`` is the TCP's height over the base.
* **Kinematics**: pads that only slide along x are two prismatic jaws; pads that keep their orientation and move on
  a circle of two parallel revolute joints are a parallelogram :class:`~graspgen.grippers.Linkage` (driver: the
  first joint on the pad's chain, coupler: the second, follower: another revolute link of the same side), checked
  against the model's pad path to 0.2 mm. Pads whose body turns more than the gripper file's ``pad_turn_tolerance``
  (degrees, default 1) while closing are refused (not a parallel-jaw gripper), the error giving the measured turn; a
  turn within it is ignored (the derived pads stay parallel) and, over 0.1 degree, named in the spec's ``source``.
* **Closed loops** (MJCF ``connect`` / ``weld`` / tendon / non-linear joint equalities, as in MuJoCo Menagerie's
  Robotiq 2F-85): MuJoCo settles the hand's other joints with the closing joints held at each of 201 samples from
  open to closed (:mod:`graspgen.sim.hand_loops`); those joint values stand in for the forward kinematics above, so
  the same slide or parallelogram is derived and checked. Such a hand needs its actuator or ``joints:`` to tell the
  closing joints; a loop MuJoCo cannot close along the stroke, or that leaves a link free, is an error naming it.
* **Collision pieces**: the open hand's collision geoms in the TCP frame, the right finger's (the left must be it
  turned 180 degrees about z, within 2 mm); boxes that stay axis-aligned stay boxes, other primitives become convex
  meshes, and mesh files go through :func:`graspgen.geometry.convex.cached_convex_decomposition` (a convex one is its
  hull; a non-convex one is cut by CoACD once and cached in ``$GRASPGEN_GRIPPER_CACHE``, default
  ``~/.cache/graspgen``). Visual-only geoms are never read.
* **Masses** from the links' inertials; **force** from the MJCF actuator's force range or a prismatic closing joint's
  URDF effort limit; **closing speed** from the joints' velocity limits. Each, when the model does not give it, is an
  error naming the gripper-file key that supplies it.
"""

from __future__ import annotations

from graspgen.grippers.model_ref import ModelRef, set_model_reader
from graspgen.grippers.spec import GripperSpec
from graspgen.sim.gripper_derive import build_spec
from graspgen.sim.hand_motion import hand_motion

__all__ = ["derive_spec"]


def derive_spec(ref: ModelRef, *, file: str = "") -> GripperSpec:
    """The :class:`GripperSpec` of the hand in ``ref`` (module docstring), read from gripper file ``file``.
    :class:`SettingsError` names what could not be derived and the key that supplies it."""
    motion, pads = hand_motion(ref)
    return build_spec(ref, motion, pads, file=file)


set_model_reader(derive_spec)
