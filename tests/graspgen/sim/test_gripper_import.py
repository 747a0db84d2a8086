"""Grippers given as robot models (graspgen.grippers.model_ref, graspgen.sim.gripper_import / gripper_derive /
hand_motion / hand_tree): what is derived from a URDF, the errors that name the missing key, and the example models of
the 'grippers' extra against the bundled hands made by hand from the same or the maker's figures."""

from __future__ import annotations

import os

import mujoco
import numpy as np
import pytest
import trimesh

from graspgen.errors import SettingsError
from graspgen.grippers import Box, Mesh, gripper_files, load_gripper, read_gripper
from graspgen.sim.gripper_model import build_gripper
from graspgen.sim.gripper_state import gripper_geom_ids, gripper_width, set_gripper_width
from tests.model_grippers import model_gripper

pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")

#: A two-jaw hand whose base is turned (approach along base -y, closing along base x) so that nothing lines up with
#: the base frame by chance; the palm and the mount come as two geoms, the pad as a box at the fingertip.
_URDF = """<robot name="test_hand">
  <link name="base"><inertial><mass value="0.5"/></inertial>
    <collision><origin xyz="0 -0.02 0"/><geometry><box size="0.1 0.04 0.03"/></geometry></collision>
    {palm_mesh}
  </link>
  <link name="left"><inertial><mass value="0.02"/></inertial>
    <collision name="left_mount"><origin xyz="-0.005 -0.01 0"/><geometry><box size="0.01 0.02 0.02"/></geometry>
    </collision>
    <collision name="left_tip"><origin xyz="0.002 -0.04 0"/><geometry><box size="0.004 0.02 0.018"/></geometry>
    </collision>
  </link>
  <link name="right"><inertial><mass value="0.02"/></inertial>
    <collision name="right_mount"><origin xyz="0.005 -0.01 0"/><geometry><box size="0.01 0.02 0.02"/></geometry>
    </collision>
    <collision name="right_tip"><origin xyz="-0.002 -0.04 0"/><geometry><box size="0.004 0.02 0.018"/></geometry>
    </collision>
  </link>
  <joint name="j_left" type="prismatic"><parent link="base"/><child link="left"/>
    <origin xyz="-0.04 0 0"/><axis xyz="1 0 0"/><limit lower="0" upper="0.035" effort="{effort}" velocity="0.05"/>
  </joint>
  <joint name="j_right" type="prismatic"><parent link="base"/><child link="right"/>
    <origin xyz="0.04 0 0"/><axis xyz="1 0 0"/><limit lower="-0.035" upper="0" effort="{effort}" velocity="0.05"/>
    <mimic joint="j_left" multiplier="-1" offset="0"/>
  </joint>
</robot>
"""


def _hand(tmp_path, *, effort=40.0, palm_mesh="", yaml_extra="", pads="[left, right]"):
    (tmp_path / "hand.urdf").write_text(_URDF.format(effort=effort, palm_mesh=palm_mesh))
    path = tmp_path / "hand.yaml"
    path.write_text(f"name: test_hand\nmodel: hand.urdf\npads: {pads}\n{yaml_extra}")
    return path


def test_a_prismatic_urdf_hand_is_derived_from_its_model(tmp_path):
    spec = read_gripper(_hand(tmp_path))
    # Pads: the tips (they reach farthest towards each other), faces at x = -0.04 + 0.004 and 0.04 - 0.004 open.
    assert spec.max_width == pytest.approx(0.072, abs=1e-9)
    assert spec.min_width == pytest.approx(0.002, abs=1e-9)  # 35 mm of travel per jaw
    assert spec.tcp_offset == pytest.approx(0.04, abs=1e-9)  # tips centred 40 mm out along base -y
    assert spec.pad_size == pytest.approx((0.004, 0.018, 0.02))  # thickness, width (base z), length (base y)
    assert isinstance(spec.pad_geom, Box) and spec.pad_geom.bounds[0][0] == pytest.approx(0.036)
    assert spec.linkage is None
    assert spec.force_limit == 40.0 and spec.closing_speed == pytest.approx(0.1)  # effort; 2 x 0.05 m/s
    assert spec.body_mass == 0.5 and spec.finger_mass == 0.02
    assert "j_left" in spec.source and "slide" in spec.source
    assert str(tmp_path / "hand.urdf") in gripper_files(tmp_path / "hand.yaml")


def test_a_derived_hand_closes_in_mujoco_to_its_stroke(tmp_path):
    spec = read_gripper(_hand(tmp_path))
    model = build_gripper(spec).compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert gripper_width(model, data) == pytest.approx(spec.max_width, abs=1e-6)
    set_gripper_width(model, data, spec.min_width)
    for _ in range(400):
        mujoco.mj_step(model, data)
    assert gripper_width(model, data) == pytest.approx(spec.min_width, abs=2e-4)
    roles = gripper_geom_ids(model)
    assert len(roles["pad"]) == 2 and len(roles["finger"]) == 2 and len(roles["palm"]) == 1


def test_an_edited_model_file_is_read_again(tmp_path):
    path = _hand(tmp_path)
    assert read_gripper(path).force_limit == 40.0
    assert read_gripper(path) is read_gripper(path)  # unchanged files: the cached spec
    urdf = tmp_path / "hand.urdf"
    stamp = urdf.stat().st_mtime_ns
    urdf.write_text(_URDF.format(effort=55.0, palm_mesh=""))  # the YAML is not touched
    os.utime(urdf, ns=(stamp + 10**9, stamp + 10**9))  # a later mtime even on a coarse clock
    assert read_gripper(path).force_limit == 55.0


def test_overrides_narrow_the_stroke_and_supply_values(tmp_path):
    spec = read_gripper(_hand(tmp_path, yaml_extra="max_width: 0.05\nforce_limit: 25\nclosing_speed: 0.02\n"))
    assert spec.max_width == pytest.approx(0.05, abs=1e-6)
    assert spec.pad_geom.bounds[0][0] == pytest.approx(0.025, abs=1e-6)  # the face where the width is 50 mm
    assert spec.force_limit == 25.0 and spec.closing_speed == 0.02


def test_a_non_convex_mesh_is_decomposed_once_and_cached(tmp_path, monkeypatch):
    monkeypatch.setenv("GRASPGEN_GRIPPER_CACHE", str(tmp_path / "cache"))
    outline = [(-0.05, 0), (0.05, 0), (0.05, 0.05), (0.04, 0.05), (0.04, 0.01), (-0.05, 0.01)]  # an L, 10 mm thick
    ell = trimesh.creation.extrude_triangulation(np.array(outline), np.array([[0, 1, 4], [0, 4, 5], [1, 2, 3],
                                                                              [1, 3, 4]]), 0.03)
    assert ell.is_watertight and ell.convex_hull.volume > 2 * ell.volume
    ell.export(tmp_path / "ell.obj")
    mesh = '<collision><origin xyz="0 0.02 0"/><geometry><mesh filename="ell.obj"/></geometry></collision>'
    spec = read_gripper(_hand(tmp_path, palm_mesh=mesh))
    pieces = [p for p in spec.palm_geoms if isinstance(p, Mesh)]
    assert len(pieces) >= 2  # an L cut into convex parts, not its hull
    assert len(list((tmp_path / "cache").glob("coacd-*.npz"))) == 1
    assert str(tmp_path / "ell.obj") in gripper_files(tmp_path / "hand.yaml")


@pytest.mark.parametrize(("change", "message"), [
    ({"pads": "[left, nowhere]"}, r"pads: no geom or body 'nowhere' in the hand; bodies: base, left, right"),
    ({"pads": "[left_tip, left_mount]"}, r"pads: both pads are on body 'left'"),
    ({"pads": "[base, right]"}, r"joints: cannot tell which joints close the hand \(independent moving joints: "
                                r"j_left\); name them with joints: \[...\]"),
    ({"effort": 0.0}, r"force_limit: the model gives no grip force"),
    ({"yaml_extra": "joints: [base_joint]\n"}, r"joints: 'base_joint' is not a moving joint of the hand; its "
                                               r"moving joints: j_left, j_right"),
    ({"yaml_extra": "tcp_offset: 0.1\n"}, r"tcp_offset: not valid beside model \(the geometry comes from the "
                                          r"model\)"),
    ({"yaml_extra": "body: palm\n"}, r"body: no body 'palm' in hand.urdf; bodies: base, left, right"),
])
def test_what_cannot_be_derived_is_an_error_naming_the_key(tmp_path, change, message):
    with pytest.raises(SettingsError, match=message):
        read_gripper(_hand(tmp_path, **change))


def test_a_missing_model_file_or_package_is_an_error(tmp_path):
    path = tmp_path / "hand.yaml"
    path.write_text("name: h\nmodel: nothing.urdf\npads: [a, b]\n")
    with pytest.raises(SettingsError, match=r"model: .*nothing.urdf: no such file"):
        read_gripper(path)
    path.write_text("name: h\nmodel: {package: no_such_package_43, path: x.urdf}\npads: [a, b]\n")
    with pytest.raises(SettingsError, match=r"Python package 'no_such_package_43' is not installed"):
        read_gripper(path)


def test_robotiq_2f85_urdf_gives_the_bundled_linkage():
    """The bundled robotiq_2f85_mesh was written by hand from the same URDF: every derived figure must match it."""
    spec, bundled = load_gripper(model_gripper("robotiq_2f85_urdf")), load_gripper("robotiq_2f85_mesh")
    assert spec.max_width == pytest.approx(0.085, abs=1e-6)
    assert spec.min_width == pytest.approx(0.0015, abs=2e-4)  # the URDF's 0.8 rad range stops 1.5 mm short
    assert spec.tcp_offset == pytest.approx(bundled.tcp_offset, abs=1e-4)
    assert spec.pad_size == pytest.approx(bundled.pad_size, abs=1e-4)
    link, ref = spec.linkage, bundled.linkage
    assert np.asarray(link.pivot) == pytest.approx(ref.pivot, abs=1e-4)
    assert np.asarray(link.crank) == pytest.approx(ref.crank, abs=1e-4)
    assert np.asarray(link.follower_pivot) == pytest.approx(ref.follower_pivot, abs=1e-4)
    widths = np.linspace(spec.min_width, spec.max_width, 9)
    assert spec.pad_rise(widths) == pytest.approx(bundled.pad_rise(widths), abs=1e-4)


def test_panda_urdf_hand_inside_the_arm_gives_the_bundled_figures():
    spec, bundled = load_gripper(model_gripper("panda_urdf")), load_gripper("panda")
    assert spec.max_width == pytest.approx(bundled.max_width, abs=1e-4)  # 2 x 0.04 m joint range
    assert spec.min_width == 0.0 and spec.linkage is None
    assert spec.tcp_offset == pytest.approx(bundled.tcp_offset, abs=5e-4)  # the fingertip box's centre
    assert spec.pad_size[1:] == pytest.approx(bundled.pad_size[1:], abs=1e-3)


def test_schunk_egk40_gets_its_box_fingers():
    spec = load_gripper(model_gripper("schunk_egk40"))
    assert spec.max_width == pytest.approx(0.1, abs=1e-9)  # mounts 55 mm apart, faces 22.5 mm outboard of them
    assert spec.min_width == pytest.approx(0.0, abs=1e-9)  # they meet at the end of the 50 mm of travel
    assert spec.force_limit == 10.0 and spec.closing_speed == pytest.approx(0.2)  # URDF effort, 2 x 0.1 m/s
    assert spec.pad_size == pytest.approx((0.002, 0.02, 0.07))


#: The same hand as _URDF in MJCF: joint equality for the mimic, a tendon position actuator with a force range,
#: a visual-only geom (ignored), and the base's approach along its -y as before.
_MJCF = """<mujoco model="test_hand">
  <worldbody>
    <body name="base">
      <geom type="box" size="0.05 0.02 0.015" pos="0 -0.02 0" mass="0.5"/>
      <geom type="sphere" size="0.5" contype="0" conaffinity="0" mass="0"/>
      <body name="left" pos="-0.04 0 0">
        <joint name="j_left" type="slide" axis="1 0 0" range="0 0.035"/>
        <geom name="left_mount" type="box" size="0.005 0.01 0.01" pos="-0.005 -0.01 0" mass="0.01"/>
        <geom name="left_tip" type="box" size="0.002 0.01 0.009" pos="0.002 -0.04 0" mass="0.01"/>
      </body>
      <body name="right" pos="0.04 0 0">
        <joint name="j_right" type="slide" axis="1 0 0" range="-0.035 0"/>
        <geom name="right_mount" type="box" size="0.005 0.01 0.01" pos="0.005 -0.01 0" mass="0.01"/>
        <geom name="right_tip" type="box" size="0.002 0.01 0.009" pos="-0.002 -0.04 0" mass="0.01"/>
      </body>
    </body>
  </worldbody>
  <tendon><fixed name="split"><joint joint="j_left" coef="0.5"/><joint joint="j_right" coef="-0.5"/></fixed></tendon>
  <equality><joint joint1="j_right" joint2="j_left" polycoef="0 -1 0 0 0"/></equality>
  <actuator><position name="close" tendon="split" kp="100" forcelimited="true" forcerange="-60 60"
    ctrlrange="0 0.035"/></actuator>
</mujoco>
"""


def test_an_mjcf_hand_gives_the_urdf_hands_figures_and_its_actuators_force(tmp_path):
    (tmp_path / "hand.xml").write_text(_MJCF)
    path = tmp_path / "hand.yaml"
    path.write_text("name: test_hand\nmodel: hand.xml\npads: [left_tip, right_tip]\nbody: base\nclosing_speed: 0.1\n")
    (tmp_path / "u").mkdir()
    spec, urdf = read_gripper(path), read_gripper(_hand(tmp_path / "u"))
    for key in ("max_width", "min_width", "tcp_offset", "pad_size", "body_mass", "finger_mass"):
        assert getattr(spec, key) == pytest.approx(getattr(urdf, key), abs=1e-9), key
    assert spec.force_limit == 30.0  # 60 N on the tendon, half of it on each jaw
    assert "actuator close" in spec.source and len(spec.palm_geoms) == 1  # the visual sphere is left out
    path.write_text("name: test_hand\nmodel: hand.xml\npads: [left_tip, right_tip]\nactuator: open\n")
    with pytest.raises(SettingsError, match=r"actuator: no actuator 'open' in the model; its actuators: close"):
        read_gripper(path)
    path.write_text("name: test_hand\nmodel: hand.xml\npads: [left_tip, right_tip]\n")
    with pytest.raises(SettingsError, match=r"closing_speed: the model gives the closing joints no velocity limit"):
        read_gripper(path)
