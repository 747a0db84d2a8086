"""Object preparation time per mesh on one core, at the settings the pipeline and ``gen evaluate`` use.

For every ACRONYM file of the learning set (``/work/shared/learn/acronym``: ShapeNetSem meshes of bowls, mugs,
knives, bottles, hats, scissors; README there), its mesh is prepared by
:func:`graspgen.workflows.prepare.prepare_object` at the file's scale, under two settings:

* ``pipeline``: what the ``objects`` stage passes (``stages.objects.ObjectsParams()``: its CoACD and stable-pose
  settings, with the physics settle check; density 700 kg/m^3, at most 0.5 m);
* ``evaluate``: what ``gen evaluate`` / :func:`graspgen.workflows.evaluate.evaluate_grasps` passes in free space
  (``EvaluateParams().coacd``, one pose and no settle check, as
  :func:`graspgen.workflows.evaluation_world.evaluation_world`).

Each preparation runs in a fresh child process (``OMP_NUM_THREADS=1``: one core) with no CoACD cache (it measures
the decomposition, not a cache hit), under a CPU-time cap (``RLIMIT_CPU``; a wall cap, by default 20x, as a
backstop): a mesh over either is reported as ``>`` the CPU seconds it had used when stopped. Reported per mesh: CPU
seconds (of the child and of the CoACD processes it waited for, :func:`pipeline.worker.task_cpu_seconds`), wall
seconds, the seconds of each step (load+repair+units+mass,
decomposition, stable poses), the parts, the way the decomposition was made and the parts' hull slack (p95 and max
mm, :func:`graspgen.geometry.convex.hull_slack`, 20,000 samples, measured after the clock stopped) and the sha256 of
the parts' bytes; then median, p90 and worst CPU seconds, overall and per category, and the worst slack p95.
``--profile`` writes a cProfile of each child (``<out>.prof/<file>.prof``). Run one at a time, ``nice -n 5``.

``--baseline DIR`` runs every mesh also with the code of another tree (``DIR``, e.g. ``git archive`` of the commit
before a change), the two children one after the other (which goes first alternates), so that both see the same
machine: the summary then has the baseline's figures too, and the ratio of the two (per mesh: the median of the CPU
seconds' ratios; overall: of the medians). CPU seconds on a shared machine drift by 10-15 % between runs made hours
apart, more than a change of a few percent; run side by side, they move together.

Run: ``python -m bench.bench_prep [--mode pipeline,evaluate] [--distinct] [--per-category N] [--cap 300]
[--only mug,bowl] [--baseline DIR] [--out FILE]``; ``--distinct`` takes one file per mesh (the set holds some
meshes at several scales), ``--per-category N`` the first N files of each category (a quick run). Writes JSON
(default ``bench/results_bench_prep.json``), merged with what it holds so a run can be resumed.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

LEARN = Path(os.environ.get("GRASPGEN_LEARN", ROOT.parent / "shared" / "learn" / "acronym"))
RESULTS = ROOT / "bench" / "results_bench_prep.json"
MODES = ("pipeline", "evaluate")


def files(folder: Path, distinct: bool, per_category: int = 0) -> list[dict]:
    """The ACRONYM files of ``folder`` as ``{"file", "category", "mesh", "scale"}``, sorted by name (with
    ``per_category`` > 0: only the first that many of each category)."""
    from graspgen.io.acronym import read_acronym

    out, seen = [], set()
    for h5 in sorted(folder.glob("*.h5")):
        acr = read_acronym(h5)
        mesh = str((h5.parent / acr.object_file).resolve())
        if distinct and mesh in seen:
            continue
        seen.add(mesh)
        category = h5.name.split("_")[0].lower()
        if per_category and sum(e["category"] == category for e in out) >= per_category:
            continue
        out.append({"file": h5.name, "category": category, "mesh": mesh, "scale": float(acr.object_scale)})
    return out


def prepare_kwargs(mode: str) -> dict:
    """The keyword arguments of ``prepare_object`` the objects stage (``pipeline``) or ``gen evaluate`` uses."""
    from graspgen.geometry.stable_poses import StablePoseParams
    from graspgen.workflows.evaluate_settings import EvaluateParams

    if mode == "pipeline":
        from stages.objects import ObjectsParams

        p = ObjectsParams()
        return {"density": p.density, "min_extent": p.min_extent, "max_extent": p.max_extent, "coacd": p.coacd,
                "poses": p.stable_poses}
    e = EvaluateParams()
    return {"density": e.density, "max_extent": e.max_extent, "coacd": e.coacd,
            "poses": StablePoseParams(settle_check=False, max_poses=1)}


def child(mesh: str, scale: float, mode: str, profile: str | None) -> dict:
    """Prepare one mesh in this process and time it (and its steps)."""
    import graspgen.workflows.prepare as prepare
    from pipeline.worker import task_cpu_seconds

    steps = {"decomposition": 0.0, "stable_poses": 0.0}
    ways: list[str] = []

    def timed(name, fn):
        def run(*a, **k):
            start = task_cpu_seconds()
            try:
                return fn(*a, **k)
            finally:
                steps[name] += task_cpu_seconds() - start
        return run

    prepare.cached_convex_decomposition = timed("decomposition", prepare.cached_convex_decomposition)
    prepare.stable_poses = timed("stable_poses", prepare.stable_poses)
    kwargs = prepare_kwargs(mode)
    import logging

    class Ways(logging.Handler):
        def emit(self, record):
            ways.append(record.getMessage())

    logging.getLogger("graspgen.geometry.convex").addHandler(Ways())
    logging.getLogger("graspgen.geometry.convex").setLevel(logging.INFO)
    profiler = None
    if profile:
        import cProfile

        profiler = cProfile.Profile()
        profiler.enable()
    cpu, wall = task_cpu_seconds(), time.perf_counter()
    prepared = prepare.prepare_object(mesh, scale=scale, rng=np.random.default_rng(0), coacd_cache_dir=None,
                                      **kwargs)
    cpu, wall = task_cpu_seconds() - cpu, time.perf_counter() - wall
    if profiler is not None:
        profiler.disable()
        profiler.dump_stats(profile)
    steps["other"] = cpu - steps["decomposition"] - steps["stable_poses"]
    return {"cpu_s": cpu, "wall_s": wall, "steps_s": steps, "parts": len(prepared.convex_parts),
            "faces": int(len(prepared.faces)), "poses": int(len(prepared.stable_probabilities)),
            "log": ways[-3:], **_slack(prepared)}


def _slack(prepared) -> dict:
    """Hull slack of the parts (mm; 20,000 samples, seed 0), measured after the clock stopped, and the sha256 of
    the parts' bytes (the same digest before and after a change: the same parts)."""
    import hashlib

    import trimesh

    from graspgen.geometry.convex import hull_slack

    mesh = trimesh.Trimesh(prepared.vertices, prepared.faces, process=False)
    slack = hull_slack(mesh, list(prepared.convex_parts), 20_000, np.random.default_rng(0))
    digest = hashlib.sha256()
    for vertices, faces in prepared.convex_parts:
        digest.update(np.ascontiguousarray(vertices).tobytes() + np.ascontiguousarray(faces).tobytes())
    return {"slack_p95_mm": 1e3 * slack.p95, "slack_max_mm": 1e3 * slack.max, "short_p95_mm": 1e3 * slack.short_p95,
            "parts_sha256": digest.hexdigest()}


def run_one(entry: dict, mode: str, cap: float, wall_cap: float, profile: str | None, root: Path = ROOT) -> dict:
    """Run :func:`child` in a fresh process under the CPU cap (and the wall cap), with the code of the tree ``root``;
    ``cpu_s`` None when capped, with the CPU seconds the child had used when stopped in ``cpu_used_s`` (its rusage,
    once reaped)."""
    def limit():
        resource.setrlimit(resource.RLIMIT_CPU, (int(cap), int(cap) + 5))

    cmd = [sys.executable, "-m", "bench.bench_prep", "--child",
           json.dumps([entry["mesh"], entry["scale"], mode, profile])]
    start, used = time.perf_counter(), _children_cpu()
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=wall_cap, preexec_fn=limit, cwd=root,
                              env={**os.environ, "PYTHONPATH": str(root)})
    except subprocess.TimeoutExpired:  # subprocess.run has killed and reaped it: its rusage is counted
        return {**entry, "mode": mode, "cpu_s": None, "cpu_used_s": _children_cpu() - used,
                "wall_s": time.perf_counter() - start, "capped": "wall"}
    if done.returncode != 0:
        capped = done.returncode in (-24, -9)  # SIGXCPU, SIGKILL at the hard limit
        return {**entry, "mode": mode, "cpu_s": None, "cpu_used_s": _children_cpu() - used,
                "wall_s": time.perf_counter() - start, "capped": "cpu" if capped else None,
                "error": None if capped else done.stderr[-2000:]}
    return {**entry, "mode": mode, **json.loads(done.stdout.strip().splitlines()[-1]), "capped": None}


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def summary(rows: list[dict], cap: float) -> dict:
    """Median, p90 and worst CPU seconds (a capped mesh counts as the cap: the figures are then lower bounds)."""
    def stats(sub):
        t = np.array([cap if r["cpu_s"] is None else r["cpu_s"] for r in sub])
        return {"n": len(sub), "median_s": float(np.median(t)), "p90_s": float(np.percentile(t, 90)),
                "worst_s": float(t.max()), "capped": sum(r["cpu_s"] is None for r in sub),
                "worst_slack_p95_mm": max((r["slack_p95_mm"] for r in sub if "slack_p95_mm" in r), default=None),
                "over_1mm": sum(r.get("slack_p95_mm", 0.0) > 1.0 for r in sub),
                "total_s": float(t.sum())}
    out = {"all": stats(rows)}
    for cat in sorted({r["category"] for r in rows}):
        out[cat] = stats([r for r in rows if r["category"] == cat])
    return out


def _ratio(rows: dict, base: dict, mode: str, chosen: set) -> dict:
    """This tree's CPU seconds against the baseline's, on the meshes both ran uncapped."""
    pairs = [(rows[k]["cpu_s"], base[k]["cpu_s"]) for k in rows
             if k[1] == mode and k[0] in chosen and k in base and rows[k]["cpu_s"] and base[k]["cpu_s"]]
    new, old = np.array(pairs).T if pairs else (np.zeros(0), np.zeros(0))
    return {"n": len(pairs), "median_per_mesh": float(np.median(new / old)) if pairs else float("nan"),
            "of_medians": float(np.median(new) / np.median(old)) if pairs else float("nan"),
            "of_totals": float(new.sum() / old.sum()) if pairs else float("nan")}


def _print_row(tag: str, entry: dict, row: dict) -> None:
    shown = f">{row['cpu_used_s']:.0f}" if row["cpu_s"] is None else f"{row['cpu_s']:.1f}"
    steps = row.get("steps_s", {})
    print(f"{tag:>17} {entry['file'][:48]:48} cpu {shown:>6} s  wall {row['wall_s']:6.1f} s  "
          f"decomp {steps.get('decomposition', 0):6.1f}  poses {steps.get('stable_poses', 0):5.1f}  "
          f"parts {row.get('parts', '-')}  slack p95 {row.get('slack_p95_mm', float('nan')):.2f} mm  "
          f"{row.get('error') or ''}", flush=True)


def _print_summary(title: str, stats: dict, cap: float) -> None:
    print(f"\n{title}: CPU s per mesh (capped at {cap:.0f} s; a capped mesh counts as the cap)")
    print("| category | n | median | p90 | worst | capped | worst slack p95 mm | p95 > 1 mm |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for cat, s in stats.items():
        print(f"| {cat} | {s['n']} | {s['median_s']:.1f} | {s['p90_s']:.1f} | "
              f"{'>' if s['capped'] else ''}{s['worst_s']:.1f} | {s['capped']} | "
              f"{'-' if s['worst_slack_p95_mm'] is None else format(s['worst_slack_p95_mm'], '.2f')} | "
              f"{s['over_1mm']} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mode", default=",".join(MODES), help="comma-separated of: pipeline, evaluate")
    ap.add_argument("--cap", type=float, default=300.0, help="CPU seconds per mesh before it is reported as >cap")
    ap.add_argument("--wall-cap", type=float, default=None, help="wall seconds per mesh (default 20 x --cap)")
    ap.add_argument("--distinct", action="store_true", help="one file per mesh (the first by name)")
    ap.add_argument("--per-category", type=int, default=0, help="only the first N files of each category")
    ap.add_argument("--only", default="", help="comma-separated substrings of file names")
    ap.add_argument("--learn", type=Path, default=LEARN)
    ap.add_argument("--profile", action="store_true", help="cProfile each preparation to <out>.prof/")
    ap.add_argument("--label", default="", help="a name for this run stored in the results (e.g. before, after)")
    ap.add_argument("--baseline", type=Path, default=None, help="another tree to run each mesh with, side by side")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child is not None:
        print(json.dumps(child(*json.loads(args.child))))
        return 0
    modes = [m for m in args.mode.split(",") if m]
    bad = [m for m in modes if m not in MODES]
    if bad:
        ap.error(f"unknown modes {bad}; known: {list(MODES)}")
    words = [w for w in args.only.split(",") if w]
    entries = [e for e in files(args.learn, args.distinct, args.per_category)
               if not words or any(w in e["file"] for w in words)]
    report = json.loads(args.out.read_text()) if args.out.is_file() else {"rows": []}
    known = {(r["file"], r["mode"]): r for r in report["rows"]}
    base = {(r["file"], r["mode"]): r for r in report.get("baseline_rows", [])}
    prof_dir = Path(str(args.out) + ".prof")
    for mode in modes:
        for i, entry in enumerate(entries):
            key = (entry["file"], mode)
            if key in known and (args.baseline is None or key in base):
                continue
            profile = None
            if args.profile:
                prof_dir.mkdir(parents=True, exist_ok=True)
                profile = str(prof_dir / f"{mode}-{entry['file']}.prof")
            runs = [("", ROOT, known)] + ([("baseline ", args.baseline.resolve(), base)] if args.baseline else [])
            for tag, root, rows in runs if i % 2 else runs[::-1]:
                row = run_one(entry, mode, args.cap, args.wall_cap or 20 * args.cap, profile, root)
                rows[key] = row
                _print_row(tag + mode, entry, row)
            report["rows"] = sorted(known.values(), key=lambda r: (r["mode"], r["file"]))
            if args.baseline is not None:
                report["baseline"] = str(args.baseline)
                report["baseline_rows"] = sorted(base.values(), key=lambda r: (r["mode"], r["file"]))
            args.out.write_text(json.dumps(report, indent=1))
    report["cap_s"] = args.cap
    report["label"] = args.label
    chosen = {e["file"] for e in entries}
    report["summary"] = {m: summary([r for r in report["rows"] if r["mode"] == m and r["file"] in chosen], args.cap)
                         for m in modes}
    if args.baseline is not None:
        report["baseline_summary"] = {m: summary([r for r in report["baseline_rows"]
                                                  if r["mode"] == m and r["file"] in chosen], args.cap)
                                      for m in modes}
        report["ratio"] = {m: _ratio(known, base, m, chosen) for m in modes}
    args.out.write_text(json.dumps(report, indent=1))
    for mode in modes:
        _print_summary(mode, report["summary"][mode], args.cap)
        if args.baseline is not None:
            _print_summary(f"{mode}, baseline {args.baseline}", report["baseline_summary"][mode], args.cap)
            r = report["ratio"][mode]
            print(f"{mode}: this tree / baseline, CPU s: median per mesh {r['median_per_mesh']:.3f}, "
                  f"of the medians {r['of_medians']:.3f}, of the totals {r['of_totals']:.3f} ({r['n']} meshes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
