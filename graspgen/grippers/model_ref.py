"""A gripper given as a robot model file (URDF or MJCF), as plain data: :class:`ModelRef`, read from a gripper file's
``model:`` entry (:func:`model_ref_from_dict`), and the hook through which :mod:`graspgen.sim.gripper_import` (which
needs MuJoCo, trimesh and CoACD, all above this package) turns it into a :class:`~graspgen.grippers.spec.GripperSpec`
(:func:`spec_from_model`).

The gripper file then reads, for example::

    name: my_2f85
    model: {package: airo_models, path: grippers/robotiq_2f_85/urdf/robotiq_2f_85.urdf}   # or model: hand.urdf
    # package: an importable package (path inside its folder) or a distribution (path inside its install root)
    pads: [left_inner_finger_pad, right_inner_finger_pad]   # geom or body names: left, then right
    force_limit: 100.0                                       # what the file does not say
    pad_turn_tolerance: 3                                    # degrees a pad may turn while closing (default 1)

Everything else (stroke, TCP, pad faces, closing direction, collision pieces, linkage, masses, speed) is derived from
the model by :func:`graspgen.sim.gripper_import.derive_spec`; any :class:`GripperSpec` scalar given beside it
(``force_limit``, ``closing_speed``, ``finger_mass``, ``body_mass``, ``max_width``, ``pad_friction``, ...) overrides
or supplies the derived value.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import importlib.util
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from graspgen.errors import SettingsError
from graspgen.grippers.shapes import Box, short_repr
from graspgen.validation import check_number

__all__ = ["MAX_PAD_TURN_TOLERANCE", "MODEL_KEYS", "MODEL_SUFFIXES", "PAD_TURN_TOLERANCE", "ModelRef",
           "model_ref_from_dict", "set_model_reader", "spec_from_model"]

#: Suffixes of the robot model files a gripper file's ``model:`` may name.
MODEL_SUFFIXES = (".urdf", ".xml")
#: The keys of a gripper file that describe its model (besides GripperSpec scalars that override derived values).
MODEL_KEYS = ("model", "pads", "joints", "actuator", "body", "finger_box", "pad_turn_tolerance")
#: Default and largest ``pad_turn_tolerance`` (degrees): a pad turning more than 10 degrees is no parallel jaw.
PAD_TURN_TOLERANCE, MAX_PAD_TURN_TOLERANCE = 1.0, 10.0


@dataclass(frozen=True)
class ModelRef:
    """Where a gripper's model is and what the user names in it. Plain data: no file is read here."""

    path: str
    """Absolute path of the URDF (``.urdf``) or MJCF (``.xml``) file."""
    pads: tuple[str, str]
    """(left, right) pad: each a collision geom's name or a body (URDF link) name; a body stands for its collision
    geom reaching farthest towards the other pad. The TCP x axis points from the left pad to the right one."""
    joints: tuple[str, ...] = ()
    """Joints that close the hand (they move together from their open end to their closed end); empty: derived
    (the actuator's joints, else the moving joints no other joint mimics)."""
    actuator: str = ""
    """MJCF actuator that closes the hand (its joint or tendon's joints are the closing joints; its force range the
    grip force); '' : the file's only actuator, if any."""
    body: str = ""
    """Body (URDF link) whose subtree is the hand, for a hand inside a robot; '' : the model's root body."""
    finger_box: Box | None = None
    """A box finger put on each pad body that has no collision geometry (hands the file gives without fingers),
    in the right pad body's frame (m); the left pad body gets it turned 180 degrees about the TCP's z axis."""
    pad_turn_tolerance: float = PAD_TURN_TOLERANCE
    """Largest turn (degrees, 0 to :data:`MAX_PAD_TURN_TOLERANCE`) of a pad body over the stroke for the pads to
    count as parallel; a hand whose pads turn more is refused. The derived gripper keeps its pads parallel: a turn
    within the tolerance is ignored (not simulated), and one over 0.1 degrees is named in the gripper's ``source``.
    MuJoCo Menagerie's Robotiq 2F-85, whose 4-bars are not exact parallelograms, turns its pads about 1.8
    degrees."""
    overrides: tuple[tuple[str, Any], ...] = ()
    """(GripperSpec field, value) pairs given beside ``model`` in the gripper file: they replace derived values."""


def _package_file(name: str, path: str, where: str) -> Path:
    """``path`` inside the installed Python package ``name`` (its folder), else inside the installed distribution
    ``name`` (its install root, e.g. ``site-packages``: for data-only packages such as example-robot-data)."""
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        spec = None
    if spec is not None and spec.submodule_search_locations:
        return Path(next(iter(spec.submodule_search_locations))) / path
    try:
        return Path(importlib.metadata.distribution(name).locate_file(path))
    except importlib.metadata.PackageNotFoundError:
        raise SettingsError(f"{where}: Python package {name!r} is not installed (pip install it; the bundled "
                            "examples need the 'grippers' extra: pip install -e '.[grippers]')") from None


def _model_path(value: Any, base_dir: Path) -> Path:
    """The model file of a ``model:`` entry: a path relative to the gripper file, or ``{package, path}``."""
    if isinstance(value, Mapping):
        unknown = sorted(set(value) - {"package", "path"})
        if unknown or "path" not in value or "package" not in value:
            raise SettingsError(f"model: a mapping has keys package (an installed Python package) and path (inside "
                                f"it), got {short_repr(dict(value))}")
        path = _package_file(str(value["package"]), str(value["path"]), "model.package")
    elif isinstance(value, str) and value:
        path = base_dir / os.path.expanduser(value)
    else:
        raise SettingsError(f"model: must be a file name (.urdf or .xml) or {{package, path}}, got {short_repr(value)}")
    if path.suffix.lower() not in MODEL_SUFFIXES:
        raise SettingsError(f"model: {path.name}: not a robot model file (expected {', '.join(MODEL_SUFFIXES)})")
    if not path.is_file():
        raise SettingsError(f"model: {path}: no such file")
    return path.resolve()


def _names(key: str, value: Any) -> tuple[str, ...]:
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, (list, tuple)) or not all(isinstance(v, str) and v for v in items):
        raise SettingsError(f"{key}: must be a list of names, got {short_repr(value)}")
    return tuple(items)


def _turn_tolerance(value: Any) -> float:
    """``pad_turn_tolerance`` (degrees) checked; :class:`SettingsError` naming the key and its unit."""
    try:
        return check_number("pad_turn_tolerance", value, low=0.0, high=MAX_PAD_TURN_TOLERANCE)
    except SettingsError as exc:
        raise SettingsError(f"{exc} (degrees a pad may turn while closing)") from None


def model_ref_from_dict(data: Mapping[str, Any], base_dir: Path, overrides: Mapping[str, Any]) -> ModelRef:
    """The :class:`ModelRef` of a gripper file's contents ``data`` (which holds ``model``); paths relative to
    ``base_dir``; ``overrides`` the GripperSpec fields given beside it. :class:`SettingsError` names the key."""
    if "pads" not in data:
        raise SettingsError("pads: missing: name the [left, right] pad geoms or fingertip bodies of the model")
    pads = _names("pads", data["pads"])
    if len(pads) != 2 or pads[0] == pads[1]:
        raise SettingsError(f"pads: must name two different geoms or bodies [left, right], got {list(pads)}")
    box = data.get("finger_box")
    if box is not None:
        if not isinstance(box, Mapping) or "size" not in box or set(box) - {"size", "pos"}:
            raise SettingsError(f"finger_box: must be a box {{size, pos}} in the right pad body's frame, got "
                                f"{short_repr(box)}")
        box = Box(size=box["size"], pos=box.get("pos", (0.0, 0.0, 0.0)))
    return ModelRef(path=str(_model_path(data["model"], base_dir)), pads=(pads[0], pads[1]),
                    joints=_names("joints", data.get("joints") or []), actuator=str(data.get("actuator") or ""),
                    body=str(data.get("body") or ""), finger_box=box,
                    pad_turn_tolerance=_turn_tolerance(data.get("pad_turn_tolerance", PAD_TURN_TOLERANCE)),
                    overrides=tuple(sorted(overrides.items())))


_READER: list[Callable] = []


def set_model_reader(reader: Callable) -> None:
    """Install the function that derives a spec from a :class:`ModelRef` (``reader(ref, file=...)``); called by
    :mod:`graspgen.sim.gripper_import` when it is imported."""
    _READER[:] = [reader]


def spec_from_model(ref: ModelRef, *, file: str = ""):
    """The :class:`~graspgen.grippers.spec.GripperSpec` derived from ``ref`` by
    :func:`graspgen.sim.gripper_import.derive_spec`. The deriving module needs MuJoCo, trimesh and CoACD, which sit
    above this package, so it is imported here by name on first use (it also registers itself when imported
    directly; every module that builds a gripper model imports it)."""
    if not _READER:
        importlib.import_module("graspgen.sim.gripper_import")
    return _READER[0](ref, file=file)
