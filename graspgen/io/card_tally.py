"""The card's counts, taken one row group at a time: running tallies of a published table, never the table.

:class:`GraspTally` reads ``grasps.parquet`` group by group and keeps running counts (outcomes overall, per object
and per scene, grippers) and the label columns as bare float64 arrays (the order statistics, histograms and rank
correlations of :func:`graspgen.io.card_stats.label_summary` need every value: 8 bytes a row per label instead of the
whole row). :class:`ObjectSetTally` and :class:`PlacedTally` do the same for ``object_grasps.parquet`` and
``placed_grasps.parquet``, where every figure is a count. Each tally has ``add`` (one row group) and ``merge``
(another tally, e.g. of another file or shard): counts add, so the figures equal those of the whole table read at
once. :class:`CardTable` is what the plots read instead of the table: the label arrays, the outcome, each row's
scene by reference, and whole rows of the few example scenes read on demand.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from graspgen.errors import NotFoundError
from graspgen.io.dataset_table import OUTCOME_NAMES, float_values

__all__ = ["CardTable", "GraspTally", "ObjectSetTally", "PlacedTally", "row_groups"]

CODES = len(OUTCOME_NAMES)


def row_groups(path: str | Path, columns: Sequence[str]) -> Iterator[pa.Table]:
    """The row groups of a Parquet file, one at a time, with ``columns`` only."""
    pf = pq.ParquetFile(path)
    for i in range(pf.metadata.num_row_groups):
        yield pf.read_row_group(i, columns=list(columns))


def _codes(column: pa.ChunkedArray) -> tuple[list[str], np.ndarray]:
    """A string column as (distinct values, (rows,) int64 index of each row's value); a null reads as "" (no object
    or scene has that name, so it counts for none, as a null did when the whole column was compared)."""
    encoded = pc.dictionary_encode(pc.fill_null(column.combine_chunks(), ""))
    return encoded.dictionary.to_pylist(), np.asarray(encoded.indices.to_numpy(zero_copy_only=False), np.int64)


def _add_counts(into: dict[str, np.ndarray], names: list[str], counts: np.ndarray) -> None:
    for name, row in zip(names, counts):
        if name in into:
            into[name] += row
        else:
            into[name] = row.copy()


class GraspTally:
    """Running counts and label values of ``grasps.parquet``, fed row groups in file order.

    Parameters
    ----------
    labels : sequence of str
        The label columns whose values are kept (those of the table).
    """

    def __init__(self, labels: Sequence[str]):
        self.labels = list(labels)
        self.rows = 0
        self.outcomes = np.zeros(CODES, np.int64)
        """(6,) int64 grasps per outcome code."""
        self.objects: dict[str, np.ndarray] = {}
        """Per object: (7,) int64, grasps per outcome code then all its grasps (codes outside 0-5 included)."""
        self.scenes: dict[str, int] = {}
        """Grasps per scene id."""
        self.grippers: set[str] = set()
        self.scene_names: list[str] = []
        """Scene ids in order of first appearance; :attr:`scene_of_row` indexes them."""
        self._scene_index: dict[str, int] = {}
        self._values: dict[str, list[np.ndarray]] = {c: [] for c in self.labels}
        self._outcome: list[np.ndarray] = []
        self._scene_rows: list[np.ndarray] = []

    def add(self, t: pa.Table) -> None:
        """One row group (columns scene_id, object_name, outcome, gripper and the labels)."""
        outcome = t.column("outcome").to_numpy().astype(np.int64)
        self.rows += len(t)
        valid = (outcome >= 0) & (outcome < CODES)
        self.outcomes += np.bincount(outcome[valid], minlength=CODES)[:CODES]
        names, idx = _codes(t.column("object_name"))
        per = np.zeros((len(names), CODES + 1), np.int64)
        np.add.at(per, (idx[valid], outcome[valid]), 1)
        per[:, CODES] = np.bincount(idx, minlength=len(names))
        _add_counts(self.objects, names, per)
        scenes, sidx = _codes(t.column("scene_id"))
        for name, n in zip(scenes, np.bincount(sidx, minlength=len(scenes)).tolist()):
            self.scenes[name] = self.scenes.get(name, 0) + n
            if name not in self._scene_index:
                self._scene_index[name] = len(self.scene_names)
                self.scene_names.append(name)
        self._scene_rows.append(np.asarray([self._scene_index[s] for s in scenes], np.int32)[sidx])
        self.grippers.update(t.column("gripper").unique().to_pylist())
        self._outcome.append(outcome.astype(np.int8))
        for c in self.labels:
            self._values[c].append(float_values(t.column(c)))

    def merge(self, other: GraspTally) -> None:
        """Add another tally's rows after this one's (the next file or shard in order)."""
        self.rows += other.rows
        self.outcomes += other.outcomes
        _add_counts(self.objects, list(other.objects), np.asarray(list(other.objects.values())).reshape(-1, 7))
        for name, n in other.scenes.items():
            self.scenes[name] = self.scenes.get(name, 0) + n
            if name not in self._scene_index:
                self._scene_index[name] = len(self.scene_names)
                self.scene_names.append(name)
        remap = np.asarray([self._scene_index[s] for s in other.scene_names], np.int32)
        self._scene_rows += [remap[r] for r in other._scene_rows]
        self.grippers |= other.grippers
        self._outcome += other._outcome
        for c in self.labels:
            self._values[c] += other._values[c]

    def values(self, column: str) -> np.ndarray:
        """(rows,) float64 values of a label column, nulls as NaN, in file order."""
        parts = self._values[column]
        return np.concatenate(parts) if parts else np.zeros(0)

    @property
    def outcome(self) -> np.ndarray:
        """(rows,) int8 outcome codes in file order."""
        return np.concatenate(self._outcome) if self._outcome else np.zeros(0, np.int8)

    @property
    def scene_of_row(self) -> np.ndarray:
        """(rows,) int32 index into :attr:`scene_names` of each row's scene."""
        return np.concatenate(self._scene_rows) if self._scene_rows else np.zeros(0, np.int32)


class _Names:
    """A string column seen as one name per row without a string per row (what ``to_pylist`` of the plots needs)."""

    def __init__(self, names: list[str], rows: np.ndarray):
        self._names, self._rows = names, rows

    def __len__(self) -> int:
        return len(self._rows)

    def to_pylist(self) -> list[str]:
        return [self._names[i] for i in self._rows.tolist()]


class CardTable:
    """What :func:`graspgen.viz.plots.draw_plots` reads of ``grasps.parquet``, with the memory of a few columns.

    ``column`` gives the outcome and label columns (arrays the tally kept) and ``scene_id`` (one reference per row);
    ``take`` reads whole rows (the card columns) of the row groups that hold them: the plots take the rows of a few
    example scenes only. Any other column is not held: KeyError.

    Parameters
    ----------
    path : path
        The grasps.parquet.
    columns : sequence of str
        The card columns (:func:`graspgen.io.card_stats.card_stats`), in file order: what ``take`` returns.
    tally : GraspTally
        The tally of that file, fed every row group in order.
    """

    def __init__(self, path: str | Path, columns: Sequence[str], tally: GraspTally):
        self.path = Path(path)
        self.column_names = list(columns)
        self._tally = tally
        self._arrays = {c: tally.values(c) for c in tally.labels}
        self._arrays["outcome"] = tally.outcome
        meta = pq.ParquetFile(self.path).metadata
        self._starts = np.cumsum([0] + [meta.row_group(i).num_rows for i in range(meta.num_row_groups)])

    def __len__(self) -> int:
        return self._tally.rows

    def column(self, name: str) -> Any:
        if name == "scene_id":
            return _Names(self._tally.scene_names, self._tally.scene_of_row)
        if name not in self._arrays:
            raise NotFoundError(f"{name}: not held by the card's table (columns held: outcome, scene_id, labels)")
        return pa.chunked_array([pa.array(self._arrays[name])])

    def take(self, indices: Any) -> pa.Table:
        """The rows at ``indices`` (positions in the file), every card column, read from their row groups."""
        rows = np.asarray(indices.to_numpy() if hasattr(indices, "to_numpy") else indices, np.int64)
        groups = sorted(set((np.searchsorted(self._starts, rows, side="right") - 1).tolist()))
        pf = pq.ParquetFile(self.path)
        parts = [pf.read_row_group(g, columns=self.column_names) for g in groups]
        if not parts:
            return pf.schema_arrow.empty_table().select(self.column_names)
        local = np.concatenate([np.arange(self._starts[g], self._starts[g + 1]) for g in groups])
        return pa.concat_tables(parts).take(pa.array(np.searchsorted(local, rows)))


class ObjectSetTally:
    """Running counts of ``object_grasps.parquet``: per object grasps, positives, near misses and their successes."""

    def __init__(self) -> None:
        self.objects: dict[str, np.ndarray] = {}
        """Per object: (4,) int64 grasps, positives, near misses, near misses that succeeded."""

    def add(self, t: pa.Table) -> None:
        """One row group (columns object_name, candidate, success)."""
        names, idx = _codes(t.column("object_name"))
        ok = t.column("success").to_numpy(zero_copy_only=False).astype(bool)
        near = pc.fill_null(pc.equal(t.column("candidate"), "near_miss"), False).to_numpy(zero_copy_only=False)
        per = np.stack([np.bincount(idx, weights=w, minlength=len(names)) for w in
                        (np.ones(len(idx)), ok, near, near & ok)], axis=1).astype(np.int64)
        _add_counts(self.objects, names, per)

    def merge(self, other: ObjectSetTally) -> None:
        _add_counts(self.objects, list(other.objects), np.asarray(list(other.objects.values())).reshape(-1, 4))


PLACED_COUNTS = ("grasps", "free", "support_collisions", "clutter_collisions", "positives", "checked", "changed",
                 "pos", "lost", "neg", "gained")


class PlacedTally:
    """Running counts of ``placed_grasps.parquet`` (:data:`PLACED_COUNTS`) and the scenes named."""

    def __init__(self) -> None:
        self.counts = dict.fromkeys(PLACED_COUNTS, 0)
        self.scenes: set[str] = set()

    def add(self, t: pa.Table) -> None:
        """One row group (columns scene_id, scene_code, object_success, success, rescene_outcome, rescene_success)."""
        code = t.column("scene_code").to_numpy()
        ok = t.column("success").to_numpy(zero_copy_only=False).astype(bool)
        obj_ok = t.column("object_success").to_numpy(zero_copy_only=False).astype(bool)
        checked = t.column("rescene_outcome").to_numpy() >= 0
        re_ok = np.asarray([bool(v) for v in t.column("rescene_success").to_pylist()], dtype=bool)
        pos, neg = checked & obj_ok, checked & ~obj_ok
        found = {
            "grasps": len(t), "free": (code < 0).sum(), "support_collisions": (code == 0).sum(),
            "clutter_collisions": (code == 2).sum(), "positives": ok.sum(), "checked": checked.sum(),
            "changed": (checked & (re_ok != obj_ok)).sum(), "pos": pos.sum(), "lost": (pos & ~re_ok).sum(),
            "neg": neg.sum(), "gained": (neg & re_ok).sum(),
        }
        for k, v in found.items():
            self.counts[k] += int(v)
        self.scenes.update(t.column("scene_id").unique().to_pylist())

    def merge(self, other: PlacedTally) -> None:
        for k, v in other.counts.items():
            self.counts[k] += v
        self.scenes |= other.scenes
