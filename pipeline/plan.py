"""Planning: a stage's tasks and their content keys, and what of them is already committed.

:func:`plan` gives every task of a stage its key (:mod:`pipeline.keys`) from its params, payload, upstream
shards, input files and code fingerprint; :func:`committed` and :func:`upstream_view` say which shards under
those keys are on disk and intact. The run (:mod:`pipeline.scheduler`) and ``status`` (:mod:`pipeline.status`)
both plan through here, so they agree on what is done.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import hashlib
import json
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from pipeline.errors import StageError
from pipeline.fingerprint import stage_fingerprint
from pipeline.keys import key_parts, params_digest, seed_key, sha256_file, sha256_text, task_key, upstream_digest
from pipeline.stage import Stage, Task, Upstream
from pipeline.store import Entry, Manifest, stage_dir

# The engine holds every entry of every stage it plans, so it holds them compact (Manifest.entries(compact=True)):
# most of a manifest line is key parts and metadata (docs/decisions/2026-12-03-engine-at-scale.md).


def read_entries(manifest: Manifest) -> dict[str, Entry]:
    """:meth:`Manifest.entries` as the engine holds them (``compact=True``: the key parts cut to ``stage``, the
    metadata as its JSON text).

    Inside :func:`one_check_per_shard` a manifest is parsed once while it stays the same file (path, size,
    mtime, inode; a commit appends a line, so it grows): a run reads a stage's manifest when it plans the stage,
    when it plans each stage below it and when it finishes it (docs/decisions/2026-12-03-engine-at-scale.md)."""
    stamp = _manifest_stamp(manifest) if _manifests is not None else None
    if stamp is not None and _manifests is not None:
        cached = _manifests.get(str(manifest.path))
        if cached is not None and cached[0] == stamp:
            return dict(cached[1])
    entries = manifest.entries(compact=True)
    if stamp is not None and _manifests is not None and _manifest_stamp(manifest) == stamp:
        _manifests[str(manifest.path)] = (stamp, entries)
    return dict(entries)


def _manifest_stamp(manifest: Manifest) -> tuple[int, ...] | None:
    """(size, mtime, inode, device) of a manifest file; None when there is none."""
    try:
        st = manifest.path.stat()
    except OSError:
        return None
    return (st.st_size, st.st_mtime_ns, st.st_ino, st.st_dev)


class UpstreamDigests:
    """The upstream digests of a stage's tasks (:func:`pipeline.keys.upstream_digest` of ``upstream.keys(needs)``
    and of ``upstream.seeds(needs)``), equal to them character for character, built from one JSON text per
    ``(stage, ids)`` shared by the tasks that read the same shards.

    Why: a scene's task reads its scene and the whole object library, so hashing each task's upstream afresh walks
    ``scenes x objects`` keys, quadratic in the objects; here the library's text is made once per stage.
    """

    def __init__(self, upstream: Upstream):
        self.upstream = upstream
        self._texts: dict[tuple[str, str, tuple[str, ...]], str] = {}

    def keys(self, needs: Mapping[str, Sequence[str]]) -> str:
        """The digest of ``upstream.keys(needs)``."""
        return self._digest("keys", needs)

    def seeds(self, needs: Mapping[str, Sequence[str]]) -> str:
        """The digest of ``upstream.seeds(needs)``."""
        return self._digest("seeds", needs)

    def _digest(self, kind: str, needs: Mapping[str, Sequence[str]]) -> str:
        inputs = set(self.upstream.stages())
        unknown = sorted(set(needs) - inputs)
        if unknown:
            raise StageError(
                f"task needs stage {unknown[0]!r}, which is not an input; inputs: {sorted(inputs)}"
            )
        body = ",".join(f"{json.dumps(stage)}:{self._text(kind, stage, needs[stage])}" for stage in sorted(needs))
        return hashlib.sha256(("{" + body + "}").encode()).hexdigest()

    def _text(self, kind: str, stage: str, ids: Sequence[str]) -> str:
        """Canonical JSON of ``{task_id: key}`` (or seed key) of one stage's ``ids``."""
        cache = (kind, stage, tuple(ids))
        if cache not in self._texts:
            pick = self.upstream.key if kind == "keys" else self._seed
            values = {tid: pick(stage, tid) for tid in sorted(ids)}
            self._texts[cache] = json.dumps(values, sort_keys=True, separators=(",", ":"))
        return self._texts[cache]

    def _seed(self, stage: str, task_id: str) -> str:
        return self.upstream.entry(stage, task_id).seed or self.upstream.key(stage, task_id)


@dataclasses.dataclass(frozen=True)
class Project:
    """A pipeline: its config schema (a dataclass with a ``run: RunConfig`` field) and its stages."""

    name: str
    schema: type
    stages: tuple[Stage, ...]
    user_errors: tuple[type[BaseException], ...] = ()
    """Exception types (besides :class:`~pipeline.errors.GenError`) the command line reports in one line."""

    def stage(self, name: str) -> Stage:
        for s in self.stages:
            if s.name == name:
                return s
        raise StageError(f"unknown stage {name!r}; choose one of: {', '.join(s.name for s in self.stages)}")


@dataclasses.dataclass(frozen=True)
class PlannedTask:
    """A task with its content key (:func:`pipeline.keys.task_key` of ``parts``), the key's parts and its seed key."""

    task: Task
    key: str
    parts: dict[str, str]
    seed: str
    """The seed key (:func:`pipeline.keys.seed_key`): the task's random generator comes from it."""


def committed(out: Path, stage: str, *, verify_hash: bool = True) -> dict[str, Entry]:
    """Successful, intact entries of a stage folder, by key."""
    manifest = Manifest(stage_dir(out, stage))
    entries = read_entries(manifest)
    if verify_hash:
        check_shards(manifest, entries.values())
    return {k: e for k, e in entries.items() if shard_ok(manifest, e, verify_hash=verify_hash)}


_checked: dict[tuple[Any, ...], bool] | None = None
"""The shard checks of the run (or status) in progress, by file and expected hash; None outside one."""

_manifests: dict[str, tuple[tuple[int, ...], dict[str, Entry]]] | None = None
"""The manifests parsed by the run (or status) in progress, by path: (file stamp, entries); None outside one."""


@contextlib.contextmanager
def one_check_per_shard() -> Iterator[None]:
    """Within the block, :func:`shard_ok` hashes each shard file once: a run looks at a stage's shards when it
    plans the stage, plans each stage below it and publishes. A check is keyed by the file's path, size, mtime,
    inode and the expected sha256, so a shard the run writes (a new file) is checked anew. Likewise
    :func:`read_entries` parses each manifest once while the file stays the same."""
    global _checked, _manifests
    saved, _checked = (_checked, _manifests), {}
    _manifests = {}
    try:
        yield
    finally:
        _checked, _manifests = saved


def shard_ok(manifest: Manifest, entry: Entry, *, verify_hash: bool = True) -> bool:
    """:meth:`Manifest.shard_ok`, done once per shard file inside :func:`one_check_per_shard`."""
    if _checked is None or not verify_hash or entry.status != "ok" or entry.file is None:
        return manifest.shard_ok(entry, verify_hash=verify_hash)
    key = _check_key(manifest, entry)
    if key is None:
        return False
    if key not in _checked:
        _checked[key] = manifest.shard_ok(entry)
    return _checked[key]


def _check_key(manifest: Manifest, entry: Entry) -> tuple[Any, ...] | None:
    """What a shard check is remembered by: the file's path, size, mtime, inode and the expected size and sha256;
    None when the file is missing."""
    path = manifest.stage_dir / str(entry.file)
    try:
        st = path.stat()
    except OSError:
        return None
    return (str(path), st.st_size, st.st_mtime_ns, st.st_ino, st.st_dev, entry.bytes, entry.sha256)


HASH_THREADS = 4
"""Threads that hash shards side by side in :func:`check_shards` (sha256 and file reads release the GIL)."""


def check_shards(manifest: Manifest, entries: Iterable[Entry]) -> None:
    """Check the shards of ``entries`` (size and sha256) in :data:`HASH_THREADS` threads, ahead of the
    :func:`shard_ok` calls that will ask for them (inside :func:`one_check_per_shard`; a no-op outside one).

    Why: ``gen status`` and every ``gen run`` hash every shard they plan on; one file after the other that is one
    core, and a wait on every read from a cold disk or a network file system
    (docs/decisions/2026-12-03-engine-at-scale.md). The answers are :meth:`Manifest.shard_ok`'s, the same as one by
    one."""
    if _checked is None:
        return
    todo: dict[tuple[Any, ...], Entry] = {}
    for entry in entries:
        if entry.status == "ok" and entry.file is not None:
            key = _check_key(manifest, entry)
            if key is not None and key not in _checked:
                todo[key] = entry
    if len(todo) < 2:
        return
    with concurrent.futures.ThreadPoolExecutor(min(HASH_THREADS, len(todo))) as pool:
        for key, ok in zip(todo, pool.map(manifest.shard_ok, todo.values())):
            _checked[key] = ok


def upstream_view(out: Path, stage: Stage, current: dict[str, set[str]], *, verify_hash: bool = True) -> Upstream:
    """The committed shards of ``stage``'s inputs whose keys are current, by task id.

    ``current`` maps each upstream stage to the keys its tasks have under the present config (the scheduler
    plans stages in order, so it knows them). Shards of older configs stay on disk but are invisible here.
    """
    entries: dict[str, dict[str, Entry]] = {}
    for dep in stage.inputs:
        keys = current.get(dep, set())
        entries[dep] = {e.task: e for k, e in committed(out, dep, verify_hash=verify_hash).items() if k in keys}
    return Upstream(out, entries)


def view_entries(view: Upstream, stage: str) -> dict[str, Entry]:
    """``{task_id: Entry}`` of one stage in an upstream view."""
    return {tid: view.entry(stage, tid) for tid in view.ids(stage)}


def _task_key(parts: dict[str, str]) -> str:
    """:func:`pipeline.keys.task_key` of a task's parts, a flat dict of strings: that is its own JSON form, so the
    canonical text is ``json.dumps`` of it, without the general walk (a third of planning time at 5,000 tasks)."""
    if all(type(k) is str and type(v) is str for k, v in parts.items()):
        return sha256_text(json.dumps(parts, sort_keys=True, separators=(",", ":")))
    return task_key(parts)


def plan(stage: Stage, params: Any, upstream: Upstream, *, seed: int = 0) -> list[PlannedTask]:
    """The stage's tasks with their content keys; ``seed`` is the run's (``config.run.seed``, see
    :func:`pipeline.keys.key_parts`): 0 leaves the keys as they were before the seed existed."""
    tasks = stage.tasks(params, upstream)
    seen: dict[str, Task] = {}
    for t in tasks:
        if t.id in seen:
            raise StageError(f"{stage.name}: two tasks share the id {t.id!r}; task ids must be unique")
        seen[t.id] = t
    file_hashes: dict[str, str] = {}
    code = stage_fingerprint(type(stage).__module__)
    params_hash = params_digest(params)  # the same for every task: hashed once, not once per task
    planned = []
    digests = UpstreamDigests(upstream)
    every: tuple[str, str] | None = None  # the upstream digests of a task that reads everything: the same for all
    for t in tasks:
        if t.needs is not None:
            up = (digests.keys(t.needs), digests.seeds(t.needs))
        else:
            every = every or (upstream_digest(upstream.keys(None)), upstream_digest(upstream.seeds(None)))
            up = every
        hashes = {}
        for i, path in enumerate(t.inputs):
            if path not in file_hashes:
                file_hashes[path] = sha256_file(path)
            hashes[str(i)] = file_hashes[path]
        parts = key_parts(
            stage=stage.name,
            version=stage.version,
            params=params,
            params_hash=params_hash,
            task_id=t.id,
            payload=t.payload,
            upstream=None,
            upstream_hash=up[0],
            input_hashes=hashes,
            code=code,
            seed=seed,
        )
        planned.append(PlannedTask(t, _task_key(parts), parts, seed_key(parts, None, upstream_seeds_hash=up[1])))
    return planned
