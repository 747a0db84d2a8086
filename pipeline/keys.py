"""Content keys: what a task's output is a function of, hashed.

A key is ``sha256`` of the canonical JSON of everything that determines a shard's bytes (ARCHITECTURE.md, The
engine): the key scheme version, the stage name and version, the stage's params, the task id and payload, the keys
of the upstream shards it reads, the sha256 of every raw input file, and the code the stage runs with the versions
of the packages it imports (:mod:`pipeline.fingerprint`). Same key -> same bytes; a changed param or source file
changes the key of that stage and of everything downstream, nothing else.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import types
from typing import Any

import numpy as np

from pipeline.config import FLATTEN, to_dict
from shared_utils.digest import sha256_file as sha256_file  # re-exported: one definition, below engine and library
from shared_utils.keys import KEY_NAME, KEY_VALUES
from shared_utils.keys import KEY_OMIT_DEFAULT as KEY_OMIT_DEFAULT  # re-exported: the library's settings set it

KEY_SCHEME = 2
"""Bump when the key recipe itself changes: every output becomes stale. 2: keys cover code and packages."""


def canonical_json(obj: Any) -> str:
    """Compact, sorted-key JSON of ``obj`` (dataclasses and tuples allowed); floats in shortest repr form."""
    return json.dumps(_jsonable(obj), sort_keys=True, separators=(",", ":"), allow_nan=False)


_PLAIN = (str, int, bool, type(None))
"""Values that are their own JSON form (most of a key's parts are strings): returned before the general walk."""


def _jsonable(obj: Any) -> Any:
    if type(obj) in _PLAIN:
        return obj
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        out: dict[str, Any] = {}
        for f in dataclasses.fields(obj):
            if _omitted(obj, f):
                continue
            raw = getattr(obj, f.name)
            if type(raw) is str and KEY_VALUES in f.metadata:  # a renamed value: hashed as it was
                raw = f.metadata[KEY_VALUES].get(raw, raw)
            value = _jsonable(raw)
            if f.metadata.get(FLATTEN):  # its keys at the section's level, as the config file writes them
                out.update(value)
            else:
                out[f.metadata.get(KEY_NAME, f.name)] = value  # a renamed field: hashed under its former name
        return out
    # Containers are walked here, not first converted whole by to_dict: a key's upstream part can hold thousands
    # of keys, and converting it at every level made hashing it quadratic in its depth times its size.
    if isinstance(obj, (dict, types.MappingProxyType)):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    obj = to_dict(obj)
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        raise ValueError(f"cannot hash a non-finite float: {obj}")
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def _omitted(obj: Any, field: dataclasses.Field) -> bool:
    if not field.metadata.get(KEY_OMIT_DEFAULT):
        return False
    if field.default is not dataclasses.MISSING:
        default = field.default
    elif field.default_factory is not dataclasses.MISSING:
        default = field.default_factory()
    else:
        return False
    return getattr(obj, field.name) == default


def sha256_text(text: str) -> str:
    """Hex sha256 of a UTF-8 string."""
    return hashlib.sha256(text.encode()).hexdigest()


def params_digest(params: Any) -> str:
    """The ``params`` part of a key: sha256 of the canonical JSON of a stage's params."""
    return sha256_text(canonical_json(params))


def upstream_digest(upstream: Any) -> str:
    """The ``upstream`` part of a key (and of a seed key): sha256 of the canonical JSON of ``{stage: {task: key}}``."""
    return sha256_text(canonical_json(upstream))


def key_parts(
    *,
    stage: str,
    version: int,
    params: Any,
    task_id: str,
    payload: Any,
    upstream: dict[str, dict[str, str]] | None,
    input_hashes: dict[str, str],
    code: dict[str, str] | None = None,
    seed: int = 0,
    params_hash: str | None = None,
    upstream_hash: str | None = None,
) -> dict[str, str]:
    """The hashed components of a task key, kept apart so ``gen status`` can say which one changed.

    ``code`` is the stage's :func:`pipeline.fingerprint.stage_fingerprint`: one part per source file
    (``code:<path>``) and per package (``package:<name>``), so a change names the file or the package.
    ``seed`` is the run's seed (``run.seed``): a ``seed`` part when not 0, none at 0, so seed 0 gives the keys of
    runs made before the seed existed. It reaches the seed key too (:func:`seed_key` keeps every part but code).
    ``params_hash``, when given, is :func:`params_digest` of ``params`` computed once for all of a stage's tasks;
    ``upstream_hash`` likewise :func:`upstream_digest` of ``upstream`` (then ``upstream`` is not read).
    """
    return {
        "scheme": str(KEY_SCHEME),
        "stage": f"{stage}@{version}",
        "params": params_hash if params_hash is not None else params_digest(params),
        "task": sha256_text(canonical_json({"id": task_id, "payload": payload})),
        "upstream": upstream_hash if upstream_hash is not None else upstream_digest(upstream),
        "inputs": sha256_text(canonical_json(input_hashes)),
        **({"seed": str(int(seed))} if seed else {}),
        **(code or {}),
    }


_PART_REASONS = {
    "scheme": "the key scheme changed",
    "stage": "the stage version changed",
    "params": "its params changed",
    "task": "the task definition changed",
    "upstream": "an upstream shard changed",
    "inputs": "an input file changed",
    "seed": "run.seed changed",
}


def changed_parts(old: dict[str, str], new: dict[str, str]) -> list[str]:
    """Why a key changed, part by part, in words: ``its params changed``, ``code: graspgen/sim/lift.py``,
    ``package: mujoco 3.3.7 -> 4.0.0``, ``code: stages/x.py (new)``."""
    reasons = []
    for name in sorted(set(old) | set(new), key=lambda n: (n.startswith(("code:", "package:")), n)):
        before, after = old.get(name), new.get(name)
        if before == after:
            continue
        kind, _, what = name.partition(":")
        if kind == "code":
            reasons.append(f"code: {what}" + (" (new)" if before is None else " (gone)" if after is None else ""))
        elif kind == "package":
            reasons.append(f"package: {what} {before or 'none'} -> {after or 'none'}")
        else:
            reasons.append(_PART_REASONS.get(name, name))
    return reasons


def task_key(parts: dict[str, str]) -> str:
    """The content key: sha256 of the canonical JSON of :func:`key_parts`."""
    return sha256_text(canonical_json(parts))


SEED_SCHEME = 1
"""Bump to draw every random number anew. The seed key below is the content key of scheme 1 (before keys covered
code): the draws of every task stay what they were then."""


def seed_key(parts: dict[str, str], upstream_seeds: dict[str, dict[str, str]] | None,
             upstream_seeds_hash: str | None = None) -> str:
    """The key a task's random generator is seeded from: its content key without the code and package parts, with
    the upstream shards named by their own seed keys. The run's ``seed`` part (:func:`key_parts`) stays in, so
    another ``run.seed`` gives every task other draws.

    A code change re-runs the stages that import the changed file (their content keys change) but with the same
    random draws, so old and new labels can be compared grasp by grasp (the same perturbations, the same scenes),
    and a refactor that changes no behaviour reproduces every byte.
    """
    data = {k: v for k, v in parts.items() if not k.startswith(("code:", "package:"))}
    digest = upstream_seeds_hash if upstream_seeds_hash is not None else upstream_digest(upstream_seeds)
    data.update(scheme=str(SEED_SCHEME), upstream=digest)
    return task_key(data)


def rng_for_key(key: str) -> np.random.Generator:
    """The task's random generator, seeded from the first 8 bytes of its key (never from time or global state)."""
    return np.random.default_rng(int.from_bytes(bytes.fromhex(key[:16]), "little"))
