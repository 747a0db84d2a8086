"""The ACRONYM exports of a published dataset folder: one ACRONYM grasp file per object, ``acronym/<object>.h5``,
with its mesh as ``acronym/meshes/<object>.obj`` (the file layout and frames: :mod:`graspgen.io.acronym`).

* :func:`export_object_acronym`, ACRONYM's own meaning: the object-centric grasp sets of ``object_grasps.parquet``,
  labelled in free space (``flex/object_in_gripper`` the still-held label, the ``flex/object_motion_*`` measures,
  ``graspgen/firm_hold`` the firm-hold label).
* :func:`export_acronym`: the scene-bound grasps of ``grasps.parquet`` (success = the table-top rollout's outcome 5),
  in each object's mesh frame.

Both read their table one object at a time (:func:`graspgen.io.row_groups.objects_of_table`: the sorted object sets
one row group at a time, grasps.parquet, sorted by scene, in passes of a batch of objects each) and write each file
atomically.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from graspgen.errors import InputError
from graspgen.io.acronym import FIRM_COLUMNS, FIRM_KEY, FLEX_MOTION, obj_text, write_acronym
from graspgen.io.arrow import column_array
from graspgen.io.atomic import atomic_path, write_text_atomic
from graspgen.io.dataset_table import float_values
from graspgen.io.row_groups import objects_of_table

__all__ = ["export_acronym", "export_object_acronym"]


def export_acronym(root: Path) -> list[str]:
    """Each object's grasps of ``root/grasps.parquet`` as ``acronym/<object>.h5`` (+ ``acronym/meshes/<object>.obj``).

    Poses are the TCP poses in the object's mesh frame (``pose_object``), written as hand-base poses
    (:func:`write_acronym`); success is outcome 5. Further qualities under ``grasps/qualities/
    graspgen/``: outcome, width, and the labels present (robustness, pfc, epsilon; NaN where missing;
    ``firm_hold``, 1 / 0, and ``max_rel_translation`` / ``max_rel_rotation`` when the table has ``firm``). Rows are in
    grasps.parquet order (by scene, then grasp id); ``graspgen/grasp_id`` and the order give the way back.

    Returns
    -------
    list of str
        The written files, relative to ``root``.
    """
    wanted = ["object_name", "gripper", "pose_object", "outcome", "width", "grasp_id"]
    schema = pq.read_schema(root / "grasps.parquet")
    labels = [c for c in ("robustness", "pfc", "epsilon") if c in schema.names]
    firm = [c for c in FIRM_COLUMNS if c in schema.names] if "firm" in schema.names else []
    written = []  # one object's rows at a time, gathered in passes (the table is sorted by scene)
    for name, part in objects_of_table(root / "grasps.parquet", wanted + labels + firm):
        gripper = _one_gripper(part, name, root / "grasps.parquet")
        mesh_rel, props = _write_object_mesh(root, name)
        qualities = {
            "graspgen/outcome": part.column("outcome").to_numpy().astype(np.int8),
            "graspgen/width": part.column("width").to_numpy(),
            "graspgen/grasp_id": part.column("grasp_id").to_numpy().astype(np.int32),
        }
        for label in labels:
            qualities[f"graspgen/{label}"] = float_values(part.column(label))
        qualities.update(_firm_qualities(part, firm))
        T = np.asarray(part.column("pose_object").combine_chunks().values, dtype=np.float64).reshape(-1, 4, 4)
        rel = f"acronym/{name}.h5"
        with atomic_path(root / rel) as tmp:
            write_acronym(
                tmp,
                T,
                part.column("outcome").to_numpy() == 5,
                object_file=f"meshes/{name}.obj",
                object_scale=1.0,
                gripper=gripper,
                qualities=qualities,
                **props,
            )
        written += [mesh_rel, rel]
    return written


def export_object_acronym(root: Path) -> list[str]:
    """Each object's free-space grasp set of ``root/object_grasps.parquet`` as ``acronym/<object>.h5`` (ACRONYM's
    meaning), with its mesh as ``acronym/meshes/<object>.obj``.

    Parameters
    ----------
    root : Path
        A published dataset folder: ``object_grasps.parquet`` (the table of :mod:`graspgen.workflows.object_grasps`,
        rows sorted by object, then ``grasp_id``) and ``objects/<object>.h5`` (:func:`graspgen.io.objects.read_object`:
        mesh in the same, scaled, mesh frame as ``pose_object``; mass properties).

    Per object, in the table's row order (by ``grasp_id``):

    * ``grasps/transforms``: ``pose_object`` (TCP, object mesh frame) as ACRONYM's hand-base poses,
      ``T_tcp @ Trans(0, 0, -tcp_offset)`` with the row gripper's ``tcp_offset`` (:func:`write_acronym`);
    * ``grasps/qualities/flex/object_in_gripper``: ``success`` of the free-space protocol (1 / 0), the still-held
      label (ACRONYM's meaning);
    * ``grasps/qualities/graspgen/firm_hold``: ``firm`` (1 / 0, int8), the firm-hold label, and
      ``graspgen/max_rel_translation`` / ``max_rel_rotation`` (m, rad), the measures it reads, where the table has
      them;
    * ``grasps/qualities/flex/object_motion_during_{closing,shaking}_{linear,angular}``: the ``motion_*`` columns
      (m, rad; NaN where the phase was not reached), where the table has them (:data:`FLEX_MOTION`);
    * ``grasps/qualities/graspgen/``: ``grasp_id`` (int32), ``outcome`` (int8), ``width`` (contact width, m) and,
      when present, ``open_width``, ``closed_width``, ``epsilon``, ``robustness`` (float64, NaN for nulls);
    * ``object/file`` ``meshes/<object>.obj``, ``object/scale`` 1 (the OBJ is in metres), ``object/mass``,
      ``object/density``, ``object/com``, ``object/inertia`` from the object record; ``gripper/type``; the root
      attribute ``protocol`` (e.g. ``acronym``).

    Returns
    -------
    list of str
        The written files (mesh, then grasp file, per object in name order), relative to ``root``.

    Raises
    ------
    graspgen.errors.InputError
        The table or an object record is missing or lacks a column / entry; an object's rows name several grippers
        or protocols. The message names the file.
    """
    path = root / "object_grasps.parquet"
    if not path.is_file():
        raise InputError(f"{path}: object grasp table not found")
    names = set(pq.read_schema(path).names)
    required = ["object_name", "grasp_id", "gripper", "protocol", "pose_object", "success", "outcome", "width"]
    missing = [c for c in required if c not in names]
    if missing:
        raise InputError(f"{path}: not an object grasp table: no column(s) {', '.join(missing)}")
    motions = [c for c in FLEX_MOTION if c in names]
    extras = [c for c in ("open_width", "closed_width", "epsilon", "robustness") if c in names]
    firm = [c for c in FIRM_COLUMNS if c in names] if "firm" in names else []
    written = []
    for name, part in objects_of_table(path, required + motions + extras + firm):
        gripper = _one_gripper(part, name, path)
        protocols = sorted(set(part.column("protocol").to_pylist()))
        if len(protocols) != 1:
            raise InputError(f"{path}: object {name!r} has grasps labelled by several protocols: {protocols}")
        mesh_rel, props = _write_object_mesh(root, name)
        qualities: dict[str, np.ndarray] = {FLEX_MOTION[c]: float_values(part.column(c)) for c in motions}
        qualities["graspgen/grasp_id"] = part.column("grasp_id").to_numpy().astype(np.int32)
        qualities["graspgen/outcome"] = part.column("outcome").to_numpy().astype(np.int8)
        for column in ("width", *extras):
            qualities[f"graspgen/{column}"] = float_values(part.column(column))
        qualities.update(_firm_qualities(part, firm))
        rel = f"acronym/{name}.h5"
        with atomic_path(root / rel) as tmp:
            write_acronym(
                tmp,
                column_array(part, "pose_object", (4, 4)),
                part.column("success").to_numpy(zero_copy_only=False).astype(bool),
                object_file=f"meshes/{name}.obj",
                object_scale=1.0,
                gripper=gripper,
                qualities=qualities,
                attrs={"protocol": str(protocols[0])},
                **props,
            )
        written += [mesh_rel, rel]
    return written


def _firm_qualities(part: pa.Table, columns: list[str]) -> dict[str, np.ndarray]:
    """The firm-hold qualities of one object's rows: ``graspgen/firm_hold`` (int8 1 / 0, null as 0) and the
    measures it reads (float64, NaN for nulls), for the :data:`FIRM_COLUMNS` present in ``columns``."""
    out: dict[str, np.ndarray] = {}
    for column in columns:
        if column == "firm":
            values = part.column("firm").fill_null(False).to_numpy(zero_copy_only=False)
            out[FIRM_KEY] = values.astype(np.int8)
        else:
            out[f"graspgen/{column}"] = float_values(part.column(column))
    return out



def _one_gripper(part: pa.Table, name: str, path: Path) -> str:
    grippers = sorted(set(part.column("gripper").to_pylist()))
    if len(grippers) != 1:
        raise InputError(f"{path}: object {name!r} has grasps of several grippers: {grippers}")
    return str(grippers[0])


def _write_object_mesh(root: Path, name: str) -> tuple[str, dict[str, Any]]:
    """Write ``acronym/meshes/<name>.obj`` from ``root/objects/<name>.h5``; return its path (relative to ``root``)
    and the object's properties as :func:`write_acronym` keywords."""
    obj = root / "objects" / f"{name}.h5"
    if not obj.is_file():
        raise InputError(f"{obj}: object record not found (needed for the mesh of {name!r})")
    try:
        with h5py.File(obj, "r") as f:
            vertices, faces = f["mesh/vertices"][()], f["mesh/faces"][()]
            props = {"object_com": f["mass/center_of_mass"][()], "object_inertia": f["mass/inertia"][()],
                     "object_mass": float(f.attrs["mass"]), "object_density": float(f.attrs["density"])}
    except (OSError, KeyError) as exc:
        raise InputError(f"{obj}: not an object record ({exc})") from None
    mesh_rel = f"acronym/meshes/{name}.obj"
    write_text_atomic(root / mesh_rel, obj_text(vertices, faces))
    return mesh_rel, props
