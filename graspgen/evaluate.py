"""Label someone else's grasps with our simulator: grasp poses for one object in, one outcome per grasp out.

:func:`evaluate_grasps` takes a mesh file and TCP poses in its (scaled) mesh frame, e.g. from an ACRONYM file
(:func:`graspgen.io.acronym.read_acronym`) or a Parquet table of poses (:func:`read_pose_table`), and rolls every grasp
out with :class:`graspgen.sim.lift.LiftSimulator`. ``gen evaluate`` is the command line for it.

Protocols (``LiftParams.protocol``, or the ``protocol`` argument; :mod:`graspgen.sim.lift`):

* ``acronym``: ACRONYM's own test (:class:`graspgen.sim.lift.AcronymParams`), always in free space: the hand is
  placed at the grasp pose with its fingers fully open (a hand that intersects the object there is
  collision_with_target), closes, gravity comes on along the approach axis, the hand shakes along its approach
  axis and about its closing axis, and the label is whether the object is still between the fingers. Widths are
  not used (the jaws open fully; ``width_source`` is ``protocol``). The four motion columns are ACRONYM's
  ``object_motion_during_{closing,shaking}_{linear,angular}``. The right protocol for comparing with ACRONYM labels.
* ``table`` (default; the pipeline's grasp-and-lift: pre-grasp 5 cm back, approach, close, lift, hold), in one of
  two worlds:

  - **free space** (default). The object is a free body at the world origin (mesh frame = world frame), at rest,
    with nothing else in the world: no ground, no table. Gravity is off during placement, approach and closing
    (``LiftParams.gravity_until_closed``), so the object floats where it is until the fingers hold it, then on for
    the lift, hold and optional shake. A grasp from below is as good as one from above.
  - **support plane** (``free_space=False``): the object rests on a table (``SupportParams``, top at z = 0) in its
    most probable stable pose, settled in MuJoCo, with gravity throughout; the grasps are moved with it
    (``T_world = T_world_object @ T_object``). Grasps from below the table top are collisions with the ground (0).

The object is prepared with :func:`graspgen.geometry.prepare.prepare_object` (repair, units, mass from density,
CoACD with cheap settings unless configured, cached by mesh hash). Gripper opening (``table``): the given widths
(the jaws open to ``width + width_margin``), or, without widths, the width found by closing the pads onto the mesh
with ray casts (:func:`graspgen.geometry.contacts.closing_contacts`); a grasp whose pads touch nothing that way
opens fully (it will most likely close on air: 3).

Parallelism: the grasps are cut into ``jobs`` contiguous chunks run by joblib workers; each worker builds and
compiles its own model once (a compiled model is never pickled) and rolls its chunk out in order, so the output is
in input order and, like every rollout (:mod:`graspgen.sim.lift`), independent of ``jobs``.

Output: one row per input grasp, in input order (:data:`SCHEMA`):

===================  ==============  =====================================================================
column               type            meaning
===================  ==============  =====================================================================
index                int32           row of the input (0..n-1)
outcome              int8            0-5 (:class:`graspgen.sim.lift.Outcome`)
outcome_name         string          its name
decided_in           string          protocol phase that decided it
steps                int32           simulated steps
sim_time             float64         simulated seconds
width                float64         pad separation the jaws opened for (before the margin), m
width_source         string          ``input``, ``raycast``, ``open`` (ray casts found no contact on a pad) or
                                     ``protocol`` (``acronym``: the jaws open fully; ``width`` is that opening)
closed_width         float64         pad separation when closing ended, m (NaN if not reached)
lift_gain            float64         how far the object rose, m (NaN if not reached)
rel_translation      float64         object displacement relative to the TCP after closing, m
rel_rotation         float64         object rotation relative to the TCP after closing, rad
pose                 float64[16]     the TCP pose evaluated, object frame, 4x4 row-major
contact_points       list<float64>   finger-object contacts at the end of closing, object frame, k*3 values
contact_normals      list<float64>   their normals, into the object, object frame, k*3 values
contact_forces       list<float64>   their normal forces, N, k values
contact_fingers      list<int8>      0 left pad/finger, 1 right, k values
motion_closing_linear  float64       object displacement while the fingers closed, m (NaN if not reached)
motion_closing_angular float64       object rotation while the fingers closed, rad
motion_shaking_linear  float64       object displacement during the shake, m (NaN if no shake ran)
motion_shaking_angular float64       object rotation during the shake, rad
===================  ==============  =====================================================================

Object frame: the scaled mesh frame of the input file. Contacts are mapped back from the world with the object's
pose at the end of closing (when they were recorded), so they are exact even where the fingers pushed the object.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import trimesh

from graspgen.errors import InputError, SettingsError
from graspgen.geometry.contacts import closing_contacts
from graspgen.geometry.convex import CoacdParams
from graspgen.geometry.prepare import prepare_object
from graspgen.geometry.stable_poses import StablePoseParams
from graspgen.io.arrow import fixed_list, variable_list
from graspgen.sim.grippers import attach_gripper, load_gripper
from graspgen.sim.lift import OUTCOME_NAMES, LiftParams, LiftSimulator, RolloutResult
from graspgen.sim.scene_model import (
    GROUND_NAME,
    SUPPORT_PREFIX,
    PlacedObject,
    SettleParams,
    SupportParams,
    build_scene_spec,
    object_body_name,
    object_poses,
    settle,
)
from graspgen.validation import check_instance, check_number, check_positive_int, check_transforms

__all__ = [
    "CHEAP_COACD",
    "METADATA_KEY",
    "OBJECT_NAME",
    "SCHEMA",
    "EvaluateParams",
    "evaluate_grasps",
    "outcome_counts",
    "read_pose_table",
]

CHEAP_COACD = CoacdParams(threshold=0.1, max_convex_hull=8, preprocess_resolution=30, resolution=1000,
                          mcts_iterations=30)
"""CoACD settings for one-off evaluation: ~3-10x faster than the dataset default, a few more cm^3 of hull slack."""

METADATA_KEY = "evaluate"
"""Key of the output table's schema metadata: JSON with the mesh, scale, gripper, protocol and its settings, mode,
mass, friction, the centre of mass and torque scale (largest vertex distance from it) in the object frame, number of
convex parts, the object's world pose (4x4) and the mesh preparation's warnings (e.g. a guessed unit)."""

OBJECT_NAME = "object"
"""Body name stem of the evaluated object (the body is ``obj/0_object``)."""

SCHEMA = pa.schema(
    [
        ("index", pa.int32()),
        ("outcome", pa.int8()),
        ("outcome_name", pa.string()),
        ("decided_in", pa.string()),
        ("steps", pa.int32()),
        ("sim_time", pa.float64()),
        ("width", pa.float64()),
        ("width_source", pa.string()),
        ("closed_width", pa.float64()),
        ("lift_gain", pa.float64()),
        ("rel_translation", pa.float64()),
        ("rel_rotation", pa.float64()),
        ("pose", pa.list_(pa.float64(), 16)),
        ("contact_points", pa.list_(pa.float64())),
        ("contact_normals", pa.list_(pa.float64())),
        ("contact_forces", pa.list_(pa.float64())),
        ("contact_fingers", pa.list_(pa.int8())),
        ("motion_closing_linear", pa.float64()),
        ("motion_closing_angular", pa.float64()),
        ("motion_shaking_linear", pa.float64()),
        ("motion_shaking_angular", pa.float64()),
    ]
)
"""The output table's schema (see the module docstring)."""


@dataclasses.dataclass(frozen=True)
class EvaluateParams:
    """How :func:`evaluate_grasps` builds the object and rolls the grasps out."""

    lift: LiftParams = dataclasses.field(default_factory=LiftParams)
    """The protocol and its settings (``lift.protocol``: ``table`` or ``acronym``; for ``table`` its
    ``gravity_until_closed`` is set by the mode: on in free space, else off)."""
    friction: float = 0.5
    """Sliding friction coefficient of the object (dimensionless; the object's value governs gripper contacts)."""
    density: float = 700.0
    """Density (kg/m^3) the mass is computed from when ``mass`` is None."""
    mass: float | None = None
    """Object mass (kg), e.g. ACRONYM's ``object/mass``; the inertia is rescaled with it (uniform density)."""
    coacd: CoacdParams = CHEAP_COACD
    """Convex decomposition of the object (cached by mesh hash and these settings)."""
    support: SupportParams = dataclasses.field(default_factory=SupportParams)
    """The table of the support-plane protocol (its top is z = 0)."""
    rays_per_side: int = 3
    """Ray-cast width finding: rays per pad edge (``rays_per_side ** 2`` per pad)."""
    max_extent: float = 1.0
    """Largest accepted object extent after scaling, m (ACRONYM has furniture-sized objects up to ~1 m)."""

    def __post_init__(self) -> None:
        check_instance("lift", self.lift, LiftParams)
        for key in ("friction", "density", "max_extent"):
            check_number(key, getattr(self, key), low=0.0, low_open=True)
        if self.mass is not None:
            check_number("mass", self.mass, low=0.0, low_open=True)
        check_positive_int("rays_per_side", self.rays_per_side)


# ---------------------------------------------------------------------------------------------------------------
# Input
# ---------------------------------------------------------------------------------------------------------------


def read_pose_table(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """TCP poses (and widths) from a Parquet table.

    Columns: ``pose_object`` or ``pose`` (16 floats: the TCP pose in the object's scaled mesh frame, 4x4 row-major;
    the grasps stage's own tables therefore work as they are), optional ``width`` (m).

    Returns
    -------
    T_tcp : (n, 4, 4) float64
    widths : (n,) float64 or None

    Raises
    ------
    graspgen.errors.InputError
        Not a Parquet file, or no pose column / wrong lengths; the message names the file.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: grasp file not found")
    try:
        table = pq.read_table(path)
    except Exception as exc:  # pyarrow raises ArrowInvalid, OSError, ... on garbage
        raise InputError(f"{path}: not a readable Parquet file ({type(exc).__name__}: {exc})") from None
    column = next((c for c in ("pose_object", "pose") if c in table.column_names), None)
    if column is None:
        raise InputError(f"{path}: no pose column: expected 'pose_object' or 'pose' (16 floats per row, the TCP "
                         f"pose 4x4 row-major); it has: {', '.join(table.column_names)}")
    rows = table.column(column).to_pylist()
    if any(r is None or len(r) != 16 for r in rows):
        raise InputError(f"{path}: every {column!r} must hold 16 numbers (a 4x4 row-major pose)")
    T = np.asarray(rows, dtype=np.float64).reshape(len(rows), 4, 4)
    widths = None
    if "width" in table.column_names:
        widths = np.asarray(table.column("width").to_pylist(), dtype=np.float64)
    return T, widths


# ---------------------------------------------------------------------------------------------------------------
# The world
# ---------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class _World:
    """What a worker needs to build its model (plain arrays: cheap to pickle, unlike a compiled model)."""

    obj: PlacedObject
    support: SupportParams | None
    gripper: str
    """A bundled gripper name or the path of a gripper file (what :func:`load_gripper` takes)."""
    lift: LiftParams


def _spec(obj: PlacedObject, support: SupportParams | None, lift: LiftParams):
    """The object (and table) as an MjSpec; without a support, the ground and table are removed: free space."""
    spec = build_scene_spec([obj], support or SupportParams(), lift.physics_options((0.0, 0.0, -9.81)))
    if support is None:
        for geom in list(spec.geoms):
            if geom.name == GROUND_NAME or geom.name.startswith(SUPPORT_PREFIX):
                spec.delete(geom)
    return spec


def _settled_pose(obj: PlacedObject, support: SupportParams, lift: LiftParams) -> np.ndarray:
    """(4, 4) pose of ``obj`` after settling on ``support`` (without the gripper: it starts at the origin, which
    the object's resting place may overlap)."""
    model = _spec(obj, support, lift).compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    settle(model, data, SettleParams())
    return object_poses(model, data)[0]


def _roll_out_chunk(world: _World, T_world: np.ndarray, widths: np.ndarray) -> list[RolloutResult]:
    """Roll out a chunk of grasps (world-frame TCP poses) in one freshly compiled model (one per worker)."""
    spec = _spec(world.obj, world.support, world.lift)
    attach_gripper(spec, load_gripper(world.gripper))
    simulator = LiftSimulator(spec.compile(), world.lift)
    body = object_body_name(0, world.obj.name)
    return [simulator.rollout(T, float(w), body) for T, w in zip(T_world, widths)]


# ---------------------------------------------------------------------------------------------------------------
# Evaluation
# ---------------------------------------------------------------------------------------------------------------


def evaluate_grasps(
    mesh_path: str | Path,
    scale: float | None,
    T_tcp: Any,
    widths: Any,
    gripper: str,
    params: EvaluateParams | None = None,
    *,
    free_space: bool = True,
    protocol: str | None = None,
    jobs: int = 1,
    cache_dir: str | Path | None = None,
) -> pa.Table:
    """Roll out grasps given as TCP poses on one object; one output row per grasp, in input order.

    Parameters
    ----------
    mesh_path : str or Path
        The object's mesh file (OBJ/STL/PLY/GLB/OFF).
    scale : float or None
        Metres per mesh unit (ACRONYM's ``object/scale``); None detects mm/cm from the size, with a warning.
    T_tcp : (n, 4, 4) float
        TCP poses (z approach, x closing, origin between the pads) in the scaled mesh frame, m.
    widths : (n,) float or None
        Pad separation (m) per grasp; None finds it by ray casting (pads touching nothing: open fully).
    gripper : str
        Gripper name (:data:`graspgen.sim.grippers.GRIPPERS`).
    params : EvaluateParams, optional
        Protocol, object properties, CoACD settings; default ``EvaluateParams()``.
    free_space : bool
        True: no support, gravity off until the fingers have closed. False: on a table, in the most probable
        stable pose (module docstring; ``table`` protocol only).
    protocol : str, optional
        ``table``, ``acronym`` or ``graspgen`` (module docstring); None: ``params.lift.protocol`` (``table`` by
        default).
    jobs : int
        Worker processes (contiguous chunks of grasps; each builds its own model); <= 0 means one per core.
    cache_dir : str or Path, optional
        Folder of the CoACD cache (``<cache_dir>/coacd``, shared with the objects stage); None: no cache.

    Returns
    -------
    pyarrow.Table
        :data:`SCHEMA`, ``n`` rows in input order.

    Raises
    ------
    graspgen.errors.InputError
        The mesh cannot be used (missing, broken, absurd size); the message names the file.
    graspgen.errors.SettingsError
        Unknown gripper (the message lists the choices) or protocol; ``acronym`` or ``graspgen`` with
        ``free_space=False``.
    ValueError
        Poses or widths of the wrong shape, non-finite, or not rigid (the message names the first bad index).
    """
    from joblib import Parallel, delayed

    params = EvaluateParams() if params is None else params
    if not isinstance(params, EvaluateParams):
        raise ValueError(f"params: expected EvaluateParams, got {type(params).__name__}")
    if protocol is not None:
        params = dataclasses.replace(params, lift=params.lift.with_protocol(protocol))
    acronym = params.lift.protocol == "acronym"
    if params.lift.protocol in ("acronym", "graspgen") and not free_space:
        raise SettingsError(f"protocol: {params.lift.protocol!r} is a free-space protocol (no support plane); use "
                            "'table' with a support")
    spec = load_gripper(gripper)
    T = check_transforms("T_tcp", T_tcp)
    n = len(T)
    if widths is not None:
        widths = np.asarray(widths, dtype=np.float64).reshape(-1)
        if len(widths) != n:
            raise ValueError(f"widths: expected {n} values (one per pose), got {len(widths)}")
        if not (np.isfinite(widths).all() and (widths >= 0).all()):
            raise ValueError(f"widths[{int(np.flatnonzero(~(np.isfinite(widths) & (widths >= 0)))[0])}]: must be "
                             "a finite width >= 0 m")
    lift = params.lift if acronym else dataclasses.replace(params.lift, gravity_until_closed=bool(free_space))

    # Stable poses only matter on a table; in free space skip their MuJoCo settle check (seconds per pose).
    poses = StablePoseParams(settle_check=not free_space, max_poses=1)
    prepared = prepare_object(mesh_path, density=params.density, scale=scale, max_extent=params.max_extent,
                              coacd=params.coacd, poses=poses, rng=np.random.default_rng(0),
                              coacd_cache_dir=None if cache_dir is None else Path(cache_dir) / "coacd")
    mass, inertia = prepared.mass.mass, np.asarray(prepared.mass.inertia)
    if params.mass is not None:  # the same shape and uniform density: inertia scales with the mass
        inertia, mass = inertia * (params.mass / mass), params.mass

    if acronym:  # the jaws open to the protocol's opening whatever the grasp's width
        opening = spec.max_width if lift.acronym.open_width is None else lift.acronym.open_width
        width, source = np.full(n, float(np.clip(opening, spec.min_width, spec.max_width))), ["protocol"] * n
    else:
        width, source = _opening(prepared, T, widths, spec, params.rays_per_side)

    obj = PlacedObject(name=OBJECT_NAME, convex_parts=prepared.convex_parts, mass=float(mass),
                       center_of_mass=np.asarray(prepared.mass.center_of_mass), inertia=inertia, pose=np.eye(4),
                       friction=params.friction)
    support = None
    if not free_space:
        support = params.support
        obj = dataclasses.replace(obj, pose=_settled_pose(
            dataclasses.replace(obj, pose=prepared.stable_transforms[0]), support, lift))
    T_world = obj.pose @ T
    world = _World(obj=obj, support=support, gripper=str(gripper), lift=lift)  # a name or a file path

    jobs = (os.cpu_count() or 1) if jobs <= 0 else int(jobs)
    chunks = [c for c in np.array_split(np.arange(n), max(1, min(jobs, n))) if len(c)]
    parts = Parallel(n_jobs=len(chunks) or 1)(
        delayed(_roll_out_chunk)(world, T_world[c], width[c]) for c in chunks
    )
    results = [r for part in parts for r in part]
    table = _table(T, width, source, results, obj.pose)
    com = np.asarray(prepared.mass.center_of_mass, dtype=np.float64)
    torque_scale = float(np.sqrt(np.max(np.sum((np.asarray(prepared.vertices) - com) ** 2, axis=1))))
    info = {"mesh": str(mesh_path), "scale": prepared.scale, "gripper": spec.name, "free_space": bool(free_space),
            "protocol": lift.protocol, "lift": lift.to_dict(), "mass": float(mass), "friction": params.friction,
            "center_of_mass": com.tolist(), "torque_scale": torque_scale, "convex_parts": len(prepared.convex_parts),
            "object_pose": obj.pose.tolist(), "warnings": list(prepared.warnings)}
    return table.replace_schema_metadata({METADATA_KEY: json.dumps(info, sort_keys=True)})


def _opening(prepared: Any, T: np.ndarray, widths: np.ndarray | None, spec: Any,
             rays_per_side: int) -> tuple[np.ndarray, list[str]]:
    """Width per grasp and where it came from (``input``, ``raycast`` or ``open``)."""
    n = len(T)
    if widths is not None:
        return widths, ["input"] * n
    mesh = trimesh.Trimesh(prepared.vertices, prepared.faces, process=False)
    found = np.array([c.width for c in closing_contacts(mesh, T, spec, rays_per_side=rays_per_side)])
    ok = np.isfinite(found)
    return np.where(ok, np.clip(found, 0.0, spec.max_width), spec.max_width), ["raycast" if k else "open" for k in ok]


def _table(T: np.ndarray, width: np.ndarray, source: list[str], results: list[RolloutResult],
           T_world_object: np.ndarray) -> pa.Table:
    def num(attr: str) -> pa.Array:
        return pa.array(np.array([getattr(r, attr) for r in results], dtype=np.float64))

    def to_object(r: RolloutResult) -> np.ndarray:
        """World -> object frame at the end of closing (the initial pose when closing was not reached)."""
        pose = r.target_pose_closed if np.isfinite(r.target_pose_closed).all() else T_world_object
        return np.linalg.inv(pose)

    frames = [to_object(r) for r in results]
    points = [(r.contact_points @ F[:3, :3].T + F[:3, 3]).reshape(-1) for r, F in zip(results, frames)]
    normals = [(r.contact_normals @ F[:3, :3].T).reshape(-1) for r, F in zip(results, frames)]
    n = len(results)
    arrays = {
        "index": pa.array(np.arange(n, dtype=np.int32)),
        "outcome": pa.array(np.array([r.code for r in results], dtype=np.int8)),
        "outcome_name": pa.array([r.name for r in results], pa.string()),
        "decided_in": pa.array([r.decided_in for r in results], pa.string()),
        "steps": pa.array(np.array([r.steps for r in results], dtype=np.int32)),
        "sim_time": num("sim_time"),
        "width": pa.array(np.asarray(width, dtype=np.float64)),
        "width_source": pa.array(source, pa.string()),
        "closed_width": num("closed_width"),
        "lift_gain": num("lift_gain"),
        "rel_translation": num("rel_translation"),
        "rel_rotation": num("rel_rotation"),
        "pose": fixed_list(T.reshape(n, 16), 16),
        "contact_points": variable_list(points, pa.float64()),
        "contact_normals": variable_list(normals, pa.float64()),
        "contact_forces": variable_list([r.contact_forces for r in results], pa.float64()),
        "contact_fingers": variable_list([r.contact_fingers for r in results], pa.int8()),
        "motion_closing_linear": num("motion_closing_linear"),
        "motion_closing_angular": num("motion_closing_angular"),
        "motion_shaking_linear": num("motion_shaking_linear"),
        "motion_shaking_angular": num("motion_shaking_angular"),
    }
    return pa.table(arrays, schema=SCHEMA)


def outcome_counts(table: pa.Table) -> dict[str, int]:
    """``{outcome_name: count}`` over all six outcomes of an evaluation (or rollouts) table."""
    codes = table.column("outcome").to_numpy()
    return {name: int((codes == c).sum()) for c, name in enumerate(OUTCOME_NAMES)}
