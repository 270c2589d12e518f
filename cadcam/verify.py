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
* drill (a cone of slope ``k``, ``h = k r``): ``z(t) + k r(t)`` is stationary where the
  cone's flank is as steep as the move, closed form, clipped to that interval;
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
import dataclasses
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cadcam.heightmap import Grid, grid_over, upper_envelope
from cadcam.model import Motion, Operation, ProgramMoves, Setup, Tool
from cadcam.workholding import fixture_contacts
from factory.core.errors import VerifyError

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
        A rapid whose tool reaches more than this deep into the remaining stock, down or
        sideways, is a crash [mm] (rapids are swept with the rim drawn in by this much).
    finish_depth : float
        A finishing tool (see :func:`finishing_moves`) engaged deeper than this is buried
        [mm]. Finishing should only meet the roughing allowance (default 0.3 mm) plus what
        roughing leaves between its passes and levels: the 6 mm ball finishing the four
        samples after their roughing engages at most 0.49 mm, while with the roughing
        deleted from the bracket program it slots 1.6 mm deep at full width (the skin of
        walls left out, see :func:`_engaged_depth`).
    engaged_width : float
        A cut counts as engagement only where it is at least this wide across the move
        [mm] (see :func:`_engaged_depth`): a thinner band is a skin shaved off a wall.
    contact_tolerance : float
        Shank or holder reaching this far into the stock or the part, or a tool tip this
        far below the stock bottom, is a fault [mm].
    """

    cell: float = 0.2
    gouge_tolerance: float = 0.01
    rapid_tolerance: float = 0.01
    finish_depth: float = 1.0
    engaged_width: float = 1.0
    contact_tolerance: float = 0.01


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
    floor_z : float or None
        The lowest the program may cut (:attr:`Setup.floor_z`) [mm]: below it, where there
        is no part, lies the holding allowance, left on purpose. None: ``stock_bottom``.
    """

    grid: Grid
    stock_top: np.ndarray
    part_top: np.ndarray
    stock_bottom: float
    floor_z: float | None = None

    @property
    def floor(self) -> float:
        """:attr:`floor_z`, or the stock bottom when unknown [mm]."""
        return self.stock_bottom if self.floor_z is None else max(float(self.floor_z), self.stock_bottom)

    @property
    def remaining(self) -> np.ndarray:
        """(ny, nx) float stock left above the part [mm]: negative is a gouge, NaN where no part."""
        with np.errstate(invalid="ignore"):
            return np.where(np.isfinite(self.part_top), self.stock_top - self.part_top, np.nan)

    #: (ny, nx) float or None: bottom of the stock at each grid point [mm] when its columns do
    #: not stand on one plane (op 2's turned-over part, :func:`simulate_flipped`); a column cut
    #: through is empty and its ``stock_top`` is ``-inf``; ``stock_bottom`` is the lowest of
    #: them. None: every column stands on ``stock_bottom``.
    stock_under: np.ndarray | None = None
    #: (n,) float or None: the stock volume each move removed [mm³] (grid cell area times the
    #: height of stock it took off each grid point, down to the stock's bottom), indexed like
    #: ``ProgramMoves.points`` (0 for ``points[0]`` and for moves that cut nothing): the
    #: engagement the cutting-power model reads (:mod:`cadcam.cutting_power`). None: not recorded.
    removed_volume: np.ndarray | None = None


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


#: What :class:`Fault` can say, in the order the report lists them.
FAULT_KINDS = ("no_cut", "rapid", "holder", "flute", "buried", "drill_side", "below_stock", "jaws")

#: Setup sheet operation kinds that finish a surface; every other kind removes bulk stock.
FINISHING_KINDS = frozenset({"raster", "waterline", "finishing"})


@dataclass(frozen=True)
class Fault:
    """Moves that would break a tool or crash the machine, of one kind and one tool.

    Attributes
    ----------
    kind : str
        One of :data:`FAULT_KINDS`: ``no_cut`` the program removes nothing; ``rapid`` a
        rapid whose cutter (its full footprint) meets stock; ``holder`` the shank or holder
        meets the stock or the part; ``flute`` a cut engaged deeper than the flute length;
        ``buried`` a finishing tool engaged deeper than :attr:`VerifyOptions.finish_depth`;
        ``drill_side`` a drill fed sideways through stock (a drill's only engagement is
        axial, held to its flute length by ``flute``); ``below_stock`` the tool tip below the stock
        bottom; ``jaws`` the tool, shank or holder reaches into the vise's jaws or parallels
        (:attr:`Setup.jaws`).
    tool : int
        Tool number (0 for ``no_cut``).
    lines : tuple of int
        1-based program lines of every offending move, ascending.
    worst : float
        The largest depth among them [mm].
    limit : float
        What it was held against [mm].
    position : tuple of 3 float or None
        Where the worst happened: X, Y of the grid point and the tool tip Z [mm].
    message : str
        One line for people.
    """

    kind: str
    tool: int
    lines: tuple[int, ...]
    worst: float
    limit: float
    position: tuple[float, float, float] | None
    message: str

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "tool": self.tool, "lines": list(self.lines), "worst": self.worst,
                "limit": self.limit, "position": None if self.position is None else list(self.position),
                "message": self.message}


@dataclass(frozen=True)
class ToolEngagement:
    """How hard one tool worked, over its moves (all [mm]).

    Attributes
    ----------
    tool : int
    finishing : bool
        Its moves were held to the finishing limit.
    moves : int
        Its moves that came below the stock top.
    max_depth : float
        Deepest engagement of any move (:func:`_engaged_depth`).
    max_depth_line : int
        Program line of that move (0 if it never engaged).
    max_width : float
        Widest radial engagement of any move.
    """

    tool: int
    finishing: bool
    moves: int
    max_depth: float
    max_depth_line: int
    max_width: float

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


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
        In program order (each also counted in a ``rapid`` :class:`Fault`).
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
    faults : tuple of Fault
        What would break a tool or crash the machine, by kind (:data:`FAULT_KINDS`) and tool.
    engagement : tuple of ToolEngagement
        Per tool, in order of tool number.
    rapids_checked : int
        Rapids that came below the stock top and were swept against the stock.
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
    faults: tuple[Fault, ...] = ()
    engagement: tuple[ToolEngagement, ...] = ()
    rapids_checked: int = 0

    @property
    def gouged(self) -> bool:
        """True if the program cuts deeper into the part than the gouge tolerance."""
        return self.max_gouge > self.gouge_tolerance

    @property
    def ok(self) -> bool:
        """No gouge beyond tolerance, no rapid into the stock and no other :class:`Fault`."""
        return not self.gouged and not self.rapid_crashes and not self.faults

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
            "faults": [f.to_dict() for f in self.faults],
            "engagement": [e.to_dict() for e in self.engagement],
            "rapids_checked": self.rapids_checked,
        }


# --------------------------------------------------------------------------------------
# Swept envelope of one tool along one straight move, per (grid point, move) pair
# --------------------------------------------------------------------------------------


def _profile(r: np.ndarray, flat_radius: np.ndarray, rc: np.ndarray) -> np.ndarray:
    """:meth:`Tool.profile_height` for per-pair tool sizes, clamped at the radius (no inf)."""
    d = np.minimum(np.maximum(r - flat_radius, 0.0), rc)
    return rc - np.sqrt(np.maximum(rc * rc - d * d, 0.0))


_FLAT, _BALL, _BULL, _CONE = 0, 1, 2, 3


@dataclass
class _Segments:
    """Straight moves with the size of the tool that makes them: contiguous 1-D arrays, one row each.

    ``x, y, z`` is the start (tool tip) and ``dx, dy, dz`` the displacement to the end [mm].
    ``move`` is the index of the end point in :attr:`ProgramMoves.points`. ``cone`` is a
    drill point's rise per mm of radius (:attr:`Tool.point_slope`; 0 for end mills).
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
    cone: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.cone = np.zeros(len(self.x)) if self.cone is None else np.asarray(self.cone, dtype=np.float64)
        self.l2 = self.dx * self.dx + self.dy * self.dy
        has_len = self.l2 > 1e-18
        self.inv_l2 = np.where(has_len, 1.0 / np.where(has_len, self.l2, 1.0), 0.0)
        # Horizontal or vertical: the nearest approach is also the lowest (closed form for every shape).
        self.trivial = ~has_len | (self.dz == 0.0)
        self.zmin = self.z + np.minimum(self.dz, 0.0)
        self.reach2 = self.radius * self.radius * (1 + 1e-12)
        self.flat_radius = self.radius - self.rc
        ball = np.abs(self.rc - self.radius) <= 1e-12 * np.maximum(self.radius, 1.0)
        self.shape = np.where(self.cone > 0.0, _CONE,
                              np.where(self.rc == 0.0, _FLAT, np.where(ball, _BALL, _BULL))).astype(np.int8)

    def __len__(self) -> int:
        return len(self.x)

    @classmethod
    def between(cls, p0, p1, radius, rc, rapid=None, move=None, cone=None) -> "_Segments":
        k = len(p0)
        return cls(
            np.ascontiguousarray(p0[:, 0]), np.ascontiguousarray(p0[:, 1]), np.ascontiguousarray(p0[:, 2]),
            p1[:, 0] - p0[:, 0], p1[:, 1] - p0[:, 1], p1[:, 2] - p0[:, 2],
            np.asarray(radius, dtype=np.float64), np.asarray(rc, dtype=np.float64),
            np.zeros(k, bool) if rapid is None else rapid, np.arange(k) if move is None else move,
            None if cone is None else np.asarray(cone, dtype=np.float64),
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
        dist = np.sqrt(dist2)
        lower += _profile(dist, seg.flat_radius[owner], seg.rc[owner])
        lower += seg.cone[owner] * np.minimum(dist, seg.radius[owner])
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
    cone = np.flatnonzero(shape == _CONE)
    if len(cone):
        m = cone
        out[m] = _cone_envelope(wx[m], wy[m], dx[m], dy[m], z0[m], dz[m], l2[m], wd[m], cross[m], R[m],
                                seg.cone[o[m]], ta[m], tb[m])
    return out


def _cone_envelope(wx, wy, dx, dy, z0, dz, l2, wd, cross, R, k, ta, tb) -> np.ndarray:
    """Minimum of the convex ``f(t) = z0 + dz t + k r(t)`` on ``[ta, tb]`` (a drill's cone).

    With ``u = t - wd / l2`` the distance is ``r = sqrt(p^2 + l2 u^2)``, ``p`` the
    perpendicular distance from the line; ``f' = 0`` where ``sqrt(l2) u / r = -dz / (k sqrt(l2))``.
    Convex, so the stationary point clipped to the interval is the minimum; without one
    (the move is steeper than the flank) an end is.
    """
    L = np.sqrt(l2)
    p = np.abs(cross) / L
    sgn = -dz / (k * L)
    interior = np.abs(sgn) < 1.0
    u = np.where(interior, sgn * p / (L * np.sqrt(np.maximum(1.0 - sgn * sgn, 1e-300))), np.sign(sgn) * np.inf)
    t = np.clip(wd / l2 + u, ta, tb)
    r = np.minimum(np.hypot(wx - t * dx, wy - t * dy), R)
    return z0 + dz * t + k * r


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
    seg = _Segments.between(p0, p1, [tool.radius], [float(tool.corner_radius)], cone=[tool.point_slope])
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
    for name in ("cell", "gouge_tolerance", "rapid_tolerance", "finish_depth", "engaged_width", "contact_tolerance"):
        v = getattr(options, name)
        positive = name in ("cell", "finish_depth")
        if not (math.isfinite(v) and (v > 0 if positive else v >= 0)):
            kind = "positive" if positive else "non-negative"
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
    check_grid_size(setup, options.cell)
    return tri


def check_grid_size(setup: Setup, cell: float, source: str = "cell") -> None:
    """Refuse a verify grid of more than 60 M cells over the stock's footprint (about 4 GB of
    height fields), before any work that would be thrown away.

    ``cell``: grid spacing [mm], > 0. Raises VerifyError naming the cell count and the stock size.
    """
    size = setup.stock_size
    cells = math.ceil(size[0] / cell) * math.ceil(size[1] / cell)
    if cells > _MAX_CELLS:
        raise VerifyError(
            f"{cells:,} verify grid cells at {cell} mm over the {size[0]:g} x {size[1]:g} mm stock are too many "
            f"(limit {_MAX_CELLS:,}); use a coarser grid",
            source=source,
        )


def _tool_table(moves: ProgramMoves, tools: Mapping[int, Tool],
                use: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Radius, corner radius and drill point slope of the tool in the spindle for each move; NaN where none.

    Raises VerifyError for a feed move with an empty spindle and for any move with a tool
    number missing from ``tools`` (among the moves selected by ``use``).
    """
    number = moves.tool[1:]
    radius = np.full(len(number), np.nan)
    rc = np.full(len(number), np.nan)
    cone = np.zeros(len(number))
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
        cone[sel] = tool.point_slope
    return radius, rc, cone


def simulate(
    moves: ProgramMoves,
    tools: Mapping[int, Tool],
    setup: Setup,
    part_triangles: np.ndarray,
    options: VerifyOptions = VerifyOptions(),
    progress: Callable[[int, int], None] | None = None,
    finishing: np.ndarray | None = None,
) -> tuple[Simulation, VerifyReport]:
    """Cut the stock with every move of a program and compare the result with the part.

    Parameters
    ----------
    moves : ProgramMoves
        The program's moves (tool tip positions in work coordinates [mm]); moves ending at
        an unknown (NaN) coordinate are skipped, a move from an unknown start is checked
        as the tool standing at its end; rapids with an empty spindle (tool 0) are skipped
        too.
    tools : mapping of int to Tool
        Tools by number, for every tool the program uses.
    setup : Setup
        The stock box (``stock_min``, ``stock_max``) in work coordinates [mm].
    part_triangles : (m, 3, 3) float
        The part's triangles in work coordinates [mm].
    options : VerifyOptions
    progress : callable, optional
        ``progress(done, total)`` in moves.
    finishing : (n,) bool, optional
        True for moves (indexed like ``moves.points``) a finishing operation makes, held
        to :attr:`VerifyOptions.finish_depth` (see :func:`finishing_moves`); default none.

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
    sim, report, _ = simulate_snapshots(moves, tools, setup, part_triangles, (), options, progress, finishing)
    return sim, report


def simulate_snapshots(
    moves: ProgramMoves,
    tools: Mapping[int, Tool],
    setup: Setup,
    part_triangles: np.ndarray,
    snapshot_moves: Sequence[int],
    options: VerifyOptions = VerifyOptions(),
    progress: Callable[[int, int], None] | None = None,
    finishing: np.ndarray | None = None,
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
    return _simulate(moves, tools, setup, part_triangles, snapshot_moves, options, progress, finishing, None)


def _simulate(moves, tools, setup, part_triangles, snapshot_moves, options, progress, finishing,
              start: "FlippedStock | None"):
    """:func:`simulate_snapshots` from the setup's stock box (``start`` None) or from a stock
    given per grid point (:func:`simulate_flipped`)."""
    snap = np.asarray(snapshot_moves, dtype=np.int64).reshape(-1)
    if len(snap) and (snap.min() < 0 or snap.max() >= len(moves.points)):
        raise VerifyError(f"snapshot move indices must lie in 0..{len(moves.points) - 1}", source="snapshot_moves")
    tri = _check_inputs(setup, options, part_triangles)
    grid = grid_over(setup.stock_min, setup.stock_max, options.cell)
    part_top = upper_envelope(tri, grid)
    if not np.isfinite(part_top).any():
        raise VerifyError("the part does not overlap the stock's footprint", source="part")
    under = None
    if start is None:
        top_z = float(setup.stock_max[2])
        stock = np.full(grid.size, top_z)
    else:
        if start.grid != grid:
            raise VerifyError(f"the starting stock's grid {start.grid} is not this setup's {grid}", source="stock")
        stock = np.array(start.top, dtype=np.float64).reshape(-1)
        under = np.array(start.bottom, dtype=np.float64).reshape(-1)
        stock[~(stock > under)] = -np.inf  # empty columns hold nothing to cut
        finite = stock[np.isfinite(stock)]
        top_z = float(finite.max()) if len(finite) else float(setup.stock_max[2])
        stock_bottom = float(under[np.isfinite(stock)].min()) if len(finite) else float(setup.stock_min[2])

    pts = moves.points
    a, b = pts[:-1].copy(), pts[1:]
    known = np.all(np.isfinite(b), axis=1)
    # The move that first makes the position known comes from wherever the machine was
    # (a tool change, the last program): the tool is at least *there* at its end, so it
    # is checked standing at its end point (a G0 Z-2 as the first move after a tool
    # change is a crash on that line).
    arrive = known & ~np.all(np.isfinite(a), axis=1)
    a[arrive] = b[arrive]
    rapid = moves.motion[1:] == Motion.RAPID
    length = np.zeros(len(a))
    length[known] = np.linalg.norm(b[known] - a[known], axis=1)
    radius, rc, cone = _tool_table(moves, tools, known)
    # "Reaches more than rapid_tolerance into the stock" holds sideways too: a rapid whose rim
    # only grazes a wall's skin (a contour's arcs and the posted coordinates' rounding leave a
    # skin microns thick beside the line a descent comes down on) is not a crash, so rapids are
    # swept with the rim drawn in by the tolerance.
    radius[rapid] -= options.rapid_tolerance
    rc[rapid] = np.minimum(rc[rapid], radius[rapid])
    # A move whose tip never comes below the stock top cannot touch the stock.
    use = known & np.isfinite(radius)
    use[use] &= np.minimum(a[use, 2], b[use, 2]) < top_z
    idx = np.flatnonzero(use)
    seg = _Segments.between(a[idx], b[idx], radius[idx], rc[idx], rapid[idx], idx + 1, cone[idx])
    part_flat = np.where(np.isfinite(part_top), part_top, -np.inf).reshape(-1)
    body = _Body(tools, moves.tool[idx + 1], part_flat, options.engaged_width, options.contact_tolerance)
    body.wall_near = _highest_part_near(part_top, grid, _SKIN).reshape(-1)

    n_moves = int(known.sum())
    done = np.cumsum(known)  # simulated moves up to and including each move, for progress
    # Segments applied by each snapshot (seg.move is increasing).
    applied = np.searchsorted(seg.move, snap, side="right")
    stats = _MoveStats(len(seg), bottom=float(setup.stock_min[2]))
    stocks = _run(seg, body, grid, stock, part_flat, progress, done[seg.move - 1] if len(seg) else done[:0],
                  n_moves, applied, stats, under)

    stock_top = stock.reshape(grid.shape)
    stock_top.setflags(write=False)
    part_top.setflags(write=False)
    removed_volume = np.zeros(len(pts))
    np.add.at(removed_volume, seg.move, stats.volume)
    removed_volume.setflags(write=False)
    sim = Simulation(grid=grid, stock_top=stock_top, part_top=part_top, stock_bottom=float(setup.stock_min[2]),
                     floor_z=setup.floor_z, removed_volume=removed_volume)
    if under is not None:
        stock_under = under.reshape(grid.shape)
        stock_under.setflags(write=False)
        sim = dataclasses.replace(sim, stock_bottom=stock_bottom, stock_under=stock_under)
    finish = np.zeros(len(pts), bool) if finishing is None else np.asarray(finishing, bool).reshape(-1)
    if len(finish) != len(pts):
        raise VerifyError(f"finishing flags: expected {len(pts)}, got {len(finish)}", source="finishing")
    crashes, faults, engagement = _judge(seg, stats, moves, tools, finish, sim, options)
    if setup.jaws:
        faults += _jaw_faults(a, b, known & np.isfinite(radius), moves, tools, setup, options)
    report = _report(
        sim, tri, moves, tools, options, crashes, n_moves, float(length[~rapid].sum()), float(length[rapid].sum()),
        faults, engagement, int(np.count_nonzero(seg.rapid)),
    )
    snapshots = tuple(flat.reshape(grid.shape) for flat in stocks)
    for top in snapshots:
        top.setflags(write=False)
    return sim, report, snapshots


def _jaw_faults(a: np.ndarray, b: np.ndarray, use: np.ndarray, moves: ProgramMoves, tools: Mapping[int, Tool],
                setup: Setup, options: VerifyOptions) -> list["Fault"]:
    """One ``jaws`` fault per tool whose moves (``a`` -> ``b``, those in ``use``) reach into the
    workholding deeper than the contact tolerance (:mod:`cadcam.workholding`)."""
    idx = np.flatnonzero(use)
    jaws = tuple(setup.jaws or ())
    hits = fixture_contacts(a[idx], b[idx], moves.tool[idx + 1], tools, jaws)
    tol = options.contact_tolerance
    # The move that takes the tool into the jaws, not the one that brings it back out.
    leaving = ((fixture_contacts(a[idx], a[idx], moves.tool[idx + 1], tools, jaws).depth > tol)
               & (fixture_contacts(b[idx], b[idx], moves.tool[idx + 1], tools, jaws).depth <= tol))
    bad = (hits.depth > tol) & ~leaving
    line = moves.line[idx + 1].astype(np.int64)
    tool = moves.tool[idx + 1].astype(np.int64)
    out = []
    for t in np.unique(tool[bad]).tolist():
        ks = np.flatnonzero(bad & (tool == t))
        k = int(ks[np.argmax(hits.depth[ks])])
        w = float(hits.depth[k])
        name = jaws[int(hits.box[k])].name
        lines = tuple(sorted(set(line[ks].tolist())))
        out.append(Fault("jaws", int(t), lines, w, options.contact_tolerance,
                         tuple(float(v) for v in hits.position[k]),
                         f"T{t} runs {w:.2f} mm into the {name}"))
    return out


#: Material within this sideways of a part wall at least as tall (less this), over part
#: lower than that, is the wall's skin [mm]: a finishing tool takes it off whatever its
#: height (raster passes meet walls head-on).
_SKIN = 1.0


def _highest_part_near(part_top: np.ndarray, grid: Grid, reach: float) -> np.ndarray:
    """(ny, nx) highest part top within ``reach`` [mm] of each grid point (``-inf``: none)."""
    top = np.where(np.isfinite(part_top), part_top, -np.inf)
    out = top.copy()
    k = int(reach // grid.cell)
    ny, nx = top.shape
    for dj in range(-k, k + 1):
        for di in range(-k, k + 1):
            if (di or dj) and (di * di + dj * dj) * grid.cell**2 <= reach * reach + 1e-12:
                src = top[max(0, dj):ny + min(0, dj), max(0, di):nx + min(0, di)]
                dst = out[max(0, -dj):ny + min(0, -dj), max(0, -di):nx + min(0, -di)]
                np.maximum(dst, src, out=dst)
    return out


class _Body:
    """The shank and holder of the tool making each segment, as flat cylinders to sweep.

    ``levels[t]``: ``(height above the tip, radius)`` of tool ``t``'s body cylinders
    (:meth:`Tool.body`), radii growing with height.
    """

    def __init__(self, tools: Mapping[int, Tool], tool_of_seg: np.ndarray, part_flat: np.ndarray,
                 engaged_width: float, graze: float = 0.0):
        self.tool_of_seg = np.asarray(tool_of_seg, dtype=np.int64)
        self.levels = {t: tools[t].body() for t in np.unique(self.tool_of_seg).tolist() if t in tools}
        flutes = {t: tools[t].flute_length for t in self.levels}
        self.flute_of_seg = np.array([flutes.get(t, np.inf) for t in self.tool_of_seg.tolist()], dtype=np.float64)
        finite = part_flat[np.isfinite(part_flat)]
        self.part_max = float(finite.max()) if len(finite) else -np.inf
        self.part = part_flat
        self.engaged_width = engaged_width
        # A shank as wide as the cutter rides a finished wall at exactly its radius: a
        # graze sideways within the contact tolerance is no contact.
        self.graze = graze

    def pairs(self, seg: _Segments, s: int, e: int, grid: Grid, stock: np.ndarray, ceiling: float):
        """(segment in batch, flat grid index, body envelope) for body parts that come below ``ceiling``."""
        tool = self.tool_of_seg[s:e]
        rows, heights, radii = [], [], []
        for t, levels in self.levels.items():
            mine = np.flatnonzero(tool == t)
            if len(mine) == 0:
                continue
            for h, r in levels:
                low = mine[seg.zmin[mine] + h < ceiling]
                if len(low):
                    rows.append(low)
                    heights.append(np.full(len(low), h))
                    radii.append(np.full(len(low), max(r - self.graze, 1e-6)))
        if not rows:
            empty = np.zeros(0, np.int64)
            return empty, empty, np.zeros(0)
        k = np.concatenate(rows)
        h = np.concatenate(heights)
        lifted = _Segments(seg.x[k], seg.y[k], seg.z[k] + h, seg.dx[k], seg.dy[k], seg.dz[k],
                           np.concatenate(radii), np.zeros(len(k)), seg.rapid[k], seg.move[k])
        owner, flat, col, row = _pairs(lifted, grid)
        bound = np.maximum(stock[flat], self.part[flat])
        env = _pair_envelope(grid.x0 + col * grid.cell, grid.y0 + row * grid.cell, owner, lifted, bound)
        hit = np.flatnonzero(np.isfinite(env))
        return k[owner[hit]], flat[hit], env[hit]


class _MoveStats:
    """Per-segment results of the simulation, filled batch by batch (all lengths [mm]).

    ``depth``: deepest *engaged* depth of the move (see :func:`_engaged_depth`);
    ``width``: lateral extent of the material it removed; ``removed_max``: thickest column
    it took off one grid point; ``contact``: deepest reach of its shank or holder into
    the stock or the part; ``*_cell``: flat grid index where that happened, -1 if nowhere;
    ``volume``: stock it removed above ``bottom`` (the stock's bottom) [mm³].
    """

    def __init__(self, n: int, bottom: float = -np.inf):
        self.volume = np.zeros(n)
        self.bottom = bottom
        self.depth = np.zeros(n)
        self.depth_cell = np.full(n, -1, np.int64)
        self.width = np.zeros(n)
        self.removed_max = np.zeros(n)
        self.removed_cell = np.full(n, -1, np.int64)
        self.removed_env = np.zeros(n)
        self.contact = np.zeros(n)
        self.contact_cell = np.full(n, -1, np.int64)
        self.contact_z = np.zeros(n)


def _run(
    seg: _Segments, body: "_Body", grid: Grid, stock: np.ndarray, part: np.ndarray, progress, done, total_moves,
    snapshot_at: np.ndarray, stats: _MoveStats, under: np.ndarray | None = None,
) -> list[np.ndarray]:
    """Apply every move to ``stock`` (flat, modified in place); fill ``stats``; return the snapshots.

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

    for c in range(len(bounds) - 1):
        s, e = int(bounds[c]), int(bounds[c + 1])
        if e > s:
            _run_batch(seg, body, s, e, grid, stock, part, stats, under)
            if progress is not None:
                progress(int(done[e - 1]), total_moves)
        if e in wanted:
            taken[e] = stock.copy()
    if progress is not None:
        progress(total_moves, total_moves)
    return [taken[k] for k in snapshot_at.tolist()]


def _pairs(seg: _Segments, grid: Grid) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every (segment, grid point) pair within a segment's reach: owner, flat index, column, row."""
    row_owner, row, first, count = _row_spans(seg, grid)
    n = int(count.sum())
    owner = np.repeat(row_owner, count)
    col = np.repeat(first - (np.cumsum(count) - count), count) + np.arange(n)
    rows = np.repeat(row, count)
    return owner, rows * grid.nx + col, col, rows


def _segmented_exclusive_min(group: np.ndarray, value: np.ndarray) -> np.ndarray:
    """Running minimum of ``value`` within each run of equal ``group``, excluding the entry itself.

    ``group`` is sorted; ``inf`` starts each run and stands for ``inf`` in ``value``. Each
    run is lifted below every earlier one by a multiple of the values' span, so one
    ``minimum.accumulate`` restarts at every run; the minimum is then read back from the
    entry that holds it, so it is exact.
    """
    out = np.full(len(value), np.inf)
    if len(value) == 0:
        return out
    finite = np.isfinite(value)
    if not finite.any():
        return out
    lo = float(value[finite].min())
    span = float(value[finite].max()) - lo + 1.0
    v = np.where(finite, value - lo, span)  # inf -> above every finite value
    start = np.r_[True, group[1:] != group[:-1]]
    run = np.cumsum(start) - 1
    lifted = v + (run[-1] - run) * (2.0 * span)
    running = np.minimum.accumulate(lifted)
    # The entry holding each running minimum (every run's first entry holds one), so the
    # minimum comes back as the exact value, whatever the lift rounded: results do not
    # depend on how moves are batched.
    idx = np.arange(len(value))
    holder = np.maximum.accumulate(np.where(lifted <= running, idx, 0))
    keep = np.flatnonzero(~start)
    out[keep] = value[holder[keep - 1]]
    return out


def _run_batch(seg_all: _Segments, body: "_Body", s: int, e: int, grid: Grid, stock: np.ndarray, part: np.ndarray,
               stats: _MoveStats, under: np.ndarray | None = None) -> None:
    """Cut segments ``s:e`` into ``stock`` and record what each met.

    Each move is judged against the stock exactly as every earlier move left it (also
    the earlier moves of this batch): pairs are ordered by grid point and move, and a
    running minimum of the earlier moves' envelopes gives the stock each move found.
    ``under`` (flat, per grid point): the bottom of a stock whose columns do not all stand
    on one plane (a flipped part); a column cut down to it is empty (``-inf``) from then on.
    """
    seg = seg_all.sub(s, e)
    owner, flat, col, row = _pairs(seg, grid)
    before0 = stock[flat]
    env = _pair_envelope(grid.x0 + col * grid.cell, grid.y0 + row * grid.cell, owner, seg, before0)
    touch = np.flatnonzero(env < before0)
    owner, flat, col, row, env = owner[touch], flat[touch], col[touch], row[touch], env[touch]

    # Shank and holder: the same sweep with the body's cylinders, only where they can
    # come below the highest stock or part there is.
    b_owner, b_flat, b_env = body.pairs(seg, s, e, grid, stock, max(float(stock.max()), body.part_max))

    n_c = len(flat)
    cells = np.concatenate([flat, b_flat])
    # At a grid point, every earlier move's cut counts, and for this move's own
    # shank, not its own cutter (which takes that material off no higher than its flutes).
    order_key = np.concatenate([owner * 2 + 1, b_owner * 2])
    value = np.concatenate([env, np.full(len(b_flat), np.inf)])
    order = np.argsort(cells * (2 * (e - s) + 2) + order_key)
    earlier = np.empty(len(cells))
    earlier[order] = _segmented_exclusive_min(cells[order], value[order])
    found = np.minimum(stock[cells], earlier)
    if under is not None:  # a column cut through by an earlier move holds nothing
        found[~(found > under[cells])] = -np.inf

    if len(b_flat):
        # This move's own flutes take off what they reach first (the tool descends or
        # moves on into it), up to the flute length above the highest tip position
        # from which they reach the point; material above that meets the body.
        qx = grid.x0 + (b_flat % grid.nx) * grid.cell
        qy = grid.y0 + (b_flat // grid.nx) * grid.cell
        ta, tb, _ = _reach_interval(seg, b_owner, qx, qy)
        z0, dz = seg.z[b_owner], seg.dz[b_owner]
        flute_top = np.where(ta <= tb, np.maximum(z0 + dz * ta, z0 + dz * tb) + body.flute_of_seg[b_owner + s], -np.inf)
        standing = found[n_c:]
        standing = np.where(standing > flute_top, standing, -np.inf)
        met = np.maximum(standing, part[b_flat]) - b_env
        hit = np.flatnonzero(met > 0.0)
        if len(hit):
            _record_max(stats.contact, stats.contact_cell, b_owner[hit] + s, met[hit], b_flat[hit],
                        extra=(stats.contact_z, b_env[hit]))

    before = found[:n_c]
    removed = before - env
    cut = np.flatnonzero(removed > 0.0)
    if len(cut):
        o, f, r = owner[cut], flat[cut], removed[cut]
        _record_max(stats.removed_max, stats.removed_cell, o + s, r, f, extra=(stats.removed_env, env[cut]))
        # A wall's skin is no engagement (see _SKIN); it is still cut, and still counts
        # for rapids and for the width of the cut.
        # Only beside a wall: floor allowance (the part right below) is engagement as usual.
        skin = (body.wall_near[f] >= before[cut] - _SKIN) & (part[f] < before[cut] - _SKIN)
        _engaged_depth(seg, o, s, grid.x0 + col[cut] * grid.cell, grid.y0 + row[cut] * grid.cell, before[cut],
                       env[cut], f, grid.cell, body.engaged_width, stats, skin)
        # what the cut took off, counted down to the stock's bottom (a through cut goes on into air)
        floor = stats.bottom if under is None else under[f]
        np.add.at(stats.volume, o + s, np.maximum(before[cut] - np.maximum(env[cut], floor), 0.0) * grid.cell**2)
        np.minimum.at(stock, f, env[cut])
        if under is not None:
            through = f[~(stock[f] > under[f])]
            stock[through] = -np.inf


def _record_max(best: np.ndarray, where: np.ndarray, owner: np.ndarray, value: np.ndarray, cell: np.ndarray,
                extra: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """``best[k] = max(value)`` over entries of owner ``k``, with the cell (and ``extra``) where it is reached."""
    np.maximum.at(best, owner, value)
    at = np.flatnonzero(value >= best[owner])
    where[owner[at]] = cell[at]
    if extra is not None:
        extra[0][owner[at]] = extra[1][at]


#: A grid point counts towards a move's width once the move takes more than this off it [mm].
_ENGAGED_FILM = 0.02


def _reach_interval(seg: _Segments, o: np.ndarray, qx: np.ndarray, qy: np.ndarray):
    """Where along each move (``t`` in [0, 1]) the grid point is within the cutting radius.

    Returns ``ta, tb, r0``: the interval's ends and the distance from the axis at the start
    [mm]; ``ta > tb`` where the point is never within reach.
    """
    wx, wy = qx - seg.x[o], qy - seg.y[o]
    dx, dy, l2, R = seg.dx[o], seg.dy[o], seg.l2[o], seg.radius[o]
    r0 = np.hypot(wx, wy)
    has = l2 > 1e-18
    l2s = np.where(has, l2, 1.0)
    cross = wx * dy - wy * dx
    root = np.sqrt(np.maximum(l2 * R * R - cross * cross, 0.0))
    wd = wx * dx + wy * dy
    ta = np.where(has, np.clip((wd - root) / l2s, 0.0, 1.0), 0.0)
    tb = np.where(has, np.clip((wd + root) / l2s, 0.0, 1.0), 1.0)
    never = (l2 * R * R * (1 + 1e-12) < cross * cross) | (~has & (r0 > R * (1 + 1e-12)))
    ta = np.where(never, 1.0, ta)
    tb = np.where(never, 0.0, tb)
    return ta, tb, r0


def _engaged_depth(seg: _Segments, o: np.ndarray, s: int, qx: np.ndarray, qy: np.ndarray, before: np.ndarray,
                   env: np.ndarray, cells: np.ndarray, cell: float, min_width: float, stats: _MoveStats,
                   skin: np.ndarray | None = None) -> None:
    """Deepest engagement of each move's cutter [mm], in ``stats.depth``; its width in ``stats.width``.

    The column a move takes off a grid point is split in two: as much of it as the tool
    descends while the point is within its reach is a plunge (taken off from above); the
    rest the cutter meets moving sideways, and that height is the axial depth of cut
    ``ap`` there. A tool is buried when

    * sideways: the grid points taken, thickest first, span ``min_width`` across the
      move's XY direction while still deeper than the depth reported (a tall but thin
      skin shaved off a wall is not a buried tool, a full-width slot is);
    * plunging: they cover half the cutter's footprint while still deeper than it (a
      drill-like entry into solid stock, not a descent past a wall; for a ball that is
      ``0.29 R`` less than the depth of its tip).

    Grid points ``skin`` (within :data:`_SKIN` of a part wall at least as tall as the
    material on them, less that distance) are left out: the allowance on a wall is
    taken off by finishing whatever its height, a raster pass meeting it head-on.
    """
    R = seg.radius[o]
    ta, tb, _ = _reach_interval(seg, o, qx, qy)
    # What the tool takes off a point while it descends over it is a plunge; the rest it
    # takes moving sideways into the material.
    removed = before - env
    plunge = np.minimum(removed, np.maximum(-seg.dz[o], 0.0) * np.maximum(tb - ta, 0.0))
    side = removed - plunge
    if skin is not None:  # the skin of a wall: taken off, but no engagement
        plunge = np.where(skin, 0.0, plunge)
        side = np.where(skin, 0.0, side)

    L = np.sqrt(seg.l2[o])
    has = L > 1e-9
    ux = np.where(has, seg.dx[o] / np.where(has, L, 1.0), 1.0)
    uy = np.where(has, seg.dy[o] / np.where(has, L, 1.0), 0.0)
    wx, wy = qx - seg.x[o], qy - seg.y[o]
    lat = np.where(has, wx * uy - wy * ux, wx)  # signed distance across the move (along X if vertical)
    film = removed > _ENGAGED_FILM
    if film.any():
        lo = np.full(len(seg), np.inf)
        hi = np.full(len(seg), -np.inf)
        np.minimum.at(lo, o[film], lat[film])
        np.maximum.at(hi, o[film], lat[film])
        k = np.flatnonzero(np.isfinite(lo))
        width = np.minimum(hi[k] - lo[k] + cell, 2 * seg.radius[k])
        stats.width[k + s] = np.maximum(stats.width[k + s], width)

    # Sideways: thickest first within each move, running extent of the lateral offsets
    # (cummax with a per-move offset that lifts each move above every earlier one).
    sel = np.flatnonzero(side > 0.0)
    if len(sel):
        order = sel[np.argsort(o[sel] * (float(side[sel].max()) + 1.0) - side[sel], kind="stable")]
        os_, lat_s = o[order], lat[order]
        shift = os_ * (4.0 * float(2 * np.max(seg.radius)) + 4.0)
        hi = np.maximum.accumulate(lat_s + shift) - shift
        lo = shift - np.maximum.accumulate(shift - lat_s)
        wide = np.flatnonzero(hi - lo + cell >= min_width)
        if len(wide):
            _record_max(stats.depth, stats.depth_cell, os_[wide] + s, side[order][wide], cells[order][wide])
    # Plunging: the k-th thickest, k grid points being half the cutter's footprint.
    sel = np.flatnonzero(plunge > 0.0)
    if len(sel):
        order = sel[np.argsort(o[sel] * (float(plunge[sel].max()) + 1.0) - plunge[sel], kind="stable")]
        os_ = o[order]
        first = np.r_[True, os_[1:] != os_[:-1]]
        rank = np.arange(len(order)) - np.maximum.accumulate(np.where(first, np.arange(len(order)), 0))
        need = np.ceil(0.5 * math.pi * R[order] ** 2 / cell**2) - 1
        at = np.flatnonzero(rank >= need)
        if len(at):
            _record_max(stats.depth, stats.depth_cell, os_[at] + s, plunge[order][at], cells[order][at])


def _judge(seg: _Segments, stats: _MoveStats, moves: ProgramMoves, tools: Mapping[int, Tool], finish: np.ndarray,
           sim: Simulation, options: VerifyOptions):
    """Rapid crashes, faults and per-tool engagement from the per-move results."""
    g = sim.grid

    def xy(cell: int) -> tuple[float, float]:
        jj, ii = divmod(int(cell), g.nx)
        return float(g.x0 + ii * g.cell), float(g.y0 + jj * g.cell)

    line = moves.line[seg.move].astype(np.int64)
    tool = moves.tool[seg.move].astype(np.int64)
    fin = finish[seg.move]
    crashes = []
    for k in np.flatnonzero(seg.rapid & (stats.removed_max > options.rapid_tolerance)).tolist():
        x, y = xy(stats.removed_cell[k])
        crashes.append(RapidCrash(line=int(line[k]), depth=float(stats.removed_max[k]),
                                  position=(x, y, float(stats.removed_env[k])), move=int(seg.move[k])))
    faults: list[Fault] = []
    # A program whose feed moves take nothing off proves nothing (an empty or truncated file).
    if not np.any(stats.removed_max[~seg.rapid] > options.gouge_tolerance):
        faults.append(Fault("no_cut", 0, (), 0.0, 0.0, None, "the program removes no material"))

    flute = np.array([tools[t].flute_length if t in tools else np.inf for t in tool.tolist()], dtype=np.float64)
    # A drill only cuts along its axis: any feed move across the stock breaks it.
    drill = np.array([t in tools and tools[t].is_drill for t in tool.tolist()], dtype=bool)
    sideways = drill & ~seg.rapid & (seg.l2 > 1e-12) & (stats.removed_max > options.gouge_tolerance)
    checks = (
        ("rapid", seg.rapid & (stats.removed_max > options.rapid_tolerance), stats.removed_max, stats.removed_cell,
         np.full(len(seg), options.rapid_tolerance), "rapid with T{t} goes {w:.2f} mm into the stock"),
        ("holder", stats.contact > options.contact_tolerance, stats.contact, stats.contact_cell,
         np.full(len(seg), options.contact_tolerance), "shank or holder of T{t} reaches {w:.2f} mm into the stock or part"),
        ("flute", ~seg.rapid & (stats.depth > flute + options.contact_tolerance), stats.depth, stats.depth_cell,
         flute, "T{t} engaged {w:.2f} mm deep, beyond its {l:g} mm flutes"),
        ("buried", ~seg.rapid & fin & (stats.depth > options.finish_depth), stats.depth, stats.depth_cell,
         np.full(len(seg), options.finish_depth), "finishing tool T{t} engaged {w:.2f} mm deep (limit {l:g} mm)"),
        ("drill_side", sideways, stats.removed_max, stats.removed_cell, np.full(len(seg), options.gouge_tolerance),
         "drill T{t} moves sideways through {w:.2f} mm of stock (drills cut only along their axis)"),
        # The move that takes the tip below the bottom, not the one that brings it back.
        ("below_stock", seg.z + seg.dz < sim.stock_bottom - options.contact_tolerance, sim.stock_bottom - seg.zmin,
         np.full(len(seg), -1), np.full(len(seg), options.contact_tolerance),
         "T{t} goes {w:.2f} mm below the stock bottom"),
    )
    for kind, bad, value, where, limit, text in checks:
        for t in np.unique(tool[bad]).tolist():
            ks = np.flatnonzero(bad & (tool == t))
            k = int(ks[np.argmax(value[ks])])
            if where[k] >= 0:
                x, y = xy(where[k])
            else:
                x, y = float(seg.x[k] + (seg.dx[k] if seg.dz[k] < 0 else 0.0)), float(seg.y[k] + (seg.dy[k] if seg.dz[k] < 0 else 0.0))
            w = float(value[k])
            faults.append(Fault(kind, int(t), tuple(sorted(set(line[ks].tolist()))), w, float(limit[k]),
                                (x, y, float(seg.zmin[k])), text.format(t=t, w=w, l=float(limit[k]))))

    engagement = []
    for t in np.unique(tool).tolist():
        ks = np.flatnonzero((tool == t) & ~seg.rapid)
        if len(ks) == 0:
            continue
        k = int(ks[np.argmax(stats.depth[ks])])
        engagement.append(ToolEngagement(
            tool=int(t), finishing=bool(fin[ks].any()), moves=int(len(ks)), max_depth=float(stats.depth[k]),
            max_depth_line=int(line[k]) if stats.depth[k] > 0 else 0, max_width=float(stats.width[ks].max()),
        ))
    return crashes, faults, tuple(engagement)


def _report(
    sim: Simulation, tri: np.ndarray, moves: ProgramMoves, tools, options: VerifyOptions, crashes, n_moves,
    cut_length, rapid_length, faults=(), engagement=(), rapids_checked=0,
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
        faults=tuple(sorted(faults, key=lambda f: (FAULT_KINDS.index(f.kind), f.tool))),
        engagement=tuple(engagement),
        rapids_checked=rapids_checked,
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
    radius, rc, cone = _tool_table(moves, tools, known)
    sel = np.flatnonzero(known & np.isfinite(radius))
    seg = _Segments.between(a[sel], b[sel], radius[sel], rc[sel], cone=cone[sel])
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
    deepest gouge is ringed in white, rapid crashes are marked with a magenta cross, every
    other fault with a square labelled with its kind, tool and first line. Y points up in
    the picture (away from the operator).

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
    others = [f.kind for f in report.faults if f.kind != "rapid"]
    if others:
        caption += ", " + ", ".join(sorted(set(others)))
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
    # Every other fault: a black-and-white square at its worst point, labelled with its
    # kind and first program line (rapids already carry their cross).
    for fault in report.faults:
        if fault.position is None or fault.kind == "rapid":
            continue
        cx, cy = to_px(fault.position[0], fault.position[1])
        draw.rectangle([cx - 8, cy - 8, cx + 8, cy + 8], outline=(0, 0, 0), width=3)
        draw.rectangle([cx - 6, cy - 6, cx + 6, cy + 6], outline=(255, 255, 255), width=1)
        label = f"{fault.kind} T{fault.tool}" + (f" L{fault.lines[0]}" if fault.lines else "")
        draw.text((cx + 10, cy - 6), label, fill=(0, 0, 0), font=font)
    return np.asarray(img, dtype=np.uint8).copy()


#: The comment the post-processor writes at the start of each operation (cadcam.post):
#: ``(op 2: finish raster [raster] T3 6 mm ball 2FL carbide)``.
_OP_COMMENT = re.compile(r"\(\s*op\s+\d+\s*:.*\[([^\]]+)\]\s*T(\d+)\b", re.IGNORECASE)


def finishing_moves(gcode_text: str, moves: ProgramMoves, operations: Sequence[Mapping[str, Any]] = ()) -> np.ndarray:
    """Which moves of a program a finishing operation makes, for :attr:`VerifyOptions.finish_depth`.

    Each move belongs to the operation whose ``op N: NAME [KIND] Tt`` comment (written by
    the post-processor) last precedes it, if that comment names the tool in the spindle;
    the kind is finishing if it is in :data:`FINISHING_KINDS`. Moves without such a
    comment (hand-edited programs, other posts) take the kind from the setup sheet's
    ``operations``: finishing if every operation there using that tool is a finishing
    one. So deleting the roughing operation, comment and all, still leaves the finishing
    tool judged as a finishing tool.

    Parameters
    ----------
    gcode_text : str
        The program the moves were parsed from.
    moves : ProgramMoves
    operations : sequence of mapping
        The setup sheet's ``operations`` (``kind`` and ``tool`` are read).

    Returns
    -------
    (n,) bool
        Indexed like ``moves.points``.
    """
    by_tool: dict[int, set[bool]] = {}
    for op in operations:
        try:
            by_tool.setdefault(int(op["tool"]), set()).add(str(op["kind"]).lower() in FINISHING_KINDS)
        except (KeyError, TypeError, ValueError):
            continue
    comment_line, comment_tool, comment_fin = [0], [-1], [False]
    for k, text in enumerate(gcode_text.splitlines(), start=1):
        m = _OP_COMMENT.search(text)
        if m:
            comment_line.append(k)
            comment_tool.append(int(m.group(2)))
            comment_fin.append(m.group(1).strip().lower() in FINISHING_KINDS)
    at = np.searchsorted(np.asarray(comment_line), moves.line, side="right") - 1
    named_tool = np.asarray(comment_tool)[at]
    from_comment = np.asarray(comment_fin)[at]
    sheet = np.array([by_tool.get(t) == {True} for t in moves.tool.tolist()], dtype=bool)
    return np.where(named_tool == moves.tool, from_comment, sheet)


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


@dataclass(frozen=True)
class FlippedStock:
    """The stock one operation left, turned over for the next: a column of material per grid point.

    Attributes
    ----------
    grid : Grid
        The next setup's grid (:func:`cadcam.heightmap.grid_over` of its stock box).
    top, bottom : (ny, nx) float
        Top and bottom of the material at each grid point in the next setup's work
        coordinates [mm]; ``top`` is ``-inf`` where the column is empty (cut through).
    """

    grid: Grid
    top: np.ndarray
    bottom: np.ndarray


def flip_stock(sim: Simulation, transform: np.ndarray, setup: Setup) -> FlippedStock:
    """The stock of ``sim`` turned over by ``transform`` into the work coordinates of ``setup``.

    A z-map column ``[bottom, top]`` turned upside down is a column ``[-top, -bottom]`` (plus
    the transform's offset): its top is the old flat bottom, its bottom the surface the
    earlier program cut. The next setup's grid must be the old one mirrored, which it is
    when ``setup``'s stock box is the old one turned over in place (:mod:`cadcam.op2`).

    Parameters
    ----------
    sim : Simulation
        The stock after the earlier program.
    transform : (4, 4) float
        Old work coordinates -> new ones [mm]: a half turn about the X axis
        (``diag(1, -1, -1)``) and a translation.
    setup : Setup
        The next setup; its grid is laid over its stock box with ``sim``'s cell.

    Raises
    ------
    VerifyError
        ``transform`` is not a half turn about X, or the grids do not coincide.
    """
    t = np.asarray(transform, dtype=np.float64).reshape(4, 4)
    if not np.allclose(t[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-12):
        raise VerifyError("the flip must be a half turn about the work X axis", source="flip")
    g1 = sim.grid
    grid = grid_over(setup.stock_min, setup.stock_max, g1.cell)
    # New grid point (x, y) comes from the old point (x - tx, ty - y).
    i_f = (grid.xs - t[0, 3] - g1.x0) / g1.cell
    j_f = (t[1, 3] - grid.ys - g1.y0) / g1.cell
    i, j = np.rint(i_f).astype(np.int64), np.rint(j_f).astype(np.int64)
    if (grid.shape != g1.shape or np.abs(i_f - i).max() > 1e-6 or np.abs(j_f - j).max() > 1e-6
            or i.min() < 0 or i.max() >= g1.nx or j.min() < 0 or j.max() >= g1.ny):
        raise VerifyError("the flipped stock does not land on the next setup's grid: its stock box must be "
                          "the old one turned over in place", source="flip")
    old_top = sim.stock_top[np.ix_(j, i)]
    old_under = (np.full(g1.shape, sim.stock_bottom) if sim.stock_under is None else sim.stock_under)[np.ix_(j, i)]
    present = old_top > old_under
    tz = t[2, 3]
    top = np.where(present, tz - old_under, -np.inf)
    bottom = np.where(present, tz - old_top, tz - old_under)
    top.setflags(write=False)
    bottom.setflags(write=False)
    return FlippedStock(grid=grid, top=top, bottom=bottom)


def simulate_flipped(
    moves: ProgramMoves,
    tools: Mapping[int, Tool],
    setup: Setup,
    part_triangles: np.ndarray,
    start: FlippedStock,
    options: VerifyOptions = VerifyOptions(),
    progress: Callable[[int, int], None] | None = None,
    finishing: np.ndarray | None = None,
) -> tuple[Simulation, VerifyReport]:
    """:func:`simulate` starting from the stock an earlier operation left, turned over.

    The simulation keeps each column's bottom (``Simulation.stock_under``): a move that cuts
    a column down to it empties it, and later moves through it cut nothing there.
    ``below_stock`` faults are held against the lowest material there is (below it: the
    vise's parallels). ``options.cell`` must be the cell ``start`` was made on.

    Raises
    ------
    VerifyError
        As :func:`simulate`; also when ``start`` lies on another grid than this setup's.
    """
    sim, report, _ = _simulate(moves, tools, setup, part_triangles, (), options, progress, finishing, start)
    return sim, report
