"""Finishing entries (issue 32): no mill feeds straight down into stock; ramps are at most 3 deg.

Judged by the tests' own sweep (tests/cadcam/sweep.py), which shares nothing with the planner's
stock model: a plunge is a feed move straight down whose tool core (all but the sweep's EDGE)
cuts stock, as benchmarks/freecad_peer.py counts them.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from hypothesis import example, given
from hypothesis import strategies as st

from cadcam.entries import RAMP_ANGLE, _ramped
from cadcam.finishing import DESCENT_MARGIN, FinishingOptions, raster_finishing
from cadcam.gcode import parse_gcode
from cadcam.mesh import load_part
from cadcam.model import Motion
from cadcam.plan import plan_job
from cadcam.post import PostOptions, post_process
from cadcam.roughing import zlevel_roughing
from cadcam.setup import make_setup
from cadcam.stock import clear_height, stock_after
from cadcam.tools import load_tool_library
from tests.cadcam.sweep import sweep_moves
from tests.cadcam.test_finishing import CUTTING, TOL, hemisphere_on_block, setup_for, tool, worst_gouge

ROOT = Path(__file__).resolve().parents[2]
#: Stock a move's core must cut to count [mm] (thinner is the sweep grid's noise).
ENGAGED_MM = 0.05


def _plunges(moves, sweep, tools) -> np.ndarray:
    """Indices of mill feed moves straight down whose core cuts stock."""
    step = np.diff(moves.points, axis=0)
    down = (moves.motion[1:] != Motion.RAPID) & (step[:, 2] < -1e-3) & (np.hypot(step[:, 0], step[:, 1]) < 1e-3)
    mills = ~np.isin(moves.tool[1:], [n for n, t in tools.items() if t.shape == "drill"])
    return np.flatnonzero(down & mills & (sweep.buried[1:] > ENGAGED_MM)) + 1


def test_dome_finishing_ball_enters_without_plunging(tmp_path):
    library = load_tool_library()
    setup, part = make_setup(load_part(ROOT / "samples" / "dome_mould.stl").mesh)
    job = plan_job(part, setup, library, part_name="dome_mould").job
    program = post_process(job, PostOptions())
    tools = {t.number: t for t in job.tools}
    moves = parse_gcode(program.text)
    sweep = sweep_moves(moves.points, moves.motion, moves.tool, tools, job.setup, 0.5)
    bad = _plunges(moves, sweep, tools)
    assert not len(bad), [(int(moves.tool[i]), round(float(sweep.buried[i]), 2)) for i in bad]
    # The entries are still there: the ball finishes (ramps cut, not skipped).
    assert any(op.kind == "waterline" and len(op.points) for op in job.operations)


chains = st.integers(3, 30).flatmap(lambda n: st.tuples(
    st.lists(st.tuples(st.floats(-20, 20), st.floats(-20, 20), st.floats(-5, 0)), min_size=n, max_size=n),
    st.booleans(), st.floats(0.01, 3.0)))


def _on_chain(p: np.ndarray, c: np.ndarray) -> float:
    """Distance [mm] from point ``p`` to the polyline ``c`` (n, 3)."""
    a, b = c[:-1], c[1:]
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0.0, 1.0)
    return float(np.min(np.linalg.norm(a + t[:, None] * ab - p, axis=1)))


def assert_ramp_holds(c: np.ndarray, rise: float) -> None:
    """The ramp into chain ``c`` from ``rise`` [mm] over its start falls at the ramp angle and never steeper,
    meets the chain, and the whole chain is cut after it."""
    tan = math.tan(math.radians(RAMP_ANGLE))
    out, n = _ramped(c, float(c[0, 2]) + rise, tan)
    assert out[0, 2] == c[0, 2] + rise and np.allclose(out[0, :2], c[0, :2])
    # No ramp only where the chain itself first climbs straight up to where the ramp starts.
    first = int(np.argmax(np.linalg.norm(c[:, :2] - c[0, :2], axis=1) > 1e-9))  # the first point off the start
    assert n > 0 or c[:first, 2].max() >= c[0, 2] + rise
    ramp = out[:n + 1]
    xy = np.linalg.norm(np.diff(ramp[:, :2], axis=0), axis=1)
    fall = -np.diff(ramp[:, 2])
    assert not np.any((xy < 1e-9) & (fall > 1e-9)), "a vertical descent on the ramp"
    # Every move of the ramp falls tan per mm sideways: never steeper, whatever the chain does under it.
    assert np.allclose(fall, xy * tan, rtol=1e-6, atol=1e-9), "a ramp move steeper or shallower than the angle"
    # It ends on the chain, no lower than the chain's lowest point, and no farther than out and back along the
    # chain by a level ramp's length (and a segment).
    assert _on_chain(ramp[-1], c) < 1e-6
    assert xy.sum() <= (c[0, 2] + rise - c[:, 2].min()) / tan + 1e-6
    longest = np.linalg.norm(np.diff(c[:, :2], axis=0), axis=1).max()
    assert xy.sum() <= 2 * (rise / tan + longest) + 1e-6
    if np.all(c[:, 2] == c[0, 2]):  # on a level chain the ramp is rise / tan long
        assert math.isclose(xy.sum(), rise / tan, rel_tol=1e-6)
    # After the ramp the tool is on the chain: every chain point is visited at its own height.
    rest = out[n:]
    for p in c:
        assert np.min(np.linalg.norm(rest - p, axis=1)) < 1e-6


@given(chains)
@example(([(0.0, 0.0, -1.0), (10.0, 0.0, -1.0), (10.0, 5.0, -1.0)], True, 1.0))  # a level loop
@example(([(0.0, 0.0, 0.0), (0.001, 0.0, -5.0), (0.0, 1.0, 0.0)], False, 1.0))  # a drop nearly straight down
@example(([(0.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0)], True, 1.0))  # a loop stepping straight down
@example(([(0.0, 0.0, -1.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0)], False, 1.0))  # one climbing straight to the top
# Found by an explore run (2026-11-27): a repeated start before the climb, and drops over 1e-9 to 1e-8 mm sideways,
# where the chain's height at the meeting point is ill-conditioned.
@example(([(1.0, 0.0, -1.0), (1.0, 0.0, -1.0), (1.0, 0.0, 0.0), (0.0, 0.0, 0.0)], False, 1.0))
@example(([(0.0, 0.0, 0.0), (0.0, 1e-09, -1.0), (0.0, 1.0, -1.0)], False, 1.0))
@example(([(0.0, 1.0, -3.875), (0.0, 0.0, -3.0), (0.0, 1.3687929638389273e-08, 0.0)], False, 1.0))
def test_ramp_falls_no_steeper_than_the_angle_and_cuts_the_whole_chain(drawn):
    pts, closed, rise = drawn
    c = np.array(pts, dtype=float)
    if closed:
        c = np.vstack([c, c[:1]])
    if np.linalg.norm(np.diff(c[:, :2], axis=0), axis=1).sum() < 1.0:
        return
    assert_ramp_holds(c, rise)


def test_a_chain_stepping_straight_down_is_ramped_without_a_vertical_descent():
    """Found by the suite's fixed draw (2026-11-27): the ramp copied the chain's own drop, straight down."""
    assert_ramp_holds(np.array([(0.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0)]), 1.0)


def test_a_balls_descent_is_fed_at_the_plunge_feed_only_in_the_last_margin_over_the_stock():
    """Issue 32: the raster's descents fed the whole 1 mm clearance at the plunge feed (dome_mould: 17 s). Through
    the clearance the stock model (conservative between its points) holds air, so that stretch is a cutting move;
    only the last :data:`DESCENT_MARGIN` over the stock, where it may be short of the real stock, is a plunge."""
    setup, part = setup_for(), hemisphere_on_block()
    flat, ball = tool("flat", 8.0), tool("ball", 6.0)
    stock = stock_after([zlevel_roughing(part, setup, flat, CUTTING)], setup, np.asarray(part.triangles), 0.5)
    op = raster_finishing(part, setup, ball, CUTTING, FinishingOptions(scallop=0.01), stock=stock)
    p, m = op.points, op.motion
    step = np.diff(p, axis=0)
    down = (m[1:] != Motion.RAPID) & (step[:, 2] < -1e-9) & (np.hypot(step[:, 0], step[:, 1]) < 1e-9)
    top = clear_height(stock, ball, p[1:][down][:, :2])
    start, kind = p[:-1][down][:, 2], m[1:][down]
    # the plunge feed only from DESCENT_MARGIN over the stock down; the cutting feed only above it, in air
    plunges = kind == Motion.PLUNGE
    assert np.all(start[plunges] <= top[plunges] + DESCENT_MARGIN + 1e-9)
    fed = (kind == Motion.CUT) & (m[:-1][down] == Motion.RAPID)  # a descent from the rapid's end (not a chain's drop)
    assert np.all(p[1:][down][fed][:, 2] >= top[fed] + DESCENT_MARGIN - 1e-9)
    # the descents are there: fed through the clearance, each ending where a plunge (or the chain) takes over
    assert np.count_nonzero(fed) >= 3
    assert not worst_gouge(op, part, ball, setup.floor_z) > TOL


def test_a_finishing_helix_into_a_roughed_counterbore_starts_just_over_what_is_left():
    """plate_bosses: T2 rests-roughs its three counterbores to 0.3 mm over their floors; its flats and walls then
    enter each by the narrowest helix it may take, whose circle keeps the tool off the wall's skin, from just over
    the floor's skin, not by the wider one from the top floor through 5 mm of air (on main: 5.0 mm of ramp each);
    verify, holding every chip to fz, passes the program."""
    from tests.cadcam.test_plan import assert_verified_with_chips, sample_op1

    setup, part, job = sample_op1("plate_bosses")
    op = next(o for o in job.operations if o.name == "finish flats+walls T2")
    step = np.diff(op.points, axis=0)
    ramp = (op.motion[1:] == Motion.PLUNGE) & (step[:, 2] < -1e-9) & (np.hypot(step[:, 0], step[:, 1]) > 1e-6)
    edges = np.flatnonzero(np.diff(np.r_[0, ramp.astype(np.int8), 0]))
    drops = [float(op.points[s, 2] - op.points[e, 2]) for s, e in zip(edges[::2], edges[1::2])]
    assert len(drops) >= 3 and max(drops) < 1.0, drops
    assert_verified_with_chips(job, setup, part)


def _whole_walk(c: np.ndarray, idx: np.ndarray, need: float, more: int) -> tuple[np.ndarray, np.ndarray, int]:
    """:func:`cadcam.entries._walked` as the ramp measured its walk before (issue 35): the whole of it, every lap."""
    walk = c[idx]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(walk[:, :2], axis=0), axis=1))])
    return walk, s, int(np.argmax(s >= need))


@given(chains, st.integers(0, 3))
@example(([(0.0, 0.0, -1.0), (10.0, 0.0, -1.0), (10.0, 5.0, -1.0)], True, 1.0), 0)  # a level loop
@example(([(0.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0)], True, 1.0), 0)  # a loop stepping straight down
def test_the_ramp_measures_as_much_of_its_walk_as_it_goes_and_gives_the_whole_walks_ramp(drawn, repeat):
    """The walk measured in doubling prefixes (:func:`cadcam.entries._walked`) holds the whole walk's first points
    and distances, the same first point ``need`` along, and a loop's next lap past it; the ramped chain is the one
    the whole walk gives, to the bit. ``repeat``: the chain's points that many times over (long chains, several
    prefixes)."""
    import cadcam.entries as entries

    pts, closed, rise = drawn
    c = np.array(pts, dtype=float)
    if closed:
        c = np.vstack([c, c[:1]])
    for _ in range(repeat):  # the same shape again, shifted along x: a longer chain
        c = np.vstack([c, c[1:] + [np.ptp(c[:, 0]) + 1.0, 0.0, 0.0]]) if not closed else np.vstack([c, c[1:]])
    if np.linalg.norm(np.diff(c[:, :2], axis=0), axis=1).sum() < 1.0:
        return
    tan = math.tan(math.radians(RAMP_ANGLE))
    m = len(c) - 1
    length = float(np.linalg.norm(np.diff(c[:, :2], axis=0), axis=1).sum())
    laps = int(math.ceil(rise / tan / length)) + 1
    idx = np.concatenate([np.arange(m + 1)] + [np.arange(1, m + 1)] * laps)
    for need in (rise / tan, 0.3 * length, 1.5 * length):
        walk, s, j = entries._walked(c, idx, need, m if closed else 0)
        whole, s_all, j_all = _whole_walk(c, idx, need, m if closed else 0)
        assert j == j_all and np.array_equal(s, s_all[:len(s)]) and np.array_equal(walk, whole[:len(walk)])
        assert len(s) == len(s_all) or j + (m if closed else 0) < len(s)
    got = _ramped(c, float(c[0, 2]) + rise, tan)
    walked = entries._walked
    entries._walked = _whole_walk
    try:
        want = _ramped(c, float(c[0, 2]) + rise, tan)
    finally:
        entries._walked = walked
    assert got[1] == want[1] and np.array_equal(got[0], want[0])
