"""Static collision pre-filter for grasp candidates: MuJoCo collision detection on the real gripper geoms, no dynamics.

A candidate is a TCP pose in the world and a contact width. The gripper is opened to ``width + width_margin``
(clipped to the gripper's range: the rollout opens it the same way), then placed at ``num_approach_samples`` poses
along its approach line, from the pre-grasp pose ``approach_distance`` back along the approach axis (-z of the TCP
frame) to the grasp pose itself. At each pose only ``mj_kinematics`` + ``mj_collision`` run (no ``mj_step``), and
every contact between a gripper geom and another geom with signed distance ``< margin`` is a collision, except that a
finger may touch the target up to :data:`TARGET_TOUCH_DEPTH` deep (the touch rule below).

Result codes (the rollout outcome codes of ARCHITECTURE.md for the same events):

* ``-1`` (:data:`FREE`): no collision at any checked pose;
* ``0`` (:data:`GROUND`): the gripper hits the ground or a support (any geom that is not part of an object);
* ``1`` (:data:`TARGET`): the gripper hits the target object, by the touch rule below. This includes the final
  grasp pose: the *open* fingers must not press into the target there (the grasp closes from
  ``width + width_margin``);
* ``2`` (:data:`CLUTTER`): the gripper hits another object.

The touch rule (the same in the rollout, :class:`graspgen.sim.lift.LiftSimulator`, so code 1 means one thing): a
finger (a geom of either jaw: pad or finger link) may touch the target, pressing up to :data:`TARGET_TOUCH_DEPTH`
into it, as a real finger brushes an object on the way in; deeper is a collision. Any other gripper geom (the palm)
touching the target is a collision. Here the depth is MuJoCo's penetration depth (``-dist``) at the checked pose; a
contact with the ground, a support or another object counts at any depth (``dist < margin``). ``margin`` shifts the
target's limits too: a finger hits the target when ``dist < margin - TARGET_TOUCH_DEPTH``, the palm when
``dist < margin``. Which geoms are fingers: :func:`touch_allowance` (the jaw bodies' geoms). The rollout runs this
same static check at each of its checks of placement and approach, on the gripper as commanded and the scene as it
stood (``LiftSimulator._static_code``), besides its live contacts and the objects' motion.

Which reason is reported: the poses are checked in the order the gripper moves (pre-grasp first, grasp pose last)
and the first pose with a collision decides, as it would in a rollout; when that pose collides with several kinds of
geom, the smallest code wins (ground before target before clutter). The approach line is sampled, not swept: an
obstacle thinner than the spacing ``approach_distance / (num_approach_samples - 1)`` can slip between two samples.

Scene conventions (how geoms are classified): a geom belongs to the body tree rooted at a child of the world body.
Roots named ``obj/...`` (``obj/<index>_<name>``) are objects; the target is named by its root body; every other
non-gripper geom (a plane named ``ground``, ``support/...`` geoms, anything else static) is ground/support. Gripper
geoms are found by name (:func:`graspgen.sim.gripper_state.gripper_geom_ids`).

Speed (why the checker owns a private compiled model): the world is compiled once with the gripper attached, one
:class:`mujoco.MjData` is reused, and the geoms' contact bitmasks are rewritten in that private model so that only
gripper-vs-other pairs are ever tested: objects resting on the table and on each other would otherwise cost most of
the collision time. A non-gripper geom keeps colliding with the gripper exactly when its original
``contype``/``conaffinity`` let it collide with the gripper geoms (visual-only geoms stay ignored). ``<exclude>``
elements are honoured by MuJoCo as in a rollout; contacts of explicit ``<pair>`` elements that do not involve the
gripper are ignored. Every non-gripper joint stays at its ``qpos0``: the scene is checked as the spec poses it.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from graspgen.errors import SettingsError
from graspgen.grippers import GripperSpec, jaw_opening
from graspgen.sim.gripper_model import attach_gripper
from graspgen.sim.gripper_state import gripper_geom_ids, linkage_couplings
from graspgen.validation import check_instance, check_number, check_positive_int, check_transforms

__all__ = [
    "FREE",
    "GROUND",
    "TARGET",
    "CLUTTER",
    "CODE_NAMES",
    "OBJECT_PREFIX",
    "PrefilterParams",
    "TARGET_TOUCH_DEPTH",
    "CollisionChecker",
    "approach_offsets",
    "touch_allowance",
]

FREE = -1
"""No collision."""
GROUND = 0
"""Collision with the ground or a support (rollout outcome ``collision_with_ground``)."""
TARGET = 1
"""Collision with the target object (rollout outcome ``collision_with_target``)."""
CLUTTER = 2
"""Collision with another object (rollout outcome ``collision_with_clutter``)."""
CODE_NAMES = {FREE: "free", GROUND: "collision_with_ground", TARGET: "collision_with_target",
              CLUTTER: "collision_with_clutter"}
"""Human-readable name of each code."""
OBJECT_PREFIX = "obj/"
"""Root bodies whose names start with this are objects (targets or clutter); everything else is support."""
TARGET_TOUCH_DEPTH = 0.002
"""How deep (m) a finger may press into the target before the touch is a collision with it (code 1): the touch
rule of the module docstring, applied by this pre-filter and by the rollout (:class:`graspgen.sim.lift.
LiftSimulator`) alike. The depth is MuJoCo's penetration depth of a jaw geom in the target as it stood before the
gripper came: here at each checked pose; in the rollout at each check of placement and approach, statically too, with
the gripper as commanded and the target at its initial pose (a pushed target yields, so its current contacts would
not tell how far a finger went into it). The palm gets no allowance.

Why 2 mm:

* It is well above MuJoCo's own penetration. Geoms here have no contact margin (MuJoCo's ``margin`` 0: a contact
  exists only where two geoms overlap, so "touching" is "overlapping"), and the soft contact solver lets a pressed
  contact sink in: with the gripper's contact softness (solref 4 ms, solimp 0.95-0.99 over 1 mm;
  :mod:`graspgen.sim.gripper_model`) a pad pressing with tens of newtons sits 0.1-0.3 mm inside the object. A tolerance
  at that scale would call a finger that merely rests on the surface in the simulation a collision; 2 mm is ~10x.
* It is what a brush is on a real hand: a pad or fingertip grazing a surface on the way in compresses its
  elastomer and flexes the finger by a millimetre or two without shoving the object. The jaws open to ``width +
  width_margin`` (10 mm of clearance per side by default), so a planned grasp only brushes through curvature, a
  tilted face or the convex decomposition's bulge over a concave region; a finger that has to go deeper than 2 mm
  runs into the object.
* It is below what moves the target: the rollout also calls a target that moved 5 mm or turned 5 degrees a
  collision (``LiftParams.max_target_shift``, ``max_target_turn``), and 2 mm is less than both (at the edge of a
  5 cm object 2 mm turn it 4.6 degrees), so a finger that presses deeper than the allowance is caught by depth,
  not only later by the motion it causes.
"""


# ---------------------------------------------------------------------------------------------------------------
# Argument checks (programmer errors -> ValueError naming the argument; the generic ones: graspgen.validation)
# ---------------------------------------------------------------------------------------------------------------


def _check_widths(widths: object, n: int) -> np.ndarray:
    w = np.asarray(widths, dtype=float)
    if w.shape != (n,):
        raise SettingsError(f"widths: must have shape ({n},) like T_world_tcp, got {w.shape}")
    if not np.isfinite(w).all() or (n and w.min() < 0):
        raise SettingsError("widths: must be finite and >= 0 (m)")
    return w


# ---------------------------------------------------------------------------------------------------------------
# Data
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PrefilterParams:
    """Settings of the static collision pre-filter."""

    approach_distance: float = 0.05
    """Distance (m, >= 0) of the pre-grasp pose behind the grasp pose, along the TCP's -z (the gripper starts
    there and moves along +z to the grasp). In a config it is the rollouts' ``physics.table.approach_distance``."""
    num_approach_samples: int = 11
    """Poses checked along the approach line, evenly spaced from the pre-grasp pose to the grasp pose (both
    included); 1 checks the grasp pose only. Default: 5 mm spacing over 0.05 m."""
    margin: float = 0.0
    """Clearance (m): a gripper contact with signed distance below this is a collision. 0 flags any penetration;
    > 0 demands that much clearance (conservative); < 0 tolerates penetration up to ``-margin``. A finger's contact
    with the target is a collision below ``margin - TARGET_TOUCH_DEPTH`` (the touch rule, module docstring); keep 0
    for labels that mean what the rollout's do."""
    width_margin: float = 0.02
    """The gripper is opened to ``width + width_margin`` (m, >= 0; clipped to the gripper's range). Use the same
    value as :attr:`graspgen.geometry.antipodal.AntipodalParams.width_margin` and as the rollout."""

    def __post_init__(self) -> None:
        check_number("approach_distance", self.approach_distance, low=0.0)
        check_positive_int("num_approach_samples", self.num_approach_samples)
        check_number("margin", self.margin)
        check_number("width_margin", self.width_margin, low=0.0)


def approach_offsets(params: PrefilterParams) -> np.ndarray:
    """Distances (m) behind the grasp pose, along -z, of the checked poses in motion order: ``(num_approach_samples,)``
    from ``approach_distance`` down to 0 (just ``[0]`` for one sample)."""
    if params.num_approach_samples == 1:
        return np.zeros(1)
    return np.linspace(params.approach_distance, 0.0, params.num_approach_samples)


def touch_allowance(model: mujoco.MjModel, *, prefix: str = "gripper/",
                    depth: float = TARGET_TOUCH_DEPTH) -> np.ndarray:
    """``(ngeom,) float``: how deep (m) each geom may press into the target before the touch is a collision (the
    touch rule of the module docstring): ``depth`` for the geoms of the bodies ``<prefix>left_jaw`` and
    ``<prefix>right_jaw`` and their descendants (pads and finger links), 0 for every other geom (the palm, and
    anything that is not the gripper's). The pre-filter and the rollout both classify the gripper's geoms with it."""
    jaws = []
    for side in ("left", "right"):
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"{prefix}{side}_jaw")
        if body < 0:
            raise SettingsError(f"model: no body named {prefix}{side}_jaw (gripper attached with another prefix?)")
        jaws.append(body)
    on_jaw = np.zeros(model.nbody, dtype=bool)
    for body in range(model.nbody):
        b = body
        while b > 0 and b not in jaws:
            b = int(model.body_parentid[b])
        on_jaw[body] = b > 0
    return np.where(on_jaw[model.geom_bodyid], float(depth), 0.0)


def _quats(R: np.ndarray) -> np.ndarray:
    """MuJoCo quaternions (w, x, y, z) of rotation matrices ``(n, 3, 3)``."""
    out = np.empty((len(R), 4))
    for i in range(len(R)):
        mujoco.mju_mat2Quat(out[i], np.ascontiguousarray(R[i]).reshape(-1))
    return out


class CollisionChecker:
    """Static gripper-vs-scene collision queries on one compiled world (see the module docstring).

    Parameters
    ----------
    world
        The scene as an :class:`mujoco.MjSpec`: support geoms, objects as bodies ``obj/<index>_<name>`` (mesh geoms)
        at their poses (free joints at ``qpos0`` = their spec pose). It is copied, never modified. If it already
        holds a gripper named ``name_prefix`` (a body ``<name_prefix>base``), that one is used (``gripper`` must
        describe it); otherwise ``gripper`` is attached with :func:`graspgen.sim.gripper_model.attach_gripper`. Every
        geom whose name starts with ``name_prefix`` is the gripper's.
    gripper
        The gripper whose geoms are checked; gives the opening range.
    params
        Approach line, margins.
    name_prefix
        Name prefix of the gripper's elements.
    """

    def __init__(self, world: mujoco.MjSpec, gripper: GripperSpec, params: PrefilterParams | None = None, *,
                 name_prefix: str = "gripper/") -> None:
        check_instance("world", world, mujoco.MjSpec, what="mujoco.MjSpec")
        check_instance("gripper", gripper, GripperSpec)
        params = check_instance("params", PrefilterParams() if params is None else params, PrefilterParams)
        self.gripper = gripper
        self.params = params
        self.prefix = name_prefix
        spec = world.copy()
        if spec.body(f"{name_prefix}base") is None:
            attach_gripper(spec, gripper, name_prefix=name_prefix)
        self._restrict_contacts(spec, name_prefix, params.margin)
        self.model = model = spec.compile()
        self.data = mujoco.MjData(model)
        self._offsets = approach_offsets(params)

        def joint_adr(name: str) -> int:
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if jid < 0:
                raise SettingsError(f"world: no joint {name!r} (gripper attached with another name_prefix?)")
            return int(model.jnt_qposadr[jid])

        self._free_adr = joint_adr(f"{name_prefix}free")
        self._jaw_adr = (joint_adr(f"{name_prefix}left_slide"), joint_adr(f"{name_prefix}right_slide"))
        self._couplings = linkage_couplings(model, prefix=name_prefix)  # a linkage's joints follow the jaws

        # Geom classes: -1 gripper (never reported), 0 support, 2 object; the target's geoms become 1 per call.
        try:
            gripper_geom_ids(model, prefix=name_prefix)  # the pads must be there
        except KeyError as exc:
            raise SettingsError(f"world: {exc.args[0]}") from None
        # Every geom named with the prefix is the gripper's (the same rule as _restrict_contacts).
        is_gripper = np.array([(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or "").startswith(name_prefix)
                               for g in range(model.ngeom)], dtype=bool)
        self._is_gripper = is_gripper
        self._allowance = touch_allowance(model, prefix=name_prefix)
        self._geom_root = model.body_rootid[model.geom_bodyid].astype(np.int64)
        root_names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(b)) or "" for b in self._geom_root]
        self._geom_code = np.where([n.startswith(OBJECT_PREFIX) for n in root_names], CLUTTER, GROUND).astype(np.int8)
        self._geom_code[is_gripper] = FREE
        self._body_roots = {mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b): int(model.body_rootid[b])
                            for b in range(1, model.nbody)}

    @staticmethod
    def _restrict_contacts(spec: mujoco.MjSpec, prefix: str, margin: float) -> None:
        """Rewrite contact masks and margins in the (private copy of the) spec, before compiling, so that MuJoCo's
        compiled body-level bounds (broadphase masks and margins) agree with the geoms'.

        Only gripper-vs-other pairs: gripper geoms get contype 2 / conaffinity 1; another geom keeps colliding with
        the gripper iff its original masks allowed it with some gripper geom, as contype 1 / conaffinity 0, which
        collides with conaffinity 1 but with no other non-gripper geom (1 & 0 == 0 both ways). MuJoCo reports a pair
        when its distance is below the larger of the two geom margins: only the gripper geoms get one, so exactly the
        contacts closer than ``max(margin, 0)`` are generated (and then filtered by ``dist < margin``).
        """
        geoms = list(spec.geoms)
        is_gripper = [(g.name or "").startswith(prefix) for g in geoms]
        masks = [(int(g.contype), int(g.conaffinity)) for g, grip in zip(geoms, is_gripper) if grip]
        for geom, grip in zip(geoms, is_gripper):
            if grip:
                # A gripper geom that collides with nothing (a visual mesh) stays that way.
                active = bool(geom.contype or geom.conaffinity)
                geom.contype, geom.conaffinity = (2, 1) if active else (0, 0)
                geom.margin = max(margin, 0.0)
            else:
                ct, ca = int(geom.contype), int(geom.conaffinity)
                collides = any((ct & g_ca) or (g_ct & ca) for g_ct, g_ca in masks)
                geom.contype, geom.conaffinity = (1 if collides else 0), 0
                geom.margin = 0.0
            geom.gap = 0.0

    # -----------------------------------------------------------------------------------------------------------

    def _target_root(self, name: str) -> int:
        if not isinstance(name, str) or name not in self._body_roots:
            raise SettingsError(f"target_body_name: no body named {name!r} in the world")
        if name.startswith(self.prefix):
            raise SettingsError(f"target_body_name: {name!r} is part of the gripper")
        return self._body_roots[name]

    def opening(self, widths) -> np.ndarray:
        """Jaw opening (m) used for contact widths ``widths (n,)``: ``width + width_margin`` clipped to the range."""
        return jaw_opening(widths, self.params.width_margin, self.gripper.min_width, self.gripper.max_width)

    def check(self, T_world_tcp, widths, target_body_name: str, *, return_steps: bool = False,
              ignore_target: bool = False):
        """Collision code of each candidate (see the module docstring).

        Parameters
        ----------
        T_world_tcp
            ``(n, 4, 4) float`` grasp (TCP) poses in the world frame.
        widths
            ``(n,) float`` contact widths (m); the gripper is opened to ``width + width_margin``.
        target_body_name
            Name of the target object's body (e.g. ``"obj/0_mug"``); contacts with any body in its tree are code 1.
        return_steps
            Also return ``(n,) int64``: the index of the first colliding pose along the approach (0 = pre-grasp,
            ``num_approach_samples - 1`` = grasp pose), -1 when free.
        ignore_target
            Contacts with the target are no collision (code 1 never reported): only support and clutter count,
            e.g. for grasps whose contact with the target was judged elsewhere (a free-space label).

        Returns
        -------
        codes : (n,) int8
            -1 free, 0 ground/support, 1 target, 2 clutter.
        """
        T = check_transforms("T_world_tcp", T_world_tcp)
        n = len(T)
        openings = self.opening(_check_widths(widths, n))
        target_root = self._target_root(target_body_name)
        geom_code = self._geom_code.copy()
        geom_code[(self._geom_root == target_root) & ~self._is_gripper] = TARGET

        model, data = self.model, self.data
        quats = _quats(T[:, :3, :3])
        # positions (n, S, 3): back along -z by each offset, in motion order.
        positions = T[:, None, :3, 3] - self._offsets[None, :, None] * T[:, None, :3, 2]
        codes = np.full(n, FREE, dtype=np.int8)
        steps = np.full(n, -1, dtype=np.int64)
        qpos = data.qpos
        a = self._free_adr
        left, right = self._jaw_adr
        is_gripper, allowance = self._is_gripper, self._allowance
        margin = self.params.margin
        for i in range(n):
            qpos[left] = qpos[right] = openings[i] / 2.0  # jaw joint = half the pad separation
            self._couplings.apply(qpos)
            qpos[a + 3:a + 7] = quats[i]
            for k in range(len(self._offsets)):
                qpos[a:a + 3] = positions[i, k]
                mujoco.mj_kinematics(model, data)
                mujoco.mj_collision(model, data)
                if data.ncon == 0:
                    continue
                contact = data.contact
                geom = contact.geom
                grip0, grip1 = is_gripper[geom[:, 0]], is_gripper[geom[:, 1]]
                # Exactly one gripper geom: explicit <pair> elements of the scene can still add object pairs.
                pair = grip0 ^ grip1
                if not pair.any():
                    continue
                other = np.where(grip0, geom[:, 1], geom[:, 0])
                mine = np.where(grip0, geom[:, 0], geom[:, 1])
                # The touch rule: a jaw geom may press up to its allowance into the target (module docstring).
                limit = margin - np.where(geom_code[other] == TARGET, allowance[mine], 0.0)
                hit = pair & (contact.dist < limit)
                if not hit.any():
                    continue
                other = other[hit]
                if ignore_target:
                    other = other[geom_code[other] != TARGET]
                    if not len(other):
                        continue
                codes[i] = geom_code[other].min()
                steps[i] = k
                break
        return (codes, steps) if return_steps else codes
