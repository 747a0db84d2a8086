"""The grasps MuJoCo and Bullet disagree on: which of MuJoCo's settings decides them?

``studies/second_reference.py`` labels the calibration grasps with the ``acronym`` protocol in MuJoCo (ours) and in
Bullet and writes every label to ``studies/results_second_reference.json``. This script reads those labels and, per
object, takes the *disputed* grasps (by default the ones MuJoCo holds and Bullet loses; ``--direction bullet``
for the other way) and a *control* set of grasps both engines hold (the first ``--control`` of them), then labels
both sets again with MuJoCo under one setting changed at a time:

* ``default``: the protocol as it is (it must reproduce the MuJoCo labels of the results file: a check);
* ``impratio 1``: MuJoCo's default friction-to-normal impedance ratio instead of our 10 (soft friction: slow slip
  under a tangential load inside the cone);
* ``solimp .99/.999``: stiffer contacts (``AcronymParams.contact_solimp``: the constraint impedance near 1, less
  penetration, in the limit a hard contact like Bullet's);
* ``timestep 1 ms``: half the time step, solver iterations and check interval doubled (as
  ``studies/label_stability_protocols.py``);
* ``pyramidal``: MuJoCo's pyramidal friction cone instead of the elliptic one.

Printed per object: how many grasps are disputed, how many of them FleX holds, and for each setting the share held
among the disputed and among the control grasps. A setting that flips the disputed grasps but keeps the control ones
is the one that decides them; if it flips the control ones too, it changes everything, not just the disputed.

Run: ``python -m studies.disputed_grasps [-j 2] [--objects hat,knife] [--direction mujoco|bullet] [--control 100]
[--results studies/results_second_reference.json]``; writes ``studies/results_disputed_grasps.json`` (gitignored).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from graspgen.sim.protocols import LiftParams
from studies.calibration import REPO, STUDIES, add_calibration_option, load_cases
from studies.fidelity import evaluate

RESULTS_IN = STUDIES / "results_second_reference.json"
RESULTS_OUT = STUDIES / "results_disputed_grasps.json"
SUCCESS = 5


def variants() -> dict[str, LiftParams]:
    """MuJoCo settings to try, one changed at a time from the ``acronym`` protocol's."""
    base = LiftParams(protocol="acronym")
    stiff = dataclasses.replace(base.acronym, contact_solimp=(0.99, 0.999, 0.001, 0.5, 2.0))
    return {
        "default": base,
        "impratio 1": dataclasses.replace(base, impratio=1.0),
        "solimp .99/.999": dataclasses.replace(base, acronym=stiff),
        "timestep 1 ms": dataclasses.replace(base, timestep=base.timestep / 2, iterations=2 * base.iterations,
                                             check_interval=2 * base.check_interval),
        "pyramidal": dataclasses.replace(base, cone="pyramidal"),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-j", "--jobs", type=int, default=1)
    ap.add_argument("--objects", type=str, default="", help="comma-separated parts of object names (default: all)")
    ap.add_argument("--direction", choices=("mujoco", "bullet"), default="mujoco",
                    help="disputed = held by this engine and lost by the other")
    ap.add_argument("--control", type=int, default=100, help="grasps both engines hold, per object")
    ap.add_argument("--results", type=Path, default=RESULTS_IN, help="second_reference.py's results file")
    add_calibration_option(ap)
    ap.add_argument("--cache-dir", type=Path, default=REPO / ".cache")
    ap.add_argument("--out", type=Path, default=RESULTS_OUT)
    args = ap.parse_args()
    args.gripper = "panda"
    if not args.results.exists():
        raise SystemExit(f"{args.results} not found: run studies/second_reference.py first")
    saved = json.loads(args.results.read_text())
    if saved.get("limit") is not None:
        raise SystemExit(f"{args.results} was made with --limit {saved['limit']}: this script needs a full run")
    codes = {k: np.asarray(v) for k, v in saved["codes"].items()}
    cases = load_cases(args.calibration, None)
    if sum(len(c.T) for c in cases) != len(codes["flex"]):
        raise SystemExit(f"{args.results} has {len(codes['flex'])} labels, the calibration folder "
                         f"{sum(len(c.T) for c in cases)} grasps: not the same files")
    wanted = [w for w in args.objects.split(",") if w.strip()]
    rows, start = [], 0
    for case in cases:
        stop = start + len(case.T)
        mj, bt, flex = (codes[k][start:stop] for k in ("mujoco", "bullet", "flex"))
        start = stop
        if wanted and not any(w in case.name for w in wanted):
            continue
        if not np.array_equal(flex, case.flex):
            raise SystemExit(f"{case.name}: the FleX labels of {args.results} differ from the file's")
        held_here, held_there = (mj == SUCCESS, bt == SUCCESS) if args.direction == "mujoco" else \
            (bt == SUCCESS, mj == SUCCESS)
        disputed = np.flatnonzero(held_here & ~held_there)
        control = np.flatnonzero((mj == SUCCESS) & (bt == SUCCESS))[:args.control]
        if len(disputed) == 0:
            print(f"{case.name:18s} nothing disputed")
            continue
        idx = np.concatenate([disputed, control])
        row = {"object": case.name, "disputed": int(len(disputed)), "flex_holds_disputed": int(flex[disputed].sum()),
               "control": int(len(control)), "held": {}}
        print(f"{case.name:18s} {args.direction} holds, the other loses: {len(disputed)} (FleX holds "
              f"{row['flex_holds_disputed']}); control (both hold): {len(control)}", flush=True)
        for name, lift in variants().items():
            t0 = time.perf_counter()
            out = evaluate(case, lift, args, T=case.T[idx]).column("outcome").to_numpy()
            if name == "default" and not np.array_equal(out, mj[idx]):
                print(f"   warning: the default setting gives {int(np.sum(out != mj[idx]))} labels other than the "
                      f"results file's (another version of the code or of MuJoCo?)")
            held = out == SUCCESS
            row["held"][name] = {"disputed": float(held[:len(disputed)].mean()),
                                 "control": float(held[len(disputed):].mean()) if len(control) else None}
            print(f"   {name:18s} held among disputed {held[:len(disputed)].mean():.2f}, among control "
                  f"{held[len(disputed):].mean() if len(control) else float('nan'):.2f} "
                  f"({time.perf_counter() - t0:.0f} s)", flush=True)
        rows.append(row)
    args.out.write_text(json.dumps({"direction": args.direction, "results": str(args.results), "objects": rows},
                                   indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
