"""Round holes: detection, drill cycles posted per dialect (judged by LinuxCNC's rs274), helices, verify."""

from __future__ import annotations

import math
import re
import shutil
import subprocess
from pathlib import Path

import manifold3d
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cadcam.drilling import POINT_CLEARANCE_MM, DrillingOptions, cycle_moves, drill_operation, find_holes, plan_holes
from cadcam.gcode import parse_gcode
from cadcam.model import DrillCycle, Job, Motion, Operation, Setup
from cadcam.plan import PlanOptions, choose_tools
from cadcam.post import PostOptions, post_process
from cadcam.setup import make_setup
from cadcam.tools import load_tool_library
from cadcam.envelope import swept_envelope
from cadcam.stock import operation_moves
from cadcam.verify import VerifyOptions, simulate
from factory.core.errors import ToolError
from tests.conftest import manifold_to_trimesh
from tests.rs274 import run_rs274, write_tool_table

LIBRARY = load_tool_library()
SEGMENTS = 96


def cylinder(cx, cy, r, z0, z1) -> manifold3d.Manifold:
    return manifold3d.Manifold.cylinder(z1 - z0, r, circular_segments=SEGMENTS).translate((cx, cy, z0))


def drilled(cx, cy, r, z_wall, z1, angle=118.0) -> manifold3d.Manifold:
    """A drill's cut: the wall from ``z_wall`` up to ``z1`` and the point's cone below it.

    One solid of revolution: a cone unioned onto a cylinder meets it at a seam that float rounding can
    leave as a wafer of material 1e-7 mm thick across the hole, and the part then truly has a flat bottom.
    """
    tip = z_wall - r / math.tan(math.radians(angle / 2))
    profile = manifold3d.CrossSection([[(0.0, tip), (r, z_wall), (r, z1), (0.0, z1)]])
    return manifold3d.Manifold.revolve(profile, SEGMENTS).translate((cx, cy, 0.0))


def plate(size=(60.0, 40.0, 12.0)) -> manifold3d.Manifold:
    return manifold3d.Manifold.cube(size)


# --------------------------------------------------------------------------- detection


def test_finds_through_flat_and_conical_holes_and_skips_bosses_and_slots():
    body = plate()
    body -= cylinder(10, 10, 5.0, -1, 13)  # 10 mm through
    body -= cylinder(25, 10, 3.4, 6, 13)  # 6.8 mm, 6 deep, flat
    body -= drilled(40, 10, 2.1, 4, 13)  # drilled 4.2
    body -= manifold3d.Manifold.cube((12, 4, 5)).translate((5, 28, 8))  # a slot: no hole
    body += cylinder(50, 30, 4, 12, 14)  # a boss: no hole
    part = manifold_to_trimesh(body)
    holes = find_holes(part)
    got = [(round(h.x, 3), round(h.y, 3), round(h.diameter, 3), h.bottom) for h in holes]
    assert got == [(10, 10, 10, "through"), (25, 10, 6.8, "flat"), (40, 10, 4.2, "conical")]
    through, flat, conical = holes
    assert (through.top_z, through.bottom_z) == (12, 0)
    assert (flat.top_z, flat.bottom_z, flat.tip_z) == (12, 6, 6)
    assert conical.bottom_z == pytest.approx(4) and conical.tip_z == pytest.approx(4 - 2.1 / math.tan(math.radians(59)))
    # The facets of a 96-gon lie inside the nominal circle.
    assert through.inscribed == pytest.approx(10 * math.cos(math.pi / SEGMENTS), abs=1e-6)


def test_a_counterbore_is_no_simple_hole_but_its_bore_is():
    body = plate()
    body -= cylinder(20, 20, 5.0, -1, 13)
    body -= cylinder(20, 20, 8.0, 8, 13)
    holes = find_holes(manifold_to_trimesh(body))
    assert [(round(h.diameter, 3), h.bottom, h.top_z) for h in holes] == [(10, "through", 8)]


# --------------------------------------------------------------------------- cycles through rs274


def _setup(size=(60.0, 40.0, 12.0)) -> Setup:
    return Setup(stock_min=np.array([0.0, 0.0, -size[2]]), stock_max=np.array([size[0], size[1], 0.0]),
                 transform_mesh_to_work=np.eye(4), safe_z=5.0, clearance=1.0)


def _drill_job(retract="r") -> Job:
    spot, drill = LIBRARY.spot_drills("al")[0], LIBRARY.drills("al")[3]
    holes = np.array([[10.0, 10.0, -12.0], [30.0, 12.5, -9.5], [45.25, 30.0, -14.0]])
    ops = (
        drill_operation("spot", "spot", spot, LIBRARY.cutting_data(spot, "al"),
                        DrillCycle(81, holes * [1, 1, 0] + [0, 0, -2.0], 1.0, 0.0, retract, 5.0)),
        drill_operation("drill", "drill", drill, LIBRARY.cutting_data(drill, "al"),
                        DrillCycle(81, holes, 1.0, 0.0, retract, 5.0)),
        drill_operation("peck", "drill", drill, LIBRARY.cutting_data(drill, "al"),
                        DrillCycle(83, holes[::-1] - [0, 0, 20.0], 1.0, 3.4, retract, 5.0)),
    )
    return Job(part_name="drill", setup=_setup((60, 40, 40)), operations=ops)


def _rs274(tmp_path: Path, job: Job, text: str) -> subprocess.CompletedProcess:
    if shutil.which("rs274") is None:
        pytest.skip("LinuxCNC's rs274 interpreter is not on PATH")
    nc = tmp_path / "drill.nc"
    nc.write_text(text)
    return run_rs274(nc, write_tool_table(nc, job.tools), tmp_path, timeout=60)


_CANON = re.compile(r"(STRAIGHT_TRAVERSE|STRAIGHT_FEED)\(([^)]*)\)")


def _path(points: np.ndarray) -> np.ndarray:
    """Positions with repeats (zero-length moves) dropped."""
    keep = np.r_[True, np.any(np.abs(np.diff(points, axis=0)) > 1e-9, axis=1)]
    return points[keep]


@pytest.mark.parametrize("retract", ["r", "initial"])
@pytest.mark.parametrize("dialect", ["linuxcnc", "fanuc"])
def test_linuxcnc_runs_the_cycles_as_we_expand_them(tmp_path, dialect, retract):
    """rs274 reads the posted G81/G83 (G98 or G99, G80) and moves exactly through our expansion."""
    job = _drill_job(retract)
    prog = post_process(job, PostOptions(dialect=dialect))
    code = prog.text
    assert "G99 G81" in code if retract == "r" else "G98 G81" in code
    assert "G83" in code and code.count("G80") >= 4  # header + one per operation
    res = _rs274(tmp_path, job, code)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    canon = [(kind, [float(a) for a in args.split(",")[:3]]) for kind, args in _CANON.findall(res.stdout)]
    theirs = np.array([v for _, v in canon])
    feeds = np.array([k == "STRAIGHT_FEED" for k, _ in canon])
    moved = np.r_[True, np.any(np.abs(np.diff(theirs, axis=0)) > 1e-9, axis=1)]  # rs274 repeats some positions
    theirs, feeds = theirs[moved], feeds[moved]
    cursor = 0
    for op in job.operations:
        pts, mot = cycle_moves(op.cycle)
        # Find the cycle's first point (over the first hole at the initial level) in rs274's moves.
        # (the last operation may have ended right there: its end is this one's start)
        cursor = max(cursor - 1, 0)
        start = cursor + int(np.flatnonzero(np.all(np.abs(theirs[cursor:] - pts[0]) < 1e-4, axis=1))[0])
        ours = _path(pts)
        cursor = start + len(ours)
        got = theirs[start:start + len(ours)]
        np.testing.assert_allclose(got, ours, atol=1e-4)
        np.testing.assert_array_equal(feeds[start + 1:start + len(ours)], mot[1:][np.any(np.diff(pts, axis=0) != 0, axis=1)] == Motion.CUT)


def test_grbl_moves_equal_the_cycles(tmp_path):
    """Grbl has no canned cycles: its G0/G1 program moves the tool as the canned-cycle program does."""
    job = _drill_job()
    grbl = post_process(job, PostOptions(dialect="grbl"))
    assert not re.search(r"^G8[0-3]\b|\bG8[13]\b|\bG9[89]\b", "\n".join(
        re.sub(r"\([^)]*\)", "", s) for s in grbl.text.splitlines()[8:]), re.M)
    cnc = post_process(job, PostOptions(dialect="linuxcnc"))
    a, b = parse_gcode(grbl.text), parse_gcode(cnc.text)
    ka = np.all(np.isfinite(a.points), axis=1)
    kb = np.all(np.isfinite(b.points), axis=1) & (b.line > 0)
    pa, pb = _path(a.points[ka]), _path(b.points[kb])
    n = min(len(pa), len(pb)) - 1  # LinuxCNC ends with G53 G0 Z0, grbl at the safe height
    np.testing.assert_allclose(pa[:n], pb[:n], atol=1e-4)
    # Our parser reads Fanuc's cycles (decimal points, % and O) as the same motion.
    c = parse_gcode(post_process(job, PostOptions(dialect="fanuc")).text)
    pc = _path(c.points[np.all(np.isfinite(c.points), axis=1) & (c.line > 0)])
    np.testing.assert_allclose(pc[:n], pb[:n], atol=1e-4)
    # Same motion kinds and the same estimate of the drilling itself.
    for ea, eb in zip(grbl.estimates, cnc.estimates):
        assert ea.cut_length == pytest.approx(eb.cut_length, abs=1e-3)
        assert ea.cut_time == pytest.approx(eb.cut_time, rel=1e-3)


def test_job_with_cycles_round_trips():
    job = _drill_job()
    again = Job.from_dict(job.to_dict())
    for a, b in zip(job.operations, again.operations):
        assert b.cycle is not None and b.cycle.code == a.cycle.code
        np.testing.assert_array_equal(a.cycle.holes, b.cycle.holes)
        assert b.tool == a.tool


# --------------------------------------------------------------------------- verify sees a drill's shape


@settings(max_examples=60, deadline=None)
@given(st.floats(-5, 5), st.floats(-5, 5), st.floats(-3, 3), st.floats(-4, 4), st.floats(-4, 4),
       st.sampled_from([0, 1]), st.floats(-3, 3), st.floats(-3, 3))
def test_drill_envelope_is_the_lowest_point_of_the_swept_cone(x0, y0, z0, dx, dy, which, qx, qy):
    drill = [LIBRARY.drills("al")[2], LIBRARY.spot_drills("al")[0]][which]
    p0, p1 = np.array([x0, y0, z0]), np.array([x0 + dx, y0 + dy, z0 - 2.0 + dx])
    q = np.array([[qx, qy]])
    env = float(swept_envelope(q, p0, p1, drill)[0])
    t = np.linspace(0.0, 1.0, 20001)
    c = p0 + t[:, None] * (p1 - p0)
    r = np.hypot(q[0, 0] - c[:, 0], q[0, 1] - c[:, 1])
    brute = c[:, 2] + drill.profile_height(r)
    expect = float(brute.min())
    if math.isinf(expect):
        assert math.isinf(env) or env >= float(np.min(c[:, 2] + drill.point_length)) - 1e-6
    else:
        assert env == pytest.approx(expect, abs=2e-3)
        assert env <= expect + 1e-9


def test_a_drill_fed_sideways_through_stock_is_a_fault():
    setup = _setup()
    part = manifold_to_trimesh(plate((56, 36, 6)).translate((2, 2, -12)))
    drill = LIBRARY.drills("al")[2]
    cut = LIBRARY.cutting_data(drill, "al")
    pts = np.array([[20, 20, 5], [20, 20, -3], [30, 20, -3], [30, 20, 5]], dtype=float)
    op = Operation("bad", "drill", drill, cut, pts, np.array([0, 1, 1, 0], dtype=np.int8))
    rep = simulate(operation_moves([op]), {drill.number: drill}, setup, part.triangles, VerifyOptions(cell=0.25)).report
    kinds = {f.kind for f in rep.faults}
    assert "drill_side" in kinds and not rep.ok
    # Straight down and up again is what a drill does: no fault.
    ok = Operation("ok", "drill", drill, cut, pts[[0, 1, 0]], np.array([0, 1, 0], dtype=np.int8))
    rep = simulate(operation_moves([ok]), {drill.number: drill}, setup, part.triangles, VerifyOptions(cell=0.25)).report
    assert rep.faults == () and rep.ok


def test_drills_are_never_chosen_for_milling_and_refused_when_named():
    setup = _setup()
    rough, finish = choose_tools(LIBRARY, setup, PlanOptions())
    assert not rough.is_drill and not finish.is_drill
    drill = LIBRARY.drills("al")[0].number
    with pytest.raises(ToolError, match="is a drill"):
        choose_tools(LIBRARY, setup, PlanOptions(rough_tool=drill))
    with pytest.raises(ToolError, match="is a drill"):
        choose_tools(LIBRARY, setup, PlanOptions(finish_tool=drill))


# --------------------------------------------------------------------------- random plates

_DIAMETERS = [3.3, 4.2, 5.0, 6.8, 8.5, 10.0, 7.0, 9.0, 11.0]


@st.composite
def plates(draw):
    """A plate with holes on a grid of 14 mm pitches: drill sizes and others, through, flat or conical."""
    thick = draw(st.sampled_from([8.0, 12.0, 20.0]))
    body = plate((60.0, 44.0, thick))
    specs = []
    n = draw(st.integers(1, 6))
    slots = draw(st.permutations([(x, y) for x in (9.0, 23.0, 37.0, 51.0) for y in (9.0, 22.0, 35.0)]))[:n]
    for x, y in slots:
        d = draw(st.sampled_from(_DIAMETERS))
        kind = draw(st.sampled_from(["through", "flat", "conical"]))
        point = d / 2 / math.tan(math.radians(59)) if kind == "conical" else 0.0
        depth = draw(st.floats(2.0, thick - 1.0 - point)) if kind != "through" else thick
        z = thick - depth
        if kind == "conical":
            cut = drilled(x, y, d / 2, z, thick + 1)
        else:
            cut = cylinder(x, y, d / 2, z if kind != "through" else -1.0, thick + 1)
        body -= cut
        specs.append((x, y, d, kind, z))
    # The roughing end mill decides which holes it enters itself and which get a helix.
    return body, specs, thick, LIBRARY.tool(draw(st.sampled_from([1, 2, 5])))


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(plates())
def test_random_plates_holes_found_drilled_to_depth_without_gouge(case):
    body, specs, thick, rough = case
    part0 = manifold_to_trimesh(body)
    setup, part = make_setup(part0)  # 2 mm sides, 1 mm over the top; the part's bottom on the stock's
    shift = setup.transform_mesh_to_work[:3, 3]
    holes = find_holes(part)
    assert len(holes) == len(specs)
    for (x, y, d, kind, z) in specs:
        h = min(holes, key=lambda h: math.hypot(h.x - x - shift[0], h.y - y - shift[1]))
        assert math.hypot(h.x - x - shift[0], h.y - y - shift[1]) < 1e-4  # float32 vertices
        assert h.diameter == pytest.approx(d, abs=1e-4) and h.bottom == kind
        if kind != "through":
            assert h.bottom_z == pytest.approx(z + shift[2], abs=1e-4)
    hp = plan_holes(part, setup, LIBRARY, rough, allowance=0.3)
    assert len(hp.drilled) + len(hp.helixed) + len(hp.left) == len(holes)
    if not hp.operations:
        return
    ops = list(hp.operations)
    tools = {op.tool.number: op.tool for op in ops}
    cell = 0.2
    verified = simulate(operation_moves(ops), tools, setup, part.triangles, VerifyOptions(cell=cell))
    sim, rep = verified.simulation, verified.report
    assert rep.max_gouge <= 0.01, rep.to_dict()
    assert rep.rapid_crashes == ()
    assert [f.kind for f in rep.faults] == [], rep.faults
    assert rep.ok
    # Every drilled or helixed hole is open to its depth at its axis.
    g = sim.grid
    floor = float(setup.floor_z)  # op 1 stops 0.5 mm under the part, in the holding allowance
    for h in (*hp.drilled, *hp.helixed):
        i, j = int(round((h.x - g.x0) / g.cell)), int(round((h.y - g.y0) / g.cell))
        top = float(sim.stock_top[j, i])
        # a drill to the hole's tip (an undersize one until its point meets the wall's bottom),
        # an end mill to the wall's bottom; never below the floor
        drilled_by = [(op.tool, row[2]) for op in ops if op.cycle is not None and op.kind == "drill"
                      for row in op.cycle.holes if math.hypot(row[0] - h.x, row[1] - h.y) < 1e-6]
        if h in hp.drilled:
            assert len(drilled_by) == 1
            drill, drilled_to = drilled_by[0]
            if h.bottom == "through":
                # on into the holding allowance, so the full diameter breaks through the part's underside
                # (no cone of stock left in the hole), but never near the stock's bottom
                assert drilled_to == pytest.approx(max(h.bottom_z - drill.point_length - DrillingOptions().breakthrough,
                                                       float(setup.stock_min[2]) + POINT_CLEARANCE_MM))
                assert drilled_to + drill.point_length <= h.bottom_z or drilled_to == pytest.approx(
                    float(setup.stock_min[2]) + POINT_CLEARANCE_MM)
            elif h not in hp.undersize:
                assert drilled_to == pytest.approx(max(h.tip_z, floor))
            depth = float(drilled_to)
        else:
            depth = h.bottom_z
        off = math.hypot(g.x0 + i * g.cell - h.x, g.y0 + j * g.cell - h.y)  # the grid point is off the axis:
        assert top <= max(depth, floor) + 0.61 * off + 1e-6, (h, top)  # up the drill's 118 deg point
        # and to its size (within the drill's tolerance) near the wall, at mid depth of the wall
        if h in hp.undersize:
            continue
        mid = 0.5 * (h.top_z + h.bottom_z)
        ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
        rr = h.inscribed / 2 - 0.1 - cell
        for a in ang:
            ii = int(round((h.x + rr * np.cos(a) - g.x0) / g.cell))
            jj = int(round((h.y + rr * np.sin(a) - g.y0) / g.cell))
            assert sim.stock_top[jj, ii] <= mid + 1e-6, (h, a)


def test_no_too_small_pocket_warning_for_holes_cut_to_size(caplog):
    """Roughing meets the helixed bores as pockets too small for its entry: they are cut already, so no warning;
    a pocket no operation cut still gets its warning."""
    import logging

    from cadcam.plan import PlanOptions, plan_job
    from cadcam.setup import make_setup

    # 12 and 12.5 mm through bores (no drill of their size; too narrow for the 10 mm roughing end mill's helix), a
    # 3.3 mm flat-bottom hole (drilled), and an 11 x 11 mm square pocket 4 mm deep no tool here enters by a helix
    solid = plate((60.0, 40.0, 12.0)) - cylinder(15, 12, 6.0, -1, 13) - cylinder(15, 28, 6.25, -1, 13) \
        - cylinder(30, 20, 1.65, 6, 13) - manifold3d.Manifold.cube((11.0, 11.0, 5.0)).translate((40, 14.5, 8))
    part_mesh = manifold_to_trimesh(solid)
    setup, part = make_setup(part_mesh)
    caplog.set_level(logging.DEBUG, logger="cadcam.roughing")
    result = plan_job(part, setup, LIBRARY, part_name="bores", options=PlanOptions(rough_tool=2))  # 10 mm
    holes = result.job.parameters["holes"]
    assert {round(h["diameter"], 1) for h in holes["helixed"]} == {12.0, 12.5}, holes
    skipped = [r for r in caplog.records if "too small to enter" in r.getMessage()]
    # roughing met the bores as pockets too small to enter, said only at debug level
    in_holes = [r for r in skipped if r.getMessage().endswith("skipped (a hole cut before)")]
    assert in_holes and all(r.levelno == logging.DEBUG for r in in_holes)
    assert all(abs(float(r.getMessage().split("near (")[1].split(",")[0]) - 17.0) < 6.0 for r in in_holes)  # in a bore
    warned = {r.getMessage().split("near ")[1][:14] for r in skipped if r.levelno >= logging.WARNING}
    assert warned == {"(47.50, 22.00)"}  # the sharp pocket the 10 mm roughing end mill cannot enter


# --------------------------------------------------------------------------- helices


@pytest.mark.parametrize("diameter", [11.0, 12.0, 12.8])
def test_helix_feeds_its_edge_at_the_cutting_feed_down_the_ramp_rule(diameter):
    """A bore no drill matches is helixed at the cutting feed at its edge (the centre line slower by
    (Dh - D) / Dh on the internal arc), descending at most 3 deg along the centre line and no deeper per
    turn than the tool's full-width depth; verify passes it with no fault and its full-width cut within
    the axial limit. 12.8 mm takes two helices (the narrower clears the pin; the 10 mm end mill needs 13)."""
    part0 = manifold_to_trimesh(plate((40.0, 40.0, 15.0)) - cylinder(20, 20, diameter / 2, -1, 16))
    setup, part = make_setup(part0)
    # 16 mm roughing: too wide to enter; from solid (a drill first would be quicker: test_predrilled_bores_...)
    hp = plan_holes(part, setup, LIBRARY, LIBRARY.tool(14), DrillingOptions(predrill=False), allowance=0.3)
    (op,) = [o for o in hp.operations if o.kind == "helix"]
    tool = op.tool
    assert tool.number == 1 and len(hp.helixed) == 1
    (h,) = hp.helixed
    feed = LIBRARY.cutting_data(tool, setup.material).feed
    helix = op.motion == Motion.PLUNGE
    step = np.diff(op.points, axis=0)
    down = step[helix[1:]]
    ends = op.points[1:][helix[1:]]
    radius = np.hypot(ends[:, 0] - h.x, ends[:, 1] - h.y)
    # the narrowest helix sets the feed: its edge, on a circle of 2 (r + R), at the library's feed
    r0 = float(radius.min())
    edge = op.cutting.feed * (r0 + tool.radius) / r0
    assert edge == pytest.approx(feed, rel=1e-3)
    assert op.cutting.plunge_feed == op.cutting.feed
    assert len(set(np.round(radius, 6))) == (2 if diameter > 12.5 else 1)
    starts = op.points[:-1][helix[1:]]
    turned = np.abs(np.angle(np.exp(1j * (np.arctan2(ends[:, 1] - h.y, ends[:, 0] - h.x)
                                          - np.arctan2(starts[:, 1] - h.y, starts[:, 0] - h.x)))))
    along = radius * turned  # along the helix (its chords are a hair shorter)
    assert (-down[:, 2] <= along * math.tan(math.radians(3.0)) + 1e-9).all()  # the ramp rule
    for r in set(np.round(radius, 6)):  # per turn, no deeper than the full-width depth
        on = np.isclose(radius, r, atol=1e-6)
        turn_fall = -down[on, 2].sum() / (along[on].sum() / (2 * math.pi * r))
        assert turn_fall <= tool.full_width_limit + 1e-9
    report = simulate(operation_moves([op]), {1: tool}, setup, part.triangles, VerifyOptions(cell=0.2)).report
    assert [f.kind for f in report.faults] == [] and report.ok, report.faults
    assert report.max_gouge <= 0.01
    (eng,) = report.engagement
    assert eng.max_full_depth <= tool.full_width_limit


@pytest.mark.parametrize("diameter, rings", [(11.0, 1), (12.0, 2)])
def test_predrilled_bores_are_quicker_and_clean(tmp_path, diameter, rings):
    """Four bores no drill matches: drill 10 mm (no spot: the helix places the bore), then helices from where the
    drill's point begins, quicker
    by the program's clock than four helices from solid. The 6 mm end mill takes the 11 mm bores' wall in one
    ring (its engagement within the tool's deep radial limit at full flute length), the 12 mm ones' in two.
    Verify and the independent sweep find no fault, no rapid into stock, no plunge, no full-width cut past the
    axial limit; the bores are cut to size; rs274 runs it. One such bore alone is drilled first too: with no spot
    before the pilot, its one tool change costs less than the helix from solid takes longer."""
    from tests.cadcam.sweep import past_axial_limit, rapid_hits, sweep_moves

    centres = [(10, 10), (30, 10), (10, 30), (30, 30)]
    solid = plate((40.0, 40.0, 15.0))
    for x, y in centres:
        solid -= cylinder(x, y, diameter / 2, -1, 16)
    setup, part = make_setup(manifold_to_trimesh(solid))
    hp = plan_holes(part, setup, LIBRARY, LIBRARY.tool(2), allowance=0.3)
    assert len(hp.predrilled) == len(hp.helixed) == 4 and hp.drilled == () and hp.undersize == ()
    ops = list(hp.operations)
    assert [o.kind for o in ops] == ["drill"] + ["helix"] * 4
    drill = ops[0].tool
    assert drill.diameter == 10.0
    tip = float(ops[0].cycle.holes[0, 2])
    for op in ops[1:]:
        feed = op.motion != Motion.RAPID
        first = int(np.flatnonzero(feed)[0])
        h = min(hp.helixed, key=lambda h: math.hypot(h.x - op.points[0, 0], h.y - op.points[0, 1]))
        # down the drilled hole's axis by rapid to where its point begins, then out on a half circle
        np.testing.assert_allclose(op.points[first - 1], [h.x, h.y, tip + drill.point_length], atol=1e-9)
        assert np.hypot(*(op.points[:first, :2] - [h.x, h.y]).T).max() < 1e-9
        helix = op.points[1:][op.motion[1:] == Motion.PLUNGE]
        assert len(set(np.round(np.hypot(helix[:, 0] - h.x, helix[:, 1] - h.y), 6))) == rings
    plain = plan_holes(part, setup, LIBRARY, LIBRARY.tool(2), DrillingOptions(predrill=False), allowance=0.3)
    job = Job(part_name="bores", setup=setup, operations=tuple(ops))
    slower = Job(part_name="bores", setup=setup, operations=plain.operations)
    assert post_process(job).total_time < post_process(slower).total_time
    tools = {o.tool.number: o.tool for o in ops}
    moves = operation_moves(ops)
    verified = simulate(moves, tools, setup, part.triangles, VerifyOptions(cell=0.2))
    rep, sim = verified.report, verified.simulation
    assert rep.ok and rep.faults == () and rep.rapid_crashes == () and rep.max_gouge <= 0.01, rep.faults
    sw = sweep_moves(moves.points, moves.motion, moves.tool, tools, setup, cell=0.25, full_width=True)
    assert rapid_hits(sw, moves.motion).size == 0
    assert past_axial_limit(sw, moves.tool, tools, slack=0.25) == {}
    step = np.diff(moves.points, axis=0)
    vertical = (moves.motion[1:] != Motion.RAPID) & (np.hypot(step[:, 0], step[:, 1]) < 1e-6) & (step[:, 2] < -1e-6)
    mill = ~np.isin(moves.tool[1:], [n for n, t in tools.items() if t.is_drill])
    assert not (vertical & mill & (sw.engagement[1:] > 0.05)).any()  # no plunge
    g = sim.grid
    for h in hp.helixed:  # to size at mid depth of the wall
        for a in np.linspace(0, 2 * np.pi, 16, endpoint=False):
            rr = h.inscribed / 2 - 0.1 - g.cell
            i, j = int(round((h.x + rr * np.cos(a) - g.x0) / g.cell)), int(round((h.y + rr * np.sin(a) - g.y0) / g.cell))
            assert sim.stock_top[j, i] <= 0.5 * (h.top_z + h.bottom_z)
    res = _rs274(tmp_path, job, post_process(job).text)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    one = manifold_to_trimesh(plate((40.0, 40.0, 15.0)) - cylinder(20, 20, diameter / 2, -1, 16))
    setup1, part1 = make_setup(one)
    alone = plan_holes(part1, setup1, LIBRARY, LIBRARY.tool(2), allowance=0.3)
    solid1 = plan_holes(part1, setup1, LIBRARY, LIBRARY.tool(2), DrillingOptions(predrill=False), allowance=0.3)
    assert len(alone.helixed) == 1 and [o.kind for o in solid1.operations] == ["helix"]
    # with no spot before it, the pilot's one tool change costs less than the helix from solid takes longer
    assert [o.kind for o in alone.operations] == ["drill", "helix"] and len(alone.predrilled) == 1
    timed = [post_process(Job(part_name="bore", setup=setup1, operations=o)).total_time
             for o in (alone.operations, solid1.operations)]
    assert timed[0] < timed[1], timed


def test_a_plans_predrilled_bores_run_at_their_chip_and_verify_passes_them():
    """In a plan, a bore's helices round the drilled hole are side cuts: they run faster than
    :func:`cadcam.drilling.helix_cutting`'s feed (a slot's from solid, the centre line slowed for the internal arc),
    at what their chip allows on the stock the drills leave; verify, holding every move's chip to the library's
    fz, passes the whole program, and nothing is plunged or cut past the axial limit."""
    from cadcam.engagement import chip_loads
    from cadcam.plan import plan_job

    solid = plate((40.0, 40.0, 15.0))
    for x, y in [(10, 10), (30, 10), (10, 30), (30, 30)]:
        solid -= cylinder(x, y, 5.5, -1, 16)
    setup, part = make_setup(manifold_to_trimesh(solid))
    job = plan_job(part, setup, LIBRARY, part_name="bores").job
    helices = [o for o in job.operations if o.kind == "helix"]
    assert len(helices) == 4 and any(o.kind == "drill" for o in job.operations)
    for op in helices:
        deep = (op.motion != Motion.RAPID) & (op.points[:, 2] < -2.0)
        assert np.median(op.move_feeds()[deep]) > 1.5 * op.cutting.feed
    sheet = [{"tool": o.tool.number, "chip_load_mm": o.cutting.chip_load, "spindle_rpm": o.cutting.spindle_rpm}
             for o in job.operations if not o.tool.is_drill]
    tools = {o.tool.number: o.tool for o in job.operations}
    report = simulate(parse_gcode(post_process(job).text), tools, setup, part.triangles, VerifyOptions(cell=0.2),
                      chips=chip_loads(sheet)).report
    assert report.ok and report.faults == (), [f.message for f in report.faults]
    assert all(e.max_full_depth <= tools[e.tool].full_width_limit for e in report.engagement)


def test_a_shallow_hole_is_drilled_without_a_spot_and_a_deep_one_is_spotted():
    """The library's solid carbide drills keep their place by themselves in a hole a few diameters deep: only the
    hole deeper than ``spot_depth`` drill diameters is spotted first; with ``spot_depth`` 0, both are."""
    solid = plate((60.0, 40.0, 40.0)) - drilled(15, 20, 2.5, 30, 41) - drilled(45, 20, 2.5, 15, 41)
    setup, part = make_setup(manifold_to_trimesh(solid))
    top = float(setup.stock_max[2])
    for spot_depth, spotted in ((DrillingOptions().spot_depth, {45}), (0.0, {15, 45})):
        plan = plan_holes(part, setup, LIBRARY, LIBRARY.tool(2), DrillingOptions(spot_depth=spot_depth))
        drills = [op for op in plan.operations if op.kind == "drill"]
        assert {round(x - setup.transform_mesh_to_work[0, 3]) for x, _, _ in
                (row for op in drills for row in op.cycle.holes.tolist())} == {15, 45}
        deep = [top - z for op in drills for x, _, z in op.cycle.holes.tolist()]
        assert min(deep) < 5 * 5.0 < max(deep)  # one hole under 5 D, one over
        spots = [op for op in plan.operations if op.kind == "spot"]
        assert len(spots) == 1 and spots[0].tool.point_angle == 90.0
        assert {round(x - setup.transform_mesh_to_work[0, 3]) for x, _, _ in spots[0].cycle.holes.tolist()} == spotted
