"""Object-centric grasp sets, ACRONYM / GraspGen style: one object alone in free space, grasps from every side.

:func:`label_object_grasps` takes one prepared object (an :class:`graspgen.io.objects.ObjectRecord`, mesh frame = the
object frame), rolls out grasp candidates on it in free space and keeps some of them, by ``selection``:

* ``natural`` (default): antipodal candidates only, each kept whatever its outcome, until ``target_grasps`` that
  do not collide at placement are kept or ``max_candidates`` were tried; a collision at placement (outcomes 0-2:
  the open hand intersects the object) is kept as a negative while the kept collisions stay within
  ``collision_share_of_negatives`` (a share of the kept negatives), and counted and dropped otherwise. The set is
  the sampler's contact-making distribution, labelled: ACRONYM's convention, and what a grasp evaluator meets when
  it scores a planner's candidates. Its positive rate (``meta["positive_rate"]``) is the natural one; a balanced
  view is the trainer's business (the probe draws balanced batches). Why:
  docs/decisions/2026-12-07-natural-object-sets.md.
* ``balanced``: until ``target_positives`` positives and ``target_negatives`` failures are kept, as below.

The ``balanced`` loop (steps 1-2 below describe it; ``natural`` uses step 1 without near misses and step 2's
rollouts):

1. **Candidates**, in batches of ``batch_size``. ``round(near_miss_fraction * batch_size)`` of each batch are near
   misses, the rest antipodal candidates; once ``target_positives`` successes are kept, only failures can still be
   kept and ``near_miss_fraction_when_positives_met`` (0.8) of each batch are near misses, where the failures are.

   - ``antipodal``: :func:`graspgen.geometry.antipodal.sample_antipodal` on the record's mesh in its own frame with
     the approach filter off (``approach="any"``): approach axes over the whole sphere, from below as much as from
     above (free space has no "down"). Each call of the sampler gives a few thousand candidates (contact pairs x
     orientations x depths); they are shuffled into a pool and each batch takes the next ones, so a batch mixes
     many contact pairs.
   - ``near_miss``: a copy of an antipodal candidate that succeeded earlier in the loop (its *parent*, drawn
     uniformly from all of them; until the first success, from the batch's own antipodal candidates) moved just far
     enough that the grasp the sampler meant is no longer there (:func:`~graspgen.workflows.near_misses.
     near_miss_offsets`). Half of them (by a coin flip) are **shifted**: the hand moves in the plane of its pads
     (TCP y-z) in a uniformly random direction, by the distance at which the parent's contact point leaves the pad
     face plus ``near_miss_overhang`` (default half the pad face's width, ``pad_size[1] / 2``). The other half are
     **tilted**: the hand turns about the TCP by ``near_miss_tilt`` about a uniformly random axis perpendicular to
     the approach (TCP x-y plane; default ``atan(max_width / (2 finger_length))``, the smallest tilt that swings an
     open finger's base past the grasp's centre line). Their width is the parent's. Why successful parents and these
     sizes, and how many of the near misses fail: docs/decisions/2026-12-07-near-miss-offsets.md.

2. **Rollouts** in free space (:func:`free_space_simulator`: the object alone, :func:`graspgen.sim.scene_model.
   free_space_spec`, the gripper attached; compiled once) with a free-space protocol of :mod:`graspgen.sim.protocols`:
   ``acronym`` (default; the hand placed open at the grasp, close, shake) or ``graspdatagen`` (close, five tugs at the
   object's weight). Both open the jaws to the protocol's ``open_width`` (fully by default), whatever the grasp's
   width (the ``open_width`` column). Candidates are rolled out one by one in trial order; a success is kept while
   fewer than ``target_positives`` successes are kept, a failure while fewer than ``target_negatives`` failures
   are (a collision at placement, outcomes 0-2, only while collisions are fewer than
   ``collision_share_of_negatives`` of ``target_negatives``), and the loop stops when both targets are met or
   ``max_candidates`` rollouts were made. "Success" is the ``label`` setting's: ``firm`` (default: outcome 5 with
   the object's motion in the hand within the firm-hold tolerances, :mod:`graspgen.sim.lift`; held-but-not-firm
   grasps are then negatives) or ``held`` (outcome 5: the object still between the fingers, ACRONYM's label). Both
   labels are in every row (``success``, ``firm``).

3. **Labels per kept row**: the rollout's outcome, ACRONYM's four motion measures, the finger contacts at the end of
   closing in the object frame (mapped with the object's pose when closing ended, so exactly), the Ferrari-Canny
   epsilon of those contacts (:class:`graspgen.quality.epsilon.EpsilonParams`; successes only) and, with
   ``num_perturbations > 0``, the success rate of that many copies of each kept success with the gripper pose
   perturbed at the grasp (``T @ [R(w) | t]``, ``t ~ N(0, perturbation_translation^2 I)``, ``w ~ N(0,
   perturbation_rotation^2 I)``, TCP frame; :func:`graspgen.quality.perturbation.perturbed_poses`).

Randomness: everything comes from the generator passed in, in a fixed order: per batch, sampler refills as needed
(each shuffled), the near misses' parents and offsets, the batch's order (the parents' pool depends on earlier
rollouts, which are deterministic); after the loop, the robustness noise
(``(positives, num_perturbations, 6)`` standard normals). Rollouts are deterministic (:mod:`graspgen.sim.lift`), so
the same record, settings and seed give the same table, byte for byte.

Output: one row per kept grasp, in trial order (:data:`SCHEMA`; the rollout columns are those of
:mod:`graspgen.workflows.rollout_columns`, the robustness ones built by
:func:`graspgen.workflows.robustness_columns.robustness_columns`):

======================  ==============  =====================================================================
column                  type            meaning
======================  ==============  =====================================================================
object_name             string          the object (the record's name)
grasp_id                int32           0..n-1 in trial order
candidate               string          ``antipodal`` or ``near_miss``
gripper                 string          gripper name or file (``object_grasps.gripper``)
protocol                string          ``acronym`` or ``graspdatagen``
pose_object             float64[16]     TCP pose in the record's mesh frame, 4x4 row-major (z approach, x closing)
width                   float64         pad separation at the sampled contacts, m (a near miss: its parent's)
open_width              float64         jaw opening the protocol used, m
outcome                 int8            0-5 (:class:`graspgen.sim.protocols.Outcome`)
outcome_name            string          its name
decided_in              string          protocol phase that decided it
success                 bool            ``outcome == 5``: still in the hand (ACRONYM's ``object_in_gripper``)
firm                    bool            firm hold: a success whose motion in the hand stayed within
                                        ``lift.firm_translation`` / ``firm_rotation`` (:mod:`graspgen.sim.lift`)
max_rel_translation     float64         largest displacement of the object in the hand (TCP frame) during the
                                        shake / tugs, from the end of closing, m (NaN if none ran)
max_rel_rotation        float64         largest rotation of the object in the hand over the same span, rad
closed_width            float64         pad separation when closing ended, m (NaN if not reached)
motion_closing_linear   float64         object displacement while the fingers closed, m
motion_closing_angular  float64         object rotation while the fingers closed, rad
motion_shaking_linear   float64         object displacement during the shake / tugs, m (NaN if none ran)
motion_shaking_angular  float64         object rotation during the shake / tugs, rad
contact_points          list<float64>   finger-object contacts at the end of closing, object frame, k*3 values
contact_normals         list<float64>   their normals, into the object, object frame, k*3 values
contact_forces          list<float64>   their normal forces, N, k values
contact_fingers         list<int8>      0 left pad/finger, 1 right, k values
epsilon                 float64         Ferrari-Canny epsilon of those contacts (unit-free); NaN unless a
                                        success with contacts
robustness_n            int32           perturbed copies rolled out (0 unless a success and
                                        ``num_perturbations > 0``)
robustness              float64         their success fraction (positives by ``label``); NaN when
                                        ``robustness_n`` is 0
======================  ==============  =====================================================================
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

import numpy as np
import pyarrow as pa
import trimesh

from graspgen.grippers import GripperSpec, load_gripper
from graspgen.io.arrow import fixed_list
from graspgen.io.objects import ObjectRecord
from graspgen.quality.perturbation import perturbed_poses
from graspgen.sim.gripper_model import attach_gripper
from graspgen.sim.lift import LiftSimulator
from graspgen.sim.protocols import OUTCOME_NAMES, LiftParams, Outcome, RolloutResult
from graspgen.sim.scene_model import free_space_spec, object_body_name, placed_object
from graspgen.sim.simulator import Simulator, make_simulator
from graspgen.sim.warp_backend import WarpParams
from graspgen.validation import check_instance, check_number, check_rng
from graspgen.workflows.candidate_pool import CandidatePool, collision_cap
from graspgen.workflows.metrics import object_geometry
from graspgen.workflows.near_misses import near_miss_draws, near_miss_offsets
from graspgen.workflows.object_grasps_settings import ObjectGraspsParams, protocol_opening
from graspgen.workflows.robustness_columns import robustness_columns
from graspgen.workflows.rollout_columns import object_frame_contacts, rollout_fields, rollout_table

__all__ = ["CANDIDATES", "SCHEMA", "free_space_simulator", "label_object_grasps"]

CANDIDATES: tuple[str, ...] = ("antipodal", "near_miss")
"""Values of the ``candidate`` column."""

SCHEMA = pa.schema(
    [
        ("object_name", pa.string()),
        ("grasp_id", pa.int32()),
        ("candidate", pa.string()),
        ("gripper", pa.string()),
        ("protocol", pa.string()),
        ("pose_object", pa.list_(pa.float64(), 16)),
        ("width", pa.float64()),
        ("open_width", pa.float64()),
        *rollout_fields("outcome", "outcome_name", "decided_in", "success", "firm", "max_rel_translation",
                        "max_rel_rotation", "closed_width", "motion_closing_linear", "motion_closing_angular",
                        "motion_shaking_linear", "motion_shaking_angular", "contact_points", "contact_normals",
                        "contact_forces", "contact_fingers"),
        ("epsilon", pa.float64()),
        ("robustness_n", pa.int32()),
        ("robustness", pa.float64()),
    ]
)
"""The object grasp table's schema (see the module docstring)."""

Kept = tuple[str, np.ndarray, float, RolloutResult]
"""A kept row: the candidate's kind, its TCP pose ``(4, 4)`` and width (m) in the object frame, its rollout."""


# ---------------------------------------------------------------------------------------------------------------
# The world
# ---------------------------------------------------------------------------------------------------------------


def free_space_simulator(record: ObjectRecord, gripper: str, lift: LiftParams, friction: float,
                         backend: str = "mujoco", warp: WarpParams | None = None) -> tuple[Simulator, str]:
    """The object alone in free space at the identity pose (world = mesh frame) with ``gripper`` attached,
    compiled: ``(simulator, target body name)``. Gravity is the scene's (0, 0, -9.81); the free-space protocols
    switch it off and on themselves.

    Parameters
    ----------
    record : ObjectRecord
        Convex parts, mass, centre of mass and inertia of the object (its mesh frame).
    gripper : str
        A bundled gripper name or a gripper file (:func:`graspgen.grippers.load_gripper`).
    lift : LiftParams
        The protocol and physics.
    friction : float
        The object's sliding friction coefficient (it governs the gripper contacts).
    backend : str
        The simulator's backend (:func:`graspgen.sim.simulator.make_simulator`).
    warp : WarpParams, optional
        The warp backend's settings.
    """
    obj = placed_object(record, np.eye(4), friction, visual=False)
    spec = free_space_spec(obj, lift.physics_options((0.0, 0.0, -9.81)))
    attach_gripper(spec, load_gripper(gripper))
    return make_simulator(spec.compile(), lift, backend, warp), object_body_name(0, record.name)


# ---------------------------------------------------------------------------------------------------------------
# The search: candidates rolled out in trial order until the targets are met
# ---------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass
class _Search:
    """The labelling loop's state: what was tried and kept, and the near misses' parents."""

    params: ObjectGraspsParams
    max_collisions: int
    """Collision negatives that may be kept (:func:`graspgen.workflows.candidate_pool.collision_cap`)."""
    counts: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(len(OUTCOME_NAMES), dtype=np.int64))
    """Outcome histogram of everything tried."""
    by_kind: dict[str, np.ndarray] = dataclasses.field(
        default_factory=lambda: {k: np.zeros(len(OUTCOME_NAMES), dtype=np.int64) for k in CANDIDATES})
    """The same histogram by candidate kind."""
    kept: list[Kept] = dataclasses.field(default_factory=list)
    positives: int = 0
    negatives: int = 0
    tried: int = 0
    collisions: int = 0
    """Collisions at placement kept (as negatives)."""
    dropped: int = 0
    """``natural``: collisions at placement not kept (over ``collision_share_of_negatives``)."""
    stopped: str = "max_candidates"
    good_pose: list[np.ndarray] = dataclasses.field(default_factory=list)
    """The antipodal candidates that succeeded (the near misses' parents): TCP poses, widths, depths."""
    good_width: list[float] = dataclasses.field(default_factory=list)
    good_depth: list[float] = dataclasses.field(default_factory=list)

    def done(self) -> bool:
        if self.params.selection == "natural":
            return len(self.kept) - self.collisions >= self.params.target_grasps
        return self.positives >= self.params.target_positives and self.negatives >= self.params.target_negatives

    def record(self, kind: str, T: np.ndarray, w: float, depth: float, result: RolloutResult) -> None:
        """Count one rollout, keep it while its target (and the collision cap) has room, and remember an antipodal
        success as a parent."""
        params = self.params
        self.tried += 1
        self.counts[result.code] += 1
        self.by_kind[kind][result.code] += 1
        if params.selection == "natural":
            self._record_natural(kind, T, w, result)
            return
        if params.positive(result):
            if kind == CANDIDATES[0]:
                self.good_pose.append(T)
                self.good_width.append(w)
                self.good_depth.append(depth)
            if self.positives < params.target_positives:
                self.positives += 1
                self.kept.append((kind, T, w, result))
        elif self.negatives < params.target_negatives:
            if result.code <= Outcome.COLLISION_WITH_CLUTTER:
                if self.collisions >= self.max_collisions:
                    return
                self.collisions += 1
            self.negatives += 1
            self.kept.append((kind, T, w, result))

    def _record_natural(self, kind: str, T: np.ndarray, w: float, result: RolloutResult) -> None:
        """``natural``: keep every rollout that does not collide at placement, whatever its outcome, and a collision
        while the kept collisions stay within ``collision_share_of_negatives`` (a share of the kept negatives)."""
        if result.code <= Outcome.COLLISION_WITH_CLUTTER:
            if self.collisions + 1 > self.params.collision_share_of_negatives * (self.negatives + 1):
                self.dropped += 1
                return
            self.collisions += 1
            self.negatives += 1
            self.kept.append((kind, T, w, result))
            return
        if self.params.positive(result):
            self.positives += 1
        else:
            self.negatives += 1
        self.kept.append((kind, T, w, result))


def _batch(search: _Search, pool: CandidatePool, n_near: int, gripper: GripperSpec, overhang: float, tilt: float,
           rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]] | None:
    """The next batch: antipodal candidates from the pool and ``n_near`` near misses, ``(poses (b, 4, 4), widths
    (b,), the antipodal ones' depths, kinds)``; None when the pool has run dry."""
    taken = pool.take(search.params.batch_size - n_near)
    pose, width, depth = taken
    if len(width) == 0:
        return None
    # Parents: the antipodal successes so far (near misses of good grasps); before the first, this batch's own.
    source = taken
    if search.good_pose:
        source = (np.array(search.good_pose), np.array(search.good_width), np.array(search.good_depth))
    parent = rng.integers(0, len(source[1]), size=n_near)
    D = near_miss_offsets(source[2][parent], near_miss_draws(rng, n_near), gripper, overhang, tilt)
    kinds = [CANDIDATES[0]] * len(width) + [CANDIDATES[1]] * n_near
    return np.concatenate([pose, source[0][parent] @ D]), np.concatenate([width, source[1][parent]]), depth, kinds


def _search(search: _Search, simulator: Simulator, body: str, pool: CandidatePool, gripper: GripperSpec,
            overhang: float, tilt: float, rng: np.random.Generator) -> None:
    """Roll candidates out batch by batch, each batch in a random order, until the targets are met, the candidates
    run out or ``max_candidates`` rollouts were made. Each batch (up to the ``max_candidates`` left) goes to the
    simulator at once and its results are taken in order up to the stop (the CPU backend rolls out only those)."""
    params = search.params
    n_near_late = round(params.near_miss_fraction_when_positives_met * params.batch_size)
    natural = params.selection == "natural"
    while search.tried < params.max_candidates and not search.done():
        # Once the positives are in (and near misses of held grasps can be made), look for negatives where they are.
        late = not natural and search.positives >= params.target_positives and bool(search.good_pose)
        n_near = 0 if natural else n_near_late if late else params.near_misses_per_batch
        batch = _batch(search, pool, n_near, gripper, overhang, tilt, rng)
        if batch is None:
            search.stopped = "no_candidates"
            break
        poses, widths, depth, kinds = batch
        ahead = rng.permutation(len(widths))[: params.max_candidates - search.tried]
        for i, result in zip(ahead, simulator.iter_rollouts(poses[ahead], widths[ahead], body)):
            d = float(depth[i]) if i < len(depth) else math.nan  # a near miss is never a parent
            search.record(kinds[i], poses[i], float(widths[i]), d, result)
            if search.done():
                break
    if search.done():
        search.stopped = "targets"


# ---------------------------------------------------------------------------------------------------------------
# Labels of the kept rows
# ---------------------------------------------------------------------------------------------------------------


def _contact_labels(kept: list[Kept], params: ObjectGraspsParams, geometry: Any,
                    friction: float) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """Per kept row its contacts in the object frame ``(k, 3)`` (points, normals) and the epsilon of a success with
    contacts (NaN otherwise)."""
    ep = params.epsilon
    mu = friction if ep.friction is None else float(ep.friction)
    points, normals, epsilon = [], [], np.full(len(kept), math.nan)
    identity = np.eye(4)  # the object starts at the identity: without closing, the frames agree
    for j, (_, _, _, r) in enumerate(kept):
        p, nrm = object_frame_contacts(r, identity)
        points.append(p)
        normals.append(nrm)
        if r.code == Outcome.SUCCESS and len(p):
            epsilon[j] = ep.epsilon(p, nrm, r.contact_fingers, geometry, mu)
    return points, normals, epsilon


@dataclasses.dataclass(frozen=True)
class _CopyLabels:
    """The robustness labels an object-centric set stores of one kept success, by the names
    :func:`graspgen.workflows.robustness_columns.robustness_columns` reads (``n``, ``robustness``)."""

    n: int
    """Perturbed copies rolled out."""
    robustness: float
    """Their success fraction (positives by ``label``)."""


def _robustness(kept: list[Kept], success_rows: list[int], noise: np.ndarray | None, params: ObjectGraspsParams,
                simulator: LiftSimulator, body: str) -> list[_CopyLabels | None]:
    """Per kept row the labels of its perturbed copies; None for a row without copies."""
    rows: list[_CopyLabels | None] = [None] * len(kept)
    if not params.num_perturbations:
        return rows
    n_copies = params.num_perturbations
    for row, z in zip(success_rows, noise):
        T = kept[row][1]
        Ts = perturbed_poses(T, params.perturbation_translation * z[:, :3], params.perturbation_rotation * z[:, 3:])
        wins = sum(params.positive(simulator.rollout(Tc, kept[row][2], body)) for Tc in Ts)
        rows[row] = _CopyLabels(n_copies, wins / n_copies)
    return rows


def _table(name: str, params: ObjectGraspsParams, opening: float, kept: list[Kept], points: list, normals: list,
           epsilon: np.ndarray, copies: list[_CopyLabels | None]) -> pa.Table:
    """The :data:`SCHEMA` table of the kept rows, in trial order."""
    n = len(kept)
    robustness_n, robustness = robustness_columns(copies, ("n", "robustness"))
    others = {
        "object_name": pa.array([name] * n, pa.string()),
        "grasp_id": pa.array(np.arange(n, dtype=np.int32)),
        "candidate": pa.array([k[0] for k in kept], pa.string()),
        "gripper": pa.array([params.gripper] * n, pa.string()),
        "protocol": pa.array([params.protocol] * n, pa.string()),
        "pose_object": fixed_list(np.array([k[1] for k in kept], dtype=np.float64).reshape(n, 16), 16),
        "width": pa.array(np.array([k[2] for k in kept], dtype=np.float64), pa.float64()),
        "open_width": pa.array(np.full(n, opening), pa.float64()),
        "epsilon": pa.array(epsilon, pa.float64()),
        "robustness_n": robustness_n,
        "robustness": robustness,
    }
    return rollout_table(SCHEMA, [k[3] for k in kept], others, contacts=(points, normals))


# ---------------------------------------------------------------------------------------------------------------
# Labelling
# ---------------------------------------------------------------------------------------------------------------


def label_object_grasps(record: ObjectRecord, params: ObjectGraspsParams,
                        rng: np.random.Generator) -> tuple[pa.Table, dict[str, Any]]:
    """Sample, roll out and label grasps on one object in free space until the targets are met (module docstring).

    Parameters
    ----------
    record : ObjectRecord
        The prepared object (:func:`graspgen.io.objects.read_object`); its ``attrs["friction"]``, when present,
        is its friction, else ``params.friction``.
    params : ObjectGraspsParams
    rng : numpy.random.Generator
        The only source of randomness (module docstring, Randomness).

    Returns
    -------
    table : pyarrow.Table
        :data:`SCHEMA`, at most ``target_positives + target_negatives`` rows in trial order.
    meta : dict
        ``tried`` (rollouts of candidates), ``positives``, ``negatives`` (kept), ``reached`` (both targets met),
        ``stopped`` (``targets``, ``max_candidates`` or ``no_candidates``: the sampler found no pair the gripper
        opens around), ``outcomes`` (histogram of everything tried, by name), ``candidates`` (tried, by kind),
        ``outcomes_by_candidate`` (the histogram by kind), ``success_rate`` (by kind, over everything tried; None
        without any), ``sampled`` (antipodal candidates
        the sampler produced), ``friction``, ``open_width``, ``near_miss`` (the overhang and tilt used),
        ``robustness`` (copies rolled out and their mean success, when on), ``rollouts`` (all, copies included),
        ``seconds`` and ``rollouts_per_s`` (wall clock: the only entries that vary between runs); then the
        simulator's :meth:`~graspgen.sim.simulator.Simulator.meta` (``warp``: ``backend``, ``warp`` and
        ``device_rollouts``, the candidates rolled out on it, whole batches).

    Raises
    ------
    graspgen.errors.InputError
        The record's mesh is degenerate (all vertices at the centre of mass).
    graspgen.errors.SettingsError
        Wrong argument types (the message names the argument).
    """
    check_instance("record", record, ObjectRecord)
    check_instance("params", params, ObjectGraspsParams)
    check_rng("rng", rng)
    start = time.perf_counter()
    gripper = load_gripper(params.gripper)
    attrs_friction = (record.attrs or {}).get("friction")
    friction = params.friction if attrs_friction is None else check_number(
        f"{record.name}.attrs.friction", float(attrs_friction), low=0.0, low_open=True)
    overhang, tilt = params.overhang(gripper), params.tilt(gripper)
    geometry = object_geometry(record)
    warp = dataclasses.replace(params.warp, nworld=min(params.warp.nworld, params.batch_size))
    simulator, body = free_space_simulator(record, params.gripper, params.lift, friction, params.backend, warp)
    mesh = trimesh.Trimesh(np.asarray(record.vertices, dtype=np.float64), np.asarray(record.faces), process=False)
    pool = CandidatePool(mesh, gripper, params.sampler, rng)
    search = _Search(params, collision_cap(params.collision_share_of_negatives, params.target_negatives or 0))
    _search(search, simulator, body, pool, gripper, overhang, tilt, rng)

    success_rows = [j for j, (_, _, _, r) in enumerate(search.kept) if params.positive(r)]
    n_copies = params.num_perturbations
    noise = rng.standard_normal((len(success_rows), n_copies, 6)) if n_copies else None
    points, normals, epsilon = _contact_labels(search.kept, params, geometry, friction)
    copies = _robustness(search.kept, success_rows, noise, params, simulator.cpu, body)  # copies: on the CPU
    opening = protocol_opening(gripper, params.lift)
    table = _table(record.name, params, opening, search.kept, points, normals, epsilon, copies)
    seconds = time.perf_counter() - start
    meta = _meta(record.name, params, search, pool.sampled, friction, opening, (overhang, tilt), success_rows,
                 copies, seconds)
    return table, {**meta, **simulator.meta()}


def _meta(name: str, params: ObjectGraspsParams, search: _Search, sampled: int, friction: float, opening: float,
          near_miss: tuple[float, float], success_rows: list[int], copies: list[_CopyLabels | None],
          seconds: float) -> dict[str, Any]:
    """The metadata of :func:`label_object_grasps` (its docstring), in its key order."""
    n_copies = params.num_perturbations * len(success_rows)
    rollouts = search.tried + n_copies
    meta: dict[str, Any] = {
        "object": name,
        "gripper": params.gripper,
        "protocol": params.lift.protocol,
        "tried": search.tried,
        "positives": search.positives,
        "negatives": search.negatives,
        "target_positives": params.target_positives if params.selection == "balanced" else None,
        "target_negatives": params.target_negatives if params.selection == "balanced" else None,
        "max_candidates": params.max_candidates,
        "reached": search.stopped == "targets",
        "selection": params.selection,
        "label": params.label,
        "target_grasps": params.target_grasps if params.selection == "natural" else None,
        "positive_rate": search.positives / len(search.kept) if search.kept else None,
        "collision_negatives": search.collisions,
        "collisions_dropped": search.dropped,
        "stopped": search.stopped,
        "outcomes": {name: int(search.counts[c]) for c, name in enumerate(OUTCOME_NAMES)},
        "candidates": {k: int(v.sum()) for k, v in search.by_kind.items()},
        "outcomes_by_candidate": {k: {name: int(v[c]) for c, name in enumerate(OUTCOME_NAMES)}
                                  for k, v in search.by_kind.items()},
        "success_rate": {k: (int(v[Outcome.SUCCESS]) / int(v.sum()) if v.sum() else None)
                         for k, v in search.by_kind.items()},
        "sampled": sampled,
        "friction": friction,
        "open_width": opening,
        "near_miss": {"overhang": near_miss[0], "tilt": near_miss[1]},
        "rollouts": rollouts,
        "seconds": round(seconds, 3),
        "rollouts_per_s": round(rollouts / seconds, 2) if seconds > 0 else None,
    }
    if params.num_perturbations:
        mean = float(np.mean(np.array([copies[j].robustness for j in success_rows]))) if success_rows else None
        meta["robustness"] = {"copies": n_copies, "mean": mean}
    return meta
