"""The parallel-jaw gripper as data: :class:`GripperSpec` (sizes, masses, drive, pads and collision pieces in
the TCP frame; :mod:`graspgen.grippers`) and the jaw opening before an approach (:func:`jaw_opening`). How a spec
becomes a MuJoCo model: :mod:`graspgen.sim.gripper_model`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from graspgen.grippers.shapes import (
    Box,
    Linkage,
    Mesh,
    Shape,
    bounds_of,
    box_around,
    check_shapes,
    shape_dict,
)
from graspgen.validation import check, check_choice, check_instance, check_int, check_number, check_vector

__all__ = ["GripperSpec", "jaw_opening"]

#: Width error (m) at which the position actuator reaches ``force_limit``: kp = force_limit / _SATURATION_ERROR.
_SATURATION_ERROR = 0.002
#: A mesh pad's contact face may lie this far (m) from ``max_width / 2`` in the open gripper's geometry.
_FACE_TOL = 5e-4


@dataclass(frozen=True)
class GripperSpec:
    """A parallel-jaw gripper, as data. All lengths in metres, in the TCP frame (:mod:`graspgen.grippers`).

    Geometry comes in one of two ways (or mixed per body): boxes given by sizes (``pad_size``, ``finger_size``,
    ``palm_boxes``), or collision pieces per body (``palm_geoms``, ``finger_geoms``, ``pad_geom``), which replace the
    boxes of their body in the MuJoCo model. The sizes stay meaningful either way: ``pad_size`` is the contact area
    (the grasp sampler and the contact model use it) and ``finger_size`` / ``palm_boxes`` the bounding boxes
    (inertia, drawings).
    """

    name: str
    """Registry name, e.g. ``"robotiq_2f85"``."""
    min_width: float
    """Smallest pad separation (m): distance between the two pads' contact faces when fully closed."""
    max_width: float
    """Largest pad separation (m) when fully open (the stroke is ``max_width - min_width``)."""
    pad_size: tuple[float, float, float]
    """Full extents (m) of each contact pad box: (thickness along x, width along y, length along z). The pad's
    contact face is its inner x face; pads are centred at y = 0, z = 0 of the TCP frame. With a ``pad_geom``, the
    contact face's width and length (and the geom's thickness)."""
    pad_friction: tuple[float, float, float]
    """MuJoCo friction of the pads: (sliding [-], torsional [m], rolling [m]). With ``build_gripper(friction="pad")``
    the sliding coefficient governs pad contacts; with the default ``friction="object"`` the object's does. The
    torsional coefficient of a pad's contact with an object is derived, not taken from here: ``mu`` x
    :func:`~graspgen.sim.gripper_model.pad_torsion_arm`, written on the object geoms by
    :func:`~graspgen.sim.gripper_model.attach_gripper` (:mod:`graspgen.sim.gripper_model`); the torsional and
    rolling entries are the floor of the pads' other contacts (support, ground, objects added after the gripper)."""
    finger_size: tuple[float, float, float]
    """Full extents (m) of each finger link box: (thickness along x, width along y, length along z). The box sits
    directly behind (outside) its pad and its tip is flush with the pad's tip (z = pad length / 2). With
    ``finger_geoms``, the extents of the finger's bounding box (pad included)."""
    palm_boxes: tuple[Box, ...]
    """Collision boxes of the palm / hand body, fixed in the TCP frame (behind the fingers, at negative z). With
    ``palm_geoms`` (which then collide instead), their bounding box; left empty, it is filled in."""
    tcp_offset: float
    """Distance (m) from the hand base (flange / hand frame) to the TCP along z; the base is at z = -tcp_offset."""
    force_limit: float
    """Maximum grip force (N): the jaw actuator's force saturates here, so each pad presses with at most this."""
    finger_mass: float
    """Mass (kg) of one jaw (finger link + pad)."""
    body_mass: float
    """Mass (kg) of the palm / hand body (everything but the two jaws)."""
    closing_speed: float
    """Rate of change of the pad separation (m/s) when the actuator is saturated and nothing is in the way."""
    pad_condim: int = 4
    """MuJoCo contact dimensionality of the pads: 3 (sliding), 4 (+ torsional) or 6 (+ rolling)."""
    source: str = ""
    """Where the numbers come from (data sheets, reference models) and what was approximated."""
    palm_geoms: tuple[Shape, ...] = ()
    """Collision pieces of the palm / hand body (TCP frame); empty: the ``palm_boxes`` collide."""
    finger_geoms: tuple[Shape, ...] = ()
    """Collision pieces of the right finger link (+x) without its pad, in the TCP frame with the jaws open (width
    ``max_width``); the left finger is the same turned 180 degrees about z. Empty: one box of ``finger_size``."""
    pad_geom: Shape | None = None
    """The right pad's collision piece, in the TCP frame with the jaws open: its contact face (its smallest x) lies
    at ``x = max_width / 2`` (within 0.5 mm; the model puts it there exactly) and it straddles y = 0 and z = 0.
    None: a box of ``pad_size``."""
    linkage: Linkage | None = None
    """The finger linkage (:class:`Linkage`): the fingers then follow its path (the pads rise or sink along z as
    they close) and its links collide too. None: the jaws slide along x only."""
    file: str = field(default="", compare=False)
    """The gripper file this spec was read from ('' for one made in Python)."""
    model_files: tuple[str, ...] = field(default=(), compare=False)
    """The files a spec derived from a robot model was read from besides ``file`` (the URDF / MJCF and its meshes,
    :mod:`graspgen.grippers.model_ref`); their bytes go into the content keys (``gripper_files``)."""

    def __post_init__(self) -> None:
        check_instance("name", self.name, str, what="string")
        check("name", bool(self.name.strip()), "be a non-empty string", self.name)
        object.__setattr__(self, "min_width", check_number("min_width", self.min_width, low=0.0))
        object.__setattr__(self, "max_width", check_number("max_width", self.max_width, low=self.min_width,
                                                           low_open=True))
        for key in ("tcp_offset", "force_limit", "finger_mass", "body_mass", "closing_speed"):
            object.__setattr__(self, key, check_number(key, getattr(self, key), low=0.0, low_open=True))
        object.__setattr__(self, "pad_size", check_vector("pad_size", self.pad_size, 3, low=0.0, low_open=True))
        object.__setattr__(self, "pad_friction", check_vector("pad_friction", self.pad_friction, 3, low=0.0))
        object.__setattr__(self, "finger_size", check_vector("finger_size", self.finger_size, 3, low=0.0,
                                                             low_open=True))
        check("pad_friction", self.pad_friction[0] > 0, "have a sliding coefficient > 0", self.pad_friction)
        check("finger_size", self.finger_size[2] >= self.pad_size[2],
              f"be at least as long as its pad (length >= pad_size z = {self.pad_size[2]} m)", self.finger_size)
        check_choice("pad_condim", check_int("pad_condim", self.pad_condim), (1, 3, 4, 6))
        palm_geoms = check_shapes("palm_geoms", self.palm_geoms)
        object.__setattr__(self, "palm_geoms", palm_geoms)
        boxes = tuple(self.palm_boxes)
        if not boxes and palm_geoms:
            boxes = (box_around(palm_geoms),)
        check("palm_boxes", bool(boxes) and all(isinstance(b, Box) for b in boxes), "be a non-empty sequence of Box",
              self.palm_boxes)
        object.__setattr__(self, "palm_boxes", boxes)
        fingers = check_shapes("finger_geoms", self.finger_geoms)
        object.__setattr__(self, "finger_geoms", fingers)
        if fingers:
            check("finger_geoms", bool(bounds_of(fingers)[0][0] >= -1e-9),
                  "describe the right finger (+x): every piece at x >= 0", f"lowest x {bounds_of(fingers)[0][0]:.4g}")
        pad = self.pad_geom
        if pad is not None:
            check_instance("pad_geom", pad, (Box, Mesh), what="Box, a Mesh or None")
            lo, hi = pad.bounds
            half = self.max_width / 2.0
            check("pad_geom", abs(lo[0] - half) <= _FACE_TOL,
                  f"have its contact face (its smallest x) at max_width / 2 = {half:.4g} m (within 0.5 mm; give it "
                  "with the jaws open)", f"smallest x {lo[0]:.4g}")
            check("pad_geom", lo[1] <= 0.0 <= hi[1] and lo[2] <= 0.0 <= hi[2],
                  "straddle the TCP (y = 0 and z = 0 within its extents)",
                  f"y {lo[1]:.4g}..{hi[1]:.4g}, z {lo[2]:.4g}..{hi[2]:.4g}")
        if self.linkage is not None:
            check_instance("linkage", self.linkage, Linkage, what="Linkage or None")
            self.linkage.couplings(self.min_width, self.max_width)  # reachable and fitted, or SettingsError
        check_instance("source", self.source, str, what="string")
        check_instance("file", self.file, str, what="string")
        object.__setattr__(self, "model_files", tuple(str(f) for f in self.model_files))

    @property
    def stroke(self) -> float:
        """``max_width - min_width`` (m)."""
        return self.max_width - self.min_width

    @property
    def kp(self) -> float:
        """Position gain (N/m) of the width actuator: saturates at ``force_limit`` for 2 mm of width error."""
        return self.force_limit / _SATURATION_ERROR

    @property
    def jaw_damping(self) -> float:
        """Viscous damping (N s/m) of each jaw joint, so that a saturated actuator closes at ``closing_speed``."""
        return 2.0 * self.force_limit / self.closing_speed

    @property
    def uses_meshes(self) -> bool:
        """Whether any body collides with :class:`Mesh` pieces (not only boxes)."""
        return any(isinstance(s, Mesh) for s in self.pieces)

    @property
    def pieces(self) -> tuple[Shape, ...]:
        """Every collision piece given as a shape: palm, finger, pad and linkage pieces (not the size boxes)."""
        link = () if self.linkage is None else (*self.linkage.driver_geoms, *self.linkage.follower_geoms)
        return (*self.palm_geoms, *self.finger_geoms, *(() if self.pad_geom is None else (self.pad_geom,)), *link)

    def pad_rise(self, width) -> np.ndarray:
        """Displacement (m) of the pads along z (+: towards the object) at pad separation ``width`` (m, scalar or
        array) from where they are when open: 0 without a linkage."""
        shift = (np.asarray(width, dtype=float) - self.max_width) / 2.0
        return np.zeros_like(shift) if self.linkage is None else self.linkage.rise(shift)

    def to_dict(self) -> dict:
        """Plain-data view (for logs / metadata files); also the gripper file format: ``write_gripper`` writes it and
        :func:`read_gripper` reads it back (meshes as their vertices). ``file`` is left out."""
        out = {}
        for f in fields(self):
            if f.name in ("file", "model_files"):
                continue
            value = getattr(self, f.name)
            if f.name in ("palm_boxes", "palm_geoms", "finger_geoms"):
                value = [shape_dict(s) for s in value]
            elif f.name == "pad_geom":
                value = None if value is None else shape_dict(value)
            elif f.name == "linkage":
                value = None if value is None else {
                    "pivot": list(value.pivot), "crank": list(value.crank),
                    "follower_pivot": list(value.follower_pivot),
                    "driver_geoms": [shape_dict(s) for s in value.driver_geoms],
                    "follower_geoms": [shape_dict(s) for s in value.follower_geoms],
                    "driver_mass": value.driver_mass, "follower_mass": value.follower_mass}
            elif isinstance(value, tuple):
                value = list(value)
            out[f.name] = value
        return out


def jaw_opening(width, width_margin: float, min_width: float, max_width: float) -> np.ndarray:
    """Pad separation (m) the jaws open to before the approach, for contact width(s) ``width`` (m, scalar or
    ``(n,)``): ``width + width_margin`` clipped to ``[min_width, max_width]``. The pre-filter and the rollout both
    use it, so the jaws checked for collisions are the jaws simulated."""
    return np.clip(np.asarray(width, dtype=float) + width_margin, min_width, max_width)
