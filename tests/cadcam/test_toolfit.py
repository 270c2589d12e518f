"""Which roughing end mill fits the part: reach by grey opening, choice by time."""

from __future__ import annotations

import manifold3d
import numpy as np
import pytest

from cadcam.plan import PlanOptions, choose_tools
from cadcam.setup import make_setup
from cadcam.toolfit import entry_radius, tool_fits
from cadcam.tools import load_tool_library
from tests.conftest import manifold_to_trimesh

LIBRARY = load_tool_library()


def _planned(body: manifold3d.Manifold):
    setup, part = make_setup(manifold_to_trimesh(body))
    return setup, np.asarray(part.triangles)


def test_an_open_step_is_reached_whole_by_every_tool():
    body = manifold3d.Manifold.cube((60.0, 40.0, 10.0)) - manifold3d.Manifold.cube((30.0, 50.0, 6.0)).translate(
        (-1.0, -5.0, 5.0))
    setup, tri = _planned(body)
    for fit in tool_fits(tri, setup, [LIBRARY.tool(1), LIBRARY.tool(2)]):
        # the step, the 1 mm on top and the 2 mm margins; the grid loses a little at the edges
        assert fit.share == pytest.approx(1.0, abs=0.02), fit.tool.number


def test_a_hole_narrower_than_the_entry_is_not_reached():
    # 12 mm across: the 6 mm mill enters (entry radius 4.2 mm), the 10 mm one does not (6.8 mm).
    body = manifold3d.Manifold.cube((60.0, 40.0, 10.0)) - manifold3d.Manifold.cylinder(12.0, 6.0, 6.0, 64).translate(
        (30.0, 20.0, -1.0))
    setup, tri = _planned(body)
    t1, t2 = LIBRARY.tool(1), LIBRARY.tool(2)
    assert entry_radius(t1, 0.3) < 6.0 < entry_radius(t2, 0.3)
    small, big = tool_fits(tri, setup, [t1, t2])
    # from the top allowance down to op 1's floor; the grid loses about half a cell at the wall
    hole = np.pi * (6.0 - 0.25) ** 2 * float(setup.stock_max[2] - setup.floor_z)
    assert small.reach_volume - big.reach_volume == pytest.approx(hole, rel=0.1)


def test_the_wide_mill_roughs_a_plate_with_a_few_small_holes():
    body = manifold3d.Manifold.cube((90.0, 60.0, 12.0)) - manifold3d.Manifold.cube((40.0, 30.0, 6.0)).translate(
        (25.0, 15.0, 7.0))
    for x in (8.0, 82.0):
        body -= manifold3d.Manifold.cylinder(14.0, 5.5, 5.5, 64).translate((x, 30.0, -1.0))
    setup, tri = _planned(body)
    rough, _ = choose_tools(LIBRARY, setup, PlanOptions(), tri)
    # not the 6 mm that fits the holes: they are drilled or rest roughed; of the wide ones, the 8 mm 4-flute
    # bull-nose clears the plate soonest (its feed), and the 16 mm gains too little over it to be taken
    assert rough.number == 5


def test_the_estimate_counts_levels_entries_and_terraces():
    """A pocket 6 mm deep: the 10 mm's 5 mm stepdown leaves a terrace on the 1 mm the 16 mm's 8 mm does
    not; every level's area is cleared, and the closed pocket is entered by helix at each level."""
    body = manifold3d.Manifold.cube((90.0, 60.0, 12.0)) - manifold3d.Manifold.cube((40.0, 30.0, 6.0)).translate(
        (25.0, 15.0, 7.0))
    setup, tri = _planned(body)
    fit = {f.tool.number: f for f in tool_fits(tri, setup, [LIBRARY.tool(2), LIBRARY.tool(14)])}
    for f in fit.values():
        assert f.level_area >= f.reach_volume / min(0.5 * f.tool.diameter, f.tool.flute_length) - 1e-6
        assert f.entry_depth > 0
        cut = LIBRARY.cutting_data(f.tool, "aluminium")
        assert f.roughing_minutes(cut) > f.level_area / (f.tool.level_stepover * cut.feed)
