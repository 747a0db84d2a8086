"""The calibration grasps every study reads: where they are, and one loader for them.

The calibration folder holds ACRONYM files (``*.h5``, searched recursively) with FleX's labels
(``grasps/qualities/flex/object_in_gripper``) and their meshes beside them: the example mug and a bottle, bowl, hat,
knife and mug of 1,000 Franka Panda grasps each. It is not part of the repository. Its path is, in order:

1. the study's ``--calibration DIR`` option;
2. the ``GRASPGEN_CALIBRATION`` environment variable;
3. ``../shared/calibration`` beside the repository root (:data:`DEFAULT_CALIBRATION`).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from pathlib import Path

import numpy as np

from graspgen.errors import InputError
from graspgen.io.acronym import read_acronym

REPO = Path(__file__).resolve().parents[1]
"""The repository root (the CoACD cache of the studies is ``REPO/.cache``, as ``run.cache_dir``)."""
STUDIES = Path(__file__).resolve().parent
"""This package's folder: the studies write their results (``results_<study>.json``, gitignored) here."""
ENV_VAR = "GRASPGEN_CALIBRATION"
"""Environment variable naming the calibration folder when no ``--calibration`` is given."""
DEFAULT_CALIBRATION = REPO.parent / "shared" / "calibration"
"""The calibration folder without option or environment variable: ``shared/calibration`` beside the repository."""


def calibration_dir(option: Path | str | None = None) -> Path:
    """The calibration folder: ``option`` (a ``--calibration`` value) when given, else ``$GRASPGEN_CALIBRATION``,
    else :data:`DEFAULT_CALIBRATION`."""
    if option is not None:
        return Path(option)
    env = os.environ.get(ENV_VAR)
    return Path(env) if env else DEFAULT_CALIBRATION


def add_calibration_option(parser: argparse.ArgumentParser, subfolder: str | None = None) -> None:
    """Add ``--calibration DIR`` to a study's parser; its default is :func:`calibration_dir` (joined with
    ``subfolder`` when the study reads one object's folder of it)."""
    default = calibration_dir() / subfolder if subfolder else calibration_dir()
    parser.add_argument("--calibration", type=Path, default=default,
                        help=f"calibration folder (default: ${ENV_VAR}, else ../shared/calibration beside the "
                        f"repository{', its ' + subfolder + '/' if subfolder else ''}; now {default})")


@dataclasses.dataclass
class Case:
    """One calibration object: its grasps (TCP poses) and FleX's labels, subset by ``--limit``."""

    name: str
    category: str
    path: Path
    mesh: Path
    scale: float
    mass: float | None
    friction: float
    density: float | None
    T: np.ndarray
    flex: np.ndarray
    flex_motion: dict[str, np.ndarray]


def object_name(path: Path) -> str:
    """``Mug_187859d3...h5`` -> ``mug 187859``; the example mug (``even_Mug_10f6e0...``) -> ``mug 10f6e0 (ex)``."""
    parts = path.stem.split("_")
    example = parts[0] == "even"
    if example:
        parts = parts[1:]
    return f"{parts[0].lower()} {parts[1][:6]}" + (" (ex)" if example else "")


def category(path: Path) -> str:
    """The ACRONYM file name's prefix, lower case: ``Mug_1878...h5`` and ``even_Mug_10f6...h5`` -> ``mug``."""
    parts = path.stem.split("_")
    return (parts[1] if parts[0] == "even" and len(parts) > 1 else parts[0]).lower()


def subset(n: int, limit: int | None) -> np.ndarray:
    """``limit`` evenly spaced indices of ``range(n)`` (all of them without a limit)."""
    if limit is None or limit >= n:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, limit)).astype(int))


def load_cases(root: Path, limit: int | None) -> list[Case]:
    """Every ACRONYM file under ``root`` (sorted by path) as a :class:`Case`, with ``limit`` evenly spaced grasps
    each (:func:`subset`); a file that cannot be read is skipped with a line on stderr."""
    files = sorted(root.rglob("*.h5"))
    if not files:
        raise SystemExit(f"no ACRONYM files under {root} (set --calibration)")
    cases, names = [], set()
    for path in files:
        try:
            acr = read_acronym(path)
        except InputError as exc:  # e.g. a quality that is not one value per grasp: say so, keep the others
            print(f"  skipped: {exc}", file=sys.stderr)
            continue
        idx = subset(len(acr), limit)
        q = acr.qualities
        motion = {k.removeprefix("flex/"): np.asarray(v)[idx] for k, v in q.items() if "object_motion" in k}
        name = object_name(path)
        k = 2
        while name in names:  # one mesh at several scales (the learning set): keep the names apart
            name = f"{object_name(path)} #{k}"
            k += 1
        names.add(name)
        cases.append(Case(
            name=name, category=category(path), path=path, mesh=path.parent / acr.object_file, scale=acr.object_scale,
            mass=acr.object_mass, friction=acr.object_friction if acr.object_friction is not None else 1.0,
            density=acr.object_density, T=acr.tcp_poses()[idx], flex=np.asarray(acr.success)[idx].astype(int),
            flex_motion=motion,
        ))
    return cases
