"""The vise's jaws and parallels as obstacles: exact sweeps, verify faults with lines, the planner's guard."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh
from shapely.geometry import Point
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam.model import CuttingData, FixtureBox, Motion, Operation, ProgramMoves, Setup, Tool, ViseJaws
from cadcam.rest import safe_rapids
from cadcam.verify import FAULT_KINDS, simulate
from cadcam.stock import operation_moves
from cadcam.workholding import KEEPOUT_CLEARANCE_MM, fixture_contacts, jaw_keepout, tool_cylinders
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


# Jaws gripping 13 mm of the 15 mm stock: their top (-2) is above the floor (-10.5), so a tool at the
# stock's Y faces would run into them; the part's block reaches both Y faces of the stock.
HIGH_JAWS = ViseJaws(jaw_height=48.0, jaw_width=150.0, jaw_thickness=20.0, parallels_height=35.0, opening_min=0.0,
                     opening_max=160.0)
HIGH_SETUP = Setup(stock_min=STOCK_MIN, stock_max=STOCK_MAX, transform_mesh_to_work=np.eye(4), floor_z=-10.5,
                   jaws=HIGH_JAWS.place(STOCK_MIN, STOCK_MAX))
EDGE_PART = trimesh.creation.box(bounds=[[12, 0, -10], [28, 20, -3]])


def test_no_keepout_where_no_tool_reaches_the_jaws():
    # as make_setup places it: 6.5 mm holding less 0.5 breakthrough, the jaws' top 1 mm under the floor
    assert jaw_keepout(dataclasses.replace(SETUP, floor_z=-9.0), (FLAT, STUBBY)) is None
    assert jaw_keepout(HIGH_SETUP, ()) is not None


def test_the_keepout_keeps_each_tool_s_cutter_shank_and_holder_off_the_jaws():
    within = jaw_keepout(HIGH_SETUP, (FLAT,))
    region = within(FLAT.radius)
    front = HIGH_SETUP.jaws[0]
    reach = max(r for h, r in tool_cylinders(FLAT) if front.hi[2] > HIGH_SETUP.floor_z + h) + KEEPOUT_CLEARANCE_MM
    # an axis just over that reach off the front jaw's face is allowed, just under it is not
    assert region.contains(Point(20.0, front.hi[1] + reach + 0.01))
    assert not region.contains(Point(20.0, front.hi[1] + reach - 0.01))
    # a radius no library tool has keeps off by the cutter alone
    assert within(1.0).contains(Point(20.0, front.hi[1] + 1.0 + KEEPOUT_CLEARANCE_MM + 0.01))


def test_a_plan_whose_floor_is_below_the_jaws_top_never_enters_them_and_reports_the_shadow():
    """Independent of the planner's regions: every move of every tool, shank and holder swept against the boxes."""
    from cadcam.plan import PlanOptions, plan_job
    from cadcam.tools import load_tool_library

    library = load_tool_library()
    job = plan_job(EDGE_PART, HIGH_SETUP, library, part_name="edge", options=PlanOptions(by_faces=False)).job
    moves = operation_moves(job.operations)
    tools = {t.number: t for t in job.tools}
    hits = fixture_contacts(moves.points[:-1], moves.points[1:], moves.tool[1:], tools, HIGH_SETUP.jaws)
    assert hits.depth.max() <= 1e-9, hits.depth.max()
    # the stock in the jaws' shadow is left and said so, not cut and not refused
    assert job.parameters["unreached"]


def test_without_the_keepout_the_same_plan_runs_into_the_jaws(monkeypatch):
    """The keep-out is what keeps that plan clear: without it the planner's last guard refuses it."""
    import cadcam.plan
    from cadcam.tools import load_tool_library

    monkeypatch.setattr(cadcam.plan, "jaw_keepout", lambda setup, tools, shadows=None: None)
    with pytest.raises(ToolpathError, match="jaw .* would hit the vise"):
        cadcam.plan.plan_job(EDGE_PART, HIGH_SETUP, load_tool_library(), part_name="edge",
                             options=cadcam.plan.PlanOptions(by_faces=False))


def test_an_operation_starting_low_is_reached_by_a_checked_descent_from_the_safe_height():
    """The link into an operation that starts in the stock: a rapid straight down, found to touch the
    stock and fed the rest of the way, never a diagonal rapid from the last operation's end."""
    cut = CuttingData(10000, 800, 300)
    first = Operation("first", "roughing", FLAT, cut, np.array([[5, 5, 5], [5, 5, 2], [5, 5, 5]], float),
                      np.array([R, C, R], np.int8))
    low = Operation("low", "roughing", FLAT, cut, np.array([[30, 10, -4], [35, 10, -4]], float),
                    np.array([R, C], np.int8))
    ops, checked, fixed = safe_rapids([first, low], SETUP, PART)
    pts, mot = ops[1].points, ops[1].motion
    assert pts[0].tolist() == [30, 10, SETUP.safe_z] and pts[-1].tolist() == [35, 10, SETUP.safe_z]
    # the descent into the stock top (z 0) rapids to the clearance above it and feeds the rest
    assert fixed == 1 and mot[1] == Motion.RAPID and 0 < pts[1, 2] < SETUP.safe_z and mot[2] == Motion.PLUNGE


def _plan_clear_of_the_jaws(part: trimesh.Trimesh, setup: Setup, options):
    """``part`` planned in ``setup``; asserts every move of every tool, shank and holder (the exact sweep,
    not the planner's regions) stays out of the jaws and parallels. Returns the job."""
    from cadcam.plan import plan_job
    from cadcam.tools import load_tool_library

    job = plan_job(part, setup, load_tool_library(), part_name="edge", options=options).job
    moves = operation_moves(job.operations)
    hits = fixture_contacts(moves.points[:-1], moves.points[1:], moves.tool[1:], {t.number: t for t in job.tools},
                            setup.jaws)
    assert hits.depth.max() <= 1e-9, hits.depth.max()
    return job


def test_flats_and_walls_at_the_jaws_keep_out_of_them_and_report_what_they_leave():
    """The faces' flat end mill passes (the default plan) at walls that run into the jaws' shadow: planned
    clear of the jaws, the shadow reported (main refused this part: T1 ran 3.35 mm into the front jaw)."""
    from cadcam.plan import PlanOptions

    job = _plan_clear_of_the_jaws(EDGE_PART, HIGH_SETUP, PlanOptions())
    assert any(op.name.startswith("finish flats+walls") for op in job.operations)
    shadow = [u for u in job.parameters["unreached"] if u["y"] < 1.0 or u["y"] > 19.0]
    assert len(shadow) == 2 and all(u["size_x"] >= EDGE_PART.extents[0] for u in shadow), shadow


def test_a_hole_in_the_jaws_shadow_is_not_drilled_and_one_clear_of_them_is():
    """Drilling and helixing keep their tools (and the spot drill before a drill, every hole spotted here) off the
    jaws: the hole 2 mm from the front jaw is left to the milling tools, the one in the middle is spotted and
    drilled."""
    from cadcam.drilling import DrillingOptions
    from cadcam.plan import PlanOptions

    part = EDGE_PART
    for x, y in ((16.0, 2.0), (22.0, 10.0)):
        part = part.difference(trimesh.creation.cylinder(radius=1.65, height=30, sections=64,
                                                         transform=trimesh.transformations.translation_matrix([x, y, -6])))
    job = _plan_clear_of_the_jaws(part, HIGH_SETUP, PlanOptions(by_faces=False, drilling=DrillingOptions(spot_depth=0)))
    holes = job.parameters["holes"]
    assert [(round(h["x"]), round(h["y"])) for h in holes["drilled"]] == [(22, 10)]
    assert [(round(h["x"]), round(h["y"])) for h in holes["left"]] == [(16, 2)]
    assert [op.kind for op in job.operations[:2]] == ["spot", "drill"]


# A 40 mm stock gripped to 2 mm under its top: the ball's walls are taller than its flutes, so the raster
# without waterline begins with the upper raster, beside the jaws.
TALL_MIN, TALL_MAX = np.array([0.0, 0.0, -40.0]), np.array([40.0, 60.0, 0.0])
TALL_SETUP = Setup(stock_min=TALL_MIN, stock_max=TALL_MAX, transform_mesh_to_work=np.eye(4), floor_z=-35.5,
                   jaws=dataclasses.replace(HIGH_JAWS, jaw_height=73.0).place(TALL_MIN, TALL_MAX))
TALL_EDGE_PART = trimesh.creation.box(bounds=[[12, 0, -35], [28, 60, -3]])


def test_the_upper_raster_beside_the_jaws_keeps_out_of_them():
    from cadcam.plan import PlanOptions

    job = _plan_clear_of_the_jaws(TALL_EDGE_PART, TALL_SETUP, PlanOptions(by_faces=False, waterline=False))
    assert "finish raster upper" in [op.name for op in job.operations]
    assert job.parameters["unreached"]


# Jaws gripping 15 mm of a 30 mm stock, their top 10 mm under the part's top; the part fills the stock's Y and
# is gripped on it. A rebate 4 mm wide runs along the front jaw, 5 mm deep, and a 3.3 mm hole with a drill
# point's cone for its bottom lies 2 mm from the back jaw, its tip 7 mm under the top: both far above the
# jaws' top, though within a tool's radius of them.
DEEP_MIN, DEEP_MAX = np.array([0.0, 0.0, -30.0]), np.array([40.0, 20.0, 0.0])
DEEP_SETUP = Setup(stock_min=DEEP_MIN, stock_max=DEEP_MAX, transform_mesh_to_work=np.eye(4), floor_z=-25.5,
                   jaws=dataclasses.replace(HIGH_JAWS, jaw_height=50.0).place(DEEP_MIN, DEEP_MAX))


def _rebated_part() -> trimesh.Trimesh:
    import manifold3d as mf

    from samples.make_samples import SEGMENTS, box, to_trimesh

    r, tip = 1.65, 1.65 / np.tan(np.radians(59.0))  # a 118 degree drill's point under the 3.3 mm bore
    hole = (mf.Manifold.cylinder(6.0, r, r, circular_segments=SEGMENTS).translate((20.0, 18.0, -6.0))
            + mf.Manifold.cylinder(tip, 0.0, r, circular_segments=SEGMENTS).translate((20.0, 18.0, -6.0 - tip)))
    return to_trimesh(box(5, 0, -25, 35, 20, -1) - box(4, -1, -6, 36, 4, 0) - hole)


def test_a_tool_that_stays_above_the_jaws_top_beside_them_is_let_near_them():
    """The keep-out counts how deep each tool really goes near a jaw: no deeper than the part's top on its
    axis. The rebate along the front jaw and the hole 2 mm from the back jaw are far above the jaws' top:
    both are cut (every move still swept clear of the jaws), where taking every tool at the floor leaves them."""
    import cadcam.plan
    from cadcam.plan import PlanOptions

    part = _rebated_part()
    job = _plan_clear_of_the_jaws(part, DEEP_SETUP, PlanOptions())
    holes = job.parameters["holes"]
    assert [(round(h["x"]), round(h["y"])) for h in holes["drilled"]] == [(20, 18)], holes
    # left: only the stock beside the part's ends, down to the floor in the jaws' shadow, none over the part
    assert all(abs(u["x"] - 20.0) - u["size_x"] / 2 >= 15.0 - 1e-6 for u in job.parameters["unreached"]), \
        job.parameters["unreached"]
    # the rebate's floor runs right up to the front jaw: its finishing tool overhangs the stock's face there
    finishing = [op for op in job.operations if op.kind == "finishing"]
    assert min(float(op.points[op.points[:, 2] < -5.0, 1].min()) for op in finishing if (op.points[:, 2] < -5.0).any()) <= 0.0

    # every tool taken at the floor everywhere: the hole is left, the rebate's strip at the jaw reported
    floor_only = lambda setup, tools, shadows=None: jaw_keepout(setup, tools)  # noqa: E731
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(cadcam.plan, "jaw_keepout", floor_only)
        old = _plan_clear_of_the_jaws(part, DEEP_SETUP, PlanOptions()).parameters
    assert [(round(h["x"]), round(h["y"])) for h in old["holes"]["left"]] == [(20, 18)]
    assert any(u["y"] < 4.0 and abs(u["x"] - 20.0) < 15.0 for u in old["unreached"]), old["unreached"]
