"""G-code parser: what it reads, how it refuses, and that it never crashes."""

from __future__ import annotations

import math
import re
import shutil

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cadcam.gcode import parse_gcode
from cadcam.model import Motion
from factory.core.errors import GcodeError
from tests.rs274 import run_rs274


def _parse(text: str, **kw):
    return parse_gcode(text, source="t.nc", **kw)


def test_lines_comments_numbers_and_modes():
    prog = """%
O1234 (TEST)
N10 G21 G90 G17 G94 (mm, absolute) ; trailing
n20 g0 x1 y2 z3
N30 G1 X4 F100
Y5 Z-1.5 ; modal G1
G91 X1 Y-1
G90
G20 G0 X1
G21 G1 X0 Y0 Z0 F200
M30
G1 X999 (after the end: not read)
%
"""
    mv = _parse(prog)
    np.testing.assert_allclose(mv.points[0], [np.nan] * 3)
    expected = [[1, 2, 3], [4, 2, 3], [4, 5, -1.5], [5, 4, -1.5], [25.4, 4, -1.5], [0, 0, 0]]
    np.testing.assert_allclose(mv.points[1:], expected)
    assert mv.motion[1:].tolist() == [Motion.RAPID, Motion.CUT, Motion.CUT, Motion.CUT, Motion.RAPID, Motion.CUT]
    np.testing.assert_allclose(mv.feed[1:], [np.nan, 100, 100, 100, np.nan, 200])
    assert mv.line[1:].tolist() == [4, 5, 6, 7, 9, 10]


def test_unprogrammed_axes_stay_nan():
    mv = _parse("G0 X1\nG0 Y2\n")
    assert math.isnan(mv.points[1, 1]) and math.isnan(mv.points[1, 2])
    assert mv.points[2, 0] == 1 and math.isnan(mv.points[2, 2])


def _on_circle(pts, cx, cy, r, tol):
    d = np.hypot(pts[:, 0] - cx, pts[:, 1] - cy)
    return np.all(np.abs(d - r) <= tol)


@pytest.mark.parametrize("block", [
    "G2 X10 Y0 I5 J0",  # incremental centre (default G91.1)
    "G2 X10 Y0 R5",
    "G90.1 G2 X10 Y0 I5 J0",  # absolute centre
])
def test_half_circle_formats(block):
    mv = _parse(f"G0 X0 Y0 Z0\nG1 F100\n{block}\n", arc_tolerance=0.001)
    arc = mv.points[2:]
    assert _on_circle(arc, 5, 0, 5, 1e-9)
    # G2 from (0,0) to (10,0) about (5,0) goes over the top (clockwise seen from +Z).
    assert arc[:, 1].max() > 4.99
    np.testing.assert_allclose(arc[-1], [10, 0, 0], atol=1e-12)
    # Chord sagitta within tolerance: chord midpoints within tol of the circle.
    mids = 0.5 * (mv.points[1:-1] + mv.points[2:])
    assert np.all(5 - np.hypot(mids[:, 0] - 5, mids[:, 1]) <= 0.001 + 1e-12)


def test_r_format_long_arc_and_ccw():
    # Negative R: the long way round (> 180 deg).
    mv = _parse("G0 X0 Y0\nG3 X10 Y0 R-7 F100\n")
    arc = mv.points[2:]
    half = 5.0
    h = math.sqrt(49 - 25)
    # CCW from (0,0) to (10,0) the long way: centre below the chord, path round the bottom.
    assert _on_circle(arc, half, -h, 7, 1e-9)
    assert arc[:, 1].min() == pytest.approx(-h - 7, abs=1e-3)
    length = np.linalg.norm(np.diff(mv.points[1:, :2], axis=0), axis=1).sum()
    assert length > math.pi * 7


def test_full_circle_and_helix_with_turns():
    mv = _parse("G0 X10 Y0 Z0\nG3 X10 Y0 Z-2 I-10 J0 P2 F100\n")
    arc = mv.points[2:]
    assert _on_circle(arc, 0, 0, 10, 1e-9)
    ang = np.unwrap(np.arctan2(arc[:, 1], arc[:, 0]))
    assert ang[-1] == pytest.approx(4 * math.pi, abs=1e-9)
    # Z linear in angle.
    np.testing.assert_allclose(arc[:, 2], -2 * ang / (4 * math.pi), atol=1e-9)


def test_inch_arc():
    mv = _parse("G20 G0 X0 Y0\nG2 X1 Y0 I0.5 F10\n")
    assert _on_circle(mv.points[2:], 12.7, 0, 12.7, 1e-9)
    assert mv.feed[-1] == pytest.approx(254.0)


def test_arc_radius_rule_follows_linuxcnc():
    # 0.01 mm end-radius error is accepted (LinuxCNC accepts it: < 0.0283 mm) ...
    _parse("G0 X0 Y0\nG2 X10.01 Y0 I5 J0 F100\n")
    # ... 0.1 mm on a 5 mm radius is not (2 % and > 0.0283 mm).
    with pytest.raises(GcodeError, match="line 2: radius to end of arc differs"):
        _parse("G0 X0 Y0\nG2 X10.1 Y0 I5 J0 F100\n")


def test_tool_change_and_lengths():
    prog = "T1 M6\nG43 H1\nG0 X0 Y0 Z5\nT2\nG0 Z6\nM6\nG0 Z7\nG49\nG0 Z8\n"
    mv = _parse(prog)
    assert mv.tool[1:].tolist() == [1, 1, 2, 2]
    np.testing.assert_allclose(mv.points[1:, 2], [5, 6, 7, 8])  # compensation assumed to match
    lengths = {1: 40.0, 2: 30.0}
    mv = _parse(prog, tool_lengths=lengths)
    # H1 active with tool 1, then with tool 2 (10 mm shorter: tip 10 mm higher), then none.
    np.testing.assert_allclose(mv.points[1:, 2], [5, 6, 17, 8 - 30])
    with pytest.raises(GcodeError, match="line 2: G43 H3: no length"):
        _parse("T3 M6\nG43 H3\n", tool_lengths=lengths)


def test_grbl_style_tool_without_m6():
    mv = _parse("T3\nG0 X0 Y0 Z1\nT4\nM0\nG0 Z2\n")
    assert mv.tool[1:].tolist() == [3, 4]


def test_g53_and_g28_retract_to_top():
    prog = "G0 X1 Y2 Z10\nG1 Z-3 F100\nG53 G0 Z0\nG1 Z-1\nG28 G91 Z0\nG90 G0 Z5\n"
    mv = _parse(prog)
    np.testing.assert_allclose(mv.points[1:, 2], [10, -3, 10, -1, 10, 5])
    assert mv.motion[3] == Motion.RAPID and mv.motion[5] == Motion.RAPID
    # At the start nothing is known: no move at all, no error.
    assert len(_parse("G28 G91 Z0.\nG90\n").points) == 1


def test_block_delete():
    prog = "G0 X0 Y0 Z0\n/G0 X5\n"
    assert len(_parse(prog).points) == 3
    assert len(_parse(prog, block_delete=True).points) == 2


def test_dwell_and_path_modes_accepted():
    mv = _parse("G64 P0.01 Q0.01\nG61\nG61.1\nG4 P0.5\nG0 X1 Y1 Z1\nM3 S1000\nM8\nM7 M8\nM9 M5\nM1\nM2\n")
    assert len(mv.points) == 2


@pytest.mark.parametrize("prog, line, message", [
    ("G0 X0 Y0\nG18\n", 2, "only XY-plane arcs supported"),
    ("G19 G2 X1 Y1 R1\n", 1, "only XY-plane arcs supported"),
    ("G0 X0\nG1 X1\n", 2, "without a feed rate"),
    ("G0 G1 X1\n", 1, "two motion codes"),
    ("G0 X1 X2\n", 1, "appears twice"),
    ("G0 X1 A2\n", 1, "unsupported word A"),
    ("G0 X1..2\n", 1, "cannot read"),
    ("G0 X--1\n", 1, "cannot read"),
    ("G0 X1 (open comment\n", 1, "not closed"),
    ("G0 X1 (a (nested) one)\n", 1, "nested"),
    ("G0 X0 Y0\nG41\n", 2, "compensation"),
    ("G73 X1 Y1 Z-1 R1\n", 1, "canned cycle"),
    ("G82 X1 Y1 Z-1 R1 P1\n", 1, "canned cycle"),
    ("G0 X0 Y0 Z5\nG83 X1 Y1 Z-1 R1 F100\n", 2, "peck depth Q"),
    ("G0 X0 Y0 Z5\nG91 G81 X1 Y1 Z-1 R1 F100\n", 2, "incremental"),
    ("G92 X0\n", 1, "G92"),
    ("G0 X#1\n", 1, "parameters"),
    ("G0 X[1+2]\n", 1, "expressions"),
    ("o100 sub\n", 1, "O words"),
    ("X1 Y1\n", 1, "without a motion mode"),
    ("G0 X0 Y0\nG2 X1 Y1 F1\n", 2, "needs I/J or R"),
    ("G0 X0 Y0\nG2 X2 Y0 I1 R1 F1\n", 2, "both R and I/J"),
    ("G0 X0 Y0\nG2 X10 Y0 R2 F1\n", 2, "too small"),
    ("G0 X0 Y0\nG2 Z1 I1 F1\n", 2, "needs an X or Y"),
    ("G0 X0 Y0\nG2 X2 I1 K1 F1\n", 2, "K word"),
    ("G2 X1 Y0 I1 F10\n", 1, "unknown X/Y position"),
    ("G91 G0 X1\n", 1, "unknown position"),
    ("G0 X0 I1\n", 1, "I word"),
    ("G53 G0 X0\n", 1, "G53 supported only for a Z retract"),
    ("G28\n", 1, "G28 without Z"),
    ("G0 X1 H1\n", 1, "H word without G43"),
    ("M98 P100\n", 1, "unsupported code M98"),
    ("G12\n", 1, "unsupported code G12"),
    ("G0 X1 N10\n", 1, "first word"),
    ("G0 X1e5\n", 1, "unsupported word E"),
    ("G0 X" + "9" * 400 + "\n", 1, "out of range"),
    ("G0 X1\nG" + "9" * 320 + "\n", 2, "out of range"),
    ("G0 X200000\n", 1, "out of range"),
    ("G0 X1\n%junk\n", 2, "after '%'"),
    ("T1.5\n", 1, "whole number"),
    ("M3 M5\n", 1, "same modal group"),
])
def test_errors_name_the_line(prog, line, message):
    with pytest.raises(GcodeError) as ei:
        _parse(prog)
    e = ei.value
    assert e.data["line"] == line
    assert e.source == "t.nc"
    assert f"line {line}: " in str(e)
    assert message in str(e)


def test_progress_reaches_the_end():
    calls = []
    parse_gcode("G0 X0 Y0 Z0\n" * 12000, progress=lambda d, n: calls.append((d, n)))
    assert calls[-1] == (12000, 12000)
    assert all(a[0] <= b[0] for a, b in zip(calls, calls[1:]))


def test_arc_tolerance_must_be_positive():
    with pytest.raises(GcodeError):
        parse_gcode("G0 X1\n", arc_tolerance=0.0)


# --------------------------------------------------------------------------- fuzzing

_ANY_TEXT = st.text(alphabet=st.characters(codec="utf-8"), max_size=300)
_GCODE_CHARS = st.text(alphabet="GMXYZIJKRPQFSTHNO0123456789.-+ ()%;/#[]\n\t", max_size=300)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(_ANY_TEXT, _GCODE_CHARS, st.binary(max_size=200).map(lambda b: b.decode("latin-1"))))
def test_fuzz_text_raises_only_gcode_error(text):
    try:
        mv = parse_gcode(text)
    except GcodeError as e:
        assert "line" in e.data
        return
    assert mv.points.shape[1] == 3


_NUM = st.one_of(
    st.integers(-200, 200).map(str),
    st.floats(-500, 500, allow_nan=False).map(lambda v: f"{v:.4f}"),
    st.sampled_from(["0", "-0", ".5", "-.5", "1.", "0.0001", "1000000"]),
)
_G = st.sampled_from(["G0", "G1", "G2", "G3", "G17", "G20", "G21", "G90", "G91", "G90.1", "G91.1",
                      "G40", "G43", "G49", "G53", "G28", "G54", "G61", "G64", "G80", "G94", "G4", "G18"])
_M = st.sampled_from(["M0", "M1", "M3", "M5", "M6", "M8", "M9"])
_WORD = st.one_of(_G, _M, st.builds(lambda a, v: a + v, st.sampled_from(list("XYZIJRFSTHPQ")), _NUM))
_BLOCK = st.lists(_WORD, min_size=1, max_size=6).map(" ".join)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_BLOCK, min_size=1, max_size=25), st.booleans())
def test_fuzz_valid_ish_blocks(blocks, with_lengths):
    text = "G21 G90 G0 X0 Y0 Z0 F100\n" + "\n".join(blocks) + "\n"
    lengths = {i: 10.0 + i for i in range(0, 201)} if with_lengths else None
    try:
        mv = parse_gcode(text, tool_lengths=lengths)
    except GcodeError as e:
        assert 1 <= e.data["line"] <= len(blocks) + 1
        return
    n = len(mv.points)
    assert all(len(a) == n for a in (mv.motion, mv.tool, mv.feed, mv.line))
    known = ~np.isnan(mv.points[1:])
    assert np.isfinite(mv.points[1:][known]).all()
    cut = mv.motion[1:] == Motion.CUT
    assert np.all(mv.feed[1:][cut] > 0)


DRILL_PROGRAM = """G21 G90 G17 G94
T1 M6
G43 H1
G0 Z10
G0 X0 Y0
G99 G81 X5 Y5 Z-3 R1 F100
X10
G98 G83 X15 Y5 Z-5 R1 Q2
X20 Z-4.5 Q1.3
G80
G0 Z10
G0 X0 Y0 Z0.5
G98 G81 X25 Y5 Z-2 R2
G80
M30
"""


def _distinct(points: np.ndarray) -> np.ndarray:
    p = points[np.all(np.isfinite(points), axis=1)]
    keep = np.ones(len(p), dtype=bool)
    keep[1:] = np.any(np.abs(np.diff(p, axis=0)) > 1e-9, axis=1)
    return p[keep]


@pytest.mark.skipif(shutil.which("rs274") is None, reason="LinuxCNC's rs274 is not installed")
def test_drill_cycles_move_as_linuxcnc_moves_them(tmp_path):
    nc = tmp_path / "drill.ngc"
    nc.write_text(DRILL_PROGRAM)
    table = tmp_path / "drill.tbl"
    table.write_text("T1 P1 D3 Z30 ;drill\n")
    p = run_rs274(nc, table, tmp_path, timeout=60)
    assert p.returncode == 0, p.stdout[-1000:]
    theirs = []
    for m in re.finditer(r"STRAIGHT_(TRAVERSE|FEED)\(([-\d.]+), ([-\d.]+), ([-\d.]+)", p.stdout):
        theirs.append((float(m.group(2)), float(m.group(3)), float(m.group(4)), m.group(1) == "FEED"))
    theirs = np.array(theirs)
    moves = parse_gcode(DRILL_PROGRAM)
    ours = _distinct(np.column_stack([moves.points, moves.motion == Motion.CUT]))
    theirs = _distinct(theirs)
    # rs274 starts at the machine origin; the parser knows no position before the first X Y.
    start = int(np.flatnonzero(np.all(np.abs(theirs - ours[0]) < 1e-4, axis=1))[0])
    np.testing.assert_allclose(ours, theirs[start:], atol=1e-4)
    # Feeds: one per G81 hole (3), G83 pecks of 2 mm to -5 (3) and of 1.3 mm to -4.5 (5).
    assert (moves.motion == Motion.CUT).sum() == 11


@settings(max_examples=40, deadline=None)
@given(r=st.floats(0.5, 5.0), depth=st.floats(0.5, 30.0), q=st.floats(0.3, 8.0), start=st.floats(-3.0, 20.0),
       g99=st.booleans())
def test_peck_drilling_reaches_the_bottom_in_pecks_and_never_feeds_sideways(r, depth, q, start, g99):
    bottom = r - depth
    prog = (f"G0 X0 Y0 Z{start:.4f}\n{'G99' if g99 else 'G98'} G83 X3 Y4 Z{bottom:.4f} R{r:.4f} Q{q:.4f} F100\n"
            "G80\nM30\n")
    moves = parse_gcode(prog)
    p, feed = moves.points, moves.motion == Motion.CUT
    a, b = p[:-1], p[1:]
    cut = feed[1:]
    assert np.allclose(b[cut, :2], [3.0, 4.0]) and np.allclose(a[cut, :2], [3.0, 4.0])
    assert np.all(b[cut, 2] < a[cut, 2])  # every feed goes down
    rr, zz, qq = (round(v, 4) for v in (r, bottom, q))
    assert p[-1, 2] == pytest.approx(rr if g99 else max(rr, round(start, 4)))
    assert np.min(b[cut, 2]) == pytest.approx(zz)
    assert int(cut.sum()) == math.ceil((rr - zz) / qq - 1e-9)
    # A peck removes at most Q of new depth (plus the clearance it re-enters above the last one).
    assert np.all(a[cut, 2] - b[cut, 2] <= qq + 0.254 + 1e-6)


# --------------------------------------------------------------------------- the plain lane

# Plain straight moves (G0/G1 with X Y Z and F, as the posts write most of a program), which the parser moves
# together, mixed with every block that changes what they mean: modes, units, tool lengths, arcs, cycles,
# refusals (no motion mode, no feed, numbers and coordinates out of range).
_PLAIN_NUM = st.one_of(_NUM, st.sampled_from(["99999", "-100001", "1" + "0" * 10, "4000"]))
_PLAIN = st.builds(
    lambda g, x, y, z, f, gap: gap.join(w for w in (g, x, y, z, f) if w),
    st.sampled_from(["", "", "G0", "G1", "G00", "G01"]),
    st.one_of(st.just(""), _PLAIN_NUM.map("X{}".format)),
    st.one_of(st.just(""), _PLAIN_NUM.map("Y{}".format)),
    st.one_of(st.just(""), _PLAIN_NUM.map("Z{}".format)),
    st.one_of(st.just(""), st.sampled_from(["F0", "F100", "F.5", "F2500.", "F" + "9" * 11]), st.just("")),
    st.sampled_from([" ", "", "\t "]))
_OTHER = st.sampled_from([
    "G90", "G91", "G20", "G21", "T1 M6", "T2 M6", "T7", "G43 H1", "G43", "G49", "(a comment)", "", "   ",
    "N10 G1 X1", "g1 x2", "G2 X1 Y0 I.5 J0", "G3 X0 Y0 R.5", "G2 X2 Y2 I1 J1", "G53 Z0", "G28 Z0",
    "G81 Z-1 R1 F50", "G80", "F-1", "G1 F0", "M2", "G0", "G1 X1 (moved)", "/G0 X5", "G1 X1 Y1 Z1 F1 S100"])


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.one_of(_PLAIN, _PLAIN, _OTHER, st.sampled_from(["G53 Z0", "G28 Z0"])), min_size=1, max_size=40),
       st.booleans(), st.booleans())
def test_plain_moves_parse_as_block_by_block(lines, with_lengths, start_known):
    """The plain lane reads every program as the general path reads it block by block: the same moves to the
    bit (points, motion, tool, feed, line), or the same refusal of the same line."""
    import cadcam.gcode as gcode

    text = ("G21 G90 G0 X0 Y0 Z0 F100\n" if start_known else "") + "\n".join(lines) + "\n"
    lengths = {1: 10.0, 2: 20.5} if with_lengths else None

    def parsed():
        try:
            mv = parse_gcode(text, source="t.nc", tool_lengths=lengths)
        except GcodeError as e:
            return str(e), e.data["line"], e.source
        return tuple(a.dtype.str + a.tobytes().hex() for a in (mv.points, mv.motion, mv.tool, mv.feed, mv.line))

    fast = parsed()
    with pytest.MonkeyPatch.context() as m:  # every block by the general path
        m.setattr(gcode, "_plain_blocks", lambda lines: gcode._PlainBlocks(
            np.zeros(0, np.int64), np.zeros((0, 5)), np.zeros((0, 5), np.int64)))
        general = parsed()
    assert fast == general


def test_the_posts_moves_take_the_plain_lane(monkeypatch):
    """A posted program's straight moves are read all at once, not block by block (what makes the lane worth
    having), and the program parses to the same moves as block by block."""
    import cadcam.gcode as gcode

    text = "G21 G90 G17 G94\nT1 M6\nG43 H1\nG0 Z5\nX1 Y2\nG1 Z-1 F300\n" + "".join(
        f"X{i * 0.1:.4f} Y{(i % 7) * 0.3:.4f} Z-1.{i % 10}\n" for i in range(500)) + "G1 X1 Y0\nG3 X-1 Y0 I-1 J0\nG1 X3\nM30\n"
    one_by_one = []
    real = gcode._execute
    monkeypatch.setattr(gcode, "_execute", lambda b, *a, **k: (one_by_one.append(b), real(b, *a, **k))[1])
    mv = parse_gcode(text)
    assert len(one_by_one) == 5  # G21 .., T1 M6, G43 H1, G3, M30: the straight moves between them were not
    assert len(mv.points) == 1 + 3 + 500 + 1 + np.count_nonzero(mv.line == 508) + 1
    np.testing.assert_array_equal(mv.points[-1], [3.0, 0.0, -1.9])
