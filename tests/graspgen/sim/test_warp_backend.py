"""Tests of the warp backend (graspgen/sim/warp_backend.py): its batched rules against the CPU backend's methods on
the same states, its settings, the missing-extra error, and (when the warp extra is installed) analytic grasps on
Warp's CPU device labelled alike by both backends.

The device tests compile MJWarp's kernels on first use (minutes on a cold Warp cache, then cached under the user's
Warp cache); they carry the ``warp`` marker (``pytest -m "not warp"`` leaves them out)."""

from __future__ import annotations

import json
import math
import sys

import mujoco
import numpy as np
import pytest

from graspgen.errors import MissingDependencyError, SettingsError
from graspgen.geometry.poses import rotation_angle, rotation_angles
from graspgen.grippers import load_gripper
from graspgen.sim import lift as L
from graspgen.sim import protocols as P
from graspgen.sim import warp_backend as W
from graspgen.sim.gripper_model import attach_gripper
from graspgen.sim.lift_rules import LEFT
from graspgen.sim.lift_rules import jaws_on as cpu_jaws_on
from graspgen.sim.physics import physics_options
from graspgen.sim.warp_rules import jaws_on, relative_poses
from tests.paths import REPO

HALF = 0.025  # m, half side of the box
FLOAT_Z = 0.5  # m, where the box floats


pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")


def _world(friction: float = 0.5, solver=None, mass: float = 0.2) -> mujoco.MjModel:
    """A free 50 mm box ``obj/0_box`` (``mass`` kg) floating at z = 0.5 m and the Panda."""
    spec = mujoco.MjSpec()
    physics_options(spec)
    if solver is not None:
        spec.option.solver = solver
    body = spec.worldbody.add_body(name="obj/0_box", pos=[0, 0, FLOAT_Z])
    body.add_freejoint(name="obj/0_box/free")
    body.add_geom(name="obj/0_box/geom", type=mujoco.mjtGeom.mjGEOM_BOX, size=[HALF] * 3, mass=mass,
                  friction=[friction, 0.005, 0.0001])
    attach_gripper(spec, load_gripper("panda"))
    return spec.compile()


def _pose(approach, closing, position) -> np.ndarray:
    """(4, 4) TCP pose from its approach (z) and closing (x) axes and origin (m), world frame."""
    z, x = np.asarray(approach, float), np.asarray(closing, float)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, np.cross(z, x), z, position
    return T


SIDE = _pose([0, 1, 0], [1, 0, 0], [0, 0, FLOAT_Z])  # across the x faces, approaching sideways
TOP = _pose([0, 0, -1], [1, 0, 0], [0, 0, FLOAT_Z])  # across the x faces, from above
AIR = _pose([0, 1, 0], [1, 0, 0], [0.2, 0, FLOAT_Z])  # 20 cm beside the box: closes on nothing
INSIDE = _pose([0, 1, 0], [1, 0, 0], [0, 0.02, FLOAT_Z])  # the palm inside the box: a collision at placement


# ------------------------------------------------------------------------------------ rules against the CPU's


def _closed_cpu_state(protocol: str = "acronym") -> tuple[L.LiftSimulator, np.ndarray, int]:
    """A CPU simulator whose data holds a box gripped across its faces (end of a rollout), its roles and target."""
    sim = L.LiftSimulator(_world(), P.LiftParams(protocol=protocol))
    res = sim.rollout(SIDE, 2 * HALF, "obj/0_box")
    assert res.code == P.Outcome.SUCCESS
    target, roles, _ = sim.target_roles("obj/0_box")
    return sim, roles, target


def test_batched_jaws_on_is_the_cpu_rule_world_by_world():
    sim, roles, target = _closed_cpu_state()
    geom = sim.data.contact.geom.copy()
    cpu_rule = cpu_jaws_on(sim.data, sim.index.geom_side, roles)
    assert cpu_rule == (True, True)
    # three worlds: all contacts, the left jaw's removed, none; the CPU rule on each world's own contacts
    side = sim.index.geom_side[geom]
    keep_right = ~((side == LEFT).any(axis=1))
    worlds = [geom, geom[keep_right], geom[:0]]
    flat = np.concatenate(worlds)
    world = np.concatenate([np.full(len(g), i) for i, g in enumerate(worlds)])
    got = jaws_on(flat, world, 4, sim.index.geom_side, roles)
    # world 0: the CPU rule on the same contacts; 1: only the right jaw's contacts left; 2, 3: no contacts
    assert [tuple(row) for row in got[:3]] == [cpu_rule, (False, True), (False, False)]
    assert cpu_jaws_on(sim.data, sim.index.geom_side, roles) == (True, True)
    assert not got[3].any()  # a world without contacts


def test_batched_relative_pose_and_angle_are_the_cpu_formulas():
    sim, _, target = _closed_cpu_state()
    d = sim.data
    p, R = relative_poses(d.xipos[target][None], d.xmat[target].reshape(1, 3, 3), d.xpos[sim.index.base][None],
                          d.xmat[sim.index.base].reshape(1, 3, 3))
    p_cpu, R_cpu = sim.relative(target)
    np.testing.assert_allclose(p[0], p_cpu, atol=1e-15)
    np.testing.assert_allclose(R[0], R_cpu, atol=1e-15)
    rng = np.random.default_rng(0)
    Ra, Rb = [], []
    for _ in range(20):
        for out in (Ra, Rb):
            q = rng.standard_normal(4)
            M = np.empty(9)
            mujoco.mju_quat2Mat(M, q / np.linalg.norm(q))
            out.append(M.reshape(3, 3))
    got = rotation_angles(np.array(Ra), np.array(Rb))
    np.testing.assert_allclose(got, [rotation_angle(a, b) for a, b in zip(Ra, Rb)], rtol=0, atol=1e-14)


# ------------------------------------------------------------------------------------ settings and errors


def test_the_warp_simulator_runs_every_protocol():
    assert set(W.WARP_PROTOCOLS) == set(P.PROTOCOLS)


@pytest.mark.parametrize("change, field", [({"nworld": 0}, "nworld"), ({"nconmax": 0}, "nconmax"),
                                           ({"njmax": -1}, "njmax"), ({"device": ""}, "device")])
def test_warp_params_name_the_bad_field(change, field):
    with pytest.raises(SettingsError, match=field):
        W.WarpParams(**change)
    assert W.WarpParams().to_dict() == {"device": None, "nworld": 1024, "nconmax": 96, "njmax": 600}


def test_missing_extra_is_a_one_line_error_naming_the_install(monkeypatch):
    for name in ("warp", "mujoco_warp"):
        monkeypatch.setitem(sys.modules, name, None)  # None in sys.modules: importing it raises ImportError
    with pytest.raises(MissingDependencyError) as err:
        W.import_warp()
    message = str(err.value)
    assert "\n" not in message and "mujoco-warp" in message and "pip install -e '.[warp]'" in message
    with pytest.raises(MissingDependencyError):  # the simulator says so before any work
        W.WarpLiftSimulator(_world(), P.LiftParams(protocol="acronym"), W.WarpParams(device="cpu", nworld=4))


def test_a_model_feature_mjwarp_lacks_is_a_simulation_error_naming_it():
    pytest.importorskip("mujoco_warp")
    from graspgen.errors import SimulationError

    model = _world(solver=mujoco.mjtSolver.mjSOL_PGS)  # MJWarp has the CG and Newton solvers only
    with pytest.raises(SimulationError, match="MuJoCo Warp cannot run this model: .*PGS") as err:
        W.WarpLiftSimulator(model, P.LiftParams(protocol="acronym"), W.WarpParams(device="cpu", nworld=4))
    assert "\n" not in str(err.value)


# ------------------------------------------------------------------------------------ on Warp's CPU device


@pytest.mark.warp
@pytest.mark.parametrize("protocol, pad_torsion", [("acronym", "face"), ("graspdatagen", "face"),
                                                   ("acronym", "patch")])
def test_both_backends_label_analytic_grasps_alike_on_the_cpu_device(protocol, pad_torsion):
    pytest.importorskip("mujoco_warp")
    pytest.importorskip("warp")
    params = P.LiftParams(protocol=protocol, pad_torsion=pad_torsion)
    model = _world()
    poses = np.array([SIDE, TOP, AIR, INSIDE])
    cpu = L.LiftSimulator(model, params)
    ref = [cpu.rollout(T, 2 * HALF, "obj/0_box") for T in poses]
    got = W.WarpLiftSimulator(model, params, W.WarpParams(device="cpu", nworld=4)).rollouts(poses, "obj/0_box")
    # the analytic truth: gripped across the faces -> held and firm; beside the box -> nothing to close on;
    # the palm inside the box -> a collision at placement
    expected = [(5, "end"), (5, "end"), (3, "closing"), (1, "placement")]
    assert [(r.code, r.decided_in) for r in ref] == expected
    assert [(r.code, r.decided_in) for r in got] == expected
    assert all(r.firm for r in got[:2])
    for a, b in zip(ref, got):
        # the same phase schedule world by world: closing stops at the same check, give or take one (float32)
        assert abs(a.steps - b.steps) <= params.check_interval
        if a.code == 5:
            assert math.isclose(a.closed_width, b.closed_width, abs_tol=1e-4)
            assert b.max_rel_translation < 1e-3 and len(b.contact_forces) > 0
    if pad_torsion == "patch":  # each world's pads got their own patch's torsion, as the CPU's did
        sim = W.WarpLiftSimulator(model, params, W.WarpParams(device="cpu", nworld=2))
        sim.rollouts(poses[:2], "obj/0_box")
        pads = sim.cpu.pad_patch.pad_geoms
        assert sim.world_friction.numpy()[:, pads, 1].min() > 0.0


@pytest.mark.warp
def test_a_light_objects_bounded_contact_and_divided_timestep_reach_the_device():
    """A 2 g box: the CPU backend shortens the pads' time constant and divides the timestep (graspgen.sim.pad_sink);
    the device runs the same model, so it closes to the same width in the same steps (the gripper model's contact
    would let the pads sink about 1 mm deeper on each side)."""
    pytest.importorskip("mujoco_warp")
    pytest.importorskip("warp")
    params = P.LiftParams(protocol="acronym")
    model = _world(mass=0.002)
    poses = np.array([SIDE, TOP])
    cpu = L.LiftSimulator(model, params)
    assert cpu.contact.substeps > 1
    ref = [cpu.rollout(T, 2 * HALF, "obj/0_box") for T in poses]
    got = W.WarpLiftSimulator(model, params, W.WarpParams(device="cpu", nworld=2)).rollouts(poses, "obj/0_box")
    assert [r.code for r in ref] == [r.code for r in got] == [5, 5]
    for a, b in zip(ref, got):
        assert abs(a.steps - b.steps) <= cpu.check_interval
        assert math.isclose(a.closed_width, b.closed_width, abs_tol=1e-4)
        assert 2 * HALF - b.closed_width < 2 * 0.001  # each pad within its 1 mm compliance


# ------------------------------------------------------------------------------------ evaluate_grasps(backend=...)

BOX_MESH = REPO / "assets" / "objects" / "box.obj"


def _top_down(z: float) -> np.ndarray:
    T = np.diag([1.0, -1.0, -1.0, 1.0])
    T[2, 3] = z
    return T


def test_evaluate_refuses_a_backend_it_does_not_know():
    from graspgen.workflows.evaluate import evaluate_grasps

    T = np.stack([_top_down(0.11)])
    with pytest.raises(SettingsError, match="backend"):
        evaluate_grasps(BOX_MESH, 1.0, T, None, "panda", protocol="acronym", backend="gpu")


@pytest.mark.warp
def test_evaluate_on_the_warp_backend_labels_as_the_cpu_backend_and_says_so():
    pytest.importorskip("mujoco_warp")
    from graspgen.workflows.evaluate import evaluate_grasps
    from graspgen.workflows.evaluate_columns import METADATA_KEY

    T = np.stack([_top_down(0.11), _top_down(0.30)])  # across the box; far above it (closes on air)
    cpu = evaluate_grasps(BOX_MESH, 1.0, T, None, "panda", protocol="acronym")
    warp = evaluate_grasps(BOX_MESH, 1.0, T, None, "panda", protocol="acronym", backend="warp",
                           warp=W.WarpParams(device="cpu", nworld=2))
    assert cpu.column("outcome").to_pylist() == warp.column("outcome").to_pylist() == [5, 3]
    meta = json.loads(warp.schema.metadata[METADATA_KEY.encode()])
    assert meta["backend"] == "warp" and meta["warp"]["nworld"] == 2
    assert json.loads(cpu.schema.metadata[METADATA_KEY.encode()])["backend"] == "mujoco"


def test_gen_evaluate_backend_option_refuses_an_unknown_backend(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq
    from typer.testing import CliRunner

    from graspgen_cli.app import app

    poses = tmp_path / "poses.parquet"
    pq.write_table(pa.table({"pose": [_top_down(0.11).reshape(-1).tolist()]}), poses)
    args = ["evaluate", "--grasps", poses, "--mesh", BOX_MESH, "--scale", "1", "--gripper", "panda",
            "--out", tmp_path / "labels.parquet", "--backend", "gpu"]
    result = CliRunner().invoke(app, [str(a) for a in args])
    assert result.exit_code != 0 and "backend" in result.output and "'gpu'" in result.output
    assert not (tmp_path / "labels.parquet").exists()
