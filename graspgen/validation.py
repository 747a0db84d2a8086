"""The one validation helper every settings class of the library uses in ``__post_init__``."""

from __future__ import annotations

from typing import Any

from graspgen.errors import SettingsError


def check(name: str, ok: bool, must: str, value: Any) -> None:
    """Raise :class:`~graspgen.errors.SettingsError` ``"name: must ..., got value"`` unless ``ok``.

    Parameters
    ----------
    name : str
        The setting's name, as the user writes it in a config (a loader prefixes the section path).
    ok : bool
        The condition that must hold.
    must : str
        What the value must be, e.g. ``"be > 0"``.
    value : Any
        The offending value, echoed in the message.
    """
    if not ok:
        raise SettingsError(f"{name}: must {must}, got {value!r}")
