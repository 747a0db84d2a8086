"""Stage 4, ``rollouts``: every collision-free grasp of a scene grasped and lifted in MuJoCo (outcome codes 0-5).

One task per scene; the work is :func:`graspgen.workflows.rollouts.roll_out_table` (see there for the columns), on
the CPU (``rollouts.backend: mujoco``, the default) or on MuJoCo Warp (``warp``: the scene's grasps in parallel
worlds, :mod:`graspgen.sim.warp_backend`).

The key (:class:`RolloutsTaskParams`): the section as before while the backend is ``mujoco`` (``backend`` and ``warp``
carry the key-omit-default flag, so adding them kept every key, this stage's and the ``dataset`` stage's, which
hashes every section); with ``warp``, the backend, its settings and the installed ``mujoco-warp`` and ``warp-lang``
versions join it.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from graspgen.io.files import write_parquet
from graspgen.io.objects import read_object
from graspgen.sim.protocols import OUTCOME_NAMES
from graspgen.sim.simulator import backend_key
from graspgen.sim.warp_backend import require_warp
from graspgen.workflows.rollouts import RolloutsParams, roll_out_table, scene_simulator, warp_batch
from pipeline.config import FLATTEN
from pipeline.keys import KEY_OMIT_DEFAULT
from pipeline.stage import RunContext, Task, Upstream
from stages.base import GraspStage


@dataclasses.dataclass(frozen=True)
class RolloutsTaskParams:
    """The stage's params: the ``rollouts`` section (its keys at the top level, as before; ``backend`` and ``warp``
    out of the key while ``backend`` is ``mujoco``) and, with ``warp``, the warp packages' versions."""

    rollouts: RolloutsParams = dataclasses.field(default_factory=RolloutsParams, metadata={FLATTEN: True})
    """The ``rollouts`` section (``warp`` reset to its default when the backend is ``mujoco``: unused there)."""
    warp_packages: dict[str, str] | None = dataclasses.field(default=None, metadata={KEY_OMIT_DEFAULT: True})
    """``{"mujoco-warp": version, "warp-lang": version}`` with the ``warp`` backend (the code fingerprint does not
    see them: :func:`graspgen.sim.warp_backend.import_warp`), else None (out of the key)."""


class RolloutsStage(GraspStage):
    name = "rollouts"
    inputs = ("grasps", "scenes", "objects")
    version = 1
    ext = "parquet"

    def params(self, config: Any) -> RolloutsTaskParams:
        section: RolloutsParams = config.rollouts.library_params()
        warp, packages = backend_key(section.backend, section.warp)
        return RolloutsTaskParams(dataclasses.replace(section, warp=warp), packages)

    def check(self, params: RolloutsTaskParams) -> None:
        """The ``warp`` backend needs its extra installed."""
        require_warp("rollouts.backend", params.rollouts.backend, params.warp_packages)

    def tasks(self, params: RolloutsTaskParams, upstream: Upstream) -> list[Task]:
        library = upstream.ids("objects")
        # The pre-filter's free grasps are the ones simulated (the rest cost nothing unless simulate_rejected).
        return [
            Task(
                id=sid,
                needs={"grasps": [sid], "scenes": [sid], "objects": library},
                cost=float(upstream.meta("grasps", sid).get("prefilter", {}).get("free", 0)),
            )
            for sid in upstream.ids("grasps")
        ]

    def run(
        self,
        task: Task,
        params: RolloutsTaskParams,
        upstream: Upstream,
        rng: np.random.Generator,
        out: Path,
        ctx: RunContext,
    ) -> dict[str, Any]:
        settings = params.rollouts
        grasps = pq.read_table(upstream.path("grasps", task.id))
        scene, simulator = scene_simulator(
            upstream.path("scenes", task.id),
            lambda name: read_object(upstream.path("objects", name)),
            grasps.column("gripper")[0].as_py() if len(grasps) else "robotiq_2f85",
            settings.lift,
            settings.backend,
            warp_batch(grasps, settings),
        )
        table = roll_out_table(scene, simulator, grasps, settings)
        write_parquet(out, table)
        outcomes = table.column("outcome").to_numpy()
        return {
            "grasps": len(table),
            "simulated": int(np.sum(table.column("simulated").to_numpy(zero_copy_only=False))),
            "outcomes": {name: int((outcomes == c).sum()) for c, name in enumerate(OUTCOME_NAMES)},
            "steps": int(np.sum(table.column("steps").to_numpy())),
            **simulator.meta(),
        }
