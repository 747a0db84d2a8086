"""Object-centric grasp sets, ACRONYM / GraspGen style: one object alone in free space, grasps from every side.

:func:`label_object_grasps` takes one prepared object (an :class:`graspgen.io.objects.ObjectRecord`, mesh frame = the
object frame) and labels grasps on it until it has ``target_positives`` successes and ``target_negatives`` failures,
or has tried ``max_candidates``:

1. **Candidates**, in batches of ``batch_size``. ``round(near_miss_fraction * batch_size)`` of each batch are near
   misses, the rest antipodal candidates; once ``target_positives`` successes are kept, only failures can still be
   kept and ``near_miss_fraction_when_positives_met`` (0.8) of each batch are near misses, where the failures are.

   - ``antipodal``: :func:`graspgen.geometry.antipodal.sample_antipodal` on the record's mesh in its own frame with
     the approach filter off (``approach="any"``): approach axes over the whole sphere, from below as much as from
     above (free space has no "down"). Each call of the sampler gives a few thousand candidates (contact pairs x
     orientations x depths); they are shuffled into a pool and each batch takes the next ones, so a batch mixes
     many contact pairs.
   - ``near_miss``: a copy of an antipodal candidate that succeeded earlier in the loop (its *parent*, drawn
     uniformly from all of them; until the first success, from the batch's own antipodal candidates) moved just far
     enough that the grasp the sampler meant is no longer there (:func:`near_miss_offsets`). Parents that held make
     near misses of good grasps: most antipodal candidates on hollow or long objects collide at placement (93 % on
     the calibration mug), and a near miss of a collision is just another collision. Half of them (by a
     coin flip) are **shifted**: the hand moves in the plane of its pads (TCP y-z) in a uniformly random direction,
     by the distance at which the parent's contact point leaves the pad face plus ``near_miss_overhang`` (default
     half the pad face's width, ``pad_size[1] / 2``: Panda 8.7 mm, 2F-85 11 mm): the pads press half a pad away from
     the spot they were aimed at, so where the surface goes on that far (a broad face) the grasp still holds and
     where it does not (an edge, a rim, a handle, a curved side) a pad misses or catches a corner. The other half
     are **tilted**: the hand turns about the TCP by ``near_miss_tilt`` about a uniformly random axis perpendicular
     to the approach (TCP x-y plane). The default tilt, ``atan(max_width / (2 finger_length))`` (Panda 0.640 rad =
     37 degrees, 2F-85 0.427 rad), is the smallest at which the base of an open finger (``finger_size[2]`` behind
     its tip) swings sideways past the grasp's centre line: about the closing axis it sweeps through the space the
     object fills between the jaws, so the finger or the palm turns into the object unless the object ends before
     the finger's base (a rim, a handle, a short part). Both sizes come from the gripper's own geometry
     (``pad_size``, ``finger_size``, ``max_width``), so they mean the same for any gripper. Measured (Panda,
     ``acronym``, friction 1.0; 3 near misses of each of 29-40 successful antipodal parents on the bundled box, mug,
     can, bowl, bottle and wedge): the default shift keeps 38-59 % of them successful, the default tilt 43-65 %; a
     3 mm overhang would keep 62-80 % and a 0.2 rad tilt 78-97 %: too close to the parent to be negatives. So
     about half of the near misses of good grasps fail: the negatives a learned grasp model finds hardest, one pad
     or one finger length from a good grasp; the other half are positives beside known ones (on the calibration
     mug, where 6 % of the antipodal candidates hold, three quarters of the positives; lower
     ``near_miss_fraction`` for more distinct contact pairs among them). Their width is the parent's.

2. **Rollouts** in free space (:func:`free_space_simulator`: the object alone, :func:`graspgen.sim.scene_model.
   free_space_spec`, the gripper attached; compiled once) with a free-space protocol of :mod:`graspgen.sim.lift`:
   ``acronym`` (default; the hand placed open at the grasp, close, shake) or ``graspgen`` (close, five tugs at the
   object's weight). Both open the jaws to the protocol's ``open_width`` (fully by default), whatever the grasp's
   width (the ``open_width`` column). Candidates are rolled out one by one in trial order; a success is kept while
   fewer than ``target_positives`` successes are kept, a failure while fewer than ``target_negatives`` failures
   are (a collision at placement, outcomes 0-2, only while collisions are fewer than ``collision_share`` of
   ``target_negatives``), and the loop stops when both targets are met or ``max_candidates`` rollouts were made.
   "Success" is the ``label`` setting's: ``held`` (default: outcome 5, the object still between the fingers,
   ACRONYM's label, so the set is what it was before the firm label existed) or ``firm`` (outcome 5 with the
   object's motion in the hand within the firm-hold tolerances, :mod:`graspgen.sim.lift`; held-but-not-firm
   grasps are then negatives). Both labels are in every row (``success``, ``firm``).

3. **Labels per kept row**: the rollout's outcome, ACRONYM's four motion measures, the finger contacts at the end of
   closing in the object frame (mapped with the object's pose when closing ended, so exactly), the Ferrari-Canny
   epsilon of those contacts (:class:`graspgen.quality.epsilon.EpsilonParams`; successes only) and, with
   ``num_perturbations > 0``, the success rate of that many copies of each kept success with the gripper pose
   perturbed at the grasp (``T @ [R(w) | t]``, ``t ~ N(0, perturbation_translation^2 I)``, ``w ~ N(0,
   perturbation_rotation^2 I)``, TCP frame; :func:`graspgen.quality.robustness.perturbed_poses`).

Randomness: everything comes from the generator passed in, in a fixed order: per batch, sampler refills as needed
(each shuffled), the near misses' parents and offsets, the batch's order (the parents' pool depends on earlier
rollouts, which are deterministic); after the loop, the robustness noise
(``(positives, num_perturbations, 6)`` standard normals). Rollouts are deterministic (:mod:`graspgen.sim.lift`), so
the same record, settings and seed give the same table, byte for byte.

Output: one row per kept grasp, in trial order (:data:`SCHEMA`):

======================  ==============  =====================================================================
column                  type            meaning
======================  ==============  =====================================================================
object_name             string          the object (the record's name)
grasp_id                int32           0..n-1 in trial order
candidate               string          ``antipodal`` or ``near_miss``
gripper                 string          gripper name or file (``object_grasps.gripper``)
protocol                string          ``acronym`` or ``graspgen``
pose_object             float64[16]     TCP pose in the record's mesh frame, 4x4 row-major (z approach, x closing)
width                   float64         pad separation at the sampled contacts, m (a near miss: its parent's)
open_width              float64         jaw opening the protocol used, m
outcome                 int8            0-5 (:class:`graspgen.sim.lift.Outcome`)
outcome_name            string          its name
decided_in              string          protocol phase that decided it
success                 bool            ``outcome == 5``: still in the hand (ACRONYM's ``object_in_gripper``)
firm                    bool            firm hold: a success whose motion in the hand stayed within
                                        ``lift.firm_translation`` / ``firm_rotation`` (:mod:`graspgen.sim.lift`)
max_rel_translation     float64         largest displacement of the object in the hand (TCP frame) during the
                                        shake / tugs, from the end of closing, m (NaN if none ran)
max_rel_rotation        float64         largest rotation of the object in the hand over the same span, rad
closed_width            float64         pad separation when closing ended, m (NaN if not reached)
motion_closing_linear   float64         object displacement while the fingers closed, m
motion_closing_angular  float64         object rotation while the fingers closed, rad
motion_shaking_linear   float64         object displacement during the shake / tugs, m (NaN if none ran)
motion_shaking_angular  float64         object rotation during the shake / tugs, rad
contact_points          list<float64>   finger-object contacts at the end of closing, object frame, k*3 values
contact_normals         list<float64>   their normals, into the object, object frame, k*3 values
contact_forces          list<float64>   their normal forces, N, k values
contact_fingers         list<int8>      0 left pad/finger, 1 right, k values
epsilon                 float64         Ferrari-Canny epsilon of those contacts (unit-free); NaN unless a
                                        success with contacts
robustness_n            int32           perturbed copies rolled out (0 unless a success and
                                        ``num_perturbations > 0``)
robustness              float64         their success fraction (positives by ``label``); NaN when
                                        ``robustness_n`` is 0
======================  ==============  =====================================================================
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

import numpy as np
import pyarrow as pa
import trimesh

from graspgen.geometry.antipodal import AntipodalParams
from graspgen.io.arrow import fixed_list, variable_list
from graspgen.io.objects import ObjectRecord
from graspgen.quality.epsilon import EpsilonParams, object_geometry
from graspgen.quality.robustness import perturbed_poses, rotvec_to_matrix
from graspgen.sim.candidate_pool import CandidatePool, collision_cap
from graspgen.sim.grippers import GripperSpec, attach_gripper, load_gripper
from graspgen.sim.lift import OUTCOME_NAMES, LiftParams, LiftSimulator, Outcome, RolloutResult
from graspgen.sim.scene_model import free_space_spec, object_body_name, placed_object
from graspgen.validation import check, check_instance, check_int, check_number, check_rng

__all__ = [
    "CANDIDATES",
    "LABELS",
    "PROTOCOLS",
    "SCHEMA",
    "ObjectGraspsParams",
    "default_overhang",
    "default_tilt",
    "free_space_simulator",
    "label_object_grasps",
    "near_miss_draws",
    "near_miss_offsets",
    "protocol_opening",
]

PROTOCOLS: tuple[str, ...] = ("acronym", "graspgen")
"""The protocols an object-centric set may use: the free-space ones of :data:`graspgen.sim.lift.PROTOCOLS`."""

LABELS: tuple[str, ...] = ("held", "firm")
"""Values of :attr:`ObjectGraspsParams.label`: which label makes a positive."""

CANDIDATES: tuple[str, ...] = ("antipodal", "near_miss")
"""Values of the ``candidate`` column."""

SCHEMA = pa.schema(
    [
        ("object_name", pa.string()),
        ("grasp_id", pa.int32()),
        ("candidate", pa.string()),
        ("gripper", pa.string()),
        ("protocol", pa.string()),
        ("pose_object", pa.list_(pa.float64(), 16)),
        ("width", pa.float64()),
        ("open_width", pa.float64()),
        ("outcome", pa.int8()),
        ("outcome_name", pa.string()),
        ("decided_in", pa.string()),
        ("success", pa.bool_()),
        ("firm", pa.bool_()),
        ("max_rel_translation", pa.float64()),
        ("max_rel_rotation", pa.float64()),
        ("closed_width", pa.float64()),
        ("motion_closing_linear", pa.float64()),
        ("motion_closing_angular", pa.float64()),
        ("motion_shaking_linear", pa.float64()),
        ("motion_shaking_angular", pa.float64()),
        ("contact_points", pa.list_(pa.float64())),
        ("contact_normals", pa.list_(pa.float64())),
        ("contact_forces", pa.list_(pa.float64())),
        ("contact_fingers", pa.list_(pa.int8())),
        ("epsilon", pa.float64()),
        ("robustness_n", pa.int32()),
        ("robustness", pa.float64()),
    ]
)
"""The object grasp table's schema (see the module docstring)."""


# ---------------------------------------------------------------------------------------------------------------
# Settings
# ---------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class ObjectGraspsParams:
    """Settings of an object-centric grasp set (config section ``object_grasps``; module docstring)."""

    gripper: str = "panda"
    """Gripper model: robotiq_2f85, panda or box_jaw, or the path of a gripper file (.yaml, .yml, .json). The Panda
    is ACRONYM's and GraspGen's gripper."""
    protocol: str = "acronym"
    """Free-space protocol of the rollouts: ``acronym`` (placed open at the grasp, close, shake; ACRONYM's test) or
    ``graspgen`` (close, then five tugs at the object's weight; GraspDataGen's test). It sets ``lift.protocol``."""
    target_positives: int = 1000
    """Successes to keep per object (the first ones in trial order)."""
    target_negatives: int = 1000
    """Failures (any outcome but success) to keep per object (the first ones in trial order)."""
    max_candidates: int = 20000
    """Most rollouts per object; the loop stops here even when a target is not met (a warning says so)."""
    collision_share: float = 0.25
    """Largest share of the kept negatives that may be collisions at placement (outcomes 0-2: the open hand
    intersects the object where the grasp puts it). Those are the cheapest negatives and the least informative: the
    hand never closed, and a plain collision check finds them without physics. Without a cap they fill the negatives
    of hollow and long objects (93 % of the antipodal candidates on the calibration mug collide), leaving none of
    the failures that teach a grasp model what does not hold (slips, closing on air). In [0, 1]; 1 keeps failures
    as they come."""
    batch_size: int = 128
    """Candidates sampled per batch (antipodal plus near misses, in a shuffled order)."""
    near_miss_fraction: float = 0.3
    """Share of each batch that are near misses (``round(fraction * batch_size)``), in [0, 1)."""
    near_miss_fraction_when_positives_met: float = 0.8
    """Share of each batch that are near misses once ``target_positives`` successes are kept (and some antipodal
    candidate has held), in [0, 1). From then on only failures are kept, and they are where the near misses are:
    on the calibration mug 12 % of near misses fail without a collision against 0.2 % of antipodal candidates, so a
    batch of mostly near misses finds the negatives ~10x sooner instead of rolling out successes that are thrown
    away (each a full closing and shake)."""
    near_miss_overhang: float | None = None
    """Shifted near misses: how far (m) beyond the edge of the pad face the parent's contact point ends up, along
    the shift (the shift is the distance from the contact to the pad's edge in a random in-plane direction plus
    this); null: half the pad face's width, ``pad_size[1] / 2`` (Panda 8.7 mm)."""
    near_miss_tilt: float | None = None
    """Tilted near misses: the tilt (rad, in (0, pi/2]) of the hand about the TCP, about a random axis
    perpendicular to the approach; null: ``atan(max_width / (2 finger_length))`` of the gripper (Panda 0.640 rad),
    the smallest tilt that swings an open finger's base past the grasp's centre line."""
    sampler: AntipodalParams = dataclasses.field(default_factory=lambda: AntipodalParams(approach="any"))
    """Antipodal sampling on the object's mesh (surface points, friction cone, orientations, depths). Its
    ``approach`` is always ``any`` here: approach axes over the whole sphere, in the object frame."""
    lift: LiftParams = dataclasses.field(default_factory=lambda: LiftParams(protocol="acronym"))
    """The rollout's protocol settings (``lift.acronym``, ``lift.graspgen``, physics); ``lift.protocol`` is set
    from ``protocol``."""
    friction: float = 1.0
    """Sliding friction coefficient (dimensionless) of an object whose record carries none (``attrs["friction"]``);
    1.0 is ACRONYM's coefficient for every object."""
    num_perturbations: int = 0
    """Robustness: copies of each kept success rolled out with the gripper pose perturbed at the grasp; 0 = off."""
    perturbation_translation: float = 0.005
    """Robustness: standard deviation (m) of the TCP translation error along each TCP axis (the robustness
    stage's 5 mm)."""
    perturbation_rotation: float = math.radians(5.0)
    """Robustness: standard deviation (rad) of each component of the TCP rotation error (a rotation vector in the
    TCP frame; the robustness stage's 5 degrees)."""
    epsilon: EpsilonParams = dataclasses.field(default_factory=EpsilonParams)
    """Contact model and friction of the epsilon (``epsilon.friction`` null: the object's friction)."""
    label: str = "held"
    """Which label makes a positive (a kept success, a near miss's parent, a robustness copy's win): ``held``
    (default; outcome 5, the object still between the fingers after the disturbance: ACRONYM's
    ``object_in_gripper``, so the set's positives are ACRONYM's and the ACRONYM export's ``object_in_gripper`` is
    this) or ``firm`` (also the object's motion in the hand within ``lift.firm_translation`` / ``firm_rotation``;
    a held-but-not-firm grasp is then kept as a negative). The other label is stored in every row either way
    (``success``, ``firm``)."""

    def __post_init__(self) -> None:
        check("gripper", isinstance(self.gripper, str) and bool(self.gripper),
              "be a gripper name or the path of a gripper file", self.gripper)
        load_gripper(self.gripper)  # unknown name: lists the bundled ones; bad file: names it and what is wrong
        check("protocol", self.protocol in PROTOCOLS,
              f"be one of {', '.join(PROTOCOLS)} (the free-space protocols; 'table' needs a support)", self.protocol)
        for key in ("target_positives", "target_negatives"):
            object.__setattr__(self, key, check_int(key, getattr(self, key), low=0))
        check("target_negatives", self.target_positives + self.target_negatives > 0,
              "be > 0 when target_positives is 0 (nothing to keep)", self.target_negatives)
        object.__setattr__(self, "collision_share", check_number("collision_share", self.collision_share,
                                                                 low=0.0, high=1.0))
        for key in ("max_candidates", "batch_size"):
            object.__setattr__(self, key, check_int(key, getattr(self, key), low=1))
        object.__setattr__(self, "near_miss_fraction", check_number(
            "near_miss_fraction", self.near_miss_fraction, low=0.0, high=1.0, high_open=True))
        object.__setattr__(self, "near_miss_fraction_when_positives_met", check_number(
            "near_miss_fraction_when_positives_met", self.near_miss_fraction_when_positives_met, low=0.0, high=1.0,
            high_open=True))
        check("near_miss_fraction_when_positives_met",
              round(self.near_miss_fraction_when_positives_met * self.batch_size) < self.batch_size,
              f"leave at least one antipodal candidate per batch of {self.batch_size}",
              self.near_miss_fraction_when_positives_met)
        check("near_miss_fraction", self.near_misses_per_batch < self.batch_size,
              f"leave at least one antipodal candidate per batch of {self.batch_size}", self.near_miss_fraction)
        if self.near_miss_overhang is not None:
            object.__setattr__(self, "near_miss_overhang", check_number("near_miss_overhang",
                                                                        self.near_miss_overhang, low=0.0))
        if self.near_miss_tilt is not None:
            object.__setattr__(self, "near_miss_tilt", check_number(
                "near_miss_tilt", self.near_miss_tilt, low=0.0, high=math.pi / 2, low_open=True))
        check_instance("sampler", self.sampler, AntipodalParams)
        if self.sampler.approach != "any":
            object.__setattr__(self, "sampler", dataclasses.replace(self.sampler, approach="any"))
        check_instance("lift", self.lift, LiftParams)
        if self.lift.protocol != self.protocol:
            object.__setattr__(self, "lift", self.lift.with_protocol(self.protocol))
        object.__setattr__(self, "friction", check_number("friction", self.friction, low=0.0, low_open=True))
        object.__setattr__(self, "num_perturbations", check_int("num_perturbations", self.num_perturbations, low=0))
        for key in ("perturbation_translation", "perturbation_rotation"):
            object.__setattr__(self, key, check_number(key, getattr(self, key), low=0.0))
        check_instance("epsilon", self.epsilon, EpsilonParams)
        check("label", self.label in LABELS, f"be one of {', '.join(LABELS)}", self.label)

    def positive(self, result: RolloutResult) -> bool:
        """Whether ``result`` is a positive under :attr:`label` (``held``: outcome 5; ``firm``: ``result.firm``)."""
        return bool(result.firm) if self.label == "firm" else result.code == Outcome.SUCCESS

    @property
    def near_misses_per_batch(self) -> int:
        """Near misses in each batch: ``round(near_miss_fraction * batch_size)``."""
        return int(round(self.near_miss_fraction * self.batch_size))

    def overhang(self, gripper: GripperSpec) -> float:
        """The shifted near misses' overhang (m) for ``gripper``: ``near_miss_overhang`` or
        :func:`default_overhang`."""
        return default_overhang(gripper) if self.near_miss_overhang is None else float(self.near_miss_overhang)

    def tilt(self, gripper: GripperSpec) -> float:
        """The tilted near misses' tilt (rad) for ``gripper``: ``near_miss_tilt`` or :func:`default_tilt`."""
        return default_tilt(gripper) if self.near_miss_tilt is None else float(self.near_miss_tilt)


def default_overhang(gripper: GripperSpec) -> float:
    """Half the width of the gripper's pad face, ``pad_size[1] / 2`` (m): how far past the pad's edge a shifted near
    miss leaves the contact it was aimed at (module docstring)."""
    return gripper.pad_size[1] / 2.0


def default_tilt(gripper: GripperSpec) -> float:
    """``atan(max_width / (2 finger_length))`` (rad): the tilt about the TCP that swings the base of an open finger
    (``finger_size[2]`` behind its tip) sideways by half the opening, past the grasp's centre line (module
    docstring)."""
    return math.atan(gripper.max_width / (2.0 * gripper.finger_size[2]))


def protocol_opening(gripper: GripperSpec, lift: LiftParams) -> float:
    """Pad separation (m) the jaws open to under a free-space protocol: its ``open_width`` (the gripper's
    ``max_width`` when null), clipped to the gripper's range (as :class:`graspgen.sim.lift.LiftSimulator` does)."""
    settings = lift.acronym if lift.protocol == "acronym" else lift.graspgen
    opening = gripper.max_width if settings.open_width is None else settings.open_width
    return float(np.clip(opening, gripper.min_width, gripper.max_width))


# ---------------------------------------------------------------------------------------------------------------
# Near misses
# ---------------------------------------------------------------------------------------------------------------


def near_miss_draws(rng: np.random.Generator, n: int) -> np.ndarray:
    """The random part of ``n`` near misses: ``(n, 2)`` uniforms in [0, 1): the kind (< 0.5 shifted, else tilted)
    and the direction (an angle, ``2 pi u``)."""
    return rng.random((n, 2))


def near_miss_offsets(depth: np.ndarray, draws: np.ndarray, gripper: GripperSpec, overhang: float,
                      tilt: float) -> np.ndarray:
    """The near misses' offsets in their parents' TCP frames: ``T_near = T_parent @ D``.

    Parameters
    ----------
    depth : (n,) float, m
        The parents' grasp depths (their contacts at ``(-+width / 2, 0, depth)`` in the TCP frame).
    draws : (n, 2) float in [0, 1)
        :func:`near_miss_draws`: kind (< 0.5 shifted) and direction angle ``phi = 2 pi u``.
    gripper : GripperSpec
        Its ``pad_size`` (width along y, length along z) bounds the pad face, centred on the TCP's y-z origin.
    overhang : float, m
        Shifted: the contact point ends this far beyond the pad face's edge, along the shift.
    tilt : float, rad
        Tilted: the rotation angle.

    Returns
    -------
    D : (n, 4, 4) float
        Shifted: no rotation, a translation ``s (0, cos phi, sin phi)`` with ``s`` such that the parent's contact
        point, which moves by ``-s (0, cos phi, sin phi)`` relative to the pads, crosses the pad face's edge at ``s
        - overhang``. Tilted: no translation, a rotation by ``tilt`` about ``(cos phi, sin phi, 0)`` (through the
        TCP, perpendicular to the approach).
    """
    depth = np.asarray(depth, dtype=np.float64).reshape(-1)
    draws = np.asarray(draws, dtype=np.float64).reshape(-1, 2)
    if len(draws) != len(depth):
        raise ValueError(f"draws: expected {len(depth)} rows (one per depth), got {len(draws)}")
    n = len(depth)
    phi = 2.0 * math.pi * draws[:, 1]
    c, s = np.cos(phi), np.sin(phi)
    shifted = draws[:, 0] < 0.5
    half_y, half_z = gripper.pad_size[1] / 2.0, gripper.pad_size[2] / 2.0
    # The contact (y, z) = (0, depth) moves along -(c, s) relative to the pads; the distance to the face's edge:
    with np.errstate(divide="ignore"):
        to_y = np.where(np.abs(c) > 1e-12, half_y / np.abs(c), np.inf)
        to_z = np.where(s < -1e-12, (half_z - depth) / -s, np.where(s > 1e-12, (half_z + depth) / s, np.inf))
    distance = np.maximum(np.minimum(to_y, to_z), 0.0) + overhang
    D = np.tile(np.eye(4), (n, 1, 1))
    D[shifted, 1, 3] = (distance * c)[shifted]
    D[shifted, 2, 3] = (distance * s)[shifted]
    axes = np.stack([c, s, np.zeros(n)], axis=1)
    tilted = ~shifted
    if tilted.any():
        D[tilted, :3, :3] = rotvec_to_matrix(tilt * axes[tilted])
    return D


# ---------------------------------------------------------------------------------------------------------------
# The world
# ---------------------------------------------------------------------------------------------------------------


def free_space_simulator(record: ObjectRecord, gripper: str, lift: LiftParams,
                         friction: float) -> tuple[LiftSimulator, str]:
    """The object alone in free space at the identity pose (world = mesh frame) with ``gripper`` attached,
    compiled: ``(simulator, target body name)``. Gravity is the scene's (0, 0, -9.81); the free-space protocols
    switch it off and on themselves.

    Parameters
    ----------
    record : ObjectRecord
        Convex parts, mass, centre of mass and inertia of the object (its mesh frame).
    gripper : str
        A bundled gripper name or a gripper file (:func:`graspgen.sim.grippers.load_gripper`).
    lift : LiftParams
        The protocol and physics.
    friction : float
        The object's sliding friction coefficient (it governs the gripper contacts).
    """
    obj = placed_object(record, np.eye(4), friction, visual=False)
    spec = free_space_spec(obj, lift.physics_options((0.0, 0.0, -9.81)))
    attach_gripper(spec, load_gripper(gripper))
    return LiftSimulator(spec.compile(), lift), object_body_name(0, record.name)


# ---------------------------------------------------------------------------------------------------------------
# Labelling
# ---------------------------------------------------------------------------------------------------------------


def _object_frame(result: RolloutResult) -> np.ndarray:
    """World -> object frame when the contacts were recorded (end of closing); the identity (the object's initial
    pose) when closing was not reached."""
    pose = result.target_pose_closed
    return np.linalg.inv(pose) if np.isfinite(pose).all() else np.eye(4)


def label_object_grasps(record: ObjectRecord, params: ObjectGraspsParams,
                        rng: np.random.Generator) -> tuple[pa.Table, dict[str, Any]]:
    """Sample, roll out and label grasps on one object in free space until the targets are met (module docstring).

    Parameters
    ----------
    record : ObjectRecord
        The prepared object (:func:`graspgen.io.objects.read_object`); its ``attrs["friction"]``, when present,
        is its friction, else ``params.friction``.
    params : ObjectGraspsParams
    rng : numpy.random.Generator
        The only source of randomness (module docstring, Randomness).

    Returns
    -------
    table : pyarrow.Table
        :data:`SCHEMA`, at most ``target_positives + target_negatives`` rows in trial order.
    meta : dict
        ``tried`` (rollouts of candidates), ``positives``, ``negatives`` (kept), ``reached`` (both targets met),
        ``stopped`` (``targets``, ``max_candidates`` or ``no_candidates``: the sampler found no pair the gripper
        opens around), ``outcomes`` (histogram of everything tried, by name), ``candidates`` (tried, by kind),
        ``outcomes_by_candidate`` (the histogram by kind), ``success_rate`` (by kind, over everything tried; None
        without any), ``sampled`` (antipodal candidates
        the sampler produced), ``friction``, ``open_width``, ``near_miss`` (the overhang and tilt used),
        ``robustness`` (copies rolled out and their mean success, when on), ``rollouts`` (all, copies included),
        ``seconds`` and ``rollouts_per_s`` (wall clock: the only entries that vary between runs).

    Raises
    ------
    graspgen.errors.InputError
        The record's mesh is degenerate (all vertices at the centre of mass).
    graspgen.errors.SettingsError
        Wrong argument types (the message names the argument).
    """
    check_instance("record", record, ObjectRecord)
    check_instance("params", params, ObjectGraspsParams)
    check_rng("rng", rng)
    start = time.perf_counter()
    gripper = load_gripper(params.gripper)
    attrs_friction = (record.attrs or {}).get("friction")
    friction = params.friction if attrs_friction is None else check_number(
        f"{record.name}.attrs.friction", float(attrs_friction), low=0.0, low_open=True)
    lift = params.lift
    opening = protocol_opening(gripper, lift)
    overhang, tilt = params.overhang(gripper), params.tilt(gripper)
    geometry = object_geometry(record)
    simulator, body = free_space_simulator(record, params.gripper, lift, friction)
    mesh = trimesh.Trimesh(np.asarray(record.vertices, dtype=np.float64), np.asarray(record.faces), process=False)
    pool = CandidatePool(mesh, gripper, params.sampler, rng)

    n_near_late = round(params.near_miss_fraction_when_positives_met * params.batch_size)
    counts = np.zeros(len(OUTCOME_NAMES), dtype=np.int64)
    by_kind = {k: np.zeros(len(OUTCOME_NAMES), dtype=np.int64) for k in CANDIDATES}  # outcome counts per kind
    kept: list[tuple[str, np.ndarray, float, RolloutResult]] = []
    positives = negatives = tried = collisions = 0
    max_collisions = collision_cap(params.collision_share, params.target_negatives)
    stopped = "max_candidates"
    good_pose: list[np.ndarray] = []  # the antipodal candidates that succeeded: the near misses' parents
    good_width: list[float] = []
    good_depth: list[float] = []

    def done() -> bool:
        return positives >= params.target_positives and negatives >= params.target_negatives

    while tried < params.max_candidates and not done():
        # Once the positives are in (and near misses of held grasps can be made), look for negatives where they are.
        late = positives >= params.target_positives and bool(good_pose)
        n_near = n_near_late if late else params.near_misses_per_batch
        pose, width, depth = pool.take(params.batch_size - n_near)
        if len(width) == 0:
            stopped = "no_candidates"
            break
        # Parents: the antipodal successes so far (near misses of good grasps); before the first, this batch's own.
        source = (pose, width, depth)
        if good_pose:
            source = (np.array(good_pose), np.array(good_width), np.array(good_depth))
        parent = rng.integers(0, len(source[1]), size=n_near)
        D = near_miss_offsets(source[2][parent], near_miss_draws(rng, n_near), gripper, overhang, tilt)
        batch_pose = np.concatenate([pose, source[0][parent] @ D])
        batch_width = np.concatenate([width, source[1][parent]])
        kinds = [CANDIDATES[0]] * len(width) + [CANDIDATES[1]] * n_near
        for i in rng.permutation(len(batch_width)):
            if tried >= params.max_candidates or done():
                break
            T, w, kind = batch_pose[i], float(batch_width[i]), kinds[i]
            result = simulator.rollout(T, w, body)
            tried += 1
            counts[result.code] += 1
            by_kind[kind][result.code] += 1
            if params.positive(result):
                if kind == CANDIDATES[0]:
                    good_pose.append(T)
                    good_width.append(w)
                    good_depth.append(float(depth[i]))
                if positives < params.target_positives:
                    positives += 1
                    kept.append((kind, T, w, result))
            elif negatives < params.target_negatives:
                if result.code <= Outcome.COLLISION_WITH_CLUTTER:
                    if collisions >= max_collisions:
                        continue
                    collisions += 1
                negatives += 1
                kept.append((kind, T, w, result))
    if done():
        stopped = "targets"

    # -- labels of the kept rows: contacts in the object frame, epsilon, robustness --------------------------------
    ep = params.epsilon
    mu = friction if ep.friction is None else float(ep.friction)
    n_copies = params.num_perturbations
    success_rows = [j for j, (_, _, _, r) in enumerate(kept) if params.positive(r)]
    noise = rng.standard_normal((len(success_rows), n_copies, 6)) if n_copies else None
    points, normals, epsilon = [], [], np.full(len(kept), math.nan)
    for j, (_, _, _, r) in enumerate(kept):
        F = _object_frame(r)
        p = r.contact_points @ F[:3, :3].T + F[:3, 3]
        nrm = r.contact_normals @ F[:3, :3].T
        points.append(p)
        normals.append(nrm)
        if r.code == Outcome.SUCCESS and len(p):
            epsilon[j] = ep.epsilon(p, nrm, r.contact_fingers, geometry, mu)
    robust_n = np.zeros(len(kept), dtype=np.int32)
    robust = np.full(len(kept), math.nan)
    copies = 0
    if n_copies:
        for row, z in zip(success_rows, noise):
            T = kept[row][1]
            Ts = perturbed_poses(T, params.perturbation_translation * z[:, :3], params.perturbation_rotation * z[:, 3:])
            wins = sum(params.positive(simulator.rollout(Tc, kept[row][2], body)) for Tc in Ts)
            robust_n[row], robust[row] = n_copies, wins / n_copies
            copies += n_copies

    table = _table(record.name, params, opening, kept, points, normals, epsilon, robust_n, robust)
    seconds = time.perf_counter() - start
    rollouts = tried + copies
    meta: dict[str, Any] = {
        "object": record.name,
        "gripper": params.gripper,
        "protocol": lift.protocol,
        "tried": tried,
        "positives": positives,
        "negatives": negatives,
        "target_positives": params.target_positives,
        "target_negatives": params.target_negatives,
        "max_candidates": params.max_candidates,
        "reached": stopped == "targets",
        "collision_negatives": collisions,
        "stopped": stopped,
        "outcomes": {name: int(counts[c]) for c, name in enumerate(OUTCOME_NAMES)},
        "candidates": {k: int(v.sum()) for k, v in by_kind.items()},
        "outcomes_by_candidate": {k: {name: int(v[c]) for c, name in enumerate(OUTCOME_NAMES)}
                                  for k, v in by_kind.items()},
        "success_rate": {k: (int(v[Outcome.SUCCESS]) / int(v.sum()) if v.sum() else None)
                         for k, v in by_kind.items()},
        "sampled": pool.sampled,
        "friction": friction,
        "open_width": opening,
        "near_miss": {"overhang": overhang, "tilt": tilt},
        "rollouts": rollouts,
        "seconds": round(seconds, 3),
        "rollouts_per_s": round(rollouts / seconds, 2) if seconds > 0 else None,
    }
    if n_copies:
        meta["robustness"] = {"copies": copies, "mean": float(np.mean(robust[success_rows])) if success_rows
                              else None}
    return table, meta


def _table(name: str, params: ObjectGraspsParams, opening: float, kept: list, points: list, normals: list,
           epsilon: np.ndarray, robust_n: np.ndarray, robust: np.ndarray) -> pa.Table:
    n = len(kept)
    results: list[RolloutResult] = [k[3] for k in kept]

    def num(attr: str) -> pa.Array:
        return pa.array(np.array([getattr(r, attr) for r in results], dtype=np.float64), pa.float64())

    codes = np.array([r.code for r in results], dtype=np.int8)
    arrays = {
        "object_name": pa.array([name] * n, pa.string()),
        "grasp_id": pa.array(np.arange(n, dtype=np.int32)),
        "candidate": pa.array([k[0] for k in kept], pa.string()),
        "gripper": pa.array([params.gripper] * n, pa.string()),
        "protocol": pa.array([params.protocol] * n, pa.string()),
        "pose_object": fixed_list(np.array([k[1] for k in kept], dtype=np.float64).reshape(n, 16), 16),
        "width": pa.array(np.array([k[2] for k in kept], dtype=np.float64), pa.float64()),
        "open_width": pa.array(np.full(n, opening), pa.float64()),
        "outcome": pa.array(codes, pa.int8()),
        "outcome_name": pa.array([r.name for r in results], pa.string()),
        "decided_in": pa.array([r.decided_in for r in results], pa.string()),
        "success": pa.array(codes == Outcome.SUCCESS, pa.bool_()),
        "firm": pa.array([r.firm for r in results], pa.bool_()),
        "max_rel_translation": num("max_rel_translation"),
        "max_rel_rotation": num("max_rel_rotation"),
        "closed_width": num("closed_width"),
        "motion_closing_linear": num("motion_closing_linear"),
        "motion_closing_angular": num("motion_closing_angular"),
        "motion_shaking_linear": num("motion_shaking_linear"),
        "motion_shaking_angular": num("motion_shaking_angular"),
        "contact_points": variable_list(points, pa.float64()),
        "contact_normals": variable_list(normals, pa.float64()),
        "contact_forces": variable_list([r.contact_forces for r in results], pa.float64()),
        "contact_fingers": variable_list([r.contact_fingers for r in results], pa.int8()),
        "epsilon": pa.array(epsilon, pa.float64()),
        "robustness_n": pa.array(robust_n, pa.int32()),
        "robustness": pa.array(robust, pa.float64()),
    }
    return pa.table(arrays, schema=SCHEMA)

