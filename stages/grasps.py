"""Stage 3, ``grasps``: antipodal grasp candidates on every object of a scene, checked by the collision pre-filter.

One task per scene; the work is :func:`graspgen.workflows.scene_grasps.sample_scene_grasps` (see there for how
candidates are sampled until each object has ``max_per_object`` that pass the pre-filter, and for the table's columns).
This module fans it out and writes the Parquet shard; the shard's metadata holds the per-object counts (tried, screened
out, pre-filter codes, kept), which the dataset card sums per object. Warnings: an object wider than the stroke
with no reachable grasp, an object short of its target after ``max_candidates``, and (:func:`ungraspable`) a target
object for which the sampler found no contact pair at all.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from graspgen.geometry.antipodal import narrowest_width
from graspgen.grippers import gripper_files
from graspgen.io.files import write_parquet
from graspgen.io.objects import read_object
from graspgen.workflows.scene_grasps import GraspsParams, sample_scene_grasps
from pipeline.errors import ConfigError
from pipeline.stage import RunContext, Task, Upstream
from stages.base import GraspStage


class GraspsStage(GraspStage):
    name = "grasps"
    inputs = ("scenes", "objects")
    version = 1
    ext = "parquet"

    def params(self, config: Any) -> GraspsParams:
        """The library's settings of the ``grasps`` section (its derived keys filled in)."""
        return config.grasps.library_params()

    def tasks(self, params: GraspsParams, upstream: Upstream) -> list[Task]:
        library = upstream.ids("objects")
        unknown = sorted(set(params.targets) - set(library))
        if unknown:
            raise ConfigError(f"grasps.targets: no object named {unknown[0]!r}; available: {', '.join(library)}")
        gripper = gripper_files(params.gripper)  # a gripper file's bytes (and its meshes') enter the keys
        return [Task(id=sid, needs={"scenes": [sid], "objects": library}, inputs=gripper)
                for sid in upstream.ids("scenes")]

    def run(
        self,
        task: Task,
        params: GraspsParams,
        upstream: Upstream,
        rng: np.random.Generator,
        out: Path,
        ctx: RunContext,
    ) -> dict[str, Any]:
        def load(name: str):
            return read_object(upstream.path("objects", name))

        table, meta = sample_scene_grasps(upstream.path("scenes", task.id), load, params, rng)
        write_parquet(out, table)
        warnings = [*meta.pop("warnings", []), *ungraspable(meta["objects"], params)]
        return {**meta, "warnings": warnings} if warnings else meta


__all__ = ["GraspsStage", "narrowest_width", "ungraspable"]


def ungraspable(objects: list[Mapping[str, Any]], params: GraspsParams) -> list[str]:
    """Warnings naming each target object (an entry of the shard's ``objects`` metadata) for which the sampler
    found no contact pair at all, though it is not wider than the gripper at its narrowest (that case has its own
    warning). The texts do not name the scene, so the engine lists a warning once with the scenes that give it."""
    return [
        f"gripper {params.gripper} found no grasp on object {o['object_name']!r}: no contact pair passed the "
        "sampler's checks (friction cone, width, approach direction: grasps.sampler)"
        for o in objects if o["stopped"] == "no_candidates" and o["sampled"] == 0 and not o["wide"]
    ]
