"""Build the bundled object set used by the grasp-dataset generator.

This script constructs twelve everyday-sized solid objects (box, cylinder,
can, bottle, mug, bowl, L-bracket, torus, cone, wedge, rock, mallet) from
trimesh / manifold3d primitives, revolutions, extrusions and boolean unions,
and writes them to ``assets/objects/`` as Wavefront OBJ files together with
``assets/objects/catalog.json``.

Re-run it from the repository root with::

    python assets/make_objects.py

Conventions
-----------
* Units are metres (lengths) and kg/m^3 (densities).
* Origin: every mesh is translated so that its axis-aligned bounding box is
  centred on the origin in x and y and its lowest point lies at z = 0, i.e.
  the origin sits at the centre of the bounding-box *base*.  In that canonical
  pose each object rests on the plane z = 0 (revolved objects stand upright on
  their base; the torus, rock, bracket, wedge and mallet lie flat).
* Every mesh is one closed, watertight, outward-wound solid with positive
  volume and no degenerate faces, and has at least one cross-section narrower
  than 80 mm so a parallel-jaw gripper with an 85 mm stroke can hold it.
* Meshes are solid, so hollow real objects (the drinks can, the bottle) are
  given an *effective* density chosen so that ``density * volume`` matches a
  realistic mass of the filled object.  Genuinely hollow objects (mug, bowl)
  are modelled with their real wall geometry and the material's density.

Determinism
-----------
The output is byte-for-byte reproducible: the only randomness (the rock) uses
``np.random.default_rng(7)``, OBJ files are written by hand with fixed ``%.6f``
formatting and no header, and ``catalog.json`` is written with
``sort_keys=True, indent=2`` and a trailing newline.
"""

from __future__ import annotations

import json
from pathlib import Path

import manifold3d as mf
import numpy as np
import trimesh

OUT_DIR = Path(__file__).resolve().parent / "objects"

# Number of segments used for full revolutions.
SEGMENTS = 64


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------
def _to_trimesh(solid: mf.Manifold) -> trimesh.Trimesh:
    """Convert a manifold3d solid into a trimesh mesh.

    Parameters
    ----------
    solid : manifold3d.Manifold
        A valid (non-empty) manifold solid.

    Returns
    -------
    trimesh.Trimesh
        Mesh with the same vertices and triangles, float64 vertices.
    """
    if solid.status() != mf.Error.NoError or solid.is_empty():
        raise ValueError(f"invalid manifold: {solid.status()}")
    mesh = solid.to_mesh64()
    verts = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    return trimesh.Trimesh(vertices=verts, faces=faces, process=False)


def _revolve(profile: list[tuple[float, float]], segments: int = SEGMENTS) -> mf.Manifold:
    """Revolve a closed (r, z) profile around the z axis.

    Parameters
    ----------
    profile : list of (float, float)
        Counter-clockwise simple polygon in the (r, z) half-plane, r >= 0.
        Points with r == 0 lie on the axis.
    segments : int, optional
        Number of angular segments.

    Returns
    -------
    manifold3d.Manifold
        The solid of revolution.
    """
    section = mf.CrossSection([np.asarray(profile, dtype=np.float64)])
    return mf.Manifold.revolve(section, circular_segments=segments)


def _extrude_xz(polygon: list[tuple[float, float]], width: float) -> mf.Manifold:
    """Extrude a polygon drawn in the x-z plane along y, centred on y = 0.

    Parameters
    ----------
    polygon : list of (float, float)
        Counter-clockwise simple polygon given as (x, z) pairs.
    width : float
        Extrusion length along y in metres.

    Returns
    -------
    manifold3d.Manifold
        The prism.
    """
    section = mf.CrossSection([np.asarray(polygon, dtype=np.float64)])
    # extrude() goes along +z from the x-y plane; rotate so that the section's
    # y becomes world z and the extrusion direction becomes world y.
    solid = mf.Manifold.extrude(section, width)
    solid = solid.rotate((90.0, 0.0, 0.0))  # (x, y, z) -> (x, -z, y)
    return solid.translate((0.0, width / 2.0, 0.0))


def _arc(
    centre: tuple[float, float],
    radii: tuple[float, float],
    start_deg: float,
    stop_deg: float,
    n: int,
) -> list[tuple[float, float]]:
    """Sample an elliptical arc.

    Parameters
    ----------
    centre : (float, float)
        Arc centre (r, z).
    radii : (float, float)
        Semi-axes along r and z.
    start_deg, stop_deg : float
        Start and stop angle in degrees, measured from +r towards +z.
    n : int
        Number of points, endpoints included.

    Returns
    -------
    list of (float, float)
        The sampled points.
    """
    t = np.radians(np.linspace(start_deg, stop_deg, n))
    return [
        (float(centre[0] + radii[0] * np.cos(a)), float(centre[1] + radii[1] * np.sin(a)))
        for a in t
    ]


def canonicalize(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Move a mesh to the canonical pose and round vertices to 1 micrometre.

    The bounding box is centred on the origin in x and y and its base placed
    on z = 0.  Vertices are rounded to six decimals (exactly what is written to
    the OBJ) so the in-memory mesh equals the file contents.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Input mesh; not modified.

    Returns
    -------
    trimesh.Trimesh
        New, validated mesh in the canonical pose.
    """
    lo, hi = mesh.bounds
    offset = np.array([-(lo[0] + hi[0]) / 2.0, -(lo[1] + hi[1]) / 2.0, -lo[2]])
    verts = np.round(mesh.vertices + offset, 6) + 0.0  # + 0.0 removes -0.0
    out = trimesh.Trimesh(vertices=verts, faces=mesh.faces.copy(), process=False)
    validate(out)
    return out


def validate(mesh: trimesh.Trimesh, min_height: float = 1e-6) -> None:
    """Raise ``ValueError`` unless the mesh is a clean closed solid.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Mesh to check.
    min_height : float, optional
        Smallest allowed triangle height (twice the area over the longest
        edge) in metres; smaller triangles count as degenerate.
    """
    if len(mesh.faces) == 0:
        raise ValueError("empty mesh")
    if not mesh.is_watertight:
        raise ValueError("mesh is not watertight")
    if not mesh.is_winding_consistent:
        raise ValueError("mesh winding is inconsistent")
    if len(mesh.split(only_watertight=False)) != 1:
        raise ValueError("mesh has more than one body")
    if not mesh.volume > 0:
        raise ValueError("mesh has non-positive volume (inward normals)")
    tri = mesh.triangles
    edges = np.linalg.norm(tri[:, [1, 2, 0]] - tri, axis=2)
    heights = 2.0 * mesh.area_faces / edges.max(axis=1)
    if heights.min() < min_height:
        raise ValueError(f"degenerate face (height {heights.min():.3g} m)")


# ---------------------------------------------------------------------------
# objects
# ---------------------------------------------------------------------------
def make_box() -> trimesh.Trimesh:
    """Rectangular wooden block, 50 x 70 x 120 mm.

    Returns
    -------
    trimesh.Trimesh
        The box.
    """
    return _to_trimesh(mf.Manifold.cube((0.05, 0.07, 0.12), center=True))


def make_cylinder() -> trimesh.Trimesh:
    """Solid wooden dowel, 50 mm diameter, 120 mm tall.

    Returns
    -------
    trimesh.Trimesh
        The cylinder, axis along z.
    """
    return _to_trimesh(mf.Manifold.cylinder(0.12, 0.025, 0.025, SEGMENTS))


def make_can() -> trimesh.Trimesh:
    """330 ml drinks can: 66 mm diameter, 115 mm tall, with a rolled top lip.

    The revolved profile has a bevelled bottom, a tapered neck, a raised lip
    around a recessed lid.

    Returns
    -------
    trimesh.Trimesh
        The can, axis along z.
    """
    profile = [
        (0.0, 0.0),
        (0.026, 0.0),
        (0.033, 0.007),
        (0.033, 0.101),
        (0.0285, 0.109),
        (0.0290, 0.1135),
        (0.0283, 0.1150),
        (0.0271, 0.1150),
        (0.0266, 0.1110),
        (0.0, 0.1110),
    ]
    return _to_trimesh(_revolve(profile))


def make_bottle() -> trimesh.Trimesh:
    """500 ml bottle: 70 mm body, curved shoulder, 25 mm neck and cap, 190 mm tall.

    Returns
    -------
    trimesh.Trimesh
        The bottle as a closed solid, axis along z.
    """
    profile = [(0.0, 0.0), (0.031, 0.0)]
    profile += _arc((0.031, 0.004), (0.004, 0.004), -90.0, 0.0, 5)[1:]  # base fillet
    # shoulder: quarter ellipse from the body wall (r=0.035, z=0.120) to the
    # neck (r=0.0125, z=0.158)
    profile += _arc((0.0125, 0.120), (0.0225, 0.038), 0.0, 90.0, 13)
    profile += [
        (0.0125, 0.166),  # neck
        (0.0150, 0.167),  # cap
        (0.0150, 0.190),
        (0.0, 0.190),
    ]
    return _to_trimesh(_revolve(profile))


def make_mug() -> trimesh.Trimesh:
    """Ceramic mug: 82 mm outer diameter, 95 mm tall, 5 mm wall, with a handle.

    The hollow cup is revolved; the handle is a torus segment (28 mm ring
    radius, 12 mm tube diameter) trimmed at mid-wall so its ends are embedded
    in the wall, unioned with the cup into a single watertight solid.

    Returns
    -------
    trimesh.Trimesh
        The mug, cup axis along z, handle towards +x.
    """
    r_out, r_in, height, floor = 0.041, 0.036, 0.095, 0.008
    cup = _revolve(
        [
            (0.0, 0.0),
            (r_out, 0.0),
            (r_out, height),
            (r_in, height),
            (r_in, floor),
            (0.0, floor),
        ]
    )
    ring_r, tube_r = 0.028, 0.006
    tube = mf.CrossSection.circle(tube_r, 24).translate((ring_r, 0.0))
    ring = mf.Manifold.revolve(tube, circular_segments=48)  # torus in x-y plane
    ring = ring.rotate((90.0, 0.0, 0.0))  # now in the x-z plane
    # ring centre 3 mm outside the wall so the tube crosses the wall cleanly
    # (no tangential contact -> no sliver triangles in the union)
    ring = ring.translate((r_out + 0.003, 0.0, 0.050))
    # keep only the part outside mid-wall so nothing protrudes into the cup
    handle = ring.trim_by_plane((1.0, 0.0, 0.0), (r_out + r_in) / 2.0)
    return _to_trimesh(cup + handle)


def make_bowl() -> trimesh.Trimesh:
    """Ceramic bowl: 140 mm diameter, 55 mm tall, 5 mm wall, flat foot.

    Returns
    -------
    trimesh.Trimesh
        The bowl, axis along z.
    """
    outer = _arc((0.035, 0.055), (0.035, 0.055), -90.0, 0.0, 10)
    inner = _arc((0.035, 0.055), (0.030, 0.049), 0.0, -90.0, 10)
    profile = [(0.0, 0.0)] + outer + inner + [(0.0, 0.006)]
    return _to_trimesh(_revolve(profile))


def make_l_bracket() -> trimesh.Trimesh:
    """Aluminium angle bracket: legs 80 mm and 60 mm, 40 mm wide, 6 mm thick.

    Returns
    -------
    trimesh.Trimesh
        The bracket, lying with its long leg on the table and the short leg
        standing up.
    """
    t = 0.006
    polygon = [(0.0, 0.0), (0.08, 0.0), (0.08, t), (t, t), (t, 0.06), (0.0, 0.06)]
    return _to_trimesh(_extrude_xz(polygon, 0.04))


def make_torus() -> trimesh.Trimesh:
    """Rubber ring: 104 mm outer diameter, 24 mm tube diameter.

    Returns
    -------
    trimesh.Trimesh
        The torus lying flat, axis along z.
    """
    tube = mf.CrossSection.circle(0.012, 24).translate((0.040, 0.0))
    return _to_trimesh(mf.Manifold.revolve(tube, circular_segments=48))


def make_cone() -> trimesh.Trimesh:
    """Plastic cone: 70 mm base diameter, 100 mm tall.

    Returns
    -------
    trimesh.Trimesh
        The cone standing on its base, apex up.
    """
    return _to_trimesh(mf.Manifold.cylinder(0.10, 0.035, 0.0, SEGMENTS))


def make_wedge() -> trimesh.Trimesh:
    """Wooden door wedge (triangular prism): 120 mm long, 50 mm wide, 35 mm tall.

    Returns
    -------
    trimesh.Trimesh
        The wedge lying on its long flat face.
    """
    return _to_trimesh(_extrude_xz([(0.0, 0.0), (0.12, 0.0), (0.12, 0.035)], 0.05))


def make_rock() -> trimesh.Trimesh:
    """Irregular convex stone, roughly 85 x 67 x 52 mm.

    The convex hull of 160 points drawn from ``np.random.default_rng(7)`` on a
    jittered ellipsoid.

    Returns
    -------
    trimesh.Trimesh
        The rock.
    """
    rng = np.random.default_rng(7)
    directions = rng.normal(size=(160, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    radial = rng.uniform(0.85, 1.0, size=(160, 1))
    points = directions * radial * np.array([0.045, 0.035, 0.028])
    hull = trimesh.convex.convex_hull(points)
    return trimesh.Trimesh(vertices=hull.vertices, faces=hull.faces, process=False)


def make_mallet() -> trimesh.Trimesh:
    """Wooden mallet: 150 mm x 26 mm handle, 100 x 40 x 40 mm head; 190 mm long.

    Returns
    -------
    trimesh.Trimesh
        The mallet lying flat, handle along x, head along y.
    """
    head = mf.Manifold.cube((0.04, 0.10, 0.04), center=True)
    handle = mf.Manifold.cylinder(0.15 + 0.02, 0.013, 0.013, 32)
    handle = handle.rotate((0.0, 90.0, 0.0))  # axis along +x, starts at x = 0
    return _to_trimesh(head + handle)


# name -> (builder, density kg/m^3, description)
OBJECTS = {
    "box": (make_box, 650.0, "Wooden block 50 x 70 x 120 mm (wood, 650 kg/m^3)."),
    "cylinder": (
        make_cylinder,
        650.0,
        "Solid wooden dowel, 50 mm diameter x 120 mm tall (wood, 650 kg/m^3).",
    ),
    "can": (
        make_can,
        1000.0,
        "330 ml drinks can, 66 mm diameter x 115 mm tall, with a raised top lip; "
        "solid mesh with effective density 1000 kg/m^3 so a full can weighs ~0.37 kg.",
    ),
    "bottle": (
        make_bottle,
        850.0,
        "500 ml bottle, 70 mm body diameter, curved shoulder, 25 mm neck / 30 mm cap, "
        "190 mm tall; solid mesh with effective density 850 kg/m^3 (filled PET "
        "bottle, ~0.50 kg).",
    ),
    "mug": (
        make_mug,
        2000.0,
        "Ceramic mug, 82 mm outer diameter x 95 mm tall, 5 mm wall, ring handle "
        "(119 mm across including handle); real wall geometry, ceramic 2000 kg/m^3.",
    ),
    "bowl": (
        make_bowl,
        2000.0,
        "Ceramic bowl, 140 mm diameter x 55 mm tall, 5 mm wall, grasp by the rim; "
        "ceramic 2000 kg/m^3.",
    ),
    "l_bracket": (
        make_l_bracket,
        2700.0,
        "Aluminium angle bracket, legs 80 mm and 60 mm, 40 mm wide, 6 mm thick "
        "(aluminium, 2700 kg/m^3).",
    ),
    "torus": (
        make_torus,
        1100.0,
        "Rubber ring, 104 mm outer diameter, 24 mm tube diameter (rubber, 1100 kg/m^3).",
    ),
    "cone": (
        make_cone,
        1050.0,
        "Solid plastic cone, 70 mm base diameter x 100 mm tall (ABS, 1050 kg/m^3).",
    ),
    "wedge": (
        make_wedge,
        650.0,
        "Wooden door wedge (triangular prism), 120 mm long x 50 mm wide x 35 mm tall "
        "(wood, 650 kg/m^3).",
    ),
    "rock": (
        make_rock,
        2600.0,
        "Irregular convex stone, about 85 x 67 x 52 mm (convex hull of seeded random "
        "points; stone, 2600 kg/m^3).",
    ),
    "mallet": (
        make_mallet,
        700.0,
        "Wooden mallet, 190 mm long: 26 mm diameter x 150 mm handle and "
        "100 x 40 x 40 mm head (hardwood, 700 kg/m^3).",
    ),
}


# ---------------------------------------------------------------------------
# output
# ---------------------------------------------------------------------------
def obj_text(mesh: trimesh.Trimesh) -> str:
    """Serialise a mesh as a minimal, deterministic OBJ (``v`` and ``f`` lines).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Mesh to write; vertices are formatted with ``%.6f``.

    Returns
    -------
    str
        OBJ file contents with 1-based face indices and no header.
    """
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in mesh.vertices.tolist()]
    lines += [f"f {a} {b} {c}" for a, b, c in (mesh.faces + 1).tolist()]
    return "\n".join(lines) + "\n"


def build_all(out_dir: Path | str = OUT_DIR) -> list[dict]:
    """Build every object and write the OBJ files and ``catalog.json``.

    Parameters
    ----------
    out_dir : path-like, optional
        Destination directory (created if missing).  Defaults to
        ``assets/objects`` next to this script.

    Returns
    -------
    list of dict
        The catalog entries, sorted by name.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    catalog = []
    for name in sorted(OBJECTS):
        builder, density, description = OBJECTS[name]
        mesh = canonicalize(builder())
        filename = f"{name}.obj"
        with open(out_dir / filename, "w", encoding="ascii", newline="\n") as fh:
            fh.write(obj_text(mesh))
        catalog.append(
            {"name": name, "file": filename, "density": density, "description": description}
        )
    with open(out_dir / "catalog.json", "w", encoding="ascii", newline="\n") as fh:
        fh.write(json.dumps(catalog, sort_keys=True, indent=2) + "\n")
    return catalog


def main() -> None:
    """Build the object set into ``assets/objects`` and print a summary."""
    for entry in build_all(OUT_DIR):
        mesh = trimesh.load(OUT_DIR / entry["file"], force="mesh")
        ext = ", ".join(f"{e:.3f}" for e in mesh.extents)
        print(
            f"{entry['name']:10s} extents=({ext}) m  volume={mesh.volume:.3e} m^3  "
            f"mass={mesh.volume * entry['density']:.3f} kg  faces={len(mesh.faces)}"
        )


if __name__ == "__main__":
    main()
