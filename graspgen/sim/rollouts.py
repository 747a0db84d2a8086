"""Stage 4, ``rollouts``: every grasp of a scene tried in MuJoCo, labelled with an outcome code 0-5.

One task per scene. The scene's model (support, objects from their convex parts, the gripper floating on a mocap
weld) is compiled once per task and reused for every grasp by resetting its state (:class:`graspgen.sim.lift.
LiftSimulator`). A grasp the pre-filter rejected keeps the pre-filter's code (0, 1 or 2) as its outcome without
being simulated, unless ``simulate_rejected`` is true.

Outcome codes: 0 collision_with_ground, 1 collision_with_target, 2 collision_with_clutter,
3 no_contact_established, 4 slipped_during_lifting, 5 success (rules: :class:`graspgen.sim.lift.LiftSimulator`).

Output per scene: one Parquet table, one row per grasp of the grasps table, joined on ``(scene_id, grasp_id)``:

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

from graspgen.io.arrow import column_array, fixed_list, variable_list
from graspgen.io.scenes import SceneRecord, read_scene
from graspgen.sim.grippers import attach_gripper, load_gripper
from graspgen.sim.lift import OUTCOME_NAMES, LiftParams, LiftSimulator, RolloutResult
from graspgen.sim.scene_model import object_body_name
from graspgen.sim.scenes import scene_spec


@dataclasses.dataclass(frozen=True)
class RolloutsParams:
    """Settings of the ``rollouts`` stage (config section ``rollouts``)."""

    simulate_rejected: bool = False
    """Also simulate grasps the pre-filter rejected (their label then comes from the simulation)."""
    lift: LiftParams = dataclasses.field(default_factory=LiftParams)
    """The grasp-and-lift protocol, outcome thresholds and physics settings."""


SCHEMA = pa.schema(
    [
        ("scene_id", pa.string()),
        ("grasp_id", pa.int32()),
        ("outcome", pa.int8()),
        ("outcome_name", pa.string()),
        ("simulated", pa.bool_()),
        ("decided_in", pa.string()),
        ("steps", pa.int32()),
        ("sim_time", pa.float64()),
        ("closed_width", pa.float64()),
        ("lift_gain", pa.float64()),
        ("rel_translation", pa.float64()),
        ("rel_rotation", pa.float64()),
        ("firm", pa.bool_()),
        ("max_rel_translation", pa.float64()),
        ("max_rel_rotation", pa.float64()),
        ("contact_points", pa.list_(pa.float64())),
        ("contact_normals", pa.list_(pa.float64())),
        ("contact_forces", pa.list_(pa.float64())),
        ("contact_fingers", pa.list_(pa.int8())),
        ("target_pose_closed", pa.list_(pa.float64(), 16)),
    ]
)


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
    prefilter = grasps.column("prefilter_code").to_numpy()
    outcome = np.array([r.code if r is not None else prefilter[i] for i, r in enumerate(results)], dtype=np.int8)

    def num(attr: str, missing: float = float("nan")) -> np.ndarray:
        return np.array([getattr(r, attr) if r is not None else missing for r in results], dtype=np.float64)

    def listed(attr: str, value_type: pa.DataType) -> pa.ListArray:
        return variable_list([getattr(r, attr) if r is not None else () for r in results], value_type)

    arrays = {
        "scene_id": grasps.column("scene_id"),
        "grasp_id": grasps.column("grasp_id"),
        "outcome": pa.array(outcome, pa.int8()),
        "outcome_name": pa.array([OUTCOME_NAMES[int(c)] for c in outcome], pa.string()),
        "simulated": pa.array([r is not None for r in results], pa.bool_()),
        "decided_in": pa.array([r.decided_in if r is not None else "prefilter" for r in results], pa.string()),
        "steps": pa.array([r.steps if r is not None else 0 for r in results], pa.int32()),
        "sim_time": pa.array(num("sim_time", 0.0)),
        "closed_width": pa.array(num("closed_width")),
        "lift_gain": pa.array(num("lift_gain")),
        "rel_translation": pa.array(num("rel_translation")),
        "rel_rotation": pa.array(num("rel_rotation")),
        "firm": pa.array([r is not None and r.firm for r in results], pa.bool_()),
        "max_rel_translation": pa.array(num("max_rel_translation")),
        "max_rel_rotation": pa.array(num("max_rel_rotation")),
        "contact_points": listed("contact_points", pa.float64()),
        "contact_normals": listed("contact_normals", pa.float64()),
        "contact_forces": listed("contact_forces", pa.float64()),
        "contact_fingers": listed("contact_fingers", pa.int8()),
        "target_pose_closed": fixed_list(
            np.array([np.ravel(r.target_pose_closed) if r is not None else np.full(16, np.nan) for r in results],
                     dtype=np.float64).reshape(-1, 16),
            16,
        ),
    }
    return pa.table(arrays, schema=SCHEMA)
