"""MuJoCo's simulation options under which grasps hold: :class:`PhysicsOptions` and :func:`physics_options`.

Measured: timestep 2 ms, elliptic friction cones, impratio 10, implicitfast. With MuJoCo's defaults (pyramidal
cones, impratio 1) held objects creep: a 2 kg box (friction 0.5) slides ~7 mm down between the 2F-85's pads during
a 1.5 s lift-and-hold, < 1 mm with ours.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco

from graspgen.errors import SettingsError
from graspgen.validation import check_choice, check_number, check_vector

__all__ = ["PhysicsOptions", "mujoco_version", "physics_options"]

_CONES = {"elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC, "pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL}
_INTEGRATORS = {
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
}


@dataclass(frozen=True)
class PhysicsOptions:
    """Simulation settings under which grasps hold (with MuJoCo's defaults, pyramidal cones and impratio 1, a held
    2 kg box creeps out between the pads; module docstring)."""

    timestep: float = 0.002
    """Integration step (s)."""
    cone: str = "elliptic"
    """Friction cone: ``"elliptic"`` (exact Coulomb cone) or ``"pyramidal"``."""
    impratio: float = 10.0
    """Frictional-to-normal constraint impedance ratio; > 1 makes friction stiffer (less creep/slip)."""
    integrator: str = "implicitfast"
    """``"implicitfast"`` (implicit damping: stable with the stiff jaw damping), ``"implicit"``, ``"euler"``,
    ``"rk4"``."""
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    """Gravity (m/s^2) in the world frame."""

    def __post_init__(self) -> None:
        check_number("timestep", self.timestep, low=0.0, high=0.05, low_open=True)
        check_choice("cone", self.cone, sorted(_CONES))
        check_number("impratio", self.impratio, low=1.0)
        check_choice("integrator", self.integrator, sorted(_INTEGRATORS))
        object.__setattr__(self, "gravity", check_vector("gravity", self.gravity, 3))

    def apply(self, target: mujoco.MjSpec | mujoco.MjModel):
        """Write these settings into an :class:`mujoco.MjSpec` (``spec.option``) or a compiled :class:`mujoco.MjModel`
        (``model.opt``); returns ``target``."""
        if isinstance(target, mujoco.MjSpec):
            opt = target.option
            opt.timestep = self.timestep
            opt.cone = _CONES[self.cone]
            opt.impratio = self.impratio
            opt.integrator = _INTEGRATORS[self.integrator]
            opt.gravity = list(self.gravity)
        elif isinstance(target, mujoco.MjModel):
            opt = target.opt
            opt.timestep = self.timestep
            opt.cone = int(_CONES[self.cone])
            opt.impratio = self.impratio
            opt.integrator = int(_INTEGRATORS[self.integrator])
            opt.gravity[:] = self.gravity
        else:
            raise SettingsError(f"target: must be an MjSpec or MjModel, got {type(target).__name__}")
        return target


def physics_options(target: mujoco.MjSpec | mujoco.MjModel, options: PhysicsOptions | None = None):
    """Apply ``options`` (default: :class:`PhysicsOptions()`: 2 ms, elliptic cones, impratio 10, implicitfast) to an
    MjSpec or MjModel; returns ``target``."""
    return (options or PhysicsOptions()).apply(target)


def mujoco_version() -> str:
    """The version string of the MuJoCo that simulates (``mujoco.__version__``, e.g. ``"3.3.7"``), for cache keys
    built outside :mod:`graspgen.sim` (only ``graspgen.sim`` imports MuJoCo)."""
    return str(mujoco.__version__)
