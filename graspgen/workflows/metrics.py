"""Stage 6, ``metrics``: the epsilon, force closure, friction and contact-noise labels of every grasp of a scene.

One task per scene (inputs rollouts, grasps, scenes, objects). For every grasp of the grasps table one contact set is
picked by the rule of :mod:`graspgen.quality.contact_set` (the rollout's contacts at the end of closing when both jaws
touched, else ray-cast closing contacts, else none), and labelled with the contact model of
:mod:`graspgen.quality.epsilon` and the contact noise of :mod:`graspgen.quality.contact_noise`.

Centre of mass from the object record; ``torque_scale`` = the largest distance of a mesh vertex from it
(:func:`object_geometry`). Friction: ``epsilon.friction``, or the object's friction in the scene when null (the
coefficient the simulation used for gripper-object contacts). The GraspNet-style label is the smallest coefficient of
``closure_frictions`` at which the grasp is in force closure (epsilon > 0).

Output per scene: one Parquet table, one row per grasp of the grasps table, joined on ``(scene_id, grasp_id)``:

====================  ========  ================================================================================
column                type      meaning
====================  ========  ================================================================================
scene_id, grasp_id    string,   the grasp
                      int32
epsilon               float64   Ferrari-Canny epsilon (unit-free, L1: unit total normal force); 0 when not in
                                force closure
contact_source        string    ``rollout``, ``raycast`` or ``none`` (see above)
num_contacts          int32     contact points the epsilon was computed from (0 for ``none``)
friction              float64   Coulomb coefficient of the friction cones
min_closure_friction  float64   smallest of ``closure_frictions`` with epsilon > 0; NaN when none is
torque_scale          float64   the object's largest vertex distance from its centre of mass, m
pfc_contact           float64   fraction of the ``num_contact_samples`` perturbed contact sets with epsilon >
                                ``epsilon_delta``, in [0, 1]; 0 for ``none``
epsilon_robust        float64   mean epsilon over the perturbed contact sets (Dex-Net's robust epsilon); 0 for
                                ``none``
====================  ========  ================================================================================

Randomness: the stage draws all contact noise for a scene up front from the task's generator,
``(grasps, num_contact_samples, 13)`` values in grasp order (for every grasp, with contacts or not;
:func:`graspgen.quality.contact_noise.contact_noise_draws`), so a grasp's noise depends only on the task key and its
row.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import pyarrow as pa
import trimesh

from graspgen.errors import InputError
from graspgen.geometry.contacts import ClosingContacts, closing_contacts
from graspgen.grippers import GripperSpec, load_gripper
from graspgen.io.arrow import column_array, list_rows
from graspgen.io.objects import ObjectRecord
from graspgen.io.scenes import SceneRecord
from graspgen.quality.contact_noise import MetricsParams, contact_noise_draws, contact_robustness
from graspgen.quality.contact_set import contact_set
from graspgen.quality.epsilon import EpsilonParams, ObjectGeometry, min_closure_friction

__all__ = ["SCHEMA", "check_joined", "object_geometry", "raycast_contacts", "scene_metrics"]


SCHEMA = pa.schema(
    [
        ("scene_id", pa.string()),
        ("grasp_id", pa.int32()),
        ("epsilon", pa.float64()),
        ("contact_source", pa.string()),
        ("num_contacts", pa.int32()),
        ("friction", pa.float64()),
        ("min_closure_friction", pa.float64()),
        ("torque_scale", pa.float64()),
        ("pfc_contact", pa.float64()),
        ("epsilon_robust", pa.float64()),
    ]
)
"""The metrics table's schema (see the module docstring)."""


def object_geometry(record: ObjectRecord) -> ObjectGeometry:
    """:class:`~graspgen.quality.epsilon.ObjectGeometry` of an object record
    (:func:`graspgen.io.objects.read_object`)."""
    vertices = np.asarray(record.vertices, dtype=np.float64)
    com = np.asarray(record.center_of_mass, dtype=np.float64).reshape(3)
    d = vertices - com
    scale = math.sqrt(float(np.einsum("ij,ij->i", d, d).max()))
    if not scale > 0:
        raise InputError(f"{record.name}: torque scale is 0 (all vertices at the centre of mass)")
    return ObjectGeometry(trimesh.Trimesh(vertices, np.asarray(record.faces), process=False), com, scale)


def check_joined(grasps: pa.Table, other: pa.Table, stage: str) -> None:
    """Raise InputError unless ``other`` has one row per grasp of ``grasps``, in the same order."""
    if other.column("grasp_id").to_pylist() != grasps.column("grasp_id").to_pylist():
        sid = grasps.column("scene_id")[0].as_py() if len(grasps) else "?"
        raise InputError(f"{stage} table of {sid}: its grasp ids do not match the grasps table's")


def raycast_contacts(
    grasps: pa.Table, rows: Sequence[int], geometries: Mapping[str, ObjectGeometry], gripper: GripperSpec,
    params: EpsilonParams,
) -> dict[int, ClosingContacts]:
    """Ray-cast closing contacts (mesh frame) of the grasps ``rows``, batched per object: ``{row: contacts}``."""
    if not rows:
        return {}
    names = grasps.column("object_name").to_pylist()
    poses = column_array(grasps, "pose_object", (4, 4))
    out: dict[int, ClosingContacts] = {}
    for name in sorted({names[i] for i in rows}):
        idx = [i for i in rows if names[i] == name]
        found = closing_contacts(geometries[name].mesh, poses[idx], gripper, rays_per_side=params.rays_per_side,
                                 tolerance=params.ray_tolerance)
        out.update(zip(idx, found))
    return out


def scene_metrics(
    grasps: pa.Table, rollouts: pa.Table, scene: SceneRecord, records: Mapping[str, ObjectRecord],
    params: MetricsParams, rng: np.random.Generator,
) -> pa.Table:
    """The metrics table of one scene (module docstring): one row per grasp of ``grasps``.

    Parameters
    ----------
    grasps, rollouts : pyarrow.Table
        The scene's grasps and rollouts tables (one rollouts row per grasp, same order).
    scene : SceneRecord
        Gives the objects' settled poses and frictions.
    records : mapping
        Object records by name, for every object the grasps target.
    params : MetricsParams
    rng : numpy.random.Generator
        The contact noise's only source (:func:`~graspgen.quality.contact_noise.contact_noise_draws`, drawn before
        anything else is computed).
    """
    check_joined(grasps, rollouts, "rollouts")
    n = len(grasps)
    draws = contact_noise_draws(rng, n, params.num_contact_samples)
    if n == 0:
        return SCHEMA.empty_table()
    ep = params.epsilon
    gripper = load_gripper(grasps.column("gripper")[0].as_py())
    names = grasps.column("object_name").to_pylist()
    index = grasps.column("object_index").to_numpy()
    geometries = {name: object_geometry(records[name]) for name in sorted(set(names))}
    simulated = rollouts.column("simulated").to_numpy(zero_copy_only=False)
    points = list_rows(rollouts, "contact_points", 3, np.float64)
    normals = list_rows(rollouts, "contact_normals", 3, np.float64)
    fingers = list_rows(rollouts, "contact_fingers", 0, np.int8)
    has_rollout = [bool(simulated[i]) and bool(np.isin((0, 1), fingers[i]).all()) for i in range(n)]
    closed_poses = (column_array(rollouts, "target_pose_closed", (4, 4))
                    if "target_pose_closed" in rollouts.column_names else None)
    rays = raycast_contacts(grasps, [i for i in range(n) if not has_rollout[i]], geometries, gripper, ep)
    cols: dict[str, list] = {name: [] for name in SCHEMA.names[2:]}
    for i in range(n):
        geometry = geometries[names[i]]
        mu = float(scene.friction[index[i]]) if ep.friction is None else ep.friction
        rollout = (points[i], normals[i], fingers[i]) if simulated[i] else None
        # The contacts were taken when closing ended: map them with the object's pose then, not the settled one
        # (the jaws may have pushed it by millimetres and degrees).
        at_closing = closed_poses[i] if closed_poses is not None and np.isfinite(closed_poses[i]).all() else None
        source, p, nrm, f = contact_set(rollout, scene.poses[index[i]] if at_closing is None else at_closing,
                                        rays.get(i))
        if source == "none":
            eps, label, pfc, robust = 0.0, math.nan, 0.0, 0.0
        else:
            pfc, robust = contact_robustness(p, nrm, f, geometry, mu, draws[i], params)
            eps = ep.epsilon(p, nrm, f, geometry, mu)
            label = min_closure_friction(p, nrm, f, geometry.center_of_mass, params.closure_frictions,
                                         torque_scale=geometry.torque_scale, torsional_friction=ep.torsional_friction,
                                         num_cone_edges=ep.num_cone_edges, contact_model=ep.contact_model)
        cols["epsilon"].append(eps)
        cols["contact_source"].append(source)
        cols["num_contacts"].append(len(p))
        cols["friction"].append(mu)
        cols["min_closure_friction"].append(label)
        cols["torque_scale"].append(geometry.torque_scale)
        cols["pfc_contact"].append(pfc)
        cols["epsilon_robust"].append(robust)
    arrays = {"scene_id": grasps.column("scene_id"), "grasp_id": grasps.column("grasp_id")}
    arrays.update({name: pa.array(values, SCHEMA.field(name).type) for name, values in cols.items()})
    return pa.table(arrays, schema=SCHEMA)
