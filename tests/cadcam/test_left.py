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
    assert all(u.to_dict()["why"] == u.why and u.describe().endswith(": " + u.why) for u in report.left)
    alone = simulate(moves, tools, setup, np.asarray(part.triangles), VerifyOptions()).report  # no op 2 after
    assert {u.why for u in alone.left} == {NO_TOOL}
    assert dataclasses.replace(alone.left[0], why="").to_dict().keys() == {"x", "y", "size_x", "size_y", "depth",
                                                                          "z_bottom"}
