"""Stage 3, ``grasps``: antipodal grasp candidates for every object of every scene, collision pre-filtered.

One task per scene. For each target object: antipodal sampling on its mesh at its settled pose
(:func:`graspgen.geometry.antipodal.sample_antipodal`), at most ``max_per_object`` candidates kept (a seeded
subsample), then the static collision pre-filter with the real gripper geoms along the approach line
(:class:`graspgen.sim.prefilter.CollisionChecker`). Rejected candidates keep their reason as a label (``prefilter_code``
0 ground/support, 1 target, 2 clutter; the same codes as the rollout outcomes) and stay in the table when
``keep_rejected`` is true, so the dataset has labelled negatives.

Output per scene: one Parquet table, one row per candidate, ``grasp_id`` 0..n-1 in sampling order. Columns:

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

from graspgen.geometry.antipodal import AntipodalParams, sample_antipodal
from graspgen.io.arrow import fixed_list
from graspgen.io.objects import ObjectRecord
from graspgen.io.scenes import read_scene
from graspgen.sim.grippers import load_gripper
from graspgen.sim.prefilter import CollisionChecker, PrefilterParams
from graspgen.sim.scene_model import object_body_name
from graspgen.sim.scenes import scene_spec
from graspgen.validation import check

PREFILTER_NAMES = {-1: "free", 0: "collision_with_ground", 1: "collision_with_target", 2: "collision_with_clutter"}


@dataclasses.dataclass(frozen=True)
class GraspsParams:
    """Settings of the ``grasps`` stage (config section ``grasps``)."""

    gripper: str = "robotiq_2f85_mesh"
    """Gripper model: robotiq_2f85_mesh (the Robotiq 2F-85 from its collision meshes, knuckles and 4-bar linkage),
    robotiq_2f85 (the same hand as boxes: faster, no knuckles), panda or box_jaw, or the path of a gripper file
    (.yaml, .yml, .json; relative to the current folder; see graspgen.sim.grippers.read_gripper). The grasp table's
    gripper column holds it."""
    targets: tuple[str, ...] = ()
    """Object names to grasp; empty grasps every object of every scene."""
    max_per_object: int = 48
    """At most this many candidates per object and scene (a seeded subsample of the sampler's output)."""
    keep_rejected: bool = True
    """Keep candidates the pre-filter rejects, labelled with the reason; false drops them."""
    sampler: AntipodalParams = dataclasses.field(default_factory=AntipodalParams)
    """Antipodal sampling (surface points, friction cone rays, orientations, approach filter, width margin)."""
    prefilter: PrefilterParams = dataclasses.field(default_factory=PrefilterParams)
    """Static collision check along the approach."""

    def __post_init__(self) -> None:
        check("gripper", isinstance(self.gripper, str) and bool(self.gripper),
              "be a gripper name or the path of a gripper file", self.gripper)
        load_gripper(self.gripper)  # unknown name: lists the bundled ones; bad file: names it and what is wrong
        check("max_per_object", self.max_per_object > 0, "be > 0", self.max_per_object)
        check(
            "prefilter.width_margin",
            self.prefilter.width_margin == self.sampler.width_margin,
            f"equal sampler.width_margin ({self.sampler.width_margin}): the gripper opens once, by one margin",
            self.prefilter.width_margin,
        )


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


def sample_scene_grasps(
    scene_path: Path, load_object: Any, params: GraspsParams, rng: np.random.Generator
) -> tuple[pa.Table, dict[str, Any]]:
    """Sample and pre-filter the grasps of one scene.

    Parameters
    ----------
    scene_path : Path
        The scene shard.
    load_object : callable
        ``name -> ObjectRecord``.
    params : GraspsParams
    rng : numpy.random.Generator

    Returns
    -------
    (table with :data:`SCHEMA`, metadata with counts per prefilter code and sampler rejections)
    """
    scene = read_scene(scene_path)
    records: dict[str, ObjectRecord] = {n: load_object(n) for n in sorted(set(scene.object_names))}
    gripper = load_gripper(params.gripper)
    checker = CollisionChecker(scene_spec(scene, records, visual=False), gripper, params.prefilter)
    columns: dict[str, list[np.ndarray]] = {f: [] for f in SCHEMA.names}
    rejected: dict[str, int] = {}
    for index, name in enumerate(scene.object_names):
        if params.targets and name not in params.targets:
            continue
        record = records[name]
        mesh = trimesh.Trimesh(record.vertices, record.faces, process=False)
        cands = sample_antipodal(mesh, gripper, params.sampler, rng, object_pose=scene.poses[index])
        for field in dataclasses.fields(cands.rejected):
            rejected[field.name] = rejected.get(field.name, 0) + int(getattr(cands.rejected, field.name))
        n = len(cands.width)
        pick = np.arange(n)
        if n > params.max_per_object:
            pick = np.sort(rng.choice(n, size=params.max_per_object, replace=False))
        if len(pick) == 0:
            continue
        codes = checker.check(cands.pose_world[pick], cands.width[pick], object_body_name(index, name))
        keep = np.ones(len(pick), dtype=bool) if params.keep_rejected else codes < 0
        pick, codes = pick[keep], codes[keep]
        k = len(pick)
        columns["object_index"].append(np.full(k, index, dtype=np.int16))
        columns["object_name"].append(np.full(k, name, dtype=object))
        columns["pose_object"].append(cands.pose_object[pick].reshape(k, 16))
        columns["pose_world"].append(cands.pose_world[pick].reshape(k, 16))
        columns["width"].append(cands.width[pick])
        columns["open_width"].append(checker.opening(cands.width[pick]))
        columns["contact1"].append(cands.p1[pick])
        columns["contact2"].append(cands.p2[pick])
        columns["normal1"].append(cands.n1[pick])
        columns["normal2"].append(cands.n2[pick])
        columns["approach_angle"].append(cands.approach_angle[pick])
        columns["prefilter_code"].append(np.asarray(codes, dtype=np.int8))
    table = _table(scene.scene_id, params.gripper, columns)
    codes = table.column("prefilter_code").to_numpy()
    meta = {
        "grasps": len(table),
        "prefilter": {PREFILTER_NAMES[c]: int((codes == c).sum()) for c in sorted(PREFILTER_NAMES)},
        "sampler_rejections": rejected,
    }
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
