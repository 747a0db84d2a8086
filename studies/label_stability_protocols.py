"""Label stability per protocol: do the outcome labels survive half the timestep? (bar: at most 5% change)

``studies/label_stability.py`` asks this of a finished pipeline run (the ``table`` protocol on a support). This script
asks it of each named protocol (:data:`graspgen.sim.protocols.PROTOCOLS`) on the calibration mug (ACRONYM's example file
in the calibration folder, Panda grasps, the file's mass, friction and scale), through
:func:`graspgen.workflows.evaluate.evaluate_grasps` in free space exactly as ``studies/fidelity.py`` evaluates it:

* baseline: ``LiftParams().with_protocol(p)`` (2 ms timestep, 100 solver iterations, rules checked every 10 steps);
* refined: the same with ``timestep`` halved, ``iterations`` doubled and ``check_interval`` doubled
  (:func:`label_stability.refined`: the rules still look at the same simulated times; only the physics resolution
  changes).

Printed per protocol: the fraction of outcome labels (codes 0-5) that change, the fraction of success labels
(code 5 or not) that change, and the confusion table (rows baseline, columns refined).

Run: ``python -m studies.label_stability_protocols [-j 2] [--limit 300] [--protocols table,acronym,graspdatagen]
[--calibration DIR] [--json PATH]``; ``--limit N`` takes N evenly spaced grasps of the mug's 2,000 (default 300;
0 = all). Writes ``studies/results_label_stability_protocols.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from graspgen.sim.protocols import PROTOCOLS, LiftParams
from studies.calibration import REPO, add_calibration_option, load_cases
from studies.fidelity import SPEED_OBJECT, evaluate
from studies.label_stability import BAR, confusion, print_confusion, refined

RESULTS = Path(__file__).resolve().parent / "results_label_stability_protocols.json"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-j", "--jobs", type=int, default=2, help="worker processes per evaluation (default 2)")
    ap.add_argument("--limit", type=int, default=300, help="evenly spaced grasps of the mug (default 300; 0 = all)")
    ap.add_argument("--protocols", default=",".join(PROTOCOLS), help="comma-separated, default: all")
    ap.add_argument("--gripper", default="panda")
    add_calibration_option(ap)
    ap.add_argument("--cache-dir", type=Path, default=REPO / ".cache", help="CoACD cache (as run.cache_dir)")
    ap.add_argument("--json", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    cases = load_cases(args.calibration, args.limit or None)
    case = next((c for c in cases if c.path.name.startswith(SPEED_OBJECT)), None)
    if case is None:
        raise SystemExit(f"no {SPEED_OBJECT}*.h5 under {args.calibration}")
    result: dict = {"object": case.name, "grasps": int(len(case.T)), "bar": BAR, "protocols": {}}
    print(f"label stability on {case.name} ({len(case.T)} grasps): timestep halved, iterations and check "
          f"interval doubled; bar <= {100 * BAR:.0f}% changed")
    for protocol in [p for p in args.protocols.split(",") if p]:
        base = LiftParams().with_protocol(protocol)
        fine = refined(base)
        t0 = time.perf_counter()
        a = evaluate(case, base, args).column("outcome").to_numpy()
        b = evaluate(case, fine, args).column("outcome").to_numpy()
        seconds = time.perf_counter() - t0
        changed = float(np.mean(a != b))
        success_changed = float(np.mean((a == 5) != (b == 5)))
        verdict = "PASS" if changed <= BAR else "FAIL"
        print(f"\n{protocol}: outcome changed {np.sum(a != b)}/{len(a)} = {100 * changed:.1f}% -> {verdict}; "
              f"success label changed {100 * success_changed:.1f}%; success {np.mean(a == 5):.3f} -> "
              f"{np.mean(b == 5):.3f} ({seconds:.0f} s); rows: baseline, columns: refined")
        print_confusion(confusion(a, b))
        result["protocols"][protocol] = {
            "baseline": {"timestep": base.timestep, "iterations": base.iterations,
                         "check_interval": base.check_interval},
            "refined": {"timestep": fine.timestep, "iterations": fine.iterations,
                        "check_interval": fine.check_interval},
            "fraction_changed": changed, "fraction_success_changed": success_changed, "pass": changed <= BAR,
            "success_baseline": float(np.mean(a == 5)), "success_refined": float(np.mean(b == 5)),
            "confusion_rows_baseline_cols_refined": confusion(a, b).tolist(), "seconds": seconds,
        }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")
    print(f"wrote {args.json}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
