"""The generic CLI on the toy pipeline: run, status, config show, clean, and their error messages."""

from __future__ import annotations

import pytest
import yaml
from typer.testing import CliRunner

from pipeline.cli import build_app
from pipeline.errors import ConfigError
from tests.paths import REPO
from tests.toy_stages import TOY, WARN_TOY

app = build_app(TOY)
runner = CliRunner()


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(autouse=True)
def _away_from_the_repository(tmp_path, monkeypatch):
    """Commands without --out look at ./out (and the config it remembers): not the repository's own."""
    monkeypatch.chdir(tmp_path)


def test_run_then_run_again_says_nothing_to_do(tmp_path):
    first = invoke("run", "--out", tmp_path / "o", "--jobs", 1)
    assert first.exit_code == 0, first.output
    assert "numbers: 4 tasks, ran 4, skipped 0, failed 0" in first.output
    second = invoke("run", "--out", tmp_path / "o", "--jobs", 1)
    assert second.exit_code == 0
    assert "Nothing to do: all 5 task(s) already done (skipped)." in second.output


def test_run_one_stage(tmp_path):
    result = invoke("run", "numbers", "--out", tmp_path / "o", "--jobs", 1)
    assert result.exit_code == 0 and "sums" not in result.output


def test_failures_exit_nonzero_with_a_summary(tmp_path):
    result = invoke("run", "--out", tmp_path / "o", "--jobs", 1, "--set", "numbers.ids=[a, bad_mesh]")
    assert result.exit_code == 1
    assert "1 task(s) failed" in result.output
    assert "numbers/bad_mesh: InputError: bad_mesh: this input is broken on purpose" in result.output


def test_config_errors_exit_2_naming_the_key(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("numbers:\n  sizee: 3\n")
    result = invoke("run", "--config", cfg, "--out", tmp_path / "o")
    assert result.exit_code == 2
    valid = "count, disk_full_while, ids, input_file, size, sleep, work_ms"
    assert f"numbers.sizee: unknown key; valid keys: {valid}" in result.output
    assert not (tmp_path / "o").exists()  # reported before any work
    result = invoke("run", "nope", "--out", tmp_path / "o")
    assert result.exit_code == 2 and "unknown stage 'nope'" in result.output
    result = invoke("run", "--backend", "spark", "--out", tmp_path / "o")
    assert result.exit_code == 2 and "run.backend: must be one of 'loky', 'dask', 'ray'" in result.output


def test_status_and_clean(tmp_path):
    out = tmp_path / "o"
    invoke("run", "numbers", "--out", out, "--jobs", 1)
    result = invoke("status", "--out", out)
    assert result.exit_code == 0
    lines = {line.split()[1]: line for line in result.output.splitlines() if line.startswith("│")}
    assert "done" in lines["numbers"] and "4/4" in lines["numbers"]
    assert "missing" in lines["sums"]
    assert (out / "shards" / "numbers").is_dir()
    assert invoke("clean", "numbers", "--out", out).exit_code == 0
    assert not (out / "shards" / "numbers").exists()


def test_config_show_prints_loadable_yaml_with_docs():
    result = invoke("config", "show", "--set", "numbers.size=9")
    assert result.exit_code == 0
    assert "# Draws per task." in result.output
    assert yaml.safe_load(result.output)["numbers"]["size"] == 9


def test_config_show_prints_what_differs_and_with_all_every_key():
    differs = yaml.safe_load(invoke("config", "show", "--set", "numbers.size=9").output)
    every = yaml.safe_load(invoke("config", "show", "--all", "--set", "numbers.size=9").output)
    assert differs == {"numbers": {"size": 9}}
    assert every["numbers"]["size"] == 9 and "run" in every and len(every["numbers"]) > 1


def test_summary_says_which_stages_ran_side_by_side():
    from rich.console import Console

    from pipeline.cli import summary_table
    from pipeline.scheduler import StageReport

    def text(reports):
        console = Console(width=120, record=True)
        console.print(summary_table(reports))
        return console.export_text()

    reports = [StageReport("a", wave=0), StageReport("b", wave=1), StageReport("c", wave=1), StageReport("d", wave=2)]
    assert "ran side by side (seconds overlap): b + c" in text(reports)
    assert "side by side" not in text([StageReport("a", wave=0), StageReport("b", wave=1)])


def test_commands_without_config_use_the_config_that_made_the_folder(tmp_path):
    out = tmp_path / "o"
    assert invoke("run", "--out", out, "--jobs", 1, "--set", "numbers.size=7").exit_code == 0
    remembered = yaml.safe_load((out / "shards" / "config.yaml").read_text())
    assert remembered["numbers"]["size"] == 7
    lines = {line.split()[1]: line for line in invoke("status", "--out", out).output.splitlines()
             if line.startswith("│")}
    assert "done" in lines["numbers"] and "done" in lines["sums"]  # not stale against the defaults (size 5)
    shown = yaml.safe_load(invoke("config", "show", "--out", out).output)
    assert shown["numbers"]["size"] == 7
    again = invoke("run", "--out", out, "--jobs", 1)
    assert again.exit_code == 0 and "Nothing to do" in again.output


# --------------------------------------------------------------------------------------------------------------
# Every bad input and fault: one plain line, exit 2 (usage) or 1 (failure), checked before any work.

TOY_MAIN = "from tests.toy_stages import TOY; from pipeline.cli import build_app; build_app(TOY)()"


def error_line(result, code=2):
    """The one line a failed command printed: asserts the exit code, no traceback, one line ``error: ...``.

    The messages are printed with ``soft_wrap`` (never wrapped by rich), so one message is one line."""
    assert result.exit_code == code, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    return lines[0]


def toy_command(*args):
    """The toy CLI as its own process (for signals and mounts), importing this checkout."""
    import os
    import sys

    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return [sys.executable, "-c", TOY_MAIN, *map(str, args)], env


def test_out_naming_a_file_is_one_line_before_any_work(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("mine\n")
    line = error_line(invoke("run", "--out", afile, "--jobs", 1))
    assert line == f"error: {afile}: is a file, not a folder; the output folder cannot be made there"
    assert afile.read_text() == "mine\n"
    line = error_line(invoke("run", "--out", afile / "o", "--jobs", 1))
    assert line == f"error: {afile / 'o'}: {afile} is a file, not a folder; the output folder cannot be made there"


def _read_only(monkeypatch, root):
    """Make every write under ``root`` fail as on a read-only file system (root ignores chmod 0555)."""
    import errno
    import os

    real_open, real_mkdir = os.open, os.mkdir
    writes = os.O_WRONLY | os.O_RDWR | os.O_CREAT

    def refuse(path):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))

    def fake_open(path, flags, *args, **kwargs):
        if str(path).startswith(str(root)) and flags & writes:
            refuse(path)
        return real_open(path, flags, *args, **kwargs)

    def fake_mkdir(path, *args, **kwargs):
        if str(path).startswith(str(root)):
            refuse(path)
        return real_mkdir(path, *args, **kwargs)

    monkeypatch.setattr(os, "open", fake_open)
    monkeypatch.setattr(os, "mkdir", fake_mkdir)


def test_read_only_output_folder_is_one_line_before_any_work(tmp_path, monkeypatch):
    ro = tmp_path / "ro"
    ro.mkdir()
    _read_only(monkeypatch, ro)
    line = error_line(invoke("run", "--out", ro, "--jobs", 1))
    assert line == f"error: {ro}: the output folder is not writable: Read-only file system"
    line = error_line(invoke("run", "--out", ro / "o", "--jobs", 1))
    assert line == f"error: {ro / 'o'}: the output folder is not writable ({ro}): Read-only file system"
    monkeypatch.undo()
    assert list(ro.iterdir()) == []


def test_read_only_mount_is_one_line(tmp_path):
    """The same on a real read-only file system: a tmpfs mounted read-only in a private mount namespace (the
    mount dies with the process). Skipped where this machine does not allow it."""
    import shlex
    import shutil
    import subprocess

    ro = tmp_path / "ro"
    ro.mkdir()
    mount = f"mount -t tmpfs -o ro tmpfs {shlex.quote(str(ro))}"
    if shutil.which("unshare") is None or subprocess.run(["unshare", "-m", "sh", "-c", mount],
                                                         capture_output=True).returncode != 0:
        pytest.skip("no private read-only mount here (needs unshare -m and mount)")
    command, env = toy_command("run", "--out", ro / "o", "--jobs", 1)
    done = subprocess.run(["unshare", "-m", "sh", "-c", f"{mount} && exec {shlex.join(command)}"],
                          capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr and done.stdout == ""
    assert done.stderr.strip() == f"error: {ro / 'o'}: the output folder is not writable ({ro}): Read-only file system"


def test_error_text_is_printed_literally(tmp_path):
    """Square brackets in messages are text, not rich markup: ``[1, 2]``, ``[bold]`` in a task id or a path."""
    line = error_line(invoke("run", "--out", tmp_path / "o", "--set", "numbers.size=[1, 2]"))
    assert line == "error: defaults: numbers.size: must be int, got [1, 2]"
    line = error_line(invoke("run", "--out", tmp_path / "o", "--set", "numbers.[bold]size=1"))
    assert line.startswith("error: defaults: numbers.[bold]size: unknown key; valid keys: ")
    result = invoke("run", "--out", tmp_path / "o", "--jobs", 1, "--set", 'numbers.ids=[a, "bad[bold]x"]')
    assert result.exit_code == 1
    assert "  numbers/bad[bold]x: InputError: bad[bold]x: this input is broken on purpose" in result.output
    (tmp_path / "f").write_text("")
    line = error_line(invoke("run", "--out", tmp_path / "f" / "[bold]o[/]"))
    assert f"{tmp_path / 'f' / '[bold]o[/]'}: {tmp_path / 'f'} is a file" in line


def _as_from_a_terminal() -> None:
    """In the child before exec: Ctrl-C handled as a terminal starts a command, however the suite was launched.
    A child inherits an ignored SIGINT (and a blocked one), and Python installs its KeyboardInterrupt handler only
    when SIGINT is not ignored at start-up; a suite run as a background job of a non-interactive shell (``cmd &``,
    ``nohup``) starts with SIGINT ignored, and the run under test would then never see the Ctrl-C."""
    import signal

    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_says_the_run_can_be_resumed(tmp_path):
    """SIGINT to the whole process group, as Ctrl-C in a terminal sends it (the loky workers get it too)."""
    import os
    import signal
    import subprocess
    import time

    out = tmp_path / "o"
    command, env = toy_command("run", "--out", out, "--jobs", 2, "--set", "numbers.sleep=1",
                               "--set", "numbers.ids=[a, b, c, d, e, f, g, h]")
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            start_new_session=True, preexec_fn=_as_from_a_terminal)
    manifest = out / "shards" / "numbers" / "manifest.jsonl"
    deadline = time.monotonic() + 60
    while not (manifest.is_file() and manifest.read_text().strip()) and time.monotonic() < deadline:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert stdout == ""
    # The command's own output is this one line. The loky workers and their resource tracker share the process
    # group and may still print their own KeyboardInterrupt (from multiprocessing), but the command itself shows
    # no traceback, no "Aborted!" and no joblib warning.
    lines = stderr.splitlines()
    assert lines.count("interrupted: finished tasks are kept; run the same command again to resume") == 1, stderr
    assert "pipeline/cli.py" not in stderr and "Aborted" not in stderr and "have been cancelled" not in stderr
    kept = len(manifest.read_text().splitlines())
    assert 1 <= kept < 8
    again = invoke("run", "--out", out, "--jobs", 2, "--set", "numbers.ids=[a, b, c, d, e, f, g, h]")
    assert again.exit_code == 0, again.output
    assert f"numbers: 8 tasks, ran {8 - kept}, skipped {kept}, failed 0" in again.output


def test_run_writes_a_log_file(tmp_path, monkeypatch):
    """OUT/logs/run-<UTC time>.log: the command, the per-stage lines, failures, warnings and errors."""
    import warnings

    import pipeline.cli
    from pipeline.store import RunLock

    real = pipeline.cli.run_pipeline

    def warn_then_run(*args, **kwargs):
        warnings.warn("a warning of the run", UserWarning, stacklevel=1)
        return real(*args, **kwargs)

    monkeypatch.setattr(pipeline.cli, "run_pipeline", warn_then_run)
    out = tmp_path / "o"
    with pytest.warns(UserWarning, match="a warning of the run"):
        result = invoke("run", "--out", out, "--jobs", 1, "--set", "numbers.ids=[a, bad]")
    assert result.exit_code == 1
    (log,) = (out / "logs").glob("run-*.log")
    text = log.read_text()
    assert f"out={out}" in text and "jobs=1" in text and "numbers.ids=[a, bad]" in text
    assert "warning: UserWarning: a warning of the run" in text
    assert "numbers: 2 tasks, ran 1, skipped 0, failed 1" in text
    assert "numbers/bad: InputError: bad: this input is broken on purpose" in text
    assert text.rstrip().splitlines()[-1].startswith("finished: ")
    assert not any((out / "published").rglob("*.log"))  # the published outputs hold no log
    monkeypatch.setattr(pipeline.cli, "run_pipeline", real)
    with RunLock(out):  # another run writes the folder: the error is in this run's log too
        line = error_line(invoke("run", "--out", out, "--jobs", 1))
    assert "another run is writing this output folder" in line
    logs = sorted((out / "logs").glob("run-*.log"))
    assert len(logs) == 2 and line in logs[1].read_text()


def test_an_unexpected_error_is_one_line_with_the_traceback_in_the_log(tmp_path, monkeypatch):
    import pipeline.cli

    def broken(*args, **kwargs):
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr(pipeline.cli, "run_pipeline", broken)
    out = tmp_path / "o"
    line = error_line(invoke("run", "--out", out), code=1)
    (log,) = (out / "logs").glob("run-*.log")
    assert line == f"error: unexpected ZeroDivisionError: division by zero (a bug; the traceback is in {log})"
    assert "Traceback (most recent call last)" in log.read_text()


# --------------------------------------------------------------------------------------------------------------
# Warnings at the end of a run; the status table names damaged published files; the run repairs them.


def test_warnings_are_printed_at_the_end_of_every_run_literally(tmp_path):
    warn_app = build_app(WARN_TOY)
    args = ["run", "--out", str(tmp_path / "o"), "--jobs", "1", "--set", "numbers.ids=[a, w1, x9]"]
    for _ in range(2):  # the second run skips everything and still warns
        result = runner.invoke(warn_app, args)
        assert result.exit_code == 0, result.output
        tail = result.output[result.output.index("3 warning(s):"):].splitlines()
        assert tail[1:4] == [
            "  numbers: left out x9 [ids starting with x]",  # square brackets are text, not markup
            "  numbers: draws look odd (2 tasks: a, w1)",
            "  numbers: w1: w1 is special",
        ]
    assert "Nothing to do: all 3 task(s) already done (skipped)." in result.output
    quiet = invoke("run", "--out", tmp_path / "q", "--jobs", 1)
    assert quiet.exit_code == 0 and "warning" not in quiet.output


def test_status_names_a_damaged_published_file_and_run_replaces_it(tmp_path):
    warn_app = build_app(WARN_TOY)
    out = tmp_path / "o"
    assert runner.invoke(warn_app, ["run", "--out", str(out), "--jobs", "1"]).exit_code == 0
    (out / "published" / "total.txt").write_text("garbage\n")
    result = runner.invoke(warn_app, ["status", "--out", str(out)])
    assert result.exit_code == 0
    text = " ".join(result.output.replace("│", " ").split())  # undo the table's wrapping
    assert "sums damaged 1/1 0 0 published: total.txt damaged (will be replaced)" in text
    result = runner.invoke(warn_app, ["run", "--out", str(out), "--jobs", "1"])
    assert result.exit_code == 0, result.output
    assert "repaired published output (1):\n  sums: replaced total.txt (damaged)\n" in result.output
    assert "No task to run: all 5 task(s) already done (skipped); only published files were repaired." in result.output
    lines = [line for line in runner.invoke(warn_app, ["status", "--out", str(out)]).output.splitlines()
             if line.startswith("│")]
    assert all(" done " in line for line in lines[:2]) and "published" not in "".join(lines)


def test_clean_without_a_stage_removes_the_whole_output_folder(tmp_path):
    out = tmp_path / "o"
    assert invoke("run", "--out", out, "--jobs", 1).exit_code == 0
    assert (out / "shards" / "config.yaml").is_file() and (out / "published" / "total.txt").is_file()
    assert invoke("clean", "--out", out).exit_code == 0
    assert not out.exists()


def test_an_existing_output_file_may_be_overwritten(tmp_path):
    from pipeline.cli import check_writable

    existing = tmp_path / "labels.parquet"
    existing.write_text("old")
    check_writable(existing, "output file", file=True)  # no error: it is replaced
    assert existing.read_text() == "old"  # and nothing written yet
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    with pytest.raises(ConfigError, match="a_file is a file, not a folder"):
        check_writable(blocker / "labels.parquet", "output file", file=True)
