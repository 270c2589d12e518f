"""Verify holds every feed move's chip to the tool's feed per tooth (issue 32, item 3): the chip of a straight
side cut against its closed form, and a feed raised past the chip-thinning rule failing."""

from __future__ import annotations

import math

import numpy as np
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam.adaptive import chip_thinned_feed
from cadcam.gcode import parse_gcode
from cadcam.heightmap import grid_over
from cadcam.stock import FlippedStock
from cadcam.model import CuttingData, Motion, ProgramMoves, Setup, Tool
from cadcam.verify import ChipLoad, VerifyOptions, chip_loads, simulate, simulate_flipped

MILL = Tool(4, "10 mm flat", "flat", 10.0, 0.0, 20.0, 3, 40.0)
RPM, FZ = 6000.0, 0.08
# Stock 40 x 20 x 10 mm; the part a slab on its bottom, well under the cut.
SETUP = Setup(stock_min=[0, 0, -10], stock_max=[40, 20, 0], transform_mesh_to_work=np.eye(4))
PART = trimesh.creation.box(bounds=[[0, 0, -10], [40, 20, -8]]).triangles
CELL = 0.2


def side_cut(ae: float, feed: float) -> ProgramMoves:
    """One straight cut along X, 3 mm deep, taking ``ae`` [mm] off the stock's back face (Y 20), from air to air."""
    y = 20.0 + MILL.radius - ae
    points = np.array([[np.nan] * 3, [-8.0, y, 5.0], [-8.0, y, -3.0], [48.0, y, -3.0], [48.0, y, 5.0]])
    motion = np.array([0, Motion.RAPID, Motion.CUT, Motion.CUT, Motion.RAPID], np.int8)
    feeds = np.where(motion == Motion.RAPID, np.nan, feed)
    return ProgramMoves(points, motion, np.full(5, MILL.number, np.int32), feeds, np.arange(5, dtype=np.int32))


def closed_form(ae: float, feed: float) -> float:
    """The thickest chip of a side cut of width ``ae`` [mm]: feed per tooth times the sine of the engagement angle."""
    share = 1.0 if ae >= MILL.radius else 2.0 * math.sqrt(ae * (MILL.diameter - ae)) / MILL.diameter
    return feed / (RPM * MILL.flutes) * share


def verified(ae: float, feed: float):
    return simulate(side_cut(ae, feed), {MILL.number: MILL}, SETUP, PART, VerifyOptions(cell=CELL),
                    chips={MILL.number: ChipLoad(FZ, RPM)}).report


@settings(max_examples=25, deadline=None)
@given(st.floats(0.2, 9.0), st.floats(300.0, 8000.0))
def test_a_side_cuts_chip_is_the_closed_form_to_a_grid_cell(ae, feed):
    report = verified(ae, feed)
    (e,) = report.engagement
    # The stock's edge is read to half a grid cell: the chip lies between those of ae -+ a cell.
    lo, hi = closed_form(max(ae - CELL, 0.01), feed), closed_form(ae + CELL, feed)
    assert lo - 1e-9 <= e.max_chip <= hi + 1e-9
    assert e.chip_load == FZ and e.max_chip_line == 3
    chip_faults = [f for f in report.faults if f.kind == "chip"]
    assert bool(chip_faults) == (e.max_chip > FZ * (1 + VerifyOptions().chip_tolerance))


@settings(max_examples=20, deadline=None)
@given(st.floats(0.5, 4.5), st.floats(1.3, 3.0))
def test_the_chip_thinned_feed_passes_and_a_feed_raised_past_it_fails(ae, raise_by):
    nominal = RPM * MILL.flutes * FZ
    thinned = chip_thinned_feed(CuttingData(RPM, nominal, nominal / 2, FZ), MILL, ae, 1e9).feed
    assert not [f for f in verified(ae, thinned).faults if f.kind == "chip"]
    faults = [f for f in verified(ae, thinned * raise_by).faults if f.kind == "chip"]
    assert len(faults) == 1 and faults[0].tool == MILL.number and faults[0].lines == (3,)
    assert faults[0].limit == FZ and faults[0].worst > FZ * (1 + VerifyOptions().chip_tolerance)


def test_a_slot_is_judged_at_the_full_feed_per_tooth():
    nominal = RPM * MILL.flutes * FZ
    assert not [f for f in verified(10.0, nominal).faults if f.kind == "chip"]
    assert [f.kind for f in verified(10.0, nominal * 1.3).faults] == ["chip"]


def test_chip_loads_are_read_from_the_sheets_operations():
    ops = [{"tool": 2, "spindle_rpm": 9000, "chip_load_mm": 0.08}, {"tool": 2, "spindle_rpm": 8000, "chip_load_mm": 0.07},
           {"tool": 3, "spindle_rpm": 9000}, {"tool": 5, "spindle_rpm": 0, "chip_load_mm": 0.05}]
    assert chip_loads(ops) == {2: ChipLoad(0.07, 8000.0)}
    # without chip loads (a sheet written before them) nothing is judged, the chip not measured against anything
    report = simulate(side_cut(0.3, 50000.0), {MILL.number: MILL}, SETUP, PART, VerifyOptions(cell=CELL)).report
    assert not report.faults and report.engagement[0].chip_load == 0.0


def test_the_library_gives_each_cutting_its_feed_per_tooth_and_thinning_keeps_it():
    from cadcam.tools import load_tool_library

    library = load_tool_library()
    for tool in library.tools:
        if tool.is_drill:
            continue
        c = library.cutting_data(tool, "aluminium")
        fz = library.material("aluminium").chip_load_for(tool.diameter) * library.feed_factor(tool)
        assert math.isclose(c.chip_load, fz, rel_tol=1e-5)
        assert c.feed <= c.spindle_rpm * tool.flutes * fz * (1 + 1e-3)  # the feed never asks for more
        assert chip_thinned_feed(c, tool, 0.1 * tool.diameter, library.max_feed).chip_load == c.chip_load



def bore_pass(r: float, ae: float, feed: float) -> tuple[ProgramMoves, FlippedStock, Setup, np.ndarray]:
    """A pocket of radius ``r + R - ae`` [mm] 4 mm deep, its wall taken ``ae`` [mm] wider by a full circle (G3)
    of centre radius ``r`` 3 mm deep at ``feed``, entered from the pocket's middle at a crawl (its own chip thin)."""
    setup = Setup(stock_min=[0, 0, -10], stock_max=[60, 60, 0], transform_mesh_to_work=np.eye(4))
    part = trimesh.creation.box(bounds=[[0, 0, -10], [60, 60, -8]]).triangles
    grid = grid_over(setup.stock_min, setup.stock_max, CELL)
    inside = np.hypot(grid.xs[None, :] - 30.0, grid.ys[:, None] - 30.0) < r + MILL.radius - ae
    start = FlippedStock(grid=grid, top=np.where(inside, -4.0, 0.0), bottom=np.full(inside.shape, -10.0))
    text = "\n".join(["G21 G90 G17", f"T{MILL.number} M6", f"S{RPM:g} M3", "G0 X30 Y30 Z5", "G1 Z-3 F50",
                      f"G1 X{30 + r:.4f} F5", f"G3 X{30 + r:.4f} Y30 I{-r:.4f} J0 F{feed:.1f}", "G1 X30 F50", "G0 Z5",
                      "M30"])
    return parse_gcode(text), start, setup, part


def concave_chip(r: float, ae: float, feed: float) -> float:
    """The thickest chip of a tool of radius R on a concave wall of radius r + R taking ``ae`` [mm] off it: the
    feed per tooth at the centre times the sine of the engagement angle the curved wall gives, from the
    direction across the path (its cosine ``((r + R - ae)^2 - r^2 - R^2) / (2 r R)``; a straight wall's is
    ``1 - ae / R``). The edge's own speed, (r + R) / r the centre's, runs along the edge and adds no thickness:
    the chip is what the centre's advance between two teeth brings the edge into the material."""
    R = MILL.radius
    c = ((r + R - ae) ** 2 - r * r - R * R) / (2 * r * R)
    share = 1.0 if c <= 0 else math.sqrt(max(1 - c * c, 0.0))
    return feed / (RPM * MILL.flutes) * share


@settings(max_examples=15, deadline=None)
@given(st.floats(1.0, 12.0), st.floats(0.3, 2.0))
def test_a_concave_arcs_chip_is_read_with_the_engagement_its_curved_wall_gives(r, ae):
    """On a concave arc the wall wraps round the cutter: the same ``ae`` engages a wider angle than on a straight
    wall, and verify (which measures the stock the curved wall left, chord by chord) reads that thicker chip, to a
    grid cell of ``ae``. A tight arc at the straight wall's chip-thinned feed is over fz where the curve makes it."""
    nominal = RPM * MILL.flutes * FZ
    moves, start, setup, part = bore_pass(r, ae, nominal)
    report = simulate_flipped(moves, {MILL.number: MILL}, setup, part, start, VerifyOptions(cell=CELL),
                              chips={MILL.number: ChipLoad(FZ, RPM)}).report
    (e,) = report.engagement
    lo, hi = concave_chip(r, max(ae - CELL, 0.01), nominal), concave_chip(r, ae + CELL, nominal)
    assert lo - 1e-9 <= e.max_chip <= hi + 1e-9
    assert e.max_chip_line == 7  # the arc's
    straight = closed_form(ae + CELL, nominal)
    if concave_chip(r, ae - CELL, nominal) > straight * 1.05:
        assert e.max_chip > straight  # the curve's engagement seen, not the straight wall's
    thinned = chip_thinned_feed(CuttingData(RPM, nominal, nominal / 2, FZ), MILL, ae, 1e9).feed
    chip = concave_chip(r, ae, thinned)
    faults = [f for f in simulate_flipped(bore_pass(r, ae, thinned)[0], {MILL.number: MILL}, setup, part, start,
                                          VerifyOptions(cell=CELL), chips={MILL.number: ChipLoad(FZ, RPM)}
                                          ).report.faults if f.kind == "chip"]
    if concave_chip(r, max(ae - CELL, 0.01), thinned) > FZ * (1 + VerifyOptions().chip_tolerance) * 1.01:
        assert faults
    elif chip < FZ:
        assert not faults


def level_passes(tool: Tool, ys: list[float], feeds: list[float], z: float) -> ProgramMoves:
    """Level passes along X at tip height ``z`` [mm], one per ``ys`` [mm] at its feed, each from air to air."""
    points, motion = [[np.nan] * 3], [0]
    for y, f in zip(ys, feeds):
        points += [[-8.0, y, 5.0], [-8.0, y, z], [48.0, y, z], [48.0, y, 5.0]]
        motion += [Motion.RAPID, Motion.CUT, Motion.CUT, Motion.RAPID]
    motion = np.array(motion, np.int8)
    feed = np.array([np.nan, *[x for f in feeds for x in (np.nan, f, f, np.nan)]])
    return ProgramMoves(np.array(points), motion, np.full(len(motion), tool.number, np.int32),
                        np.where(motion == Motion.RAPID, np.nan, feed), np.arange(len(motion), dtype=np.int32))


@settings(max_examples=12, deadline=None)
@given(st.floats(0.5, 3.0), st.floats(0.5, 3.0))
def test_a_bull_noses_next_pass_is_judged_by_the_wall_not_by_the_fillet_its_corner_left(ae, rc):
    """A bull nose (D 8) cuts a wall 3 mm deep; the next pass, ``ae`` nearer the stock at the same depth, meets the
    fillet the corner left at the wall's foot with its flat bottom, nearer its axis than the wall. The corner meets
    that fillet low on its radius, where its circle is small and its edge leans: the chip there is thinner than the
    wall's, and the pass is judged by the wall's side cut, to a grid cell (read on the tool's radius, the fillet
    made a side cut of ae = 1.2 read as 1.15 fz: the dome's adaptive rings)."""
    tool = Tool(5, "8 mm bull-nose", "bull", 8.0, rc, 20.0, 4, 40.0)
    first = 20.0 + tool.radius - 4.0  # takes 4 mm off the back face, at a crawl (its chip thin)
    second = first - ae
    nominal = RPM * tool.flutes * FZ
    moves = level_passes(tool, [first, second], [nominal / 50.0, nominal], -6.0)
    report = simulate(moves, {tool.number: tool}, SETUP, PART, VerifyOptions(cell=CELL),
                      chips={tool.number: ChipLoad(FZ, RPM)}).report
    (e,) = report.engagement

    def side(a: float) -> float:
        return FZ * 2.0 * math.sqrt(a * (tool.diameter - a)) / tool.diameter

    assert side(max(ae - CELL, 0.01)) - 1e-9 <= e.max_chip <= side(ae + CELL) + 1e-9
    assert not [f for f in report.faults if f.kind == "chip"]


@settings(max_examples=12, deadline=None)
@given(st.floats(0.05, 2.9))
def test_a_balls_shallow_level_cut_is_thinned_by_the_height_it_meets_the_stock_at(ap):
    """A 6 mm ball skims ``ap`` [mm] off the stock's top in one level pass: the material on its path meets the ball
    only up to ``ap`` above its tip, where its edge turns towards the flat: the chip is fz times the sine of its
    lead angle there, ``sqrt(ap (2R - ap)) / R`` (makers' ball-nose chip thinning)."""
    ball = Tool(3, "6 mm ball", "ball", 6.0, 3.0, 12.0, 2, 30.0)
    nominal = RPM * ball.flutes * FZ
    report = simulate(level_passes(ball, [10.0], [nominal], -ap), {ball.number: ball}, SETUP, PART,
                      VerifyOptions(cell=CELL), chips={ball.number: ChipLoad(FZ, RPM)}).report
    (e,) = report.engagement
    R = ball.radius
    assert math.isclose(e.max_chip, FZ * math.sqrt(ap * (2 * R - ap)) / R, rel_tol=1e-6, abs_tol=1e-9)


@settings(max_examples=12, deadline=None)
@given(st.floats(5.0, 40.0), st.floats(0.1, 1.5))
def test_a_ball_on_a_slope_is_thinned_by_its_depth_of_cut_across_the_move(slope, a):
    """A 6 mm ball climbs a plane of ``slope`` [deg] taking ``a`` [mm] off it, measured square to the plane: its
    sphere's front meets the stock first at ``R - a`` from its centre line, so the chip is ``fz sqrt(a (2R - a)) /
    R`` whatever the slope (the level rule in 3-D), to half a grid cell of ``a``."""
    ball = Tool(3, "6 mm ball", "ball", 6.0, 3.0, 12.0, 2, 30.0)
    R, t = ball.radius, math.tan(math.radians(slope))
    setup = Setup(stock_min=[0, -10, -30], stock_max=[40, 10, 40 * t], transform_mesh_to_work=np.eye(4))
    part = trimesh.creation.box(bounds=[[0, -10, -30], [40, 10, -28]]).triangles
    grid = grid_over(setup.stock_min, setup.stock_max, CELL)
    start = FlippedStock(grid=grid, top=np.broadcast_to(grid.xs[None, :] * t, (grid.ny, grid.nx)).copy(),
                         bottom=np.full((grid.ny, grid.nx), -30.0))
    lift = (R - a) / math.cos(math.radians(slope)) - R  # the tip under the centre, R - a off the plane square to it
    nominal = RPM * ball.flutes * FZ
    text = "\n".join(["G21 G90 G17", f"T{ball.number} M6", f"S{RPM:g} M3", "G0 X-8 Y0 Z60",
                      f"G1 Z{-8 * t + lift:.4f} F{nominal:.1f}", f"G1 X48 Z{48 * t + lift:.4f}", "G0 Z60", "M30"])
    report = simulate_flipped(parse_gcode(text), {ball.number: ball}, setup, part, start, VerifyOptions(cell=CELL),
                              chips={ball.number: ChipLoad(FZ, RPM)}).report
    (e,) = report.engagement

    def thinned(depth: float) -> float:
        return FZ * math.sqrt(depth * (2 * R - depth)) / R

    assert e.max_chip_line == 6
    assert thinned(a) - 1e-9 <= e.max_chip <= thinned(a + 0.5 * CELL) + 1e-9
