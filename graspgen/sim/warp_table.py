"""The ``table`` protocol on MuJoCo Warp: :class:`TableRun`, the batch machine of
:class:`graspgen.sim.warp_backend.WarpLiftSimulator` for grasps on a support (or in free space with gravity off
until closed, ``gravity_until_closed``).

What ``table`` adds to the free-space protocols (:class:`graspgen.sim.warp_batch.BatchRun`), each the CPU backend's
rule (:meth:`graspgen.sim.protocol_phases.TableProtocol.rollout`):

* **placement** at the pre-grasp pose (``approach_distance`` back along -z), the jaws open to the grasp's width plus
  ``width_margin`` (:func:`graspgen.grippers.jaw_opening`), judged on the CPU by the touch rule with the fingers'
  allowance (:func:`table_placement`); gravity as the protocol says (on, or off until closed);
* **approach**: the mocap target moves along +z to the grasp; at each check, the pre-filter's static check of the
  gripper as commanded (the CPU's own :class:`graspgen.sim.lift_model.StaticCheck`, on the CPU: it reads only the
  commanded pose, never the device), then the live contacts with support and clutter (:func:`live_codes`), then
  the objects' motion since placement (:func:`moved_objects`: the target -> 1, another object -> 2);
* **closing** starts per world when its approach ends (the width command goes to ``min_width`` then);
* **lift** (world z), **hold**, **shake** (world z, then about the TCP x axis at the top) with the slip rule at
  every check (:func:`slipped` -> 4) and, at the end, the lift-gain rule (risen less than ``min_lift_fraction *
  lift_height`` since closing ended -> 4, else 5); gravity on from closing's end.
"""

from __future__ import annotations

import math

import numpy as np

from graspgen.grippers import jaw_opening
from graspgen.sim.lift import LiftSimulator
from graspgen.sim.motion import Segment
from graspgen.sim.protocols import Outcome, RolloutResult
from graspgen.sim.warp_batch import BatchRun, unfinished_result
from graspgen.sim.warp_rules import NO_CODE, live_codes, moved_objects, slipped

__all__ = ["TableRun", "table_placement"]


def table_placement(cpu: LiftSimulator, pose: np.ndarray, pos: np.ndarray, quat: np.ndarray, width: float,
                    target: int, roles: np.ndarray) -> dict | RolloutResult:
    """The ``table`` protocol's placement on the CPU (``TableProtocol.place``, step 1): a result when the
    open hand at the pre-grasp pose collides (codes 0-2), else the world's start state.

    Parameters
    ----------
    cpu
        The warp simulator's CPU simulator.
    pose
        ``(4, 4)`` TCP pose of the grasp, world frame.
    pos, quat
        ``(3,)`` and ``(4,)``: its position and MuJoCo quaternion.
    width
        The grasp's pad separation (m); the jaws open to ``width + width_margin``, clipped.
    target, roles
        The target body and the geom roles (``LiftSimulator.target_roles``).
    """
    p = cpu.params
    z_axis = pose[:3, 2].copy()
    open_width = float(jaw_opening(width, p.width_margin, cpu.min_width, cpu.max_width))
    pre = pos - p.approach_distance * z_axis
    cpu.place(pre, quat, open_width)
    code = cpu.contact_code(roles, target)
    if code is not None:
        return unfinished_result(cpu, Outcome(code), "placement", 0)
    d, objects = cpu.data, cpu.index.objects
    return {"pos": pos, "quat": quat, "R": pose[:3, :3].copy(), "start": pre, "open_width": open_width,
            "target": target, "roles": roles,
            "qpos": d.qpos.copy(), "ctrl": d.ctrl.copy(), "mark": cpu.mark(target),
            "objects0": (d.xipos[objects].copy(), d.xquat[objects].copy())}


class TableRun(BatchRun):
    """A batch of ``table`` grasps (module docstring): the approach before closing, the slip and lift-gain rules."""

    def __init__(self, sim, states: list[dict]) -> None:
        super().__init__(sim, states)
        p, cpu = sim.params, sim.cpu
        self.approach = cpu.schedule.approach
        self.pre = np.array([s["start"] for s in states])
        self.open_width = np.array([s["open_width"] for s in states])
        self.obj_pos0 = np.array([s["objects0"][0] for s in states])
        self.obj_quat0 = np.array([s["objects0"][1] for s in states])
        self.z0 = np.zeros(self.n)  # the target's height when closing ended
        self.target_index = np.searchsorted(cpu.index.objects, self.targets)  # the target among the objects
        self.shift2 = p.max_target_shift ** 2
        self.cos_half_turn = math.cos(min(p.max_target_turn, math.pi) / 2.0)
        self.slip2 = p.slip_tolerance ** 2
        self.cos_slip = math.cos(min(p.slip_rotation_tolerance, math.pi))

    def _before_closing(self) -> list[Segment]:
        """The approach: the grasp position plus ``approach[k] - approach_distance`` along the approach axis."""
        s, d = self.sim.cpu.schedule, self.sim.params.approach_distance
        return [Segment("approach", len(s.approach), "pos", s.approach - d)]

    def _closing_gravity(self) -> np.ndarray:
        cpu = self.sim.cpu
        return np.zeros(3) if cpu.params.gravity_until_closed else cpu.gravity.copy()

    def _read(self, contacts: bool) -> dict:
        out = super()._read(contacts)
        if contacts:
            out["xquat"] = self.sim.device_data.xquat.numpy().astype(float)
        return out

    def _static_code(self, i: int) -> int | None:
        """The pre-filter's check of world ``i``'s gripper as commanded now (the mocap row last written)."""
        cpu = self.sim.cpu
        hand = self.pre[i] + self.approach[self.k[i] - 1] * self.R[i, :, 2]
        return cpu.commanded_code(hand, self.quat[i], self.open_width[i], self.roles[i])

    def _check_before(self, worlds: np.ndarray, a: dict) -> None:
        """The approach rule (``check_approach``), then closing for the worlds whose approach ended."""
        cpu, n = self.sim.cpu, self.n
        live = live_codes(a["geom"], a["world"], self.B, cpu.index.geom_is_gripper, self.roles)[:n]
        objects = cpu.index.objects
        moved = moved_objects(a["xipos"][worlds][:, objects], a["xquat"][worlds][:, objects], self.obj_pos0[worlds],
                              self.obj_quat0[worlds], self.shift2, self.cos_half_turn)
        started = False
        for row, i in enumerate(worlds):
            static = self._static_code(int(i))
            code = min(NO_CODE if static is None else static, int(live[i]))
            if code == NO_CODE and moved[row].any():
                target_moved = moved[row, self.target_index[i]]
                code = Outcome.COLLISION_WITH_TARGET if target_moved else Outcome.COLLISION_WITH_CLUTTER
            if code != NO_CODE:
                self.results[i] = unfinished_result(cpu, Outcome(code), "approach", int(self.steps[i]))
                self.seg[i] = self.done_seg
            elif self.k[i] == self.seglen[0]:
                self._start_closing(int(i), a)
                started = True
        if started:
            self._write_ctrl()

    def _start_closing(self, i: int, a: dict) -> None:
        """World ``i``'s approach ended: command the smallest width (``LiftSimulator._close``)."""
        cpu = self.sim.cpu
        self.states[i]["ctrl"][cpu.index.act] = cpu.min_width
        t = self.targets[i]
        self.states[i]["mark"] = (a["xipos"][i, t].copy(), a["xmat"][i, t].reshape(3, 3).copy())
        q = cpu.index.jaw_qadr
        self.last_width[i] = a["qpos"][i, q[0]] + a["qpos"][i, q[1]]
        self.seg[i], self.k[i] = self.C, 0
        if self.friction is not None:
            self._pad_torsion_closing(i)

    def _end_closing(self, i: int, a: dict, p: np.ndarray, R: np.ndarray) -> None:
        self.z0[i] = a["xipos"][i, self.targets[i], 2]
        super()._end_closing(i, a, p, R)

    def _held_rule(self, held: np.ndarray, on: np.ndarray, a: dict, p: np.ndarray, R: np.ndarray) -> None:
        """Lift, hold, shake (``check_slip``): moved or turned in the hand beyond the slip tolerances -> 4."""
        bad = slipped(p[held], R[held], self.rel0_p[held], self.rel0_R[held], self.slip2, self.cos_slip)
        for i in held[bad]:
            self._decide(int(i), Outcome.SLIPPED_DURING_LIFTING, self.plan[self.seg[i]].phase, a, p, R)

    def _end_rule(self, i: int, on: np.ndarray, a: dict, p: np.ndarray, R: np.ndarray) -> None:
        """The end: risen less than ``min_lift_fraction * lift_height`` since closing ended -> 4, else 5."""
        params = self.sim.params
        code = Outcome.SLIPPED_DURING_LIFTING if self._lift_gain(i, a) < params.min_lift_fraction * \
            params.lift_height else Outcome.SUCCESS
        self._decide(i, code, "end", a, p, R)

    def _lift_gain(self, i: int, a: dict) -> float:
        return float(a["xipos"][i, self.targets[i], 2] - self.z0[i])
