"""A compliant-contact engine on the calibration grasps: do soft contacts side with FleX where two rigid engines don't?

``studies/second_reference.py`` found that MuJoCo (ours) and Bullet, both rigid-body engines given the same geometry
and physics, agree with each other (0.944) far more than either does with ACRONYM's FleX labels (0.849, 0.864). One
objection remains: FleX is a particle-based, compliant simulator, and real fingers and objects are compliant too, so
perhaps two rigid engines share an error. This script runs the same ``acronym`` protocol in Drake with
*hydroelastic* contact (``pydrake``: each contact is a pressure field over the overlap of two compliant volumes, so a
contact has an area, its pressure grows with penetration as ``p = E e``, and the friction and torsion that a patch
can carry come from that area rather than from a point's friction coefficients), solved by SAP (convex, implicit,
1 ms), and prints its agreement with FleX, MuJoCo and Bullet on the same grasps.

Same as ``second_reference.py`` (and ``gen evaluate --protocol acronym``): the evaluation's CoACD pieces, mass,
centre of mass and inertia (:func:`graspgen.workflows.evaluation_world.evaluation_world`), the file's friction (1.0, for
the object and the fingers: Drake combines two coefficients as ``2 mu1 mu2 / (mu1 + mu2)``), the Panda pieces of
``assets/grippers/panda``, 70 N per jaw, 0.1 m/s of width, the jaws geared together (a coupler constraint), fully
open at the grasp, gravity off while closing and then along the approach axis (a force ``m g`` at the centre of
mass), the same Hann-windowed shake and settle, the same rules (placement overlap 1, not both jaws after closing 3,
neither jaw during the shake 4, both at the end 5).

What is Drake's: the world frame is the hand's frame at the grasp (the object is placed at the inverse of the grasp,
as GraspDataGen does), the hand rides a prismatic joint along the approach and a revolute joint about the closing
axis through the TCP, both PD-driven to the shake trajectory (SAP's implicit PD: stiff and stable); the jaws are
velocity-controlled (PD with only a velocity gain) with the effort limited to the grip force; a jaw touches the object
when a hydroelastic contact surface (or a point contact, for pairs without a compliant representation) joins
them. No torsional-friction coefficient: the patch carries the torsion.

Material: the gripper's pieces are compliant with hydroelastic modulus ``--modulus`` (Pa), the object's pieces
rigid (``--compliant-object`` makes them compliant with the same modulus); ``--dissipation`` (s/m) is the
Hunt-Crossley dissipation. The hydroelastic modulus is not Young's modulus: a compliant convex piece's pressure rises
from 0 at its surface to ``E`` at its deepest point, so ``E`` is roughly Young's modulus for a piece whose depth is
its size. The Panda's fingers are hard plastic (Young's modulus ~2 GPa): the default ``E`` = 1e9 Pa. Softer values
are what-ifs (1e7: rubber-like pads, sinking millimetres into a thin edge under 70 N; with the hat's pieces compliant
too, the jaws closed 10 mm further than in MuJoCo on one of its grasps). Compliant thin object pieces (a hat brim, a
knife blade, a mug wall) let a finger sink through half their thickness, which is why objects are rigid by default.

Needs ``drake`` (``pip install -e '.[reference]'``; not a dependency of the package). Run: ``python
studies/compliant_reference.py [-j 2] [--limit 50] [--disputed 10] [--modulus 1e9] [--compliant-object] [--objects
mug,hat] [--results studies/results_second_reference.json]``; writes ``studies/results_compliant_reference.json``
(gitignored). Grasps: ``--limit N`` evenly spaced per object (as the other benches: ``fidelity.subset``), or all of
them; the agreements are over these. ``--disputed M`` adds, per object, M evenly spaced among the other grasps on which
MuJoCo and Bullet agree and FleX differs, and M on which MuJoCo and Bullet differ; for those only who Drake sides with
is counted. Speed (rigid object pieces): 1.8 rollouts/s per core on the bottle (2 pieces), 0.3-0.8 on the
100-128-piece objects; compliant object pieces are 2-4 times slower.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from pathlib import Path

import numpy as np
from joblib import Parallel, delayed

from graspgen.grippers import load_gripper
from graspgen.sim.motion import shake_wave
from graspgen.sim.protocols import AcronymParams
from studies.calibration import REPO, STUDIES, add_calibration_option, load_cases, subset
from studies.fidelity import kappa
from studies.second_reference import PANDA, acronym_world, mesh_pieces

RESULTS = STUDIES / "results_compliant_reference.json"
SECOND = STUDIES / "results_second_reference.json"

TIMESTEP = 0.001  # s
MODULUS = 1e9  # Pa, hydroelastic modulus of the gripper pieces (hard plastic)
DISSIPATION = 5.0  # s/m, Hunt-Crossley
CHECK_INTERVAL = 0.01  # s between contact checks while shaking (MuJoCo's: every 10 steps of 2 ms)
CLOSE_TIMEOUT = 1.5  # s
STOPPED_SPEED = 0.002  # m/s: a jaw slower than this has stopped
SHAKE_KP, SHAKE_KD = 1e6, 2e3  # N/m, N s/m (the hand's joints; per radian for the turn, scaled by TURN_SCALE)
TURN_SCALE = 1e-2  # m^2: the turn's gains are the slide's times this (a hand ~0.1 m across)
JAW_KD = 1e4  # N s/m: the jaw's velocity gain; its force saturates at the grip force well before full speed error

COLLISION_WITH_TARGET, NO_CONTACT, LOST, SUCCESS = 1, 3, 4, 5


class DrakeAcronym:
    """The ``acronym`` protocol in Drake (hydroelastic contact, SAP) for one object; one per worker process."""

    def __init__(self, parts, mass: float, com: np.ndarray, inertia: np.ndarray, friction: float, *,
                 timestep: float = TIMESTEP, modulus: float = MODULUS, dissipation: float = DISSIPATION,
                 compliant_object: bool = False) -> None:
        from pydrake.geometry import (
            AddCompliantHydroelasticProperties,
            AddContactMaterial,
            AddRigidHydroelasticProperties,
            CollisionFilterDeclaration,
            Convex,
            GeometrySet,
            ProximityProperties,
        )
        from pydrake.math import RigidTransform
        from pydrake.multibody.plant import AddMultibodyPlant, CoulombFriction, MultibodyPlantConfig
        from pydrake.multibody.tree import (
            PdControllerGains,
            PrismaticJoint,
            RevoluteJoint,
            RotationalInertia,
            SpatialInertia,
        )
        from pydrake.systems.analysis import Simulator
        from pydrake.systems.framework import DiagramBuilder

        gripper = load_gripper("panda")
        self.dt = timestep
        self.grip_force = float(gripper.force_limit)
        self.finger_speed = float(gripper.closing_speed) / 2.0
        stroke = float(gripper.max_width - gripper.min_width) / 2.0
        tcp_offset = float(gripper.tcp_offset)
        acr = AcronymParams()
        self.shake_z = shake_wave(acr.shake_amplitude, acr.shake_frequency, acr.shake_cycles, timestep)
        self.shake_angle = shake_wave(acr.shake_angle, acr.shake_frequency, acr.shake_cycles, timestep)
        self.settle_steps = int(round(acr.settle_time / timestep))
        self.mass, self.com = float(mass), np.asarray(com, float)

        builder = DiagramBuilder()
        config = MultibodyPlantConfig(time_step=timestep, contact_model="hydroelastic_with_fallback",
                                      discrete_contact_approximation="lagged")
        plant, scene_graph = AddMultibodyPlant(config, builder)
        plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, 0.0])

        def props(mu: float, compliant: bool = True) -> ProximityProperties:
            p = ProximityProperties()
            AddContactMaterial(dissipation=dissipation, point_stiffness=1e6, friction=CoulombFriction(mu, mu),
                               properties=p)
            if compliant:
                AddCompliantHydroelasticProperties(resolution_hint=0.01, hydroelastic_modulus=modulus, properties=p)
            else:
                AddRigidHydroelasticProperties(resolution_hint=0.01, properties=p)
            return p

        # the object: a free body in its mesh frame
        obj_instance = plant.AddModelInstance("object")
        J = np.asarray(inertia, float)  # about the centre of mass, mesh axes
        spatial = SpatialInertia.MakeFromCentralInertia(
            self.mass, self.com, RotationalInertia(J[0, 0], J[1, 1], J[2, 2], J[0, 1], J[0, 2], J[1, 2]))
        self.obj = plant.AddRigidBody("object", obj_instance, spatial)
        obj_geoms = [plant.RegisterCollisionGeometry(self.obj, RigidTransform(),
                                                     Convex(np.asarray(v, float).T, f"object{i}"), f"object{i}",
                                                     props(friction, compliant_object))
                     for i, (v, _) in enumerate(parts)]
        self.obj_geoms = set(obj_geoms)

        # the hand: world -> slide along z -> turn about x through the TCP -> hand (TCP frame); jaws on the hand
        hand_instance = plant.AddModelInstance("panda")
        small = SpatialInertia.MakeFromCentralInertia(0.1, np.zeros(3), RotationalInertia(1e-4, 1e-4, 1e-4))
        slider = plant.AddRigidBody("slider", hand_instance, small)
        hand = plant.AddRigidBody("hand", hand_instance, SpatialInertia.MakeFromCentralInertia(
            float(gripper.body_mass), np.array([0.0, 0.0, -tcp_offset]), RotationalInertia(1e-3, 1e-3, 1e-3)))
        slide = plant.AddJoint(PrismaticJoint("slide", plant.world_frame(), slider.body_frame(), [0.0, 0.0, 1.0]))
        turn = plant.AddJoint(RevoluteJoint("turn", slider.body_frame(), hand.body_frame(), [1.0, 0.0, 0.0]))
        base = np.array([0.0, 0.0, -tcp_offset])  # the OBJ files are in the hand-base frame
        gripper_geoms = [plant.RegisterCollisionGeometry(hand, RigidTransform(), Convex((v + base).T, f"hand{i}"),
                                                         f"hand{i}", props(friction))
                         for i, v in enumerate(mesh_pieces(PANDA / "hand.obj"))]
        finger = mesh_pieces(PANDA / "finger.obj") + mesh_pieces(PANDA / "pad.obj")
        flip = np.diag([-1.0, -1.0, 1.0])
        self.jaw_bodies, jaw_joints = [], []
        for side, R in (("right", np.eye(3)), ("left", flip)):
            body = plant.AddRigidBody(side, hand_instance, SpatialInertia.MakeFromCentralInertia(
                float(gripper.finger_mass), np.zeros(3), RotationalInertia(1e-6, 1e-6, 1e-6)))
            joint = plant.AddJoint(PrismaticJoint(side, hand.body_frame(), body.body_frame(), R @ [-1.0, 0.0, 0.0],
                                                  0.0, stroke))
            for i, v in enumerate(finger):
                gripper_geoms.append(plant.RegisterCollisionGeometry(
                    body, RigidTransform(), Convex((v @ R.T + base).T, f"{side}{i}"), f"{side}{i}", props(friction)))
            self.jaw_bodies.append(body)
            jaw_joints.append(joint)
        plant.AddCouplerConstraint(jaw_joints[0], jaw_joints[1], 1.0, 0.0)
        for joint, limit, kp, kd in ((slide, math.inf, SHAKE_KP, SHAKE_KD),
                                     (turn, math.inf, SHAKE_KP * TURN_SCALE, SHAKE_KD * TURN_SCALE),
                                     (jaw_joints[0], self.grip_force, 0.0, JAW_KD),
                                     (jaw_joints[1], self.grip_force, 0.0, JAW_KD)):
            actuator = plant.AddJointActuator(joint.name(), joint, limit)
            actuator.set_controller_gains(PdControllerGains(p=kp, d=kd))
        plant.Finalize()
        scene_graph.collision_filter_manager().Apply(
            CollisionFilterDeclaration().ExcludeWithin(GeometrySet(gripper_geoms)))
        self.gripper_geoms = set(gripper_geoms)
        self.jaw_geoms = [{g for g in gripper_geoms if plant.GetBodyFromFrameId(
            scene_graph.model_inspector().GetFrameId(g)).index() == b.index()} for b in self.jaw_bodies]
        self.diagram = builder.Build()
        self.plant, self.scene_graph, self.hand_instance = plant, scene_graph, hand_instance
        self.slide, self.turn, self.jaw_joints = slide, turn, jaw_joints
        self.simulator = Simulator(self.diagram)
        self.context = self.simulator.get_mutable_context()
        self.plant_context = plant.GetMyMutableContextFromRoot(self.context)
        self.sg_context = scene_graph.GetMyContextFromRoot(self.context)
        self.desired = plant.get_desired_state_input_port(hand_instance)
        self.forces = plant.get_applied_spatial_force_input_port()
        self.default_state = self.context.Clone()

    # -- helpers ---------------------------------------------------------------------------------------------------

    def _command(self, z: float, angle: float, jaw_speed: float, vz: float = 0.0, vangle: float = 0.0) -> None:
        # desired state of the actuated joints in actuator order: [slide, turn, right, left] positions, velocities
        self.desired.FixValue(self.plant_context, np.array([z, angle, 0.0, 0.0, vz, vangle, jaw_speed, jaw_speed]))

    def _gravity(self, g: float) -> None:
        from pydrake.multibody.math import SpatialForce
        from pydrake.multibody.plant import ExternallyAppliedSpatialForce
        force = ExternallyAppliedSpatialForce()
        force.body_index = self.obj.index()
        force.p_BoBq_B = self.com
        force.F_Bq_W = SpatialForce(np.zeros(3), np.array([0.0, 0.0, self.mass * g]))
        self.forces.FixValue(self.plant_context, [force])

    def _jaws_on(self) -> tuple[bool, bool]:
        results = self.plant.get_contact_results_output_port().Eval(self.plant_context)
        touched = set()
        for i in range(results.num_hydroelastic_contacts()):
            surface = results.hydroelastic_contact_info(i).contact_surface()
            touched.update((surface.id_M(), surface.id_N()))
        for i in range(results.num_point_pair_contacts()):
            pair = results.point_pair_contact_info(i).point_pair()
            touched.update((pair.id_A, pair.id_B))
        if not touched & self.obj_geoms:
            return False, False
        return bool(touched & self.jaw_geoms[0]), bool(touched & self.jaw_geoms[1])

    def _object_pose(self) -> tuple[np.ndarray, np.ndarray]:
        X = self.plant.EvalBodyPoseInWorld(self.plant_context, self.obj)
        return X.translation().copy(), X.rotation().matrix().copy()

    def _jaw_speeds(self) -> list[float]:
        return [j.get_translation_rate(self.plant_context) for j in self.jaw_joints]

    def _advance(self, steps: int = 1) -> None:
        self.simulator.AdvanceTo(self.context.get_time() + steps * self.dt)

    # -- the protocol ----------------------------------------------------------------------------------------------

    def rollout(self, T_tcp: np.ndarray) -> dict:
        """One grasp (TCP pose in the object's mesh frame); returns its code and the object's motion while closing."""
        from pydrake.math import RigidTransform
        self.context.SetTimeStateAndParametersFrom(self.default_state)
        self.simulator.Initialize()
        X_WO = RigidTransform(np.linalg.inv(np.asarray(T_tcp, float)))  # world = the TCP frame at the grasp
        self.plant.SetFreeBodyPose(self.plant_context, self.obj, X_WO)
        self._command(0.0, 0.0, 0.0)
        self._gravity(0.0)
        query = self.scene_graph.get_query_output_port().Eval(self.sg_context)
        for pair in query.ComputeSignedDistancePairwiseClosestPoints(0.0):
            if pair.distance < 0.0 and ({pair.id_A, pair.id_B} & self.obj_geoms):
                return {"code": COLLISION_WITH_TARGET, "motion_closing": [math.nan, math.nan]}
        p0, R0 = self._object_pose()
        self._command(0.0, 0.0, self.finger_speed)
        t, slow = 0.0, 0
        every = max(1, round(CHECK_INTERVAL / self.dt))
        while t < CLOSE_TIMEOUT:
            self._advance()
            t += self.dt
            slow = slow + 1 if t > 0.02 and max(abs(v) for v in self._jaw_speeds()) < STOPPED_SPEED else 0
            if slow * self.dt >= 0.01:
                break
        p1, R1 = self._object_pose()
        motion = [float(np.linalg.norm(p1 - p0)), float(np.arccos(np.clip((np.trace(R0.T @ R1) - 1) / 2, -1, 1)))]
        if not all(self._jaws_on()):
            return {"code": NO_CONTACT, "motion_closing": motion}
        self._gravity(9.81)  # along the approach axis (world +z, the TCP's z at the grasp)
        vz = np.gradient(self.shake_z, self.dt)
        va = np.gradient(self.shake_angle, self.dt)
        plan = [(z, 0.0, v, 0.0) for z, v in zip(self.shake_z, vz)]
        plan += [(0.0, a, 0.0, v) for a, v in zip(self.shake_angle, va)]
        plan += [(0.0, 0.0, 0.0, 0.0)] * self.settle_steps
        for i, (z, a, v, w) in enumerate(plan):
            self._command(z, a, self.finger_speed, v, w)
            self._advance()
            if (i + 1) % every == 0 and not any(self._jaws_on()):
                return {"code": LOST, "motion_closing": motion}
        return {"code": SUCCESS if all(self._jaws_on()) else LOST, "motion_closing": motion}


def _run_chunk(world_args: dict, T: np.ndarray, settings: dict) -> list[dict]:
    sim = DrakeAcronym(**world_args, **settings)
    return [sim.rollout(t) for t in T]


def drake_labels(case, idx: np.ndarray, args) -> list[dict]:
    """Drake's outcome of the case's grasps ``idx``."""
    world_args, T = acronym_world(case, case.T[idx], args.cache_dir)
    chunks = np.array_split(np.arange(len(T)), max(1, args.jobs) * 2)
    settings = {"timestep": args.timestep, "modulus": args.modulus, "dissipation": args.dissipation,
                "compliant_object": args.compliant_object}
    out = Parallel(n_jobs=args.jobs)(delayed(_run_chunk)(world_args, T[c], settings) for c in chunks if len(c))
    return [r for chunk in out for r in chunk]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-j", "--jobs", type=int, default=1)
    ap.add_argument("--limit", type=int, default=None, help="evenly spaced grasps per object (default: all)")
    ap.add_argument("--objects", type=str, default="", help="comma-separated parts of object names (default: all)")
    ap.add_argument("--disputed", type=int, default=0,
                    help="also this many grasps per object where MuJoCo and Bullet agree and FleX differs, and as "
                         "many where MuJoCo and Bullet differ (counted apart from the evenly spaced ones)")
    ap.add_argument("--modulus", type=float, default=MODULUS, help="hydroelastic modulus of the gripper pieces (Pa)")
    ap.add_argument("--compliant-object", action="store_true",
                    help="the object's pieces compliant too (same modulus) instead of rigid")
    ap.add_argument("--dissipation", type=float, default=DISSIPATION, help="Hunt-Crossley dissipation (s/m)")
    ap.add_argument("--timestep", type=float, default=TIMESTEP)
    ap.add_argument("--results", type=Path, default=SECOND,
                    help="second_reference.py's full results (MuJoCo and Bullet labels to compare with)")
    add_calibration_option(ap)
    ap.add_argument("--cache-dir", type=Path, default=REPO / ".cache")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    try:
        import pydrake  # noqa: F401
    except ImportError:
        raise SystemExit("drake is not installed: pip install -e '.[reference]'") from None
    saved = None
    if args.results.exists():
        saved = json.loads(args.results.read_text())
        if saved.get("limit") is not None:
            print(f"{args.results} is from a --limit run: MuJoCo and Bullet are left out")
            saved = None
    cases = load_cases(args.calibration, None)
    wanted = [w for w in args.objects.split(",") if w.strip()]
    rows, pooled, start = [], {k: [] for k in ("flex", "drake", "mujoco", "bullet")}, 0
    disputes = {k: [] for k in ("flex", "drake", "mujoco", "bullet")}
    t_all = time.perf_counter()
    for case in cases:
        first, start = start, start + len(case.T)
        if wanted and not any(w in case.name for w in wanted):
            continue
        idx = subset(len(case.T), args.limit)
        extra = np.zeros(0, dtype=int)
        if saved is not None and args.disputed:
            mj_all, bt_all = (np.asarray(saved["codes"][k])[first:first + len(case.T)] == SUCCESS
                              for k in ("mujoco", "bullet"))
            flex_all = case.flex == 1
            rest = np.setdiff1d(np.arange(len(case.T)), idx)
            pick = []
            for mask in ((mj_all == bt_all) & (mj_all != flex_all), mj_all != bt_all):
                cand = rest[mask[rest]]
                pick.append(cand[subset(len(cand), args.disputed)] if len(cand) else cand)
            extra = np.concatenate(pick)
        t0 = time.perf_counter()
        out = drake_labels(case, np.concatenate([idx, extra]), args)
        seconds = time.perf_counter() - t0
        codes_all = np.array([r["code"] for r in out])
        if saved is not None:
            for k in ("mujoco", "bullet"):
                disputes[k].append(np.asarray(saved["codes"][k])[first:first + len(case.T)][extra] == SUCCESS)
            disputes["flex"].append(case.flex[extra] == 1)
            disputes["drake"].append(codes_all[len(idx):] == SUCCESS)
        codes = codes_all[:len(idx)]
        labels = {"flex": case.flex[idx] == 1, "drake": codes == SUCCESS}
        if saved is not None:
            for k in ("mujoco", "bullet"):
                labels[k] = np.asarray(saved["codes"][k])[first:first + len(case.T)][idx] == SUCCESS
        row = {"object": case.name, "n": int(len(idx)), "seconds": seconds, "rollouts_per_s": len(idx) / seconds,
               "drake_codes": {str(c): int(np.sum(codes == c)) for c in (1, 3, 4, 5)},
               "success": {k: float(v.mean()) for k, v in labels.items()},
               "pairs": {f"{a}_vs_{b}": {"agreement": float(np.mean(labels[a] == labels[b])),
                                         "kappa": float(kappa(labels[a], labels[b]))}
                         for a in labels for b in labels if a < b}}
        rows.append(row)
        for k, v in labels.items():
            pooled[k].append(v)
        print(f"{case.name:18s} n {row['n']}  success " + " ".join(f"{k} {v:.3f}" for k, v in row["success"].items())
              + " | " + "; ".join(f"{k} {v['agreement']:.3f} ({v['kappa']:.2f})" for k, v in row["pairs"].items())
              + f" | drake codes {row['drake_codes']} | {row['rollouts_per_s']:.2f} rollouts/s", flush=True)
    P = {k: np.concatenate(v) for k, v in pooled.items() if v}
    summary = {f"{a}_vs_{b}": {"agreement": float(np.mean(P[a] == P[b])), "kappa": float(kappa(P[a], P[b]))}
               for a in P for b in P if a < b}
    print(f"\npooled ({len(P['flex'])} grasps): " + "; ".join(
        f"{k} {v['agreement']:.3f} (kappa {v['kappa']:.2f})" for k, v in summary.items()))
    sided = {}
    for name, parts in (("evenly spaced", pooled), ("disputed extra", disputes)):
        if not parts["mujoco"] or not sum(len(p) for p in parts["mujoco"]):
            continue
        mj, bt, dk, fl = (np.concatenate(parts[k]) for k in ("mujoco", "bullet", "drake", "flex"))
        both = mj == bt
        sided[name] = {
            "rigid_agree_flex_differs": int(np.sum(both & (mj != fl))),
            "drake_sides_with_flex": int(np.sum(both & (mj != fl) & (dk == fl))),
            "rigid_engines_differ": int(np.sum(~both)), "drake_sides_with_mujoco": int(np.sum(~both & (dk == mj))),
            "drake_sides_with_flex_where_rigid_differ": int(np.sum(~both & (dk == fl)))}
        v = sided[name]
        print(f"{name}: where MuJoCo and Bullet agree and FleX differs ({v['rigid_agree_flex_differs']} grasps), "
              f"Drake sides with FleX on {v['drake_sides_with_flex']}; where MuJoCo and Bullet differ "
              f"({v['rigid_engines_differ']}), Drake sides with MuJoCo on {v['drake_sides_with_mujoco']} (with FleX "
              f"on {v['drake_sides_with_flex_where_rigid_differ']})")
    import pydrake
    args.out.write_text(json.dumps({
        "limit": args.limit, "modulus": args.modulus, "compliant_object": args.compliant_object,
        "dissipation": args.dissipation, "timestep": args.timestep,
        "drake": getattr(pydrake, "__version__", "?"), "machine": platform.platform(), "objects": rows,
        "pooled": summary, "sided": sided, "disputed_per_object": args.disputed,
        "seconds": time.perf_counter() - t_all,
    }, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
