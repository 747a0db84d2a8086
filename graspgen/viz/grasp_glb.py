"""Grasps in 3-D: a GLB (binary glTF 2.0) scene of objects and one gripper marker per grasp (``gen show grasps --3d``).

The marker is ACRONYM's open-hand "fork" of thin boxes in the grasp's TCP frame, sized by the gripper: two fingers
with inner faces at ``x = -+max_width / 2`` and tips flush with the pads, a palm bar, a stem back to the hand base
(``z = -tcp_offset``). Markers of one label share one mesh (small files); nodes are named ``grasp_<id>`` and carry
the grasp pose, object nodes the object's name and pose. The bytes are a pure function of the arguments for a given
trimesh version.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import trimesh

from graspgen.errors import SettingsError
from graspgen.grippers import DEFAULT_GRIPPER, GripperSpec, load_gripper
from graspgen.io.arrow import column_array
from graspgen.io.atomic import atomic_path
from graspgen.io.objects import ObjectRecord
from graspgen.io.scenes import SceneRecord
from graspgen.validation import check_transforms
from graspgen.viz.grasp_view import LABELS, choose_grasps, grasp_labels

__all__ = [
    "SUCCESS_COLOUR",
    "FAILURE_COLOUR",
    "OBJECT_COLOUR",
    "SUPPORT_COLOUR",
    "marker_mesh",
    "labelled_grasps_glb",
    "grasps_glb",
    "object_set_glb",
    "scene_glb",
    "write_glb",
]

SUCCESS_COLOUR = (40, 200, 60, 255)
"""RGBA of a successful grasp's marker (the green of :data:`graspgen.viz.grasp_view.LABELS`)."""
FAILURE_COLOUR = (235, 30, 30, 255)
"""RGBA of a failed grasp's marker (red)."""
OBJECT_COLOUR = (170, 170, 170, 255)
"""RGBA of object meshes."""
SUPPORT_COLOUR = (120, 90, 60, 255)
"""RGBA of a scene's table top."""

PLAIN_LABELS: dict[int, tuple[str, tuple[int, int, int, int]]] = {1: ("success", SUCCESS_COLOUR),
                                                                  0: ("failure", FAILURE_COLOUR)}
"""Label code -> (name, RGBA) of :func:`grasps_glb`: 1 success, 0 failure."""


def _spec(gripper: GripperSpec | str | None) -> GripperSpec:
    if isinstance(gripper, GripperSpec):
        return gripper
    return load_gripper(DEFAULT_GRIPPER if gripper is None else gripper)


def marker_mesh(gripper: GripperSpec | str | None = None, colour: Sequence[int] = SUCCESS_COLOUR) -> trimesh.Trimesh:
    """The fork marker of one grasp in its TCP frame, RGBA ``colour`` (4,) 0-255: four boxes (left finger, right finger,
    palm bar, stem), 32 vertices, 48 faces, m; ``gripper`` a spec, name or file (None: the default gripper)."""
    spec = _spec(gripper)
    w, t = float(spec.max_width), float(spec.max_width) / 40.0
    tip = spec.pad_size[2] / 2.0
    back = tip - float(spec.finger_size[2])
    stem_end = min(-float(spec.tcp_offset), back - t - spec.finger_size[2] / 2.0)
    stem = (back - t) - stem_end

    def box(extents: Sequence[float], centre: Sequence[float]) -> trimesh.Trimesh:
        T = np.eye(4)
        T[:3, 3] = centre
        return trimesh.creation.box(extents=extents, transform=T)

    parts = [
        box((t, t, tip - back), (-(w + t) / 2.0, 0.0, (tip + back) / 2.0)),
        box((t, t, tip - back), ((w + t) / 2.0, 0.0, (tip + back) / 2.0)),
        box((w + 2.0 * t, t, t), (0.0, 0.0, back - t / 2.0)),
        box((t, t, stem), (0.0, 0.0, stem_end + stem / 2.0)),
    ]
    mesh = trimesh.util.concatenate(parts)
    mesh.visual.face_colors = np.asarray(colour, dtype=np.uint8)
    return mesh


def _coloured(vertices: Any, faces: Any, colour: Sequence[int], where: str) -> trimesh.Trimesh:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1:] != (3,) or not np.isfinite(v).all():
        raise SettingsError(f"{where}: vertices must be finite (v, 3), got shape {v.shape}")
    in_range = len(f) == 0 or (f.min() >= 0 and f.max() < len(v))
    if f.ndim != 2 or f.shape[1:] != (3,) or f.dtype.kind not in "iu" or not in_range:
        raise SettingsError(f"{where}: faces must be (f, 3) integer indices into the {len(v)} vertices")
    mesh = trimesh.Trimesh(v, f.astype(np.int64), process=False)
    mesh.visual.face_colors = np.asarray(colour, dtype=np.uint8)
    return mesh


def labelled_grasps_glb(
    objects: Sequence[tuple[str, Any, Any, Any]],
    T_tcp: Any,
    labels: Any,
    colours: Mapping[int, tuple[str, Sequence[int]]],
    *,
    gripper: GripperSpec | str | None = None,
    grasp_ids: Any = None,
    extra: Sequence[tuple[str, trimesh.Trimesh, Any]] = (),
) -> bytes:
    """The GLB bytes of objects at their poses and one marker per grasp, coloured by label.

    Parameters
    ----------
    objects : sequence of (name, vertices (v, 3), faces (f, 3), pose (4, 4))
        Meshes (m, mesh frame) and their poses in the file's frame; names unique.
    T_tcp : (n, 4, 4) float
        Grasp TCP poses in the file's frame.
    labels : (n,) int
        Label code per grasp, a key of ``colours`` (``{code: (name, RGBA)}``).
    grasp_ids : (n,) int, optional
        Node names ``grasp_<id>`` (default 0..n-1; unique).
    extra : sequence of (name, mesh, pose (4, 4))
        Further coloured meshes (e.g. a table top).

    Raises
    ------
    ValueError
        Shapes that do not match, a label without a colour, repeated names or ids.
    """
    n = len(np.asarray(T_tcp))
    T = np.zeros((0, 4, 4)) if n == 0 else check_transforms("T_tcp", T_tcp)
    codes = np.asarray(labels).reshape(-1)
    if len(codes) != n:
        raise SettingsError(f"labels: expected {n} labels (one per pose), got {len(codes)}")
    ids = np.arange(n) if grasp_ids is None else np.asarray(grasp_ids).reshape(-1)
    if len(ids) != n or len(set(ids.tolist())) != n:
        raise SettingsError(f"grasp_ids: expected {n} distinct ids (one per pose), got {len(ids)} "
                            f"({len(set(ids.tolist()))} distinct)")
    unknown = sorted({int(c) for c in codes} - {int(c) for c in colours})
    if unknown:
        raise SettingsError(f"labels: no colour for label(s) {unknown}; known: {sorted(int(c) for c in colours)}")
    spec = _spec(gripper)
    scene = trimesh.Scene()
    names: set[str] = set()

    def node(name: str, geometry: str, pose: Any) -> None:
        if name in names:
            raise SettingsError(f"objects: the name {name!r} is used twice")
        names.add(name)
        scene.graph.update(frame_to=name, frame_from=scene.graph.base_frame, geometry=geometry,
                           matrix=np.asarray(pose, dtype=np.float64))

    for name, vertices, faces, pose in objects:
        scene.geometry[str(name)] = _coloured(vertices, faces, OBJECT_COLOUR, f"objects[{name!r}]")
        node(str(name), str(name), check_transforms(f"objects[{name!r}] pose", pose, allow_single=True)[0])
    for name, mesh, pose in extra:
        scene.geometry[str(name)] = mesh
        node(str(name), str(name), pose)
    for code in sorted({int(c) for c in codes}):
        label, colour = colours[code]
        geometry = f"marker_{label}"
        scene.geometry[geometry] = marker_mesh(spec, colour)
        for i in np.flatnonzero(codes == code):
            node(f"grasp_{int(ids[i])}", geometry, T[i])
    return scene.export(file_type="glb")


def grasps_glb(
    vertices: Any,
    faces: Any,
    T_tcp: Any,
    success: Any,
    *,
    gripper: GripperSpec | str | None = None,
    grasp_ids: Any = None,
    name: str = "object",
) -> bytes:
    """The GLB bytes of one object (mesh ``vertices`` (v, 3) m, ``faces`` (f, 3), at its mesh frame's origin) and a
    marker per TCP pose ``T_tcp`` (n, 4, 4): :data:`SUCCESS_COLOUR` where ``success`` (n,), else
    :data:`FAILURE_COLOUR`."""
    flags = np.asarray(success).reshape(-1)
    if flags.dtype != np.bool_ and not (flags.dtype.kind in "iu" and np.isin(flags, (0, 1)).all()):
        raise SettingsError(f"success: must be booleans (or 0/1), got {flags.dtype}")
    return labelled_grasps_glb([(name, vertices, faces, np.eye(4))], T_tcp, flags.astype(np.int64), PLAIN_LABELS,
                               gripper=gripper, grasp_ids=grasp_ids)


def object_set_glb(record: ObjectRecord, grasps: pa.Table, *, n: int | None = None,
                   gripper: GripperSpec | str | None = None) -> bytes:
    """The GLB bytes of an object's grasp set (``grasp_id``, ``gripper``, ``pose_object``, ``success``), at most ``n``
    grasps spread over successes and failures (:func:`graspgen.viz.grasp_view.choose_grasps`; None: all); ``gripper``
    defaults to the table's."""
    success = grasps.column("success").to_numpy(zero_copy_only=False).astype(bool)
    rows = np.arange(len(grasps)) if n is None else choose_grasps(success.astype(np.int64), n, [1, 0])
    if gripper is None and len(grasps):
        gripper = grasps.column("gripper")[0].as_py()
    T = column_array(grasps, "pose_object", (4, 4))[rows]
    ids = grasps.column("grasp_id").to_numpy()[rows]
    return grasps_glb(record.vertices, record.faces, T, success[rows], gripper=gripper, grasp_ids=ids,
                      name=record.name)


def scene_glb(scene: SceneRecord, objects: Callable[[str], ObjectRecord], grasps: pa.Table,
              rollouts: pa.Table | None = None, *, n: int | None = None,
              gripper: GripperSpec | str | None = None) -> bytes:
    """The GLB bytes of a scene in its world frame: the table top (top at z = 0), the objects at their settled poses,
    and at most ``n`` markers at the grasps' world poses coloured by rollout outcome (by pre-filter code without
    ``rollouts``), in the colours of :data:`graspgen.viz.grasp_view.LABELS`; ``objects`` maps a name to its record.

    Raises
    ------
    ValueError
        ``rollouts`` not matching ``grasps``.
    """
    codes, source = grasp_labels(grasps, rollouts)
    labels = LABELS[source]
    rows = np.arange(len(grasps)) if n is None else choose_grasps(codes, n, list(labels))
    if gripper is None and len(grasps):
        gripper = grasps.column("gripper")[0].as_py()
    records = {name: objects(name) for name in dict.fromkeys(scene.object_names)}
    placed = [(f"{i}_{name}", records[name].vertices, records[name].faces, scene.poses[i])
              for i, name in enumerate(scene.object_names)]
    sx, sy = scene.support.size
    top = trimesh.creation.box(extents=(sx, sy, 0.01))
    top.visual.face_colors = np.asarray(SUPPORT_COLOUR, dtype=np.uint8)
    under = np.eye(4)
    under[2, 3] = -0.005
    colours = {code: (name, (*rgb, 255)) for code, (name, rgb) in labels.items()}
    return labelled_grasps_glb(placed, column_array(grasps, "pose_world", (4, 4))[rows], codes[rows], colours,
                               gripper=gripper, grasp_ids=grasps.column("grasp_id").to_numpy()[rows],
                               extra=[("support", top, under)])


def write_glb(path: str | Path, data: bytes) -> None:
    """Write GLB bytes to ``path`` atomically (the folder is made when missing)."""
    with atomic_path(Path(path)) as tmp:
        tmp.write_bytes(data)
