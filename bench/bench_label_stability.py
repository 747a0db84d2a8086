"""How far the CPU backend's labels hold when only the numerics change: the agreement a float32 backend can expect.

On the ACRONYM files and grasps of a ``bench_warp`` agreement run (``--warp-json``, default
``bench/results_bench_warp_agreement_cpu_device.json``: the same files, the same evenly spaced grasps), each file's
grasps are rolled out by the CPU backend three times, in one process on one core:

* as the pipeline does (``opt.tolerance`` as the model has it, 1e-8);
* at MJWarp's solver tolerance: ``mujoco_warp.put_model`` raises ``opt.tolerance`` to at least 1e-6 for float32,
  so the warp backend's solver stops earlier than the CPU's (``--tolerance``);
* with the grasp poses and widths rounded to float32, as the warp backend receives them.

Per protocol, pooled over files: the success-label agreement and Cohen's kappa of each variant against the first
(the same confusion counts as ``bench_warp``), outcome-code changes, per category; beside them the warp backend's
agreement on the same grasps as that run recorded it. A label that flips when the solver stops at 1e-6 instead of
1e-8 is not decided by the physics to better than that: those grasps bound what a float32 engine can agree on.
(``studies/label_stability.py`` asks the other question: do the pipeline's labels survive a finer timestep.)

Run: ``python -m bench.bench_label_stability [--protocols acronym] [--limit N] [--out FILE]``; the JSON is rewritten
after every file and ``--resume`` adds to it.
"""

from __future__ import annotations

import argparse
import json
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from bench.bench_warp import LEARN, ROOT, kappa, record, worlds  # noqa: E402

CALIBRATION = ROOT.parent / "shared" / "calibration" / "acronym_more"
WARP_JSON = ROOT / "bench" / "results_bench_warp_agreement_cpu_device.json"
RESULTS = ROOT / "bench" / "results_label_stability.json"
VARIANTS = ("tolerance", "float32_inputs")


def file_path(name: str) -> Path:
    """The ACRONYM file ``name`` in the calibration folder, else in the learning set."""
    calibration = CALIBRATION / name
    return calibration if calibration.exists() else LEARN / name


def rollouts(ew, tolerance: float | None = None, float32: bool = False) -> list[int]:
    """Outcome codes of the world's grasps on the CPU backend (``tolerance``: at least this solver tolerance;
    ``float32``: poses and widths rounded to float32 first)."""
    sim = ew.simulator()
    if tolerance is not None:
        sim.model.opt.tolerance = max(float(sim.model.opt.tolerance), tolerance)
    T, widths = np.asarray(ew.T_world), np.asarray(ew.width)
    if float32:
        T, widths = T.astype(np.float32).astype(np.float64), widths.astype(np.float32).astype(np.float64)
    return record([sim.rollout(t, float(w), ew.target_body) for t, w in zip(T, widths)])["code"]


def file_row(name: str, grasps: int, protocol: str, tolerance: float, warp_codes: list[int] | None) -> dict:
    """One file's codes: as the pipeline runs, and under each variant."""
    ew = worlds(file_path(name), grasps, protocol, ROOT / ".cache")
    row = {"n": len(ew.T_world), "codes": rollouts(ew), "tolerance": rollouts(ew, tolerance=tolerance),
           "float32_inputs": rollouts(ew, float32=True)}
    if warp_codes is not None and len(warp_codes) == row["n"]:
        row["warp"] = warp_codes
    return row


def pooled(rows: dict, key: str) -> dict:
    """Success agreement, kappa and code changes of ``key`` against the CPU's own codes, over the rows that have
    it, overall and per category (the file name's first word)."""
    def figures(sub: list[dict]) -> dict:
        base = np.concatenate([np.asarray(r["codes"]) for r in sub])
        other = np.concatenate([np.asarray(r[key]) for r in sub])
        a, b = base == 5, other == 5
        return {"grasps": int(len(base)), "success_flips": int(np.sum(a != b)), "agreement": float(np.mean(a == b)),
                "kappa": kappa(a, b), "code_changes": int(np.sum(base != other))}

    have = {n: r for n, r in rows.items() if key in r}
    if not have:
        return {}
    categories = sorted({n.split("_")[0] for n in have})
    return {"all": figures(list(have.values())),
            "by_category": {c: figures([r for n, r in have.items() if n.split("_")[0] == c]) for c in categories}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--protocols", default="acronym")
    ap.add_argument("--warp-json", type=Path, default=WARP_JSON)
    ap.add_argument("--tolerance", type=float, default=1e-6, help="MJWarp's floor on opt.tolerance")
    ap.add_argument("--limit", type=int, default=0, help="first N files only (0: all)")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--resume", action="store_true")
    args = ap.parse_args()
    warp = json.loads(args.warp_json.read_text())
    out = json.loads(args.out.read_text()) if args.resume and args.out.exists() else {"protocols": {}}
    out.update({"warp_json": args.warp_json.name, "tolerance": args.tolerance})
    for protocol in args.protocols.split(","):
        objects = warp["protocols"][protocol]["objects"]
        names = [n for n, r in objects.items() if "records" in r][: args.limit or None]
        entry = out["protocols"].setdefault(protocol, {"files": {}})
        for name in names:
            if name in entry["files"]:
                continue
            entry["files"][name] = file_row(name, warp["grasps_per_file"][name], protocol, args.tolerance,
                                            objects[name]["records"]["warp"]["code"])
            entry["pooled"] = {k: pooled(entry["files"], k) for k in (*VARIANTS, "warp")}
            args.out.write_text(json.dumps(out, indent=1, sort_keys=True))
            print(protocol, name, {k: entry["pooled"][k]["all"]["success_flips"] for k in entry["pooled"]},
                  flush=True)
    print(args.out)


if __name__ == "__main__":
    main()
