"""The vise's jaws and parallels as obstacles: exact sweeps, verify faults with lines, the planner's guard."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam.model import CuttingData, FixtureBox, Motion, Operation, ProgramMoves, Setup, Tool, ViseJaws
from cadcam.rest import safe_rapids
from cadcam.verify import FAULT_KINDS, simulate
from cadcam.workholding import fixture_contacts, tool_cylinders
from factory.core.errors import ToolpathError

FLAT = Tool(1, "6 mm flat", "flat", 6.0, 0.0, 20.0, 3, 40.0)
STUBBY = Tool(2, "6 mm flat, 8 mm out", "flat", 6.0, 0.0, 6.0, 3, 8.0)
TOOLS = {t.number: t for t in (FLAT, STUBBY)}
JAWS = ViseJaws(jaw_height=40.0, jaw_width=150.0, jaw_thickness=20.0, parallels_height=35.0, opening_min=0.0,
                opening_max=160.0)
# Stock 40 x 20 x 15 mm, top-front-left; the part 10 mm tall on 5 mm of holding allowance.
STOCK_MIN, STOCK_MAX = np.array([0.0, 0.0, -15.0]), np.array([40.0, 20.0, 0.0])
SETUP = Setup(stock_min=STOCK_MIN, stock_max=STOCK_MAX, transform_mesh_to_work=np.eye(4), floor_z=-10.5,
              jaws=JAWS.place(STOCK_MIN, STOCK_MAX))
PART = trimesh.creation.box(bounds=[[5, 3, -10], [35, 17, -2]]).triangles


def test_jaws_sit_against_the_stock_and_grip_its_lowest_5_mm():
    front, back, parallels = SETUP.jaws
    np.testing.assert_allclose(front.lo, [-55, -20, -50])
    np.testing.assert_allclose(front.hi, [95, 0, -10])
    np.testing.assert_allclose(back.lo, [-55, 20, -50])
    np.testing.assert_allclose(parallels.hi, [95, 20, -15])


def _sampled_depth(a, b, tool: Tool, box: FixtureBox, n: int = 4001) -> float:
    """Independent estimate: the tool's cylinders at many points along the move."""
    t = np.linspace(0.0, 1.0, n)[:, None]
    p = a + t * (b - a)
    best = 0.0
    for h, r in tool_cylinders(tool):
        d = np.maximum(np.maximum(box.lo[:2] - p[:, :2], p[:, :2] - box.hi[:2]), 0.0)
        radial = r - np.hypot(d[:, 0], d[:, 1])
        vertical = box.hi[2] - h - p[:, 2]
        depth = np.where(vertical >= 0, np.minimum(radial, vertical), 0.0)
        best = max(best, float(depth.max()))
    return best


@settings(max_examples=150, deadline=None)
@given(a=st.tuples(st.floats(-30, 70), st.floats(-30, 50), st.floats(-25, 20)),
       b=st.tuples(st.floats(-30, 70), st.floats(-30, 50), st.floats(-25, 20)),
       tool=st.sampled_from([FLAT, STUBBY]), which=st.integers(0, 2))
def test_sweep_matches_dense_sampling(a, b, tool, which):
    a, b = np.array(a), np.array(b)
    box = SETUP.jaws[which]
    hits = fixture_contacts(a[None], b[None], np.array([tool.number]), TOOLS, (box,))
    sampled = _sampled_depth(a, b, tool, box)
    # The sweep's depth bounds every sampled contact from above (it is the lesser of the
    # deepest radial and vertical overlap), and is positive only where the samples find the
    # body inside the box too (up to the step between samples).
    step = float(np.linalg.norm(b - a)) / 4000
    assert hits.depth[0] >= sampled - 1e-9
    if hits.depth[0] > step + 1e-6:
        assert sampled > 0.0
    if sampled > 0.0:
        assert hits.box[0] == 0


def _program(blocks):
    n = len(blocks) + 1
    points = np.full((n, 3), np.nan)
    motion = np.zeros(n, np.int8)
    tool = np.zeros(n, np.int32)
    for k, (m, t, p) in enumerate(blocks, start=1):
        points[k], motion[k], tool[k] = p, m, t
    feed = np.where(motion == Motion.RAPID, np.nan, 500.0)
    return ProgramMoves(points, motion, tool, feed, np.arange(n, dtype=np.int32))


R, C = Motion.RAPID, Motion.CUT


def test_a_cut_into_the_front_jaw_is_a_jaws_fault_on_its_line():
    prog = _program([(R, 1, (20, 10, 5)), (C, 1, (20, 10, -5)), (C, 1, (20, 1, -5)),  # a real cut, lines 1-3
                     (R, 1, (20, 1, 5)), (R, 1, (20, -6, 5)), (C, 1, (20, -6, -12)),  # line 6: into the jaw
                     (C, 1, (25, -6, -12)), (R, 1, (25, -6, 5))])  # line 7 cuts on in it, line 8 leaves it
    report = simulate(prog, TOOLS, SETUP, PART).report
    jaws = [f for f in report.faults if f.kind == "jaws"]
    assert len(jaws) == 1 and jaws[0].lines == (6, 7) and jaws[0].worst == pytest.approx(2.0)
    assert "front jaw" in jaws[0].message and not report.ok
    assert FAULT_KINDS[-1] == "jaws"


def test_a_short_tool_s_holder_reaching_a_jaw_beside_the_stock_is_caught():
    # the tip stays 2 mm above the jaw top beside the stock; with 8 mm stick-out the holder
    # (28 mm across) clears it, the cut itself is fine: no fault ...
    ok = _program([(R, 2, (20, 4, 5)), (C, 2, (20, 4, -8))])
    assert not [f for f in simulate(ok, TOOLS, SETUP, PART).report.faults if f.kind == "jaws"]
    # ... while over the jaw, the tool itself comes down onto it
    bad = _program([(R, 2, (20, -2, 5)), (C, 2, (20, -2, -11))])
    (f,) = [f for f in simulate(bad, TOOLS, SETUP, PART).report.faults if f.kind == "jaws"]
    assert f.tool == 2 and f.lines == (2,) and f.worst == pytest.approx(1.0)


def test_moves_clear_of_the_jaws_and_old_setups_without_jaws_are_not_flagged():
    prog = _program([(R, 1, (20, 10, 5)), (C, 1, (20, 10, -10.5)), (C, 1, (-10, 10, -10.5))])
    report = simulate(prog, TOOLS, SETUP, PART).report  # out past the stock's side: along the jaws, not into them
    assert not [f for f in report.faults if f.kind == "jaws"]
    deep = _program([(R, 1, (20, -6, 5)), (C, 1, (20, -6, -12))])
    old = Setup(stock_min=STOCK_MIN, stock_max=STOCK_MAX, transform_mesh_to_work=np.eye(4))
    assert not [f for f in simulate(deep, TOOLS, old, PART).report.faults if f.kind == "jaws"]


def test_the_planner_refuses_a_toolpath_into_the_vise():
    cut = CuttingData(10000, 800, 300)
    pts = np.array([[20, -6, 5], [20, -6, -12], [20, -6, 5]], float)
    op = Operation("doctored", "roughing", FLAT, cut, pts, np.array([R, C, R], np.int8))
    with pytest.raises(ToolpathError, match="front jaw .* would hit the vise"):
        safe_rapids([op], SETUP, PART)
