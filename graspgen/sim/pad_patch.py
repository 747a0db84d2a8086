"""The patch of a pad's face that a grasped object presses, and the torsional friction arm of that patch.

A flat pad pressed on an object resists a moment about its normal of ``mu F r``, ``r`` the pressure-weighted mean
distance of the patch from its pressure centre (Howe & Cutkosky 1996; uniform pressure on the whole face gives the
face's closed form :func:`rectangle_arm`). The pressure comes from an elastic foundation (Johnson 1985, 5.9): the
pad is a bed of springs, each pressed by how far the object's surface reaches past the line where the pad is
indented ``w`` deep, ``p ~ (w - h)+``, ``h`` the gap between the face and the object above its deepest point. ``w``
is the gripper contact's own compliance width (solimp ``width``, 1 mm), read from the compiled model. The gaps are
measured in the simulation itself once the jaws have closed: a grid of rays starts behind each face (inside the pad)
and runs along the face's inward normal to the target. A pinch of an edge with little overlap then carries little
torsion, a flat face covering the pad the whole face's, and a line contact on a curved surface a strip whose width
follows the curvature, not the grid (docs/decisions/2026-12-07-pad-patch-torsion.md).

The face of each pad is the box site ``<prefix><side>_face`` that :func:`graspgen.sim.gripper_model.build_gripper`
puts at the pad's contact face (half sizes: ``(0, width / 2, length / 2)`` of ``GripperSpec.pad_size``).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from graspgen.errors import SettingsError

__all__ = ["PATCH_CELLS", "PadPatch", "PatchTorsion", "face_grid", "foundation_pressure", "rectangle_arm"]

PATCH_CELLS = 12
"""Rays per side of the face grid (12 x 12 = 144 per pad; a cell of the Panda's 17.4 x 17.6 mm face is 1.5 mm)."""
_BEHIND = 0.005
"""Where the rays start (m) behind the face: deeper than a pressed pad's penetration (0.1-0.3 mm)."""
_SOLIMP_WIDTH = 2
"""Index of ``width`` in a geom's solimp."""


def rectangle_arm(p: float, q: float) -> float:
    """Mean distance (m) of a rectangle of half-sides ``p``, ``q`` (m) from its centre: closed form of
    ``(1 / (p q)) int_0^p int_0^q sqrt(x^2 + y^2) dy dx = (2 p q d + p^3 ln((q + d) / p) + q^3 ln((p + d) / q))
    / (6 p q)``, ``d = sqrt(p^2 + q^2)``; 0.3826 x the side of a square."""
    d = math.hypot(p, q)
    return (2.0 * p * q * d + p ** 3 * math.log((q + d) / p) + q ** 3 * math.log((p + d) / q)) / (6.0 * p * q)


def face_grid(cells: int = PATCH_CELLS) -> np.ndarray:
    """``(cells**2, 2) float``: cell centres of a unit square centred on 0 (coordinates in [-0.5, 0.5])."""
    u = (np.arange(cells) + 0.5) / cells - 0.5
    a, b = np.meshgrid(u, u, indexing="ij")
    return np.stack([a.ravel(), b.ravel()], axis=1)


def _mean_radius(points: np.ndarray, weights: np.ndarray | None = None) -> float:
    """Weighted mean distance of ``points`` ``(n, 2)`` from their weighted centroid (uniform without ``weights``)."""
    w = np.ones(len(points)) if weights is None else weights
    centre = w @ points / w.sum()
    return float(w @ np.linalg.norm(points - centre, axis=1) / w.sum())


def foundation_pressure(gaps: np.ndarray, width: float) -> np.ndarray:
    """Elastic-foundation pressure of a pad on an object, up to a factor: ``(width - (gap - min gap))+``.

    Parameters
    ----------
    gaps : (n,) float
        Gap (m) from each cell of the face to the object along the face's inward normal, negative where the object
        is inside the pad, ``inf`` where the object is not there.
    width : float
        Indentation (m) of the pad at its deepest point.

    Returns
    -------
    (n,) float
        Zero everywhere when every gap is ``inf``.
    """
    out = np.zeros(len(gaps))
    finite = np.isfinite(gaps)
    if not finite.any():
        return out
    out[finite] = np.maximum(width - (gaps[finite] - gaps[finite].min()), 0.0)
    return out


class PadPatch:
    """The pressed patch of one pad's face in a compiled scene (:meth:`arm`), rays cast by ``mj_ray``.

    Parameters
    ----------
    model
        The compiled scene; ``site`` its face site's id; ``geom`` the pad geom, whose solimp width is the pad's
        indentation (:func:`foundation_pressure`).
    inward
        ``+1`` when the face's inward normal (towards the other pad) is the site's +x axis, ``-1`` for -x.
    exclude_group
        Geom group of the gripper's own geoms, which the rays pass through.
    """

    def __init__(self, model: mujoco.MjModel, site: int, geom: int, inward: float, exclude_group: int,
                 cells: int = PATCH_CELLS) -> None:
        self.site = int(site)
        self.geom = int(geom)
        self.inward = float(inward)
        half = np.asarray(model.site_size[site], dtype=float)
        grid = face_grid(cells)
        self._local = np.zeros((len(grid), 3))
        self._local[:, 0] = -self.inward * _BEHIND
        self._local[:, 1] = grid[:, 0] * 2.0 * half[1]
        self._local[:, 2] = grid[:, 1] * 2.0 * half[2]
        self.face_arm = rectangle_arm(half[1], half[2])
        """Torsional arm (m) of the whole face, :func:`rectangle_arm` of its half sides."""
        self._grid_arm = _mean_radius(self._local[:, 1:])
        self._groups = np.ones(mujoco.mjNGROUP, dtype=np.uint8)
        self._groups[exclude_group] = 0
        self._geomid = np.zeros(1, dtype=np.int32)

    def gaps(self, model: mujoco.MjModel, data: mujoco.MjData, target: int) -> np.ndarray:
        """``(cells**2,) float``: gap (m) from each cell of the face to body ``target``'s surface along the inward
        normal (negative inside the pad); ``inf`` where the ray meets nothing, or another body first, within
        :data:`_BEHIND` past the face."""
        R = data.site_xmat[self.site].reshape(3, 3)
        origins = data.site_xpos[self.site] + self._local @ R.T
        direction = self.inward * R[:, 0]
        gaps = np.full(len(origins), np.inf)
        for k, origin in enumerate(origins):
            dist = mujoco.mj_ray(model, data, origin, direction, self._groups, 0, -1, self._geomid)
            g = int(self._geomid[0])
            if 0.0 <= dist <= 2.0 * _BEHIND and g >= 0 and model.body_rootid[model.geom_bodyid[g]] == target:
                gaps[k] = dist - _BEHIND
        return gaps

    def touches(self, model: mujoco.MjModel, data: mujoco.MjData, target: int) -> bool:
        """Whether the pad geom is in contact with a geom of body ``target`` (``data``'s contact list)."""
        roots = model.body_rootid[model.geom_bodyid]
        for c in data.contact[:data.ncon]:
            if c.geom1 == self.geom and roots[c.geom2] == target or c.geom2 == self.geom and roots[c.geom1] == target:
                return True
        return False

    def pressure(self, model: mujoco.MjModel, data: mujoco.MjData, target: int) -> np.ndarray:
        """``(cells**2,) float``: :func:`foundation_pressure` of the cells (m of indentation), at the pad geom's
        solimp width read now; zero where the pad does not touch the target. The deepest point, not the face site,
        is the reference, since the site and the pad's collision surface may differ by a fraction of a mm."""
        if not self.touches(model, data, target):
            return np.zeros(len(self._local))
        return foundation_pressure(self.gaps(model, data, target), float(model.geom_solimp[self.geom, _SOLIMP_WIDTH]))

    def pressed(self, model: mujoco.MjModel, data: mujoco.MjData, target: int) -> np.ndarray:
        """``(cells**2,) bool``: the cells under pressure."""
        return self.pressure(model, data, target) > 0.0

    def arm(self, model: mujoco.MjModel, data: mujoco.MjData, target: int) -> float:
        """Torsional arm (m) of the pressed patch: :attr:`face_arm` scaled by the patch's pressure-weighted mean
        radius over the whole grid's (so a face fully and evenly pressed gets exactly :attr:`face_arm`); 0 with
        fewer than two cells under pressure."""
        p = self.pressure(model, data, target)
        if (p > 0.0).sum() < 2:
            return 0.0
        return self.face_arm * _mean_radius(self._local[:, 1:], p) / self._grid_arm


class PatchTorsion:
    """The ``"patch"`` pad-torsion model in one compiled scene (:attr:`graspgen.sim.protocols.LiftParams.
    pad_torsion`), written into ``model`` (the simulator's own copy).

    MuJoCo takes the larger of two geoms' torsional coefficients, so the object geoms' (which
    :func:`graspgen.sim.gripper_model.attach_gripper` sets to ``mu * face arm``) are zeroed here and each pad carries
    its own: 0 from placement (:meth:`placed`), the target's whole-face value while the jaws close
    (:meth:`closing`), ``mu * arm of its pressed patch`` from the end of closing on (:meth:`closed`). Every rollout
    sets all three, so a rollout never sees the one before.
    """

    def __init__(self, model: mujoco.MjModel, prefix: str, movable_objects: np.ndarray, exclude_group: int) -> None:
        """``movable_objects``: ``(ngeom,) bool``, the geoms of the movable objects (not the gripper, not the
        support); ``exclude_group``: the gripper geoms' group (the rays pass through it)."""
        K = mujoco.mjtObj
        self.pads = []
        for side, inward in (("left", 1.0), ("right", -1.0)):
            site = mujoco.mj_name2id(model, K.mjOBJ_SITE, f"{prefix}{side}_face")
            geom = mujoco.mj_name2id(model, K.mjOBJ_GEOM, f"{prefix}{side}_pad")
            if site < 0 or geom < 0:
                raise SettingsError(f"model: no pad face site {prefix}{side}_face or pad geom {prefix}{side}_pad "
                                    "(pad_torsion 'patch' needs a gripper built by graspgen.sim.build_gripper)")
            self.pads.append((geom, PadPatch(model, site, geom, inward, exclude_group)))
        pad_geom = self.pads[0][0]
        touches_pads = ((model.geom_contype & model.geom_conaffinity[pad_geom]) != 0) | (
            (model.geom_conaffinity & model.geom_contype[pad_geom]) != 0)
        objects = np.flatnonzero(movable_objects & touches_pads)  # not the visual geoms (contype 0)
        model.geom_friction[objects, 1] = 0.0
        self._geom_root = model.body_rootid[model.geom_bodyid]
        self._objects = objects

    def _mu_with(self, model: mujoco.MjModel, pad: int, target: int) -> float:
        """Sliding friction of the pad's contacts with the target: the pad's own when its priority wins (a gripper
        built with ``friction="pad"``), else the larger of the two (MuJoCo's rule; the pad's is 0 by default)."""
        geoms = self._objects[self._geom_root[self._objects] == target]
        mu = model.geom_friction[:, 0]  # read now: callers may set an object's friction after set-up
        if len(geoms) and model.geom_priority[pad] <= model.geom_priority[geoms].max():
            return float(max(mu[geoms].max(), mu[pad]))
        return float(mu[pad])

    @property
    def pad_geoms(self) -> list[int]:
        """The two pad geoms' ids, left and right."""
        return [geom for geom, _ in self.pads]

    def placed(self, model: mujoco.MjModel) -> None:
        for geom, _ in self.pads:
            model.geom_friction[geom, 1] = 0.0

    def closing(self, model: mujoco.MjModel, target: int) -> None:
        for geom, patch in self.pads:
            model.geom_friction[geom, 1] = self._mu_with(model, geom, target) * patch.face_arm

    def closed(self, model: mujoco.MjModel, data: mujoco.MjData, target: int) -> tuple[float, float]:
        """Write each pad's patch torsion; returns the two arms (m), left and right."""
        arms = []
        for geom, patch in self.pads:
            arm = patch.arm(model, data, target)
            model.geom_friction[geom, 1] = self._mu_with(model, geom, target) * arm
            arms.append(arm)
        return arms[0], arms[1]
