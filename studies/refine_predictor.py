"""Whether a mesh's global shape says which way the objects stage's decomposition goes, so that its first CoACD cut
could be skipped (tried, not adopted: none of these separates the ways; docs/cluster.md).

For every distinct mesh of ../shared/learn, prepared as the objects stage prepares it (repaired, at the file's
scale): its fill (volume / convex hull volume), its area over its hull's, and its volume / area over its largest
extent (a thinness); beside the first cut's pieces and the way the refinement went, read from a ``bench_prep`` results
file of the rule (by default ``bench/results_bench_prep_i5_rough_area_pipeline.json``). Skipping the first cut pays
only where a mesh would be cut again whole at a quarter of the threshold; the rough-pieces, half-threshold and
merge-only ways exist because a quarter-threshold cut of those meshes costs several times more
(``studies/direct_fine_cut.py``).

Run: ``python -m studies.refine_predictor [--results FILE]``; prints one row per mesh, sorted by category and fill.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np

from bench.bench_prep import LEARN, ROOT, files, prepare_kwargs
from graspgen.geometry.mesh_io import load_mesh
from graspgen.geometry.repair import repair_mesh
from graspgen.geometry.units import normalize_units

RESULTS = ROOT / "bench" / "results_bench_prep_i5_rough_area_pipeline.json"


def way(log: list[str]) -> tuple[int, str]:
    """The first cut's pieces (-1: not refined) and the way the refinement went, from a bench_prep row's log."""
    if not log:
        return -1, "first cut kept"
    pieces = re.match(r".*?: (\d+) pieces", log[0])
    return int(pieces.group(1)) if pieces else -1, log[0].split("refined: ")[1].split(",")[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", type=Path, default=RESULTS)
    args = ap.parse_args()
    rows = {r["file"]: r for r in json.loads(args.results.read_text())["rows"] if r["mode"] == "pipeline"}
    stage = prepare_kwargs("pipeline")  # the objects stage's extent bounds, as it prepares the mesh
    table = []
    for entry in files(LEARN, distinct=True):
        if entry["file"] not in rows:
            continue
        mesh, _ = repair_mesh(load_mesh(entry["mesh"]))
        mesh, _, _ = normalize_units(mesh, scale=entry["scale"], min_extent=stage["min_extent"],
                                     max_extent=stage["max_extent"])
        hull = mesh.convex_hull
        pieces, how = way(rows[entry["file"]]["log"])
        table.append((entry["category"], mesh.volume / hull.volume, mesh.area / hull.area,
                      mesh.volume / mesh.area / float(np.max(np.ptp(mesh.vertices, axis=0))), pieces, how,
                      rows[entry["file"]]["cpu_s"]))
    print("| category | fill | area / hull area | thinness | first cut pieces | way | CPU s |")
    print("|---|---|---|---|---|---|---|")
    for category, fill, area, thin, pieces, how, cpu in sorted(table):
        print(f"| {category} | {fill:.2f} | {area:.2f} | {thin:.4f} | {pieces} | {how} | {cpu:.1f} |")


if __name__ == "__main__":
    main()
