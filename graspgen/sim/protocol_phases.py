"""The evaluation protocols as objects: one class per protocol, its phases as methods, registered by name.

:class:`LiftSimulator.rollout <graspgen.sim.lift.LiftSimulator>` asks the protocol of its ``params``
(:func:`protocol_of`) to run a grasp; the rules of each phase are written out in :class:`LiftSimulator`'s docstring
and the settings in :mod:`graspgen.sim.protocols`. Everything the simulator, the MuJoCo Warp backend and code outside
the simulator need to know of a protocol is a method or attribute of its class (the interface:
:class:`graspgen.sim.protocol_base.RolloutProtocol`), never a test of its name: its phases, motion schedule, contact
overrides, Warp placement kind, segments and gravity, and its ``free_space``, ``lifts``, ``settings``, ``load`` and
``calm``.

Adding a protocol: its settings in :class:`graspgen.sim.protocols.LiftParams` (and its name in
:data:`~graspgen.sim.protocols.PROTOCOLS`), a subclass of :class:`RolloutProtocol` (or of :class:`FreeSpaceProtocol`,
whose frame places, closes and judges, with :meth:`~FreeSpaceProtocol.disturb`, :meth:`~RolloutProtocol.segments`
and its schedule its own) and one entry in :data:`ROLLOUT_PROTOCOLS`.

Each phase method takes the simulator (``sim``, a :class:`~graspgen.sim.lift.LiftSimulator`; not imported here, so
that the model set-up and the motion profiles below it can ask a protocol too) and works on its state; a rule that
fires raises :class:`Decided`. The MuJoCo calls and their order are the simulator's own.
"""

from __future__ import annotations

import dataclasses
import math
from types import MappingProxyType
from typing import Any

import numpy as np

from graspgen.geometry.poses import quat_mul, rotation_angle
from graspgen.grippers import jaw_opening
from graspgen.sim.lift_rules import Drift, both_jaws, jaws_on, no_contacts
from graspgen.sim.motion import Schedule, Segment, base_schedule, shake_quats, shake_wave
from graspgen.sim.protocol_base import Decided, Load, RolloutProtocol
from graspgen.sim.protocols import PROTOCOLS, AcronymParams, GraspDataGenParams, LiftParams, Outcome, RolloutResult
from graspgen.validation import check_choice

__all__ = ["ROLLOUT_PROTOCOLS", "AcronymProtocol", "Decided", "FreeSpaceProtocol", "GraspDataGenProtocol", "Load",
           "RolloutProtocol", "TableProtocol", "protocol_of"]


class TableProtocol(RolloutProtocol):
    """``table``: placement at the pre-grasp pose, approach, closing, lift, hold, shake (:class:`LiftSimulator`)."""

    name = "table"
    free_space = False
    placement = "pregrasp"

    def load(self, lift: LiftParams, g: float) -> Load:
        shake = (lift.shake_amplitude, lift.shake_angle, lift.shake_frequency, lift.shake_cycles) if lift.shake \
            else None
        return Load(g, lift.lift_acceleration, shake, 1.0)

    def calm(self, lift: LiftParams) -> LiftParams:
        return dataclasses.replace(lift, shake=False)

    def schedule(self, lift, dt, min_width, max_width, closing_speed) -> Schedule:
        s = base_schedule(lift, dt)
        if not lift.shake:
            return s
        return dataclasses.replace(
            s, shake_z=shake_wave(lift.shake_amplitude, lift.shake_frequency, lift.shake_cycles, dt),
            shake_qx=shake_quats(lift.shake_angle, lift.shake_frequency, lift.shake_cycles, dt))

    def segments(self, lift, schedule) -> list[Segment]:
        """Lift, hold and :meth:`shake`."""
        s = schedule
        top = float(s.lift_offsets[-1, 2])
        segments = [Segment("lifting", len(s.lift_offsets), "zpos", s.lift_offsets[:, 2]),
                    Segment("holding", s.hold_steps, "wait")]
        if lift.shake:
            segments += [Segment("shaking", len(s.shake_z), "zpos", top + s.shake_z, mark=True),
                         Segment("shaking", len(s.shake_qx), "quat", s.shake_qx, lift=top)]
        return segments

    @staticmethod
    def approach_check(sim: Any, roles: np.ndarray, target: int, index: int):
        """The rule of placement and approach, as a ``check(phase)`` callback; the objects' pose at placement is
        read now."""
        objects = sim.index.objects
        pos0, quat0 = sim._xipos[objects], sim._xquat[objects]  # fancy indexing: copies

        def check_approach(phase: str) -> None:
            code = sim.contact_code(roles, target)
            if code is not None:
                raise Decided(code, phase)
            moved = sim._moved(pos0, quat0)
            if moved[index]:
                raise Decided(Outcome.COLLISION_WITH_TARGET, phase)
            if moved.any():
                raise Decided(Outcome.COLLISION_WITH_CLUTTER, phase)

        return check_approach

    def place(self, sim: Any, pos, quat, z_axis, width, target, roles, index, observer) -> None:
        """Placement at the pre-grasp pose, jaws open to ``width + width_margin``, then the approach."""
        p, s = sim.params, sim.schedule
        open_width = float(jaw_opening(width, p.width_margin, sim.min_width, sim.max_width))
        pre = pos - p.approach_distance * z_axis
        sim.place(pre, quat, open_width)
        check_approach = self.approach_check(sim, roles, target, index)
        if observer is not None:
            observer("placement", 0)
        check_approach("placement")
        sim._move(pre + s.approach[:, None] * z_axis, None, "approach", check_approach, observer)

    @staticmethod
    def shake(sim: Any, pos: np.ndarray, quat: np.ndarray, check_slip, observer) -> None:
        """The shake at the top of the lift: along world z, then about the TCP x axis."""
        s = sim.schedule
        top = pos + s.lift_offsets[-1]
        shake_pos = np.repeat(top[None], len(s.shake_z), axis=0)
        shake_pos[:, 2] += s.shake_z
        sim._move(shake_pos, None, "shaking", check_slip, observer)
        sim._move(np.repeat(top[None], len(s.shake_qx), axis=0), quat_mul(quat, s.shake_qx),
                  "shaking", check_slip, observer)

    def rollout(self, sim, pos, quat, R, width, target, roles, index, observer) -> RolloutResult:
        p, s = sim.params, sim.schedule
        nan = math.nan
        closed_width = lift_gain = rel_t = rel_r = nan
        motion_closing = motion_shaking = (nan, nan)
        pose_closed = np.full((4, 4), nan)
        shake_mark = drift = None
        contacts = no_contacts()
        sim._gravity_view[:] = 0.0 if p.gravity_until_closed else sim.gravity
        try:
            self.place(sim, pos, quat, R[:, 2].copy(), width, target, roles, index, observer)
            closed_width, motion_closing, pose_closed, contacts = sim._closing(target, roles, observer)
            if not both_jaws(contacts):
                raise Decided(Outcome.NO_CONTACT_ESTABLISHED, "closing")
            sim._gravity_view[:] = self.start_gravity(p, sim.gravity, R)
            # lift, hold, shake
            rel_p0, rel_R0 = sim.relative(target)
            drift = Drift(rel_p0, rel_R0)
            z_obj0 = float(sim._xipos[target][2])

            def check_slip(phase: str) -> None:
                if sim._slipped(target, rel_p0, rel_R0, drift):
                    raise Decided(Outcome.SLIPPED_DURING_LIFTING, phase)

            sim._move(pos + s.lift_offsets, None, "lifting", check_slip, observer)
            sim._wait(s.hold_steps, "holding", check_slip, observer)
            if p.shake:
                shake_mark = sim.mark(target)
                self.shake(sim, pos, quat, check_slip, observer)
            # judge
            lift_gain = float(sim._xipos[target][2]) - z_obj0
            if lift_gain < p.min_lift_fraction * p.lift_height:
                raise Decided(Outcome.SLIPPED_DURING_LIFTING, "end")
            code, phase = Outcome.SUCCESS, "end"
        except Decided as decided:
            code, phase = Outcome(decided.code), decided.phase
        finally:
            sim._gravity_view[:] = sim.gravity
        if code >= Outcome.SLIPPED_DURING_LIFTING:
            rel_p, rel_R = sim.relative(target)
            rel_t = math.sqrt(float((rel_p - rel_p0) @ (rel_p - rel_p0)))
            rel_r = rotation_angle(rel_R0, rel_R)
            lift_gain = float(sim._xipos[target][2]) - z_obj0
        if shake_mark is not None:
            motion_shaking = sim.motion(target, shake_mark)
        return sim.result(code, phase, closed_width, lift_gain, (rel_t, rel_r), contacts, motion_closing,
                          motion_shaking, pose_closed, sim._final_drift(target, drift))


class FreeSpaceProtocol(RolloutProtocol):
    """The frame the free-space protocols share: gravity off, the hand placed at the grasp pose with its jaws open
    (touching anything there decides the grasp, the target without the fingers' allowance), closed, then
    :meth:`disturb` tests the grip (the protocol's own part); success when both jaws still touch the target."""

    free_space = True
    placement = "grasp"

    def settings(self, lift: LiftParams) -> AcronymParams | GraspDataGenParams:
        return getattr(lift, self.name)

    def schedule(self, lift, dt, min_width, max_width, closing_speed) -> Schedule:
        """The shared profiles with the protocol's own opening, and a closing timeout of at least 1.25x a full
        close (from fully open to fully closed takes ``(open - min) / closing_speed``)."""
        s, free = base_schedule(lift, dt), self.settings(lift)
        open_width = float(np.clip(max_width if free.open_width is None else free.open_width, min_width, max_width))
        full_close = 1.25 * (open_width - min_width) / closing_speed
        return dataclasses.replace(s, open_width=open_width,
                                   close_max_steps=max(s.close_max_steps, math.ceil(full_close / dt - 1e-9)))

    def start_gravity(self, lift, gravity, R) -> np.ndarray:
        """Off (the free-space protocols' gravity stays off unless theirs says otherwise)."""
        return np.zeros(3)

    def disturb(self, sim: Any, pos, quat, R, target, check_held, observer) -> None:
        """The disturbance after closing, under :meth:`start_gravity`; ``check_held(phase)`` at every check."""
        raise NotImplementedError

    def rollout(self, sim, pos, quat, R, width, target, roles, index, observer) -> RolloutResult:
        nan = math.nan
        closed_width = rel_t = rel_r = nan
        motion_closing = motion_shaking = (nan, nan)
        pose_closed = np.full((4, 4), nan)
        shake_mark = rel0 = drift = None
        contacts = no_contacts()
        sim._gravity_view[:] = 0.0
        side = sim.index.geom_side
        try:
            # placement: at the grasp pose, jaws open; the open hand must not touch anything
            sim.place(pos, quat, sim.schedule.open_width)
            if observer is not None:
                observer("placement", 0)
            code = sim.contact_code(roles, target, sim.strict_allowance)
            if code is not None:
                raise Decided(code, "placement")
            # closing, gravity off
            closed_width, motion_closing, pose_closed, contacts = sim._closing(target, roles, observer)
            if not both_jaws(contacts):
                raise Decided(Outcome.NO_CONTACT_ESTABLISHED, "closing")
            rel0 = sim.relative(target)
            drift = Drift(*rel0)

            def check_held(phase: str) -> None:
                drift.update(*sim.relative(target))
                if not any(jaws_on(sim.data, side, roles)):
                    raise Decided(Outcome.SLIPPED_DURING_LIFTING, phase)

            # the protocol's disturbance, then the judge
            shake_mark = sim.mark(target)
            sim._gravity_view[:] = self.start_gravity(sim.params, sim.gravity, R)
            self.disturb(sim, pos, quat, R, target, check_held, observer)
            if not all(jaws_on(sim.data, side, roles)):
                raise Decided(Outcome.SLIPPED_DURING_LIFTING, "end")
            code, phase = Outcome.SUCCESS, "end"
        except Decided as decided:
            code, phase = Outcome(decided.code), decided.phase
        finally:
            sim.data.xfrc_applied[target] = 0.0
            sim._gravity_view[:] = sim.gravity
        if rel0 is not None:
            rel_p, rel_R = sim.relative(target)
            rel_t = math.sqrt(float((rel_p - rel0[0]) @ (rel_p - rel0[0])))
            rel_r = rotation_angle(rel0[1], rel_R)
        if shake_mark is not None:
            motion_shaking = sim.motion(target, shake_mark)
        return sim.result(code, phase, closed_width, nan, (rel_t, rel_r), contacts, motion_closing, motion_shaking,
                          pose_closed, sim._final_drift(target, drift))


class AcronymProtocol(FreeSpaceProtocol):
    """``acronym`` (:class:`graspgen.sim.protocols.AcronymParams`): gravity on as configured once closed, shake
    along the approach axis, then about the closing axis through the TCP, then settle."""

    name = "acronym"

    def load(self, lift: LiftParams, g: float) -> Load:
        p = lift.acronym
        shake = (p.shake_amplitude, p.shake_angle, p.shake_frequency, p.shake_cycles) \
            if p.shake_amplitude > 0 or p.shake_angle > 0 else None
        return Load(g if p.gravity != "off" else 0.0, 0.0, shake, -1.0)

    def calm(self, lift: LiftParams) -> LiftParams:
        return dataclasses.replace(lift, acronym=AcronymParams(shake_amplitude=0.0, shake_angle=0.0))

    def contact_overrides(self, lift: LiftParams) -> AcronymParams:
        return lift.acronym

    def schedule(self, lift, dt, min_width, max_width, closing_speed) -> Schedule:
        acr = lift.acronym
        return dataclasses.replace(
            super().schedule(lift, dt, min_width, max_width, closing_speed),
            shake_z=shake_wave(acr.shake_amplitude, acr.shake_frequency, acr.shake_cycles, dt),
            shake_qx=shake_quats(acr.shake_angle, acr.shake_frequency, acr.shake_cycles, dt),
            settle_steps=int(round(acr.settle_time / dt)))

    def segments(self, lift, schedule) -> list[Segment]:
        s = schedule
        return [Segment("shaking", len(s.shake_z), "pos", s.shake_z, mark=True),
                Segment("shaking", len(s.shake_qx), "quat", s.shake_qx),
                Segment("holding", s.settle_steps, "wait")]

    def start_gravity(self, lift, gravity, R) -> np.ndarray:
        """As ``acronym.gravity`` says: the scene's (``world``), its magnitude along the approach (``approach``),
        or off."""
        if lift.acronym.gravity == "world":
            return gravity.copy()
        if lift.acronym.gravity == "approach":
            return math.sqrt(float(gravity @ gravity)) * R[:, 2]
        return np.zeros(3)

    def disturb(self, sim, pos, quat, R, target, check_held, observer) -> None:
        s = sim.schedule
        sim._move(pos + s.shake_z[:, None] * R[:, 2], None, "shaking", check_held, observer)
        sim._move(np.repeat(pos[None], len(s.shake_qx), axis=0), quat_mul(quat, s.shake_qx),
                  "shaking", check_held, observer)
        sim._wait(s.settle_steps, "holding", check_held, observer)


class GraspDataGenProtocol(FreeSpaceProtocol):
    """``graspdatagen`` (:class:`graspgen.sim.protocols.GraspDataGenParams`): gravity stays off; the object's
    weight pulls it along each tug direction (TCP frame at the grasp) at its centre of mass."""

    name = "graspdatagen"

    def load(self, lift: LiftParams, g: float) -> Load:
        return Load(lift.graspdatagen.force_scale * g, 0.0, None, 1.0)

    def schedule(self, lift, dt, min_width, max_width, closing_speed) -> Schedule:
        return dataclasses.replace(super().schedule(lift, dt, min_width, max_width, closing_speed),
                                   tug_steps=max(1, int(round(lift.graspdatagen.tug_time / dt))),
                                   tug_dirs=lift.graspdatagen.directions())

    def segments(self, lift, schedule) -> list[Segment]:
        """One tug per direction."""
        return [Segment("shaking", schedule.tug_steps, "tug", d, mark=i == 0) for i, d in enumerate(schedule.tug_dirs)]

    def disturb(self, sim, pos, quat, R, target, check_held, observer) -> None:
        weight = sim.params.graspdatagen.force_scale * float(sim.model.body_subtreemass[target]) * math.sqrt(
            float(sim.gravity @ sim.gravity))
        for direction in sim.schedule.tug_dirs:
            sim.data.xfrc_applied[target, :3] = weight * (R @ direction)
            sim._wait(sim.schedule.tug_steps, "shaking", check_held, observer)
        sim.data.xfrc_applied[target, :3] = 0.0


#: The protocols by name, one object each (:data:`graspgen.sim.protocols.PROTOCOLS`, in that order).
ROLLOUT_PROTOCOLS: MappingProxyType[str, RolloutProtocol] = MappingProxyType(
    {p.name: p for p in (TableProtocol(), AcronymProtocol(), GraspDataGenProtocol())})


def protocol_of(lift: LiftParams | str) -> RolloutProtocol:
    """The protocol object of ``lift.protocol`` (or of a name); SettingsError listing the protocols."""
    name = lift if isinstance(lift, str) else lift.protocol
    check_choice("protocol", name, PROTOCOLS)
    return ROLLOUT_PROTOCOLS[name]
