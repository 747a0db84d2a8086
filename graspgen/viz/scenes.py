"""Pictures of a scene: colourised depth and segmentation, and a contact sheet of every view."""

from __future__ import annotations

import colorsys
from collections.abc import Sequence

import numpy as np  # noqa: E402

import graspgen.sim.gl  # noqa: F401 - imported first: chooses MUJOCO_GL before anything imports mujoco
from graspgen.errors import InputError, SettingsError  # noqa: E402
from graspgen.io.scenes import SceneRecord  # noqa: E402
from graspgen.sim.scene_model import SEG_BACKGROUND, SEG_GROUND, SEG_SUPPORT  # noqa: E402

_RAMP = np.array([[253, 231, 37], [94, 201, 98], [33, 145, 140], [59, 82, 139], [68, 1, 84]], dtype=float)
"""Depth colour ramp, near to far (viridis anchors, reversed so near is bright)."""


def colorize_depth(depth: np.ndarray, focus: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 3) uint8 colour image of a depth map: near yellow to far purple; 0 is black.

    The colour range spans the depths of the pixels where ``focus`` (H, W) bool is true (all valid pixels when
    None); depths beyond it are clipped to the end colours.
    """
    depth = np.asarray(depth, dtype=float)
    valid = depth > 0
    out = np.zeros((*depth.shape, 3), dtype=np.uint8)
    if not valid.any():
        return out
    # Scale to the near part (objects and support) when given, so a far-away ground does not wash it out.
    near = valid if focus is None else valid & np.asarray(focus, dtype=bool)
    near = near if near.any() else valid
    lo, hi = depth[near].min(), depth[near].max()
    t = (depth - lo) / max(hi - lo, 1e-9) * (len(_RAMP) - 1)
    i = np.clip(np.floor(t).astype(int), 0, len(_RAMP) - 2)
    f = np.clip(t - i, 0.0, 1.0)[..., None]
    rgb = _RAMP[i] * (1 - f) + _RAMP[i + 1] * f
    out[valid] = np.round(rgb[valid]).astype(np.uint8)
    return out


def colorize_segmentation(seg: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8: one colour per object id (golden-angle hues), grey support, dark ground, black nothing."""
    seg = np.asarray(seg)
    ids = np.unique(seg)
    lut = {SEG_BACKGROUND: (0, 0, 0), SEG_SUPPORT: (150, 150, 150), SEG_GROUND: (70, 70, 70)}
    out = np.zeros((*seg.shape, 3), dtype=np.uint8)
    for i in ids:
        if i in lut:
            color = lut[int(i)]
        else:
            r, g, b = colorsys.hsv_to_rgb((0.61803398875 * int(i) + 0.05) % 1.0, 0.75, 0.95)
            color = (round(r * 255), round(g * 255), round(b * 255))
        out[seg == i] = color
    return out


def contact_sheet(scene: SceneRecord, views: Sequence[int] | None = None):
    """A PIL image: one row per view, columns RGB | depth (colour-mapped) | segmentation, each row labelled."""
    from PIL import Image, ImageDraw

    if scene.rgb is None or scene.depth is None or scene.segmentation is None:
        raise InputError(f"{scene.scene_id}: the shard has no images (made with cameras.render: false or no views)")
    n_views = len(scene.cameras)
    views = list(range(n_views)) if views is None else list(views)
    for k in views:
        if not 0 <= k < n_views:
            raise SettingsError(f"view: {scene.scene_id} has views 0..{n_views - 1}, got {k}")
    h, w = scene.depth.shape[1:]
    label_h, pad = 16, 4
    sheet = Image.new("RGB", (3 * w + 4 * pad, len(views) * (h + label_h + pad) + pad), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for row, k in enumerate(views):
        y = pad + row * (h + label_h + pad)
        valid = (scene.depth[k] > 0) & (scene.segmentation[k] >= SEG_SUPPORT)
        rng_text = f"{scene.depth[k][valid].min():.2f}-{scene.depth[k][valid].max():.2f} m" if valid.any() else "-"
        draw.text(
            (pad, y),
            f"{scene.scene_id} view {k}: rgb | depth {rng_text} | segmentation ({', '.join(scene.object_names)})",
            fill=(0, 0, 0),
        )
        y += label_h
        for col, img in enumerate(
            (
                scene.rgb[k],
                colorize_depth(scene.depth[k], focus=scene.segmentation[k] >= SEG_SUPPORT),
                colorize_segmentation(scene.segmentation[k]),
            )
        ):
            sheet.paste(Image.fromarray(img), (pad + col * (w + pad), y))
    return sheet
