"""Arc fitting: output stays within tolerance of the input, and circles get shorter."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.geometry import point_polyline_distance
from cadcam.arcs import FitOptions, SegmentKind, arc_sweep, discretize_arc, fit_segments
from cadcam.model import Motion
from factory.core.errors import GcodeError

TOL = 0.002
#: Slack for checking a curve against a polyline by sampling: arcs are checked at
#: vertices and at quarter points of chords, so the worst point in between may exceed
#: the tolerance by a few percent of it.
SLACK = 0.05 * TOL + 1e-9


def check_within(points: np.ndarray, motion: np.ndarray, opt: FitOptions):
    seg = fit_segments(points, motion, opt)
    poly, owner = seg.polyline(chord_tolerance=TOL / 20)
    # Both ways: every input point near the fitted path, every fitted point near the input.
    d_in = point_polyline_distance(points, poly)
    d_out = point_polyline_distance(poly, points)
    tol = opt.tolerance + TOL / 20 + SLACK
    assert d_in.max() <= tol, d_in.max()
    assert d_out.max() <= tol, d_out.max()
    # Ends at the same place, and the segments replace input moves in order.
    np.testing.assert_allclose(poly[0], points[0])
    if len(seg):
        np.testing.assert_allclose(seg.end[-1], points[-1])
        assert np.all(np.diff(seg.source_end) > 0)
        # No segment spans a change of motion kind, and its motion is that of its moves.
        prev = 0
        for k in range(len(seg)):
            # Zero-length moves are dropped, so their motion does not matter.
            lengths = np.linalg.norm(np.diff(points[prev:seg.source_end[k] + 1], axis=0), axis=1)
            kinds = set(motion[prev + 1:seg.source_end[k] + 1][lengths > 1e-9].tolist())
            assert kinds == {int(seg.motion[k])}
            prev = int(seg.source_end[k])
        assert not np.any((seg.motion == Motion.RAPID) & (seg.kind != SegmentKind.LINE))
    return seg


def test_full_circle_becomes_two_arcs():
    th = np.linspace(0, 2 * np.pi, 721)
    p = np.c_[20 * np.cos(th) + 5, 20 * np.sin(th) - 3, np.full_like(th, -1.0)]
    m = np.full(len(p), Motion.CUT)
    seg = check_within(p, m, FitOptions())
    assert seg.kind.tolist() == [SegmentKind.CCW, SegmentKind.CCW]
    np.testing.assert_allclose(seg.centre, [[5, -3], [5, -3]], atol=1e-9)
    assert seg.lengths().sum() == pytest.approx(40 * np.pi, rel=1e-9)


def test_clockwise_helix():
    th = np.linspace(0, -6 * np.pi, 1000)
    p = np.c_[4 * np.cos(th), 4 * np.sin(th), 2 + th / (2 * np.pi)]
    seg = check_within(p, np.full(len(p), Motion.PLUNGE), FitOptions())
    # Six half turns; a short leftover may be a line when a line is within tolerance too.
    assert set(seg.kind.tolist()) <= {SegmentKind.CW, SegmentKind.LINE}
    assert (seg.kind == SegmentKind.CW).sum() == 6 and len(seg) <= 8
    np.testing.assert_allclose(seg.end[-1], p[-1])
    expected = math.hypot(4 * 6 * np.pi, 3.0)
    assert seg.lengths().sum() == pytest.approx(expected, rel=1e-6)


def test_noisy_line_merges_and_zigzag_does_not():
    rng = np.random.default_rng(1)
    x = np.linspace(0, 50, 500)
    p = np.c_[x, 0.0005 * rng.uniform(-1, 1, len(x)), np.full_like(x, -2.0)]
    seg = check_within(p, np.full(len(p), Motion.CUT), FitOptions())
    assert len(seg) == 1 and seg.kind[0] == SegmentKind.LINE
    z = np.c_[np.arange(20.0), np.tile([0.0, 1.0], 10), np.zeros(20)]
    seg = check_within(z, np.full(20, Motion.CUT), FitOptions())
    assert len(seg) == 19


def test_sparse_polygon_is_not_an_arc():
    # Eight points on a circle of radius 10: chords sag 0.76 mm, far beyond tolerance.
    th = np.linspace(0, np.pi, 5)
    p = np.c_[10 * np.cos(th), 10 * np.sin(th), np.zeros(5)]
    seg = check_within(p, np.full(5, Motion.CUT), FitOptions())
    assert np.all(seg.kind == SegmentKind.LINE)


def test_rapids_and_motion_changes():
    th = np.linspace(0, np.pi, 181)
    arc = np.c_[10 * np.cos(th), 10 * np.sin(th), np.zeros_like(th)]
    m = np.full(len(arc), Motion.CUT)
    m[90:] = Motion.PLUNGE  # a change of feed halfway round
    seg = check_within(arc, m, FitOptions())
    assert len(seg) == 2 and np.all(seg.kind == SegmentKind.CCW)
    seg = check_within(arc, np.full(len(arc), Motion.RAPID), FitOptions())
    assert np.all(seg.kind == SegmentKind.LINE)
    seg = check_within(arc, np.full(len(arc), Motion.CUT), FitOptions(arcs=False))
    # Lines may merge pairs of 1 deg chords (sagitta 0.0015 mm) but no more than 2.29 deg.
    assert np.all(seg.kind == SegmentKind.LINE) and 79 <= len(seg) < 180


def test_degenerate_radii_stay_lines():
    # Tiny circle (radius 0.004 mm) and a huge one (radius 1e5 mm, an almost straight line).
    th = np.linspace(0, np.pi, 50)
    tiny = np.c_[0.004 * np.cos(th), 0.004 * np.sin(th), np.zeros_like(th)]
    seg = fit_segments(tiny, np.full(len(th), Motion.CUT), FitOptions(tolerance=1e-4))
    assert np.all(seg.kind == SegmentKind.LINE)
    th = np.linspace(0, 2e-3, 50)
    huge = np.c_[1e5 * np.sin(th), 1e5 * (1 - np.cos(th)), np.zeros_like(th)]
    seg = fit_segments(huge, np.full(len(th), Motion.CUT))
    assert np.all(seg.kind == SegmentKind.LINE)


def test_single_point_and_duplicates():
    seg = fit_segments(np.zeros((1, 3)), np.zeros(1))
    assert len(seg) == 0
    p = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 0], [2, 0, 0.0]])
    seg = fit_segments(p, np.ones(4))
    assert len(seg) == 1


def test_bad_input():
    with pytest.raises(GcodeError):
        fit_segments(np.array([[0, 0, np.nan]]), np.zeros(1))
    with pytest.raises(GcodeError):
        FitOptions(tolerance=0)


def test_arc_sweep_rules():
    c = np.zeros(2)
    assert arc_sweep([1, 0], [0, 1], c, False) == pytest.approx(np.pi / 2)
    assert arc_sweep([1, 0], [0, 1], c, True) == pytest.approx(-3 * np.pi / 2)
    assert arc_sweep([1, 0], [1, 0], c, False) == pytest.approx(2 * np.pi)
    assert arc_sweep([1, 0], [1, 0], c, True, turns=2) == pytest.approx(-4 * np.pi)
    pts = discretize_arc(np.array([1.0, 0, 0]), np.array([-1.0, 0, -1]), c, np.pi, 1e-3)
    np.testing.assert_allclose(np.hypot(pts[:, 0], pts[:, 1]), 1.0)
    assert pts[:, 1].min() >= 0


# --------------------------------------------------------------------------- hypothesis


@st.composite
def polylines(draw):
    """Random chains of lines, arcs and helices with noise below the tolerance."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    noise = draw(st.sampled_from([0.0, 0.2, 0.3])) * TOL
    pieces = [rng.uniform(-50, 50, (1, 3))]
    motions = [np.zeros(1, np.int64)]
    for _ in range(draw(st.integers(1, 5))):
        start = pieces[-1][-1]
        kind = draw(st.sampled_from(["line", "arc", "helix", "walk"]))
        mot = draw(st.sampled_from([Motion.CUT, Motion.PLUNGE, Motion.RAPID]))
        n = draw(st.integers(2, 120))
        if kind == "line":
            end = start + rng.uniform(-30, 30, 3)
            pts = start + np.linspace(0, 1, n)[1:, None] * (end - start)
        elif kind == "walk":
            pts = start + np.cumsum(rng.uniform(-2, 2, (n, 3)), axis=0)
        else:
            r = float(np.exp(rng.uniform(np.log(0.2), np.log(100))))
            a0 = rng.uniform(0, 2 * np.pi)
            sweep = rng.uniform(-2.2, 2.2) * np.pi
            centre = start[:2] - r * np.array([np.cos(a0), np.sin(a0)])
            # Keep chords short enough that a fine arc is representable (sagitta < tol).
            n = max(n, int(abs(sweep) / (2 * math.acos(1 - 0.8 * TOL / r))) + 2) if r > TOL else n
            n = min(n, 3000)
            a = a0 + sweep * np.linspace(0, 1, n)[1:]
            dz = rng.uniform(-5, 5) if kind == "helix" else 0.0
            pts = np.c_[centre[0] + r * np.cos(a), centre[1] + r * np.sin(a),
                        start[2] + dz * np.linspace(0, 1, n)[1:]]
        pts = pts + rng.uniform(-1, 1, pts.shape) * noise / math.sqrt(3)
        pieces.append(pts)
        motions.append(np.full(len(pts), int(mot)))
    return np.vstack(pieces), np.concatenate(motions)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(polylines(), st.sampled_from([0.002, 0.01]))
def test_fit_stays_within_tolerance(path, tol):
    points, motion = path
    check_within(points, motion, FitOptions(tolerance=tol))


@settings(max_examples=30, deadline=None)
@given(st.floats(0.5, 200), st.floats(-3, 3), st.integers(0, 2**31), st.floats(0.0, 0.4))
def test_circles_get_fewer_lines(r, dz, seed, noise_frac):
    rng = np.random.default_rng(seed)
    step = 2 * math.acos(1 - 0.5 * TOL / r)  # chords sag half the tolerance
    n = int(2 * np.pi / step) + 2
    th = np.linspace(0, 2 * np.pi, n)
    p = np.c_[r * np.cos(th), r * np.sin(th), dz * th / (2 * np.pi)]
    p += rng.uniform(-1, 1, p.shape) * noise_frac * TOL / math.sqrt(3)
    seg = check_within(p, np.full(n, Motion.CUT), FitOptions())
    assert len(seg) <= max(4, (n - 1) // 4)
    assert np.any(seg.kind != SegmentKind.LINE)


@st.composite
def screened_paths(draw):
    """:func:`polylines` with what the screen must not misjudge: a raster's passes (x or y exactly constant,
    z rippling), and zigzags whose points sit within an ulp or a nanometre of the tolerance off their chord."""
    points, motion = draw(polylines())
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    pieces, motions = [points], [motion]
    for _ in range(draw(st.integers(1, 3))):
        start = pieces[-1][-1]
        n = draw(st.integers(3, 60))
        u = np.arange(1, n + 1) * rng.uniform(0.05, 1.0)
        if draw(st.booleans()):  # a raster pass
            axis = draw(st.integers(0, 1))
            pts = np.repeat(start[None], n, axis=0)
            pts[:, axis] += u
            pts[:, 2] += 0.3 * np.sin(u / rng.uniform(0.5, 5)) * draw(st.sampled_from([0.0, 1.0]))
        else:  # zigzag at the tolerance, across a pass (lines decide) or beside it (arcs decide)
            off = TOL * (1 + draw(st.sampled_from([0.0, 1e-12, -1e-12, 1e-9, -1e-9, 1e-6, -1e-6, 0.5, -0.5])))
            a = draw(st.sampled_from([0.0, 0.5 * np.pi, rng.uniform(0, 2 * np.pi)]))
            direction = np.array([np.cos(a), np.sin(a), 0.0])
            side = np.array([0, 0, 1.0]) if draw(st.booleans()) else np.array([-np.sin(a), np.cos(a), 0.0])
            pts = start + u[:, None] * direction + (np.arange(n) % 2 * 2 - 1)[:, None] * 0.5 * off * side
        pieces.append(pts)
        motions.append(np.full(n, int(Motion.CUT)))
    return np.vstack(pieces), np.concatenate(motions)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(screened_paths(), st.sampled_from([0.002, 0.01]))
def test_the_short_windows_judged_at_once_give_the_very_fit_the_exact_tests_give(path, tol):
    """The screen (cadcam.arcs._Screen) judges only where it is sure: the fit is bit for bit the one
    each window's exact test alone gives (no screen)."""
    import cadcam.arcs

    points, motion = path
    opt = FitOptions(tolerance=tol)
    screened = fit_segments(points, motion, opt)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(cadcam.arcs, "_SCREEN_MOVES", 1)  # no window judged at once
        exact = fit_segments(points, motion, opt)
    for name in ("start", "end", "kind", "centre", "motion", "source_end"):
        a, b = np.asarray(getattr(screened, name)), np.asarray(getattr(exact, name))
        assert a.shape == b.shape and a.tobytes() == b.tobytes(), name
