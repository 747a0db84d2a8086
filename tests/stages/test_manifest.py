"""Object manifests (``objects.manifest``): the format and its errors, per-object settings in the shard and the
key, combining with bundled objects and ``objects.paths``, and per-object friction reaching the scenes."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from graspgen.errors import InputError, SettingsError
from graspgen.io.objects import MANIFEST_COLUMNS, ManifestEntry, read_object_manifest
from graspgen.io.scenes import read_scene
from graspgen.workflows.prepare import prepare_object
from graspgen.workflows.scenes import make_scene
from pipeline.config import load_config
from pipeline.errors import ConfigError
from pipeline.keys import rng_for_key
from pipeline.plan import committed, plan
from pipeline.scheduler import run_pipeline
from pipeline.stage import Upstream
from pipeline.status import status
from pipeline.store import stage_dir
from stages.objects import ASSETS, ObjectsParams, ObjectsStage, catalog, selected_objects
from stages.project import PROJECT

CHEAP = [
    "objects.coacd.threshold=0.2",
    "objects.coacd.resolution=300",
    "objects.coacd.mcts_iterations=10",
    "objects.coacd.preprocess_resolution=20",
    "objects.coacd.max_convex_hull=4",
    "objects.stable_poses.max_poses=4",
    "objects.stable_poses.settle_time=0.5",
]

HEADER = "path,name,scale,mass,density,friction,category"


@pytest.fixture
def meshes(tmp_path) -> Path:
    """A folder with a manifest's meshes: a 40 x 50 x 60 mm box in metres and a 30 x 30 x 80 mm box in mm."""
    d = tmp_path / "set"
    (d / "meshes").mkdir(parents=True)
    trimesh.creation.box((0.04, 0.05, 0.06)).export(d / "meshes" / "crate.obj")
    trimesh.creation.box((30.0, 30.0, 80.0)).export(d / "meshes" / "post_mm.stl")
    return d


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


# ---------------------------------------------------------------------------------------------------------------
# The format


def test_csv_and_yaml_manifests_read_the_same(meshes):
    csv = write(
        meshes / "objects.csv",
        f"{HEADER}\nmeshes/crate.obj,,,0.25,,0.6,box\n\nmeshes/post_mm.stl, post ,0.001,,1200,,tool\n",
    )
    yml = write(
        meshes / "objects.yaml",
        "- {path: meshes/crate.obj, mass: 0.25, friction: 0.6, category: box}\n"
        "- {path: meshes/post_mm.stl, name: post, scale: 1e-3, density: 1200, category: tool}\n",
    )
    expected = [
        ManifestEntry("crate", meshes / "meshes/crate.obj", 1, mass=0.25, friction=0.6, category="box"),
        ManifestEntry("post", meshes / "meshes/post_mm.stl", 2, scale=0.001, density=1200.0, category="tool"),
    ]
    assert read_object_manifest(csv) == expected
    assert read_object_manifest(yml) == expected
    # only the path column is required, in any column order
    only = write(meshes / "only.csv", "category,path\n,meshes/crate.obj\n")
    assert read_object_manifest(only) == [ManifestEntry("crate", meshes / "meshes/crate.obj", 1)]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            "path,colour\nmeshes/crate.obj,red\n",
            r"objects.csv: header \(line 1\): unknown column 'colour'; valid columns: " + ", ".join(MANIFEST_COLUMNS),
        ),
        ("name,mass\ncrate,1\n", r"objects.csv: header \(line 1\): no 'path' column"),
        (
            f"{HEADER}\nmeshes/crate.obj,,,,,0.5,\nmeshes/post_mm.stl,,,,,slippery,\n",
            r"objects.csv: row 2 \(line 3\), column 'friction': 'slippery' is not a number",
        ),
        (f"{HEADER}\nmeshes/crate.obj,,,-2,,,\n", r"row 1 \(line 2\), column 'mass': must be a finite number > 0"),
        (f"{HEADER}\nmeshes/crate.obj,,0,,,,\n", r"row 1 \(line 2\), column 'scale': must be a finite number > 0"),
        (f"{HEADER}\nmeshes/crate.obj,,,,nan,,\n", r"column 'density': must be a finite number > 0"),
        (f"{HEADER}\nmeshes/crate.obj,,,1,800,,\n", r"row 1 \(line 2\), columns 'mass' and 'density': give one"),
        (f"{HEADER}\nmeshes/nothing.obj,,,,,,\n", r"row 1 \(line 2\), column 'path': no such file: .*nothing.obj"),
        (f"{HEADER}\nmeshes,,,,,,\n", r"column 'path': is a folder, not a mesh file"),
        (f"{HEADER}\n,crate,,,,,\n", r"row 1 \(line 2\), column 'path': empty"),
        (
            f"{HEADER}\nmeshes/crate.obj,a,,,,,\nmeshes/post_mm.stl,a,,,,,\n",
            r"row 2 \(line 3\), column 'name': 'a' is already the name of row 1; names must be unique",
        ),
        (
            f"{HEADER}\nmeshes/crate.obj,,,,,,\nmeshes/crate.obj,,,,,,\n",
            r"row 2 \(line 3\), column 'name': 'crate' is already the name of row 1",
        ),
        (f"{HEADER}\nmeshes/crate.obj,a/b,,,,,\n", r"column 'name': 'a/b' must be a plain name"),
        (f"{HEADER}\nmeshes/crate.obj,,,,,,,extra\n", r"row 1 \(line 2\): 8 cells but the header names 7 columns"),
        ("path,path\nmeshes/crate.obj,meshes/crate.obj\n", r"column 'path' appears twice"),
        (f"{HEADER}\n", r"objects.csv: the object manifest lists no objects"),
    ],
)
def test_csv_errors_name_the_file_row_and_column(meshes, text, message):
    with pytest.raises(InputError, match=message):
        read_object_manifest(write(meshes / "objects.csv", text))


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("- {path: meshes/crate.obj, frction: 0.5}\n", r"objects.yaml: row 1: unknown column 'frction'; valid"),
        ("- {path: meshes/crate.obj}\n- {path: meshes/post_mm.stl, mass: heavy}\n", r"row 2, column 'mass': 'heavy'"),
        ("- {path: meshes/crate.obj, friction: true}\n", r"row 1, column 'friction': True is not a number"),
        ("- meshes/crate.obj\n", r"objects.yaml: row 1: must be a mapping with a path key"),
        ("{path: meshes/crate.obj}\n", r"objects.yaml: an object manifest must be a list of objects"),
        ("- {path: [a, b]}\n", r"row 1, column 'path': must be text"),
        ("- [unclosed\n", r"objects.yaml: not valid YAML"),
    ],
)
def test_yaml_errors_name_the_file_row_and_column(meshes, text, message):
    with pytest.raises(InputError, match=message):
        read_object_manifest(write(meshes / "objects.yaml", text))


def test_missing_or_unknown_manifest_files(tmp_path):
    with pytest.raises(InputError, match=r"nowhere.csv: object manifest not found"):
        read_object_manifest(tmp_path / "nowhere.csv")
    with pytest.raises(InputError, match=r"objects.json: an object manifest must be a CSV or YAML file"):
        read_object_manifest(write(tmp_path / "objects.json", "[]"))


# ---------------------------------------------------------------------------------------------------------------
# Combining with bundled objects and objects.paths; the config errors


def test_manifest_objects_join_bundled_and_paths_with_unique_names(meshes, tmp_path):
    manifest = write(meshes / "objects.csv", f"{HEADER}\nmeshes/crate.obj,,,0.25,,0.6,box\nmeshes/post_mm.stl,,,,,,\n")
    extra = tmp_path / "extra"
    extra.mkdir()
    trimesh.creation.box((0.05, 0.05, 0.05)).export(extra / "cube.obj")
    params = ObjectsParams(paths=(str(extra / "*.obj"),), manifest=str(manifest), densities={"post_mm": 900.0})
    sources = {s.name: s for s in selected_objects(params)}
    assert set(sources) == set(catalog()) | {"cube", "crate", "post_mm"}
    assert (sources["crate"].mass, sources["crate"].density, sources["crate"].friction) == (0.25, None, 0.6)
    assert (sources["post_mm"].density, sources["post_mm"].friction) == (900.0, None)  # densities still apply
    assert sources["cube"].density == 700.0 and sources["cube"].friction is None
    only = {s.name for s in selected_objects(ObjectsParams(manifest=str(manifest), include=("crate", "box")))}
    assert only == {"crate", "box"}

    clash = write(meshes / "clash.csv", f"{HEADER}\nmeshes/crate.obj,box,,,,,\n")
    with pytest.raises(
        ConfigError,
        match=r"objects.manifest: .*clash.csv: row 1, column 'name': the name 'box' is "
        r"already taken by .*box.obj \(bundled\); names must be unique",
    ):
        selected_objects(ObjectsParams(manifest=str(clash)))
    with pytest.raises(ConfigError, match=r"the name 'cube' is already taken by .*cube.obj \(objects.paths\)"):
        selected_objects(
            ObjectsParams(
                paths=(str(extra / "*.obj"),),
                manifest=str(write(meshes / "clash2.csv", f"{HEADER}\nmeshes/crate.obj,cube,,,,,\n")),
            )
        )
    with pytest.raises(ConfigError, match=r"^objects.manifest: .*bad.csv: row 1 \(line 2\), column 'friction'"):
        selected_objects(ObjectsParams(manifest=str(write(meshes / "bad.csv", f"{HEADER}\nmeshes/crate.obj,,,,,x,\n"))))


def test_gen_run_reports_a_bad_manifest_in_one_line(meshes, tmp_path):
    write(meshes / "objects.csv", f"{HEADER}\nmeshes/crate.obj,,,,,0.5,\nmeshes/post_mm.stl,,,heavy,,,\n")
    exe = Path(sys.executable).with_name("gen")
    for manifest, message in [
        (
            "objects.csv",
            "error: objects.manifest: objects.csv: row 2 (line 3), column 'mass': 'heavy' is not a number (kg)",
        ),
        ("gone.yaml", "error: objects.manifest: gone.yaml: object manifest not found"),
    ]:
        result = subprocess.run(
            [str(exe), "run", "objects", "--out", str(tmp_path / "o"), "--set", f"objects.manifest={manifest}"],
            capture_output=True, text=True, cwd=meshes, env={**os.environ, "COLUMNS": "200"}, timeout=120,
        )  # fmt: skip
        assert result.returncode == 2, result.stdout + result.stderr
        assert result.stderr.strip() == message


def test_objects_without_own_settings_keep_their_task_payload():
    """The payload (and so the key) of an object without manifest settings is what it was before manifests."""
    (task,) = ObjectsStage().tasks(ObjectsParams(include=("box",)), None)
    box = catalog()["box"]
    assert task.payload == {"density": float(box["density"]), "suffix": Path(box["file"]).suffix.lower()}
    assert task.inputs == (str(ASSETS / box["file"]),)


def test_a_changed_row_makes_only_its_object_stale(meshes):
    def keys(friction: str) -> dict[str, str]:
        manifest = write(
            meshes / "objects.csv", f"{HEADER}\nmeshes/crate.obj,,,,,{friction},\nmeshes/post_mm.stl,,,,,,\n"
        )
        params = ObjectsParams(bundled=False, manifest=str(manifest))
        return {p.task.id: p.key for p in plan(ObjectsStage(), params, Upstream(meshes, {}))}

    before, after = keys("0.6"), keys("0.7")
    assert before["post_mm"] == after["post_mm"]
    assert before["crate"] != after["crate"]
    assert keys("0.6") == before


# ---------------------------------------------------------------------------------------------------------------
# Mass from a given mass


def test_prepare_object_with_a_mass_weighs_exactly_that(tmp_path):
    path = tmp_path / "slab.obj"
    trimesh.creation.box((0.1, 0.05, 0.02)).export(path)
    rng = np.random.default_rng(0)
    prepared = prepare_object(path, mass=0.3, rng=rng)
    a, b, c = 0.1, 0.05, 0.02
    assert prepared.mass.mass == pytest.approx(0.3, rel=1e-12)
    assert prepared.mass.mass / prepared.mass.volume == pytest.approx(0.3 / (a * b * c), rel=1e-9)
    np.testing.assert_allclose(np.diag(prepared.mass.inertia), 0.3 / 12 * np.array([b*b + c*c, a*a + c*c, a*a + b*b]),
                               rtol=1e-9)  # fmt: skip
    with pytest.raises(SettingsError, match="density, mass: give exactly one"):
        prepare_object(path, mass=0.3, density=500.0, rng=rng)
    with pytest.raises(SettingsError, match="density, mass: give exactly one"):
        prepare_object(path, rng=rng)
    with pytest.raises(SettingsError, match=r"mass: must be in \(0, inf\)"):
        prepare_object(path, mass=-1.0, rng=rng)


# ---------------------------------------------------------------------------------------------------------------
# Through the engine: the shard's attributes, staleness, and friction in the scenes


def _config(out: Path, manifest: Path, *sets: str):
    return load_config(
        PROJECT.schema,
        None,
        [
            f"run.out={out}",
            f"run.cache_dir={out.parent / 'cache'}",
            "run.jobs=1",
            "objects.bundled=false",
            f"objects.manifest={manifest}",
            *CHEAP,
            "scenes.num_scenes=2",
            "scenes.choice=fixed",
            "scenes.objects=[crate, post]",
            "scenes.friction=[0.3, 0.9]",
            "scenes.cameras.render=false",
            "scenes.cameras.num_views=1",
            *sets,
        ],
    )


def _shard(out: Path, stage: str, task: str) -> Path:
    (entry,) = [e for e in committed(out, stage).values() if e.task == task]
    return stage_dir(out, stage) / entry.file


def test_manifest_settings_reach_the_shards_and_the_scenes(meshes, tmp_path):
    from graspgen.io.objects import read_object

    own = write(meshes / "own.csv", f"{HEADER}\nmeshes/crate.obj,,,0.25,,0.37,box\nmeshes/post_mm.stl,post,0.001,,,,\n")
    out = tmp_path / "own"
    reports = {r.stage: r for r in run_pipeline(PROJECT, _config(out, own), ["scenes"])}
    assert (reports["objects"].ran, reports["scenes"].ran, reports["scenes"].failed) == (2, 2, 0)

    crate = read_object(_shard(out, "objects", "crate"))
    assert crate.mass == pytest.approx(0.25, rel=1e-9)
    assert crate.attrs["density"] == pytest.approx(0.25 / (0.04 * 0.05 * 0.06), rel=1e-9)
    assert (crate.attrs["friction"], crate.friction, crate.category) == (0.37, 0.37, "box")
    post = read_object(_shard(out, "objects", "post"))
    assert post.attrs["scale"] == 0.001 and not any("millimetres" in w for w in post.attrs["warnings"])
    assert np.ptp(post.vertices[:, 2]) == pytest.approx(0.08, rel=1e-6)
    assert post.mass == pytest.approx(700.0 * 0.03 * 0.03 * 0.08, rel=1e-9)  # objects.density
    assert "friction" not in post.attrs and "category" not in post.attrs and post.friction is None

    # The object's own friction wins in every scene; the other's is drawn from scenes.friction.
    drawn = {}
    for sid in ("scene_000000", "scene_000001"):
        scene = read_scene(_shard(out, "scenes", sid))
        mu = dict(zip(scene.object_names, scene.friction))
        assert mu["crate"] == 0.37
        assert 0.3 <= mu["post"] <= 0.9
        drawn[sid] = (mu["post"], scene.tree["objects"]["placed_poses"])

    # The same draws without the crate's own friction (the scene's rng as the engine seeds it): the crate gets its
    # drawn friction, and everything else drawn is what it was (the own friction replaces a draw, it skips none).
    records = {"crate": crate, "post": post}
    bare = {
        **records,
        "crate": dataclasses.replace(crate, attrs={k: v for k, v in crate.attrs.items() if k != "friction"}),
    }
    params = _config(out, own).scenes
    for sid, (mu_post, placed) in drawn.items():
        seed = next(e.seed for e in committed(out, "scenes").values() if e.task == sid)
        made = {
            name: make_scene(sid, params, ["crate", "post"], recs.__getitem__, lambda n: "k", rng_for_key(seed)).tree
            for name, recs in (("own", records), ("bare", bare))
        }
        np.testing.assert_array_equal(made["own"]["objects"]["placed_poses"], placed)  # as the engine made it
        np.testing.assert_array_equal(made["bare"]["objects"]["placed_poses"], placed)
        mu = dict(zip(made["bare"]["@attrs"]["object_names"], made["bare"]["objects"]["friction"]))
        assert mu["crate"] != 0.37 and 0.3 <= mu["crate"] <= 0.9
        assert mu["post"] == mu_post

    # The manifest edited in place (its path is a param: moving it makes every object stale), the crate's friction
    # dropped: gen status says only the crate is stale, and the scenes wait for it.
    write(own, f"{HEADER}\nmeshes/crate.obj,,,0.25,,,box\nmeshes/post_mm.stl,post,0.001,,,,\n")
    rows = {s.stage: s for s in status(PROJECT, _config(out, own), ["scenes"])}
    assert (rows["objects"].state, rows["objects"].done, rows["objects"].missing) == ("stale", 1, 1)
    assert rows["objects"].reasons == ["1 task(s): the task definition changed"]
    assert rows["scenes"].state == "waiting"
