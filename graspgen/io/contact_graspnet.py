"""The scenes as Contact-GraspNet's training data (``NVlabs/contact_graspnet``, Sundermeyer et al., ICRA 2021).

:func:`export_contact_graspnet` writes ``<root>/contact_graspnet/``: ``scene_contacts/{0_train,1_test}_<scene>.npz``
(one per scene with a positive), ``meshes/<object>.obj`` and ``splits/{scenes,objects}.json``. Each ``.npz`` holds
the keys Contact-GraspNet reads (``grasp_transforms`` (n, 4, 4) in its Panda hand-base frame,
``scene_contact_points`` (n, 2, 3) from its closing rays, ``obj_paths``, ``obj_scales``, ``obj_transforms``), every
pose shifted up by :data:`CGN_TABLE_TOP` onto its renderer's table, plus our ids, labels and the other rows. Files
are written atomically with fixed zip timestamps, so the same dataset gives the same bytes. Every key, the frames and
the split rule: docs/format.md, "Contact-GraspNet files".
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Iterator, Mapping
from pathlib import Path

import h5py
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import trimesh
from trimesh.ray.ray_triangle import RayMeshIntersector

from graspgen.errors import InputError
from graspgen.io.acronym import obj_text
from graspgen.io.arrow import column_array
from graspgen.io.atomic import atomic_path, write_text_atomic
from graspgen.io.dataset_table import float_values
from graspgen.io.nvidia_graspgen import split_of
from graspgen.validation import check_transforms

__all__ = [
    "CGN_DEPTH",
    "CGN_FINGER_X",
    "CGN_RAY_REACH",
    "CGN_TABLE_TOP",
    "FOLDER",
    "SCENE_CONTACTS",
    "cgn_contacts",
    "cgn_grasp_from_tcp",
    "export_contact_graspnet",
    "scene_file",
    "tcp_from_cgn_grasp",
    "write_npz",
]

FOLDER = "contact_graspnet"
"""The export's folder in the dataset: Contact-GraspNet's ``dataset_folder``."""
SCENE_CONTACTS = "scene_contacts"
"""Its scene folder: Contact-GraspNet's ``scene_contacts_path`` (``DATA.scene_contacts_path`` of its config)."""
CGN_DEPTH = 0.1034
"""m: grasp frame (Panda hand base) to the finger-centre plane along +z (``build_6d_grasp(gripper_depth=0.1034)``,
``panda_gripper_coords.yml`` ``gripper_left_center_flat: [0.0399, 0, 0.1034]``)."""
CGN_FINGER_X = 0.0399
"""m: x of the Panda's pad centres in the grasp frame, where its contact rays start (``gripper_*_center_flat``)."""
CGN_RAY_REACH = 0.08
"""m: longest contact ray (``grasp_contact_location``: ``<= 2.0 * gripper.q``, q = 0.04 the open finger)."""
CGN_TABLE_TOP = 0.3
"""m: the top of Contact-GraspNet's table (``SceneRenderer._table_dims = [1.0, 1.2, 0.6]``, centred on the origin)."""
TEST_FRACTION = 0.2
"""Share of scenes (and objects) held out, by hash: the GraspGen export's ``valid_fraction``."""

PLACED_LABELS = ("object_outcome", "scene_code")
SCENE_LABELS = ("outcome", "firm", "robustness", "pfc", "epsilon")
_STAMP = (1980, 1, 1, 0, 0, 0)


def _shift(z: float) -> np.ndarray:
    T = np.eye(4)
    T[2, 3] = z
    return T


def cgn_grasp_from_tcp(T_world_tcp: np.ndarray, table_top: float = CGN_TABLE_TOP) -> np.ndarray:
    """Contact-GraspNet grasp poses of our TCP poses: ``Trans(0, 0, table_top) @ T @ Trans(0, 0, -CGN_DEPTH)``.

    Parameters
    ----------
    T_world_tcp : (n, 4, 4) or (4, 4) float
        TCP poses (z approach, x closing, origin midway between the pads) in our world frame, m.
    table_top : float
        m added to z: where Contact-GraspNet's table top is (our support's top is z = 0).

    Returns
    -------
    (n, 4, 4) float64

    Raises
    ------
    graspgen.errors.SettingsError
        Not rigid transforms.
    """
    return _shift(table_top) @ check_transforms("T_world_tcp", T_world_tcp, allow_single=True) @ _shift(-CGN_DEPTH)


def tcp_from_cgn_grasp(T_cgn: np.ndarray, table_top: float = CGN_TABLE_TOP) -> np.ndarray:
    """Our world TCP poses of Contact-GraspNet grasp poses (the inverse of :func:`cgn_grasp_from_tcp`), (n, 4, 4)."""
    return _shift(-table_top) @ check_transforms("T_cgn", T_cgn, allow_single=True) @ _shift(CGN_DEPTH)


def cgn_contacts(mesh: trimesh.Trimesh, T_base: np.ndarray) -> np.ndarray:
    """Contact-GraspNet's two contacts of each grasp on ``mesh`` (``mesh_utils.grasp_contact_location``).

    Per grasp, a ray from each Panda pad centre, ``T_base @ (+-CGN_FINGER_X, 0, CGN_DEPTH)``, along the grasp's
    ``-+x`` (towards the other finger); its first hit on the mesh (front or back face, as Contact-GraspNet's) is the
    contact when it lies within :data:`CGN_RAY_REACH` of the origin. Exact float64 ray casting (trimesh's
    ``ray_triangle``), so the result does not depend on Embree being installed.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The object, m, in the frame of ``T_base``.
    T_base : (n, 4, 4) float
        Grasp poses in Contact-GraspNet's convention (:func:`cgn_grasp_from_tcp`) in the mesh's frame.

    Returns
    -------
    (n, 2, 3) float64
        Contact 0 from the +x finger, contact 1 from the -x finger; NaN where that ray found nothing in reach.
    """
    T = np.asarray(T_base, dtype=np.float64).reshape(-1, 4, 4)
    out = np.full((len(T), 2, 3), np.nan)
    if not len(T):
        return out
    local = np.array([[CGN_FINGER_X, 0.0, CGN_DEPTH], [-CGN_FINGER_X, 0.0, CGN_DEPTH]])
    origins = (np.einsum("nij,kj->nki", T[:, :3, :3], local) + T[:, None, :3, 3]).reshape(-1, 3)
    x = T[:, :3, 0]
    dirs = np.stack([-x, x], axis=1).reshape(-1, 3)
    hits, ray, _ = RayMeshIntersector(mesh).intersects_location(origins, dirs, multiple_hits=False)
    ok = np.linalg.norm(hits - origins[ray], axis=1) <= CGN_RAY_REACH
    flat = out.reshape(-1, 3)
    flat[ray[ok]] = hits[ok]
    return flat.reshape(-1, 2, 3)


def write_npz(path: Path, arrays: Mapping[str, np.ndarray]) -> None:
    """Write ``arrays`` as an ``.npz`` that ``numpy.load(allow_pickle=False)`` reads, atomically, the same bytes for
    the same arrays (fixed zip timestamps, stored, in the mapping's order).

    Raises
    ------
    ValueError
        An array of Python objects (it would need pickling).
    """
    with atomic_path(Path(path)) as tmp, zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED) as zf:
        for key, value in arrays.items():
            info = zipfile.ZipInfo(f"{key}.npy", date_time=_STAMP)
            info.external_attr = 0o644 << 16
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.asanyarray(value), allow_pickle=False)


def export_contact_graspnet(root: Path, *, test_fraction: float = TEST_FRACTION,
                            table_top: float = CGN_TABLE_TOP) -> list[str]:
    """A published dataset's scenes as Contact-GraspNet's training data under ``root/contact_graspnet/`` (the
    layout, keys and frames in docs/format.md).

    Parameters
    ----------
    root : Path
        The dataset folder: ``scenes/<scene_id>.h5`` (object names and settled mesh-to-world poses),
        ``objects/<object>.h5`` (meshes in the frame of ``pose_object``) and ``placed_grasps.parquet`` (used when
        present) or ``grasps.parquet`` (rows sorted by ``scene_id``).
    test_fraction : float
        Long-run share of held-out scenes and objects (:func:`graspgen.io.nvidia_graspgen.split_of`).
    table_top : float
        m added to every z (:data:`CGN_TABLE_TOP`).

    Returns
    -------
    list of str
        The written files relative to ``root``: meshes and scene files (in scene order), then the two split files.

    Raises
    ------
    graspgen.errors.InputError
        No grasp table, or one without a needed column or not sorted by scene; a scene or object record missing
        or unreadable; a row whose ``object_index`` is not an object of its scene. The message names the file.
    """
    root = Path(root)
    source, path, labels = _source(root)
    scene_files = sorted((root / "scenes").glob("*.h5"))
    scene_ids = [p.stem for p in scene_files]
    split = {sid: "test" if split_of(sid, test_fraction) == "valid" else "train" for sid in scene_ids}
    meshes: dict[str, tuple[trimesh.Trimesh, np.ndarray]] = {}
    written: list[str] = []
    kept: dict[str, str] = {}
    left_out: dict[str, str] = {}
    rows_of = _rows_by_scene(path, _columns(source, labels))
    pending = next(rows_of, None)
    for sid in scene_ids:
        rows = None
        if pending is not None and pending[0] == sid:
            rows, pending = pending[1], next(rows_of, None)
        names, poses = _read_scene(root / "scenes" / f"{sid}.h5")
        for name in names:
            if name not in meshes:
                meshes[name] = _mesh(root, name)
                written.append(f"{FOLDER}/meshes/{name}.obj")
        arrays = scene_arrays(sid, names, poses, rows, {n: meshes[n] for n in names}, source, labels, table_top)
        if not len(arrays["grasp_transforms"]):  # Contact-GraspNet needs a positive per scene (docs/format.md)
            left_out[sid] = "no positive grasp with two contacts"
            continue
        kept[sid] = scene_file(sid, split[sid])
        write_npz(root / FOLDER / SCENE_CONTACTS / kept[sid], arrays)
        written.append(f"{FOLDER}/{SCENE_CONTACTS}/{kept[sid]}")
    if pending is not None:
        raise InputError(f"{path}: rows of scene {pending[0]!r}, which has no scenes/{pending[0]}.h5 (or the table is "
                         "not sorted by scene_id)")
    tests = [s for s in kept if split[s] == "test"]
    scenes_split = {"train": [s for s in kept if split[s] == "train"], "test": tests, "num_test_scenes": len(tests),
                    "files": sorted(kept.values()), "left_out": left_out}
    objects_split = {k: sorted(n for n in meshes if (split_of(n, test_fraction) == "valid") == (k == "test"))
                     for k in ("train", "test")}
    for name, data in (("scenes", scenes_split), ("objects", objects_split)):
        rel = f"{FOLDER}/splits/{name}.json"
        write_text_atomic(root / rel, json.dumps(data, indent=1) + "\n")
        written.append(rel)
    return written


def scene_file(scene_id: str, split: str) -> str:
    """The scene's file name: ``0_train_<scene_id>.npz`` or ``1_test_<scene_id>.npz``, so that in name order (the
    order Contact-GraspNet reads and splits them) every held-out scene comes after every training scene."""
    return f"{0 if split == 'train' else 1}_{split}_{scene_id}.npz"


def scene_arrays(scene_id: str, names: list[str], poses: np.ndarray, rows: pa.Table | None,
                 meshes: Mapping[str, tuple[trimesh.Trimesh, np.ndarray]], source: str, labels: tuple[str, ...],
                 table_top: float = CGN_TABLE_TOP) -> dict[str, np.ndarray]:
    """One scene's file (the keys of docs/format.md) from its objects and its grasp rows.

    Parameters
    ----------
    scene_id : str
    names : list of str
        The scene's objects by index.
    poses : (k, 4, 4) float
        Their settled mesh-to-world poses (support top at z = 0), m.
    rows : pyarrow.Table or None
        The scene's grasp rows: ``grasp_id``, ``object_index``, ``gripper``, ``pose_object``, ``pose_world``,
        ``width``, ``success`` (placed grasps) or ``outcome`` (scene grasps), and ``labels``; None: no grasps.
    meshes : mapping
        Object name -> (mesh in its record's frame, (3,) mean of its vertices), m.
    source : str
        ``placed_grasps`` or ``grasps``.
    labels : tuple of str
        Label columns kept as ``grasp_<label>`` / ``other_<label>``.
    table_top : float
        m, see :func:`cgn_grasp_from_tcp`.

    Returns
    -------
    dict of str to numpy.ndarray
        In the order written.

    Raises
    ------
    graspgen.errors.InputError
        A row's ``object_index`` outside the scene's objects.
    """
    up = _shift(table_top)
    obj_T = np.array([up @ np.asarray(p, dtype=np.float64) for p in poses]).reshape(-1, 4, 4)
    for i, name in enumerate(names):
        obj_T[i, :3, 3] += obj_T[i, :3, :3] @ meshes[name][1]
    n = 0 if rows is None else rows.num_rows
    idx, gid = (np.zeros(0, np.int64),) * 2 if not n else (
        rows.column(c).to_numpy().astype(np.int64) for c in ("object_index", "grasp_id"))
    if n and (idx.min() < 0 or idx.max() >= len(names)):
        raise InputError(f"{source}.parquet: scene {scene_id!r} has a grasp of object index {int(idx.max())}, but "
                         f"the scene has {len(names)} objects")
    order = np.lexsort((gid, idx))
    idx, gid = idx[order], gid[order]
    T_world = column_array(rows, "pose_world", (4, 4))[order] if n else np.zeros((0, 4, 4))
    T_obj = column_array(rows, "pose_object", (4, 4))[order] if n else np.zeros((0, 4, 4))
    contacts = _world_contacts(idx, T_obj, up @ np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4),
                               [meshes[name][0] for name in names])
    success = np.zeros(0, bool) if not n else _success(rows, source)[order]
    positive = success & np.isfinite(contacts).all(axis=(1, 2))
    grasps = cgn_grasp_from_tcp(T_world, table_top) if n else np.zeros((0, 4, 4))
    widths = np.zeros(0) if not n else float_values(rows.column("width"))[order]
    label_values = {lab: _label(rows, lab)[order] for lab in labels} if n else {lab: np.zeros(0) for lab in labels}
    grippers = sorted(set(rows.column("gripper").to_pylist())) if n else []
    arrays: dict[str, np.ndarray] = {
        "scene_contact_points": contacts[positive],
        "grasp_transforms": grasps[positive],
        "obj_paths": np.array([f"meshes/{name}.obj" for name in names], dtype=str),
        "obj_scales": np.ones(len(names)),
        "obj_transforms": obj_T,
        "obj_names": np.array(list(names), dtype=str),
        "obj_grasp_idcs": np.searchsorted(idx[positive], np.arange(len(names)), side="right").astype(np.int64),
        "scene_id": np.array(scene_id),
        "source": np.array(source),
        "gripper": np.array(",".join(str(g) for g in grippers)),
        "table_top": np.array(float(table_top)),
        "grasp_ids": gid[positive],
        "grasp_obj_idcs": idx[positive],
        "grasp_widths": widths[positive],
    }
    arrays.update({f"grasp_{lab}": v[positive] for lab, v in label_values.items()})
    other = ~positive
    arrays.update({"other_grasp_transforms": grasps[other], "other_contact_points": contacts[other],
                   "other_grasp_ids": gid[other], "other_obj_idcs": idx[other], "other_success": success[other],
                   "other_widths": widths[other], **{f"other_{lab}": v[other] for lab, v in label_values.items()}})
    return arrays


def _world_contacts(idx: np.ndarray, T_obj: np.ndarray, to_world: np.ndarray,
                    meshes: list[trimesh.Trimesh]) -> np.ndarray:
    """(n, 2, 3) :func:`cgn_contacts` of TCP poses ``T_obj`` (each in its object's mesh frame, object ``idx``),
    cast on the object's mesh and taken to the world by its ``to_world`` (k, 4, 4)."""
    contacts = np.full((len(idx), 2, 3), np.nan)
    for i in np.unique(idx):
        sel = idx == i
        local = cgn_contacts(meshes[i], T_obj[sel] @ _shift(-CGN_DEPTH))
        contacts[sel] = local @ to_world[i, :3, :3].T + to_world[i, :3, 3]
    return contacts


def _success(rows: pa.Table, source: str) -> np.ndarray:
    if source == "placed_grasps":
        return rows.column("success").fill_null(False).to_numpy(zero_copy_only=False).astype(bool)
    return rows.column("outcome").to_numpy().astype(np.int64) == 5


def _label(rows: pa.Table, name: str) -> np.ndarray:
    column = rows.column(name)
    if pa.types.is_floating(column.type):
        return float_values(column)
    if pa.types.is_boolean(column.type):
        return column.fill_null(False).to_numpy(zero_copy_only=False).astype(bool)
    return column.fill_null(-1).to_numpy().astype(np.int64)


def _source(root: Path) -> tuple[str, Path, tuple[str, ...]]:
    """(source name, table path, label columns): the placed grasps when published, else the scene grasps."""
    placed = root / "placed_grasps.parquet"
    if placed.is_file():
        return "placed_grasps", placed, PLACED_LABELS
    path = root / "grasps.parquet"
    if not path.is_file():
        raise InputError(f"{path}: no grasp table (nor placed_grasps.parquet) to export for Contact-GraspNet")
    names = set(pq.read_schema(path).names)
    return "grasps", path, tuple(c for c in SCENE_LABELS if c in names)


def _columns(source: str, labels: tuple[str, ...]) -> list[str]:
    base = ["scene_id", "grasp_id", "object_index", "gripper", "pose_object", "pose_world", "width"]
    return base + ["success" if source == "placed_grasps" else "outcome"] + [c for c in labels if c != "outcome"]


def _rows_by_scene(path: Path, columns: list[str]) -> Iterator[tuple[str, pa.Table]]:
    """The table's rows per ``scene_id`` in table order, one row group in memory at a time.

    Raises
    ------
    graspgen.errors.InputError
        A missing column; a scene whose rows are not contiguous or scenes out of order.
    """
    pf = pq.ParquetFile(path)
    missing = [c for c in columns if c not in pf.schema_arrow.names]
    if missing:
        raise InputError(f"{path}: no column(s) {', '.join(missing)} (needed for the Contact-GraspNet export)")
    sid: str | None = None
    parts: list[pa.Table] = []
    for g in range(pf.metadata.num_row_groups):
        group = pf.read_row_group(g, columns=columns)
        ids = np.asarray(group.column("scene_id").to_pylist(), dtype=object)
        starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]]) if len(ids) else np.zeros(0, int)
        for j, start in enumerate(starts):
            stop = starts[j + 1] if j + 1 < len(starts) else len(ids)
            if ids[start] != sid:
                if sid is not None:
                    if str(ids[start]) <= sid:
                        raise InputError(f"{path}: not sorted by scene_id ({ids[start]!r} after {sid!r})")
                    yield sid, pa.concat_tables(parts)
                sid, parts = str(ids[start]), []
            parts.append(group.slice(start, stop - start))
    if sid is not None:
        yield sid, pa.concat_tables(parts)


def _read_scene(path: Path) -> tuple[list[str], np.ndarray]:
    """(object names, (k, 4, 4) settled mesh-to-world poses) of a scene record."""
    if not path.is_file():
        raise InputError(f"{path}: scene record not found")
    try:
        with h5py.File(path, "r") as f:
            names = f.attrs["object_names"]
            poses = np.asarray(f["objects/poses"][()], dtype=np.float64)
    except (OSError, KeyError) as exc:
        raise InputError(f"{path}: not a scene record ({exc})") from None
    names = json.loads(names) if isinstance(names, str) else [str(n) for n in names]
    if len(names) != len(poses):
        raise InputError(f"{path}: {len(names)} object names but {len(poses)} poses")
    return [str(n) for n in names], poses


def _mesh(root: Path, name: str) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Write ``contact_graspnet/meshes/<name>.obj`` from ``objects/<name>.h5``; return the mesh (record frame) and
    the mean of its vertices."""
    path = root / "objects" / f"{name}.h5"
    if not path.is_file():
        raise InputError(f"{path}: object record not found (needed for the mesh of {name!r})")
    try:
        with h5py.File(path, "r") as f:
            vertices = np.asarray(f["mesh/vertices"][()], dtype=np.float64)
            faces = np.asarray(f["mesh/faces"][()], dtype=np.int64)
    except (OSError, KeyError) as exc:
        raise InputError(f"{path}: not an object record ({exc})") from None
    write_text_atomic(root / FOLDER / "meshes" / f"{name}.obj", obj_text(vertices, faces))
    return trimesh.Trimesh(vertices, faces, process=False), vertices.mean(axis=0)
