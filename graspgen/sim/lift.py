"""The grasp-and-lift protocol in MuJoCo and its outcome labels (ARCHITECTURE.md, Conventions).

:class:`LiftSimulator` takes a compiled scene (ground / support geoms, free object bodies, a floating gripper attached
with :func:`graspgen.sim.grippers.attach_gripper`) and rolls out grasps in it: place the gripper at the pre-grasp pose,
approach, close under a force limit, lift, hold, shake (on by default; ``LiftParams.shake``), and label what happened
with one of six outcome codes (:class:`Outcome`). The rules are written out in :class:`LiftSimulator`'s docstring.

Frames: a grasp is the 4x4 world pose of the gripper's TCP frame (origin midway between the pads, z = approach
direction palm -> object, x = closing direction; the *left* jaw sits on -x, the *right* on +x) and a pad separation
``width`` in metres (:mod:`graspgen.sim.grippers`).

Speed (``bench/bench_rollouts.py``; 2F-85 on the bundled box / can, one core): a successful rollout is ~990 steps
(1.98 s simulated: 0.15 s approach, ~0.12 s closing, 0.5 s lift, 0.2 s hold, 2 x 0.5 s shake; ~490 without the
shake); failures stop earlier. Most of a rollout is waiting, so the protocol keeps simulated time short and stops as
soon as a rule decides, and it keeps Python out of the step loop: the mocap target is written once per step only
while the gripper moves (a row copy, ~1 us against ~15 us per step), closing and holding run as
``mj_step(model, data, nstep=check_interval)``, and the rules are checked once per ``check_interval`` steps on cached
ids and views (squared distances and cosines, no allocation beyond a few small temporaries). Measured: 90-130
rollouts/s with the default shake (160-240 without), within 1.12x of the bare ``mj_step`` cost of the same steps.

Protocols (:data:`PROTOCOLS`, ``LiftParams.protocol``): ``table`` is the pipeline's grasp-and-lift above (the default;
with ``shake=False`` its results are what they were before protocols were named, and before the shake was on by
default); ``acronym`` is ACRONYM's free-space test: the hand is
placed at the grasp with open fingers and closes on the floating object, then gravity comes on along the approach
axis, the hand shakes along and about its own axes, and the label is whether the object is still between the fingers
(:class:`AcronymParams` cites where each number comes from). On the calibration mug (``bench/fidelity.py``) a held
object takes ~650-950 steps (0.2-0.8 s closing from fully open, 1 s of shaking, 0.1 s settle), ~50 rollouts/s.
``graspgen`` is GraspDataGen's (the data generator of NVIDIA's GraspGen) free-space tug test: gravity off, the open
hand at the grasp closes, then the object is pulled with its own weight along the hand's approach axis and four
directions tilted 63.4 degrees from it, 0.5 s each; the label is whether both fingers still touch it
(:class:`GraspGenParams` cites the source).

Determinism: every rollout starts from ``mj_resetData`` (which also clears the solver's warm start) plus the saved
initial ``qpos``, so a rollout's result depends only on its inputs, not on earlier rollouts in the same
:class:`LiftSimulator`; no wall clock, no threads, no global random state.
"""

from __future__ import annotations

import copy
import dataclasses
import enum
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Literal

import mujoco
import numpy as np

from graspgen.sim.grippers import PhysicsOptions, jaw_opening, linkage_couplings, pad_geom_ids
from graspgen.sim.prefilter import TARGET_TOUCH_DEPTH, touch_allowance
from graspgen.validation import (
    check,
    check_bool,
    check_choice,
    check_instance,
    check_int,
    check_number,
    check_transform,
    check_vector,
)

__all__ = [
    "Outcome",
    "OUTCOME_NAMES",
    "PHASES",
    "PROTOCOLS",
    "AcronymParams",
    "GraspGenParams",
    "LiftParams",
    "RolloutResult",
    "LiftSimulator",
]


class Outcome(enum.IntEnum):
    """Outcome codes of a grasp-and-lift rollout (the research report's codes; ARCHITECTURE.md, Conventions)."""

    COLLISION_WITH_GROUND = 0
    COLLISION_WITH_TARGET = 1
    COLLISION_WITH_CLUTTER = 2
    NO_CONTACT_ESTABLISHED = 3
    SLIPPED_DURING_LIFTING = 4
    SUCCESS = 5


#: Outcome name by code: ``OUTCOME_NAMES[code]``.
OUTCOME_NAMES: tuple[str, ...] = tuple(o.name.lower() for o in Outcome)

#: Phases of a rollout, in order; :attr:`RolloutResult.decided_in` is one of them (``"end"``: all phases ran).
PHASES: tuple[str, ...] = ("placement", "approach", "closing", "lifting", "holding", "shaking", "end")

#: The named protocols (:attr:`LiftParams.protocol`): ``table`` (the pipeline's grasp-and-lift, the default),
#: ``acronym`` (ACRONYM's free-space close-and-shake, :class:`AcronymParams`) and ``graspgen`` (GraspDataGen's
#: free-space tug test, :class:`GraspGenParams`).
PROTOCOLS: tuple[str, ...] = ("table", "acronym", "graspgen")

# Geom roles (index = outcome code for a gripper contact with such a geom during placement/approach).
_SUPPORT, _TARGET, _CLUTTER, _GRIPPER = 0, 1, 2, 3
# Gripper geom sides.
_LEFT, _RIGHT, _PALM, _NOT_GRIPPER = 0, 1, 2, -1


# ---------------------------------------------------------------------------------------------------------------
# Argument checks (programmer errors -> SettingsError, a ValueError, naming the argument)
# ---------------------------------------------------------------------------------------------------------------


def _pos_quat(name: str, T) -> tuple[np.ndarray, np.ndarray]:
    """(position (3,), unit quaternion (4,)) of a 4x4 rigid transform; SettingsError naming ``name`` otherwise."""
    T = check_transform(name, T)
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(T[:3, :3]).reshape(-1))
    return T[:3, 3].copy(), quat


# ---------------------------------------------------------------------------------------------------------------
# Parameters
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class AcronymParams:
    """Settings of the ``acronym`` protocol (``LiftParams(protocol="acronym")``): ACRONYM's free-space
    close-and-shake (Eppner, Mousavian, Fox, "ACRONYM: A Large-Scale Grasp Dataset Based on Simulation", ICRA 2021,
    arXiv:2011.09584; labels made with NVIDIA FleX).

    What comes from where:

    * **ACRONYM (the paper and its files)**: the object floats in free space, no support; the gripper is a free,
      position-controlled body placed *at* the grasp pose with its fingers open (the files' ``gripper/configuration``
      is 0.04 m per finger: the Panda fully open); the fingers close under a velocity controller until a force
      threshold is reached or the hand is fully closed; then the hand shakes: up and down along its approach
      direction (TCP z), then it rotates about a line parallel to the fingers' prismatic axes (TCP x, taken through
      the TCP); the label is whether the object is still in contact with both fingers. Object friction 1.0 and
      density 150 kg/m^3 come with the files (``gen evaluate`` reads them). The paper publishes no amplitude,
      frequency, duration, closing speed, force threshold or gravity setting.
    * **The nearest published numbers**: a public FleX grasping scene of the same group (it reads ACRONYM's JSON
      grasp format; YuMi gripper) places the object relative to a hand in a fixed world orientation, sets gravity
      to zero, closes at 0.02 m/s under a 10 N motor limit until 20 N of total contact force, shakes 3 cycles per
      axis of 2 s each (0.5 Hz): +-1 cm along the vertical, then +-pi/32 rad about the closing axis, and waits 5 s.
      Its linear shake peaks at ~0.1 m/s^2 (0.01 g). We keep its order (linear, then angular) and its ratio of
      rotation to translation (pi/32 rad per cm), not its magnitudes: with no gravity and a 0.01 g shake nothing
      loads a grasp, and a frictionless object would stay "held".
    * **Ours, by physical argument** (not fitted to the calibration labels): gravity is switched on when the
      fingers have closed, along the approach axis (``gravity="approach"``): the object hangs from a top-down grasp,
      the direction ACRONYM's "up and down along its approach direction" names; while closing it floats (FleX's
      free space). On top of it the linear shake peaks at ~1 g (``shake_amplitude`` 0.015 m at 4 Hz: peak
      1.05 * 0.015 * (2 pi 4)^2 = 9.9 m/s^2, peak speed 0.38 m/s, within a Franka arm's Cartesian limits of
      13 m/s^2 and 1.7 m/s), so the grasp must carry between 0 and 2 g: twice the object's weight at the peak, the
      safety factor of 2 used when sizing a gripper's force for a pick with acceleration. The rotation keeps the
      FleX ratio (``shake_angle`` 0.15 rad: peak 99 rad/s^2, i.e. 1 g tangential 10 cm from the axis, ACRONYM
      objects' typical half size). 4 Hz keeps the hand within 13 mm / 7.5 degrees of the grasp pose and far below
      the bandwidth of the hand's weld (5 ms time constant); 2 cycles per axis is the fewest for which the
      Hann-windowed sine swings fully both ways. Grip force: the Panda's rated continuous force (70 N, the gripper
      model's ``force_limit``); closing speed: the gripper model's (Panda: 0.1 m/s of width, franka_gripper's
      maximum).

    Rules: the open hand touching the target at placement -> 1 collision_with_target (any other geom: 0 / 2 as in
    the table protocol); after closing, not both jaws on the target -> 3 no_contact_established; during the shake
    and the settle, neither jaw touching the target -> 4 (the object left the hand; decided in ``shaking`` /
    ``holding``, the rollout stops); at the end both jaws touching -> 5 success, else 4.
    """

    open_width: float | None = None
    """Pad separation (m) the jaws open to at placement; null: the gripper's ``max_width`` (ACRONYM's fingers are
    fully open)."""
    grip_force: float | None = None
    """Force (N) each jaw presses with; null: the gripper model's ``force_limit`` (the Panda's rated 70 N). The
    table protocol's ``grip_force`` does not apply here."""
    closing_speed: float | None = None
    """Width rate (m/s) of the closing jaws; null: the gripper model's (Panda 0.1 m/s). The jaw damping is set to
    ``2 * grip_force / closing_speed``."""
    gravity: Literal["approach", "off", "world"] = "approach"
    """Gravity, switched on when closing ends (the object floats while the fingers close, as in FleX's free space):
    ``approach``: the scene's gravity magnitude along the grasp's approach axis (TCP +z at the grasp), i.e. the
    object hangs from a top-down grasp, the "up and down along its approach direction" of ACRONYM's shake;
    ``world``: the scene's gravity vector; ``off``: none at any time (the FleX scene above)."""
    shake_amplitude: float = 0.015
    """Peak displacement (m) of the shake along the TCP z (approach) axis (peak acceleration ~ 1.05 *
    amplitude * (2 pi frequency)^2: ~1 g by default)."""
    shake_angle: float = 0.15
    """Peak rotation (rad) of the shake about the TCP x (closing) axis through the TCP."""
    shake_frequency: float = 4.0
    """Frequency (Hz) of both shakes (each a sine under a Hann window: starts and ends at rest)."""
    shake_cycles: int = 2
    """Oscillations per shake axis (linear first, then angular)."""
    settle_time: float = 0.1
    """Time (s) the hand holds still after the shake before the label is read (an object on its way out has left
    the fingers by then)."""
    contact_solref: tuple[float, float] | None = None
    """Gripper contact softness (MuJoCo solref: time constant s, damping ratio) written into every gripper geom;
    null keeps the gripper model's (4 ms, 1.0)."""
    contact_solimp: tuple[float, float, float, float, float] | None = None
    """Gripper contact impedance (MuJoCo solimp: dmin, dmax, width m, midpoint, power); null keeps the gripper
    model's (0.95, 0.99, 0.001, 0.5, 2)."""
    torsional_friction: float | None = None
    """Torsional friction coefficient (m) of the pad contacts (written into the pads and, as MuJoCo takes the larger
    of two geoms' values, into every other geom); null keeps the models' (pads and objects 0.005 m). 0 also makes
    the pads condim 3: point contacts that cannot resist rotation about their line."""

    def __post_init__(self) -> None:
        for key in ("open_width", "grip_force", "closing_speed"):
            if getattr(self, key) is not None:
                object.__setattr__(self, key, check_number(key, getattr(self, key), low=0.0, low_open=True))
        for key in ("shake_amplitude", "shake_angle", "settle_time"):
            object.__setattr__(self, key, check_number(key, getattr(self, key), low=0.0))
        object.__setattr__(self, "shake_frequency", check_number("shake_frequency", self.shake_frequency, low=0.0,
                                                                 low_open=True))
        object.__setattr__(self, "shake_cycles", check_int("shake_cycles", self.shake_cycles, low=1))
        check_choice("gravity", self.gravity, ("approach", "off", "world"))
        if self.contact_solref is not None:
            object.__setattr__(self, "contact_solref", tuple(float(v) for v in check_vector(
                "contact_solref", self.contact_solref, 2, low=0.0, low_open=True)))
        if self.contact_solimp is not None:
            solimp = tuple(float(v) for v in check_vector("contact_solimp", self.contact_solimp, 5, low=0.0))
            check("contact_solimp", 0 < solimp[0] <= solimp[1] < 1 and solimp[2] > 0 and 0 < solimp[3] < 1
                  and solimp[4] >= 1, "be (dmin, dmax, width, midpoint, power) with 0 < dmin <= dmax < 1, width > 0, "
                  "0 < midpoint < 1, power >= 1", self.contact_solimp)
            object.__setattr__(self, "contact_solimp", solimp)
        if self.torsional_friction is not None:
            object.__setattr__(self, "torsional_friction", check_number("torsional_friction",
                                                                        self.torsional_friction, low=0.0))

    def to_dict(self) -> dict:
        """Plain-data view (for configs and metadata)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


#: GraspDataGen's tug directions, (x, y, z) before normalising, in its order (``default_tug_sequences``).
_GRASPDATAGEN_TUGS = ((0.0, 0.0, 1.0), (0.0, 2.0, 1.0), (0.0, -2.0, 1.0), (2.0, 0.0, 1.0), (-2.0, 0.0, 1.0))


@dataclass(frozen=True)
class GraspGenParams:
    """Settings of the ``graspgen`` protocol (``LiftParams(protocol="graspgen")``): the grasp validation of
    GraspDataGen, the data generator published with NVIDIA's GraspGen (Murali et al., "GraspGen: A Diffusion-based
    Framework for 6-DOF Grasping", arXiv:2507.13097; github.com/NVlabs/GraspDataGen, ``scripts/graspgen/grasp_sim.py``,
    Isaac Lab / PhysX).

    What comes from where:

    * **GraspDataGen's ``grasp_sim.py`` (its defaults)**: the simulation runs with gravity disabled
      (``gravity_enabled=False``, and ``disable_gravity=True`` on the object) and no ground, i.e. in free space; the
      gripper's root is placed at the origin and the object at the inverse of the grasp transform, so the world frame
      is the hand's frame; the gripper starts at its pre-grasp joint positions and its joints are driven to the
      closing limit (stiffness 4000, damping 200) for ``initial_grasp_duration`` = 1.0 s; then ``tug_sequences``
      pull the object: ``[[0.5, [0, 0, 1], 1.0], [0.5, [0, 2, 1], 1.0], [0.5, [0, -2, 1], 1.0], [0.5, [2, 0, 1],
      1.0], [0.5, [-2, 0, 1], 1.0]]`` (duration s, direction normalised, scale), a constant external force at the
      object's centre of mass of ``force_magnitude`` (1.0, in g) x gravity magnitude x object mass, i.e. the
      object's own weight, held fixed in the world (the hand's) frame while the object turns. The directions are
      +z (the approach axis of its grippers, ``approach_axis`` 2: out through the fingertips) and four tilted
      atan(2) = 63.4 degrees from it towards +-y and +-x. Physics at 250 Hz (4 ms). A grasp succeeds when the
      object is still in the grasp at the end: both finger colliders' contact sensors report contact with the
      object (NVlabs' version; some forks read a 5 cm drift of the object in the hand instead). Read from the
      public copies of the script (NVIDIA's file in forks of the repository), which agree on these defaults.
    * **Mapped onto our simulator**: the force is applied with ``xfrc_applied`` on the target body (MuJoCo applies it
      at the centre of mass), in the world frame, along the TCP frame's axes at the grasp pose (the hand is held
      there by its weld): z approach, x closing, y = z x x. GraspDataGen's x / y are its gripper file's axes; which
      one closes depends on the gripper, so we take x = closing; both signs of each are applied, so only the order
      of the two tilted pairs could differ. The hand is placed *at* the grasp with the jaws fully open
      (``open_width``; GraspDataGen's pre-grasp joint positions come from its grasp-guess step, which opens the
      gripper to its open limit), and, as in the ``acronym`` protocol, a hand touching anything there is a
      collision (GraspDataGen's guesses are collision-free by construction, so the rule only labels what it never
      simulates).
    * **Ours, by physical argument** (the source gives no such number): the grip force is the gripper model's rated
      force (``grip_force``; GraspDataGen's is whatever its USD drive saturates at), closing at the model's speed;
      closing ends when the jaws have stopped (``LiftParams.close_speed_tol`` / ``close_timeout``, at least the time
      to close fully from open) instead of after a fixed 1 s: with gravity off and no load nothing happens in the
      rest of that second but contact settling. No settle time after the last tug: the label is read when the last
      force ends, as GraspDataGen does.

    Rules: the open hand touching the target at placement -> 1 collision_with_target (any other geom: 0 / 2 as in
    the table protocol); after closing, not both jaws on the target -> 3 no_contact_established; during the tugs
    (phase ``shaking``), neither jaw touching the target -> 4 (it left the hand; the rollout stops); at the end
    both jaws touching -> 5 success, else 4 (decided in ``end``). ``motion_shaking_*`` measure the tug.
    """

    open_width: float | None = None
    """Pad separation (m) the jaws open to at placement; null: the gripper's ``max_width``."""
    grip_force: float | None = None
    """Force (N) each jaw presses with; null: the gripper model's ``force_limit``."""
    closing_speed: float | None = None
    """Width rate (m/s) of the closing jaws; null: the gripper model's. The jaw damping is set to
    ``2 * grip_force / closing_speed``."""
    force_scale: float = 1.0
    """Tug force in multiples of the object's weight (mass x the scene's gravity magnitude; GraspDataGen's
    ``force_magnitude`` 1.0 x each sequence's scale 1.0)."""
    tug_time: float = 0.5
    """Duration (s) of each of the five tugs (GraspDataGen: 0.5 s each)."""
    tug_tilt: float = math.atan(2.0)
    """Angle (rad) of the four tilted tugs from the approach axis (GraspDataGen's (0, +-2, 1), (+-2, 0, 1):
    atan(2) = 1.107 rad = 63.4 degrees)."""

    def __post_init__(self) -> None:
        for key in ("open_width", "grip_force", "closing_speed"):
            if getattr(self, key) is not None:
                object.__setattr__(self, key, check_number(key, getattr(self, key), low=0.0, low_open=True))
        object.__setattr__(self, "force_scale", check_number("force_scale", self.force_scale, low=0.0))
        object.__setattr__(self, "tug_time", check_number("tug_time", self.tug_time, low=0.0, low_open=True))
        object.__setattr__(self, "tug_tilt", check_number("tug_tilt", self.tug_tilt, low=0.0, high=math.pi))

    def directions(self) -> np.ndarray:
        """``(5, 3)`` unit tug directions in the TCP frame (x closing, y, z approach), in order: +z, then tilted
        towards +y, -y, +x, -x."""
        c, s = math.cos(self.tug_tilt), math.sin(self.tug_tilt)
        return np.array([[0.0, 0.0, 1.0]] + [[s * x / 2.0, s * y / 2.0, c] for x, y, _ in _GRASPDATAGEN_TUGS[1:]])

    def to_dict(self) -> dict:
        """Plain-data view (for configs and metadata)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class LiftParams:
    """Protocol, outcome thresholds and physics settings of a grasp-and-lift rollout.

    The defaults are tuned on the Robotiq 2F-85 (``tests/test_lift.py``): a 1 kg box at friction 0.5 must be lifted
    and held, a 3 kg box at friction 0.3 must slip. Coulomb says the first needs a grip of 1 kg x (9.81 + 5 m/s^2 of
    lift acceleration) / (2 x 0.5) = 14.8 N per jaw for the lift and 1 kg x (9.81 + 9.9 m/s^2) / (2 x 0.5) = 19.7 N
    for the default shake's ~1 g peak, and the second 49 N just to hold still and 98.6 N through the shake. Measured
    without the shake, the 1 kg box is held from 14 N on and the 3 kg box slips up to 60 N (held from 65 N); with the
    default shake the 1 kg box slides 20 / 6 / 1 mm in the hand at 14 / 16 / 18 N (held: less than
    ``slip_tolerance``) and 0.1 mm from 20 N on, and the 3 kg box is shaken out up to 70 N (held from 80 N, still
    sliding 6 mm there, 0.4 mm at 100 N). ``grip_force`` = 30 N sits between the edges (1.5x the 1 kg box's
    Coulomb grip through the shake, 0.3x the 3 kg box's; the 2F-85 grips with 20-235 N).

    The ``table`` protocol disturbs the grasp after the hold by default (``shake``): ACRONYM's shake (Eppner,
    Mousavian, Fox, ICRA 2021, arXiv:2011.09584), with the numbers and the argument of :class:`AcronymParams`
    (``shake_*`` below say which).

    ``protocol`` names the phase sequence (:data:`PROTOCOLS`): ``table`` (default; every field below but
    ``acronym`` and ``graspgen``), ``acronym`` (its own settings in ``acronym``) or ``graspgen`` (its own settings
    in ``graspgen``); of the fields below these two use the closing stop (``close_speed_tol``, ``close_timeout``),
    ``check_interval`` and the physics. :meth:`with_protocol` switches.
    """

    # -- protocol ---------------------------------------------------------------------------------------------------
    protocol: Literal["table", "acronym", "graspgen"] = "table"
    """``table``: place at the pre-grasp pose, approach, close, lift, hold, shake (``shake``, on by default), on a
    support or in free space (the pipeline's protocol). ``acronym``: ACRONYM's free-space protocol, placed at the
    grasp with the jaws open, close, shake along and about the hand's axes, label = object still between the
    fingers (:class:`AcronymParams`)."""
    acronym: AcronymParams = field(default_factory=AcronymParams)
    """Settings of the ``acronym`` protocol (ignored by the others)."""
    graspgen: GraspGenParams = field(default_factory=GraspGenParams)
    """Settings of the ``graspgen`` protocol (ignored by the others): gravity off, close, then tug the object with
    its own weight along the approach and four tilted directions; held if both fingers still touch it."""

    # -- approach ---------------------------------------------------------------------------------------------------
    approach_distance: float = 0.05
    """Pre-grasp offset (m): the gripper is placed this far back along the TCP's -z (approach) axis from the grasp
    pose and moves along +z to it."""
    approach_speed: float = 0.5
    """Peak TCP speed (m/s) of the approach (trapezoidal speed profile)."""
    approach_acceleration: float = 10.0
    """Acceleration and deceleration (m/s^2) of the approach profile; the gripper arrives at rest."""
    width_margin: float = 0.02
    """The jaws open to ``width + width_margin`` (m) pad separation before the approach (clipped to the gripper's
    ``[min_width, max_width]``), i.e. ``width_margin / 2`` of clearance per side."""

    # -- closing ----------------------------------------------------------------------------------------------------
    grip_force: float | None = 30.0
    """Force (N) each jaw presses with when closed on an object: the width actuator's force limit. The jaw damping
    is rescaled with it so the jaws still close at the gripper's own closing speed. None keeps the gripper model's
    ``force_limit`` (100 N for the 2F-85, which also holds a 3 kg box at friction 0.3)."""
    close_speed_tol: float = 0.005
    """Closing ends when the pad separation changed slower than this (m/s), averaged over one check interval: the
    jaws have stopped (on the object, or fully closed)."""
    close_timeout: float = 1.0
    """Closing ends after at most this (s) even if the jaws still move (the 2F-85 closes fully in 0.57 s)."""

    # -- lift, hold, shake ------------------------------------------------------------------------------------------
    lift_height: float = 0.2
    """The TCP is lifted straight up (world +z) by this (m) after closing."""
    lift_speed: float = 0.5
    """Peak speed (m/s) of the lift (trapezoidal profile)."""
    lift_acceleration: float = 5.0
    """Acceleration and deceleration (m/s^2) of the lift profile (what the grip must resist on top of gravity)."""
    hold_time: float = 0.2
    """Time (s) the gripper holds still at the top before the shake starts (or, with ``shake`` off, before the
    outcome is judged)."""
    shake: bool = True
    """ACRONYM's shake after the hold, on by default (the disturbance of the ``table`` protocol): ``shake_cycles``
    oscillations of the TCP along world z (linear acceleration against the grip's friction), then as many about the
    TCP x (closing) axis through the TCP (angular acceleration, resisted only by the pads' torsional friction, the
    weak axis of a two-finger grasp); the slip rules are checked throughout. ACRONYM (Eppner et al., ICRA 2021,
    arXiv:2011.09584) shakes "up and down along the approach direction", then rotates about the fingers' axis, and
    publishes no magnitudes; the numbers below are :class:`AcronymParams`' (its docstring gives the sources and the
    argument): the order and rotation-to-translation ratio of the group's public FleX grasping scene, and a ~1 g
    peak so that the grip carries 0-2 g, twice the object's weight at the peak. Here the linear shake is along world
    z, i.e. along gravity, as the ``acronym`` protocol's is along its approach-axis gravity, so the same argument
    holds. Costs 2 x ``shake_cycles / shake_frequency`` s (500 steps at 2 ms by default). False: lift and hold
    only (what the protocol did by default before)."""
    shake_amplitude: float = 0.015
    """Peak displacement (m) of the vertical shake; :attr:`AcronymParams.shake_amplitude`. Peak acceleration ~
    1.05 * amplitude * (2 pi frequency)^2 = 9.9 m/s^2 (~1 g) at 4 Hz, peak speed 0.38 m/s (within a Franka arm's
    Cartesian limits of 13 m/s^2 and 1.7 m/s)."""
    shake_angle: float = 0.15
    """Peak rotation (rad) of the rotational shake about the TCP x axis; :attr:`AcronymParams.shake_angle`: the FleX
    scene's pi/32 rad per cm of linear amplitude, 99 rad/s^2 at the peak (1 g tangential 10 cm from the axis)."""
    shake_frequency: float = 4.0
    """Frequency (Hz) of both shakes; :attr:`AcronymParams.shake_frequency`. Each is a sine under a Hann window, so
    it starts and ends at rest."""
    shake_cycles: int = 2
    """Oscillations per shake axis; :attr:`AcronymParams.shake_cycles` (the fewest for which the Hann-windowed sine
    swings fully both ways)."""

    # -- outcome thresholds -----------------------------------------------------------------------------------------
    target_touch_fails: bool = False
    """Strict touch rule: at placement and during the approach any finger contact that presses into the target is
    a collision (code 1). False (default): the touch rule shared with the pre-filter
    (:data:`graspgen.sim.prefilter.TARGET_TOUCH_DEPTH`): a finger may press up to 2 mm into the target, the palm not
    at all. The pre-filter has no strict mode, so with True a rollout's code 1 is stricter than the pre-filter's."""
    max_target_shift: float = 0.005
    """During placement/approach the target's centre of mass may move at most this (m) from its initial position;
    more is a collision with the target (code 1). Other objects moving more is a collision with clutter (code 2)."""
    max_target_turn: float = math.radians(5.0)
    """As ``max_target_shift``, for rotation (rad)."""
    min_lift_fraction: float = 0.5
    """After lift/hold/shake the target's centre of mass must have risen by at least this fraction of
    ``lift_height`` since the end of closing; less is a slip (code 4)."""
    slip_tolerance: float = 0.02
    """From the end of closing on, the target's centre of mass may move at most this (m) in the TCP frame; more is
    a slip (code 4). Checked at every check interval, so the rollout stops when the object falls."""
    slip_rotation_tolerance: float = math.radians(20.0)
    """As ``slip_tolerance``, for the target's rotation relative to the TCP frame (rad)."""
    firm_translation: float = 0.005
    """Firm-hold tolerance (m): a success is also *firm* (:attr:`RolloutResult.firm`) when the target's centre of
    mass never moved more than this in the TCP frame from the end of closing to the end of the disturbance
    (:attr:`RolloutResult.max_rel_translation`, the largest displacement at any check, not only at the end). 5 mm
    is the project's own threshold for "the object moved" (``max_target_shift``), under a third of the Panda's
    17.6 mm pad face (a contact that moves less stays on the patch it closed on) and about the accuracy a
    place-on-a-surface or drop-into-a-bin step plans with; a quarter of ``slip_tolerance`` (which labels a drop)."""
    firm_rotation: float = math.radians(5.0)
    """Firm-hold tolerance (rad) for the target's rotation relative to the TCP frame, likewise the largest over
    the disturbance (:attr:`RolloutResult.max_rel_rotation`). 5 degrees is ``max_target_turn``, the project's
    threshold for "the object turned"; it moves a point 10 cm from the pivot (ACRONYM objects' typical half size)
    by 8.7 mm, the order of ``firm_translation``. A bottle held by its neck that swings 30-50 degrees round the
    pinch and stays between the fingers is held (code 5) but not firm."""

    # -- mode and pacing --------------------------------------------------------------------------------------------
    gravity_until_closed: bool = False
    """Free-space evaluation (ACRONYM): gravity is off during placement, approach and closing (objects float where
    they are; no support needed) and switched on for lift, hold and shake."""
    check_interval: int = 10
    """The rules are checked every this many steps (10 x 2 ms = 20 ms), not every step: fewer Python round trips.
    Contacts that begin and end between two checks are not seen (a graze that moves nothing)."""

    # -- physics (written into the simulator's copy of the model) ---------------------------------------------------
    timestep: float = 0.002
    """Integration step (s)."""
    cone: str = "elliptic"
    """Friction cone, ``"elliptic"`` or ``"pyramidal"`` (elliptic: no creep of held objects, ARCHITECTURE.md,
    Conventions)."""
    impratio: float = 10.0
    """Ratio of frictional to normal constraint impedance (> 1 makes friction stiffer, held objects do not creep)."""
    noslip_iterations: int = 0
    """MuJoCo's post-solver no-slip iterations (0 = off; costs ~30-40% more per step, not needed with the above)."""
    iterations: int = 100
    """Maximum main-solver iterations per step (the Newton solver usually converges in a few)."""
    ls_iterations: int = 50
    """Maximum line-search iterations per solver iteration."""
    integrator: str = "implicitfast"
    """``"implicitfast"`` (implicit in the stiff jaw damping), ``"implicit"``, ``"euler"`` or ``"rk4"``."""

    def __post_init__(self) -> None:
        check_choice("protocol", self.protocol, PROTOCOLS)
        check_instance("acronym", self.acronym, AcronymParams)
        check_instance("graspgen", self.graspgen, GraspGenParams)
        for key in ("approach_distance", "width_margin", "lift_height", "hold_time", "shake_amplitude",
                    "shake_angle", "max_target_shift", "max_target_turn", "slip_tolerance",
                    "slip_rotation_tolerance", "firm_translation", "firm_rotation"):
            object.__setattr__(self, key, check_number(key, getattr(self, key), low=0.0))
        for key in ("approach_speed", "approach_acceleration", "close_speed_tol", "close_timeout", "lift_speed",
                    "lift_acceleration", "shake_frequency", "timestep"):
            object.__setattr__(self, key, check_number(key, getattr(self, key), low=0.0, low_open=True))
        if self.grip_force is not None:
            object.__setattr__(self, "grip_force", check_number("grip_force", self.grip_force, low=0.0,
                                                                low_open=True))
        object.__setattr__(self, "min_lift_fraction",
                           check_number("min_lift_fraction", self.min_lift_fraction, low=0.0, high=1.0))
        object.__setattr__(self, "shake", check_bool("shake", self.shake))
        object.__setattr__(self, "gravity_until_closed", check_bool("gravity_until_closed",
                                                                    self.gravity_until_closed))
        object.__setattr__(self, "shake_cycles", check_int("shake_cycles", self.shake_cycles, low=1))
        object.__setattr__(self, "check_interval", check_int("check_interval", self.check_interval, low=1))
        object.__setattr__(self, "noslip_iterations", check_int("noslip_iterations", self.noslip_iterations, low=0))
        object.__setattr__(self, "iterations", check_int("iterations", self.iterations, low=1))
        object.__setattr__(self, "ls_iterations", check_int("ls_iterations", self.ls_iterations, low=1))
        self.physics_options((0.0, 0.0, -9.81))  # validates timestep, cone, impratio, integrator (names the field)

    def physics_options(self, gravity) -> PhysicsOptions:
        """These physics settings as :class:`graspgen.sim.grippers.PhysicsOptions`, with the scene's ``gravity``."""
        return PhysicsOptions(timestep=self.timestep, cone=self.cone, impratio=self.impratio,
                              integrator=self.integrator, gravity=tuple(float(g) for g in gravity))

    def with_protocol(self, protocol: str) -> LiftParams:
        """A copy with ``protocol`` set (the other settings, the protocols' sections included, are kept)."""
        check_choice("protocol", protocol, PROTOCOLS)
        return dataclasses.replace(self, protocol=protocol)

    def to_dict(self) -> dict:
        """Plain-data view (for configs and metadata)."""
        return {f.name: (getattr(self, f.name).to_dict() if f.name in ("acronym", "graspgen")
                         else getattr(self, f.name)) for f in fields(self)}


# ---------------------------------------------------------------------------------------------------------------
# Result
# ---------------------------------------------------------------------------------------------------------------


def _bits(value) -> bytes:
    if isinstance(value, np.ndarray):
        return value.dtype.str.encode() + str(value.shape).encode() + value.tobytes()
    if isinstance(value, float):
        return struct.pack("<d", value)
    return repr(value).encode()


@dataclass(frozen=True, eq=False)
class RolloutResult:
    """What one grasp-and-lift rollout did. Arrays are read-only; ``==`` means bit-identical in every field."""

    code: int
    """Outcome code, 0-5 (:class:`Outcome`)."""
    name: str
    """Outcome name, ``OUTCOME_NAMES[code]``."""
    decided_in: str
    """Phase in which the outcome was decided (:data:`PHASES`); ``"end"`` when every phase ran (code 4 or 5)."""
    steps: int
    """Simulation steps taken (the rollout stops as soon as the outcome is decided)."""
    sim_time: float
    """Simulated time (s), ``steps * timestep``."""
    closed_width: float
    """Pad separation (m) at the end of closing; NaN when the rollout ended before closing."""
    lift_gain: float
    """Rise (m) of the target's centre of mass, world z, from the end of closing to the end; NaN before that."""
    rel_translation: float
    """Displacement (m) of the target's centre of mass in the TCP frame from the end of closing to the end (the
    slip); NaN when the rollout ended before closing finished."""
    rel_rotation: float
    """Rotation angle (rad) of the target relative to the TCP frame over the same span; NaN likewise."""
    contact_points: np.ndarray
    """``(k, 3) float64`` world positions (m) of the jaw-target contacts at the end of closing (pads and finger
    links; MuJoCo's contact point, midway between the two surfaces). ``k = 0`` when closing was not reached."""
    contact_normals: np.ndarray
    """``(k, 3) float64`` unit contact normals pointing INTO the target (the direction the jaw pushes), world."""
    contact_forces: np.ndarray
    """``(k,) float64`` normal force (N) of each contact (``mj_contactForce``), >= 0."""
    contact_fingers: np.ndarray
    """``(k,) int8`` which jaw made each contact: 0 left (on the TCP's -x side), 1 right (+x side)."""
    motion_closing_linear: float = math.nan
    """ACRONYM's ``object_motion_during_closing_linear``: displacement (m) of the target's centre of mass, world
    frame, from the start to the end of closing (the hand stands still meanwhile); NaN when closing was not
    reached."""
    motion_closing_angular: float = math.nan
    """ACRONYM's ``object_motion_during_closing_angular``: rotation angle (rad) of the target over the same span."""
    motion_shaking_linear: float = math.nan
    """ACRONYM's ``object_motion_during_shaking_linear``: displacement (m) of the target's centre of mass, world
    frame, from the start of the shake to the end of the rollout (the hand is back at its pose when the shake
    ends; a rollout stopped early measures to where it stopped); NaN when no shake ran."""
    motion_shaking_angular: float = math.nan
    """ACRONYM's ``object_motion_during_shaking_angular``: rotation angle (rad) of the target over the same span."""
    target_pose_closed: np.ndarray = field(default_factory=lambda: np.full((4, 4), math.nan))
    """``(4, 4) float64`` world pose of the target body's frame (a scene object's mesh frame) at the end of closing,
    when the contacts were recorded (they map to the object frame exactly with it); NaN before closing ended."""
    max_rel_translation: float = math.nan
    """Largest displacement (m) of the target's centre of mass in the TCP frame (the simulated hand's frame, not
    the world's) from the end of closing, over every check (each ``check_interval`` steps) of the disturbance
    (``table``: lift, hold, shake; ``acronym``: shake and settle; ``graspgen``: the tugs) and its end. Unlike
    ``rel_translation`` (end minus start) an object that swings and swings back is caught. NaN when no
    disturbance started (a collision, or code 3)."""
    max_rel_rotation: float = math.nan
    """Largest rotation angle (rad) of the target relative to the TCP frame over the same checks."""
    firm: bool = False
    """Firm hold: ``code == 5`` (still in the hand) and ``max_rel_translation <= LiftParams.firm_translation`` and
    ``max_rel_rotation <= LiftParams.firm_rotation``; False for every other outcome."""

    def __post_init__(self) -> None:
        for key in ("contact_points", "contact_normals", "contact_forces", "contact_fingers", "target_pose_closed"):
            getattr(self, key).setflags(write=False)

    @property
    def success(self) -> bool:
        """``code == Outcome.SUCCESS``."""
        return self.code == Outcome.SUCCESS

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, RolloutResult):
            return NotImplemented
        return all(_bits(getattr(self, f.name)) == _bits(getattr(other, f.name)) for f in fields(self))

    __hash__ = None  # type: ignore[assignment]  # mutable-array fields: not hashable

    def to_dict(self) -> dict:
        """Plain-data view: arrays as nested lists."""
        return {f.name: (getattr(self, f.name).tolist() if isinstance(getattr(self, f.name), np.ndarray)
                         else getattr(self, f.name)) for f in fields(self)}


# ---------------------------------------------------------------------------------------------------------------
# Motion profiles
# ---------------------------------------------------------------------------------------------------------------


def _trapezoid(distance: float, speed: float, accel: float, dt: float) -> np.ndarray:
    """Distance travelled (m) at the end of each step of a rest-to-rest trapezoidal speed profile, ``(n,)``.

    Peak speed ``speed`` (m/s), acceleration ``accel`` (m/s^2); a triangle when the distance is too short to reach
    ``speed``. The last entry is exactly ``distance``; empty for ``distance == 0``.
    """
    if distance <= 0.0:
        return np.zeros(0)
    t_acc = speed / accel
    if accel * t_acc * t_acc > distance:  # never reaches the peak speed: triangle
        t_acc = math.sqrt(distance / accel)
        speed = accel * t_acc
    t_cruise = (distance - accel * t_acc * t_acc) / speed
    total = 2.0 * t_acc + t_cruise
    n = max(1, math.ceil(total / dt - 1e-9))
    t = np.minimum(dt * np.arange(1, n + 1), total)
    d_acc = 0.5 * accel * t_acc * t_acc
    t_dec = np.maximum(t - t_acc - t_cruise, 0.0)
    s = np.where(t < t_acc, 0.5 * accel * t * t,
                 np.where(t < t_acc + t_cruise, d_acc + speed * (t - t_acc),
                          d_acc + speed * t_cruise + speed * t_dec - 0.5 * accel * t_dec * t_dec))
    s[-1] = distance
    return s


def _shake_wave(amplitude: float, frequency: float, cycles: int, dt: float) -> np.ndarray:
    """``amplitude * sin(2 pi f t) * sin^2(pi t / T)`` at the end of each step over ``T = cycles / f``, ``(n,)``:
    a sine under a Hann window, so position and velocity start and end at zero (no velocity jump)."""
    total = cycles / frequency
    n = max(1, math.ceil(total / dt - 1e-9))
    t = np.minimum(dt * np.arange(1, n + 1), total)
    return amplitude * np.sin(2.0 * math.pi * frequency * t) * np.sin(math.pi * t / total) ** 2


def _quat_mul(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternion ``q (4,)`` with each row of ``r (n, 4)`` (w, x, y, z)."""
    w0, x0, y0, z0 = q
    w1, x1, y1, z1 = r.T
    return np.stack([w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1,
                     w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1,
                     w0 * y1 - x0 * z1 + y0 * w1 + z0 * x1,
                     w0 * z1 + x0 * y1 - y0 * x1 + z0 * w1], axis=1)


def _angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Rotation angle (rad) between two 3x3 rotation matrices.

    atan2(sin, cos) of ``R = Ra^T Rb``, not acos of the trace alone: acos loses all precision near 0 (an angle
    below ~1e-8 rad reads as exactly 0, one of 1e-4 rad is off by percent)."""
    R = Ra.T @ Rb
    c = (R[0, 0] + R[1, 1] + R[2, 2] - 1.0) / 2.0
    s = 0.5 * math.sqrt((R[2, 1] - R[1, 2]) ** 2 + (R[0, 2] - R[2, 0]) ** 2 + (R[1, 0] - R[0, 1]) ** 2)
    return math.atan2(s, c)


# ---------------------------------------------------------------------------------------------------------------
# Simulator
# ---------------------------------------------------------------------------------------------------------------


class _Drift:
    """The target's largest displacement (m) and rotation (rad) in the TCP frame since a reference pose, over the
    poses given to :meth:`update` (read-only bookkeeping: it never touches the simulation)."""

    def __init__(self, p0: np.ndarray, R0: np.ndarray) -> None:
        self.p0, self.R0 = p0.copy(), R0.copy()
        self.translation = 0.0
        self.rotation = 0.0

    def update(self, p: np.ndarray, R: np.ndarray) -> None:
        dp = p - self.p0
        self.translation = max(self.translation, math.sqrt(float(dp @ dp)))
        self.rotation = max(self.rotation, _angle(self.R0, R))


class _JawsStopped(Exception):
    """Internal: the closing jaws have stopped."""


class _Decided(Exception):
    """Internal: a rule fired; carries the outcome code and phase."""

    def __init__(self, code: int, phase: str) -> None:
        super().__init__(code, phase)
        self.code = code
        self.phase = phase


class LiftSimulator:
    """Grasp-and-lift rollouts in one compiled scene, reusing one :class:`mujoco.MjData`.

    The scene model holds the static environment (a plane named ``ground`` and/or geoms named ``support/...``;
    every geom fixed to the world counts as support, whatever its name), objects as free bodies (named
    ``obj/<index>_<name>`` by convention; any movable body that is not the gripper counts as an object), and a
    floating gripper attached with :func:`graspgen.sim.grippers.attach_gripper` under ``prefix``. Ids are looked up by
    name once here, never assumed by index. The simulator works on its own copy of the model: it writes the
    physics settings of ``params`` into it and sets the gripper's force limit to ``params.grip_force`` (rescaling
    the jaw damping so the jaws keep the gripper's closing speed). The caller's model is not modified.

    Protocol of :meth:`rollout` (phases as in :data:`PHASES`), and the outcome rules. The rules are checked in this
    order; the first that fires decides the outcome and the simulation stops there. "Contact" means a MuJoCo contact
    between a gripper geom and a non-gripper geom; a gripper geom touching several kinds at once gives the lowest
    code. Checks run every ``check_interval`` steps and at the end of each phase.

    1. **placement** (no step): ``mj_resetData`` plus the scene's initial ``qpos``; the gripper is put at the
       pre-grasp pose (the grasp pose moved ``approach_distance`` back along its -z) with the jaws open at
       ``clip(width + width_margin, min_width, max_width)``; ``mj_forward``.
       Contact with support -> **0 collision_with_ground**; with the target, by the touch rule below -> **1
       collision_with_target**; with another object -> **2 collision_with_clutter**.
    2. **approach**: the mocap target moves along +z to the grasp pose (trapezoidal profile, ``approach_speed``,
       ``approach_acceleration``). Contact with support -> **0**, with another object -> **2**; contact with the
       target -> **1** by the touch rule; the target's centre of mass moved more than ``max_target_shift`` or
       turned more than ``max_target_turn`` from its initial pose -> **1**; another object moved/turned more than
       that -> **2**.

       Contacts at placement and on the approach are judged twice, and either counts: as the pre-filter judges
       them (:mod:`graspgen.sim.prefilter`), statically, with the gripper as commanded at this instant (hand on
       the approach line, jaws at the opening) against the scene as it stood at placement
       (:meth:`_static_code`), and live, the simulated gripper's contacts with support and other objects. The
       touch rule is the pre-filter's, so code 1 means the same there and here: a finger (either jaw's pad or
       finger link) may touch the target, pressing up to :data:`graspgen.sim.prefilter.TARGET_TOUCH_DEPTH` (2 mm)
       into it, as a real finger brushes an object on the way in; deeper is a collision, and so is any palm contact
       with the target. It is judged on the static check only: a pushed target yields, so its live contacts do not
       tell how far a finger went into it (its motion is the rule above). ``target_touch_fails`` gives the fingers
       no allowance.
    3. **closing**: the width command goes to ``min_width``, so each jaw presses with ``grip_force``. Closing ends
       when the pad separation changes slower than ``close_speed_tol`` averaged over a check interval, or after
       ``close_timeout``. Then both jaws (each jaw's pad or finger link) must touch the target; otherwise ->
       **3 no_contact_established**. The jaw-target contacts are recorded now (points, normals into the target,
       normal forces, jaw). Gravity is switched on here in free-space mode (``gravity_until_closed``).
    4. **lifting, holding, shaking**: the TCP rises ``lift_height`` straight up in world z (trapezoidal profile,
       ``lift_speed``, ``lift_acceleration``), holds for ``hold_time``, then shakes if ``shake``. At every check: the
       target's centre of mass moved more than ``slip_tolerance`` in the TCP frame since the end of closing, or the
       target turned relative to the TCP frame by more than ``slip_rotation_tolerance`` -> **4
       slipped_during_lifting**. At the end: the target's centre of mass rose less than
       ``min_lift_fraction * lift_height`` since the end of closing -> **4**.
    5. Otherwise -> **5 success**.

    Collisions after the approach (a lifted object brushing a neighbour, a finger touching the table while closing)
    are not labels of their own: they count only through their effect on the grasp (3 or 4).

    That is the ``table`` protocol (``params.protocol``, the default). The ``acronym`` protocol
    (:class:`AcronymParams`, where its numbers come from) has no approach and no lift: gravity off until closing
    ends (then along the approach axis, ``acronym.gravity``); **placement** at the grasp pose itself with the jaws
    open to ``acronym.open_width`` (fully by default): any contact with the target -> **1** (no allowance for the
    fingers: see below), with support -> **0**, with another object -> **2**; **closing** as above (at
    ``acronym.grip_force`` and ``acronym.closing_speed``; the timeout is at least 1.25x the time to close fully),
    then not both jaws on the target -> **3**; **shaking**: the TCP oscillates along its own z axis, then rotates
    about its own x axis through the TCP (``acronym.shake_*``), then holds still for ``acronym.settle_time`` (phase
    ``holding``); at every check, neither jaw touching the target -> **4** (the object has left the hand); at the
    end, both jaws touching the target -> **5 success**, else **4**. ``lift_gain`` is NaN (nothing is lifted);
    ``rel_translation``/``rel_rotation`` are the object's motion in the hand since closing; the ``motion_*`` fields
    are ACRONYM's four motion measures.

    The free-space protocols keep their sources' strict rule: any overlap of the open hand with the target at the
    grasp pose is a collision, the fingers get no allowance (ACRONYM and GraspDataGen take grasps whose hand
    collides with the mesh as failures, with no tolerance). Measured (``bench/fidelity.py --limit 100``, 600
    calibration grasps): with the table protocol's 2 mm allowance the ``acronym`` protocol turned 26 of its 30
    collisions into successes or other codes, most of them grasps FleX loses, and its agreement with FleX fell from
    0.845 to 0.827 (kappa 0.50 to 0.41).

    Both protocols record the object's motion during closing and during the shake (``motion_*``, world frame) and
    its pose at the end of closing (``target_pose_closed``).

    **Firm hold**, a second label beside the outcome, in every protocol: from the end of closing on, at every check
    of the disturbance (``table``: lift, hold, shake; ``acronym``: shake, settle; ``graspgen``: tugs) and at the end,
    the target's pose in the TCP frame (the simulated hand's) is compared with its pose when closing ended; the
    largest displacement and rotation are :attr:`RolloutResult.max_rel_translation` / ``max_rel_rotation``, and a
    success is firm (:attr:`RolloutResult.firm`) when both stay within ``firm_translation`` / ``firm_rotation``.
    Hand frame, not world: the shake moves the hand, so a world-frame displacement over it (``motion_shaking_*``)
    means motion in the hand only because the hand is back at its pose when the shake ends, and it misses an
    object that swings round the pinch and swings back. Bookkeeping only: it reads the state and never changes a
    step, so outcome codes and every other field are what they were without it.

    Parameters
    ----------
    model
        Compiled scene with the gripper attached (see above).
    params
        Protocol, thresholds and physics; None means ``LiftParams()``.
    qpos
        ``(nq,)`` initial configuration of the scene (e.g. settled object poses); None means ``model.qpos0``.
        The gripper's own joints in it are ignored (every rollout places the gripper).
    prefix
        Name prefix of the gripper's elements (as given to :func:`graspgen.sim.grippers.attach_gripper`).
    """

    def __init__(self, model: mujoco.MjModel, params: LiftParams | None = None, *, qpos=None,
                 prefix: str = "gripper/") -> None:
        check_instance("model", model, mujoco.MjModel, what="compiled mujoco.MjModel")
        params = check_instance("params", LiftParams() if params is None else params, LiftParams)
        if not isinstance(prefix, str) or not prefix:
            raise ValueError(f"prefix: expected a non-empty string, got {prefix!r}")
        self.params = params
        self.prefix = prefix
        # Our own copy: physics options, grip force and (in free-space mode) gravity are written into it.
        self.model = m = copy.deepcopy(model)
        self._gravity = np.array(m.opt.gravity, dtype=float)
        params.physics_options(self._gravity).apply(m)
        m.opt.noslip_iterations = params.noslip_iterations
        m.opt.iterations = params.iterations
        m.opt.ls_iterations = params.ls_iterations

        # -- gripper elements, by name -------------------------------------------------------------------------
        def lookup(objtype, local: str) -> int:
            idx = mujoco.mj_name2id(m, objtype, prefix + local)
            if idx < 0:
                kind = mujoco.mjtObj(objtype).name.removeprefix("mjOBJ_").lower()
                raise ValueError(f"model: no {kind} named {prefix + local!r} (is the gripper attached with "
                                 f"prefix {prefix!r}?)")
            return idx

        self._act = lookup(mujoco.mjtObj.mjOBJ_ACTUATOR, "width")
        self._base = lookup(mujoco.mjtObj.mjOBJ_BODY, "base")
        mocap_body = lookup(mujoco.mjtObj.mjOBJ_BODY, "mocap")
        self._mocap = int(m.body_mocapid[mocap_body])
        if self._mocap < 0:
            raise ValueError(f"model: body {prefix + 'mocap'!r} is not a mocap body")
        free = lookup(mujoco.mjtObj.mjOBJ_JOINT, "free")
        self._base_qadr = int(m.jnt_qposadr[free])
        jaw_joints = [lookup(mujoco.mjtObj.mjOBJ_JOINT, f"{side}_slide") for side in ("left", "right")]
        self._jaw_qadr = [int(m.jnt_qposadr[j]) for j in jaw_joints]
        self._jaw_vadr = [int(m.jnt_dofadr[j]) for j in jaw_joints]
        self._couplings = linkage_couplings(m, prefix=prefix)  # a finger linkage's joints follow the jaws
        jaw_bodies = [lookup(mujoco.mjtObj.mjOBJ_BODY, f"{side}_jaw") for side in ("left", "right")]
        self.min_width, self.max_width = (float(v) for v in m.actuator_ctrlrange[self._act])
        """Pad separation range (m) of the gripper (its width actuator's control range)."""

        # -- grip force: force limit, and jaw damping rescaled to keep the closing speed --------------------------
        # grippers.py sets damping = 2 * force_limit / closing_speed per jaw, so a saturated actuator closes the
        # width at closing_speed; keep that ratio for the new force limit.
        model_force = float(m.actuator_forcerange[self._act][1])
        damping = float(m.dof_damping[self._jaw_vadr[0]])
        self.closing_speed = 2.0 * model_force / damping if damping > 0 else math.inf
        """Width rate (m/s) of the closing jaws when nothing is in the way."""
        acr = params.acronym
        self._acronym = params.protocol == "acronym"
        self._graspgen = params.protocol == "graspgen"
        if self._graspgen:
            acr = params.graspgen  # the same grip settings (open_width, grip_force, closing_speed) as acronym's
        if not (self._acronym or self._graspgen):
            self.grip_force = model_force if params.grip_force is None else params.grip_force
            """Force (N) each jaw presses with when closed on an object."""
            m.actuator_forcerange[self._act] = (-self.grip_force, self.grip_force)
            if damping > 0:
                for vadr in self._jaw_vadr:
                    m.dof_damping[vadr] = damping * self.grip_force / model_force
        else:
            self.grip_force = model_force if acr.grip_force is None else acr.grip_force
            if acr.closing_speed is not None:
                self.closing_speed = acr.closing_speed
            m.actuator_forcerange[self._act] = (-self.grip_force, self.grip_force)
            if damping > 0 or acr.closing_speed is not None:
                for vadr in self._jaw_vadr:
                    m.dof_damping[vadr] = 2.0 * self.grip_force / self.closing_speed

        # -- geom roles ---------------------------------------------------------------------------------------------
        gripper_root = int(m.body_rootid[self._base])
        body_side = np.full(m.nbody, _NOT_GRIPPER, dtype=np.int8)
        for b in range(m.nbody):
            if m.body_rootid[b] == gripper_root:
                body_side[b] = _PALM
        for side, jaw in ((_LEFT, jaw_bodies[0]), (_RIGHT, jaw_bodies[1])):
            for b in range(m.nbody):
                if self._is_descendant(b, jaw):
                    body_side[b] = side
        self._geom_side = body_side[m.geom_bodyid]
        """(ngeom,) int8: 0 left jaw, 1 right jaw, 2 palm/base, -1 not the gripper."""
        self._geom_is_gripper = self._geom_side != _NOT_GRIPPER
        self._allowance = touch_allowance(m, prefix=prefix, depth=0.0 if params.target_touch_fails
                                          else TARGET_TOUCH_DEPTH)
        """(ngeom,) float: how deep (m) each gripper geom may press into the target (the touch rule)."""
        # The free-space protocols keep their sources' rule: the open hand must not touch the target at all.
        self._no_allowance = np.zeros(m.ngeom)
        weld = m.body_weldid[m.geom_bodyid]
        static = (weld == 0) | (m.body_mocapid[weld] >= 0)
        names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or "" for g in range(m.ngeom)]
        named_support = np.array([n == "ground" or n.startswith("support/") for n in names], dtype=bool)
        self._geom_static = (static | named_support) & ~self._geom_is_gripper
        self._geom_root = m.body_rootid[m.geom_bodyid].astype(np.int64)
        # Objects: movable root bodies that are not the gripper (free bodies under the world).
        objects = [b for b in range(1, m.nbody)
                   if m.body_rootid[b] == b and body_side[b] == _NOT_GRIPPER and m.body_weldid[b] != 0
                   and m.body_mocapid[b] < 0]
        self._objects = np.array(objects, dtype=np.int64)
        self.object_names: tuple[str, ...] = tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) or ""
                                                   for b in objects)
        """Names of the movable object bodies (possible targets)."""
        self._roles: dict[str, tuple[int, np.ndarray, int]] = {}
        # The static check's private model (_static_code): the scene as it stood, the gripper as commanded.
        self._ghost_model = gm = copy.deepcopy(m)
        self._ghost = mujoco.MjData(gm)
        # Only gripper-vs-other pairs (as the pre-filter's private model): another geom collides with the gripper
        # geoms iff its masks let it collide with one of them.
        grip_ct, grip_ca = m.geom_contype[self._geom_is_gripper], m.geom_conaffinity[self._geom_is_gripper]
        for g in np.flatnonzero(~self._geom_is_gripper):
            ct, ca = int(m.geom_contype[g]), int(m.geom_conaffinity[g])
            gm.geom_contype[g] = int(bool(np.any((ct & grip_ca) | (grip_ct & ca))))
            gm.geom_conaffinity[g] = 0
        self._shift2 = params.max_target_shift ** 2
        self._cos_half_turn = math.cos(min(params.max_target_turn, math.pi) / 2.0)
        self._slip2 = params.slip_tolerance ** 2
        self._cos_slip = math.cos(min(params.slip_rotation_tolerance, math.pi))
        if self._acronym:  # contact overrides of the acronym protocol, on the gripper's geoms (by role and name)
            grip = np.flatnonzero(self._geom_is_gripper)
            if acr.contact_solref is not None:
                m.geom_solref[grip] = acr.contact_solref
            if acr.contact_solimp is not None:
                m.geom_solimp[grip] = acr.contact_solimp
            if acr.torsional_friction is not None:
                # MuJoCo takes the larger coefficient of the two geoms (and the larger condim): set it on the pads
                # and on every other geom, so the pad contacts get exactly this value; 0 makes them condim 3.
                pads = list(sum(pad_geom_ids(m, prefix=prefix), ()))
                m.geom_friction[pads, 1] = acr.torsional_friction
                m.geom_friction[np.flatnonzero(~self._geom_is_gripper), 1] = acr.torsional_friction
                if acr.torsional_friction == 0.0:
                    m.geom_condim[pads] = np.minimum(m.geom_condim[pads], 3)

        # -- initial state ------------------------------------------------------------------------------------------
        self.data = mujoco.MjData(m)
        """The one :class:`mujoco.MjData` every rollout reuses (after a rollout: its final state)."""
        if qpos is None:
            qpos = m.qpos0
        qpos = np.array(qpos, dtype=float)
        if qpos.shape != (m.nq,) or not np.isfinite(qpos).all():
            raise ValueError(f"qpos: expected {m.nq} finite numbers, got shape {qpos.shape}")
        qpos.setflags(write=False)
        self._qpos_init = qpos

        # -- cached views into data (valid for the life of self.data) and motion profiles --------------------------
        d = self.data
        self._qpos, self._ctrl = d.qpos, d.ctrl
        self._mocap_pos, self._mocap_quat = d.mocap_pos[self._mocap], d.mocap_quat[self._mocap]
        self._xipos, self._xquat, self._xmat, self._xpos = d.xipos, d.xquat, d.xmat, d.xpos
        self._gravity_view = m.opt.gravity
        dt = float(m.opt.timestep)
        self._dt = dt
        self._approach_s = _trapezoid(params.approach_distance, params.approach_speed,
                                      params.approach_acceleration, dt)
        lift_s = _trapezoid(params.lift_height, params.lift_speed, params.lift_acceleration, dt)
        self._lift_offsets = np.zeros((len(lift_s), 3))
        self._lift_offsets[:, 2] = lift_s
        self._hold_steps = int(round(params.hold_time / dt))
        self._close_max_steps = max(1, math.ceil(params.close_timeout / dt - 1e-9))
        if params.shake:
            self._shake_z = _shake_wave(params.shake_amplitude, params.shake_frequency, params.shake_cycles, dt)
            half = 0.5 * _shake_wave(params.shake_angle, params.shake_frequency, params.shake_cycles, dt)
            self._shake_qx = np.stack([np.cos(half), np.sin(half), np.zeros_like(half), np.zeros_like(half)], 1)
        if self._graspgen:
            self._open_width = float(np.clip(self.max_width if acr.open_width is None else acr.open_width,
                                             self.min_width, self.max_width))
            self._tug_steps = max(1, int(round(acr.tug_time / dt)))
            self._tug_dirs = acr.directions()
            full_close = 1.25 * (self._open_width - self.min_width) / self.closing_speed
            self._close_max_steps = max(self._close_max_steps, math.ceil(full_close / dt - 1e-9))
        if self._acronym:
            self._open_width = float(np.clip(self.max_width if acr.open_width is None else acr.open_width,
                                             self.min_width, self.max_width))
            self._shake_z = _shake_wave(acr.shake_amplitude, acr.shake_frequency, acr.shake_cycles, dt)
            half = 0.5 * _shake_wave(acr.shake_angle, acr.shake_frequency, acr.shake_cycles, dt)
            self._shake_qx = np.stack([np.cos(half), np.sin(half), np.zeros_like(half), np.zeros_like(half)], 1)
            self._settle_steps = int(round(acr.settle_time / dt))
            # From fully open to fully closed takes (open - min) / closing_speed: never stop closing before that.
            full_close = 1.25 * (self._open_width - self.min_width) / self.closing_speed
            self._close_max_steps = max(self._close_max_steps, math.ceil(full_close / dt - 1e-9))
        self._f6 = np.zeros(6)
        self.steps = 0
        """Steps taken by the current (or last) rollout."""

    # -- helpers ----------------------------------------------------------------------------------------------------

    def _is_descendant(self, body: int, ancestor: int) -> bool:
        parent = self.model.body_parentid
        while body > 0:
            if body == ancestor:
                return True
            body = int(parent[body])
        return ancestor == 0

    def _target_roles(self, target_body) -> tuple[int, np.ndarray, int]:
        """(target body id, geom roles (ngeom,) int8, index of the target in the object list), cached."""
        if target_body in self._roles:
            return self._roles[target_body]
        if not isinstance(target_body, str):
            raise ValueError(f"target_body: expected a body name, got {target_body!r}")
        bid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, target_body)
        if bid < 0 or bid not in self._objects:
            raise ValueError(f"target_body: no movable object body named {target_body!r}; objects: "
                             f"{', '.join(self.object_names) or '(none)'}")
        roles = np.where(self._geom_root == bid, _TARGET, _CLUTTER).astype(np.int8)
        roles[self._geom_static] = _SUPPORT
        roles[self._geom_is_gripper] = _GRIPPER
        self._roles[target_body] = (bid, roles, int(np.flatnonzero(self._objects == bid)[0]))
        return self._roles[target_body]

    def _contact_code(self, roles: np.ndarray, target: int, allowance: np.ndarray | None = None) -> int | None:
        """Lowest outcome code (0 support, 1 target, 2 clutter) among the gripper's collisions now; None if none:
        the pre-filter's static check (:meth:`_static_code`, the touch rule with ``allowance`` per geom, None: the
        table protocol's) and the live contacts with support and other objects (any contact; the live contacts
        with the target do not count: a pushed target yields, see :meth:`_static_code`)."""
        code = self._static_code(roles, target, self._allowance if allowance is None else allowance)
        if self.data.ncon == 0:
            return code
        geom = self.data.contact.geom
        grip = self._geom_is_gripper[geom]
        mask = grip[:, 0] != grip[:, 1]
        if not mask.any():
            return code
        codes = roles[np.where(grip[:, 0], geom[:, 1], geom[:, 0])[mask]]
        codes = codes[codes != _TARGET]
        if len(codes) and (code is None or codes.min() < code):
            code = int(codes.min())
        return code

    def _static_code(self, roles: np.ndarray, target: int, allowance: np.ndarray) -> int | None:
        """The pre-filter's check (:class:`graspgen.sim.prefilter.CollisionChecker`) at this instant of the rollout:
        the lowest code (0 support, 1 target by the touch rule, 2 clutter) of the gripper as commanded against the
        scene as it stood at placement; None if free. ``allowance`` (``(ngeom,)`` m,
        :func:`graspgen.sim.prefilter.touch_allowance`): how deep each gripper geom may press into the target.

        In a private copy of the model in which only gripper-vs-other pairs collide, every object stands at its
        initial ``qpos``, the hand at the mocap target (its pose on the approach line now) and each jaw at half the
        commanded opening; ``mj_kinematics`` + ``mj_collision``, no step.

        Why the scene as it stood: a pushed target yields (a finger pressing on it mostly moves it, a knocked one
        flies off and loses contact), so its current contacts say little about how far the finger went into it;
        the motion itself is judged by ``max_target_shift`` / ``max_target_turn``. Why the commanded gripper: the
        simulated hand lags the mocap target by up to ~2.5 mm at full approach speed and ~1 mm when the approach
        ends (the weld's 5 ms time constant), and a jaw pressed into the target gives way against its force-limited
        servo; both are the softness of the simulated mount and drive, not the path a position-controlled arm and a
        non-backdrivable gripper take (with them a finger pressed 3 mm into the target could pass as a brush), and
        support and clutter are checked on the same commanded gripper so that the first kind of collision on the
        way is the pre-filter's. The live contacts (:meth:`_contact_code`) add what only the simulation sees."""
        gm, gd = self._ghost_model, self._ghost
        gd.qpos[:] = self._qpos_init
        a = self._base_qadr  # the gripper as commanded: the hand at the mocap target, the jaws at the opening
        gd.qpos[a:a + 3] = self._mocap_pos
        gd.qpos[a + 3:a + 7] = self._mocap_quat
        gd.qpos[self._jaw_qadr] = self._ctrl[self._act] / 2.0  # jaw joint = half the pad separation
        mujoco.mj_kinematics(gm, gd)
        mujoco.mj_collision(gm, gd)
        if gd.ncon == 0:
            return None
        con = gd.contact
        geom = con.geom
        grip = self._geom_is_gripper[geom]
        mine = np.where(grip[:, 0], geom[:, 0], geom[:, 1])
        other = np.where(grip[:, 0], geom[:, 1], geom[:, 0])
        codes = roles[other]
        limit = np.where(codes == _TARGET, allowance[mine], 0.0)
        codes = codes[(grip[:, 0] != grip[:, 1]) & (-con.dist > limit)]
        return int(codes.min()) if len(codes) else None

    def _moved(self, pos0: np.ndarray, quat0: np.ndarray) -> np.ndarray:
        """``(n_objects,) bool``: which objects' centres of mass moved more than ``max_target_shift`` or turned more
        than ``max_target_turn`` since ``pos0 (n, 3)``, ``quat0 (n, 4)``. Squared distances and cosines, no sqrt or
        arccos: this runs at every check of the approach."""
        dp = self._xipos[self._objects] - pos0
        cos_half = np.abs(np.einsum("ij,ij->i", self._xquat[self._objects], quat0))  # |<q, q0>| = cos(turn / 2)
        return (np.einsum("ij,ij->i", dp, dp) > self._shift2) | (cos_half < self._cos_half_turn)

    def _width(self) -> float:
        return float(self._qpos[self._jaw_qadr[0]] + self._qpos[self._jaw_qadr[1]])

    def _relative(self, target: int) -> tuple[np.ndarray, np.ndarray]:
        """Target's centre of mass (3,) and rotation (3, 3) in the TCP frame."""
        R_tcp = self._xmat[self._base].reshape(3, 3)
        p = (self._xipos[target] - self._xpos[self._base]) @ R_tcp  # = R_tcp^T (x - x_tcp)
        R = R_tcp.T @ self._xmat[target].reshape(3, 3)
        return p, R

    def _slipped(self, target: int, p0: np.ndarray, R0: np.ndarray, drift: _Drift) -> bool:
        """The target moved more than ``slip_tolerance`` or turned more than ``slip_rotation_tolerance`` in the TCP
        frame since (``p0``, ``R0``) (squared distance and cosine: this runs at every check of lift/hold/shake);
        ``drift`` records the pose (the firm-hold measures)."""
        p, R = self._relative(target)
        drift.update(p, R)
        dp = p - p0
        return bool(dp @ dp > self._slip2 or (float(np.vdot(R0, R)) - 1.0) / 2.0 < self._cos_slip)

    def _jaw_contacts(self, target_roles: np.ndarray):
        """Jaw-target contacts now: points (k, 3), normals into the target (k, 3), normal forces (k,), jaws (k,)."""
        m, d = self.model, self.data
        points, normals, forces, jaws = [], [], [], []
        if d.ncon:
            con = d.contact
            geom, pos, frame = con.geom, con.pos, con.frame  # each attribute access copies all contacts: once
            side = self._geom_side[geom]
            for i in range(d.ncon):
                g1, g2 = int(geom[i, 0]), int(geom[i, 1])
                if side[i, 0] in (_LEFT, _RIGHT) and target_roles[g2] == _TARGET:
                    jaw, sign = int(side[i, 0]), 1.0  # frame[0:3] points from geom1 (jaw) to geom2 (target)
                elif side[i, 1] in (_LEFT, _RIGHT) and target_roles[g1] == _TARGET:
                    jaw, sign = int(side[i, 1]), -1.0
                else:
                    continue
                mujoco.mj_contactForce(m, d, i, self._f6)
                points.append(pos[i])
                normals.append(sign * frame[i, :3])
                forces.append(float(self._f6[0]))
                jaws.append(jaw)
        k = len(forces)
        return (np.array(points, dtype=float).reshape(k, 3), np.array(normals, dtype=float).reshape(k, 3),
                np.array(forces, dtype=float).reshape(k), np.array(jaws, dtype=np.int8).reshape(k))

    def _place(self, pos: np.ndarray, quat: np.ndarray, width: float) -> None:
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        self._qpos[:] = self._qpos_init
        a = self._base_qadr
        self._qpos[a:a + 3] = pos
        self._qpos[a + 3:a + 7] = quat
        half = width / 2.0
        for qadr in self._jaw_qadr:
            self._qpos[qadr] = half
        self._couplings.apply(self._qpos)
        self._ctrl[self._act] = width
        self._mocap_pos[:] = pos
        self._mocap_quat[:] = quat
        mujoco.mj_forward(m, d)

    def _move(self, positions: np.ndarray, quats: np.ndarray | None, phase: str, check, observer) -> None:
        """Step once per row of ``positions (n, 3)`` (and ``quats (n, 4)``) with the mocap target there; ``check``
        every ``check_interval`` steps and at the end."""
        m, d = self.model, self.data
        step = mujoco.mj_step  # looked up per call, not at import: bench/bench_rollouts.py wraps it to time it
        mpos, mquat = self._mocap_pos, self._mocap_quat
        n, k = len(positions), self.params.check_interval
        for c0 in range(0, n, k):
            c1 = min(c0 + k, n)
            if quats is None:
                for i in range(c0, c1):
                    mpos[:] = positions[i]
                    step(m, d)
            else:
                for i in range(c0, c1):
                    mpos[:] = positions[i]
                    mquat[:] = quats[i]
                    step(m, d)
            self.steps += c1 - c0
            if observer is not None:
                observer(phase, self.steps)
            check(phase)

    def _wait(self, n: int, phase: str, check, observer) -> None:
        """Step ``n`` times with the targets fixed, ``check`` every ``check_interval`` steps and at the end."""
        m, d = self.model, self.data
        k = self.params.check_interval
        done = 0
        while done < n:
            c = min(k, n - done)
            mujoco.mj_step(m, d, nstep=c)
            done += c
            self.steps += c
            if observer is not None:
                observer(phase, self.steps)
            check(phase)

    # -- the protocol ---------------------------------------------------------------------------------------------

    def rollout(self, T_tcp_world, width: float, target_body: str, *,
                observer: Callable[[str, int], None] | None = None) -> RolloutResult:
        """Roll out one grasp and label it (protocol and rules in the class docstring).

        Parameters
        ----------
        T_tcp_world
            ``(4, 4)`` world pose of the TCP frame at the grasp (z approach, x closing).
        width
            Pad separation (m) of the grasp (the object's width between the contacts); the jaws open to
            ``width + params.width_margin`` (``table``); ignored by ``acronym`` (the jaws open to
            ``params.acronym.open_width``, by default fully).
        target_body
            Name of the object body to grasp, e.g. ``"obj/0_box"``.
        observer
            Called as ``observer(phase, steps_so_far)`` after placement and after every chunk of steps, with
            :attr:`data` holding the current state (for recording or benchmarking; must not modify the state).

        Returns
        -------
        RolloutResult
        """
        pos, quat = _pos_quat("T_tcp_world", T_tcp_world)
        width = check_number("width", width, low=0.0)
        target, roles, index = self._target_roles(target_body)
        self.steps = 0
        R = np.asarray(T_tcp_world, dtype=float)[:3, :3]
        if self._graspgen:
            return self._rollout_free_space(pos, quat, R, target, roles, observer, self._graspgen_tugs)
        if self._acronym:
            return self._rollout_free_space(pos, quat, R, target, roles, observer, self._acronym_shake)
        return self._rollout_table(pos, quat, np.asarray(T_tcp_world, dtype=float)[:3, :3], width, target, roles,
                                   index, observer)

    def _close(self, observer) -> None:
        """The closing phase: command ``min_width`` and step until the jaws stop or ``close_timeout``."""
        p = self.params
        self._ctrl[self._act] = self.min_width
        tol = p.close_speed_tol * p.check_interval * self._dt  # width change per check interval
        last = [self._width()]

        def check_closing(phase: str) -> None:
            w = self._width()
            if abs(w - last[0]) < tol:
                raise _JawsStopped
            last[0] = w

        try:
            self._wait(self._close_max_steps, "closing", check_closing, observer)
        except _JawsStopped:
            pass

    def _mark(self, target: int) -> tuple[np.ndarray, np.ndarray]:
        """The target's centre of mass (3,) and rotation (3, 3), world frame, now (copies)."""
        return self._xipos[target].copy(), self._xmat[target].reshape(3, 3).copy()

    def _motion(self, target: int, mark: tuple[np.ndarray, np.ndarray]) -> tuple[float, float]:
        """Displacement (m) and rotation angle (rad) of the target, world frame, since ``mark``."""
        d = self._xipos[target] - mark[0]
        return math.sqrt(float(d @ d)), _angle(mark[1], self._xmat[target].reshape(3, 3))

    def _body_pose(self, body: int) -> np.ndarray:
        """(4, 4) world pose of ``body``'s frame now."""
        T = np.eye(4)
        T[:3, :3] = self._xmat[body].reshape(3, 3)
        T[:3, 3] = self._xpos[body]
        return T

    def _rollout_table(self, pos, quat, R, width, target, roles, index, observer) -> RolloutResult:
        """The ``table`` protocol (class docstring)."""
        p = self.params
        z_axis = R[:, 2].copy()
        open_width = float(jaw_opening(width, p.width_margin, self.min_width, self.max_width))
        pre = pos - p.approach_distance * z_axis
        nan = math.nan
        closed_width = lift_gain = rel_t = rel_r = nan
        motion_closing = motion_shaking = (nan, nan)
        pose_closed = np.full((4, 4), nan)
        shake_mark = drift = None
        contacts = (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int8))
        self._gravity_view[:] = 0.0 if p.gravity_until_closed else self._gravity
        try:
            # 1. placement
            self._place(pre, quat, open_width)
            pos0, quat0 = self._xipos[self._objects], self._xquat[self._objects]  # fancy indexing: copies
            if observer is not None:
                observer("placement", 0)

            def check_approach(phase: str) -> None:
                code = self._contact_code(roles, target)
                if code is not None:
                    raise _Decided(code, phase)
                moved = self._moved(pos0, quat0)
                if moved[index]:
                    raise _Decided(Outcome.COLLISION_WITH_TARGET, phase)
                if moved.any():
                    raise _Decided(Outcome.COLLISION_WITH_CLUTTER, phase)

            check_approach("placement")
            # 2. approach
            self._move(pre + self._approach_s[:, None] * z_axis, None, "approach", check_approach, observer)
            # 3. closing
            close_mark = self._mark(target)
            self._close(observer)
            closed_width = self._width()
            motion_closing = self._motion(target, close_mark)
            pose_closed = self._body_pose(target)
            contacts = self._jaw_contacts(roles)
            if not (np.any(contacts[3] == _LEFT) and np.any(contacts[3] == _RIGHT)):
                raise _Decided(Outcome.NO_CONTACT_ESTABLISHED, "closing")
            self._gravity_view[:] = self._gravity
            # 4. lift, hold, shake
            rel_p0, rel_R0 = self._relative(target)
            drift = _Drift(rel_p0, rel_R0)
            z_obj0 = float(self._xipos[target][2])

            def check_slip(phase: str) -> None:
                if self._slipped(target, rel_p0, rel_R0, drift):
                    raise _Decided(Outcome.SLIPPED_DURING_LIFTING, phase)

            self._move(pos + self._lift_offsets, None, "lifting", check_slip, observer)
            self._wait(self._hold_steps, "holding", check_slip, observer)
            if p.shake:
                shake_mark = self._mark(target)
                top = pos + self._lift_offsets[-1]
                shake_pos = np.repeat(top[None], len(self._shake_z), axis=0)
                shake_pos[:, 2] += self._shake_z
                self._move(shake_pos, None, "shaking", check_slip, observer)
                self._move(np.repeat(top[None], len(self._shake_qx), axis=0), _quat_mul(quat, self._shake_qx),
                           "shaking", check_slip, observer)
            lift_gain = float(self._xipos[target][2]) - z_obj0
            if lift_gain < p.min_lift_fraction * p.lift_height:
                raise _Decided(Outcome.SLIPPED_DURING_LIFTING, "end")
            code, phase = Outcome.SUCCESS, "end"
        except _Decided as decided:
            code, phase = Outcome(decided.code), decided.phase
        finally:
            self._gravity_view[:] = self._gravity
        if code >= Outcome.SLIPPED_DURING_LIFTING:
            rel_p, rel_R = self._relative(target)
            rel_t = math.sqrt(float((rel_p - rel_p0) @ (rel_p - rel_p0)))
            rel_r = _angle(rel_R0, rel_R)
            lift_gain = float(self._xipos[target][2]) - z_obj0
        if shake_mark is not None:
            motion_shaking = self._motion(target, shake_mark)
        return self._result(code, phase, closed_width, lift_gain, (rel_t, rel_r), contacts, motion_closing,
                            motion_shaking, pose_closed, self._final_drift(target, drift))

    def _final_drift(self, target: int, drift: _Drift | None) -> tuple[float, float]:
        """(max translation m, max rotation rad) of the target in the TCP frame over the disturbance, the final pose
        included; NaNs when closing was not finished (no reference)."""
        if drift is None:
            return math.nan, math.nan
        drift.update(*self._relative(target))
        return drift.translation, drift.rotation

    def _result(self, code, phase, closed_width, lift_gain, relative, contacts, motion_closing, motion_shaking,
                pose_closed, drift) -> RolloutResult:
        """The :class:`RolloutResult` every protocol returns (``relative``, ``drift``: translation m, rotation
        rad; ``drift`` the largest over the disturbance)."""
        p = self.params
        firm = bool(code == Outcome.SUCCESS and drift[0] <= p.firm_translation and drift[1] <= p.firm_rotation)
        return RolloutResult(
            code=int(code), name=OUTCOME_NAMES[code], decided_in=phase, steps=self.steps,
            sim_time=self.steps * self._dt, closed_width=closed_width, lift_gain=lift_gain,
            rel_translation=relative[0], rel_rotation=relative[1], contact_points=contacts[0],
            contact_normals=contacts[1], contact_forces=contacts[2], contact_fingers=contacts[3],
            motion_closing_linear=motion_closing[0], motion_closing_angular=motion_closing[1],
            motion_shaking_linear=motion_shaking[0], motion_shaking_angular=motion_shaking[1],
            target_pose_closed=pose_closed, max_rel_translation=drift[0], max_rel_rotation=drift[1], firm=firm)

    def _jaws_on(self, roles: np.ndarray) -> tuple[bool, bool]:
        """(left jaw touches the target, right jaw touches the target) now; no contact forces (cheap)."""
        if self.data.ncon == 0:
            return False, False
        geom = self.data.contact.geom
        side = self._geom_side[geom]
        on_target = roles[geom] == _TARGET
        hits = np.concatenate([side[:, 0][on_target[:, 1]], side[:, 1][on_target[:, 0]]])
        return bool(np.any(hits == _LEFT)), bool(np.any(hits == _RIGHT))

    def _rollout_free_space(self, pos, quat, R, target, roles, observer, disturb) -> RolloutResult:
        """The frame the free-space protocols share (``acronym``, ``graspgen``): gravity off, the hand placed at the
        grasp pose with its jaws open (touching anything there decides the grasp, the target without the fingers'
        allowance), closed, then ``disturb(pos, quat, R, target, check_held, observer)`` tests the grip (the
        protocol's own part); success when both jaws still touch the target at the end."""
        nan = math.nan
        closed_width = rel_t = rel_r = nan
        motion_closing = motion_shaking = (nan, nan)
        pose_closed = np.full((4, 4), nan)
        shake_mark = rel0 = drift = None
        contacts = (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int8))
        self._gravity_view[:] = 0.0
        try:
            # 1. placement: at the grasp pose, jaws open; the open hand must not touch anything
            self._place(pos, quat, self._open_width)
            if observer is not None:
                observer("placement", 0)
            code = self._contact_code(roles, target, self._no_allowance)
            if code is not None:
                raise _Decided(code, "placement")
            # 2. closing, gravity off
            close_mark = self._mark(target)
            self._close(observer)
            closed_width = self._width()
            motion_closing = self._motion(target, close_mark)
            pose_closed = self._body_pose(target)
            contacts = self._jaw_contacts(roles)
            if not (np.any(contacts[3] == _LEFT) and np.any(contacts[3] == _RIGHT)):
                raise _Decided(Outcome.NO_CONTACT_ESTABLISHED, "closing")
            rel0 = self._relative(target)
            drift = _Drift(*rel0)

            def check_held(phase: str) -> None:
                drift.update(*self._relative(target))
                if not any(self._jaws_on(roles)):
                    raise _Decided(Outcome.SLIPPED_DURING_LIFTING, phase)

            # 3. the protocol's disturbance
            shake_mark = self._mark(target)
            disturb(pos, quat, R, target, check_held, observer)
            if not all(self._jaws_on(roles)):
                raise _Decided(Outcome.SLIPPED_DURING_LIFTING, "end")
            code, phase = Outcome.SUCCESS, "end"
        except _Decided as decided:
            code, phase = Outcome(decided.code), decided.phase
        finally:
            self.data.xfrc_applied[target] = 0.0
            self._gravity_view[:] = self._gravity
        if rel0 is not None:
            rel_p, rel_R = self._relative(target)
            rel_t = math.sqrt(float((rel_p - rel0[0]) @ (rel_p - rel0[0])))
            rel_r = _angle(rel0[1], rel_R)
        if shake_mark is not None:
            motion_shaking = self._motion(target, shake_mark)
        return self._result(code, phase, closed_width, nan, (rel_t, rel_r), contacts, motion_closing, motion_shaking,
                            pose_closed, self._final_drift(target, drift))

    def _acronym_shake(self, pos, quat, R, target, check_held, observer) -> None:
        """``acronym`` (:class:`AcronymParams`): gravity on as configured, shake along the approach axis, then about
        the closing axis through the TCP, then settle."""
        acr = self.params.acronym
        if acr.gravity == "world":
            self._gravity_view[:] = self._gravity
        elif acr.gravity == "approach":
            self._gravity_view[:] = math.sqrt(float(self._gravity @ self._gravity)) * R[:, 2]
        self._move(pos + self._shake_z[:, None] * R[:, 2], None, "shaking", check_held, observer)
        self._move(np.repeat(pos[None], len(self._shake_qx), axis=0), _quat_mul(quat, self._shake_qx),
                   "shaking", check_held, observer)
        self._wait(self._settle_steps, "holding", check_held, observer)

    def _graspgen_tugs(self, pos, quat, R, target, check_held, observer) -> None:
        """``graspgen`` (:class:`GraspGenParams`): gravity stays off; the object's weight pulls it along each tug
        direction (TCP frame at the grasp) at its centre of mass."""
        weight = self.params.graspgen.force_scale * float(self.model.body_subtreemass[target]) * math.sqrt(
            float(self._gravity @ self._gravity))
        for direction in self._tug_dirs:
            self.data.xfrc_applied[target, :3] = weight * (R @ direction)
            self._wait(self._tug_steps, "shaking", check_held, observer)
        self.data.xfrc_applied[target, :3] = 0.0
