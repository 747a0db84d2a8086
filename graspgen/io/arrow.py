"""Arrow helpers shared by the grasp tables: list columns of numpy arrays, and back.

Two kinds of list column: *fixed-size* ones (a pose, 16 float64 per row: :func:`fixed_list`, read back with
:func:`column_array`) and *variable-length* ones (the k contacts of a rollout, k * 3 float64 per row:
:func:`variable_list`, read back with :func:`list_rows`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import pyarrow as pa

__all__ = ["fixed_list", "column_array", "variable_list", "list_rows"]


def fixed_list(values: np.ndarray, n: int) -> pa.FixedSizeListArray:
    """(rows, n) float array as an Arrow fixed-size list column."""
    flat = np.ascontiguousarray(values, dtype=np.float64).reshape(-1)
    return pa.FixedSizeListArray.from_arrays(pa.array(flat, type=pa.float64()), n)


def column_array(table: pa.Table, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """A fixed-size list column back as a (rows, *shape) float64 array."""
    col = table.column(name).combine_chunks()
    return np.asarray(col.values, dtype=np.float64).reshape((len(table), *shape))


def variable_list(parts: Sequence[Any], value_type: pa.DataType) -> pa.ListArray:
    """One variable-length list per row: ``parts[i]`` (any shape, flattened) becomes row ``i``.

    Parameters
    ----------
    parts : sequence of array-like
        One array per row (``(k_i, 3)`` contact points, ``(k_i,)`` labels, empty for a row without values); each is
        converted to ``value_type``'s numpy dtype and flattened in C order.
    value_type : pyarrow.DataType
        Type of the list's values, e.g. ``pa.float64()`` or ``pa.int8()``.

    Returns
    -------
    pyarrow.ListArray
        ``list<value_type>`` with 32-bit offsets, ``len(parts)`` rows.
    """
    dtype = value_type.to_pandas_dtype()
    flat = [np.asarray(p, dtype=dtype).reshape(-1) for p in parts]
    offsets = np.concatenate([[0], np.cumsum([len(p) for p in flat])]).astype(np.int32)
    values = np.concatenate(flat) if flat else np.zeros(0, dtype)
    return pa.ListArray.from_arrays(pa.array(offsets), pa.array(values, type=value_type))


def list_rows(table: pa.Table, name: str, width: int = 0, dtype: Any = None) -> list[np.ndarray]:
    """A variable-length list column back as one array per row: the inverse of :func:`variable_list`.

    Parameters
    ----------
    table : pyarrow.Table
        The table.
    name : str
        A ``list<...>`` column of it.
    width : int
        0: each row as a flat ``(k,)`` array; otherwise as ``(k / width, width)`` (e.g. 3 for points).
    dtype : numpy dtype or None
        Dtype of the arrays (None: the column's own value type).

    Returns
    -------
    list of numpy.ndarray, one per row
        Views into one array holding the whole column's values.
    """
    col = table.column(name).combine_chunks()
    offsets = np.asarray(col.offsets, dtype=np.int64)
    values = np.asarray(col.values.to_numpy(zero_copy_only=False), dtype=dtype)
    rows = [values[offsets[i] : offsets[i + 1]] for i in range(len(table))]
    return [r.reshape(-1, width) for r in rows] if width else rows
