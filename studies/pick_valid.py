"""Pick on the validation files: network (c) with the library's defaults, ``gen probe pick`` on each of the 18.

Trains network (c) as :mod:`studies.learnability` does (the default :class:`graspgen.learn.train.TrainParams`, on a
``gen run object_grasps`` run of the 51 training files) and runs ``gen probe pick`` with the default
:class:`graspgen.learn.pick.PickParams` (the hand check included) on every validation file: the top 10 of 1,000
candidates, 10 random ones from all candidates and 10 from those clear of the open hand, rolled out at each
file's density and friction. Only the picks: ``studies/learnability.py --pick`` also trains (a), (b), (b').

Run: ``python -m studies.pick_valid --ours RUN [--seed 1] [--out FILE]``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from studies.learnability import DEFAULT_LEARN, HERE, _files, _group, _is_valid, _train, file_pick, run_sets


def main() -> None:
    from graspgen.learn.pick import pick, simulate_pick

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--learn", type=Path, default=DEFAULT_LEARN)
    ap.add_argument("--ours", type=Path, required=True, help="run folder of gen run object_grasps (training files)")
    ap.add_argument("--seed", type=int, default=0, help="training draws, candidates and random picks")
    ap.add_argument("-j", "--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=HERE / "results_pick_valid.json")
    args = ap.parse_args()
    start = time.perf_counter()
    model, timing = _train(run_sets(args.ours), args.seed, args.jobs)
    print("trained", timing, flush=True)
    rows = []
    for f in [f for f in _files(args.learn) if _is_valid(_group(f))]:
        mesh, params, rng = file_pick(f, 1000, args.seed)
        out = simulate_pick(pick(model, mesh, params, rng), model.gripper, params, jobs=args.jobs)
        out.pop("top_scores")
        out.pop("random_scores")
        rows.append({"name": f.stem, **out})
        print(f"  {f.stem[:44]:<44} top {out['top_success']:.1f} ({out['top_firm']:.1f}) random "
              f"{out['random_success']:.1f} random clear {out['random_clear_success']:.1f} clear "
              f"{out['clear_candidates']} {out['top_outcomes']}", flush=True)
    summary = {k: float(np.mean([r[k] for r in rows])) for k in ("top_success", "top_firm", "random_success",
                                                                 "random_firm", "random_clear_success")}
    summary["files_at_0.9"] = int(sum(r["top_success"] >= 0.9 - 1e-9 for r in rows))
    print(summary, f"{time.perf_counter() - start:.0f} s")
    args.out.write_text(json.dumps({"seed": args.seed, "members": model.train_info.get("members", 1),
                                    "train": timing, "summary": summary, "objects": rows}, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
