"""What a protocol is to the rest of the simulator: :class:`RolloutProtocol`, the interface every protocol of
:mod:`graspgen.sim.protocol_phases` implements, with :class:`Decided` (a rule fired) and :class:`Load` (what a grip
carries, for the analytic thresholds).

Every per-protocol decision of the simulator is a method or attribute here, answered by the protocol's own class:
its phases on the CPU (:meth:`RolloutProtocol.rollout`), its motion (:meth:`~RolloutProtocol.schedule`), its
model (:meth:`~RolloutProtocol.contact_overrides`), its rollout on MuJoCo Warp (:attr:`~RolloutProtocol.placement`,
:meth:`~RolloutProtocol.segments`, :meth:`~RolloutProtocol.start_gravity`) and what callers outside the simulator
ask (:attr:`~RolloutProtocol.free_space`, :attr:`~RolloutProtocol.lifts`, :meth:`~RolloutProtocol.settings`,
:meth:`~RolloutProtocol.load`, :meth:`~RolloutProtocol.calm`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from graspgen.sim.motion import Schedule, Segment, base_schedule
from graspgen.sim.protocols import AcronymParams, GraspDataGenParams, LiftParams, RolloutResult

__all__ = ["Decided", "Load", "RolloutProtocol"]


class Decided(Exception):
    """A rule fired: carries the outcome code and the phase."""

    def __init__(self, code: int, phase: str) -> None:
        super().__init__(code, phase)
        self.code = code
        self.phase = phase


@dataclass(frozen=True)
class Load:
    """What a protocol asks of a grip after closing, for the analytic thresholds
    (:func:`graspgen.quality.mechanics_theory.shake_profiles`)."""

    gravity: float
    """Acceleration (m/s^2) the grip carries at rest along the approach: gravity, or the tug's."""
    lift_acceleration: float
    """Peak acceleration (m/s^2) of the lift on top of it (0: nothing is lifted)."""
    shake: tuple[float, float, float, int] | None
    """``(amplitude m, angle rad, frequency Hz, cycles)`` of the linear then angular shake; None: no shake."""
    shake_sign: float
    """+1: the linear shake's acceleration adds to the load as world z does (table: up); -1: along +approach."""


class RolloutProtocol:
    """A protocol: its phases (``rollout`` runs them) and what the outside needs to know of it."""

    name: ClassVar[str]
    """The protocol's name (:data:`graspgen.sim.protocols.PROTOCOLS`)."""
    free_space: ClassVar[bool]
    """Runs in free space: the hand placed at the grasp with its jaws at the protocol's own opening, gravity the
    protocol's; needs no support (a support would be in the way). False: approach and lift on a support."""
    placement: ClassVar[str]
    """How the hand is placed, the kind of rollout the MuJoCo Warp backend runs for the protocol
    (:data:`graspgen.sim.warp_backend.WARP_RUNS`): ``"pregrasp"``, back along the approach with the jaws open to the
    grasp's width plus ``width_margin``, then the approach (needs each grasp's width); ``"grasp"``, at the grasp
    with the jaws at the protocol's own opening (the width is ignored)."""

    @property
    def lifts(self) -> bool:
        """Lifts the object (the hand rises ``lift_height``)."""
        return not self.free_space

    def settings(self, lift: LiftParams) -> AcronymParams | GraspDataGenParams | None:
        """The protocol's own settings block of ``lift`` (None: ``LiftParams``' own fields)."""
        return None

    def load(self, lift: LiftParams, g: float) -> Load:
        """The grip's load under ``lift`` with gravity ``g`` (m/s^2)."""
        raise NotImplementedError

    def contact_overrides(self, lift: LiftParams) -> AcronymParams | None:
        """The contact settings the protocol writes into the gripper's geoms (``contact_solref``,
        ``contact_solimp``, ``torsional_friction``: :func:`graspgen.sim.lift_model.apply_contact_overrides`; an
        explicit torsional friction replaces the ``"patch"`` pad torsion); None: the models' own."""
        return None

    def schedule(self, lift: LiftParams, dt: float, min_width: float, max_width: float,
                 closing_speed: float) -> Schedule:
        """Every motion profile and step count of the protocol under ``lift`` at timestep ``dt`` (s), for a gripper
        of pad separation range ``[min_width, max_width]`` (m) whose jaws close at ``closing_speed`` (m/s)."""
        return base_schedule(lift, dt)

    def segments(self, lift: LiftParams, schedule: Schedule) -> list[Segment]:
        """What :meth:`rollout` does after closing, as the segments the MuJoCo Warp backend replays
        (:class:`graspgen.sim.warp_batch.BatchRun`); ``schedule``: :meth:`schedule`'s."""
        raise NotImplementedError

    def start_gravity(self, lift: LiftParams, gravity: np.ndarray, R: np.ndarray) -> np.ndarray:
        """Gravity (3,) m/s^2 from the end of closing on, for the scene's ``gravity (3,)`` and the grasp's rotation
        ``R (3, 3)`` (a new array)."""
        return gravity.copy()

    def calm(self, lift: LiftParams) -> LiftParams:
        """``lift`` without the disturbance after closing (no shake), where the protocol has one to switch off."""
        return lift

    def rollout(self, sim: Any, pos: np.ndarray, quat: np.ndarray, R: np.ndarray, width: float,
                target: int, roles: np.ndarray, index: int, observer) -> RolloutResult:
        """Run the phases on ``sim`` for the grasp at ``pos (3,)``, ``quat (4,)``, ``R (3, 3)`` of pad separation
        ``width`` (m) on body ``target`` (``roles``, ``index``: :meth:`LiftSimulator.target_roles`)."""
        raise NotImplementedError
