"""Post-processors: programs round-trip through the parser, LinuxCNC accepts them,
each dialect keeps its controller's syntax rules, and time estimates add up."""

from __future__ import annotations

import dataclasses
import math
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from tests.geometry import point_polyline_distance
from tests.rs274 import run_rs274, write_tool_table
from cadcam.gcode import parse_gcode
from cadcam.model import CuttingData, Job, Motion, Operation, Setup, Tool
from cadcam.post import PostOptions, linuxcnc_tool_table, post_process, tool_table_file
from factory.core.errors import GcodeError

FLAT = Tool(1, "6 mm flat 3FL (carbide)", "flat", 6.0, 0.0, 20.0, 3, 40.0)
BALL = Tool(4, "3 mm ball", "ball", 3.0, 1.5, 10.0, 2, 30.0)
#: A tool whose name LinuxCNC would cut, with figures that are not whole millimetres.
DRILL = Tool(7, "8.5 mm drill 118deg carbide 5xD (M10 tap)", "drill", 8.5, 0.0, 40.0, 2, 45.25, point_angle=118.0)
CUT = CuttingData(spindle_rpm=12000, feed=1200, plunge_feed=300)
SLOW = CuttingData(spindle_rpm=18000.4, feed=800, plunge_feed=200)
SETUP = Setup([0, 0, -20], [80, 60, 0], np.eye(4), safe_z=10.0)
DIALECTS = ("linuxcnc", "fanuc", "grbl")
CHORD = 0.001  # parser chord tolerance [mm]


def _pocket_op() -> Operation:
    """Helix entry, a circle at depth, a spiral-out step, lines, a rapid hop, a zigzag."""
    pts: list[np.ndarray] = []
    mot: list[np.ndarray] = []

    def add(p, m):
        p = np.atleast_2d(np.asarray(p, dtype=float))
        pts.append(p)
        mot.append(np.full(len(p), int(m)))

    cx, cy, r = 20.0, 20.0, 4.0
    add([cx + r, cy, 1.0], Motion.RAPID)
    th = np.linspace(0, -4 * np.pi, 240)[1:]  # clockwise helix, two turns, 1 -> -3
    add(np.c_[cx + r * np.cos(th), cy + r * np.sin(th), 1.0 - 4.0 * th / (-4 * np.pi)], Motion.PLUNGE)
    th = np.linspace(0, 2 * np.pi, 181)[1:]  # full counter-clockwise circle at depth
    add(np.c_[cx + r * np.cos(th), cy + r * np.sin(th), np.full(len(th), -3.0)], Motion.CUT)
    add([[cx + 7, cy, -3.0]], Motion.CUT)
    th = np.linspace(0, np.pi / 2, 91)[1:]  # quarter circle, r = 7
    add(np.c_[cx + 7 * np.cos(th), cy + 7 * np.sin(th), np.full(len(th), -3.0)], Motion.CUT)
    add([[cx, cy + 7, 2.0], [50, 10, 2.0]], Motion.RAPID)
    add([[50, 10, -2.0]], Motion.PLUNGE)
    zig = [[50 + 20 * (k % 2 == 0), 10 + 1.5 * k, -2.0] for k in range(1, 8)]
    add([[70, 10, -2.0]] + zig, Motion.CUT)
    return Operation("rough pocket", "roughing", FLAT, CUT, np.vstack(pts), np.concatenate(mot))


def _raster_op(tool: Tool, cutting: CuttingData, name: str) -> Operation:
    x = np.linspace(5, 75, 36)
    pts = [[5, 45, 1.0], [5, 45, -0.5]]
    mot = [Motion.RAPID, Motion.PLUNGE]
    for k, y in enumerate((45.0, 47.0, 49.0)):
        xs = x if k % 2 == 0 else x[::-1]
        # A surface that undulates in Z: not collinear, so stays lines (or small arcs).
        for xi in xs:
            pts.append([xi, y, -0.5 - 0.3 * math.sin(xi / 7.0)])
            mot.append(Motion.CUT)
    return Operation(name, "raster", tool, cutting, pts, mot)


def _job() -> Job:
    return Job(
        part_name="bracket (v2)",
        setup=SETUP,
        operations=(_pocket_op(), _raster_op(FLAT, CUT, "raster same tool"),
                    _raster_op(BALL, SLOW, "finish raster ball")),
        source_sha256="0123456789abcdef" * 4,
    )


# --------------------------------------------------------------------------- helpers


def _op_line_ranges(text: str) -> list[tuple[int, int]]:
    """1-based [first, next) line ranges of each operation, from its ``(op k:`` comment."""
    lines = text.splitlines()
    starts = [i + 1 for i, s in enumerate(lines) if re.match(r"\(op \d+:", s, re.I)]
    return list(zip(starts, starts[1:] + [len(lines) + 1]))


def _code(text: str) -> list[str]:
    """Program lines with comments removed."""
    return [re.sub(r"\([^)]*\)", "", s).strip() for s in text.splitlines()]


# --------------------------------------------------------------------------- round trip


@pytest.mark.parametrize("dialect", DIALECTS)
@pytest.mark.parametrize("arcs", [True, False])
def test_round_trip_through_parser(dialect, arcs):
    job = _job()
    opt = PostOptions(dialect=dialect, arcs=arcs)
    prog = post_process(job, opt)
    mv = parse_gcode(prog.text, source=f"{dialect}.nc", arc_tolerance=CHORD)
    # Fitting tolerance + chord sagitta + rounding to 4 decimals (+ 5 % sampling slack).
    tol = opt.arc_tolerance * 1.05 + CHORD + 1e-4
    ranges = _op_line_ranges(prog.text)
    assert len(ranges) == len(job.operations)
    for k, (op, (lo, hi)) in enumerate(zip(job.operations, ranges)):
        sel = np.flatnonzero((mv.line >= lo) & (mv.line < hi))
        known = np.isfinite(mv.points[sel]).all(axis=1)
        # Only the very first move (up to the safe height, X and Y not yet known) has NaN.
        assert known[1:].all() and (known[0] or k == 0)
        sel = sel[known]
        path = mv.points[sel]
        # Every cutter location lies on the parsed path.
        assert point_polyline_distance(op.points, path).max() <= tol
        # Every parsed point lies on the job's polyline, or at the safe height (approach,
        # retract) straight above the operation's first/last point.
        d = point_polyline_distance(mv.points[sel], op.points)
        at_safe = np.isclose(mv.points[sel, 2], SETUP.safe_z)
        assert np.all((d <= tol) | at_safe)
        # Feeds are the operation's, rapids carry none; the right tool is in the spindle.
        cut = mv.motion[sel] == Motion.CUT
        assert set(np.round(mv.feed[sel][cut], 6)) <= {op.cutting.feed, op.cutting.plunge_feed}
        assert np.isnan(mv.feed[sel][~cut]).all()
        # (Fanuc's "G28 G91 Z0." retract before the tool change still has the old tool.)
        code = _code(prog.text)
        after_change = np.array(["G28" not in code[ln - 1] for ln in mv.line[sel]])
        assert np.all(mv.tool[sel][after_change] == op.tool.number)
        # Feed moves happen only where the job feeds: parsed CUT points are near feed segments.
        feed_seg = op.motion[1:] != Motion.RAPID
        pieces = [op.points[i:i + 2] for i in np.flatnonzero(feed_seg)]
        dmin = np.min([point_polyline_distance(mv.points[sel][cut], p) for p in pieces], axis=0)
        assert dmin.max() <= tol
    # The program ends up, above everything.
    assert mv.points[-1, 2] >= SETUP.safe_z


def test_arcs_shorten_the_program():
    job = _job()
    with_arcs = post_process(job)
    lines_only = post_process(job, PostOptions(arcs=False))
    assert with_arcs.line_count < lines_only.line_count - 300
    assert with_arcs.moves_before_fitting == lines_only.moves_before_fitting == sum(
        len(op.points) - 1 for op in job.operations)
    assert re.search(r"^G2 .*Z", with_arcs.text, re.M)  # the helix, clockwise
    assert re.search(r"^G3 ", with_arcs.text, re.M)


def test_progress_reaches_the_end():
    calls = []
    job = _job()
    prog = post_process(job, progress=lambda d, n: calls.append((d, n)))
    assert calls[-1] == (prog.moves_before_fitting, prog.moves_before_fitting)
    assert all(a[0] <= b[0] for a, b in zip(calls, calls[1:]))


def test_deterministic():
    for d in DIALECTS:
        a = post_process(_job(), PostOptions(dialect=d)).text
        b = post_process(_job(), PostOptions(dialect=d)).text
        assert a == b


# --------------------------------------------------------------------------- LinuxCNC


def _rs274(tmp_path: Path, text: str, name: str) -> subprocess.CompletedProcess:
    if shutil.which("rs274") is None:
        pytest.skip("LinuxCNC's rs274 interpreter is not on PATH")
    nc = tmp_path / name
    nc.write_text(text)
    return run_rs274(nc, write_tool_table(nc, _job().tools), tmp_path, timeout=60)


_CANON = re.compile(r"(STRAIGHT_TRAVERSE|STRAIGHT_FEED|ARC_FEED)\(([^)]*)\)")


@pytest.mark.parametrize("work_offset", [1, 2], ids=["G54", "G55"])
@pytest.mark.parametrize("dialect", ["linuxcnc", "fanuc"])
def test_linuxcnc_interpreter_accepts(tmp_path, dialect, work_offset):
    """rs274 accepts the program, in op 1's work offset and op 2's. Fanuc programs happen to be
    valid RS274/NGC too (``%`` bounds, the ``O`` number alone on its line, ``G28 G91 Z0.``)."""
    prog = post_process(_job(), PostOptions(dialect=dialect, work_offset=work_offset))
    res = _rs274(tmp_path, prog.text, f"{dialect}.nc")
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    assert "PROGRAM_END" in res.stdout


def test_linuxcnc_interpreter_agrees_with_our_parser(tmp_path):
    """LinuxCNC's canonical moves end where our parser's blocks end, arcs turn the same way."""
    prog = post_process(_job(), PostOptions(dialect="linuxcnc"))
    res = _rs274(tmp_path, prog.text, "linuxcnc.nc")
    assert res.returncode == 0
    theirs, arcs = [], []
    for kind, args in _CANON.findall(res.stdout):
        v = [float(a) for a in args.split(",")]
        theirs.append((v[0], v[1], v[5]) if kind == "ARC_FEED" else tuple(v[:3]))
        if kind == "ARC_FEED":
            arcs.append(v)
    # The final G53 G0 Z0 goes where rs274's machine configuration says: not compared.
    code = _code(prog.text)
    assert code[-2] == "M30" or code[-1] == "M30"
    theirs = np.array(theirs[:-1])
    ours = parse_gcode(prog.text)
    blocks = [ln for ln in dict.fromkeys(ours.line[1:].tolist()) if "G53" not in code[ln - 1]]
    ends = np.array([ours.points[np.flatnonzero(ours.line == ln)[-1]] for ln in blocks])
    assert theirs.shape == ends.shape
    known = np.isfinite(ends)  # rs274 starts at 0,0,0 where we say "unknown"
    np.testing.assert_allclose(theirs[known], ends[known], atol=1e-4)
    # ARC_FEED rotation is -1 for G2 and +1 for G3; centres agree with the I/J we wrote.
    arc_lines = [s for s in code if s.startswith(("G2 ", "G3 "))]
    assert len(arcs) == len(arc_lines) > 0
    assert [a[4] < 0 for a in arcs] == [s.startswith("G2 ") for s in arc_lines]


# --------------------------------------------------------------------------- dialect rules

_WORDS = re.compile(r"([A-Z])(-?[\d.]+)")


@pytest.mark.parametrize("dialect", DIALECTS)
def test_number_format(dialect):
    text = post_process(_job(), PostOptions(dialect=dialect)).text
    for line in _code(text):
        for letter, num in _WORDS.findall(line):
            assert num not in ("-0", "-0.", "-.0"), line
            assert not re.fullmatch(r"-?0\d.*", num) or num.startswith("0."), line
            if "." in num:
                assert not num.endswith("0"), line  # trailing zeros trimmed
                assert len(num.split(".")[1]) <= 4, line
            if dialect == "fanuc" and letter in "XYZIJRF":
                assert "." in num, line  # X10. not X10 (Fanuc reads X10 as 0.010 mm)
            if dialect != "fanuc" and letter in "XYZIJ":
                assert not num.endswith("."), line


def test_fanuc_program_structure():
    text = post_process(_job(), PostOptions(dialect="fanuc", program_number=42)).text
    lines = text.splitlines()
    assert lines[0] == "%" and lines[-1] == "%"
    assert lines[1].startswith("O0042 (BRACKET [V2])")
    assert "M30" in lines[-3:]
    assert "G28 G91 Z0." in lines
    # Tool change: home Z first, then T M6, then G43 H on the first Z move.
    i = lines.index("T4 M6")
    assert lines[i - 2:i] == ["G28 G91 Z0.", "G90"]
    assert any(re.fullmatch(r"G43 H4 Z10\.", s) for s in lines[i:i + 6])
    for s in lines:
        if s.startswith("("):
            assert s == s.upper()


@pytest.mark.parametrize("work_offset", [1, 2], ids=["G54", "G55"])
def test_grbl_uses_only_grbl_codes(work_offset):
    text = post_process(_job(), PostOptions(dialect="grbl", work_offset=work_offset)).text
    grbl_g = {"0", "1", "2", "3", "4", "10", "17", "18", "19", "20", "21", "28", "28.1", "30", "30.1",
              "38.2", "38.3", "38.4", "38.5", "40", "43.1", "49", "53", "54", "55", "56", "57", "58",
              "59", "61", "80", "90", "91", "91.1", "92", "92.1", "93", "94"}
    grbl_m = {"0", "1", "2", "30", "3", "4", "5", "7", "8", "9"}
    for line in _code(text):
        assert not line.startswith(("%", "O")), line
        for letter, num in _WORDS.findall(line):
            if letter == "G":
                assert num in grbl_g, line
            if letter == "M":
                assert num in grbl_m, line
            assert letter != "H", line
    # Manual tool change: stop, name the tool, pause.
    assert re.search(r"^M5\nM9\n\(change to T4 3 mm ball.*\)\nT4\nM0$", text, re.M)


def test_linuxcnc_header_and_tool_change():
    text = post_process(_job(), PostOptions(arc_tolerance=0.005)).text
    lines = text.splitlines()
    assert lines[0] == "(part bracket [v2])"
    assert "(source sha256 " + "0123456789abcdef" * 4 + ")" in lines
    for word in ("G21", "G90", "G17", "G40", "G49", "G80", "G94", "G54", "G64 P0.005"):
        assert any(re.search(rf"(^|\s){re.escape(word)}(\s|$)", s) for s in lines[:12]), word
    # Same tool twice: one tool change for T1, one for T4.
    assert lines.count("T1 M6") == 1 and lines.count("T4 M6") == 1
    i = lines.index("T4 M6")
    assert lines[i + 1] == "G43 H4"
    assert lines[i - 2:i] == ["M5", "M9"]
    assert "S18000 M3" in lines
    assert lines[-3:] == ["M9", "G53 G0 Z0", "M30"]


def test_feed_written_only_when_it_changes():
    text = post_process(_job()).text
    feeds = [m.group(1) for s in _code(text) for m in [re.search(r"F([\d.]+)", s)] if m]
    assert all(a != b for a, b in zip(feeds, feeds[1:]))
    # Every feed move after a tool change has a feed in force (the parser would refuse).
    parse_gcode(text)


def test_no_coolant():
    text = post_process(_job(), PostOptions(coolant=False)).text
    assert not re.search(r"\bM[789]\b", "\n".join(_code(text)))


def test_tool_table():
    tbl = linuxcnc_tool_table([BALL, FLAT, FLAT])
    assert tbl.splitlines() == ["T1 P1 D6 Z40 ;6 mm flat 3FL (carbide)", "T4 P4 D3 Z30 ;3 mm ball"]
    # LinuxCNC keeps 39 characters of a name (and warns about the rest): cut here
    assert linuxcnc_tool_table([DRILL]) == "T7 P7 D8.5 Z45.25 ;8.5 mm drill 118deg carbide 5xD (M10 ta\n"


def test_only_linuxcnc_reads_a_tool_table_file():
    assert tool_table_file(PostOptions(dialect="linuxcnc"), [FLAT]) == linuxcnc_tool_table([FLAT])
    assert tool_table_file(PostOptions(dialect="grbl"), [FLAT]) is None  # grbl has no tool table
    assert tool_table_file(PostOptions(dialect="fanuc"), [FLAT]) is None  # offsets set at the control


def test_one_number_for_two_tools_is_refused():
    other = dataclasses.replace(BALL, number=FLAT.number)
    with pytest.raises(GcodeError, match="T1 names two tools"):
        linuxcnc_tool_table([FLAT, other])
    assert linuxcnc_tool_table([FLAT, dataclasses.replace(FLAT)]) == linuxcnc_tool_table([FLAT])


_DEBUG = re.compile(r'MESSAGE\(" ?T([\d.]+) D([\d.]+) Z([\d.]+)"\)')


def test_linuxcnc_reads_the_tool_table_as_written(tmp_path):
    """rs274 loads every line of the table (a line it cannot read fails run_rs274) and holds each tool's
    number, diameter and length offset as written: the program reads them back from its parameters
    (#5400 tool, #5410 diameter, #5403 Z offset, in force after G43)."""
    if shutil.which("rs274") is None:
        pytest.skip("LinuxCNC's rs274 interpreter is not on PATH")
    tools = [FLAT, BALL, DRILL]
    nc = tmp_path / "tools.nc"
    nc.write_text("G21 G90\n" + "".join(f"T{t.number} M6\nG43 H{t.number}\n(debug, T#5400 D#5410 Z#5403)\n"
                                         for t in tools) + "M30\n")
    res = run_rs274(nc, write_tool_table(nc, tools), tmp_path, timeout=60)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    read = [tuple(float(v) for v in m) for m in _DEBUG.findall(res.stdout)]
    assert read == [(t.number, t.diameter, t.length) for t in tools]


def test_linuxcnc_refuses_a_program_whose_tool_the_table_lacks(tmp_path):
    """The job's program with a table that lacks one of its tools (T4) stops at that tool: what the
    tests' rs274 runs rely on to show the table covers the program."""
    if shutil.which("rs274") is None:
        pytest.skip("LinuxCNC's rs274 interpreter is not on PATH")
    nc = tmp_path / "job.nc"
    nc.write_text(post_process(_job()).text)
    res = run_rs274(nc, write_tool_table(nc, [FLAT]), tmp_path, timeout=60)
    assert res.returncode != 0
    assert "Requested tool 4 not found in the tool table" in res.stdout + res.stderr
    assert "PROGRAM_END" not in res.stdout
    res = run_rs274(nc, write_tool_table(nc, [FLAT, BALL]), tmp_path, timeout=60)
    assert res.returncode == 0 and "PROGRAM_END" in res.stdout


# --------------------------------------------------------------------------- estimates


def test_time_estimate_by_hand():
    pts = [[0, 0, 1], [0, 0, -1], [30, 0, -1], [30, 40, -1], [30, 40, 5]]
    mot = [Motion.RAPID, Motion.PLUNGE, Motion.CUT, Motion.CUT, Motion.RAPID]
    cd = CuttingData(10000, feed=600, plunge_feed=200)
    op1 = Operation("pocket", "roughing", FLAT, cd, pts, mot)
    # Second op, other tool: a half circle of radius 10 at 600 mm/min, starting at (50, 0).
    th = np.linspace(0, np.pi, 181)
    semi = np.c_[40 + 10 * np.cos(th), 10 * np.sin(th), np.full_like(th, -1.0)]
    op2 = Operation("arc", "waterline", BALL, cd, semi, [Motion.RAPID] + [Motion.CUT] * 180)
    job = Job("t", SETUP, (op1, op2))
    opt = PostOptions(rapid_rate=6000.0, tool_change_time=10.0)
    prog = post_process(job, opt)
    e1, e2 = prog.estimates
    assert e1.cut_length == pytest.approx(2 + 30 + 40)
    assert e1.cut_time == pytest.approx(2 / 200 * 60 + 70 / 600 * 60)
    # Down from safe Z 10 to 1, the hop up to 5, the retract 5 -> 10.
    assert e1.rapid_length == pytest.approx(9 + 6 + 5)
    assert e1.rapid_time == pytest.approx(20 / 6000 * 60)
    # After a tool change the XY traverse is from an unknown place: not counted.
    assert e2.cut_length == pytest.approx(10 * math.pi, rel=1e-9)
    assert e2.cut_time == pytest.approx(10 * math.pi / 600 * 60, rel=1e-9)
    assert e2.rapid_length == pytest.approx(11 + 11)
    total = e1.cut_time + e1.rapid_time + e2.cut_time + e2.rapid_time + 2 * 10.0
    assert prog.total_time == pytest.approx(total)
    assert e1.tool_number == 1 and e2.tool_number == 4
    assert sum(e.lines for e in prog.estimates) < prog.line_count
    assert prog.line_count == len(prog.text.splitlines())
    # The arc came out as one G3 (half circle), so its time is by arc length.
    assert len(re.findall(r"^G3 ", prog.text, re.M)) == 1


def test_same_tool_traverse_is_counted():
    cd = CuttingData(10000, feed=600, plunge_feed=200)
    a = Operation("a", "raster", FLAT, cd, [[0, 0, 0], [10, 0, 0]], [0, 1])
    b = Operation("b", "raster", FLAT, cd, [[10, 20, 0], [0, 20, 0]], [0, 1])
    prog = post_process(Job("t", SETUP, (a, b)), PostOptions(tool_change_time=5.0))
    assert prog.estimates[1].rapid_length == pytest.approx(20 + 10 + 10)
    assert prog.total_time == pytest.approx(sum(e.cut_time + e.rapid_time for e in prog.estimates) + 5.0)


# --------------------------------------------------------------------------- errors


def test_bad_jobs_and_options():
    with pytest.raises(GcodeError, match="no operations"):
        post_process(Job("t", SETUP, ()))
    bad = Operation("x", "raster", FLAT, CuttingData(1000, 0.0, 100), [[0, 0, 0], [1, 0, 0]], [0, 1])
    with pytest.raises(GcodeError, match="feed must be positive") as ei:
        post_process(Job("t", SETUP, (bad,)))
    assert "operation 1 (x)" in str(ei.value)
    nan = Operation("x", "raster", FLAT, CUT, [[0, 0, 0], [np.nan, 0, 0]], [0, 1])
    with pytest.raises(GcodeError, match="NaN"):
        post_process(Job("t", SETUP, (nan,)))
    for kw in ({"dialect": "mach3"}, {"decimals": 1}, {"program_number": 0}, {"arc_tolerance": -1.0},
               {"rapid_rate": 0.0}):
        with pytest.raises(GcodeError):
            PostOptions(**kw)


@pytest.mark.parametrize("dialect", DIALECTS)
def test_work_offset_is_the_fixture_the_program_runs_in(dialect):
    """Op 2 of a part turned over runs in G55: G54..G59 are read by LinuxCNC, Fanuc and grbl 1.1 alike."""
    op1 = _code(post_process(_job(), PostOptions(dialect=dialect)).text)
    op2 = _code(post_process(_job(), PostOptions(dialect=dialect, work_offset=2)).text)
    assert "G54" in op1 and "G55" not in op1
    assert "G55" in op2 and "G54" not in op2
    assert [ln for ln in op1 if ln != "G54"] == [ln for ln in op2 if ln != "G55"]
    for bad in (0, 7):
        with pytest.raises(GcodeError, match="work_offset"):
            PostOptions(dialect=dialect, work_offset=bad)



def test_fitting_in_worker_processes_writes_the_same_program(monkeypatch):
    """Operations fitted in forked processes give the serial program, progress to the end."""
    import cadcam.parallel
    import cadcam.post

    job = _job()
    serial = post_process(job, PostOptions(dialect="linuxcnc"))
    monkeypatch.setattr(cadcam.post, "_PARALLEL_FIT_MOVES", 0)
    monkeypatch.setenv(cadcam.parallel.THREADS_ENV, "2")
    calls = []
    parallel = post_process(job, PostOptions(dialect="linuxcnc"), progress=lambda d, n: calls.append((d, n)))
    assert parallel.text == serial.text
    assert calls[-1] == (parallel.moves_before_fitting, parallel.moves_before_fitting)
    assert all(a[0] <= b[0] for a, b in zip(calls, calls[1:]))


def test_op2_program_numbers_its_operations_as_op_2():
    """Op 2's program (``parameters["op"] == 2``) says op 2 in every operation comment, under its
    "op 2: part turned over" note; the code itself is the same as the job posted without it, and
    verify still reads each comment's kind (a finishing tool stays a finishing tool)."""
    from cadcam.verify import finishing_moves

    plain = _job()
    op2 = dataclasses.replace(plain, parameters={"op": 2, "setup_note": "op 2: part turned over"})
    for d in DIALECTS:
        a = post_process(plain, PostOptions(dialect=d)).text
        b = post_process(op2, PostOptions(dialect=d)).text
        comments = [s for s in b.splitlines() if re.match(r"[(;]\s*op \d", s, re.I)]
        assert [re.match(r"[(;]\s*op ([\d.]+)", s, re.I).group(1) for s in comments][1:] == ["2.1", "2.2", "2.3"], d
        assert not re.search(r"op 1\b", b, re.I), d
        assert [s for s in _code(b) if s] == [s for s in _code(a) if s], d
    a, b = post_process(plain, PostOptions()).text, post_process(op2, PostOptions()).text
    fin = finishing_moves(b, parse_gcode(b))
    assert fin.tolist() == finishing_moves(a, parse_gcode(a)).tolist()
    assert fin.any() and not fin.all()
