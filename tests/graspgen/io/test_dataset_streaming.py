"""The dataset stage's memory does not grow with the dataset: the streaming writer, the card's running counts, the
row-group-at-a-time table check and the reader's object selection, each against the whole-table way (kept here as
the slow reference) on tables split into many shards and row groups."""

from __future__ import annotations

import io
import json

import h5py
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
import scipy.stats

from graspgen.io import row_groups
from graspgen.io.card_stats import CORRELATED, LABEL_COLUMNS, CardSettings, _num, card_stats, label_summary
from graspgen.io.card_tally import GraspTally
from graspgen.io.dataset_table import OUTCOME_NAMES, GroupedParquetWriter, check_table, float_values
from graspgen.io.reader import open_dataset

BINS = 20


# ---------------------------------------------------------------------------------------------------------------
# The whole-table reference: the card statistics as they were computed before streaming (the table read at once)
# ---------------------------------------------------------------------------------------------------------------


def _ref_correlations(table):
    """The labels' pairwise correlations by scipy (independent of the library's ``_correlations``): Pearson from
    ``scipy.stats.pearsonr``, Spearman from ``scipy.stats.spearmanr`` (average ranks for ties), None where fewer
    than 3 pairs or a constant side."""
    cols = [c for c in CORRELATED if c in table.column_names]
    values = {c: float_values(table.column(c)) for c in cols}
    pearson, spearman, counts = [], [], []
    for a in cols:
        rows_p, rows_s, rows_n = [], [], []
        for b in cols:
            ok = np.isfinite(values[a]) & np.isfinite(values[b])
            x, y = values[a][ok], values[b][ok]
            rows_n.append(int(ok.sum()))
            if ok.sum() < 3 or np.ptp(x) == 0 or np.ptp(y) == 0:
                rows_p.append(None)
                rows_s.append(None)
                continue
            rows_p.append(float(scipy.stats.pearsonr(x, y).statistic))
            rows_s.append(float(scipy.stats.spearmanr(x, y).statistic))
        pearson.append(rows_p)
        spearman.append(rows_s)
        counts.append(rows_n)
    return {"columns": cols, "n": counts, "pearson": pearson, "spearman": spearman}


def assert_correlations_close(got, expected, rel=1e-5):
    """The card's correlations against the reference: same columns, pair counts and undefined (None) entries, each
    coefficient within ``rel`` (the card rounds to 6 significant digits)."""
    assert got["columns"] == expected["columns"] and got["n"] == expected["n"]
    for kind in ("pearson", "spearman"):
        for row_got, row_ref in zip(got[kind], expected[kind], strict=True):
            for g, r in zip(row_got, row_ref, strict=True):
                assert (g is None) == (r is None), (kind, got[kind], expected[kind])
                if r is not None:
                    assert g == pytest.approx(r, rel=rel, abs=1e-6), (kind, got[kind], expected[kind])


def _ref_rate(k, n):
    return _num(k / n) if n else None


def reference_stats(root, files):
    """The card statistics of the code before streaming: every table read whole."""
    table = pq.read_table(root / "grasps.parquet")
    outcome = table.column("outcome").to_numpy()
    objects = np.asarray(table.column("object_name").to_pylist(), dtype=object)
    scene_col = np.asarray(table.column("scene_id").to_pylist(), dtype=object)
    scenes = {}
    for path in sorted(root / rel for rel in files if rel.startswith("scenes/")):
        with h5py.File(path, "r") as f:
            names = json.loads(f.attrs["object_names"])
            scenes[path.stem] = {"grasps": int((scene_col == path.stem).sum()), "objects": [str(n) for n in names],
                                 "views": int(f["cameras/K"].shape[0])}
    library = sorted(rel.split("/")[1][: -len(".h5")] for rel in files if rel.startswith("objects/"))
    per_object = {}
    for name in library:
        sel = objects == name
        counts = [int(((outcome == c) & sel).sum()) for c in range(len(OUTCOME_NAMES))]
        n = int(sel.sum())
        per_object[name] = {"scenes": sum(name in s["objects"] for s in scenes.values()), "grasps": n,
                            "outcomes": counts, "success_rate": _num(counts[5] / n) if n else None}
    labels = {col: label_summary(float_values(table.column(col)), BINS, col in ("robustness", "pfc"))
              for col in LABEL_COLUMNS if col in table.column_names}
    stats = {
        "counts": {"grasps": len(table), "scenes": len(scenes), "views": sum(s["views"] for s in scenes.values()),
                   "objects": len(library),
                   "objects_with_grasps": int(sum(1 for o in per_object.values() if o["grasps"])),
                   "grippers": sorted(set(table.column("gripper").to_pylist()))},
        "outcomes": [{"code": c, "name": name, "grasps": int((outcome == c).sum())}
                     for c, name in enumerate(OUTCOME_NAMES)],
        "objects": per_object, "scenes": scenes, "labels": labels,
    }
    sets = {}
    t = pq.read_table(root / "object_grasps.parquet", columns=["object_name", "candidate", "outcome", "success",
                                                                "firm"])
    meta = json.loads(pq.read_schema(root / "object_grasps.parquet").metadata[b"graspgen.dataset"])["tasks"]
    names = np.asarray(t.column("object_name").to_pylist(), dtype=object)
    kind = np.asarray(t.column("candidate").to_pylist(), dtype=object)
    code = np.asarray(t.column("outcome").to_pylist())
    ok = np.asarray(t.column("success").to_pylist(), dtype=bool)
    firm = np.asarray(t.column("firm").to_pylist(), dtype=bool)
    sets["objects"] = {}
    sets["grippers"] = sorted(set(t.column("gripper").to_pylist())) if "gripper" in t.column_names else []
    for name in sorted(set(names) | set(meta)):
        sel = names == name
        m = meta.get(name, {})
        near = sel & (kind == "near_miss")
        positive = firm if m.get("label") == "firm" else ok
        sets["objects"][name] = {
            "grasps": int(sel.sum()), "label": m.get("label") or "held",
            "selection": m.get("selection") or "balanced",
            "positives": int((sel & positive).sum()), "negatives": int((sel & ~positive).sum()),
            "target_grasps": m.get("target_grasps"),
            "target_positives": m.get("target_positives"), "target_negatives": m.get("target_negatives"),
            "tried": m.get("tried"), "reached": m.get("reached"), "collisions_dropped": m.get("collisions_dropped"),
            "outcome_mix": {"collision": int((sel & (code <= 2)).sum()), "no_contact": int((sel & (code == 3)).sum()),
                            "slipped": int((sel & (code == 4)).sum()), "held_not_firm": int((sel & ok & ~firm).sum()),
                            "firm": int((sel & firm).sum())},
            "near_miss": int(near.sum()),
            "near_miss_success_rate": _ref_rate(int((near & ok).sum()), int(near.sum())),
        }
    t = pq.read_table(root / "placed_grasps.parquet")
    code = t.column("scene_code").to_numpy()
    ok = t.column("success").to_numpy(zero_copy_only=False).astype(bool)
    obj_ok = t.column("object_success").to_numpy(zero_copy_only=False).astype(bool)
    checked = t.column("rescene_outcome").to_numpy() >= 0
    re_ok = np.asarray([bool(v) for v in t.column("rescene_success").to_pylist()])
    pos, neg = checked & obj_ok, checked & ~obj_ok
    sets["placed"] = {
        "grasps": len(t), "scenes": len(set(t.column("scene_id").to_pylist())), "free": int((code < 0).sum()),
        "support_collisions": int((code == 0).sum()), "clutter_collisions": int((code == 2).sum()),
        "positives": int(ok.sum()), "rescene_checked": int(checked.sum()),
        "rescene_changed": int((checked & (re_ok != obj_ok)).sum()),
        "rescene_change_rate": _ref_rate(int((checked & (re_ok != obj_ok)).sum()), int(checked.sum())),
        "rescene_lost": _ref_rate(int((pos & ~re_ok).sum()), int(pos.sum())),
        "rescene_gained": _ref_rate(int((neg & re_ok).sum()), int(neg.sum())),
    }
    stats["object_sets"] = sets
    return stats


def reference_write(path, tables, row_group_rows, metadata):
    """The writer before streaming: every table in a list, packed into groups, then written."""
    schema = tables[0].schema.with_metadata(dict(metadata))
    groups, rows = [[]], 0
    for t in tables:
        if len(t) == 0:
            continue
        if groups[-1] and rows + len(t) > row_group_rows:
            groups.append([])
            rows = 0
        groups[-1].append(t)
        rows += len(t)
    strings = [f.name for f in schema if pa.types.is_string(f.type)]  # the published files' dictionaries
    with pq.ParquetWriter(path, schema, compression="zstd", compression_level=3, use_dictionary=strings,
                          write_statistics=True, store_schema=True) as writer:
        for group in groups:
            if group:
                table = pa.concat_tables(group).cast(schema).combine_chunks()
                writer.write_table(table, row_group_size=len(table))


# ---------------------------------------------------------------------------------------------------------------
# A synthetic published dataset in many shards
# ---------------------------------------------------------------------------------------------------------------

OBJECTS = [f"obj_{i:02d}" for i in range(9)]
LIBRARY = [*OBJECTS, "never_grasped"]


def _rigid(rng, n):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    R = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
                  2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
                  2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1).reshape(n, 3, 3)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3], T[:, :3, 3] = R, rng.normal(size=(n, 3))
    return T.reshape(n, 16)


def scene_table(rng, sid, n, objects):
    """One scene's merged rows: outcomes of every code, robustness of 5 copies for successes, continuous epsilon
    (with zeros and NaNs), min_closure_friction on a grid."""
    outcome = rng.integers(0, 6, n).astype(np.int8)
    success = outcome == 5
    copies = rng.integers(0, 6, n)
    robustness = np.where(success, copies / 5, np.nan)
    pfc = np.where(success, rng.integers(0, 6, n) / 5, np.nan)
    epsilon = np.where(rng.random(n) < 0.2, 0.0, rng.gamma(2.0, 0.02, n))
    epsilon[rng.random(n) < 0.05] = np.nan
    friction = np.where(rng.random(n) < 0.3, np.nan, rng.integers(1, 11, n) / 10)
    names = [objects[i] for i in rng.integers(0, len(objects), n)]
    return pa.table({
        "scene_id": pa.array([sid] * n), "grasp_id": pa.array(np.arange(n), pa.int32()),
        "object_name": pa.array(names), "object_index": pa.array(rng.integers(0, 3, n), pa.int16()),
        "gripper": pa.array(["panda"] * n), "outcome": pa.array(outcome),
        "outcome_name": pa.array([OUTCOME_NAMES[o] for o in outcome]),
        "pose_world": pa.FixedSizeListArray.from_arrays(pa.array(_rigid(rng, n).reshape(-1)), 16),
        "robustness": pa.array(robustness), "epsilon": pa.array(epsilon), "pfc": pa.array(pfc),
        "min_closure_friction": pa.array(friction),
        # The rest of the required columns (graspgen.io.dataset_table.REQUIRED_SCHEMA), for check_table.
        "pose_object": pa.FixedSizeListArray.from_arrays(pa.array(_rigid(rng, n).reshape(-1)), 16),
        "width": pa.array(rng.random(n) * 0.08), "open_width": pa.array(np.full(n, 0.08)),
        **{c: pa.FixedSizeListArray.from_arrays(pa.array(rng.normal(size=3 * n)), 3)
           for c in ("contact1", "contact2", "normal1", "normal2")},
        "prefilter_code": pa.array(rng.integers(-1, 3, n).astype(np.int8)), "source_key": pa.array([sid] * n),
    })


def object_set(rng, name, n):
    outcome = rng.integers(0, 6, n).astype(np.int8)
    return pa.table({
        "object_name": pa.array([name] * n), "grasp_id": pa.array(np.arange(n), pa.int32()),
        "candidate": pa.array([("near_miss", "antipodal")[i] for i in rng.integers(0, 2, n)]),
        "outcome": pa.array(outcome), "success": pa.array(outcome == 5),
        "firm": pa.array((outcome == 5) & (rng.random(n) < 0.6)), "width": pa.array(rng.random(n)),
    })


def placed_set(rng, sid, n):
    obj_ok = rng.random(n) < 0.5
    outcome = np.where(rng.random(n) < 0.3, rng.integers(0, 6, n), -1).astype(np.int8)
    code = rng.integers(-1, 3, n).astype(np.int8)
    return pa.table({
        "scene_id": pa.array([sid] * n), "grasp_id": pa.array(np.arange(n), pa.int32()),
        "object_success": pa.array(obj_ok), "scene_code": pa.array(code),
        "success": pa.array(obj_ok & (code < 0)), "rescene_outcome": pa.array(outcome),
        "rescene_success": pa.array(outcome == 5),
    })


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A published folder written shard by shard: 14 scenes (row groups of about 200 rows), 9 object sets in
    groups of about 300 rows, 7 placed scenes; the scene and object files the card lists."""
    root = tmp_path_factory.mktemp("streamed")
    rng = np.random.default_rng(7)
    files = {}
    scenes = [(f"scene_{i:03d}", int(rng.integers(40, 160))) for i in range(14)]
    with GroupedParquetWriter(root / "grasps.parquet", row_group_rows=200, metadata={b"k": b"v"}) as w:
        for sid, n in scenes:
            w.add(scene_table(rng, sid, n, OBJECTS[:-1] if sid != "scene_005" else OBJECTS))
    (root / "scenes").mkdir()
    for sid, _ in scenes:
        with h5py.File(root / "scenes" / f"{sid}.h5", "w") as f:
            f.attrs["object_names"] = json.dumps(list(rng.choice(OBJECTS, 3, replace=False)))
            f["cameras/K"] = np.zeros((int(rng.integers(1, 4)), 3, 3))
        files[f"scenes/{sid}.h5"] = {}
    (root / "objects").mkdir()
    for name in LIBRARY:
        (root / "objects" / f"{name}.h5").write_bytes(b"")
        files[f"objects/{name}.h5"] = {}
    tasks = {name: {"tried": 100 + i, "reached": bool(i % 2), "target_positives": 50} for i, name in enumerate(OBJECTS)}
    for name in OBJECTS[::2]:  # natural sets labelled firm beside balanced ones labelled held (older metadata)
        tasks[name].update(selection="natural", label="firm", target_grasps=150, collisions_dropped=9)
    tasks["no_rows_object"] = {"tried": 7, "reached": False}
    meta = {b"graspgen.dataset": json.dumps({"tasks": tasks}).encode()}
    with GroupedParquetWriter(root / "object_grasps.parquet", row_group_rows=300, metadata=meta) as w:
        for name in OBJECTS:
            w.add(object_set(rng, name, int(rng.integers(80, 200))))
    with GroupedParquetWriter(root / "placed_grasps.parquet", row_group_rows=250, metadata={}) as w:
        for sid, _ in scenes[:7]:
            w.add(placed_set(rng, sid, int(rng.integers(50, 150))))
    files["object_grasps.parquet"] = files["placed_grasps.parquet"] = {}
    return root, files


def test_the_files_are_in_many_row_groups(dataset):
    root, _ = dataset
    for name, at_least in (("grasps.parquet", 6), ("object_grasps.parquet", 4), ("placed_grasps.parquet", 3)):
        assert pq.ParquetFile(root / name).metadata.num_row_groups >= at_least


def test_card_statistics_streamed_equal_the_whole_table_ones(dataset):
    root, files = dataset
    stats, _ = card_stats(root, files, CardSettings(plots=False, histogram_bins=BINS))
    expected = reference_stats(root, files)
    stats = json.loads(json.dumps(stats))
    correlation = stats.pop("correlation")
    assert stats == json.loads(json.dumps(expected))
    reference = _ref_correlations(pq.read_table(root / "grasps.parquet"))
    assert_correlations_close(correlation, reference)
    # The correlations are not trivial: defined off the diagonal, neither 0 nor +-1 everywhere, Spearman not Pearson.
    off = [(i, j) for i in range(len(reference["columns"])) for j in range(len(reference["columns"])) if i != j]
    assert all(reference["spearman"][i][j] is not None for i, j in off)
    assert any(0.01 < abs(reference["pearson"][i][j]) < 0.99 for i, j in off)
    assert any(abs(reference["pearson"][i][j] - reference["spearman"][i][j]) > 1e-3 for i, j in off)
    # The figures are not trivial: every label summarised, a per-value and a binned histogram, correlations.
    assert set(stats["labels"]) == set(LABEL_COLUMNS)
    assert "values" in stats["labels"]["robustness"]["histogram"] and "edges" in stats["labels"]["epsilon"]["histogram"]
    assert stats["objects"]["never_grasped"]["grasps"] == 0 and stats["object_sets"]["objects"]["no_rows_object"]


def test_tallies_merged_per_shard_equal_one_tally(dataset):
    root, _ = dataset
    pf = pq.ParquetFile(root / "grasps.parquet")
    labels = list(LABEL_COLUMNS)
    cols = ["scene_id", "grasp_id", "object_name", "outcome", "gripper", *labels]
    whole, merged = GraspTally(labels), GraspTally(labels)
    whole.add(pf.read(columns=cols))
    for i in range(pf.num_row_groups):
        part = GraspTally(labels)
        part.add(pf.read_row_group(i, columns=cols))
        merged.merge(part)
    assert merged.rows == whole.rows and np.array_equal(merged.outcomes, whole.outcomes)
    assert merged.scenes == whole.scenes and merged.grippers == whole.grippers
    assert {k: v.tolist() for k, v in merged.objects.items()} == {k: v.tolist() for k, v in whole.objects.items()}
    for c in labels:
        assert np.array_equal(merged.label_tally.values(c), whole.label_tally.values(c), equal_nan=True)
    assert merged.scene_runs == whole.scene_runs
    scene_col = np.asarray(pf.read(columns=["scene_id"]).column(0).to_pylist(), dtype=object)
    for sid in set(scene_col):
        assert merged.scene_rows(sid).tolist() == np.flatnonzero(scene_col == sid).tolist()
    assert all(len(runs) == 1 for runs in merged.scene_runs.values())  # a sorted file: one run per scene


def test_the_plots_table_reads_the_rows_it_is_asked_for(dataset):
    root, files = dataset
    _, table = card_stats(root, files, CardSettings(plots=False))
    full = pq.read_table(root / "grasps.parquet")
    scene_col = np.asarray(full.column("scene_id").to_pylist())
    rows = np.flatnonzero(scene_col == "scene_009")
    assert _bytes(table.take(pa.array(rows))) == _bytes(full.select(table.column_names).take(pa.array(rows)))
    assert table.scene_ids == sorted(set(scene_col.tolist()))
    assert table.scene_rows("scene_009").tolist() == rows.tolist()
    assert np.array_equal(float_values(table.column("epsilon")), float_values(full.column("epsilon")), equal_nan=True)
    assert not table.sampled


def _bytes(table):
    """The table's content as bytes (equal tables, NaNs included, give equal bytes; Table.equals says NaN != NaN)."""
    buf = io.BytesIO()
    pq.write_table(table.combine_chunks().replace_schema_metadata(table.schema.metadata or None), buf)
    return buf.getvalue()


@pytest.mark.parametrize("compact", [2, 1000])
@pytest.mark.parametrize("group_rows", [1, 150, 400, 10_000])
def test_streamed_writer_makes_the_bytes_of_the_whole_list_writer(tmp_path, group_rows, compact, monkeypatch):
    monkeypatch.setattr(row_groups, "COMPACT_TABLES", compact)  # the buffered tables made one block every 2: same bytes
    rng = np.random.default_rng(3)
    tables = [scene_table(rng, f"s{i:02d}", max(n, 1), OBJECTS).slice(0, n)
              for i, n in enumerate([120, 0, 35, 300, 80, 80, 1])]  # an empty scene too: it takes no group
    reference_write(tmp_path / "ref.parquet", tables, group_rows, {b"m": b"1"})
    writer = GroupedParquetWriter(tmp_path / "new.parquet", row_group_rows=group_rows, metadata={b"m": b"1"})
    held = []
    with writer:
        for t in iter(tables):
            writer.add(t)
            held.append(writer._group_rows)
    assert (tmp_path / "new.parquet").read_bytes() == (tmp_path / "ref.parquet").read_bytes()
    assert writer.rows == sum(len(t) for t in tables)
    assert max(held) <= max(group_rows, max(len(t) for t in tables))  # one group's tables held, at most


def test_only_the_string_columns_are_dictionary_encoded(tmp_path):
    rng = np.random.default_rng(4)
    tables = [scene_table(rng, f"s{i:02d}", 50, OBJECTS) for i in range(3)]
    with GroupedParquetWriter(tmp_path / "t.parquet", row_group_rows=1000, metadata={}) as writer:
        for t in tables:
            writer.add(t)
    meta = pq.ParquetFile(tmp_path / "t.parquet").metadata
    schema = tables[0].schema
    for i in range(meta.num_columns):
        column = meta.row_group(0).column(i)
        top = schema.field(column.path_in_schema.split(".")[0])
        dictionary = any("DICTIONARY" in e for e in column.encodings)
        assert dictionary == pa.types.is_string(top.type), (column.path_in_schema, column.encodings)


def _card_of(root):
    schema = pq.read_schema(root / "grasps.parquet")
    return {"schema": [{"name": f.name, "type": str(f.type)} for f in schema],
            "counts": {"grasps": pq.ParquetFile(root / "grasps.parquet").metadata.num_rows}}


def test_table_check_row_group_by_row_group_finds_what_the_whole_table_check_found(dataset, tmp_path):
    root, _ = dataset
    assert check_table(root, _card_of(root)) == []
    full = pq.read_table(root / "grasps.parquet")
    first = full.slice(0, 400)
    # Sorted within each row group, but the second group starts before the first ended; a wrong name in group 2.
    names = first.column("outcome_name").to_pylist()
    names[350] = "success" if names[350] != "success" else "collision_with_ground"
    bad = first.set_column(first.schema.get_field_index("outcome_name"), "outcome_name", pa.array(names))
    bad_root = tmp_path / "bad"
    (bad_root / "scenes").mkdir(parents=True)
    (bad_root / "objects").mkdir()
    with pq.ParquetWriter(bad_root / "grasps.parquet", bad.schema) as w:
        w.write_table(bad.slice(200, 200))
        w.write_table(bad.slice(0, 200))
    problems = check_table(bad_root, _card_of(bad_root))
    where = str(bad_root / "grasps.parquet")
    assert problems[:2] == [f"{where}: rows are not sorted and unique by (scene_id, grasp_id)",
                            f"{where}: outcome_name does not match outcome"]
    named = set(bad.column("scene_id").to_pylist()) | set(bad.column("object_name").to_pylist())
    assert all("missing" in p for p in problems[2:]) and len(problems) == 2 + len(named)  # no files there


def test_reader_reads_one_object_from_its_row_groups_in_either_layout(dataset, tmp_path):
    root, _ = dataset
    ds = open_dataset(root)
    full = pq.read_table(root / "object_grasps.parquet")
    groups = pq.ParquetFile(root / "object_grasps.parquet").metadata.num_row_groups
    for name in ("obj_00", "obj_04", "obj_08"):
        expected = full.filter(pc.equal(full.column("object_name"), name))
        assert _bytes(ds.object_grasps(name)) == _bytes(expected)
    some = ds.object_grasps(["obj_01", "obj_02"], columns=["object_name", "success"], success=True)
    assert set(some.column("object_name").to_pylist()) == {"obj_01", "obj_02"} and all(
        some.column("success").to_pylist())
    assert _bytes(ds.object_grasps()) == _bytes(full)
    placed = pq.read_table(root / "placed_grasps.parquet")
    assert _bytes(ds.placed_grasps("scene_003")) == _bytes(placed.filter(pc.equal(placed.column("scene_id"),
                                                                                   "scene_003")))
    # Only the groups whose statistics admit the object are read.
    from graspgen.io.reader import _set_source

    source = _set_source(root, "object_grasps")
    assert len(list(source.parts("object_name", ["obj_04"]))) <= 2 < groups
    # The same set as a folder of one file per object reads the same.
    other = tmp_path / "by_object"
    other.mkdir()
    for name in ("grasps.parquet", "placed_grasps.parquet"):
        (other / name).symlink_to(root / name)
    (other / "object_grasps").mkdir()
    for name in OBJECTS:
        part = full.filter(pc.equal(full.column("object_name"), name))
        pq.write_table(part, other / "object_grasps" / f"{name}.parquet")
    ds2 = open_dataset(other)
    assert _bytes(ds2.object_grasps("obj_04")) == _bytes(ds.object_grasps("obj_04"))
    assert _bytes(ds2.object_grasps()) == _bytes(full)
    with pytest.raises(KeyError, match="no column"):
        ds.object_grasps("obj_00", columns=["nope"])
