"""Fixtures shared by the library's tests in more than one package (tests/graspgen/<package>/)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest


def _random_poses(n: int, seed: int = 0) -> np.ndarray:
    """(n, 4, 4) random rigid transforms (rotations from QR of Gaussian matrices, det +1), translations in +-0.2 m,
    from ``numpy.random.default_rng(seed)``."""
    rng = np.random.default_rng(seed)
    T = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):
        q, r = np.linalg.qr(rng.standard_normal((3, 3)))
        q *= np.sign(np.diag(r))
        if np.linalg.det(q) < 0:
            q[:, 0] *= -1
        T[i, :3, :3] = q
        T[i, :3, 3] = rng.uniform(-0.2, 0.2, 3)
    return T


@pytest.fixture(scope="session")
def random_poses() -> Callable[..., np.ndarray]:
    """The function ``random_poses(n, seed=0)``: (n, 4, 4) random rigid transforms (det +1 rotations, translations
    in +-0.2 m), the same poses for the same ``(n, seed)``."""
    return _random_poses
