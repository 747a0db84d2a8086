"""The rollout columns: how one grasp-and-lift result (:class:`graspgen.sim.protocols.RolloutResult`) becomes Arrow
columns, defined once for the three tables that hold rollouts.

* the rollouts stage's per-scene table (:data:`graspgen.workflows.rollouts.SCHEMA`): contacts in the world frame,
  rows the pre-filter decided without a rollout (``None`` results, :data:`NOT_SIMULATED`);
* ``gen evaluate``'s table (:data:`graspgen.workflows.evaluate_columns.SCHEMA`): contacts in the object frame;
* the object-centric sets (:data:`graspgen.workflows.object_grasps.SCHEMA`): contacts in the object frame.

Each table's schema names the rollout columns it has (:func:`rollout_fields`) between its own, in its own order;
:func:`rollout_table` builds every rollout column the schema names from the results and takes the others from the
caller. Name, type and meaning of a rollout column are those of :data:`ROLLOUT_TYPES` in every table.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pyarrow as pa

from graspgen.errors import SettingsError
from graspgen.io.arrow import fixed_list, variable_list
from graspgen.sim.protocols import OUTCOME_NAMES, Outcome, RolloutResult

__all__ = ["NOT_SIMULATED", "ROLLOUT_TYPES", "object_frame_contacts", "rollout_fields", "rollout_table"]

ROLLOUT_TYPES: dict[str, pa.DataType] = {
    "outcome": pa.int8(),
    "outcome_name": pa.string(),
    "simulated": pa.bool_(),
    "decided_in": pa.string(),
    "success": pa.bool_(),
    "steps": pa.int32(),
    "sim_time": pa.float64(),
    "closed_width": pa.float64(),
    "lift_gain": pa.float64(),
    "rel_translation": pa.float64(),
    "rel_rotation": pa.float64(),
    "firm": pa.bool_(),
    "max_rel_translation": pa.float64(),
    "max_rel_rotation": pa.float64(),
    "motion_closing_linear": pa.float64(),
    "motion_closing_angular": pa.float64(),
    "motion_shaking_linear": pa.float64(),
    "motion_shaking_angular": pa.float64(),
    "contact_points": pa.list_(pa.float64()),
    "contact_normals": pa.list_(pa.float64()),
    "contact_forces": pa.list_(pa.float64()),
    "contact_fingers": pa.list_(pa.int8()),
    "target_pose_closed": pa.list_(pa.float64(), 16),
}
"""Every rollout column and its Arrow type. ``outcome`` 0-5 (:class:`graspgen.sim.protocols.Outcome`), ``outcome_name``
its name, ``simulated`` false where the pre-filter decided, ``decided_in`` the protocol phase that decided it,
``success`` ``outcome == 5``, ``steps`` simulated steps, ``sim_time`` s; ``closed_width``, ``lift_gain``,
``rel_translation``, ``max_rel_translation``, ``motion_*_linear`` m; ``rel_rotation``, ``max_rel_rotation``,
``motion_*_angular`` rad; ``firm`` the firm hold; ``contact_points`` / ``contact_normals`` k*3 values (world or object
frame, per table), ``contact_forces`` N, k values, ``contact_fingers`` 0 left, 1 right, k values;
``target_pose_closed`` the target's pose when closing ended, 4x4 row-major (meanings:
:class:`graspgen.sim.protocols.RolloutResult`)."""

NOT_SIMULATED: dict[str, Any] = {"decided_in": "prefilter", "steps": 0, "sim_time": 0.0, "firm": False}
"""Values of a row without a rollout (its result ``None``: the pre-filter's label stands): these, NaN for the other
numbers and the pose, no contacts, ``simulated`` false, and the outcome code the caller gives."""

_FLOATS = ("sim_time", "closed_width", "lift_gain", "rel_translation", "rel_rotation", "max_rel_translation",
           "max_rel_rotation", "motion_closing_linear", "motion_closing_angular", "motion_shaking_linear",
           "motion_shaking_angular")
_LISTS = {"contact_forces": pa.float64(), "contact_fingers": pa.int8()}


def rollout_fields(*names: str) -> list[pa.Field]:
    """The Arrow fields of the rollout columns ``names``, in that order (:data:`ROLLOUT_TYPES`)."""
    return [pa.field(name, ROLLOUT_TYPES[name]) for name in names]


def object_frame_contacts(result: RolloutResult, fallback: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The finger contacts of ``result`` in the object frame: ``(points (k, 3) m, normals (k, 3))``.

    They were recorded in the world at the end of closing; the object's pose then (``target_pose_closed``) maps them
    back exactly, also where the fingers pushed the object. ``fallback`` ``(4, 4)`` is the world-to-object transform
    used when closing was not reached (the inverse of the object's initial pose; there are no contacts then)."""
    pose = result.target_pose_closed
    F = np.linalg.inv(pose) if np.isfinite(pose).all() else fallback
    return result.contact_points @ F[:3, :3].T + F[:3, 3], result.contact_normals @ F[:3, :3].T


def _codes(results: Sequence[RolloutResult | None], codes: Any) -> np.ndarray:
    """Outcome per row: the result's, else ``codes[i]`` (the pre-filter's)."""
    if codes is None and any(r is None for r in results):
        raise SettingsError("codes: rows without a rollout (None results) need the pre-filter's outcome codes")
    return np.array([r.code if r is not None else codes[i] for i, r in enumerate(results)], dtype=np.int8)


def _column(name: str, results: Sequence[RolloutResult | None], outcome: np.ndarray,
            contacts: tuple[list, list] | None) -> pa.Array:
    """One rollout column of ``results`` (``None``: not simulated)."""
    if name == "outcome":
        return pa.array(outcome, pa.int8())
    if name == "outcome_name":
        return pa.array([r.name if r is not None else OUTCOME_NAMES[int(c)] for r, c in zip(results, outcome)],
                        pa.string())
    if name == "simulated":
        return pa.array([r is not None for r in results], pa.bool_())
    if name == "success":
        return pa.array(outcome == Outcome.SUCCESS, pa.bool_())
    if name in ("decided_in", "firm", "steps"):
        missing = NOT_SIMULATED[name]
        values = [getattr(r, name) if r is not None else missing for r in results]
        if name == "steps":
            return pa.array(np.array(values, dtype=np.int32), pa.int32())
        return pa.array(values, ROLLOUT_TYPES[name])
    if name in _FLOATS:
        missing = NOT_SIMULATED.get(name, float("nan"))
        return pa.array(np.array([getattr(r, name) if r is not None else missing for r in results],
                                 dtype=np.float64), pa.float64())
    if name in ("contact_points", "contact_normals"):
        if contacts is not None:
            return variable_list(contacts[name == "contact_normals"], pa.float64())
        return variable_list([getattr(r, name) if r is not None else () for r in results], pa.float64())
    if name in _LISTS:
        return variable_list([getattr(r, name) if r is not None else () for r in results], _LISTS[name])
    if name == "target_pose_closed":
        rows = [np.ravel(r.target_pose_closed) if r is not None else np.full(16, np.nan) for r in results]
        return fixed_list(np.array(rows, dtype=np.float64).reshape(-1, 16), 16)
    raise SettingsError(f"name: not a rollout column: {name!r}; choose one of {', '.join(ROLLOUT_TYPES)}")


def rollout_table(schema: pa.Schema, results: Sequence[RolloutResult | None], others: Mapping[str, Any], *,
                  codes: Any = None, contacts: tuple[list, list] | None = None) -> pa.Table:
    """A table of ``schema``, one row per result: the rollout columns it names built from ``results``, the rest
    from ``others``.

    Parameters
    ----------
    schema : pyarrow.Schema
        The table's columns in order; those named in :data:`ROLLOUT_TYPES` come from the results.
    results : sequence of RolloutResult or None
        One per row; None: no rollout (the pre-filter decided; :data:`NOT_SIMULATED`).
    others : mapping
        The table's other columns (Arrow arrays, or values ``pa.table`` converts to the schema's type).
    codes : (n,) int, optional
        Outcome codes of the rows without a rollout (needed when a result is None).
    contacts : (points, normals), optional
        Per row ``(k, 3)`` arrays that replace the results' world-frame contacts (:func:`object_frame_contacts`).

    Returns
    -------
    pyarrow.Table
    """
    outcome = _codes(results, codes)
    arrays = dict(others)
    for name in schema.names:
        if name not in arrays:
            arrays[name] = _column(name, results, outcome, contacts)
    return pa.table(arrays, schema=schema)
