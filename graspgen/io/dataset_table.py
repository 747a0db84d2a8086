"""The merged grasp table of a published dataset (``grasps.parquet``): the join, its schema, its checks.

Each scene's per-stage tables (:data:`TABLES`: ``grasps``, ``rollouts``, ``robustness``, ``metrics``) are joined
on ``(scene_id, grasp_id)`` by :func:`join_scene`: one row per grasp of the first (defining) table, plus every
column of each other table except the join keys (a table without a row for a grasp leaves nulls there; a column
name already taken gets its stage's name as a prefix; the few renames of :data:`RENAMES` make generic names
specific). :func:`write_grasps_parquet` writes the scenes deterministically (zstd level 3, dictionary-encoded
strings, statistics on; no timestamps) with row groups that hold whole scenes. Every column carries its
description (:data:`COLUMN_DOCS`) in the Parquet field metadata; :data:`REQUIRED_SCHEMA` and :data:`LABEL_TYPES`
are the types every published table has, and :func:`check_table` checks a published table against them and its
card.

Columns of ``grasps.parquet`` (with the default table stages; every column's description, :data:`COLUMN_DOCS`,
is also stored in the Parquet field metadata under ``description``;
poses are 4x4 row-major, TCP frame: z approach, x closing):

=======================  ===============  ===========================================================================
column                   type             meaning
=======================  ===============  ===========================================================================
scene_id                 string           the scene (``scenes/<scene_id>.h5``)
grasp_id                 int32            grasp id within the scene
object_name              string           target object (``objects/<object_name>.h5``)
object_index             int16            target's index in the scene (its segmentation / point id)
gripper                  string           gripper model
pose_object              float64[16]      TCP pose in the object's mesh frame
pose_world               float64[16]      TCP pose in the world (scene) frame
width                    float64          pad separation at the sampled contacts, m
open_width               float64          opening before the approach, m
contact1, contact2       float64[3]       sampled contact points (left, right pad), object frame, m
normal1, normal2         float64[3]       inward surface normals there, object frame
approach_angle           float64          approach axis angle from straight down, rad
prefilter_code           int8             -1 free, 0 ground/support, 1 target, 2 clutter (collision pre-filter)
outcome                  int8             0 collision_with_ground, 1 collision_with_target, 2 collision_with_clutter,
                                          3 no_contact_established, 4 slipped_during_lifting, 5 success
outcome_name             string           its name
simulated ... rel_rotation                rollout details (``stages.rollouts``): simulated, decided_in, steps,
                                          sim_time s, closed_width m, lift_gain m, rel_translation m, rel_rotation rad
contact_points/_normals  list<float64>    finger-object contacts at the end of closing, world frame, k*3 values
contact_forces           list<float64>    their normal forces, N; contact_fingers list<int8>: 0 left, 1 right
target_pose_closed       float64[16]      the target's pose when closing ended (maps the contacts to its frame)
robustness_n             int32            perturbed copies rolled out (0 unless outcome is 5)
robustness_successes     int32            copies that succeeded
robustness               float64          success fraction of the copies; NaN when robustness_n = 0
robustness_lo, _hi       float64          Wilson score 95% interval of it
grip_robustness          float64          successes among the copies that reached the grip (codes 3-5); NaN if none
grip_robustness_lo, _hi  float64          Wilson score 95% interval of it
pfc                      float64          probability of force closure: copies with epsilon > delta
copy_outcomes            list<int8>       outcome (failure cause) of each copy; copy_epsilon list<float64>: epsilon
radius_x/_y/_z, _rx/...  float64          robustness radius along / about the TCP axes, m / rad (NaN when off)
epsilon                  float64          Ferrari-Canny epsilon (unit-free); 0 when not in force closure
contact_source           string           where epsilon's contacts came from: rollout, raycast or none
epsilon_contacts         int32            contact points epsilon was computed from
epsilon_friction         float64          Coulomb coefficient of epsilon's friction cones
min_closure_friction     float64          smallest tested friction with force closure; NaN when none
pfc_contact              float64          copies of the contacts under contact noise with epsilon > delta (fraction)
epsilon_robust           float64          mean epsilon over those copies (Dex-Net-style robust epsilon)
torque_scale             float64          epsilon's torque scale (object radius about its centre of mass), m
source_key               string           the key of the scene's rollouts shard (its provenance)
=======================  ===============  ===========================================================================
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from graspgen.errors import InputError
from graspgen.io.row_groups import GroupedParquetWriter, write_grasps_parquet

__all__ = [
    "COLUMN_DOCS",
    "FORMAT",
    "GroupedParquetWriter",
    "ID_COLUMNS",
    "JOIN_KEYS",
    "LABEL_TYPES",
    "META_KEY",
    "OUTCOME_NAMES",
    "RENAMES",
    "REQUIRED_SCHEMA",
    "TABLES",
    "check_table",
    "dataset_dir",
    "float_values",
    "join_scene",
    "write_grasps_parquet",
]

TABLES = ("grasps", "rollouts", "robustness", "metrics")
"""The per-scene table stages joined, in column order; the first one defines the rows."""

JOIN_KEYS = ("scene_id", "grasp_id")
ID_COLUMNS = ("scene_id", "grasp_id", "object_name", "object_index")
"""Columns that come first in the merged table."""

RENAMES: dict[str, dict[str, str]] = {
    "robustness": {"n": "robustness_n", "successes": "robustness_successes"},
    "metrics": {"friction": "epsilon_friction", "num_contacts": "epsilon_contacts"},
}
"""Per stage, columns whose names are too generic for the merged table."""

OUTCOME_NAMES = (
    "collision_with_ground",
    "collision_with_target",
    "collision_with_clutter",
    "no_contact_established",
    "slipped_during_lifting",
    "success",
)
"""Outcome name by code (the same as :data:`graspgen.sim.protocols.OUTCOME_NAMES`; kept here so reading needs no
MuJoCo)."""


COLUMN_DOCS: dict[str, str] = {
    "scene_id": "the scene (scenes/<scene_id>.h5)",
    "grasp_id": "grasp id within the scene",
    "object_name": "target object (objects/<object_name>.h5)",
    "object_index": "index of the target in the scene: its segmentation and point-cloud id",
    "gripper": "gripper model",
    "pose_object": "TCP pose in the object's mesh frame, 4x4 row-major (z approach, x closing), m",
    "pose_world": "TCP pose in the world (scene) frame, 4x4 row-major (z approach, x closing), m",
    "width": "pad separation at the sampled contacts, m",
    "open_width": "opening before the approach (width + margin, clipped to the gripper's range), m",
    "contact1": "sampled contact point of the left pad, object frame, m",
    "contact2": "sampled contact point of the right pad, object frame, m",
    "normal1": "inward surface normal at contact1, object frame",
    "normal2": "inward surface normal at contact2, object frame",
    "approach_angle": "angle of the approach axis from straight down, rad",
    "prefilter_code": "collision pre-filter: -1 free, 0 ground/support, 1 target, 2 clutter",
    "outcome": "rollout outcome: 0 collision_with_ground, 1 collision_with_target, 2 collision_with_clutter, "
    "3 no_contact_established, 4 slipped_during_lifting, 5 success",
    "outcome_name": "name of the outcome code",
    "firm": "firm-hold label: outcome 5 (still in the hand: the still-held label, exported as ACRONYM's "
    "flex/object_in_gripper) and the object's largest motion in the hand during lift, hold and shake within "
    "physics.firm_translation (5 mm) and physics.firm_rotation (5 degrees); exported as graspgen/firm_hold",
    "simulated": "false when the pre-filter decided the outcome",
    "decided_in": "rollout phase that decided the outcome (prefilter when not simulated)",
    "steps": "simulated steps",
    "sim_time": "simulated time, s",
    "closed_width": "pad separation when closing ended, m (NaN if not reached)",
    "lift_gain": "how far the object rose, m (NaN if not reached)",
    "rel_translation": "object displacement relative to the TCP after closing, m",
    "rel_rotation": "object rotation relative to the TCP after closing, rad",
    "max_rel_translation": "largest displacement of the object's centre of mass in the hand (TCP frame) from the "
    "end of closing, over every check of lift, hold and shake, m (NaN if not reached); the firm label reads it",
    "max_rel_rotation": "largest rotation of the object relative to the hand (TCP frame) over the same checks, rad",
    "contact_points": "finger-object contacts at the end of closing, world frame, k*3 values, m",
    "contact_normals": "their normals, into the object, k*3 values",
    "contact_forces": "their normal forces, k values, N",
    "contact_fingers": "their finger: 0 left, 1 right, k values",
    "target_pose_closed": "the target's pose (mesh frame to world) when closing ended, 4x4 row-major; NaN if not "
                          "reached: it takes the contact columns to the object frame",
    "robustness_n": "perturbed copies rolled out (0 unless the outcome is 5)",
    "robustness_successes": "perturbed copies that succeeded",
    "robustness": "success fraction of the perturbed copies, in [0, 1]; NaN when robustness_n = 0",
    "robustness_lo": "Wilson score 95% interval of robustness, lower end",
    "robustness_hi": "Wilson score 95% interval of robustness, upper end",
    "grip_robustness": "success fraction of the perturbed copies that reached the grip (outcome 3-5: not stopped by "
    "a collision during placement or approach), in [0, 1]; NaN when none did",
    "grip_robustness_lo": "Wilson score 95% interval of grip_robustness, lower end",
    "grip_robustness_hi": "Wilson score 95% interval of grip_robustness, upper end",
    "pfc": "probability of force closure: fraction of the copies with epsilon > delta; NaN when robustness_n = 0",
    "copy_outcomes": "outcome code of each perturbed copy (its failure cause)",
    "copy_epsilon": "epsilon of each perturbed copy",
    "radius_x": "robustness radius along the TCP x axis, m (NaN when off)",
    "radius_y": "robustness radius along the TCP y axis, m (NaN when off)",
    "radius_z": "robustness radius along the TCP z axis, m (NaN when off)",
    "radius_rx": "robustness radius about the TCP x axis, rad (NaN when off)",
    "radius_ry": "robustness radius about the TCP y axis, rad (NaN when off)",
    "radius_rz": "robustness radius about the TCP z axis, rad (NaN when off)",
    "epsilon": "Ferrari-Canny epsilon, unit-free; 0 when not in force closure",
    "contact_source": "where epsilon's contacts came from: rollout, raycast or none",
    "epsilon_contacts": "contact points epsilon was computed from",
    "epsilon_friction": "Coulomb coefficient of epsilon's friction cones",
    "min_closure_friction": "smallest tested friction coefficient with force closure; NaN when none",
    "torque_scale": "epsilon's torque scale: the object's largest vertex distance from its centre of mass, m",
    "pfc_contact": "probability of force closure under contact noise: fraction of the metrics stage's perturbed "
    "contact sets (pad shift, normal tilt, friction) with epsilon > delta; 0 when contact_source is none",
    "epsilon_robust": "robust epsilon: mean epsilon over the metrics stage's perturbed contact sets, unit-free; "
    "0 when contact_source is none",
    "source_key": "content key of the scene's rollouts shard (provenance)",
}
"""Description of each known column (stored in the Parquet field metadata and the card)."""

_F16, _F3 = pa.list_(pa.float64(), 16), pa.list_(pa.float64(), 3)
REQUIRED_SCHEMA = pa.schema(
    [
        ("scene_id", pa.string()),
        ("grasp_id", pa.int32()),
        ("object_name", pa.string()),
        ("object_index", pa.int16()),
        ("gripper", pa.string()),
        ("pose_object", _F16),
        ("pose_world", _F16),
        ("width", pa.float64()),
        ("open_width", pa.float64()),
        ("contact1", _F3),
        ("contact2", _F3),
        ("normal1", _F3),
        ("normal2", _F3),
        ("prefilter_code", pa.int8()),
        ("outcome", pa.int8()),
        ("outcome_name", pa.string()),
        ("source_key", pa.string()),
    ]
)
"""Columns every published grasps.parquet has, with their types (:func:`check_table` checks them); the label
columns of the robustness and metrics stages are checked by type when present."""

LABEL_TYPES = {
    "robustness": pa.float64(),
    "robustness_lo": pa.float64(),
    "robustness_hi": pa.float64(),
    "robustness_n": pa.int32(),
    "pfc": pa.float64(),
    "epsilon": pa.float64(),
    "min_closure_friction": pa.float64(),
    "pfc_contact": pa.float64(),
    "epsilon_robust": pa.float64(),
    "grip_robustness": pa.float64(),
    "grip_robustness_lo": pa.float64(),
    "grip_robustness_hi": pa.float64(),
    "firm": pa.bool_(),
    "max_rel_translation": pa.float64(),
    "max_rel_rotation": pa.float64(),
}
"""Types of the label columns, checked when present."""

META_KEY = b"graspgen.dataset"
"""Parquet schema metadata key: JSON with the format, the table stages and the resolved config."""

FORMAT = "graspgen-dataset/1"
"""The format of a published dataset, in the table's metadata and in its card."""


def float_values(column: pa.ChunkedArray) -> np.ndarray:
    """A numeric column as float64 with nulls as NaN."""
    return np.asarray(column.to_numpy(zero_copy_only=False), dtype=np.float64)


def _described(field: pa.Field, stage: str) -> pa.Field:
    doc = COLUMN_DOCS.get(field.name, f"column of the {stage} stage's table")
    return field.with_metadata({b"description": doc.encode(), b"stage": stage.encode()})


def join_scene(parts: Sequence[tuple[str, pa.Table]], source_key: str) -> pa.Table:
    """One scene's tables joined on ``grasp_id`` into the merged table's row layout.

    Parameters
    ----------
    parts : sequence of (stage, pyarrow.Table)
        The scene's table of each table stage, the defining one (grasps) first.
    source_key : str
        Goes into every row's ``source_key``.

    Returns
    -------
    pyarrow.Table
        One row per row of the first table, sorted by ``grasp_id``; :data:`ID_COLUMNS` first, then the other
        columns of each table in order, then ``source_key``. Each field carries its description and stage.

    Raises
    ------
    InputError
        Duplicate grasp ids, a table with a grasp the first one does not have, or another scene's rows.
    """
    stage0, base = parts[0]
    for name in JOIN_KEYS:
        if name not in base.column_names:
            raise InputError(f"{stage0}: table has no {name!r} column")
    scene_ids = set(base.column("scene_id").unique().to_pylist())
    base = base.take(pc.sort_indices(base, [("grasp_id", "ascending")]))
    gid = base.column("grasp_id").to_numpy()
    if len(np.unique(gid)) != len(gid):
        raise InputError(f"{stage0}: duplicate grasp ids in scene {sorted(scene_ids)}")
    fields: list[pa.Field] = []
    arrays: list[pa.ChunkedArray] = []
    order = [c for c in ID_COLUMNS if c in base.column_names]
    order += [c for c in base.column_names if c not in order]
    for name in order:
        fields.append(_described(base.schema.field(name), stage0))
        arrays.append(base.column(name))
    taken = set(order)
    for stage, table in parts[1:]:
        for name in JOIN_KEYS:
            if name not in table.column_names:
                raise InputError(f"{stage}: table has no {name!r} column")
        other_scenes = set(table.column("scene_id").unique().to_pylist())
        if len(table) and not other_scenes <= scene_ids:
            raise InputError(f"{stage}: rows of scene {sorted(other_scenes - scene_ids)} in scene {sorted(scene_ids)}")
        ids = table.column("grasp_id").to_numpy()
        loc = np.searchsorted(gid, ids)
        found = (loc < len(gid)) & (gid[np.minimum(loc, max(len(gid) - 1, 0))] == ids) if len(gid) else ids != ids
        if not np.all(found):
            raise InputError(f"{stage}: grasp ids {ids[~found][:5].tolist()} are not in the {stage0} table")
        if len(np.unique(ids)) != len(ids):
            raise InputError(f"{stage}: duplicate grasp ids in scene {sorted(scene_ids)}")
        take = np.full(len(gid), -1, dtype=np.int64)
        take[loc] = np.arange(len(ids))
        missing = take < 0
        indices = pa.array(take, mask=missing) if missing.any() else pa.array(take)
        for name in table.column_names:
            if name in JOIN_KEYS:
                continue
            out = RENAMES.get(stage, {}).get(name, name)
            if out in taken:
                out = f"{stage}_{name}"
            taken.add(out)
            field = table.schema.field(name).with_name(out)
            fields.append(_described(field, stage))
            arrays.append(table.column(name).take(indices))
    fields.append(_described(pa.field("source_key", pa.string()), "dataset"))
    arrays.append(pa.chunked_array([pa.array([source_key] * len(gid), pa.string())]))
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields))


def dataset_dir(path: str | Path) -> Path:
    """The published dataset folder of ``path``: ``path`` itself when it holds grasps.parquet, else path/dataset.

    Raises
    ------
    InputError
        Neither holds a grasps.parquet.
    """
    path = Path(path)
    for candidate in (path, path / "dataset"):
        if (candidate / "grasps.parquet").is_file():
            return candidate
    raise InputError(f"{path}: no published dataset here (no grasps.parquet in it or in {path / 'dataset'})")


def check_table(root: Path, card: Mapping[str, Any]) -> list[str]:
    """Problems of ``root/grasps.parquet`` against :data:`REQUIRED_SCHEMA`, :data:`LABEL_TYPES` and ``card`` (the
    parsed card.json): types, the card's schema and row count, rows sorted and unique by (scene_id, grasp_id),
    outcome codes and names that agree, labels in range, rigid poses, a file for every scene and object named. Each
    problem starts with the path of the file at fault; an empty list means none."""
    path = root / "grasps.parquet"
    where = str(path)
    try:
        pf = pq.ParquetFile(path)
        schema = pf.schema_arrow
    except Exception as exc:  # noqa: BLE001 - any failure to parse is the finding
        return [f"{where}: not a readable Parquet file ({type(exc).__name__}: {exc})"]
    problems = []
    for field in REQUIRED_SCHEMA:
        if field.name not in schema.names:
            problems.append(f"{where}: no column {field.name!r}")
        elif not schema.field(field.name).type.equals(field.type):
            problems.append(f"{where}: column {field.name!r} is {schema.field(field.name).type}, expected {field.type}")
    for name, t in LABEL_TYPES.items():
        if name in schema.names and not schema.field(name).type.equals(t):
            problems.append(f"{where}: column {name!r} is {schema.field(name).type}, expected {t}")
    if [(f["name"], f["type"]) for f in card.get("schema", [])] != [(f.name, str(f.type)) for f in schema]:
        problems.append(f"{where}: its columns differ from the schema in card.json")
    if problems:
        return problems
    if pf.metadata.num_rows != card.get("counts", {}).get("grasps"):
        problems.append(f"{where}: {pf.metadata.num_rows} rows, card.json says {card.get('counts', {}).get('grasps')}")
    cols = [c for c in ("scene_id", "grasp_id", "object_name", "outcome", "outcome_name", "pose_world",
                        "robustness", "robustness_lo", "robustness_hi", "pfc", "epsilon") if c in schema.names]
    found = _RowChecks()
    for i in range(pf.metadata.num_row_groups):  # one row group in memory at a time
        found.add(pf.read_row_group(i, columns=cols))
    problems += found.problems(where)
    for s in sorted(found.scenes):
        if not (root / "scenes" / f"{s}.h5").is_file():
            problems.append(f"{root / 'scenes' / f'{s}.h5'}: missing (grasps.parquet has grasps of {s})")
    for o in sorted(found.objects):
        if not (root / "objects" / f"{o}.h5").is_file():
            problems.append(f"{root / 'objects' / f'{o}.h5'}: missing (grasps.parquet has grasps of {o})")
    return problems


class _RowChecks:
    """The row checks of :func:`check_table`, fed one row group at a time: what was found, and the scenes and
    objects named (memory: the names, not the rows)."""

    MESSAGES = {
        "order": "rows are not sorted and unique by (scene_id, grasp_id)",
        "codes": "outcome codes outside 0-5",
        "names": "outcome_name does not match outcome",
        "robustness": "robustness outside [0, 1]",
        "robustness_lo": "robustness_lo outside [0, 1]",
        "robustness_hi": "robustness_hi outside [0, 1]",
        "pfc": "pfc outside [0, 1]",
        "interval": "robustness outside its interval [robustness_lo, robustness_hi]",
        "epsilon": "negative epsilon",
        "poses": "pose_world holds matrices that are not rigid transforms",
    }
    """Each finding's text, in the order they are reported."""

    def __init__(self) -> None:
        self.found: set[str] = set()
        self.scenes: set[str] = set()
        self.objects: set[str] = set()
        self._last: tuple[str, int] | None = None

    def add(self, t: pa.Table) -> None:
        if len(t) == 0:
            return
        sid = np.asarray(t.column("scene_id").to_pylist(), dtype=object)
        gid = t.column("grasp_id").to_numpy().astype(np.int64)
        if self._last is not None:  # the group's first row follows the last group's last one
            sid, gid = np.r_[np.asarray([self._last[0]], dtype=object), sid], np.r_[self._last[1], gid]
        later = (sid[1:] > sid[:-1]) | ((sid[1:] == sid[:-1]) & (gid[1:] > gid[:-1]))
        if not np.all(later):
            self.found.add("order")
        self._last = (str(sid[-1]), int(gid[-1]))
        self.scenes.update(t.column("scene_id").unique().to_pylist())
        self.objects.update(t.column("object_name").unique().to_pylist())
        outcome = t.column("outcome").to_numpy()
        if outcome.min() < 0 or outcome.max() >= len(OUTCOME_NAMES):
            self.found.add("codes")
        elif [OUTCOME_NAMES[o] for o in outcome.tolist()] != t.column("outcome_name").to_pylist():
            self.found.add("names")
        for name in ("robustness", "robustness_lo", "robustness_hi", "pfc"):
            if name in t.column_names:
                v = float_values(t.column(name))
                if np.any((v < 0) | (v > 1)):
                    self.found.add(name)
        if {"robustness", "robustness_lo", "robustness_hi"} <= set(t.column_names):
            r, lo, hi = (float_values(t.column(n)) for n in ("robustness", "robustness_lo", "robustness_hi"))
            ok = np.isfinite(r)
            if np.any(lo[ok] > r[ok] + 1e-12) or np.any(hi[ok] < r[ok] - 1e-12):
                self.found.add("interval")
        if "epsilon" in t.column_names and np.any(float_values(t.column("epsilon")) < 0):
            self.found.add("epsilon")
        T = np.asarray(t.column("pose_world").combine_chunks().values, dtype=np.float64).reshape(-1, 4, 4)
        R = T[:, :3, :3]
        if (
            not np.allclose(R @ R.transpose(0, 2, 1), np.eye(3), atol=1e-6)
            or not np.allclose(T[:, 3], [0, 0, 0, 1])
            or np.any(np.linalg.det(R) < 0)
        ):
            self.found.add("poses")

    def problems(self, where: str) -> list[str]:
        """The findings as problem lines (``where`` first), once each, in :data:`MESSAGES` order; outcome names
        are only compared where no code was out of range."""
        found = self.found - {"names"} if "codes" in self.found else self.found
        return [f"{where}: {text}" for key, text in self.MESSAGES.items() if key in found]
