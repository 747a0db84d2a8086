"""The objects stage's decomposition rule against one CoACD cut straight at a quarter of its threshold (issue 24's
note: the first cut is spent on 46 of 47 learn meshes before the finer cut anyway).

For every distinct mesh of ../shared/learn, in one process, alternating which goes first: ``rule`` (the objects
stage's :class:`graspgen.geometry.convex.CoacdParams`, first cut at 0.08 and the refinement) and ``direct`` (threshold
0.02, the refined meshes' 64-part cap, no refinement). Records CPU seconds (this process and the CoACD children), the
parts and their hull slack (p95 mm, 20,000 samples).

Run: ``python -m studies.direct_fine_cut --part 0 --parts 2 --out FILE`` (one process per core, then merge).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np
import trimesh

import graspgen.geometry.convex as convex
import graspgen.workflows.prepare as prepare
from bench.bench_prep import LEARN, files, prepare_kwargs
from pipeline.worker import task_cpu_seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", type=int, default=0)
    ap.add_argument("--parts", type=int, default=1)
    ap.add_argument("--out", type=Path, default=Path("studies/results_direct_fine_cut.json"))
    args = ap.parse_args()
    kwargs = prepare_kwargs("pipeline")
    rule = kwargs["coacd"]
    variants = {"rule": rule, "direct": dataclasses.replace(rule, threshold=rule.threshold / 4,
                                                             max_convex_hull=4 * rule.max_convex_hull,
                                                             refine_excess=0.0)}
    rows = []
    for i, entry in enumerate(files(LEARN, distinct=True)[args.part::args.parts]):
        for name in list(variants) if i % 2 == 0 else list(variants)[::-1]:
            start = task_cpu_seconds()
            obj = prepare.prepare_object(entry["mesh"], scale=entry["scale"], rng=np.random.default_rng(0),
                                         coacd_cache_dir=None, **dict(kwargs, coacd=variants[name]))
            cpu = task_cpu_seconds() - start
            mesh = trimesh.Trimesh(obj.vertices, obj.faces, process=False)
            slack = convex.hull_slack(mesh, list(obj.convex_parts), 20_000, np.random.default_rng(0)).p95
            rows.append({"file": entry["file"], "variant": name, "cpu_s": cpu, "slack_mm": 1e3 * slack,
                         "parts": len(obj.convex_parts)})
            print(json.dumps(rows[-1]), flush=True)
            args.out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
