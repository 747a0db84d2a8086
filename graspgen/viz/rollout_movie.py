"""Looking at rollouts: re-run one grasp of a scene and render frames of it, to see why it failed.

:func:`rollout_movie` re-runs a grasp exactly as the rollouts stage did (the same compiled scene from
:func:`graspgen.workflows.rollouts.scene_simulator`, the same :class:`graspgen.sim.protocols.LiftParams`), records the
state at every rule check through the simulator's ``observer`` hook, keeps a few of those states (:func:`pick_frames`:
the start, the end of every phase reached, then evenly spaced ones) and renders them from a side camera
(:func:`side_cameras`) with MuJoCo's renderer. :func:`save_movie` writes a PNG strip or an animated GIF with the
outcome in the title. ``gen show rollout SCENE_ID GRASP_ID -o file.png|gif`` is the command line for it.

Rendering uses a second model of the same scene built with the objects' visual meshes (the simulation model has
only their convex parts, which the renderer hides); both have the same joints, so a recorded ``qpos`` poses either.
The physics is therefore untouched by rendering: the re-run gives the stored outcome bit for bit (a rollout depends
only on the model and its inputs, :mod:`graspgen.sim.lift`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from graspgen.errors import SettingsError
from graspgen.sim.gl import select_backend

select_backend()  # Rendering needs a headless GL backend; MuJoCo reads MUJOCO_GL when first imported.

import numpy as np  # noqa: E402
import pyarrow as pa  # noqa: E402

from graspgen.grippers import load_gripper  # noqa: E402
from graspgen.io.arrow import column_array  # noqa: E402
from graspgen.sim.camera import Camera, camera_on_sphere, intrinsics_from_fov  # noqa: E402
from graspgen.sim.gripper_model import attach_gripper  # noqa: E402
from graspgen.sim.lift import LiftSimulator  # noqa: E402
from graspgen.sim.protocols import LiftParams, RolloutResult  # noqa: E402
from graspgen.sim.render import render_frames  # noqa: E402
from graspgen.sim.scene_model import object_body_name, scene_spec  # noqa: E402
from graspgen.workflows.rollouts import scene_simulator  # noqa: E402
from graspgen.workflows.scene_grasps import PREFILTER_NAMES  # noqa: E402

__all__ = [
    "Frame",
    "RolloutMovie",
    "record_rollout",
    "pick_frames",
    "side_cameras",
    "rollout_movie",
    "save_movie",
]

_LABEL_H = 14
"""Height (px) of the text line under each frame."""
_TITLE_H = 18
"""Height (px) of the title line."""
_PAD = 4
"""Gap (px) between frames and around the strip."""


@dataclasses.dataclass(frozen=True, eq=False)
class Frame:
    """The simulation state at one rule check of a rollout."""

    phase: str
    """Protocol phase (:data:`graspgen.sim.protocols.PHASES`) the state was recorded in."""
    step: int
    """Steps simulated so far in the rollout."""
    time: float
    """Simulated time so far, s."""
    qpos: np.ndarray
    """``(nq,) float64`` joint positions (objects and gripper)."""


@dataclasses.dataclass(frozen=True, eq=False)
class RolloutMovie:
    """Frames of one re-run rollout, ready to save."""

    images: list[np.ndarray]
    """``(H, W, 3) uint8`` RGB per frame."""
    labels: list[str]
    """One caption per frame (phase and time)."""
    title: str
    """Scene, grasp, object, outcome."""
    result: RolloutResult
    """The re-run's result."""
    stored_outcome: int | None
    """The outcome in the rollouts table (None when no table was given)."""
    simulated: bool
    """Whether the rollouts stage simulated this grasp (False: the pre-filter labelled it; re-run anyway here)."""


def record_rollout(simulator: LiftSimulator, T_world_tcp: np.ndarray, width: float,
                   target_body: str) -> tuple[RolloutResult, list[Frame]]:
    """Roll one grasp out and record the state at every rule check (the observer calls: after placement and every
    ``check_interval`` steps). Recording reads the state only, so the result is the unobserved one."""
    frames: list[Frame] = []
    dt = float(simulator.model.opt.timestep)

    def observe(phase: str, steps: int) -> None:
        frames.append(Frame(phase, int(steps), steps * dt, simulator.data.qpos.copy()))

    result = simulator.rollout(T_world_tcp, width, target_body, observer=observe)
    return result, frames


def pick_frames(frames: Sequence[Frame], n: int) -> list[Frame]:
    """At most ``n`` of ``frames``, in time order: the first, the last of every phase, then those farthest in time
    from the frames already kept.

    When the phase ends alone are more than ``n``, the first and the last frame are kept and the rest thinned
    evenly. The result has ``min(n, len(frames))`` frames.
    """
    if n < 1:
        raise SettingsError(f"n: must be >= 1, got {n}")
    count = len(frames)
    if count <= n:
        return list(frames)
    keys = {0} | {i for i in range(count) if i == count - 1 or frames[i + 1].phase != frames[i].phase}
    if len(keys) > n:
        inner = sorted(keys - {0, count - 1})
        take = np.linspace(0, len(inner) - 1, n - 2).round().astype(int) if n > 2 else []
        keys = {0, count - 1} | {inner[i] for i in take} if n > 1 else {count - 1}
    else:
        # Fill up with the frames farthest in time from those already kept (greedy; ties: the earliest).
        steps = np.array([f.step for f in frames], dtype=float)
        while len(keys) < n:
            kept = np.array(sorted(keys))
            gap = np.abs(steps[:, None] - steps[kept][None, :]).min(axis=1)
            gap[kept] = -1.0
            keys.add(int(np.argmax(gap)))
    return [frames[i] for i in sorted(keys)]


def side_cameras(T_world_tcp: np.ndarray, lift_height: float, *, width: int = 320, height: int = 240,
                 distance: float = 0.55, elevation: float = math.radians(15.0)) -> list[Camera]:
    """Cameras looking at a grasp from the side, framing the grasp and the lift above it, best first.

    The first looks along the TCP's y axis (perpendicular to the approach and closing axes, so the jaws are seen
    closing left-right), levelled to the horizontal and raised by ``elevation`` (rad); the second from the opposite
    side; then two along the approach axis (levelled), useful when the y axis is nearly vertical (it is then left
    out). Each is aimed at the grasp point raised by half ``lift_height`` (m), from ``distance`` (m), with a 45
    degree vertical field of view. :func:`rollout_movie` takes the first whose view of the grasp is not blocked.
    """
    T = np.asarray(T_world_tcp, dtype=float)
    target = T[:3, 3] + np.array([0.0, 0.0, lift_height / 2.0])
    K = intrinsics_from_fov(width, height, math.radians(45.0))
    cameras = []
    for axis in (T[:3, 1], -T[:3, 1], T[:3, 2], -T[:3, 2]):
        view = np.array([axis[0], axis[1], 0.0])
        if np.linalg.norm(view) < 0.3:  # nearly vertical: a levelled view along it would be arbitrary
            continue
        azimuth = math.atan2(-view[1], -view[0])  # the camera sits at -view from the target, looking along +view
        cameras.append(Camera(K, camera_on_sphere(target, distance, elevation, azimuth), width, height))
    if not cameras:  # y and z both (nearly) vertical cannot happen for a rotation; guard anyway
        cameras.append(Camera(K, camera_on_sphere(target, distance, elevation, 0.0), width, height))
    return cameras


def rollout_movie(
    scene_path: str | Path,
    load_object: Callable[[str], Any],
    grasps: pa.Table,
    grasp_id: int,
    lift: LiftParams,
    *,
    rollouts: pa.Table | None = None,
    n_frames: int = 6,
    size: tuple[int, int] = (320, 240),
) -> RolloutMovie:
    """Re-run grasp ``grasp_id`` of a scene and render ``n_frames`` frames of it.

    Parameters
    ----------
    scene_path : str or Path
        The scene shard.
    load_object : callable
        ``name -> ObjectRecord`` (as the rollouts stage loads them).
    grasps : pyarrow.Table
        The scene's grasps table.
    grasp_id : int
        Row id in it.
    lift : LiftParams
        The protocol the rollouts were made with (config ``rollouts.lift``).
    rollouts : pyarrow.Table, optional
        The scene's rollouts table, for the stored outcome.
    n_frames : int
        At most this many frames (:func:`pick_frames`).
    size : (width, height)
        Frame size, pixels.
    """
    ids = grasps.column("grasp_id").to_numpy()
    rows = np.flatnonzero(ids == grasp_id)
    if len(rows) == 0:
        hint = f"0..{len(ids) - 1}" if len(ids) else "none"
        raise SettingsError(f"grasp_id: the scene has no grasp {grasp_id} (its grasp ids: {hint})")
    row = int(rows[0])
    gripper = grasps.column("gripper")[row].as_py()
    scene, simulator = scene_simulator(Path(scene_path), load_object, gripper, lift)
    index = int(grasps.column("object_index")[row].as_py())
    name = scene.object_names[index]
    T = column_array(grasps, "pose_world", (4, 4))[row]
    width = float(grasps.column("width")[row].as_py())
    result, states = record_rollout(simulator.cpu, T, width, object_body_name(index, name))
    frames = pick_frames(states, n_frames)

    # The same scene with visual meshes, for the renderer, filmed by the first side camera whose line of sight to
    # the grasp point is clear (a neighbour may hide the grasp).
    records = {n: load_object(n) for n in sorted(set(scene.object_names))}
    spec = scene_spec(scene, records, visual=True)
    attach_gripper(spec, load_gripper(gripper))
    cameras = side_cameras(T, lift.lift_height, width=size[0], height=size[1])
    images = render_frames(spec, [f.qpos for f in frames], cameras, target_body=object_body_name(index, name),
                           point=T[:3, 3])

    stored, simulated = None, True
    if rollouts is not None:
        r = int(np.flatnonzero(rollouts.column("grasp_id").to_numpy() == grasp_id)[0])
        stored = int(rollouts.column("outcome")[r].as_py())
        simulated = bool(rollouts.column("simulated")[r].as_py())
    title = f"{scene.scene_id} grasp {grasp_id} ({name}): {result.name} ({result.code}), decided in {result.decided_in}"
    if not simulated:
        pre = int(grasps.column("prefilter_code")[row].as_py())
        title += f"; dataset label from the pre-filter: {PREFILTER_NAMES[pre]} ({pre})"
    elif stored is not None:
        title += f"; stored outcome {stored}" + (" (DIFFERS)" if stored != result.code else " (same)")
    labels = [f"{f.phase} t={f.time:.2f} s" for f in frames]
    return RolloutMovie(images, labels, title, result, stored, simulated)


def _composite(image: np.ndarray, label: str, title: str | None):
    """One frame as a PIL image with its caption below (and the title above, for GIF frames)."""
    from PIL import Image, ImageDraw

    h, w = image.shape[:2]
    top = _TITLE_H if title is not None else 0
    canvas = Image.new("RGB", (w, top + h + _LABEL_H), (255, 255, 255))
    draw = ImageDraw.Draw(canvas)
    if title is not None:
        draw.text((2, 3), title, fill=(0, 0, 0))
    canvas.paste(Image.fromarray(image), (0, top))
    draw.text((2, top + h + 1), label, fill=(0, 0, 0))
    return canvas


def save_movie(movie: RolloutMovie, path: str | Path, *, frame_ms: int = 600) -> Path:
    """Write ``movie`` as a PNG strip (frames left to right under the title) or an animated GIF, by suffix.

    The PNG carries text chunks ``frames`` (count), ``outcome`` and ``title``; the GIF has one frame per image,
    ``frame_ms`` each, looping, with the title on every frame.

    Raises
    ------
    ValueError
        A suffix other than ``.png`` or ``.gif``.
    """
    from PIL import Image, ImageDraw
    from PIL.PngImagePlugin import PngInfo

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".png", ".gif"):
        raise SettingsError(f"{path}: unsupported image type {path.suffix or '(none)'!r}; use .png or .gif")
    if not movie.images:
        raise SettingsError("movie: no frames to save")
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".gif":
        frames = [_composite(img, lab, movie.title) for img, lab in zip(movie.images, movie.labels)]
        # Adaptive palettes per frame; disposal 2 so each frame fully replaces the last.
        frames[0].save(path, save_all=True, append_images=frames[1:], duration=frame_ms, loop=0, disposal=2,
                       optimize=False)
        return path
    h, w = movie.images[0].shape[:2]
    n = len(movie.images)
    sheet = Image.new("RGB", (n * (w + _PAD) + _PAD, _TITLE_H + h + _LABEL_H + 2 * _PAD), (255, 255, 255))
    ImageDraw.Draw(sheet).text((_PAD, 3), movie.title, fill=(0, 0, 0))
    for k, (img, lab) in enumerate(zip(movie.images, movie.labels)):
        sheet.paste(_composite(img, lab, None), (_PAD + k * (w + _PAD), _TITLE_H + _PAD))
    info = PngInfo()
    info.add_text("frames", str(n))
    info.add_text("outcome", str(movie.result.code))
    info.add_text("title", movie.title)
    sheet.save(path, pnginfo=info)
    return path
