"""The world :func:`graspgen.workflows.evaluate.evaluate_grasps` rolls grasps out in: the object prepared from its
mesh, its opening widths chosen, placed in free space or settled on a table, and the gripper attached.

:func:`evaluation_world` builds it without rolling anything out (to roll one grasp out again exactly as
``evaluate_grasps`` did, or to film it); :class:`EvaluationWorld` holds plain arrays and settings, cheap to pickle to
workers (a compiled model is not).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from graspgen.errors import SettingsError
from graspgen.geometry.contacts import closing_contacts
from graspgen.geometry.stable_poses import StablePoseParams
from graspgen.grippers import GripperSpec, load_gripper
from graspgen.quality.epsilon import ObjectGeometry
from graspgen.sim.lift import LiftSimulator
from graspgen.sim.object_world import ObjectWorld, settled_object_pose, world_simulator, world_warp_simulator
from graspgen.sim.protocol_phases import protocol_of
from graspgen.sim.protocols import LiftParams
from graspgen.sim.scene_model import PlacedObject, object_body_name
from graspgen.sim.warp_backend import WarpLiftSimulator, WarpParams
from graspgen.validation import check_instance, check_transforms
from graspgen.workflows.evaluate_settings import EvaluateParams
from graspgen.workflows.prepare import prepare_object

__all__ = ["OBJECT_NAME", "EvaluationWorld", "ObjectWorld", "evaluation_world"]

OBJECT_NAME = "object"
"""Body name stem of the evaluated object (the body is ``obj/0_object``)."""


@dataclasses.dataclass(frozen=True, eq=False)
class EvaluationWorld:
    """The world :func:`graspgen.workflows.evaluate.evaluate_grasps` rolls grasps out in and the grasps in it
    (:func:`evaluation_world`): plain arrays and settings, cheap to pickle to workers (a compiled model is not)."""

    world: ObjectWorld
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
    """The output table's metadata (:data:`graspgen.workflows.evaluate_columns.METADATA_KEY`)."""

    @property
    def target_body(self) -> str:
        """The object's body name in the model (``obj/0_object``)."""
        return object_body_name(0, self.world.obj.name)

    def simulator(self) -> LiftSimulator:
        """The world compiled with the gripper, in a fresh model: rolls a grasp out as ``evaluate_grasps`` did."""
        return world_simulator(self.world)

    def warp_simulator(self, warp: WarpParams | None = None) -> WarpLiftSimulator:
        """The same world on the warp backend (:class:`graspgen.sim.warp_backend.WarpLiftSimulator`, batches of
        ``warp.nworld`` grasps): ``warp_simulator().rollouts(T_world, target_body)`` rolls them out as
        ``evaluate_grasps`` with ``backend="warp"`` does."""
        return world_warp_simulator(self.world, warp)

    def visual(self) -> tuple[np.ndarray, np.ndarray]:
        """The object's visual mesh, ``(vertices (v, 3) float64 m, faces (f, 3))`` in its frame, for
        :func:`graspgen.sim.object_world.world_spec` (rendering: the joints are the simulator's, so a recorded
        ``qpos`` poses that model)."""
        mesh = self.geometry.mesh
        return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)


def _settings(params: EvaluateParams | None, protocol: str | None, free_space: bool) -> EvaluateParams:
    """``params`` (default ``EvaluateParams()``) with ``protocol`` set; a free-space protocol needs free space."""
    params = EvaluateParams() if params is None else check_instance("params", params, EvaluateParams)
    if protocol is not None:
        params = dataclasses.replace(params, lift=params.lift.with_protocol(protocol))
    if protocol_of(params.lift).free_space and not free_space:
        raise SettingsError(f"protocol: {params.lift.protocol!r} is a free-space protocol (no support plane); use "
                            "'table' with a support")
    return params


def _checked_widths(widths: Any, n: int) -> np.ndarray | None:
    """``(n,) float64`` widths, each finite and >= 0 m; None stays None (find them by ray casting)."""
    if widths is None:
        return None
    widths = np.asarray(widths, dtype=np.float64).reshape(-1)
    if len(widths) != n:
        raise SettingsError(f"widths: expected {n} values (one per pose), got {len(widths)}")
    if not (np.isfinite(widths).all() and (widths >= 0).all()):
        raise SettingsError(f"widths[{int(np.flatnonzero(~(np.isfinite(widths) & (widths >= 0)))[0])}]: must be "
                            "a finite width >= 0 m")
    return widths


def _opening(prepared: Any, T: np.ndarray, widths: np.ndarray | None, spec: GripperSpec, rays_per_side: int,
             lift: LiftParams) -> tuple[np.ndarray, list[str]]:
    """Width per grasp and where it came from (``protocol``, ``input``, ``raycast`` or ``open``)."""
    n = len(T)
    protocol = protocol_of(lift)
    if protocol.free_space:  # the jaws open to the protocol's opening whatever the grasp's width
        opening = spec.max_width if protocol.settings(lift).open_width is None else protocol.settings(lift).open_width
        return np.full(n, float(np.clip(opening, spec.min_width, spec.max_width))), ["protocol"] * n
    if widths is not None:
        return widths, ["input"] * n
    mesh = trimesh.Trimesh(prepared.vertices, prepared.faces, process=False)
    found = np.array([c.width for c in closing_contacts(mesh, T, spec, rays_per_side=rays_per_side)])
    ok = np.isfinite(found)
    return np.where(ok, np.clip(found, 0.0, spec.max_width), spec.max_width), ["raycast" if k else "open" for k in ok]


def _placed_object(prepared: Any, params: EvaluateParams, free_space: bool, lift: LiftParams) -> PlacedObject:
    """The prepared object as a body: its mass (``params.mass`` rescales the inertia: the same shape and uniform
    density), at the origin in free space, else settled on ``params.support`` from its most probable stable pose."""
    mass, inertia = prepared.mass.mass, np.asarray(prepared.mass.inertia)
    if params.mass is not None:
        inertia, mass = inertia * (params.mass / mass), params.mass
    obj = PlacedObject(name=OBJECT_NAME, convex_parts=prepared.convex_parts, mass=float(mass),
                       center_of_mass=np.asarray(prepared.mass.center_of_mass), inertia=inertia, pose=np.eye(4),
                       friction=params.friction)
    if free_space:
        return obj
    return dataclasses.replace(obj, pose=settled_object_pose(
        dataclasses.replace(obj, pose=prepared.stable_transforms[0]), params.support, lift))


def _geometry(prepared: Any) -> ObjectGeometry:
    """The prepared mesh, its centre of mass and torque scale (its largest vertex distance from the centre of mass)."""
    com = np.asarray(prepared.mass.center_of_mass, dtype=np.float64)
    vertices = np.asarray(prepared.vertices, dtype=np.float64)
    torque_scale = float(np.sqrt(np.max(np.sum((vertices - com) ** 2, axis=1))))
    return ObjectGeometry(trimesh.Trimesh(vertices, np.asarray(prepared.faces), process=False), com, torque_scale)


def _info(mesh_path: str | Path, prepared: Any, spec: GripperSpec, world: ObjectWorld, free_space: bool,
          geometry: ObjectGeometry) -> dict[str, Any]:
    """The table's metadata (:data:`graspgen.workflows.evaluate_columns.METADATA_KEY`)."""
    obj, lift = world.obj, world.lift
    return {"mesh": str(mesh_path), "scale": prepared.scale, "gripper": spec.name, "free_space": bool(free_space),
            "protocol": lift.protocol, "lift": lift.to_dict(), "mass": obj.mass, "friction": obj.friction,
            "center_of_mass": geometry.center_of_mass.tolist(), "torque_scale": geometry.torque_scale,
            "convex_parts": len(prepared.convex_parts), "object_pose": obj.pose.tolist(),
            "warnings": list(prepared.warnings)}


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
    """The world :func:`graspgen.workflows.evaluate.evaluate_grasps` rolls the grasps out in, with the grasps placed
    in it, without rolling any out: the object prepared, opened widths chosen, settled on the table
    (``free_space=False``).

    Parameters and errors as ``evaluate_grasps`` (less ``jobs`` and ``robustness``). Use it to roll one grasp out
    again exactly as ``evaluate_grasps`` did (:meth:`EvaluationWorld.simulator`, e.g. to film it:
    :func:`graspgen.viz.evaluate_movie.evaluated_rollout_movie`).

    Returns
    -------
    EvaluationWorld
    """
    params = _settings(params, protocol, free_space)
    spec = load_gripper(gripper)
    T = check_transforms("T_tcp", T_tcp)
    widths = _checked_widths(widths, len(T))
    lift = params.lift
    if protocol_of(lift).lifts:  # the free-space protocols switch gravity themselves
        lift = dataclasses.replace(lift, gravity_until_closed=bool(free_space))
    # Stable poses only matter on a table; in free space skip their MuJoCo settle check (seconds per pose).
    poses = StablePoseParams(settle_check=not free_space, max_poses=1)
    prepared = prepare_object(mesh_path, density=params.density, scale=scale, max_extent=params.max_extent,
                              coacd=params.coacd, poses=poses, rng=np.random.default_rng(0),
                              coacd_cache_dir=None if cache_dir is None else Path(cache_dir) / "coacd")
    width, source = _opening(prepared, T, widths, spec, params.rays_per_side, lift)
    obj = _placed_object(prepared, params, free_space, lift)
    world = ObjectWorld(obj=obj, support=None if free_space else params.support, gripper=str(gripper), lift=lift)
    geometry = _geometry(prepared)
    return EvaluationWorld(world=world, T_tcp=T, T_world=obj.pose @ T, width=np.asarray(width, dtype=np.float64),
                           source=tuple(source), geometry=geometry,
                           info=_info(mesh_path, prepared, spec, world, free_space, geometry))
