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

and nothing else: the engine's shards and manifest of this stage are in ``OUT/shards/dataset/``, so copying or archiving
``OUT/dataset`` hands over exactly the published files. The card is :mod:`graspgen.io.card`
(:func:`graspgen.io.card.report` renders it and the plots of :mod:`graspgen.viz.plots` again from a published folder:
``gen report``); :func:`validate` checks a folder against the manifests, the card's hashes and the schema (``gen
validate``). Read a dataset with
:func:`graspgen.io.reader.open_dataset`.

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
import json
import os
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from graspgen.io.acronym import export_acronym
from graspgen.io.card import (
    CARD_VERSION,
    MANAGED,
    CardSettings,
    add_file,
    build_card,
    package_versions,
    render_card,
)
from graspgen.io.dataset_table import (
    FORMAT,
    META_KEY,
    TABLES,
    check_table,
    dataset_dir,
    join_scene,
    write_grasps_parquet,
)
from graspgen.validation import check
from pipeline.config import to_dict, to_yaml
from pipeline.errors import StageError
from pipeline.keys import canonical_json, sha256_file
from pipeline.stage import RunContext, Task, Upstream
from pipeline.store import MANIFEST, SHARDS, Manifest, atomic_path, write_text_atomic
from stages.base import GraspStage

__all__ = [
    "DatasetParams",
    "DatasetStage",
    "DatasetTaskParams",
    "config_yaml",
    "included_scenes",
    "validate",
]

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
    """

    name = "dataset"
    version = 1
    ext = "parquet"
    published = ("dataset",)

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
            "format": FORMAT,
            "tables": list(self.tables),
            "config": to_dict(params.config),
        }
        rows = write_grasps_parquet(
            out,
            merged,
            row_group_rows=params.dataset.row_group_rows,
            metadata={META_KEY: canonical_json(meta).encode()},
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
        add_file(files, root, "config.yaml")
        if params.dataset.acronym:
            for rel in export_acronym(root):
                add_file(files, root, rel)
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
        build_card(root, provenance, files, card_settings(params.dataset))  # also removes an earlier dataset's files


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
