"""Grasp files for :func:`graspgen.workflows.evaluate.evaluate_grasps`: an ACRONYM HDF5 file or a Parquet table of
TCP poses, with the mesh they refer to (what ``gen evaluate`` and ``gen show rollout --grasps`` read)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from graspgen.errors import GraspGenError, InputError
from graspgen.io.acronym import read_acronym
from graspgen.workflows.evaluate_settings import EvaluateParams

__all__ = ["GraspFile", "read_grasp_file", "read_pose_table"]


def read_pose_table(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """TCP poses (and widths) from a Parquet table.

    Columns: ``pose_object`` or ``pose`` (16 floats: the TCP pose in the object's scaled mesh frame, 4x4 row-major;
    the grasps stage's own tables therefore work as they are), optional ``width`` (m).

    Returns
    -------
    T_tcp : (n, 4, 4) float64
    widths : (n,) float64 or None

    Raises
    ------
    graspgen.errors.InputError
        Not a Parquet file, or no pose column / wrong lengths; the message names the file.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: grasp file not found")
    try:
        table = pq.read_table(path)
    except Exception as exc:  # pyarrow raises ArrowInvalid, OSError, ... on garbage
        raise InputError(f"{path}: not a readable Parquet file ({type(exc).__name__}: {exc})") from None
    column = next((c for c in ("pose_object", "pose") if c in table.column_names), None)
    if column is None:
        raise InputError(f"{path}: no pose column: expected 'pose_object' or 'pose' (16 floats per row, the TCP "
                         f"pose 4x4 row-major); it has: {', '.join(table.column_names)}")
    rows = table.column(column).to_pylist()
    if any(r is None or len(r) != 16 for r in rows):
        raise InputError(f"{path}: every {column!r} must hold 16 numbers (a 4x4 row-major pose)")
    T = np.asarray(rows, dtype=np.float64).reshape(len(rows), 4, 4)
    widths = None
    if "width" in table.column_names:
        widths = np.asarray(table.column("width").to_pylist(), dtype=np.float64)
    return T, widths


@dataclasses.dataclass(frozen=True, eq=False)
class GraspFile:
    """The grasps of one object read from a file by :func:`read_grasp_file`: what
    :func:`graspgen.workflows.evaluate.evaluate_grasps` takes."""

    kind: str
    """``acronym`` (an ACRONYM HDF5 file) or ``parquet`` (a table of TCP poses)."""
    T_tcp: np.ndarray
    """``(n, 4, 4) float64`` TCP poses in the object's scaled mesh frame, m."""
    widths: np.ndarray | None
    """``(n,) float64`` pad separations, m (a Parquet ``width`` column); None when the file has none."""
    mesh_path: Path
    """The object's mesh file."""
    scale: float | None
    """Metres per mesh unit (ACRONYM's ``object/scale`` unless overridden); None: detect from the size."""
    params: EvaluateParams
    """The params given, with the file's object mass, density and friction (ACRONYM) or the friction given."""
    reference: np.ndarray | None
    """``(n,) int8`` the file's own success label (ACRONYM's ``flex/object_in_gripper``); None when absent."""
    gripper: str | None
    """Our name of the file's gripper (ACRONYM's ``gripper/type``, e.g. ``panda``); None for Parquet."""


def read_grasp_file(
    path: str | Path,
    params: EvaluateParams | None = None,
    *,
    mesh_root: str | Path | None = None,
    mesh: str | Path | None = None,
    scale: float | None = None,
    friction: float | None = None,
) -> GraspFile:
    """Read an ACRONYM file (``.h5``, ``.hdf5``) or a Parquet table of TCP poses (``.parquet``, :func:`read_pose_table`)
    with its mesh: what ``gen evaluate`` and ``gen show rollout --grasps`` label.

    Parameters
    ----------
    path : str or Path
        The grasp file.
    params : EvaluateParams, optional
        Settings to start from (default ``EvaluateParams()``); ACRONYM's ``object/mass``, ``density`` and
        ``friction`` replace theirs.
    mesh_root : str or Path, optional
        Folder ACRONYM's ``object/file`` is relative to (default: the current directory); for Parquet, the folder a
        relative ``mesh`` is relative to.
    mesh : str or Path, optional
        The mesh file; needed with Parquet; replaces ACRONYM's ``object/file``.
    scale : float, optional
        Metres per mesh unit; default ACRONYM's ``object/scale``, for Parquet detected from the size.
    friction : float, optional
        The object's sliding friction; default ACRONYM's ``object/friction``, else ``params.friction``.

    Raises
    ------
    graspgen.errors.InputError
        Missing or unreadable file, unknown suffix, Parquet without ``mesh``, mesh not found; the message names the
        file.
    """
    path = Path(path)
    params = EvaluateParams() if params is None else params
    suffix = path.suffix.lower()
    if not path.is_file():
        raise InputError(f"{path}: grasp file not found")
    if suffix in (".h5", ".hdf5"):
        acr = read_acronym(path)
        try:
            T = acr.tcp_poses()
            gripper = acr.gripper
        except GraspGenError as exc:
            raise InputError(f"{path}: gripper/type {acr.gripper_type!r}: {exc}") from None
        root = Path(mesh_root) if mesh_root is not None else Path.cwd()
        mesh_path = Path(mesh) if mesh is not None else root / acr.object_file
        if not mesh_path.is_file():
            how = "--mesh" if mesh is not None else f"object/file {acr.object_file!r} under --mesh-root {root}"
            raise InputError(f"{path}: mesh not found: {mesh_path} ({how})")
        fric = friction if friction is not None else acr.object_friction
        params = dataclasses.replace(
            params, friction=fric if fric is not None else params.friction, mass=acr.object_mass,
            density=acr.object_density if acr.object_density is not None else params.density)
        return GraspFile("acronym", T, None, mesh_path, acr.object_scale if scale is None else scale, params,
                         acr.success, gripper)
    if suffix == ".parquet":
        if mesh is None:
            raise InputError(f"{path}: a Parquet grasp file needs --mesh (the mesh its poses refer to)")
        T, widths = read_pose_table(path)
        mesh_path = Path(mesh) if mesh_root is None or Path(mesh).is_absolute() else Path(mesh_root) / mesh
        if not mesh_path.is_file():
            raise InputError(f"{path}: mesh not found: {mesh_path} (--mesh)")
        if friction is not None:
            params = dataclasses.replace(params, friction=friction)
        return GraspFile("parquet", T, widths, mesh_path, scale, params, None, None)
    raise InputError(
        f"{path}: unsupported grasp file format {path.suffix or '(none)'!r}; expected an ACRONYM HDF5 "
        "file (.h5, .hdf5) or a Parquet table of poses (.parquet)"
    )
