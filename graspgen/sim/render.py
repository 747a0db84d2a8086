"""Headless rendering of a scene model with MuJoCo: RGB, depth and segmentation from any
:class:`~graspgen.sim.camera.Camera`.

Images: depth is float32 metres along the optical axis (the camera-frame z, not the ray length), **0 where
nothing was hit**; segmentation is int16 with the object index (0..n-1) for objects and the negative codes
:data:`~graspgen.sim.scene_model.SEG_BACKGROUND` (-1, nothing), :data:`~graspgen.sim.scene_model.SEG_SUPPORT`
(-2) and :data:`~graspgen.sim.scene_model.SEG_GROUND` (-3). The camera model (OpenCV convention) is
:mod:`graspgen.sim.camera`.

Shadows and reflections are off; lighting is a headlight plus one directional light. MuJoCo picks its OpenGL
backend from the environment variable ``MUJOCO_GL`` when it is first imported:
``egl`` (needs ``libEGL`` and Mesa: Debian/Ubuntu ``libegl1 libgl1-mesa-dri``; Mesa's llvmpipe renders on the
CPU, no GPU needed) or ``osmesa`` (``libosmesa6``). :func:`graspgen.sim.gl.select_backend` chooses it before
this module imports mujoco (``egl`` when libEGL loads, else ``osmesa`` when libOSMesa loads, else nothing), so
importing this module never needs OpenGL; :class:`SceneRenderer` raises :class:`~graspgen.errors.RenderError`
in one line when no back end can render. Image bytes are deterministic for one GL implementation (Mesa
llvmpipe here: the same view renders to the same bytes whatever was rendered before, in any process); another
driver (a GPU's EGL) may differ in the last bit of some pixels, and so in the shard bytes.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence

from graspgen.sim.gl import HOW_TO_FIX, backend_in_use, render_problem, select_backend

select_backend()  # MuJoCo reads MUJOCO_GL once, at its first import: choose a headless back end before that.

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from graspgen.errors import RenderError, SettingsError  # noqa: E402
from graspgen.sim.camera import Camera  # noqa: E402
from graspgen.sim.scene_model import SEG_BACKGROUND  # noqa: E402
from graspgen.sim.scene_state import geom_labels  # noqa: E402

__all__ = ["RenderedView", "SceneRenderer", "render_frames"]


def _gl_backend_note() -> str:
    """What MUJOCO_GL says and which backend mujoco actually loaded (it reads the variable once, at import)."""
    env = os.environ.get("MUJOCO_GL")
    used = backend_in_use()
    if used != (env or "").lower().strip():
        return (
            f"MUJOCO_GL={env!r} now, but mujoco was imported when it was {used or 'unset'!r} and uses that "
            "backend: set MUJOCO_GL in the environment before Python starts"
        )
    return f"MUJOCO_GL={env!r}"


@dataclasses.dataclass(frozen=True, eq=False)
class RenderedView:
    """Images of one camera view."""

    rgb: np.ndarray | None
    """(H, W, 3) uint8, or None when not asked for."""
    depth: np.ndarray
    """(H, W) float32 metres along the optical axis; 0 where nothing was hit."""
    segmentation: np.ndarray
    """(H, W) int16: object index, or SEG_BACKGROUND / SEG_SUPPORT / SEG_GROUND."""


class SceneRenderer:
    """Renders RGB, depth and segmentation of a scene model from arbitrary :class:`Camera` s, headless.

    One OpenGL context per instance; use it as a context manager (or call :meth:`close`). Shadows and
    reflections are off (they cost more than the rest of a frame and carry no information for learning).

    Parameters
    ----------
    model : mujoco.MjModel
        From :func:`graspgen.sim.scene_model.build_scene_spec` (its offscreen buffer must be at least ``width`` x
        ``height``).
    width, height : int
        Image size, pixels.

    Raises
    ------
    RenderError
        When no offscreen OpenGL context can be made; the message says what to install or set.
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int):
        self.model = model
        self.width, self.height = int(width), int(height)
        self._renderer = None
        problem = render_problem()  # no usable back end: say so before mujoco tries (it may crash without one)
        if problem is not None:
            raise RenderError(problem)
        try:
            self._renderer = mujoco.Renderer(model, self.height, self.width)
        except ValueError as exc:  # image larger than the model's offscreen buffer: MuJoCo's message says so
            raise SettingsError(f"width, height: {exc}") from exc
        except Exception as exc:  # noqa: BLE001 - GL failures surface as many types (ImportError, FatalError...)
            detail = " ".join(f"{type(exc).__name__}: {exc}".split())  # one line
            raise RenderError(
                f"cannot create an offscreen OpenGL context ({_gl_backend_note()}): {detail}; {HOW_TO_FIX}"
            ) from exc
        scene = self._renderer.scene
        scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        self._option = mujoco.MjvOption()  # default: groups 0-2 visible, so the collision parts (3) are hidden
        self._labels = geom_labels(model)

    def __enter__(self) -> SceneRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if getattr(self, "_renderer", None) is not None:
            self._renderer.close()
            self._renderer = None

    def render(self, data: mujoco.MjData, camera: Camera, *, rgb: bool = True) -> RenderedView:
        """Images of the state ``data`` (``mj_forward`` must have run) seen by ``camera``."""
        if (camera.width, camera.height) != (self.width, self.height):
            raise SettingsError(
                f"camera: image size {camera.width}x{camera.height} differs from the renderer's "
                f"{self.width}x{self.height}"
            )
        r = self._renderer
        r.update_scene(data, camera=-1, scene_option=self._option)
        self._set_gl_camera(camera)
        r.enable_segmentation_rendering()
        seg = r.render()
        r.enable_depth_rendering()
        depth = r.render()
        r.disable_depth_rendering()
        color = r.render().copy() if rgb else None
        hit = seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)
        ids = np.where(hit, seg[..., 0], 0)
        labels = np.where(hit, self._labels[np.clip(ids, 0, len(self._labels) - 1)], SEG_BACKGROUND)
        depth = np.where(seg[..., 0] >= 0, depth, 0.0).astype(np.float32)
        return RenderedView(rgb=color, depth=depth, segmentation=labels.astype(np.int16))

    def _set_gl_camera(self, camera: Camera) -> None:
        """Point MuJoCo's OpenGL camera(s) along ``camera`` and set the frustum from its K exactly.

        OpenGL looks along -z with y up: forward = OpenCV z, up = -OpenCV y. The frustum at the near plane n
        spans u in [-0.5, W - 0.5] and v in [-0.5, H - 0.5] (pixel edges), v growing downwards.
        """
        T = np.asarray(camera.T_world_camera, dtype=float)
        K = np.asarray(camera.K, dtype=float)
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        extent = self.model.stat.extent
        near = self.model.vis.map.znear * extent  # the renderer's depth conversion assumes these planes
        far = self.model.vis.map.zfar * extent
        left = near * (-0.5 - cx) / fx
        right = near * (self.width - 0.5 - cx) / fx
        top = near * (cy + 0.5) / fy
        bottom = -near * (self.height - 0.5 - cy) / fy
        # Both eyes identical: mjr_render averages the stereo pair, which would otherwise be offset by +-ipd/2.
        for gl in self._renderer.scene.camera:
            gl.pos[:] = T[:3, 3]
            gl.forward[:] = T[:3, 2]
            gl.up[:] = -T[:3, 1]
            gl.frustum_near = near
            gl.frustum_far = far
            gl.frustum_center = (left + right) / 2
            gl.frustum_width = (right - left) / 2
            gl.frustum_top = top
            gl.frustum_bottom = bottom
            gl.orthographic = 0


def _blocked(model: mujoco.MjModel, data: mujoco.MjData, camera: Camera, point: np.ndarray, target: int) -> bool:
    """Whether something other than the target object and the gripper lies between the camera and ``point``."""
    eye = np.asarray(camera.T_world_camera, dtype=float)[:3, 3]
    ray = np.asarray(point, dtype=float) - eye
    length = float(np.linalg.norm(ray))
    groups = np.array([1, 1, 0, 0, 0, 0], dtype=np.uint8)  # support and visual meshes; not the gripper (group 2)
    hit = mujoco.mj_ray(model, data, eye, ray / length, groups, 1, target, np.zeros(1, dtype=np.int32))
    return 0.0 <= hit < length - 0.01


def render_frames(
    spec: mujoco.MjSpec,
    qpos: Sequence[np.ndarray],
    cameras: Sequence[Camera],
    *,
    target_body: str | None = None,
    point: np.ndarray | None = None,
) -> list[np.ndarray]:
    """RGB images of a model posed at each of ``qpos``, from one camera.

    Parameters
    ----------
    spec
        The world to draw (a visual model with the simulator's joints, e.g.
        :func:`graspgen.sim.object_world.world_spec` with ``visual``); its offscreen buffer is enlarged to the
        cameras' size, then it is compiled.
    qpos
        ``(nq,) float64`` joint positions, one per image.
    cameras
        Candidate cameras, all of one size, best first.
    target_body, point
        With both: the first camera whose line of sight to ``point (3,)`` (world, m) is clear in the first pose,
        ignoring ``target_body`` and the gripper, is used (``cameras[0]`` when none is); else ``cameras[0]``.

    Returns
    -------
    list of (H, W, 3) uint8

    Raises
    ------
    SettingsError
        A ``qpos`` of another length than the model's, or images larger than the model's buffer.
    RenderError
        No OpenGL back end can render in this process.
    """
    camera = cameras[0]
    spec.visual.global_.offwidth = max(int(spec.visual.global_.offwidth), camera.width)
    spec.visual.global_.offheight = max(int(spec.visual.global_.offheight), camera.height)
    model = spec.compile()
    for q in qpos:
        if q.shape != (model.nq,):
            raise SettingsError(f"frames: qpos has {q.shape[0]} entries, the model {model.nq}")
    if target_body is not None and point is not None:
        data = mujoco.MjData(model)
        data.qpos[:] = qpos[0]
        mujoco.mj_forward(model, data)
        target = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, target_body)
        camera = next((c for c in cameras if not _blocked(model, data, c, point, target)), cameras[0])
    data = mujoco.MjData(model)
    images = []
    with SceneRenderer(model, camera.width, camera.height) as renderer:
        for q in qpos:
            data.qpos[:] = q
            mujoco.mj_forward(model, data)
            images.append(renderer.render(data, camera, rgb=True).rgb)
    return images
