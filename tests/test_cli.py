"""The generic CLI on the toy pipeline: run, status, config show, clean, and their error messages."""

from __future__ import annotations

import pytest
import yaml
from toy_stages import TOY
from typer.testing import CliRunner

from pipeline.cli import build_app

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
    assert "numbers.sizee: unknown key; valid keys: disk_full_while, ids, input_file, size, sleep" in result.output
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
