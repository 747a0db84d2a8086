"""How far the warp backend's labels agree with the CPU backend's (MuJoCo Warp against MuJoCo, same grasps).

For each protocol (``acronym``, ``graspdatagen``, ``table``; ``table`` on a support, the object settled on it in its
most probable stable pose, the jaws opened to the ray-cast width plus the margin, as ``gen evaluate --support``
does), on the device it finds (the first CUDA GPU, else Warp's CPU device; ``--device`` picks one): the calibration
grasps (ACRONYM files: the first ``--objects`` of ``--calibration``, default all five of
``../shared/calibration/acronym_more``, and the first ``--learn-objects`` of ``--learn``, default
``../shared/learn/acronym``; ``--grasps`` / ``--learn-grasps`` evenly spaced grasps of each, Panda) rolled out by both
backends. Per protocol: the success-label agreement and Cohen's kappa (warp vs CPU), the outcome-code agreement, the
firm-label agreement, the same over the grasps that reached the device (not decided at placement, which both
backends decide with the same CPU code), the flip rate of the success label between two warp runs of the same
grasps (MJWarp's contact order is not fixed across runs) on the first ``--flip-objects`` objects, steps per rollout
and each object's first-run (compile) time.

Each object runs in a fresh child process (``-X faulthandler``; ``--retries`` more tries when one crashes): a crash of
native code (CoACD has segfaulted in a long run) loses that object's try only. The JSON is rewritten after every
object, with each object's per-grasp codes (``records``), so ``--resume`` adds objects to a run and the pooled
figures pool the confusion counts of every object; a crashed object is ``{"crashed": [...]}`` and is tried again by
``--resume``. ``studies/label_stability_numerics.py`` reads the JSON (its files and grasps).

Run: ``python -m studies.warp_agreement [--device cuda:0] [--protocols acronym,graspdatagen,table] [--out FILE]
[--skip N] [--limit N] [--resume]``; writes ``studies/results_warp_agreement.json`` (gitignored; the checked-in run
on Warp's CPU device: ``studies/results_warp_agreement_cpu_device.json``). Throughput: ``bench/bench_warp.py``.
Needs the warp extra (``pip install -e '.[warp]'``).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import resource
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np

from bench.bench_warp import (
    LEARN,
    ROOT,
    add_cache_arguments,
    add_device_arguments,
    pick_device,
    run_cpu,
    run_warp,
    start_warp,
    subset,
    worlds,
)
from graspgen.sim.warp_backend import WARP_PROTOCOLS, WarpParams

RESULTS = ROOT / "studies" / "results_warp_agreement.json"


def kappa(a: np.ndarray, b: np.ndarray) -> float:
    """Cohen's kappa of two binary label vectors (NaN when chance agreement is 1)."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    if len(a) == 0:
        return math.nan
    po = float(np.mean(a == b))
    pe = float(np.mean(a) * np.mean(b) + np.mean(~a) * np.mean(~b))
    return (po - pe) / (1.0 - pe) if pe < 1.0 else math.nan


def record(results: list | None) -> dict | None:
    """The per-grasp columns the agreement needs (plain lists: they go into the JSON, so a resumed or merged run
    pools the confusion counts of every object): outcome code, firm label, steps, decided at placement."""
    if results is None:
        return None
    return {"code": [int(r.code) for r in results], "firm": [bool(r.firm) for r in results],
            "steps": [int(r.steps) for r in results], "placement": [r.decided_in == "placement" for r in results]}


def _cat(records: list[dict]) -> dict:
    keys = ("code", "firm", "steps", "placement")
    return {k: [v for r in records for v in r[k]] for k in keys}


def _take(rec: dict, idx) -> dict:
    return {k: [v[i] for i in idx] for k, v in rec.items()}


def _labels(cpu: dict, warp: dict) -> dict:
    c, w = np.array(cpu["code"], dtype=int), np.array(warp["code"], dtype=int)
    f, fw = np.array(cpu["firm"], bool), np.array(warp["firm"], bool)
    n = len(c)
    cs, ws = c == 5, w == 5
    return {"n": n, "cpu_success": int(np.sum(cs)), "warp_success": int(np.sum(ws)),
            "success_agreement": float(np.mean(cs == ws)) if n else math.nan,
            "success_kappa": kappa(cs, ws), "outcome_agreement": float(np.mean(c == w)) if n else math.nan,
            "firm_agreement": float(np.mean(f == fw)) if n else math.nan, "firm_kappa": kappa(f, fw),
            "success_confusion": {"both": int(np.sum(cs & ws)), "cpu_only": int(np.sum(cs & ~ws)),
                                  "warp_only": int(np.sum(~cs & ws)), "neither": int(np.sum(~cs & ~ws))},
            "cpu_outcomes": np.bincount(c, minlength=6).tolist(), "warp_outcomes": np.bincount(w, minlength=6).tolist()}


def agreement(cpu: dict, warp1: dict, warp2: dict | None) -> dict:
    """Warp against CPU (:func:`record` s) over all grasps and over those that reached the device; flips between
    two warp runs."""
    out = _labels(cpu, warp1)
    reached = [i for i, p in enumerate(cpu["placement"]) if not p]
    out["reached_device"] = {k: v for k, v in _labels(_take(cpu, reached), _take(warp1, reached)).items()
                             if not isinstance(v, list)}
    out["steps_per_rollout_cpu"] = float(np.mean(cpu["steps"])) if cpu["steps"] else math.nan
    out["steps_per_rollout_warp"] = float(np.mean(warp1["steps"])) if warp1["steps"] else math.nan
    if warp2 is not None:
        w1, w2 = np.array(warp1["code"][:len(warp2["code"])]), np.array(warp2["code"])
        out.update({"flip_n": int(len(w2)), "flip_rate_success": float(np.mean((w1 == 5) != (w2 == 5))),
                    "flip_rate_outcome": float(np.mean(w1 != w2)),
                    "flip_n_reached_device": int(sum(not p for p in warp2["placement"]))})
    return out


def object_row(path: Path, grasps: int, protocol: str, flip: bool, device: str, nworld: int, cache: Path) -> dict:
    """Both backends on one file's grasps (a second warp run when ``flip``): the row of one object."""
    ew = worlds(path, grasps, protocol, cache)
    cpu, cpu_s = run_cpu(ew)
    # worlds = the grasps that reach the device (placement is the same CPU code on both backends; a grasp the CPU
    # run did not decide there and warp did would only start one more batch): on Warp's CPU device a launch costs
    # per world, stepped or idle
    nworld = min(nworld, max(1, sum(r.decided_in != "placement" for r in cpu)))
    w1, t1 = run_warp(ew, WarpParams(device=device, nworld=nworld))
    w2 = run_warp(ew, WarpParams(device=device, nworld=nworld))[0] if flip else None
    records = {"cpu": record(cpu), "warp": record(w1), "warp2": record(w2)}
    return {**agreement(records["cpu"], records["warp"], records["warp2"]), "nworld": nworld,
            "cpu_rollouts_per_cpu_s": len(cpu) / max(cpu_s, 1e-9),
            "warp_rollouts_per_wall_s": len(cpu) / t1["rollout_wall_s"],
            "warp_rollouts_per_cpu_s": len(cpu) / max(t1["cpu_s"], 1e-9), "warp_cpu_s": t1["cpu_s"],
            "cpu_cpu_s": cpu_s, "first_run_wall_s": t1["init_s"] + t1["rollout_wall_s"],
            "first_run_cpu_s": t1["init_cpu_s"] + t1["cpu_s"], "records": records,
            "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _worker(spec_path: Path) -> None:
    """The child of :func:`run_object`: one object's row, written to the spec's ``out``."""
    spec = json.loads(spec_path.read_text())
    start_warp(spec["kernel_cache"])
    row = object_row(Path(spec["path"]), spec["grasps"], spec["protocol"], spec["flip"], spec["device"],
                     spec["nworld"], Path(spec["cache"]))
    tmp = Path(spec["out"] + ".tmp")
    tmp.write_text(json.dumps(row))
    tmp.replace(spec["out"])


def run_object(path: Path, grasps: int, protocol: str, flip: bool, args, device: str, nworld: int) -> dict:
    """One object's row, made in a fresh child process (``-X faulthandler``), up to ``1 + args.retries`` tries: a
    crash of native code (CoACD has segfaulted) loses that try only, and bounds each object's memory. A row
    whose every try crashed is ``{"crashed": [...]}``; the failed tries of a row that succeeded are in its
    ``crashed``."""
    work = args.out.parent / (args.out.name + ".work")
    work.mkdir(parents=True, exist_ok=True)
    stem = f"{protocol}-{path.stem}"[:120]
    spec = {"path": str(path), "grasps": grasps, "protocol": protocol, "flip": flip, "device": device,
            "nworld": nworld, "cache": str(args.cache_dir), "out": str(work / f"{stem}.row.json"),
            "kernel_cache": None if args.kernel_cache is None else str(args.kernel_cache)}
    spec_path = work / f"{stem}.spec.json"
    spec_path.write_text(json.dumps(spec))
    crashed: list[str] = []
    for _ in range(1 + args.retries):
        Path(spec["out"]).unlink(missing_ok=True)
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        rc = subprocess.run([sys.executable, "-X", "faulthandler", "-m", "studies.warp_agreement", "--worker",
                             str(spec_path)], cwd=ROOT, check=False).returncode
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu_s = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
        if rc == 0 and Path(spec["out"]).exists():
            row = json.loads(Path(spec["out"]).read_text())
            row.update({"process_cpu_s": cpu_s, "crashed": crashed})
            return row
        why = f"killed by {signal.Signals(-rc).name}" if rc < 0 else f"exit status {rc}"
        crashed.append(f"{why} after {cpu_s:.0f} CPU s")
        print(protocol, path.name[:40], "CRASHED:", crashed[-1], flush=True)
    return {"crashed": crashed}


def pooled(objects: dict) -> dict:
    """The agreement pooled over the objects' grasps (confusion counts summed, not a mean of per-object kappas);
    the flips over the objects rolled out twice; CPU seconds summed."""
    ok = {k: o for k, o in objects.items() if "records" in o}
    if not ok:
        return {"objects": 0, "crashed_objects": sorted(objects)}
    cpu = _cat([o["records"]["cpu"] for o in ok.values()])
    warp = _cat([o["records"]["warp"] for o in ok.values()])
    out = agreement(cpu, warp, None)
    flips = [o for o in ok.values() if o["records"]["warp2"] is not None]
    if flips:
        w1 = _cat([_take(o["records"]["warp"], range(len(o["records"]["warp2"]["code"]))) for o in flips])
        out.update({k: v for k, v in agreement(w1, w1, _cat([o["records"]["warp2"] for o in flips])).items()
                    if k.startswith("flip")})
    warp_s, cpu_s = sum(o["warp_cpu_s"] for o in ok.values()), sum(o["cpu_cpu_s"] for o in ok.values())
    out.update({"objects": len(ok), "crashed_objects": sorted(k for k in objects if k not in ok),
                "objects_with_a_crashed_try": sorted(k for k, o in ok.items() if o.get("crashed")),
                "warp_cpu_s": warp_s, "cpu_cpu_s": cpu_s, "warp_rollouts_per_cpu_s": out["n"] / max(warp_s, 1e-9),
                "cpu_rollouts_per_cpu_s": out["n"] / max(cpu_s, 1e-9)})
    return out


def agreement_runs(files: list[tuple[Path, int]], protocol: str, args, device: str, nworld: int, entry: dict,
                   save) -> dict:
    """Both backends on every file's grasps, one child process per file (:func:`run_object`), a second warp run on
    the first ``args.flip_objects`` files; ``entry`` holds the rows done before (``--resume``: those are kept,
    crashed ones tried again); ``save()`` is called after each object."""
    objects = entry.setdefault("objects", {})
    for j, (path, grasps) in enumerate(files):
        if "records" in objects.get(path.name, {}):
            continue
        row = run_object(path, grasps, protocol, j < args.flip_objects, args, device, nworld)
        objects[path.name] = row
        if "records" in row:
            print(protocol, path.name[:40], json.dumps({k: v for k, v in row.items()
                                                        if not isinstance(v, (list, dict))}), flush=True)
        entry["pooled"] = pooled(objects)
        save()
    entry["pooled"] = pooled(objects)
    return entry


def calibration_files(args) -> list[tuple[Path, int]]:
    """The ACRONYM files and grasp counts ``args`` select: the first ``args.objects`` calibration files, then
    ``args.learn_objects`` evenly spaced learning-set files, after ``args.skip``, at most ``args.limit``."""
    calibration = sorted(args.calibration.glob("*.h5"))
    if args.objects > 0 and not calibration:
        raise SystemExit(f"--calibration {args.calibration}: no ACRONYM files (*.h5) there")
    files = [(f, args.grasps) for f in calibration[: args.objects]]
    if args.learn_objects > 0:
        learn = sorted(args.learn.glob("*.h5"))
        if not learn:
            raise SystemExit(f"--learn {args.learn}: no ACRONYM files (*.h5) there")
        files += [(learn[i], args.learn_grasps) for i in subset(len(learn), args.learn_objects)]
    return files[args.skip:][: args.limit if args.limit > 0 else None]


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_device_arguments(ap)
    ap.add_argument("--objects", type=int, default=5, help="calibration ACRONYM files (sorted) used for the agreement")
    ap.add_argument("--grasps", type=int, default=100, help="evenly spaced grasps per calibration file")
    ap.add_argument("--learn", type=Path, default=LEARN, help="folder of the learning set's ACRONYM files")
    ap.add_argument("--learn-objects", type=int, default=0, help="learning-set files, evenly spaced (0: none)")
    ap.add_argument("--learn-grasps", type=int, default=50, help="evenly spaced grasps per learning-set file")
    ap.add_argument("--skip", type=int, default=0, help="leave out the first SKIP files (calibration, then learn)")
    ap.add_argument("--limit", type=int, default=0, help="at most LIMIT files after --skip (0: all)")
    ap.add_argument("--flip-objects", type=int, default=2, help="files rolled out twice on warp (the flip rate)")
    ap.add_argument("--protocols", default=",".join(WARP_PROTOCOLS))
    ap.add_argument("--agreement-worlds", type=int, default=None, help="nworld of the agreement runs (default: "
                    "1024 on a GPU, 256 on the CPU device)")
    add_cache_arguments(ap)
    ap.add_argument("--out", type=Path, default=RESULTS, help="the JSON written")
    ap.add_argument("--resume", action="store_true", help="keep the objects --out already holds (crashed ones are "
                    "tried again) and add the rest")
    ap.add_argument("--retries", type=int, default=1, help="fresh tries of an object whose child process crashed")
    ap.add_argument("--worker", type=Path, default=None, help=argparse.SUPPRESS)  # run_object's child
    return ap


def main() -> None:
    args = _parser().parse_args()
    if args.worker is not None:
        _worker(args.worker)
        return
    wp = start_warp(args.kernel_cache)
    device = pick_device(wp, args.device)
    agree_worlds = args.agreement_worlds or (1024 if wp.get_device(device).is_cuda else 256)
    files = calibration_files(args)
    out: dict = json.loads(args.out.read_text()) if args.resume and args.out.exists() else {"protocols": {}}
    out.update({"device": device, "device_name": str(wp.get_device(device).name), "platform": platform.platform(),
                "warp": wp.config.version, "agreement_worlds": agree_worlds, "flip_objects": args.flip_objects})
    out["files"] = list(dict.fromkeys(out.get("files", []) + [f.name for f, _ in files]))
    # a file done before keeps the grasp count its rows were made with (its row's ``n``)
    out["grasps_per_file"] = {**{f.name: g for f, g in files}, **out.get("grasps_per_file", {})}
    args.out.parent.mkdir(parents=True, exist_ok=True)

    def save() -> None:
        out["maxrss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        out["children_maxrss_mb"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        tmp = args.out.with_name(args.out.name + ".tmp")
        tmp.write_text(json.dumps(out, indent=1, sort_keys=True))
        tmp.replace(args.out)

    for protocol in args.protocols.split(","):
        agreement_runs(files, protocol, args, device, agree_worlds, out["protocols"].setdefault(protocol, {}), save)
        save()
    print(args.out)


if __name__ == "__main__":
    main()
