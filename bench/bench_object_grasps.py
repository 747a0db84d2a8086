"""Throughput of object-centric grasp sets: labelled grasps per core-hour on the bundled objects, one core.

Two measurements, in one process:

* **throughput**: every bundled object (``assets/objects``) prepared as the objects stage does (repair, units,
  mass from the catalog density, CoACD parts from the ``.cache/coacd`` cache; no stable-pose physics check: free
  space does not use it), then :func:`graspgen.workflows.object_grasps.label_object_grasps` with the Panda and the
  ``acronym`` protocol, once per selection (``--selections``), in this process: ``natural`` (the default set:
  ``--grasps`` collision-free grasps, default 200, firm label) and ``balanced`` (the sets before 2026-12-07:
  ``--positives`` / ``--negatives`` targets, default 100 / 100, held label, near misses, the sampler's class
  defaults), both at most
  ``--max-candidates`` (3,000). Labelled grasps per core-hour = kept rows / CPU seconds of the labelling
  (``time.process_time``: the machine may be shared, so wall time would charge us for other processes) x 3,600;
  wall-clock figures are printed beside it. Preparing the meshes is not counted (the objects stage's work, cached).
* **baseline ratio**: on one object (``--baseline-object``, default the mug) ``--baseline-n`` candidates (default
  300) labelled with every candidate kept (targets above ``max_candidates``), then the same poses rolled out by
  plain :func:`graspgen.workflows.evaluate.evaluate_grasps` (same mesh, CoACD settings, mass, friction, gripper and
  protocol, one job) in the same process. evaluate's rate is the slope of two timed calls (``n`` and 10 poses), so
  preparing the mesh and compiling the model do not count; ours includes sampling, near misses, the epsilon and
  the table. Same poses, same outcome mix: the ratio is our overhead per rollout (1.0 = none; < 1: slower).

The goal: at least 100,000 labelled grasps per core-hour (27.8 per CPU second).

Usage: ``python -m bench.bench_object_grasps [--grasps 200] [--positives 100] [--negatives 100]
[--max-candidates 3000] [--selections natural,balanced] [--objects box,mug] [--baseline-object mug] [--baseline-n 300]
[--out bench/results_object_grasps.json]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

# One core: no BLAS / OpenMP thread pools.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent

from graspgen.geometry.antipodal import AntipodalParams  # noqa: E402
from graspgen.geometry.stable_poses import StablePoseParams  # noqa: E402
from graspgen.io.arrow import column_array  # noqa: E402
from graspgen.io.objects import ObjectRecord  # noqa: E402
from graspgen.workflows.evaluate import evaluate_grasps  # noqa: E402
from graspgen.workflows.evaluate_settings import CHEAP_COACD, EvaluateParams  # noqa: E402
from graspgen.workflows.object_grasps import label_object_grasps  # noqa: E402
from graspgen.workflows.object_grasps_settings import ObjectGraspsParams  # noqa: E402
from graspgen.workflows.prepare import prepare_object  # noqa: E402
from stages.objects import ASSETS, catalog  # noqa: E402

GOAL_PER_CORE_HOUR = 100_000.0
COACD = CHEAP_COACD  # the same parts for our labelling and for evaluate_grasps' own preparation
CACHE = ROOT / ".cache" / "coacd"


def prepare(name: str) -> ObjectRecord:
    """A bundled object as an object record (what the objects stage would write, minus the stable poses)."""
    entry = catalog()[name]
    prep = prepare_object(ASSETS / entry["file"], density=float(entry["density"]), coacd=COACD,
                          poses=StablePoseParams(settle_check=False, max_poses=1), rng=np.random.default_rng(0),
                          coacd_cache_dir=CACHE)
    return ObjectRecord(
        name=name, vertices=np.asarray(prep.vertices), faces=np.asarray(prep.faces),
        convex_parts=[(np.asarray(v), np.asarray(f)) for v, f in prep.convex_parts], mass=float(prep.mass.mass),
        center_of_mass=np.asarray(prep.mass.center_of_mass), inertia=np.asarray(prep.mass.inertia),
        stable_poses=np.asarray(prep.stable_transforms), stable_probabilities=np.asarray(prep.stable_probabilities),
        attrs={},
    )


def throughput(names: list[str], params: ObjectGraspsParams) -> dict:
    rows, cpu_total, wall_total = [], 0.0, 0.0
    print(f"{'object':<10} {'tried':>6} {'kept':>5} {'pos':>4} {'neg':>4} {'reached':>7} {'coll.':>6} "
          f"{'anti ok':>7} {'near ok':>7} {'cpu s':>6} {'/cpu-h':>9}")
    for name in names:
        record = prepare(name)
        c0, w0 = time.process_time(), time.perf_counter()
        table, meta = label_object_grasps(record, params, np.random.default_rng(0))
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        cpu_total += cpu
        wall_total += wall
        rate = meta["success_rate"]
        collisions = sum(meta["outcomes"][k] for k in ("collision_with_ground", "collision_with_target",
                                                         "collision_with_clutter")) / max(meta["tried"], 1)
        row = {"object": name, "tried": meta["tried"], "kept": len(table), "positives": meta["positives"],
               "negatives": meta["negatives"], "reached": meta["reached"], "collision_share": collisions,
               "success_rate": rate, "outcomes": meta["outcomes"], "cpu_s": cpu, "wall_s": wall,
               "per_core_hour": len(table) / cpu * 3600.0 if cpu > 0 else None}
        rows.append(row)

        def pct(x):
            return "    -  " if x is None else f"{100 * x:6.1f}%"

        print(f"{name:<10} {meta['tried']:>6} {len(table):>5} {meta['positives']:>4} {meta['negatives']:>4} "
              f"{str(meta['reached']):>7} {100 * collisions:5.1f}% {pct(rate['antipodal'])} {pct(rate['near_miss'])} "
              f"{cpu:6.2f} {row['per_core_hour']:9.0f}", flush=True)
    kept = sum(r["kept"] for r in rows)
    tried = sum(r["tried"] for r in rows)
    out = {"objects": rows, "kept": kept, "tried": tried, "cpu_s": cpu_total, "wall_s": wall_total,
           "per_core_hour": kept / cpu_total * 3600.0, "per_wall_hour": kept / wall_total * 3600.0,
           "rollouts_per_cpu_s": tried / cpu_total}
    print(f"all: {kept} labelled grasps ({tried} rollouts) in {cpu_total:.1f} CPU s ({wall_total:.1f} s wall): "
          f"{out['per_core_hour']:,.0f} labelled grasps per core-hour (goal {GOAL_PER_CORE_HOUR:,.0f}: "
          f"{'met' if out['per_core_hour'] >= GOAL_PER_CORE_HOUR else 'NOT met'}); {out['per_wall_hour']:,.0f} per "
          f"wall-clock hour; {out['rollouts_per_cpu_s']:.1f} rollouts per CPU second", flush=True)
    return out


def baseline(name: str, n: int, params: ObjectGraspsParams) -> dict:
    record = prepare(name)
    every = ObjectGraspsParams(**{**{f: getattr(params, f) for f in ("gripper", "protocol", "friction")},
                                  "selection": "balanced", "target_positives": n, "target_negatives": n,
                                  "max_candidates": n,
                                  "collision_share_of_negatives": 1.0})  # every candidate, collisions too
    c0 = time.process_time()
    table, meta = label_object_grasps(record, every, np.random.default_rng(1))
    ours_cpu = time.process_time() - c0
    assert len(table) == n == meta["tried"], (len(table), meta["tried"])
    T = column_array(table, "pose_object", (4, 4))
    entry = catalog()[name]
    ev = EvaluateParams(lift=every.lift, friction=every.friction, mass=record.mass, coacd=COACD)
    mesh = ASSETS / entry["file"]

    def timed(k: int):
        c = time.process_time()
        labels = evaluate_grasps(mesh, None, T[:k], None, every.gripper, ev, cache_dir=CACHE.parent)
        return time.process_time() - c, labels

    timed(10)  # warm: imports, caches
    small, _ = timed(10)
    large, labels = timed(n)
    ev_rate = (n - 10) / max(large - small, 1e-9)
    ours_rate = n / ours_cpu
    same = float(np.mean(labels.column("outcome").to_numpy() == table.column("outcome").to_numpy()))
    out = {"object": name, "n": n, "ours_rollouts_per_cpu_s": ours_rate, "evaluate_rollouts_per_cpu_s": ev_rate,
           "ratio": ours_rate / ev_rate, "same_outcome": same, "outcomes": meta["outcomes"]}
    print(f"baseline on {name}, the same {n} poses: label_object_grasps {ours_rate:.1f} rollouts/CPU s (sampling, "
          f"near misses, epsilon and table included), evaluate_grasps {ev_rate:.1f} rollouts/CPU s (slope of {n} "
          f"and 10 poses): ratio {out['ratio']:.2f}; same outcome on {100 * same:.1f}% of the poses", flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--grasps", type=int, default=200, help="natural selection: collision-free grasps per object")
    ap.add_argument("--positives", type=int, default=100, help="balanced selection: positives per object")
    ap.add_argument("--negatives", type=int, default=100, help="balanced selection: negatives per object")
    ap.add_argument("--max-candidates", type=int, default=3000)
    ap.add_argument("--selections", default="natural,balanced",
                    help="comma-separated: natural (the default set: firm label), balanced (the sets before "
                         "2026-12-07: held label, near misses); each measured in this process")
    ap.add_argument("--objects", default=",".join(e for e in sorted(catalog())), help="comma-separated names")
    ap.add_argument("--baseline-object", default="mug")
    ap.add_argument("--baseline-n", type=int, default=300)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results_object_grasps.json")
    args = ap.parse_args(argv)
    settings = {
        "natural": ObjectGraspsParams(selection="natural", label="firm", target_grasps=args.grasps,
                                      max_candidates=args.max_candidates),
        "balanced": ObjectGraspsParams(selection="balanced", label="held", target_positives=args.positives,
                                       target_negatives=args.negatives, max_candidates=args.max_candidates,
                                       sampler=AntipodalParams(approach="any")),  # the sets before 2026-12-07
    }
    results: dict = {"throughput": {}}
    for selection in args.selections.split(","):
        params = settings[selection]
        print(f"\n{selection}: gripper {params.gripper}, protocol {params.protocol}, label {params.label}, targets "
              + (f"{args.grasps} collision-free" if selection == "natural" else
                 f"{args.positives} / {args.negatives} ({params.near_misses_per_batch} near misses per batch)")
              + f", at most {args.max_candidates} candidates; python {platform.python_version()}", flush=True)
        results["throughput"][selection] = throughput(args.objects.split(","), params)
    rates = {k: v["per_core_hour"] for k, v in results["throughput"].items()}
    if len(rates) == 2:
        results["ratio_natural_to_balanced"] = rates["natural"] / rates["balanced"]
        print(f"\nkept grasps per core-hour: natural {rates['natural']:,.0f}, balanced {rates['balanced']:,.0f}: "
              f"ratio {results['ratio_natural_to_balanced']:.2f}", flush=True)
    results.update(baseline=baseline(args.baseline_object, args.baseline_n, settings["natural"]),
                   goal_per_core_hour=GOAL_PER_CORE_HOUR, platform=platform.platform())
    args.out.write_text(json.dumps(results, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
