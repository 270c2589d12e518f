"""Cutting moves raised to the feed their chip allows (cadcam.chipfeed), judged by verify's chip check."""

from __future__ import annotations

import dataclasses

import numpy as np
import trimesh
from hypothesis import example, given, settings
from hypothesis import strategies as st

from cadcam.chipfeed import CHIP_CELL, FEED_STEP, chained_chip_feeds, chip_fed, chip_feeds
from cadcam.chipfeed import _finer, _raised, _run_again, _shifted
from cadcam.model import CuttingData, Motion, Operation, Setup, Tool
from cadcam.post import PostOptions, post_process
from cadcam.gcode import parse_gcode
from cadcam.model import Job
from cadcam.stock import cut_stock, operation_moves, stock_after
from cadcam.verify import ChipLoad, VerifyOptions, simulate

MILL = Tool(2, "10 mm flat", "flat", 10.0, 0.0, 30.0, 3, 50.0)
RPM, FZ = 9549.0, 0.08
NOMINAL = CuttingData(RPM, round(RPM * 3 * FZ, 1), 700.0, FZ)
MAX_FEED = 10000.0
SETUP = Setup(stock_min=[0, 0, -10], stock_max=[40, 20, 0], transform_mesh_to_work=np.eye(4), safe_z=10.0)
PART = trimesh.creation.box(bounds=[[0, 0, -10], [40, 10, 0]]).triangles  # a wall along X at Y 10


def pass_along(y: float, z: float = -4.0, x_end: float = 48.0) -> np.ndarray:
    """From the air at the left, along X at ``y`` to ``x_end``, out into the air at the right: (points, motion)."""
    pts = np.array([[-8, y, 10], [-8, y, z], [x_end, y, z], [x_end, y, 10]], float)
    return pts, np.array([Motion.RAPID, Motion.PLUNGE, Motion.CUT, Motion.RAPID], np.int8)


def op(name: str, y: float, kind: str = "roughing", x_end: float = 48.0) -> Operation:
    pts, mot = pass_along(y, x_end=x_end)
    return Operation(name, kind, MILL, NOMINAL, pts, mot)


def verdict(ops, setup: Setup = SETUP, part: np.ndarray = PART, cell: float = 0.2):
    text = post_process(Job(part_name="p", setup=setup, operations=tuple(ops)), PostOptions()).text
    report = simulate(parse_gcode(text), {MILL.number: MILL}, setup, part, VerifyOptions(cell=cell),
                      chips={MILL.number: ChipLoad(FZ, RPM)}).report
    return text, report


@settings(max_examples=6, deadline=None)
@given(st.floats(0.2, 2.0), st.sampled_from([0.2, 0.5]))
def test_a_wall_pass_after_roughing_runs_at_its_chip_thinned_feed_and_verify_passes_it(allowance, cell):
    rough = op("rough", 10.0 + allowance + MILL.radius)
    stock = stock_after([rough], SETUP, PART, cell)
    finish = chip_feeds(op("finish", 10.0 + MILL.radius, "finishing"), stock, SETUP, PART, MAX_FEED)
    assert finish.feeds is not None
    cut = finish.move_feeds()[2]  # the pass along the wall
    assert NOMINAL.feed < cut <= MAX_FEED
    # never faster than the closed form for the skin's width less the model's cell
    ae = max(allowance - cell, 0.05)
    thinned = NOMINAL.feed * MILL.diameter / (2 * np.sqrt(ae * (MILL.diameter - ae)))
    assert cut <= min(MAX_FEED, thinned) + 1e-6
    text, report = verdict([rough, finish])
    assert report.ok, [f.message for f in report.faults]
    assert f"F{cut:g}" in text.replace(".0 ", " ") or f"F{cut}" in text


def test_a_slot_keeps_its_feed_and_a_pass_in_air_runs_at_the_machines():
    slot = chip_feeds(op("slot", 15.0), stock_after([op("air", 40.0)], SETUP, PART, 0.5), SETUP, PART, MAX_FEED)
    assert slot.feeds is None or np.all(np.isnan(slot.feeds[slot.motion == Motion.CUT]))
    # again where the stock is cut away, off the wall by more than the model's grain (a pass beside the wall reads
    # the grown tool's half cell diagonal of it: the wall's own pass is raised by its skin, above)
    cleared = stock_after([op("rough", 16.0)], SETUP, PART, 0.5)
    air = chip_feeds(op("again", 17.0), cleared, SETUP, PART, MAX_FEED)
    assert air.move_feeds()[2] == MAX_FEED
    assert air.move_feeds()[1] == NOMINAL.plunge_feed  # plunges are not raised
    assert verdict([op("rough", 16.0), air])[1].ok


@settings(max_examples=6, deadline=None)
@given(st.floats(15.0, 16.0), st.floats(0.5, 6.0))
def test_chained_passes_are_each_measured_on_the_stock_the_ones_before_leave(y, step):
    """Roughing from the fresh block (no model yet), clear of the wall at Y 10: the first pass slots at the library's feed, a second pass
    ``step`` over is raised by its thinner chip (to the cap where it meets nothing), and verify passes both."""
    first, second = op("slot", y), op("beside", min(y + step, 19.0))
    fed = chained_chip_feeds([first, second], None, SETUP, PART, MAX_FEED)
    assert fed[0].feeds is None or np.all(np.isnan(fed[0].feeds[fed[0].motion == Motion.CUT]))
    ae = min(y + step, 19.0) - y  # the second pass's radial engagement
    cut = fed[1].move_feeds()[2]
    if ae < 2.5:  # a chip thinner than a slot's by more than a feed step (and the grid's cell): raised
        assert cut > NOMINAL.feed
    assert cut <= MAX_FEED
    # chip_feeds of one is the chain of one
    assert chip_feeds(first, None, SETUP, PART, MAX_FEED) is first or fed[0].feeds is not None
    text, report = verdict(fed)
    assert report.ok, [f.message for f in report.faults]


@settings(max_examples=3, deadline=None)
@given(st.floats(11.0, 19.0), st.floats(11.0, 19.0))
def test_the_stock_the_chained_passes_leave_is_the_planning_model_on_the_chip_grid(y0, y1):
    """The stock :func:`chip_fed` cuts the passes into (the planner's model on that grid after them, cut on from
    there) is, point for point, the model the planner would cut of them from the block; from a model on its own
    grid too, which it takes as it is."""
    first, second = op("first", y0), op("second", y1)
    whole = stock_after([first, second], SETUP, PART, CHIP_CELL)
    for fed in (chip_fed([first, second], None, SETUP, PART, MAX_FEED),
                chip_fed([second], stock_after([first], SETUP, PART, CHIP_CELL), SETUP, PART, MAX_FEED)):
        assert fed.stock is not None and fed.stock.grid == whole.grid
        assert np.array_equal(fed.stock.stock_top, whole.stock_top)
        assert np.array_equal(fed.stock.part_top, whole.part_top, equal_nan=True)
    assert np.array_equal(fed.operations[0].points, second.points)  # the same moves, only their feeds raised
    # an operation it does not cut (one without a chip load, as a drill's) leaves no stock to take
    unmeasured = Operation("no chip", "roughing", MILL, dataclasses.replace(NOMINAL, chip_load=None), *pass_along(5.0))
    assert chip_fed([unmeasured, second], None, SETUP, PART, MAX_FEED).stock is None


BIG = Setup(stock_min=[0, 0, -10], stock_max=[60, 60, 0], transform_mesh_to_work=np.eye(4), safe_z=10.0)
CORNER = trimesh.creation.box(bounds=[[0, 0, -10], [5, 5, 0]]).triangles  # a part out of the helix's way


def helix(r: float, depth: float = 3.0, centre=(35.0, 35.0)) -> Operation:
    """From the air above, a 3 deg helix of centre-path radius ``r`` down to ``-depth``, a circle there, out."""
    per_turn = 2 * np.pi * r * np.tan(np.radians(3.0))
    a = np.radians(np.arange(0.0, 360.0 * (depth + 1.0) / per_turn + 10.0, 10.0))
    z = np.maximum(1.0 - a / (2 * np.pi) * per_turn, -depth)
    ring = np.c_[centre[0] + r * np.cos(a), centre[1] + r * np.sin(a), z]
    pts = np.vstack([ring[:1] + [0, 0, 9], ring, ring[-1:] + [0, 0, 11]])
    mot = np.array([Motion.RAPID, Motion.RAPID, *[Motion.PLUNGE] * (len(ring) - 1), Motion.RAPID], np.int8)
    mot[2:-1][np.diff(z) == 0] = Motion.CUT
    return Operation("helix", "roughing", MILL, NOMINAL, pts, mot)


@settings(max_examples=8, deadline=None)
@given(st.floats(1.5, 5.0))
def test_a_helix_runs_at_the_feed_its_edge_allows_and_verify_passes_it(r):
    """A helix turns inside the bore it cuts, the bore's wall wrapped round the cutter: into the solid block its
    chip is the full feed per tooth (a slot), so it runs raised from the plunge feed up to the library's feed, the
    full chip's, and no faster (the edge's own speed, (r + R) / r the centre's, runs along the edge: no thicker
    chip, not divided out again); faster only in the air above. Verify, which reads the curved wall's
    engagement, passes it."""
    h = helix(r)
    fed = chip_feeds(h, None, BIG, CORNER, MAX_FEED)
    f = fed.move_feeds()
    ramp = (h.motion == Motion.PLUNGE)
    deep = ramp & (h.points[:, 2] < -0.5)  # moves wholly in the stock
    full = RPM * MILL.flutes * FZ  # the feed whose chip at full engagement is fz
    assert np.all(f[ramp] >= NOMINAL.plunge_feed - 1e-9)
    # at the full chip's feed itself (to the 0.1 mm/min feeds are written to), not at the ladder's step under it
    assert np.allclose(f[deep], full, atol=0.05)
    # the posted program carries the feeds, and verify holds every chip to fz
    text = post_process(Job(part_name="p", setup=BIG, operations=(fed,)), PostOptions()).text
    report = simulate(parse_gcode(text), {MILL.number: MILL}, BIG, CORNER, VerifyOptions(cell=0.2),
                      chips={MILL.number: ChipLoad(FZ, RPM)}).report
    assert report.ok, [f.message for f in report.faults]


def test_a_helix_through_a_bore_cut_before_is_raised_past_one_into_the_solid():
    """The same helix again once the bore is cut (the finishing's descent): it meets air and runs faster."""
    first = helix(3.0)
    again = chip_feeds(helix(3.0), stock_after([first], BIG, CORNER, 0.5), BIG, CORNER, MAX_FEED)
    solid = chip_feeds(helix(3.0), None, BIG, CORNER, MAX_FEED)
    deep = (first.motion == Motion.PLUNGE) & (first.points[:, 2] < -0.5)
    assert np.median(again.move_feeds()[deep]) > np.max(solid.move_feeds()[deep])
    # a vertical plunge is never raised
    down = Operation("down", "roughing", MILL, NOMINAL, np.array([[35, 35, 5.0], [35, 35, 1], [35, 35, -2]]),
                     np.array([Motion.RAPID, Motion.RAPID, Motion.PLUNGE], np.int8))
    assert chip_feeds(down, None, BIG, CORNER, MAX_FEED).move_feeds()[2] == NOMINAL.plunge_feed


@settings(max_examples=8, deadline=None)
@given(st.floats(30.0, 31.0), st.floats(0.11, 0.19), st.sampled_from([0.2, 0.5]))
@example(30.71, 0.15, 0.5)  # the strip between the 0.2 mm grid's points 30.7 and 30.9, round the 0.5 mm grid's 30.75
def test_a_strip_narrower_than_a_cell_between_two_passes_is_met_at_its_chip(start, width, cell):
    """Two slots leave a strip of stock ``width`` [mm] wide (less than the model's 0.2 mm cell) between them, as
    floor loops 0.85 D apart do; a third pass sweeps it. However the strip falls between the planner's grid points,
    the third pass is not raised past the chip the strip gives it: verify on either grid finds no chip fault."""
    # each pass across the whole 60 mm block, in and out in the air
    under = op("under", start - MILL.radius, x_end=68.0)  # clears up to Y = start
    over = op("over", start + width + MILL.radius, x_end=68.0)  # clears from Y = start + width
    # meets the strip half a radius off its axis
    across = op("across", start + 0.5 * width + 0.5 * MILL.radius, x_end=68.0)
    fed = chained_chip_feeds([under, over, across], None, BIG, CORNER, MAX_FEED)
    report = verdict(fed, BIG, CORNER, cell)[1]
    assert report.ok, [f.message for f in report.faults]


@settings(max_examples=8, deadline=None)
@given(st.lists(st.tuples(st.floats(-5.0, 45.0), st.floats(-5.0, 25.0), st.floats(-6.0, 1.0)), min_size=3,
                max_size=12),
       st.lists(st.integers(0, 10), min_size=1, max_size=6), st.booleans())
def test_a_move_run_again_is_not_cut_and_every_move_keeps_the_feed_the_whole_measure_gives(corners, again, block):
    """A path of random moves (ramps, climbs, moves across the wall at Y 10), some run again later along the same
    ends: the chip feeds leave the moves run again out of their cut and measure only the chip, yet the stock and
    every move's chip are those of cutting every move with everything measured, on both chip grids, and so is
    every feed."""
    pts = np.array([[c[0], c[1], c[2]] for c in corners], float)
    for k in again:  # the move ending at point k + 1, run again after the path so far
        k = k % (len(pts) - 1)
        pts = np.vstack([pts, pts[k], pts[k + 1]])
    pts = np.vstack([[pts[0, 0], pts[0, 1], 10.0], pts, [pts[-1, 0], pts[-1, 1], 10.0]])
    mot = np.full(len(pts), Motion.CUT, np.int8)
    mot[[0, -1]] = Motion.RAPID
    path = Operation("path", "roughing", MILL, NOMINAL, pts, mot)
    start = None if block else stock_after([op("rough", 16.0)], SETUP, PART, 0.5)
    moves, tools = operation_moves([path]), {MILL.number: MILL}
    share = np.zeros(len(pts))
    for placed in (SETUP, _shifted(SETUP, 0.5 * CHIP_CELL)):
        whole = cut_stock(moves, tools, placed, PART, CHIP_CELL, start=None if start is None
                          else _finer(start, placed, CHIP_CELL))
        quick = cut_stock(moves, tools, placed, PART, CHIP_CELL, measure="chip", skip=_run_again(moves),
                          start=None if start is None else _finer(start, placed, CHIP_CELL))
        assert np.array_equal(quick.simulation.stock_top, whole.simulation.stock_top)
        chips = [np.zeros(len(pts)), np.zeros(len(pts))]
        np.maximum.at(chips[0], whole.segments.move, whole.met.chip)
        np.maximum.at(chips[1], quick.segments.move, quick.met.chip)
        assert np.array_equal(chips[0], chips[1])
        np.maximum.at(share, whole.segments.move, whole.met.chip)
    fed = chip_feeds(path, start, SETUP, PART, MAX_FEED)
    assert np.array_equal(fed.move_feeds(), _raised(path, share, MAX_FEED).move_feeds(), equal_nan=True)


def test_the_shifted_grid_s_part_is_made_here_once_and_given_to_the_worker(monkeypatch):
    """A pass worth a process of its own (``_FORK_POINTS`` lowered; one processor, so the worker's call runs here):
    the stock model rasterises the part on the setup's own grid only, the shifted grid's part coming from
    :func:`chip_fed` (kept for a plan's next calls; a forked worker starts with no kept answers), and the feeds are
    those of the pass measured without a worker."""
    import cadcam.chipfeed
    import cadcam.stock

    monkeypatch.setenv("FACTORY_THREADS", "1")
    ops = [op("rough", 16.0), op("finish", 10.0 + MILL.radius, "finishing")]
    alone = chip_fed(ops, None, SETUP, PART, MAX_FEED)
    real, grids = cadcam.stock.upper_envelope, []
    monkeypatch.setattr(cadcam.stock, "upper_envelope", lambda tri, grid: grids.append(grid) or real(tri, grid))
    monkeypatch.setattr(cadcam.chipfeed, "_FORK_POINTS", 2)
    worked = chip_fed(ops, None, SETUP, PART, MAX_FEED)
    own = cadcam.chipfeed.grid_over(SETUP.stock_min, SETUP.stock_max, CHIP_CELL)
    assert grids == [own]
    for a, b in zip(alone.operations, worked.operations):
        assert np.array_equal(a.move_feeds(), b.move_feeds(), equal_nan=True) and (a.feeds is None) == (b.feeds is None)
    assert np.array_equal(alone.stock.stock_top, worked.stock.stock_top)
