"""The warp backend (MuJoCo Warp, :mod:`graspgen.sim.warp_backend`) against the CPU backend (issue 25).

On the device it finds (the first CUDA GPU, else Warp's CPU device; ``--device`` picks one), for each protocol
(``acronym``, ``graspgen``, ``table``; ``table`` on a support, the object settled on it in its most probable stable
pose, the jaws opened to the ray-cast width plus the margin, as ``gen evaluate --support`` does):

* **agreement**: the calibration grasps (ACRONYM files: the first ``--objects`` of ``--calibration``, default all
  five of ``../shared/calibration/acronym_more``, and the first ``--learn-objects`` of ``--learn``, default
  ``../shared/learn/acronym``; ``--grasps`` / ``--learn-grasps`` evenly spaced grasps of each, Panda) rolled out by
  both backends; per protocol the success-label agreement and Cohen's kappa (warp vs CPU), the outcome-code
  agreement, the firm-label agreement, the same over the grasps that reached the device (not decided at placement,
  which both backends decide with the same CPU code), and the flip rate of the success label between two warp runs
  of the same grasps (MJWarp's contact order is not fixed across runs) on the first ``--flip-objects`` objects;
* **speed**: rollouts per second of one batch of ``nworld`` grasps against ``nworld`` (``--batches``; default 256 to
  8,192 on a GPU, 16 / 64 / 256 on the CPU device), the first object's ``--speed-grasps`` calibration grasps that
  reach the device (not decided at placement) tiled to fill the batch; beside it the CPU backend's rollouts per
  second on one core (process time) on the same grasps. CPU seconds and wall seconds are both reported (Warp's CPU
  device runs a launch on one thread);
* **steps per rollout** (mean, both backends) and **memory per world** (bytes of the MJWarp ``Data`` arrays / nworld);
* **where the time goes** per batch: the placements and the end-of-closing records run on the CPU (the CPU
  backend's own code, one ``mj_forward`` per grasp each), the rest is stepping and the batched rules;
* **compile**: wall seconds of the first warp run (kernel compilation, cold or warm as the cache is;
  ``--kernel-cache DIR`` points Warp at a folder, an empty one measures a cold compile) and of the second (warm).

Run: ``python -m bench.bench_warp [--device cuda:0] [--protocols acronym,graspgen,table] [--out $OUT/warp.json]``;
the JSON is rewritten after each protocol (a run cut short keeps what it finished). Needs the warp extra
(``pip install -e '.[warp]'``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import platform
import resource
import time
from pathlib import Path

import numpy as np

from graspgen.sim.warp_backend import WARP_PROTOCOLS, WarpParams, import_warp
from graspgen.workflows.evaluate_settings import CHEAP_COACD, EvaluateParams
from graspgen.workflows.evaluation_world import evaluation_world
from graspgen.workflows.grasp_files import read_grasp_file
from studies.calibration import add_calibration_option

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results_warp.json"
LEARN = ROOT.parent / "shared" / "learn" / "acronym"
GPU_BATCHES = "256,512,1024,2048,4096,8192"
CPU_BATCHES = "16,64,256"


def kappa(a: np.ndarray, b: np.ndarray) -> float:
    """Cohen's kappa of two binary label vectors (NaN when chance agreement is 1)."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    if len(a) == 0:
        return math.nan
    po = float(np.mean(a == b))
    pe = float(np.mean(a) * np.mean(b) + np.mean(~a) * np.mean(~b))
    return (po - pe) / (1.0 - pe) if pe < 1.0 else math.nan


def subset(n: int, limit: int) -> np.ndarray:
    return np.unique(np.round(np.linspace(0, n - 1, min(n, limit))).astype(int))


def cpu_seconds() -> float:
    return time.process_time()


def worlds(path: Path, grasps: int, protocol: str, cache: Path):
    """The evaluation world of ``grasps`` evenly spaced grasps of an ACRONYM file under ``protocol`` (``table``: on
    the default support, widths by ray casting)."""
    loaded = read_grasp_file(path, EvaluateParams(coacd=CHEAP_COACD), mesh_root=path.parent)
    params = dataclasses.replace(loaded.params, lift=loaded.params.lift.with_protocol(protocol))
    idx = subset(len(loaded.T_tcp), grasps)
    widths = None if protocol == "table" else loaded.widths[idx] if loaded.widths is not None else None
    return evaluation_world(loaded.mesh_path, loaded.scale, loaded.T_tcp[idx], widths, "panda", params,
                            free_space=protocol != "table", protocol=protocol, cache_dir=cache)


def run_cpu(ew) -> tuple[list, float]:
    sim = ew.simulator()
    t = cpu_seconds()
    results = [sim.rollout(T, float(w), ew.target_body) for T, w in zip(ew.T_world, ew.width)]
    return results, cpu_seconds() - t


def run_warp(ew, params: WarpParams, T=None, widths=None) -> tuple[list, dict]:
    t0, c0 = time.perf_counter(), cpu_seconds()
    sim = ew.warp_simulator(params)
    t1, c1 = time.perf_counter(), cpu_seconds()
    results = sim.rollouts(ew.T_world if T is None else T, ew.target_body, ew.width if widths is None else widths)
    t2, c2 = time.perf_counter(), cpu_seconds()
    return results, {"init_s": t1 - t0, "init_cpu_s": c1 - c0, "rollout_wall_s": t2 - t1, "cpu_s": c2 - c1,
                     "sim": sim}


def data_bytes(obj, seen=None) -> int:
    """Bytes of every Warp array reachable from an MJWarp ``Data`` (its nested dataclasses included)."""
    wp, _ = import_warp()
    seen = set() if seen is None else seen
    if id(obj) in seen:
        return 0
    seen.add(id(obj))
    if isinstance(obj, wp.array):
        return int(obj.capacity)
    if dataclasses.is_dataclass(obj):
        return sum(data_bytes(getattr(obj, f.name), seen) for f in dataclasses.fields(obj))
    return 0


def _labels(cpu: list, warp: list) -> dict:
    c, w = np.array([r.code for r in cpu], dtype=int), np.array([r.code for r in warp], dtype=int)
    f, fw = np.array([r.firm for r in cpu], bool), np.array([r.firm for r in warp], bool)
    n = len(c)
    return {"n": n, "cpu_success": int(np.sum(c == 5)), "warp_success": int(np.sum(w == 5)),
            "success_agreement": float(np.mean((c == 5) == (w == 5))) if n else math.nan,
            "success_kappa": kappa(c == 5, w == 5), "outcome_agreement": float(np.mean(c == w)) if n else math.nan,
            "firm_agreement": float(np.mean(f == fw)) if n else math.nan, "firm_kappa": kappa(f, fw),
            "cpu_outcomes": np.bincount(c, minlength=6).tolist(), "warp_outcomes": np.bincount(w, minlength=6).tolist()}


def agreement(cpu: list, warp1: list, warp2: list | None) -> dict:
    """Warp against CPU over all grasps and over those that reached the device; flips between two warp runs."""
    out = _labels(cpu, warp1)
    reached = [i for i, r in enumerate(cpu) if r.decided_in != "placement"]
    out["reached_device"] = {k: v for k, v in _labels([cpu[i] for i in reached], [warp1[i] for i in reached]).items()
                             if not isinstance(v, list)}
    out["steps_per_rollout_cpu"] = float(np.mean([r.steps for r in cpu])) if cpu else math.nan
    out["steps_per_rollout_warp"] = float(np.mean([r.steps for r in warp1])) if warp1 else math.nan
    if warp2 is not None:
        w1, w2 = np.array([r.code for r in warp1[:len(warp2)]]), np.array([r.code for r in warp2])
        out.update({"flip_n": int(len(w2)), "flip_rate_success": float(np.mean((w1 == 5) != (w2 == 5))),
                    "flip_rate_outcome": float(np.mean(w1 != w2)),
                    "flip_n_reached_device": int(sum(r.decided_in != "placement" for r in warp2))})
    return out


def agreement_runs(files: list[tuple[Path, int]], protocol: str, args, device: str, nworld: int) -> dict:
    """Both backends on every file's grasps; a second warp run on the first ``args.flip_objects`` files."""
    entry: dict = {"objects": {}}
    cpu_all, w1_all, w2_all, flip_cpu = [], [], [], []
    for j, (path, grasps) in enumerate(files):
        ew = worlds(path, grasps, protocol, args.cache_dir)
        cpu, cpu_s = run_cpu(ew)
        w1, t1 = run_warp(ew, WarpParams(device=device, nworld=nworld))
        w2 = None
        if j < args.flip_objects:
            w2, t2 = run_warp(ew, WarpParams(device=device, nworld=nworld))
            w2_all += w2
            flip_cpu += w1
        entry.setdefault("compile", {"first_run_wall_s": t1["init_s"] + t1["rollout_wall_s"],
                                     "first_run_cpu_s": t1["init_cpu_s"] + t1["cpu_s"]})
        cpu_all += cpu
        w1_all += w1
        row = {**agreement(cpu, w1, w2), "cpu_rollouts_per_cpu_s": len(cpu) / max(cpu_s, 1e-9),
               "warp_rollouts_per_wall_s": len(cpu) / t1["rollout_wall_s"],
               "warp_rollouts_per_cpu_s": len(cpu) / max(t1["cpu_s"], 1e-9), "warp_cpu_s": t1["cpu_s"],
               "cpu_cpu_s": cpu_s}
        entry["objects"][path.name] = row
        print(protocol, path.name[:40], json.dumps({k: v for k, v in row.items() if not isinstance(v, (list, dict))}),
              flush=True)
    entry["pooled"] = agreement(cpu_all, w1_all, None)
    if w2_all:
        entry["pooled"].update({k: v for k, v in agreement(flip_cpu, flip_cpu, w2_all).items()
                                if k.startswith("flip")})
    entry["warp_cpu_s"] = sum(o["warp_cpu_s"] for o in entry["objects"].values())
    entry["cpu_cpu_s"] = sum(o["cpu_cpu_s"] for o in entry["objects"].values())
    return entry


def speed_runs(path: Path, grasps: int, protocol: str, args, device: str, batches: list[int]) -> dict:
    """One batch of each size, beside the CPU backend per core: the first object's grasps that reach the device
    (those the CPU backend does not decide at placement; a placement costs the same on both backends) tiled."""
    ew = worlds(path, grasps, protocol, args.cache_dir)
    cpu, _ = run_cpu(ew)
    keep = np.array([r.decided_in != "placement" for r in cpu])
    ew = dataclasses.replace(ew, T_world=ew.T_world[keep], width=ew.width[keep])
    cpu, cpu_s = run_cpu(ew)
    speed = {"grasps_tiled": int(keep.sum()), "of_grasps": int(len(keep)),
             "cpu_backend_rollouts_per_core_s": len(cpu) / cpu_s,
             "cpu_steps_per_rollout": float(np.mean([r.steps for r in cpu])), "per_batch": []}
    for nworld in batches:
        reps = math.ceil(nworld / len(ew.T_world))
        T = np.concatenate([ew.T_world] * reps)[:nworld]
        widths = np.concatenate([ew.width] * reps)[:nworld]
        res, t = run_warp(ew, WarpParams(device=device, nworld=nworld), T, widths)
        sim = t["sim"]
        row = {"nworld": nworld, "wall_s": t["rollout_wall_s"], "cpu_s": t["cpu_s"],
               "rollouts_per_s": nworld / t["rollout_wall_s"],
               "ratio_to_cpu_core": nworld / t["rollout_wall_s"] / speed["cpu_backend_rollouts_per_core_s"],
               "rollouts_per_cpu_s": nworld / t["cpu_s"],  # the CPU device: per core (a shared machine's wall lies)
               "ratio_to_cpu_core_by_cpu_s": nworld / t["cpu_s"] / speed["cpu_backend_rollouts_per_core_s"],
               "steps_per_rollout": float(np.mean([r.steps for r in res])),
               **{f"{k}_wall": v for k, v in sim.timings.items()}, "cuda_graph": sim._graph is not None,
               "graph_error": sim.graph_error, "memory_per_world_bytes": data_bytes(sim.device_data) / nworld}
        speed["per_batch"].append(row)
        print(protocol, json.dumps(row), flush=True)
    return speed


def _files(args) -> list[tuple[Path, int]]:
    calibration = sorted(args.calibration.glob("*.h5"))
    if args.objects > 0 and not calibration:
        raise SystemExit(f"--calibration {args.calibration}: no ACRONYM files (*.h5) there")
    files = [(f, args.grasps) for f in calibration[: args.objects]]
    if args.learn_objects > 0:
        learn = sorted(args.learn.glob("*.h5"))
        if not learn:
            raise SystemExit(f"--learn {args.learn}: no ACRONYM files (*.h5) there")
        files += [(learn[i], args.learn_grasps) for i in subset(len(learn), args.learn_objects)]
    return files


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default=None, help="Warp device (default: cuda:0 if present, else cpu)")
    add_calibration_option(ap, "acronym_more")
    ap.add_argument("--objects", type=int, default=5, help="calibration ACRONYM files (sorted) used for the agreement")
    ap.add_argument("--grasps", type=int, default=100, help="evenly spaced grasps per calibration file")
    ap.add_argument("--learn", type=Path, default=LEARN, help="folder of the learning set's ACRONYM files")
    ap.add_argument("--learn-objects", type=int, default=0, help="learning-set files, evenly spaced (0: none)")
    ap.add_argument("--learn-grasps", type=int, default=50, help="evenly spaced grasps per learning-set file")
    ap.add_argument("--flip-objects", type=int, default=2, help="files rolled out twice on warp (the flip rate)")
    ap.add_argument("--protocols", default=",".join(WARP_PROTOCOLS))
    ap.add_argument("--batches", default=None, help=f"nworld sweep (default {GPU_BATCHES} on a GPU, {CPU_BATCHES} "
                    "on the CPU device)")
    ap.add_argument("--agreement-worlds", type=int, default=None, help="nworld of the agreement runs (default: "
                    "1024 on a GPU, 256 on the CPU device)")
    ap.add_argument("--speed-grasps", type=int, default=100, help="grasps of the first file tiled in the sweep")
    ap.add_argument("--kernel-cache", type=Path, default=None, help="Warp kernel cache folder (empty: cold)")
    ap.add_argument("--cache-dir", type=Path, default=ROOT / ".cache", help="CoACD cache (as run.cache_dir)")
    ap.add_argument("--skip-agreement", action="store_true")
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--out", type=Path, default=RESULTS, help="the JSON written (e.g. $OUT/bench_warp.json)")
    return ap


def main() -> None:
    args = _parser().parse_args()
    wp, _ = import_warp()
    if args.kernel_cache is not None:
        wp.config.kernel_cache_dir = str(args.kernel_cache)
    wp.init()
    device = args.device or ("cuda:0" if wp.get_cuda_device_count() > 0 else "cpu")
    gpu = wp.get_device(device).is_cuda
    batches = [int(b) for b in (args.batches or (GPU_BATCHES if gpu else CPU_BATCHES)).split(",")]
    agree_worlds = args.agreement_worlds or (1024 if gpu else 256)
    files = _files(args)
    out: dict = {"device": device, "device_name": str(wp.get_device(device).name), "platform": platform.platform(),
                 "warp": wp.config.version, "files": [f.name for f, _ in files], "grasps_per_file":
                 {f.name: g for f, g in files}, "batches": batches, "agreement_worlds": agree_worlds,
                 "flip_objects": args.flip_objects, "protocols": {}}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    for protocol in args.protocols.split(","):
        entry: dict = {}
        if not args.skip_agreement:
            entry.update(agreement_runs(files, protocol, args, device, agree_worlds))
        if not args.skip_speed:
            entry["speed"] = speed_runs(files[0][0], args.speed_grasps, protocol, args, device, batches)
        out["protocols"][protocol] = entry
        out["maxrss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        args.out.write_text(json.dumps(out, indent=1, sort_keys=True))
    print(args.out)


if __name__ == "__main__":
    main()
