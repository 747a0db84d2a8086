"""Procedural objects (graspgen.geometry.procedural) and their source in the objects stage."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from graspgen.errors import SettingsError
from graspgen.geometry.procedural import (
    FAMILIES,
    MIN_ASPECT,
    ProceduralParams,
    build_mesh,
    draw_shape,
    draw_shapes,
    shape_from_spec,
)
from graspgen.grippers import DEFAULT_GRIPPER, load_gripper
from graspgen.io.acronym import obj_text
from graspgen.io.objects import read_object
from pipeline.keys import canonical_json
from pipeline.plan import plan
from pipeline.stage import RunContext, Upstream
from stages.config import Config
from stages.objects import ObjectsParams, ObjectsStage, selected_objects

PARAMS = ProceduralParams(count=16, seed=7, size_range=(0.04, 0.1), max_grasp_width=0.055)


@pytest.fixture(scope="module")
def built():
    shapes = draw_shapes(PARAMS)
    return shapes, [build_mesh(s) for s in shapes]


def mesh_bytes(mesh) -> str:
    return obj_text(mesh.vertices, mesh.faces)


def test_every_object_is_a_light_watertight_solid_of_its_drawn_size(built):
    shapes, meshes = built
    assert [s.family for s in shapes] == [FAMILIES[i % 4] for i in range(16)]
    for shape, mesh in zip(shapes, meshes):
        assert mesh.is_watertight and mesh.is_winding_consistent, shape.name
        assert mesh.volume > 0 and len(mesh.faces) <= 3000, shape.name
        ext = np.sort(mesh.extents)
        np.testing.assert_allclose(mesh.extents, shape.extents, rtol=1e-12)
        np.testing.assert_allclose(mesh.bounds.mean(axis=0), 0.0, atol=1e-12)
        assert PARAMS.size_range[0] <= ext[2] <= PARAMS.size_range[1], shape.name
        assert MIN_ASPECT * ext[2] <= ext[0] <= ext[1] <= PARAMS.max_grasp_width, shape.name
        assert mesh.volume <= np.prod(ext) * (1 + 1e-9), shape.name  # inside its bounding box
    blobs = [m for s, m in zip(shapes, meshes) if s.family == "blob"]
    assert all(m.is_convex for m in blobs)
    assert any(not m.is_convex for s, m in zip(shapes, meshes) if s.family == "extrusion")  # star polygons


def test_default_sizes_fit_the_default_grippers():
    params = ProceduralParams()
    for gripper in (DEFAULT_GRIPPER, "panda"):
        assert params.max_grasp_width < load_gripper(gripper).max_width
    for shape in draw_shapes(dataclasses.replace(params, count=20)):
        assert sorted(shape.extents)[1] <= params.max_grasp_width


def test_ellipsoid_and_prism_volumes_match_their_formulas():
    """Independent truth: a superquadric with e1 = e2 = 1 is an ellipsoid (4/3 pi abc, less the icosphere's facet
    deficit, < 2%), an extrusion a prism (shoelace area x height, exact)."""
    shape = draw_shape(PARAMS, 0)
    ellipsoid = build_mesh(dataclasses.replace(shape, values={"e1": 1.0, "e2": 1.0}))
    a, b, c = np.asarray(shape.extents) / 2
    assert 0.98 < ellipsoid.volume / (4 / 3 * np.pi * a * b * c) <= 1.0
    prism_shape = draw_shape(PARAMS, 2)
    assert prism_shape.family == "extrusion"
    prism = build_mesh(prism_shape)
    angles, radii = np.asarray(prism_shape.values["angles"]), np.asarray(prism_shape.values["radii"])
    ring = np.column_stack([radii * np.cos(angles), radii * np.sin(angles)])
    scale = np.asarray(prism_shape.extents[:2]) / np.ptp(ring, axis=0)
    x, y = (ring * scale).T
    area = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    assert prism.volume == pytest.approx(area * prism_shape.extents[2], rel=1e-12)


def test_same_seed_same_bytes_and_another_seed_other_shapes(built):
    shapes, meshes = built
    again = [build_mesh(s) for s in draw_shapes(PARAMS)]
    assert [mesh_bytes(m) for m in again] == [mesh_bytes(m) for m in meshes]
    other = draw_shapes(dataclasses.replace(PARAMS, seed=8))
    assert all(o.spec()["values"] != s.spec()["values"] for o, s in zip(other, shapes))
    assert len({s.name for s in shapes + other}) == 32


def test_object_i_does_not_depend_on_count(built):
    shapes, meshes = built
    few = draw_shapes(dataclasses.replace(PARAMS, count=3))
    assert [s.spec() for s in few] == [s.spec() for s in shapes[:3]]
    late = draw_shape(dataclasses.replace(PARAMS, count=1), 13)
    assert late.spec() == shapes[13].spec() and mesh_bytes(build_mesh(late)) == mesh_bytes(meshes[13])


def test_spec_through_json_builds_the_same_bytes(built):
    shapes, meshes = built
    for shape, mesh in zip(shapes, meshes):
        back = shape_from_spec(json.loads(canonical_json(shape.spec())))
        assert mesh_bytes(build_mesh(back)) == mesh_bytes(mesh)


@pytest.mark.parametrize(("changes", "field"), [
    ({"count": 0}, "count"),
    ({"families": ()}, "families"),
    ({"families": ("blob", "cube")}, r"families\[1\]"),
    ({"families": ("blob", "blob")}, "families"),
    ({"seed": -1}, "seed"),
    ({"size_range": (0.1, 0.05)}, "size_range"),
    ({"size_range": (0.001, 0.05)}, "size_range"),
    ({"max_grasp_width": 0.02}, "max_grasp_width"),
    ({"max_grasp_width": -0.05}, "max_grasp_width"),
])
def test_bad_settings_name_the_field(changes, field):
    with pytest.raises(SettingsError, match=rf"^{field}: must"):
        ProceduralParams(**changes)


def test_config_rejects_objects_wider_than_the_grippers_open():
    Config(objects=ObjectsParams(procedural=ProceduralParams(max_grasp_width=0.079)))
    with pytest.raises(SettingsError, match=r"^objects.procedural.max_grasp_width: must be < the largest opening "
                                            r"of panda \(0.08 m"):
        Config(objects=ObjectsParams(procedural=ProceduralParams(max_grasp_width=0.081)))


def test_procedural_source_yields_keyed_tasks_without_files(tmp_path):
    params = ObjectsParams(bundled=False, procedural=ProceduralParams(count=5, seed=3))
    sources = selected_objects(params)
    assert [s.name for s in sources] == sorted(f"{FAMILIES[i % 4]}_s3_{i:05d}" for i in range(5))
    assert all(s.inputs() == () and s.payload()["procedural"] == s.shape.spec() for s in sources)
    upstream = Upstream(tmp_path, {})
    keys = {t.task.id: t.key for t in plan(ObjectsStage(), params, upstream)}
    assert keys == {t.task.id: t.key for t in plan(ObjectsStage(), params, upstream)}
    other = dataclasses.replace(params, procedural=ProceduralParams(count=5, seed=4))
    assert not set(keys.values()) & {t.key for t in plan(ObjectsStage(), other, upstream)}
    both = selected_objects(dataclasses.replace(params, bundled=True))
    assert {"box", "blob_s3_00001"} <= {s.name for s in both}


def test_procedural_task_prepares_the_object_the_same_bytes_twice(tmp_path):
    params = ObjectsParams(bundled=False, procedural=ProceduralParams(count=4, seed=1))
    task = next(t for t in ObjectsStage().tasks(params, Upstream(tmp_path, {})) if t.id.startswith("union"))
    ctx = RunContext(tmp_path, tmp_path / "cache")
    outs = []
    for k in range(2):
        out = tmp_path / f"o{k}.h5"
        meta = ObjectsStage().run(task, params, Upstream(tmp_path, {}), np.random.default_rng(5), out, ctx)
        outs.append(out.read_bytes())
    assert outs[0] == outs[1] and meta["stable_poses"] >= 1
    record = read_object(tmp_path / "o0.h5")
    mesh = build_mesh(shape_from_spec(task.payload["procedural"]))
    assert record.name == task.id and record.attrs["watertight"]
    assert record.attrs["source_file"] == f"{task.id}.obj" and record.attrs["scale"] == 1.0
    np.testing.assert_allclose(record.vertices, mesh.vertices, atol=0)
    assert record.attrs["volume"] == pytest.approx(mesh.volume, rel=1e-9)
    assert record.mass == pytest.approx(700.0 * mesh.volume, rel=1e-9)
