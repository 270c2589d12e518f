"""Verify holds every feed move's chip to the tool's feed per tooth (issue 32, item 3): the chip of a straight
side cut against its closed form, and a feed raised past the chip-thinning rule failing."""

from __future__ import annotations

import math

import numpy as np
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam.adaptive import chip_thinned_feed
from cadcam.model import CuttingData, Motion, ProgramMoves, Setup, Tool
from cadcam.verify import ChipLoad, VerifyOptions, chip_loads, simulate

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
