"""Read a dataset's Contact-GraspNet export with Contact-GraspNet's own, unmodified loading code and check it.

    python tools/check_contact_graspnet.py OUT/dataset [--source PATH] [--json report.json]

``--source`` is a checkout of ``NVlabs/contact_graspnet`` or a bare git directory of it (default: the environment's
``CONTACT_GRASPNET_SRC``); a bare one is extracted (``git archive HEAD``) into a temporary folder. Nothing of it is
copied into this repository.

What runs: ``contact_graspnet/data.py`` is imported as it is and its ``load_scene_contacts(folder,
scene_contacts_path='scene_contacts')`` reads every scene file, exactly as ``train.py`` does. ``data.py`` imports
``scene_renderer`` (which imports ``pyrender`` and ``mesh_utils``), ``cv2``, and ``mesh_utils`` imports
``tensorflow.compat.v1`` and ``tqdm``; ``load_scene_contacts`` calls none of them (it uses ``glob``, ``os`` and
``numpy``), so where one is not installed it is replaced by a stub module whose every attribute access raises: a
call would fail the check, not pass it. When ``tqdm`` is installed, ``mesh_utils.grasp_contact_location`` (the
function Contact-GraspNet's ``tools/create_contact_infos.py`` makes its contacts with, Panda gripper files from the
checkout) is run on each exported grasp too, and its contacts are compared with the exported ones.

Checks, per scene file (its scene found by ``splits/scenes.json``'s ``files``, the sorted order the loader reads):

* counts: one file per published scene with a positive (the others listed as left out); the held-out scenes are
  the last ``num_test_scenes`` files; the positives plus the other rows are the scene's rows of the source table
  (``placed_grasps.parquet`` or ``grasps.parquet``, the file's ``source``); positives are exactly its successes whose
  two contact rays hit;
* poses: each positive's ``grasp_transforms @ Trans(0, 0, 0.1034)`` less the table shift is its row's
  ``pose_world`` (largest entry difference);
* objects: each ``obj_paths`` mesh, loaded, scaled and centred as Contact-GraspNet's renderer does, and moved by
  ``obj_transforms``, is the scene record's mesh at its settled pose plus the table shift (largest vertex difference);
* contacts: on that object's surface (largest distance), on the grasp's closing line through its finger-centre plane,
  contact 0 on the +x finger's side, and (with ``tqdm``) equal to ``grasp_contact_location``'s.

Exit status 1 when a check fails (the report says which), else 0.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import types
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pyarrow.parquet as pq
import trimesh

DEPTH = 0.1034  # Contact-GraspNet's gripper_depth
TOL_POSE = 1e-9
TOL_SURFACE = 1e-5  # m: a ray's hit on a sliver triangle may lie microns past its edge (3.6e-6 on the default set)
TOL_UPSTREAM = 1e-5  # Embree (float32) against our float64 ray casts
STUBBED = ("tensorflow", "tensorflow.compat", "tensorflow.compat.v1", "pyrender", "cv2", "tqdm")


def checkout(source: str | Path) -> Path:
    """A folder with Contact-GraspNet's files: ``source`` itself, or a bare git directory extracted to a temp dir."""
    source = Path(source)
    if (source / "contact_graspnet" / "data.py").is_file():
        return source
    if not (source / "HEAD").is_file():
        raise SystemExit(f"{source}: neither a Contact-GraspNet checkout nor a git directory")
    dest = Path(tempfile.mkdtemp(prefix="contact_graspnet_"))
    archive = subprocess.run(["git", f"--git-dir={source}", "archive", "HEAD", "contact_graspnet",
                              "gripper_control_points", "gripper_models", "pointnet2/utils"],
                             check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest


class _Unused:
    """A name imported from a stub module (``from tqdm import tqdm``): calling it or reading from it raises."""

    def __init__(self, name: str):
        self._name = name

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        raise RuntimeError(f"stub {self._name!r} was called, so the checked path does use it")

    def __getattr__(self, attr: str) -> Any:
        raise RuntimeError(f"stub {self._name}.{attr} was used, so the checked path does use it")


class _Stub(types.ModuleType):
    """A module that is imported but must never be used: its names are :class:`_Unused`."""

    def __getattr__(self, attr: str) -> Any:
        if attr.startswith("__"):
            raise AttributeError(attr)
        return _Unused(f"{self.__name__}.{attr}")


def load_upstream(src: Path) -> tuple[types.ModuleType, types.ModuleType, list[str]]:
    """Import ``contact_graspnet/data.py`` and ``mesh_utils`` from ``src``; returns them and the stubbed modules."""
    stubbed = []
    for name in STUBBED:
        if name in sys.modules:
            continue
        try:
            importlib.import_module(name)
        except ImportError:
            sys.modules[name] = _Stub(name)
            stubbed.append(name)
    if "tensorflow" in stubbed:  # ``import tensorflow.compat.v1 as tf`` reads the attribute chain
        object.__setattr__(sys.modules["tensorflow"], "compat", sys.modules["tensorflow.compat"])
        object.__setattr__(sys.modules["tensorflow.compat"], "v1", sys.modules["tensorflow.compat.v1"])
    spec = importlib.util.spec_from_file_location("contact_graspnet_data", src / "contact_graspnet" / "data.py")
    assert spec is not None and spec.loader is not None
    data = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(data)  # appends its own folders to sys.path, as when train.py imports it
    return data, sys.modules["mesh_utils"], stubbed


def _table(dataset: Path, source: str) -> dict[str, dict[str, np.ndarray]]:
    """The source table's rows per scene: grasp_id -> pose_world, success."""
    label = "success" if source == "placed_grasps" else "outcome"
    t = pq.read_table(dataset / f"{source}.parquet", columns=["scene_id", "grasp_id", "pose_world", label])
    out: dict[str, dict[str, np.ndarray]] = {}
    sids = np.asarray(t.column("scene_id").to_pylist(), dtype=object)
    poses = np.asarray(t.column("pose_world").combine_chunks().values).reshape(-1, 4, 4)
    ok = (t.column("success").to_numpy(zero_copy_only=False) if source == "placed_grasps"
          else t.column("outcome").to_numpy() == 5).astype(bool)
    gid = t.column("grasp_id").to_numpy()
    for sid in sorted(set(sids)):
        sel = sids == sid
        out[sid] = {"grasp_id": gid[sel], "pose_world": poses[sel], "success": ok[sel]}
    return out


def _upstream_object(folder: Path, rel: str, scale: float, T: np.ndarray, mesh_utils: types.ModuleType):
    """The object as Contact-GraspNet's renderer places it (``SceneRenderer._load_object``, then its pose):
    ``mesh_utils.Object(path).rescale(scale)`` when python-fcl is installed (its constructor builds a collision
    manager), else its two steps, ``trimesh.load(path)`` and ``apply_scale(scale)``; then the vertex mean subtracted."""
    try:
        obj = mesh_utils.Object(str(folder / rel))
        obj.rescale(scale)
        mesh = obj.mesh
    except ValueError as exc:
        if "FCL" not in str(exc):
            raise
        mesh = trimesh.load(str(folder / rel))
        mesh.apply_scale(scale)
    mesh.vertices -= np.expand_dims(np.mean(mesh.vertices, 0), 0)
    return mesh.copy().apply_transform(T)


def check(dataset: Path, src: Path) -> dict[str, Any]:
    """Run the checks (module docstring); returns the report (``failures`` empty when all pass)."""
    dataset = Path(dataset)
    folder = dataset / "contact_graspnet"
    data, mesh_utils, stubbed = load_upstream(src)
    infos = data.load_scene_contacts(str(folder), scene_contacts_path="scene_contacts")
    split = json.loads((folder / "splits" / "scenes.json").read_text())
    files, left_out = split["files"], split["left_out"]
    scenes = sorted(p.stem for p in (dataset / "scenes").glob("*.h5"))
    report: dict[str, Any] = {"stubbed": stubbed, "scenes": len(scenes), "files_loaded": len(infos),
                              "left_out": left_out, "upstream_contacts": "tqdm" not in stubbed, "failures": [],
                              "per_scene": []}
    fail = report["failures"]
    if len(infos) != len(files) or len(files) + len(left_out) != len(scenes):
        fail.append(f"{len(infos)} files loaded, {len(files)} listed + {len(left_out)} left out, {len(scenes)} "
                    "scenes published")
    if split["num_test_scenes"] != sum("_test_" in f for f in files) or files[len(files) - len(split["test"]):] != \
            [f for f in files if "_test_" in f]:
        fail.append("the held-out scenes are not the last num_test_scenes files")
    err = {"pose": 0.0, "object": 0.0, "surface": 0.0, "line": 0.0, "upstream": 0.0}
    tables: dict[str, dict] = {}
    for info, name in zip(infos, files):
        z = np.load(folder / "scene_contacts" / name, allow_pickle=False)
        sid, source, top = str(z["scene_id"]), str(z["source"]), float(z["table_top"])
        rows = tables.setdefault(source, _table(dataset, source)).get(sid)
        n_rows = 0 if rows is None else len(rows["grasp_id"])
        G, C = info["grasp_transforms"], info["scene_contact_points"]
        line = {"scene": sid, "positives": len(G), "rows": n_rows,
                "successes": 0 if rows is None else int(rows["success"].sum())}
        report["per_scene"].append(line)
        if len(G) + len(z["other_grasp_ids"]) != n_rows:
            fail.append(f"{name}: {len(G)} + {len(z['other_grasp_ids'])} grasps, {source} has {n_rows} rows")
        if rows is None:
            continue
        at = {int(g): i for i, g in enumerate(rows["grasp_id"])}
        hit_other = np.isfinite(z["other_contact_points"]).all(axis=(1, 2))
        missed = int((z["other_success"] & ~hit_other).sum())
        line["successes_without_contacts"] = missed
        if len(G) + missed != line["successes"] or (z["other_success"] & hit_other).any():
            fail.append(f"{name}: positives {len(G)} + {missed} without contacts != {line['successes']} successes")
        up = np.eye(4)
        up[2, 3] = top
        tcp = G @ np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, DEPTH], [0, 0, 0, 1.0]])
        want = np.array([up @ rows["pose_world"][at[int(g)]] for g in z["grasp_ids"]]).reshape(-1, 4, 4)
        err["pose"] = max(err["pose"], float(np.abs(tcp - want).max(initial=0.0)))
        err.update(_check_objects(dataset, folder, info, z, up, tcp, C, mesh_utils, err))
    source = str(np.load(folder / "scene_contacts" / files[0], allow_pickle=False)["source"]) if files else None
    for sid in left_out:  # their rows, for the totals: successes there had no two contacts
        rows = tables.setdefault(source, _table(dataset, source)).get(sid) if source else None
        n_ok = 0 if rows is None else int(rows["success"].sum())
        report["per_scene"].append({"scene": sid, "positives": 0, "rows": 0 if rows is None else len(rows["success"]),
                                    "successes": n_ok, "successes_without_contacts": n_ok, "left_out": True})
    report["max_errors"] = err
    for key, tol in (("pose", TOL_POSE), ("object", TOL_POSE * 1e3), ("surface", TOL_SURFACE), ("line", TOL_SURFACE),
                     ("upstream", TOL_UPSTREAM)):
        if err[key] > tol:
            fail.append(f"largest {key} error {err[key]:.3g} above {tol:g}")
    return report


def _check_objects(dataset: Path, folder: Path, info: dict, z: Any, up: np.ndarray, tcp: np.ndarray, C: np.ndarray,
                   mesh_utils: types.ModuleType, err: dict[str, float]) -> dict[str, float]:
    """Object placement and the contacts of one scene file; returns the updated largest errors."""
    err = dict(err)
    with h5py.File(dataset / "scenes" / f"{z['scene_id']}.h5", "r") as f:
        poses = f["objects/poses"][()]
    for i, (rel, scale, T) in enumerate(zip(info["obj_paths"], info["obj_scales"], info["obj_transforms"])):
        placed = _upstream_object(folder, str(rel), float(scale), T, mesh_utils)
        with h5py.File(dataset / "objects" / f"{z['obj_names'][i]}.h5", "r") as f:
            record = trimesh.Trimesh(f["mesh/vertices"][()], f["mesh/faces"][()], process=False)
        ours = record.apply_transform(up @ poses[i])
        err["object"] = max(err["object"], float(np.abs(np.sort(placed.vertices, 0) - np.sort(ours.vertices, 0)).max()))
        sel = z["grasp_obj_idcs"] == i
        if not sel.any():
            continue
        pts = C[sel].reshape(-1, 3)
        _, dist, _ = trimesh.proximity.closest_point(placed, pts)
        err["surface"] = max(err["surface"], float(dist.max()))
        x, o = tcp[sel][:, :3, 0], tcp[sel][:, :3, 3]
        for k, sign in ((0, 1.0), (1, -1.0)):
            d = C[sel][:, k] - o
            along = np.einsum("ij,ij->i", d, x)
            off = np.linalg.norm(d - along[:, None] * x, axis=1)
            err["line"] = max(err["line"], float(off.max()), float(np.maximum(-sign * along, 0).max()))
        if not isinstance(sys.modules.get("tqdm"), _Stub):
            G = info["grasp_transforms"][sel]
            res = mesh_utils.grasp_contact_location(G, [1] * len(G), [0] * len(G), placed, silent=True)
            if len(res) != len(G):
                err["upstream"] = float("inf")
                continue
            for r, c, g in zip(res, C[sel], G):
                first = np.einsum("ij,j->i", r["contact_directions"], g[:3, 0]) < 0  # the +x finger's ray
                theirs = np.stack([r["contact_points"][first][0], r["contact_points"][~first][0]])
                err["upstream"] = max(err["upstream"], float(np.abs(theirs - c).max()))
    return err


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path, help="OUT/dataset (or OUT)")
    parser.add_argument("--source", default=os.environ.get("CONTACT_GRASPNET_SRC"),
                        help="Contact-GraspNet checkout or bare git dir (default $CONTACT_GRASPNET_SRC)")
    parser.add_argument("--json", type=Path, help="also write the report here")
    args = parser.parse_args(argv)
    if not args.source:
        parser.error("--source (or CONTACT_GRASPNET_SRC) is required")
    dataset = args.dataset / "dataset" if (args.dataset / "dataset" / "contact_graspnet").is_dir() else args.dataset
    report = check(dataset, checkout(args.source))
    totals = {k: sum(s.get(k, 0) for s in report["per_scene"])
              for k in ("rows", "successes", "positives", "successes_without_contacts")}
    print(f"Contact-GraspNet load_scene_contacts: {report['files_loaded']} scene files for {report['scenes']} scenes "
          f"({len(report['left_out'])} left out: no positive); stubbed (never called): "
          f"{', '.join(report['stubbed']) or 'none'}")
    print(f"rows {totals['rows']}, successes {totals['successes']}, exported positives {totals['positives']}, "
          f"successes without two contacts {totals['successes_without_contacts']}")
    print("largest errors: " + ", ".join(f"{k} {v:.3g}" for k, v in report["max_errors"].items())
          + ("" if report["upstream_contacts"] else " (upstream contacts not run: no tqdm)"))
    print("FAIL:\n  " + "\n  ".join(report["failures"]) if report["failures"] else "OK")
    if args.json:
        args.json.write_text(json.dumps(report, indent=1) + "\n")
    return 1 if report["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
