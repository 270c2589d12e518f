"""The whole CAM chain: part → job → G-code → parsed back → simulated. No gouge, no crash, rs274 accepts it."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import manifold3d
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cadcam.drilling import POINT_CLEARANCE_MM
from cadcam.finishing import FinishingOptions
from cadcam.gcode import parse_gcode
from cadcam.mesh import load_part
from cadcam.model import Motion
from cadcam.plan import PlanOptions, plan_job
from cadcam.post import PostOptions, post_process
from cadcam.setup import make_setup
from cadcam.tools import load_tool_library
from cadcam.setup import BREAKTHROUGH_MM, MIN_HOLDING_LEFT_MM
from cadcam.verify import VerifyOptions, simulate
from factory.core.resources import FIXTURES
from factory.cam import vise_jaws
from robotprog.cell import load_cell
from tests.cadcam.sweep import past_axial_limit, sweep_moves
from tests.cadcam.test_rest import assert_safe
from tests.conftest import SAMPLES, manifold_to_trimesh
from tests.shared import content, key_of, once
from tests.rs274 import run_rs274, write_tool_table

LIBRARY = load_tool_library()
# A coarser scallop than the default keeps the suite quick; gouge-freedom does not depend on it.
TEST_PLAN = PlanOptions(finishing=FinishingOptions(scallop=0.02))
# The closed solids; samples/relief.stl is an open surface, planned as a relief (tests/cadcam/test_relief.py).
SAMPLE_PARTS = sorted(p for p in SAMPLES.glob("*.stl") if p.stem != "relief")
#: The default cell's vise [mm]: every plan here is held in it, as `factory plan` holds it.
JAWS = vise_jaws(load_cell(FIXTURES / "cell.yaml", check_robot=False).vise)


def sample_op1(name: str):
    """(setup, part in the work frame, job): the sample ``name``'s op 1 as :func:`cadcam.setup.make_setup`
    holds it by default, planned with :data:`TEST_PLAN`. Several modules want the bracket's: it is planned
    once in the run (:mod:`tests.shared`), each caller getting its own copy."""
    path = SAMPLES / f"{name}.stl"

    def compute():
        setup, part = make_setup(load_part(path).mesh)
        return setup, part, plan_job(part, setup, LIBRARY, part_name=name, options=TEST_PLAN).job

    return once("sample_op1", key_of(content(path), name, repr(TEST_PLAN)), compute)


def assert_held(job, moves, part) -> None:
    """Op 1 leaves the holding allowance: no feed below the part's bottom by more than 0.6 mm,
    at least 3 mm of stock under it, the jaws clear (read from the posted G-code). A through hole's
    drill point alone goes on into the allowance, so the drill's full diameter breaks through, and
    stops short of the stock's bottom."""
    setup = job.setup
    drills = [t.number for t in job.tools if t.is_drill]
    feed = (moves.motion[1:] != Motion.RAPID) & np.isfinite(moves.points[1:, 2])
    drilling = feed & np.isin(moves.tool[1:], drills)
    if drilling.any():
        assert moves.points[1:, 2][drilling].min() >= float(setup.stock_min[2]) + POINT_CLEARANCE_MM - 1e-9
    z = moves.points[1:, 2][feed & ~drilling]
    part_bottom = float(part.bounds[0][2])
    assert z.min() >= part_bottom - 0.6, (z.min(), part_bottom)
    assert z.min() - setup.stock_min[2] >= MIN_HOLDING_LEFT_MM - 1e-9
    assert setup.floor_z == pytest.approx(part_bottom - BREAKTHROUGH_MM)
    assert setup.jaws is not None and min(b.hi[2] for b in setup.jaws) < z.min()


def plan_post_verify(part_mesh, name: str, tmp_path: Path, options: PlanOptions = TEST_PLAN, cell: float = 0.2):
    job, program, report, nc, _ = plan_post_verify_moves(part_mesh, name, tmp_path, options, cell)
    return job, program, report, nc


def plan_post_verify_moves(part_mesh, name: str, tmp_path: Path, options: PlanOptions = TEST_PLAN,
                           cell: float = 0.2):
    setup, part = make_setup(part_mesh, jaws=JAWS)
    job = plan_job(part, setup, LIBRARY, part_name=name, options=options).job
    program = post_process(job, PostOptions())
    moves = parse_gcode(program.text, source=name)
    tools = {t.number: t for t in job.tools}
    verified = simulate(moves, tools, setup, np.asarray(part.triangles), VerifyOptions(cell=cell))
    sim, report = verified.simulation, verified.report
    nc = tmp_path / f"{name}.nc"
    nc.write_text(program.text)
    assert_held(job, moves, part)
    return job, program, report, nc, moves


def rs274_accepts(nc: Path, job, tmp_path: Path) -> None:
    """rs274 runs ``nc`` to its end with the job's tool table beside it (what ``factory gcode`` writes)."""
    p = run_rs274(nc, write_tool_table(nc, job.tools), tmp_path)
    assert p.returncode == 0, (p.stdout[-1500:], p.stderr[-1500:])


needs_rs274 = pytest.mark.skipif(shutil.which("rs274") is None,
                                 reason="LinuxCNC's rs274 is not installed (apt-get install linuxcnc-uspace)")


@pytest.mark.parametrize("sample", SAMPLE_PARTS, ids=lambda p: p.stem)
def test_sample_never_gouges_and_never_crashes(sample, tmp_path):
    job, program, report, nc, moves = plan_post_verify_moves(load_part(sample).mesh, sample.stem, tmp_path)
    # Round holes are drilled or helixed first (cadcam.drilling), then the roughing.
    assert [op.kind for op in job.operations if op.kind not in ("spot", "drill", "helix")][0] == "roughing"
    assert report.max_gouge <= 0.01, report.to_dict()
    assert report.rapid_crashes == (), report.rapid_crashes[:3]
    assert report.ok, [f.message for f in report.faults]  # the jaws among them
    # Finishing actually finished: most of the surface is within the roughing allowance.
    assert report.remaining_p95 <= TEST_PLAN.roughing.allowance + 0.05, report.to_dict()
    # No finishing tool buried, no rapid through stock, by the independent sweep probe.
    library = {t.number: t for t in job.tools}
    sw = sweep_moves(moves.points, moves.motion, moves.tool, library, job.setup, 0.5, full_width=True)
    assert_safe(job, job.setup, moves, sw, program.text)
    # No tool takes more than its axial limit at full width, by the probe's own leading-edge reading.
    assert past_axial_limit(sw, moves.tool, library, 0.5) == {}
    if shutil.which("rs274"):
        rs274_accepts(nc, job, tmp_path)


@needs_rs274
@pytest.mark.parametrize("dialect", ["linuxcnc", "fanuc"])
def test_rs274_accepts_every_dialect_it_knows(dialect, tmp_path):
    # LinuxCNC's interpreter also reads Fanuc-style programs (% bounds, O-number words aside).
    _, _, job = sample_op1(SAMPLE_PARTS[0].stem)  # one plan for both dialects (and tests/cadcam/test_stock.py)
    nc = tmp_path / "p.nc"
    nc.write_text(post_process(job, PostOptions(dialect=dialect)).text)
    rs274_accepts(nc, job, tmp_path)


def random_block(size, pockets, bosses) -> manifold3d.Manifold:
    body = manifold3d.Manifold.cube(size)
    for (x, y, w, h, depth) in pockets:
        body -= manifold3d.Manifold.cube((w, h, depth + 1)).translate((x, y, size[2] - depth))
    for (x, y, r, height) in bosses:
        body += manifold3d.Manifold.cylinder(height, r, r, 48).translate((x, y, size[2]))
    return body


@st.composite
def blocks(draw):
    sx = draw(st.floats(30, 50))
    sy = draw(st.floats(25, 40))
    sz = draw(st.floats(6, 12))
    pockets = []
    for _ in range(draw(st.integers(0, 2))):
        w, h = draw(st.floats(8, sx / 2)), draw(st.floats(8, sy / 2))
        x, y = draw(st.floats(2, sx - w - 2)), draw(st.floats(2, sy - h - 2))
        pockets.append((x, y, w, h, draw(st.floats(1, sz - 2))))
    bosses = []
    for _ in range(draw(st.integers(0, 2))):
        r = draw(st.floats(3, 7))
        bosses.append((draw(st.floats(r, sx - r)), draw(st.floats(r, sy - r)), r, draw(st.floats(1, 6))))
    return random_block((sx, sy, sz), pockets, bosses)


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(body=blocks())
def test_random_blocks_with_pockets_and_bosses_never_gouge(body, tmp_path):
    mesh = manifold_to_trimesh(body)
    options = dataclasses.replace(TEST_PLAN, finishing=FinishingOptions(scallop=0.05))
    _, _, report, _ = plan_post_verify(mesh, "random", tmp_path, options=options, cell=0.25)
    assert report.max_gouge <= 0.01, report.to_dict()
    assert report.rapid_crashes == ()
    assert not [f for f in report.faults if f.kind == "jaws"]


@pytest.mark.parametrize("pocket_depth", [1.0, 4.05])
def test_boss_overhanging_a_pocket_is_left_alone(pocket_depth, tmp_path):
    # Found by the random test above: a cylinder boss on the top face overhangs a shallow
    # pocket (an undercut the mill cannot reach). Every operation must stay above the part's
    # upper envelope; the finishing loop round the boss passes a hair (within the post's
    # arc tolerance) from its wall, which must not read as a cut of the wall's height.
    body = random_block((30.0, 34.78619542368884, 9.104785453418112),
                        [(10.111421395187252, 14.178455896001513, 10.0, 11.508132788630487, pocket_depth)],
                        [(19.473482411893556, 24.229522864450953, 6.811485297059996, 4.885542869202025)])
    # The ball over everything (by_faces off): its loop round the boss is what this is about.
    options = dataclasses.replace(TEST_PLAN, finishing=FinishingOptions(scallop=0.05), by_faces=False)
    job, _, report, _ = plan_post_verify(manifold_to_trimesh(body), "overhang", tmp_path, options=options, cell=0.25)
    kinds = [op.kind for op in job.operations]
    assert kinds[-2:] == ["waterline", "raster"] and set(kinds[:-2]) == {"roughing"}, kinds
    assert report.max_gouge <= 0.01, report.to_dict()
    assert report.rapid_crashes == ()
    assert not [f for f in report.faults if f.kind == "jaws"]


def test_raster_only_keeps_the_shank_off_a_wall_taller_than_the_flutes(tmp_path):
    # A wall standing 21 mm over its floor, the 6 mm ball's flutes 18 mm: a zigzag pass to
    # the floor beside it would rub its shank on the allowance roughing left on the wall's
    # top (stepped_wall.stl with --no-waterline). A first raster within the flutes' reach
    # finishes the wall's upper part before the full-depth one.
    body = manifold3d.Manifold.cube((30.0, 24.0, 4.0))
    body += manifold3d.Manifold.cube((3.0, 14.0, 21.0)).translate((12.0, 5.0, 3.0))
    # the ball's raster over everything (by_faces would finish this prismatic part with flat end mills)
    options = dataclasses.replace(TEST_PLAN, waterline=False, by_faces=False, finishing=FinishingOptions(scallop=0.05))
    job, _, report, _ = plan_post_verify(manifold_to_trimesh(body), "tall wall", tmp_path, options=options, cell=0.25)
    assert [op.name for op in job.operations if op.kind == "raster"] == ["finish raster upper", "finish raster"]
    assert job.operations[-2].points[:, 2].min() >= job.setup.stock_max[2] - LIBRARY.tool(3).flute_length
    assert [f.kind for f in report.faults] == [], report.faults
    assert report.ok and report.max_gouge <= 0.01


def test_in_a_pipe_a_stage_ends_when_its_work_does_not_when_its_counted_steps_do(monkeypatch):
    """Waterline and raster count their CL grid, then refine, link and check their moves uncounted; the
    stock model between stages counts nothing. A pipe's ``done`` line comes after all of that (issue 35:
    dome_mould showed gaps of seconds no stage accounted for)."""
    import cadcam.finishing
    from cli.common import StageLines

    events: list[str] = []
    real = cadcam.finishing._assemble

    def assembling(*args, **kwargs):  # the last step of each finishing pass, after its counted grid
        events.append(f"assemble {args[3]}")
        return real(*args, **kwargs)

    monkeypatch.setattr(cadcam.finishing, "_assemble", assembling)
    lines = StageLines()
    monkeypatch.setattr(lines, "_line", lambda now, text: events.append(text))
    dome = manifold3d.Manifold.cube((26.0, 20.0, 5.0)) + manifold3d.Manifold.sphere(6.0, 32).translate((13.0, 10.0, 3.0))
    setup, part = make_setup(manifold_to_trimesh(dome), jaws=JAWS)
    plan_job(part, setup, LIBRARY, part_name="dome", options=TEST_PLAN, progress=lines)
    for stage in ("waterline", "raster"):
        start, end = events.index(f"{stage} ..."), next(i for i, e in enumerate(events) if e.startswith(f"{stage} done"))
        assert f"assemble {stage}" in events[start:end], events[start:end + 1]
    started = [e[:-len(" ...")] for e in events if e.endswith(" ...")]
    assert started.count("stock model") >= 2 and "freeform area" in started  # the work between stages shows
    assert sorted(started) == sorted(e.split(" done in ")[0] for e in events if " done in " in e)


def assert_verified_with_chips(job, setup, part) -> None:
    """Verify, on its 0.2 mm grid, holding every move's chip to its tool's library fz (the job's chip loads, as
    `factory plan` gives them), passes the job's program with no fault and no gouge."""
    from cadcam.engagement import chip_loads

    sheet = [{"tool": o.tool.number, "chip_load_mm": o.cutting.chip_load, "spindle_rpm": o.cutting.spindle_rpm}
             for o in job.operations if not o.tool.is_drill]
    tools = {t.number: t for t in job.tools}
    report = simulate(parse_gcode(post_process(job).text), tools, setup, np.asarray(part.triangles),
                      VerifyOptions(cell=0.2), chips=chip_loads(sheet)).report
    assert report.ok and [f.kind for f in report.faults] == [], [f.message for f in report.faults]
    assert report.max_gouge <= 0.01


def test_the_balls_passes_run_at_their_chip_and_verify_holds_every_chip_to_fz(tmp_path):
    """The ball's waterline and raster run at the feed each move's chip allows on the stock before them (as flats
    and walls do): over a dome that roughing left in terraces some of their moves run faster than the library's
    feed, none slower; verify, holding every move's chip to the library's fz, passes the program."""
    dome = manifold3d.Manifold.cube((26.0, 20.0, 5.0)) + manifold3d.Manifold.sphere(6.0, 32).translate((13.0, 10.0, 3.0))
    setup, part = make_setup(manifold_to_trimesh(dome), jaws=JAWS)
    job = plan_job(part, setup, LIBRARY, part_name="dome", options=TEST_PLAN).job
    ball = [op for op in job.operations if op.kind in ("waterline", "raster")]
    assert [op.kind for op in ball] == ["waterline", "raster"]
    for op in ball:
        fed = op.move_feeds()[op.motion != Motion.RAPID][1:]
        assert (fed >= min(op.cutting.feed, op.cutting.plunge_feed) - 1e-9).all()
    assert any((op.move_feeds()[op.motion == Motion.CUT] > op.cutting.feed * 1.2).any() for op in ball)
    assert_verified_with_chips(job, setup, part)


def _terraced_dome():
    """(setup, part): a dome on a block, which the roughing levels leave in terraces (the roughing tool steps
    down between them again, :func:`cadcam.plan._terraces`)."""
    cap = manifold3d.Manifold.sphere(11.0, 48).translate((20.0, 15.0, 4.0))
    dome = manifold3d.Manifold.cube((40.0, 30.0, 6.0)) + cap
    return make_setup(manifold_to_trimesh(dome), jaws=JAWS)


def test_the_terraces_run_at_their_chip_and_verify_holds_every_chip_to_fz():
    """The roughing tool's terraces run at the feed each move's chip allows (measured with the bores and the
    roughing, in one chain from the stock the drills leave): a terrace cuts a step's skin, narrower than the
    tool's full width, so some of their cutting moves run faster than the library's feed, none slower; verify,
    holding every move's chip to the library's fz, passes the program."""
    setup, part = _terraced_dome()
    job = plan_job(part, setup, LIBRARY, part_name="dome", options=TEST_PLAN).job
    rough = job.parameters["rough_tool"]
    terraces = [op for op in job.operations if op.name == f"rest rough T{rough}"]
    assert len(terraces) == 1, [op.name for op in job.operations]
    op = terraces[0]
    fed = op.move_feeds()
    cutting = fed[op.motion == Motion.CUT][1:]
    assert (cutting >= op.cutting.feed - 1e-9).all()
    assert (cutting > op.cutting.feed * 1.2).mean() > 0.1  # most of a terrace's skin is a light cut
    assert_verified_with_chips(job, setup, part)


def test_each_stock_model_cuts_on_from_the_last_when_feeds_were_raised_since(monkeypatch):
    """The planning models are cut incrementally (``stock_after``'s ``earlier``): after the bores, roughing and
    terraces are replaced by their copies at raised feeds, the next model still cuts on from the last one (the
    same moves, so the same stock) instead of cutting every operation from the block again."""
    import cadcam.plan as plan_module

    calls = []
    real = plan_module.stock_after

    def spy(ops, setup, triangles, cell=0.5, earlier=None):
        done = () if earlier is None else earlier.operations
        calls.append((cell, len(ops), len(done), all(a is b for a, b in zip(done, ops))))
        return real(ops, setup, triangles, cell, earlier)

    monkeypatch.setattr(plan_module, "stock_after", spy)
    setup, part = _terraced_dome()
    job = plan_job(part, setup, LIBRARY, part_name="dome", options=TEST_PLAN).job
    assert any(op.feeds is not None for op in job.operations if op.kind == "roughing")
    seen = set()
    for cell, n, done, same in calls:
        if cell in seen:  # every model after the first on its grid cuts on from the one before
            assert done > 0 and same and done <= n, calls
        seen.add(cell)


def test_the_roughing_tool_finishes_before_a_narrower_one_roughs_so_each_tool_is_loaded_once():
    """plate_bosses: T14 roughs, then finishes the flats and walls it reaches (planned on the stock before the rest
    roughing, keeping off what T2 roughs there); T2 roughs what T14 could not enter and finishes it. Each end mill
    is loaded once (on main T14 and T2 came twice each); verify, holding every chip to fz, passes the program."""
    setup, part, job = sample_op1("plate_bosses")
    rough = job.parameters["rough_tool"]
    assert any(op.kind == "roughing" and op.tool.number != rough for op in job.operations)  # a narrower tool's rest
    mills = [op.tool.number for op in job.operations if not op.tool.is_drill]
    loaded = [t for i, t in enumerate(mills) if i == 0 or t != mills[i - 1]]
    assert len(loaded) == len(set(loaded)), [op.name for op in job.operations]
    assert_verified_with_chips(job, setup, part)


def test_every_roughing_operation_cuts_stock_the_ones_before_left():
    """plate_bosses: each roughing operation takes stock the operations before it left, on the plan's model
    (on main the 16 mm end mill's terraces grazed the gaps between the bosses, which only T2 enters, on 20
    levels, and cut nothing: 12 s)."""
    from cadcam.stock import OperationsCut, stock_after

    setup, part, job = sample_op1("plate_bosses")
    triangles = np.asarray(part.triangles)
    before = None
    for i, op in enumerate(job.operations):
        after = stock_after(job.operations[:i + 1], setup, triangles, 0.5, before)
        if op.kind == "roughing" and i:
            assert np.any(after.stock_top < before.simulation.stock_top - 1e-9), op.name
        before = OperationsCut(tuple(job.operations[:i + 1]), after)
