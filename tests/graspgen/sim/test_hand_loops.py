"""Hands with closed kinematic loops (graspgen.sim.hand_loops, and hand_mjcf / hand_motion / gripper_derive for them):
a hand laid out as MuJoCo Menagerie's Robotiq 2F-85 (each finger a 4-bar closed by an equality connect, the drivers
tied by a joint equality and driven by an actuator on a tendon) gives the stroke, TCP and pad path that MuJoCo's own
simulation of the same file gives, and grasps a box; loops that do not reduce to a parallel-jaw hand are errors
naming them."""

from __future__ import annotations

import re

import mujoco
import numpy as np
import pytest
import trimesh

from graspgen.errors import SettingsError
from graspgen.grippers import read_gripper
from graspgen.sim.hand_loops import LoopSolver
from graspgen.sim.hand_mjcf import read_mjcf
from graspgen.workflows.evaluate import evaluate_grasps
from graspgen.workflows.evaluate_settings import EvaluateParams
from tests.paths import TESTS
from tests.shapes import top_down

pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")

HAND = TESTS / "graspgen" / "sim" / "data" / "loop_2f85.xml"
"""The 2F-85 laid out as Menagerie's: 85 mm stroke, the pad box 22 mm wide and 37.5 mm long (see its comment)."""

_YAML = "name: loop_2f85\nmodel: hand.xml\npads: [left_pad_box, right_pad_box]\nforce_limit: 100\nclosing_speed: 0.1\n"


def _gripper(tmp_path, xml: str | None = None, yaml: str = _YAML):
    (tmp_path / "hand.xml").write_text(HAND.read_text() if xml is None else xml)
    (tmp_path / "hand.yaml").write_text(yaml)
    return tmp_path / "hand.yaml"


def _corners(data: mujoco.MjData, model: mujoco.MjModel, geom: str) -> np.ndarray:
    """(8, 3) corners (m, world = the base's frame) of box geom ``geom``."""
    g = model.geom(geom).id
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    return data.geom_xpos[g] + (signs * model.geom_size[g]) @ data.geom_xmat[g].reshape(3, 3).T


def _reference(path, holds: int = 41) -> dict:
    """The file's own simulation, the slow reference: its actuator's control stepped from open to closed and held at
    ``holds`` values until the hand settles, gravity and contacts off; the pads' faces along the stroke in the base
    frame (which closes along y and approaches along z). The control range (0 .. 255 for 0 .. 0.8 rad) is widened by
    a tenth at each end, so that the position actuator, which the spring links' springs push, holds the drivers at
    their joint limits there rather than a few mrad short."""
    model = mujoco.MjModel.from_xml_path(str(path))
    model.opt.gravity[:] = 0.0
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    model.actuator_ctrlrange[0] = (-25.5, 280.5)
    data = mujoco.MjData(model)
    out = {"width": [], "z_lo": [], "z_hi": [], "right_z": [], "turn": [], "right_pad": []}
    for ctrl in np.linspace(-25.5, 280.5, holds):
        data.ctrl[0] = ctrl
        for _ in range(1500):  # 3 s: the position actuator's damped response settles to well under a micrometre
            mujoco.mj_step(model, data)
        right, left = _corners(data, model, "right_pad_box"), _corners(data, model, "left_pad_box")
        out["width"].append(right[:, 1].min() - left[:, 1].max())
        out["z_lo"].append(max(right[:, 2].min(), left[:, 2].min()))
        out["z_hi"].append(min(right[:, 2].max(), left[:, 2].max()))
        out["right_z"].append(right[:, 2].mean())
        out["turn"].append(data.xmat[model.body("right_pad").id].reshape(3, 3).copy())  # a view of data: copy it
        out["right_pad"].append(data.xpos[model.body("right_pad").id].copy())
    return {k: np.array(v) for k, v in out.items()}


def test_a_menagerie_style_2f85_with_loops_gives_the_stroke_tcp_and_pad_path_of_its_own_simulation(tmp_path):
    spec = read_gripper(_gripper(tmp_path))
    ref = _reference(HAND)
    assert np.all(np.diff(ref["width"]) < 1e-7)  # the reference closes steadily (held at the limits at the ends)
    assert spec.max_width == pytest.approx(ref["width"][0], abs=5e-5)
    assert spec.max_width == pytest.approx(0.085, abs=1e-4)  # the data sheet's stroke
    assert ref["width"][-1] < 0 and spec.min_width == 0.0  # the faces meet before the drivers' 0.8 rad
    # TCP: halfway along the part of the pad faces that faces it at every width, over the base.
    tcp = (ref["z_lo"].max() + ref["z_hi"].min()) / 2.0
    assert spec.tcp_offset == pytest.approx(tcp, abs=5e-5)
    assert spec.pad_size[2] == pytest.approx(ref["z_hi"].min() - ref["z_lo"].max(), abs=1e-4)
    # The pads ride the parallelogram: the derived linkage's rise is the simulated one to 0.2 mm (the derivation's own
    # check against its path), and the pads stay parallel.
    inside = ref["width"] > 0.0
    rise = ref["right_z"][inside] - ref["right_z"][0]
    assert spec.linkage is not None
    assert spec.pad_rise(ref["width"][inside]) == pytest.approx(rise, abs=5e-5)
    assert rise.max() > 0.01  # it does rise: 13 mm over the stroke
    turn = [np.arccos(np.clip((np.trace(ref["turn"][0].T @ R) - 1.0) / 2.0, -1.0, 1.0)) for R in ref["turn"]]
    assert max(turn) < np.radians(0.1)
    assert "loops right_loop, left_loop closed by MuJoCo" in spec.source
    assert spec.finger_mass == pytest.approx(0.016)  # follower and pad
    assert spec.linkage.driver_mass == pytest.approx(0.022)  # the spring link, on the pad's chain
    assert spec.linkage.follower_mass == pytest.approx(0.024)  # driver and coupler, the loop's other side


def test_the_loops_are_kept_for_mujoco_and_the_drivers_coupling_is_a_mimic():
    tree = read_mjcf(HAND)
    assert tree.loops == {"right_loop": ("right_follower", "right_coupler"),
                          "left_loop": ("left_follower", "left_coupler")}
    joints = {j.name: j for j in tree.joints}
    assert joints["right_driver_joint"].mimic == ("left_driver_joint", 1.0, 0.0)
    assert tree.actuators["fingers"][0] == ("right_driver_joint", "left_driver_joint")
    assert joints["right_follower_joint"].anchor == pytest.approx((0.0, -0.0174, 0.006))


def test_the_solver_holds_the_parallelogram_along_the_stroke():
    hand = [f"{s}_{j}_joint" for s in ("right", "left") for j in ("driver", "coupler", "spring_link", "follower")]
    solver = LoopSolver(HAND, hand, ("right_driver_joint", "left_driver_joint"), ("right_loop", "left_loop"))
    path = solver.path({"right_driver_joint": (0.0, 0.8), "left_driver_joint": (0.0, 0.8)}, 21)
    q = dict(zip(path.joints, path.q.T))
    assert q["right_driver_joint"] == pytest.approx(np.linspace(0.0, 0.8, 21))
    # A parallelogram: the spring link turns with the driver, the follower turns back by as much (the pad keeps its
    # orientation) and the coupler stays at its limit, where the spring link's spring holds it.
    assert q["right_spring_link_joint"] == pytest.approx(q["right_driver_joint"], abs=1e-4)
    assert q["right_follower_joint"] == pytest.approx(-q["right_driver_joint"], abs=1e-4)
    assert q["right_coupler_joint"] == pytest.approx(0.0, abs=1e-4)
    assert path.at(0.5)["left_spring_link_joint"] == pytest.approx(0.4, abs=1e-4)


def test_a_looped_hand_grasps_a_box_and_not_an_oversized_one(tmp_path):
    gripper = _gripper(tmp_path)
    for size, name in ((0.04, "small.obj"), (0.2, "large.obj")):
        trimesh.creation.box(extents=(size, 0.04, 0.04)).export(tmp_path / name)
    poses = top_down(0.0, 0.0, 0.0)[None]
    small, large = (evaluate_grasps(tmp_path / n, 1.0, poses, None, gripper, EvaluateParams(), protocol="acronym",
                                    cache_dir=tmp_path / "cache") for n in ("small.obj", "large.obj"))
    assert small.column("outcome").to_pylist() == [5]  # lifted
    assert large.column("outcome").to_pylist() != [5]  # 200 mm does not fit between the pads


#: Each follower's joint 6 mm lower on it: its spring link is shorter than its driver, the 4-bars are no
#: parallelograms and the pads turn.
_SKEWED = ('pos="0 -0.0174 0.006"', 'pos="0 -0.0174 0.0"')
#: The couplers free to turn (no limit at 0 to lean on): the spring links' springs swing them and the pads turn.
_LOOSE = ('<joint range="-1.57 0"/>', '<joint range="-1.57 1.57"/>')
#: No spring on the spring links: nothing holds the couplers at their limit, the links' pose depends on the way there.
_FREE = ('stiffness="0.05"', 'stiffness="0"')
#: The left pad welded to the base: no closing motion keeps the weld.
_STUCK = ("</equality>", '<weld name="stuck" body1="left_pad" body2="base"/></equality>')


@pytest.mark.parametrize(("edit", "message"), [
    (_SKEWED, r"pads: the pad body 'right_pad' turns \d+\.\d\d degrees while closing \(with its loops "
              r"right_loop, left_loop closed by MuJoCo\), more than pad_turn_tolerance \(1 deg\); graspgen simulates "
              r"parallel-jaw grippers"),
    (_LOOSE, r"pads: the pad body 'right_pad' turns \d+\.\d\d degrees while closing \(with its loops "),
    (_FREE, r"model hand.xml: the loops \(right_loop, left_loop\) do not fix the fingers: body \w+ is "
            r"\d\.\d\d mm apart closing and opening through the same joint values"),
    (_STUCK, r"model hand.xml: equality stuck cannot be closed with the closing joints at right_driver_joint = .*; "
             r"name the joints that close the hand with joints: \[...\] or fix the loop"),
])
def test_loops_that_do_not_reduce_to_a_parallel_jaw_hand_are_errors_naming_them(tmp_path, edit, message):
    text = HAND.read_text()
    assert edit[0] in text
    with pytest.raises(SettingsError, match=message):
        read_gripper(_gripper(tmp_path, text.replace(*edit)))


def test_a_looped_hand_without_an_actuator_needs_its_closing_joints_named(tmp_path):
    text = HAND.read_text().replace("<actuator>", "<!-- <actuator>").replace("</actuator>", "</actuator> -->")
    with pytest.raises(SettingsError, match=r"joints: the hand's loops \(right_loop, left_loop\) hide which joints "
                                            r"drive it and it has no actuator; name the joints that close it"):
        read_gripper(_gripper(tmp_path, text))
    spec = read_gripper(_gripper(tmp_path, text, _YAML + "joints: [right_driver_joint, left_driver_joint]\n"))
    assert spec.max_width == pytest.approx(0.085, abs=1e-4) and spec.linkage is not None



SKEW = TESTS / "graspgen" / "sim" / "data" / "loop_2f85_skew.xml"
"""loop_2f85.xml with 4-bars that are no parallelograms, as Menagerie's 2F-85's: base side 18.4 mm, opposite 19.1 mm."""


def _skew(tmp_path, tolerance=None):
    """The skewed hand's gripper file, with ``pad_turn_tolerance: <tolerance>`` (degrees) when given."""
    extra = "" if tolerance is None else f"pad_turn_tolerance: {tolerance}\n"
    return _gripper(tmp_path, SKEW.read_text(), _YAML + extra)


def _turns(ref: dict) -> np.ndarray:
    """(k,) degrees the right pad body has turned at each reference sample since the first (open)."""
    return np.degrees([np.arccos(np.clip((np.trace(ref["turn"][0].T @ R) - 1.0) / 2.0, -1.0, 1.0))
                       for R in ref["turn"]])


def test_the_skewed_4bar_has_menagerie_sides():
    model = mujoco.MjModel.from_xml_path(str(SKEW))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    pos = {n: data.xanchor[model.joint(f"right_{n}_joint").id] for n in ("driver", "spring_link", "follower")}
    follower = model.body("right_follower").id
    anchor = data.xpos[follower] + data.xmat[follower].reshape(3, 3) @ model.eq("right_loop").data[:3]
    assert np.linalg.norm(pos["driver"] - pos["spring_link"]) == pytest.approx(0.0184, abs=5e-5)
    assert np.linalg.norm(anchor - pos["follower"]) == pytest.approx(0.0191, abs=5e-5)


def test_pads_that_turn_more_than_the_tolerance_are_refused_naming_the_turn_and_the_option(tmp_path):
    ref = _reference(SKEW)
    with pytest.raises(SettingsError) as err:
        read_gripper(_skew(tmp_path))
    message = str(err.value)
    assert "more than pad_turn_tolerance (1 deg)" in message
    assert "give pad_turn_tolerance: 2 (degrees) in the gripper file" in message
    assert "the derived gripper keeps its pads parallel, the turn is ignored" in message
    turned = float(re.search(r"pad body 'right_pad' turns (\d+\.\d+) degrees while closing", message)[1])
    # The simulated turn where the faces meet (the end of the stroke), between the reference's samples.
    inside = ref["width"] > -0.005
    simulated = float(np.interp(0.0, ref["width"][inside][::-1], _turns(ref)[inside][::-1]))
    assert turned == pytest.approx(simulated, abs=0.02)
    assert 1.5 < turned < 2.0  # Menagerie's 2F-85 turns its pads about 1.8 degrees


def test_pads_that_turn_within_the_tolerance_are_kept_parallel_on_the_simulated_path(tmp_path):
    spec = read_gripper(_skew(tmp_path, 3))
    ref = _reference(SKEW)
    assert np.all(np.diff(ref["width"]) < 1e-7)
    assert spec.max_width == pytest.approx(ref["width"][0], abs=5e-5)
    assert spec.max_width == pytest.approx(0.085, abs=1e-4)
    assert spec.min_width == 0.0
    assert spec.tcp_offset == pytest.approx((ref["z_lo"].max() + ref["z_hi"].min()) / 2.0, abs=1e-4)
    inside = ref["width"] > 0.0
    assert spec.linkage is not None
    # The pad body's origin rides the derived linkage to 0.05 mm (the derivation checks 0.2 mm) ...
    travel = ref["right_pad"][inside] - ref["right_pad"][0]
    assert spec.linkage.rise(travel[:, 1]) == pytest.approx(travel[:, 2], abs=1e-4)
    # ... and the pad face rises as simulated to 0.3 mm at the same width: the 1.7 degrees the derived pads do not turn
    # tilt the simulated face (37.5 mm long) by up to 1.1 mm, which moves where it touches at a width.
    rise = ref["right_z"][inside] - ref["right_z"][0]
    assert spec.pad_rise(ref["width"][inside]) == pytest.approx(rise, abs=3e-4)
    assert re.search(r"; the pads turn 1\.\d\d degrees while closing \(pad_turn_tolerance 3 deg\): simulated "
                     r"parallel, the turn ignored$", spec.source)
    exact = tmp_path / "exact"
    exact.mkdir()
    assert "turn" not in read_gripper(_gripper(exact)).source  # the exact parallelogram's pads turn under 0.1 degree


def test_a_hand_whose_pads_turn_within_the_tolerance_grasps_a_box(tmp_path):
    gripper = _skew(tmp_path, 3)
    trimesh.creation.box(extents=(0.04, 0.04, 0.04)).export(tmp_path / "small.obj")
    table = evaluate_grasps(tmp_path / "small.obj", 1.0, top_down(0.0, 0.0, 0.0)[None], None, gripper,
                            EvaluateParams(), protocol="acronym", cache_dir=tmp_path / "cache")
    assert table.column("outcome").to_pylist() == [5]  # lifted


@pytest.mark.parametrize(("value", "message"), [
    (-1, r"pad_turn_tolerance: must be in \[0, 10\], got -1 \(degrees a pad may turn while closing\)"),
    (30, r"pad_turn_tolerance: must be in \[0, 10\], got 30 \(degrees"),
    ("'2 deg'", r"pad_turn_tolerance: must be a number, got '2 deg' \(degrees"),
])
def test_a_bad_pad_turn_tolerance_is_an_error_naming_the_key(tmp_path, value, message):
    with pytest.raises(SettingsError, match=message):
        read_gripper(_skew(tmp_path, value))
