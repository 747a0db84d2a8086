"""Stage 4, ``rollouts``: every grasp of a scene tried in MuJoCo, labelled with an outcome code 0-5.

One task per scene. The scene's model (support, objects from their convex parts, the gripper floating on a mocap
weld) is compiled once per task and reused for every grasp by resetting its state (:class:`graspgen.sim.lift.
LiftSimulator`). A grasp the pre-filter rejected keeps the pre-filter's code (0, 1 or 2) as its outcome without
being simulated, unless ``simulate_rejected`` is true.

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

import pyarrow as pa

from graspgen.grippers import load_gripper
from graspgen.io.arrow import column_array
from graspgen.io.scenes import SceneRecord, read_scene
from graspgen.sim.gripper_model import attach_gripper
from graspgen.sim.lift import LiftSimulator
from graspgen.sim.protocols import LiftParams, RolloutResult
from graspgen.sim.scene_model import object_body_name, scene_spec
from graspgen.validation import check_bool, check_instance
from graspgen.workflows.rollout_columns import rollout_fields, rollout_table

__all__ = ["SCHEMA", "RolloutsParams", "results_table", "roll_out_table", "scene_simulator"]


@dataclasses.dataclass(frozen=True)
class RolloutsParams:
    """Settings of the ``rollouts`` stage (config section ``rollouts``)."""

    simulate_rejected: bool = False
    """Also simulate grasps the pre-filter rejected (their label then comes from the simulation)."""
    lift: LiftParams = dataclasses.field(default_factory=LiftParams)
    """The grasp-and-lift protocol, outcome thresholds and physics settings."""

    def __post_init__(self) -> None:
        check_bool("simulate_rejected", self.simulate_rejected)
        check_instance("lift", self.lift, LiftParams)


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
    scene_path: Path, load_object: Any, gripper: str, lift: LiftParams
) -> tuple[SceneRecord, LiftSimulator]:
    """Read a scene and compile it with the gripper attached, once, into a reusable :class:`LiftSimulator`."""
    scene = read_scene(scene_path)
    records = {n: load_object(n) for n in sorted(set(scene.object_names))}
    spec = scene_spec(scene, records, visual=False)
    attach_gripper(spec, load_gripper(gripper))
    return scene, LiftSimulator(spec.compile(), lift)


def roll_out_table(scene: SceneRecord, simulator: LiftSimulator, grasps: pa.Table, params: RolloutsParams) -> pa.Table:
    """Roll out (or take the pre-filter's label for) every grasp of a grasps table; one output row per grasp."""
    poses = column_array(grasps, "pose_world", (4, 4))
    widths = grasps.column("width").to_numpy()
    prefilter = grasps.column("prefilter_code").to_numpy()
    index = grasps.column("object_index").to_numpy()
    results: list[RolloutResult | None] = []
    for i in range(len(grasps)):
        if prefilter[i] >= 0 and not params.simulate_rejected:
            results.append(None)
            continue
        body = object_body_name(int(index[i]), scene.object_names[int(index[i])])
        results.append(simulator.rollout(poses[i], float(widths[i]), body))
    return results_table(grasps, results)


def results_table(grasps: pa.Table, results: list[RolloutResult | None]) -> pa.Table:
    """The rollouts table: a simulated result per row, or the pre-filter's code where ``results[i]`` is None."""
    others = {"scene_id": grasps.column("scene_id"), "grasp_id": grasps.column("grasp_id")}
    return rollout_table(SCHEMA, results, others, codes=grasps.column("prefilter_code").to_numpy())
