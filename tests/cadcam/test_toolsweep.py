"""cadcam.toolsweep: the compiled sweep gives every tool shape's lowest point over each grid point, on every kind
of move, as dense sampling of the move finds it; and the running minimum is the earlier moves' (issue 35)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam import toolsweep
from cadcam.envelope import Segments, pair_envelope
from cadcam.model import Tool
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
