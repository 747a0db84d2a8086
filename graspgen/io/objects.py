"""Object records: the HDF5 layout of a prepared object (mesh, convex parts, mass properties, stable poses)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

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
    """Provenance and flags (source file, scale, density, warnings, ...)."""


def object_tree(name: str, path: Path, prepared: PreparedObject, params: Mapping[str, Any]) -> dict[str, Any]:
    """The HDF5 layout of one object shard (see the module docstring)."""
    parts = prepared.convex_parts
    v_off = np.cumsum([0] + [len(v) for v, _ in parts], dtype=np.int64)
    f_off = np.cumsum([0] + [len(f) for _, f in parts], dtype=np.int64)
    mass = prepared.mass
    return {
        "@attrs": {
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
