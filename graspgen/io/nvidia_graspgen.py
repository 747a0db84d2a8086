"""Write and read grasp sets in the dataset layout of NVIDIA's GraspGen (``NVlabs/GraspGen``, Murali et al., 2025).

``<root>/objects/<object>.obj`` (metres), ``<root>/grasp_data/<gripper>/<object>.grasps.json`` with
``map_uuid_to_path.json``, and ``<root>/splits/<gripper>/{train,valid}.txt``, where ``<gripper>`` is GraspGen's name
for the gripper (:data:`GRASPGEN_GRIPPER_NAMES`). Poses are the gripper's hand base in the mesh frame (not shifted
to GraspGen's tool tip); ``object_in_gripper`` is the still-held label, ``firm_hold`` ours; ``contact_locations``
(n, 2, 3) the left and right pad contacts, NaN for a pad without one; splits by a hash of the object name
(:func:`split_of`). The layout, the loader lines it was checked against and the frame argument:
docs/format.md, "NVIDIA GraspGen layout".
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from graspgen.errors import InputError, SettingsError
from graspgen.grippers import load_gripper
from graspgen.io.acronym import hand_base_from_tcp, obj_text, tcp_from_hand_base
from graspgen.io.arrow import column_array
from graspgen.io.atomic import write_text_atomic
from graspgen.io.row_groups import objects_of_table
from graspgen.validation import check_number, check_transforms

__all__ = [
    "GRASPGEN_GRIPPER_NAMES",
    "GRASPGEN_GRIPPER_SIZES",
    "SPLITS",
    "GraspGenObject",
    "GraspGenEntry",
    "graspgen_gripper_name",
    "split_of",
    "write_graspgen",
    "export_graspgen",
    "read_graspgen",
]

SPLITS = ("train", "valid")
"""The split files GraspGen reads (``<root_dir>/{train,valid}.txt``)."""

GRASPGEN_GRIPPER_NAMES = {
    "panda": "franka_panda",
    "robotiq_2f85": "robotiq_2f_85",
    "robotiq_2f85_mesh": "robotiq_2f_85",
}
"""Our registered gripper name -> GraspGen's (the stem of its ``config/grippers/<name>.yaml``, NVlabs/GraspGen
at commit a56d518: ``franka_panda``, ``robotiq_2f_85``, ``robotiq_2f_140``, ``single_suction_cup_30mm``). Both
2F-85 models (boxes and meshes) are the one hand GraspGen calls ``robotiq_2f_85``."""

GRASPGEN_GRIPPER_SIZES = {"franka_panda": (0.10537486, 0.10527314)}
"""GraspGen's ``width`` and ``depth`` (m) of the grippers whose config has them (``config/grippers/franka_panda.yaml``
lines 22-23 at commit a56d518; ``robotiq_2f_85.yaml`` has neither): what GraspGen derives its control points and tool
point from (docs/format.md, "NVIDIA GraspGen layout"). Written as the JSON's ``gripper.width`` / ``gripper.depth``; a
gripper not listed gets our ``max_width`` and ``tcp_offset`` there, the values a GraspGen config for it should have."""

_OUR_NAME = {"franka_panda": "panda", "robotiq_2f_85": "robotiq_2f85"}
"""GraspGen's folder name -> our gripper, for files without ``gripper.source_gripper``."""

_IDENTITY_OFFSET = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
"""GraspGen's ``transform_offset_from_asset_to_graspgen_convention`` (translation, quaternion xyzw) for a gripper whose
base frame already has GraspGen's axes, as ours do."""


@dataclasses.dataclass(frozen=True, eq=False)
class GraspGenObject:
    """One object's grasp set for :func:`write_graspgen`."""

    name: str
    """Object name: the file stem of its mesh and JSON (no ``/``)."""
    vertices: np.ndarray
    """(v, 3) float64 mesh vertices, m, mesh frame."""
    faces: np.ndarray
    """(f, 3) int faces, 0-based."""
    T_tcp: np.ndarray
    """(n, 4, 4) float64 TCP poses in the mesh frame (our convention: z approach, x closing, origin between pads)."""
    success: np.ndarray
    """(n,) bool labels (written as ``object_in_gripper``)."""
    gripper: str
    """Our gripper name or gripper file (:func:`graspgen.grippers.load_gripper`)."""
    grasp_ids: np.ndarray | None = None
    """(n,) int grasp ids (default 0..n-1)."""
    protocol: str = ""
    """The protocol that labelled the grasps (e.g. ``acronym``), recorded in the JSON."""
    firm: np.ndarray | None = None
    """(n,) bool firm-hold labels (written as ``firm_hold``; None: not written)."""
    contacts: np.ndarray | None = None
    """(n, 2, 3) float64 contact pairs in the mesh frame, m: [left pad (-x), right pad (+x)], NaN where a pad had none
    (written as ``contact_locations``; None: not written, and GraspGen takes each grasp's origin instead)."""


@dataclasses.dataclass(frozen=True, eq=False)
class GraspGenEntry:
    """One object's JSON file read back by :func:`read_graspgen`. Arrays are read-only."""

    key: str
    """``object.file``: the mesh path relative to the object dataset root (the split files' entry)."""
    name: str
    """The JSON file's stem before ``.grasps.json``."""
    gripper: str
    """Our gripper name (:func:`graspgen.grippers.load_gripper`): the file's ``gripper.source_gripper``, else
    the folder's GraspGen name mapped back (``franka_panda`` -> ``panda``), else the folder name."""
    split: str | None
    """``train`` or ``valid``: the split file listing ``key`` (None when neither does)."""
    mesh_path: Path
    """``<root>/objects/<key>``."""
    scale: float
    """``object.scale``."""
    transforms: np.ndarray
    """(n, 4, 4) float64 gripper base-link poses in the (scaled) mesh frame, m (GraspGen's ``grasps.transforms``)."""
    success: np.ndarray
    """(n,) bool ``grasps.object_in_gripper``."""
    depth: float | None
    """``gripper.depth`` (m): base link -> GraspGen's tool point along +z (GraspGen's value for its grippers,
    :data:`GRASPGEN_GRIPPER_SIZES`); None when the file has no ``gripper`` block."""
    grasp_ids: np.ndarray | None
    """(n,) int64 ``grasps.grasp_id`` or None."""
    protocol: str
    """``grasps.protocol`` ('' when absent)."""
    path: Path
    """The JSON file."""
    firm: np.ndarray | None = None
    """(n,) bool ``grasps.firm_hold`` (ours: the firm-hold label) or None when absent."""
    folder: str = ""
    """The ``grasp_data/<folder>`` it was found in: GraspGen's gripper name (``franka_panda``) in exports written
    now, our own (``panda``) in older ones."""
    tcp_offset: float | None = None
    """``gripper.tcp_offset`` (m): base link -> our TCP along +z; older exports, which wrote our TCP offset as
    ``gripper.depth``, give that; None when the file has neither."""
    contacts: np.ndarray | None = None
    """(n, 2, 3) float64 ``grasps.contact_locations`` (NaN where a pad had none) or None when absent."""

    def __len__(self) -> int:
        return len(self.transforms)

    def tcp_poses(self, depth: float | None = None) -> np.ndarray:
        """(n, 4, 4) TCP poses in the mesh frame: ``transforms @ Trans(0, 0, depth)`` (default the file's
        ``gripper.tcp_offset``, else our gripper of that name's ``tcp_offset``)."""
        if depth is None:
            depth = self.tcp_offset if self.tcp_offset is not None else load_gripper(self.gripper).tcp_offset
        return tcp_from_hand_base(self.transforms, depth) if len(self) else np.zeros((0, 4, 4))


def graspgen_gripper_name(name: str) -> str:
    """The folder (and ``gripper.name``) GraspGen knows our gripper ``name`` by: :data:`GRASPGEN_GRIPPER_NAMES`,
    else ``name`` itself (a gripper GraspGen has no config for)."""
    return GRASPGEN_GRIPPER_NAMES.get(name, name)


def split_of(name: str, valid_fraction: float) -> str:
    """``valid`` or ``train`` for an object name, by a hash.

    Parameters
    ----------
    name : str
        Object name.
    valid_fraction : float
        In [0, 1]: the long-run share of ``valid`` objects (0: all train, 1: all valid).

    Returns
    -------
    str
    """
    fraction = check_number("valid_fraction", valid_fraction, low=0.0, high=1.0)
    u = int.from_bytes(hashlib.sha256(str(name).encode("utf-8")).digest()[:8], "big") / 2.0**64
    return "valid" if u < fraction else "train"


def _check_name(name: Any, where: str) -> str:
    if not isinstance(name, str) or not name or "/" in name or "\\" in name or name in (".", ".."):
        raise InputError(f"{where}: object name must be a non-empty file name (no '/'), got {name!r}")
    return name


def _grasp_json(obj: GraspGenObject, key: str) -> tuple[str, str]:
    """(JSON text, GraspGen's gripper name) of one object."""
    spec = load_gripper(obj.gripper)
    T_tcp = np.zeros((0, 4, 4)) if len(np.asarray(obj.T_tcp)) == 0 else check_transforms("T_tcp", obj.T_tcp)
    n = len(T_tcp)
    success = np.asarray(obj.success).reshape(-1)
    if len(success) != n:
        raise SettingsError(f"{obj.name}: success: expected {n} labels (one per pose), got {len(success)}")
    ids = np.arange(n) if obj.grasp_ids is None else np.asarray(obj.grasp_ids).reshape(-1)
    if len(ids) != n:
        raise SettingsError(f"{obj.name}: grasp_ids: expected {n} ids (one per pose), got {len(ids)}")
    firm = None if obj.firm is None else np.asarray(obj.firm).reshape(-1)
    if firm is not None and len(firm) != n:
        raise SettingsError(f"{obj.name}: firm: expected {n} labels (one per pose), got {len(firm)}")
    contacts = None if obj.contacts is None else np.asarray(obj.contacts, dtype=np.float64).reshape(-1, 2, 3)
    if contacts is not None and len(contacts) != n:
        raise SettingsError(f"{obj.name}: contacts: expected {n} (2, 3) pairs (one per pose), got {len(contacts)}")
    T_base = hand_base_from_tcp(T_tcp, spec.tcp_offset) if n else T_tcp
    name = graspgen_gripper_name(spec.name)
    width, depth = GRASPGEN_GRIPPER_SIZES.get(name, (float(spec.max_width), float(spec.tcp_offset)))
    data = {
        "object": {"file": key, "scale": 1.0},
        "gripper": {"name": name, "width": width, "depth": depth,
                    "transform_offset_from_asset_to_graspgen_convention": _IDENTITY_OFFSET,
                    "tcp_offset": float(spec.tcp_offset), "source_gripper": spec.name},
        "grasps": {"transforms": T_base.tolist(), "object_in_gripper": [bool(s) for s in success],
                   "grasp_id": [int(i) for i in ids], "protocol": str(obj.protocol)},
    }
    if contacts is not None:
        data["grasps"]["contact_locations"] = contacts.tolist()  # NaN written as the token NaN (GraspGen's isnan)
    if firm is not None:
        data["grasps"]["firm_hold"] = [bool(f) for f in firm]
    return json.dumps(data, separators=(",", ":")) + "\n", name


def write_graspgen(
    root: str | Path,
    objects: Iterable[GraspGenObject],
    *,
    valid_fraction: float = 0.2,
    splits: Mapping[str, str] | None = None,
) -> list[str]:
    """Write grasp sets in GraspGen's dataset layout under ``root`` (docs/format.md).

    Parameters
    ----------
    root : str or Path
        Output folder (made when missing; files in it are overwritten, others left alone).
    objects : iterable of GraspGenObject
        One entry per (object, gripper), consumed one at a time (each one's files are written before the next);
        an object with grasps of several grippers has one entry per gripper (its mesh is written once; the entries
        must share it).
    valid_fraction : float
        Share of objects for ``valid`` (:func:`split_of`), in [0, 1].
    splits : mapping, optional
        ``{name: "train" | "valid"}`` overriding the hash for the names it lists.

    Returns
    -------
    list of str
        The written files relative to ``root``, sorted.

    Raises
    ------
    graspgen.errors.InputError
        A bad object name, or two entries of one object and gripper (by GraspGen's name: ``robotiq_2f85`` and
        ``robotiq_2f85_mesh`` are both ``robotiq_2f_85``).
    graspgen.errors.SettingsError
        Poses, labels or ids of the wrong shape; a split other than train / valid (also a ``ValueError``).
    graspgen.errors.SettingsError
        An unknown gripper.
    """
    root = Path(root)
    check_number("valid_fraction", valid_fraction, low=0.0, high=1.0)
    chosen = dict(splits or {})
    for name, split in chosen.items():
        if split not in SPLITS:
            raise SettingsError(f"splits[{name!r}]: must be one of {', '.join(SPLITS)}, got {split!r}")
    written: set[str] = set()
    mesh_digests: dict[str, str] = {}
    listed: dict[str, dict[str, list[str]]] = {}

    def write(rel: str, text: str) -> None:
        write_text_atomic(root / rel, text)
        written.add(rel)

    # Each object's files are written as it comes, so an iterable of objects is never held whole.
    for obj in objects:
        name = _check_name(obj.name, "objects")
        key = f"{name}.obj"
        mesh = obj_text(obj.vertices, obj.faces)
        digest = hashlib.sha256(mesh.encode()).hexdigest()
        if mesh_digests.setdefault(key, digest) != digest:
            raise InputError(f"objects: {name!r} is given twice with different meshes")
        text, gripper = _grasp_json(obj, key)
        rel = f"grasp_data/{gripper}/{name}.grasps.json"
        if rel in written:
            raise InputError(f"objects: {name!r} is given twice for gripper {gripper!r} (GraspGen's name; this entry's "
                             f"gripper: {str(obj.gripper)!r})")
        if f"objects/{key}" not in written:
            write(f"objects/{key}", mesh)
        write(rel, text)
        split = chosen.get(name) or split_of(name, valid_fraction)
        listed.setdefault(gripper, {s: [] for s in SPLITS})[split].append(key)
    for gripper, by_split in listed.items():
        keys = sorted(k for keys in by_split.values() for k in keys)
        mapping = {k: f"{k[: -len('.obj')]}.grasps.json" for k in keys}
        write(f"grasp_data/{gripper}/map_uuid_to_path.json", json.dumps(mapping, indent=2, sort_keys=True) + "\n")
        for split, keys in by_split.items():
            write(f"splits/{gripper}/{split}.txt", "".join(f"{k}\n" for k in sorted(keys)))
    return sorted(written)


def export_graspgen(root: Path, *, valid_fraction: float = 0.2) -> list[str]:
    """The object grasp sets of a published dataset folder in GraspGen's layout, under ``root/graspgen/``.

    Reads ``root/object_grasps.parquet`` (columns ``object_name``, ``grasp_id``, ``gripper``, ``protocol``,
    ``pose_object`` (TCP, object mesh frame), ``success`` (written as ``object_in_gripper``), ``firm`` when present
    (written as ``firm_hold``), ``contact_points`` and ``contact_fingers`` when present (written as
    ``contact_locations``: per grasp the mean of each pad's contact points, left then right, NaN for a pad without
    one); rows by object, then ``grasp_id``) and each object's mesh
    from ``root/objects/<object>.h5`` (``mesh/vertices``, ``mesh/faces``: the frame of ``pose_object``), and calls
    :func:`write_graspgen` with one entry per (object, gripper), grasps in table order.

    Parameters
    ----------
    root : Path
        The dataset folder.
    valid_fraction : float
        See :func:`split_of`.

    Returns
    -------
    list of str
        The written files, relative to ``root`` (``graspgen/...``), sorted.

    Raises
    ------
    graspgen.errors.InputError
        The table or an object record is missing, or lacks a column / entry; an object's rows of one gripper
        name several protocols. The message names the file.
    """
    path = root / "object_grasps.parquet"
    if not path.is_file():
        raise InputError(f"{path}: object grasp table not found")
    wanted = ["object_name", "grasp_id", "gripper", "protocol", "pose_object", "success"]
    missing = [c for c in wanted if c not in pq.read_schema(path).names]
    if missing:
        raise InputError(f"{path}: not an object grasp table: no column(s) {', '.join(missing)}")
    names = pq.read_schema(path).names
    has_firm = "firm" in names
    has_contacts = "contact_points" in names and "contact_fingers" in names
    columns = wanted + (["firm"] if has_firm else []) + (["contact_points", "contact_fingers"] if has_contacts else [])
    objects = _objects_of(root, path, columns, has_firm)
    return [f"graspgen/{rel}" for rel in write_graspgen(root / "graspgen", objects, valid_fraction=valid_fraction)]


def _objects_of(root: Path, path: Path, columns: list[str], has_firm: bool) -> Iterator[GraspGenObject]:
    """One :class:`GraspGenObject` per (object, gripper) of the table, in that order, read one object at a time."""

    def contact_pairs(part: pa.Table) -> np.ndarray | None:
        """(n, 2, 3): per grasp the mean of the left (finger 0) and right (finger 1) pad's contacts, NaN if none."""
        if "contact_points" not in part.column_names:
            return None
        out = np.full((part.num_rows, 2, 3), np.nan)
        for i, (pts, fingers) in enumerate(zip(part.column("contact_points").to_pylist(),
                                               part.column("contact_fingers").to_pylist(), strict=True)):
            points = np.asarray(pts or [], dtype=np.float64).reshape(-1, 3)
            which = np.asarray(fingers or [], dtype=np.int64)
            for finger in (0, 1):
                mine = points[which == finger] if len(which) == len(points) else points[:0]
                if len(mine):
                    out[i, finger] = mine.mean(axis=0)
        return out

    for name, rows in objects_of_table(path, columns):
        _check_name(name, str(path))
        grippers = np.asarray(rows.column("gripper").to_pylist(), dtype=object)
        vertices, faces = _read_mesh(root / "objects" / f"{name}.h5", name)
        for gripper in sorted({str(g) for g in grippers}):
            part = rows.take(pa.array(np.flatnonzero(grippers == gripper)))
            protocols = sorted(set(part.column("protocol").to_pylist()))
            if len(protocols) != 1:
                raise InputError(f"{path}: object {name!r} ({gripper}) has grasps labelled by several protocols: "
                                 f"{protocols}")
            yield GraspGenObject(
                name=name, vertices=vertices, faces=faces,
                T_tcp=column_array(part, "pose_object", (4, 4)),
                success=part.column("success").to_numpy(zero_copy_only=False).astype(bool),
                gripper=gripper, grasp_ids=part.column("grasp_id").to_numpy(), protocol=str(protocols[0]),
                firm=part.column("firm").fill_null(False).to_numpy(zero_copy_only=False).astype(bool) if has_firm
                else None,
                contacts=contact_pairs(part),
            )


def _read_mesh(path: Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    if not path.is_file():
        raise InputError(f"{path}: object record not found (needed for the mesh of {name!r})")
    try:
        with h5py.File(path, "r") as f:
            return np.asarray(f["mesh/vertices"][()], dtype=np.float64), np.asarray(f["mesh/faces"][()])
    except (OSError, KeyError) as exc:
        raise InputError(f"{path}: not an object record ({exc})") from None


def read_graspgen(root: str | Path) -> list[GraspGenEntry]:
    """Read a GraspGen-layout folder (docs/format.md): every ``grasp_data/<gripper>/*.json`` but
    ``map_uuid_to_path.json``, with its split from ``splits/<gripper>/{train,valid}.txt``. The gripper folders may
    have GraspGen's names (``franka_panda``: exports from now on, and GraspGen's own data) or ours (``panda``: older
    exports); each entry names the folder it came from (``folder``) and our gripper (``gripper``).

    Parameters
    ----------
    root : str or Path
        The folder holding ``grasp_data/``, ``splits/`` and ``objects/``.

    Returns
    -------
    list of GraspGenEntry
        Sorted by folder, then file name.

    Raises
    ------
    graspgen.errors.InputError
        No ``grasp_data`` folder; a JSON file that is not valid JSON or lacks ``object.file`` /
        ``grasps.transforms`` / ``grasps.object_in_gripper``, or has poses that are not (n, 4, 4) rigid transforms or
        labels that are not one boolean per pose. The message names the file.
    """
    root = Path(root)
    data_dir = root / "grasp_data"
    if not data_dir.is_dir():
        raise InputError(f"{data_dir}: no grasp_data folder, so not a GraspGen dataset")
    entries = []
    for folder in sorted(p for p in data_dir.iterdir() if p.is_dir()):
        split_of_key: dict[str, str] = {}
        for split in SPLITS:
            split_file = root / "splits" / folder.name / f"{split}.txt"
            if split_file.is_file():
                for line in split_file.read_text(encoding="utf-8").splitlines():
                    if line.strip():
                        split_of_key.setdefault(line.strip(), split)
        for path in sorted(folder.glob("*.json")):
            if path.name == "map_uuid_to_path.json":
                continue
            entries.append(_read_entry(path, root, folder.name, split_of_key))
    return entries


def _read_entry(path: Path, root: Path, gripper: str, split_of_key: Mapping[str, str]) -> GraspGenEntry:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        key, scale = str(data["object"]["file"]), float(data["object"].get("scale", 1.0))
        grasps = data["grasps"]
        T = np.asarray(grasps["transforms"], dtype=np.float64)
        success = np.asarray(grasps["object_in_gripper"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{path}: not a GraspGen grasp file ({type(exc).__name__}: {exc})") from None
    if len(T) == 0:
        T = np.zeros((0, 4, 4))
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise InputError(f"{path}: grasps.transforms must be (n, 4, 4) transforms, got shape {T.shape}")
    if len(T):
        try:
            check_transforms("grasps.transforms", T)
        except SettingsError as exc:
            raise InputError(f"{path}: {exc}") from None
    if success.shape != (len(T),) or (len(T) and success.dtype != np.bool_):
        raise InputError(f"{path}: grasps.object_in_gripper must be {len(T)} booleans (one per transform), got "
                         f"shape {success.shape} of {success.dtype}")
    ids = np.asarray(grasps["grasp_id"], dtype=np.int64) if "grasp_id" in grasps else None
    if ids is not None and ids.shape != (len(T),):
        raise InputError(f"{path}: grasps.grasp_id must be {len(T)} ids, got shape {ids.shape}")
    firm = np.asarray(grasps["firm_hold"]) if "firm_hold" in grasps else None
    if firm is not None and (firm.shape != (len(T),) or (len(T) and firm.dtype != np.bool_)):
        raise InputError(f"{path}: grasps.firm_hold must be {len(T)} booleans (one per transform), got shape "
                         f"{firm.shape} of {firm.dtype}")
    contacts = None
    if "contact_locations" in grasps:
        try:
            contacts = np.asarray(grasps["contact_locations"], dtype=np.float64)
        except (ValueError, TypeError):
            contacts = np.zeros((1, 0))  # ragged or not numbers: reported as a shape error below
        if contacts.size == 0 and len(T) == 0:
            contacts = np.zeros((0, 2, 3))
        if contacts.shape != (len(T), 2, 3):
            raise InputError(f"{path}: grasps.contact_locations must be {len(T)} (2, 3) contact pairs, got shape "
                             f"{contacts.shape}")
    grip = data.get("gripper") or {}
    ours = str(grip.get("source_gripper") or _OUR_NAME.get(gripper, gripper))
    # Exports before gripper.tcp_offset wrote our TCP offset as gripper.depth.
    tcp_offset = grip.get("tcp_offset", grip.get("depth") if "source_gripper" in grip else None)
    success = success.astype(bool)
    firm = None if firm is None else firm.astype(bool)
    for a in (T, success, ids, firm, contacts):
        if a is not None:
            a.setflags(write=False)
    name = path.name[: -len(".grasps.json")] if path.name.endswith(".grasps.json") else path.stem
    return GraspGenEntry(
        key=key, name=name, gripper=ours, split=split_of_key.get(key), mesh_path=root / "objects" / key,
        scale=scale, transforms=T, success=success, depth=float(grip["depth"]) if "depth" in grip else None,
        grasp_ids=ids, protocol=str(grasps.get("protocol", "")), path=path, firm=firm, folder=gripper,
        tcp_offset=None if tcp_offset is None else float(tcp_offset), contacts=contacts,
    )
