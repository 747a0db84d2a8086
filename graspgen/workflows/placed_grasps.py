"""Scene grasps from object-centric grasp sets, as ACRONYM builds its scenes: no new rollouts, a cheap collision check.

An object-centric grasp set (the ``object_grasps`` table: one object, its TCP poses in the object record's mesh
frame, each labelled by a free-space protocol) is placed into a scene: every grasp of every object of the scene is
moved with its object (``T_world_tcp = T_world_object @ T_object_tcp``) and the gripper, opened to the opening the
object-level label used (``open_width``), is checked against the scene with the static collision pre-filter
(:class:`graspgen.sim.prefilter.CollisionChecker`, ``ignore_target=True``). Only the support/ground (code 0) and the
other objects (code 2) count: contact with the target itself is the object-level label's business (the free-space
protocol already judged it). The scene label is ACRONYM's: ``success = object_success and scene_code == -1``
(Eppner et al., ICRA 2021: scene grasps are the object's successful grasps whose gripper is collision-free in the
scene).

By default (``approach_distance`` 0) only the grasp pose is checked, as ACRONYM does: its labels come from a hand
placed at the grasp with open fingers, so a pose that is free at the grasp is as reachable as the label assumes. A
positive ``approach_distance`` also checks the line the table protocol's approach would sweep (poses every
``approach_step`` back along the TCP's -z): stricter, closer to what a real approach needs.

Optionally (``rescene_check`` > 0) a few collision-free placed grasps per scene, drawn with the task's generator,
are rolled out in the scene with the pipeline's ``table`` protocol (:class:`graspgen.sim.lift.LiftSimulator`: the
jaws open to ``width + lift.width_margin``, approach, close, lift), and the metadata says how often the scene
rollout disagrees with the object-level label, both ways: how cheap placement is paid for in label quality.

Randomness (in this order, all from the ``rng`` passed in): per scene object in scene order, when its set has more
than ``max_per_object`` rows, a subsample of that many rows (kept in row order); then the ``rescene_check`` draw
among the collision-free rows (kept in row order).

Output: one Parquet table per scene, one row per placed grasp, ``grasp_id`` 0..n-1 in scene-object then
object-set row order (:data:`SCHEMA`):

===================  ==============  ===================================================================
column               type            meaning
===================  ==============  ===================================================================
scene_id             string          the scene
grasp_id             int32           row id within the scene
object_index         int16           index of the object in the scene
object_name          string          its name (the objects stage's task id)
object_grasp_id      int32           the grasp's ``grasp_id`` in the object's set
gripper              string          gripper name or file
pose_object          float64[16]     TCP pose in the object's mesh frame, 4x4 row-major
pose_world           float64[16]     TCP pose in the world (scene) frame, 4x4 row-major
width                float64         pad separation at the contacts (object set), m
open_width           float64         jaw opening the object-level label used (and the check uses), m
object_outcome       int8            object-level outcome 0-5 (:class:`graspgen.sim.protocols.Outcome`)
object_success       bool            object-level success
scene_code           int8            -1 free, 0 support/ground, 2 clutter (the checker's codes)
success              bool            ACRONYM's scene label: ``object_success and scene_code == -1``
rescene_outcome      int8            outcome 0-5 of the scene rollout; -1 when not re-simulated
rescene_success      bool            its success; null when not re-simulated
===================  ==============  ===================================================================
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from graspgen.errors import InputError
from graspgen.grippers import load_gripper
from graspgen.io.arrow import column_array, fixed_list
from graspgen.io.objects import ObjectRecord
from graspgen.io.scenes import SceneRecord, read_scene
from graspgen.sim.gripper_model import attach_gripper
from graspgen.sim.lift import LiftSimulator
from graspgen.sim.prefilter import CLUTTER, FREE, GROUND, CollisionChecker, PrefilterParams
from graspgen.sim.protocol_phases import protocol_of
from graspgen.sim.protocols import LiftParams, Outcome
from graspgen.sim.scene_model import object_body_name, scene_spec
from graspgen.validation import check, check_instance, check_int, check_number, check_rng

__all__ = ["OBJECT_COLUMNS", "SCHEMA", "SCENE_CODE_NAMES", "PlacedGraspsParams", "place_object_grasps"]

SCENE_CODE_NAMES = {FREE: "free", GROUND: "collision_with_ground", CLUTTER: "collision_with_clutter"}
"""Name of each ``scene_code``."""

OBJECT_COLUMNS = ("grasp_id", "gripper", "pose_object", "width", "open_width", "outcome", "success")
"""Columns this module reads from an object grasp set (the ``object_grasps`` table); others are ignored."""


@dataclasses.dataclass(frozen=True)
class PlacedGraspsParams:
    """Settings of the ``placed_grasps`` stage (config section ``placed_grasps``)."""

    approach_distance: float = 0.0
    """Length (m, >= 0) of the approach line checked behind each grasp pose, along the TCP's -z. 0 (default):
    the grasp pose only, as ACRONYM builds its scenes: the object-level labels come from a hand placed at the grasp
    with open jaws, so the check asks what the label assumed. Set it to ``physics.table.approach_distance`` (0.05) to
    also demand the table protocol's approach be free (stricter)."""
    approach_step: float = 0.005
    """Spacing (m, > 0) of the poses checked along the approach line (unused when ``approach_distance`` is 0);
    an obstacle thinner than this can slip between two of them."""
    margin: float = 0.0
    """Clearance (m) the gripper must keep from the support and the other objects; 0 flags any penetration, > 0
    is conservative, < 0 tolerates that much penetration."""
    max_per_object: int = 0
    """At most this many grasps per object and scene (a seeded subsample of its set, kept in row order); 0: all."""
    rescene_check: int = 0
    """Collision-free placed grasps per scene re-simulated in the scene with ``lift`` (drawn with the task's rng);
    0: off. Measures how often placement without rollouts gets the label wrong (metadata ``rescene``)."""
    lift: LiftParams = dataclasses.field(default_factory=LiftParams)
    """The scene rollout of ``rescene_check``: the ``table`` protocol (in a config it comes from ``physics`` and
    ``placed_grasps.protocol``, as the rollouts' does, so the labels compare with the pipeline's own)."""

    def __post_init__(self) -> None:
        check_number("approach_distance", self.approach_distance, low=0.0)
        check_number("approach_step", self.approach_step, low=0.0, low_open=True)
        check_number("margin", self.margin)
        check_int("max_per_object", self.max_per_object, low=0)
        check_int("rescene_check", self.rescene_check, low=0)
        check_instance("lift", self.lift, LiftParams)
        check("lift.protocol", protocol_of(self.lift).lifts,
              "be 'table': the scene rollout approaches and lifts in the scene", self.lift.protocol)

    def prefilter(self) -> PrefilterParams:
        """The checker's settings: the approach line, ``margin``, and no width margin (the jaws open to the
        ``open_width`` of the object-level label as given)."""
        samples = 1 if self.approach_distance == 0 else 1 + math.ceil(self.approach_distance / self.approach_step)
        return PrefilterParams(approach_distance=self.approach_distance, num_approach_samples=samples,
                               margin=self.margin, width_margin=0.0)


SCHEMA = pa.schema(
    [
        ("scene_id", pa.string()),
        ("grasp_id", pa.int32()),
        ("object_index", pa.int16()),
        ("object_name", pa.string()),
        ("object_grasp_id", pa.int32()),
        ("gripper", pa.string()),
        ("pose_object", pa.list_(pa.float64(), 16)),
        ("pose_world", pa.list_(pa.float64(), 16)),
        ("width", pa.float64()),
        ("open_width", pa.float64()),
        ("object_outcome", pa.int8()),
        ("object_success", pa.bool_()),
        ("scene_code", pa.int8()),
        ("success", pa.bool_()),
        ("rescene_outcome", pa.int8()),
        ("rescene_success", pa.bool_()),
    ]
)
"""The placed grasp table's schema (see the module docstring)."""


def _object_rows(name: str, table: pa.Table) -> dict[str, np.ndarray]:
    """The columns of an object grasp set this module uses, as arrays; InputError naming the object otherwise."""
    missing = [c for c in OBJECT_COLUMNS if c not in table.column_names]
    if missing:
        raise InputError(f"object grasps of {name!r}: no column {missing[0]!r} (needs {', '.join(OBJECT_COLUMNS)})")
    n = len(table)
    try:
        pose = column_array(table, "pose_object", (4, 4)) if n else np.zeros((0, 4, 4))
    except ValueError:
        raise InputError(f"object grasps of {name!r}: 'pose_object' must hold 16 numbers per row") from None
    rows = {
        "grasp_id": table.column("grasp_id").to_numpy(zero_copy_only=False).astype(np.int32),
        "gripper": np.array(table.column("gripper").to_pylist(), dtype=object),
        "pose_object": pose,
        "width": table.column("width").to_numpy(zero_copy_only=False).astype(np.float64),
        "open_width": table.column("open_width").to_numpy(zero_copy_only=False).astype(np.float64),
        "outcome": table.column("outcome").to_numpy(zero_copy_only=False).astype(np.int8),
        "success": np.array(table.column("success").to_pylist(), dtype=bool),
    }
    if n and not np.isfinite(rows["open_width"]).all():
        raise InputError(f"object grasps of {name!r}: 'open_width' must be finite (the opening the label used)")
    if n and not np.isfinite(pose).all():
        raise InputError(f"object grasps of {name!r}: 'pose_object' must be finite")
    if any(g is None or g == "" for g in rows["gripper"]):
        raise InputError(f"object grasps of {name!r}: 'gripper' must name a gripper in every row")
    return rows


def _rate(k: int, n: int) -> float | None:
    return round(k / n, 6) if n else None


def _object_sets(names: list[str], load_object_grasps: Callable[[str], pa.Table | None]) -> dict[str, Any]:
    """Each object's grasp set as arrays (:func:`_object_rows`), None for an object without one."""
    sets: dict[str, dict[str, np.ndarray] | None] = {}
    for n in names:
        table = load_object_grasps(n)
        sets[n] = None if table is None else _object_rows(n, table)
    return sets


def _place_object(scene: SceneRecord, index: int, rows: dict[str, np.ndarray],
                  new_checker: Callable[[str], CollisionChecker], checkers: dict[str, CollisionChecker],
                  max_per_object: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """One scene object's set (a seeded subsample of ``max_per_object`` rows; 0: all) moved into the scene and
    checked with each gripper's checker (``new_checker(gripper)``, made on first use and kept in ``checkers``)."""
    name = scene.object_names[index]
    pick = np.arange(len(rows["grasp_id"]))
    if max_per_object and len(pick) > max_per_object:
        pick = np.sort(rng.choice(len(pick), size=max_per_object, replace=False))
    k = len(pick)
    T_obj = rows["pose_object"][pick]
    T_world = np.einsum("ij,njk->nik", scene.poses[index], T_obj)
    open_width = rows["open_width"][pick]
    grippers = rows["gripper"][pick]
    codes = np.full(k, FREE, dtype=np.int8)
    body = object_body_name(index, name)
    for gripper in sorted(set(grippers)):
        sel = np.flatnonzero(grippers == gripper)
        if gripper not in checkers:
            checkers[gripper] = new_checker(gripper)
        codes[sel] = checkers[gripper].check(T_world[sel], open_width[sel], body, ignore_target=True)
    return {
        "object_index": np.full(k, index, dtype=np.int16),
        "object_name": np.full(k, name, dtype=object),
        "object_grasp_id": rows["grasp_id"][pick],
        "gripper": grippers,
        "pose_object": T_obj.reshape(k, 16),
        "pose_world": T_world.reshape(k, 16),
        "width": rows["width"][pick],
        "open_width": open_width,
        "object_outcome": rows["outcome"][pick],
        "object_success": rows["success"][pick],
        "scene_code": codes,
    }


_COLUMNS = (("object_index", (), np.int16), ("object_name", (), object), ("object_grasp_id", (), np.int32),
            ("gripper", (), object), ("pose_object", (16,), np.float64), ("pose_world", (16,), np.float64),
            ("width", (), np.float64), ("open_width", (), np.float64), ("object_outcome", (), np.int8),
            ("object_success", (), bool), ("scene_code", (), np.int8))
"""The placed rows' arrays: name, trailing shape and dtype (of an empty scene)."""


def _concatenated(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The objects' placed rows in one array per column."""
    return {key: np.concatenate([p[key] for p in parts]) if parts else np.zeros((0, *shape), dtype=dtype)
            for key, shape, dtype in _COLUMNS}


def _rescene(scene: SceneRecord, records: dict[str, ObjectRecord], col: dict[str, np.ndarray], free: np.ndarray,
             params: PlacedGraspsParams, rng: np.random.Generator) -> tuple[np.ndarray, dict[str, Any]]:
    """The ``rescene_check`` rollouts: up to that many collision-free rows (drawn with ``rng``, in row order)
    rolled out in the scene; ``(outcome per row, -1 where not simulated; their agreement, :func:`_rescene_meta`)``."""
    rescene_outcome = np.full(len(free), -1, dtype=np.int8)
    candidates = np.flatnonzero(free & np.isfinite(col["width"]))
    m = min(params.rescene_check, len(candidates))
    chosen = candidates[np.sort(rng.choice(len(candidates), size=m, replace=False))] if m else candidates[:0]
    simulators: dict[str, LiftSimulator] = {}
    for i in chosen:
        gripper = str(col["gripper"][i])
        if gripper not in simulators:
            sim_spec = scene_spec(scene, records, visual=False)
            attach_gripper(sim_spec, load_gripper(gripper))
            simulators[gripper] = LiftSimulator(sim_spec.compile(), params.lift)
        index = int(col["object_index"][i])
        result = simulators[gripper].rollout(col["pose_world"][i].reshape(4, 4), float(col["width"][i]),
                                             object_body_name(index, scene.object_names[index]))
        rescene_outcome[i] = result.code
    return rescene_outcome, _rescene_meta(col["object_success"][chosen], rescene_outcome[chosen])


def _table(scene_id: str, col: dict[str, np.ndarray], success: np.ndarray, rescene_outcome: np.ndarray) -> pa.Table:
    """The :data:`SCHEMA` table of the placed rows."""
    n = len(col["scene_code"])
    simulated = rescene_outcome >= 0
    arrays = {
        "scene_id": pa.array([scene_id] * n, pa.string()),
        "grasp_id": pa.array(np.arange(n, dtype=np.int32)),
        "object_index": pa.array(col["object_index"], pa.int16()),
        "object_name": pa.array(list(col["object_name"]), pa.string()),
        "object_grasp_id": pa.array(col["object_grasp_id"], pa.int32()),
        "gripper": pa.array(list(col["gripper"]), pa.string()),
        "pose_object": fixed_list(col["pose_object"], 16),
        "pose_world": fixed_list(col["pose_world"], 16),
        "width": pa.array(col["width"], pa.float64()),
        "open_width": pa.array(col["open_width"], pa.float64()),
        "object_outcome": pa.array(col["object_outcome"], pa.int8()),
        "object_success": pa.array(col["object_success"], pa.bool_()),
        "scene_code": pa.array(col["scene_code"], pa.int8()),
        "success": pa.array(success, pa.bool_()),
        "rescene_outcome": pa.array(rescene_outcome, pa.int8()),
        "rescene_success": pa.array(rescene_outcome == int(Outcome.SUCCESS), pa.bool_(), mask=~simulated),
    }
    return pa.table(arrays, schema=SCHEMA)


def place_object_grasps(
    scene_path: str | Path,
    load_object: Callable[[str], ObjectRecord],
    load_object_grasps: Callable[[str], pa.Table | None],
    params: PlacedGraspsParams,
    rng: np.random.Generator,
) -> tuple[pa.Table, dict[str, Any]]:
    """Place the object grasp sets of a scene's objects into the scene and label them (see the module docstring).

    Parameters
    ----------
    scene_path : str or Path
        The scene shard (:func:`graspgen.io.scenes.read_scene`): object names and their ``(n, 4, 4)`` poses.
    load_object : callable
        ``name -> ObjectRecord``; called once per distinct object of the scene (every object is an obstacle).
    load_object_grasps : callable
        ``name -> pyarrow.Table`` of that object's grasp set (the ``object_grasps`` schema; the columns
        :data:`OBJECT_COLUMNS` are read), or None when the object has none: it stays an obstacle and gets no rows
        (named in the metadata's ``objects_without_grasps``). Called once per distinct object.
    params : PlacedGraspsParams
    rng : numpy.random.Generator
        The only source of randomness (the subsample and the ``rescene_check`` draw).

    Returns
    -------
    table : pyarrow.Table
        :data:`SCHEMA`, one row per placed grasp.
    meta : dict
        ``grasps``, ``success`` (scene labels), ``scene_codes`` (rows per code name), ``objects_without_grasps``,
        ``rescene`` (with ``rescene_check``: ``simulated``, ``object_success``, ``scene_success``, ``agree`` and
        ``agree_rate``; ``success_to_failure`` (object success, scene rollout not) with its rate among the simulated
        object successes, ``failure_to_success`` with its rate among the simulated object failures (None when there
        are none); ``outcomes`` of the scene rollouts by name) and timings (wall seconds, the only varying entries).

    Raises
    ------
    graspgen.errors.InputError
        An object grasp set lacks a column or holds unusable values (the message names the object).
    """
    check_instance("params", params, PlacedGraspsParams)
    rng = check_rng("rng", rng)
    t0 = time.perf_counter()
    scene = read_scene(scene_path)
    names = sorted(set(scene.object_names))
    records = {n: load_object(n) for n in names}
    sets = _object_sets(names, load_object_grasps)
    spec = scene_spec(scene, records, visual=False)
    prefilter = params.prefilter()
    checkers: dict[str, CollisionChecker] = {}
    t1 = time.perf_counter()
    def new_checker(gripper: str) -> CollisionChecker:
        return CollisionChecker(spec, load_gripper(gripper), prefilter)

    parts = [_place_object(scene, index, sets[name], new_checker, checkers, params.max_per_object, rng)
             for index, name in enumerate(scene.object_names)
             if sets[name] is not None and len(sets[name]["grasp_id"])]
    t2 = time.perf_counter()
    col = _concatenated(parts)
    free = col["scene_code"] == FREE
    success = col["object_success"] & free
    rescene_outcome, rescene_meta = np.full(len(free), -1, dtype=np.int8), None
    if params.rescene_check:
        rescene_outcome, rescene_meta = _rescene(scene, records, col, free, params, rng)
    t3 = time.perf_counter()
    table = _table(scene.scene_id, col, success, rescene_outcome)
    meta: dict[str, Any] = {
        "grasps": len(table),
        "success": int(success.sum()),
        "scene_codes": {SCENE_CODE_NAMES[c]: int((col["scene_code"] == c).sum()) for c in sorted(SCENE_CODE_NAMES)},
        "objects_without_grasps": sorted(n for n in names if sets[n] is None),
        "seconds_setup": round(t1 - t0, 4),
        "seconds_check": round(t2 - t1, 4),
    }
    if rescene_meta is not None:
        meta["rescene"] = rescene_meta
        meta["seconds_rescene"] = round(t3 - t2, 4)
    return table, meta


def _rescene_meta(object_success: np.ndarray, outcome: np.ndarray) -> dict[str, Any]:
    """Counts and rates of agreement between the object-level label and the scene rollout of the same grasps."""
    scene_success = outcome == int(Outcome.SUCCESS)
    n, n_obj = len(outcome), int(object_success.sum())
    s2f = int((object_success & ~scene_success).sum())
    f2s = int((~object_success & scene_success).sum())
    return {
        "simulated": n,
        "object_success": n_obj,
        "scene_success": int(scene_success.sum()),
        "agree": n - s2f - f2s,
        "agree_rate": _rate(n - s2f - f2s, n),
        "success_to_failure": s2f,
        "success_to_failure_rate": _rate(s2f, n_obj),
        "failure_to_success": f2s,
        "failure_to_success_rate": _rate(f2s, n - n_obj),
        "outcomes": {o.name.lower(): int((outcome == int(o)).sum()) for o in Outcome},
    }
