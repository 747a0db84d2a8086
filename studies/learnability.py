"""Learnability: do the labels teach a network about grasps on objects it has never seen?

On ``../shared/learn`` (69 ACRONYM files, about 45 ShapeNetSem meshes, FleX-labelled Panda grasps), split by mesh
with :func:`graspgen.learn.sources.split_by_object` (``valid_fraction=0.3``, ``salt="learn"``: a fixed split, the
same in every run, chosen before any figure was seen), three label sources train the same PointNet evaluator
(:class:`graspgen.learn.model.PointNetEvaluator`, the default :class:`graspgen.learn.train.TrainParams`):

* (a) ``flex``: FleX's labels of the training files' grasps (``grasps/qualities/flex/object_in_gripper``);
* (b) ``sim``: our simulator's labels of the same poses (``gen evaluate``'s path, protocol ``acronym``, Panda,
  the file's mass, friction and scale), cached by content under ``.cache/labels``;
* (b') ``firm``: the same simulation's firm-hold label (held, and the object stayed within 5 mm / 5 degrees of
  where it was in the hand: :attr:`graspgen.sim.protocols.RolloutResult.firm`);
* (c) ``ours``: our own object-centric sets made on the same training meshes, no FleX data at all: the
  ``object_grasps`` stage run on the training files (``--ours RUN[:LABEL]``, repeatable: a run folder of ``gen run
  object_grasps`` with the manifest this script writes with ``--write-manifest``, read by the sets' own label or
  by ``held`` / ``firm``; each a row ``c_<folder>[:LABEL]``; see ``--help``).

Each network is evaluated on FleX's labels and on our two labels of the validation files' grasps: pooled ROC-AUC,
average precision, mean per-object AUC (within-object discrimination, which knowing each object's success rate
cannot lift above 0.5), beside the baselines on the same split (base rate; the per-object rate, an oracle that knows
each held-out object's own rate; gradient-boosted trees on the same features, trained on the same source). The
learning curve trains source (b) on the first 5, 10, 20 and all training meshes (in a seeded order) and evaluates
on both label sources. Training wall and CPU time are reported per network.

Nothing here is tuned on the validation objects: the settings are the library's defaults.

``--pick N`` runs ``gen probe pick`` on every validation mesh with the first network (c) (or (b) without ``--ours``):
the top 10 of N sampled candidates and 10 random ones, rolled out at the file's density and friction.

Run: ``python -m studies.learnability [--learn DIR] [--per-object N] [-j 2] [--ours RUN[:LABEL]]... [--curve]
[--pick N]``; writes
``studies/results_learnability.json`` (gitignored).
"""

from __future__ import annotations

import argparse
import csv
import fnmatch
import hashlib
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from graspgen.learn.features import FeatureParams
from graspgen.learn.sources import ObjectGraspSet, acronym_sets, label_column, split_by_object

HERE = Path(__file__).resolve().parent
DEFAULT_LEARN = Path(os.environ.get("GRASPGEN_LEARN", HERE.parent.parent / "shared" / "learn" / "acronym"))
SALT = "learn"
VALID_FRACTION = 0.3
CURVE = (5, 10, 20)


def _files(root: Path) -> list[Path]:
    files = sorted(root.glob("*.h5"))
    if not files:
        raise SystemExit(f"no ACRONYM files (*.h5) in {root}: pass --learn DIR")
    return files


def _group(path: Path) -> str:
    category, mesh, _ = path.stem.split("_", 2)
    return f"{category}_{mesh}"


def _is_valid(group: str) -> bool:
    return int(hashlib.sha256((SALT + group).encode()).hexdigest()[:8], 16) / 2**32 < VALID_FRACTION


def write_manifest(files: list[Path], path: Path) -> int:
    """The objects manifest of the training files (mesh, scale, density, friction as in each file), for (c)."""
    import h5py

    rows = []
    for f in files:
        if _is_valid(_group(f)):
            continue
        with h5py.File(f, "r") as h:
            rows.append({"path": str((f.parent / h["object/file"][()].decode()).resolve()), "name": f.stem,
                         "scale": float(h["object/scale"][()]), "density": float(h["object/density"][()]),
                         "friction": float(h["object/friction"][()]), "category": f.stem.split("_")[0]})
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return len(rows)


def run_sets(run: Path, label: str | None = None) -> list[ObjectGraspSet]:
    """Object-centric sets from a run folder's shards (``objects`` and ``object_grasps``): (c). ``label``: ``held``
    or ``firm``; None: each set's own (``object_grasps.label``)."""
    import pyarrow.parquet as pq

    from graspgen.io.objects import read_object

    def manifest(stage: str) -> dict[str, Path]:
        lines = (run / "shards" / stage / "manifest.jsonl").read_text().splitlines()
        rows = [json.loads(line) for line in lines if line.strip()]
        return {r["task"]: run / "shards" / stage / r["file"] for r in rows if r.get("status", "ok") == "ok"}

    objects, grasp_files = manifest("objects"), manifest("object_grasps")
    labels = {r["task"]: (r.get("meta") or {}).get("label") for r in
              (json.loads(line) for line in (run / "shards" / "object_grasps" / "manifest.jsonl").read_text()
               .splitlines() if line.strip())}
    sets = []
    for name in sorted(grasp_files):
        column = label_column(label or labels.get(name))
        table = pq.read_table(grasp_files[name], columns=["object_name", "gripper", "pose_object", "width", column])
        if table.num_rows == 0 or name not in objects:
            continue
        record = read_object(objects[name])
        poses = np.asarray(table.column("pose_object").to_pylist(), dtype=np.float64).reshape(-1, 4, 4)
        sets.append(ObjectGraspSet(
            name=name, group=_group(Path(name + ".h5")), vertices=np.asarray(record.vertices, np.float64),
            faces=np.asarray(record.faces, np.int64), T_tcp=poses,
            width=table.column("width").to_numpy().astype(np.float64),
            label=table.column(column).to_numpy(zero_copy_only=False).astype(bool),
            gripper=table.column("gripper")[0].as_py(), source="ours"))
    return sets


def _cpu() -> float:
    t = os.times()  # with the members' worker processes once they have exited
    return t.user + t.system + t.children_user + t.children_system


def _members() -> int:
    from graspgen.learn.train import TrainParams

    return TrainParams().members


def _train(sets, seed: int, jobs: int = 1):
    """A network of the default :class:`TrainParams` (``jobs``: processes training an ensemble's members)."""
    from graspgen.learn.train import TrainParams, train_evaluator

    wall, cpu = time.perf_counter(), _cpu()
    model = train_evaluator(sets, TrainParams(seed=seed), FeatureParams(), jobs=max(1, jobs))
    return model, {"seconds": time.perf_counter() - wall, "cpu_seconds": _cpu() - cpu,
                   "grasps": int(sum(len(s.label) for s in sets)), "objects": len(sets)}


def _measures(report: dict) -> dict:
    return {k: report.get(k) for k in ("auc", "ap", "mean_object_auc", "base_rate", "n")}


def cross_source(train: dict[str, list], valid: dict[str, list], seed: int, models: dict | None = None,
                 jobs: int = 1) -> dict:
    """Every training source's network and GBT on every validation label source (the networks into ``models``)."""
    from graspgen.learn.baselines import baselines
    from graspgen.learn.report import score_report

    out: dict = {}
    for source, sets in train.items():
        if not sets:
            continue
        model, timing = _train(sets, seed, jobs)
        if models is not None:
            models[source] = model
        row = {"train": timing, "eval": {}}
        for target, vsets in valid.items():
            scores = model.score(vsets)
            base = baselines(sets, vsets, FeatureParams(), seed)
            row["eval"][target] = {"network": _measures(score_report(vsets, scores)),
                                   **{k: _measures(v) for k, v in base.items()}}
        out[source] = row
        print(f"  trained on {source}: {timing['grasps']} grasps, {timing['objects']} objects, "
              f"{timing['seconds']:.0f} s wall, {timing['cpu_seconds']:.0f} s CPU")
    return out


def learning_curve(sets: list, valid: dict[str, list], seed: int, jobs: int = 1) -> list[dict]:
    """Source (b) trained on the first 5, 10, 20 and all training meshes (seeded order of the meshes)."""
    from graspgen.learn.report import score_report

    groups = sorted({s.group for s in sets})
    order = [groups[i] for i in np.random.default_rng(seed).permutation(len(groups))]
    rows = []
    for n in [*[c for c in CURVE if c < len(order)], len(order)]:
        keep = set(order[:n])
        model, timing = _train([s for s in sets if s.group in keep], seed, jobs)
        rows.append({"meshes": n, "train": timing,
                     **{t: _measures(score_report(v, model.score(v))) for t, v in valid.items()}})
        print(f"  {n:3d} meshes: " + "  ".join(f"{t} auc {rows[-1][t]['auc']:.3f} object-auc "
                                                f"{rows[-1][t]['mean_object_auc']:.3f}" for t in valid))
    return rows


def file_pick(f: Path, candidates: int, seed: int):
    """What ``gen probe pick`` needs for an ACRONYM file: (mesh path, PickParams at the file's scale, friction and
    density, top 10 of ``candidates``; the generator of ``seed`` and the file's stem)."""
    import h5py

    from graspgen.learn.pick import PickParams

    with h5py.File(f, "r") as h:
        mesh, scale = f.parent / h["object/file"][()].decode(), float(h["object/scale"][()])
        friction, density = float(h["object/friction"][()]), float(h["object/density"][()])
    params = PickParams(candidates=candidates, top=10, scale=scale, friction=friction, density=density)
    return mesh, params, np.random.default_rng([seed, int(hashlib.sha256(f.stem.encode()).hexdigest()[:8], 16)])


def pick_on_valid(model, files: list[Path], candidates: int, seed: int, jobs: int) -> list[dict]:
    """``gen probe pick`` on every validation file's mesh (its scale; ACRONYM's friction 1.0 and density 150): the
    network's top 10 of ``candidates`` sampled grasps and 10 random ones, rolled out (``acronym`` protocol)."""
    from graspgen.learn.pick import pick, simulate_pick

    rows = []
    for f in files:
        mesh, params, rng = file_pick(f, candidates, seed)
        out = simulate_pick(pick(model, mesh, params, rng), model.gripper, params, jobs=jobs)
        rows.append({"name": f.stem, **{k: out[k] for k in ("top_success", "random_success", "top_firm",
                                                              "random_firm", "n_top", "n_random", "candidates",
                                                              "top_outcomes", "random_outcomes")}})
        print(f"  {f.stem[:48]:<48} top {out['top_success']:.2f} (firm {out['top_firm']:.2f})  random "
              f"{out['random_success']:.2f} (firm {out['random_firm']:.2f})  ({out['candidates']} candidates)",
              flush=True)
    return rows


def _print_table(table: dict) -> None:
    print(f"\n{'trained on':<10} {'evaluated on':<12} {'model':<12} {'auc':>6} {'obj-auc':>8} {'ap':>6} {'base':>6}")
    for source, row in table.items():
        for target, models in row["eval"].items():
            for name, m in models.items():
                oa = "-" if m.get("mean_object_auc") is None else f"{m['mean_object_auc']:.3f}"
                print(f"{source:<10} {target:<12} {name:<12} {m['auc']:6.3f} {oa:>8} {m['ap']:6.3f} "
                      f"{m['base_rate']:6.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--learn", type=Path, default=DEFAULT_LEARN, help="folder of ACRONYM files (../shared/learn)")
    ap.add_argument("--per-object", type=int, default=500, help="grasps per file, a fixed seeded sample")
    ap.add_argument("-j", "--jobs", type=int, default=1,
                    help="worker processes for the sim labels and the ensembles' members")
    ap.add_argument("--ours", action="append", default=[], metavar="RUN[:LABEL]",
                    help="run folder of `gen run object_grasps` for (c), optionally with the label to read (held, "
                         "firm; default: the sets' own); repeat for several (c) rows")
    ap.add_argument("--write-manifest", type=Path, default=None,
                    help="write the objects manifest of the training files for (c) and stop")
    ap.add_argument("--curve", action="store_true", help="also the learning curve of source (b)")
    ap.add_argument("--pick", type=int, default=0, metavar="N",
                    help="also gen probe pick on every validation mesh: top 10 of N candidates, network (c)")
    ap.add_argument("--exclude", nargs="*", default=[], metavar="PATTERN",
                    help="leave out the files whose stem matches (fnmatch), from every source alike")
    ap.add_argument("--seed", type=int, default=0, help="the sample of ACRONYM's poses and, by default, the rest")
    ap.add_argument("--train-seed", type=int, default=None,
                    help="the networks' training draws and the picks' candidates (default: --seed); another value "
                         "on the same sample (whose sim labels are cached) measures the training noise")
    ap.add_argument("--out", type=Path, default=HERE / "results_learnability.json")
    args = ap.parse_args()

    files = [f for f in _files(args.learn) if not any(fnmatch.fnmatch(f.stem, p) for p in args.exclude)]
    if args.write_manifest:
        print(f"{write_manifest(files, args.write_manifest)} training files -> {args.write_manifest}")
        return
    t0 = time.perf_counter()
    flex = acronym_sets(files, labels="flex", per_object=args.per_object, seed=args.seed)
    sim = acronym_sets(files, labels="sim", per_object=args.per_object, seed=args.seed, jobs=args.jobs)
    firm = acronym_sets(files, labels="sim", per_object=args.per_object, seed=args.seed, jobs=args.jobs,
                        sim_label="firm")
    label_seconds = time.perf_counter() - t0
    flex_train, flex_valid = split_by_object(flex, VALID_FRACTION, SALT)
    sim_train, sim_valid = split_by_object(sim, VALID_FRACTION, SALT)
    firm_train, firm_valid = split_by_object(firm, VALID_FRACTION, SALT)
    ours: dict[str, list] = {}
    for spec in args.ours:
        run, _, label = spec.partition(":")
        key = "c_" + Path(run).name + (f":{label}" if label else "")
        ours[key] = run_sets(Path(run), label or None)
        leaked = {s.group for s in ours[key]} & {s.group for s in flex_valid}
        if leaked:
            raise SystemExit(f"--ours {spec} holds validation meshes {sorted(leaked)}: make it with --write-manifest")
    print(f"split by mesh: {len({s.group for s in flex_train})} training meshes ({len(flex_train)} files), "
          f"{len({s.group for s in flex_valid})} validation meshes ({len(flex_valid)} files); "
          f"{sum(len(s.label) for s in flex_train)} / {sum(len(s.label) for s in flex_valid)} grasps; "
          f"labels read/simulated in {label_seconds:.0f} s")
    valid = {"flex": flex_valid, "sim": sim_valid, "firm": firm_valid}
    models: dict = {}
    train_seed = args.seed if args.train_seed is None else args.train_seed
    table = cross_source({"a_flex": flex_train, "b_sim": sim_train, "b_firm": firm_train, **ours}, valid,
                         train_seed, models, args.jobs)
    _print_table(table)
    result = {"learn": str(args.learn), "per_object": args.per_object, "excluded": args.exclude,
              "valid_fraction": VALID_FRACTION, "salt": SALT, "train_objects": sorted(s.name for s in flex_train),
              "valid_objects": sorted(s.name for s in flex_valid), "cross_source": table,
              "seed": args.seed, "train_seed": train_seed, "members": _members(),
              "label_seconds": label_seconds, "platform": platform.platform(), "cpus": os.cpu_count()}
    if args.pick:
        source = next(iter(ours), "b_sim")
        print(f"\npick on the validation meshes, network {source}: top 10 of {args.pick} candidates vs 10 random")
        valid_files = [f for f in files if _is_valid(_group(f))]
        rows = pick_on_valid(models[source], valid_files, args.pick, train_seed, args.jobs)
        result["pick"] = {"network": source, "candidates": args.pick, "objects": rows,
                          **{k: float(np.mean([r[k] for r in rows])) for k in ("top_success", "random_success",
                                                                                "top_firm", "random_firm")}}
        print(f"  mean: top {result['pick']['top_success']:.3f}, random {result['pick']['random_success']:.3f}")
    if args.curve:
        print("\nlearning curve, trained on (b) sim labels:")
        result["learning_curve"] = learning_curve(sim_train, valid, train_seed, args.jobs)
    args.out.write_text(json.dumps(result, indent=1))
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
