"""Build the convex collision pieces of the bundled Panda hand from ACRONYM's Franka collision mesh, and those of the
Robotiq 2F-85 (``robotiq_2f85_mesh``) from the airo-models collision meshes (:func:`robotiq`; README in
``assets/grippers/robotiq_2f85``).

Input: ``assets/grippers/panda/franka_gripper_collision_mesh.stl`` (vendored from github NVlabs/acronym,
``data/franka_gripper_collision_mesh.stl``, MIT, (c) 2020 NVIDIA Corporation; see the README beside it): the hand
and both fingers open at 0.04 m each, in metres, in the hand frame (z approach, fingers closing along x; the TCP
lies 0.1034 m along z).

Output, next to it (read by ``assets/grippers/panda/panda.yaml``, so nothing is decomposed when a run starts):

* ``hand.obj``: the hand's convex piece(s);
* ``finger.obj``: the right finger (+x) without its pad;
* ``pad.obj``: the right finger's pad: the finger tip from where its flat inner (contact) face begins, i.e. the
  part of the finger at ``z >= tcp_offset - pad_length / 2`` (the left finger is the same part turned 180 degrees
  about z, which the script checks).

All in the hand frame (``frame: base`` in the YAML). MuJoCo collides convex geoms only, so each part is used as
its convex hull when the hull is no more than ``MAX_HULL_EXCESS`` larger than the part (measured: the hand 0.01 %,
a finger 0.03 %); a part that is not convex enough is split with CoACD (``graspgen.geometry.convex``) instead.

Re-run from the repository root with::

    python assets/make_grippers.py            # or: python assets/make_grippers.py OUT_DIR (tests compare the bytes)

The output is byte-for-byte reproducible (fixed ``%.7f`` OBJ formatting, vertices and faces in a canonical order).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh

HERE = Path(__file__).resolve().parent
PANDA = HERE / "grippers" / "panda"
SOURCE = PANDA / "franka_gripper_collision_mesh.stl"
TCP_OFFSET = 0.1034
"""Hand frame -> TCP along z (m), ACRONYM's value."""
OPEN_HALF_WIDTH = 0.04
"""ACRONYM's ``gripper/configuration``: each finger 0.04 m from the centre when open."""
MAX_HULL_EXCESS = 0.02
"""A part whose convex hull is at most 2 % larger than the part is used as its hull; else CoACD splits it."""
FACE_TOL = 5e-4
"""Vertices within 0.5 mm of the finger's innermost x belong to its flat contact face."""


def _canonical(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The convex hull with vertices sorted (z, y, x) and faces sorted, so the OBJ bytes do not depend on the
    order trimesh or qhull produced them in."""
    hull = mesh.convex_hull
    order = np.lexsort(hull.vertices.round(9).T)
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    faces = rank[hull.faces]
    faces = np.array([np.roll(f, -int(np.argmin(f))) for f in faces])  # smallest index first, winding kept
    faces = faces[np.lexsort(faces.T[::-1])]
    return trimesh.Trimesh(hull.vertices[order], faces, process=False)


def _write_obj(path: Path, pieces: list[trimesh.Trimesh], comment: str) -> None:
    lines = [f"# {line}" for line in comment.splitlines()]
    base = 1
    for k, piece in enumerate(pieces):
        lines.append(f"o piece_{k}")
        lines += [f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in piece.vertices]
        lines += [f"f {a + base} {b + base} {c + base}" for a, b, c in piece.faces]
        base += len(piece.vertices)
    path.write_text("\n".join(lines) + "\n")


def _cut_z(hull: trimesh.Trimesh, z: float) -> tuple[trimesh.Trimesh, trimesh.Trimesh]:
    """The parts of a convex mesh above and below the plane at height ``z``: each the hull of its side's vertices
    and of the points where the mesh's edges cross the plane."""
    v = hull.vertices
    a, b = v[hull.edges_unique[:, 0]], v[hull.edges_unique[:, 1]]
    crossing = (a[:, 2] - z) * (b[:, 2] - z) < 0
    t = (z - a[crossing, 2]) / (b[crossing, 2] - a[crossing, 2])
    cut = a[crossing] + t[:, None] * (b[crossing] - a[crossing])
    cut[:, 2] = z
    above = np.vstack([v[v[:, 2] >= z], cut])
    below = np.vstack([v[v[:, 2] <= z], cut])
    return trimesh.convex.convex_hull(above), trimesh.convex.convex_hull(below)


def _convex_pieces(name: str, part: trimesh.Trimesh) -> list[trimesh.Trimesh]:
    excess = part.convex_hull.volume / part.volume - 1.0
    if excess <= MAX_HULL_EXCESS:
        print(f"{name}: hull {excess:.3%} larger than the part: used as one convex piece")
        return [_canonical(part)]
    sys.path.insert(0, str(HERE.parent))
    from graspgen.geometry.convex import CoacdParams, convex_decomposition

    parts = convex_decomposition(part, CoacdParams())
    print(f"{name}: hull {excess:.1%} larger than the part: CoACD, {len(parts)} convex pieces")
    return [_canonical(trimesh.Trimesh(v, f)) for v, f in parts]


def panda(out_dir: Path = PANDA) -> None:
    """The Panda's pieces (see the module docstring) into ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    mesh = trimesh.load(SOURCE, force="mesh")
    parts = mesh.split(only_watertight=False)
    right = [p for p in parts if p.bounds[0, 0] > 0.02]
    left = [p for p in parts if p.bounds[1, 0] < -0.02]
    hand = [p for p in parts if p.bounds[0, 0] < 0.0 < p.bounds[1, 0]]
    if (len(right), len(left), len(hand)) != (1, 1, 1):
        raise SystemExit(f"{SOURCE}: expected the hand and two fingers, got {len(parts)} parts")
    right, left, hand = right[0], left[0], hand[0]
    turned = left.vertices * [-1.0, -1.0, 1.0]
    gap = np.abs(np.sort(turned.round(6), axis=0) - np.sort(right.vertices.round(6), axis=0)).max()
    if gap > 1e-5:
        raise SystemExit(f"{SOURCE}: the left finger is not the right one turned about z (off by {gap} m)")

    x_face = float(right.vertices[:, 0].min())
    face = right.vertices[right.vertices[:, 0] < x_face + FACE_TOL]
    z_lo, z_tip = float(face[:, 2].min()), float(right.vertices[:, 2].max())
    print(f"right finger: inner face at x = {x_face:.5f} m (open half width {OPEN_HALF_WIDTH}), "
          f"flat from z = {z_lo:.4f} to the tip at {z_tip:.4f}: centre {(z_lo + z_tip) / 2:.4f} "
          f"(TCP {TCP_OFFSET}), length {z_tip - z_lo:.4f}, width {np.ptp(face[:, 1]):.4f}")
    if abs((z_lo + z_tip) / 2 - TCP_OFFSET) > 1e-3 or abs(x_face - OPEN_HALF_WIDTH) > 5e-4:
        raise SystemExit("the finger's contact face is not centred on the TCP: check the source mesh's frame")

    hull = right.convex_hull
    print(f"right finger: hull {hull.volume / right.volume - 1.0:.3%} larger than the part")
    pad, link = _cut_z(hull, z_lo)
    print(f"pad: {pad.volume * 1e6:.2f} cm^3, bounds {pad.bounds.round(4).tolist()}; "
          f"finger link: {link.volume * 1e6:.2f} cm^3")

    note = ("Generated by assets/make_grippers.py from franka_gripper_collision_mesh.stl (NVlabs/acronym, MIT,\n"
            "(c) 2020 NVIDIA Corporation). Hand frame, metres; convex pieces (one 'o' group each).")
    _write_obj(out_dir / "hand.obj", _convex_pieces("hand", hand), note)
    _write_obj(out_dir / "finger.obj", _convex_pieces("finger link", link),
               note + "\nRight finger (+x) without its pad.")
    _write_obj(out_dir / "pad.obj", [_canonical(pad)], note + "\nRight finger's pad (its tip, z >= the contact face).")
    for name in ("hand.obj", "finger.obj", "pad.obj"):
        print(f"wrote {out_dir / name}")


# ---------------------------------------------------------------------------------------------------------------
# Robotiq 2F-85
# ---------------------------------------------------------------------------------------------------------------

ROBOTIQ = HERE / "grippers" / "robotiq_2f85"
AIRO = ROBOTIQ / "airo"
"""The vendored airo-models 0.0.12 files (``airo_models/grippers/robotiq_2f_85``): URDF and collision OBJs."""
MAX_WIDTH = 0.085
"""Data sheet stroke (m): the pads' faces 85 mm apart when open."""
# URDF numbers (robotiq_2f_85.urdf), in its ``base_link_inertia`` frame I (fingers closing along y, z approach):
URDF_DRIVER_PIVOT = (0.0306011, 0.054904)
"""(y, z) of the right outer knuckle's joint (``right_outer_knuckle_joint``)."""
URDF_FOLLOWER_PIVOT = (0.0127, 0.06142)
"""(y, z) of the right inner knuckle's joint (``right_inner_knuckle_joint``)."""
URDF_OUTER_FINGER = (0.0315, -0.0041)
"""(y, z) of the outer finger in the outer knuckle (``right_outer_finger_joint``, fixed)."""
URDF_INNER_FINGER = (0.0061, 0.0471)
"""(y, z) of the inner finger's joint in the outer finger (``right_inner_finger_joint``, mimic -1)."""
URDF_PAD = (-0.0220203446692936, 0.03242)
"""(y, z) of the pad box's centre in the inner finger (``right_inner_finger_pad_joint``)."""
URDF_PAD_SIZE = (0.022, 0.00635, 0.0375)
"""The pad box (x width, y thickness, z length) of ``right_inner_finger_pad``."""


def _rot_x(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _to_base(points_i: np.ndarray) -> np.ndarray:
    """URDF ``base_link_inertia`` frame -> ``base_link`` (the hand base): turned -90 degrees about z (the URDF's
    -1.57 rad, taken as exactly -pi/2 so that the two fingers stay mirror images), so I's y becomes x."""
    p = np.atleast_2d(points_i)
    return np.stack([p[:, 1], -p[:, 0], p[:, 2]], axis=1)


def _yz(v) -> np.ndarray:
    return np.array([0.0, v[0], v[1]])


def robotiq_linkage(theta: float) -> dict[str, np.ndarray]:
    """Points of the right finger's 4-bar linkage (base frame, m) at outer-knuckle angle ``theta`` (rad, 0 = the URDF's
    zero, closing > 0): driver and follower pivots, the coupler (inner finger) joint, the pad centre and contact face
    centre. The inner finger keeps its orientation (its joint mimics the knuckle with -1): a parallelogram."""
    pivot = _yz(URDF_DRIVER_PIVOT)
    crank = _yz(np.add(URDF_OUTER_FINGER, URDF_INNER_FINGER))
    joint = pivot + _rot_x(theta) @ crank
    pad = joint + _yz(URDF_PAD)
    face = pad - [0.0, URDF_PAD_SIZE[1] / 2.0, 0.0]
    out = {"pivot": pivot, "follower_pivot": _yz(URDF_FOLLOWER_PIVOT), "joint": joint, "pad": pad, "face": face}
    return {k: _to_base(v)[0] for k, v in out.items()}


def robotiq_angle(half_width: float) -> float:
    """Outer-knuckle angle (rad) at which the right pad's contact face lies at ``x = half_width`` (m)."""
    crank = np.add(URDF_OUTER_FINGER, URDF_INNER_FINGER)
    radius, phi0 = float(np.hypot(*crank)), float(np.arctan2(crank[1], crank[0]))
    x0 = URDF_DRIVER_PIVOT[0] + URDF_PAD[0] - URDF_PAD_SIZE[1] / 2.0  # face x minus the crank's x
    return float(np.arccos((half_width - x0) / radius) - phi0)


def _load_mm(name: str) -> np.ndarray:
    return np.asarray(trimesh.load(AIRO / name, force="mesh").vertices, dtype=float) * 0.001


def robotiq(out_dir: Path = ROBOTIQ) -> None:
    """The 2F-85's convex pieces from the vendored airo-models collision meshes, posed open (pad faces
    ``MAX_WIDTH`` apart), right finger (+x), in the hand-base frame (the URDF's ``base_link``; ``frame: base``):

    * ``palm.obj``: the base housing (``robotiq_arg2f_base_link.obj``);
    * ``driver.obj``: outer knuckle + outer finger (two pieces), which turn about the driver pivot;
    * ``follower.obj``: the inner knuckle, which turns about the follower pivot;
    * ``finger.obj``: the inner finger (the coupler, which translates: it carries the pad).

    The pad is the URDF's box, written in the YAML. Each source mesh is convex already (its hull is the mesh)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    theta = robotiq_angle(MAX_WIDTH / 2.0)
    R = _rot_x(theta)
    pivot, follower = _yz(URDF_DRIVER_PIVOT), _yz(URDF_FOLLOWER_PIVOT)
    joint = pivot + R @ _yz(np.add(URDF_OUTER_FINGER, URDF_INNER_FINGER))
    parts = {
        "palm": [_to_base(np.asarray(trimesh.load(AIRO / "robotiq_arg2f_base_link.obj", force="mesh").vertices))],
        "driver": [_to_base(pivot + _load_mm("robotiq_arg2f_85_outer_knuckle.obj") @ R.T),
                   _to_base(pivot + (_yz(URDF_OUTER_FINGER) + _load_mm("robotiq_arg2f_85_outer_finger.obj")) @ R.T)],
        "follower": [_to_base(follower + _load_mm("robotiq_arg2f_85_inner_knuckle.obj") @ R.T)],
        "finger": [_to_base(joint + _load_mm("robotiq_arg2f_85_inner_finger.obj"))],
    }
    points = robotiq_linkage(theta)
    print(f"2F-85 open ({MAX_WIDTH * 1e3:.0f} mm): knuckle angle {theta:.6f} rad; "
          + ", ".join(f"{k} {np.round(v, 7).tolist()}" for k, v in points.items()))
    note = ("Generated by assets/make_grippers.py from the airo-models 0.0.12 Robotiq 2F-85 collision meshes\n"
            "(airo/, MIT; README.md). Hand-base frame (the URDF's base_link), metres, right finger (+x), open\n"
            f"({MAX_WIDTH * 1e3:.0f} mm between the pads); convex pieces (one 'o' group each).")
    for name, pieces in parts.items():
        meshes = [_canonical(trimesh.Trimesh(v, trimesh.convex.convex_hull(v).faces)) for v in pieces]
        _write_obj(out_dir / f"{name}.obj", meshes, note + f"\n{name}")
        print(f"wrote {out_dir / name}.obj")


def main(out_dir: Path | None = None) -> None:
    """Both grippers' pieces: into their folders, or into ``out_dir/panda`` and ``out_dir/robotiq_2f85``."""
    panda(PANDA if out_dir is None else Path(out_dir) / "panda")
    robotiq(ROBOTIQ if out_dir is None else Path(out_dir) / "robotiq_2f85")


if __name__ == "__main__":
    main(*sys.argv[1:2])
