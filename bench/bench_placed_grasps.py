"""Placed scene grasps (ACRONYM's way) against today's scene-bound pipeline, per core-hour, on the same scenes.

In one process, pinned to one core where the OS allows it:

1. **Inputs**: the objects and scenes of ``--config`` (default ``configs/smoke.yaml``, ``scenes.num_scenes`` set by
   ``--scenes``) are made with :func:`pipeline.scheduler.run_pipeline` into ``--out`` (finished work is skipped).
   The object grasp sets come from the ``object_grasps`` stage when the project has one (run there too, with the
   config's ``object_grasps`` section); otherwise they are made here by the library,
   :func:`graspgen.workflows.object_grasps.label_object_grasps` (``--per-object`` rows per object, half successes, half
   failures; ``acronym`` protocol in free space); ``--set`` sizes the stage's sets
   (``--set object_grasps.target_grasps=400``). Their cost is reported, not counted in the placed rate: a set is
   made once per object and reused by every scene it appears in (the amortised rate for this bench's scene count is
   printed too).
2. **Placed** (:func:`graspgen.workflows.placed_grasps.place_object_grasps`, default params: grasp pose only, no
   re-simulation): every scene; rows, collision-free rows, ACRONYM scene successes.
3. **Today** (stages ``grasps`` + ``rollouts``): :func:`graspgen.workflows.scene_grasps.sample_scene_grasps` (sampling
   and the pre-filter along the approach) then :func:`graspgen.workflows.rollouts.scene_simulator` +
   :func:`graspgen.workflows.rollouts.roll_out_table` (rollouts of the free ones) with the config's ``grasps`` and
   ``rollouts`` sections and the same task seeds; rows = rows of the rollouts table (every candidate, labelled by
   the pre-filter or a rollout).

Both sides read object records and grasp sets from memory (loaded once before timing), so file reads are not
measured on either. Rates are per CPU-hour of this process (``time.process_time``; the machine is shared, so wall
time is reported too, and the best of ``--rounds`` is kept for each side). Goal: at least 10x today's 38,817 scene
rows per core-hour in collision-free placed grasps per core-hour.

Usage: ``python -m bench.bench_placed_grasps [--config configs/smoke.yaml] [--scenes 12] [--out DIR]
[--per-object 400] [--rounds 2] [--json PATH] [--set KEY=VALUE ...]``
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parent.parent

from graspgen.sim.gl import select_backend  # noqa: E402

select_backend()

import numpy as np  # noqa: E402
import pyarrow as pa  # noqa: E402
import pyarrow.parquet as pq  # noqa: E402

from graspgen.io.objects import read_object  # noqa: E402
from graspgen.workflows.placed_grasps import PlacedGraspsParams, place_object_grasps  # noqa: E402
from graspgen.workflows.rollouts import roll_out_table, scene_simulator  # noqa: E402
from graspgen.workflows.scene_grasps import sample_scene_grasps  # noqa: E402
from pipeline.config import load_config  # noqa: E402
from pipeline.plan import committed  # noqa: E402
from pipeline.scheduler import run_pipeline  # noqa: E402
from pipeline.store import stage_dir  # noqa: E402
from stages.project import PROJECT  # noqa: E402

TODAY_ROWS_PER_CORE_HOUR = 38_817
GOAL_RATIO = 10.0


def _pin_one_core() -> str:
    try:
        cpu = min(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cpu})
        return f"pinned to cpu {cpu}"
    except (AttributeError, OSError):
        return "not pinned"


def _shards(out: Path, stage: str) -> dict[str, Path]:
    return {e.task: stage_dir(out, stage) / e.file for e in committed(out, stage).values()}


def _object_sets_here(records: dict, config, per_object: int) -> dict[str, pa.Table]:
    """The object grasp sets made in this process with the library (no ``object_grasps`` stage in the project):
    :func:`graspgen.workflows.object_grasps.label_object_grasps` with the config's ``object_grasps`` section when it has
    one, else its defaults with the ``grasps`` gripper; half successes, half failures, ``per_object`` in all."""
    from graspgen.workflows.object_grasps import label_object_grasps
    from graspgen.workflows.object_grasps_settings import ObjectGraspsParams

    base = getattr(config, "object_grasps", None) or ObjectGraspsParams(gripper=config.grasps.gripper)
    params = dataclasses.replace(base, selection="balanced", target_positives=per_object // 2,
                                 target_negatives=per_object // 2)
    return {name: label_object_grasps(rec, params, np.random.default_rng(i))[0]
            for i, (name, rec) in enumerate(sorted(records.items()))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default=str(ROOT / "configs" / "smoke.yaml"))
    ap.add_argument("--scenes", type=int, default=12)
    ap.add_argument("--out", default=str(ROOT / "build" / "bench_placed_grasps"))
    ap.add_argument("--per-object", type=int, default=400)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--json", default=None)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="config override (e.g. object_grasps.target_grasps=400); repeatable")
    args = ap.parse_args()
    pinned = _pin_one_core()
    out = Path(args.out)
    cfg = load_config(PROJECT.schema, args.config, [f"run.out={out}", f"run.cache_dir={out / 'cache'}", "run.jobs=1",
                                                     f"scenes.num_scenes={args.scenes}", *args.set])
    has_stage = any(s.name == "object_grasps" for s in PROJECT.stages)
    run_pipeline(PROJECT, cfg, ["scenes", "object_grasps"] if has_stage else ["scenes"])
    objects, scenes = _shards(out, "objects"), _shards(out, "scenes")
    records = {n: read_object(p) for n, p in objects.items()}
    t0 = time.process_time()
    if has_stage:
        sets = {n: pq.read_table(p) for n, p in _shards(out, "object_grasps").items()}
        # The stage's own timing (wall seconds of each task, from its manifest): run with --jobs 1, one core each.
        sets_cpu = sum(float(e.meta.get("seconds", 0.0)) for e in committed(out, "object_grasps").values())
        sets_source = "object_grasps stage, wall s from its manifest"
    else:
        sets = _object_sets_here(records, cfg, args.per_object)
        sets_source, sets_cpu = "label_object_grasps in this process, CPU s", time.process_time() - t0
    set_rows = sum(len(t) for t in sets.values())

    def placed_round() -> dict:
        c0, w0 = time.process_time(), time.perf_counter()
        rows = free = success = ground = clutter = 0
        for k, (_sid, path) in enumerate(sorted(scenes.items())):
            table, meta = place_object_grasps(path, records.__getitem__, sets.get, PlacedGraspsParams(),
                                              np.random.default_rng(k))
            rows += len(table)
            free += meta["scene_codes"]["free"]
            ground += meta["scene_codes"]["collision_with_ground"]
            clutter += meta["scene_codes"]["collision_with_clutter"]
            success += meta["success"]
        return {"rows": rows, "free": free, "support": ground, "clutter": clutter, "success": success,
                "cpu_s": time.process_time() - c0, "wall_s": time.perf_counter() - w0}

    def today_round() -> dict:
        c0, w0 = time.process_time(), time.perf_counter()
        rows = simulated = success = 0
        for k, (_sid, path) in enumerate(sorted(scenes.items())):
            grasps, _ = sample_scene_grasps(path, records.__getitem__, cfg.grasps, np.random.default_rng(k))
            scene, sim = scene_simulator(path, records.__getitem__, cfg.grasps.gripper, cfg.rollouts.lift)
            table = roll_out_table(scene, sim, grasps, cfg.rollouts)
            rows += len(table)
            simulated += int(np.sum(table.column("simulated").to_numpy(zero_copy_only=False)))
            success += int((table.column("outcome").to_numpy() == 5).sum())
        return {"rows": rows, "simulated": simulated, "success": success, "cpu_s": time.process_time() - c0,
                "wall_s": time.perf_counter() - w0}

    placed = min((placed_round() for _ in range(args.rounds)), key=lambda r: r["cpu_s"])
    today = min((today_round() for _ in range(args.rounds)), key=lambda r: r["cpu_s"])

    def per_hour(n: int, s: float) -> float:
        return n / s * 3600.0 if s > 0 else float("inf")

    free_rate = per_hour(placed["free"], placed["cpu_s"])
    today_rate = per_hour(today["rows"], today["cpu_s"])
    summary = {
        "config": str(args.config), "scenes": len(scenes), "objects": len(records), "cpu": pinned,
        "object_sets": {"source": sets_source, "rows": set_rows,
                        "seconds": None if sets_cpu is None else round(sets_cpu, 2)},
        "placed": {**placed, "free_per_core_hour": round(free_rate),
                   "rows_per_core_hour": round(per_hour(placed["rows"], placed["cpu_s"])),
                   "free_per_core_hour_wall": round(per_hour(placed["free"], placed["wall_s"]))},
        "today": {**today, "rows_per_core_hour": round(today_rate),
                  "rolled_out_per_core_hour": round(per_hour(today["simulated"], today["cpu_s"])),
                  "rows_per_core_hour_wall": round(per_hour(today["rows"], today["wall_s"]))},
        "ratio_free_vs_today_rows": round(free_rate / today_rate, 1),
        "ratio_free_vs_today_reference_38817": round(free_rate / TODAY_ROWS_PER_CORE_HOUR, 1),
        "ratio_free_vs_today_rolled_out": round(free_rate / per_hour(today["simulated"], today["cpu_s"]), 1),
    }
    if sets_cpu is not None:
        summary["placed"]["free_per_core_hour_with_object_sets"] = round(
            per_hour(placed["free"], placed["cpu_s"] + sets_cpu))
    print(f"{len(scenes)} scenes, {len(records)} objects, {set_rows} object-level grasps ({sets_source}"
          + (f", {sets_cpu:.1f} s" if sets_cpu is not None else "") + f"); {pinned}")
    print(f"placed: {placed['rows']} rows, {placed['free']} collision-free ({placed['support']} support, "
          f"{placed['clutter']} clutter collisions), {placed['success']} scene successes in "
          f"{placed['cpu_s']:.3f} CPU s ({placed['wall_s']:.3f} s wall): {free_rate:,.0f} collision-free placed "
          "grasps per core-hour")
    print(f"today (grasps + rollouts stages): {today['rows']} rows ({today['simulated']} rolled out, "
          f"{today['success']} successes) in {today['cpu_s']:.2f} CPU s ({today['wall_s']:.2f} s wall): "
          f"{today_rate:,.0f} rows per core-hour")
    print(f"ratio: {summary['ratio_free_vs_today_rows']}x today's rows on the same scenes, "
          f"{summary['ratio_free_vs_today_reference_38817']}x the reference {TODAY_ROWS_PER_CORE_HOUR:,} "
          f"(goal >= {GOAL_RATIO:g}x); {summary['ratio_free_vs_today_rolled_out']}x today's rolled-out (free) rows")
    if sets_cpu is not None:
        print(f"with the object sets' one-off cost over these {len(scenes)} scenes: "
              f"{summary['placed']['free_per_core_hour_with_object_sets']:,} collision-free per core-hour")
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=2) + "\n")


if __name__ == "__main__":
    main()
