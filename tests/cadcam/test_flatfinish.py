"""Flats and walls finished with flat end mills at their heights: checked from the posted program."""

from __future__ import annotations

import dataclasses

import manifold3d
import numpy as np
import pytest

from cadcam.faces import classify_faces
from cadcam.finishing import FinishingOptions
from cadcam.gcode import parse_gcode
from cadcam.plan import PlanOptions, plan_job
from cadcam.post import PostOptions, post_process
from cadcam.stock import SHARP_CORNER
from cadcam.setup import make_setup
from cadcam.tools import load_tool_library
from cadcam.verify import VerifyOptions, finishing_moves, simulate
from tests.conftest import manifold_to_trimesh

LIBRARY = load_tool_library()
FAST = PlanOptions(finishing=FinishingOptions(scallop=0.05))


def _plan_and_verify(body: manifold3d.Manifold, options: PlanOptions = FAST, cell: float = 0.1, library=LIBRARY):
    setup, part = make_setup(manifold_to_trimesh(body))
    job = plan_job(part, setup, library, part_name="p", options=options).job
    text = post_process(job, PostOptions()).text
    moves = parse_gcode(text)
    sheet_ops = [{"kind": op.kind, "tool": op.tool.number} for op in job.operations]
    verified = simulate(moves, {t.number: t for t in job.tools}, setup, np.asarray(part.triangles),
                        VerifyOptions(cell=cell), finishing=finishing_moves(text, moves, sheet_ops))
    sim, report = verified.simulation, verified.report
    return job, setup, sim, report


def test_a_prismatic_part_is_finished_by_flat_end_mills_alone():
    # A step, an open pocket with r5 corners, and a blind 11 mm hole the 10 mm mill cannot enter.
    body = manifold3d.Manifold.cube((60.0, 40.0, 12.0))
    body -= manifold3d.Manifold.cube((20.0, 50.0, 5.0)).translate((-1.0, -5.0, 8.0))
    body -= manifold3d.Manifold.cylinder(8.0, 5.5, 5.5, 96).translate((45.0, 20.0, 6.0))
    job, setup, sim, report = _plan_and_verify(body)
    kinds = [(op.kind, op.tool.number) for op in job.operations]
    assert all(op.tool.shape == "flat" for op in job.operations), kinds
    # the flats and walls finished by the roughing end mill (the 16 or 10 mm, whichever roughs sooner); the
    # hole helixed to size by the 6 mm mill (cadcam.drilling: not the long-neck 8 mm, it is not that deep)
    # or finished by it
    rough = job.parameters["rough_tool"]
    assert rough in (2, 14) and ("finishing", rough) in kinds, kinds
    assert ("finishing", 1) in kinds or ("helix", 1) in kinds, kinds
    assert report.ok, [f.message for f in report.faults]
    rem = sim.remaining
    covered = np.isfinite(rem)
    assert np.percentile(rem[covered], 95) <= 0.02
    # The hole's floor and the foot of its wall: within 0.2 mm of the wall, all finished.
    g = sim.grid
    X, Y = np.meshgrid(g.x0 + g.cell * np.arange(g.nx), g.y0 + g.cell * np.arange(g.ny))
    centre = np.array([45.0, 20.0]) + [2.0, 2.0]  # make_setup's 2 mm margin
    r = np.hypot(X - centre[0], Y - centre[1])
    hole = (r < 5.5 - 0.05) & covered
    assert hole.sum() > 100 and rem[hole].max() <= 0.02, float(rem[hole].max())
    assert job.parameters["faces"]["area_mm2"]["steep"] == 0.0


def test_freeform_keeps_the_ball_only_where_the_surface_curves():
    # A block with a spherical dimple: the ball finishes the dimple, flat mills the rest.
    body = manifold3d.Manifold.cube((50.0, 40.0, 15.0)) - manifold3d.Manifold.sphere(10.0, 96).translate(
        (25.0, 20.0, 19.0))
    job, setup, sim, report = _plan_and_verify(body, cell=0.2)
    assert classify_faces(manifold_to_trimesh(body)).freeform
    ball = [op for op in job.operations if op.tool.shape == "ball"]
    assert ball, [op.name for op in job.operations]
    centre = np.array([25.0, 20.0]) + 2.0
    for op in ball:
        cut = op.points[op.motion[:] != 0]
        # every ball cut within the dimple's rim (r = 8 at the top face) and the ball's radius
        assert np.hypot(*(cut[:, :2] - centre).T).max() <= 8.0 + 3.0 + 0.6
    assert report.ok, [f.message for f in report.faults]
    rem = sim.remaining
    g = sim.grid
    X, Y = np.meshgrid(g.x0 + g.cell * np.arange(g.nx), g.y0 + g.cell * np.arange(g.ny))
    r = np.hypot(X - centre[0], Y - centre[1])
    covered = np.isfinite(rem)
    assert np.percentile(rem[covered & (r > 8.5)], 95) <= 0.02  # the top face, by the flat end mill
    # the dimple: the 0.05 mm scallop asked is for flat ground; on its slopes the raster leaves more
    assert np.percentile(rem[covered & (r < 7.5)], 95) <= 2 * 0.05


def test_by_faces_off_keeps_the_ball_over_everything():
    body = manifold3d.Manifold.cube((30.0, 20.0, 8.0)) - manifold3d.Manifold.cube((12.0, 8.0, 4.0)).translate(
        (9.0, 6.0, 5.0))
    setup, part = make_setup(manifold_to_trimesh(body))
    job = plan_job(part, setup, LIBRARY, part_name="p", options=PlanOptions(
        finishing=FinishingOptions(scallop=0.05), by_faces=False)).job
    assert "raster" in [op.kind for op in job.operations]
    assert job.parameters["faces"] is None


@pytest.mark.parametrize("tool", [3, 5])
def test_flat_finishing_refuses_a_tool_that_is_not_flat(tool):
    from cadcam.flatfinish import flat_wall_finishing
    from factory.core.errors import ToolError

    setup, part = make_setup(manifold_to_trimesh(manifold3d.Manifold.cube((20.0, 20.0, 5.0))))
    t = LIBRARY.tool(tool)
    with pytest.raises(ToolError, match="flat"):
        flat_wall_finishing(part, setup, t, LIBRARY.cutting_data(t, "aluminium"), classify_faces(part), None)


def _pocket_body() -> manifold3d.Manifold:
    # A closed 36 x 24 pocket 4 mm deep: floor and four walls, for the 10 mm flat end mill.
    return manifold3d.Manifold.cube((60.0, 40.0, 10.0)) - manifold3d.Manifold.cube((36.0, 24.0, 5.0)).translate(
        (12.0, 8.0, 6.0))


def _flat_tool(job) -> int:
    """The number of the flat end mill that finishes the flats and walls first (the roughing one if flat)."""
    return next(op.tool.number for op in job.operations if op.kind == "finishing" and op.tool.shape == "flat")


def _flat_ops(job, tool: int):
    return [op for op in job.operations if op.kind == "finishing" and op.tool.number == tool]


def _cut_length(op) -> float:
    d = np.linalg.norm(np.diff(op.points, axis=0), axis=1)
    return float(d[op.motion[1:] == 1].sum())


def test_floors_at_a_wide_stepover_are_still_finished():
    from cadcam.flatfinish import FLOOR_STEPOVER, FlatFinishOptions

    assert 0.6 <= FLOOR_STEPOVER <= 0.85  # overlapping the last loop by at least 0.15 D
    narrow = dataclasses.replace(FAST, flat_finish=FlatFinishOptions(stepover=5.0))
    wide_job, setup, sim, report = _plan_and_verify(_pocket_body(), cell=0.2)
    narrow_job, _, _, _ = _plan_and_verify(_pocket_body(), narrow, cell=0.2)
    assert report.ok, [f.message for f in report.faults]
    rem = sim.remaining
    assert np.percentile(rem[np.isfinite(rem)], 95) <= 0.02
    # fewer loops over the floor than at half the diameter
    flat = _flat_tool(wide_job)
    assert flat == _flat_tool(narrow_job)
    assert sum(map(_cut_length, _flat_ops(wide_job, flat))) < sum(map(_cut_length, _flat_ops(narrow_job, flat)))


def test_a_spring_pass_runs_the_walls_again_and_is_off_by_default():
    from cadcam.flatfinish import FlatFinishOptions

    assert not FlatFinishOptions().spring_pass
    spring = dataclasses.replace(FAST, flat_finish=FlatFinishOptions(spring_pass=True))
    plain_job, _, _, _ = _plan_and_verify(_pocket_body(), cell=0.2)
    job, setup, sim, report = _plan_and_verify(_pocket_body(), spring, cell=0.2)
    assert report.ok, [f.message for f in report.faults]
    flat = _flat_tool(plain_job)
    (plain,), (sprung,) = _flat_ops(plain_job, flat), _flat_ops(job, flat)
    extra = _cut_length(sprung) - _cut_length(plain)
    # at least the pocket's wall loop (36 x 24 less the tool, corners rounded) once more
    d = plain.tool.diameter
    assert extra >= 2 * (36 - d + 24 - d) - 1.0, extra
    # every extra cut point lies on a loop already cut: the spring pass cuts no new ground
    cut = plain.points[1:][plain.motion[1:] == 1]
    extra_pts = sprung.points[1:][sprung.motion[1:] == 1]
    from scipy.spatial import cKDTree

    d, _ = cKDTree(cut).query(extra_pts)
    assert np.percentile(d, 99) <= 0.5
    rem = sim.remaining
    assert np.percentile(rem[np.isfinite(rem)], 95) <= 0.02


def test_a_wall_taller_than_the_flutes_is_finished_in_steps_even_where_the_model_grid_misses_its_skin():
    # A slot 4 mm wide and 8.75 mm deep (random_4 of benchmarks/cycle_time.py): only the 2 mm T6 enters
    # it; rest roughing leaves 0.3 mm on its walls, 2.75 mm more than T6's 6 mm flutes reach. The
    # slot's front wall (work Y 13.39: part Y 11.39 + make_setup's 2 mm margin) lies 0.36 mm from
    # the 0.5 mm stock model's grid points (Y 13.25, 13.75) on the slot side: a model that coarse
    # sees no skin there, and the flank pass took the whole wall at the floor, shank in the skin.
    body = manifold3d.Manifold.cube((40.0, 30.0, 12.0))
    body -= manifold3d.Manifold.cube((10.0, 4.0, 9.75)).translate((10.233, 11.39, 12.0 - 8.75))
    job, setup, sim, report = _plan_and_verify(body, cell=0.2)
    kinds = [(op.kind, op.tool.number) for op in job.operations]
    assert ("roughing", 6) in kinds and ("finishing", 6) in kinds, kinds
    assert report.ok, [f.message for f in report.faults]
    # the slot's walls are finished from top to floor: only its four sharp corners keep stock
    g = sim.grid
    X, Y = np.meshgrid(g.x0 + g.cell * np.arange(g.nx), g.y0 + g.cell * np.arange(g.ny))
    slot = (X > 12.233 + 1.0) & (X < 22.233 - 1.0) & (Y > 13.39) & (Y < 17.39)
    assert sim.remaining[slot].max() <= 0.02, float(sim.remaining[slot].max())


def test_a_sharp_inside_corner_no_tool_reaches_is_left_alone_not_taken_whole_by_the_flank():
    # face_recognition_sample_part's fault (issue 29), small: a sharp inside corner between a 20 mm wall and
    # an 8 mm ledge, with no end mill narrower than the 10 mm one. Rest roughing leaves the corner's curved
    # triangle more than the finishing engagement over the part; the planner reports it unreached ("finishing
    # leaves it alone"), yet the flats-and-walls pass at the floor took its whole height at once (verify: T2
    # buried 8.51 mm, limit 1 mm).
    only_10 = dataclasses.replace(LIBRARY, tools=(LIBRARY.tool(2), LIBRARY.tool(3)), feed_factors=())
    body = manifold3d.Manifold.cube((30.0, 8.0, 20.0)) + manifold3d.Manifold.cube((12.0, 18.0, 8.0)).translate(
        (18.0, 8.0, 0.0))
    job, setup, sim, report = _plan_and_verify(body, cell=0.2, library=only_10)
    assert ("finishing", 2) in [(op.kind, op.tool.number) for op in job.operations]
    assert report.ok, [f.message for f in report.faults]
    corner = np.array([18.0, 8.0]) + 2.0  # make_setup's 2 mm margin
    (unreached,) = job.parameters["unreached"]
    assert np.hypot(unreached["x"] - corner[0], unreached["y"] - corner[1]) < 3.0
    # left, and said to be the corner a round tool cannot enter: verify's region holds the planner's
    (left,) = report.left
    assert left.why == SHARP_CORNER
    assert abs(left.x - unreached["x"]) <= (left.size_x - unreached["size_x"]) / 2 + 0.2
    assert abs(left.y - unreached["y"]) <= (left.size_y - unreached["size_y"]) / 2 + 0.2
    # the walls and the ledge are finished up to a tool radius of the corner
    g = sim.grid
    X, Y = np.meshgrid(g.x0 + g.cell * np.arange(g.nx), g.y0 + g.cell * np.arange(g.ny))
    rem = sim.remaining
    away = np.isfinite(rem) & (np.hypot(X - corner[0], Y - corner[1]) > 5.0)
    assert rem[away].max() <= 0.02, float(rem[away].max())


def test_an_end_mill_shorter_than_the_stock_finishes_a_narrow_slot_but_not_where_the_ball_finishes():
    # 18 mm tall: the 2 mm T6 reaches 16 mm below its holder, less than the stock is deep. It alone enters
    # the 4 mm slot, within its stick-out; the skin round the dimple's rim, which the wider flat end mills
    # leave and the ball finishes after them, is not its work (a tool change and minutes for nothing).
    body = manifold3d.Manifold.cube((50.0, 40.0, 18.0))
    body -= manifold3d.Manifold.sphere(10.0, 96).translate((14.0, 20.0, 22.0))
    body -= manifold3d.Manifold.cube((16.0, 4.0, 5.0)).translate((30.0, 18.0, 14.0))
    job, setup, sim, report = _plan_and_verify(body, cell=0.2)
    t6 = LIBRARY.tool(6)
    assert float(setup.stock_max[2] - setup.floor_z) > t6.length
    finishing = [op for op in job.operations if op.kind == "finishing" and op.tool.number == 6]
    assert len(finishing) == 1, [op.name for op in job.operations]
    op = finishing[0]
    cut = op.points[1:][op.motion[1:] != 0]
    # every T6 cut inside the slot (work X 32..48, Y 20..24: make_setup's 2 mm margin), none round the dimple
    assert cut[:, 0].min() >= 32.0 + t6.radius - 0.05 and cut[:, 0].max() <= 48.0 - t6.radius + 0.05, cut[:, 0]
    assert cut[:, 1].min() >= 20.0 + t6.radius - 0.05 and cut[:, 1].max() <= 24.0 - t6.radius + 0.05, cut[:, 1]
    assert report.ok, [f.message for f in report.faults]
    # the slot's floor and walls are finished: only its four sharp corners keep stock
    g = sim.grid
    X, Y = np.meshgrid(g.x0 + g.cell * np.arange(g.nx), g.y0 + g.cell * np.arange(g.ny))
    slot = (X > 32.0 + 1.0) & (X < 48.0 - 1.0) & (Y > 20.0) & (Y < 24.0)
    assert sim.remaining[slot].max() <= 0.02, float(sim.remaining[slot].max())


def test_below_its_reach_a_finishing_tool_s_holder_keeps_off_the_walls_not_only_off_the_skin_it_finishes():
    """Finishing flats and walls cuts a stand-in stock that holds only the skin to finish (the walls are taken
    away); below the tool's reach its holder must still keep off the walls themselves. Issue 34's web_in_tube:
    the 2 mm end mill finished the floor of a 56 mm deep tube along its walls, its 16 mm holder 40 mm into them."""
    from cadcam.model import CuttingData, Operation
    from cadcam.rest import HOLDER_CLEARANCE_MM
    from cadcam.roughing import RoughingOptions, zlevel_roughing
    from cadcam.stock import stock_after

    body = manifold3d.Manifold.cube((54.0, 50.0, 30.0)) - manifold3d.Manifold.cube((40.0, 36.0, 30.0)).translate(
        (7.0, 7.0, 4.0))  # a pocket 26 mm deep, its floor 4 mm over the part's bottom
    setup, part = make_setup(manifold_to_trimesh(body))
    t6 = LIBRARY.tool(6)
    cut = CuttingData(20000.0, 600.0, 200.0)
    above = Operation("above", "roughing", t6, cut, np.array([[0.0, 0.0, 10.0]]), np.zeros(1))  # cuts nothing
    stock = stock_after([above], setup, np.asarray(part.triangles), 0.25)
    g = stock.grid
    X, Y = np.meshgrid(g.x0 + g.cell * np.arange(g.nx), g.y0 + g.cell * np.arange(g.ny))
    lo, hi = part.bounds[0][:2] + 7.0, part.bounds[0][:2] + [47.0, 43.0]  # the pocket's walls
    inside = (X > lo[0]) & (X < hi[0]) & (Y > lo[1]) & (Y < hi[1])
    floor = float(part.bounds[0][2]) + 4.0
    # the pocket roughed to 0.3 mm over its floor and walls: the skin along the floor's edge and a patch in its
    # middle are what is left
    middle = np.hypot(X - (lo[0] + hi[0]) / 2, Y - (lo[1] + hi[1]) / 2) < 3.0
    near = inside & ((X < lo[0] + 3) | (X > hi[0] - 3) | (Y < lo[1] + 3) | (Y > hi[1] - 3) | middle)
    air_top = np.where(inside, floor + 0.3, stock.stock_top)
    air = dataclasses.replace(stock, stock_top=air_top)
    target = dataclasses.replace(stock, stock_top=np.where(near, floor + 0.3, -np.inf),
                                 part_top=np.full_like(stock.part_top, -np.inf))
    assert float(setup.stock_max[2]) - floor > t6.length  # the floor lies below the 2 mm end mill's reach
    op = zlevel_roughing(part, setup, t6, cut, RoughingOptions(stepdown=1.0, allowance=0.0),
                         rest=target, rest_above=0.0, air=air)
    deep = op.points[op.points[:, 2] < float(setup.stock_max[2]) - t6.length]
    assert len(deep), "the patch in the floor's middle, away from the walls, is finished"
    holder = min(r for h, r in t6.body() if h >= t6.length)  # its narrowest, lowest part
    off_walls = np.minimum.reduce([deep[:, 0] - lo[0], hi[0] - deep[:, 0], deep[:, 1] - lo[1], hi[1] - deep[:, 1]])
    assert off_walls.min() >= holder + HOLDER_CLEARANCE_MM - g.cell * np.sqrt(2.0) - 1e-6, off_walls.min()
