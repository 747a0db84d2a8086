"""The generic command line: ``run``, ``status``, ``config show``, ``clean`` for any :class:`Project`.

A domain package builds its console script with :func:`build_app` and may add commands of its own to the
returned Typer app.
"""

# No `from __future__ import annotations`: Typer reads the annotations of closures at run time.

import shutil
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

from pipeline.config import load_config, to_yaml
from pipeline.errors import GenError
from pipeline.scheduler import BACKENDS, Project, StageReport, run_pipeline, status
from pipeline.store import SHARDS, RunLock, run_config_path, stage_dir

ConfigOpt = Annotated[Path | None, typer.Option("--config", "-c", help="YAML config file (defaults when omitted).")]
OutOpt = Annotated[Path | None, typer.Option("--out", "-o", help="Output folder (overrides run.out).")]
SetOpt = Annotated[
    list[str] | None, typer.Option("--set", "-s", help="Override a config key: key.path=value (YAML). Repeatable.")
]


def load(project: Project, config: Path | None, sets: list[str] | None, **run_overrides: Any) -> Any:
    """Load the config with ``--set`` overrides, then the CLI's own run options (which win).

    Without ``--config``, the config the output folder remembers from its latest run (``OUT/shards/config.yaml``)
    is used when there is one, so ``gen status`` after ``make dataset`` compares against what made the folder;
    otherwise the defaults.
    """
    overrides = list(sets or [])
    if config is None:
        out = run_overrides.get("out") or load_config(project.schema, None, overrides).run.out
        remembered = run_config_path(out)
        if remembered.is_file():
            config = remembered
            run_overrides = {**run_overrides, "out": out}
    for key, value in run_overrides.items():
        if value is not None:
            overrides.append(f"run.{key}={value}")
    return load_config(project.schema, config, overrides)


def fail(console: Console, message: str, code: int = 2) -> None:
    console.print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


class _ProgressDisplay:
    """Turns scheduler events into a rich progress bar per stage (plain lines when not on a terminal)."""

    def __init__(self, console: Console):
        self.console = console
        self.progress = Progress(
            TextColumn("[bold]{task.description:<11}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[note]}"),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            console=console,
            disable=not console.is_terminal,
        )
        self.bars: dict[str, Any] = {}
        self.failed: dict[str, int] = {}

    def __call__(self, event: str, **info: Any) -> None:
        stage = info["stage"]
        if event == "stage_start":
            done = info["skipped"] + info["remembered"]
            self.failed[stage] = info["remembered"]
            self.bars[stage] = self.progress.add_task(
                stage, total=info["total"], completed=done, note=f"skipped {info['skipped']}"
            )
        elif event == "task_done":
            if not info["ok"]:
                self.failed[stage] += 1
            self.progress.update(self.bars[stage], advance=1, note=f"failed {self.failed[stage]}")
        elif event == "stage_end" and not self.console.is_terminal:
            r: StageReport = info["report"]
            self.console.print(
                f"{stage}: {r.total} tasks, ran {r.ran}, skipped {r.skipped}, failed {r.failed} ({r.seconds:.1f} s)",
                highlight=False,
            )


def summary_table(reports: list[StageReport]) -> Table:
    table = Table(title="run summary", title_justify="left")
    for col in ("stage", "tasks", "ran", "skipped", "failed", "seconds"):
        table.add_column(col, justify="left" if col == "stage" else "right")
    for r in reports:
        table.add_row(r.stage, str(r.total), str(r.ran), str(r.skipped), str(r.failed), f"{r.seconds:.1f}")
    shared = [[r.stage for r in reports if r.wave == w] for w in sorted({r.wave for r in reports})]
    shared = [group for group in shared if len(group) > 1]
    if shared:
        table.caption = "ran side by side (seconds overlap): " + "; ".join(" + ".join(g) for g in shared)
        table.caption_justify = "left"
    return table


def build_app(project: Project) -> typer.Typer:
    """A Typer app with the generic commands for ``project``."""
    user_errors = (GenError, *project.user_errors)
    app = typer.Typer(help=f"{project.name}: run the pipeline, see where it stands.", no_args_is_help=True)
    config_app = typer.Typer(help="Inspect the configuration.", no_args_is_help=True)
    app.add_typer(config_app, name="config")
    stage_names = ", ".join(s.name for s in project.stages)

    @app.command()
    def run(
        stage: Annotated[str | None, typer.Argument(help=f"Stage to run with what it needs: {stage_names}.")] = None,
        config: ConfigOpt = None,
        out: OutOpt = None,
        jobs: Annotated[int | None, typer.Option("--jobs", "-j", help="Workers (default: all cores).")] = None,
        backend: Annotated[str | None, typer.Option(help=f"joblib backend: {', '.join(BACKENDS)}.")] = None,
        set_: SetOpt = None,
        retry_failed: Annotated[bool, typer.Option("--retry-failed", help="Run failed tasks again.")] = False,
    ) -> None:
        """Run STAGE (and the stages it needs), or every stage. Finished work is skipped."""
        console = Console(stderr=True)
        try:
            cfg = load(project, config, set_, out=out, jobs=jobs, backend=backend)
            display = _ProgressDisplay(console)
            with display.progress:
                reports = run_pipeline(
                    project, cfg, [stage] if stage else None, retry_failed=retry_failed, progress=display
                )
        except user_errors as exc:
            fail(console, str(exc))
        console.print(summary_table(reports))
        failures = [(r.stage, t, e) for r in reports for t, e in r.failures]
        if failures:
            console.print(f"[bold red]{len(failures)} task(s) failed:[/]")
            for stage_name, task, error in failures:
                console.print(f"  {stage_name}/{task}: {error.splitlines()[0]}", highlight=False, soft_wrap=True)
            console.print("Fix the inputs and run again, or use --retry-failed to retry them as they are.")
            raise typer.Exit(1)
        if all(r.ran == 0 for r in reports):
            console.print(f"Nothing to do: all {sum(r.skipped for r in reports)} task(s) already done (skipped).")

    @app.command("status")
    def status_cmd(
        stage: Annotated[str | None, typer.Argument(help="Limit to this stage and what it needs.")] = None,
        config: ConfigOpt = None,
        out: OutOpt = None,
        set_: SetOpt = None,
    ) -> None:
        """Say for each stage whether it is done, missing, stale (and why), failed or waiting."""
        console = Console()
        try:
            cfg = load(project, config, set_, out=out)
            rows = status(project, cfg, [stage] if stage else None)
        except user_errors as exc:
            fail(console, str(exc))
        table = Table(title=f"status of {cfg.run.out}", title_justify="left")
        for col in ("stage", "state", "done", "missing", "failed", "why"):
            table.add_column(col)
        for s in rows:
            total = f"{s.done}/{s.total}" if s.state != "waiting" else "-"
            table.add_row(s.stage, s.state, total, str(s.missing), str(s.failed), "; ".join(s.reasons))
        console.print(table)

    @config_app.command("show")
    def config_show(
        config: ConfigOpt = None,
        out: OutOpt = None,
        set_: SetOpt = None,
        comments: Annotated[bool, typer.Option(help="Print each key's description.")] = True,
    ) -> None:
        """Print the resolved config (file + overrides + defaults, or the one OUT remembers) as YAML."""
        try:
            cfg = load(project, config, set_, out=out)
        except user_errors as exc:
            fail(Console(stderr=True), str(exc))
        sys.stdout.write(to_yaml(cfg, comments=comments))

    @app.command()
    def clean(
        stage: Annotated[str | None, typer.Argument(help="Only this stage's outputs.")] = None,
        config: ConfigOpt = None,
        out: OutOpt = None,
        set_: SetOpt = None,
    ) -> None:
        """Delete the outputs of STAGE (or all outputs). Caches (run.cache_dir) are kept."""
        console = Console(stderr=True)
        try:
            cfg = load(project, config, set_, out=out)
            names = [project.stage(stage).name] if stage else [s.name for s in project.stages]
        except user_errors as exc:
            fail(console, str(exc))
        root = Path(cfg.run.out)
        if not root.exists():
            return
        try:
            lock = RunLock(root).__enter__()
        except user_errors as exc:
            fail(console, str(exc))
        for name in names:
            published = [root / rel for rel in project.stage(name).published]
            for path in [stage_dir(root, name), *published]:
                if path.is_dir():
                    shutil.rmtree(path)
                    console.print(f"removed {path}")
                elif path.exists():
                    path.unlink()
                    console.print(f"removed {path}")
        if (root / SHARDS).is_dir() and not any((root / SHARDS).iterdir()):
            (root / SHARDS).rmdir()
        lock.__exit__()
        if not stage and not any(p for p in root.iterdir() if p.name != ".lock"):
            shutil.rmtree(root)

    return app
