"""Settings of the ``scenes`` stage (config section ``scenes``): which objects, how they are placed, settled and
seen (:class:`ScenesParams` and its camera and depth-noise sections; :func:`graspgen.workflows.scenes.make_scene`
builds a scene from them)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from typing import Any, Literal

import numpy as np

from graspgen.sim.camera import intrinsics_from_fov
from graspgen.sim.settle import SettleParams
from graspgen.sim.support import SupportParams
from graspgen.validation import (
    check,
    check_bool,
    check_choice,
    check_instance,
    check_int,
    check_number,
    check_range,
)

__all__ = ["CameraParams", "DepthNoiseParams", "ScenesParams"]


def _pair(name: str, value: Any, check_one: Callable[..., Any]) -> tuple[Any, Any]:
    """(lo, hi) of a setting that is one value or a ``[lo, hi]`` pair, each checked by ``check_one``."""
    if isinstance(value, (tuple, list)):
        check(name, len(value) == 2, "be a number or [lo, hi]", value)
        return check_one(f"{name}[0]", value[0]), check_one(f"{name}[1]", value[1])
    one = check_one(name, value)
    return one, one


@dataclasses.dataclass(frozen=True)
class DepthNoiseParams:
    """Optional depth sensor noise, stored as ``images/depth_noisy`` next to the clean depth."""

    enabled: bool = False
    """Store a noisy copy of every depth image (drawn from the task's rng)."""
    sigma: float = 0.001
    """Standard deviation of the Gaussian depth noise at zero range, m."""
    sigma_quadratic: float = 0.0025
    """Growth of the standard deviation with range: sigma + sigma_quadratic * z^2, 1/m (0.0025 gives 1 mm more at
    0.63 m; typical of structured-light sensors)."""
    dropout: float = 0.01
    """Probability that a pixel returns no depth (set to 0)."""

    def __post_init__(self) -> None:
        check_bool("enabled", self.enabled)
        check_number("sigma", self.sigma, low=0.0)
        check_number("sigma_quadratic", self.sigma_quadratic, low=0.0)
        check_number("dropout", self.dropout, low=0.0, high=1.0)


@dataclasses.dataclass(frozen=True)
class CameraParams:
    """Camera views of each scene (config section ``scenes.cameras``). Angles in rad, lengths in m."""

    num_views: int = 3
    """Views per scene."""
    distance: tuple[float, float] = (0.55, 0.8)
    """Range of the camera's distance to the scene centre (the objects' bounding-box centre), m."""
    elevation: tuple[float, float] = (0.6, 1.2)
    """Range of the angle above the table plane, rad (0.6-1.2 is about 35-70 degrees; pi/2 looks straight down)."""
    azimuth: tuple[float, float] = (-math.pi, math.pi)
    """Range of the angle about the world z axis, from +x towards +y, rad."""
    roll: tuple[float, float] = (0.0, 0.0)
    """Range of the in-plane rotation about the optical axis, rad (0: world up is image up)."""
    width: int = 320
    """Image width, pixels."""
    height: int = 240
    """Image height, pixels."""
    fov_y: float = 0.785
    """Vertical field of view, rad (0.785 = 45 degrees); square pixels, centred principal point. Ignored when
    fx, fy, cx, cy are given."""
    fx: float | None = None
    """Focal length along x, pixels; give all of fx, fy, cx, cy or none."""
    fy: float | None = None
    """Focal length along y, pixels."""
    cx: float | None = None
    """Principal point column, pixels (pixel centres at integer coordinates)."""
    cy: float | None = None
    """Principal point row, pixels."""
    render: bool = True
    """Render images and clouds. False makes scenes without images (no OpenGL needed); camera poses are still
    sampled and stored."""
    clouds: Literal["world", "camera", "both", "none"] = "world"
    """Which point-cloud frames to store (object and support points of every view; the depth images keep the rest). A
    frame not stored is one call away (:meth:`SceneRecord.cloud`); clouds are most of a shard, so ``none`` keeps shards
    small."""
    depth_noise: DepthNoiseParams = dataclasses.field(default_factory=DepthNoiseParams)
    """Optional depth noise (off by default)."""

    def __post_init__(self) -> None:
        check_int("num_views", self.num_views, low=0)
        check_range("distance", self.distance, low=1e-3)
        check_range("elevation", self.elevation, low=-math.pi / 2, high=math.pi / 2)
        check_range("azimuth", self.azimuth, low=-4 * math.pi, high=4 * math.pi)
        check_range("roll", self.roll, low=-math.pi, high=math.pi)
        check_int("width", self.width, low=8, high=8192)
        check_int("height", self.height, low=8, high=8192)
        check_number("fov_y", self.fov_y, low=0.0, high=math.pi, low_open=True, high_open=True)
        given = [v is not None for v in (self.fx, self.fy, self.cx, self.cy)]
        check("fx", all(given) or not any(given), "be given together with fy, cx, cy (or none of them)", self.fx)
        if all(given):
            check_number("fx", self.fx, low=0.0, low_open=True)
            check_number("fy", self.fy, low=0.0, low_open=True)
            check_number("cx", self.cx)
            check_number("cy", self.cy)
        check_bool("render", self.render)
        check_choice("clouds", self.clouds, ("world", "camera", "both", "none"))
        check_instance("depth_noise", self.depth_noise, DepthNoiseParams)

    def intrinsics(self) -> np.ndarray:
        """(3, 3) K from fx, fy, cx, cy when given, else from ``fov_y``."""
        if self.fx is not None:
            return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])
        return intrinsics_from_fov(self.width, self.height, self.fov_y)


@dataclasses.dataclass(frozen=True)
class ScenesParams:
    """Settings of the ``scenes`` stage (config section ``scenes``)."""

    num_scenes: int = 4
    """Number of scenes (tasks ``scene_000000`` ...)."""
    objects_per_scene: int | tuple[int, int] = 3
    """Objects per scene: a number, or [min, max] drawn uniformly per scene. Ignored with ``choice: fixed``."""
    choice: Literal["random", "fixed"] = "random"
    """``random``: draw the objects of each scene from ``objects`` (or the library); ``fixed``: every scene holds
    exactly the objects listed in ``objects``, in that order."""
    objects: tuple[str, ...] = ()
    """Object names (objects-stage task ids) to use; empty means every object of the library."""
    weights: dict[str, float] = dataclasses.field(default_factory=dict)
    """Relative probability of drawing each object by name (names not listed weigh 1); random choice only."""
    replace: bool = False
    """Allow one object to appear more than once in a scene (random choice)."""
    placement: Literal["uniform", "gaussian"] = "uniform"
    """How x/y positions are drawn in ``support.area``: uniform, or Gaussian around its centre (clipped to it)."""
    placement_sigma: float = 0.08
    """Standard deviation of Gaussian placement, m."""
    gap: float = 0.005
    """Smallest clearance between two objects' footprints, and to the support's edges and walls, at placement, m."""
    friction: float | tuple[float, float] = 0.8
    """Sliding friction of each object: a value, or [lo, hi] drawn uniformly per object. An object with its own friction
    (its manifest row's ``friction``) keeps it; its draw is still made, so the other objects' draws do not move."""
    max_tries: int = 100
    """Placements tried per object before it is left out of the scene."""
    max_scene_tries: int = 10
    """Scene draws before the task fails (a draw fails when too few objects fit or, with ``on_unstable: retry``,
    when one is unstable)."""
    on_unstable: Literal["remove", "retry"] = "remove"
    """What to do with objects that fall, tip or keep moving while settling: remove them and settle the rest
    again, or draw the scene again."""
    max_tilt: float = 0.35
    """An object whose up axis turns by more than this while settling has tipped over, rad (0.35 = 20 degrees)."""
    support: SupportParams = dataclasses.field(default_factory=SupportParams)
    """What the objects stand on."""
    settle: SettleParams = dataclasses.field(default_factory=SettleParams)
    """When a scene is at rest."""
    cameras: CameraParams = dataclasses.field(default_factory=CameraParams)
    """Camera views and rendering."""

    def __post_init__(self) -> None:
        check_int("num_scenes", self.num_scenes, low=0)
        lo, hi = _pair("objects_per_scene", self.objects_per_scene, check_int)
        check(
            "objects_per_scene",
            1 <= lo <= hi,
            "be a number >= 1 or [min, max] with 1 <= min <= max",
            self.objects_per_scene,
        )
        check_choice("choice", self.choice, ("random", "fixed"))
        names = not isinstance(self.objects, str) and all(isinstance(n, str) for n in self.objects)
        check("objects", names, "be a list of object names", self.objects)
        check_bool("replace", self.replace)
        if self.choice == "fixed":
            check(
                "objects", len(self.objects) > 0, "list the objects of every scene when choice is fixed", self.objects
            )
        if not self.replace and self.choice == "random" and self.objects:
            check(
                "objects_per_scene",
                hi <= len(set(self.objects)),
                f"be at most the {len(set(self.objects))} listed objects (or set replace: true)",
                self.objects_per_scene,
            )
        check_instance("weights", self.weights, Mapping, what="mapping of object names to weights")
        for name, w in self.weights.items():
            check_number(f"weights.{name}", w, low=0.0)
        check_choice("placement", self.placement, ("uniform", "gaussian"))
        check_number("placement_sigma", self.placement_sigma, low=0.0, low_open=True)
        check_number("gap", self.gap, low=0.0, high=0.1)
        flo, fhi = _pair("friction", self.friction, check_number)
        check("friction", 0 < flo <= fhi, "be > 0 (or [lo, hi] with 0 < lo <= hi)", self.friction)
        check_int("max_tries", self.max_tries, low=1)
        check_int("max_scene_tries", self.max_scene_tries, low=1)
        check_choice("on_unstable", self.on_unstable, ("remove", "retry"))
        check_number("max_tilt", self.max_tilt, low=0.0, high=math.pi, low_open=True)
        check_instance("support", self.support, SupportParams)
        check_instance("settle", self.settle, SettleParams)
        check_instance("cameras", self.cameras, CameraParams)

    @property
    def count_range(self) -> tuple[int, int]:
        """(min, max) objects per scene."""
        n = self.objects_per_scene
        return (n, n) if isinstance(n, int) else (int(n[0]), int(n[1]))

    @property
    def friction_range(self) -> tuple[float, float]:
        """(lo, hi) of the per-object friction."""
        f = self.friction
        return (float(f), float(f)) if isinstance(f, (int, float)) else (float(f[0]), float(f[1]))
