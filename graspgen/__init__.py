"""graspgen: physics-labelled parallel-jaw grasps from object meshes.

The grasp library, usable without the pipeline. Its public entry points:

* :func:`open_dataset` -- lazy reader of a published dataset (``OUT/dataset``): grasps, scene views, point clouds.
* :func:`evaluate_grasps` -- label grasps given as TCP poses on one mesh with the MuJoCo grasp-and-lift protocol.
* :func:`load_gripper` -- a gripper model (:class:`~graspgen.grippers.GripperSpec`) by name.

They are imported on first use, so ``from graspgen import open_dataset`` needs numpy, pyarrow and h5py only (no
MuJoCo, no trimesh). The building blocks live in the sub-packages: :mod:`graspgen.grippers` (gripper specs and
files), :mod:`graspgen.geometry` (meshes, convex decomposition, stable poses, antipodal sampling, ray contacts),
:mod:`graspgen.sim` (the gripper's MuJoCo model, scene model, grasp-and-lift protocol, collision pre-filter),
:mod:`graspgen.quality` (wrench maths, epsilon, robustness), :mod:`graspgen.io` (records, Arrow helpers, ACRONYM,
the reader), :mod:`graspgen.workflows` (the table builders the stages call, and ``evaluate_grasps``) and
:mod:`graspgen.viz` (pictures).
ARCHITECTURE.md in the repository shows how they fit together.
"""

from __future__ import annotations

import importlib
from typing import Any

import graspgen.sim.gl  # noqa: F401 - chooses MuJoCo's GL back end before anything imports mujoco

__all__ = ["evaluate_grasps", "load_gripper", "open_dataset"]

_PUBLIC = {
    "open_dataset": ("graspgen.io.reader", "open_dataset"),
    "evaluate_grasps": ("graspgen.workflows.evaluate", "evaluate_grasps"),
    "load_gripper": ("graspgen.grippers", "load_gripper"),
}


def __getattr__(name: str) -> Any:
    if name not in _PUBLIC:
        raise AttributeError(f"module 'graspgen' has no attribute {name!r}; public names: {', '.join(__all__)}")
    module, attr = _PUBLIC[name]
    value = getattr(importlib.import_module(module), attr)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
