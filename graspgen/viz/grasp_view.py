"""Grasps drawn on a scene's camera image: the picture behind ``gen show grasps``.

Each grasp is a parallel-jaw "fork" in its TCP frame (fingers at ``x = -+open_width / 2`` over the pad length,
a palm bar, a stem back along -z), projected with the view's :class:`~graspgen.sim.camera.Camera` and drawn with
Pillow on the upscaled RGB image, coloured by outcome code (with a rollouts table) or by pre-filter code
(:data:`LABELS`). Pure functions of their arguments.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pyarrow as pa
from PIL import Image, ImageDraw, ImageFont

from graspgen.errors import SettingsError
from graspgen.grippers import GripperSpec, load_gripper
from graspgen.io.arrow import column_array
from graspgen.io.scenes import SceneRecord
from graspgen.sim.camera import Camera, project, transform_points

__all__ = [
    "MARKER_SEGMENTS",
    "LABELS",
    "NEAR_CLIP",
    "grasp_marker_segments",
    "segment_pixels",
    "draw_grasps",
    "grasp_labels",
    "rollouts_match",
    "choose_grasps",
    "grasp_picture",
]

MARKER_SEGMENTS = 4
"""Segments per marker: left finger, right finger, palm bar, stem."""

NEAR_CLIP = 1e-3
"""Segments are clipped to camera-frame depth z >= this (m) before projecting: a point behind the camera has no
image, and one just in front of it projects arbitrarily far away."""

_GREEN, _ORANGE, _YELLOW, _BLUE = (40, 200, 60), (255, 140, 0), (250, 225, 0), (40, 120, 255)
_DARK_RED, _RED, _PINK_RED = (150, 0, 20), (235, 30, 30), (255, 110, 130)

LABELS: dict[str, dict[int, tuple[str, tuple[int, int, int]]]] = {
    "rollouts": {
        5: ("success", _GREEN),
        4: ("slipped_during_lifting", _ORANGE),
        3: ("no_contact_established", _YELLOW),
        0: ("collision_with_ground", _DARK_RED),
        1: ("collision_with_target", _RED),
        2: ("collision_with_clutter", _PINK_RED),
    },
    "prefilter": {
        -1: ("free", _BLUE),
        0: ("collision_with_ground", _DARK_RED),
        1: ("collision_with_target", _RED),
        2: ("collision_with_clutter", _PINK_RED),
    },
}
"""Label source -> code -> (name, RGB colour); each dict's order is the priority: first in the legend, first served by
:func:`choose_grasps`, drawn on top."""


# ---------------------------------------------------------------------------------------------------------------
# Geometry
# ---------------------------------------------------------------------------------------------------------------


def grasp_marker_segments(T_world: np.ndarray, open_width: np.ndarray, gripper: GripperSpec) -> np.ndarray:
    """World-frame segments (m) of each grasp's fork marker: (n, MARKER_SEGMENTS, 2, 3) float64, left finger (tip,
    back), right finger, palm bar, stem, from TCP poses ``T_world`` (n, 4, 4), openings ``open_width`` (n,) m and the
    gripper's pad length."""
    T = np.asarray(T_world, dtype=float)
    w = np.asarray(open_width, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise SettingsError(f"T_world: must have shape (n, 4, 4), got {T.shape}")
    if w.shape != (len(T),):
        raise SettingsError(f"open_width: must have shape ({len(T)},) like T_world, got {w.shape}")
    half_len = gripper.pad_size[2] / 2.0
    h = w / 2.0
    zero = np.zeros_like(h)
    tip, back = np.full_like(h, half_len), np.full_like(h, -half_len)
    local = np.stack(
        [
            np.stack([np.stack([-h, zero, tip], -1), np.stack([-h, zero, back], -1)], 1),
            np.stack([np.stack([h, zero, tip], -1), np.stack([h, zero, back], -1)], 1),
            np.stack([np.stack([-h, zero, back], -1), np.stack([h, zero, back], -1)], 1),
            np.stack([np.stack([zero, zero, back], -1), np.stack([zero, zero, back - 2 * half_len], -1)], 1),
        ],
        axis=1,
    )  # (n, 4, 2, 3) in the TCP frame
    return np.einsum("nij,nsej->nsei", T[:, :3, :3], local) + T[:, None, None, :3, 3]


def segment_pixels(camera: Camera, segments: np.ndarray, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Image coordinates of world-frame segments ``(..., 2, 3)`` seen by ``camera``, clipped to the near plane.

    Returns
    -------
    uv : (..., 2, 2) float64
        (column, row) of both end points in the image upscaled by ``scale``; NaN where the whole segment is behind
        :data:`NEAR_CLIP`.
    visible : (...) bool
        Whether any part of the segment lies in front of the camera.
    """
    seg = np.asarray(segments, dtype=float)
    if seg.shape[-2:] != (2, 3):
        raise SettingsError(f"segments: must have shape (..., 2, 3), got {seg.shape}")
    p = transform_points(np.linalg.inv(np.asarray(camera.T_world_camera, dtype=float)), seg)
    a, b = p[..., 0, :], p[..., 1, :]
    za, zb = a[..., 2:3], b[..., 2:3]
    visible = (za[..., 0] >= NEAR_CLIP) | (zb[..., 0] >= NEAR_CLIP)
    # Move an end point behind the near plane along the segment onto it (only where the other end is in front).
    with np.errstate(divide="ignore", invalid="ignore"):
        t_a = np.where(za < NEAR_CLIP, (NEAR_CLIP - za) / (zb - za), 0.0)
        t_b = np.where(zb < NEAR_CLIP, (NEAR_CLIP - zb) / (za - zb), 0.0)
    a_clip = a + np.clip(np.nan_to_num(t_a), 0.0, 1.0) * (b - a)
    b_clip = b + np.clip(np.nan_to_num(t_b), 0.0, 1.0) * (a - b)
    clipped = np.stack([a_clip, b_clip], axis=-2)
    clipped[..., 2] = np.maximum(clipped[..., 2], NEAR_CLIP)  # round-off of the crossing point
    uv = scale * (project(camera.K, clipped) + 0.5) - 0.5
    uv[~visible] = np.nan
    return uv, visible


def _clip_segments(uv: np.ndarray, limit: float) -> tuple[np.ndarray, np.ndarray]:
    """Segments ``(..., 2, 2)`` cut to the square ``[-limit, limit]^2`` (Liang-Barsky): (clipped end points, whether
    any part is inside). NaN segments are outside."""
    a, d = uv[..., 0, :], uv[..., 1, :] - uv[..., 0, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_low, t_high = (-limit - a) / d, (limit - a) / d
    t_in = np.where(d == 0, np.where(np.abs(a) <= limit, -np.inf, np.inf), np.minimum(t_low, t_high))
    t_out = np.where(d == 0, np.where(np.abs(a) <= limit, np.inf, -np.inf), np.maximum(t_low, t_high))
    t0 = np.maximum(0.0, t_in.max(axis=-1))
    t1 = np.minimum(1.0, t_out.min(axis=-1))
    inside = (t0 <= t1) & np.isfinite(uv).all(axis=(-1, -2))
    t0, t1 = np.where(inside, t0, 0.0), np.where(inside, t1, 0.0)  # outside: the inf bounds are not used
    clipped = np.stack([a + t0[..., None] * d, a + t1[..., None] * d], axis=-2)
    return np.where(inside[..., None, None], clipped, np.nan), inside


def draw_grasps(
    rgb: np.ndarray,
    camera: Camera,
    segments: np.ndarray,
    colours: Sequence[Sequence[int]] | np.ndarray,
    *,
    scale: int = 3,
    line_width: int | None = None,
    outline: bool = True,
) -> Image.Image:
    """The image ``rgb`` (H, W, 3) uint8 upscaled by ``scale`` (nearest neighbour) with each marker ``segments``
    (n, s, 2, 3) drawn in ``colours`` (n, 3), later on top: a PIL RGB image of ``(W scale, H scale)``. ``camera`` must
    be the one that took ``rgb``; ``outline`` draws each marker first in black, 2 pixels wider."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise SettingsError(f"rgb: must be an (H, W, 3) uint8 image, got {rgb.shape} {rgb.dtype}")
    if (camera.width, camera.height) != (rgb.shape[1], rgb.shape[0]):
        raise SettingsError(f"camera: image size {camera.width}x{camera.height} differs from rgb's "
                            f"{rgb.shape[1]}x{rgb.shape[0]}")
    if not (isinstance(scale, (int, np.integer)) and scale >= 1):
        raise SettingsError(f"scale: must be a positive integer, got {scale!r}")
    seg = np.asarray(segments, dtype=float)
    if seg.ndim != 4 or seg.shape[2:] != (2, 3):
        raise SettingsError(f"segments: must have shape (n, s, 2, 3), got {seg.shape}")
    cols = np.asarray(colours, dtype=int).reshape(-1, 3) if len(seg) else np.zeros((0, 3), dtype=int)
    if len(cols) != len(seg):
        raise SettingsError(f"colours: need one RGB colour per grasp ({len(seg)}), got {len(cols)}")
    width = max(1, scale - 1) if line_width is None else int(line_width)
    h, w = rgb.shape[:2]
    image = Image.fromarray(rgb).resize((w * scale, h * scale), Image.Resampling.NEAREST)
    draw = ImageDraw.Draw(image)
    uv, visible = segment_pixels(camera, seg, scale)
    # Points near the camera plane project arbitrarily far, and Pillow walks a 1-pixel line pixel by pixel (seconds
    # for 1e9 pixels): cut every segment to a box around the image first, along the segment.
    uv, inside = _clip_segments(uv, 2.0 * max(w, h) * scale)
    visible &= inside
    # Round to the nearest pixel centre ourselves: Pillow truncates float coordinates, which would shift an end point
    # that lands a hair below an integer by a whole pixel.
    uv = np.floor(np.nan_to_num(uv) + 0.5).astype(np.int64)
    for i in range(len(seg)):
        passes = [((0, 0, 0), width + 2)] if outline else []
        passes.append((tuple(int(c) for c in cols[i]), width))
        for fill, lw in passes:
            for k in np.flatnonzero(visible[i]):
                (u0, v0), (u1, v1) = uv[i, k]
                draw.line([(int(u0), int(v0)), (int(u1), int(v1))], fill=fill, width=lw)
    return image


# ---------------------------------------------------------------------------------------------------------------
# Labels and choice
# ---------------------------------------------------------------------------------------------------------------


def rollouts_match(grasps: pa.Table, rollouts: pa.Table) -> bool:
    """Whether ``rollouts`` is the rollouts table of ``grasps``: the same grasp ids in order, and every grasp the
    rollouts did not simulate labelled with its pre-filter code (as the rollouts stage does)."""
    if len(grasps) != len(rollouts):
        return False
    if grasps.column("grasp_id").to_pylist() != rollouts.column("grasp_id").to_pylist():
        return False
    pre = grasps.column("prefilter_code").to_numpy().astype(int)
    outcome = rollouts.column("outcome").to_numpy().astype(int)
    simulated = rollouts.column("simulated").to_numpy(zero_copy_only=False).astype(bool)
    return bool(np.all(outcome[~simulated] == pre[~simulated]) and np.all(pre[~simulated] >= 0))


def grasp_labels(grasps: pa.Table, rollouts: pa.Table | None = None) -> tuple[np.ndarray, str]:
    """Each grasp's label code (n,) int64 and its source: outcome codes 0-5 from ``rollouts`` (``"rollouts"``), or
    pre-filter codes -1..2 from ``grasps`` when ``rollouts`` is None (``"prefilter"``)."""
    if rollouts is None:
        return grasps.column("prefilter_code").to_numpy().astype(np.int64), "prefilter"
    if not rollouts_match(grasps, rollouts):
        raise SettingsError("rollouts: not the rollouts of this grasps table (grasp ids or pre-filter labels differ)")
    return rollouts.column("outcome").to_numpy().astype(np.int64), "rollouts"


def choose_grasps(codes: np.ndarray, n: int, priority: Sequence[int]) -> np.ndarray:
    """At most ``n`` row indices (increasing, int64), dealt to the labels in ``priority`` order one slot at a time and
    evenly spaced within a label's rows; deterministic. Codes not in ``priority`` come after, in increasing order."""
    codes = np.asarray(codes).astype(np.int64)
    if n < 0:
        raise SettingsError(f"n: must be >= 0, got {n}")
    present = [int(c) for c in priority if np.any(codes == c)]
    present += sorted(int(c) for c in np.unique(codes) if int(c) not in present)
    available = {c: int(np.count_nonzero(codes == c)) for c in present}
    quota = dict.fromkeys(present, 0)
    left = min(n, len(codes))
    while left > 0:
        for c in present:
            if left > 0 and quota[c] < available[c]:
                quota[c] += 1
                left -= 1
    picks = []
    for c in present:
        rows = np.flatnonzero(codes == c)
        q = quota[c]
        if q:
            # floor(x + 0.5), not np.round (half to even), so a spacing >= 1 never maps two picks to one row.
            picks.append(rows[np.floor(np.linspace(0, len(rows) - 1, q) + 0.5).astype(np.int64)])
    return np.sort(np.concatenate(picks)) if picks else np.zeros(0, dtype=np.int64)


# ---------------------------------------------------------------------------------------------------------------
# The picture
# ---------------------------------------------------------------------------------------------------------------


def _font(size: int) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    try:
        return ImageFont.load_default(size=size)
    except (TypeError, ImportError, OSError):  # Pillow without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def _legend(image: Image.Image, title: str, entries: Sequence[tuple[str, tuple[int, int, int], str]]) -> Image.Image:
    """``image`` with a white strip below: ``title`` and one swatch + text per entry, wrapped to the width."""
    font = _font(14)
    pad, swatch, gap = 6, 12, 16
    probe = ImageDraw.Draw(image)
    line_h = max(swatch, int(probe.textbbox((0, 0), "Ag", font=font)[3])) + 4
    lines: list[list[tuple[str, tuple[int, int, int], str, int]]] = [[]]
    x = pad
    for name, colour, text in entries:
        label = f"{name} {text}"
        item_w = swatch + 4 + int(probe.textlength(label, font=font))
        if lines[-1] and x + item_w > image.width - pad:
            lines.append([])
            x = pad
        lines[-1].append((label, colour, text, x))
        x += item_w + gap
    title_lines = [""]
    for word in title.split(" "):  # wrap the title at spaces to the image width
        trial = f"{title_lines[-1]} {word}".strip()
        if title_lines[-1] and probe.textlength(trial, font=font) > image.width - 2 * pad:
            title_lines.append(word)
        else:
            title_lines[-1] = trial
    height = pad + line_h * (len(title_lines) + len(lines)) + pad
    sheet = Image.new("RGB", (image.width, image.height + height), (255, 255, 255))
    sheet.paste(image, (0, 0))
    draw = ImageDraw.Draw(sheet)
    y = image.height + pad - line_h
    for text in title_lines:
        y += line_h
        draw.text((pad, y), text, fill=(0, 0, 0), font=font)
    for row in lines:
        y += line_h
        for label, colour, _, x in row:
            top = y + (line_h - 4 - swatch) // 2
            draw.rectangle([x, top, x + swatch, top + swatch], fill=colour, outline=(0, 0, 0))
            draw.text((x + swatch + 4, y), label, fill=(0, 0, 0), font=font)
    return sheet


def grasp_picture(
    scene: SceneRecord,
    grasps: pa.Table,
    rollouts: pa.Table | None = None,
    *,
    view: int = 0,
    n: int = 30,
    scale: int = 3,
    gripper: GripperSpec | None = None,
) -> Image.Image:
    """The scene's RGB view ``view`` with up to ``n`` grasp markers coloured by label and a legend below: a PIL RGB
    image of ``(W scale, H scale + legend)``. ``gripper`` sizes the markers (default the table's gripper).

    Raises
    ------
    ValueError
        No images in the shard, ``view`` out of range, ``rollouts`` not matching ``grasps``.
    """
    if scene.rgb is None:
        raise SettingsError(f"{scene.scene_id}: the shard has no RGB images (made with cameras.render: false)")
    if not 0 <= view < len(scene.cameras):
        raise SettingsError(f"view: {scene.scene_id} has views 0..{len(scene.cameras) - 1}, got {view}")
    codes, source = grasp_labels(grasps, rollouts)
    labels: Mapping[int, tuple[str, tuple[int, int, int]]] = LABELS[source]
    priority = list(labels)
    chosen = choose_grasps(codes, n, priority)
    # Draw low-priority labels first so that successes (or free grasps) end up on top.
    rank = {c: i for i, c in enumerate(priority)}
    chosen = chosen[np.argsort([-rank.get(int(codes[i]), len(rank)) for i in chosen], kind="stable")]
    if gripper is None:
        name = grasps.column("gripper")[0].as_py() if len(grasps) else "robotiq_2f85"
        gripper = load_gripper(name)
    T = column_array(grasps, "pose_world", (4, 4))[chosen]
    opening = grasps.column("open_width").to_numpy()[chosen]
    segments = grasp_marker_segments(T, opening, gripper)
    colours = [labels.get(int(codes[i]), ("?", (255, 255, 255)))[1] for i in chosen]
    image = draw_grasps(scene.rgb[view], scene.cameras[view], segments, colours, scale=scale)
    shown = codes[chosen]
    entries = [
        (name, colour, f"{int(np.sum(shown == c))}/{int(np.sum(codes == c))}")
        for c, (name, colour) in labels.items()
        if np.any(codes == c)
    ]
    what = "rollout outcome" if source == "rollouts" else "pre-filter (no rollouts)"
    title = (f"{scene.scene_id} view {view}: {len(chosen)} of {len(grasps)} grasps ({gripper.name}), "
             f"coloured by {what}; shown/total")
    return _legend(image, title, entries)
