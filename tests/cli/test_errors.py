"""The ``gen`` commands on bad input and faults: one plain line ``error: ...`` (printed literally, square brackets
and all), exit 2 (usage) or 1 (failure), no traceback, checked before any work where it can be."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from graspgen_cli.app import app
from tests.paths import REPO

BOX = REPO / "assets" / "objects" / "box.obj"


def gen(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def error_line(result, code=2):
    """The one line a failed command printed: asserts the exit code, no traceback, one line ``error: ...``.

    Errors are printed with ``soft_wrap`` (rich never wraps them), so one message is one line."""
    assert result.exit_code == code, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    return lines[0]


@pytest.fixture(autouse=True)
def _away_from_the_repository(tmp_path, monkeypatch):
    """Commands without --out look at ./out (and the config it remembers): not the repository's own."""
    monkeypatch.chdir(tmp_path)


@pytest.fixture
def poses(tmp_path):
    """A Parquet file of two TCP poses on the bundled box (valid input for gen evaluate --mesh BOX)."""
    path = tmp_path / "poses.parquet"
    T = np.tile(np.diag([1.0, -1.0, -1.0, 1.0]), (2, 1, 1))
    T[:, 2, 3] = [0.11, 0.14]
    pq.write_table(pa.table({"pose": [t.reshape(-1).tolist() for t in T]}), path)
    return path


@pytest.fixture
def no_simulation(monkeypatch):
    """Fail the test if gen evaluate gets as far as simulating."""
    import graspgen.workflows.evaluate

    def simulate(*args, **kwargs):
        raise AssertionError("simulated before the output was checked")

    monkeypatch.setattr(graspgen.workflows.evaluate, "evaluate_grasps", simulate)


def evaluate(poses, output):
    return gen("evaluate", "--grasps", poses, "--mesh", BOX, "--gripper", "panda", "-o", output)


def test_evaluate_output_naming_a_folder_is_checked_before_simulating(poses, tmp_path, no_simulation):
    folder = tmp_path / "labels"
    folder.mkdir()
    line = error_line(evaluate(poses, folder))
    assert line == f"error: {folder}: is a folder; the output file (-o) must name a file, not a folder"
    assert list(folder.iterdir()) == []


def test_evaluate_output_under_a_file_is_checked_before_simulating(poses, tmp_path, no_simulation):
    afile = tmp_path / "afile"
    afile.write_text("")
    line = error_line(evaluate(poses, afile / "labels.parquet"))
    assert line == (f"error: {afile / 'labels.parquet'}: {afile} is a file, not a folder; "
                    "the output file (-o) cannot be made there")


def test_evaluate_output_in_a_read_only_folder_is_checked_before_simulating(poses, tmp_path, monkeypatch,
                                                                            no_simulation):
    """As on a read-only file system (root ignores chmod 0555): every file created under the folder fails."""
    ro = tmp_path / "ro"
    ro.mkdir()
    real_open = os.open

    def fake_open(path, flags, *args, **kwargs):
        if str(path).startswith(str(ro)) and flags & os.O_CREAT:
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", fake_open)
    line = error_line(evaluate(poses, ro / "labels.parquet"))
    assert line == f"error: {ro / 'labels.parquet'}: the output file (-o) is not writable: Read-only file system"


def fake_dataset(root: Path) -> Path:
    """A minimal published dataset (grasps.parquet, one scene file, card.json listing both with their sizes)."""
    root.mkdir(parents=True)
    table = pa.table({"scene_id": ["scene_000000"], "grasp_id": pa.array([0], pa.int32()),
                      "object_name": ["box"], "gripper": ["panda"], "outcome": pa.array([5], pa.int8())})
    pq.write_table(table, root / "grasps.parquet")
    (root / "scenes").mkdir()
    (root / "scenes" / "scene_000000.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(200))
    files = {rel: {"bytes": (root / rel).stat().st_size, "sha256": "0" * 64}
             for rel in ("grasps.parquet", "scenes/scene_000000.h5")}
    card = {"dataset_key": "k", "tables": ["grasps"], "left_out": {}, "stages": {}, "versions": {},
            "config": {"dataset": {"plots": False}}, "files": files}
    (root / "card.json").write_text(json.dumps(card, indent=1))
    return root


def truncate(path: Path, keep: float = 0.5) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


def test_report_on_a_truncated_table_names_it(tmp_path):
    d = fake_dataset(tmp_path / "d")
    size = (d / "grasps.parquet").stat().st_size
    truncate(d / "grasps.parquet")
    line = error_line(gen("report", d))
    assert line == (f"error: {d / 'grasps.parquet'}: {size // 2} bytes, card.json says {size} (truncated?); "
                    f"gen validate {d} lists every damaged file")
    assert not (d / "card.md").exists()


def test_report_on_a_truncated_scene_names_it(tmp_path):
    d = fake_dataset(tmp_path / "d")
    truncate(d / "scenes" / "scene_000000.h5")
    line = error_line(gen("report", tmp_path / "d"))
    assert line.startswith(f"error: {d / 'scenes' / 'scene_000000.h5'}: 104 bytes, card.json says 208")


def test_report_on_a_damaged_scene_of_the_right_size_is_one_line(tmp_path):
    d = fake_dataset(tmp_path / "d")
    line = error_line(gen("report", d), code=1)  # the scene file is the right size but not HDF5 inside
    assert line.startswith(f"error: {d}: cannot render the card (")
    assert line.endswith(f"gen validate {d} names bad files")


def test_report_on_a_truncated_or_incomplete_card_names_it(tmp_path):
    d = fake_dataset(tmp_path / "d")
    truncate(d / "card.json")
    line = error_line(gen("report", d))
    assert line.startswith(f"error: {d / 'card.json'}: cannot read the card (")
    (d / "card.json").write_text("{}")
    line = error_line(gen("report", d))
    assert line == (f"error: {d / 'card.json'}: not a complete dataset card (no dataset_key, tables, left_out, "
                    "stages, versions, config, files); publish again with gen run")


def test_paths_and_values_with_square_brackets_are_printed_literally(tmp_path):
    """``[bold]`` in a path and ``[min, max]`` in a message are text, not rich markup."""
    odd = tmp_path / "[bold]x[/bold]"
    line = error_line(gen("report", odd))
    assert line == f"error: {odd}: no published dataset here (no grasps.parquet in it or in {odd / 'dataset'})"
    line = error_line(gen("run", "--out", tmp_path / "o", "--set", "scenes.objects_per_scene=[3, 2]"))
    assert line == ("error: defaults: scenes.objects_per_scene: must be a number >= 1 or [min, max] with "
                    "1 <= min <= max, got (3, 2)")
    assert not (tmp_path / "o").exists()
    d = fake_dataset(tmp_path / "[red]d")
    result = gen("validate", d)
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert f"in {d} (" in result.output
    assert f"  {d / 'grasps.parquet'}: sha256 differs from card.json's" in result.output


def test_run_with_out_naming_a_file_is_one_line(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("")
    line = error_line(gen("run", "--out", afile))
    assert line == f"error: {afile}: is a file, not a folder; the output folder cannot be made there"


def test_show_output_naming_a_folder_is_checked_first(tmp_path):
    folder = tmp_path / "pics"
    folder.mkdir()
    line = error_line(gen("show", "scene", "scene_000000", "--out", tmp_path / "o", "-o", folder))
    assert line == f"error: {folder}: is a folder; the output file must name a file, not a folder"


def test_unreachable_dask_scheduler_is_one_line_before_any_work(tmp_path, monkeypatch):
    """End to end through gen run: the connect fails after run.DASK_CONNECT_TIMEOUT (10 s; 2 s here)."""
    pytest.importorskip("dask.distributed")
    import pipeline.backends

    monkeypatch.setattr(pipeline.backends, "DASK_CONNECT_TIMEOUT", 2)
    out = tmp_path / "o"
    line = error_line(gen("run", "--out", out, "--backend", "dask", "--set", "run.dask_address=tcp://127.0.0.1:1"))
    assert line.startswith("error: run.dask_address: cannot reach a dask scheduler at tcp://127.0.0.1:1 within 2 s")
    assert line.endswith("start one (dask scheduler) or fix the address")
    assert not (out / "shards").exists()  # nothing planned or run
