"""One batch of :class:`graspgen.sim.warp_backend.WarpLiftSimulator`: the per-world phase machine on MJWarp.

Every world follows its own timeline, as its grasp would on the CPU: the protocol's segments before closing (the
``table`` protocol's approach: :class:`graspgen.sim.warp_table.TableRun`), closing (until the jaws stop, checked
every ``check_interval`` steps, or the timeout), then the protocol's disturbance segments
(:class:`graspgen.sim.motion.Segment`), each with its own checks every ``check_interval`` of its steps and at its
end; a world whose outcome is decided stops counting steps and its record is frozen (its world keeps stepping with
the others, unobserved, until the batch is done). What is read on the CPU (the end of closing, the results) is the
CPU backend's own code (:class:`graspgen.sim.lift_state.LiftState`, :mod:`graspgen.sim.lift_rules`). :class:`BatchRun`
is the machine of the protocols placed at the grasp (``placement`` ``"grasp"``, placed by :func:`free_placement`);
its hooks (:meth:`BatchRun._check_before`, ``_held_rule``, ``_end_rule``, ``_lift_gain``) are what the
``"pregrasp"`` placement's machine (``table``) replaces.
"""

from __future__ import annotations

import math
import time

import mujoco
import numpy as np

from graspgen.errors import SimulationError
from graspgen.geometry.poses import quat_mul, rotation_angles
from graspgen.sim.lift import LiftSimulator
from graspgen.sim.lift_rules import both_jaws, closing_tolerance, no_contacts, rollout_result
from graspgen.sim.motion import Segment
from graspgen.sim.protocols import Outcome, RolloutResult
from graspgen.sim.warp_rules import jaws_on, relative_poses

__all__ = ["BatchRun", "closing_record", "free_placement", "unfinished_result"]


def unfinished_result(cpu: LiftSimulator, code: Outcome, phase: str, steps: int, contacts=None,
                      closing=None) -> RolloutResult:
    """A result decided before the disturbance started (placement or closing, after ``steps`` steps), as the CPU
    backend builds it; ``closing``: ``(closed_width, motion_closing, pose_closed)``."""
    nan = math.nan
    closed_width, motion, pose = closing if closing is not None else (nan, (nan, nan), np.full((4, 4), nan))
    return rollout_result(cpu.params, code, phase, steps, cpu.schedule.dt, closed_width, nan, (nan, nan),
                          no_contacts() if contacts is None else contacts, motion, (nan, nan), pose, (nan, nan))


def free_placement(cpu: LiftSimulator, pose: np.ndarray, pos: np.ndarray, quat: np.ndarray, width: float | None,
                   target: int, roles: np.ndarray) -> dict | RolloutResult:
    """The free-space protocols' placement on the CPU (``FreeSpaceProtocol.rollout``'s, gravity off): a result when
    the hand at the grasp pose ``pose (4, 4)`` (``pos (3,)``, ``quat (4,)``), open to the protocol's opening,
    touches anything (the target with no allowance), else the world's start state; ``width`` is ignored."""
    cpu.place(pos, quat, cpu.schedule.open_width)
    code = cpu.contact_code(roles, target, cpu.strict_allowance)
    if code is not None:
        return unfinished_result(cpu, Outcome(code), "placement", 0)
    d = cpu.data
    return {"pos": pos, "quat": quat, "R": pose[:3, :3].copy(), "qpos": d.qpos.copy(), "ctrl": d.ctrl.copy(),
            "mark": cpu.mark(target), "target": target, "roles": roles}


def closing_record(cpu: LiftSimulator, world: int, state: dict, target: int, roles: np.ndarray, arrays: dict,
                   gravity: np.ndarray | None = None):
    """Load world ``world``'s state (``arrays``: the batch's ``qpos``, ``qvel``, ``qacc_warmstart``) into the CPU
    data and read the end of closing with the CPU backend's code: ``(closed_width, motion_closing, pose_closed,
    contacts)``; ``gravity (3,)``: the gravity closing ran under (None: off, the free-space protocols)."""
    d = cpu.data
    d.qpos[:] = arrays["qpos"][world]
    d.qvel[:] = arrays["qvel"][world]
    d.ctrl[:] = state["ctrl"]
    d.mocap_pos[cpu.index.mocap] = state["pos"]
    d.mocap_quat[cpu.index.mocap] = state["quat"]
    d.qacc_warmstart[:] = arrays["qacc_warmstart"][world]
    d.xfrc_applied[:] = 0.0
    view = cpu.model.opt.gravity
    view[:] = 0.0 if gravity is None else gravity
    try:
        mujoco.mj_forward(cpu.model, d)
    finally:
        view[:] = cpu.gravity
    return cpu.width(), cpu.motion(target, state["mark"]), cpu.body_pose(target), cpu.jaw_contacts(roles)


class BatchRun:
    """A batch of states placed on the CPU (``WarpLiftSimulator._place``; each with its ``target`` body id and geom
    ``roles``: the worlds of a batch may grasp different objects of the scene), rolled out together; :meth:`run`.

    ``seg`` numbers each world's segment in :attr:`plan`: the segments before closing (none here), closing (index
    :attr:`C`, ``None`` in the plan), the disturbance, then ``done_seg``; ``k`` counts the steps taken in it."""

    def __init__(self, sim, states: list[dict]) -> None:
        self.sim, self.states = sim, states
        cpu = sim.cpu
        self.n = n = len(states)
        self.B = sim.nworld
        self.targets = np.array([s["target"] for s in states], dtype=np.int64)
        """``(n,)`` the target body of each world."""
        self.roles = np.array([states[i % n]["roles"] for i in range(self.B)])
        """``(nworld, ngeom)`` the geom roles of each world (unused worlds repeat real ones)."""
        self.K = cpu.check_interval
        self.tol = closing_tolerance(sim.params, cpu.schedule.dt * cpu.check_interval)
        before = self._before_closing()
        self.C = len(before)
        """Index of closing in :attr:`plan`."""
        self.plan: list[Segment | None] = [*before, None, *sim.segments]
        """The segments, closing as None."""
        self.seglen = np.array([cpu.schedule.close_max_steps if s is None else s.n for s in self.plan] + [0])
        self.done_seg = len(self.plan)
        self.seg = np.zeros(n, dtype=np.int64)
        self.k = np.zeros(n, dtype=np.int64)
        self.steps = np.zeros(n, dtype=np.int64)
        self.last_width = np.zeros(n)
        self.pos = np.array([s["pos"] for s in states])
        self.quat = np.array([s["quat"] for s in states])
        self.R = np.array([s["R"] for s in states])
        self.results: list[RolloutResult | None] = [None] * n
        self.closing: list[tuple | None] = [None] * n
        self.rel0_p, self.rel0_R = np.zeros((n, 3)), np.zeros((n, 3, 3))  # the target in the hand at closing's end
        self.mark_x, self.mark_R = np.zeros((n, 3)), np.zeros((n, 3, 3))  # the target in the world at the mark
        self.marked = np.zeros(n, dtype=bool)
        self.drift = np.zeros((n, 2))
        pad = [states[i % n] for i in range(self.B)]  # unused worlds repeat real ones (their results are dropped)
        self.mocap_pos = np.array([s.get("start", s["pos"]) for s in pad])
        self.mocap_quat = np.array([s["quat"] for s in pad])
        self.gravity = np.zeros((self.B, 3))
        self.gravity[:] = self._closing_gravity()
        self.xfrc = np.zeros((self.B, cpu.model.nbody, 6))
        self._pad = pad
        self.forces_changed = False
        self.friction = None if sim.world_friction is None else np.repeat(cpu.model.geom_friction[None], self.B, 0)
        """``(nworld, ngeom, 3)`` each world's geom friction with the ``"patch"`` pad torsion, else None."""
        if self.friction is not None:  # placement: 0 on the pads (LiftState.place); closing: the whole face's
            self.friction[:, cpu.pad_patch.pad_geoms, 1] = 0.0
            if self.C == 0:
                for i in range(self.B):
                    self._pad_torsion_closing(i)

    def _pad_torsion_closing(self, i: int) -> None:
        """World ``i`` starts closing: its pads carry the target's whole-face torsion (``PatchTorsion.closing``)."""
        cpu = self.sim.cpu
        target = int(self.targets[i % self.n])
        cpu.pad_patch.closing(cpu.model, target)
        pads = cpu.pad_patch.pad_geoms
        self.friction[i, pads, 1] = cpu.model.geom_friction[pads, 1]
        self.forces_changed = True

    # -- the protocol's hooks (the free-space protocols here; graspgen.sim.warp_table.TableRun: ``table``) -------

    def _before_closing(self) -> list[Segment]:
        """The segments before closing."""
        return []

    def _closing_gravity(self) -> np.ndarray:
        """Gravity (3,) until a world's closing ends (free space: off)."""
        return np.zeros(3)

    def _check_before(self, worlds: np.ndarray, a: dict) -> None:
        """The rules of the worlds in a segment before closing, due for a check (none here)."""

    def _held_rule(self, held: np.ndarray, on: np.ndarray, a: dict, p: np.ndarray, R: np.ndarray) -> None:
        """The disturbance's rule (``check_held``): neither jaw on the target -> 4."""
        for i in held[~on[held].any(axis=1)]:
            self._decide(int(i), Outcome.SLIPPED_DURING_LIFTING, self.plan[self.seg[i]].phase, a, p, R)

    def _end_rule(self, i: int, on: np.ndarray, a: dict, p: np.ndarray, R: np.ndarray) -> None:
        """The end: both jaws still on -> 5, else 4."""
        self._decide(i, Outcome.SUCCESS if on[i].all() else Outcome.SLIPPED_DURING_LIFTING, "end", a, p, R)

    def _lift_gain(self, i: int, a: dict) -> float:
        """``lift_gain`` of a decided world (free space: NaN)."""
        return math.nan

    # -- device I/O -----------------------------------------------------------------------------------------------

    def _reset(self) -> None:
        sim, cpu = self.sim, self.sim.cpu
        wp, mjw = sim.wp, sim.mjw
        with wp.ScopedDevice(sim.device):
            mjw.reset_data(sim.device_model, sim.device_data)
            sim.device_data.qpos.assign(np.array([s["qpos"] for s in self._pad], dtype=np.float32))
            m = cpu.index.mocap
            mp = np.zeros((self.B, cpu.model.nmocap, 3), dtype=np.float32)
            mq = np.zeros((self.B, cpu.model.nmocap, 4), dtype=np.float32)
            mp[:, m], mq[:, m] = self.mocap_pos, self.mocap_quat
            self._mp, self._mq = mp, mq
            sim.device_data.mocap_pos.assign(mp)
            sim.device_data.mocap_quat.assign(mq)
            sim.world_gravity.assign(self.gravity.astype(np.float32))
            sim.device_data.xfrc_applied.assign(self.xfrc.astype(np.float32))
            if self.friction is not None:
                sim.world_friction.assign(self.friction.astype(np.float32))
        for s in self.states:
            s["ctrl"] = s["ctrl"].copy()
        if self.C == 0:  # closing from the start: every world commands the smallest width (LiftSimulator._close)
            for s in self.states:
                s["ctrl"][cpu.index.act] = cpu.min_width
        self._write_ctrl()

    def _write_ctrl(self) -> None:
        with self.sim.wp.ScopedDevice(self.sim.device):
            self.sim.device_data.ctrl.assign(np.array([s["ctrl"] for s in self._pad], dtype=np.float32))

    def _read(self, contacts: bool) -> dict:
        d = self.sim.device_data
        out = {"qpos": d.qpos.numpy().astype(float), "xipos": d.xipos.numpy().astype(float),
               "xmat": d.xmat.numpy().astype(float), "xpos": d.xpos.numpy().astype(float)}
        if not np.isfinite(out["qpos"][: self.n]).all():
            bad = int(np.flatnonzero(~np.isfinite(out["qpos"][: self.n]).all(axis=1))[0])
            raise SimulationError(f"warp backend: the state of world {bad} is not finite (the simulation diverged)")
        if contacts:
            nacon = int(d.nacon.numpy()[0])
            if nacon > self.sim.naconmax:
                raise SimulationError(f"warp backend: {nacon} contacts exceed the {self.sim.naconmax} allocated "
                                      f"(raise nconmax, now {self.sim.nconmax} per world)")
            if nacon == 0:
                out["geom"], out["world"] = np.zeros((0, 2), dtype=np.int64), np.zeros(0, dtype=np.int64)
            else:  # a view's copy: the nacon rows only, not the whole buffer
                out["geom"] = d.contact.geom[:nacon].numpy().astype(np.int64).reshape(nacon, 2)
                out["world"] = d.contact.worldid[:nacon].numpy().astype(np.int64)
        return out

    # -- the loop -------------------------------------------------------------------------------------------------

    def run(self) -> list[RolloutResult]:
        sim = self.sim
        self._reset()
        a = self._read(False)
        self.last_width = self._width(a)
        active = np.ones(self.n, dtype=bool)
        while active.any():
            self._targets(active)
            sim.step()
            self.steps[active] += 1
            self.k[active] += 1
            due = active & ((self.k % self.K == 0) | (self.k == self.seglen[self.seg]))
            if due.any():
                self._check(np.flatnonzero(due), self._read(True))
            active = self.seg < self.done_seg
        return self.results  # type: ignore[return-value]

    def _width(self, a: dict) -> np.ndarray:
        q = self.sim.cpu.index.jaw_qadr
        return a["qpos"][: self.n, q[0]] + a["qpos"][: self.n, q[1]]

    def _targets(self, active: np.ndarray) -> None:
        """Write this step's mocap targets (the segment's row ``k``) for the worlds in a moving segment."""
        changed = False
        for j, s in enumerate(self.plan):
            if s is None or s.kind not in ("pos", "zpos", "quat"):
                continue
            sel = np.flatnonzero(active & (self.seg == j))
            if len(sel) == 0:
                continue
            rows = s.table[self.k[sel]]
            if s.kind == "pos":
                self.mocap_pos[sel] = self.pos[sel] + rows[:, None] * self.R[sel, :, 2]
            elif s.kind == "zpos":
                self.mocap_pos[sel] = self.pos[sel]
                self.mocap_pos[sel, 2] += rows
            else:
                self.mocap_pos[sel] = self.pos[sel]
                self.mocap_pos[sel, 2] += s.lift
                self.mocap_quat[sel] = quat_mul(self.quat[sel], rows)
            changed = True
        if changed:
            m = self.sim.cpu.index.mocap
            self._mp[:, m], self._mq[:, m] = self.mocap_pos, self.mocap_quat
            with self.sim.wp.ScopedDevice(self.sim.device):
                self.sim.device_data.mocap_pos.assign(self._mp)
                self.sim.device_data.mocap_quat.assign(self._mq)

    def _check(self, worlds: np.ndarray, a: dict) -> None:
        """The rules of the worlds due for a check now (the CPU's ``check`` callbacks, world by world)."""
        cpu = self.sim.cpu
        t, base, n, C = self.targets, cpu.index.base, self.n, self.C
        seg0 = self.seg[worlds].copy()  # the segment each world was checked in (a rule may move it on)
        on = jaws_on(a["geom"], a["world"], self.B, cpu.index.geom_side, self.roles)[:n]
        rows = np.arange(n)
        p, R = relative_poses(a["xipos"][rows, t], a["xmat"][rows, t].reshape(-1, 3, 3), a["xpos"][:n, base],
                              a["xmat"][:n, base].reshape(-1, 3, 3))
        self.forces_changed = False
        if C:
            self._check_before(worlds[seg0 < C], a)
        # closing (LiftSimulator._close): stopped when the width changed less than the tolerance since the last check
        closing = worlds[seg0 == C]
        if len(closing):
            width = self._width(a)[closing]
            stopped = np.abs(width - self.last_width[closing]) < self.tol
            self.last_width[closing] = width
            for i in closing[stopped | (self.k[closing] == self.seglen[C])]:
                self._end_closing(int(i), a, p, R)
        # the disturbance: the firm-hold drift, the protocol's rule, the end of each segment
        held = worlds[(seg0 > C) & (seg0 < self.done_seg)]
        if len(held):
            self._update_drift(held, p, R)
            self._held_rule(held, on, a, p, R)
            ended = held[(self.seg[held] < self.done_seg) & (self.k[held] == self.seglen[self.seg[held]])]
            for i in ended:
                self._advance(int(i), a)
                if self.seg[i] == self.done_seg:
                    self._end_rule(int(i), on, a, p, R)
        if self.forces_changed:
            with self.sim.wp.ScopedDevice(self.sim.device):
                self.sim.world_gravity.assign(self.gravity.astype(np.float32))
                self.sim.device_data.xfrc_applied.assign(self.xfrc.astype(np.float32))
                if self.friction is not None:
                    self.sim.world_friction.assign(self.friction.astype(np.float32))

    def _end_closing(self, i: int, a: dict, p: np.ndarray, R: np.ndarray) -> None:
        """Closing ended in world ``i``: the CPU backend's record and rule, then the disturbance starts."""
        if "qvel" not in a:  # read once per check, whatever the number of worlds ending their closing
            a["qvel"] = self.sim.device_data.qvel.numpy().astype(float)
            a["qacc_warmstart"] = self.sim.device_data.qacc_warmstart.numpy().astype(float)
        t0 = time.perf_counter()
        gravity = self.gravity[i].copy() if self.gravity[i].any() else None
        closed_width, motion, pose, contacts = closing_record(self.sim.cpu, i, self.states[i], int(self.targets[i]),
                                                              self.roles[i], a, gravity)
        if self.friction is not None:  # the CPU data holds world i's closed state: its pads' patch torsion
            cpu = self.sim.cpu
            cpu.pad_patch.closed(cpu.model, cpu.data, int(self.targets[i]))
            pads = cpu.pad_patch.pad_geoms
            self.friction[i, pads, 1] = cpu.model.geom_friction[pads, 1]
        self.sim.timings["closing_record_s"] += time.perf_counter() - t0
        self.closing[i] = (closed_width, motion, pose, contacts)
        if not both_jaws(contacts):
            self.results[i] = unfinished_result(self.sim.cpu, Outcome.NO_CONTACT_ESTABLISHED, "closing",
                                                int(self.steps[i]), contacts, (closed_width, motion, pose))
            self.seg[i] = self.done_seg
            return
        self.rel0_p[i], self.rel0_R[i] = p[i], R[i]
        self.gravity[i] = self.sim.protocol.start_gravity(self.sim.params, self.sim.cpu.gravity, self.R[i])
        self.forces_changed = True
        self.seg[i], self.k[i] = self.C, 0
        self._advance(i, a)

    def _advance(self, i: int, a: dict) -> None:
        """World ``i`` enters its next non-empty segment (or done); sets that segment's tug force and takes the
        object's pose when a segment with ``mark`` starts."""
        self.seg[i] += 1
        self.k[i] = 0
        while self.seg[i] < self.done_seg and self.seglen[self.seg[i]] == 0:
            self.seg[i] += 1  # an empty wait (settle_time 0) takes no step and no check, as on the CPU
        t = int(self.targets[i])
        self.xfrc[i, t] = 0.0
        self.forces_changed = True
        if self.seg[i] < self.done_seg:
            s = self.plan[self.seg[i]]
            if s.mark:
                self.mark_x[i], self.mark_R[i] = a["xipos"][i, t], a["xmat"][i, t].reshape(3, 3)
                self.marked[i] = True
            if s.kind == "tug":
                cpu = self.sim.cpu
                weight = self.sim.params.graspdatagen.force_scale * float(cpu.model.body_subtreemass[t]) * \
                    math.sqrt(float(cpu.gravity @ cpu.gravity))
                self.xfrc[i, t, :3] = weight * (self.R[i] @ s.table)

    def _update_drift(self, worlds: np.ndarray, p: np.ndarray, R: np.ndarray) -> None:
        """The firm-hold measures (``_Drift.update``): largest displacement and rotation in the hand so far."""
        dp = p[worlds] - self.rel0_p[worlds]
        self.drift[worlds, 0] = np.maximum(self.drift[worlds, 0], np.sqrt(np.einsum("ij,ij->i", dp, dp)))
        self.drift[worlds, 1] = np.maximum(self.drift[worlds, 1], rotation_angles(self.rel0_R[worlds], R[worlds]))

    def _decide(self, i: int, code: Outcome, phase: str, a: dict, p: np.ndarray, R: np.ndarray) -> None:
        """World ``i``'s outcome after its disturbance started: the CPU backend's end-of-rollout measures."""
        cpu, t = self.sim.cpu, int(self.targets[i])
        p0, R0 = self.rel0_p[i], self.rel0_R[i]
        dp = p[i] - p0
        rel = (math.sqrt(float(dp @ dp)), float(rotation_angles(R0[None], R[i][None])[0]))
        motion_shaking = (math.nan, math.nan)
        if self.marked[i]:
            dx = a["xipos"][i, t] - self.mark_x[i]
            turned = rotation_angles(self.mark_R[i][None], a["xmat"][i, t].reshape(1, 3, 3))[0]
            motion_shaking = (math.sqrt(float(dx @ dx)), float(turned))
        closed_width, motion, pose, contacts = self.closing[i]
        self.results[i] = rollout_result(cpu.params, code, phase, int(self.steps[i]), cpu.schedule.dt, closed_width,
                                         self._lift_gain(i, a), rel, contacts, motion, motion_shaking, pose,
                                         (float(self.drift[i, 0]), float(self.drift[i, 1])))
        self.seg[i] = self.done_seg
        self.xfrc[i, t] = 0.0
        self.forces_changed = True
