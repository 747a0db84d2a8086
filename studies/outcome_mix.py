"""Outcome mix: where our labels part from FleX's, on ACRONYM's poses and in our own object-centric sets.

Two populations of Panda grasps on the training meshes of ``../shared/learn`` (the learnability study's fixed split;
the validation meshes are never read):

* ACRONYM's poses: a fixed seeded sample of ``--per-object`` grasps per file (the learnability study's sample), with
  FleX's label and our simulator's outcome and firm label (``gen evaluate``'s path, acronym protocol, the file's
  mass, friction and scale; :func:`graspgen.learn.sources.sim_outcomes`, cached);
* our object-centric sets: a run folder of ``gen run object_grasps`` on the training manifest (``--ours RUN``), its
  kept rows and the collisions it dropped (the tasks' metadata).

For each: the outcome mix (collision at placement, no contact, slip, held but not firm, firm), and by two geometric
measures of each grasp the share of grasps and the success rates (ours held and firm; FleX's where it has labels):

* pad overlap, mm^2: the smaller over the two pads of the pad-face area that meets the surface when the pad closes
  (a 7 x 7 grid of rays over the pad face, ``gripper.pad_size``, cast from the open pad towards the other; a cell
  counts when its ray hits within ``--touch`` of the pad's first hit);
* closing-point distance, mm: from the TCP (the pads' centre) to the object's centre of mass (uniform density).

Run: ``python -m studies.outcome_mix [--learn DIR] [--per-object 200] [--ours RUN] [--out FILE]``; prints the
tables docs/fidelity.md quotes and writes ``studies/results_outcome_mix.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from studies.learnability import DEFAULT_LEARN, _files, _group, _is_valid

HERE = Path(__file__).resolve().parent
OVERLAP_BINS = (0.0, 25.0, 75.0, 150.0, 250.0, 1e9)
"""Pad-overlap bins, mm^2 (the Panda's pad face is 17.4 x 17.6 = 306 mm^2)."""
DISTANCE_BINS = (0.0, 15.0, 30.0, 50.0, 80.0, 1e9)
"""Closing-point to centre-of-mass bins, mm."""
MIX = ("collision", "no_contact", "slipped", "held_not_firm", "firm")


def pad_overlap(mesh, T: np.ndarray, gripper, touch: float = 0.002, cells: int = 7) -> np.ndarray:
    """(m,) float64 mm^2: per grasp ``T (m, 4, 4)`` the smaller of the two pads' faces' areas that meet the mesh
    within ``touch`` (m) of the pad's first hit, closing from fully open."""
    _, w, length = gripper.pad_size
    y, z = np.meshgrid((np.arange(cells) + 0.5) / cells * w - w / 2,
                       (np.arange(cells) + 0.5) / cells * length - length / 2)
    grid = np.stack([y.ravel(), z.ravel()], axis=1)
    cell_area = (w / cells) * (length / cells) * 1e6
    m, k = len(T), len(grid)
    out = np.full((m, 2), 0.0)
    for side, sign in enumerate((-1.0, 1.0)):
        local = np.zeros((m, k, 4))
        local[..., 0] = sign * (gripper.max_width / 2 + 1e-3)
        local[..., 1:3] = grid
        local[..., 3] = 1.0
        origins = np.einsum("mij,mkj->mki", T, local)[..., :3].reshape(-1, 3)
        direction = np.repeat(-sign * T[:, :3, 0], k, axis=0)
        loc, ray, _ = mesh.ray.intersects_location(origins, direction, multiple_hits=False)
        dist = np.full(m * k, np.inf)
        dist[ray] = np.linalg.norm(loc - origins[ray], axis=1)
        dist = dist.reshape(m, k)
        dist[dist > gripper.max_width + 2e-3] = np.inf
        first = dist.min(axis=1, keepdims=True)
        out[:, side] = ((dist <= first + touch) & np.isfinite(dist)).sum(axis=1) * cell_area
    return out.min(axis=1)


def com_distance(T: np.ndarray, com: np.ndarray) -> np.ndarray:
    """(m,) float64 mm from each TCP to the centre of mass."""
    return np.linalg.norm(T[:, :3, 3] - com, axis=1) * 1e3


def _mix(outcome: np.ndarray, firm: np.ndarray) -> dict[str, int]:
    return {"collision": int((outcome <= 2).sum()), "no_contact": int((outcome == 3).sum()),
            "slipped": int((outcome == 4).sum()), "held_not_firm": int(((outcome == 5) & ~firm).sum()),
            "firm": int(firm.sum())}


def _binned(values: np.ndarray, edges, held, firm, flex=None) -> list[dict]:
    rows = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (values >= lo) & (values < hi)
        n = int(sel.sum())
        row = {"bin": [lo, hi if hi < 1e8 else None], "n": n, "share": n / max(len(values), 1),
               "held": float(held[sel].mean()) if n else None, "firm": float(firm[sel].mean()) if n else None}
        if flex is not None:
            row["flex"] = float(flex[sel].mean()) if n else None
        rows.append(row)
    return rows


def acronym_population(files: list[Path], per_object: int, seed: int) -> dict:
    """ACRONYM's poses of the training files: FleX's labels, our outcomes, the two measures."""
    import trimesh

    from graspgen.grippers import load_gripper
    from graspgen.io.acronym import read_acronym
    from graspgen.learn.sources import _sample, sim_outcomes

    cols: dict[str, list] = {k: [] for k in ("flex", "outcome", "firm", "overlap", "distance")}
    for path in files:
        acr = read_acronym(path)
        mesh_path = path.parent / acr.object_file
        mesh = trimesh.load(mesh_path, force="mesh", process=False)
        mesh.apply_scale(acr.object_scale)
        gripper = load_gripper(acr.gripper)
        idx = _sample(len(acr), per_object, seed, path.stem)
        T = acr.tcp_poses()[idx]
        outcome, firm = sim_outcomes(mesh_path, acr, T, gripper.name, "acronym", Path(".cache") / "labels")
        cols["flex"].append(np.asarray(acr.success)[idx] == 1)
        cols["outcome"].append(outcome)
        cols["firm"].append(firm)
        cols["overlap"].append(pad_overlap(mesh, T, gripper))
        cols["distance"].append(com_distance(T, np.asarray(mesh.center_mass)))
    return {k: np.concatenate(v) for k, v in cols.items()}


def ours_population(run: Path, selection: str | None = None) -> tuple[dict, dict]:
    """Our sets' kept rows (outcome, firm, the two measures) and the summed task metadata; ``selection``: only the
    sets made with it (``natural``, ``balanced``; sets that do not say are ``balanced``)."""
    import pyarrow.parquet as pq
    import trimesh

    from graspgen.grippers import load_gripper
    from graspgen.io.objects import read_object

    def manifest(stage: str) -> dict[str, dict]:
        lines = (run / "shards" / stage / "manifest.jsonl").read_text().splitlines()
        rows = [json.loads(line) for line in lines if line.strip()]
        return {r["task"]: r for r in rows if r.get("status", "ok") == "ok"}

    objects, sets = manifest("objects"), manifest("object_grasps")
    if selection is not None:
        sets = {k: r for k, r in sets.items() if r.get("meta", {}).get("selection", "balanced") == selection}
    cols: dict[str, list] = {k: [] for k in ("outcome", "firm", "overlap", "distance")}
    tried = dropped = objects_read = 0
    for name in sorted(sets):
        t = pq.read_table(run / "shards" / "object_grasps" / sets[name]["file"],
                          columns=["pose_object", "outcome", "firm", "gripper"])
        meta = sets[name].get("meta", {})
        tried += int(meta.get("tried", 0))
        dropped += int(meta.get("collisions_dropped", 0))
        objects_read += 1
        if t.num_rows == 0:
            continue
        record = read_object(run / "shards" / "objects" / objects[name]["file"])
        mesh = trimesh.Trimesh(np.asarray(record.vertices), np.asarray(record.faces), process=False)
        T = np.asarray(t.column("pose_object").to_pylist(), dtype=np.float64).reshape(-1, 4, 4)
        cols["outcome"].append(t.column("outcome").to_numpy().astype(np.int8))
        cols["firm"].append(t.column("firm").to_numpy(zero_copy_only=False).astype(bool))
        cols["overlap"].append(pad_overlap(mesh, T, load_gripper(t.column("gripper")[0].as_py())))
        cols["distance"].append(com_distance(T, np.asarray(record.center_of_mass)))
    return {k: np.concatenate(v) for k, v in cols.items()}, {"tried": tried, "collisions_dropped": dropped,
                                                             "objects": objects_read}


def summary(pop: dict) -> dict:
    held, firm = pop["outcome"] == 5, pop["firm"]
    flex = pop.get("flex")
    out = {"n": int(len(held)), "mix": _mix(pop["outcome"], firm), "held": float(held.mean()),
           "firm": float(firm.mean()),
           "by_overlap": _binned(pop["overlap"], OVERLAP_BINS, held, firm, flex),
           "by_distance": _binned(pop["distance"], DISTANCE_BINS, held, firm, flex)}
    if flex is not None:
        out["flex"] = float(flex.mean())
        out["agreement_held"] = float((held == flex).mean())
        out["agreement_firm"] = float((firm == flex).mean())
        out["flex_fail_we_hold"] = float((held & ~flex).sum() / max((~flex).sum(), 1))
        out["flex_fail_firm"] = float((firm & ~flex).sum() / max((~flex).sum(), 1))
    return out


def _print(name: str, s: dict) -> None:
    print(f"\n{name}: {s['n']} grasps; mix " + ", ".join(f"{k} {v} ({v / max(s['n'], 1):.1%})"
                                                     for k, v in s["mix"].items()))
    print(f"  held {s['held']:.3f}  firm {s['firm']:.3f}" + (f"  flex {s['flex']:.3f}; of FleX's failures we hold "
                                                              f"{s['flex_fail_we_hold']:.2f}, firmly "
                                                              f"{s['flex_fail_firm']:.2f}" if "flex" in s else ""))
    for key, unit in (("by_overlap", "mm^2"), ("by_distance", "mm")):
        print(f"  {key} ({unit}):  bin | share | held | firm" + (" | flex" if "flex" in s else ""))
        for r in s[key]:
            hi = "inf" if r["bin"][1] is None else f"{r['bin'][1]:g}"
            vals = [r["held"], r["firm"]] + ([r["flex"]] if "flex" in s else [])
            print(f"    [{r['bin'][0]:g}, {hi}) | {r['share']:.3f} | " + " | ".join(
                "-" if v is None else f"{v:.2f}" for v in vals))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--learn", type=Path, default=DEFAULT_LEARN)
    ap.add_argument("--per-object", type=int, default=200)
    ap.add_argument("--ours", action="append", default=[], metavar="RUN[:SELECTION]",
                    help="run folder(s) of gen run object_grasps, optionally only its sets of one selection")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=HERE / "results_outcome_mix.json")
    args = ap.parse_args()
    train = [f for f in _files(args.learn) if not _is_valid(_group(f))]
    result = {"acronym": summary(acronym_population(train, args.per_object, args.seed)), "ours": {}}
    _print("ACRONYM's poses, training files", result["acronym"])
    for spec in args.ours:
        run, _, selection = spec.partition(":")
        pop, meta = ours_population(Path(run), selection or None)
        result["ours"][spec] = {**summary(pop), **meta}
        _print(f"our sets ({spec}; {meta['objects']} objects, {meta['tried']} tried, {meta['collisions_dropped']} "
               "collisions dropped)", result["ours"][spec])
    args.out.write_text(json.dumps(result, indent=1))
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
