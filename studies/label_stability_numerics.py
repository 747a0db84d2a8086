"""How far the CPU backend's labels hold when only the numerics change: the agreement a float32 backend can expect.

On the ACRONYM files and grasps of a ``studies.warp_agreement`` run (``--warp-json``, default
``studies/results_warp_agreement_cpu_device.json``: the same files, the same evenly spaced grasps), each file's
grasps are rolled out by the CPU backend four times, in one process on one core:

* as the pipeline does (``opt.tolerance`` as the model has it, 1e-8);
* at MJWarp's solver tolerance: ``mujoco_warp.put_model`` raises ``opt.tolerance`` to at least 1e-6 for float32,
  so the warp backend's solver stops earlier than the CPU's (``--tolerance``);
* with the grasp poses and widths rounded to float32, as the warp backend receives them;
* with each grasp moved by ``--nudge`` (10 um by default) in a direction drawn per grasp from a generator seeded by
  the file's name: far below anything a grasp's pose means, so a label that changes is not decided by the physics.

Per protocol, pooled over files: the success-label agreement and Cohen's kappa of each variant against the first
(the same confusion counts as ``studies.warp_agreement``), outcome-code changes, per category; beside them the warp
backend's agreement on the same grasps as that run recorded it, and where its disagreements lie: how many are on
*fragile* grasps (whose CPU label changes under any of the variants) against the fragile share of all grasps. A
label that flips when the solver stops at 1e-6 instead of 1e-8 is not decided by the physics to better than that:
those grasps bound what a float32 engine can agree on.
(``studies/label_stability.py`` asks the other question: do the pipeline's labels survive a finer timestep.)

Run: ``python -m studies.label_stability_numerics [--protocols acronym] [--limit N] [--out FILE]``; writes
``studies/results_label_stability_numerics.json`` (gitignored; the checked-in run with ``--warp-device cpu``:
``studies/results_label_stability_numerics_cpu_device.json``). The JSON is rewritten after every file and
``--resume`` adds to it. ``--warp-device cpu`` rolls the warp backend out in the same process
(its codes then come from the same code and parts as the CPU's, not from the agreement run's JSON).
"""

from __future__ import annotations

import argparse
import json
import os
import zlib

os.environ.setdefault("OMP_NUM_THREADS", "1")

from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from bench.bench_warp import LEARN, ROOT, run_warp, worlds  # noqa: E402
from graspgen.sim.warp_backend import WarpParams  # noqa: E402
from studies.warp_agreement import kappa, record  # noqa: E402

CALIBRATION = ROOT.parent / "shared" / "calibration" / "acronym_more"
WARP_JSON = ROOT / "studies" / "results_warp_agreement_cpu_device.json"
RESULTS = ROOT / "studies" / "results_label_stability_numerics.json"
VARIANTS = ("tolerance", "float32_inputs", "nudge")


def file_path(name: str) -> Path:
    """The ACRONYM file ``name`` in the calibration folder, else in the learning set."""
    calibration = CALIBRATION / name
    return calibration if calibration.exists() else LEARN / name


def rollouts(ew, tolerance: float | None = None, float32: bool = False, nudge: float = 0.0,
             rng: np.random.Generator | None = None) -> list[int]:
    """Outcome codes of the world's grasps on the CPU backend (``tolerance``: at least this solver tolerance;
    ``float32``: poses and widths rounded to float32 first; ``nudge``: each pose translated by this many m in a
    uniformly random direction drawn from ``rng``)."""
    sim = ew.simulator()
    if tolerance is not None:
        sim.model.opt.tolerance = max(float(sim.model.opt.tolerance), tolerance)
    T, widths = np.array(ew.T_world, dtype=np.float64), np.asarray(ew.width)
    if float32:
        T, widths = T.astype(np.float32).astype(np.float64), widths.astype(np.float32).astype(np.float64)
    if nudge:
        direction = rng.normal(size=(len(T), 3))
        T[:, :3, 3] += nudge * direction / np.linalg.norm(direction, axis=1, keepdims=True)
    return record([sim.rollout(t, float(w), ew.target_body) for t, w in zip(T, widths)])["code"]


def file_row(name: str, grasps: int, protocol: str, tolerance: float, nudge: float, warp_codes: list[int] | None,
             row: dict | None = None, warp_device: str | None = None) -> dict:
    """One file's codes: as the pipeline runs, and under each variant ``row`` (a resumed file's) lacks; the warp
    backend's: rolled out here on ``warp_device`` (all the file's grasps in one batch) unless ``row`` has them from
    that device, else ``warp_codes``, the agreement run's."""
    ew = worlds(file_path(name), grasps, protocol, ROOT / ".cache")
    row = dict(row or {})
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    runs = {"codes": lambda: rollouts(ew), "tolerance": lambda: rollouts(ew, tolerance=tolerance),
            "float32_inputs": lambda: rollouts(ew, float32=True), "nudge": lambda: rollouts(ew, nudge=nudge, rng=rng)}
    for key, run in runs.items():
        if key not in row:
            row[key] = run()
    row["n"] = len(ew.T_world)
    if warp_device is not None:
        if row.get("warp_device") != warp_device:
            results, _ = run_warp(ew, WarpParams(device=warp_device, nworld=row["n"]))
            row["warp"], row["warp_device"] = record(results)["code"], warp_device
    elif warp_codes is not None and len(warp_codes) == row["n"]:
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


def fragile(rows: dict) -> dict:
    """Where the warp backend's disagreements with the CPU lie: grasps whose CPU success label changes under any
    variant are fragile; the disagreements on them against the fragile share of all grasps, and the warp backend's
    agreement and kappa on the rest."""
    have = [r for r in rows.values() if "warp" in r and all(k in r for k in VARIANTS)]
    if not have:
        return {}
    base = np.concatenate([np.asarray(r["codes"]) for r in have]) == 5
    warp = np.concatenate([np.asarray(r["warp"]) for r in have]) == 5
    weak = np.zeros_like(base)
    for key in VARIANTS:
        weak |= (np.concatenate([np.asarray(r[key]) for r in have]) == 5) != base
    differ = base != warp
    return {"grasps": int(len(base)), "fragile": int(weak.sum()), "warp_disagreements": int(differ.sum()),
            "warp_disagreements_fragile": int((differ & weak).sum()),
            "robust": {"grasps": int((~weak).sum()), "agreement": float(np.mean(~differ[~weak])),
                       "kappa": kappa(base[~weak], warp[~weak])}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--protocols", default="acronym")
    ap.add_argument("--warp-json", type=Path, default=WARP_JSON)
    ap.add_argument("--tolerance", type=float, default=1e-6, help="MJWarp's floor on opt.tolerance")
    ap.add_argument("--nudge", type=float, default=1e-5, help="m each pose is moved for the nudge variant")
    ap.add_argument("--warp-device", default=None, help="roll the warp backend out here, on this Warp device "
                    "(cpu, cuda:0), instead of taking its codes from --warp-json")
    ap.add_argument("--limit", type=int, default=0, help="first N files only (0: all)")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--resume", action="store_true")
    args = ap.parse_args()
    warp = json.loads(args.warp_json.read_text())
    out = json.loads(args.out.read_text()) if args.resume and args.out.exists() else {"protocols": {}}
    out.update({"warp_json": args.warp_json.name, "tolerance": args.tolerance, "nudge_m": args.nudge})
    for protocol in args.protocols.split(","):
        objects = warp["protocols"][protocol]["objects"]
        names = [n for n, r in objects.items() if "records" in r][: args.limit or None]
        entry = out["protocols"].setdefault(protocol, {"files": {}})
        for name in names:
            done = entry["files"].get(name)
            if done is not None and all(k in done for k in VARIANTS) and (
                    args.warp_device is None or done.get("warp_device") == args.warp_device):
                continue
            entry["files"][name] = file_row(name, warp["grasps_per_file"][name], protocol, args.tolerance,
                                            args.nudge, objects[name]["records"]["warp"]["code"], done,
                                            args.warp_device)
            entry["pooled"] = {k: pooled(entry["files"], k) for k in (*VARIANTS, "warp")}
            entry["fragile"] = fragile(entry["files"])
            args.out.write_text(json.dumps(out, indent=1, sort_keys=True))
            print(protocol, name, {k: entry["pooled"][k]["all"]["success_flips"] for k in entry["pooled"]},
                  flush=True)
    print(args.out)


if __name__ == "__main__":
    main()
