"""Throughput of the warp backend (MuJoCo Warp, :mod:`graspgen.sim.warp_backend`) beside the CPU backend.

On the device it finds (the first CUDA GPU, else Warp's CPU device; ``--device`` picks one), for each protocol
(``acronym``, ``graspdatagen``, ``table``; ``table`` on a support, the object settled on it in its most probable stable
pose, the jaws opened to the ray-cast width plus the margin, as ``gen evaluate --support`` does):

* **speed**: rollouts per second of one batch of ``nworld`` grasps against ``nworld`` (``--batches``; default 256 to
  8,192 on a GPU, 16 / 64 / 256 on the CPU device), the first calibration file's ``--speed-grasps`` grasps that
  reach the device (not decided at placement) tiled to fill the batch; beside it the CPU backend's rollouts per
  second on one core (process time) on the same grasps. CPU seconds and wall seconds are both reported (Warp's CPU
  device runs a launch on one thread);
* **steps per rollout** (both backends) and **memory per world** (bytes of the MJWarp ``Data`` arrays / nworld);
* **where the time goes** per batch: the placements and the end-of-closing records run on the CPU (the CPU
  backend's own code, one ``mj_forward`` per grasp each), the rest is stepping and the batched rules.

How far the two backends' labels agree is a study: ``studies/warp_agreement.py``.

Run: ``python -m bench.bench_warp [--device cuda:0] [--protocols acronym,graspdatagen,table] [--out $OUT/warp.json]``.
Needs the warp extra (``pip install -e '.[warp]'``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import resource
import time
from pathlib import Path

import numpy as np

from graspgen.sim.warp_backend import WARP_PROTOCOLS, WarpParams, import_warp
from graspgen.workflows.evaluate_settings import CHEAP_COACD, EvaluateParams
from graspgen.workflows.evaluation_world import evaluation_world
from graspgen.workflows.grasp_files import read_grasp_file

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results_warp.json"
LEARN = ROOT.parent / "shared" / "learn" / "acronym"
CALIBRATION_ENV = "GRASPGEN_CALIBRATION"
"""Environment variable naming the calibration folder (the one the studies read, ``studies/calibration.py``)."""
GPU_BATCHES = "256,512,1024,2048,4096,8192"
CPU_BATCHES = "16,64,256"


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


def calibration_default() -> Path:
    """Default of ``--calibration``: ``acronym_more/`` of ``$GRASPGEN_CALIBRATION``, else of ``../shared/calibration``
    beside the repository."""
    env = os.environ.get(CALIBRATION_ENV)
    return (Path(env) if env else ROOT.parent / "shared" / "calibration") / "acronym_more"


def add_device_arguments(ap: argparse.ArgumentParser, calibration_use: str = "") -> None:
    """``--device`` and ``--calibration``, the first options of every Warp measurement (this benchmark and
    ``studies/warp_agreement.py``); ``calibration_use`` ends the latter's help (what the command does with it)."""
    ap.add_argument("--device", default=None, help="Warp device (default: cuda:0 if present, else cpu)")
    default = calibration_default()
    ap.add_argument("--calibration", type=Path, default=default,
                    help=f"calibration folder (default: ${CALIBRATION_ENV}, else ../shared/calibration beside the "
                    f"repository, its acronym_more/; now {default}){calibration_use}")


def add_cache_arguments(ap: argparse.ArgumentParser) -> None:
    """``--kernel-cache`` (read by :func:`start_warp`) and ``--cache-dir`` (the CoACD cache :func:`worlds` uses)."""
    ap.add_argument("--kernel-cache", type=Path, default=None, help="Warp kernel cache folder (empty: cold)")
    ap.add_argument("--cache-dir", type=Path, default=ROOT / ".cache", help="CoACD cache (as run.cache_dir)")


def start_warp(kernel_cache: Path | str | None):
    """Warp imported and initialised, its kernels cached in ``kernel_cache`` when given (else Warp's own folder)."""
    wp, _ = import_warp()
    if kernel_cache is not None:
        wp.config.kernel_cache_dir = str(kernel_cache)
    wp.init()
    return wp


def pick_device(wp, device: str | None) -> str:
    """``device`` (``--device``), else the first CUDA GPU, else Warp's CPU device."""
    return device or ("cuda:0" if wp.get_cuda_device_count() > 0 else "cpu")


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_device_arguments(ap, "; its first ACRONYM file is tiled")
    ap.add_argument("--protocols", default=",".join(WARP_PROTOCOLS))
    ap.add_argument("--batches", default=None, help=f"nworld sweep (default {GPU_BATCHES} on a GPU, {CPU_BATCHES} "
                    "on the CPU device)")
    ap.add_argument("--speed-grasps", type=int, default=100, help="grasps of the first file tiled in the sweep")
    add_cache_arguments(ap)
    ap.add_argument("--out", type=Path, default=RESULTS, help="the JSON written (e.g. $OUT/bench_warp.json)")
    return ap


def main() -> None:
    args = _parser().parse_args()
    wp = start_warp(args.kernel_cache)
    device = pick_device(wp, args.device)
    gpu = wp.get_device(device).is_cuda
    batches = [int(b) for b in (args.batches or (GPU_BATCHES if gpu else CPU_BATCHES)).split(",")]
    first = sorted(args.calibration.glob("*.h5"))[:1]
    if not first:
        raise SystemExit(f"--calibration {args.calibration}: no ACRONYM files (*.h5) there")
    out: dict = {"device": device, "device_name": str(wp.get_device(device).name), "platform": platform.platform(),
                 "warp": wp.config.version, "batches": batches, "file": first[0].name, "protocols": {}}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    for protocol in args.protocols.split(","):
        out["protocols"][protocol] = {"speed": speed_runs(first[0], args.speed_grasps, protocol, args, device,
                                                          batches)}
        out["maxrss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        tmp = args.out.with_name(args.out.name + ".tmp")
        tmp.write_text(json.dumps(out, indent=1, sort_keys=True))
        tmp.replace(args.out)
    print(args.out)


if __name__ == "__main__":
    main()
