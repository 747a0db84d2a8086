"""The plots of a dataset card (``plots/*.png``): outcomes, robustness, epsilon, their correlation, examples.

:func:`draw_plots` draws them with matplotlib (Agg) from the card statistics (:func:`graspgen.io.card_stats.card_stats`)
and the table they were computed from; the bytes depend on the data and the matplotlib version only (no date, no
software tag; the scatter jitter is seeded). The examples contact sheet draws grasps on the first view of the first
scenes (:func:`graspgen.viz.grasp_view.grasp_picture`).
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from graspgen.io.atomic import atomic_path
from graspgen.io.card_labels import row_hash
from graspgen.io.card_render import fmt
from graspgen.io.card_stats import CardSettings
from graspgen.io.dataset_table import float_values

__all__ = ["OUTCOME_COLOURS", "PLOT_FILES", "draw_plots"]

PLOT_FILES = ("outcomes.png", "robustness.png", "epsilon.png", "correlation.png", "examples.png")
"""The plots :func:`draw_plots` can write in ``plots/`` (each only when its data is there)."""

OUTCOME_COLOURS = ("#960014", "#eb1e1e", "#ff6e82", "#fae100", "#ff8c00", "#28c83c")
"""Plot colour by outcome code (as in :mod:`graspgen.viz.grasp_view`)."""


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


def draw_plots(root: Path, table: pa.Table, stats: Mapping[str, Any], settings: CardSettings) -> list[str]:
    """Write the card's PNGs in ``root/plots``; returns their paths relative to ``root``.

    Parameters
    ----------
    root : Path
        The dataset folder (its scenes are read for the examples).
    table : pyarrow.Table or CardTable
        The card's columns of grasps.parquet (:class:`graspgen.io.card_tally.CardTable`).
    stats : mapping
        :func:`graspgen.io.card_stats.card_stats` of the folder.
    settings : CardSettings
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": 9, "svg.hashsalt": "graspgen", "figure.max_open_warning": 0})
    written = [_outcomes_plot(plt, root, stats)]
    for drawn in (_robustness_plot(plt, root, stats), _epsilon_plot(plt, root, table, stats, settings),
                  _correlation_plot(plt, root, table, stats), _examples_plot(root, table, settings)):
        if drawn is not None:
            written.append(drawn)
    return written


OUTCOME_ROWS = 40
"""Most rows of the outcomes plot's per-object panel: beyond it, objects are sorted by their success share and
drawn in this many groups of consecutive objects, so the figure (and the memory drawing it takes) stays one size
however many objects the dataset has (docs/decisions/2026-12-03-engine-at-scale.md)."""


def _outcomes_plot(plt: Any, root: Path, stats: Mapping[str, Any]) -> str:
    """Outcomes: overall bars and each object's mix (or, past :data:`OUTCOME_ROWS` objects, the mix of groups of
    objects sorted by success share)."""
    names = [o["name"] for o in stats["outcomes"]]
    counts = [o["grasps"] for o in stats["outcomes"]]
    rows, labels, title = _outcome_rows(stats)
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, max(3.5, 0.3 * len(rows) + 1.5)), width_ratios=[1, 1.3])
    a.bar(range(len(names)), counts, color=OUTCOME_COLOURS, edgecolor="black", linewidth=0.5)
    for i, n in enumerate(counts):
        a.text(i, n, str(n), ha="center", va="bottom")
    a.set_xticks(range(len(names)), [f"{i} {n}" for i, n in enumerate(names)], rotation=30, ha="right")
    a.set_ylabel("grasps")
    a.set_title(f"outcomes of {stats['counts']['grasps']} grasps")
    left = np.zeros(len(rows))
    for code, colour in enumerate(OUTCOME_COLOURS):
        share = rows[:, code] if len(rows) else np.zeros(0)
        b.barh(range(len(rows)), share, left=left, color=colour, edgecolor="black", linewidth=0.3,
               label=f"{code} {names[code]}")
        left += share
    b.set_yticks(range(len(rows)), labels)
    b.invert_yaxis()
    b.set_xlim(0, 1)
    b.set_title(title)
    b.legend(loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=3, fontsize=7, frameon=False)
    fig.tight_layout()
    _save(fig, root / "plots" / "outcomes.png")
    return "plots/outcomes.png"


def _outcome_rows(stats: Mapping[str, Any]) -> tuple[np.ndarray, list[str], str]:
    """The per-object panel's rows: ``(k, 6)`` outcome shares, their labels and the panel title; one row per
    object with grasps, or :data:`OUTCOME_ROWS` groups of objects (sorted by success share, then name) with the
    mix of their grasps pooled."""
    objects = [k for k, v in stats["objects"].items() if v["grasps"]]
    counts = np.array([stats["objects"][o]["outcomes"][: len(OUTCOME_COLOURS)] for o in objects], dtype=float)
    counts = counts.reshape(len(objects), len(OUTCOME_COLOURS))
    totals = np.array([stats["objects"][o]["grasps"] for o in objects], dtype=float)
    if len(objects) <= OUTCOME_ROWS:
        return (counts / totals[:, None], [f"{o} ({int(n)})" for o, n in zip(objects, totals)],
                "share of each object's grasps by outcome (grasps)")
    success = counts[:, -1] / totals
    order = sorted(range(len(objects)), key=lambda i: (-success[i], objects[i]))
    groups = np.array_split(np.asarray(order), OUTCOME_ROWS)
    rows = np.array([counts[g].sum(axis=0) / totals[g].sum() for g in groups])
    starts = np.cumsum([0] + [len(g) for g in groups[:-1]])
    labels = [f"objects {start + 1}-{start + len(g)}" for start, g in zip(starts, groups)]
    title = (f"{len(objects)} objects sorted by success share, in {OUTCOME_ROWS} groups: "
             "share of each group's grasps by outcome")
    return rows, labels, title


def _robustness_plot(plt: Any, root: Path, stats: Mapping[str, Any]) -> str | None:
    """Histograms of robustness and pfc over the successful grasps (None: neither label is there)."""
    labels = stats["labels"]
    if not (labels.get("robustness", {}).get("n") or labels.get("pfc", {}).get("n")):
        return None
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
    return "plots/robustness.png"


def _epsilon_plot(plt: Any, root: Path, table: pa.Table, stats: Mapping[str, Any],
                  settings: CardSettings) -> str | None:
    """Stacked histogram of epsilon by outcome (None: no epsilon labels)."""
    if not stats["labels"].get("epsilon", {}).get("n"):
        return None
    eps = float_values(table.column("epsilon"))
    outcome = table.column("outcome").to_numpy()
    fig, ax = plt.subplots(figsize=(8, 3.6))
    finite = np.isfinite(eps)
    hi = float(eps[finite].max()) if finite.any() else 1.0
    edges = np.linspace(0.0, hi if hi > 0 else 1.0, settings.histogram_bins + 1)
    groups = [("success (5)", outcome == 5, "#28c83c"), ("slipped / no contact (3, 4)",
              (outcome == 3) | (outcome == 4), "#ff8c00"), ("collision (0-2)", outcome <= 2, "#eb1e1e")]
    ax.hist([eps[g & finite] for _, g, _ in groups], bins=edges, stacked=True,
            color=[c for _, _, c in groups], label=[n for n, _, _ in groups], edgecolor="black", linewidth=0.3)
    zero = int(((eps == 0) & finite).sum())
    ax.set_xlabel("Ferrari-Canny epsilon (unit-free)")
    ax.set_ylabel("grasps")
    if "label_sample" in stats:  # past the card's cap the table's label columns are a sample of the rows
        ax.set_title(f"epsilon by outcome: a sample of {int(finite.sum())} of {stats['labels']['epsilon']['n']} "
                     f"grasps ({zero} not in force closure)")
    else:
        ax.set_title(f"epsilon of {int(finite.sum())} grasps by outcome ({zero} not in force closure: epsilon 0)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    _save(fig, root / "plots" / "epsilon.png")
    return "plots/epsilon.png"


SCATTER_POINTS = 20_000
"""Most points of the correlation scatter: past it, those of the rows with the smallest
:func:`graspgen.io.card_labels.row_hash` (the same rows whatever the table's split); more make a blot, and drawing
them takes memory that grows with the points."""


def _row_hashes(table: Any) -> np.ndarray:
    """(n,) uint64 row hashes of the table's label rows: the card table's own, else from scene_id and grasp_id."""
    if not isinstance(table, pa.Table):
        return table.hashes
    return row_hash(table.column("scene_id"), table.column("grasp_id").to_numpy())


def _correlation_plot(plt: Any, root: Path, table: pa.Table, stats: Mapping[str, Any]) -> str | None:
    """Robustness against epsilon, coloured by pfc (None: fewer than two grasps have both)."""
    if not ("robustness" in table.column_names and "epsilon" in table.column_names):
        return None
    r, e = float_values(table.column("robustness")), float_values(table.column("epsilon"))
    p = float_values(table.column("pfc")) if "pfc" in table.column_names else np.full(len(r), np.nan)
    ok = np.isfinite(r) & np.isfinite(e)
    if ok.sum() < 2:
        return None
    corr = stats["correlation"]
    i, j = corr["columns"].index("robustness"), corr["columns"].index("epsilon")
    pairs = int(corr["n"][i][j])  # all rows' pairs, also where the table's columns are a sample
    if ok.sum() > SCATTER_POINTS:
        h = _row_hashes(table)
        ok &= h < np.partition(h[ok], SCATTER_POINTS)[SCATTER_POINTS]
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    jitter = (np.random.default_rng(0).random(int(ok.sum())) - 0.5) * 0.02  # seeded: bytes stay fixed
    colour = np.where(np.isfinite(p[ok]), p[ok], 0.0)
    sc = ax.scatter(e[ok], r[ok] + jitter, c=colour, cmap="viridis", vmin=0, vmax=1, s=14,
                    edgecolors="black", linewidths=0.2)
    fig.colorbar(sc, ax=ax, label="pfc")
    rho = corr["spearman"][i][j]
    ax.set_xlabel("epsilon")
    ax.set_ylabel("robustness (jittered)")
    drawn = "" if ok.sum() == pairs else f", {int(ok.sum())} drawn"
    ax.set_title(f"robustness vs epsilon, {pairs} successful grasps{drawn} (Spearman {fmt(rho, 2)})")
    fig.tight_layout()
    _save(fig, root / "plots" / "correlation.png")
    return "plots/correlation.png"


def _examples_plot(root: Path, table: pa.Table, settings: CardSettings) -> str | None:
    """The examples contact sheet as ``plots/examples.png`` (None: no scene with images, or none asked for)."""
    sheet = _examples_sheet(root, table, settings)
    if sheet is None:
        return None
    buf = io.BytesIO()
    sheet.save(buf, format="PNG", optimize=False)
    with atomic_path(root / "plots" / "examples.png") as tmp:
        tmp.write_bytes(buf.getvalue())
    return "plots/examples.png"


def _examples_sheet(root: Path, table: pa.Table, settings: CardSettings) -> Any:
    """Contact sheet of example grasps drawn on the first view of the first scenes (:mod:`graspgen.viz.grasp_view`)."""
    if settings.example_scenes == 0 or settings.example_grasps == 0:
        return None
    from PIL import Image

    from graspgen.io.scenes import read_scene
    from graspgen.viz.grasp_view import grasp_picture

    scene_ids, scene_rows = _scenes_of(table)
    pictures = []
    for sid in scene_ids:
        if len(pictures) == settings.example_scenes:
            break
        scene = read_scene(root / "scenes" / f"{sid}.h5")
        if scene.rgb is None:
            continue
        part = table.take(pa.array(scene_rows(sid)))
        pictures.append(grasp_picture(scene, part, part, view=0, n=settings.example_grasps, scale=2))
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


def _scenes_of(table: Any) -> tuple[list[str], Callable[[str], np.ndarray]]:
    """The table's scene ids (sorted) and a function giving a scene's row positions: from the card's table
    (:class:`graspgen.io.card_tally.CardTable`, which keeps runs of rows per scene, not a scene id per row) or from
    a pyarrow Table's ``scene_id`` column."""
    if not isinstance(table, pa.Table):
        return table.scene_ids, table.scene_rows
    scene_col = np.asarray(table.column("scene_id").to_pylist(), dtype=object)
    return sorted(set(scene_col)), lambda sid: np.flatnonzero(scene_col == sid)
