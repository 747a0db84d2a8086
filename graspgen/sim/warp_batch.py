"""One batch of :class:`graspgen.sim.warp_backend.WarpLiftSimulator`: the per-world phase machine on MJWarp.

Every world follows its own timeline, as its grasp would on the CPU: closing (until the jaws stop, checked every
``check_interval`` steps, or the timeout), then the protocol's disturbance segments (:class:`Segment`), each with
its own checks every ``check_interval`` of its steps and at its end; a world whose outcome is decided stops counting
steps and its record is frozen (its world keeps stepping with the others, unobserved, until the batch is done).
What is read on the CPU (the end of closing, the results) is the CPU backend's own code
(:class:`graspgen.sim.lift_state.LiftState`, :mod:`graspgen.sim.lift_rules`).
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
from graspgen.sim.motion import Schedule
from graspgen.sim.protocols import LiftParams, Outcome, RolloutResult
from graspgen.sim.warp_rules import jaws_on, relative_poses

__all__ = ["BatchRun", "Segment", "closing_record", "disturbance_segments", "start_gravity", "unfinished_result"]

_CLOSING = 0  # seg index 0 is closing; 1..S the disturbance segments; S + 1 done


class Segment:
    """One stretch of a disturbance (a CPU ``_move`` or ``_wait`` call): ``n`` steps under phase name ``phase``;
    ``kind`` is ``pos`` (mocap at the grasp plus ``table[k]`` m along the approach axis), ``quat`` (mocap at the
    grasp turned by the quaternion ``table[k]``), ``wait`` (targets unchanged) or ``tug`` (a wait with the object
    pulled by its weight along the TCP-frame direction ``table (3,)``)."""

    def __init__(self, phase: str, n: int, kind: str, table: np.ndarray | None = None) -> None:
        self.phase, self.n, self.kind, self.table = phase, int(n), kind, table


def disturbance_segments(params: LiftParams, schedule: Schedule) -> list[Segment]:
    """The protocol's disturbance (the CPU backend's ``_acronym_shake`` / ``_graspgen_tugs``) as segments."""
    s = schedule
    if params.protocol == "acronym":
        return [Segment("shaking", len(s.shake_z), "pos", s.shake_z),
                Segment("shaking", len(s.shake_qx), "quat", s.shake_qx),
                Segment("holding", s.settle_steps, "wait")]
    return [Segment("shaking", s.tug_steps, "tug", d) for d in s.tug_dirs]


def start_gravity(cpu: LiftSimulator, R: np.ndarray) -> np.ndarray:
    """Gravity (3,) of a world once its closing ended, for the grasp's rotation ``R (3, 3)``
    (:meth:`LiftSimulator._acronym_shake`; ``graspgen``: off)."""
    if cpu.params.protocol == "acronym":
        if cpu.params.acronym.gravity == "world":
            return cpu.gravity.copy()
        if cpu.params.acronym.gravity == "approach":
            return math.sqrt(float(cpu.gravity @ cpu.gravity)) * R[:, 2]
    return np.zeros(3)


def unfinished_result(cpu: LiftSimulator, code: Outcome, phase: str, steps: int, contacts=None,
                      closing=None) -> RolloutResult:
    """A result decided before the disturbance started (placement or closing, after ``steps`` steps), as the CPU
    backend builds it; ``closing``: ``(closed_width, motion_closing, pose_closed)``."""
    nan = math.nan
    closed_width, motion, pose = closing if closing is not None else (nan, (nan, nan), np.full((4, 4), nan))
    return rollout_result(cpu.params, code, phase, steps, cpu.schedule.dt, closed_width, nan, (nan, nan),
                          no_contacts() if contacts is None else contacts, motion, (nan, nan), pose, (nan, nan))


def closing_record(cpu: LiftSimulator, world: int, state: dict, target: int, roles: np.ndarray, arrays: dict):
    """Load world ``world``'s state (``arrays``: the batch's ``qpos``, ``qvel``, ``qacc_warmstart``) into the CPU
    data and read the end of closing with the CPU backend's code: ``(closed_width, motion_closing, pose_closed,
    contacts)``."""
    d = cpu.data
    d.qpos[:] = arrays["qpos"][world]
    d.qvel[:] = arrays["qvel"][world]
    d.ctrl[:] = state["ctrl"]
    d.mocap_pos[cpu.index.mocap] = state["pos"]
    d.mocap_quat[cpu.index.mocap] = state["quat"]
    d.qacc_warmstart[:] = arrays["qacc_warmstart"][world]
    d.xfrc_applied[:] = 0.0
    gravity = cpu.model.opt.gravity
    gravity[:] = 0.0
    try:
        mujoco.mj_forward(cpu.model, d)
    finally:
        gravity[:] = cpu.gravity
    return cpu.width(), cpu.motion(target, state["mark"]), cpu.body_pose(target), cpu.jaw_contacts(roles)


class BatchRun:
    """A batch of states placed on the CPU (``WarpLiftSimulator._place``), rolled out together; :meth:`run`."""

    def __init__(self, sim, states: list[dict], target: int, roles: np.ndarray) -> None:
        self.sim, self.states, self.target, self.roles = sim, states, target, roles
        cpu = sim.cpu
        self.n = len(states)
        self.B = sim.nworld
        self.K = sim.params.check_interval
        self.tol = closing_tolerance(sim.params, cpu.schedule.dt)
        self.segments = sim.segments
        self.seglen = np.array([cpu.schedule.close_max_steps] + [s.n for s in self.segments] + [0])
        self.done_seg = len(self.segments) + 1
        n = self.n
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
        self.mark_x, self.mark_R = np.zeros((n, 3)), np.zeros((n, 3, 3))  # the target in the world then
        self.drift = np.zeros((n, 2))
        pad = [states[i % n] for i in range(self.B)]  # unused worlds repeat real ones (their results are dropped)
        self.mocap_pos = np.array([s["pos"] for s in pad])
        self.mocap_quat = np.array([s["quat"] for s in pad])
        self.gravity = np.zeros((self.B, 3))
        self.xfrc = np.zeros((self.B, cpu.model.nbody, 6))
        self._pad = pad

    # -- device I/O -----------------------------------------------------------------------------------------------

    def _reset(self) -> None:
        sim, cpu = self.sim, self.sim.cpu
        wp, mjw = sim.wp, sim.mjw
        with wp.ScopedDevice(sim.device):
            mjw.reset_data(sim.device_model, sim.device_data)
            sim.device_data.qpos.assign(np.array([s["qpos"] for s in self._pad], dtype=np.float32))
            sim.device_data.ctrl.assign(np.array([s["ctrl"] for s in self._pad], dtype=np.float32))
            m = cpu.index.mocap
            mp = np.zeros((self.B, cpu.model.nmocap, 3), dtype=np.float32)
            mq = np.zeros((self.B, cpu.model.nmocap, 4), dtype=np.float32)
            mp[:, m], mq[:, m] = self.mocap_pos, self.mocap_quat
            self._mp, self._mq = mp, mq
            sim.device_data.mocap_pos.assign(mp)
            sim.device_data.mocap_quat.assign(mq)
            sim.world_gravity.assign(self.gravity.astype(np.float32))
            sim.device_data.xfrc_applied.assign(self.xfrc.astype(np.float32))
        # closing: every world commands the smallest width (LiftSimulator._close)
        for s in self.states:
            s["ctrl"] = s["ctrl"].copy()
            s["ctrl"][cpu.index.act] = cpu.min_width
        with wp.ScopedDevice(sim.device):
            sim.device_data.ctrl.assign(np.array([s["ctrl"] for s in self._pad], dtype=np.float32))

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
        moving = active & (self.seg > _CLOSING)
        for j, s in enumerate(self.segments):
            sel = np.flatnonzero(moving & (self.seg == j + 1))
            if len(sel) == 0 or s.kind not in ("pos", "quat"):
                continue
            rows = s.table[self.k[sel]]
            if s.kind == "pos":
                self.mocap_pos[sel] = self.pos[sel] + rows[:, None] * self.R[sel, :, 2]
            else:
                self.mocap_pos[sel] = self.pos[sel]
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
        t, base, n = self.target, cpu.index.base, self.n
        on = jaws_on(a["geom"], a["world"], self.B, cpu.index.geom_side, self.roles)[:n]
        p, R = relative_poses(a["xipos"][:n, t], a["xmat"][:n, t].reshape(-1, 3, 3), a["xpos"][:n, base],
                              a["xmat"][:n, base].reshape(-1, 3, 3))
        forces_changed = False
        # closing (LiftSimulator._close): stopped when the width changed less than the tolerance since the last check
        closing = worlds[self.seg[worlds] == _CLOSING]
        if len(closing):
            width = self._width(a)[closing]
            stopped = np.abs(width - self.last_width[closing]) < self.tol
            self.last_width[closing] = width
            for i in closing[stopped | (self.k[closing] == self.seglen[_CLOSING])]:
                forces_changed |= self._end_closing(int(i), a, p, R)
        # the disturbance (check_held of LiftSimulator._rollout_free_space): drift, then neither jaw on -> 4
        held = worlds[(self.seg[worlds] > _CLOSING) & (self.seg[worlds] < self.done_seg)]
        held = held[~np.isin(held, closing)]
        if len(held):
            self._update_drift(held, p, R)
            for i in held[~on[held].any(axis=1)]:
                self._decide(int(i), Outcome.SLIPPED_DURING_LIFTING, self.segments[self.seg[i] - 1].phase, a, p, R)
            ended = held[(self.seg[held] < self.done_seg) & (self.k[held] == self.seglen[self.seg[held]])]
            for i in ended:
                forces_changed |= self._advance(int(i))
                if self.seg[i] == self.done_seg:  # the end: both jaws still on -> 5, else 4
                    code = Outcome.SUCCESS if on[i].all() else Outcome.SLIPPED_DURING_LIFTING
                    self._decide(int(i), code, "end", a, p, R)
        if forces_changed:
            with self.sim.wp.ScopedDevice(self.sim.device):
                self.sim.world_gravity.assign(self.gravity.astype(np.float32))
                self.sim.device_data.xfrc_applied.assign(self.xfrc.astype(np.float32))

    def _end_closing(self, i: int, a: dict, p: np.ndarray, R: np.ndarray) -> bool:
        """Closing ended in world ``i``: the CPU backend's record and rule, then the disturbance starts."""
        if "qvel" not in a:  # read once per check, whatever the number of worlds ending their closing
            a["qvel"] = self.sim.device_data.qvel.numpy().astype(float)
            a["qacc_warmstart"] = self.sim.device_data.qacc_warmstart.numpy().astype(float)
        t0 = time.perf_counter()
        closed_width, motion, pose, contacts = closing_record(self.sim.cpu, i, self.states[i], self.target,
                                                              self.roles, a)
        self.sim.timings["closing_record_s"] += time.perf_counter() - t0
        self.closing[i] = (closed_width, motion, pose, contacts)
        if not both_jaws(contacts):
            self.results[i] = unfinished_result(self.sim.cpu, Outcome.NO_CONTACT_ESTABLISHED, "closing",
                                                int(self.steps[i]), contacts, (closed_width, motion, pose))
            self.seg[i] = self.done_seg
            return False
        self.rel0_p[i], self.rel0_R[i] = p[i], R[i]
        self.mark_x[i], self.mark_R[i] = a["xipos"][i, self.target], a["xmat"][i, self.target].reshape(3, 3)
        self.gravity[i] = start_gravity(self.sim.cpu, self.R[i])
        self.seg[i], self.k[i] = _CLOSING, 0
        self._advance(i)
        return True

    def _advance(self, i: int) -> bool:
        """World ``i`` enters its next non-empty segment (or done); sets that segment's tug force."""
        self.seg[i] += 1
        self.k[i] = 0
        while self.seg[i] < self.done_seg and self.seglen[self.seg[i]] == 0:
            self.seg[i] += 1  # an empty wait (settle_time 0) takes no step and no check, as on the CPU
        self.xfrc[i, self.target] = 0.0
        if self.seg[i] < self.done_seg:
            s = self.segments[self.seg[i] - 1]
            if s.kind == "tug":
                cpu = self.sim.cpu
                weight = self.sim.params.graspgen.force_scale * float(cpu.model.body_subtreemass[self.target]) * \
                    math.sqrt(float(cpu.gravity @ cpu.gravity))
                self.xfrc[i, self.target, :3] = weight * (self.R[i] @ s.table)
        return True

    def _update_drift(self, worlds: np.ndarray, p: np.ndarray, R: np.ndarray) -> None:
        """The firm-hold measures (``_Drift.update``): largest displacement and rotation in the hand so far."""
        dp = p[worlds] - self.rel0_p[worlds]
        self.drift[worlds, 0] = np.maximum(self.drift[worlds, 0], np.sqrt(np.einsum("ij,ij->i", dp, dp)))
        self.drift[worlds, 1] = np.maximum(self.drift[worlds, 1], rotation_angles(self.rel0_R[worlds], R[worlds]))

    def _decide(self, i: int, code: Outcome, phase: str, a: dict, p: np.ndarray, R: np.ndarray) -> None:
        """World ``i``'s outcome after its disturbance started: the CPU backend's end-of-rollout measures."""
        cpu = self.sim.cpu
        p0, R0 = self.rel0_p[i], self.rel0_R[i]
        dp = p[i] - p0
        rel = (math.sqrt(float(dp @ dp)), float(rotation_angles(R0[None], R[i][None])[0]))
        x0, M0 = self.mark_x[i], self.mark_R[i]
        dx = a["xipos"][i, self.target] - x0
        motion_shaking = (math.sqrt(float(dx @ dx)), float(rotation_angles(M0[None], a["xmat"][i, self.target].reshape(
            1, 3, 3))[0]))
        closed_width, motion, pose, contacts = self.closing[i]
        self.results[i] = rollout_result(cpu.params, code, phase, int(self.steps[i]), cpu.schedule.dt, closed_width,
                                         math.nan, rel, contacts, motion, motion_shaking, pose,
                                         (float(self.drift[i, 0]), float(self.drift[i, 1])))
        self.seg[i] = self.done_seg
        self.xfrc[i, self.target] = 0.0
