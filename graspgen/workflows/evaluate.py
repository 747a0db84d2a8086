"""Label someone else's grasps with our simulator: grasp poses for one object in, one outcome per grasp out.

:func:`evaluate_grasps` takes a mesh file and TCP poses in its (scaled) mesh frame, e.g. from an ACRONYM file
(:func:`graspgen.io.acronym.read_acronym`) or a Parquet table of poses
(:func:`graspgen.workflows.grasp_files.read_pose_table`), and rolls every grasp out with
:class:`graspgen.sim.lift.LiftSimulator`. ``gen evaluate`` is the command line for it. Its settings:
:mod:`graspgen.workflows.evaluate_settings`; its world: :mod:`graspgen.workflows.evaluation_world`; its table:
:mod:`graspgen.workflows.evaluate_columns`.

Protocols (``LiftParams.protocol``, or the ``protocol`` argument; :mod:`graspgen.sim.protocols`):

* ``acronym``: ACRONYM's own test (:class:`graspgen.sim.protocols.AcronymParams`), always in free space: the hand is
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

The object is prepared with :func:`graspgen.workflows.prepare.prepare_object` (repair, units, mass from density,
CoACD with cheap settings unless configured, cached by mesh hash). Gripper opening (``table``): the given widths
(the jaws open to ``width + width_margin``), or, without widths, the width found by closing the pads onto the mesh
with ray casts (:func:`graspgen.geometry.contacts.closing_contacts`); a grasp whose pads touch nothing that way
opens fully (it will most likely close on air: 3).

Parallelism: the grasps are cut into ``jobs`` contiguous chunks run by joblib workers; each worker builds and
compiles its own model once (a compiled model is never pickled) and rolls its chunk out in order, so the output is
in input order and, like every rollout (:mod:`graspgen.sim.lift`), independent of ``jobs``.

Backends (``backend``): ``mujoco``, the CPU rollouts above (the reference; bit-identical across runs and ``jobs``),
or ``warp`` (:mod:`graspgen.sim.warp_backend`, the ``warp`` extra): the same model on MuJoCo Warp, ``warp.nworld``
grasps at once in one process (a GPU, or Warp's CPU device), for every protocol; float32
with a contact order that is not fixed, so a grasp on the edge of a rule can be labelled differently than on the CPU
or in another warp run (``bench/bench_warp.py`` measures both). The table's metadata names the backend.

Output: one row per input grasp, in input order (:data:`graspgen.workflows.evaluate_columns.SCHEMA`).

Robustness (``robustness=RobustnessParams(...)``, ``gen evaluate --robustness N``): every grasp whose nominal
outcome is 5 is rolled out again as ``num_perturbations`` perturbed copies, by the robustness stage's own function
(:func:`graspgen.workflows.robustness.grasp_robustness`, so the same perturbation model: TCP pose noise in the TCP
frame, the object's mass, centre of mass and friction, and with ``object_noise`` its planar pose), in the same world
and protocol as the nominal rollout. The draws are made up front from one generator, ``(n, num_perturbations,
DRAWS_PER_COPY)`` standard normals in input order (for every grasp, successful or not), as the stage does; the
generator is the ``rng`` given, else seeded from a SHA-256 of the poses, widths and settings (:func:`content_seed`;
the seed is in the metadata). The copies of a grasp depend only on its draws, so the labels are the same for any
``jobs``. Extra columns: :data:`graspgen.workflows.evaluate_columns.ROBUSTNESS_FIELDS`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from graspgen.grippers import load_gripper
from graspgen.quality.epsilon import EpsilonParams, ObjectGeometry
from graspgen.quality.perturbation import DRAWS_PER_COPY, RobustnessParams
from graspgen.sim.object_world import world_simulator, world_spec
from graspgen.sim.protocols import Outcome, RolloutResult
from graspgen.sim.scene_model import object_body_name
from graspgen.sim.simulator import SIMULATORS, check_backend, make_simulator
from graspgen.sim.warp_backend import WarpParams
from graspgen.validation import check_instance, check_rng
from graspgen.workflows.evaluate_columns import METADATA_KEY, evaluation_table, with_robustness_columns
from graspgen.workflows.evaluate_settings import EvaluateParams
from graspgen.workflows.evaluation_world import EvaluationWorld, ObjectWorld, evaluation_world
from graspgen.workflows.robustness import grasp_robustness
from graspgen.workflows.robustness_columns import GraspRobustness
from shared_utils.keys import key_view

__all__ = ["content_seed", "evaluate_grasps"]


def evaluate_grasps(
    mesh_path: str | Path, scale: float | None, T_tcp: Any, widths: Any, gripper: str,
    params: EvaluateParams | None = None, *, free_space: bool = True, protocol: str | None = None, jobs: int = 1,
    cache_dir: str | Path | None = None, robustness: RobustnessParams | None = None,
    rng: np.random.Generator | None = None, backend: str = "mujoco", warp: WarpParams | None = None,
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
        Gripper name (:data:`graspgen.grippers.GRIPPERS`) or the path of a gripper file.
    params : EvaluateParams, optional
        Protocol, object properties, CoACD settings; default ``EvaluateParams()``.
    free_space : bool
        True: no support, gravity off until the fingers have closed. False: on a table, in the most probable
        stable pose (module docstring; ``table`` protocol only).
    protocol : str, optional
        ``table``, ``acronym`` or ``graspdatagen`` (module docstring); None: ``params.lift.protocol`` (``table`` by
        default).
    jobs : int
        Worker processes (contiguous chunks of grasps; each builds its own model); <= 0 means one per core.
    cache_dir : str or Path, optional
        Folder of the CoACD cache (``<cache_dir>/coacd``, shared with the objects stage); None: no cache.
    robustness : RobustnessParams, optional
        Also roll out ``robustness.num_perturbations`` perturbed copies of every successful grasp and add
        :data:`~graspgen.workflows.evaluate_columns.ROBUSTNESS_FIELDS` (module docstring); ``robustness.radius`` is
        not computed. None: no copies.
    rng : numpy.random.Generator, optional
        Generator of the copies' draws (``robustness`` only); None: seeded by :func:`content_seed` from the poses,
        widths and settings.
    backend : str
        ``mujoco`` (the CPU, ``jobs`` workers) or ``warp`` (MuJoCo Warp, :mod:`graspgen.sim.warp_backend`: all
        grasps in batches of ``warp.nworld`` parallel worlds in one process; every protocol;
        float32, so labels on the edge of a rule can differ from the CPU's and between runs). The robustness copies
        always run on the CPU.
    warp : WarpParams, optional
        Device and batch of the warp backend; None: ``WarpParams()``.

    Returns
    -------
    pyarrow.Table
        :data:`~graspgen.workflows.evaluate_columns.SCHEMA` (plus ``ROBUSTNESS_FIELDS`` with ``robustness``), ``n``
        rows in input order.

    Raises
    ------
    graspgen.errors.InputError
        The mesh cannot be used (missing, broken, absurd size); the message names the file.
    graspgen.errors.SettingsError
        Unknown gripper (the message lists the choices) or protocol; ``acronym`` or ``graspdatagen`` with
        ``free_space=False``; poses or widths of the wrong shape, non-finite, or not rigid (the message names the
        first bad index); ``params``, ``robustness`` or ``rng`` of the wrong type.
    """
    if robustness is not None:
        check_instance("robustness", robustness, RobustnessParams)
    if rng is not None:
        check_rng("rng", rng)
    ew = evaluation_world(mesh_path, scale, T_tcp, widths, gripper, params, free_space=free_space,
                          protocol=protocol, cache_dir=cache_dir)
    check_backend(backend, ew.world.lift.protocol)
    jobs = (os.cpu_count() or 1) if jobs <= 0 else int(jobs)
    results, backend_meta = _roll_out(ew, backend, warp, jobs)
    table = evaluation_table(ew.T_tcp, ew.width, list(ew.source), results, ew.world.obj.pose)
    info = dict(ew.info)
    info["backend"] = backend
    info.update(backend_meta)
    if robustness is not None:
        table = _with_robustness(table, ew, robustness, rng, jobs, info)
    return table.replace_schema_metadata({METADATA_KEY: json.dumps(info, sort_keys=True)})


def content_seed(world: EvaluationWorld, robustness: RobustnessParams) -> int:
    """Seed (a 64-bit integer) of the robustness draws when no generator is given: the first 8 bytes of a SHA-256 of
    the grasps' poses and widths (float64 bytes) and of the settings (the object's mass, friction, centre of mass
    and pose, the gripper, the protocol and its settings, the robustness settings; canonical JSON). The mesh path
    and the preparation's warnings do not enter: the same grasps and settings give the same draws wherever the
    file lies."""
    settings = {k: v for k, v in world.info.items() if k not in ("mesh", "warnings")}
    settings["lift"] = key_view(world.world.lift)  # renamed settings as they were named: the same draws
    settings["protocol"] = settings["lift"]["protocol"]
    settings["robustness"] = dataclasses.asdict(robustness)
    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(world.T_tcp, dtype="<f8").tobytes())
    digest.update(np.ascontiguousarray(world.width, dtype="<f8").tobytes())
    digest.update(json.dumps(settings, sort_keys=True, default=str).encode())
    return int.from_bytes(digest.digest()[:8], "little")


def _roll_out(ew: EvaluationWorld, backend: str, warp: WarpParams | None,
              jobs: int) -> tuple[list[RolloutResult], dict[str, Any]]:
    """All grasps, in input order, and the backend's metadata: contiguous chunks, one joblib worker and one compiled
    model each; ``jobs`` chunks where the backend gains from workers (the CPU), else one."""
    from joblib import Parallel, delayed

    n = len(ew.T_world)
    workers = jobs if SIMULATORS[backend].parallel_workers else 1
    chunks = [c for c in np.array_split(np.arange(n), max(1, min(workers, n))) if len(c)]
    parts = Parallel(n_jobs=len(chunks) or 1)(
        delayed(_roll_out_chunk)(ew.world, ew.T_world[c], ew.width[c], backend, warp) for c in chunks
    )
    return [r for part, _ in parts for r in part], {k: v for _, meta in parts for k, v in meta.items()}


def _roll_out_chunk(world: ObjectWorld, T_world: np.ndarray, widths: np.ndarray, backend: str,
                    warp: WarpParams | None) -> tuple[list[RolloutResult], dict[str, Any]]:
    """Roll out a chunk of grasps (world-frame TCP poses ``(k, 4, 4)``, widths ``(k,)``) in one freshly compiled
    model (one per worker); the results and the simulator's metadata."""
    simulator = make_simulator(world_spec(world).compile(), world.lift, backend, warp)
    return simulator.rollouts(T_world, widths, object_body_name(0, world.obj.name)), simulator.meta()


def _with_robustness(table: pa.Table, ew: EvaluationWorld, robustness: RobustnessParams,
                     rng: np.random.Generator | None, jobs: int, info: dict[str, Any]) -> pa.Table:
    """``table`` with the robustness columns of its successful grasps (module docstring); notes the settings and
    the seed (when drawn from :func:`content_seed`) in ``info``."""
    from joblib import Parallel, delayed

    robustness = dataclasses.replace(robustness, radius=False)
    if rng is None:
        seed = content_seed(ew, robustness)
        info["robustness_seed"] = seed
        rng = np.random.default_rng(seed)
    info["robustness"] = dataclasses.asdict(robustness)
    draws = rng.standard_normal((len(ew.T_world), robustness.num_perturbations, DRAWS_PER_COPY))
    ok = np.flatnonzero(table.column("outcome").to_numpy() == Outcome.SUCCESS)
    rows: list[GraspRobustness] = []
    if len(ok):
        groups = [c for c in np.array_split(ok, min(jobs, len(ok))) if len(c)]
        found = Parallel(n_jobs=len(groups))(
            delayed(_robustness_chunk)(ew.world, ew.geometry, ew.T_world[c], ew.width[c], draws[c], robustness)
            for c in groups
        )
        rows = [r for part in found for r in part]
    return with_robustness_columns(table, ok, rows)


def _robustness_chunk(world: ObjectWorld, geometry: ObjectGeometry, T_world: np.ndarray, widths: np.ndarray,
                      draws: np.ndarray, params: RobustnessParams) -> list[GraspRobustness]:
    """The perturbed copies of a chunk of successful grasps (world-frame poses ``(k, 4, 4)``, widths ``(k,)``,
    draws ``(k, n, DRAWS_PER_COPY)``), in one freshly compiled model per worker, by the robustness stage's
    :func:`graspgen.workflows.robustness.grasp_robustness` (the copies' epsilon by the default ``EpsilonParams``)."""
    simulator = world_simulator(world)
    gripper = load_gripper(world.gripper)
    body = object_body_name(0, world.obj.name)
    epsilon = EpsilonParams()
    return [grasp_robustness(simulator, T, float(w), body, geometry, world.obj.friction, d, params, epsilon, gripper)
            for T, w, d in zip(T_world, widths, draws)]
