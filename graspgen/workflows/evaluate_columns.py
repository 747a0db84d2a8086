"""The table :func:`graspgen.workflows.evaluate.evaluate_grasps` returns: one row per input grasp, in input order.

Columns (:data:`SCHEMA`; the rollout columns are those of :mod:`graspgen.workflows.rollout_columns`):

===================  ==============  =====================================================================
column               type            meaning
===================  ==============  =====================================================================
index                int32           row of the input (0..n-1)
outcome              int8            0-5 (:class:`graspgen.sim.protocols.Outcome`)
outcome_name         string          its name
decided_in           string          protocol phase that decided it
steps                int32           simulated steps
sim_time             float64         simulated seconds
width                float64         pad separation the jaws opened for (before the margin), m
width_source         string          ``input``, ``raycast``, ``open`` (ray casts found no contact on a pad) or
                                     ``protocol`` (``acronym``: the jaws open fully; ``width`` is that opening)
closed_width         float64         pad separation when closing ended, m (NaN if not reached)
lift_gain            float64         how far the object rose, m (NaN if not reached)
rel_translation      float64         object displacement relative to the TCP after closing, m
rel_rotation         float64         object rotation relative to the TCP after closing, rad
firm                 bool            firm hold: outcome 5 (still in the hand) and the object's motion in the
                                     hand within ``lift.firm_translation`` / ``firm_rotation``
max_rel_translation  float64         largest displacement of the object in the TCP frame from the end of
                                     closing over the disturbance (``acronym``: shake and settle; ``table``:
                                     lift, hold, shake; ``graspdatagen``: tugs), m (NaN if not reached)
max_rel_rotation     float64         largest rotation relative to the TCP over the same span, rad
pose                 float64[16]     the TCP pose evaluated, object frame, 4x4 row-major
contact_points       list<float64>   finger-object contacts at the end of closing, object frame, k*3 values
contact_normals      list<float64>   their normals, into the object, object frame, k*3 values
contact_forces       list<float64>   their normal forces, N, k values
contact_fingers      list<int8>      0 left pad/finger, 1 right, k values
motion_closing_linear  float64       object displacement while the fingers closed, m (NaN if not reached)
motion_closing_angular float64       object rotation while the fingers closed, rad
motion_shaking_linear  float64       object displacement during the shake, m (NaN if no shake ran)
motion_shaking_angular float64       object rotation during the shake, rad
===================  ==============  =====================================================================

Object frame: the scaled mesh frame of the input file. Contacts are mapped back from the world with the object's
pose at the end of closing (when they were recorded), so they are exact even where the fingers pushed the object.

With robustness, :data:`ROBUSTNESS_FIELDS` follow (grasps that did not succeed get ``robustness_n = 0``, NaN labels
and no copies; built by :func:`graspgen.workflows.robustness_columns.robustness_columns`):

===================  ==============  =====================================================================
robustness_n         int32           perturbed copies rolled out (0 unless the nominal outcome is 5)
robustness_successes int32           copies with outcome 5
robustness           float64         robustness_successes / robustness_n; NaN when robustness_n = 0
robustness_lo/_hi    float64         its Wilson score 95% interval
grip_robustness      float64         successes / copies that reached the grip (outcome 3-5: collisions at
                                     placement or during the approach left out); NaN when none did
grip_robustness_lo   float64         its Wilson score 95% interval (``_lo``, ``_hi``)
/_hi
copy_outcomes        list<int8>      outcome code of every copy, robustness_n values
===================  ==============  =====================================================================
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from graspgen.io.arrow import fixed_list
from graspgen.sim.protocols import OUTCOME_NAMES, RolloutResult
from graspgen.workflows.robustness_columns import LABEL_FIELDS, GraspRobustness, robustness_columns, rows_at
from graspgen.workflows.rollout_columns import object_frame_contacts, rollout_fields, rollout_table

__all__ = ["METADATA_KEY", "ROBUSTNESS_FIELDS", "SCHEMA", "evaluation_table", "outcome_counts",
           "with_robustness_columns"]

METADATA_KEY = "evaluate"
"""Key of the output table's schema metadata: JSON with the mesh, scale, gripper, protocol and its settings, mode,
mass, friction, the centre of mass and torque scale (largest vertex distance from it) in the object frame, number of
convex parts, the object's world pose (4x4) and the mesh preparation's warnings (e.g. a guessed unit)."""

SCHEMA = pa.schema(
    [
        ("index", pa.int32()),
        *rollout_fields("outcome", "outcome_name", "decided_in", "steps", "sim_time"),
        ("width", pa.float64()),
        ("width_source", pa.string()),
        *rollout_fields("closed_width", "lift_gain", "rel_translation", "rel_rotation", "firm", "max_rel_translation",
                        "max_rel_rotation"),
        ("pose", pa.list_(pa.float64(), 16)),
        *rollout_fields("contact_points", "contact_normals", "contact_forces", "contact_fingers",
                        "motion_closing_linear", "motion_closing_angular", "motion_shaking_linear",
                        "motion_shaking_angular"),
    ]
)
"""The output table's schema (see the module docstring)."""

_ROBUSTNESS_LABELS = ("n", "successes", "robustness", "robustness_lo", "robustness_hi", "grip_robustness",
                      "grip_robustness_lo", "grip_robustness_hi", "copy_outcomes")
"""The robustness labels (:data:`graspgen.workflows.robustness_columns.LABELS`) that evaluate writes."""

_COLUMN_NAMES = {"n": "robustness_n", "successes": "robustness_successes"}
"""Evaluate's names for the labels whose own name says nothing beside the rollout columns."""

ROBUSTNESS_FIELDS = tuple(pa.field(_COLUMN_NAMES.get(field.name, field.name), field.type)
                          for label in _ROBUSTNESS_LABELS for field in LABEL_FIELDS if field.name == label)
"""The columns appended to :data:`SCHEMA` with ``robustness`` (see the module docstring): the shared label
fields (:data:`graspgen.workflows.robustness_columns.LABEL_FIELDS`), in :data:`_ROBUSTNESS_LABELS` order."""


def evaluation_table(T: np.ndarray, width: np.ndarray, source: list[str], results: list[RolloutResult],
                     T_world_object: np.ndarray) -> pa.Table:
    """The :data:`SCHEMA` table of ``n`` rollouts: TCP poses ``T`` ``(n, 4, 4)`` and ``width`` ``(n,)`` (m) in the
    object frame, the widths' ``source``, the results, and the object's initial world pose ``(4, 4)``."""
    n = len(results)
    fallback = np.linalg.inv(T_world_object)  # closing not reached: the object is still where it started
    contacts = [object_frame_contacts(r, fallback) for r in results]
    others = {
        "index": pa.array(np.arange(n, dtype=np.int32)),
        "width": pa.array(np.asarray(width, dtype=np.float64)),
        "width_source": pa.array(source, pa.string()),
        "pose": fixed_list(T.reshape(n, 16), 16),
    }
    return rollout_table(SCHEMA, results, others, contacts=([c[0] for c in contacts], [c[1] for c in contacts]))


def with_robustness_columns(table: pa.Table, ok: np.ndarray, rows: list[GraspRobustness]) -> pa.Table:
    """``table`` with :data:`ROBUSTNESS_FIELDS` appended; ``rows[k]`` are the labels of row ``ok[k]``, the other rows
    were not perturbed."""
    columns = robustness_columns(rows_at(len(table), ok, rows), _ROBUSTNESS_LABELS)
    for field, column in zip(ROBUSTNESS_FIELDS, columns):
        table = table.append_column(field, column)
    return table


def outcome_counts(table: pa.Table) -> dict[str, int]:
    """``{outcome_name: count}`` over all six outcomes of an evaluation (or rollouts) table."""
    codes = table.column("outcome").to_numpy()
    return {name: int((codes == c).sum()) for c, name in enumerate(OUTCOME_NAMES)}
