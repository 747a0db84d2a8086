"""Stage 2, ``scenes``: random, physically settled scenes of the objects on a support, seen by cameras.

One task per scene (``scene_000000``, ...); each may draw any object the config allows (their keys enter its key).
The scene itself is made by :func:`graspgen.workflows.scenes.make_scene` (placement, settling, rendering: see there for
the steps and the shard layout); this module only fans the work out and writes the shard.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np  # noqa: E402

import graspgen.sim.gl  # noqa: F401 - imported first: chooses MUJOCO_GL before anything imports mujoco
from graspgen.io.files import write_h5  # noqa: E402
from graspgen.io.objects import read_object
from graspgen.workflows.scenes import ScenesParams, check_rendering, make_scene
from pipeline.errors import ConfigError, StageError  # noqa: E402
from pipeline.stage import RunContext, Task, Upstream  # noqa: E402
from stages.base import GraspStage


class ScenesStage(GraspStage):
    name = "scenes"
    inputs = ("objects",)
    version = 1
    ext = "h5"

    def check(self, params: ScenesParams) -> None:
        if params.num_scenes:
            check_rendering(params)  # images asked for where OpenGL cannot render: say so before any work

    def tasks(self, params: ScenesParams, upstream: Upstream) -> list[Task]:
        library = upstream.ids("objects")
        if params.num_scenes == 0:
            return []
        if not library:
            raise StageError("scenes: no objects to build scenes from: the objects stage has no finished shard")
        unknown = sorted((set(params.objects) | set(params.weights)) - set(library))
        if unknown:
            raise ConfigError(
                f"scenes.objects: no object named {unknown[0]!r} in the library; available: {', '.join(library)}"
            )
        pool = sorted(set(params.objects)) if params.objects else library
        usable = [n for n in pool if params.weights.get(n, 1.0) > 0]
        if params.choice == "random" and not params.replace and params.count_range[1] > len(usable):
            raise ConfigError(
                f"scenes.objects_per_scene: up to {params.count_range[1]} objects per scene, but only {len(usable)} "
                "objects can be drawn (set replace: true, or lower it)"
            )
        # Every object a scene may draw enters its key (the draw happens in `run`, from the task's rng).
        return [Task(id=f"scene_{i:06d}", needs={"objects": pool}) for i in range(params.num_scenes)]

    def run(
        self,
        task: Task,
        params: ScenesParams,
        upstream: Upstream,
        rng: np.random.Generator,
        out: Path,
        ctx: RunContext,
    ) -> dict[str, Any]:
        scene = make_scene(
            task.id,
            params,
            upstream.ids("objects"),
            lambda name: read_object(upstream.path("objects", name)),
            lambda name: upstream.key("objects", name),
            rng,
        )
        write_h5(out, scene.tree)
        return scene.meta
