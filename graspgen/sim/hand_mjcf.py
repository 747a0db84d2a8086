"""An MJCF file's kinematic tree as a :class:`~graspgen.sim.hand_tree.HandTree` (:func:`read_mjcf`), read from the
model MuJoCo compiles (so defaults, includes and ``meshdir`` apply as in MuJoCo).

* Bodies are links (the world body is ``world``); a body's hinge or slide joint is its joint (``ref`` and the
  anchor kept), a body without one is fixed to its parent, a free joint is ignored (the hand is placed by graspgen);
  ball joints and bodies with several joints are refused.
* Collision geoms only: a geom with ``contype`` and ``conaffinity`` both 0 is visual and ignored. Boxes, spheres,
  capsules, cylinders, ellipsoids and meshes are read; meshes are decomposed later (MuJoCo would collide their hulls).
* Joint equalities ``q1 = ref1 + a0 + a1 (q2 - ref2)`` (linear polycoef) become mimic joints; the other equalities
  (connect, weld, tendon and non-linear joint couplings: closed kinematic loops, as the Robotiq 2F-85 of MuJoCo
  Menagerie closes each finger's 4-bar) are kept in :attr:`HandTree.loops` with the bodies they tie, for
  :mod:`graspgen.sim.hand_loops` to resolve with MuJoCo; flex equalities are refused.
* Actuators: each one's joints (a joint transmission, or the joints of a fixed tendon) and its force limit on each
  (``forcerange`` x gear x tendon coefficient).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import trimesh

from graspgen.errors import SettingsError
from graspgen.sim.hand_tree import Geom, HandTree, Joint, Link

__all__ = ["read_mjcf"]

_TYPES = {int(mujoco.mjtJoint.mjJNT_HINGE): "revolute", int(mujoco.mjtJoint.mjJNT_SLIDE): "prismatic"}


def _pose(pos, quat) -> np.ndarray:
    T = np.eye(4)
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, dtype=float))
    T[:3, :3] = mat.reshape(3, 3)
    T[:3, 3] = pos
    return T


def _name(model: mujoco.MjModel, kind, idx: int, fallback: str) -> str:
    return mujoco.mj_id2name(model, kind, idx) or fallback


def _surface(model: mujoco.MjModel, g: int, where: str) -> tuple[trimesh.Trimesh, tuple | None, bool]:
    """(surface in the geom frame, box extents or None, convex) of geom ``g``."""
    kind, size = int(model.geom_type[g]), model.geom_size[g]
    G = mujoco.mjtGeom
    if kind == G.mjGEOM_BOX:
        return trimesh.creation.box(extents=2.0 * size), tuple(float(v) for v in 2.0 * size), True
    if kind == G.mjGEOM_SPHERE:
        return trimesh.creation.icosphere(subdivisions=2, radius=float(size[0])), None, True
    if kind == G.mjGEOM_CAPSULE:
        return trimesh.creation.capsule(height=2.0 * float(size[1]), radius=float(size[0]), count=[16, 16]), None, True
    if kind == G.mjGEOM_CYLINDER:
        return trimesh.creation.cylinder(radius=float(size[0]), height=2.0 * float(size[1]), sections=32), None, True
    if kind == G.mjGEOM_ELLIPSOID:
        sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
        sphere.apply_scale(np.asarray(size, dtype=float))
        return sphere, None, True
    if kind == G.mjGEOM_MESH:
        mid = int(model.geom_dataid[g])
        v0, nv = int(model.mesh_vertadr[mid]), int(model.mesh_vertnum[mid])
        f0, nf = int(model.mesh_faceadr[mid]), int(model.mesh_facenum[mid])
        mesh = trimesh.Trimesh(model.mesh_vert[v0:v0 + nv].astype(float), model.mesh_face[f0:f0 + nf], process=True)
        return mesh, None, False
    raise SettingsError(f"{where}: geom type {mujoco.mjtGeom(kind).name} not supported (box, sphere, capsule, "
                        "cylinder, ellipsoid, mesh)")


def _links(model: mujoco.MjModel, path: Path) -> dict[str, Link]:
    links = {}
    for b in range(model.nbody):
        name = _name(model, mujoco.mjtObj.mjOBJ_BODY, b, f"body{b}")
        geoms = []
        for g in range(int(model.body_geomadr[b]), int(model.body_geomadr[b]) + int(model.body_geomnum[b])):
            if model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0:
                continue  # visual only
            if int(model.geom_type[g]) == mujoco.mjtGeom.mjGEOM_PLANE:
                continue
            gname = _name(model, mujoco.mjtObj.mjOBJ_GEOM, g, "")
            mesh, box, convex = _surface(model, g, f"model {path.name}: geom {gname or g} of body {name}")
            geoms.append(Geom(name=gname, pose=_pose(model.geom_pos[g], model.geom_quat[g]), mesh=mesh, box=box,
                              convex=convex))
        links[name] = Link(name=name, geoms=tuple(geoms), mass=float(model.body_mass[b]))
    return links


def _tied_bodies(model: mujoco.MjModel, e: int) -> tuple[str, ...]:
    """The bodies equality ``e`` ties: its two bodies (or sites' bodies), or the bodies of its joints or tendons'
    joints."""
    kind, objs = int(model.eq_type[e]), [int(model.eq_obj1id[e]), int(model.eq_obj2id[e])]
    if kind in (mujoco.mjtEq.mjEQ_CONNECT, mujoco.mjtEq.mjEQ_WELD):
        if int(model.eq_objtype[e]) == mujoco.mjtObj.mjOBJ_SITE:
            objs = [int(model.site_bodyid[o]) for o in objs if o >= 0]
        bodies = [o for o in objs if o >= 0]
    elif kind == mujoco.mjtEq.mjEQ_JOINT:
        bodies = [int(model.jnt_bodyid[o]) for o in objs if o >= 0]
    else:  # tendon
        bodies = [int(model.jnt_bodyid[model.wrap_objid[w]]) for t in objs if t >= 0
                  for w in range(int(model.tendon_adr[t]), int(model.tendon_adr[t]) + int(model.tendon_num[t]))
                  if int(model.wrap_type[w]) == mujoco.mjtWrap.mjWRAP_JOINT]
    return tuple(_name(model, mujoco.mjtObj.mjOBJ_BODY, b, "world" if b == 0 else f"body{b}") for b in bodies)


def _equalities(model: mujoco.MjModel, path: Path) -> tuple[dict[int, tuple[int, float, float]], dict]:
    """(dependent joint id -> (source joint id, multiplier, offset) of the active linear joint equalities,
    equality name -> tied bodies of the other active ones: the loops)."""
    mimics, loops = {}, {}
    for e in range(model.neq):
        if not model.eq_active0[e]:
            continue
        name = _name(model, mujoco.mjtObj.mjOBJ_EQUALITY, e, f"equality {e}")
        kind = int(model.eq_type[e])
        if kind not in (mujoco.mjtEq.mjEQ_CONNECT, mujoco.mjtEq.mjEQ_WELD, mujoco.mjtEq.mjEQ_JOINT,
                        mujoco.mjtEq.mjEQ_TENDON):
            raise SettingsError(f"model {path.name}: equality {name} ({mujoco.mjtEq(kind).name}): graspgen reads "
                                "hands tied by connect, weld, joint and tendon equalities only")
        j1, j2 = int(model.eq_obj1id[e]), int(model.eq_obj2id[e])
        a = model.eq_data[e][:5]
        if kind != mujoco.mjtEq.mjEQ_JOINT or j2 < 0 or np.any(np.abs(a[2:]) > 1e-12):
            loops[name] = _tied_bodies(model, e)
            continue
        ref1, ref2 = float(model.qpos0[model.jnt_qposadr[j1]]), float(model.qpos0[model.jnt_qposadr[j2]])
        mimics[j1] = (j2, float(a[1]), ref1 + float(a[0]) - float(a[1]) * ref2)
    return mimics, loops


def _joints(model: mujoco.MjModel, path: Path, mimics: dict) -> list[Joint]:
    out = []
    for b in range(1, model.nbody):
        name = _name(model, mujoco.mjtObj.mjOBJ_BODY, b, f"body{b}")
        parent = _name(model, mujoco.mjtObj.mjOBJ_BODY, int(model.body_parentid[b]), "world")
        origin = _pose(model.body_pos[b], model.body_quat[b])
        ids = [j for j in range(int(model.body_jntadr[b]), int(model.body_jntadr[b]) + int(model.body_jntnum[b]))
               if int(model.jnt_type[j]) != mujoco.mjtJoint.mjJNT_FREE]
        if not ids:
            out.append(Joint(name=f"{name}_fixed", type="fixed", parent=parent, child=name, origin=origin,
                             axis=np.array([1.0, 0.0, 0.0])))
            continue
        if len(ids) > 1 or int(model.jnt_type[ids[0]]) not in _TYPES:
            raise SettingsError(f"model {path.name}: body {name}: graspgen reads one hinge or slide joint per body")
        j = ids[0]
        limited = bool(model.jnt_limited[j])
        mimic = mimics.get(j)
        out.append(Joint(
            name=_name(model, mujoco.mjtObj.mjOBJ_JOINT, j, f"joint{j}"), type=_TYPES[int(model.jnt_type[j])],
            parent=parent, child=name, origin=origin, axis=np.asarray(model.jnt_axis[j], dtype=float),
            lower=float(model.jnt_range[j][0]) if limited else -np.inf,
            upper=float(model.jnt_range[j][1]) if limited else np.inf,
            effort=float(np.abs(model.jnt_actfrcrange[j]).max()) if model.jnt_actfrclimited[j] else 0.0,
            mimic=None if mimic is None else (_name(model, mujoco.mjtObj.mjOBJ_JOINT, mimic[0], ""), *mimic[1:]),
            anchor=tuple(float(v) for v in model.jnt_pos[j]), ref=float(model.qpos0[model.jnt_qposadr[j]])))
    return out


def _actuators(model: mujoco.MjModel) -> dict:
    out = {}
    for a in range(model.nu):
        gear = abs(float(model.actuator_gear[a][0]))
        limit = float(np.abs(model.actuator_forcerange[a]).max()) if model.actuator_forcelimited[a] else 0.0
        target = int(model.actuator_trnid[a][0])
        if int(model.actuator_trntype[a]) == mujoco.mjtTrn.mjTRN_JOINT:
            wraps = [(target, 1.0)]
        elif int(model.actuator_trntype[a]) == mujoco.mjtTrn.mjTRN_TENDON:
            adr, num = int(model.tendon_adr[target]), int(model.tendon_num[target])
            wraps = [(int(model.wrap_objid[w]), float(model.wrap_prm[w])) for w in range(adr, adr + num)
                     if int(model.wrap_type[w]) == mujoco.mjtWrap.mjWRAP_JOINT]
        else:
            continue
        joints = tuple(_name(model, mujoco.mjtObj.mjOBJ_JOINT, j, "") for j, _ in wraps)
        force = min(limit * gear * abs(c) for _, c in wraps) if wraps else 0.0
        out[_name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a, f"actuator{a}")] = (joints, force)
    return out


def _mesh_files(path: Path) -> list[str]:
    spec = mujoco.MjSpec.from_file(str(path))
    folder = path.parent / (spec.meshdir or "")
    return [str((folder / m.file).resolve()) for m in spec.meshes if m.file]


def read_mjcf(path: str | Path) -> HandTree:
    """The :class:`HandTree` of an MJCF file (module docstring). :class:`SettingsError` on what it cannot read."""
    path = Path(path)
    try:
        model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:
        raise SettingsError(f"model {path}: MuJoCo cannot load it ({' '.join(str(exc).split())})") from None
    mimics, loops = _equalities(model, path)
    return HandTree(path=str(path), links=_links(model, path), joints=tuple(_joints(model, path, mimics)),
                    files=(str(path), *_mesh_files(path)), actuators=_actuators(model), loops=loops)
