"""Stage 7, ``dataset``: the per-scene shards merged into the published dataset with its card.

One task joins the per-scene tables of :data:`graspgen.io.dataset_table.TABLES` on ``(scene_id, grasp_id)``
(:func:`graspgen.io.dataset_table.join_scene`), scene by scene in id order, into row groups of whole scenes
(:class:`graspgen.io.row_groups.GroupedParquetWriter`), so the task holds one row group, not the table; only scenes
with a shard in every table stage are included. Each object-set stage is one more task. After the commit,
:meth:`DatasetStage.publish` lays out ``OUT/dataset/`` (layout, and how the folder heals: docs/format.md,
"The published dataset"), with the card of :mod:`graspgen.io.card` and the plots of :mod:`graspgen.viz.plots`
(:func:`make_card`); :func:`report` renders them again (``gen report``), :func:`validate` checks a folder
(``gen validate``). The columns are listed in :mod:`graspgen.io.dataset_table`.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from graspgen.errors import InputError
from graspgen.io.acronym_export import export_acronym, export_object_acronym
from graspgen.io.card import CARD_VERSION, add_file, card_sources, package_versions, write_card
from graspgen.io.card_grasps import scene_grasp_counts
from graspgen.io.card_stats import CardSettings, card_stats
from graspgen.io.contact_graspnet import export_contact_graspnet
from graspgen.io.dataset_table import (
    FORMAT,
    META_KEY,
    TABLES,
    GroupedParquetWriter,
    dataset_dir,
    join_scene,
    write_grasps_parquet,
)
from graspgen.io.nvidia_graspgen import export_graspgen
from graspgen.io.probe_files import publish_probe
from graspgen.io.publish_check import (
    ShardFile,
    ShardLookup,
    check_folder,
    check_published,
    file_record,
    link_file,
    read_record,
    same_file,
)
from graspgen.validation import check_bool, check_positive_int
from graspgen.viz.plots import draw_plots
from pipeline.config import FLATTEN, to_dict, to_yaml
from pipeline.errors import StageError
from pipeline.keys import canonical_json, sha256_file
from pipeline.stage import RunContext, Task, Upstream
from pipeline.store import MANIFEST, SHARDS, Entry, Manifest, stage_dir, write_text_atomic
from stages.base import GraspStage

__all__ = [
    "DatasetParams",
    "DatasetStage",
    "DatasetTaskParams",
    "config_yaml",
    "included_scenes",
    "make_card",
    "report",
    "validate",
]

OBJECT_SETS = ("object_grasps", "placed_grasps")
"""Stages whose shards are published as they are, concatenated, one table each: ``object_grasps.parquet`` (the
object-centric grasp sets, by object) and ``placed_grasps.parquet`` (those sets placed in the scenes, by scene)."""

OBJECT_SET_META = ("tried", "positives", "negatives", "target_positives", "target_negatives", "reached", "selection",
                   "label", "target_grasps", "positive_rate", "collisions_dropped", "friction")
"""Keys of an object-grasps task's manifest meta kept in ``object_grasps.parquet``'s metadata (under
:data:`graspgen.io.dataset_table.META_KEY`); timings are left out so the bytes do not differ between runs."""

PROBE = "probe"
"""The learnability probe's stage (:mod:`stages.probe`); PROBE_TASK is its one task."""
PROBE_TASK = "probe"

PROVENANCE_STAGE = "rollouts"
"""``source_key`` holds the key of this stage's shard of the scene (the last table stage when it is not joined)."""

PUBLISH_RECORD = "published.json"
"""The publish record (:mod:`graspgen.io.publish_check`), ``OUT/shards/dataset/published.json``: it describes files on
one disk, so it lives with the engine's files, not in the dataset."""

CARD_FILES = ("card.json", "card.md")
"""Published files that card.json does not list (itself and its rendering)."""


# ---------------------------------------------------------------------------------------------------------------
# Params
# ---------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class DatasetParams:
    """Settings of the ``dataset`` stage (config section ``dataset``; the card's keys sit at its level)."""

    row_group_rows: int = 16384
    """Rows per Parquet row group, about: whole scenes are packed into a group until the next would pass this (a
    larger scene gets a group of its own)."""
    acronym: bool = True
    """Also export each object's grasps as an ACRONYM file (acronym/<object>.h5) with its mesh as OBJ: its
    object-centric set when the object_grasps stage ran, else its scene grasps."""
    graspgen: bool = True
    """Also export the object-centric sets in GraspGen's dataset layout (graspgen/: splits and one JSON per
    object; :mod:`graspgen.io.nvidia_graspgen`)."""
    contact_graspnet: bool = True
    """Also export the scenes as Contact-GraspNet's training data (contact_graspnet/: per-scene .npz, meshes, splits;
    :mod:`graspgen.io.contact_graspnet`)."""
    card: CardSettings = dataclasses.field(default_factory=CardSettings, metadata={FLATTEN: True})
    """The card and its plots (:class:`graspgen.io.card_stats.CardSettings`: ``plots``, ``histogram_bins``,
    ``example_scenes``, ``example_grasps``, written at this section's level)."""

    def __post_init__(self) -> None:
        check_positive_int("row_group_rows", self.row_group_rows)
        check_bool("acronym", self.acronym)
        check_bool("graspgen", self.graspgen)
        check_bool("contact_graspnet", self.contact_graspnet)


@dataclasses.dataclass(frozen=True)
class DatasetTaskParams:
    """What the ``dataset`` task and its publish step see: its own section and the resolved config (the card shows it
    all); ``run`` is left out because it never enters a key."""

    dataset: DatasetParams
    """The ``dataset`` section."""
    config: Mapping[str, Any]
    """Every section of the resolved config except ``run``, by name (dataclasses), in the schema's order."""


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


def _shard_lookup(shards: Upstream) -> ShardLookup:
    """The verified shards of ``shards`` as :func:`graspgen.io.publish_check.check_published` looks them up."""

    def lookup(stage: str, task_id: str) -> ShardFile | None:
        if stage not in shards.stages() or task_id not in shards.ids(stage):
            return None
        entry = shards.entry(stage, task_id)
        return ShardFile(path=shards.path(stage, task_id), sha256=entry.sha256, bytes=entry.bytes)

    return lookup


def _write_record(path: Path, record: Mapping[str, Any]) -> None:
    write_text_atomic(path, json.dumps(record, indent=1, sort_keys=True) + "\n")


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
        """Lay out ``dest/dataset``, or repair it against the publish record when it already shows this shard (damaged
        links remade, stray files removed, any other damaged file lays the folder out again); returns what it
        repaired."""
        if "dataset" not in shards.ids(self.name):
            return []  # the task failed: leave the last good folder as it is
        entry = shards.entry(self.name, "dataset")
        root = Path(dest) / self.name
        record_path = stage_dir(dest, self.name) / PUBLISH_RECORD
        check = check_published(root, read_record(record_path), _shard_lookup(shards), entry.key)
        if check.remake is None and not check.rebuild:
            if check.relink or check.stray or check.refresh:
                record = check.record
                for rel in check.relink:
                    stage, task_id = record["files"][rel]["source"]
                    link_file(shards.path(stage, task_id), root / rel)
                    linked = same_file(root / rel, shards.path(stage, task_id))
                    record["files"][rel] = file_record(root, rel, {**record["files"][rel], "linked": linked})
                for rel in check.stray:
                    (root / rel).unlink(missing_ok=True)
                for rel in check.refresh:
                    record["files"][rel] = file_record(root, rel, record["files"][rel])
                _write_record(record_path, record)
            return check.done_lines()
        record_path.unlink(missing_ok=True)  # a folder half made again has no record: the next run remakes it
        _write_record(record_path, self._lay_out(params, shards, root, entry))
        return check.done_lines()

    def publish_status(self, params: DatasetTaskParams, shards: Upstream, dest: Path) -> list[str]:
        """What :meth:`publish` would repair (the same check), one line per file; empty when the folder is intact.
        A shard missing from ``shards`` is one the run remakes: the published file linked to it is damaged."""
        key = shards.key(self.name, "dataset") if "dataset" in shards.ids(self.name) else None
        root = Path(dest) / self.name
        record = read_record(stage_dir(dest, self.name) / PUBLISH_RECORD)
        return check_published(root, record, _shard_lookup(shards), key).status_lines()

    def _lay_out(self, params: DatasetTaskParams, shards: Upstream, root: Path, entry: Entry) -> dict[str, Any]:
        """Publish the whole folder: links, config.yaml, ACRONYM files, card and plots; returns the publish record
        of the files laid out."""
        files: dict[str, dict[str, Any]] = {}
        sources: dict[str, tuple[str, str]] = {}
        object_sets = self._link_shards(shards, root, files, sources)
        write_text_atomic(root / "config.yaml", config_yaml(params.config))
        add_file(files, root, "config.yaml")
        if self.probe and PROBE_TASK in shards.ids(self.probe):
            for rel in publish_probe(shards.path(self.probe, PROBE_TASK), root):
                add_file(files, root, rel)
        for rel in _exports(root, params.dataset, object_sets):
            add_file(files, root, rel)
        card = make_card(root, self._provenance(params, shards, entry), files, params.dataset.card)
        record: dict[str, Any] = {"dataset_key": entry.key, "card_version": CARD_VERSION, "files": {}}
        for rel, info in card["files"].items():
            known = {"sha256": info["sha256"]}
            if rel in sources:
                stage, task_id = sources[rel]
                known["source"] = [stage, task_id]
                known["linked"] = same_file(root / rel, shards.path(stage, task_id))
            record["files"][rel] = file_record(root, rel, known)
        for rel in CARD_FILES:
            record["files"][rel] = file_record(root, rel, {"sha256": sha256_file(root / rel)})
        return record

    def _link_shards(self, shards: Upstream, root: Path, files: dict[str, dict[str, Any]],
                     sources: dict[str, tuple[str, str]]) -> list[str]:
        """Link the published shards (the tables, the included scenes, the objects) into ``root``, listed in
        ``files`` and ``sources``; returns the object-set stages published."""

        def shard(stage: str, task_id: str, rel: str) -> None:
            e = shards.entry(stage, task_id)
            link_file(shards.path(stage, task_id), root / rel)
            files[rel] = {"sha256": e.sha256, "bytes": e.bytes, "source": f"{stage}/{e.key}"}
            sources[rel] = (stage, task_id)

        shard(self.name, "dataset", "grasps.parquet")
        object_sets = [stage for stage in self.object_sets if stage in shards.ids(self.name)]
        for stage in object_sets:
            shard(self.name, stage, f"{stage}.parquet")
        scenes, _ = included_scenes(shards, self.tables)
        for sid in scenes:
            shard("scenes", sid, f"scenes/{sid}.h5")
        for name in shards.ids("objects"):
            shard("objects", name, f"objects/{name}.h5")
        return object_sets

    def _provenance(self, params: DatasetTaskParams, shards: Upstream, entry: Entry) -> dict[str, Any]:
        """What the card says of the run that made the data: keys, versions, warnings, config, sampling counts."""
        stages = {
            stage: {
                "version": next(iter({shards.entry(stage, t).parts.get("stage", "") for t in shards.ids(stage)}), ""),
                "keys": {t: shards.key(stage, t) for t in shards.ids(stage)},
            }
            for stage in (*self.inputs, self.name)
        }
        warnings = [f"{stage}: {text}" for stage in (*self.inputs, self.name) for text in shards.warnings(stage)]
        return {
            "dataset_key": entry.key,
            "tables": list(self.tables),
            "left_out": included_scenes(shards, self.tables)[1],
            "warnings": warnings,
            "stages": stages,
            "versions": package_versions(),
            "config": to_dict(params.config),
            "scene_grasps": scene_grasp_counts(shards.meta("grasps", t) for t in shards.ids("grasps"))
            if "grasps" in self.inputs else None,
        }


def _exports(root: Path, params: DatasetParams, object_sets: Sequence[str]) -> list[str]:
    """Write the ACRONYM, GraspGen and Contact-GraspNet exports the params ask for; returns the files written
    (relative)."""
    written: list[str] = []
    if params.acronym:  # ACRONYM's meaning (a free-space label per object grasp) where there is one
        export = export_object_acronym if "object_grasps" in object_sets else export_acronym
        written += export(root)
    if params.graspgen and "object_grasps" in object_sets:
        written += export_graspgen(root)
    if params.contact_graspnet:
        written += export_contact_graspnet(root)
    return written


def config_yaml(sections: Mapping[str, Any]) -> str:
    """The resolved config as YAML with every key's description (as ``gen config show --all``), ``run`` left out."""
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
# The card, gen report, gen validate
# ---------------------------------------------------------------------------------------------------------------


def make_card(root: Path, provenance: Mapping[str, Any], files: Mapping[str, Any], settings: CardSettings) -> dict:
    """The card of the dataset folder ``root``: statistics, plots (when ``settings.plots``), ``card.json`` /
    ``card.md``; ``files`` maps data files (relative path) to sha256 and bytes. Returns what card.json holds."""
    stats, table = card_stats(root, files, settings)
    files = dict(files)
    plots = draw_plots(root, table, stats, settings) if settings.plots else []
    for rel in plots:
        add_file(files, root, rel)
    return write_card(root, provenance, files, stats, plots)


def report(path: str | Path) -> Path:
    """Render ``card.md``, ``card.json`` and the plots of a published dataset again; returns the card.md path. What the
    data cannot tell (keys, config, versions, hashes) comes from the existing ``card.json``, so an intact folder gets
    its published card, byte for byte.

    Raises
    ------
    graspgen.errors.InputError
        No dataset there; card.json unreadable or incomplete; a data file missing, truncated or unreadable.
    """
    sources = card_sources(path)
    root = sources.root
    try:
        make_card(root, sources.provenance, sources.data_files, sources.settings)
    except pa.ArrowException as exc:  # same size but damaged
        raise InputError(f"{root / 'grasps.parquet'}: cannot be read ({exc}); gen validate {path} says more") from None
    return root / "card.md"


def _check_shards(run_root: Path) -> tuple[list[str], int]:
    """Every manifest entry's shard in ``run_root`` exists with its recorded size and sha256."""
    problems: list[str] = []
    checked = 0
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
    return problems, checked


def validate(path: str | Path) -> tuple[list[str], int]:
    """Check a published dataset (and, when ``path`` is a run folder, every stage's shards): shard sizes and sha256s,
    the card's files and no others, the table's schema, sort order and labels and the files it names
    (:func:`graspgen.io.dataset_table.check_table`), card.md rendered from card.json.

    Returns
    -------
    (problems, files_checked)
        Each problem starts with the path of the file at fault.
    """
    root = dataset_dir(path)
    problems, checked = _check_shards(root.parent) if (root.parent / SHARDS).is_dir() else ([], 0)
    found, listed = check_folder(root)
    return problems + found, checked + listed
