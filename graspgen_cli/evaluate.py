"""``gen evaluate``: label external grasps of one object (an ACRONYM file or Parquet poses) with our simulator.

The library is :func:`graspgen.workflows.evaluate.evaluate_grasps`; this command reads the arguments, calls it, writes
the labels and prints their counts. Errors a user can cause are one line and exit 2.
"""

# No `from __future__ import annotations`: Typer reads the annotations at run time.

from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console

from pipeline.cli import ConfigOpt, SetOpt, check_writable, fail, load, os_error_text
from stages.project import PROJECT, USER_ERRORS


def evaluate(
    grasps: Annotated[
        Path, typer.Option("--grasps", help="ACRONYM grasp file (.h5, .hdf5) or Parquet of TCP poses (.parquet).")
    ],
    gripper: Annotated[str, typer.Option(
        "--gripper", help="Gripper to evaluate with: box_jaw, panda, robotiq_2f85, robotiq_2f85_mesh, or a file.")],
    output: Annotated[Path, typer.Option("--out", "-o", help="Output Parquet file, one row per input grasp.")],
    mesh_root: Annotated[
        Path | None, typer.Option("--mesh-root", help="Folder ACRONYM's object/file is relative to (default: cwd).")
    ] = None,
    mesh: Annotated[
        Path | None, typer.Option("--mesh", help="Mesh file: needed with Parquet input; replaces object/file.")
    ] = None,
    scale: Annotated[
        float | None, typer.Option("--scale", help="Metres per mesh unit (default: object/scale; Parquet: detect).")
    ] = None,
    friction: Annotated[
        float | None, typer.Option("--friction", help="Object friction (default: object/friction, else 0.5).")
    ] = None,
    support: Annotated[
        bool, typer.Option("--support", help="Object on a table in its most probable stable pose (table protocol).")
    ] = False,
    protocol: Annotated[
        str | None,
        typer.Option(
            "--protocol",
            help="acronym (ACRONYM's free-space close-and-shake), graspdatagen (GraspDataGen's free-space tug test: "
            "gravity off, close, pull with the object's weight along +z and four tilted directions) or table "
            "(approach, close, lift); default: acronym for ACRONYM files (table with --support), table for Parquet.",
        ),
    ] = None,
    jobs: Annotated[int, typer.Option("--jobs", "-j", help="Worker processes (0 = all cores).")] = 1,
    robustness: Annotated[
        int,
        typer.Option(
            "--robustness",
            help="Also roll out N perturbed copies of every successful grasp (the robustness stage's noise, config "
            "section robustness) and add robustness columns (robustness, its Wilson interval, grip_robustness, "
            "copy_outcomes); 0: none.",
            min=0,
        ),
    ] = 0,
    backend: Annotated[
        str,
        typer.Option("--backend", help="mujoco (the CPU, --jobs workers) or warp (MuJoCo Warp: many grasps at once "
                     "on a GPU, or Warp's CPU device; every protocol; needs the warp extra)."),
    ] = "mujoco",
    device: Annotated[
        str | None, typer.Option("--device", help="With --backend warp: Warp device (cpu, cuda:0; default: Warp's).")
    ] = None,
    worlds: Annotated[
        int, typer.Option("--worlds", help="With --backend warp: grasps rolled out at once (parallel worlds).", min=1)
    ] = 1024,
    config: ConfigOpt = None,
    set_: SetOpt = None,
) -> None:
    """Label external grasps of one object with our simulator (outcome 0-5 per grasp, in input order).

    Protocols (docs/protocols.md): acronym (ACRONYM files' default) places the open hand at the grasp, closes and
    shakes in free space; table approaches, closes, lifts and shakes, in free space (gravity off until the fingers have
    closed) or, with --support, on a table.

    ACRONYM: hand-base poses + the file gripper's TCP offset; object/scale, mass (or density), friction are used.

    --config: the protocol is its rollouts.lift, CoACD its objects.coacd (else cheap), cache in run.cache_dir.

    --robustness N: N perturbed copies of each success, as the robustness stage perturbs them (its config section:
    TCP pose, object mass, centre of mass and friction; radius not computed); the draws are seeded from the poses and
    settings.
    """
    console = Console(stderr=True)
    table, reference, protocol = _label(console, grasps, gripper, output, mesh_root, mesh, scale, friction, support,
                                        protocol, jobs, robustness, backend, device, worlds, config, set_)
    _write_labels(console, output, table)
    _print_counts(console, table, reference, support, protocol, backend, robustness)
    print(output)


def _label(console: Console, grasps: Path, gripper: str, output: Path, mesh_root: Path | None, mesh: Path | None,
           scale: float | None, friction: float | None, support: bool, protocol: str | None, jobs: int,
           robustness: int, backend: str, device: str | None, worlds: int, config: Path | None,
           set_: list[str] | None) -> tuple[Any, Any, str | None]:
    """Read the grasp file and roll its grasps out: ``(table, reference, protocol)``, the labels (with the file's
    own label as ``reference_success`` when it has one), that label (``(n,)`` int or None) and the protocol."""
    import dataclasses

    import numpy as np
    import pyarrow as pa

    from graspgen.grippers import load_gripper
    from graspgen.sim.warp_backend import WarpParams
    from graspgen.workflows.evaluate import evaluate_grasps
    from graspgen.workflows.evaluate_settings import CHEAP_COACD, EvaluateParams
    from graspgen.workflows.grasp_files import read_grasp_file

    try:
        cfg = load(PROJECT, config, set_)
        load_gripper(gripper)  # ConfigError listing the grippers, before any work
        check_writable(output, "output file (-o)", file=True)  # a folder, a read-only place: before simulating
        params = EvaluateParams(lift=cfg.rollouts.lift, coacd=cfg.objects.coacd if config else CHEAP_COACD)
        loaded = read_grasp_file(grasps, params, mesh_root=mesh_root, mesh=mesh, scale=scale, friction=friction)
        if protocol is None:
            protocol = "acronym" if loaded.kind == "acronym" and not support else "table"
        params = dataclasses.replace(loaded.params, lift=loaded.params.lift.with_protocol(protocol))
        reference = loaded.reference
        noise = dataclasses.replace(cfg.robustness, num_perturbations=robustness) if robustness else None
        table = evaluate_grasps(
            loaded.mesh_path, loaded.scale, loaded.T_tcp, loaded.widths, gripper, params, free_space=not support,
            jobs=jobs, cache_dir=cfg.run.cache_dir, robustness=noise, backend=backend,
            warp=WarpParams(device=device, nworld=worlds),
        )
    except (*USER_ERRORS, ValueError) as exc:
        fail(console, str(exc))
    if reference is not None:  # keep the file's own label next to ours, for comparison
        table = table.append_column("reference_success", pa.array(np.asarray(reference, dtype=np.int8)))
    return table, reference, protocol


def _write_labels(console: Console, output: Path, table: Any) -> None:
    """Write the labels to ``output`` (its folder made when missing) and print the warnings they carry."""
    import json

    from graspgen.io.files import write_parquet
    from graspgen.workflows.evaluate_columns import METADATA_KEY

    try:
        output.parent.mkdir(parents=True, exist_ok=True)
        write_parquet(output, table)
    except OSError as exc:
        fail(console, f"{output}: cannot write the labels ({os_error_text(exc)})", code=1)
    for warning in json.loads(table.schema.metadata[METADATA_KEY.encode()])["warnings"]:
        console.print(f"warning: {warning}", highlight=False, markup=False)


def _print_counts(console: Console, table: Any, reference: Any, support: bool, protocol: str | None, backend: str,
                  robustness: int) -> None:
    """Print the outcome counts, the held and firm labels, the agreement with the file's own label and the mean
    robustness."""
    import numpy as np

    from graspgen.workflows.evaluate_columns import outcome_counts

    counts = ", ".join(f"{name} {n}" for name, n in outcome_counts(table).items() if n)
    mode = "support plane" if support else f"{protocol or 'table'} protocol, free space"
    mode += f", {backend} backend" if backend != "mujoco" else ""
    console.print(f"{len(table)} grasps ({mode}): {counts}", highlight=False)
    held, firm = int(np.sum(table.column("outcome").to_numpy() == 5)), int(np.sum(table.column("firm").to_numpy()))
    console.print(f"labels: held {held}, firm {firm} (held and within the firm-hold tolerances)", highlight=False)
    if reference is not None:
        agree = int(np.sum((table.column("outcome").to_numpy() == 5) == (np.asarray(reference) == 1)))
        console.print(f"agreement with the file's success label: {agree}/{len(table)}", highlight=False)
    if robustness:
        n_copies = table.column("robustness_n").to_numpy()
        held = n_copies > 0
        mean = float(np.mean(table.column("robustness").to_numpy()[held])) if held.any() else float("nan")
        console.print(f"robustness: {int(n_copies.sum())} copies of {int(held.sum())} successes; mean robustness "
                      f"{mean:.3f}", highlight=False)
