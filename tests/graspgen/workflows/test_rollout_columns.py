"""The one rollout column builder (graspgen.workflows.rollout_columns) behind the rollouts, evaluate and object grasp
tables: rows the pre-filter decided, contacts mapped to the object frame, and the three tables agreeing on the
columns they share."""

from __future__ import annotations

import math

import numpy as np
import pyarrow as pa
import pytest

from graspgen.errors import SettingsError
from graspgen.io.arrow import list_rows
from graspgen.quality.perturbation import rotvec_to_matrix
from graspgen.sim.protocols import OUTCOME_NAMES, RolloutResult
from graspgen.workflows import evaluate_columns, object_grasps, rollouts
from graspgen.workflows.rollout_columns import NOT_SIMULATED, ROLLOUT_TYPES, object_frame_contacts, rollout_table


def result(code: int, pose: np.ndarray, k: int, seed: int) -> RolloutResult:
    """A rollout result with ``k`` random contacts (world frame) and the target at ``pose`` when closing ended."""
    rng = np.random.default_rng(seed)
    normals = rng.normal(size=(k, 3))
    return RolloutResult(
        code=code, name=OUTCOME_NAMES[code], decided_in="end", steps=100 + seed, sim_time=0.2 + seed,
        closed_width=0.03, lift_gain=0.1, rel_translation=0.001, rel_rotation=0.01,
        contact_points=rng.normal(size=(k, 3)), contact_normals=normals / np.linalg.norm(normals, axis=1)[:, None],
        contact_forces=rng.random(k), contact_fingers=(np.arange(k) % 2).astype(np.int8),
        target_pose_closed=pose, max_rel_translation=0.002, max_rel_rotation=0.02, firm=code == 5,
        motion_closing_linear=0.004, motion_closing_angular=0.04)


def pose(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    T = np.eye(4)
    T[:3, :3] = rotvec_to_matrix(rng.normal(size=(1, 3)))[0]
    T[:3, 3] = rng.normal(size=3)
    return T


def test_prefilter_rows_get_their_code_and_the_not_simulated_values():
    results = [result(5, pose(1), 4, 1), None]
    with pytest.raises(SettingsError, match="codes"):
        rollout_table(rollouts.SCHEMA, results, {"scene_id": ["s", "s"], "grasp_id": [0, 1]})
    table = rollout_table(rollouts.SCHEMA, results, {"scene_id": ["s", "s"], "grasp_id": [0, 1]},
                          codes=np.array([-1, 2], dtype=np.int8))
    row = table.to_pylist()[1]
    assert row["outcome"] == 2 and row["outcome_name"] == "collision_with_clutter" and row["simulated"] is False
    assert {k: row[k] for k in NOT_SIMULATED} == {"decided_in": "prefilter", "steps": 0, "sim_time": 0.0, "firm": False}
    assert math.isnan(row["closed_width"]) and row["contact_points"] == [] and all(map(math.isnan,
                                                                                      row["target_pose_closed"]))
    first = table.to_pylist()[0]
    assert first["outcome"] == 5 and first["simulated"] is True and first["steps"] == 101 and first["firm"] is True
    assert np.array_equal(np.reshape(first["contact_points"], (-1, 3)), results[0].contact_points)


def test_object_frame_contacts_map_back_to_the_world():
    r = result(5, pose(2), 6, 2)
    points, normals = object_frame_contacts(r, np.full((4, 4), np.nan))  # fallback unused: closing was reached
    T = r.target_pose_closed
    assert np.allclose(points @ T[:3, :3].T + T[:3, 3], r.contact_points, atol=1e-12)
    assert np.allclose(normals @ T[:3, :3].T, r.contact_normals, atol=1e-12)
    missed = result(3, np.full((4, 4), np.nan), 0, 3)
    fallback = np.linalg.inv(pose(4))
    assert object_frame_contacts(missed, fallback)[0].shape == (0, 3)


def test_the_three_tables_agree_on_the_columns_they_share():
    results = [result(5, pose(5), 4, 5), result(4, pose(6), 2, 6), result(3, np.eye(4), 0, 7)]
    n = len(results)
    eye = np.tile(np.eye(4), (n, 1, 1))
    ev = evaluate_columns.evaluation_table(eye, np.full(n, 0.05), ["input"] * n, results, np.eye(4))
    contacts = [object_frame_contacts(r, np.eye(4)) for r in results]
    og = rollout_table(object_grasps.SCHEMA, results, {
        "object_name": ["o"] * n, "grasp_id": pa.array(range(n), pa.int32()), "candidate": ["antipodal"] * n,
        "gripper": ["panda"] * n, "protocol": ["acronym"] * n, "pose_object": pa.array([[0.0] * 16] * n,
                                                                                     pa.list_(pa.float64(), 16)),
        "width": [0.05] * n, "open_width": [0.08] * n, "epsilon": [0.1] * n, "robustness_n": pa.array([0] * n,
                                                                                                     pa.int32()),
        "robustness": [math.nan] * n}, contacts=([c[0] for c in contacts], [c[1] for c in contacts]))
    ro = rollout_table(rollouts.SCHEMA, results, {"scene_id": ["s"] * n, "grasp_id": pa.array(range(n), pa.int32())})
    tables = {"evaluate": ev, "object_grasps": og, "rollouts": ro}
    for name in ROLLOUT_TYPES:
        having = {k: t for k, t in tables.items() if name in t.column_names}
        assert all(t.schema.field(name).type == ROLLOUT_TYPES[name] for t in having.values()), name
        if name in ("contact_points", "contact_normals"):  # object frame in two, world frame in the rollouts table
            world = list_rows(ro, name, 3)
            for t in (ev, og):
                back = [p @ r.target_pose_closed[:3, :3].T + (r.target_pose_closed[:3, 3] if name == "contact_points"
                                                              else 0.0)
                        for r, p in zip(results, list_rows(t, name, 3))]
                assert all(np.allclose(b, w, atol=1e-12) for b, w in zip(back, world)), name
            continue
        values = [t.column(name).to_pylist() for t in having.values()]
        assert all(v == values[0] for v in values[1:]) or all(
            np.allclose(np.asarray(v, dtype=float), np.asarray(values[0], dtype=float), equal_nan=True)
            for v in values[1:]), name
