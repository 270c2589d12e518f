"""Cutting moves raised to the feed their chip allows (cadcam.chipfeed), judged by verify's chip check."""

from __future__ import annotations

import numpy as np
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam.chipfeed import chained_chip_feeds, chip_feeds
from cadcam.model import CuttingData, Motion, Operation, Setup, Tool
from cadcam.post import PostOptions, post_process
from cadcam.gcode import parse_gcode
from cadcam.model import Job
from cadcam.stock import stock_after
from cadcam.verify import ChipLoad, VerifyOptions, simulate

MILL = Tool(2, "10 mm flat", "flat", 10.0, 0.0, 30.0, 3, 50.0)
RPM, FZ = 9549.0, 0.08
NOMINAL = CuttingData(RPM, round(RPM * 3 * FZ, 1), 700.0, FZ)
MAX_FEED = 10000.0
SETUP = Setup(stock_min=[0, 0, -10], stock_max=[40, 20, 0], transform_mesh_to_work=np.eye(4), safe_z=10.0)
PART = trimesh.creation.box(bounds=[[0, 0, -10], [40, 10, 0]]).triangles  # a wall along X at Y 10


def pass_along(y: float, z: float = -4.0) -> np.ndarray:
    """From the air at the left, along X at ``y``, out into the air at the right: (points, motion)."""
    pts = np.array([[-8, y, 10], [-8, y, z], [48, y, z], [48, y, 10]], float)
    return pts, np.array([Motion.RAPID, Motion.PLUNGE, Motion.CUT, Motion.RAPID], np.int8)


def op(name: str, y: float, kind: str = "roughing") -> Operation:
    pts, mot = pass_along(y)
    return Operation(name, kind, MILL, NOMINAL, pts, mot)


def verdict(ops):
    text = post_process(Job(part_name="p", setup=SETUP, operations=tuple(ops)), PostOptions()).text
    report = simulate(parse_gcode(text), {MILL.number: MILL}, SETUP, PART, VerifyOptions(cell=0.2),
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
