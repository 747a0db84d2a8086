"""Stage 7, ``dataset``: the per-scene shards merged into the published dataset with its card.

One task (``dataset``) reads the per-scene tables of the table stages (:data:`graspgen.io.dataset_table.TABLES`:
``grasps``, ``rollouts``, ``robustness``, ``metrics``) and joins them on ``(scene_id, grasp_id)``
(:func:`graspgen.io.dataset_table.join_scene`): one row per grasp of the grasps table, plus every column of each
other table except the join keys (a table without a row for a grasp leaves nulls there; a column name already taken
gets its stage's name as a prefix; the few renames of :data:`graspgen.io.dataset_table.RENAMES` make generic names
specific). Scenes are sorted by id and grasps by id within a scene. Only scenes with a shard in every table stage
are included; the others are named in the manifest meta and in the card. The task's shard is that table, written
deterministically (zstd level 3, dictionary-encoded strings, statistics on; no timestamps) with row groups that hold
whole scenes, packed up to ``dataset.row_group_rows`` rows: a reader that wants one scene touches one row group, and
the footer stays small with many scenes (one row group per scene would make it grow with every scene). The shards
are read one scene at a time, in scene id order, and written as row groups fill
(:class:`graspgen.io.row_groups.GroupedParquetWriter`): the task holds one row group, not the table, and so do the
object-set tasks (one shard at a time, by task id). The card's statistics are running counts over the published
files' row groups (:mod:`graspgen.io.card_tally`) and ``gen validate`` checks the table one row group at a time.

After the task has been committed, :meth:`DatasetStage.publish` lays out ``OUT/dataset/`` (each file atomically;
shards as hard links, copies where links are not possible)::

    grasps.parquet          the merged table: the dataset shard
    scenes/<scene_id>.h5    the scene shards of the included scenes (cameras, images, clouds, object poses)
    objects/<name>.h5       the object shards of the library (mesh, convex parts, mass properties, stable poses)
    acronym/<name>.h5       each object's grasps as an ACRONYM grasp file (:mod:`graspgen.io.acronym`), rows in
                            grasps.parquet order; its mesh as acronym/meshes/<name>.obj (the file's object/file)
    plots/*.png             outcomes, robustness, epsilon, correlation (label columns present), examples
    probe/model.pt          the learnability probe's grasp evaluator (when the probe stage ran); probe/report.json
                            its held-out scores, which the card renders (:mod:`graspgen.io.card_learn`)
    config.yaml             the resolved config: every stage section with its comments (``run`` left out)
    card.json, card.md      counts per object and outcome, label summaries, histograms and correlations, the
                            schema, every file's sha256, every stage's shard keys, package versions, the config

and nothing else: the engine's shards and manifest of this stage are in ``OUT/shards/dataset/``, so copying or archiving
``OUT/dataset`` hands over exactly the published files. The card is :mod:`graspgen.io.card`
(:func:`graspgen.io.card.report` renders it and the plots of :mod:`graspgen.viz.plots` again from a published folder:
``gen report``); :func:`validate` checks a folder against the manifests, the card's hashes and the schema (``gen
validate``). Read a dataset with
:func:`graspgen.io.reader.open_dataset`.

The folder heals. Publish keeps a record of every file it laid out (size, mtime, inode, sha256; for a shard's link
its shard) in ``OUT/shards/dataset/published.json`` and every run checks the folder against it, fast
(:func:`check_published`: a link is intact when it is its verified shard's inode with its size, any other file
when its size, mtime and inode are unchanged, else its sha256 decides): a damaged or missing link is made again
(a damaged shard is remade by its stage first: the run checks shards by sha256), a stray file in the dataset's
folders is removed, and a damaged or missing file of any other kind (plots, ACRONYM files, the card) lays the
folder out again. ``gen status`` runs the same check (:meth:`DatasetStage.publish_status`) and names each file
the run will replace. Only ``gen validate`` reads every byte. The card also lists the run's warnings (unit guesses
and repairs of meshes, objects left out and why, objects the gripper cannot grasp), given to publish by the engine.

Columns of ``grasps.parquet`` (with the default table stages; every column's description,
:data:`graspgen.io.dataset_table.COLUMN_DOCS`, is also stored in the Parquet field metadata under ``description``;
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

import dataclasses
import json
import os
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from graspgen.io.acronym import export_acronym, export_object_acronym
from graspgen.io.card import (
    CARD_VERSION,
    MANAGED,
    CardSettings,
    add_file,
    build_card,
    package_versions,
    render_card,
)
from graspgen.io.card_grasps import scene_grasp_counts
from graspgen.io.dataset_table import (
    FORMAT,
    META_KEY,
    TABLES,
    GroupedParquetWriter,
    check_table,
    dataset_dir,
    join_scene,
    write_grasps_parquet,
)
from graspgen.io.graspgen_format import export_graspgen
from graspgen.io.probe_files import publish_probe
from graspgen.validation import check
from pipeline.config import to_dict, to_yaml
from pipeline.errors import StageError
from pipeline.keys import canonical_json, sha256_file
from pipeline.stage import RunContext, Task, Upstream
from pipeline.store import MANIFEST, SHARDS, Entry, Manifest, atomic_path, stage_dir, write_text_atomic
from stages.base import GraspStage

__all__ = [
    "DatasetParams",
    "DatasetStage",
    "DatasetTaskParams",
    "config_yaml",
    "included_scenes",
    "validate",
]

OBJECT_SETS = ("object_grasps", "placed_grasps")
"""Stages whose shards are published as they are, concatenated, one table each: ``object_grasps.parquet`` (the
object-centric grasp sets, by object) and ``placed_grasps.parquet`` (those sets placed in the scenes, by scene)."""

OBJECT_SET_META = ("tried", "positives", "negatives", "target_positives", "target_negatives", "reached")
"""Keys of an object-grasps task's manifest meta kept in ``object_grasps.parquet``'s metadata (under
:data:`graspgen.io.dataset_table.META_KEY`, ``"tasks"``): how far each object's set got. Timings are left out: they
would make the bytes differ between runs."""

PROBE = "probe"
"""The learnability probe's stage (:mod:`stages.probe`); PROBE_TASK is its one task."""
PROBE_TASK = "probe"

PROVENANCE_STAGE = "rollouts"
"""``source_key`` holds the key of this stage's shard of the scene (the last table stage when it is not joined)."""


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
    """Also export each object's grasps as an ACRONYM grasp file (acronym/<object>.h5) with its mesh as OBJ: its
    object-centric set (free-space labels, ACRONYM's meaning) when the object_grasps stage ran, else its scene
    grasps."""
    graspgen: bool = True
    """Also export the object-centric sets in GraspGen's dataset layout (graspgen/: splits and one JSON per
    object; :mod:`graspgen.io.graspgen_format`)."""
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


def card_settings(params: DatasetParams) -> CardSettings:
    """The fields of the ``dataset`` section that the card and its plots read."""
    return CardSettings(
        plots=params.plots,
        histogram_bins=params.histogram_bins,
        example_scenes=params.example_scenes,
        example_grasps=params.example_grasps,
    )


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
    object_sets : sequence of str
        Stages whose shards are concatenated as they are into ``<stage>.parquet`` (:data:`OBJECT_SETS`); each is
        one more task of this stage, made when that stage has shards.
    probe : str, optional
        The learnability probe's stage (:data:`PROBE`): its shard is published as ``probe/model.pt`` and
        ``probe/report.json`` (:func:`graspgen.io.probe_files.publish_probe`) and the card renders the report. Its
        key enters the ``dataset`` task's key, so a new probe result publishes the folder again.
    """

    name = "dataset"
    version = 1
    ext = "parquet"
    published = ("dataset",)

    def __init__(self, tables: Sequence[str] = TABLES, object_sets: Sequence[str] = (), probe: str | None = None):
        if not tables:
            raise StageError("dataset: needs at least one table stage")
        self.tables = tuple(tables)
        self.object_sets = tuple(object_sets)
        self.probe = probe
        self.inputs = ("objects", "scenes", *self.tables, *self.object_sets, *((probe,) if probe else ()))

    def params(self, config: Any) -> DatasetTaskParams:
        sections = {f.name: getattr(config, f.name) for f in dataclasses.fields(config) if f.name != "run"}
        return DatasetTaskParams(dataset=config.dataset, config=sections)

    def tasks(self, params: DatasetTaskParams, upstream: Upstream) -> list[Task]:
        needs = {stage: upstream.ids(stage) for stage in ("objects", "scenes", *self.tables)}
        if self.probe and upstream.ids(self.probe):
            needs[self.probe] = upstream.ids(self.probe)
        tasks = [Task(id="dataset", payload={"tables": list(self.tables)}, needs=needs)]
        for stage in self.object_sets:
            if upstream.ids(stage):
                tasks.append(Task(id=stage, payload={"stage": stage}, needs={stage: upstream.ids(stage)}))
        return tasks

    def run(
        self,
        task: Task,
        params: DatasetTaskParams,
        upstream: Upstream,
        rng: np.random.Generator,
        out: Path,
        ctx: RunContext,
    ) -> dict[str, Any]:
        if task.id in self.object_sets:
            return self._concatenate(task.id, upstream, params, out)
        scenes, left_out = included_scenes(upstream, self.tables)
        if not scenes:
            raise StageError(
                f"dataset: no scene has a shard in every table stage ({', '.join(self.tables)}); "
                + (f"e.g. {next(iter(left_out))}: {next(iter(left_out.values()))}" if left_out else "no scenes at all")
            )
        key_stage = PROVENANCE_STAGE if PROVENANCE_STAGE in self.tables else self.tables[-1]
        meta = {
            "format": FORMAT,
            "tables": list(self.tables),
            "config": to_dict(params.config),
        }
        writer = GroupedParquetWriter(
            out, row_group_rows=params.dataset.row_group_rows, metadata={META_KEY: canonical_json(meta).encode()}
        )
        with writer:  # one scene's shards read at a time, in scene id order: memory holds one row group
            for sid in scenes:
                parts = [(t, pq.read_table(upstream.path(t, sid))) for t in self.tables]
                writer.add(join_scene(parts, upstream.key(key_stage, sid)))
        assert writer.schema is not None
        return {"grasps": writer.rows, "scenes": len(scenes), "left_out": left_out, "columns": len(writer.schema)}

    def _concatenate(self, stage: str, upstream: Upstream, params: DatasetTaskParams, out: Path) -> dict[str, Any]:
        """``<stage>.parquet``: the stage's shards one after the other, by task id (object or scene name), with
        what each task's meta says of how far it got (:data:`OBJECT_SET_META`) in the file's metadata."""
        ids = upstream.ids(stage)  # sorted: the file's order does not depend on how the shards were made
        tasks = {tid: {k: v for k, v in upstream.meta(stage, tid).items() if k in OBJECT_SET_META} for tid in ids}
        meta = {"format": FORMAT, "stage": stage, "tasks": tasks}
        shards = (pq.read_table(upstream.path(stage, tid)) for tid in ids)  # one shard in memory at a time
        rows = write_grasps_parquet(out, shards, row_group_rows=params.dataset.row_group_rows,
                                    metadata={META_KEY: canonical_json(meta).encode()})
        return {"rows": rows, "tasks": len(ids)}

    def publish(self, params: DatasetTaskParams, shards: Upstream, dest: Path) -> list[str]:
        """Lay out ``dest/dataset`` (module docstring), or repair it when it already shows this shard.

        Every run checks the folder fast against the publish record (:func:`check_published`: a file linked to
        its shard by inode and size, any other by size, mtime and inode): damaged or missing links are made
        again, stray files in the dataset's folders removed, and a damaged file of any other kind (plots,
        ACRONYM files, the card) makes the whole folder again. Returns what it repaired (nothing for a new
        dataset or an intact folder).
        """
        if "dataset" not in shards.ids(self.name):
            return []  # the task failed: leave the last good folder as it is
        entry = shards.entry(self.name, "dataset")
        root = Path(dest) / self.name
        record_path = stage_dir(dest, self.name) / PUBLISH_RECORD
        check = check_published(root, _read_record(record_path), shards, entry.key)
        if check.remake is None and not check.rebuild:
            if check.relink or check.stray or check.refresh:
                record = check.record
                for rel in check.relink:
                    stage, task_id = record["files"][rel]["source"]
                    _link(shards.path(stage, task_id), root / rel)
                    linked = _same_file(root / rel, shards.path(stage, task_id))
                    record["files"][rel] = _file_record(root, rel, {**record["files"][rel], "linked": linked})
                for rel in check.stray:
                    (root / rel).unlink(missing_ok=True)
                for rel in check.refresh:
                    record["files"][rel] = _file_record(root, rel, record["files"][rel])
                write_text_atomic(record_path, json.dumps(record, indent=1, sort_keys=True) + "\n")
            return check.done_lines()
        record_path.unlink(missing_ok=True)  # a folder half made again has no record: the next run remakes it
        record = self._lay_out(params, shards, root, entry)
        write_text_atomic(record_path, json.dumps(record, indent=1, sort_keys=True) + "\n")
        return check.done_lines()

    def publish_status(self, params: DatasetTaskParams, shards: Upstream, dest: Path) -> list[str]:
        """What :meth:`publish` would repair (the same check), one line per file; empty when the folder is intact.
        A shard missing from ``shards`` is one the run remakes: the published file linked to it is damaged."""
        key = shards.key(self.name, "dataset") if "dataset" in shards.ids(self.name) else None
        root = Path(dest) / self.name
        check = check_published(root, _read_record(stage_dir(dest, self.name) / PUBLISH_RECORD), shards, key)
        return check.status_lines()

    def _lay_out(self, params: DatasetTaskParams, shards: Upstream, root: Path, entry: Entry) -> dict[str, Any]:
        """Publish the whole folder: links, config.yaml, ACRONYM files, card and plots; returns the publish record
        of the files laid out."""
        files: dict[str, dict[str, Any]] = {}
        sources: dict[str, tuple[str, str]] = {}

        def shard(stage: str, task_id: str, rel: str) -> None:
            e = shards.entry(stage, task_id)
            _link(shards.path(stage, task_id), root / rel)
            files[rel] = {"sha256": e.sha256, "bytes": e.bytes, "source": f"{stage}/{e.key}"}
            sources[rel] = (stage, task_id)

        shard(self.name, "dataset", "grasps.parquet")
        object_sets = [stage for stage in self.object_sets if stage in shards.ids(self.name)]
        for stage in object_sets:
            shard(self.name, stage, f"{stage}.parquet")
        scenes, left_out = included_scenes(shards, self.tables)
        for sid in scenes:
            shard("scenes", sid, f"scenes/{sid}.h5")
        for name in shards.ids("objects"):
            shard("objects", name, f"objects/{name}.h5")
        write_text_atomic(root / "config.yaml", config_yaml(params.config))
        add_file(files, root, "config.yaml")
        if self.probe and PROBE_TASK in shards.ids(self.probe):
            for rel in publish_probe(shards.path(self.probe, PROBE_TASK), root):
                add_file(files, root, rel)
        if params.dataset.acronym:  # ACRONYM's meaning (a free-space label per object grasp) where there is one
            export = export_object_acronym if "object_grasps" in object_sets else export_acronym
            for rel in export(root):
                add_file(files, root, rel)
        if params.dataset.graspgen and "object_grasps" in object_sets:
            for rel in export_graspgen(root):
                add_file(files, root, rel)
        stages = {
            stage: {
                "version": next(iter({shards.entry(stage, t).parts.get("stage", "") for t in shards.ids(stage)}), ""),
                "keys": {t: shards.key(stage, t) for t in shards.ids(stage)},
            }
            for stage in (*self.inputs, self.name)
        }
        warnings = [f"{stage}: {text}" for stage in (*self.inputs, self.name) for text in shards.warnings(stage)]
        provenance = {
            "dataset_key": entry.key,
            "tables": list(self.tables),
            "left_out": left_out,
            "warnings": warnings,
            "stages": stages,
            "versions": package_versions(),
            "config": to_dict(params.config),
            "scene_grasps": scene_grasp_counts(shards.meta("grasps", t) for t in shards.ids("grasps"))
            if "grasps" in self.inputs else None,
        }
        card = build_card(root, provenance, files, card_settings(params.dataset))  # also removes stray files
        record: dict[str, Any] = {"dataset_key": entry.key, "card_version": CARD_VERSION, "files": {}}
        for rel, info in card["files"].items():
            known = {"sha256": info["sha256"]}
            if rel in sources:
                stage, task_id = sources[rel]
                known["source"] = [stage, task_id]
                known["linked"] = _same_file(root / rel, shards.path(stage, task_id))
            record["files"][rel] = _file_record(root, rel, known)
        for rel in CARD_FILES:
            record["files"][rel] = _file_record(root, rel, {"sha256": sha256_file(root / rel)})
        return record


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


PUBLISH_RECORD = "published.json"
"""The publish step's record of the files it laid out: ``OUT/shards/dataset/published.json``, with the engine's
files of the stage (it describes files on one disk, not the data, so it is not part of the dataset). Per file
(relative to ``OUT/dataset``): ``bytes``, ``mtime_ns``, ``ino``, ``dev``, ``sha256``, and for a shard's link its
``source`` ``[stage, task id]`` and whether it is ``linked`` (a hard link) or a copy."""

CARD_FILES = ("card.json", "card.md")
"""Published files that card.json does not list (itself and its rendering)."""


def _read_record(path: Path) -> dict[str, Any] | None:
    try:
        record = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    return record if isinstance(record, dict) and isinstance(record.get("files"), dict) else None


def _file_record(root: Path, rel: str, known: Mapping[str, Any]) -> dict[str, Any]:
    """``known`` (sha256, source, linked) with the file's size, mtime and inode as they are now."""
    st = os.stat(root / rel)
    return {**known, "bytes": st.st_size, "mtime_ns": st.st_mtime_ns, "ino": st.st_ino, "dev": st.st_dev}


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _unchanged(st: os.stat_result, info: Mapping[str, Any]) -> bool:
    """The file's size, mtime and inode are those the record holds (the fast check: no read)."""
    return (st.st_size, st.st_mtime_ns, st.st_ino, st.st_dev) == tuple(
        info.get(k) for k in ("bytes", "mtime_ns", "ino", "dev")
    )


@dataclasses.dataclass
class PublishCheck:
    """What :func:`check_published` found in a published folder, and what :meth:`DatasetStage.publish` does."""

    record: dict[str, Any] = dataclasses.field(default_factory=dict)
    """The publish record read (updated by publish when it repairs)."""
    remake: str | None = None
    """The whole folder is laid out: :data:`FIRST` (no folder yet), :data:`OTHER` (it shows another dataset
    shard) or why (no record of its files, another card version). None: it is repaired file by file."""
    problems: list[tuple[str, str]] = dataclasses.field(default_factory=list)
    """``(path, what)``: missing, damaged or not part of the dataset."""
    relink: list[str] = dataclasses.field(default_factory=list)
    """Shards' links to make again."""
    stray: list[str] = dataclasses.field(default_factory=list)
    """Files in the dataset's folders that the dataset does not list: removed."""
    refresh: list[str] = dataclasses.field(default_factory=list)
    """Files with another mtime or inode but their recorded sha256 (rewritten with the same bytes, e.g. by
    ``gen report``): only their record is updated."""
    rebuild: bool = False
    """A file that is not a shard's link is damaged or missing: the whole folder is laid out again."""

    def status_lines(self) -> list[str]:
        """For ``gen status``: what a run will do."""
        if self.remake == FIRST:
            return ["not published yet (will be)"]
        if self.remake == OTHER:
            return ["the folder holds another dataset (will be made again)"]
        if self.remake is not None:
            return [f"the folder will be made again ({self.remake})"]
        lines = [f"{rel} {what} (will be {'removed' if what == STRAY else 'replaced'})" for rel, what in self.problems]
        return _at_most(lines, "file(s) more to repair")

    def done_lines(self) -> list[str]:
        """For the run's report: what publish did (a first or new dataset's publish is no repair: nothing)."""
        if self.remake in (FIRST, OTHER):
            return []
        if self.remake is not None:
            return [f"made the folder again ({self.remake})"]
        lines = [f"{'removed' if what == STRAY else 'replaced'} {rel} ({what})" for rel, what in self.problems]
        return _at_most(lines, "file(s) more repaired")


STRAY = "not part of the dataset"
PROBLEMS_LISTED = 8
"""At most this many files are named in the lines of a :class:`PublishCheck`; the rest are counted."""


def _at_most(lines: list[str], more: str) -> list[str]:
    if len(lines) <= PROBLEMS_LISTED:
        return lines
    return lines[: PROBLEMS_LISTED - 1] + [f"{len(lines) - PROBLEMS_LISTED + 1} {more}"]
FIRST = "first"
OTHER = "other"


def _card_key(root: Path) -> str | None:
    try:
        return json.loads((root / "card.json").read_text()).get("dataset_key")
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError):
        return None


def check_published(root: Path, record: dict[str, Any] | None, shards: Upstream, key: str | None) -> PublishCheck:
    """Compare a published dataset folder with its publish record, fast: stats, no reads (module docstring).

    A shard's link is intact when it is the shard's file (same inode) with the shard's size; the shards in
    ``shards`` are the ones the run verified, so this costs nothing. A link whose shard is not in ``shards`` (a
    damaged shard the run remakes) is damaged. Any other file is intact when its size, mtime and inode are the
    recorded ones; when they are not, its sha256 decides (so a file rewritten with the same bytes is not
    replaced). ``key`` is the dataset shard's key (None when it is not known: it is being remade).
    """
    check = PublishCheck(record=record or {})
    if record is None:
        if not (root / "card.json").exists():
            check.remake = FIRST
        elif key is not None and _card_key(root) != key:
            check.remake = OTHER
        else:
            check.remake = "the folder has no record of its files"
    elif key is not None and record.get("dataset_key") != key:
        check.remake = OTHER
    elif not root.is_dir():
        check.remake = "the folder is missing"
    elif record.get("card_version") != CARD_VERSION:
        check.remake = "the card's version changed"
    if check.remake is not None:
        return check
    files: dict[str, Any] = record["files"]
    for rel, info in files.items():
        try:
            st = os.stat(root / rel)
        except OSError:
            st = None
        source = info.get("source")
        if source is not None:
            stage, task_id = source
            entry = shards.entry(stage, task_id) if stage in shards.stages() and task_id in shards.ids(stage) else None
            if st is None or entry is None:
                check.problems.append((rel, "missing" if st is None else "damaged"))
                check.relink.append(rel)
                if entry is not None and entry.sha256 != info.get("sha256"):
                    check.rebuild = True  # the shard was remade with other bytes: the card changes too
                continue
            shard_st = os.stat(shards.path(stage, task_id))
            if (st.st_ino, st.st_dev) == (shard_st.st_ino, shard_st.st_dev) and st.st_size == entry.bytes:
                continue
            if not info.get("linked") and _unchanged(st, info):
                continue  # a copy (no hard links there), untouched since it was made
            if st.st_size != entry.bytes or sha256_file(root / rel) != entry.sha256:
                check.problems.append((rel, "damaged"))
                check.relink.append(rel)
            elif info.get("linked"):
                check.relink.append(rel)  # an intact separate copy of a linked file: linked again, silently
            else:
                check.refresh.append(rel)
            if entry.sha256 != info.get("sha256"):
                check.rebuild = True
            continue
        if st is None:
            check.problems.append((rel, "missing"))
            check.rebuild = True
        elif not _unchanged(st, info):
            if sha256_file(root / rel) == info.get("sha256"):
                check.refresh.append(rel)
            else:
                check.problems.append((rel, "damaged"))
                check.rebuild = True
    for sub in MANAGED:
        try:
            found = sorted(os.scandir(root / sub), key=lambda d: d.name)
        except OSError:
            continue
        for item in found:
            rel = f"{sub}/{item.name}"
            if rel not in files and not item.name.startswith(".") and item.is_file(follow_symlinks=False):
                check.problems.append((rel, STRAY))
                check.stray.append(rel)
    return check


# ---------------------------------------------------------------------------------------------------------------
# gen validate
# ---------------------------------------------------------------------------------------------------------------


def validate(path: str | Path) -> tuple[list[str], int]:
    """Check a published dataset (and, when ``path`` is a run folder, every stage's shards).

    Checks: every manifest entry's shard exists with its recorded size and sha256; every file listed in
    ``card.json`` exists with its sha256 and no other file sits in the dataset's folders; grasps.parquet has the
    schema of the card and the required columns and types (:data:`graspgen.io.dataset_table.REQUIRED_SCHEMA`),
    rows sorted and unique by (scene_id, grasp_id), outcome codes and names that agree, labels in range, rigid
    poses; every scene and object it names has its file (:func:`graspgen.io.dataset_table.check_table`); card.md is
    the rendering of card.json.

    Returns
    -------
    (problems, files_checked)
        Each problem starts with the path of the file at fault.
    """
    root = dataset_dir(path)
    problems: list[str] = []
    checked = 0
    run_root = root.parent if (root.parent / SHARDS).is_dir() else None
    if run_root is not None:
        for manifest_path in sorted((run_root / SHARDS).glob(f"*/{MANIFEST}")):
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
    for sub in MANAGED:
        for f in sorted((root / sub).glob("*")) if (root / sub).is_dir() else []:
            rel = f.relative_to(root).as_posix()
            if f.is_file() and rel not in listed and not f.name.startswith("."):
                problems.append(f"{f}: not part of the dataset (not listed in card.json)")
    problems += check_table(root, card)
    try:
        if (root / "card.md").read_text() != render_card(card):
            problems.append(f"{root / 'card.md'}: is not the rendering of card.json (run gen report)")
    except OSError:
        problems.append(f"{root / 'card.md'}: missing")
    return problems, checked
