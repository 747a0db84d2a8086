"""Tests of stages/grippers.py: gripper data, the MjSpec builder, attach, helpers and grasp-and-lift physics."""

from __future__ import annotations

import dataclasses
import time

import mujoco
import numpy as np
import pytest

from graspgen.errors import GraspGenError, SettingsError
from graspgen.sim import grippers as G

GRIPPER_NAMES = sorted(G.GRIPPERS)
BOX_HALF = 0.025  # 5 cm box


@pytest.fixture(autouse=True)
def _no_log_in_repo(tmp_path, monkeypatch):
    """MuJoCo writes MUJOCO_LOG.TXT into the cwd on errors; keep it out of the repository."""
    monkeypatch.chdir(tmp_path)


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
               friction_mode: str = "object", options: G.PhysicsOptions | None = None) -> mujoco.MjSpec:
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
    G.physics_options(world, options)
    G.attach_gripper(world, G.load_gripper(gripper), friction=friction_mode)
    return world


def _grasp_and_lift(model, data, *, lift: float = 0.2, lift_time: float = 1.0) -> dict:
    """Top-down grasp of the box: TCP at the box centre, z (approach) pointing down; open, close, lift, hold."""
    box = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "box")
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # x closing along world x, z approach along world -z
    T[:3, 3] = [0.0, 0.0, BOX_HALF]
    G.set_gripper_width(model, data, G.load_gripper("robotiq_2f85").max_width, instant=True)
    G.set_gripper_pose(model, data, T)
    z0 = float(data.xpos[box][2])
    n_steps, step_time = 0, 0.0

    def step():
        nonlocal n_steps, step_time
        t = time.perf_counter()
        mujoco.mj_step(model, data)
        step_time += time.perf_counter() - t
        n_steps += 1

    t0 = time.perf_counter()
    G.set_gripper_width(model, data, 0.0)  # close: force saturates at force_limit on the box
    for _ in range(400):  # 0.8 s: closing 85 -> 50 mm at 0.15 m/s takes ~0.25 s
        step()
    steps = int(round(lift_time / model.opt.timestep))
    rel_before = np.linalg.inv(G.gripper_pose(model, data)) @ np.append(data.xpos[box], 1.0)
    for i in range(steps):
        Ti = T.copy()
        Ti[2, 3] += lift * (i + 1) / steps
        G.set_gripper_target(model, data, Ti)
        step()
    for _ in range(250):  # hold 0.5 s
        step()
    elapsed = time.perf_counter() - t0
    T_now = G.gripper_pose(model, data)
    rel_after = np.linalg.inv(T_now) @ np.append(data.xpos[box], 1.0)
    return {
        "dz": float(data.xpos[box][2]) - z0,
        "box_in_tcp": rel_after[:3],
        "slip": float(np.linalg.norm(rel_after[:3] - rel_before[:3])),
        "width": G.gripper_width(model, data),
        "loop_steps_per_s": n_steps / elapsed,  # with the Python helpers moving the target each step
        "steps_per_s": n_steps / step_time,  # mj_step alone
        "tcp_error": float(np.linalg.norm(T_now[:3, 3] - Ti[:3, 3])),
    }


def _pad_contacts(model, data) -> tuple[bool, bool]:
    left, right = G.pad_geom_ids(model)
    box_geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "box")
    touching = {g for c in data.contact[: data.ncon] for g in (c.geom1, c.geom2)
                if box_geom in (c.geom1, c.geom2)}
    return bool(touching & set(left)), bool(touching & set(right))


# ------------------------------------------------------------------------------------------------- data & registry


def test_registry_holds_the_three_grippers():
    assert set(G.GRIPPERS) == {"robotiq_2f85", "panda", "box_jaw"}
    assert G.DEFAULT_GRIPPER == "robotiq_2f85"
    f85 = G.load_gripper("robotiq_2f85")
    assert (f85.min_width, f85.max_width) == (0.0, 0.085)
    assert 20.0 <= f85.force_limit <= 235.0  # Robotiq 2F-85 data sheet grip force range
    assert 0.13 <= f85.tcp_offset <= 0.15
    assert f85.pad_size[1] == pytest.approx(0.022)
    panda = G.load_gripper("panda")
    assert (panda.max_width, panda.tcp_offset, panda.force_limit) == (0.08, 0.1034, 70.0)
    assert G.load_gripper("box_jaw").max_width == 0.1
    for spec in G.GRIPPERS.values():
        assert G.GRIPPERS[spec.name] is spec
        assert spec.to_dict()["name"] == spec.name


def test_unknown_gripper_raises_settings_error_listing_choices():
    with pytest.raises(SettingsError) as err:
        G.load_gripper("x")
    assert str(err.value) == "gripper: unknown 'x'; choose one of: box_jaw, panda, robotiq_2f85"
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
        dataclasses.replace(G.load_gripper("box_jaw"), **change)


def test_spec_is_frozen_and_normalised():
    spec = dataclasses.replace(G.load_gripper("box_jaw"), pad_size=[0.01, 0.03, 0.04], max_width=1)
    assert spec.pad_size == (0.01, 0.03, 0.04) and isinstance(spec.max_width, float)
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.max_width = 0.2  # type: ignore[misc]
    with pytest.raises(ValueError, match="Box.size"):
        G.Box(size=(0.1, 0.0, 0.1))


def test_physics_options_apply_to_spec_and_model():
    spec = mujoco.MjSpec()
    assert G.physics_options(spec) is spec
    assert spec.option.timestep == 0.002 and spec.option.impratio == 10.0
    assert spec.option.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    assert spec.option.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    model = mujoco.MjSpec().compile()
    G.physics_options(model, G.PhysicsOptions(timestep=0.001))
    assert model.opt.timestep == 0.001 and model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST and model.opt.impratio == 10.0
    with pytest.raises(ValueError, match="cone"):
        G.PhysicsOptions(cone="round")


# ------------------------------------------------------------------------------------------------- model structure


@pytest.mark.parametrize("name", GRIPPER_NAMES)
def test_gripper_compiles_with_tcp_frame_at_origin(name):
    spec = G.load_gripper(name)
    model, data = _compile(G.build_gripper(spec))
    base = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "gripper/base")
    tcp_site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "gripper/tcp")
    np.testing.assert_allclose(data.xpos[base], 0.0, atol=1e-12)
    np.testing.assert_allclose(data.xmat[base].reshape(3, 3), np.eye(3), atol=1e-12)
    np.testing.assert_allclose(data.site_xpos[tcp_site], 0.0, atol=1e-12)
    np.testing.assert_allclose(G.gripper_pose(model, data), np.eye(4), atol=1e-12)
    assert G.gripper_width(model, data) == pytest.approx(spec.max_width, abs=1e-9)  # starts open
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
    roles = G.gripper_geom_ids(model)
    assert len(roles["left_pad"]) == len(roles["right_pad"]) == 1
    assert len(roles["finger"]) == 2 and len(roles["palm"]) == len(spec.palm_boxes)
    for gid in roles["all"]:
        assert model.geom_contype[gid] == G.GRIPPER_CONTYPE
        assert model.geom_conaffinity[gid] == G.GRIPPER_CONAFFINITY
        assert model.geom_group[gid] == G.GRIPPER_GEOM_GROUP
    for gid in roles["pad"]:
        assert model.geom_condim[gid] == spec.pad_condim
        np.testing.assert_allclose(model.geom_size[gid] * 2, spec.pad_size)
    # Hand base (flange) behind the TCP: the palm reaches back to z = -tcp_offset.
    palm_min_z = min(model.geom_pos[g][2] - model.geom_size[g][2] for g in roles["palm"])
    assert palm_min_z == pytest.approx(-spec.tcp_offset, abs=1e-9)


@pytest.mark.parametrize("name", GRIPPER_NAMES)
def test_width_tracks_command_and_pads_stay_centred(name):
    spec = G.load_gripper(name)
    gspec = G.build_gripper(spec)
    gspec.option.gravity = [0.0, 0.0, 0.0]
    model, data = _compile(gspec)
    left, right = G.pad_geom_ids(model)
    widths = [spec.min_width, 0.2 * spec.max_width, 0.5 * spec.max_width, 0.8 * spec.max_width, spec.max_width]
    for width in widths:
        assert G.set_gripper_width(model, data, width) == pytest.approx(width)
        _settle(model, data, 1.0)
        assert G.gripper_width(model, data) == pytest.approx(width, abs=1e-3)
        pl, pr = data.geom_xpos[left[0]], data.geom_xpos[right[0]]
        np.testing.assert_allclose((pl + pr) / 2.0, 0.0, atol=1e-3)  # midpoint of the pad centres = TCP origin
        # The pads face each other along TCP x: centre separation = width + pad thickness, no y/z offset.
        assert pr[0] - pl[0] == pytest.approx(width + spec.pad_size[0], abs=1e-3)
        np.testing.assert_allclose((pr - pl)[1:], 0.0, atol=1e-6)
    assert data.ncon == 0  # closed to width 0 (pads touching) without self-contacts


@pytest.mark.parametrize("name", GRIPPER_NAMES)
def test_width_command_beyond_range_is_clipped(name):
    spec = G.load_gripper(name)
    gspec = G.build_gripper(spec)
    gspec.option.gravity = [0.0, 0.0, 0.0]
    model, data = _compile(gspec)
    act = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, "gripper/width")
    assert G.set_gripper_width(model, data, -0.05) == spec.min_width and data.ctrl[act] == spec.min_width
    _settle(model, data, 1.0)
    assert G.gripper_width(model, data) == pytest.approx(spec.min_width, abs=1e-3)
    data.ctrl[act] = spec.max_width + 0.05  # raw control beyond the range: MuJoCo's ctrlrange clamps it
    _settle(model, data, 1.0)
    assert G.gripper_width(model, data) == pytest.approx(spec.max_width, abs=1e-3)
    # instant=True puts the jaws there at once (used to open before placing the gripper).
    G.set_gripper_width(model, data, 10.0, instant=True)
    assert G.gripper_width(model, data) == pytest.approx(spec.max_width, abs=1e-9)


def test_attach_looks_everything_up_by_name():
    """Two grippers attached after a scene actuator: helpers find their own elements whatever the index order."""
    world = mujoco.MjSpec.from_string("""
    <mujoco>
      <worldbody>
        <body name="slider"><joint name="slide" type="slide"/><geom type="sphere" size="0.01" mass="0.1"/></body>
      </worldbody>
      <actuator><position name="scene_act" joint="slide" kp="10"/></actuator>
    </mujoco>""")
    G.physics_options(world, G.PhysicsOptions(gravity=(0.0, 0.0, 0.0)))
    G.attach_gripper(world, G.load_gripper("panda"), name_prefix="a/")
    G.attach_gripper(world, G.load_gripper("box_jaw"), name_prefix="b/")
    model, data = _compile(world)
    assert model.nu == 3 and model.nmocap == 2
    scene_act = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, "scene_act")
    G.set_gripper_width(model, data, 0.02, prefix="a/")
    G.set_gripper_width(model, data, 0.06, prefix="b/")
    assert data.ctrl[scene_act] == 0.0
    Ta, Tb = np.eye(4), np.eye(4)
    Ta[:3, 3], Tb[:3, 3] = [0.5, 0.0, 0.0], [-0.5, 0.0, 0.0]
    G.set_gripper_pose(model, data, Ta, prefix="a/")
    G.set_gripper_pose(model, data, Tb, prefix="b/")
    _settle(model, data, 1.0)
    assert G.gripper_width(model, data, prefix="a/") == pytest.approx(0.02, abs=1e-3)
    assert G.gripper_width(model, data, prefix="b/") == pytest.approx(0.06, abs=1e-3)
    np.testing.assert_allclose(G.gripper_pose(model, data, prefix="a/")[:3, 3], Ta[:3, 3], atol=1e-3)
    left_a, right_a = G.pad_geom_ids(model, prefix="a/")
    assert mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, left_a[0]) == "a/left_pad"
    assert mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, right_a[0]) == "a/right_pad"
    with pytest.raises(KeyError):
        G.gripper_width(model, data, prefix="gripper/")
    with pytest.raises(ValueError, match="name_prefix"):
        G.attach_gripper(world, G.load_gripper("panda"), name_prefix="")


# ------------------------------------------------------------------------------------------------- pose


@pytest.mark.parametrize("name", ["robotiq_2f85", "panda"])
def test_set_gripper_pose_puts_tcp_there(name):
    rng = np.random.default_rng(7)
    world = mujoco.MjSpec.from_string('<mujoco><worldbody><geom type="plane" size="2 2 0.1"/></worldbody></mujoco>')
    G.physics_options(world)
    G.attach_gripper(world, G.load_gripper(name))
    model, data = _compile(world)
    for _ in range(5):
        T = np.eye(4)
        T[:3, :3] = _random_rotation(rng)
        T[:3, 3] = rng.uniform([-0.5, -0.5, 0.6], [0.5, 0.5, 1.0])  # clear of the ground
        G.set_gripper_pose(model, data, T)
        for check in range(2):  # right after mj_forward, then after 50 steps under gravity (weld holds it)
            Tn = G.gripper_pose(model, data)
            assert np.linalg.norm(Tn[:3, 3] - T[:3, 3]) < 1e-3
            assert _rotation_angle_deg(Tn[:3, :3], T[:3, :3]) < 1.0
            site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "gripper/tcp")
            np.testing.assert_allclose(data.site_xpos[site], Tn[:3, 3], atol=1e-9)
            if check == 0:
                _settle(model, data, 0.1)
    with pytest.raises(ValueError):
        G.set_gripper_pose(model, data, np.diag([1.0, 1.0, -1.0, 1.0]))  # a reflection, not a rotation


# ------------------------------------------------------------------------------------------------- grasp physics


def test_2f85_grasps_and_lifts_a_box(capsys):
    model, data = _compile(_box_world(0.8))
    res = _grasp_and_lift(model, data)
    assert res["dz"] > 0.15, res
    assert res["slip"] < 1e-3, res  # the box hardly moves in the TCP frame during lift + hold
    bx, by, _ = res["box_in_tcp"]
    assert abs(bx) < 2e-3 and abs(by) < G.load_gripper("robotiq_2f85").pad_size[1] / 2, res  # between the pads
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
    default = _grasp_and_lift(*_compile(_box_world(0.5, box_mass=2.0, options=G.PhysicsOptions(
        cone="pyramidal", impratio=1.0))))
    assert ours["slip"] < 1e-3, ours
    assert default["slip"] > 3e-3, default
