"""The top-down grasp (robotprog.grasp): centred on the top face, fingers across the narrow side,
tips inside the box but clear of what it stands on, the yaw nearer home; and its refusals."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from factory.core.errors import PlanningError
from robotprog.grasp import GraspOptions, box_pose, open_fingers, top_grasp

OPTIONS = GraspOptions()


def support(yaw: float, xyz=(0.4, -0.2, 0.8)) -> np.ndarray:
    t = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    t[:2, :2] = [[c, -s], [s, c]]
    t[:3, 3] = xyz
    return t


@settings(max_examples=30, deadline=None)
@given(st.floats(0.02, 0.08), st.floats(0.02, 0.2), st.floats(0.01, 0.05), st.floats(-np.pi, np.pi))
def test_a_box_is_gripped_from_above_across_its_narrow_side(cell, a, b, height, yaw):
    size = np.array([a, b, height])
    bmin, bmax = np.array([-a / 2, -b / 2, 0.0]), np.array([a / 2, b / 2, height])
    t_support = support(yaw)
    g = top_grasp(cell, t_support, bmin, bmax, np.eye(3), OPTIONS, "box")
    t = g.transform_world_to_tcp
    np.testing.assert_allclose(t[:3, 2], [0.0, 0.0, -1.0], atol=1e-12)  # the tool points down
    narrow = t_support[:3, int(a > b)]
    assert abs(abs(t[:3, 1] @ narrow) - 1.0) < 1e-9  # the fingers close across the narrow side
    centre = box_pose(t_support, bmin, bmax)[:3, 3]
    np.testing.assert_allclose(t[:2, 3], centre[:2], atol=1e-12)  # centred on the top face
    bottom, top = 0.8, 0.8 + height
    assert bottom + OPTIONS.floor_clearance - 1e-12 <= t[2, 3] <= top - OPTIONS.min_grip_depth + 1e-9
    assert top - t[2, 3] <= OPTIONS.grip_depth + 1e-12
    # the held box is the box, seen from the TCP
    np.testing.assert_allclose(g.held.size, size)
    np.testing.assert_allclose(t @ np.asarray(g.held.transform_tcp_to_box), box_pose(t_support, bmin, bmax),
                               atol=1e-12)


def test_of_the_two_yaws_the_one_nearer_home(cell):
    bmin, bmax = np.array([-0.05, -0.02, 0.0]), np.array([0.05, 0.02, 0.02])
    down = np.diag([1.0, -1.0, -1.0])  # x along world X, tool down
    g = top_grasp(cell, support(0.0), bmin, bmax, down, OPTIONS, "box").transform_world_to_tcp
    np.testing.assert_allclose(g[:3, :3], down, atol=1e-12)
    turned = np.diag([-1.0, 1.0, -1.0])  # the same, half a turn about the tool
    g = top_grasp(cell, support(0.0), bmin, bmax, turned, OPTIONS, "box").transform_world_to_tcp
    np.testing.assert_allclose(g[:3, :3], turned, atol=1e-12)


@pytest.mark.parametrize("size, match, field", [
    ((0.12, 0.10, 0.02), "box 100.0 mm across its narrowest side is wider than the gripper opens",
     "gripper.opening.max"),
    ((0.05, 0.04, 0.004), "box 4.0 mm tall is too thin to grip", "gripper.fingers"),
])
def test_a_box_the_gripper_cannot_take(cell, size, match, field):
    bmax = np.array(size)
    with pytest.raises(PlanningError, match=match) as e:
        top_grasp(cell, support(0.0), np.zeros(3), bmax, np.eye(3), OPTIONS, "box")
    assert e.value.source == field


def test_open_fingers_leave_a_clearance_but_open_no_wider_than_they_can(cell):
    fingers = cell.gripper.fingers
    gap = open_fingers(cell, 0.03)
    inner = abs(gap[0].transform_tcp_to_box[1][3] - gap[1].transform_tcp_to_box[1][3]) - fingers.thickness
    assert inner == pytest.approx(0.03 + 2 * fingers.clearance)
    wide = open_fingers(cell, cell.gripper.opening_max)
    inner = abs(wide[0].transform_tcp_to_box[1][3] - wide[1].transform_tcp_to_box[1][3]) - fingers.thickness
    assert inner == pytest.approx(cell.gripper.opening_max)
