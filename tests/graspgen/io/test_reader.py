"""The public reader on a published smoke dataset: filters, a grasp's view and cloud, samples, pyarrow alone, the
PyTorch adapter (with a stand-in torch), and the README's example."""

from __future__ import annotations

import os
import pickle
import re
import subprocess
import sys
import textwrap
import types

import numpy as np
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
import trimesh
from scipy.spatial import cKDTree

from graspgen.errors import InputError, NotFoundError, SettingsError
from graspgen.io.reader import Grasp, open_dataset
from pipeline.config import load_config
from pipeline.scheduler import run_pipeline
from stages.project import PROJECT
from tests.paths import REPO

ROOT = REPO


@pytest.fixture(scope="module")
def out(tmp_path_factory):
    root = tmp_path_factory.mktemp("reader")
    cfg = load_config(
        PROJECT.schema,
        "configs/smoke.yaml",
        [f"run.out={root / 'out'}", f"run.cache_dir={root / 'cache'}", "run.jobs=2"],
    )
    reports = run_pipeline(PROJECT, cfg)
    assert all(r.failed == 0 for r in reports), [r.failures for r in reports]
    return root / "out"


def test_open_finds_the_folder_and_reads_lazily(out):
    ds = open_dataset(out)
    assert ds.root == out / "dataset" and open_dataset(out / "dataset").root == ds.root
    assert len(ds) == pq.ParquetFile(out / "dataset" / "grasps.parquet").metadata.num_rows > 0
    assert ds.scene_ids == ["scene_000000", "scene_000001", "scene_000002"]
    assert ds.card["counts"]["grasps"] == len(ds)
    assert ds.schema.field("epsilon").metadata[b"description"]
    with pytest.raises(InputError, match="no published dataset"):
        open_dataset(out / "scenes")


def test_filters(out):
    ds = open_dataset(out)
    everything = ds.grasps(columns=["outcome", "object_name", "robustness"])
    outcome = everything.column("outcome").to_numpy()
    by_name = ds.grasps(outcome="success", columns=["grasp_id", "outcome"])
    by_code = ds.grasps(outcome=5, columns=["grasp_id", "outcome"])
    assert by_name.equals(by_code) and len(by_name) == int((outcome == 5).sum()) > 0
    assert set(by_name.column("outcome").to_pylist()) == {5}
    two = ds.grasps(outcome=["success", "slipped_during_lifting"], object_name=["box", "wedge"], columns=["outcome"])
    names = np.asarray(everything.column("object_name").to_pylist())
    assert len(two) == int(((outcome >= 4) & np.isin(names, ["box", "wedge"])).sum())
    robust = ds.grasps(filter=pc.field("robustness") >= 0.3, columns=["robustness"])
    r = everything.column("robustness").to_numpy()
    assert len(robust) == int(np.sum(r >= 0.3)) > 0
    with pytest.raises(KeyError, match="no column 'nope'"):
        ds.grasps(nope=1)
    # pandas, when installed, from the same call
    pd = pytest.importorskip("pandas")
    assert isinstance(by_name.to_pandas(), pd.DataFrame)


def test_a_grasp_its_view_and_its_point_cloud(out):
    ds = open_dataset(out)
    successes = ds.grasps(outcome="success", columns=["scene_id", "grasp_id"]).to_pylist()
    nearest = []
    for row in successes:
        g = ds.grasp(row["scene_id"], row["grasp_id"])
        assert isinstance(g, Grasp) and g.outcome == 5 and g["outcome_name"] == "success"
        assert g.pose_world.shape == (4, 4) and g.contact_points.shape[1] == 3
        scene = ds.scene(g.scene_id)
        assert scene.object_names[g.object_index] == g.object_name
        np.testing.assert_allclose(scene.poses[g.object_index] @ g.pose_object, g.pose_world, atol=1e-9)
        view = ds.view(g.scene_id, 0)
        assert view.rgb.shape == (view.height, view.width, 3) and view.depth.shape == (view.height, view.width)
        points, ids = view.cloud("world")
        target = points[ids == g.object_index].astype(np.float64)
        assert len(target) > 20
        # The object's points lie on its mesh, placed by the scene pose.
        vertices, faces = ds.object_mesh(g.object_name)
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        mesh.apply_transform(scene.poses[g.object_index])
        assert np.abs(trimesh.proximity.signed_distance(mesh, target)).max() < 5e-4
        # The grasp's contacts lie on the seen object: the nearer one next to its points (the other may be hidden).
        T = scene.poses[g.object_index]
        contacts = np.array([g.contact1, g.contact2]) @ T[:3, :3].T + T[:3, 3]
        nearest.append(cKDTree(target).query(contacts)[0].min())
        # The camera frame agrees with the world frame.
        cam, _ = view.cloud("camera")
        back = cam.astype(np.float64) @ view.T_world_camera[:3, :3].T + view.T_world_camera[:3, 3]
        np.testing.assert_allclose(back, points, atol=1e-5)
        assert np.all(cam[:, 2] > 0)
    assert np.median(nearest) < 0.006 and max(nearest) < 0.03, nearest
    with pytest.raises(SettingsError, match=r"view: must be in \[0, 1\) for scene_\d+, got 1"):
        ds.view(g.scene_id, ds.scene(g.scene_id).num_views)
    with pytest.raises(SettingsError, match="frame: must be 'world' or 'camera', got 'base'"):
        view.cloud("base")
    with pytest.raises(NotFoundError, match="no scene 'nope'") as caught:
        ds.scene("nope")
    assert isinstance(caught.value, KeyError)


def test_samples_cover_each_scene_view_once(out):
    ds = open_dataset(out)
    samples = list(ds.samples(outcome="success", columns=["robustness"]))
    expected = ds.grasps(outcome="success", columns=["scene_id"]).column(0).to_pylist()
    assert [s.scene_id for s in samples] == sorted(set(expected))  # one view per scene in the smoke config
    assert sum(len(s.grasps) for s in samples) == len(expected)
    for s in samples:
        assert set(s.grasps.column("scene_id").to_pylist()) == {s.scene_id}
        assert "robustness" in s.grasps.column_names
        world, camera = s.poses("world"), s.poses("camera")
        np.testing.assert_allclose(s.view.T_world_camera @ camera, world, atol=1e-9)
    assert len(list(ds.samples(views=[0], scene_id="scene_000001"))) == 1


_BLOCK = """
import importlib.abc, sys
class _Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in ("pandas", "torch"):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
sys.meta_path.insert(0, _Block())
"""


def _python(code, **env):
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, env={**os.environ, **env}, timeout=120
    )


def test_works_with_pyarrow_alone(out):
    code = _BLOCK + textwrap.dedent(
        f"""
        from graspgen.io.reader import open_dataset
        ds = open_dataset({str(out)!r})
        t = ds.grasps(outcome="success", columns=["scene_id", "grasp_id"])
        g = ds.grasp(t["scene_id"][0].as_py(), t["grasp_id"][0].as_py())
        points, ids = ds.view(g.scene_id, 0).cloud()
        n = sum(len(s.grasps) for s in ds.samples(outcome="success"))
        try:
            ds.torch_dataset()
        except ImportError as exc:
            print("no torch:", exc)
        print(len(t), n, len(points), "pandas" in sys.modules, "torch" in sys.modules, "mujoco" in sys.modules)
        """
    )
    result = _python(code)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.split("\n")
    assert lines[0].startswith("no torch: ") and "pip install 'graspgen[torch]'" in lines[0]
    n, m, points, *flags = lines[1].split()
    assert int(n) == int(m) > 0 and int(points) > 0
    assert flags == ["False", "False", "False"]  # no pandas, no torch, no MuJoCo needed


@pytest.fixture
def fake_torch(monkeypatch):
    """A stand-in for torch with what the adapter uses (Dataset, from_numpy), when torch is not installed."""
    import graspgen.io.reader as reader

    if "torch" not in sys.modules:
        try:
            import torch  # noqa: F401
        except ImportError:
            torch = types.ModuleType("torch")
            torch.from_numpy = lambda a: a
            torch.utils = types.ModuleType("torch.utils")
            torch.utils.data = types.ModuleType("torch.utils.data")
            torch.utils.data.Dataset = type("Dataset", (), {})
            monkeypatch.setitem(sys.modules, "torch", torch)
            monkeypatch.setitem(sys.modules, "torch.utils", torch.utils)
            monkeypatch.setitem(sys.modules, "torch.utils.data", torch.utils.data)
    monkeypatch.delitem(reader.__dict__, "TorchDataset", raising=False)
    yield sys.modules["torch"]
    reader.__dict__.pop("TorchDataset", None)


def test_torch_adapter(out, fake_torch):
    import graspgen.io.reader as reader

    ds = open_dataset(out)
    tds = ds.torch_dataset(labels=("outcome", "robustness", "nope"), outcome="success")
    assert isinstance(tds, fake_torch.utils.data.Dataset) and isinstance(tds, reader.TorchDataset)
    assert len(tds) == len(set(ds.grasps(outcome="success", columns=["scene_id"]).column(0).to_pylist()))
    item = tds[0]
    n = len(ds.grasps(outcome="success", scene_id=item["scene_id"], columns=["grasp_id"]))
    assert tuple(item["poses"].shape) == (n, 4, 4) and tuple(item["outcome"].shape) == (n,)
    assert "nope" not in item and tuple(item["points"].shape)[1] == 3
    assert np.all(np.asarray(item["outcome"]) == 5)
    view = ds.view(item["scene_id"], item["view"])
    np.testing.assert_allclose(np.asarray(item["points"]), view.cloud("camera")[0], atol=1e-6)
    again = pickle.loads(pickle.dumps(tds))  # what a DataLoader worker gets
    np.testing.assert_array_equal(np.asarray(again[0]["poses"]), np.asarray(item["poses"]))


def test_torch_adapter_without_torch_says_how_to_install_it(out, monkeypatch):
    import graspgen.io.reader as reader
    from graspgen.errors import GraspGenError

    monkeypatch.setitem(sys.modules, "torch", None)  # absent, whether or not it is installed: import raises
    monkeypatch.delitem(reader.__dict__, "TorchDataset", raising=False)
    ds = open_dataset(out)
    for make in (ds.torch_dataset, lambda: reader.TorchDataset):
        with pytest.raises(ImportError) as info:
            make()
        assert all(isinstance(info.value, t) for t in (reader.TorchMissingError, GraspGenError, ModuleNotFoundError))
        assert info.value.name == "torch" and info.value.__cause__ is None
        assert "needs torch, which is not installed: pip install 'graspgen[torch]'" in str(info.value)
    assert "TorchDataset" not in reader.__dict__


def test_readme_reader_example_runs(out):
    readme = (ROOT / "README.md").read_text()
    section = readme.split("## Reading a dataset", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    result = _python(code, OUT=str(out))
    assert result.returncode == 0, result.stderr
    assert "grasps" in result.stdout
