"""The robustness stage: Wilson intervals, perturbations in the TCP frame, edge versus centre grasps of the bundled
box, contacts of perturbed copies, the radius search, and the stage in a real pipeline (rates, bytes, workers)."""

from __future__ import annotations

import math
from pathlib import Path
from statistics import NormalDist

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import trimesh
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation
from scipy.stats import binomtest

from graspgen.errors import SettingsError
from graspgen.geometry.contacts import closing_contacts
from graspgen.grippers import load_gripper
from graspgen.io.objects import ObjectRecord
from graspgen.quality.contact_noise import MetricsParams
from graspgen.quality.contact_set import contact_set
from graspgen.quality.epsilon import EpsilonParams
from graspgen.quality.perturbation import (
    DRAWS_PER_COPY,
    RobustnessParams,
    perturbed_poses,
    rotvec_to_matrix,
    truncated_friction,
)
from graspgen.quality.resting import _project_onto_halfspaces, resting_com_offset
from graspgen.quality.statistics import wilson_interval
from graspgen.sim.gripper_model import attach_gripper
from graspgen.sim.lift import LiftSimulator
from graspgen.sim.perturbed_copies import (
    initial_object_pose,
    rollout_with_object_pose,
    support_points,
    with_object_pose,
)
from graspgen.sim.protocols import LiftParams
from graspgen.sim.scene_model import build_scene_spec, object_body_name, placed_object
from graspgen.sim.support import SupportParams
from graspgen.workflows.metrics import object_geometry
from graspgen.workflows.prepare import prepare_object
from graspgen.workflows.robustness import GRIP_CODES, SCHEMA, grasp_robustness
from graspgen.workflows.robustness_columns import LABELS, RADIUS_AXES, GraspRobustness, robustness_columns, rows_at
from pipeline.config import load_config
from pipeline.errors import ConfigError
from pipeline.plan import committed
from pipeline.repro import shard_hashes
from pipeline.scheduler import run_pipeline
from pipeline.store import stage_dir
from stages.objects import ASSETS, catalog
from stages.project import PROJECT
from tests.paths import REPO

GRIPPER = load_gripper("robotiq_2f85")
FRICTION = 0.5


pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")


# ------------------------------------------------------------------------------------------------ Wilson interval


@pytest.mark.parametrize(
    "successes, n, lo, hi",
    [
        # Newcombe (1998), Stat. Med. 17:857, Table I, method 3 (Wilson score, no continuity correction)
        (81, 263, 0.2553, 0.3662),
        (15, 148, 0.0624, 0.1605),
        (0, 20, 0.0, 0.1611),
        (1, 29, 0.0061, 0.1718),
        (5, 10, 0.2366, 0.7634),
    ],
)
def test_wilson_interval_known_values(successes, n, lo, hi):
    got = wilson_interval(successes, n)
    assert got == pytest.approx((lo, hi), abs=5e-5)


@pytest.mark.parametrize("n", [1, 5, 20, 100])
def test_wilson_interval_at_the_edges(n):
    z2 = 1.96**2
    # 0/n: [0, z^2 / (n + z^2)]; n/n: [n / (n + z^2), 1]; never a point interval
    assert wilson_interval(0, n) == (0.0, pytest.approx(z2 / (n + z2), rel=1e-12))
    assert wilson_interval(n, n) == (pytest.approx(n / (n + z2), rel=1e-12), 1.0)
    for s in range(n + 1):
        lo, hi = wilson_interval(s, n)
        assert 0.0 <= lo <= s / n <= hi <= 1.0 and lo < hi
    # symmetric: s/n and (n-s)/n mirror each other
    lo, hi = wilson_interval(n // 3, n)
    assert wilson_interval(n - n // 3, n) == (pytest.approx(1 - hi, abs=1e-12), pytest.approx(1 - lo, abs=1e-12))


def test_wilson_interval_narrows_with_n_and_rejects_bad_input():
    widths = [np.subtract(*wilson_interval(n // 2, n)[::-1]) for n in (10, 40, 160)]
    assert widths[0] > widths[1] > widths[2]
    assert all(math.isnan(v) for v in wilson_interval(0, 0))  # no trials, no information
    with pytest.raises(ValueError, match="successes: must be <= n"):
        wilson_interval(3, 2)
    with pytest.raises(ValueError, match=r"n: must be an integer in \[0, inf\)"):
        wilson_interval(0, -1)
    with pytest.raises(ValueError, match="successes: must be an integer"):
        wilson_interval(0.5, 2)
    with pytest.raises(ValueError, match=r"z: must be in \(0, inf\)"):
        wilson_interval(1, 2, z=0)


# ------------------------------------------------------------------------------------------------ perturbations


def test_rotvec_to_matrix_matches_scipy():
    rng = np.random.default_rng(1)
    v = np.concatenate([rng.normal(0, 1, (50, 3)), rng.normal(0, 1e-8, (5, 3)), np.zeros((1, 3))])
    R = rotvec_to_matrix(v)
    np.testing.assert_allclose(R, Rotation.from_rotvec(v).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)


def test_perturbations_are_in_the_tcp_frame():
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [0.3, -1.0, 2.0]).as_matrix()
    T[:3, 3] = (0.1, -0.2, 0.3)
    t = np.array([[0.01, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    w = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.2]])
    P = perturbed_poses(T, t, w)
    np.testing.assert_allclose(P[1], T, atol=1e-15)  # no perturbation: the nominal pose
    np.testing.assert_allclose(P[0][:3, 3], T[:3, 3] + 0.01 * T[:3, 0], atol=1e-15)  # 1 cm along the closing axis
    np.testing.assert_allclose(P[0][:3, :3], T[:3, :3], atol=1e-15)
    # 0.2 rad about the TCP's own approach axis: origin and z stay, x turns within the TCP's x-y plane
    np.testing.assert_allclose(P[2][:3, 3], T[:3, 3], atol=1e-15)
    np.testing.assert_allclose(P[2][:3, 2], T[:3, 2], atol=1e-15)
    assert P[2][:3, 0] @ T[:3, 0] == pytest.approx(math.cos(0.2), abs=1e-12)


# ------------------------------------------------------------------------------------------------ the bundled box


def _bundled_box() -> ObjectRecord:
    return _bundled("box")


def _bundled(name: str) -> ObjectRecord:
    entry = catalog()[name]
    prep = prepare_object(ASSETS / entry["file"], density=entry["density"], rng=np.random.default_rng(0))
    return ObjectRecord(
        name=prep.name,
        vertices=np.asarray(prep.vertices),
        faces=np.asarray(prep.faces),
        convex_parts=[(np.asarray(v), np.asarray(f)) for v, f in prep.convex_parts],
        mass=prep.mass.mass,
        center_of_mass=np.asarray(prep.mass.center_of_mass),
        inertia=np.asarray(prep.mass.inertia),
        stable_poses=np.asarray(prep.stable_transforms),
        stable_probabilities=np.asarray(prep.stable_probabilities),
        attrs={},
    )


@pytest.fixture(scope="module")
def box_scene():
    """The bundled 50 x 70 x 120 mm box in its most probable stable pose (flat on its 70 x 120 face, 50 mm tall)
    on a table, with the 2F-85: (record, simulator, body name, world vertices)."""
    record = _bundled_box()
    pose = record.stable_poses[0]
    spec = build_scene_spec([placed_object(record, pose, FRICTION, visual=False)], SupportParams())
    attach_gripper(spec, GRIPPER)
    verts = record.vertices @ pose[:3, :3].T + pose[:3, 3]
    np.testing.assert_allclose(np.ptp(verts, axis=0), [0.07, 0.12, 0.05], atol=1e-9)  # the pose we think it is
    # The figures in these tests assume 5 mm of clearance per side (the default margin is 10 mm per side).
    sim = LiftSimulator(spec.compile(), LiftParams(width_margin=0.01))
    return record, sim, object_body_name(0, record.name), verts


def _top_down(verts: np.ndarray, along: float) -> tuple[np.ndarray, float]:
    """Top-down grasp across the box's 70 mm extent (closing along world x, onto its 50 x 120 mm faces), ``along``
    metres from its centre along its 120 mm axis (world y), TCP 2 cm below the top. Returns (pose, width)."""
    centre = (verts.max(0) + verts.min(0)) / 2
    T = np.eye(4)
    T[:3, 0] = (1.0, 0.0, 0.0)
    T[:3, 2] = (0.0, 0.0, -1.0)
    T[:3, 1] = np.cross(T[:3, 2], T[:3, 0])
    T[:3, 3] = (centre[0], centre[1] + along, verts[:, 2].max() - 0.02)
    return T, float(np.ptp(verts[:, 0]))


def test_edge_grasp_is_less_robust_than_centre_grasp(box_scene):
    record, sim, body, verts = box_scene
    geometry = object_geometry(record)
    params = RobustnessParams(num_perturbations=120, mass_sigma=0.0, com_sigma=0.0, friction_sigma=0.0)
    # The box ends 60 mm from its centre; the 22 mm wide pads centred 68 mm out overlap its end by 3 mm. Both
    # nominal grasps succeed; copies of the edge grasp also slide off the end (no contact, code 3). Both grasps get
    # the same draws (common random numbers), so the comparison is paired.
    draws = np.random.default_rng(7).standard_normal((params.num_perturbations, DRAWS_PER_COPY))
    labels = {}
    for name, along in (("centre", 0.0), ("edge", 0.068)):
        T, width = _top_down(verts, along)
        assert sim.rollout(T, width, body).success
        labels[name] = grasp_robustness(sim, T, width, body, geometry, FRICTION, draws, params, EpsilonParams(),
                                        GRIPPER)
    centre, edge = labels["centre"], labels["edge"]
    for r in (centre, edge):
        assert 0.0 <= r.robustness <= 1.0 and r.n == 120
        assert r.successes == int(np.sum(r.outcomes == 5)) and r.robustness == r.successes / r.n
        assert r.interval == wilson_interval(r.successes, r.n)
    assert edge.robustness < centre.robustness  # measured: 37/120 against 61/120
    assert np.sum(edge.outcomes == 3) > np.sum(centre.outcomes == 3) == 0
    # Not by chance: exact sign test (McNemar) on the copies where the two disagree. Measured 26 copies succeed only
    # at the centre, 6 only at the edge: p = 3e-4 that a fair coin splits them that unevenly; other seeds give
    # 1e-7 to 2e-3. (With 14 draws per copy: 28 against 4.)
    ok_c, ok_e = centre.outcomes == 5, edge.outcomes == 5
    only_centre, only_edge = int(np.sum(ok_c & ~ok_e)), int(np.sum(ok_e & ~ok_c))
    assert binomtest(only_centre, only_centre + only_edge, 0.5, alternative="greater").pvalue < 0.01


def test_epsilon_from_rollout_and_raycast_contacts_agree_for_a_clean_box_grasp(box_scene):
    record, sim, body, verts = box_scene
    geometry = object_geometry(record)
    T, width = _top_down(verts, 0.0)
    result, T_placed, T_closed = rollout_with_object_pose(sim, T, width, body)
    assert result.success and T_closed is not None
    np.testing.assert_allclose(T_placed, initial_object_pose(sim, body), atol=1e-12)  # the scene at rest
    source, p, n, f = contact_set((result.contact_points, result.contact_normals, result.contact_fingers),
                                  T_closed, None)
    assert source == "rollout" and set(f.tolist()) == {0, 1}
    # the contacts lie on the mesh (MuJoCo's contact point is midway between the surfaces: within a mm)
    _, dist, _ = trimesh.proximity.closest_point(geometry.mesh, p)
    assert dist.max() < 1e-3
    T_object = np.linalg.inv(initial_object_pose(sim, body)) @ T
    (rays,) = closing_contacts(geometry.mesh, T_object, GRIPPER)
    source_r, pr, nr, fr = contact_set(None, np.eye(4), rays)
    assert source_r == "raycast"
    eps = EpsilonParams()
    e_rollout = eps.epsilon(p, n, f, geometry, FRICTION)
    e_raycast = eps.epsilon(pr, nr, fr, geometry, FRICTION)
    assert e_rollout > 0 and e_raycast > 0
    # ... while the same points with every normal tilted 63 degrees the same way (outside the 27 degree cones) are
    # not in closure: no contact can then pull the object back the other way
    axis = n[f == 0].mean(axis=0)
    side = np.cross(axis, (0.0, 0.0, 1.0) if abs(axis[2]) < 0.9 else (1.0, 0.0, 0.0))
    tilted = n + 2.0 * side / np.linalg.norm(side)
    tilted /= np.linalg.norm(tilted, axis=1, keepdims=True)
    assert eps.epsilon(p, tilted, f, geometry, FRICTION) == 0.0


def test_object_noise_and_radius(box_scene):
    record, sim, body, verts = box_scene
    geometry = object_geometry(record)
    T, width = _top_down(verts, 0.0)
    draws = np.random.default_rng(0).standard_normal((4, DRAWS_PER_COPY))
    # Zero noise everywhere, object noise on: every copy is the nominal grasp (a rebuilt simulator at the same pose)
    still = RobustnessParams(num_perturbations=4, translation_sigma=0.0, rotation_sigma=0.0, object_noise=True,
                             object_translation_sigma=0.0, object_rotation_sigma=0.0, mass_sigma=0.0,
                             com_sigma=0.0, friction_sigma=0.0)
    r = grasp_robustness(sim, T, width, body, geometry, FRICTION, draws, still, EpsilonParams(), GRIPPER)
    assert r.robustness == 1.0 and len(set(r.epsilons.tolist())) == 1 and r.epsilons[0] > 0
    # Moving the box 3 cm along its long axis and up to ~60 degrees about z loses some grasps
    moved = RobustnessParams(num_perturbations=4, translation_sigma=0.0, rotation_sigma=0.0, object_noise=True,
                             object_translation_sigma=0.03, object_rotation_sigma=1.0, mass_sigma=0.0,
                             com_sigma=0.0, friction_sigma=0.0)
    assert grasp_robustness(sim, T, width, body, geometry, FRICTION, draws, moved, EpsilonParams(),
                            GRIPPER).robustness < 1.0
    # Radius along the closing axis = the clearance: the jaws open to width + 10 mm, 5 mm each side; a larger
    # offset puts a finger onto the box during the approach (the bisection resolves 20 mm / 2^5 = 0.6 mm).
    radius = grasp_robustness(sim, T, width, body, geometry, FRICTION, draws[:1],
                              RobustnessParams(num_perturbations=1, radius=True), EpsilonParams(), GRIPPER).radius
    assert radius.shape == (len(RADIUS_AXES),) and np.isfinite(radius).all()
    assert 0.004 <= radius[0] <= 0.0056
    # ... and deeper along the approach axis: the TCP is 30 mm above the table, the fingertips 19 mm below the TCP
    assert 0.010 <= radius[2] <= 0.012
    assert np.all(radius[:3] <= 0.02) and np.all(radius[3:] <= 0.5) and np.all(radius >= 0)


def _quiet(**kw) -> RobustnessParams:
    """Every perturbation off, then ``kw``."""
    zero = dict(translation_sigma=0.0, rotation_sigma=0.0, object_translation_sigma=0.0, object_rotation_sigma=0.0,
                mass_sigma=0.0, com_sigma=0.0, friction_sigma=0.0)
    return RobustnessParams(**{**zero, **kw})


def test_truncated_friction():
    assert truncated_friction(0.5, 0.0, 3.0) == 0.5
    zs = np.linspace(-8, 8, 161)
    mus = np.array([truncated_friction(0.1, 0.1, z) for z in zs])
    assert np.all(mus > 0) and np.all(np.diff(mus) >= 0)  # truncated > 0, monotone in the draw
    # five sigmas from the truncation it is the plain normal, mu + sigma z, to 1e-7
    assert truncated_friction(0.5, 0.1, 1.0) == pytest.approx(0.6, abs=1e-7)
    # its mean is the truncated normal's: mu + sigma phi(alpha) / (1 - Phi(alpha)), alpha = -mu / sigma
    z = np.random.default_rng(0).standard_normal(100_000)
    draws = np.array([truncated_friction(0.1, 0.1, v) for v in z])
    nd = NormalDist()
    assert draws.mean() == pytest.approx(0.1 + 0.1 * nd.pdf(-1.0) / (1 - nd.cdf(-1.0)), abs=2e-3)


@pytest.mark.parametrize("along", [0.0, 0.075])
def test_zero_sigmas_every_copy_is_the_nominal_outcome(box_scene, along):
    """With every sigma 0 each copy is the nominal grasp: the same outcome (success at the centre, no contact past
    the box's end) and the same epsilon, also through the rebuilt (object-noise / physics) simulator."""
    record, sim, body, verts = box_scene
    geometry = object_geometry(record)
    T, width = _top_down(verts, along)
    nominal = sim.rollout(T, width, body).code
    assert nominal == (5 if along == 0.0 else 3)
    draws = np.random.default_rng(1).standard_normal((3, DRAWS_PER_COPY))
    for params in (_quiet(num_perturbations=3), _quiet(num_perturbations=3, object_noise=True)):
        r = grasp_robustness(sim, T, width, body, geometry, FRICTION, draws, params, EpsilonParams(), GRIPPER)
        assert r.outcomes.tolist() == [nominal] * 3
        assert len(set(r.epsilons.tolist())) == 1
        assert r.grip_n == 3 and r.grip_robustness == r.robustness == (1.0 if nominal == 5 else 0.0)


def test_grip_robustness_leaves_out_approach_collisions(box_scene):
    """1 mm of clearance per side against 5 mm of TCP error: most copies land a finger on the box (code 1) or push
    it on the approach, but those that reach it hold. grip_robustness counts only those."""
    record, sim, body, verts = box_scene
    tight = LiftSimulator(sim.model, LiftParams(width_margin=0.002))
    geometry = object_geometry(record)
    T, width = _top_down(verts, 0.0)
    assert tight.rollout(T, width, body).success
    params = RobustnessParams(num_perturbations=40)
    draws = np.random.default_rng(3).standard_normal((40, DRAWS_PER_COPY))
    r = grasp_robustness(tight, T, width, body, geometry, FRICTION, draws, params, EpsilonParams(), GRIPPER)
    codes = r.outcomes
    reached = np.isin(codes, GRIP_CODES)
    assert np.sum(~reached) >= 10 and set(codes[~reached].tolist()) <= {0, 1, 2}  # failure causes kept per copy
    assert r.grip_n == int(reached.sum()) and r.grip_robustness == r.successes / r.grip_n
    assert r.grip_interval == wilson_interval(r.successes, r.grip_n)
    # measured: 35 of 40 copies code 1, the 5 that reached the box all held (0.125 against 1.0)
    assert r.grip_robustness > r.robustness and r.grip_robustness >= 0.8


def test_heavy_slippery_copies_slip(box_scene):
    """Mass x10 at friction 0.2: 30 N per jaw at mu 0.2 holds 12 N, the box then weighs ~10x its nominal weight: the
    copies slip (code 4). The same draws without the mass and friction entries succeed."""
    record, sim, body, verts = box_scene
    geometry = object_geometry(record)
    T, width = _top_down(verts, 0.0)
    params = _quiet(num_perturbations=4, mass_sigma=1.0, friction_sigma=0.1)
    nd = NormalDist()
    a = nd.cdf(-FRICTION / 0.1)
    z_mu = nd.inv_cdf((nd.cdf((0.2 - FRICTION) / 0.1) - a) / (1 - a))
    assert truncated_friction(FRICTION, 0.1, z_mu) == pytest.approx(0.2, abs=1e-9)
    plain = np.zeros((4, DRAWS_PER_COPY))
    heavy = plain.copy()
    heavy[:, 9], heavy[:, 13] = math.log(10.0), z_mu
    base = grasp_robustness(sim, T, width, body, geometry, FRICTION, plain, params, EpsilonParams(), GRIPPER)
    hard = grasp_robustness(sim, T, width, body, geometry, FRICTION, heavy, params, EpsilonParams(), GRIPPER)
    assert base.robustness == 1.0
    assert hard.robustness < base.robustness and set(hard.outcomes.tolist()) == {4}
    assert hard.grip_robustness == 0.0 and hard.grip_n == 4  # they reached the grip: a grip failure
    # the copies' epsilon follows their friction (smaller cones)
    assert 0 <= hard.epsilons[0] < base.epsilons[0]


def test_same_draws_same_bytes(box_scene):
    record, sim, body, verts = box_scene
    geometry = object_geometry(record)
    T, width = _top_down(verts, 0.0)
    params = RobustnessParams(num_perturbations=3, object_noise=True, com_sigma=0.005)  # every perturbation on
    draws = np.random.default_rng(5).standard_normal((3, DRAWS_PER_COPY))
    a, b = (grasp_robustness(sim, T, width, body, geometry, FRICTION, draws, params, EpsilonParams(), GRIPPER)
            for _ in range(2))
    assert a.outcomes.tobytes() == b.outcomes.tobytes() and a.epsilons.tobytes() == b.epsilons.tobytes()


# ------------------------------------------------------------------------------------------------ the stage


def small(out: Path, cache: Path, *sets: str):
    """The smoke config cut to the two convex objects (no CoACD), two scenes and 6 copies per grasp."""
    return load_config(
        PROJECT.schema,
        REPO / "configs" / "smoke.yaml",
        [
            f"run.out={out}",
            f"run.cache_dir={cache}",
            "run.jobs=1",
            "objects.include=[box, cylinder]",
            "scenes.num_scenes=2",
            "robustness.num_perturbations=6",
            *sets,
        ],
    )


def tables(out: Path, stage: str) -> dict:
    return {e.task: pq.read_table(stage_dir(out, stage) / e.file) for e in committed(out, stage).values()}


@pytest.fixture(scope="module")
def pipeline_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("robustness")
    reports = run_pipeline(PROJECT, small(root / "out", root / "cache"), ["robustness"])
    assert all(r.failed == 0 for r in reports), [r.failures for r in reports]
    return root


def test_robustness_is_a_rate_on_a_real_pipeline_run(pipeline_run):
    out = pipeline_run / "out"
    rollouts, robust = tables(out, "rollouts"), tables(out, "robustness")
    assert set(robust) == set(rollouts) and robust
    evaluated = 0
    for sid, t in robust.items():
        assert t.schema.equals(SCHEMA)
        r = rollouts[sid]
        assert t.column("grasp_id").to_pylist() == r.column("grasp_id").to_pylist()
        ok = r.column("outcome").to_numpy() == 5
        n = t.column("n").to_numpy()
        rate = t.column("robustness").to_numpy()
        assert np.array_equal(n, np.where(ok, 6, 0))
        # not successful: not measured (NaN), never 0
        assert np.isnan(rate[~ok]).all() and np.isnan(t.column("pfc").to_numpy()[~ok]).all()
        lo, hi = t.column("robustness_lo").to_numpy(), t.column("robustness_hi").to_numpy()
        assert np.all((rate[ok] >= 0) & (rate[ok] <= 1)) and np.all((lo[ok] <= rate[ok]) & (rate[ok] <= hi[ok]))
        grip = t.column("grip_robustness").to_numpy()
        assert np.isnan(grip[~ok]).all()
        outcomes, eps = t.column("copy_outcomes").to_pylist(), t.column("copy_epsilon").to_pylist()
        for i in np.flatnonzero(ok):
            codes = np.array(outcomes[i])
            assert len(codes) == len(eps[i]) == 6 and set(codes.tolist()) <= set(range(6))
            assert rate[i] == np.mean(codes == 5)  # a success fraction, not an average of codes
            reached = int(np.sum(codes >= 3))
            if reached:
                assert grip[i] == np.sum(codes == 5) / reached >= rate[i]
                assert (t.column("grip_robustness_lo")[i].as_py(), t.column("grip_robustness_hi")[i].as_py()) == \
                    wilson_interval(int(np.sum(codes == 5)), reached)
            else:
                assert np.isnan(grip[i])
            assert t.column("pfc")[i].as_py() == np.mean(np.array(eps[i]) > 0.0)
        for axis in RADIUS_AXES:  # off by default
            assert np.isnan(t.column(f"radius_{axis}").to_numpy()).all()
        evaluated += int(ok.sum())
    assert evaluated > 0


def test_same_key_same_bytes_and_independent_of_workers(pipeline_run, tmp_path):
    cache = pipeline_run / "cache"
    again = run_pipeline(PROJECT, small(tmp_path / "again", cache), ["robustness"])
    two = run_pipeline(PROJECT, small(tmp_path / "two", cache, "run.jobs=2"), ["robustness"])
    assert all(r.failed == 0 for r in again + two)
    first = {k: v for k, v in shard_hashes(pipeline_run / "out").items() if k.startswith("robustness/")}
    assert first and first == {k: v for k, v in shard_hashes(tmp_path / "again").items() if k in first}
    assert first == {k: v for k, v in shard_hashes(tmp_path / "two").items() if k in first}


def test_the_key_follows_the_rollout_protocol_and_the_epsilon_model(pipeline_run):
    out, cache = pipeline_run / "out", pipeline_run / "cache"
    stage = PROJECT.stage("robustness")
    base = stage.params(small(out, cache))
    assert base.lift == small(out, cache).rollouts.lift and base.epsilon == small(out, cache).metrics.epsilon
    changed = stage.params(small(out, cache, "metrics.epsilon.torsional_friction=0.001"))
    assert changed != base
    # the GraspNet label's friction list is not part of it: changing it does not re-run robustness rollouts
    assert stage.params(small(out, cache, "metrics.closure_frictions=[0.5, 1.0]")) == base


def test_config_errors_name_the_key(tmp_path):
    with pytest.raises(ConfigError, match="robustness.num_perturbations: must be a positive integer, got 0"):
        small(tmp_path, tmp_path, "robustness.num_perturbations=0")
    with pytest.raises(ConfigError, match=r"robustness.translation_sigma: must be in \[0, inf\), got -0.001"):
        small(tmp_path, tmp_path, "robustness.translation_sigma=-0.001")
    with pytest.raises(ConfigError, match="robustness.radius_max_rotation: must be in"):
        small(tmp_path, tmp_path, "robustness.radius_max_rotation=4")


# ------------------------------------------------------------------------------------------------ centre of mass


def _slow_projection(x: np.ndarray, A: np.ndarray, b: np.ndarray, start: np.ndarray) -> np.ndarray:
    """The nearest point of ``{y : A y >= b}`` to ``x`` by a general-purpose constrained minimiser (SLSQP)."""
    return minimize(lambda y: np.sum((y - x) ** 2), start, jac=lambda y: 2 * (y - x), method="SLSQP",
                    constraints=[{"type": "ineq", "fun": lambda y: A @ y - b, "jac": lambda y: A}],
                    options={"ftol": 1e-14, "maxiter": 500}).x


def test_projection_onto_halfspaces_matches_a_slow_quadratic_program():
    rng = np.random.default_rng(3)
    for _ in range(20):
        A = rng.standard_normal((6, 3))
        inside = rng.standard_normal(3) * 0.01
        b = A @ inside - rng.random(6) * 0.01  # the set holds `inside`
        x = inside + rng.standard_normal(3) * 0.05
        ours = _project_onto_halfspaces(x, A, b)
        slow = _slow_projection(x, A, b, inside)
        assert np.all(A @ ours - b >= -1e-9)
        np.testing.assert_allclose(ours, slow, atol=1e-6)


def _resting(record: ObjectRecord, pose: np.ndarray) -> tuple[LiftSimulator, str]:
    spec = build_scene_spec([placed_object(record, pose, FRICTION, visual=False)], SupportParams())
    attach_gripper(spec, GRIPPER)
    return LiftSimulator(spec.compile(), LiftParams()), object_body_name(0, record.name)


def _drift(simulator: LiftSimulator, body: str, offset: np.ndarray, seconds: float = 0.6) -> float:
    """How far (m) the target's origin moves in ``seconds`` with its centre of mass moved by ``offset`` (mesh frame)
    and nothing touching it but its support (the gripper made non-colliding)."""
    import mujoco

    m = with_object_pose(simulator, body, None, 1.0, offset, None).model
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, int(b)) or "" for b in m.geom_bodyid]
    gripper = np.array([n.startswith("gripper/") for n in names])
    m.geom_contype[gripper] = 0
    m.geom_conaffinity[gripper] = 0
    d = mujoco.MjData(m)
    d.qpos[:] = m.qpos0
    bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, body)
    mujoco.mj_forward(m, d)
    start = d.xpos[bid].copy()
    for _ in range(int(seconds / m.opt.timestep)):
        mujoco.mj_step(m, d)
    return float(np.linalg.norm(d.xpos[bid] - start))


def test_support_of_a_box_lying_flat_is_its_bottom_face(box_scene):
    record, sim, body, verts = box_scene
    support = support_points(sim, body)
    T = initial_object_pose(sim, body)
    world = support @ T[:3, :3].T + T[:3, 3]
    assert len(world) == 4  # the four corners of the 70 x 120 mm face
    np.testing.assert_allclose(np.ptp(world[:, :2], axis=0), [0.07, 0.12], atol=1e-4)
    assert np.ptp(world[:, 2]) < 1e-4 and abs(world[:, 2].min() - verts[:, 2].min()) < 1e-4
    # Offsets well inside the face are kept whole; one past its edge is pulled back inside, the height kept
    kept = np.array([0.004, -0.003, 0.005])
    np.testing.assert_allclose(resting_com_offset(kept, support, T, record.center_of_mass), kept, atol=1e-12)
    far = T[:3, :3].T @ np.array([0.06, 0.0, 0.002])  # 6 cm along world x: the face's half width is 35 mm
    pulled = T[:3, :3] @ resting_com_offset(far, support, T, record.center_of_mass)
    assert 0.02 < pulled[0] < 0.035 and abs(pulled[1]) < 1e-6 and pulled[2] == pytest.approx(0.002, abs=1e-6)


def test_a_cylinder_on_its_side_keeps_only_offsets_that_do_not_roll_it():
    record = _bundled("cylinder")
    axis_horizontal = [i for i, P in enumerate(record.stable_poses) if abs(P[2, 2]) < 0.1]  # mesh z = its axis
    assert axis_horizontal, "the bundled cylinder should have a stable pose on its side"
    sim, body = _resting(record, record.stable_poses[axis_horizontal[0]])
    support = support_points(sim, body)
    T = initial_object_pose(sim, body)
    R = T[:3, :3]
    world = support @ R.T + T[:3, 3]
    across = np.cross([0.0, 0.0, 1.0], R[:, 2])
    assert np.ptp(world @ R[:, 2]) > 0.1 and np.ptp(world @ across) < 3e-3  # a line (or a facet) along the axis
    rng = np.random.default_rng(5)
    raw_drift, kept_drift = [], []
    for _ in range(8):
        offset = 0.005 * rng.standard_normal(3)
        kept = resting_com_offset(offset, support, T, record.center_of_mass)
        assert abs((R @ kept) @ R[:, 2] - (R @ offset) @ R[:, 2]) < 1e-9  # along the axis: kept
        assert abs((R @ kept) @ across) <= abs((R @ offset) @ across) + 1e-12
        raw_drift.append(_drift(sim, body, offset))
        kept_drift.append(_drift(sim, body, kept))
    # Unprojected, a centre off the support rolls the cylinder away before any hand arrives; projected, it moves no
    # more than the nominal cylinder does (placed at its stable pose unsettled, it sinks into the soft contact)
    nominal = _drift(sim, body, np.zeros(3))
    assert max(raw_drift) > nominal + 0.005
    assert max(kept_drift) < nominal + 5e-4


def test_no_support_in_free_space_keeps_the_offset():
    offset = np.array([0.003, -0.002, 0.001])
    np.testing.assert_array_equal(resting_com_offset(offset, np.zeros((0, 3)), np.eye(4), np.zeros(3)), offset)


# ------------------------------------------------------------------------------------------------ settings, columns


def test_settings_are_typed_and_name_the_field():
    with pytest.raises(SettingsError, match="num_perturbations: must be a positive integer, got 2.5"):
        RobustnessParams(num_perturbations=2.5)
    with pytest.raises(SettingsError, match="radius: must be a bool, got 'yes'"):
        RobustnessParams(radius="yes")
    with pytest.raises(SettingsError, match=r"mass_sigma: must be in \[0, 2\], got 3.0"):
        RobustnessParams(mass_sigma=3.0)
    with pytest.raises(SettingsError, match="com_sigma: must be finite"):
        RobustnessParams(com_sigma=math.inf)
    with pytest.raises(SettingsError, match="num_cone_edges: must be an integer, got 8.0"):
        EpsilonParams(num_cone_edges=8.0)
    with pytest.raises(SettingsError, match=r"closure_frictions\[1\]: must be a number, got 'x'"):
        MetricsParams(closure_frictions=(0.5, "x"))
    with pytest.raises(SettingsError, match="epsilon: must be an EpsilonParams, got dict"):
        MetricsParams(epsilon={})


def _labels_row(outcomes: list[int], epsilons: list[float]) -> GraspRobustness:
    outcomes = np.array(outcomes, dtype=np.int8)
    successes, grip_n = int((outcomes == 5).sum()), int((outcomes >= 3).sum())
    return GraspRobustness(n=len(outcomes), successes=successes, robustness=successes / len(outcomes),
                           interval=wilson_interval(successes, len(outcomes)), grip_n=grip_n,
                           grip_robustness=successes / grip_n if grip_n else math.nan,
                           grip_interval=wilson_interval(successes, grip_n), pfc=float(np.mean(np.array(epsilons) > 0)),
                           outcomes=outcomes, epsilons=np.array(epsilons), sources=("rollout",) * len(outcomes),
                           radius=np.arange(6, dtype=np.float64) / 100)


def test_one_robustness_column_builder_for_the_stage_and_evaluate():
    a, b = _labels_row([5, 5, 1], [0.1, 0.2, 0.0]), _labels_row([1, 0], [0.0, 0.0])
    rows = rows_at(4, [3, 1], [a, b])
    assert rows == [None, b, None, a]
    table = pa.table(dict(zip(LABELS, robustness_columns(rows))))
    assert table.schema == pa.schema(list(SCHEMA)[2:])  # the stage's table: scene_id, grasp_id, then the labels
    assert table.column("n").to_pylist() == [0, 2, 0, 3]
    assert table.column("successes").to_pylist() == [0, 0, 0, 2]
    assert table.column("robustness").to_pylist()[1::2] == [0.0, 2 / 3]
    assert table.column("grip_robustness_lo").to_pylist()[3] == wilson_interval(2, 2)[0]
    assert math.isnan(table.column("grip_robustness").to_pylist()[1])  # no copy of b reached the grip
    assert table.column("copy_outcomes").to_pylist() == [[], [1, 0], [], [5, 5, 1]]
    assert table.column("copy_epsilon").to_pylist()[3] == [0.1, 0.2, 0.0]
    assert table.column("radius_rz").to_pylist()[3] == 0.05
    for name in LABELS[2:]:  # a grasp not perturbed: NaN labels and no copies, never a measured 0
        value = table.column(name).to_pylist()[0]
        assert value == [] if name.startswith("copy_") else math.isnan(value)
    # evaluate's subset, in its order and under its own names, gives the same arrays
    subset = ("n", "successes", "robustness", "copy_outcomes")
    picked = robustness_columns(rows, subset)
    assert [c.type for c in picked] == [SCHEMA.field(n).type for n in subset]
    assert [repr(c.to_pylist()) for c in picked] == [repr(table.column(n).to_pylist()) for n in subset]  # NaN != NaN
    with pytest.raises(SettingsError, match="labels: unknown 'robustness_n'"):
        robustness_columns(rows, ("robustness_n",))
