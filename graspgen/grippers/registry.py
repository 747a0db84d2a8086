"""The gripper registry: the bundled grippers by name (:data:`GRIPPERS`), the default ones
(:data:`DEFAULT_GRIPPER`, :data:`ACRONYM_GRIPPER`), :func:`load_gripper` (a name or a gripper file) and the files
a gripper given by path is read from (:func:`gripper_files`).
"""

from __future__ import annotations

import os
from typing import Any

from graspgen.errors import SettingsError
from graspgen.grippers.bundled import BUNDLED_FILES, GRIPPERS_DIR
from graspgen.grippers.files import GRIPPER_FILE_SUFFIXES, read_gripper
from graspgen.grippers.shapes import Mesh
from graspgen.grippers.spec import GripperSpec

__all__ = ["GRIPPERS", "DEFAULT_GRIPPER", "ACRONYM_GRIPPER", "load_gripper", "is_gripper_path", "gripper_files"]


def _read_bundled(name: str) -> GripperSpec:
    spec = read_gripper(GRIPPERS_DIR / BUNDLED_FILES[name])
    if spec.name != name:
        raise SettingsError(f"gripper: {spec.file}: name {spec.name!r} differs from its registry name {name!r}")
    return spec


#: Registered grippers by name, read from their files in ``assets/grippers``.
GRIPPERS: dict[str, GripperSpec] = {name: _read_bundled(name) for name in sorted(BUNDLED_FILES)}
#: The default gripper's name: the Robotiq 2F-85 from its collision meshes and 4-bar linkage (``robotiq_2f85`` is
#: the same hand as boxes, a little faster).
DEFAULT_GRIPPER = "robotiq_2f85_mesh"
#: The gripper of the object-centric (ACRONYM / GraspGen) sets and of ACRONYM files: the Franka Panda hand, the one
#: ACRONYM itself uses.
ACRONYM_GRIPPER = "panda"


def is_gripper_path(name: Any) -> bool:
    """Whether ``name`` is meant as a gripper file rather than a registered name: a path object, or a string with a
    gripper-file suffix or a path separator."""
    if isinstance(name, os.PathLike):
        return True
    return isinstance(name, str) and (name.lower().endswith(GRIPPER_FILE_SUFFIXES) or "/" in name or os.sep in name)


def load_gripper(name: str | os.PathLike) -> GripperSpec:
    """The registered :class:`GripperSpec` called ``name``, or the gripper file at path ``name``
    (:func:`read_gripper`); :class:`SettingsError` listing the registered names otherwise."""
    if isinstance(name, str) and name in GRIPPERS:
        return GRIPPERS[name]
    if is_gripper_path(name):
        return read_gripper(name)
    raise SettingsError(f"gripper: unknown {name!r}; choose one of: {', '.join(sorted(GRIPPERS))} (or give the path "
                        f"of a gripper file: {', '.join(GRIPPER_FILE_SUFFIXES)})")


def gripper_files(name_or_path: str | os.PathLike) -> tuple[str, ...]:
    """The files a gripper given by path is read from (its gripper file, its robot model's files, then its mesh
    files), whose bytes a stage puts into its content keys; () for a registered name (the bundled files count as
    code: see :data:`BUNDLED_DIGESTS`)."""
    if isinstance(name_or_path, str) and name_or_path in GRIPPERS:
        return ()
    spec = load_gripper(name_or_path)
    files = [spec.file] if spec.file else []
    files += [f for f in spec.model_files if f not in files]
    for piece in spec.pieces:
        if isinstance(piece, Mesh) and piece.file and piece.file not in files:
            files.append(piece.file)
    return tuple(files)
