"""Checks for the bundled object set in ``assets/objects``.

The committed meshes must be clean, realistically sized and weighted solids,
and must be exactly what ``assets/make_objects.py`` produces.
"""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest
import trimesh

from tests.paths import REPO

ROOT = REPO
OBJECTS_DIR = ROOT / "assets" / "objects"
SCRIPT = ROOT / "assets" / "make_objects.py"
CATALOG = OBJECTS_DIR / "catalog.json"


def _load_catalog() -> list[dict]:
    with open(CATALOG, encoding="utf-8") as fh:
        return json.load(fh)


ENTRIES = _load_catalog()


def _load_builder():
    spec = importlib.util.spec_from_file_location("make_objects", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_catalog_format():
    names = [e["name"] for e in ENTRIES]
    assert len(names) >= 10
    assert names == sorted(names)
    assert len(set(names)) == len(names)
    for entry in ENTRIES:
        assert set(entry) == {"name", "file", "density", "description"}
        assert entry["file"] == f"{entry['name']}.obj"
        assert (OBJECTS_DIR / entry["file"]).is_file()
        assert 100.0 <= entry["density"] <= 8000.0
        assert entry["description"]
    text = CATALOG.read_text(encoding="utf-8")
    assert text == json.dumps(ENTRIES, sort_keys=True, indent=2) + "\n"


def test_no_stray_files():
    expected = {e["file"] for e in ENTRIES} | {"catalog.json"}
    assert {p.name for p in OBJECTS_DIR.iterdir()} == expected


def test_total_size_small():
    total = sum(p.stat().st_size for p in OBJECTS_DIR.iterdir())
    assert total < 2_000_000


@pytest.mark.parametrize("entry", ENTRIES, ids=[e["name"] for e in ENTRIES])
def test_mesh_is_valid_graspable_solid(entry):
    mesh = trimesh.load(OBJECTS_DIR / entry["file"], force="mesh")
    assert isinstance(mesh, trimesh.Trimesh)
    assert mesh.is_watertight
    assert mesh.is_winding_consistent
    assert mesh.body_count == 1
    assert mesh.volume > 0
    assert 4 <= len(mesh.faces) <= 3500
    # no degenerate faces
    assert mesh.area_faces.min() > 1e-12

    extents = mesh.extents
    assert 0.03 <= extents.max() <= 0.20
    assert extents.min() < 0.085

    mass = entry["density"] * mesh.volume
    assert 0.02 <= mass <= 3.0

    # documented origin convention: bbox centred in x/y, base on z = 0
    lo, hi = mesh.bounds
    np.testing.assert_allclose((lo[:2] + hi[:2]) / 2.0, 0.0, atol=1e-5)
    assert abs(lo[2]) < 1e-6


def test_builder_reproduces_committed_files(tmp_path):
    builder = _load_builder()
    catalog = builder.build_all(tmp_path)
    assert catalog == ENTRIES
    committed = sorted(p.name for p in OBJECTS_DIR.iterdir())
    generated = sorted(p.name for p in tmp_path.iterdir())
    assert generated == committed
    for name in committed:
        assert (tmp_path / name).read_bytes() == (OBJECTS_DIR / name).read_bytes(), name
