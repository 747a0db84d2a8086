"""Object-centric grasp sets (graspgen.workflows.object_grasps and the object_grasps stage): analytic grasps on a box,
the targets, the near misses, whole-sphere coverage, determinism, and the stage in the smoke pipeline."""

from __future__ import annotations

import math

import numpy as np
import pyarrow.parquet as pq
import pytest
import trimesh

from graspgen.errors import SettingsError
from graspgen.grippers import load_gripper
from graspgen.io.arrow import column_array, list_rows
from graspgen.io.files import write_parquet
from graspgen.io.objects import ObjectRecord
from graspgen.sim.protocols import Outcome
from graspgen.workflows.near_misses import near_miss_offsets
from graspgen.workflows.object_grasps import SCHEMA, free_space_simulator, label_object_grasps
from graspgen.workflows.object_grasps_settings import ObjectGraspsParams, default_overhang, default_tilt
from pipeline.config import load_config
from pipeline.errors import ConfigError
from pipeline.plan import committed
from pipeline.scheduler import run_pipeline
from pipeline.store import stage_dir
from stages.config import Config
from stages.object_grasps import shortfall
from stages.project import PROJECT
from tests.shapes import top_down

PANDA = load_gripper("panda")
HALF = np.array([0.02, 0.025, 0.03])  # the box's half extents, m: 40 x 50 x 60 mm, all within the Panda's 80 mm


@pytest.fixture(scope="module")
def box() -> ObjectRecord:
    """A 40 x 50 x 60 mm box of 500 kg/m^3 centred on its mesh frame, one convex part (itself)."""
    mesh = trimesh.creation.box(extents=2 * HALF)
    mesh.density = 500.0
    v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int32)
    return ObjectRecord(name="box", vertices=v, faces=f, convex_parts=[(v, f)], mass=float(mesh.mass),
                        center_of_mass=np.zeros(3), inertia=np.asarray(mesh.moment_inertia),
                        stable_poses=np.eye(4)[None], stable_probabilities=np.ones(1), attrs={})



def params(**kw) -> ObjectGraspsParams:
    return ObjectGraspsParams(**{"selection": "balanced", "label": "held", "target_positives": 1000,
                                 "target_negatives": 1000, "batch_size": 16, "near_miss_fraction": 0.25, **kw})


@pytest.fixture(scope="module")
def two_batches(box):
    """Two batches of 16 on the box (4 near misses each), every candidate kept (targets far away)."""
    return label_object_grasps(box, params(max_candidates=32), np.random.default_rng(7))


# ------------------------------------------------------------------------------------------------ analytic grasps


def test_a_box_grasped_across_its_faces_is_held_and_pads_beside_it_miss(box):
    simulator, body = free_space_simulator(box, "panda", ObjectGraspsParams().lift, 1.0)
    # Pads on the two 50 x 60 faces, 10 mm below the top face: the object stays between the fingers.
    held = simulator.rollout(top_down(0.0, 0.0, HALF[2] - 0.01), 0.04, body)
    assert held.code == Outcome.SUCCESS
    assert set(held.contact_fingers.tolist()) == {0, 1}
    assert held.closed_width == pytest.approx(2 * HALF[0], abs=1e-3)  # the jaws stopped on the 40 mm faces
    # The same hand 50 mm to the side: the 17.4 mm pads (and 21 mm fingers) pass beside the 50 mm face.
    beside = simulator.rollout(top_down(0.0, HALF[1] + 0.025, HALF[2] - 0.01), 0.04, body)
    # ... and 20 mm above the top face: the pads (8.8 mm half length) close on air above it.
    above = simulator.rollout(top_down(0.0, 0.0, HALF[2] + 0.02), 0.04, body)
    for result in (beside, above):
        assert result.code == Outcome.NO_CONTACT_ESTABLISHED and result.decided_in == "closing"
        assert result.closed_width == pytest.approx(PANDA.min_width, abs=1e-3)  # closed fully on nothing


def test_kept_contacts_lie_on_the_box_and_only_successes_have_an_epsilon(two_batches):
    table, _ = two_batches
    success = table.column("success").to_numpy(zero_copy_only=False)
    assert success.any() and (~success).any()
    points = list_rows(table, "contact_points", 3, np.float64)
    epsilon = table.column("epsilon").to_numpy()
    for i in np.flatnonzero(success):
        # mapped with the box's pose at the end of closing: on its surface (MuJoCo's point is mid-penetration)
        outside = np.abs(points[i]) - HALF
        assert np.all(outside.max(axis=1) == pytest.approx(0.0, abs=5e-4)), points[i]
        assert np.isfinite(epsilon[i]) and epsilon[i] >= 0.0
    assert np.isnan(epsilon[~success]).all()
    assert (table.column("robustness_n").to_numpy() == 0).all()
    assert np.isnan(table.column("robustness").to_numpy()).all()


# ------------------------------------------------------------------------------------------------ the loop


def test_targets_stop_the_loop_when_reachable(box):
    table, meta = label_object_grasps(box, params(target_positives=4, target_negatives=3, max_candidates=400),
                                      np.random.default_rng(1))
    success = table.column("success").to_numpy(zero_copy_only=False)
    assert (meta["positives"], meta["negatives"]) == (4, 3) == (int(success.sum()), int((~success).sum()))
    assert meta["reached"] and meta["stopped"] == "targets" and shortfall("box", meta) is None
    assert table.column("grasp_id").to_pylist() == list(range(7))
    # Nothing was rolled out after the last kept row, and every rollout is in the histogram.
    assert sum(meta["outcomes"].values()) == meta["tried"] == sum(meta["candidates"].values()) <= 400
    assert table.schema.equals(SCHEMA)


def test_too_few_candidates_leave_the_targets_unmet_with_a_warning(box):
    table, meta = label_object_grasps(box, params(target_positives=50, target_negatives=50, max_candidates=8),
                                      np.random.default_rng(2))
    assert meta["tried"] == 8 == len(table) and not meta["reached"] and meta["stopped"] == "max_candidates"
    assert shortfall("box", meta) == (f"object 'box': {meta['positives']} of 50 positives, {meta['negatives']} of 50 "
                                      "negatives after 8 candidates (object_grasps.max_candidates)")


def test_near_misses_are_their_share_and_sit_one_offset_from_an_antipodal_parent(two_batches):
    table, meta = two_batches
    kind = np.array(table.column("candidate").to_pylist())
    assert len(table) == 32 and meta["candidates"] == {"antipodal": 24, "near_miss": 8}
    assert (kind == "near_miss").sum() == 8
    T = column_array(table, "pose_object", (4, 4))
    width = table.column("width").to_numpy()
    overhang, tilt = default_overhang(PANDA), default_tilt(PANDA)
    success = table.column("success").to_numpy(zero_copy_only=False)
    good = np.flatnonzero((kind[:16] == "antipodal") & success[:16])
    assert len(good)  # the box's first batch holds, so the second batch's parents are those successes
    for b in (0, 1):  # near misses of the antipodal successes so far; before the first, of the batch's own
        rows = np.arange(16 * b, 16 * b + 16)
        parents = rows[kind[rows] == "antipodal"] if b == 0 else good
        for i in rows[kind[rows] == "near_miss"]:
            D = np.linalg.inv(T[parents]) @ T[i]
            R, t = D[:, :3, :3], D[:, :3, 3]
            angle = np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1))
            shifted = (angle < 1e-9) & (np.abs(t[:, 0]) < 1e-12) & (np.linalg.norm(t, axis=1) > overhang - 1e-12)
            axis_z = (R[:, 1, 0] - R[:, 0, 1])  # the rotation axis's z component times 2 sin(angle)
            tilted = (np.abs(angle - tilt) < 1e-9) & (np.abs(axis_z) < 1e-9) & (np.linalg.norm(t, axis=1) < 1e-12)
            match = np.flatnonzero(shifted | tilted)
            assert len(match) >= 1, i
            assert width[i] in width[parents[match]]  # the parent's width


def test_near_miss_offsets_put_the_contact_past_the_pad_edge_or_tilt_the_hand():
    depth = np.repeat([0.0, 0.0038], 8)
    draws = np.stack([np.tile([0.1, 0.2, 0.3, 0.4, 0.6, 0.7, 0.8, 0.9], 2), np.linspace(0.01, 0.99, 16)], axis=1)
    overhang, tilt = 0.004, 0.3
    D = near_miss_offsets(depth, draws, PANDA, overhang, tilt)
    half = np.array(PANDA.pad_size[1:]) / 2  # pad face: half width (y), half length (z)
    for k in range(16):
        if draws[k, 0] < 0.5:  # shifted in the pad plane; the contact (0, depth) moves by -t relative to the pads
            np.testing.assert_array_equal(D[k, :3, :3], np.eye(3))
            t = D[k, 1:3, 3]
            assert D[k, 0, 3] == 0.0
            u = t / np.linalg.norm(t)
            at_edge = np.array([0.0, depth[k]]) - (np.linalg.norm(t) - overhang) * u
            assert np.max(np.abs(at_edge) - half) == pytest.approx(0.0, abs=1e-12)  # on the pad face's boundary
        else:  # tilted about an axis perpendicular to the approach, through the TCP
            np.testing.assert_array_equal(D[k, :3, 3], 0.0)
            R = D[k, :3, :3]
            assert math.acos((np.trace(R) - 1) / 2) == pytest.approx(tilt, abs=1e-12)
            axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
            assert abs(axis[2]) < 1e-12 and np.linalg.norm(axis) > 0.1


def test_approach_axes_cover_the_whole_sphere(two_batches):
    table, _ = two_batches
    z = column_array(table, "pose_object", (4, 4))[:, :3, 2]  # approach axes in the object frame
    assert (z[:, 2] > 0.5).any() and (z[:, 2] < -0.5).any()  # from below as well as from above
    assert (np.abs(z).argmax(axis=1)[:, None] == np.arange(3)).any(axis=0).sum() >= 2  # several face normals


def test_same_seed_same_bytes_other_seed_other_bytes(box, tmp_path):
    p = params(target_positives=2, target_negatives=2, max_candidates=12)
    for name, seed in (("a", 3), ("b", 3), ("c", 4)):
        write_parquet(tmp_path / f"{name}.parquet", label_object_grasps(box, p, np.random.default_rng(seed))[0])
    a, b, c = ((tmp_path / f"{n}.parquet").read_bytes() for n in "abc")
    assert a == b and a != c


def test_the_graspgen_protocol_opens_fully_and_tugs(box):
    table, meta = label_object_grasps(box, params(protocol="graspdatagen", target_positives=1, target_negatives=1,
                                                  max_candidates=32), np.random.default_rng(6))
    assert meta["protocol"] == "graspdatagen" and meta["positives"] == 1 and len(table) == 2
    assert set(table.column("protocol").to_pylist()) == {"graspdatagen"}
    assert table.column("open_width").to_pylist() == [PANDA.max_width] * 2  # GraspDataGen's open limit
    held = table.filter(table.column("success"))
    assert held.column("decided_in").to_pylist() == ["end"]  # all five tugs ran
    assert held.column("motion_shaking_linear").to_numpy()[0] >= 0.0


def test_robustness_copies_of_the_successes(box):
    table, meta = label_object_grasps(box, params(target_positives=2, target_negatives=0, max_candidates=64,
                                                  num_perturbations=3), np.random.default_rng(5))
    assert meta["positives"] == 2 and len(table) == 2 and meta["robustness"]["copies"] == 6
    assert (table.column("robustness_n").to_numpy() == 3).all()
    assert set(table.column("robustness").to_numpy().tolist()) <= {0.0, 1 / 3, 2 / 3, 1.0}


# ------------------------------------------------------------------------------------------------ settings


def test_settings_take_only_free_space_protocols_and_the_whole_sphere():
    with pytest.raises(SettingsError, match=r"protocol: must be one of acronym, graspdatagen .*got 'table'"):
        ObjectGraspsParams(protocol="table")
    p = ObjectGraspsParams(protocol="graspdatagen")
    assert p.lift.protocol == "graspdatagen" and p.sampler.approach == "any"
    with pytest.raises(SettingsError, match="gripper: unknown 'nope'"):
        ObjectGraspsParams(gripper="nope")
    with pytest.raises(SettingsError, match="near_miss_fraction"):
        ObjectGraspsParams(near_miss_fraction=1.0)


@pytest.mark.parametrize("overrides, message", [
    (["object_grasps.protocol=graspgen"], "object_grasps.protocol: protocol 'graspgen' was renamed 'graspdatagen'"),
    (["physics.graspgen.tug_time=1.0"], "physics.graspgen: section 'graspgen' was renamed 'graspdatagen'"),
    (["object_grasps.lift.protocol=graspgen"], "object_grasps.lift.protocol: moved to object_grasps.protocol"),
    (["object_grasps.lift.graspgen.tug_time=1.0"], "object_grasps.lift.graspgen.tug_time: moved to "
                                                   "physics.graspdatagen.tug_time"),
])
def test_a_config_with_the_former_protocol_name_is_told_the_new_one(overrides, message):
    """GraspDataGen's protocol and its section were called ``graspgen``: users' configs are told the new name."""
    with pytest.raises(ConfigError) as err:
        load_config(Config, None, overrides)
    assert message in str(err.value)
    with pytest.raises(SettingsError, match="protocol: protocol 'graspgen' was renamed 'graspdatagen'"):
        ObjectGraspsParams(protocol="graspgen")


# ------------------------------------------------------------------------------------------------ the stage


def test_the_stage_runs_in_the_smoke_pipeline(tmp_path):
    out = tmp_path / "out"
    cfg = load_config(PROJECT.schema, "configs/smoke.yaml",
                      [f"run.out={out}", f"run.cache_dir={tmp_path / 'cache'}", "run.jobs=1"])
    reports = {r.stage: r for r in run_pipeline(PROJECT, cfg, ["object_grasps"])}
    assert set(reports) == {"objects", "object_grasps"} and reports["object_grasps"].failed == 0
    entries = committed(out, "object_grasps")
    assert sorted(e.task for e in entries.values()) == sorted(cfg.objects.include)
    og = cfg.object_grasps
    for e in entries.values():
        table = pq.read_table(stage_dir(out, "object_grasps") / e.file)
        assert table.schema.equals(SCHEMA, check_metadata=False)
        positive = table.column(og.label_column).to_numpy(zero_copy_only=False)
        assert og.selection == "natural" and og.label == "firm"
        assert positive.sum() == e.meta["positives"] and (~positive).sum() == e.meta["negatives"]
        collision = table.column("outcome").to_numpy() <= Outcome.COLLISION_WITH_CLUTTER
        assert (~collision).sum() <= og.target_grasps and e.meta["tried"] <= og.max_candidates
        assert collision.sum() == e.meta["collision_negatives"] <= og.collision_share_of_negatives * e.meta["negatives"]
        assert set(table.column("object_name").to_pylist()) <= {e.task}
        assert bool(e.meta.get("warnings")) == (not e.meta["reached"])


def test_collisions_fill_at_most_their_share_of_the_negatives(box):
    """``collision_share_of_negatives`` caps the kept collisions (outcomes 0-2); the other failures are kept as they
    come. Reference: every failure of the same 48 trials (nothing capped, targets out of reach), filtered by hand."""
    every = label_object_grasps(box, params(max_candidates=48, collision_share_of_negatives=1.0),
                                np.random.default_rng(3))[0]
    codes = every.column("outcome").to_numpy()
    failures = [i for i in range(len(codes)) if codes[i] != Outcome.SUCCESS]
    assert sum(codes[i] <= Outcome.COLLISION_WITH_CLUTTER for i in failures) >= 3, "need collisions to cap"
    expected, collisions = [], 0
    for i in failures:  # the rule by hand: 8 negatives, of which at most 2 (0.25 x 8) collisions
        if len(expected) == 8:
            break
        if codes[i] <= Outcome.COLLISION_WITH_CLUTTER:
            if collisions == 2:
                continue
            collisions += 1
        expected.append(i)
    capped, meta = label_object_grasps(
        box, params(max_candidates=48, target_negatives=8, collision_share_of_negatives=0.25), np.random.default_rng(3))
    kept = capped.filter(np.asarray(capped.column("success").to_pylist()) == False)  # noqa: E712
    assert meta["collision_negatives"] == collisions <= 2
    np.testing.assert_array_equal(column_array(kept, "pose_object", (16,)),
                                  column_array(every, "pose_object", (16,))[expected])


def test_once_the_positives_are_in_the_batches_are_mostly_near_misses(box):
    """After ``target_positives`` successes only failures are kept: the batches turn to near misses (0.8 of 16 = 13
    each), where the failures are; with the same share as before (0.25 = 4 of 16) nothing changes."""
    kw = {"target_positives": 2, "max_candidates": 160}
    meta = label_object_grasps(box, params(**kw), np.random.default_rng(5))[1]
    same = label_object_grasps(box, params(**kw, near_miss_fraction_when_positives_met=0.25),
                               np.random.default_rng(5))[1]
    assert same["candidates"] == {"antipodal": 120, "near_miss": 40}  # 10 batches of 12 + 4
    assert meta["positives"] == 2 and meta["candidates"]["near_miss"] >= 4 * 2 + 13 * 8  # late from batch 3 on
    with pytest.raises(SettingsError, match="near_miss_fraction_when_positives_met"):
        params(near_miss_fraction_when_positives_met=1.0)


# ------------------------------------------------------------------------------------------------ natural selection


def test_a_natural_set_keeps_every_collision_free_rollout_in_trial_order(box):
    """``natural`` keeps what the balanced loop keeps with no near misses, no collisions and targets out of reach
    (the reference), up to ``target_grasps``; its positives are the firm label's."""
    reference = label_object_grasps(
        box, params(max_candidates=96, near_miss_fraction=0.0, collision_share_of_negatives=0.0),
        np.random.default_rng(4))[0]
    codes = reference.column("outcome").to_numpy()
    assert (codes > Outcome.COLLISION_WITH_CLUTTER).all() and len(reference) >= 10
    natural, meta = label_object_grasps(
        box, ObjectGraspsParams(selection="natural", target_grasps=10, batch_size=16, max_candidates=96,
                                collision_share_of_negatives=0.0), np.random.default_rng(4))
    np.testing.assert_array_equal(column_array(natural, "pose_object", (16,)),
                                  column_array(reference, "pose_object", (16,))[:10])
    firm = natural.column("firm").to_numpy(zero_copy_only=False)
    assert meta["reached"] and meta["stopped"] == "targets" and set(natural.column("candidate").to_pylist()) == {
        "antipodal"}
    assert (meta["positives"], meta["negatives"]) == (int(firm.sum()), int((~firm).sum()))
    assert meta["positive_rate"] == pytest.approx(firm.mean())
    assert meta["collisions_dropped"] == sum(meta["outcomes"][n] for n in (
        "collision_with_ground", "collision_with_target", "collision_with_clutter"))
    assert meta["tried"] == 10 + meta["collisions_dropped"]
    assert shortfall("box", meta) is None


def test_a_natural_set_short_of_its_target_warns_with_the_count(box):
    table, meta = label_object_grasps(
        box, ObjectGraspsParams(selection="natural", target_grasps=500, batch_size=16, max_candidates=16),
        np.random.default_rng(2))
    free = int((table.column("outcome").to_numpy() > Outcome.COLLISION_WITH_CLUTTER).sum())
    assert not meta["reached"] and free < len(table) < 500  # some collisions kept: not counted as collision-free
    assert shortfall("box", meta) == (f"object 'box': {free} of 500 collision-free grasps after 16 candidates "
                                      "(object_grasps.max_candidates)")


def test_a_natural_set_keeps_collisions_within_their_share_of_the_negatives(box):
    """Reference: every rollout of the same trials (balanced, nothing capped, targets out of reach), the rule
    applied by hand: a collision is kept while the kept collisions stay within 0.25 of the kept negatives."""
    every = label_object_grasps(
        box, params(max_candidates=64, near_miss_fraction=0.0, collision_share_of_negatives=1.0),
        np.random.default_rng(6))[0]
    codes, firm = every.column("outcome").to_numpy(), every.column("firm").to_numpy(zero_copy_only=False)
    expected, collisions, negatives, free = [], 0, 0, 0
    for i, code in enumerate(codes):
        if free == 20:
            break
        if code <= Outcome.COLLISION_WITH_CLUTTER:
            if collisions + 1 > 0.25 * (negatives + 1):
                continue
            collisions, negatives = collisions + 1, negatives + 1
        else:
            free += 1
            negatives += not firm[i]
        expected.append(i)
    assert collisions >= 1, "need a kept collision"
    got, meta = label_object_grasps(
        box, ObjectGraspsParams(selection="natural", target_grasps=20, batch_size=16, max_candidates=64,
                                collision_share_of_negatives=0.25), np.random.default_rng(6))
    np.testing.assert_array_equal(column_array(got, "pose_object", (16,)),
                                  column_array(every, "pose_object", (16,))[expected])
    assert meta["collision_negatives"] == collisions and meta["negatives"] == negatives
    assert meta["tried"] == len(expected) + meta["collisions_dropped"]


def test_balanced_targets_with_a_natural_set_are_an_error_naming_the_way_out(tmp_path):
    with pytest.raises(SettingsError, match="target_positives: must be unset with selection: natural.*target_grasps"):
        ObjectGraspsParams(target_positives=400)
    assert ObjectGraspsParams(selection="balanced").target_negatives == 1000
    cfg = tmp_path / "old.yaml"
    cfg.write_text("object_grasps:\n  target_positives: 400\n  target_negatives: 400\n")
    with pytest.raises(Exception, match="object_grasps.target_positives: must be unset with selection: natural"):
        load_config(PROJECT.schema, str(cfg))
