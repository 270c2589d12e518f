"""The roadmap of the static cell: what it holds is proven, and plans through it are proven as before."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import PPoly

from factory.core.errors import CellError
from robotprog.collision import collision_world
from robotprog.planner import MotionPlanner
from robotprog.roadmap import Roadmap, RoadmapOptions, build_roadmap, cell_roadmap
from robotprog.sweep import monotone_breaks, swept_motion
from robotprog.tending import plan_tending
from tests.robotprog.test_tending import SAMPLE_STOCK, sheet

#: Small enough to build in a test, dense enough for the sample parts' transfers.
SMALL = RoadmapOptions(nodes=40, neighbours=6)


@pytest.fixture(scope="module")
def roadmap(cell, world):
    return cell_roadmap(cell, world, SMALL)


def test_roadmap_is_proven_free_and_reproducible(roadmap, cell, world):
    static = collision_world(cell, world.robot)
    sweep = swept_motion(static, SMALL.joint_resolution)
    np.testing.assert_array_equal(roadmap.nodes[0], cell.robot.home)
    assert len(roadmap.nodes) == SMALL.nodes + 1
    assert len(roadmap.edges) > len(roadmap.nodes)  # joined, not a scatter of points
    assert not any(static.in_collision(q) for q in roadmap.nodes)
    for i, j in roadmap.edges:  # each segment proven again, all along, independently of the build
        assert sweep.polyline_contact(roadmap.nodes[[i, j]]) is None
    again = cell_roadmap(cell, world, SMALL)
    np.testing.assert_array_equal(again.nodes, roadmap.nodes)
    np.testing.assert_array_equal(again.edges, roadmap.edges)


def test_roadmap_keeps_only_segments_the_proof_accepts():
    # A wall at x = 0.5 in a 2-joint box: a segment across it is refused, the nodes stay on both sides.
    def segment_free(a, b):
        return (a[0] - 0.5) * (b[0] - 0.5) > 0

    rm = build_roadmap(np.array([0.1, 0.1]), np.zeros(2), np.ones(2), lambda q: abs(q[0] - 0.5) > 0.01,
                       segment_free, RoadmapOptions(nodes=30, neighbours=5))
    for i, j in rm.edges:
        assert segment_free(rm.nodes[i], rm.nodes[j])
    assert ((rm.nodes[:, 0] > 0.5).any() and (rm.nodes[:, 0] < 0.5).any())


def test_lazy_search_drops_refused_segments_and_says_when_there_is_no_way():
    # A square of four nodes: the short way (via node 1) is refused, the long way (via 3) is taken.
    nodes = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    rm = Roadmap(nodes, np.array([[0, 1], [1, 2], [2, 3], [0, 3]]))
    refused = {(1.0, 0.0)}

    def free(a, b):
        return tuple(a) not in refused and tuple(b) not in refused

    got = rm.path(np.array([0.0, -0.1]), np.array([1.1, 1.0]), free, connect=1)
    np.testing.assert_allclose(got[1:-1], nodes[[0, 3, 2]])
    for a, b in zip(got[:-1], got[1:]):
        assert free(a, b)
    assert rm.path(np.array([0.0, -0.1]), np.array([1.1, 1.0]), lambda a, b: False) is None


def test_roadmap_round_trips_and_refuses_what_is_not_one(roadmap):
    back = Roadmap.from_bytes(roadmap.to_bytes(), len(roadmap.nodes[0]))
    np.testing.assert_array_equal(back.nodes, roadmap.nodes)
    np.testing.assert_array_equal(back.edges, roadmap.edges)
    with pytest.raises(CellError, match="not a roadmap"):
        Roadmap.from_bytes(b"not an npz", 6, "x.npz")
    with pytest.raises(CellError, match=r"\(n, 7\)"):
        Roadmap.from_bytes(roadmap.to_bytes(), 7, "x.npz")


@pytest.mark.parametrize("name", ["bracket", "stepped_wall"])
def test_plan_through_the_roadmap_is_proven_all_along(name, roadmap, cell, world, tending):
    plan = plan_tending(cell, sheet(*SAMPLE_STOCK[name]), world=world, roadmap=roadmap)
    bare = tending("cell.yaml", sheet(*SAMPLE_STOCK[name]))
    assert [m.name for m in plan.moves] == [m.name for m in bare.moves]
    # The posted motion proven again, independently of the planner: the timed spline all along,
    # in the world of the plan (the blanks beside and the tray parts as obstacles).
    own = collision_world(cell, world.robot, obstacles=plan.obstacles)
    sweep = swept_motion(own, SMALL.joint_resolution)
    for m in plan.moves + plan.reject:
        if m.kind == "gripper":
            continue
        t = m.trajectory
        path = PPoly(t.coefficients, t.breakpoints)
        assert sweep.first_contact(path, monotone_breaks(t.breakpoints, t.coefficients), m.held) is None, m.name
        assert own.path_free(t.resample(500.0).q, m.held) is None, m.name


def test_transfer_that_is_not_straight_goes_through_the_roadmap(roadmap, cell, world):
    p = MotionPlanner(cell, world, roadmap=roadmap)
    home = np.asarray(cell.robot.home, dtype=float)
    # a node the straight joint segment from home cannot reach (it sweeps the arm through a box)
    blocked = [q for q in roadmap.nodes if not p.edge_free(home, q, None)]
    assert blocked, "every roadmap node is a straight segment from home"
    q = blocked[0]
    got = p.transfer(home, q, None, "test")
    assert got.search == "roadmap"
    np.testing.assert_allclose(got.waypoints[[0, -1]], [home, q])
    assert all(p.edge_free(a, b, None) for a, b in zip(got.waypoints[:-1], got.waypoints[1:]))
