"""Outcome histogram per object of a finished run: how each object's grasps ended (codes 0-5).

Reads the rollouts and grasps tables of the current config's committed shards (found through the stage manifests,
like ``gen status``), joins them on ``(scene_id, grasp_id)`` and takes ``object_name`` from the grasps table. Counts
every grasp, simulated or labelled by the pre-filter (a ``simulated`` column says how many were simulated, and the
success rate is given both over all grasps and over the simulated ones).

Run: ``python -m studies.outcome_histogram --config configs/default.yaml --out DIR [--json PATH]``; prints a table and
writes JSON (default ``studies/results_outcome_histogram.json``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from graspgen.sim.protocols import OUTCOME_NAMES
from pipeline.config import load_config
from pipeline.plan import Project, committed, plan, upstream_view
from pipeline.stage import topological_order
from pipeline.store import stage_dir
from stages.project import PROJECT

RESULTS = Path(__file__).resolve().parent / "results_outcome_histogram.json"
SHORT = ("ground", "target", "clutter", "no_contact", "slipped", "success")
"""Column headers for the outcome codes 0-5 (the full names are in the JSON)."""


def current_shards(project: Project, config: Any, stage: str) -> dict[str, dict[str, Path]]:
    """``{stage name: {task id: shard path}}`` of ``stage`` and everything upstream of it: the committed shards whose
    keys belong to the current config (older configs' shards in the same folder are ignored)."""
    out = Path(config.run.out)
    keys: dict[str, set[str]] = {}
    shards: dict[str, dict[str, Path]] = {}
    for s in topological_order(project.stages, [stage]):
        planned = plan(s, s.params(config), upstream_view(out, s, keys, verify_hash=False), seed=config.run.seed)
        keys[s.name] = {p.key for p in planned}
        entries = committed(out, s.name, verify_hash=False)
        folder = stage_dir(out, s.name)
        shards[s.name] = {p.task.id: folder / str(entries[p.key].file) for p in planned if p.key in entries}
    return shards


def joined_table(shards: dict[str, dict[str, Path]]) -> pa.Table:
    """Rollouts joined with their grasps (``object_name``, ``prefilter_code``) over all scenes, scene order."""
    parts = []
    for sid in sorted(shards["rollouts"]):
        # list columns (contacts) cannot go through Arrow's join, and the histogram needs none of them
        r = pq.read_table(shards["rollouts"][sid], columns=["scene_id", "grasp_id", "outcome", "simulated"])
        g = pq.read_table(shards["grasps"][sid], columns=["scene_id", "grasp_id", "object_name", "prefilter_code"])
        parts.append(r.join(g, keys=["scene_id", "grasp_id"], join_type="inner").sort_by([("grasp_id", "ascending")]))
        if len(parts[-1]) != len(r):
            raise SystemExit(f"{sid}: {len(r)} rollout rows but {len(parts[-1])} joined with the grasps table")
    if not parts:
        raise SystemExit("no rollouts shards of the current config in this folder (`gen status` says why): run "
                         "`gen run rollouts` with the same --config and --out first")
    return pa.concat_tables(parts)


def histogram(table: pa.Table) -> dict[str, dict[str, Any]]:
    """Per object (sorted by name; ``ALL`` last): counts per outcome, grasps, simulated, success rates."""
    names = np.asarray(table.column("object_name").to_pylist(), dtype=object)
    outcome = table.column("outcome").to_numpy()
    simulated = table.column("simulated").to_numpy(zero_copy_only=False)
    result: dict[str, dict[str, Any]] = {}
    for name in [*sorted(set(names)), "ALL"]:
        sel = np.ones(len(names), dtype=bool) if name == "ALL" else names == name
        counts = {OUTCOME_NAMES[c]: int(np.sum(outcome[sel] == c)) for c in range(len(OUTCOME_NAMES))}
        n, n_sim = int(sel.sum()), int(simulated[sel].sum())
        ok = counts["success"]
        result[name] = {
            "grasps": n,
            "simulated": n_sim,
            "outcomes": counts,
            "success_rate": ok / n if n else float("nan"),
            "success_rate_simulated": ok / n_sim if n_sim else float("nan"),
        }
    return result


def print_table(hist: dict[str, dict[str, Any]]) -> None:
    header = f"{'object':<12}{'grasps':>7}{'sim':>5}" + "".join(f"{s:>11}" for s in SHORT)
    header += f"{'ok/all':>8}{'ok/sim':>8}"
    print(header)
    print("-" * len(header))
    for name, h in hist.items():
        if name == "ALL":
            print("-" * len(header))
        cells = "".join(f"{h['outcomes'][o]:>11}" for o in OUTCOME_NAMES)
        print(f"{name:<12}{h['grasps']:>7}{h['simulated']:>5}{cells}"
              f"{h['success_rate']:>8.2f}{h['success_rate_simulated']:>8.2f}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", type=Path, default=None, help="YAML config of the run (defaults when omitted)")
    ap.add_argument("--out", type=Path, default=None, help="output folder of the run (overrides run.out)")
    ap.add_argument("--json", type=Path, default=RESULTS, help=f"JSON result file (default {RESULTS})")
    args = ap.parse_args(argv)
    config = load_config(PROJECT.schema, args.config, [f"run.out={args.out}"] if args.out else [])
    table = joined_table(current_shards(PROJECT, config, "rollouts"))
    hist = histogram(table)
    print(f"outcomes per object in {config.run.out} ({len(table)} grasps)")
    print_table(hist)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"out": str(config.run.out), "config": str(args.config), "objects": hist},
                                    indent=2, sort_keys=True) + "\n")
    print(f"wrote {args.json}", file=sys.stderr)


if __name__ == "__main__":
    main()
