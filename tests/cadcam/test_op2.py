"""cadcam.op2: the part turned over about the jaw axis, the holding allowance faced off, verify from op 1's stock."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import manifold3d
import numpy as np
import pytest
from scipy import ndimage
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cadcam.finishing import FinishingOptions
from cadcam.gcode import parse_gcode
from cadcam.heightmap import grid_over
from cadcam.model import CuttingData, Motion, ProgramMoves, Setup, SoftJaws, ViseJaws
from cadcam.op2 import (FacingOptions, Op2Options, facing, facing_gap, facing_levels, flip_transform, op2_setup,
                        op2_setup_image, plan_op2)
from cadcam.plan import PlanOptions, plan_job
from cadcam.post import PostOptions, post_process
from cadcam.setup import make_setup
from cadcam.tools import load_tool_library
from cadcam.stock import Simulation, flip_stock, operation_moves
from cadcam.verify import VerifyOptions, finishing_moves, simulate, simulate_flipped
from factory.core.errors import SetupError, ToolError, VerifyError
from tests.cadcam.test_plan import blocks, needs_rs274, rs274_accepts
from tests.conftest import manifold_to_trimesh, pocket_block

LIBRARY = load_tool_library()
FLAT10 = LIBRARY.tool(2)
CUT = CuttingData(9000.0, 2000.0, 600.0)
PLAN = PlanOptions(finishing=FinishingOptions(scallop=0.05), waterline=False)
#: A vise like the sample cell's [mm]: 5 mm grip, 20 mm jaws.
JAWS = ViseJaws(jaw_height=45.0, jaw_width=150.0, jaw_thickness=20.0, parallels_height=40.0, opening_min=0.0,
                opening_max=160.0)


def _setup(size=(40.0, 30.0, 20.0), origin="top-front-left") -> Setup:
    lo = np.array([0.0, 0.0, -size[2]]) if origin == "top-front-left" else np.array([-size[0] / 2, -size[1] / 2,
                                                                                       -size[2]])
    return Setup(stock_min=lo, stock_max=lo + np.asarray(size), transform_mesh_to_work=np.eye(4), origin=origin,
                 safe_z=5.0)


# --------------------------------------------------------------------------- the flip


@given(sx=st.floats(5, 200), sy=st.floats(5, 200), sz=st.floats(3, 80), centre=st.booleans())
def test_the_flip_is_a_half_turn_about_the_jaw_axis_onto_the_same_box(sx, sy, sz, centre):
    s = _setup((sx, sy, sz), "top-centre" if centre else "top-front-left")
    t = flip_transform(s)
    np.testing.assert_allclose(t[:3, :3], np.diag([1.0, -1.0, -1.0]))  # about X, the jaws' axis
    assert np.linalg.det(t[:3, :3]) == pytest.approx(1.0)  # a rotation, not a mirror
    s2 = op2_setup(s)
    corners = np.array([[x, y, z, 1.0] for x in (s.stock_min[0], s.stock_max[0])
                        for y in (s.stock_min[1], s.stock_max[1]) for z in (s.stock_min[2], s.stock_max[2])])
    moved = (t @ corners.T).T[:, :3]
    np.testing.assert_allclose(moved.min(axis=0), s2.stock_min, atol=1e-9)
    np.testing.assert_allclose(moved.max(axis=0), s2.stock_max, atol=1e-9)
    assert s2.stock_max[2] == 0.0 and s2.safe_z == pytest.approx(s.safe_z - s.stock_max[2])
    # The old stock bottom is the new top: the point under the old origin is on the new top.
    assert (t @ [s.stock_min[0], s.stock_min[1], s.stock_min[2], 1.0])[2] == pytest.approx(0.0)


@settings(max_examples=30, deadline=None)
@given(sx=st.floats(4, 30), sy=st.floats(4, 30), depth=st.floats(1, 10), seed=st.integers(0, 2**31 - 1),
       cell=st.sampled_from([0.25, 0.5, 1.0]))
def test_flipped_stock_keeps_every_column(sx, sy, depth, seed, cell):
    s = _setup((sx, sy, depth))
    grid = grid_over(s.stock_min, s.stock_max, cell)
    rng = np.random.default_rng(seed)
    top = rng.uniform(-depth - 1.0, 0.0, grid.shape)  # some columns cut through
    sim = Simulation(grid, top, np.full(grid.shape, -np.inf), float(s.stock_min[2]))
    s2 = op2_setup(s)
    flipped = flip_stock(sim, flip_transform(s), s2)
    assert flipped.grid == grid_over(s2.stock_min, s2.stock_max, cell)
    old = top[::-1]  # row j of the new grid is row ny-1-j of the old: Y is mirrored, X is not
    present = old > -depth
    np.testing.assert_array_equal(np.isfinite(flipped.top), present)
    np.testing.assert_allclose(flipped.top[present], 0.0, atol=1e-9)  # the old flat bottom is the new top
    np.testing.assert_allclose((flipped.top - flipped.bottom)[present], (old + depth)[present], atol=1e-9)


def test_flip_stock_refuses_another_turn_or_grid():
    s = _setup()
    grid = grid_over(s.stock_min, s.stock_max, 0.5)
    sim = Simulation(grid, np.zeros(grid.shape), np.zeros(grid.shape), -20.0)
    t = flip_transform(s)
    with pytest.raises(VerifyError, match="half turn"):
        flip_stock(sim, np.eye(4), op2_setup(s))
    moved = dataclasses.replace(op2_setup(s), stock_max=op2_setup(s).stock_max + [3.0, 0, 0])
    with pytest.raises(VerifyError, match="grid"):
        flip_stock(sim, t, moved)


# --------------------------------------------------------------------------- facing


@given(top=st.floats(-5, 5), depth=st.floats(0.01, 40), stepdown=st.floats(0.5, 6), skim=st.floats(0, 0.4))
def test_facing_levels_end_on_the_face_and_never_step_deeper_than_the_stepdown(top, depth, stepdown, skim):
    face = top - depth
    levels = facing_levels(top, face, stepdown, skim)
    assert levels[-1] == face
    steps = -np.diff(np.concatenate([[top], levels]))
    assert (steps > 0).all() and (steps <= stepdown + 1e-9).all()


def test_facing_clears_the_whole_top_down_to_the_face_and_enters_beside_the_stock():
    s = _setup((41.0, 27.0, 15.0))
    face = -6.3
    op = facing(s, face, FLAT10, CUT)
    assert op.kind == "facing" and op.tool is FLAT10
    cuts = op.motion != Motion.RAPID
    assert op.points[cuts, 2].min() == face
    # Every descent (plunge-feed ramp) ends beside the stock: the tool meets material only sideways.
    ramps = np.flatnonzero(op.motion == Motion.PLUNGE)
    assert len(ramps) == len(facing_levels(0.0, face, 5.0, FacingOptions().finish_depth))
    for k in ramps:
        a, b = op.points[k - 1], op.points[k]
        assert b[2] < a[2]
        for p in (a, b):
            assert p[0] <= s.stock_min[0] - FLAT10.radius or p[0] >= s.stock_max[0] + FLAT10.radius
        slope = math.degrees(math.atan2(a[2] - b[2], abs(b[0] - a[0])))
        assert slope == pytest.approx(FacingOptions().ramp_angle)
    # Passes 70 % of the diameter apart at most.
    ys = np.unique(np.round(op.points[cuts, 1], 6))
    assert np.diff(ys).max() <= 0.7 * FLAT10.diameter + 1e-9
    # Simulated: the whole footprint is at the face, nothing deeper.
    tri = np.array([[[5, 5, -14], [30, 5, -14], [5, 20, -14]]], dtype=float)  # a sliver of part far below
    verified = simulate(operation_moves([op]), {2: FLAT10}, s, tri, VerifyOptions(cell=0.5))
    sim, report = verified.simulation, verified.report
    np.testing.assert_allclose(sim.stock_top, face, atol=1e-9)
    assert report.ok, report.to_dict()


def test_an_allowance_within_one_stepdown_is_faced_in_one_level_whose_bottom_is_the_face():
    """Issue 32: the samples' 6.5 mm holding allowance with the 16 mm end mill (stepdown 8 mm) is one
    level; the 0.2 mm skim after a 6.3 mm level swept the whole footprint a second time."""
    s = _setup((94.0, 74.0, 24.5))
    wide = LIBRARY.tool(14)
    face = -6.5
    op = facing(s, face, wide, CUT)
    level = (op.motion == Motion.CUT) & (np.abs(np.diff(op.points[:, 2], prepend=np.nan)) < 1e-12)
    np.testing.assert_array_equal(np.unique(op.points[level, 2]), [face])
    ramps = np.flatnonzero(op.motion == Motion.PLUNGE)
    assert len(ramps) == 1
    # Fed down only over the last radius of run, where a block seated off by facing_reach meets the side.
    a, b = op.points[ramps[0] - 1], op.points[ramps[0]]
    assert abs(b[0] - a[0]) == pytest.approx(wide.radius)
    assert op.motion[ramps[0] - 1] == Motion.RAPID
    assert abs(a[0] - s.stock_min[0]) >= facing_gap(s) + 2 * wide.radius - 1e-9
    tri = np.array([[[5, 5, -20], [30, 5, -20], [5, 20, -20]]], dtype=float)
    verified = simulate(operation_moves([op]), {14: wide}, s, tri, VerifyOptions(cell=0.5))
    np.testing.assert_allclose(verified.simulation.stock_top, face, atol=1e-9)
    assert verified.report.ok, verified.report.to_dict()


def test_facing_needs_a_flat_end_mill_that_reaches():
    s = _setup()
    with pytest.raises(ToolError, match="flat"):
        facing(s, -5.0, LIBRARY.tool(3), CUT)
    with pytest.raises(ToolError, match="reaches"):
        facing(s, -40.0, LIBRARY.tool(6), CUT)


# --------------------------------------------------------------------------- the flipped simulation


def _moves(points, motion, tool=2) -> ProgramMoves:
    points = np.asarray(points, dtype=float)
    return ProgramMoves(points, np.asarray(motion, np.int8), np.full(len(points), tool),
                        np.where(np.asarray(motion) == Motion.RAPID, np.nan, 1000.0),
                        np.arange(len(points), dtype=np.int32))


def test_a_column_cut_through_in_op_1_is_air_in_op_2():
    """Op 1 drills through the stock at one spot; in op 2 a rapid down that hole is no crash,
    the same rapid beside it is."""
    s = _setup((40.0, 30.0, 10.0))
    tri = np.array([[[1, 1, -8], [39, 1, -8], [1, 29, -8]], [[39, 1, -8], [39, 29, -8], [1, 29, -8]]], float)
    drill = _moves([[10, 10, 5], [10, 10, 1], [10, 10, -11], [10, 10, 5]],
                   [Motion.RAPID, Motion.RAPID, Motion.CUT, Motion.RAPID])
    sim1 = simulate(drill, {2: FLAT10}, s, tri, VerifyOptions(cell=0.5)).simulation
    s2 = op2_setup(s)
    start = flip_stock(sim1, flip_transform(s), s2)
    t = flip_transform(s)
    hole = (t @ [10, 10, 0, 1.0])[:2]  # the hole's XY in op 2
    tri2 = (np.c_[tri.reshape(-1, 3), np.ones(6)] @ t.T)[:, :3].reshape(-1, 3, 3)
    small = LIBRARY.tool(6)  # 2 mm: fits in the 10 mm hole
    down_hole = _moves([[*hole, 5], [*hole, -12]], [Motion.RAPID, Motion.RAPID], tool=6)
    report = simulate_flipped(down_hole, {6: small}, s2, tri2, start, VerifyOptions(cell=0.5)).report
    assert report.rapid_crashes == ()
    beside = _moves([[hole[0] + 12, hole[1], 5], [hole[0] + 12, hole[1], -1]], [Motion.RAPID, Motion.RAPID], tool=6)
    report = simulate_flipped(beside, {6: small}, s2, tri2, start, VerifyOptions(cell=0.5)).report
    assert len(report.rapid_crashes) == 1 and report.rapid_crashes[0].depth == pytest.approx(1.0)


# --------------------------------------------------------------------------- op 1 then op 2, end to end


def op1(mesh, name: str, options: PlanOptions = PLAN):
    """Op 1 with the part lifted on its holding allowance; roughing stops at the setup's floor
    (the part's bottom less the breakthrough), as a vise-held op 1 must."""
    setup, part = make_setup(mesh, jaws=JAWS)
    floored = dataclasses.replace(setup, stock_min=np.array([*setup.stock_min[:2], setup.floor_z]))
    job = plan_job(part, floored, LIBRARY, part_name=name, options=options).job
    return dataclasses.replace(job, setup=setup), part


def op1_then_op2(mesh, name: str, tmp_path: Path, cell: float = 0.25, options: PlanOptions = PLAN):
    job1, part = op1(mesh, name, options)
    job2, part2 = plan_op2(part, job1, LIBRARY, options=Op2Options(plan=options), jaws=JAWS)
    return verify_both(job1, job2, part, part2, name, tmp_path, cell)


def verify_both(job1, job2, part, part2, name: str, tmp_path: Path, cell: float):
    """Both jobs posted and verified, op 2 from op 1's verified stock turned over (``part``: op 1's, ``part2``:
    op 2's): the jobs, the programs, (stock, report) of each and op 2's moves; op 2's program in ``tmp_path``."""
    p1 = post_process(job1)
    p2 = post_process(job2, PostOptions(work_offset=2))
    opts = VerifyOptions(cell=cell)
    m1 = parse_gcode(p1.text)
    verified = simulate(m1, {t.number: t for t in job1.tools}, job1.setup, np.asarray(part.triangles), opts,
                        finishing=finishing_moves(p1.text, m1))
    sim1, r1 = verified.simulation, verified.report
    m2 = parse_gcode(p2.text)
    start = flip_stock(sim1, flip_transform(job1.setup), job2.setup)
    verified = simulate_flipped(m2, {t.number: t for t in job2.tools}, job2.setup, np.asarray(part2.triangles), start,
                                opts, finishing=finishing_moves(p2.text, m2))
    sim2, r2 = verified.simulation, verified.report
    (tmp_path / f"{name}.op2.nc").write_text(p2.text)
    return job1, job2, part2, (p1, p2), (sim1, r1), (sim2, r2), m2


@pytest.fixture(scope="module")
def block_ops(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("block")
    return tmp, op1_then_op2(pocket_block(size=(30.0, 20.0, 16.0)), "block", tmp)


def test_op_2_faces_the_allowance_down_to_the_parts_bottom_face(block_ops):
    _, (job1, job2, part2, _, _, (sim2, r2), m2) = block_ops
    face = job2.parameters["face_z"]
    assert face == pytest.approx(float(part2.bounds[1][2]))
    assert job2.parameters["holding_mm"] >= JAWS.grip_depth + 0.5 + 1.0 - 1e-9
    assert [op.kind for op in job2.operations] == ["facing"]
    # The tool reaches the face and nothing goes deeper over the part.
    feed = np.flatnonzero(m2.motion == Motion.CUT)
    assert m2.points[feed, 2].min() == pytest.approx(face, abs=1e-4)
    # Every grid point over the part's bottom face is at the face within the gouge tolerance.
    on = np.isfinite(sim2.part_top)
    assert np.abs(sim2.stock_top[on] - sim2.part_top[on]).max() <= r2.gouge_tolerance
    assert r2.ok, r2.to_dict()
    assert r2.max_gouge <= 0.01 and r2.remaining_p95 <= 0.02


def test_op_2_jaws_grip_the_finished_faces_below_the_face(block_ops):
    _, (_, job2, part2, _, _, _, _) = block_ops
    names = [b.name for b in job2.setup.jaws]
    assert names == ["front jaw", "back jaw", "parallels"]
    lo, hi = part2.bounds
    front, back, parallels = job2.setup.jaws
    assert front.hi[1] == pytest.approx(lo[1]) and back.lo[1] == pytest.approx(hi[1])  # on the part's Y faces
    assert front.hi[2] == pytest.approx(lo[2] + JAWS.grip_depth)
    assert front.hi[2] <= job2.parameters["face_z"] - 1.0
    assert parallels.hi[2] == pytest.approx(lo[2]) and job2.setup.floor_z == pytest.approx(lo[2])


def test_soft_jaws_hold_op_2_as_deep_as_the_cell_file_says(block_ops):
    _, (job1, _, _, _, _, _, _) = block_ops
    _, part1 = make_setup(pocket_block(size=(30.0, 20.0, 16.0)), jaws=JAWS)  # the part as op 1 held it
    soft = dataclasses.replace(JAWS, soft_jaws=SoftJaws("pocket", 3.0))
    job2, part2 = plan_op2(part1, job1, LIBRARY, options=Op2Options(plan=PLAN), jaws=soft)
    front = job2.setup.jaws[0]
    assert front.hi[2] == pytest.approx(part2.bounds[0][2] + 3.0)
    assert job2.parameters["held_in"] == "soft jaws (pocket)"


def test_a_part_too_thin_to_grip_in_op_2_is_refused():
    thin = pocket_block(size=(30.0, 20.0, 0.8), pocket=(4.0, 4.0, 0.3))
    job1, part = op1(thin, "thin")
    with pytest.raises(SetupError, match="cannot grip"):
        plan_op2(part, job1, LIBRARY, options=Op2Options(plan=PLAN), jaws=JAWS)


@needs_rs274
def test_rs274_accepts_op_2_in_g55(block_ops):
    tmp, (job1, job2, _, (p1, p2), _, _, _) = block_ops
    assert "\nG55\n" in p2.text and "\nG54\n" in p1.text
    assert "(op 2: part turned over about X" in p2.text  # the operator's setup note in the header
    rs274_accepts(tmp / "block.op2.nc", job2, tmp)


def test_setup_picture(block_ops):
    _, (_, job2, part2, _, _, _, _) = block_ops
    img = op2_setup_image(job2, part2)
    assert img.ndim == 3 and img.shape[2] == 3 and img.shape[1] == 720
    jaw_blue = np.all(img == [40, 60, 120], axis=-1)
    allowance = np.all(img == [253, 214, 170], axis=-1)
    assert jaw_blue.sum() > 100 and allowance.sum() > 100


def test_a_pocket_in_the_bottom_is_cut_in_op_2(tmp_path):
    """A pocket opening downwards: op 1 cannot reach it through the part; op 2 rest roughs and
    finishes it, and nothing else."""
    mesh = pocket_block(size=(30.0, 20.0, 12.0), pocket=(16.0, 12.0, 3.0))
    mesh.apply_transform(np.diag([1.0, -1.0, -1.0, 1.0]))
    job1, job2, part2, _, (sim1, r1), (sim2, r2), _ = op1_then_op2(mesh, "under", tmp_path, cell=0.5)
    kinds = [op.kind for op in job2.operations]
    assert kinds[0] == "facing" and "roughing" in kinds and kinds[-1] == "raster"
    assert r1.max_gouge <= 0.01 and r2.ok, r2.to_dict()
    # The pocket floor, seen from below, is cut down to its allowance-free finish away from
    # the walls (a 6 mm ball leaves its radius in the floor's corners, as it does in op 1).
    floor = np.isclose(sim2.part_top, float(part2.bounds[1][2]) - 3.0, atol=1e-6)
    ball = next(op.tool for op in job2.operations if op.kind == "raster")
    inner = ndimage.binary_erosion(floor, iterations=int(math.ceil((ball.radius + 0.5) / 0.5)))
    assert inner.sum() > 20
    assert np.percentile(sim2.remaining[inner], 95) <= PLAN.finishing.scallop  # the raster's cusps
    # Op 2 starts with the pocket full (a z-map from above holds it under the part's top):
    # turned over, every column there reaches from the stock top down to the part's old top.
    start = flip_stock(sim1, flip_transform(job1.setup), job2.setup)
    assert np.all(start.top[inner] == 0.0)


@settings(max_examples=3, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(body=blocks())
def test_random_parts_give_two_programs_that_finish_the_bottom(body, tmp_path):
    mesh = manifold_to_trimesh(body)
    job1, job2, part2, (p1, p2), (sim1, r1), (sim2, r2), _ = op1_then_op2(mesh, "random", tmp_path, cell=0.5)
    assert p1.total_time > 0 and p2.total_time > 0
    assert r1.max_gouge <= 0.01 and r2.max_gouge <= 0.01, (r1.to_dict(), r2.to_dict())
    assert r1.rapid_crashes == () and r2.ok, r2.to_dict()
    assert r2.remaining_p95 <= 0.02  # the bottom: random blocks have flat bottoms
    # Op 2 starts from op 1's stock: its material never exceeds the holding allowance plus the part.
    assert np.isfinite(sim2.stock_top).any()


def test_op_2_jaws_grip_below_a_face_it_cuts_beside_them(tmp_path):
    """Issue 34, OpenCAMLib's sphere_on_plate: a boss stands 3 mm under a plate, so turned over the face op 2
    faces to is the boss's, and the plate's underside, out to the jaws, lies 3 mm lower. Gripped to 1 mm under
    the face, the jaws kept every tool off a strip along each of them (76 x 3 mm, 3.2 deep, left): they grip
    under the plate's underside instead, and op 2 cleans it to the edges."""
    plate = manifold3d.Manifold.cube((40.0, 30.0, 10.0)).translate((0.0, 0.0, 3.0))
    boss = manifold3d.Manifold.cylinder(3.5, 6.0, 6.0, circular_segments=48).translate((20.0, 15.0, 0.0))
    job1, job2, part2, _, _, (sim2, r2), _ = op1_then_op2(manifold_to_trimesh(plate + boss), "boss_under", tmp_path,
                                                          cell=0.5)
    underside = float(part2.bounds[1][2]) - 3.0  # the plate's old bottom, turned over
    front, back = job2.setup.jaws[:2]
    assert max(front.hi[2], back.hi[2]) <= underside - 1.0 + 1e-9
    assert front.hi[2] - float(part2.bounds[0][2]) >= 3.0 - 1e-9  # still held
    assert not job2.parameters["unreached"], job2.parameters["unreached"]
    assert r2.ok, r2.to_dict()
    lo, hi = part2.bounds
    # (the 6 mm ball leaves its radius in the corner round the boss, as in any pocket's floor: not along the jaws)
    assert all(lo[1] + 4.0 < u.y - u.size_y / 2 and u.y + u.size_y / 2 < hi[1] - 4.0 for u in r2.left), r2.left
    ys = sim2.grid.ys
    along = np.isfinite(sim2.part_top) & ((ys < lo[1] + 4.0) | (ys > hi[1] - 4.0))[:, None]
    assert (sim2.stock_top - sim2.part_top)[along].max() <= 0.35  # along the jaws: the allowance at most
