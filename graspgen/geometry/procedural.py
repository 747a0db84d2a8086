"""Procedural objects: watertight meshes drawn from a seed, sized to fit between a gripper's open jaws.

Random procedural objects are a training source of their own (Tobin et al. 2018 trained grasp networks on thousands
of them and transferred to real objects). Four families (:data:`FAMILIES`):

- ``superquadric``: an icosphere mapped radially onto a superellipsoid ``(|x|^(2/e2) + |y|^(2/e2))^(e2/e1) +
  |z|^(2/e1) = 1`` with exponents ``e1, e2`` in [0.25, 1.6] (boxy to pinched);
- ``blob``: the convex hull of 8-32 Gaussian points;
- ``extrusion``: a prism over a random star-shaped polygon of 5-12 corners (radii 0.45-1: usually not convex);
- ``union``: the boolean union (manifold3d) of 2-3 boxes, cylinders and spheres, each later one centred inside the
  first (so the union is one body) and turned at random.

Each shape is then scaled per axis so its bounding box has the drawn extents: the largest uniform in ``size_range``,
the smallest uniform in ``[0.3 * largest, min(largest, max_grasp_width)]``, the middle one uniform between the
smallest and ``min(largest, max_grasp_width)``, the three assigned to the axes in a random order. So the gripper
spans an object across either of its two thinner axes; in particular from above when it rests on its broadest face
(docs/decisions/2026-12-07-procedural-extents.md).

Two steps, so that a task key can hash what a mesh is made from: :func:`draw_shape` draws object ``index``'s family
parameters (a :class:`ProceduralShape`, JSON-able by :meth:`ProceduralShape.spec`), and :func:`build_mesh` turns
them, and only them, into a checked mesh (:func:`check_solid`). Object ``index``'s generator is seeded from
``(seed, index, family)`` alone, so it does not depend on ``count`` or on the other objects. Meshes have at most a few
thousand faces (icosphere of 1,280, circles of 24 segments) so convex decomposition stays cheap. Units: m.
"""

from __future__ import annotations

import dataclasses
import zlib
from collections.abc import Mapping
from typing import Any

import numpy as np
import trimesh

from graspgen.errors import InputError
from graspgen.validation import check, check_choice, check_int, check_number, check_range

__all__ = [
    "FAMILIES",
    "MIN_ASPECT",
    "ProceduralParams",
    "ProceduralShape",
    "build_mesh",
    "check_solid",
    "draw_shape",
    "draw_shapes",
    "shape_from_spec",
    "shape_name",
]

FAMILIES = ("superquadric", "blob", "extrusion", "union")
"""The shape families, in the order objects cycle through them."""

MIN_ASPECT = 0.3
"""The smallest extent is at least this fraction of the largest (no needles or sheets)."""

GENERATOR_VERSION = 1
"""Bump when a family's drawing or meshing changes: it enters every shape's spec, hence the task keys."""

_ICOSPHERE_SUBDIVISIONS = 3  # 1,280 faces
_CIRCLE_SEGMENTS = 24
_PRIMITIVES = ("box", "cylinder", "sphere")


@dataclasses.dataclass(frozen=True)
class ProceduralParams:
    """How many procedural objects to make, of which families, from which seed and how large."""

    count: int = 12
    """Number of objects (indices ``0 .. count - 1``)."""
    families: tuple[str, ...] = FAMILIES
    """Families to cycle through: object ``i`` is of family ``families[i % len(families)]`` (see :data:`FAMILIES`)."""
    seed: int = 0
    """Seed of the shapes (>= 0): the same seed gives the same shapes, names and bytes."""
    size_range: tuple[float, float] = (0.04, 0.12)
    """``[min, max]`` of an object's largest bounding-box extent, m."""
    max_grasp_width: float = 0.06
    """An object's two smaller bounding-box extents are at most this, m: less than the gripper's largest opening,
    so it can be grasped across either (the project config checks it against the configured grippers)."""

    def __post_init__(self) -> None:
        check_int("count", self.count, low=1)
        check("families", len(self.families) > 0, f"list at least one of {', '.join(FAMILIES)}", self.families)
        for i, family in enumerate(self.families):
            check_choice(f"families[{i}]", family, FAMILIES)
        check("families", len(set(self.families)) == len(self.families), "not repeat a family", self.families)
        check_int("seed", self.seed, low=0)
        lo, hi = check_range("size_range", self.size_range, low=0.005, high=0.5)
        check("size_range", lo > 0.005, "have min > 0.005 m", self.size_range)
        object.__setattr__(self, "size_range", (lo, hi))
        width = check_number("max_grasp_width", self.max_grasp_width, low=0.0, low_open=True)
        check("max_grasp_width", width > MIN_ASPECT * hi,
              f"be > {MIN_ASPECT} * size_range max = {MIN_ASPECT * hi:.4g} m (the thinnest an object of the largest "
              "size may be)", self.max_grasp_width)


@dataclasses.dataclass(frozen=True)
class ProceduralShape:
    """One procedural object's generation parameters: everything :func:`build_mesh` reads."""

    name: str
    """``<family>_s<seed>_<index:05d>``: unique per seed and index, readable."""
    family: str
    """One of :data:`FAMILIES`."""
    seed: int
    """The seed of the set it belongs to."""
    index: int
    """Its index in the set."""
    extents: tuple[float, float, float]
    """Bounding-box extents along x, y, z of the finished mesh, m."""
    values: Mapping[str, Any]
    """The family's own parameters (JSON-able numbers and lists; unit-free: the shape before scaling)."""

    def spec(self) -> dict[str, Any]:
        """JSON-able form (what enters a task key); :func:`shape_from_spec` reads it back."""
        return {"generator": GENERATOR_VERSION, "name": self.name, "family": self.family, "seed": self.seed,
                "index": self.index, "extents": list(self.extents), "values": _jsonable(self.values)}


def shape_name(family: str, seed: int, index: int) -> str:
    """``<family>_s<seed>_<index:05d>``."""
    return f"{family}_s{seed}_{index:05d}"


def shape_from_spec(spec: Mapping[str, Any]) -> ProceduralShape:
    """The :class:`ProceduralShape` of a :meth:`ProceduralShape.spec` dict.

    Raises
    ------
    InputError
        A spec of another generator version, or missing a key.
    """
    try:
        if spec["generator"] != GENERATOR_VERSION:
            raise InputError(f"{spec.get('name')}: procedural spec of generator {spec['generator']}, this code "
                             f"builds version {GENERATOR_VERSION}")
        return ProceduralShape(str(spec["name"]), str(spec["family"]), int(spec["seed"]), int(spec["index"]),
                               tuple(float(e) for e in spec["extents"]), dict(spec["values"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"not a procedural shape spec ({type(exc).__name__}: {exc})") from None


def draw_shapes(params: ProceduralParams) -> list[ProceduralShape]:
    """Every object of ``params``, by index."""
    return [draw_shape(params, i) for i in range(params.count)]


def draw_shape(params: ProceduralParams, index: int) -> ProceduralShape:
    """Object ``index``'s parameters: family ``families[index % len(families)]``, drawn from a generator seeded by
    ``(seed, index, family)`` only.

    Parameters
    ----------
    params : ProceduralParams
    index : int
        ``>= 0``; may exceed ``count`` (the object a larger set would have).
    """
    index = check_int("index", index, low=0)
    family = params.families[index % len(params.families)]
    rng = np.random.default_rng([params.seed, index, zlib.crc32(family.encode())])
    extents = _draw_extents(rng, params.size_range, params.max_grasp_width)
    values = _DRAW[family](rng)
    return ProceduralShape(shape_name(family, params.seed, index), family, params.seed, index, extents, values)


def _draw_extents(rng: np.random.Generator, size_range: tuple[float, float], max_width: float) -> tuple[float, ...]:
    largest = float(rng.uniform(*size_range))
    smallest = float(rng.uniform(MIN_ASPECT * largest, min(largest, max_width)))
    middle = float(rng.uniform(smallest, min(largest, max_width)))
    order = rng.permutation(3)
    return tuple(float(e) for e in np.array([largest, middle, smallest])[order])


def _draw_superquadric(rng: np.random.Generator) -> dict[str, Any]:
    e1, e2 = rng.uniform(0.25, 1.6, size=2)
    return {"e1": float(e1), "e2": float(e2)}


def _draw_blob(rng: np.random.Generator) -> dict[str, Any]:
    n = int(rng.integers(8, 33))
    return {"points": rng.standard_normal((n, 3)).tolist()}


def _draw_extrusion(rng: np.random.Generator) -> dict[str, Any]:
    n = int(rng.integers(5, 13))
    # Corners at jittered, sorted angles (gaps < pi) and positive radii: a star-shaped polygon around the origin,
    # so the fan from the origin triangulates it.
    angles = 2.0 * np.pi * (np.arange(n) + rng.uniform(0.0, 0.8, size=n)) / n
    radii = rng.uniform(0.45, 1.0, size=n)
    return {"angles": angles.tolist(), "radii": radii.tolist()}


def _draw_union(rng: np.random.Generator) -> dict[str, Any]:
    parts = []
    for k in range(int(rng.integers(2, 4))):
        kind = _PRIMITIVES[int(rng.integers(len(_PRIMITIVES)))]
        size = [1.0, 1.0, 1.0] if k == 0 else rng.uniform(0.4, 0.9, size=3).tolist()
        # Later parts are centred within 0.25 of the origin on each axis (|c| <= 0.433): inside the first part
        # whatever its kind (half-size 0.5), so the union is one body.
        centre = [0.0, 0.0, 0.0] if k == 0 else rng.uniform(-0.25, 0.25, size=3).tolist()
        quat = [1.0, 0.0, 0.0, 0.0] if k == 0 else _unit(rng.standard_normal(4)).tolist()
        parts.append({"kind": kind, "size": size, "centre": centre, "quaternion_wxyz": quat})
    return {"parts": parts}


_DRAW = {"superquadric": _draw_superquadric, "blob": _draw_blob, "extrusion": _draw_extrusion, "union": _draw_union}


def build_mesh(shape: ProceduralShape) -> trimesh.Trimesh:
    """The checked mesh of ``shape``: its family's solid scaled to ``shape.extents``, bounding box centred on the
    origin, outward winding.

    Returns
    -------
    trimesh.Trimesh
        ``vertices (v, 3) float64`` m, ``faces (f, 3) int64``; watertight, consistently wound, volume > 0.

    Raises
    ------
    InputError
        The mesh is not a closed, consistently wound solid of positive volume (a bug, named by the shape).
    """
    vertices, faces = _BUILD[shape.family](shape.values)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    vertices = (vertices - (lo + hi) / 2.0) * (np.asarray(shape.extents) / (hi - lo))
    mesh = trimesh.Trimesh(np.ascontiguousarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64),
                           process=False)
    if mesh.volume < 0:
        mesh.invert()
    check_solid(mesh, shape.name)
    return mesh


def check_solid(mesh: trimesh.Trimesh, name: str) -> None:
    """Raise :class:`InputError` naming ``name`` unless ``mesh`` is watertight, consistently wound, of positive
    volume and one body."""
    problems = []
    if not mesh.is_watertight:
        problems.append("not watertight")
    if not mesh.is_winding_consistent:
        problems.append("winding not consistent")
    if not mesh.volume > 0:
        problems.append(f"volume {mesh.volume:.3g} m^3 not > 0")
    if len(trimesh.graph.connected_components(mesh.face_adjacency, nodes=np.arange(len(mesh.faces)))) != 1:
        problems.append("not one body")
    if problems:
        raise InputError(f"{name}: procedural mesh is not a valid solid: {', '.join(problems)}")


def _superquadric(values: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    sphere = trimesh.creation.icosphere(subdivisions=_ICOSPHERE_SUBDIVISIONS)
    d = np.asarray(sphere.vertices, dtype=np.float64)
    e1, e2 = float(values["e1"]), float(values["e2"])
    ax = np.abs(d)
    # The inside-outside function is homogeneous of degree 2/e1, so the ray along d meets the surface at
    # r = F(d)^(-e1/2): a radial map of the sphere, which keeps its topology and winding.
    f = (ax[:, 0] ** (2 / e2) + ax[:, 1] ** (2 / e2)) ** (e2 / e1) + ax[:, 2] ** (2 / e1)
    return d * (f ** (-e1 / 2.0))[:, None], np.asarray(sphere.faces)


def _blob(values: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    hull = trimesh.convex.convex_hull(np.asarray(values["points"], dtype=np.float64))
    return np.asarray(hull.vertices, dtype=np.float64), np.asarray(hull.faces)


def _extrusion(values: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    angles, radii = np.asarray(values["angles"]), np.asarray(values["radii"])
    n = len(angles)
    ring = np.column_stack([radii * np.cos(angles), radii * np.sin(angles)])
    bottom = np.column_stack([ring, np.full(n, -0.5)])
    top = np.column_stack([ring, np.full(n, 0.5)])
    vertices = np.vstack([bottom, top, [[0.0, 0.0, -0.5], [0.0, 0.0, 0.5]]])
    k = np.arange(n)
    nxt = (k + 1) % n
    cb, ct = 2 * n, 2 * n + 1
    faces = np.vstack([
        np.column_stack([np.full(n, cb), nxt, k]),            # bottom fan, facing -z
        np.column_stack([np.full(n, ct), n + k, n + nxt]),    # top fan, facing +z
        np.column_stack([k, nxt, n + nxt]),                   # sides (counter-clockwise ring: outward)
        np.column_stack([k, n + nxt, n + k]),
    ])
    return vertices, faces


def _union(values: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    import manifold3d

    solid = None
    for part in values["parts"]:
        size = [float(s) for s in part["size"]]
        if part["kind"] == "box":
            body = manifold3d.Manifold.cube(size, True)
        elif part["kind"] == "cylinder":
            body = manifold3d.Manifold.cylinder(1.0, 0.5, 0.5, _CIRCLE_SEGMENTS, True).scale(size)
        else:
            body = manifold3d.Manifold.sphere(0.5, _CIRCLE_SEGMENTS).scale(size)
        R = trimesh.transformations.quaternion_matrix(part["quaternion_wxyz"])[:3, :3]
        affine = np.column_stack([R, np.asarray(part["centre"], dtype=np.float64)])
        body = body.transform(affine)
        solid = body if solid is None else solid + body
    mesh = solid.to_mesh64()
    return np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3], np.asarray(mesh.tri_verts, dtype=np.int64)


_BUILD = {"superquadric": _superquadric, "blob": _blob, "extrusion": _extrusion, "union": _union}


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    return obj
