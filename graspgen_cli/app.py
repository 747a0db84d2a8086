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

from graspgen_cli.evaluate import evaluate  # noqa: E402
from graspgen_cli.probe import probe_app  # noqa: E402
from pipeline.cli import ConfigOpt, SetOpt, build_app, check_writable, fail, load, os_error_text  # noqa: E402
from pipeline.errors import StageError  # noqa: E402
from pipeline.plan import Project, committed, plan, upstream_view  # noqa: E402
from pipeline.stage import topological_order  # noqa: E402
from pipeline.store import Manifest, stage_dir  # noqa: E402
from stages.project import PROJECT, USER_ERRORS  # noqa: E402

app = build_app(PROJECT)
app.add_typer(probe_app, name="probe")
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
            planned = plan(s, s.params(config), upstream_view(out, s, keys, verify_hash=False), seed=config.run.seed)
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
    scene_id: Annotated[
        str, typer.Argument(help="Scene task id, e.g. scene_000000; with --3d also an object name (its grasp set).")
    ],
    num: Annotated[
        int, typer.Option("--num", "-n", help="At most this many grasps, spread over the labels.", min=0)
    ] = 30,
    view: Annotated[int, typer.Option("--view", "-v", help="Camera view to draw on.")] = 0,
    output: Annotated[
        Path | None,
        typer.Option("--output", "-o", help="PNG path (default: OUT/show/<scene>_grasps_view<k>.png); with --3d a "
                     ".glb path (default: OUT/show/<id>_grasps.glb)."),
    ] = None,
    scale: Annotated[int, typer.Option("--scale", help="Upscaling of the rendered view.", min=1, max=8)] = 3,
    three_d: Annotated[
        bool, typer.Option("--3d", help="Write a 3-D scene (GLB): the mesh(es) and one gripper marker per grasp.")
    ] = False,
    config: ConfigOpt = None,
    out: Annotated[Path | None, typer.Option("--out", help="Output folder of the run (overrides run.out).")] = None,
    set_: SetOpt = None,
) -> None:
    """Draw a scene's grasps on one of its camera views as gripper markers (PNG), coloured by rollout outcome when
    the scene was rolled out, else by the collision pre-filter; print the PNG's path.

    With --3d, write a GLB instead: for an object name, the object and its free-space grasp set (the object_grasps
    stage), green success, red failure, in the object's mesh frame; for a scene id, the scene's objects at their
    poses and its grasps in the world frame, coloured as the picture is."""
    import pyarrow.parquet as pq

    from graspgen.io.scenes import read_scene
    from graspgen.viz.grasp_view import grasp_picture, rollouts_match

    console = Console(stderr=True)
    notes = []
    if three_d:
        _show_grasps_3d(console, scene_id, num, output, config, out, set_)
        return
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


def _show_grasps_3d(console: Console, name: str, num: int, output: Path | None, config: Any, out: Path | None,
                    set_: Any) -> None:
    """``gen show grasps --3d``: an object's grasp set (object_grasps stage) or a scene's grasps as a GLB."""
    import pyarrow.parquet as pq

    from graspgen.io.objects import read_object
    from graspgen.io.scenes import read_scene
    from graspgen.viz.grasp_glb import object_set_glb, scene_glb, write_glb
    from graspgen.viz.grasp_view import rollouts_match

    notes = []
    try:
        cfg = load(PROJECT, config, set_, out=out)
        if output is not None and output.suffix.lower() != ".glb":
            raise ValueError(f"{output}: --3d writes a GLB file; use a .glb path")
        if output is None:
            output = Path(cfg.run.out) / "show" / f"{name}_grasps.glb"
        check_writable(output, "output file", file=True)
        try:
            set_path, current = find_shard(PROJECT, cfg, "object_grasps", name)
        except StageError as object_error:
            set_path, current = None, False
            try:
                scene_path, current = find_shard(PROJECT, cfg, "scenes", name)
            except StageError as scene_error:
                raise StageError(f"{name!r} is neither an object with a grasp set ({object_error}) nor a scene "
                                 f"({scene_error})") from None
        if set_path is not None:
            record = read_object(find_shard(PROJECT, cfg, "objects", name)[0])
            data = object_set_glb(record, pq.read_table(set_path), n=num)
        else:
            grasps_path, grasps_current = find_shard(PROJECT, cfg, "grasps", name)
            grasps = pq.read_table(grasps_path)
            try:
                rollouts_path, rollouts_current = find_shard(PROJECT, cfg, "rollouts", name)
                rollouts = pq.read_table(rollouts_path)
            except StageError:
                rollouts, rollouts_current = None, False
            if rollouts is not None and (rollouts_current != grasps_current or not rollouts_match(grasps, rollouts)):
                notes.append(f"the rollouts of {name} do not belong to its grasps shard: colouring by the pre-filter")
                rollouts = None
            current = current and grasps_current
            data = scene_glb(read_scene(scene_path), lambda n: read_object(find_shard(PROJECT, cfg, "objects", n)[0]),
                             grasps, rollouts, n=num)
        if not current:
            notes.append(f"{name} is from an earlier config (its key differs from the current one)")
    except (*USER_ERRORS, ValueError) as exc:
        fail(console, str(exc))
    for note in notes:
        console.print(f"note: {note}", highlight=False, markup=False)
    save_image(console, output, lambda path: write_glb(path, data))


@show_app.command("rollout")
def show_rollout(
    scene_id: Annotated[
        str | None, typer.Argument(help="Scene task id, e.g. scene_000000 (not with --grasps).", show_default=False)
    ] = None,
    grasp_id: Annotated[
        int | None,
        typer.Argument(help="Grasp id within the scene (the grasps table's grasp_id).", show_default=False),
    ] = None,
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="PNG strip or GIF (default: OUT/show/<scene>_g<id>.png).")
    ] = None,
    frames: Annotated[int, typer.Option("--frames", "-n", help="At most this many frames.", min=1, max=16)] = 6,
    grasps: Annotated[
        Path | None,
        typer.Option("--grasps", help="Instead of a scene: an external grasp file as gen evaluate takes (ACRONYM "
                     ".h5 or Parquet poses); show grasp --index in gen evaluate's world."),
    ] = None,
    index: Annotated[int | None, typer.Option("--index", help="Row of the grasp in --grasps (0-based).", min=0)] = None,
    protocol: Annotated[
        str | None,
        typer.Option("--protocol", help="With --grasps: acronym, graspdatagen or table (default as gen evaluate: "
                     "acronym for ACRONYM files, table for Parquet or with --support)."),
    ] = None,
    gripper: Annotated[
        str | None, typer.Option("--gripper", help="With --grasps: the gripper (default: the ACRONYM file's).")
    ] = None,
    mesh_root: Annotated[
        Path | None, typer.Option("--mesh-root", help="With --grasps: folder of ACRONYM's object/file (default: cwd).")
    ] = None,
    mesh: Annotated[
        Path | None, typer.Option("--mesh", help="With --grasps: the mesh file (needed with Parquet).")
    ] = None,
    scale: Annotated[float | None, typer.Option("--scale", help="With --grasps: metres per mesh unit.")] = None,
    friction: Annotated[float | None, typer.Option("--friction", help="With --grasps: the object's friction.")] = None,
    support: Annotated[
        bool, typer.Option("--support", help="With --grasps: the object on a table (table protocol).")
    ] = False,
    config: ConfigOpt = None,
    out: Annotated[Path | None, typer.Option("--out", help="Output folder of the run (overrides run.out).")] = None,
    set_: SetOpt = None,
) -> None:
    """Re-run one grasp of a scene and write frames of it (placement, approach, closing, lift) with its outcome.

    With --grasps FILE --index I: one grasp of an external grasp file, rolled out as gen evaluate rolls it out (the
    same object, protocol and world; --config as for gen evaluate), e.g. an ACRONYM grasp under the acronym protocol
    (placed open, close, shake).
    """
    console = Console(stderr=True)
    if grasps is not None:
        if scene_id is not None or grasp_id is not None:
            fail(console, "scene_id, grasp_id: give either SCENE_ID GRASP_ID or --grasps FILE --index I, not both")
        if index is None:
            fail(console, "--index: which grasp of --grasps to show (its 0-based row)")
        _show_external_rollout(console, grasps, index, output, frames, protocol, gripper, mesh_root, mesh, scale,
                               friction, support, config, out, set_)
        return
    if scene_id is None or grasp_id is None:
        fail(console, "scene_id, grasp_id: missing; give SCENE_ID GRASP_ID (or --grasps FILE --index I)")
    _show_scene_rollout(console, scene_id, grasp_id, output, frames, config, out, set_)


def _show_scene_rollout(console: Console, scene_id: str, grasp_id: int, output: Path | None, frames: int,
                        config: Path | None, out: Path | None, set_: list[str] | None) -> None:
    """``gen show rollout SCENE_ID GRASP_ID``: the grasp re-run in its scene, filmed, with its stored outcome."""
    import pyarrow.parquet as pq

    from graspgen.io.objects import read_object
    from graspgen.viz.rollout_movie import rollout_movie, save_movie

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


def _show_external_rollout(console: Console, grasps: Path, index: int, output: Path | None, frames: int,
                           protocol: str | None, gripper: str | None, mesh_root: Path | None, mesh: Path | None,
                           scale: float | None, friction: float | None, support: bool, config: Path | None,
                           out: Path | None, set_: list[str] | None) -> None:
    """``gen show rollout --grasps FILE --index I``: grasp I of FILE in gen evaluate's world, filmed."""
    import dataclasses

    from graspgen.viz.evaluate_movie import evaluated_rollout_movie
    from graspgen.viz.rollout_movie import save_movie
    from graspgen.workflows.evaluate_settings import CHEAP_COACD, EvaluateParams
    from graspgen.workflows.evaluation_world import evaluation_world
    from graspgen.workflows.grasp_files import read_grasp_file

    try:
        cfg = load(PROJECT, config, set_, out=out)
        if output is not None and output.suffix.lower() not in (".png", ".gif"):
            raise ValueError(f"{output}: unsupported image type {output.suffix or '(none)'!r}; use .png or .gif")
        if output is None:
            output = Path(cfg.run.out) / "show" / f"{grasps.stem}_i{index}.png"
        check_writable(output, "output file", file=True)
        params = EvaluateParams(lift=cfg.rollouts.lift, coacd=cfg.objects.coacd if config else CHEAP_COACD)
        loaded = read_grasp_file(grasps, params, mesh_root=mesh_root, mesh=mesh, scale=scale, friction=friction)
        n = len(loaded.T_tcp)
        if index >= n:
            raise ValueError(f"--index: {index} is out of range; {grasps} has grasps 0..{n - 1}")
        if gripper is None:
            if loaded.gripper is None:
                raise ValueError(f"--gripper: needed with {grasps} (a Parquet file names no gripper)")
            gripper = loaded.gripper
        if protocol is None:
            protocol = "acronym" if loaded.kind == "acronym" and not support else "table"
        params = dataclasses.replace(loaded.params, lift=loaded.params.lift.with_protocol(protocol))
        one = slice(index, index + 1)
        world = evaluation_world(loaded.mesh_path, loaded.scale, loaded.T_tcp[one],
                                 None if loaded.widths is None else loaded.widths[one], gripper, params,
                                 free_space=not support, cache_dir=cfg.run.cache_dir)
        reference = None if loaded.reference is None else int(loaded.reference[index])
        movie = evaluated_rollout_movie(world, 0, name=f"{grasps.name} grasp {index}", reference=reference,
                                        n_frames=frames)
    except (*USER_ERRORS, ValueError) as exc:
        fail(console, str(exc))
    save_image(console, output, lambda path: save_movie(movie, path), show=False)
    label = "" if reference is None else f" (file label: {'held' if reference == 1 else 'lost'})"
    console.print(f"outcome {movie.result.code} {movie.result.name}{label}; {len(movie.images)} frames",
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
    from graspgen.grippers import load_gripper
    from graspgen.viz.gripper_picture import gripper_picture

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


app.command("evaluate")(evaluate)


@app.command("report")
def report_cmd(
    out: Annotated[Path, typer.Argument(help="The run folder (or its dataset/ folder) of a published dataset.")],
) -> None:
    """Render the dataset card (card.md, card.json) and its plots again from a published dataset."""
    from stages.dataset import report

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
