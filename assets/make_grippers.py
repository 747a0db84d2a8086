"""Build the convex collision pieces of the bundled Panda hand from ACRONYM's Franka collision mesh.

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


def main(out_dir: Path = PANDA) -> None:
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


if __name__ == "__main__":
    main(*sys.argv[1:2])
