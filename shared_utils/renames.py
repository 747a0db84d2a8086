"""Former names of settings and of their values: the field metadata by which the engine's config loader answers an
old name with the new one, and the one message it and the library's own checks give."""

from __future__ import annotations

__all__ = ["RENAMED_FROM", "RENAMED_VALUES", "renamed_message"]

RENAMED_FROM = "renamed_from"
"""Field metadata: the names a settings field had before, a tuple (``dataclasses.field(..., metadata={RENAMED_FROM:
("old",)})``). A config that still writes an old key fails with :func:`renamed_message` instead of "unknown key"."""

RENAMED_VALUES = "renamed_values"
"""Field metadata: ``{former value: current value}`` of a field whose values were renamed. A config that still
writes a former value fails with :func:`renamed_message` (the library's ``__post_init__`` checks say the same)."""


def renamed_message(what: str, old: str, new: str) -> str:
    """``"protocol 'graspgen' was renamed 'graspdatagen'"``: ``what`` names the kind of thing renamed."""
    return f"{what} {old!r} was renamed {new!r}"
