"""A second simulator on the calibration grasps: who is the outlier, FleX or MuJoCo?

``studies/fidelity.py`` measures how far our MuJoCo labels are from ACRONYM's FleX labels. Where they disagree, either
simulator may be the one that is off: FleX's code and settings were never published, and ours are choices too. This
script asks a third, independent rigid-body engine, Bullet (``pybullet``: GJK/EPA contact manifolds of up to four
points per pair of convex pieces, a sequential-impulse LCP solver, a Coulomb friction cone), to run the same
``acronym`` protocol on the same grasps with the same geometry, and prints the three pairwise agreements (pooled with
95% bootstrap intervals, the grasps resampled within each object: ``fidelity.kappa_interval``), the agreement in the
strata where MuJoCo and FleX disagree most (the grasps' closed width), and the three-way confusion.

What is the same as ``gen evaluate --protocol acronym`` (:class:`graspgen.sim.protocols.AcronymParams`): the object
(the evaluation's CoACD parts, mass, centre of mass and inertia from
:func:`graspgen.workflows.evaluation_world.evaluation_world`, the file's friction 1.0); the Panda of
``assets/grippers/panda`` (its hand, finger and pad pieces, 70 N, 0.1 m/s of width, 0.04 m per finger open); the
protocol: placed at the grasp with the jaws fully open (any overlap of the open hand with the object: collision),
gravity off while the jaws close until they stop, then gravity along the approach axis, the Hann-windowed shake (15 mm
along the approach, then 0.15 rad about the closing axis, 2 cycles at 4 Hz each), 0.1 s settle; success when both
fingers touch the object at the end, lost as soon as neither does.

Physical parameters as MuJoCo's models: sliding friction from the file, torsional friction 0.005 m at every contact
(``--torsional``), the Panda's fingers geared to move symmetrically (one motor and a rack in the real hand; MuJoCo's
model couples them too), 70 N of grip.

What is Bullet's own: contacts are rigid (no MuJoCo solref/solimp softness; penetration is pushed out by the
solver's error reduction); Bullet inflates every convex piece by its 1 mm collision margin, so each piece is shrunk
by it first (faces moved 1 mm in: the inflated piece has the true faces and rounded edges; ``--inflate X`` makes the
object's pieces X fatter, a what-if); the hand follows its trajectory through a stiff fixed constraint (MuJoCo: a
weld to a mocap body); the jaws are velocity-controlled joints whose motor force saturates at the grip force
(MuJoCo: a damped actuator saturating at it); a jaw touches the object when a manifold point is closer than 0.5 mm.
Time step 1 ms, 100 solver iterations: fewer iterations leave the jaw motors short of their force (50 at 2 ms give
18 N of the 70); against 1 ms with 200 iterations (the same labels as 0.5 ms with 200) they change 0% of 100 bottle
grasps and 2% of 100 example-mug grasps (2 ms with 200: 0% and 5%).

Needs ``pybullet`` (``pip install -e '.[reference]'``); it is not a dependency of the package.

``--impratio 1,...`` also labels the grasps with MuJoCo at other friction-to-normal impedance ratios (ours is 10,
:class:`graspgen.sim.physics.PhysicsOptions`) and compares those labels with FleX's and Bullet's.

Run: ``python -m studies.second_reference [-j 2] [--limit N] [--impratio 1] [--calibration DIR]``; writes
``studies/results_second_reference.json`` (gitignored). ``--from-results FILE`` prints a saved run's per-object and
pooled figures again (with the intervals) without simulating.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh
from joblib import Parallel, delayed
from scipy.spatial.transform import Rotation

from graspgen.grippers import load_gripper
from graspgen.sim.motion import shake_wave
from graspgen.sim.protocols import OUTCOME_NAMES, AcronymParams, LiftParams
from graspgen.workflows.evaluate import evaluate_grasps
from graspgen.workflows.evaluate_settings import EvaluateParams
from graspgen.workflows.evaluation_world import evaluation_world
from studies.calibration import REPO, STUDIES, add_calibration_option, load_cases
from studies.fidelity import kappa, kappa_interval

RESULTS = STUDIES / "results_second_reference.json"
PANDA = REPO / "assets" / "grippers" / "panda"

TIMESTEP = 0.001  # s
SOLVER_ITERATIONS = 100  # fewer leave the jaw motors short of their force: 50 at 2 ms give 18 N of the 70
MARGIN = 0.001  # m, Bullet's collision margin of a mesh piece loaded from a URDF (it inflates the piece by this;
#               changeDynamics(collisionMargin=...) reaches only one piece of a compound, so pieces are shrunk instead)
CHECK_INTERVAL = 0.01  # s between contact checks while shaking (MuJoCo's: every 10 steps of 2 ms)
CLOSE_TIMEOUT = 1.5  # s
STOPPED_SPEED = 0.002  # m/s: a jaw slower than this has stopped
TORSIONAL = 0.005  # m, torsional friction of the contacts (MuJoCo's models: pads and objects 0.005 m)
TOUCH = 0.0005  # m: a manifold point closer than this is a touch (Bullet keeps points up to 2 cm apart)
HOLD_FORCE = 2000.0  # N, the fixed constraint that carries the hand along its trajectory

COLLISION_WITH_TARGET, NO_CONTACT, LOST, SUCCESS = 1, 3, 4, 5


def mesh_pieces(path: Path) -> list[np.ndarray]:
    """The convex pieces of one of the gripper's OBJ files (one ``o`` group each), vertices ``(v, 3)`` m."""
    scene = trimesh.load(path, process=False, split_object=True, group_material=False)
    geoms = list(scene.geometry.values()) if isinstance(scene, trimesh.Scene) else [scene]
    return [np.asarray(g.vertices, dtype=float) for g in geoms]


def shrunk_hull(vertices: np.ndarray, margin: float) -> tuple[np.ndarray, float]:
    """Vertices ``(k, 3)`` of the convex hull of ``vertices`` with every face moved ``margin`` inwards, so that
    Bullet's margin (a sphere of that radius swept over the piece) gives back the piece's faces (Bullet's own remedy,
    ``btConvexHullComputer``'s shrink). A piece thinner than ``2 * margin`` is shrunk as far as it goes (to just
    inside its Chebyshev ball); returns the vertices and the shrink used (m)."""
    from scipy.optimize import linprog
    from scipy.spatial import ConvexHull, HalfspaceIntersection
    hull = ConvexHull(np.asarray(vertices, float))
    eq = np.unique(np.round(hull.equations, 12), axis=0)  # unit normals n, offsets b: n.x + b <= 0 inside
    # Chebyshev centre: max r with n.x + b + r <= 0 for every face
    res = linprog([0, 0, 0, -1], A_ub=np.c_[eq[:, :3], np.ones(len(eq))], b_ub=-eq[:, 3],
                  bounds=[(None, None)] * 3 + [(0, None)], method="highs")
    centre, radius = res.x[:3], float(res.x[3])
    shrink = min(margin, 0.98 * radius)
    planes = eq.copy()
    planes[:, 3] += shrink
    points = HalfspaceIntersection(planes, centre).intersections
    return ConvexHull(points).points[ConvexHull(points).vertices], shrink


def _quat_xyzw(R: np.ndarray) -> list[float]:
    """Bullet's (x, y, z, w) quaternion of a rotation matrix."""
    return Rotation.from_matrix(R).as_quat().tolist()


def _link(name: str, mass: float, com, axes: np.ndarray, moments, collisions: str) -> str:
    """A URDF link: inertial frame at ``com`` along ``axes`` (columns) with principal ``moments``."""
    rpy = " ".join(f"{x:.9g}" for x in Rotation.from_matrix(axes).as_euler("xyz"))
    xyz = " ".join(f"{x:.9g}" for x in com)
    ixx, iyy, izz = (f"{x:.9g}" for x in moments)
    return (f"<link name='{name}'><inertial><origin xyz='{xyz}' rpy='{rpy}'/><mass value='{mass:.9g}'/>"
            f"<inertia ixx='{ixx}' iyy='{iyy}' izz='{izz}' ixy='0' ixz='0' iyz='0'/></inertial>{collisions}</link>")


class BulletAcronym:
    """The ``acronym`` protocol in Bullet for one object; one instance per worker process (its own client)."""

    def __init__(self, parts, mass: float, com: np.ndarray, inertia: np.ndarray, friction: float, *,
                 timestep: float = TIMESTEP, iterations: int = SOLVER_ITERATIONS, inflate: float = 0.0,
                 torsional: float = TORSIONAL) -> None:
        import pybullet as pb
        from pybullet_utils.bullet_client import BulletClient
        self.pb = pb
        self.c = BulletClient(connection_mode=pb.DIRECT)
        self.dt, self.iterations, self.friction, self.torsional = timestep, iterations, friction, torsional
        gripper = load_gripper("panda")
        self.grip_force = float(gripper.force_limit)
        self.finger_speed = float(gripper.closing_speed) / 2.0
        self.stroke = float(gripper.max_width - gripper.min_width) / 2.0
        self.tcp_offset = float(gripper.tcp_offset)
        acr = AcronymParams()
        self.shake_z = shake_wave(acr.shake_amplitude, acr.shake_frequency, acr.shake_cycles, timestep)
        self.shake_angle = shake_wave(acr.shake_angle, acr.shake_frequency, acr.shake_cycles, timestep)
        self.settle_steps = int(round(acr.settle_time / timestep))

        self._tmp = tempfile.TemporaryDirectory(prefix="bullet-hulls-")
        self._files = 0
        self.unshrunk = 0  # pieces thinner than twice the margin: Bullet sees them up to a margin fatter
        moments, axes = np.linalg.eigh(np.asarray(inertia, float))
        if np.linalg.det(axes) < 0:
            axes[:, 2] *= -1
        # Bullet places a body by its inertial frame: at rest in the mesh frame that is (com, principal axes).
        self.obj_rest = (np.asarray(com, float).tolist(), _quat_xyzw(axes))
        obj_link = _link("object", mass, com, axes, moments, self._collisions([v for v, _ in parts], inflate))
        self.obj_urdf = self._urdf("object", f"<robot name='object'>{obj_link}</robot>")

        # Gripper: the hand (base, hand frame), per side a prismatic finger carrying its link and pad pieces; the
        # left one is the right one turned 180 deg about z. Joint q = 0 open, q = stroke closed.
        finger = mesh_pieces(PANDA / "finger.obj") + mesh_pieces(PANDA / "pad.obj")
        flip = np.diag([-1.0, -1.0, 1.0])
        m_f = float(gripper.finger_mass)
        links = [_link("hand", float(gripper.body_mass), np.zeros(3), np.eye(3), np.full(3, 1e-3),
                       self._collisions(mesh_pieces(PANDA / "hand.obj")))]
        joints = []
        for side, R in (("right", np.eye(3)), ("left", flip)):
            links.append(_link(side, m_f, np.zeros(3), np.eye(3), np.full(3, 1e-6),
                               self._collisions([v @ R.T for v in finger])))
            axis = " ".join(f"{x:g}" for x in R @ [-1.0, 0.0, 0.0])
            joints.append(f"<joint name='{side}' type='prismatic'><parent link='hand'/><child link='{side}'/>"
                          f"<axis xyz='{axis}'/><limit lower='0' upper='{self.stroke:.6f}' "
                          f"effort='{self.grip_force:g}' velocity='1'/></joint>")
        text = "<robot name='panda'>\n" + "\n".join(links + joints) + "\n</robot>"
        self.gripper_urdf = self._urdf("panda", text)
        self.jaws = (0, 1)
        self.sides = ({0}, {1})

    def _build(self) -> None:
        """A new world with the object and the hand at rest. Every rollout starts in one: in a world reused with its
        bodies reset (even through saveState / restoreState), the contact cache and warm starts a rollout leaves
        change the next one's label (3 of 120 grasps, measured)."""
        c, pb = self.c, self.pb
        c.resetSimulation()
        c.setPhysicsEngineParameter(fixedTimeStep=self.dt, numSolverIterations=self.iterations,
                                    enableConeFriction=1, deterministicOverlappingPairs=1)
        c.setGravity(0, 0, 0)
        self.obj = c.loadURDF(self.obj_urdf, *self.obj_rest, flags=pb.URDF_USE_INERTIA_FROM_FILE)
        # Bullet combines friction as a product and torsional friction as spinning_a * friction_b + spinning_b *
        # friction_a: the gripper's sliding 1.0 and spinning 0 leave the object's values, MuJoCo's models' (sliding
        # from the file, torsional 0.005 m on pads and objects, graspgen.sim.gripper_model).
        c.changeDynamics(self.obj, -1, lateralFriction=self.friction, spinningFriction=self.torsional,
                         rollingFriction=0.0, linearDamping=0.0, angularDamping=0.0)
        self.gripper = c.loadURDF(self.gripper_urdf, flags=pb.URDF_USE_INERTIA_FROM_FILE)
        for link in (-1, 0, 1):
            c.changeDynamics(self.gripper, link, lateralFriction=1.0, spinningFriction=0.0, rollingFriction=0.0,
                             linearDamping=0.0, angularDamping=0.0)
        # The Panda's fingers are geared together (one motor, a rack): the jaws move symmetrically, as MuJoCo's model
        # couples them; uncoupled, the pair drifts sideways under two equal motors.
        gear = c.createConstraint(self.gripper, 0, self.gripper, 1, pb.JOINT_GEAR, [1, 0, 0], [0, 0, 0], [0, 0, 0])
        c.changeConstraint(gear, gearRatio=-1.0, maxForce=10.0 * self.grip_force, erp=0.2)
        self.hold = c.createConstraint(self.gripper, -1, -1, -1, pb.JOINT_FIXED, [0, 0, 0], [0, 0, 0], [0, 0, 0])
        c.changeConstraint(self.hold, maxForce=HOLD_FORCE)

    # -- helpers ---------------------------------------------------------------------------------------------------

    def _collisions(self, pieces: list[np.ndarray], inflate: float = 0.0) -> str:
        """URDF ``<collision>`` elements of convex pieces, one OBJ file a hull (Bullet takes meshes as files), each
        acting ``inflate`` (m) fatter than it is."""
        out = []
        for vertices in pieces:
            name = os.path.join(self._tmp.name, f"hull{self._files}.obj")
            self._files += 1
            inner, shrink = shrunk_hull(vertices, MARGIN - inflate)
            self.unshrunk += shrink < MARGIN - inflate - 1e-9
            trimesh.convex.convex_hull(inner).export(name)
            out.append(f'<collision><geometry><mesh filename="{name}"/></geometry></collision>')
        return "\n".join(out)

    def _urdf(self, name: str, text: str) -> str:
        path = os.path.join(self._tmp.name, f"{name}.urdf")
        Path(path).write_text(text)
        return path

    def _hand_pose(self, T_tcp: np.ndarray) -> tuple[list[float], list[float]]:
        R = T_tcp[:3, :3]
        return (T_tcp[:3, 3] - self.tcp_offset * R[:, 2]).tolist(), _quat_xyzw(R)

    def _drive(self, T_tcp: np.ndarray) -> None:
        pos, orn = self._hand_pose(T_tcp)
        self.c.changeConstraint(self.hold, jointChildPivot=pos, jointChildFrameOrientation=orn, maxForce=HOLD_FORCE)

    def _jaws_on(self) -> tuple[bool, bool]:
        links = {p[3] for p in self.c.getContactPoints(bodyA=self.gripper, bodyB=self.obj) if p[8] < TOUCH}
        return bool(links & self.sides[0]), bool(links & self.sides[1])

    def _object_pose(self) -> tuple[np.ndarray, np.ndarray]:
        p, q = self.c.getBasePositionAndOrientation(self.obj)
        return np.asarray(p), np.asarray(self.c.getMatrixFromQuaternion(q)).reshape(3, 3)

    # -- the protocol ----------------------------------------------------------------------------------------------

    def rollout(self, T_tcp: np.ndarray) -> dict:
        """One grasp (TCP pose in the object's mesh frame, which is the world here); returns its code and motion."""
        c, pb = self.c, self.pb
        self._build()
        c.resetBasePositionAndOrientation(self.obj, *self.obj_rest)
        c.resetBaseVelocity(self.obj, [0, 0, 0], [0, 0, 0])
        pos, orn = self._hand_pose(T_tcp)
        c.resetBasePositionAndOrientation(self.gripper, pos, orn)
        c.resetBaseVelocity(self.gripper, [0, 0, 0], [0, 0, 0])
        for jaw in self.jaws:
            c.resetJointState(self.gripper, jaw, 0.0, 0.0)
            c.setJointMotorControl2(self.gripper, jaw, pb.VELOCITY_CONTROL, targetVelocity=0.0, force=self.grip_force)
        self._drive(T_tcp)
        c.performCollisionDetection()
        if c.getClosestPoints(self.gripper, self.obj, distance=0.0):
            return {"code": COLLISION_WITH_TARGET, "motion_closing": [math.nan, math.nan]}
        p0, R0 = self._object_pose()
        # close until both jaws stop (or the timeout)
        for jaw in self.jaws:
            c.setJointMotorControl2(self.gripper, jaw, pb.VELOCITY_CONTROL, targetVelocity=self.finger_speed,
                                    force=self.grip_force)
        steps, slow = 0, 0
        while steps * self.dt < CLOSE_TIMEOUT:
            c.stepSimulation()
            steps += 1
            v = [c.getJointState(self.gripper, jaw)[1] for jaw in self.jaws]
            slow = slow + 1 if steps * self.dt > 0.02 and max(abs(x) for x in v) < STOPPED_SPEED else 0
            if slow * self.dt >= 0.01:
                break
        p1, R1 = self._object_pose()
        motion = [float(np.linalg.norm(p1 - p0)),
                  float(np.arccos(np.clip((np.trace(R0.T @ R1) - 1) / 2, -1, 1)))]
        if not all(self._jaws_on()):
            return {"code": NO_CONTACT, "motion_closing": motion}
        # gravity along the approach axis, then the shake along the approach and about the closing axis
        g = 9.81 * T_tcp[:3, 2]
        c.setGravity(*g.tolist())
        R, x, z = T_tcp[:3, :3], T_tcp[:3, 0], T_tcp[:3, 2]
        hand_p, hand_q = self._hand_pose(T_tcp)
        poses = [((T_tcp[:3, 3] + dz * z - self.tcp_offset * z).tolist(), hand_q) for dz in self.shake_z]
        turns = Rotation.from_rotvec(self.shake_angle[:, None] * x[None, :]) * Rotation.from_matrix(R)
        base = T_tcp[:3, 3][None, :] - self.tcp_offset * turns.as_matrix()[:, :, 2]  # rotation about the TCP
        poses += list(zip(base.tolist(), turns.as_quat().tolist()))
        poses += [(hand_p, hand_q)] * self.settle_steps
        every = max(1, round(CHECK_INTERVAL / self.dt))
        for i, (p, q) in enumerate(poses):
            c.changeConstraint(self.hold, jointChildPivot=p, jointChildFrameOrientation=q, maxForce=HOLD_FORCE)
            c.stepSimulation()
            if (i + 1) % every == 0 and not any(self._jaws_on()):
                return {"code": LOST, "motion_closing": motion}
        return {"code": SUCCESS if all(self._jaws_on()) else LOST, "motion_closing": motion}


def _run_chunk(world_args: dict, T: np.ndarray, settings: dict) -> list[dict]:
    sim = BulletAcronym(**world_args, **settings)
    return [sim.rollout(t) for t in T]


def acronym_world(case, T: np.ndarray, cache_dir: Path) -> tuple[dict, np.ndarray]:
    """What ``gen evaluate --protocol acronym`` simulates for the case's grasps ``T`` ``(n, 4, 4)``: the object as
    keyword arguments of another engine's world (``parts``: the evaluation's convex pieces, ``mass``, ``com``,
    ``inertia`` about it, ``friction``; mesh frame, m, kg) and the TCP poses in that frame ``(n, 4, 4)``."""
    params = EvaluateParams(lift=LiftParams(protocol="acronym"), friction=case.friction, mass=case.mass,
                            density=case.density if case.density is not None else 700.0)
    world = evaluation_world(case.mesh, case.scale, T, None, "panda", params, protocol="acronym",
                             cache_dir=cache_dir)
    obj = world.world.obj
    world_args = {"parts": [(np.asarray(v), np.asarray(f)) for v, f in obj.convex_parts], "mass": obj.mass,
                  "com": np.asarray(obj.center_of_mass), "inertia": np.asarray(obj.inertia),
                  "friction": obj.friction}
    return world_args, world.T_world


def bullet_labels(case, args) -> tuple[list[dict], dict]:
    """Bullet's outcome of each of the case's grasps."""
    world_args, T = acronym_world(case, case.T, args.cache_dir)
    chunks = np.array_split(np.arange(len(T)), max(1, args.jobs) * 4)
    settings = {"timestep": args.timestep, "iterations": args.iterations, "inflate": args.inflate,
                "torsional": args.torsional}
    out = Parallel(n_jobs=args.jobs)(delayed(_run_chunk)(world_args, T[idx], settings) for idx in chunks if len(idx))
    thin = sum(shrunk_hull(v, MARGIN)[1] < MARGIN - 1e-9 for v, _ in world_args["parts"])
    return [r for chunk in out for r in chunk], {"mass": world_args["mass"], "parts": len(world_args["parts"]),
                                                 "parts_thinner_than_two_margins": int(thin)}


def mujoco_labels(case, args, impratio: float | None = None):
    """Our outcome codes and closed widths of the case's grasps (``gen evaluate --protocol acronym``); ``impratio``
    replaces the protocol's MuJoCo friction-to-normal impedance ratio (default 10)."""
    lift = LiftParams(protocol="acronym")
    if impratio is not None:
        lift = dataclasses.replace(lift, impratio=impratio)
    params = EvaluateParams(lift=lift, friction=case.friction, mass=case.mass,
                            density=case.density if case.density is not None else 700.0)
    table = evaluate_grasps(case.mesh, case.scale, case.T, None, "panda", params, jobs=args.jobs,
                            cache_dir=args.cache_dir)
    return table.column("outcome").to_numpy(), table.column("closed_width").to_numpy()


def pairwise(a: np.ndarray, b: np.ndarray) -> dict:
    return {"agreement": float(np.mean(a == b)), "kappa": float(kappa(a, b))}


def pooled_summary(flex: np.ndarray, mj: np.ndarray, bt: np.ndarray, groups: np.ndarray) -> tuple[dict, dict]:
    """The three pairwise agreements and kappas of the held labels ``(n,) bool`` with their bootstrap intervals
    (grasps resampled within each object, ``groups`` ``(n,)``), and the three-way confusion (MuJoCo, Bullet) -> FleX
    held / lost."""
    summary = {}
    for name, (a, b) in {"mujoco_vs_flex": (mj, flex), "bullet_vs_flex": (bt, flex),
                         "mujoco_vs_bullet": (mj, bt)}.items():
        summary[name] = {**pairwise(a, b), "interval": kappa_interval(a, b, groups)}
    three = {f"mujoco {'held' if a else 'lost'}, bullet {'held' if b else 'lost'}":
             {"flex_held": int(np.sum((mj == a) & (bt == b) & flex)), "flex_lost": int(np.sum((mj == a) & (bt == b)
                                                                                              & ~flex))}
             for a in (True, False) for b in (True, False)}
    return summary, three


def print_pooled(summary: dict, three: dict, n: int) -> None:
    print(f"\npooled ({n} grasps; 95% bootstrap intervals over the grasps within each object):")
    for k, v in summary.items():
        iv = v["interval"]
        print(f"  {k:18s} agreement {v['agreement']:.3f} [{iv['agreement'][0]:.3f}, {iv['agreement'][1]:.3f}]  "
              f"kappa {v['kappa']:.2f} [{iv['kappa'][0]:.2f}, {iv['kappa'][1]:.2f}]")
    print("three-way (ours, Bullet) -> FleX held / lost:")
    for k, v in three.items():
        print(f"  {k:28s} {v['flex_held']:5d} / {v['flex_lost']:5d}")


def summarise_saved(path: Path) -> None:
    """Print the pooled figures of a saved run (``--from-results``) without simulating anything."""
    saved = json.loads(path.read_text())
    codes = {k: np.asarray(v) for k, v in saved["codes"].items()}
    rows = saved["objects"]
    groups = np.repeat(np.arange(len(rows)), [r["n"] for r in rows])
    if len(groups) != len(codes["flex"]):
        raise SystemExit(f"{path}: {len(codes['flex'])} labels but the objects list {len(groups)} grasps")
    held = {"flex": codes["flex"] == 1, "mujoco": codes["mujoco"] == SUCCESS, "bullet": codes["bullet"] == SUCCESS}
    print("per object: agreement [95% bootstrap interval] (kappa)")
    for i, row in enumerate(rows):
        mine = groups == i
        cells = []
        for a, b in (("mujoco", "flex"), ("bullet", "flex"), ("mujoco", "bullet")):
            iv = kappa_interval(held[a][mine], held[b][mine], groups[mine])["agreement"]
            cells.append(f"{a}-{b} {np.mean(held[a][mine] == held[b][mine]):.3f} [{iv[0]:.3f}, {iv[1]:.3f}] "
                         f"({kappa(held[a][mine], held[b][mine]):.2f})")
        print(f"  {row['object']:18s} n {row['n']}  " + "  ".join(cells))
    summary, three = pooled_summary(held["flex"], held["mujoco"], held["bullet"], groups)
    print_pooled(summary, three, len(groups))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-j", "--jobs", type=int, default=1)
    ap.add_argument("--limit", type=int, default=None, help="evenly spaced grasps per object (default: all)")
    add_calibration_option(ap)
    ap.add_argument("--cache-dir", type=Path, default=REPO / ".cache")
    ap.add_argument("--timestep", type=float, default=TIMESTEP, help="Bullet's time step (s)")
    ap.add_argument("--iterations", type=int, default=SOLVER_ITERATIONS, help="Bullet's solver iterations")
    ap.add_argument("--inflate", type=float, default=0.0,
                    help="make the object's pieces act this much (m) fatter (a what-if: FleX's margins are unknown)")
    ap.add_argument("--torsional", type=float, default=TORSIONAL, help="torsional friction of the contacts (m)")
    ap.add_argument("--impratio", type=str, default="",
                    help="also label with MuJoCo at these impratio values (comma-separated) and compare them too")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--from-results", type=Path, default=None,
                    help="print the pooled figures (with bootstrap intervals) of a saved run and stop")
    args = ap.parse_args()
    if args.from_results is not None:
        summarise_saved(args.from_results)
        return
    try:
        import pybullet  # noqa: F401
    except ImportError:
        raise SystemExit("pybullet is not installed: pip install -e '.[reference]'") from None

    cases = load_cases(args.calibration, args.limit)
    rows, pooled = [], {"flex": [], "mujoco": [], "bullet": [], "width": [], "mcode": [], "bcode": []}
    variants = [float(x) for x in args.impratio.split(",") if x.strip()]
    pooled_variants = {v: [] for v in variants}
    t_all = time.perf_counter()
    for case in cases:
        t0 = time.perf_counter()
        mcodes, widths = mujoco_labels(case, args)
        t1 = time.perf_counter()
        bullet, info = bullet_labels(case, args)
        t2 = time.perf_counter()
        bcodes = np.array([r["code"] for r in bullet])
        flex, mj, bt = case.flex == 1, mcodes == 5, bcodes == 5
        row = {"object": case.name, "n": int(len(flex)), "flex_success": float(flex.mean()),
               "mujoco_success": float(mj.mean()), "bullet_success": float(bt.mean()),
               "mujoco_vs_flex": pairwise(mj, flex), "bullet_vs_flex": pairwise(bt, flex),
               "mujoco_vs_bullet": pairwise(mj, bt),
               "bullet_codes": {OUTCOME_NAMES[k]: int(np.sum(bcodes == k)) for k in (1, 3, 4, 5)},
               "seconds_mujoco": t1 - t0, "seconds_bullet": t2 - t1, "bullet_rollouts_per_s": len(flex) / (t2 - t1),
               **info}
        for v in variants:
            vm = mujoco_labels(case, args, v)[0] == 5
            pooled_variants[v].append(vm)
            row[f"mujoco_impratio_{v:g}"] = {"success": float(vm.mean()), "vs_flex": pairwise(vm, flex),
                                             "vs_bullet": pairwise(vm, bt)}
            print(f"{case.name:18s} MuJoCo with impratio {v:g}: success {vm.mean():.3f}, agreement (kappa) with "
                  f"FleX {np.mean(vm == flex):.3f} ({kappa(vm, flex):.2f}), with Bullet {np.mean(vm == bt):.3f} "
                  f"({kappa(vm, bt):.2f})", flush=True)
        rows.append(row)
        for k, v in (("flex", flex), ("mujoco", mj), ("bullet", bt), ("width", widths), ("mcode", mcodes),
                     ("bcode", bcodes)):
            pooled[k].append(v)
        print(f"{case.name:18s} n {row['n']}  success flex {row['flex_success']:.3f} mujoco "
              f"{row['mujoco_success']:.3f} bullet {row['bullet_success']:.3f} | agreement (kappa) mujoco-flex "
              f"{row['mujoco_vs_flex']['agreement']:.3f} ({row['mujoco_vs_flex']['kappa']:.2f}) bullet-flex "
              f"{row['bullet_vs_flex']['agreement']:.3f} ({row['bullet_vs_flex']['kappa']:.2f}) mujoco-bullet "
              f"{row['mujoco_vs_bullet']['agreement']:.3f} ({row['mujoco_vs_bullet']['kappa']:.2f}) | bullet "
              f"{row['bullet_rollouts_per_s']:.1f} rollouts/s", flush=True)
    P = {k: np.concatenate(v) for k, v in pooled.items()}
    flex, mj, bt = P["flex"], P["mujoco"], P["bullet"]
    groups = np.repeat(np.arange(len(rows)), [r["n"] for r in rows])
    summary, three = pooled_summary(flex, mj, bt, groups)
    strata = {}
    for lo, hi in ((0.0, 0.02), (0.02, 0.06), (0.06, 0.09)):
        m = (P["width"] >= lo) & (P["width"] < hi) & mj
        if m.any():
            strata[f"mujoco successes, closed width {lo * 1000:.0f}-{hi * 1000:.0f} mm"] = {
                "n": int(m.sum()), "flex_held": float(flex[m].mean()), "bullet_held": float(bt[m].mean())}
    print_pooled(summary, three, len(flex))
    for v, parts in pooled_variants.items():
        vm = np.concatenate(parts)
        summary[f"mujoco_impratio_{v:g}_vs_flex"] = pairwise(vm, flex)
        summary[f"mujoco_impratio_{v:g}_vs_bullet"] = pairwise(vm, bt)
        print(f"MuJoCo with impratio {v:g}: agreement (kappa) with FleX {np.mean(vm == flex):.3f} "
              f"({kappa(vm, flex):.2f}), with Bullet {np.mean(vm == bt):.3f} ({kappa(vm, bt):.2f})")
    print("strata of our successes by closed width: FleX and Bullet hold")
    for k, v in strata.items():
        print(f"  {k:45s} n {v['n']:5d}  FleX {v['flex_held']:.2f}  Bullet {v['bullet_held']:.2f}")
    import pybullet as pb
    args.out.write_text(json.dumps({
        "limit": args.limit, "timestep": args.timestep, "solver_iterations": args.iterations, "margin": MARGIN,
        "inflate": args.inflate, "torsional": args.torsional,
        "pybullet_api": pb.getAPIVersion(), "machine": platform.platform(), "objects": rows, "pooled": summary,
        "three_way": three, "strata": strata, "seconds": time.perf_counter() - t_all,
        "codes": {"mujoco": [int(x) for x in P["mcode"]], "bullet": [int(x) for x in P["bcode"]],
                  "flex": [int(x) for x in flex]},
    }, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
