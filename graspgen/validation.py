"""Argument and settings checks shared by the whole grasp library.

Settings classes call them in ``__post_init__`` and functions on their arguments, so every mistake gives one kind of
message, ``"<name>: must <what>, got <value>"`` (a config loader prefixes the section path), e.g.
``shake_cycles: must be an integer in [1, inf), got 0``. Every check raises :class:`~graspgen.errors.SettingsError`
(also a ``ValueError``); bools are never numbers, and NaN or infinite numbers are rejected.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Collection, Mapping
from typing import Any

import numpy as np

from graspgen.errors import SettingsError

__all__ = [
    "POSE_TOL",
    "check",
    "check_bool",
    "check_choice",
    "check_instance",
    "check_int",
    "check_number",
    "check_positive_int",
    "check_range",
    "check_rng",
    "check_transform",
    "check_transforms",
    "check_vector",
]

POSE_TOL = 1e-5
"""Largest per-entry deviation of a rotation block from orthonormality, and of the last row from ``0 0 0 1``, that the
pose checks accept: above float32 storage round-off (~1e-7), far below a scaled or sheared matrix."""

_EYE3 = np.eye(3)
_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])


def check(name: str, ok: bool, must: str, value: Any) -> None:
    """Raise :class:`~graspgen.errors.SettingsError` ``"name: must <must>, got <value>"`` unless ``ok``; ``name`` as the
    user writes it in a config."""
    if not ok:
        raise SettingsError(f"{name}: must {must}, got {value!r}")


def _interval(low: float | None, high: float | None, low_open: bool, high_open: bool) -> str:
    """``[0, inf)``-style text of an interval; an absent or infinite bound is always open."""
    no_low = low is None or math.isinf(low)
    no_high = high is None or math.isinf(high)
    left = "(" if low_open or no_low else "["
    right = ")" if high_open or no_high else "]"
    low_text = "-inf" if no_low else f"{low:g}"
    high_text = "inf" if no_high else f"{high:g}"
    return f"{left}{low_text}, {high_text}{right}"


def _outside(x: float, low: float | None, high: float | None, low_open: bool, high_open: bool) -> bool:
    too_low = low is not None and (x <= low if low_open else x < low)
    too_high = high is not None and (x >= high if high_open else x > high)
    return too_low or too_high


def _is_real(value: Any) -> bool:
    if isinstance(value, (bool, np.bool_)):
        return False
    if isinstance(value, np.ndarray):  # a 0-d numeric array (what numpy reductions sometimes hand back)
        return value.ndim == 0 and value.dtype.kind in "iuf"
    return isinstance(value, numbers.Real)


def check_number(
    name: str,
    value: Any,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
) -> float:
    """A finite real number within ``[low, high]`` as a Python float; None bounds are unbounded, ``low_open`` /
    ``high_open`` exclude a bound.

    ``value`` may be a Python or numpy real scalar or a 0-d numeric array; bools are rejected.

    Raises
    ------
    SettingsError
        Not a number, not finite, or outside the interval (``"friction: must be in (0, inf), got -1"``).
    """
    if not _is_real(value):
        raise SettingsError(f"{name}: must be a number, got {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise SettingsError(f"{name}: must be finite, got {value!r}")
    if _outside(x, low, high, low_open, high_open):
        raise SettingsError(f"{name}: must be in {_interval(low, high, low_open, high_open)}, got {value!r}")
    return x


def check_int(name: str, value: Any, *, low: int | None = None, high: int | None = None) -> int:
    """An integer (Python or numpy; not a bool, not ``2.0``) within the inclusive ``[low, high]``, as a Python int.

    Raises
    ------
    SettingsError
        ``"name: must be an integer, got 2.5"`` or ``"name: must be an integer in [1, inf), got 0"``.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise SettingsError(f"{name}: must be an integer, got {value!r}")
    if _outside(value, low, high, False, False):
        raise SettingsError(f"{name}: must be an integer in {_interval(low, high, False, False)}, got {value!r}")
    return int(value)


def check_positive_int(name: str, value: Any) -> int:
    """An integer >= 1 as a Python int; raises :class:`SettingsError` ``"name: must be a positive integer, got 0"``
    (also for bools and floats)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral) or value < 1:
        raise SettingsError(f"{name}: must be a positive integer, got {value!r}")
    return int(value)


def check_bool(name: str, value: Any) -> bool:
    """A bool (Python or numpy; not 0/1, not a string) as a Python bool; else :class:`SettingsError`."""
    if not isinstance(value, (bool, np.bool_)):
        raise SettingsError(f"{name}: must be a bool, got {value!r}")
    return bool(value)


def check_rng(name: str, value: Any) -> np.random.Generator:
    """A ``numpy.random.Generator`` (not a seed, not ``RandomState``), returned as is; else :class:`SettingsError`."""
    if not isinstance(value, np.random.Generator):
        raise SettingsError(f"{name}: must be a numpy.random.Generator, got {type(value).__name__}")
    return value


def check_instance(name: str, value: Any, cls: type, *, what: str | None = None) -> Any:
    """An instance of ``cls``, returned as is; else :class:`SettingsError` ``"gripper: must be a GripperSpec, got str"``
    (``what`` names the class in the message, default ``cls.__name__``)."""
    if not isinstance(value, cls):
        what = what or cls.__name__
        article = "an" if what[:1].lower() in "aeiou" else "a"
        raise SettingsError(f"{name}: must be {article} {what}, got {type(value).__name__}")
    return value


def check_choice(name: str, value: Any, choices: Collection[Any]) -> Any:
    """One of ``choices`` (compared with ``==``), returned as is; else :class:`SettingsError` listing the choices in the
    order given."""
    try:
        ok = value in choices
    except TypeError:  # an unhashable value tested against a set or dict
        ok = False
    if not ok:
        raise SettingsError(f"{name}: must be one of {', '.join(str(c) for c in choices)}, got {value!r}")
    return value


def check_vector(name: str, value: Any, size: int, *, low: float | None = None,
                 low_open: bool = False) -> tuple[float, ...]:
    """``size`` finite numbers (any array-like, flattened), each ``>= low`` (``> low`` with ``low_open``), as a tuple.

    Raises
    ------
    SettingsError
        Wrong count, a non-finite entry, or an entry below ``low`` (``"pad_size: must be 3 finite numbers, ..."``).
    """
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != (size,) or not np.isfinite(arr).all():
        raise SettingsError(f"{name}: must be {size} finite numbers, got {value!r}")
    if low is not None and any(_outside(float(x), low, None, low_open, False) for x in arr):
        raise SettingsError(f"{name}: every entry must be in {_interval(low, None, low_open, False)}, got {value!r}")
    return tuple(float(x) for x in arr)


def check_range(name: str, value: Any, *, low: float | None = None, high: float | None = None) -> tuple[float, float]:
    """A ``[min, max]`` pair of numbers with ``min <= max``, both within the inclusive ``[low, high]``, as floats.

    Raises
    ------
    SettingsError
        ``"distance: must be [min, max] with min <= max, got (0.8, 0.5)"`` or ``"elevation: must lie in [...]"``.
    """
    try:
        pair = tuple(value)
        ok = len(pair) == 2 and all(_is_real(v) for v in pair) and pair[0] <= pair[1]
    except TypeError:
        ok = False
    if not ok:
        raise SettingsError(f"{name}: must be [min, max] with min <= max, got {value!r}")
    lo, hi = float(pair[0]), float(pair[1])
    if _outside(lo, low, high, False, False) or _outside(hi, low, high, False, False):
        raise SettingsError(f"{name}: must lie in {_interval(low, high, False, False)}, got {value!r}")
    return lo, hi


def _as_float_array(name: str, T: Any) -> np.ndarray:
    try:
        return np.asarray(T, dtype=np.float64)
    except (TypeError, ValueError):
        raise SettingsError(f"{name}: must be an array of 4x4 rigid transforms, got {T!r}") from None


def _rigid_faults(T: np.ndarray) -> tuple[str, np.ndarray] | None:
    """The first kind of fault of a ``(n, 4, 4)`` stack (``(what, bad (n,) bool)``), or None when all are rigid."""
    finite = np.isfinite(T).reshape(len(T), 16).all(axis=1)
    if not finite.all():
        return "must be finite", ~finite
    R = T[:, :3, :3]
    ortho = np.abs(np.matmul(R, np.swapaxes(R, 1, 2)) - _EYE3).max(axis=(1, 2), initial=0.0)
    rotation = (ortho <= POSE_TOL) & (np.linalg.det(R) > 0)
    if not rotation.all():
        return f"the rotation block is not a proper rotation (orthonormal to {POSE_TOL:g}, det +1)", ~rotation
    last = np.abs(T[:, 3, :] - _LAST_ROW).max(axis=1, initial=0.0) <= POSE_TOL
    if not last.all():
        return "the last row must be 0 0 0 1", ~last
    return None


def check_transform(name: str, T: Any) -> np.ndarray:
    """One rigid transform as a (4, 4) float64 array (no copy when it is one): finite, rotation block orthonormal to
    :data:`POSE_TOL` with determinant > 0, last row ``0 0 0 1``.

    Raises
    ------
    SettingsError
        Wrong shape, not finite, not a proper rotation, or a bad last row.
    """
    arr = _as_float_array(name, T)
    if arr.shape != (4, 4):
        raise SettingsError(f"{name}: must have shape (4, 4), got shape {arr.shape}")
    fault = _rigid_faults(arr[None])
    if fault is not None:
        raise SettingsError(f"{name}: {fault[0]}")
    return arr


def check_transforms(name: str, T: Any, *, allow_single: bool = False) -> np.ndarray:
    """A stack of rigid transforms as (n, 4, 4) float64 (``n = 0`` is fine), each as :func:`check_transform` requires;
    ``allow_single`` also takes one (4, 4) transform and returns a stack of one.

    Raises
    ------
    SettingsError
        Wrong shape, or for the first bad transform e.g. ``"T_tcp[3]: the rotation block is not a proper rotation
        (orthonormal to 1e-05, det +1) (2 of 10 transforms)"``.
    """
    arr = _as_float_array(name, T)
    if allow_single and arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[1:] != (4, 4):
        shapes = "(4, 4) or (n, 4, 4)" if allow_single else "(n, 4, 4)"
        raise SettingsError(f"{name}: must have shape {shapes}, got shape {np.shape(T)}")
    fault = _rigid_faults(arr)
    if fault is not None:
        what, bad = fault
        raise SettingsError(f"{name}[{int(np.flatnonzero(bad)[0])}]: {what} ({int(bad.sum())} of {len(arr)} "
                            "transforms)")
    return arr


def settings_dict(settings: Any) -> Any:
    """Plain (JSON-able) form of a settings dataclass (dataclasses and mappings -> dicts, tuples -> lists): the
    provenance the library stores in the files it writes."""
    if dataclasses.is_dataclass(settings) and not isinstance(settings, type):
        return {f.name: settings_dict(getattr(settings, f.name)) for f in dataclasses.fields(settings)}
    if isinstance(settings, (tuple, list)):
        return [settings_dict(v) for v in settings]
    if isinstance(settings, Mapping):
        return {str(k): settings_dict(v) for k, v in settings.items()}
    return settings
