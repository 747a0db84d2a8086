"""Tests of studies/calibration.py: where the calibration folder is (``--calibration``, then
``$GRASPGEN_CALIBRATION``, then ``../shared/calibration`` beside the repository) and the error when it holds no
ACRONYM file."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from graspgen.io.acronym import write_acronym
from studies import calibration
from studies.calibration import DEFAULT_CALIBRATION, ENV_VAR, add_calibration_option, calibration_dir, load_cases
from tests.paths import REPO


def parse(argv: list[str], subfolder: str | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_calibration_option(parser, subfolder)
    return parser.parse_args(argv)


def write_mug(folder, n: int = 5) -> None:
    """One ACRONYM file of ``n`` grasps (every other one a FleX success) named the way the calibration set is."""
    folder.mkdir(parents=True, exist_ok=True)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 2, 3] = np.linspace(0.0, 0.1, n)
    write_acronym(folder / "Mug_187859d3abcdef_0.01.h5", T, np.arange(n) % 2 == 0, object_file="mug.obj",
                  object_scale=0.01)


def test_the_default_is_shared_calibration_beside_the_repository(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert DEFAULT_CALIBRATION == REPO.parent / "shared" / "calibration"
    assert calibration_dir() == DEFAULT_CALIBRATION
    assert parse([]).calibration == DEFAULT_CALIBRATION
    monkeypatch.setenv(ENV_VAR, "")  # set but empty: as if unset
    assert calibration_dir() == DEFAULT_CALIBRATION


def test_the_environment_variable_comes_before_the_default(tmp_path, monkeypatch):
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "env"))
    assert calibration_dir() == tmp_path / "env"
    assert parse([]).calibration == tmp_path / "env"
    assert parse([], subfolder="mug").calibration == tmp_path / "env" / "mug"  # one object's folder of it


def test_the_option_comes_before_the_environment_variable(tmp_path, monkeypatch):
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "env"))
    assert calibration_dir(tmp_path / "opt") == tmp_path / "opt"
    assert calibration_dir(str(tmp_path / "opt")) == tmp_path / "opt"
    assert parse(["--calibration", str(tmp_path / "opt")]).calibration == tmp_path / "opt"
    assert parse(["--calibration", str(tmp_path / "opt")], subfolder="mug").calibration == tmp_path / "opt"


def test_the_resolved_folder_is_the_one_loaded(tmp_path, monkeypatch):
    write_mug(tmp_path / "env")
    write_mug(tmp_path / "opt" / "nested", n=7)  # searched recursively
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "env"))
    (env_case,) = load_cases(parse([]).calibration, limit=None)
    (opt_case,) = load_cases(parse(["--calibration", str(tmp_path / "opt")]).calibration, limit=3)
    assert env_case.path.parent == tmp_path / "env" and len(env_case.T) == 5
    assert env_case.name == "mug 187859" and env_case.category == "mug"
    np.testing.assert_array_equal(env_case.flex, [1, 0, 1, 0, 1])
    assert opt_case.path.parent == tmp_path / "opt" / "nested" and len(opt_case.T) == 3  # limit: 3 evenly spaced
    np.testing.assert_allclose(opt_case.T[:, 2, 3], [0.0, 0.05, 0.1], atol=1e-12)


@pytest.mark.parametrize("make", [False, True], ids=["missing folder", "folder without h5 files"])
def test_no_calibration_files_is_a_clear_error_naming_the_folder_and_the_option(tmp_path, monkeypatch, make):
    root = tmp_path / "nowhere"
    if make:
        root.mkdir()
        (root / "notes.txt").write_text("no grasps here\n")
    monkeypatch.setenv(ENV_VAR, str(root))
    with pytest.raises(SystemExit) as err:
        load_cases(calibration.calibration_dir(), limit=None)
    assert str(err.value) == f"no ACRONYM files under {root} (set --calibration)"
