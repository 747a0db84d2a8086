"""The free-space protocols (``acronym``, ``graspgen``) on MuJoCo Warp (MJWarp): many grasps at once, one per world.

:class:`WarpLiftSimulator` takes the same compiled scene as :class:`graspgen.sim.lift.LiftSimulator` (free object,
gripper attached with :func:`graspgen.sim.grippers.attach_gripper`) and rolls out a batch of grasps in ``nworld``
parallel worlds of one MJWarp model. What is reused from the CPU backend, unchanged: the model copy with the
protocol's physics, force limit, damping and contact overrides written into it, the geom roles, the motion profiles
and step counts (all built by a :class:`LiftSimulator` it holds), the placement rule (the open hand placed and judged
on the CPU, float64, exactly as the CPU backend does: :meth:`LiftSimulator._place` and ``_contact_code``; a grasp
decided there never reaches the GPU), the end-of-closing record and the ``no_contact_established`` rule (the world's
state copied into the CPU data, ``mj_forward``, :meth:`LiftSimulator._jaw_contacts`) and the result and firm label
(:meth:`LiftSimulator._result`). What runs batched on the device: the steps, and the rules checked during a phase
(closing stop, jaws on the target, drift in the hand; :mod:`graspgen.sim.warp_rules`), with the CPU's check schedule:
every ``check_interval`` steps of each phase segment and at its end, per world.

What differs from the CPU backend, and so what the warp backend promises: MJWarp computes in float32 and its
contact order within a step is not fixed across runs, so two runs of the same grasps can differ in the last bits and,
for a grasp on the edge of a rule, in the label. The promise is the labels' rules and codes, not bit-identical
results: ``bench/bench_warp.py`` measures the run-to-run flip rate and the agreement with the CPU backend. Results say
which backend made them (``gen evaluate``'s metadata ``backend``); ``make repro`` covers the CPU backend only. The
placement decision and the end-of-closing contacts are the CPU's own code on the same state (float64), so a grasp
decided at placement is labelled identically by both backends.

The ``table`` protocol is not implemented here yet (SettingsError).
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, fields

import mujoco
import numpy as np

from graspgen.errors import MissingDependencyError, SettingsError, SimulationError
from graspgen.sim.lift import (
    _LEFT,
    _RIGHT,
    LiftParams,
    LiftSimulator,
    Outcome,
    RolloutResult,
    _pos_quat,
)
from graspgen.validation import check, check_choice, check_int, check_number

__all__ = ["BACKENDS", "WARP_PROTOCOLS", "WarpParams", "WarpLiftSimulator", "check_backend", "import_warp"]

#: Rollout backends: ``mujoco`` (the CPU, :class:`LiftSimulator`) and ``warp`` (:class:`WarpLiftSimulator`).
BACKENDS: tuple[str, ...] = ("mujoco", "warp")

#: The protocols the warp backend runs.
WARP_PROTOCOLS: tuple[str, ...] = ("acronym", "graspgen")

_INSTALL = "pip install -e '.[warp]' (mujoco-warp and warp-lang)"


def import_warp():
    """``(warp, mujoco_warp)``, imported; :class:`graspgen.errors.MissingDependencyError` when the extra is missing."""
    try:
        import warp

        if warp.config.log_level < 30:  # before mujoco_warp initialises Warp: no banner, no module load lines
            warp.config.log_level = 30  # warp.LOG_WARNING
        import mujoco_warp
    except ImportError as exc:
        raise MissingDependencyError(f"the warp backend needs mujoco-warp and warp-lang, which are not installed "
                                     f"({exc.name or exc}): {_INSTALL}") from None
    return warp, mujoco_warp


def check_backend(backend: str, protocol: str) -> str:
    """``backend`` if it is one of :data:`BACKENDS` and runs ``protocol``; SettingsError naming ``backend``."""
    check_choice("backend", backend, BACKENDS)
    check("backend", backend == "mujoco" or protocol in WARP_PROTOCOLS,
          f"be 'mujoco' for the {protocol!r} protocol (the warp backend runs {', '.join(WARP_PROTOCOLS)})", backend)
    return backend


@dataclass(frozen=True)
class WarpParams:
    """How the warp backend batches and sizes its worlds (:class:`WarpLiftSimulator`)."""

    device: str | None = None
    """Warp device, e.g. ``cpu`` or ``cuda:0``; null: Warp's default (the first GPU when there is one, else the
    CPU)."""
    nworld: int = 1024
    """Grasps rolled out at once (parallel worlds of one model; memory grows linearly with it)."""
    nconmax: int = 96
    """Contacts allocated per world (MJWarp's fixed contact buffer is ``nworld * nconmax``)."""
    njmax: int = 600
    """Constraint rows allocated per world (an elliptic pad contact takes 4-6 rows)."""

    def __post_init__(self) -> None:
        if self.device is not None:
            check("device", isinstance(self.device, str) and bool(self.device), "be a Warp device name",
                  self.device)
        for key in ("nworld", "nconmax", "njmax"):
            object.__setattr__(self, key, check_int(key, getattr(self, key), low=1))

    def to_dict(self) -> dict:
        """Plain-data view (for configs and metadata)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


class _Segment:
    """One stretch of a disturbance (a CPU ``_move`` or ``_wait`` call): ``n`` steps under phase name ``phase``;
    ``kind`` is ``pos`` (mocap at the grasp plus ``table[k]`` m along the approach axis), ``quat`` (mocap at the
    grasp turned by the quaternion ``table[k]``), ``wait`` (targets unchanged) or ``tug`` (a wait with the object
    pulled by its weight along the TCP-frame direction ``table (3,)``)."""

    def __init__(self, phase: str, n: int, kind: str, table: np.ndarray | None = None) -> None:
        self.phase, self.n, self.kind, self.table = phase, int(n), kind, table


class WarpLiftSimulator:
    """Batched free-space rollouts on MJWarp (module docstring).

    Parameters
    ----------
    model
        Compiled scene with the gripper attached, as for :class:`LiftSimulator`.
    params
        Protocol and settings; ``params.protocol`` must be one of :data:`WARP_PROTOCOLS`.
    warp
        Device, worlds per batch and buffer sizes (:class:`WarpParams`); a batch of fewer grasps still steps
        ``warp.nworld`` worlds. A step that needs more contacts than allocated raises
        :class:`graspgen.errors.SimulationError` naming ``nconmax``.
    qpos, prefix
        As for :class:`LiftSimulator`.

    Raises
    ------
    graspgen.errors.MissingDependencyError
        mujoco-warp / warp-lang not installed.
    graspgen.errors.SettingsError
        A protocol the backend does not run.
    graspgen.errors.SimulationError
        MJWarp refuses the model (the message names the feature).
    """

    def __init__(self, model: mujoco.MjModel, params: LiftParams | None = None, warp: WarpParams | None = None, *,
                 qpos=None, prefix: str = "gripper/") -> None:
        params = LiftParams() if params is None else params
        warp = WarpParams() if warp is None else warp
        if not isinstance(warp, WarpParams):
            raise SettingsError(f"warp: expected WarpParams, got {type(warp).__name__}")
        check_backend("warp", params.protocol)
        self.warp = warp
        self.nworld, self.nconmax, self.njmax = warp.nworld, warp.nconmax, warp.njmax
        self.wp, self.mjw = import_warp()
        self.cpu = cpu = LiftSimulator(model, params, qpos=qpos, prefix=prefix)
        self.params = params
        self.device = self.wp.get_device(warp.device)
        mujoco.mj_resetData(cpu.model, cpu.data)
        with self.wp.ScopedDevice(self.device):
            try:
                with warnings.catch_warnings():
                    # The grippers' frictionless geoms (friction 0 by design) draw a "may cause NaN" warning per
                    # geom; a state that does go non-finite raises SimulationError (warp_batch.BatchRun._read).
                    warnings.filterwarnings("ignore", message=".*MJ_MINMU.*", category=UserWarning)
                    self._m = self.mjw.put_model(cpu.model)
            except (NotImplementedError, ValueError) as exc:
                raise SimulationError(f"MuJoCo Warp cannot run this model: {exc}") from None
            self._d = self.mjw.put_data(cpu.model, cpu.data, nworld=self.nworld, nconmax=self.nconmax,
                                        njmax=self.njmax)
            self._gravity = self.wp.zeros(self.nworld, dtype=self.wp.vec3)
            self._m.opt.gravity = self._gravity  # one gravity per world (MJWarp broadcasts a leading '*' axis)
        self._naconmax = int(self._d.contact.geom.shape[0])
        self._segments = self._disturbance()
        self.timings = {"placement_s": 0.0, "batches_s": 0.0, "closing_record_s": 0.0}
        """Wall seconds (benchmarks): the placements on the CPU, the batches (all of them), and within those the
        end-of-closing records on the CPU, summed over :meth:`rollouts` calls."""
        self._graph = None
        self.graph_error: str | None = None
        """Why stepping on a GPU runs without a CUDA graph (its capture failed), or None."""

    def _step(self) -> None:
        """One ``mjw.step`` of every world; on a GPU replayed from a CUDA graph captured on the first call (one
        launch instead of hundreds; the inputs are written in place, so the graph stays valid), plain launches if
        the capture fails (:attr:`graph_error`)."""
        wp, mjw = self.wp, self.mjw
        with wp.ScopedDevice(self.device):
            if self.device.is_cuda and self._graph is None and self.graph_error is None:
                mjw.step(self._m, self._d)  # loads the kernels outside the capture
                try:
                    with wp.ScopedCapture() as capture:
                        mjw.step(self._m, self._d)
                    self._graph = capture.graph
                except Exception as exc:  # noqa: BLE001 -- any capture failure: fall back to plain launches
                    self.graph_error = f"{type(exc).__name__}: {exc}"
                return
            if self._graph is not None:
                wp.capture_launch(self._graph)
            else:
                mjw.step(self._m, self._d)

    # -- the protocol's disturbance as segments (the CPU backend's _acronym_shake / _graspgen_tugs) -------------

    def _disturbance(self) -> list[_Segment]:
        cpu, p = self.cpu, self.params
        if p.protocol == "acronym":
            return [_Segment("shaking", len(cpu._shake_z), "pos", cpu._shake_z),
                    _Segment("shaking", len(cpu._shake_qx), "quat", cpu._shake_qx),
                    _Segment("holding", cpu._settle_steps, "wait")]
        return [_Segment("shaking", cpu._tug_steps, "tug", d) for d in cpu._tug_dirs]

    def _start_gravity(self, R: np.ndarray) -> np.ndarray:
        """Gravity (3,) of a world once its closing ended (:meth:`LiftSimulator._acronym_shake`; ``graspgen``:
        off)."""
        cpu = self.cpu
        if self.params.protocol == "acronym":
            if self.params.acronym.gravity == "world":
                return cpu._gravity.copy()
            if self.params.acronym.gravity == "approach":
                return math.sqrt(float(cpu._gravity @ cpu._gravity)) * R[:, 2]
        return np.zeros(3)

    # -- public -------------------------------------------------------------------------------------------------

    def rollouts(self, T_tcp_world, target_body: str) -> list[RolloutResult]:
        """Roll out grasps and label them, ``nworld`` at a time; one result per grasp, in input order.

        Parameters
        ----------
        T_tcp_world
            ``(n, 4, 4)`` world poses of the TCP frame at the grasps (z approach, x closing). The free-space
            protocols open the jaws to their ``open_width`` whatever the grasp's width, so no width is taken.
        target_body
            Name of the object body, e.g. ``"obj/0_box"``.

        Returns
        -------
        list of RolloutResult
            As :meth:`LiftSimulator.rollout` returns, per grasp.
        """
        T = np.asarray(T_tcp_world, dtype=float)
        if T.ndim != 3 or T.shape[1:] != (4, 4):
            raise SettingsError(f"T_tcp_world: expected (n, 4, 4) poses, got shape {T.shape}")
        target, roles, _ = self.cpu._target_roles(target_body)
        results: list[RolloutResult | None] = [None] * len(T)
        pending: list[tuple[int, dict]] = []
        t0 = time.perf_counter()
        for i, pose in enumerate(T):
            placed = self._place(pose, target, roles)
            if isinstance(placed, RolloutResult):
                results[i] = placed
            else:
                pending.append((i, placed))
        self.timings["placement_s"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        for b0 in range(0, len(pending), self.nworld):
            batch = pending[b0:b0 + self.nworld]
            for (i, _), result in zip(batch, self._run_batch([s for _, s in batch], target, roles)):
                results[i] = result
        self.timings["batches_s"] += time.perf_counter() - t0
        return results  # type: ignore[return-value]

    # -- placement, on the CPU (LiftSimulator's own code) -------------------------------------------------------

    def _place(self, pose: np.ndarray, target: int, roles: np.ndarray) -> dict | RolloutResult:
        cpu = self.cpu
        pos, quat = _pos_quat("T_tcp_world", pose)
        cpu.steps = 0
        cpu._gravity_view[:] = 0.0
        try:
            cpu._place(pos, quat, cpu._open_width)
            code = cpu._contact_code(roles, target, cpu._no_allowance)
        finally:
            cpu._gravity_view[:] = cpu._gravity
        if code is not None:
            return self._unfinished(Outcome(code), "placement")
        d = cpu.data
        return {"pos": pos, "quat": quat, "R": pose[:3, :3].copy(), "qpos": d.qpos.copy(), "ctrl": d.ctrl.copy(),
                "mark": cpu._mark(target)}

    def _unfinished(self, code: Outcome, phase: str, contacts=None, closing=None) -> RolloutResult:
        """A result decided before the disturbance started (placement or closing), as the CPU backend builds it."""
        nan = math.nan
        empty = (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int8))
        closed_width, motion, pose = closing if closing is not None else (nan, (nan, nan), np.full((4, 4), nan))
        return self.cpu._result(code, phase, closed_width, nan, (nan, nan), empty if contacts is None else contacts,
                                motion, (nan, nan), pose, (nan, nan))

    # -- one batch on the device ----------------------------------------------------------------------------------

    def _upload(self, name: str, values: np.ndarray, target=None) -> None:
        arr = getattr(self._d, name) if target is None else target
        arr.assign(values.astype(np.float32))

    def _run_batch(self, states: list[dict], target: int, roles: np.ndarray) -> list[RolloutResult]:
        from graspgen.sim.warp_batch import BatchRun

        return BatchRun(self, states, target, roles).run()

    def _closing_record(self, world: int, state: dict, target: int, roles: np.ndarray, arrays: dict):
        """Load world ``world``'s state into the CPU data and read the end of closing with the CPU backend's code:
        ``(closed_width, motion_closing, pose_closed, contacts)``."""
        t0 = time.perf_counter()
        cpu = self.cpu
        d = cpu.data
        d.qpos[:] = arrays["qpos"][world]
        d.qvel[:] = arrays["qvel"][world]
        d.ctrl[:] = state["ctrl"]
        d.mocap_pos[cpu._mocap] = state["pos"]
        d.mocap_quat[cpu._mocap] = state["quat"]
        d.qacc_warmstart[:] = arrays["qacc_warmstart"][world]
        d.xfrc_applied[:] = 0.0
        cpu._gravity_view[:] = 0.0
        try:
            mujoco.mj_forward(cpu.model, d)
        finally:
            cpu._gravity_view[:] = cpu._gravity
        record = cpu._width(), cpu._motion(target, state["mark"]), cpu._body_pose(target), cpu._jaw_contacts(roles)
        self.timings["closing_record_s"] += time.perf_counter() - t0
        return record


def closing_tolerance(params: LiftParams, dt: float) -> float:
    """Width change (m) per check interval below which the closing jaws count as stopped (:meth:`LiftSimulator.
    _close`)."""
    return check_number("close_speed_tol", params.close_speed_tol, low=0.0) * params.check_interval * dt


def both_jaws(contacts) -> bool:
    """The CPU backend's closing rule: both jaws touch the target (``contacts`` from ``_jaw_contacts``)."""
    return bool(np.any(contacts[3] == _LEFT) and np.any(contacts[3] == _RIGHT))

