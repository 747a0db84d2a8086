"""The simulator's side of a compiled scene: what :class:`graspgen.sim.lift.LiftSimulator` (and the MuJoCo Warp
backend through it) looks up and writes once, before any rollout.

:func:`index_scene` finds the gripper's elements by name and gives every geom its side of the hand and its role
(:class:`LiftIndex`); :func:`set_grip` writes a protocol's force limit and jaw damping; :func:`apply_contact_overrides`
the ``acronym`` protocol's contact settings; :class:`StaticCheck` is the pre-filter's static collision check on a
private copy of the model.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import mujoco
import numpy as np

from graspgen.errors import SettingsError
from graspgen.sim.gripper_state import LinkageCouplings, linkage_couplings, pad_geom_ids
from graspgen.sim.lift_rules import CLUTTER, GRIPPER, LEFT, NOT_GRIPPER, PALM, RIGHT, SUPPORT, TARGET
from graspgen.sim.protocol_phases import protocol_of
from graspgen.sim.protocols import AcronymParams, LiftParams

__all__ = ["LiftIndex", "StaticCheck", "apply_contact_overrides", "index_scene", "set_grip"]


@dataclass(frozen=True, eq=False)
class LiftIndex:
    """Ids of the gripper's elements and the role of every geom in one compiled scene (:func:`index_scene`)."""

    act: int
    """The width actuator."""
    base: int
    """The hand's base body (its frame is the TCP frame)."""
    mocap: int
    """Index of the gripper's mocap body in ``data.mocap_pos`` / ``mocap_quat``."""
    base_qadr: int
    """qpos address of the gripper's free joint (position 3, quaternion 4)."""
    jaw_qadr: np.ndarray
    """``(2,) int64`` qpos addresses of the left and right jaw slides (each is half the pad separation)."""
    jaw_vadr: np.ndarray
    """``(2,) int64`` dof addresses of the jaw slides."""
    couplings: LinkageCouplings
    """The finger linkage's joint couplings (:func:`graspgen.sim.gripper_state.linkage_couplings`; ``.apply(qpos)``
    sets the linkage's joints from the jaws')."""
    min_width: float
    """Smallest pad separation (m): the width actuator's control range."""
    max_width: float
    """Largest pad separation (m)."""
    geom_side: np.ndarray
    """``(ngeom,) int8``: 0 left jaw, 1 right jaw, 2 palm/base, -1 not the gripper."""
    geom_is_gripper: np.ndarray
    """``(ngeom,) bool``."""
    geom_static: np.ndarray
    """``(ngeom,) bool``: support (fixed to the world or a mocap body, or named ``ground`` / ``support/...``), not
    the gripper."""
    geom_root: np.ndarray
    """``(ngeom,) int64`` root body of each geom."""
    objects: np.ndarray
    """``(n,) int64`` the movable object bodies (free roots that are not the gripper)."""
    object_names: tuple[str, ...]
    """Their names."""

    def roles(self, body: int) -> np.ndarray:
        """``(ngeom,) int8`` geom roles with ``body`` as the target: 0 support, 1 target, 2 clutter, 3 gripper (the
        first three are the outcome codes of a gripper touching them at placement)."""
        roles = np.where(self.geom_root == body, TARGET, CLUTTER).astype(np.int8)
        roles[self.geom_static] = SUPPORT
        roles[self.geom_is_gripper] = GRIPPER
        return roles


def _lookup(m: mujoco.MjModel, prefix: str, objtype, local: str) -> int:
    idx = mujoco.mj_name2id(m, objtype, prefix + local)
    if idx < 0:
        kind = mujoco.mjtObj(objtype).name.removeprefix("mjOBJ_").lower()
        raise SettingsError(f"model: no {kind} named {prefix + local!r} (is the gripper attached with "
                            f"prefix {prefix!r}?)")
    return idx


def _is_descendant(m: mujoco.MjModel, body: int, ancestor: int) -> bool:
    parent = m.body_parentid
    while body > 0:
        if body == ancestor:
            return True
        body = int(parent[body])
    return ancestor == 0


def _body_sides(m: mujoco.MjModel, base: int, jaw_bodies: list[int]) -> np.ndarray:
    """``(nbody,) int8`` side of the hand of every body (as :attr:`LiftIndex.geom_side`)."""
    gripper_root = int(m.body_rootid[base])
    body_side = np.full(m.nbody, NOT_GRIPPER, dtype=np.int8)
    for b in range(m.nbody):
        if m.body_rootid[b] == gripper_root:
            body_side[b] = PALM
    for side, jaw in ((LEFT, jaw_bodies[0]), (RIGHT, jaw_bodies[1])):
        for b in range(m.nbody):
            if _is_descendant(m, b, jaw):
                body_side[b] = side
    return body_side


def index_scene(m: mujoco.MjModel, prefix: str) -> LiftIndex:
    """The :class:`LiftIndex` of compiled scene ``m`` whose gripper's names start with ``prefix``; SettingsError
    naming ``model`` when an element is missing."""
    K = mujoco.mjtObj
    act = _lookup(m, prefix, K.mjOBJ_ACTUATOR, "width")
    base = _lookup(m, prefix, K.mjOBJ_BODY, "base")
    mocap = int(m.body_mocapid[_lookup(m, prefix, K.mjOBJ_BODY, "mocap")])
    if mocap < 0:
        raise SettingsError(f"model: body {prefix + 'mocap'!r} is not a mocap body")
    free = _lookup(m, prefix, K.mjOBJ_JOINT, "free")
    jaw_joints = [_lookup(m, prefix, K.mjOBJ_JOINT, f"{side}_slide") for side in ("left", "right")]
    couplings = linkage_couplings(m, prefix=prefix)  # a finger linkage's joints follow the jaws
    jaw_bodies = [_lookup(m, prefix, K.mjOBJ_BODY, f"{side}_jaw") for side in ("left", "right")]
    min_width, max_width = (float(v) for v in m.actuator_ctrlrange[act])
    body_side = _body_sides(m, base, jaw_bodies)
    geom_side = body_side[m.geom_bodyid]
    geom_is_gripper = geom_side != NOT_GRIPPER
    weld = m.body_weldid[m.geom_bodyid]
    static = (weld == 0) | (m.body_mocapid[weld] >= 0)
    names = [mujoco.mj_id2name(m, K.mjOBJ_GEOM, g) or "" for g in range(m.ngeom)]
    named_support = np.array([n == "ground" or n.startswith("support/") for n in names], dtype=bool)
    # Objects: movable root bodies that are not the gripper (free bodies under the world).
    objects = [b for b in range(1, m.nbody)
               if m.body_rootid[b] == b and body_side[b] == NOT_GRIPPER and m.body_weldid[b] != 0
               and m.body_mocapid[b] < 0]
    return LiftIndex(
        act=act, base=base, mocap=mocap, base_qadr=int(m.jnt_qposadr[free]),
        jaw_qadr=np.array([int(m.jnt_qposadr[j]) for j in jaw_joints], dtype=np.int64),
        jaw_vadr=np.array([int(m.jnt_dofadr[j]) for j in jaw_joints], dtype=np.int64),
        couplings=couplings, min_width=min_width, max_width=max_width, geom_side=geom_side,
        geom_is_gripper=geom_is_gripper, geom_static=(static | named_support) & ~geom_is_gripper,
        geom_root=m.body_rootid[m.geom_bodyid].astype(np.int64), objects=np.array(objects, dtype=np.int64),
        object_names=tuple(mujoco.mj_id2name(m, K.mjOBJ_BODY, b) or "" for b in objects))


def set_grip(m: mujoco.MjModel, params: LiftParams, index: LiftIndex) -> tuple[float, float]:
    """Write the protocol's grip into ``m``: the width actuator's force limit and the jaw damping, rescaled so the
    jaws close at the gripper's own closing speed (``table``) or at the protocol's ``closing_speed``.

    Returns
    -------
    grip_force : float
        Force (N) each jaw presses with.
    closing_speed : float
        Width rate (m/s) of the closing jaws when nothing is in the way (inf for an undamped model).
    """
    # grippers.py sets damping = 2 * force_limit / closing_speed per jaw, so a saturated actuator closes the
    # width at closing_speed; keep that ratio for the new force limit.
    act, jaw_vadr = index.act, index.jaw_vadr
    model_force = float(m.actuator_forcerange[act][1])
    damping = float(m.dof_damping[jaw_vadr[0]])
    closing_speed = 2.0 * model_force / damping if damping > 0 else math.inf
    free = protocol_of(params).settings(params)  # the free-space protocols' grip settings
    if free is None:
        grip_force = model_force if params.grip_force is None else params.grip_force
        m.actuator_forcerange[act] = (-grip_force, grip_force)
        if damping > 0:
            for vadr in jaw_vadr:
                m.dof_damping[vadr] = damping * grip_force / model_force
        return grip_force, closing_speed
    grip_force = model_force if free.grip_force is None else free.grip_force
    if free.closing_speed is not None:
        closing_speed = free.closing_speed
    m.actuator_forcerange[act] = (-grip_force, grip_force)
    if damping > 0 or free.closing_speed is not None:
        for vadr in jaw_vadr:
            m.dof_damping[vadr] = 2.0 * grip_force / closing_speed
    return grip_force, closing_speed


def apply_contact_overrides(m: mujoco.MjModel, acr: AcronymParams, index: LiftIndex, prefix: str) -> None:
    """Write a protocol's contact settings (solref, solimp, torsional friction: ``acr``, the ``acronym`` protocol's
    block, :meth:`~graspgen.sim.protocol_phases.RolloutProtocol.contact_overrides`) into ``m``'s gripper geoms (by
    role and name); the ones left None keep the models'."""
    grip = np.flatnonzero(index.geom_is_gripper)
    if acr.contact_solref is not None:
        m.geom_solref[grip] = acr.contact_solref
    if acr.contact_solimp is not None:
        m.geom_solimp[grip] = acr.contact_solimp
    if acr.torsional_friction is not None:
        # MuJoCo takes the larger coefficient of the two geoms (and the larger condim): set it on the pads
        # and on every other geom, so the pad contacts get exactly this value; 0 makes them condim 3.
        pads = list(sum(pad_geom_ids(m, prefix=prefix), ()))
        m.geom_friction[pads, 1] = acr.torsional_friction
        m.geom_friction[np.flatnonzero(~index.geom_is_gripper), 1] = acr.torsional_friction
        if acr.torsional_friction == 0.0:
            m.geom_condim[pads] = np.minimum(m.geom_condim[pads], 3)


class StaticCheck:
    """The pre-filter's check (:class:`graspgen.sim.prefilter.CollisionChecker`) at one instant of a rollout, on a
    private copy of the model in which only gripper-vs-other pairs collide (:meth:`LiftSimulator._static_code
    <graspgen.sim.lift.LiftSimulator>` explains why the scene as it stood and the gripper as commanded)."""

    def __init__(self, m: mujoco.MjModel, index: LiftIndex) -> None:
        self.index = index
        self.model = gm = copy.deepcopy(m)
        self.data = mujoco.MjData(gm)
        # Only gripper-vs-other pairs (as the pre-filter's private model): another geom collides with the gripper
        # geoms iff its masks let it collide with one of them.
        is_grip = index.geom_is_gripper
        grip_ct, grip_ca = m.geom_contype[is_grip], m.geom_conaffinity[is_grip]
        for g in np.flatnonzero(~is_grip):
            ct, ca = int(m.geom_contype[g]), int(m.geom_conaffinity[g])
            gm.geom_contype[g] = int(bool(np.any((ct & grip_ca) | (grip_ct & ca))))
            gm.geom_conaffinity[g] = 0

    def code(self, qpos: np.ndarray, hand_pos: np.ndarray, hand_quat: np.ndarray, opening: float,
             roles: np.ndarray, allowance: np.ndarray) -> int | None:
        """Lowest code (0 support, 1 target by the touch rule, 2 clutter) of the gripper with its hand at
        ``hand_pos (3,)`` / ``hand_quat (4,)`` and its pads ``opening`` m apart, against the scene at ``qpos (nq,)``;
        None if free. ``allowance (ngeom,)`` m: how deep each gripper geom may press into the target."""
        ix, gm, gd = self.index, self.model, self.data
        gd.qpos[:] = qpos
        a = ix.base_qadr
        gd.qpos[a:a + 3] = hand_pos
        gd.qpos[a + 3:a + 7] = hand_quat
        gd.qpos[ix.jaw_qadr] = opening / 2.0  # jaw joint = half the pad separation
        mujoco.mj_kinematics(gm, gd)
        mujoco.mj_collision(gm, gd)
        if gd.ncon == 0:
            return None
        con = gd.contact
        geom = con.geom
        grip = ix.geom_is_gripper[geom]
        mine = np.where(grip[:, 0], geom[:, 0], geom[:, 1])
        other = np.where(grip[:, 0], geom[:, 1], geom[:, 0])
        codes = roles[other]
        limit = np.where(codes == TARGET, allowance[mine], 0.0)
        codes = codes[(grip[:, 0] != grip[:, 1]) & (-con.dist > limit)]
        return int(codes.min()) if len(codes) else None
