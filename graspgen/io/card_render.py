"""The Markdown rendering of a dataset card: :func:`render_card`, a pure function of ``card.json``'s content.

Section by section (the introduction, files, outcomes, per object, object sets, learnability, scene grasps, labels,
plots, warnings, scenes left out, schema, provenance, config), each a small function of the card returning lines.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from graspgen.io.card_grasps import scene_grasps_lines
from graspgen.io.card_learn import learnability_lines
from graspgen.io.dataset_table import OUTCOME_NAMES

__all__ = ["fmt", "keys_digest", "render_card"]


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
    lines = _intro_lines(card) + _file_lines(card) + _outcome_lines(card)
    lines += _object_set_lines(card.get("object_sets", {}))
    lines += learnability_lines(card.get("learnability"))
    lines += scene_grasps_lines(card.get("scene_grasps"))
    lines += _label_lines(card) + _plot_lines(card) + _warning_lines(card) + _left_out_lines(card)
    lines += _schema_lines(card) + _provenance_lines(card)
    return "\n".join(lines)


def _intro_lines(card: Mapping[str, Any]) -> list[str]:
    """The title, what the dataset is (the scene grasps' gripper and the object sets' gripper, and which sections
    cover which), its key and how to check and read it."""
    c = card["counts"]
    sets = card.get("object_sets", {})
    scene_gripper = ", ".join(c["grippers"]) or "-"
    set_gripper = ", ".join(sets.get("grippers") or []) or "-"
    lines = ["# Dataset card", ""]
    lines += [
        f"A grasp dataset made by graspgen {card['versions'].get('graspgen', '?')}: {c['grasps']} scene grasps of "
        f"{c['objects_with_grasps']} objects in {c['scenes']} scenes ({c['views']} camera views) by the gripper "
        f"{scene_gripper}, each labelled by a simulated grasp-and-lift in its scene"
        + (", perturbed copies (robustness: the share of the copies still held; pfc, the probability of force "
           "closure: the share with epsilon above delta)" if "robustness" in card["labels"] else "")
        + (" and the Ferrari-Canny epsilon" if "epsilon" in card["labels"] else "")
        + "."
        + (f" Beside them, object-centric grasp sets of the gripper {set_gripper}, labelled in free space and placed "
           "in the scenes." if "objects" in sets else ""),
        "",
    ]
    if "objects" in sets:
        lines += [
            f"What covers what: `grasps.parquet` and the sections Outcomes, Per object, Scene grasps, Labels and Plots "
            f"are the scene grasps ({scene_gripper}); `object_grasps.parquet`, `placed_grasps.parquet`, the "
            "exports (ACRONYM, GraspGen, Contact-GraspNet) and the sections Object-centric grasp sets and "
            f"Learnability are the object-centric sets ({set_gripper}).",
            "",
        ]
    lines += [
        f"Dataset key `{card['dataset_key']}` (the content key of `grasps.parquet`; it changes with any input, "
        "parameter or stage version). Check the files with `gen validate <folder>`; read them with "
        "`graspgen.io.reader.open_dataset(<folder>)`, pandas, polars, duckdb or h5py.",
        "",
    ]
    return lines


def _file_lines(card: Mapping[str, Any]) -> list[str]:
    """The table of the published files (those the dataset has)."""
    c = card["counts"]
    lines = [
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
        lines.append("| `graspgen/` | the object-centric sets in GraspGen's layout (one JSON per object; splits: an "
                     "object is `valid` when a hash of its name alone falls in the lowest 20%) |")
    if any(k.startswith("contact_graspnet/") for k in card["files"]):
        what = "placed object-centric grasps" if "placed" in sets else "scene grasps"
        lines.append(f"| `contact_graspnet/` | the scenes as Contact-GraspNet's training data: per scene the positive "
                     f"{what} as its Panda grasp frames and finger contacts, the meshes, the splits (scenes by a hash "
                     "of the id, held-out scenes named last; objects as in `graspgen/`; scenes without a positive left "
                     "out) |")
    if any(k.startswith("probe/") for k in card["files"]):
        lines.append("| `probe/` | `model.pt`, a grasp evaluator trained on the object sets, and `report.json`, its "
                     "held-out scores (Learnability, below) |")
    lines += [
        "| `config.yaml` | the resolved config (`gen run --config config.yaml` makes the dataset again) |",
        "| `card.json` | this card as data, with every file's sha256 and every shard key |",
        "",
    ]
    return lines


def _outcome_lines(card: Mapping[str, Any]) -> list[str]:
    """The grasps per outcome and per object."""
    c = card["counts"]
    lines = [
        "## Outcomes",
        "",
        f"The scene grasps (`grasps.parquet`, gripper {', '.join(c['grippers']) or '-'}) by the outcome of their "
        "rollout in the scene.",
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
    lines += ["", "Scene grasps per object; columns 0-5 are the outcome codes above.", ""]
    return lines


def _label_lines(card: Mapping[str, Any]) -> list[str]:
    """The labels' summaries, histograms and correlations."""
    lines = ["## Labels", ""]
    if not card["labels"]:
        return lines + ["No label columns beyond the outcome (the robustness and metrics stages were not joined).", ""]
    lines += [
        "Of the scene grasps (`grasps.parquet`), over the grasps where the label is defined (robustness and pfc: "
        "successful grasps; pfc is the share of the perturbed copies in force closure).",
        "",
        "| label | n | mean | std | min | 5% | median | 95% | max |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for name, s in card["labels"].items():
        cells = [fmt(s.get(k)) for k in ("mean", "std", "min", "p05", "median", "p95", "max")]
        lines.append(f"| {name} | {s['n']} | " + " | ".join(cells) + " |")
    lines.append("")
    sample = card.get("label_sample")
    if sample:  # past the card's cap (graspgen.io.card_labels): which figures come from a sample
        lines += [f"The table has more than {sample['exact_up_to']} rows: {', '.join(sample['from_sample'])} come "
                  f"from a sample of {sample['sampled']} of its {sample['rows']} rows ({sample['selection']}); "
                  "every other figure is of all rows.", ""]
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
    return lines + _correlation_lines(card["correlation"])


def _correlation_lines(corr: Mapping[str, Any]) -> list[str]:
    """The table of the labels' rank and linear correlations (nothing for fewer than two labels)."""
    if len(corr["columns"]) < 2:
        return []
    cols = corr["columns"]
    lines = [
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
    return lines


def _plot_lines(card: Mapping[str, Any]) -> list[str]:
    if not card["plots"]:
        return []
    lines = ["## Plots", "", "Of the scene grasps (`grasps.parquet`).", ""]
    for rel in card["plots"]:
        lines.append(f"![{Path(rel).stem}]({rel})")
        lines.append("")
    return lines


def _warning_lines(card: Mapping[str, Any]) -> list[str]:
    if not card.get("warnings"):
        return []
    lines = [
        "## Warnings",
        "",
        "What the run that made this dataset warned about: unit guesses and repairs of meshes, objects left out "
        "and why, objects the gripper cannot grasp (stage: text).",
        "",
    ]
    lines += [f"- {_md_text(w)}" for w in card["warnings"]]
    lines.append("")
    return lines


def _left_out_lines(card: Mapping[str, Any]) -> list[str]:
    if not card["left_out"]:
        return []
    lines = ["## Scenes left out", ""]
    lines += [f"- {sid}: {why}" for sid, why in card["left_out"].items()]
    lines.append("")
    return lines


def _schema_lines(card: Mapping[str, Any]) -> list[str]:
    lines = ["## Schema of grasps.parquet", "", "| column | type | description |", "| --- | --- | --- |"]
    for f in card["schema"]:
        lines.append(f"| `{f['name']}` | {f['type']} | {f['description']} |")
    return lines


def _provenance_lines(card: Mapping[str, Any]) -> list[str]:
    """Every stage's shard count and keys digest, the package versions and the config."""
    lines = [
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
    return lines


OBJECT_SET_MIX = {"firm": "firm", "held_not_firm": "held but not firm", "slipped": "slipped", "no_contact":
                  "no contact", "collision": "collision at placement"}
"""The outcome mix of the object-centric sets as the card names it."""


def _share(part: int, whole: int) -> str:
    return "-" if not whole else f"{100 * part / whole:.1f}%"


def _object_set_lines(sets: Mapping[str, Any]) -> list[str]:
    """The card's section on the object-centric sets (nothing when the dataset has none)."""
    lines: list[str] = []
    if "objects" in sets:
        objects = sets["objects"]
        mix = {k: sum(o["outcome_mix"][k] for o in objects.values()) for k in OBJECT_SET_MIX}
        kept = sum(o["grasps"] for o in objects.values())
        labels = sorted({o["label"] for o in objects.values()})
        selections = sorted({o["selection"] for o in objects.values()})
        lines += [
            "## Object-centric grasp sets",
            "",
            "Per object: grasps sampled over the whole object and labelled in free space (`object_grasps.parquet`). "
            f"Selection: {', '.join(selections)} (`natural`: every candidate that does not collide at placement, "
            "kept whatever its outcome, so the positive share is the sampler's own, and collisions within "
            "`object_grasps.collision_share_of_negatives`; `balanced`: kept until positive and negative targets were "
            "met). "
            f"Positives by the `{', '.join(labels)}` label (`object_grasps.label`). Tried: candidates rolled out; "
            "reached: whether the set met its targets before `max_candidates` were tried; near misses (`balanced` "
            "only): copies of grasps that held, shifted past the contact or tilted, kept as hard negatives, and "
            "their success the share of them that still held.",
            "",
            f"Outcome mix of the {kept} kept grasps: " + ", ".join(
                f"{OBJECT_SET_MIX[k]} {mix[k]} ({_share(mix[k], kept)})" for k in OBJECT_SET_MIX) + ".",
            "",
            "| object | grasps | positives | share | held, not firm | slipped | no contact | collisions kept | "
            "collisions dropped | tried | reached | near misses | their success |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- | ---: | ---: |",
        ]
        for name, o in objects.items():
            rate = "-" if o["near_miss_success_rate"] is None else f"{100 * o['near_miss_success_rate']:.1f}%"
            reached = "-" if o["reached"] is None else ("yes" if o["reached"] else "no")
            m = o["outcome_mix"]
            lines.append(f"| {name} | {o['grasps']} | {o['positives']} | {_share(o['positives'], o['grasps'])} | "
                         f"{m['held_not_firm']} | {m['slipped']} | {m['no_contact']} | {m['collision']} | "
                         f"{fmt(o['collisions_dropped'])} | {fmt(o['tried'])} | {reached} | {o['near_miss']} | "
                         f"{rate} |")
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
                f"negatives gained {fmt(None if p['rescene_gained'] is None else 100 * p['rescene_gained'])}%. "
                "What it means: a placed label is the object's free-space label and a collision check of the open "
                "hand at the pose; the approach, the support and the neighbours during the grasp are not simulated. "
                "The lost share is about how many placed positives would fail if grasped in their scene (an estimate "
                "from the positives of that sample): read a placed positive as held in free space and not blocked "
                "at the pose, as ACRONYM's scene labels are, not as picked up in that scene; the scene grasps "
                "(`grasps.parquet`) are the labels simulated in the scene.",
                "",
            ]
    return lines


def _md_text(text: str) -> str:
    """``text`` as literal Markdown inline text: the characters that would start markup (emphasis by ``*``, code,
    links, HTML) are escaped; underscores inside words (``scene_000002``) are literal in Markdown already."""
    return "".join("\\" + ch if ch in "\\`*[]<>" else ch for ch in str(text))
