"""The motion planner (robotprog.planner): transfers straight or searched, seeded and reproducible,
timed and proven; a planner among more boxes keeps its world's and starts its generator afresh."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from factory.core.errors import PlanningError
from robotprog.cell import Box, Pose
from robotprog.collision import collision_world
from robotprog.planner import MotionPlanner, PlannerOptions, raise_up


def test_rrt_connect_finds_free_deterministic_path_when_direct_move_collides(cell, world):
    home = np.array(cell.robot.home)
    a = home.copy()
    a[:3] = (-1.5, -0.6, 1.0)
    b = a.copy()
    b[0] = 1.5  # swinging the low arm across passes through the mill
    planner = MotionPlanner(cell, world, PlannerOptions(seed=3))
    assert not world.in_collision(a) and not world.in_collision(b)
    assert not planner.edge_free(a, b, None)
    found = planner.transfer(a, b, None, "test")
    assert found.search == "rrt-connect"
    path = found.waypoints
    np.testing.assert_allclose(path[0], a)
    np.testing.assert_allclose(path[-1], b)
    assert len(path) >= 3
    assert world.path_free(planner.densify(path)) is None
    again = MotionPlanner(cell, world, PlannerOptions(seed=3)).transfer(a, b, None, "test")
    np.testing.assert_array_equal(path, again.waypoints)
    timed = planner.timed("rrt", "joint", path, None)
    s = timed.trajectory.resample(200.0)
    assert world.path_free(s.q) is None


def test_a_free_transfer_is_straight(cell, world):
    a = np.asarray(cell.robot.home, dtype=float)
    b = a + np.array([0.1, 0.0, 0.0, 0.0, 0.0, 0.05])
    planner = MotionPlanner(cell, world)
    state = planner.rng.bit_generator.state
    found = planner.transfer(a, b, None, "test")
    assert found.search == "straight"
    np.testing.assert_array_equal(found.waypoints, [a, b])
    assert planner.rng.bit_generator.state == state  # nothing drawn: the plans after it are unchanged
    move = planner.joint_move("test", a, b, None, "test")
    assert move.kind == "joint" and move.duration > 0
    np.testing.assert_array_equal(move.waypoints, [a, b])


def test_rrt_gives_up_after_its_iterations(cell, world):
    a = np.asarray(cell.robot.home, dtype=float).copy()
    a[:3] = (-1.5, -0.6, 1.0)
    b = a.copy()
    b[0] = 1.5
    planner = MotionPlanner(cell, world, PlannerOptions(rrt_iterations=1))
    with pytest.raises(PlanningError, match="across the mill: no collision-free joint path found in 1 RRT"):
        planner.transfer(a, b, None, "across the mill")


def test_a_planner_among_more_boxes(cell, world):
    """The new world keeps the old one's boxes and door and adds the new ones; the generator starts
    from the seed again (the same draws as a planner built afresh)."""
    home = np.asarray(cell.robot.home, dtype=float)
    near = home.copy()
    near[0] += 0.3
    planner = MotionPlanner(cell, world, PlannerOptions(seed=7))
    body = (planner.tcp_world(near) @ np.array([0.0, 0.0, -0.1, 1.0]))[:3]  # up the tool axis, the gripper
    block = Box("block", (0.06, 0.06, 0.06), Pose(tuple(float(v) for v in body), (0.0, 0.0, 0.0)))
    first = Box("first", (0.02, 0.02, 0.02), Pose((0.0, 0.0, 2.5), (0.0, 0.0, 0.0)))
    # the door closed, but far from the arm (closed where it is, it touches the arm at home)
    far = dataclasses.replace(cell.enclosure.door, pose=Pose((5.0, 5.0, 1.0), (0.0, 0.0, 0.0)))
    shut = dataclasses.replace(cell, enclosure=dataclasses.replace(cell.enclosure, door=far))
    base = MotionPlanner(shut, collision_world(shut, world.robot, door_closed=True, obstacles=(first,)),
                         PlannerOptions(seed=7))
    base.rng.random(6)  # the generator has moved on
    among = base.among((block,))
    assert among.world.obstacles == (first, block)
    assert among.world.door_closed and far.name in among.world.static_names
    assert among.options == base.options
    assert among.rng.random() == np.random.default_rng(7).random()
    assert base.edge_free(home, near, None)
    assert among.world.in_collision(near) and not among.edge_free(home, near, None)  # the block is in the way


def test_raise_up_moves_only_the_height():
    t = np.eye(4)
    t[:3, 3] = (0.1, 0.2, 0.3)
    up = raise_up(t, 0.1)
    np.testing.assert_allclose(up[:3, 3], (0.1, 0.2, 0.4))
    np.testing.assert_array_equal(up[:3, :3], t[:3, :3])
    assert t[2, 3] == 0.3  # the pose given is not changed


def test_options_are_values():
    o = PlannerOptions()
    with pytest.raises(dataclasses.FrozenInstanceError):
        o.seed = 1  # type: ignore[misc]
    assert dataclasses.replace(o, seed=1).seed == 1 and o.seed == 0


def test_a_line_is_proven_once_as_the_motion_that_runs_and_only_in_its_own_world(cell, world):
    """A TCP line's timed spline is proven as the line is solved (prove_line) and timed() takes it: the
    same timing and room as proving it afresh, the room proven free by an independent call; a planner
    with a box in the line's way proves it again and refuses it; a line into that box is refused as
    it is solved."""
    from scipy.interpolate import PPoly

    from robotprog.planner import CHORD_PERIOD_S
    from robotprog.sweep import monotone_breaks

    home = np.asarray(cell.robot.home, dtype=float)
    p = MotionPlanner(cell, world)
    t_a = p.tcp_world(home)
    t_b = raise_up(t_a, -0.2)
    qs = p.line(t_a, t_b, home, None, "down", "test")
    assert len(p._lines) == 1
    move = p.timed("down", "linear", qs, None)
    assert not p._lines  # taken, not kept
    fresh = MotionPlanner(cell, world)._timed_once("down", "linear", qs, None)
    np.testing.assert_array_equal(move.trajectory.coefficients, fresh.trajectory.coefficients)
    np.testing.assert_array_equal(move.trajectory.breakpoints, fresh.trajectory.breakpoints)
    assert move.tube is not None
    np.testing.assert_array_equal(move.tube, fresh.tube)
    assert np.all(move.tube >= move.trajectory.chord_deviation(CHORD_PERIOD_S))
    traj = move.trajectory
    assert p.sweep.first_contact(PPoly(traj.coefficients, traj.breakpoints),
                                 monotone_breaks(traj.breakpoints, traj.coefficients), None, move.tube) is None
    # a box where the line ends: another world, so the line proven above is not taken as proven there
    blocked = p.among((Box("in_the_way", (0.2, 0.2, 0.24), Pose(tuple(t_b[:3, 3]))),))
    p.line(t_a, t_b, home, None, "down", "test")
    with pytest.raises(PlanningError, match="collides"):
        blocked.timed("down", "linear", qs, None)
    with pytest.raises(PlanningError, match="down collides"):
        blocked.line(t_a, t_b, home, None, "down", "test")
    assert not blocked._lines
