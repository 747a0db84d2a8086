"""The warp backend (MuJoCo Warp, :mod:`graspgen.sim.warp_backend`) against the CPU backend (issue 25).

On the device it finds (the first CUDA GPU, else Warp's CPU device; ``--device`` picks one), for each protocol
(``acronym``, ``graspgen``):

* **agreement**: the calibration grasps (ACRONYM files under ``--calibration``, ``--grasps`` evenly spaced grasps of
  each of the first ``--objects`` files, Panda) rolled out by both backends; per protocol the success-label
  agreement and Cohen's kappa (warp vs CPU), the outcome-code agreement, the firm-label agreement, and the flip rate
  of the success label between two warp runs of the same grasps (MJWarp's contact order is not fixed across runs);
* **speed**: rollouts per second of one batch of ``nworld`` grasps against ``nworld`` (``--batches``; default 256 to
  8,192 on a GPU, 4 / 16 / 64 on the CPU device), the calibration grasps of the first object tiled to fill the
  batch; beside it the CPU backend's rollouts per second on one core (process time) on the same grasps. CPU seconds
  and wall seconds are both reported (Warp's CPU device runs a launch on one thread);
* **steps per rollout** (mean, both backends) and **memory per world** (bytes of the MJWarp ``Data`` arrays / nworld);
* **where the time goes** per batch: the placements and the end-of-closing records run on the CPU (the CPU
  backend's own code, one ``mj_forward`` per grasp each), the rest is stepping and the batched rules;
* **compile**: wall seconds of the first batch (kernel compilation, cold or warm as the cache is; ``--kernel-cache
  DIR`` points Warp at a folder, an empty one measures a cold compile) and of the second (warm).

Run: ``python -m bench.bench_warp [--device cuda:0] [--objects 5] [--grasps 100] [--batches 256,...]``; writes
``--out`` (JSON; default ``bench/results_warp.json``). Needs the warp extra (``pip install -e '.[warp]'``).
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


def kappa(a: np.ndarray, b: np.ndarray) -> float:
    """Cohen's kappa of two binary label vectors (NaN when chance agreement is 1)."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    po = float(np.mean(a == b))
    pe = float(np.mean(a) * np.mean(b) + np.mean(~a) * np.mean(~b))
    return (po - pe) / (1.0 - pe) if pe < 1.0 else math.nan


def subset(n: int, limit: int) -> np.ndarray:
    return np.unique(np.round(np.linspace(0, n - 1, min(n, limit))).astype(int))


def cpu_seconds() -> float:
    return time.process_time()


def worlds(path: Path, grasps: int, protocol: str, cache: Path):
    """The evaluation world of ``grasps`` evenly spaced grasps of an ACRONYM file under ``protocol``."""
    loaded = read_grasp_file(path, EvaluateParams(coacd=CHEAP_COACD), mesh_root=path.parent)
    params = dataclasses.replace(loaded.params, lift=loaded.params.lift.with_protocol(protocol))
    idx = subset(len(loaded.T_tcp), grasps)
    return evaluation_world(loaded.mesh_path, loaded.scale, loaded.T_tcp[idx], None, "panda", params,
                            protocol=protocol, cache_dir=cache)


def run_cpu(ew) -> tuple[list, float]:
    sim = ew.simulator()
    t = cpu_seconds()
    results = [sim.rollout(T, float(w), ew.target_body) for T, w in zip(ew.T_world, ew.width)]
    return results, cpu_seconds() - t


def run_warp(ew, params: WarpParams, T=None) -> tuple[list, dict]:
    t0, c0 = time.perf_counter(), cpu_seconds()
    sim = ew.warp_simulator(params)
    t1, c1 = time.perf_counter(), cpu_seconds()
    results = sim.rollouts(ew.T_world if T is None else T, ew.target_body)
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


def agreement(cpu: list, warp1: list, warp2: list) -> dict:
    c = np.array([r.code for r in cpu])
    w1, w2 = np.array([r.code for r in warp1]), np.array([r.code for r in warp2])
    f = np.array([r.firm for r in cpu])
    f1 = np.array([r.firm for r in warp1])
    return {
        "n": int(len(c)), "cpu_success": int(np.sum(c == 5)), "warp_success": int(np.sum(w1 == 5)),
        "success_agreement": float(np.mean((c == 5) == (w1 == 5))), "success_kappa": kappa(c == 5, w1 == 5),
        "outcome_agreement": float(np.mean(c == w1)), "firm_agreement": float(np.mean(f == f1)),
        "firm_kappa": kappa(f, f1), "flip_rate_success": float(np.mean((w1 == 5) != (w2 == 5))),
        "flip_rate_outcome": float(np.mean(w1 != w2)),
        "cpu_outcomes": np.bincount(c, minlength=6).tolist(), "warp_outcomes": np.bincount(w1, minlength=6).tolist(),
        "steps_per_rollout_cpu": float(np.mean([r.steps for r in cpu])),
        "steps_per_rollout_warp": float(np.mean([r.steps for r in warp1])),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default=None, help="Warp device (default: cuda:0 if present, else cpu)")
    add_calibration_option(ap, "acronym_more")
    ap.add_argument("--objects", type=int, default=5, help="ACRONYM files (sorted) used for the agreement")
    ap.add_argument("--grasps", type=int, default=100, help="evenly spaced grasps per file")
    ap.add_argument("--protocols", default=",".join(WARP_PROTOCOLS))
    ap.add_argument("--batches", default=None, help="comma-separated nworld values for the speed sweep")
    ap.add_argument("--agreement-worlds", type=int, default=None, help="nworld of the agreement runs")
    ap.add_argument("--kernel-cache", type=Path, default=None, help="Warp kernel cache folder (empty: cold)")
    ap.add_argument("--cache-dir", type=Path, default=ROOT / ".cache", help="CoACD cache (as run.cache_dir)")
    ap.add_argument("--skip-agreement", action="store_true")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()

    wp, _ = import_warp()
    if args.kernel_cache is not None:
        wp.config.kernel_cache_dir = str(args.kernel_cache)
    wp.init()
    device = args.device or ("cuda:0" if wp.get_cuda_device_count() > 0 else "cpu")
    gpu = device.startswith("cuda")
    batches = [int(b) for b in (args.batches or ("256,512,1024,2048,4096,8192" if gpu else "4,16,64")).split(",")]
    agree_worlds = args.agreement_worlds or (1024 if gpu else 16)
    files = sorted(args.calibration.glob("*.h5"))[: args.objects]
    out: dict = {"device": device, "device_name": str(wp.get_device(device).name), "platform": platform.platform(),
                 "files": [f.name for f in files], "grasps_per_file": args.grasps, "batches": batches,
                 "agreement_worlds": agree_worlds, "protocols": {}}
    for protocol in args.protocols.split(","):
        entry: dict = {"objects": {}}
        cpu_all, w1_all, w2_all = [], [], []
        first_call = None
        if not args.skip_agreement:
            for path in files:
                ew = worlds(path, args.grasps, protocol, args.cache_dir)
                cpu, cpu_s = run_cpu(ew)
                w1, t1 = run_warp(ew, WarpParams(device=device, nworld=agree_worlds))
                w2, t2 = run_warp(ew, WarpParams(device=device, nworld=agree_worlds))
                first_call = first_call or {"first_batch_wall_s": t1["init_s"] + t1["rollout_wall_s"],
                                            "second_run_wall_s": t2["init_s"] + t2["rollout_wall_s"]}
                cpu_all += cpu
                w1_all += w1
                w2_all += w2
                entry["objects"][path.name] = {**agreement(cpu, w1, w2), "cpu_rollouts_per_s": len(cpu) / cpu_s,
                                               "warp_rollouts_per_wall_s": len(cpu) / t2["rollout_wall_s"],
                                               "warp_rollouts_per_cpu_s": len(cpu) / t2["cpu_s"]}
                print(protocol, path.name[:30], json.dumps({k: v for k, v in entry["objects"][path.name].items()
                                                            if not isinstance(v, list)}), flush=True)
            entry["pooled"] = agreement(cpu_all, w1_all, w2_all)
            entry["compile"] = first_call
        # speed against batch size, on the first object's grasps tiled to fill each batch
        ew = worlds(files[0], args.grasps, protocol, args.cache_dir)
        cpu, cpu_s = run_cpu(ew)
        speed = {"cpu_backend_rollouts_per_core_s": len(cpu) / cpu_s, "per_batch": []}
        for nworld in batches:
            T = np.concatenate([ew.T_world] * math.ceil(nworld / len(ew.T_world)))[:nworld]
            res, t = run_warp(ew, WarpParams(device=device, nworld=nworld), T)
            row = {"nworld": nworld, "wall_s": t["rollout_wall_s"], "cpu_s": t["cpu_s"],
                   "rollouts_per_s": nworld / t["rollout_wall_s"],
                   "ratio_to_cpu_core": nworld / t["rollout_wall_s"] / speed["cpu_backend_rollouts_per_core_s"],
                   "rollouts_per_cpu_s": nworld / t["cpu_s"],  # the CPU device: per core (a shared machine's wall lies)
                   "ratio_to_cpu_core_by_cpu_s": nworld / t["cpu_s"] / speed["cpu_backend_rollouts_per_core_s"],
                   "steps_per_rollout": float(np.mean([r.steps for r in res])),
                   "reached_device": int(sum(r.decided_in != "placement" for r in res)),
                   **{f"{k}_wall": v for k, v in t["sim"].timings.items()}, "cuda_graph": t["sim"]._graph is not None,
                   "graph_error": t["sim"].graph_error,
                   "memory_per_world_bytes": data_bytes(t["sim"]._d) / nworld}
            speed["per_batch"].append(row)
            print(protocol, json.dumps(row), flush=True)
        entry["speed"] = speed
        out["protocols"][protocol] = entry
    out["maxrss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=1, sort_keys=True))
    print(args.out)


if __name__ == "__main__":
    main()
