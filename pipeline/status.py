"""Where each stage stands against the current config: what ``gen run`` with the same config would do."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pipeline.fingerprint import module_cache
from pipeline.keys import changed_parts
from pipeline.plan import PlannedTask, Project, check_shards, one_check_per_shard, plan, read_entries, shard_ok
from pipeline.scheduler import WARNING_TASKS_SHOWN
from pipeline.stage import Upstream, topological_order
from pipeline.store import Entry, Manifest, stage_dir


@dataclasses.dataclass
class StageStatus:
    """Where a stage stands against the current config."""

    stage: str
    state: str
    """``done``, ``missing`` (some tasks not committed, or their shards missing or damaged), ``stale`` (committed
    under old keys), ``failed``, ``waiting`` (an input stage has new work first), ``damaged`` (the shards are
    done but output the stage published is missing or damaged: :meth:`Stage.publish_status`)."""
    total: int = 0
    done: int = 0
    failed: int = 0
    missing: int = 0
    reasons: list[str] = dataclasses.field(default_factory=list)


DAMAGED_SHARD = "its shard is missing or damaged"
"""Status reason of a task whose entry is current but whose shard fails the run's check (size and sha256)."""


def status(project: Project, config: Any, targets: Sequence[str] | None = None) -> list[StageStatus]:
    """done / missing / stale / failed / waiting / damaged for each stage, with the reasons: what ``gen run`` with
    the same config would do.

    Shards are checked as the run checks them (size and sha256). A current shard that is missing or damaged is
    remade by the run with the same key, so the stages below it are planned as the run will plan them (not
    ``waiting``). A stage with no new work (and no failed task) is asked what its publish step would repair
    (:meth:`Stage.publish_status`): those lines appear as ``published: ...`` reasons.
    """
    with one_check_per_shard(), module_cache(config.run.cache_dir):
        return _status(project, config, targets)


def _status(project: Project, config: Any, targets: Sequence[str] | None) -> list[StageStatus]:
    out = Path(config.run.out)
    result = []
    not_done: set[str] = set()
    current: dict[str, set[str]] = {}
    intact: dict[str, dict[str, Entry]] = {}
    """Per stage, the current shards that pass the check, by task id: what the run and its publish see."""
    redo: dict[str, dict[str, Entry]] = {}
    """Per stage, the current entries whose shard is missing or damaged: remade by the run with the same key."""
    for stage in topological_order(project.stages, targets):
        waiting = [d for d in stage.inputs if d in not_done]
        if waiting:
            result.append(StageStatus(stage.name, "waiting", reasons=[f"needs {', '.join(waiting)} first"]))
            not_done.add(stage.name)
            continue
        manifest = Manifest(stage_dir(out, stage.name))
        entries = read_entries(manifest)
        by_task: dict[str, Entry] = {}
        for e in entries.values():
            by_task[e.task] = e
        params = stage.params(config)
        after_run = {d: {**intact.get(d, {}), **redo.get(d, {})} for d in stage.inputs}
        planned = plan(stage, params, Upstream(out, after_run), seed=config.run.seed)
        current[stage.name] = {p.key for p in planned}
        check_shards(manifest, [entries[p.key] for p in planned if p.key in entries])
        st = StageStatus(stage.name, "done", total=len(planned))
        reasons: dict[str, list[str]] = {}
        own_intact: dict[str, Entry] = {}
        own_redo: dict[str, Entry] = {}
        new_work = False
        stale: list[tuple[PlannedTask, str]] = []
        for p in planned:
            entry = entries.get(p.key)
            if entry is not None and entry.status == "ok":
                ok = shard_ok(manifest, entry)  # size and sha256, as the run checks
                st.done += ok
                (own_intact if ok else own_redo)[p.task.id] = entry
            elif entry is not None and entry.status == "failed":
                st.failed += 1
            else:
                new_work = True
                old = by_task.get(p.task.id)
                if old is not None:
                    stale.append((p, old.key))
        old_parts = manifest.parts({key for _, key in stale}) if stale else {}
        for p, key in stale:
            for r in changed_parts(old_parts.get(key, {}), p.parts) or ["its key changed"]:
                reasons.setdefault(r, []).append(p.task.id)
        intact[stage.name], redo[stage.name] = own_intact, own_redo
        st.missing = len(planned) - st.done - st.failed
        st.reasons = [f"{len(ids)} task(s): {r}" for r, ids in sorted(reasons.items())]
        if own_redo:
            st.reasons.append(f"{len(own_redo)} task(s): {DAMAGED_SHARD} ({_some(sorted(own_redo))})")
        if new_work:
            st.state = "stale" if reasons else "missing"
            not_done.add(stage.name)
        elif own_redo:
            st.state = "missing"
        elif st.failed:
            st.state = "failed"
        if not new_work and not st.failed:
            view = Upstream(out, {**{d: intact.get(d, {}) for d in stage.inputs}, stage.name: own_intact})
            problems = [f"published: {line}" for line in stage.publish_status(params, view, out)]
            st.reasons += problems
            if problems and st.state == "done":
                st.state = "damaged"
        result.append(st)
    return result


def _some(names: Sequence[str], shown: int = WARNING_TASKS_SHOWN) -> str:
    """``a, b, c`` or ``a, b, c and 4 more``."""
    more = f" and {len(names) - shown} more" if len(names) > shown else ""
    return ", ".join(names[:shown]) + more

