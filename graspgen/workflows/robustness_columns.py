"""The one builder of robustness label columns: the robustness stage's table and ``evaluate_grasps``'s robustness
columns both come from :func:`robustness_columns`, so a label has one name, one type and one "not perturbed"
value everywhere.

Canonical labels (:data:`LABEL_FIELDS`, in this order):

==================  ==============  =========================================================================
label               type            value of a grasp that was not perturbed (a ``None`` row)
==================  ==============  =========================================================================
n, successes        int32           0
robustness(_lo/_hi) float64         NaN
grip_robustness     float64         NaN
(_lo/_hi)
pfc                 float64         NaN
copy_outcomes       list<int8>      empty
copy_epsilon        list<float64>   empty
radius_x .. _rz     float64         NaN (:data:`RADIUS_AXES`)
==================  ==============  =========================================================================

A table that names a label otherwise (``evaluate_grasps``: ``robustness_n``) picks the labels it needs, in its
order, and gives them its own field names.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
import pyarrow as pa

from graspgen.errors import SettingsError
from graspgen.io.arrow import variable_list

__all__ = ["LABELS", "LABEL_FIELDS", "RADIUS_AXES", "GraspRobustness", "robustness_columns", "rows_at"]

RADIUS_AXES = ("x", "y", "z", "rx", "ry", "rz")
"""Axes of the robustness radius: translation along the TCP x, y, z axes, then rotation about them."""


@dataclasses.dataclass(frozen=True, eq=False)
class GraspRobustness:
    """The robustness labels of one grasp (:func:`graspgen.workflows.robustness.grasp_robustness`)."""

    n: int
    successes: int
    robustness: float
    """successes / n."""
    interval: tuple[float, float]
    """Wilson score 95% interval."""
    grip_n: int
    """Copies that reached the grip (outcome in :data:`graspgen.workflows.robustness.GRIP_CODES`)."""
    grip_robustness: float
    """successes / grip_n; NaN when grip_n = 0."""
    grip_interval: tuple[float, float]
    """Wilson score 95% interval of grip_robustness."""
    pfc: float
    """Fraction of copies with epsilon > delta."""
    outcomes: np.ndarray
    """(n,) int8 outcome codes of the copies."""
    epsilons: np.ndarray
    """(n,) float64 epsilon of the copies."""
    sources: tuple[str, ...]
    """Where each copy's contacts came from (``rollout``, ``raycast``, ``none``)."""
    radius: np.ndarray
    """(6,) float64 robustness radius along/about the TCP axes (:data:`RADIUS_AXES`); NaN when not computed."""


LABEL_FIELDS = (
    pa.field("n", pa.int32()),
    pa.field("successes", pa.int32()),
    pa.field("robustness", pa.float64()),
    pa.field("robustness_lo", pa.float64()),
    pa.field("robustness_hi", pa.float64()),
    pa.field("grip_robustness", pa.float64()),
    pa.field("grip_robustness_lo", pa.float64()),
    pa.field("grip_robustness_hi", pa.float64()),
    pa.field("pfc", pa.float64()),
    pa.field("copy_outcomes", pa.list_(pa.int8())),
    pa.field("copy_epsilon", pa.list_(pa.float64())),
    *[pa.field(f"radius_{a}", pa.float64()) for a in RADIUS_AXES],
)
"""The robustness labels of a grasp, canonical names and types, in table order (module docstring)."""

LABELS = tuple(f.name for f in LABEL_FIELDS)
"""The names of :data:`LABEL_FIELDS`."""

_COUNTS = {"n": lambda r: r.n, "successes": lambda r: r.successes}
_NUMBERS = {
    "robustness": lambda r: r.robustness,
    "robustness_lo": lambda r: r.interval[0],
    "robustness_hi": lambda r: r.interval[1],
    "grip_robustness": lambda r: r.grip_robustness,
    "grip_robustness_lo": lambda r: r.grip_interval[0],
    "grip_robustness_hi": lambda r: r.grip_interval[1],
    "pfc": lambda r: r.pfc,
    **{f"radius_{axis}": (lambda r, a=a: r.radius[a]) for a, axis in enumerate(RADIUS_AXES)},
}
_LISTS = {"copy_outcomes": (lambda r: r.outcomes, pa.int8()), "copy_epsilon": (lambda r: r.epsilons, pa.float64())}


def rows_at(n: int, index: Sequence[int] | np.ndarray, rows: Sequence[GraspRobustness]) -> list[GraspRobustness | None]:
    """``n`` rows with ``rows[k]`` at position ``index[k]`` and None (not perturbed) elsewhere."""
    out: list[GraspRobustness | None] = [None] * n
    for i, r in zip(index, rows):
        out[int(i)] = r
    return out


def robustness_columns(rows: Sequence[GraspRobustness | None], labels: Sequence[str] = LABELS) -> list[pa.Array]:
    """The label columns of a table of grasps, one per name of ``labels`` (of :data:`LABELS`), in that order.

    Parameters
    ----------
    rows : sequence of GraspRobustness or None
        One per grasp (table row); None for a grasp that was not perturbed (module docstring).
    labels : sequence of str
        Which labels, in which order.

    Returns
    -------
    list of pyarrow.Array
        ``len(labels)`` arrays of ``len(rows)`` values, of the types of :data:`LABEL_FIELDS`.
    """
    out = []
    for label in labels:
        if label in _COUNTS:
            get = _COUNTS[label]
            out.append(pa.array([get(r) if r is not None else 0 for r in rows], pa.int32()))
        elif label in _NUMBERS:
            get = _NUMBERS[label]
            out.append(pa.array([get(r) if r is not None else math.nan for r in rows], pa.float64()))
        elif label in _LISTS:
            get, kind = _LISTS[label]
            out.append(variable_list([get(r) if r is not None else () for r in rows], kind))
        else:
            raise SettingsError(f"labels: unknown {label!r}; choose from: {', '.join(LABELS)}")
    return out
