"""Deterministic shard formats: the same content always gives the same file bytes.

HDF5: no timestamps (``track_times=False``), the oldest file format (``libver="earliest"``), fixed chunking and
gzip level, attributes written in sorted order. Parquet: fixed compression and row-group size, no pandas index
metadata.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from graspgen.errors import SettingsError
from shared_utils.digest import sha256_file as sha256_file  # re-exported: one definition, below engine and library

ATTRS = "@attrs"
"""Key in a tree node whose value (a mapping) becomes the HDF5 attributes of that group."""

_COMPRESS_ABOVE = 4096
"""Arrays with more elements than this are gzip-compressed (small ones stay contiguous: faster to read)."""


def write_h5(path: str | Path, tree: Mapping[str, Any]) -> None:
    """Write a nested mapping to HDF5: mappings become groups, arrays datasets, ``"@attrs"`` attributes.

    Parameters
    ----------
    path : str or Path
        Destination (usually the temp path the engine gives a task).
    tree : mapping
        ``{name: ndarray | scalar | str | mapping}``. Strings and scalars become scalar datasets; put metadata
        in ``"@attrs"`` instead when it describes a group. Attribute values that are dicts or lists are stored
        as JSON strings.
    """
    with h5py.File(path, "w", libver="earliest", track_order=False) as f:
        _write_group(f, tree)


def _write_group(group: h5py.Group, tree: Mapping[str, Any]) -> None:
    for name in sorted(tree):
        value = tree[name]
        if name == ATTRS:
            for attr in sorted(value):
                group.attrs[attr] = _attr_value(value[attr])
        elif isinstance(value, Mapping):
            _write_group(group.create_group(name, track_order=False), value)
        else:
            _write_dataset(group, name, value)


def _attr_value(value: Any) -> Any:
    if isinstance(value, (dict, list, tuple)):
        return json.dumps(value, sort_keys=True, separators=(",", ":"))
    if value is None:
        return "null"
    return value


def _write_dataset(group: h5py.Group, name: str, value: Any) -> None:
    if isinstance(value, str):
        group.create_dataset(name, data=value, dtype=h5py.string_dtype(), track_times=False)
        return
    arr = np.require(value, requirements="C")  # unlike ascontiguousarray, keeps a 0-d scalar 0-d
    if arr.dtype.kind in "OUS":
        raise SettingsError(f"{name}: store strings as str scalars or attributes, not arrays of {arr.dtype}")
    kwargs: dict[str, Any] = {"track_times": False}
    if arr.size > _COMPRESS_ABOVE:
        kwargs.update(compression="gzip", compression_opts=4, shuffle=True, chunks=_chunks(arr.shape, arr.itemsize))
    dataset = group.create_dataset(name, data=arr, **kwargs)
    # A compressed chunk gets its place in the file when it leaves the chunk cache, i.e. when the dataset is
    # flushed or closed. Closing waits for the garbage collector, so in some processes (a dask worker) two
    # datasets' chunks landed in the other order: same content, other bytes. Flush now, in name order.
    dataset.flush()


def _chunks(shape: tuple[int, ...], itemsize: int, target: int = 1 << 18) -> tuple[int, ...]:
    """Chunks of about 256 KiB along the first axis, a pure function of shape (so bytes do not vary)."""
    row = int(np.prod(shape[1:], dtype=np.int64)) * itemsize or 1
    first = max(1, min(shape[0], target // row))
    return (first, *shape[1:])


def read_h5(path: str | Path) -> dict[str, Any]:
    """Read a whole HDF5 file back into the nested-mapping form of :func:`write_h5` (JSON attributes decoded)."""
    with h5py.File(path, "r") as f:
        return _read_group(f)


def _read_group(group: h5py.Group) -> dict[str, Any]:
    out: dict[str, Any] = {}
    attrs = {k: _decode_attr(v) for k, v in group.attrs.items()}
    if attrs:
        out[ATTRS] = attrs
    for name, item in group.items():
        if isinstance(item, h5py.Group):
            out[name] = _read_group(item)
        elif item.dtype.kind == "O":
            out[name] = item.asstr()[()]
        else:
            out[name] = item[()]
    return out


def _decode_attr(value: Any) -> Any:
    if isinstance(value, bytes):
        value = value.decode()
    if isinstance(value, str) and (value.startswith(("[", "{")) or value == "null"):
        try:
            return json.loads(value)
        except (TypeError, json.JSONDecodeError):
            return value
    if isinstance(value, np.generic):
        return value.item()
    return value


def write_parquet(path: str | Path, table: pa.Table, *, row_group_size: int = 65536) -> None:
    """Write a Arrow table to Parquet with fixed settings (zstd level 3, fixed row groups, no pandas metadata)."""
    meta = table.schema.metadata or {}
    meta = {k: v for k, v in meta.items() if k != b"pandas"}
    table = table.replace_schema_metadata(meta or None)
    pq.write_table(
        table,
        path,
        compression="zstd",
        compression_level=3,
        row_group_size=row_group_size,
        use_dictionary=True,
        write_statistics=True,
        store_schema=True,
    )
