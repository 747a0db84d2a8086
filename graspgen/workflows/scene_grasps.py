"""Scene grasps: antipodal candidates on every object of a scene, sampled until enough pass the collision pre-filter.

For each target object in its settled pose (:func:`sample_scene_grasps`), candidates come ``batch_size`` at a time
from a :class:`graspgen.workflows.candidate_pool.CandidatePool`; the reach screen (:mod:`graspgen.sim.reach`) drops
those the hand's own collision geometry cannot reach (counted as ``unreachable``); the pre-filter
(:class:`graspgen.sim.prefilter.CollisionChecker`) labels the rest -1 free or 0/1/2 collision. Free candidates are
kept until ``max_per_object``, collisions up to ``collision_share`` of the object's rows
(:func:`graspgen.workflows.candidate_pool.collision_cap`); the loop stops at the target, at ``max_candidates``
(with a warning) or when the sampler finds nothing. An object wider at its narrowest than the gripper closes on
keeps no collisions. Randomness comes only from the generator passed in, per object in scene order, so the same
inputs and seed give the same table, byte for byte.

Output per scene: one Parquet table, one row per kept candidate, ``grasp_id`` 0..n-1 in trial order. Columns:

==================  ==================  ======================================================================
column              type                meaning
==================  ==================  ======================================================================
scene_id            string              the scene
grasp_id            int32               row id within the scene
object_index        int16               index of the target object in the scene
object_name         string              its name (the objects stage's task id)
gripper             string              gripper name
pose_object         float64[16]         TCP pose in the object's mesh frame, 4x4 row-major
pose_world          float64[16]         TCP pose in the world frame, 4x4 row-major
width               float64             pad separation at contact, m
open_width          float64             opening before the approach: width + margin, clipped to the range, m
contact1/contact2   float64[3]          contact points (left pad, right pad), object frame, m
normal1/normal2     float64[3]          inward surface normals at the contacts, object frame
approach_angle      float64             angle of the approach axis from straight down, rad
prefilter_code      int8                -1 free, 0 ground/support, 1 target, 2 clutter
==================  ==================  ======================================================================
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import trimesh

from graspgen.geometry.antipodal import AntipodalParams, narrowest_width
from graspgen.grippers import DEFAULT_GRIPPER, GripperSpec, load_gripper
from graspgen.io.arrow import fixed_list
from graspgen.io.objects import ObjectRecord
from graspgen.io.scenes import read_scene
from graspgen.sim.prefilter import FREE, CollisionChecker, PrefilterParams
from graspgen.sim.reach import ReachParams, clearance_boxes, reachable, surface_points
from graspgen.sim.scene_model import object_body_name, scene_spec
from graspgen.validation import check, check_bool, check_instance, check_number, check_positive_int
from graspgen.workflows.candidate_pool import CandidatePool, collision_cap

PREFILTER_NAMES = {-1: "free", 0: "collision_with_ground", 1: "collision_with_target", 2: "collision_with_clutter"}

_FIELDS = ("pose_object", "pose_world", "width", "p1", "p2", "n1", "n2", "approach_angle")
"""The candidate arrays a pool keeps (:class:`graspgen.geometry.antipodal.AntipodalCandidates`)."""


@dataclasses.dataclass(frozen=True)
class GraspsParams:
    """Settings of the ``grasps`` stage (config section ``grasps``)."""

    gripper: str = DEFAULT_GRIPPER
    """Gripper model: robotiq_2f85_mesh (the Robotiq 2F-85 from its collision meshes), robotiq_2f85 (the same hand as
    boxes: faster), panda or box_jaw, or the path of a gripper file (.yaml, .yml, .json; see
    graspgen.grippers.read_gripper). The grasp table's gripper column holds it."""
    targets: tuple[str, ...] = ()
    """Object names to grasp; empty grasps every object of every scene."""
    max_per_object: int = 48
    """Candidates that pass the pre-filter (free: the rollouts simulate them) to find per object and scene."""
    collision_share: float = 0.2
    """Largest share (in [0, 1)) of an object's rows that are pre-filter collisions: with ``k`` free candidates
    kept, up to ``floor(collision_share / (1 - collision_share) * k)`` collisions, the first ones in trial order
    (docs/operations.md, "Scene grasps"). Default 0.2: 12 free keep up to 3. A share of all the rows; the
    object-centric sets' ``object_grasps.collision_share_of_negatives`` is one of the kept negatives."""
    max_candidates: int = 2000
    """Most candidates tried per object and scene (screened or pre-filtered); the loop stops here short of
    ``max_per_object`` with a warning."""
    batch_size: int = 32
    """Candidates taken from the pool and screened at a time."""
    keep_rejected: bool = True
    """Keep collisions (up to ``collision_share``) labelled with their reason; false keeps only free candidates."""
    sampler: AntipodalParams = dataclasses.field(default_factory=AntipodalParams)
    """Antipodal sampling (surface points, friction cone rays, orientations, approach filter, width margin)."""
    reach: ReachParams = dataclasses.field(default_factory=ReachParams)
    """The screen of candidates the hand cannot reach, from the gripper's collision geometry
    (:mod:`graspgen.sim.reach`)."""
    prefilter: PrefilterParams = dataclasses.field(default_factory=PrefilterParams)
    """Static collision check along the approach."""

    def __post_init__(self) -> None:
        check("gripper", isinstance(self.gripper, str) and bool(self.gripper),
              "be a gripper name or the path of a gripper file", self.gripper)
        load_gripper(self.gripper)  # unknown name: lists the bundled ones; bad file: names it and what is wrong
        for key in ("max_per_object", "max_candidates", "batch_size"):
            check_positive_int(key, getattr(self, key))
        check_number("collision_share", self.collision_share, low=0.0, high=1.0, high_open=True)
        check_bool("keep_rejected", self.keep_rejected)
        check_instance("sampler", self.sampler, AntipodalParams)
        check_instance("reach", self.reach, ReachParams)
        check_instance("prefilter", self.prefilter, PrefilterParams)
        check(
            "prefilter.width_margin",
            self.prefilter.width_margin == self.sampler.width_margin,
            f"equal sampler.width_margin ({self.sampler.width_margin}): the gripper opens once, by one margin",
            self.prefilter.width_margin,
        )

    @property
    def max_collisions(self) -> int:
        """Collisions kept per object and scene (``collision_share``; 0 without ``keep_rejected``)."""
        if not self.keep_rejected:
            return 0
        return collision_cap(self.collision_share / (1.0 - self.collision_share), self.max_per_object)


def _list_type(n: int) -> pa.DataType:
    return pa.list_(pa.float64(), n)


SCHEMA = pa.schema(
    [
        ("scene_id", pa.string()),
        ("grasp_id", pa.int32()),
        ("object_index", pa.int16()),
        ("object_name", pa.string()),
        ("gripper", pa.string()),
        ("pose_object", _list_type(16)),
        ("pose_world", _list_type(16)),
        ("width", pa.float64()),
        ("open_width", pa.float64()),
        ("contact1", _list_type(3)),
        ("contact2", _list_type(3)),
        ("normal1", _list_type(3)),
        ("normal2", _list_type(3)),
        ("approach_angle", pa.float64()),
        ("prefilter_code", pa.int8()),
    ]
)
"""The grasp table's schema (see the module docstring)."""


def wide_warning(gripper_name: str, name: str, width: float, opening: float, gripper: GripperSpec) -> str:
    """The warning for an object wider at its narrowest than the gripper closes on, with no reachable grasp."""
    return (f"gripper {gripper_name} cannot grasp object {name!r}: it is {1000 * width:.0f} mm across at its "
            f"narrowest, the gripper closes on at most {1000 * opening:.0f} mm ({1000 * gripper.max_width:.0f} mm "
            "stroke less grasps.sampler.min_clearance), and no thin part of it (rim, handle) gave a candidate that "
            "passes the pre-filter")


def _sample_object(mesh: trimesh.Trimesh, pose: np.ndarray, body: str, checker: CollisionChecker,
                   gripper: GripperSpec, params: GraspsParams, rng: np.random.Generator,
                   max_collisions: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """One object's kept candidates (arrays by field, plus ``code``) and its counts (module docstring, 1-4)."""
    points = surface_points(mesh.vertices, mesh.faces, params.reach.num_points, rng) if params.reach.enabled else None
    boxes = clearance_boxes(gripper, params.reach.num_openings) if params.reach.enabled else None
    pool = CandidatePool(mesh, gripper, params.sampler, rng, fields=_FIELDS, object_pose=pose)
    kept: dict[str, list[np.ndarray]] = {f: [] for f in (*_FIELDS, "code")}
    tried = free = collisions = 0
    unreachable = np.zeros(2, dtype=np.int64)  # ground, target
    codes_seen = np.zeros(3, dtype=np.int64)  # pre-filter collisions by code, kept or not
    stopped = "max_candidates"
    while tried < params.max_candidates:
        batch = dict(zip(_FIELDS, pool.take(min(params.batch_size, params.max_candidates - tried))))
        n = len(batch["width"])
        if n == 0:
            stopped = "no_candidates"
            break
        ok = np.ones(n, dtype=bool)
        why = np.full(n, -1, dtype=np.int8)
        if params.reach.enabled:
            ok, why = reachable(batch["pose_object"], batch["pose_world"], batch["width"], points, boxes, gripper,
                                params.prefilter.width_margin, params.prefilter.approach_distance, params.reach)
        codes = np.full(n, -1, dtype=np.int8)
        idx = np.flatnonzero(ok)
        # Check only as many as the free target can still use (the rest of the batch stays untried).
        end, need, start = n, params.max_per_object - free, 0
        while start < len(idx):
            chunk = idx[start:start + max(need, 4)]
            start += len(chunk)
            codes[chunk] = checker.check(batch["pose_world"][chunk], batch["width"][chunk], body)
            free_here = np.cumsum(codes[chunk] == FREE)
            if free_here[-1] >= need:
                end = int(chunk[np.searchsorted(free_here, need)]) + 1
                break
            need -= int(free_here[-1])
        tried += end
        unreachable += np.bincount(why[:end][why[:end] >= 0], minlength=2)
        take = np.zeros(n, dtype=bool)
        for i in idx[idx < end]:
            if codes[i] == FREE:
                take[i] = free < params.max_per_object
                free += int(take[i])
            else:
                codes_seen[codes[i]] += 1
                take[i] = collisions < max_collisions
                collisions += int(take[i])
        for f in _FIELDS:
            kept[f].append(batch[f][take])
        kept["code"].append(codes[take])
        if free >= params.max_per_object:
            stopped = "target"
            break
    arrays = {f: np.concatenate(v) if v else np.zeros(0) for f, v in kept.items()}
    # The share holds for the rows the object ends with, also short of its target: the first collisions stay.
    allowed = min(collisions, collision_cap(params.collision_share / (1.0 - params.collision_share), free))
    if allowed < collisions and len(arrays["code"]):
        keep = (arrays["code"] < 0) | (np.cumsum(arrays["code"] >= 0) <= allowed)
        arrays = {f: v[keep] for f, v in arrays.items()}
        collisions = allowed
    counts = {
        "tried": tried,
        "unreachable": {"ground": int(unreachable[0]), "target": int(unreachable[1])},
        "prefilter": {"free": free, **{PREFILTER_NAMES[c]: int(codes_seen[c]) for c in range(3)}},
        "kept": {"free": free, "collisions": collisions},
        "stopped": stopped,
        "sampled": pool.sampled,
        "sampler_rejections": pool.rejected,
    }
    return arrays, counts


def sample_scene_grasps(
    scene_path: Path, load_object: Any, params: GraspsParams, rng: np.random.Generator
) -> tuple[pa.Table, dict[str, Any]]:
    """Sample, screen and pre-filter the grasps of one scene (the shard ``scene_path``; ``load_object`` maps a name to
    its record) until each target object has its free candidates; ``rng`` is the only source of randomness.

    Returns
    -------
    table : pyarrow.Table
        :data:`SCHEMA`, the kept candidates in trial order.
    meta : dict
        ``grasps``, ``prefilter`` (rows by code name), ``tried``, ``sampler_rejections``, ``objects`` (per target in
        scene order: index, name, tried, unreachable, prefilter, kept, ``stopped``, sampled, rejections, narrowest,
        wide) and ``warnings`` (without the scene's name, so the engine lists each once).
    """
    scene = read_scene(scene_path)
    records: dict[str, ObjectRecord] = {n: load_object(n) for n in sorted(set(scene.object_names))}
    gripper = load_gripper(params.gripper)
    checker = CollisionChecker(scene_spec(scene, records, visual=False), gripper, params.prefilter)
    opening = gripper.max_width - params.sampler.min_clearance
    columns: dict[str, list[np.ndarray]] = {f: [] for f in SCHEMA.names}
    objects, warnings, rejected = [], [], {}
    for index, name in enumerate(scene.object_names):
        if params.targets and name not in params.targets:
            continue
        record = records[name]
        mesh = trimesh.Trimesh(record.vertices, record.faces, process=False)
        narrowest = narrowest_width(record.vertices)
        wide = narrowest > opening
        cap = 0 if wide else params.max_collisions
        got, counts = _sample_object(mesh, scene.poses[index], object_body_name(index, name), checker, gripper,
                                     params, rng, cap)
        objects.append({"object_index": index, "object_name": name, **counts, "narrowest": round(narrowest, 6),
                        "wide": bool(wide)})
        for key, value in counts["sampler_rejections"].items():
            rejected[key] = rejected.get(key, 0) + value
        free = counts["kept"]["free"]
        if wide and free == 0:
            warnings.append(wide_warning(params.gripper, name, narrowest, opening, gripper))
        elif counts["stopped"] == "max_candidates":
            warnings.append(f"object {name!r}: {free} of {params.max_per_object} collision-free grasp candidates "
                            f"after {counts['tried']} tried (grasps.max_candidates)")
        k = len(got["code"])
        if k == 0:
            continue
        columns["object_index"].append(np.full(k, index, dtype=np.int16))
        columns["object_name"].append(np.full(k, name, dtype=object))
        columns["pose_object"].append(got["pose_object"].reshape(k, 16))
        columns["pose_world"].append(got["pose_world"].reshape(k, 16))
        columns["width"].append(got["width"])
        columns["open_width"].append(checker.opening(got["width"]))
        for col, f in (("contact1", "p1"), ("contact2", "p2"), ("normal1", "n1"), ("normal2", "n2"),
                       ("approach_angle", "approach_angle")):
            columns[col].append(got[f])
        columns["prefilter_code"].append(np.asarray(got["code"], dtype=np.int8))
    table = _table(scene.scene_id, params.gripper, columns)
    codes = table.column("prefilter_code").to_numpy()
    meta: dict[str, Any] = {
        "grasps": len(table),
        "prefilter": {PREFILTER_NAMES[c]: int((codes == c).sum()) for c in sorted(PREFILTER_NAMES)},
        "tried": sum(o["tried"] for o in objects),
        "sampler_rejections": rejected,
        "objects": objects,
    }
    if warnings:
        meta["warnings"] = warnings
    return table, meta


def _table(scene_id: str, gripper: str, columns: dict[str, list[np.ndarray]]) -> pa.Table:
    n = sum(len(a) for a in columns["width"])

    def cat(name: str, shape: tuple[int, ...], dtype: Any) -> np.ndarray:
        parts = columns[name]
        return np.concatenate(parts) if parts else np.zeros((0, *shape), dtype=dtype)

    arrays = {
        "scene_id": pa.array([scene_id] * n, pa.string()),
        "grasp_id": pa.array(np.arange(n, dtype=np.int32)),
        "object_index": pa.array(cat("object_index", (), np.int16)),
        "object_name": pa.array(list(cat("object_name", (), object)), pa.string()),
        "gripper": pa.array([gripper] * n, pa.string()),
        "pose_object": fixed_list(cat("pose_object", (16,), float), 16),
        "pose_world": fixed_list(cat("pose_world", (16,), float), 16),
        "width": pa.array(cat("width", (), float), pa.float64()),
        "open_width": pa.array(cat("open_width", (), float), pa.float64()),
        "contact1": fixed_list(cat("contact1", (3,), float), 3),
        "contact2": fixed_list(cat("contact2", (3,), float), 3),
        "normal1": fixed_list(cat("normal1", (3,), float), 3),
        "normal2": fixed_list(cat("normal2", (3,), float), 3),
        "approach_angle": pa.array(cat("approach_angle", (), float), pa.float64()),
        "prefilter_code": pa.array(cat("prefilter_code", (), np.int8), pa.int8()),
    }
    return pa.table(arrays, schema=SCHEMA)
