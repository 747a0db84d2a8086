"""The state and the steps of a grasp-and-lift rollout in one compiled scene: :class:`LiftState`, the base of
:class:`graspgen.sim.lift.LiftSimulator` (which adds the protocols' phase sequences).

What is here is what a rollout does between the protocols' decisions, and what the MuJoCo Warp backend
(:mod:`graspgen.sim.warp_backend`) reuses on the CPU: its own copy of the model with the protocol's physics and
grip written into it (:mod:`graspgen.sim.lift_model`), the one :class:`mujoco.MjData`, the placement, the
contact rule of placement and approach, the readings of the target's pose and contacts, the stepping with checks
every ``check_interval`` steps, closing, and the result record (:mod:`graspgen.sim.lift_rules`).
"""

from __future__ import annotations

import copy
import math

import mujoco
import numpy as np

from graspgen.errors import SettingsError
from graspgen.geometry.poses import rotation_angle
from graspgen.sim.gripper_model import GRIPPER_GEOM_GROUP
from graspgen.sim.lift_model import StaticCheck, apply_contact_overrides, index_scene, set_grip
from graspgen.sim.lift_rules import Drift, closing_tolerance, jaw_contacts, live_code, rollout_result
from graspgen.sim.pad_patch import PatchTorsion
from graspgen.sim.pad_sink import BoundedContact, bounded_contact
from graspgen.sim.prefilter import TARGET_TOUCH_DEPTH, touch_allowance
from graspgen.sim.protocol_phases import protocol_of
from graspgen.sim.protocols import LiftParams, RolloutResult
from graspgen.validation import check_instance

__all__ = ["LiftState"]


class _JawsStopped(Exception):
    """Internal: the closing jaws have stopped."""


class LiftState:
    """One compiled scene set up for rollouts, and the steps of a rollout; :class:`graspgen.sim.lift.
    LiftSimulator` documents the parameters (``model``, ``params``, ``qpos``, ``prefix``) and the rules."""

    def __init__(self, model: mujoco.MjModel, params: LiftParams | None = None, *, qpos=None,
                 prefix: str = "gripper/") -> None:
        check_instance("model", model, mujoco.MjModel, what="compiled mujoco.MjModel")
        params = check_instance("params", LiftParams() if params is None else params, LiftParams)
        if not isinstance(prefix, str) or not prefix:
            raise SettingsError(f"prefix: expected a non-empty string, got {prefix!r}")
        self.params = params
        self.prefix = prefix
        self.model = m = self._own_model(model, params)
        self.gravity = np.array(model.opt.gravity, dtype=float)
        """The scene's gravity (3,) m/s^2 (the protocols switch the model's off and on again)."""
        self.index = ix = index_scene(m, prefix)
        """Ids of the gripper's elements and the geom roles (:class:`graspgen.sim.lift_model.LiftIndex`)."""
        self.min_width, self.max_width = ix.min_width, ix.max_width
        """Pad separation range (m) of the gripper (its width actuator's control range)."""
        self.grip_force, self.closing_speed = set_grip(m, params, ix)
        """Force (N) each jaw presses with when closed on an object; width rate (m/s) of the closing jaws when
        nothing is in the way."""
        self._allowance = touch_allowance(m, prefix=prefix, depth=0.0 if params.target_touch_fails
                                          else TARGET_TOUCH_DEPTH)
        """(ngeom,) float: how deep (m) each gripper geom may press into the target (the touch rule)."""
        # The free-space protocols keep their sources' rule: the open hand must not touch the target at all.
        self.strict_allowance = np.zeros(m.ngeom)
        """(ngeom,) zeros: the free-space protocols' touch rule (no allowance; :meth:`contact_code`)."""
        self.object_names: tuple[str, ...] = ix.object_names
        """Names of the movable object bodies (possible targets)."""
        self._roles: dict[str, tuple[int, np.ndarray, int]] = {}
        # The static check's private model (_static_code): the scene as it stood, the gripper as commanded; copied
        # before the protocol's contact overrides, as it always was.
        self._static = StaticCheck(m, ix)
        self._shift2 = params.max_target_shift ** 2
        self._cos_half_turn = math.cos(min(params.max_target_turn, math.pi) / 2.0)
        self._slip2 = params.slip_tolerance ** 2
        self._cos_slip = math.cos(min(params.slip_rotation_tolerance, math.pi))
        overrides = protocol_of(params).contact_overrides(params)
        if overrides is not None:
            apply_contact_overrides(m, overrides, ix, prefix)
        self.contact = self._bound_pad_sink(m, params, ix)
        """The gripper's contact time constant and timestep division for this scene's objects
        (:class:`graspgen.sim.pad_sink.BoundedContact`; ``LiftParams.pad_sink``)."""
        self.check_interval = params.check_interval * self.contact.substeps
        """Steps between two checks of the rules: ``params.check_interval`` at the base timestep, so a scene with a
        divided timestep checks at the same simulated times."""
        explicit = overrides is not None and overrides.torsional_friction is not None
        self.pad_patch = None if params.pad_torsion == "face" or explicit else PatchTorsion(
            m, prefix, ~ix.geom_is_gripper & ~ix.geom_static, GRIPPER_GEOM_GROUP)
        """The ``"patch"`` pad-torsion model (:mod:`graspgen.sim.pad_patch`); None with ``"face"`` or an explicit
        torsional friction in the protocol's contact overrides (``acronym.torsional_friction``), which then holds
        for every contact."""
        self.data = mujoco.MjData(m)
        """The one :class:`mujoco.MjData` every rollout reuses (after a rollout: its final state)."""
        self._qpos_init = self._initial_qpos(m, qpos)
        self._cache_views()
        self.schedule = protocol_of(params).schedule(params, self._dt, self.min_width, self.max_width,
                                                     self.closing_speed)
        """The protocol's motion profiles and step counts (:class:`graspgen.sim.motion.Schedule`, from the
        protocol's ``schedule``)."""
        self._f6 = np.zeros(6)
        self.steps = 0
        """Steps taken by the current (or last) rollout."""

    # -- set-up -------------------------------------------------------------------------------------------------

    @staticmethod
    def _own_model(model: mujoco.MjModel, params: LiftParams) -> mujoco.MjModel:
        """Our own copy: physics options, grip force and (in free-space mode) gravity are written into it."""
        m = copy.deepcopy(model)
        params.physics_options(np.array(m.opt.gravity, dtype=float)).apply(m)
        m.opt.noslip_iterations = params.noslip_iterations
        m.opt.iterations = params.iterations
        m.opt.ls_iterations = params.ls_iterations
        return m

    def _bound_pad_sink(self, m: mujoco.MjModel, params: LiftParams, ix) -> BoundedContact:
        """``params.pad_sink``: ``bounded`` shortens the gripper's contact time constant (and the timestep) in ``m``
        for light objects (:func:`graspgen.sim.pad_sink.bounded_contact`); ``model`` leaves ``m`` as it is."""
        grip = np.flatnonzero(ix.geom_is_gripper)
        if params.pad_sink == "model":
            return BoundedContact(float(m.geom_solref[grip, 0].min()), 1, math.nan)
        return bounded_contact(m, grip, ix.objects, self.grip_force)

    @staticmethod
    def _initial_qpos(m: mujoco.MjModel, qpos) -> np.ndarray:
        """``qpos`` (None: ``qpos0``) as a read-only ``(nq,)`` float64 copy; SettingsError naming ``qpos``."""
        if qpos is None:
            qpos = m.qpos0
        qpos = np.array(qpos, dtype=float)
        if qpos.shape != (m.nq,) or not np.isfinite(qpos).all():
            raise SettingsError(f"qpos: expected {m.nq} finite numbers, got shape {qpos.shape}")
        qpos.setflags(write=False)
        return qpos

    def _cache_views(self) -> None:
        """Views into ``data`` and the model kept for the rules (valid for the life of :attr:`data`)."""
        m, d, ix = self.model, self.data, self.index
        self._qpos, self._ctrl = d.qpos, d.ctrl
        self._mocap_pos, self._mocap_quat = d.mocap_pos[ix.mocap], d.mocap_quat[ix.mocap]
        self._xipos, self._xquat, self._xmat, self._xpos = d.xipos, d.xquat, d.xmat, d.xpos
        self._gravity_view = m.opt.gravity
        self._dt = float(m.opt.timestep)

    # -- the steps of a rollout (shared with graspgen.sim.warp_backend) -----------------------------------------

    def target_roles(self, target_body) -> tuple[int, np.ndarray, int]:
        """(target body id, geom roles (ngeom,) int8, index of the target in the object list), cached;
        SettingsError naming ``target_body`` when it is not one of :attr:`object_names`."""
        if target_body in self._roles:
            return self._roles[target_body]
        if not isinstance(target_body, str):
            raise SettingsError(f"target_body: expected a body name, got {target_body!r}")
        bid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, target_body)
        if bid < 0 or bid not in self.index.objects:
            raise SettingsError(f"target_body: no movable object body named {target_body!r}; objects: "
                                f"{', '.join(self.object_names) or '(none)'}")
        self._roles[target_body] = (bid, self.index.roles(bid), int(np.flatnonzero(self.index.objects == bid)[0]))
        return self._roles[target_body]

    def place(self, pos: np.ndarray, quat: np.ndarray, width: float) -> None:
        """Placement: ``mj_resetData`` plus the initial ``qpos``, the hand (free joint and mocap target) at
        ``pos (3,)`` / ``quat (4,)``, the jaws and the width command at ``width`` m; ``mj_forward``."""
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        self._qpos[:] = self._qpos_init
        a = self.index.base_qadr
        self._qpos[a:a + 3] = pos
        self._qpos[a + 3:a + 7] = quat
        half = width / 2.0
        for qadr in self.index.jaw_qadr:
            self._qpos[qadr] = half
        self.index.couplings.apply(self._qpos)
        self._ctrl[self.index.act] = width
        self._mocap_pos[:] = pos
        self._mocap_quat[:] = quat
        if self.pad_patch is not None:
            self.pad_patch.placed(m)
        mujoco.mj_forward(m, d)

    def contact_code(self, roles: np.ndarray, target: int, allowance: np.ndarray | None = None) -> int | None:
        """Lowest outcome code (0 support, 1 target, 2 clutter) among the gripper's collisions now; None if none:
        the pre-filter's static check (:meth:`_static_code`, the touch rule with ``allowance`` per geom, None: the
        table protocol's) and the live contacts with support and other objects (any contact; the live contacts
        with the target do not count: a pushed target yields, see :meth:`_static_code`)."""
        code = self._static_code(roles, target, self._allowance if allowance is None else allowance)
        return live_code(self.data, self.index.geom_is_gripper, roles, code)

    def width(self) -> float:
        """Pad separation (m) now."""
        q = self.index.jaw_qadr
        return float(self._qpos[q[0]] + self._qpos[q[1]])

    def relative(self, target: int) -> tuple[np.ndarray, np.ndarray]:
        """Target's centre of mass (3,) and rotation (3, 3) in the TCP frame now."""
        base = self.index.base
        R_tcp = self._xmat[base].reshape(3, 3)
        p = (self._xipos[target] - self._xpos[base]) @ R_tcp  # = R_tcp^T (x - x_tcp)
        R = R_tcp.T @ self._xmat[target].reshape(3, 3)
        return p, R

    def mark(self, target: int) -> tuple[np.ndarray, np.ndarray]:
        """The target's centre of mass (3,) and rotation (3, 3), world frame, now (copies)."""
        return self._xipos[target].copy(), self._xmat[target].reshape(3, 3).copy()

    def motion(self, target: int, mark: tuple[np.ndarray, np.ndarray]) -> tuple[float, float]:
        """Displacement (m) and rotation angle (rad) of the target, world frame, since ``mark``."""
        d = self._xipos[target] - mark[0]
        return math.sqrt(float(d @ d)), rotation_angle(mark[1], self._xmat[target].reshape(3, 3))

    def body_pose(self, body: int) -> np.ndarray:
        """(4, 4) world pose of ``body``'s frame now."""
        T = np.eye(4)
        T[:3, :3] = self._xmat[body].reshape(3, 3)
        T[:3, 3] = self._xpos[body]
        return T

    def jaw_contacts(self, roles: np.ndarray):
        """Jaw-target contacts now (:func:`graspgen.sim.lift_rules.jaw_contacts`)."""
        return jaw_contacts(self.model, self.data, self.index.geom_side, roles, self._f6)

    def result(self, code, phase, closed_width, lift_gain, relative, contacts, motion_closing, motion_shaking,
               pose_closed, drift) -> RolloutResult:
        """The :class:`RolloutResult` of the rollout so far (:attr:`steps`; the rest as
        :func:`graspgen.sim.lift_rules.rollout_result` takes them)."""
        return rollout_result(self.params, code, phase, self.steps, self._dt, closed_width, lift_gain, relative,
                              contacts, motion_closing, motion_shaking, pose_closed, drift)

    # -- rules and stepping ---------------------------------------------------------------------------------------

    def _static_code(self, roles: np.ndarray, target: int, allowance: np.ndarray) -> int | None:
        """The pre-filter's check (:class:`graspgen.sim.prefilter.CollisionChecker`) at this instant of the rollout:
        the lowest code (0 support, 1 target by the touch rule, 2 clutter) of the gripper as commanded against the
        scene as it stood at placement; None if free. ``allowance`` (``(ngeom,)`` m,
        :func:`graspgen.sim.prefilter.touch_allowance`): how deep each gripper geom may press into the target.

        In a private copy of the model in which only gripper-vs-other pairs collide, every object stands at its
        initial ``qpos``, the hand at the mocap target (its pose on the approach line now) and each jaw at half the
        commanded opening; ``mj_kinematics`` + ``mj_collision``, no step (:class:`graspgen.sim.lift_model.
        StaticCheck`).

        Why the scene as it stood: a pushed target yields (a finger pressing on it mostly moves it, a knocked one
        flies off and loses contact), so its current contacts say little about how far the finger went into it;
        the motion itself is judged by ``max_target_shift`` / ``max_target_turn``. Why the commanded gripper: the
        simulated hand lags the mocap target by up to ~2.5 mm at full approach speed and ~1 mm when the approach
        ends (the weld's 5 ms time constant), and a jaw pressed into the target gives way against its force-limited
        servo; both are the softness of the simulated mount and drive, not the path a position-controlled arm and a
        non-backdrivable gripper take (with them a finger pressed 3 mm into the target could pass as a brush), and
        support and clutter are checked on the same commanded gripper so that the first kind of collision on the
        way is the pre-filter's. The live contacts (:meth:`contact_code`) add what only the simulation sees."""
        return self.commanded_code(self._mocap_pos, self._mocap_quat, self._ctrl[self.index.act], roles, allowance)

    def commanded_code(self, hand_pos: np.ndarray, hand_quat: np.ndarray, opening: float, roles: np.ndarray,
                       allowance: np.ndarray | None = None) -> int | None:
        """The pre-filter's check of :meth:`_static_code` for a gripper commanded to ``hand_pos (3,)`` /
        ``hand_quat (4,)`` with its pads ``opening`` m apart, against the scene as placed (the initial ``qpos``);
        ``allowance (ngeom,)`` m, None: the table protocol's touch rule. The MuJoCo Warp backend asks it for each
        world (:mod:`graspgen.sim.warp_table`)."""
        return self._static.code(self._qpos_init, hand_pos, hand_quat, opening, roles,
                                 self._allowance if allowance is None else allowance)

    def _moved(self, pos0: np.ndarray, quat0: np.ndarray) -> np.ndarray:
        """``(n_objects,) bool``: which objects' centres of mass moved more than ``max_target_shift`` or turned more
        than ``max_target_turn`` since ``pos0 (n, 3)``, ``quat0 (n, 4)``. Squared distances and cosines, no sqrt or
        arccos: this runs at every check of the approach."""
        objects = self.index.objects
        dp = self._xipos[objects] - pos0
        cos_half = np.abs(np.einsum("ij,ij->i", self._xquat[objects], quat0))  # |<q, q0>| = cos(turn / 2)
        return (np.einsum("ij,ij->i", dp, dp) > self._shift2) | (cos_half < self._cos_half_turn)

    def _slipped(self, target: int, p0: np.ndarray, R0: np.ndarray, drift: Drift) -> bool:
        """The target moved more than ``slip_tolerance`` or turned more than ``slip_rotation_tolerance`` in the TCP
        frame since (``p0``, ``R0``) (squared distance and cosine: this runs at every check of lift/hold/shake);
        ``drift`` records the pose (the firm-hold measures)."""
        p, R = self.relative(target)
        drift.update(p, R)
        dp = p - p0
        return bool(dp @ dp > self._slip2 or (float(np.vdot(R0, R)) - 1.0) / 2.0 < self._cos_slip)

    def _move(self, positions: np.ndarray, quats: np.ndarray | None, phase: str, check, observer) -> None:
        """Step once per row of ``positions (n, 3)`` (and ``quats (n, 4)``) with the mocap target there; ``check``
        every ``check_interval`` steps and at the end."""
        m, d = self.model, self.data
        step = mujoco.mj_step  # looked up per call, not at import: bench/bench_rollouts.py wraps it to time it
        mpos, mquat = self._mocap_pos, self._mocap_quat
        n, k = len(positions), self.check_interval
        for c0 in range(0, n, k):
            c1 = min(c0 + k, n)
            if quats is None:
                for i in range(c0, c1):
                    mpos[:] = positions[i]
                    step(m, d)
            else:
                for i in range(c0, c1):
                    mpos[:] = positions[i]
                    mquat[:] = quats[i]
                    step(m, d)
            self.steps += c1 - c0
            if observer is not None:
                observer(phase, self.steps)
            check(phase)

    def _wait(self, n: int, phase: str, check, observer) -> None:
        """Step ``n`` times with the targets fixed, ``check`` every ``check_interval`` steps and at the end."""
        m, d = self.model, self.data
        k = self.check_interval
        done = 0
        while done < n:
            c = min(k, n - done)
            mujoco.mj_step(m, d, nstep=c)
            done += c
            self.steps += c
            if observer is not None:
                observer(phase, self.steps)
            check(phase)

    def _close(self, observer) -> None:
        """The closing phase: command ``min_width`` and step until the jaws stop or ``close_timeout``."""
        self._ctrl[self.index.act] = self.min_width
        tol = closing_tolerance(self.params, self._dt * self.check_interval)  # width change per check interval
        last = [self.width()]

        def check_closing(phase: str) -> None:
            w = self.width()
            if abs(w - last[0]) < tol:
                raise _JawsStopped
            last[0] = w

        try:
            self._wait(self.schedule.close_max_steps, "closing", check_closing, observer)
        except _JawsStopped:
            pass

    def _closing(self, target: int, roles: np.ndarray, observer):
        """Close (:meth:`_close`) and record the end of closing: ``(closed_width, motion_closing, pose_closed,
        contacts)``."""
        close_mark = self.mark(target)
        if self.pad_patch is not None:
            self.pad_patch.closing(self.model, target)
        self._close(observer)
        if self.pad_patch is not None:
            self.pad_patch.closed(self.model, self.data, target)
        return self.width(), self.motion(target, close_mark), self.body_pose(target), self.jaw_contacts(roles)

    def _final_drift(self, target: int, drift: Drift | None) -> tuple[float, float]:
        """(max translation m, max rotation rad) of the target in the TCP frame over the disturbance, the final pose
        included; NaNs when closing was not finished (no reference)."""
        if drift is None:
            return math.nan, math.nan
        drift.update(*self.relative(target))
        return drift.translation, drift.rotation
