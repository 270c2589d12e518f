"""cadcam.toolsweep: the compiled sweep gives every tool shape's lowest point over each grid point, on every kind
of move, as dense sampling of the move finds it; and the running minimum is the earlier moves' (issue 35)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam import toolsweep
from cadcam.engagement import MoveRecord, _across, _side_chip
from cadcam.envelope import SpanTops, Segments, grid_pairs, pair_envelope, row_lower
from cadcam.heightmap import grid_over
from cadcam.model import BALL as BALL_SHAPE
from cadcam.model import CONE, Tool
from tests.cadcam.test_verify import BALL, BULL, FLAT, brute_envelope, dist_to_segment

DRILL = Tool(5, "5 mm twist drill", "drill", 5.0, 0.0, 30.0, 2, 50.0, point_angle=118.0)
SPOT = Tool(6, "6 mm 90 deg spot drill", "drill", 6.0, 0.0, 10.0, 2, 40.0, point_angle=90.0)
SMALL_BULL = Tool(7, "4 mm bull r0.5", "bull", 4.0, 0.5, 12.0, 3, 30.0)
TOOLS = (FLAT, BALL, BULL, SMALL_BULL, DRILL, SPOT)

coord = st.floats(-4, 4, allow_nan=False, allow_infinity=False)
step = st.floats(-5, 5, allow_nan=False, allow_infinity=False).filter(lambda v: abs(v) > 1e-3)


@st.composite
def moves(draw):
    """A straight move of one kind: ``(start, end)`` tool tip positions [mm]."""
    kind = draw(st.sampled_from(["horizontal", "vertical", "sloped", "ramp"]))
    p0 = np.array([draw(coord), draw(coord), draw(coord)])
    d = {"horizontal": (draw(step), draw(step), 0.0), "vertical": (0.0, 0.0, draw(step)),
         "sloped": (draw(step), draw(step), draw(step)), "ramp": (draw(step), draw(step), draw(step) * 0.05)}[kind]
    return p0, p0 + np.array(d)


@settings(max_examples=60, deadline=None)
@given(moves=st.lists(st.tuples(st.sampled_from(range(len(TOOLS))), moves()), min_size=1, max_size=6),
       seed=st.integers(0, 2**32 - 1))
def test_every_shape_on_every_kind_of_move_is_the_lowest_point_of_the_swept_tool(moves, seed):
    """Moves of mixed tools in one call (the kernel chooses each pair's formula by its move's shape), each grid
    point paired with every move: the envelope is dense sampling's minimum, never above it."""
    tools = [TOOLS[i] for i, _ in moves]
    p0 = np.array([m[0] for _, m in moves])
    p1 = np.array([m[1] for _, m in moves])
    seg = Segments.between(p0, p1, [t.radius for t in tools], [float(t.corner_radius) for t in tools],
                           cone=[t.point_slope for t in tools])
    q = np.random.default_rng(seed).uniform(-10, 10, (150, 2))
    owner = np.repeat(np.arange(len(moves)), len(q))
    qq = np.tile(q, (len(moves), 1))
    env = pair_envelope(qq[:, 0].copy(), qq[:, 1].copy(), owner, seg).reshape(len(moves), len(q))
    for k, tool in enumerate(tools):
        brute = brute_envelope(q, p0[k], p1[k], tool)
        reached = np.isfinite(brute)
        assert np.all(np.isfinite(env[k, reached])), f"{tool.name}: a point the tool passes over was missed"
        assert np.all(env[k, reached] <= brute[reached] + 1e-9), tool.name
        assert np.all(brute[reached] - env[k, reached] <= 2e-5), tool.name
        # only a sliver at the tool's reach is finite without the sampling landing on it
        beside = np.isfinite(env[k, ~reached])
        away = dist_to_segment(q[~reached, 0], q[~reached, 1], p0[k], p1[k])
        assert np.all(away[beside] > tool.radius - 1e-3), tool.name


@settings(max_examples=60, deadline=None)
@given(groups=st.lists(st.integers(0, 5), min_size=1, max_size=60),
       values=st.lists(st.one_of(st.floats(-1e3, 1e3), st.just(np.inf)), min_size=60, max_size=60))
def test_the_running_minimum_is_the_earlier_entries_of_each_run(groups, values):
    group = np.sort(np.array(groups))
    value = np.array(values[:len(group)])
    out = toolsweep.segmented_exclusive_min(group, value)
    finite = value[np.isfinite(value)]
    # the runs are lifted apart by multiples of twice the values' span: the minimum is read back exactly, but
    # values closer than the lift's rounding are one to it
    slack = 4 * np.finfo(float).eps * 2 * (np.ptp(finite) + 1.0) * len(np.unique(group)) if len(finite) else 0.0
    for i in range(len(group)):
        earlier = value[:i][group[:i] == group[i]]
        if not len(earlier) or np.isinf(earlier).all():
            assert out[i] == np.inf
        else:
            assert out[i] in earlier and out[i] - earlier.min() <= slack


def _segments(moves):
    tools = [TOOLS[i] for i, _ in moves]
    p0 = np.array([m[0] for _, m in moves])
    p1 = np.array([m[1] for _, m in moves])
    seg = Segments.between(p0, p1, [t.radius for t in tools], [float(t.corner_radius) for t in tools],
                           cone=[t.point_slope for t in tools])
    return seg, p0, p1, tools


GRID = grid_over(np.array([-9.0, -7.0, -5.0]), np.array([9.0, 7.0, 5.0]), 0.2)


@settings(max_examples=40, deadline=None)
@given(moves=st.lists(st.tuples(st.sampled_from(range(len(TOOLS))), moves()), min_size=1, max_size=5),
       seed=st.integers(0, 2**32 - 1), cut=st.floats(0.0, 6.0))
def test_the_compiled_pairs_are_every_grid_point_in_reach_and_the_cull_drops_only_points_the_tool_stays_over(
        moves, seed, cut):
    """The runs, pieces and pairs (:func:`cadcam.envelope.grid_pairs`, compiled): without a bound, each move's
    pairs hold, in grid order, every grid point within its radius of its XY segment, none beyond its box;
    against a stock's :class:`SpanTops`, the pairs dropped are ones whose envelope stays at or over the stock,
    each run's bound is at least the stock's highest over it, and :func:`row_lower` is under every point's
    cheap bound on its row."""
    seg, p0, p1, tools = _segments(moves)
    owner, flat, col, row = grid_pairs(seg, GRID)
    assert np.array_equal(flat, row * GRID.nx + col)
    key = owner * GRID.size + flat
    assert np.all(np.diff(key) > 0)  # each move's points once, row by row, column by column
    X, Y = GRID.x0 + col * GRID.cell, GRID.y0 + row * GRID.cell
    xs, ys = np.meshgrid(GRID.xs, GRID.ys)
    for k, tool in enumerate(tools):
        d_all = dist_to_segment(xs.ravel(), ys.ravel(), p0[k], p1[k])
        mine = np.flatnonzero(owner == k)
        assert set(np.flatnonzero(d_all <= tool.radius).tolist()) <= set(flat[mine].tolist()), tool.name
        lo, hi = np.minimum(p0[k], p1[k])[:2] - tool.radius - 1e-6, np.maximum(p0[k], p1[k])[:2] + tool.radius + 1e-6
        assert np.all((X[mine] >= lo[0]) & (X[mine] <= hi[0]) & (Y[mine] >= lo[1]) & (Y[mine] <= hi[1]))
    rng = np.random.default_rng(seed)
    stock = 5.0 - cut * rng.random(GRID.size) * (rng.random(GRID.size) < 0.7)
    tops = SpanTops(stock, GRID)
    kept = grid_pairs(seg, GRID, tops.above)
    kept_key = kept[0] * GRID.size + kept[1]
    assert np.all(np.diff(kept_key) > 0) and set(kept_key.tolist()) <= set(key.tolist())
    dropped = ~np.isin(key, kept_key)
    env = pair_envelope(X[dropped], Y[dropped], owner[dropped], seg)
    assert np.all(env >= stock[flat[dropped]]), "a pair the tool cuts was dropped"
    r0, c0 = rng.integers(0, GRID.ny, 50), rng.integers(0, GRID.nx, 50)
    n = np.minimum(rng.integers(1, GRID.nx + 1, 50), GRID.nx - c0)
    top = rng.random(GRID.shape)  # every point its own height: a bound that misses a block is caught
    rough = SpanTops(top.ravel(), GRID)
    assert all(rough.above(r0[i:i + 1], c0[i:i + 1], n[i:i + 1])[0] >= top[r0[i], c0[i]:c0[i] + n[i]].max()
               for i in range(50))
    lower = row_lower(seg, owner, Y)
    stretch = row_lower(seg, owner, Y, X - GRID.cell, X + GRID.cell)
    near = np.hypot(*[np.maximum(np.maximum(np.minimum(a, a + d) - v, v - np.maximum(a, a + d)), 0.0)
                      for a, d, v in ((seg.x[owner], seg.dx[owner], X), (seg.y[owner], seg.dy[owner], Y))])
    bound = seg.zmin[owner] + np.array([Tool.profile_height(tools[o], min(r, tools[o].radius)) for o, r in
                                        zip(owner, near)])
    assert np.all(lower <= bound + 1e-9) and np.all(stretch <= bound + 1e-9) and np.all(lower <= stretch + 1e-12)


def _chip_by_hand(seg, o, q, w, before, env, cell):
    """The chip share of one pair, as :func:`cadcam.engagement._side_chip` documents it, in plain Python."""
    r, rc, z, dz = seg.radius[o], seg.rc[o], seg.z[o], seg.dz[o]
    if seg.shape[o] == BALL_SHAPE and dz != 0.0:  # a ball on a slope: the sphere's front at the column's nearest stock
        u = np.array([seg.dx[o], seg.dy[o], dz]) / np.sqrt(seg.l2[o] + dz * dz)
        a = np.array([q[0] - seg.x[o], q[1] - seg.y[o], -(z + r)])
        hs = np.linspace(env, before, 2001)
        d = min(np.linalg.norm(np.cross(a + np.array([0, 0, h]), u)) for h in hs)
        return np.sqrt(1 - np.clip((d - 0.5 * cell) / r, 0, 1) ** 2)
    if seg.shape[o] == CONE or dz != 0.0:
        rc = 0.0
    below = max(rc - (before - z), 0.0)
    reach = np.sqrt(max(rc * rc - below * below, 0.0))
    lead = reach / rc if rc > 0 else 1.0
    return lead * np.sqrt(1 - np.clip((abs(w) - 0.5 * cell) / (r - rc + reach), 0, 1) ** 2)


@settings(max_examples=40, deadline=None)
@given(moves=st.lists(st.tuples(st.sampled_from(range(len(TOOLS))), moves()), min_size=1, max_size=4),
       seed=st.integers(0, 2**32 - 1))
def test_the_compiled_chip_is_the_documented_one_of_each_point_the_largest_kept_per_move(moves, seed):
    """:func:`cadcam.engagement._side_chip` (compiled): each move keeps the largest chip share of its points, each
    the rule written out by hand (a ball on a slope searched along the column), and :func:`_across` is each point's
    signed distance across its move."""
    seg, p0, p1, tools = _segments(moves)
    rng = np.random.default_rng(seed)
    o = rng.integers(0, len(tools), 30)
    q = rng.uniform(-8, 8, (30, 2))
    lat, has = _across(seg, o, q[:, 0], q[:, 1])
    d = np.hypot(seg.dx[o], seg.dy[o])
    by_hand = np.where(d > 1e-9, ((q[:, 0] - seg.x[o]) * seg.dy[o] - (q[:, 1] - seg.y[o]) * seg.dx[o]) / np.maximum(
        d, 1e-300), q[:, 0] - seg.x[o])
    assert np.array_equal(has, d > 1e-9) and np.allclose(lat, by_hand, atol=1e-9)
    env = seg.z[o] + rng.uniform(0, 3, 30)
    before = env + rng.uniform(0.01, 4, 30)
    stats = MoveRecord(len(tools) + 2)
    _side_chip(seg, o, q[:, 0], q[:, 1], lat, before, env, 0.2, 2, stats)
    want = np.zeros(len(tools) + 2)
    for i in range(30):
        want[o[i] + 2] = max(want[o[i] + 2], _chip_by_hand(seg, o[i], q[i], lat[i], before[i], env[i], 0.2))
    assert np.allclose(stats.chip, want, atol=2e-3, rtol=0)
