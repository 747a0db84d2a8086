"""An experiment, not the pipeline's rule: refine only the rough pieces of CoACD's first cut (issue 24's note).

:func:`graspgen.geometry.convex.convex_decomposition` refines parts that stand more than ``slack_p95`` out of the
surface by cutting the whole mesh again at a finer threshold. Here, for each mesh that rule refines, the same first
cut's pieces are also sorted into rough (over 5 % of a piece's area more than ``slack_p95`` outside the mesh: 4,000
area samples over all pieces, distance to the surface, then winding numbers for the far ones) and smooth; each rough
piece is cut again alone, on the mesh inside its hull (a manifold3d intersection), at the threshold that gives the
whole-mesh finer cut's absolute concavity (CoACD's threshold is relative to half the largest extent); the smooth
pieces are kept; all are merged to four times ``max_convex_hull`` as the rule does. Both are timed (CPU s of this
process and the CoACD children) and their hull slack (p95) measured.

Run: ``python -m studies.rough_piece_refine --mode evaluate --categories mug,bowl --per-category 6 [--out FILE]``.
``--mode`` is bench_prep's (``pipeline``: the objects stage's settings; ``evaluate``: ``gen evaluate``'s).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np
import trimesh

import graspgen.geometry.convex as convex
import graspgen.geometry.prepare as prepare
from bench.bench_prep import LEARN, files, prepare_kwargs
from graspgen.geometry.coacd_process import CoacdCrash
from graspgen.geometry.slack import _area_samples, _surface_distance, _winding_number
from pipeline.worker import task_cpu_seconds

ROUGH_SHARE = 0.05
"""A piece is rough when more than this share of its area samples stand over ``slack_p95`` outside the mesh."""


def rough_pieces(mesh: trimesh.Trimesh, pieces: list, slack: float, rng: np.random.Generator) -> np.ndarray:
    """``(n,) bool``: which pieces are rough."""
    triangles = np.concatenate([p.vertices[p.faces] for p in pieces])
    owner = np.concatenate([np.full(len(p.faces), i) for i, p in enumerate(pieces)])
    points, which = _area_samples(triangles, 4000, rng)
    owner = owner[which]
    far = np.flatnonzero(_surface_distance(mesh, points) > slack)
    outside = np.zeros(len(points), dtype=bool)
    if len(far):
        outside[far] = np.abs(_winding_number(mesh, points[far])) <= 0.5
    return np.array([outside[owner == i].mean() > ROUGH_SHARE if np.any(owner == i) else False
                     for i in range(len(pieces))])


def refine_rough(mesh: trimesh.Trimesh, pieces: list, params: convex.CoacdParams) -> tuple[list, dict]:
    """The rough pieces cut again alone, the smooth ones kept, all merged to four times the cap."""
    rough = rough_pieces(mesh, pieces, params.slack_p95, np.random.default_rng(params.seed))
    half = float(np.max(np.ptp(mesh.vertices, axis=0))) / 2
    kept = [p for p, r in zip(pieces, rough) if not r]
    crashed = 0
    for piece in (p for p, r in zip(pieces, rough) if r):
        inside = trimesh.boolean.intersection([mesh, trimesh.Trimesh(piece.vertices, piece.faces, process=False)],
                                              engine="manifold")
        if inside.is_empty or inside.volume <= 0:
            continue
        threshold = min(1.0, params.threshold / 4 * half / (float(np.max(np.ptp(inside.vertices, axis=0))) / 2))
        try:
            cut = convex._coacd_pieces(inside, inside.convex_hull, dataclasses.replace(params, threshold=threshold),
                                       True)
        except CoacdCrash:
            crashed, cut = crashed + 1, []
        kept += cut or [piece]
    return convex._merged(kept, 4 * params.max_convex_hull, params), {"rough": int(rough.sum()), "crashed": crashed}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mode", choices=("pipeline", "evaluate"), default="evaluate")
    ap.add_argument("--categories", default="mug,bowl,knife,bottle,hat")
    ap.add_argument("--per-category", type=int, default=6)
    ap.add_argument("--out", type=Path, default=Path("studies/results_rough_piece_refine.json"))
    args = ap.parse_args()
    rows: list[dict] = []
    record: dict = {}
    rule = convex._refined

    def both(mesh, hull, closed, pieces, first, params):
        start = task_cpu_seconds()
        parts, info = refine_rough(mesh, pieces, params)
        record.update(rough_s=task_cpu_seconds() - start, rough_slack_mm=1e3 * convex._slack_p95(mesh, parts, params),
                      rough_parts=len(parts), pieces=len(pieces), **info)
        start = task_cpu_seconds()
        chosen = rule(mesh, hull, closed, pieces, first, params)
        record.update(rule_s=task_cpu_seconds() - start, rule_slack_mm=1e3 * convex._slack_p95(mesh, chosen, params),
                      rule_parts=len(chosen))
        return chosen

    convex._refined = both
    wanted = args.categories.split(",")
    for entry in files(LEARN, distinct=True):
        taken = sum(r["category"] == entry["category"] for r in rows)
        if entry["category"] not in wanted or taken >= args.per_category:
            continue
        record.clear()
        prepare.prepare_object(entry["mesh"], scale=entry["scale"], rng=np.random.default_rng(0), coacd_cache_dir=None,
                               **prepare_kwargs(args.mode))
        rows.append({"file": entry["file"], "category": entry["category"], **record})
        print(json.dumps(rows[-1]), flush=True)
        args.out.write_text(json.dumps({"mode": args.mode, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
