"""Spindle power and load from the stock model's removed volume (cadcam.cutting_power)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam.cutting_power import METER_WINDOW_S, program_spindle_load, spindle_load
from cadcam.timeline import machine_timeline
from cadcam.tools import load_tool_library
from cadcam.verify import VerifyOptions, simulate
from factory.core.errors import ToolError, VerifyError
from tests.cadcam.test_op2 import block_ops  # noqa: F401  (a fixture: the pocketed block's op 1 and op 2)
from tests.cadcam.test_verify import SETUP, TOOLS, C, R, box, program

NO_PART = box([0, 0, -30], [40, 20, -20])  # far below the stock: nothing to gouge
ALUMINIUM = 0.7  # [W·s/mm³]


def slot(depth: float, feed: float = 600.0, y: float = 10.0):
    """A full-width slot of the 6 mm flat along X through the 40 x 20 x 10 stock, ``depth`` deep."""
    moves = program([(R, 1, (-5, y, 5)), (R, 1, (-5, y, -depth)), (C, 1, (45, y, -depth)), (R, 1, (45, y, 5))])
    moves = type(moves)(moves.points, moves.motion, moves.tool, np.where(np.isnan(moves.feed), np.nan, feed),
                        moves.line)
    sim = simulate(moves, TOOLS, SETUP, NO_PART, VerifyOptions(cell=0.25)).simulation
    return moves, sim


def test_a_slot_removes_width_times_depth_times_length_and_nothing_else():
    moves, sim = slot(2.0)
    # the cut move alone removes stock: 6 mm wide, 2 mm deep, along the stock's 40 mm
    assert sim.removed_volume[3] == pytest.approx(6.0 * 2.0 * 40.0, rel=0.03)
    assert sim.removed_volume[[0, 1, 2, 4]].tolist() == [0.0, 0.0, 0.0, 0.0]
    # and it is what the stock lost, grid point by grid point
    lost = (SETUP.stock_max[2] - np.asarray(sim.stock_top)).sum() * sim.grid.cell ** 2
    assert sim.removed_volume.sum() == pytest.approx(lost)


def test_slot_power_is_mrr_times_specific_energy():
    moves, sim = slot(2.0, feed=600.0)
    timeline = machine_timeline(moves)
    load = spindle_load(timeline, sim.removed_volume, ALUMINIUM, 7.5)
    mrr = 6.0 * 2.0 * 600.0 / 60.0  # ae * ap * vf [mm³/s]: 120 while in the stock
    # the move's mean: 40 of its 50 mm run through the stock
    assert load.move_power[3] == pytest.approx(ALUMINIUM * mrr * 40.0 / 50.0, rel=0.03)
    # a move spends its energy evenly: the meter reads its mean within it, nothing before it
    # or a window after it
    cut_mid = 0.5 * (timeline.start[3] + timeline.end[3])
    assert load.power_at(cut_mid)[0] == pytest.approx(load.move_power[3])
    assert load.load_percent_at(cut_mid)[0] == pytest.approx(100 * load.move_power[3] / 7500.0)
    assert load.power_at([0.0, timeline.end[3] + 2 * METER_WINDOW_S]).tolist() == [0.0, 0.0]
    # the energy it spent is the volume times the specific energy
    assert load.energy[-1] == pytest.approx(ALUMINIUM * sim.removed_volume.sum())


def test_deeper_and_faster_cuts_load_the_spindle_more():
    powers = {}
    for depth, feed in ((1.0, 600.0), (3.0, 600.0), (3.0, 1200.0)):
        moves, sim = slot(depth, feed)
        powers[(depth, feed)] = spindle_load(machine_timeline(moves), sim.removed_volume, ALUMINIUM, 7.5).move_power[3]
    assert powers[(1.0, 600.0)] < powers[(3.0, 600.0)] < powers[(3.0, 1200.0)]
    assert powers[(3.0, 600.0)] == pytest.approx(3 * powers[(1.0, 600.0)], rel=0.05)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.0, 500.0), min_size=2, max_size=12), st.floats(0.05, 5.0),
       st.lists(st.floats(-5.0, 200.0), min_size=1, max_size=20))
def test_power_is_finite_non_negative_and_integrates_to_the_energy(volumes, window, times):
    n = len(volumes)
    moves = program([(C, 1, (10.0 * k, 0.0, 0.0)) for k in range(1, n)], start=(0.0, 0.0, 0.0))
    timeline = machine_timeline(moves)
    load = spindle_load(timeline, np.r_[0.0, volumes[1:]], 2.7, 5.0)
    p = load.power_at(np.asarray(times), window)
    assert np.isfinite(p).all() and (p >= 0).all()
    # summed over back-to-back windows the meter sees every joule
    edges = np.arange(1, math.ceil(timeline.duration / window) + 2) * window
    assert (load.power_at(edges, window) * window).sum() == pytest.approx(2.7 * sum(volumes[1:]), rel=1e-9, abs=1e-9)


def test_the_library_gives_the_energy_and_the_rated_power():
    library = load_tool_library()
    assert library.spindle_power_kw == 7.5
    assert library.material("6061").specific_energy == ALUMINIUM
    assert library.material("steel").specific_energy > library.material("aluminium").specific_energy
    moves, sim = slot(2.0)
    timeline = machine_timeline(moves)
    al = program_spindle_load(timeline, sim.removed_volume, library, "aluminium")
    steel = program_spindle_load(timeline, sim.removed_volume, library, "steel")
    assert al.rated_power == 7500.0
    assert steel.move_power[3] / al.move_power[3] == pytest.approx(2.7 / 0.7)


def test_bad_inputs_are_refused():
    moves, sim = slot(2.0)
    timeline = machine_timeline(moves)
    with pytest.raises(VerifyError, match="moves"):
        spindle_load(timeline, sim.removed_volume[:-1], ALUMINIUM, 7.5)
    with pytest.raises(VerifyError, match=">= 0"):
        spindle_load(timeline, -sim.removed_volume, ALUMINIUM, 7.5)
    for energy, power in ((0.0, 7.5), (math.nan, 7.5), (ALUMINIUM, -1.0)):
        with pytest.raises(ToolError):
            spindle_load(timeline, sim.removed_volume, energy, power)
    with pytest.raises(ValueError, match="window"):
        spindle_load(timeline, sim.removed_volume, ALUMINIUM, 7.5).power_at(1.0, 0.0)


def test_a_material_without_specific_energy_names_what_to_add(tmp_path):
    text = open(load_tool_library().source, encoding="utf-8").read()
    path = tmp_path / "tools.yaml"
    path.write_text(text.replace("    specific_energy: 0.7", "    # none"))
    library = load_tool_library(path)
    moves, sim = slot(2.0)
    with pytest.raises(ToolError, match="materials.aluminium: no specific_energy"):
        program_spindle_load(machine_timeline(moves), sim.removed_volume, library, "aluminium")


def test_op_2_removes_what_the_turned_over_stock_lost(block_ops):  # noqa: F811
    """Op 2 starts from op 1's stock turned over, whose columns stand on their own bottoms: what
    each move removed adds up to what those columns lost, never counting air below them."""
    from cadcam.op2 import flip_transform
    from cadcam.stock import flip_stock

    _, (job1, job2, _, _, (sim1, _), (sim2, _), m2) = block_ops
    start = flip_stock(sim1, flip_transform(job1.setup), job2.setup)
    top, bottom = np.asarray(start.top), np.asarray(start.bottom)
    full = np.isfinite(top) & (top > bottom)
    final = np.where(np.isfinite(sim2.stock_top), sim2.stock_top, bottom)
    lost = np.clip(top - np.maximum(final, bottom), 0.0, None)[full].sum() * sim2.grid.cell ** 2
    assert lost > 100.0  # the facing took the holding allowance off
    assert sim2.removed_volume.sum() == pytest.approx(lost, rel=1e-9)
    load = program_spindle_load(machine_timeline(m2), sim2.removed_volume, load_tool_library(), "aluminium")
    assert load.energy[-1] == pytest.approx(ALUMINIUM * lost) and load.move_power.max() > 0
