"""Tests of graspgen.grippers (gripper data and files), graspgen.sim.gripper_model / gripper_state / physics (the
MjSpec builder, attach, helpers, grasp-and-lift physics), the bundled grippers against their published figures, and
graspgen.viz.gripper_picture."""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.util
import json
import time
from pathlib import Path

import mujoco
import numpy as np
import pytest
import trimesh

from graspgen.errors import GraspGenError, NotFoundError, SettingsError
from graspgen.grippers import (
    ACRONYM_GRIPPER,
    BUNDLED_DIGESTS,
    DEFAULT_GRIPPER,
    GRIPPERS,
    GRIPPERS_DIR,
    Box,
    GripperSpec,
    gripper_files,
    load_gripper,
    read_gripper,
    write_gripper,
)
from graspgen.sim.gripper_model import (
    GRIPPER_CONAFFINITY,
    GRIPPER_CONTYPE,
    GRIPPER_GEOM_GROUP,
    attach_gripper,
    build_gripper,
)
from graspgen.sim.gripper_state import (
    gripper_geom_ids,
    gripper_pose,
    gripper_width,
    linkage_couplings,
    pad_geom_ids,
    set_gripper_pose,
    set_gripper_target,
    set_gripper_width,
)
from graspgen.sim.physics import PhysicsOptions, physics_options
from graspgen.viz.gripper_picture import gripper_picture
from tests.paths import REPO

PANDA_STL = REPO / "assets" / "grippers" / "panda" / "franka_gripper_collision_mesh.stl"

GRIPPER_NAMES = sorted(GRIPPERS)
BOX_HALF = 0.025  # 5 cm box


pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")


def _compile(spec: mujoco.MjSpec) -> tuple[mujoco.MjModel, mujoco.MjData]:
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data


def _settle(model, data, seconds: float) -> None:
    for _ in range(int(round(seconds / model.opt.timestep))):
        mujoco.mj_step(model, data)


def _rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, q)
    return R.reshape(3, 3)


def _box_world(box_friction: float, *, box_mass: float = 1.0, gripper: str = "robotiq_2f85",
               friction_mode: str = "object", options: PhysicsOptions | None = None) -> mujoco.MjSpec:
    """Ground plane + a free 5 cm box resting on it (inline XML) + the gripper attached by MjSpec attach."""
    xml = f"""
    <mujoco model="box_world">
      <worldbody>
        <geom name="ground" type="plane" size="1 1 0.1" friction="1 0.005 0.0001"/>
        <body name="box" pos="0 0 {BOX_HALF}">
          <freejoint name="box_free"/>
          <geom name="box" type="box" size="{BOX_HALF} {BOX_HALF} {BOX_HALF}" mass="{box_mass}"
                friction="{box_friction} 0.005 0.0001"/>
        </body>
      </worldbody>
    </mujoco>"""
    world = mujoco.MjSpec.from_string(xml)
    physics_options(world, options)
    attach_gripper(world, load_gripper(gripper), friction=friction_mode)
    return world


def _grasp_and_lift(model, data, *, lift: float = 0.2, lift_time: float = 1.0) -> dict:
    """Top-down grasp of the box: TCP at the box centre, z (approach) pointing down; open, close, lift, hold."""
    box = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "box")
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # x closing along world x, z approach along world -z
    T[:3, 3] = [0.0, 0.0, BOX_HALF]
    set_gripper_width(model, data, load_gripper("robotiq_2f85").max_width, instant=True)
    set_gripper_pose(model, data, T)
    z0 = float(data.xpos[box][2])
    n_steps, step_time = 0, 0.0

    def step():
        nonlocal n_steps, step_time
        t = time.perf_counter()
        mujoco.mj_step(model, data)
        step_time += time.perf_counter() - t
        n_steps += 1

    t0 = time.perf_counter()
    set_gripper_width(model, data, 0.0)  # close: force saturates at force_limit on the box
    for _ in range(400):  # 0.8 s: closing 85 -> 50 mm at 0.15 m/s takes ~0.25 s
        step()
    steps = int(round(lift_time / model.opt.timestep))
    rel_before = np.linalg.inv(gripper_pose(model, data)) @ np.append(data.xpos[box], 1.0)
    for i in range(steps):
        Ti = T.copy()
        Ti[2, 3] += lift * (i + 1) / steps
        set_gripper_target(model, data, Ti)
        step()
    for _ in range(250):  # hold 0.5 s
        step()
    elapsed = time.perf_counter() - t0
    T_now = gripper_pose(model, data)
    rel_after = np.linalg.inv(T_now) @ np.append(data.xpos[box], 1.0)
    return {
        "dz": float(data.xpos[box][2]) - z0,
        "box_in_tcp": rel_after[:3],
        "slip": float(np.linalg.norm(rel_after[:3] - rel_before[:3])),
        "width": gripper_width(model, data),
        "loop_steps_per_s": n_steps / elapsed,  # with the Python helpers moving the target each step
        "steps_per_s": n_steps / step_time,  # mj_step alone
        "tcp_error": float(np.linalg.norm(T_now[:3, 3] - Ti[:3, 3])),
    }


def _geom_vertices(model, data, gid: int) -> np.ndarray:
    """(n, 3) world vertices of a box (its corners) or mesh geom."""
    R, p = data.geom_xmat[gid].reshape(3, 3), data.geom_xpos[gid]
    if model.geom_type[gid] == mujoco.mjtGeom.mjGEOM_MESH:
        m = model.geom_dataid[gid]
        local = model.mesh_vert[model.mesh_vertadr[m]:model.mesh_vertadr[m] + model.mesh_vertnum[m]]
    else:
        local = np.array(np.meshgrid(*[[-h, h] for h in model.geom_size[gid]])).reshape(3, -1).T
    return local @ R.T + p


def _in_tcp(model, data, points: np.ndarray) -> np.ndarray:
    T = gripper_pose(model, data)
    return (points - T[:3, 3]) @ T[:3, :3]


def _pad_faces(model, data) -> tuple[float, float, float, float]:
    """TCP-frame x of the left and right pads' contact faces (the left pad's largest x, the right's smallest), and
    the lowest and highest z of the pads."""
    left, right = pad_geom_ids(model)
    pl = _in_tcp(model, data, _geom_vertices(model, data, left[0]))
    pr = _in_tcp(model, data, _geom_vertices(model, data, right[0]))
    both = np.vstack([pl, pr])
    return float(pl[:, 0].max()), float(pr[:, 0].min()), float(both[:, 2].min()), float(both[:, 2].max())


def _pad_centre_z(spec: GripperSpec, width: float) -> float:
    """TCP-frame z (m) of the pads' centre at ``width``: 0, or with a linkage, the open pad's centre plus its rise."""
    if spec.linkage is None:
        return 0.0
    lo, hi = (spec.pad_geom or Box(size=spec.pad_size)).bounds
    return float((lo[2] + hi[2]) / 2.0 + spec.pad_rise(width))


def _pad_contacts(model, data) -> tuple[bool, bool]:
    left, right = pad_geom_ids(model)
    box_geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "box")
    touching = {g for c in data.contact[: data.ncon] for g in (c.geom1, c.geom2)
                if box_geom in (c.geom1, c.geom2)}
    return bool(touching & set(left)), bool(touching & set(right))


# ------------------------------------------------------------------------------------------------- data & registry


def test_registry_holds_the_bundled_grippers():
    assert set(GRIPPERS) == {"robotiq_2f85", "robotiq_2f85_mesh", "panda", "box_jaw"}
    assert DEFAULT_GRIPPER == "robotiq_2f85_mesh"
    f85 = load_gripper("robotiq_2f85")
    assert (f85.min_width, f85.max_width) == (0.0, 0.085)
    assert 20.0 <= f85.force_limit <= 235.0  # Robotiq 2F-85 data sheet grip force range
    assert 0.13 <= f85.tcp_offset <= 0.15
    assert f85.pad_size[1] == pytest.approx(0.022)
    panda = load_gripper("panda")
    assert (panda.max_width, panda.tcp_offset, panda.force_limit) == (0.08, 0.1034, 70.0)
    assert load_gripper("box_jaw").max_width == 0.1
    for spec in GRIPPERS.values():
        assert GRIPPERS[spec.name] is spec
        assert spec.to_dict()["name"] == spec.name


def test_default_gripper_names_are_the_settings_defaults():
    """One constant per default: the scene grasps' (the mesh 2F-85) and the object-centric / ACRONYM one (the
    Panda, ACRONYM's own hand); the config sections and the ACRONYM writer take them from graspgen.grippers."""
    import inspect

    from graspgen.io.acronym import write_acronym
    from stages.config import Config

    assert (DEFAULT_GRIPPER, ACRONYM_GRIPPER) == ("robotiq_2f85_mesh", "panda")
    assert {DEFAULT_GRIPPER, ACRONYM_GRIPPER} <= set(GRIPPERS)
    config = Config()
    assert config.grasps.gripper == DEFAULT_GRIPPER
    assert config.object_grasps.gripper == ACRONYM_GRIPPER
    assert inspect.signature(write_acronym).parameters["gripper"].default == ACRONYM_GRIPPER


def test_unknown_gripper_raises_settings_error_listing_choices():
    with pytest.raises(SettingsError) as err:
        load_gripper("x")
    assert str(err.value) == ("gripper: unknown 'x'; choose one of: box_jaw, panda, robotiq_2f85, robotiq_2f85_mesh "
                              "(or give the path of a gripper file: .yaml, .yml, .json)")
    assert isinstance(err.value, GraspGenError)


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"max_width": 0.0}, "max_width"),
        ({"min_width": -0.01}, "min_width"),
        ({"pad_size": (0.01, 0.02)}, "pad_size"),
        ({"pad_size": (0.01, -0.02, 0.03)}, "pad_size"),
        ({"pad_friction": (0.0, 0.005, 0.0001)}, "pad_friction"),
        ({"finger_size": (0.01, 0.03, 0.01)}, "finger_size"),
        ({"palm_boxes": ()}, "palm_boxes"),
        ({"tcp_offset": 0.0}, "tcp_offset"),
        ({"force_limit": -5.0}, "force_limit"),
        ({"finger_mass": 0.0}, "finger_mass"),
        ({"body_mass": float("nan")}, "body_mass"),
        ({"closing_speed": 0.0}, "closing_speed"),
        ({"pad_condim": 5}, "pad_condim"),
        ({"name": ""}, "name"),
    ],
)
def test_spec_validation_names_the_field(change, field):
    with pytest.raises(ValueError, match=field):
        dataclasses.replace(load_gripper("box_jaw"), **change)


def test_spec_is_frozen_and_normalised():
    spec = dataclasses.replace(load_gripper("box_jaw"), pad_size=[0.01, 0.03, 0.04], max_width=1)
    assert spec.pad_size == (0.01, 0.03, 0.04) and isinstance(spec.max_width, float)
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.max_width = 0.2  # type: ignore[misc]
    with pytest.raises(ValueError, match="Box.size"):
        Box(size=(0.1, 0.0, 0.1))


def test_physics_options_apply_to_spec_and_model():
    spec = mujoco.MjSpec()
    assert physics_options(spec) is spec
    assert spec.option.timestep == 0.002 and spec.option.impratio == 10.0
    assert spec.option.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    assert spec.option.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    model = mujoco.MjSpec().compile()
    physics_options(model, PhysicsOptions(timestep=0.001))
    assert model.opt.timestep == 0.001 and model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST and model.opt.impratio == 10.0
    with pytest.raises(ValueError, match="cone"):
        PhysicsOptions(cone="round")
    with pytest.raises(SettingsError, match="^target: must be an MjSpec or MjModel, got str"):
        physics_options("world.xml")


def test_model_builder_raises_settings_errors():
    spec = load_gripper("box_jaw")
    with pytest.raises(SettingsError, match="^spec: must be a GripperSpec, got dict"):
        build_gripper(spec.to_dict())
    with pytest.raises(SettingsError, match="^friction: must be one of object, pad, got 'rubber'"):
        build_gripper(spec, friction="rubber")
    with pytest.raises(SettingsError, match="^name_prefix: must be non-empty"):
        attach_gripper(mujoco.MjSpec(), spec, name_prefix="")


# ------------------------------------------------------------------------------------------------- model structure


@pytest.mark.parametrize("name", GRIPPER_NAMES)
def test_gripper_compiles_with_tcp_frame_at_origin(name):
    spec = load_gripper(name)
    model, data = _compile(build_gripper(spec))
    base = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "gripper/base")
    tcp_site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "gripper/tcp")
    np.testing.assert_allclose(data.xpos[base], 0.0, atol=1e-12)
    np.testing.assert_allclose(data.xmat[base].reshape(3, 3), np.eye(3), atol=1e-12)
    np.testing.assert_allclose(data.site_xpos[tcp_site], 0.0, atol=1e-12)
    np.testing.assert_allclose(gripper_pose(model, data), np.eye(4), atol=1e-12)
    assert gripper_width(model, data) == pytest.approx(spec.max_width, abs=1e-9)  # starts open
    # Weld: TCP body <-> mocap body, anchor at the origin, identity relative pose (not add_equality's default).
    weld = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, "gripper/weld")
    assert model.eq_type[weld] == mujoco.mjtEq.mjEQ_WELD
    np.testing.assert_allclose(model.eq_data[weld][:11], [0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 1])
    mocap = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "gripper/mocap")
    assert {model.eq_obj1id[weld], model.eq_obj2id[weld]} == {base, mocap} and model.body_mocapid[mocap] >= 0
    # Actuator: target width in metres, clipped to the stroke, force-limited at force_limit.
    act = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, "gripper/width")
    np.testing.assert_allclose(model.actuator_ctrlrange[act], [spec.min_width, spec.max_width])
    np.testing.assert_allclose(model.actuator_forcerange[act], [-spec.force_limit, spec.force_limit])
    # Geoms: named by role, gripper collision bits, one group.
    roles = gripper_geom_ids(model)
    assert len(roles["left_pad"]) == len(roles["right_pad"]) == 1
    links = 0 if spec.linkage is None else len(spec.linkage.driver_geoms) + len(spec.linkage.follower_geoms)
    assert len(roles["finger"]) == 2 * (max(1, len(spec.finger_geoms)) + links)
    assert len(roles["palm"]) == len(spec.palm_geoms or spec.palm_boxes)
    for gid in roles["all"]:
        assert model.geom_contype[gid] == GRIPPER_CONTYPE
        assert model.geom_conaffinity[gid] == GRIPPER_CONAFFINITY
        assert model.geom_group[gid] == GRIPPER_GEOM_GROUP
    for gid in roles["pad"]:
        assert model.geom_condim[gid] == spec.pad_condim
        if spec.pad_geom is None:
            np.testing.assert_allclose(model.geom_size[gid] * 2, spec.pad_size)
    # Hand base (flange / hand frame) behind the TCP: the palm reaches back to z = -tcp_offset (the Panda's hand
    # mesh 25.9 mm further, behind its hand frame; the 2F-85 housing's centring boss 2.74 mm behind its mounting face).
    palm_min_z = min(_geom_vertices(model, data, g)[:, 2].min() for g in roles["palm"])
    behind = {"panda": 0.0259248, "robotiq_2f85_mesh": 0.00274}.get(spec.name, 0.0)
    assert palm_min_z == pytest.approx(-spec.tcp_offset - behind, abs=1e-6)


@pytest.mark.parametrize("name", GRIPPER_NAMES)
def test_width_tracks_command_and_pads_stay_centred(name):
    spec = load_gripper(name)
    gspec = build_gripper(spec)
    gspec.option.gravity = [0.0, 0.0, 0.0]
    model, data = _compile(gspec)
    left, right = pad_geom_ids(model)
    widths = [spec.min_width, 0.2 * spec.max_width, 0.5 * spec.max_width, 0.8 * spec.max_width, spec.max_width]
    for width in widths:
        assert set_gripper_width(model, data, width) == pytest.approx(width)
        _settle(model, data, 1.0)
        assert gripper_width(model, data) == pytest.approx(width, abs=1e-3)
        pl, pr = data.geom_xpos[left[0]], data.geom_xpos[right[0]]
        np.testing.assert_allclose(((pl + pr) / 2.0)[:2], 0.0, atol=1e-3)  # pads symmetric about the TCP
        # The pads' contact faces are `width` apart along TCP x, midway around the TCP origin, and the pads are
        # centred on the TCP plane z = 0 (a mesh pad: its extent along z, whatever its centroid); with a linkage,
        # where its path puts them: the TCP plane halfway between their lowest and highest centre.
        left_face, right_face, z_lo, z_hi = _pad_faces(model, data)
        assert right_face - left_face == pytest.approx(width, abs=1e-3)
        assert (right_face + left_face) / 2.0 == pytest.approx(0.0, abs=1e-3)
        assert (z_lo + z_hi) / 2.0 == pytest.approx(_pad_centre_z(spec, width), abs=1e-3)
        assert abs((pr - pl)[2]) < 1e-6  # the left pad is the right one turned about z: same height
    assert data.ncon == 0  # closed to width 0 (pads touching) without self-contacts


@pytest.mark.parametrize("name", GRIPPER_NAMES)
def test_width_command_beyond_range_is_clipped(name):
    spec = load_gripper(name)
    gspec = build_gripper(spec)
    gspec.option.gravity = [0.0, 0.0, 0.0]
    model, data = _compile(gspec)
    act = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, "gripper/width")
    assert set_gripper_width(model, data, -0.05) == spec.min_width and data.ctrl[act] == spec.min_width
    _settle(model, data, 1.0)
    assert gripper_width(model, data) == pytest.approx(spec.min_width, abs=1e-3)
    data.ctrl[act] = spec.max_width + 0.05  # raw control beyond the range: MuJoCo's ctrlrange clamps it
    _settle(model, data, 1.0)
    assert gripper_width(model, data) == pytest.approx(spec.max_width, abs=1e-3)
    # instant=True puts the jaws there at once (used to open before placing the gripper).
    set_gripper_width(model, data, 10.0, instant=True)
    assert gripper_width(model, data) == pytest.approx(spec.max_width, abs=1e-9)


def test_attach_looks_everything_up_by_name():
    """Two grippers attached after a scene actuator: helpers find their own elements whatever the index order."""
    world = mujoco.MjSpec.from_string("""
    <mujoco>
      <worldbody>
        <body name="slider"><joint name="slide" type="slide"/><geom type="sphere" size="0.01" mass="0.1"/></body>
      </worldbody>
      <actuator><position name="scene_act" joint="slide" kp="10"/></actuator>
    </mujoco>""")
    physics_options(world, PhysicsOptions(gravity=(0.0, 0.0, 0.0)))
    attach_gripper(world, load_gripper("panda"), name_prefix="a/")
    attach_gripper(world, load_gripper("box_jaw"), name_prefix="b/")
    model, data = _compile(world)
    assert model.nu == 3 and model.nmocap == 2
    scene_act = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, "scene_act")
    set_gripper_width(model, data, 0.02, prefix="a/")
    set_gripper_width(model, data, 0.06, prefix="b/")
    assert data.ctrl[scene_act] == 0.0
    Ta, Tb = np.eye(4), np.eye(4)
    Ta[:3, 3], Tb[:3, 3] = [0.5, 0.0, 0.0], [-0.5, 0.0, 0.0]
    set_gripper_pose(model, data, Ta, prefix="a/")
    set_gripper_pose(model, data, Tb, prefix="b/")
    _settle(model, data, 1.0)
    assert gripper_width(model, data, prefix="a/") == pytest.approx(0.02, abs=1e-3)
    assert gripper_width(model, data, prefix="b/") == pytest.approx(0.06, abs=1e-3)
    np.testing.assert_allclose(gripper_pose(model, data, prefix="a/")[:3, 3], Ta[:3, 3], atol=1e-3)
    left_a, right_a = pad_geom_ids(model, prefix="a/")
    assert mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, left_a[0]) == "a/left_pad"
    assert mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, right_a[0]) == "a/right_pad"
    with pytest.raises(NotFoundError, match="no body named 'gripper/left_jaw'") as err:  # also a KeyError
        gripper_width(model, data, prefix="gripper/")
    assert isinstance(err.value, KeyError)
    with pytest.raises(NotFoundError, match="no gripper pads named c/left_pad"):
        gripper_geom_ids(model, prefix="c/")
    with pytest.raises(ValueError, match="name_prefix"):
        attach_gripper(world, load_gripper("panda"), name_prefix="")


# ------------------------------------------------------------------------------------------------- pose


@pytest.mark.parametrize("name", ["robotiq_2f85", "panda"])
def test_set_gripper_pose_puts_tcp_there(name):
    rng = np.random.default_rng(7)
    world = mujoco.MjSpec.from_string('<mujoco><worldbody><geom type="plane" size="2 2 0.1"/></worldbody></mujoco>')
    physics_options(world)
    attach_gripper(world, load_gripper(name))
    model, data = _compile(world)
    for _ in range(5):
        T = np.eye(4)
        T[:3, :3] = _random_rotation(rng)
        T[:3, 3] = rng.uniform([-0.5, -0.5, 0.6], [0.5, 0.5, 1.0])  # clear of the ground
        set_gripper_pose(model, data, T)
        for check in range(2):  # right after mj_forward, then after 50 steps under gravity (weld holds it)
            Tn = gripper_pose(model, data)
            assert np.linalg.norm(Tn[:3, 3] - T[:3, 3]) < 1e-3
            assert _rotation_angle_deg(Tn[:3, :3], T[:3, :3]) < 1.0
            site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "gripper/tcp")
            np.testing.assert_allclose(data.site_xpos[site], Tn[:3, 3], atol=1e-9)
            if check == 0:
                _settle(model, data, 0.1)
    with pytest.raises(ValueError):
        set_gripper_pose(model, data, np.diag([1.0, 1.0, -1.0, 1.0]))  # a reflection, not a rotation


# ------------------------------------------------------------------------------------------------- grasp physics


def test_2f85_grasps_and_lifts_a_box(capsys):
    model, data = _compile(_box_world(0.8))
    res = _grasp_and_lift(model, data)
    assert res["dz"] > 0.15, res
    assert res["slip"] < 1e-3, res  # the box hardly moves in the TCP frame during lift + hold
    bx, by, _ = res["box_in_tcp"]
    assert abs(bx) < 2e-3 and abs(by) < load_gripper("robotiq_2f85").pad_size[1] / 2, res  # between the pads
    assert res["width"] == pytest.approx(2 * BOX_HALF, abs=1.5e-3), res  # pads on the faces, barely penetrating
    assert _pad_contacts(model, data) == (True, True)
    with capsys.disabled():
        print(f"\n[grippers] 2F-85 grasp-and-lift scene (nv={model.nv}, ncon={data.ncon}): "
              f"{res['steps_per_s']:.0f} mj_step/s, {res['loop_steps_per_s']:.0f} steps/s with helpers; "
              f"TCP error at rest {res['tcp_error'] * 1e3:.2f} mm")


def test_low_friction_box_slips_out():
    model, data = _compile(_box_world(0.01))
    res = _grasp_and_lift(model, data)
    assert res["dz"] < 0.02, res


def test_pad_friction_mode_lets_the_pads_govern():
    model, data = _compile(_box_world(0.01, friction_mode="pad"))
    res = _grasp_and_lift(model, data)
    assert res["dz"] > 0.15, res


def test_default_physics_settings_let_a_heavy_box_creep():
    """MuJoCo's defaults (pyramidal cones, impratio 1) let a 2 kg box creep down between the pads; ours hold it."""
    ours = _grasp_and_lift(*_compile(_box_world(0.5, box_mass=2.0)))
    default = _grasp_and_lift(*_compile(_box_world(0.5, box_mass=2.0, options=PhysicsOptions(
        cone="pyramidal", impratio=1.0))))
    assert ours["slip"] < 1e-3, ours
    assert default["slip"] > 3e-3, default


def test_panda_mesh_grasps_and_lifts_a_box():
    model, data = _compile(_box_world(0.8, gripper="panda"))
    res = _grasp_and_lift(model, data)
    assert res["dz"] > 0.15, res
    assert res["slip"] < 1e-3, res
    assert res["width"] == pytest.approx(2 * BOX_HALF, abs=1.5e-3), res
    assert _pad_contacts(model, data) == (True, True)


# ------------------------------------------------------------------------------------------------- published figures


def _stl_parts() -> dict[str, np.ndarray]:
    """ACRONYM's Franka collision mesh split into hand and fingers: vertices in the TCP frame (hand z - 0.1034)."""
    parts = trimesh.load(PANDA_STL, force="mesh").split(only_watertight=False)
    pick = {"right": lambda p: p.bounds[0, 0] > 0.02, "left": lambda p: p.bounds[1, 0] < -0.02,
            "hand": lambda p: p.bounds[0, 0] < 0.0 < p.bounds[1, 0]}
    out = {}
    for name, test in pick.items():
        (part,) = [p for p in parts if test(p)]
        out[name] = part.vertices - [0.0, 0.0, 0.1034]
    return out


def test_panda_matches_acronyms_figures_and_mesh():
    """Panda: TCP 0.1034 m along z from the hand frame, 0-80 mm, pads centred on the TCP plane open and closed, and
    the compiled model's hand, fingers and pads are ACRONYM's collision mesh."""
    spec = load_gripper("panda")
    assert (spec.min_width, spec.max_width, spec.tcp_offset, spec.force_limit) == (0.0, 0.08, 0.1034, 70.0)
    assert spec.uses_meshes and spec.pad_size[1:] == (0.0174, 0.0176)
    gspec = build_gripper(spec)
    gspec.option.gravity = [0.0, 0.0, 0.0]
    model, data = _compile(gspec)
    roles = gripper_geom_ids(model)
    stl = _stl_parts()
    face = stl["right"][stl["right"][:, 0] < stl["right"][:, 0].min() + 5e-4]  # the fingertip's flat contact face
    assert abs((face[:, 2].min() + stl["right"][:, 2].max()) / 2) < 2e-4  # ACRONYM's TCP: midway along that face
    assert abs(face[:, 1].min() + face[:, 1].max()) / 2 < 1e-4  # and across it
    for width in (spec.max_width, spec.min_width):
        set_gripper_width(model, data, width, instant=True)
        left_face, right_face, z_lo, z_hi = _pad_faces(model, data)
        assert (left_face, right_face) == (pytest.approx(-width / 2, abs=1e-9), pytest.approx(width / 2, abs=1e-9))
        assert gripper_width(model, data) == pytest.approx(width, abs=1e-9)
        # The pads are the fingertips from where the flat face begins to the tip: centred on the TCP plane.
        assert (z_lo, z_hi) == (pytest.approx(face[:, 2].min(), abs=1e-6), pytest.approx(stl["right"][:, 2].max(),
                                                                                          abs=1e-6))
        assert abs(z_lo + z_hi) / 2 < 2e-4
        shift = np.array([width / 2 - face[:, 0].min(), 0.0, 0.0])  # the fingers slide; 0.13 mm face alignment
        for side, sign, pad in (("right", 1.0, roles["right_pad"][0]), ("left", -1.0, roles["left_pad"][0])):
            jaw = np.vstack([_in_tcp(model, data, _geom_vertices(model, data, g))
                             for g in (pad, *[f for f in roles["finger"] if model.geom_bodyid[f]
                                              == model.geom_bodyid[pad]])])
            expect = stl[side] + sign * shift
            np.testing.assert_allclose(jaw.min(axis=0), expect.min(axis=0), atol=1e-6)
            np.testing.assert_allclose(jaw.max(axis=0), expect.max(axis=0), atol=1e-6)
            # The pad's contact face (its vertices on the face plane) is the fingertip's face, centred on the TCP.
            pad_v = _in_tcp(model, data, _geom_vertices(model, data, pad))
            on_face = pad_v[np.abs(pad_v[:, 0] - sign * width / 2) < 5e-4]
            stl_face = expect[np.abs(expect[:, 0] - sign * width / 2) < 5e-4]
            centre = (on_face.min(axis=0) + on_face.max(axis=0)) / 2
            np.testing.assert_allclose(centre[1:], (stl_face.min(axis=0) + stl_face.max(axis=0))[1:] / 2, atol=1e-6)
            np.testing.assert_allclose(centre, [sign * width / 2, 0.0, 0.0], atol=2e-4)
            assert sign * _in_tcp(model, data, data.geom_xpos[pad][None])[0, 0] > width / 2  # pad behind its face
    palm = np.vstack([_in_tcp(model, data, _geom_vertices(model, data, g)) for g in roles["palm"]])
    np.testing.assert_allclose(palm.min(axis=0), stl["hand"].min(axis=0), atol=1e-6)
    np.testing.assert_allclose(palm.max(axis=0), stl["hand"].max(axis=0), atol=1e-6)
    assert trimesh.convex.convex_hull(palm).volume == pytest.approx(trimesh.convex.convex_hull(stl["hand"]).volume,
                                                                     rel=1e-4)


def test_2f85_and_box_jaw_figures():
    f85 = load_gripper("robotiq_2f85")
    assert (f85.min_width, f85.max_width, f85.tcp_offset) == (0.0, 0.085, 0.14)  # data sheet stroke, flange->pads
    assert f85.pad_size == (0.008, 0.022, 0.0375) and not f85.uses_meshes
    jaw = load_gripper("box_jaw")
    assert (jaw.max_width, jaw.tcp_offset, jaw.pad_size) == (0.1, 0.1, (0.01, 0.03, 0.04))
    for spec in (f85, jaw):
        model, data = _compile(build_gripper(spec))
        for width in (spec.max_width, spec.min_width):
            set_gripper_width(model, data, width, instant=True)
            left_face, right_face, z_lo, z_hi = _pad_faces(model, data)
            assert (left_face, right_face, z_lo, z_hi) == pytest.approx(
                (-width / 2, width / 2, -spec.pad_size[2] / 2, spec.pad_size[2] / 2), abs=1e-9)


# ------------------------------------------------------------------------------------------------- gripper files


ROBOTIQ_DIR = REPO / "assets" / "grippers" / "robotiq_2f85"


def _urdf_joints() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The vendored 2F-85 URDF's joints: name -> (origin xyz, rpy)."""
    import xml.etree.ElementTree as ET

    text = (ROBOTIQ_DIR / "airo" / "robotiq_2f_85.urdf").read_text().replace("drake:", "drake_")  # no xmlns
    root = ET.fromstring(text)
    return {j.get("name"): (np.array(j.find("origin").get("xyz").split(), dtype=float),
                            np.array(j.find("origin").get("rpy", "0 0 0").split(), dtype=float))
            for j in root.iter("joint") if j.find("origin") is not None}


def _urdf_right_finger(theta: float) -> dict[str, np.ndarray]:
    """The right finger's parts at outer-knuckle angle ``theta`` by the URDF's chain (the knuckles turn by theta, the
    inner finger's joint by -theta: its mimic), hand-base frame (base_link: I turned -90 deg about z, y -> x)."""
    j = _urdf_joints()

    def rot(t):
        c, s = np.cos(t), np.sin(t)
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])

    def mesh(name):
        return trimesh.load(ROBOTIQ_DIR / "airo" / name, force="mesh").vertices * 0.001

    R = rot(theta)
    knuckle = j["right_outer_knuckle_joint"][0]
    outer = knuckle + j["right_outer_finger_joint"][0] @ R.T
    inner = outer + j["right_inner_finger_joint"][0] @ R.T  # then turned back by -theta: orientation as at 0
    parts = {
        "driver": np.vstack([knuckle + mesh("robotiq_arg2f_85_outer_knuckle.obj") @ R.T,
                             outer + mesh("robotiq_arg2f_85_outer_finger.obj") @ R.T]),
        "follower": j["right_inner_knuckle_joint"][0] + mesh("robotiq_arg2f_85_inner_knuckle.obj") @ R.T,
        "finger": inner + mesh("robotiq_arg2f_85_inner_finger.obj"),
        "pad": (inner + j["right_inner_finger_pad_joint"][0])[None],
    }
    return {k: np.stack([v[:, 1], -v[:, 0], v[:, 2]], axis=1) for k, v in parts.items()}


def test_2f85_mesh_matches_the_urdf_and_data_sheet():
    """robotiq_2f85_mesh: the data sheet's stroke (0-85 mm), force range, speed and mass; the URDF's pad box and
    joint frames; and at every width the compiled model's links, finger and pad are where the URDF's chain puts them
    (knuckle angle from the pad face's x), the pads parallel, rising 13.7 mm towards the object as they close."""
    from scipy.spatial import cKDTree

    spec = load_gripper("robotiq_2f85_mesh")
    assert (spec.min_width, spec.max_width) == (0.0, 0.085)  # data sheet: stroke 85 mm
    assert 20.0 <= spec.force_limit <= 235.0 and 0.02 <= spec.closing_speed <= 0.15  # N, m/s (data sheet)
    link = spec.linkage
    mass = spec.body_mass + 2 * (spec.finger_mass + link.driver_mass + link.follower_mass)
    assert mass == pytest.approx(0.925, abs=1e-6)  # data sheet: 0.925 kg
    j = _urdf_joints()
    tcp = spec.tcp_offset
    assert link.pivot == pytest.approx((j["right_outer_knuckle_joint"][0][1], j["right_outer_knuckle_joint"][0][2]
                                        - tcp), abs=1e-9)
    assert link.follower_pivot == pytest.approx((j["right_inner_knuckle_joint"][0][1],
                                                 j["right_inner_knuckle_joint"][0][2] - tcp), abs=1e-9)
    crank0 = j["right_outer_finger_joint"][0] + j["right_inner_finger_joint"][0]  # at the URDF's zero
    assert link.radius == pytest.approx(np.hypot(crank0[1], crank0[2]), abs=1e-6)
    pad_box = Box(size=(0.00635, 0.022, 0.0375))  # the URDF's pad box, thickness first
    assert spec.pad_geom.size == pad_box.size
    gspec = build_gripper(spec)
    gspec.option.gravity = [0.0, 0.0, 0.0]
    model, data = _compile(gspec)
    roles = gripper_geom_ids(model)
    right_pad = roles["right_pad"][0]
    body_of = {name: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"gripper/right_{name}")
               for name in ("driver", "follower", "jaw")}
    centres = []
    for width in np.linspace(spec.max_width, spec.min_width, 6):
        set_gripper_width(model, data, width, instant=True)
        theta = link.angle((width - spec.max_width) / 2.0) + np.arctan2(link.crank[1], link.crank[0]) - np.arctan2(
            crank0[2], crank0[1])  # the URDF's knuckle angle
        urdf = {k: v - [0.0, 0.0, tcp] for k, v in _urdf_right_finger(float(theta)).items()}
        assert urdf["pad"][0, 0] - pad_box.size[0] / 2 == pytest.approx(width / 2, abs=1e-6)  # face at width / 2
        for name, body in body_of.items():
            geoms = [g for g in roles["finger"] if model.geom_bodyid[g] == body]
            ours = np.vstack([_in_tcp(model, data, _geom_vertices(model, data, g)) for g in geoms])
            expect = urdf["finger" if name == "jaw" else name]
            np.testing.assert_allclose(ours.min(axis=0), expect.min(axis=0), atol=1e-4)  # quartic fit < 0.1 mm
            np.testing.assert_allclose(ours.max(axis=0), expect.max(axis=0), atol=1e-4)
            # every vertex of our pieces (their hulls' vertices) is a vertex of the URDF's meshes, posed
            assert len(ours) >= 4 and cKDTree(expect).query(ours)[0].max() < 1e-4
        pad = _in_tcp(model, data, data.geom_xpos[right_pad][None])[0]
        np.testing.assert_allclose(pad, urdf["pad"][0], atol=1e-4)
        np.testing.assert_allclose(data.geom_xmat[right_pad].reshape(3, 3), np.eye(3), atol=1e-9)  # parallel
        centres.append(pad[2])
    assert theta == pytest.approx(0.81, abs=0.01)  # closed: the URDF's knuckle limit (0.8 left, 0.81 right)
    # The pads move towards the object as the fingers close (Robotiq: the fingertips' "vertical motion"), 13.7 mm
    # over the stroke; the TCP plane lies halfway along that travel, and the contact length the sampler uses is the
    # part of the 37.5 mm pads that faces it at every width.
    rise = max(centres) - centres[0]
    assert rise == pytest.approx(0.0137, abs=2e-4) and centres[-1] > centres[0]
    assert (max(centres) + min(centres)) / 2 == pytest.approx(0.0, abs=1e-4)
    assert spec.pad_size[1:] == pytest.approx((0.022, 0.0375 - rise), abs=2e-4)
    fine = np.linspace(spec.min_width, spec.max_width, 200)
    assert float(np.ptp(spec.pad_rise(fine))) == pytest.approx(rise, abs=1e-4)


def test_linkage_couplings_pose_the_links_as_the_simulation_does():
    """Setting only the jaw slides and applying the couplings (what the pre-filter and the rollouts do) puts every
    linkage joint where the simulated gripper puts it; a gripper without a linkage has none."""
    assert len(linkage_couplings(_compile(build_gripper(load_gripper("robotiq_2f85")))[0]).qposadr) == 0
    gspec = build_gripper(load_gripper("robotiq_2f85_mesh"))
    gspec.option.gravity = [0.0, 0.0, 0.0]
    model, data = _compile(gspec)
    couplings = linkage_couplings(model)
    assert len(couplings.qposadr) == 6  # per side: the pad's lift, the driver and the follower
    for width in (0.0, 0.03, 0.07):
        set_gripper_width(model, data, width)
        _settle(model, data, 1.0)
        qpos = data.qpos.copy()
        qpos[couplings.qposadr] = 0.0
        couplings.apply(qpos)
        np.testing.assert_allclose(qpos, data.qpos, atol=2e-5)


def test_2f85_mesh_grasps_and_lifts_a_box():
    """The mesh 2F-85 lifts a 5 cm, 1 kg box (friction 0.8) with both pads; its inner knuckles reach the cube's top
    edges at 50 mm (real geometry), which push it ~1.5 mm towards the fingertips while it is held."""
    model, data = _compile(_box_world(0.8, gripper="robotiq_2f85_mesh"))
    res = _grasp_and_lift(model, data)
    assert res["dz"] > 0.15, res
    assert res["slip"] < 3e-3, res
    assert res["width"] == pytest.approx(2 * BOX_HALF, abs=1.5e-3), res
    assert _pad_contacts(model, data) == (True, True)
    low = _grasp_and_lift(*_compile(_box_world(0.01, gripper="robotiq_2f85_mesh")))
    assert low["dz"] < 0.02, low


def test_robotiq_pieces_are_up_to_date(tmp_path):
    """assets/make_grippers.py makes the committed 2F-85 pieces byte for byte from the vendored airo-models meshes."""
    spec = importlib.util.spec_from_file_location("make_grippers", REPO / "assets" / "make_grippers.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.robotiq(tmp_path)
    for name in ("palm.obj", "driver.obj", "follower.obj", "finger.obj"):
        assert (tmp_path / name).read_bytes() == (ROBOTIQ_DIR / name).read_bytes(), name


def test_linkage_in_a_user_file_round_trips_and_is_checked(tmp_path):
    spec = load_gripper("robotiq_2f85_mesh")
    path = write_gripper(spec, tmp_path / "mine.yaml")
    again = read_gripper(path)
    assert again == spec and again.linkage == spec.linkage
    data = json.loads(json.dumps(spec.to_dict()))
    data["linkage"]["crank"] = [0.001, 0.02]  # too short a reach to close the pads
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(SettingsError, match=r"bad.json: linkage.crank: must reach the closed pads"):
        read_gripper(tmp_path / "bad.json")
    data["linkage"] = {"pivot": [0.0, 0.0], "crank": [0.03, 0.04], "follower_pivot": [0.0, 0.0], "hinge": 1}
    (tmp_path / "bad2.json").write_text(json.dumps(data))
    with pytest.raises(SettingsError, match=r"linkage.hinge: unknown key"):
        read_gripper(tmp_path / "bad2.json")


def test_bundled_gripper_files_match_their_digests():
    """The bundled gripper files count as code (their digests are in grippers.py): editing one must change it."""
    files = sorted(p for p in GRIPPERS_DIR.rglob("*") if p.suffix in (".yaml", ".obj"))
    found = {str(p.relative_to(GRIPPERS_DIR)): hashlib.sha256(p.read_bytes()).hexdigest()[:16] for p in files}
    assert found == BUNDLED_DIGESTS, "update BUNDLED_DIGESTS in graspgen/grippers/bundled.py"
    for name in GRIPPERS:
        assert gripper_files(name) == ()  # covered by the code fingerprint instead


def test_panda_pieces_are_up_to_date(tmp_path):
    """assets/make_grippers.py makes the committed convex pieces byte for byte from the vendored mesh."""
    spec = importlib.util.spec_from_file_location("make_grippers", REPO / "assets" / "make_grippers.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.panda(tmp_path)
    for name in ("hand.obj", "finger.obj", "pad.obj"):
        assert (tmp_path / name).read_bytes() == (GRIPPERS_DIR / "panda" / name).read_bytes(), name


def _finger_obj(path: Path, x0: float, thickness: float, z0: float, z1: float) -> None:
    box = trimesh.creation.box(extents=(thickness, 0.02, z1 - z0))
    box.apply_translation((x0 + thickness / 2, 0.0, (z0 + z1) / 2))
    box.export(path)


def _user_file(folder: Path, **change) -> Path:
    """A user's gripper: boxes for the palm, an OBJ finger link and pad, hand-base frame, 60 mm stroke."""
    _finger_obj(folder / "link.obj", 0.035, 0.01, 0.02, 0.09)  # hand frame: the link from z 0.02 to 0.09
    _finger_obj(folder / "pad.obj", 0.03, 0.005, 0.09, 0.11)  # pad face at x = 0.03, z 0.09..0.11 (TCP at 0.1)
    data = {
        "name": "my_hand", "frame": "base", "max_width": 0.06, "tcp_offset": 0.1, "force_limit": 40.0,
        "closing_speed": 0.05, "finger_mass": 0.02, "body_mass": 0.3, "source": "a test hand",
        "palm_geoms": [{"size": [0.12, 0.04, 0.02], "pos": [0.0, 0.0, 0.01]}],
        "finger_geoms": [{"mesh": "link.obj"}], "pad_geom": {"mesh": "pad.obj"},
    }
    data.update(change)
    path = folder / "my_hand.yaml"
    path.write_text(json.dumps(data))  # JSON is YAML
    return path


def test_user_gripper_file_round_trip(tmp_path):
    path = _user_file(tmp_path)
    spec = load_gripper(str(path))
    assert spec.name == "my_hand" and spec.file == str(path) and spec.min_width == 0.0
    assert spec.pad_size == pytest.approx((0.005, 0.02, 0.02))  # the pad's extents
    assert spec.finger_size == pytest.approx((0.015, 0.02, 0.09))  # link and pad together
    (palm,) = spec.palm_boxes  # the palm pieces' bounding box, moved from the base frame to the TCP frame
    assert palm.size == pytest.approx((0.12, 0.04, 0.02)) and palm.pos == pytest.approx((0.0, 0.0, -0.09))
    assert load_gripper(path) is spec  # cached while unchanged; a Path works too
    assert gripper_files(str(path)) == (str(path), str(tmp_path / "link.obj"), str(tmp_path / "pad.obj"))
    model, data = _compile(build_gripper(spec))
    roles = gripper_geom_ids(model)
    assert len(roles["pad"]) == 2 and len(roles["finger"]) == 2 and len(roles["palm"]) == 1
    for width in (0.06, 0.0):
        set_gripper_width(model, data, width, instant=True)
        assert _pad_faces(model, data) == pytest.approx((-width / 2, width / 2, -0.01, 0.01), abs=1e-9)
    for suffix in (".yaml", ".json"):
        again = read_gripper(write_gripper(spec, tmp_path / f"copy{suffix}"))
        assert again == spec and again.file == str(tmp_path / f"copy{suffix}")
    panda = load_gripper("panda")
    assert read_gripper(write_gripper(panda, tmp_path / "panda.yaml")) == panda
    # The grasps stage takes a path; its gripper column then holds the path.
    from graspgen.workflows.scene_grasps import GraspsParams

    assert GraspsParams(gripper=str(path)).gripper == str(path)


@pytest.mark.parametrize(
    ("write", "message"),
    [
        (None, "no such gripper file; bundled grippers: box_jaw, panda, robotiq_2f85"),
        ("name: [unclosed\n", "not valid YAML"),
        ("- 1\n- 2\n", "must be a mapping of gripper settings"),
        ({"max_widht": 0.1}, "max_widht: unknown key; valid keys: body_mass, closing_speed,"),
        ({"force_limit": None}, "force_limit: missing (a gripper file needs force_limit)"),
        ({"force_limit": -1}, "force_limit: must be in (0, inf), got -1"),
        ({"pad_size": [0.01]}, "pad_size: must be 3 finite numbers"),
        ({"finger_geoms": [{"mesh": "nope.obj"}]}, "finger_geoms[0]: mesh: mesh file"),
        ({"finger_geoms": [{"mesh": "l.obj"}]}, "is not convex (its hull is"),
        ({"pad_geom": {"size": [0.01, 0.02, 0.02], "pos": [0.03, 0.0, 0.1]}}, "pad_geom: must have its contact face"),
        ({"frame": "world"}, "frame: must be one of tcp, base"),
        ({"palm_geoms": [{"size": [0.1, 0.1, 0.1], "colour": "red"}]}, "palm_geoms[0]: unknown key 'colour'"),
    ],
)
def test_bad_gripper_files_give_one_line_naming_the_file(tmp_path, write, message):
    path = _user_file(tmp_path)
    if isinstance(write, dict):
        data = json.loads(path.read_text())
        data.update(write)
        data = {k: v for k, v in data.items() if v is not None}
        path.write_text(json.dumps(data))
    elif isinstance(write, str):
        path.write_text(write)
    else:
        path = tmp_path / "missing.yaml"
    _l_shape().export(tmp_path / "l.obj")
    with pytest.raises(SettingsError) as err:
        load_gripper(str(path))
    text = str(err.value)
    assert text.startswith(f"gripper: {path}: ") and message in text and "\n" not in text, text
    with pytest.raises(ValueError, match="gripper: "):  # the config's grasps.gripper
        from graspgen.workflows.scene_grasps import GraspsParams

        GraspsParams(gripper=str(path))


def _l_shape() -> trimesh.Trimesh:
    """A watertight L-shaped prism (not convex: its hull is ~60 % larger)."""
    outline = np.array([[0, 0], [0.04, 0], [0.04, 0.01], [0.01, 0.01], [0.01, 0.04], [0, 0.04]], dtype=float)
    n = len(outline)
    vertices = np.vstack([np.c_[outline[:, 0] + 0.035, np.full(n, -0.01), outline[:, 1] + 0.02],
                          np.c_[outline[:, 0] + 0.035, np.full(n, 0.01), outline[:, 1] + 0.02]])
    faces = [[0, k + 1, k] for k in range(1, n - 1)] + [[n, n + k, n + k + 1] for k in range(1, n - 1)]
    for k in range(n):
        j = (k + 1) % n
        faces += [[k, j, n + j], [k, n + j, n + k]]
    mesh = trimesh.Trimesh(vertices, faces, process=True)
    mesh.fix_normals()
    return mesh


def test_not_a_gripper_file_or_name():
    with pytest.raises(SettingsError, match=r"^gripper: hand\.txt: not a gripper file \(expected \.yaml"):
        load_gripper(Path("hand.txt"))
    with pytest.raises(SettingsError, match="unknown 'pandas'; choose one of: box_jaw, panda, robotiq_2f85"):
        load_gripper("pandas")


# ------------------------------------------------------------------------------------------------- picture


def test_gripper_picture_and_show_command(tmp_path):
    from typer.testing import CliRunner

    from graspgen_cli.app import app

    spec = load_gripper(str(_user_file(tmp_path)))
    image = gripper_picture(spec, size=200, render=False)
    assert image.size == (400, 58 + 2 * (200 + 20))
    out = tmp_path / "g.png"
    result = CliRunner().invoke(app, ["show", "gripper", str(tmp_path / "my_hand.yaml"), "-o", str(out), "--wireframe"])
    assert result.exit_code == 0, result.output
    assert out.is_file() and str(out) in result.output
    bad = CliRunner().invoke(app, ["show", "gripper", "pandas"])
    assert bad.exit_code == 2 and "choose one of: box_jaw, panda, robotiq_2f85" in " ".join(bad.output.split())
