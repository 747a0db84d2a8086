"""The generic command line: ``run``, ``status``, ``config show``, ``clean`` for any :class:`Project`.

A domain package builds its console script with :func:`build_app` and may add commands of its own to the
returned Typer app.
"""

# No `from __future__ import annotations`: Typer reads the annotations of closures at run time.

import datetime
import os
import shlex
import shutil
import sys
import tempfile
import traceback
import warnings
from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer
from rich.console import Console
from rich.control import Control
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table
from rich.text import Text

from pipeline.backends import BACKENDS
from pipeline.config import load_config, to_yaml
from pipeline.errors import ConfigError, GenError
from pipeline.plan import Project
from pipeline.scheduler import StageReport, run_pipeline
from pipeline.status import status
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


def fail(console: Console, message: str, code: int = 2, word: str = "error:") -> NoReturn:
    """Print ``word message`` in one line and exit with ``code``. The message is printed literally: square
    brackets in it (``[min, max]``, a path) are text, not markup; only ``word`` is coloured."""
    console.print(Text.assemble((word, "bold red"), " ", str(message)), highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def os_error_text(exc: OSError) -> str:
    """``path: reason`` of an ``OSError`` (no ``[Errno n]`` prefix), or its text when it names no file."""
    reason = exc.strerror or str(exc)
    return f"{exc.filename}: {reason}" if exc.filename is not None else reason


def check_writable(path: Path, what: str = "output folder", *, file: bool = False) -> None:
    """Raise :class:`ConfigError` unless ``path`` (a folder, or a file with ``file``) can be written, before any
    work: it is not the wrong kind, and its nearest existing folder is one we can create a file in. Writes nothing
    that stays (a probe file is made and removed at once)."""
    path = existing = Path(path)
    try:
        if file and path.is_dir():
            raise ConfigError(f"{path}: is a folder; the {what} must name a file, not a folder")
        start = path.parent if file else path  # an existing output file is overwritten: its folder must be writable
        existing = next(p for p in (start, *start.parents) if p.exists())
        if not existing.is_dir():
            where = "is a file" if existing == path else f"{existing} is a file"
            raise ConfigError(f"{path}: {where}, not a folder; the {what} cannot be made there")
        fd, probe = tempfile.mkstemp(prefix=".write-check-", dir=existing)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        reason = exc.strerror or str(exc)
        where = "" if existing == path or existing == path.parent and file else f" ({existing})"
        raise ConfigError(f"{path}: the {what} is not writable{where}: {reason}") from None


class _LoggedConsole(Console):
    """A console that also writes, as plain text, everything it prints to a run's log file once one is opened."""

    def __init__(self, **kwargs: Any):
        super().__init__(**kwargs)
        self.log_file: Console | None = None
        self.log_path: Path | None = None

    def open_log(self, out: Path, options: dict[str, Any]) -> None:
        """Open ``out/logs/run-<UTC time>.log``; write the command line and its parsed ``options`` to it."""
        now = datetime.datetime.now(datetime.timezone.utc)
        self.log_path = Path(out) / LOGS / f"run-{now:%Y%m%dT%H%M%S.%fZ}.log"
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        stream = self.log_path.open("a", encoding="utf-8")
        self.log_file = Console(file=stream, width=120, color_system=None, force_terminal=False, soft_wrap=True)
        self.log_only(f"command: {shlex.join(sys.argv)}")
        self.log_only("options: " + " ".join(f"{k}={v}" for k, v in options.items() if v not in (None, False, [])))
        self.log_only(f"cwd: {Path.cwd()}")
        self.log_only(f"started: {now:%Y-%m-%dT%H:%M:%SZ}")
        self._showwarning = warnings.showwarning
        warnings.showwarning = self._warning

    def _warning(self, message: Any, category: type, filename: str, lineno: int, *args: Any, **kwargs: Any) -> None:
        """Python warnings of the run's process: shown as usual, and logged."""
        self._showwarning(message, category, filename, lineno, *args, **kwargs)
        self.log_only(f"warning: {category.__name__}: {message} ({filename}:{lineno})")

    def bug(self, exc: BaseException) -> str:
        """Log the traceback of an unexpected error; return the one line to show."""
        self.log_only("".join(traceback.format_exception(exc)).rstrip())
        return f"unexpected {type(exc).__name__}: {exc} (a bug; the traceback is in {self.log_path})"

    def log_only(self, line: str) -> None:
        """Write ``line`` (literally) to the log file alone."""
        if self.log_file is not None:
            self.log_file.print(line, markup=False, highlight=False)
            self.log_file.file.flush()

    def print(self, *objects: Any, **kwargs: Any) -> None:
        super().print(*objects, **kwargs)
        if self.log_file is not None and not (objects and all(isinstance(o, Control) for o in objects)):
            self.log_file.print(*objects, **kwargs)
            self.log_file.file.flush()

    def close_log(self) -> None:
        if self.log_file is not None:
            warnings.showwarning = self._showwarning
            self.log_only(f"finished: {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%dT%H:%M:%SZ}")
            self.log_file.file.close()
            self.log_file = None


LOGS = "logs"
"""``OUT/logs/``: one log file per ``run`` (what the terminal showed, warnings, errors). Never part of a shard."""


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
        elif event == "stage_end":
            r: StageReport = info["report"]
            line = f"{stage}: {r.total} tasks, ran {r.ran}, skipped {r.skipped}, failed {r.failed} ({r.seconds:.1f} s)"
            if not self.console.is_terminal:
                self.console.print(line, highlight=False, markup=False)
            elif isinstance(self.console, _LoggedConsole):
                self.console.log_only(line)  # the terminal shows the bars; the log gets the line


def print_warnings(console: Console, reports: list[StageReport]) -> int:
    """Print the run's warnings (``N warning(s):`` then ``  stage: text`` per line, literally); returns N."""
    lines = [f"{r.stage}: {w}" for r in reports for w in r.warnings]
    if lines:
        console.print(f"{len(lines)} warning(s):", style="bold yellow", markup=False, highlight=False)
        for line in lines:
            console.print(f"  {line}", markup=False, highlight=False, soft_wrap=True)
    return len(lines)


def print_repaired(console: Console, reports: list[StageReport]) -> int:
    """Print what the stages' publish steps repaired in output published earlier; returns how many lines."""
    lines = [f"{r.stage}: {line}" for r in reports for line in r.repaired]
    if lines:
        console.print(f"repaired published output ({len(lines)}):", markup=False, highlight=False)
        for line in lines:
            console.print(f"  {line}", markup=False, highlight=False, soft_wrap=True)
    return len(lines)


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
    app = typer.Typer(help=f"{project.name}: run the pipeline, see where it stands.", no_args_is_help=True)
    config_app = typer.Typer(help="Inspect the configuration.", no_args_is_help=True)
    app.add_typer(config_app, name="config")
    _add_run(app, project)
    _add_status(app, project)
    _add_config_show(config_app, project)
    _add_clean(app, project)
    return app


def _add_run(app: typer.Typer, project: Project) -> None:
    stage_names = ", ".join(s.name for s in project.stages)

    @app.command()
    def run(
        ctx: typer.Context,
        stage: Annotated[str | None, typer.Argument(help=f"Stage to run with what it needs: {stage_names}.")] = None,
        config: ConfigOpt = None,
        out: OutOpt = None,
        jobs: Annotated[int | None, typer.Option("--jobs", "-j", help="Workers (default: all cores).")] = None,
        backend: Annotated[str | None, typer.Option(help=f"joblib backend: {', '.join(BACKENDS)}.")] = None,
        set_: SetOpt = None,
        retry_failed: Annotated[bool, typer.Option("--retry-failed", help="Run failed tasks again.")] = False,
    ) -> None:
        """Run STAGE (and the stages it needs), or every stage. Finished work is skipped.

        Each run writes what it shows, its warnings and errors to OUT/logs/run-<UTC time>.log."""
        console = _LoggedConsole(stderr=True)
        reports = _run_stages(project, console, ctx, stage, config, set_, retry_failed,
                              out=out, jobs=jobs, backend=backend)
        _report_run(console, reports)


def _run_stages(project: Project, console: _LoggedConsole, ctx: typer.Context, stage: str | None,
                config: Path | None, sets: list[str] | None, retry_failed: bool, **run_options: Any
                ) -> list[StageReport]:
    """``gen run``'s work: load the config, open the run's log, run the stages with a progress display. Errors are
    one line (the traceback of a bug goes to the log) and exit: 2 for a user error, 130 on Ctrl-C, else 1."""
    try:
        cfg = load(project, config, sets, **run_options)
        check_writable(Path(cfg.run.out))  # before any work: a file, a read-only folder
        console.open_log(Path(cfg.run.out), ctx.params)
        ctx.call_on_close(console.close_log)
        display = _ProgressDisplay(console)
        with display.progress, warnings.catch_warnings():
            warnings.filterwarnings("ignore", ".*by the workers have been cancelled", UserWarning)  # Ctrl-C
            return run_pipeline(project, cfg, [stage] if stage else None, retry_failed=retry_failed, progress=display)
    except (GenError, *project.user_errors) as exc:
        fail(console, str(exc))
    except KeyboardInterrupt:
        fail(console, "finished tasks are kept; run the same command again to resume", 130, "interrupted:")
    except OSError as exc:
        fail(console, os_error_text(exc), code=1)
    except Exception as exc:
        if console.log_path is None:
            raise
        fail(console, console.bug(exc), code=1)  # one line here, the traceback in the log


def _report_run(console: Console, reports: list[StageReport]) -> None:
    """The end of ``gen run``: the summary table, repairs, failed tasks (exit 1 when any), warnings."""
    console.print(summary_table(reports))
    repaired = print_repaired(console, reports)
    failures = [(r.stage, t, e) for r in reports for t, e in r.failures]
    if failures:
        console.print(f"[bold red]{len(failures)} task(s) failed:[/]")
        for stage_name, task, error in failures:
            console.print(f"  {stage_name}/{task}: {error.splitlines()[0]}", highlight=False, soft_wrap=True,
                          markup=False)
    print_warnings(console, reports)
    if failures:
        console.print("Fix the inputs and run again, or use --retry-failed to retry them as they are.")
        raise typer.Exit(1)
    if all(r.ran == 0 for r in reports):
        done = f"all {sum(r.skipped for r in reports)} task(s) already done (skipped)"
        console.print(f"No task to run: {done}; only published files were repaired." if repaired
                      else f"Nothing to do: {done}.", soft_wrap=True, markup=False)


def _add_status(app: typer.Typer, project: Project) -> None:
    @app.command("status")
    def status_cmd(
        stage: Annotated[str | None, typer.Argument(help="Limit to this stage and what it needs.")] = None,
        config: ConfigOpt = None,
        out: OutOpt = None,
        set_: SetOpt = None,
    ) -> None:
        """Say for each stage whether it is done, missing, stale (and why), failed, waiting or damaged (its
        published files), with the reasons: what `run` with the same config would do."""
        console = Console()
        try:
            cfg = load(project, config, set_, out=out)
            rows = status(project, cfg, [stage] if stage else None)
        except (GenError, *project.user_errors) as exc:
            fail(console, str(exc))
        table = Table(title=f"status of {cfg.run.out}", title_justify="left")
        for col in ("stage", "state", "done", "missing", "failed", "why"):
            table.add_column(col)
        for s in rows:
            total = f"{s.done}/{s.total}" if s.state != "waiting" else "-"
            table.add_row(s.stage, s.state, total, str(s.missing), str(s.failed), Text("; ".join(s.reasons)))
        console.print(table)


def _add_config_show(config_app: typer.Typer, project: Project) -> None:
    @config_app.command("show")
    def config_show(
        config: ConfigOpt = None,
        out: OutOpt = None,
        set_: SetOpt = None,
        comments: Annotated[bool, typer.Option(help="Print each key's description.")] = True,
        every: Annotated[bool, typer.Option("--all", help="Every key, not only those that differ from the defaults.")]
        = False,
    ) -> None:
        """Print the resolved config (file + overrides + defaults, or the one OUT remembers) as YAML: the keys that
        differ from the defaults, or with --all every key."""
        try:
            cfg = load(project, config, set_, out=out)
        except (GenError, *project.user_errors) as exc:
            fail(Console(stderr=True), str(exc))
        if every:
            sys.stdout.write(to_yaml(cfg, comments=comments))
            return
        sys.stdout.write("# The keys that differ from the defaults; every key: gen config show --all\n")
        sys.stdout.write(to_yaml(cfg, comments=comments, defaults=load_config(project.schema)))


def _add_clean(app: typer.Typer, project: Project) -> None:
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
        except (GenError, *project.user_errors) as exc:
            fail(console, str(exc))
        _clean(project, console, Path(cfg.run.out), names, everything=not stage)


def _clean(project: Project, console: Console, root: Path, names: list[str], *, everything: bool) -> None:
    """Remove the shards and published files of the stages ``names`` under ``root``, under the run lock; with
    ``everything`` also the remembered config and the logs, and ``root`` itself when nothing else is left in it."""
    if not root.exists():
        return
    try:
        lock = RunLock(root).__enter__()
    except (GenError, *project.user_errors) as exc:
        fail(console, str(exc))
    paths = []
    for name in names:
        paths += [stage_dir(root, name), *(root / rel for rel in project.stage(name).published)]
    if everything:  # the remembered config and the run logs go too
        paths += [root / SHARDS, root / LOGS]
    for path in paths:
        if path.is_dir():
            shutil.rmtree(path)
            console.print(f"removed {path}", markup=False, highlight=False)
        elif path.exists():
            path.unlink()
            console.print(f"removed {path}", markup=False, highlight=False)
    lock.__exit__()
    if everything and not any(p for p in root.iterdir() if p.name != ".lock"):
        shutil.rmtree(root)
