"""The closing motion of a hand in a robot model (:class:`HandMotion`): which joints close it and which way, its pads,
and fingers added where the file has none (:func:`hand_motion`). Plain numpy over :class:`~graspgen.sim.hand_tree.
HandTree`, except for a hand with closed kinematic loops (MJCF equalities, :attr:`HandTree.loops`), whose joints
MuJoCo settles along the stroke (:mod:`graspgen.sim.hand_loops`); :mod:`graspgen.sim.gripper_import` (module
docstring: what is derived) turns it into a gripper spec.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
import trimesh

from graspgen.errors import SettingsError
from graspgen.grippers.model_ref import ModelRef
from graspgen.sim.hand_tree import Geom, HandTree, read_urdf

if TYPE_CHECKING:
    from graspgen.sim.hand_loops import LoopPath

__all__ = ["HandMotion", "hand_motion", "world_vertices"]


@dataclass(frozen=True)
class HandMotion:
    """The hand's closing motion as the model gives it: link poses from open (s = 0) to closed (s = 1)."""

    tree: HandTree
    """The model's tree."""
    root: str
    """The hand's base link."""
    closing: dict
    """Closing joint name -> (open value, closed value) (rad or m)."""
    mimic: dict
    """Mimic joint name -> (source, multiplier, offset), sources resolved to closing joints."""
    actuator: str = ""
    """The MJCF actuator that closes the hand ('' when the closing joints were named or derived otherwise)."""
    loops: LoopPath | None = None
    """For a hand with closed kinematic loops: every hand joint's value along the stroke as MuJoCo settles it
    (:mod:`graspgen.sim.hand_loops`); None for open chains."""

    def q(self, s: float) -> dict[str, float]:
        """Joint values (rad or m) at closing fraction ``s`` (0 open, 1 closed)."""
        q = {n: a + s * (b - a) for n, (a, b) in self.closing.items()}
        for name, (src, mult, off) in self.mimic.items():
            q[name] = mult * q[src] + off
        if self.loops is not None:
            q.update({n: v for n, v in self.loops.at(s).items() if n not in self.closing})
        return q

    @property
    def moving(self) -> set[str]:
        """Names of the joints that move with the closing ones: the closing and mimic joints, and every joint the
        loops settle."""
        return set(self.closing) | set(self.mimic) | set(() if self.loops is None else self.loops.joints)

    def poses(self, s: float) -> dict[str, np.ndarray]:
        """(4, 4) pose of each link in the base frame at ``s``."""
        return self.tree.poses(self.root, self.q(s))


def _read_tree(ref: ModelRef) -> HandTree:
    if ref.path.lower().endswith(".urdf"):
        return read_urdf(ref.path)
    from graspgen.sim.hand_mjcf import read_mjcf

    return read_mjcf(ref.path)


def _actuator(tree: HandTree, ref: ModelRef, moving: dict) -> str:
    """The actuator that closes the hand: ``ref.actuator``, else the only one acting on the hand's joints."""
    mine = {n: v for n, v in tree.actuators.items() if any(j in moving for j in v[0])}
    if ref.actuator:
        if ref.actuator not in tree.actuators:
            raise SettingsError(f"actuator: no actuator {ref.actuator!r} in the model; its actuators: "
                                f"{', '.join(tree.actuators) or 'none'}")
        return ref.actuator
    if len(mine) > 1:
        raise SettingsError(f"actuator: the hand has {len(mine)} actuators ({', '.join(mine)}); name the one that "
                            "closes it")
    return next(iter(mine), "")


def _closing_joints(tree: HandTree, root: str, ref: ModelRef, pad_links: tuple[str, str],
                    loops: tuple[str, ...] = ()) -> tuple[list, dict, str]:
    """(closing joint names, mimic map resolved to them, closing actuator or '') of the subtree of ``root``;
    ``loops``: the equalities that close loops in it (their joints are not told apart from closing ones)."""
    links = set(tree.subtree(root))
    moving = {j.name: j for j in tree.joints if j.child in links and j.type != "fixed"}
    actuator = "" if ref.joints else _actuator(tree, ref, moving)
    if loops and not actuator and not ref.joints:
        raise SettingsError(f"joints: the hand's loops ({', '.join(loops)}) hide which joints drive it and it has "
                            "no actuator; name the joints that close it with joints: [...]")
    if actuator:
        closing = [j for j in tree.actuators[actuator][0] if j in moving]
        if not closing:
            raise SettingsError(f"actuator: {actuator!r} moves none of the hand's joints")
    elif ref.joints:
        bad = [n for n in ref.joints if n not in moving]
        if bad:
            raise SettingsError(f"joints: {bad[0]!r} is not a moving joint of the hand; its moving joints: "
                                f"{', '.join(moving) or 'none'}")
        closing = list(ref.joints)
    else:
        closing = [n for n, j in moving.items() if j.mimic is None]
        on_chain = {j.name for pad in pad_links for j in tree.chain(root, pad)}
        if not closing or any(n not in on_chain for n in closing):
            raise SettingsError(f"joints: cannot tell which joints close the hand (independent moving joints: "
                                f"{', '.join(closing) or 'none'}); name them with joints: [...]")
    mimic = {}
    for name, joint in moving.items():
        if name in closing or joint.mimic is None:
            continue
        src, mult, off = joint.mimic
        while src not in closing and src in moving and moving[src].mimic is not None:
            s2, m2, o2 = moving[src].mimic
            src, mult, off = s2, mult * m2, mult * o2 + off
        if src in closing:
            mimic[name] = (src, mult, off)
    for name in closing:
        joint = moving[name]
        if not (np.isfinite(joint.lower) and np.isfinite(joint.upper) and joint.upper > joint.lower):
            raise SettingsError(f"joints: {name!r} has no finite range in the model; the stroke comes from it")
    return closing, mimic, actuator


def _named(tree: HandTree, root: str, name: str) -> tuple[str, int | None]:
    """(link, geom index) of a pad's name: a collision geom's name (index), or a link's (index None)."""
    links = tree.subtree(root)
    for link in links:
        for k, g in enumerate(tree.links[link].geoms):
            if g.name == name:
                return link, k
    if name not in links:
        geoms = [g.name for link in links for g in tree.links[link].geoms if g.name]
        raise SettingsError(f"pads: no geom or body {name!r} in the hand; bodies: {', '.join(links)}"
                            + (f"; named geoms: {', '.join(geoms)}" if geoms else ""))
    if not tree.links[name].geoms:
        raise SettingsError(f"pads: body {name!r} has no collision geometry; give finger_box: {{size, pos}} (a box "
                            "finger on each pad body, in the right one's frame) or name a body that has some")
    return name, None


def _pad_geoms(tree: HandTree, root: str, names: tuple[str, str]) -> tuple[tuple[str, int], tuple[str, int]]:
    """(link, geom index) of the (left, right) pads: a geom by its name, or a link's geom that reaches farthest
    towards the other pad's link along the line between the two links' geometry (a fingertip's pad, not its
    mount)."""
    found = [_named(tree, root, n) for n in names]
    if found[0][0] == found[1][0]:
        raise SettingsError(f"pads: both pads are on body {found[0][0]!r}; name one on each finger")
    poses = tree.poses(root, {})

    def centre(link):
        return np.mean([trimesh.transform_points(g.mesh.vertices, poses[link] @ g.pose).mean(axis=0)
                        for g in tree.links[link].geoms], axis=0)
    out = []
    for (link, k), (other, _) in zip(found, found[::-1]):
        if k is None:
            line = centre(other) - centre(link)
            if np.linalg.norm(line) < 1e-9:
                raise SettingsError(f"pads: bodies {link!r} and {other!r} coincide at the joints' zero; name the pad "
                                    "geoms")
            line /= np.linalg.norm(line)
            k = int(np.argmax([float((trimesh.transform_points(g.mesh.vertices, poses[link] @ g.pose) @ line).max())
                               for g in tree.links[link].geoms]))
        out.append((link, k))
    return out[0], out[1]


#: Thickness (m) of the face layer of a ``finger_box`` that is its pad (a geom of its own, as every gripper's pads).
PAD_LAYER = 0.002


def _split_box(size, pos, inward: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """(size, pos) of a box's pad layer (its :data:`PAD_LAYER` facing ``inward``, body frame) and of the rest."""
    axis = int(np.argmax(np.abs(inward)))
    sign = float(np.sign(inward[axis]))
    size, pos = np.asarray(size, dtype=float), np.asarray(pos, dtype=float)
    layer = min(PAD_LAYER, size[axis] / 2.0)
    pad_size, rest_size = size.copy(), size.copy()
    pad_size[axis], rest_size[axis] = layer, size[axis] - layer
    pad_pos, rest_pos = pos.copy(), pos.copy()
    pad_pos[axis] += sign * (size[axis] - layer) / 2.0
    rest_pos[axis] -= sign * layer / 2.0
    return [(pad_size, pad_pos), (rest_size, rest_pos)]


def _with_finger_box(tree: HandTree, root: str, ref: ModelRef) -> HandTree:
    """``tree`` with ``ref.finger_box`` on each pad body that has no collision geometry: as given on the right
    body, turned 180 degrees about the axis through both bodies' midpoint along the approach for the left. Each box
    is two geoms: its :data:`PAD_LAYER` facing the other body (the pad) and the rest (the finger)."""
    box = ref.finger_box
    if box is None:
        return tree
    poses = tree.poses(root, {})
    left, right = ref.pads
    for name in (left, right):
        if name not in tree.links or tree.links[name].geoms:
            raise SettingsError(f"finger_box: goes on pad bodies without collision geometry; {name!r} is not one")
    mid = (poses[left][:3, 3] + poses[right][:3, 3]) / 2.0
    up = mid - poses[root][:3, 3]
    if np.linalg.norm(up) < 1e-6 or np.linalg.norm(poses[right][:3, 3] - mid) < 1e-6:
        raise SettingsError("finger_box: the pad bodies' frames and the hand's base do not span the hand at the "
                            "joints' zero; model the fingers in the file")
    turn = trimesh.transformations.rotation_matrix(np.pi, up / np.linalg.norm(up), mid)
    inward = poses[right][:3, :3].T @ (mid - poses[right][:3, 3])
    links = dict(tree.links)
    for name in (right, left):
        geoms = []
        for k, (size, pos) in enumerate(_split_box(box.size, box.pos, inward)):
            pose = np.eye(4)
            pose[:3, 3] = pos
            if name == left:
                pose = np.linalg.inv(poses[left]) @ turn @ poses[right] @ pose
            geoms.append(Geom(name=f"{name}_{('pad', 'finger')[k]}", pose=pose,
                              mesh=trimesh.creation.box(extents=size), box=tuple(size)))
        links[name] = replace(tree.links[name], geoms=tuple(geoms))
    return replace(tree, links=links)


def world_vertices(motion_poses: dict, link: str, geom: Geom) -> np.ndarray:
    """(n, 3) vertices (m) of ``geom`` of ``link`` in the base frame, with link poses ``motion_poses``."""
    return trimesh.transform_points(geom.mesh.vertices, motion_poses[link] @ geom.pose)


def _orient(tree: HandTree, root: str, closing: list, mimic: dict, pads: tuple, actuator: str) -> HandMotion:
    """The :class:`HandMotion` with each closing joint's open end chosen (pads farther apart there)."""
    def gap(q):
        poses = tree.poses(root, q)
        centres = [world_vertices(poses, link, tree.links[link].geoms[k]).mean(axis=0) for link, k in pads]
        return float(np.linalg.norm(centres[1] - centres[0]))
    joints = {j.name: j for j in tree.joints}
    mid = {n: (joints[n].lower + joints[n].upper) / 2.0 for n in closing}
    ends = {}
    for name in closing:
        j = joints[name]
        probe = [dict(mid, **{name: v}) for v in (j.lower, j.upper)]
        for q in probe:
            for m, (src, mult, off) in mimic.items():
                q[m] = mult * q[src] + off
        low, high = gap(probe[0]), gap(probe[1])
        if abs(high - low) < 1e-6:
            raise SettingsError(f"joints: {name!r} does not move the pads apart or together; name the joints that "
                                "close the hand")
        ends[name] = (j.upper, j.lower) if high > low else (j.lower, j.upper)
    return HandMotion(tree=tree, root=root, closing=ends, mimic=mimic, actuator=actuator)


#: Samples of the stroke at which MuJoCo settles a looped hand's joints (linear between them).
LOOP_SAMPLES = 201


def _orient_loops(tree: HandTree, root: str, closing: list, mimic: dict, pads: tuple, actuator: str,
                  loops: tuple[str, ...]) -> HandMotion:
    """:func:`_orient` for a hand with closed loops: MuJoCo settles the loops with each closing joint at either end
    of its range (the others mid-range) to find its open end, then along the stroke from open to closed."""
    from graspgen.sim.hand_loops import LoopSolver

    links = set(tree.subtree(root))
    hand = [j.name for j in tree.joints if j.child in links and j.type != "fixed"]
    solver = LoopSolver(tree.path, hand, closing, loops)
    joints = {j.name: j for j in tree.joints}

    def gap(q):
        poses = tree.poses(root, q)
        centres = [world_vertices(poses, link, tree.links[link].geoms[k]).mean(axis=0) for link, k in pads]
        return float(np.linalg.norm(centres[1] - centres[0]))
    mid = {n: (joints[n].lower + joints[n].upper) / 2.0 for n in closing}
    ends = {}
    for name in closing:
        j = joints[name]
        low, high = (gap(solver.settle(dict(mid, **{name: v}), check=False)) for v in (j.lower, j.upper))
        if abs(high - low) < 1e-6:
            raise SettingsError(f"joints: {name!r} does not move the pads apart or together with the loops "
                                f"({', '.join(loops)}) closed; name the joints that close the hand")
        ends[name] = (j.upper, j.lower) if high > low else (j.lower, j.upper)
    path = solver.path(ends, LOOP_SAMPLES)
    return HandMotion(tree=tree, root=root, closing=ends, mimic=mimic, actuator=actuator, loops=path)


def _hand_loops(tree: HandTree, root: str) -> tuple[str, ...]:
    """The loop equalities that tie a body of ``root``'s subtree."""
    links = set(tree.subtree(root))
    return tuple(n for n, bodies in tree.loops.items() if links & set(bodies))


def hand_motion(ref: ModelRef) -> tuple[HandMotion, tuple[tuple[str, int], tuple[str, int]]]:
    """The :class:`HandMotion` of the hand in ``ref`` and its (left, right) pad geoms as (link, geom index)."""
    tree = _read_tree(ref)
    root = ref.body or tree.root()
    tree.subtree(root)  # the body exists
    tree = _with_finger_box(tree, root, ref)
    left, right = _pad_geoms(tree, root, ref.pads)
    loops = _hand_loops(tree, root)
    closing, mimic, actuator = _closing_joints(tree, root, ref, (left[0], right[0]), loops)
    if loops:
        return _orient_loops(tree, root, closing, mimic, (left, right), actuator, loops), (left, right)
    return _orient(tree, root, closing, mimic, (left, right), actuator), (left, right)
