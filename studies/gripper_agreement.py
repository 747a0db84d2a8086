"""Two grippers' labels on the same calibration grasps: how far a gripper given as a robot model (a URDF or MJCF,
``assets/model_grippers``) labels like the bundled hand it stands for, and how each agrees with FleX.

It reads two result files of :mod:`studies.fidelity` run with the same ``--limit``, ``--protocols`` and calibration
folder (one per ``--gripper``) and prints, per object and pooled, FleX's held rate, each gripper's held rate
(outcome 5), each one's agreement and Cohen's kappa against FleX, their agreement and kappa with each other, and the
outcome codes on which they differ (most frequent first).

Run: ``python -m studies.fidelity --protocols acronym --gripper panda --out A.json``, the same with
``--gripper assets/model_grippers/panda_urdf.yaml --out B.json``, then ``python -m studies.gripper_agreement A.json
B.json [--protocol acronym]``.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np

from studies.fidelity import kappa


def _rows(path: Path, protocol: str) -> tuple[str, dict[str, dict]]:
    report = json.loads(path.read_text())
    rows = report["protocols"][protocol]["objects"]
    return report["gripper"]["name"], {r["object"]: r for r in rows}


def _cells(a: np.ndarray, b: np.ndarray, flex: np.ndarray) -> str:
    pairs = ((a, flex), (b, flex), (a, b))
    return " | ".join(f"{np.mean(x == y):.3f} / {kappa(x, y):.2f}" for x, y in pairs)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("first", type=Path, help="studies.fidelity result of the first gripper")
    ap.add_argument("second", type=Path, help="studies.fidelity result of the second gripper, same grasps")
    ap.add_argument("--protocol", default="acronym")
    args = ap.parse_args(argv)
    (name_a, rows_a), (name_b, rows_b) = _rows(args.first, args.protocol), _rows(args.second, args.protocol)
    if set(rows_a) != set(rows_b) or any(rows_a[k]["flex"] != rows_b[k]["flex"] for k in rows_a):
        raise SystemExit("the two result files hold different grasps: run both with the same --limit and folder")
    print(f"{name_a} (a) against {name_b} (b), {args.protocol} protocol; held = outcome 5; cells: agreement / kappa")
    print("| object | n | FleX held | a held | b held | a vs FleX | b vs FleX | a vs b |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    codes_a, codes_b, flex_all = [], [], []
    for obj in sorted(rows_a):
        ca, cb = np.array(rows_a[obj]["codes"]), np.array(rows_b[obj]["codes"])
        flex = np.array(rows_a[obj]["flex"]) == 1
        codes_a.append(ca), codes_b.append(cb), flex_all.append(flex)
        print(f"| {obj} | {len(flex)} | {flex.mean():.3f} | {np.mean(ca == 5):.3f} | {np.mean(cb == 5):.3f} | "
              f"{_cells(ca == 5, cb == 5, flex)} |")
    ca, cb, flex = (np.concatenate(x) for x in (codes_a, codes_b, flex_all))
    print(f"| pooled | {len(flex)} | {flex.mean():.3f} | {np.mean(ca == 5):.3f} | {np.mean(cb == 5):.3f} | "
          f"{_cells(ca == 5, cb == 5, flex)} |")
    differ = Counter(zip(ca[ca != cb].tolist(), cb[ca != cb].tolist()))
    print("outcome codes where they differ (a -> b: count): "
          + ", ".join(f"{x} -> {y}: {n}" for (x, y), n in differ.most_common()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
