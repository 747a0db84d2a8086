"""Parquet files written one table at a time, whole tables (scenes, objects' sets) per row group.

:class:`GroupedParquetWriter` is fed the tables in order and writes a row group whenever the next table would take
it past ``row_group_rows`` rows, so a file of any size is written holding one row group's tables;
:func:`write_grasps_parquet` writes an iterable of tables with it. The settings are those of
:func:`graspgen.io.files.write_parquet` (zstd 3, statistics, no pandas metadata, no timestamps) but for
dictionaries, kept to the string columns (:func:`dictionary_columns`): the bytes are a function of the tables and
the packing alone (:mod:`graspgen.io.dataset_table` uses both for the
published tables).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from graspgen.errors import InputError

__all__ = [
    "OBJECT_BATCH_ROWS",
    "GroupedParquetWriter",
    "by_object",
    "dictionary_columns",
    "objects_of_table",
    "write_grasps_parquet",
]


def write_grasps_parquet(
    path: str | Path,
    scenes: Iterable[pa.Table],
    *,
    row_group_rows: int,
    metadata: Mapping[bytes, bytes],
) -> int:
    """Write the merged scenes to one Parquet file, whole scenes per row group; returns the number of rows.

    ``scenes`` may be any iterable (a generator reading one shard at a time): it is consumed once, and only one
    row group's tables are held (:class:`GroupedParquetWriter`). The settings are fixed (module docstring), so the
    bytes are a function of the tables alone. Row groups: consecutive scenes packed until the next would take the group
    past ``row_group_rows`` rows. The same goes for any list of tables of one schema (objects' grasp sets: whole
    objects per group).
    """
    writer = GroupedParquetWriter(path, row_group_rows=row_group_rows, metadata=metadata)
    with writer:
        for table in scenes:
            writer.add(table)
    return writer.rows


COMPACT_TABLES = 32
"""A row group's tables are made one block every this many tables: a table read from its own small shard holds its
schema, metadata and buffers besides its data, many times over in a group of many small tables
(docs/decisions/2026-12-03-engine-at-scale.md); the blocks hold the same rows, so the file's bytes do not change."""


class GroupedParquetWriter:
    """A Parquet writer fed one table (a scene, an object's set) at a time, whole tables per row group.

    Tables are buffered until the next would take the group past ``row_group_rows`` rows; then the buffer is
    written as one row group (a larger table gets a group of its own). So memory holds at most one row group's
    tables, whatever the number of tables, and the bytes are those of writing all tables at once with the same
    packing. Every table must have the first one's schema, metadata included; the file's schema is it with
    ``metadata``. Use as a context manager: leaving it normally writes the last group and closes the file;
    leaving it by an exception closes the file without the last group (the caller's atomic write discards it).

    Parameters
    ----------
    path : path
        The file to write.
    row_group_rows : int
        Rows per row group, about (> 0).
    metadata : mapping of bytes to bytes
        The file's schema metadata.

    Raises
    ------
    InputError
        (from :meth:`add`) a table with other columns than the first; (on close) no table at all.
    """

    def __init__(self, path: str | Path, *, row_group_rows: int, metadata: Mapping[bytes, bytes]):
        self.path = path
        self.row_group_rows = int(row_group_rows)
        self.metadata = dict(metadata)
        self.rows = 0
        """Rows written so far (all rows once closed)."""
        self.schema: pa.Schema | None = None
        """The file's schema (the first table's, with ``metadata``); None before the first table."""
        self.tables = 0
        """Tables added."""
        self._first: pa.Schema | None = None
        self._first_name = ""
        self._group: list[pa.Table] = []
        """The group's tables so far: blocks of :data:`COMPACT_TABLES` tables made one, then the latest tables."""
        self._fresh = 0
        """How many of the last tables in ``_group`` are as added (not yet made one block)."""
        self._group_rows = 0
        self._writer: pq.ParquetWriter | None = None

    def __enter__(self) -> GroupedParquetWriter:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.close()
        elif self._writer is not None:
            self._writer.close()

    def add(self, table: pa.Table) -> None:
        """Add one table (a scene, an object's set); a full group is written first when it would not fit."""
        if self._first is None:
            self._first, self._first_name = table.schema, _scene_of(table)
            self.schema = table.schema.with_metadata(self.metadata)
        elif not table.schema.equals(self._first, check_metadata=True):
            raise InputError(f"dataset: scene {_scene_of(table)} has other columns than {self._first_name}")
        self.tables += 1
        if len(table) == 0:
            return
        if self._group and self._group_rows + len(table) > self.row_group_rows:
            self._flush()
        self._group.append(table)
        self._group_rows += len(table)
        self._fresh += 1
        if self._fresh >= COMPACT_TABLES:
            block = pa.concat_tables(self._group[-self._fresh:]).combine_chunks()
            self._group[-self._fresh:] = [block]
            self._fresh = 0

    def close(self) -> None:
        """Write the last group and close the file."""
        if self.schema is None:
            raise InputError("dataset: no scene to write")
        self._flush()
        self._open().close()

    def _open(self) -> pq.ParquetWriter:
        if self._writer is None:
            self._writer = pq.ParquetWriter(
                self.path,
                self.schema,
                compression="zstd",
                compression_level=3,
                use_dictionary=dictionary_columns(self.schema),
                write_statistics=True,
                store_schema=True,
            )
        return self._writer

    def _flush(self) -> None:
        if not self._group:
            return
        table = pa.concat_tables(self._group).cast(self.schema).combine_chunks()
        self._group, self._group_rows, self._fresh = [], 0, 0
        self._open().write_table(table, row_group_size=len(table))
        self.rows += len(table)


def dictionary_columns(schema: pa.Schema) -> list[str]:
    """The names of ``schema``'s columns written dictionary-encoded: the string and binary ones (ids, names, keys),
    whose few values repeat. Numbers are written plain: a dictionary for values that rarely repeat costs memory
    and size (docs/decisions/2026-12-03-engine-at-scale.md)."""
    text = (pa.types.is_string, pa.types.is_large_string, pa.types.is_binary, pa.types.is_large_binary,
            pa.types.is_dictionary)
    return [f.name for f in schema if any(is_(f.type) for is_ in text)]


def _scene_of(table: pa.Table) -> str:
    """The first id column's first value (the scene, or the object of an object set), for messages."""
    for name in ("scene_id", "object_name"):
        if name in table.column_names and len(table):
            return str(table.column(name)[0].as_py())
    return "(empty)"


OBJECT_BATCH_ROWS = 1 << 17
"""Rows of whole objects gathered per pass over a table not sorted by object (:func:`objects_of_table`): memory
holds about this many rows (and one row group), whatever the table's size; a larger object is one pass alone."""


def objects_of_table(path: Path, columns: list[str], batch_rows: int = OBJECT_BATCH_ROWS,
                     ) -> Iterator[tuple[str, pa.Table]]:
    """The rows of a grasp table per ``object_name``, objects in name order, rows in table order, in memory that
    does not grow with the table (``columns`` must include ``object_name``).

    A first pass over the ``object_name`` column counts each object's rows and checks the order. A table sorted by
    object (the published object sets: :func:`write_grasps_parquet` writes them so) is then read one row group at a
    time, holding one object's rows. Any other (``grasps.parquet``, sorted by scene) is read in passes: objects in
    name order are gathered in batches of about ``batch_rows`` rows, one pass over the row groups per batch (row
    groups whose ``object_name`` statistics rule the batch out are skipped unread). The same result as the whole
    table split by :func:`by_object`."""
    pf = pq.ParquetFile(path)
    is_sorted, counts = _scan_objects(pf, path)
    if not is_sorted:
        yield from _objects_in_passes(pf, columns, counts, batch_rows)
        return
    name: str | None = None
    parts: list[pa.Table] = []
    for i in range(pf.metadata.num_row_groups):
        group = pf.read_row_group(i, columns=columns)
        names = np.asarray(group.column("object_name").to_pylist(), dtype=object)
        starts = np.flatnonzero(np.r_[True, names[1:] != names[:-1]]) if len(names) else np.zeros(0, int)
        for j, start in enumerate(starts):
            stop = starts[j + 1] if j + 1 < len(starts) else len(names)
            if names[start] != name:
                if name is not None:
                    yield name, pa.concat_tables(parts)
                name, parts = str(names[start]), []
            parts.append(group.slice(start, stop - start))
    if name is not None:
        yield name, pa.concat_tables(parts)


def _scan_objects(pf: pq.ParquetFile, path: Path) -> tuple[bool, dict[str, int]]:
    """Whether the ``object_name`` column never decreases, and the rows of each object (one row group at a time)."""
    last = None
    ordered = True
    counts: dict[str, int] = {}
    for i in range(pf.metadata.num_row_groups):
        names = np.asarray(pf.read_row_group(i, columns=["object_name"]).column(0).to_pylist(), dtype=object)
        _check_object_names(names, path)
        if len(names) == 0:
            continue
        if (last is not None and names[0] < last) or bool(np.any(names[1:] < names[:-1])):
            ordered = False
        last = names[-1]
        for name, n in zip(*np.unique(names, return_counts=True)):
            counts[str(name)] = counts.get(str(name), 0) + int(n)
    return ordered, counts


def _objects_in_passes(pf: pq.ParquetFile, columns: list[str], counts: dict[str, int],
                       batch_rows: int) -> Iterator[tuple[str, pa.Table]]:
    """The objects of an unsorted table in name order, gathered a batch of about ``batch_rows`` rows per pass."""
    batches: list[list[str]] = [[]]
    rows = 0
    for name in sorted(counts):
        if batches[-1] and rows + counts[name] > batch_rows:
            batches.append([])
            rows = 0
        batches[-1].append(name)
        rows += counts[name]
    leaves = pf.metadata.schema
    column = next(j for j in range(len(leaves)) if leaves.column(j).path == "object_name")
    for batch in batches:
        if not batch:
            continue
        parts: dict[str, list[pa.Table]] = {name: [] for name in batch}
        for i in range(pf.metadata.num_row_groups):
            stats = pf.metadata.row_group(i).column(column).statistics
            if stats is not None and stats.has_min_max and (stats.max < batch[0] or stats.min > batch[-1]):
                continue  # no object of the batch in this group
            group = pf.read_row_group(i, columns=columns)
            group = group.filter(pc.is_in(group.column("object_name"), value_set=pa.array(batch)))
            names = np.asarray(group.column("object_name").to_pylist(), dtype=object)
            for name in sorted(set(names.tolist())):
                parts[name].append(group.take(pa.array(np.flatnonzero(names == name))))
        for name in batch:
            yield name, pa.concat_tables(parts.pop(name))


def _check_object_names(names: np.ndarray, path: Path) -> None:
    if any(not isinstance(n, str) or not n or "/" in n or n in (".", "..") for n in names):
        raise InputError(f"{path}: object_name must be a non-empty file name (no '/') in every row")


def by_object(table: pa.Table, path: Path) -> list[tuple[str, pa.Table]]:
    """``table``'s rows per ``object_name``, objects in name order, rows in table order."""
    names = np.asarray(table.column("object_name").to_pylist(), dtype=object)
    _check_object_names(names, path)
    return [(str(name), table.take(pa.array(np.flatnonzero(names == name)))) for name in sorted(set(names))]
