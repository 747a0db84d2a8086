"""Stage 5, ``robustness``: how often a successful grasp still succeeds when it is placed with error.

One task per scene, the scene and gripper compiled once (:func:`graspgen.workflows.rollouts.scene_simulator`, the
rollouts stage's protocol). Every grasp with outcome 5 is rolled out again from ``num_perturbations`` perturbed
copies, the perturbation model of :mod:`graspgen.quality.perturbation` (TCP pose; optionally the object's planar
pose; its mass, centre of mass and friction); a copy with an object perturbation gets its own simulator
(:func:`graspgen.sim.perturbed_copies.with_object_pose`). Each copy's epsilon uses its contacts by the rule of
:mod:`graspgen.quality.contact_set` and its own centre of mass and friction. ``robustness`` counts successes over all
copies, ``grip_robustness`` over the copies that reached the grip (outcome 3-5), both with Wilson 95% intervals;
``pfc`` is the share of copies with epsilon > ``epsilon_delta``. Other grasps get ``n = 0`` and NaN labels (not
measured, not 0). The optional radius bisects each TCP axis on ``[0, radius_max_*]`` in both directions and keeps
the smaller; no randomness. All draws for a scene are made up front, ``(grasps, n, DRAWS_PER_COPY)`` standard
normals in grasp order, so a grasp's copies depend only on the task key and its row.

Output per scene: one Parquet table, one row per grasp of the grasps table, joined on ``(scene_id, grasp_id)``:

==================  ==============  =========================================================================
column              type            meaning
==================  ==============  =========================================================================
scene_id, grasp_id  string, int32   the grasp
n                   int32           perturbed copies rolled out (0 unless the grasp's outcome is 5)
successes           int32           copies with outcome 5
robustness          float64         successes / n, in [0, 1]; NaN when n = 0
robustness_lo/_hi   float64         Wilson score 95% interval of the success rate; NaN when n = 0
grip_robustness     float64         successes / copies with outcome 3-5 (that reached the grip); NaN when none
grip_robustness_lo  float64         Wilson score 95% interval of grip_robustness (``_lo``, ``_hi``); NaN when
/_hi                                none
pfc                 float64         fraction of copies with epsilon > ``epsilon_delta``; NaN when n = 0
copy_outcomes       list<int8>      outcome code 0-5 of each copy (its failure cause), n values
copy_epsilon        list<float64>   epsilon of each copy, n values
radius_x/_y/_z      float64         robustness radius along the TCP axes, m; NaN when off or n = 0
radius_rx/_ry/_rz   float64         robustness radius about the TCP axes, rad; NaN when off or n = 0
==================  ==============  =========================================================================
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pyarrow as pa

from graspgen.errors import SettingsError
from graspgen.geometry.contacts import closing_contacts
from graspgen.grippers import GripperSpec, load_gripper
from graspgen.io.arrow import column_array
from graspgen.io.objects import ObjectRecord
from graspgen.quality.contact_set import CONTACT_SOURCES, contact_set
from graspgen.quality.epsilon import EpsilonParams, ObjectGeometry
from graspgen.quality.perturbation import (
    DRAWS_PER_COPY,
    RobustnessParams,
    perturbed_poses,
    planar_object_noise,
    truncated_friction,
)
from graspgen.quality.resting import resting_com_offset
from graspgen.quality.statistics import wilson_interval
from graspgen.sim.lift import LiftSimulator
from graspgen.sim.perturbed_copies import (
    initial_object_pose,
    rollout_with_object_pose,
    support_points,
    target_friction,
    with_object_pose,
)
from graspgen.sim.protocols import OUTCOME_NAMES, LiftParams, Outcome, RolloutResult
from graspgen.sim.scene_model import object_body_name
from graspgen.validation import check_instance
from graspgen.workflows.metrics import check_joined, object_geometry
from graspgen.workflows.robustness_columns import LABEL_FIELDS, LABELS, RADIUS_AXES, GraspRobustness, robustness_columns

__all__ = [
    "GRIP_CODES",
    "RobustnessTaskParams",
    "SCHEMA",
    "grasp_robustness",
    "robustness_radius",
    "scene_robustness",
]

GRIP_CODES = (Outcome.NO_CONTACT_ESTABLISHED, Outcome.SLIPPED_DURING_LIFTING, Outcome.SUCCESS)
"""Outcome codes of copies that reached the grip (``grip_robustness``'s denominator): not stopped by a collision
during placement or approach (codes 0-2)."""


@dataclasses.dataclass(frozen=True)
class RobustnessTaskParams:
    """Everything a robustness task depends on (what enters its key): its own section, the rollout protocol and
    the epsilon model. Built by :meth:`RobustnessStage.params` from the config."""

    robustness: RobustnessParams = dataclasses.field(default_factory=RobustnessParams)
    """The perturbation model and the radius search (config section ``robustness``)."""
    lift: LiftParams = dataclasses.field(default_factory=LiftParams)
    """The rollout protocol of the copies (``rollouts.lift``)."""
    epsilon: EpsilonParams = dataclasses.field(default_factory=EpsilonParams)
    """The contact model of the copies' epsilon (``metrics.epsilon``)."""

    def __post_init__(self) -> None:
        check_instance("robustness", self.robustness, RobustnessParams)
        check_instance("lift", self.lift, LiftParams)
        check_instance("epsilon", self.epsilon, EpsilonParams)


def grasp_robustness(
    simulator: LiftSimulator,
    T_world_tcp: np.ndarray,
    width: float,
    target_body: str,
    geometry: ObjectGeometry,
    friction: float,
    draws: np.ndarray,
    params: RobustnessParams,
    epsilon: EpsilonParams,
    gripper: GripperSpec,
    epsilon_friction_follows: bool = True,
) -> GraspRobustness:
    """Roll out the perturbed copies of one grasp and label it: a :class:`GraspRobustness`.

    Parameters
    ----------
    simulator : LiftSimulator
        The compiled scene with the gripper (its initial configuration = the scene at rest).
    T_world_tcp : (4, 4) float
        The nominal grasp (TCP to world); ``width`` its pad separation, m.
    target_body : str
        The target's body name, ``obj/<i>_<name>``.
    geometry : ObjectGeometry
        The target's mesh, centre of mass and torque scale (epsilon of the copies).
    friction : float
        Coulomb coefficient of the epsilon's friction cones; with ``epsilon_friction_follows`` each copy's perturbed
        friction is used instead.
    draws : (n, 14) float
        Standard normals per copy (:data:`~graspgen.quality.perturbation.DRAWS_PER_COPY`); ``n`` copies are rolled out.
    gripper : GripperSpec
        Its pads give the ray-cast contacts.
    """
    draws = np.asarray(draws, dtype=np.float64)
    if draws.ndim != 2 or draws.shape[1] != DRAWS_PER_COPY or len(draws) == 0:
        raise SettingsError(f"draws: expected shape (n >= 1, {DRAWS_PER_COPY}), got {draws.shape}")
    poses = perturbed_poses(T_world_tcp, params.translation_sigma * draws[:, 0:3],
                            params.rotation_sigma * draws[:, 3:6])
    outcomes, results, coms, mus = _roll_out_copies(simulator, poses, width, target_body, geometry, friction, draws,
                                                    params, epsilon_friction_follows)
    epsilons, sources = _copy_epsilons(results, poses, geometry, coms, mus, params, epsilon, gripper)
    radius = np.full(len(RADIUS_AXES), np.nan)
    if params.radius:
        radius = robustness_radius(simulator, T_world_tcp, width, target_body, params)
    return _labels(outcomes, epsilons, sources, radius, params)


def _roll_out_copies(
    simulator: LiftSimulator, poses: np.ndarray, width: float, target_body: str, geometry: ObjectGeometry,
    friction: float, draws: np.ndarray, params: RobustnessParams, epsilon_friction_follows: bool,
) -> tuple[np.ndarray, list[tuple[RolloutResult, np.ndarray | None, np.ndarray]], np.ndarray, np.ndarray]:
    """Roll out the copies at ``poses (n, 4, 4)``: their outcome codes ``(n,) int8``, ``(result, target pose at the
    end of closing or None, target pose at placement)`` each, and the centre of mass ``(n, 3)`` and friction
    ``(n,)`` their epsilon uses."""
    T_obj0 = initial_object_pose(simulator, target_body) if params.object_noise or params.com_sigma > 0 else None
    support = support_points(simulator, target_body) if params.com_sigma > 0 else np.zeros((0, 3))
    physics = params.mass_sigma > 0 or params.com_sigma > 0 or params.friction_sigma > 0
    mu_sim = target_friction(simulator, target_body)
    n = len(draws)
    outcomes = np.zeros(n, dtype=np.int8)
    results: list[tuple[RolloutResult, np.ndarray | None, np.ndarray]] = []
    coms = np.tile(np.asarray(geometry.center_of_mass, dtype=np.float64), (n, 1))
    mus = np.full(n, float(friction))
    for j in range(n):
        sim = simulator
        if params.object_noise or physics:
            sim, offset, mu = _perturbed_simulator(simulator, target_body, geometry, draws[j], params, T_obj0,
                                                   support, mu_sim)
            coms[j] += offset
            if epsilon_friction_follows:
                mus[j] = mu
        result, T_placed, T_closed = rollout_with_object_pose(sim, poses[j], width, target_body)
        outcomes[j] = result.code
        results.append((result, T_closed, T_placed))
    return outcomes, results, coms, mus


def _perturbed_simulator(
    simulator: LiftSimulator, target_body: str, geometry: ObjectGeometry, row: np.ndarray, params: RobustnessParams,
    T_obj0: np.ndarray | None, support: np.ndarray, mu_sim: float,
) -> tuple[LiftSimulator, np.ndarray, float]:
    """The simulator of one copy with an object perturbation (its draws ``row (14,)``), the copy's centre-of-mass
    offset ``(3,)`` m (mesh frame) and its target friction."""
    T_obj = None
    if params.object_noise:
        dx, dy, yaw = row[6:9] * (params.object_translation_sigma, params.object_translation_sigma,
                                  params.object_rotation_sigma)
        T_obj = planar_object_noise(T_obj0, geometry.center_of_mass, dx, dy, yaw)
    mass_scale = math.exp(params.mass_sigma * row[9])
    offset = resting_com_offset(params.com_sigma * row[10:13], support, T_obj0 if T_obj is None else T_obj,
                                geometry.center_of_mass)
    mu = truncated_friction(mu_sim, params.friction_sigma, row[13])
    return with_object_pose(simulator, target_body, T_obj, mass_scale, offset, mu), offset, mu


def _copy_epsilons(
    results: list[tuple[RolloutResult, np.ndarray | None, np.ndarray]], poses: np.ndarray, geometry: ObjectGeometry,
    coms: np.ndarray, mus: np.ndarray, params: RobustnessParams, epsilon: EpsilonParams, gripper: GripperSpec,
) -> tuple[np.ndarray, list[str]]:
    """The epsilon ``(n,)`` of every copy and where its contacts came from (``rollout``, ``raycast``, ``none``)."""
    # Ray casts only where the copy's own contacts do not touch both pads, at the copy's pose relative to the object
    # as placed; batched: one call per grasp.
    need = [j for j, (r, _, _) in enumerate(results) if not np.isin((0, 1), r.contact_fingers).all()]
    rays = {}
    if need:
        rel = np.stack([np.linalg.inv(results[j][2]) @ poses[j] for j in need])
        found = closing_contacts(geometry.mesh, rel, gripper, rays_per_side=epsilon.rays_per_side,
                                 tolerance=epsilon.ray_tolerance)
        rays = dict(zip(need, found))
    epsilons = np.zeros(len(results))
    sources = []
    for j, (r, T_closed, _) in enumerate(results):
        rollout = (r.contact_points, r.contact_normals, r.contact_fingers)
        source, p, nrm, f = contact_set(rollout, T_closed if T_closed is not None else np.eye(4), rays.get(j))
        sources.append(source)
        if source != "none":
            g = geometry if not params.com_sigma else dataclasses.replace(geometry, center_of_mass=coms[j])
            epsilons[j] = epsilon.epsilon(p, nrm, f, g, float(mus[j]))
    return epsilons, sources


def _labels(outcomes: np.ndarray, epsilons: np.ndarray, sources: list[str], radius: np.ndarray,
            params: RobustnessParams) -> GraspRobustness:
    """The labels of a grasp from its copies' outcome codes ``(n,)``, epsilons ``(n,)`` and contact sources."""
    n = len(outcomes)
    successes = int((outcomes == Outcome.SUCCESS).sum())
    grip_n = int(np.isin(outcomes, GRIP_CODES).sum())
    return GraspRobustness(
        n=n, successes=successes, robustness=successes / n, interval=wilson_interval(successes, n),
        grip_n=grip_n, grip_robustness=successes / grip_n if grip_n else math.nan,
        grip_interval=wilson_interval(successes, grip_n),
        pfc=float(np.mean(epsilons > params.epsilon_delta)), outcomes=outcomes, epsilons=epsilons,
        sources=tuple(sources), radius=radius,
    )


def robustness_radius(
    simulator: LiftSimulator, T_world_tcp: np.ndarray, width: float, target_body: str, params: RobustnessParams
) -> np.ndarray:
    """Robustness radius (6,) of a successful grasp along and about each TCP axis
    (:data:`~graspgen.workflows.robustness_columns.RADIUS_AXES`), m and rad: per direction the maximum when a copy
    offset by it succeeds, else ``radius_iterations`` halvings of ``[0, maximum]``; per axis the smaller direction."""
    out = np.zeros(len(RADIUS_AXES))
    for axis in range(len(RADIUS_AXES)):
        top = params.radius_max_translation if axis < 3 else params.radius_max_rotation
        edges = []
        for sign in (1.0, -1.0):
            if _offset_succeeds(simulator, T_world_tcp, width, target_body, axis, sign * top):
                edges.append(top)
                continue
            lo, hi = 0.0, top
            for _ in range(params.radius_iterations):
                mid = 0.5 * (lo + hi)
                ok = _offset_succeeds(simulator, T_world_tcp, width, target_body, axis, sign * mid)
                lo, hi = (mid, hi) if ok else (lo, mid)
            edges.append(lo)
        out[axis] = min(edges)
    return out


def _offset_succeeds(simulator: LiftSimulator, T_world_tcp: np.ndarray, width: float, target_body: str, axis: int,
                     amount: float) -> bool:
    """Whether the grasp offset by ``amount`` along/about TCP axis ``axis`` (0-2 m, 3-5 rad) succeeds."""
    offset = np.zeros(6)
    offset[axis] = amount
    (T,) = perturbed_poses(T_world_tcp, offset[None, :3], offset[None, 3:])
    return simulator.rollout(T, width, target_body).code == Outcome.SUCCESS


SCHEMA = pa.schema([("scene_id", pa.string()), ("grasp_id", pa.int32()), *LABEL_FIELDS])
"""The robustness table's schema (see the module docstring)."""


def scene_robustness(
    grasps: pa.Table,
    rollouts: pa.Table,
    simulator: LiftSimulator,
    object_names: list[str],
    friction: np.ndarray,
    records: dict[str, ObjectRecord],
    params: RobustnessTaskParams,
    rng: np.random.Generator,
) -> tuple[pa.Table, dict[str, Any]]:
    """The robustness table of one scene (module docstring) and its metadata (copies rolled out, their outcomes), from
    the scene's ``grasps`` and ``rollouts`` (row for row), its compiled ``simulator``, ``object_names`` by scene index
    with their ``friction``, the object ``records`` by name, and the task's ``rng`` (every draw made up front)."""
    check_joined(grasps, rollouts, "rollouts")
    p = params.robustness
    draws = rng.standard_normal((len(grasps), p.num_perturbations, DRAWS_PER_COPY))
    rows = _scene_rows(grasps, rollouts, simulator, object_names, friction, records, params, draws)
    arrays = {"scene_id": grasps.column("scene_id"), "grasp_id": grasps.column("grasp_id")}
    arrays.update(zip(LABELS, robustness_columns(rows)))
    return pa.table(arrays, schema=SCHEMA), _scene_meta(rows)


def _scene_rows(
    grasps: pa.Table, rollouts: pa.Table, simulator: LiftSimulator, object_names: list[str], friction: np.ndarray,
    records: dict[str, ObjectRecord], params: RobustnessTaskParams, draws: np.ndarray,
) -> list[GraspRobustness | None]:
    """The labels of every grasp of the scene (None for a grasp whose rollout did not succeed), its copies' draws
    ``(grasps, num_perturbations, DRAWS_PER_COPY)``."""
    p, ep = params.robustness, params.epsilon
    outcome = rollouts.column("outcome").to_numpy()
    poses = column_array(grasps, "pose_world", (4, 4))
    widths = grasps.column("width").to_numpy()
    index = grasps.column("object_index").to_numpy()
    gripper = load_gripper(grasps.column("gripper")[0].as_py()) if len(grasps) else None
    geometries: dict[str, ObjectGeometry] = {}
    rows: list[GraspRobustness | None] = []
    for i in range(len(grasps)):
        if outcome[i] != Outcome.SUCCESS:
            rows.append(None)
            continue
        k = int(index[i])
        name = object_names[k]
        if name not in geometries:
            geometries[name] = object_geometry(records[name])
        mu = float(friction[k]) if ep.friction is None else ep.friction
        rows.append(grasp_robustness(simulator, poses[i], float(widths[i]), object_body_name(k, name),
                                     geometries[name], mu, draws[i], p, ep, gripper,
                                     epsilon_friction_follows=ep.friction is None))
    return rows


def _scene_meta(rows: list[GraspRobustness | None]) -> dict[str, Any]:
    """The shard metadata of a scene's labels: grasps, grasps evaluated, copies and their outcomes and contacts."""
    done = [r for r in rows if r is not None]
    copy_outcomes = np.concatenate([r.outcomes for r in done]) if done else np.zeros(0, np.int8)
    sources = [s for r in done for s in r.sources]
    return {
        "grasps": len(rows),
        "evaluated": len(done),
        "copies": int(len(copy_outcomes)),
        "copy_successes": int((copy_outcomes == Outcome.SUCCESS).sum()),
        "copy_outcomes": {name: int((copy_outcomes == code).sum()) for code, name in enumerate(OUTCOME_NAMES)},
        "copy_grip_reached": int(np.isin(copy_outcomes, GRIP_CODES).sum()),
        "copy_contacts": {s: sources.count(s) for s in CONTACT_SOURCES},
    }
