"""The machine timeline: tool position over time by the post's time model, and the stock as it is cut."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam.finishing import FinishingOptions
from cadcam.gcode import parse_gcode
from cadcam.model import CuttingData, Job, Motion, Operation, ProgramMoves, Tool
from cadcam.plan import PlanOptions, plan_job
from cadcam.post import PostOptions, post_process
from cadcam.setup import make_setup
from cadcam.timeline import MachineTimeline, machine_timeline, stock_snapshots
from cadcam.tools import load_tool_library
from cadcam.stock import cut_stock
from cadcam.verify import VerifyOptions, simulate
from factory.core.errors import GcodeError, VerifyError
from tests.conftest import pocket_block

R, C = int(Motion.RAPID), int(Motion.CUT)
RAPID_RATE = 5000.0  # PostOptions default [mm/min]


# --------------------------------------------------------------------------- synthetic programs


@st.composite
def programs(draw) -> ProgramMoves:
    """Random moves as the parser reports them: row 0 unknown, axes set one by one, tool changes, repeats."""
    n = draw(st.integers(1, 20)) + 1
    coord = st.floats(-50, 50, allow_nan=False, allow_infinity=False)
    pts = np.array(draw(st.lists(st.tuples(coord, coord, coord), min_size=n, max_size=n)), dtype=np.float64)
    for k in range(1, n):
        if draw(st.booleans()) and draw(st.booleans()):
            pts[k] = pts[k - 1]  # a move that goes nowhere
    for axis in range(3):  # each axis first programmed somewhere among the first moves
        pts[: draw(st.integers(1, min(3, n - 1))), axis] = np.nan
    pts[0] = np.nan
    motion = np.array([R] + draw(st.lists(st.sampled_from([R, C]), min_size=n - 1, max_size=n - 1)), np.int8)
    feeds = np.array([np.nan] + draw(st.lists(st.floats(10, 5000), min_size=n - 1, max_size=n - 1)))
    feeds[motion == R] = np.nan
    tool = np.array([0] + draw(st.lists(st.sampled_from([1, 1, 1, 2]), min_size=n - 1, max_size=n - 1)), np.int32)
    return ProgramMoves(pts, motion, tool, feeds, np.arange(n, dtype=np.int32))


def _speed(moves: ProgramMoves, i: int) -> float:
    """Speed of move i in the time model [mm/s], written out independently."""
    return (RAPID_RATE if moves.motion[i] == R else float(moves.feed[i])) / 60.0


@settings(max_examples=150, deadline=None)
@given(programs(), st.sampled_from(["linuxcnc", "grbl"]))
def test_position_is_piecewise_linear_along_the_moves_at_their_speeds(moves, dialect):
    tl = machine_timeline(moves, PostOptions(dialect=dialect))
    n = len(moves.points)
    # Time runs forward: each move ends after it starts, the next starts after that.
    assert tl.start[0] == tl.end[0] == 0.0
    assert np.all(tl.end >= tl.start)
    assert np.all(tl.start[1:] >= tl.end[:-1])
    # Where a coordinate is known the timeline holds the program's point.
    known = np.isfinite(moves.points)
    assert np.array_equal(tl.points[known], moves.points[known])
    assert np.isfinite(tl.points).all()
    for i in range(1, n):
        a, b = tl.points[i - 1], tl.points[i]
        s, e = tl.start[i], tl.end[i]
        if e > s:
            # At its start time the tool is exactly at the move's first point ...
            assert np.array_equal(tl.position_at([s])[0], a)
            # ... runs along the straight line at the move's speed ...
            u = np.array([0.25, 0.5, 0.9])
            np.testing.assert_allclose(tl.position_at(s + u * (e - s)), a + u[:, None] * (b - a), atol=1e-9)
            v = _speed(moves, i)
            assert np.linalg.norm(b - a) == pytest.approx(v * (e - s), rel=1e-9, abs=1e-12 * v * (1.0 + e))
            # ... and arrives continuously at the end point.
            np.testing.assert_allclose(tl.position_at([e - 1e-9 * (e - s)])[0], b, atol=1e-6)
            assert np.all(tl.tool_at(s + u * (e - s)) == moves.tool[i])
        if tl.start[i] > tl.end[i - 1]:
            # A pause (tool change): standing still at the move's first point.
            mid = 0.5 * (tl.end[i - 1] + tl.start[i])
            assert np.array_equal(tl.position_at([mid])[0], a)
            assert moves.tool[i] != moves.tool[i - 1]
    # Clamped at both ends; vectorised calls agree with one-at-a-time ones.
    assert np.array_equal(tl.position_at([-5.0]), tl.position_at([0.0]))
    assert np.array_equal(tl.position_at([tl.duration + 5.0])[0], tl.points[-1])
    ts = np.linspace(-1.0, tl.duration + 1.0, 17)
    assert np.array_equal(tl.position_at(ts), np.vstack([tl.position_at([t]) for t in ts]))
    assert tl.position_at(ts).shape == (17, 3) and tl.tool_at(ts).shape == (17,)


@settings(max_examples=60, deadline=None)
@given(programs())
def test_without_tool_changes_the_duration_is_length_over_speed(moves):
    tool = np.ones(len(moves.tool))  # loaded before the start
    moves = ProgramMoves(moves.points, moves.motion, tool, moves.feed, moves.line)
    tl = machine_timeline(moves)
    # The tool starts where each axis is first set, so moves from unknown places are free.
    p = tl.points
    expected = sum(np.linalg.norm(p[i] - p[i - 1]) / _speed(moves, i) for i in range(1, len(p)))
    assert tl.duration == pytest.approx(expected, rel=1e-12, abs=1e-12)


def test_tool_change_is_a_pause_and_the_traverse_after_it_is_free():
    pts = [[np.nan] * 3, [0, 0, 5], [0, 0, 0], [0, 0, 5], [30, 40, 5], [30, 40, 0]]
    moves = ProgramMoves(pts, [R, R, C, R, R, C], [0, 1, 1, 1, 2, 2], [np.nan, np.nan, 300, np.nan, np.nan, 600],
                         np.arange(6))
    tl = machine_timeline(moves, PostOptions(tool_change_time=7.0))
    # Load T1 (7 s), feed down 5 mm at 300 mm/min (1 s), rapid up 5 mm, change to T2 (7 s),
    # the 50 mm traverse in no time, feed down 5 mm at 600 mm/min (0.5 s).
    up = 5 / RAPID_RATE * 60
    assert tl.start.tolist() == pytest.approx([0, 7, 7, 8, 15 + up, 15 + up])
    assert tl.duration == pytest.approx(15.5 + up)
    assert tl.tool_at([3.0, 7.5, 10.0, 15.2]).tolist() == [0, 1, 1, 2]
    assert machine_timeline(moves, PostOptions(tool_change_time=7.0, dialect="grbl")).duration == pytest.approx(
        8.5 + up)


def test_sample_covers_the_program_at_the_rate():
    moves = ProgramMoves([[np.nan] * 3, [0, 0, 0], [10, 0, 0]], [R, R, C], [0, 1, 1], [np.nan, np.nan, 60.0],
                         np.arange(3))
    tl = machine_timeline(moves, PostOptions(tool_change_time=0.0))  # 10 s along X
    times, positions, tools = tl.sample(4.0)
    assert times[0] == 0.0 and times[-1] == tl.duration == pytest.approx(10.0)
    assert np.allclose(np.diff(times), 0.25)
    np.testing.assert_allclose(positions[:, 0], times, atol=1e-12)
    assert np.all(tools == 1)
    assert tl.sample(0.3).times.tolist() == pytest.approx([0.0, 10 / 3, 20 / 3, 10.0])
    assert len(tl.sample(0.25).times) == 4  # 0, 4, 8 on the grid, then the end
    with pytest.raises(ValueError):
        tl.sample(0.0)


def test_errors():
    never_y = ProgramMoves([[np.nan] * 3, [0, np.nan, 0]], [R, R], [0, 1], [np.nan] * 2, [0, 1])
    with pytest.raises(GcodeError, match="never sets Y"):
        machine_timeline(never_y)
    no_feed = ProgramMoves([[np.nan] * 3, [0, 0, 0], [1, 0, 0]], [R, R, C], [0, 1, 1], [np.nan, np.nan, 0.0],
                           [0, 1, 7])
    with pytest.raises(GcodeError, match="line 7"):
        machine_timeline(no_feed)
    with pytest.raises(ValueError):
        MachineTimeline(np.zeros((2, 3)), [0, 1], [0, 1], [0], [0, 1])


# --------------------------------------------------------------------------- posted programs


@pytest.fixture(scope="module")
def posted():
    setup, part = make_setup(pocket_block(), origin="top-centre", material="brass")
    job = plan_job(part, setup, load_tool_library(), part_name="block",
                      options=PlanOptions(finishing=FinishingOptions(scallop=0.2), waterline=False)).job
    return job, part


@pytest.mark.parametrize("dialect", ["linuxcnc", "fanuc", "grbl"])
def test_duration_is_the_posts_estimate(posted, dialect):
    job, _ = posted
    assert len({op.tool.number for op in job.operations}) >= 2  # tool changes in the middle
    opt = PostOptions(dialect=dialect, rapid_rate=4000.0, tool_change_time=6.0)
    program = post_process(job, opt)
    # Arcs parsed as chords 0.01 um from the arc: their shortfall stays far below the tolerance
    # however many helix entries the job has; what is left is the text's rounding (0.1 um, 0.1 mm/min).
    tl = machine_timeline(parse_gcode(program.text, arc_tolerance=1e-5), opt)
    assert tl.duration == pytest.approx(program.total_time, abs=0.01)


def test_duration_is_the_estimate_for_a_traverse_after_a_tool_change():
    # Two tools, and the second operation starts far from where the first ended.
    flat = Tool(1, "6 mm flat", "flat", 6.0, 0.0, 20.0, 3, 40.0)
    ball = Tool(4, "3 mm ball", "ball", 3.0, 1.5, 10.0, 2, 30.0)
    cd = CuttingData(10000, feed=600, plunge_feed=200)
    op1 = Operation("pocket", "roughing", flat, cd, [[0, 0, 1], [0, 0, -1], [30, 0, -1], [30, 40, -1]],
                    [R, Motion.PLUNGE, C, C])
    op2 = Operation("line", "raster", ball, cd, [[-50, -50, -1], [-20, -50, -1]], [R, C])
    op3 = Operation("back", "raster", ball, cd, [[-20, -40, -1], [-50, -40, -1]], [R, C])
    setup = make_setup(pocket_block(), origin="top-centre")[0]
    for dialect in ("linuxcnc", "fanuc", "grbl"):
        opt = PostOptions(dialect=dialect, arcs=False)
        program = post_process(Job("t", setup, (op1, op2, op3)), opt)
        tl = machine_timeline(parse_gcode(program.text), opt)
        assert tl.duration == pytest.approx(program.total_time, abs=1e-4), dialect


# --------------------------------------------------------------------------- stock snapshots


@pytest.fixture(scope="module")
def cut(posted):
    job, part = posted
    moves = parse_gcode(post_process(job).text)
    tools = {t.number: t for t in job.tools}
    tri = np.asarray(part.triangles)
    return moves, tools, job.setup, tri, machine_timeline(moves)


def test_snapshots_are_the_stock_of_the_program_so_far(cut):
    moves, tools, setup, tri, tl = cut
    times = [tl.duration + 1.0, 0.0, 0.3 * tl.duration, 0.7 * tl.duration, 0.3 * tl.duration]
    snaps = stock_snapshots(moves, tools, setup, tri, times, cell=1.0, timeline=tl)
    assert [t for t, _ in snaps] == times
    full = simulate(moves, tools, setup, tri, VerifyOptions(cell=1.0)).simulation
    assert np.array_equal(snaps[0][1].stock_top, full.stock_top)
    assert np.all(snaps[1][1].stock_top == setup.stock_max[2])  # loading the first tool: nothing cut yet
    assert np.array_equal(snaps[2][1].stock_top, snaps[4][1].stock_top)
    # Each snapshot is what simulating the program up to the move under way leaves.
    for t, sim in snaps[2:4]:
        m = int(tl.move_at([t])[0]) + 1
        head = ProgramMoves(moves.points[:m], moves.motion[:m], moves.tool[:m], moves.feed[:m], moves.line[:m])
        alone = simulate(head, tools, setup, tri, VerifyOptions(cell=1.0)).simulation
        assert np.array_equal(sim.stock_top, alone.stock_top)
        assert sim.grid == full.grid and np.array_equal(sim.part_top, full.part_top)
    assert not snaps[2][1].stock_top.flags.writeable


def test_snapshots_only_ever_lower_the_stock(cut):
    moves, tools, setup, tri, tl = cut
    snaps = stock_snapshots(moves, tools, setup, tri, np.linspace(0.0, tl.duration, 20), cell=1.0, timeline=tl)
    tops = np.stack([sim.stock_top for _, sim in snaps])
    assert np.all(np.diff(tops, axis=0) <= 0.0)
    assert (tops[0] - tops[-1]).sum() > 0.0
    removed = (tops[0] - tops).sum(axis=(1, 2))
    assert len(np.unique(removed)) > 5  # the cutting is spread over the timeline, not all at once


def test_snapshot_hook_keeps_the_full_result(cut):
    moves, tools, setup, tri, _ = cut
    plain = simulate(moves, tools, setup, tri, VerifyOptions(cell=1.5)).simulation
    whole = cut_stock(moves, tools, setup, tri, 1.5)
    n = len(moves.points)
    snapped = cut_stock(moves, tools, setup, tri, 1.5, snapshot_moves=[n - 1, 0, n // 2, n // 2])
    sim, tops = snapped.simulation, snapped.snapshots
    assert np.array_equal(sim.stock_top, plain.stock_top)
    assert np.array_equal(sim.removed_volume, plain.removed_volume)
    # batches split at the snapshots: what each move met is the same
    for name in ("removed_max", "depth", "width", "contact", "volume"):
        assert np.array_equal(getattr(snapped.met, name), getattr(whole.met, name)), name
    assert np.array_equal(tops[0], plain.stock_top)
    assert np.all(tops[1] == setup.stock_max[2])
    assert np.array_equal(tops[2], tops[3])
    with pytest.raises(VerifyError):
        cut_stock(moves, tools, setup, tri, 1.5, snapshot_moves=[n])
    with pytest.raises(VerifyError):
        stock_snapshots(moves, tools, setup, tri, [0.0], timeline=machine_timeline(
            ProgramMoves(moves.points[:5], moves.motion[:5], moves.tool[:5], moves.feed[:5], moves.line[:5])))
