"""The statistics of a dataset card: counts per object and outcome, label summaries and histograms, correlations.

:func:`card_stats` computes them from the files of a dataset folder (grasps.parquet read one row group at a time
into running counts, :mod:`graspgen.io.card_tally`, its labels in bounded memory, :mod:`graspgen.io.card_labels`:
exact up to :data:`graspgen.io.card_labels.EXACT_ROWS` rows, past it the card's ``label_sample`` names the figures
taken from a sample; the scenes and objects listed), :func:`object_set_stats` those of the object-centric sets.
:class:`CardSettings` is what the card and its plots read of the ``dataset`` config section. The card itself
(card.json, card.md) is :mod:`graspgen.io.card`.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from graspgen.io.card_labels import (
    DISCRETE_LABEL_VALUES,
    EXACT_ROWS,
    HASH,
    SAMPLE_ROWS,
    LabelTally,
    Moments,
    binned_counts,
    count_quantiles,
)
from graspgen.io.card_tally import OBJECT_SET_COUNTS, CardTable, GraspTally, ObjectSetTally, PlacedTally, row_groups
from graspgen.io.dataset_table import META_KEY, OUTCOME_NAMES, float_values
from graspgen.validation import check_bool, check_int

__all__ = [
    "CORRELATED",
    "DISCRETE_LABEL_VALUES",
    "LABEL_COLUMNS",
    "OBJECT_SET_FILES",
    "CardSettings",
    "card_stats",
    "label_summary",
    "object_set_stats",
]

LABEL_COLUMNS = ("robustness", "epsilon", "pfc", "min_closure_friction")
"""Numeric labels the card summarises (those present)."""

CORRELATED = ("robustness", "epsilon", "pfc")
"""Labels whose pairwise correlations the card reports."""

QUANTILES = (0.05, 0.5, 0.95)
"""The quantiles a label summary gives (p05, median, p95)."""

TALLY_COLUMNS = ("scene_id", "grasp_id", "object_name", "outcome", "gripper")
"""The columns of grasps.parquet the counts read (with the labels)."""

OBJECT_SET_FILES = ("object_grasps.parquet", "placed_grasps.parquet")
"""The object-centric tables a dataset may hold besides grasps.parquet."""


@dataclasses.dataclass(frozen=True)
class CardSettings:
    """What the card and its plots read of the ``dataset`` config section (its keys sit at that section's level)."""

    plots: bool = True
    """Draw the card's plots (plots/*.png, with matplotlib)."""
    histogram_bins: int = 20
    """Bins of the label histograms (card and plots) for labels with more than 32 distinct values."""
    example_scenes: int = 4
    """Scenes in the examples contact sheet (the first ones by id that have RGB images)."""
    example_grasps: int = 24
    """At most this many grasps drawn per example scene, spread over the outcomes."""

    def __post_init__(self) -> None:
        check_bool("plots", self.plots)
        check_int("histogram_bins", self.histogram_bins, low=1, high=1000)
        check_int("example_scenes", self.example_scenes, low=0)
        check_int("example_grasps", self.example_grasps, low=0)


def _num(x: float) -> float | None:
    """A float for JSON: 6 significant digits (stable across summation orders), None when not finite."""
    x = float(x)
    return float(f"{x:.6g}") if math.isfinite(x) else None


def _rate(k: int, n: int) -> float | None:
    return _num(k / n) if n else None


def label_summary(values: np.ndarray, bins: int, unit_range: bool) -> dict[str, Any]:
    """Summary and histogram of one label's finite values.

    A label with at most :data:`DISCRETE_LABEL_VALUES` distinct values (robustness of n copies, a friction grid)
    gets one bar per value; otherwise ``bins`` equal bins over [0, 1] (``unit_range``) or over [min, max].

    Parameters
    ----------
    values : (n,) float
        The label per grasp; NaN where it is undefined (left out).
    bins : int
        Bins of a label with many distinct values.
    unit_range : bool
        Bin over [0, 1] (fractions) instead of over the values' range.
    """
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    out: dict[str, Any] = {"n": int(len(v))}
    if len(v) == 0:
        return out
    q = np.quantile(v, QUANTILES)
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
    """Ranks 1..n with ties given their average rank (as ``scipy.stats.rankdata``, whose import publish would pay
    in the parent, in series with everything: docs/decisions/2026-12-03-engine-at-scale.md)."""
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


def _scene_stats(root: Path, files: Mapping[str, Any], tally: GraspTally) -> dict[str, Any]:
    """Per listed scene file (by id): its grasps, its objects' names and its camera views."""
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
    return scenes


def _object_stats(library: list[str], scenes: Mapping[str, Any], tally: GraspTally) -> dict[str, Any]:
    """Per library object (by name): the scenes it is in, its grasps, their outcome counts and success rate."""
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
    return per_object


def card_stats(root: Path, files: Mapping[str, Any], settings: CardSettings, *, exact_rows: int = EXACT_ROWS,
               sample_rows: int = SAMPLE_ROWS) -> tuple[dict[str, Any], CardTable]:
    """Counts, label summaries and correlations of the dataset in ``root`` whose data files are ``files`` (relative
    paths; the scenes and objects are those listed, not whatever else sits in the folder); also returns what the
    plots read of the table (:class:`graspgen.io.card_tally.CardTable`).

    grasps.parquet is read one row group at a time into running counts (:class:`GraspTally`), its labels into a
    :class:`graspgen.io.card_labels.LabelTally`: up to ``exact_rows`` rows every figure is exact (from the whole
    columns, as :func:`label_summary` and the correlations always computed them); past it, the card's
    ``label_sample`` says which figures come from a sample of ``sample_rows`` rows (:func:`_label_stats`)."""
    path = root / "grasps.parquet"
    schema = pq.read_schema(path)
    labels = [c for c in LABEL_COLUMNS if c in schema.names]
    tally = GraspTally(labels, exact_rows, sample_rows)
    for group in row_groups(path, [c for c in schema.names if c in (*TALLY_COLUMNS, *labels)]):
        tally.add(group)
    scenes = _scene_stats(root, files, tally)
    library = sorted(Path(rel).stem for rel in files if rel.startswith("objects/"))
    per_object = _object_stats(library, scenes, tally)
    summaries, correlation, sample = _label_stats(path, tally.label_tally, settings)
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
        "correlation": correlation,
    }
    if sample is not None:
        stats["label_sample"] = sample
    sets = object_set_stats(root, files)
    if sets:
        stats["object_sets"] = sets
    return stats, CardTable(path, _card_columns(schema), tally)


def _label_stats(path: Path, tally: LabelTally, settings: CardSettings) -> tuple[dict, dict, dict | None]:
    """The label summaries, the correlations and, past the tally's cap, what the card says of its sample.

    Up to the cap every row is held: :func:`label_summary` and :func:`_correlations` of the whole columns. Past it
    (:mod:`graspgen.io.card_labels`): n, mean, std, min, max and per-value histograms from the streamed figures,
    binned histograms from a second pass over the column, quantiles from the value counts of a label with at most
    :data:`DISCRETE_LABEL_VALUES` values, else from the sample (the summary's ``sample``: the sampled values they
    come from), the correlation coefficients from the sample (``sample_rows``) with the pair counts of all rows."""
    values = {c: tally.values(c) for c in tally.labels}
    unit = {c: c in ("robustness", "pfc") for c in tally.labels}
    if not tally.sampled:
        summaries = {c: label_summary(values[c], settings.histogram_bins, unit[c]) for c in tally.labels}
        return summaries, _correlations(values), None
    summaries = {c: _streamed_summary(path, c, tally.moments[c], values[c], settings.histogram_bins, unit[c])
                 for c in tally.labels}
    correlation = _correlations(values)
    index = {c: i for i, c in enumerate(tally.labels)}
    correlation["n"] = [[int(tally.pairs[index[a], index[b]]) for b in correlation["columns"]]
                        for a in correlation["columns"]]
    correlation["sample_rows"] = len(tally.hashes)
    from_sample = [f"{c} quantiles" for c in tally.labels if tally.moments[c].distinct is None]
    sample = {"rows": tally.rows, "sampled": len(tally.hashes), "exact_up_to": tally.exact_rows, "selection": HASH,
              "from_sample": [*from_sample, "correlation coefficients"]}
    return summaries, correlation, sample


def _streamed_summary(path: Path, column: str, m: Moments, sample: np.ndarray, bins: int,
                      unit_range: bool) -> dict[str, Any]:
    """:func:`label_summary`'s figures of a label past the cap, from its streamed figures ``m``, its ``sample``
    ((k,) float64, NaN where undefined) and, for a binned histogram, a second pass over ``column`` of ``path``."""
    out: dict[str, Any] = {"n": m.n}
    if m.n == 0:
        return out
    if m.distinct is not None:
        distinct = np.asarray(sorted(m.distinct), np.float64)
        counts = np.asarray([m.distinct[v] for v in distinct.tolist()], np.int64)
        q = count_quantiles(distinct, counts, QUANTILES)
    else:
        finite = sample[np.isfinite(sample)]
        q = np.quantile(finite, QUANTILES) if len(finite) else np.full(len(QUANTILES), np.nan)
    out.update(mean=_num(m.mean), std=_num(m.std), min=_num(m.lo), p05=_num(q[0]), median=_num(q[1]),
               p95=_num(q[2]), max=_num(m.hi))
    if m.distinct is not None:
        out["histogram"] = {"values": [_num(x) for x in distinct], "counts": counts.tolist()}
        return out
    lo, hi = (0.0, 1.0) if unit_range else (m.lo, m.hi)
    hi = hi if hi > lo else lo + 1.0
    groups = (float_values(g.column(0)) for g in row_groups(path, [column]))
    out["histogram"] = {"edges": [_num(e) for e in np.linspace(lo, hi, bins + 1)],
                        "counts": binned_counts(groups, lo, hi, bins).tolist()}
    out["sample"] = int(len(finite))
    return out


def object_set_stats(root: Path, files: Mapping[str, Any]) -> dict[str, Any]:
    """What the card says of the object-centric sets, when ``files`` lists them (else an empty dict).

    ``grippers``: the sets' grippers. ``objects``: per object the grasps kept, positives and negatives, the
    targets and the candidates tried (from the file's metadata: how far each object's set got), the success rate
    among the kept antipodal and near-miss candidates. ``placed``: the placed scene grasps, how many are free of the
    support and the neighbours, how many are positives (object-level success and free), and the re-simulation
    check: how many were rolled out again in their scene and how often the label changed (both ways). Both files
    are read one row group at a time into running counts (:mod:`graspgen.io.card_tally`).
    """
    out: dict[str, Any] = {}
    if "object_grasps.parquet" in files:
        out["objects"] = _object_set_objects(root / "object_grasps.parquet")
        grippers: set[str] = set()
        if "gripper" in pq.read_schema(root / "object_grasps.parquet").names:
            for group in row_groups(root / "object_grasps.parquet", ["gripper"]):
                grippers.update(str(g) for g in group.column("gripper").unique().to_pylist())
        out["grippers"] = sorted(grippers)
    if "placed_grasps.parquet" in files:
        out["placed"] = _placed_stats(root / "placed_grasps.parquet")
    return out


def _object_set_objects(path: Path) -> dict[str, Any]:
    """Per object of ``object_grasps.parquet``: its kept grasps and how far its set got (the file's metadata)."""
    meta = json.loads((pq.read_schema(path).metadata or {}).get(META_KEY, b"{}")).get("tasks", {})
    sets = ObjectSetTally()
    for group in row_groups(path, ["object_name", "candidate", "outcome", "success", "firm"]):
        sets.add(group)
    objects = {}
    for name in sorted(set(sets.objects) | set(meta)):
        counts = dict(zip(OBJECT_SET_COUNTS, (int(v) for v in sets.objects.get(
            name, np.zeros(len(OBJECT_SET_COUNTS), np.int64)))))
        m = meta.get(name, {})
        label = m.get("label") or "held"
        positives = counts["firm"] if label == "firm" else counts["held"]
        objects[name] = {
            "grasps": counts["grasps"],
            "label": label,
            "selection": m.get("selection") or "balanced",
            "positives": positives,
            "negatives": counts["grasps"] - positives,
            "target_grasps": m.get("target_grasps"),
            "target_positives": m.get("target_positives"),
            "target_negatives": m.get("target_negatives"),
            "tried": m.get("tried"),
            "reached": m.get("reached"),
            "collisions_dropped": m.get("collisions_dropped"),
            "outcome_mix": {k: counts[k] for k in ("collision", "no_contact", "slipped", "held_not_firm", "firm")},
            "near_miss": counts["near_miss"],
            "near_miss_success_rate": _rate(counts["near_miss_held"], counts["near_miss"]),
        }
    return objects


def _placed_stats(path: Path) -> dict[str, Any]:
    """The counts of ``placed_grasps.parquet``: free, colliding, positive, re-simulated and changed grasps."""
    placed = PlacedTally()
    for group in row_groups(path, ["scene_id", "scene_code", "object_success", "success", "rescene_outcome",
                                   "rescene_success"]):
        placed.add(group)
    n = placed.counts
    return {
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
