"""Read and write grasp files in the ACRONYM format (Eppner et al., 2021; ``NVlabs/acronym``).

One HDF5 file per object: ``grasps/transforms`` (n, 4, 4) hand-base poses in the mesh frame (m),
``grasps/qualities/...`` per-grasp labels (``flex/object_in_gripper``; ours ``graspgen/firm_hold``), ``object/*``
(mesh file, scale, mass properties) and ``gripper/{type,configuration}``. ACRONYM's hand base has our TCP axes; the
TCP sits ``tcp_offset`` along its +z (:func:`tcp_from_hand_base`, :func:`hand_base_from_tcp`). The full layout and
what the two exports of :mod:`graspgen.io.acronym_export` write: docs/format.md, "ACRONYM files".
"""

from __future__ import annotations

import dataclasses
import io
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from graspgen.errors import InputError, SettingsError
from graspgen.grippers import ACRONYM_GRIPPER, load_gripper
from graspgen.validation import check_number, check_transforms

__all__ = [
    "SUCCESS_KEY",
    "GRIPPER_ALIASES",
    "AcronymGrasps",
    "tcp_from_hand_base",
    "hand_base_from_tcp",
    "gripper_name",
    "read_acronym",
    "write_acronym",
    "obj_text",
    "FLEX_MOTION",
    "FIRM_KEY",
    "FIRM_COLUMNS",
]

SUCCESS_KEY = "flex/object_in_gripper"
"""Key (below ``grasps/qualities``) of ACRONYM's success label."""

GRIPPER_ALIASES: dict[str, str] = {"franka_panda": "panda"}
"""``gripper/type`` names that are not ours -> our gripper registry names (:data:`graspgen.grippers.GRIPPERS`):
``franka_panda``, written by our exports before they wrote ACRONYM's own ``panda``."""

_FILE_NAMES: dict[str, str] = {}
"""Our gripper names -> the ``gripper/type`` we write where it is not our name (none: ACRONYM's own name for the
Panda, ``panda``, is ours)."""

FLEX_MOTION: dict[str, str] = {
    "motion_closing_linear": "flex/object_motion_during_closing_linear",
    "motion_closing_angular": "flex/object_motion_during_closing_angular",
    "motion_shaking_linear": "flex/object_motion_during_shaking_linear",
    "motion_shaking_angular": "flex/object_motion_during_shaking_angular",
}
"""Our rollout motion columns (m, rad; NaN where the phase was not reached) -> ACRONYM's quality keys (below
``grasps/qualities``) for the same measures of its close-and-shake test."""

FIRM_KEY = "graspgen/firm_hold"
"""Key (below ``grasps/qualities``) of our firm-hold label (1 / 0): still held and the object's motion in the hand
within the firm-hold tolerances (:attr:`graspgen.sim.protocols.RolloutResult.firm`). ``flex/object_in_gripper`` stays
the still-held label."""

FIRM_COLUMNS: tuple[str, ...] = ("firm", "max_rel_translation", "max_rel_rotation")
"""Table columns the exports write as ``graspgen/firm_hold`` and ``graspgen/<column>`` when ``firm`` is present."""


def _offset(tcp_offset: float) -> np.ndarray:
    """(4, 4) translation by ``tcp_offset`` (m) along z."""
    T = np.eye(4)
    T[2, 3] = check_number("tcp_offset", tcp_offset)
    return T


def tcp_from_hand_base(T_base: Any, tcp_offset: float) -> np.ndarray:
    """TCP poses of hand-base poses: ``T_tcp = T_base @ Trans(0, 0, +tcp_offset)``.

    The two frames share their axes (z approach, x closing); the TCP lies ``tcp_offset`` (m) along the base's z.

    Parameters
    ----------
    T_base : (n, 4, 4) or (4, 4) float
        Hand-base poses (ACRONYM's ``grasps/transforms``).
    tcp_offset : float
        m, :attr:`graspgen.grippers.GripperSpec.tcp_offset` of the gripper the poses belong to.

    Returns
    -------
    (n, 4, 4) float64
    """
    return check_transforms("T_base", T_base, allow_single=True) @ _offset(tcp_offset)


def hand_base_from_tcp(T_tcp: Any, tcp_offset: float) -> np.ndarray:
    """Hand-base poses of TCP poses, the inverse of :func:`tcp_from_hand_base`: ``T_tcp @ Trans(0, 0, -offset)``.

    Returns
    -------
    (n, 4, 4) float64
    """
    return check_transforms("T_tcp", T_tcp, allow_single=True) @ _offset(-float(tcp_offset))


def gripper_name(file_type: str) -> str:
    """Our registry name of an ACRONYM ``gripper/type`` (``panda``, ACRONYM's and ours, passes; ``franka_panda`` ->
    ``panda``).

    Raises
    ------
    graspgen.errors.SettingsError
        Unknown gripper; the message lists the registered ones.
    """
    name = GRIPPER_ALIASES.get(file_type, file_type)
    load_gripper(name)  # SettingsError listing the choices when unknown
    return name


@dataclasses.dataclass(frozen=True, eq=False)
class AcronymGrasps:
    """The contents of one ACRONYM grasp file. Arrays are read-only; optional fields are None when absent."""

    transforms: np.ndarray
    """(n, 4, 4) float64 hand-base poses in the object's (scaled) mesh frame, m (ACRONYM's convention)."""
    success: np.ndarray | None
    """(n,) int8: ``grasps/qualities/flex/object_in_gripper`` (1 success, 0 failure); None when the file has none."""
    qualities: dict[str, np.ndarray]
    """Every per-grasp quality below ``grasps/qualities``, by path (e.g. ``flex/object_in_gripper``), as read."""
    object_file: str
    """Mesh path as stored (relative to a mesh root folder, usually)."""
    object_scale: float
    """Metres per mesh-file unit."""
    gripper_type: str
    """``gripper/type`` as stored (e.g. ``panda``); :meth:`tcp_poses` maps it with :func:`gripper_name`."""
    object_mass: float | None = None
    """kg."""
    object_com: np.ndarray | None = None
    """(3,) float64 centre of mass, m, scaled mesh frame."""
    object_inertia: np.ndarray | None = None
    """(3, 3) float64, kg m^2."""
    object_density: float | None = None
    """kg/m^3."""
    object_friction: float | None = None
    """Sliding friction coefficient (dimensionless)."""
    gripper_configuration: np.ndarray | None = None
    """(k,) float64 gripper joint configuration as stored."""
    attrs: dict[str, Any] = dataclasses.field(default_factory=dict)
    """Root attributes of the file (ACRONYM writes none; the object export writes ``protocol``), strings
    decoded."""
    path: str = ""
    """File it was read from (empty when built in memory)."""

    def __post_init__(self) -> None:
        T = check_transforms("transforms", self.transforms, allow_single=True)
        object.__setattr__(self, "transforms", T)
        n = len(T)
        if self.success is not None:
            object.__setattr__(self, "success", np.asarray(self.success).astype(np.int8).reshape(-1))
            if len(self.success) != n:
                raise SettingsError(f"success: expected {n} labels (one per transform), got {len(self.success)}")
        for value in (self.transforms, self.success, self.object_com, self.object_inertia,
                      self.gripper_configuration, *self.qualities.values()):
            if isinstance(value, np.ndarray):
                value.setflags(write=False)

    def __len__(self) -> int:
        return len(self.transforms)

    @property
    def gripper(self) -> str:
        """Our registry name of the file's gripper (SettingsError when we do not know it)."""
        return gripper_name(self.gripper_type)

    def tcp_poses(self, tcp_offset: float | None = None) -> np.ndarray:
        """(n, 4, 4) TCP poses in the object frame: :func:`tcp_from_hand_base` with the file's gripper's
        ``tcp_offset`` (or the one given, m)."""
        if tcp_offset is None:
            tcp_offset = load_gripper(self.gripper).tcp_offset
        return tcp_from_hand_base(self.transforms, tcp_offset)


# ---------------------------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------------------------


def _string(value: Any) -> str:
    if isinstance(value, np.ndarray):
        value = value.reshape(-1)[0] if value.size else ""
    if isinstance(value, bytes):
        return value.decode("utf-8")
    return str(value)


def _float(group: h5py.Group, key: str) -> float | None:
    if key not in group:
        return None
    return float(np.asarray(group[key][()], dtype=np.float64).reshape(-1)[0])


def _array(group: h5py.Group, key: str, shape: tuple[int, ...]) -> np.ndarray | None:
    if key not in group:
        return None
    return np.asarray(group[key][()], dtype=np.float64).reshape(shape)


def _qualities(group: h5py.Group, prefix: str = "") -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for name, item in group.items():
        if isinstance(item, h5py.Group):
            out.update(_qualities(item, f"{prefix}{name}/"))
        else:
            out[f"{prefix}{name}"] = np.asarray(item[()])
    return out


def read_acronym(path: str | Path) -> AcronymGrasps:
    """Read an ACRONYM grasp file (layout: docs/format.md, "ACRONYM files").

    Required: ``grasps/transforms`` and ``object/file``; ``object/scale`` defaults to 1 and ``gripper/type`` to
    ``panda`` (the only gripper ACRONYM itself uses, by the name its files give it); everything else is optional.

    Raises
    ------
    graspgen.errors.InputError
        The file is missing, not HDF5, or lacks / mangles a required entry; the message names the file.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: grasp file not found")
    try:
        handle = h5py.File(path, "r")
    except OSError as exc:
        raise InputError(f"{path}: not an HDF5 file, so not an ACRONYM grasp file ({exc})") from None
    with handle as f:
        for key in ("grasps/transforms", "object/file"):
            if key not in f:
                raise InputError(f"{path}: not an ACRONYM grasp file: no {key!r} (it has: {', '.join(sorted(f))})")
        T = np.asarray(f["grasps/transforms"][()], dtype=np.float64)
        if T.ndim != 3 or T.shape[1:] != (4, 4) or not np.isfinite(T).all():
            raise InputError(f"{path}: grasps/transforms must be finite (n, 4, 4) transforms, got shape {T.shape}")
        try:
            check_transforms("grasps/transforms", T)
        except SettingsError as exc:
            raise InputError(f"{path}: {exc}") from None
        qualities = _qualities(f["grasps/qualities"]) if "grasps/qualities" in f else {}
        # Only the label is required to be per grasp: real ACRONYM exports carry other-shaped extras (one of
        # ../shared/learn has flex/object_in_gripper_grasp of shape (65, 2000)), which are not ours to judge.
        success = qualities.get(SUCCESS_KEY)
        if success is not None and success.shape[:1] != (len(T),):
            raise InputError(f"{path}: grasps/qualities/{SUCCESS_KEY} has shape {success.shape}, expected ({len(T)},)")
        qualities = {k: v for k, v in qualities.items() if v.shape[:1] == (len(T),)}
        obj, grip = f["object"], f.get("gripper")
        scale = _float(obj, "scale")
        if scale is not None and not (scale > 0 and math.isfinite(scale)):
            raise InputError(f"{path}: object/scale must be > 0, got {scale}")
        return AcronymGrasps(
            transforms=T,
            success=qualities.get(SUCCESS_KEY),
            qualities=qualities,
            object_file=_string(obj["file"][()]),
            object_scale=1.0 if scale is None else scale,
            gripper_type=_string(grip["type"][()]) if grip is not None and "type" in grip else "panda",
            object_mass=_float(obj, "mass"),
            object_com=_array(obj, "com", (3,)),
            object_inertia=_array(obj, "inertia", (3, 3)),
            object_density=_float(obj, "density"),
            object_friction=_float(obj, "friction"),
            gripper_configuration=(np.asarray(grip["configuration"][()], dtype=np.float64).reshape(-1)
                                   if grip is not None and "configuration" in grip else None),
            attrs={str(k): _string(v) if isinstance(v, (bytes, str)) else v for k, v in f.attrs.items()},
            path=str(path),
        )


# ---------------------------------------------------------------------------------------------------------------
# Writing
# ---------------------------------------------------------------------------------------------------------------


def write_acronym(
    path: str | Path,
    T_tcp: Any,
    success: Any,
    *,
    object_file: str,
    object_scale: float = 1.0,
    gripper: str = ACRONYM_GRIPPER,
    object_mass: float | None = None,
    object_com: Any = None,
    object_inertia: Any = None,
    object_density: float | None = None,
    object_friction: float | None = None,
    gripper_configuration: Any = None,
    qualities: Mapping[str, Any] | None = None,
    attrs: Mapping[str, str] | None = None,
) -> None:
    """Write grasps of one object as an ACRONYM grasp file (layout: docs/format.md, "ACRONYM files").

    Parameters
    ----------
    path : str or Path
        Destination ``.h5`` (overwritten).
    T_tcp : (n, 4, 4) float
        TCP poses in the object's (scaled) mesh frame, m (our convention); written as hand-base poses with
        :func:`hand_base_from_tcp` and ``gripper``'s ``tcp_offset``.
    success : (n,) bool or int
        Success labels, written to ``grasps/qualities/flex/object_in_gripper`` (1 / 0) -- for our data, outcome 5.
    object_file : str
        Mesh path as it should be stored (relative to the reader's mesh root).
    object_scale : float
        Metres per mesh-file unit.
    gripper : str
        Our gripper name (:data:`graspgen.grippers.GRIPPERS`), written as ``gripper/type`` (the Panda as ``panda``,
        ACRONYM's own name for it).
    object_mass, object_com, object_inertia, object_density, object_friction
        Optional object properties (kg, (3,) m, (3, 3) kg m^2, kg/m^3, -); omitted from the file when None.
    gripper_configuration : (k,) float, optional
        Default: half the gripper's maximum opening (one finger joint of a fully open hand, 0.04 m for the Panda).
    qualities : mapping, optional
        Further per-grasp columns ``{"name/sub": (n,) array}`` written below ``grasps/qualities``.
    attrs : mapping, optional
        String attributes of the file's root (e.g. ``{"protocol": "acronym"}``), written in sorted order.
    """
    spec = load_gripper(gripper)
    T_base = hand_base_from_tcp(T_tcp, spec.tcp_offset)
    n = len(T_base)
    labels = np.asarray(success).reshape(-1)
    if len(labels) != n:
        raise SettingsError(f"success: expected {n} labels (one per pose), got {len(labels)}")
    extra = {str(k): np.asarray(v) for k, v in (qualities or {}).items()}
    for key, value in extra.items():
        if key == SUCCESS_KEY:
            raise SettingsError(f"qualities: {SUCCESS_KEY!r} is written from `success`; do not pass it twice")
        if value.shape[:1] != (n,):
            raise SettingsError(f"qualities[{key!r}]: expected {n} values, got shape {value.shape}")
    check_number("object_scale", object_scale, low=0.0, low_open=True)
    config = (np.array([spec.max_width / 2.0]) if gripper_configuration is None
              else np.asarray(gripper_configuration, dtype=np.float64).reshape(-1))
    text = h5py.string_dtype("utf-8")
    with h5py.File(path, "w") as f:
        f.create_dataset("grasps/transforms", data=T_base)
        f.create_dataset(f"grasps/qualities/{SUCCESS_KEY}", data=labels.astype(np.int64))
        for key in sorted(extra):
            f.create_dataset(f"grasps/qualities/{key}", data=extra[key])
        f.create_dataset("object/file", data=str(object_file), dtype=text)
        f.create_dataset("object/scale", data=float(object_scale))
        for key, value, shape in (("mass", object_mass, ()), ("density", object_density, ()),
                                  ("friction", object_friction, ()), ("com", object_com, (3,)),
                                  ("inertia", object_inertia, (3, 3))):
            if value is not None:
                f.create_dataset(f"object/{key}", data=np.asarray(value, dtype=np.float64).reshape(shape))
        f.create_dataset("gripper/type", data=_FILE_NAMES.get(spec.name, spec.name), dtype=text)
        f.create_dataset("gripper/configuration", data=config)
        for key in sorted(attrs or {}):
            f.attrs[str(key)] = str(attrs[key])  # type: ignore[index]


def obj_text(vertices: np.ndarray, faces: np.ndarray) -> str:
    """Wavefront OBJ of a triangle mesh (shortest round-trip floats: deterministic, exact).

    Parameters
    ----------
    vertices : (v, 3) float
        m.
    faces : (f, 3) int
        0-based vertex indices (written 1-based).

    Returns
    -------
    str
    """
    out = io.StringIO()
    out.write("# graspgen object mesh, metres\n")
    for x, y, z in np.asarray(vertices, dtype=np.float64).tolist():
        out.write(f"v {x!r} {y!r} {z!r}\n")
    for a, b, c in (np.asarray(faces, dtype=np.int64) + 1).tolist():
        out.write(f"f {a} {b} {c}\n")
    return out.getvalue()
