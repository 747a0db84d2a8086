"""The output folder: shard paths, atomic writes, per-stage manifests and the run lock.

Layout::

    OUT/shards/<stage>/<key[:2]>/<key>.<ext>     one shard per task
    OUT/shards/<stage>/manifest.jsonl            append-only log of finished tasks: the commit point
    OUT/shards/config.yaml                       the resolved config of the latest run (written at its start)
    OUT/.lock                                    held (flock) by the run writing OUT

The engine keeps to ``OUT/shards`` and ``OUT/.lock``; the rest of OUT belongs to what stages publish for people
(:meth:`pipeline.stage.Stage.publish`), so a published folder holds only published files.

A shard without a manifest entry does not exist: a run killed between writing a shard and appending its entry
simply redoes that task (and writes the same bytes again). A manifest line cut short by a kill is ignored.
"""

from __future__ import annotations

import dataclasses
import fcntl
import json
import os
import socket
from collections.abc import Collection, Iterator, Mapping
from pathlib import Path
from typing import Any

from pipeline.errors import LockError

# Atomic writes live in shared_utils, below the engine and the library alike; re-exported as this module's own.
from shared_utils.atomic import TEMP_SUFFIX as TEMP_SUFFIX
from shared_utils.atomic import atomic_path as atomic_path
from shared_utils.atomic import file_mode as file_mode
from shared_utils.atomic import write_text_atomic as write_text_atomic
from shared_utils.digest import sha256_file

MANIFEST = "manifest.jsonl"
SHARDS = "shards"
"""The engine's folder in OUT: one sub-folder of shards and a manifest per stage."""


RUN_CONFIG = "config.yaml"
"""The resolved config of the latest run, kept in the engine's folder: commands without ``--config`` use it."""


def run_config_path(out: str | os.PathLike) -> Path:
    """Where a run folder remembers the config that made it: ``OUT/shards/config.yaml``."""
    return Path(out) / SHARDS / RUN_CONFIG


def stage_dir(out: str | os.PathLike, stage: str) -> Path:
    """The engine's folder of ``stage`` in the output folder ``out``: ``OUT/shards/<stage>``."""
    return Path(out) / SHARDS / stage


class MetaText(Mapping[str, Any]):
    """An entry's ``meta`` held as its compact JSON text and decoded on each read.

    Why: the engine holds every shard's entry of every stage it plans, and decoded metadata (per-object counts,
    outcome tables) takes several times its text in memory (docs/decisions/2026-12-03-engine-at-scale.md). Read it
    whole with :meth:`to_dict` (a ``Mapping`` lookup decodes the text each time).
    """

    __slots__ = ("text",)

    def __init__(self, text: str):
        self.text = text

    def to_dict(self) -> dict[str, Any]:
        """The metadata as a fresh dict."""
        return json.loads(self.text)

    def __getitem__(self, name: str) -> Any:
        return self.to_dict()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self.to_dict())

    def __len__(self) -> int:
        return len(self.to_dict())

    def __deepcopy__(self, memo: dict) -> dict[str, Any]:
        return self.to_dict()  # so that dataclasses.asdict (Entry.to_json) writes the plain dict

    def __repr__(self) -> str:
        return f"MetaText({self.text!r})"


@dataclasses.dataclass(frozen=True)
class Entry:
    """One manifest line: the record of a finished (or failed) task."""

    key: str
    """Content key of the task."""
    task: str
    """Task id, unique within its stage (e.g. an object name)."""
    status: str
    """``ok`` or ``failed``."""
    file: str | None = None
    """Shard path relative to the stage folder (None for a failed task)."""
    sha256: str | None = None
    """sha256 of the shard's bytes."""
    bytes: int = 0
    """Shard size in bytes."""
    seconds: float = 0.0
    """Wall time the task took, in seconds."""
    cpu_seconds: float = 0.0
    """CPU time the task's process spent on it, in seconds (what a cost model needs: wall time grows with the
    machine's load, CPU time does not). 0 in manifests written before the field existed."""
    parts: dict[str, str] = dataclasses.field(default_factory=dict)
    """The key's components (see :func:`pipeline.keys.key_parts`), to explain staleness."""
    meta: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    """Small stage-defined metadata (row counts, warnings) that downstream ``tasks()`` may read: a dict, or a
    :class:`MetaText` in the entries the engine holds (``Manifest.entries(compact=True)``); read it whole with
    :meth:`meta_dict`."""
    error: str | None = None
    """Error text of a failed task."""
    seed: str | None = None
    """The seed key the task's random generator came from (:func:`pipeline.keys.seed_key`); downstream seed keys
    name this shard by it."""

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True, separators=(",", ":"))

    def compacted(self, stage_parts: dict[str, dict[str, str]] | None = None) -> Entry:
        """This entry as the engine holds it (:meth:`Manifest.entries` with ``compact=True``): the key's parts cut
        to ``stage`` (one dict per stage part, shared through ``stage_parts``), the metadata as a
        :class:`MetaText`."""
        stage = self.parts.get("stage")
        shared = {} if stage_parts is None else stage_parts
        parts = {} if stage is None else shared.setdefault(stage, {"stage": stage})
        meta = self.meta if isinstance(self.meta, MetaText) else MetaText(json.dumps(self.meta, separators=(",", ":")))
        return dataclasses.replace(self, parts=parts, meta=meta)

    def meta_dict(self) -> dict[str, Any]:
        """:attr:`meta` as a fresh dict."""
        return self.meta.to_dict() if isinstance(self.meta, MetaText) else dict(self.meta)


def shard_path(stage_dir: Path, key: str, ext: str) -> Path:
    """Where the shard of ``key`` lives: ``<stage_dir>/<key[:2]>/<key>.<ext>``."""
    return stage_dir / key[:2] / f"{key}.{ext}"


class Manifest:
    """The append-only manifest of one stage folder."""

    def __init__(self, stage_dir: Path):
        self.stage_dir = Path(stage_dir)
        self.path = self.stage_dir / MANIFEST

    def entries(self, *, compact: bool = False) -> dict[str, Entry]:
        """The latest entry per key (a later line overrides an earlier one, e.g. a retried failure).

        ``compact=True`` gives the entries as the engine holds them, a third of the memory: the key's parts cut
        to its ``stage`` part (the rest, one code digest per source file, only explains staleness:
        :meth:`parts`), the metadata as a :class:`MetaText`.
        """
        out: dict[str, Entry] = {}
        stage_parts: dict[str, dict[str, str]] = {}
        for fields in self._lines():
            try:
                entry = Entry(**fields)
            except TypeError:
                continue  # not an entry of this version's fields
            out[entry.key] = entry.compacted(stage_parts) if compact else entry
        return out

    def parts(self, keys: Collection[str]) -> dict[str, dict[str, str]]:
        """The full key parts of the entries of ``keys`` (the latest line of each), by key."""
        wanted = set(keys)
        return {f["key"]: f.get("parts", {}) for f in self._lines() if f.get("key") in wanted}

    def _lines(self) -> Iterator[dict[str, Any]]:
        """Each committed line as a dict, in file order."""
        if not self.path.exists():
            return
        with open(self.path) as f:
            for line in f:
                line = line.strip()
                if not line:
                    continue
                try:
                    fields = json.loads(line)
                except json.JSONDecodeError:
                    continue  # a line cut short by a kill: that task is simply not committed
                if isinstance(fields, dict):
                    yield fields

    def append(self, entry: Entry) -> None:
        """Commit ``entry``: append one line and fsync, so it survives a kill right after."""
        self.stage_dir.mkdir(parents=True, exist_ok=True)
        with open(self.path, "a") as f:
            f.write(entry.to_json() + "\n")
            f.flush()
            os.fsync(f.fileno())

    def shard_ok(self, entry: Entry, *, verify_hash: bool = True) -> bool:
        """True when ``entry`` is a success whose shard exists with the recorded size (and sha256)."""
        if entry.status != "ok" or entry.file is None:
            return False
        path = self.stage_dir / entry.file
        try:
            if path.stat().st_size != entry.bytes:
                return False
        except OSError:
            return False
        return not verify_hash or sha256_file(path) == entry.sha256


def remove_stray_temps(root: Path) -> list[Path]:
    """Delete the temp files a killed run left under ``root`` (call with the run lock held). Returns them."""
    stray = sorted(p for p in Path(root).rglob(f".*{TEMP_SUFFIX}") if p.is_file())
    for path in stray:
        path.unlink(missing_ok=True)
    return stray


class RunLock:
    """An exclusive ``flock`` on ``OUT/.lock``: one run writes an output folder at a time.

    The OS drops the lock when the holder dies (even by ``kill -9``), so a stale lock cannot block a resume.
    """

    def __init__(self, out: Path):
        self.path = Path(out) / ".lock"
        self._fd: int | None = None

    def __enter__(self) -> RunLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 200).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise LockError(
                f"{self.path.parent}: another run is writing this output folder ({holder}); "
                "wait for it or use another --out"
            ) from None
        os.ftruncate(fd, 0)
        os.write(fd, f"pid {os.getpid()} on {socket.gethostname()}".encode())
        self._fd = fd
        return self

    def __exit__(self, *exc: object) -> None:
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None
