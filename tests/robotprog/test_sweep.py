"""Continuous collision proof (robotprog.sweep): the motion bound holds, a graze between the
planner's 0.02 rad checks is caught, a path proven free is free when sampled finely, and the
spline is cut where joints turn."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.interpolate import CubicSpline

from robotprog.cell import Box, Pose
from robotprog.collision import HeldBox, collision_world, finger_boxes
from robotprog.sweep import WIDE_MARGIN_M, _wide, _within, monotone_breaks, swept_motion
from robotprog.planner import MotionPlanner, PlannerOptions

STEP = PlannerOptions().joint_resolution


@pytest.fixture(scope="module")
def sweep(world):
    return swept_motion(world, STEP)


def _corners(world, q):
    """(ngeoms, 8, 3) AABB corners of every robot geometry at ``q`` in the model frame [m]."""
    model, data, gm = world.robot.model, world.robot.model.createData(), world.geometry
    pin.framesForwardKinematics(model, data, q)
    gd = pin.GeometryData(gm)
    pin.updateGeometryPlacements(model, data, gm, gd)
    out = []
    for i, g in enumerate(gm.geometryObjects):
        if g.parentJoint == 0:
            continue
        g.geometry.computeLocalAABB()
        lo, hi = np.asarray(g.geometry.aabb_local.min_), np.asarray(g.geometry.aabb_local.max_)
        c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        m = gd.oMg[i]
        out.append((i, c @ m.rotation.T + m.translation))
    return out


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(-3.0, 3.0), min_size=6, max_size=6), st.lists(st.floats(-0.05, 0.05), min_size=6,
                                                                          max_size=6))
def test_no_point_moves_further_than_the_bound(world, sweep, q, dq):
    """Every bounding corner of every link moves at most its chain's rate times the joint motion
    (relative to the cell: the rows of a link against a static box)."""
    q, dq = np.array(q), np.array(dq)
    a, b = dict(_corners(world, q)), dict(_corners(world, q + dq))
    gm = world.geometry
    for k, pair in enumerate(gm.collisionPairs):
        links = [i for i in (pair.first, pair.second) if gm.geometryObjects[i].parentJoint != 0]
        if len(links) != 1:
            continue
        moved = np.linalg.norm(b[links[0]] - a[links[0]], axis=1).max()
        assert moved <= sweep.pair_rates[k] @ np.abs(dq) + 1e-12


ROD = HeldBox.at((0.001, 0.001, 0.1), np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.05], [0, 0, 0, 1.0]]), 0.0,
                 "rod")


def test_a_graze_between_the_checks_is_caught(world, cell):
    """A 1 mm rod hanging from the TCP passes through a 1 mm plate while the base turns 0.02 rad:
    free at both ends (the planner's discrete check), through the plate in between."""
    planner = MotionPlanner(cell, world)
    a = np.asarray(cell.robot.home, dtype=float)
    b = a.copy()
    b[0] += STEP

    def tip(q):  # the rod's lower part [m], world frame
        return (planner.tcp_world(q) @ np.array([0.0, 0.0, 0.09, 1.0]))[:3]

    x = tip(b) - tip(a)
    x /= np.linalg.norm(x)
    z = planner.tcp_world((a + b) / 2)[:3, 2]
    z = z - (z @ x) * x
    z /= np.linalg.norm(z)
    rot = np.column_stack([x, np.cross(z, x), z])
    plate = Box("thin_plate", (0.001, 0.02, 0.02),
                Pose(tuple(float(v) for v in tip((a + b) / 2)), tuple(float(v) for v in pin.rpy.matrixToRpy(rot))))
    w = collision_world(cell, world.robot, obstacles=(plate,))
    assert w.path_free(planner.densify(np.array([a, b])), ROD) is None  # the 0.02 rad check misses it
    assert w.in_collision((a + b) / 2, ROD)
    hit = swept_motion(w, STEP).polyline_contact(np.array([a, b]), ROD)
    assert hit is not None and 0.0 < hit[0] <= 1.0 and hit[1] == "rod <-> thin_plate"
    assert swept_motion(world, STEP).polyline_contact(np.array([a, b]), ROD) is None


def test_a_path_proven_free_is_free_all_along(world, sweep, cell):
    rng = np.random.default_rng(5)
    home = np.asarray(cell.robot.home)
    fingers = finger_boxes(cell, 0.08)
    held = fingers + (HeldBox.at((0.1, 0.06, 0.02), np.eye(4)),)
    proven = 0
    for _ in range(60):
        a = home + rng.normal(0, 0.4, 6)
        b = a + rng.normal(0, 0.3, 6)
        if sweep.polyline_contact(np.array([a, b]), held) is None:
            proven += 1
            f = np.linspace(0, 1, 2001)[:, None]
            assert world.path_free(a + f * (b - a), held) is None
    assert proven >= 5


def test_spline_pieces_between_breaks_are_monotone():
    rng = np.random.default_rng(2)
    wp = np.cumsum(rng.normal(0, 0.5, (7, 6)), axis=0)
    sp = CubicSpline(np.linspace(0, 3, 7), wp, bc_type="not-a-knot")
    breaks = monotone_breaks(sp.x, sp.c)
    assert breaks[0] == 0 and breaks[-1] == 3 and len(breaks) > 7
    for lo, hi in zip(breaks[:-1], breaks[1:]):
        q = sp(np.linspace(lo, hi, 50))
        d = np.diff(q, axis=0)
        assert ((d >= -1e-12).all(axis=0) | (d <= 1e-12).all(axis=0)).all()


def test_standing_still_is_checked_exactly(world, sweep, cell):
    home = np.asarray(cell.robot.home)
    assert sweep.polyline_contact(np.array([home, home])) is None
    bad = home.copy()
    bad[1] = -0.6
    hit = sweep.polyline_contact(np.array([bad]))
    assert hit is not None and "mill_table" in hit[1]


def test_a_blended_corner_is_proven_over_its_whole_triangle(world, cell):
    """A controller's blend round a corner runs inside the triangle of the corner and its segments'
    midpoints. A 5 mm cube at the rod's tip where the arm stands at the triangle's centroid lies
    off the corner's polyline and off its chord (the old sampled check passes), inside the
    triangle: the corner proof finds it, and proves the same corner free without the cube."""
    planner = MotionPlanner(cell, world)
    c = np.asarray(cell.robot.home, dtype=float)
    a, b = c.copy(), c.copy()
    # the base turns into the corner, then the elbow bends out of it; turned away from the vise, whose
    # 6-inch body the rod's triangle would graze the other way round
    a[0] += 0.3
    b[2] += 0.3
    centroid = (a + b + c) / 3
    tip = planner.tcp_world(centroid) @ np.array([0.0, 0.0, 0.09, 1.0])
    cube = Box("cube", (0.005, 0.005, 0.005), Pose(tuple(float(v) for v in tip[:3]), (0.0, 0.0, 0.0)))
    w = collision_world(cell, world.robot, obstacles=(cube,))
    assert w.in_collision(centroid, ROD)
    assert w.path_free(planner.densify(np.array([a, c, b])), ROD) is None  # the polyline misses it
    assert w.path_free(planner.densify(np.array([a, b])), ROD) is None  # and so does the chord
    assert swept_motion(w, STEP).corner_contact(a, c, b, ROD) == "rod <-> cube"
    assert swept_motion(world, STEP).corner_contact(a, c, b, ROD) is None


@settings(max_examples=15, deadline=None)
@given(st.lists(st.floats(-0.4, 0.4), min_size=12, max_size=12), st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_a_corner_proven_free_is_free_inside(world, sweep, cell, offsets, u, v):
    """Wherever a corner's proof says free, a point inside its triangle is free (the held box too)."""
    c = np.asarray(cell.robot.home, dtype=float)
    a, b = c + np.array(offsets[:6]), c + np.array(offsets[6:])
    if u + v > 1:
        u, v = 1 - u, 1 - v
    held = finger_boxes(cell, 0.08) + (HeldBox.at((0.1, 0.06, 0.02), np.eye(4)),)
    if sweep.corner_contact(a, c, b, held) is None:
        assert not world.in_collision(c + u * (a - c) + v * (b - c), held)


def test_room_proven_around_a_path_is_free(world, sweep, cell):
    """A path proven with a tube: every configuration within the tube of it, joint by joint, is
    free; a tube wider than a path's clearance is refused where the path alone is proven."""
    rng = np.random.default_rng(11)
    home = np.asarray(cell.robot.home)
    held = finger_boxes(cell, 0.08) + (HeldBox.at((0.1, 0.06, 0.02), np.eye(4)),)
    tube = np.full(6, 0.01)
    proven = 0
    for _ in range(40):
        a = home + rng.normal(0, 0.4, 6)
        b = a + rng.normal(0, 0.3, 6)
        if sweep.polyline_contact(np.array([a, b]), held) is not None:
            continue
        path = lambda s: a + np.asarray(s)[:, None] * (b - a)  # noqa: E731
        if sweep.first_contact(path, np.array([0.0, 1.0]), held, tube) is None:
            proven += 1
            f = rng.random(300)[:, None]
            corners = path(f[:, 0]) + tube * rng.choice([-1.0, 1.0], (300, 6))
            assert world.path_free(corners, held) is None
    assert proven >= 3
    # standing still next to the mill table, clear by less than a wide tube's reach
    near = home.copy()
    lo, hi = home[1], -0.6
    for _ in range(40):  # the shoulder angle where the arm just clears the table
        mid = 0.5 * (lo + hi)
        near[1] = mid
        lo, hi = (mid, hi) if sweep.polyline_contact(np.array([near])) is None else (lo, mid)
    near[1] = lo
    assert sweep.polyline_contact(np.array([near, near])) is None
    wide = np.full(6, 0.05)
    assert sweep.first_contact(lambda s: np.repeat(near[None], len(s), 0), np.array([0.0, 1.0]), None,
                               wide) is not None


@settings(max_examples=20, deadline=None)
@given(st.lists(st.floats(-3.0, 3.0), min_size=6, max_size=6), st.floats(0.0, 0.4))
def test_a_wide_margin_between_meshes_asked_by_distance_is_the_collision_query(world, sweep, q, margin):
    """Between two meshes a wide margin is asked by coal's distance query (robotprog.sweep._within): it
    answers as the collision query with that security margin, pair by pair, wide or not."""
    rider = sweep._rider(None)
    g, gd = rider.geometry, pin.GeometryData(rider.geometry)
    pin.framesForwardKinematics(world.robot.model, world._data, np.array(q))
    pin.updateGeometryPlacements(world.robot.model, world._data, g, gd)
    margins = np.full(len(g.collisionPairs), margin)
    wide = _wide(rider.meshes, margins)
    assert (wide is not None) == (margin > WIDE_MARGIN_M) and rider.meshes.any()
    for k in np.flatnonzero(rider.meshes):
        gd.collisionRequests[int(k)].security_margin = margin
        d = pin.computeDistance(g, gd, int(k)).min_distance
        if abs(d - margin) > 1e-9:  # not on the margin itself, where either answer is a rounding
            assert bool(_within(g, gd, int(k), margins, wide)) == pin.computeCollision(g, gd, int(k))


def test_a_path_proven_with_wide_margins_by_distance_is_proven_alike(world, cell, monkeypatch):
    """The proof of a long transfer past the arm's own base (coarse levels: margins wider than
    WIDE_MARGIN_M between its meshes) finds the same as with every margin asked by collision query."""
    import robotprog.sweep as sweep_module

    p = MotionPlanner(cell, world)
    home = np.array(cell.robot.home)
    far = home + np.array([-1.1, 0.45, 0.05, 0.7, 0.45, -1.5])
    qs = p.densify(np.array([home, far]), 0.3)
    swept = swept_motion(world, STEP)
    found = swept.polyline_contact(qs)
    rider = swept._rider(None)  # the coarsest level asks some pair of meshes by distance
    assert _wide(rider.meshes, swept._margins(rider.rates, STEP * 2.0 ** -sweep_module.COARSEST_LEVEL)) is not None
    monkeypatch.setattr(sweep_module, "WIDE_MARGIN_M", np.inf)
    assert swept_motion(world, STEP).polyline_contact(qs) == found
