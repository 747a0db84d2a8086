"""The card's label statistics in memory that does not grow with the table: exact up to a cap, then streamed figures
and a deterministic sample.

:class:`LabelTally` keeps every value up to :data:`EXACT_ROWS` rows (every figure exact); beyond it it streams what
merges exactly (count, min, max, mean, variance, counts of up to :data:`DISCRETE_LABEL_VALUES` distinct values, pair
counts) and keeps the :data:`SAMPLE_ROWS` rows of smallest :func:`row_hash` of (scene_id, grasp_id) for the
quantiles of continuous labels and the correlation coefficients; the card names the sample (``label_sample``).
Memory: at most ``EXACT_ROWS`` rows, then ``2 * SAMPLE_ROWS``. Why this design:
docs/decisions/2026-12-03-card-label-statistics.md.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Mapping, Sequence

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

__all__ = [
    "DISCRETE_LABEL_VALUES",
    "EXACT_ROWS",
    "SAMPLE_ROWS",
    "LabelTally",
    "Moments",
    "binned_counts",
    "count_quantiles",
    "row_hash",
]

EXACT_ROWS = 1 << 18
"""Rows up to which every label value is kept and every figure is exact (262,144: ~11 MB with four labels)."""

SAMPLE_ROWS = 1 << 18
"""Rows of the sample beyond :data:`EXACT_ROWS` (quantiles of continuous labels, correlation coefficients): a
quantile's rank within about 0.001 (one standard error, sqrt(p (1 - p) / k)), a correlation within about 0.002."""

DISCRETE_LABEL_VALUES = 32
"""A label with at most this many distinct values is counted per value (robustness and pfc of up to 31 copies, a
friction grid), not binned."""

HASH = "the rows with the smallest 64-bit hash of (scene_id, grasp_id)"
"""How the sample is chosen, as the card says it."""

_MIX = (np.uint64(0x9E3779B97F4A7C15), np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB))


def _mix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64's finaliser on a uint64 array (a bijection that spreads every input bit over the output)."""
    with np.errstate(over="ignore"):
        z = x + _MIX[0]
        z = (z ^ (z >> np.uint64(30))) * _MIX[1]
        z = (z ^ (z >> np.uint64(27))) * _MIX[2]
    return z ^ (z >> np.uint64(31))


def row_hash(scene_id: pa.Array | pa.ChunkedArray, grasp_id: np.ndarray) -> np.ndarray:
    """(n,) uint64 hash of each row's (scene_id, grasp_id): blake2b of the scene id (once per distinct id), mixed
    with the grasp id by SplitMix64. A function of the two values alone (no seed, no platform dependence)."""
    column = scene_id.combine_chunks() if isinstance(scene_id, pa.ChunkedArray) else scene_id
    encoded = pc.dictionary_encode(pc.fill_null(column, ""))
    scenes = np.asarray([int.from_bytes(hashlib.blake2b(s.encode(), digest_size=8).digest(), "little")
                         for s in encoded.dictionary.to_pylist()], dtype=np.uint64)
    idx = np.asarray(encoded.indices.to_numpy(zero_copy_only=False), np.int64)
    return _mix64(scenes[idx] ^ _mix64(np.asarray(grasp_id).astype(np.int64).view(np.uint64)))


class Moments:
    """Streamed figures of one label's finite values: count, mean, sum of squared deviations, min, max, and the
    count of each distinct value while there are at most :data:`DISCRETE_LABEL_VALUES` (None past that)."""

    def __init__(self) -> None:
        self.n = 0
        """Finite values seen."""
        self.mean = 0.0
        """Their mean (a part of one repeated value: that value exactly)."""
        self.m2 = 0.0
        """Sum of squared deviations from the mean (0 exactly when every value is the same)."""
        self.lo = np.inf
        """Smallest value (inf before any)."""
        self.hi = -np.inf
        """Largest value (-inf before any)."""
        self.distinct: dict[float, int] | None = {}
        """Count per distinct value, or None once there are more than :data:`DISCRETE_LABEL_VALUES`."""

    def add(self, v: np.ndarray) -> None:
        """Finite values of one row group."""
        other = Moments()
        other.n = len(v)
        if other.n:
            other.lo, other.hi = float(v.min()), float(v.max())
            other.mean = other.lo if other.lo == other.hi else float(v.mean())
            other.m2 = float(np.square(v - other.mean).sum())
            if self.distinct is not None:
                values, counts = np.unique(v, return_counts=True)
                other.distinct = dict(zip(values.tolist(), counts.tolist())) if len(values) <= DISCRETE_LABEL_VALUES \
                    else None
        self.merge(other)

    def merge(self, other: Moments) -> None:
        """Add another part's figures (Chan, Golub and LeVeque's pairwise update of mean and squared deviations)."""
        n = self.n + other.n
        if other.n:
            delta = other.mean - self.mean
            self.m2 = self.m2 + other.m2 + delta * delta * self.n * other.n / n
            self.mean = self.mean + delta * other.n / n if self.n else other.mean
            self.lo, self.hi = min(self.lo, other.lo), max(self.hi, other.hi)
        self.n = n
        if self.distinct is None or other.distinct is None:
            self.distinct = None
            return
        for value, count in other.distinct.items():
            self.distinct[value] = self.distinct.get(value, 0) + count
        if len(self.distinct) > DISCRETE_LABEL_VALUES:
            self.distinct = None

    @property
    def std(self) -> float:
        """Population standard deviation (numpy's ``std``)."""
        return float(np.sqrt(self.m2 / self.n)) if self.n else float("nan")


class LabelTally:
    """The ``labels`` columns of a table, fed row groups in order: every value up to ``exact_rows``, then streamed
    figures and a bottom-k sample of ``sample_rows`` rows (module docstring)."""

    def __init__(self, labels: Sequence[str], exact_rows: int = EXACT_ROWS, sample_rows: int = SAMPLE_ROWS):
        self.labels = list(labels)
        """The label columns, in the order of :attr:`pairs`."""
        self.exact_rows = int(exact_rows)
        """Rows up to which every value is kept."""
        self.sample_rows = int(sample_rows)
        """Rows of the sample past that."""
        self.rows = 0
        """Rows added (all of them, sampled or not)."""
        self.sampled = False
        """Whether the table passed ``exact_rows``: the held rows are then the sample."""
        self.moments = {c: Moments() for c in self.labels}
        """Per label, its streamed figures (all rows)."""
        self.pairs = np.zeros((len(self.labels), len(self.labels)), np.int64)
        """(L, L) int64 rows where both labels are finite (all rows)."""
        self._held: list[dict[str, np.ndarray]] = []
        """Parts of held rows: ``_hash`` (uint64), ``_outcome`` (int8) and each label (float64)."""
        self._held_rows = 0
        self._threshold: np.uint64 | None = None
        """Sampling: rows with a hash at or above it are not in the sample (None: none dropped yet)."""

    @property
    def held_rows(self) -> int:
        """Rows held now (what the tally's memory grows with)."""
        return self._held_rows

    @property
    def nbytes(self) -> int:
        """Bytes of the rows held now."""
        return sum(a.nbytes for part in self._held for a in part.values())

    def add(self, hashes: np.ndarray, outcome: np.ndarray, values: Mapping[str, np.ndarray]) -> None:
        """One row group: (n,) uint64 :func:`row_hash`, (n,) outcome codes and (n,) float64 per label (NaN: none)."""
        finite = [np.isfinite(values[c]) for c in self.labels]
        for c, ok in zip(self.labels, finite):
            self.moments[c].add(values[c][ok])
        if finite:
            f = np.stack(finite).astype(np.int64)
            self.pairs += f @ f.T
        self.rows += len(hashes)
        part = {"_hash": np.asarray(hashes, np.uint64), "_outcome": np.asarray(outcome).astype(np.int8),
                **{c: np.asarray(values[c], np.float64) for c in self.labels}}
        self._hold(part)

    def merge(self, other: LabelTally) -> None:
        """Add another tally's rows after this one's (the next file or shard in order)."""
        for c in self.labels:
            self.moments[c].merge(other.moments[c])
        self.pairs += other.pairs
        self.rows += other.rows
        if other._threshold is not None:
            self._sample()
            self._threshold = other._threshold if self._threshold is None else min(self._threshold, other._threshold)
        for part in other._held:
            self._hold(part)

    def _hold(self, part: dict[str, np.ndarray]) -> None:
        if self.sampled and self._threshold is not None:
            keep = part["_hash"] < self._threshold
            part = {k: v[keep] for k, v in part.items()}
        if len(part["_hash"]):
            self._held.append(part)
            self._held_rows += len(part["_hash"])
        if not self.sampled and self.rows > self.exact_rows:
            self._sample()
        if self.sampled and self._held_rows >= 2 * self.sample_rows:
            self._prune()

    def _sample(self) -> None:
        """Switch to sampling: the rows held so far are pruned to the sample."""
        if not self.sampled:
            self.sampled = True
            self._prune()

    def _prune(self) -> None:
        """Keep the held rows whose hash is below the (k+1)-th smallest (k = ``sample_rows``), sorted by hash."""
        if not self._held:
            return
        whole = {k: np.concatenate([p[k] for p in self._held]) for k in self._held[0]}
        h = whole["_hash"]
        if len(h) > self.sample_rows:
            t = np.partition(h, self.sample_rows)[self.sample_rows]
            self._threshold = t if self._threshold is None else min(self._threshold, t)
        if self._threshold is not None:
            keep = h < self._threshold
            whole = {k: v[keep] for k, v in whole.items()}
        order = np.argsort(whole["_hash"], kind="stable")
        self._held = [{k: v[order] for k, v in whole.items()}]
        self._held_rows = len(order)

    def _column(self, key: str, dtype: type) -> np.ndarray:
        if self.sampled and len(self._held) > 1:
            self._prune()
        parts = [p[key] for p in self._held]
        return np.concatenate(parts) if parts else np.zeros(0, dtype)

    def values(self, column: str) -> np.ndarray:
        """(m,) float64 values of a label, nulls as NaN: every row in file order, or the sample's rows by hash."""
        return self._column(column, np.float64)

    @property
    def outcome(self) -> np.ndarray:
        """(m,) int8 outcome codes of the rows :meth:`values` gives."""
        return self._column("_outcome", np.int8)

    @property
    def hashes(self) -> np.ndarray:
        """(m,) uint64 :func:`row_hash` of the rows :meth:`values` gives."""
        return self._column("_hash", np.uint64)


def count_quantiles(values: np.ndarray, counts: np.ndarray, qs: Sequence[float]) -> np.ndarray:
    """Quantiles of the values ``values`` (k,) sorted, each ``counts`` (k,) times, as ``np.quantile`` of the values
    spelled out (linear interpolation, numpy's rounding of it) without spelling them out."""
    ends = np.cumsum(counts)
    n = int(ends[-1])

    def order(i: int) -> float:
        return float(values[np.searchsorted(ends, i, side="right")])

    out = []
    for q in qs:
        h = q * (n - 1)
        lo = int(np.floor(h))
        g = h - lo
        a, b = order(lo), order(min(lo + 1, n - 1))
        out.append(b - (b - a) * (1 - g) if g >= 0.5 else a + (b - a) * g)
    return np.asarray(out)


def binned_counts(groups: Iterable[np.ndarray], lo: float, hi: float, bins: int) -> np.ndarray:
    """(bins,) int64 histogram over [lo, hi] of the finite values of the (n,) float64 arrays in ``groups`` (e.g. row
    groups read one at a time), binned as :func:`graspgen.io.card_stats.label_summary` bins (an edge value goes up)."""
    total = np.zeros(bins, np.int64)
    for v in groups:
        v = np.asarray(v, np.float64)
        v = v[np.isfinite(v)]
        nudged = np.minimum(v + 1e-9 * (hi - lo), hi)
        total += np.histogram(nudged, bins=bins, range=(lo, hi))[0]
    return total
