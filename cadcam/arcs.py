"""Arc fitting: turn a polyline of cutter locations into G1 lines and G2/G3 arcs.

A CAM polyline describes a circle or a helix with hundreds of short chords; a controller
runs far smoother (and the program is far shorter) when it gets one ``G2``/``G3`` instead.
:func:`fit_segments` walks the polyline greedily, at each point taking the longest run of
points that one straight line or one arc in the XY plane (optionally helical: Z linear in
the swept angle) reproduces within a tolerance, and writes that run as one segment.

"Reproduces within tolerance" means: every input point, and the midpoint and quarter
points of every input chord, lie within ``tolerance`` of the segment. Checking points on
the chords (not only the vertices) keeps the fitted arc within tolerance of the input
*path*, in both directions: sparse input points on a circle of the wrong radius fail.

Runs never cross a change of :class:`~cadcam.model.Motion`, and rapids are only merged
into lines (``G0`` cannot be an arc). Arcs sweep at most ``max_sweep`` (default 180 deg), so
a full circle comes out as two or more arcs, which every controller reads the same way.

The module also discretizes arcs back into chords (:func:`arc_sweep`,
:func:`discretize_arc`), shared with the G-code parser.
"""

from __future__ import annotations

import enum
import logging
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from cadcam.model import Motion, frozen_array
from factory.core.errors import GcodeError

log = logging.getLogger(__name__)

#: Two consecutive cutter locations closer than this are one point [mm].
_SAME_POINT = 1e-9


class SegmentKind(enum.IntEnum):
    """Shape of a fitted segment; the values are the G-code motion numbers."""

    LINE = 1  #: straight line (G0 or G1, by the segment's motion)
    CW = 2  #: clockwise arc seen from +Z (G2)
    CCW = 3  #: counter-clockwise arc seen from +Z (G3)


@dataclass(frozen=True)
class FitOptions:
    """How closely fitted segments must follow the input polyline.

    Attributes
    ----------
    tolerance : float
        Largest distance between the input path and a fitted segment [mm]. Default 0.002.
    arcs : bool
        Fit arcs; with ``False`` only collinear runs are merged into lines.
    min_radius : float
        Smaller arcs are left as lines [mm]. Default 0.01; controllers reject arcs near
        zero radius and such arcs gain nothing.
    max_radius : float
        Larger arcs are left as lines [mm]. Default 5000: centres kilometres away
        turn round-off in the written centre into visible path error.
    max_sweep : float
        Largest angle one arc sweeps [deg]. Default 180, so full circles split in two.
    min_chord : float
        Arcs whose start and end are closer than this are left as lines [mm]. Default
        0.01; it must exceed the rounding of written coordinates many times over, so that
        rounding can never turn a short arc into a near-full circle.
    """

    tolerance: float = 0.002
    arcs: bool = True
    min_radius: float = 0.01
    max_radius: float = 5000.0
    max_sweep: float = 180.0
    min_chord: float = 0.01

    def __post_init__(self) -> None:
        if not (self.tolerance > 0 and math.isfinite(self.tolerance)):
            raise GcodeError(f"arc tolerance must be a positive number of mm, got {self.tolerance}")
        if not 0 < self.max_sweep <= 359.0:
            raise GcodeError(f"max_sweep must lie in (0, 359] deg, got {self.max_sweep}")
        if not 0 < self.min_radius < self.max_radius:
            raise GcodeError("need 0 < min_radius < max_radius")
        if not self.min_chord > 0:
            raise GcodeError("min_chord must be positive")


@dataclass(frozen=True)
class Segments:
    """A path as lines and arcs, what the post writes one block each.

    Attributes
    ----------
    start : (3,) float
        Position before the first segment [mm].
    end : (m, 3) float
        End point of each segment [mm].
    kind : (m,) int8
        :class:`SegmentKind` of each segment.
    centre : (m, 2) float
        Arc centre in XY [mm]; NaN for lines.
    motion : (m,) int8
        :class:`~cadcam.model.Motion` of each segment.
    source_end : (m,) int64
        Index in the input polyline of each segment's end point (the segment replaces the
        input moves ``source_end[k-1] + 1 .. source_end[k]``).
    """

    start: np.ndarray
    end: np.ndarray
    kind: np.ndarray
    centre: np.ndarray
    motion: np.ndarray
    source_end: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "start", frozen_array(self.start).reshape(3))
        object.__setattr__(self, "end", frozen_array(self.end).reshape(-1, 3))
        object.__setattr__(self, "kind", frozen_array(self.kind, dtype=np.int8).reshape(-1))
        object.__setattr__(self, "centre", frozen_array(self.centre).reshape(-1, 2))
        object.__setattr__(self, "motion", frozen_array(self.motion, dtype=np.int8).reshape(-1))
        object.__setattr__(self, "source_end", frozen_array(self.source_end, dtype=np.int64).reshape(-1))
        n = len(self.end)
        if not all(len(a) == n for a in (self.kind, self.centre, self.motion, self.source_end)):
            raise ValueError("Segments arrays must have the same length")

    def __len__(self) -> int:
        return len(self.end)

    @property
    def starts(self) -> np.ndarray:
        """Start point of each segment, ``(m, 3)`` [mm]."""
        return np.vstack([self.start[None, :], self.end[:-1]])

    def sweeps(self) -> np.ndarray:
        """Signed angle each segment sweeps, ``(m,)`` [rad]: + CCW, - CW, 0 for lines."""
        out = np.zeros(len(self))
        arc = self.kind != SegmentKind.LINE
        if arc.any():
            s = self.starts[arc]
            out[arc] = arc_sweep(s[:, :2], self.end[arc, :2], self.centre[arc], self.kind[arc] == SegmentKind.CW)
        return out

    def lengths(self) -> np.ndarray:
        """Path length of each segment, ``(m,)`` [mm]; arcs by arc length (helical)."""
        d = self.end - self.starts
        out = np.linalg.norm(d, axis=1)
        arc = self.kind != SegmentKind.LINE
        if arc.any():
            r = np.linalg.norm(self.starts[arc, :2] - self.centre[arc], axis=1)
            out[arc] = np.hypot(r * np.abs(self.sweeps()[arc]), d[arc, 2])
        return out

    def polyline(self, chord_tolerance: float = 0.001) -> tuple[np.ndarray, np.ndarray]:
        """The segments as a polyline, arcs broken into chords.

        Parameters
        ----------
        chord_tolerance : float
            Largest sagitta of an arc chord [mm].

        Returns
        -------
        points : (k, 3) float
            ``points[0]`` is :attr:`start` [mm].
        segment : (k,) int64
            Index of the segment each point ends (-1 for ``points[0]``).
        """
        pts = [self.start[None, :]]
        seg = [np.array([-1])]
        starts = self.starts
        sweeps = self.sweeps()
        for k in range(len(self)):
            if self.kind[k] == SegmentKind.LINE:
                p = self.end[k][None, :]
            else:
                p = discretize_arc(starts[k], self.end[k], self.centre[k], sweeps[k], chord_tolerance)
            pts.append(p)
            seg.append(np.full(len(p), k))
        return np.vstack(pts), np.concatenate(seg)


def arc_sweep(start_xy: np.ndarray, end_xy: np.ndarray, centre: np.ndarray,
              clockwise: np.ndarray | bool, turns: int = 1) -> np.ndarray:
    """Signed angle an XY arc sweeps from start to end around centre [rad].

    Follows the RS274/NGC rule: the arc runs in its direction from the start angle to the
    first time it reaches the end angle, so an end point equal to the start point means a
    full circle. ``turns > 1`` adds ``turns - 1`` full circles (LinuxCNC's ``P`` word).

    Parameters
    ----------
    start_xy, end_xy, centre : (..., 2) float [mm]
    clockwise : (...) bool
    turns : int

    Returns
    -------
    (...) float
        Negative for clockwise arcs, in ``(0, 2 pi]`` turns for counter-clockwise ones.
    """
    s = np.asarray(start_xy, dtype=np.float64) - centre
    e = np.asarray(end_xy, dtype=np.float64) - centre
    a = np.arctan2(e[..., 1], e[..., 0]) - np.arctan2(s[..., 1], s[..., 0])
    cw = np.asarray(clockwise, dtype=bool)
    ccw_sweep = np.mod(a, 2 * np.pi)
    ccw_sweep = np.where(ccw_sweep <= 0.0, 2 * np.pi, ccw_sweep)
    cw_sweep = np.mod(-a, 2 * np.pi)
    cw_sweep = np.where(cw_sweep <= 0.0, 2 * np.pi, cw_sweep)
    extra = 2 * np.pi * (turns - 1)
    return np.where(cw, -(cw_sweep + extra), ccw_sweep + extra)


def discretize_arc(start: np.ndarray, end: np.ndarray, centre: np.ndarray, sweep: float,
                   chord_tolerance: float, max_chords: int = 1_000_000) -> np.ndarray:
    """Points along an XY arc (helical in Z, spiral in radius) with a bounded sagitta.

    Radius and Z change linearly with the swept angle from the start to the end values,
    as LinuxCNC moves an arc whose end radius differs slightly from its start radius.

    Parameters
    ----------
    start, end : (3,) float
        Arc end points [mm] (Z may be NaN when never programmed: it stays NaN).
    centre : (2,) float
        Centre in XY [mm].
    sweep : float
        Signed swept angle [rad], as from :func:`arc_sweep`.
    chord_tolerance : float
        Largest distance between a chord and the arc [mm].
    max_chords : int
        Refuse arcs that need more chords than this (``GcodeError``).

    Returns
    -------
    (k, 3) float
        Points after the start, the last exactly ``end`` [mm].
    """
    start = np.asarray(start, dtype=np.float64)
    end = np.asarray(end, dtype=np.float64)
    r0 = math.hypot(start[0] - centre[0], start[1] - centre[1])
    r1 = math.hypot(end[0] - centre[0], end[1] - centre[1])
    r = max(r0, r1)
    if r <= chord_tolerance:
        step = math.pi / 2
    else:
        step = 2.0 * math.acos(1.0 - chord_tolerance / r)
    n_f = math.ceil(abs(sweep) / step) if step > 0 else max_chords + 1
    if n_f > max_chords:
        raise GcodeError(f"arc of radius {r:.4g} mm needs over {max_chords} chords at tolerance {chord_tolerance} mm")
    n = max(int(n_f), 1)
    f = np.arange(1, n + 1) / n
    a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
    ang = a0 + sweep * f
    rad = r0 + (r1 - r0) * f
    out = np.empty((n, 3))
    out[:, 0] = centre[0] + rad * np.cos(ang)
    out[:, 1] = centre[1] + rad * np.sin(ang)
    out[:, 2] = start[2] + (end[2] - start[2]) * f
    out[-1] = end
    return out


# --------------------------------------------------------------------------- fitting

#: Where on each input chord the fit is checked besides the vertices (fractions).
_CHORD_SAMPLES = np.array([0.25, 0.5, 0.75])


def _line_error(p: np.ndarray) -> float:
    """Largest distance of the points ``p`` (k, 3) from the segment p[0] -> p[-1] [mm]."""
    a = p[0]
    d = p[-1] - a
    v = p - a
    dd = float(d @ d)
    if dd <= _SAME_POINT**2:
        return math.sqrt(float(np.einsum("ij,ij->i", v, v).max()))
    t = np.minimum(np.maximum((v @ d) / dd, 0.0), 1.0)  # np.clip's values, without its wrapper's cost
    w = v - t[:, None] * d
    return math.sqrt(float(np.einsum("ij,ij->i", w, w).max()))


def _fit_arc(p: np.ndarray, opt: FitOptions) -> tuple[np.ndarray, bool] | None:
    """Fit one XY arc (Z linear in angle) through p[0] and p[-1] to the points ``p`` (k, 3).

    Returns ``(centre, clockwise)`` when every point and every sampled chord point lies
    within tolerance, else None. The centre lies on the bisector of p[0]-p[-1], so the
    arc passes exactly through both ends; its position along the bisector is the
    algebraic least-squares fit to the inner points (linear in one unknown).
    """
    xy = p[:, :2]
    a, b = xy[0], xy[-1]
    chord = b - a
    c_len = math.hypot(chord[0], chord[1])
    if c_len < opt.min_chord:
        return None
    m = 0.5 * (a + b)
    nrm = np.array([-chord[1], chord[0]]) / c_len
    h2 = 0.25 * c_len * c_len
    d = xy[1:-1] - m
    lhs = np.einsum("ij,ij->i", d, d) - h2
    coef = 2.0 * (d @ nrm)
    den = float(coef @ coef)
    if den <= 1e-30:
        return None
    t = float(lhs @ coef) / den
    r = math.sqrt(h2 + t * t)
    if not opt.min_radius <= r <= opt.max_radius:
        return None
    centre = m + t * nrm
    v = xy - centre
    ang = np.arctan2(v[:, 1], v[:, 0])
    dth = ang[1:] - ang[:-1]
    dth = (dth + np.pi) % (2 * np.pi) - np.pi
    if (dth > 0).all():
        cw = False
    elif (dth < 0).all():
        cw = True
    else:
        return None
    theta = np.concatenate([[0.0], np.cumsum(dth)])
    total = theta[-1]
    if abs(total) > math.radians(opt.max_sweep) + 1e-12:
        return None
    z0, z1 = p[0, 2], p[-1, 2]
    tol2 = opt.tolerance**2
    # Vertices.
    rad_err = np.hypot(v[:, 0], v[:, 1]) - r
    z_err = p[:, 2] - (z0 + (z1 - z0) * theta / total)
    if float((rad_err * rad_err + z_err * z_err).max()) > tol2:
        return None
    # Points along every input chord: catches sparse points on a wrong-radius circle.
    f = _CHORD_SAMPLES[None, :, None]
    q = p[:-1, None, :] * (1.0 - f) + p[1:, None, :] * f  # (k-1, s, 3)
    th = theta[:-1, None] * (1.0 - f[..., 0]) + theta[1:, None] * f[..., 0]
    qv = q[..., :2] - centre
    rad_err = np.hypot(qv[..., 0], qv[..., 1]) - r
    z_err = q[..., 2] - (z0 + (z1 - z0) * th / total)
    if float((rad_err * rad_err + z_err * z_err).max()) > tol2:
        return None
    return centre, cw


#: Windows of up to this many moves are first judged for every start at once (:class:`_Screen`).
_SCREEN_MOVES = 4
#: Starts judged per batch of array operations (bounds the screen's memory).
_SCREEN_BATCH = 16_384
#: A bound on the relative rounding of one floating-point operation, with room to spare (eps is 2.2e-16).
_ROUND = 1e-15


class _Screen:
    """The short windows' tests, judged for every start at once where the answer is sure.

    :func:`fit_segments` asks its windows one at a time, each a dozen small numpy calls, and most are
    short: a relief's raster asks 3 to 5 points at a time, over hundreds of thousands of starts. Here
    each window length is one set of array operations over all starts. Its sums run in another order
    than the exact tests' (a BLAS dot may fuse a multiply and an add), so it judges a window only where
    the answer is clear of every limit by more than a bound on that rounding: a line surely within or
    surely beyond tolerance, an arc that surely fails. An arc that may fit is left to :func:`_fit_arc`
    (which gives its centre), as is any window nearer a limit: the fit is the one the exact tests give.

    ``line[s, k]``: 1 (within), 0 (beyond) or -1 (ask) for the line ``s .. s + k``; ``arc_fails[s, k]``:
    the arc ``s .. s + k`` surely fails.
    """

    def __init__(self, pts: np.ndarray, opt: FitOptions):
        n = len(pts)
        moves = max(min(_SCREEN_MOVES, n - 1), 0)
        self.moves = moves
        self.line = np.full((n, moves + 1), -1, dtype=np.int8)
        self.arc_fails = np.zeros((n, moves + 1), dtype=bool)
        for k in range(2, moves + 1):
            for s0 in range(0, n - k, _SCREEN_BATCH):
                s1 = min(s0 + _SCREEN_BATCH, n - k)
                win = np.stack([pts[s0 + j:s1 + j] for j in range(k + 1)])  # (k + 1, starts, 3)
                self.line[s0:s1, k] = _lines_within(win, opt.tolerance)
                if opt.arcs:
                    self.arc_fails[s0:s1, k] = _arcs_fail(win, opt)

    def line_within(self, s: int, e: int) -> int:
        """1, 0 or -1 (ask :func:`_line_error`) for the line from point ``s`` to ``e``."""
        return int(self.line[s, e - s]) if e - s <= self.moves else -1

    def arc_surely_fails(self, s: int, e: int) -> bool:
        return e - s <= self.moves and bool(self.arc_fails[s, e - s])


def _lines_within(win: np.ndarray, tol: float) -> np.ndarray:
    """:func:`_line_error` <= ``tol`` of each window ``win[:, i]`` ((k + 1, m, 3)): 1, 0, or -1 where unsure."""
    a = win[0]
    d = win[-1] - a
    v = win - a
    dd = (d * d).sum(-1)
    with np.errstate(all="ignore"):
        t = np.minimum(np.maximum((v * d).sum(-1) / dd, 0.0), 1.0)
    w = v - t[..., None] * d
    err = np.sqrt((w * w).sum(-1).max(0))
    # Rounding moves t by a few eps * |v| / |d| and so w by a few eps * |v|, whatever |d| is.
    slack = 64 * _ROUND * (np.abs(v).sum(-1).max(0) + 1.0)
    out = np.where(err <= tol - slack, 1, np.where(err > tol + slack, 0, -1)).astype(np.int8)
    out[~(dd > 4 * _SAME_POINT**2)] = -1  # (near) one point: _line_error measures from it
    return out


def _arcs_fail(win: np.ndarray, opt: FitOptions) -> np.ndarray:
    """Whether :func:`_fit_arc` surely returns None for each window ``win[:, i]`` ((k + 1, m, 3)).

    The same quantities, each carried with a bound on how far rounding may have moved it from the exact
    test's; a check fails surely when it fails by more than that bound."""
    e = _ROUND
    xy, z = win[..., :2], win[..., 2]
    a, b = xy[0], xy[-1]
    chord = b - a  # as the exact test: the same subtraction
    c_len = np.hypot(chord[:, 0], chord[:, 1])
    # Points on one line x = const or y = const (a raster's pass): the exact test's every d . nrm is a sum of
    # products each exactly zero, so its den is 0 whatever the order of the sum.
    straight = (xy[..., 0] == xy[0, :, 0]).all(0) | (xy[..., 1] == xy[0, :, 1]).all(0)
    fail = (c_len < opt.min_chord * (1 - 4 * e)) | straight
    judge = (c_len > opt.min_chord * (1 + 4 * e)) & ~straight
    with np.errstate(all="ignore"):
        m = 0.5 * (a + b)
        nrm = np.stack([-chord[:, 1], chord[:, 0]], axis=-1) / c_len[:, None]
        h2 = 0.25 * c_len * c_len
        d = xy[1:-1] - m
        coef = 2.0 * (d * nrm).sum(-1)
        lhs = (d * d).sum(-1) - h2
        e_coef = 16 * e * np.abs(d).sum(-1)
        e_lhs = 16 * e * ((d * d).sum(-1) + h2)
        den = (coef * coef).sum(0)
        den_hi = ((np.abs(coef) + e_coef) ** 2).sum(0) * (1 + 8 * e)
        den_lo = (np.maximum(np.abs(coef) - e_coef, 0.0) ** 2).sum(0) * (1 - 8 * e)
        fail |= judge & (den_hi <= 1e-30)
        judge &= den_lo > 1e-30
        num = (lhs * coef).sum(0)
        t = num / den
        e_num = (np.abs(lhs) * e_coef + e_lhs * np.abs(coef) + e_coef * e_lhs).sum(0) + 8 * e * np.abs(lhs * coef).sum(0)
        e_den = den_hi - den_lo + 8 * e * den
        e_t = (e_num + np.abs(t) * e_den) / den_lo + 8 * e * np.abs(t)
        r = np.sqrt(h2 + t * t)
        e_r = e_t + 8 * e * r
        fail |= judge & ((r - e_r > opt.max_radius) | (r + e_r < opt.min_radius))
        judge &= (r - e_r >= opt.min_radius) & (r + e_r <= opt.max_radius)
        centre = m + t[:, None] * nrm
        e_c = e_t + 16 * e * (np.abs(m).sum(-1) + np.abs(t) + 1.0)  # the centre's shift [mm]
        v = xy - centre
        rho = np.hypot(v[..., 0], v[..., 1])
        ang = np.arctan2(v[..., 1], v[..., 0])
        e_ang = ((e_c + 16 * e * rho) / rho + 16 * e).max(0)  # each angle's [rad]
        dth = ang[1:] - ang[:-1]
        dth = (dth + np.pi) % (2 * np.pi) - np.pi
        de = 2 * e_ang + 16 * e
        # Only where each shift is small beside the point's distance, and no step is near the half turn
        # that the wrap would flip.
        judge &= (e_c < 1e-6 * rho.min(0)) & (np.abs(dth) < np.pi - 1e-6).all(0)
        pos, neg = (dth > de).all(0), (dth < -de).all(0)
        fail |= judge & (dth > de).any(0) & (dth < -de).any(0)
        judge &= pos | neg
        theta = np.concatenate([np.zeros((1, dth.shape[1])), np.cumsum(dth, axis=0)])
        total = theta[-1]
        k = len(dth)
        e_tot = k * de + 16 * e * k * np.abs(total)
        sweep = math.radians(opt.max_sweep) + 1e-12
        fail |= judge & (np.abs(total) - e_tot > sweep)
        judge &= (np.abs(total) + e_tot <= sweep) & (np.abs(total) > 2 * e_tot)
        z0, z1 = z[0], z[-1]
        # How far each point's distance from the exact test's arc may have moved [mm].
        bound = (e_c + e_r + 16 * e * (rho.max(0) + r) + np.abs(z1 - z0) * 4 * e_tot / np.abs(total)
                 + 16 * e * (np.abs(z).max(0) + 1.0))
        far = opt.tolerance + 2 * bound
        err = np.hypot(rho - r, z - (z0 + (z1 - z0) * theta / total)).max(0)
        f = _CHORD_SAMPLES[None, :, None, None]
        q = win[:-1, None] * (1.0 - f) + win[1:, None] * f  # (k, s, m, 3)
        th = theta[:-1, None] * (1.0 - f[..., 0]) + theta[1:, None] * f[..., 0]
        qv = q[..., :2] - centre
        q_err = np.hypot(np.hypot(qv[..., 0], qv[..., 1]) - r, q[..., 2] - (z0 + (z1 - z0) * th / total))
        fail |= judge & ((err > far) | (q_err.max(axis=(0, 1)) > far))
    return fail


def _longest(ok: Callable[[int, int], object], s: int, first: int, stop: int, step: int) -> tuple[int, object]:
    """Largest ``e`` in ``[first, stop]`` with ``ok(s, e)`` truthy, by doubling then bisection.

    Returns ``(e, ok(s, e))``, or ``(first - 1, None)`` when even ``first`` fails. Assumes
    that a window that fits mostly implies its shorter windows fit (true for lines and
    arcs up to noise): the result is a window that fits, not always the longest one.
    """
    if first > stop:
        return first - 1, None
    res = ok(s, first)
    if not res:
        return first - 1, None
    good, good_res = first, res
    bad = None
    step = max(1, step)
    while good < stop:
        e = min(good + step, stop)
        res = ok(s, e)
        if res:
            good, good_res = e, res
            step *= 2
        else:
            bad = e
            break
    if bad is not None:
        while bad - good > 1:
            mid = (good + bad) // 2
            res = ok(s, mid)
            if res:
                good, good_res = mid, res
            else:
                bad = mid
    return good, good_res


def fit_segments(points: np.ndarray, motion: np.ndarray, options: FitOptions = FitOptions(), *,
                 progress: Callable[[int, int], None] | None = None) -> Segments:
    """Fit lines and arcs to a polyline of cutter locations.

    Parameters
    ----------
    points : (n, 3) float
        Cutter locations [mm], n >= 1.
    motion : (n,) int
        :class:`~cadcam.model.Motion` of the move ending at each point (``motion[0]`` is
        ignored). Segments never span a change of motion; rapids are never arcs.
    options : FitOptions
    progress : callable, optional
        Called as ``progress(points_done, n)``.

    Returns
    -------
    Segments
        Starting at ``points[0]``; zero-length moves are dropped.

    Raises
    ------
    GcodeError
        Non-finite points or mismatched shapes.
    """
    pts = np.asarray(points, dtype=np.float64)
    mot = np.asarray(motion).astype(np.int8).reshape(-1)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) != len(mot) or len(pts) == 0:
        raise GcodeError(f"need (n, 3) points and (n,) motion with n >= 1, got {pts.shape} and {mot.shape}")
    if not np.isfinite(pts).all():
        raise GcodeError("cutter locations contain NaN or infinity")
    # Zero-length moves carry nothing a controller can execute; they would also confuse the
    # angle monotonicity test of arcs.
    keep = np.ones(len(pts), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(pts, axis=0), axis=1) > _SAME_POINT
    idx = np.flatnonzero(keep)
    pts, mot = pts[idx], mot[idx]
    n = len(pts)
    tol = options.tolerance

    screen = _Screen(pts, options)  # the short windows judged at once, where sure

    def line_ok(s: int, e: int) -> bool:
        if e == s + 1:
            return True
        sure = screen.line_within(s, e)
        return bool(sure) if sure >= 0 else _line_error(pts[s:e + 1]) <= tol

    def arc_ok(s: int, e: int) -> tuple[np.ndarray, bool] | None:
        return None if screen.arc_surely_fails(s, e) else _fit_arc(pts[s:e + 1], options)

    ends: list[int] = []
    kinds: list[int] = []
    centres: list[np.ndarray] = []
    motions: list[int] = []
    nan2 = np.array([np.nan, np.nan])
    # Runs of equal motion: moves run_start+1 .. run_end share motion[run_start+1].
    change = np.flatnonzero(mot[2:] != mot[1:-1]) + 1 if n > 2 else np.array([], dtype=np.int64)
    bounds = np.concatenate([[0], change, [n - 1]]).astype(np.int64)
    hint_line = hint_arc = 1
    reported, report_every = 0, max(1, n // 200)
    for r in range(len(bounds) - 1):
        s, stop = int(bounds[r]), int(bounds[r + 1])
        kind_motion = int(mot[s + 1]) if stop > s else 0
        try_arcs = options.arcs and kind_motion != Motion.RAPID
        while s < stop:
            e_line, _ = _longest(line_ok, s, s + 1, stop, hint_line)
            e_arc, fit = (_longest(arc_ok, s, s + 2, stop, hint_arc) if try_arcs else (s, None))
            if fit is not None and e_arc > e_line:
                centre, cw = fit
                ends.append(e_arc)
                kinds.append(SegmentKind.CW if cw else SegmentKind.CCW)
                centres.append(centre)
                hint_arc = max(1, (e_arc - s) // 2)
                s = e_arc
            else:
                ends.append(e_line)
                kinds.append(SegmentKind.LINE)
                centres.append(nan2)
                hint_line = max(1, (e_line - s) // 2)
                s = e_line
            motions.append(kind_motion)
            if progress is not None and s - reported >= report_every:
                reported = s
                progress(s, n - 1)
    if progress is not None:
        progress(n - 1, n - 1)
    m = len(ends)
    seg = Segments(
        start=pts[0],
        end=pts[np.asarray(ends, dtype=np.int64)] if m else np.empty((0, 3)),
        kind=np.asarray(kinds, dtype=np.int8),
        centre=np.asarray(centres).reshape(-1, 2) if m else np.empty((0, 2)),
        motion=np.asarray(motions, dtype=np.int8),
        source_end=idx[np.asarray(ends, dtype=np.int64)] if m else np.empty(0, dtype=np.int64),
    )
    log.debug("fitted %d moves as %d segments (%d arcs)", n - 1, m, int((seg.kind != SegmentKind.LINE).sum()))
    return seg
