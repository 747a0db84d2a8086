"""studies/outcome_mix.py: the pad-overlap and closing-point measures against a box's analytic answers."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from graspgen.grippers import load_gripper
from studies.outcome_mix import _mix, com_distance, pad_overlap
from tests.shapes import top_down

PANDA = load_gripper("panda")
PAD = PANDA.pad_size[1] * PANDA.pad_size[2] * 1e6  # mm^2: 17.4 x 17.6



def test_pad_overlap_is_the_pad_face_on_the_box_and_shrinks_past_its_edges():
    box = trimesh.creation.box(extents=(0.04, 0.05, 0.06))  # closing across the 40 mm, pads on the 50 x 60 faces
    T = np.stack([top_down(0, 0, 0.02),          # the whole pad on the face
                  top_down(0, 0.025, 0.02),      # centred on the face's edge along y: 4 of 7 cell columns
                  top_down(0, 0, 0.03),          # centred on the top edge along z: 4 of 7 cell rows
                  top_down(0, 0, 0.045)])        # above the box: nothing
    got = pad_overlap(box, T, PANDA)
    assert got == pytest.approx([PAD, PAD * 4 / 7, PAD * 4 / 7, 0.0])


def test_a_tilted_face_meets_the_pad_only_along_a_strip():
    # A wedge-like face: the box turned 30 degrees about the approach axis's normal makes the pads meet an inclined
    # face, so only the cells within 2 mm of the first touch count.
    box = trimesh.creation.box(extents=(0.04, 0.05, 0.06))
    box.apply_transform(trimesh.transformations.rotation_matrix(np.radians(30), (0, 1, 0)))
    full = pad_overlap(box, top_down(0, 0, 0)[None], PANDA)[0]
    assert 0 < full < PAD / 2


def test_closing_point_distance_and_the_outcome_mix():
    T = np.stack([top_down(0.003, 0.004, 0.0), top_down(0, 0, 0.01)])
    assert com_distance(T, np.zeros(3)) == pytest.approx([5.0, 10.0])
    outcome = np.array([0, 1, 3, 4, 5, 5, 5])
    firm = np.array([False, False, False, False, True, False, True])
    assert _mix(outcome, firm) == {"collision": 2, "no_contact": 1, "slipped": 1, "held_not_firm": 1, "firm": 2}
