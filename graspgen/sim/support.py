"""What the objects of a scene stand on: the table, bin or shelf settings, its static boxes and the region an
object's footprint may occupy.

World frame: z up, metres. **The support's top surface is the plane z = 0**: the table top (and the floor of a
bin) is at z = 0, the table body is a box below it, and the ground plane lies at z = -``SupportParams.height``.
The boxes are named ``support/table``, ``support/wall_px|nx|py|ny`` (bin), ``support/shelf_board`` and
``support/shelf_post_px|nx`` (shelf); the ground plane is ``ground`` (:func:`graspgen.sim.scene_model.build_scene_spec`
makes the MuJoCo geoms).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import numpy as np

from graspgen.validation import check, check_choice, check_number, check_vector

__all__ = ["GROUND_NAME", "SUPPORT_PREFIX", "SupportBox", "SupportParams", "free_region", "support_boxes"]

SUPPORT_PREFIX = "support/"
"""Name prefix of the support's box geoms."""
GROUND_NAME = "ground"
"""Name of the ground plane geom."""


@dataclasses.dataclass(frozen=True)
class SupportParams:
    """What the objects stand on (config section ``scenes.support``). Lengths in m; the top surface is z = 0."""

    kind: Literal["table", "bin", "shelf"] = "table"
    """``table``: a table top; ``bin``: the table plus four walls around the placement area; ``shelf``: the table
    plus a board above it, carried by two posts at the table's x ends."""
    size: tuple[float, float] = (0.6, 0.6)
    """Table top extents along x and y, m."""
    height: float = 0.75
    """Table height, m: the ground plane is at z = -height."""
    area: tuple[float, float] = (0.3, 0.3)
    """Placement area (x, y extents, m), centred on the table: object positions are drawn in it. For a bin, the
    inner size of the bin."""
    wall_height: float = 0.08
    """Bin wall height above the table top, m."""
    wall_thickness: float = 0.01
    """Bin wall (and shelf post) thickness, m."""
    shelf_height: float = 0.3
    """Clear height between the table top and the underside of the shelf board, m."""
    shelf_thickness: float = 0.02
    """Shelf board thickness, m."""
    friction: float = 0.8
    """Sliding friction of the support and the ground (MuJoCo uses the larger of the two geoms' values)."""

    def __post_init__(self) -> None:
        check_choice("kind", self.kind, ("table", "bin", "shelf"))
        check_vector("size", self.size, 2, low=0.0, low_open=True)
        check_number("height", self.height, low=0.0, low_open=True)
        check_vector("area", self.area, 2, low=0.0, low_open=True)
        check("area", all(a <= s for a, s in zip(self.area, self.size)), f"fit on the table top {self.size}", self.area)
        check_number("wall_height", self.wall_height, low=0.0, low_open=True)
        check_number("wall_thickness", self.wall_thickness, low=0.0, low_open=True)
        check_number("shelf_height", self.shelf_height, low=0.0, low_open=True)
        check_number("shelf_thickness", self.shelf_thickness, low=0.0, low_open=True)
        check_number("friction", self.friction, low=0.0, low_open=True)
        if self.kind == "bin":
            outer = [a + 2 * self.wall_thickness for a in self.area]
            check(
                "area", all(o <= s for o, s in zip(outer, self.size)), "plus the bin walls fit on the table", self.area
            )
        if self.kind == "shelf":
            inner = self.size[0] - 2 * self.wall_thickness
            check("area", self.area[0] <= inner, f"fit between the shelf posts ({inner:.3f} m along x)", self.area)


@dataclasses.dataclass(frozen=True)
class SupportBox:
    """One static box of the support."""

    name: str
    """Geom name, ``support/<what>``."""
    center: tuple[float, float, float]
    """Box centre in the world frame, m."""
    size: tuple[float, float, float]
    """Full extents along world x, y, z, m (not MuJoCo's half sizes)."""


def support_boxes(support: SupportParams) -> list[SupportBox]:
    """The static boxes of ``support`` (axis-aligned, world frame); the ground plane is not included."""
    sx, sy = support.size
    h = support.height
    boxes = [SupportBox(f"{SUPPORT_PREFIX}table", (0.0, 0.0, -h / 2), (sx, sy, h))]
    t = support.wall_thickness
    if support.kind == "bin":
        ax, ay = support.area
        wh = support.wall_height
        boxes += [
            SupportBox(f"{SUPPORT_PREFIX}wall_px", (ax / 2 + t / 2, 0.0, wh / 2), (t, ay + 2 * t, wh)),
            SupportBox(f"{SUPPORT_PREFIX}wall_nx", (-ax / 2 - t / 2, 0.0, wh / 2), (t, ay + 2 * t, wh)),
            SupportBox(f"{SUPPORT_PREFIX}wall_py", (0.0, ay / 2 + t / 2, wh / 2), (ax, t, wh)),
            SupportBox(f"{SUPPORT_PREFIX}wall_ny", (0.0, -ay / 2 - t / 2, wh / 2), (ax, t, wh)),
        ]
    elif support.kind == "shelf":
        sh, st = support.shelf_height, support.shelf_thickness
        boxes += [
            SupportBox(f"{SUPPORT_PREFIX}shelf_board", (0.0, 0.0, sh + st / 2), (sx, sy, st)),
            SupportBox(f"{SUPPORT_PREFIX}shelf_post_px", (sx / 2 - t / 2, 0.0, sh / 2), (t, sy, sh)),
            SupportBox(f"{SUPPORT_PREFIX}shelf_post_nx", (-sx / 2 + t / 2, 0.0, sh / 2), (t, sy, sh)),
        ]
    return boxes


def free_region(support: SupportParams) -> tuple[np.ndarray, np.ndarray, float]:
    """Where an object's footprint may lie on the support: the x/y box ``[lo, hi]`` and the highest z it may reach.

    Table: the table top, no height limit. Bin: inside the walls. Shelf: between the posts, below the board.

    Returns
    -------
    lo, hi : (2,) float
        Corners of the allowed footprint region, m.
    z_max : float
        Highest allowed point of an object, m (``inf`` when unbounded).
    """
    half = np.asarray(support.size, dtype=float) / 2
    if support.kind == "bin":
        half = np.asarray(support.area, dtype=float) / 2
        return -half, half, math.inf
    if support.kind == "shelf":
        half = half - np.array([support.wall_thickness, 0.0])
        return -half, half, support.shelf_height
    return -half, half, math.inf
