"""Epsilon throughput (ARCHITECTURE.md, Performance bars: >= 2,000 grasps per second per core) and the robustness
stage's cost per grasp.

Scene: the bundled box (50 x 70 x 120 mm, 0.27 kg) prepared with :func:`graspgen.workflows.prepare.prepare_object`, in
its most probable stable pose (flat on its 70 x 120 mm face) on the scenes stage's table
(:func:`graspgen.sim.scene_model.build_scene_spec`), with the Robotiq 2F-85 attached, compiled once into a
:class:`graspgen.sim.lift.LiftSimulator` (default :class:`graspgen.sim.protocols.LiftParams`), object friction 0.5.
Grasps: top-down, closing across the 70 mm extent (turned by N(0, 5 deg) about the vertical), offset uniformly by up to
45 mm along the 120 mm axis and N(0, 2 mm) across it, TCP 10-30 mm below the top.

1. **Epsilon**: the contact sets of those grasps, as the metrics stage sees them: each grasp's rollout contacts at the
   end of closing (1-4 per pad, object frame) when both jaws touched, and its ray-cast closing contacts (3 x 3 rays per
   pad). Timed: :func:`graspgen.quality.epsilon.grasp_epsilon` per contact set, one process (one core), the ``pad``
   model (default) and the ``points`` model; best of ``--rounds`` passes. The ratio is to the bar (2,000/s).
2. **Robustness**: for successful grasps, :func:`graspgen.workflows.robustness.grasp_robustness` with N = 20, 50, 100
   perturbed copies (default sigmas: 5 mm, 5 deg): N rollouts, the epsilon of each copy (ray casts for copies without
   two-jaw contacts). Reported: seconds per grasp, copies (rollouts) per second, the share of the time spent
   outside the rollouts (epsilon, ray casts, bookkeeping), and the copies' outcome histogram. The scene's compile
   (once per task) is reported apart.

Run: ``python -m bench.bench_metrics [--grasps N] [--rounds R] [--seed S]``; prints a table and writes
``bench/results_metrics.json``.
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

from graspgen.geometry.contacts import closing_contacts
from graspgen.grippers import DEFAULT_GRIPPER, load_gripper
from graspgen.io.objects import ObjectRecord
from graspgen.quality.contact_set import contact_set
from graspgen.quality.epsilon import EpsilonParams, grasp_epsilon
from graspgen.quality.perturbation import DRAWS_PER_COPY, RobustnessParams
from graspgen.sim.gripper_model import attach_gripper
from graspgen.sim.lift import LiftSimulator
from graspgen.sim.perturbed_copies import rollout_with_object_pose
from graspgen.sim.protocols import OUTCOME_NAMES, LiftParams
from graspgen.sim.scene_model import build_scene_spec, object_body_name, placed_object
from graspgen.sim.support import SupportParams
from graspgen.workflows.metrics import object_geometry
from graspgen.workflows.prepare import prepare_object
from graspgen.workflows.robustness import grasp_robustness
from stages.objects import ASSETS, catalog

RESULTS = Path(__file__).resolve().parent / "results_metrics.json"
FRICTION = 0.5
BAR = 2000.0  # epsilon evaluations per second per core (ARCHITECTURE.md, Performance bars)


def bundled_box() -> ObjectRecord:
    entry = catalog()["box"]
    prep = prepare_object(ASSETS / entry["file"], density=entry["density"], rng=np.random.default_rng(0))
    return ObjectRecord(
        name=prep.name, vertices=np.asarray(prep.vertices), faces=np.asarray(prep.faces),
        convex_parts=[(np.asarray(v), np.asarray(f)) for v, f in prep.convex_parts], mass=prep.mass.mass,
        center_of_mass=np.asarray(prep.mass.center_of_mass), inertia=np.asarray(prep.mass.inertia),
        stable_poses=np.asarray(prep.stable_transforms), stable_probabilities=np.asarray(prep.stable_probabilities),
        attrs={},
    )


def box_scene(record: ObjectRecord) -> tuple[LiftSimulator, str, np.ndarray, float]:
    """(simulator, target body, object pose (4, 4), compile seconds) of the box on the table with the 2F-85."""
    pose = np.asarray(record.stable_poses[0])
    t = time.perf_counter()
    spec = build_scene_spec([placed_object(record, pose, FRICTION, visual=False)], SupportParams())
    attach_gripper(spec, load_gripper(DEFAULT_GRIPPER))
    sim = LiftSimulator(spec.compile(), LiftParams())
    return sim, object_body_name(0, record.name), pose, time.perf_counter() - t


def sample_grasps(verts: np.ndarray, n: int, rng: np.random.Generator) -> list[tuple[np.ndarray, float]]:
    """Top-down grasps across the box's 70 mm extent (module docstring)."""
    lo, hi = verts.min(0), verts.max(0)
    centre, ext = (lo + hi) / 2, hi - lo
    short, long = (0, 1) if ext[0] < ext[1] else (1, 0)
    grasps = []
    for _ in range(n):
        yaw = rng.normal(0.0, math.radians(5.0))
        x = np.zeros(3)
        x[short], x[long] = math.cos(yaw), math.sin(yaw)
        T = np.eye(4)
        T[:3, 0], T[:3, 2] = x, (0.0, 0.0, -1.0)
        T[:3, 1] = np.cross(T[:3, 2], T[:3, 0])
        T[:3, 3] = centre
        T[long, 3] += rng.uniform(-0.045, 0.045)
        T[short, 3] += rng.normal(0.0, 0.002)
        T[2, 3] = hi[2] - rng.uniform(0.01, 0.03)
        grasps.append((T, float(np.ptp(verts @ x))))
    return grasps


def contact_sets(sim, body, pose, geometry, grasps) -> tuple[list, list, list]:
    """Rollout contact sets (object frame, two jaws), ray-cast contact sets, and the successful grasps."""
    rollout_sets, ray_sets, successes = [], [], []
    rel = np.stack([np.linalg.inv(pose) @ T for T, _ in grasps])
    rays = closing_contacts(geometry.mesh, rel, load_gripper(DEFAULT_GRIPPER))
    for (T, w), c in zip(grasps, rays):
        result, _, T_closed = rollout_with_object_pose(sim, T, w, body)
        if result.success:
            successes.append((T, w))
        if T_closed is not None:
            source, p, n, f = contact_set((result.contact_points, result.contact_normals, result.contact_fingers),
                                          T_closed, None)
            if source == "rollout":
                rollout_sets.append((p, n, f))
        if c.both_fingers:
            ray_sets.append((c.points, c.normals, c.finger))
    return rollout_sets, ray_sets, successes


def time_epsilon(sets, geometry, model: str, rounds: int, min_seconds: float = 1.0) -> dict:
    """Best-of-rounds epsilon evaluations per second over ``sets`` (each pass repeats them for >= min_seconds)."""
    ep = EpsilonParams(contact_model=model)
    kw = dict(friction=FRICTION, torque_scale=geometry.torque_scale, torsional_friction=ep.torsional_friction,
              num_cone_edges=ep.num_cone_edges, contact_model=model)
    com = geometry.center_of_mass
    eps = [grasp_epsilon(p, n, f, com, **kw) for p, n, f in sets]  # warm-up and the values
    rates = []
    for _ in range(rounds):
        done, t0 = 0, time.perf_counter()
        while True:
            for p, n, f in sets:
                grasp_epsilon(p, n, f, com, **kw)
            done += len(sets)
            elapsed = time.perf_counter() - t0
            if elapsed >= min_seconds:
                break
        rates.append(done / elapsed)
    contacts = np.array([len(f) for _, _, f in sets])
    return {"model": model, "sets": len(sets), "contacts_per_set": float(contacts.mean()),
            "in_closure": float(np.mean(np.array(eps) > 0)), "per_s": max(rates), "us_each": 1e6 / max(rates),
            "ratio_to_bar": max(rates) / BAR}


def time_robustness(sim, body, geometry, grasps, n_copies: int, seed: int) -> dict:
    """Seconds per grasp of grasp_robustness with ``n_copies`` copies, and the time inside the rollouts."""
    params = RobustnessParams(num_perturbations=n_copies)
    rng = np.random.default_rng(seed)
    gripper = load_gripper(DEFAULT_GRIPPER)
    inside = [0.0]
    rollout = sim.rollout

    def timed(*args, **kwargs):  # the share of the time that is physics (reset, steps, rules)
        t = time.perf_counter()
        try:
            return rollout(*args, **kwargs)
        finally:
            inside[0] += time.perf_counter() - t

    sim.rollout = timed
    outcomes: collections.Counter = collections.Counter()
    robust = []
    try:
        t0 = time.perf_counter()
        for T, w in grasps:
            draws = rng.standard_normal((n_copies, DRAWS_PER_COPY))
            r = grasp_robustness(sim, T, w, body, geometry, FRICTION, draws, params, EpsilonParams(), gripper)
            outcomes.update(OUTCOME_NAMES[c] for c in r.outcomes)
            robust.append(r.robustness)
        wall = time.perf_counter() - t0
    finally:
        del sim.rollout
    copies = n_copies * len(grasps)
    return {"n": n_copies, "grasps": len(grasps), "s_per_grasp": wall / len(grasps), "copies_per_s": copies / wall,
            "ms_per_copy": 1e3 * wall / copies, "outside_rollouts": 1.0 - inside[0] / wall,
            "mean_robustness": float(np.mean(robust)),
            "outcomes": {name: outcomes.get(name, 0) for name in OUTCOME_NAMES}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grasps", type=int, default=200, help="grasps sampled for the epsilon contact sets")
    parser.add_argument("--robust-grasps", type=int, default=10, help="successful grasps timed per N")
    parser.add_argument("--rounds", type=int, default=3, help="timed epsilon passes (the best counts)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    record = bundled_box()
    geometry = object_geometry(record)
    sim, body, pose, compile_s = box_scene(record)
    verts = record.vertices @ pose[:3, :3].T + pose[:3, 3]
    grasps = sample_grasps(verts, args.grasps, np.random.default_rng(args.seed))
    rollout_sets, ray_sets, successes = contact_sets(sim, body, pose, geometry, grasps)
    eps_rows = []
    for label, sets in (("rollout", rollout_sets), ("raycast", ray_sets)):
        for model in ("pad", "points"):
            row = time_epsilon(sets, geometry, model, args.rounds, min_seconds=1.0 if model == "pad" else 0.5)
            eps_rows.append({"contacts": label, **row})
    robust_rows = [time_robustness(sim, body, geometry, successes[: args.robust_grasps], n, args.seed)
                   for n in (20, 50, 100)]

    print(f"epsilon, one core (bar: {BAR:,.0f}/s)")
    header = (f"{'contacts':<8} {'model':<6} {'sets':>5} {'pts/set':>7} {'closure':>7} {'eps/s':>8} {'us':>7} "
              f"{'x bar':>6}")
    print(header)
    print("-" * len(header))
    for r in eps_rows:
        print(f"{r['contacts']:<8} {r['model']:<6} {r['sets']:>5} {r['contacts_per_set']:>7.1f} "
              f"{r['in_closure']:>7.2f} {r['per_s']:>8.0f} {r['us_each']:>7.0f} {r['ratio_to_bar']:>6.2f}")
    print(f"\nrobustness per successful grasp, one core (scene compile once per task: {1e3 * compile_s:.1f} ms)")
    header = (f"{'N':>4} {'grasps':>6} {'s/grasp':>8} {'copies/s':>8} {'ms/copy':>8} {'non-sim':>7} {'mean rob':>8}"
              "  copy outcomes 0/1/2/3/4/5")
    print(header)
    print("-" * len(header))
    for r in robust_rows:
        hist = "/".join(str(v) for v in r["outcomes"].values())
        print(f"{r['n']:>4} {r['grasps']:>6} {r['s_per_grasp']:>8.3f} {r['copies_per_s']:>8.1f} "
              f"{r['ms_per_copy']:>8.2f} {r['outside_rollouts']:>7.1%} {r['mean_robustness']:>8.2f}  {hist}")
    out = {
        "bench": "metrics",
        "object": "box",
        "object_friction": FRICTION,
        "gripper": DEFAULT_GRIPPER,
        "epsilon_params": EpsilonParams().__dict__,
        "robustness_params": {k: v for k, v in RobustnessParams().__dict__.items() if k != "num_perturbations"},
        "scene_compile_ms": 1e3 * compile_s,
        "bar_epsilon_per_s": BAR,
        "mujoco": mujoco.__version__,
        "python": sys.version.split()[0],
        "machine": platform.machine(),
        "cpu_count": os.cpu_count(),
        "epsilon": eps_rows,
        "robustness": robust_rows,
    }
    args.out.write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
