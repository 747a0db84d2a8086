"""Tests of stages/antipodal.py: the antipodal sampler's geometry, filters, frames, bookkeeping and determinism."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from graspgen.geometry import antipodal as A
from graspgen.geometry.mesh_io import load_mesh
from graspgen.grippers import load_gripper
from tests.paths import REPO

BOX_EXTENTS = (0.05, 0.07, 0.12)
SPHERE_RADIUS = 0.03
ASSETS = REPO / "assets" / "objects"
GRIPPER = load_gripper("robotiq_2f85")
ARRAY_FIELDS = [f.name for f in dataclasses.fields(A.AntipodalCandidates) if f.name != "rejected"]


def _box() -> trimesh.Trimesh:
    return trimesh.creation.box(BOX_EXTENTS)


def _sphere() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=3, radius=SPHERE_RADIUS)


def _sample(mesh, params=None, seed=0, gripper=GRIPPER, **kwargs) -> A.AntipodalCandidates:
    return A.sample_antipodal(mesh, gripper, params or A.AntipodalParams(), np.random.default_rng(seed), **kwargs)


def _random_pose(seed: int) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    T[:3, 3] = np.random.default_rng(seed).uniform(-0.5, 0.5, 3)
    return T


def _cone_angles(c: A.AntipodalCandidates) -> tuple[np.ndarray, np.ndarray]:
    u = (c.p2 - c.p1) / np.linalg.norm(c.p2 - c.p1, axis=1, keepdims=True)
    a1 = np.arccos(np.clip(np.einsum("ij,ij->i", u, c.n1), -1, 1))
    a2 = np.arccos(np.clip(np.einsum("ij,ij->i", -u, c.n2), -1, 1))
    return a1, a2


def _off_face(mesh: trimesh.Trimesh, points: np.ndarray, faces: np.ndarray) -> float:
    """Largest distance (m) of ``points`` from their triangles ``faces``: off-plane distance, plus how far outside
    the triangle in barycentric terms (scaled by the triangle's size). ``trimesh.proximity.closest_point`` is only
    accurate to ~1e-6 m, too coarse for this."""
    tri = mesh.triangles[faces]
    plane = np.abs(np.einsum("ij,ij->i", points - tri[:, 0], mesh.face_normals[faces]))
    bary = trimesh.triangles.points_to_barycentric(tri, points)
    size = np.linalg.norm(tri[:, 1] - tri[:, 0], axis=1)
    outside = np.maximum(0.0, -bary.min(axis=1)) * size
    return float(np.max(plane + outside, initial=0.0))


# ---------------------------------------------------------------------------------------------------------------
# Parameters and arguments
# ---------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("key, value", [
    ("num_surface_points", 0), ("num_surface_points", 2.5), ("rays_per_point", -1), ("friction", 0.0),
    ("friction", float("nan")), ("num_orientations", 0), ("approach", "below"), ("max_approach_angle", 0.0),
    ("max_approach_angle", math.pi / 2), ("width_margin", -0.001), ("surface_offset", 0.0), ("num_depths", 0),
    ("num_depths", 1.0), ("depth_margin", -0.001), ("depth_margin", float("inf")), ("min_clearance", -0.001),
    ("min_clearance", 0.03),  # more than width_margin (0.02)
])
def test_params_reject_bad_values_naming_the_key(key, value):
    with pytest.raises(ValueError, match=f"^{key}: "):
        A.AntipodalParams(**{key: value})


def test_params_defaults_are_valid_and_cone_angle():
    p = A.AntipodalParams(friction=1.0)
    assert p.cone_half_angle == pytest.approx(math.pi / 4)


def test_bad_arguments_raise_value_error():
    mesh = _box()
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="^mesh: "):
        A.sample_antipodal("box", GRIPPER, A.AntipodalParams(), rng)
    with pytest.raises(ValueError, match="^gripper: "):
        A.sample_antipodal(mesh, "robotiq_2f85", A.AntipodalParams(), rng)
    with pytest.raises(ValueError, match="^params: "):
        A.sample_antipodal(mesh, GRIPPER, {}, rng)
    with pytest.raises(ValueError, match="^rng: "):
        A.sample_antipodal(mesh, GRIPPER, A.AntipodalParams(), 0)
    with pytest.raises(ValueError, match="^object_pose: "):
        A.sample_antipodal(mesh, GRIPPER, A.AntipodalParams(), rng, object_pose=np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(ValueError, match="min_clearance"):
        A.sample_antipodal(mesh, GRIPPER, A.AntipodalParams(width_margin=0.1, min_clearance=0.1), rng)
    with pytest.raises(ValueError, match="depth_margin"):
        A.sample_antipodal(mesh, GRIPPER, A.AntipodalParams(depth_margin=0.02), rng)  # 2F-85 pads: 37.5 mm


def test_meshes_use_the_embree_intersector():
    assert A.uses_embree(_box())


# ---------------------------------------------------------------------------------------------------------------
# Geometry
# ---------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("friction", [0.2, 0.5, 0.9])
def test_box_contacts_lie_on_opposite_faces_within_the_cone(friction):
    mesh = _box()
    half = np.array(BOX_EXTENTS) / 2
    params = A.AntipodalParams(num_surface_points=400, friction=friction, approach="any")
    c = _sample(mesh, params)
    assert len(c) > 500
    # Inward normals are opposite coordinate axes: n1 = -n2 = +-e_k.
    np.testing.assert_allclose(c.n1, -c.n2, atol=1e-12)
    axis = np.argmax(np.abs(c.n1), axis=1)
    np.testing.assert_allclose(np.abs(c.n1[np.arange(len(c)), axis]), 1.0, atol=1e-12)
    rows = np.arange(len(c))
    # p1 on the face whose outward normal is -n1, p2 on the opposite face.
    np.testing.assert_allclose(c.p1[rows, axis], -np.sign(c.n1[rows, axis]) * half[axis], atol=1e-9)
    np.testing.assert_allclose(c.p2[rows, axis], np.sign(c.n1[rows, axis]) * half[axis], atol=1e-9)
    assert np.all(np.abs(c.p1) <= half + 1e-9) and np.all(np.abs(c.p2) <= half + 1e-9)
    a1, a2 = _cone_angles(c)
    assert a1.max() <= math.atan(friction) + 1e-9
    assert a2.max() <= math.atan(friction) + 1e-9
    # The 0.12 m axis is wider than the 2F-85 opens: never used.
    assert not np.any(axis == 2)
    assert c.rejected.width_too_large > 0


def test_contacts_are_on_the_surface():
    for mesh in (_box(), _sphere(), load_mesh(ASSETS / "mug.obj")):
        c = _sample(mesh, A.AntipodalParams(num_surface_points=200, num_orientations=2, approach="any"))
        assert len(c) > 50
        assert _off_face(mesh, c.p1, c.face1) < 1e-9
        assert _off_face(mesh, c.p2, c.face2) < 1e-9
        # The recorded faces are the contacts' faces: the normals are theirs.
        np.testing.assert_allclose(c.n1, -mesh.face_normals[c.face1])
        np.testing.assert_allclose(c.n2, -mesh.face_normals[c.face2])


@pytest.mark.parametrize("friction", [0.05, 0.3])
def test_sphere_contact_lines_pass_near_the_centre(friction):
    mesh = _sphere()
    c = _sample(mesh, A.AntipodalParams(num_surface_points=400, friction=friction, approach="any"))
    assert len(c) > 500
    # A line within the cone (half-angle atan(mu)) of a face normal that deviates by at most `facet` from the radial
    # direction passes within r sin(atan(mu) + facet) of the centre.
    radial = mesh.vertices[mesh.faces] / np.linalg.norm(mesh.vertices[mesh.faces], axis=2, keepdims=True)
    facet = np.arccos(np.clip(np.einsum("fvk,fk->fv", radial, mesh.face_normals), -1, 1)).max()
    u = (c.p2 - c.p1) / c.width[:, None]
    dist = np.linalg.norm(np.cross(-c.p1, u), axis=1)  # distance of the centre (origin) from each line
    assert dist.max() <= SPHERE_RADIUS * math.sin(math.atan(friction) + facet) + 1e-9
    # And the chords are near-diameters.
    assert c.width.min() >= 2 * SPHERE_RADIUS * math.cos(math.atan(friction) + facet) * math.cos(facet) - 1e-9


@pytest.mark.parametrize("gripper_name, margin, clearance",
                         [("robotiq_2f85", 0.02, 0.01), ("panda", 0.0, 0.0), ("box_jaw", 0.03, 0.03)])
def test_no_kept_grasp_has_width_outside_the_opening_range(gripper_name, margin, clearance):
    gripper = load_gripper(gripper_name)
    mesh = _box()
    params = A.AntipodalParams(num_surface_points=400, width_margin=margin, min_clearance=clearance, approach="any")
    c = _sample(mesh, params, gripper=gripper)
    assert len(c) > 0
    assert c.width.min() >= max(gripper.min_width, params.surface_offset)
    assert c.width.max() + clearance <= gripper.max_width + 1e-12
    np.testing.assert_allclose(c.width, np.linalg.norm(c.p2 - c.p1, axis=1))


def test_a_block_wider_than_stroke_minus_margin_is_still_grasped_across_it():
    """The bundled 50 x 70 x 120 mm block in the 85 mm 2F-85: 70 mm + the 20 mm margin exceeds the stroke, but the
    full opening leaves 15 mm, more than ``min_clearance``: its 70 mm faces are grasped, its 120 mm ones never."""
    mesh = trimesh.creation.box((0.05, 0.07, 0.12))
    c = _sample(mesh, A.AntipodalParams(num_surface_points=400, approach="any"))
    axis = np.abs((c.p2 - c.p1) / c.width[:, None]).argmax(axis=1)
    assert {0, 1} <= set(axis.tolist()) and 2 not in set(axis.tolist())
    # pairs across the 70 mm faces (their lines may lean inside the cone, so the width is >= 70 mm)
    np.testing.assert_allclose(np.abs(c.p2 - c.p1)[axis == 1, 1], 0.07, atol=1e-6)
    strict = _sample(mesh, A.AntipodalParams(num_surface_points=400, approach="any", min_clearance=0.02))
    assert len(strict) > 0 and strict.width.max() < 0.065


def test_thin_object_widths_too_small_for_a_gripper_with_a_minimum():
    gripper = dataclasses.replace(GRIPPER, min_width=0.03)
    mesh = trimesh.creation.box((0.02, 0.06, 0.06))  # 2 cm thick plate: pinching it needs width 0.02 < 0.03
    c = _sample(mesh, A.AntipodalParams(approach="any"), gripper=gripper)
    assert c.rejected.width_too_small > 0
    assert len(c) == 0 or c.width.min() >= 0.03


def test_mug_wall_pairs_pinch_one_wall():
    """On a thin-walled mug the second contact is where the ray first leaves the material: no pair spans the
    cavity, so the segment p1 -> p2 lies inside the object."""
    mesh = load_mesh(ASSETS / "mug.obj")
    c = _sample(mesh, A.AntipodalParams(num_surface_points=300, approach="any"))
    assert len(c) > 100
    assert c.rejected.no_exit <= 0.01 * c.rejected.rays
    mids = (c.p1 + c.p2) / 2
    assert mesh.contains(mids[::8]).all()


def test_open_mesh_rays_through_the_hole_are_no_exit():
    mesh = _box()
    top = np.flatnonzero(mesh.face_normals[:, 2] > 0.5)
    open_box = trimesh.Trimesh(mesh.vertices, np.delete(mesh.faces, top, axis=0), process=False)
    params = A.AntipodalParams(num_surface_points=400, approach="any", friction=0.9)
    c = _sample(open_box, params)
    # Rays heading for the missing top leave through the hole: no second contact.
    assert c.rejected.no_exit > 0
    a1, a2 = _cone_angles(c)
    assert max(a1.max(), a2.max()) <= math.atan(0.9) + 1e-9
    assert _off_face(open_box, c.p2, c.face2) < 1e-9


# ---------------------------------------------------------------------------------------------------------------
# Frames and the approach filter
# ---------------------------------------------------------------------------------------------------------------


def test_tcp_frame_is_right_handed_with_x_along_the_contact_line_and_origin_behind_the_midpoint():
    pose = _random_pose(3)
    params = A.AntipodalParams(num_surface_points=100, approach="any")
    c = _sample(_sphere(), params, object_pose=pose)
    R = c.pose_object[:, :3, :3]
    np.testing.assert_allclose(np.matmul(np.swapaxes(R, 1, 2), R), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    x, y, z = R[:, :, 0], R[:, :, 1], R[:, :, 2]
    np.testing.assert_allclose(x, (c.p2 - c.p1) / c.width[:, None], atol=1e-12)
    np.testing.assert_allclose(y, np.cross(z, x), atol=1e-12)
    # The TCP sits `depth` behind the contacts' midpoint along the approach axis.
    np.testing.assert_allclose(c.pose_object[:, :3, 3], (c.p1 + c.p2) / 2 - c.depth[:, None] * z, atol=1e-15)
    np.testing.assert_array_equal(c.pose_object[:, 3], np.broadcast_to([0.0, 0.0, 0.0, 1.0], (len(c), 4)))
    np.testing.assert_allclose(c.pose_world, np.matmul(pose, c.pose_object), atol=1e-15)
    np.testing.assert_array_equal(c.object_pose, pose)
    np.testing.assert_allclose(np.linalg.norm(c.n1, axis=1), 1.0)
    np.testing.assert_allclose(np.linalg.norm(c.n2, axis=1), 1.0)
    # The left pad's contact p1 is on the TCP's -x side, the right pad's p2 on +x, each at width / 2, depth ahead.
    local1 = np.einsum("nji,nj->ni", R, c.p1 - c.pose_object[:, :3, 3])
    np.testing.assert_allclose(local1, np.stack([-c.width / 2, 0 * c.width, c.depth], axis=1), atol=1e-12)
    local2 = np.einsum("nji,nj->ni", R, c.p2 - c.pose_object[:, :3, 3])
    np.testing.assert_allclose(local2, np.stack([c.width / 2, 0 * c.width, c.depth], axis=1), atol=1e-12)


def test_one_depth_puts_the_tcp_at_the_midpoint_and_depths_do_not_touch_the_rng_stream():
    mesh = load_mesh(ASSETS / "mug.obj")
    one = _sample(mesh, A.AntipodalParams(num_surface_points=150, num_depths=1), seed=5)
    three = _sample(mesh, A.AntipodalParams(num_surface_points=150, num_depths=3), seed=5)
    np.testing.assert_array_equal(one.depth, 0.0)
    np.testing.assert_allclose(one.pose_object[:, :3, 3], (one.p1 + one.p2) / 2, atol=1e-15)
    # Same draws: the 3-depth set is the 1-depth set with each candidate repeated at 3 depths (depth innermost).
    assert len(three) == 3 * len(one)
    for name in ("p1", "p2", "n1", "n2", "face1", "face2", "width", "approach_angle", "ray_index"):
        np.testing.assert_array_equal(getattr(three, name), np.repeat(getattr(one, name), 3, axis=0), err_msg=name)
    np.testing.assert_array_equal(three.pose_object[:, :3, :3], np.repeat(one.pose_object[:, :3, :3], 3, axis=0))
    np.testing.assert_array_equal(three.depth, np.tile(A.grasp_depths(GRIPPER, A.AntipodalParams()), len(one)))


@pytest.mark.parametrize("gripper_name", ["robotiq_2f85", "panda", "box_jaw"])
def test_grasp_depths_span_zero_to_the_pad_tip_less_the_margin(gripper_name):
    gripper = load_gripper(gripper_name)
    half = gripper.pad_size[2] / 2
    np.testing.assert_array_equal(A.grasp_depths(gripper, A.AntipodalParams(num_depths=1)), [0.0])
    d = A.grasp_depths(gripper, A.AntipodalParams(num_depths=4, depth_margin=0.004))
    np.testing.assert_allclose(d, np.linspace(0.0, half - 0.004, 4))
    with pytest.raises(ValueError, match="^params.depth_margin: "):
        A.grasp_depths(gripper, A.AntipodalParams(num_depths=2, depth_margin=half))
    # One depth never needs room on the pads.
    np.testing.assert_array_equal(A.grasp_depths(gripper, A.AntipodalParams(num_depths=1, depth_margin=1.0)), [0.0])


@pytest.mark.parametrize("gripper_name", ["robotiq_2f85", "panda", "box_jaw"])
@pytest.mark.parametrize("num_depths, margin", [(1, 0.005), (3, 0.005), (5, 0.0)])
def test_contacts_lie_on_the_pad_faces_in_the_tcp_frame(gripper_name, num_depths, margin):
    """Each contact, in the TCP frame, lies on its pad's contact face: x = -+width / 2 (the pad's inner face when
    the jaws have closed to ``width``), |y| <= pad width / 2, |z| <= pad length / 2 - depth_margin."""
    gripper = load_gripper(gripper_name)
    _, pad_w, pad_l = gripper.pad_size
    params = A.AntipodalParams(num_surface_points=200, num_depths=num_depths, depth_margin=margin, approach="any")
    for mesh in (_box(), load_mesh(ASSETS / "mug.obj")):
        c = _sample(mesh, params, gripper=gripper, object_pose=_random_pose(1))
        assert len(c) > 0
        T = c.pose_world  # in the world frame, as the rollout places the gripper
        R, t = T[:, :3, :3], T[:, :3, 3]
        for p, sign in ((c.p1, -1.0), (c.p2, 1.0)):
            world = p @ c.object_pose[:3, :3].T + c.object_pose[:3, 3]
            local = np.einsum("nji,nj->ni", R, world - t)
            np.testing.assert_allclose(local[:, 0], sign * c.width / 2, atol=1e-12)
            assert np.abs(local[:, 1]).max() <= pad_w / 2
            assert np.abs(local[:, 2]).max() <= pad_l / 2 - margin + 1e-12
        np.testing.assert_allclose(np.unique(c.depth), A.grasp_depths(gripper, params), atol=1e-15)
    # The deepest-set TCP leaves exactly `margin` of pad past the contacts (finger tips flush with the pads).
    if num_depths > 1:
        assert c.depth.max() == pytest.approx(pad_l / 2 - margin)


def test_orientations_are_evenly_spaced_about_the_contact_axis():
    k, d = 6, 2
    c = _sample(_box(), A.AntipodalParams(num_surface_points=50, num_orientations=k, num_depths=d, approach="any"))
    _, first, counts = np.unique(c.ray_index, return_index=True, return_counts=True)
    assert np.all(counts == k * d)
    for start in first[:20]:
        z = c.pose_object[start:start + k * d:d, :3, 2]  # one per orientation (depths are innermost)
        x = c.pose_object[start, :3, 0]
        angles = np.arctan2(np.cross(z[0], z) @ x, z @ z[0])
        np.testing.assert_allclose(np.mod(angles, 2 * np.pi), 2 * np.pi / k * np.arange(k), atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_above_never_yields_an_upward_approach(seed):
    pose = _random_pose(seed)
    max_angle = math.radians(40)
    params = A.AntipodalParams(num_surface_points=300, approach="above", max_approach_angle=max_angle)
    c = _sample(_box(), params, seed=seed, object_pose=pose)
    assert len(c) > 0
    z_world = c.pose_world[:, :3, 2]
    assert z_world[:, 2].max() < 0
    angle = np.arccos(np.clip(-z_world[:, 2], -1, 1))
    np.testing.assert_allclose(c.approach_angle, angle, atol=1e-12)
    assert angle.max() <= max_angle
    assert c.rejected.approach > 0


def test_hemisphere_and_any_filters():
    mesh = _sphere()
    hemi = _sample(mesh, A.AntipodalParams(num_surface_points=200, approach="hemisphere"))
    every = _sample(mesh, A.AntipodalParams(num_surface_points=200, approach="any"))
    assert hemi.pose_world[:, 2, 2].max() < 0
    assert every.pose_world[:, 2, 2].max() > 0.5  # 'any' keeps upward approaches
    assert every.rejected.approach == 0
    # Same rng stream, so the hemisphere set is exactly the downward subset of 'any'.
    down = every.pose_world[:, 2, 2] < 0
    np.testing.assert_array_equal(hemi.pose_world, every.pose_world[down])


# ---------------------------------------------------------------------------------------------------------------
# Bookkeeping and determinism
# ---------------------------------------------------------------------------------------------------------------


def test_reject_counts_add_up():
    params = A.AntipodalParams(num_surface_points=300, rays_per_point=3, num_orientations=5, num_depths=3,
                               approach="above")
    for mesh in (_box(), _sphere(), load_mesh(ASSETS / "mug.obj")):
        c = _sample(mesh, params)
        r = c.rejected
        assert r.rays == 300 * 3
        assert r.rays == r.no_exit + r.outside_cone + r.width_too_small + r.width_too_large + r.pairs
        assert r.pairs * 5 * 3 == r.approach + r.kept
        assert r.kept == len(c) == len(c.ray_index)
        assert set(r.as_dict()) == {"rays", "no_exit", "outside_cone", "width_too_small", "width_too_large",
                                    "pairs", "approach", "kept"}


def test_same_seed_gives_identical_arrays_and_another_seed_does_not():
    mesh = load_mesh(ASSETS / "mug.obj")
    params = A.AntipodalParams(num_surface_points=200)
    pose = _random_pose(7)
    a = _sample(mesh, params, seed=42, object_pose=pose)
    b = _sample(mesh.copy(), params, seed=42, object_pose=pose)  # a fresh mesh: a fresh Embree scene
    for name in ARRAY_FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
        assert getattr(a, name).dtype == getattr(b, name).dtype
    assert a.rejected == b.rejected
    c = _sample(mesh, params, seed=43, object_pose=pose)
    assert len(c) != len(a) or not np.array_equal(c.p1, a.p1)


def test_output_arrays_are_read_only_and_shaped():
    c = _sample(_box(), A.AntipodalParams(num_surface_points=20))
    n = len(c)
    shapes = {"p1": (n, 3), "p2": (n, 3), "n1": (n, 3), "n2": (n, 3), "face1": (n,), "face2": (n,), "width": (n,),
              "pose_object": (n, 4, 4), "pose_world": (n, 4, 4), "approach_angle": (n,), "ray_index": (n,),
              "depth": (n,), "object_pose": (4, 4)}
    for name in ARRAY_FIELDS:
        arr = getattr(c, name)
        assert arr.shape == shapes[name], name
        assert not arr.flags.writeable, name
    with pytest.raises(ValueError):
        c.width[0] = 1.0


def test_nothing_kept_gives_empty_arrays():
    big = trimesh.creation.box((0.3, 0.3, 0.3))  # wider than any opening
    c = _sample(big, A.AntipodalParams(num_surface_points=50))
    assert len(c) == 0 and c.rejected.pairs == 0
    assert c.pose_world.shape == (0, 4, 4) and c.p1.shape == (0, 3)
