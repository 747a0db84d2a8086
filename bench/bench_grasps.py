"""Throughput of antipodal grasp sampling and of the static collision pre-filter, on one core.

For each bundled object (mug, box) this measures, in one process:

* raw Embree rays/s: ``mesh.ray.intersects_first`` on as many rays as one sampler call casts (the floor of the
  sampler's own cost: it casts exactly one ray per contact pair);
* sampling alone: :func:`graspgen.geometry.antipodal.sample_antipodal` candidates/s (kept candidates after every filter,
  default approach filter ``hemisphere``, default ``num_depths`` = 3 grasp depths per orientation: each accepted
  ray gives up to 8 x 3 candidates, so candidates/s is ~3x that of one depth for the same rays) and its rays/s, as
  a ratio to the raw Embree rate;
* the pre-filter: :class:`graspgen.sim.prefilter.CollisionChecker` candidates/s (default params: up to 11 poses
  along a 0.05 m approach) and its cost per pose it actually checked (a candidate stops at its first colliding pose:
  the checker's ``return_steps`` gives that pose's index, so a candidate counts ``index + 1`` poses, a free one all
  11), against the floor: one ``mj_kinematics`` + ``mj_collision`` of the same model with the gripper in free
  space;
* sampling + pre-filter together: candidates/s through both.

The object is prepared like the objects stage does it (repair, units, CoACD parts from the ``.cache/coacd`` cache,
most probable stable pose; first run: ~15 s for the mug's CoACD) and placed on a ground plane for the pre-filter.
The bar (ARCHITECTURE.md, Performance bars): at least 5,000 antipodal candidates per second per core.

Usage: ``python -m bench.bench_grasps [--repeats N] [--out bench/results_grasps.json]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

# One core: no BLAS / OpenMP thread pools; pinned below where the OS allows it.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent

from graspgen.geometry.antipodal import AntipodalParams, sample_antipodal, uses_embree  # noqa: E402
from graspgen.geometry.stable_poses import StablePoseParams  # noqa: E402
from graspgen.grippers import DEFAULT_GRIPPER, load_gripper  # noqa: E402
from graspgen.sim.prefilter import CollisionChecker, PrefilterParams  # noqa: E402
from graspgen.workflows.prepare import prepare_object  # noqa: E402
from stages.objects import catalog  # noqa: E402

BAR_CANDIDATES_PER_S = 5000.0
OBJECTS = ("mug", "box")
SAMPLER = AntipodalParams(num_surface_points=500)
PREFILTER = PrefilterParams()


def _pin_one_core() -> str:
    try:
        cpu = min(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cpu})
        return f"pinned to cpu {cpu}"
    except (AttributeError, OSError):
        return "not pinned"


def _prepare(name: str):
    entry = catalog()[name]
    return prepare_object(ROOT / "assets" / "objects" / entry["file"], density=float(entry["density"]),
                          poses=StablePoseParams(settle_check=False, max_poses=1), rng=np.random.default_rng(0),
                          coacd_cache_dir=ROOT / ".cache" / "coacd")


def _world(name: str, parts) -> mujoco.MjSpec:
    """Ground plane + the object as a free body of convex mesh parts (the scene conventions of the pre-filter)."""
    spec = mujoco.MjSpec()
    ground = spec.worldbody.add_geom()
    ground.name = "ground"
    ground.type = mujoco.mjtGeom.mjGEOM_PLANE
    ground.size = [1.0, 1.0, 0.1]
    body = spec.worldbody.add_body()
    body.name = f"obj/0_{name}"
    body.add_freejoint()
    for k, (vertices, faces) in enumerate(parts):
        mesh = spec.add_mesh()
        mesh.name = f"{name}_part_{k}"
        mesh.uservert = np.asarray(vertices, dtype=float).ravel().tolist()
        mesh.userface = np.asarray(faces).ravel().tolist()
        geom = body.add_geom()
        geom.name = f"obj/0_{name}/part_{k}"
        geom.type = mujoco.mjtGeom.mjGEOM_MESH
        geom.meshname = mesh.name
    return spec


def _placed(spec: mujoco.MjSpec, name: str, pose: np.ndarray) -> mujoco.MjSpec:
    body = spec.body(f"obj/0_{name}")
    body.pos = list(pose[:3, 3])
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(pose[:3, :3]).reshape(-1))
    body.quat = list(quat)
    return spec


def _best(fn, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def bench_object(name: str, repeats: int) -> dict:
    gripper = load_gripper(DEFAULT_GRIPPER)
    t0 = time.perf_counter()
    obj = _prepare(name)
    prep_s = time.perf_counter() - t0
    mesh = trimesh.Trimesh(obj.vertices, obj.faces, process=False)
    pose = np.asarray(obj.stable_transforms[0])
    rays = SAMPLER.num_surface_points * SAMPLER.rays_per_point

    # Floor: raw Embree first-hit rays from just inside the surface, as many as one sampler call.
    rng = np.random.default_rng(1)
    points, face = trimesh.sample.sample_surface(mesh, rays, seed=1)
    dirs = -mesh.face_normals[face]
    origins = points + 1e-5 * dirs
    mesh.ray.intersects_first(origins, dirs)  # build the BVH outside the timing
    raw_s = _best(lambda: mesh.ray.intersects_first(origins, dirs), repeats)

    # Sampling alone (fresh seeds; warm-up call builds trimesh's caches).
    sample_antipodal(mesh, gripper, SAMPLER, rng, object_pose=pose)
    kept, sample_time, all_cands = 0, 0.0, []
    for seed in range(repeats):
        t0 = time.perf_counter()
        cands = sample_antipodal(mesh, gripper, SAMPLER, np.random.default_rng(100 + seed), object_pose=pose)
        sample_time += time.perf_counter() - t0
        kept += len(cands)
        all_cands.append(cands)
    rejected = all_cands[0].rejected.as_dict()

    # Pre-filter: built once (not timed in the rate), then every sampled candidate checked.
    t0 = time.perf_counter()
    checker = CollisionChecker(_placed(_world(name, obj.convex_parts), name, pose), gripper, PREFILTER)
    build_s = time.perf_counter() - t0
    check_time, codes = 0.0, []
    for cands in all_cands:
        t0 = time.perf_counter()
        codes.append(checker.check(cands.pose_world, cands.width, f"obj/0_{name}", return_steps=True))
        check_time += time.perf_counter() - t0
    first_hit = np.concatenate([s for _, s in codes])
    codes = np.concatenate([c for c, _ in codes])
    # Poses the checker actually placed and collided: up to the first colliding one, all of them for a free one.
    poses_checked = int(np.where(first_hit >= 0, first_hit + 1, PREFILTER.num_approach_samples).sum())

    # Floor of one checked pose: kinematics + collision of the same model, gripper far from everything.
    model, data = checker.model, checker.data
    far = np.eye(4)
    far[:3, 3] = (0.0, 0.0, 5.0)
    checker.check(far[None], [0.05], f"obj/0_{name}")
    n_floor = 20000

    def floor_loop() -> None:
        for _ in range(n_floor):
            mujoco.mj_kinematics(model, data)
            mujoco.mj_collision(model, data)

    floor_pose_s = _best(floor_loop, 3) / n_floor
    sample_rate = kept / sample_time
    return {
        "object": name,
        "faces": int(len(mesh.faces)),
        "convex_parts": len(obj.convex_parts),
        "embree": uses_embree(mesh),
        "prepare_s": round(prep_s, 2),
        "checker_build_s": round(build_s, 4),
        "rays_per_call": rays,
        "raw_embree_rays_per_s": rays / raw_s,
        "sampler_rays_per_s": rays * repeats / sample_time,
        "sampler_ray_ratio_to_raw": (rays * repeats / sample_time) / (rays / raw_s),
        "candidates": kept,
        "candidates_per_call": kept / repeats,
        "sample_candidates_per_s": sample_rate,
        "sample_ratio_to_bar": sample_rate / BAR_CANDIDATES_PER_S,
        "prefilter_candidates_per_s": len(codes) / check_time,
        "prefilter_poses_checked": poses_checked,
        "prefilter_poses_per_candidate": poses_checked / max(1, len(codes)),
        "prefilter_us_per_pose": 1e6 * check_time / poses_checked,
        "floor_us_per_pose": 1e6 * floor_pose_s,
        "combined_candidates_per_s": kept / (sample_time + check_time),
        "combined_ratio_to_bar": kept / (sample_time + check_time) / BAR_CANDIDATES_PER_S,
        "codes": {"free": int(np.sum(codes == -1)), "ground": int(np.sum(codes == 0)),
                  "target": int(np.sum(codes == 1)), "clutter": int(np.sum(codes == 2))},
        "sampler_rejects_first_call": rejected,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=10, help="sampler calls per object (default 10)")
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results_grasps.json")
    args = parser.parse_args(argv)
    pinned = _pin_one_core()
    rows = [bench_object(name, args.repeats) for name in OBJECTS]

    print(f"antipodal sampling + pre-filter, one core ({pinned}); sampler {SAMPLER.num_surface_points} points x "
          f"{SAMPLER.rays_per_point} rays x {SAMPLER.num_orientations} orientations x {SAMPLER.num_depths} depths, "
          f"approach {SAMPLER.approach}; "
          f"pre-filter {PREFILTER.num_approach_samples} poses over {PREFILTER.approach_distance} m")
    header = (f"{'object':<6} {'raw rays/s':>11} {'smp rays/s':>11} {'ratio':>6} {'cand/call':>9} "
              f"{'sample c/s':>11} {'x bar':>6} {'prefilt c/s':>11} {'us/pose':>8} {'floor us':>8} "
              f"{'both c/s':>10} {'x bar':>6} {'free %':>7}")
    print(header)
    print("-" * len(header))
    for r in rows:
        free = 100.0 * r["codes"]["free"] / max(1, r["candidates"])
        print(f"{r['object']:<6} {r['raw_embree_rays_per_s']:>11,.0f} {r['sampler_rays_per_s']:>11,.0f} "
              f"{r['sampler_ray_ratio_to_raw']:>6.2f} {r['candidates_per_call']:>9,.0f} "
              f"{r['sample_candidates_per_s']:>11,.0f} {r['sample_ratio_to_bar']:>6.1f} "
              f"{r['prefilter_candidates_per_s']:>11,.0f} {r['prefilter_us_per_pose']:>8.2f} "
              f"{r['floor_us_per_pose']:>8.2f} {r['combined_candidates_per_s']:>10,.0f} "
              f"{r['combined_ratio_to_bar']:>6.1f} {free:>6.1f}%")
    print(f"bar: {BAR_CANDIDATES_PER_S:,.0f} candidates/s (sampling). 'ratio' = sampler rays/s over raw Embree rays/s "
          "(same process); us/pose = pre-filter time over the poses it checked (a candidate stops at its first "
          "collision) vs floor = one mj_kinematics + mj_collision of the same model")
    result = {
        "benchmark": "grasps",
        "bar_candidates_per_s": BAR_CANDIDATES_PER_S,
        "cores": pinned,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "trimesh": trimesh.__version__,
        "mujoco": mujoco.__version__,
        "machine": platform.machine(),
        "sampler_params": {k: getattr(SAMPLER, k) for k in SAMPLER.__dataclass_fields__},
        "prefilter_params": {k: getattr(PREFILTER, k) for k in PREFILTER.__dataclass_fields__},
        "repeats": args.repeats,
        "rows": rows,
        "meets_bar": all(r["sample_candidates_per_s"] >= BAR_CANDIDATES_PER_S for r in rows),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")
    print(f"wrote {args.out}")
    return 0 if result["meets_bar"] else 1


if __name__ == "__main__":
    sys.exit(main())
