"""The MuJoCo model of a floating parallel-jaw gripper, built from its spec (:mod:`graspgen.grippers`):
:func:`build_gripper`, :func:`attach_gripper`, and the pads' derived torsional friction.

Modelling, the same for every gripper (the frames: :mod:`graspgen.grippers`; posing and reading a compiled
model: :mod:`graspgen.sim.gripper_state`):

* **Linkage.** With a :class:`~graspgen.grippers.Linkage` (``robotiq_2f85_mesh``) each jaw also has a z slide
  ``<side>_lift`` and carries its two links as hinged child bodies (``<side>_driver``, ``<side>_follower``: a link
  turning about its palm pivot while the finger translates is the link turning by the same angle about its joint on
  the finger), every one of those joints tied to the jaw slide by a quartic joint equality
  ``<side>_<joint>_coupling`` fitted to the linkage's circle. The jaw slide stays the one driven coordinate, so
  everything below holds for both kinds; whoever sets the slides' qpos by hand applies
  :func:`graspgen.sim.gripper_state.linkage_couplings` too.
* **Jaw joint coordinate = half the width.** Each jaw's slide joint ``q`` is the distance of its pad's contact face
  from the TCP plane x = 0, so pad separation (width) = ``q_left + q_right``; range ``[min_width, max_width] / 2``,
  ``qpos0 = max_width / 2`` (a freshly built gripper is open).
* **Symmetric drive.** A fixed tendon ``width = q_left + q_right`` is driven by one position actuator whose control is
  the target width in metres (``ctrl = width`` gives pad separation ``width`` when nothing is in the way);
  ``ctrlrange = [min_width, max_width]`` so larger/smaller commands are clipped. A joint equality ``q_left = q_right``
  keeps the jaws centred on the TCP. The actuator force acts on each jaw (tendon coefficients 1), and
  ``forcerange = +-force_limit``: a jaw closing on an object squeezes it with at most ``force_limit`` newtons
  (the position gain saturates at 2 mm of width error, ``GripperSpec.kp``, so closing on an object -- command
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
  constant 5 ms). ``set_gripper_pose`` teleports both, so a new grasp pose starts with zero error.
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
  - the **pads' condim** (``pad_condim``) acts as a floor, so pad contacts have torsional friction even with
    condim-3 objects; their torsional coefficient on objects is derived (below), ``pad_friction[1:]`` is the floor
    of their other contacts;
  - the **gripper's stiff contact softness** governs (solref 4 ms, solimp 0.95/0.99, via ``solmix`` = 1e6): MuJoCo's
    softness is mass-normalised, and with the default solref (20 ms) a 100 N grip on a 0.1 kg box sinks ~7 mm into
    each pad; with the stiff setting (and the jaw armature) it is ~0.1-0.3 mm.

  ``friction="pad"`` gives gripper geoms priority 1 instead: the pads' full ``pad_friction`` (e.g. 1.0), condim
  and solref govern, and the object's friction is ignored for gripper contacts.

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
  overwrites them). Caveat, measured (:mod:`graspgen.workflows.mechanics`): MuJoCo 4 (multiccd) gives a pad several
  contact points on a flat face (the Panda's mesh pad 3, a box pad 4 at its corners), whose sliding friction
  resists torsion too; the Panda's pivot threshold lands within 4 % of ``mu F r_mean``, box pads resist 35-40 %
  more. Rolling friction is not derived: the bundled pads are condim 4 (a flat pad resists tipping by shifting its
  pressure, not by friction), so rolling is the larger of the two geoms' values, as before, and unused.
  With ``LiftParams.pad_torsion = "patch"`` (the default; ``"face"`` keeps the whole face) the simulator replaces
  the whole face by the pressure of the patch the object presses once the jaws have closed
  (:mod:`graspgen.sim.pad_patch`): the pads then carry the value and the objects 0 until then. Each pad has a box
  site ``<prefix><side>_face`` on its contact face.

Physics settings that hold objects (timestep 2 ms, elliptic cones, impratio 10, implicitfast):
:mod:`graspgen.sim.physics`.

MuJoCo note: with :meth:`mujoco.MjSpec.attach` the order of actuators/joints/geoms depends on the order of attachment,
so every helper here looks elements up by *name* (``name_prefix`` + local name), never by index.
"""

from __future__ import annotations

import mujoco
import numpy as np

from graspgen.errors import SettingsError
from graspgen.grippers import Box, GripperSpec, Mesh, Shape
from graspgen.grippers.shapes import bounds_of
from graspgen.sim import gripper_import  # noqa: F401 - derives grippers given as robot models (gripper files' model:)
from graspgen.sim.pad_patch import rectangle_arm
from graspgen.sim.physics import physics_options
from graspgen.validation import check_choice, check_instance

__all__ = [
    "GRIPPER_CONTYPE",
    "GRIPPER_CONAFFINITY",
    "GRIPPER_GEOM_GROUP",
    "build_gripper",
    "attach_gripper",
    "pad_torsion_arm",
    "object_torsion",
    "set_pad_torsion",
]

#: Contact bitmasks of every gripper geom: collide with default geoms (contype = conaffinity = 1: objects, ground),
#: never with each other (2 & 1 == 0 both ways).
GRIPPER_CONTYPE = 2
GRIPPER_CONAFFINITY = 1
#: Geom group of every gripper geom (MuJoCo's viewer shows groups 0-2 by default).
GRIPPER_GEOM_GROUP = 2
#: Site group of the pads' face sites (hidden in the viewer's default groups).
_FACE_SITE_GROUP = 5
#: Half thickness (m) of the face sites (MuJoCo refuses a zero size).
_FACE_SITE_HALF_THICKNESS = 1e-4

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
            lo, hi = bounds_of(shapes)
            body.ipos = list((lo + hi) / 2.0)
            body.inertia = _box_inertia(mass, hi - lo)
        else:
            body.ipos = [0.0, 0.0, 0.0]
            body.inertia = _box_inertia(mass, [0.01, 0.01, 0.01])


_PALM_RGBA = (0.25, 0.25, 0.28, 1.0)
_PAD_RGBA = (0.85, 0.45, 0.1, 1.0)
_FINGER_RGBA = (0.45, 0.45, 0.5, 1.0)


def _add_mocap(parent, p: str) -> None:
    """The mocap body ``<p>mocap`` (the pose target) with its marker site."""
    mocap = parent.add_body()
    mocap.name = f"{p}mocap"
    mocap.mocap = True
    site = mocap.add_site()
    site.name = f"{p}mocap_site"
    site.size = [0.005, 0.005, 0.005]
    site.rgba = [1.0, 0.2, 0.2, 0.3]
    site.group = 5


def _add_base(spec: GripperSpec, parent, *, p: str, friction: str, model: mujoco.MjSpec) -> mujoco.MjsBody:
    """The TCP body ``<p>base`` (free joint, palm inertia, site ``<p>tcp``) and its palm geoms ``<p>palm_<k>``."""
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
    return base


def _add_jaw_slide(spec: GripperSpec, base: mujoco.MjsBody, *, p: str, side: str, sign: float) -> mujoco.MjsBody:
    """The jaw body ``<p><side>_jaw`` and its slide joint ``<p><side>_slide``. Body frame = the pad contact face's
    centre when fully open; the joint's qpos0 (= ref) is max_width / 2."""
    half_open = spec.max_width / 2.0
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
    _add_face_site(spec, jaw, p=p, side=side)
    return jaw


def _add_face_site(spec: GripperSpec, jaw: mujoco.MjsBody, *, p: str, side: str) -> None:
    """The box site ``<p><side>_face`` on the pad's contact face (the jaw's frame), half sizes ``(t, width / 2,
    length / 2)`` of ``pad_size`` (t: a token thickness): where :mod:`graspgen.sim.pad_patch` casts its rays."""
    face = jaw.add_site()
    face.name = f"{p}{side}_face"
    face.type = mujoco.mjtGeom.mjGEOM_BOX
    face.size = [_FACE_SITE_HALF_THICKNESS, spec.pad_size[1] / 2.0, spec.pad_size[2] / 2.0]
    face.group = _FACE_SITE_GROUP


def _add_jaw(spec: GripperSpec, base: mujoco.MjsBody, *, p: str, side: str, sign: float, friction: str,
             pad_friction, face_x: float, model: mujoco.MjSpec) -> None:
    """One jaw: its slide, pad ``<p><side>_pad``, finger geoms ``<p><side>_finger[_<k>]``, inertia and linkage."""
    jaw = _add_jaw_slide(spec, base, p=p, side=side, sign=sign)
    pad_t, _, pad_l = spec.pad_size
    fin_t, _, fin_l = spec.finger_size
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
        jlo, jhi = bounds_of([pad, *links])
        jaw.ipos = list((jlo + jhi) / 2.0)
        jaw.inertia = _box_inertia(spec.finger_mass, jhi - jlo)
    if spec.linkage is not None:
        _add_linkage(spec, model, jaw, p=p, side=side, sign=sign, face_x=face_x, friction=friction,
                     first_piece=len(links))


def _add_drive(spec: GripperSpec, model: mujoco.MjSpec, *, p: str) -> None:
    """The tendon ``<p>width`` (q_left + q_right) and the position actuator ``<p>width`` that drives it."""
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


def _add_couplings(spec: GripperSpec, model: mujoco.MjSpec, *, p: str) -> None:
    """The joint equalities: ``<p>jaw_coupling`` (q_left = q_right) and a linkage's ``<p><side>_<joint>_coupling``."""
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


def _add_weld(model: mujoco.MjSpec, *, p: str) -> None:
    """The weld ``<p>weld`` that ties the TCP body to the mocap body."""
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


def _build_into(spec: GripperSpec, parent, *, p: str, friction: str, model: mujoco.MjSpec) -> None:
    """Add the gripper's bodies under ``parent`` (the world body of ``model``); constraints/actuators to ``model``.
    The order of the elements is part of the model (MuJoCo numbers them in the order they are added)."""
    _add_mocap(parent, p)
    base = _add_base(spec, parent, p=p, friction=friction, model=model)
    face_x = _pad_face_x(spec)
    # The pads' torsional coefficient: derived (module docstring). "object": 0 on the pad, so the object geom's
    # (attach_gripper writes mu_object * r_mean there) governs by MuJoCo's max rule; "pad": the pad's mu * r_mean.
    mu_pad, roll = spec.pad_friction[0], spec.pad_friction[2]
    pad_friction = (mu_pad, object_torsion(spec, mu_pad) if friction == "pad" else 0.0, roll)
    for side, sign in (("left", -1.0), ("right", 1.0)):
        _add_jaw(spec, base, p=p, side=side, sign=sign, friction=friction, pad_friction=pad_friction,
                 face_x=face_x, model=model)
    _add_drive(spec, model, p=p)
    _add_couplings(spec, model, p=p)
    _add_weld(model, p=p)


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
    check_instance("spec", spec, GripperSpec)
    check_choice("friction", friction, sorted(_FRICTION_MODES))
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
        raise SettingsError("name_prefix: must be non-empty (it keeps gripper names apart from the scene's)")
    if friction == "object":
        set_pad_torsion(_object_geoms(world), spec)
    child = _gripper_model(spec, name_prefix="", friction=friction)
    frame = world.worldbody.add_frame()
    frame.name = f"{name_prefix}attach"
    world.attach(child, prefix=name_prefix, frame=frame)
    return frame


def pad_torsion_arm(spec: GripperSpec) -> float:
    """Torsional friction arm (m) of a pad: the mean distance of its contact face (``pad_size`` y x z) from the
    face's centroid, the moment ``mu F r_mean`` that Coulomb friction under uniform pressure resists about the face
    normal, per unit ``mu F`` (module docstring; :func:`graspgen.sim.pad_patch.rectangle_arm`; Panda, 17.4 x 17.6 mm:
    6.70 mm)."""
    return rectangle_arm(spec.pad_size[1] / 2.0, spec.pad_size[2] / 2.0)


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
