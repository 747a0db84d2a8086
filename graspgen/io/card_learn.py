"""The dataset card's "Learnability" section: how well a small network learns the labels, from ``probe/report.json``.

:func:`learnability` is what ``card.json`` holds under ``learnability`` (the report the ``probe`` stage published,
or why there is none); :func:`learnability_lines` renders it as Markdown (a pure function of that dict). The report's
layout is :func:`graspgen.learn.probe.run_probe`'s, less its timings (:func:`graspgen.io.probe_files.clean_report`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from graspgen.errors import InputError
from graspgen.io.probe_files import MODEL, REPORT

__all__ = ["BASELINES", "HOW_TO_READ", "learnability", "learnability_lines"]

BASELINES = (
    ("gbt", "gradient-boosted trees on pooled statistics of the same points"),
    ("object_rate", "per-object rate (each held-out object's own success rate)"),
    ("base_rate", "base rate (the training grasps' success rate)"),
)
"""The report's baselines, in the order the card lists them, with their names on the card."""

HOW_TO_READ = (
    "How to read it: the pooled ROC-AUC ranks all held-out grasps together, so it can be high from object difficulty "
    "alone (the per-object-rate row knows nothing but each held-out object's success rate and shows how high that "
    "gets); the mean per-object AUC is discrimination within each object, which knowing each object's rate cannot "
    "lift above 0.5. A network well above 0.5 there, and above the trees, has learned from the geometry which grasps "
    "on a shape it has not seen hold."
)
"""The sentence on how to read the section's numbers."""


def learnability(root: Path, files: Mapping[str, Any], config: Mapping[str, Any],
                 warnings: Sequence[str] = ()) -> dict[str, Any]:
    """What the card says of the probe: ``{"status": "run", "report": ..., "model": path}`` when ``files`` lists
    :data:`REPORT`, else ``{"status": "not run", "reason": ...}``.

    Parameters
    ----------
    root : Path
        The dataset folder.
    files : mapping
        The card's data files (relative paths).
    config : mapping
        The resolved config as a dict (``probe.enabled`` says whether it was asked for).
    warnings : sequence of str
        The run's warnings (``"stage: text"``): a probe warning is the reason when it did not run.

    Raises
    ------
    InputError
        :data:`REPORT` is listed but cannot be read as JSON (names the file).
    """
    if REPORT in files:
        path = root / REPORT
        try:
            report = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(f"{path}: cannot read the probe's report ({exc})") from None
        sets = config.get("object_grasps")
        label = sets.get("label") if isinstance(sets, Mapping) else None
        return {"status": "run", "report": report, "model": MODEL if MODEL in files else None, "label": label}
    section = config.get("probe")
    if not isinstance(section, Mapping):
        reason = "this pipeline has no probe stage"
    elif section.get("enabled") is False:
        reason = "probe.enabled: false"
    else:
        said = [w.split(": ", 1)[1] for w in warnings if str(w).startswith("probe: ")]
        reason = said[0].removeprefix("not run: ") if said else "the probe stage has no result (see the run's log)"
    return {"status": "not run", "reason": reason}


def _f(x: Any) -> str:
    return "-" if x is None else f"{float(x):.3f}"


def _pct(x: Any) -> str:
    return "-" if x is None else f"{100 * float(x):.1f}%"


def _names(names: Sequence[str]) -> str:
    return ", ".join(str(n) for n in names) or "-"


def learnability_lines(section: Mapping[str, Any] | None) -> list[str]:
    """The card's "Learnability" section (Markdown lines) of a :func:`learnability` dict; None (a card made
    before the section existed) renders nothing."""
    if section is None:
        return []
    lines = ["## Learnability", ""]
    if section.get("status") != "run":
        return lines + [f"Learnability: not run ({section.get('reason', 'no report')}).", ""]
    r = section["report"]
    split, net, train = r.get("split", {}), r.get("network", {}), r.get("train", {})
    baselines = r.get("baselines", {})
    lines += [
        f"A small PointNet grasp evaluator (`graspgen.learn`) trained for {train.get('epochs', '-')} epochs on the "
        f"object-centric sets of {len(split.get('train_objects', []))} objects ({split.get('train_grasps', '-')} "
        f"grasps) and scored on {len(split.get('valid_objects', []))} held-out object(s) "
        f"({split.get('valid_grasps', '-')} grasps, base rate {_pct(net.get('base_rate'))} positives): can a network "
        "tell from the object's shape around the jaws which grasps hold? Objects are split by a hash of their name "
        f"(valid fraction {split.get('valid_fraction', '-')}, salt `{split.get('salt', '')}`), so no held-out "
        "object was seen in training. This split is the probe's own: the GraspGen export's (`graspgen/splits/`, "
        "and the object split of `contact_graspnet/`) hashes the name alone with 20% valid, so an object held out "
        "here may be a training object there."
        + (f" It learned the sets' `{section['label']}` label (`object_grasps.label`)." if section.get("label")
           else "")
        + (f" The model is `{section['model']}` (`gen probe eval --model` scores other grasps with it)."
           if section.get("model") else ""),
        "",
        HOW_TO_READ,
        "",
        "| scorer | ROC-AUC | average precision | mean per-object AUC | top-k success |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    rows = [("network", net)] + [(label, baselines[key]) for key, label in BASELINES if key in baselines]
    for label, rep in rows:
        top = rep.get("top_k") or {}
        lines.append(f"| {label} | {_f(rep.get('auc'))} | {_f(rep.get('ap'))} | {_f(rep.get('mean_object_auc'))} | "
                     f"{_pct(top.get('success'))} |")
    top = net.get("top_k") or {}
    if top:
        lines += ["", f"Top-k: per held-out object, the success rate of its {top.get('k', '-')} best-scored grasps, "
                  f"averaged over {top.get('objects', '-')} objects; a random grasp of the same objects succeeds "
                  f"{_pct(top.get('random'))} of the time. Grasps of equal score count at their expected value "
                  "over a random order (`graspgen.learn.report.top_k_success`), so a scorer that gives an object's "
                  "grasps one score (the per-object and base rates) scores exactly random."]
    gbt = {o["name"]: o for o in (baselines.get("gbt") or {}).get("per_object", [])}
    lines += ["", "| held-out object | grasps | positives | network AUC | trees AUC |",
              "| --- | ---: | ---: | ---: | ---: |"]
    for o in net.get("per_object", []):
        lines.append(f"| {o['name']} | {o['n']} | {o.get('positives', '-')} | {_f(o.get('auc'))} | "
                     f"{_f(gbt.get(o['name'], {}).get('auc'))} |")
    lines += [
        "",
        "AUC `-`: the object's held-out grasps are all one class. "
        f"Trained on: {_names(split.get('train_objects', []))}. Held out: {_names(split.get('valid_objects', []))}. "
        f"{net.get('n', '-')} held-out grasps scored; torch {train.get('torch', '-')}.",
        "",
    ]
    return lines
