"""What each finer CoACD cut of the refinement costs and leaves, per mesh: data for choosing the refinement's threshold
from the first cut's own slack instead of from its piece count (tried, not adopted).

For every distinct mesh of ../shared/learn, at the objects stage's or ``gen evaluate``'s settings: the first cut (its
pieces, merged parts, volume excess and hull slack p95), the rough pieces' share of the area, the rough pieces alone cut
again at a quarter of the threshold, and the whole mesh cut again at 1/2, 1/3 and 1/4 of the threshold (each merged to
four times ``max_convex_hull``, as :func:`graspgen.geometry.convex._refined` does). Each CoACD call runs in its own
child process so that its CPU seconds (this process and the child, :func:`pipeline.worker.task_cpu_seconds`) are its
own; the slack is the rule's (4,000 samples, seeded) so that what a rule would decide can be replayed offline. Whole
cuts are skipped where the first cut made more than four times ``max_convex_hull`` pieces (the rule never makes them).

``--replay FILE`` replays two rules on a results file, adding up each mesh's recorded CPU seconds (its first cut, and
what the rule would have cut after it; the rough pieces' merge and slack, not recorded, as 0.3 s): ``count``, the
library's rule (the whole mesh cut at the affordable divisor, 4 where the first cut made at most twice
``max_convex_hull`` pieces, else 2), and ``slack``, the rule tried (at the threshold divided by the first slack over
1 mm, rounded up, at least 2, at most the affordable divisor; then at the affordable one if still over). ``slack``
saved 12 % of ``gen evaluate``'s decomposition time within the slack criterion but moved labels on thin objects
(docs/cluster.md), so the library keeps ``count``.

Run: ``python -m studies.refine_threshold --mode pipeline|evaluate --out FILE`` (one mode per core), then
``python -m studies.refine_threshold --mode M --replay FILE``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import trimesh

import graspgen.geometry.convex as convex
from bench.bench_prep import LEARN, files, prepare_kwargs
from graspgen.geometry.mesh_io import load_mesh
from graspgen.geometry.repair import repair_mesh
from graspgen.geometry.slack import rough_parts
from graspgen.geometry.units import normalize_units
from pipeline.worker import task_cpu_seconds

DIVISORS = (2, 3, 4)


def _timed(fn, *args):
    start = task_cpu_seconds()
    out = fn(*args)
    return out, task_cpu_seconds() - start


def _cut(mesh: trimesh.Trimesh, hull: trimesh.Trimesh, params: convex.CoacdParams, cap: int) -> dict:
    pieces, seconds = _timed(convex._coacd_pieces, mesh, hull, params, True)
    parts, merge_s = _timed(convex._merged, pieces, cap, params)
    slack, slack_s = _timed(convex._slack_p95, mesh, parts, params)
    return {"pieces": len(pieces), "parts": len(parts), "slack_mm": 1e3 * slack, "cut_s": seconds,
            "merge_s": merge_s, "slack_s": slack_s, "excess": convex._volume_excess(mesh, parts), "_pieces": pieces}


def study(entry: dict, params: convex.CoacdParams) -> dict:
    loaded = load_mesh(entry["mesh"])
    repaired, _ = repair_mesh(loaded)
    mesh, _, _ = normalize_units(repaired, scale=entry["scale"], min_extent=0.005, max_extent=0.5)
    hull = mesh.convex_hull
    row = {"file": entry["file"], "category": entry["category"], "faces": len(mesh.faces),
           "extent_mm": 1e3 * float(np.max(np.ptp(mesh.vertices, axis=0)))}
    if not convex._is_closed(mesh):
        return {**row, "skipped": "not closed"}
    first = _cut(mesh, hull, params, params.max_convex_hull)
    pieces = first.pop("_pieces")
    row["first"] = first
    cap = 4 * params.max_convex_hull
    arrays = [convex._part_arrays(p) for p in pieces]
    rough, row["rough_s"] = _timed(rough_parts, mesh, arrays, params.slack_p95, convex._ROUGH_SHARE,
                                   params.slack_samples, np.random.default_rng(params.seed))
    areas = np.array([0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum()
                      for v, f in arrays])
    row["rough"] = {"count": int(rough.sum()), "area_share": float(areas[rough].sum() / areas.sum())}
    if rough.any():
        recut, seconds = _timed(convex._rough_pieces_recut, mesh, pieces, rough, params)
        merged = convex._merged(recut, cap, params)
        row["rough_recut"] = {"pieces": len(recut), "cut_s": seconds,
                              "slack_mm": 1e3 * convex._slack_p95(mesh, merged, params)}
    if len(pieces) <= 4 * params.max_convex_hull:
        for divisor in DIVISORS:
            finer = _cut(mesh, hull, dataclasses.replace(params, threshold=params.threshold / divisor), cap)
            finer.pop("_pieces")
            row[f"cut_1/{divisor}"] = finer
    return row


def _seconds(cut: dict) -> float:
    return cut["cut_s"] + cut["merge_s"] + cut["slack_s"]


def replay(row: dict, params: convex.CoacdParams, rule: str) -> tuple[float, float, str]:
    """CPU seconds, slack p95 (mm) and the cuts made, of one mesh under ``rule`` (``count`` or ``slack``)."""
    first, target = row["first"], 1e3 * params.slack_p95
    seconds, tries = _seconds(first), [first["slack_mm"]]
    if not (first["excess"] > params.refine_excess and first["slack_mm"] > target):
        return seconds, first["slack_mm"], "first"
    count, hulls = first["pieces"], params.max_convex_hull
    if count > 4 * hulls:
        return seconds, first["slack_mm"], "merged again"
    seconds += row["rough_s"]
    if row["rough"]["area_share"] <= convex._ROUGH_AREA and "rough_recut" in row:
        seconds += row["rough_recut"]["cut_s"] + 0.3
        tries.append(row["rough_recut"]["slack_mm"])
        if tries[-1] <= target:
            return seconds, min(tries), "rough"
    affordable = 4 if count <= 2 * hulls else 2
    needed = affordable if rule == "count" else min(max(math.ceil(first["slack_mm"] / target), 2), affordable)
    made = []
    for divisor in dict.fromkeys((needed, affordable)):
        cut = row[f"cut_1/{divisor}"]
        seconds += _seconds(cut)
        tries.append(cut["slack_mm"])
        made.append(f"1/{divisor}")
        if tries[-1] <= target:
            break
    return seconds, min(tries), " ".join(made)


def _print_replay(rows: list[dict], params: convex.CoacdParams) -> None:
    rows = [r for r in rows if "first" in r]
    results = {rule: [replay(r, params, rule) for r in rows] for rule in ("count", "slack")}
    for row, before, after in zip(rows, results["count"], results["slack"]):
        print(f"{row['file'][:24]:24s} count {before[0]:5.1f} s {before[1]:5.2f} mm {before[2]:12s} "
              f"slack {after[0]:5.1f} s {after[1]:5.2f} mm {after[2]}")
    for rule, out in results.items():
        seconds, slack = np.array([o[0] for o in out]), np.array([o[1] for o in out])
        print(f"{rule}: {len(rows)} meshes, median {np.median(seconds):.2f} s, p90 {np.percentile(seconds, 90):.2f} s, "
              f"total {seconds.sum():.1f} s, slack p95 over 1 mm: {(slack > 1e3 * params.slack_p95).sum()}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mode", choices=("pipeline", "evaluate"), required=True)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--replay", type=Path)
    args = ap.parse_args()
    params = prepare_kwargs(args.mode)["coacd"]
    if args.replay:
        _print_replay(json.loads(args.replay.read_text()), params)
        return
    if args.out is None:
        ap.error("--out FILE is required to run the study (or --replay FILE to replay one)")
    rows = json.loads(args.out.read_text()) if args.out.is_file() else []
    done = {r["file"] for r in rows}
    for entry in files(LEARN, distinct=True):
        if entry["file"] in done:
            continue
        rows.append(study(entry, params))
        print(json.dumps(rows[-1]), flush=True)
        args.out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
