"""Stage 7, ``dataset``: the per-scene shards merged into the published dataset (DESIGN section 8), with its card.

One task (``dataset``) reads the per-scene tables of the table stages (:data:`TABLES`: ``grasps``, ``rollouts``,
``robustness``, ``metrics``) and joins them on ``(scene_id, grasp_id)``: one row per grasp of the grasps table,
plus every column of each other table except the join keys (a table without a row for a grasp leaves nulls there;
a column name already taken gets its stage's name as a prefix; the few renames of :data:`RENAMES` make generic names
specific). Scenes are sorted by id and grasps by id within a scene. Only scenes with a shard in every table stage
are included; the others are named in the manifest meta and in the card. The task's shard is that table, written
deterministically (zstd level 3, dictionary-encoded strings, statistics on; no timestamps) with row groups that hold
whole scenes, packed up to ``dataset.row_group_rows`` rows: a reader that wants one scene touches one row group, and
the footer stays small with many scenes (one row group per scene would make it grow with every scene).

After the task has been committed, :meth:`DatasetStage.publish` lays out ``OUT/dataset/`` (each file atomically;
shards as hard links, copies where links are not possible)::

    grasps.parquet          the merged table: the dataset shard
    scenes/<scene_id>.h5    the scene shards of the included scenes (cameras, images, clouds, object poses)
    objects/<name>.h5       the object shards of the library (mesh, convex parts, mass properties, stable poses)
    acronym/<name>.h5       each object's grasps as an ACRONYM grasp file (:mod:`graspgen.io.acronym`), rows in
                            grasps.parquet order; its mesh as acronym/meshes/<name>.obj (the file's object/file)
    plots/*.png             outcomes, robustness, epsilon, correlation (label columns present), examples
    config.yaml             the resolved config: every stage section with its comments (``run`` left out)
    card.json, card.md      counts per object and outcome, label summaries, histograms and correlations, the
                            schema, every file's sha256, every stage's shard keys, package versions, the config

next to the engine's own files (``manifest.jsonl`` and the shard folders ``<xx>/``), which are not part of the
dataset. :func:`report` renders the card and plots again from a published folder (``gen report``);
:func:`validate` checks a folder against the manifests, the card's hashes and the schema (``gen validate``).
Read a dataset with :func:`graspgen.io.reader.open_dataset`.

Columns of ``grasps.parquet`` (with the default table stages; every column's description is also stored in the
Parquet field metadata under ``description``; poses are 4x4 row-major, TCP frame: z approach, x closing):

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
robustness_n             int32            perturbed copies rolled out (0 unless outcome is 5)
robustness_successes     int32            copies that succeeded
robustness               float64          success fraction of the copies; NaN when robustness_n = 0
robustness_lo, _hi       float64          Wilson score 95% interval of it
pfc                      float64          probability of force closure: copies with epsilon > delta
copy_outcomes            list<int8>       outcome of each copy; copy_epsilon list<float64>: epsilon of each copy
radius_x/_y/_z, _rx/...  float64          robustness radius along / about the TCP axes, m / rad (NaN when off)
epsilon                  float64          Ferrari-Canny epsilon (unit-free); 0 when not in force closure
contact_source           string           where epsilon's contacts came from: rollout, raycast or none
epsilon_contacts         int32            contact points epsilon was computed from
epsilon_friction         float64          Coulomb coefficient of epsilon's friction cones
min_closure_friction     float64          smallest tested friction with force closure; NaN when none
torque_scale             float64          epsilon's torque scale (object radius about its centre of mass), m
source_key               string           the key of the scene's rollouts shard (its provenance)
=======================  ===============  ===========================================================================
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import math
import os
import platform
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import yaml

from graspgen.errors import InputError
from graspgen.validation import check
from pipeline.config import to_dict, to_yaml
from pipeline.errors import StageError
from pipeline.keys import canonical_json, sha256_file
from pipeline.stage import RunContext, Task, Upstream
from pipeline.store import MANIFEST, Manifest, atomic_path, write_text_atomic
from stages.base import GraspStage

__all__ = [
    "CARD_VERSION",
    "COLUMN_DOCS",
    "DatasetParams",
    "DatasetStage",
    "DatasetTaskParams",
    "LABEL_COLUMNS",
    "REQUIRED_SCHEMA",
    "TABLES",
    "dataset_dir",
    "join_scene",
    "label_summary",
    "render_card",
    "report",
    "validate",
    "write_grasps_parquet",
]

TABLES = ("grasps", "rollouts", "robustness", "metrics")
"""The per-scene table stages joined, in column order; the first one defines the rows."""

JOIN_KEYS = ("scene_id", "grasp_id")
ID_COLUMNS = ("scene_id", "grasp_id", "object_name", "object_index")
"""Columns that come first in the merged table."""

PROVENANCE_STAGE = "rollouts"
"""``source_key`` holds the key of this stage's shard of the scene (the last table stage when it is not joined)."""

RENAMES: dict[str, dict[str, str]] = {
    "robustness": {"n": "robustness_n", "successes": "robustness_successes"},
    "metrics": {"friction": "epsilon_friction", "num_contacts": "epsilon_contacts"},
}
"""Per stage, columns whose names are too generic for the merged table."""

LABEL_COLUMNS = ("robustness", "epsilon", "pfc", "min_closure_friction")
"""Numeric labels the card summarises (those present)."""

CORRELATED = ("robustness", "epsilon", "pfc")
"""Labels whose pairwise correlations the card reports."""

DISCRETE_LABEL_VALUES = 32
"""A label with at most this many distinct values is counted per value (robustness and pfc of up to 31 copies, a
friction grid), not binned."""

CARD_VERSION = 2
"""Bump when the card's content or the plots change: published folders are then re-rendered."""

PLOT_FILES = ("outcomes.png", "robustness.png", "epsilon.png", "correlation.png", "examples.png")

OUTCOME_NAMES = (
    "collision_with_ground",
    "collision_with_target",
    "collision_with_clutter",
    "no_contact_established",
    "slipped_during_lifting",
    "success",
)
"""Outcome name by code (the same as :data:`graspgen.sim.lift.OUTCOME_NAMES`; kept here so reading needs no MuJoCo)."""

OUTCOME_COLOURS = ("#960014", "#eb1e1e", "#ff6e82", "#fae100", "#ff8c00", "#28c83c")
"""Plot colour by outcome code (as in :mod:`graspgen.viz.grasp_view`)."""

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
    "simulated": "false when the pre-filter decided the outcome",
    "decided_in": "rollout phase that decided the outcome (prefilter when not simulated)",
    "steps": "simulated steps",
    "sim_time": "simulated time, s",
    "closed_width": "pad separation when closing ended, m (NaN if not reached)",
    "lift_gain": "how far the object rose, m (NaN if not reached)",
    "rel_translation": "object displacement relative to the TCP after closing, m",
    "rel_rotation": "object rotation relative to the TCP after closing, rad",
    "contact_points": "finger-object contacts at the end of closing, world frame, k*3 values, m",
    "contact_normals": "their normals, into the object, k*3 values",
    "contact_forces": "their normal forces, k values, N",
    "contact_fingers": "their finger: 0 left, 1 right, k values",
    "robustness_n": "perturbed copies rolled out (0 unless the outcome is 5)",
    "robustness_successes": "perturbed copies that succeeded",
    "robustness": "success fraction of the perturbed copies, in [0, 1]; NaN when robustness_n = 0",
    "robustness_lo": "Wilson score 95% interval of robustness, lower end",
    "robustness_hi": "Wilson score 95% interval of robustness, upper end",
    "pfc": "probability of force closure: fraction of the copies with epsilon > delta; NaN when robustness_n = 0",
    "copy_outcomes": "outcome code of each perturbed copy",
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
"""Columns every published grasps.parquet has, with their types (:func:`validate` checks them); the label columns
of the robustness and metrics stages are checked by type when present."""

LABEL_TYPES = {
    "robustness": pa.float64(),
    "robustness_lo": pa.float64(),
    "robustness_hi": pa.float64(),
    "robustness_n": pa.int32(),
    "pfc": pa.float64(),
    "epsilon": pa.float64(),
    "min_closure_friction": pa.float64(),
}

_META_KEY = b"graspgen.dataset"
"""Parquet schema metadata key: JSON with the format, the table stages and the resolved config."""

_FORMAT = "graspgen-dataset/1"


# ---------------------------------------------------------------------------------------------------------------
# Params
# ---------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class DatasetParams:
    """Settings of the ``dataset`` stage (config section ``dataset``)."""

    row_group_rows: int = 16384
    """Rows per Parquet row group, about: whole scenes are packed into a group until the next would pass this (a
    larger scene gets a group of its own)."""
    acronym: bool = True
    """Also export each object's grasps as an ACRONYM grasp file (acronym/<object>.h5) with its mesh as OBJ."""
    plots: bool = True
    """Draw the card's plots (plots/*.png, with matplotlib)."""
    histogram_bins: int = 20
    """Bins of the label histograms (card and plots) for labels with more than 32 distinct values."""
    example_scenes: int = 4
    """Scenes in the examples contact sheet (the first ones by id that have RGB images)."""
    example_grasps: int = 24
    """At most this many grasps drawn per example scene, spread over the outcomes."""

    def __post_init__(self) -> None:
        check("row_group_rows", self.row_group_rows > 0, "be > 0", self.row_group_rows)
        check("histogram_bins", 1 <= self.histogram_bins <= 1000, "be in [1, 1000]", self.histogram_bins)
        check("example_scenes", self.example_scenes >= 0, "be >= 0", self.example_scenes)
        check("example_grasps", self.example_grasps >= 0, "be >= 0", self.example_grasps)


@dataclasses.dataclass(frozen=True)
class DatasetTaskParams:
    """What the ``dataset`` task and its publish step see: its own section and the resolved config.

    The engine gives a stage its ``params(config)`` only, and the card must show the whole config. Every section
    but ``run`` already shapes the upstream keys, so carrying them here re-runs nothing that would not re-run
    anyway; ``run`` (output folder, workers, backend) never enters a key, so it is left out.
    """

    dataset: DatasetParams
    """The ``dataset`` section."""
    config: Mapping[str, Any]
    """Every section of the resolved config except ``run``, by name (dataclasses), in the schema's order."""


# ---------------------------------------------------------------------------------------------------------------
# Merging
# ---------------------------------------------------------------------------------------------------------------


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
    StageError
        Duplicate grasp ids, a table with a grasp the first one does not have, or another scene's rows.
    """
    stage0, base = parts[0]
    for name in JOIN_KEYS:
        if name not in base.column_names:
            raise StageError(f"{stage0}: table has no {name!r} column")
    scene_ids = set(base.column("scene_id").unique().to_pylist())
    base = base.take(pc.sort_indices(base, [("grasp_id", "ascending")]))
    gid = base.column("grasp_id").to_numpy()
    if len(np.unique(gid)) != len(gid):
        raise StageError(f"{stage0}: duplicate grasp ids in scene {sorted(scene_ids)}")
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
                raise StageError(f"{stage}: table has no {name!r} column")
        other_scenes = set(table.column("scene_id").unique().to_pylist())
        if len(table) and not other_scenes <= scene_ids:
            raise StageError(f"{stage}: rows of scene {sorted(other_scenes - scene_ids)} in scene {sorted(scene_ids)}")
        ids = table.column("grasp_id").to_numpy()
        loc = np.searchsorted(gid, ids)
        found = (loc < len(gid)) & (gid[np.minimum(loc, max(len(gid) - 1, 0))] == ids) if len(gid) else ids != ids
        if not np.all(found):
            raise StageError(f"{stage}: grasp ids {ids[~found][:5].tolist()} are not in the {stage0} table")
        if len(np.unique(ids)) != len(ids):
            raise StageError(f"{stage}: duplicate grasp ids in scene {sorted(scene_ids)}")
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


def write_grasps_parquet(
    path: str | Path, scenes: Sequence[pa.Table], *, row_group_rows: int, metadata: Mapping[bytes, bytes]
) -> int:
    """Write the merged scenes to one Parquet file, whole scenes per row group; returns the number of rows.

    The settings are those of :func:`pipeline.io.write_parquet` (zstd 3, dictionaries, statistics, no pandas
    metadata), so the bytes are a function of the tables alone. Row groups: consecutive scenes packed until the
    next would take the group past ``row_group_rows`` rows.
    """
    if not scenes:
        raise StageError("dataset: no scene to write")
    schema = scenes[0].schema.with_metadata(dict(metadata))
    for t in scenes[1:]:
        if not t.schema.equals(scenes[0].schema, check_metadata=True):
            raise StageError(f"dataset: scene {_scene_of(t)} has other columns than {_scene_of(scenes[0])}")
    groups: list[list[pa.Table]] = [[]]
    rows = 0
    for t in scenes:
        if len(t) == 0:
            continue
        if groups[-1] and rows + len(t) > row_group_rows:
            groups.append([])
            rows = 0
        groups[-1].append(t)
        rows += len(t)
    total = 0
    with pq.ParquetWriter(
        path,
        schema,
        compression="zstd",
        compression_level=3,
        use_dictionary=True,
        write_statistics=True,
        store_schema=True,
    ) as writer:
        for group in groups:
            if not group:
                continue
            table = pa.concat_tables(group).cast(schema).combine_chunks()
            writer.write_table(table, row_group_size=len(table))
            total += len(table)
    return total


def _scene_of(table: pa.Table) -> str:
    return table.column("scene_id")[0].as_py() if len(table) else "(empty)"


def included_scenes(upstream: Upstream, tables: Sequence[str]) -> tuple[list[str], dict[str, str]]:
    """Scenes with a shard in every table stage (sorted), and the others with the reason they are left out."""
    have = {t: set(upstream.ids(t)) for t in tables}
    every = sorted(set().union(*have.values()))
    keep, left = [], {}
    for sid in every:
        missing = [t for t in tables if sid not in have[t]]
        if missing:
            left[sid] = f"no {', '.join(missing)} shard"
        else:
            keep.append(sid)
    return keep, left


class DatasetStage(GraspStage):
    """The published dataset: one task merging the table stages; :meth:`publish` lays out ``OUT/dataset``.

    Parameters
    ----------
    tables : sequence of str
        The per-scene table stages to join, the defining one (``grasps``) first.
    """

    name = "dataset"
    version = 1
    ext = "parquet"

    def __init__(self, tables: Sequence[str] = TABLES):
        if not tables:
            raise StageError("dataset: needs at least one table stage")
        self.tables = tuple(tables)
        self.inputs = ("objects", "scenes", *self.tables)

    def params(self, config: Any) -> DatasetTaskParams:
        sections = {f.name: getattr(config, f.name) for f in dataclasses.fields(config) if f.name != "run"}
        return DatasetTaskParams(dataset=config.dataset, config=sections)

    def tasks(self, params: DatasetTaskParams, upstream: Upstream) -> list[Task]:
        return [Task(id="dataset", payload={"tables": list(self.tables)})]

    def run(
        self,
        task: Task,
        params: DatasetTaskParams,
        upstream: Upstream,
        rng: np.random.Generator,
        out: Path,
        ctx: RunContext,
    ) -> dict[str, Any]:
        scenes, left_out = included_scenes(upstream, self.tables)
        if not scenes:
            raise StageError(
                f"dataset: no scene has a shard in every table stage ({', '.join(self.tables)}); "
                + (f"e.g. {next(iter(left_out))}: {next(iter(left_out.values()))}" if left_out else "no scenes at all")
            )
        key_stage = PROVENANCE_STAGE if PROVENANCE_STAGE in self.tables else self.tables[-1]
        merged = []
        for sid in scenes:
            parts = [(t, pq.read_table(upstream.path(t, sid))) for t in self.tables]
            merged.append(join_scene(parts, upstream.key(key_stage, sid)))
        meta = {
            "format": _FORMAT,
            "tables": list(self.tables),
            "config": to_dict(params.config),
        }
        rows = write_grasps_parquet(
            out,
            merged,
            row_group_rows=params.dataset.row_group_rows,
            metadata={_META_KEY: canonical_json(meta).encode()},
        )
        return {"grasps": rows, "scenes": len(scenes), "left_out": left_out, "columns": merged[0].num_columns}

    def publish(self, params: DatasetTaskParams, shards: Upstream, dest: Path) -> None:
        """Lay out ``dest/dataset`` (module docstring); skipped when the folder already shows this shard."""
        if "dataset" not in shards.ids(self.name):
            return  # the task failed: leave the last good folder as it is
        entry = shards.entry(self.name, "dataset")
        root = Path(dest) / self.name
        if _up_to_date(root, entry.key):
            return
        files: dict[str, dict[str, Any]] = {}

        def shard(stage: str, task_id: str, rel: str) -> None:
            e = shards.entry(stage, task_id)
            _link(shards.path(stage, task_id), root / rel)
            files[rel] = {"sha256": e.sha256, "bytes": e.bytes, "source": f"{stage}/{e.key}"}

        shard(self.name, "dataset", "grasps.parquet")
        scenes, left_out = included_scenes(shards, self.tables)
        for sid in scenes:
            shard("scenes", sid, f"scenes/{sid}.h5")
        for name in shards.ids("objects"):
            shard("objects", name, f"objects/{name}.h5")
        write_text_atomic(root / "config.yaml", config_yaml(params.config))
        _add_file(files, root, "config.yaml")
        if params.dataset.acronym:
            for rel in export_acronym(root):
                _add_file(files, root, rel)
        stages = {
            stage: {
                "version": next(iter({shards.entry(stage, t).parts.get("stage", "") for t in shards.ids(stage)}), ""),
                "keys": {t: shards.key(stage, t) for t in shards.ids(stage)},
            }
            for stage in (*self.inputs, self.name)
        }
        provenance = {
            "dataset_key": entry.key,
            "tables": list(self.tables),
            "left_out": left_out,
            "stages": stages,
            "versions": package_versions(),
            "config": to_dict(params.config),
        }
        build_card(root, provenance, files, params.dataset)  # also removes files of an earlier dataset


def config_yaml(sections: Mapping[str, Any]) -> str:
    """The resolved config as YAML with every key's description (as ``gen config show``), ``run`` left out."""
    lines = [
        "# The resolved config this dataset was made with (every stage section; the run settings are left out).",
        "# Make it again: gen run --config config.yaml --out OUT",
    ]
    for name, section in sections.items():
        body = to_yaml(section, comments=True)
        lines.append(f"{name}:")
        lines.extend(f"  {line}" for line in body.splitlines())
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------------------------
# Publishing helpers
# ---------------------------------------------------------------------------------------------------------------

_MANAGED = ("scenes", "objects", "acronym", "acronym/meshes", "plots")
"""Subfolders publish owns: files there that are not part of the current dataset are removed."""


def _link(src: Path, dst: Path) -> None:
    """Make ``dst`` the same file as ``src``: a hard link (atomically replaced), else a copy."""
    try:
        if dst.exists() and os.path.samefile(src, dst):
            return
    except OSError:
        pass
    with atomic_path(dst) as tmp:
        tmp.unlink()
        try:
            os.link(src, tmp)
        except OSError:  # another file system, or links not allowed: copy
            shutil.copyfile(src, tmp)


def _add_file(files: dict[str, dict[str, Any]], root: Path, rel: str) -> None:
    path = root / rel
    files[rel] = {"sha256": sha256_file(path), "bytes": path.stat().st_size}


def _prune(root: Path, files: Mapping[str, Any]) -> None:
    for sub in _MANAGED:
        folder = root / sub
        if not folder.is_dir():
            continue
        for path in folder.iterdir():
            rel = path.relative_to(root).as_posix()
            if path.is_file() and rel not in files and not path.name.startswith("."):
                path.unlink()


def _up_to_date(root: Path, key: str) -> bool:
    """The folder was published from the shard ``key`` by this card version and no listed file is missing."""
    try:
        card = json.loads((root / "card.json").read_text())
    except (OSError, json.JSONDecodeError):
        return False
    if card.get("dataset_key") != key or card.get("card_version") != CARD_VERSION or not (root / "card.md").exists():
        return False
    for rel, info in card.get("files", {}).items():
        try:
            if (root / rel).stat().st_size != info["bytes"]:
                return False
        except OSError:
            return False
    return True


def package_versions() -> dict[str, str]:
    """Python and the versions of the packages that shape the data (and this one)."""
    from importlib import metadata

    out = {"python": platform.python_version()}
    for name in ("graspgen", "numpy", "scipy", "mujoco", "trimesh", "coacd", "manifold3d", "embreex", "h5py",
                 "pyarrow", "joblib", "pillow", "matplotlib"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def export_acronym(root: Path) -> list[str]:
    """Each object's grasps of ``root/grasps.parquet`` as ``acronym/<object>.h5`` (+ ``acronym/meshes/<object>.obj``).

    Poses are the TCP poses in the object's mesh frame (``pose_object``), written as hand-base poses
    (:func:`graspgen.io.acronym.write_acronym`); success is outcome 5. Further qualities under ``grasps/qualities/
    graspgen/``: outcome, width, and the labels present (robustness, pfc, epsilon; NaN where missing). Rows are in
    grasps.parquet order (by scene, then grasp id); ``graspgen/grasp_id`` and the order give the way back.

    Returns
    -------
    list of str
        The written files, relative to ``root``.
    """
    from graspgen.io.acronym import write_acronym

    wanted = ["object_name", "gripper", "pose_object", "outcome", "width", "grasp_id"]
    schema = pq.read_schema(root / "grasps.parquet")
    labels = [c for c in ("robustness", "pfc", "epsilon") if c in schema.names]
    table = pq.read_table(root / "grasps.parquet", columns=wanted + labels)
    names = np.asarray(table.column("object_name").to_pylist(), dtype=object)
    written = []
    for name in sorted(set(names)):
        rows = np.flatnonzero(names == name)
        part = table.take(pa.array(rows))
        grippers = sorted(set(part.column("gripper").to_pylist()))
        if len(grippers) != 1:
            raise StageError(f"acronym export: object {name!r} has grasps of several grippers: {grippers}")
        obj = root / "objects" / f"{name}.h5"
        with h5py.File(obj, "r") as f:
            vertices, faces = f["mesh/vertices"][()], f["mesh/faces"][()]
            com, inertia = f["mass/center_of_mass"][()], f["mass/inertia"][()]
            mass, density = float(f.attrs["mass"]), float(f.attrs["density"])
        mesh_rel = f"acronym/meshes/{name}.obj"
        write_text_atomic(root / mesh_rel, _obj_text(vertices, faces))
        qualities = {
            "graspgen/outcome": part.column("outcome").to_numpy().astype(np.int8),
            "graspgen/width": part.column("width").to_numpy(),
            "graspgen/grasp_id": part.column("grasp_id").to_numpy().astype(np.int32),
        }
        for label in labels:
            qualities[f"graspgen/{label}"] = _floats(part.column(label))
        T = np.asarray(part.column("pose_object").combine_chunks().values, dtype=np.float64).reshape(-1, 4, 4)
        rel = f"acronym/{name}.h5"
        with atomic_path(root / rel) as tmp:
            write_acronym(
                tmp,
                T,
                part.column("outcome").to_numpy() == 5,
                object_file=f"meshes/{name}.obj",
                object_scale=1.0,
                gripper=grippers[0],
                object_mass=mass,
                object_com=com,
                object_inertia=inertia,
                object_density=density,
                qualities=qualities,
            )
        written += [mesh_rel, rel]
    return written


def _obj_text(vertices: np.ndarray, faces: np.ndarray) -> str:
    """Wavefront OBJ of a triangle mesh (shortest round-trip floats: deterministic, exact)."""
    out = io.StringIO()
    out.write("# graspgen object mesh, metres\n")
    for x, y, z in np.asarray(vertices, dtype=np.float64).tolist():
        out.write(f"v {x!r} {y!r} {z!r}\n")
    for a, b, c in (np.asarray(faces, dtype=np.int64) + 1).tolist():
        out.write(f"f {a} {b} {c}\n")
    return out.getvalue()


def _floats(column: pa.ChunkedArray) -> np.ndarray:
    """A numeric column as float64 with nulls as NaN."""
    return np.asarray(column.to_numpy(zero_copy_only=False), dtype=np.float64)


# ---------------------------------------------------------------------------------------------------------------
# The card
# ---------------------------------------------------------------------------------------------------------------


def _num(x: float) -> float | None:
    """A float for JSON: 6 significant digits (stable across summation orders), None when not finite."""
    x = float(x)
    return float(f"{x:.6g}") if math.isfinite(x) else None


def label_summary(values: np.ndarray, bins: int, unit_range: bool) -> dict[str, Any]:
    """Summary and histogram of one label's finite values.

    A label with at most :data:`DISCRETE_LABEL_VALUES` distinct values (robustness of n copies, a friction grid)
    gets one bar per value; otherwise ``bins`` equal bins over [0, 1] (``unit_range``) or over [min, max].
    """
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    out: dict[str, Any] = {"n": int(len(v))}
    if len(v) == 0:
        return out
    q = np.quantile(v, [0.05, 0.5, 0.95])
    out.update(
        mean=_num(v.mean()), std=_num(v.std()), min=_num(v.min()), p05=_num(q[0]), median=_num(q[1]),
        p95=_num(q[2]), max=_num(v.max()),
    )
    distinct = np.unique(v)
    if len(distinct) <= DISCRETE_LABEL_VALUES:
        out["histogram"] = {"values": [_num(x) for x in distinct], "counts": [int((v == x).sum()) for x in distinct]}
    else:
        lo, hi = (0.0, 1.0) if unit_range else (float(v.min()), float(v.max()))
        hi = hi if hi > lo else lo + 1.0
        # Values on a bin edge (k/n fractions on edges k/bins) go to the bin above, whatever the edges' rounding.
        nudged = np.minimum(v + 1e-9 * (hi - lo), hi)
        counts, edges = np.histogram(nudged, bins=bins, range=(lo, hi))
        out["histogram"] = {"edges": [_num(e) for e in edges], "counts": counts.astype(int).tolist()}
    return out


def _ranks(x: np.ndarray) -> np.ndarray:
    """Ranks 1..n with ties given their average rank (as ``scipy.stats.rankdata``; scipy.stats takes 0.5 s to
    import, and publish runs in the parent, in series with everything)."""
    ranks = np.empty(len(x))
    ranks[np.argsort(x, kind="stable")] = np.arange(1, len(x) + 1)
    _, inverse, counts = np.unique(x, return_inverse=True, return_counts=True)
    return (np.bincount(inverse, weights=ranks) / counts)[inverse]


def _correlations(table: pa.Table) -> dict[str, Any]:
    cols = [c for c in CORRELATED if c in table.column_names]
    values = {c: _floats(table.column(c)) for c in cols}
    pearson, spearman, counts = [], [], []
    for a in cols:
        rows_p, rows_s, rows_n = [], [], []
        for b in cols:
            ok = np.isfinite(values[a]) & np.isfinite(values[b])
            x, y = values[a][ok], values[b][ok]
            rows_n.append(int(ok.sum()))
            if ok.sum() < 3 or x.std() == 0 or y.std() == 0:
                rows_p.append(None)
                rows_s.append(None)
                continue
            rows_p.append(_num(np.corrcoef(x, y)[0, 1]))
            rows_s.append(_num(np.corrcoef(_ranks(x), _ranks(y))[0, 1]))
        pearson.append(rows_p)
        spearman.append(rows_s)
        counts.append(rows_n)
    return {"columns": cols, "n": counts, "pearson": pearson, "spearman": spearman}


def _card_columns(schema: pa.Schema) -> list[str]:
    """The columns the card statistics and plots read (not the heavy list columns)."""
    want = {"scene_id", "grasp_id", "object_name", "object_index", "gripper", "outcome", "outcome_name",
            "prefilter_code", "simulated", "pose_world", "open_width", *LABEL_COLUMNS, "robustness_n"}
    return [n for n in schema.names if n in want]


def card_stats(root: Path, files: Mapping[str, Any], params: DatasetParams) -> tuple[dict[str, Any], pa.Table]:
    """Counts, label summaries and correlations of the dataset in ``root`` whose data files are ``files`` (relative
    paths; the scenes and objects are those listed, not whatever else sits in the folder); also returns the table
    read."""
    schema = pq.read_schema(root / "grasps.parquet")
    table = pq.read_table(root / "grasps.parquet", columns=_card_columns(schema))
    outcome = table.column("outcome").to_numpy()
    objects = np.asarray(table.column("object_name").to_pylist(), dtype=object)
    scene_col = np.asarray(table.column("scene_id").to_pylist(), dtype=object)
    scenes: dict[str, Any] = {}
    for path in sorted(root / rel for rel in files if rel.startswith("scenes/")):
        with h5py.File(path, "r") as f:
            names = f.attrs["object_names"]
            names = json.loads(names.decode() if isinstance(names, bytes) else names) if not isinstance(
                names, np.ndarray) else names.tolist()
            scenes[path.stem] = {
                "grasps": int((scene_col == path.stem).sum()),
                "objects": [str(n) for n in names],
                "views": int(f["cameras/K"].shape[0]),
            }
    library = sorted(Path(rel).stem for rel in files if rel.startswith("objects/"))
    per_object = {}
    for name in library:
        sel = objects == name
        counts = [int(((outcome == c) & sel).sum()) for c in range(len(OUTCOME_NAMES))]
        n = int(sel.sum())
        per_object[name] = {
            "scenes": sum(name in s["objects"] for s in scenes.values()),
            "grasps": n,
            "outcomes": counts,
            "success_rate": _num(counts[5] / n) if n else None,
        }
    labels = {}
    for col in LABEL_COLUMNS:
        if col in table.column_names:
            labels[col] = label_summary(_floats(table.column(col)), params.histogram_bins, col in ("robustness", "pfc"))
    stats = {
        "counts": {
            "grasps": len(table),
            "scenes": len(scenes),
            "views": sum(s["views"] for s in scenes.values()),
            "objects": len(library),
            "objects_with_grasps": int(sum(1 for o in per_object.values() if o["grasps"])),
            "grippers": sorted(set(table.column("gripper").to_pylist())),
        },
        "outcomes": [
            {"code": c, "name": name, "grasps": int((outcome == c).sum())} for c, name in enumerate(OUTCOME_NAMES)
        ],
        "objects": per_object,
        "scenes": scenes,
        "labels": labels,
        "correlation": _correlations(table),
    }
    return stats, table


def _schema_doc(schema: pa.Schema) -> list[dict[str, str]]:
    return [
        {
            "name": f.name,
            "type": str(f.type),
            "description": (f.metadata or {}).get(b"description", b"").decode(),
        }
        for f in schema
    ]


def build_card(root: Path, provenance: Mapping[str, Any], files: Mapping[str, Any], params: DatasetParams) -> dict:
    """Compute the statistics, draw the plots and write ``card.json`` and ``card.md`` in ``root``.

    Parameters
    ----------
    root : Path
        The dataset folder (grasps.parquet, scenes/, objects/ in place).
    provenance : mapping
        ``dataset_key``, ``tables``, ``left_out``, ``stages`` (version and keys per stage), ``versions``,
        ``config``: what the data alone cannot tell.
    files : mapping
        ``{relative path: {"sha256", "bytes", ...}}`` of the data files (the plots are added here).
    params : DatasetParams
    """
    stats, table = card_stats(root, files, params)
    files = dict(files)
    plots = []
    if params.plots:
        plots = draw_plots(root, table, stats, params)
        for rel in plots:
            _add_file(files, root, rel)
    schema = pq.read_schema(root / "grasps.parquet")
    card = {
        "format": _FORMAT,
        "card_version": CARD_VERSION,
        "dataset_key": provenance["dataset_key"],
        "tables": list(provenance["tables"]),
        **stats,
        "left_out": dict(provenance["left_out"]),
        "schema": _schema_doc(schema),
        "plots": plots,
        "files": {k: files[k] for k in sorted(files)},
        "stages": provenance["stages"],
        "versions": provenance["versions"],
        "config": provenance["config"],
    }
    card = json.loads(json.dumps(card, allow_nan=False))  # what card.json holds is exactly what is rendered
    write_text_atomic(root / "card.json", json.dumps(card, indent=1) + "\n")
    write_text_atomic(root / "card.md", render_card(card))
    _prune(root, card["files"])
    return card


def _fmt(x: Any, digits: int = 3) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return f"{x:.{digits}g}"
    return str(x)


def render_card(card: Mapping[str, Any]) -> str:
    """The Markdown dataset card of a ``card.json`` dict (a pure function of it)."""
    c = card["counts"]
    lines = ["# Dataset card", ""]
    lines += [
        f"A grasp dataset made by graspgen {card['versions'].get('graspgen', '?')}: {c['grasps']} grasps of "
        f"{c['objects_with_grasps']} objects in {c['scenes']} scenes ({c['views']} camera views), gripper "
        f"{', '.join(c['grippers']) or '-'}, each labelled by a simulated grasp-and-lift"
        + (", perturbed copies (robustness, pfc)" if "robustness" in card["labels"] else "")
        + (" and the Ferrari-Canny epsilon" if "epsilon" in card["labels"] else "")
        + ".",
        "",
        f"Dataset key `{card['dataset_key']}` (the content key of `grasps.parquet`; it changes with any input, "
        "parameter or stage version). Check the files with `gen validate <folder>`; read them with "
        "`graspgen.io.reader.open_dataset(<folder>)`, pandas, polars, duckdb or h5py.",
        "",
        "## Files",
        "",
        "| path | what |",
        "| --- | --- |",
        f"| `grasps.parquet` | one row per grasp, {len(card['schema'])} columns (schema below), row groups of whole "
        "scenes sorted by `scene_id`, `grasp_id` |",
        f"| `scenes/<scene_id>.h5` | {c['scenes']} scenes: object names and settled poses, cameras (K, "
        "camera-to-world), RGB, depth, segmentation, point clouds |",
        f"| `objects/<name>.h5` | {c['objects']} objects: mesh, convex parts, mass properties, stable poses |",
    ]
    if any(k.startswith("acronym/") for k in card["files"]):
        lines.append("| `acronym/<name>.h5` | each object's grasps in the ACRONYM format (mesh: `acronym/meshes/`) |")
    lines += [
        "| `config.yaml` | the resolved config (`gen run --config config.yaml` makes the dataset again) |",
        "| `card.json` | this card as data, with every file's sha256 and every shard key |",
        "",
        "## Outcomes",
        "",
        "| code | outcome | grasps | share |",
        "| ---: | --- | ---: | ---: |",
    ]
    total = max(c["grasps"], 1)
    for o in card["outcomes"]:
        lines.append(f"| {o['code']} | {o['name']} | {o['grasps']} | {100 * o['grasps'] / total:.1f}% |")
    lines += [
        "",
        "## Per object",
        "",
        "| object | scenes | grasps | " + " | ".join(str(i) for i in range(len(OUTCOME_NAMES))) + " | success rate |",
        "| --- | ---: | ---: | " + " | ".join("---:" for _ in OUTCOME_NAMES) + " | ---: |",
    ]
    for name, o in card["objects"].items():
        rate = "-" if o["success_rate"] is None else f"{100 * o['success_rate']:.1f}%"
        counts = " | ".join(str(n) for n in o["outcomes"])
        lines.append(f"| {name} | {o['scenes']} | {o['grasps']} | {counts} | {rate} |")
    lines += ["", "Columns 0-5 are the outcome codes above.", ""]
    lines += ["## Labels", ""]
    if card["labels"]:
        lines += [
            "Over the grasps where the label is defined (robustness and pfc: successful grasps).",
            "",
            "| label | n | mean | std | min | 5% | median | 95% | max |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
        ]
        for name, s in card["labels"].items():
            cells = [_fmt(s.get(k)) for k in ("mean", "std", "min", "p05", "median", "p95", "max")]
            lines.append(f"| {name} | {s['n']} | " + " | ".join(cells) + " |")
        lines.append("")
        for name, s in card["labels"].items():
            h = s.get("histogram")
            if not h:
                continue
            if "values" in h:
                bars = ", ".join(f"{_fmt(v)}: {n}" for v, n in zip(h["values"], h["counts"]))
            else:
                e = h["edges"]
                bars = ", ".join(f"[{_fmt(e[i])}, {_fmt(e[i + 1])}): {n}" for i, n in enumerate(h["counts"]))
            lines.append(f"- `{name}` histogram: {bars}")
        lines.append("")
        corr = card["correlation"]
        if len(corr["columns"]) >= 2:
            cols = corr["columns"]
            lines += [
                "Correlation between labels (Spearman rank / Pearson; n = grasps where both are defined):",
                "",
                "| | " + " | ".join(cols) + " |",
                "| --- |" + " ---: |" * len(cols),
            ]
            for i, a in enumerate(cols):
                cells = [
                    f"{_fmt(corr['spearman'][i][j], 2)} / {_fmt(corr['pearson'][i][j], 2)} (n {corr['n'][i][j]})"
                    for j in range(len(cols))
                ]
                lines.append(f"| {a} | " + " | ".join(cells) + " |")
            lines.append("")
    else:
        lines += ["No label columns beyond the outcome (the robustness and metrics stages were not joined).", ""]
    if card["plots"]:
        lines += ["## Plots", ""]
        for rel in card["plots"]:
            lines.append(f"![{Path(rel).stem}]({rel})")
            lines.append("")
    if card["left_out"]:
        lines += ["## Scenes left out", ""]
        lines += [f"- {sid}: {why}" for sid, why in card["left_out"].items()]
        lines.append("")
    lines += ["## Schema of grasps.parquet", "", "| column | type | description |", "| --- | --- | --- |"]
    for f in card["schema"]:
        lines.append(f"| `{f['name']}` | {f['type']} | {f['description']} |")
    lines += [
        "",
        "## Provenance",
        "",
        "Every shard is named by its content key; `card.json` lists every key (`stages`).",
        "",
        "| stage | version | shards | keys digest |",
        "| --- | --- | ---: | --- |",
    ]
    for stage, s in card["stages"].items():
        digest = hashlib.sha256(canonical_json(s["keys"]).encode()).hexdigest()[:16]
        lines.append(f"| {stage} | {s['version']} | {len(s['keys'])} | `{digest}` |")
    lines += ["", "Package versions: " + ", ".join(f"{k} {v}" for k, v in card["versions"].items()) + ".", ""]
    lines += [
        "## Config",
        "",
        "```yaml",
        yaml.safe_dump(card["config"], sort_keys=False, default_flow_style=None, width=110).rstrip(),
        "```",
        "",
    ]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------------------------
# Plots
# ---------------------------------------------------------------------------------------------------------------


def _save(fig: Any, path: Path) -> None:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    # No "Software" entry, no date: the PNG bytes depend on the data and the matplotlib version only.
    fig.savefig(buf, format="png", dpi=100, metadata={"Software": None})
    plt.close(fig)
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.getvalue())


def _bars(ax: Any, summary: Mapping[str, Any], colour: str) -> None:
    h = summary["histogram"]
    if "values" in h:
        values = np.asarray(h["values"], dtype=float)
        step = np.min(np.diff(values)) if len(values) > 1 else 1.0
        ax.bar(values, h["counts"], width=0.8 * step, color=colour, edgecolor="black", linewidth=0.5)
    else:
        e = np.asarray(h["edges"], dtype=float)
        ax.bar(e[:-1], h["counts"], width=np.diff(e), align="edge", color=colour, edgecolor="black", linewidth=0.5)
    ax.set_ylabel("grasps")


def draw_plots(root: Path, table: pa.Table, stats: Mapping[str, Any], params: DatasetParams) -> list[str]:
    """Write the card's PNGs in ``root/plots``; returns their paths relative to ``root``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": 9, "svg.hashsalt": "graspgen", "figure.max_open_warning": 0})
    written = []
    names = [o["name"] for o in stats["outcomes"]]
    counts = [o["grasps"] for o in stats["outcomes"]]
    objects = [k for k, v in stats["objects"].items() if v["grasps"]]

    # Outcomes: overall bars and each object's mix.
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, max(3.5, 0.3 * len(objects) + 1.5)), width_ratios=[1, 1.3])
    a.bar(range(len(names)), counts, color=OUTCOME_COLOURS, edgecolor="black", linewidth=0.5)
    for i, n in enumerate(counts):
        a.text(i, n, str(n), ha="center", va="bottom")
    a.set_xticks(range(len(names)), [f"{i} {n}" for i, n in enumerate(names)], rotation=30, ha="right")
    a.set_ylabel("grasps")
    a.set_title(f"outcomes of {stats['counts']['grasps']} grasps")
    left = np.zeros(len(objects))
    for code, colour in enumerate(OUTCOME_COLOURS):
        share = np.array([stats["objects"][o]["outcomes"][code] / stats["objects"][o]["grasps"] for o in objects])
        b.barh(range(len(objects)), share, left=left, color=colour, edgecolor="black", linewidth=0.3,
               label=f"{code} {names[code]}")
        left += share
    b.set_yticks(range(len(objects)), [f"{o} ({stats['objects'][o]['grasps']})" for o in objects])
    b.invert_yaxis()
    b.set_xlim(0, 1)
    b.set_title("share of each object's grasps by outcome (grasps)")
    b.legend(loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=3, fontsize=7, frameon=False)
    fig.tight_layout()
    _save(fig, root / "plots" / "outcomes.png")
    written.append("plots/outcomes.png")

    labels = stats["labels"]
    if labels.get("robustness", {}).get("n") or labels.get("pfc", {}).get("n"):
        fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
        for ax, col, colour in zip(axes, ("robustness", "pfc"), ("#28c83c", "#3c78d8")):
            s = labels.get(col, {})
            if s.get("n"):
                _bars(ax, s, colour)
                ax.set_title(f"{col} of {s['n']} successful grasps (mean {s['mean']:.2f})")
            else:
                ax.set_title(f"no {col} labels")
            ax.set_xlim(-0.05, 1.05)
            ax.set_xlabel(col)
        fig.tight_layout()
        _save(fig, root / "plots" / "robustness.png")
        written.append("plots/robustness.png")

    if labels.get("epsilon", {}).get("n"):
        eps = _floats(table.column("epsilon"))
        outcome = table.column("outcome").to_numpy()
        fig, ax = plt.subplots(figsize=(8, 3.6))
        finite = np.isfinite(eps)
        hi = float(eps[finite].max()) if finite.any() else 1.0
        edges = np.linspace(0.0, hi if hi > 0 else 1.0, params.histogram_bins + 1)
        groups = [("success (5)", outcome == 5, "#28c83c"), ("slipped / no contact (3, 4)",
                  (outcome == 3) | (outcome == 4), "#ff8c00"), ("collision (0-2)", outcome <= 2, "#eb1e1e")]
        ax.hist([eps[g & finite] for _, g, _ in groups], bins=edges, stacked=True,
                color=[c for _, _, c in groups], label=[n for n, _, _ in groups], edgecolor="black", linewidth=0.3)
        zero = int(((eps == 0) & finite).sum())
        ax.set_xlabel("Ferrari-Canny epsilon (unit-free)")
        ax.set_ylabel("grasps")
        ax.set_title(f"epsilon of {int(finite.sum())} grasps by outcome ({zero} not in force closure: epsilon 0)")
        ax.legend(fontsize=8)
        fig.tight_layout()
        _save(fig, root / "plots" / "epsilon.png")
        written.append("plots/epsilon.png")

    if "robustness" in table.column_names and "epsilon" in table.column_names:
        r, e = _floats(table.column("robustness")), _floats(table.column("epsilon"))
        p = _floats(table.column("pfc")) if "pfc" in table.column_names else np.full(len(r), np.nan)
        ok = np.isfinite(r) & np.isfinite(e)
        if ok.sum() >= 2:
            fig, ax = plt.subplots(figsize=(6.5, 4.5))
            jitter = (np.random.default_rng(0).random(int(ok.sum())) - 0.5) * 0.02  # seeded: bytes stay fixed
            colour = np.where(np.isfinite(p[ok]), p[ok], 0.0)
            sc = ax.scatter(e[ok], r[ok] + jitter, c=colour, cmap="viridis", vmin=0, vmax=1, s=14,
                            edgecolors="black", linewidths=0.2)
            fig.colorbar(sc, ax=ax, label="pfc")
            corr = stats["correlation"]
            i, j = corr["columns"].index("robustness"), corr["columns"].index("epsilon")
            rho = corr["spearman"][i][j]
            ax.set_xlabel("epsilon")
            ax.set_ylabel("robustness (jittered)")
            ax.set_title(f"robustness vs epsilon, {int(ok.sum())} successful grasps (Spearman {_fmt(rho, 2)})")
            fig.tight_layout()
            _save(fig, root / "plots" / "correlation.png")
            written.append("plots/correlation.png")

    sheet = _examples_sheet(root, table, params)
    if sheet is not None:
        buf = io.BytesIO()
        sheet.save(buf, format="PNG", optimize=False)
        with atomic_path(root / "plots" / "examples.png") as tmp:
            tmp.write_bytes(buf.getvalue())
        written.append("plots/examples.png")
    return written


def _examples_sheet(root: Path, table: pa.Table, params: DatasetParams) -> Any:
    """Contact sheet of example grasps drawn on the first view of the first scenes (:mod:`graspgen.viz.grasp_view`)."""
    if params.example_scenes == 0 or params.example_grasps == 0:
        return None
    from PIL import Image

    from graspgen.io.scenes import read_scene
    from graspgen.viz.grasp_view import grasp_picture

    scene_col = np.asarray(table.column("scene_id").to_pylist(), dtype=object)
    pictures = []
    for sid in sorted(set(scene_col)):
        if len(pictures) == params.example_scenes:
            break
        scene = read_scene(root / "scenes" / f"{sid}.h5")
        if scene.rgb is None:
            continue
        part = table.take(pa.array(np.flatnonzero(scene_col == sid)))
        pictures.append(grasp_picture(scene, part, part, view=0, n=params.example_grasps, scale=2))
    if not pictures:
        return None
    cols = 2 if len(pictures) > 1 else 1
    rows = math.ceil(len(pictures) / cols)
    w = max(p.width for p in pictures)
    h = max(p.height for p in pictures)
    sheet = Image.new("RGB", (cols * w + (cols + 1) * 6, rows * h + (rows + 1) * 6), (255, 255, 255))
    for i, p in enumerate(pictures):
        sheet.paste(p, (6 + (i % cols) * (w + 6), 6 + (i // cols) * (h + 6)))
    return sheet


# ---------------------------------------------------------------------------------------------------------------
# gen report, gen validate
# ---------------------------------------------------------------------------------------------------------------


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


def report(path: str | Path) -> Path:
    """Render ``card.md``, ``card.json`` and the plots of a published dataset again; returns the card.md path.

    The statistics and plots come from the data files; what the data cannot tell (keys, config, package versions,
    the data files' hashes) is taken from the existing ``card.json``. So on an intact folder the result is the
    published card, byte for byte.
    """
    root = dataset_dir(path)
    try:
        old = json.loads((root / "card.json").read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"{root / 'card.json'}: cannot read the card ({exc}); publish again with gen run") from None
    fields = {f.name for f in dataclasses.fields(DatasetParams)}
    params = DatasetParams(**{k: v for k, v in old.get("config", {}).get("dataset", {}).items() if k in fields})
    data_files = {k: v for k, v in old.get("files", {}).items() if not k.startswith("plots/")}
    provenance = {k: old[k] for k in ("dataset_key", "tables", "left_out", "stages", "versions", "config")}
    build_card(root, provenance, data_files, params)
    return root / "card.md"


def validate(path: str | Path) -> tuple[list[str], int]:
    """Check a published dataset (and, when ``path`` is a run folder, every stage's shards).

    Checks: every manifest entry's shard exists with its recorded size and sha256; every file listed in
    ``card.json`` exists with its sha256 and no other file sits in the dataset's folders; grasps.parquet has the
    schema of the card and the required columns and types (:data:`REQUIRED_SCHEMA`), rows sorted and unique by
    (scene_id, grasp_id), outcome codes and names that agree, labels in range, rigid poses; every scene and object
    it names has its file; card.md is the rendering of card.json.

    Returns
    -------
    (problems, files_checked)
        Each problem starts with the path of the file at fault.
    """
    root = dataset_dir(path)
    problems: list[str] = []
    checked = 0
    run_root = root.parent if (root / MANIFEST).is_file() else None
    if run_root is not None:
        for manifest_path in sorted(run_root.glob(f"*/{MANIFEST}")):
            manifest = Manifest(manifest_path.parent)
            for entry in manifest.entries().values():
                if entry.status != "ok" or entry.file is None:
                    continue
                shard = manifest.stage_dir / entry.file
                checked += 1
                if not shard.is_file():
                    problems.append(f"{shard}: missing (listed in {manifest_path})")
                elif shard.stat().st_size != entry.bytes:
                    problems.append(f"{shard}: {shard.stat().st_size} bytes, the manifest says {entry.bytes}")
                elif sha256_file(shard) != entry.sha256:
                    problems.append(f"{shard}: sha256 differs from the manifest's (the file was changed)")
    try:
        card = json.loads((root / "card.json").read_text())
    except (OSError, json.JSONDecodeError) as exc:
        return problems + [f"{root / 'card.json'}: cannot read the card ({exc})"], checked
    listed = card.get("files", {})
    for rel, info in listed.items():
        f = root / rel
        checked += 1
        if not f.is_file():
            problems.append(f"{f}: missing (listed in card.json)")
        elif f.stat().st_size != info["bytes"] or sha256_file(f) != info["sha256"]:
            problems.append(f"{f}: sha256 differs from card.json's (the file was changed)")
    for sub in _MANAGED:
        for f in sorted((root / sub).glob("*")) if (root / sub).is_dir() else []:
            rel = f.relative_to(root).as_posix()
            if f.is_file() and rel not in listed and not f.name.startswith("."):
                problems.append(f"{f}: not part of the dataset (not listed in card.json)")
    problems += _check_table(root, card)
    try:
        if (root / "card.md").read_text() != render_card(card):
            problems.append(f"{root / 'card.md'}: is not the rendering of card.json (run gen report)")
    except OSError:
        problems.append(f"{root / 'card.md'}: missing")
    return problems, checked


def _check_table(root: Path, card: Mapping[str, Any]) -> list[str]:
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
    t = pf.read(columns=cols)
    sid = np.asarray(t.column("scene_id").to_pylist(), dtype=object)
    gid = t.column("grasp_id").to_numpy()
    keys = list(zip(sid.tolist(), gid.tolist()))
    if keys != sorted(set(keys)):
        problems.append(f"{where}: rows are not sorted and unique by (scene_id, grasp_id)")
    outcome = t.column("outcome").to_numpy()
    if len(outcome) and (outcome.min() < 0 or outcome.max() >= len(OUTCOME_NAMES)):
        problems.append(f"{where}: outcome codes outside 0-5")
    elif [OUTCOME_NAMES[o] for o in outcome.tolist()] != t.column("outcome_name").to_pylist():
        problems.append(f"{where}: outcome_name does not match outcome")
    for name in ("robustness", "robustness_lo", "robustness_hi", "pfc"):
        if name in t.column_names:
            v = _floats(t.column(name))
            if np.any((v < 0) | (v > 1)):
                problems.append(f"{where}: {name} outside [0, 1]")
    if {"robustness", "robustness_lo", "robustness_hi"} <= set(t.column_names):
        r, lo, hi = (_floats(t.column(n)) for n in ("robustness", "robustness_lo", "robustness_hi"))
        ok = np.isfinite(r)
        if np.any(lo[ok] > r[ok] + 1e-12) or np.any(hi[ok] < r[ok] - 1e-12):
            problems.append(f"{where}: robustness outside its interval [robustness_lo, robustness_hi]")
    if "epsilon" in t.column_names and np.any(_floats(t.column("epsilon")) < 0):
        problems.append(f"{where}: negative epsilon")
    T = np.asarray(t.column("pose_world").combine_chunks().values, dtype=np.float64).reshape(-1, 4, 4)
    R = T[:, :3, :3]
    if len(T) and (
        not np.allclose(R @ R.transpose(0, 2, 1), np.eye(3), atol=1e-6)
        or not np.allclose(T[:, 3], [0, 0, 0, 1])
        or np.any(np.linalg.det(R) < 0)
    ):
        problems.append(f"{where}: pose_world holds matrices that are not rigid transforms")
    for s in sorted(set(sid.tolist())):
        if not (root / "scenes" / f"{s}.h5").is_file():
            problems.append(f"{root / 'scenes' / f'{s}.h5'}: missing (grasps.parquet has grasps of {s})")
    for o in sorted(set(t.column("object_name").to_pylist())):
        if not (root / "objects" / f"{o}.h5").is_file():
            problems.append(f"{root / 'objects' / f'{o}.h5'}: missing (grasps.parquet has grasps of {o})")
    return problems
