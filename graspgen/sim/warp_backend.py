"""The protocols (``acronym``, ``graspdatagen``, ``table``) on MuJoCo Warp (MJWarp): many grasps at once, one per world.

:class:`WarpLiftSimulator` takes the same compiled scene as :class:`graspgen.sim.lift.LiftSimulator` (objects, support,
gripper attached with :func:`graspgen.sim.gripper_model.attach_gripper`) and rolls out a batch of grasps in ``nworld``
parallel worlds of one MJWarp model. What is reused from the CPU backend, unchanged: the model copy with the
protocol's physics, force limit, damping and contact overrides written into it, the geom roles, the motion profiles
and step counts (all built by a :class:`LiftSimulator` it holds: :mod:`graspgen.sim.lift_state`), the placement rule
(the open hand placed and judged on the CPU, float64, exactly as the CPU backend does: :meth:`LiftSimulator.place` and
:meth:`~LiftSimulator.contact_code`; a grasp decided there never reaches the GPU), the end-of-closing record and the
``no_contact_established`` rule (the world's state copied into the CPU data, ``mj_forward``,
:meth:`LiftSimulator.jaw_contacts`, :func:`graspgen.sim.lift_rules.both_jaws`) and the result and firm label
(:func:`graspgen.sim.lift_rules.rollout_result`). What runs batched on the device: the steps, and the rules checked
during a phase (closing stop, jaws on the target, drift in the hand; ``table``: the live contacts and the objects'
motion on the approach, the slip; :mod:`graspgen.sim.warp_rules`), with the CPU's check schedule: every
``check_interval`` steps of each phase segment and at its end, per world. The worlds of a batch may grasp different
objects of the scene (one target per grasp).

What differs from the CPU backend, and so what the warp backend promises: MJWarp computes in float32 and its
contact order within a step is not fixed across runs, so two runs of the same grasps can differ in the last bits and,
for a grasp on the edge of a rule, in the label. The promise is the labels' rules and codes, not bit-identical
results: ``bench/bench_warp.py`` measures the run-to-run flip rate and the agreement with the CPU backend. Results say
which backend made them (``gen evaluate``'s metadata ``backend``; the ``rollouts`` stage's key); ``make repro`` covers
the CPU backend only. The
placement decision and the end-of-closing contacts are the CPU's own code on the same state (float64), so a grasp
decided at placement is labelled identically by both backends.

The ``table`` protocol (approach, closing, lift, hold, shake on the scene's support) adds the approach rules and the
slip and lift-gain rules: :mod:`graspgen.sim.warp_table`.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, fields
from types import MappingProxyType

import mujoco
import numpy as np

from graspgen.errors import MissingDependencyError, SettingsError, SimulationError
from graspgen.sim.lift import LiftSimulator
from graspgen.sim.lift_rules import batch_arguments
from graspgen.sim.poses_mj import pos_quat
from graspgen.sim.protocol_phases import ROLLOUT_PROTOCOLS
from graspgen.sim.protocols import LiftParams, RolloutResult
from graspgen.sim.warp_batch import BatchRun, free_placement
from graspgen.sim.warp_table import TableRun, table_placement
from graspgen.validation import check, check_instance, check_int
from shared_utils.keys import KEY_OMIT_DEFAULT  # the flag of the settings added with this backend (re-exported)

__all__ = ["KEY_OMIT_DEFAULT", "WARP_PROTOCOLS", "WARP_RUNS", "WarpLiftSimulator", "WarpParams", "WarpRun",
           "import_warp", "require_warp", "warp_versions"]


@dataclass(frozen=True)
class WarpRun:
    """How the warp backend rolls out one kind of placement (:attr:`graspgen.sim.protocol_base.RolloutProtocol.
    placement`)."""

    place: Callable[..., dict | RolloutResult]
    """``place(cpu, pose, pos, quat, width, target, roles)``: the placement on the CPU, gravity off; a result when
    it decides the grasp, else the world's start state (:func:`graspgen.sim.warp_table.table_placement`,
    :func:`graspgen.sim.warp_batch.free_placement`)."""
    batch: type[BatchRun]
    """The batch machine (:class:`graspgen.sim.warp_batch.BatchRun` or a subclass)."""
    widths: bool
    """The placement needs each grasp's width."""


#: The warp backend's rollout for each kind of placement a protocol names.
WARP_RUNS: MappingProxyType[str, WarpRun] = MappingProxyType({
    "grasp": WarpRun(free_placement, BatchRun, widths=False),
    "pregrasp": WarpRun(table_placement, TableRun, widths=True)})

#: The protocols the warp backend runs: those whose placement it knows.
WARP_PROTOCOLS: tuple[str, ...] = tuple(sorted(name for name, p in ROLLOUT_PROTOCOLS.items()
                                               if p.placement in WARP_RUNS))

_INSTALL = "pip install -e '.[warp]' (mujoco-warp and warp-lang)"


def import_warp():
    """``(warp, mujoco_warp)``, imported; :class:`graspgen.errors.MissingDependencyError` when the extra is missing.

    Imported by name (``importlib``), not by an ``import`` statement: a stage's code fingerprint
    (:mod:`pipeline.fingerprint`) adds the version of every package its modules import, and the ``rollouts``
    stage imports this module whatever its backend, so the warp packages' versions would enter the keys of the
    CPU backend's shards (and differ between machines with and without the extra). The ``rollouts`` stage puts
    them in its key itself when its backend is ``warp`` (:func:`warp_versions`)."""
    try:
        warp = importlib.import_module("warp")
        if warp.config.log_level < 30:  # before mujoco_warp initialises Warp: no banner, no module load lines
            warp.config.log_level = 30  # warp.LOG_WARNING
        mujoco_warp = importlib.import_module("mujoco_warp")
    except ImportError as exc:
        raise MissingDependencyError(f"the warp backend needs mujoco-warp and warp-lang, which are not installed "
                                     f"({exc.name or exc}): {_INSTALL}") from None
    return warp, mujoco_warp


def warp_versions() -> dict[str, str] | None:
    """``{"mujoco-warp": version, "warp-lang": version}`` of the installed extra, None when either is missing (no
    import: the distributions' metadata only)."""
    try:
        return {name: importlib.metadata.version(name) for name in ("mujoco-warp", "warp-lang")}
    except importlib.metadata.PackageNotFoundError:
        return None


def require_warp(key: str, backend: str, packages: dict[str, str] | None) -> None:
    """SettingsError naming the config ``key`` when ``backend`` is ``warp`` and its extra is not installed
    (``packages``: :func:`warp_versions`, None when missing)."""
    if backend == "warp" and packages is None:
        raise SettingsError(f"{key}: 'warp' needs mujoco-warp and warp-lang, which are not installed "
                            "(pip install -e '.[warp]'), or use 'mujoco'")


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


class WarpLiftSimulator:
    """Batched rollouts on MJWarp (module docstring).

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
        params = check_instance("params", LiftParams() if params is None else params, LiftParams)
        warp = check_instance("warp", WarpParams() if warp is None else warp, WarpParams)
        check("params.protocol", params.protocol in WARP_PROTOCOLS, f"be one of {', '.join(WARP_PROTOCOLS)} (the "
              "protocols the warp backend runs)", params.protocol)
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
                    self.device_model = self.mjw.put_model(cpu.model)
                    """The MJWarp model (one for every world)."""
            except (NotImplementedError, ValueError) as exc:
                raise SimulationError(f"MuJoCo Warp cannot run this model: {exc}") from None
            self.device_data = self.mjw.put_data(cpu.model, cpu.data, nworld=self.nworld, nconmax=self.nconmax,
                                                 njmax=self.njmax)
            """The MJWarp data of the ``nworld`` worlds."""
            self.world_gravity = self.wp.zeros(self.nworld, dtype=self.wp.vec3)
            """``(nworld,) vec3`` gravity per world, written into the model's options."""
            # one gravity per world (MJWarp broadcasts a leading '*' axis)
            self.device_model.opt.gravity = self.world_gravity
            self.world_friction = None
            """``(nworld, ngeom) vec3`` geom friction per world with the ``"patch"`` pad torsion (each world's pads
            carry their own torsional coefficient, :mod:`graspgen.sim.pad_patch`); None with ``"face"``."""
            if cpu.pad_patch is not None:
                self.world_friction = self.wp.array(np.repeat(cpu.model.geom_friction[None], self.nworld, axis=0)
                                                    .astype(np.float32), dtype=self.wp.vec3)
                self.device_model.geom_friction = self.world_friction
        self.naconmax = int(self.device_data.contact.geom.shape[0])
        """Contacts allocated for the whole batch."""
        self.protocol = cpu.protocol
        """The protocol object (:mod:`graspgen.sim.protocol_phases`)."""
        self.run = WARP_RUNS[self.protocol.placement]
        """The placement and batch machine of the protocol's placement."""
        self.segments = self.protocol.segments(params, cpu.schedule)
        """The protocol's disturbance as :class:`graspgen.sim.motion.Segment` s."""
        self.timings = {"placement_s": 0.0, "batches_s": 0.0, "closing_record_s": 0.0}
        """Wall seconds (benchmarks): the placements on the CPU, the batches (all of them), and within those the
        end-of-closing records on the CPU, summed over :meth:`rollouts` calls."""
        self._graph = None
        self.graph_error: str | None = None
        """Why stepping on a GPU runs without a CUDA graph (its capture failed), or None."""

    def step(self) -> None:
        """One ``mjw.step`` of every world; on a GPU replayed from a CUDA graph captured on the first call (one
        launch instead of hundreds; the inputs are written in place, so the graph stays valid), plain launches if
        the capture fails (:attr:`graph_error`)."""
        wp, mjw = self.wp, self.mjw
        m, d = self.device_model, self.device_data
        with wp.ScopedDevice(self.device):
            if self.device.is_cuda and self._graph is None and self.graph_error is None:
                mjw.step(m, d)  # loads the kernels outside the capture
                try:
                    with wp.ScopedCapture() as capture:
                        mjw.step(m, d)
                    self._graph = capture.graph
                except Exception as exc:  # noqa: BLE001 -- any capture failure: fall back to plain launches
                    self.graph_error = f"{type(exc).__name__}: {exc}"
                return
            if self._graph is not None:
                wp.capture_launch(self._graph)
            else:
                mjw.step(m, d)

    # -- public -------------------------------------------------------------------------------------------------

    def rollouts(self, T_world_tcp, target_body, widths=None) -> list[RolloutResult]:
        """Roll out grasps and label them, ``nworld`` at a time; one result per grasp, in input order.

        Parameters
        ----------
        T_world_tcp
            ``(n, 4, 4)`` world poses of the TCP frame at the grasps (z approach, x closing).
        target_body
            Name of the object body, e.g. ``"obj/0_box"``, or ``(n,)`` names, one per grasp (the worlds of a batch
            may grasp different objects of the scene).
        widths
            ``(n,)`` pad separations (m) of the grasps: the ``table`` protocol opens the jaws to ``width +
            width_margin`` (required there); the free-space protocols open them to their ``open_width`` and ignore
            it.

        Returns
        -------
        list of RolloutResult
            As :meth:`LiftSimulator.rollout` returns, per grasp.
        """
        needed_by = f"the {self.params.protocol} protocol" if self.run.widths else None
        T, widths, bodies = batch_arguments(T_world_tcp, widths, target_body, widths_needed_by=needed_by)
        results: list[RolloutResult | None] = [None] * len(T)
        pending: list[tuple[int, dict]] = []
        t0 = time.perf_counter()
        for i, pose in enumerate(T):
            target, roles, _ = self.cpu.target_roles(bodies[i])
            placed = self._place(pose, None if widths is None else float(widths[i]), target, roles)
            if isinstance(placed, RolloutResult):
                results[i] = placed
            else:
                pending.append((i, placed))
        self.timings["placement_s"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        run = self.run.batch
        for b0 in range(0, len(pending), self.nworld):
            batch = pending[b0:b0 + self.nworld]
            for (i, _), result in zip(batch, run(self, [s for _, s in batch]).run()):
                results[i] = result
        self.timings["batches_s"] += time.perf_counter() - t0
        return results  # type: ignore[return-value]

    # -- placement, on the CPU (LiftSimulator's own code) -------------------------------------------------------

    def _place(self, pose: np.ndarray, width: float | None, target: int, roles: np.ndarray) -> dict | RolloutResult:
        cpu = self.cpu
        pos, quat = pos_quat(pose, "T_world_tcp")
        gravity = cpu.model.opt.gravity
        gravity[:] = 0.0
        try:
            return self.run.place(cpu, pose, pos, quat, width, target, roles)
        finally:
            gravity[:] = cpu.gravity
