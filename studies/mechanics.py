"""Mechanics cases: where the simulator's labels flip against Coulomb friction's threshold, per case, bundled
gripper and protocol (:mod:`graspgen.workflows.mechanics`).

Run: ``python -m studies.mechanics [--grippers panda,...] [--protocols acronym,graspdatagen,table] [--kinds
slip,heavy,pivot,wedge] [--json PATH]``; one process, one core, ~2-4 minutes for the whole matrix. Writes
``studies/results_mechanics.json``.

Trimmed from the matrix (and why): ``wedge`` x ``table`` (the wedge must widen away from the palm to be squeezed
out along the approach, so on a table it would stand on its narrow end, and the table under it would stop the
ejection); ``heavy`` x ``graspdatagen`` (its tug is the object's weight with nothing added: the same case as ``slip``).
Per case the table shows the analytic threshold under the protocol's disturbance and with it off (``rest``), and
where the success label and the firm hold (5 mm / 5 degrees) flip, with their errors against the analytic value.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

from graspgen.workflows import mechanics
from studies.calibration import REPO

GRIPPERS = ("panda", "robotiq_2f85_mesh", "robotiq_2f85", "box_jaw")
PROTOCOLS = ("acronym", "graspdatagen", "table")
TRIMMED = {("wedge", "table"), ("heavy", "graspdatagen")}
RESULTS = Path(__file__).resolve().parent / "results_mechanics.json"


def _fmt(v: float) -> str:
    return f"{v:>8}" if math.isinf(v) else f"{v:8.4g}"


def _err(v: float) -> str:
    return f"{'':>6}" if not math.isfinite(v) else f"{100 * v:+5.0f}%"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grippers", default=",".join(GRIPPERS))
    ap.add_argument("--protocols", default=",".join(PROTOCOLS))
    ap.add_argument("--kinds", default=",".join(mechanics.CASES))
    ap.add_argument("--rel-tol", type=float, default=0.03, help="bisection tolerance, relative (default 0.03)")
    ap.add_argument("--cache-dir", type=Path, default=REPO / ".cache", help="CoACD cache (as run.cache_dir)")
    ap.add_argument("--json", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    rows, t0 = [], time.perf_counter()
    print(f"{'case':6} {'gripper':18} {'protocol':8} {'variable':14} {'analytic':>8} {'rest':>8} {'label':>8} "
          f"{'err':>6} {'firm':>8} {'err':>6} {'n':>3} {'s':>5}")
    for kind in args.kinds.split(","):
        for gripper in args.grippers.split(","):
            for protocol in args.protocols.split(","):
                if (kind, protocol) in TRIMMED:
                    continue
                t = time.perf_counter()
                r = mechanics.run_case(kind, gripper, protocol, cache_dir=args.cache_dir, rel_tol=args.rel_tol)
                e = r.error
                print(f"{kind:6} {gripper:18} {protocol:8} {r.variable:14} {_fmt(r.analytic)} {_fmt(r.analytic_rest)} "
                      f"{_fmt(r.label)} {_err(e[0])} {_fmt(r.firm)} {_err(e[1])} {r.rollouts:3d} "
                      f"{time.perf_counter() - t:5.1f}", flush=True)
                rows.append({**r.to_dict(), "seconds": time.perf_counter() - t})
    total = time.perf_counter() - t0
    print(f"{len(rows)} cases in {total:.0f} s; trimmed: {sorted(TRIMMED)}")
    rows = [{k: (str(v) if isinstance(v, float) and not math.isfinite(v) else v) for k, v in row.items()}
            for row in rows]  # JSON has no inf: "inf" = held over the whole range, "-inf" = failed at its low end
    args.json.write_text(json.dumps({"cases": rows, "seconds": total, "trimmed": sorted(TRIMMED)}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
