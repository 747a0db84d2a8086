"""Tests of graspgen/sim/pad_patch.py: the pressed patch of a pad's face and its torsional arm."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from graspgen.grippers import load_gripper
from graspgen.sim.gripper_model import GRIPPER_GEOM_GROUP, attach_gripper, pad_torsion_arm
from graspgen.sim.pad_patch import PATCH_CELLS, PadPatch, PatchTorsion, face_grid, foundation_pressure, rectangle_arm
from graspgen.sim.physics import physics_options

pytestmark = pytest.mark.usefixtures("no_mujoco_log_in_repo")

PANDA = load_gripper("panda")


def _slow_arm(p: float, q: float, n: int = 400) -> float:
    """Mean distance of a rectangle of half-sides p, q from its centre, by a fine midpoint grid (the reference)."""
    u = (np.arange(n) + 0.5) / n
    x, y = np.meshgrid((u - 0.5) * 2 * p, (u - 0.5) * 2 * q)
    return float(np.hypot(x, y).mean())


@pytest.mark.parametrize("p, q", [(0.005, 0.005), (0.0087, 0.0088), (0.002, 0.01)])
def test_rectangle_arm_matches_numeric_integral(p, q):
    assert rectangle_arm(p, q) == pytest.approx(_slow_arm(p, q), rel=1e-4)


def test_rectangle_arm_of_square_and_panda_face():
    assert rectangle_arm(0.5, 0.5) == pytest.approx(0.3826, abs=1e-4)
    assert pad_torsion_arm(PANDA) == pytest.approx(rectangle_arm(0.0087, 0.0088))


def test_face_grid_covers_unit_square():
    g = face_grid(4)
    assert g.shape == (16, 2)
    np.testing.assert_allclose(g.mean(axis=0), 0.0, atol=1e-12)
    assert g.min() == pytest.approx(-0.375) and g.max() == pytest.approx(0.375)


def test_foundation_pressure_is_the_indentation_above_the_deepest_point():
    gaps = np.array([-2e-4, 3e-4, 8e-4, 1.5e-3, np.inf])
    np.testing.assert_allclose(foundation_pressure(gaps, 1e-3), [1e-3, 5e-4, 0.0, 0.0, 0.0], atol=1e-15)
    assert not foundation_pressure(np.full(3, np.inf), 1e-3).any()


def _slow_foundation_arm(gap, p: float, q: float, width: float, n: int = 600) -> float:
    """Reference: pressure-weighted mean radius of ``(width - gap(y, z))+`` on a fine grid of the face."""
    u = (np.arange(n) + 0.5) / n - 0.5
    y, z = np.meshgrid(u * 2 * p, u * 2 * q, indexing="ij")
    w = np.maximum(width - gap(y, z), 0.0).ravel()
    pts = np.stack([y.ravel(), z.ravel()], axis=1)
    c = w @ pts / w.sum()
    return float(w @ np.linalg.norm(pts - c, axis=1) / w.sum())


def _world(block_half, block_pos, *, other=None, cylinder=None):
    """The Panda, open, its TCP at the origin (x closing, z approach along world z), a free box ``target`` of half
    sizes ``block_half`` at ``block_pos``, and optionally a second free box ``other`` (half sizes, position)."""
    spec = mujoco.MjSpec()
    physics_options(spec)
    for name, block in (("target", (block_half, block_pos)), ("other", other)):
        if block is None:
            continue
        half, pos = block
        body = spec.worldbody.add_body(name=name, pos=list(pos))
        body.add_freejoint()
        if cylinder is not None and name == "target":  # (radius, half length), its axis along z
            body.add_geom(type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[*cylinder, 0.0], mass=0.1, friction=[0.5, 0, 0])
        else:
            body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=list(half), mass=0.1, friction=[0.5, 0, 0])
    attach_gripper(spec, PANDA)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data


def _left(model, cells: int = PATCH_CELLS) -> PadPatch:
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "gripper/left_face")
    geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "gripper/left_pad")
    return PadPatch(model, site, geom, 1.0, GRIPPER_GEOM_GROUP, cells=cells)


def _target(model) -> int:
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "target")


def _face_x(model, data) -> float:
    return float(data.site_xpos[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "gripper/left_face")][0])


def test_face_site_sits_on_the_pad_face_with_its_size():
    model, data = _world((0.01, 0.01, 0.01), (0.0, 0.0, 0.5))
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "gripper/left_face")
    np.testing.assert_allclose(model.site_size[site][1:], np.array(PANDA.pad_size[1:]) / 2)
    assert _face_x(model, data) == pytest.approx(-PANDA.max_width / 2, abs=1e-6)


def test_a_face_covered_whole_gets_the_face_arm():
    model, data = _world((0.02, 0.05, 0.05), (0.0, 0.0, 0.0))
    data.qpos[:3] = [_face_x(model, data) + 0.02 - 2e-4, 0.0, 0.0]  # the block's left face 0.2 mm into the pad
    mujoco.mj_forward(model, data)
    patch = _left(model)
    assert patch.pressed(model, data, _target(model)).all()
    assert patch.arm(model, data, _target(model)) == pytest.approx(pad_torsion_arm(PANDA), rel=1e-9)


def test_a_half_covered_face_gets_the_arm_of_its_half():
    model, data = _world((0.02, 0.05, 0.05), (0.0, 0.0, 0.0))
    # the block's top face at the TCP's z = 0: it covers the lower half (approach side -z) of the face
    data.qpos[:3] = [_face_x(model, data) + 0.02 - 2e-4, 0.0, -0.05]
    mujoco.mj_forward(model, data)
    patch = _left(model)
    hit = patch.pressed(model, data, _target(model))
    assert hit.mean() == pytest.approx(0.5)
    p, q = PANDA.pad_size[1] / 2, PANDA.pad_size[2] / 2
    assert patch.arm(model, data, _target(model)) == pytest.approx(rectangle_arm(p, q / 2), rel=0.03)


def test_a_gap_or_another_body_presses_nothing():
    model, data = _world((0.02, 0.05, 0.05), (0.0, 0.0, 0.0), other=((0.02, 0.05, 0.05), (0.3, 0.0, 0.0)))
    target = _target(model)
    x = _face_x(model, data) + 0.02
    data.qpos[:3] = [x + 1e-3, 0.0, 0.0]  # 1 mm short of the face
    mujoco.mj_forward(model, data)
    assert _left(model).arm(model, data, target) == 0.0
    data.qpos[:3] = [1.0, 0.0, 0.0]  # target away; the other block pressed into the face instead
    data.qpos[7:10] = [x - 2e-4, 0.0, 0.0]
    mujoco.mj_forward(model, data)
    assert not _left(model).pressed(model, data, target).any()


def test_a_turned_block_presses_a_wedge_of_the_face():
    model, data = _world((0.02, 0.05, 0.05), (0.0, 0.0, 0.0))
    # turned 10 degrees about z: its -x face crosses the pad's face at y_cut, 3 mm inside the +y edge, and is in
    # front of the face (a gap) below y_cut, pressed into it above
    a = math.radians(10.0)
    y_cut = PANDA.pad_size[1] / 2 - 0.003
    f0y = -0.02 * math.sin(a)  # the -x face's centre (the block's centre at y = 0)
    f0x = _face_x(model, data) + math.tan(a) * (y_cut - f0y)
    data.qpos[:7] = [f0x + 0.02 * math.cos(a), 0.0, 0.0, math.cos(a / 2), 0.0, 0.0, math.sin(a / 2)]
    mujoco.mj_forward(model, data)
    patch = _left(model)
    target = _target(model)
    p, q = PANDA.pad_size[1] / 2, PANDA.pad_size[2] / 2
    y = face_grid(PATCH_CELLS)[:, 0] * 2 * p
    np.testing.assert_allclose(patch.gaps(model, data, target), -math.tan(a) * (y - y_cut), atol=1e-7)
    width = float(model.geom_solimp[patch.geom, 2])
    assert width == pytest.approx(1e-3)
    pressed = patch.pressed(model, data, target).reshape(PATCH_CELLS, PATCH_CELLS)  # rows: y, columns: z
    rows = math.ceil(width / math.tan(a) / (2 * p / PATCH_CELLS))  # the rows within 5.7 mm of the deepest one
    assert pressed[-rows:].all() and not pressed[:-rows].any()
    reference = _slow_foundation_arm(lambda yy, zz: math.tan(a) * (p - yy), p, q, width)
    assert patch.arm(model, data, target) == pytest.approx(reference, rel=0.08)


@pytest.mark.parametrize("radius, offset", [(0.02, 0.0), (0.02, 4e-4), (0.05, 0.0), (0.008, 0.0)])
def test_a_cylinder_presses_a_strip_whose_width_follows_its_curvature(radius, offset):
    """A line contact along the pad: the strip is narrower than a cell of the rigid surfaces' patch would be, and the
    arm is the same at 12 and at 36 cells a side and matches the fine-grid reference (not the grid's resolution)."""
    model, data = _world(None, (0.0, 0.0, 0.0), cylinder=(radius, 0.05))
    data.qpos[:3] = [_face_x(model, data) + radius - 2e-4, offset, 0.0]
    mujoco.mj_forward(model, data)
    target = _target(model)
    p, q = PANDA.pad_size[1] / 2, PANDA.pad_size[2] / 2
    width = 1e-3
    coarse, fine = _left(model).arm(model, data, target), _left(model, cells=36).arm(model, data, target)
    reference = _slow_foundation_arm(
        lambda yy, zz: radius - np.sqrt(np.maximum(radius ** 2 - (yy - offset) ** 2, 0.0)), p, q, width)
    assert fine == pytest.approx(reference, rel=0.03)
    assert coarse == pytest.approx(reference, rel=0.06)
    assert 0.4 * pad_torsion_arm(PANDA) < coarse < pad_torsion_arm(PANDA)  # a strip: less than the face


def test_patch_torsion_moves_the_torsion_from_objects_to_pads():
    model, data = _world((0.02, 0.05, 0.05), (0.0, 0.0, 0.0))
    target = _target(model)
    g_obj = int(model.body_geomadr[target])
    assert model.geom_friction[g_obj, 1] == pytest.approx(0.5 * pad_torsion_arm(PANDA))  # attach_gripper's value
    side = np.full(model.ngeom, True)
    side[[g for g in range(model.ngeom) if model.geom_group[g] == GRIPPER_GEOM_GROUP]] = False
    torsion = PatchTorsion(model, "gripper/", side, GRIPPER_GEOM_GROUP)
    assert model.geom_friction[g_obj, 1] == 0.0
    pads = [g for g, _ in torsion.pads]
    torsion.closing(model, target)
    np.testing.assert_allclose(model.geom_friction[pads, 1], 0.5 * pad_torsion_arm(PANDA))
    torsion.placed(model)
    np.testing.assert_allclose(model.geom_friction[pads, 1], 0.0)
    data.qpos[:3] = [_face_x(model, data) + 0.02 - 2e-4, 0.0, -0.05]
    mujoco.mj_forward(model, data)
    left, right = torsion.closed(model, data, target)
    assert left == pytest.approx(rectangle_arm(PANDA.pad_size[1] / 2, PANDA.pad_size[2] / 4), rel=0.03)
    assert right == 0.0  # the right pad touches nothing
    np.testing.assert_allclose(model.geom_friction[pads, 1], [0.5 * left, 0.0])


def _free_space_simulator():
    from graspgen.sim.lift import LiftSimulator
    from graspgen.sim.protocols import LiftParams

    spec = mujoco.MjSpec()
    physics_options(spec)
    body = spec.worldbody.add_body(name="obj/0_box", pos=[0.0, 0.0, 0.3])
    body.add_freejoint()
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.02, 0.05, 0.03], mass=0.2, friction=[0.5, 0, 0])
    attach_gripper(spec, PANDA)
    return LiftSimulator(spec.compile(), LiftParams(protocol="acronym", pad_torsion="patch"))


def _grasp(z: float) -> np.ndarray:
    """TCP frame closing along x across the box's 40 mm, approaching along -z, ``z`` (m) above the box centre."""
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [0.0, 0.0, 0.3 + z]
    return T


def test_a_rollout_does_not_see_the_one_before():
    sim = _free_space_simulator()
    edge, centre = _grasp(0.03 - 0.002), _grasp(0.0)  # the pads overlap 2 mm of the box's top edge, or its middle
    alone = sim.rollout(edge, 0.04, "obj/0_box")
    sim.rollout(centre, 0.04, "obj/0_box")
    again = sim.rollout(edge, 0.04, "obj/0_box")
    assert (alone.code, alone.steps, alone.max_rel_rotation) == (again.code, again.steps, again.max_rel_rotation)
    pads = sim.pad_patch.pad_geoms
    after_edge = sim.model.geom_friction[pads, 1].copy()
    sim.rollout(centre, 0.04, "obj/0_box")
    after_centre = sim.model.geom_friction[pads, 1]
    assert (after_edge < after_centre).all()  # the edge pinch's patch is smaller than the middle's
    np.testing.assert_allclose(after_centre, 0.5 * pad_torsion_arm(PANDA), rtol=0.02)  # flat on flat, squeezed
