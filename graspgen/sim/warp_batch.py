"""One batch of :class:`graspgen.sim.warp_backend.WarpLiftSimulator`: the per-world phase machine on MJWarp.

Every world follows its own timeline, as its grasp would on the CPU: closing (until the jaws stop, checked every
``check_interval`` steps, or the timeout), then the protocol's disturbance segments (:class:`_Segment`), each with
its own checks every ``check_interval`` of its steps and at its end; a world whose outcome is decided stops counting
steps and its record is frozen (its world keeps stepping with the others, unobserved, until the batch is done).
"""

from __future__ import annotations

import math

import numpy as np

from graspgen.errors import SimulationError
from graspgen.sim.lift import Outcome, RolloutResult
from graspgen.sim.warp_backend import both_jaws, closing_tolerance
from graspgen.sim.warp_rules import angles, jaws_on, quat_mul_rows, relative_poses

__all__ = ["BatchRun"]

_CLOSING = 0  # seg index 0 is closing; 1..S the disturbance segments; S + 1 done


class BatchRun:
    """A batch of states placed on the CPU (``WarpLiftSimulator._place``), rolled out together; :meth:`run`."""

    def __init__(self, sim, states: list[dict], target: int, roles: np.ndarray) -> None:
        self.sim, self.states, self.target, self.roles = sim, states, target, roles
        cpu = sim.cpu
        self.n = len(states)
        self.B = sim.nworld
        self.K = sim.params.check_interval
        self.tol = closing_tolerance(sim.params, cpu._dt)
        self.segments = sim._segments
        self.seglen = np.array([cpu._close_max_steps] + [s.n for s in self.segments] + [0])
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
            mjw.reset_data(sim._m, sim._d)
            sim._d.qpos.assign(np.array([s["qpos"] for s in self._pad], dtype=np.float32))
            sim._d.ctrl.assign(np.array([s["ctrl"] for s in self._pad], dtype=np.float32))
            m = cpu._mocap
            mp = np.zeros((self.B, cpu.model.nmocap, 3), dtype=np.float32)
            mq = np.zeros((self.B, cpu.model.nmocap, 4), dtype=np.float32)
            mp[:, m], mq[:, m] = self.mocap_pos, self.mocap_quat
            self._mp, self._mq = mp, mq
            sim._d.mocap_pos.assign(mp)
            sim._d.mocap_quat.assign(mq)
            sim._gravity.assign(self.gravity.astype(np.float32))
            sim._d.xfrc_applied.assign(self.xfrc.astype(np.float32))
        # closing: every world commands the smallest width (LiftSimulator._close)
        for s in self.states:
            s["ctrl"] = s["ctrl"].copy()
            s["ctrl"][cpu._act] = cpu.min_width
        with wp.ScopedDevice(sim.device):
            sim._d.ctrl.assign(np.array([s["ctrl"] for s in self._pad], dtype=np.float32))

    def _read(self, contacts: bool) -> dict:
        d = self.sim._d
        out = {"qpos": d.qpos.numpy().astype(float), "xipos": d.xipos.numpy().astype(float),
               "xmat": d.xmat.numpy().astype(float), "xpos": d.xpos.numpy().astype(float)}
        if not np.isfinite(out["qpos"][: self.n]).all():
            bad = int(np.flatnonzero(~np.isfinite(out["qpos"][: self.n]).all(axis=1))[0])
            raise SimulationError(f"warp backend: the state of world {bad} is not finite (the simulation diverged)")
        if contacts:
            nacon = int(d.nacon.numpy()[0])
            if nacon > self.sim._naconmax:
                raise SimulationError(f"warp backend: {nacon} contacts exceed the {self.sim._naconmax} allocated "
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
            sim._step()
            self.steps[active] += 1
            self.k[active] += 1
            due = active & ((self.k % self.K == 0) | (self.k == self.seglen[self.seg]))
            if due.any():
                self._check(np.flatnonzero(due), self._read(True))
            active = self.seg < self.done_seg
        return self.results  # type: ignore[return-value]

    def _width(self, a: dict) -> np.ndarray:
        q = self.sim.cpu._jaw_qadr
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
                self.mocap_quat[sel] = quat_mul_rows(self.quat[sel], rows)
            changed = True
        if changed:
            m = self.sim.cpu._mocap
            self._mp[:, m], self._mq[:, m] = self.mocap_pos, self.mocap_quat
            with self.sim.wp.ScopedDevice(self.sim.device):
                self.sim._d.mocap_pos.assign(self._mp)
                self.sim._d.mocap_quat.assign(self._mq)

    def _check(self, worlds: np.ndarray, a: dict) -> None:
        """The rules of the worlds due for a check now (the CPU's ``check`` callbacks, world by world)."""
        cpu = self.sim.cpu
        t, base, n = self.target, cpu._base, self.n
        on = jaws_on(a["geom"], a["world"], self.B, cpu._geom_side, self.roles)[:n]
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
                self.sim._gravity.assign(self.gravity.astype(np.float32))
                self.sim._d.xfrc_applied.assign(self.xfrc.astype(np.float32))

    def _end_closing(self, i: int, a: dict, p: np.ndarray, R: np.ndarray) -> bool:
        """Closing ended in world ``i``: the CPU backend's record and rule, then the disturbance starts."""
        if "qvel" not in a:  # read once per check, whatever the number of worlds ending their closing
            a["qvel"] = self.sim._d.qvel.numpy().astype(float)
            a["qacc_warmstart"] = self.sim._d.qacc_warmstart.numpy().astype(float)
        closed_width, motion, pose, contacts = self.sim._closing_record(i, self.states[i], self.target,
                                                                        self.roles, a)
        self.closing[i] = (closed_width, motion, pose, contacts)
        if not both_jaws(contacts):
            cpu = self.sim.cpu
            cpu.steps = int(self.steps[i])
            self.results[i] = self.sim._unfinished(Outcome.NO_CONTACT_ESTABLISHED, "closing", contacts,
                                                   (closed_width, motion, pose))
            self.seg[i] = self.done_seg
            return False
        self.rel0_p[i], self.rel0_R[i] = p[i], R[i]
        self.mark_x[i], self.mark_R[i] = a["xipos"][i, self.target], a["xmat"][i, self.target].reshape(3, 3)
        self.gravity[i] = self.sim._start_gravity(self.R[i])
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
                    math.sqrt(float(cpu._gravity @ cpu._gravity))
                self.xfrc[i, self.target, :3] = weight * (self.R[i] @ s.table)
        return True

    def _update_drift(self, worlds: np.ndarray, p: np.ndarray, R: np.ndarray) -> None:
        """The firm-hold measures (``_Drift.update``): largest displacement and rotation in the hand so far."""
        dp = p[worlds] - self.rel0_p[worlds]
        self.drift[worlds, 0] = np.maximum(self.drift[worlds, 0], np.sqrt(np.einsum("ij,ij->i", dp, dp)))
        self.drift[worlds, 1] = np.maximum(self.drift[worlds, 1], angles(self.rel0_R[worlds], R[worlds]))

    def _decide(self, i: int, code: Outcome, phase: str, a: dict, p: np.ndarray, R: np.ndarray) -> None:
        """World ``i``'s outcome after its disturbance started: the CPU backend's end-of-rollout measures."""
        cpu = self.sim.cpu
        p0, R0 = self.rel0_p[i], self.rel0_R[i]
        dp = p[i] - p0
        rel = (math.sqrt(float(dp @ dp)), float(angles(R0[None], R[i][None])[0]))
        x0, M0 = self.mark_x[i], self.mark_R[i]
        dx = a["xipos"][i, self.target] - x0
        motion_shaking = (math.sqrt(float(dx @ dx)), float(angles(M0[None], a["xmat"][i, self.target].reshape(
            1, 3, 3))[0]))
        closed_width, motion, pose, contacts = self.closing[i]
        cpu.steps = int(self.steps[i])
        self.results[i] = cpu._result(code, phase, closed_width, math.nan, rel, contacts, motion, motion_shaking,
                                      pose, (float(self.drift[i, 0]), float(self.drift[i, 1])))
        self.seg[i] = self.done_seg
        self.xfrc[i, self.target] = 0.0
