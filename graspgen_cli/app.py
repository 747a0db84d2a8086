"""The ``gen`` console script: the generic pipeline commands bound to this project's stages, plus ``gen show``."""

# No `from __future__ import annotations`: Typer reads the annotations of closures at run time.

# MuJoCo reads MUJOCO_GL once, when it is first imported (stages.objects imports it): choose a headless OpenGL
# back end this machine has before that (EGL, else OSMesa, else none), so that no command needs OpenGL to start.
from graspgen.sim.gl import select_backend

select_backend()

from pathlib import Path  # noqa: E402
from typing import Annotated, Any  # noqa: E402

import typer  # noqa: E402
from rich.console import Console  # noqa: E402
from rich.text import Text  # noqa: E402

from pipeline.cli import ConfigOpt, SetOpt, build_app, check_writable, fail, load, os_error_text  # noqa: E402
from pipeline.errors import StageError  # noqa: E402
from pipeline.scheduler import Project, committed, plan, upstream_view  # noqa: E402
from pipeline.stage import topological_order  # noqa: E402
from pipeline.store import Manifest, stage_dir  # noqa: E402
from stages.project import PROJECT, USER_ERRORS  # noqa: E402

app = build_app(PROJECT)
show_app = typer.Typer(help="Look at outputs (writes PNG images).", no_args_is_help=True)
app.add_typer(show_app, name="show")


def find_shard(project: Project, config: Any, stage: str, task_id: str) -> tuple[Path, bool]:
    """The shard of ``task_id`` in ``stage`` under ``config.run.out``.

    Returns ``(path, current)``: the shard of the current config's key when it is committed (``current`` True),
    else the latest committed shard of that task id from an earlier config (``current`` False).

    Raises
    ------
    StageError
        When the stage has no committed shard for ``task_id``.
    """
    out = Path(config.run.out)
    keys: dict[str, set[str]] = {}
    want: str | None = None
    for s in topological_order(project.stages, [stage]):
        try:
            planned = plan(s, s.params(config), upstream_view(out, s, keys, verify_hash=False))
        except USER_ERRORS:
            planned = []  # e.g. upstream not run yet: fall back to whatever is on disk
        keys[s.name] = {p.key for p in planned}
        if s.name == stage:
            want = next((p.key for p in planned if p.task.id == task_id), None)
    entries = committed(out, stage, verify_hash=False)
    if want is not None and want in entries:
        return stage_dir(out, stage) / str(entries[want].file), True
    older = [e for e in Manifest(stage_dir(out, stage)).entries().values() if e.task == task_id and e.key in entries]
    if older:
        return stage_dir(out, stage) / str(older[-1].file), False
    known = sorted({e.task for e in entries.values()})
    hint = f"; it has: {', '.join(known[:5])}{' ...' if len(known) > 5 else ''}" if known else ""
    raise StageError(
        f"no {stage} shard for {task_id!r} in {stage_dir(out, stage)}{hint}. "
        f"Run `gen run {stage}` with this config first"
    )


@show_app.command("scene")
def show_scene(
    scene_id: Annotated[str, typer.Argument(help="Scene task id, e.g. scene_000000.")],
    view: Annotated[int | None, typer.Option("--view", "-v", help="Only this view (default: all).")] = None,
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="PNG path (default: OUT/show/<scene>[_view<k>].png).")
    ] = None,
    config: ConfigOpt = None,
    out: Annotated[Path | None, typer.Option("--out", help="Output folder of the run (overrides run.out).")] = None,
    set_: SetOpt = None,
) -> None:
    """Write a contact sheet of a scene (RGB | depth | segmentation per view) as PNG and print its path."""
    from graspgen.io.scenes import read_scene
    from graspgen.viz.scenes import contact_sheet

    console = Console(stderr=True)
    try:
        cfg = load(PROJECT, config, set_, out=out)
        if output is None:
            output = Path(cfg.run.out) / "show" / (f"{scene_id}.png" if view is None else f"{scene_id}_view{view}.png")
        check_writable(output, "output file", file=True)
        path, current = find_shard(PROJECT, cfg, "scenes", scene_id)
        scene = read_scene(path)
        sheet = contact_sheet(scene, None if view is None else [view])
    except (*USER_ERRORS, ValueError) as exc:
        fail(console, str(exc))
    if not current:
        console.print(f"note: {scene_id} is from an earlier config (its key differs from the current one)",
                      markup=False, highlight=False)
    save_image(console, output, sheet.save)


@show_app.command("grasps")
def show_grasps(
    scene_id: Annotated[str, typer.Argument(help="Scene task id, e.g. scene_000000.")],
    num: Annotated[
        int, typer.Option("--num", "-n", help="At most this many grasps, spread over the labels.", min=0)
    ] = 30,
    view: Annotated[int, typer.Option("--view", "-v", help="Camera view to draw on.")] = 0,
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="PNG path (default: OUT/show/<scene>_grasps_view<k>.png).")
    ] = None,
    scale: Annotated[int, typer.Option("--scale", help="Upscaling of the rendered view.", min=1, max=8)] = 3,
    config: ConfigOpt = None,
    out: Annotated[Path | None, typer.Option("--out", help="Output folder of the run (overrides run.out).")] = None,
    set_: SetOpt = None,
) -> None:
    """Draw a scene's grasps on one of its camera views as gripper markers (PNG), coloured by rollout outcome when
    the scene was rolled out, else by the collision pre-filter; print the PNG's path."""
    import pyarrow.parquet as pq

    from graspgen.io.scenes import read_scene
    from graspgen.viz.grasp_view import grasp_picture, rollouts_match

    console = Console(stderr=True)
    notes = []
    try:
        cfg = load(PROJECT, config, set_, out=out)
        if output is None:
            output = Path(cfg.run.out) / "show" / f"{scene_id}_grasps_view{view}.png"
        check_writable(output, "output file", file=True)
        scene_path, current = find_shard(PROJECT, cfg, "scenes", scene_id)
        grasps_path, grasps_current = find_shard(PROJECT, cfg, "grasps", scene_id)
        grasps = pq.read_table(grasps_path)
        try:
            rollouts_path, rollouts_current = find_shard(PROJECT, cfg, "rollouts", scene_id)
            rollouts = pq.read_table(rollouts_path)
        except StageError:
            rollouts, rollouts_current = None, False  # not rolled out (yet): colour by the pre-filter
        # A rollouts shard of another config than the grasps shard labels other grasps: do not mix them.
        if rollouts is not None and (rollouts_current != grasps_current or not rollouts_match(grasps, rollouts)):
            notes.append(f"the rollouts of {scene_id} do not belong to its grasps shard: colouring by the pre-filter")
            rollouts = None
        if not (current and grasps_current):
            notes.append(f"{scene_id} is from an earlier config (its key differs from the current one)")
        picture = grasp_picture(read_scene(scene_path), grasps, rollouts, view=view, n=num, scale=scale)
    except (*USER_ERRORS, ValueError) as exc:
        fail(console, str(exc))
    for note in notes:
        console.print(f"note: {note}", highlight=False, markup=False)
    save_image(console, output, picture.save)


@show_app.command("rollout")
def show_rollout(
    scene_id: Annotated[str, typer.Argument(help="Scene task id, e.g. scene_000000.")],
    grasp_id: Annotated[int, typer.Argument(help="Grasp id within the scene (the grasps table's grasp_id).")],
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="PNG strip or GIF (default: OUT/show/<scene>_g<id>.png).")
    ] = None,
    frames: Annotated[int, typer.Option("--frames", "-n", help="At most this many frames.", min=1, max=16)] = 6,
    config: ConfigOpt = None,
    out: Annotated[Path | None, typer.Option("--out", help="Output folder of the run (overrides run.out).")] = None,
    set_: SetOpt = None,
) -> None:
    """Re-run one grasp of a scene and write frames of it (placement, approach, closing, lift) with its outcome."""
    import pyarrow.parquet as pq

    from graspgen.io.objects import read_object
    from graspgen.viz.rollout_movie import rollout_movie, save_movie

    console = Console(stderr=True)
    try:
        cfg = load(PROJECT, config, set_, out=out)
        if output is not None and output.suffix.lower() not in (".png", ".gif"):
            raise ValueError(f"{output}: unsupported image type {output.suffix or '(none)'!r}; use .png or .gif")
        if output is None:
            output = Path(cfg.run.out) / "show" / f"{scene_id}_g{grasp_id}.png"
        check_writable(output, "output file", file=True)
        scene_path, current = find_shard(PROJECT, cfg, "scenes", scene_id)
        grasps = pq.read_table(find_shard(PROJECT, cfg, "grasps", scene_id)[0])
        try:
            rollouts = pq.read_table(find_shard(PROJECT, cfg, "rollouts", scene_id)[0])
        except StageError:
            rollouts = None  # grasps exist but were not rolled out yet: show the re-run alone
        movie = rollout_movie(
            scene_path,
            lambda name: read_object(find_shard(PROJECT, cfg, "objects", name)[0]),
            grasps,
            grasp_id,
            cfg.rollouts.lift,
            rollouts=rollouts,
            n_frames=frames,
        )
    except (*USER_ERRORS, ValueError) as exc:
        fail(console, str(exc))
    save_image(console, output, lambda path: save_movie(movie, path), show=False)
    if not current:
        console.print(f"note: {scene_id} is from an earlier config (its key differs from the current one)",
                      markup=False, highlight=False)
    stored = "not rolled out" if movie.stored_outcome is None else str(movie.stored_outcome)
    console.print(f"outcome {movie.result.code} {movie.result.name} (stored: {stored}); {len(movie.images)} frames",
                  highlight=False)
    print(output)


@show_app.command("gripper")
def show_gripper(
    gripper: Annotated[str, typer.Argument(help="A bundled gripper's name or the path of a gripper file (.yaml).")],
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="PNG path (default: OUT/show/gripper_<name>.png).")
    ] = None,
    wireframe: Annotated[
        bool, typer.Option("--wireframe", help="Draw the collision geoms' outlines (matplotlib), no rendering.")
    ] = False,
    config: ConfigOpt = None,
    out: Annotated[Path | None, typer.Option("--out", help="Output folder of the run (overrides run.out).")] = None,
) -> None:
    """Draw a gripper open and closed with its TCP frame (PNG); print the PNG's path."""
    from graspgen.sim.grippers import gripper_picture, load_gripper

    console = Console(stderr=True)
    try:
        spec = load_gripper(gripper)
        if output is None:
            safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in spec.name)
            output = Path(load(PROJECT, config, None, out=out).run.out) / "show" / f"gripper_{safe}.png"
        check_writable(output, "output file", file=True)
        picture = gripper_picture(spec, render=not wireframe)
    except (*USER_ERRORS, ValueError) as exc:
        fail(console, str(exc))
    save_image(console, output, picture.save)


@app.command("evaluate")
def evaluate(
    grasps: Annotated[
        Path, typer.Option("--grasps", help="ACRONYM grasp file (.h5, .hdf5) or Parquet of TCP poses (.parquet).")
    ],
    gripper: Annotated[str, typer.Option("--gripper", help="Gripper to evaluate with: box_jaw, panda, robotiq_2f85.")],
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
            help="acronym (ACRONYM's free-space close-and-shake), graspgen (GraspDataGen's free-space tug test: "
            "gravity off, close, pull with the object's weight along +z and four tilted directions) or table "
            "(approach, close, lift); default: acronym for ACRONYM files (table with --support), table for Parquet.",
        ),
    ] = None,
    jobs: Annotated[int, typer.Option("--jobs", "-j", help="Worker processes (0 = all cores).")] = 1,
    config: ConfigOpt = None,
    set_: SetOpt = None,
) -> None:
    """Label external grasps of one object with our simulator (outcome 0-5 per grasp, in input order).

    Protocols (README, Protocols): acronym (ACRONYM files' default) places the open hand at the grasp, closes and
    shakes in free space; table approaches, closes and lifts, in free space (gravity off until the fingers have
    closed) or, with --support, on a table.

    ACRONYM: hand-base poses + the file gripper's TCP offset; object/scale, mass (or density), friction are used.

    --config: the protocol is its rollouts.lift, CoACD its objects.coacd (else cheap), cache in run.cache_dir.
    """
    import dataclasses
    import json

    import numpy as np
    import pyarrow as pa

    from graspgen.errors import InputError
    from graspgen.evaluate import (
        CHEAP_COACD,
        METADATA_KEY,
        EvaluateParams,
        evaluate_grasps,
        outcome_counts,
        read_pose_table,
    )
    from graspgen.io.acronym import read_acronym
    from graspgen.io.files import write_parquet
    from graspgen.sim.grippers import load_gripper

    console = Console(stderr=True)
    try:
        cfg = load(PROJECT, config, set_)
        load_gripper(gripper)  # ConfigError listing the grippers, before any work
        check_writable(output, "output file (-o)", file=True)  # a folder, a read-only place: before simulating
        suffix = grasps.suffix.lower()
        if not grasps.is_file():
            raise InputError(f"{grasps}: grasp file not found")
        params = EvaluateParams(lift=cfg.rollouts.lift, coacd=cfg.objects.coacd if config else CHEAP_COACD)
        reference = None
        if protocol is None:
            protocol = "acronym" if suffix in (".h5", ".hdf5") and not support else "table"
        params = dataclasses.replace(params, lift=params.lift.with_protocol(protocol))
        if suffix in (".h5", ".hdf5"):
            acr = read_acronym(grasps)
            try:
                T = acr.tcp_poses()
            except USER_ERRORS as exc:
                raise InputError(f"{grasps}: gripper/type {acr.gripper_type!r}: {exc}") from None
            widths = None
            root = mesh_root if mesh_root is not None else Path.cwd()
            mesh_path = mesh if mesh is not None else root / acr.object_file
            if not mesh_path.is_file():
                how = "--mesh" if mesh is not None else f"object/file {acr.object_file!r} under --mesh-root {root}"
                raise InputError(f"{grasps}: mesh not found: {mesh_path} ({how})")
            scale = acr.object_scale if scale is None else scale
            fric = friction if friction is not None else acr.object_friction
            params = dataclasses.replace(
                params,
                friction=fric if fric is not None else params.friction,
                mass=acr.object_mass,
                density=acr.object_density if acr.object_density is not None else params.density,
            )
            reference = acr.success
        elif suffix == ".parquet":
            if mesh is None:
                raise InputError(f"{grasps}: a Parquet grasp file needs --mesh (the mesh its poses refer to)")
            T, widths = read_pose_table(grasps)
            mesh_path = mesh if mesh_root is None or mesh.is_absolute() else mesh_root / mesh
            if not mesh_path.is_file():
                raise InputError(f"{grasps}: mesh not found: {mesh_path} (--mesh)")
            if friction is not None:
                params = dataclasses.replace(params, friction=friction)
        else:
            raise InputError(
                f"{grasps}: unsupported grasp file format {grasps.suffix or '(none)'!r}; expected an ACRONYM HDF5 "
                "file (.h5, .hdf5) or a Parquet table of poses (.parquet)"
            )
        table = evaluate_grasps(
            mesh_path, scale, T, widths, gripper, params, free_space=not support, jobs=jobs, cache_dir=cfg.run.cache_dir
        )
    except (*USER_ERRORS, ValueError) as exc:
        fail(console, str(exc))
    if reference is not None:  # keep the file's own label next to ours, for comparison
        table = table.append_column("reference_success", pa.array(np.asarray(reference, dtype=np.int8)))
    try:
        output.parent.mkdir(parents=True, exist_ok=True)
        write_parquet(output, table)
    except OSError as exc:
        fail(console, f"{output}: cannot write the labels ({os_error_text(exc)})", code=1)
    for warning in json.loads(table.schema.metadata[METADATA_KEY.encode()])["warnings"]:
        console.print(f"warning: {warning}", highlight=False, markup=False)
    counts = ", ".join(f"{name} {n}" for name, n in outcome_counts(table).items() if n)
    mode = "support plane" if support else f"{protocol or 'table'} protocol, free space"
    console.print(f"{len(table)} grasps ({mode}): {counts}", highlight=False)
    if reference is not None:
        agree = int(np.sum((table.column("outcome").to_numpy() == 5) == (np.asarray(reference) == 1)))
        console.print(f"agreement with the file's success label: {agree}/{len(table)}", highlight=False)
    print(output)


@app.command("report")
def report_cmd(
    out: Annotated[Path, typer.Argument(help="The run folder (or its dataset/ folder) of a published dataset.")],
) -> None:
    """Render the dataset card (card.md, card.json) and its plots again from a published dataset."""
    from graspgen.io.card import report

    console = Console(stderr=True)
    try:
        path = report(out)
    except USER_ERRORS as exc:
        fail(console, str(exc))
    except OSError as exc:  # a read-only dataset folder, a damaged HDF5 file
        fail(console, f"{out}: cannot render the card ({os_error_text(exc)}); gen validate {out} names bad files", 1)
    print(path)


@app.command("validate")
def validate_cmd(
    out: Annotated[Path, typer.Argument(help="The run folder (or its dataset/ folder) of a published dataset.")],
) -> None:
    """Check every file of a dataset against its manifest / card hashes and the schema; list what is wrong."""
    from stages.dataset import validate

    console = Console(stderr=True)
    try:
        problems, checked = validate(out)
    except USER_ERRORS as exc:
        fail(console, str(exc))
    if problems:
        head = Text.assemble((f"{len(problems)} problem(s)", "bold red"), f" in {out} ({checked} files checked):")
        console.print(head, highlight=False, soft_wrap=True)
        for p in problems:
            console.print(f"  {p}", highlight=False, soft_wrap=True, markup=False)
        raise typer.Exit(1)
    console.print(f"OK: {out}: {checked} files match their hashes; the table matches its schema",
                  highlight=False, soft_wrap=True, markup=False)


def save_image(console: Console, output: Path, save: Any, *, show: bool = True) -> None:
    """``save(output)`` into its folder (made when missing), then print the path (with ``show``); a failure to
    write is one line and exit 1."""
    try:
        output.parent.mkdir(parents=True, exist_ok=True)
        save(output)
    except OSError as exc:
        fail(console, f"{output}: cannot write the image ({os_error_text(exc)})", code=1)
    except ValueError as exc:
        fail(console, str(exc))
    if show:
        print(output)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
