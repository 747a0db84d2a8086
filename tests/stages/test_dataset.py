"""The dataset stage on the smoke config: the published layout, the join, the schema, byte-identical output across
workers and backends, ``gen validate``, ``gen report`` and the ACRONYM export."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from graspgen.io.card_render import render_card
from graspgen.io.contact_graspnet import scene_file
from graspgen.io.dataset_table import COLUMN_DOCS, REQUIRED_SCHEMA
from graspgen_cli.app import app
from pipeline.config import load_config, to_dict
from pipeline.keys import sha256_file
from pipeline.plan import committed
from pipeline.repro import shard_hashes
from pipeline.scheduler import run_pipeline
from pipeline.status import status
from pipeline.store import stage_dir
from stages.project import PROJECT
from tests.paths import REPO


def smoke(out, cache, *sets):
    return load_config(
        PROJECT.schema, "configs/smoke.yaml", [f"run.out={out}", f"run.cache_dir={cache}", "run.jobs=1", *sets]
    )


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """The smoke config run through the dataset stage with one worker: (root folder, config)."""
    root = tmp_path_factory.mktemp("dataset")
    cfg = smoke(root / "out", root / "cache")
    reports = run_pipeline(PROJECT, cfg)
    assert all(r.failed == 0 for r in reports), [r.failures for r in reports]
    return root, cfg


def invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def tables(out, stage):
    return {e.task: pq.read_table(stage_dir(out, stage) / e.file) for e in committed(out, stage).values()}


def keys(out, stage):
    return {e.task: e.key for e in committed(out, stage).values()}


def test_published_layout(run):
    root, _ = run
    d = root / "out" / "dataset"
    scenes = sorted(keys(root / "out", "scenes"))
    objects = sorted(keys(root / "out", "objects"))
    assert sorted(p.stem for p in (d / "scenes").glob("*.h5")) == scenes and len(scenes) == 3
    assert sorted(p.stem for p in (d / "objects").glob("*.h5")) == objects and len(objects) == 4
    for name in ("grasps.parquet", "card.md", "card.json", "config.yaml"):
        assert (d / name).is_file(), name
    # Only the dataset: the engine's shards and manifest of this stage live in OUT/shards/dataset.
    published = {"grasps.parquet", "object_grasps.parquet", "placed_grasps.parquet", "card.md", "card.json",
                 "config.yaml", "scenes", "objects", "acronym", "graspgen", "contact_graspnet", "plots", "probe"}
    assert {p.name for p in d.iterdir()} == published
    plots = {p.name for p in (d / "plots").glob("*.png")}
    assert plots == {"outcomes.png", "robustness.png", "epsilon.png", "correlation.png", "examples.png"}
    for png in (d / "plots").glob("*.png"):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with_sets = set(pq.read_table(d / "object_grasps.parquet", columns=["object_name"]).column(0).to_pylist())
    assert {p.stem for p in (d / "acronym").glob("*.h5")} == with_sets == set(objects)
    # The published shards are the shards themselves (hard links where the file system allows them).
    committed_scenes = committed(root / "out", "scenes")
    shard = stage_dir(root / "out", "scenes") / committed_scenes[keys(root / "out", "scenes")[scenes[0]]].file
    assert sha256_file(d / "scenes" / f"{scenes[0]}.h5") == sha256_file(shard)
    card = json.loads((d / "card.json").read_text())
    assert set(card["files"]) >= {"grasps.parquet", "config.yaml", *(f"plots/{p}" for p in plots)}
    assert set(card["stages"]) == {"objects", "object_grasps", "scenes", "grasps", "placed_grasps", "rollouts",
                                   "robustness", "metrics", "probe", "dataset"}
    assert card["stages"]["rollouts"]["keys"] == keys(root / "out", "rollouts")
    assert card["config"]["grasps"]["max_per_object"] == 8 and "run" not in card["config"]
    assert {"python", "numpy", "mujoco", "pyarrow", "graspgen"} <= set(card["versions"])


def test_rows_are_the_grasps_of_every_scene(run):
    root, _ = run
    out = root / "out"
    t = pq.read_table(out / "dataset" / "grasps.parquet")
    per_scene = {sid: len(g) for sid, g in tables(out, "grasps").items()}
    assert len(t) == sum(per_scene.values()) > 0
    card = json.loads((out / "dataset" / "card.json").read_text())
    assert card["counts"]["grasps"] == len(t)
    assert {s: v["grasps"] for s, v in card["scenes"].items()} == per_scene
    assert sum(o["grasps"] for o in card["outcomes"]) == len(t)
    assert sum(o["grasps"] for o in card["objects"].values()) == len(t)


def test_join_matches_every_stage_table(run):
    root, _ = run
    out = root / "out"
    t = pq.read_table(out / "dataset" / "grasps.parquet")
    rows = {(r["scene_id"], r["grasp_id"]): r for r in t.to_pylist()}
    rollout_keys = keys(out, "rollouts")
    for stage, columns in (
        ("grasps", {"object_name": "object_name", "width": "width", "pose_world": "pose_world"}),
        ("rollouts", {"outcome": "outcome", "outcome_name": "outcome_name", "contact_forces": "contact_forces"}),
        ("robustness", {"robustness": "robustness", "n": "robustness_n", "pfc": "pfc"}),
        ("metrics", {"epsilon": "epsilon", "friction": "epsilon_friction", "contact_source": "contact_source"}),
    ):
        for sid, table in tables(out, stage).items():
            for r in table.to_pylist():
                row = rows[(sid, r["grasp_id"])]
                for src, dst in columns.items():
                    a, b = r[src], row[dst]
                    if isinstance(a, float) and np.isnan(a):
                        assert np.isnan(b), (stage, sid, r["grasp_id"], dst)
                    else:
                        assert a == b, (stage, sid, r["grasp_id"], dst)
                assert row["source_key"] == rollout_keys[sid]


def test_schema_types_order_and_row_groups(run):
    root, _ = run
    path = root / "out" / "dataset" / "grasps.parquet"
    pf = pq.ParquetFile(path)
    schema = pf.schema_arrow
    assert schema.names[:4] == ["scene_id", "grasp_id", "object_name", "object_index"]
    for field in REQUIRED_SCHEMA:
        assert schema.field(field.name).type.equals(field.type), field.name
    for name in ("robustness", "robustness_lo", "robustness_hi", "pfc", "epsilon", "min_closure_friction"):
        assert schema.field(name).type == pa.float64()
    assert schema.field("robustness_n").type == pa.int32()
    for field in schema:  # every column documented, the known ones with our own words
        assert field.metadata[b"description"], field.name
        if field.name in COLUMN_DOCS:
            assert field.metadata[b"description"].decode() == COLUMN_DOCS[field.name]
    t = pf.read(columns=["scene_id", "grasp_id"])
    ids = list(zip(t.column(0).to_pylist(), t.column(1).to_pylist()))
    assert ids == sorted(set(ids))
    # every scene sits in one row group
    groups = {}
    for g in range(pf.num_row_groups):
        for sid in set(pf.read_row_group(g, columns=["scene_id"]).column(0).to_pylist()):
            groups.setdefault(sid, set()).add(g)
    assert all(len(v) == 1 for v in groups.values())


def test_same_bytes_for_one_and_two_workers_and_dask(run, tmp_path):
    pytest.importorskip("dask.distributed")
    root, _ = run
    reference = shard_hashes(root / "out")
    assert "dataset/dataset" in reference
    published = sha256_file(root / "out" / "dataset" / "grasps.parquet")
    for name, sets in (("two", ["run.jobs=2"]), ("dask", ["run.jobs=2", "run.backend=dask"])):
        reports = run_pipeline(PROJECT, smoke(tmp_path / name, root / "cache", *sets))
        assert all(r.failed == 0 for r in reports), name
        assert shard_hashes(tmp_path / name) == reference, name
        assert sha256_file(tmp_path / name / "dataset" / "grasps.parquet") == published, name
        for folder in ("acronym", "graspgen", "contact_graspnet"):  # the exports, file by file
            mine = {p.relative_to(root / "out").as_posix(): sha256_file(p)
                    for p in sorted((root / "out" / "dataset" / folder).rglob("*")) if p.is_file()}
            theirs = {p.relative_to(tmp_path / name).as_posix(): sha256_file(p)
                      for p in sorted((tmp_path / name / "dataset" / folder).rglob("*")) if p.is_file()}
            assert mine == theirs and mine, (name, folder)
        card = json.loads((tmp_path / name / "dataset" / "card.json").read_text())
        assert card == json.loads((root / "out" / "dataset" / "card.json").read_text()), name


def test_second_run_does_no_work_and_keeps_the_folder(run):
    root, cfg = run
    d = root / "out" / "dataset"
    before = {p: p.stat().st_mtime_ns for p in d.rglob("*") if p.is_file()}
    reports = run_pipeline(PROJECT, cfg)
    assert all(r.ran == 0 for r in reports)
    assert {p: p.stat().st_mtime_ns for p in d.rglob("*") if p.is_file()} == before


def test_validate_passes_then_names_the_damaged_file(run, tmp_path):
    root, _ = run
    ok = invoke("validate", root / "out")
    assert ok.exit_code == 0, ok.output
    assert "OK:" in ok.output
    copy = tmp_path / "copy"
    shutil.copytree(root / "out", copy)
    (entry,) = [e for e in committed(copy, "rollouts").values() if e.task == "scene_000001"]
    shard = stage_dir(copy, "rollouts") / entry.file
    data = bytearray(shard.read_bytes())
    data[len(data) // 2] ^= 0x01
    shard.write_bytes(bytes(data))
    scene = copy / "dataset" / "scenes" / "scene_000002.h5"
    data = bytearray(scene.read_bytes())
    data[-100] ^= 0x01
    scene.write_bytes(bytes(data))
    (copy / "dataset" / "plots" / "stray.png").write_bytes(b"x")
    bad = invoke("validate", copy)
    assert bad.exit_code == 1
    text = " ".join(bad.output.split())  # undo line wrapping
    assert f"{shard}: sha256 differs from the manifest's" in text
    assert f"{scene}: sha256 differs from card.json's" in text
    assert f"{copy / 'dataset' / 'plots' / 'stray.png'}: not part of the dataset" in text
    assert str(copy / "dataset" / "grasps.parquet") not in text  # intact files are not blamed


def test_validate_checks_the_schema(run, tmp_path):
    root, _ = run
    copy = tmp_path / "copy"
    shutil.copytree(root / "out" / "dataset", copy)
    path = copy / "grasps.parquet"
    t = pq.read_table(path)
    t = t.set_column(t.schema.get_field_index("outcome"), "outcome", t.column("outcome").cast(pa.int64()))
    path.unlink()  # a hard link: do not write through it into the shard
    pq.write_table(t, path)
    result = invoke("validate", copy)
    assert result.exit_code == 1
    text = " ".join(result.output.split())
    assert f"{path}: sha256 differs from card.json's" in text
    assert f"{path}: column 'outcome' is int64, expected int8" in text


def test_report_renders_the_same_card(run, tmp_path):
    root, _ = run
    copy = tmp_path / "copy"
    shutil.copytree(root / "out" / "dataset", copy)
    published = {p.relative_to(copy): p.read_bytes() for p in (copy / "plots").glob("*.png")}
    card_md, card_json = (copy / "card.md").read_text(), (copy / "card.json").read_text()
    (copy / "card.md").unlink()
    shutil.rmtree(copy / "plots")
    result = invoke("report", copy)
    assert result.exit_code == 0, result.output
    assert (copy / "card.md").read_text() == card_md
    assert (copy / "card.json").read_text() == card_json
    assert {p.relative_to(copy): p.read_bytes() for p in (copy / "plots").glob("*.png")} == published
    assert render_card(json.loads(card_json)) == card_md


def test_config_yaml_makes_the_same_config(run):
    root, cfg = run
    again = load_config(PROJECT.schema, root / "out" / "dataset" / "config.yaml")
    for f in dataclasses.fields(cfg):
        if f.name != "run":
            assert to_dict(getattr(again, f.name)) == to_dict(getattr(cfg, f.name)), f.name


def test_object_sets_are_the_stage_shards_one_after_the_other(run):
    root, cfg = run
    out = root / "out"
    for stage, by in (("object_grasps", "object_name"), ("placed_grasps", "scene_id")):
        published = pq.read_table(out / "dataset" / f"{stage}.parquet")
        shards = tables(out, stage)
        assert published.column_names == shards[next(iter(shards))].column_names
        expected = pa.concat_tables([shards[t] for t in sorted(shards)])
        assert json.dumps(published.to_pylist()) == json.dumps(expected.to_pylist()), stage  # NaN == NaN here
        assert published.column(by).to_pylist() == sorted(published.column(by).to_pylist())
    card = json.loads((out / "dataset" / "card.json").read_text())
    sets = card["object_sets"]
    got = pq.read_table(out / "dataset" / "object_grasps.parquet")
    for name, o in sets["objects"].items():
        rows = got.filter(pa.compute.equal(got.column("object_name"), name))
        assert o["label"] == "firm" and o["selection"] == "natural"  # the defaults
        assert o["positives"] == sum(rows.column("firm").to_pylist())
        assert o["positives"] + o["negatives"] == len(rows) and o["tried"] >= len(rows)
        assert sum(o["outcome_mix"].values()) == len(rows)
        assert o["outcome_mix"]["collision"] <= cfg.object_grasps.collision_share_of_negatives * o["negatives"]
    md = (out / "dataset" / "card.md").read_text()
    assert "Selection: natural" in md and "Positives by the `firm` label" in md
    assert f"Outcome mix of the {len(got)} kept grasps: firm {sum(got.column('firm').to_pylist())} (" in md
    placed = pq.read_table(out / "dataset" / "placed_grasps.parquet")
    assert sets["placed"]["grasps"] == len(placed)
    assert sets["placed"]["positives"] == sum(placed.column("success").to_pylist())


def test_acronym_export_is_the_object_sets_with_free_space_labels(run):
    from graspgen.io.acronym import read_acronym

    root, _ = run
    d = root / "out" / "dataset"
    t = pq.read_table(d / "object_grasps.parquet")
    names = np.asarray(t.column("object_name").to_pylist())
    for path in sorted((d / "acronym").glob("*.h5")):
        rows = t.take(pa.array(np.flatnonzero(names == path.stem)))
        acr = read_acronym(path)
        expected = np.asarray(rows.column("pose_object").combine_chunks().values).reshape(-1, 4, 4)
        np.testing.assert_allclose(acr.tcp_poses(), expected, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(acr.success, np.asarray(rows.column("success").to_pylist()))
        np.testing.assert_array_equal(acr.qualities["graspgen/grasp_id"], rows.column("grasp_id").to_numpy())
        assert acr.gripper == "panda"
        assert (d / "acronym" / acr.object_file).is_file()
        mesh = (d / "acronym" / acr.object_file).read_text().splitlines()
        assert sum(line.startswith("v ") for line in mesh) > 0


# ---------------------------------------------------------------------------------------------------------------
# The published folder heals: status names what run will repair, run repairs it, validate passes.

TABLE_STAGES = ("grasps", "rollouts", "robustness", "metrics")


def copy_run(src, dst):
    """A copy of a run folder that keeps its hard links: published shards stay links to the copied shards."""
    subprocess.run(["cp", "-a", str(src), str(dst)], check=True)


def flip_byte(path):
    """Change one byte in the middle of ``path`` in place: same size, same inode (a link writes into its shard)."""
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    with open(path, "r+b") as f:
        f.write(data)


def shard_of(out, stage, task):
    (entry,) = [e for e in committed(out, stage).values() if e.task == task]
    return stage_dir(out, stage) / entry.file


def states(cfg):
    return {s.stage: s.state for s in status(PROJECT, cfg)}


def status_text(out):
    result = CliRunner().invoke(app, ["status", "--out", str(out)], env={"COLUMNS": "250"})
    assert result.exit_code == 0, result.output
    return " ".join(result.output.replace("│", " ").split())


def test_contact_graspnet_export_is_the_placed_positives_of_every_scene(run):
    root, _ = run
    d = root / "out" / "dataset"
    cgn = d / "contact_graspnet"
    split = json.loads((cgn / "splits" / "scenes.json").read_text())
    files = sorted(p.name for p in (cgn / "scene_contacts").glob("*.npz"))
    assert files == split["files"] and files  # one per scene with a positive, held-out scenes last in name order
    assert files == sorted([scene_file(s, "train") for s in split["train"]] + [scene_file(s, "test")
                                                                                for s in split["test"]])
    assert len(split["test"]) == split["num_test_scenes"]
    assert sorted(split["train"] + split["test"] + list(split["left_out"])) == sorted(keys(root / "out", "scenes"))
    placed = pq.read_table(d / "placed_grasps.parquet", columns=["scene_id", "grasp_id", "success"]).to_pandas()
    card = json.loads((d / "card.json").read_text())
    for name in files:
        assert f"contact_graspnet/scene_contacts/{name}" in card["files"]
        z = np.load(cgn / "scene_contacts" / name, allow_pickle=False)
        rows = placed[placed.scene_id == str(z["scene_id"])]
        assert sorted([*z["grasp_ids"], *z["other_grasp_ids"]]) == sorted(rows.grasp_id)
        assert set(z["grasp_ids"]) <= set(rows.grasp_id[rows.success])
        for rel in z["obj_paths"]:
            assert (cgn / str(rel)).is_file() and f"contact_graspnet/{rel}" in card["files"]


CONTACT_GRASPNET_SOURCES = [os.environ.get("CONTACT_GRASPNET_SRC", ""), "/work/.mirror/NVlabs+contact_graspnet/repo"]
CONTACT_GRASPNET = next((s for s in CONTACT_GRASPNET_SOURCES if s and os.path.exists(s)), None)


@pytest.mark.skipif(CONTACT_GRASPNET is None, reason="Contact-GraspNet's source is not here: set CONTACT_GRASPNET_SRC "
                    "to a checkout (or bare git dir) of NVlabs/contact_graspnet")
def test_contact_graspnet_loads_the_export_with_its_own_code(run, tmp_path):
    """Contact-GraspNet's unmodified load_scene_contacts reads the smoke dataset's export; counts, poses, object
    placement and contacts agree with placed_grasps.parquet and the scene records (tools/check_contact_graspnet.py).
    A copy with its grasps moved by 1 mm fails the same check."""
    root, _ = run
    tool = [sys.executable, "tools/check_contact_graspnet.py", "--source", CONTACT_GRASPNET]
    ok = subprocess.run([*tool, str(root / "out" / "dataset"), "--json", str(tmp_path / "r.json")],
                        capture_output=True, text=True, cwd=REPO)
    assert ok.returncode == 0, ok.stdout + ok.stderr
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["files_loaded"] + len(report["left_out"]) == report["scenes"] == 3 and not report["failures"]
    assert {"pyrender", "cv2"} <= set(report["stubbed"]) or report["stubbed"] == []
    bad = tmp_path / "bad"
    shutil.copytree(root / "out" / "dataset", bad)
    moved = False
    for path in sorted((bad / "contact_graspnet" / "scene_contacts").glob("*.npz")):
        z = dict(np.load(path, allow_pickle=False))
        if len(z["grasp_transforms"]) or len(z["other_grasp_transforms"]):
            z["grasp_transforms"][:, :3, 3] += 0.001  # moved 1 mm along x, y and z
            z["other_grasp_ids"] = z["other_grasp_ids"][1:]  # and one row short
            moved = True
        path.unlink()
        np.savez(path, **z)
    assert moved
    failed = subprocess.run([*tool, str(bad)], capture_output=True, text=True, cwd=REPO)
    assert failed.returncode == 1 and "FAIL" in failed.stdout, failed.stdout + failed.stderr


def test_status_names_damaged_published_files_and_run_replaces_them(run, tmp_path):
    root, _ = run
    out = tmp_path / "out"
    copy_run(root / "out", out)
    cfg = smoke(out, root / "cache")
    assert set(states(cfg).values()) == {"done"}  # an untouched finished folder
    d = out / "dataset"
    scene = d / "scenes" / "scene_000002.h5"
    assert os.path.samefile(scene, shard_of(out, "scenes", "scene_000002"))
    flip_byte(scene)  # through the hard link: the scene shard is damaged too
    flip_byte(d / "grasps.parquet")  # and the dataset shard
    st = {s.stage: s for s in status(PROJECT, cfg)}
    assert st["scenes"].state == "missing"
    assert st["scenes"].reasons == ["1 task(s): its shard is missing or damaged (scene_000002)"]
    assert all(st[t].state == "done" for t in ("objects", *TABLE_STAGES))  # same keys after the remake
    assert st["dataset"].state == "missing"
    assert st["dataset"].reasons == [
        "1 task(s): its shard is missing or damaged (dataset)",
        "published: grasps.parquet damaged (will be replaced)",
        "published: scenes/scene_000002.h5 damaged (will be replaced)",
    ]
    text = status_text(out)
    assert "published: grasps.parquet damaged (will be replaced)" in text
    assert "published: scenes/scene_000002.h5 damaged (will be replaced)" in text
    reports = {r.stage: r for r in run_pipeline(PROJECT, cfg)}
    assert {s: r.ran for s, r in reports.items()} == {
        "objects": 0, "object_grasps": 0, "scenes": 1, "grasps": 0, "placed_grasps": 0, "rollouts": 0,
        "robustness": 0, "metrics": 0, "probe": 0, "dataset": 1,
    }
    assert reports["dataset"].repaired == [
        "replaced grasps.parquet (damaged)",
        "replaced scenes/scene_000002.h5 (damaged)",
    ]
    assert os.path.samefile(scene, shard_of(out, "scenes", "scene_000002"))  # linked to the remade shard
    assert os.path.samefile(d / "grasps.parquet", shard_of(out, "dataset", "dataset"))
    result = invoke("validate", out)
    assert result.exit_code == 0, result.output
    assert set(states(cfg).values()) == {"done"}
    again = run_pipeline(PROJECT, cfg)
    assert all(r.ran == 0 and not r.repaired for r in again)


def test_damaged_missing_and_stray_published_files_are_repaired(run, tmp_path):
    root, _ = run
    out = tmp_path / "out"
    copy_run(root / "out", out)
    cfg = smoke(out, root / "cache")
    d = out / "dataset"
    acronym = sorted((d / "acronym").glob("*.h5"))[0]
    acronym.unlink()
    flip_byte(d / "plots" / "outcomes.png")
    (d / "plots" / "stray.png").write_bytes(b"x")
    (d / "card.md").write_text("edited\n")
    st = {s.stage: s for s in status(PROJECT, cfg)}
    assert all(st[t].state == "done" for t in ("objects", "scenes", *TABLE_STAGES))
    assert st["dataset"].state == "damaged" and st["dataset"].done == 3  # grasps and the two object-set tables
    rel = acronym.relative_to(d).as_posix()
    assert st["dataset"].reasons == [
        f"published: {rel} missing (will be replaced)",
        "published: card.md damaged (will be replaced)",
        "published: plots/outcomes.png damaged (will be replaced)",
        "published: plots/stray.png not part of the dataset (will be removed)",
    ]
    reports = {r.stage: r for r in run_pipeline(PROJECT, cfg)}
    assert all(r.ran == 0 for r in reports.values())
    assert reports["dataset"].repaired == [
        f"replaced {rel} (missing)",
        "replaced card.md (damaged)",
        "replaced plots/outcomes.png (damaged)",
        "removed plots/stray.png (not part of the dataset)",
    ]
    result = invoke("validate", out)
    assert result.exit_code == 0, result.output
    assert set(states(cfg).values()) == {"done"}
    assert (d / "card.md").read_text() == (root / "out" / "dataset" / "card.md").read_text()
    # files rewritten with the same bytes (gen report) are intact: nothing to repair
    assert invoke("report", out).exit_code == 0
    assert set(states(cfg).values()) == {"done"}
    assert all(not r.repaired for r in run_pipeline(PROJECT, cfg))
    # the whole folder gone: made again
    shutil.rmtree(d)
    st = {s.stage: s for s in status(PROJECT, cfg)}
    assert st["dataset"].reasons == ["published: the folder will be made again (the folder is missing)"]
    reports = {r.stage: r for r in run_pipeline(PROJECT, cfg)}
    assert reports["dataset"].repaired == ["made the folder again (the folder is missing)"]
    assert invoke("validate", out).exit_code == 0


def test_a_damaged_shard_is_named_by_status_and_only_it_is_run_again(run, tmp_path):
    root, _ = run
    out = tmp_path / "out"
    copy_run(root / "out", out)
    cfg = smoke(out, root / "cache")
    shard = shard_of(out, "rollouts", "scene_000001")
    flip_byte(shard)
    st = {s.stage: s for s in status(PROJECT, cfg)}
    assert st["rollouts"].state == "missing" and st["rollouts"].missing == 1
    assert st["rollouts"].reasons == ["1 task(s): its shard is missing or damaged (scene_000001)"]
    assert all(st[t].state == "done" for t in ("objects", "scenes", "grasps", "robustness", "metrics", "dataset"))
    assert "its shard is missing or damaged (scene_000001)" in status_text(out)
    reports = {r.stage: r for r in run_pipeline(PROJECT, cfg)}
    assert {s: r.ran for s, r in reports.items() if r.ran} == {"rollouts": 1}
    assert not reports["dataset"].repaired
    assert set(states(cfg).values()) == {"done"}
    assert invoke("validate", out).exit_code == 0


def test_the_card_says_which_gripper_and_which_grasps_each_part_covers(run):
    root, _ = run
    card = json.loads((root / "out" / "dataset" / "card.json").read_text())
    md = render_card(card)
    assert card["object_sets"]["grippers"] == ["panda"] and card["counts"]["grippers"] == ["robotiq_2f85_mesh"]
    headline = md.split("\n")[2]
    assert "by the gripper robotiq_2f85_mesh" in headline and "of the gripper panda" in headline
    assert "pfc, the probability of force closure" in headline  # defined where it is first used
    assert "What covers what: `grasps.parquet` and the sections Outcomes, Per object, Scene grasps, Labels" in md
    table = md.index("| object | grasps | positives |")
    assert md.index("reached: whether") < table and md.index("near misses (`balanced`") < table
    assert "This split is the probe's own" in md and "| `contact_graspnet/` |" in md
    placed = dict(card["object_sets"]["placed"], rescene_checked=10, rescene_changed=3, rescene_change_rate=0.3,
                  rescene_lost=0.39, rescene_gained=0.1)
    text = render_card({**card, "object_sets": {**card["object_sets"], "placed": placed}})
    assert "positives lost 39%" in text and "not as picked up in that scene" in text


def test_the_card_lists_the_warnings(run):
    root, _ = run
    card = json.loads((root / "out" / "dataset" / "card.json").read_text())
    assert card["warnings"] == []  # the smoke objects are clean
    assert "## Warnings" not in render_card(card)
    card["warnings"] = ["objects: mug_mm: mug_mm.obj: largest extent 95.0 units, assumed millimetres [*]"]
    md = render_card(card)
    assert "## Warnings" in md
    assert "- objects: mug_mm: mug_mm.obj: largest extent 95.0 units, assumed millimetres \\[\\*\\]" in md
