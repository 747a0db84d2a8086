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
* ``table`` (default; the pipeline's grasp-and-lift: pre-grasp 5 cm back, approach, close, lift, hold, shake (on by
  default, ACRONYM's numbers: ``LiftParams.shake``)), in one of two worlds:

  - **free space** (default). The object is a free body at the world origin (mesh frame = world frame), at rest,
    with nothing else in the world: no ground, no table. Gravity is off during placement, approach and closing
    (``LiftParams.gravity_until_closed``), so the object floats where it is until the fingers hold it, then on for
    the lift, hold and shake. A grasp from below is as good as one from above.
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

Backends (``backend``): ``mujoco``, the CPU rollouts above (the reference; bit-identical across runs and ``jobs``),
or ``warp`` (:mod:`graspgen.sim.warp_backend`, the ``warp`` extra): the same model on MuJoCo Warp, ``warp.nworld``
grasps at once in one process (a GPU, or Warp's CPU device), for the ``acronym`` and ``graspgen`` protocols; float32
with a contact order that is not fixed, so a grasp on the edge of a rule can be labelled differently than on the CPU
or in another warp run (``bench/bench_warp.py`` measures both). The table's metadata names the backend.

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
firm                 bool            firm hold: outcome 5 (still in the hand) and the object's motion in the
                                     hand within ``lift.firm_translation`` / ``firm_rotation``
max_rel_translation  float64         largest displacement of the object in the TCP frame from the end of
                                     closing over the disturbance (``acronym``: shake and settle; ``table``:
                                     lift, hold, shake; ``graspgen``: tugs), m (NaN if not reached)
max_rel_rotation     float64         largest rotation relative to the TCP over the same span, rad
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

Robustness (``robustness=RobustnessParams(...)``, ``gen evaluate --robustness N``): every grasp whose nominal
outcome is 5 is rolled out again as ``num_perturbations`` perturbed copies, by the robustness stage's own function
(:func:`graspgen.quality.robustness.grasp_robustness`, so the same perturbation model: TCP pose noise in the TCP
frame, the object's mass, centre of mass and friction, and with ``object_noise`` its planar pose), in the same world
and protocol as the nominal rollout. The draws are made up front from one generator, ``(n, num_perturbations,
DRAWS_PER_COPY)`` standard normals in input order (for every grasp, successful or not), as the stage does; the
generator is the ``rng`` given, else seeded from a SHA-256 of the poses, widths and settings (:func:`content_seed`;
the seed is in the metadata). The copies of a grasp depend only on its draws, so the labels are the same for any
``jobs``. Extra columns (:data:`ROBUSTNESS_FIELDS`; grasps that did not succeed get ``robustness_n = 0``, NaN
labels and no copies):

===================  ==============  =====================================================================
robustness_n         int32           perturbed copies rolled out (0 unless the nominal outcome is 5)
robustness_successes int32           copies with outcome 5
robustness           float64         robustness_successes / robustness_n; NaN when robustness_n = 0
robustness_lo/_hi    float64         its Wilson score 95% interval
grip_robustness      float64         successes / copies that reached the grip (outcome 3-5: collisions at
                                     placement or during the approach left out); NaN when none did
grip_robustness_lo   float64         its Wilson score 95% interval (``_lo``, ``_hi``)
/_hi
copy_outcomes        list<int8>      outcome code of every copy, robustness_n values
===================  ==============  =====================================================================
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import trimesh

from graspgen.errors import GraspGenError, InputError, SettingsError
from graspgen.geometry.contacts import closing_contacts
from graspgen.geometry.convex import CoacdParams
from graspgen.geometry.prepare import prepare_object
from graspgen.geometry.stable_poses import StablePoseParams
from graspgen.io.acronym import read_acronym
from graspgen.io.arrow import fixed_list, variable_list
from graspgen.quality.epsilon import EpsilonParams, ObjectGeometry
from graspgen.quality.robustness import DRAWS_PER_COPY, GraspRobustness, RobustnessParams, grasp_robustness
from graspgen.sim.grippers import attach_gripper, load_gripper
from graspgen.sim.lift import OUTCOME_NAMES, LiftParams, LiftSimulator, Outcome, RolloutResult
from graspgen.sim.scene_model import (
    PlacedObject,
    SettleParams,
    SupportParams,
    build_scene_spec,
    free_space_spec,
    object_body_name,
    object_poses,
    settle,
)
from graspgen.sim.warp_backend import WarpLiftSimulator, WarpParams, check_backend
from graspgen.validation import check_instance, check_number, check_positive_int, check_transforms

__all__ = [
    "CHEAP_COACD",
    "METADATA_KEY",
    "OBJECT_NAME",
    "ROBUSTNESS_FIELDS",
    "SCHEMA",
    "EvaluateParams",
    "EvaluationWorld",
    "GraspFile",
    "content_seed",
    "evaluate_grasps",
    "evaluation_world",
    "outcome_counts",
    "read_grasp_file",
    "read_pose_table",
]

CHEAP_COACD = CoacdParams(threshold=0.05, max_convex_hull=32, preprocess_resolution=60, resolution=1000,
                          mcts_iterations=30)
"""CoACD settings for one-off evaluation, chosen by hull slack (``bench/hull_slack.py``): how far the parts MuJoCo
collides stand out of the true surface, which ACRONYM checks the open hand against. Criterion, fixed before any
agreement with FleX was looked at: slack p95 <= 1 mm (half the fingers' 2 mm touch allowance,
:data:`graspgen.sim.prefilter.TARGET_TOUCH_DEPTH`, which is meant in the object: slack eats it; the palm has none) on
every calibration object, within 600 s of CoACD on one core each; none meets it on all six (the 0.35 m hat: 1.64 mm
at best), so the tightest worst case in time. p95 / max slack, mm, now (before: threshold 0.1, 8 hulls, preprocess
resolution 30): example mug 0.67 / 2.07 (2.34 / 3.55), mug 187859 0.36 / 1.61 (2.08 / 4.40), bowl 4b93a8 0.64 / 1.12
(2.16 / 3.27), knife 0.40 / 1.09 (1.01 / 2.19), hat 1.64 / 2.82 (3.72 / 6.31), bottle 3ae3a9 1.28 / 2.33 (the same).
Cost: 571 s of one core for the six (before: 54 s), 389 s of it the example mug, whose self-intersecting mesh CoACD
first rebuilds on a grid of that many cells (at 30, with the same threshold: p95 1.20 mm); cached after the first
run."""

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
        ("firm", pa.bool_()),
        ("max_rel_translation", pa.float64()),
        ("max_rel_rotation", pa.float64()),
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

ROBUSTNESS_FIELDS = (
    pa.field("robustness_n", pa.int32()),
    pa.field("robustness_successes", pa.int32()),
    pa.field("robustness", pa.float64()),
    pa.field("robustness_lo", pa.float64()),
    pa.field("robustness_hi", pa.float64()),
    pa.field("grip_robustness", pa.float64()),
    pa.field("grip_robustness_lo", pa.float64()),
    pa.field("grip_robustness_hi", pa.float64()),
    pa.field("copy_outcomes", pa.list_(pa.int8())),
)
"""The columns appended to :data:`SCHEMA` with ``robustness`` (see the module docstring)."""


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


@dataclasses.dataclass(frozen=True, eq=False)
class GraspFile:
    """The grasps of one object read from a file by :func:`read_grasp_file`: what :func:`evaluate_grasps` takes."""

    kind: str
    """``acronym`` (an ACRONYM HDF5 file) or ``parquet`` (a table of TCP poses)."""
    T_tcp: np.ndarray
    """``(n, 4, 4) float64`` TCP poses in the object's scaled mesh frame, m."""
    widths: np.ndarray | None
    """``(n,) float64`` pad separations, m (a Parquet ``width`` column); None when the file has none."""
    mesh_path: Path
    """The object's mesh file."""
    scale: float | None
    """Metres per mesh unit (ACRONYM's ``object/scale`` unless overridden); None: detect from the size."""
    params: EvaluateParams
    """The params given, with the file's object mass, density and friction (ACRONYM) or the friction given."""
    reference: np.ndarray | None
    """``(n,) int8`` the file's own success label (ACRONYM's ``flex/object_in_gripper``); None when absent."""
    gripper: str | None
    """Our name of the file's gripper (ACRONYM's ``gripper/type``, e.g. ``panda``); None for Parquet."""


def read_grasp_file(
    path: str | Path,
    params: EvaluateParams | None = None,
    *,
    mesh_root: str | Path | None = None,
    mesh: str | Path | None = None,
    scale: float | None = None,
    friction: float | None = None,
) -> GraspFile:
    """Read an ACRONYM file (``.h5``, ``.hdf5``) or a Parquet table of TCP poses (``.parquet``, :func:`read_pose_table`)
    with its mesh: what ``gen evaluate`` and ``gen show rollout --grasps`` label.

    Parameters
    ----------
    path : str or Path
        The grasp file.
    params : EvaluateParams, optional
        Settings to start from (default ``EvaluateParams()``); ACRONYM's ``object/mass``, ``density`` and
        ``friction`` replace theirs.
    mesh_root : str or Path, optional
        Folder ACRONYM's ``object/file`` is relative to (default: the current directory); for Parquet, the folder a
        relative ``mesh`` is relative to.
    mesh : str or Path, optional
        The mesh file; needed with Parquet; replaces ACRONYM's ``object/file``.
    scale : float, optional
        Metres per mesh unit; default ACRONYM's ``object/scale``, for Parquet detected from the size.
    friction : float, optional
        The object's sliding friction; default ACRONYM's ``object/friction``, else ``params.friction``.

    Raises
    ------
    graspgen.errors.InputError
        Missing or unreadable file, unknown suffix, Parquet without ``mesh``, mesh not found; the message names the
        file.
    """
    path = Path(path)
    params = EvaluateParams() if params is None else params
    suffix = path.suffix.lower()
    if not path.is_file():
        raise InputError(f"{path}: grasp file not found")
    if suffix in (".h5", ".hdf5"):
        acr = read_acronym(path)
        try:
            T = acr.tcp_poses()
            gripper = acr.gripper
        except GraspGenError as exc:
            raise InputError(f"{path}: gripper/type {acr.gripper_type!r}: {exc}") from None
        root = Path(mesh_root) if mesh_root is not None else Path.cwd()
        mesh_path = Path(mesh) if mesh is not None else root / acr.object_file
        if not mesh_path.is_file():
            how = "--mesh" if mesh is not None else f"object/file {acr.object_file!r} under --mesh-root {root}"
            raise InputError(f"{path}: mesh not found: {mesh_path} ({how})")
        fric = friction if friction is not None else acr.object_friction
        params = dataclasses.replace(
            params, friction=fric if fric is not None else params.friction, mass=acr.object_mass,
            density=acr.object_density if acr.object_density is not None else params.density)
        return GraspFile("acronym", T, None, mesh_path, acr.object_scale if scale is None else scale, params,
                         acr.success, gripper)
    if suffix == ".parquet":
        if mesh is None:
            raise InputError(f"{path}: a Parquet grasp file needs --mesh (the mesh its poses refer to)")
        T, widths = read_pose_table(path)
        mesh_path = Path(mesh) if mesh_root is None or Path(mesh).is_absolute() else Path(mesh_root) / mesh
        if not mesh_path.is_file():
            raise InputError(f"{path}: mesh not found: {mesh_path} (--mesh)")
        if friction is not None:
            params = dataclasses.replace(params, friction=friction)
        return GraspFile("parquet", T, widths, mesh_path, scale, params, None, None)
    raise InputError(
        f"{path}: unsupported grasp file format {path.suffix or '(none)'!r}; expected an ACRONYM HDF5 "
        "file (.h5, .hdf5) or a Parquet table of poses (.parquet)"
    )


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
    physics = lift.physics_options((0.0, 0.0, -9.81))
    if support is None:
        return free_space_spec(obj, physics)
    return build_scene_spec([obj], support, physics)


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


def _roll_out_warp(world: _World, T_world: np.ndarray, warp: WarpParams | None) -> list[RolloutResult]:
    """All grasps on the warp backend, in one model of ``warp.nworld`` worlds (input order)."""
    if len(T_world) == 0:
        return []
    simulator = WarpLiftSimulator(_world_spec(world).compile(), world.lift, warp)  # as EvaluationWorld's
    return simulator.rollouts(T_world, object_body_name(0, world.obj.name))


def _world_spec(world: _World, visual: tuple[np.ndarray, np.ndarray] | None = None) -> mujoco.MjSpec:
    """The world as an MjSpec with the gripper attached; ``visual`` ``(vertices (v, 3) m, faces (f, 3))`` adds the
    object's visual mesh (drawn only: the physics and the joints are those of the model without it)."""
    obj = world.obj if visual is None else dataclasses.replace(world.obj, visual=visual)
    spec = _spec(obj, world.support, world.lift)
    attach_gripper(spec, load_gripper(world.gripper))
    return spec


@dataclasses.dataclass(frozen=True, eq=False)
class EvaluationWorld:
    """The world :func:`evaluate_grasps` rolls grasps out in and the grasps in it (:func:`evaluation_world`): plain
    arrays and settings, cheap to pickle to workers (a compiled model is not)."""

    world: _World
    """The object (placed), the support (None: free space), the gripper and the protocol."""
    T_tcp: np.ndarray
    """``(n, 4, 4) float64`` the TCP poses in the object's scaled mesh frame, m."""
    T_world: np.ndarray
    """``(n, 4, 4) float64`` the same poses in the world (the object's pose times ``T_tcp``), m."""
    width: np.ndarray
    """``(n,) float64`` the pad separation each grasp opens the jaws for (before the margin), m."""
    source: tuple[str, ...]
    """Where each width came from: ``input``, ``raycast``, ``open`` or ``protocol``."""
    geometry: ObjectGeometry
    """The prepared (scaled, repaired) mesh, its centre of mass (m) and torque scale (m), object frame."""
    info: dict[str, Any]
    """The output table's metadata (:data:`METADATA_KEY`)."""

    @property
    def target_body(self) -> str:
        """The object's body name in the model (``obj/0_object``)."""
        return object_body_name(0, self.world.obj.name)

    def simulator(self) -> LiftSimulator:
        """The world compiled with the gripper, in a fresh model: rolls a grasp out as :func:`evaluate_grasps` did."""
        return LiftSimulator(_world_spec(self.world).compile(), self.world.lift)

    def warp_simulator(self, warp: WarpParams | None = None) -> WarpLiftSimulator:
        """The same world on the warp backend (:class:`graspgen.sim.warp_backend.WarpLiftSimulator`, batches of
        ``warp.nworld`` grasps): ``warp_simulator().rollouts(T_world, target_body)`` rolls them out as
        :func:`evaluate_grasps` with ``backend="warp"`` does."""
        return WarpLiftSimulator(_world_spec(self.world).compile(), self.world.lift, warp)

    def visual_spec(self) -> mujoco.MjSpec:
        """The world with the gripper and the object's visual mesh (for rendering); its joints are the simulator's,
        so a recorded ``qpos`` poses it."""
        mesh = self.geometry.mesh
        return _world_spec(self.world, (np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)))


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
    robustness: RobustnessParams | None = None,
    rng: np.random.Generator | None = None,
    backend: str = "mujoco",
    warp: WarpParams | None = None,
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
    robustness : RobustnessParams, optional
        Also roll out ``robustness.num_perturbations`` perturbed copies of every successful grasp and add
        :data:`ROBUSTNESS_FIELDS` (module docstring); ``robustness.radius`` is not computed. None: no copies.
    rng : numpy.random.Generator, optional
        Generator of the copies' draws (``robustness`` only); None: seeded by :func:`content_seed` from the poses,
        widths and settings.
    backend : str
        ``mujoco`` (the CPU, ``jobs`` workers) or ``warp`` (MuJoCo Warp, :mod:`graspgen.sim.warp_backend`: all
        grasps in batches of ``warp.nworld`` parallel worlds in one process; ``acronym`` and ``graspgen`` protocols;
        float32, so labels on the edge of a rule can differ from the CPU's and between runs). The robustness copies
        always run on the CPU.
    warp : WarpParams, optional
        Device and batch of the warp backend; None: ``WarpParams()``.

    Returns
    -------
    pyarrow.Table
        :data:`SCHEMA` (plus :data:`ROBUSTNESS_FIELDS` with ``robustness``), ``n`` rows in input order.

    Raises
    ------
    graspgen.errors.InputError
        The mesh cannot be used (missing, broken, absurd size); the message names the file.
    graspgen.errors.SettingsError
        Unknown gripper (the message lists the choices) or protocol; ``acronym`` or ``graspgen`` with
        ``free_space=False``.
    ValueError
        Poses or widths of the wrong shape, non-finite, or not rigid (the message names the first bad index);
        ``robustness`` or ``rng`` of the wrong type.
    """
    from joblib import Parallel, delayed

    if robustness is not None and not isinstance(robustness, RobustnessParams):
        raise ValueError(f"robustness: expected RobustnessParams or None, got {type(robustness).__name__}")
    if rng is not None and not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng: expected numpy.random.Generator or None, got {type(rng).__name__}")
    ew = evaluation_world(mesh_path, scale, T_tcp, widths, gripper, params, free_space=free_space,
                          protocol=protocol, cache_dir=cache_dir)
    world, T_world, width = ew.world, ew.T_world, ew.width
    check_backend(backend, world.lift.protocol)
    n = len(T_world)
    jobs = (os.cpu_count() or 1) if jobs <= 0 else int(jobs)
    if backend == "warp":
        results = _roll_out_warp(world, T_world, warp)
    else:
        chunks = [c for c in np.array_split(np.arange(n), max(1, min(jobs, n))) if len(c)]
        parts = Parallel(n_jobs=len(chunks) or 1)(
            delayed(_roll_out_chunk)(world, T_world[c], width[c]) for c in chunks
        )
        results = [r for part in parts for r in part]
    table = _table(ew.T_tcp, width, list(ew.source), results, world.obj.pose)
    info = dict(ew.info)
    info["backend"] = backend
    if backend == "warp":
        info["warp"] = (warp or WarpParams()).to_dict()
    if robustness is not None:
        robustness = dataclasses.replace(robustness, radius=False)
        if rng is None:
            seed = content_seed(ew, robustness)
            info["robustness_seed"] = seed
            rng = np.random.default_rng(seed)
        info["robustness"] = dataclasses.asdict(robustness)
        draws = rng.standard_normal((n, robustness.num_perturbations, DRAWS_PER_COPY))
        ok = np.flatnonzero(table.column("outcome").to_numpy() == Outcome.SUCCESS)
        rows: list[GraspRobustness] = []
        if len(ok):
            groups = [c for c in np.array_split(ok, min(jobs, len(ok))) if len(c)]
            found = Parallel(n_jobs=len(groups))(
                delayed(_robustness_chunk)(world, ew.geometry, T_world[c], width[c], draws[c], robustness)
                for c in groups
            )
            rows = [r for part in found for r in part]
        for field, column in zip(ROBUSTNESS_FIELDS, _robustness_columns(n, ok, rows)):
            table = table.append_column(field, column)
    return table.replace_schema_metadata({METADATA_KEY: json.dumps(info, sort_keys=True)})


def evaluation_world(
    mesh_path: str | Path,
    scale: float | None,
    T_tcp: Any,
    widths: Any,
    gripper: str,
    params: EvaluateParams | None = None,
    *,
    free_space: bool = True,
    protocol: str | None = None,
    cache_dir: str | Path | None = None,
) -> EvaluationWorld:
    """The world :func:`evaluate_grasps` rolls the grasps out in, with the grasps placed in it, without rolling any
    out: the object prepared, opened widths chosen, settled on the table (``free_space=False``).

    Parameters and errors as :func:`evaluate_grasps` (less ``jobs`` and ``robustness``). Use it to roll one grasp
    out again exactly as :func:`evaluate_grasps` did (:meth:`EvaluationWorld.simulator`, e.g. to film it:
    :func:`graspgen.viz.evaluate_movie.evaluated_rollout_movie`).

    Returns
    -------
    EvaluationWorld
    """
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
    world = _World(obj=obj, support=support, gripper=str(gripper), lift=lift)  # a name or a file path
    com = np.asarray(prepared.mass.center_of_mass, dtype=np.float64)
    vertices = np.asarray(prepared.vertices, dtype=np.float64)
    torque_scale = float(np.sqrt(np.max(np.sum((vertices - com) ** 2, axis=1))))
    geometry = ObjectGeometry(trimesh.Trimesh(vertices, np.asarray(prepared.faces), process=False), com, torque_scale)
    info = {"mesh": str(mesh_path), "scale": prepared.scale, "gripper": spec.name, "free_space": bool(free_space),
            "protocol": lift.protocol, "lift": lift.to_dict(), "mass": float(mass), "friction": params.friction,
            "center_of_mass": com.tolist(), "torque_scale": torque_scale, "convex_parts": len(prepared.convex_parts),
            "object_pose": obj.pose.tolist(), "warnings": list(prepared.warnings)}
    return EvaluationWorld(world=world, T_tcp=T, T_world=obj.pose @ T, width=np.asarray(width, dtype=np.float64),
                           source=tuple(source), geometry=geometry, info=info)


def content_seed(world: EvaluationWorld, robustness: RobustnessParams) -> int:
    """Seed (a 64-bit integer) of the robustness draws when no generator is given: the first 8 bytes of a SHA-256 of
    the grasps' poses and widths (float64 bytes) and of the settings (the object's mass, friction, centre of mass
    and pose, the gripper, the protocol and its settings, the robustness settings; canonical JSON). The mesh path
    and the preparation's warnings do not enter: the same grasps and settings give the same draws wherever the
    file lies."""
    settings = {k: v for k, v in world.info.items() if k not in ("mesh", "warnings")}
    settings["robustness"] = dataclasses.asdict(robustness)
    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(world.T_tcp, dtype="<f8").tobytes())
    digest.update(np.ascontiguousarray(world.width, dtype="<f8").tobytes())
    digest.update(json.dumps(settings, sort_keys=True, default=str).encode())
    return int.from_bytes(digest.digest()[:8], "little")


def _robustness_chunk(world: _World, geometry: ObjectGeometry, T_world: np.ndarray, widths: np.ndarray,
                      draws: np.ndarray, params: RobustnessParams) -> list[GraspRobustness]:
    """The perturbed copies of a chunk of successful grasps (world-frame poses ``(k, 4, 4)``, widths ``(k,)``,
    draws ``(k, n, DRAWS_PER_COPY)``), in one freshly compiled model per worker, by the robustness stage's
    :func:`graspgen.quality.robustness.grasp_robustness` (the copies' epsilon by the default ``EpsilonParams``)."""
    simulator = LiftSimulator(_world_spec(world).compile(), world.lift)
    gripper = load_gripper(world.gripper)
    body = object_body_name(0, world.obj.name)
    epsilon = EpsilonParams()
    return [grasp_robustness(simulator, T, float(w), body, geometry, world.obj.friction, d, params, epsilon, gripper)
            for T, w, d in zip(T_world, widths, draws)]


def _robustness_columns(n: int, ok: np.ndarray, rows: list[GraspRobustness]) -> list[pa.Array]:
    """The :data:`ROBUSTNESS_FIELDS` columns of ``n`` grasps, ``rows[k]`` the labels of grasp ``ok[k]``."""
    by_row: list[GraspRobustness | None] = [None] * n
    for i, r in zip(ok, rows):
        by_row[int(i)] = r
    nan = float("nan")

    def num(get) -> pa.Array:
        return pa.array([get(r) if r is not None else nan for r in by_row], pa.float64())

    return [
        pa.array([r.n if r is not None else 0 for r in by_row], pa.int32()),
        pa.array([r.successes if r is not None else 0 for r in by_row], pa.int32()),
        num(lambda r: r.robustness),
        num(lambda r: r.interval[0]),
        num(lambda r: r.interval[1]),
        num(lambda r: r.grip_robustness),
        num(lambda r: r.grip_interval[0]),
        num(lambda r: r.grip_interval[1]),
        variable_list([r.outcomes if r is not None else () for r in by_row], pa.int8()),
    ]


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
        "firm": pa.array([r.firm for r in results], pa.bool_()),
        "max_rel_translation": num("max_rel_translation"),
        "max_rel_rotation": num("max_rel_rotation"),
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
