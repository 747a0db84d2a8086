"""studies/unseen.py: the choice leaves out seen and misaligned meshes, and the oracle is the per-object rate."""

from __future__ import annotations

import csv

import h5py
import numpy as np
import pytest
import trimesh

from graspgen.io.acronym import read_acronym
from studies.unseen import TCP_DEPTH, alignment, object_rate_auc, prepare


def _poses_at(points: np.ndarray) -> np.ndarray:
    """``(n, 4, 4)`` poses, identity rotation, whose closing point is at ``points``."""
    T = np.tile(np.eye(4), (len(points), 1, 1))
    T[:, :3, 3] = points - np.array([0.0, 0.0, TCP_DEPTH])
    return T


def _write_source_file(path, mesh_file, T, success, scale=1.0):
    path.parent.mkdir(parents=True, exist_ok=True)
    with h5py.File(path, "w") as h:
        h["grasps/transforms"] = np.tile(np.eye(4), (len(T), 1, 1))  # the original frame: not used
        h["grasps/transforms_adjust"] = T
        h["grasps/qualities/flex/object_in_gripper"] = success.astype(np.float64)
        h["grasps/good_wrap"] = T[:1]
        h["object/file"] = mesh_file
        h["object/scale"] = scale
        h["object/density"] = 150.0
        h["object/friction"] = 1.0
        h["gripper/type"] = "panda"
        h["gripper/configuration"] = np.array([0.08])


def test_alignment_counts_successes_near_the_surface():
    box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    on_face = np.array([[0.05, 0.0, 0.0], [0.0, -0.05, 0.01], [0.0, 0.0, 0.05]])
    far = np.array([[0.2, 0.0, 0.0]])
    T = _poses_at(np.concatenate([on_face, far]))
    assert alignment(T, np.array([True, True, True, False]), box) == 1.0
    assert alignment(T, np.array([True, True, False, True]), box) == pytest.approx(2 / 3)
    assert alignment(T, np.zeros(4, bool), box) == 0.0


def test_object_rate_auc_is_the_auc_of_each_files_rate(tmp_path):
    # file A: 3 of 4 succeed, file B: 1 of 4; scored 0.75 / 0.25, pooled AUC by counting pairs
    for name, labels in (("A", [1, 1, 1, 0]), ("B", [1, 0, 0, 0])):
        with h5py.File(tmp_path / f"{name}.h5", "w") as h:
            h["grasps/qualities/flex/object_in_gripper"] = np.array(labels, float)
    # positives: 3 at 0.75, 1 at 0.25; negatives: 1 at 0.75, 3 at 0.25. Of the 16 pairs, 9 are ordered and
    # 3 + 3 tie (half each)
    assert object_rate_auc(sorted(tmp_path.glob("*.h5"))) == pytest.approx((9 + 0.5 * 3 + 0.5 * 3) / 16)


def test_prepare_leaves_out_seen_and_misaligned_meshes(tmp_path):
    source, shared, out = tmp_path / "src", tmp_path / "shared", tmp_path / "out"
    box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    for mesh_id in ("aaa", "bbb", "ccc"):
        (source / "meshes" / "Mug").mkdir(parents=True, exist_ok=True)
        box.export(source / "meshes" / "Mug" / f"{mesh_id}.obj")
    success = np.array([True, True, False])
    aligned = _poses_at(np.array([[0.05, 0.0, 0.0], [-0.05, 0.0, 0.0], [0.3, 0.0, 0.0]]))
    misaligned = _poses_at(np.array([[0.3, 0.0, 0.0], [-0.05, 0.0, 0.0], [0.0, 0.0, 0.0]]))
    _write_source_file(source / "grasps" / "Mug_aaa_1.0.h5", "meshes/Mug/aaa.obj", aligned, success)
    _write_source_file(source / "grasps" / "Mug_bbb_1.0.h5", "meshes/Mug/bbb.obj", misaligned, success)
    _write_source_file(source / "grasps" / "Mug_ccc_1.0.h5", "meshes/Mug/ccc.obj", aligned, success)
    (shared / "learn").mkdir(parents=True)
    (shared / "learn" / "Mug_ccc_0.5.h5").write_bytes(b"")  # ccc is seen (at another scale)

    rows = prepare(source, out, shared, quota={"Mug": 3})

    assert [r["name"] for r in rows] == ["Mug_aaa_1.0"]
    with open(out / "objects.csv") as fh:
        listed = list(csv.DictReader(fh))
    assert [r["name"] for r in listed] == ["Mug_aaa_1.0"] and listed[0]["density"] == "150.0"
    grasps = read_acronym(out / "Mug_aaa_1.0.h5")
    np.testing.assert_array_equal(grasps.transforms, aligned)
    np.testing.assert_array_equal(grasps.success, success)
    assert (out / "meshes" / "Mug" / "aaa.obj").exists()
