"""Grippers as data, and the MuJoCo model of a floating parallel-jaw gripper built from that data.

Frames (ARCHITECTURE.md, Conventions). A grasp pose is the 4x4 transform of the gripper's tool centre point (TCP) frame:

* origin: midpoint between the two finger pads (between their contact faces, half-way along the pads);
* z: approach direction (palm -> object);
* x: closing direction (the line between the pads; the *right* pad sits on +x, the *left* pad on -x);
* y = z cross x.

The hand base (the robot flange for the 2F-85, the hand frame for the Panda) sits at ``-tcp_offset`` along z.

Modelling, the same for every gripper:

* **Two prismatic jaws.** Every gripper is a parallel-jaw gripper whose two jaws slide along +-x. The real Robotiq
  2F-85 closes its fingers with a 4-bar linkage; its pads stay parallel but also travel along z (about 1 cm over the
  stroke) and the linkage sweeps outwards when open. We neglect both: pads move along x only and the links are
  approximated by one box per finger. Geometry is boxes only (no meshes can be downloaded here).
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
  ``<prefix>right_pad``, ``<prefix>left_finger``, ``<prefix>right_finger``, ``<prefix>palm_<k>``.
* **Contact parameters: who sets what.** MuJoCo has no per-material-pair friction; it combines two geoms' parameters
  by *priority* (the higher-priority geom's friction, condim, solref, solimp win) and, at equal priority, takes the
  element-wise maximum friction, the maximum condim, and a ``solmix``-weighted average of solref/solimp.
  ``build_gripper(friction="object")`` (the default) uses this so that

  - the **object's sliding friction** governs gripper-object contacts: gripper geoms have priority 0 (like objects)
    and sliding friction 0, so max(0, mu_object) = mu_object. A scene's per-object friction is what the simulation
    uses: a 0.01-friction box slips out of the pads, a 0.8 one is lifted;
  - the **pads' torsional/rolling friction and condim** (:attr:`GripperSpec.pad_friction` [1:], :attr:`pad_condim`)
    act as a floor, so pad contacts have torsional friction even with condim-3 objects;
  - the **gripper's stiff contact softness** governs (solref 4 ms, solimp 0.95/0.99, via ``solmix`` = 1e6): MuJoCo's
    softness is mass-normalised, and with the default solref (20 ms) a 100 N grip on a 0.1 kg box sinks ~7 mm into
    each pad; with the stiff setting (and the jaw armature) it is ~0.1-0.3 mm.

  ``friction="pad"`` gives gripper geoms priority 1 instead: the pads' full :attr:`pad_friction` (e.g. 1.0),
  condim and solref govern, and the object's friction is ignored for gripper contacts.

Physics settings that hold objects (measured): timestep 2 ms, elliptic friction cones, impratio 10, implicitfast
(:class:`PhysicsOptions`). With MuJoCo's defaults (pyramidal cones, impratio 1) held objects creep: measured here, a
2 kg box (friction 0.5) slides ~7 mm down between the 2F-85's pads during a 1.5 s lift-and-hold, < 1 mm with ours.

MuJoCo note: with :meth:`mujoco.MjSpec.attach` the order of actuators/joints/geoms depends on the order of attachment,
so every helper here looks elements up by *name* (``name_prefix`` + local name), never by index.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import mujoco
import numpy as np

from graspgen.errors import SettingsError
from graspgen.validation import check, check_choice, check_number, check_transform, check_vector

__all__ = [
    "Box",
    "GripperSpec",
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


@dataclass(frozen=True)
class GripperSpec:
    """A parallel-jaw gripper, as data. All lengths in metres, in the TCP frame (see the module docstring)."""

    name: str
    """Registry name, e.g. ``"robotiq_2f85"``."""
    min_width: float
    """Smallest pad separation (m): distance between the two pads' contact faces when fully closed."""
    max_width: float
    """Largest pad separation (m) when fully open (the stroke is ``max_width - min_width``)."""
    pad_size: tuple[float, float, float]
    """Full extents (m) of each contact pad box: (thickness along x, width along y, length along z). The pad's
    contact face is its inner x face; pads are centred at y = 0, z = 0 of the TCP frame."""
    pad_friction: tuple[float, float, float]
    """MuJoCo friction of the pads: (sliding [-], torsional [m], rolling [m]). With ``build_gripper(friction="pad")``
    all three govern pad contacts; with the default ``friction="object"`` the sliding coefficient is replaced by the
    object's and the torsional/rolling ones act as a floor (see the module docstring)."""
    finger_size: tuple[float, float, float]
    """Full extents (m) of each finger link box: (thickness along x, width along y, length along z). The box sits
    directly behind (outside) its pad and its tip is flush with the pad's tip (z = pad length / 2)."""
    palm_boxes: tuple[Box, ...]
    """Collision boxes of the palm / hand body, fixed in the TCP frame (behind the fingers, at negative z)."""
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
        boxes = tuple(self.palm_boxes)
        check("palm_boxes", bool(boxes) and all(isinstance(b, Box) for b in boxes), "be a non-empty sequence of Box",
              self.palm_boxes)
        object.__setattr__(self, "palm_boxes", boxes)
        check("source", isinstance(self.source, str), "be a string", self.source)

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

    def to_dict(self) -> dict:
        """Plain-data view (for logs / metadata files)."""
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "palm_boxes":
                value = [{"size": list(b.size), "pos": list(b.pos)} for b in value]
            elif isinstance(value, tuple):
                value = list(value)
            out[f.name] = value
        return out


# Robotiq 2F-85. Public data sheet / instruction manual: stroke 0-85 mm, grip force 20-235 N (adjustable), closing
# speed 20-150 mm/s, mass 0.925 kg. Geometry from the public MuJoCo Menagerie 2F-85 model (open configuration):
# pads 22 mm wide x 37.5 mm long x 8 mm thick, pad centre ~0.141 m from the mount flange; base housing up to
# ~0.066 m above the flange; linkage masses ~0.06 kg per finger.
_ROBOTIQ_2F85 = GripperSpec(
    name="robotiq_2f85",
    min_width=0.0,
    max_width=0.085,
    pad_size=(0.008, 0.022, 0.0375),
    pad_friction=(1.0, 0.005, 0.0001),
    finger_size=(0.012, 0.022, 0.0935),  # tip at z = +0.01875, root at the palm's lower face (z = -0.075)
    palm_boxes=(Box(size=(0.085, 0.045, 0.065), pos=(0.0, 0.0, -0.1075)),),  # flange (z = -0.14) .. z = -0.075
    tcp_offset=0.14,
    force_limit=100.0,
    finger_mass=0.06,
    body_mass=0.8,
    closing_speed=0.15,
    source=("Robotiq 2F-85 data sheet: stroke 85 mm, grip force 20-235 N (we use 100 N, a mid setting), speed "
            "20-150 mm/s (we use the maximum), 0.925 kg. Pads/links/housing sizes approximated as boxes after the "
            "MuJoCo Menagerie 2F-85 model; 4-bar linkage replaced by prismatic jaws (pads stay parallel; their "
            "~1 cm z travel over the stroke is neglected)."),
)

# Franka Emika Panda hand, in ACRONYM's gripper frame (z approach, x closing; TCP 0.1034 m from the hand frame).
# Franka data sheet: travel 80 mm, continuous grip force 70 N (140 N peak), ~0.73 kg; franka_gripper's maximum
# width speed 0.1 m/s. Fingers from z = 0.0584 (hand frame) to the tips at ~0.112 (ACRONYM's gripper marker);
# fingertip pads ~18 x 18 mm, 8 mm thick (MuJoCo Menagerie's fingertip pad boxes: 17 x 17 x 8 mm).
_PANDA = GripperSpec(
    name="panda",
    min_width=0.0,
    max_width=0.08,
    pad_size=(0.008, 0.018, 0.018),
    pad_friction=(1.0, 0.005, 0.0001),
    finger_size=(0.010, 0.020, 0.054),  # tip at +0.009 (hand z 0.1124), root at -0.045 (hand z 0.0584)
    palm_boxes=(Box(size=(0.18, 0.06, 0.0584), pos=(0.0, 0.0, -0.1034 + 0.0292)),),  # hand z 0 .. 0.0584
    tcp_offset=0.1034,
    force_limit=70.0,
    finger_mass=0.015,
    body_mass=0.7,
    closing_speed=0.1,
    source=("Franka Emika Panda hand data sheet: 80 mm travel, 70 N continuous force, 0.73 kg; ACRONYM's gripper "
            "frame and TCP offset (0.1034 m); finger/pad boxes after ACRONYM's franka gripper marker and MuJoCo "
            "Menagerie's fingertip pads; the hand body approximated by one bounding box."),
)

# A simple test gripper: two box jaws and one palm box, nothing borrowed from a real device.
_BOX_JAW = GripperSpec(
    name="box_jaw",
    min_width=0.0,
    max_width=0.1,
    pad_size=(0.01, 0.03, 0.04),
    pad_friction=(1.0, 0.005, 0.0001),
    finger_size=(0.01, 0.03, 0.08),  # tip at +0.02, root at -0.06
    palm_boxes=(Box(size=(0.16, 0.04, 0.04), pos=(0.0, 0.0, -0.08)),),  # z -0.1 .. -0.06
    tcp_offset=0.1,
    force_limit=100.0,
    finger_mass=0.05,
    body_mass=0.5,
    closing_speed=0.2,
    source="Synthetic test gripper: two box jaws (0-100 mm) and one palm box.",
)

#: Registered grippers by name.
GRIPPERS: dict[str, GripperSpec] = {g.name: g for g in (_BOX_JAW, _PANDA, _ROBOTIQ_2F85)}
#: The default gripper's name.
DEFAULT_GRIPPER = "robotiq_2f85"


def jaw_opening(width, width_margin: float, min_width: float, max_width: float) -> np.ndarray:
    """Pad separation (m) the jaws open to before the approach, for contact width(s) ``width`` (m, scalar or
    ``(n,)``): ``width + width_margin`` clipped to ``[min_width, max_width]``. The pre-filter and the rollout both
    use it, so the jaws checked for collisions are the jaws simulated."""
    return np.clip(np.asarray(width, dtype=float) + width_margin, min_width, max_width)


def load_gripper(name: str) -> GripperSpec:
    """The registered :class:`GripperSpec` called ``name``; :class:`SettingsError` listing the choices otherwise."""
    try:
        return GRIPPERS[name]
    except (KeyError, TypeError):
        raise SettingsError(f"gripper: unknown {name!r}; choose one of: {', '.join(sorted(GRIPPERS))}") from None


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


def _add_collision_box(body: mujoco.MjsBody, name: str, full_size, pos, *, mode: str, rgba, friction,
                       condim: int) -> mujoco.MjsGeom:
    geom = body.add_geom()
    geom.name = name
    geom.type = mujoco.mjtGeom.mjGEOM_BOX
    geom.size = [s / 2.0 for s in full_size]
    geom.pos = list(pos)
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
    for k, box in enumerate(spec.palm_boxes):
        _add_collision_box(base, f"{p}palm_{k}", box.size, box.pos, mode=friction, rgba=(0.25, 0.25, 0.28, 1.0),
                           friction=spec.pad_friction, condim=3)

    half_open = spec.max_width / 2.0
    pad_t, _, pad_l = spec.pad_size
    fin_t, _, fin_l = spec.finger_size
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
        jaw.ipos = fin_pos
        jaw.inertia = _box_inertia(spec.finger_mass, spec.finger_size)
        _add_collision_box(jaw, f"{p}{side}_pad", spec.pad_size, pad_pos, mode=friction,
                           rgba=(0.85, 0.45, 0.1, 1.0), friction=spec.pad_friction, condim=spec.pad_condim)
        _add_collision_box(jaw, f"{p}{side}_finger", spec.finger_size, fin_pos, mode=friction,
                           rgba=(0.45, 0.45, 0.5, 1.0), friction=spec.pad_friction, condim=3)

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
    """
    if not name_prefix:
        raise ValueError("name_prefix: must be non-empty (it keeps gripper names apart from the scene's)")
    child = _gripper_model(spec, name_prefix="", friction=friction)
    frame = world.worldbody.add_frame()
    frame.name = f"{name_prefix}attach"
    world.attach(child, prefix=name_prefix, frame=frame)
    return frame


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
        mujoco.mj_forward(model, data)
    return w


def gripper_width(model: mujoco.MjModel, data: mujoco.MjData, *, prefix: str = "gripper/") -> float:
    """Current pad separation (m): distance between the pads' contact faces along the TCP x axis, from the pad
    geoms' poses (needs ``mj_forward``/``mj_step`` to have run)."""
    left = _id(model, mujoco.mjtObj.mjOBJ_GEOM, f"{prefix}left_pad")
    right = _id(model, mujoco.mjtObj.mjOBJ_GEOM, f"{prefix}right_pad")
    x_axis = gripper_pose(model, data, prefix=prefix)[:3, 0]
    centres = float(np.dot(data.geom_xpos[right] - data.geom_xpos[left], x_axis))
    return centres - float(model.geom_size[left][0] + model.geom_size[right][0])


def pad_geom_ids(model: mujoco.MjModel, *, prefix: str = "gripper/") -> tuple[tuple[int, ...], tuple[int, ...]]:
    """Geom ids of the (left, right) contact pads, looked up by name."""
    roles = gripper_geom_ids(model, prefix=prefix)
    return roles["left_pad"], roles["right_pad"]


def gripper_geom_ids(model: mujoco.MjModel, *, prefix: str = "gripper/") -> dict[str, tuple[int, ...]]:
    """Geom ids of the gripper by role: ``left_pad``, ``right_pad``, ``pad`` (both), ``finger`` (both fingers),
    ``palm``, ``all``. Found by name (``<prefix>left_pad`` ...), so it works however the gripper was attached."""
    out: dict[str, list[int]] = {"left_pad": [], "right_pad": [], "finger": [], "palm": []}
    for gid in range(model.ngeom):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, gid) or ""
        if not name.startswith(prefix):
            continue
        local = name[len(prefix):]
        if local in ("left_pad", "right_pad"):
            out[local].append(gid)
        elif local in ("left_finger", "right_finger"):
            out["finger"].append(gid)
        elif local.startswith("palm_"):
            out["palm"].append(gid)
    if not out["left_pad"] or not out["right_pad"]:
        raise KeyError(f"no gripper pads named {prefix}left_pad / {prefix}right_pad in the model")
    res = {k: tuple(v) for k, v in out.items()}
    res["pad"] = res["left_pad"] + res["right_pad"]
    res["all"] = res["pad"] + res["finger"] + res["palm"]
    return res
