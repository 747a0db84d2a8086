"""The config sections of the stages that roll grasps out: each is the library's settings class with its rollout
settings (``lift``, a :class:`graspgen.sim.protocols.LiftParams`) derived from the ``physics`` section, the protocol
it names and its own overrides, instead of holding a copy of them; and the ``grasps`` section, whose opening and
approach are the rollouts'. :class:`stages.config.Config` fills the derived keys in.

A stage hashes its section's :meth:`~_LibrarySection.library_params`, the library's class without the fields added
here (``protocol``, ``overrides``: their effect is in ``lift``), so it hashes what it hashed when its section held
the copy (the ``dataset`` task, which hashes the whole config, leaves them out while they hold their defaults).
``config_derived`` and ``config_moved`` are the engine's :data:`pipeline.config.DERIVED` and
:data:`pipeline.config.MOVED`."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from functools import partial
from types import MappingProxyType
from typing import Any, ClassVar

from graspgen.sim.protocol_phases import ROLLOUT_PROTOCOLS
from graspgen.sim.protocols import check_protocol
from graspgen.workflows.object_grasps_settings import ObjectGraspsParams
from graspgen.workflows.placed_grasps import PlacedGraspsParams
from graspgen.workflows.rollouts import RolloutsParams
from graspgen.workflows.scene_grasps import GraspsParams
from pipeline.keys import KEY_OMIT_DEFAULT
from stages.physics import moved_lift_key

__all__ = ["GraspsSection", "ObjectGraspsSection", "PlacedGraspsSection", "RolloutsSection"]

LIFTING = tuple(name for name, p in ROLLOUT_PROTOCOLS.items() if p.lifts)
"""The protocols that approach and lift in a scene (``placed_grasps.protocol``)."""


class _LibrarySection:
    """What a config section made from a library settings class adds to it."""

    def library_params(self) -> Any:
        """The library's settings instance (the first dataclass this section derives from), the keys this section
        adds left out: what the stage passes on and hashes."""
        base = next(k for k in type(self).__mro__[1:] if dataclasses.is_dataclass(k))
        return base(**{f.name: getattr(self, f.name) for f in dataclasses.fields(base)})


def _overrides() -> Any:
    return dataclasses.field(default_factory=lambda: MappingProxyType({}), metadata={KEY_OMIT_DEFAULT: True})


def _derived_lift(section: str) -> Mapping[str, str]:
    """The :data:`pipeline.config.DERIVED` of a section whose ``lift`` is derived."""
    return {"lift": f"physics, {section}.protocol and {section}.overrides"}


@dataclasses.dataclass(frozen=True)
class RolloutsSection(RolloutsParams, _LibrarySection):
    """Config section ``rollouts``: :class:`graspgen.workflows.rollouts.RolloutsParams`, its ``lift`` from
    ``physics``."""

    config_derived: ClassVar[Mapping[str, str]] = _derived_lift("rollouts")
    config_moved: ClassVar[Callable[[str], str | None]] = staticmethod(partial(moved_lift_key, "rollouts"))
    protocol: str = dataclasses.field(default="table", metadata={KEY_OMIT_DEFAULT: True})
    """Protocol of the scene rollouts: a settings block of ``physics`` (``table``, ``acronym``, ``graspdatagen``)."""
    overrides: dict[str, Any] = _overrides()
    """Keys of ``physics`` or of its block of ``protocol`` set for this stage alone (``{grip_force: 40}``)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        check_protocol("protocol", self.protocol)


@dataclasses.dataclass(frozen=True)
class ObjectGraspsSection(ObjectGraspsParams, _LibrarySection):
    """Config section ``object_grasps``: :class:`graspgen.workflows.object_grasps_settings.ObjectGraspsParams`,
    its ``lift`` from ``physics`` and ``protocol``."""

    config_derived: ClassVar[Mapping[str, str]] = _derived_lift("object_grasps")
    config_moved: ClassVar[Callable[[str], str | None]] = staticmethod(partial(moved_lift_key, "object_grasps"))
    overrides: dict[str, Any] = _overrides()
    """Keys of ``physics`` or of its block of ``protocol`` set for this stage alone (``{grip_force: 40}``)."""


@dataclasses.dataclass(frozen=True)
class PlacedGraspsSection(PlacedGraspsParams, _LibrarySection):
    """Config section ``placed_grasps``: :class:`graspgen.workflows.placed_grasps.PlacedGraspsParams`, the ``lift``
    of its ``rescene_check`` from ``physics``."""

    config_derived: ClassVar[Mapping[str, str]] = _derived_lift("placed_grasps")
    config_moved: ClassVar[Callable[[str], str | None]] = staticmethod(partial(moved_lift_key, "placed_grasps"))
    protocol: str = dataclasses.field(default="table", metadata={KEY_OMIT_DEFAULT: True})
    """Protocol of the ``rescene_check`` rollouts: one that lifts in the scene (``table``)."""
    overrides: dict[str, Any] = _overrides()
    """Keys of ``physics`` or of its block of ``protocol`` set for this stage alone (``{grip_force: 40}``)."""

    def __post_init__(self) -> None:
        check_protocol("protocol", self.protocol, LIFTING, " (the scene rollout approaches and lifts)")
        super().__post_init__()


@dataclasses.dataclass(frozen=True)
class GraspsSection(GraspsParams, _LibrarySection):
    """Config section ``grasps``: :class:`graspgen.workflows.scene_grasps.GraspsParams`; the jaws open and approach
    as the rollouts' protocol says, so those keys are derived from it."""

    config_derived: ClassVar[Mapping[str, str]] = {
        "sampler.width_margin": "the rollouts' width_margin (physics.table.width_margin, rollouts.overrides)",
        "prefilter.width_margin": "the rollouts' width_margin (physics.table.width_margin, rollouts.overrides)",
        "prefilter.approach_distance": "the rollouts' approach_distance (physics.table.approach_distance, "
                                       "rollouts.overrides)",
    }
