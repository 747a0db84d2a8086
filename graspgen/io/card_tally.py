"""The card's counts, taken one row group at a time: running tallies of a published table, never the table.

:class:`GraspTally` reads ``grasps.parquet`` group by group and keeps running counts (outcomes overall, per object
and per scene, grippers), where each scene's rows are (runs of row positions, one per scene in a sorted file) and
the label columns in bounded memory (:class:`graspgen.io.card_labels.LabelTally`: every value up to
:data:`graspgen.io.card_labels.EXACT_ROWS` rows, then streamed figures and a deterministic sample).
:class:`ObjectSetTally` and :class:`PlacedTally` do the same for ``object_grasps.parquet`` and
``placed_grasps.parquet``, where every figure is a count. Each tally has ``add`` (one row group) and ``merge``
(another tally, e.g. of another file or shard): counts add, so the figures equal those of the whole table read at
once. :class:`CardTable` is what the plots read instead of the table: the label values and outcomes the label tally
holds, the rows of each scene, and whole rows of the few example scenes read on demand.
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
from graspgen.io.card_labels import EXACT_ROWS, SAMPLE_ROWS, LabelTally, row_hash
from graspgen.io.dataset_table import OUTCOME_NAMES, float_values

__all__ = ["OBJECT_SET_COUNTS", "CardTable", "GraspTally", "ObjectSetTally", "PlacedTally", "row_groups"]

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


def _add_runs(into: dict[str, list[list[int]]], names: list[str], idx: np.ndarray, offset: int) -> None:
    """Add the runs of consecutive rows of each scene (``idx`` (n,) indexes ``names``; rows from ``offset``) to
    ``into`` (per scene ``[start, stop)`` runs, a run that continues the last one joined to it)."""
    if len(idx) == 0:
        return
    starts = np.flatnonzero(np.r_[True, idx[1:] != idx[:-1]])
    stops = np.r_[starts[1:], len(idx)]
    for a, b in zip(starts.tolist(), stops.tolist()):
        runs = into.setdefault(names[idx[a]], [])
        if runs and runs[-1][1] == offset + a:
            runs[-1][1] = offset + b
        else:
            runs.append([offset + a, offset + b])


class GraspTally:
    """Running counts of ``grasps.parquet`` and its labels in bounded memory, fed row groups in file order.

    Parameters
    ----------
    labels : sequence of str
        The label columns summarised (those of the table).
    exact_rows, sample_rows : int
        Of the label tally (:class:`graspgen.io.card_labels.LabelTally`).
    """

    def __init__(self, labels: Sequence[str], exact_rows: int = EXACT_ROWS, sample_rows: int = SAMPLE_ROWS):
        self.labels = list(labels)
        self.rows = 0
        self.outcomes = np.zeros(CODES, np.int64)
        """(6,) int64 grasps per outcome code."""
        self.objects: dict[str, np.ndarray] = {}
        """Per object: (7,) int64, grasps per outcome code then all its grasps (codes outside 0-5 included)."""
        self.scenes: dict[str, int] = {}
        """Grasps per scene id."""
        self.grippers: set[str] = set()
        self.scene_runs: dict[str, list[list[int]]] = {}
        """Per scene id, its rows as ``[start, stop)`` runs of file positions (one run per scene in a file sorted
        by scene): what the examples plot reads, in memory that grows with the scenes, not the rows."""
        self.label_tally = LabelTally(self.labels, exact_rows, sample_rows)
        """The label columns and outcomes: every row up to ``exact_rows``, then streamed figures and a sample."""

    def add(self, t: pa.Table) -> None:
        """One row group (columns scene_id, grasp_id, object_name, outcome, gripper and the labels)."""
        outcome = t.column("outcome").to_numpy().astype(np.int64)
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
        _add_runs(self.scene_runs, scenes, sidx, self.rows)
        self.rows += len(t)
        self.grippers.update(t.column("gripper").unique().to_pylist())
        hashes = row_hash(t.column("scene_id"), t.column("grasp_id").to_numpy())
        self.label_tally.add(hashes, outcome.astype(np.int8), {c: float_values(t.column(c)) for c in self.labels})

    def merge(self, other: GraspTally) -> None:
        """Add another tally's rows after this one's (the next file or shard in order)."""
        self.outcomes += other.outcomes
        _add_counts(self.objects, list(other.objects), np.asarray(list(other.objects.values())).reshape(-1, 7))
        for name, n in other.scenes.items():
            self.scenes[name] = self.scenes.get(name, 0) + n
        for name, runs in other.scene_runs.items():
            mine = self.scene_runs.setdefault(name, [])
            for a, b in runs:
                if mine and mine[-1][1] == self.rows + a:
                    mine[-1][1] = self.rows + b
                else:
                    mine.append([self.rows + a, self.rows + b])
        self.rows += other.rows
        self.grippers |= other.grippers
        self.label_tally.merge(other.label_tally)

    def scene_rows(self, scene_id: str) -> np.ndarray:
        """(m,) int64 file positions of the rows of ``scene_id``, in file order (empty when it has none)."""
        runs = self.scene_runs.get(scene_id, [])
        return np.concatenate([np.arange(a, b) for a, b in runs]) if runs else np.zeros(0, np.int64)


class CardTable:
    """What :func:`graspgen.viz.plots.draw_plots` reads of ``grasps.parquet``, in memory that does not grow with it.

    ``column`` gives the outcome and label columns the label tally holds: every row in file order up to its cap,
    else the sample's rows (:attr:`sampled`); :attr:`hashes` are those rows' :func:`graspgen.io.card_labels.row_hash`.
    ``scene_ids`` and ``scene_rows`` give the scenes and their rows' file positions, and ``take`` reads whole rows
    (the card columns) of the row groups that hold them: the plots take the rows of a few example scenes only. Any
    other column is not held: KeyError.

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
        self.sampled = tally.label_tally.sampled
        """Whether the label columns are a sample of the rows (the table passed the label tally's cap)."""
        self._arrays = {c: tally.label_tally.values(c) for c in tally.labels}
        self._arrays["outcome"] = tally.label_tally.outcome
        self.hashes = tally.label_tally.hashes
        """(m,) uint64 row hashes of the rows ``column`` gives."""
        meta = pq.ParquetFile(self.path).metadata
        self._starts = np.cumsum([0] + [meta.row_group(i).num_rows for i in range(meta.num_row_groups)])

    def __len__(self) -> int:
        return self._tally.rows

    @property
    def scene_ids(self) -> list[str]:
        """The scene ids with rows, sorted."""
        return sorted(self._tally.scene_runs)

    def scene_rows(self, scene_id: str) -> np.ndarray:
        """(m,) int64 file positions of a scene's rows."""
        return self._tally.scene_rows(scene_id)

    def column(self, name: str) -> Any:
        if name not in self._arrays:
            raise NotFoundError(f"{name}: not held by the card's table (columns held: outcome, labels)")
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


OBJECT_SET_COUNTS = ("grasps", "held", "firm", "near_miss", "near_miss_held", "collision", "no_contact", "slipped",
                     "held_not_firm")
"""Per-object counts of :class:`ObjectSetTally`, in order: kept grasps, held (outcome 5), firm, near misses and
the held ones among them, and the outcome mix (collisions at placement: outcomes 0-2; 3; 4; held but not firm)."""


class ObjectSetTally:
    """Running counts of ``object_grasps.parquet`` per object (:data:`OBJECT_SET_COUNTS`)."""

    def __init__(self) -> None:
        self.objects: dict[str, np.ndarray] = {}
        """Per object: (9,) int64 counts, :data:`OBJECT_SET_COUNTS`."""

    def add(self, t: pa.Table) -> None:
        """One row group (columns object_name, candidate, outcome, success, firm)."""
        names, idx = _codes(t.column("object_name"))
        held = t.column("success").to_numpy(zero_copy_only=False).astype(bool)
        firm = t.column("firm").to_numpy(zero_copy_only=False).astype(bool)
        code = t.column("outcome").to_numpy(zero_copy_only=False).astype(np.int64)
        near = pc.fill_null(pc.equal(t.column("candidate"), "near_miss"), False).to_numpy(zero_copy_only=False)
        weights = (np.ones(len(idx)), held, firm, near, near & held, code <= 2, code == 3, code == 4, held & ~firm)
        per = np.stack([np.bincount(idx, weights=w, minlength=len(names)) for w in weights], axis=1).astype(np.int64)
        _add_counts(self.objects, names, per)

    def merge(self, other: ObjectSetTally) -> None:
        _add_counts(self.objects, list(other.objects),
                    np.asarray(list(other.objects.values())).reshape(-1, len(OBJECT_SET_COUNTS)))


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
