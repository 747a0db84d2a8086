"""Label stability: do the outcome labels survive a finer simulation? (bar: at most 5% of them change)

Takes a finished run (the current config's committed shards, found through the stage manifests) and rolls every
grasp the rollouts stage simulated out again, in the same scene model
(:func:`graspgen.workflows.rollouts.scene_simulator`), with the config's ``rollouts.lift`` changed in the physics only:

* ``timestep`` halved (2 ms -> 1 ms) and solver ``iterations`` doubled (100 -> 200);
* ``check_interval`` doubled, so the rules are still checked at the same simulated times (20 ms): only the physics
  resolution changes, not when the protocol looks.

Grasps the pre-filter labelled (not simulated) are left out: no physics decided them. Reported: the fraction of
simulated grasps whose outcome changes (stored label -> refined label), a confusion table (rows: stored, columns:
refined), the changes per object and each changed grasp. As a sanity check the baseline is re-run too: it must give
the stored labels (the run is up to date with the code and deterministic).

Run: ``python -m studies.label_stability --config configs/default.yaml --out DIR [--json PATH]``; prints the tables
and writes JSON (default ``studies/results_label_stability.json``). Serial, one scene model at a time.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from graspgen.io.arrow import column_array
from graspgen.io.objects import read_object
from graspgen.sim.protocols import OUTCOME_NAMES, LiftParams
from graspgen.sim.scene_model import object_body_name
from graspgen.workflows.rollouts import scene_simulator
from pipeline.config import load_config
from stages.project import PROJECT
from studies.outcome_histogram import SHORT, current_shards

RESULTS = Path(__file__).resolve().parent / "results_label_stability.json"
BAR = 0.05
"""At most this fraction of simulated labels may change under the finer simulation."""


def refined(lift: LiftParams) -> LiftParams:
    """``lift`` with half the timestep, twice the solver iterations, and the rules checked at the same times."""
    return dataclasses.replace(lift, timestep=lift.timestep / 2, iterations=2 * lift.iterations,
                               check_interval=2 * lift.check_interval)


def rerun_scene(scene_path: Path, objects: dict[str, Path], grasps_path: Path, rollouts_path: Path,
                lifts: dict[str, LiftParams]) -> list[dict]:
    """Every simulated grasp of one scene rolled out under each of ``lifts``; one dict per grasp."""
    grasps, rollouts = pq.read_table(grasps_path), pq.read_table(rollouts_path)
    if grasps.column("grasp_id").to_pylist() != rollouts.column("grasp_id").to_pylist():
        raise SystemExit(f"{rollouts_path}: its grasp ids differ from those of {grasps_path}")
    simulated = np.flatnonzero(rollouts.column("simulated").to_numpy(zero_copy_only=False))
    if len(simulated) == 0:
        return []
    poses = column_array(grasps, "pose_world", (4, 4))
    widths = grasps.column("width").to_numpy()
    index = grasps.column("object_index").to_numpy()
    names = grasps.column("object_name").to_pylist()
    stored = rollouts.column("outcome").to_numpy()
    gripper = grasps.column("gripper")[0].as_py()
    rows = [{"scene_id": rollouts.column("scene_id")[0].as_py(), "grasp_id": int(i), "object": names[i],
             "stored": int(stored[i])} for i in simulated]
    for label, lift in lifts.items():
        scene, sim = scene_simulator(scene_path, lambda n: read_object(objects[n]), gripper, lift)
        for row, i in zip(rows, simulated):
            res = sim.rollout(poses[i], float(widths[i]), object_body_name(int(index[i]), scene.object_names[index[i]]))
            row[label] = res.code
    return rows


def confusion(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(6, 6) int counts: rows = ``a`` outcome, columns = ``b`` outcome."""
    table = np.zeros((len(OUTCOME_NAMES), len(OUTCOME_NAMES)), dtype=int)
    np.add.at(table, (a, b), 1)
    return table


def print_confusion(table: np.ndarray) -> None:
    corner = "stored \\ refined"
    print(f"{corner:<17}" + "".join(f"{s:>11}" for s in SHORT))
    for c, row in enumerate(table):
        if row.any() or table[:, c].any():
            print(f"{SHORT[c]:<17}" + "".join(f"{v:>11}" for v in row))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", type=Path, default=None, help="YAML config of the run (defaults when omitted)")
    ap.add_argument("--out", type=Path, default=None, help="output folder of the run (overrides run.out)")
    ap.add_argument("--json", type=Path, default=RESULTS, help=f"JSON result file (default {RESULTS})")
    args = ap.parse_args(argv)
    config = load_config(PROJECT.schema, args.config, [f"run.out={args.out}"] if args.out else [])
    shards = current_shards(PROJECT, config, "rollouts")
    if not shards["rollouts"]:
        raise SystemExit("no rollouts shards of the current config in this folder (`gen status` says why): run "
                         "`gen run rollouts` with the same --config and --out first")
    base = config.rollouts.lift
    lifts = {"baseline": base, "refined": refined(base)}
    start = time.perf_counter()
    rows = []
    for sid in sorted(shards["rollouts"]):
        rows += rerun_scene(shards["scenes"][sid], shards["objects"], shards["grasps"][sid],
                            shards["rollouts"][sid], lifts)
    seconds = time.perf_counter() - start
    if not rows:
        raise SystemExit("no simulated grasps in this run: nothing to compare")
    stored = np.array([r["stored"] for r in rows])
    base_codes = np.array([r["baseline"] for r in rows])
    fine = np.array([r["refined"] for r in rows])
    changed = stored != fine
    n, k = len(rows), int(changed.sum())
    fraction = k / n
    reproduced = int(np.sum(base_codes == stored))
    objects = sorted({r["object"] for r in rows})
    per_object = {o: {"simulated": int(sum(r["object"] == o for r in rows)),
                      "changed": int(sum(r["object"] == o and r["stored"] != r["refined"] for r in rows))}
                  for o in objects}

    print(f"label stability of {config.run.out}: {n} simulated grasps in {len(shards['rollouts'])} scenes, "
          f"re-run at timestep {lifts['refined'].timestep * 1e3:g} ms / {lifts['refined'].iterations} iterations "
          f"({seconds:.1f} s for both passes)")
    print(f"baseline re-run reproduces the stored labels: {reproduced}/{n}")
    verdict = "PASS" if fraction <= BAR else "FAIL"
    print(f"changed: {k}/{n} = {100 * fraction:.1f}% (bar: <= {100 * BAR:.0f}%) -> {verdict}")
    print()
    print_confusion(confusion(stored, fine))
    print()
    print(f"{'object':<12}{'simulated':>10}{'changed':>9}")
    for o, v in per_object.items():
        print(f"{o:<12}{v['simulated']:>10}{v['changed']:>9}")
    changes = [r for r in rows if r["stored"] != r["refined"]]
    if changes:
        print()
        for r in changes:
            print(f"  {r['scene_id']} grasp {r['grasp_id']} ({r['object']}): "
                  f"{OUTCOME_NAMES[r['stored']]} -> {OUTCOME_NAMES[r['refined']]}")
    result = {
        "out": str(config.run.out),
        "config": str(args.config),
        "baseline": {"timestep": base.timestep, "iterations": base.iterations, "check_interval": base.check_interval},
        "refined": {k_: getattr(lifts["refined"], k_) for k_ in ("timestep", "iterations", "check_interval")},
        "simulated_grasps": n,
        "changed": k,
        "fraction_changed": fraction,
        "bar": BAR,
        "pass": fraction <= BAR,
        "baseline_reproduced": reproduced,
        "confusion": {"rows_stored_cols_refined": OUTCOME_NAMES, "counts": confusion(stored, fine).tolist()},
        "per_object": per_object,
        "changes": changes,
        "seconds": seconds,
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")
    print(f"wrote {args.json}", file=sys.stderr)


if __name__ == "__main__":
    main()
