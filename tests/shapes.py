"""Test meshes with known geometry, shared by the mesh-preparation, hull-slack and convex-rule tests, and the grasp
pose the object-centric set tests aim at them."""

from __future__ import annotations

import numpy as np
import trimesh


def top_down(x: float, y: float, z: float) -> np.ndarray:
    """(4, 4) TCP pose at (x, y, z) approaching straight down -z, closing along x."""
    T = np.eye(4)
    T[:3, 0], T[:3, 2] = (1.0, 0.0, 0.0), (0.0, 0.0, -1.0)
    T[:3, 1] = np.cross(T[:3, 2], T[:3, 0])
    T[:3, 3] = (x, y, z)
    return T


def l_shape() -> trimesh.Trimesh:
    """Two 0.1 x 0.02 x 0.02 m bars meeting at a corner; volume 2 * 4e-5 - 8e-6 = 7.2e-5 m^3."""
    a = trimesh.creation.box((0.1, 0.02, 0.02))
    a.apply_translation((0.05, 0.01, 0.01))
    b = trimesh.creation.box((0.02, 0.1, 0.02))
    b.apply_translation((0.01, 0.05, 0.01))
    return a.union(b)
