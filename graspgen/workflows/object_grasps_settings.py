"""Settings of an object-centric grasp set (:func:`graspgen.workflows.object_grasps.label_object_grasps`, config
section ``object_grasps``) and what they mean for a gripper: the near misses' default overhang and tilt, the
protocol's opening."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from graspgen.geometry.antipodal import AntipodalParams
from graspgen.grippers import ACRONYM_GRIPPER, GripperSpec, load_gripper
from graspgen.quality.epsilon import EpsilonParams
from graspgen.sim.protocol_phases import ROLLOUT_PROTOCOLS, protocol_of
from graspgen.sim.protocols import PROTOCOL_KEYS, LiftParams, Outcome, RolloutResult, check_protocol
from graspgen.sim.simulator import check_backend
from graspgen.sim.warp_backend import KEY_OMIT_DEFAULT, WarpParams
from graspgen.validation import check, check_choice, check_instance, check_int, check_number
from shared_utils.keys import KEY_NAME, KEY_VALUES
from shared_utils.renames import RENAMED_FROM

__all__ = ["LABELS", "PROTOCOLS", "SELECTIONS", "ObjectGraspsParams", "default_overhang", "default_tilt",
           "free_space_sampler", "protocol_opening"]

PROTOCOLS: tuple[str, ...] = tuple(name for name, p in ROLLOUT_PROTOCOLS.items() if p.free_space)
"""The protocols an object-centric set may use: the free-space ones of :data:`graspgen.sim.protocols.PROTOCOLS`."""

LABELS: tuple[str, ...] = ("held", "firm")
"""Values of :attr:`ObjectGraspsParams.label`: which label makes a positive."""

SELECTIONS: tuple[str, ...] = ("natural", "balanced")
"""Values of :attr:`ObjectGraspsParams.selection`: which rollouts a set keeps."""


@dataclasses.dataclass(frozen=True)
class ObjectGraspsParams:
    """Settings of an object-centric grasp set (config section ``object_grasps``;
    :mod:`graspgen.workflows.object_grasps`)."""

    gripper: str = ACRONYM_GRIPPER
    """Gripper model: robotiq_2f85, panda or box_jaw, or the path of a gripper file (.yaml, .yml, .json). The Panda
    is ACRONYM's and GraspGen's gripper."""
    protocol: str = dataclasses.field(default="acronym", metadata={KEY_VALUES: PROTOCOL_KEYS})
    """Free-space protocol of the rollouts: ``acronym`` (placed open at the grasp, close, shake; ACRONYM's test) or
    ``graspdatagen`` (close, then five tugs at the object's weight; GraspDataGen's test). It sets ``lift.protocol``."""
    selection: str = "natural"
    """Which rollouts are kept. ``natural`` (default): every candidate that does not collide at placement (outcomes 3-5)
    until ``target_grasps``, plus collisions within ``collision_share_of_negatives``, as ACRONYM keeps its poses.
    ``balanced``: ``target_positives`` and ``target_negatives`` with near misses. Why natural:
    docs/decisions/2026-12-07-natural-object-sets.md."""
    target_grasps: int = 800
    """``natural``: rollouts that do not collide at placement to keep per object (the first ones in trial
    order)."""
    target_positives: int | None = None
    """``balanced``: positives to keep per object (the first ones in trial order); null: 1000. Unset with
    ``natural``."""
    target_negatives: int | None = None
    """``balanced``: failures (not positive under ``label``) to keep per object (the first ones in trial order);
    null: 1000. Unset with ``natural``."""
    max_candidates: int = 20000
    """Most rollouts per object; the loop stops here even when a target is not met (a warning says so)."""
    # Was ``collision_share`` (the name ``grasps`` keeps for a share of all rows): a config that writes it here is
    # told the new name, and keys and seeds hash the former one, so sets made before keep their keys and draws.
    collision_share_of_negatives: float = dataclasses.field(
        default=0.25, metadata={RENAMED_FROM: ("collision_share",), KEY_NAME: "collision_share"})
    """Largest share of the kept negatives that may be collisions at placement (outcomes 0-2), in [0, 1]; 1 keeps
    failures as they come. Some are kept because a grasp model must rank a planner's colliding candidates last; capped
    because they teach nothing of what holds. (``grasps.collision_share`` is a share of all of a scene object's
    rows.)"""
    batch_size: int = 128
    """Candidates sampled per batch (antipodal plus near misses, in a shuffled order)."""
    near_miss_fraction: float = 0.3
    """``balanced``: share of each batch that are near misses (``round(fraction * batch_size)``), in [0, 1)."""
    near_miss_fraction_when_positives_met: float = 0.8
    """``balanced``: share of each batch that are near misses once ``target_positives`` are kept, in [0, 1)."""
    near_miss_overhang: float | None = None
    """Shifted near misses: how far (m) beyond the pad face's edge the parent's contact point ends up; null: half the
    pad face's width, ``pad_size[1] / 2``."""
    near_miss_tilt: float | None = None
    """Tilted near misses: the hand's tilt about the TCP (rad, in (0, pi/2]) about a random axis perpendicular to the
    approach; null: :func:`default_tilt`."""
    sampler: AntipodalParams = dataclasses.field(default_factory=lambda: free_space_sampler())
    """Antipodal sampling on the object's mesh; its ``approach`` is always ``any`` here (the whole sphere, object
    frame). Defaults as ACRONYM samples: friction cone of coefficient 1.0, one depth (no table for the finger tips to
    reach)."""
    lift: LiftParams = dataclasses.field(default_factory=lambda: LiftParams(protocol="acronym"))
    """The rollout's protocol settings (``lift.acronym``, ``lift.graspdatagen``, physics); ``lift.protocol`` is set
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
    label: str = "firm"
    """Which label makes a positive: ``firm`` (default; outcome 5 and the object's motion in the hand within the
    firm-hold tolerances) or ``held`` (outcome 5: ACRONYM's ``object_in_gripper``). Both are stored in every row
    (``firm``, ``success``)."""
    backend: str = dataclasses.field(default="mujoco", metadata={KEY_OMIT_DEFAULT: True})
    """Where the candidates are rolled out: ``mujoco`` (CPU, one at a time) or ``warp`` (MuJoCo Warp, ``batch_size`` at
    once; ``pip install -e '.[warp]'``). Both take results in the same trial order, so the same labels keep the same
    rows; robustness copies run on the CPU."""
    warp: WarpParams = dataclasses.field(default_factory=WarpParams, metadata={KEY_OMIT_DEFAULT: True})
    """Device and buffer sizes of the ``warp`` backend (:class:`graspgen.sim.warp_backend.WarpParams`; its
    ``nworld`` is capped at ``batch_size``; unused by ``mujoco``)."""

    def __post_init__(self) -> None:
        check("gripper", isinstance(self.gripper, str) and bool(self.gripper),
              "be a gripper name or the path of a gripper file", self.gripper)
        load_gripper(self.gripper)  # unknown name: lists the bundled ones; bad file: names it and what is wrong
        check_protocol("protocol", self.protocol, PROTOCOLS, " (the free-space protocols; 'table' needs a support)")
        check_choice("selection", self.selection, SELECTIONS)
        object.__setattr__(self, "target_grasps", check_int("target_grasps", self.target_grasps, low=1))
        for key in ("target_positives", "target_negatives"):
            value = getattr(self, key)
            if self.selection == "natural":
                check(key, value is None, "be unset with selection: natural, which keeps target_grasps rows whatever "
                      "their outcome (set target_grasps, or selection: balanced)", value)
            else:
                object.__setattr__(self, key, check_int(key, 1000 if value is None else value, low=0))
        if self.selection == "balanced":
            check("target_negatives", self.target_positives + self.target_negatives > 0,
                  "be > 0 when target_positives is 0 (nothing to keep)", self.target_negatives)
        object.__setattr__(self, "collision_share_of_negatives", check_number(
            "collision_share_of_negatives", self.collision_share_of_negatives, low=0.0, high=1.0))
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
        object.__setattr__(self, "lift", self.lift.with_protocol(self.protocol))
        check_backend(self.backend, self.protocol)
        check_instance("warp", self.warp, WarpParams)
        object.__setattr__(self, "friction", check_number("friction", self.friction, low=0.0, low_open=True))
        object.__setattr__(self, "num_perturbations", check_int("num_perturbations", self.num_perturbations, low=0))
        for key in ("perturbation_translation", "perturbation_rotation"):
            object.__setattr__(self, key, check_number(key, getattr(self, key), low=0.0))
        check_instance("epsilon", self.epsilon, EpsilonParams)
        check_choice("label", self.label, LABELS)

    @property
    def label_column(self) -> str:
        """The table column that holds this set's positives: ``firm`` or ``success`` (held)."""
        return "firm" if self.label == "firm" else "success"

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


def free_space_sampler() -> AntipodalParams:
    """The antipodal sampler of object-centric sets (and of ``gen probe pick``'s candidates): approach axes over
    the whole sphere, the friction cone of ACRONYM's coefficient 1.0, the TCP at the contacts' midpoint."""
    return AntipodalParams(approach="any", friction=1.0, num_depths=1)


def default_overhang(gripper: GripperSpec) -> float:
    """Half the width of the gripper's pad face, ``pad_size[1] / 2`` (m): how far past the pad's edge a shifted near
    miss leaves the contact it was aimed at (:mod:`graspgen.workflows.object_grasps`)."""
    return gripper.pad_size[1] / 2.0


def default_tilt(gripper: GripperSpec) -> float:
    """``atan(max_width / (2 finger_length))`` (rad): the smallest tilt about the TCP that swings an open finger's base
    past the grasp's centre line."""
    return math.atan(gripper.max_width / (2.0 * gripper.finger_size[2]))


def protocol_opening(gripper: GripperSpec, lift: LiftParams) -> float:
    """Pad separation (m) the jaws open to under a free-space protocol: its ``open_width`` (the gripper's
    ``max_width`` when null), clipped to the gripper's range (as :class:`graspgen.sim.lift.LiftSimulator` does)."""
    settings = protocol_of(lift).settings(lift)
    opening = gripper.max_width if settings.open_width is None else settings.open_width
    return float(np.clip(opening, gripper.min_width, gripper.max_width))
