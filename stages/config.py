"""The project's config schema: the run settings plus one section per stage."""

from __future__ import annotations

import dataclasses

from pipeline.config import RunConfig
from stages.objects import ObjectsParams


@dataclasses.dataclass(frozen=True)
class Config:
    """A whole config file. Each section's keys are documented in its dataclass (``gen config show``)."""

    run: RunConfig = dataclasses.field(default_factory=RunConfig)
    """Where and how to run (output folder, workers, backend). Never enters a content key."""
    objects: ObjectsParams = dataclasses.field(default_factory=ObjectsParams)
    """Stage 1: mesh preparation."""
