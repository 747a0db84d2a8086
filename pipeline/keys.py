"""Content keys: what a task's output is a function of, hashed.

A key is ``sha256`` of the canonical JSON of everything that determines a shard's bytes (ARCHITECTURE.md, The engine):
the key scheme version, the stage name and version, the stage's params, the task id and payload, the keys of the
upstream shards it reads, and the sha256 of every raw input file. Same key -> same bytes; a changed param changes the
key of that stage and of everything downstream, nothing else.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.config import to_dict

KEY_SCHEME = 1
"""Bump when the key recipe itself changes: every output becomes stale."""


def canonical_json(obj: Any) -> str:
    """Compact, sorted-key JSON of ``obj`` (dataclasses and tuples allowed); floats in shortest repr form."""
    return json.dumps(_jsonable(obj), sort_keys=True, separators=(",", ":"), allow_nan=False)


def _jsonable(obj: Any) -> Any:
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


def sha256_text(text: str) -> str:
    """Hex sha256 of a UTF-8 string."""
    return hashlib.sha256(text.encode()).hexdigest()


def sha256_file(path: str | Path, chunk: int = 1 << 20) -> str:
    """Hex sha256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def key_parts(
    *,
    stage: str,
    version: int,
    params: Any,
    task_id: str,
    payload: Any,
    upstream: dict[str, dict[str, str]],
    input_hashes: dict[str, str],
) -> dict[str, str]:
    """The hashed components of a task key, kept apart so ``gen status`` can say which one changed."""
    return {
        "scheme": str(KEY_SCHEME),
        "stage": f"{stage}@{version}",
        "params": sha256_text(canonical_json(params)),
        "task": sha256_text(canonical_json({"id": task_id, "payload": payload})),
        "upstream": sha256_text(canonical_json(upstream)),
        "inputs": sha256_text(canonical_json(input_hashes)),
    }


def task_key(parts: dict[str, str]) -> str:
    """The content key: sha256 of the canonical JSON of :func:`key_parts`."""
    return sha256_text(canonical_json(parts))


def rng_for_key(key: str) -> np.random.Generator:
    """The task's random generator, seeded from the first 8 bytes of its key (never from time or global state)."""
    return np.random.default_rng(int.from_bytes(bytes.fromhex(key[:16]), "little"))
