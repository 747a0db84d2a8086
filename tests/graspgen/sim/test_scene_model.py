"""The scene model on its own: MuJoCo model building and naming, settling, the camera model, headless rendering."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import trimesh

from graspgen.errors import SettingsError
from graspgen.sim.camera import (
    Camera,
    backproject,
    camera_on_sphere,
    depth_noise,
    intrinsics_from_fov,
    project,
    transform_points,
)
from graspgen.sim.render import SceneRenderer
from graspgen.sim.scene_model import (
    GROUP_COLLISION,
    GROUP_SUPPORT,
    GROUP_VISUAL,
    SEG_BACKGROUND,
    SEG_GROUND,
    SEG_SUPPORT,
    PlacedObject,
    build_scene_spec,
)
from graspgen.sim.scene_state import (
    geom_labels,
    object_bodies,
    object_geom_ids,
    object_poses,
    set_object_poses,
    support_geom_ids,
)
from graspgen.sim.settle import SettleParams, settle
from graspgen.sim.support import SupportParams, free_region, support_boxes

BOX = (0.04, 0.06, 0.08)


def box_object(name: str, xy=(0.0, 0.0), yaw=0.0, *, z=0.0, size=BOX, friction=0.8) -> PlacedObject:
    """A solid box resting on z = 0 (its mesh frame at its centre), rotated by ``yaw`` about z."""
    mesh = trimesh.creation.box(size)
    mass = 500.0 * mesh.volume
    pose = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    pose[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    pose[:3, 3] = (xy[0], xy[1], size[2] / 2 + z)
    return PlacedObject(
        name=name,
        convex_parts=[(np.asarray(mesh.vertices), np.asarray(mesh.faces))],
        mass=mass,
        center_of_mass=np.zeros(3),
        inertia=mass
        / 12
        * np.diag([size[1] ** 2 + size[2] ** 2, size[0] ** 2 + size[2] ** 2, size[0] ** 2 + size[1] ** 2]),
        pose=pose,
        friction=friction,
        visual=(np.asarray(mesh.vertices), np.asarray(mesh.faces)),
    )


def compiled(objects, support=None, size=(320, 240)):
    model = build_scene_spec(objects, support or SupportParams(), image_size=size).compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data


# --------------------------------------------------------------------------------------------------------------
# Model


def test_names_groups_and_labels_tell_support_target_and_clutter_apart():
    model, data = compiled([box_object("a", (-0.1, 0)), box_object("b", (0.1, 0))], SupportParams(kind="bin"))
    assert [(i, n) for i, n, _ in object_bodies(model)] == [(0, "a"), (1, "b")]
    assert model.body("obj/0_a").jntnum == 1 and model.jnt_type[model.body("obj/0_a").jntadr] == 0  # free joint
    labels = geom_labels(model)
    names = [model.geom(g).name for g in range(model.ngeom)]
    assert labels[names.index("ground")] == SEG_GROUND
    assert {names[g] for g in support_geom_ids(model, ground=False)} == {
        "support/table",
        "support/wall_px",
        "support/wall_nx",
        "support/wall_py",
        "support/wall_ny",
    }
    (part,) = object_geom_ids(model, 1)
    (visual,) = object_geom_ids(model, 1, collision=False)
    assert (names[part], names[visual]) == ("obj/1_b/part_0", "obj/1_b/visual")
    assert model.geom_group[part] == GROUP_COLLISION and model.geom_contype[part] == 1
    assert (
        model.geom_group[visual] == GROUP_VISUAL and model.geom_contype[visual] == model.geom_conaffinity[visual] == 0
    )
    assert all(model.geom_group[g] == GROUP_SUPPORT for g in support_geom_ids(model))
    # explicit inertia from the record, not from the geoms; the body frame is the mesh frame
    assert model.body("obj/0_a").mass[0] == pytest.approx(500.0 * np.prod(BOX))
    np.testing.assert_allclose(model.body("obj/0_a").ipos, 0.0, atol=1e-12)
    # elliptic cones, impratio 10, 2 ms (graspgen.sim.physics.PhysicsOptions)
    assert (model.opt.timestep, model.opt.cone, model.opt.impratio) == (0.002, mujoco.mjtCone.mjCONE_ELLIPTIC, 10.0)


def test_poses_round_trip_through_qpos():
    objs = [box_object("a", (-0.1, 0.02), 0.3), box_object("b", (0.1, -0.05), -1.2)]
    model, data = compiled(objs)
    np.testing.assert_allclose(object_poses(model, data), [o.pose for o in objs], atol=1e-12)
    moved = object_poses(model, data)
    moved[1, :3, 3] += (0.01, 0.02, 0.0)
    data.qvel[:] = 1.0
    set_object_poses(model, data, moved)
    np.testing.assert_allclose(object_poses(model, data), moved, atol=1e-12)
    assert not data.qvel.any()
    np.testing.assert_allclose(data.xpos[model.body("obj/1_b").id], moved[1, :3, 3], atol=1e-12)  # mj_forward ran
    with pytest.raises(ValueError, match=r"poses: must have shape \(2, 4, 4\)"):
        set_object_poses(model, data, moved[:1])


def test_support_kinds_and_free_region():
    assert [b.name for b in support_boxes(SupportParams())] == ["support/table"]
    table = support_boxes(SupportParams(height=0.7))[0]
    assert table.center[2] + table.size[2] / 2 == 0.0 and table.size[2] == 0.7  # top surface at z = 0
    shelf = SupportParams(kind="shelf", shelf_height=0.25)
    board = next(b for b in support_boxes(shelf) if b.name == "support/shelf_board")
    assert board.center[2] - board.size[2] / 2 == pytest.approx(0.25)
    lo, hi, zmax = free_region(shelf)
    assert zmax == 0.25 and hi[0] == pytest.approx(0.3 - 0.01)
    lo, hi, zmax = free_region(SupportParams(kind="bin", area=(0.2, 0.3)))
    np.testing.assert_allclose([lo, hi], [[-0.1, -0.15], [0.1, 0.15]]) and zmax == math.inf


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"kind": "floor"}, "kind: must be one of table, bin, shelf"),
        ({"height": 0}, r"height: must be in \(0, inf\), got 0"),
        ({"height": True}, "height: must be a number, got True"),
        ({"height": math.inf}, "height: must be finite, got inf"),
        ({"size": (0.6,)}, r"size: must be 2 finite numbers, got \(0.6,\)"),
        ({"wall_height": "tall"}, "wall_height: must be a number, got 'tall'"),
        ({"area": (0.7, 0.3)}, "area: must fit on the table top"),
        ({"kind": "bin", "area": (0.6, 0.3)}, "area: must plus the bin walls fit"),
        ({"friction": -1}, r"friction: must be in \(0, inf\), got -1"),
    ],
)
def test_support_params_errors_name_the_field(kwargs, message):
    with pytest.raises(SettingsError, match=message):
        SupportParams(**kwargs)


def test_settle_brings_a_dropped_box_to_rest_deterministically():
    objs = [box_object("a", (0.0, 0.0), 0.4, z=0.01)]
    runs = []
    for _ in range(2):
        model, data = compiled(objs)
        result = settle(model, data, SettleParams())
        runs.append(object_poses(model, data))
        assert result.at_rest and not result.moving(SettleParams()).any()
        assert SettleParams().min_time <= result.time < SettleParams().max_time
    assert np.array_equal(runs[0], runs[1])  # bit-identical
    assert runs[0][0, 2, 3] == pytest.approx(BOX[2] / 2, abs=5e-4)  # resting on the table top z = 0


def test_settle_params_errors():
    with pytest.raises(ValueError, match="min_time: must be in"):
        SettleParams(min_time=5.0, max_time=1.0)
    with pytest.raises(SettingsError, match=r"linear_speed: must be in \(0, inf\)"):
        SettleParams(linear_speed=0)
    with pytest.raises(SettingsError, match="max_time: must be a number, got True"):
        SettleParams(max_time=True)
    with pytest.raises(SettingsError, match="drop_height: must be finite"):
        SettleParams(drop_height=math.nan)


# --------------------------------------------------------------------------------------------------------------
# Camera model


def test_intrinsics_from_fov():
    K = intrinsics_from_fov(320, 240, math.radians(60))
    f = 120 / math.tan(math.radians(30))
    np.testing.assert_allclose(K, [[f, 0, 159.5], [0, f, 119.5], [0, 0, 1]])
    # the top and bottom pixel edges are at +-fov/2
    assert math.atan2(-0.5 - K[1, 2], K[1, 1]) == pytest.approx(-math.radians(30))
    with pytest.raises(ValueError, match="fov_y"):
        intrinsics_from_fov(320, 240, 0.0)


def test_opencv_convention_point_in_front_has_positive_z_and_up_is_up():
    target = np.array([0.1, -0.05, 0.02])
    for el, az in [(0.3, 0.0), (1.0, 2.0), (math.pi / 2, -1.0)]:
        T = camera_on_sphere(target, 0.7, el, az)
        R = T[:3, :3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        p = transform_points(np.linalg.inv(T), target)
        assert p[2] == pytest.approx(0.7) and np.allclose(p[:2], 0.0, atol=1e-12)  # in front, on the optical axis
        K = intrinsics_from_fov(320, 240, 0.8)
        above = transform_points(np.linalg.inv(T), target + [0, 0, 0.05])
        if el < math.pi / 2:
            assert project(K, above)[1] < K[1, 2]  # world up is image up (rows grow downwards)
    # roll turns the image about the optical axis, keeping the camera where it is
    T0, T1 = camera_on_sphere(target, 0.7, 0.8, 0.5), camera_on_sphere(target, 0.7, 0.8, 0.5, roll=0.3)
    np.testing.assert_allclose(T0[:3, 3], T1[:3, 3]) and np.testing.assert_allclose(T0[:3, 2], T1[:3, 2])
    assert math.acos(T0[:3, 0] @ T1[:3, 0]) == pytest.approx(0.3)


def test_backprojecting_a_plane_gives_points_on_that_plane():
    K = np.array([[300.0, 0, 150.0], [0, 280.0, 100.0], [0, 0, 1]])
    normal = np.array([0.2, -0.3, -1.0])
    normal /= np.linalg.norm(normal)
    c = -0.6  # plane n . p = c in the camera frame, ~0.6 m in front
    v, u = np.indices((200, 320), dtype=float)
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    depth = c / (rays @ normal)  # z of the ray's hit (rays have z = 1)
    points = backproject(depth, K)
    np.testing.assert_allclose(points @ normal, c, atol=1e-12)
    np.testing.assert_allclose(points[..., 2], depth)
    np.testing.assert_allclose(project(K, points[5, 7]), [7, 5], atol=1e-9)  # and back to its pixel
    assert np.all(backproject(np.zeros((2, 3)), K) == 0)


def test_camera_validation():
    with pytest.raises(ValueError, match="K: must be"):
        Camera(np.eye(3) * 0, np.eye(4), 10, 10)
    with pytest.raises(ValueError, match="T_world_camera: the rotation block is not a proper rotation"):
        Camera(np.eye(3), np.diag([1, 1, -1, 1.0]), 10, 10)


def test_depth_noise_keeps_zeros_and_is_seeded():
    depth = np.full((100, 100), 0.5, dtype=np.float32)
    depth[:10] = 0
    a = depth_noise(depth, np.random.default_rng(3), sigma=0.001, sigma_quadratic=0.004, dropout=0.1)
    b = depth_noise(depth, np.random.default_rng(3), sigma=0.001, sigma_quadratic=0.004, dropout=0.1)
    assert a.dtype == np.float32 and np.array_equal(a, b) and np.all(depth[:10] == 0)
    assert np.all(a[:10] == 0)
    kept = a[10:][a[10:] > 0]
    assert 0.85 < kept.size / depth[10:].size < 0.95  # ~10 % dropped
    assert np.std(kept - 0.5) == pytest.approx(0.001 + 0.004 * 0.25, rel=0.1)
    with pytest.raises(SettingsError, match=r"dropout: must be in \[0, 1\], got 2"):
        depth_noise(depth, np.random.default_rng(3), sigma=0.001, dropout=2)
    with pytest.raises(SettingsError, match=r"sigma: must be in \[0, inf\), got -0.1"):
        depth_noise(depth, np.random.default_rng(3), sigma=-0.1)
    with pytest.raises(SettingsError, match=r"depth: must be an \(H, W\) image, got shape \(3,\)"):
        backproject(np.zeros(3), np.eye(3))


# --------------------------------------------------------------------------------------------------------------
# Rendering


def test_render_matches_the_camera_model_for_any_intrinsics():
    """Object pixels back-projected with K and T land on the box surface; ids, depth 0 and support as documented."""
    objs = [box_object("a", (-0.06, 0.0), 0.5), box_object("b", (0.07, 0.03), -0.3)]
    model, data = compiled(objs, size=(200, 160))
    K = np.array([[210.0, 0, 90.0], [0, 190.0, 85.0], [0, 0, 1]])  # fx != fy, off-centre principal point
    cameras = [
        Camera(K, camera_on_sphere([0, 0, 0.04], 0.6, 0.7, 0.4, roll=0.2), 200, 160),
        Camera(K, camera_on_sphere([0, 0, 0.04], 0.5, 1.3, -2.0), 200, 160),
    ]
    with SceneRenderer(model, 200, 160) as renderer:
        views = [renderer.render(data, cam) for cam in cameras]
        again = renderer.render(data, cameras[0])
    assert np.array_equal(views[0].rgb, again.rgb) and np.array_equal(views[0].depth, again.depth)
    for view, cam in zip(views, cameras):
        assert view.rgb.shape == (160, 200, 3) and view.rgb.dtype == np.uint8
        assert view.depth.dtype == np.float32 and view.segmentation.dtype == np.int16
        ids = set(np.unique(view.segmentation).tolist())
        assert {0, 1, SEG_SUPPORT} <= ids <= {0, 1, SEG_SUPPORT, SEG_GROUND, SEG_BACKGROUND}
        assert np.all((view.depth == 0) == (view.segmentation == SEG_BACKGROUND))
        world = transform_points(cam.T_world_camera, backproject(view.depth, cam.K))
        for i, obj in enumerate(objs):
            pts = transform_points(np.linalg.inv(obj.pose), world[view.segmentation == i])
            # distance from a point to the box surface (all points are outside or on it)
            half = np.array(BOX) / 2
            outside = np.linalg.norm(np.maximum(np.abs(pts) - half, 0), axis=1)
            inside = np.min(half - np.abs(pts), axis=1)
            dist = np.where(outside > 0, outside, inside)
            assert len(pts) > 50 and dist.max() < 1e-3
        table = world[view.segmentation == SEG_SUPPORT]
        assert np.abs(table[:, 2]).max() < 1e-3  # seen table points lie on its top surface z = 0


def test_renderer_rejects_a_camera_of_another_size():
    model, data = compiled([box_object("a")], size=(64, 48))
    with SceneRenderer(model, 64, 48) as renderer:
        with pytest.raises(ValueError, match="image size 32x48 differs"):
            renderer.render(data, Camera(intrinsics_from_fov(32, 48, 1.0), np.eye(4), 32, 48))
