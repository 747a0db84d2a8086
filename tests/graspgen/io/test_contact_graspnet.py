"""The Contact-GraspNet export (graspgen/io/contact_graspnet.py) on an analytic case: a box placed in a scene, grasps
whose Panda-frame poses and finger-ray contacts are known in closed form. No upstream code here; the run of
Contact-GraspNet's own loader is tests/graspgen/io/test_contact_graspnet_upstream.py."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import trimesh

from graspgen.errors import InputError
from graspgen.grippers import load_gripper
from graspgen.io.arrow import fixed_list
from graspgen.io.contact_graspnet import (
    CGN_DEPTH,
    CGN_TABLE_TOP,
    cgn_contacts,
    cgn_grasp_from_tcp,
    export_contact_graspnet,
    scene_file,
    tcp_from_cgn_grasp,
)
from graspgen.io.nvidia_graspgen import split_of

# A 40 x 60 x 100 mm box standing on its base: mesh frame with the base at z = 0, so its vertex mean is (0, 0, 0.05).
BOX = trimesh.creation.box((0.04, 0.06, 0.10), transform=trimesh.transformations.translation_matrix((0, 0, 0.05)))
MEAN = np.array([0.0, 0.0, 0.05])
# Placed at (0.1, 0.2, 0) turned 90 degrees about z: the box's x (40 mm) runs along the world's y.
POSE = trimesh.transformations.rotation_matrix(np.pi / 2, (0, 0, 1))
POSE[:3, 3] = (0.1, 0.2, 0.0)


def top_down(x_axis, height):
    """A TCP pose in the box's mesh frame: z down (approach), x = x_axis (closing), at the box's axis."""
    x = np.asarray(x_axis, dtype=float)
    z = np.array([0.0, 0.0, -1.0])
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = x, np.cross(z, x), z
    T[:3, 3] = (0.0, 0.0, height)
    return T


# Row 0: closes across the 40 mm side 30 mm below the top (a positive); row 1: across the 60 mm side (a negative);
# row 2: a positive whose rays start inside the box (closing across its 100 mm height from the side: out of reach).
T_OBJ = np.stack([top_down((1, 0, 0), 0.07), top_down((0, 1, 0), 0.07), np.eye(4)])
T_OBJ[2, :3, :3] = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]  # z along the box's +x, closing along its height
T_OBJ[2, :3, 3] = (0.0, 0.0, 0.05)
SUCCESS = np.array([True, False, True])


def write_dataset(root, success=SUCCESS, scene="scene_000000"):
    """A dataset folder with one object record, one scene record and placed_grasps.parquet for T_OBJ."""
    (root / "objects").mkdir(parents=True)
    (root / "scenes").mkdir()
    with h5py.File(root / "objects" / "box.h5", "w") as f:
        f["mesh/vertices"], f["mesh/faces"] = BOX.vertices, BOX.faces
    with h5py.File(root / "scenes" / f"{scene}.h5", "w") as f:
        f.attrs["object_names"] = json.dumps(["box"])
        f["objects/poses"] = POSE[None]
    n = len(T_OBJ)
    table = pa.table({
        "scene_id": [scene] * n, "grasp_id": pa.array(range(n), pa.int32()),
        "object_index": pa.array([0] * n, pa.int16()), "gripper": ["panda"] * n,
        "pose_object": fixed_list(T_OBJ.reshape(n, 16), 16),
        "pose_world": fixed_list((POSE @ T_OBJ).reshape(n, 16), 16),
        "width": [0.04, 0.06, 0.10], "object_outcome": pa.array([5, 3, 5], pa.int8()),
        "scene_code": pa.array([-1, -1, -1], pa.int8()), "success": list(map(bool, success)),
    })
    pq.write_table(table, root / "placed_grasps.parquet")
    return root


def test_grasp_frame_is_the_panda_base_shifted_onto_the_table():
    T = POSE @ T_OBJ[0]
    G = cgn_grasp_from_tcp(T)[0]
    assert np.allclose(G[:3, :3], T[:3, :3])  # same axes: z approach, x closing
    # the finger-centre plane (0.1034 along the grasp's z) is our TCP, lifted by Contact-GraspNet's table top
    assert np.allclose(G[:3, 3] + CGN_DEPTH * G[:3, 2], T[:3, 3] + [0, 0, CGN_TABLE_TOP])
    assert np.allclose(tcp_from_cgn_grasp(G[None])[0], T)
    assert CGN_DEPTH == pytest.approx(load_gripper("panda").tcp_offset)  # our Panda's TCP is Contact-GraspNet's


def test_contacts_are_the_finger_rays_first_hits():
    c = cgn_contacts(BOX, T_OBJ @ _down(CGN_DEPTH))
    # row 0: the +x finger's ray hits the box's +x face (x = 0.02) first, the -x finger's the -x face
    assert np.allclose(c[0], [[0.02, 0, 0.07], [-0.02, 0, 0.07]])
    assert np.allclose(c[1], [[0, 0.03, 0.07], [0, -0.03, 0.07]])
    # row 2: the pads' centres are 39.9 mm either side of the box's middle along its 100 mm height: inside the box,
    # so each ray's first hit is the far face, 89.9 mm away: out of reach (80 mm), no contact
    assert np.isnan(c[2]).all()


def _down(d):
    T = np.eye(4)
    T[2, 3] = -d
    return T


def test_export_keys_shapes_and_frames(tmp_path):
    root = write_dataset(tmp_path)
    written = export_contact_graspnet(root)
    name = scene_file("scene_000000", "train" if split_of("scene_000000", 0.2) == "train" else "test")
    assert written == ["contact_graspnet/meshes/box.obj", f"contact_graspnet/scene_contacts/{name}",
                       "contact_graspnet/splits/scenes.json", "contact_graspnet/splits/objects.json"]
    z = np.load(root / written[1], allow_pickle=False)  # as Contact-GraspNet's load_scene_contacts reads it
    assert z["scene_contact_points"].shape == (1, 2, 3) and z["grasp_transforms"].shape == (1, 4, 4)
    assert z["obj_paths"].tolist() == ["meshes/box.obj"] and z["obj_scales"].tolist() == [1.0]
    assert (root / "contact_graspnet" / str(z["obj_paths"][0])).is_file()
    up = np.array([0, 0, CGN_TABLE_TOP])
    # the object: its mesh centred on its vertex mean (as Contact-GraspNet's renderer loads it), on its table
    centred = trimesh.load(root / "contact_graspnet/meshes/box.obj")
    centred.vertices -= centred.vertices.mean(axis=0)
    T_obj = z["obj_transforms"][0]
    assert np.allclose(T_obj[:3, 3], POSE[:3, :3] @ MEAN + POSE[:3, 3] + up)
    world_box = BOX.copy().apply_transform(POSE).apply_translation(up)
    assert np.allclose(np.sort(centred.apply_transform(T_obj).vertices, axis=0), np.sort(world_box.vertices, axis=0))
    # the positive: row 0, Panda base 0.1034 behind the TCP; contacts on the box's faces, 40 mm apart, +x finger first
    G = z["grasp_transforms"][0]
    T_world = POSE @ T_OBJ[0]
    assert np.allclose(G, cgn_grasp_from_tcp(T_world)[0])
    tcp = T_world[:3, 3] + up
    x = T_world[:3, 0]
    assert np.allclose(z["scene_contact_points"][0], [tcp + 0.02 * x, tcp - 0.02 * x])
    assert z["grasp_ids"].tolist() == [0] and z["obj_grasp_idcs"].tolist() == [1]
    assert z["grasp_object_outcome"].tolist() == [5] and z["grasp_widths"].tolist() == [0.04]
    # beside it: the negative and the positive whose rays found no contact
    assert z["other_grasp_ids"].tolist() == [1, 2] and z["other_success"].tolist() == [False, True]
    x1 = (POSE @ T_OBJ[1])[:3, 0]  # row 1 closes across the 60 mm side, at the same TCP
    assert np.allclose(z["other_contact_points"][0], [tcp + 0.03 * x1, tcp - 0.03 * x1])
    assert np.isnan(z["other_contact_points"][1]).all()
    assert str(z["source"]) == "placed_grasps" and str(z["scene_id"]) == "scene_000000"
    split = json.loads((root / "contact_graspnet/splits/scenes.json").read_text())
    assert split["train"] + split["test"] == ["scene_000000"] and split["num_test_scenes"] == len(split["test"])
    assert split["files"] == [name] and split["left_out"] == {}


def test_held_out_scenes_sort_last_and_scenes_without_positives_get_no_file(tmp_path):
    ids = [f"scene_{i:06d}" for i in range(40)]
    split = {sid: "train" if split_of(sid, 0.2) == "train" else "test" for sid in ids}
    names = sorted(scene_file(sid, split[sid]) for sid in ids)  # Contact-GraspNet's order: sorted(glob(...))
    tests = sum(v == "test" for v in split.values())
    assert 0 < tests < 40 and all("_test_" in n for n in names[-tests:]) and all("_train_" in n for n in names[:-tests])
    root = write_dataset(tmp_path, success=[False, False, False])
    written = export_contact_graspnet(root)
    assert not any("scene_contacts/" in w for w in written)  # its loader would misalign the scenes after it
    scenes = json.loads((root / "contact_graspnet/splits/scenes.json").read_text())
    assert scenes["files"] == [] and scenes["left_out"] == {"scene_000000": "no positive grasp with two contacts"}


def test_same_dataset_same_bytes(tmp_path):
    a, b = write_dataset(tmp_path / "a"), write_dataset(tmp_path / "b")
    export_contact_graspnet(a)
    export_contact_graspnet(b)
    for path in sorted((a / "contact_graspnet").rglob("*")):
        if path.is_file():
            assert path.read_bytes() == (b / path.relative_to(a)).read_bytes(), path


def test_errors_name_the_file(tmp_path):
    root = write_dataset(tmp_path)
    (root / "scenes" / "scene_000000.h5").unlink()
    with pytest.raises(InputError, match="placed_grasps.parquet: rows of scene 'scene_000000'"):
        export_contact_graspnet(root)
    (root / "placed_grasps.parquet").unlink()
    with pytest.raises(InputError, match="grasps.parquet: no grasp table"):
        export_contact_graspnet(root)


def test_without_object_sets_the_scene_grasps_are_exported(tmp_path):
    """No placed_grasps.parquet: the scene grasps of grasps.parquet (positives: outcome 5), their labels beside."""
    root = write_dataset(tmp_path)
    placed = pq.read_table(root / "placed_grasps.parquet")
    (root / "placed_grasps.parquet").unlink()
    scene = placed.select(["scene_id", "grasp_id", "object_index", "gripper", "pose_object", "pose_world", "width"])
    scene = scene.append_column("outcome", pa.array([5, 3, 4], pa.int8()))
    scene = scene.append_column("firm", pa.array([True, False, None]))
    scene = scene.append_column("robustness", pa.array([0.8, None, None], pa.float64()))
    pq.write_table(scene, root / "grasps.parquet")
    written = export_contact_graspnet(root)
    z = np.load(root / written[1], allow_pickle=False)
    assert str(z["source"]) == "grasps" and str(z["gripper"]) == "panda"
    assert z["grasp_ids"].tolist() == [0]
    assert np.allclose(z["grasp_transforms"][0], cgn_grasp_from_tcp(POSE @ T_OBJ[0])[0])
    assert z["grasp_outcome"].tolist() == [5] and z["grasp_firm"].tolist() == [True]
    assert z["grasp_robustness"].tolist() == [0.8]
    assert z["other_grasp_ids"].tolist() == [1, 2] and z["other_success"].tolist() == [False, False]
    assert z["other_firm"].tolist() == [False, False] and np.isnan(z["other_robustness"]).all()
    assert "grasp_scene_code" not in z.files
