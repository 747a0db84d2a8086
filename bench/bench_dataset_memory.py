"""Peak memory and time of the dataset stage (its tasks, publish, ``gen validate``, the reader) as the dataset grows.

Synthetic run folders are made from a real run's shards (``--src``, e.g. a default ``make dataset``): ``N`` objects,
each an ``object_grasps`` shard of a real object cut to ``--grasps`` rows under a new name (its object file linked
under that name), and ``N / 4`` scenes, each a real scene's shards (scenes, grasps, rollouts, robustness, metrics,
placed_grasps, the last cut to ``4 * --grasps`` rows) under a new scene id; the real objects stay in the library
(the scene grasps name them). Shards and entries are written with the real schemas, so the stage reads them as the
engine's. Each measured step runs in a child process of its own and reports the high-water mark of its resident
memory (``VmHWM``), the resident memory after its imports, and CPU and wall seconds (and, for ``tasks`` and
``publish``, ``upstream_mb``: what the run's manifest entries take, held as the engine holds them -- the ``gen run``
process with each stage's key-part strings shared, a worker's view without key parts; they grow with the tasks,
~1 kB each, and belong to the engine, not to the stage):

- ``tasks``: the stage's three tasks (object_grasps.parquet, placed_grasps.parquet, grasps.parquet shards);
- ``publish``: :meth:`stages.dataset.DatasetStage.publish` (links, card, plots, ACRONYM and GraspGen exports unless
  ``--no-exports``);
- ``validate``: :func:`stages.dataset.validate` on the published folder (every byte hashed, the table checked);
- ``read``: ``open_dataset``, the first object's set (``object_grasps(name)`` where the reader has it) and one
  scene's grasps.

``--card-rows N ...`` measures the card alone (``card``: :func:`graspgen.io.card_stats.card_stats` and the plots
but the examples) on a synthetic ``grasps.parquet`` of N rows (scenes of 128 grasps, row groups of 16,384 rows, the
columns the card reads: ids, outcome, robustness and pfc of 10 copies on successes, a continuous epsilon, a friction
grid), so the label statistics are measured at sizes the scene shards of ``--src`` do not reach (ACRONYM: 17.7M).

``--code DIR`` runs the children on another checkout (e.g. the code before a change): ``PYTHONPATH=DIR``.

Usage::

    python -m bench.bench_dataset_memory --src out --work /tmp/bench --objects 100 1000
    python -m bench.bench_dataset_memory --work /tmp/bench --objects --card-rows 250000 1000000 4000000
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

SCENE_STAGES = ("scenes", "grasps", "rollouts", "robustness", "metrics", "placed_grasps")
OBJECTS_PER_SCENE = 4


def _manifest(out: Path, stage: str) -> dict[str, dict]:
    entries = {}
    path = out / "shards" / stage / "manifest.jsonl"
    for line in path.read_text().splitlines():
        e = json.loads(line)
        if e["status"] == "ok":
            entries[e["task"]] = e  # the last line of a task wins
    return entries


def _sha(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _put(out: Path, stage: str, task: str, src_entry: dict, *, link: Path | None = None, table=None) -> dict:
    """One shard of ``stage`` for ``task``: a link to ``link`` or ``table`` written; returns its entry."""
    import pyarrow.parquet as pq

    key = hashlib.sha256(f"bench/{stage}/{task}".encode()).hexdigest()
    ext = Path(src_entry["file"]).suffix
    rel = f"{key[:2]}/{key}{ext}"
    path = out / "shards" / stage / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.exists():
        if link is not None:
            os.link(link, path)
        else:
            pq.write_table(table, path, compression="zstd", compression_level=3, store_schema=True)
    return {**src_entry, "key": key, "task": task, "file": rel, "sha256": _sha(path), "bytes": path.stat().st_size,
            "seed": key}


def _renamed(table, column: str, mapping: dict[str, str]):
    import pyarrow as pa

    values = [mapping.get(v, v) for v in table.column(column).to_pylist()]
    i = table.schema.get_field_index(column)
    return table.set_column(i, table.schema.field(column), pa.array(values, pa.string()))


def build(src: Path, out: Path, n: int, grasps: int) -> None:
    """The synthetic run folder of ``n`` objects (module docstring); its entries in ``out/entries.json``."""
    import pyarrow.parquet as pq

    if (out / "entries.json").is_file():
        return
    entries: dict[str, dict[str, dict]] = {}
    objects = _manifest(src, "objects")
    sets = _manifest(src, "object_grasps")
    entries["objects"] = {t: _put(out, "objects", t, e, link=src / "shards/objects" / e["file"])
                          for t, e in objects.items()}
    entries["object_grasps"] = {}
    names = sorted(sets)
    for i in range(n):
        base = names[i % len(names)]
        new = f"syn_{i:05d}"
        e = sets[base]
        t = pq.read_table(src / "shards/object_grasps" / e["file"]).slice(0, grasps)
        t = _renamed(t, "object_name", {base: new})
        entries["object_grasps"][new] = _put(out, "object_grasps", new, e, table=t)
        entries["objects"][new] = _put(out, "objects", new, objects[base], link=src / "shards/objects" /
                                       objects[base]["file"])
    scene_entries = {s: _manifest(src, s) for s in SCENE_STAGES}
    scene_ids = sorted(scene_entries["grasps"])
    for s in SCENE_STAGES:
        entries[s] = {}
    for j in range(max(1, n // OBJECTS_PER_SCENE)):
        base = scene_ids[j % len(scene_ids)]
        new = f"syn_scene_{j:05d}"
        for s in SCENE_STAGES:
            e = scene_entries[s][base]
            path = src / "shards" / s / e["file"]
            if s == "scenes":
                entries[s][new] = _put(out, s, new, e, link=path)
                continue
            t = pq.read_table(path)
            if s == "placed_grasps":
                t = t.slice(0, OBJECTS_PER_SCENE * grasps)
            entries[s][new] = _put(out, s, new, e, table=_renamed(t, "scene_id", {base: new}))
    probe = _manifest(src, "probe")
    entries["probe"] = {t: _put(out, "probe", t, e, link=src / "shards/probe" / e["file"]) for t, e in probe.items()}
    (out / "entries.json").write_text(json.dumps(entries))


CARD_GROUP_ROWS = 16384
CARD_SCENE_ROWS = 128


def build_card_table(out: Path, rows: int) -> None:
    """``out/grasps.parquet``: ``rows`` synthetic rows of the columns the card reads (module docstring)."""
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = out / "grasps.parquet"
    if path.is_file():
        return
    out.mkdir(parents=True, exist_ok=True)
    writer = None
    for start in range(0, rows, CARD_GROUP_ROWS):
        n = min(CARD_GROUP_ROWS, rows - start)
        rng = np.random.default_rng(start)
        row = np.arange(start, start + n)
        outcome = rng.integers(0, 6, n).astype(np.int8)
        ok = outcome == 5
        epsilon = np.where(rng.random(n) < 0.2, 0.0, rng.gamma(2.0, 0.02, n))
        epsilon[rng.random(n) < 0.05] = np.nan
        t = pa.table({
            "scene_id": pa.array([f"scene_{s:07d}" for s in (row // CARD_SCENE_ROWS).tolist()]),
            "grasp_id": pa.array(row % CARD_SCENE_ROWS, pa.int32()),
            "object_name": pa.array([f"obj_{o:04d}" for o in rng.integers(0, 1000, n).tolist()]),
            "gripper": pa.array(["panda"] * n), "outcome": pa.array(outcome),
            "robustness": pa.array(np.where(ok, rng.integers(0, 11, n) / 10, np.nan)),
            "epsilon": pa.array(epsilon), "pfc": pa.array(np.where(ok, rng.integers(0, 11, n) / 10, np.nan)),
            "min_closure_friction": pa.array(np.where(rng.random(n) < 0.3, np.nan, rng.integers(1, 21, n) / 20)),
        })
        if writer is None:
            writer = pq.ParquetWriter(path, t.schema, compression="zstd", compression_level=3)
        writer.write_table(t, row_group_size=n)
    assert writer is not None
    writer.close()


def card_child(out: Path) -> dict:
    """The card of ``out/grasps.parquet`` and its plots (no examples: the table has no scene files)."""
    from graspgen.io.card_stats import CardSettings, card_stats
    from graspgen.viz.plots import draw_plots

    settings = CardSettings(example_scenes=0)
    stats, table = card_stats(out, {}, settings)
    draw_plots(out, table, stats, settings)
    return {"rows": stats["counts"]["grasps"], "sampled": (stats.get("label_sample") or {}).get("sampled")}


# ---------------------------------------------------------------------------------------------------------------
# Children
# ---------------------------------------------------------------------------------------------------------------


def _status(key: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    return 0


def _upstream(out: Path):
    """The run's entries as the engine holds them, in the ``gen run`` process (publish) and as shipped to a
    worker (the tasks): compact (:meth:`pipeline.store.Entry.compacted`, what :func:`pipeline.plan.read_entries`
    gives)."""
    from pipeline.stage import Upstream
    from pipeline.store import Entry

    raw = json.loads((out / "entries.json").read_text())
    done = out / "dataset_entries.json"
    if done.is_file():
        raw["dataset"] = json.loads(done.read_text())
    entries = {}
    for stage, by in raw.items():
        shared: dict[str, dict[str, str]] = {}
        entries[stage] = {t: Entry(**e).compacted(shared) for t, e in by.items()}
    del raw
    return Upstream(out, entries)


def _stage_and_params(src: Path, exports: bool):
    import dataclasses

    from graspgen.io.dataset_table import TABLES
    from pipeline.config import load_config
    from stages.config import Config
    from stages.dataset import OBJECT_SETS, PROBE, DatasetStage

    config = load_config(Config, src / "shards" / "config.yaml")
    if not exports:
        config = dataclasses.replace(config, dataset=dataclasses.replace(config.dataset, acronym=False, graspgen=False))
    stage = DatasetStage(tables=TABLES, object_sets=OBJECT_SETS, probe=PROBE)
    return stage, stage.params(config)


def child(phase: str, src: Path, out: Path, exports: bool) -> dict:
    import numpy as np  # noqa: F401 - the imports every phase pays, before the base line

    import stages.dataset  # noqa: F401
    from graspgen.io.reader import open_dataset

    base = _status("VmRSS")
    t0, c0 = time.perf_counter(), time.process_time()
    extra: dict = {}
    if phase == "tasks":
        from pipeline.store import Entry

        stage, params = _stage_and_params(src, exports)
        r0 = _status("VmRSS")
        upstream = _upstream(out)
        extra["upstream_mb"] = (_status("VmRSS") - r0) / 1024
        done = {}
        for task in stage.tasks(params, upstream):
            key = hashlib.sha256(f"bench/dataset/{task.id}".encode()).hexdigest()
            rel = f"{key[:2]}/{key}.parquet"
            path = out / "shards" / "dataset" / rel
            path.parent.mkdir(parents=True, exist_ok=True)
            meta = stage.run(task, params, upstream, np.random.default_rng(0), path, None)
            done[task.id] = Entry(key=key, task=task.id, status="ok", file=rel, sha256=_sha(path),
                                  bytes=path.stat().st_size, meta=meta, parts={"stage": "1"}).__dict__
        (out / "dataset_entries.json").write_text(json.dumps(done, default=str))
        extra["rows"] = {t: e["meta"].get("rows", e["meta"].get("grasps")) for t, e in done.items()}
    elif phase == "publish":
        stage, params = _stage_and_params(src, exports)
        r0 = _status("VmRSS")
        upstream = _upstream(out)
        extra["upstream_mb"] = (_status("VmRSS") - r0) / 1024
        stage.publish(params, upstream, out)
    elif phase == "validate":
        from stages.dataset import validate

        problems, checked = validate(out / "dataset")
        extra.update(problems=len(problems), first_problems=problems[:3], files=checked)
    elif phase == "card":
        extra.update(card_child(out))
    elif phase == "read":
        ds = open_dataset(out)
        extra["open_s"] = time.perf_counter() - t0
        t1 = time.perf_counter()
        if hasattr(ds, "object_grasps"):
            extra["one_object_rows"] = len(ds.object_grasps("syn_00000"))
        else:  # the reader before: the object sets are read with pyarrow, filtered
            import pyarrow.parquet as pq

            extra["one_object_rows"] = len(pq.read_table(out / "dataset" / "object_grasps.parquet",
                                                         filters=[("object_name", "==", "syn_00000")]))
        extra["one_object_s"] = time.perf_counter() - t1
        t1 = time.perf_counter()
        extra["one_scene_rows"] = len(ds.grasps(scene_id="syn_scene_00000"))
        extra["one_scene_s"] = time.perf_counter() - t1
    return {"phase": phase, "peak_mb": _status("VmHWM") / 1024, "base_mb": base / 1024,
            "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0, **extra}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", type=Path, default=Path("/work/fresh/out"), help="a real run folder (shards)")
    ap.add_argument("--work", type=Path, required=True, help="where the synthetic run folders go")
    ap.add_argument("--objects", type=int, nargs="*", default=[100, 1000])
    ap.add_argument("--card-rows", type=int, nargs="*", default=[], help="also the card alone on tables of N rows")
    ap.add_argument("--grasps", type=int, default=200, help="grasps per object set")
    ap.add_argument("--code", type=Path, default=None, help="checkout the children run (PYTHONPATH)")
    ap.add_argument("--tag", default="", help="name of this code in the output folders (e.g. before, after)")
    ap.add_argument("--no-exports", action="store_true", help="publish without the ACRONYM and GraspGen exports")
    ap.add_argument("--child", nargs=2, metavar=("PHASE", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    exports = not args.no_exports
    if args.child:
        print(json.dumps(child(args.child[0], args.src, Path(args.child[1]), exports)))
        return
    env = dict(os.environ)
    if args.code is not None:
        env["PYTHONPATH"] = str(args.code)
    rows = []
    for n in args.card_rows:
        out = args.work / f"card_{n}"
        build_card_table(out, n)
        cmd = [sys.executable, __file__, "--work", str(args.work), "--child", "card", str(out)]
        done = subprocess.run(cmd, capture_output=True, text=True, env=env)
        if done.returncode:
            sys.exit(f"card at {n} rows failed:\n{done.stderr[-3000:]}")
        r = {"objects": n, **json.loads(done.stdout.strip().splitlines()[-1])}
        rows.append(r)
        print(json.dumps(r), flush=True)
    for n in args.objects:
        shared = args.work / f"inputs_{n}"
        build(args.src, shared, n, args.grasps)
        out = args.work / f"run_{n}_{args.tag or 'code'}{'' if exports else '_noexp'}"
        if not out.exists():  # the inputs as links, the stage's own outputs fresh
            subprocess.run(["cp", "-al", str(shared), str(out)], check=True)
        for phase in ("tasks", "publish", "validate", "read"):
            # The file as a script, not -m from this checkout: with --code the children import that checkout's code.
            cmd = [sys.executable, __file__, "--src", str(args.src), "--work", str(args.work),
                   *(["--no-exports"] if not exports else []), "--child", phase, str(out)]
            done = subprocess.run(cmd, capture_output=True, text=True, env=env)
            if done.returncode:
                sys.exit(f"{phase} at {n} objects failed:\n{done.stderr[-3000:]}")
            r = {"objects": n, **json.loads(done.stdout.strip().splitlines()[-1])}
            rows.append(r)
            print(json.dumps(r), flush=True)
    print(f"\n{'N':>7} {'phase':>9} {'peak MB':>8} {'base MB':>8} {'cpu s':>7} {'wall s':>7}")
    for r in rows:
        print(f"{r['objects']:>7} {r['phase']:>9} {r['peak_mb']:>8.1f} {r['base_mb']:>8.1f} {r['cpu_s']:>7.2f} "
              f"{r['wall_s']:>7.2f}")


if __name__ == "__main__":
    main()
