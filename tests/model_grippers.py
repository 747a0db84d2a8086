"""The example grippers given as robot models (``assets/model_grippers``) and the optional packages that ship their
models (the ``grippers`` extra): tests that need one are skipped, with the reason, when it is not installed."""

from __future__ import annotations

import importlib.metadata

import pytest

from tests.paths import REPO

MODEL_GRIPPERS_DIR = REPO / "assets" / "model_grippers"
"""The example gripper files that name a robot model."""

#: Example gripper -> the distribution (pip name) that ships its model.
MODEL_GRIPPERS = {"robotiq_2f85_urdf": "airo-models", "panda_urdf": "example-robot-data",
                  "schunk_egk40": "airo-models"}


def installed(distribution: str) -> bool:
    """Whether the distribution ``distribution`` is installed."""
    try:
        importlib.metadata.distribution(distribution)
    except importlib.metadata.PackageNotFoundError:
        return False
    return True


def model_gripper(name: str) -> str:
    """The path of example model gripper ``name``; skips the test when its package is missing."""
    dist = MODEL_GRIPPERS[name]
    if not installed(dist):
        pytest.skip(f"{dist} is not installed (the 'grippers' extra: pip install -e '.[grippers]')")
    return str(MODEL_GRIPPERS_DIR / f"{name}.yaml")


def model_gripper_params(names=tuple(MODEL_GRIPPERS), marks=None) -> list:
    """``pytest.param`` of each example model gripper's path, skipped with the reason when its package is missing;
    ``marks``: name -> extra marks."""
    out = []
    for name in names:
        dist = MODEL_GRIPPERS[name]
        skip = [] if installed(dist) else [pytest.mark.skip(reason=f"{dist} is not installed (the 'grippers' "
                                                                   "extra: pip install -e '.[grippers]')")]
        out.append(pytest.param(str(MODEL_GRIPPERS_DIR / f"{name}.yaml"), id=name,
                                marks=[*skip, *((marks or {}).get(name, []))]))
    return out
