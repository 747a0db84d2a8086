"""graspgen.learn.sources: ACRONYM sets (FleX and cached sim labels), dataset folders, the split by object."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import trimesh

from graspgen.errors import InputError, SettingsError
from graspgen.io.acronym import write_acronym
from graspgen.learn import sources
from graspgen.learn.sources import ObjectGraspSet, acronym_sets, held_out, split_by_object


def _cube_file(tmp_path, name="Box_abc_0.5", n=6):
    mesh_dir = tmp_path / "meshes"
    mesh_dir.mkdir(exist_ok=True)
    trimesh.creation.box(extents=(0.08, 0.08, 0.08)).export(mesh_dir / "cube.obj")  # 0.5 scale: a 4 cm cube
    T = np.repeat(np.eye(4)[None], n, axis=0)
    T[:, 0, 3] = np.linspace(0.0, 0.05, n)  # sliding off the cube along x
    success = (np.arange(n) % 2).astype(np.int8)
    path = tmp_path / f"{name}.h5"
    write_acronym(path, T, success, object_file="meshes/cube.obj", object_scale=0.5, object_mass=0.1)
    return path, T, success


def test_acronym_flex_sets(tmp_path):
    path, T, success = _cube_file(tmp_path)
    (s,) = acronym_sets([tmp_path])
    assert s.name == "Box_abc_0.5" and s.group == "Box_abc" and s.source == "flex" and s.gripper == "panda"
    assert np.allclose(s.T_tcp, T) and s.label.tolist() == success.astype(bool).tolist()
    assert np.allclose(np.abs(s.vertices).max(), 0.02)  # scaled
    assert np.isclose(s.width[0], 0.04, atol=1e-6)  # the pads closed onto the 4 cm cube


def test_per_object_sample_is_fixed(tmp_path):
    _cube_file(tmp_path, n=20)
    a = acronym_sets([tmp_path], per_object=5, seed=3)[0]
    b = acronym_sets([tmp_path], per_object=5, seed=3)[0]
    c = acronym_sets([tmp_path], per_object=5, seed=4)[0]
    assert len(a.label) == 5 and np.array_equal(a.T_tcp, b.T_tcp) and not np.array_equal(a.T_tcp, c.T_tcp)


def test_acronym_errors_name_the_file(tmp_path):
    path, _, _ = _cube_file(tmp_path)
    (tmp_path / "meshes" / "cube.obj").unlink()
    with pytest.raises(InputError, match="cube.obj"):
        acronym_sets([path])
    bad = tmp_path / "junk.h5"
    bad.write_bytes(b"not hdf5")
    with pytest.raises(InputError, match="junk.h5"):
        acronym_sets([bad])


def test_sim_labels_are_cached_by_content(tmp_path, monkeypatch):
    path, _, _ = _cube_file(tmp_path, n=2)
    cache = tmp_path / "cache" / "labels"
    first = acronym_sets([path], labels="sim", cache_dir=cache)[0]
    assert first.source == "sim" and len(list(cache.glob("*.npz"))) == 1

    def no_sim(*a, **k):
        raise AssertionError("simulated again")

    monkeypatch.setattr("graspgen.workflows.evaluate.evaluate_grasps", no_sim)
    again = acronym_sets([path], labels="sim", cache_dir=cache)[0]
    assert np.array_equal(first.label, again.label)
    assert not any(p.name.endswith(".tmp") for p in cache.iterdir())


def _set(group, n=4):
    return ObjectGraspSet(name=group + "_1", group=group, vertices=np.zeros((3, 3)), faces=np.zeros((1, 3), int),
                          T_tcp=np.repeat(np.eye(4)[None], n, 0), width=np.zeros(n), label=np.zeros(n, bool),
                          gripper="panda", source="flex")


def test_split_keeps_groups_whole_and_follows_the_hash():
    sets = [_set(f"Mug_{i // 3}") for i in range(60)]  # three scales per mesh
    sets = [dataclasses.replace(s, name=f"{s.group}_{i}") for i, s in enumerate(sets)]
    train, valid = split_by_object(sets, 0.3, salt="x")
    tg, vg = {s.group for s in train}, {s.group for s in valid}
    assert not tg & vg and len(train) + len(valid) == 60
    assert all(held_out(g, 0.3, "x") for g in vg) and not any(held_out(g, 0.3, "x") for g in tg)
    import hashlib

    g = sets[0].group
    assert held_out(g, 0.3, "x") == (int(hashlib.sha256(("x" + g).encode()).hexdigest()[:8], 16) / 2**32 < 0.3)
    with pytest.raises(SettingsError, match="valid_fraction"):
        split_by_object(sets[:1], 0.3, salt="x")


def test_dataset_sets_read_a_folder(tmp_path, monkeypatch):
    import pyarrow as pa
    import pyarrow.parquet as pq

    root = tmp_path / "dataset"
    (root / "objects").mkdir(parents=True)
    poses = [np.eye(4).ravel().tolist()] * 3
    table = pa.table({"object_name": ["b", "a", "b"], "pose_object": poses, "width": [0.01, 0.02, 0.03],
                      "success": [True, False, True], "firm": [True, False, False], "gripper": ["panda"] * 3,
                      "protocol": ["acronym"] * 3})
    # b's set was made with the firm label; a's metadata predates the label (held)
    tasks = {"tasks": {"b": {"label": "firm", "friction": 0.5}, "a": {}}}
    table = table.replace_schema_metadata({b"graspgen.dataset": json.dumps(tasks).encode()})
    pq.write_table(table, root / "object_grasps.parquet")
    for n in ("a", "b"):
        (root / "objects" / f"{n}.h5").write_bytes(b"")
    box = trimesh.creation.box()  # 1 m^3
    rec = type("R", (), {"vertices": box.vertices, "faces": box.faces, "mass": 150.0, "attrs": {}})
    monkeypatch.setattr("graspgen.io.objects.read_object", lambda p: rec)
    a, b = sources.dataset_sets(tmp_path)
    assert (a.name, b.name) == ("a", "b") and b.width.tolist() == [0.01, 0.03] and b.label.tolist() == [True, False]
    assert a.group == "a" and a.source == "dataset"
    assert b.physics == {"label": "firm", "protocol": "acronym", "mass": 150.0, "density": pytest.approx(150.0),
                         "friction": 0.5}
    assert a.physics["label"] == "held" and a.physics["friction"] == 1.0
    _, held = sources.dataset_sets(tmp_path, "held")
    assert held.label.tolist() == [True, True] and held.physics["label"] == "held"
    (root / "objects" / "a.h5").unlink()
    with pytest.raises(InputError, match="a.h5"):
        sources.dataset_sets(root)


def test_the_physics_digest_covers_every_module_the_evaluate_path_runs():
    # Reference: the graspgen modules loaded after labelling real grasps (lazy, function-level imports included).
    # Each must be in the digest, or an edit to it would reuse stale labels.
    import subprocess
    import sys
    from pathlib import Path

    script = (
        "import sys, numpy as np, trimesh\n"
        "from graspgen.workflows.evaluate import evaluate_grasps\n"
        "from graspgen.workflows.evaluate_settings import EvaluateParams, CHEAP_COACD\n"
        "import tempfile, os\n"
        "d = tempfile.mkdtemp(); p = os.path.join(d, 'box.obj')\n"
        "trimesh.creation.box(extents=(0.04, 0.05, 0.06)).export(p)\n"
        "T = np.eye(4); T[:3, 2] = (0, 0, -1); T[:3, 1] = (0, -1, 0); T[2, 3] = 0.02\n"
        "evaluate_grasps(p, 1.0, T[None], None, 'panda', EvaluateParams(coacd=CHEAP_COACD), cache_dir=d)\n"
        "print('\\n'.join(m.__file__ for n, m in sys.modules.items() if n.startswith('graspgen') and "
        "getattr(m, '__file__', None)))\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True).stdout
    loaded = {Path(line).resolve() for line in out.split() if line.endswith(".py")}
    covered = set(sources.physics_modules())
    labels = {f for f in loaded if "learn" not in f.parts}  # what labels; not this caller
    assert labels and labels <= covered, sorted(str(f) for f in labels - covered)
    from graspgen.workflows import object_grasps

    assert Path(object_grasps.__file__).resolve() not in covered  # code the labels do not run


def test_the_physics_digest_ignores_docstrings_and_comments_but_not_code():
    before = b'"""Module."""\n\n\nclass P:\n    """Doc."""\n\n    force: float = 20.0\n    """N."""\n\n\n' \
             b'def f(x):\n    """Doc."""\n    return x * 2  # why\n'
    reworded = b'"""Another module text."""\n\nclass P:\n    force: float = 20.0\n    """Newtons, per pad."""\n\n' \
               b'def f(x):\n    return x*2\n'
    edited = before.replace(b"20.0", b"25.0")
    assert sources.code_digest_text(before) == sources.code_digest_text(reworded)
    assert sources.code_digest_text(before) != sources.code_digest_text(edited)
    assert sources.code_digest_text(b"def (:") == b"def (:"  # not Python: the bytes themselves
