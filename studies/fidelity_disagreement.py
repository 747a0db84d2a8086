"""Label disagreement with FleX, by grasp property: what separates FleX-held from FleX-lost among OUR successes.

A diagnostic, not a test, and nothing in the library is tuned from it: it measures which properties of a grasp go
with ACRONYM's FleX losing a grasp that our ``acronym`` protocol holds (the largest cell of the disagreement in
``studies/fidelity.py``), so that the next change can be chosen from the physics rather than by fitting settings.

What it does, per calibration object (:mod:`studies.calibration`: 6 objects x 1,000 Franka Panda grasps with FleX
labels ``grasps/qualities/flex/object_in_gripper``):

1. labels the grasps with :func:`graspgen.workflows.evaluate.evaluate_grasps`, protocol ``acronym`` with the default
   ``LiftParams(protocol="acronym")`` (via ``fidelity.evaluate``: the object's mass and friction from the file);
2. rolls our successes (outcome 5) and our collisions at placement (outcome 1) out once more, one by one, in the
   same world (:func:`graspgen.workflows.evaluation_world.evaluation_world`,
   :meth:`~graspgen.workflows.evaluation_world.EvaluationWorld.simulator`): the table's contacts are in the object's
   frame at the end of closing, whose pose it does not keep, and the contacts on the pads need the TCP frame. The
   rollouts are deterministic; the number whose outcome differs from the table's is printed (``replay mismatches``;
   expected 0). For outcome 1 the replay gives how deep the open hand is in the object's collision hulls and which part
   (pad, finger link, palm);
3. computes per grasp the features below, and prints, per object and pooled, for each feature among our successes
   the Mann-Whitney AUC of FleX-held against FleX-lost (``fidelity.auc``: the probability that a random FleX-held
   grasp has the larger value; 0.5 = no separation, < 0.5: larger values go with FleX losing the grasp), the
   number of held / lost grasps with a finite value, and the medians of both groups. The pooled AUC mixes objects
   (a feature that only tells the objects apart scores there); ``AUC within`` compares held and lost grasps of the
   same object only (the per-object AUCs weighted by n_held * n_lost), so per-object constants (mass, size) give
   0.5 there. Features are ranked by ``|AUC within - 0.5|``. The same is printed for our outcome 1 where there
   are >= 20 such grasps (pooled; per object where that object has >= 20).

Features (object frame = the scaled mesh frame; TCP frame: x closing, y across the pads, z approach, origin
between the pad faces, half-way along them; "left" = finger 0 on -x, pushing +x):

* ``ours_motion_{closing,shaking}_{linear_m,angular_rad}``: our object motion (the table's ``motion_*``);
  ``ours_slip_{m,rad}``: the object's motion in the hand from the end of closing to the end (``rel_*``; the hand
  is back at its pose when the shake ends, so for successes these equal ``ours_motion_shaking_*``).
* ``flex_motion_{closing,shaking}_{linear_m,angular_rad}``: FleX's own ``object_motion_during_*`` from the file
  (diagnostic only: whether FleX pushed the object around while closing; ``flex_motion_shaking_*`` is close to the
  label itself).
* ``closed_width_m``: pad separation when our closing ended.
* ``width_at_pads_m``: the object's width between the open pads, by ray casts from the pad faces along the
  closing axis at the grasp pose (5 x 5 rays per pad, :func:`graspgen.geometry.contacts.closing_contacts`);
  ``open_clearance_m``: open width (0.08 m) minus it; ``pad_gap_asymmetry_m``: the difference of the two open
  pads' distances to the surface (off-centre: how far the first pad to touch pushes the object before the other
  does; our jaws are coupled and push half of it); ``raycast_normal_angle_max_deg``: the largest angle between a
  ray-cast surface normal (into the object) and its pad's pushing direction, at the grasp pose;
  ``raycast_com_line_distance_m``: distance of the centre of mass from the line through the two pads' ray-cast
  contact centroids. These exist for every grasp whose open pads are outside the mesh (also for outcome 1).
* ``extent_along_closing_m``: the whole object's extent along the TCP x axis; ``object_extent_m``: the largest
  side of its bounding box; ``object_mass_kg``.
* ``grasp_depth_m``: fingertips (pad tip, TCP z = +8.8 mm) minus the TCP z of the object's surface point nearest
  the TCP (larger: deeper between the fingers); ``tcp_surface_distance_m``: distance of that point from the TCP.
* From our contacts at the end of closing (outcome 5; in the TCP frame of the grasp pose, where the hand stands
  while closing): ``contacts_{min,max}_per_finger``; ``link_contacts``: contacts below the pads (on the finger
  links, TCP z < -9.3 mm); ``pad_offset_along_max_m``: the larger over the fingers of the contact centroid's TCP z
  (+: towards the fingertip, which is at +8.8 mm: a fingertip grasp), ``pad_offset_along_abs_max_m`` its absolute
  value, ``pad_offset_across_abs_max_m`` the same across the pad (|TCP y|, pad half-width 8.7 mm);
  ``contact_spread_min_m``: per finger the largest distance of a contact from the finger's centroid, the smaller
  over the fingers (0: a single contact point, whose only resistance to turning about the grasp axis is the
  torsional friction); ``normal_angle_max_deg``: the largest angle between a contact normal (MuJoCo's, into the
  object) and the pushing direction of its finger (friction 1.0: the cone's edge is at 45 deg);
  ``surface_normal_angle_max_deg``: the same with the mesh's face normal at the surface point nearest each contact;
  ``grip_force_min_finger_N``: the smaller over the fingers of the summed normal forces.
* Lever arms (outcome 5; the centre of mass at the end of closing, the grasp axis through the two fingers' contact
  centroids): ``com_line_distance_m``, ``com_line_distance_x_mass_kgm`` (torque scale);
  ``gravity_torque_about_axis_Nm``: the torque of the object's weight (gravity along the approach axis, as the
  protocol applies it) about the grasp axis, which only friction (torsional, and sliding over a spread contact
  patch) resists; ``gravity_torque_over_torsional``: that over the pads' torsional friction capacity
  (0.005 m x total normal force); ``inertia_about_axis_kgm2``: the object's moment of inertia about the grasp axis
  (what the rotational shake about TCP x loads, peak ~99 rad/s^2).
* Outcome 1 only: ``open_hand_penetration_m``: deepest overlap of the open hand with the object's collision hulls
  at placement (what made it a collision), and the part (pad / finger / palm) counted per FleX label.

Run: ``python -m studies.fidelity_disagreement [-j 1] [--limit N] [--objects WORD,...] [--per-grasp]
[--calibration DIR]``. ``--limit N`` takes N evenly spaced grasps per object (as ``studies/fidelity.py``); the default
is all 1,000: 6,000 rollouts and ~5,400 replays, about 6 minutes on one core (CoACD cached in ``.cache``). Writes
``studies/results_fidelity_disagreement.json`` (gitignored); ``--per-grasp`` adds every grasp's outcome, FleX label
and features (NaN as null; rows in input order, with ``--limit`` the rows ``calibration.subset(1000, N)`` of the file).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import platform
import sys
import time
from pathlib import Path

import mujoco
import numpy as np
import trimesh

from graspgen.geometry.contacts import LEFT, RIGHT, closing_contacts
from graspgen.grippers import GripperSpec, load_gripper
from graspgen.sim.gripper_state import gripper_geom_ids
from graspgen.sim.protocols import OUTCOME_NAMES, AcronymParams, LiftParams, RolloutResult
from graspgen.workflows.evaluate_settings import EvaluateParams
from graspgen.workflows.evaluation_world import EvaluationWorld, evaluation_world
from studies import fidelity
from studies.calibration import REPO, STUDIES, Case, add_calibration_option, load_cases

RESULTS = STUDIES / "results_fidelity_disagreement.json"
G = 9.81  # m/s^2, the scene's gravity magnitude
RAYS_PER_SIDE = 5  # ray-cast grid per pad (5 x 5)
LINK_MARGIN = 0.0005  # m below the pad's lower edge from which a contact counts as on the finger link
MIN_GROUP = 20  # our outcome-1 grasps needed for their section (pooled, and per object)
TOP = 8  # features shown per object
SUCCESS, COLLISION = 5, 1
PARTS = ("pad", "finger", "palm")


# ---------------------------------------------------------------------------------------------------------------
# Rollouts
# ---------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass
class Replay:
    """One grasp rolled out again: the rollout, and for a collision at placement the open hand's overlap."""

    result: RolloutResult
    penetration: float = math.nan
    """Deepest overlap (m, > 0) of a gripper geom with the target at placement; NaN without one."""
    part: str = ""
    """The overlapping gripper part: ``pad``, ``finger`` or ``palm`` ('' without one)."""


def evaluate_params(case: Case, lift: LiftParams) -> EvaluateParams:
    """The object settings ``fidelity.evaluate`` uses (mass and friction from the file, density 700 otherwise)."""
    return EvaluateParams(lift=lift, friction=case.friction, mass=case.mass,
                          density=case.density if case.density is not None else 700.0)


def placement_overlap(model: mujoco.MjModel, data: mujoco.MjData, target_body: int,
                      part_of_geom: np.ndarray) -> tuple[float, str]:
    """Deepest gripper-target overlap among the contacts in ``data`` (the state at placement) and its part.

    Parameters
    ----------
    part_of_geom : (ngeom,) int
        Index into :data:`PARTS` of every gripper geom, -1 for the other geoms.

    Returns
    -------
    depth : float
        m, > 0; NaN without an overlapping contact.
    part : str
    """
    if data.ncon == 0:
        return math.nan, ""
    geom, dist = data.contact.geom.copy(), data.contact.dist.copy()
    on_target = model.geom_bodyid[geom] == target_body
    part = part_of_geom[geom]
    hand = np.where(on_target[:, 1], part[:, 0], np.where(on_target[:, 0], part[:, 1], -1))
    keep = (hand >= 0) & (dist < 0.0)
    if not keep.any():
        return math.nan, ""
    k = int(np.argmin(np.where(keep, dist, np.inf)))
    return float(-dist[k]), PARTS[int(hand[k])]


def replay_chunk(ew: EvaluationWorld, indices: np.ndarray) -> list[Replay]:
    """Roll grasps ``indices`` of ``ew`` out again in one freshly compiled model, as :func:`evaluate_grasps` does."""
    sim = ew.simulator()
    ids = gripper_geom_ids(sim.model)
    part_of_geom = np.full(sim.model.ngeom, -1)
    for p, name in enumerate(PARTS):
        part_of_geom[list(ids[name])] = p
    target = mujoco.mj_name2id(sim.model, mujoco.mjtObj.mjOBJ_BODY, ew.target_body)
    out = []
    for i in indices:
        result = sim.rollout(ew.T_world[i], float(ew.width[i]), ew.target_body)
        rep = Replay(result)
        if result.code == COLLISION and result.decided_in == "placement":
            rep.penetration, rep.part = placement_overlap(sim.model, sim.data, target, part_of_geom)
        out.append(rep)
    return out


def replay(ew: EvaluationWorld, indices: np.ndarray, jobs: int) -> dict[int, Replay]:
    """``{index: Replay}`` for the grasps ``indices``, in ``jobs`` contiguous chunks (joblib workers)."""
    from joblib import Parallel, delayed

    chunks = [c for c in np.array_split(np.asarray(indices), max(1, min(jobs, len(indices)))) if len(c)]
    parts = Parallel(n_jobs=len(chunks) or 1)(delayed(replay_chunk)(ew, c) for c in chunks)
    return {int(i): r for c, part in zip(chunks, parts) for i, r in zip(c, part)}


# ---------------------------------------------------------------------------------------------------------------
# Geometry
# ---------------------------------------------------------------------------------------------------------------


def to_tcp(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points ``(k, 3)`` (the frame ``T`` is given in) into the TCP frame of ``T`` ``(4, 4)``: ``(k, 3)``."""
    return (points - T[:3, 3]) @ T[:3, :3]


def pushing_directions(R_tcp: np.ndarray, fingers: np.ndarray) -> np.ndarray:
    """Direction each finger pushes, ``(k, 3)``, in the frame of ``R_tcp`` ``(3, 3)``: +x (left), -x (right)."""
    sign = np.where(np.asarray(fingers) == LEFT, 1.0, -1.0)
    return sign[:, None] * R_tcp[:, 0][None, :]


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (deg) between unit vectors ``a`` and ``b``, ``(k, 3)`` each: ``(k,)``."""
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)))


def line_distance(point: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Distance of ``point`` (3,) from the line through ``a`` and ``b`` (3,), the unit direction ``a -> b`` and the
    perpendicular offset vector from the line to the point (3,)."""
    u = (b - a) / max(float(np.linalg.norm(b - a)), 1e-12)
    r = point - a
    perp = r - (r @ u) * u
    return float(np.linalg.norm(perp)), u, perp


def raycast_features(mesh: trimesh.Trimesh, T: np.ndarray, spec: GripperSpec,
                     com: np.ndarray) -> dict[str, np.ndarray]:
    """Features of the object between the open pads at the grasp pose, by ray casts along the closing axis.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The prepared object, object frame, m.
    T : (n, 4, 4) float
        TCP poses, object frame.
    com : (3,) float
        Centre of mass, object frame.

    Returns
    -------
    dict of (n,) float arrays (NaN where a pad's rays hit nothing from outside)
        ``width_at_pads_m``, ``open_clearance_m``, ``pad_gap_asymmetry_m``, ``raycast_normal_angle_max_deg``,
        ``raycast_com_line_distance_m``.
    """
    n = len(T)
    out = {k: np.full(n, np.nan) for k in ("width_at_pads_m", "open_clearance_m", "pad_gap_asymmetry_m",
                                            "raycast_normal_angle_max_deg", "raycast_com_line_distance_m")}
    for i, c in enumerate(closing_contacts(mesh, T, spec, rays_per_side=RAYS_PER_SIDE)):
        if not c.both_fingers:
            continue
        x = to_tcp(T[i], c.points)[:, 0]
        left, right = c.finger == LEFT, c.finger == RIGHT
        x_left, x_right = x[left].min(), x[right].max()  # the first surface each pad reaches
        out["width_at_pads_m"][i] = x_right - x_left
        out["open_clearance_m"][i] = spec.max_width - (x_right - x_left)
        out["pad_gap_asymmetry_m"][i] = abs(x_left + x_right)  # gap_left - gap_right
        push = pushing_directions(T[i][:3, :3], c.finger)
        out["raycast_normal_angle_max_deg"][i] = angle_deg(c.normals, push).max()
        out["raycast_com_line_distance_m"][i] = line_distance(com, c.points[left].mean(0), c.points[right].mean(0))[0]
    return out


def depth_features(mesh: trimesh.Trimesh, T: np.ndarray, spec: GripperSpec) -> dict[str, np.ndarray]:
    """Grasp depth from the object's surface point nearest each TCP.

    Parameters
    ----------
    T : (n, 4, 4) float
        TCP poses, object frame.

    Returns
    -------
    dict of (n,) float arrays
        ``grasp_depth_m`` (fingertip TCP z minus the nearest surface point's TCP z), ``tcp_surface_distance_m``,
        ``extent_along_closing_m`` (the whole object's extent along TCP x).
    """
    nearest, distance, _ = trimesh.proximity.closest_point(mesh, T[:, :3, 3])
    z = np.einsum("nij,ni->nj", T[:, :3, :3], nearest - T[:, :3, 3])[:, 2]
    along_x = np.asarray(mesh.vertices) @ T[:, :3, 0].T  # (v, n)
    return {"grasp_depth_m": spec.pad_size[2] / 2.0 - z, "tcp_surface_distance_m": np.asarray(distance),
            "extent_along_closing_m": along_x.max(0) - along_x.min(0)}


def contact_features(T: np.ndarray, rep: Replay, mesh: trimesh.Trimesh, com: np.ndarray, inertia: np.ndarray,
                     mass: float, spec: GripperSpec, torsional: float) -> dict[str, float]:
    """Features of one successful grasp's contacts at the end of our closing.

    Parameters
    ----------
    T : (4, 4) float
        TCP pose in the world (the object starts at the world origin in free space, so also its initial frame).
    rep : Replay
        The rollout (contacts in the world; the object's pose at the end of closing).
    mesh : trimesh.Trimesh
        The prepared object, object frame.
    com : (3,) float
        Centre of mass, object frame.
    inertia : (3, 3) float
        kg m^2 about the centre of mass, object axes.
    torsional : float
        m, the pads' torsional friction coefficient.

    Returns
    -------
    dict of float (see the module docstring); empty when a finger has no contact.
    """
    r = rep.result
    fingers = np.asarray(r.contact_fingers)
    if not (np.any(fingers == LEFT) and np.any(fingers == RIGHT)):
        return {}
    points, normals, forces = np.asarray(r.contact_points), np.asarray(r.contact_normals), np.asarray(r.contact_forces)
    P = np.asarray(r.target_pose_closed)
    local = to_tcp(T, points)
    per = {}
    for f in (LEFT, RIGHT):
        sel = fingers == f
        centroid = local[sel].mean(0)
        per[f] = {"n": int(sel.sum()), "z": centroid[2], "y": abs(centroid[1]), "force": float(forces[sel].sum()),
                  "spread": float(np.linalg.norm(local[sel] - centroid, axis=1).max()),
                  "world": points[sel].mean(0)}
    push = pushing_directions(T[:3, :3], fingers)
    # surface normals at the contacts, object frame at the end of closing
    in_object = to_tcp(P, points)
    _, _, tri = trimesh.proximity.closest_point(mesh, in_object)
    outward = mesh.face_normals[tri]
    push_object = push @ P[:3, :3]  # world directions into the object's frame
    com_world = P[:3, :3] @ com + P[:3, 3]
    d, u, perp = line_distance(com_world, per[LEFT]["world"], per[RIGHT]["world"])
    weight = mass * G * T[:3, 2]  # gravity along the approach axis (AcronymParams.gravity = "approach")
    torque = abs(float(np.cross(perp, weight) @ u))
    I_world = P[:3, :3] @ inertia @ P[:3, :3].T
    total_force = float(forces.sum())
    return {
        "contacts_min_per_finger": min(per[LEFT]["n"], per[RIGHT]["n"]),
        "contacts_max_per_finger": max(per[LEFT]["n"], per[RIGHT]["n"]),
        "link_contacts": int(np.sum(local[:, 2] < -spec.pad_size[2] / 2.0 - LINK_MARGIN)),
        "pad_offset_along_max_m": max(per[LEFT]["z"], per[RIGHT]["z"]),
        "pad_offset_along_abs_max_m": max(abs(per[LEFT]["z"]), abs(per[RIGHT]["z"])),
        "pad_offset_across_abs_max_m": max(per[LEFT]["y"], per[RIGHT]["y"]),
        "contact_spread_min_m": min(per[LEFT]["spread"], per[RIGHT]["spread"]),
        "normal_angle_max_deg": float(angle_deg(normals, push).max()),
        "surface_normal_angle_max_deg": float(angle_deg(-outward, push_object).max()),
        "grip_force_min_finger_N": min(per[LEFT]["force"], per[RIGHT]["force"]),
        "com_line_distance_m": d,
        "com_line_distance_x_mass_kgm": d * mass,
        "gravity_torque_about_axis_Nm": torque,
        "gravity_torque_over_torsional": torque / max(torsional * total_force, 1e-12),
        "inertia_about_axis_kgm2": float(u @ I_world @ u) + mass * d * d,
    }


# ---------------------------------------------------------------------------------------------------------------
# Features of one object
# ---------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass
class ObjectFeatures:
    """Everything measured on one calibration object."""

    name: str
    codes: np.ndarray
    """(n,) int, our outcome per grasp."""
    flex: np.ndarray
    """(n,) bool, FleX held."""
    features: dict[str, np.ndarray]
    """name -> (n,) float (NaN where not defined)."""
    parts: np.ndarray
    """(n,) str, the open hand's overlapping part for our outcome 1 ('' otherwise)."""
    mismatches: int
    """Replayed grasps whose outcome differs from the table's."""
    seconds: float


def table_features(table) -> dict[str, np.ndarray]:
    """Our own measures from the evaluate table, ``(n,)`` float each."""
    col = lambda k: np.asarray(table.column(k).to_numpy(zero_copy_only=False), dtype=float)  # noqa: E731
    return {
        "ours_motion_closing_linear_m": col("motion_closing_linear"),
        "ours_motion_closing_angular_rad": col("motion_closing_angular"),
        "ours_motion_shaking_linear_m": col("motion_shaking_linear"),
        "ours_motion_shaking_angular_rad": col("motion_shaking_angular"),
        "ours_slip_m": col("rel_translation"),
        "ours_slip_rad": col("rel_rotation"),
        "closed_width_m": col("closed_width"),
    }


def flex_features(case: Case) -> dict[str, np.ndarray]:
    """FleX's motion measures from the ACRONYM file, ``(n,)`` float each (NaN when the file lacks one)."""
    n = len(case.flex)
    out = {}
    for phase in ("closing", "shaking"):
        for kind, unit in (("linear", "m"), ("angular", "rad")):
            values = case.flex_motion.get(f"object_motion_during_{phase}_{kind}")
            out[f"flex_motion_{phase}_{kind}_{unit}"] = np.full(n, np.nan) if values is None else np.asarray(
                values, dtype=float)
    return out


def object_features(case: Case, lift: LiftParams, args) -> ObjectFeatures:
    """Label ``case``'s grasps (``fidelity.evaluate``), replay our successes and collisions, and measure them."""
    t0 = time.perf_counter()
    table = fidelity.evaluate(case, lift, args)
    codes = table.column("outcome").to_numpy().astype(int)
    n = len(codes)
    spec = load_gripper(args.gripper)
    ew = evaluation_world(case.mesh, case.scale, case.T, None, args.gripper, evaluate_params(case, lift),
                          cache_dir=args.cache_dir)
    mesh, com = ew.geometry.mesh, np.asarray(ew.geometry.center_of_mass)
    mass, inertia = float(ew.world.obj.mass), np.asarray(ew.world.obj.inertia)
    torsional = lift.acronym.torsional_friction if lift.acronym.torsional_friction is not None else \
        spec.pad_friction[1]

    features = {**table_features(table), **flex_features(case)}
    features.update(raycast_features(mesh, ew.T_tcp, spec, com))
    features.update(depth_features(mesh, ew.T_tcp, spec))
    features["object_mass_kg"] = np.full(n, mass)
    features["object_extent_m"] = np.full(n, float(np.max(mesh.extents)))

    replays = replay(ew, np.flatnonzero(np.isin(codes, (SUCCESS, COLLISION))), args.jobs)
    mismatches = sum(int(rep.result.code != codes[i]) for i, rep in replays.items())
    parts = np.full(n, "", dtype=object)
    penetration = np.full(n, np.nan)
    rows: dict[int, dict[str, float]] = {}
    for i, rep in replays.items():
        if rep.result.code == SUCCESS and codes[i] == SUCCESS:
            rows[i] = contact_features(ew.T_world[i], rep, mesh, com, inertia, mass, spec, torsional)
        elif codes[i] == COLLISION:
            penetration[i], parts[i] = rep.penetration, rep.part
    for key in sorted({k for row in rows.values() for k in row}):
        features[key] = np.array([rows.get(i, {}).get(key, np.nan) for i in range(n)], dtype=float)
    features["open_hand_penetration_m"] = penetration
    return ObjectFeatures(case.name, codes, case.flex.astype(bool), features, parts, mismatches,
                          time.perf_counter() - t0)


# ---------------------------------------------------------------------------------------------------------------
# Statistics
# ---------------------------------------------------------------------------------------------------------------


def median(x: np.ndarray) -> float:
    """Median of the finite values of ``x`` ``(k,)``; NaN when none."""
    x = x[np.isfinite(x)]
    return float(np.median(x)) if len(x) else math.nan


def separation(x: np.ndarray, held: np.ndarray) -> dict:
    """AUC of ``x`` ``(k,)`` for FleX-held (``held`` ``(k,)`` bool) against FleX-lost, over its finite values, with
    the group sizes and medians."""
    ok = np.isfinite(x)
    x, held = x[ok], held[ok]
    return {"auc": fidelity.auc(x, held), "n_held": int(held.sum()), "n_lost": int((~held).sum()),
            "median_held": median(x[held]), "median_lost": median(x[~held])}


def within_auc(per_object: list[dict]) -> float:
    """AUC over held/lost pairs of the same object only: per-object AUCs weighted by n_held * n_lost."""
    w = np.array([r["n_held"] * r["n_lost"] if math.isfinite(r["auc"]) else 0 for r in per_object], dtype=float)
    if w.sum() == 0:
        return math.nan
    return float(sum(wi * r["auc"] for wi, r in zip(w, per_object) if wi) / w.sum())


def compare(objects: list[ObjectFeatures], code: int, min_n: int = 1) -> dict:
    """Per feature, among the grasps with our outcome ``code``: per-object and pooled separation of FleX-held from
    FleX-lost, and the within-object AUC; objects with fewer than ``min_n`` such grasps are left out per object."""
    names = [k for k in objects[0].features]
    out = {}
    for name in names:
        per = {}
        for o in objects:
            sel = o.codes == code
            if sel.sum() >= min_n:
                per[o.name] = separation(o.features[name][sel], o.flex[sel])
        x = np.concatenate([o.features[name][o.codes == code] for o in objects])
        held = np.concatenate([o.flex[o.codes == code] for o in objects])
        if not np.isfinite(x).any():
            continue
        out[name] = {"pooled": separation(x, held), "within": within_auc(list(per.values())), "objects": per}
    return out


def ranked(result: dict, ours_only: bool = False) -> list[str]:
    """Feature names by decreasing ``|AUC within - 0.5|`` (NaN last); ``ours_only`` leaves FleX's own out."""
    def key(name: str) -> float:
        w = result[name]["within"]
        return -abs(w - 0.5) if math.isfinite(w) else 1.0
    return sorted((k for k in result if not (ours_only and k.startswith("flex_"))), key=key)


# ---------------------------------------------------------------------------------------------------------------
# Report
# ---------------------------------------------------------------------------------------------------------------


def num(x, digits: int = 3) -> str:
    """``x`` with ``digits`` significant digits, '-' for None/NaN."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{x:.{digits}g}"


def print_pooled(title: str, result: dict) -> None:
    print(f"\n### {title}: pooled, features by |AUC within objects - 0.5|\n")
    print("| feature | AUC pooled | AUC within | n held / lost | median held | median lost |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for name in ranked(result):
        p = result[name]["pooled"]
        print(f"| {name} | {num(p['auc'], 2)} | {num(result[name]['within'], 2)} | {p['n_held']} / {p['n_lost']} | "
              f"{num(p['median_held'])} | {num(p['median_lost'])} |")


def print_per_object(title: str, result: dict, objects: list[str]) -> None:
    print(f"\n### {title}: AUC per object (same order)\n")
    print("| feature | " + " | ".join(objects) + " |")
    print("| --- |" + " ---: |" * len(objects))
    for name in ranked(result):
        per = result[name]["objects"]
        print(f"| {name} | " + " | ".join(num(per[o]["auc"], 2) if o in per else "-" for o in objects) + " |")
    print(f"\n### {title}: top {TOP} features per object, FleX's own left out (AUC; median held / lost; n held / "
          "lost)\n")
    top = ranked(result, ours_only=True)[:TOP]
    print("| object | " + " | ".join(top) + " |")
    print("| --- |" + " --- |" * len(top))
    for o in objects:
        cells = []
        for name in top:
            r = result[name]["objects"].get(o)
            cells.append("-" if r is None else f"{num(r['auc'], 2)}; {num(r['median_held'])} / "
                                               f"{num(r['median_lost'])}; {r['n_held']}/{r['n_lost']}")
        print(f"| {o} | " + " | ".join(cells) + " |")


def collision_parts(objects: list[ObjectFeatures]) -> dict:
    """``{part: [FleX held, FleX lost]}`` over our outcome-1 grasps, by the open hand's overlapping part."""
    out = {}
    for o in objects:
        sel = o.codes == COLLISION
        for part, held in zip(o.parts[sel], o.flex[sel]):
            out.setdefault(part or "none found", [0, 0])[0 if held else 1] += 1
    return out


def counts(objects: list[ObjectFeatures]) -> list[dict]:
    return [{"object": o.name, "n": int(len(o.codes)),
             "our_success": {"held": int(np.sum((o.codes == SUCCESS) & o.flex)),
                             "lost": int(np.sum((o.codes == SUCCESS) & ~o.flex))},
             "our_collision": {"held": int(np.sum((o.codes == COLLISION) & o.flex)),
                               "lost": int(np.sum((o.codes == COLLISION) & ~o.flex))},
             "replay_mismatches": o.mismatches, "seconds": o.seconds} for o in objects]


def plain(value):
    """``value`` with NaN/inf as None and numpy scalars as Python numbers (strict JSON)."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("-j", "--jobs", type=int, default=1, help="worker processes (default 1)")
    ap.add_argument("--limit", type=int, default=None, help="evenly spaced grasps per object (default: all)")
    ap.add_argument("--objects", default="", help="comma-separated words: only objects whose name contains one")
    ap.add_argument("--gripper", default="panda")
    add_calibration_option(ap)
    ap.add_argument("--cache-dir", type=Path, default=REPO / ".cache", help="CoACD cache")
    ap.add_argument("--per-grasp", action="store_true", help="also write every grasp's outcome, FleX label and "
                    "features to the JSON (for further analysis)")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    cases = load_cases(args.calibration, args.limit)
    words = [w for w in args.objects.split(",") if w]
    cases = [c for c in cases if not words or any(w in c.name for w in words)]
    lift = LiftParams(protocol="acronym")
    objects = []
    for case in cases:
        objects.append(object_features(case, lift, args))
        o = objects[-1]
        print(f"  {o.name}: {len(o.codes)} grasps in {o.seconds:.1f} s (replay mismatches {o.mismatches})",
              file=sys.stderr)
    names = [o.name for o in objects]
    summary = counts(objects)
    print("\n### grasps (our outcome 5 / 1, by FleX label)\n")
    print("| object | n | ours 5: FleX held / lost | ours 1: FleX held / lost | replay mismatches |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for s in summary:
        print(f"| {s['object']} | {s['n']} | {s['our_success']['held']} / {s['our_success']['lost']} | "
              f"{s['our_collision']['held']} / {s['our_collision']['lost']} | {s['replay_mismatches']} |")

    success = compare(objects, SUCCESS)
    print_pooled("our successes (5), FleX held vs lost", success)
    print_per_object("our successes (5)", success, names)
    report = {"limit": args.limit, "protocol": "acronym", "acronym_params": AcronymParams().to_dict(),
              "machine": platform.platform(), "mujoco": mujoco.__version__, "objects": summary,
              "auc_positive": "FleX held", "success": success}

    n_collision = sum(int(np.sum(o.codes == COLLISION)) for o in objects)
    if n_collision >= MIN_GROUP:
        collision = compare(objects, COLLISION, min_n=MIN_GROUP)
        with_object = [n for n in names if any(n in r["objects"] for r in collision.values())]
        print_pooled(f"our collisions at placement (1, n = {n_collision}), FleX held vs lost", collision)
        print_per_object("our collisions (1)", collision, with_object)
        parts = collision_parts(objects)
        print("\nour outcome 1 by the open hand's overlapping part (deepest overlap):\n")
        print("| part | FleX held | FleX lost |\n| --- | ---: | ---: |")
        for part, (held, lost) in sorted(parts.items()):
            print(f"| {part} | {held} | {lost} |")
        report["collision"] = collision
        report["collision_parts"] = parts
    else:
        print(f"\nour collisions at placement: {n_collision} < {MIN_GROUP}, not compared")
    if args.per_grasp:
        report["grasps"] = [{"object": o.name, "outcome": o.codes.tolist(), "flex_held": o.flex.astype(int).tolist(),
                             "overlap_part": list(o.parts), "features": {k: v.tolist() for k, v in o.features.items()}}
                            for o in objects]
    report["outcome_names"] = list(OUTCOME_NAMES)
    report["seconds"] = time.perf_counter() - t0
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(plain(report), indent=1))
    print(f"\nwrote {args.out} ({report['seconds']:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
