"""Material-removal simulation of a 3-axis program on a z-map, and the checks behind ``factory verify``.

The stock is a heightfield: one top height per grid point (:func:`cadcam.heightmap.grid_over`).
Every move lowers it to the *swept lower envelope* of the tool: for a grid point ``q`` and a
move from ``p0`` to ``p1`` (tool tip positions),

    env(q) = min over t in [0, 1] of  z(t) + h(|q - p_xy(t)|)

with ``h`` = :meth:`Tool.profile_height` (infinite beyond the radius: above the profile
the tool is a cylinder, which never reaches lower than its own profile). ``r(t) =
|q - p_xy(t)|`` is convex in ``t``, ``h`` is convex and increasing on ``[0, R]`` and ``z``
is linear, so the function is convex on the interval where ``r(t) <= R`` and the minimum
is found exactly:

* flat end mill: linear on that interval, so one of its ends;
* ball end mill: the lowest point of the capsule the ball centre sweeps, closed form;
* bull-nose: bisection on the sign of the derivative over that interval (the minimiser to
  1e-6 mm; the error in height is second order in that);
* horizontal or vertical moves, any shape: closest point on the segment.

Everything is exact at the grid points: a gouge, the remaining stock and a rapid's
penetration depth are true values there, and what the grid can miss is detail *between*
points (cost grows as ``1 / cell**2``). A gouge beyond the tolerance is measured from the
lowest part top within the tolerance sideways, so a wall nicked within the tolerance does
not read as a cut of the wall's height.

Each move covers the grid points within the tool radius of its XY segment, enumerated
exactly row by row; (grid point, move) pairs from consecutive moves are evaluated in
vectorised batches. A cheap lower bound (lowest tip height plus the profile at the nearest
approach) skips the exact evaluation wherever the move cannot go below the stock. Cuts
within a batch commute (the stock keeps the minimum), so only rapids that actually reach
into the stock are replayed in order, against the stock as every earlier move left it.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cadcam.heightmap import Grid, grid_over, upper_envelope
from cadcam.model import Motion, Operation, ProgramMoves, Setup, Tool
from factory.errors import VerifyError

log = logging.getLogger(__name__)

#: (grid point, move) pairs per vectorised batch: small enough for the work arrays to stay in cache.
_PAIR_BUDGET = 1 << 16

#: Bull-nose tools: bisect until the minimiser is known to this along the move [mm]. The
#: height error is second order in it (``f' = 0`` there), far below a nanometre.
_BISECT_RESOLUTION = 1e-6

#: Largest grid the simulation accepts (two float64 maps of this size plus work arrays).
_MAX_CELLS = 60_000_000


@dataclass(frozen=True)
class VerifyOptions:
    """How finely to simulate and what counts as a fault.

    Attributes
    ----------
    cell : float
        Grid spacing [mm]. Results are exact at the grid points; features narrower than a
        cell (a gouge by a tool corner between two points, a thin rib of stock) can be
        missed. Halving the cell quadruples memory and run time; the default puts 250 000
        points (2 MB per map) on a 100 x 100 mm stock.
    gouge_tolerance : float
        The part may be cut this deep before it counts as a gouge [mm].
    rapid_tolerance : float
        A rapid whose tool reaches more than this deep into the remaining stock is a crash [mm].
    """

    cell: float = 0.2
    gouge_tolerance: float = 0.01
    rapid_tolerance: float = 0.01


@dataclass(frozen=True)
class Simulation:
    """The stock after the program and the part, sampled on the same grid.

    Attributes
    ----------
    grid : Grid
        Covers the stock's XY footprint (:func:`grid_over`): material is only tracked
        inside the stock box, so a tool overhanging its sides cuts nothing there.
    stock_top : (ny, nx) float
        Top of the remaining stock at each grid point after the program [mm] (read-only).
    part_top : (ny, nx) float
        Highest part surface at each grid point [mm]; ``-inf`` where there is no part
        (outside it, through holes) (read-only).
    stock_bottom : float
        Bottom of the stock [mm]; the stock top can be cut below it (through cuts).
    """

    grid: Grid
    stock_top: np.ndarray
    part_top: np.ndarray
    stock_bottom: float

    @property
    def remaining(self) -> np.ndarray:
        """(ny, nx) float stock left above the part [mm]: negative is a gouge, NaN where no part."""
        with np.errstate(invalid="ignore"):
            return np.where(np.isfinite(self.part_top), self.stock_top - self.part_top, np.nan)


@dataclass(frozen=True)
class RapidCrash:
    """A rapid (G0) move that reaches into the remaining stock.

    Attributes
    ----------
    line : int
        1-based source line of the move.
    depth : float
        Deepest penetration into the stock as it was before the move [mm].
    position : tuple of 3 float
        Where that happened: grid point X, Y and the tool's lowest Z there [mm].
    move : int
        Index of the move's end point in :attr:`ProgramMoves.points`.
    """

    line: int
    depth: float
    position: tuple[float, float, float]
    move: int

    def to_dict(self) -> dict[str, Any]:
        return {"line": self.line, "depth": self.depth, "position": list(self.position), "move": self.move}


@dataclass(frozen=True)
class VerifyReport:
    """What the simulation found.

    Attributes
    ----------
    max_gouge : float
        Deepest cut into the part over the grid points [mm], 0 if the part is untouched.
        A cut deeper than ``gouge_tolerance`` is measured from the lowest part top within
        ``gouge_tolerance`` sideways of the point, so a vertical wall nicked by less than
        the tolerance is no gouge of the wall's height (see :func:`_lowest_part_near`).
    gouge_position : tuple of 3 float or None
        X, Y of that grid point and the stock top Z there [mm]; None without a gouge.
    gouge_line : int or None
        Source line of the first move that cut that deep there; None without a gouge.
    remaining_max, remaining_mean, remaining_p95 : float
        Stock left above the part over the grid points the part covers [mm] (max, mean,
        95th percentile; a gouge counts as negative).
    rapid_crashes : tuple of RapidCrash
        In program order.
    moves : int
        Moves simulated (both end points known).
    cut_length, rapid_length : float
        Path length of feed moves and of rapids [mm].
    cells : int
        Grid points.
    cell : float
        Grid spacing [mm].
    gouge_tolerance, rapid_tolerance : float
        The tolerances the verdict used [mm].
    """

    max_gouge: float
    gouge_position: tuple[float, float, float] | None
    gouge_line: int | None
    remaining_max: float
    remaining_mean: float
    remaining_p95: float
    rapid_crashes: tuple[RapidCrash, ...]
    moves: int
    cut_length: float
    rapid_length: float
    cells: int
    cell: float
    gouge_tolerance: float = 0.01
    rapid_tolerance: float = 0.01

    @property
    def gouged(self) -> bool:
        """True if the program cuts deeper into the part than the gouge tolerance."""
        return self.max_gouge > self.gouge_tolerance

    @property
    def ok(self) -> bool:
        """No gouge beyond tolerance and no rapid into the stock."""
        return not self.gouged and not self.rapid_crashes

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (plain floats, ints, lists and None)."""
        return {
            "ok": self.ok,
            "max_gouge": self.max_gouge,
            "gouge_position": None if self.gouge_position is None else list(self.gouge_position),
            "gouge_line": self.gouge_line,
            "remaining_max": self.remaining_max,
            "remaining_mean": self.remaining_mean,
            "remaining_p95": self.remaining_p95,
            "rapid_crashes": [c.to_dict() for c in self.rapid_crashes],
            "moves": self.moves,
            "cut_length": self.cut_length,
            "rapid_length": self.rapid_length,
            "cells": self.cells,
            "cell": self.cell,
            "gouge_tolerance": self.gouge_tolerance,
            "rapid_tolerance": self.rapid_tolerance,
        }


# --------------------------------------------------------------------------------------
# Swept envelope of one tool along one straight move, per (grid point, move) pair
# --------------------------------------------------------------------------------------


def _profile(r: np.ndarray, flat_radius: np.ndarray, rc: np.ndarray) -> np.ndarray:
    """:meth:`Tool.profile_height` for per-pair tool sizes, clamped at the radius (no inf)."""
    d = np.minimum(np.maximum(r - flat_radius, 0.0), rc)
    return rc - np.sqrt(np.maximum(rc * rc - d * d, 0.0))


_FLAT, _BALL, _BULL = 0, 1, 2


@dataclass
class _Segments:
    """Straight moves with the size of the tool that makes them: contiguous 1-D arrays, one row each.

    ``x, y, z`` is the start (tool tip) and ``dx, dy, dz`` the displacement to the end [mm].
    ``move`` is the index of the end point in :attr:`ProgramMoves.points`.
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    dx: np.ndarray
    dy: np.ndarray
    dz: np.ndarray
    radius: np.ndarray
    rc: np.ndarray
    rapid: np.ndarray
    move: np.ndarray

    def __post_init__(self) -> None:
        self.l2 = self.dx * self.dx + self.dy * self.dy
        has_len = self.l2 > 1e-18
        self.inv_l2 = np.where(has_len, 1.0 / np.where(has_len, self.l2, 1.0), 0.0)
        # Horizontal or vertical: the nearest approach is also the lowest (closed form for every shape).
        self.trivial = ~has_len | (self.dz == 0.0)
        self.zmin = self.z + np.minimum(self.dz, 0.0)
        self.reach2 = self.radius * self.radius * (1 + 1e-12)
        self.flat_radius = self.radius - self.rc
        ball = np.abs(self.rc - self.radius) <= 1e-12 * np.maximum(self.radius, 1.0)
        self.shape = np.where(self.rc == 0.0, _FLAT, np.where(ball, _BALL, _BULL)).astype(np.int8)

    def __len__(self) -> int:
        return len(self.x)

    @classmethod
    def between(cls, p0, p1, radius, rc, rapid=None, move=None) -> "_Segments":
        k = len(p0)
        return cls(
            np.ascontiguousarray(p0[:, 0]), np.ascontiguousarray(p0[:, 1]), np.ascontiguousarray(p0[:, 2]),
            p1[:, 0] - p0[:, 0], p1[:, 1] - p0[:, 1], p1[:, 2] - p0[:, 2],
            np.asarray(radius, dtype=np.float64), np.asarray(rc, dtype=np.float64),
            np.zeros(k, bool) if rapid is None else rapid, np.arange(k) if move is None else move,
        )

    def sub(self, s: int, e: int) -> "_Segments":
        out = object.__new__(_Segments)
        for name, value in vars(self).items():
            setattr(out, name, value[s:e])
        return out


def _pair_envelope(
    qx: np.ndarray, qy: np.ndarray, owner: np.ndarray, seg: _Segments, bound: np.ndarray | None = None
) -> np.ndarray:
    """Lowest point of the swept tool above each query point, one (point, move) pair per entry.

    Parameters
    ----------
    qx, qy : (k,) float
        Query points [mm].
    owner : (k,) int
        Row of ``seg`` (the move) for each query point.
    seg : _Segments
    bound : (k,) float, optional
        Only envelopes below this matter [mm] (the current stock top): pairs whose cheap
        lower bound is not below it are not evaluated exactly and come back as ``inf``.

    Returns
    -------
    (k,) float
        Envelope height [mm]; ``inf`` where the tool never comes within its radius (or,
        with ``bound``, where it provably stays at or above the bound).
    """
    env = np.full(len(qx), np.inf)
    if len(qx) == 0:
        return env
    wx = qx - seg.x[owner]
    wy = qy - seg.y[owner]
    dx = seg.dx[owner]
    dy = seg.dy[owner]
    wd = wx * dx
    wd += wy * dy
    t = wd * seg.inv_l2[owner]
    np.clip(t, 0.0, 1.0, out=t)
    ex = t * dx
    np.subtract(wx, ex, out=ex)
    ey = np.multiply(t, dy, out=t)
    np.subtract(wy, ey, out=ey)
    dist2 = np.multiply(ex, ex, out=ex)
    dist2 += ey * ey
    del ey, dx, dy
    # Lowest tip height plus the profile at the nearest approach: exact for horizontal
    # and vertical moves, a lower bound otherwise (z(t) >= zmin and r(t) >= distance).
    lower = seg.zmin[owner]
    if np.any(seg.shape != _FLAT):
        lower += _profile(np.sqrt(dist2), seg.flat_radius[owner], seg.rc[owner])
    cand = dist2 <= seg.reach2[owner]
    if bound is not None:
        cand &= lower < bound
    idx = np.flatnonzero(cand)
    if len(idx) == 0:
        return env
    o = owner[idx]
    out = lower[idx]
    sloped = np.flatnonzero(~seg.trivial[o])
    if len(sloped):
        j = idx[sloped]
        os_ = o[sloped]
        out[sloped] = _sloped_envelope(wx[j], wy[j], wd[j], os_, seg)
    env[idx] = out
    return env


def _sloped_envelope(wx, wy, wd, o, seg: _Segments) -> np.ndarray:
    """Exact envelope for moves that climb or descend while moving sideways (``o``: move rows)."""
    dx, dy, dz, z0 = seg.dx[o], seg.dy[o], seg.dz[o], seg.z[o]
    l2, R, rc = seg.l2[o], seg.radius[o], seg.rc[o]
    shape = seg.shape[o]
    # Interval of t where r(t) <= R: roots of l2 t^2 - 2 wd t + |w|^2 - R^2; the
    # discriminant written with the cross product avoids cancellation.
    cross = wx * dy - wy * dx
    s = np.sqrt(np.maximum(l2 * R * R - cross * cross, 0.0))
    ta = np.clip((wd - s) / l2, 0.0, 1.0)
    tb = np.maximum(np.clip((wd + s) / l2, 0.0, 1.0), ta)
    # Flat end mill: linear in t on the interval, so one of its ends. Also the fallback
    # for ball points right at the reach limit (see below).
    out = z0 + np.minimum(dz * ta, dz * tb)

    ball = np.flatnonzero(shape == _BALL)
    if len(ball):
        m = ball if len(ball) < len(out) else slice(None)
        Rb, z0b, dzb, l2b, wdb = R[m], z0[m], dz[m], l2[m], wd[m]
        R2 = Rb * Rb
        # Lowest entry of the vertical line through q into the capsule swept by the ball
        # centre: the infinite cylinder round the centre's path if the entry's foot lies on
        # the move, else one of the end spheres (both are inside the capsule, so the
        # minimum of all valid candidates is the entry).
        D2 = l2b + dzb * dzb
        u = (dzb * wdb - np.sqrt(D2) * s[m]) / l2b
        t = (wdb + dzb * u) / D2
        best = np.where((t >= 0.0) & (t <= 1.0), z0b + Rb + u, np.inf)
        w2 = wx[m] ** 2 + wy[m] ** 2
        e2 = (wx[m] - dx[m]) ** 2 + (wy[m] - dy[m]) ** 2
        best = np.minimum(best, np.where(w2 <= R2, z0b + Rb - np.sqrt(np.maximum(R2 - w2, 0.0)), np.inf))
        best = np.minimum(best, np.where(e2 <= R2, z0b + dzb + Rb - np.sqrt(np.maximum(R2 - e2, 0.0)), np.inf))
        # Rounding can leave a point right at the reach limit without a valid candidate;
        # the tool touches it only with its rim there, at the interval end's height + R.
        out[m] = np.where(np.isfinite(best), best, out[m] + Rb)

    bull = np.flatnonzero(shape == _BULL)
    if len(bull):
        m = bull
        out[m] = _bisect_envelope(wx[m], wy[m], dx[m], dy[m], z0[m], dz[m], R[m] - rc[m], rc[m], ta[m], tb[m])
    return out


def _bisect_envelope(wx, wy, dx, dy, z0, dz, a, rc, ta, tb) -> np.ndarray:
    """Minimum of the convex ``f(t) = z0 + dz t + h(r(t))`` on ``[ta, tb]``.

    ``f`` is C1 inside the interval (the bull-nose profile is flat at ``r = 0`` and
    tangent where the corner starts), so its minimum is an end or a zero of the
    non-decreasing ``f'``, found by bisection on the sign of ``f'``.
    """

    def f(t: np.ndarray) -> np.ndarray:
        ex = wx - t * dx
        ey = wy - t * dy
        return z0 + dz * t + _profile(np.sqrt(ex * ex + ey * ey), a, rc)

    lo, hi = ta.copy(), tb.copy()
    rc2 = rc * rc
    span = float(np.max((tb - ta) * np.sqrt(dx * dx + dy * dy + dz * dz)))
    steps = int(np.clip(math.ceil(math.log2(max(span, 1e-300) / _BISECT_RESOLUTION)), 1, 60))
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        ex = wx - mid * dx
        ey = wy - mid * dy
        r = np.sqrt(ex * ex + ey * ey)
        d = np.minimum(np.maximum(r - a, 0.0), rc)
        # f' = dz + h'(r) r'(t), h' = d / sqrt(rc^2 - d^2), r' = -(e . d) / r; the tiny
        # floors only matter where h' is 0 (d = 0) or the tool rim is reached.
        slope = dz - d * (ex * dx + ey * dy) / (np.sqrt(np.maximum(rc2 - d * d, 1e-300)) * np.maximum(r, 1e-300))
        right = slope < 0.0
        np.copyto(lo, mid, where=right)
        np.copyto(hi, mid, where=~right)
    return np.minimum(f(0.5 * (lo + hi)), np.minimum(f(ta), f(tb)))


def swept_envelope(q: np.ndarray, start: np.ndarray, end: np.ndarray, tool: Tool) -> np.ndarray:
    """Lowest point of ``tool`` moved in a straight line from ``start`` to ``end``, above each point.

    Parameters
    ----------
    q : (k, 2) float
        XY query points [mm].
    start, end : (3,) float
        Tool tip positions at the ends of the move [mm].
    tool : Tool

    Returns
    -------
    (k,) float
        Height of the swept tool's lower surface at each point [mm]; ``inf`` where the
        tool never passes over the point.
    """
    q = np.asarray(q, dtype=np.float64).reshape(-1, 2)
    p0 = np.asarray(start, dtype=np.float64).reshape(1, 3)
    p1 = np.asarray(end, dtype=np.float64).reshape(1, 3)
    seg = _Segments.between(p0, p1, [tool.radius], [float(tool.corner_radius)])
    return _pair_envelope(q[:, 0].copy(), q[:, 1].copy(), np.zeros(len(q), np.int64), seg)


def _row_spans(seg: _Segments, grid: Grid) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The grid points each move's tool passes over, as runs of columns on each grid row.

    The region is the set of points within the tool radius of the move's XY segment (a
    stadium); its intersection with a row is one interval: the union of those of the two
    end disks and of the band along the segment.

    Returns
    -------
    owner, row, first, count : (r,) int64
        Move, grid row, first column and number of columns of each run (count may be 0).
    """
    R = seg.radius * (1 + 1e-9) + 1e-9  # the exact reach test comes later; never lose a point here
    x1, y1 = seg.x + seg.dx, seg.y + seg.dy
    j0, j1 = grid.row_range(np.minimum(seg.y, y1) - R, np.maximum(seg.y, y1) + R)
    nj = np.maximum(j1 - j0 + 1, 0)
    owner = np.repeat(np.arange(len(seg)), nj)
    row = np.repeat(j0, nj) + (np.arange(int(nj.sum())) - np.repeat(np.cumsum(nj) - nj, nj))
    yr = grid.y0 + row * grid.cell
    Ro = R[owner]
    ax, ay, dx, dy = seg.x[owner], seg.y[owner], seg.dx[owner], seg.dy[owner]

    def disk(cx, cy):
        h2 = Ro * Ro - (yr - cy) ** 2
        half = np.sqrt(np.maximum(h2, 0.0))
        return np.where(h2 >= 0, cx - half, np.inf), np.where(h2 >= 0, cx + half, -np.inf)

    lo_a, hi_a = disk(ax, ay)
    lo_b, hi_b = disk(ax + dx, ay + dy)
    # Band: 0 <= (p - a).d <= |d|^2 and |(p - a) x d| <= R |d|, each linear in x on the row.
    ey = yr - ay
    l2 = dx * dx + dy * dy
    L = np.sqrt(l2)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        u_lo, u_hi = -ey * dy / dx, (l2 - ey * dy) / dx
        v_lo, v_hi = (ey * dx - Ro * L) / dy, (ey * dx + Ro * L) / dy
    along_all = (dx == 0) & (ey * dy >= 0) & (ey * dy <= l2)
    across_all = (dy == 0) & (np.abs(ey * dx) <= Ro * L)
    lo_u = np.where(dx != 0, np.minimum(u_lo, u_hi), np.where(along_all, -np.inf, np.inf))
    hi_u = np.where(dx != 0, np.maximum(u_lo, u_hi), np.where(along_all, np.inf, -np.inf))
    lo_v = np.where(dy != 0, np.minimum(v_lo, v_hi), np.where(across_all, -np.inf, np.inf))
    hi_v = np.where(dy != 0, np.maximum(v_lo, v_hi), np.where(across_all, np.inf, -np.inf))
    band = l2 > 1e-18
    lo_band = np.where(band, ax + np.maximum(lo_u, lo_v), np.inf)
    hi_band = np.where(band, ax + np.minimum(hi_u, hi_v), -np.inf)
    lo = np.minimum(np.minimum(lo_a, lo_b), lo_band)
    hi = np.maximum(np.maximum(hi_a, hi_b), hi_band)
    first, last = grid.column_range(lo, hi)
    return owner, row, first, np.maximum(last - first + 1, 0)


# --------------------------------------------------------------------------------------
# The simulation
# --------------------------------------------------------------------------------------


def _check_inputs(setup: Setup, options: VerifyOptions, tri: Any) -> np.ndarray:
    for name in ("cell", "gouge_tolerance", "rapid_tolerance"):
        v = getattr(options, name)
        if not (math.isfinite(v) and (v > 0 if name == "cell" else v >= 0)):
            kind = "positive" if name == "cell" else "non-negative"
            raise VerifyError(f"{name} must be a {kind} number of mm, got {v}", source=name)
    tri = np.asarray(tri, dtype=np.float64)
    if tri.ndim != 3 or tri.shape[1:] != (3, 3):
        raise VerifyError(f"part triangles must have shape (m, 3, 3), got {tri.shape}", source="part")
    if len(tri) == 0:
        raise VerifyError("the part mesh has no triangles", source="part")
    if not np.all(np.isfinite(tri)):
        raise VerifyError("the part mesh holds non-finite coordinates", source="part")
    size = setup.stock_size
    if not (np.all(np.isfinite(size)) and np.all(size > 0)):
        raise VerifyError(
            f"stock box is empty: {setup.stock_min.tolist()} .. {setup.stock_max.tolist()}", source="stock"
        )
    cells = math.ceil(size[0] / options.cell) * math.ceil(size[1] / options.cell)
    if cells > _MAX_CELLS:
        raise VerifyError(
            f"{cells} grid cells at {options.cell} mm is too many (limit {_MAX_CELLS}); use a coarser cell",
            source="cell",
        )
    return tri


def _tool_table(moves: ProgramMoves, tools: Mapping[int, Tool], use: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Radius and corner radius of the tool in the spindle for each move; NaN where none.

    Raises VerifyError for a feed move with an empty spindle and for any move with a tool
    number missing from ``tools`` (among the moves selected by ``use``).
    """
    number = moves.tool[1:]
    radius = np.full(len(number), np.nan)
    rc = np.full(len(number), np.nan)
    cutting = moves.motion[1:] != Motion.RAPID
    for t in np.unique(number[use]).tolist():
        sel = use & (number == t)
        tool = tools.get(t) if t != 0 else None
        if tool is None:
            culprits = sel & (cutting | (number != 0))
            if culprits.any():
                first = int(np.flatnonzero(culprits)[0])
                what = "no tool in the spindle" if t == 0 else f"tool T{t} is not in the tool table"
                line = int(moves.line[first + 1])
                kind = "feed" if cutting[first] else "rapid"
                raise VerifyError(f"line {line}: {kind} move with {what}", source=moves.source, line=line)
            continue  # rapids with an empty spindle: nothing to collide
        radius[sel] = tool.radius
        rc[sel] = float(tool.corner_radius)
    return radius, rc


def simulate(
    moves: ProgramMoves,
    tools: Mapping[int, Tool],
    setup: Setup,
    part_triangles: np.ndarray,
    options: VerifyOptions = VerifyOptions(),
    progress: Callable[[int, int], None] | None = None,
) -> tuple[Simulation, VerifyReport]:
    """Cut the stock with every move of a program and compare the result with the part.

    Parameters
    ----------
    moves : ProgramMoves
        The program's moves (tool tip positions in work coordinates [mm]); moves with an
        unknown (NaN) coordinate at either end are skipped, rapids with an empty spindle
        (tool 0) too.
    tools : mapping of int to Tool
        Tools by number, for every tool the program uses.
    setup : Setup
        The stock box (``stock_min``, ``stock_max``) in work coordinates [mm].
    part_triangles : (m, 3, 3) float
        The part's triangles in work coordinates [mm].
    options : VerifyOptions
    progress : callable, optional
        ``progress(done, total)`` in moves.

    Returns
    -------
    Simulation, VerifyReport

    Raises
    ------
    VerifyError
        If a feed move runs with no tool, or any move with a tool not in ``tools``
        (``source`` names the G-code line, ``data["line"]`` holds it); if the part, stock
        or options are unusable.
    """
    sim, report, _ = simulate_snapshots(moves, tools, setup, part_triangles, (), options, progress)
    return sim, report


def simulate_snapshots(
    moves: ProgramMoves,
    tools: Mapping[int, Tool],
    setup: Setup,
    part_triangles: np.ndarray,
    snapshot_moves: Sequence[int],
    options: VerifyOptions = VerifyOptions(),
    progress: Callable[[int, int], None] | None = None,
) -> tuple[Simulation, VerifyReport, tuple[np.ndarray, ...]]:
    """:func:`simulate`, also keeping the stock as it was part way through, in the same pass.

    Parameters
    ----------
    snapshot_moves : (s,) sequence of int
        Indices into ``moves.points``: snapshot ``k`` is the stock once every move up to
        and including the one ending at ``points[snapshot_moves[k]]`` has cut (0: the
        uncut stock). Any order; repeats allowed.
    moves, tools, setup, part_triangles, options, progress
        As for :func:`simulate`.

    Returns
    -------
    Simulation, VerifyReport
        As :func:`simulate` returns them.
    snapshots : tuple of s (ny, nx) float
        Stock top at each snapshot [mm] (read-only), on ``Simulation.grid``.

    Raises
    ------
    VerifyError
        As :func:`simulate`; also for a snapshot index outside ``0 .. len(moves.points) - 1``.
    """
    snap = np.asarray(snapshot_moves, dtype=np.int64).reshape(-1)
    if len(snap) and (snap.min() < 0 or snap.max() >= len(moves.points)):
        raise VerifyError(f"snapshot move indices must lie in 0..{len(moves.points) - 1}", source="snapshot_moves")
    tri = _check_inputs(setup, options, part_triangles)
    grid = grid_over(setup.stock_min, setup.stock_max, options.cell)
    part_top = upper_envelope(tri, grid)
    if not np.isfinite(part_top).any():
        raise VerifyError("the part does not overlap the stock's footprint", source="part")
    top_z = float(setup.stock_max[2])
    stock = np.full(grid.size, top_z)

    pts = moves.points
    a, b = pts[:-1], pts[1:]
    known = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    rapid = moves.motion[1:] == Motion.RAPID
    length = np.zeros(len(a))
    length[known] = np.linalg.norm(b[known] - a[known], axis=1)
    radius, rc = _tool_table(moves, tools, known)
    # A move whose tip never comes below the stock top cannot touch the stock.
    use = known & np.isfinite(radius)
    use[use] &= np.minimum(a[use, 2], b[use, 2]) < top_z
    idx = np.flatnonzero(use)
    seg = _Segments.between(a[idx], b[idx], radius[idx], rc[idx], rapid[idx], idx + 1)

    n_moves = int(known.sum())
    done = np.cumsum(known)  # simulated moves up to and including each move, for progress
    # Segments applied by each snapshot (seg.move is increasing).
    applied = np.searchsorted(seg.move, snap, side="right")
    crashes, stocks = _run(seg, grid, stock, moves, options, progress,
                           done[seg.move - 1] if len(seg) else done[:0], n_moves, applied)

    stock_top = stock.reshape(grid.shape)
    stock_top.setflags(write=False)
    part_top.setflags(write=False)
    sim = Simulation(grid=grid, stock_top=stock_top, part_top=part_top, stock_bottom=float(setup.stock_min[2]))
    report = _report(
        sim, tri, moves, tools, options, crashes, n_moves, float(length[~rapid].sum()), float(length[rapid].sum())
    )
    snapshots = tuple(flat.reshape(grid.shape) for flat in stocks)
    for top in snapshots:
        top.setflags(write=False)
    return sim, report, snapshots


def _run(
    seg: _Segments, grid: Grid, stock: np.ndarray, moves: ProgramMoves, options, progress, done, total_moves,
    snapshot_at: np.ndarray,
) -> tuple[list[RapidCrash], list[np.ndarray]]:
    """Apply every move to ``stock`` (flat, modified in place); return the rapid crashes and snapshots.

    ``done[k]`` is the progress count once segment ``k`` is applied. ``snapshot_at[i]`` is a
    number of segments: a copy of ``stock`` is taken once that many are applied (the
    batches are split there; cuts commute, so the final stock is the same).
    """
    # Batch boundaries from an estimate of each move's grid points (its stadium's area).
    L = np.sqrt(seg.l2)
    est = (L + 2 * seg.radius + 2 * grid.cell) * (2 * seg.radius + 2 * grid.cell) / grid.cell**2
    cum = np.cumsum(est)
    bucket = ((cum - est) // _PAIR_BUDGET).astype(np.int64)
    bounds = np.concatenate([[0], np.flatnonzero(np.diff(bucket)) + 1, [len(seg)]]).astype(np.int64)
    bounds = np.union1d(bounds, snapshot_at)
    wanted = set(snapshot_at.tolist())
    taken = {0: stock.copy()} if 0 in wanted else {}  # segments applied -> stock then

    crashes: list[RapidCrash] = []
    for c in range(len(bounds) - 1):
        s, e = int(bounds[c]), int(bounds[c + 1])
        if e > s:
            crashes += _run_batch(seg.sub(s, e), grid, stock, moves, options)
            if progress is not None:
                progress(int(done[e - 1]), total_moves)
        if e in wanted:
            taken[e] = stock.copy()
    if progress is not None:
        progress(total_moves, total_moves)
    return crashes, [taken[k] for k in snapshot_at.tolist()]


def _run_batch(seg: _Segments, grid: Grid, stock: np.ndarray, moves: ProgramMoves, options) -> list[RapidCrash]:
    row_owner, row, first, count = _row_spans(seg, grid)
    n = int(count.sum())
    if n == 0:
        return []
    owner = np.repeat(row_owner, count)
    col = np.repeat(first - (np.cumsum(count) - count), count) + np.arange(n)
    flat = np.repeat(row * grid.nx, count) + col
    # Only pairs that go below the stock as it was at the start of the batch change
    # anything; the stock only gets lower, so the rest never will.
    before = stock[flat]
    env = _pair_envelope(grid.x0 + col * grid.cell, np.repeat(grid.y0 + row * grid.cell, count), owner, seg, before)
    touch = np.flatnonzero(env < before)
    if len(touch) == 0:
        return []
    owner, flat, env = owner[touch], flat[touch], env[touch]
    suspects = np.unique(owner[seg.rapid[owner]])
    if len(suspects) == 0:
        np.minimum.at(stock, flat, env)
        return []
    # Rapids that reach into the stock are replayed in program order against the stock as
    # every earlier move left it; the feed moves between them still go in bulk (owner is
    # sorted, so each move's pairs are one run).
    crashes = []
    starts = np.searchsorted(owner, suspects, side="left")
    stops = np.searchsorted(owner, suspects, side="right")
    done = 0
    for k, f, l in zip(suspects.tolist(), starts.tolist(), stops.tolist()):
        if f > done:
            np.minimum.at(stock, flat[done:f], env[done:f])
        cells, e = flat[f:l], env[f:l]
        depth = stock[cells] - e
        worst = int(np.argmax(depth))
        if depth[worst] > options.rapid_tolerance:
            jj, ii = divmod(int(cells[worst]), grid.nx)
            move = int(seg.move[k])
            crashes.append(RapidCrash(
                line=int(moves.line[move]),
                depth=float(depth[worst]),
                position=(grid.x0 + ii * grid.cell, grid.y0 + jj * grid.cell, float(e[worst])),
                move=move,
            ))
            log.debug("rapid on line %d goes %.3f mm into the stock", crashes[-1].line, crashes[-1].depth)
        stock[cells] = np.minimum(stock[cells], e)  # a move's cells are distinct
        done = l
    if done < len(owner):
        np.minimum.at(stock, flat[done:], env[done:])
    return crashes


def _report(
    sim: Simulation, tri: np.ndarray, moves: ProgramMoves, tools, options: VerifyOptions, crashes, n_moves,
    cut_length, rapid_length,
) -> VerifyReport:
    covered = np.isfinite(sim.part_top)
    rem = (sim.stock_top - np.where(covered, sim.part_top, 0.0))[covered]
    # Only cuts deeper than the tolerance can fail the verdict; measure those against the
    # part within the tolerance sideways too (see _lowest_part_near).
    deep = np.flatnonzero(rem < -options.gouge_tolerance)
    gouge = -rem
    if len(deep) and options.gouge_tolerance > 0:
        cells = np.flatnonzero(covered.reshape(-1))[deep]
        low = _lowest_part_near(tri, sim.grid, sim.part_top.reshape(-1)[cells], cells, options.gouge_tolerance)
        gouge[deep] = low - sim.stock_top.reshape(-1)[cells]
    k = int(np.argmax(gouge))
    max_gouge = max(0.0, float(gouge[k]))  # never -0.0: max keeps its first argument on a tie
    gouge_position = gouge_line = None
    if max_gouge > 0.0:
        cell = int(np.flatnonzero(covered.reshape(-1))[k])
        jj, ii = divmod(cell, sim.grid.nx)
        x, y = sim.grid.x0 + ii * sim.grid.cell, sim.grid.y0 + jj * sim.grid.cell
        z = float(sim.stock_top.reshape(-1)[cell])
        gouge_position = (float(x), float(y), z)
        gouge_line = _line_reaching(moves, tools, x, y, z)
    return VerifyReport(
        max_gouge=max_gouge,
        gouge_position=gouge_position,
        gouge_line=gouge_line,
        remaining_max=float(rem.max()),
        remaining_mean=float(rem.mean()),
        remaining_p95=float(np.percentile(rem, 95)),
        rapid_crashes=tuple(crashes),
        moves=n_moves,
        cut_length=cut_length,
        rapid_length=rapid_length,
        cells=sim.grid.size,
        cell=sim.grid.cell,
        gouge_tolerance=options.gouge_tolerance,
        rapid_tolerance=options.rapid_tolerance,
    )


#: Directions [rad] in which :func:`_lowest_part_near` looks sideways: within 22.5 deg of
#: any wall normal, so a wall nicked less than ``cos(22.5 deg) = 0.92`` times the reach is
#: always seen past.
_SIDEWAYS = np.linspace(0.0, 2.0 * math.pi, 8, endpoint=False)


def _lowest_part_near(tri: np.ndarray, grid: Grid, part_top: np.ndarray, cells: np.ndarray, reach: float) -> np.ndarray:
    """Lowest part top at, and ``reach`` [mm] sideways of, some grid points [mm].

    Why: on a vertical wall the part top jumps, so a tool that passes within the path
    tolerance of the wall (finishing touches walls by design, and the post-processor's
    line and arc fit may move the path ``arc_tolerance`` either way) takes a grid point
    lying a hair inside the wall down to the tool's side: a cut of the wall's full height
    at that point, though the tool reached only microns into the part. Measured against
    the lowest part top within ``reach`` sideways, such a nick counts for what it is, while
    a cut deeper into the part than ``reach`` in every direction keeps its full depth
    (floors, and walls cut into by more than the tolerance).

    Parameters
    ----------
    tri : (m, 3, 3) float
        Part triangles [mm].
    grid : Grid
    part_top : (k,) float
        Upper envelope of the part at those points [mm].
    cells : (k,) int
        Flat indices of the grid points (row-major, ``(ny, nx)``).
    reach : float
        How far to look sideways [mm].

    Returns
    -------
    (k,) float
        ``-inf`` where no part lies under some point looked at.
    """
    jj, ii = np.divmod(cells, grid.nx)
    i0, j0 = int(ii.min()), int(jj.min())
    low = np.asarray(part_top, dtype=np.float64).copy()
    for angle in _SIDEWAYS:
        # The grid points' bounding box, shifted: one rasterisation per direction.
        shifted = Grid(
            x0=grid.x0 + i0 * grid.cell + reach * math.cos(angle),
            y0=grid.y0 + j0 * grid.cell + reach * math.sin(angle),
            cell=grid.cell, nx=int(ii.max()) - i0 + 1, ny=int(jj.max()) - j0 + 1,
        )
        low = np.minimum(low, upper_envelope(tri, shifted)[jj - j0, ii - i0])
    return low


def _line_reaching(moves: ProgramMoves, tools: Mapping[int, Tool], x: float, y: float, z: float) -> int | None:
    """Source line of the first move whose tool reaches down to ``z`` at ``(x, y)``."""
    a, b = moves.points[:-1], moves.points[1:]
    known = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    radius, rc = _tool_table(moves, tools, known)
    sel = np.flatnonzero(known & np.isfinite(radius))
    seg = _Segments.between(a[sel], b[sel], radius[sel], rc[sel])
    k = len(sel)
    env = _pair_envelope(np.full(k, x), np.full(k, y), np.arange(k), seg)
    hit = np.flatnonzero(env <= z + 1e-9)
    return int(moves.line[sel[hit[0]] + 1]) if len(hit) else None


# --------------------------------------------------------------------------------------
# Picture
# --------------------------------------------------------------------------------------

#: Colour stops for remaining stock, from on size (0) to the top of the scale (1).
_STOPS = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
_COLOURS = np.array([[40, 70, 200], [0, 180, 220], [60, 185, 75], [240, 215, 40], [245, 130, 20]], dtype=np.float64)
_GOUGE = np.array([215, 25, 30], dtype=np.float64)
_NO_PART = np.array([70, 70, 70], dtype=np.float64)


def _colour(values: np.ndarray, vmax: float, tol: float) -> np.ndarray:
    """RGB (float) for remaining-stock values: blue on size, to orange at ``vmax``, red for gouges."""
    u = np.clip(np.nan_to_num(values, nan=0.0) / vmax, 0.0, 1.0)
    rgb = np.stack([np.interp(u, _STOPS, _COLOURS[:, c]) for c in range(3)], axis=-1)
    rgb[values < -tol] = _GOUGE
    rgb[np.isnan(values)] = _NO_PART
    return rgb


def deviation_image(sim: Simulation, report: VerifyReport, width: int = 640) -> np.ndarray:
    """A top view of the stock left on the part, with a colour bar.

    Blue is on size, through cyan, green and yellow to orange at the largest remaining
    stock; red is a gouge deeper than the tolerance; grey is where there is no part. The
    deepest gouge is ringed in white, rapid crashes are marked with a magenta cross. Y
    points up in the picture (away from the operator).

    Parameters
    ----------
    sim : Simulation
    report : VerifyReport
    width : int
        Approximate width of the map part of the picture [px].

    Returns
    -------
    (H, W, 3) uint8
        RGB picture; write it with :func:`factory.pictures.png_bytes`.
    """
    from PIL import Image, ImageDraw, ImageFont

    grid = sim.grid
    tol = report.gouge_tolerance
    vmax = report.remaining_max if report.remaining_max > max(tol, 1e-6) else 1.0
    rgb = _colour(sim.remaining, vmax, tol)[::-1]  # row 0 of the picture is the largest Y
    scale = max(1, width // max(grid.nx, grid.ny))
    step = max(1, math.ceil(max(grid.nx, grid.ny) / width))
    rgb = rgb[::step, ::step]
    rgb = np.repeat(np.repeat(rgb, scale, axis=0), scale, axis=1)
    px = scale / step  # picture pixels per grid point
    h, w = rgb.shape[:2]

    margin, bar_w, label_w, caption_h = 12, 18, 150, 20
    H = max(h + 2 * margin + caption_h, 260)
    W = max(w + 2 * margin + bar_w + label_w, 2 * margin + 420)  # room for the caption
    canvas = np.full((H, W, 3), 255, dtype=np.uint8)
    canvas[margin:margin + h, margin:margin + w] = np.round(rgb).astype(np.uint8)

    # Colour bar: gouge band at the bottom, then 0 .. vmax upwards.
    bx = margin + w + margin
    bar_h = H - 2 * margin - 40
    gouge_h = 14
    ramp_h = bar_h - gouge_h - 4
    vals = np.linspace(vmax, 0.0, ramp_h)
    canvas[margin:margin + ramp_h, bx:bx + bar_w] = np.round(_colour(vals, vmax, tol))[:, None, :].astype(np.uint8)
    gy = margin + ramp_h + 4
    canvas[gy:gy + gouge_h, bx:bx + bar_w] = _GOUGE.astype(np.uint8)
    ny_ = gy + gouge_h + 4
    canvas[ny_:ny_ + gouge_h, bx:bx + bar_w] = _NO_PART.astype(np.uint8)

    img = Image.fromarray(canvas)
    draw = ImageDraw.Draw(img)
    font = ImageFont.load_default()
    tx = bx + bar_w + 5
    for frac in (0.0, 0.5, 1.0):
        y = margin + int(round((1 - frac) * (ramp_h - 1)))
        draw.line([(bx + bar_w, y), (bx + bar_w + 3, y)], fill=(0, 0, 0))
        draw.text((tx, y - 6), f"{frac * vmax:.3f} mm", fill=(0, 0, 0), font=font)
    draw.text((tx, gy), f"gouge > {tol:g} mm", fill=(0, 0, 0), font=font)
    draw.text((tx, ny_), "no part", fill=(0, 0, 0), font=font)
    caption = f"remaining stock above the part, max gouge {report.max_gouge:.3f} mm"
    if report.rapid_crashes:
        caption += f", {len(report.rapid_crashes)} rapid crash(es)"
    draw.text((margin, margin + h + 6), caption, fill=(0, 0, 0), font=font)

    def to_px(x: float, y: float) -> tuple[float, float]:
        col = (x - grid.x0) / grid.cell
        row = (grid.ny - 1) - (y - grid.y0) / grid.cell
        return margin + col * px + px / 2, margin + row * px + px / 2

    if report.gouged and report.gouge_position is not None:
        cx, cy = to_px(report.gouge_position[0], report.gouge_position[1])
        for r in (9, 10):
            draw.ellipse([cx - r, cy - r, cx + r, cy + r], outline=(255, 255, 255))
        draw.ellipse([cx - 11, cy - 11, cx + 11, cy + 11], outline=(0, 0, 0))
    for crash in report.rapid_crashes:
        cx, cy = to_px(crash.position[0], crash.position[1])
        draw.line([(cx - 7, cy - 7), (cx + 7, cy + 7)], fill=(255, 0, 255), width=3)
        draw.line([(cx - 7, cy + 7), (cx + 7, cy - 7)], fill=(255, 0, 255), width=3)
    return np.asarray(img, dtype=np.uint8).copy()


def operation_moves(operations: Sequence[Operation]) -> ProgramMoves:
    """The moves of operations as a controller would run them, without posting G-code.

    PLUNGE moves become feed moves (the simulation does not tell feeds apart); each
    operation's first point is reached by a rapid from the previous one's last.
    """
    points = np.concatenate([op.points for op in operations])
    motion = np.concatenate([op.motion for op in operations]).astype(np.int8)
    motion[motion == Motion.PLUNGE] = Motion.CUT
    tool = np.concatenate([np.full(len(op.points), op.tool.number) for op in operations])
    feed = np.concatenate([np.where(op.motion == Motion.RAPID, np.nan, op.cutting.feed) for op in operations])
    return ProgramMoves(points, motion, tool, feed, np.zeros(len(points), dtype=np.int32))


def stock_after(operations: Sequence[Operation], setup: Setup, part_triangles: np.ndarray,
                cell: float = 0.5) -> Simulation:
    """The stock left by ``operations``, on a grid of ``cell`` [mm], for planning later ones."""
    tools = {op.tool.number: op.tool for op in operations}
    sim, _ = simulate(operation_moves(operations), tools, setup, part_triangles, VerifyOptions(cell=cell))
    return sim


def clear_height(sim: Simulation, tool: Tool, xy: np.ndarray) -> np.ndarray:
    """Lowest tool tip height at each ``xy`` that touches none of the stock in ``sim`` [mm].

    Conservative between grid points: the stock is taken as reaching up to a grid point's
    height anywhere within a cell diagonal of it.

    Parameters
    ----------
    sim : Simulation
    tool : Tool
    xy : (n, 2) float
        Tool axis positions [mm].

    Returns
    -------
    (n,) float
        ``-inf`` where no stock lies under the tool.
    """
    g = sim.grid
    slack = g.cell * math.sqrt(2.0)
    reach = tool.radius + slack
    k = int(math.ceil(reach / g.cell))
    di, dj = np.meshgrid(np.arange(-k, k + 1), np.arange(-k, k + 1))
    di, dj = di.ravel(), dj.ravel()
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    i0 = np.rint((xy[:, 0] - g.x0) / g.cell).astype(np.int64)
    j0 = np.rint((xy[:, 1] - g.y0) / g.cell).astype(np.int64)
    out = np.full(len(xy), -np.inf)
    for a, b in zip(di, dj):
        i, j = i0 + a, j0 + b
        inside = (i >= 0) & (i < g.nx) & (j >= 0) & (j < g.ny)
        if not inside.any():
            continue
        ii, jj = i[inside], j[inside]
        r = np.hypot(g.x0 + ii * g.cell - xy[inside, 0], g.y0 + jj * g.cell - xy[inside, 1])
        near = r <= reach
        h = tool.profile_height(np.clip(r - slack, 0.0, tool.radius))
        need = np.where(near, sim.stock_top[jj, ii] - h, -np.inf)
        out[inside] = np.maximum(out[inside], need)
    return out
