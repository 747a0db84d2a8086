"""The merged grasp table (graspgen/io/dataset_table.py): the join of a scene's tables, row groups of whole scenes."""

from __future__ import annotations

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from graspgen.errors import InputError
from graspgen.io.dataset_table import join_scene, write_grasps_parquet
from graspgen.io.files import sha256_file


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
    with pytest.raises(InputError, match=r"grasp ids \[5\] are not in the grasps table"):
        join_scene([("grasps", base), ("rollouts", _table("s", [0, 5], outcome=[1, 2]))], "k")
    with pytest.raises(InputError, match="duplicate grasp ids"):
        join_scene([("grasps", base), ("rollouts", _table("s", [0, 0], outcome=[1, 2]))], "k")
    with pytest.raises(InputError, match="rows of scene"):
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
