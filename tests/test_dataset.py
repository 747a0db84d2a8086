"""The dataset stage on the smoke config: the published layout, the join, the schema, byte-identical output across
workers and backends, ``gen validate``, ``gen report`` and the ACRONYM export."""

from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from graspgen_cli.app import PROJECT, app
from pipeline.config import load_config, to_dict
from pipeline.errors import StageError
from pipeline.keys import sha256_file
from pipeline.repro import shard_hashes
from pipeline.scheduler import committed, run_pipeline
from stages.dataset import (
    COLUMN_DOCS,
    REQUIRED_SCHEMA,
    join_scene,
    label_summary,
    render_card,
    write_grasps_parquet,
)


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
    return {e.task: pq.read_table(out / stage / e.file) for e in committed(out, stage).values()}


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
    plots = {p.name for p in (d / "plots").glob("*.png")}
    assert plots == {"outcomes.png", "robustness.png", "epsilon.png", "correlation.png", "examples.png"}
    for png in (d / "plots").glob("*.png"):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with_grasps = set(pq.read_table(d / "grasps.parquet", columns=["object_name"]).column(0).to_pylist())
    assert {p.stem for p in (d / "acronym").glob("*.h5")} == with_grasps
    # The published shards are the shards themselves (hard links where the file system allows them).
    shard = root / "out" / "scenes" / committed(root / "out", "scenes")[keys(root / "out", "scenes")[scenes[0]]].file
    assert sha256_file(d / "scenes" / f"{scenes[0]}.h5") == sha256_file(shard)
    card = json.loads((d / "card.json").read_text())
    assert set(card["files"]) >= {"grasps.parquet", "config.yaml", *(f"plots/{p}" for p in plots)}
    assert set(card["stages"]) == {"objects", "scenes", "grasps", "rollouts", "robustness", "metrics", "dataset"}
    assert card["stages"]["rollouts"]["keys"] == keys(root / "out", "rollouts")
    assert card["config"]["grasps"]["max_per_object"] == 24 and "run" not in card["config"]
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
    shard = copy / "rollouts" / entry.file
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
    shutil.copytree(root / "out" / "dataset", copy, ignore=shutil.ignore_patterns("manifest.jsonl", "??"))
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


def test_acronym_export_round_trips_the_poses(run):
    from graspgen.io.acronym import read_acronym

    root, _ = run
    d = root / "out" / "dataset"
    t = pq.read_table(d / "grasps.parquet")
    names = np.asarray(t.column("object_name").to_pylist())
    for path in sorted((d / "acronym").glob("*.h5")):
        rows = t.take(pa.array(np.flatnonzero(names == path.stem)))
        acr = read_acronym(path)
        expected = np.asarray(rows.column("pose_object").combine_chunks().values).reshape(-1, 4, 4)
        np.testing.assert_allclose(acr.tcp_poses(), expected, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(acr.success, rows.column("outcome").to_numpy() == 5)
        np.testing.assert_array_equal(acr.qualities["graspgen/grasp_id"], rows.column("grasp_id").to_numpy())
        np.testing.assert_array_equal(acr.qualities["graspgen/robustness"], rows.column("robustness").to_numpy())
        assert acr.gripper == "robotiq_2f85"
        assert (d / "acronym" / acr.object_file).is_file()
        mesh = (d / "acronym" / acr.object_file).read_text().splitlines()
        assert sum(line.startswith("v ") for line in mesh) > 0


# --------------------------------------------------------------------------------------------------------------
# Units


def _table(sid, ids, **cols):
    arrays = {"scene_id": pa.array([sid] * len(ids)), "grasp_id": pa.array(ids, pa.int32())}
    arrays.update({k: pa.array(v) for k, v in cols.items()})
    return pa.table(arrays)


def test_join_scene_fills_missing_rows_with_nulls_and_renames():
    base = _table("s", [2, 0, 1], object_name=["a", "b", "c"], object_index=pa.array([0, 1, 1], pa.int16()),
                  width=[0.1, 0.2, 0.3])
    labels = _table("s", [1, 2], n=pa.array([4, 8], pa.int32()), width=[9.0, 9.5])
    t = join_scene([("grasps", base), ("robustness", labels)], "k")
    assert t.column_names == ["scene_id", "grasp_id", "object_name", "object_index", "width", "robustness_n",
                              "robustness_width", "source_key"]
    assert t.column("grasp_id").to_pylist() == [0, 1, 2]
    assert t.column("object_name").to_pylist() == ["b", "c", "a"]
    assert t.column("robustness_n").to_pylist() == [None, 4, 8]
    assert t.column("source_key").to_pylist() == ["k"] * 3
    assert t.schema.field("robustness_n").metadata[b"stage"] == b"robustness"


def test_join_scene_refuses_rows_it_cannot_place():
    base = _table("s", [0, 1], object_name=["a", "b"])
    with pytest.raises(StageError, match=r"grasp ids \[5\] are not in the grasps table"):
        join_scene([("grasps", base), ("rollouts", _table("s", [0, 5], outcome=[1, 2]))], "k")
    with pytest.raises(StageError, match="duplicate grasp ids"):
        join_scene([("grasps", base), ("rollouts", _table("s", [0, 0], outcome=[1, 2]))], "k")
    with pytest.raises(StageError, match="rows of scene"):
        join_scene([("grasps", base), ("rollouts", _table("t", [0], outcome=[1]))], "k")


def test_row_groups_hold_whole_scenes(tmp_path):
    scenes = [join_scene([("grasps", _table(f"s{i}", list(range(n)), object_name=["a"] * n))], "k")
              for i, n in enumerate([3, 4, 2, 6, 1])]
    path = tmp_path / "g.parquet"
    assert write_grasps_parquet(path, scenes, row_group_rows=6, metadata={b"x": b"y"}) == 16
    pf = pq.ParquetFile(path)
    sizes = [pf.metadata.row_group(g).num_rows for g in range(pf.num_row_groups)]
    assert sizes == [3, 6, 6, 1]  # s0 | s1 s2 | s3 (alone: would pass 6) | s4
    other = tmp_path / "h.parquet"
    write_grasps_parquet(other, scenes, row_group_rows=6, metadata={b"x": b"y"})
    assert sha256_file(path) == sha256_file(other)


def test_label_summary_discrete_and_binned():
    s = label_summary(np.array([0.0, 0.25, 0.25, 1.0, np.nan]), bins=4, unit_range=True)
    assert s["n"] == 4 and s["histogram"] == {"values": [0.0, 0.25, 1.0], "counts": [1, 2, 1]}
    s = label_summary(np.linspace(0, 1, 101), bins=4, unit_range=True)
    assert s["histogram"]["edges"] == [0.0, 0.25, 0.5, 0.75, 1.0] and sum(s["histogram"]["counts"]) == 101
    # k/40 fractions: those on an edge go up, never to the neighbour below through rounding
    s = label_summary(np.arange(41) / 40, bins=20, unit_range=True)
    assert s["histogram"]["counts"] == [2] * 19 + [3]
    assert label_summary(np.array([np.nan]), bins=4, unit_range=False) == {"n": 0}


def test_ranks_average_ties_like_scipy():
    from scipy.stats import rankdata

    from stages.dataset import _ranks

    rng = np.random.default_rng(0)
    for n in (1, 2, 7, 40):
        x = rng.integers(0, 4, size=n).astype(float)
        np.testing.assert_allclose(_ranks(x), rankdata(x))
