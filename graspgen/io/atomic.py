"""Atomic file writes for the library: :func:`atomic_path`, :func:`write_text_atomic` and :data:`TEMP_SUFFIX`,
defined once in :mod:`shared_utils.atomic` (below the engine and the library, so the library still runs without the
engine) and re-exported here. A reader never sees a half-written file; a failed write leaves nothing behind.
"""

from __future__ import annotations

from shared_utils.atomic import TEMP_SUFFIX, atomic_path, write_text_atomic

__all__ = ["TEMP_SUFFIX", "atomic_path", "write_text_atomic"]
