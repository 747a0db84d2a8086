"""Flags that the engine's content keys (and the library's own seeds) read from the library's settings classes."""

from __future__ import annotations

import dataclasses
from typing import Any

__all__ = ["KEY_NAME", "KEY_OMIT_DEFAULT", "KEY_VALUES", "key_view"]

KEY_OMIT_DEFAULT = "key_omit_default"
"""Field metadata flag: a settings field added after datasets were made with its section, left out of the key
while it holds its default (``dataclasses.field(default=None, metadata={KEY_OMIT_DEFAULT: True})``), so adding it
keeps the keys and random draws of every config that does not set it."""

KEY_NAME = "key_name"
"""Field metadata: the name a renamed settings field is hashed under, its name when datasets were made with it
(``metadata={KEY_NAME: "old_name"}``), so renaming it keeps every content key and random draw."""

KEY_VALUES = "key_values"
"""Field metadata: ``{value: value hashed}`` of a field whose values were renamed; keys and random draws hash the
former value, so renaming it keeps them."""


def key_view(obj: Any) -> Any:
    """A settings dataclass as plain data the way keys see it: each field under its :data:`KEY_NAME` (default its
    name), a string value through its :data:`KEY_VALUES`, nested dataclasses likewise; other values as they are."""
    if not (dataclasses.is_dataclass(obj) and not isinstance(obj, type)):
        return obj
    out = {}
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if isinstance(value, str):
            value = f.metadata.get(KEY_VALUES, {}).get(value, value)
        out[f.metadata.get(KEY_NAME, f.name)] = key_view(value)
    return out
