"""The grasp-and-lift protocol in MuJoCo and its outcome labels (ARCHITECTURE.md, Conventions).

:class:`LiftSimulator` takes a compiled scene (ground / support geoms, free object bodies, a floating gripper attached
with :func:`graspgen.sim.gripper_model.attach_gripper`) and rolls out grasps in it: place the gripper at the
pre-grasp pose, approach, close under a force limit, lift, hold, shake (on by default; ``LiftParams.shake``), and
label what happened with one of six outcome codes (:class:`graspgen.sim.protocols.Outcome`). The rules are written
out in :class:`LiftSimulator`'s docstring. Around it: the settings and the result record
(:mod:`graspgen.sim.protocols`), the motion profiles (:mod:`graspgen.sim.motion`), the model set-up
(:mod:`graspgen.sim.lift_model`), the state and steps of a rollout that the MuJoCo Warp backend shares
(:mod:`graspgen.sim.lift_state`, :mod:`graspgen.sim.lift_rules`).

Frames: a grasp is the 4x4 world pose of the gripper's TCP frame (origin midway between the pads, z = approach
direction palm -> object, x = closing direction; the *left* jaw sits on -x, the *right* on +x) and a pad separation
``width`` in metres (:mod:`graspgen.grippers`).

Speed (``bench/bench_rollouts.py``; 2F-85 on the bundled box / can, one core): a successful rollout is ~990 steps
(1.98 s simulated: 0.15 s approach, ~0.12 s closing, 0.5 s lift, 0.2 s hold, 2 x 0.5 s shake; ~490 without the
shake); failures stop earlier. Most of a rollout is waiting, so the protocol keeps simulated time short and stops as
soon as a rule decides, and it keeps Python out of the step loop: the mocap target is written once per step only
while the gripper moves (a row copy, ~1 us against ~15 us per step), closing and holding run as
``mj_step(model, data, nstep=check_interval)``, and the rules are checked once per ``check_interval`` steps on cached
ids and views (squared distances and cosines, no allocation beyond a few small temporaries). Measured: 90-130
rollouts/s with the default shake (160-240 without), within 1.12x of the bare ``mj_step`` cost of the same steps.

Protocols (:data:`graspgen.sim.protocols.PROTOCOLS`, ``LiftParams.protocol``): ``table``, ``acronym`` and
``graspdatagen``, described in :mod:`graspgen.sim.protocols`.

Determinism: every rollout starts from ``mj_resetData`` (which also clears the solver's warm start) plus the saved
initial ``qpos``, so a rollout's result depends only on its inputs, not on earlier rollouts in the same
:class:`LiftSimulator`; no wall clock, no threads, no global random state.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from graspgen.sim.lift_state import LiftState
from graspgen.sim.poses_mj import pos_quat
from graspgen.sim.protocol_phases import RolloutProtocol, protocol_of
from graspgen.sim.protocols import RolloutResult
from graspgen.validation import check_number

__all__ = ["LiftSimulator"]


class LiftSimulator(LiftState):
    """Grasp-and-lift rollouts in one compiled scene, reusing one :class:`mujoco.MjData`.

    The scene model holds the static environment (a plane named ``ground`` and/or geoms named ``support/...``;
    every geom fixed to the world counts as support, whatever its name), objects as free bodies (named
    ``obj/<index>_<name>`` by convention; any movable body that is not the gripper counts as an object), and a
    floating gripper attached with :func:`graspgen.sim.gripper_model.attach_gripper` under ``prefix``. Ids are looked
    up by name once here, never assumed by index. The simulator works on its own copy of the model: it writes the
    physics settings of ``params`` into it and sets the gripper's force limit to ``params.grip_force`` (rescaling
    the jaw damping so the jaws keep the gripper's closing speed). The caller's model is not modified.

    Protocol of :meth:`rollout` (phases as in :data:`~graspgen.sim.protocols.PHASES`), and the outcome rules. The
    rules are checked in this order; the first that fires decides the outcome and the simulation stops there.
    "Contact" means a MuJoCo contact between a gripper geom and a non-gripper geom; a gripper geom touching several
    kinds at once gives the lowest code. Checks run every ``check_interval`` steps and at the end of each phase.

    1. **placement** (no step): ``mj_resetData`` plus the scene's initial ``qpos``; the gripper is put at the
       pre-grasp pose (the grasp pose moved ``approach_distance`` back along its -z) with the jaws open at
       ``clip(width + width_margin, min_width, max_width)``; ``mj_forward``.
       Contact with support -> **0 collision_with_ground**; with the target, by the touch rule below -> **1
       collision_with_target**; with another object -> **2 collision_with_clutter**.
    2. **approach**: the mocap target moves along +z to the grasp pose (trapezoidal profile, ``approach_speed``,
       ``approach_acceleration``). Contact with support -> **0**, with another object -> **2**; contact with the
       target -> **1** by the touch rule; the target's centre of mass moved more than ``max_target_shift`` or
       turned more than ``max_target_turn`` from its initial pose -> **1**; another object moved/turned more than
       that -> **2**.

       Contacts at placement and on the approach are judged twice, and either counts: as the pre-filter judges
       them (:mod:`graspgen.sim.prefilter`), statically, with the gripper as commanded at this instant (hand on
       the approach line, jaws at the opening) against the scene as it stood at placement
       (:meth:`_static_code`), and live, the simulated gripper's contacts with support and other objects. The
       touch rule is the pre-filter's, so code 1 means the same there and here: a finger (either jaw's pad or
       finger link) may touch the target, pressing up to :data:`graspgen.sim.prefilter.TARGET_TOUCH_DEPTH` (2 mm)
       into it, as a real finger brushes an object on the way in; deeper is a collision, and so is any palm contact
       with the target. It is judged on the static check only: a pushed target yields, so its live contacts do not
       tell how far a finger went into it (its motion is the rule above). ``target_touch_fails`` gives the fingers
       no allowance.
    3. **closing**: the width command goes to ``min_width``, so each jaw presses with ``grip_force``. Closing ends
       when the pad separation changes slower than ``close_speed_tol`` averaged over a check interval, or after
       ``close_timeout``. Then both jaws (each jaw's pad or finger link) must touch the target; otherwise ->
       **3 no_contact_established**. The jaw-target contacts are recorded now (points, normals into the target,
       normal forces, jaw). Gravity is switched on here in free-space mode (``gravity_until_closed``).
    4. **lifting, holding, shaking**: the TCP rises ``lift_height`` straight up in world z (trapezoidal profile,
       ``lift_speed``, ``lift_acceleration``), holds for ``hold_time``, then shakes if ``shake``. At every check: the
       target's centre of mass moved more than ``slip_tolerance`` in the TCP frame since the end of closing, or the
       target turned relative to the TCP frame by more than ``slip_rotation_tolerance`` -> **4
       slipped_during_lifting**. At the end: the target's centre of mass rose less than
       ``min_lift_fraction * lift_height`` since the end of closing -> **4**.
    5. Otherwise -> **5 success**.

    Collisions after the approach (a lifted object brushing a neighbour, a finger touching the table while closing)
    are not labels of their own: they count only through their effect on the grasp (3 or 4).

    That is the ``table`` protocol (``params.protocol``, the default). The ``acronym`` protocol
    (:class:`~graspgen.sim.protocols.AcronymParams`, where its numbers come from) has no approach and no lift:
    gravity off until closing ends (then along the approach axis, ``acronym.gravity``); **placement** at the grasp
    pose itself with the jaws open to ``acronym.open_width`` (fully by default): any contact with the target ->
    **1** (no allowance for the fingers: see below), with support -> **0**, with another object -> **2**;
    **closing** as above (at ``acronym.grip_force`` and ``acronym.closing_speed``; the timeout is at least 1.25x the
    time to close fully), then not both jaws on the target -> **3**; **shaking**: the TCP oscillates along its own z
    axis, then rotates about its own x axis through the TCP (``acronym.shake_*``), then holds still for
    ``acronym.settle_time`` (phase ``holding``); at every check, neither jaw touching the target -> **4** (the
    object has left the hand); at the end, both jaws touching the target -> **5 success**, else **4**. ``lift_gain``
    is NaN (nothing is lifted); ``rel_translation``/``rel_rotation`` are the object's motion in the hand since
    closing; the ``motion_*`` fields are ACRONYM's four motion measures.

    The free-space protocols keep their sources' strict rule: any overlap of the open hand with the target at the
    grasp pose is a collision, the fingers get no allowance (ACRONYM and GraspDataGen take grasps whose hand
    collides with the mesh as failures, with no tolerance). Measured (``studies/fidelity.py --limit 100``, 600
    calibration grasps): with the table protocol's 2 mm allowance the ``acronym`` protocol turned 26 of its 30
    collisions into successes or other codes, most of them grasps FleX loses, and its agreement with FleX fell from
    0.845 to 0.827 (kappa 0.50 to 0.41).

    Both protocols record the object's motion during closing and during the shake (``motion_*``, world frame) and
    its pose at the end of closing (``target_pose_closed``).

    **Firm hold**, a second label beside the outcome, in every protocol: from the end of closing on, at every check
    of the disturbance (``table``: lift, hold, shake; ``acronym``: shake, settle; ``graspdatagen``: tugs) and at the
    end, the target's pose in the TCP frame (the simulated hand's) is compared with its pose when closing ended; the
    largest displacement and rotation are :attr:`~graspgen.sim.protocols.RolloutResult.max_rel_translation` /
    ``max_rel_rotation``, and a success is firm (:attr:`~graspgen.sim.protocols.RolloutResult.firm`) when both stay
    within ``firm_translation`` / ``firm_rotation``. Hand frame, not world: the shake moves the hand, so a
    world-frame displacement over it (``motion_shaking_*``) means motion in the hand only because the hand is back
    at its pose when the shake ends, and it misses an object that swings round the pinch and swings back.
    Bookkeeping only: it reads the state and never changes a step, so outcome codes and every other field are what
    they were without it.

    Parameters
    ----------
    model
        Compiled scene with the gripper attached (see above).
    params
        Protocol, thresholds and physics; None means ``LiftParams()``.
    qpos
        ``(nq,)`` initial configuration of the scene (e.g. settled object poses); None means ``model.qpos0``.
        The gripper's own joints in it are ignored (every rollout places the gripper).
    prefix
        Name prefix of the gripper's elements (as given to :func:`graspgen.sim.gripper_model.attach_gripper`).
    """

    @property
    def protocol(self) -> RolloutProtocol:
        """The protocol object of ``params.protocol`` (:mod:`graspgen.sim.protocol_phases`): it runs the phases."""
        return protocol_of(self.params)

    def rollout(self, T_world_tcp, width: float, target_body: str, *,
                observer: Callable[[str, int], None] | None = None) -> RolloutResult:
        """Roll out one grasp and label it (protocol and rules in the class docstring).

        Parameters
        ----------
        T_world_tcp
            ``(4, 4)`` world pose of the TCP frame at the grasp (z approach, x closing).
        width
            Pad separation (m) of the grasp (the object's width between the contacts); the jaws open to
            ``width + params.width_margin`` (``table``); ignored by ``acronym`` (the jaws open to
            ``params.acronym.open_width``, by default fully).
        target_body
            Name of the object body to grasp, e.g. ``"obj/0_box"``.
        observer
            Called as ``observer(phase, steps_so_far)`` after placement and after every chunk of steps, with
            :attr:`data` holding the current state (for recording or benchmarking; must not modify the state).

        Returns
        -------
        RolloutResult
        """
        pos, quat = pos_quat(T_world_tcp, "T_world_tcp")
        width = check_number("width", width, low=0.0)
        target, roles, index = self.target_roles(target_body)
        self.steps = 0
        R = np.asarray(T_world_tcp, dtype=float)[:3, :3]
        return self.protocol.rollout(self, pos, quat, R, width, target, roles, index, observer)
