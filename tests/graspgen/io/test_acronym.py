"""Tests of stages/acronym.py: ACRONYM grasp files, the hand-base <-> TCP conversion, read errors."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from graspgen.errors import InputError, SettingsError
from graspgen.grippers import load_gripper
from graspgen.io.acronym import SUCCESS_KEY, hand_base_from_tcp, read_acronym, tcp_from_hand_base, write_acronym


def test_tcp_lies_along_the_base_z_axis_and_the_axes_are_shared(random_poses):
    T_tcp = random_poses(5)
    base = hand_base_from_tcp(T_tcp, 0.1034)
    np.testing.assert_array_equal(base[:, :3, :3], T_tcp[:, :3, :3])  # z approach, x closing in both frames
    np.testing.assert_allclose(T_tcp[:, :3, 3] - base[:, :3, 3], 0.1034 * T_tcp[:, :3, 2], atol=1e-15)
    np.testing.assert_allclose(tcp_from_hand_base(base, 0.1034), T_tcp, atol=1e-15)
    single = tcp_from_hand_base(np.eye(4), 0.1034)
    assert single.shape == (1, 4, 4) and single[0, 2, 3] == pytest.approx(0.1034)
    with pytest.raises(ValueError, match=r"T_base: must have shape \(4, 4\) or \(n, 4, 4\)"):
        tcp_from_hand_base(np.eye(3), 0.1)


@pytest.mark.parametrize("gripper, file_type", [("panda", "panda"), ("robotiq_2f85", "robotiq_2f85")])
def test_export_then_import_gives_the_same_poses(tmp_path, gripper, file_type, random_poses):
    T_tcp = random_poses(50, seed=1)
    success = np.arange(50) % 3 == 0
    path = tmp_path / "g.h5"
    write_acronym(path, T_tcp, success, object_file="meshes/Mug/abc.obj", object_scale=0.02, gripper=gripper,
                  object_mass=0.3, object_com=[0.0, 0.01, 0.02], object_inertia=np.eye(3) * 1e-4,
                  object_density=150.0, object_friction=1.0, qualities={"flex/object_motion": np.linspace(0, 1, 50)})
    grasps = read_acronym(path)
    assert len(grasps) == 50 and grasps.gripper_type == file_type and grasps.gripper == gripper
    np.testing.assert_allclose(grasps.tcp_poses(), T_tcp, atol=1e-9)
    offset = load_gripper(gripper).tcp_offset  # the file holds hand-base poses, offset back along z
    np.testing.assert_allclose(grasps.transforms[:, :3, 3], T_tcp[:, :3, 3] - offset * T_tcp[:, :3, 2], atol=1e-12)
    np.testing.assert_array_equal(grasps.success, success.astype(np.int8))
    assert grasps.object_file == "meshes/Mug/abc.obj" and grasps.object_scale == 0.02
    assert (grasps.object_mass, grasps.object_density, grasps.object_friction) == (0.3, 150.0, 1.0)
    np.testing.assert_array_equal(grasps.object_com, [0.0, 0.01, 0.02])
    np.testing.assert_array_equal(grasps.object_inertia, np.eye(3) * 1e-4)
    np.testing.assert_allclose(grasps.gripper_configuration, [load_gripper(gripper).max_width / 2])
    assert set(grasps.qualities) == {SUCCESS_KEY, "flex/object_motion"}
    assert not grasps.transforms.flags.writeable


def test_reads_files_written_the_way_acronym_writes_them(tmp_path, random_poses):
    """Byte strings (h5py's fixed-length ASCII), no scale or gripper entries: ACRONYM's defaults apply."""
    path = tmp_path / "Mug_x_0.01.h5"
    T_base = random_poses(3, seed=2)
    with h5py.File(path, "w") as f:
        f["grasps/transforms"] = T_base
        f["grasps/qualities/flex/object_in_gripper"] = np.array([1, 0, 1])
        f["object/file"] = np.bytes_("meshes/Mug/x.obj")
    grasps = read_acronym(path)
    assert grasps.object_file == "meshes/Mug/x.obj" and grasps.object_scale == 1.0
    assert grasps.gripper_type == "panda" and grasps.object_mass is None
    np.testing.assert_allclose(grasps.tcp_poses(), tcp_from_hand_base(T_base, 0.1034), atol=1e-15)


def test_read_errors_name_the_file(tmp_path):
    with pytest.raises(InputError, match="nope.h5: grasp file not found"):
        read_acronym(tmp_path / "nope.h5")
    text = tmp_path / "text.h5"
    text.write_text("hello")
    with pytest.raises(InputError, match="text.h5: not an HDF5 file"):
        read_acronym(text)
    empty = tmp_path / "empty.h5"
    with h5py.File(empty, "w") as f:
        f["object/file"] = "a.obj"
    with pytest.raises(InputError, match="empty.h5: not an ACRONYM grasp file: no 'grasps/transforms'"):
        read_acronym(empty)
    bad = tmp_path / "bad.h5"
    with h5py.File(bad, "w") as f:
        f["grasps/transforms"] = np.zeros((3, 3))
        f["object/file"] = "a.obj"
    with pytest.raises(InputError, match=r"bad.h5: grasps/transforms must be finite \(n, 4, 4\)"):
        read_acronym(bad)


def test_unknown_gripper_type_lists_the_known_ones(tmp_path, random_poses):
    path = tmp_path / "g.h5"
    write_acronym(path, random_poses(2), [1, 0], object_file="a.obj")
    with h5py.File(path, "r+") as f:
        del f["gripper/type"]
        f["gripper/type"] = "shadow_hand"
    grasps = read_acronym(path)  # reading works; converting needs the gripper's TCP offset
    with pytest.raises(SettingsError, match="unknown 'shadow_hand'; choose one of: box_jaw, panda, robotiq_2f85"):
        grasps.tcp_poses()
    np.testing.assert_allclose(grasps.tcp_poses(0.1034), random_poses(2), atol=1e-12)  # an explicit offset works


def test_write_checks_its_arguments(tmp_path, random_poses):
    with pytest.raises(ValueError, match="success: expected 2 labels"):
        write_acronym(tmp_path / "g.h5", random_poses(2), [1], object_file="a.obj")
    with pytest.raises(SettingsError, match="unknown 'hand'"):
        write_acronym(tmp_path / "g.h5", random_poses(2), [1, 1], object_file="a.obj", gripper="hand")
    with pytest.raises(ValueError, match="do not pass it twice"):
        write_acronym(tmp_path / "g.h5", random_poses(2), [1, 1], object_file="a.obj",
                      qualities={SUCCESS_KEY: [1, 1]})


# Upstream values, from ACRONYM's own example file (NVlabs/acronym at commit d02f58f,
# data/examples/grasps/Mug_10f6e09036350e92b3f21f1137c3c347_0.0002682457830986903.h5, read with h5py; the same in
# every file of its release, e.g. ../shared/calibration/acronym_more/*.h5):
ACRONYM_GRIPPER_TYPE = "panda"  # gripper/type: a variable-length UTF-8 string scalar
ACRONYM_GRIPPER_CONFIGURATION = [0.04]  # gripper/configuration, float64 (1,)
ACRONYM_LABEL_DTYPE = np.int64  # grasps/qualities/flex/object_in_gripper
ACRONYM_OBJECT_FILE = "meshes/Mug/10f6e09036350e92b3f21f1137c3c347.obj"  # object/file: relative to the mesh root


def test_panda_files_say_what_acronym_files_say(tmp_path, random_poses):
    path = tmp_path / "g.h5"
    write_acronym(path, random_poses(3, seed=4), [1, 0, 1], object_file="meshes/Mug/x.obj", object_scale=1.0,
                  gripper="panda")
    with h5py.File(path, "r") as f:
        assert f["gripper/type"][()].decode() == ACRONYM_GRIPPER_TYPE
        for key in ("gripper/type", "object/file"):
            info = h5py.check_string_dtype(f[key].dtype)  # ACRONYM: encoding utf-8, length None
            assert (info.encoding, info.length, f[key].shape) == ("utf-8", None, ())
        np.testing.assert_array_equal(f["gripper/configuration"][()], ACRONYM_GRIPPER_CONFIGURATION)
        assert f["gripper/configuration"].dtype == np.float64
        assert f["grasps/qualities/flex/object_in_gripper"].dtype == ACRONYM_LABEL_DTYPE
        assert f["object/file"][()].decode().split("/")[0] == ACRONYM_OBJECT_FILE.split("/")[0]  # meshes/...
    assert read_acronym(path).gripper == "panda"


def test_reads_the_older_exports_franka_panda(tmp_path, random_poses):
    """Exports made before the Panda was written as ``panda`` said ``franka_panda``: still our Panda."""
    path = tmp_path / "old.h5"
    T_base = random_poses(2, seed=5)
    with h5py.File(path, "w") as f:
        f["grasps/transforms"] = T_base
        f["object/file"] = np.bytes_("meshes/x.obj")
        f["gripper/type"] = np.bytes_("franka_panda")
    grasps = read_acronym(path)
    assert grasps.gripper == "panda"
    np.testing.assert_allclose(grasps.tcp_poses(), tcp_from_hand_base(T_base, 0.1034), atol=1e-15)
