"""Flags that the engine's content keys read from the library's settings classes."""

from __future__ import annotations

__all__ = ["KEY_OMIT_DEFAULT"]

KEY_OMIT_DEFAULT = "key_omit_default"
"""Field metadata flag: a settings field added after datasets were made with its section, left out of the key
while it holds its default (``dataclasses.field(default=None, metadata={KEY_OMIT_DEFAULT: True})``), so adding it
keeps the keys and random draws of every config that does not set it."""
