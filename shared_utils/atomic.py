"""Atomic file writes: a reader never sees a half-written file, and a failed write leaves nothing behind.

Write to a temp file in the destination's folder (``.<final name>.<random>.tmp``), flush it to disk, then
``os.replace`` it onto the final name. The file gets the mode the umask gives, as ``open()`` would.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

__all__ = ["TEMP_SUFFIX", "atomic_path", "file_mode", "write_text_atomic"]

TEMP_SUFFIX = ".tmp"
"""Suffix of the temp files of :func:`atomic_path` (named ``.<final name>.<random>.tmp``)."""


def file_mode() -> int:
    """The mode a new file gets under the current umask (0644 under 022), as ``open()`` would give it."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


@contextlib.contextmanager
def atomic_path(final: Path) -> Iterator[Path]:
    """Yield a temp path in ``final``'s folder; on success move it onto ``final`` with ``os.replace``.

    ``final``'s folder is made if missing. The temp file is removed if the body raises, so a failed write never
    leaves a partial file behind. The file gets the mode the umask gives (``mkstemp`` alone would make it 0600:
    unreadable to colleagues on a shared disk).
    """
    final.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{final.name}.", suffix=TEMP_SUFFIX, dir=final.parent)
    os.fchmod(fd, file_mode())
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        with open(tmp_path, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp_path, final)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def write_text_atomic(path: Path, text: str) -> None:
    """Write a small text file atomically (:func:`atomic_path`)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
