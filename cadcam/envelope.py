"""The swept envelope of a milling tool: the lowest its cutting surface comes over each grid point along a straight move.

For a grid point ``q`` and a move from ``p0`` to ``p1`` (tool tip positions),

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

Each move covers the grid points within the tool radius of its XY segment, enumerated
exactly row by row (:func:`grid_pairs`); the stock model (:mod:`cadcam.stock`) evaluates
those (grid point, move) pairs in batches with :func:`pair_envelope`, one pair at a time in the compiled loops
of :mod:`cadcam.toolsweep`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cadcam.heightmap import Grid
from cadcam.model import BALL, BULL, CONE, FLAT, Tool

#: Bull-nose tools: bisect until the minimiser is known to this along the move [mm]. The
#: height error is second order in it (``f' = 0`` there), far below a nanometre.
_BISECT_RESOLUTION = 1e-6


def _profile(r: np.ndarray, flat_radius: np.ndarray, rc: np.ndarray) -> np.ndarray:
    """:meth:`Tool.profile_height` for per-pair tool sizes, clamped at the radius (no inf)."""
    d = np.minimum(np.maximum(r - flat_radius, 0.0), rc)
    return rc - np.sqrt(np.maximum(rc * rc - d * d, 0.0))



@dataclass
class Segments:
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
        self.shape = np.where(self.cone > 0.0, CONE,
                              np.where(self.rc == 0.0, FLAT, np.where(ball, BALL, BULL))).astype(np.int8)

    def __len__(self) -> int:
        return len(self.x)

    @classmethod
    def between(cls, p0, p1, radius, rc, rapid=None, move=None, cone=None) -> "Segments":
        k = len(p0)
        return cls(
            np.ascontiguousarray(p0[:, 0]), np.ascontiguousarray(p0[:, 1]), np.ascontiguousarray(p0[:, 2]),
            p1[:, 0] - p0[:, 0], p1[:, 1] - p0[:, 1], p1[:, 2] - p0[:, 2],
            np.asarray(radius, dtype=np.float64), np.asarray(rc, dtype=np.float64),
            np.zeros(k, bool) if rapid is None else rapid, np.arange(k) if move is None else move,
            None if cone is None else np.asarray(cone, dtype=np.float64),
        )

    def sub(self, s: int, e: int) -> "Segments":
        out = object.__new__(Segments)
        for name, value in vars(self).items():
            setattr(out, name, value[s:e])
        return out


def pair_envelope(
    qx: np.ndarray, qy: np.ndarray, owner: np.ndarray, seg: Segments, bound: np.ndarray | None = None
) -> np.ndarray:
    """Lowest point of the swept tool above each query point, one (point, move) pair per entry.

    Parameters
    ----------
    qx, qy : (k,) float
        Query points [mm].
    owner : (k,) int
        Row of ``seg`` (the move) for each query point.
    seg : Segments
    bound : (k,) float, optional
        Only envelopes below this matter [mm] (the current stock top): pairs whose cheap
        lower bound is not below it are not evaluated exactly and come back as ``inf``.

    Returns
    -------
    (k,) float
        Envelope height [mm]; ``inf`` where the tool never comes within its radius (or,
        with ``bound``, where it provably stays at or above the bound).
    """
    if len(qx) == 0:
        return np.full(0, np.inf)
    return _Approach.of(qx, qy, owner, seg).envelope(owner, seg, bound)


@dataclass(frozen=True)
class _Approach:
    """Each (grid point, move) pair's nearest approach, the part of :func:`pair_envelope` that needs no stock bound:
    ``lower`` the lowest tip height plus the profile there [mm] (exact for horizontal and vertical moves, else a
    lower bound: z(t) >= zmin and r(t) >= that distance), ``reach`` whether the point is within the radius, and
    ``wx, wy, wd`` (the point less the move's start [mm], its dot product with the move [mm^2]) for the exact
    envelope. (k,) arrays, one entry per pair."""

    lower: np.ndarray
    reach: np.ndarray
    wx: np.ndarray
    wy: np.ndarray
    wd: np.ndarray

    @classmethod
    def of(cls, qx: np.ndarray, qy: np.ndarray, owner: np.ndarray, seg: Segments) -> "_Approach":
        from cadcam import toolsweep  # numba loads with the first cut, not with every command importing this

        toolsweep.say_if_compiling()
        # the profile only where some move's is not 0 at the nearest approach (a flat end mill's is)
        return cls(*toolsweep.nearest_approach(qx, qy, owner, seg.x, seg.y, seg.dx, seg.dy, seg.inv_l2, seg.zmin,
                                               seg.flat_radius, seg.rc, seg.cone, seg.radius, seg.reach2,
                                               bool(np.any(seg.shape != FLAT)), bool(seg.cone.any())))

    @classmethod
    def kept(cls, seg: Segments, grid: Grid, stock: np.ndarray, tops: "SpanTops | None" = None) -> tuple:
        """``owner, flat, col, row`` and the approach of the pairs of moves ``seg`` on ``grid`` that can cut
        ``stock`` (ny * nx,) [mm]: within reach, ``lower`` under it, in :func:`grid_pairs`' order
        (:func:`cadcam.toolsweep.kept_pairs`); ``tops``: bounds of that stock, or of an earlier state of it, which
        leave out the runs and pieces (:data:`_PIECE`) the moves provably cannot cut."""
        from cadcam import toolsweep

        toolsweep.say_if_compiling()
        # no tops: no levels to read, each run one piece
        table, block, piece = (np.zeros((0, 1, 1)), 1, 1 << 40) if tops is None else (tops.table, tops._BLOCK, _PIECE)
        *pairs, lower, wx, wy, wd = toolsweep.kept_pairs(
            *_row_spans(seg, grid), grid.nx, grid.x0, grid.y0, grid.cell, stock, seg.x, seg.y, seg.dx, seg.dy,
            seg.inv_l2, seg.zmin, seg.flat_radius, seg.rc, seg.cone, seg.radius, seg.reach2,
            bool(np.any(seg.shape != FLAT)), bool(seg.cone.any()), table, block, piece)
        return (*pairs, cls(lower, np.ones(len(lower), bool), wx, wy, wd))

    def take(self, keep: np.ndarray) -> "_Approach":
        """The pairs ``keep`` (indices, in order) of these."""
        return _Approach(self.lower[keep], self.reach[keep], self.wx[keep], self.wy[keep], self.wd[keep])

    def envelope(self, owner: np.ndarray, seg: Segments, bound: np.ndarray | None = None) -> np.ndarray:
        """:func:`pair_envelope` of these pairs (``owner``: each one's row of ``seg``), with ``bound``."""
        env = np.full(len(owner), np.inf)
        cand = self.reach if bound is None else self.reach & (self.lower < bound)
        idx = np.flatnonzero(cand)
        if len(idx) == 0:
            return env
        o = owner[idx]
        out = self.lower[idx]
        sloped = np.flatnonzero(~seg.trivial[o])
        if len(sloped):
            out[sloped] = _sloped_envelope(self, owner, idx[sloped], seg)
        env[idx] = out
        return env


@dataclass(frozen=True)
class BatchPairs:
    """The (grid point, move) pairs of a batch of moves (:func:`grid_pairs`) with each one's nearest approach,
    all that :func:`pair_envelope` works out before it reads the stock: made from stock bounds ``above`` that
    may be older than the stock the batch cuts (it only falls, so they still hold), the pairs are a superset of
    those made from newer ones whose extra pairs :meth:`envelope` never finds below the stock. So they can be
    made while the batch before is still cutting (:func:`cadcam.stock.cut_stock`).

    ``owner, flat, col, row``: (k,) int, as :func:`grid_pairs` gives them. Made against a stock (:meth:`of`):
    ``exact`` (k,) float, each pair's envelope [mm]; ``bisect`` (k,) bool, the pairs whose envelope is a bull-nose's
    bisection (on a sloped move), ``lengths`` (k,) the stretch of the move bisected [mm] (0 for the others) and
    ``steps`` the bisection's steps (:func:`_bisect_steps` of all of them): :meth:`envelope` takes their values
    only where the pairs it bisects would take as many."""

    owner: np.ndarray
    flat: np.ndarray
    col: np.ndarray
    row: np.ndarray
    approach: _Approach
    exact: np.ndarray | None = None
    bisect: np.ndarray | None = None
    lengths: np.ndarray | None = None
    steps: int = 0

    @classmethod
    def of(cls, seg: Segments, grid: Grid, above=None, pairs=None, stock: np.ndarray | None = None) -> "BatchPairs":
        """The pairs of moves ``seg`` on ``grid``, with :func:`grid_pairs`'s ``above`` (``pairs``: that
        function, or one that stands for it). ``stock``: (ny * nx,) the stock's top [mm] as it is now, or any
        later state of it: only the pairs whose cheap bound comes below it within reach are kept (in their
        order), the others :meth:`envelope` would give ``inf`` against it or any lower stock; and the kept
        ones' closed-form envelopes are worked out. Read while another thread cuts it
        (:func:`cadcam.stock.cut_stock`), each value is one it held, so an upper bound."""
        tops = getattr(above, "__self__", None)
        if stock is not None and pairs in (None, grid_pairs) and (above is None or (
                isinstance(tops, SpanTops) and above.__func__ is _SPAN_TOPS_ABOVE)):
            # The pairs that can cut: the rest (most of them) leave here, not in every pass of the cut, which runs
            # on the thread a second processor does not help (issue 35), and are never written out: one compiled
            # walk over the rows, judged against the tops' table as it goes (grid_runs' culls), instead of every
            # pair's arrays, their approach's and the kept ones' copies. A stand-in ``above`` or ``pairs`` (a
            # test's) goes the way of grid_pairs, whose pairs are then filtered alike.
            owner, flat, col, row, approach = _Approach.kept(seg, grid, stock, tops)
        else:
            owner, flat, col, row = (pairs or grid_pairs)(seg, grid, above)
            approach = _Approach.of(grid.x0 + col * grid.cell, grid.y0 + row * grid.cell, owner, seg)
            if stock is None or len(owner) == 0:
                return cls(owner, flat, col, row, approach)
            keep = approach.reach & (approach.lower < stock[flat])  # a stand-in's pairs (a test's), as they come
            if not keep.all():
                keep = np.flatnonzero(keep)
                owner, flat, col, row = owner[keep], flat[keep], col[keep], row[keep]
                approach = approach.take(keep)
        # Each pair's envelope depends on its own inputs only (the values envelope() would give), but for the
        # bull-nose's bisection, whose step count follows the longest stretch it is given: envelope() checks it.
        exact = approach.lower.copy()
        bisect = ~seg.trivial[owner]
        sloped = np.flatnonzero(bisect)
        bisect[sloped] = seg.shape[owner[sloped]] == BULL
        b = sloped[bisect[sloped]]
        lengths, steps = None, 0
        if len(b):
            lengths = np.zeros(len(owner))
            lengths[b] = _bisected_lengths(approach, owner, b, seg)
            steps = _bisect_steps(lengths[b])
        if len(sloped):
            exact[sloped] = _sloped_envelope(approach, owner, sloped, seg, steps)
        return cls(owner, flat, col, row, approach, exact, bisect, lengths, steps)

    def envelope(self, seg: Segments, bound: np.ndarray) -> np.ndarray:
        """:func:`pair_envelope` of the pairs with ``bound`` (k,) [mm]: the same values, to the bit."""
        if len(self.owner) == 0:
            return np.full(0, np.inf)
        if self.exact is None:
            return self.approach.envelope(self.owner, seg, bound)
        env = np.full(len(self.owner), np.inf)
        idx = np.flatnonzero(self.approach.lower < bound)  # (all within reach)
        out = self.exact[idx]
        bull = np.flatnonzero(self.bisect[idx])
        if len(bull) and _bisect_steps(self.lengths[idx[bull]]) != self.steps:
            # the longest stretch left to bisect needs fewer halvings than the longest when made did: bisected
            # here with those, as before the pairs were made ahead (in practice a batch keeps its longest)
            out[bull] = _sloped_envelope(self.approach, self.owner, idx[bull], seg)
        env[idx] = out
        return env


def _bisected_lengths(a: _Approach, owner: np.ndarray, pick: np.ndarray, seg: Segments) -> np.ndarray:
    """(len(pick),) how long the stretch of each picked pair's move is that its bull-nose bisection searches [mm]."""
    from cadcam import toolsweep

    return toolsweep.bisected_lengths(a.wx, a.wy, a.wd, owner, pick, seg.dx, seg.dy, seg.dz, seg.l2, seg.radius)


def _bisect_steps(lengths: np.ndarray) -> int:
    """How many halvings take the longest of ``lengths`` [mm] (1-D, not empty) to :data:`_BISECT_RESOLUTION`."""
    span = float(np.max(lengths))
    return int(np.clip(math.ceil(math.log2(max(span, 1e-300) / _BISECT_RESOLUTION)), 1, 60))


def _sloped_envelope(a: _Approach, owner: np.ndarray, pick: np.ndarray, seg: Segments, steps: int | None = None
                     ) -> np.ndarray:
    """(len(pick),) the exact envelope [mm] of pairs ``pick`` of ``a`` (``owner``: each pair's move row) whose moves
    climb or descend while moving sideways (:func:`cadcam.toolsweep.sloped_envelope`). ``steps``: the
    bull-nose's bisection steps (:func:`_bisect_steps`; default, those of the picked pairs)."""
    if steps is None:
        bull = pick[seg.shape[owner[pick]] == BULL]
        steps = _bisect_steps(_bisected_lengths(a, owner, bull, seg)) if len(bull) else 1
    from cadcam import toolsweep

    return toolsweep.sloped_envelope(a.wx, a.wy, a.wd, owner, pick, seg.z, seg.dx, seg.dy, seg.dz, seg.l2,
                                     seg.radius, seg.rc, seg.cone, seg.shape, steps)


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
    seg = Segments.between(p0, p1, [tool.radius], [float(tool.corner_radius)], cone=[tool.point_slope])
    return pair_envelope(q[:, 0].copy(), q[:, 1].copy(), np.zeros(len(q), np.int64), seg)


def _row_spans(seg: Segments, grid: Grid) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The grid points each move's tool passes over, as runs of columns on each grid row.

    The region is the set of points within the tool radius of the move's XY segment (a
    stadium); its intersection with a row is one interval: the union of those of the two
    end disks and of the band along the segment (:func:`cadcam.toolsweep.row_spans`, compiled).

    Returns
    -------
    owner, row, first, count : (r,) int64
        Move, grid row, first column and number of columns of each run (count may be 0).
    """
    from cadcam import toolsweep

    return toolsweep.row_spans(seg.x, seg.y, seg.dx, seg.dy, seg.radius, grid.x0, grid.y0, grid.cell, grid.nx, grid.ny)


def grid_pairs(seg: Segments, grid: Grid, above: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray] | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every (segment, grid point) pair within a segment's reach: owner, flat index, column, row.

    ``above(row, first, count)``: optional, an upper bound on the heights of interest [mm] over each
    run of ``count`` columns from ``first`` on grid ``row`` (the stock there); a run over which the
    move's tool cannot come below it (:func:`row_lower`) gives no pairs, as :func:`pair_envelope`
    with that bound would give them no envelope. The other pairs come in the same order."""
    row_owner, row, first, count = _row_spans(seg, grid)
    if above is not None and len(count):
        live = np.flatnonzero(count > 0)
        lower = row_lower(seg, row_owner[live], grid.y0 + row[live] * grid.cell)
        count[live[lower >= above(row[live], first[live], count[live])]] = 0
        row_owner, row, first, count = _live_pieces(seg, grid, above, row_owner, row, first, count)
    from cadcam import toolsweep

    return toolsweep.run_pairs(row_owner, row, first, count, grid.nx)


#: A run of a row's grid points that survives :func:`row_lower` is judged again in pieces of this many columns
#: (on multiples of it), each against its own stretch of stock and its own distance from the move: most of the
#: pairs a run leaves are still ones the move cannot cut (72 % of them in the dome's plan). The dome's verify:
#: 29.4 million pairs whole, 18.4 million in pieces of 16, 18.0 in pieces of 8 (more pieces cost more than that).
_PIECE = 16


def _live_pieces(seg: Segments, grid: Grid, above, owner, row, first, count):
    """The runs ``owner, row, first, count`` (:func:`_row_spans`) cut into pieces of :data:`_PIECE` columns, the
    pieces the move provably cannot cut (as :func:`row_lower`, the distance across the row too) given no
    columns; the others in the runs' order, so the pairs that are left come in the same order."""
    from cadcam import toolsweep

    p_owner, p_row, start, p_count = toolsweep.run_pieces(owner, row, first, count, _PIECE)
    if len(p_count) == np.count_nonzero(count > 0):  # no run is more than one piece
        return owner, row, first, count
    lower = row_lower(seg, p_owner, grid.y0 + p_row * grid.cell, grid.x0 + start * grid.cell,
                      grid.x0 + (start + p_count - 1) * grid.cell)
    p_count[lower >= above(p_row, start, p_count)] = 0
    return p_owner, p_row, start, p_count


def row_lower(seg: Segments, owner: np.ndarray, yr: np.ndarray, xa: np.ndarray | None = None,
              xb: np.ndarray | None = None) -> np.ndarray:
    """A lower bound [mm] of :func:`pair_envelope`'s cheap bound ``lower`` (lowest tip height plus the
    profile at the nearest approach) at every point of grid row ``yr`` [mm] (from ``xa`` to ``xb`` [mm] when
    given), for the move of each row ``owner``: the nearest approach of such a point is at least the distance
    from the row's line (or stretch) to the box round the move's XY segment, and the profile only rises with
    distance (rounding included: the distance is taken 1e-7 mm short, far beyond any rounding of it).
    Compiled (:func:`cadcam.toolsweep.row_lower`)."""
    from cadcam import toolsweep

    across = xa is not None
    xa, xb = (xa, xb) if across else (yr, yr)
    return toolsweep.row_lower(owner, yr, xa, xb, seg.x, seg.y, seg.dx, seg.dy, seg.zmin, seg.flat_radius, seg.rc,
                               seg.cone, seg.radius, across)


def reach_interval(seg: Segments, o: np.ndarray, qx: np.ndarray, qy: np.ndarray):
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


class SpanTops:
    """Upper bounds of a stock z-map [mm] on any run of columns of a grid row: the maxima of blocks of
    :data:`_BLOCK` columns, in a sparse table over each row (the maximum of ``2**k`` blocks from each
    block), so a run's bound is the larger of two table entries. :func:`grid_pairs` reads them (``above``)
    to leave out the runs of grid points a move provably cannot cut (:mod:`cadcam.stock`)."""

    _BLOCK = 16

    def __init__(self, stock: np.ndarray, grid: Grid):
        from cadcam import toolsweep

        nb = -(-grid.nx // self._BLOCK)
        level = toolsweep.block_tops(stock.reshape(grid.ny, grid.nx), self._BLOCK)  # (ny, nb), as np.max reads them
        levels = [level]
        width = 1
        while 2 * width <= nb:
            nxt = np.full_like(level, -np.inf)
            nxt[:, :nb - width] = np.maximum(level[:, :nb - width], level[:, width:])
            levels.append(nxt)
            level, width = nxt, 2 * width
        self.table = np.stack(levels)  # (levels, ny, blocks)

    @classmethod
    def of_table(cls, table: np.ndarray) -> "SpanTops":
        """The bounds whose table is ``table`` (as :attr:`table` holds it)."""
        out = object.__new__(cls)
        out.table = table
        return out

    def highest(self) -> float:
        """The highest the stock is anywhere, or more [mm] (a sixteenth of the reads of the stock's own)."""
        return float(self.table[0].max())

    def above(self, row: np.ndarray, first: np.ndarray, count: np.ndarray) -> np.ndarray:
        """(r,) the highest the stock is over columns ``first .. first + count - 1`` (count >= 1) of ``row``, or more [mm]."""
        from cadcam import toolsweep

        return toolsweep.span_tops_above(self.table, self._BLOCK, row, first, count)


#: The tops' own bounds: :meth:`BatchPairs.of` reads their table in the compiled walk (any other ``above`` is called).
_SPAN_TOPS_ABOVE = SpanTops.above
