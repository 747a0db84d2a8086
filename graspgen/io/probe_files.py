"""The probe's files: its shard (the trained evaluator and its report in one HDF5) and what a dataset publishes of it.

The ``probe`` stage (:mod:`stages.probe`) trains a small grasp evaluator (:mod:`graspgen.learn`) on the dataset's
object-centric sets and writes one shard with :func:`write_probe_shard`: the model file's bytes (``model``, uint8)
and the report (``report``, canonical JSON: sorted keys, no wall-clock times, non-finite numbers as null). The
``dataset`` stage lays them out as :data:`MODEL` and :data:`REPORT` with :func:`publish_probe`, byte for byte, and the
card renders the report (:mod:`graspgen.io.card_learn`). Nothing here needs torch.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from graspgen.errors import InputError
from graspgen.io.atomic import atomic_path, write_text_atomic
from graspgen.io.files import write_h5

__all__ = ["FOLDER", "MODEL", "REPORT", "TIMING_KEYS", "canonical_torch_zip", "clean_report", "publish_probe",
           "read_probe_shard", "report_text", "write_probe_shard"]

FOLDER = "probe"
"""Subfolder of a published dataset holding the probe's files."""
MODEL = f"{FOLDER}/model.pt"
"""The trained evaluator (:func:`graspgen.learn.load_model` reads it; ``gen probe eval --model``)."""
REPORT = f"{FOLDER}/report.json"
"""Its report: the split, the held-out scores of the network and the baselines (what the card renders)."""

TIMING_KEYS = ("seconds", "cpu_seconds")
"""Keys of the report's ``train`` section that are wall-clock or CPU times: left out of the shard (they differ from
run to run) and kept in the task's manifest meta instead."""


SERIALIZATION_ID = ".data/serialization_id"
"""The record torch.save adds at the end of its archive in some processes and not in others (see
:func:`canonical_torch_zip`)."""

_EOCD, _Z64_EOCD, _Z64_LOCATOR, _CENTRAL = b"PK\x05\x06", b"PK\x06\x06", b"PK\x06\x07", b"PK\x01\x02"


def canonical_torch_zip(data: bytes) -> bytes:
    """The bytes of a ``torch.save`` archive without its ``<archive>/.data/serialization_id`` record.

    torch.save writes that record in one process and not in another: not in a process that loaded ``coacd``
    before torch (its library brings its own C++ runtime), so a pipeline worker that ran an objects task first
    writes other bytes than a fresh process for the same tensors. Every other record, and its central-directory
    entry, is byte-identical and at the same offset, and the id is the last record; so cutting the file at that
    record and writing the central directory again (miniz's layout: entries, zip64 end record, zip64 locator, end
    record) gives the bytes torch writes without it. torch.load reads both (the id is optional). An archive without
    the record comes back unchanged.

    Raises
    ------
    InputError
        Not a zip archive as torch.save writes it (no end record, entries that do not parse).
    """
    end = data.rfind(_EOCD)
    z64 = data.rfind(_Z64_EOCD)
    if end < 0 or z64 < 0 or data.rfind(_Z64_LOCATOR) < 0:
        raise InputError("model bytes: not a torch.save archive (no zip64 end of central directory)")
    made_by, needed = struct.unpack("<HH", data[z64 + 12 : z64 + 16])
    (cd_start,) = struct.unpack("<Q", data[z64 + 48 : z64 + 56])
    entries, pos, cut = [], cd_start, None
    while data[pos : pos + 4] == _CENTRAL:
        name_len, extra_len, comment_len = struct.unpack("<HHH", data[pos + 28 : pos + 34])
        size = 46 + name_len + extra_len + comment_len
        name = data[pos + 46 : pos + 46 + name_len].decode()
        if name.endswith("/" + SERIALIZATION_ID) or name == SERIALIZATION_ID:
            (cut,) = struct.unpack("<I", data[pos + 42 : pos + 46])
        else:
            entries.append(data[pos : pos + size])
        pos += size
    if pos != z64:
        raise InputError("model bytes: the central directory of the archive does not parse")
    if cut is None:
        return bytes(data)
    directory = b"".join(entries)
    n, start = len(entries), cut
    zip64_end = _Z64_EOCD + struct.pack("<QHHIIQQQQ", 44, made_by, needed, 0, 0, n, n, len(directory), start)
    locator = _Z64_LOCATOR + struct.pack("<IQI", 0, start + len(directory), 1)
    end_record = _EOCD + struct.pack("<HHHHIIH", 0, 0, min(n, 0xFFFF), min(n, 0xFFFF),
                                     min(len(directory), 0xFFFFFFFF), min(start, 0xFFFFFFFF), 0)
    return bytes(data[:cut]) + directory + zip64_end + locator + end_record


def _finite(value: Any) -> Any:
    """``value`` with every non-finite float replaced by None and numpy scalars made Python numbers (valid JSON)."""
    if isinstance(value, Mapping):
        return {str(k): _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def clean_report(report: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Split a :func:`graspgen.learn.run_probe` report into what is reproducible and the timings.

    Returns
    -------
    (report, timings)
        The report without :data:`TIMING_KEYS` in its ``train`` section, as plain JSON values (non-finite numbers
        as None); and those timings (``{"seconds": ..., "cpu_seconds": ...}``, those present).
    """
    out = _finite(report)
    train = dict(out.get("train") or {})
    timings = {k: train.pop(k) for k in TIMING_KEYS if k in train}
    if "train" in out:
        out["train"] = train
    return out, timings


def report_text(report: Mapping[str, Any]) -> str:
    """The report as the published ``report.json`` holds it: indented JSON with sorted keys, one final newline."""
    return json.dumps(_finite(report), indent=1, sort_keys=True, allow_nan=False) + "\n"


def write_probe_shard(path: str | Path, model_bytes: bytes, report: Mapping[str, Any]) -> None:
    """Write the probe's shard: ``model`` (the model file's bytes, ``(n,) uint8``) and ``report`` (JSON text).

    The report must already be free of timings (:func:`clean_report`): the same model and report give the same
    bytes.
    """
    write_h5(path, {"model": np.frombuffer(bytes(model_bytes), dtype=np.uint8), "report": report_text(report)})


def read_probe_shard(path: str | Path) -> tuple[bytes, dict[str, Any]]:
    """The model file's bytes and the report of a probe shard.

    Raises
    ------
    InputError
        Not a probe shard (names the file).
    """
    try:
        with h5py.File(path, "r") as f:
            model = f["model"][()].tobytes()
            text = f["report"][()]
    except (OSError, KeyError) as exc:
        raise InputError(f"{path}: not a probe shard ({exc})") from None
    text = text.decode() if isinstance(text, bytes) else str(text)
    return model, json.loads(text)


def publish_probe(shard: str | Path, root: str | Path) -> list[str]:
    """Lay out a probe shard in the dataset folder ``root``: :data:`MODEL` and :data:`REPORT` (atomically).

    Returns
    -------
    list of str
        The paths written, relative to ``root``.
    """
    root = Path(root)
    model, report = read_probe_shard(shard)
    (root / FOLDER).mkdir(parents=True, exist_ok=True)
    with atomic_path(root / MODEL) as tmp:
        tmp.write_bytes(model)
    write_text_atomic(root / REPORT, report_text(report))
    return [MODEL, REPORT]
