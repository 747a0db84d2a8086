"""Tests of the object-centric exports: ACRONYM files (graspgen/io/acronym_export.py: export_object_acronym) and
GraspGen's dataset layout (graspgen/io/nvidia_graspgen.py), on a dataset folder whose grasp sets were labelled by real
free-space rollouts (ACRONYM's protocol) of antipodal candidates."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import h5py
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import trimesh

from graspgen.errors import InputError, SettingsError
from graspgen.geometry.antipodal import AntipodalParams, sample_antipodal
from graspgen.geometry.stable_poses import StablePoseParams
from graspgen.grippers import load_gripper
from graspgen.io.acronym import FIRM_KEY, FLEX_MOTION, read_acronym
from graspgen.io.acronym_export import export_object_acronym
from graspgen.io.arrow import column_array, fixed_list
from graspgen.io.files import write_h5, write_parquet
from graspgen.io.nvidia_graspgen import (
    GRASPGEN_GRIPPER_NAMES,
    GraspGenObject,
    export_graspgen,
    graspgen_gripper_name,
    read_graspgen,
    split_of,
    write_graspgen,
)
from graspgen.io.objects import object_tree, read_object
from graspgen.workflows.evaluate import evaluate_grasps
from graspgen.workflows.evaluate_settings import CHEAP_COACD
from graspgen.workflows.object_grasps import SCHEMA
from graspgen.workflows.prepare import prepare_object
from tests.paths import REPO

ASSETS = REPO / "assets" / "objects"
PANDA_TCP_OFFSET = 0.1034  # ACRONYM's Panda hand: TCP 0.1034 m along the hand frame's z (ARCHITECTURE.md)
OBJECTS = {"box": 650.0, "can": 1000.0}

# GraspGen's conventions, from NVlabs/GraspGen at commit a56d518 (its code cannot be installed or committed here):
GRASPGEN_PANDA_WIDTH = 0.10537486  # config/grippers/franka_panda.yaml:22 `width`
GRASPGEN_PANDA_DEPTH = 0.10527314  # config/grippers/franka_panda.yaml:23 `depth`: base link -> its tool point, +z
GRASPGEN_PANDA_OFFSET = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]  # franka_panda.yaml:24, post-multiplied onto the
# poses by grasp_gen/dataset/dataset_utils.py:609-631
GRASPGEN_PANDA_FINGER = (0.04, 0.0584)  # config/grippers/franka_panda.py:20-21: its (open) finger meshes are moved to
# x = +-0.04, z = 0.0584 from the base link: franka_description's panda_hand frame, ACRONYM's hand frame
GRASPGEN_CONTACTS_KEY = "contact_locations"  # dataset_utils.py:927-929: grasps.contact_locations, masked by
# object_in_gripper; (n, 2, 3) pairs (dataset.py:251-261: contact_dir = c1 - c0, offset = |c1 - c0|); a positive whose
# pair holds a NaN is dropped (dataset_utils.py:931-944); without the key each positive's origin is taken (956-960)
GRASPGEN_MAPPING_FILE = "map_uuid_to_path.json"  # dataset_utils.py:77: read from grasp_root_dir itself
GRASPGEN_GRASP_ROOT = "grasp_data/{gripper}"  # runs/train_graspgen_franka_panda_gen.sh:25, relative to GRASP_DIR
GRASPGEN_SPLITS_ROOT = "splits/{gripper}"  # runs/train_graspgen_franka_panda_gen.sh:26; dataset.py:427 reads
# f"{root_dir}/{split}.txt"
MOTIONS = list(FLEX_MOTION)


def object_set(path: Path, name: str, density: float, cache: Path, seed: int) -> tuple[pa.Table, object]:
    """Up to 12 antipodal candidates on one bundled object, rolled out with ACRONYM's free-space protocol, as rows of
    the object grasp table (graspgen.workflows.object_grasps.SCHEMA; epsilon and robustness not measured: null)."""
    prep = prepare_object(path, density=density, coacd=CHEAP_COACD, rng=np.random.default_rng(0),
                          poses=StablePoseParams(settle_check=False, max_poses=1), coacd_cache_dir=cache)
    mesh = trimesh.Trimesh(prep.vertices, prep.faces, process=False)
    params = AntipodalParams(num_surface_points=12, approach="any", num_orientations=2, num_depths=1)
    cand = sample_antipodal(mesh, load_gripper("panda"), params, np.random.default_rng(seed))
    k = min(12, len(cand.width))
    T = cand.pose_object[:k]
    ev = evaluate_grasps(path, prep.scale, T, None, "panda", protocol="acronym", cache_dir=cache.parent)
    outcome = ev.column("outcome").to_numpy()
    rows = {
        "object_name": pa.array([name] * k),
        "grasp_id": pa.array(np.arange(k) * 3 + 1, type=pa.int32()),  # not 0..k-1: ids are carried, not recounted
        "candidate": pa.array(["antipodal"] * k),
        "gripper": pa.array(["panda"] * k),
        "protocol": pa.array(["acronym"] * k),
        "pose_object": fixed_list(T.reshape(k, 16), 16),
        "width": pa.array(cand.width[:k]),
        "open_width": ev.column("width"),
        "outcome": ev.column("outcome"),
        "outcome_name": ev.column("outcome_name"),
        "decided_in": ev.column("decided_in"),
        "success": pa.array(outcome == 5),
        **{c: ev.column(c) for c in ("firm", "max_rel_translation", "max_rel_rotation")},
        "closed_width": ev.column("closed_width"),
        **{m: ev.column(m) for m in MOTIONS},
        **{c: ev.column(c) for c in ("contact_points", "contact_normals", "contact_forces", "contact_fingers")},
        "epsilon": pa.nulls(k, pa.float64()),  # not computed here: null, as the stage leaves what it did not measure
        "robustness_n": pa.array(np.zeros(k, dtype=np.int32)),
        "robustness": pa.nulls(k, pa.float64()),
    }
    return pa.table(rows).cast(SCHEMA), prep


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A dataset folder: objects/<name>.h5 and object_grasps.parquet (sorted by object, then grasp id)."""
    root = tmp_path_factory.mktemp("objset") / "dataset"
    (root / "objects").mkdir(parents=True)
    cache = root.parent / "cache" / "coacd"
    parts = []
    for seed, (name, density) in enumerate(OBJECTS.items()):
        table, prep = object_set(ASSETS / f"{name}.obj", name, density, cache, seed + 1)
        write_h5(root / "objects" / f"{name}.h5", object_tree(name, ASSETS / f"{name}.obj", prep, {}))
        parts.append(table)
    table = pa.concat_tables(parts)
    write_parquet(root / "object_grasps.parquet", table)
    success = table.column("success").to_numpy(zero_copy_only=False)
    assert success.any() and not success.all(), "the fixture needs both labels"
    return root


def rows_of(root: Path, name: str) -> pa.Table:
    table = pq.read_table(root / "object_grasps.parquet")
    return table.filter(pa.compute.equal(table.column("object_name"), name))


def file_bytes(root: Path, rels: list[str]) -> dict[str, bytes]:
    return {rel: (root / rel).read_bytes() for rel in rels}


# ---------------------------------------------------------------------------------------------------------------
# ACRONYM
# ---------------------------------------------------------------------------------------------------------------


def test_object_acronym_files_round_trip_poses_labels_and_motions(dataset):
    written = export_object_acronym(dataset)
    assert written == ["acronym/meshes/box.obj", "acronym/box.h5", "acronym/meshes/can.obj", "acronym/can.h5"]
    for name in OBJECTS:
        rows = rows_of(dataset, name)
        T_tcp = column_array(rows, "pose_object", (4, 4))
        grasps = read_acronym(dataset / "acronym" / f"{name}.h5")
        assert len(grasps) == len(rows) and grasps.gripper_type == "panda"
        np.testing.assert_allclose(grasps.tcp_poses(), T_tcp, atol=1e-12)
        # the file holds the Panda hand frame: same axes, origin 0.1034 m back along the approach axis
        np.testing.assert_array_equal(grasps.transforms[:, :3, :3], T_tcp[:, :3, :3])
        np.testing.assert_allclose(grasps.transforms[:, :3, 3], T_tcp[:, :3, 3] - PANDA_TCP_OFFSET * T_tcp[:, :3, 2],
                                   atol=1e-12)
        np.testing.assert_array_equal(grasps.success, rows.column("outcome").to_numpy() == 5)
        for column, key in FLEX_MOTION.items():
            assert key.startswith("flex/object_motion_during_")
            np.testing.assert_array_equal(grasps.qualities[key], rows.column(column).to_numpy())
        np.testing.assert_array_equal(grasps.qualities["graspgen/grasp_id"], rows.column("grasp_id").to_numpy())
        np.testing.assert_array_equal(grasps.qualities["graspgen/outcome"], rows.column("outcome").to_numpy())
        np.testing.assert_array_equal(grasps.qualities["graspgen/closed_width"], rows.column("closed_width").to_numpy())
        assert np.isnan(grasps.qualities["graspgen/epsilon"]).all()  # null (not measured) stays NaN, not 0
        assert np.isnan(grasps.qualities["graspgen/robustness"]).all()
        # object_in_gripper is the still-held label; the firm-hold label and its measures are extra qualities
        firm = rows.column("firm").to_numpy(zero_copy_only=False)
        assert grasps.qualities[FIRM_KEY].dtype == np.int8
        np.testing.assert_array_equal(grasps.qualities[FIRM_KEY], firm.astype(np.int8))
        assert not np.any(firm & ~grasps.success.astype(bool))  # firm implies held
        for column in ("max_rel_translation", "max_rel_rotation"):
            np.testing.assert_array_equal(grasps.qualities[f"graspgen/{column}"], rows.column(column).to_numpy())
        assert grasps.attrs == {"protocol": "acronym"}
        record = read_object(dataset / "objects" / f"{name}.h5")
        assert grasps.object_file == f"meshes/{name}.obj" and grasps.object_scale == 1.0
        assert grasps.object_mass == pytest.approx(record.mass, rel=1e-15)
        np.testing.assert_array_equal(grasps.object_com, record.center_of_mass)
        mesh = trimesh.load(dataset / "acronym" / grasps.object_file, process=False)
        np.testing.assert_array_equal(mesh.vertices, record.vertices)
        np.testing.assert_array_equal(mesh.faces, record.faces)


def test_object_acronym_labels_reproduce_when_the_export_is_rolled_out_again(dataset):
    """The exported file is a grasp set in its own right: ACRONYM's protocol on its poses and mesh gives its labels."""
    export_object_acronym(dataset)
    grasps = read_acronym(dataset / "acronym" / "box.h5")
    again = evaluate_grasps(dataset / "acronym" / grasps.object_file, grasps.object_scale, grasps.tcp_poses(), None,
                            grasps.gripper, protocol="acronym", cache_dir=dataset.parent / "cache")
    np.testing.assert_array_equal(again.column("outcome").to_numpy() == 5, grasps.success.astype(bool))


def test_object_acronym_export_is_byte_deterministic(dataset):
    first = file_bytes(dataset, export_object_acronym(dataset))
    second = file_bytes(dataset, export_object_acronym(dataset))
    assert first == second


def test_object_acronym_errors_name_the_file(dataset, tmp_path):
    with pytest.raises(InputError, match=r"object_grasps.parquet: object grasp table not found"):
        export_object_acronym(tmp_path)
    table = pq.read_table(dataset / "object_grasps.parquet")
    write_parquet(tmp_path / "object_grasps.parquet", table.drop_columns(["success"]))
    with pytest.raises(InputError, match=r"object_grasps.parquet: not an object grasp table: no column\(s\) success"):
        export_object_acronym(tmp_path)
    grippers = ["robotiq_2f85" if i == 0 else g for i, g in enumerate(table.column("gripper").to_pylist())]
    mixed = table.set_column(table.schema.get_field_index("gripper"), "gripper", pa.array(grippers))
    write_parquet(tmp_path / "object_grasps.parquet", mixed)
    with pytest.raises(InputError, match=r"object 'box' has grasps of several grippers"):
        export_object_acronym(tmp_path)
    write_parquet(tmp_path / "object_grasps.parquet", table)
    with pytest.raises(InputError, match=r"objects/box.h5: object record not found"):
        export_object_acronym(tmp_path)


# ---------------------------------------------------------------------------------------------------------------
# GraspGen
# ---------------------------------------------------------------------------------------------------------------


def test_graspgen_export_round_trips_poses_flags_and_meshes(dataset):
    written = export_graspgen(dataset)
    gg = dataset / "graspgen"
    assert written == sorted([
        "graspgen/grasp_data/franka_panda/box.grasps.json", "graspgen/grasp_data/franka_panda/can.grasps.json",
        "graspgen/grasp_data/franka_panda/map_uuid_to_path.json", "graspgen/objects/box.obj",
        "graspgen/objects/can.obj", "graspgen/splits/franka_panda/train.txt", "graspgen/splits/franka_panda/valid.txt",
    ])
    entries = read_graspgen(gg)
    assert [(e.gripper, e.folder, e.name, e.key) for e in entries] == [
        ("panda", "franka_panda", "box", "box.obj"), ("panda", "franka_panda", "can", "can.obj")]
    for entry in entries:
        rows = rows_of(dataset, entry.name)
        T_tcp = column_array(rows, "pose_object", (4, 4))
        np.testing.assert_allclose(entry.tcp_poses(), T_tcp, atol=1e-12)
        np.testing.assert_array_equal(entry.success, rows.column("success").to_numpy(zero_copy_only=False))
        np.testing.assert_array_equal(entry.firm, rows.column("firm").to_numpy(zero_copy_only=False))
        np.testing.assert_array_equal(entry.grasp_ids, rows.column("grasp_id").to_numpy())
        assert entry.scale == 1.0 and entry.protocol == "acronym"
        assert entry.depth == GRASPGEN_PANDA_DEPTH and entry.tcp_offset == PANDA_TCP_OFFSET
        np.testing.assert_array_equal(entry.contacts, expected_contacts(rows))
        record = read_object(dataset / "objects" / f"{entry.name}.h5")
        mesh = trimesh.load(entry.mesh_path, process=False)
        np.testing.assert_array_equal(mesh.vertices, record.vertices)
        np.testing.assert_array_equal(mesh.faces, record.faces)
        assert entry.split == split_of(entry.name, 0.2)


def test_graspgen_files_read_the_way_graspgen_reads_them(dataset):
    """GraspGen's loader: the JSON found by object key, mesh at object_root/key scaled by object.scale, transforms
    masked by object_in_gripper, the TCP ``depth`` along the base link's +z."""
    export_graspgen(dataset)
    gg = dataset / "graspgen"
    mapping = json.loads((gg / "grasp_data/franka_panda/map_uuid_to_path.json").read_text())
    assert mapping == {"box.obj": "box.grasps.json", "can.obj": "can.grasps.json"}
    splits = {s: (gg / f"splits/franka_panda/{s}.txt").read_text().split() for s in ("train", "valid")}
    assert sorted(splits["train"] + splits["valid"]) == ["box.obj", "can.obj"]
    for key, json_name in mapping.items():
        data = json.loads((gg / "grasp_data/franka_panda" / json_name).read_text())
        assert data["object"]["file"] == key and os.path.isfile(os.path.join(gg / "objects", key))
        poses = np.array(data["grasps"]["transforms"])
        mask = np.array(data["grasps"]["object_in_gripper"])
        positive = poses[mask]  # GraspGen's own indexing: a boolean mask, not row numbers
        rows = rows_of(dataset, key[: -len(".obj")])
        T_tcp = column_array(rows, "pose_object", (4, 4))
        success = rows.column("success").to_numpy(zero_copy_only=False)
        assert positive.shape == (int(success.sum()), 4, 4)
        tcp_offset = data["gripper"]["tcp_offset"]
        tcp = positive[:, :3, 3] + tcp_offset * positive[:, :3, 2]
        np.testing.assert_allclose(tcp, T_tcp[success][:, :3, 3], atol=1e-12)
        np.testing.assert_array_equal(positive[:, :3, :3], T_tcp[success][:, :3, :3])  # z approach, x closing
        assert data["gripper"]["transform_offset_from_asset_to_graspgen_convention"] == [[0, 0, 0], [0, 0, 0, 1]]


def expected_contacts(rows: pa.Table) -> np.ndarray:
    """Per grasp: the mean of the left (finger 0) and right (finger 1) pad's contact points, NaN where none."""
    out = np.full((rows.num_rows, 2, 3), np.nan)
    for i, (pts, fingers) in enumerate(zip(rows.column("contact_points").to_pylist(),
                                           rows.column("contact_fingers").to_pylist())):
        pts = np.asarray(pts or [], dtype=float).reshape(-1, 3)
        for f in (0, 1):
            if (np.asarray(fingers or []) == f).any():
                out[i, f] = pts[np.asarray(fingers) == f].mean(axis=0)
    return out


def test_graspgen_conventions_are_graspgen_s_own(dataset):
    """Each convention against GraspGen's value (constants above, with the upstream file and line)."""
    export_graspgen(dataset)
    gg = dataset / "graspgen"
    grasp_root = gg / GRASPGEN_GRASP_ROOT.format(gripper="franka_panda")
    splits_root = gg / GRASPGEN_SPLITS_ROOT.format(gripper="franka_panda")
    mapping = json.loads((grasp_root / GRASPGEN_MAPPING_FILE).read_text())
    keys = sorted((splits_root / "train.txt").read_text().split() + (splits_root / "valid.txt").read_text().split())
    assert sorted(mapping) == keys
    for key, json_name in mapping.items():
        assert (gg / "objects" / key).is_file()  # object_root_dir = <dataset>/graspgen/objects (dataset_utils.py:880)
        data = json.loads((grasp_root / json_name).read_text())
        grip = data["gripper"]
        assert (grip["width"], grip["depth"]) == (GRASPGEN_PANDA_WIDTH, GRASPGEN_PANDA_DEPTH)
        assert grip["transform_offset_from_asset_to_graspgen_convention"] == GRASPGEN_PANDA_OFFSET
        assert grip["tcp_offset"] == PANDA_TCP_OFFSET
        poses = np.array(data["grasps"]["transforms"])
        mask = np.array(data["grasps"]["object_in_gripper"])
        contacts = np.array(data["grasps"][GRASPGEN_CONTACTS_KEY])
        rows = rows_of(dataset, key[: -len(".obj")])
        T_tcp = column_array(rows, "pose_object", (4, 4))
        assert contacts.shape == (len(poses), 2, 3)
        # GraspGen's loader, dataset_utils.py:927-943, as written there
        pos_contacts = contacts[mask]
        keep = np.logical_not(np.any(np.any(np.isnan(pos_contacts), axis=1), axis=1))
        assert keep.all(), "every positive has a contact on each pad, so GraspGen drops none"
        positive = poses[mask][keep]
        # the pair is ours: the pads' contacts, in the poses' mesh frame; c1 - c0 along the grasp's +x (closing)
        np.testing.assert_array_equal(pos_contacts, expected_contacts(rows)[mask])
        closing = pos_contacts[:, 1] - pos_contacts[:, 0]
        assert (np.einsum("ij,ij->i", closing, positive[:, :3, 0]) > 0).all()
        # the poses are the hand base link GraspGen's franka_panda mesh is built in, so they are not moved: GraspGen's
        # tool point (base link @ Trans(0, 0, depth): robot.py:388-392, metrics.py:84-97, dataset_utils.py:264-266)
        # lies depth - tcp_offset = 1.87 mm beyond our TCP along the approach, as on GraspGen's own Panda data
        tool = positive[:, :3, 3] + GRASPGEN_PANDA_DEPTH * positive[:, :3, 2]
        tcp = T_tcp[mask][keep]
        np.testing.assert_allclose(tool - tcp[:, :3, 3], (GRASPGEN_PANDA_DEPTH - PANDA_TCP_OFFSET) * tcp[:, :3, 2],
                                   atol=1e-12)
    # our Panda's (open) right finger sits where GraspGen's does in the same hand frame: its base at z = 0.0584, its
    # inner face at x = 0.04 (assets/grippers/panda/finger.obj, in the frame our poses are written in)
    lo = trimesh.load(REPO / "assets/grippers/panda/finger.obj", process=False).bounds[0]
    assert lo[0] == pytest.approx(GRASPGEN_PANDA_FINGER[0], abs=5e-4)
    assert lo[2] == pytest.approx(GRASPGEN_PANDA_FINGER[1], abs=5e-4)


def test_graspgen_contacts_are_written_only_when_given_nan_where_a_pad_had_none(tmp_path):
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    T = np.tile(np.eye(4), (2, 1, 1))
    pairs = np.array([[[-0.025, 0.0, 0.0], [0.025, 0.0, 0.0]], [[np.nan] * 3, [0.025, 0.01, 0.0]]])
    write_graspgen(tmp_path / "a", [GraspGenObject("o", box.vertices, box.faces, T, [True, False], "panda",
                                                   contacts=pairs)])
    text = (tmp_path / "a/grasp_data/franka_panda/o.grasps.json").read_text()
    assert '"contact_locations":[[[-0.025,0.0,0.0],[0.025,0.0,0.0]],[[NaN,NaN,NaN],[0.025,0.01,0.0]]]' in text
    (entry,) = read_graspgen(tmp_path / "a")
    np.testing.assert_array_equal(entry.contacts, pairs)
    write_graspgen(tmp_path / "b", [GraspGenObject("o", box.vertices, box.faces, T, [True, False], "panda")])
    assert "contact_locations" not in (tmp_path / "b/grasp_data/franka_panda/o.grasps.json").read_text()
    assert read_graspgen(tmp_path / "b")[0].contacts is None
    with pytest.raises(SettingsError, match=r"o: contacts: expected 2 \(2, 3\) pairs \(one per pose\), got 1"):
        write_graspgen(tmp_path / "c", [GraspGenObject("o", box.vertices, box.faces, T, [True, False], "panda",
                                                       contacts=pairs[:1])])
    bad = tmp_path / "a/grasp_data/franka_panda/o.grasps.json"
    bad.write_text(text.replace('[[NaN,NaN,NaN],[0.025,0.01,0.0]]', '[[0.0,0.0],[0.025,0.01,0.0]]'))
    with pytest.raises(InputError, match=r"o.grasps.json: grasps.contact_locations must be 2 \(2, 3\) contact pairs"):
        read_graspgen(tmp_path / "a")


def test_split_is_a_hash_of_the_name():
    for name in ("box", "can", "mug_0001", "é"):
        u = int(hashlib.sha256(name.encode()).hexdigest()[:16], 16) / 2**64
        assert split_of(name, 0.2) == ("valid" if u < 0.2 else "train")
        assert split_of(name, 0.0) == "train" and split_of(name, 1.0) == "valid"
    names = [f"object_{i:04d}" for i in range(2000)]
    share = np.mean([split_of(n, 0.2) == "valid" for n in names])
    assert 0.17 < share < 0.23
    with pytest.raises(SettingsError, match="valid_fraction"):
        split_of("box", 1.5)


def test_splits_do_not_move_when_objects_are_added_and_assignments_override(tmp_path):
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    T = np.tile(np.eye(4), (2, 1, 1))

    def objs(names):
        return [GraspGenObject(n, box.vertices, box.faces, T, [True, False], "panda") for n in names]

    def split_files(root):
        return {s: (root / f"splits/franka_panda/{s}.txt").read_text().split() for s in ("train", "valid")}

    few = [f"o{i}" for i in range(6)]
    write_graspgen(tmp_path / "a", objs(few), valid_fraction=0.5)
    write_graspgen(tmp_path / "b", objs(few + [f"p{i}" for i in range(20)]), valid_fraction=0.5)
    a, b = split_files(tmp_path / "a"), split_files(tmp_path / "b")
    for s in ("train", "valid"):
        assert set(a[s]) == {k for k in b[s] if k.startswith("o")}
    write_graspgen(tmp_path / "c", objs(few), valid_fraction=0.0, splits={"o3": "valid"})
    assert split_files(tmp_path / "c") == {"train": ["o0.obj", "o1.obj", "o2.obj", "o4.obj", "o5.obj"],
                                           "valid": ["o3.obj"]}
    with pytest.raises(ValueError, match=r"splits\['o1'\]: must be one of train, valid, got 'test'"):
        write_graspgen(tmp_path / "d", objs(few), splits={"o1": "test"})
    with pytest.raises(InputError, match=r"'o1' is given twice for gripper 'franka_panda' \(GraspGen's name; this "
                                         r"entry's gripper: 'panda'\)"):
        write_graspgen(tmp_path / "d", objs(["o1", "o1"]))


def test_gripper_folders_have_graspgen_s_names_and_old_folders_still_read(dataset, tmp_path):
    """GraspGen registers grippers by config/grippers/<name>.yaml (franka_panda, robotiq_2f_85, robotiq_2f_140, ...
    at NVlabs/GraspGen a56d518) and its scripts read grasp_data/$GRIPPER_NAME and splits/$GRIPPER_NAME: our export
    uses those names; a gripper GraspGen lacks keeps ours; exports with our old folder names still read."""
    assert GRASPGEN_GRIPPER_NAMES == {"panda": "franka_panda", "robotiq_2f85": "robotiq_2f_85",
                                      "robotiq_2f85_mesh": "robotiq_2f_85"}
    assert graspgen_gripper_name("box_jaw") == "box_jaw"
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    T = np.tile(np.eye(4), (2, 1, 1))
    written = write_graspgen(tmp_path / "new", [GraspGenObject("o", box.vertices, box.faces, T, [True, False], g)
                                                for g in ("robotiq_2f85_mesh", "box_jaw")])
    assert {Path(w).parts[1] for w in written if not w.startswith("objects/")} == {"robotiq_2f_85", "box_jaw"}
    data = json.loads((tmp_path / "new/grasp_data/robotiq_2f_85/o.grasps.json").read_text())
    assert data["gripper"]["name"] == "robotiq_2f_85" and data["gripper"]["source_gripper"] == "robotiq_2f85_mesh"
    entries = read_graspgen(tmp_path / "new")
    assert [(e.folder, e.gripper) for e in entries] == [("box_jaw", "box_jaw"), ("robotiq_2f_85", "robotiq_2f85_mesh")]
    with pytest.raises(InputError, match=r"'o' is given twice for gripper 'robotiq_2f_85'"):
        write_graspgen(tmp_path / "clash", [GraspGenObject("o", box.vertices, box.faces, T, [True, False], g)
                                            for g in ("robotiq_2f85", "robotiq_2f85_mesh")])
    export_graspgen(dataset)
    gg = dataset / "graspgen"
    for sub in ("grasp_data", "splits"):  # what GraspGen's train_graspgen_franka_panda_*.sh point at
        assert sorted(os.listdir(gg / sub / "franka_panda"))[:1] and not (gg / sub / "panda").exists()
    old = tmp_path / "old"
    for sub in ("grasp_data", "splits", "objects"):
        src = gg / sub / ("franka_panda" if sub != "objects" else "")
        dst = old / sub / ("panda" if sub != "objects" else "")
        dst.mkdir(parents=True)
        for f in sorted(src.iterdir()):
            if f.is_file():
                text = f.read_text()
                if f.name.endswith(".grasps.json"):  # as written before: our name, no source_gripper
                    d = json.loads(text)
                    d["gripper"]["name"] = "panda"
                    del d["gripper"]["source_gripper"]
                    text = json.dumps(d)
                (dst / f.name).write_text(text)
    then, now = read_graspgen(old), read_graspgen(gg)
    assert [(e.folder, e.gripper, e.name, e.split) for e in then] == [("panda", "panda", e.name, e.split) for e in now]
    for a, b in zip(then, now):
        np.testing.assert_array_equal(a.tcp_poses(), b.tcp_poses())
    renamed = tmp_path / "renamed"  # GraspGen's folder name without source_gripper: mapped back to ours
    for sub in ("grasp_data", "splits"):
        (renamed / sub).mkdir(parents=True)
        (old / sub / "panda").rename(renamed / sub / "franka_panda")
    assert {(e.folder, e.gripper) for e in read_graspgen(renamed)} == {("franka_panda", "panda")}


def test_graspgen_export_is_byte_deterministic(dataset):
    first = file_bytes(dataset, export_graspgen(dataset))
    second = file_bytes(dataset, export_graspgen(dataset))
    assert first == second


def test_graspgen_reader_errors_name_the_file(tmp_path):
    with pytest.raises(InputError, match="grasp_data: no grasp_data folder"):
        read_graspgen(tmp_path)
    folder = tmp_path / "grasp_data" / "panda"
    folder.mkdir(parents=True)
    bad = folder / "x.grasps.json"
    bad.write_text(json.dumps({"object": {"file": "x.obj", "scale": 1.0},
                               "grasps": {"transforms": [np.eye(4).tolist()] * 2, "object_in_gripper": [1, 0]}}))
    with pytest.raises(InputError, match=r"x.grasps.json: grasps.object_in_gripper must be 2 booleans"):
        read_graspgen(tmp_path)
    bad.write_text("{not json")
    with pytest.raises(InputError, match=r"x.grasps.json: not a GraspGen grasp file"):
        read_graspgen(tmp_path)
    bad.write_text(json.dumps({"object": {"file": "x.obj"}, "grasps": {"transforms": [[1, 2]],
                                                                       "object_in_gripper": [True]}}))
    with pytest.raises(InputError, match=r"x.grasps.json: grasps.transforms must be \(n, 4, 4\)"):
        read_graspgen(tmp_path)


def test_object_records_hold_the_mesh_frame_of_the_poses(dataset):
    """The fixture's premise: pose_object lives in the frame of objects/<name>.h5's mesh (the grasp centre lies
    between the two contacts, which lie on that mesh's surface)."""
    for name in OBJECTS:
        rows = rows_of(dataset, name)
        with h5py.File(dataset / "objects" / f"{name}.h5") as f:
            mesh = trimesh.Trimesh(f["mesh/vertices"][()], f["mesh/faces"][()], process=False)
        T = column_array(rows, "pose_object", (4, 4))
        width = rows.column("width").to_numpy()
        for side in (-0.5, 0.5):
            contact = T[:, :3, 3] + side * width[:, None] * T[:, :3, 0]
            _, distance, _ = trimesh.proximity.closest_point(mesh, contact)
            assert distance.max() < 1e-6
