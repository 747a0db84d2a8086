"""Grippers as data, and the MuJoCo model of a floating parallel-jaw gripper built from that data.

Frames (ARCHITECTURE.md, Conventions). A grasp pose is the 4x4 transform of the gripper's tool centre point (TCP) frame:

* origin: midpoint between the two finger pads (between their contact faces, half-way along the pads);
* z: approach direction (palm -> object);
* x: closing direction (the line between the pads; the *right* pad sits on +x, the *left* pad on -x);
* y = z cross x.

The hand base (the robot flange for the 2F-85, the hand frame for the Panda) sits at ``-tcp_offset`` along z.

Modelling, the same for every gripper:

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
  :class:`Linkage` (``robotiq_2f85_mesh``) keeps them: each jaw also has a z slide ``<side>_lift`` and carries its
  two links as hinged child bodies (``<side>_driver``, ``<side>_follower``: a link turning about its palm pivot
  while the finger translates is the link turning by the same angle about its joint on the finger), every one of
  those joints tied to the jaw slide by a quartic joint equality ``<side>_<joint>_coupling`` fitted to the linkage's
  circle. The jaw slide stays the one driven coordinate, so everything below holds for both kinds; whoever sets
  the slides' qpos by hand applies :func:`linkage_couplings` too.
* **Jaw joint coordinate = half the width.** Each jaw's slide joint ``q`` is the distance of its pad's contact face
  from the TCP plane x = 0, so pad separation (width) = ``q_left + q_right``; range ``[min_width, max_width] / 2``,
  ``qpos0 = max_width / 2`` (a freshly built gripper is open).
* **Symmetric drive.** A fixed tendon ``width = q_left + q_right`` is driven by one position actuator whose control is
  the target width in metres (``ctrl = width`` gives pad separation ``width`` when nothing is in the way);
  ``ctrlrange = [min_width, max_width]`` so larger/smaller commands are clipped. A joint equality ``q_left = q_right``
  keeps the jaws centred on the TCP. The actuator force acts on each jaw (tendon coefficients 1), and
  ``forcerange = +-force_limit``: a jaw closing on an object squeezes it with at most ``force_limit`` newtons
  (the position gain saturates at ``_SATURATION_ERROR`` of width error, so closing on an object -- command
  ``min_width`` -- squeezes with exactly ``force_limit``).
* **Closing speed.** Each jaw joint has viscous damping ``2 * force_limit / closing_speed``: a saturated actuator
  then drives the width at ``closing_speed``, like a force- and speed-limited electric gripper. The damping is
  integrated implicitly by ``implicitfast``.
* **Floating base: mocap body + weld.** The TCP body has a free joint and is welded (equality constraint) to a mocap
  body; callers move the mocap body (``set_gripper_target``) and the gripper follows. We chose this over 6 actuated
  joints (3 slide + 3 hinge) because (1) the weld is solved by the constraint solver together with the contacts, so
  it stays stiff under load without gains that the explicit part of the integrator limits by the timestep
  (``implicitfast`` only integrates velocity terms implicitly; a position servo's kp is explicit), (2) a free joint
  has no Euler-angle hinge chain and so no gimbal singularity for arbitrary grasp orientations, (3) it is the usual
  protocol for floating-gripper grasp-and-lift evaluation. Measured: at rest the TCP sits within 0.1 mm / 0.1 deg
  of the target, also holding a 2 kg box; while the target moves at 0.2 m/s the TCP lags ~2 mm (weld time
  constant 5 ms). :func:`set_gripper_pose` teleports both, so a new grasp pose starts with zero error.
  All gripper bodies have gravity compensation, so the weld carries only the object (not the gripper's own weight).
* **Collisions.** Gripper geoms have ``contype=2, conaffinity=1`` (:data:`GRIPPER_CONTYPE`,
  :data:`GRIPPER_CONAFFINITY`): they collide with default geoms (objects, ground: contype = conaffinity = 1) but not
  with each other. They live in geom group :data:`GRIPPER_GEOM_GROUP` and are named ``<prefix>left_pad``,
  ``<prefix>right_pad``, ``<prefix>left_finger``, ``<prefix>right_finger`` (further finger pieces
  ``<prefix>left_finger_<k>``, k >= 1), ``<prefix>palm_<k>``; each jaw body's frame is its pad's contact face.
* **Contact parameters: who sets what.** MuJoCo has no per-material-pair friction; it combines two geoms' parameters
  by *priority* (the higher-priority geom's friction, condim, solref, solimp win) and, at equal priority, takes the
  element-wise maximum friction, the maximum condim, and a ``solmix``-weighted average of solref/solimp.
  ``build_gripper(friction="object")`` (the default) uses this so that

  - the **object's sliding friction** governs gripper-object contacts: gripper geoms have priority 0 (like objects)
    and sliding friction 0, so max(0, mu_object) = mu_object. A scene's per-object friction is what the simulation
    uses: a 0.01-friction box slips out of the pads, a 0.8 one is lifted;
  - the **pads' condim** (:attr:`pad_condim`) acts as a floor, so pad contacts have torsional friction even with
    condim-3 objects; their torsional coefficient on objects is derived (below), :attr:`GripperSpec.pad_friction`
    [1:] is the floor of their other contacts;
  - the **gripper's stiff contact softness** governs (solref 4 ms, solimp 0.95/0.99, via ``solmix`` = 1e6): MuJoCo's
    softness is mass-normalised, and with the default solref (20 ms) a 100 N grip on a 0.1 kg box sinks ~7 mm into
    each pad; with the stiff setting (and the jaw armature) it is ~0.1-0.3 mm.

  ``friction="pad"`` gives gripper geoms priority 1 instead: the pads' full :attr:`pad_friction` (e.g. 1.0),
  condim and solref govern, and the object's friction is ignored for gripper contacts.

* **Pad-object torsional friction is derived, per object** (:func:`pad_torsion_arm`, :func:`set_pad_torsion`).
  MuJoCo's torsional friction (condim >= 4) limits the moment about a contact's normal to ``gamma * f_n`` with
  ``gamma`` in metres. Coulomb friction ``mu p dA`` over a patch A pressed with total force F under uniform pressure
  resists a moment of ``mu F r_mean``, r_mean = the mean distance of A from its centroid (Howe & Cutkosky 1996,
  "Practical force-motion models for sliding manipulation", IJRR 15(6); the limit-surface view of Goyal, Ruina &
  Papadopoulos 1991), so ``gamma = mu_contact * r_mean(pad face)``: it scales with the object's friction as Coulomb
  friction does. The patch is the pad face (``pad_size`` y x z), the patch of a flat object face that covers the
  pad; a smaller or curved face touches less of it, so this is the upper end. Pressure model, by argument: the pads
  are flat faces (rubber-faced on the Panda and the 2F-85) pressed against flat faces; a thin compliant layer on a
  rigid backing squeezed between parallel flat faces is compressed evenly (a Winkler foundation: pressure ~ local
  compression), so the pressure is uniform. Hertz's ``p0 sqrt(1 - r^2/R^2)`` is for non-conforming curved bodies
  (it would give 3 pi / 16 = 0.59 instead of 2/3 = 0.67 mu F R on a disc, 12 % less) and a rigid flat punch on an
  elastic half-space concentrates pressure at the rim (pi / 4 = 0.79 mu F R, 18 % more): neither describes a flat
  pad on a flat face. Sliding and torsion share MuJoCo's elliptic cone ``(f_t / mu)^2 + (m / gamma)^2 <= f_n^2``,
  the ellipsoidal approximation of the limit surface in the same papers. Where it is written: MuJoCo takes the
  larger of two geoms' torsional coefficients, so with ``friction="object"`` the pads carry 0 and
  :func:`attach_gripper` gives every object geom already in the world ``mu_object * r_mean`` (objects are condim
  3: the value acts only in their condim-4 contacts with the pads); a scene of objects of different frictions gets
  each its own ``gamma``, and masks (contype / conaffinity) still switch contacts off. Not explicit ``<pair>``s:
  those ignore the masks and the geoms' friction, which other code edits at run time. With ``"pad"`` the pads
  carry their own ``mu_pad * r_mean``. One gripper per world sets the object values (a second attached one
  overwrites them). Caveat, measured (:mod:`graspgen.sim.mechanics`): MuJoCo 4 (multiccd) gives a pad several
  contact points on a flat face (the Panda's mesh pad 3, a box pad 4 at its corners), whose sliding friction
  resists torsion too; the Panda's pivot threshold lands within 4 % of ``mu F r_mean``, box pads resist 35-40 %
  more. Rolling friction is not derived: the bundled pads are condim 4 (a flat pad resists tipping by shifting its
  pressure, not by friction), so rolling is the larger of the two geoms' values, as before, and unused.

Physics settings that hold objects (measured): timestep 2 ms, elliptic friction cones, impratio 10, implicitfast
(:class:`PhysicsOptions`). With MuJoCo's defaults (pyramidal cones, impratio 1) held objects creep: measured here, a
2 kg box (friction 0.5) slides ~7 mm down between the 2F-85's pads during a 1.5 s lift-and-hold, < 1 mm with ours.

MuJoCo note: with :meth:`mujoco.MjSpec.attach` the order of actuators/joints/geoms depends on the order of attachment,
so every helper here looks elements up by *name* (``name_prefix`` + local name), never by index.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Mapping
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import yaml

from graspgen.errors import SettingsError
from graspgen.validation import check, check_choice, check_number, check_transform, check_vector

__all__ = [
    "Box",
    "Mesh",
    "GripperSpec",
    "GRIPPERS_DIR",
    "read_gripper",
    "write_gripper",
    "gripper_from_dict",
    "gripper_files",
    "is_gripper_path",
    "BUNDLED_DIGESTS",
    "GRIPPERS",
    "DEFAULT_GRIPPER",
    "GRIPPER_CONTYPE",
    "GRIPPER_CONAFFINITY",
    "GRIPPER_GEOM_GROUP",
    "PhysicsOptions",
    "physics_options",
    "load_gripper",
    "build_gripper",
    "attach_gripper",
    "set_gripper_pose",
    "set_gripper_target",
    "gripper_pose",
    "set_gripper_width",
    "gripper_width",
    "pad_geom_ids",
    "gripper_geom_ids",
    "pad_torsion_arm",
    "object_torsion",
    "set_pad_torsion",
    "Linkage",
    "LinkageCouplings",
    "linkage_couplings",
]

#: Contact bitmasks of every gripper geom: collide with default geoms (contype = conaffinity = 1: objects, ground),
#: never with each other (2 & 1 == 0 both ways).
GRIPPER_CONTYPE = 2
GRIPPER_CONAFFINITY = 1
#: Geom group of every gripper geom (MuJoCo's viewer shows groups 0-2 by default).
GRIPPER_GEOM_GROUP = 2

#: Width error (m) at which the position actuator reaches ``force_limit``: kp = force_limit / _SATURATION_ERROR.
_SATURATION_ERROR = 0.002
#: Armature (kg) of each jaw's slide joint: the reflected inertia of the drive (motor + screw / linkage). Without it
#: a 15-60 g jaw between the stiff pad contact and the saturated servo chatters (measured: +-1.5 mm width jitter
#: on a held box); with 0.5 kg the width is steady. It only slows the jaws' acceleration (time constant
#: (m + armature) / damping < 1 ms), not their damping-limited closing speed.
_JAW_ARMATURE = 0.5
#: Contact softness of every gripper geom (rubber pads are stiff at this scale): time constant 4 ms (= 2 timesteps,
#: the smallest MuJoCo accepts at 2 ms), critical damping; impedance 0.95 -> 0.99 over 1 mm.
_CONTACT_SOLREF = (0.004, 1.0)
_CONTACT_SOLIMP = (0.95, 0.99, 0.001, 0.5, 2.0)
#: solmix of gripper geoms: at equal priority their solref/solimp get weight 1e6 / (1e6 + solmix_object) ~ 1.
_CONTACT_SOLMIX = 1e6
#: build_gripper(friction=...) choices -> gripper geom priority.
_FRICTION_MODES = {"object": 0, "pad": 1}
#: Weld (mocap -> TCP body) and jaw-coupling constraint softness: time constant 5 ms (>= 2 timesteps of 2 ms),
#: critical damping; solimp with a narrow transition to an impedance of 0.99 (stiff).
_WELD_SOLREF = (0.005, 1.0)
_WELD_SOLIMP = (0.95, 0.99, 0.001, 0.5, 2.0)


# ---------------------------------------------------------------------------------------------------------------
# Data
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Box:
    """An axis-aligned collision box in the gripper's TCP frame (used for the palm / hand body)."""

    size: tuple[float, float, float]
    """Full extents (m) along TCP x (closing), y, z (approach). Not MuJoCo's half-sizes."""
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Centre of the box (m) in the TCP frame; the palm lies at negative z (behind the pads)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "size", check_vector("Box.size", self.size, 3, low=0.0, low_open=True))
        object.__setattr__(self, "pos", check_vector("Box.pos", self.pos, 3))

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lowest corner, highest corner) (m), each (3,)."""
        return np.subtract(self.pos, np.divide(self.size, 2)), np.add(self.pos, np.divide(self.size, 2))


@dataclass(frozen=True)
class Mesh:
    """A convex collision piece given by its vertices, in the gripper's TCP frame (MuJoCo collides with the convex
    hull of a mesh, so only the hull's vertices matter)."""

    vertices: tuple[tuple[float, float, float], ...]
    """Vertices (m), at least 4 and not all in one plane."""
    file: str = field(default="", compare=False)
    """The mesh file it was read from ('' when given by its vertices); for messages and :func:`gripper_files`."""

    def __post_init__(self) -> None:
        try:
            v = np.asarray(self.vertices, dtype=float)
        except (TypeError, ValueError):
            v = None
        check("Mesh.vertices", v is not None and v.ndim == 2 and v.shape[1:] == (3,) and len(v) >= 4
              and bool(np.isfinite(v).all()), "be 4 or more finite (x, y, z) points", _short(self.vertices))
        spread = np.linalg.svd(v - v.mean(axis=0), compute_uv=False)
        check("Mesh.vertices", spread[2] > 1e-9 * max(spread[0], 1e-12) and spread[2] > 1e-9,
              "span a volume (not all in one plane)", _short(self.vertices))
        object.__setattr__(self, "vertices", tuple(tuple(float(x) for x in row) for row in v))

    @property
    def array(self) -> np.ndarray:
        """The vertices as an (n, 3) float64 array (a copy)."""
        return np.array(self.vertices, dtype=float)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lowest corner, highest corner) (m) of the axis-aligned bounding box, each (3,)."""
        v = self.array
        return v.min(axis=0), v.max(axis=0)


Shape = Box | Mesh
"""A collision geom of a gripper body: a :class:`Box` or a convex :class:`Mesh`."""


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _bounds_of(shapes) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (3,) of the axis-aligned box around ``shapes``."""
    los, his = zip(*(s.bounds for s in shapes))
    return np.min(los, axis=0), np.max(his, axis=0)


def _box_around(shapes) -> Box:
    lo, hi = _bounds_of(shapes)
    return Box(size=tuple(hi - lo), pos=tuple((lo + hi) / 2.0))


def _check_shapes(name: str, value: Any) -> tuple[Shape, ...]:
    try:
        shapes = tuple(value)
    except TypeError:
        shapes = None
    check(name, shapes is not None and all(isinstance(s, (Box, Mesh)) for s in shapes),
          "be a sequence of Box or Mesh", _short(value))
    return shapes


#: Largest error allowed of the quartics that couple a linkage's joints to the jaw slide: pad height (m) and link
#: angle (rad) over the stroke.
_LINKAGE_FIT_TOL = (5e-5, 2e-3)


@dataclass(frozen=True)
class Linkage:
    """A parallelogram (4-bar) finger linkage, as on the Robotiq 2F-85: two links per finger, the *driver* and the
    *follower*, turn about pivots fixed in the palm, and the finger they carry (the coupler: the finger link and its
    pad, :attr:`GripperSpec.finger_geoms` and :attr:`GripperSpec.pad_geom`) keeps its orientation, so every point of
    it, the pad included, moves on a circle of the crank's radius: the pads stay parallel and rise or sink along z
    as they close. Given for the right finger (+x), in the gripper file's frame, with the jaws open; the left finger
    is the same turned 180 degrees about z. All points are (x, z) pairs (m) in the closing/approach plane y = 0.
    """

    pivot: tuple[float, float]
    """(x, z) (m) of the driver link's pivot on the palm (TCP frame)."""
    crank: tuple[float, float]
    """(x, z) (m) from the driver's pivot to its joint on the finger, jaws open; the follower's crank is the same
    (a parallelogram), so its joint on the finger is ``follower_pivot + crank``."""
    follower_pivot: tuple[float, float]
    """(x, z) (m) of the follower link's pivot on the palm (TCP frame)."""
    driver_geoms: tuple[Shape, ...]
    """Collision pieces of the right driver link, in the TCP frame with the jaws open."""
    follower_geoms: tuple[Shape, ...] = ()
    """Collision pieces of the right follower link, in the TCP frame with the jaws open (may be empty)."""
    driver_mass: float = 0.03
    """Mass (kg) of one driver link."""
    follower_mass: float = 0.03
    """Mass (kg) of one follower link."""

    def __post_init__(self) -> None:
        for key in ("pivot", "crank", "follower_pivot"):
            object.__setattr__(self, key, check_vector(f"linkage.{key}", getattr(self, key), 2))
        check("linkage.crank", float(np.hypot(*self.crank)) > 1e-4, "be longer than 0.1 mm", self.crank)
        object.__setattr__(self, "driver_geoms", _check_shapes("linkage.driver_geoms", self.driver_geoms))
        check("linkage.driver_geoms", bool(self.driver_geoms), "hold at least one piece", self.driver_geoms)
        object.__setattr__(self, "follower_geoms", _check_shapes("linkage.follower_geoms", self.follower_geoms))
        for key in ("driver_mass", "follower_mass"):
            object.__setattr__(self, key, check_number(f"linkage.{key}", getattr(self, key), low=0.0,
                                                       low_open=True))

    @property
    def radius(self) -> float:
        """Crank length (m): the radius of every finger point's path."""
        return float(np.hypot(*self.crank))

    def angle(self, shift) -> np.ndarray:
        """Closing rotation (rad) of the links when the pad has moved ``shift`` (m, scalar or array; <= 0 closing)
        along x from the open position: the crank's angle from +x grows as the finger moves in."""
        cx, cz = self.crank
        return np.arccos(np.clip((cx + np.asarray(shift, dtype=float)) / self.radius, -1.0, 1.0)) - np.arctan2(cz, cx)

    def rise(self, shift) -> np.ndarray:
        """The pad's displacement (m) along z (+: towards the object) when it has moved ``shift`` (m) along x."""
        cx, cz = self.crank
        phi = np.arctan2(cz, cx) + self.angle(shift)
        return self.radius * np.sin(phi) - cz

    def couplings(self, min_width: float, max_width: float) -> dict[str, tuple[float, ...]]:
        """Quartic coefficients ``(a0, .., a4)`` of each joint driven by the jaw slide ``q`` (the pad face's x), in
        MuJoCo's joint-equality form ``q1 - q1_ref = sum a_k (q - max_width / 2)^k``: ``lift`` (the pad's z, m),
        ``driver`` and ``follower`` (the links' angle, rad). Least squares on 64 Chebyshev nodes of the stroke;
        :class:`SettingsError` when the path is not reachable or a fit is off by more than 0.05 mm / 2 mrad."""
        lo = (min_width - max_width) / 2.0
        check("linkage.crank", (self.crank[0] + lo) / self.radius >= -1.0,
              f"reach the closed pads: its x ({self.crank[0]:.4g} m) plus the closing travel must stay within the "
              f"crank's radius ({self.radius:.4g} m)", self.crank)
        nodes = lo / 2.0 * (1.0 - np.cos(np.linspace(0.0, np.pi, 64)))
        fine = np.linspace(lo, 0.0, 1001)
        out = {}
        for key, fn, tol in (("lift", self.rise, _LINKAGE_FIT_TOL[0]), ("driver", self.angle, _LINKAGE_FIT_TOL[1])):
            coef = np.polynomial.polynomial.polyfit(nodes, fn(nodes) - fn(0.0), 4)
            err = float(np.abs(np.polynomial.polynomial.polyval(fine, coef) - (fn(fine) - fn(0.0))).max())
            check("linkage", err <= tol, f"have a path a quartic follows over the stroke (the {key} fit is off by "
                  f"{err:.3g}, more than {tol:g})", self.crank)
            out[key] = tuple(float(c) for c in coef)
        out["follower"] = out["driver"]
        return out


@dataclass(frozen=True)
class GripperSpec:
    """A parallel-jaw gripper, as data. All lengths in metres, in the TCP frame (see the module docstring).

    Geometry comes in one of two ways (or mixed per body): boxes given by sizes (``pad_size``, ``finger_size``,
    ``palm_boxes``), or collision pieces per body (``palm_geoms``, ``finger_geoms``, ``pad_geom``), which replace the
    boxes of their body in the MuJoCo model. The sizes stay meaningful either way: ``pad_size`` is the contact area
    (the grasp sampler and the contact model use it) and ``finger_size`` / ``palm_boxes`` the bounding boxes
    (inertia, drawings).
    """

    name: str
    """Registry name, e.g. ``"robotiq_2f85"``."""
    min_width: float
    """Smallest pad separation (m): distance between the two pads' contact faces when fully closed."""
    max_width: float
    """Largest pad separation (m) when fully open (the stroke is ``max_width - min_width``)."""
    pad_size: tuple[float, float, float]
    """Full extents (m) of each contact pad box: (thickness along x, width along y, length along z). The pad's
    contact face is its inner x face; pads are centred at y = 0, z = 0 of the TCP frame. With a ``pad_geom``, the
    contact face's width and length (and the geom's thickness)."""
    pad_friction: tuple[float, float, float]
    """MuJoCo friction of the pads: (sliding [-], torsional [m], rolling [m]). With ``build_gripper(friction="pad")``
    the sliding coefficient governs pad contacts; with the default ``friction="object"`` the object's does. The
    torsional coefficient of a pad's contact with an object is derived, not taken from here: ``mu`` x
    :func:`pad_torsion_arm`, written on the object geoms by :func:`attach_gripper` (module docstring); the torsional and
    rolling entries are the floor of the pads' other contacts (support, ground, objects added after the gripper)."""
    finger_size: tuple[float, float, float]
    """Full extents (m) of each finger link box: (thickness along x, width along y, length along z). The box sits
    directly behind (outside) its pad and its tip is flush with the pad's tip (z = pad length / 2). With
    ``finger_geoms``, the extents of the finger's bounding box (pad included)."""
    palm_boxes: tuple[Box, ...]
    """Collision boxes of the palm / hand body, fixed in the TCP frame (behind the fingers, at negative z). With
    ``palm_geoms`` (which then collide instead), their bounding box; left empty, it is filled in."""
    tcp_offset: float
    """Distance (m) from the hand base (flange / hand frame) to the TCP along z; the base is at z = -tcp_offset."""
    force_limit: float
    """Maximum grip force (N): the jaw actuator's force saturates here, so each pad presses with at most this."""
    finger_mass: float
    """Mass (kg) of one jaw (finger link + pad)."""
    body_mass: float
    """Mass (kg) of the palm / hand body (everything but the two jaws)."""
    closing_speed: float
    """Rate of change of the pad separation (m/s) when the actuator is saturated and nothing is in the way."""
    pad_condim: int = 4
    """MuJoCo contact dimensionality of the pads: 3 (sliding), 4 (+ torsional) or 6 (+ rolling)."""
    source: str = ""
    """Where the numbers come from (data sheets, reference models) and what was approximated."""
    palm_geoms: tuple[Shape, ...] = ()
    """Collision pieces of the palm / hand body (TCP frame); empty: the ``palm_boxes`` collide."""
    finger_geoms: tuple[Shape, ...] = ()
    """Collision pieces of the right finger link (+x) without its pad, in the TCP frame with the jaws open (width
    ``max_width``); the left finger is the same turned 180 degrees about z. Empty: one box of ``finger_size``."""
    pad_geom: Shape | None = None
    """The right pad's collision piece, in the TCP frame with the jaws open: its contact face (its smallest x) lies
    at ``x = max_width / 2`` (within 0.5 mm; the model puts it there exactly) and it straddles y = 0 and z = 0.
    None: a box of ``pad_size``."""
    linkage: Linkage | None = None
    """The finger linkage (:class:`Linkage`): the fingers then follow its path (the pads rise or sink along z as
    they close) and its links collide too. None: the jaws slide along x only."""
    file: str = field(default="", compare=False)
    """The gripper file this spec was read from ('' for one made in Python)."""

    def __post_init__(self) -> None:
        check("name", isinstance(self.name, str) and bool(self.name.strip()), "be a non-empty string", self.name)
        object.__setattr__(self, "min_width", check_number("min_width", self.min_width, low=0.0))
        object.__setattr__(self, "max_width", check_number("max_width", self.max_width, low=self.min_width,
                                                           low_open=True))
        for key in ("tcp_offset", "force_limit", "finger_mass", "body_mass", "closing_speed"):
            object.__setattr__(self, key, check_number(key, getattr(self, key), low=0.0, low_open=True))
        object.__setattr__(self, "pad_size", check_vector("pad_size", self.pad_size, 3, low=0.0, low_open=True))
        object.__setattr__(self, "pad_friction", check_vector("pad_friction", self.pad_friction, 3, low=0.0))
        object.__setattr__(self, "finger_size", check_vector("finger_size", self.finger_size, 3, low=0.0,
                                                             low_open=True))
        check("pad_friction", self.pad_friction[0] > 0, "have a sliding coefficient > 0", self.pad_friction)
        check("finger_size", self.finger_size[2] >= self.pad_size[2],
              f"be at least as long as its pad (length >= pad_size z = {self.pad_size[2]} m)", self.finger_size)
        check("pad_condim", self.pad_condim in (1, 3, 4, 6) and not isinstance(self.pad_condim, bool),
              "be one of 1, 3, 4, 6", self.pad_condim)
        palm_geoms = _check_shapes("palm_geoms", self.palm_geoms)
        object.__setattr__(self, "palm_geoms", palm_geoms)
        boxes = tuple(self.palm_boxes)
        if not boxes and palm_geoms:
            boxes = (_box_around(palm_geoms),)
        check("palm_boxes", bool(boxes) and all(isinstance(b, Box) for b in boxes), "be a non-empty sequence of Box",
              self.palm_boxes)
        object.__setattr__(self, "palm_boxes", boxes)
        fingers = _check_shapes("finger_geoms", self.finger_geoms)
        object.__setattr__(self, "finger_geoms", fingers)
        if fingers:
            check("finger_geoms", bool(_bounds_of(fingers)[0][0] >= -1e-9),
                  "describe the right finger (+x): every piece at x >= 0", f"lowest x {_bounds_of(fingers)[0][0]:.4g}")
        pad = self.pad_geom
        check("pad_geom", pad is None or isinstance(pad, (Box, Mesh)), "be a Box, a Mesh or None", _short(pad))
        if pad is not None:
            lo, hi = pad.bounds
            half = self.max_width / 2.0
            check("pad_geom", abs(lo[0] - half) <= _FACE_TOL,
                  f"have its contact face (its smallest x) at max_width / 2 = {half:.4g} m (within 0.5 mm; give it "
                  "with the jaws open)", f"smallest x {lo[0]:.4g}")
            check("pad_geom", lo[1] <= 0.0 <= hi[1] and lo[2] <= 0.0 <= hi[2],
                  "straddle the TCP (y = 0 and z = 0 within its extents)",
                  f"y {lo[1]:.4g}..{hi[1]:.4g}, z {lo[2]:.4g}..{hi[2]:.4g}")
        check("linkage", self.linkage is None or isinstance(self.linkage, Linkage), "be a Linkage or None",
              _short(self.linkage))
        if self.linkage is not None:
            self.linkage.couplings(self.min_width, self.max_width)  # reachable and fitted, or SettingsError
        check("source", isinstance(self.source, str), "be a string", self.source)
        check("file", isinstance(self.file, str), "be a string", self.file)

    @property
    def stroke(self) -> float:
        """``max_width - min_width`` (m)."""
        return self.max_width - self.min_width

    @property
    def kp(self) -> float:
        """Position gain (N/m) of the width actuator: saturates at ``force_limit`` for 2 mm of width error."""
        return self.force_limit / _SATURATION_ERROR

    @property
    def jaw_damping(self) -> float:
        """Viscous damping (N s/m) of each jaw joint, so that a saturated actuator closes at ``closing_speed``."""
        return 2.0 * self.force_limit / self.closing_speed

    @property
    def uses_meshes(self) -> bool:
        """Whether any body collides with :class:`Mesh` pieces (not only boxes)."""
        return any(isinstance(s, Mesh) for s in self.pieces)

    @property
    def pieces(self) -> tuple[Shape, ...]:
        """Every collision piece given as a shape: palm, finger, pad and linkage pieces (not the size boxes)."""
        link = () if self.linkage is None else (*self.linkage.driver_geoms, *self.linkage.follower_geoms)
        return (*self.palm_geoms, *self.finger_geoms, *(() if self.pad_geom is None else (self.pad_geom,)), *link)

    def pad_rise(self, width) -> np.ndarray:
        """Displacement (m) of the pads along z (+: towards the object) at pad separation ``width`` (m, scalar or
        array) from where they are when open: 0 without a linkage."""
        shift = (np.asarray(width, dtype=float) - self.max_width) / 2.0
        return np.zeros_like(shift) if self.linkage is None else self.linkage.rise(shift)

    def to_dict(self) -> dict:
        """Plain-data view (for logs / metadata files); also the gripper file format: ``write_gripper`` writes it and
        :func:`read_gripper` reads it back (meshes as their vertices). ``file`` is left out."""
        out = {}
        for f in fields(self):
            if f.name == "file":
                continue
            value = getattr(self, f.name)
            if f.name in ("palm_boxes", "palm_geoms", "finger_geoms"):
                value = [_shape_dict(s) for s in value]
            elif f.name == "pad_geom":
                value = None if value is None else _shape_dict(value)
            elif f.name == "linkage":
                value = None if value is None else {
                    "pivot": list(value.pivot), "crank": list(value.crank),
                    "follower_pivot": list(value.follower_pivot),
                    "driver_geoms": [_shape_dict(s) for s in value.driver_geoms],
                    "follower_geoms": [_shape_dict(s) for s in value.follower_geoms],
                    "driver_mass": value.driver_mass, "follower_mass": value.follower_mass}
            elif isinstance(value, tuple):
                value = list(value)
            out[f.name] = value
        return out


#: A mesh pad's contact face may lie this far (m) from ``max_width / 2`` in the open gripper's geometry.
_FACE_TOL = 5e-4
#: A mesh piece whose convex hull is this much larger than the piece is refused as not convex (MuJoCo would
#: collide its hull).
_MAX_HULL_EXCESS = 0.05
#: Suffixes of gripper files.
GRIPPER_FILE_SUFFIXES = (".yaml", ".yml", ".json")
#: The folder of the bundled gripper files.
GRIPPERS_DIR = Path(__file__).resolve().parents[2] / "assets" / "grippers"
_BUNDLED = {"box_jaw": "box_jaw.yaml", "panda": "panda/panda.yaml", "robotiq_2f85": "robotiq_2f85.yaml",
            "robotiq_2f85_mesh": "robotiq_2f85/robotiq_2f85_mesh.yaml"}
#: sha256 (first 16 hex digits) of every file the bundled grippers are read from, relative to GRIPPERS_DIR. The
#: bundled grippers are part of the library, so their files must count as code: a stage's content key holds the
#: digest of this module, and with it these digests, so editing a bundled file (and then this table, which
#: tests/test_grippers.py checks) re-runs the stages that use grippers, with the same random draws.
BUNDLED_DIGESTS = {
    "box_jaw.yaml": "0aad5e0055e1f959",
    "panda/finger.obj": "67373fdf9def1084",
    "panda/hand.obj": "feaab1d7eddd6fcb",
    "panda/pad.obj": "88587d01d351de87",
    "panda/panda.yaml": "560bbd1544ce8738",
    "robotiq_2f85/airo/robotiq_arg2f_85_inner_finger.obj": "f6507cef254ba4a1",
    "robotiq_2f85/airo/robotiq_arg2f_85_inner_knuckle.obj": "81dcdd59590b823a",
    "robotiq_2f85/airo/robotiq_arg2f_85_outer_finger.obj": "135d80498c0bdee5",
    "robotiq_2f85/airo/robotiq_arg2f_85_outer_knuckle.obj": "bd3a4fb67e22d904",
    "robotiq_2f85/airo/robotiq_arg2f_base_link.obj": "912592cfa4056b44",
    "robotiq_2f85/driver.obj": "342523646af15430",
    "robotiq_2f85/finger.obj": "49b214ca3971d013",
    "robotiq_2f85/follower.obj": "71cda5c7693f5f7a",
    "robotiq_2f85/palm.obj": "bfdebd31d584551f",
    "robotiq_2f85/robotiq_2f85_mesh.yaml": "555855ac7388c2e0",
    "robotiq_2f85.yaml": "f7cae12808cecc68",
}
#: Keys a gripper file may have besides the :class:`GripperSpec` fields.
_FILE_ONLY_KEYS = ("frame",)
_FILE_DEFAULTS = {"min_width": 0.0, "pad_friction": (1.0, 0.005, 0.0001)}
_FRAMES = ("tcp", "base")


def _shape_dict(shape: Shape) -> dict:
    if isinstance(shape, Box):
        return {"size": list(shape.size), "pos": list(shape.pos)}
    return {"vertices": [list(v) for v in shape.vertices]}


def _bundled_names() -> str:
    return ", ".join(sorted(_BUNDLED))


def _mesh_pieces(path: Path, scale: float, where: str) -> list[np.ndarray]:
    """Vertices of the convex hull of each connected component of the mesh file ``path`` (times ``scale``)."""
    import trimesh

    if not path.is_file():
        raise SettingsError(f"{where}: mesh file {path} not found")
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as exc:  # noqa: BLE001 - trimesh raises many types for unreadable files
        raise SettingsError(f"{where}: cannot read mesh file {path} ({type(exc).__name__}: {exc})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise SettingsError(f"{where}: mesh file {path} holds no triangles")
    pieces = []
    for k, part in enumerate(mesh.split(only_watertight=False) or [mesh]):
        part = part.copy()
        part.apply_scale(scale)
        hull = part.convex_hull
        if part.is_watertight and part.volume > 0 and hull.volume > (1.0 + _MAX_HULL_EXCESS) * part.volume:
            raise SettingsError(
                f"{where}: {path} piece {k} is not convex (its hull is {hull.volume / part.volume - 1:.0%} larger); "
                "MuJoCo collides convex hulls, so split it into convex pieces (e.g. with CoACD, as "
                "assets/make_grippers.py does) and list them"
            )
        pieces.append(np.asarray(hull.vertices, dtype=float))
    return pieces


def _shapes(key: str, value: Any, base_dir: Path, shift: np.ndarray) -> list[Shape]:
    """The shapes of a file entry: a box ``{size, pos}``, a mesh file ``{mesh, scale}`` (one piece per connected
    component) or inline ``{vertices}``; ``shift`` moves them from the file's frame to the TCP frame."""
    items = [value] if isinstance(value, Mapping) else value
    if not isinstance(items, (list, tuple)):
        raise SettingsError(f"{key}: must be a list of geoms ({{size, pos}}, {{mesh}} or {{vertices}}), got "
                            f"{_short(value)}")
    out: list[Shape] = []
    for i, item in enumerate(items):
        where = key if isinstance(value, Mapping) else f"{key}[{i}]"
        kinds = {"size": ("size", "pos"), "mesh": ("mesh", "scale"), "vertices": ("vertices",)}
        kind = next((k for k in kinds if isinstance(item, Mapping) and k in item), None)
        if kind is None:
            raise SettingsError(f"{where}: must be a box {{size, pos}}, a mesh file {{mesh, scale}} or "
                                f"{{vertices}}, got {_short(item)}")
        unknown = sorted(set(item) - set(kinds[kind]))
        if unknown:
            raise SettingsError(f"{where}: unknown key {unknown[0]!r}; a {kind} entry has: {', '.join(kinds[kind])}")
        try:
            if kind == "size":
                pos = np.asarray(check_vector("pos", item.get("pos", (0.0, 0.0, 0.0)), 3)) + shift
                out.append(Box(size=item["size"], pos=tuple(pos)))
            elif kind == "vertices":
                vertices = np.asarray(Mesh(item["vertices"]).vertices) + shift
                out.append(Mesh(vertices))
            else:
                name = item["mesh"]
                check("mesh", isinstance(name, str) and bool(name), "be a file name", name)
                scale = check_number("scale", item.get("scale", 1.0), low=0.0, low_open=True)
                path = base_dir / name
                out += [Mesh(v + shift, file=str(path)) for v in _mesh_pieces(path, scale, "mesh")]
        except SettingsError as exc:
            raise SettingsError(f"{where}: {exc}") from None
    return out


_LINKAGE_KEYS = ("pivot", "crank", "follower_pivot", "driver_geoms", "follower_geoms", "driver_mass",
                 "follower_mass")


def _linkage(value: Any, base_dir: Path, shift: np.ndarray) -> Linkage:
    """The :class:`Linkage` of a file's ``linkage`` mapping (pivots moved by ``shift`` into the TCP frame)."""
    if not isinstance(value, Mapping):
        raise SettingsError(f"linkage: must be a mapping ({', '.join(_LINKAGE_KEYS)}), got {_short(value)}")
    unknown = sorted(str(k) for k in set(value) - set(_LINKAGE_KEYS))
    if unknown:
        raise SettingsError(f"linkage.{unknown[0]}: unknown key; valid keys: {', '.join(_LINKAGE_KEYS)}")
    missing = [k for k in ("pivot", "crank", "follower_pivot", "driver_geoms") if k not in value]
    if missing:
        raise SettingsError(f"linkage.{missing[0]}: missing")
    values = dict(value)
    for key in ("pivot", "follower_pivot"):
        x, z = check_vector(f"linkage.{key}", values[key], 2)
        values[key] = (x, z + shift[2])
    for key in ("driver_geoms", "follower_geoms"):
        values[key] = tuple(_shapes(f"linkage.{key}", values.get(key) or [], base_dir, shift))
    return Linkage(**values)


def gripper_from_dict(data: Mapping[str, Any], *, base_dir: str | os.PathLike = ".", file: str = "") -> GripperSpec:
    """A :class:`GripperSpec` from the contents of a gripper file (see :func:`read_gripper`); mesh files are
    relative to ``base_dir``. :class:`SettingsError` names the offending key."""
    if not isinstance(data, Mapping):
        raise SettingsError(f"must be a mapping of gripper settings (name, max_width, ...), got {_short(data)}")
    names = [f.name for f in fields(GripperSpec) if f.name != "file"]
    unknown = sorted(str(k) for k in set(data) - set(names) - set(_FILE_ONLY_KEYS))
    if unknown:
        valid = ", ".join(sorted(names + list(_FILE_ONLY_KEYS)))
        raise SettingsError(f"{unknown[0]}: unknown key; valid keys: {valid}")
    values = {**_FILE_DEFAULTS, **{k: v for k, v in data.items() if k in names}}
    frame = data.get("frame", "tcp")
    check_choice("frame", frame, _FRAMES)
    shift = np.zeros(3)
    if frame == "base":
        shift[2] = -check_number("tcp_offset", values.get("tcp_offset"), low=0.0, low_open=True)
    base = Path(base_dir)
    for key in ("palm_geoms", "finger_geoms"):
        values[key] = tuple(_shapes(key, values.get(key) or [], base, shift))
    if values.get("pad_geom") is not None:
        pad = _shapes("pad_geom", values["pad_geom"], base, shift)
        check("pad_geom", len(pad) == 1, "be one convex piece", f"{len(pad)} pieces")
        values["pad_geom"] = pad[0]
        lo, hi = pad[0].bounds
        values.setdefault("pad_size", tuple(hi - lo))
    if values.get("linkage") is not None:
        values["linkage"] = _linkage(values["linkage"], base, shift)
    boxes = values.get("palm_boxes") or []
    if not isinstance(boxes, (list, tuple)) or not all(isinstance(b, Mapping) and "size" in b for b in boxes):
        raise SettingsError(f"palm_boxes: must be a list of boxes {{size, pos}}, got {_short(boxes)}")
    values["palm_boxes"] = tuple(_shapes("palm_boxes", list(boxes), base, shift))
    if values["finger_geoms"] and "finger_size" not in values:
        pieces = values["finger_geoms"] + ((values["pad_geom"],) if values.get("pad_geom") is not None else ())
        lo, hi = _bounds_of(pieces)
        values["finger_size"] = tuple(hi - lo)
    missing = [f.name for f in fields(GripperSpec)
               if f.name not in values and f.default is MISSING and f.default_factory is MISSING]
    if missing:
        raise SettingsError(f"{missing[0]}: missing (a gripper file needs {', '.join(missing)})")
    return GripperSpec(**values, file=file)


_FILE_CACHE: dict[tuple, GripperSpec] = {}


def read_gripper(path: str | os.PathLike) -> GripperSpec:
    """Read a gripper file: YAML (``.yaml``, ``.yml``) or JSON (``.json``), a mapping of :class:`GripperSpec` fields.

    * Required: ``name``, ``max_width``, ``tcp_offset``, ``force_limit``, ``closing_speed``, ``finger_mass``,
      ``body_mass`` and the geometry; optional: ``min_width`` (0), ``pad_friction`` (1, 0.005, 0.0001),
      ``pad_condim`` (4), ``source``.
    * Geometry, in metres, in the TCP frame (z approach, x closing, origin midway between the pads) or, with
      ``frame: base``, in the hand-base frame (the TCP at ``tcp_offset`` along z); the fingers as they are when
      open (pad separation ``max_width``):

      - boxes by size: ``pad_size``, ``finger_size`` ([thickness x, width y, length z]) and ``palm_boxes``
        (a list of ``{size: [x, y, z], pos: [x, y, z]}``), placed as in :class:`GripperSpec`; or
      - pieces per body: ``palm_geoms`` and ``finger_geoms`` (lists) and ``pad_geom`` (one), each a box
        ``{size, pos}``, a mesh file ``{mesh: hand.obj, scale: 1.0}`` (relative to the gripper file; each connected
        component is one convex piece, a non-convex one is refused) or ``{vertices: [[x, y, z], ...]}``. Give the
        right finger (+x) and its pad; the left one is it turned 180 degrees about z. The pad's contact face
        (its smallest x) must lie at ``max_width / 2``. ``pad_size`` (the contact area) and ``finger_size`` default
        to the pieces' bounding boxes.

    Returns the spec (cached while the file is unchanged). Raises :class:`SettingsError` in one line,
    ``gripper: <path>: <what>``.
    """
    label = os.fspath(path)
    p = Path(label)
    if p.suffix.lower() not in GRIPPER_FILE_SUFFIXES:
        raise SettingsError(f"gripper: {label}: not a gripper file (expected {', '.join(GRIPPER_FILE_SUFFIXES)}); "
                            f"bundled grippers: {_bundled_names()}")
    try:
        stat = p.stat()
        if not p.is_file():
            raise IsADirectoryError(label)
    except OSError:
        raise SettingsError(f"gripper: {label}: no such gripper file; bundled grippers: {_bundled_names()}") from None
    key = (label, str(p.resolve()), stat.st_mtime_ns, stat.st_size)
    if key in _FILE_CACHE:
        return _FILE_CACHE[key]
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SettingsError(f"gripper: {label}: cannot read it ({type(exc).__name__}: {exc})") from None
    try:
        data = json.loads(text) if p.suffix.lower() == ".json" else yaml.safe_load(text)
    except json.JSONDecodeError as exc:
        raise SettingsError(f"gripper: {label}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        problem = " ".join(str(getattr(exc, "problem", None) or exc).split())
        raise SettingsError(f"gripper: {label}: not valid YAML ({problem}{where})") from None
    try:
        spec = gripper_from_dict(data, base_dir=p.parent, file=label)
    except SettingsError as exc:
        raise SettingsError(f"gripper: {label}: {' '.join(str(exc).split())}") from None
    _FILE_CACHE[key] = spec
    return spec


def write_gripper(spec: GripperSpec, path: str | os.PathLike) -> Path:
    """Write ``spec`` as a gripper file (YAML, or JSON for ``.json``) that :func:`read_gripper` reads back into an
    equal spec (meshes written as their vertices). Returns the path."""
    p = Path(path)
    if p.suffix.lower() not in GRIPPER_FILE_SUFFIXES:
        raise SettingsError(f"path: a gripper file ends in {', '.join(GRIPPER_FILE_SUFFIXES)}, got {p.name!r}")
    data = spec.to_dict()
    text = json.dumps(data, indent=1) + "\n" if p.suffix.lower() == ".json" else yaml.safe_dump(data, sort_keys=False)
    p.write_text(text, encoding="utf-8")
    return p


def gripper_files(name_or_path: str | os.PathLike) -> tuple[str, ...]:
    """The files a gripper given by path is read from (its gripper file, then its mesh files), whose bytes a stage
    puts into its content keys; () for a registered name (the bundled files count as code: see
    :data:`BUNDLED_DIGESTS`)."""
    if isinstance(name_or_path, str) and name_or_path in GRIPPERS:
        return ()
    spec = load_gripper(name_or_path)
    files = [spec.file] if spec.file else []
    for piece in spec.pieces:
        if isinstance(piece, Mesh) and piece.file and piece.file not in files:
            files.append(piece.file)
    return tuple(files)


def _read_bundled(name: str) -> GripperSpec:
    spec = read_gripper(GRIPPERS_DIR / _BUNDLED[name])
    if spec.name != name:
        raise SettingsError(f"gripper: {spec.file}: name {spec.name!r} differs from its registry name {name!r}")
    return spec


#: Registered grippers by name, read from their files in ``assets/grippers``.
GRIPPERS: dict[str, GripperSpec] = {name: _read_bundled(name) for name in sorted(_BUNDLED)}
#: The default gripper's name: the Robotiq 2F-85 from its collision meshes and 4-bar linkage (``robotiq_2f85`` is
#: the same hand as boxes, 1.1-1.2x faster per rollout in ``bench/bench_rollouts.py``).
DEFAULT_GRIPPER = "robotiq_2f85_mesh"


def jaw_opening(width, width_margin: float, min_width: float, max_width: float) -> np.ndarray:
    """Pad separation (m) the jaws open to before the approach, for contact width(s) ``width`` (m, scalar or
    ``(n,)``): ``width + width_margin`` clipped to ``[min_width, max_width]``. The pre-filter and the rollout both
    use it, so the jaws checked for collisions are the jaws simulated."""
    return np.clip(np.asarray(width, dtype=float) + width_margin, min_width, max_width)


def is_gripper_path(name: Any) -> bool:
    """Whether ``name`` is meant as a gripper file rather than a registered name: a path object, or a string with a
    gripper-file suffix or a path separator."""
    if isinstance(name, os.PathLike):
        return True
    return isinstance(name, str) and (name.lower().endswith(GRIPPER_FILE_SUFFIXES) or "/" in name or os.sep in name)


def load_gripper(name: str | os.PathLike) -> GripperSpec:
    """The registered :class:`GripperSpec` called ``name``, or the gripper file at path ``name``
    (:func:`read_gripper`); :class:`SettingsError` listing the registered names otherwise."""
    if isinstance(name, str) and name in GRIPPERS:
        return GRIPPERS[name]
    if is_gripper_path(name):
        return read_gripper(name)
    raise SettingsError(f"gripper: unknown {name!r}; choose one of: {', '.join(sorted(GRIPPERS))} (or give the path "
                        f"of a gripper file: {', '.join(GRIPPER_FILE_SUFFIXES)})")


# ---------------------------------------------------------------------------------------------------------------
# Physics options
# ---------------------------------------------------------------------------------------------------------------

_CONES = {"elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC, "pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL}
_INTEGRATORS = {
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
}


@dataclass(frozen=True)
class PhysicsOptions:
    """Simulation settings under which grasps hold (with MuJoCo's defaults, pyramidal cones and impratio 1, a held
    2 kg box creeps out between the pads; see the module docstring)."""

    timestep: float = 0.002
    """Integration step (s)."""
    cone: str = "elliptic"
    """Friction cone: ``"elliptic"`` (exact Coulomb cone) or ``"pyramidal"``."""
    impratio: float = 10.0
    """Frictional-to-normal constraint impedance ratio; > 1 makes friction stiffer (less creep/slip)."""
    integrator: str = "implicitfast"
    """``"implicitfast"`` (implicit damping: stable with the stiff jaw damping), ``"implicit"``, ``"euler"``,
    ``"rk4"``."""
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    """Gravity (m/s^2) in the world frame."""

    def __post_init__(self) -> None:
        check_number("timestep", self.timestep, low=0.0, high=0.05, low_open=True)
        check_choice("cone", self.cone, sorted(_CONES))
        check_number("impratio", self.impratio, low=1.0)
        check_choice("integrator", self.integrator, sorted(_INTEGRATORS))
        object.__setattr__(self, "gravity", check_vector("gravity", self.gravity, 3))

    def apply(self, target: mujoco.MjSpec | mujoco.MjModel):
        """Write these settings into an :class:`mujoco.MjSpec` (``spec.option``) or a compiled :class:`mujoco.MjModel`
        (``model.opt``); returns ``target``."""
        if isinstance(target, mujoco.MjSpec):
            opt = target.option
            opt.timestep = self.timestep
            opt.cone = _CONES[self.cone]
            opt.impratio = self.impratio
            opt.integrator = _INTEGRATORS[self.integrator]
            opt.gravity = list(self.gravity)
        elif isinstance(target, mujoco.MjModel):
            opt = target.opt
            opt.timestep = self.timestep
            opt.cone = int(_CONES[self.cone])
            opt.impratio = self.impratio
            opt.integrator = int(_INTEGRATORS[self.integrator])
            opt.gravity[:] = self.gravity
        else:
            raise TypeError(f"physics options apply to an MjSpec or MjModel, not {type(target).__name__}")
        return target


def physics_options(target: mujoco.MjSpec | mujoco.MjModel, options: PhysicsOptions | None = None):
    """Apply ``options`` (default: :class:`PhysicsOptions()`: 2 ms, elliptic cones, impratio 10, implicitfast) to an
    MjSpec or MjModel; returns ``target``."""
    return (options or PhysicsOptions()).apply(target)


# ---------------------------------------------------------------------------------------------------------------
# Model building
# ---------------------------------------------------------------------------------------------------------------


def _box_inertia(mass: float, full_size) -> list[float]:
    x, y, z = full_size
    return [mass * (y * y + z * z) / 12.0, mass * (x * x + z * z) / 12.0, mass * (x * x + y * y) / 12.0]


def _bounding_box(boxes) -> tuple[np.ndarray, np.ndarray]:
    lo = np.min([np.subtract(b.pos, np.divide(b.size, 2)) for b in boxes], axis=0)
    hi = np.max([np.add(b.pos, np.divide(b.size, 2)) for b in boxes], axis=0)
    return lo, hi


def _set_contact(geom: mujoco.MjsGeom, name: str, *, mode: str, rgba, friction, condim: int) -> mujoco.MjsGeom:
    geom.name = name
    geom.contype = GRIPPER_CONTYPE
    geom.conaffinity = GRIPPER_CONAFFINITY
    geom.group = GRIPPER_GEOM_GROUP
    geom.rgba = list(rgba)
    geom.density = 0.0  # bodies carry explicit inertia
    geom.priority = _FRICTION_MODES[mode]
    geom.friction = [0.0 if mode == "object" else friction[0], friction[1], friction[2]]
    geom.condim = condim
    geom.solref = list(_CONTACT_SOLREF)
    geom.solimp = list(_CONTACT_SOLIMP)
    geom.solmix = _CONTACT_SOLMIX
    return geom


def _add_collision_box(body: mujoco.MjsBody, name: str, full_size, pos, *, mode: str, rgba, friction,
                       condim: int) -> mujoco.MjsGeom:
    geom = body.add_geom()
    geom.type = mujoco.mjtGeom.mjGEOM_BOX
    geom.size = [s / 2.0 for s in full_size]
    geom.pos = list(pos)
    return _set_contact(geom, name, mode=mode, rgba=rgba, friction=friction, condim=condim)


def _add_shape(model: mujoco.MjSpec, body: mujoco.MjsBody, name: str, shape: Shape, *, mode: str, rgba, friction,
               condim: int) -> mujoco.MjsGeom:
    """A :class:`Box` or convex :class:`Mesh` collision geom (the mesh asset is named like the geom)."""
    if isinstance(shape, Box):
        return _add_collision_box(body, name, shape.size, shape.pos, mode=mode, rgba=rgba, friction=friction,
                                  condim=condim)
    mesh = model.add_mesh()
    mesh.name = name
    mesh.uservert = shape.array.reshape(-1).tolist()
    geom = body.add_geom()
    geom.type = mujoco.mjtGeom.mjGEOM_MESH
    geom.meshname = name
    return _set_contact(geom, name, mode=mode, rgba=rgba, friction=friction, condim=condim)


def _pad_face_x(spec: GripperSpec) -> float:
    """x (m) of the right pad's contact face in the open gripper's geometry (``max_width / 2`` for a box pad)."""
    return float(spec.pad_geom.bounds[0][0]) if spec.pad_geom is not None else spec.max_width / 2.0


def _in_jaw(shape: Shape, face_x: float, sign: float) -> Shape:
    """``shape`` (the right finger's, TCP frame, open) in a jaw's body frame (origin: the pad's contact face): moved
    by ``-face_x`` along x and, for the left jaw (``sign`` -1), turned 180 degrees about z."""
    flip = np.array([sign, sign, 1.0])
    if isinstance(shape, Box):
        return Box(size=shape.size, pos=tuple((np.asarray(shape.pos) - [face_x, 0.0, 0.0]) * flip))
    return Mesh((shape.array - [face_x, 0.0, 0.0]) * flip, file=shape.file)


#: Armature of the joints a linkage drives from the jaw slide (the pad's z slide, kg; the links' hinges, kg m^2):
#: small next to the jaw's, enough to keep their coupling constraints' effective mass away from zero.
_LIFT_ARMATURE = 0.05
_LINK_ARMATURE = 1e-4


def _shifted(shape: Shape, offset) -> Shape:
    """``shape`` moved by ``-offset`` (into the frame of a body at ``offset``)."""
    if isinstance(shape, Box):
        return Box(size=shape.size, pos=tuple(np.subtract(shape.pos, offset)))
    return Mesh(shape.array - np.asarray(offset, dtype=float), file=shape.file)


def _add_linkage(spec: GripperSpec, model: mujoco.MjSpec, jaw: mujoco.MjsBody, *, p: str, side: str, sign: float,
                 face_x: float, friction: str, first_piece: int) -> None:
    """The linkage of one jaw: a z slide ``<side>_lift`` on the jaw (the pad's rise), and the driver and follower
    links as child bodies of the jaw hinged where they hold the finger (a link turning about its palm pivot while the
    finger it holds translates is the same as the link turning by the same angle about its joint on the finger).
    Their joints follow the jaw slide through the equalities ``<side>_<joint>_coupling`` (see :func:`_build_into`).
    Link geoms are named ``<side>_finger_<k>`` (finger pieces), so every helper counts them as finger geoms."""
    link = spec.linkage
    flip = np.array([sign, sign, 1.0])
    lift = jaw.add_joint()
    lift.name = f"{p}{side}_lift"
    lift.type = mujoco.mjtJoint.mjJNT_SLIDE
    lift.axis = [0.0, 0.0, 1.0]
    lift.armature = _LIFT_ARMATURE
    k = first_piece
    for name, pivot, geoms, mass in (("driver", link.pivot, link.driver_geoms, link.driver_mass),
                                     ("follower", link.follower_pivot, link.follower_geoms, link.follower_mass)):
        hinge_tcp = np.array([pivot[0] + link.crank[0], 0.0, pivot[1] + link.crank[1]])
        hinge = (hinge_tcp - [face_x, 0.0, 0.0]) * flip  # in the jaw's frame
        body = jaw.add_body()
        body.name = f"{p}{side}_{name}"
        body.pos = list(hinge)
        body.gravcomp = 1.0
        joint = body.add_joint()
        joint.name = f"{p}{side}_{name}"
        joint.type = mujoco.mjtJoint.mjJNT_HINGE
        joint.axis = [0.0, -sign, 0.0]  # closing turns the right crank from +x towards +z: about -y
        joint.armature = _LINK_ARMATURE
        shapes = [_shifted(_in_jaw(g, face_x, sign), hinge) for g in geoms]
        for shape in shapes:
            _add_shape(model, body, f"{p}{side}_finger_{k}", shape, mode=friction, rgba=_FINGER_RGBA,
                       friction=spec.pad_friction, condim=3)
            k += 1
        body.explicitinertial = True
        body.mass = mass
        if shapes:
            lo, hi = _bounds_of(shapes)
            body.ipos = list((lo + hi) / 2.0)
            body.inertia = _box_inertia(mass, hi - lo)
        else:
            body.ipos = [0.0, 0.0, 0.0]
            body.inertia = _box_inertia(mass, [0.01, 0.01, 0.01])


_PALM_RGBA = (0.25, 0.25, 0.28, 1.0)
_PAD_RGBA = (0.85, 0.45, 0.1, 1.0)
_FINGER_RGBA = (0.45, 0.45, 0.5, 1.0)


def _build_into(spec: GripperSpec, parent, *, p: str, friction: str, model: mujoco.MjSpec) -> None:
    """Add the gripper's bodies under ``parent`` (the world body of ``model``); constraints/actuators to ``model``."""
    mocap = parent.add_body()
    mocap.name = f"{p}mocap"
    mocap.mocap = True
    site = mocap.add_site()
    site.name = f"{p}mocap_site"
    site.size = [0.005, 0.005, 0.005]
    site.rgba = [1.0, 0.2, 0.2, 0.3]
    site.group = 5

    base = parent.add_body()
    base.name = f"{p}base"
    base.gravcomp = 1.0
    free = base.add_freejoint()
    free.name = f"{p}free"
    lo, hi = _bounding_box(spec.palm_boxes)
    base.explicitinertial = True
    base.mass = spec.body_mass
    base.ipos = list((lo + hi) / 2.0)
    base.inertia = _box_inertia(spec.body_mass, hi - lo)
    tcp = base.add_site()
    tcp.name = f"{p}tcp"
    tcp.size = [0.004, 0.004, 0.004]
    tcp.rgba = [0.2, 1.0, 0.2, 0.5]
    tcp.group = 5
    if spec.palm_geoms:
        for k, shape in enumerate(spec.palm_geoms):
            _add_shape(model, base, f"{p}palm_{k}", shape, mode=friction, rgba=_PALM_RGBA, friction=spec.pad_friction,
                       condim=3)
    else:
        for k, box in enumerate(spec.palm_boxes):
            _add_collision_box(base, f"{p}palm_{k}", box.size, box.pos, mode=friction, rgba=_PALM_RGBA,
                               friction=spec.pad_friction, condim=3)

    half_open = spec.max_width / 2.0
    pad_t, _, pad_l = spec.pad_size
    fin_t, _, fin_l = spec.finger_size
    face_x = _pad_face_x(spec)
    # The pads' torsional coefficient: derived (module docstring). "object": 0 on the pad, so the object geom's
    # (attach_gripper writes mu_object * r_mean there) governs by MuJoCo's max rule; "pad": the pad's mu * r_mean.
    mu_pad, roll = spec.pad_friction[0], spec.pad_friction[2]
    pad_friction = (mu_pad, object_torsion(spec, mu_pad) if friction == "pad" else 0.0, roll)
    for side, sign in (("left", -1.0), ("right", 1.0)):
        # Body frame = the pad contact face's centre when fully open; the joint's qpos0 (= ref) is max_width / 2.
        jaw = base.add_body()
        jaw.name = f"{p}{side}_jaw"
        jaw.pos = [sign * half_open, 0.0, 0.0]
        jaw.gravcomp = 1.0
        joint = jaw.add_joint()
        joint.name = f"{p}{side}_slide"
        joint.type = mujoco.mjtJoint.mjJNT_SLIDE
        joint.axis = [sign, 0.0, 0.0]
        joint.ref = half_open
        joint.range = [spec.min_width / 2.0, spec.max_width / 2.0]
        joint.limited = mujoco.mjtLimited.mjLIMITED_TRUE
        if np.size(joint.damping) == 3:  # MuJoCo 4: (linear, quadratic, cubic) damping coefficients
            joint.damping = [spec.jaw_damping, 0.0, 0.0]
        else:  # MuJoCo 3: one linear coefficient
            joint.damping = spec.jaw_damping
        joint.armature = _JAW_ARMATURE
        pad_pos = [sign * pad_t / 2.0, 0.0, 0.0]
        fin_pos = [sign * (pad_t + fin_t / 2.0), 0.0, pad_l / 2.0 - fin_l / 2.0]
        jaw.explicitinertial = True
        jaw.mass = spec.finger_mass
        if spec.pad_geom is None and not spec.finger_geoms:
            jaw.ipos = fin_pos
            jaw.inertia = _box_inertia(spec.finger_mass, spec.finger_size)
        if spec.pad_geom is None:
            pad = Box(size=spec.pad_size, pos=pad_pos)
            _add_collision_box(jaw, f"{p}{side}_pad", spec.pad_size, pad_pos, mode=friction, rgba=_PAD_RGBA,
                               friction=pad_friction, condim=spec.pad_condim)
        else:
            pad = _in_jaw(spec.pad_geom, face_x, sign)
            _add_shape(model, jaw, f"{p}{side}_pad", pad, mode=friction, rgba=_PAD_RGBA, friction=pad_friction,
                       condim=spec.pad_condim)
        if not spec.finger_geoms:
            links = [Box(size=spec.finger_size, pos=fin_pos)]
            _add_collision_box(jaw, f"{p}{side}_finger", spec.finger_size, fin_pos, mode=friction,
                               rgba=_FINGER_RGBA, friction=spec.pad_friction, condim=3)
        else:
            links = [_in_jaw(shape, face_x, sign) for shape in spec.finger_geoms]
            for k, shape in enumerate(links):
                _add_shape(model, jaw, f"{p}{side}_finger" + (f"_{k}" if k else ""), shape, mode=friction,
                           rgba=_FINGER_RGBA, friction=spec.pad_friction, condim=3)
        if spec.pad_geom is not None or spec.finger_geoms:  # inertia of the jaw's bounding box
            jlo, jhi = _bounds_of([pad, *links])
            jaw.ipos = list((jlo + jhi) / 2.0)
            jaw.inertia = _box_inertia(spec.finger_mass, jhi - jlo)
        if spec.linkage is not None:
            _add_linkage(spec, model, jaw, p=p, side=side, sign=sign, face_x=face_x, friction=friction,
                         first_piece=len(links))

    tendon = model.add_tendon()
    tendon.name = f"{p}width"
    tendon.wrap_joint(f"{p}left_slide", 1.0)
    tendon.wrap_joint(f"{p}right_slide", 1.0)

    act = model.add_actuator()
    act.name = f"{p}width"
    act.trntype = mujoco.mjtTrn.mjTRN_TENDON
    act.target = f"{p}width"
    act.set_to_position(kp=spec.kp, kv=0.0)
    act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
    act.ctrlrange = [spec.min_width, spec.max_width]
    act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
    act.forcerange = [-spec.force_limit, spec.force_limit]

    couple = model.add_equality()
    couple.name = f"{p}jaw_coupling"
    couple.type = mujoco.mjtEq.mjEQ_JOINT
    couple.objtype = mujoco.mjtObj.mjOBJ_JOINT
    couple.name1 = f"{p}left_slide"
    couple.name2 = f"{p}right_slide"
    couple.data = [0.0, 1.0, 0.0, 0.0, 0.0] + [0.0] * (len(couple.data) - 5)  # q_left - ref = q_right - ref
    couple.solref = list(_WELD_SOLREF)
    couple.solimp = list(_WELD_SOLIMP)

    if spec.linkage is not None:
        for side in ("left", "right"):
            for joint, coef in spec.linkage.couplings(spec.min_width, spec.max_width).items():
                eq = model.add_equality()
                eq.name = f"{p}{side}_{joint}_coupling"
                eq.type = mujoco.mjtEq.mjEQ_JOINT
                eq.objtype = mujoco.mjtObj.mjOBJ_JOINT
                eq.name1 = f"{p}{side}_{joint}"
                eq.name2 = f"{p}{side}_slide"
                eq.data = list(coef) + [0.0] * (len(eq.data) - 5)
                eq.solref = list(_WELD_SOLREF)
                eq.solimp = list(_WELD_SOLIMP)

    weld = model.add_equality()
    weld.name = f"{p}weld"
    weld.type = mujoco.mjtEq.mjEQ_WELD
    weld.objtype = mujoco.mjtObj.mjOBJ_BODY
    weld.name1 = f"{p}base"
    weld.name2 = f"{p}mocap"
    # eq_data of a body weld: anchor (3, in body2 = mocap), relpose pos (3) and quat (4) of body2 in body1,
    # torquescale, and a "relpose from qpos0" flag. add_equality()'s default puts the anchor 1 m away; the TCP body
    # must coincide with the mocap body, so: anchor 0, relpose identity, torquescale 1.
    data = [0.0] * len(weld.data)
    data[6] = 1.0
    data[10] = 1.0
    weld.data = data
    weld.solref = list(_WELD_SOLREF)
    weld.solimp = list(_WELD_SOLIMP)


def build_gripper(spec: GripperSpec, *, name_prefix: str = "gripper/", friction: str = "object") -> mujoco.MjSpec:
    """A stand-alone MjSpec of the floating gripper ``spec``.

    Bodies (names prefixed with ``name_prefix``): ``mocap`` (mocap body, the pose target) and ``base`` (free joint
    ``free``; its frame IS the TCP frame; site ``tcp``) with children ``left_jaw`` / ``right_jaw`` (slide joints
    ``left_slide`` / ``right_slide``). Tendon and actuator ``width`` (ctrl = target pad separation in m), equalities
    ``jaw_coupling`` and ``weld``. At the zero configuration the TCP frame is the world frame and the jaws are open.
    Physics options are set to :class:`PhysicsOptions` defaults. ``friction``: ``"object"`` (the touched object's
    sliding friction governs gripper contacts) or ``"pad"`` (the pads' :attr:`GripperSpec.pad_friction` governs);
    see the module docstring.
    """
    model = _gripper_model(spec, name_prefix=name_prefix, friction=friction)
    physics_options(model)
    return model


def _gripper_model(spec: GripperSpec, *, name_prefix: str, friction: str) -> mujoco.MjSpec:
    if not isinstance(spec, GripperSpec):
        raise TypeError(f"expected a GripperSpec, got {type(spec).__name__}")
    if friction not in _FRICTION_MODES:
        raise ValueError(f"friction: must be one of {sorted(_FRICTION_MODES)}, got {friction!r}")
    model = mujoco.MjSpec()
    model.modelname = spec.name
    model.compiler.degree = False
    _build_into(spec, model.worldbody, p=name_prefix, friction=friction, model=model)
    return model


def attach_gripper(world: mujoco.MjSpec, spec: GripperSpec, *, name_prefix: str = "gripper/",
                   friction: str = "object") -> mujoco.MjsFrame:
    """Attach the floating gripper ``spec`` into ``world`` (a scene spec with ground / objects) via MjSpec attach.

    The gripper is built without a prefix and attached to a new frame at the world origin with
    ``prefix=name_prefix``, so every element is named ``name_prefix + local name`` exactly as in
    :func:`build_gripper` (mocap body and TCP body coincide at the origin; move them with :func:`set_gripper_pose`).
    The gripper spec authors no physics options, so nothing conflicts at attach time: the world's options apply
    (call :func:`physics_options` on the world). Returns the attachment frame.

    With ``friction="object"`` it also writes the pads' derived torsional friction into the world: every geom of a
    body already in ``world`` that can touch the gripper gets torsional coefficient ``mu * pad_torsion_arm(spec)``
    from its own sliding ``mu`` (:func:`set_pad_torsion`; module docstring), so each object of a scene has its own.
    Objects are condim 3, so the value only acts in their condim-4 contacts with the pads.
    """
    if not name_prefix:
        raise ValueError("name_prefix: must be non-empty (it keeps gripper names apart from the scene's)")
    if friction == "object":
        set_pad_torsion(_object_geoms(world), spec)
    child = _gripper_model(spec, name_prefix="", friction=friction)
    frame = world.worldbody.add_frame()
    frame.name = f"{name_prefix}attach"
    world.attach(child, prefix=name_prefix, frame=frame)
    return frame


def pad_torsion_arm(spec: GripperSpec) -> float:
    """Torsional friction arm (m) of a pad: the mean distance of its contact face (``pad_size`` y x z, a rectangle
    of half-sides p, q) from the face's centroid, the moment ``mu F r_mean`` that Coulomb friction under uniform
    pressure resists about the face normal, per unit ``mu F`` (module docstring). Closed form of
    ``(1 / (p q)) int_0^p int_0^q sqrt(x^2 + y^2) dy dx = (2 p q d + p^3 ln((q + d) / p) + q^3 ln((p + d) / q))
    / (6 p q)`` with ``d = sqrt(p^2 + q^2)``; 0.3826 x the side of a square (Panda, 17.4 x 17.6 mm: 6.70 mm)."""
    p, q = spec.pad_size[1] / 2.0, spec.pad_size[2] / 2.0
    d = float(np.hypot(p, q))
    return float((2.0 * p * q * d + p ** 3 * np.log((q + d) / p) + q ** 3 * np.log((p + d) / q)) / (6.0 * p * q))


def object_torsion(spec: GripperSpec, mu: float) -> float:
    """Torsional friction coefficient (m) of a contact of sliding friction ``mu`` with one of ``spec``'s pads:
    ``mu * pad_torsion_arm(spec)`` (module docstring)."""
    return float(mu) * pad_torsion_arm(spec)


def _collides_with_gripper(geom: mujoco.MjsGeom) -> bool:
    return bool((int(geom.contype) & GRIPPER_CONAFFINITY) or (int(geom.conaffinity) & GRIPPER_CONTYPE))


def _object_geoms(world: mujoco.MjSpec) -> list[mujoco.MjsGeom]:
    """The geoms of ``world``'s bodies (not the world body's static geoms: ground, supports) that collide with
    gripper geoms."""
    return [geom for body in world.bodies if body.name != "world" for geom in body.geoms
            if _collides_with_gripper(geom)]


def set_pad_torsion(targets, spec: GripperSpec) -> int:
    """Give each object geom of ``targets`` (``MjsGeom``) the torsional friction its contacts with ``spec``'s pads
    need: :func:`object_torsion` of its own sliding friction (module docstring). Returns how many were set."""
    for geom in targets:
        friction = list(geom.friction)
        geom.friction = [friction[0], object_torsion(spec, friction[0]), friction[2]]
    return len(targets)


# ---------------------------------------------------------------------------------------------------------------
# Runtime helpers (by name, never by index)
# ---------------------------------------------------------------------------------------------------------------


def _id(model: mujoco.MjModel, objtype, name: str) -> int:
    idx = mujoco.mj_name2id(model, objtype, name)
    if idx < 0:
        kind = mujoco.mjtObj(objtype).name.removeprefix("mjOBJ_").lower()
        raise KeyError(f"no {kind} named {name!r} in the model (wrong gripper name_prefix?)")
    return idx


def _pos_quat(T) -> tuple[np.ndarray, np.ndarray]:
    """(position (3,), unit quaternion (4,)) of the rigid transform ``T_tcp``; SettingsError otherwise."""
    T = check_transform("T_tcp", T)
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(T[:3, :3]).reshape(-1))
    return T[:3, 3].copy(), quat


def set_gripper_target(model: mujoco.MjModel, data: mujoco.MjData, T_tcp, *, prefix: str = "gripper/") -> None:
    """Move only the mocap target to TCP pose ``T_tcp`` (4x4, world); the weld pulls the gripper there while
    stepping. Use for smooth motions (approach, lift)."""
    pos, quat = _pos_quat(T_tcp)
    mocap_id = model.body_mocapid[_id(model, mujoco.mjtObj.mjOBJ_BODY, f"{prefix}mocap")]
    data.mocap_pos[mocap_id] = pos
    data.mocap_quat[mocap_id] = quat


def set_gripper_pose(model: mujoco.MjModel, data: mujoco.MjData, T_tcp, *, prefix: str = "gripper/") -> None:
    """Teleport the gripper: put the TCP frame (free joint) AND the mocap target at ``T_tcp`` (4x4, world), zero the
    base velocity, and run ``mj_forward``. Jaw joints are left as they are."""
    pos, quat = _pos_quat(T_tcp)
    set_gripper_target(model, data, T_tcp, prefix=prefix)
    jid = _id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{prefix}free")
    qadr, vadr = model.jnt_qposadr[jid], model.jnt_dofadr[jid]
    data.qpos[qadr:qadr + 3] = pos
    data.qpos[qadr + 3:qadr + 7] = quat
    data.qvel[vadr:vadr + 6] = 0.0
    mujoco.mj_forward(model, data)


def gripper_pose(model: mujoco.MjModel, data: mujoco.MjData, *, prefix: str = "gripper/") -> np.ndarray:
    """Current 4x4 world pose of the TCP frame (needs ``mj_forward``/``mj_step`` to have run)."""
    bid = _id(model, mujoco.mjtObj.mjOBJ_BODY, f"{prefix}base")
    T = np.eye(4)
    T[:3, :3] = data.xmat[bid].reshape(3, 3)
    T[:3, 3] = data.xpos[bid]
    return T


def set_gripper_width(model: mujoco.MjModel, data: mujoco.MjData, width: float, *, prefix: str = "gripper/",
                      instant: bool = False) -> float:
    """Command pad separation ``width`` (m), clipped to ``[min_width, max_width]`` (the actuator's ctrlrange).
    With ``instant=True`` also put the jaws there at once (qpos, zero velocity, ``mj_forward``) -- for opening the
    gripper before it is placed, not for closing on an object. Returns the clipped command."""
    aid = _id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, f"{prefix}width")
    lo, hi = model.actuator_ctrlrange[aid]
    w = float(np.clip(float(width), lo, hi))
    data.ctrl[aid] = w
    if instant:
        for side in ("left", "right"):
            jid = _id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{prefix}{side}_slide")
            data.qpos[model.jnt_qposadr[jid]] = w / 2.0
            data.qvel[model.jnt_dofadr[jid]] = 0.0
        couplings = linkage_couplings(model, prefix=prefix)
        couplings.apply(data.qpos)
        data.qvel[couplings.dofadr] = 0.0
        mujoco.mj_forward(model, data)
    return w


@dataclass(frozen=True)
class LinkageCouplings:
    """The joints a gripper's linkage drives from its jaw slides (the equalities ``<side>_<joint>_coupling``), read
    from a compiled model, to pose them by hand: whoever sets the jaw slides' ``qpos`` directly (placing an open
    gripper, the collision pre-filter) calls :meth:`apply` so that the pads and links sit where the linkage puts
    them. Empty (``apply`` does nothing) for a gripper without a linkage."""

    qposadr: np.ndarray
    """(k,) int: qpos address of each driven joint."""
    dofadr: np.ndarray
    """(k,) int: dof address of each driven joint."""
    slide_qposadr: np.ndarray
    """(k,) int: qpos address of the jaw slide that drives it."""
    ref: np.ndarray
    """(k,) float: each driven joint's reference (``qpos0``; m or rad)."""
    slide_ref: np.ndarray
    """(k,) float: the driving slide's reference (``qpos0``, m)."""
    coef: np.ndarray
    """(k, 5) float: quartic coefficients, ``q - ref = sum coef[j] (q_slide - slide_ref)^j``."""

    def apply(self, qpos: np.ndarray) -> None:
        """Set the driven joints in ``qpos`` (modified in place) from the jaw slides' values there."""
        if len(self.qposadr):
            d = qpos[self.slide_qposadr] - self.slide_ref
            qpos[self.qposadr] = self.ref + self.coef[:, 0] + d * (self.coef[:, 1] + d * (
                self.coef[:, 2] + d * (self.coef[:, 3] + d * self.coef[:, 4])))


def linkage_couplings(model: mujoco.MjModel, *, prefix: str = "gripper/") -> LinkageCouplings:
    """The :class:`LinkageCouplings` of the gripper named ``prefix`` in ``model`` (found by equality names)."""
    rows = []
    for eq in range(model.neq):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_EQUALITY, eq) or ""
        local = name[len(prefix):] if name.startswith(prefix) else ""
        if model.eq_type[eq] != mujoco.mjtEq.mjEQ_JOINT or not re.fullmatch(r"(left|right)_\w+_coupling", local):
            continue
        j1, j2 = int(model.eq_obj1id[eq]), int(model.eq_obj2id[eq])
        q1, q2 = int(model.jnt_qposadr[j1]), int(model.jnt_qposadr[j2])
        rows.append((q1, int(model.jnt_dofadr[j1]), q2, float(model.qpos0[q1]), float(model.qpos0[q2]),
                     np.array(model.eq_data[eq][:5], dtype=float)))
    cols = list(zip(*rows)) if rows else [(), (), (), (), (), ()]
    return LinkageCouplings(
        qposadr=np.array(cols[0], dtype=np.int64), dofadr=np.array(cols[1], dtype=np.int64),
        slide_qposadr=np.array(cols[2], dtype=np.int64), ref=np.array(cols[3], dtype=float),
        slide_ref=np.array(cols[4], dtype=float), coef=np.array(cols[5], dtype=float).reshape(len(rows), 5))


def gripper_width(model: mujoco.MjModel, data: mujoco.MjData, *, prefix: str = "gripper/") -> float:
    """Current pad separation (m): distance between the pads' contact faces along the TCP x axis, from the jaw
    bodies' poses (each jaw's frame is its pad's contact face; needs ``mj_forward``/``mj_step`` to have run)."""
    left = _id(model, mujoco.mjtObj.mjOBJ_BODY, f"{prefix}left_jaw")
    right = _id(model, mujoco.mjtObj.mjOBJ_BODY, f"{prefix}right_jaw")
    x_axis = gripper_pose(model, data, prefix=prefix)[:3, 0]
    return float(np.dot(data.xpos[right] - data.xpos[left], x_axis))


_FINGER_PIECE = re.compile(r"(left|right)_finger_[0-9]+")


def pad_geom_ids(model: mujoco.MjModel, *, prefix: str = "gripper/") -> tuple[tuple[int, ...], tuple[int, ...]]:
    """Geom ids of the (left, right) contact pads, looked up by name."""
    roles = gripper_geom_ids(model, prefix=prefix)
    return roles["left_pad"], roles["right_pad"]


def gripper_geom_ids(model: mujoco.MjModel, *, prefix: str = "gripper/") -> dict[str, tuple[int, ...]]:
    """Geom ids of the gripper by role: ``left_pad``, ``right_pad``, ``pad`` (both), ``finger`` (every piece of both
    finger links), ``palm``, ``all``. Found by name (``<prefix>left_pad``, ``<prefix>left_finger``,
    ``<prefix>left_finger_<k>``, ``<prefix>palm_<k>`` ...), so it works however the gripper was attached."""
    out: dict[str, list[int]] = {"left_pad": [], "right_pad": [], "finger": [], "palm": []}
    for gid in range(model.ngeom):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, gid) or ""
        if not name.startswith(prefix):
            continue
        local = name[len(prefix):]
        if local in ("left_pad", "right_pad"):
            out[local].append(gid)
        elif local in ("left_finger", "right_finger") or _FINGER_PIECE.fullmatch(local):
            out["finger"].append(gid)
        elif local.startswith("palm_"):
            out["palm"].append(gid)
    if not out["left_pad"] or not out["right_pad"]:
        raise KeyError(f"no gripper pads named {prefix}left_pad / {prefix}right_pad in the model")
    res = {k: tuple(v) for k, v in out.items()}
    res["pad"] = res["left_pad"] + res["right_pad"]
    res["all"] = res["pad"] + res["finger"] + res["palm"]
    return res


# ---------------------------------------------------------------------------------------------------------------
# Picture
# ---------------------------------------------------------------------------------------------------------------

#: Pose of the TCP in the picture's world: approach (TCP z) pointing down, closing (TCP x) to the right.
_PICTURE_POSE = np.diag([1.0, -1.0, -1.0, 1.0])
_AXIS_COLOURS = ((220, 30, 30), (30, 160, 30), (40, 70, 230))


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: one bitmap size
        return ImageFont.load_default()


def _picture_frame(spec: GripperSpec) -> tuple[np.ndarray, float]:
    """(centre (3,), size m) of the region the picture shows, in the picture's world (TCP at the origin)."""
    lo, hi = _bounds_of(list(spec.palm_boxes) + [Box(size=spec.finger_size, pos=(0.0, 0.0, 0.0))])
    z_tip = max(spec.pad_size[2] / 2.0, 0.0)
    if spec.pad_geom is not None:
        z_tip = float(spec.pad_geom.bounds[1][2])
    for piece in spec.finger_geoms:
        z_tip = max(z_tip, float(piece.bounds[1][2]))
    z_back = float(min(lo[2], -spec.tcp_offset))
    half_x = max(abs(lo[0]), abs(hi[0]), spec.max_width / 2.0 + spec.finger_size[0] + spec.pad_size[0])
    centre = np.array([0.0, 0.0, -(z_back + z_tip) / 2.0])  # world z = -TCP z
    return centre, max(2.0 * half_x, z_tip - z_back)


def _views(centre: np.ndarray, extent: float, px: int):
    """(title, Camera) of the two views: front (along TCP y: closing left-right, approach down) and three-quarter."""
    import math

    from graspgen.sim.scene_model import Camera, camera_on_sphere, intrinsics_from_fov

    fov = math.radians(30.0)
    distance = 0.62 * extent / math.tan(fov / 2.0) + 0.05
    K = intrinsics_from_fov(px, px, fov)
    return [("front", Camera(K, camera_on_sphere(centre, distance, 0.0, -math.pi / 2), px, px)),
            ("3/4 view", Camera(K, camera_on_sphere(centre, distance, 0.45, -math.pi / 2 + 0.7), px, px))]


def _tcp_axes(draw, camera, length: float) -> None:
    """The TCP frame's axes (x red, y green, z blue) drawn as lines from the TCP origin."""
    from graspgen.sim.scene_model import project, transform_points

    T_cam_world = np.linalg.inv(np.asarray(camera.T_world_camera, dtype=float))
    ends = _PICTURE_POSE[:3, 3] + length * _PICTURE_POSE[:3, :3].T
    points = transform_points(T_cam_world, np.vstack([_PICTURE_POSE[:3, 3], ends]))
    uv = project(camera.K, points)
    font = _font(13)
    for k, name in enumerate("xyz"):
        draw.line([tuple(uv[0]), tuple(uv[k + 1])], fill=_AXIS_COLOURS[k], width=3)
        draw.text((uv[k + 1][0] + 3, uv[k + 1][1] - 7), name, fill=_AXIS_COLOURS[k], font=font)
    r = 3
    draw.ellipse([uv[0][0] - r, uv[0][1] - r, uv[0][0] + r, uv[0][1] + r], fill=(0, 0, 0))


def _render_views(spec: GripperSpec, widths, px: int):
    """MuJoCo renders: {(width, view title): PIL image}. RenderError when OpenGL is unavailable."""
    from PIL import Image, ImageDraw

    from graspgen.sim.scene_model import SceneRenderer

    world = mujoco.MjSpec()
    world.visual.global_.offwidth = px
    world.visual.global_.offheight = px
    light = world.worldbody.add_light()
    light.pos = [0.3, -0.6, 0.8]
    light.dir = [-0.3, 0.6, -0.8]
    attach_gripper(world, spec)
    model = world.compile()
    data = mujoco.MjData(model)
    centre, extent = _picture_frame(spec)
    out = {}
    with SceneRenderer(model, px, px) as renderer:
        for width in widths:
            set_gripper_pose(model, data, _PICTURE_POSE)
            set_gripper_width(model, data, width, instant=True)
            for title, camera in _views(centre, extent, px):
                image = Image.fromarray(renderer.render(data, camera, rgb=True).rgb)
                _tcp_axes(ImageDraw.Draw(image), camera, 0.03)
                out[width, title] = image
    return out


def _wireframe_views(spec: GripperSpec, widths, px: int):
    """Matplotlib drawings of the collision geoms (outlines of each piece's silhouette), same layout as
    :func:`_render_views`: {(width, view title): PIL image}."""
    import io

    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    import matplotlib.ticker
    from PIL import Image
    from scipy.spatial import ConvexHull

    model = build_gripper(spec).compile()
    data = mujoco.MjData(model)
    roles = gripper_geom_ids(model)
    colours = {g: tuple(model.geom_rgba[g][:3]) for g in roles["all"]}
    out = {}
    for width in widths:
        set_gripper_pose(model, data, _PICTURE_POSE)
        set_gripper_width(model, data, width, instant=True)
        for title, axes in (("front", (0, 2)), ("side", (1, 2))):
            fig, ax = plt.subplots(figsize=(px / 100, px / 100), dpi=100)
            for g in roles["all"]:
                R, p = data.geom_xmat[g].reshape(3, 3), data.geom_xpos[g]
                if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
                    m = model.geom_dataid[g]
                    local = model.mesh_vert[model.mesh_vertadr[m]:model.mesh_vertadr[m] + model.mesh_vertnum[m]]
                else:
                    local = np.array(np.meshgrid(*[[-h, h] for h in model.geom_size[g]])).reshape(3, -1).T
                pts = (local @ R.T + p)[:, axes]
                hull = pts[ConvexHull(pts).vertices]
                ax.fill(hull[:, 0], hull[:, 1], color=colours[g], alpha=0.35, lw=1.2, ec=colours[g])
            for k in range(3):
                tip = 0.03 * _PICTURE_POSE[:3, k]
                if np.hypot(tip[axes[0]], tip[axes[1]]) > 1e-6:
                    ax.annotate("", xy=(tip[axes[0]], tip[axes[1]]), xytext=(0, 0),
                                arrowprops={"arrowstyle": "->", "color": np.divide(_AXIS_COLOURS[k], 255), "lw": 2})
                    ax.text(tip[axes[0]], tip[axes[1]], "xyz"[k], color=np.divide(_AXIS_COLOURS[k], 255))
                    ax.update_datalim([(1.3 * tip[axes[0]], 1.3 * tip[axes[1]])])
            ax.autoscale_view()
            ax.set_aspect("equal")
            ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(4))
            ax.set_xlabel(f"world {'xy'[axes[0]]} (m)")
            ax.set_title(title, fontsize=9)
            fig.tight_layout()
            buffer = io.BytesIO()
            fig.savefig(buffer, format="png")
            plt.close(fig)
            out[width, title] = Image.open(io.BytesIO(buffer.getvalue())).convert("RGB").resize((px, px))
    return out


def gripper_picture(spec: GripperSpec, *, size: int = 360, render: bool = True):
    """A PIL image of ``spec`` open (``max_width``) and closed (``min_width``), each from the front (closing axis
    left-right, approach down) and in a three-quarter view, with the TCP frame (x red, y green, z blue) and a caption
    (name, stroke, TCP offset, force, geometry).

    Drawn by MuJoCo's offscreen renderer (the collision geoms: palm dark grey, finger links grey, pads orange); with
    ``render=False``, or when no OpenGL back end is available, a matplotlib drawing of the geoms' silhouettes
    (front and side) instead, which the caption says.
    """
    from PIL import Image, ImageDraw

    from graspgen.errors import RenderError

    widths = (spec.max_width, spec.min_width)
    how = "MuJoCo render"
    try:
        if not render:
            raise RenderError("rendering off")
        views = _render_views(spec, widths, size)
    except RenderError as exc:
        views = _wireframe_views(spec, widths, size)
        how = "wireframe of the collision geoms" + ("" if not render else f" (no rendering: {exc})")
    titles = list(dict.fromkeys(t for _, t in views))
    top, label_h = 58, 20
    sheet = Image.new("RGB", (size * len(titles), top + len(widths) * (size + label_h)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    geometry = "convex meshes" if spec.uses_meshes else "boxes"
    draw.text((6, 4), f"{spec.name}" + (f"  ({spec.file})" if spec.file else ""), fill=(0, 0, 0), font=_font(16))
    draw.text((6, 24), f"stroke {spec.min_width * 1e3:.0f}-{spec.max_width * 1e3:.0f} mm, TCP {spec.tcp_offset:.4g} m "
              f"from the hand base along z, force {spec.force_limit:.0f} N, {spec.closing_speed:.2g} m/s; {geometry}",
              fill=(0, 0, 0), font=_font(12))
    draw.text((6, 40), f"{how}; TCP frame: x closing (red), y (green), z approach (blue); pads orange",
              fill=(80, 80, 80), font=_font(12))
    for row, width in enumerate(widths):
        y = top + row * (size + label_h)
        state = "open" if row == 0 else "closed"
        for col, title in enumerate(titles):
            draw.text((col * size + 6, y + 3), f"{state}, width {width * 1e3:.0f} mm, {title}", fill=(0, 0, 0),
                      font=_font(13))
            sheet.paste(views[width, title], (col * size, y + label_h))
    return sheet
