"""Turning a hand's closing motion (:mod:`graspgen.sim.hand_motion`) into a
:class:`~graspgen.grippers.GripperSpec`: frames, stroke, TCP, pads, kinematics, pieces, masses, force and speed
(:func:`build_spec`; what each is: :mod:`graspgen.sim.gripper_import`).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import trimesh

from graspgen.errors import SettingsError
from graspgen.geometry.convex import CoacdParams, cached_convex_decomposition
from graspgen.grippers.model_ref import MAX_PAD_TURN_TOLERANCE, ModelRef
from graspgen.grippers.shapes import Box, Linkage, Mesh, Shape, bounds_of
from graspgen.grippers.spec import GripperSpec
from graspgen.sim.hand_motion import HandMotion, world_vertices
from graspgen.sim.hand_tree import Link

__all__ = ["build_spec", "gripper_cache_dir", "shapes_of", "mirrored_bounds_gap"]

_SAMPLES = 401
#: Smallest turn (degrees) of a pad over the stroke that the gripper's ``source`` names (the pads' largest allowed
#: turn is the gripper file's ``pad_turn_tolerance``, :attr:`ModelRef.pad_turn_tolerance`).
_NAMED_TURN = 0.1
#: Largest off-axis travel (m) of a pad over the stroke for its jaw to count as prismatic.
_SLIDE_TOL = 1e-4
#: Largest error (m) of the fitted parallelogram linkage against the model's pad path.
_LINKAGE_TOL = 2e-4
#: Largest difference (m) between the left finger's bounds and the right one's turned 180 degrees about z.
_MIRROR_TOL = 2e-3


def gripper_cache_dir() -> Path:
    """Folder of the CoACD cache of model grippers: ``$GRASPGEN_GRIPPER_CACHE``, else ``~/.cache/graspgen``."""
    return Path(os.environ.get("GRASPGEN_GRIPPER_CACHE") or Path.home() / ".cache" / "graspgen")


def shapes_of(link: Link, T: np.ndarray, where: str) -> list[Shape]:
    """Collision pieces of ``link`` posed by ``T`` (4x4, link -> TCP frame): axis-aligned boxes as :class:`Box`,
    everything else as convex :class:`Mesh` pieces (mesh files through the cached CoACD decomposition)."""
    out: list[Shape] = []
    for geom in link.geoms:
        G = T @ geom.pose
        R = G[:3, :3]
        if geom.box is not None and np.allclose(np.abs(R), np.round(np.abs(R)), atol=1e-6):
            size = np.abs(R) @ np.asarray(geom.box)
            out.append(Box(size=tuple(size), pos=tuple(G[:3, 3])))
        elif geom.convex:
            out.append(Mesh(trimesh.transform_points(geom.mesh.convex_hull.vertices, G), file=geom.file))
        else:
            try:
                parts = cached_convex_decomposition(geom.mesh, CoacdParams(), gripper_cache_dir())
            except Exception as exc:  # noqa: BLE001 - a mesh CoACD cannot cut: say which
                raise SettingsError(f"{where}: cannot decompose {geom.file} ({type(exc).__name__}: {exc})") from None
            out += [Mesh(trimesh.transform_points(v, G), file=geom.file) for v, _ in parts]
    return out


def mirrored_bounds_gap(right: list[Shape], left: list[Shape]) -> float:
    """Largest difference (m) between the bounds of ``left`` and those of ``right`` turned 180 degrees about z."""
    rlo, rhi = bounds_of(right)
    llo, lhi = bounds_of(left)
    flip = np.array([-1.0, -1.0, 1.0])
    mlo, mhi = np.minimum(rlo * flip, rhi * flip), np.maximum(rlo * flip, rhi * flip)
    return float(max(np.abs(mlo - llo).max(), np.abs(mhi - lhi).max()))


@dataclass(frozen=True)
class _Samples:
    """The hand sampled over the stroke: base-frame link poses and pad vertices at each closing fraction."""

    s: np.ndarray
    """(k,) closing fractions."""
    poses: list
    """k dicts link -> (4, 4) pose in the base frame."""
    left: list
    """k (n, 3) left-pad vertices (base frame)."""
    right: list
    """k (n, 3) right-pad vertices (base frame)."""


def _sample(motion: HandMotion, pads, s: np.ndarray) -> _Samples:
    (ll, lk), (rl, rk) = pads
    geoms = motion.tree.links
    poses = [motion.poses(float(v)) for v in s]
    return _Samples(s=s, poses=poses, left=[world_vertices(p, ll, geoms[ll].geoms[lk]) for p in poses],
                    right=[world_vertices(p, rl, geoms[rl].geoms[rk]) for p in poses])


def _axes(smp: _Samples) -> np.ndarray:
    """(3, 3) columns x (closing), y, z (approach) of the TCP frame in the base frame, from the open pads."""
    cl, cr = smp.left[0].mean(axis=0), smp.right[0].mean(axis=0)
    x = (cr - cl) / np.linalg.norm(cr - cl)
    z = (cl + cr) / 2.0
    z = z - np.dot(z, x) * x
    if np.linalg.norm(z) < 1e-3:
        raise SettingsError("body: cannot derive the approach direction: the pads' midpoint lies on the closing line "
                            "through the hand's base; give the hand's base body with body:")
    z /= np.linalg.norm(z)
    return np.column_stack([x, np.cross(z, x), z])


def _widths(smp: _Samples, R: np.ndarray) -> np.ndarray:
    """(k,) pad separation (m) along x: right face (its lowest x) minus left face (its highest x)."""
    return np.array([(r @ R[:, 0]).min() - (le @ R[:, 0]).max() for le, r in zip(smp.left, smp.right)])


def _stroke(motion: HandMotion, pads, ref: ModelRef) -> tuple[_Samples, np.ndarray]:
    """The samples from open to closed, narrowed to where the faces meet and to a given min/max width, and the
    TCP axes."""
    smp = _sample(motion, pads, np.linspace(0.0, 1.0, _SAMPLES))
    R = _axes(smp)
    w = _widths(smp, R)
    if np.any(np.diff(w) > 1e-7):
        raise SettingsError(f"joints: the pads do not close steadily over the closing joints' range "
                            f"({', '.join(motion.closing)}); name the joints that close the hand")
    given = dict(ref.overrides)
    hi = min(w[0], float(given.get("max_width", np.inf)))
    lo = max(w[-1], 0.0, float(given.get("min_width", 0.0)))
    if hi <= lo:
        raise SettingsError(f"max_width: the stroke is empty ({lo:.4g} .. {hi:.4g} m between the pad faces)")
    s_open, s_closed = (float(np.interp(v, w[::-1], smp.s[::-1])) for v in (hi, lo))
    smp = _sample(motion, pads, np.linspace(s_open, s_closed, _SAMPLES))
    return smp, R


def _turn(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (rad) between rotations ``a`` and ``b`` (3x3)."""
    return float(np.arccos(np.clip((np.trace(a.T @ b) - 1.0) / 2.0, -1.0, 1.0)))


def _tcp(smp: _Samples, R: np.ndarray) -> tuple[np.ndarray, tuple[float, float, float], float, float]:
    """(T_tcp_base (4, 4), pad_size, min_width, max_width): the TCP midway between the faces, at the pads' mean y,
    halfway along the part of the pad faces that faces it at every width."""
    w = _widths(smp, R)
    left, right = smp.left[0] @ R, smp.right[0] @ R
    x_c = (right[:, 0].min() + left[:, 0].max()) / 2.0
    y_c = (right[:, 1].min() + right[:, 1].max() + left[:, 1].min() + left[:, 1].max()) / 4.0
    z_lo = max(float((v @ R[:, 2]).min()) for v in smp.right + smp.left)
    z_hi = min(float((v @ R[:, 2]).max()) for v in smp.right + smp.left)
    if z_hi <= z_lo:
        raise SettingsError(f"pads: no part of the pad faces faces the TCP at every width (they travel "
                            f"{z_lo - z_hi:.4g} m more along the approach than they are long)")
    z_c = (z_lo + z_hi) / 2.0
    if z_c <= 0.0:
        raise SettingsError("body: the pads are not in front of the hand's base along the approach; give the hand's "
                            "base body with body:")
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = R @ [x_c, y_c, z_c]
    size = (float(np.ptp(right[:, 0])), float(np.ptp(right[:, 1])), z_hi - z_lo)
    return np.linalg.inv(T), size, max(float(w[-1]), 0.0), float(w[0])


def _moving(smp: _Samples) -> set[str]:
    """Links that move over the stroke."""
    first, last = smp.poses[0], smp.poses[-1]
    return {n for n in first if not np.allclose(first[n], last[n], atol=1e-7)}


def _side_links(motion: HandMotion, smp: _Samples, T: np.ndarray) -> tuple[list, list, list]:
    """(static, left, right) links of the hand, the moving ones by the side of their open pose (TCP x)."""
    moving = _moving(smp)
    static, left, right = [], [], []
    for name, pose in smp.poses[0].items():
        link = motion.tree.links[name]
        if name not in moving:
            static.append(name)
            continue
        if link.geoms:
            x = np.mean([(T @ pose @ g.pose)[0, 3] for g in link.geoms])
        else:
            x = (T @ pose)[0, 3]
        (right if x > 0 else left).append(name)
    return static, left, right


def _pieces(motion: HandMotion, smp: _Samples, T: np.ndarray, links, skip=None) -> list[Shape]:
    out: list[Shape] = []
    for name in links:
        link = motion.tree.links[name]
        if skip is not None and skip[0] == name:
            link = replace(link, geoms=tuple(g for k, g in enumerate(link.geoms) if k != skip[1]))
        out += shapes_of(link, T @ smp.poses[0][name], f"model body {name}")
    return out


def _revolute_y(motion: HandMotion, smp: _Samples, T: np.ndarray, joint) -> tuple[float, float] | None:
    """(x, z) (m, TCP frame) of the axis of a revolute joint turning about the TCP y axis (open pose), or None."""
    if joint.type not in ("revolute", "continuous"):
        return None
    frame = T @ smp.poses[0][joint.parent] @ joint.origin
    axis = frame[:3, :3] @ joint.axis
    if abs(abs(axis[1]) - 1.0) > 1e-4:
        return None
    point = frame @ np.array([*joint.anchor, 1.0])  # the joint turns about its anchor (MJCF pos), fixed by its turn
    return float(point[0]), float(point[2])


def _linkage(motion: HandMotion, smp: _Samples, T: np.ndarray, right: list, pad, pieces) -> tuple:
    """(Linkage, coupler links) of the right finger: its pad's chain must hold two revolute joints about y."""
    names = motion.moving
    chain = [j for j in motion.tree.chain(motion.root, pad[0]) if j.name in names]
    if len(chain) != 2 or any(_revolute_y(motion, smp, T, j) is None for j in chain):
        raise SettingsError(f"pads: the pad {pad[0]!r} neither slides along the closing direction nor rides a "
                            f"parallelogram of two revolute joints about y (its moving joints: "
                            f"{', '.join(j.name for j in chain)}); graspgen simulates those parallel-jaw kinds")
    driver, coupler = chain
    pivot, joint = _revolute_y(motion, smp, T, driver), _revolute_y(motion, smp, T, coupler)
    below = {n: [j.name for j in motion.tree.chain(motion.root, n)] for n in right}
    coupler_links = [n for n in right if coupler.name in below[n]]
    driver_links = [n for n in right if driver.name in below[n] and n not in coupler_links]
    rest = [n for n in right if n not in coupler_links and n not in driver_links]
    follower = next((j for n in rest for j in motion.tree.chain(motion.root, n)
                     if j.name in names and _revolute_y(motion, smp, T, j) is not None), None)
    follower_links = [] if follower is None else [n for n in rest if follower.name in below[n]]
    mass = {k: sum(motion.tree.links[n].mass for n in v) for k, v in
            (("driver_mass", driver_links), ("follower_mass", follower_links))}
    linkage = Linkage(pivot=pivot, crank=(joint[0] - pivot[0], joint[1] - pivot[1]),
                      follower_pivot=pivot if follower is None else _revolute_y(motion, smp, T, follower),
                      driver_geoms=tuple(pieces(driver_links)), follower_geoms=tuple(pieces(follower_links)),
                      **{k: v for k, v in mass.items() if v > 0})
    return linkage, coupler_links


def _loops_note(motion: HandMotion) -> str:
    """' (its loops ... closed by MuJoCo)' for a hand with loops, else ''."""
    if motion.loops is None:
        return ""
    return f" (with its loops {', '.join(motion.loops.equalities)} closed by MuJoCo)"


def _check_turn(motion: HandMotion, smp: _Samples, pad: str, tolerance: float) -> float:
    """The largest turn (degrees) of the right pad body over the stroke; :class:`SettingsError` over ``tolerance``
    (degrees), naming the gripper-file key that raises it where that would do."""
    turn = float(np.degrees(max(_turn(smp.poses[0][pad][:3, :3], poses[pad][:3, :3]) for poses in smp.poses)))
    if turn > tolerance:
        hint = ""
        if math.floor(turn) + 1 <= MAX_PAD_TURN_TOLERANCE:
            hint = (f"; to accept it, give pad_turn_tolerance: {math.floor(turn) + 1} (degrees) in the gripper file: "
                    "the derived gripper keeps its pads parallel, the turn is ignored")
        raise SettingsError(f"pads: the pad body {pad!r} turns {turn:.2f} degrees while closing{_loops_note(motion)}, "
                            f"more than pad_turn_tolerance ({tolerance:g} deg); graspgen simulates parallel-jaw "
                            f"grippers whose pads stay parallel{hint}")
    return turn


def _check_path(smp: _Samples, T: np.ndarray, pad: str, linkage: Linkage | None, motion: HandMotion) -> str:
    """The right pad's path against the kinematics chosen; returns 'slide' or 'linkage'."""
    p = np.array([(T @ poses[pad])[:3, 3] for poses in smp.poses])
    d = p - p[0]
    if linkage is None:
        return "slide"
    err = float(np.abs(linkage.rise(d[:, 0]) - d[:, 2]).max())
    if err > _LINKAGE_TOL:
        raise SettingsError(f"pads: the pad's path{_loops_note(motion)} is not the parallelogram linkage of its "
                            f"joints (off by {err * 1e3:.2f} mm)")
    return "linkage"


def _slides(smp: _Samples, T: np.ndarray, pad: str) -> bool:
    p = np.array([(T @ poses[pad])[:3, 3] for poses in smp.poses])
    return float(np.abs(p[:, 1:] - p[0, 1:]).max()) <= _SLIDE_TOL


def _drive(motion: HandMotion, smp: _Samples, stroke: float, given: dict) -> tuple[float, float, str]:
    """(force_limit N, closing_speed m/s, note): given values, else the prismatic closing joints' effort limit and
    the closing joints' velocity limits; :class:`SettingsError` naming the key when the model does not say."""
    joints = {j.name: j for j in motion.tree.joints}
    closing = [joints[n] for n in motion.closing]
    notes = []
    force = given.get("force_limit")
    if force is None and motion.actuator and motion.tree.actuators[motion.actuator][1] > 0:
        if any(j.type != "prismatic" for j in closing):
            raise SettingsError(f"force_limit: the actuator {motion.actuator!r} turns its joints (a torque, not a "
                                "grip force); give force_limit (N, e.g. the data sheet's)")
        force = motion.tree.actuators[motion.actuator][1]
        notes.append(f"force {force:g} N: actuator {motion.actuator}'s force range")
    if force is None:
        efforts = [j.effort for j in closing if j.type == "prismatic" and j.effort > 0]
        if len(efforts) != len(closing):
            raise SettingsError("force_limit: the model gives no grip force (an effort limit of a revolute joint is "
                                "a torque, not a grip force); give force_limit (N, e.g. the data sheet's)")
        force = min(efforts)
        notes.append(f"force {force:g} N: the closing joints' effort limit")
    speed = given.get("closing_speed")
    if speed is None:
        frac = abs(smp.s[-1] - smp.s[0])
        if any(j.velocity <= 0 for j in closing):
            raise SettingsError("closing_speed: the model gives the closing joints no velocity limit; give "
                                "closing_speed (m/s of the width)")
        seconds = max(abs(b - a) * frac / joints[n].velocity for n, (a, b) in motion.closing.items())
        speed = stroke / seconds
        notes.append(f"closing speed {speed:.3g} m/s: the joints' velocity limits")
    return float(force), float(speed), "; ".join(notes)


def _masses(motion: HandMotion, static: list, fingers: list, given: dict) -> tuple[float, float]:
    """(body_mass, finger_mass) kg: given, else the links' inertial masses."""
    out = []
    for key, links in (("body_mass", static), ("finger_mass", fingers)):
        value = given.get(key, sum(motion.tree.links[n].mass for n in links))
        if not value or value <= 0:
            raise SettingsError(f"{key}: the model gives {', '.join(links) or 'these links'} no mass; give {key} (kg)")
        out.append(float(value))
    return out[0], out[1]


def build_spec(ref: ModelRef, motion: HandMotion, pads, *, file: str = "") -> GripperSpec:
    """The :class:`GripperSpec` of ``motion`` with pads ``pads`` ((link, geom index) left, right): see
    :mod:`graspgen.sim.gripper_import`. :class:`SettingsError` names what could not be derived."""
    given = dict(ref.overrides)
    smp, R = _stroke(motion, pads, ref)
    T, pad_size, min_width, max_width = _tcp(smp, R)
    static, left, right = _side_links(motion, smp, T)
    if pads[1][0] not in right or pads[0][0] not in left:
        raise SettingsError("pads: each pad must be on a finger that the closing joints move")

    def pieces(links, skip=None):
        return _pieces(motion, smp, T, links, skip)
    pad_link = motion.tree.links[pads[1][0]]
    pad_shape = shapes_of(replace(pad_link, geoms=(pad_link.geoms[pads[1][1]],)), T @ smp.poses[0][pads[1][0]],
                          "pads")
    if len(pad_shape) != 1:
        raise SettingsError(f"pads: the right pad geom of {pads[1][0]!r} is not convex; name a convex geom")
    gap = mirrored_bounds_gap(pieces(right), pieces(left))
    if gap > _MIRROR_TOL:
        raise SettingsError(f"pads: the left finger is not the right one turned 180 degrees about the approach axis "
                            f"(bounds differ by {gap * 1e3:.1f} mm); graspgen mirrors the right finger")
    linkage, fingers = None, right
    if not _slides(smp, T, pads[1][0]):
        linkage, fingers = _linkage(motion, smp, T, right, pads[1], pieces)
    turn = _check_turn(motion, smp, pads[1][0], ref.pad_turn_tolerance)
    kind = _check_path(smp, T, pads[1][0], linkage, motion)
    if motion.loops is not None:
        kind += f", loops {', '.join(motion.loops.equalities)} closed by MuJoCo"
    turned = "" if turn < _NAMED_TURN else (
        f"; the pads turn {turn:.2f} degrees while closing (pad_turn_tolerance {ref.pad_turn_tolerance:g} deg): "
        "simulated parallel, the turn ignored")
    body_mass, finger_mass = _masses(motion, static, fingers, given)
    force, speed, notes = _drive(motion, smp, max_width - min_width, given)
    palm = pieces(static)
    if not palm:
        raise SettingsError(f"body: the hand's base ({motion.root}) has no collision geometry below it that stays "
                            "still while closing")
    source = (given.get("source") or (
        f"derived from {Path(ref.path).name} (hand {motion.root}; pads {ref.pads[0]}, {ref.pads[1]}; closing "
        f"joints {', '.join(motion.closing)}; {kind}){'; ' + notes if notes else ''}")) + turned
    finger_size = _finger_size(pad_shape + pieces(fingers, skip=pads[1]))
    pad_size = (*pad_size[:2], min(pad_size[2], finger_size[2]))  # the shared face lies within the finger
    return GripperSpec(
        name=given["name"], min_width=min_width, max_width=max_width, pad_size=pad_size, finger_size=finger_size,
        pad_friction=given.get("pad_friction", (1.0, 0.005, 0.0001)), palm_boxes=(), tcp_offset=_offset(T),
        force_limit=force, finger_mass=finger_mass, body_mass=body_mass, closing_speed=speed,
        pad_condim=given.get("pad_condim", 4), source=source, palm_geoms=tuple(palm),
        finger_geoms=tuple(pieces(fingers, skip=pads[1])), pad_geom=pad_shape[0], linkage=linkage, file=file,
        model_files=motion.tree.files)


def _offset(T: np.ndarray) -> float:
    """The TCP's height over the base along the approach: the base origin's -z in the TCP frame."""
    return float(-T[2, 3])


def _finger_size(shapes: list[Shape]) -> tuple[float, float, float]:
    lo, hi = bounds_of(shapes)
    return tuple(float(v) for v in hi - lo)
