"""Safe cutting: tools chosen by reach, rest roughing, finishing kept out of uncut stock, rapids clear of it.

Engagement is measured by the independent probe in tests/cadcam/sweep.py, not by the
planner's own stock model.
"""

from __future__ import annotations

import dataclasses
import logging

import manifold3d
import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from cadcam.drilling import POINT_CLEARANCE_MM
from cadcam.finishing import FinishingOptions
from cadcam.gcode import parse_gcode
from cadcam.model import CuttingData, Motion, Operation, Setup
from cadcam.plan import PlanOptions, choose_tools, plan_job
from cadcam.post import PostOptions, post_process
from cadcam.heightmap import Grid
from cadcam.rest import holder_keepout, levels_within_reach, safe_rapids
from cadcam.roughing import zlevel_roughing
from cadcam.stock import Simulation, operation_moves, stock_after
from cadcam.verify import simulate
from cadcam.setup import make_setup
from cadcam.tools import load_tool_library
from factory.core.errors import ToolError
from tests.cadcam.sweep import past_axial_limit, rapid_hits, sweep_moves
from tests.conftest import manifold_to_trimesh, pocket_block

LIBRARY = load_tool_library()
FAST = PlanOptions(finishing=FinishingOptions(scallop=0.05))
#: Finishing engagement the plan promises [mm], and the probe's slack for its grid.
LIMIT = FAST.finish_engagement
SLACK = 0.3


def box_setup(size) -> Setup:
    return Setup(stock_min=[0.0, 0.0, -size[2]], stock_max=[size[0], size[1], 0.0], transform_mesh_to_work=np.eye(4))


def test_a_deep_part_gets_the_tools_that_reach_it():
    # 34.5 mm deep: T1 (32 mm stick-out) and the standard balls are too short, T2 (45), T5 (40) and T14 (55)
    # reach; so does the long-neck 6 mm ball T17 (50).
    rough, finish = choose_tools(LIBRARY, box_setup((80.0, 60.0, 34.5)), PlanOptions())
    assert rough.length >= 34.5 and rough.shape != "ball"
    assert finish.length >= 34.5
    # The narrowest that reaches (a tenth of 60 mm is less than any of them), then the ball that reaches:
    # a long-neck one, since no standard ball does.
    assert (rough.number, finish.number) == (5, 17)


def test_a_shallow_part_keeps_the_usual_tools():
    rough, finish = choose_tools(LIBRARY, box_setup((64.0, 64.0, 16.0)), PlanOptions())
    assert (rough.number, finish.number) == (1, 3)


def test_overrides_win_and_are_still_checked():
    rough, finish = choose_tools(LIBRARY, box_setup((64.0, 64.0, 16.0)), PlanOptions(rough_tool=5, finish_tool=4))
    assert (rough.number, finish.number) == (5, 4)
    with pytest.raises(ToolError, match="T1 reaches 32"):
        choose_tools(LIBRARY, box_setup((80.0, 60.0, 34.5)), PlanOptions(rough_tool=1))


def test_refuses_naming_what_is_missing_only_when_nothing_reaches():
    with pytest.raises(ToolError, match=r"no flat or bull-nose end mill .* 70 mm .* longest is T15 with 66 mm"):
        choose_tools(LIBRARY, box_setup((80.0, 60.0, 70.0)), PlanOptions())


def test_a_drill_never_roughs():
    # Chosen by fit, the roughing end mill came from every tool that is not a ball: a drill too.
    library = dataclasses.replace(LIBRARY, tools=tuple(t for t in LIBRARY.tools if t.shape not in ("flat", "bull")))
    assert any(t.is_drill for t in library.tools)
    setup, part = make_setup(manifold_to_trimesh(manifold3d.Manifold.cube((30.0, 24.0, 8.0))))
    with pytest.raises(ToolError, match="no flat or bull-nose end mill"):
        choose_tools(library, setup, PlanOptions(), np.asarray(part.triangles))
    rough, _ = choose_tools(LIBRARY, setup, PlanOptions(), np.asarray(part.triangles))
    assert rough.shape in ("flat", "bull")


def _doctored(setup: Setup, tool_number: int, descent_xy) -> Operation:
    tool = LIBRARY.tool(tool_number)
    x, y = descent_xy
    pts = [[x, y, setup.safe_z], [x, y, -2.0], [x + 5.0, y, -2.0], [x + 5.0, y, setup.safe_z]]
    motion = [Motion.RAPID, Motion.RAPID, Motion.CUT, Motion.RAPID]
    return Operation("doctored", "roughing", tool, CuttingData(10000, 1000, 300), pts, motion)


@pytest.mark.parametrize("xy", [(20.0, 15.0), (-1.0, 20.0)], ids=["centre-in-stock", "edge-only"])
def test_a_rapid_into_stock_is_split_into_rapid_then_plunge(xy):
    # (-1, 20): the tool's centre is outside the stock, its edge 2 mm inside it.
    setup = box_setup((40.0, 30.0, 10.0))
    part = manifold_to_trimesh(manifold3d.Manifold.cube((36.0, 26.0, 5.0)).translate((2.0, 2.0, -10.0)))
    op = _doctored(setup, 1, xy)
    before = sweep_moves(op.points, op.motion, np.full(len(op.points), 1), {1: op.tool}, setup, 0.25)
    assert len(rapid_hits(before, op.motion)) == 1
    (fixed,), checked, n_fixed = safe_rapids([op], setup, np.asarray(part.triangles))
    assert (checked, n_fixed) == (1, 1)
    after = sweep_moves(fixed.points, fixed.motion, np.full(len(fixed.points), 1), {1: op.tool}, setup, 0.25)
    assert len(rapid_hits(after, fixed.motion)) == 0
    # Rapid down to the clearance above the stock top, feed the rest.
    assert fixed.points[1, 2] == pytest.approx(setup.clearance, abs=1e-6) and fixed.points[2, 2] == -2.0
    assert fixed.motion[1] == Motion.RAPID and fixed.motion[2] == Motion.PLUNGE


def probe_plan(body: manifold3d.Manifold, options: PlanOptions = FAST, cell: float = 0.5, library=LIBRARY,
               full_width: bool = False):
    setup, part = make_setup(manifold_to_trimesh(body))
    job = plan_job(part, setup, library, part_name="p", options=options).job
    text = post_process(job, PostOptions()).text
    moves = parse_gcode(text)
    tools = {t.number: t for t in job.tools}
    sw = sweep_moves(moves.points, moves.motion, moves.tool, tools, setup, cell, full_width=full_width)
    return job, setup, moves, sw, text


def finishing_moves(moves, text: str) -> np.ndarray:
    """(n,) bool: moves of the program's finishing operations (after their ``(op k: ... [raster])`` comment:
    raster, waterline, or flats and walls with a flat end mill)."""
    kind = np.zeros(len(text.splitlines()) + 2, dtype=bool)
    current = False
    for i, line in enumerate(text.splitlines(), start=1):
        if line.startswith("(op "):
            current = any(f"[{kind}]" in line for kind in ("raster", "waterline", "finishing"))
        kind[i] = current
    return kind[moves.line]


def assert_safe(job, setup, moves, sw, text: str) -> None:
    feed = moves.motion != Motion.RAPID
    fin = finishing_moves(moves, text) & feed
    for t in {op.tool.number for op in job.operations if op.kind in ("raster", "waterline", "finishing")}:
        sel = fin & (moves.tool == t)
        assert sw.buried[sel].max(initial=0.0) <= LIMIT + SLACK, (t, float(sw.buried[sel].max()))
    hits = rapid_hits(sw, moves.motion)
    assert len(hits) == 0, [(int(moves.line[k]), float(sw.engagement[k])) for k in hits[:5]]
    # The post writes 4 decimals. No feed below the setup's floor: the holding allowance stays. A through hole's
    # drill point alone goes on into it (its full diameter breaks through), short of the stock's bottom.
    drilling = feed & np.isin(moves.tool, [t.number for t in job.tools if t.is_drill])
    assert np.nanmin(np.where(feed & ~drilling, sw.lowest, np.nan), initial=np.inf) >= float(setup.floor_z) - 1e-4
    if drilling.any():
        assert np.nanmin(np.where(drilling, sw.lowest, np.nan)) >= float(setup.stock_min[2]) + POINT_CLEARANCE_MM - 1e-4
    assert float(setup.floor_z) - float(setup.stock_min[2]) >= 3.0 - 1e-9


def test_a_slot_too_narrow_for_the_roughing_tool_is_rest_roughed_then_finished():
    body = manifold3d.Manifold.cube((40.0, 30.0, 10.0)) - manifold3d.Manifold.cube((24.0, 4.0, 7.0)).translate(
        (8.0, 13.0, 4.0))
    job, setup, moves, sw, text = probe_plan(body)
    kinds = [(op.kind, op.tool.number) for op in job.operations]
    assert ("roughing", 6) in kinds, kinds
    assert job.parameters["unreached"] == []
    assert_safe(job, setup, moves, sw, text)


def test_rest_roughing_steps_down_through_the_corners_a_wider_tool_left():
    """The pocketed block: the 8 mm bull-nose leaves slivers in the pocket's corners up to its top, thinner than
    the excess counts; the rest tools take them a level at a time, never deeper apart than their axial limit
    (the 2 mm end mill used to enter them at the pocket's floor only and take 3.0 mm at full width at once; the
    narrower end mills now reach them from the room round them in the pocket, issue 34)."""
    setup, part = make_setup(pocket_block())
    job = plan_job(part, setup, LIBRARY, part_name="p", options=FAST).job
    rests = [op for op in job.operations if op.kind == "roughing" and op.name.startswith("rest rough")]
    assert rests
    for rest in rests:
        levels = np.unique(np.round(rest.points[rest.motion == Motion.CUT, 2], 3))[::-1]
        assert np.all(-np.diff(levels) <= rest.tool.full_width_limit + 1e-6), (rest.name, levels)
    # down to the pocket's floor (Z-5 under the 1 mm on top, plus the allowance)
    assert min(float(op.points[:, 2].min()) for op in rests) == pytest.approx(-4.7)
    text = post_process(job, PostOptions()).text
    moves = parse_gcode(text)
    report = simulate(moves, {t.number: t for t in job.tools}, setup, np.asarray(part.triangles),
                      finishing=finishing_moves(moves, text)).report
    assert report.ok, [f.message for f in report.faults]
    for e in report.engagement:
        assert e.max_full_depth <= e.axial_limit + e.cell, e
    assert {e.tool: e for e in report.engagement}[6].cell <= 0.2 + 1e-9


def test_a_hole_no_tool_fits_is_reported_and_left_alone():
    # 4 mm across, in a library whose narrowest end mill is T1 (6 mm): the 2 mm T6 taken out.
    library = dataclasses.replace(LIBRARY, tools=tuple(t for t in LIBRARY.tools if t.number != 6))
    body = manifold3d.Manifold.cube((30.0, 24.0, 8.0)) - manifold3d.Manifold.cylinder(10.0, 2.0, 2.0, 32).translate(
        (15.0, 12.0, 2.0))
    job, setup, moves, sw, text = probe_plan(body, library=library)
    (u,) = job.parameters["unreached"]
    # Work coordinates: make_setup puts the part 2 mm in from the stock's front-left corner.
    assert u["x"] == pytest.approx(17.0, abs=1.0) and u["y"] == pytest.approx(14.0, abs=1.0)
    assert u["size_x"] <= 4.5 and u["depth"] > LIMIT
    assert_safe(job, setup, moves, sw, text)


@st.composite
def machinable_blocks(draw):
    sx, sy, sz = draw(st.floats(30, 45)), draw(st.floats(25, 35)), draw(st.floats(6, 12))
    body = manifold3d.Manifold.cube((sx, sy, sz))
    for _ in range(draw(st.integers(0, 2))):  # round holes, blind or through
        r = draw(st.floats(0.6, 6.0))
        depth = draw(st.floats(2.0, sz + 1.0))
        x, y = draw(st.floats(r + 2, sx - r - 2)), draw(st.floats(r + 2, sy - r - 2))
        body -= manifold3d.Manifold.cylinder(depth + 1.0, r, r, 32).translate((x, y, sz - depth))
    for _ in range(draw(st.integers(0, 2))):  # pockets and slots, some narrower than the roughing tool
        w, h = draw(st.floats(2.5, sx / 3)), draw(st.floats(2.5, sy / 3))
        x, y = draw(st.floats(2, sx - w - 2)), draw(st.floats(2, sy - h - 2))
        depth = draw(st.floats(1.0, sz - 1.5))
        body -= manifold3d.Manifold.cube((w, h, depth + 1.0)).translate((x, y, sz - depth))
    if draw(st.booleans()):  # a step down one side
        body -= manifold3d.Manifold.cube((sx / 3 + 1, sy + 2, draw(st.floats(1.0, sz - 2)) + 1)).translate(
            (-1.0, -1.0, sz - 1))
    return body


def _narrow_slot_beside_a_bore() -> manifold3d.Manifold:
    """Hypothesis found it (seed 1): beside the 2.5 mm slot the 6 mm end mill left, the 2 mm one finished
    flats and walls in one pass and was buried 2.0 mm at full width."""
    body = manifold3d.Manifold.cube((30.0, 25.0, 6.0))
    body -= manifold3d.Manifold.cylinder(3.0, 6.0, 6.0, 32).translate((8.0, 8.0, 4.0))
    depth = 3.948276768568355
    return body - manifold3d.Manifold.cube((2.5, 7.83755944262363, depth + 1.0)).translate((2.0, 2.0, 6.0 - depth))


@settings(max_examples=3, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(body=machinable_blocks())
@example(body=_narrow_slot_beside_a_bore())
def test_random_parts_plan_with_no_buried_finishing_tool_and_no_rapid_into_stock(body):
    options = dataclasses.replace(FAST, waterline=True)
    job, setup, moves, sw, text = probe_plan(body, options, full_width=True)
    assert_safe(job, setup, moves, sw, text)
    # No tool past its axial limit at full width, by the probe's leading-edge reading (a grid step of slack).
    assert past_axial_limit(sw, moves.tool, {t.number: t for t in job.tools}, 0.5) == {}


def test_a_part_deeper_than_t1_reaches_plans_with_longer_tools():
    # The case: 34.5 mm deep (35.5 mm of stock over the part's bottom with the default 1 mm on top,
    # 3.5 mm of holding allowance under it); the tools reach the floor 0.5 mm below the part: 36 mm.
    body = manifold3d.Manifold.cube((24.0, 18.0, 34.5)) - manifold3d.Manifold.cube((10.0, 20.0, 12.0)).translate(
        (-1.0, -1.0, 23.5))
    job, setup, moves, sw, text = probe_plan(body)
    assert float(setup.stock_size[2]) == pytest.approx(39.0)
    assert float(setup.stock_max[2] - setup.floor_z) == pytest.approx(36.0)
    assert all(op.tool.length >= 36.0 for op in job.operations)
    assert_safe(job, setup, moves, sw, text)


def test_the_corners_a_wider_tool_left_in_a_narrow_deep_pocket_are_entered_by_a_ramp_along_the_pocket(caplog):
    """An 11 mm pocket 30 mm deep (issue 34's explore block, shortened): the 10 mm end mill roughs it, ramping
    along its 0.4 mm wide centre region, and leaves a sliver in each corner. The 8 mm end mill's regions at
    those corners are slivers no helix or ramp of their own fits; they used to be skipped, and barred the
    pocket below them. Now each is cut with the room round it, entered by a ramp of at most 3 degrees along
    the pocket, level by level at the tool's axial limit, never deeper at full width."""
    body = manifold3d.Manifold.cube((40.0, 25.0, 32.0)) - manifold3d.Manifold.cube((26.07, 10.97, 31.0)).translate(
        (6.965, 7.015, 2.0))
    setup, part = make_setup(manifold_to_trimesh(body))
    tri = np.asarray(part.triangles)
    t10, t8 = LIBRARY.tool(2), LIBRARY.tool(16)
    cut = CuttingData(9000.0, 2000.0, 600.0)
    first = zlevel_roughing(part, setup, t10, cut)
    stock = stock_after([first], setup, tri, 0.5)
    with caplog.at_level(logging.WARNING, logger="cadcam.roughing"):
        rest = zlevel_roughing(part, setup, t8, cut, rest=stock, rest_above=LIMIT)
    assert "too small to enter" not in caplog.text
    floor = float(part.bounds[0][2]) + 2.0  # the pocket's floor in work coordinates
    cuts = rest.points[rest.motion == Motion.CUT]
    levels = np.unique(np.round(cuts[:, 2], 3))[::-1]
    # every level down to the floor (plus the allowance), no more than the axial limit apart
    assert levels[-1] == pytest.approx(floor + 0.3, abs=1e-3) and np.all(-np.diff(levels) <= t8.full_width_limit + 1e-6)
    # into all four corners of the pocket, as near as the 8 mm tool comes (4.3 mm off both walls: 6.1 mm from
    # the corner), nearer than the 10 mm one could (5.3 and 5.5 mm off: 7.6 mm)
    (x0, y0), (x1, y1) = part.bounds[0][:2] + [6.965, 7.015], part.bounds[0][:2] + [6.965 + 26.07, 7.015 + 10.97]
    inside = cuts[(cuts[:, 0] > x0) & (cuts[:, 0] < x1) & (cuts[:, 1] > y0) & (cuts[:, 1] < y1)]
    for cx, cy in ((x0, y0), (x0, y1), (x1, y0), (x1, y1)):
        assert (np.hypot(inside[:, 0] - cx, inside[:, 1] - cy) < 6.5).any(), (cx, cy)
    # entered by ramps no steeper than 3 degrees: every feed move down with a run sideways
    p, m = rest.points, rest.motion
    down = (m[1:] == Motion.PLUNGE) & (p[1:, 2] < p[:-1, 2] - 1e-9)
    run = np.hypot(*(p[1:, :2] - p[:-1, :2]).T)[down]
    drop = (p[:-1, 2] - p[1:, 2])[down]
    sideways = run > 1e-6
    assert sideways.any() and np.all(drop[sideways] <= run[sideways] * np.tan(np.radians(3.0)) + 1e-6)
    report = simulate(operation_moves([first, rest]), {2: t10, 16: t8}, setup, tri).report
    assert report.ok, [f.message for f in report.faults]
    t8_engaged = {e.tool: e for e in report.engagement}[16]
    assert t8_engaged.max_full_depth <= t8.full_width_limit + t8_engaged.cell, t8_engaged


def test_a_rest_tool_goes_as_deep_as_it_reaches_and_no_deeper():
    levels = np.array([-4.0, -8.0, -12.0, -16.0])
    assert levels_within_reach(levels, 0.0, 13.5).tolist() == [-4.0, -8.0, -12.0, -13.5]
    assert levels_within_reach(levels, 0.0, 16.0).tolist() == levels.tolist()
    assert levels_within_reach(levels, 0.0, 12.0).tolist() == [-4.0, -8.0, -12.0]
    assert levels_within_reach(levels, 0.0, 3.0).tolist() == [-3.0]


def _cornered_stock(cell: float, cut: shapely.Geometry, size=(40.0, 30.0), top=0.0, floor=-25.0) -> Simulation:
    """A stock box of ``size`` [mm] sampled every ``cell`` (points half a cell in from its edges, as
    :func:`cadcam.heightmap.grid_over` lays them), cut down to ``floor`` inside ``cut``, whole (``top``) outside."""
    nx, ny = int(round(size[0] / cell)), int(round(size[1] / cell))
    grid = Grid(0.5 * cell, 0.5 * cell, cell, nx, ny)
    x, y = np.meshgrid(grid.xs, grid.ys)
    stock = np.where(shapely.contains_xy(cut, x, y), floor, top)
    return Simulation(grid, stock, np.full_like(stock, -np.inf), -30.0)


def test_below_its_reach_a_holder_kept_out_on_the_planning_grid_clears_the_rim_a_finer_grid_sees():
    """A relief's roughing leaves a rim of whole stock in the block's corners (the round corners of its
    8 mm end mill's region) that thins to nothing along the edges. On the planning model's 0.5 mm grid the
    first row, a quarter of a millimetre in, reads the rim ending 0.8 mm short of where verify's finer
    grid finds it: T6 (2 mm, 16 mm out of an ER11 chuck) rest-roughing 25 mm down beside it ran its holder
    into it (the 100k-triangle relief failed verify on its first plan). Every axis position outside
    holder_keepout on the coarse model must keep each holder cylinder off the stock of the fine one."""
    box = shapely.box(0.0, 0.0, 40.0, 30.0)
    cut = box.buffer(-8.1, join_style="mitre").buffer(8.1, quad_segs=32)  # the roughing tool's region, round corners
    coarse, fine = _cornered_stock(0.5, cut), _cornered_stock(0.1, cut)
    tool = LIBRARY.tool(6)
    z = -25.0
    assert z < 0.0 - tool.length  # below its reach: the holder is lower than the stock top
    keepout = holder_keepout(coarse, tool, z)
    ax, ay = np.meshgrid(np.arange(0.0, 30.0, 0.1), np.arange(0.0, 20.0, 0.1))
    free = ~shapely.contains_xy(keepout, ax, ay) & shapely.contains_xy(cut, ax, ay)
    assert free.sum() > 1000  # room is left to cut
    axes = np.column_stack([ax[free], ay[free]])
    fx, fy = np.meshgrid(fine.grid.xs, fine.grid.ys)
    for h, r in tool.body():
        if h < tool.length:
            continue  # the shank: the flutes' own reach, not the holder's
        above = fine.stock_top > z + h
        if not above.any():
            continue
        near, _ = cKDTree(np.column_stack([fx[above], fy[above]])).query(axes)
        assert near.min() >= r, (h, r, axes[np.argmin(near)], near.min())
