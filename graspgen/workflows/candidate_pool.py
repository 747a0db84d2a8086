"""Sampling until targets are met: a shuffled pool of antipodal candidates and the cap on collision negatives.

Shared by the object-centric sets (:mod:`graspgen.workflows.object_grasps`: rollouts in free space until the positive
and negative targets are met) and the scene grasps (:mod:`graspgen.workflows.scene_grasps`: pre-filter checks until an
object has its collision-free candidates). Both draw candidates from a :class:`CandidatePool` batch by batch, and
both keep collision negatives only up to a share (:func:`collision_cap`), so that the cheapest and least
informative label, "the open hand went through something", cannot fill a table.

Randomness: a pool draws only from the generator it is given, in a fixed order: one
:func:`graspgen.geometry.antipodal.sample_antipodal` call per refill, then one ``rng.permutation`` of its output.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from graspgen.geometry.antipodal import AntipodalParams, sample_antipodal
from graspgen.grippers import GripperSpec

__all__ = ["EMPTY_REFILLS", "CandidatePool", "collision_cap"]

EMPTY_REFILLS = 3
"""Consecutive sampler calls without a single candidate after which a pool gives up (the object is too big or too
thin for the gripper, or no approach passes the filter)."""


_SHAPES = {"pose_object": (4, 4), "pose_world": (4, 4), "p1": (3,), "p2": (3,), "n1": (3,), "n2": (3,)}
"""Trailing shapes of the candidate arrays that are not one number per candidate (for an empty :meth:`take`)."""


def collision_cap(share: float, count: int) -> int:
    """How many collision negatives a table of ``count`` rows (or negatives) may keep: ``floor(share * count)``.

    The ``1e-9`` guards the floor against round-off (``0.3 * 10`` is ``2.9999999999999996`` in binary)."""
    return math.floor(share * count + 1e-9)


class CandidatePool:
    """Unused antipodal candidates, shuffled, refilled from the sampler when short.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The object's surface in its own frame (reuse one mesh: its ray intersector is cached on it).
    gripper : GripperSpec
    params : AntipodalParams
    rng : numpy.random.Generator
        The only source of randomness (module docstring).
    fields : tuple of str
        The :class:`graspgen.geometry.antipodal.AntipodalCandidates` arrays to keep, in the order :meth:`take`
        returns them.
    object_pose : (4, 4) float, optional
        The object's pose in the world (the sampler's approach filter and ``pose_world``); None: the identity.
    """

    def __init__(self, mesh: trimesh.Trimesh, gripper: GripperSpec, params: AntipodalParams,
                 rng: np.random.Generator, *, fields: tuple[str, ...] = ("pose_object", "width", "depth"),
                 object_pose: np.ndarray | None = None) -> None:
        self.mesh, self.gripper, self.params, self.rng = mesh, gripper, params, rng
        self.fields = tuple(fields)
        self.object_pose = object_pose
        self._arrays: dict[str, np.ndarray] | None = None
        self.sampled = 0
        """Candidates the sampler produced so far."""
        self.refills = 0
        """Sampler calls so far."""
        self.rejected: dict[str, int] = {}
        """The sampler's rejection counts (:class:`graspgen.geometry.antipodal.RejectCounts`), summed over calls."""

    def __len__(self) -> int:
        return 0 if self._arrays is None else len(self._arrays[self.fields[0]])

    def _refill(self) -> int:
        kwargs = {} if self.object_pose is None else {"object_pose": self.object_pose}
        cands = sample_antipodal(self.mesh, self.gripper, self.params, self.rng, **kwargs)
        self.refills += 1
        for key, value in cands.rejected.as_dict().items():
            self.rejected[key] = self.rejected.get(key, 0) + value
        n = len(cands)
        self.sampled += n
        if n == 0:
            return 0
        order = self.rng.permutation(n)
        new = {f: getattr(cands, f)[order] for f in self.fields}
        if self._arrays is None:
            self._arrays = new
        else:
            self._arrays = {f: np.concatenate([self._arrays[f], new[f]]) for f in self.fields}
        return n

    def take(self, k: int) -> tuple[np.ndarray, ...]:
        """The next ``k`` candidates (one array per field), or fewer when the sampler keeps finding none
        (:data:`EMPTY_REFILLS` calls in a row)."""
        empty = 0
        while len(self) < k and empty < EMPTY_REFILLS:
            empty = 0 if self._refill() else empty + 1
        if self._arrays is None:
            return tuple(np.zeros((0, *_SHAPES.get(f, ()))) for f in self.fields)
        k = min(k, len(self))
        out = tuple(self._arrays[f][:k] for f in self.fields)
        self._arrays = {f: a[k:] for f, a in self._arrays.items()}
        return out
