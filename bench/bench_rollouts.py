"""Grasp-and-lift rollout throughput (ARCHITECTURE.md, Performance bars: >= 20 rollouts/s per core, report the ratio to
the floor).

For each bundled object (box, can): prepare it with :func:`graspgen.workflows.prepare.prepare_object`, rest it in its
most probable stable pose on a table (``support/table``), settle it, attach the default gripper (Robotiq 2F-85), and
roll out random top-down grasps across it with :class:`graspgen.sim.lift.LiftSimulator` (default :class:`LiftParams`,
once without and once with the shake). Reported per object:

* rollouts/s in one process on one core (MuJoCo is single-threaded), and ms per rollout: plain passes (nothing
  instrumented), the best of ``--rounds`` (the machine is shared; the minimum is the least disturbed);
* simulated steps per rollout (mean) and the outcome histogram;
* the floor and the ratio to it, both from one instrumented pass: the same rollouts with ``mujoco.mj_step`` wrapped
  in a timer (:class:`_StepTimer`), the pass timed as a whole (its wall) and the time inside ``mj_step`` summed (its
  floor: what the rollouts would cost if everything but the physics steps were free -- reset, placement, rule
  checks, mocap updates, result extraction); ratio = that wall / that floor. The floor is part of the same pass's
  wall, so the ratio is never below 1 (two separate passes, one for each, could give less on a noisy machine). Of
  the ``--rounds`` instrumented passes the one with the smallest wall is reported. Its wall includes the timer's
  own cost (two clock reads and a Python call per ``mj_step`` call, ``timer_calls_per_rollout`` of them; about
  ``timer_overhead_us_per_call``, measured on a no-op), so the ratio errs high by about that much, never low.
  Plain and instrumented passes alternate and must give bit-identical results (checked).

Convex parts: the box and the can meshes are both convex to 1e-6 of their hull volume, so ``prepare_object``
returns each one's hull as the single collision part (CoACD is not run; its cheap settings are passed anyway).

Poses: the most probable stable pose of each (the box flat on its 70 x 120 mm face, the can lying on its side).
Grasps (top-down, TCP z = world -z): closing axis across the object's narrower horizontal extent (the box's 70 mm
side, the can's 66 mm diameter) turned by N(0, 10 deg) about z; TCP offset uniformly along the object's long axis
over 1.2x its length (some grasps miss the end), N(0, 3 mm) along the closing axis; TCP depth below the object's
top uniform in [0, 45] mm (the deepest put the fingertips into the table); width = the object's extent along the
closing axis (clipped to the 2F-85's 85 mm). Object friction 0.5. A realistic mix of outcomes: table collisions,
misses past the object's ends, and can grasps above its equator that squeeze it out downwards (slips).

Run: ``python -m bench.bench_rollouts [--rollouts N] [--rounds R] [--seed S] [--gripper G]``; prints a table and writes
``bench/results_rollouts.json``.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import math
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np

from graspgen.geometry.convex import CoacdParams
from graspgen.grippers import DEFAULT_GRIPPER, load_gripper
from graspgen.sim.gripper_model import attach_gripper
from graspgen.sim.gripper_state import set_gripper_pose
from graspgen.sim.lift import LiftSimulator
from graspgen.sim.physics import physics_options
from graspgen.sim.protocols import OUTCOME_NAMES, LiftParams
from graspgen.workflows.prepare import PreparedObject, prepare_object

ROOT = Path(__file__).resolve().parents[1]
OBJECTS = ROOT / "assets" / "objects"
RESULTS = Path(__file__).resolve().parent / "results_rollouts.json"
TABLE_TOP = 0.0  # m
FRICTION = 0.5  # object sliding friction
CHEAP_COACD = CoacdParams(threshold=0.1, max_convex_hull=8, mcts_iterations=30, resolution=1000,
                          preprocess_resolution=30)


def load_object(name: str) -> PreparedObject:
    catalog = {c["name"]: c for c in json.loads((OBJECTS / "catalog.json").read_text())}
    cache = Path(tempfile.gettempdir()) / "graspgen-bench-coacd"
    return prepare_object(OBJECTS / catalog[name]["file"], density=catalog[name]["density"], coacd=CHEAP_COACD,
                          rng=np.random.default_rng(0), coacd_cache_dir=cache)


def build_scene(obj: PreparedObject, gripper: str = DEFAULT_GRIPPER) -> tuple[mujoco.MjModel, np.ndarray,
                                                                                np.ndarray]:
    """Table + the object in its most probable stable pose + ``gripper``. Returns (model, settled qpos, world
    vertices (n, 3) of the settled object)."""
    spec = mujoco.MjSpec()
    physics_options(spec)
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    world = spec.worldbody
    world.add_geom(name="ground", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1], pos=[0, 0, TABLE_TOP - 0.75])
    world.add_geom(name="support/table", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.4, 0.4, 0.02],
                   pos=[0, 0, TABLE_TOP - 0.02])
    T = np.array(obj.stable_transforms[0])
    T[2, 3] += TABLE_TOP
    body = world.add_body(name=f"obj/0_{obj.name}", pos=T[:3, 3])
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(T[:3, :3]).reshape(-1))
    body.quat = quat
    body.add_freejoint(name=f"obj/0_{obj.name}/free")
    body.explicitinertial = True
    body.mass = obj.mass.mass
    body.ipos = obj.mass.center_of_mass
    inertia = obj.mass.inertia
    body.fullinertia = [inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2]]
    for i, (vertices, faces) in enumerate(obj.convex_parts):
        spec.add_mesh(name=f"{obj.name}_part_{i}", uservert=np.asarray(vertices).ravel().tolist(),
                      userface=np.asarray(faces).ravel().tolist())
        body.add_geom(name=f"obj/0_{obj.name}/part_{i}", type=mujoco.mjtGeom.mjGEOM_MESH,
                      meshname=f"{obj.name}_part_{i}", friction=[FRICTION, 0.005, 0.0001])
    attach_gripper(spec, load_gripper(gripper))
    model = spec.compile()
    # Settle (what the scenes stage does): park the gripper far away, let the object come to rest, keep the qpos.
    data = mujoco.MjData(model)
    away = np.eye(4)
    away[:3, 3] = [2.0, 2.0, 1.0]
    set_gripper_pose(model, data, away)
    mujoco.mj_step(model, data, nstep=250)
    bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"obj/0_{obj.name}")
    R = data.xmat[bid].reshape(3, 3)
    verts = obj.vertices @ R.T + data.xpos[bid]
    return model, data.qpos.copy(), verts


def sample_grasps(verts: np.ndarray, n: int, rng: np.random.Generator) -> list[tuple[np.ndarray, float]]:
    """Random top-down grasps across the object (see the module docstring)."""
    xy = verts[:, :2]
    centre_xy = (xy.max(0) + xy.min(0)) / 2.0
    evals, evecs = np.linalg.eigh(np.cov((xy - centre_xy).T))
    short_axis, long_axis = evecs[:, 0], evecs[:, 1]  # eigh: ascending
    length = float(np.ptp(xy @ long_axis))
    top = float(verts[:, 2].max())
    grasps = []
    for _ in range(n):
        yaw = math.atan2(short_axis[1], short_axis[0]) + rng.normal(0.0, math.radians(10.0))
        x_axis = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        z_axis = np.array([0.0, 0.0, -1.0])
        T = np.eye(4)
        T[:3, 0], T[:3, 2] = x_axis, z_axis
        T[:3, 1] = np.cross(z_axis, x_axis)
        along = rng.uniform(-0.6, 0.6) * length
        across = rng.normal(0.0, 0.003)
        T[:2, 3] = centre_xy + along * long_axis + across * x_axis[:2]
        T[2, 3] = top - rng.uniform(0.0, 0.045)
        width = float(np.ptp(verts @ x_axis))
        grasps.append((T, width))
    return grasps


class _StepTimer:
    """Context manager: while active, ``mujoco.mj_step`` is wrapped so that the time spent inside it (and the steps
    taken) are summed. :mod:`graspgen.sim.lift` looks ``mujoco.mj_step`` up when it steps (never caches it across
    calls), so the rollouts run their exact physics through the wrapper: the sum is the bare ``mj_step`` cost of
    exactly those steps, Python -> C call included, everything else excluded."""

    def __enter__(self) -> _StepTimer:
        self.seconds, self.steps, self.calls = 0.0, 0, 0
        self._orig = orig = mujoco.mj_step
        clock = time.perf_counter

        def timed(m, d, nstep=1):
            t = clock()
            orig(m, d, nstep)
            self.seconds += clock() - t
            self.steps += nstep
            self.calls += 1

        mujoco.mj_step = timed
        return self

    def __exit__(self, *exc) -> None:
        mujoco.mj_step = self._orig


def timer_overhead_s(calls: int = 200_000) -> float:
    """Seconds :class:`_StepTimer` adds per ``mj_step`` call: ``calls`` calls of a no-op through the timer's
    wrapper, less the same calls of the no-op itself, per call."""

    def noop(m, d, nstep=1):
        return None

    def loop(fn) -> float:
        t0 = time.perf_counter()
        for _ in range(calls):
            fn(None, None)
        return time.perf_counter() - t0

    orig = mujoco.mj_step
    mujoco.mj_step = noop
    try:
        with _StepTimer():
            wrapped = loop(mujoco.mj_step)
    finally:
        mujoco.mj_step = orig
    return max(0.0, (wrapped - loop(noop)) / calls)


def measure(model, qpos, grasps, target: str, params: LiftParams, rounds: int) -> dict:
    """Time the rollouts (best of ``rounds`` plain passes), and the wall and the ``mj_step`` floor of one
    instrumented pass (of ``rounds``, the one with the smallest wall): wall and floor of the same pass."""
    sim = LiftSimulator(model, params, qpos=qpos)
    for T, w in grasps[:5]:  # warm-up (caches, first touch of MjData pages)
        sim.rollout(T, w, target)
    walls, instrumented = [], []
    results = None
    for _ in range(rounds):  # interleaved, best of each: this machine is shared, the minimum is the least disturbed
        t0 = time.perf_counter()
        timed = [sim.rollout(T, w, target) for T, w in grasps]
        walls.append(time.perf_counter() - t0)
        with _StepTimer() as timer:
            t0 = time.perf_counter()
            again = [sim.rollout(T, w, target) for T, w in grasps]
            pass_wall = time.perf_counter() - t0
        instrumented.append((pass_wall, timer.seconds, timer.calls))
        assert timer.steps == sum(r.steps for r in again), "a step escaped the timer"
        assert again == timed and (results is None or timed == results), "rollouts must be deterministic"
        results = timed
    wall = min(walls)
    floor_wall, floor, calls = min(instrumented)
    steps = np.array([r.steps for r in results])
    success = np.array([r.success for r in results])
    hist = collections.Counter(OUTCOME_NAMES[r.code] for r in results)
    n = len(grasps)
    return {
        "rollouts": n,
        "rounds": rounds,
        "rollouts_per_s": n / wall,
        "ms_per_rollout": 1e3 * wall / n,
        "steps_per_rollout": float(steps.mean()),
        "steps_per_success": float(steps[success].mean()) if success.any() else None,
        "sim_s_per_rollout": float(steps.mean() * sim.model.opt.timestep),
        "bare_us_per_step": 1e6 * floor / int(steps.sum()),
        "floor_ms_per_rollout": 1e3 * floor / n,
        "floor_pass_ms_per_rollout": 1e3 * floor_wall / n,
        "ratio_to_floor": floor_wall / floor,
        "timer_calls_per_rollout": calls / n,
        "timer_overhead_us_per_call": 1e6 * timer_overhead_s(),
        "outcomes": {name: hist.get(name, 0) for name in OUTCOME_NAMES},
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rollouts", type=int, default=300, help="rollouts per object and setting")
    parser.add_argument("--rounds", type=int, default=3, help="timed passes (the best counts)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--gripper", default=DEFAULT_GRIPPER,
                        help="bundled gripper name or gripper file (e.g. panda, robotiq_2f85_mesh)")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    rows = []
    for name in ("box", "can"):
        t = time.perf_counter()
        obj = load_object(name)
        prep_s = time.perf_counter() - t
        model, qpos, verts = build_scene(obj, args.gripper)
        grasps = sample_grasps(verts, args.rollouts, np.random.default_rng(args.seed))
        for shake in (False, True):
            params = LiftParams(shake=shake)
            row = {"object": name, "shake": shake, "convex_parts": len(obj.convex_parts),
                   "hull_vertices": [len(v) for v, _ in obj.convex_parts], "mass_kg": obj.mass.mass,
                   "prepare_s": prep_s, "nv": model.nv, "ngeom": model.ngeom}
            row.update(measure(model, qpos, grasps, f"obj/0_{obj.name}", params, args.rounds))
            rows.append(row)
    header = (f"{'object':<6} {'shake':<5} {'parts':>5} {'rollouts/s':>10} {'ms/roll':>8} {'steps/roll':>10} "
              f"{'steps/succ':>10} {'us/step':>8} {'floor ms':>8} {'ratio':>6}  outcomes 0/1/2/3/4/5")
    print(header)
    print("-" * len(header))
    for r in rows:
        hist = "/".join(str(v) for v in r["outcomes"].values())
        print(f"{r['object']:<6} {str(r['shake']):<5} {r['convex_parts']:>5} {r['rollouts_per_s']:>10.1f} "
              f"{r['ms_per_rollout']:>8.2f} {r['steps_per_rollout']:>10.0f} {r['steps_per_success'] or 0:>10.0f} "
              f"{r['bare_us_per_step']:>8.1f} "
              f"{r['floor_ms_per_rollout']:>8.2f} {r['ratio_to_floor']:>6.3f}  {hist}")
    print("rollouts/s, ms/roll: best plain pass; floor ms: time inside mj_step, ratio: that pass's wall / floor (one "
          f"instrumented pass; its timer adds ~{rows[0]['timer_overhead_us_per_call']:.2f} us per mj_step call, "
          "timer_calls_per_rollout in the JSON)")
    out = {
        "bench": "rollouts",
        "params": {k: v for k, v in dataclasses.asdict(LiftParams()).items()},
        "gripper": args.gripper,
        "object_friction": FRICTION,
        "mujoco": mujoco.__version__,
        "python": sys.version.split()[0],
        "machine": platform.machine(),
        "cpu_count": os.cpu_count(),
        "results": rows,
    }
    args.out.write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
