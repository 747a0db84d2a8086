"""``gen probe``: train a small grasp evaluator on labelled grasps, score grasps with it, pick grasps with it.

The library is :mod:`graspgen.learn` (needs torch and scikit-learn: ``pip install -e '.[learn]'``); these commands
only read arguments, call it and print. Errors a user can cause are one line and exit 2.
"""

# No `from __future__ import annotations`: Typer reads the annotations at run time.

import json
import os
import time
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console

from pipeline.cli import check_writable, fail, load, os_error_text
from stages.project import PROJECT, USER_ERRORS

probe_app = typer.Typer(
    help="Learnability: train a small grasp evaluator on labelled grasps, score grasps with it, pick with it "
    "(needs torch and scikit-learn: pip install -e '.[learn]').",
    no_args_is_help=True,
)

GraspsOpt = Annotated[
    list[Path],
    typer.Option("--grasps", help="ACRONYM grasp files (.h5) or folders of them, or a published dataset folder (its "
                 "object-centric sets and their own labels); repeat for several."),
]
MeshRootOpt = Annotated[
    Path | None, typer.Option("--mesh-root", help="Folder ACRONYM's object/file is relative to (default: each file's "
                              "folder).")
]
LabelsOpt = Annotated[
    str, typer.Option("--labels", help="flex: the ACRONYM files' own labels (object_in_gripper); sim: the same poses "
                      "labelled by our simulator (acronym protocol, still held; cached under run.cache_dir/labels); "
                      "firm: the same simulation's firm-hold label. A dataset folder: its sets' own label, or firm "
                      "with firm.")
]
LABELS = ("flex", "sim", "firm")
PerObjectOpt = Annotated[
    int | None, typer.Option("--per-object", help="At most this many grasps per object (a fixed seeded sample).",
                             min=1)
]


def _sets(grasps: list[Path], mesh_root: Path | None, labels: str, per_object: int | None, seed: int,
          jobs: int) -> list[Any]:
    """The object-grasp sets of every ``--grasps`` path: dataset folders by their own labels, the rest as ACRONYM."""
    from graspgen.learn.sources import acronym_sets, dataset_sets

    if labels not in LABELS:
        raise ValueError(f"--labels: {labels!r} is not one of {', '.join(LABELS)}")
    if not grasps:
        raise ValueError("--grasps: give at least one ACRONYM file, folder of them, or dataset folder")
    cache = Path(load(PROJECT, None, None).run.cache_dir) / "labels"
    sets: list[Any] = []
    for path in grasps:
        if not path.exists():
            raise ValueError(f"--grasps: {path}: no such file or folder")
        if _is_dataset(path):
            sets += dataset_sets(path, "firm" if labels == "firm" else None)
        else:
            sets += acronym_sets([path], mesh_root=mesh_root, labels="flex" if labels == "flex" else "sim",
                                 per_object=per_object, seed=seed, cache_dir=cache, jobs=jobs,
                                 sim_label="firm" if labels == "firm" else "held")
    if not sets:
        raise ValueError(f"--grasps: no grasps found in {', '.join(str(p) for p in grasps)}")
    return sets


def _is_dataset(path: Path) -> bool:
    """A published dataset folder or the run folder above it (object_grasps.parquet there)."""
    return path.is_dir() and ((path / "object_grasps.parquet").is_file()
                              or (path / "dataset" / "object_grasps.parquet").is_file())


def _one_gripper(sets: list[Any]) -> str:
    grippers = sorted({s.gripper for s in sets})
    if len(grippers) != 1:
        raise ValueError(f"--grasps: the grasps are of {len(grippers)} grippers ({', '.join(grippers)}); a model "
                         "learns one gripper: give the files of one")
    return grippers[0]


def _write_json(console: Console, path: Path, data: Any) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(data, indent=1, sort_keys=True, allow_nan=False) + "\n")
    except OSError as exc:
        fail(console, f"{path}: cannot write the results ({os_error_text(exc)})", code=1)


@probe_app.command("train")
def train_cmd(
    grasps: GraspsOpt,
    output: Annotated[Path, typer.Option("--out", "-o", help="The model file to write (.pt).")],
    mesh_root: MeshRootOpt = None,
    labels: LabelsOpt = "flex",
    per_object: PerObjectOpt = None,
    valid_fraction: Annotated[
        float, typer.Option("--valid-fraction", help="Hold out this share of the objects (by a hash of their "
                            "group: an ACRONYM mesh's scales stay together) and report the held-out AUC; 0: train "
                            "on every object.", min=0.0, max=0.99)
    ] = 0.0,
    epochs: Annotated[int, typer.Option("--epochs", help="Passes over the training grasps.", min=1)] = 10,
    seed: Annotated[int, typer.Option("--seed", help="Seed of every draw (samples, weights, batches).", min=0)] = 0,
    members: Annotated[
        int | None, typer.Option("--members", help="Networks trained from independent draws; their mean probability "
                                 "is the score (an ensemble; default: TrainParams.members, 5).", min=1)
    ] = None,
    jobs: Annotated[int, typer.Option("--jobs", "-j", help="Workers of the sim labels and of the ensemble's members "
                                      "(0 = all cores).")] = 1,
) -> None:
    """Train a grasp evaluator on labelled grasps and write it (--out); print grasps, objects and seconds."""
    console = Console(stderr=True)
    start = time.perf_counter()
    try:
        from graspgen.learn import require_torch

        require_torch()
        from graspgen.learn.features import FeatureParams
        from graspgen.learn.report import score_report
        from graspgen.learn.sources import split_by_object
        from graspgen.learn.train import TrainParams, save_model, train_evaluator

        check_writable(output, "model file (--out)", file=True)
        sets = _sets(grasps, mesh_root, labels, per_object, seed, jobs)
        gripper = _one_gripper(sets)
        train, valid = (split_by_object(sets, valid_fraction, "probe") if valid_fraction > 0 else (sets, []))
        params = TrainParams(epochs=epochs, seed=seed, **({} if members is None else {"members": members}))
        model = train_evaluator(train, params, FeatureParams(), gripper=gripper, valid=valid or None,
                                jobs=jobs if jobs > 0 else os.cpu_count() or 1)
        report = score_report(valid, model.score(valid, seed=seed)) if valid else None
    except (*USER_ERRORS, ValueError) as exc:
        fail(console, _line(exc))
    try:
        output.parent.mkdir(parents=True, exist_ok=True)
        save_model(model, output)
    except OSError as exc:
        fail(console, f"{output}: cannot write the model ({os_error_text(exc)})", code=1)
    n = sum(len(s.label) for s in train)
    nets = model.train_info.get("members", 1)
    console.print(f"trained on {n} grasps of {len(train)} objects ({gripper}), {nets} network{'s' * (nets > 1)}, in "
                  f"{time.perf_counter() - start:.1f} s", highlight=False)
    if report is not None:
        console.print(f"held out {report['n']} grasps of {len(valid)} objects: auc {_num(report['auc'])}, mean "
                      f"per-object auc {_num(report['mean_object_auc'])}", highlight=False)
    print(output)


def _line(exc: BaseException) -> str:
    """The error's first line: torch's own messages (inside a model-file error) run over several."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _num(x: Any) -> str:
    return "-" if x is None else f"{float(x):.3f}"


@probe_app.command("eval")
def eval_cmd(
    model_path: Annotated[Path, typer.Option("--model", help="A model file of gen probe train (or probe/model.pt).")],
    grasps: GraspsOpt,
    json_path: Annotated[Path, typer.Option("--json", help="Write the scores' report here (JSON).")],
    mesh_root: MeshRootOpt = None,
    labels: LabelsOpt = "flex",
    per_object: PerObjectOpt = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the per-object samples and the surface points.",
                                      min=0)] = 0,
    jobs: Annotated[int, typer.Option("--jobs", "-j", help="Workers of the sim labels (0 = all cores).")] = 1,
) -> None:
    """Score labelled grasps with a model: ROC-AUC, average precision, base rate, per object (name, n, auc) and
    the mean per-object AUC; printed and written to --json."""
    console = Console(stderr=True)
    try:
        from graspgen.learn import require_torch

        require_torch()
        from graspgen.learn.report import score_report
        from graspgen.learn.train import load_model

        check_writable(json_path, "results file (--json)", file=True)
        model = load_model(model_path)
        sets = _sets(grasps, mesh_root, labels, per_object, seed, jobs)
        gripper = _one_gripper(sets)
        if gripper != model.gripper:
            raise ValueError(f"--model: {model_path} is a model of the {model.gripper} gripper; the grasps are of "
                             f"the {gripper}")
        report = score_report(sets, model.score(sets, seed=seed))
    except (*USER_ERRORS, ValueError) as exc:
        fail(console, _line(exc))
    data = {k: report[k] for k in ("auc", "ap", "base_rate", "n", "mean_object_auc")}
    data["per_object"] = [{"name": o["name"], "n": o["n"], "auc": o["auc"]} for o in report["per_object"]]
    data.update(model=str(model_path), labels=labels)
    _write_json(console, json_path, data)
    console.print(f"{data['n']} grasps of {len(sets)} objects: auc {_num(data['auc'])}, ap {_num(data['ap'])}, base "
                  f"rate {_num(data['base_rate'])}, mean per-object auc {_num(data['mean_object_auc'])}",
                  highlight=False)
    for o in data["per_object"]:
        console.print(f"  {o['name']}: n {o['n']}, auc {_num(o['auc'])}", highlight=False, markup=False)
    print(json_path)


@probe_app.command("pick")
def pick_cmd(
    model_path: Annotated[Path, typer.Option("--model", help="A model file of gen probe train (or probe/model.pt).")],
    mesh: Annotated[Path, typer.Option("--mesh", help="The object's mesh file (OBJ/STL/PLY/GLB/OFF).")],
    json_path: Annotated[Path, typer.Option("--json", help="Write the results here (JSON).")],
    candidates: Annotated[int, typer.Option("--candidates", help="Candidates sampled over the object.", min=1)] = 1000,
    top: Annotated[int, typer.Option("--top", help="Simulate the K best-scored and K random candidates.", min=1)] = 10,
    scale: Annotated[
        float | None, typer.Option("--scale", help="Metres per mesh unit (default: detect mm/cm from the size).")
    ] = None,
    density: Annotated[
        float | None, typer.Option("--density", help="Object density of the rollouts, kg/m^3 (default: the model's "
                                   "training physics, else 700).", min=0.0)
    ] = None,
    friction: Annotated[
        float | None, typer.Option("--friction", help="Object friction of the rollouts (default: the model's "
                                   "training physics, else 1.0).", min=0.0)
    ] = None,
    hand_check: Annotated[
        int, typer.Option("--hand-check", help="Surface points tested against the open hand before choosing: the "
                          "top K are drawn from the candidates whose hand holds none (0: no check).", min=0)
    ] = 20000,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the candidates and the random pick.", min=0)] = 0,
    jobs: Annotated[int, typer.Option("--jobs", "-j", help="Workers of the rollouts (0 = all cores).")] = 1,
) -> None:
    """Sample candidates on a mesh, score them with a model, and simulate the top K and K random ones (acronym
    protocol, the model's gripper, at the physics the model was trained at unless --density / --friction): their
    success rates (held and firm), printed and written to --json."""
    import numpy as np

    console = Console(stderr=True)
    try:
        from graspgen.learn import require_torch

        require_torch()
        from graspgen.learn.pick import PickParams, pick, simulate_pick
        from graspgen.learn.train import load_model

        check_writable(json_path, "results file (--json)", file=True)
        if not mesh.is_file():
            raise ValueError(f"--mesh: {mesh}: no such file")
        model = load_model(model_path)
        learned = model.physics
        params = PickParams(candidates=candidates, top=top, scale=scale, hand_check_points=hand_check,
                            density=density if density is not None else learned.get("density") or 700.0,
                            friction=friction if friction is not None else learned.get("friction") or 1.0)
        result = pick(model, mesh, params, np.random.default_rng(seed))
        summary = simulate_pick(result, model.gripper, params, jobs=jobs,
                                cache_dir=load(PROJECT, None, None).run.cache_dir)
    except (*USER_ERRORS, ValueError) as exc:
        fail(console, _line(exc))
    summary.update(model=str(model_path), seed=seed)
    _write_json(console, json_path, summary)
    console.print(f"{summary['candidates']} candidates on {mesh.name}: top {summary['n_top']} by score "
                  f"{100 * summary['top_success']:.0f}% success ({100 * summary['top_firm']:.0f}% firm), "
                  f"{summary['n_random']} random {100 * summary['random_success']:.0f}% "
                  f"({100 * summary['random_firm']:.0f}% firm); density {params.density:g} kg/m^3, friction "
                  f"{params.friction:g}", highlight=False)
    if "clear_candidates" in summary:
        clear = summary["random_clear_success"]
        console.print(f"{summary['clear_candidates']} candidates clear of the open hand; "
                      f"{len(summary['random_clear_outcomes'])} random "
                      f"of them {'-' if clear is None else f'{100 * clear:.0f}%'} success", highlight=False)
    print(json_path)
