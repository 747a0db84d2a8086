"""Labelled grasps per object, from ACRONYM files (FleX or our simulator's labels) or a dataset folder, and the
split of objects into training and held-out sets (by mesh identity, never by grasp). Numpy only (the sim labels
call :func:`graspgen.workflows.evaluate.evaluate_grasps`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np

from graspgen.errors import InputError, SettingsError
from graspgen.io.atomic import atomic_path

__all__ = ["ObjectGraspSet", "acronym_sets", "dataset_sets", "held_out", "split_by_object"]

SUCCESS = 5  # graspgen.sim.protocols.Outcome.SUCCESS


@dataclasses.dataclass(frozen=True, eq=False)
class ObjectGraspSet:
    """The labelled grasps of one object."""

    name: str
    """Object name (ACRONYM file stem, or the dataset's ``object_name``)."""
    group: str
    """Split key, the mesh identity (ACRONYM ``<Category>_<meshid>``: the scales of one mesh share it)."""
    vertices: np.ndarray
    """(v, 3) float64 mesh vertices, scaled mesh frame, m."""
    faces: np.ndarray
    """(f, 3) int64."""
    T_tcp: np.ndarray
    """(m, 4, 4) float64 TCP poses in the mesh frame."""
    width: np.ndarray
    """(m,) float64 pad separation, m."""
    label: np.ndarray
    """(m,) bool success."""
    gripper: str
    """Gripper name, e.g. ``panda``."""
    source: str
    """``flex``, ``sim`` or ``dataset``."""
    physics: dict | None = None
    """What the labels were made at: ``label`` (``flex``, ``held`` or ``firm``), ``protocol``, ``friction``,
    ``density`` (kg/m^3) and ``mass`` (kg; either may be None); None when unknown."""


def _hash_fraction(text: str) -> float:
    return int(hashlib.sha256(text.encode()).hexdigest()[:8], 16) / 2**32


def held_out(group: str, valid_fraction: float, salt: str = "") -> bool:
    """Whether :func:`split_by_object` puts ``group`` in the held-out side: sha256(salt + group)'s first 32 bits,
    as a fraction of 2**32, below ``valid_fraction``."""
    return _hash_fraction(salt + group) < valid_fraction


def split_by_object(sets, valid_fraction: float, salt: str = "") -> tuple[list, list]:
    """(train, valid) by :func:`held_out` of each set's ``group``, input order kept; SettingsError naming the empty
    side if either is empty."""
    if not 0.0 < valid_fraction < 1.0:
        raise SettingsError(f"valid_fraction: must be in (0, 1), got {valid_fraction}")
    train = [s for s in sets if not held_out(s.group, valid_fraction, salt)]
    valid = [s for s in sets if held_out(s.group, valid_fraction, salt)]
    for side, part in (("train", train), ("valid", valid)):
        if not part:
            raise SettingsError(f"valid_fraction: the {side} side of the split is empty ({len(sets)} objects, "
                                f"valid_fraction {valid_fraction}, salt {salt!r})")
    return train, valid


def _files(paths) -> list[Path]:
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            out += sorted(p.glob("*.h5"))
        elif p.is_file():
            out.append(p)
        else:
            raise InputError(f"{p}: no such ACRONYM file or folder")
    return out


def _sample(n: int, per_object: int | None, seed: int, name: str) -> np.ndarray:
    if per_object is None or per_object >= n:
        return np.arange(n)
    rng = np.random.default_rng([seed, int(hashlib.sha256(name.encode()).hexdigest()[:8], 16)])
    return np.sort(rng.choice(n, size=per_object, replace=False))


def _widths(mesh, T: np.ndarray, gripper) -> np.ndarray:
    """Pad separation (m) by closing the pads onto the mesh with ray casts; no contact on a pad: fully open."""
    from graspgen.geometry.contacts import closing_contacts

    w = np.array([c.width for c in closing_contacts(mesh, T, gripper)], dtype=np.float64)
    return np.where(np.isfinite(w), np.clip(w, gripper.min_width, gripper.max_width), gripper.max_width)


_PHYSICS_ROOTS = ("graspgen.workflows.evaluate",)
"""The modules simulated labels are made by; with every ``graspgen`` module they can import (any import statement,
function-level ones included: :func:`physics_modules`) they are the code the labels depend on."""
_PHYSICS_DATA = ("assets/grippers",)
"""Data the labels depend on besides the code: the bundled grippers' files."""


def physics_modules() -> list[Path]:
    """The source files of :data:`_PHYSICS_ROOTS` and of every ``graspgen`` module they can import, transitively
    (read from their import statements, not by running them), with the packages' ``__init__.py``; sorted."""
    import ast

    root = Path(__file__).resolve().parents[2]

    def files(name: str) -> list[Path]:
        parts = name.split(".")
        found = [root.joinpath(*parts[:i], "__init__.py") for i in range(1, len(parts) + 1)]
        found.append(root.joinpath(*parts).with_suffix(".py"))
        return [f for f in found if f.is_file()]

    seen: set[Path] = set()
    todo = [f for name in _PHYSICS_ROOTS for f in files(name)]
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        for node in ast.walk(ast.parse(path.read_bytes())):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            todo += [f for n in names if n.split(".")[0] == "graspgen" for f in files(n)]
    return sorted(seen)


def _physics_digest() -> str:
    """sha256 of the code simulated labels depend on (:func:`physics_modules`), the gripper assets
    (:data:`_PHYSICS_DATA`) and MuJoCo's version. A Python file enters as its syntax tree without docstrings
    (:func:`code_digest_text`): comments, docstrings and layout do not change labels, so editing them (or code the
    labels do not run) keeps the cache."""
    from graspgen.sim.physics import mujoco_version

    root = Path(__file__).resolve().parents[2]
    h = hashlib.sha256(mujoco_version().encode())
    for f in physics_modules():
        h.update(f.relative_to(root).as_posix().encode() + b"\0" + code_digest_text(f.read_bytes()))
    for rel in _PHYSICS_DATA:
        for f in sorted((root / rel).rglob("*")):
            if f.is_file() and f.suffix in (".py", ".yaml", ".obj", ".stl") and "__pycache__" not in f.parts:
                h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes())
    return h.hexdigest()


def code_digest_text(source: bytes) -> bytes:
    """What of a Python source enters :func:`_physics_digest`: ``ast.dump`` of its syntax tree without its bare
    string statements (docstrings, attribute docstrings: no-ops when run), comments, layout or line numbers; the
    source itself when it does not parse."""
    import ast

    try:
        tree = ast.parse(source)
    except SyntaxError:
        return source
    def text(stmt: ast.stmt) -> bool:
        return isinstance(stmt, ast.Expr) and isinstance(stmt.value, ast.Constant) and isinstance(stmt.value.value, str)

    for node in list(ast.walk(tree)):
        for field in ("body", "orelse", "finalbody"):
            body = getattr(node, field, None)
            if isinstance(body, list) and any(isinstance(s, ast.stmt) and text(s) for s in body):
                setattr(node, field, [s for s in body if not text(s)] or [ast.Pass()])
    return ast.dump(tree, include_attributes=False).encode()


def _sim_labels(mesh_path: Path, acr, T: np.ndarray, gripper: str, protocol: str, cache_dir: Path,
                jobs: int, sim_label: str) -> np.ndarray:
    """Our simulator's labels of the poses (``held``: outcome 5; ``firm``: held and still in place)."""
    outcome, firm = sim_outcomes(mesh_path, acr, T, gripper, protocol, cache_dir, jobs)
    return firm if sim_label == "firm" else outcome == SUCCESS


def sim_outcomes(mesh_path: Path, acr, T: np.ndarray, gripper: str, protocol: str, cache_dir: Path,
                 jobs: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Our simulator's outcome codes ``(m,) int8`` and firm labels ``(m,) bool`` of the poses ``T (m, 4, 4)`` of
    an ACRONYM file ``acr`` (its mass, friction, density and scale), cached by content under ``cache_dir`` (npz):
    mesh bytes, scale, poses, gripper, protocol, the evaluate settings, the physics code and MuJoCo's version
    (:func:`_physics_digest`), so an edited simulator never reuses old labels."""
    from graspgen.workflows.evaluate import evaluate_grasps
    from graspgen.workflows.evaluate_settings import EvaluateParams

    params = EvaluateParams(mass=acr.object_mass, friction=acr.object_friction or 1.0,
                            density=acr.object_density or 700.0)
    key = hashlib.sha256()
    key.update(mesh_path.read_bytes())
    key.update(json.dumps([float(acr.object_scale), gripper, protocol, repr(params), _physics_digest()]).encode())
    key.update(np.ascontiguousarray(T, dtype=np.float64).tobytes())
    path = cache_dir / f"{key.hexdigest()[:32]}.npz"
    if not path.exists():
        table = evaluate_grasps(mesh_path, acr.object_scale, T, None, gripper, params, protocol=protocol,
                                jobs=jobs, cache_dir=cache_dir.parent)
        outcome = table.column("outcome").to_numpy().astype(np.int8)
        firm = table.column("firm").to_numpy(zero_copy_only=False).astype(bool)
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez(f, outcome=outcome, firm=firm)
    with np.load(path) as z:
        return z["outcome"].astype(np.int8), z["firm"].astype(bool)


def acronym_sets(paths, *, mesh_root=None, labels: str = "flex", per_object: int | None = None, seed: int = 0,
                 cache_dir=None, jobs: int = 1, protocol: str = "acronym",
                 sim_label: str = "held") -> list[ObjectGraspSet]:
    """One set per ACRONYM file (``paths``: files or folders of ``*.h5``); meshes relative to each file's folder
    unless ``mesh_root``. Widths: the pads closed onto the mesh by ray casts. ``labels``: ``flex``
    (``object_in_gripper``) or ``sim`` (:func:`graspgen.workflows.evaluate.evaluate_grasps`, cached under ``cache_dir``,
    default ``.cache/labels``; the CoACD cache goes beside it). ``per_object``: a seeded sample of each file's
    grasps (rng from ``seed`` and the file stem). ``sim_label``: ``held`` (still in the hand, outcome 5) or
    ``firm`` (held and within the firm-hold tolerances, :attr:`graspgen.sim.protocols.RolloutResult.firm`); both are
    cached, so asking for the other costs nothing. InputError naming the file when it cannot be used."""
    import trimesh

    from graspgen.grippers import load_gripper
    from graspgen.io.acronym import read_acronym

    if labels not in ("flex", "sim"):
        raise SettingsError(f"labels: {labels!r} is not one of flex, sim")
    if sim_label not in ("held", "firm"):
        raise SettingsError(f"sim_label: {sim_label!r} is not one of held, firm")
    cache = Path(cache_dir) if cache_dir is not None else Path(".cache") / "labels"
    sets = []
    for path in _files(paths):
        try:
            acr = read_acronym(path)
        except (OSError, KeyError, ValueError) as exc:
            raise InputError(f"{path}: not an ACRONYM grasp file ({exc})") from None
        if len(acr) == 0:
            raise InputError(f"{path}: no grasps")
        mesh_path = (Path(mesh_root) if mesh_root is not None else path.parent) / acr.object_file
        if not mesh_path.is_file():
            raise InputError(f"{path}: its mesh {mesh_path} does not exist")
        mesh = trimesh.load(mesh_path, force="mesh", process=False)
        mesh.apply_scale(acr.object_scale)
        gripper = load_gripper(acr.gripper)
        idx = _sample(len(acr), per_object, seed, path.stem)
        T = acr.tcp_poses()[idx]
        if labels == "flex":
            if acr.success is None:
                raise InputError(f"{path}: no flex/object_in_gripper labels")
            label = np.asarray(acr.success)[idx] == 1
        else:
            label = _sim_labels(mesh_path, acr, T, gripper.name, protocol, cache, jobs, sim_label)
        physics = {"label": "flex" if labels == "flex" else sim_label, "protocol": protocol,
                   "friction": acr.object_friction or 1.0, "density": acr.object_density, "mass": acr.object_mass}
        sets.append(ObjectGraspSet(
            name=path.stem, group=path.stem.rsplit("_", 1)[0],
            vertices=np.asarray(mesh.vertices, dtype=np.float64), faces=np.asarray(mesh.faces, dtype=np.int64),
            T_tcp=T, width=_widths(mesh, T, gripper), label=label, gripper=gripper.name, source=labels,
            physics=physics))
    return sets


def record_physics(record, label: str, protocol: str, friction: float | None = None) -> dict:
    """:attr:`ObjectGraspSet.physics` of a set made on an object record: its mass and density (mass over the mesh's
    volume, when the mesh is a volume), its friction (``attrs["friction"]``, else ``friction``, else 1.0)."""
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(record.vertices, np.float64), np.asarray(record.faces), process=False)
    density = float(record.mass) / float(mesh.volume) if mesh.is_volume and mesh.volume > 0 else None
    own = (record.attrs or {}).get("friction")
    return {"label": label, "protocol": protocol, "mass": float(record.mass), "density": density,
            "friction": float(own if own is not None else friction if friction is not None else 1.0)}


def label_column(label: str | None) -> str:
    """The object grasp table's column of a set label: ``firm`` -> ``firm``; ``held`` or None (sets made before
    the label was recorded) -> ``success``."""
    if label not in (None, "held", "firm"):
        raise InputError(f"label: {label!r} is not one of held, firm")
    return "firm" if label == "firm" else "success"


def dataset_sets(folder, label: str | None = None) -> list[ObjectGraspSet]:
    """One set per object of a dataset folder (or the run folder above it): ``object_grasps.parquet`` (columns
    ``object_name``, ``pose_object``, ``width``, ``success``, ``firm``, ``gripper``) and ``objects/<name>.h5``;
    group = the object's name. ``label``: ``held`` or ``firm``; None: each set's own (``object_grasps.label``, in
    the table's metadata)."""
    import pyarrow.parquet as pq

    from graspgen.io.dataset_table import META_KEY
    from graspgen.io.objects import read_object

    root = Path(folder)
    if not (root / "object_grasps.parquet").is_file() and (root / "dataset" / "object_grasps.parquet").is_file():
        root = root / "dataset"
    table_path = root / "object_grasps.parquet"
    if not table_path.is_file():
        raise InputError(f"{folder}: no object_grasps.parquet")
    t = pq.read_table(table_path, columns=["object_name", "pose_object", "width", "success", "firm", "gripper",
                                           "protocol"])
    tasks = json.loads((t.schema.metadata or {}).get(META_KEY, b"{}")).get("tasks", {})
    names = np.asarray(t.column("object_name").to_pylist())
    poses = np.asarray(t.column("pose_object").to_pylist(), dtype=np.float64).reshape(-1, 4, 4)
    width = t.column("width").to_numpy().astype(np.float64)
    columns = {c: np.asarray(t.column(c).to_pylist(), dtype=bool) for c in ("success", "firm")}
    grippers = np.asarray(t.column("gripper").to_pylist())
    protocols = np.asarray(t.column("protocol").to_pylist())
    sets = []
    for name in sorted(set(names.tolist())):
        rows = names == name
        obj_path = root / "objects" / f"{name}.h5"
        if not obj_path.is_file():
            raise InputError(f"{obj_path}: missing (object {name!r} of {table_path})")
        rec = read_object(obj_path)
        own = label or tasks.get(name, {}).get("label") or "held"
        sets.append(ObjectGraspSet(
            name=name, group=name, vertices=np.asarray(rec.vertices, dtype=np.float64),
            faces=np.asarray(rec.faces, dtype=np.int64), T_tcp=poses[rows], width=width[rows],
            label=columns[label_column(own)][rows], gripper=str(grippers[rows][0]), source="dataset",
            physics=record_physics(rec, own, str(protocols[rows][0]), tasks.get(name, {}).get("friction"))))
    return sets
