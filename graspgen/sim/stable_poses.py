"""Step 6 of mesh preparation, the physics: each candidate resting pose dropped 1 mm onto a plane in MuJoCo.

:func:`stable_poses` chains the geometry of :mod:`graspgen.geometry.stable_poses` (the quasi-static candidates, the
merge of settled faces, the final poses) with the drop of every candidate here (:func:`build_settle_model`,
:func:`settle_pose`). Lengths in m, times in s, speeds in m/s and rad/s; poses are 4x4 mesh-frame-to-world
transforms resting on z = 0.
"""

from __future__ import annotations

import mujoco
import numpy as np
import trimesh

from graspgen.geometry.mass import MassProperties
from graspgen.geometry.mesh_io import _label
from graspgen.geometry.stable_poses import (
    StablePoseParams,
    check_parts,
    merge_settled,
    pose_candidates,
    resting_poses,
    resting_transform,
)
from graspgen.sim.settle import SettleResult

__all__ = ["build_settle_model", "settle_drops", "settle_pose", "stable_poses"]

# Drop height for the settle check: enough that no contact starts in penetration, small enough not to bounce.
_SETTLE_DROP_HEIGHT = 1e-3  # m

# After settling, an object moving slower than this has not toppled. The limits are loose on purpose: a
# faceted solid of revolution on its side (a can, a cone) keeps rolling slowly after the 1 mm drop because
# nothing but facet edges resists rolling, yet it is resting on its side; its settled face is taken as its pose.
# A body still faster than this after settle_time is tumbling off its pose.
_REST_LINEAR_SPEED = 2e-2  # m/s
_REST_ANGULAR_SPEED = 0.3  # rad/s


def build_settle_model(
    parts: list[tuple[np.ndarray, np.ndarray]] | tuple, mass: MassProperties, params: StablePoseParams
) -> mujoco.MjModel:
    """MuJoCo model of the object as a free body of convex mesh geoms above a ground plane.

    Mass and inertia come from ``mass`` (not from the geoms), so the dynamics match the analysis. The body
    frame is the mesh frame. Options: ``params.timestep``, elliptic friction cones, impratio 10.

    Raises
    ------
    SettingsError
        ``parts`` is empty or a part is not ``(vertices (v, 3), faces (f, 3))``.
    """
    check_parts(parts, "parts")
    spec = mujoco.MjSpec()
    spec.modelname = "settle"
    spec.option.timestep = params.timestep
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = 10.0
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    friction = [params.friction, 0.005, 0.0001]
    spec.worldbody.add_geom(name="ground", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0.0, 0.0, 1.0], friction=friction)
    body = spec.worldbody.add_body(name="object")
    body.add_freejoint(name="free")
    body.explicitinertial = True
    body.mass = mass.mass
    body.ipos = mass.center_of_mass
    inertia = mass.inertia
    body.fullinertia = [inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2]]
    for i, (vertices, faces) in enumerate(parts):
        spec.add_mesh(
            name=f"part_{i}",
            uservert=np.asarray(vertices, dtype=np.float64).ravel().tolist(),
            userface=np.asarray(faces, dtype=np.int32).ravel().tolist(),
        )
        body.add_geom(name=f"part_{i}", type=mujoco.mjtGeom.mjGEOM_MESH, meshname=f"part_{i}", friction=friction)
    return spec.compile()


def settle_pose(
    model: mujoco.MjModel, transform: np.ndarray, params: StablePoseParams, data: mujoco.MjData | None = None
) -> SettleResult:
    """Drop the object from ``transform`` lifted by 1 mm and simulate ``params.settle_time``.

    Parameters
    ----------
    model
        From :func:`build_settle_model`.
    transform
        ``(4, 4) float`` mesh-to-world pose resting on z = 0.
    params
        Only ``settle_time`` is read here (timestep and friction are baked into ``model``).
    data
        Reused scratch state; it is fully reset, so reuse never changes the result.

    Returns
    -------
    SettleResult
        One object: its final pose, its speeds at the last step (not window means) and ``at_rest``: the state is
        finite and the object moves slower than 2 cm/s and 0.3 rad/s (loose on purpose: a faceted can on its side
        keeps rolling slowly on its facet edges yet rests on its side).
    """
    data = mujoco.MjData(model) if data is None else data
    mujoco.mj_resetData(model, data)
    transform = np.asarray(transform, dtype=np.float64)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(transform[:3, :3]).ravel())
    data.qpos[:3] = transform[:3, 3] + (0.0, 0.0, _SETTLE_DROP_HEIGHT)
    data.qpos[3:7] = quat
    steps = max(1, int(round(params.settle_time / model.opt.timestep)))
    mujoco.mj_step(model, data, nstep=steps)
    body = model.body("object").id
    pose = np.eye(4)
    pose[:3, :3] = np.array(data.xmat[body], dtype=np.float64).reshape(3, 3)
    pose[:3, 3] = np.array(data.xpos[body], dtype=np.float64)
    linear_speed = float(np.linalg.norm(data.qvel[:3]))
    angular_speed = float(np.linalg.norm(data.qvel[3:6]))
    at_rest = bool(
        np.isfinite(pose[:3, :3]).all() and linear_speed < _REST_LINEAR_SPEED and angular_speed < _REST_ANGULAR_SPEED
    )
    return SettleResult(
        time=float(data.time),
        at_rest=at_rest,
        linear_speed=np.array([linear_speed]),
        angular_speed=np.array([angular_speed]),
        poses=pose[None],
    )


def settle_drops(
    parts: list[tuple[np.ndarray, np.ndarray]] | tuple,
    mass: MassProperties,
    transforms: np.ndarray,
    params: StablePoseParams,
) -> tuple[np.ndarray, np.ndarray]:
    """Drop the object from each of ``transforms (k, 4, 4)`` (:func:`settle_pose`, one model compiled, reset per drop).

    Returns
    -------
    rotations : (k, 3, 3) float64
        Each drop's final mesh-to-world rotation (non-finite where the simulation diverged).
    at_rest : (k,) bool
        Whether each drop came to rest.
    """
    model = build_settle_model(parts, mass, params)
    data = mujoco.MjData(model)
    results = [settle_pose(model, transform, params, data) for transform in transforms]
    rotations = np.array([r.poses[0, :3, :3] for r in results], dtype=np.float64).reshape(-1, 3, 3)
    return rotations, np.array([r.at_rest for r in results], dtype=bool)


def stable_poses(
    mesh: trimesh.Trimesh,
    mass: MassProperties,
    parts: list[tuple[np.ndarray, np.ndarray]] | tuple,
    params: StablePoseParams,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Poses in which the object rests on a table, with the probability of landing in each.

    The candidates of :func:`~graspgen.geometry.stable_poses.pose_candidates`; with ``params.settle_check`` each is
    dropped 1 mm in MuJoCo (convex ``parts``, mass and inertia from ``mass``: :func:`settle_drops`) and replaced by
    the face it settled onto, unrested ones dropped and equal ones merged
    (:func:`~graspgen.geometry.stable_poses.merge_settled`). At most ``max_poses`` poses are returned, most probable
    first, probabilities renormalised to sum to 1.

    Parameters
    ----------
    mesh
        Repaired mesh in m.
    mass
        Its mass properties.
    parts
        Convex parts from :func:`~graspgen.geometry.convex.convex_decomposition` (only used by the settle check).
    params
        Settings.
    rng
        Random generator; only drawn from when ``params.com_sigma > 0``.

    Returns
    -------
    transforms : (n, 4, 4) float64
        Mesh-to-world transforms resting the object on z = 0 (lowest hull vertex at z = 0, centre of mass above
        the origin), n >= 1.
    probabilities : (n,) float64
        Sum to 1, descending.

    Raises
    ------
    InputError
        The centre of mass is not inside the convex hull.
    SettingsError
        Arguments of the wrong kind, or bad ``parts`` with ``settle_check``.
    """
    normals, probs = pose_candidates(mesh, mass, params, rng)
    hull = mesh.convex_hull
    if params.settle_check:
        com = np.asarray(mass.center_of_mass)
        starts = np.array([resting_transform(hull.vertices, com, n) for n in normals]).reshape(-1, 4, 4)
        rotations, at_rest = settle_drops(parts, mass, starts, params)
        normals, probs = merge_settled(hull, normals, probs, rotations, at_rest, params, _label(mesh))
    return resting_poses(hull, mass, normals, probs, params)
