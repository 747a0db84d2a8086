"""Label fidelity: our labels against ACRONYM's FleX labels on the calibration grasps (:mod:`studies.calibration`).

For every ACRONYM file under the calibration folder (the example mug, and a bottle, bowl, hat, knife and mug: 1,000
Franka Panda grasps each, ``grasps/qualities/flex/object_in_gripper``), the grasps are labelled by
:func:`graspgen.workflows.evaluate.evaluate_grasps` with the Panda (object mass, friction and scale from the file) under

* ``table``: the pipeline's protocol in free space (pre-grasp 5 cm back, approach, close, lift, hold, then the
  shake, on by default since issue 11: ``LiftParams.shake``): what ``gen evaluate`` did before protocols were named
  (then without the shake), the "before" numbers;
* ``acronym``: ACRONYM's own test (:class:`graspgen.sim.protocols.AcronymParams`): the "after" numbers;
* ``graspdatagen``: GraspDataGen's tug test (:class:`graspgen.sim.protocols.GraspDataGenParams`), on request
  (``--protocols table,acronym,graspdatagen``).

Printed per object and pooled: agreement (our success == FleX held), Cohen's kappa, our and FleX's success rates,
the confusion of our outcome codes against FleX held/lost, and, among our successes, the AUC with which a score
separates FleX-held from FleX-lost grasps (Mann-Whitney; 0.5 = no better than chance): ``epsilon`` (Ferrari-Canny
of our closing contacts, pad model, the object's friction, torsional 0.005 m, :func:`graspgen.quality.epsilon.
grasp_epsilon`) and, with ``--robustness N``, ``robustness`` and ``grip_robustness`` (the success rate of N copies of
the grasp perturbed as the robustness stage perturbs them, its default noise: TCP 5 mm / 5 deg per axis, object mass
log-normal 0.2, centre of mass 5 mm per axis, friction +-0.1; rolled out with the same protocol by the evaluate path
itself, ``evaluate_grasps(robustness=RobustnessParams(num_perturbations=N))``, i.e. ``gen evaluate --robustness N``, the
draws seeded from the poses and settings; ``grip_robustness`` leaves out the copies stopped by a collision at
placement or approach; skipped with a note otherwise: it costs N rollouts per success). Also the median motion of
the object during closing and shaking, ours against FleX's (ACRONYM's ``object_motion_during_*``), for the grasps
both call held.

Two labels of ours are compared with FleX's ``object_in_gripper``: **held** (outcome 5: the object still between the
fingers after the protocol's disturbance, the label ACRONYM's files carry) and **firm** (held, and the object's
largest motion in the hand over the disturbance within ``LiftParams.firm_translation`` / ``firm_rotation``,
:attr:`graspgen.sim.protocols.RolloutResult.firm`). Both are reported pooled and per category (the ACRONYM file name's
prefix: bottle, bowl, hat, knife, mug, scissors), with bootstrap 95% intervals (:func:`kappa_interval`, grasps
resampled within each object), and the median largest rotation in the hand of our held grasps against FleX's
``object_motion_during_shaking_angular`` of its held ones.

``--speed``: rollouts per second of each protocol run on the calibration mug in one process (one core), from the
slope of two timed evaluations (300 and 10 grasps, so preparing the mesh and compiling the model do not count),
best of 2.

``--sweep``: the sensitivity of the pooled agreement and kappa to the acronym protocol's free parameters, one at a
time around the defaults (the others at their defaults): shake amplitude and frequency, grip force, closing speed,
contact softness (solref time constant; solimp), friction (the object's sliding coefficient, which governs gripper
contacts, :mod:`graspgen.sim.gripper_model`; and the pads' torsional coefficient: how pad and object friction combine
into the contact's sliding and torsional terms) and the gravity mode.

The defaults are NOT chosen from these numbers: the calibration files are a sample, and a protocol tuned to them
would measure nothing. Where each default comes from (the ACRONYM paper and files, the nearest published FleX
scene, the Panda's data sheet, physical arguments) is written in :class:`graspgen.sim.protocols.AcronymParams`; the
sweep only shows how much the agreement depends on each choice.

Run: ``python -m studies.fidelity [-j 2] [--limit N] [--protocols table,acronym,graspdatagen] [--sweep] [--speed]
[--robustness N] [--calibration DIR] [--out FILE]``; writes ``studies/results_fidelity.json`` (gitignored).
``--limit N`` takes N evenly spaced grasps per object (quick runs); the default is all of them. The learning set
(``--calibration ../shared/learn/acronym --limit 100``: 100 grasps of each of its 69 files) is read the same way.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

from graspgen.grippers import load_gripper
from graspgen.io.acronym import read_acronym
from graspgen.quality.epsilon import grasp_epsilon
from graspgen.quality.perturbation import RobustnessParams
from graspgen.sim.gripper_model import build_gripper
from graspgen.sim.protocols import OUTCOME_NAMES, AcronymParams, GraspDataGenParams, LiftParams
from graspgen.workflows.evaluate import evaluate_grasps
from graspgen.workflows.evaluate_columns import METADATA_KEY
from graspgen.workflows.evaluate_settings import EvaluateParams
from studies.calibration import REPO, STUDIES, Case, add_calibration_option, load_cases, subset

RESULTS = STUDIES / "results_fidelity.json"
SPEED_OBJECT = "even_Mug_10f6e0"  # the calibration mug (ACRONYM's example)
TORSIONAL = 0.005  # m, the pads' torsional friction (the epsilon's soft-finger floor, as metrics.epsilon)


LABELS = ("held", "firm")
"""Our labels compared with FleX's: held (outcome 5) and firm (:attr:`graspgen.sim.protocols.RolloutResult.firm`)."""


# ---------------------------------------------------------------------------------------------------------------
# Statistics
# ---------------------------------------------------------------------------------------------------------------


def kappa(ours: np.ndarray, theirs: np.ndarray) -> float:
    """Cohen's kappa of two binary label vectors (NaN when chance agreement is 1)."""
    ours, theirs = np.asarray(ours, bool), np.asarray(theirs, bool)
    po = float(np.mean(ours == theirs))
    pe = float(np.mean(ours) * np.mean(theirs) + np.mean(~ours) * np.mean(~theirs))
    return (po - pe) / (1.0 - pe) if pe < 1.0 else math.nan


def kappa_interval(ours: np.ndarray, theirs: np.ndarray, groups: np.ndarray, resamples: int = 2000,
                   seed: int = 0, level: float = 0.95) -> dict:
    """Bootstrap interval of Cohen's kappa and of the agreement of two binary label vectors ``(n,)``: the grasps are
    resampled with replacement within each group (object), so every resample keeps each object's share; percentile
    interval at ``level``, draws from ``numpy.random.default_rng(seed)``."""
    ours, theirs, groups = np.asarray(ours, bool), np.asarray(theirs, bool), np.asarray(groups)
    rng = np.random.default_rng(seed)
    members = [np.flatnonzero(groups == g) for g in np.unique(groups)]
    kappas, agreements = np.empty(resamples), np.empty(resamples)
    for r in range(resamples):
        idx = np.concatenate([rng.choice(m, size=len(m)) for m in members])
        kappas[r], agreements[r] = kappa(ours[idx], theirs[idx]), np.mean(ours[idx] == theirs[idx])
    q = [100 * (1 - level) / 2, 100 * (1 + level) / 2]
    return {"kappa": [float(x) for x in np.nanpercentile(kappas, q)],
            "agreement": [float(x) for x in np.percentile(agreements, q)], "level": level, "resamples": resamples}


def auc(scores: np.ndarray, positive: np.ndarray) -> float:
    """Probability that a random positive scores above a random negative (ties count half); NaN without both."""
    scores, positive = np.asarray(scores, float), np.asarray(positive, bool)
    pos, neg = scores[positive], scores[~positive]
    if len(pos) == 0 or len(neg) == 0:
        return math.nan
    order = np.argsort(np.concatenate([pos, neg]), kind="mergesort")
    values = np.concatenate([pos, neg])[order]
    ranks = np.empty(len(values))
    i = 0
    while i < len(values):  # average ranks of ties
        j = i
        while j + 1 < len(values) and values[j + 1] == values[i]:
            j += 1
        ranks[i:j + 1] = (i + j) / 2.0 + 1.0
        i = j + 1
    r = np.empty(len(values))
    r[order] = ranks
    return float((r[:len(pos)].sum() - len(pos) * (len(pos) + 1) / 2.0) / (len(pos) * len(neg)))


# ---------------------------------------------------------------------------------------------------------------
# Evaluation
# ---------------------------------------------------------------------------------------------------------------


def evaluate(case: Case, lift: LiftParams, args, T: np.ndarray | None = None, friction: float | None = None,
             robustness: int = 0):
    """``evaluate_grasps`` on the case's object; ``robustness`` > 0 adds that many perturbed copies per success
    (the robustness stage's default noise) and the robustness columns."""
    params = EvaluateParams(lift=lift, friction=case.friction if friction is None else friction, mass=case.mass,
                            density=case.density if case.density is not None else 700.0)
    noise = RobustnessParams(num_perturbations=robustness) if robustness else None
    return evaluate_grasps(case.mesh, case.scale, case.T if T is None else T, None, args.gripper, params,
                           jobs=args.jobs, cache_dir=args.cache_dir, robustness=noise)


def epsilons(table, friction: float) -> np.ndarray:
    """Epsilon of every row's closing contacts (object frame), 0 without contacts on both jaws."""
    meta = json.loads(table.schema.metadata[METADATA_KEY.encode()])
    com, scale = np.asarray(meta["center_of_mass"]), float(meta["torque_scale"])
    points, normals = table.column("contact_points").to_pylist(), table.column("contact_normals").to_pylist()
    fingers = table.column("contact_fingers").to_pylist()
    out = np.zeros(len(table))
    for i, (p, n, f) in enumerate(zip(points, normals, fingers)):
        if f and len(set(f)) == 2:
            out[i] = grasp_epsilon(np.reshape(p, (-1, 3)), np.reshape(n, (-1, 3)), np.asarray(f), com,
                                   friction=friction, torque_scale=scale, torsional_friction=TORSIONAL)
    return out


def summarise(case: Case, table, lift: LiftParams, args) -> dict:
    codes = table.column("outcome").to_numpy()
    ours, flex = codes == 5, case.flex == 1
    confusion = {OUTCOME_NAMES[c]: [int(np.sum((codes == c) & flex)), int(np.sum((codes == c) & ~flex))]
                 for c in range(6)}
    eps = epsilons(table, case.friction)
    firm = table.column("firm").to_numpy(zero_copy_only=False).astype(bool)
    row = {
        "object": case.name, "category": case.category, "firm": firm.tolist(),
        "max_rel_translation": table.column("max_rel_translation").to_numpy().tolist(),
        "max_rel_rotation": table.column("max_rel_rotation").to_numpy().tolist(),
        "firm_agreement": float(np.mean(firm == flex)), "firm_kappa": kappa(firm, flex),
        "our_firm": float(np.mean(firm)), "n": int(len(codes)), "agreement": float(np.mean(ours == flex)),
        "kappa": kappa(ours, flex), "our_success": float(np.mean(ours)), "flex_success": float(np.mean(flex)),
        "confusion": confusion, "auc_epsilon": auc(eps[ours], flex[ours]),
        "codes": codes.tolist(), "flex": case.flex.tolist(), "epsilon": eps.tolist(),
    }
    if args.robustness:  # from the evaluate path's own columns (NaN where our nominal outcome is not success)
        for key in ("robustness", "grip_robustness"):
            values = table.column(key).to_numpy(zero_copy_only=False)
            known = ours & np.isfinite(values)
            row[f"auc_{key}"] = auc(values[known], flex[known])
            row[key] = [None if math.isnan(v) else float(v) for v in values]
        row["robustness_copies"] = int(np.sum(table.column("robustness_n").to_numpy()))
    both = ours & flex
    for phase in ("closing", "shaking"):
        for kind in ("linear", "angular"):
            key = f"motion_{phase}_{kind}"
            mine = table.column(key).to_numpy()[both]
            theirs = case.flex_motion.get(f"object_motion_during_{phase}_{kind}", np.full(len(codes), np.nan))[both]
            row[key] = {"ours_median": float(np.nanmedian(mine)) if np.isfinite(mine).any() else math.nan,
                        "flex_median": float(np.nanmedian(theirs)) if len(theirs) else math.nan}
    return row


def pooled(rows: list[dict]) -> dict:
    codes = np.concatenate([r["codes"] for r in rows])
    flex = np.concatenate([r["flex"] for r in rows]).astype(bool)
    eps = np.concatenate([r["epsilon"] for r in rows])
    ours = codes == 5
    out = {
        "object": "pooled", "n": int(len(codes)), "agreement": float(np.mean(ours == flex)), "kappa": kappa(ours, flex),
        "interval": kappa_interval(ours, flex, np.repeat(np.arange(len(rows)), [r["n"] for r in rows])),
        "our_success": float(np.mean(ours)), "flex_success": float(np.mean(flex)),
        "confusion": {OUTCOME_NAMES[c]: [int(np.sum((codes == c) & flex)), int(np.sum((codes == c) & ~flex))]
                      for c in range(6)},
        # Pooled AUCs mix objects whose scores are on different scales; the per-object mean is given too.
        "auc_epsilon": auc(eps[ours], flex[ours]),
        "auc_epsilon_mean": float(np.nanmean([r["auc_epsilon"] for r in rows])),
    }
    if all("robustness" in r for r in rows):
        for key in ("robustness", "grip_robustness"):
            values = np.array([np.nan if v is None else v for r in rows for v in r[key]])
            known = ours & np.isfinite(values)
            out[f"auc_{key}"] = auc(values[known], flex[known])
            out[f"auc_{key}_mean"] = float(np.nanmean([r[f"auc_{key}"] for r in rows]))
    return out


def ours(row: dict, label: str) -> np.ndarray:
    """``(n,) bool`` our ``label`` (:data:`LABELS`) of a summarised object."""
    return np.asarray(row["codes"]) == 5 if label == "held" else np.asarray(row["firm"], bool)


def by_category(rows: list[dict]) -> dict:
    """Agreement and kappa of each of our :data:`LABELS` with FleX's, pooled (``all``) and per category, with
    bootstrap 95% intervals (grasps resampled within each object), our and FleX's success rates, and the median
    largest rotation / translation in the hand (``max_rel_*``) of our held grasps and FleX's median shaking rotation
    of its held ones."""
    groups = {"all": rows}
    for r in rows:
        groups.setdefault(r["category"], []).append(r)
    out: dict = {}
    for group, members in groups.items():
        flex = np.concatenate([r["flex"] for r in members]).astype(bool)
        objects = np.repeat(np.arange(len(members)), [r["n"] for r in members])
        held = np.concatenate([ours(r, "held") for r in members])
        entry: dict = {"objects": len(members), "n": int(len(flex)), "flex_success": float(np.mean(flex))}
        for label in LABELS:
            mine = np.concatenate([ours(r, label) for r in members])
            entry[label] = {"agreement": float(np.mean(mine == flex)), "kappa": kappa(mine, flex),
                            "our_success": float(np.mean(mine)),
                            "interval": kappa_interval(mine, flex, objects, resamples=1000)}
        rot = np.concatenate([r["max_rel_rotation"] for r in members])[held]
        trans = np.concatenate([r["max_rel_translation"] for r in members])[held]
        flex_rot = np.concatenate([np.asarray(r["flex_shaking_angular"], float) for r in members])[flex]
        entry["held_max_rel_rotation_median"] = float(np.median(rot)) if len(rot) else math.nan
        entry["held_max_rel_translation_median"] = float(np.median(trans)) if len(trans) else math.nan
        entry["flex_held_shaking_angular_median"] = (float(np.nanmedian(flex_rot)) if np.isfinite(flex_rot).any()
                                                     else math.nan)
        out[group] = entry
    return out


def run_protocol(cases: list[Case], lift: LiftParams, args, label: str) -> dict:
    rows = []
    for case in cases:
        t0 = time.perf_counter()
        table = evaluate(case, lift, args, robustness=args.robustness)
        rows.append(summarise(case, table, lift, args))
        rows[-1]["flex_shaking_angular"] = case.flex_motion.get(
            "object_motion_during_shaking_angular", np.full(len(table), np.nan)).tolist()
        print(f"  [{label}] {case.name}: {len(table)} grasps in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return {"objects": rows, "pooled": pooled(rows), "labels": by_category(rows)}


def print_labels(result: dict) -> None:
    """The held and firm labels against FleX, pooled and per category."""
    lift = LiftParams()
    print(f"\nour two labels against FleX's object_in_gripper (firm: max motion in the hand <= "
          f"{1000 * lift.firm_translation:.0f} mm and {math.degrees(lift.firm_rotation):.0f} deg), 95% bootstrap "
          "intervals:\n")
    print("| category | objects | n | FleX held | label | our held | agreement | kappa | median max rotation in hand "
          "(ours held) / FleX shaking rad |")
    print("| --- | ---: | ---: | ---: | --- | ---: | --- | --- | --- |")
    for group, e in result["labels"].items():
        for label in LABELS:
            x = e[label]
            iv = x["interval"]
            rot = (f"{fmt(e['held_max_rel_rotation_median'])} / {fmt(e['flex_held_shaking_angular_median'])}"
                   if label == "held" else "")
            print(f"| {group} | {e['objects']} | {e['n']} | {fmt(e['flex_success'])} | {label} | "
                  f"{fmt(x['our_success'])} | {fmt(x['agreement'])} ({fmt(iv['agreement'][0])}-"
                  f"{fmt(iv['agreement'][1])}) | {fmt(x['kappa'], 2)} ({fmt(iv['kappa'][0], 2)}-"
                  f"{fmt(iv['kappa'][1], 2)}) | {rot} |")


# ---------------------------------------------------------------------------------------------------------------
# Speed and sweep
# ---------------------------------------------------------------------------------------------------------------


def speed(cases: list[Case], args, protocol: str = "acronym") -> dict:
    """``protocol``'s rollouts/s in one process on the calibration mug: slope between 10 and 300 grasps, best of 2."""
    case = next((c for c in cases if c.path.name.startswith(SPEED_OBJECT)), cases[0])
    full = read_acronym(case.path)
    T = full.tcp_poses()[subset(len(full), 300)]
    lift = LiftParams(protocol=protocol)
    one = argparse.Namespace(**{**vars(args), "jobs": 1})
    best = None
    for _ in range(2):
        times, cpu, steps = [], [], []
        for m in (10, len(T)):
            t0, c0 = time.perf_counter(), time.process_time()
            table = evaluate(case, lift, one, T=T[:m])
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
            steps.append(int(np.sum(table.column("steps").to_numpy())))
        rate = (len(T) - 10) / (times[1] - times[0])
        if best is None or rate > best["rollouts_per_s"]:
            best = {"object": case.name, "rollouts": len(T), "rollouts_per_s": rate,
                    "rollouts_per_cpu_s": (len(T) - 10) / (cpu[1] - cpu[0]),
                    "load_average": os.getloadavg()[0], "cpus": os.cpu_count(),
                    "steps_per_rollout": (steps[1] - steps[0]) / (len(T) - 10),
                    "us_per_step": 1e6 * (times[1] - times[0]) / (steps[1] - steps[0]),
                    "outcomes": {n: int(v) for n, v in zip(OUTCOME_NAMES, np.bincount(
                        table.column("outcome").to_numpy(), minlength=6))}}
    return best


def sweep_settings() -> list[tuple[str, list, object]]:
    """(parameter, values, how a value becomes (LiftParams, object friction or None))."""
    base = AcronymParams()

    def acr(**kw) -> LiftParams:
        return LiftParams(protocol="acronym", acronym=dataclasses.replace(base, **kw))

    return [
        ("shake_amplitude (m)", [0.0, 0.0075, 0.015, 0.03], lambda v: (acr(shake_amplitude=v), None)),
        ("shake_frequency (Hz)", [2.0, 4.0, 8.0], lambda v: (acr(shake_frequency=v), None)),
        ("shake_angle (rad)", [0.0, 0.075, 0.15, 0.3], lambda v: (acr(shake_angle=v), None)),
        ("grip_force (N)", [20.0, 35.0, 70.0, 140.0], lambda v: (acr(grip_force=v), None)),
        ("closing_speed (m/s)", [0.05, 0.1, 0.2], lambda v: (acr(closing_speed=v), None)),
        ("contact solref time constant (s)", [0.004, 0.01, 0.02],
         lambda v: (acr(contact_solref=(v, 1.0)), None)),
        ("contact solimp (dmin, dmax)", [(0.95, 0.99), (0.9, 0.95), (0.99, 0.999)],
         lambda v: (acr(contact_solimp=(v[0], v[1], 0.001, 0.5, 2.0)), None)),
        ("sliding friction (object, governs)", [0.5, 0.7, 1.0, 1.4], lambda v: (acr(), v)),
        ("pad torsional friction (m)", [0.0, 0.005, 0.02], lambda v: (acr(torsional_friction=v), None)),
        ("gravity", ["approach", "world", "off"], lambda v: (acr(gravity=v), None)),
    ]


DEFAULTS = {"shake_amplitude (m)": 0.015, "shake_frequency (Hz)": 4.0, "shake_angle (rad)": 0.15,
            "grip_force (N)": 70.0, "closing_speed (m/s)": 0.1, "contact solref time constant (s)": 0.004,
            "contact solimp (dmin, dmax)": (0.95, 0.99), "sliding friction (object, governs)": 1.0,
            "pad torsional friction (m)": 0.005, "gravity": "approach"}


def sweep(cases: list[Case], args) -> list[dict]:
    out = []
    only = [w for w in args.sweep_only.split(",") if w]
    for name, values, make in sweep_settings():
        if only and not any(w in name for w in only):
            continue
        for v in values:
            lift, friction = make(v)
            t0 = time.perf_counter()
            codes, flex = [], []
            for case in cases:
                codes.append(evaluate(case, lift, args, friction=friction).column("outcome").to_numpy())
                flex.append(case.flex)
            codes, flex = np.concatenate(codes), np.concatenate(flex).astype(bool)
            ours = codes == 5
            row = {"parameter": name, "value": v, "default": v == DEFAULTS[name], "n": int(len(codes)),
                   "agreement": float(np.mean(ours == flex)), "kappa": kappa(ours, flex),
                   "our_success": float(np.mean(ours))}
            out.append(row)
            print(f"  [sweep] {name} = {v}: agreement {row['agreement']:.3f} kappa {row['kappa']:.3f} "
                  f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return out


# ---------------------------------------------------------------------------------------------------------------
# Report
# ---------------------------------------------------------------------------------------------------------------


def gripper_info(name: str) -> dict:
    spec = load_gripper(name)
    model = build_gripper(spec).compile()
    kinds = [mujoco.mjtGeom(int(t)).name.removeprefix("mjGEOM_").lower() for t in model.geom_type]
    return {"name": spec.name, "source": spec.source, "geoms": {k: kinds.count(k) for k in sorted(set(kinds))}}


def fmt(x: float, digits: int = 3) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def print_protocol(label: str, result: dict, robust: bool) -> None:
    print(f"\n### {label}\n")
    head = "| object | n | agreement | kappa | our success | FleX success | AUC epsilon |"
    print(head + (" AUC robustness | AUC grip robustness |" if robust else ""))
    print("|" + " --- |" * (7 + 2 * robust))
    for r in result["objects"] + [result["pooled"]]:
        cells = [r["object"], str(r["n"]), fmt(r["agreement"]), fmt(r["kappa"], 2), fmt(r["our_success"]),
                 fmt(r["flex_success"]), fmt(r["auc_epsilon"], 2)]
        if robust:
            cells += [fmt(r.get("auc_robustness"), 2), fmt(r.get("auc_grip_robustness"), 2)]
        print("| " + " | ".join(cells) + " |")
    if not robust:
        print("\nAUC robustness: not computed (run with --robustness N: N perturbed rollouts per success).")
    p = result["pooled"]
    iv = p["interval"]
    print(f"\npooled 95% bootstrap intervals (grasps resampled within each object): agreement "
          f"{fmt(iv['agreement'][0])}-{fmt(iv['agreement'][1])}, "
          f"kappa {fmt(iv['kappa'][0], 2)}-{fmt(iv['kappa'][1], 2)}")
    print(f"\npooled AUC epsilon: {fmt(p['auc_epsilon'], 2)} (mean of per-object AUCs {fmt(p['auc_epsilon_mean'], 2)})"
          + (f"; robustness: {fmt(p['auc_robustness'], 2)} (mean {fmt(p['auc_robustness_mean'], 2)}); grip "
             f"robustness: {fmt(p['auc_grip_robustness'], 2)} (mean {fmt(p['auc_grip_robustness_mean'], 2)})"
             if "auc_robustness" in p else ""))
    print("\nconfusion (pooled): our outcome vs FleX\n\n| our outcome | n | FleX held | FleX lost | FleX held % |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for name, (held, lost) in p["confusion"].items():
        if held + lost:
            print(f"| {name} | {held + lost} | {held} | {lost} | {100.0 * held / (held + lost):.0f} |")
    print("\nmedian object motion, grasps both call held (ours / FleX):\n")
    print("| object | closing m | closing rad | shaking m | shaking rad |\n| --- | --- | --- | --- | --- |")
    for r in result["objects"]:
        cells = [f"{fmt(r[k]['ours_median'], 4)} / {fmt(r[k]['flex_median'], 4)}" for k in (
            "motion_closing_linear", "motion_closing_angular", "motion_shaking_linear", "motion_shaking_angular")]
        print(f"| {r['object']} | " + " | ".join(cells) + " |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("-j", "--jobs", type=int, default=2, help="worker processes per evaluation (default 2)")
    ap.add_argument("--limit", type=int, default=None, help="evenly spaced grasps per object (default: all)")
    ap.add_argument("--protocols", default="table,acronym", help="comma-separated: table, acronym, graspdatagen")
    ap.add_argument("--sweep", action="store_true", help="sensitivity of pooled agreement/kappa (acronym protocol)")
    ap.add_argument("--sweep-only", default="", help="comma-separated words: sweep only parameters naming one")
    ap.add_argument("--speed", action="store_true", help="rollouts/s of each protocol on the calibration mug, one "
                    "core (acronym when --protocols is empty)")
    ap.add_argument("--robustness", type=int, default=0, help="perturbed copies per success for the robustness AUC")
    ap.add_argument("--gripper", default="panda")
    ap.add_argument("--pad-sink", default=LiftParams().pad_sink, choices=("bounded", "model"),
                    help="LiftParams.pad_sink: the pads' sink into light objects bounded (default) or the model's")
    add_calibration_option(ap)
    ap.add_argument("--cache-dir", type=Path, default=REPO / ".cache", help="CoACD cache (as run.cache_dir)")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    protocols = [p for p in args.protocols.split(",") if p]
    cases = load_cases(args.calibration, args.limit)
    report: dict = {"limit": args.limit, "calibration": str(args.calibration),
                    "firm_tolerances": {"translation": LiftParams().firm_translation,
                                        "rotation": LiftParams().firm_rotation},
                    "gripper": gripper_info(args.gripper), "pad_sink": args.pad_sink, "protocols": {},
                    "acronym_params": AcronymParams().to_dict(), "graspdatagen_params": GraspDataGenParams().to_dict(),
                    "machine": platform.platform(),
                    "mujoco": mujoco.__version__}
    g = report["gripper"]
    print(f"gripper {g['name']}: geoms {g['geoms']}; {g['source'][:160]}")
    for protocol in protocols:
        lift = dataclasses.replace(LiftParams().with_protocol(protocol), pad_sink=args.pad_sink)
        report["protocols"][protocol] = run_protocol(cases, lift, args, protocol)
        kind = {"table": "free space, shake on", "acronym": "ACRONYM", "graspdatagen": "GraspDataGen"}[protocol]
        print_protocol(f"{protocol} protocol ({kind})",
                       report["protocols"][protocol], bool(args.robustness))
        print_labels(report["protocols"][protocol])
    if args.speed:
        report["speed"] = {}
        for protocol in protocols or ["acronym"]:
            report["speed"][protocol] = s = speed(cases, args, protocol)
            print(f"\nspeed ({protocol}, {s['object']}, one process): {s['rollouts_per_s']:.1f} rollouts/s wall, "
                  f"{s['rollouts_per_cpu_s']:.1f} per CPU second, {s['steps_per_rollout']:.0f} steps/rollout, "
                  f"{s['us_per_step']:.1f} us/step (load average {s['load_average']:.1f} on {s['cpus']} cores); "
                  f"{s['outcomes']}")
    if args.sweep:
        report["sweep"] = rows = sweep(cases, args)
        print("\n### sweep (acronym protocol, pooled; one parameter at a time, * = default)\n")
        print("| parameter | value | agreement | kappa | our success |\n| --- | --- | ---: | ---: | ---: |")
        for r in rows:
            print(f"| {r['parameter']} | {r['value']}{' *' if r['default'] else ''} | {fmt(r['agreement'])} | "
                  f"{fmt(r['kappa'], 2)} | {fmt(r['our_success'])} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1, default=lambda o: list(o) if isinstance(o, tuple) else str(o)))
    print(f"\nwrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
