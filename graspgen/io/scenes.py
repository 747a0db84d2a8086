"""Scene records: reading a scene's HDF5 file (object poses, support, cameras, images, point clouds)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Literal

import numpy as np  # noqa: E402

import graspgen.sim.gl  # noqa: F401 - imported first: chooses MUJOCO_GL before anything imports mujoco
from graspgen.errors import InputError  # noqa: E402
from graspgen.io.files import read_h5  # noqa: E402
from graspgen.sim.camera import Camera, backproject, transform_points  # noqa: E402
from graspgen.sim.scene_model import SEG_GROUND  # noqa: E402
from graspgen.sim.support import SupportParams  # noqa: E402
from graspgen.validation import check_choice, check_int  # noqa: E402


@dataclasses.dataclass(frozen=True, eq=False)
class SceneRecord:
    """A scene shard read back (see the module docstring for shapes and conventions)."""

    scene_id: str
    object_names: list[str]
    """By scene index."""
    object_keys: list[str]
    """Keys of the objects stage's shards, by scene index."""
    poses: np.ndarray
    """(n, 4, 4) settled mesh-to-world poses."""
    friction: np.ndarray
    """(n,) sliding friction per object."""
    support: SupportParams
    cameras: list[Camera]
    rgb: np.ndarray | None
    """(v, H, W, 3) uint8 or None."""
    depth: np.ndarray | None
    """(v, H, W) float32 m, 0 = no return, or None."""
    segmentation: np.ndarray | None
    """(v, H, W) int16 or None."""
    depth_noisy: np.ndarray | None
    clouds: dict[str, np.ndarray] | None
    attrs: dict[str, Any]
    tree: dict[str, Any]
    """The whole shard as read by :func:`graspgen.io.files.read_h5`."""

    def cloud(self, view: int, frame: Literal["world", "camera"] = "world") -> tuple[np.ndarray, np.ndarray]:
        """(points (N, 3) float32, ids (N,) int16) of one view's object and support points in ``frame``.

        From the stored cloud (transformed by the view's extrinsics when only the other frame is stored), else
        back-projected from the depth image.
        """
        check_int("view", view, low=0, high=len(self.cameras) - 1)
        check_choice("frame", frame, ("world", "camera"))
        T = np.asarray(self.cameras[view].T_world_camera, dtype=float)
        to_frame = {"world": {"world": None, "camera": T}, "camera": {"camera": None, "world": np.linalg.inv(T)}}
        if self.clouds is not None:
            a, b = self.clouds["view_offsets"][view : view + 2]
            for stored in (frame, "camera" if frame == "world" else "world"):
                if f"points_{stored}" in self.clouds:
                    pts = self.clouds[f"points_{stored}"][a:b]
                    T_conv = to_frame[frame][stored]
                    if T_conv is not None:
                        pts = transform_points(T_conv, pts).astype(np.float32)
                    return pts, self.clouds["ids"][a:b]
        if self.depth is None or self.segmentation is None:
            raise InputError(f"{self.scene_id}: the shard has no images (cameras.render was false)")
        cam = self.cameras[view]
        valid = (self.depth[view] > 0) & (self.segmentation[view] != SEG_GROUND)
        pts = backproject(self.depth[view], cam.K)[valid]
        if frame == "world":
            pts = transform_points(T, pts)
        return pts.astype(np.float32), self.segmentation[view][valid]


def read_scene(path: str | Path) -> SceneRecord:
    """Read a scene shard written by the ``scenes`` stage."""
    tree = read_h5(path)
    attrs = tree["@attrs"]
    support = attrs["support"]
    support = SupportParams(**{k: tuple(v) if isinstance(v, list) else v for k, v in support.items()})
    cams = tree["cameras"]
    width, height = int(cams["@attrs"]["width"]), int(cams["@attrs"]["height"])
    cameras = [Camera(K, T, width, height) for K, T in zip(cams["K"], cams["T_world_camera"])]
    images = tree.get("images", {})
    return SceneRecord(
        scene_id=attrs["scene_id"],
        object_names=list(attrs["object_names"]),
        object_keys=list(attrs["object_keys"]),
        poses=tree["objects"]["poses"],
        friction=tree["objects"]["friction"],
        support=support,
        cameras=cameras,
        rgb=images.get("rgb"),
        depth=images.get("depth"),
        segmentation=images.get("segmentation"),
        depth_noisy=images.get("depth_noisy"),
        clouds=tree.get("clouds"),
        attrs=attrs,
        tree=tree,
    )
