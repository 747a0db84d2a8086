"""Tests of the mesh-preparation steps (graspgen.geometry: mesh_io, repair, units, mass, convex, stable_poses,
prepare) against analytic truth. Meshes are built inline; nothing in assets/ is used."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import trimesh

from graspgen.errors import InputError
from graspgen.geometry import coacd_process
from graspgen.geometry.convex import CoacdParams, _convex_part, _read_parts, convex_decomposition, write_parts
from graspgen.geometry.mass import _physical_inertia, mass_properties
from graspgen.geometry.mesh_io import load_mesh
from graspgen.geometry.repair import repair_mesh
from graspgen.geometry.stable_poses import StablePoseParams, resting_transform
from graspgen.geometry.units import normalize_units
from graspgen.sim.stable_poses import build_settle_model, settle_pose, stable_poses
from graspgen.workflows.prepare import prepare_object
from tests.shapes import l_shape

# Cheap CoACD settings: the shapes here are simple, and the whole file must stay fast on one core.
FAST_COACD = CoacdParams(threshold=0.05, resolution=300, mcts_iterations=20, mcts_nodes=10, preprocess_resolution=20)
POSES = StablePoseParams()
DENSITY = 800.0  # kg/m^3


# ---------------------------------------------------------------------------------------------------------------
# Helpers
# ---------------------------------------------------------------------------------------------------------------



L_VOLUME = 2 * 0.1 * 0.02 * 0.02 - 0.02**3


def prepared(mesh: trimesh.Trimesh, coacd: CoacdParams = FAST_COACD):
    """Repair, weigh and decompose a mesh already in metres."""
    repaired, report = repair_mesh(mesh)
    mass = mass_properties(repaired, DENSITY, watertight=report.watertight)
    parts = convex_decomposition(repaired, coacd)
    return repaired, mass, parts


def union_volume(parts, pitch: float = 0.002, bounds=((0, 0, 0), (0.1, 0.1, 0.02))) -> float:
    """Volume covered by at least one part, by counting grid-cell centres (parts may overlap)."""
    lo, hi = np.asarray(bounds[0]), np.asarray(bounds[1])
    axes = [np.arange(lo[i] + pitch / 2, hi[i], pitch) for i in range(3)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    inside = np.zeros(len(points), dtype=bool)
    for vertices, faces in parts:
        hull = trimesh.Trimesh(vertices, faces, process=False)
        inside |= np.all(
            points @ hull.face_normals.T - np.einsum("ij,ij->i", hull.face_normals, hull.triangles_center) <= 1e-9,
            axis=1,
        )
    return inside.sum() * pitch**3


def up_vector(transform: np.ndarray) -> np.ndarray:
    """World +z expressed in the mesh frame."""
    return transform[2, :3]


# ---------------------------------------------------------------------------------------------------------------
# Settings
# ---------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("cls", "field", "value"),
    [
        (CoacdParams, "threshold", 2.0),
        (CoacdParams, "threshold", 0.0),
        (CoacdParams, "max_convex_hull", 0),
        (CoacdParams, "resolution", 0),
        (CoacdParams, "mcts_depth", 1.5),
        (StablePoseParams, "min_probability", 1.0),
        (StablePoseParams, "max_poses", 0),
        (StablePoseParams, "settle_time", -1.0),
        (StablePoseParams, "max_tilt", 0.0),
        (StablePoseParams, "friction", float("nan")),
    ],
)
def test_params_reject_bad_values_naming_the_field(cls, field, value):
    with pytest.raises(ValueError, match=f"^{field}: "):
        cls(**{field: value})


def test_params_accept_unlimited_hulls():
    assert CoacdParams(max_convex_hull=-1).max_convex_hull == -1


# ---------------------------------------------------------------------------------------------------------------
# load_mesh
# ---------------------------------------------------------------------------------------------------------------

_PLY_NAN = (
    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    "element face 1\nproperty list uchar int vertex_indices\nend_header\nnan 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
)
_PLY_CLOUD = (
    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    "end_header\n0 0 0\n1 0 0\n0 1 0\n"
)


@pytest.mark.parametrize(
    ("name", "content", "reason"),
    [
        ("empty.obj", b"", "empty file"),
        ("garbage.obj", bytes(range(256)) * 4, "not a valid OBJ"),
        ("garbage.ply", b"\x00\xff\x13garbage" * 50, "not a readable PLY"),
        ("nan.obj", b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN or infinite"),
        ("inf.obj", b"v inf 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN or infinite"),
        ("nan.ply", _PLY_NAN.encode(), "NaN or infinite"),
        ("degenerate.obj", b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "all 1 faces have zero area"),
        ("cloud.ply", _PLY_CLOUD.encode(), "not a mesh"),
        ("text.obj", b"hello world\n", "not a mesh"),
    ],
)
def test_load_mesh_rejects_broken_files(tmp_path, name, content, reason):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(InputError) as info:
        load_mesh(path)
    assert name in str(info.value)
    assert reason in str(info.value)


def test_load_mesh_rejects_missing_file(tmp_path):
    with pytest.raises(InputError, match=r"nothere\.obj: file not found"):
        load_mesh(tmp_path / "nothere.obj")


def test_load_mesh_rejects_unsupported_suffix(tmp_path):
    path = tmp_path / "mesh.xyz"
    path.write_text("0 0 0\n")
    with pytest.raises(InputError, match=r"mesh\.xyz: unsupported mesh format"):
        load_mesh(path)


def test_load_mesh_reads_valid_obj(tmp_path):
    box = trimesh.creation.box((0.1, 0.06, 0.03))
    path = tmp_path / "box.obj"
    box.export(path)
    mesh = load_mesh(path)
    assert len(mesh.faces) == 12
    np.testing.assert_allclose(mesh.extents, (0.1, 0.06, 0.03), rtol=1e-6)
    assert mesh.metadata["file_name"] == "box.obj"


def test_load_mesh_merges_scene_with_transforms(tmp_path):
    scene = trimesh.Scene()
    scene.add_geometry(
        trimesh.creation.box((0.02, 0.02, 0.02)), transform=trimesh.transformations.translation_matrix((0.1, 0, 0))
    )
    scene.add_geometry(trimesh.creation.box((0.02, 0.02, 0.02)))
    path = tmp_path / "two.glb"
    scene.export(path)
    mesh = load_mesh(path)
    np.testing.assert_allclose(mesh.bounds, [(-0.01, -0.01, -0.01), (0.11, 0.01, 0.01)], atol=1e-6)


# ---------------------------------------------------------------------------------------------------------------
# normalize_units
# ---------------------------------------------------------------------------------------------------------------


def test_normalize_units_guesses_millimetres():
    cylinder = trimesh.creation.cylinder(radius=40.0, height=95.0)
    scaled, scale, warning = normalize_units(cylinder, source="mug.obj")
    assert scale == 0.001
    np.testing.assert_allclose(scaled.extents.max(), 0.095, rtol=1e-12)
    assert warning == "mug.obj: largest extent 95.0 units, assumed millimetres, scaled by 0.001"


def test_normalize_units_keeps_plausible_metres():
    box = trimesh.creation.box((0.1, 0.05, 0.02))
    scaled, scale, warning = normalize_units(box)
    assert scale == 1.0 and warning is None
    np.testing.assert_array_equal(scaled.vertices, box.vertices)


def test_normalize_units_rejects_1000_unit_mesh():
    tower = trimesh.creation.box((100.0, 100.0, 1000.0))
    with pytest.raises(InputError, match=r"tower\.obj: absurd size after unit handling: .*1\.0 m as millimetres"):
        normalize_units(tower, source="tower.obj")


def test_normalize_units_honours_explicit_scale():
    box = trimesh.creation.box((10.0, 5.0, 2.0))
    scaled, scale, warning = normalize_units(box, scale=0.01)
    assert scale == 0.01 and warning is None
    np.testing.assert_allclose(scaled.extents, (0.1, 0.05, 0.02), rtol=1e-12)
    with pytest.raises(InputError, match="absurd size after unit handling"):
        normalize_units(box, scale=1.0)


def test_normalize_units_ignores_stray_unreferenced_vertex():
    box = trimesh.creation.box((0.1, 0.05, 0.02))
    stray = trimesh.Trimesh(np.vstack([box.vertices, [[500.0, 0.0, 0.0]]]), box.faces, process=False)
    assert normalize_units(stray)[1] == 1.0


# ---------------------------------------------------------------------------------------------------------------
# repair_mesh
# ---------------------------------------------------------------------------------------------------------------


def test_repair_fixes_flipped_faces_and_duplicate_vertices():
    box = trimesh.creation.box((0.1, 0.06, 0.03))
    soup_vertices = box.vertices[box.faces].reshape(-1, 3)  # every face has its own three vertices
    soup_faces = np.arange(len(soup_vertices)).reshape(-1, 3)
    soup_faces[::3] = soup_faces[::3, ::-1]  # flip every third face
    broken = trimesh.Trimesh(soup_vertices, soup_faces, process=False)
    assert not broken.is_watertight

    repaired, report = repair_mesh(broken)

    assert report.watertight
    assert report.merged_vertices == 36 - 8
    assert report.fixed_normals
    assert repaired.volume == pytest.approx(0.1 * 0.06 * 0.03, rel=1e-9)
    assert len(broken.vertices) == 36  # input untouched


def test_repair_removes_degenerate_and_duplicate_faces():
    box = trimesh.creation.box((0.1, 0.06, 0.03))
    faces = np.vstack([box.faces, box.faces[:2], [[0, 0, 1]]])
    repaired, report = repair_mesh(trimesh.Trimesh(box.vertices, faces, process=False))
    assert report.removed_duplicate_faces == 2
    assert report.removed_degenerate_faces == 1
    assert report.watertight and len(repaired.faces) == 12


def test_repair_reports_open_mesh():
    box = trimesh.creation.box((0.1, 0.06, 0.03))
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-2], process=False)  # one side missing: a square hole
    repaired, report = repair_mesh(open_box)
    assert report.filled_holes and report.watertight  # trimesh fills holes of up to four edges

    bowl = trimesh.creation.icosphere(2, 0.05)
    bowl = trimesh.Trimesh(bowl.vertices, bowl.faces[bowl.triangles_center[:, 2] < 0.02], process=False)
    _, report = repair_mesh(bowl)
    assert not report.watertight
    assert "mesh is not watertight after repair" in report.notes


# ---------------------------------------------------------------------------------------------------------------
# mass_properties
# ---------------------------------------------------------------------------------------------------------------


def test_mass_properties_of_box_are_exact():
    a, b, c, rho = 0.1, 0.06, 0.03, 700.0
    box = trimesh.creation.box((a, b, c))
    box.apply_translation((0.2, -0.1, 0.05))
    props = mass_properties(box, rho, watertight=True)
    mass = rho * a * b * c
    assert props.mass == pytest.approx(mass, rel=1e-9)
    assert props.volume == pytest.approx(a * b * c, rel=1e-9)
    np.testing.assert_allclose(props.center_of_mass, (0.2, -0.1, 0.05), rtol=1e-9, atol=1e-15)
    expected = np.diag([mass / 12 * (b * b + c * c), mass / 12 * (a * a + c * c), mass / 12 * (a * a + b * b)])
    np.testing.assert_allclose(props.inertia, expected, rtol=1e-9, atol=1e-9 * expected.max())
    assert not props.from_convex_hull
    assert not props.inertia.flags.writeable


def test_mass_properties_of_sphere_within_one_percent():
    radius, rho = 0.04, 1000.0
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    props = mass_properties(sphere, rho, watertight=True)
    mass = rho * 4 / 3 * math.pi * radius**3
    # The inscribed polyhedron lacks ~0.9 % of the mass and ~1.4 % of the inertia of the true sphere; its radius
    # of gyration, sqrt(2/5) r, is within 1 %.
    assert props.mass == pytest.approx(mass, rel=0.01)
    np.testing.assert_allclose(np.diag(props.inertia), 2 / 5 * props.mass * radius**2, rtol=0.01)
    np.testing.assert_allclose(props.inertia - np.diag(np.diag(props.inertia)), 0.0, atol=1e-6 * props.inertia[0, 0])
    np.testing.assert_allclose(props.center_of_mass, 0.0, atol=1e-12)


def test_mass_properties_of_open_mesh_use_convex_hull():
    box = trimesh.creation.box((0.1, 0.06, 0.03))
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-2], process=False)
    props = mass_properties(open_box, 1000.0, watertight=False)
    assert props.from_convex_hull
    assert props.volume == pytest.approx(0.1 * 0.06 * 0.03, rel=1e-9)


def test_mass_properties_reject_zero_volume():
    flat = trimesh.creation.box((0.1, 0.06, 0.03))
    flat = trimesh.Trimesh(
        flat.vertices * (1.0, 1.0, 0.0), flat.faces, process=False, metadata={"file_name": "flat.obj"}
    )
    with pytest.raises(InputError, match=r"flat\.obj: zero volume"):
        mass_properties(flat, 1000.0, watertight=True)


def test_physical_inertia_fixes_rounding_on_the_triangle_inequality():
    plate = np.diag([1.0, 2.0, 3.0 + 1e-12])  # a flat plate has I3 = I1 + I2; rounding pushed it over
    fixed = _physical_inertia(plate, "plate")
    moments = np.linalg.eigvalsh(fixed)
    assert moments[2] <= moments[0] + moments[1]
    np.testing.assert_allclose(fixed, plate, atol=1e-11)
    with pytest.raises(InputError, match="inertia is not physical"):
        _physical_inertia(np.diag([1.0, 1.0, 3.0]), "bad")


# ---------------------------------------------------------------------------------------------------------------
# convex_decomposition
# ---------------------------------------------------------------------------------------------------------------


def test_convex_decomposition_of_box_is_the_box(monkeypatch):
    monkeypatch.setattr(coacd_process, "run_coacd", _fail)  # a convex mesh must not go through CoACD
    box = trimesh.creation.box((0.1, 0.06, 0.03))
    parts = convex_decomposition(box, FAST_COACD)
    assert len(parts) == 1
    vertices, faces = parts[0]
    assert vertices.dtype == np.float64 and faces.dtype == np.int32
    part = trimesh.Trimesh(vertices, faces, process=False)
    assert part.volume == pytest.approx(0.1 * 0.06 * 0.03, rel=1e-12)
    np.testing.assert_allclose(part.bounds, box.bounds, atol=1e-15)


def test_convex_decomposition_of_l_shape(capfd):
    mesh = l_shape()
    parts = convex_decomposition(mesh, FAST_COACD)
    assert "CoACD" not in capfd.readouterr().out  # its per-run log is silenced
    assert len(parts) >= 2
    for vertices, faces in parts:
        part = trimesh.Trimesh(vertices, faces, process=False)
        assert part.is_watertight and part.volume > 0
        assert part.volume == pytest.approx(part.convex_hull.volume, rel=1e-9)
    assert union_volume(parts) == pytest.approx(L_VOLUME, rel=0.10)

    again = convex_decomposition(mesh, FAST_COACD)
    assert len(again) == len(parts)
    for (v1, f1), (v2, f2) in zip(parts, again, strict=True):
        assert v1.tobytes() == v2.tobytes() and f1.tobytes() == f2.tobytes()


def _fail(*args, **kwargs):
    raise AssertionError("coacd.run_coacd must not be called")


@pytest.mark.filterwarnings("ignore:invalid value encountered in divide:RuntimeWarning")  # trimesh: 0-volume mass
def test_degenerate_coacd_parts_have_no_volume_or_no_hull():
    flat = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0.5, 0.5, 0]], dtype=np.float64) * 0.01
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    for points in (flat, flat * [1, 0, 0]):  # a flat part, a collinear part: no volume, dropped as slivers
        part = _convex_part(points, faces)
        assert part is None or not part.volume > 0
    for bad in (np.inf, np.nan):  # QhullError, ValueError: no hull at all
        points = flat.copy()
        points[0, 2] = bad
        assert _convex_part(points, faces) is None


def _damage(path, how):
    data = path.read_bytes()
    if how == "empty":
        path.write_bytes(b"")
    elif how == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif how == "bit flip":
        i = data.index(b"\x93NUMPY", len(data) // 2) + 64  # inside the last array's data: a CRC mismatch
        path.write_bytes(data[:i] + bytes([data[i] ^ 0xFF]) + data[i + 1 :])
    elif how == "text":
        path.write_bytes(b"not an npz")
    elif how == "plain npy":
        with open(path, "wb") as f:
            np.save(f, np.arange(3))
    elif how == "part missing":
        with open(path, "wb") as f:
            np.savez(f, count=np.array(2), vertices_0=np.zeros((4, 3)), faces_0=np.zeros((4, 3)))
    elif how == "folder":
        path.unlink()
        path.mkdir()


@pytest.mark.parametrize("how", ["empty", "truncated", "bit flip", "text", "plain npy", "part missing", "folder"])
def test_damaged_cache_entry_is_reported_and_recomputed(tmp_path, caplog, how):
    path = tmp_path / "coacd-x.npz"
    write_parts(path, [(np.zeros((4, 3)), np.zeros((4, 3), dtype=np.int32))])
    assert len(_read_parts(path)) == 1
    _damage(path, how)
    if how == "folder":
        assert _read_parts(path) is None  # not a file: simply a miss
        return
    with caplog.at_level("WARNING", logger="graspgen.geometry.convex"):
        assert _read_parts(path) is None
    assert "unreadable CoACD cache entry, recomputing" in caplog.text


# ---------------------------------------------------------------------------------------------------------------
# stable_poses
# ---------------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def box_object():
    return prepared(trimesh.creation.box((0.1, 0.06, 0.03)))


def test_stable_poses_of_box(box_object):
    mesh, mass, parts = box_object
    transforms, probs = stable_poses(mesh, mass, parts, POSES, np.random.default_rng(0))
    assert transforms.shape == (len(probs), 4, 4) and transforms.dtype == np.float64
    assert probs.sum() == pytest.approx(1.0, abs=1e-12)
    assert np.all(np.diff(probs) <= 0)
    for transform in transforms:
        placed = trimesh.transform_points(mesh.vertices, transform)
        assert placed[:, 2].min() == pytest.approx(0.0, abs=1e-4)
    placed = trimesh.transform_points(mesh.vertices, transforms[0])
    np.testing.assert_allclose(np.ptp(placed[:, 2]), 0.03, rtol=1e-9)  # on a 0.1 x 0.06 face
    # the two large faces are equally likely and together the most probable
    assert probs[0] == pytest.approx(probs[1], rel=1e-9)
    assert abs(up_vector(transforms[1])[2]) == pytest.approx(1.0)


def test_stable_poses_are_at_rest_when_resimulated(box_object):
    mesh, mass, parts = box_object
    transforms, _ = stable_poses(mesh, mass, parts, POSES, np.random.default_rng(0))
    model = build_settle_model(parts, mass, POSES)
    for transform in transforms:
        result = settle_pose(model, transform, POSES)
        assert result.at_rest
        pose = result.poses[0]
        tilt = math.acos(np.clip(pose[2, :3] @ transform[2, :3], -1.0, 1.0))
        assert tilt < POSES.max_tilt
        assert pose[2, 3] == pytest.approx(transform[2, 3], abs=5e-4)  # still on the plane, not sunk


def test_stable_poses_are_deterministic_and_leave_global_rng_alone(box_object):
    mesh, mass, parts = box_object
    noisy = StablePoseParams(com_sigma=0.002, com_samples=4)
    global_state = np.random.get_state()[1].copy()
    trimesh_state = trimesh.util._RANDOM_DEFAULT.bit_generator.state
    first = stable_poses(mesh, mass, parts, noisy, np.random.default_rng(7))
    second = stable_poses(mesh, mass, parts, noisy, np.random.default_rng(7))
    assert first[0].tobytes() == second[0].tobytes()
    assert first[1].tobytes() == second[1].tobytes()
    np.testing.assert_array_equal(np.random.get_state()[1], global_state)
    assert trimesh.util._RANDOM_DEFAULT.bit_generator.state == trimesh_state


def test_stable_poses_without_settle_check(box_object):
    mesh, mass, parts = box_object
    params = StablePoseParams(settle_check=False, max_poses=2)
    transforms, probs = stable_poses(mesh, mass, parts, params, np.random.default_rng(0))
    assert len(probs) == 2 and probs.sum() == pytest.approx(1.0)
    # two slots go to the two most probable classes: the largest face first, then the middle one
    assert abs(up_vector(transforms[0])[2]) == pytest.approx(1.0)
    assert abs(up_vector(transforms[1])[1]) == pytest.approx(1.0)


def test_stable_poses_of_sphere_are_one_class():
    # 320 faces, each far below min_probability, but all one class (the centre rests at the same height)
    mesh, mass, parts = prepared(trimesh.creation.icosphere(2, 0.03))
    transforms, probs = stable_poses(mesh, mass, parts, POSES, np.random.default_rng(0))
    assert 1 <= len(probs) <= POSES.max_poses and probs.sum() == pytest.approx(1.0)
    for transform in transforms:
        assert trimesh.transform_points(mesh.vertices, transform)[:, 2].min() == pytest.approx(0.0, abs=1e-6)


def test_faceted_cylinder_keeps_its_side_poses():
    # 64 side facets of ~1 % each: one class that holds most of the probability, not dropped by the threshold
    mesh, mass, parts = prepared(trimesh.creation.cylinder(radius=0.025, height=0.06, sections=64))
    raw_t, raw_p = trimesh.poses.compute_stable_poses(mesh, center_mass=mass.center_of_mass, sigma=0.0, seed=0)
    side = np.abs(np.asarray(raw_t)[:, 2, 2]) < 1e-6  # cylinder axis horizontal
    assert raw_p[side].max() < POSES.min_probability < raw_p[side].sum()
    params = StablePoseParams(settle_check=False)
    transforms, probs = stable_poses(mesh, mass, parts, params, np.random.default_rng(0))
    lying = np.abs(transforms[:, 2, 2]) < 1e-6
    assert lying.any() and (~lying).any()
    assert probs[lying].sum() == pytest.approx(raw_p[side].sum() / raw_p.sum(), abs=1e-9)


@pytest.fixture(scope="module")
def thin_cylinder():
    """0.2 m tall, 1 cm radius: stands on its end only if placed exactly upright."""
    return prepared(trimesh.creation.cylinder(radius=0.01, height=0.2, sections=16))


def _with_extra_candidate(monkeypatch, normal, prob):
    original = trimesh.poses.compute_stable_poses

    def patched(mesh, **kwargs):
        transforms, probs = original(mesh, **kwargs)
        extra = resting_transform(mesh.convex_hull.vertices, kwargs["center_mass"], np.asarray(normal))
        return np.concatenate([extra[None], transforms]), np.concatenate([[prob], probs])

    monkeypatch.setattr(trimesh.poses, "compute_stable_poses", patched)


def test_thin_cylinder_lies_on_its_side(thin_cylinder):
    # the quasi-static analysis gives the end caps no probability: every pose is on a side facet
    mesh, mass, parts = thin_cylinder
    transforms, probs = stable_poses(mesh, mass, parts, POSES, np.random.default_rng(0))
    assert len(probs) == POSES.max_poses
    for transform in transforms:
        assert abs(up_vector(transform)[2]) < 1e-9  # mesh z (the axis) horizontal
        assert np.ptp(trimesh.transform_points(mesh.vertices, transform)[:, 2]) < 0.021


def _raw_candidates(mesh, mass, params):
    """Unsettled candidate probabilities at or above ``min_probability``."""
    _, probs = trimesh.poses.compute_stable_poses(mesh, center_mass=mass.center_of_mass, sigma=0.0, n_samples=1, seed=0)
    return probs[probs >= params.min_probability]


UNCAPPED = StablePoseParams(max_poses=64)


def test_leaning_cylinder_topples_and_merges_into_a_side_pose(thin_cylinder, monkeypatch):
    # A candidate leaning 20 degrees on its rim is not stable: the settle check replaces it by the side pose it
    # falls onto and adds its probability there; no new pose appears.
    mesh, mass, parts = thin_cylinder
    raw = _raw_candidates(mesh, mass, UNCAPPED)
    lean = 0.35
    _with_extra_candidate(monkeypatch, (math.sin(lean), 0.0, -math.cos(lean)), 0.5)
    transforms, probs = stable_poses(mesh, mass, parts, UNCAPPED, np.random.default_rng(0))
    assert probs.sum() == pytest.approx(1.0)
    for transform in transforms:
        assert abs(up_vector(transform)[2]) < 1e-9  # no leaning pose survives
    assert len(probs) == len(raw)
    total = 0.5 + raw.sum()
    merged_into = probs[0] * total - 0.5
    assert np.min(np.abs(raw - merged_into)) < 1e-9


def test_upright_cylinder_stays_standing(thin_cylinder, monkeypatch):
    # Placed exactly upright on its flat end the cylinder is in equilibrium and the settle check keeps it.
    mesh, mass, parts = thin_cylinder
    raw = _raw_candidates(mesh, mass, UNCAPPED)
    _with_extra_candidate(monkeypatch, (0.0, 0.0, -1.0), 0.5)
    transforms, probs = stable_poses(mesh, mass, parts, UNCAPPED, np.random.default_rng(0))
    # the upright candidate is kept, with the other end cap (same class: its centre rests as high)
    upright = np.array([abs(up_vector(t)[2]) > 1 - 1e-12 for t in transforms])
    assert len(probs) == len(raw) + upright.sum() and 1 <= upright.sum() <= 2
    np.testing.assert_allclose(up_vector(transforms[0]), (0.0, 0.0, 1.0), atol=1e-12)
    assert probs[upright].sum() >= 0.5 / (0.5 + raw.sum()) - 1e-12
    for transform in transforms[upright]:
        placed = trimesh.transform_points(mesh.vertices, transform)
        assert placed[:, 2].min() == pytest.approx(0.0, abs=1e-12)
        assert np.ptp(placed[:, 2]) == pytest.approx(0.2)


# ---------------------------------------------------------------------------------------------------------------
# prepare_object
# ---------------------------------------------------------------------------------------------------------------


def test_prepare_object_end_to_end_with_cache(tmp_path, monkeypatch):
    mesh = l_shape()
    mesh.apply_scale(1000.0)  # written in millimetres
    path = tmp_path / "ell.obj"
    mesh.export(path)
    cache = tmp_path / "cache"

    first = prepare_object(
        path, density=DENSITY, coacd=FAST_COACD, poses=POSES, rng=np.random.default_rng(1), coacd_cache_dir=cache
    )

    assert first.name == "ell" and first.source_path == str(path)
    assert first.scale == 0.001
    assert any("assumed millimetres" in w for w in first.warnings)
    assert first.vertices.dtype == np.float64 and first.faces.dtype == np.int32
    assert first.mass.volume == pytest.approx(L_VOLUME, rel=1e-6)  # manifold3d's union rounds to ~1e-8
    assert first.mass.mass == pytest.approx(DENSITY * first.mass.volume, rel=1e-12)
    assert len(first.convex_parts) >= 2
    assert first.stable_probabilities.sum() == pytest.approx(1.0)
    assert len(list(cache.glob("*.npz"))) == 1
    assert not list(cache.glob("*.tmp"))

    monkeypatch.setattr(coacd_process, "run_coacd", _fail)
    second = prepare_object(
        path, density=DENSITY, coacd=FAST_COACD, poses=POSES, rng=np.random.default_rng(1), coacd_cache_dir=cache
    )

    assert len(second.convex_parts) == len(first.convex_parts)
    for (v1, f1), (v2, f2) in zip(first.convex_parts, second.convex_parts, strict=True):
        assert v1.tobytes() == v2.tobytes() and f1.tobytes() == f2.tobytes()
    assert first.stable_transforms.tobytes() == second.stable_transforms.tobytes()
    assert first.stable_probabilities.tobytes() == second.stable_probabilities.tobytes()


def test_prepare_object_recomputes_over_a_corrupt_cache_entry(tmp_path):
    path = tmp_path / "ell.obj"
    l_shape().export(path)
    cache = tmp_path / "cache"
    first = prepare_object(
        path, density=DENSITY, coacd=FAST_COACD, poses=POSES, rng=np.random.default_rng(1), coacd_cache_dir=cache
    )
    (entry,) = cache.glob("*.npz")
    entry.write_bytes(b"not an npz")
    second = prepare_object(
        path, density=DENSITY, coacd=FAST_COACD, poses=POSES, rng=np.random.default_rng(1), coacd_cache_dir=cache
    )
    assert [v.tobytes() for v, _ in first.convex_parts] == [v.tobytes() for v, _ in second.convex_parts]


def test_prepare_object_reports_broken_file(tmp_path):
    path = tmp_path / "tower.obj"
    trimesh.creation.box((100.0, 100.0, 1000.0)).export(path)
    with pytest.raises(InputError, match=r"tower\.obj: absurd size"):
        prepare_object(path, density=DENSITY, rng=np.random.default_rng(0))


def test_parts_that_fill_a_cavity_are_refined():
    # A thin-walled cup: a coarse decomposition bridges the opening and fills the cavity, so a finger could not
    # go in; the refinement (a quarter of the threshold) keeps the parts close to the true volume.
    outer = trimesh.creation.cylinder(radius=0.03, height=0.06, sections=24)
    inner = trimesh.creation.cylinder(radius=0.027, height=0.06, sections=24)
    inner.apply_translation((0, 0, 0.004))
    cup = outer.difference(inner, engine="manifold")
    cup, _ = repair_mesh(cup)
    assert cup.is_watertight
    coarse = CoacdParams(threshold=0.2, max_convex_hull=4, resolution=300, mcts_iterations=10, refine_excess=0.0)

    def excess(parts):
        return sum(trimesh.Trimesh(v, f).volume for v, f in parts) / cup.volume - 1

    bridged = excess(convex_decomposition(cup, coarse))
    refined = excess(convex_decomposition(cup, dataclasses.replace(coarse, refine_excess=0.1)))
    assert bridged > 0.1 and refined < bridged
