"""Shard formats: round trips and byte-determinism."""

from __future__ import annotations

import time

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from graspgen.io.files import read_h5, write_h5, write_parquet
from pipeline.keys import sha256_file


def tree(rng):
    return {
        "@attrs": {"name": "thing", "notes": ["a", "b"], "params": {"x": 1}, "empty": "", "none": None},
        "big": rng.normal(size=(3000, 3)),
        "small": np.arange(6, dtype=np.int32).reshape(2, 3),
        "label": "hello",
        "group": {"@attrs": {"k": 2.5}, "inner": np.eye(4)},
    }


def test_h5_round_trip(tmp_path):
    t = tree(np.random.default_rng(0))
    write_h5(tmp_path / "a.h5", t)
    back = read_h5(tmp_path / "a.h5")
    assert back["@attrs"] == {"name": "thing", "notes": ["a", "b"], "params": {"x": 1}, "empty": "", "none": None}
    np.testing.assert_array_equal(back["big"], t["big"])
    np.testing.assert_array_equal(back["small"], t["small"])
    assert back["small"].dtype == np.int32
    assert back["label"] == "hello"
    assert back["group"]["@attrs"] == {"k": 2.5}


def test_h5_same_content_same_bytes(tmp_path):
    write_h5(tmp_path / "a.h5", tree(np.random.default_rng(1)))
    time.sleep(1.1)  # HDF5 would record a different modification time if times were tracked
    write_h5(tmp_path / "b.h5", tree(np.random.default_rng(1)))
    assert sha256_file(tmp_path / "a.h5") == sha256_file(tmp_path / "b.h5")


def test_parquet_same_content_same_bytes(tmp_path):
    import pandas as pd

    df = pd.DataFrame({"a": np.arange(10), "b": np.linspace(0, 1, 10)}, index=np.arange(10) * 3)
    write_parquet(tmp_path / "a.parquet", pa.Table.from_pandas(df))
    write_parquet(tmp_path / "b.parquet", pa.Table.from_pandas(df))
    assert sha256_file(tmp_path / "a.parquet") == sha256_file(tmp_path / "b.parquet")
    assert pq.read_table(tmp_path / "a.parquet").column("b").to_pylist() == list(np.linspace(0, 1, 10))
