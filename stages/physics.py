"""The config section ``physics``: the simulation and outcome rules every rollout shares, defined once, and the
three protocols' settings blocks (``table``, ``acronym``, ``graspdatagen``) that the stage sections name
(``rollouts.protocol: table``). :meth:`PhysicsParams.lift` builds the library's
:class:`graspgen.sim.protocols.LiftParams` of a stage from them; the defaults are LiftParams' own (its docstrings say
where each number comes from), so a stage sees the LiftParams it saw when its section held a copy of it."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from graspgen.errors import SettingsError
from graspgen.sim.protocols import AcronymParams, GraspDataGenParams, LiftParams, check_protocol
from graspgen.validation import check_instance
from shared_utils.renames import RENAMED_FROM

__all__ = ["PROTOCOL_BLOCKS", "PhysicsParams", "TableProtocol", "moved_lift_key"]

_LIFT = LiftParams()
"""Where the defaults below come from."""


@dataclasses.dataclass(frozen=True)
class TableProtocol:
    """The ``table`` protocol's own settings: place the hand back along the approach, approach, close, lift, hold,
    shake (:class:`graspgen.sim.protocols.LiftParams`)."""

    approach_distance: float = _LIFT.approach_distance
    """Pre-grasp offset (m) back along the TCP's -z; the hand approaches from there. The pre-filter checks the same
    line (``grasps.prefilter`` takes it from here)."""
    approach_speed: float = _LIFT.approach_speed
    """Peak TCP speed (m/s) of the approach (trapezoidal profile)."""
    approach_acceleration: float = _LIFT.approach_acceleration
    """Acceleration and deceleration (m/s^2) of the approach; the hand arrives at rest."""
    width_margin: float = _LIFT.width_margin
    """The jaws open to ``width + width_margin`` (m) before the approach; the sampler and the pre-filter open them
    alike (``grasps.sampler`` and ``grasps.prefilter`` take it from here)."""
    grip_force: float | None = _LIFT.grip_force
    """Force (N) each jaw presses with; null: the gripper model's ``force_limit``."""
    lift_height: float = _LIFT.lift_height
    """Height (m) the TCP is lifted, world +z, after closing."""
    lift_speed: float = _LIFT.lift_speed
    """Peak speed (m/s) of the lift (trapezoidal profile)."""
    lift_acceleration: float = _LIFT.lift_acceleration
    """Acceleration and deceleration (m/s^2) of the lift."""
    hold_time: float = _LIFT.hold_time
    """Time (s) held still at the top before the shake."""
    shake: bool = _LIFT.shake
    """ACRONYM's shake after the hold: along world z, then about the TCP x axis; false: lift and hold only."""
    shake_amplitude: float = _LIFT.shake_amplitude
    """Peak displacement (m) of the vertical shake (~1 g peak at 4 Hz)."""
    shake_angle: float = _LIFT.shake_angle
    """Peak rotation (rad) of the shake about the TCP x (closing) axis."""
    shake_frequency: float = _LIFT.shake_frequency
    """Frequency (Hz) of both shakes (Hann-windowed sines)."""
    shake_cycles: int = _LIFT.shake_cycles
    """Oscillations per shake axis."""
    min_lift_fraction: float = _LIFT.min_lift_fraction
    """Share of ``lift_height`` (in [0, 1]) the target must have risen by at the end; less is a slip (code 4)."""
    gravity_until_closed: bool = _LIFT.gravity_until_closed
    """Free space: gravity off until the jaws have closed (objects float; no support needed)."""


PROTOCOL_BLOCKS: Mapping[str, type] = {"table": TableProtocol, "acronym": AcronymParams,
                                       "graspdatagen": GraspDataGenParams}
"""Each protocol's settings block in :class:`PhysicsParams`, by protocol name."""


@dataclasses.dataclass(frozen=True)
class PhysicsParams:
    """Config section ``physics``: what every rollout shares (MuJoCo's options, the closing stop, the outcome
    tolerances) and each protocol's settings. A stage section names its protocol (``rollouts.protocol``) and may
    override any of these keys, or its protocol's, for itself (``rollouts.overrides: {grip_force: 40}``)."""

    timestep: float = _LIFT.timestep
    """Integration step (s)."""
    cone: str = _LIFT.cone
    """Friction cone: ``elliptic`` (held objects do not creep) or ``pyramidal``."""
    impratio: float = _LIFT.impratio
    """Frictional to normal constraint impedance ratio (> 1: stiffer friction)."""
    noslip_iterations: int = _LIFT.noslip_iterations
    """MuJoCo's post-solver no-slip iterations (0: off)."""
    iterations: int = _LIFT.iterations
    """Most main-solver iterations per step."""
    ls_iterations: int = _LIFT.ls_iterations
    """Most line-search iterations per solver iteration."""
    integrator: str = _LIFT.integrator
    """``implicitfast``, ``implicit``, ``euler`` or ``rk4``."""
    pad_torsion: str = _LIFT.pad_torsion
    """The pads' torsional friction arm: ``face`` (the whole pad face) or ``patch`` (the part the object covers)."""
    pad_sink: str = _LIFT.pad_sink
    """``bounded``: a light object's scene gets a shorter gripper contact time constant (and timestep) so the pads
    sink no deeper than their 1 mm compliance into it; ``model``: the gripper model's contact whatever the mass."""
    check_interval: int = _LIFT.check_interval
    """Steps between two checks of the outcome rules."""
    close_speed_tol: float = _LIFT.close_speed_tol
    """Closing ends when the jaws move slower than this (m/s of pad separation)."""
    close_timeout: float = _LIFT.close_timeout
    """Closing ends after at most this (s)."""
    target_touch_fails: bool = _LIFT.target_touch_fails
    """Strict touch rule: any finger contact pressing into the target at placement or approach is code 1."""
    max_target_shift: float = _LIFT.max_target_shift
    """Largest target motion (m) during placement and approach before it is a collision (code 1)."""
    max_target_turn: float = _LIFT.max_target_turn
    """Largest target rotation (rad) during placement and approach before it is a collision (code 1)."""
    slip_tolerance: float = _LIFT.slip_tolerance
    """Largest target motion (m) in the hand from the end of closing on before it is a slip (code 4)."""
    slip_rotation_tolerance: float = _LIFT.slip_rotation_tolerance
    """Largest target rotation (rad) in the hand before it is a slip (code 4)."""
    firm_translation: float = _LIFT.firm_translation
    """A success is firm when the target never moved more than this (m) in the hand."""
    firm_rotation: float = _LIFT.firm_rotation
    """... and never turned more than this (rad) in the hand."""
    table: TableProtocol = dataclasses.field(default_factory=TableProtocol)
    """The ``table`` protocol: approach, close, lift, hold, shake, on a support (the scene rollouts)."""
    acronym: AcronymParams = dataclasses.field(default_factory=AcronymParams)
    """The ``acronym`` protocol: ACRONYM's free-space close and shake (the object-centric sets)."""
    graspdatagen: GraspDataGenParams = dataclasses.field(default_factory=GraspDataGenParams,
                                                         metadata={RENAMED_FROM: ("graspgen",)})
    """The ``graspdatagen`` protocol: GraspDataGen's free-space close and five tugs."""

    def __post_init__(self) -> None:
        check_instance("table", self.table, TableProtocol)
        check_instance("acronym", self.acronym, AcronymParams)
        check_instance("graspdatagen", self.graspdatagen, GraspDataGenParams)
        self.lift("table")  # checks the shared keys and the table block (LiftParams' checks, each key's path)

    def lift(self, protocol: str, overrides: Mapping[str, Any] | None = None) -> LiftParams:
        """The :class:`LiftParams` of a stage that runs ``protocol``: every key of this section, with ``overrides``
        (keys of this section or of ``protocol``'s block) replacing theirs. SettingsError naming the key, as a
        config writes it, for a bad value or an unknown override."""
        check_protocol("protocol", protocol)
        shared = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in PROTOCOL_BLOCKS}
        blocks = {name: dataclasses.asdict(getattr(self, name)) for name in PROTOCOL_BLOCKS}
        for key, value in (overrides or {}).items():
            if key in shared:
                shared[key] = value
            elif key in blocks[protocol]:
                blocks[protocol][key] = tuple(value) if isinstance(value, list) else value
            else:
                raise SettingsError(f"overrides.{key}: unknown key; valid keys: the keys of physics and of "
                                    f"physics.{protocol}")
        where = {**{k: "" for k in shared}, **{k: "table." for k in blocks["table"]}}
        try:
            return LiftParams(protocol=protocol, **shared, **blocks["table"],
                              acronym=AcronymParams(**blocks["acronym"]),
                              graspdatagen=GraspDataGenParams(**blocks["graspdatagen"]))
        except SettingsError as exc:
            key = str(exc).partition(":")[0]
            raise SettingsError(f"{'overrides.' if key in (overrides or {}) else where.get(key, '')}{exc}") from None


def moved_lift_key(section: str, path: str) -> str | None:
    """Where a key of a stage section's former ``lift`` (``path`` in the section, ``"lift.timestep"``) is now
    (``"physics.timestep, or rollouts.overrides.timestep for this stage"``); None for other paths."""
    parts = path.split(".")
    if parts[0] != "lift":
        return None
    if len(parts) == 1:
        return f"{section}.protocol and the physics section"
    key, alone = parts[-1], f", or {section}.overrides.{parts[-1]} for this stage"
    if parts[1] == "protocol":
        return f"{section}.protocol"
    if parts[1] in ("acronym", "graspdatagen", "graspgen") and len(parts) > 2:
        return f"physics.{'graspdatagen' if parts[1] == 'graspgen' else parts[1]}.{key}{alone}"
    if parts[1] in {f.name for f in dataclasses.fields(TableProtocol)}:
        return f"physics.table.{key}{alone}"
    if parts[1] in {f.name for f in dataclasses.fields(PhysicsParams)}:
        return f"physics.{key}{alone}"
    return None
