"""A robot model's kinematic tree as plain data (:class:`HandTree`: links with their collision geoms, joints with
their frames, axes, limits and mimic relations) and its forward kinematics, read from a URDF file
(:func:`read_urdf`) or an MJCF file (:mod:`graspgen.sim.hand_mjcf`). Only collision geometry is read: visual-only
geoms are ignored. :mod:`graspgen.sim.gripper_import` derives a gripper from it.

URDF conventions (ROS REP 103 / the URDF spec): lengths in metres, angles in radians, ``rpy`` fixed-axis roll, pitch,
yaw (R = Rz(yaw) Ry(pitch) Rx(roll)); a joint's ``origin`` is the child link's frame in the parent link's frame at
q = 0; revolute / continuous joints turn about ``axis`` (in the joint frame), prismatic ones slide along it; a
``mimic`` joint follows ``q = multiplier * q_source + offset``. Mesh files ``package://PKG/rest`` are looked up in
the nearest folder named ``PKG`` above the URDF file (how ROS packages are laid out in share folders).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from graspgen.errors import SettingsError
from graspgen.grippers.files import read_mesh_file

__all__ = ["Geom", "Joint", "Link", "HandTree", "read_urdf", "rpy_matrix", "joint_motion"]

#: Joint types the tree knows (MJCF hinge -> revolute, slide -> prismatic); others are refused.
JOINT_TYPES = ("fixed", "revolute", "continuous", "prismatic")


@dataclass(frozen=True)
class Geom:
    """One collision geom of a link."""

    name: str
    """Its name in the file ('' when it has none)."""
    pose: np.ndarray = field(repr=False)
    """(4, 4) pose of the geom's frame in its link's frame (m)."""
    mesh: trimesh.Trimesh = field(repr=False)
    """Its surface in the geom frame (m): a box, cylinder or sphere as triangles, or the (scaled) mesh file."""
    box: tuple[float, float, float] | None = None
    """Full extents (m) when the geom is a box (centred on its frame), else None."""
    convex: bool = True
    """Whether the geom is convex as given (primitives); a mesh file's geom is checked by the importer."""
    file: str = ""
    """The mesh file it was read from ('' for primitives)."""


@dataclass(frozen=True)
class Link:
    """A link (MJCF body): its collision geoms and inertial mass."""

    name: str
    """Its name in the file."""
    geoms: tuple[Geom, ...]
    """Its collision geoms (visual-only geoms are not read)."""
    mass: float = 0.0
    """Inertial mass (kg), 0 when the file gives none."""


@dataclass(frozen=True)
class Joint:
    """A joint between two links."""

    name: str
    """Its name in the file."""
    type: str
    """One of :data:`JOINT_TYPES`."""
    parent: str
    """Parent link name."""
    child: str
    """Child link name."""
    origin: np.ndarray = field(repr=False)
    """(4, 4) child link frame in the parent link frame at q = 0 (m)."""
    axis: np.ndarray = field(repr=False)
    """(3,) unit axis in the joint (child) frame."""
    lower: float = 0.0
    """Lower limit (rad or m); -inf when unlimited."""
    upper: float = 0.0
    """Upper limit (rad or m); +inf when unlimited."""
    velocity: float = 0.0
    """Velocity limit (rad/s or m/s), 0 when not given."""
    effort: float = 0.0
    """Effort limit (N m or N), 0 when not given."""
    mimic: tuple[str, float, float] | None = None
    """(source joint, multiplier, offset): q = multiplier * q_source + offset; None when independent."""
    anchor: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Point (m, child frame) the axis passes through (MJCF joints; URDF: the child frame's origin)."""
    ref: float = 0.0
    """Joint value (rad or m) at which the child sits at ``origin`` (MJCF ``ref``; URDF 0)."""


@dataclass(frozen=True)
class HandTree:
    """A model's links and joints (a tree: each link is the child of at most one joint)."""

    path: str
    """The model file."""
    links: dict[str, Link] = field(repr=False)
    """Links by name."""
    joints: tuple[Joint, ...] = field(repr=False)
    """Joints, in file order."""
    files: tuple[str, ...] = ()
    """Every file read: the model file, then its mesh files."""
    actuators: dict = field(default_factory=dict, repr=False)
    """MJCF actuator name -> (its joints, the force limit on each (N for a slide, N m for a hinge; 0: none)); empty
    for URDF, which has no actuators."""
    loops: dict = field(default_factory=dict, repr=False)
    """MJCF equality name -> the bodies it ties, for each active equality that closes a kinematic loop (connect,
    weld, tendon and non-linear joint couplings; :mod:`graspgen.sim.hand_loops` resolves them); empty for URDF."""

    def root(self) -> str:
        """The link that is no joint's child (:class:`SettingsError` if there is not exactly one)."""
        roots = sorted(set(self.links) - {j.child for j in self.joints})
        if len(roots) != 1:
            raise SettingsError(f"model {self.path}: {len(roots)} root links ({', '.join(roots[:5])}); give body:")
        return roots[0]

    def subtree(self, body: str) -> list[str]:
        """``body`` and every link below it, parents before children."""
        if body not in self.links:
            raise SettingsError(f"body: no body {body!r} in {Path(self.path).name}; bodies: "
                                f"{', '.join(sorted(self.links))}")
        out, todo = [], [body]
        while todo:
            name = todo.pop(0)
            out.append(name)
            todo += [j.child for j in self.joints if j.parent == name]
        return out

    def parent_joint(self, link: str) -> Joint | None:
        """The joint whose child is ``link`` (None for the root)."""
        return next((j for j in self.joints if j.child == link), None)

    def chain(self, root: str, link: str) -> list[Joint]:
        """The joints from ``root`` down to ``link``."""
        out = []
        while link != root:
            joint = self.parent_joint(link)
            if joint is None:
                raise SettingsError(f"{link!r} is not below body {root!r}")
            out.insert(0, joint)
            link = joint.parent
        return out

    def poses(self, root: str, q: dict[str, float]) -> dict[str, np.ndarray]:
        """(4, 4) pose of every link of ``root``'s subtree in ``root``'s frame, with joint values ``q`` (by name;
        missing joints at 0)."""
        out = {root: np.eye(4)}
        for name in self.subtree(root)[1:]:
            joint = self.parent_joint(name)
            out[name] = out[joint.parent] @ joint.origin @ joint_motion(joint, q.get(joint.name, 0.0))
        return out


def rpy_matrix(rpy) -> np.ndarray:
    """(3, 3) rotation of URDF ``rpy`` (rad): Rz(yaw) @ Ry(pitch) @ Rx(roll)."""
    r, p, y = (float(a) for a in rpy)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def joint_motion(joint: Joint, q: float) -> np.ndarray:
    """(4, 4) motion of ``joint`` at value ``q``: a turn by ``q - ref`` about its axis through its anchor
    (revolute) or a slide by ``q - ref`` along it (prismatic)."""
    T = np.eye(4)
    q = q - joint.ref
    if joint.type in ("revolute", "continuous"):
        a = joint.axis
        K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
        T[:3, :3] = np.eye(3) + np.sin(q) * K + (1.0 - np.cos(q)) * K @ K
        p = np.asarray(joint.anchor, dtype=float)
        T[:3, 3] = p - T[:3, :3] @ p
    elif joint.type == "prismatic":
        T[:3, 3] = joint.axis * q
    return T


def _origin(elem: ET.Element | None) -> np.ndarray:
    T = np.eye(4)
    if elem is not None:
        T[:3, :3] = rpy_matrix([float(v) for v in elem.get("rpy", "0 0 0").split()])
        T[:3, 3] = [float(v) for v in elem.get("xyz", "0 0 0").split()]
    return T


def _mesh_file(uri: str, urdf: Path) -> Path:
    """The file of a URDF mesh ``filename``: ``package://PKG/rest`` in the nearest folder named PKG above the URDF,
    ``file://path``, or a path relative to the URDF."""
    if uri.startswith("package://"):
        package, _, rest = uri.removeprefix("package://").partition("/")
        for folder in urdf.parents:
            if folder.name == package:
                return folder / rest
        raise SettingsError(f"model {urdf.name}: mesh {uri}: no folder named {package!r} above the URDF")
    return (urdf.parent / uri.removeprefix("file://")).resolve()


def _geometry(elem: ET.Element, urdf: Path, where: str) -> tuple[trimesh.Trimesh, tuple | None, bool, str]:
    """(surface, box extents or None, convex, file) of a URDF ``<geometry>``."""
    shape = next(iter(elem), None)
    tag = None if shape is None else shape.tag
    if tag == "box":
        size = tuple(float(v) for v in shape.get("size").split())
        return trimesh.creation.box(extents=size), size, True, ""
    if tag == "cylinder":
        r, length = float(shape.get("radius")), float(shape.get("length"))
        return trimesh.creation.cylinder(radius=r, height=length, sections=32), None, True, ""
    if tag == "sphere":
        return trimesh.creation.icosphere(subdivisions=2, radius=float(shape.get("radius"))), None, True, ""
    if tag == "mesh":
        path = _mesh_file(shape.get("filename", ""), urdf)
        mesh = read_mesh_file(path, where)
        scale = [float(v) for v in shape.get("scale", "1 1 1").split()]
        mesh.apply_transform(np.diag([*scale, 1.0]))
        return mesh, None, False, str(path)
    raise SettingsError(f"{where}: geometry {tag!r} not supported (box, cylinder, sphere, mesh)")


def read_urdf(path: str | Path) -> HandTree:
    """The :class:`HandTree` of a URDF file (collision geoms only). :class:`SettingsError` on what it cannot read."""
    urdf = Path(path)
    try:
        # Tags of other tools' namespaces (drake:, gazebo:, ...) often come undeclared: keep them, unprefixed.
        text = re.sub(r"<(/?)([A-Za-z_][\w.-]*):", r"<\1\2_", urdf.read_text(encoding="utf-8"))
        root = ET.fromstring(text)
    except (OSError, UnicodeDecodeError, ET.ParseError) as exc:
        raise SettingsError(f"model {urdf}: cannot read it as URDF ({exc})") from None
    links, files = {}, [str(urdf)]
    for link in root.findall("link"):
        name = link.get("name")
        geoms = []
        for k, col in enumerate(link.findall("collision")):
            where = f"model {urdf.name}: link {name} collision {k}"
            mesh, box, convex, file = _geometry(col.find("geometry"), urdf, where)
            geoms.append(Geom(name=col.get("name", ""), pose=_origin(col.find("origin")), mesh=mesh, box=box,
                              convex=convex, file=file))
            if file and file not in files:
                files.append(file)
        mass = link.find("inertial/mass")
        links[name] = Link(name=name, geoms=tuple(geoms), mass=0.0 if mass is None else float(mass.get("value")))
    joints = []
    for j in root.findall("joint"):
        kind = j.get("type")
        if kind not in JOINT_TYPES:
            raise SettingsError(f"model {urdf.name}: joint {j.get('name')}: type {kind!r} not supported "
                                f"({', '.join(JOINT_TYPES)})")
        axis = np.array([float(v) for v in (j.find("axis").get("xyz") if j.find("axis") is not None
                                            else "1 0 0").split()])
        limit, mimic = j.find("limit"), j.find("mimic")
        lo, hi = (-np.inf, np.inf) if kind == "continuous" or limit is None else (
            float(limit.get("lower", 0.0)), float(limit.get("upper", 0.0)))
        joints.append(Joint(
            name=j.get("name"), type=kind, parent=j.find("parent").get("link"), child=j.find("child").get("link"),
            origin=_origin(j.find("origin")), axis=axis / np.linalg.norm(axis), lower=lo, upper=hi,
            velocity=0.0 if limit is None else float(limit.get("velocity", 0.0)),
            effort=0.0 if limit is None else float(limit.get("effort", 0.0)),
            mimic=None if mimic is None else (mimic.get("joint"), float(mimic.get("multiplier", 1.0)),
                                              float(mimic.get("offset", 0.0)))))
    return HandTree(path=str(urdf), links=links, joints=tuple(joints), files=tuple(files))
