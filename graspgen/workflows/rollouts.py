"""Stage 4, ``rollouts``: every grasp of a scene tried in MuJoCo, labelled with an outcome code 0-5.

One task per scene. The scene's model (support, objects from their convex parts, the gripper floating on a mocap
weld) is compiled once per task and reused for every grasp by resetting its state (:class:`graspgen.sim.lift.
LiftSimulator`). A grasp the pre-filter rejected keeps the pre-filter's code (0, 1 or 2) as its outcome without
being simulated, unless ``simulate_rejected`` is true.

Backends (``backend``): ``mujoco``, the CPU, one grasp after another (bit-identical across runs); ``warp``, the same
compiled model on MuJoCo Warp (:class:`graspgen.sim.warp_backend.WarpLiftSimulator`, the ``warp`` extra): the
scene's grasps (on any of its objects) rolled out together, ``warp.nworld`` worlds per batch, with the same rules
and codes; float32 and a contact order that is not fixed, so a grasp on the edge of a rule can be labelled
differently than on the CPU or in another run (``bench/bench_warp.py`` measures how often).

Outcome codes: 0 collision_with_ground, 1 collision_with_target, 2 collision_with_clutter,
3 no_contact_established, 4 slipped_during_lifting, 5 success (rules: :class:`graspgen.sim.lift.LiftSimulator`).

Output per scene: one Parquet table, one row per grasp of the grasps table, joined on ``(scene_id, grasp_id)``
(:data:`SCHEMA`; the rollout columns are those of :mod:`graspgen.workflows.rollout_columns`, with
:data:`~graspgen.workflows.rollout_columns.NOT_SIMULATED` where the pre-filter decided):

===================  ==================  ===================================================================
column               type                meaning
===================  ==================  ===================================================================
scene_id, grasp_id   string, int32       the grasp
outcome              int8                0-5
outcome_name         string              its name
simulated            bool                false when the pre-filter decided
decided_in           string              protocol phase that decided it (``prefilter`` when not simulated)
steps                int32               simulated steps
sim_time             float64             simulated seconds
closed_width         float64             pad separation when closing ended, m (NaN if not reached)
lift_gain            float64             how far the object rose, m (NaN if not reached)
rel_translation      float64             object displacement relative to the TCP after closing, m
rel_rotation         float64             object rotation relative to the TCP after closing, rad
firm                 bool                firm hold: outcome 5 and the object's motion in the hand within
                                         ``lift.firm_translation`` / ``firm_rotation`` (false when not simulated)
max_rel_translation  float64             largest displacement of the object in the TCP frame from the end of
                                         closing over lift, hold and shake, m (NaN if not reached)
max_rel_rotation     float64             largest rotation relative to the TCP over the same span, rad
contact_points       list<float64>       finger-object contacts at the end of closing, world frame, k*3 values
contact_normals      list<float64>       their normals, pointing into the object, k*3 values
contact_forces       list<float64>       their normal forces, N, k values
contact_fingers      list<int8>          0 left pad/finger, 1 right, k values
target_pose_closed   float64[16]         the target's pose (mesh frame to world) when closing ended, 4x4
                                         row-major; NaN if closing was not reached. The contacts above are in
                                         the world at that instant: this pose takes them to the object frame
===================  ==================  ===================================================================
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from graspgen.grippers import load_gripper
from graspgen.io.arrow import column_array
from graspgen.io.scenes import SceneRecord, read_scene
from graspgen.sim.gripper_model import attach_gripper
from graspgen.sim.protocols import LiftParams, RolloutResult
from graspgen.sim.scene_model import object_body_name, scene_spec
from graspgen.sim.simulator import Simulator, check_backend, make_simulator
from graspgen.sim.warp_backend import KEY_OMIT_DEFAULT, WarpParams
from graspgen.validation import check_bool, check_instance
from graspgen.workflows.rollout_columns import rollout_fields, rollout_table

__all__ = ["SCHEMA", "RolloutsParams", "results_table", "roll_out_table", "scene_simulator", "warp_batch"]


@dataclasses.dataclass(frozen=True)
class RolloutsParams:
    """Settings of the ``rollouts`` stage (config section ``rollouts``)."""

    simulate_rejected: bool = False
    """Also simulate grasps the pre-filter rejected (their label then comes from the simulation)."""
    lift: LiftParams = dataclasses.field(default_factory=LiftParams)
    """The grasp-and-lift protocol, outcome thresholds and physics settings."""
    backend: str = dataclasses.field(default="mujoco", metadata={KEY_OMIT_DEFAULT: True})
    """Where the rollouts run: ``mujoco`` (the CPU, one grasp after another) or ``warp`` (MuJoCo Warp, a scene's
    grasps in parallel worlds on a GPU or Warp's CPU device; needs ``pip install -e '.[warp]'``)."""
    warp: WarpParams = dataclasses.field(default_factory=WarpParams, metadata={KEY_OMIT_DEFAULT: True})
    """Device, worlds per batch and buffer sizes of the ``warp`` backend (:class:`graspgen.sim.warp_backend.
    WarpParams`; unused by ``mujoco``)."""

    def __post_init__(self) -> None:
        check_bool("simulate_rejected", self.simulate_rejected)
        check_instance("lift", self.lift, LiftParams)
        check_backend(self.backend, self.lift.protocol)
        check_instance("warp", self.warp, WarpParams)


SCHEMA = pa.schema(
    [
        ("scene_id", pa.string()),
        ("grasp_id", pa.int32()),
        *rollout_fields("outcome", "outcome_name", "simulated", "decided_in", "steps", "sim_time", "closed_width",
                        "lift_gain", "rel_translation", "rel_rotation", "firm", "max_rel_translation",
                        "max_rel_rotation", "contact_points", "contact_normals", "contact_forces", "contact_fingers",
                        "target_pose_closed"),
    ]
)
"""The rollouts table's schema (see the module docstring)."""


def scene_simulator(
    scene_path: Path, load_object: Any, gripper: str, lift: LiftParams, backend: str = "mujoco",
    warp: WarpParams | None = None
) -> tuple[SceneRecord, Simulator]:
    """Read a scene and compile it with the gripper attached, once, into a reusable
    :class:`~graspgen.sim.simulator.Simulator` of ``backend`` (:func:`graspgen.sim.simulator.make_simulator`;
    ``warp``: the warp backend's settings)."""
    scene = read_scene(scene_path)
    records = {n: load_object(n) for n in sorted(set(scene.object_names))}
    spec = scene_spec(scene, records, visual=False)
    attach_gripper(spec, load_gripper(gripper))
    return scene, make_simulator(spec.compile(), lift, backend, warp)


def roll_out_table(scene: SceneRecord, simulator: Simulator, grasps: pa.Table, params: RolloutsParams) -> pa.Table:
    """Roll out (or take the pre-filter's label for) every grasp of a grasps table; one output row per grasp.

    The scene's grasps are rolled out as one batch, whatever object each grasps
    (:meth:`graspgen.sim.simulator.Simulator.rollouts`); results are in row order."""
    poses = column_array(grasps, "pose_world", (4, 4))
    widths = grasps.column("width").to_numpy()
    prefilter = grasps.column("prefilter_code").to_numpy()
    index = grasps.column("object_index").to_numpy()
    results: list[RolloutResult | None] = [None] * len(grasps)
    todo = [i for i in range(len(grasps)) if prefilter[i] < 0 or params.simulate_rejected]
    bodies = [object_body_name(int(index[i]), scene.object_names[int(index[i])]) for i in todo]
    for i, result in zip(todo, simulator.rollouts(poses[todo], widths[todo], bodies)):
        results[i] = result
    return results_table(grasps, results)


def warp_batch(grasps: pa.Table, params: RolloutsParams) -> WarpParams:
    """The warp backend's settings for a scene's grasps table: ``params.warp`` with ``nworld`` no larger than the
    number of grasps simulated (a batch steps all its worlds, used or not; the CPU backend ignores them). Each
    world is independent, so the batch size does not change a grasp's rules."""
    todo = int(np.sum((grasps.column("prefilter_code").to_numpy() < 0) | params.simulate_rejected))
    return dataclasses.replace(params.warp, nworld=max(1, min(params.warp.nworld, todo)))


def results_table(grasps: pa.Table, results: list[RolloutResult | None]) -> pa.Table:
    """The rollouts table: a simulated result per row, or the pre-filter's code where ``results[i]`` is None."""
    others = {"scene_id": grasps.column("scene_id"), "grasp_id": grasps.column("grasp_id")}
    return rollout_table(SCHEMA, results, others, codes=grasps.column("prefilter_code").to_numpy())
