"""Argument and settings checks shared by the whole grasp library.

Every settings class validates itself in ``__post_init__`` with these helpers, and the library's functions check
their arguments with them, so one kind of mistake gives one kind of message, always starting with the name of the
offending setting or argument (a config loader prefixes the section path)::

    friction: must be in (0, inf), got -1
    shake_cycles: must be an integer in [1, inf), got 0
    rays_per_point: must be a positive integer, got 0
    T_tcp[3]: the rotation block is not a proper rotation (orthonormal to 1e-05, det +1) (1 of 10 transforms)

Every check raises :class:`~graspgen.errors.SettingsError`, which is also a ``ValueError``. Bools are never
numbers here (``True`` is not a count of 1), and NaN or infinite numbers are rejected.
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
"""Largest deviation (per entry) of a rigid transform's rotation block from orthonormality, and of its last row
from ``0 0 0 1``, that the pose checks accept. Poses read back from float32 storage are orthonormal only to
~1e-7 per entry (and products of a few of them to a few times that), so 1e-5 accepts every stored pose while a
scaled, sheared or garbage matrix is still far outside it."""

_EYE3 = np.eye(3)
_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])


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
    """A finite real number within ``[low, high]`` (either end open on request), as a Python float.

    Parameters
    ----------
    name : str
        Named first in the message.
    value : Any
        A Python or numpy real scalar (or a 0-d numeric array); bools are rejected.
    low, high : float or None
        Bounds; None leaves that side unbounded.
    low_open, high_open : bool
        Exclude the bound itself (``low_open=True`` with ``low=0`` means ``> 0``).

    Returns
    -------
    float
        ``float(value)``.

    Raises
    ------
    SettingsError
        ``"name: must be a number, got 'x'"``, ``"name: must be finite, got nan"`` or
        ``"name: must be in (0, inf), got -1"``.
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
    """An integer (Python or numpy, not a bool, not a float such as ``2.0``) within ``[low, high]``.

    Parameters
    ----------
    name : str
        Named first in the message.
    value : Any
        The value to check.
    low, high : int or None
        Inclusive bounds; None leaves that side unbounded.

    Returns
    -------
    int
        ``int(value)``.

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
    """An integer >= 1 (a count of things that cannot be zero), as a Python int.

    Returns
    -------
    int
        ``int(value)``.

    Raises
    ------
    SettingsError
        ``"name: must be a positive integer, got 0"`` (also for bools and floats).
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral) or value < 1:
        raise SettingsError(f"{name}: must be a positive integer, got {value!r}")
    return int(value)


def check_bool(name: str, value: Any) -> bool:
    """A bool (Python or numpy; not 0/1, not a string), as a Python bool.

    Raises
    ------
    SettingsError
        ``"name: must be a bool, got 1"``.
    """
    if not isinstance(value, (bool, np.bool_)):
        raise SettingsError(f"{name}: must be a bool, got {value!r}")
    return bool(value)


def check_rng(name: str, value: Any) -> np.random.Generator:
    """A ``numpy.random.Generator`` (not a seed, not the legacy ``RandomState``), returned as is.

    Raises
    ------
    SettingsError
        ``"rng: must be a numpy.random.Generator, got int"``.
    """
    if not isinstance(value, np.random.Generator):
        raise SettingsError(f"{name}: must be a numpy.random.Generator, got {type(value).__name__}")
    return value


def check_instance(name: str, value: Any, cls: type, *, what: str | None = None) -> Any:
    """An instance of ``cls``, returned as is.

    Parameters
    ----------
    name : str
        Named first in the message.
    value : Any
        The value to check.
    cls : type
        The class ``value`` must be an instance of.
    what : str or None
        How the message names the class (default ``cls.__name__``, e.g. ``"trimesh.Trimesh"`` to be clearer).

    Raises
    ------
    SettingsError
        ``"gripper: must be a GripperSpec, got str"``.
    """
    if not isinstance(value, cls):
        what = what or cls.__name__
        article = "an" if what[:1].lower() in "aeiou" else "a"
        raise SettingsError(f"{name}: must be {article} {what}, got {type(value).__name__}")
    return value


def check_choice(name: str, value: Any, choices: Collection[Any]) -> Any:
    """One of ``choices`` (compared with ``==``), returned as is.

    Raises
    ------
    SettingsError
        ``"approach: must be one of above, hemisphere, any, got 'below'"`` (choices in the order given).
    """
    try:
        ok = value in choices
    except TypeError:  # an unhashable value tested against a set or dict
        ok = False
    if not ok:
        raise SettingsError(f"{name}: must be one of {', '.join(str(c) for c in choices)}, got {value!r}")
    return value


def check_vector(name: str, value: Any, size: int, *, low: float | None = None,
                 low_open: bool = False) -> tuple[float, ...]:
    """``size`` finite numbers (any array-like, flattened), each ``>= low`` (``> low`` with ``low_open``).

    Parameters
    ----------
    name : str
        Named first in the message.
    value : array-like, (size,)
        The numbers (a nested sequence is flattened).
    size : int
        How many numbers.
    low : float or None
        Lower bound of every entry; None: unbounded.
    low_open : bool
        Exclude the bound itself.

    Returns
    -------
    tuple of float, (size,)

    Raises
    ------
    SettingsError
        ``"pad_size: must be 3 finite numbers, got (0.01, 0.02)"`` or
        ``"pad_size: every entry must be in (0, inf), got (0.01, -0.02, 0.03)"``.
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
    """A ``[min, max]`` pair of numbers with ``min <= max``, lying in ``[low, high]``.

    Parameters
    ----------
    name : str
        Named first in the message.
    value : sequence of 2 numbers
        The pair.
    low, high : float or None
        Inclusive bounds of both ends; None leaves that side unbounded.

    Returns
    -------
    (float, float)

    Raises
    ------
    SettingsError
        ``"distance: must be [min, max] with min <= max, got (0.8, 0.5)"`` or
        ``"elevation: must lie in [-1.5708, 1.5708], got (0.2, 2.0)"``.
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
    """One rigid transform: a finite ``(4, 4)`` matrix whose rotation block is a proper rotation (orthonormal to
    :data:`POSE_TOL` per entry, determinant > 0) and whose last row is ``0 0 0 1`` (to :data:`POSE_TOL`).

    Parameters
    ----------
    name : str
        Named first in the message.
    T : array-like, (4, 4)
        The transform.

    Returns
    -------
    (4, 4) float64
        ``numpy.asarray(T, dtype=float64)`` (no copy when it already is one).

    Raises
    ------
    SettingsError
        ``"object_pose: must have shape (4, 4), got shape (3, 3)"``, ``"object_pose: must be finite"``,
        ``"object_pose: the rotation block is not a proper rotation (orthonormal to 1e-05, det +1)"`` or
        ``"object_pose: the last row must be 0 0 0 1"``.
    """
    arr = _as_float_array(name, T)
    if arr.shape != (4, 4):
        raise SettingsError(f"{name}: must have shape (4, 4), got shape {arr.shape}")
    fault = _rigid_faults(arr[None])
    if fault is not None:
        raise SettingsError(f"{name}: {fault[0]}")
    return arr


def check_transforms(name: str, T: Any, *, allow_single: bool = False) -> np.ndarray:
    """A stack of rigid transforms, each as :func:`check_transform` requires.

    Parameters
    ----------
    name : str
        Named first in the message, with the index of the first bad transform (``T_tcp[3]: ...``).
    T : array-like, (n, 4, 4), or (4, 4) with ``allow_single``
        The transforms (``n = 0`` is fine).
    allow_single : bool
        Also accept one ``(4, 4)`` transform, returned as a stack of one.

    Returns
    -------
    (n, 4, 4) float64
        ``numpy.asarray(T, dtype=float64)`` (no copy when it already is one; a single transform gets a new axis).

    Raises
    ------
    SettingsError
        ``"T_tcp: must have shape (n, 4, 4), got shape (3, 3)"``, or for the first bad transform e.g.
        ``"T_tcp[3]: the rotation block is not a proper rotation (orthonormal to 1e-05, det +1) (2 of 10
        transforms)"`` (likewise ``must be finite`` and ``the last row must be 0 0 0 1``).
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
    """Plain (JSON-able) form of a settings dataclass: dataclasses -> dicts, tuples -> lists, any mapping (a
    config loader may hand in read-only ``MappingProxyType``\\s, which :func:`dataclasses.asdict` cannot copy)
    -> dict. What the library stores as provenance in the files it writes."""
    if dataclasses.is_dataclass(settings) and not isinstance(settings, type):
        return {f.name: settings_dict(getattr(settings, f.name)) for f in dataclasses.fields(settings)}
    if isinstance(settings, (tuple, list)):
        return [settings_dict(v) for v in settings]
    if isinstance(settings, Mapping):
        return {str(k): settings_dict(v) for k, v in settings.items()}
    return settings
