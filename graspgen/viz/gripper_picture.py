"""A picture of a gripper (``gen show gripper``): open and closed, from the front and in a three-quarter view, with
its TCP frame and a caption; MuJoCo's offscreen renderer, or a matplotlib drawing of the collision geoms' silhouettes
where no OpenGL back end is available.
"""

from __future__ import annotations

import io
import math

import numpy as np

from graspgen.errors import RenderError
from graspgen.grippers import Box, GripperSpec
from graspgen.grippers.shapes import bounds_of
from graspgen.sim.camera import Camera, camera_on_sphere, intrinsics_from_fov, project, transform_points
from graspgen.sim.gripper_views import gripper_geom_points, render_gripper

__all__ = ["gripper_picture"]

#: Pose of the TCP in the picture's world: approach (TCP z) pointing down, closing (TCP x) to the right.
_PICTURE_POSE = np.diag([1.0, -1.0, -1.0, 1.0])
_AXIS_COLOURS = ((220, 30, 30), (30, 160, 30), (40, 70, 230))


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: one bitmap size
        return ImageFont.load_default()


def _picture_frame(spec: GripperSpec) -> tuple[np.ndarray, float]:
    """(centre (3,), size m) of the region the picture shows, in the picture's world (TCP at the origin)."""
    lo, hi = bounds_of(list(spec.palm_boxes) + [Box(size=spec.finger_size, pos=(0.0, 0.0, 0.0))])
    z_tip = max(spec.pad_size[2] / 2.0, 0.0)
    if spec.pad_geom is not None:
        z_tip = float(spec.pad_geom.bounds[1][2])
    for piece in spec.finger_geoms:
        z_tip = max(z_tip, float(piece.bounds[1][2]))
    z_back = float(min(lo[2], -spec.tcp_offset))
    half_x = max(abs(lo[0]), abs(hi[0]), spec.max_width / 2.0 + spec.finger_size[0] + spec.pad_size[0])
    centre = np.array([0.0, 0.0, -(z_back + z_tip) / 2.0])  # world z = -TCP z
    return centre, max(2.0 * half_x, z_tip - z_back)


def _views(centre: np.ndarray, extent: float, px: int):
    """(title, Camera) of the two views: front (along TCP y: closing left-right, approach down) and three-quarter."""
    fov = math.radians(30.0)
    distance = 0.62 * extent / math.tan(fov / 2.0) + 0.05
    K = intrinsics_from_fov(px, px, fov)
    return [("front", Camera(K, camera_on_sphere(centre, distance, 0.0, -math.pi / 2), px, px)),
            ("3/4 view", Camera(K, camera_on_sphere(centre, distance, 0.45, -math.pi / 2 + 0.7), px, px))]


def _tcp_axes(draw, camera, length: float) -> None:
    """The TCP frame's axes (x red, y green, z blue) drawn as lines from the TCP origin."""
    T_camera_world = np.linalg.inv(np.asarray(camera.T_world_camera, dtype=float))
    ends = _PICTURE_POSE[:3, 3] + length * _PICTURE_POSE[:3, :3].T
    points = transform_points(T_camera_world, np.vstack([_PICTURE_POSE[:3, 3], ends]))
    uv = project(camera.K, points)
    font = _font(13)
    for k, name in enumerate("xyz"):
        draw.line([tuple(uv[0]), tuple(uv[k + 1])], fill=_AXIS_COLOURS[k], width=3)
        draw.text((uv[k + 1][0] + 3, uv[k + 1][1] - 7), name, fill=_AXIS_COLOURS[k], font=font)
    r = 3
    draw.ellipse([uv[0][0] - r, uv[0][1] - r, uv[0][0] + r, uv[0][1] + r], fill=(0, 0, 0))


def _render_views(spec: GripperSpec, widths, px: int):
    """MuJoCo renders: {(width, view title): PIL image}. RenderError when OpenGL is unavailable."""
    from PIL import Image, ImageDraw

    centre, extent = _picture_frame(spec)
    views = _views(centre, extent, px)
    rgb = render_gripper(spec, _PICTURE_POSE, widths, [camera for _, camera in views], px)
    out = {}
    for width in widths:
        for k, (title, camera) in enumerate(views):
            image = Image.fromarray(rgb[width, k])
            _tcp_axes(ImageDraw.Draw(image), camera, 0.03)
            out[width, title] = image
    return out


def _wireframe_views(spec: GripperSpec, widths, px: int):
    """Matplotlib drawings of the collision geoms (outlines of each piece's silhouette), same layout as
    :func:`_render_views`: {(width, view title): PIL image}."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    import matplotlib.ticker
    from PIL import Image
    from scipy.spatial import ConvexHull

    geoms = gripper_geom_points(spec, _PICTURE_POSE, widths)
    out = {}
    for width in widths:
        for title, axes in (("front", (0, 2)), ("side", (1, 2))):
            fig, ax = plt.subplots(figsize=(px / 100, px / 100), dpi=100)
            for points, rgb in geoms[width]:
                colour = tuple(rgb)
                pts = points[:, axes]
                hull = pts[ConvexHull(pts).vertices]
                ax.fill(hull[:, 0], hull[:, 1], color=colour, alpha=0.35, lw=1.2, ec=colour)
            for k in range(3):
                tip = 0.03 * _PICTURE_POSE[:3, k]
                if np.hypot(tip[axes[0]], tip[axes[1]]) > 1e-6:
                    ax.annotate("", xy=(tip[axes[0]], tip[axes[1]]), xytext=(0, 0),
                                arrowprops={"arrowstyle": "->", "color": np.divide(_AXIS_COLOURS[k], 255), "lw": 2})
                    ax.text(tip[axes[0]], tip[axes[1]], "xyz"[k], color=np.divide(_AXIS_COLOURS[k], 255))
                    ax.update_datalim([(1.3 * tip[axes[0]], 1.3 * tip[axes[1]])])
            ax.autoscale_view()
            ax.set_aspect("equal")
            ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(4))
            ax.set_xlabel(f"world {'xy'[axes[0]]} (m)")
            ax.set_title(title, fontsize=9)
            fig.tight_layout()
            buffer = io.BytesIO()
            fig.savefig(buffer, format="png")
            plt.close(fig)
            out[width, title] = Image.open(io.BytesIO(buffer.getvalue())).convert("RGB").resize((px, px))
    return out


def gripper_picture(spec: GripperSpec, *, size: int = 360, render: bool = True):
    """A PIL image of ``spec`` open (``max_width``) and closed (``min_width``), each from the front (closing axis
    left-right, approach down) and in a three-quarter view, with the TCP frame (x red, y green, z blue) and a caption
    (name, stroke, TCP offset, force, geometry).

    Drawn by MuJoCo's offscreen renderer (the collision geoms: palm dark grey, finger links grey, pads orange); with
    ``render=False``, or when no OpenGL back end is available, a matplotlib drawing of the geoms' silhouettes
    (front and side) instead, which the caption says.
    """
    from PIL import Image, ImageDraw

    widths = (spec.max_width, spec.min_width)
    how = "MuJoCo render"
    try:
        if not render:
            raise RenderError("rendering off")
        views = _render_views(spec, widths, size)
    except RenderError as exc:
        views = _wireframe_views(spec, widths, size)
        how = "wireframe of the collision geoms" + ("" if not render else f" (no rendering: {exc})")
    titles = list(dict.fromkeys(t for _, t in views))
    top, label_h = 58, 20
    sheet = Image.new("RGB", (size * len(titles), top + len(widths) * (size + label_h)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    geometry = "convex meshes" if spec.uses_meshes else "boxes"
    draw.text((6, 4), f"{spec.name}" + (f"  ({spec.file})" if spec.file else ""), fill=(0, 0, 0), font=_font(16))
    draw.text((6, 24), f"stroke {spec.min_width * 1e3:.0f}-{spec.max_width * 1e3:.0f} mm, TCP {spec.tcp_offset:.4g} m "
              f"from the hand base along z, force {spec.force_limit:.0f} N, {spec.closing_speed:.2g} m/s; {geometry}",
              fill=(0, 0, 0), font=_font(12))
    draw.text((6, 40), f"{how}; TCP frame: x closing (red), y (green), z approach (blue); pads orange",
              fill=(80, 80, 80), font=_font(12))
    for row, width in enumerate(widths):
        y = top + row * (size + label_h)
        state = "open" if row == 0 else "closed"
        for col, title in enumerate(titles):
            draw.text((col * size + 6, y + 3), f"{state}, width {width * 1e3:.0f} mm, {title}", fill=(0, 0, 0),
                      font=_font(13))
            sheet.paste(views[width, title], (col * size, y + label_h))
    return sheet
