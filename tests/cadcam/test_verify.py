"""Material-removal simulation: exact swept envelopes, gouges, rapid crashes, remaining stock."""

from __future__ import annotations

import json
import re
from unittest import mock

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam import stock
from cadcam.model import Motion, ProgramMoves, Setup, Tool
from cadcam.rest import _grown
from cadcam.envelope import swept_envelope
from cadcam.preview import deviation_image
from cadcam.verify import VerifyOptions, simulate
from tests.cadcam.sweep import sweep_moves
from factory.core.errors import VerifyError
from factory.pictures import png_bytes

FLAT = Tool(1, "6 mm flat", "flat", 6.0, 0.0, 20.0, 3, 40.0)
BALL = Tool(2, "6 mm ball", "ball", 6.0, 3.0, 20.0, 2, 40.0)
BULL = Tool(3, "6 mm bull r1", "bull", 6.0, 1.0, 20.0, 3, 40.0)
FACE = Tool(4, "10 mm flat", "flat", 10.0, 0.0, 20.0, 3, 40.0)
TOOLS = {t.number: t for t in (FLAT, BALL, BULL, FACE)}
SHAPES = {"flat": FLAT, "ball": BALL, "bull": BULL}

# Stock 40 x 20 x 10 mm, origin top-front-left; the part is a box sitting on the stock bottom.
SETUP = Setup(stock_min=[0, 0, -10], stock_max=[40, 20, 0], transform_mesh_to_work=np.eye(4))


def box(lo, hi) -> np.ndarray:
    return trimesh.creation.box(bounds=[lo, hi]).triangles


LOW_PART = box([10, 5, -10], [30, 15, -5])  # top at z = -5


def program(blocks, start=None):
    """ProgramMoves from ``[(motion, tool, (x, y, z)), ...]``; block k is source line k + 1."""
    n = len(blocks) + 1
    points = np.full((n, 3), np.nan)
    if start is not None:
        points[0] = start
    motion = np.zeros(n, np.int8)
    tool = np.zeros(n, np.int32)
    line = np.arange(n, dtype=np.int32)
    for k, (m, t, p) in enumerate(blocks, start=1):
        points[k] = p
        motion[k], tool[k] = m, t
    feed = np.where(motion == Motion.RAPID, np.nan, 500.0)
    return ProgramMoves(points, motion, tool, feed, line)


R, C = Motion.RAPID, Motion.CUT


def grid_xy(sim):
    return np.meshgrid(sim.grid.xs, sim.grid.ys)


def dist_to_segment(X, Y, a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    d = b[:2] - a[:2]
    t = np.clip(((X - a[0]) * d[0] + (Y - a[1]) * d[1]) / max(d @ d, 1e-300), 0, 1)
    return np.hypot(X - a[0] - t * d[0], Y - a[1] - t * d[1])


# --- the swept envelope of one move ---------------------------------------------------


def brute_envelope(q, p0, p1, tool, n=4001):
    """Minimum over densely sampled t, refined once around the best sample."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)

    def f(t):  # (k, m)
        P = p0 + t[..., None] * (p1 - p0)
        r = np.hypot(q[:, None, 0] - P[..., 0], q[:, None, 1] - P[..., 1])
        return P[..., 2] + tool.profile_height(r)

    t = np.broadcast_to(np.linspace(0, 1, n), (len(q), n))
    v = f(t)
    best = t[np.arange(len(q)), np.argmin(v, axis=1)]
    fine = np.clip(best[:, None] + np.linspace(-1, 1, n)[None, :] / (n - 1), 0, 1)
    return np.minimum(v.min(axis=1), f(fine).min(axis=1))


coord = st.floats(-4, 4, allow_nan=False, allow_infinity=False)


@settings(max_examples=40, deadline=None)
@given(
    shape=st.sampled_from(sorted(SHAPES)),
    p0=st.tuples(coord, coord, coord),
    p1=st.tuples(coord, coord, coord),
    seed=st.integers(0, 2**32 - 1),
)
def test_sloped_move_envelope_matches_dense_sampling(shape, p0, p1, seed):
    tool = SHAPES[shape]
    q = np.random.default_rng(seed).uniform(-8, 8, (300, 2))
    exact = swept_envelope(q, p0, p1, tool)
    brute = brute_envelope(q, p0, p1, tool)
    reached = np.isfinite(brute)
    assert np.all(np.isfinite(exact[reached])), "a point the tool passes over was missed"
    # Sampling can only miss the minimum: the exact envelope is never above it ...
    assert np.all(exact[reached] <= brute[reached] + 1e-9)
    # ... and the dense sampling gets within a hair of it.
    assert np.all(brute[reached] - exact[reached] <= 2e-5)
    # Only a sliver at the tool's reach can be finite without sampling landing on it.
    assert np.all(exact[~reached] == np.inf) or np.all(
        dist_to_segment(q[~reached, 0], q[~reached, 1], p0, p1)[np.isfinite(exact[~reached])] > tool.radius - 1e-3
    )


def test_horizontal_and_vertical_moves_are_closed_form():
    q = np.array([[0.0, 0.0], [1.0, 2.0], [2.9, 0.0], [3.1, 0.0], [5.0, 1.5]])
    for tool in SHAPES.values():
        horiz = swept_envelope(q, (0, 0, -1), (5, 0, -1), tool)
        d = dist_to_segment(q[:, 0], q[:, 1], (0, 0), (5, 0))
        assert np.allclose(horiz, -1 + tool.profile_height(d))
        vert = swept_envelope(q, (0, 0, 2), (0, 0, -3), tool)
        assert np.allclose(vert, -3 + tool.profile_height(np.hypot(q[:, 0], q[:, 1])))


# --- simulate ------------------------------------------------------------------------


@pytest.mark.parametrize("tool", [BALL, BULL, FLAT], ids=lambda t: t.shape)
def test_horizontal_pass_cuts_the_tool_profile(tool):
    moves = program([(R, tool.number, (5, 10, 5)), (C, tool.number, (5, 10, -2)), (C, tool.number, (35, 12, -2)),
                     (R, tool.number, (35, 12, 5))])
    verified = simulate(moves, TOOLS, SETUP, LOW_PART, VerifyOptions(cell=0.25))
    sim, report = verified.simulation, verified.report
    X, Y = grid_xy(sim)
    d = dist_to_segment(X, Y, (5, 10), (35, 12))
    # The plunge at (5, 10) and the pass both reach their lowest at z = -2.
    groove = np.where(d <= tool.radius, -2 + tool.profile_height(np.minimum(d, tool.radius)), np.inf)
    assert np.allclose(sim.stock_top, np.minimum(0.0, groove), atol=1e-9)
    assert report.max_gouge == 0.0 and report.ok
    assert report.moves == 4  # the first positioning move (from NaN) is checked standing at its end
    assert report.cut_length == pytest.approx(7 + np.hypot(30, 2))
    assert report.rapid_length == pytest.approx(7)


moves_strategy = st.lists(
    st.tuples(st.sampled_from([C, C, R]), st.sampled_from(sorted(TOOLS)),
              st.tuples(st.floats(-5, 45), st.floats(-5, 25), st.floats(-4, 1))),
    min_size=1, max_size=12,
)


@settings(max_examples=25, deadline=None)
@given(blocks=moves_strategy)
def test_simulated_stock_is_the_minimum_of_all_swept_envelopes(blocks):
    """Batching, row spans and the lower-bound shortcut lose no grid point."""
    moves = program(blocks, start=(20, 10, 5))
    verified = simulate(moves, TOOLS, SETUP, LOW_PART, VerifyOptions(cell=0.5))
    sim, report = verified.simulation, verified.report
    with mock.patch.object(stock, "_PAIR_BUDGET", 300):  # one move per batch
        verified = simulate(moves, TOOLS, SETUP, LOW_PART, VerifyOptions(cell=0.5))
        small, small_report = verified.simulation, verified.report
    # Equal up to rounding: the skip bounds compare heights, so subnormal depths may differ.
    assert np.allclose(small.stock_top, sim.stock_top, atol=1e-9, rtol=0)
    # the same crashes, their depths equal up to the same rounding
    assert [(c.line, c.move) for c in small_report.rapid_crashes] == [(c.line, c.move) for c in report.rapid_crashes]
    for a, b in zip(small_report.rapid_crashes, report.rapid_crashes):
        assert a.depth == pytest.approx(b.depth, abs=1e-9)
        np.testing.assert_allclose(a.position, b.position, atol=1e-9)
    X, Y = grid_xy(sim)
    q = np.column_stack([X.ravel(), Y.ravel()])
    expected = np.zeros(len(q))
    for k in range(1, len(moves.points)):
        tool = TOOLS[int(moves.tool[k])]
        if moves.motion[k] == Motion.RAPID:  # a rapid's rim is drawn in by the rapid tolerance
            tool = _grown(tool, -VerifyOptions().rapid_tolerance)
        env = swept_envelope(q, moves.points[k - 1], moves.points[k], tool)
        expected = np.minimum(expected, env)
    assert np.allclose(sim.stock_top.ravel(), expected, atol=1e-9)
    assert report.moves == len(blocks)


def test_gouging_plunge_reports_its_depth_line_and_position():
    opts = VerifyOptions(cell=0.2)
    moves = program([
        (R, 2, (20, 10, 5)),
        (C, 2, (20, 10, -4)),  # down to 1 mm above the part
        (C, 2, (20.1, 10.1, -5.5)),  # 0.5 mm into it
        (C, 2, (20.1, 10.1, -4)),
        (R, 2, (20.1, 10.1, 5)),
    ])
    verified = simulate(moves, TOOLS, SETUP, LOW_PART, opts)
    sim, report = verified.simulation, verified.report
    # Exact at grid points: the nearest point to the tip is at most half a cell diagonal away.
    slack = float(BALL.profile_height(opts.cell * np.sqrt(0.5)))
    assert 0.5 - slack <= report.max_gouge <= 0.5 + 1e-9
    assert report.gouge_line == 3
    assert report.gouge_position[:2] == pytest.approx((20.1, 10.1), abs=opts.cell)
    assert report.gouge_position[2] == pytest.approx(-5 - report.max_gouge)
    assert not report.ok
    assert report.remaining_p95 == pytest.approx(5.0)


def test_cutting_into_a_through_hole_is_not_a_gouge():
    plate = trimesh.creation.box(bounds=[[0, 0, -10], [40, 20, -2]])
    hole = trimesh.creation.cylinder(radius=6, height=30, sections=64)
    hole.apply_translation([20, 10, -5])
    part = plate.difference(hole)
    # A 6 mm flat plunges to the stock bottom in the middle of the 12 mm hole.
    moves = program([(R, 1, (20, 10, 5)), (C, 1, (20, 10, -10)), (R, 1, (20, 10, 5))])
    verified = simulate(moves, TOOLS, SETUP, part.triangles, VerifyOptions(cell=0.25))
    sim, report = verified.simulation, verified.report
    assert report.max_gouge == 0.0 and report.gouge_line is None
    assert report.remaining_max == pytest.approx(2.0)


def test_rapid_through_stock_is_a_crash_with_its_line():
    moves = program([
        (R, 1, (-5, 10, 5)),
        (R, 1, (-5, 10, -2)),  # beside the stock: harmless
        (R, 1, (45, 10, -2)),  # through it, 2 mm deep
        (R, 1, (45, 10, 5)),
    ])
    verified = simulate(moves, TOOLS, SETUP, LOW_PART, VerifyOptions(cell=0.5))
    sim, report = verified.simulation, verified.report
    assert [c.line for c in report.rapid_crashes] == [3]
    crash = report.rapid_crashes[0]
    assert crash.depth == pytest.approx(2.0)
    assert crash.move == 3 and crash.position[2] == pytest.approx(-2.0)
    assert not report.ok
    # Material is still removed, violently.
    assert sim.stock_top.min() == pytest.approx(-2.0)


@pytest.mark.parametrize("budget", [None, 300], ids=["one batch", "a batch per move"])
def test_rapids_are_checked_against_the_stock_left_by_earlier_moves(budget):
    moves = program([
        (R, 1, (-5, 10, 5)),
        (R, 1, (-5, 10, -2)),
        (C, 1, (45, 10, -2)),  # cut a slot ...
        (R, 1, (-5, 10, -1.5)),  # ... and rapid back inside it: fine
        (R, 1, (45, 10, -3)),  # deeper than the slot, sloping: crash of up to 1 mm
        (R, 1, (-5, 10, -1.5)),  # back along the same path: the rapid before cleared it
        (R, 1, (-5, 10, 5)),
    ])
    with mock.patch.object(stock, "_PAIR_BUDGET", budget or stock._PAIR_BUDGET):
        verified = simulate(moves, TOOLS, SETUP, LOW_PART, VerifyOptions(cell=0.5))
        sim, report = verified.simulation, verified.report
    assert [c.line for c in report.rapid_crashes] == [5]
    # Deepest where the rapid leaves the stock, on the last grid point the tool covers.
    assert 0.85 < report.rapid_crashes[0].depth <= 1.0 + 1e-9


def test_rapid_grazing_within_tolerance_is_not_a_crash():
    moves = program([(R, 1, (-5, 10, 5)), (R, 1, (-5, 10, -0.005)), (R, 1, (45, 10, -0.005))])
    report = simulate(moves, TOOLS, SETUP, LOW_PART, VerifyOptions(cell=0.5, rapid_tolerance=0.01)).report
    assert report.rapid_crashes == ()


def test_cutting_air_leaves_the_full_stock_above_the_part():
    moves = program([(R, 1, (-10, -10, 5)), (C, 1, (50, 30, 1)), (C, 1, (50, -10, 0.0)), (C, 1, (-20, 10, 2))])
    verified = simulate(moves, TOOLS, SETUP, LOW_PART, VerifyOptions(cell=0.5))
    sim, report = verified.simulation, verified.report
    assert np.all(sim.stock_top == 0.0)
    assert report.remaining_max == report.remaining_mean == report.remaining_p95 == pytest.approx(5.0)
    # Nothing cut proves nothing: the program fails as one that removes no material.
    assert report.max_gouge == 0.0 and not report.ok
    assert [f.kind for f in report.faults] == ["no_cut"]


def test_facing_to_the_part_top_leaves_nothing_and_gouges_nothing():
    part = box([0, 0, -10], [40, 20, -3])  # the part fills the stock footprint, 3 mm below its top
    blocks = [(R, 4, (-6, -2, 5)), (C, 4, (-6, -2, -3))]
    for k, y in enumerate(np.arange(-2, 23, 4.0)):  # 10 mm cutter, 4 mm stepover, overhanging the stock
        x0, x1 = (-6, 46) if k % 2 == 0 else (46, -6)
        blocks += [(C, 4, (x0, y, -3)), (C, 4, (x1, y, -3))]
    blocks.append((R, 4, (-6, 30, 5)))
    verified = simulate(program(blocks), TOOLS, SETUP, part, VerifyOptions(cell=0.25))
    sim, report = verified.simulation, verified.report
    assert abs(report.remaining_max) <= 1e-9 and abs(report.remaining_mean) <= 1e-9
    assert report.max_gouge <= 1e-9
    assert report.ok


def test_moves_with_unknown_axes_are_skipped_and_the_first_known_position_is_checked():
    moves = ProgramMoves(
        points=[[np.nan] * 3, [10, 10, np.nan], [10, 10, -3], [20, 10, -3]],
        motion=[0, R, C, C], tool=[0, 1, 1, 1], feed=[np.nan, np.nan, 500, 500], line=[0, 1, 2, 3],
    )
    verified = simulate(moves, TOOLS, SETUP, LOW_PART, VerifyOptions(cell=0.5))
    sim, report = verified.simulation, verified.report
    # Line 1 ends at an unknown Z: skipped. Line 2 comes from there: the tool stands at
    # its end, already 3 mm down in the stock, which line 3 then cuts on from.
    assert report.moves == 2
    assert sim.stock_top.min() == pytest.approx(-3.0)
    assert sim.stock_top[np.abs(sim.grid.ys - 10).argmin(), np.abs(sim.grid.xs - 8).argmin()] == pytest.approx(-3.0)


def test_feed_move_without_a_known_tool_is_an_error():
    no_tool = program([(R, 0, (0, 0, 5)), (C, 0, (5, 5, -1))])
    with pytest.raises(VerifyError) as err:
        simulate(no_tool, TOOLS, SETUP, LOW_PART, VerifyOptions(cell=1.0))
    assert err.value.data["line"] == 2
    unknown = program([(R, 9, (0, 0, 5)), (C, 9, (5, 5, -1))])
    with pytest.raises(VerifyError, match="T9"):
        simulate(unknown, TOOLS, SETUP, LOW_PART, VerifyOptions(cell=1.0))


def test_an_error_about_a_line_names_the_program_file():
    from cadcam.gcode import parse_gcode

    moves = parse_gcode("G21 G90\nG0 X0 Y0 Z5\nG1 X5 Y5 Z-1 F300\n", source="p.ngc")
    assert moves.source == "p.ngc"
    with pytest.raises(VerifyError) as err:
        simulate(moves, TOOLS, SETUP, LOW_PART, VerifyOptions(cell=1.0))
    assert str(err.value) == "p.ngc: line 3: feed move with no tool in the spindle"


def test_rapid_with_empty_spindle_is_skipped():
    moves = program([(R, 0, (-5, 10, -2)), (R, 0, (45, 10, -2))])
    verified = simulate(moves, TOOLS, SETUP, LOW_PART, VerifyOptions(cell=1.0))
    sim, report = verified.simulation, verified.report
    assert report.rapid_crashes == () and np.all(sim.stock_top == 0.0)


def test_bad_inputs_are_verify_errors():
    moves = program([(R, 1, (0, 0, 5))])
    with pytest.raises(VerifyError):
        simulate(moves, TOOLS, SETUP, LOW_PART, VerifyOptions(cell=0.0))
    with pytest.raises(VerifyError):
        simulate(moves, TOOLS, SETUP, np.zeros((0, 3, 3)), VerifyOptions(cell=1.0))
    with pytest.raises(VerifyError):
        simulate(moves, TOOLS, SETUP, box([100, 100, -10], [110, 110, -5]), VerifyOptions(cell=1.0))


def test_progress_reaches_the_total_and_report_is_json_ready():
    calls = []
    moves = program([(R, 2, (20, 10, 5)), (C, 2, (20, 10, -5.5)), (R, 2, (20, 10, 5)), (R, 1, (-5, 10, 5)),
                     (R, 1, (-5, 10, -1)), (R, 1, (45, 10, -1))])
    verified = simulate(moves, TOOLS, SETUP, LOW_PART, VerifyOptions(cell=0.5),
                        progress=lambda d, t: calls.append((d, t)))
    sim, report = verified.simulation, verified.report
    assert calls and calls[-1] == (report.moves, report.moves)
    assert all(d <= t for d, t in calls)
    d = json.loads(json.dumps(report.to_dict()))
    assert d["ok"] is False and d["gouge_line"] == 2
    assert [c["line"] for c in d["rapid_crashes"]] == [6]
    assert not sim.stock_top.flags.writeable and not sim.part_top.flags.writeable


def test_deviation_image_is_a_sane_picture():
    moves = program([(R, 2, (20, 10, 5)), (C, 2, (20, 10, -5.5)), (C, 2, (30, 10, -4)), (R, 2, (30, 10, 5))])
    verified = simulate(moves, TOOLS, SETUP, LOW_PART, VerifyOptions(cell=0.25))
    sim, report = verified.simulation, verified.report
    img = deviation_image(sim, report)
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
    assert img.shape[0] >= 160 and img.shape[1] >= 160 + 160  # map plus colour bar and labels
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 10
    # The gouge shows in red.
    red = (img[..., 0] > 180) & (img[..., 1] < 60) & (img[..., 2] < 60)
    assert red.sum() > 20
    png = png_bytes(img)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_deviation_picture_has_axes_in_mm_a_scale_bar_and_the_work_origin(monkeypatch):
    """Issue 30: a machinist finds where stock is left by reading the picture's axes. Each X tick's
    label stands under the column of the grid point at that X, each Y label beside its row."""
    from PIL import ImageDraw

    from cadcam.preview import _GOUGE

    drawn = []
    real = ImageDraw.ImageDraw.text

    def text(self, xy, s, *args, **kwargs):
        drawn.append((tuple(map(float, xy)), s, float(self.textlength(s))))
        return real(self, xy, s, *args, **kwargs)

    monkeypatch.setattr(ImageDraw.ImageDraw, "text", text)
    moves = program([(R, 2, (20, 10, 5)), (C, 2, (20, 10, -5.5)), (C, 2, (30, 10, -4)), (R, 2, (30, 10, 5))])
    verified = simulate(moves, TOOLS, SETUP, LOW_PART, VerifyOptions(cell=0.25))
    sim, report = verified.simulation, verified.report
    img = deviation_image(sim, report)
    labels = [s.strip() for _, s, _ in drawn]
    assert "X, Y mm" in labels and "X0 Y0" in labels
    assert any(re.fullmatch(r"\d+ mm", s) for s in labels), labels  # the scale bar's length
    # Where the labels say X = 20 and X = 30 stand (each centred under its tick), the gouge's first red
    # column must stand at the X of the first gouged grid point, less half a cell.
    (u20, _), = [(xy[0] + w / 2, s) for xy, s, w in drawn if s == "20" and xy[1] > img.shape[0] / 2]
    (u30, _), = [(xy[0] + w / 2, s) for xy, s, w in drawn if s == "30" and xy[1] > img.shape[0] / 2]
    per_mm = (u30 - u20) / 10.0
    g = sim.grid
    assert per_mm == pytest.approx((640 // g.nx) / g.cell, rel=0.02)  # 4 px a 0.25 mm grid point
    gouged = sim.remaining < -report.gouge_tolerance
    x_first = g.x0 + g.cell * np.flatnonzero(gouged.any(axis=0)).min()
    u_red = np.flatnonzero((img == _GOUGE.astype(np.uint8)).all(axis=2).any(axis=0)).min()
    assert u_red == pytest.approx(u20 + (x_first - 0.5 * g.cell - 20.0) * per_mm, abs=4.0)
    ys = sorted((xy[1], float(s)) for xy, s, _ in drawn if re.fullmatch(r"\s+-?\d+", s))
    assert len(ys) >= 2 and all(a[1] > b[1] for a, b in zip(ys, ys[1:]))  # Y grows up the picture


def test_a_reliefs_colour_scale_runs_over_its_surface_not_the_uncut_rim():
    """Issue 30: 0.5 mm left on a relief's 20 x 20 mm surface, 9.9 mm on the uncut rim round it. Clipped to the
    surface, the 0.5 mm is the scale's top colour; over the rim too it would be near the blue of on size."""
    from cadcam.heightmap import Grid, upper_envelope
    from cadcam.preview import _COLOURS
    from cadcam.relief import machining_surface, surface_footprint
    from cadcam.stock import Simulation
    from cadcam.verify import VerifyReport

    sheet = trimesh.Trimesh(vertices=[[10, 10, -9.9], [30, 10, -9.9], [30, 30, -9.9], [10, 30, -9.9]],
                            faces=[[0, 1, 2], [0, 2, 3]])
    setup = Setup(stock_min=[0, 0, -20], stock_max=[40, 40, 0], transform_mesh_to_work=np.eye(4))
    tri = np.asarray(machining_surface(sheet, setup).triangles)
    grid = Grid(x0=0.5, y0=0.5, cell=1.0, nx=40, ny=40)
    on = surface_footprint(tri, grid)
    assert on.sum() == 18 * 18 and not on[0].any()  # the base plane round it is not the surface, nor its edge
    part_top = upper_envelope(tri, grid)
    sim = Simulation(grid=grid, stock_top=np.where(on, -9.4, 0.0), part_top=part_top, stock_bottom=-20.0)
    report = VerifyReport(max_gouge=0.0, gouge_position=None, gouge_line=None, remaining_max=9.9,
                          remaining_mean=5.0, remaining_p95=9.9, rapid_crashes=(), moves=0, cut_length=0.0,
                          rapid_length=0.0, cells=grid.size, cell=grid.cell)
    centre = (12 + 320, 56 + 320)  # top margin and the Y labels' room, then 16 px a grid point
    clipped = deviation_image(sim, report, on_part=on)[centre]
    assert np.abs(clipped.astype(float) - _COLOURS[-1]).max() <= 1, clipped
    whole = deviation_image(sim, report)[centre]
    assert np.abs(whole.astype(float) - _COLOURS[-1]).max() > 100 and whole[2] > 180, whole  # near on-size blue


def test_a_wall_nicked_within_the_tolerance_is_no_gouge_of_its_height():
    # The part's wall at x = 29.8755 leaves grid point x = 29.875 (cell 0.25) 0.5 um inside it.
    part = box([10, 5, -10], [29.8755, 15, -5])
    opts = VerifyOptions(cell=0.25)

    def pass_beside_wall(nick):
        x = 29.8755 + BALL.radius - nick  # the ball's side reaches ``nick`` into the wall
        return simulate(program([(R, 2, (x, 1, 5)), (C, 2, (x, 1, -9)), (C, 2, (x, 19, -9)), (R, 2, (x, 19, 5))]),
                        TOOLS, SETUP, part, opts)

    verified = pass_beside_wall(0.002)
    sim, report = verified.simulation, verified.report
    assert np.nanmin(sim.remaining) < -1.0  # the z-map alone would read a 1 mm cut there
    # No gouge; the pass itself slots the stock 9 mm deep, past the ball's 6 mm axial limit: that, only.
    assert report.max_gouge <= opts.gouge_tolerance and not report.gouged and not report.rapid_crashes
    assert [(f.kind, f.tool) for f in report.faults] == [("full_width", 2)]
    # Into the wall by more than the tolerance: the grid point 0.25 mm inside keeps its full
    # cut, from the wall top (z = -5) down to the ball's side (centre at z = -6).
    verified = pass_beside_wall(0.3)
    sim, report = verified.simulation, verified.report
    d = BALL.radius - 0.3 + (29.8755 - 29.625)  # from the tool axis to that grid point [mm]
    assert report.max_gouge == pytest.approx(1.0 + np.sqrt(BALL.radius**2 - d**2), abs=1e-9)
    assert report.gouge_position[0] == pytest.approx(29.625)
    assert report.gouge_line == 3


# --- what breaks a tool or crashes the machine ------------------------------------------
#
# Random parts (a box in the left of the stock, its top a few mm below the stock top), a
# clean program that faces the stock down to the part top with the flat end mill, and
# doctored copies of it. Programs are G-code text parsed by the real parser, so the
# line numbers the faults name are the lines of the text.

from cadcam.gcode import parse_gcode  # noqa: E402
from cadcam.model import HolderSegment  # noqa: E402
from cadcam.verify import finishing_moves  # noqa: E402

SAFE_STOCK = Setup(stock_min=[0, 0, -20], stock_max=[60, 30, 0], transform_mesh_to_work=np.eye(4))
#: A 4 mm flat end mill sticking out only 8 mm from a 16 mm holder.
STUBBY = Tool(5, "4 mm flat, short", "flat", 4.0, 0.0, 6.0, 2, 8.0, shank_diameter=4.0,
              holder=(HolderSegment(16.0, 30.0, 16.0),))
SAFE_TOOLS = {**TOOLS, STUBBY.number: STUBBY}
FAST = VerifyOptions(cell=0.5)


def facing(face: float, stepdown: float) -> list[str]:
    """Face the whole stock down to ``face`` with T1 (6 mm flat): entries beside the stock."""
    out = ["G21 G90 G17", "(op 1: face [roughing] T1 6 mm flat)", "T1 M6", "G0 Z5"]
    levels = np.arange(-stepdown, face - 1e-9, -stepdown).tolist() + [face]
    for z in dict.fromkeys(round(v, 4) for v in levels):
        out += ["G0 X-4 Y0", f"G0 Z{z}"]
        for k, y in enumerate(np.arange(0.0, 30.01, 4.0).tolist()):
            out += [f"G1 X{64 if k % 2 == 0 else -4} Y{y} F800", f"G1 Y{y + 4}"]
        out.append("G0 Z5")
    return out


def verify_text(lines: list[str], part, sheet_ops=()):
    text = "\n".join(lines) + "\n"
    moves = parse_gcode(text)
    return simulate(moves, SAFE_TOOLS, SAFE_STOCK, part, FAST, finishing=finishing_moves(text, moves, sheet_ops))


def line_of(lines: list[str], text: str, start: int = 0) -> int:
    return lines.index(text, start) + 1


def faults_by_kind(report):
    return {(f.kind, f.tool): f for f in report.faults}


part_strategy = st.tuples(st.floats(12.0, 26.0), st.floats(14.0, 26.0), st.floats(1.5, 6.0))


def random_part(size):
    sx, sy, depth = size
    return box([2, 2, -20], [2 + sx, 2 + sy, -depth]), -depth


@settings(max_examples=12, deadline=None)
@given(part_strategy)
def test_a_clean_program_is_not_flagged(size):
    part, face = random_part(size)
    verified = verify_text(facing(face, 1.5), part)
    sim, report = verified.simulation, verified.report
    assert report.ok, report.faults
    assert report.engagement[0].max_depth <= 1.5 + 1e-9  # never more than the stepdown
    assert report.engagement[0].max_width == pytest.approx(4.0, abs=FAST.cell)  # the stepover


@settings(max_examples=12, deadline=None)
@given(part_strategy, st.floats(36.0, 52.0), st.floats(7.0, 23.0), st.floats(3.0, 10.0), st.sampled_from([0.0, 4.0]))
def test_a_buried_finishing_tool_is_caught_on_its_lines(size, x, y, depth, travel):
    part, face = random_part(size)
    lines = facing(face, 1.5) + [
        "(op 2: finish raster [raster] T2 6 mm ball)", "T2 M6", "G0 Z5", f"G0 X{x} Y{y}", f"G0 Z{face + 1}",
        f"G1 Z{face - depth} F300", f"G1 X{x - travel}", "G0 Z5",
    ]
    report = verify_text(lines, part).report
    buried = faults_by_kind(report)[("buried", 2)]
    plunge = line_of(lines, f"G1 Z{face - depth} F300")
    assert set(buried.lines) <= {plunge, plunge + 1} and plunge in buried.lines
    # Sideways the whole column under the ball's centre; plunging, the thickness over half
    # the footprint (r <= R / sqrt 2, where the ball stands 0.88 mm above its tip).
    assert depth - 0.88 - FAST.cell < buried.worst <= depth + 1e-9
    if travel:
        assert buried.worst > depth - 0.1
    # Nothing else (no gouge, no crash) but, travelling, a slot past the ball's 6 mm axial limit.
    assert {f.kind for f in report.faults} - {"full_width"} == {"buried"}
    assert ("full_width", 2) not in faults_by_kind(report) or (travel and depth > BALL.full_width_limit)
    # The same moves with a roughing tool are within its 20 mm flutes.
    rough = [ln.replace("[raster] T2", "[roughing] T2") for ln in lines]
    assert {f.kind for f in verify_text(rough, part).report.faults} <= {"full_width"}


@settings(max_examples=12, deadline=None)
@given(part_strategy, st.floats(0.3, 2.7), st.floats(0.5, 4.0), st.floats(4.0, 26.0))
def test_a_rapid_whose_edge_alone_meets_stock_is_caught(size, outside, depth, y):
    """The tool's centre stays outside the stock; its edge reaches ``3 - outside`` mm in."""
    part, face = random_part(size)
    base = facing(face, 1.5)
    lines = base[:4] + [f"G0 X{-outside} Y{y}", f"G0 Z{-depth}", "G0 Z5"] + base[4:]
    report = verify_text(lines, part).report
    crash = faults_by_kind(report)[("rapid", 1)]
    assert crash.lines == (6,)  # the G0 Z-depth
    assert crash.worst == pytest.approx(depth)
    assert [c.line for c in report.rapid_crashes] == [6]
    assert {f.kind for f in report.faults} == {"rapid"}


@settings(max_examples=10, deadline=None)
@given(part_strategy, st.floats(36.0, 52.0), st.floats(8.0, 22.0), st.integers(9, 14))
def test_a_short_tool_reaching_deep_is_caught_by_its_holder(size, x, y, depth):
    """A narrow pocket cut 1 mm per level: no level is deep, but the holder comes down on the stock."""
    part, face = random_part(size)
    lines = facing(face, 1.5) + ["(op 2: pocket [roughing] T5 4 mm flat, short)", "T5 M6", "G0 Z5",
                                 f"G0 X{x + 1} Y{y}", f"G0 Z{face + 1}"]
    for k in range(1, depth + 1):
        lines += [f"G1 Z{face - k} F200", f"G2 X{x + 1} Y{y} I-1 J0 F400"]
    lines.append("G0 Z5")
    text = "\n".join(lines) + "\n"
    moves = parse_gcode(text)
    report = verify_text(lines, part).report
    holder = faults_by_kind(report)[("holder", 5)]
    # Every move of T5 whose tip goes more than the 8 mm stick-out below the faced top.
    low = np.minimum(moves.points[:-1, 2], moves.points[1:, 2]) < face - 8 - FAST.contact_tolerance
    expected = set(moves.line[1:][low & (moves.tool[1:] == 5)].tolist())
    assert set(holder.lines) == expected and expected
    assert {f.kind for f in report.faults} == {"holder"}
    assert holder.worst == pytest.approx(depth - 8.0, abs=0.05)


def test_a_cut_deeper_than_the_flutes_and_below_the_stock():
    part, face = random_part((20.0, 20.0, 3.0))
    lines = facing(face, 1.5) + ["(op 2: slot [roughing] T5 4 mm flat, short)", "T5 M6", "G0 Z5",
                                 "G0 X40 Y15", "G0 Z-2", "G1 Z-3 F200", "G1 X50 Z-10", "G1 Z-21", "G0 Z5"]
    report = verify_text(lines, part).report
    found = faults_by_kind(report)
    ramp = line_of(lines, "G1 X50 Z-10")
    assert ramp in found[("flute", 5)].lines  # 7 mm of stock met sideways by 6 mm flutes
    assert found[("below_stock", 5)].lines == (line_of(lines, "G1 Z-21"),)
    assert found[("below_stock", 5)].worst == pytest.approx(1.0)


def test_an_empty_program_fails():
    part, _ = random_part((20.0, 20.0, 3.0))
    for text in ([], ["G21 G90", "T1 M6", "G0 Z5", "M30"]):
        report = verify_text(text, part).report
        assert not report.ok and [f.kind for f in report.faults] == ["no_cut"]


@settings(max_examples=8, deadline=None)
@given(part_strategy, st.floats(36.0, 52.0), st.floats(7.0, 23.0), st.floats(3.0, 10.0))
def test_one_batch_or_a_batch_per_move_judge_alike(size, x, y, depth):
    """Within a batch each move meets the stock its predecessors left, as across batches."""
    part, face = random_part(size)
    lines = facing(face, 1.5) + [
        "(op 2: finish raster [raster] T2 6 mm ball)", "T2 M6", "G0 Z5", f"G0 X{x} Y{y}", f"G0 Z{face + 1}",
        f"G1 Z{face - depth} F300", f"G1 X{x - 4}", f"G1 X{x}", f"G0 X{x - 4}", "G0 Z5",
    ]
    verified = verify_text(lines, part)
    sim1, one = verified.simulation, verified.report
    with mock.patch.object(stock, "_PAIR_BUDGET", 50):
        verified = verify_text(lines, part)
        sim2, many = verified.simulation, verified.report
    np.testing.assert_array_equal(sim1.stock_top, sim2.stock_top)
    # Where and on which line a maximum is reached may differ between moves that tie.
    assert_same([(f.kind, f.tool, f.lines, f.worst) for f in one.faults],
                [(f.kind, f.tool, f.lines, f.worst) for f in many.faults])
    assert_same([(e.tool, e.max_depth, e.max_width) for e in one.engagement],
                [(e.tool, e.max_depth, e.max_width) for e in many.engagement])
    assert_same(one.rapid_crashes, many.rapid_crashes)


def assert_same(a, b, path="report"):
    """Equal structure and text; numbers equal to 1e-7 mm (batching reorders float sums)."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            assert_same(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), path
        for k, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{path}[{k}]")
    elif isinstance(a, float):
        assert a == pytest.approx(b, abs=1e-7), path
    else:
        assert a == b, path


def test_finishing_moves_follow_the_op_comments_then_the_sheet():
    text = "\n".join(["(op 1: rough [roughing] T1 flat)", "T1 M6", "G0 X0 Y0 Z5", "G1 Z-1 F100",
                      "(op 2: finish [raster] T2 ball)", "T2 M6", "G1 Z-1", "T3 M6", "G1 Z-2"]) + "\n"
    moves = parse_gcode(text)
    ops = [{"kind": "roughing", "tool": 1}, {"kind": "raster", "tool": 2}, {"kind": "waterline", "tool": 3}]
    fin = dict(zip(moves.line.tolist(), finishing_moves(text, moves, ops).tolist()))
    assert fin[4] is False and fin[7] is True
    assert fin[9] is True  # T3 under op 2's comment (which names T2): the sheet says T3 only finishes
    no_comments = "\n".join(ln for ln in text.splitlines() if not ln.startswith("(")) + "\n"
    moves = parse_gcode(no_comments)
    fin = finishing_moves(no_comments, moves, ops)
    assert fin[moves.tool == 1].sum() == 0 and fin[moves.tool == 2].all()


def test_a_shank_as_wide_as_the_cutter_riding_a_finished_wall_is_no_contact():
    """A ball with short flutes plunges down a 15 mm wall at exactly its radius from it."""
    wall = box([30, 2, -20], [58, 28, 0])  # top flush with the stock top
    ball = Tool(6, "6 mm ball, 8 mm flutes", "ball", 6.0, 3.0, 8.0, 2, 40.0)
    lines = ["G21 G90", "(op 1: rough [roughing] T1 6 mm flat)", "T1 M6", "G0 Z5"]
    for z in np.arange(-1.5, -15.01, -1.5).round(2).tolist():  # clear x < 30 leaving 0.3 mm
        lines += ["G0 X-4 Y0", f"G0 Z{z}"]
        for k, y in enumerate(np.arange(0.0, 30.01, 4.0).tolist()):
            lines += [f"G1 X{26.7 if k % 2 == 0 else -4} Y{y} F800", f"G1 Y{y + 4}"]
        lines += ["G1 X26.7 Y32", "G1 Y-2", "G0 Z5"]  # and along the wall: no scallops between the rows
    lines += ["(op 2: finish [raster] T6 6 mm ball)", "T6 M6", "G0 X27 Y15 Z5", "G1 Z-15 F300", "G0 Z5"]
    text = "\n".join(lines) + "\n"
    moves = parse_gcode(text)
    tools = {1: FLAT, 6: ball}
    report = simulate(moves, tools, SAFE_STOCK, wall, FAST, finishing=finishing_moves(text, moves)).report
    assert report.faults == () and not report.gouged
    # Dragged along the wall at that depth, the shank does rub the 0.3 mm skin above the flutes.
    text = text.replace("G1 Z-15 F300\n", "G1 Z-15 F300\nG1 Y25\n")
    moves = parse_gcode(text)
    report = simulate(moves, tools, SAFE_STOCK, wall, FAST, finishing=finishing_moves(text, moves)).report
    assert [(f.kind, f.tool) for f in report.faults] == [("holder", 6)]
    assert report.faults[0].lines == (text.splitlines().index("G1 Y25") + 1,)


# --- engagement as a machinist reads it: angle, radial and full-width axial depth ----------

SMALL = Tool(6, "2 mm flat", "flat", 2.0, 0.0, 6.0, 2, 16.0, axial_limit=1.0)
CORNER_SETUP = Setup(stock_min=[0, 0, -10], stock_max=[30, 30, 0], transform_mesh_to_work=np.eye(4))
# An L of walls round a square pocket 6 mm deep: a sharp inside corner at X10 Y10.
CORNER_PART = np.concatenate([box([0, 0, -10], [30, 10, 0]), box([0, 0, -10], [10, 30, 0]),
                              box([0, 0, -10], [30, 30, -6])])


def corner_program(levels_small):
    """The 6 mm end mill clears the pocket in 2 mm levels, leaving its R3 in the corner; then the 2 mm
    end mill runs along both walls into the corner at each of ``levels_small`` [mm]."""
    blocks = []
    for z in (-2.0, -4.0, -6.0):
        blocks.append((R, 1, (34, 13, 2)))
        blocks.append((C, 1, (34, 13, z)))
        for k, y in enumerate(np.arange(13, 34, 4.0)):
            xs = (34, 13) if k % 2 == 0 else (13, 34)
            blocks += [(C, 1, (xs[0], y, z)), (C, 1, (xs[1], y, z))]
        blocks.append((R, 1, (13, 33, 2)))
    for z in levels_small:
        blocks += [(R, 6, (20, 11, 2)), (C, 6, (20, 11, z)), (C, 6, (11, 11, z)), (C, 6, (11, 20, z)),
                   (R, 6, (11, 20, 2))]
    return program(blocks, start=(34, 13, 5))


def test_a_small_end_mill_buried_in_an_inside_corner_fails_with_its_figures():
    """Issue 34: the 2 mm flat cleans the corner the 6 mm one left in one pass 6 mm down, its flutes
    5 mm into the corner's sliver at full width; in 1 mm steps it passes."""
    tools = {1: FLAT, 6: SMALL}
    report = simulate(corner_program([-6.0]), tools, CORNER_SETUP, CORNER_PART).report
    assert not report.ok
    (fault,) = [f for f in report.faults if f.kind == "full_width"]
    assert fault.tool == 6 and fault.limit == 1.0 and 4.0 <= fault.worst <= 6.0, fault
    x, y, z = fault.position
    assert 10 <= x <= 13.5 and 10 <= y <= 13.5 and z == pytest.approx(-6.0), fault
    assert fault.message.startswith(f"T6 cuts {fault.worst:.2f} mm deep at full width near X{x:.1f} Y{y:.1f} Z-6.0")
    assert "1 mm axial limit" in fault.message
    eng = {e.tool: e for e in report.engagement}
    assert eng[6].max_full_depth == fault.worst and eng[6].axial_limit == 1.0 and eng[6].angle.max >= 120
    assert eng[1].max_full_depth <= 2.0 + report.cell  # the 6 mm end mill's own 2 mm levels
    stepped = simulate(corner_program([-1.0, -2.0, -3.0, -4.0, -5.0, -6.0]), tools, CORNER_SETUP, CORNER_PART).report
    assert stepped.ok, [f.message for f in stepped.faults]
    assert {e.tool: e for e in stepped.engagement}[6].max_full_depth <= 1.0 + stepped.cell


def test_a_coarse_grid_measures_a_small_tool_on_its_own_finer_grid():
    """At a 0.5 mm grid the 2 mm end mill (D/10 = 0.2 mm) is measured again around its moves."""
    report = simulate(corner_program([-6.0]), {1: FLAT, 6: SMALL}, CORNER_SETUP, CORNER_PART,
                      VerifyOptions(cell=0.5)).report
    eng = {e.tool: e for e in report.engagement}
    assert eng[6].cell == pytest.approx(0.2) and eng[1].cell == 0.5
    assert [f.tool for f in report.faults if f.kind == "full_width"] == [6]
    assert 4.0 <= eng[6].max_full_depth <= 6.0


SLOT_SETUP = Setup(stock_min=[0, 0, -15], stock_max=[30, 20, 0], transform_mesh_to_work=np.eye(4))
SLOT_PART = box([0, 0, -15], [30, 20, -14.5])


@settings(max_examples=25, deadline=None)
@given(st.sampled_from([2.0, 6.0, 10.0]), st.floats(0.2, 0.9), st.floats(0.05, 0.45), st.booleans())
def test_a_slot_is_full_width_to_its_depth_and_a_side_cut_never(diameter, depth_share, ae_share, slot):
    """One pass at a random depth: a slot (the cutter's full width in stock) meets material over
    180 deg and its whole depth counts at full width, failing beyond the axial limit; a side cut of
    width ``ae`` meets ``acos(1 - 2 ae / D)`` and counts none, however deep."""
    tool = Tool(1, "flat", "flat", diameter, 0.0, 12.0, 3, 40.0)
    r = diameter / 2
    depth = depth_share * tool.flute_length
    y = 10.0 if slot else -r + ae_share * diameter  # the stock starts at Y0
    moves = program([(R, 1, (-r - 1, y, 2)), (C, 1, (-r - 1, y, -depth)), (C, 1, (30 + r + 1, y, -depth)),
                     (R, 1, (30 + r + 1, y, 2))], start=(-r - 1, y, 5))
    report = simulate(moves, {1: tool}, SLOT_SETUP, SLOT_PART).report
    (eng,) = report.engagement
    cell = report.cell
    faulted = [f for f in report.faults if f.kind == "full_width"]
    if slot:
        assert eng.angle.max == pytest.approx(180.0)
        assert abs(eng.max_full_depth - depth) <= 1e-6, (eng, depth)
        assert eng.max_width == pytest.approx(diameter)
        assert bool(faulted) == (depth > tool.full_width_limit + cell)
    else:
        ae = ae_share * diameter
        expected = np.degrees(np.arccos(1 - ae / r))
        # an arc bin, and a cell either side of the arc's ends
        slack = 5.0 + np.degrees(np.arcsin(min(1.0, cell / r))) + np.degrees(np.arccos(max(0.0, 1 - cell / r)))
        assert abs(eng.angle.max - expected) <= slack + 1e-6, (eng.angle, expected)
        assert eng.max_full_depth == 0.0 and not faulted
        assert abs(eng.max_width - ae) <= cell + 1e-6


@pytest.mark.parametrize("ae, radial_limit, depth, faulted", [
    (1.2, None, 12.0, False),  # 0.2 D, 12 mm deep: the side cut adaptive clearing takes
    (2.7, None, 12.0, True),  # 0.45 D that deep: past the rule's 0.3 D
    (2.7, 0.5, 12.0, False),  # ... within a tool whose library allows 0.5 D
    (2.7, None, 5.0, False),  # ... within the full-width depth (6 mm): any width
])
def test_a_deep_side_cut_is_held_to_the_tools_radial_limit(ae, radial_limit, depth, faulted):
    """Below its full-width depth a cut must be a side cut within the tool's own radial limit (its library's
    ``radial_limit``, else 0.3 D): verify fails a wider one as ``radial``, naming the tool and its limit."""
    tool = Tool(3, "6 mm flat", "flat", 6.0, 0.0, 18.0, 3, 40.0, radial_limit=radial_limit)
    y = -3.0 + ae  # the stock starts at Y0
    moves = program([(R, 3, (-4, y, 2)), (C, 3, (-4, y, -depth)), (C, 3, (34, y, -depth)), (R, 3, (34, y, 2))],
                    start=(-4, y, 5))
    report = simulate(moves, {3: tool}, SLOT_SETUP, SLOT_PART).report
    radial = [f for f in report.faults if f.kind == "radial"]
    assert not [f for f in report.faults if f.kind == "full_width"]
    assert bool(radial) == faulted, [f.message for f in report.faults]
    if faulted:
        (fault,) = radial
        assert fault.tool == 3 and fault.limit == pytest.approx(1.8) and fault.worst == pytest.approx(ae, abs=report.cell)
        assert "T3" in fault.message and "1.8 mm radial limit" in fault.message


def test_the_independent_probe_sees_the_corner_as_verify_does():
    """tests/cadcam/sweep.py's leading-edge probes (no code of cadcam.stock's engagement) agree: 6 mm of
    the corner at full width in one pass, its own 1 mm in steps; the 6 mm end mill's 2 mm levels."""
    tools = {1: FLAT, 6: SMALL}
    for levels, deepest in (([-6.0], 6.0), ([-1.0, -2.0, -3.0, -4.0, -5.0, -6.0], 1.0)):
        m = corner_program(levels)
        sw = sweep_moves(m.points, m.motion, m.tool, tools, CORNER_SETUP, 0.2, full_width=True)
        assert sw.full_width[m.tool == 6].max() == pytest.approx(deepest, abs=0.2)
        assert sw.full_width[m.tool == 1].max() == pytest.approx(2.0, abs=0.2)


def test_a_small_tool_in_op_2_is_measured_finely_from_the_stock_it_starts_on():
    """Op 2 starts from a stock given per grid point; the finer grid takes it from the nearest point."""
    from cadcam.heightmap import grid_over
    from cadcam.stock import FlippedStock
    from cadcam.verify import simulate_flipped

    grid = grid_over(CORNER_SETUP.stock_min, CORNER_SETUP.stock_max, 0.5)
    start = FlippedStock(grid=grid, top=np.zeros(grid.shape), bottom=np.full(grid.shape, -10.0))
    options = VerifyOptions(cell=0.5)
    tools = {1: FLAT, 6: SMALL}
    flipped = simulate_flipped(corner_program([-6.0]), tools, CORNER_SETUP, CORNER_PART, start, options).report
    plain = simulate(corner_program([-6.0]), tools, CORNER_SETUP, CORNER_PART, options).report
    assert [(f.kind, f.tool) for f in flipped.faults] == [("full_width", 6)]
    assert {e.tool: e.max_full_depth for e in flipped.engagement} == {e.tool: e.max_full_depth for e in plain.engagement}


def test_a_column_cut_through_at_a_hole_s_edge_hides_no_gouge_elsewhere():
    """A grid point on a through hole's wall whose column a drill took through the bottom (stock -inf) has no
    part within the tolerance on the hole's side (the look sideways gives -inf too): no gouge there, and the
    real gouge elsewhere is still the one reported. As -inf - -inf it was NaN, which argmax takes for the
    maximum, and verify said 0 mm over a 0.5 mm gouge."""
    from types import SimpleNamespace

    from cadcam.heightmap import Grid, upper_envelope
    from cadcam.gouge import gouge_depths

    plate = trimesh.creation.box(extents=(20.0, 20.0, 5.0))
    plate.apply_translation((10.0, 10.0, 2.5))
    hole = trimesh.creation.box(extents=(4.0, 4.0, 7.0))
    hole.apply_translation((10.0, 10.0, 2.5))
    part = plate.difference(hole)
    tri = np.asarray(part.triangles)
    g = Grid(x0=0.0, y0=0.0, cell=0.2, nx=101, ny=101)
    top = upper_envelope(tri, g)
    covered = np.isfinite(top)
    stock_top = np.where(covered, top, -np.inf)
    wall, nick = (50, 40), (20, 20)  # (row, column): x = 8 on the hole's wall; x = y = 4 on the top face
    assert covered[wall] and covered[nick]
    stock_top[wall] = -np.inf  # the drill's column, cut through
    stock_top[nick] = top[nick] - 0.5  # a real gouge
    rem = (stock_top - np.where(covered, top, 0.0))[covered]
    gouge = gouge_depths(SimpleNamespace(grid=g, part_top=top, stock_top=stock_top), tri, covered, rem, 0.01)
    assert not np.isnan(gouge).any()
    k = int(np.argmax(gouge))
    assert np.flatnonzero(covered.reshape(-1))[k] == nick[0] * g.nx + nick[1]
    assert gouge[k] == pytest.approx(0.5)
