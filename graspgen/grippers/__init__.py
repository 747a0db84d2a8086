"""Grippers as data: parallel-jaw gripper specs, their shapes and linkage, gripper files and the bundled grippers.

No MuJoCo here (numpy, trimesh and yaml only): :mod:`graspgen.sim.gripper_model` builds the MuJoCo model of a spec,
:mod:`graspgen.sim.gripper_state` poses and reads it, :mod:`graspgen.viz.gripper_picture` draws it.

Frames (ARCHITECTURE.md, Conventions). A grasp pose is the 4x4 transform of the gripper's tool centre point (TCP) frame:

* origin: midpoint between the two finger pads (between their contact faces, half-way along the pads);
* z: approach direction (palm -> object);
* x: closing direction (the line between the pads; the *right* pad sits on +x, the *left* pad on -x);
* y = z cross x.

The hand base (the robot flange for the 2F-85, the hand frame for the Panda) sits at ``-tcp_offset`` along z.

* **A gripper is a file.** Each bundled gripper is a YAML file in ``assets/grippers`` (``robotiq_2f85.yaml``,
  ``robotiq_2f85/robotiq_2f85_mesh.yaml``, ``box_jaw.yaml``, ``panda/panda.yaml``), and :func:`load_gripper` takes
  a registered name or the path of such a file written for another hand (the format: :func:`read_gripper`;
  ``assets/grippers/README.md``).
* **Geometry: boxes or convex meshes.** A gripper is either boxes given by sizes (``pad_size``, ``finger_size``,
  ``palm_boxes``: the 2F-85 and the box jaw) or collision pieces per body (``palm_geoms``, ``finger_geoms``,
  ``pad_geom``: :class:`Box` or convex :class:`Mesh`, in the TCP frame with the jaws open; the Panda, from
  ACRONYM's collision mesh). MuJoCo collides convex hulls, so a non-convex part is given as several convex pieces
  (``assets/make_grippers.py`` makes the Panda's). The pads stay separate geoms either way.
* **Two prismatic jaws.** Every gripper is a parallel-jaw gripper whose two jaws slide along +-x; the left jaw is
  the right one turned 180 degrees about z. The real Robotiq 2F-85 closes its fingers with a 4-bar linkage; its
  pads stay parallel but also travel along z (13.7 mm over the stroke) and the linkage sweeps outwards when open.
  ``robotiq_2f85`` (boxes) neglects both: pads move along x only, one box per finger. A gripper with a
  :class:`Linkage` (``robotiq_2f85_mesh``) keeps them (how the model does it: :mod:`graspgen.sim.gripper_model`).
"""

from __future__ import annotations

from graspgen.grippers.bundled import BUNDLED_DIGESTS, GRIPPERS_DIR
from graspgen.grippers.files import GRIPPER_FILE_SUFFIXES, gripper_from_dict, read_gripper, write_gripper
from graspgen.grippers.registry import (
    ACRONYM_GRIPPER,
    DEFAULT_GRIPPER,
    GRIPPERS,
    gripper_files,
    is_gripper_path,
    load_gripper,
)
from graspgen.grippers.shapes import Box, Linkage, Mesh, Shape
from graspgen.grippers.spec import GripperSpec, jaw_opening

__all__ = [
    "ACRONYM_GRIPPER",
    "BUNDLED_DIGESTS",
    "Box",
    "DEFAULT_GRIPPER",
    "GRIPPERS",
    "GRIPPERS_DIR",
    "GRIPPER_FILE_SUFFIXES",
    "GripperSpec",
    "Linkage",
    "Mesh",
    "Shape",
    "gripper_files",
    "gripper_from_dict",
    "is_gripper_path",
    "jaw_opening",
    "load_gripper",
    "read_gripper",
    "write_gripper",
]
