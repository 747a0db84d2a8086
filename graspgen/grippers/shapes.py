"""The collision shapes of a gripper and its finger linkage, as data: :class:`Box`, convex :class:`Mesh`
(``Shape`` is either) and the 4-bar :class:`Linkage` of the Robotiq 2F-85, all in the gripper's TCP frame
(:mod:`graspgen.grippers`) with the jaws open. No MuJoCo here: :mod:`graspgen.sim.gripper_model` turns them into
geoms and joints.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from graspgen.validation import check, check_number, check_vector

__all__ = ["Box", "Mesh", "Shape", "Linkage", "bounds_of", "box_around", "check_shapes", "shape_dict", "short_repr"]


@dataclass(frozen=True)
class Box:
    """An axis-aligned collision box in the gripper's TCP frame (used for the palm / hand body)."""

    size: tuple[float, float, float]
    """Full extents (m) along TCP x (closing), y, z (approach). Not MuJoCo's half-sizes."""
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Centre of the box (m) in the TCP frame; the palm lies at negative z (behind the pads)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "size", check_vector("Box.size", self.size, 3, low=0.0, low_open=True))
        object.__setattr__(self, "pos", check_vector("Box.pos", self.pos, 3))

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lowest corner, highest corner) (m), each (3,)."""
        return np.subtract(self.pos, np.divide(self.size, 2)), np.add(self.pos, np.divide(self.size, 2))


@dataclass(frozen=True)
class Mesh:
    """A convex collision piece given by its vertices, in the gripper's TCP frame (MuJoCo collides with the convex
    hull of a mesh, so only the hull's vertices matter)."""

    vertices: tuple[tuple[float, float, float], ...]
    """Vertices (m), at least 4 and not all in one plane."""
    file: str = field(default="", compare=False)
    """The mesh file it was read from ('' when given by its vertices); for messages and :func:`gripper_files`."""

    def __post_init__(self) -> None:
        try:
            v = np.asarray(self.vertices, dtype=float)
        except (TypeError, ValueError):
            v = None
        check("Mesh.vertices", v is not None and v.ndim == 2 and v.shape[1:] == (3,) and len(v) >= 4
              and bool(np.isfinite(v).all()), "be 4 or more finite (x, y, z) points", short_repr(self.vertices))
        spread = np.linalg.svd(v - v.mean(axis=0), compute_uv=False)
        check("Mesh.vertices", spread[2] > 1e-9 * max(spread[0], 1e-12) and spread[2] > 1e-9,
              "span a volume (not all in one plane)", short_repr(self.vertices))
        object.__setattr__(self, "vertices", tuple(tuple(float(x) for x in row) for row in v))

    @property
    def array(self) -> np.ndarray:
        """The vertices as an (n, 3) float64 array (a copy)."""
        return np.array(self.vertices, dtype=float)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lowest corner, highest corner) (m) of the axis-aligned bounding box, each (3,)."""
        v = self.array
        return v.min(axis=0), v.max(axis=0)


Shape = Box | Mesh
"""A collision geom of a gripper body: a :class:`Box` or a convex :class:`Mesh`."""


def short_repr(value: Any) -> str:
    """``repr(value)``, cut to 80 characters (for messages)."""
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def bounds_of(shapes) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (3,) of the axis-aligned box around ``shapes``."""
    los, his = zip(*(s.bounds for s in shapes))
    return np.min(los, axis=0), np.max(his, axis=0)


def box_around(shapes) -> Box:
    """The axis-aligned :class:`Box` around ``shapes``."""
    lo, hi = bounds_of(shapes)
    return Box(size=tuple(hi - lo), pos=tuple((lo + hi) / 2.0))


def check_shapes(name: str, value: Any) -> tuple[Shape, ...]:
    """``value`` as a tuple of :class:`Box` / :class:`Mesh`; :class:`SettingsError` naming ``name`` otherwise."""
    try:
        shapes = tuple(value)
    except TypeError:
        shapes = None
    check(name, shapes is not None and all(isinstance(s, (Box, Mesh)) for s in shapes),
          "be a sequence of Box or Mesh", short_repr(value))
    return shapes


#: Largest error allowed of the quartics that couple a linkage's joints to the jaw slide: pad height (m) and link
#: angle (rad) over the stroke.
_LINKAGE_FIT_TOL = (5e-5, 2e-3)


@dataclass(frozen=True)
class Linkage:
    """A parallelogram (4-bar) finger linkage, as on the Robotiq 2F-85: two links per finger, the *driver* and the
    *follower*, turn about pivots fixed in the palm, and the finger they carry (the coupler: the finger link and its
    pad, :attr:`GripperSpec.finger_geoms` and :attr:`GripperSpec.pad_geom`) keeps its orientation, so every point of
    it, the pad included, moves on a circle of the crank's radius: the pads stay parallel and rise or sink along z
    as they close. Given for the right finger (+x), in the gripper file's frame, with the jaws open; the left finger
    is the same turned 180 degrees about z. All points are (x, z) pairs (m) in the closing/approach plane y = 0.
    """

    pivot: tuple[float, float]
    """(x, z) (m) of the driver link's pivot on the palm (TCP frame)."""
    crank: tuple[float, float]
    """(x, z) (m) from the driver's pivot to its joint on the finger, jaws open; the follower's crank is the same
    (a parallelogram), so its joint on the finger is ``follower_pivot + crank``."""
    follower_pivot: tuple[float, float]
    """(x, z) (m) of the follower link's pivot on the palm (TCP frame)."""
    driver_geoms: tuple[Shape, ...]
    """Collision pieces of the right driver link, in the TCP frame with the jaws open."""
    follower_geoms: tuple[Shape, ...] = ()
    """Collision pieces of the right follower link, in the TCP frame with the jaws open (may be empty)."""
    driver_mass: float = 0.03
    """Mass (kg) of one driver link."""
    follower_mass: float = 0.03
    """Mass (kg) of one follower link."""

    def __post_init__(self) -> None:
        for key in ("pivot", "crank", "follower_pivot"):
            object.__setattr__(self, key, check_vector(f"linkage.{key}", getattr(self, key), 2))
        check("linkage.crank", float(np.hypot(*self.crank)) > 1e-4, "be longer than 0.1 mm", self.crank)
        object.__setattr__(self, "driver_geoms", check_shapes("linkage.driver_geoms", self.driver_geoms))
        check("linkage.driver_geoms", bool(self.driver_geoms), "hold at least one piece", self.driver_geoms)
        object.__setattr__(self, "follower_geoms", check_shapes("linkage.follower_geoms", self.follower_geoms))
        for key in ("driver_mass", "follower_mass"):
            object.__setattr__(self, key, check_number(f"linkage.{key}", getattr(self, key), low=0.0,
                                                       low_open=True))

    @property
    def radius(self) -> float:
        """Crank length (m): the radius of every finger point's path."""
        return float(np.hypot(*self.crank))

    def angle(self, shift) -> np.ndarray:
        """Closing rotation (rad) of the links when the pad has moved ``shift`` (m, scalar or array; <= 0 closing)
        along x from the open position: the crank's angle from +x grows as the finger moves in."""
        cx, cz = self.crank
        return np.arccos(np.clip((cx + np.asarray(shift, dtype=float)) / self.radius, -1.0, 1.0)) - np.arctan2(cz, cx)

    def rise(self, shift) -> np.ndarray:
        """The pad's displacement (m) along z (+: towards the object) when it has moved ``shift`` (m) along x."""
        cx, cz = self.crank
        phi = np.arctan2(cz, cx) + self.angle(shift)
        return self.radius * np.sin(phi) - cz

    def couplings(self, min_width: float, max_width: float) -> dict[str, tuple[float, ...]]:
        """Quartic coefficients ``(a0, .., a4)`` of each joint driven by the jaw slide ``q`` (the pad face's x), in
        MuJoCo's joint-equality form ``q1 - q1_ref = sum a_k (q - max_width / 2)^k``: ``lift`` (the pad's z, m),
        ``driver`` and ``follower`` (the links' angle, rad). Least squares on 64 Chebyshev nodes of the stroke;
        :class:`SettingsError` when the path is not reachable or a fit is off by more than 0.05 mm / 2 mrad."""
        lo = (min_width - max_width) / 2.0
        check("linkage.crank", (self.crank[0] + lo) / self.radius >= -1.0,
              f"reach the closed pads: its x ({self.crank[0]:.4g} m) plus the closing travel must stay within the "
              f"crank's radius ({self.radius:.4g} m)", self.crank)
        nodes = lo / 2.0 * (1.0 - np.cos(np.linspace(0.0, np.pi, 64)))
        fine = np.linspace(lo, 0.0, 1001)
        out = {}
        for key, fn, tol in (("lift", self.rise, _LINKAGE_FIT_TOL[0]), ("driver", self.angle, _LINKAGE_FIT_TOL[1])):
            coef = np.polynomial.polynomial.polyfit(nodes, fn(nodes) - fn(0.0), 4)
            err = float(np.abs(np.polynomial.polynomial.polyval(fine, coef) - (fn(fine) - fn(0.0))).max())
            check("linkage", err <= tol, f"have a path a quartic follows over the stroke (the {key} fit is off by "
                  f"{err:.3g}, more than {tol:g})", self.crank)
            out[key] = tuple(float(c) for c in coef)
        out["follower"] = out["driver"]
        return out


def shape_dict(shape: Shape) -> dict:
    """The gripper-file entry of ``shape``: ``{size, pos}`` for a box, ``{vertices}`` for a mesh."""
    if isinstance(shape, Box):
        return {"size": list(shape.size), "pos": list(shape.pos)}
    return {"vertices": [list(v) for v in shape.vertices]}
