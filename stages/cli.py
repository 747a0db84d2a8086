"""The ``gen`` console script: the generic pipeline commands bound to this project's stages, plus ``gen show``."""

# No `from __future__ import annotations`: Typer reads the annotations of closures at run time.

import os

# MuJoCo's renderer needs a headless GL backend on machines without a display; EGL works with Mesa. MuJoCo reads
# the variable once, when it is first imported (stages.objects imports it), so this must come before that.
os.environ.setdefault("MUJOCO_GL", "egl")

from pathlib import Path  # noqa: E402
from typing import Annotated, Any  # noqa: E402

import typer  # noqa: E402
from rich.console import Console  # noqa: E402

from pipeline.cli import ConfigOpt, SetOpt, build_app, fail, load  # noqa: E402
from pipeline.errors import GenError, StageError  # noqa: E402
from pipeline.scheduler import Project, committed, plan, upstream_view  # noqa: E402
from pipeline.stage import topological_order  # noqa: E402
from pipeline.store import Manifest  # noqa: E402
from stages.config import Config  # noqa: E402
from stages.objects import ObjectsStage  # noqa: E402
from stages.grasps import GraspsStage  # noqa: E402
from stages.rollouts import RolloutsStage  # noqa: E402
from stages.scenes import ScenesStage  # noqa: E402

PROJECT = Project(name="gen", schema=Config, stages=(ObjectsStage(), ScenesStage(), GraspsStage(), RolloutsStage()))
"""The stages in their declared order; the scheduler sorts them by dependency."""

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
        except GenError:
            planned = []  # e.g. upstream not run yet: fall back to whatever is on disk
        keys[s.name] = {p.key for p in planned}
        if s.name == stage:
            want = next((p.key for p in planned if p.task.id == task_id), None)
    entries = committed(out, stage, verify_hash=False)
    if want is not None and want in entries:
        return out / stage / str(entries[want].file), True
    older = [e for e in Manifest(out / stage).entries().values() if e.task == task_id and e.key in entries]
    if older:
        return out / stage / str(older[-1].file), False
    known = sorted({e.task for e in entries.values()})
    hint = f"; it has: {', '.join(known[:5])}{' ...' if len(known) > 5 else ''}" if known else ""
    raise StageError(
        f"no {stage} shard for {task_id!r} in {out / stage}{hint}. Run `gen run {stage}` with this config first"
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
    from stages.scenes import contact_sheet, read_scene

    console = Console(stderr=True)
    try:
        cfg = load(PROJECT, config, set_, out=out)
        path, current = find_shard(PROJECT, cfg, "scenes", scene_id)
        scene = read_scene(path)
        sheet = contact_sheet(scene, None if view is None else [view])
    except (GenError, ValueError) as exc:
        fail(console, str(exc))
    if not current:
        console.print(f"note: {scene_id} is from an earlier config (its key differs from the current one)")
    if output is None:
        output = Path(cfg.run.out) / "show" / (f"{scene_id}.png" if view is None else f"{scene_id}_view{view}.png")
    output.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(output)
    print(output)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
