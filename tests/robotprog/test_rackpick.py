"""The pick of a blank off its slot's centre, corrected by where it was located and proven."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factory.core.errors import PlanningError
from robotprog.cell import Box, Pose
from robotprog.collision import collision_world
from robotprog.grasp import box_pose
from robotprog.planner import MotionPlanner
from robotprog.rackpick import (CORRECTED_MOVES, BlankScatter, PlannedPick, SlotOffset, corrected_pick, draw_offset,
                                slot_room)
from robotprog.tending import _neighbours
from tests.robotprog.test_tending import SAMPLE_STOCK, sheet


@pytest.fixture(scope="module")
def bracket(tending) -> PlannedPick:
    """The plan's pick of the bracket's blank (104 x 64 x 16 mm) in rack slot (0, 0)."""
    plan = tending("cell.yaml", sheet(*SAMPLE_STOCK["bracket"]))
    end = {m.name: m.q_end for m in plan.moves}
    return PlannedPick(end["load: home to above rack"], end["load: approach stock"], end["load: retreat from rack"],
                       np.asarray(plan.stock.size, dtype=float))


def test_the_offsets_keep_the_turned_blank_within_its_slot(cell):
    size = np.array([0.104, 0.064, 0.016])
    scatter = BlankScatter(max_shift=0.01, max_yaw=math.radians(5.0), seed=3)
    room = slot_room(cell, size, scatter.max_yaw)
    pitch = np.asarray(cell.rack.pitch)
    corners = np.array([[sx, sy] for sx in (-1, 1) for sy in (-1, 1)]) * size[:2] / 2
    drawn = [draw_offset(scatter, room, job, slot) for job in range(1, 60) for slot in range(3)]
    for o in drawn:
        c, s = math.cos(o.dyaw), math.sin(o.dyaw)
        turned = corners @ np.array([[c, s], [-s, c]]) + [o.dx, o.dy]
        assert (np.abs(turned) <= pitch / 2 + 1e-12).all()
        assert abs(o.dyaw) <= scatter.max_yaw
    # the slot, not the scatter, bounds x here: 120 mm of pitch leaves the 104 mm blank 8 mm less its turn
    assert max(abs(o.dx) for o in drawn) > 0.5 * room.dx and room.dx < scatter.max_shift
    assert draw_offset(scatter, room, 7, 1) == draw_offset(scatter, room, 7, 1) != draw_offset(scatter, room, 8, 1)
    # a blank that fills the pitch cannot move at all
    assert slot_room(cell, np.array([0.12, 0.1, 0.02]), 0.05) == SlotOffset(0.0, 0.0, 0.0)


def test_a_located_blank_is_picked_by_the_corrected_grasp_and_the_pick_is_proven(cell, world, bracket):
    true = SlotOffset(0.0025, -0.002, math.radians(2.5))
    located = SlotOffset(0.00255, -0.00195, math.radians(2.45))  # the camera's error: 0.07 mm, 0.05 deg
    pick = corrected_pick(cell, world.robot, bracket, located, true)
    assert tuple(m.name for m in pick.moves) == CORRECTED_MOVES
    p = MotionPlanner(cell, world)
    t_slot = cell.rack.slot_transform(0, 0)
    planned_grasp = p.tcp_world(bracket.q_grasp)
    grasp = p.tcp_world(pick.moves[1].q_end)
    np.testing.assert_allclose(grasp, located.transform(t_slot) @ planned_grasp, atol=1e-6)
    # the grasp turned with the blank, and sits over its located centre
    turn = math.atan2(grasp[1, 0], grasp[0, 0]) - math.atan2(planned_grasp[1, 0], planned_grasp[0, 0])
    assert math.isclose((turn + math.pi) % (2 * math.pi) - math.pi, located.dyaw, abs_tol=1e-6)
    # it starts where the plan stands over the slot and ends where the plan's retreat ends
    np.testing.assert_allclose(pick.moves[0].waypoints[0], bracket.q_above, atol=1e-9)
    np.testing.assert_allclose(pick.moves[-1].q_end, bracket.q_lifted, atol=1e-9)
    assert 0 < pick.duration < 10
    # an independent look at the proof: the open fingers around the true blank touch nothing
    size = bracket.size
    true_box = true.transform(t_slot) @ box_pose(t_slot, -size * [0.5, 0.5, 0], size * [0.5, 0.5, 1])
    blank = Box("blank", tuple(size), Pose(tuple(true_box[:3, 3]), (0.0, 0.0, math.atan2(true_box[1, 0],
                                                                                         true_box[0, 0]))))
    around = collision_world(cell, world.robot, obstacles=_neighbours(cell.rack, (0, 0), size, "n") + (blank,))
    for m in pick.moves[:2]:
        ts = np.linspace(0.0, m.trajectory.duration, 40)
        assert around.path_free(m.trajectory.sample(ts)[0], m.held) is None


def test_a_pick_corrected_by_a_wrong_location_hits_the_blank_and_is_refused(cell, world, bracket):
    true = SlotOffset(0.0, 0.0, 0.0)
    # located 10 mm off across the fingers, beyond their 8 mm clearance: a finger comes down on the blank
    with pytest.raises(PlanningError, match="collides"):
        corrected_pick(cell, world.robot, bracket, SlotOffset(0.0, 0.010, 0.0), true)


def test_a_blank_in_another_slot_is_picked_from_its_own_slot_and_the_pick_is_proven(cell, world, bracket):
    """The plan picks from slot (0, 0); a blank in slot (1, 2) is reached by the corrected pick: over it,
    down, grip, up, and the joint move back to where the plan's retreat ends, every move proven."""
    from robotprog.rack import RackSlot
    true = SlotOffset(0.001, -0.0015, math.radians(1.0))
    located = SlotOffset(0.00105, -0.00148, math.radians(1.05))
    standing = tuple(RackSlot(i, r, c, 0, tuple(bracket.size)).box(cell.rack)
                     for i, (r, c) in enumerate(((0, 0), (0, 1), (0, 2), (1, 0), (1, 1))))
    pick = corrected_pick(cell, world.robot, bracket, located, true, slot=(1, 2), neighbours=standing)
    p = MotionPlanner(cell, world)
    t_far, t_plan = cell.rack.slot_transform(1, 2), cell.rack.slot_transform(0, 0)
    grasp = p.tcp_world(pick.moves[1].q_end)
    np.testing.assert_allclose(grasp, located.transform(t_far) @ t_far @ np.linalg.inv(t_plan)
                               @ p.tcp_world(bracket.q_grasp), atol=1e-6)
    assert np.linalg.norm(grasp[:2, 3] - t_far[:2, 3]) < 0.003  # over slot (1, 2), 260 mm from the plan's slot
    np.testing.assert_allclose(pick.moves[0].waypoints[0], bracket.q_above, atol=1e-9)
    np.testing.assert_allclose(pick.moves[-1].q_end, bracket.q_lifted, atol=1e-9)
    # the neighbours given are the obstacles: a blank standing where the fingers go down is hit
    crowded = standing + (Box("in_the_way", (0.02, 0.02, 0.05), Pose(tuple(grasp[:3, 3] + [0.0, 0.04, -0.03]))),)
    with pytest.raises(PlanningError, match="collides"):
        corrected_pick(cell, world.robot, bracket, located, true, slot=(1, 2), neighbours=crowded)
