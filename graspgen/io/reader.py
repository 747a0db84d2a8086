"""Reading a published dataset (``OUT/dataset``, :mod:`graspgen.io.dataset_table`): :func:`open_dataset`.

Lazy: opening reads the Parquet footer and ``card.json`` only; grasps are read with the filter pushed into the
Parquet reader (row groups hold whole scenes or objects), a scene view from its HDF5 file alone. Needs numpy,
pyarrow and h5py only (torch when :class:`TorchDataset` is first used). Example: README.md, "Reading a dataset".

Conventions (as in the shards): metres, radians; poses map a frame to the world (``pose_world``: TCP to world);
cameras OpenCV with ``T_world_camera`` camera-to-world; segmentation and point ids are the object's index in the
scene, -1 nothing, -2 support, -3 ground (ground points are not in the clouds).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from graspgen.errors import GraspGenError, NotFoundError, SettingsError
from graspgen.io.dataset_table import dataset_dir

__all__ = ["GraspDataset", "Grasp", "Scene", "View", "Sample", "open_dataset"]  # + TorchDataset, made when used

SEG_GROUND = -3
_POSES = ("pose_world", "pose_object")
_POINT_LISTS = ("contact_points", "contact_normals")


def open_dataset(path: str | Path) -> GraspDataset:
    """Open a published dataset: ``path`` is its folder (with grasps.parquet) or the run folder holding ``dataset/``.

    Raises
    ------
    graspgen.errors.InputError
        Neither holds a grasps.parquet.
    """
    return GraspDataset(dataset_dir(path))


def _to_numpy(value: Any, name: str) -> Any:
    """A row value as the reader hands it out: fixed-size and numeric lists as arrays, poses (4, 4)."""
    if isinstance(value, list):
        arr = np.asarray([np.nan if v is None else v for v in value], dtype=np.float64)
        if name in _POSES:
            return arr.reshape(4, 4)
        if name in _POINT_LISTS:
            return arr.reshape(-1, 3)
        if name in ("contact_fingers", "copy_outcomes"):
            return arr.astype(np.int8)
        return arr
    return value


class Grasp(Mapping):
    """One row of grasps.parquet: a read-only mapping ``column -> value`` that also reads as attributes.

    ``pose_world`` / ``pose_object`` are (4, 4) arrays, ``contact_points`` / ``contact_normals`` (k, 3), other list
    columns 1-D arrays; nulls are None (NaN inside arrays).
    """

    def __init__(self, row: Mapping[str, Any]):
        self._row = {k: _to_numpy(v, k) for k, v in row.items()}

    def __getitem__(self, key: str) -> Any:
        return self._row[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._row)

    def __len__(self) -> int:
        return len(self._row)

    def __getattr__(self, key: str) -> Any:
        try:
            return self.__dict__["_row"][key]
        except KeyError:
            raise AttributeError(f"Grasp has no column {key!r}") from None

    def __repr__(self) -> str:
        keys = ("scene_id", "grasp_id", "object_name", "outcome_name")
        return "Grasp(" + ", ".join(f"{k}={self._row[k]!r}" for k in keys if k in self._row) + ")"


@dataclasses.dataclass(frozen=True, eq=False)
class View:
    """One camera view of a scene: calibration, images and its point cloud (world frame)."""

    scene_id: str
    index: int
    K: np.ndarray
    """(3, 3) intrinsics, pixels."""
    T_world_camera: np.ndarray
    """(4, 4) camera-to-world (OpenCV camera frame)."""
    width: int
    height: int
    rgb: np.ndarray | None
    """(H, W, 3) uint8, or None when the scene was made without images."""
    depth: np.ndarray | None
    """(H, W) float32 m along the optical axis, 0 = no return."""
    segmentation: np.ndarray | None
    """(H, W) int16 object index, -1 nothing, -2 support, -3 ground."""
    points: np.ndarray
    """(N, 3) float32 world-frame points of the objects and the support seen in this view, m."""
    point_ids: np.ndarray
    """(N,) int16 segmentation id of each point."""

    def cloud(self, frame: str = "world") -> tuple[np.ndarray, np.ndarray]:
        """``(points (N, 3) float32, ids (N,) int16)`` in the ``world`` or ``camera`` frame."""
        if frame == "world":
            return self.points, self.point_ids
        if frame == "camera":
            T = np.linalg.inv(self.T_world_camera)
            pts = self.points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
            return pts.astype(np.float32), self.point_ids
        raise SettingsError(f"frame: must be 'world' or 'camera', got {frame!r}")

    def to_camera(self, T_world: np.ndarray) -> np.ndarray:
        """Poses (..., 4, 4) given in the world frame, expressed in this camera's frame."""
        return np.linalg.inv(self.T_world_camera) @ np.asarray(T_world, dtype=np.float64)


class Scene:
    """A scene file, read on demand: objects and poses at once, views one at a time (:meth:`view`)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        with h5py.File(self.path, "r") as f:
            self.scene_id: str = _attr(f.attrs["scene_id"])
            self.object_names: list[str] = list(json.loads(_attr(f.attrs["object_names"])))
            """Object names by scene index (the grasps' ``object_index``, the segmentation id)."""
            self.poses: np.ndarray = f["objects/poses"][()]
            """(n, 4, 4) settled mesh-to-world poses by scene index."""
            self.num_views: int = int(f["cameras/K"].shape[0])

    def view(self, index: int = 0) -> View:
        """Camera view ``index``: its images and its cloud (stored, else back-projected from depth)."""
        if not 0 <= index < self.num_views:
            raise SettingsError(f"view: must be in [0, {self.num_views}) for {self.scene_id}, got {index}")
        with h5py.File(self.path, "r") as f:
            cams = f["cameras"]
            K, T = cams["K"][index], cams["T_world_camera"][index]
            width, height = int(cams.attrs["width"]), int(cams.attrs["height"])
            images = f.get("images")
            rgb = images["rgb"][index] if images is not None and "rgb" in images else None
            depth = images["depth"][index] if images is not None and "depth" in images else None
            seg = images["segmentation"][index] if images is not None and "segmentation" in images else None
            clouds = f.get("clouds")
            points = ids = None
            if clouds is not None and "view_offsets" in clouds:
                a, b = (int(x) for x in clouds["view_offsets"][index : index + 2])
                if "points_world" in clouds:
                    points = clouds["points_world"][a:b]
                elif "points_camera" in clouds:
                    pc_ = clouds["points_camera"][a:b].astype(np.float64)
                    points = (pc_ @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
                if points is not None:
                    ids = clouds["ids"][a:b]
        if points is None:
            if depth is None or seg is None:
                points, ids = np.zeros((0, 3), np.float32), np.zeros(0, np.int16)
            else:  # no stored cloud: back-project the depth image (pinhole, OpenCV)
                valid = (depth > 0) & (seg != SEG_GROUND)
                v, u = np.nonzero(valid)
                z = depth[valid].astype(np.float64)
                cam = np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=-1)
                points = (cam @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
                ids = seg[valid]
        return View(self.scene_id, index, K, T, width, height, rgb, depth, seg, points, ids)


def _attr(value: Any) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


@dataclasses.dataclass(frozen=True, eq=False)
class Sample:
    """A training sample: one view of a scene and the scene's grasps (those that passed the filter)."""

    scene_id: str
    view: View
    grasps: pa.Table
    """The scene's grasps, the columns asked for (``pose_world`` always)."""

    def poses(self, frame: str = "world") -> np.ndarray:
        """(m, 4, 4) grasp TCP poses in the ``world`` or the view's ``camera`` frame."""
        T = np.asarray(self.grasps.column("pose_world").combine_chunks().values, dtype=np.float64)
        T = T.reshape(-1, 4, 4)
        if frame == "world":
            return T
        if frame == "camera":
            return self.view.to_camera(T)
        raise SettingsError(f"frame: must be 'world' or 'camera', got {frame!r}")


class GraspDataset:
    """A published dataset (use :func:`open_dataset`)."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self._file = pq.ParquetFile(self.root / "grasps.parquet")
        card = self.root / "card.json"
        self.card: dict[str, Any] = json.loads(card.read_text()) if card.is_file() else {}
        """The dataset card (counts, label summaries, config, keys), empty when the folder has none."""

    def __len__(self) -> int:
        return self._file.metadata.num_rows

    def __repr__(self) -> str:
        return f"GraspDataset({str(self.root)!r}: {len(self)} grasps, {len(self.scene_ids)} scenes)"

    @property
    def schema(self) -> pa.Schema:
        """The table's schema; each field's ``metadata[b"description"]`` says what it holds."""
        return self._file.schema_arrow

    @property
    def columns(self) -> list[str]:
        return list(self.schema.names)

    @property
    def scene_ids(self) -> list[str]:
        return sorted(p.stem for p in (self.root / "scenes").glob("*.h5"))

    @property
    def object_names(self) -> list[str]:
        return sorted(p.stem for p in (self.root / "objects").glob("*.h5"))

    # -- grasps ---------------------------------------------------------------------------------------------------

    def _expression(self, filter: pc.Expression | None, where: Mapping[str, Any]) -> pc.Expression | None:
        expr = filter
        for column, value in where.items():
            values = list(value) if isinstance(value, (list, tuple, set, frozenset)) else [value]
            if column == "outcome" and all(isinstance(v, str) for v in values):
                column = "outcome_name"  # outcome="success" reads naturally
            if column not in self.schema.names:
                raise NotFoundError(f"no column {column!r}; columns: {', '.join(self.schema.names)}")
            e = pc.field(column).isin(values) if len(values) != 1 else pc.field(column) == values[0]
            expr = e if expr is None else expr & e
        return expr

    def grasps(
        self, columns: Sequence[str] | None = None, filter: pc.Expression | None = None, **where: Any
    ) -> pa.Table:
        """The grasps that match, as a pyarrow Table: ``columns`` to read (default all), ``filter`` any
        ``pyarrow.compute.Expression``, and ``**where`` column equalities ANDed (``outcome=5`` or ``outcome="success"``,
        ``object_name=["box", "can"]`` for any of, ``scene_id="scene_000003"``)."""
        expr = self._expression(filter, where)
        cols = None if columns is None else list(columns)
        if cols is not None:
            unknown = [c for c in cols if c not in self.schema.names]
            if unknown:
                raise NotFoundError(f"no column {unknown[0]!r}; columns: {', '.join(self.schema.names)}")
        return pq.read_table(self.root / "grasps.parquet", columns=cols, filters=expr)

    def _matching_scenes(self, where: Mapping[str, Any]) -> Iterator[str]:
        """Scene ids with a grasp that matches, read one row group at a time (ids only)."""
        import pyarrow.dataset as pads

        expr = self._expression(None, where)
        (fragment,) = pads.dataset(self.root / "grasps.parquet", format="parquet").get_fragments()
        for group in fragment.split_by_row_group(filter=expr):
            yield from group.to_table(columns=["scene_id"], filter=expr).column("scene_id").unique().to_pylist()

    # -- object-centric sets ----------------------------------------------------------------------------------

    def object_grasps(
        self, object_name: str | Sequence[str] | None = None, columns: Sequence[str] | None = None,
        filter: pc.Expression | None = None, **where: Any,
    ) -> pa.Table:
        """Rows of the object-centric sets (``object_grasps.parquet`` or a folder ``object_grasps/`` of that schema),
        sorted by object; ``object_name`` reads only the row groups or files whose statistics can hold it; ``columns``,
        ``filter``, ``**where`` as in :meth:`grasps`.

        Raises
        ------
        graspgen.errors.NotFoundError
            The dataset has no object sets, or an unknown column (also a ``KeyError``).
        """
        return self._set_rows("object_grasps", "object_name", object_name, columns, filter, where)

    def placed_grasps(
        self, scene_id: str | Sequence[str] | None = None, columns: Sequence[str] | None = None,
        filter: pc.Expression | None = None, **where: Any,
    ) -> pa.Table:
        """Rows of the object sets placed in the scenes (``placed_grasps.parquet``), as :meth:`object_grasps`
        with ``scene_id`` selecting row groups (whole scenes each)."""
        return self._set_rows("placed_grasps", "scene_id", scene_id, columns, filter, where)

    def _set_rows(self, name: str, key: str, value: Any, columns: Sequence[str] | None,
                  filter: pc.Expression | None, where: Mapping[str, Any]) -> pa.Table:
        source = _set_source(self.root, name)
        schema = source.schema
        cols = None if columns is None else list(columns)
        for c in [*(cols or []), *where]:
            if c not in schema.names:
                raise NotFoundError(f"no column {c!r} in {name}; columns: {', '.join(schema.names)}")
        values = None if value is None else sorted({value} if isinstance(value, str) else set(value))
        conditions = dict(where) if values is None else {**where, key: values}
        expr = filter
        for column, v in conditions.items():
            vs = list(v) if isinstance(v, (list, tuple, set, frozenset)) else [v]
            e = pc.field(column).isin(vs) if len(vs) != 1 else pc.field(column) == vs[0]
            expr = e if expr is None else expr & e
        parts = []
        for part in source.parts(key, values):
            part = part if expr is None else part.filter(expr)
            parts.append(part if cols is None else part.select(cols))
        if not parts:
            return schema.empty_table() if cols is None else schema.empty_table().select(cols)
        return pa.concat_tables(parts)

    def grasp(self, scene_id: str, grasp_id: int) -> Grasp:
        """One grasp by its ids (every column)."""
        t = self.grasps(scene_id=scene_id, grasp_id=int(grasp_id))
        if len(t) != 1:
            raise NotFoundError(f"no grasp ({scene_id!r}, {grasp_id}) in {self.root}")
        return Grasp(t.to_pylist()[0])

    # -- scenes and objects ---------------------------------------------------------------------------------------

    def scene(self, scene_id: str) -> Scene:
        path = self.root / "scenes" / f"{scene_id}.h5"
        if not path.is_file():
            raise NotFoundError(f"no scene {scene_id!r} in {self.root / 'scenes'}")
        return Scene(path)

    def view(self, scene_id: str, index: int = 0) -> View:
        """A scene's camera view ``index`` (calibration, images, point cloud)."""
        return self.scene(scene_id).view(index)

    def object_mesh(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """``(vertices (v, 3) float64 m, faces (f, 3) int32)`` of an object, in its mesh frame."""
        path = self.root / "objects" / f"{name}.h5"
        if not path.is_file():
            raise NotFoundError(f"no object {name!r} in {self.root / 'objects'}")
        with h5py.File(path, "r") as f:
            return f["mesh/vertices"][()], f["mesh/faces"][()]

    # -- training -------------------------------------------------------------------------------------------------

    def samples(
        self,
        views: int | Sequence[int] | None = None,
        columns: Sequence[str] | None = None,
        filter: pc.Expression | None = None,
        **where: Any,
    ) -> Iterator[Sample]:
        """``(scene, view, grasps)`` samples, scene by scene (one row group in memory at a time), for ``views`` (default
        all); ``columns`` to carry beside ``pose_world`` and the ids; ``filter``, ``**where`` as in :meth:`grasps`.
        Scenes without a matching grasp are skipped."""
        import pyarrow.dataset as pads

        expr = self._expression(filter, where)
        cols = None
        if columns is not None:
            cols = list(dict.fromkeys(["scene_id", "grasp_id", "object_index", "pose_world", *columns]))
        (fragment,) = pads.dataset(self.root / "grasps.parquet", format="parquet").get_fragments()
        # One row group at a time (whole scenes each); groups the filter rules out by their statistics are skipped.
        for group in fragment.split_by_row_group(filter=expr):
            table = group.to_table(columns=cols, filter=expr)
            if len(table) == 0:
                continue
            sid = table.column("scene_id").to_numpy(zero_copy_only=False)
            starts = np.flatnonzero(np.r_[True, sid[1:] != sid[:-1]])
            for a, b in zip(starts, np.r_[starts[1:], len(sid)]):
                scene = self.scene(str(sid[a]))
                chosen = range(scene.num_views) if views is None else [views] if isinstance(views, int) else views
                part = table.slice(int(a), int(b - a))
                for k in chosen:
                    yield Sample(scene.scene_id, scene.view(int(k)), part)

    def torch_dataset(self, **kwargs: Any) -> Any:
        """A PyTorch map-style Dataset of (scene, view) samples: :class:`TorchDataset` (imports torch; raises
        :class:`TorchMissingError`, an ``ImportError``, naming ``pip install 'graspgen[torch]'`` without it)."""
        return __getattr__("TorchDataset")(self.root, **kwargs)


class TorchMissingError(GraspGenError, ModuleNotFoundError):
    """The PyTorch adapter was used where torch is not installed (also a ``ModuleNotFoundError``)."""


def _import_torch() -> Any:
    """``torch``, or one clear error saying how to install it (a torch that is installed but broken raises its
    own error)."""
    try:
        import torch
    except ModuleNotFoundError as exc:
        if exc.name != "torch":
            raise
        raise TorchMissingError(
            "the PyTorch adapter (torch_dataset, TorchDataset) needs torch, which is not installed: "
            "pip install 'graspgen[torch]' (in a checkout: pip install -e '.[torch]')",
            name="torch",
        ) from None
    return torch


class _TorchSamples:
    """The body of :class:`TorchDataset` (a ``torch.utils.data.Dataset`` subclass made when first used).

    Item ``i`` is one (scene, view) with matching grasps (``**where`` as in :meth:`GraspDataset.grasps`), a dict:
    ``points`` (N, 3) float32 and ``point_ids`` (N,) int64 in ``frame`` (``"camera"`` or ``"world"``), ``poses``
    (m, 4, 4) float32 in ``frame``, one (m,) float32 tensor per column of ``labels`` (nulls NaN), ``scene_id``,
    ``view``. Sizes vary per item: batch with ``collate_fn=list`` (or pad).
    """

    def __init__(
        self,
        root: str | Path,
        labels: Sequence[str] = ("outcome", "robustness", "epsilon"),
        frame: str = "camera",
        views: int | Sequence[int] | None = None,
        **where: Any,
    ):
        _import_torch()  # fail here, with one clear message, when torch is not installed
        if frame not in ("world", "camera"):
            raise SettingsError(f"frame: must be 'world' or 'camera', got {frame!r}")
        self.root = open_dataset(root).root
        ds = self._dataset
        self.labels = [c for c in labels if c in ds.columns]
        self.frame = frame
        self.where = dict(where)
        scenes = set(ds._matching_scenes(where))  # one row group's ids at a time, not the whole column
        self.items: list[tuple[str, int]] = []
        for sid in sorted(scenes):
            n = ds.scene(sid).num_views
            chosen = range(n) if views is None else [views] if isinstance(views, int) else views
            self.items += [(sid, int(k)) for k in chosen]

    @property
    def _dataset(self) -> GraspDataset:
        # Opened lazily per process: a ParquetFile does not travel to DataLoader workers.
        ds = self.__dict__.get("_ds")
        if ds is None:
            ds = self.__dict__["_ds"] = GraspDataset(self.root)
        return ds

    def __getstate__(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if k != "_ds"}

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, i: int) -> dict[str, Any]:
        import torch

        sid, k = self.items[i]
        ds = self._dataset
        view = ds.view(sid, k)
        grasps = ds.grasps(columns=["pose_world", *self.labels], **{**self.where, "scene_id": sid})
        sample = Sample(sid, view, grasps)
        points, ids = view.cloud(self.frame)
        out = {
            "scene_id": sid,
            "view": k,
            "points": torch.from_numpy(np.ascontiguousarray(points, dtype=np.float32)),
            "point_ids": torch.from_numpy(ids.astype(np.int64)),
            "poses": torch.from_numpy(sample.poses(self.frame).astype(np.float32)),
        }
        for c in self.labels:
            values = np.asarray(grasps.column(c).to_numpy(zero_copy_only=False), dtype=np.float32)
            out[c] = torch.from_numpy(values)
        return out


def __getattr__(name: str) -> Any:
    # TorchDataset subclasses torch.utils.data.Dataset, so the class is made on first access (importing torch
    # then, not when this module is imported) and kept as a module attribute: pickling finds it by name.
    if name == "TorchDataset":
        if "TorchDataset" in globals():
            return globals()["TorchDataset"]
        _import_torch()
        from torch.utils.data import Dataset

        cls = type("TorchDataset", (_TorchSamples, Dataset), {"__module__": __name__, "__doc__": _TorchSamples.__doc__})
        globals()["TorchDataset"] = cls
        return cls
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class _SetSource:
    """One object-set table in either layout: a file (its row groups) or a folder of files (each file's groups)."""

    def __init__(self, paths: list[Path]):
        self.paths = paths
        self.schema = pq.read_schema(paths[0])
        self.groups_read = 0
        """Row groups read so far (what a selection cost)."""

    def parts(self, key: str, values: list[str] | None) -> Iterator[pa.Table]:
        """The row groups that can hold rows with ``key`` in ``values`` (all when None), in file order, read one
        at a time; the others are skipped by their ``key`` statistics, unread."""
        for path in self.paths:
            pf = pq.ParquetFile(path)
            leaves = pf.metadata.schema
            column = next(j for j in range(len(leaves)) if leaves.column(j).path == key)
            for i in range(pf.metadata.num_row_groups):
                if values is None or _may_hold(pf.metadata.row_group(i).column(column).statistics, values):
                    self.groups_read += 1
                    yield pf.read_row_group(i)


def _may_hold(stats: Any, values: list[str]) -> bool:
    """Whether a row group with these column statistics can hold one of ``values`` (yes when it has none)."""
    if stats is None or not stats.has_min_max:
        return True
    return any(stats.min <= v <= stats.max for v in values)


def _set_source(root: Path, name: str) -> _SetSource:
    one = root / f"{name}.parquet"
    if one.is_file():
        return _SetSource([one])
    folder = root / name
    files = sorted(folder.glob("*.parquet")) if folder.is_dir() else []
    if not files:
        raise NotFoundError(f"no {name} in {root} (neither {one.name} nor a folder {name}/ of Parquet files)")
    return _SetSource(files)
