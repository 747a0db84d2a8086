"""The ACRONYM export reads the object grasp table one object at a time; the slow reference splits it whole."""

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from graspgen.errors import InputError
from graspgen.io.row_groups import by_object, objects_of_table

CASES = [
    (["a"] * 5 + ["b"] * 7 + ["c"] * 3, 4),  # objects across row-group boundaries
    (["a"] * 5 + ["b"] * 7 + ["c"] * 3, 100),  # one row group
    (["b"] * 3 + ["a"] * 4 + ["c"] * 2, 2),  # not sorted: read in passes, same result
    (["a", "b", "a"], 1),  # an object that comes back after another
]


@pytest.mark.parametrize(("names", "group_rows"), CASES)
def test_objects_of_table_matches_the_whole_table_split(tmp_path, names, group_rows):
    path = tmp_path / "object_grasps.parquet"
    pq.write_table(pa.table({"object_name": names, "grasp_id": list(range(len(names)))}), path,
                   row_group_size=group_rows)
    columns = ["object_name", "grasp_id"]
    got = [(n, t.column("grasp_id").to_pylist()) for n, t in objects_of_table(path, columns)]
    ref = [(n, t.column("grasp_id").to_pylist()) for n, t in by_object(pq.read_table(path), path)]
    assert got == ref
    assert sorted(n for n, _ in got) == [n for n, _ in got] == sorted(set(names))


def test_a_bad_object_name_is_refused_with_the_file(tmp_path):
    path = tmp_path / "object_grasps.parquet"
    pq.write_table(pa.table({"object_name": ["a", "x/y"], "grasp_id": [0, 1]}), path)
    with pytest.raises(InputError, match="object_grasps.parquet: object_name must be a non-empty file name"):
        list(objects_of_table(path, ["object_name", "grasp_id"]))


@pytest.mark.parametrize("batch_rows", [1, 7, 50, 10_000])
@pytest.mark.parametrize("group_rows", [3, 40, 1000])
def test_an_unsorted_table_read_in_passes_matches_the_whole_table_split(tmp_path, batch_rows, group_rows):
    """A table sorted by scene (objects mixed in every group), read a batch of objects per pass: the same objects,
    rows and order as the whole table split; memory holds about one batch (one object when a batch is smaller)."""
    rng = np.random.default_rng(group_rows + batch_rows)
    names = [f"obj_{i:02d}" for i in rng.integers(0, 12, 400)]
    path = tmp_path / "grasps.parquet"
    pq.write_table(pa.table({"object_name": names, "grasp_id": np.arange(400), "v": rng.random(400)}), path,
                   row_group_size=group_rows)
    got = list(objects_of_table(path, ["object_name", "grasp_id", "v"], batch_rows=batch_rows))
    ref = by_object(pq.read_table(path), path)
    assert [n for n, _ in got] == [n for n, _ in ref]
    for (_, a), (_, b) in zip(got, ref):
        assert a.combine_chunks().equals(b.combine_chunks())
