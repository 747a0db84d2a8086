"""The evaluation protocols' settings and the record of one rollout: :class:`LiftParams` (with its sections
:class:`AcronymParams` and :class:`GraspDataGenParams`), the outcome codes (:class:`Outcome`, ARCHITECTURE.md,
Conventions) and :class:`RolloutResult`. The protocols run in :class:`graspgen.sim.lift.LiftSimulator` (the rules
are written out in its docstring); the motion profiles they follow are :mod:`graspgen.sim.motion`'s.

Protocols (:data:`PROTOCOLS`, ``LiftParams.protocol``): ``table`` is the pipeline's grasp-and-lift (place at the
pre-grasp pose, approach, close, lift, hold, shake; the default; with ``shake=False`` its results are what they were
before protocols were named, and before the shake was on by default); ``acronym`` is ACRONYM's free-space test: the
hand is placed at the grasp with open fingers and closes on the floating object, then gravity comes on along the
approach axis, the hand shakes along and about its own axes, and the label is whether the object is still between
the fingers (:class:`AcronymParams` cites where each number comes from). On the calibration mug
(``studies/fidelity.py``) a held object takes ~650-950 steps (0.2-0.8 s closing from fully open, 1 s of shaking, 0.1 s
settle), ~50 rollouts/s. ``graspdatagen`` is GraspDataGen's (the data generator of NVIDIA's GraspGen) free-space tug
test: gravity off, the open hand at the grasp closes, then the object is pulled with its own weight along the hand's
approach axis and four directions tilted 63.4 degrees from it, 0.5 s each; the label is whether both fingers still
touch it (:class:`GraspDataGenParams` cites the source).
"""

from __future__ import annotations

import dataclasses
import enum
import math
import struct
from dataclasses import dataclass, field, fields
from types import MappingProxyType
from typing import Literal

import numpy as np

from graspgen.errors import SettingsError
from graspgen.sim.physics import PhysicsOptions
from graspgen.validation import (
    check,
    check_bool,
    check_choice,
    check_instance,
    check_int,
    check_number,
    check_vector,
)
from shared_utils.keys import KEY_NAME, KEY_OMIT_DEFAULT, KEY_VALUES
from shared_utils.renames import RENAMED_FROM, RENAMED_VALUES, renamed_message

__all__ = ["Outcome", "OUTCOME_NAMES", "PAD_SINK", "PAD_TORSION", "PHASES", "PROTOCOLS", "PROTOCOL_KEYS",
           "RENAMED_PROTOCOLS", "AcronymParams", "GraspDataGenParams", "LiftParams", "RolloutResult", "check_protocol"]


PAD_TORSION = ("face", "patch")
"""The pads' torsional friction models (:attr:`LiftParams.pad_torsion`)."""

PAD_SINK = ("bounded", "model")
"""How deep the pads may sink into a light object (:attr:`LiftParams.pad_sink`)."""


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
#: ``acronym`` (ACRONYM's free-space close-and-shake, :class:`AcronymParams`) and ``graspdatagen`` (GraspDataGen's
#: free-space tug test, :class:`GraspDataGenParams`).
PROTOCOLS: tuple[str, ...] = ("table", "acronym", "graspdatagen")

#: Former protocol names and their names now: ``graspgen`` was GraspDataGen's protocol (renamed so that it is not
#: taken for this package or for NVIDIA's GraspGen format). A config or call that still uses one fails with a
#: message naming the new name.
RENAMED_PROTOCOLS = MappingProxyType({"graspgen": "graspdatagen"})

#: How content keys and seeds hash a protocol name: the renamed ones as they were (``shared_utils.keys.KEY_VALUES``),
#: so the rename keeps every key and random draw.
PROTOCOL_KEYS = MappingProxyType({new: old for old, new in RENAMED_PROTOCOLS.items()})


def check_protocol(name: str, value: object, choices: tuple[str, ...] = PROTOCOLS, why: str = "") -> str:
    """``value`` if it is one of ``choices``. SettingsError ``"name: protocol 'graspgen' was renamed
    'graspdatagen'"`` for a former name (:data:`RENAMED_PROTOCOLS`), else ``"name: must be one of table, acronym,
    graspdatagen<why>, got 'x'"``."""
    if isinstance(value, str) and value in RENAMED_PROTOCOLS:
        raise SettingsError(f"{name}: {renamed_message('protocol', value, RENAMED_PROTOCOLS[value])}")
    check(name, isinstance(value, str) and value in choices, f"be one of {', '.join(choices)}{why}", value)
    return value


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
class GraspDataGenParams:
    """Settings of the ``graspdatagen`` protocol (``LiftParams(protocol="graspdatagen")``): the grasp validation of
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

    The defaults are tuned on the Robotiq 2F-85 (``tests/graspgen/sim/test_lift.py``): a 1 kg box at friction 0.5 must
    be lifted and held, a 3 kg box at friction 0.3 must slip. Coulomb says the first needs a grip of 1 kg x (9.81 + 5
    m/s^2 of lift acceleration) / (2 x 0.5) = 14.8 N per jaw for the lift and 1 kg x (9.81 + 9.9 m/s^2) / (2 x 0.5) =
    19.7 N for the default shake's ~1 g peak, and the second 49 N just to hold still and 98.6 N through the shake.
    Measured without the shake, the 1 kg box is held from 14 N on and the 3 kg box slips up to 60 N (held from 65 N);
    with the default shake the 1 kg box slides 20 / 6 / 1 mm in the hand at 14 / 16 / 18 N (held: less than
    ``slip_tolerance``) and 0.1 mm from 20 N on, and the 3 kg box is shaken out up to 70 N (held from 80 N, still
    sliding 6 mm there, 0.4 mm at 100 N). ``grip_force`` = 30 N sits between the edges (1.5x the 1 kg box's Coulomb grip
    through the shake, 0.3x the 3 kg box's; the 2F-85 grips with 20-235 N).

    The ``table`` protocol disturbs the grasp after the hold by default (``shake``): ACRONYM's shake (Eppner,
    Mousavian, Fox, ICRA 2021, arXiv:2011.09584), with the numbers and the argument of :class:`AcronymParams`
    (``shake_*`` below say which).

    ``protocol`` names the phase sequence (:data:`PROTOCOLS`): ``table`` (default; every field below but
    ``acronym`` and ``graspdatagen``), ``acronym`` (its own settings in ``acronym``) or ``graspdatagen`` (its own
    settings in ``graspdatagen``); of the fields below these two use the closing stop (``close_speed_tol``,
    ``close_timeout``), ``check_interval`` and the physics. :meth:`with_protocol` switches.
    """

    # -- protocol ---------------------------------------------------------------------------------------------------
    protocol: Literal["table", "acronym", "graspdatagen"] = field(
        default="table", metadata={RENAMED_VALUES: RENAMED_PROTOCOLS, KEY_VALUES: PROTOCOL_KEYS})
    """``table``: place at the pre-grasp pose, approach, close, lift, hold, shake (``shake``, on by default), on a
    support or in free space (the pipeline's protocol). ``acronym``: ACRONYM's free-space protocol, placed at the
    grasp with the jaws open, close, shake along and about the hand's axes, label = object still between the
    fingers (:class:`AcronymParams`)."""
    acronym: AcronymParams = field(default_factory=AcronymParams)
    """Settings of the ``acronym`` protocol (ignored by the others)."""
    graspdatagen: GraspDataGenParams = field(default_factory=GraspDataGenParams,
                                             metadata={RENAMED_FROM: ("graspgen",), KEY_NAME: "graspgen"})
    """Settings of the ``graspdatagen`` protocol (ignored by the others): gravity off, close, then tug the object with
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
    pad_torsion: str = field(default="patch", metadata={KEY_OMIT_DEFAULT: True})
    """The pads' torsional friction arm: ``"patch"``, that of the pressure the target puts on the pad's face once
    the jaws have closed (:mod:`graspgen.sim.pad_patch`), or ``"face"``, the whole pad face's for every grasp
    (:func:`graspgen.sim.gripper_model.pad_torsion_arm`, the upper end)."""
    pad_sink: str = field(default="bounded", metadata={KEY_OMIT_DEFAULT: True})
    """``"bounded"``: the pads sink no deeper than the gripper's impedance width into the scene's lightest object
    (:mod:`graspgen.sim.pad_sink`); ``"model"``: the gripper model's contact whatever the object's mass."""

    def __post_init__(self) -> None:
        check_protocol("protocol", self.protocol)
        check_instance("acronym", self.acronym, AcronymParams)
        check_instance("graspdatagen", self.graspdatagen, GraspDataGenParams)
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
        check_choice("pad_torsion", self.pad_torsion, PAD_TORSION)
        check_choice("pad_sink", self.pad_sink, PAD_SINK)
        self.physics_options((0.0, 0.0, -9.81))  # validates timestep, cone, impratio, integrator (names the field)

    def physics_options(self, gravity) -> PhysicsOptions:
        """These physics settings as :class:`graspgen.sim.physics.PhysicsOptions`, with the scene's ``gravity``."""
        return PhysicsOptions(timestep=self.timestep, cone=self.cone, impratio=self.impratio,
                              integrator=self.integrator, gravity=tuple(float(g) for g in gravity))

    def with_protocol(self, protocol: str) -> LiftParams:
        """A copy with ``protocol`` set (the other settings, the protocols' sections included, are kept)."""
        check_protocol("protocol", protocol)
        return dataclasses.replace(self, protocol=protocol)

    def to_dict(self) -> dict:
        """Plain-data view (for configs and metadata)."""
        return {f.name: (getattr(self, f.name).to_dict() if f.name in ("acronym", "graspdatagen")
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
    (``table``: lift, hold, shake; ``acronym``: shake and settle; ``graspdatagen``: the tugs) and its end. Unlike
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
