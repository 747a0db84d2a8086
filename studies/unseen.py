"""The issue's own check on ACRONYM meshes outside ``../shared``: do our default sets teach there too?

Two steps around the command-line check (``gen run``, ``gen probe train/eval/pick``; the commands are in
docs/fidelity.md, "On meshes outside ../shared"):

``prepare`` chooses the files. Its source is AffordanceGrasp's ``data/affordance_grasps`` (github
turbohiro/AffordanceGrasp, ACRONYM's FleX labels on ShapeNetSem meshes, CC BY-NC 4.0: the source of
``../shared/learn``). It keeps one file per mesh whose mesh is in neither ``../shared/learn`` nor
``../shared/calibration``, in a fixed order (sha1 of the mesh id), up to a quota per category, and only files whose
poses line up with their mesh: the file's ``grasps/transforms_adjust`` (the poses in the re-exported meshes' frame,
as in ``../shared/learn``) put at least 99 % of FleX's successes' closing points within 2 cm of the surface, the
criterion ``../shared/learn``'s README states. Nothing about our labels or networks enters the choice. It writes
the files in ACRONYM's layout (``grasps/transforms`` = the adjusted poses) and an objects manifest (mesh, scale,
density, friction, category).

``summary`` reads what the commands wrote (``gen probe eval``'s JSON per network, ``gen probe pick``'s per mesh),
adds the per-object-rate oracle computed from the files' FleX labels, and writes one results file.

``plates`` measures why the knives fail there: a Panda grasp face-on at the centre of a plate, by thickness and
density, with the gripper's contact as it is and as :data:`PLATE_SETTINGS` changes it (:func:`plate_sweep`);
``resim`` rolls one object's set grasps out again with the model's contact, a 1 ms time constant and the default
bounded sink (:func:`resimulate`).

Run: ``python -m studies.unseen prepare --source DIR --out DIR`` then, after the commands,
``python -m studies.unseen summary --files DIR --eval a A.json --eval c C.json --picks DIR --part NAME``;
``python -m studies.unseen plates``; ``python -m studies.unseen resim --dataset U/out/dataset --object NAME --mesh
MESH --scale SCALE``.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from graspgen.learn.report import roc_auc

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared"
QUOTA = {"Bottle": 6, "Bowl": 6, "Mug": 8, "Knife": 6, "Hat": 2, "Scissors": 2}
"""Files per category: the categories of ``../shared/learn``, in about its proportions."""
TCP_DEPTH = 0.1034
"""Distance (m) from the Panda's grasp frame to the closing point along its approach axis (ACRONYM's frame)."""
ALIGNED = 0.99
"""Share of FleX's successes whose closing point lies within :data:`NEAR` of the surface for a file to count as
lined up with its mesh (``../shared/learn``'s README)."""
NEAR = 0.02
"""Metres."""


def seen_meshes(shared: Path) -> set[str]:
    """Mesh ids (``Category_<id>_<scale>.h5``'s id, and the calibration meshes' file names) under ``shared``."""
    ids = {p.stem.split("_")[-2] for p in shared.rglob("*.h5") if p.stem.count("_") >= 2}
    return ids | {p.stem for p in shared.rglob("*.obj")}


def alignment(T: np.ndarray, success: np.ndarray, mesh) -> float:
    """Share of the successful poses' closing points within :data:`NEAR` of ``mesh``'s surface.

    ``T``: ``(n, 4, 4)`` grasp poses; ``success``: ``(n,) bool``; ``mesh``: a scaled ``trimesh.Trimesh``.
    0.0 when no pose succeeds (nothing to line up)."""
    import trimesh

    if not success.any():
        return 0.0
    points = (T[success] @ np.array([0.0, 0.0, TCP_DEPTH, 1.0]))[:, :3]
    return float(np.mean(np.abs(trimesh.proximity.signed_distance(mesh, points)) < NEAR))


def _sha1(text: str) -> str:
    return hashlib.sha1(text.encode()).hexdigest()


def prepare(source: Path, out: Path, shared: Path = SHARED, quota: dict[str, int] = QUOTA) -> list[dict]:
    """Choose, convert and list the files (module docstring); returns the manifest's rows."""
    import h5py
    import trimesh

    files = sorted((source / "grasps").glob("*.h5"))
    if not files:
        raise SystemExit(f"--source {source}: no ACRONYM files in {source / 'grasps'} (give AffordanceGrasp's "
                         "data/affordance_grasps)")
    seen = seen_meshes(shared)
    by_mesh: dict[tuple[str, str], list[Path]] = defaultdict(list)
    for f in files:
        category, mesh_id, _ = f.stem.split("_", 2)
        if category in quota and mesh_id not in seen:
            by_mesh[(category, mesh_id)].append(f)
    rows = []
    for category, wanted in quota.items():
        meshes = sorted((k for k in by_mesh if k[0] == category), key=lambda k: _sha1(k[1]))
        kept = 0
        for key in meshes:
            if kept == wanted:
                break
            f = sorted(by_mesh[key], key=lambda p: _sha1(p.name))[0]
            with h5py.File(f, "r") as h:
                T = h["grasps/transforms_adjust"][()]
                success = h["grasps/qualities/flex/object_in_gripper"][()] > 0
                mesh_file, scale = h["object/file"][()].decode(), float(h["object/scale"][()])
                physics = {k: float(h[f"object/{k}"][()]) for k in ("density", "friction")}
            mesh = trimesh.load(source / mesh_file, force="mesh")
            mesh.apply_scale(scale)
            share = alignment(T, success, mesh)
            print(f"  {f.stem[:48]:<48} lined up {share:.3f}", flush=True)
            if share < ALIGNED:
                continue
            kept += 1
            rows.append({"path": str((out / mesh_file).resolve()), "name": f.stem, "scale": scale, **physics,
                         "category": category})
            _write_acronym(f, out / f.name, T)
            (out / mesh_file).parent.mkdir(parents=True, exist_ok=True)
            (out / mesh_file).write_bytes((source / mesh_file).read_bytes())
    with open(out / "objects.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=["path", "name", "scale", "density", "friction", "category"])
        writer.writeheader()
        writer.writerows(rows)
    return rows


def _write_acronym(src: Path, dst: Path, T: np.ndarray) -> None:
    """``src`` in ACRONYM's layout with ``grasps/transforms`` = ``T``, the FleX labels, object and gripper."""
    import h5py

    dst.parent.mkdir(parents=True, exist_ok=True)
    with h5py.File(src, "r") as h, h5py.File(dst, "w") as o:
        for group in ("object", "gripper"):
            h.copy(group, o)
        h.copy("grasps/qualities", o.require_group("grasps"))
        o["grasps/transforms"] = T


def object_rate_auc(files: list[Path]) -> float | None:
    """Pooled ROC-AUC of FleX's labels scored by each file's own success rate (the per-object-rate oracle)."""
    import h5py

    labels, scores = [], []
    for f in files:
        with h5py.File(f, "r") as h:
            y = h["grasps/qualities/flex/object_in_gripper"][()] > 0
        labels.append(y)
        scores.append(np.full(len(y), y.mean()))
    return roc_auc(np.concatenate(labels), np.concatenate(scores))


def summary(files: Path, evals: dict[str, Path], picks: Path | None) -> dict:
    """The check's results: ``files``, the ACRONYM files evaluated; ``evals``, network name -> ``gen probe eval``'s
    JSON; ``picks``, the folder of ``gen probe pick``'s JSONs (module docstring)."""
    h5 = sorted(files.glob("*.h5"))
    result: dict = {"files": [f.stem for f in h5]}
    for net, path in evals.items():
        report = json.loads(path.read_text())
        result[net] = {k: report.get(k) for k in ("n", "auc", "ap", "mean_object_auc", "base_rate")}
        result[net]["per_object"] = {r["name"]: r["auc"] for r in report.get("per_object", [])}
    result["object_rate_auc"] = object_rate_auc(h5)
    rows = [json.loads(p.read_text()) | {"name": p.stem} for p in sorted(picks.glob("*.json"))] if picks else []
    if rows:
        keys = ("top_success", "top_firm", "random_success", "random_firm", "random_clear_success")
        result["pick"] = {k: float(np.mean([r[k] for r in rows if r.get(k) is not None])) for k in keys}
        result["pick"]["files"] = len(rows)
        result["pick"]["files_at_0.9"] = int(sum(r["top_success"] >= 0.9 - 1e-9 for r in rows))
        result["pick_objects"] = [{k: r.get(k) for k in ("name", "top_success", "top_firm", "random_success",
                                                          "random_clear_success", "clear_candidates",
                                                          "top_outcomes")} for r in rows]
    return result


PLATE_FACE = (0.014, 0.067)
"""Width and length (m) of the plates of :func:`plate_sweep`: a knife blade's."""


PLATE_SETTINGS = ({"pad_sink": "model"}, {"pad_sink": "model", "solimp": (0.95, 0.9999, 0.001, 0.5, 2.0)},
                  {"pad_sink": "model", "solimp": (0.9999, 0.9999, 0.001, 0.5, 2.0)},
                  {"pad_sink": "model", "timestep": 0.0005, "solref": (0.001, 1.0)},
                  {"pad_sink": "model", "timestep": 0.00025, "solref": (0.0005, 1.0)}, {})
"""The gripper model's contact (``pad_sink="model"``), two stiffer impedances, two shorter time constants with the
timesteps they need (two steps each), and the default, the pads' sink bounded per object
(:mod:`graspgen.sim.pad_sink`)."""


def _contact_params(density: float, solimp=None, solref=None, timestep: float | None = None,
                    pad_sink: str = "bounded"):
    """Default :class:`EvaluateParams` at ``density`` (kg/m^3) and friction 1, with the ``acronym`` protocol's
    gripper contact changed as given (None keeps the model's; ``timestep`` in s; ``pad_sink``:
    ``LiftParams.pad_sink``)."""
    import dataclasses

    from graspgen.workflows.evaluate_settings import EvaluateParams

    params = EvaluateParams()
    lift = dataclasses.replace(params.lift, timestep=timestep or params.lift.timestep, pad_sink=pad_sink,
                               acronym=dataclasses.replace(params.lift.acronym, contact_solimp=solimp,
                                                           contact_solref=solref))
    return dataclasses.replace(params, density=float(density), friction=1.0, lift=lift)


def plate_sweep(folder: Path, thicknesses=(0.002, 0.004, 0.008, 0.016),
                densities=(150.0, 300.0, 1000.0, 3000.0, 10000.0), solimp=None, solref=None,
                timestep: float | None = None, pad_sink: str = "bounded") -> list[dict]:
    """A Panda grasp face-on at the centre of a plate (faces :data:`PLATE_FACE`), ``acronym`` protocol, mu 1: its
    outcome, firm label and the pads' gap after closing, per thickness (m) and density (kg/m^3). ``solimp``,
    ``solref``: the protocol's ``contact_solimp`` / ``contact_solref`` (None: the gripper model's); ``timestep`` (s):
    None keeps the protocol's; ``pad_sink``: ``LiftParams.pad_sink``. The meshes are written to ``folder``."""
    import trimesh

    from graspgen.workflows.evaluate import evaluate_grasps

    grasp = np.eye(4)
    grasp[:3, :3] = np.column_stack([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # close along x
    rows = []
    for thickness in thicknesses:
        plate = trimesh.creation.box(extents=(thickness, *PLATE_FACE))
        mesh = folder / f"plate_{thickness * 1000:g}mm.obj"
        plate.export(mesh)
        for density in densities:
            params = _contact_params(density, solimp, solref, timestep, pad_sink)
            row = evaluate_grasps(mesh, 1.0, grasp[None], np.array([thickness]), "panda", params,
                                  protocol="acronym").to_pylist()[0]
            rows.append({"thickness_mm": thickness * 1000, "density": density,
                         "mass_g": float(plate.volume * density * 1000), "outcome": int(row["outcome"]),
                         "firm": bool(row["firm"]), "closed_mm": float(row["closed_width"]) * 1000,
                         "motion_closing_m": float(row["motion_closing_linear"]), "solimp": solimp,
                         "solref": solref, "timestep": timestep, "pad_sink": pad_sink})
            print(f"  {thickness * 1000:g} mm, {density:g} kg/m^3 ({rows[-1]['mass_g']:.2f} g): outcome "
                  f"{rows[-1]['outcome']}, firm {rows[-1]['firm']}, pads {rows[-1]['closed_mm']:.3f} mm apart",
                  flush=True)
    return rows


def resimulate(dataset: Path, name: str, mesh: Path, scale: float, n: int = 200, seed: int = 0) -> list[dict]:
    """``n`` of object ``name``'s set grasps (collisions left out, drawn with ``seed``) from a published dataset's
    ``object_grasps.parquet``, rolled out again with the gripper model's contact, with a 1 ms time constant at
    0.5 ms steps, and with the default bounded sink (:data:`PLATE_SETTINGS`): the outcome counts (codes 0-5), held
    and firm shares, seconds."""
    import time

    import pyarrow.parquet as pq

    from graspgen.workflows.evaluate import evaluate_grasps

    table = pq.read_table(dataset / "object_grasps.parquet", filters=[("object_name", "=", name)],
                          columns=["pose_object", "width", "outcome", "protocol"]).to_pandas()
    table = table[table.outcome != 1]
    pick = np.random.default_rng(seed).choice(len(table), min(n, len(table)), replace=False)
    poses = np.stack([np.asarray(p, np.float64).reshape(4, 4) for p in table.pose_object.iloc[pick]])
    widths = table.width.to_numpy()[pick]
    rows = []
    for setting in (PLATE_SETTINGS[0], PLATE_SETTINGS[3], {}):
        params = _contact_params(150.0, **setting)
        start = time.perf_counter()
        out = evaluate_grasps(mesh, scale, poses, widths, "panda", params, protocol="acronym").to_pandas()
        rows.append({"setting": setting, "outcomes": np.bincount(out.outcome, minlength=6).tolist(),
                     "held": float((out.outcome == 5).mean()), "firm": float(out.firm.mean()),
                     "seconds": time.perf_counter() - start})
        print(f"  {setting or 'bounded (default)'}: outcomes {rows[-1]['outcomes']}, held {rows[-1]['held']:.2f}, firm "
              f"{rows[-1]['firm']:.2f}, {rows[-1]['seconds']:.0f} s", flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)
    p = sub.add_parser("prepare", help="choose and convert the files, write objects.csv")
    p.add_argument("--source", type=Path, required=True, help="AffordanceGrasp's data/affordance_grasps")
    p.add_argument("--out", type=Path, required=True, help="folder for the files (OUT/acronym)")
    p.add_argument("--shared", type=Path, default=SHARED, help="meshes here are left out (default ../shared)")
    s = sub.add_parser("summary", help="collect the commands' results")
    s.add_argument("--files", type=Path, required=True, help="the ACRONYM files the networks were evaluated on")
    s.add_argument("--eval", nargs=2, action="append", metavar=("NAME", "JSON"), default=[],
                   help="a network's name and its gen probe eval JSON (repeatable)")
    s.add_argument("--picks", type=Path, default=None, help="folder of gen probe pick's JSONs")
    s.add_argument("--part", default="check", help="the results' key in --out (other keys are kept)")
    s.add_argument("--out", type=Path, default=HERE / "results_unseen.json")
    pl = sub.add_parser("plates", help="the plate sweep (pads through light thin parts), each PLATE_SETTINGS contact")
    pl.add_argument("--out", type=Path, default=HERE / "results_unseen.json")
    r = sub.add_parser("resim", help="one object's set grasps again: the model's contact, 1 ms, and bounded")
    r.add_argument("--dataset", type=Path, required=True, help="a published dataset folder (object_grasps.parquet)")
    r.add_argument("--object", required=True, help="the object's name in the sets")
    r.add_argument("--mesh", type=Path, required=True)
    r.add_argument("--scale", type=float, required=True, help="metres per mesh unit")
    r.add_argument("-n", type=int, default=200)
    r.add_argument("--out", type=Path, default=HERE / "results_unseen.json")
    args = ap.parse_args()
    if args.command == "plates":
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            rows = [r for setting in PLATE_SETTINGS for r in plate_sweep(Path(tmp), **setting)]
        parts = json.loads(args.out.read_text()) if args.out.exists() else {}
        args.out.write_text(json.dumps(parts | {"plates": rows}, indent=1))
        print(f"wrote {args.out}")
    elif args.command == "resim":
        rows = resimulate(args.dataset, args.object, args.mesh, args.scale, args.n)
        parts = json.loads(args.out.read_text()) if args.out.exists() else {}
        args.out.write_text(json.dumps(parts | {f"resim_{args.object}": rows}, indent=1))
        print(f"wrote {args.out}")
    elif args.command == "prepare":
        rows = prepare(args.source, args.out, args.shared)
        print(f"{len(rows)} files -> {args.out / 'objects.csv'}")
    else:
        missing = [str(p) for p in (args.files, *(Path(path) for _, path in args.eval), args.picks)
                   if p is not None and not Path(p).exists()]
        if missing:
            raise SystemExit(f"not found: {', '.join(missing)}")
        result = summary(args.files, {name: Path(path) for name, path in args.eval}, args.picks)
        parts = json.loads(args.out.read_text()) if args.out.exists() else {}
        args.out.write_text(json.dumps(parts | {args.part: result}, indent=1))
        print(json.dumps({k: v for k, v in result.items() if k not in ("files", "pick_objects")}, indent=1))
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
