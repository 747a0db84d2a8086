"""The metrics stage: which contacts each grasp's epsilon comes from, the friction label, the torque scale, the fast
pad path against the plain grasp matrix, and the stage in a real pipeline (rows, bytes, workers)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from graspgen.geometry.contacts import ClosingContacts, closing_contacts
from graspgen.grippers import load_gripper
from graspgen.io.arrow import column_array
from graspgen.io.objects import ObjectRecord, read_object
from graspgen.io.scenes import read_scene
from graspgen.quality.closure import ferrari_canny_from_wrenches
from graspgen.quality.contact_set import contact_set, world_to_object
from graspgen.quality.epsilon import EpsilonParams, grasp_epsilon, min_closure_friction, pad_contacts
from graspgen.quality.wrench import grasp_matrix
from graspgen.workflows.metrics import SCHEMA, object_geometry
from pipeline.config import load_config
from pipeline.errors import ConfigError
from pipeline.plan import committed
from pipeline.repro import shard_hashes
from pipeline.scheduler import run_pipeline
from pipeline.store import stage_dir
from stages.project import PROJECT
from tests.paths import REPO

GRIPPER = load_gripper("robotiq_2f85")


pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")


# ------------------------------------------------------------------------------------------------ plain functions


def test_world_to_object_inverts_the_pose():
    rng = np.random.default_rng(0)
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=1).as_matrix()
    T[:3, 3] = (0.1, -0.3, 0.7)
    p_obj = rng.normal(0, 0.05, (5, 3))
    n_obj = rng.normal(0, 1, (5, 3))
    n_obj /= np.linalg.norm(n_obj, axis=1, keepdims=True)
    p, n = world_to_object(p_obj @ T[:3, :3].T + T[:3, 3], n_obj @ T[:3, :3].T, T)
    np.testing.assert_allclose(p, p_obj, atol=1e-15)
    np.testing.assert_allclose(n, n_obj, atol=1e-15)


def test_contact_set_prefers_two_pad_rollout_contacts():
    rays = ClosingContacts(np.array([[-1.0, 0, 0], [1.0, 0, 0]]), np.array([[1.0, 0, 0], [-1.0, 0, 0]]),
                           np.array([0, 1], np.int8), 2.0)
    shift = np.eye(4)
    shift[:3, 3] = (0.0, 0.0, 1.0)
    both = (np.array([[-1.0, 0, 1], [1.0, 0, 1]]), np.array([[1.0, 0, 0], [-1.0, 0, 0]]), np.array([0, 1]))
    source, p, _, f = contact_set(both, shift, rays)
    assert source == "rollout" and np.allclose(p, [[-1, 0, 0], [1, 0, 0]]) and f.dtype == np.int8
    one_pad = (both[0][:1], both[1][:1], both[2][:1])
    assert contact_set(one_pad, shift, rays)[0] == "raycast"  # a jaw missed: fall back to the ray casts
    assert contact_set(None, shift, rays)[0] == "raycast"  # not simulated
    one_ray = ClosingContacts(rays.points[:1], rays.normals[:1], rays.finger[:1], math.nan)
    source, p, n, f = contact_set(one_pad, shift, one_ray)
    assert source == "none" and p.shape == n.shape == (0, 3) and f.shape == (0,)


def test_fast_pad_path_equals_the_plain_grasp_matrix():
    # grasp_epsilon builds the pad model's wrenches in one vectorised call; it must equal the hull of the columns of
    # grasp_matrix per pad, stacked (the definition), on random two-pad contact sets, in and out of closure
    rng = np.random.default_rng(3)
    closed = 0
    for _ in range(200):
        k = rng.integers(1, 6, size=2)
        finger = np.repeat([0, 1], k)
        base = np.array([[1.0, 0, 0]] * k[0] + [[-1.0, 0, 0]] * k[1])
        normals = base + rng.normal(0, 0.4, base.shape)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        points = -0.03 * base + rng.normal(0, 0.01, base.shape)
        com = rng.normal(0, 0.01, 3)
        mu, tf = rng.uniform(0.2, 1.0), rng.choice([0.0, 0.003])
        eps = grasp_epsilon(points, normals, finger, com, friction=mu, torque_scale=0.06, torsional_friction=tf)
        c, n, g = pad_contacts(points, normals, finger, friction=mu, torsional_friction=tf)
        w = np.hstack([grasp_matrix(c[i : i + 1], n[i : i + 1], com, friction=mu, torque_scale=0.06,
                                    torsional_friction=g[i]) for i in range(len(c))])
        assert eps == pytest.approx(ferrari_canny_from_wrenches(w), rel=1e-9, abs=1e-15)
        closed += eps > 0
    assert 20 < closed < 180  # both kinds were exercised


def test_min_closure_friction_is_monotone_with_epsilon():
    c = closing_contacts(object_geometry(_unit_box()).mesh, _top_down(), GRIPPER)[0]
    frictions = [0.1, 0.2, 0.5, 1.0]
    label = min_closure_friction(c.points, c.normals, c.finger, np.zeros(3), frictions, torque_scale=0.07)
    assert label == 0.1  # clean antipodal box grasp: in closure at any friction
    assert grasp_epsilon(c.points, c.normals, c.finger, np.zeros(3), friction=0.1, torque_scale=0.07) > 0


def _unit_box() -> ObjectRecord:
    box = trimesh.creation.box((0.05, 0.07, 0.12))
    return ObjectRecord("box", box.vertices, box.faces, [], 1.0, np.zeros(3), np.eye(3), np.eye(4)[None],
                        np.ones(1), {})


def _top_down():
    T = np.eye(4)
    T[:3, 2] = (0.0, 0.0, -1.0)
    T[:3, 1] = np.cross(T[:3, 2], T[:3, 0])
    return T


def test_torque_scale_is_the_largest_vertex_distance_from_the_centre_of_mass():
    geometry = object_geometry(_unit_box())
    assert geometry.torque_scale == pytest.approx(math.sqrt(0.025**2 + 0.035**2 + 0.06**2), rel=1e-12)


# ------------------------------------------------------------------------------------------------ the stage


def small(out: Path, cache: Path, *sets: str):
    """The smoke config cut to the two convex objects (no CoACD), four scenes, few robustness copies. Four scenes,
    not two: the rows that are not two-pad rollouts (labelled collisions, raycast contacts) come from the draws,
    which follow the code's keys; two scenes had none after an unrelated change, four have ~10 of ~65 rows."""
    return load_config(
        PROJECT.schema,
        REPO / "configs" / "smoke.yaml",
        [
            f"run.out={out}",
            f"run.cache_dir={cache}",
            "run.jobs=1",
            "objects.include=[box, cylinder]",
            "scenes.num_scenes=4",
            "robustness.num_perturbations=3",
            *sets,
        ],
    )


def tables(out: Path, stage: str) -> dict:
    return {e.task: pq.read_table(stage_dir(out, stage) / e.file) for e in committed(out, stage).values()}


def shard(out: Path, stage: str, task: str) -> Path:
    (entry,) = [e for e in committed(out, stage).values() if e.task == task]
    return stage_dir(out, stage) / entry.file


@pytest.fixture(scope="module")
def pipeline_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("metrics")
    reports = run_pipeline(PROJECT, small(root / "out", root / "cache"), ["metrics"])
    assert all(r.failed == 0 for r in reports), [r.failures for r in reports]
    return root


def test_one_row_per_grasp_with_the_documented_contact_rule(pipeline_run):
    out = pipeline_run / "out"
    grasps, rollouts, metrics = tables(out, "grasps"), tables(out, "rollouts"), tables(out, "metrics")
    assert set(metrics) == set(grasps) and metrics
    seen = set()
    for sid, m in metrics.items():
        g, r = grasps[sid], rollouts[sid]
        assert m.schema.equals(SCHEMA)
        assert m.column("grasp_id").to_pylist() == g.column("grasp_id").to_pylist()
        simulated = r.column("simulated").to_numpy(zero_copy_only=False)
        fingers = r.column("contact_fingers").to_pylist()
        source = m.column("contact_source").to_pylist()
        count = m.column("num_contacts").to_numpy()
        eps = m.column("epsilon").to_numpy()
        label = m.column("min_closure_friction").to_numpy()
        friction = m.column("friction").to_numpy()
        for i in range(len(m)):
            two_pads = bool(simulated[i]) and {0, 1} <= set(fingers[i])
            assert (source[i] == "rollout") == two_pads
            if two_pads:
                assert count[i] == len(fingers[i])
            if source[i] == "none":
                assert eps[i] == 0 and count[i] == 0 and math.isnan(label[i])
        seen.update(source)
        assert np.all(eps >= 0) and np.all(friction == 0.8)  # the scenes' object friction (smoke: 0.8)
        # closure only grows with friction: in closure at 0.8 <=> the label is at most 0.8
        in_closure = eps > 0
        assert np.all(label[in_closure] <= 0.8)
        assert np.all(np.isnan(label[~in_closure]) | (label[~in_closure] > 0.8))
    assert {"rollout", "raycast"} <= seen


def test_rows_recomputed_by_hand(pipeline_run):
    out = pipeline_run / "out"
    checked = set()
    ep = EpsilonParams()
    for sid, m in tables(out, "metrics").items():
        g = pq.read_table(shard(out, "grasps", sid))
        r = pq.read_table(shard(out, "rollouts", sid))
        scene = read_scene(shard(out, "scenes", sid))
        for i, source in enumerate(m.column("contact_source").to_pylist()):
            if source in checked or source == "none":
                continue
            k = g.column("object_index")[i].as_py()
            geometry = object_geometry(read_object(shard(out, "objects", scene.object_names[k])))
            d = np.linalg.norm(geometry.mesh.vertices - geometry.center_of_mass, axis=1).max()
            assert m.column("torque_scale")[i].as_py() == pytest.approx(d, rel=1e-12)
            if source == "rollout":  # world contacts at the end of closing, through the object's pose at that time
                at_closing = column_array(r, "target_pose_closed", (4, 4))[i]
                p, n = world_to_object(np.reshape(r.column("contact_points")[i].as_py(), (-1, 3)),
                                       np.reshape(r.column("contact_normals")[i].as_py(), (-1, 3)), at_closing)
                f = np.array(r.column("contact_fingers")[i].as_py())
                # independent truth: through that pose the contacts lie on the mesh (within contact penetration)
                _, distance, _ = trimesh.proximity.closest_point(geometry.mesh, p)
                assert distance.max() < 2e-3, distance
            else:  # the pads closed onto the mesh at the grasp's object-frame pose
                gripper = load_gripper(g.column("gripper")[i].as_py())  # the grasps' own gripper
                (c,) = closing_contacts(geometry.mesh, column_array(g, "pose_object", (4, 4))[i], gripper)
                p, n, f = c.points, c.normals, c.finger
            mu = float(scene.friction[k])  # the object's friction in its scene
            assert m.column("epsilon")[i].as_py() == ep.epsilon(p, n, f, geometry, mu)
            checked.add(source)
    assert checked == {"rollout", "raycast"}


def test_contact_noise_columns(pipeline_run, tmp_path):
    # default noise: labels in range, 0 without contacts; zero noise: the nominal epsilon and closure exactly
    for m in tables(pipeline_run / "out", "metrics").values():
        pfc, robust = m.column("pfc_contact").to_numpy(), m.column("epsilon_robust").to_numpy()
        none = np.array(m.column("contact_source").to_pylist()) == "none"
        assert np.all((pfc >= 0) & (pfc <= 1)) and np.all(robust >= 0)
        assert np.all(pfc[none] == 0) and np.all(robust[none] == 0)
    quiet = ["metrics.contact_position_sigma=0", "metrics.contact_normal_sigma=0", "metrics.friction_sigma=0"]
    reports = run_pipeline(PROJECT, small(tmp_path / "q", pipeline_run / "cache", *quiet), ["metrics"])
    assert all(r.failed == 0 for r in reports)
    noisy = tables(pipeline_run / "out", "metrics")
    for sid, m in tables(tmp_path / "q", "metrics").items():
        eps = m.column("epsilon").to_numpy()
        assert np.array_equal(m.column("epsilon_robust").to_numpy(), eps)
        assert np.array_equal(m.column("pfc_contact").to_numpy(), (eps > 0).astype(float))
        for name in SCHEMA.names[:8]:  # the nominal columns do not depend on the noise
            assert list(map(repr, m.column(name).to_pylist())) == list(map(repr, noisy[sid].column(name).to_pylist()))
    with pytest.raises(ConfigError, match="metrics.num_contact_samples: must be a positive integer, got 0"):
        small(tmp_path, pipeline_run / "cache", "metrics.num_contact_samples=0")


def test_same_key_same_bytes_and_independent_of_workers(pipeline_run, tmp_path):
    cache = pipeline_run / "cache"
    again = run_pipeline(PROJECT, small(tmp_path / "again", cache), ["metrics"])
    two = run_pipeline(PROJECT, small(tmp_path / "two", cache, "run.jobs=2"), ["metrics"])
    assert all(r.failed == 0 for r in again + two)
    first = {k: v for k, v in shard_hashes(pipeline_run / "out").items() if k.startswith("metrics/")}
    assert first and first == {k: v for k, v in shard_hashes(tmp_path / "again").items() if k in first}
    assert first == {k: v for k, v in shard_hashes(tmp_path / "two").items() if k in first}


def test_fixed_friction_and_config_errors(pipeline_run, tmp_path):
    cache = pipeline_run / "cache"
    reports = run_pipeline(PROJECT, small(tmp_path / "o", cache, "metrics.epsilon.friction=0.3"), ["metrics"])
    assert all(r.failed == 0 for r in reports)
    for m in tables(tmp_path / "o", "metrics").values():
        assert np.all(m.column("friction").to_numpy() == 0.3)
    with pytest.raises(ConfigError, match="metrics.closure_frictions: must list at least one"):
        small(tmp_path, cache, "metrics.closure_frictions=[]")
    with pytest.raises(ConfigError, match=r"metrics.closure_frictions\[1\]: must be in \(0, inf\), got 0"):
        small(tmp_path, cache, "metrics.closure_frictions=[0.5, 0]")
    with pytest.raises(ConfigError, match="metrics.epsilon.contact_model: must be one of"):
        small(tmp_path, cache, "metrics.epsilon.contact_model=soft")
    with pytest.raises(ConfigError, match=r"metrics.epsilon.friction: must be in \(0, inf\)"):
        small(tmp_path, cache, "metrics.epsilon.friction=0")
