"""Object records: the HDF5 layout of a prepared object (mesh, convex parts, mass properties, stable poses), and
object manifests: a CSV or YAML file listing objects with their own settings (:func:`read_object_manifest`).

An object manifest has one object per CSV row (a header row names the columns) or per YAML list entry (a mapping)::

    path,name,scale,mass,density,friction,category
    meshes/mug.obj,,0.001,0.35,,0.6,mug
    meshes/bolt.stl,bolt_m8,,,7800,0.4,hardware

    - {path: meshes/mug.obj, scale: 0.001, mass: 0.35, friction: 0.6, category: mug}
    - {path: meshes/bolt.stl, name: bolt_m8, density: 7800, friction: 0.4, category: hardware}

Columns (:data:`MANIFEST_COLUMNS`; only ``path`` is required, an empty cell or a missing key means "not given"):
``path`` the mesh file, relative to the manifest's folder (or absolute); ``name`` the object's name (default: the
file's stem); ``scale`` metres per mesh unit; ``mass`` kg or ``density`` kg/m^3 (not both); ``friction`` the
object's sliding friction coefficient in simulation; ``category`` free text (``mug``, ``tool``).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from graspgen.errors import InputError
from graspgen.geometry.mesh_io import SUPPORTED_SUFFIXES
from graspgen.geometry.prepare import PreparedObject
from graspgen.io.files import read_h5, sha256_file


@dataclasses.dataclass(frozen=True)
class ObjectRecord:
    """A prepared object as read back from its shard (what downstream stages use)."""

    name: str
    vertices: np.ndarray
    """(v, 3) float64, m, mesh frame."""
    faces: np.ndarray
    """(f, 3) int32."""
    convex_parts: list[tuple[np.ndarray, np.ndarray]]
    """Convex parts as (vertices (n, 3) float64, faces (m, 3) int32)."""
    mass: float
    """kg."""
    center_of_mass: np.ndarray
    """(3,) m, mesh frame."""
    inertia: np.ndarray
    """(3, 3) kg m^2 about the centre of mass, mesh frame axes."""
    stable_poses: np.ndarray
    """(n, 4, 4) transforms placing the mesh frame so the object rests on the plane z = 0."""
    stable_probabilities: np.ndarray
    """(n,) probabilities, summing to 1."""
    attrs: dict[str, Any]
    """Provenance and flags (source file, scale, density, warnings, ...); ``friction`` and ``category`` only for an
    object that has its own (from an object manifest)."""

    @property
    def friction(self) -> float | None:
        """The object's own sliding friction coefficient (unitless), None when it has none (the scenes stage then
        draws one from ``scenes.friction``)."""
        value = self.attrs.get("friction")
        return None if value is None else float(value)

    @property
    def category(self) -> str | None:
        """The object's category (free text from its manifest row), None when it has none."""
        value = self.attrs.get("category")
        return None if value is None else str(value)


def object_tree(
    name: str,
    path: Path,
    prepared: PreparedObject,
    params: Mapping[str, Any],
    *,
    friction: float | None = None,
    category: str | None = None,
) -> dict[str, Any]:
    """The HDF5 layout of one object shard (see the ``objects`` stage's docstring).

    ``friction`` (the object's own sliding friction coefficient) and ``category`` become attributes only when
    given, so an object without them keeps the same shard bytes.
    """
    parts = prepared.convex_parts
    v_off = np.cumsum([0] + [len(v) for v, _ in parts], dtype=np.int64)
    f_off = np.cumsum([0] + [len(f) for _, f in parts], dtype=np.int64)
    mass = prepared.mass
    own: dict[str, Any] = {}
    if friction is not None:
        own["friction"] = float(friction)
    if category is not None:
        own["category"] = str(category)
    return {
        "@attrs": {
            **own,
            "name": name,
            "source_file": path.name,
            "source_sha256": sha256_file(path),
            "scale": float(prepared.scale),
            "density": float(mass.mass / mass.volume),
            "mass": float(mass.mass),
            "volume": float(mass.volume),
            "watertight": bool(prepared.repair.watertight),
            "from_convex_hull": bool(mass.from_convex_hull),
            "repair_notes": list(prepared.repair.notes),
            "warnings": list(prepared.warnings),
            "params": dict(params),
        },
        "mesh": {
            "vertices": np.asarray(prepared.vertices, dtype=np.float64),
            "faces": np.asarray(prepared.faces, dtype=np.int32),
        },
        "convex": {
            "vertices": np.concatenate([v for v, _ in parts]).astype(np.float64),
            "faces": np.concatenate([f for _, f in parts]).astype(np.int32),
            "vertex_offsets": v_off,
            "face_offsets": f_off,
        },
        "mass": {
            "center_of_mass": np.asarray(mass.center_of_mass, dtype=np.float64),
            "inertia": np.asarray(mass.inertia, dtype=np.float64),
        },
        "stable_poses": {
            "transforms": np.asarray(prepared.stable_transforms, dtype=np.float64),
            "probabilities": np.asarray(prepared.stable_probabilities, dtype=np.float64),
        },
    }


def read_object(path: str | Path) -> ObjectRecord:
    """Read an object shard written by the ``objects`` stage."""
    tree = read_h5(path)
    conv = tree["convex"]
    v_off, f_off = conv["vertex_offsets"], conv["face_offsets"]
    parts = [
        (conv["vertices"][v_off[i] : v_off[i + 1]], conv["faces"][f_off[i] : f_off[i + 1]])
        for i in range(len(v_off) - 1)
    ]
    attrs = tree["@attrs"]
    return ObjectRecord(
        name=attrs["name"],
        vertices=tree["mesh"]["vertices"],
        faces=tree["mesh"]["faces"],
        convex_parts=parts,
        mass=float(attrs["mass"]),
        center_of_mass=tree["mass"]["center_of_mass"],
        inertia=tree["mass"]["inertia"],
        stable_poses=tree["stable_poses"]["transforms"],
        stable_probabilities=tree["stable_poses"]["probabilities"],
        attrs=attrs,
    )


# --------------------------------------------------------------------------------------------------------------
# Object manifests

MANIFEST_COLUMNS = ("path", "name", "scale", "mass", "density", "friction", "category")
"""The columns (CSV) or keys (YAML) an object manifest may have; only ``path`` is required."""
MANIFEST_SUFFIXES = (".csv", ".yaml", ".yml")
"""File suffixes of object manifests: CSV, or YAML."""
_UNITS = {
    "scale": "m per mesh unit",
    "mass": "kg",
    "density": "kg/m^3",
    "friction": "sliding friction coefficient",
}


@dataclasses.dataclass(frozen=True)
class ManifestEntry:
    """One object of an object manifest (:func:`read_object_manifest`)."""

    name: str
    """Object name: the ``name`` column, else the mesh file's stem."""
    path: Path
    """The mesh file: the ``path`` column joined to the manifest's folder (unchanged when absolute)."""
    row: int
    """Which object of the manifest it is, from 1 (CSV: data rows, the header not counted; YAML: list entries)."""
    scale: float | None = None
    """Metres per mesh unit; None: not given (the config's ``objects.scale``, or detected from the size)."""
    mass: float | None = None
    """Mass, kg; None: not given."""
    density: float | None = None
    """Density, kg/m^3; None: not given."""
    friction: float | None = None
    """Sliding friction coefficient of the object in simulation (unitless, > 0); None: not given."""
    category: str | None = None
    """Free-text class of the object (``mug``, ``tool``); None: not given."""


def read_object_manifest(path: str | Path) -> list[ManifestEntry]:
    """The objects an object manifest lists (format: the module docstring), in file order.

    Every mesh file must exist; numbers must be finite and > 0; ``mass`` and ``density`` exclude each other; names
    must be unique.

    Raises
    ------
    InputError
        Naming the manifest file, the row (and for CSV the line) and the column: a missing or unreadable file, an
        unknown column (listing the valid ones), a missing ``path``, a mesh file that does not exist, a value that
        is not a number or not > 0, a duplicate name.
    """
    path = Path(path)
    if path.suffix.lower() not in MANIFEST_SUFFIXES:
        raise InputError(
            f"{path}: an object manifest must be a CSV or YAML file ({', '.join(MANIFEST_SUFFIXES)}), "
            f"got {path.suffix or 'no suffix'!r}"
        )
    try:
        text = path.read_text(encoding="utf-8-sig")  # -sig: a spreadsheet's byte order mark is no column name
    except FileNotFoundError:
        raise InputError(f"{path}: object manifest not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the object manifest ({getattr(exc, 'strerror', None) or exc})") from None
    rows = _csv_rows(path, text) if path.suffix.lower() == ".csv" else _yaml_rows(path, text)
    if not rows:
        raise InputError(f"{path}: the object manifest lists no objects")
    entries: list[ManifestEntry] = []
    names: dict[str, int] = {}
    for row, (where, raw) in enumerate(rows, start=1):
        entry = _manifest_entry(path, row, where, raw)
        if entry.name in names:
            raise InputError(
                f"{where}, column 'name': {entry.name!r} is already the name of row {names[entry.name]}; "
                "names must be unique (set the name column of one of them)"
            )
        names[entry.name] = row
        entries.append(entry)
    return entries


def _unknown_columns(where: str, columns: list[Any]) -> None:
    for column in columns:
        if column not in MANIFEST_COLUMNS:
            raise InputError(f"{where}: unknown column {column!r}; valid columns: {', '.join(MANIFEST_COLUMNS)}")


def _csv_rows(path: Path, text: str) -> list[tuple[str, dict[str, Any]]]:
    """(where, {column: cell}) of each data row of a CSV manifest; blank lines skipped."""
    reader = csv.reader(io.StringIO(text))
    header: list[str] | None = None
    rows = []
    try:
        for cells in reader:
            if not any(c.strip() for c in cells):
                continue
            if header is None:
                header = [c.strip() for c in cells]
                _unknown_columns(f"{path}: header (line {reader.line_num})", header)
                repeated = sorted({c for c in header if header.count(c) > 1})
                if repeated:
                    raise InputError(f"{path}: header (line {reader.line_num}): column {repeated[0]!r} appears twice")
                if "path" not in header:
                    raise InputError(
                        f"{path}: header (line {reader.line_num}): no 'path' column (every object needs its mesh "
                        f"file); columns: {', '.join(MANIFEST_COLUMNS)}"
                    )
                continue
            where = f"{path}: row {len(rows) + 1} (line {reader.line_num})"
            if len(cells) > len(header):
                raise InputError(f"{where}: {len(cells)} cells but the header names {len(header)} columns")
            rows.append((where, dict(zip(header, cells))))
    except csv.Error as exc:
        raise InputError(f"{path}: line {reader.line_num}: not valid CSV ({exc})") from None
    return rows


def _yaml_rows(path: Path, text: str) -> list[tuple[str, dict[str, Any]]]:
    """(where, {key: value}) of each entry of a YAML manifest (a list of mappings)."""
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML: {exc}") from None
    if data is None:
        return []
    if not isinstance(data, list):
        raise InputError(
            f"{path}: an object manifest must be a list of objects (mappings with a path key), "
            f"got {type(data).__name__}"
        )
    rows = []
    for row, item in enumerate(data, start=1):
        where = f"{path}: row {row}"
        if not isinstance(item, dict):
            raise InputError(
                f"{where}: must be a mapping with a path key ({', '.join(MANIFEST_COLUMNS)}), got {item!r}"
            )
        _unknown_columns(where, list(item))
        rows.append((where, item))
    return rows


def _manifest_entry(manifest: Path, row: int, where: str, raw: Mapping[str, Any]) -> ManifestEntry:
    """One row's entry, its values checked (messages start with ``where`` and name the column)."""

    def text(column: str) -> str | None:
        value = raw.get(column)
        if value is None or isinstance(value, (dict, list, bool)):
            if value is not None:
                raise InputError(f"{where}, column {column!r}: must be text, got {value!r}")
            return None
        return str(value).strip() or None

    def number(column: str) -> float | None:
        value = raw.get(column)
        if value is None or isinstance(value, str) and not value.strip():
            return None
        try:
            if isinstance(value, bool):
                raise ValueError
            x = float(value.strip() if isinstance(value, str) else value)
        except (TypeError, ValueError):
            raise InputError(f"{where}, column {column!r}: {value!r} is not a number ({_UNITS[column]})") from None
        if not (math.isfinite(x) and x > 0):
            raise InputError(
                f"{where}, column {column!r}: must be a finite number > 0 ({_UNITS[column]}), got {value!r}"
            )
        return x

    file = text("path")
    if file is None:
        raise InputError(f"{where}, column 'path': empty; every object needs its mesh file")
    mesh = manifest.parent / file
    if not mesh.is_file():
        what = "is a folder, not a mesh file" if mesh.is_dir() else "no such file"
        raise InputError(f"{where}, column 'path': {what}: {mesh}")
    if mesh.suffix.lower() not in SUPPORTED_SUFFIXES:
        raise InputError(
            f"{where}, column 'path': unsupported mesh format {mesh.suffix or '(no suffix)'!r} of {mesh}, expected "
            f"one of {', '.join(SUPPORTED_SUFFIXES)}"
        )
    name = text("name") or mesh.stem
    if "/" in name or "\\" in name or name.startswith("."):
        raise InputError(
            f"{where}, column 'name': {name!r} must be a plain name (no '/' or '\\', not starting with '.')"
        )
    mass, density = number("mass"), number("density")
    if mass is not None and density is not None:
        raise InputError(
            f"{where}, columns 'mass' and 'density': give one of them, not both "
            f"(mass {mass} kg, density {density} kg/m^3)"
        )
    return ManifestEntry(
        name=name,
        path=mesh,
        row=row,
        scale=number("scale"),
        mass=mass,
        density=density,
        friction=number("friction"),
        category=text("category"),
    )
