"""One batch-first interface to the rollout backends, and the one place that chooses a backend.

A :class:`Simulator` rolls out grasps in one compiled scene (the gripper attached as for
:class:`graspgen.sim.lift.LiftSimulator`): :meth:`Simulator.rollouts` takes ``n`` TCP poses, ``n`` widths and the
target body and returns ``n`` :class:`~graspgen.sim.protocols.RolloutResult` in input order, whatever the backend.
The backends (:data:`SIMULATORS`, by name):

- ``mujoco``: :class:`CpuSimulator`, a loop over :meth:`LiftSimulator.rollout` on the CPU (bit-identical across runs
  and processes; the reference);
- ``warp``: :class:`WarpSimulator`, :class:`graspgen.sim.warp_backend.WarpLiftSimulator` on MuJoCo Warp
  (``warp.nworld`` grasps at once; float32, so labels on the edge of a rule may differ, module docstring there).

:func:`make_simulator` builds one by name; callers never branch on the backend. Adding a backend is a subclass of
:class:`Simulator` and one entry in :data:`SIMULATORS`.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from types import MappingProxyType
from typing import Any, ClassVar

import mujoco
import numpy as np

from graspgen.sim.lift import LiftSimulator
from graspgen.sim.lift_rules import batch_arguments
from graspgen.sim.protocols import PROTOCOLS, LiftParams, RolloutResult
from graspgen.sim.warp_backend import WARP_PROTOCOLS, WarpLiftSimulator, WarpParams, warp_versions
from graspgen.validation import check, check_choice

__all__ = ["BACKENDS", "SIMULATORS", "CpuSimulator", "Simulator", "WarpSimulator", "backend_key", "check_backend",
           "make_simulator"]


class Simulator:
    """Rollouts of grasps in one compiled scene, a batch at a time (module docstring).

    Parameters (of every backend)
    ----------
    model
        Compiled scene with the gripper attached (:func:`graspgen.sim.gripper_model.attach_gripper`).
    lift
        Protocol, thresholds and physics (:class:`~graspgen.sim.protocols.LiftParams`).
    warp
        The ``warp`` backend's settings (:class:`~graspgen.sim.warp_backend.WarpParams`); ignored by the others.
    qpos, prefix
        As for :class:`~graspgen.sim.lift.LiftSimulator`.
    """

    backend: ClassVar[str]
    """The backend's name (:data:`SIMULATORS`)."""
    protocols: ClassVar[tuple[str, ...]] = PROTOCOLS
    """The protocols the backend runs."""
    parallel_workers: ClassVar[bool] = True
    """Whether worker processes, one simulator each, speed a large batch up (the CPU); False for a backend that
    batches on its own device."""
    cpu: LiftSimulator
    """The CPU simulator of the same model (perturbed copies, recording a rollout, placement checks)."""

    def __init__(self, model: mujoco.MjModel, lift: LiftParams | None = None, warp: WarpParams | None = None, *,
                 qpos=None, prefix: str = "gripper/") -> None:
        raise NotImplementedError

    @property
    def params(self) -> LiftParams:
        """The protocol and its settings."""
        return self.cpu.params

    def iter_rollouts(self, T_world_tcp, widths, target_body: str | Sequence[str]) -> Iterator[RolloutResult]:
        """The results of :meth:`rollouts`, one at a time: a caller that stops early saves the CPU backend the rest
        (a batched backend has rolled the whole batch out already)."""
        raise NotImplementedError

    def rollouts(self, T_world_tcp, widths, target_body: str | Sequence[str]) -> list[RolloutResult]:
        """Roll out ``n`` grasps and label them.

        Parameters
        ----------
        T_world_tcp
            ``(n, 4, 4)`` world poses of the TCP frame at the grasps (z approach, x closing).
        widths
            ``(n,)`` pad separations (m) at the grasps, finite and >= 0 (the free-space protocols open to their own
            width and ignore them).
        target_body
            The object body's name, e.g. ``"obj/0_box"``, or ``n`` names, one per grasp.

        Returns
        -------
        list of RolloutResult
            ``n`` results, in input order.

        Raises
        ------
        graspgen.errors.SettingsError
            Shapes that do not match (the message names the argument).
        """
        return list(self.iter_rollouts(T_world_tcp, widths, target_body))

    def rollout(self, T_world_tcp, width: float, target_body: str) -> RolloutResult:
        """One grasp: ``T_world_tcp (4, 4)``, ``width`` (m); :meth:`rollouts` of a batch of one."""
        return self.rollouts(np.asarray(T_world_tcp, dtype=float)[None], [width], target_body)[0]

    def meta(self) -> dict[str, Any]:
        """What a results table's metadata says of the backend: nothing for the CPU (the reference)."""
        return {}

    @classmethod
    def key_settings(cls, warp: WarpParams) -> tuple[WarpParams, dict[str, str] | None]:
        """What a stage's key holds of the backend (:func:`backend_key`): the CPU uses no ``warp`` settings (their
        defaults, out of the key) and no extra packages."""
        return WarpParams(), None


def _batch(T_world_tcp, widths, target_body) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The arguments of :meth:`Simulator.rollouts` checked: ``(T (n, 4, 4), widths (n,), bodies (n,))``."""
    return batch_arguments(T_world_tcp, widths, target_body, widths_needed_by="Simulator.rollouts")


class CpuSimulator(Simulator):
    """The ``mujoco`` backend: one :class:`~graspgen.sim.lift.LiftSimulator`, one grasp after another."""

    backend = "mujoco"

    def __init__(self, model: mujoco.MjModel, lift: LiftParams | None = None, warp: WarpParams | None = None, *,
                 qpos=None, prefix: str = "gripper/") -> None:
        self.cpu = LiftSimulator(model, lift, qpos=qpos, prefix=prefix)

    def iter_rollouts(self, T_world_tcp, widths, target_body: str | Sequence[str]) -> Iterator[RolloutResult]:
        T, widths, bodies = _batch(T_world_tcp, widths, target_body)
        return (self.cpu.rollout(T[i], float(widths[i]), bodies[i]) for i in range(len(T)))

    def rollout(self, T_world_tcp, width: float, target_body: str) -> RolloutResult:
        return self.cpu.rollout(T_world_tcp, width, target_body)


class WarpSimulator(Simulator):
    """The ``warp`` backend: :class:`~graspgen.sim.warp_backend.WarpLiftSimulator`, ``warp.nworld`` grasps at once."""

    backend = "warp"
    protocols = WARP_PROTOCOLS
    parallel_workers = False

    def __init__(self, model: mujoco.MjModel, lift: LiftParams | None = None, warp: WarpParams | None = None, *,
                 qpos=None, prefix: str = "gripper/") -> None:
        self.device = WarpLiftSimulator(model, lift, warp, qpos=qpos, prefix=prefix)
        """The batched simulator."""
        self.cpu = self.device.cpu
        self.device_rollouts = 0
        """Grasps rolled out on the device so far."""

    def iter_rollouts(self, T_world_tcp, widths, target_body: str | Sequence[str]) -> Iterator[RolloutResult]:
        return iter(self.rollouts(T_world_tcp, widths, target_body))

    def rollouts(self, T_world_tcp, widths, target_body: str | Sequence[str]) -> list[RolloutResult]:
        T, widths, bodies = _batch(T_world_tcp, widths, target_body)
        self.device_rollouts += len(T)
        return self.device.rollouts(T, bodies, widths)

    def meta(self) -> dict[str, Any]:
        """``backend`` (``warp``), ``warp`` (its settings) and ``device_rollouts`` (grasps rolled out on it)."""
        return {"backend": self.backend, "warp": self.device.warp.to_dict(), "device_rollouts": self.device_rollouts}

    @classmethod
    def key_settings(cls, warp: WarpParams) -> tuple[WarpParams, dict[str, str] | None]:
        """``warp`` and the installed ``mujoco-warp`` / ``warp-lang`` versions (the code fingerprint does not see
        them: :func:`graspgen.sim.warp_backend.import_warp`)."""
        return warp, warp_versions()


#: The backends by name; :func:`make_simulator` builds one.
SIMULATORS: MappingProxyType[str, type[Simulator]] = MappingProxyType({"mujoco": CpuSimulator, "warp": WarpSimulator})

#: The backends' names: ``mujoco`` (the CPU) and ``warp`` (MuJoCo Warp).
BACKENDS: tuple[str, ...] = tuple(SIMULATORS)


def check_backend(backend: str, protocol: str) -> str:
    """``backend`` if it is one of :data:`BACKENDS` and runs ``protocol``; SettingsError naming ``backend`` and the
    valid choices."""
    check_choice("backend", backend, BACKENDS)
    runs = SIMULATORS[backend].protocols
    check("backend", protocol in runs, f"run the {protocol!r} protocol (the {backend} backend runs {', '.join(runs)})",
          backend)
    return backend


def make_simulator(model: mujoco.MjModel, lift: LiftParams | None = None, backend: str = "mujoco",
                   warp: WarpParams | None = None, *, qpos=None, prefix: str = "gripper/") -> Simulator:
    """The ``backend``'s :class:`Simulator` of ``model`` (parameters: :class:`Simulator`); SettingsError for an
    unknown backend or one that does not run ``lift.protocol``."""
    lift = LiftParams() if lift is None else lift
    check_backend(backend, lift.protocol)
    return SIMULATORS[backend](model, lift, warp, qpos=qpos, prefix=prefix)


def backend_key(backend: str, warp: WarpParams) -> tuple[WarpParams, dict[str, str] | None]:
    """What a stage's key holds of its backend: the ``warp`` settings (their defaults when the backend does not use
    them, so they stay out of the key) and the installed warp packages' versions (None for the CPU)."""
    check_choice("backend", backend, BACKENDS)
    return SIMULATORS[backend].key_settings(warp)
