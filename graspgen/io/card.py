"""The dataset card of a published dataset: ``card.json`` (the statistics and provenance as data) and ``card.md``.

:func:`build_card` computes, from the files in a dataset folder, the counts per object and outcome, each label's
summary and histogram (:func:`label_summary`) and the labels' correlations (:func:`card_stats`), draws the plots
(:func:`graspgen.viz.plots.draw_plots`) and writes ``card.json`` and its Markdown rendering ``card.md``
(:func:`render_card`, a pure function of card.json). What the files cannot tell (the shard keys, the config, the
package versions, the data files' hashes) comes in as ``provenance`` and ``files``. :func:`report` renders a
published card again from its folder.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import platform
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import yaml

from graspgen.errors import InputError
from graspgen.io.atomic import write_text_atomic
from graspgen.io.card_grasps import scene_grasps_lines
from graspgen.io.card_learn import learnability, learnability_lines
from graspgen.io.card_tally import CardTable, GraspTally, ObjectSetTally, PlacedTally, row_groups
from graspgen.io.dataset_table import FORMAT, META_KEY, OUTCOME_NAMES, dataset_dir
from graspgen.io.files import sha256_file
from graspgen.validation import check

__all__ = [
    "CARD_VERSION",
    "LABEL_COLUMNS",
    "MANAGED",
    "CardSettings",
    "add_file",
    "build_card",
    "card_stats",
    "fmt",
    "keys_digest",
    "label_summary",
    "package_versions",
    "render_card",
    "report",
]

LABEL_COLUMNS = ("robustness", "epsilon", "pfc", "min_closure_friction")
"""Numeric labels the card summarises (those present)."""

CORRELATED = ("robustness", "epsilon", "pfc")
"""Labels whose pairwise correlations the card reports."""

DISCRETE_LABEL_VALUES = 32
"""A label with at most this many distinct values is counted per value (robustness and pfc of up to 31 copies, a
friction grid), not binned."""

CARD_VERSION = 4
"""Bump when the card's content or the plots change: published folders are then re-rendered."""

MANAGED = ("scenes", "objects", "acronym", "acronym/meshes", "plots", "graspgen", "graspgen/objects", "probe")
"""Subfolders of a dataset folder that the card owns: files there that it does not list are not part of the
dataset, and :func:`build_card` removes them."""


@dataclasses.dataclass(frozen=True)
class CardSettings:
    """What the card and its plots read of the ``dataset`` config section (the same names and checks)."""

    plots: bool = True
    """Draw the card's plots (plots/*.png, with matplotlib)."""
    histogram_bins: int = 20
    """Bins of the label histograms (card and plots) for labels with more than 32 distinct values."""
    example_scenes: int = 4
    """Scenes in the examples contact sheet (the first ones by id that have RGB images)."""
    example_grasps: int = 24
    """At most this many grasps drawn per example scene, spread over the outcomes."""

    def __post_init__(self) -> None:
        check("histogram_bins", 1 <= self.histogram_bins <= 1000, "be in [1, 1000]", self.histogram_bins)
        check("example_scenes", self.example_scenes >= 0, "be >= 0", self.example_scenes)
        check("example_grasps", self.example_grasps >= 0, "be >= 0", self.example_grasps)


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


def _correlations(values: Mapping[str, np.ndarray]) -> dict[str, Any]:
    """Pearson and Spearman correlations (and pair counts) of the :data:`CORRELATED` labels in ``values`` (each a
    (rows,) float64 array, NaN where undefined, rows aligned)."""
    cols = [c for c in CORRELATED if c in values]
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


TALLY_COLUMNS = ("scene_id", "object_name", "outcome", "gripper")
"""The columns of grasps.parquet the counts read (with the labels)."""


def card_stats(root: Path, files: Mapping[str, Any], settings: CardSettings) -> tuple[dict[str, Any], CardTable]:
    """Counts, label summaries and correlations of the dataset in ``root`` whose data files are ``files`` (relative
    paths; the scenes and objects are those listed, not whatever else sits in the folder); also returns what the
    plots read of the table (:class:`graspgen.io.card_tally.CardTable`).

    grasps.parquet is read one row group at a time into running counts (:class:`GraspTally`); only the label
    columns are kept whole (as float64 arrays: their quantiles and rank correlations need every value)."""
    path = root / "grasps.parquet"
    schema = pq.read_schema(path)
    labels = [c for c in LABEL_COLUMNS if c in schema.names]
    tally = GraspTally(labels)
    for group in row_groups(path, [c for c in schema.names if c in (*TALLY_COLUMNS, *labels)]):
        tally.add(group)
    scenes: dict[str, Any] = {}
    for scene_path in sorted(root / rel for rel in files if rel.startswith("scenes/")):
        with h5py.File(scene_path, "r") as f:
            names = f.attrs["object_names"]
            names = json.loads(names.decode() if isinstance(names, bytes) else names) if not isinstance(
                names, np.ndarray) else names.tolist()
            scenes[scene_path.stem] = {
                "grasps": tally.scenes.get(scene_path.stem, 0),
                "objects": [str(n) for n in names],
                "views": int(f["cameras/K"].shape[0]),
            }
    library = sorted(Path(rel).stem for rel in files if rel.startswith("objects/"))
    per_object = {}
    for name in library:
        row = tally.objects.get(name, np.zeros(len(OUTCOME_NAMES) + 1, np.int64))
        counts = [int(n) for n in row[: len(OUTCOME_NAMES)]]
        n = int(row[len(OUTCOME_NAMES)])
        per_object[name] = {
            "scenes": sum(name in s["objects"] for s in scenes.values()),
            "grasps": n,
            "outcomes": counts,
            "success_rate": _num(counts[5] / n) if n else None,
        }
    values = {c: tally.values(c) for c in labels}
    summaries = {
        col: label_summary(values[col], settings.histogram_bins, col in ("robustness", "pfc")) for col in labels
    }
    stats = {
        "counts": {
            "grasps": tally.rows,
            "scenes": len(scenes),
            "views": sum(s["views"] for s in scenes.values()),
            "objects": len(library),
            "objects_with_grasps": int(sum(1 for o in per_object.values() if o["grasps"])),
            "grippers": sorted(tally.grippers),
        },
        "outcomes": [
            {"code": c, "name": name, "grasps": int(tally.outcomes[c])} for c, name in enumerate(OUTCOME_NAMES)
        ],
        "objects": per_object,
        "scenes": scenes,
        "labels": summaries,
        "correlation": _correlations(values),
    }
    del values
    sets = object_set_stats(root, files)
    if sets:
        stats["object_sets"] = sets
    return stats, CardTable(path, _card_columns(schema), tally)


OBJECT_SET_FILES = ("object_grasps.parquet", "placed_grasps.parquet")
"""The object-centric tables a dataset may hold besides grasps.parquet."""


def _rate(k: int, n: int) -> float | None:
    return _num(k / n) if n else None


def object_set_stats(root: Path, files: Mapping[str, Any]) -> dict[str, Any]:
    """What the card says of the object-centric sets, when ``files`` lists them (else an empty dict).

    ``objects``: per object the grasps kept, positives and negatives, the targets and the candidates tried (from
    the file's metadata: how far each object's set got), the success rate among the kept antipodal and near-miss
    candidates. ``placed``: the placed scene grasps, how many are free of the support and the neighbours, how many
    are positives (object-level success and free), and the re-simulation check: how many were rolled out again in
    their scene and how often the label changed (both ways). Both files are read one row group at a time into
    running counts (:mod:`graspgen.io.card_tally`).
    """
    out: dict[str, Any] = {}
    if "object_grasps.parquet" in files:
        path = root / "object_grasps.parquet"
        meta = json.loads((pq.read_schema(path).metadata or {}).get(META_KEY, b"{}")).get("tasks", {})
        sets = ObjectSetTally()
        for group in row_groups(path, ["object_name", "candidate", "success"]):
            sets.add(group)
        objects = {}
        for name in sorted(set(sets.objects) | set(meta)):
            grasps, positives, near, near_ok = (int(v) for v in sets.objects.get(name, np.zeros(4, np.int64)))
            m = meta.get(name, {})
            objects[name] = {
                "grasps": grasps,
                "positives": positives,
                "negatives": grasps - positives,
                "target_positives": m.get("target_positives"),
                "target_negatives": m.get("target_negatives"),
                "tried": m.get("tried"),
                "reached": m.get("reached"),
                "near_miss": near,
                "near_miss_success_rate": _rate(near_ok, near),
            }
        out["objects"] = objects
    if "placed_grasps.parquet" in files:
        placed = PlacedTally()
        for group in row_groups(root / "placed_grasps.parquet", ["scene_id", "scene_code", "object_success",
                                                                  "success", "rescene_outcome", "rescene_success"]):
            placed.add(group)
        n = placed.counts
        out["placed"] = {
            "grasps": n["grasps"],
            "scenes": len(placed.scenes),
            "free": n["free"],
            "support_collisions": n["support_collisions"],
            "clutter_collisions": n["clutter_collisions"],
            "positives": n["positives"],
            "rescene_checked": n["checked"],
            "rescene_changed": n["changed"],
            "rescene_change_rate": _rate(n["changed"], n["checked"]),
            "rescene_lost": _rate(n["lost"], n["pos"]),
            "rescene_gained": _rate(n["gained"], n["neg"]),
        }
    return out


def _schema_doc(schema: pa.Schema) -> list[dict[str, str]]:
    return [
        {
            "name": f.name,
            "type": str(f.type),
            "description": (f.metadata or {}).get(b"description", b"").decode(),
        }
        for f in schema
    ]


def build_card(root: Path, provenance: Mapping[str, Any], files: Mapping[str, Any], settings: CardSettings) -> dict:
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
    settings : CardSettings
    """
    stats, table = card_stats(root, files, settings)
    files = dict(files)
    plots = []
    if settings.plots:
        from graspgen.viz.plots import draw_plots  # matplotlib and the picture code only when plots are drawn

        plots = draw_plots(root, table, stats, settings)
        for rel in plots:
            add_file(files, root, rel)
    schema = pq.read_schema(root / "grasps.parquet")
    card = {
        "format": FORMAT,
        "card_version": CARD_VERSION,
        "dataset_key": provenance["dataset_key"],
        "tables": list(provenance["tables"]),
        **stats,
        "left_out": dict(provenance["left_out"]),
        "warnings": [str(w) for w in provenance.get("warnings", [])],
        "schema": _schema_doc(schema),
        "plots": plots,
        "learnability": learnability(root, files, provenance["config"], provenance.get("warnings", [])),
        "scene_grasps": provenance.get("scene_grasps"),  # per-object sampling counts (graspgen.io.card_grasps)
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


def keys_digest(keys: Mapping[str, str]) -> str:
    """First 16 hex digits of the sha256 of a stage's shard keys (``{task id: key}``) as compact, sorted-key JSON:
    the text the engine's canonical JSON gives for such a mapping, so the card shows the same digest."""
    text = json.dumps(dict(keys), sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def fmt(x: Any, digits: int = 3) -> str:
    """A card cell: ``-`` for None, a float to ``digits`` significant digits, anything else as str."""
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
    sets = card.get("object_sets", {})
    if "objects" in sets:
        lines.append("| `object_grasps.parquet` | each object's object-centric grasp set: grasps over the whole object "
                     "labelled in free space |")
    if "placed" in sets:
        lines.append("| `placed_grasps.parquet` | those sets placed in the scenes, kept or rejected by a collision "
                     "check against the support and the neighbours |")
    if any(k.startswith("acronym/") for k in card["files"]):
        what = "object-centric set (free-space labels)" if "objects" in sets else "grasps"
        lines.append(f"| `acronym/<name>.h5` | each object's {what} in the ACRONYM format (mesh: `acronym/meshes/`) |")
    if any(k.startswith("graspgen/") for k in card["files"]):
        lines.append("| `graspgen/` | the object-centric sets in GraspGen's layout (splits, one JSON per object) |")
    if any(k.startswith("probe/") for k in card["files"]):
        lines.append("| `probe/` | `model.pt`, a grasp evaluator trained on the object sets, and `report.json`, its "
                     "held-out scores (Learnability, below) |")
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
    lines += _object_set_lines(sets)
    lines += learnability_lines(card.get("learnability"))
    lines += scene_grasps_lines(card.get("scene_grasps"))
    lines += ["## Labels", ""]
    if card["labels"]:
        lines += [
            "Over the grasps where the label is defined (robustness and pfc: successful grasps).",
            "",
            "| label | n | mean | std | min | 5% | median | 95% | max |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
        ]
        for name, s in card["labels"].items():
            cells = [fmt(s.get(k)) for k in ("mean", "std", "min", "p05", "median", "p95", "max")]
            lines.append(f"| {name} | {s['n']} | " + " | ".join(cells) + " |")
        lines.append("")
        for name, s in card["labels"].items():
            h = s.get("histogram")
            if not h:
                continue
            if "values" in h:
                bars = ", ".join(f"{fmt(v)}: {n}" for v, n in zip(h["values"], h["counts"]))
            else:
                e = h["edges"]
                bars = ", ".join(f"[{fmt(e[i])}, {fmt(e[i + 1])}): {n}" for i, n in enumerate(h["counts"]))
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
                    f"{fmt(corr['spearman'][i][j], 2)} / {fmt(corr['pearson'][i][j], 2)} (n {corr['n'][i][j]})"
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
    if card.get("warnings"):
        lines += [
            "## Warnings",
            "",
            "What the run that made this dataset warned about: unit guesses and repairs of meshes, objects left out "
            "and why, objects the gripper cannot grasp (stage: text).",
            "",
        ]
        lines += [f"- {_md_text(w)}" for w in card["warnings"]]
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
        digest = keys_digest(s["keys"])
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


def _object_set_lines(sets: Mapping[str, Any]) -> list[str]:
    """The card's section on the object-centric sets (nothing when the dataset has none)."""
    lines: list[str] = []
    if "objects" in sets:
        lines += [
            "## Object-centric grasp sets",
            "",
            "Per object: grasps sampled over the whole object and labelled in free space (`object_grasps.parquet`), "
            "kept until the targets were met or the candidate budget was spent.",
            "",
            "| object | positives | target | negatives | target | tried | reached | near misses | their success |",
            "| --- | ---: | ---: | ---: | ---: | ---: | --- | ---: | ---: |",
        ]
        for name, o in sets["objects"].items():
            rate = "-" if o["near_miss_success_rate"] is None else f"{100 * o['near_miss_success_rate']:.1f}%"
            reached = "-" if o["reached"] is None else ("yes" if o["reached"] else "no")
            lines.append(f"| {name} | {o['positives']} | {fmt(o['target_positives'])} | {o['negatives']} | "
                         f"{fmt(o['target_negatives'])} | {fmt(o['tried'])} | {reached} | {o['near_miss']} | {rate} |")
        lines.append("")
    if "placed" in sets:
        p = sets["placed"]
        lines += [
            "### Placed in the scenes",
            "",
            f"{p['grasps']} object grasps placed in {p['scenes']} scenes: {p['free']} free of the support and the "
            f"neighbours ({p['support_collisions']} hit the support, {p['clutter_collisions']} a neighbour), "
            f"{p['positives']} positives (object-level success and free: ACRONYM's scene label).",
            "",
        ]
        if p["rescene_checked"]:
            lines += [
                f"Re-simulation check: {p['rescene_checked']} placed free grasps rolled out again in their scene "
                f"(table protocol); the label changed for {p['rescene_changed']} "
                f"({fmt(None if p['rescene_change_rate'] is None else 100 * p['rescene_change_rate'])}%): "
                f"positives lost {fmt(None if p['rescene_lost'] is None else 100 * p['rescene_lost'])}%, "
                f"negatives gained {fmt(None if p['rescene_gained'] is None else 100 * p['rescene_gained'])}%.",
                "",
            ]
    return lines


def _md_text(text: str) -> str:
    """``text`` as literal Markdown inline text: the characters that would start markup (emphasis by ``*``, code,
    links, HTML) are escaped; underscores inside words (``scene_000002``) are literal in Markdown already."""
    return "".join("\\" + ch if ch in "\\`*[]<>" else ch for ch in str(text))


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


def add_file(files: dict[str, dict[str, Any]], root: Path, rel: str) -> None:
    """Add ``root/rel`` to ``files`` (a card's file list) with its sha256 and size."""
    path = root / rel
    files[rel] = {"sha256": sha256_file(path), "bytes": path.stat().st_size}


def _prune(root: Path, files: Mapping[str, Any]) -> None:
    """Remove the files of :data:`MANAGED` folders that ``files`` does not list (those of an earlier dataset)."""
    for sub in MANAGED:
        folder = root / sub
        if not folder.is_dir():
            continue
        for path in folder.iterdir():
            rel = path.relative_to(root).as_posix()
            if path.is_file() and rel not in files and not path.name.startswith("."):
                path.unlink()


def report(path: str | Path) -> Path:
    """Render ``card.md``, ``card.json`` and the plots of a published dataset again; returns the card.md path.

    The statistics and plots come from the data files; what the data cannot tell (keys, config, package versions,
    the data files' hashes) is taken from the existing ``card.json``. So on an intact folder the result is the
    published card, byte for byte.

    Raises
    ------
    InputError
        No dataset there; card.json unreadable or incomplete; a data file it lists missing, of another size
        (truncated) or unreadable. The message names the file.
    """
    root = dataset_dir(path)
    card_path = root / "card.json"
    try:
        old = json.loads(card_path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{card_path}: cannot read the card ({exc}); publish again with gen run") from None
    needed = ("dataset_key", "tables", "left_out", "stages", "versions", "config", "files")
    missing = [k for k in needed if k not in old] if isinstance(old, dict) else list(needed)
    if missing or not isinstance(old["files"], dict) or not isinstance(old["config"], dict):
        raise InputError(f"{card_path}: not a complete dataset card (no {', '.join(missing) or 'files/config'}); "
                         "publish again with gen run")
    fields = {f.name for f in dataclasses.fields(CardSettings)}
    settings = CardSettings(**{k: v for k, v in (old["config"].get("dataset") or {}).items() if k in fields})
    data_files = {k: v for k, v in old["files"].items() if not k.startswith("plots/")}
    for rel, info in data_files.items():  # a truncated or missing data file: name it, before reading any
        f = root / rel
        size = f.stat().st_size if f.is_file() else None
        listed = info.get("bytes") if isinstance(info, dict) else None
        if size is None or size != listed:
            state = "missing" if size is None else f"{size} bytes, card.json says {listed} (truncated?)"
            raise InputError(f"{f}: {state}; gen validate {path} lists every damaged file")
    provenance = {k: old[k] for k in ("dataset_key", "tables", "left_out", "stages", "versions", "config")}
    provenance["warnings"] = old.get("warnings", [])
    provenance["scene_grasps"] = old.get("scene_grasps")
    try:
        build_card(root, provenance, data_files, settings)
    except pa.ArrowException as exc:  # same size but damaged
        raise InputError(f"{root / 'grasps.parquet'}: cannot be read ({exc}); gen validate {path} says more") from None
    return root / "card.md"
