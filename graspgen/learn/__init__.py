"""Can a network learn these labels? A small grasp-success evaluator trained on labelled grasps, measured on
objects it never saw.

* :mod:`graspgen.learn.features`: per grasp, the object's surface points nearest the closing region and nearest
  the hand's body in the TCP frame, each flagged inside the closing volume / inside the hand, and the width (numpy
  only).
* :mod:`graspgen.learn.sources`: labelled grasp sets per object (ACRONYM files with FleX or our simulator's
  labels, a dataset folder) and the split by object (numpy only).
* :mod:`graspgen.learn.report`: ROC-AUC, average precision, per-object AUC, top-k (numpy only).
* :mod:`graspgen.learn.model`, :mod:`~graspgen.learn.train`, :mod:`~graspgen.learn.baselines`,
  :mod:`~graspgen.learn.probe`: the PointNet evaluator, its seeded training, the baselines and the probe
  (need torch and scikit-learn: ``pip install -e '.[learn]'``; call :func:`require_torch` first).

Importing this package, ``features``, ``sources`` or ``report`` never imports torch.
"""

from __future__ import annotations

import importlib

from graspgen.errors import MissingDependencyError

__all__ = ["INSTALL_MESSAGE", "require_torch"]

INSTALL_MESSAGE = ("graspgen.learn needs torch and scikit-learn, which are not installed: pip install -e '.[learn]' "
                   "(CPU build: pip install torch==2.13.0 scikit-learn)")
"""The one line :func:`require_torch` raises with."""


def require_torch() -> None:
    """Raise :class:`graspgen.errors.MissingDependencyError` (:data:`INSTALL_MESSAGE`) unless torch and
    scikit-learn import."""
    for module in ("torch", "sklearn"):
        try:
            importlib.import_module(module)
        except ImportError:
            raise MissingDependencyError(INSTALL_MESSAGE) from None
