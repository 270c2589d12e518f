"""Why stock is left (cadcam.stock.why_left): the verdict names a sharp inside corner, a place no tool reaches,
and what op 2 takes from below."""

from __future__ import annotations

import dataclasses

import manifold3d
import numpy as np

from cadcam.gcode import parse_gcode
from cadcam.plan import PlanOptions, plan_job
from cadcam.post import PostOptions, post_process
from cadcam.setup import make_setup
from cadcam.heightmap import Grid
from cadcam.stock import FOR_OP2, NO_TOOL, SHARP_CORNER, Simulation, unreached, why_left
from cadcam.tools import load_tool_library
from cadcam.verify import VerifyOptions, simulate
from factory.verify import report_text
from tests.conftest import manifold_to_trimesh

LIBRARY = load_tool_library()


def _floor_with_walls():
    """A 10 x 10 mm pocket floor at Z-5 on a 0.1 mm grid, walls (Z0) along X < 1 and Y < 1 mm."""
    g = Grid(x0=0.0, y0=0.0, cell=0.1, nx=101, ny=101)
    x, y = np.meshgrid(g.xs, g.ys)
    part = np.where((x < 1.0) | (y < 1.0), 0.0, -5.0)
    return g, x, y, part


def test_a_corner_a_round_tool_left_is_a_sharp_inside_corner_a_square_patch_is_not():
    g, x, y, part = _floor_with_walls()
    # what an R3 tool leaves in the corner: outside its circle about (4, 4), inside the corner's square
    corner = (x >= 1.0) & (y >= 1.0) & (x < 4.0) & (y < 4.0) & (np.hypot(x - 4.0, y - 4.0) > 3.0)
    patch = (x >= 6.0) & (x <= 8.5) & (y >= 6.0) & (y <= 8.5)  # a 2.5 mm square no tool entered
    sim = Simulation(grid=g, stock_top=np.where(corner | patch, 0.0, part), part_top=part, stock_bottom=-20.0)
    left = why_left(unreached(sim, 0.1, 0.0), sim, 0.1, radius=3.0)
    by_place = {(round(u.x), round(u.y)): u.why for u in left}
    assert len(left) == 2 and by_place[(7, 7)] == NO_TOOL, left
    assert [u.why for u in left if u.x < 4] == [SHARP_CORNER], left
    # a narrower tool than the corner's size: no tool of the program leaves such a corner
    assert {u.why for u in why_left(unreached(sim, 0.1, 0.0), sim, 0.1, radius=1.0)} == {NO_TOOL}


def test_each_region_left_says_why():
    # 80 x 50 x 12 mm plate with a 1.5 mm slot through it that no end mill enters
    solid = manifold3d.Manifold.cube((80.0, 50.0, 12.0)) \
        - manifold3d.Manifold.cube((1.5, 20.0, 14.0)).translate((60, 15, -1))
    setup, part = make_setup(manifold_to_trimesh(solid))
    job = plan_job(part, setup, LIBRARY, part_name="left", options=PlanOptions()).job
    moves = parse_gcode(post_process(job, PostOptions()).text, source="left.nc")
    tools = {t.number: t for t in job.tools}
    report = simulate(moves, tools, setup, np.asarray(part.triangles), VerifyOptions(op2_follows=True)).report
    assert report.left and {u.why for u in report.left} == {FOR_OP2}, report.left
    # op 1 is done with what op 2 takes from below, and its one-liner says what that leaves (issue 30)
    n = len(report.left)
    assert report.finished and report.on_part == ()
    assert report_text(report).startswith(f"verify OK, finished to 0.1 mm except {n} region{'s' if n > 1 else ''} "
                                          f"left for op 2: "), report_text(report)
    assert all(u.to_dict()["why"] == u.why and u.describe().endswith(": " + u.why) for u in report.left)
    alone = simulate(moves, tools, setup, np.asarray(part.triangles), VerifyOptions()).report  # no op 2 after
    assert {u.why for u in alone.left} == {NO_TOOL}
    assert not alone.finished and report_text(alone).startswith("verify: no gouge or crash, but stock left in ")
    assert dataclasses.replace(alone.left[0], why="").to_dict().keys() == {"x", "y", "size_x", "size_y", "depth",
                                                                          "z_bottom"}


def _plan_and_verify(solid, op2_follows: bool = True):
    setup, part = make_setup(manifold_to_trimesh(solid))
    job = plan_job(part, setup, LIBRARY, part_name="corners", options=PlanOptions()).job
    moves = parse_gcode(post_process(job, PostOptions()).text, source="corners.nc")
    tools = {t.number: t for t in job.tools}
    report = simulate(moves, tools, setup, np.asarray(part.triangles), VerifyOptions(op2_follows=op2_follows)).report
    return setup, report


def test_a_square_cornered_pocket_and_slot_keep_their_corners_and_verify_says_so():
    """Issue 30: a round tool cannot finish a sharp inside corner. The sliver it leaves lies within a cell
    diagonal of both walls, where the grid cannot see it, yet it stands the walls' full height; verify
    lists each corner with its place and depth, and the part is not 'finished'."""
    plate = manifold3d.Manifold.cube((80.0, 50.0, 12.0))
    slot = manifold3d.Manifold.cube((30.0, 8.0, 20.0)).translate((25.0, 21.0, -4.0))  # through
    pocket = manifold3d.Manifold.cube((20.0, 12.0, 20.0)).translate((10.0, 5.0, 6.0))  # 6 mm deep
    setup, report = _plan_and_verify(plate - slot - pocket)
    corners = [u for u in report.left if u.why == SHARP_CORNER]
    assert not report.finished and len(corners) == 8, report.left
    # back from work coordinates to the model's: the corners stand where the model has them
    shift = np.asarray(setup.transform_mesh_to_work)[:3, 3]
    at = sorted((round(u.x - shift[0], 1), round(u.y - shift[1], 1)) for u in corners)
    assert at == sorted([(25.0, 21.0), (55.0, 21.0), (25.0, 29.0), (55.0, 29.0),
                         (10.0, 5.0), (30.0, 5.0), (10.0, 17.0), (30.0, 17.0)]), at
    for u in corners:
        pocket_corner = u.x - shift[0] in (10.0, 30.0)
        assert abs(u.depth - (6.0 if pocket_corner else 12.0)) < 0.6, u  # the walls' height (and the skin on top)
        assert 0.0 < u.size_x <= 0.6 and u.describe().endswith(": sharp inside corner")


def test_a_facetted_round_hole_has_no_sharp_corner():
    """The revert of the first attempt: cells a micrometre outside a facetted round hole were listed as
    15 mm sharp corners. Between two facets of a 64-gon the walls meet at 174 deg, whose sliver is
    micrometres: no corner is listed, and the part is finished."""
    from cadcam.corners import inside_corners, sliver

    plate = manifold3d.Manifold.cube((60.0, 40.0, 15.0))
    hole = manifold3d.Manifold.cylinder(20.0, 8.0, 8.0, 64).translate((30.0, 20.0, -2.0))
    solid = plate - hole
    edges = inside_corners(np.asarray(manifold_to_trimesh(solid).triangles))
    assert len(edges) >= 64 and np.allclose(edges.angle, 180.0 - 360.0 / 64, atol=1e-6)
    assert sliver(5.0, edges.angle).max() < 0.01
    _, report = _plan_and_verify(solid)
    assert not [u for u in report.left if u.why == SHARP_CORNER], report.left


def test_inside_corners_are_the_concave_vertical_edges_at_their_angle():
    """A square pocket's four corners at 90 deg; an L-shaped pocket's re-entrant corner is convex (not
    listed) and its five others are; the outside of a block has none."""
    from cadcam.corners import inside_corners

    block = manifold3d.Manifold.cube((40.0, 30.0, 10.0))
    assert len(inside_corners(np.asarray(manifold_to_trimesh(block).triangles))) == 0
    square = block - manifold3d.Manifold.cube((10.0, 10.0, 20.0)).translate((5.0, 5.0, 4.0))
    edges = inside_corners(np.asarray(manifold_to_trimesh(square).triangles))
    assert np.allclose(edges.angle, 90.0) and {tuple(np.round(p, 6)) for p in edges.xy} == \
        {(5.0, 5.0), (15.0, 5.0), (5.0, 15.0), (15.0, 15.0)}
    assert np.allclose(edges.z_low, 4.0) and np.allclose(edges.z_high, 10.0)
    ell = block - manifold3d.Manifold.cube((20.0, 8.0, 20.0)).translate((5.0, 5.0, 4.0)) \
        - manifold3d.Manifold.cube((8.0, 20.0, 20.0)).translate((5.0, 5.0, 4.0))
    edges = inside_corners(np.asarray(manifold_to_trimesh(ell).triangles))
    assert {tuple(np.round(p, 6)) for p in edges.xy} == {(5.0, 5.0), (25.0, 5.0), (25.0, 13.0), (13.0, 25.0),
                                                         (5.0, 25.0)}


def test_a_reliefs_rim_its_boundary_band_and_stock_on_its_surface_are_told_apart():
    """Issue 34: the relief sample's verify said "124.0 x 84.0 mm near X62.0 Y42.0, 9.9 mm of stock: no tool
    reaches": the uncut rim round the surface, joined through the stock along the boundary to pockets on the
    surface. A 20 x 20 mm relief at Z-9.9 in a 40 x 40 mm block: the rim stands 9.9 mm round it, the R4 roughing
    tool left the surface's four corners whole, a 1.2 mm patch runs 8 mm in from the boundary, and a 4 x 4 mm
    pocket 1 mm deep lies in the middle. Each is named at its own place and size."""
    import trimesh

    from cadcam.heightmap import upper_envelope
    from cadcam.model import Setup
    from cadcam.relief import machining_surface, surface_footprint
    from cadcam.stock import AT_BOUNDARY, OUTSIDE_RELIEF
    from cadcam.verify import VerifyReport

    sheet = trimesh.Trimesh(vertices=[[10, 10, -9.9], [30, 10, -9.9], [30, 30, -9.9], [10, 30, -9.9]],
                            faces=[[0, 1, 2], [0, 2, 3]])
    setup = Setup(stock_min=[0, 0, -20], stock_max=[40, 40, 0], transform_mesh_to_work=np.eye(4))
    tri = np.asarray(machining_surface(sheet, setup).triangles)
    g = Grid(x0=0.25, y0=0.25, cell=0.5, nx=80, ny=80)
    x, y = np.meshgrid(g.xs, g.ys)
    on = surface_footprint(tri, g)
    corners = np.zeros_like(on)
    for kx, ky in ((10, 10), (10, 30), (30, 10), (30, 30)):  # beyond the R4 tool's centre nearest each corner
        cx, cy = kx + (4 if kx < 20 else -4), ky + (4 if ky < 20 else -4)
        corners |= ((x - cx) * (kx - cx) > 0) & ((y - cy) * (ky - cy) > 0) & (np.hypot(x - cx, y - cy) > 4.0)
    patch = (x > 18.0) & (x < 24.0) & (y < 18.0)
    pocket = (x > 18.0) & (x < 22.0) & (y > 20.0) & (y < 24.0)
    stock = np.where(~on | corners, 0.0, np.where(patch, -8.7, np.where(pocket, -8.9, -9.9)))
    sim = Simulation(grid=g, stock_top=stock, part_top=upper_envelope(tri, g), stock_bottom=-20.0)
    left = why_left(unreached(sim, 0.1, 0.0, ~on, band=4.0), sim, 0.1, radius=4.0)
    rim = [u for u in left if u.why == OUTSIDE_RELIEF]
    assert len(rim) == 1 and rim[0].size_x == rim[0].size_y == 40.0 and rim[0].depth > 9.8, left
    edge = sorted((round(u.x), round(u.y), round(u.depth, 1)) for u in left if u.why == AT_BOUNDARY)
    assert edge == [(11, 11, 9.9), (11, 29, 9.9), (21, 12, 1.2), (29, 11, 9.9), (29, 29, 9.9)], left
    assert all(u.band <= 4.0 + g.cell for u in left if u.why == AT_BOUNDARY), left
    # further in than the roughing tool's radius: the patch's inner 4 mm and the pocket, each where it is
    rest = sorted((round(u.x), round(u.y), round(u.size_x), round(u.size_y), round(u.depth, 1))
                  for u in left if u.why not in (OUTSIDE_RELIEF, AT_BOUNDARY))
    assert rest == [(20, 22, 4, 4, 1.0), (21, 16, 6, 4, 1.2)], left
    # the verdict's lines list what is on the part, the boundary's stock by how far in it is, not the rim
    report = VerifyReport(max_gouge=0.0, gouge_position=None, gouge_line=None, remaining_max=9.9,
                          remaining_mean=1.0, remaining_p95=1.2, rapid_crashes=(), moves=1, cut_length=1.0,
                          rapid_length=0.0, cells=g.size, cell=g.cell, left=left)
    text = report_text(report)
    assert OUTSIDE_RELIEF not in text and f"stock left in {len(left) - 1} regions" in text, text
    assert "left: 1.0 x 1.0 mm near X11.0 Y11.0 up to 0.5 mm in from the boundary, 9.9 mm of stock" in text, text
