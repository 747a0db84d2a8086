"""The refinement's two ways on ../shared/learn's meshes: the rough pieces of CoACD's first cut cut again alone, or
the whole mesh cut again (issue 24's note).

:func:`graspgen.geometry.convex.convex_decomposition` refines parts that stand more than ``slack_p95`` out of the
surface. For each mesh it refines, this study runs, on the same first cut (CoACD's pieces before merging):

* ``rough``: each rough piece (over 5 % of its area more than ``slack_p95`` outside the mesh,
  :func:`graspgen.geometry.slack.rough_parts`) cut again alone, on the mesh inside its hull, at the concavity
  of a whole-mesh cut at a quarter of the threshold; the other pieces kept
  (:func:`graspgen.geometry.convex._rough_pieces_recut`);
* ``whole``: the whole mesh cut again, at a quarter of the threshold where the first cut made at most twice
  ``max_convex_hull`` pieces, else at half;

each merged to four times ``max_convex_hull``, and records their CPU seconds (this process and the CoACD children),
the pieces they made and their hull slack (p95, mm), with the first cut's CPU seconds, its pieces, how many are rough
and the rough pieces' share of the pieces' area. Meshes whose first cut made more than four times ``max_convex_hull``
pieces are only merged again by the rule and are recorded without the two.

Run: ``python -m studies.rough_piece_refine --mode pipeline|evaluate [--categories mug,bowl] [--per-category N]
[--every K --offset I] [--out FILE]``. ``--mode`` is bench_prep's (``pipeline``: the objects stage's settings;
``evaluate``: ``gen evaluate``'s).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

import graspgen.geometry.convex as convex
import graspgen.workflows.prepare as prepare
from bench.bench_prep import LEARN, files, prepare_kwargs
from graspgen.geometry.slack import rough_parts
from pipeline.worker import task_cpu_seconds


def _area(piece) -> float:
    t = piece.vertices[piece.faces]
    return float(0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum())


def _timed(record: dict, name: str, make):
    start = task_cpu_seconds()
    out = make()
    record[f"{name}_s"] = task_cpu_seconds() - start
    return out


def both_ways(mesh, hull, closed, pieces, params) -> dict:
    """The two refinements of one first cut ``pieces`` (see the module's docstring), as a record."""
    cap = 4 * params.max_convex_hull
    record: dict = {"pieces": len(pieces)}
    rough = _timed(record, "classify", lambda: rough_parts(
        mesh, [convex._part_arrays(p) for p in pieces], params.slack_p95, convex._ROUGH_SHARE, params.slack_samples,
        np.random.default_rng(params.seed)))
    areas = np.array([_area(p) for p in pieces])
    record.update(rough=int(rough.sum()), rough_area_share=float(areas[rough].sum() / areas.sum()))
    if rough.any():
        cut = _timed(record, "rough", lambda: convex._rough_pieces_recut(mesh, pieces, rough, params))
        parts = convex._merged(cut, cap, params)
        record.update(rough_pieces=len(cut), rough_slack_mm=1e3 * convex._slack_p95(mesh, parts, params))
    divisor = 4 if len(pieces) <= convex._QUARTER_CUT_PIECES * params.max_convex_hull else 2
    finer = dataclasses.replace(params, threshold=params.threshold / divisor)
    cut = _timed(record, "whole", lambda: convex._coacd_pieces(mesh, hull, finer, closed))
    parts = convex._merged(cut, cap, params)
    record.update(divisor=divisor, whole_pieces=len(cut), whole_slack_mm=1e3 * convex._slack_p95(mesh, parts, params))
    return record


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mode", choices=("pipeline", "evaluate"), default="evaluate")
    ap.add_argument("--categories", default="")
    ap.add_argument("--per-category", type=int, default=0)
    ap.add_argument("--every", type=int, default=1, help="take every K-th mesh (with --offset: split a run)")
    ap.add_argument("--offset", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("studies/results_rough_piece_refine.json"))
    args = ap.parse_args()
    rows: list[dict] = []
    record: dict = {}
    first_cut = convex._coacd_pieces

    def timed_first(mesh, hull, params, closed):
        if "first_s" in record:
            return first_cut(mesh, hull, params, closed)
        return _timed(record, "first", lambda: first_cut(mesh, hull, params, closed))

    def study(mesh, hull, closed, pieces, first, params):
        if len(pieces) <= convex._HALF_CUT_PIECES * params.max_convex_hull:
            record.update(both_ways(mesh, hull, closed, pieces, params), first_slack_mm=1e3 * first[1])
        return first[0]

    convex._coacd_pieces, convex._refined = timed_first, study
    wanted = set(args.categories.split(",")) - {""}
    chosen = [e for e in files(LEARN, distinct=True) if not wanted or e["category"] in wanted]
    for entry in chosen[args.offset::args.every]:
        if args.per_category and sum(r["category"] == entry["category"] for r in rows) >= args.per_category:
            continue
        record.clear()
        prepare.prepare_object(entry["mesh"], scale=entry["scale"], rng=np.random.default_rng(0),
                               coacd_cache_dir=None, **prepare_kwargs(args.mode))
        rows.append({"file": entry["file"], "category": entry["category"], **record})
        print(json.dumps(rows[-1]), flush=True)
        args.out.write_text(json.dumps({"mode": args.mode, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
