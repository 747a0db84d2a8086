"""Hull slack: how far the convex parts MuJoCo collides stand out of the true surface, per CoACD setting.

For each calibration object (every ACRONYM file under the calibration folder, its mesh at the file's scale) and
each bundled object (``assets/objects``), the mesh is prepared as :func:`graspgen.workflows.prepare.prepare_object`
prepares it (load, repair, units: the same bytes, so the same CoACD cache entries as ``gen evaluate`` and the
objects stage), decomposed with each candidate setting below and measured with
:func:`graspgen.geometry.convex.hull_slack` (the union's boundary, area-sampled: max and 95th percentile of the
distance outside the mesh; and how deep parts fall short inside it). The decomposition time is CoACD on one core
(``OMP_NUM_THREADS=1``; CPU seconds), as first computed: a cached decomposition keeps the time recorded in the results
file.

The criterion, fixed before any agreement with FleX was looked at (``studies/fidelity.py``):

    p95 slack <= TARGET_TOUCH_DEPTH / 2 = 1 mm on every calibration object (the bundled objects are reported,
    not held to it: ``gen evaluate`` is what the calibration files measure), at no more than MAX_SECONDS = 600 s
    of CoACD on one core for any of them.

Why: the rollout's touch rule (:data:`graspgen.sim.prefilter.TARGET_TOUCH_DEPTH`, 2 mm) lets a finger press 2 mm into
the target before the touch is a collision, and gives the palm nothing. That depth is meant in the object, but it
is measured in the parts, so wherever the parts stand ``s`` out of the surface a finger is flagged at ``2 mm - s``
of true depth and the palm at ``s`` of clearance. With ``s <= 1 mm`` on 95 % of the surface a brushing finger
(which a real pad does by compressing 1-2 mm) still has at least half its allowance, and the palm's false clearance
is within the 1 mm band of a position-controlled hand and its pads' compliance (0.1-0.3 mm in the simulation). Of the
settings meeting it, the one with the least total decomposition time on the calibration objects is chosen; none
meeting it on every object, the one with the smallest worst p95 (the tightest) within the time bound. The time
bound (added once the first decomposition times were seen, still before any agreement): ``gen evaluate`` decomposes
a mesh once (then cached) before its first rollout, and ten minutes is already longer than rolling out a whole
ACRONYM file of 2,000 grasps on two cores.

The candidates (others as ``CHEAP_COACD``: resolution 1000, 30 MCTS iterations, depth 3, 20 nodes, refine_excess
0.1) vary what sets the slack (measured on the calibration mug while writing this script):

* ``threshold`` / ``max_convex_hull``: CoACD's concavity bound, relative to the object's size (CoACD normalises the
  mesh to its bounding box), so a part may stand out by ~threshold x half the largest extent; a thin-walled
  object's parts exceed its volume by > 10 % and are redone once at a quarter of the threshold and four times the
  hulls (``CoacdParams.refine_excess``);
* ``preprocess_resolution``: a mesh CoACD does not find manifold (self-intersecting triangles, e.g. a handle pushed
  into the body; here the example mug and the hat: the others take the same time at every resolution) is first
  rebuilt as the 0.55-voxel level set of a grid of that many cells per axis, i.e. dilated by about a voxel's half
  (relative to size too): a 3 mm mug wall comes out a few mm thicker at 30.

Since issue 24 every candidate also carries ``CoacdParams``' newer defaults: ``preprocess_mode="unless_watertight"``
(no voxel rebuild of a mesh that is closed after repair, so ``preprocess_resolution`` only matters for open or
self-intersecting input the repair leaves open), the near-convex skip and the slack-judged refinement (criterion
``slack_p95`` = the 1 mm here); results recorded before that are under other cache keys and are recomputed.

CoACD is not monotone in these: a lower threshold can end with fewer, larger parts (merged down to the hull bound,
or left unrefined), so every candidate is measured rather than inferred.

Run: ``python -m studies.hull_slack [--settings cheap,t05_h32_r60] [--objects mug,bowl] [--samples 20000] [-j 1]``;
writes ``studies/results_hull_slack.json`` (merged with what it holds, so runs can be split and resumed).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core per decomposition: the times are per core

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from graspgen.geometry.convex import (  # noqa: E402
    CoacdParams,
    cached_convex_decomposition,  # the cache of gen evaluate and the objects stage, so the fidelity run reuses it
    coacd_cache_key,
    convex_decomposition,
    hull_slack,
    write_parts,
)
from graspgen.geometry.mesh_io import load_mesh  # noqa: E402
from graspgen.geometry.repair import repair_mesh  # noqa: E402
from graspgen.geometry.units import normalize_units  # noqa: E402
from graspgen.io.acronym import read_acronym  # noqa: E402
from graspgen.sim.prefilter import TARGET_TOUCH_DEPTH  # noqa: E402
from graspgen.workflows.evaluate_settings import CHEAP_COACD, EvaluateParams  # noqa: E402
from studies.calibration import REPO, STUDIES, add_calibration_option  # noqa: E402

RESULTS = STUDIES / "results_hull_slack.json"
P95_LIMIT = TARGET_TOUCH_DEPTH / 2  # m, the criterion (module docstring)
MAX_SECONDS = 600.0  # s of CoACD on one core for any calibration object (module docstring)


def _setting(threshold: float, hulls: int, resolution: int) -> CoacdParams:
    return dataclasses.replace(CHEAP_COACD, threshold=threshold, max_convex_hull=hulls,
                               preprocess_resolution=resolution)


SETTINGS: dict[str, CoacdParams] = {
    "cheap": CoacdParams(threshold=0.1, max_convex_hull=8, preprocess_resolution=30, resolution=1000,
                         mcts_iterations=30, mcts_nodes=20),  # CHEAP_COACD before issue 11
    "t05_h32_r30": _setting(0.05, 32, 30),
    "t05_h32_r60": _setting(0.05, 32, 60),
    "t05_h32_r120": _setting(0.05, 32, 120),
    "t03_h32_r60": _setting(0.03, 32, 60),
    "t02_h32_r60": _setting(0.02, 32, 60),
    "t05_h32_r60_m20": dataclasses.replace(_setting(0.05, 32, 60), mcts_iterations=20, mcts_nodes=10),
}
"""Candidate settings by name: ``t<threshold x 100>_h<max hulls>_r<preprocess resolution>``, ``_m20``: 20 MCTS
iterations of 10 nodes (CoACD's search budget per cut, what its time is proportional to) instead of 30 of 20."""


@dataclasses.dataclass(frozen=True)
class Obj:
    name: str
    path: Path
    scale: float | None
    max_extent: float
    calibration: bool


def objects(calibration: Path) -> list[Obj]:
    out = []
    for h5 in sorted(calibration.rglob("*.h5")):
        acr = read_acronym(h5)
        stem = h5.stem.split("_")
        example = stem[0] == "even"
        stem = stem[1:] if example else stem
        name = f"{stem[0].lower()} {stem[1][:6]}" + (" (ex)" if example else "")
        out.append(Obj(name, h5.parent / acr.object_file, acr.object_scale, EvaluateParams().max_extent, True))
    for path in sorted((REPO / "assets" / "objects").glob("*.obj")):
        out.append(Obj(path.stem, path, None, 0.5, False))  # as the objects stage: detected units, 0.5 m at most
    return out


def prepared_mesh(obj: Obj):
    """The mesh prepare_object decomposes: loaded, repaired, in metres (the same bytes: the same cache key)."""
    repaired, _ = repair_mesh(load_mesh(obj.path))
    mesh, _, _ = normalize_units(repaired, scale=obj.scale, min_extent=0.005, max_extent=obj.max_extent)
    return mesh


def measure(obj: Obj, name: str, params: CoacdParams, cache_dir: Path, samples: int, known: dict | None,
            fresh: bool) -> dict:
    mesh = prepared_mesh(obj)
    entry = cache_dir / "coacd" / f"coacd-{coacd_cache_key(mesh, params)}.npz"
    timed = known is not None and known.get("key") == entry.name and known.get("time_s") is not None
    if entry.is_file() and (timed or not fresh):  # cached: the time of its first computation, where recorded
        parts = cached_convex_decomposition(mesh, params, cache_dir / "coacd")
        seconds = known["time_s"] if timed else None
    else:  # --fresh times a cached one again, untimed so far (CoACD is deterministic: the same parts)
        start = time.process_time()  # CPU seconds: the machine may be shared
        parts = convex_decomposition(mesh, params)
        seconds = time.process_time() - start
        if not entry.is_file():
            write_parts(entry, parts)
    slack = hull_slack(mesh, parts, samples, np.random.default_rng(0))
    return {
        "object": obj.name, "setting": name, "calibration": obj.calibration, "key": entry.name,
        "extent_m": float(max(mesh.extents)), "parts": len(parts), "time_s": seconds,
        "slack_max_mm": 1e3 * slack.max, "slack_p95_mm": 1e3 * slack.p95,
        "short_max_mm": 1e3 * slack.short_max, "short_p95_mm": 1e3 * slack.short_p95,
        "samples": slack.samples,
    }


def _load(path: Path) -> dict:
    if path.is_file():
        return json.loads(path.read_text())
    return {"rows": []}


def _key(row: dict) -> tuple[str, str]:
    return row["object"], row["setting"]


def choose(rows: list[dict], names: list[str]) -> tuple[str | None, dict]:
    """The cheapest setting meeting the criterion on every calibration object, else the tightest; only settings
    measured on all of them within the time bound (an unrecorded time, a cached entry's, counts as within)."""
    everyone = {r["object"] for r in rows if r["calibration"]}
    summary = {}
    for name in names:
        mine = [r for r in rows if r["setting"] == name and r["calibration"]]
        if not mine:
            continue
        times = [r["time_s"] for r in mine]
        slowest = max((t for t in times if t is not None), default=0.0)
        summary[name] = {
            "objects": len(mine), "worst_p95_mm": max(r["slack_p95_mm"] for r in mine),
            "worst_object": max(mine, key=lambda r: r["slack_p95_mm"])["object"],
            "total_time_s": None if any(t is None for t in times) else float(sum(times)), "slowest_s": slowest,
            "eligible": {r["object"] for r in mine} == everyone and slowest <= MAX_SECONDS,
        }
        summary[name]["meets"] = summary[name]["worst_p95_mm"] <= 1e3 * P95_LIMIT + 1e-9
    eligible = [n for n, s in summary.items() if s["eligible"]]
    meeting = [n for n in eligible if summary[n]["meets"]]
    if meeting:
        return min(meeting, key=lambda n: summary[n]["total_time_s"] or float("inf")), summary
    if eligible:
        return min(eligible, key=lambda n: summary[n]["worst_p95_mm"]), summary
    return None, summary


def fmt(value, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--settings", default=",".join(SETTINGS), help=f"comma-separated, of: {', '.join(SETTINGS)}")
    ap.add_argument("--objects", default="", help="comma-separated substrings of object names (default: all)")
    ap.add_argument("--samples", type=int, default=20_000, help="area samples per measurement")
    ap.add_argument("-j", "--jobs", type=int, default=1, help="worker processes (one decomposition each)")
    add_calibration_option(ap)
    ap.add_argument("--fresh", action="store_true", help="recompute cached decompositions that have no recorded time")
    ap.add_argument("--cache-dir", type=Path, default=REPO / ".cache", help="CoACD cache (as run.cache_dir)")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    names = [n for n in args.settings.split(",") if n]
    unknown = [n for n in names if n not in SETTINGS]
    if unknown:
        ap.error(f"unknown settings {unknown}; known: {list(SETTINGS)}")
    words = [w for w in args.objects.split(",") if w]
    objs = [o for o in objects(args.calibration) if not words or any(w in o.name for w in words)]

    report = _load(args.out)
    known = {_key(r): r for r in report["rows"]}
    jobs = [(o, n) for n in names for o in objs]
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        futures = [pool.submit(measure, o, n, SETTINGS[n], args.cache_dir, args.samples, known.get((o.name, n)),
                               args.fresh)
                   for o, n in jobs]
        for future in futures:
            row = future.result()
            known[_key(row)] = row
            print(f"{row['object']:>16} {row['setting']:>13}: {row['parts']:4d} parts {fmt(row['time_s'], 0):>5} s  "
                  f"slack max {row['slack_max_mm']:.2f} p95 {row['slack_p95_mm']:.2f} mm, "
                  f"short max {row['short_max_mm']:.2f} p95 {row['short_p95_mm']:.2f} mm", flush=True)
            report["rows"] = sorted(known.values(), key=lambda r: (r["setting"], r["object"]))
            report["settings"] = {n: dataclasses.asdict(p) for n, p in SETTINGS.items()}
            args.out.write_text(json.dumps(report, indent=1))

    rows = report["rows"]
    shown = [n for n in SETTINGS if any(r["setting"] == n for r in rows)]
    print("\nslack p95 / max (mm), parts, CoACD seconds on one core:\n")
    print("| object | extent m | " + " | ".join(shown) + " |")
    print("| --- | ---: | " + " | ".join("---:" for _ in shown) + " |")
    for name in dict.fromkeys(r["object"] for r in rows):
        cells = []
        for s in shown:
            r = known.get((name, s))
            cells.append("-" if r is None else f"{r['slack_p95_mm']:.2f} / {r['slack_max_mm']:.2f}, {r['parts']}, "
                         f"{fmt(r['time_s'], 0)} s")
        extent = next(r["extent_m"] for r in rows if r["object"] == name)
        print(f"| {name} | {extent:.3f} | " + " | ".join(cells) + " |")
    chosen, summary = choose(rows, shown)
    print(f"\ncriterion: p95 <= {1e3 * P95_LIMIT:.1f} mm on every calibration object, <= {MAX_SECONDS:.0f} s each")
    for name, s in summary.items():
        print(f"  {name}: worst p95 {s['worst_p95_mm']:.2f} mm ({s['worst_object']}) over {s['objects']} objects, "
              f"{fmt(s['total_time_s'], 0)} s in all, slowest {s['slowest_s']:.0f} s: "
              f"{'meets' if s['meets'] else 'fails'}{'' if s['eligible'] else ' (not eligible)'}")
    print(f"chosen: {chosen}")
    report["criterion"] = {"p95_limit_mm": 1e3 * P95_LIMIT, "max_seconds": MAX_SECONDS, "summary": summary,
                           "chosen": chosen}
    args.out.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
