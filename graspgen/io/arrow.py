"""Arrow helpers shared by the grasp tables: fixed-size list columns of numpy arrays, and back."""

from __future__ import annotations

import numpy as np
import pyarrow as pa


def fixed_list(values: np.ndarray, n: int) -> pa.FixedSizeListArray:
    """(rows, n) float array as an Arrow fixed-size list column."""
    flat = np.ascontiguousarray(values, dtype=np.float64).reshape(-1)
    return pa.FixedSizeListArray.from_arrays(pa.array(flat, type=pa.float64()), n)


def column_array(table: pa.Table, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """A fixed-size list column back as a (rows, *shape) float64 array."""
    col = table.column(name).combine_chunks()
    return np.asarray(col.values, dtype=np.float64).reshape((len(table), *shape))
