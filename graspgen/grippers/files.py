"""Gripper files: a :class:`~graspgen.grippers.spec.GripperSpec` read from YAML or JSON (:func:`read_gripper`,
:func:`gripper_from_dict`, with convex mesh pieces from mesh files) and written back (:func:`write_gripper`). The
format is in :func:`read_gripper` and ``assets/grippers/README.md``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import MISSING, fields
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from graspgen.errors import SettingsError
from graspgen.grippers.bundled import bundled_names
from graspgen.grippers.model_ref import MODEL_KEYS, model_ref_from_dict, spec_from_model
from graspgen.grippers.shapes import Box, Linkage, Mesh, Shape, bounds_of, short_repr
from graspgen.grippers.spec import GripperSpec
from graspgen.validation import check, check_choice, check_number, check_vector

__all__ = ["GRIPPER_FILE_SUFFIXES", "gripper_from_dict", "read_gripper", "read_mesh_file", "write_gripper"]

#: A mesh piece whose convex hull is this much larger than the piece is refused as not convex (MuJoCo would
#: collide its hull).
_MAX_HULL_EXCESS = 0.05
#: Suffixes of gripper files.
GRIPPER_FILE_SUFFIXES = (".yaml", ".yml", ".json")
#: Keys a gripper file may have besides the :class:`GripperSpec` fields.
_FILE_ONLY_KEYS = ("frame",)
_FILE_DEFAULTS = {"min_width": 0.0, "pad_friction": (1.0, 0.005, 0.0001)}
_FRAMES = ("tcp", "base")


def read_mesh_file(path: Path, where: str):
    """The ``trimesh.Trimesh`` of a gripper's mesh file; SettingsError naming ``where`` and the file when it is
    missing or unreadable."""
    import trimesh

    if not path.is_file():
        raise SettingsError(f"{where}: mesh file {path} not found")
    try:
        return trimesh.load(path, force="mesh")
    except Exception as exc:  # noqa: BLE001 - trimesh raises many types for unreadable files
        raise SettingsError(f"{where}: cannot read mesh file {path} ({type(exc).__name__}: {exc})") from None


def _mesh_pieces(path: Path, scale: float, where: str) -> list[np.ndarray]:
    """Vertices of the convex hull of each connected component of the mesh file ``path`` (times ``scale``)."""
    import trimesh

    mesh = read_mesh_file(path, where)
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise SettingsError(f"{where}: mesh file {path} holds no triangles")
    pieces = []
    for k, part in enumerate(mesh.split(only_watertight=False) or [mesh]):
        part = part.copy()
        part.apply_scale(scale)
        hull = part.convex_hull
        if part.is_watertight and part.volume > 0 and hull.volume > (1.0 + _MAX_HULL_EXCESS) * part.volume:
            raise SettingsError(
                f"{where}: {path} piece {k} is not convex (its hull is {hull.volume / part.volume - 1:.0%} larger); "
                "MuJoCo collides convex hulls, so split it into convex pieces (e.g. with CoACD, as "
                "assets/make_grippers.py does) and list them"
            )
        pieces.append(np.asarray(hull.vertices, dtype=float))
    return pieces


def _shapes(key: str, value: Any, base_dir: Path, shift: np.ndarray) -> list[Shape]:
    """The shapes of a file entry: a box ``{size, pos}``, a mesh file ``{mesh, scale}`` (one piece per connected
    component) or inline ``{vertices}``; ``shift`` moves them from the file's frame to the TCP frame."""
    items = [value] if isinstance(value, Mapping) else value
    if not isinstance(items, (list, tuple)):
        raise SettingsError(f"{key}: must be a list of geoms ({{size, pos}}, {{mesh}} or {{vertices}}), got "
                            f"{short_repr(value)}")
    out: list[Shape] = []
    for i, item in enumerate(items):
        where = key if isinstance(value, Mapping) else f"{key}[{i}]"
        kinds = {"size": ("size", "pos"), "mesh": ("mesh", "scale"), "vertices": ("vertices",)}
        kind = next((k for k in kinds if isinstance(item, Mapping) and k in item), None)
        if kind is None:
            raise SettingsError(f"{where}: must be a box {{size, pos}}, a mesh file {{mesh, scale}} or "
                                f"{{vertices}}, got {short_repr(item)}")
        unknown = sorted(set(item) - set(kinds[kind]))
        if unknown:
            raise SettingsError(f"{where}: unknown key {unknown[0]!r}; a {kind} entry has: {', '.join(kinds[kind])}")
        try:
            if kind == "size":
                pos = np.asarray(check_vector("pos", item.get("pos", (0.0, 0.0, 0.0)), 3)) + shift
                out.append(Box(size=item["size"], pos=tuple(pos)))
            elif kind == "vertices":
                vertices = np.asarray(Mesh(item["vertices"]).vertices) + shift
                out.append(Mesh(vertices))
            else:
                name = item["mesh"]
                check("mesh", isinstance(name, str) and bool(name), "be a file name", name)
                scale = check_number("scale", item.get("scale", 1.0), low=0.0, low_open=True)
                path = base_dir / name
                out += [Mesh(v + shift, file=str(path)) for v in _mesh_pieces(path, scale, "mesh")]
        except SettingsError as exc:
            raise SettingsError(f"{where}: {exc}") from None
    return out


_LINKAGE_KEYS = ("pivot", "crank", "follower_pivot", "driver_geoms", "follower_geoms", "driver_mass",
                 "follower_mass")


def _linkage(value: Any, base_dir: Path, shift: np.ndarray) -> Linkage:
    """The :class:`Linkage` of a file's ``linkage`` mapping (pivots moved by ``shift`` into the TCP frame)."""
    if not isinstance(value, Mapping):
        raise SettingsError(f"linkage: must be a mapping ({', '.join(_LINKAGE_KEYS)}), got {short_repr(value)}")
    unknown = sorted(str(k) for k in set(value) - set(_LINKAGE_KEYS))
    if unknown:
        raise SettingsError(f"linkage.{unknown[0]}: unknown key; valid keys: {', '.join(_LINKAGE_KEYS)}")
    missing = [k for k in ("pivot", "crank", "follower_pivot", "driver_geoms") if k not in value]
    if missing:
        raise SettingsError(f"linkage.{missing[0]}: missing")
    values = dict(value)
    for key in ("pivot", "follower_pivot"):
        x, z = check_vector(f"linkage.{key}", values[key], 2)
        values[key] = (x, z + shift[2])
    for key in ("driver_geoms", "follower_geoms"):
        values[key] = tuple(_shapes(f"linkage.{key}", values.get(key) or [], base_dir, shift))
    return Linkage(**values)


def gripper_from_dict(data: Mapping[str, Any], *, base_dir: str | os.PathLike = ".", file: str = "") -> GripperSpec:
    """A :class:`GripperSpec` from the contents of a gripper file (see :func:`read_gripper`); mesh files are
    relative to ``base_dir``. :class:`SettingsError` names the offending key."""
    if not isinstance(data, Mapping):
        raise SettingsError(f"must be a mapping of gripper settings (name, max_width, ...), got {short_repr(data)}")
    names = [f.name for f in fields(GripperSpec) if f.name not in ("file", "model_files")]
    if "model" in data:
        return _from_model(data, names, Path(base_dir), file)
    unknown = sorted(str(k) for k in set(data) - set(names) - set(_FILE_ONLY_KEYS))
    if unknown:
        valid = ", ".join(sorted(names + list(_FILE_ONLY_KEYS)))
        raise SettingsError(f"{unknown[0]}: unknown key; valid keys: {valid}")
    values = {**_FILE_DEFAULTS, **{k: v for k, v in data.items() if k in names}}
    frame = data.get("frame", "tcp")
    check_choice("frame", frame, _FRAMES)
    shift = np.zeros(3)
    if frame == "base":
        shift[2] = -check_number("tcp_offset", values.get("tcp_offset"), low=0.0, low_open=True)
    base = Path(base_dir)
    for key in ("palm_geoms", "finger_geoms"):
        values[key] = tuple(_shapes(key, values.get(key) or [], base, shift))
    if values.get("pad_geom") is not None:
        pad = _shapes("pad_geom", values["pad_geom"], base, shift)
        check("pad_geom", len(pad) == 1, "be one convex piece", f"{len(pad)} pieces")
        values["pad_geom"] = pad[0]
        lo, hi = pad[0].bounds
        values.setdefault("pad_size", tuple(hi - lo))
    if values.get("linkage") is not None:
        values["linkage"] = _linkage(values["linkage"], base, shift)
    boxes = values.get("palm_boxes") or []
    if not isinstance(boxes, (list, tuple)) or not all(isinstance(b, Mapping) and "size" in b for b in boxes):
        raise SettingsError(f"palm_boxes: must be a list of boxes {{size, pos}}, got {short_repr(boxes)}")
    values["palm_boxes"] = tuple(_shapes("palm_boxes", list(boxes), base, shift))
    if values["finger_geoms"] and "finger_size" not in values:
        pieces = values["finger_geoms"] + ((values["pad_geom"],) if values.get("pad_geom") is not None else ())
        lo, hi = bounds_of(pieces)
        values["finger_size"] = tuple(hi - lo)
    missing = [f.name for f in fields(GripperSpec)
               if f.name not in values and f.default is MISSING and f.default_factory is MISSING]
    if missing:
        raise SettingsError(f"{missing[0]}: missing (a gripper file needs {', '.join(missing)})")
    return GripperSpec(**values, file=file)


#: GripperSpec fields a gripper file with ``model:`` may give beside it (the geometry comes from the model).
_MODEL_OVERRIDES = ("name", "min_width", "max_width", "force_limit", "closing_speed", "finger_mass", "body_mass",
                    "pad_friction", "pad_condim", "source")


def _from_model(data: Mapping[str, Any], names: list[str], base_dir: Path, file: str) -> GripperSpec:
    """The spec of a gripper file that names a robot model (``model:``; :mod:`graspgen.grippers.model_ref`)."""
    valid = sorted(MODEL_KEYS + _MODEL_OVERRIDES)
    unknown = sorted(str(k) for k in set(data) - set(valid))
    if unknown:
        geometry = " (the geometry comes from the model)" if unknown[0] in names else ""
        raise SettingsError(f"{unknown[0]}: not valid beside model{geometry}; valid keys: {', '.join(valid)}")
    if "name" not in data:
        raise SettingsError("name: missing (a gripper file needs a name)")
    overrides = {k: data[k] for k in _MODEL_OVERRIDES if k in data}
    return spec_from_model(model_ref_from_dict(data, base_dir, overrides), file=file)


_FILE_CACHE: dict[tuple, tuple[GripperSpec, tuple]] = {}


def _file_stamps(files) -> tuple:
    """``((path, mtime_ns, size), ...)`` of ``files``; a file that is gone stamps ``(path, None, None)``."""
    stamps = []
    for f in files:
        try:
            st = os.stat(f)
            stamps.append((str(f), st.st_mtime_ns, st.st_size))
        except OSError:
            stamps.append((str(f), None, None))
    return tuple(stamps)


def read_gripper(path: str | os.PathLike) -> GripperSpec:
    """Read a gripper file: YAML (``.yaml``, ``.yml``) or JSON (``.json``), a mapping of :class:`GripperSpec` fields.

    * Required: ``name``, ``max_width``, ``tcp_offset``, ``force_limit``, ``closing_speed``, ``finger_mass``,
      ``body_mass`` and the geometry; optional: ``min_width`` (0), ``pad_friction`` (1, 0.005, 0.0001),
      ``pad_condim`` (4), ``source``.
    * Geometry, in metres, in the TCP frame (z approach, x closing, origin midway between the pads) or, with
      ``frame: base``, in the hand-base frame (the TCP at ``tcp_offset`` along z); the fingers as they are when
      open (pad separation ``max_width``):

      - boxes by size: ``pad_size``, ``finger_size`` ([thickness x, width y, length z]) and ``palm_boxes``
        (a list of ``{size: [x, y, z], pos: [x, y, z]}``), placed as in :class:`GripperSpec`; or
      - pieces per body: ``palm_geoms`` and ``finger_geoms`` (lists) and ``pad_geom`` (one), each a box
        ``{size, pos}``, a mesh file ``{mesh: hand.obj, scale: 1.0}`` (relative to the gripper file; each connected
        component is one convex piece, a non-convex one is refused) or ``{vertices: [[x, y, z], ...]}``. Give the
        right finger (+x) and its pad; the left one is it turned 180 degrees about z. The pad's contact face
        (its smallest x) must lie at ``max_width / 2``. ``pad_size`` (the contact area) and ``finger_size`` default
        to the pieces' bounding boxes.

    * Or a robot model: ``model`` (a URDF / MJCF file) with ``pads`` and, where needed, ``joints``, ``actuator``,
      ``body``, ``finger_box``; the geometry is then derived from the model (:mod:`graspgen.grippers.model_ref`,
      :mod:`graspgen.sim.gripper_import`), and only ``name`` and the scalars that supply or override derived values
      may stand beside it.

    Returns the spec (cached while the gripper file and the model files it names, meshes included, are unchanged).
    Raises :class:`SettingsError` in one line,
    ``gripper: <path>: <what>``.
    """
    label = os.fspath(path)
    p = Path(label)
    if p.suffix.lower() not in GRIPPER_FILE_SUFFIXES:
        raise SettingsError(f"gripper: {label}: not a gripper file (expected {', '.join(GRIPPER_FILE_SUFFIXES)}); "
                            f"bundled grippers: {bundled_names()}")
    try:
        stat = p.stat()
        if not p.is_file():
            raise IsADirectoryError(label)
    except OSError:
        raise SettingsError(f"gripper: {label}: no such gripper file; bundled grippers: {bundled_names()}") from None
    key = (label, str(p.resolve()), stat.st_mtime_ns, stat.st_size)
    if key in _FILE_CACHE:
        spec, stamps = _FILE_CACHE[key]
        if _file_stamps(spec.model_files) == stamps:
            return spec
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SettingsError(f"gripper: {label}: cannot read it ({type(exc).__name__}: {exc})") from None
    try:
        data = json.loads(text) if p.suffix.lower() == ".json" else yaml.safe_load(text)
    except json.JSONDecodeError as exc:
        raise SettingsError(f"gripper: {label}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        problem = " ".join(str(getattr(exc, "problem", None) or exc).split())
        raise SettingsError(f"gripper: {label}: not valid YAML ({problem}{where})") from None
    try:
        spec = gripper_from_dict(data, base_dir=p.parent, file=label)
    except SettingsError as exc:
        raise SettingsError(f"gripper: {label}: {' '.join(str(exc).split())}") from None
    _FILE_CACHE[key] = (spec, _file_stamps(spec.model_files))
    return spec


def write_gripper(spec: GripperSpec, path: str | os.PathLike) -> Path:
    """Write ``spec`` as a gripper file (YAML, or JSON for ``.json``) that :func:`read_gripper` reads back into an
    equal spec (meshes written as their vertices). Returns the path."""
    p = Path(path)
    if p.suffix.lower() not in GRIPPER_FILE_SUFFIXES:
        raise SettingsError(f"path: a gripper file ends in {', '.join(GRIPPER_FILE_SUFFIXES)}, got {p.name!r}")
    data = spec.to_dict()
    text = json.dumps(data, indent=1) + "\n" if p.suffix.lower() == ".json" else yaml.safe_dump(data, sort_keys=False)
    p.write_text(text, encoding="utf-8")
    return p
