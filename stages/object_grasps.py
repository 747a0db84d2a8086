"""Stage ``object_grasps``: an object-centric grasp set per object, ACRONYM / GraspGen style.

One task per object (input ``objects``); the work is :func:`graspgen.workflows.object_grasps.label_object_grasps` (see
there for the candidates, the protocol and the table's columns): grasps over the whole sphere around the object
alone in free space, rolled out until ``target_positives`` successes and ``target_negatives`` failures are kept or
``max_candidates`` were tried. One Parquet shard per object; an object that falls short of a target is named in the
task's warnings.

``object_grasps.backend: warp`` rolls each batch of candidates out at once on MuJoCo Warp; ``backend`` and ``warp``
are out of the key while the backend is ``mujoco`` (so adding them kept every key); with ``warp`` they join it with
the installed ``mujoco-warp`` and ``warp-lang`` versions (:class:`ObjectGraspsTaskParams`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from graspgen.grippers import gripper_files
from graspgen.io.files import write_parquet
from graspgen.io.objects import read_object
from graspgen.sim.simulator import backend_key
from graspgen.sim.warp_backend import require_warp
from graspgen.workflows.object_grasps import label_object_grasps
from graspgen.workflows.object_grasps_settings import ObjectGraspsParams
from pipeline.config import FLATTEN
from pipeline.keys import KEY_OMIT_DEFAULT
from pipeline.stage import RunContext, Task, Upstream
from stages.base import GraspStage


@dataclasses.dataclass(frozen=True)
class ObjectGraspsTaskParams:
    """The stage's params: the ``object_grasps`` section (its keys at the top level, as before) and, with the ``warp``
    backend, the warp packages' versions."""

    object_grasps: ObjectGraspsParams = dataclasses.field(default_factory=ObjectGraspsParams,
                                                          metadata={FLATTEN: True})
    """The ``object_grasps`` section (``warp`` reset to its default when the backend is ``mujoco``: unused there)."""
    warp_packages: dict[str, str] | None = dataclasses.field(default=None, metadata={KEY_OMIT_DEFAULT: True})
    """``{"mujoco-warp": version, "warp-lang": version}`` with the ``warp`` backend, else None (out of the key)."""


class ObjectGraspsStage(GraspStage):
    name = "object_grasps"
    inputs = ("objects",)
    version = 1
    ext = "parquet"

    def params(self, config: Any) -> ObjectGraspsTaskParams:
        section: ObjectGraspsParams = config.object_grasps.library_params()
        warp, packages = backend_key(section.backend, section.warp)
        return ObjectGraspsTaskParams(dataclasses.replace(section, warp=warp), packages)

    def check(self, params: ObjectGraspsTaskParams) -> None:
        """The ``warp`` backend needs its extra installed."""
        require_warp("object_grasps.backend", params.object_grasps.backend, params.warp_packages)

    def tasks(self, params: ObjectGraspsTaskParams, upstream: Upstream) -> list[Task]:
        gripper = gripper_files(params.object_grasps.gripper)  # a gripper file's bytes (and its meshes') enter the keys
        return [Task(id=name, needs={"objects": [name]}, inputs=gripper) for name in upstream.ids("objects")]

    def run(
        self,
        task: Task,
        params: ObjectGraspsTaskParams,
        upstream: Upstream,
        rng: np.random.Generator,
        out: Path,
        ctx: RunContext,
    ) -> dict[str, Any]:
        record = read_object(upstream.path("objects", task.id))
        table, meta = label_object_grasps(record, params.object_grasps, rng)
        write_parquet(out, table)
        warning = shortfall(task.id, meta)
        return {**meta, "warnings": [warning]} if warning else meta


def shortfall(name: str, meta: dict[str, Any]) -> str | None:
    """The warning for an object whose targets were not reached (None when they were), from the meta of
    :func:`graspgen.workflows.object_grasps.label_object_grasps`."""
    if meta["reached"]:
        return None
    if meta.get("selection") == "natural":
        free = meta["positives"] + meta["negatives"] - meta.get("collision_negatives", 0)
        counts = f"object {name!r}: {free} of {meta['target_grasps']} collision-free grasps"
    else:
        counts = (f"object {name!r}: {meta['positives']} of {meta['target_positives']} positives, "
                  f"{meta['negatives']} of {meta['target_negatives']} negatives")
    if meta["stopped"] == "no_candidates":
        return (f"{counts} after {meta['tried']} candidates: the sampler found no more antipodal pairs the gripper "
                "opens around (object_grasps.sampler, object_grasps.gripper)")
    return f"{counts} after {meta['tried']} candidates (object_grasps.max_candidates)"
