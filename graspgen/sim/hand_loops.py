"""Closed kinematic loops of an MJCF hand resolved by MuJoCo itself (:class:`LoopSolver`, :class:`LoopPath`).

A hand such as MuJoCo Menagerie's Robotiq 2F-85 ties its bodies with equalities (``connect`` between a follower and
a coupler, ``weld``, tendon or non-linear joint couplings): the pads' pose is not the forward kinematics of the
closing joints alone but of every joint of the loops, which only the constraints fix. Rather than solving each kind
of loop by hand, the model file is compiled as it is (defaults, springs, joint limits, the equalities' own
``solref`` / ``solimp``) and its closing joints are driven quasi-statically from open to closed, with gravity,
contacts and actuators off: at each sample the closing joints are held at their value (and every joint outside the
hand at its ``qpos0``) while the other joints of the hand settle under the constraints, their springs and limits.
The settled joint values along the stroke (:class:`LoopPath`) then stand in for the closing joints' forward
kinematics; :mod:`graspgen.sim.gripper_derive` derives the slide or the parallelogram linkage from them as for an
open-chain hand and checks it against this path.

A loop that cannot be resolved this way is an error naming its equalities: one MuJoCo cannot close along the stroke
(off by more than :data:`LOOP_TOL`) or one that leaves a link free, so that closing and opening put it in different
places (an underactuated finger that only contact would fix).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from graspgen.errors import SettingsError

__all__ = ["LOOP_TOL", "LoopPath", "LoopSolver"]

#: Largest violation (m for positions, rad for angles) of a loop equality at a settled sample, and the largest
#: difference (m) of a hand body's position between closing and opening through the same sample.
LOOP_TOL = 1e-4
#: Constraint impedance of the loops and joint limits while they settle (MuJoCo's largest).
_STIFF_IMPEDANCE = 0.9999
#: Armature (kg m^2 or kg) added to the held joints.
_HELD_ARMATURE = 1e3
#: Simulation steps to move the closing joints over their whole range (fewer for a shorter move, at least 10).
_RAMP_STEPS = 2000
#: Largest number of steps to wait at a sample for the free joints to settle.
_MAX_HOLD_STEPS = 4000
#: Joint speed (rad/s or m/s) under which the free joints count as settled.
_SETTLED_SPEED = 1e-4


@dataclass(frozen=True)
class LoopPath:
    """The hand's joint values along its closing motion, with the loops closed by MuJoCo."""

    s: np.ndarray = field(repr=False)
    """(k,) closing fractions of the samples, 0 (open) to 1 (closed), increasing."""
    joints: tuple[str, ...]
    """The hand's hinge and slide joints, in the columns' order."""
    q: np.ndarray = field(repr=False)
    """(k, n) settled joint values (rad or m) at each sample."""
    equalities: tuple[str, ...] = ()
    """The equalities that close the loops (for messages)."""

    def at(self, s: float) -> dict[str, float]:
        """Joint values (rad or m) at closing fraction ``s``, linear between the samples."""
        return {n: float(np.interp(s, self.s, self.q[:, k])) for k, n in enumerate(self.joints)}


def _equality_rows(model: mujoco.MjModel, data: mujoco.MjData, ids: np.ndarray) -> np.ndarray:
    """Constraint rows of ``data`` that belong to the equalities ``ids``."""
    return np.flatnonzero((data.efc_type[:data.nefc] == int(mujoco.mjtConstraint.mjCNSTR_EQUALITY))
                          & np.isin(data.efc_id[:data.nefc], ids))


class LoopSolver:
    """A hand's MJCF model set up to settle its loops with the closing joints held (module docstring).

    Parameters
    ----------
    path
        The MJCF file.
    hand_joints
        The hinge and slide joints of the hand (the subtree of its base body): all but the closing ones settle.
    closing
        The joints that are driven.
    equalities
        The names of the equalities that close the hand's loops (for messages and the residual check).
    """

    def __init__(self, path: str | Path, hand_joints, closing, equalities) -> None:
        self.file = Path(path)
        model = mujoco.MjModel.from_xml_path(str(self.file))
        model.opt.gravity[:] = 0.0
        model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)
        # Rigid loops and limits: a spring that loads a loop must not stretch it (MuJoCo's constraints are soft; at the
        # stiffest impedance and time constant a 2 N load on a 50 g finger opens a connect by about 0.02 mm).
        for imp, ref in ((model.eq_solimp, model.eq_solref), (model.jnt_solimp, model.jnt_solref)):
            imp[:, :2] = _STIFF_IMPEDANCE
            ref[:, 0], ref[:, 1] = 2.0 * model.opt.timestep, 1.0
        self.model, self.data = model, mujoco.MjData(model)
        self.joints = tuple(hand_joints)
        self.closing = tuple(closing)
        self.equalities = tuple(equalities)
        self._eq_ids = np.array([_equality_id(model, n) for n in self.equalities], dtype=int)
        ids = {n: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in self.joints}
        self._qadr = np.array([model.jnt_qposadr[ids[n]] for n in self.joints])
        free = set(self.joints) - set(self.closing)
        held = [j for j in range(model.njnt) if mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) not in free]
        self._held_q = np.concatenate([np.arange(model.jnt_qposadr[j], model.jnt_qposadr[j] + _width(model, j, True))
                                       for j in held]).astype(int) if held else np.zeros(0, int)
        self._held_v = np.concatenate([np.arange(model.jnt_dofadr[j], model.jnt_dofadr[j] + _width(model, j, False))
                                       for j in held]).astype(int) if held else np.zeros(0, int)
        self._free_v = np.setdiff1d(np.arange(model.nv), self._held_v)
        # The held joints as if bolted down: light, the constraints would move them within each step (their values
        # are set again after it) and a spring loading a loop would stretch it by ten times more.
        model.dof_armature[self._held_v] += _HELD_ARMATURE
        self._closing_adr = np.array([model.jnt_qposadr[ids[n]] for n in self.closing], dtype=int)
        span = np.array([np.ptp(model.jnt_range[ids[n]]) for n in self.closing])
        self._span = np.where(span > 0.0, span, 1.0)
        self._hand_bodies = np.unique([model.jnt_bodyid[ids[n]] for n in self.joints])
        self._target = model.qpos0.copy()
        mujoco.mj_forward(model, self.data)

    def _step(self, target: np.ndarray) -> None:
        self.data.qpos[self._held_q] = target[self._held_q]
        self.data.qvel[self._held_v] = 0.0
        mujoco.mj_step(self.model, self.data)
        self.data.qpos[self._held_q] = target[self._held_q]
        self.data.qvel[self._held_v] = 0.0

    def settle(self, closing: dict[str, float], *, check: bool = True) -> dict[str, float]:
        """Move the closing joints to ``closing`` (name -> value, rad or m) in a ramp from where they are, let the
        other joints settle, and return every hand joint's value (rad or m). With ``check``, :class:`SettingsError`
        naming the loop equality that stays open by more than :data:`LOOP_TOL`."""
        target = self._target.copy()
        target[self._closing_adr] = [closing[n] for n in self.closing]
        start = self._target
        share = np.abs(target - start)[self._closing_adr] / self._span
        steps = max(10, int(np.ceil(_RAMP_STEPS * share.max(initial=0.0))))
        for k in range(1, steps + 1):
            self._step(start + (target - start) * (k / steps))
        self._target = target
        for _ in range(_MAX_HOLD_STEPS):
            self._step(target)
            if np.abs(self.data.qvel[self._free_v]).max(initial=0.0) < _SETTLED_SPEED:
                break
        mujoco.mj_forward(self.model, self.data)
        rows = _equality_rows(self.model, self.data, self._eq_ids)
        off = np.abs(self.data.efc_pos[rows])
        if check and rows.size and off.max() > LOOP_TOL:
            worst = int(self.data.efc_id[rows[int(np.argmax(off))]])
            name = self.equalities[int(np.flatnonzero(self._eq_ids == worst)[0])]
            at = ", ".join(f"{n} = {v:.4g}" for n, v in closing.items())
            raise SettingsError(
                f"model {self.file.name}: equality {name} cannot be closed with the closing joints at {at} (off by "
                f"{off.max() * 1e3:.3g} mm or mrad, more than {LOOP_TOL * 1e3:g}); name the joints that close the "
                "hand with joints: [...] or fix the loop")
        return {n: float(self.data.qpos[a]) for n, a in zip(self.joints, self._qadr)}

    def _bodies(self) -> np.ndarray:
        return self.data.xpos[self._hand_bodies].copy()

    def path(self, ends: dict[str, tuple[float, float]], samples: int) -> LoopPath:
        """The :class:`LoopPath` of the closing joints going from their open to their closed value (``ends``:
        name -> (open, closed)) in ``samples`` samples, checked against the way back (closing and opening must
        put every hand body in the same place within :data:`LOOP_TOL`, else :class:`SettingsError`)."""
        s = np.linspace(0.0, 1.0, samples)

        def at(v):
            return {n: a + v * (b - a) for n, (a, b) in ends.items()}
        q, there = [], []
        for v in s:
            step = self.settle(at(v))
            q.append([step[n] for n in self.joints])
            there.append(self._bodies())
        for k in range(samples - 1, -1, -1):
            self.settle(at(s[k]))
            gap = np.linalg.norm(self._bodies() - there[k], axis=1)
            if gap.max() > LOOP_TOL:
                body = mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_BODY,
                                         int(self._hand_bodies[int(np.argmax(gap))]))
                raise SettingsError(
                    f"model {self.file.name}: the loops ({', '.join(self.equalities)}) do not fix the fingers: body "
                    f"{body} is {gap.max() * 1e3:.2f} mm apart closing and opening through the same joint values "
                    f"({', '.join(self.closing)}); graspgen needs fingers whose pose the closing joints set (a spring "
                    "or a joint limit holding the loops' free links), or name more joints with joints: [...]")
        return LoopPath(s=s, joints=self.joints, q=np.array(q), equalities=self.equalities)


def _equality_id(model: mujoco.MjModel, name: str) -> int:
    """The id of equality ``name`` (an unnamed one goes by ``equality <id>``, as :mod:`graspgen.sim.hand_mjcf`
    calls it)."""
    found = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, name)
    if found < 0 and name.startswith("equality ") and name[9:].isdigit():
        found = int(name[9:])
    return found


def _width(model: mujoco.MjModel, j: int, qpos: bool) -> int:
    """Number of qpos (``qpos``) or dof entries of joint ``j``."""
    kind = int(model.jnt_type[j])
    if kind == mujoco.mjtJoint.mjJNT_FREE:
        return 7 if qpos else 6
    if kind == mujoco.mjtJoint.mjJNT_BALL:
        return 4 if qpos else 3
    return 1
