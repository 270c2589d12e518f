"""Each cutting move of a pass at the feed its chip allows (issue 32): a finishing pass raised where it meets little.

A finishing pass along a wall takes only the roughing allowance off it (0.3 mm on a 10 mm end mill: a 20 deg
engagement), and much of a flats-and-walls pass crosses stock cut away already. At a radial engagement
``ae < D/2`` the chip at the edge is thinner than the feed per tooth, by the sine of the engagement angle
(``2 sqrt(ae (D - ae)) / D``, :func:`cadcam.adaptive.chip_thinned_feed`); a move in air cuts none. So each
cutting move runs at the library's feed per tooth over that sine, capped by the machine's feed.

The engagement is the one the planner knows: the pass is cut (:func:`cadcam.stock.cut_stock`) into the stock
model before it, laid on verify's grid (:data:`CHIP_CELL`) and on a second grid half a cell off it (a strip of
stock narrower than a cell can fall between one grid's points; each move keeps the larger chip), each fine point as
high as the highest of the four coarse points round it, so that the stock between the model's points, which the tool may
meet, is there (beside a wall that reads a skin up to a coarse cell thicker: slower, never faster); each move's
chip is read as verify reads it (``MoveRecord.chip``), the largest of the moves within the tool's radius along
the path (a move shorter than a cell reaches no new grid point and would read as air).
``factory verify`` judges the result independently, on its own grid from the program (``chip`` faults).
Feeds are taken down to a ladder of steps (:data:`FEED_STEP`) so that the program changes feed only where
the engagement does. Lengths in millimetres, feeds in mm/min.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from cadcam.heightmap import grid_over, upper_envelope
from cadcam.model import Motion, Operation, ProgramMoves, Setup, Tool
from cadcam.parallel import Background
from cadcam.stock import FlippedStock, Simulation, StockCut, cut_stock, operation_moves

#: Raised feeds are a power of this times the operation's feed (or the machine's cap): the program
#: changes F only where the engagement changes by more than a step, each step at most this much slower.
FEED_STEP = 1.25
#: Grid the pass's engagement is measured on [mm]: verify's default, which judges it.
CHIP_CELL = 0.2
#: A plunge move no steeper than this (rise over run) is a ramp or a helix: it cuts with the side, its chip
#: read as a cutting move's (roughing's ramps and helices descend at 3 deg, tan 0.052); a steeper one keeps
#: the plunge feed.
RAMP_SLOPE = math.tan(math.radians(5.0))
#: Passes of at least this many points measure their second grid in a process of its own (a fork costs ~20 ms;
#: a pass this long takes a second or more to cut).
_FORK_POINTS = 5000


def chip_feeds(op: Operation, stock: Simulation | None, setup: Setup, part_triangles: np.ndarray,
               max_feed: float) -> Operation:
    """``op`` with each cutting move's feed raised to what its chip allows on ``stock`` (module docstring),
    at most ``max_feed`` [mm/min], never below ``op.cutting.feed``; ``op`` itself where nothing is raised,
    its cutting data gives no chip load, or it is a drill's or a canned cycle's. ``stock`` None: the
    setup's whole block."""
    return chained_chip_feeds([op], stock, setup, part_triangles, max_feed)[0]


def chained_chip_feeds(ops: Sequence[Operation], stock: Simulation | None, setup: Setup,
                       part_triangles: np.ndarray, max_feed: float) -> list[Operation]:
    """:func:`chip_feeds` of operations that run one after the other from ``stock``: each measured on the stock
    the ones before it leave, all cut into the model once (roughing's levels, then its deep cuts)."""
    return chip_fed(ops, stock, setup, part_triangles, max_feed).operations


@dataclass(frozen=True)
class ChipFed:
    """Operations at the feeds their chips allow (:func:`chip_fed`), and the stock they leave.

    Attributes
    ----------
    operations : list of Operation
        The operations, each at the feeds its chip allows (the operation itself where nothing was raised).
    stock : Simulation or None
        The stock they leave on the setup's grid of :data:`CHIP_CELL` [mm], cut from the stock they started
        from (``removed_volume`` None: the moves before them are not counted); None where one of them was not
        measured (a drill's, a canned cycle's, one without a chip load: not cut), or none was.
    """

    operations: list[Operation]
    stock: Simulation | None


def chip_fed(ops: Sequence[Operation], stock: Simulation | None, setup: Setup, part_triangles: np.ndarray,
             max_feed: float) -> ChipFed:
    """:func:`chained_chip_feeds`, with the stock the operations leave on the setup's chip grid (the planner's
    model on that grid, measured already). ``stock`` on that very grid is taken as it is (:func:`_finer`)."""
    judged = [op for op in ops if op.cutting.chip_load is not None and not op.tool.is_drill and op.cycle is None
              and len(op.points) >= 2]
    if not judged:
        return ChipFed(list(ops), None)
    moves, tools = operation_moves(judged), {op.tool.number: op.tool for op in judged}
    again = _run_again(moves)
    # A strip of stock narrower than a cell can fall between one grid's points and read as air, while a
    # verify grid of another phase or cell has a point in it and measures the chip the raised feed makes
    # there (two floor loops 0.85 D apart leave such a strip). Measured on two grids half a cell apart, any
    # strip wider than half a cell holds a point of one of them. The two cuts are independent: the shifted
    # grid's runs on another processor where there is one and the pass is worth a process, given the part on
    # that grid (kept here for the plan's next calls; a forked process starts with no kept answers).
    shifted = _shifted(setup, 0.5 * CHIP_CELL)
    other = None
    if len(moves.points) >= _FORK_POINTS:
        part_there = upper_envelope(part_triangles, grid_over(shifted.stock_min, shifted.stock_max, CHIP_CELL))
        other = Background(_chip_shares, moves, tools, shifted, part_triangles, stock, again, part_there)
    cut = _chip_cut(moves, tools, setup, part_triangles, stock, again)
    share = np.maximum(_shares(cut, len(moves.points)), other.result() if other is not None
                       else _chip_shares(moves, tools, shifted, part_triangles, stock, again))
    left = cut.simulation
    first = np.cumsum([0] + [len(op.points) for op in judged])
    fed = {id(op): _raised(op, share[a:b], max_feed) for op, a, b in zip(judged, first[:-1], first[1:])}
    whole = len(judged) == len(ops)
    return ChipFed([fed.get(id(op), op) for op in ops],
                   dataclasses.replace(left, removed_volume=None) if whole else None)


def _run_again(moves: ProgramMoves) -> np.ndarray | None:
    """(n,) bool over ``moves.points``: the move ending at each point marked runs again along an earlier one (the
    same ends in the same order, the same tool and kind), for :func:`cadcam.stock.cut_stock` to skip; None: none
    does. The earlier move lowered the stock to their common envelope already (each grid point keeps the lowest
    cut), so the move again takes nothing off and meets no chip: the stock and every move's chip are the same to
    the bit without it. (A raster's links run back along its passes: a fifth of the relief's ball raster.)"""
    n = len(moves.points)
    if n < 3:
        return None
    key = np.empty(n - 1, dtype=[("tool", np.int64), ("motion", np.int8), ("a", np.float64, 3), ("b", np.float64, 3)])
    key["tool"], key["motion"] = moves.tool[1:], moves.motion[1:]
    key["a"], key["b"] = moves.points[:-1], moves.points[1:]
    _, first = np.unique(key.view(np.void(key.dtype.itemsize)), return_index=True)
    again = np.ones(n, bool)
    again[0] = False
    again[first + 1] = False
    return again if again.any() else None


def _chip_cut(moves: ProgramMoves, tools: Mapping[int, Tool], placed: Setup, part_triangles: np.ndarray,
              stock: Simulation | None, again: np.ndarray | None = None, part_top: np.ndarray | None = None
              ) -> StockCut:
    """``moves`` cut on the grid of :data:`CHIP_CELL` over ``placed``'s stock box from ``stock`` (None: the
    block), each move's chip measured (nothing else); the moves ``again`` marks (:func:`_run_again`) left out.
    ``part_top``: the part's envelope on that grid, if made already (:func:`cadcam.stock.cut_stock`'s)."""
    return cut_stock(moves, tools, placed, part_triangles, CHIP_CELL, measure="chip",
                     start=None if stock is None else _finer(stock, placed, CHIP_CELL), skip=again, part_top=part_top)


def _shares(cut: StockCut, n: int) -> np.ndarray:
    """(n,) the thickest chip of the move ending at each of the ``n`` points ``cut`` cut, as a share of fz."""
    share = np.zeros(n)
    np.maximum.at(share, cut.segments.move, cut.met.chip)
    return share


def _chip_shares(moves: ProgramMoves, tools: Mapping[int, Tool], placed: Setup, part_triangles: np.ndarray,
                 stock: Simulation | None, again: np.ndarray | None = None, part_top: np.ndarray | None = None
                 ) -> np.ndarray:
    """:func:`_shares` of :func:`_chip_cut` (what a process of its own sends back)."""
    return _shares(_chip_cut(moves, tools, placed, part_triangles, stock, again, part_top), len(moves.points))


def _raised(op: Operation, share: np.ndarray, max_feed: float) -> Operation:
    """``op`` with its cutting moves at the feed their chip ``share`` (of fz, per point) allows."""
    c = op.cutting
    share = _nearby_max(op.points, share, op.tool.radius + CHIP_CELL)
    full = c.spindle_rpm * op.tool.flutes * c.chip_load  # the feed at which a full-width chip is fz
    want = np.where(share > 0, full / np.maximum(share, 1e-9), np.inf)
    feed = np.where(want >= max_feed, max_feed, _ladder(want, c.feed, max_feed))
    raised = (op.motion == Motion.CUT) & (feed > c.feed * (1 + 1e-9))
    ramp = _ramp_feeds(op, want, full, max_feed)
    feed = np.where(np.isnan(ramp), feed, ramp)
    raised = (raised | ~np.isnan(ramp))
    raised[0] = False
    if not raised.any():
        return op
    if op.feeds is not None:  # feeds already raised (the adaptive cuts'): never lower one
        raised &= ~(op.feeds >= feed)
    return dataclasses.replace(op, feeds=np.where(raised, np.round(feed, 1), op.feeds if op.feeds is not None
                                                  else np.nan))


def _ladder(want: np.ndarray, base: float, max_feed: float) -> np.ndarray:
    """(n,) the highest step of the feed ladder up from ``base`` (``base`` x :data:`FEED_STEP` ** k, k >= 0) at
    or under each ``want``, at most ``max_feed`` [mm/min]; ``base`` where ``want`` is below it."""
    steps = np.floor(np.log(np.maximum(want, base) / base) / math.log(FEED_STEP) + 1e-9)
    return np.minimum(base * FEED_STEP ** steps, max_feed)


def _ramp_feeds(op: Operation, want: np.ndarray, full: float, max_feed: float) -> np.ndarray:
    """(n,) the feed of each ramp and helix move of ``op`` (a PLUNGE move across, no steeper than
    :data:`RAMP_SLOPE`) where its chip allows more than the plunge feed [mm/min], NaN elsewhere.

    ``want``: the feed at which the move's chip is fz, as verify reads it from the stock the move meets: on a
    helix the curved wall of the bore wraps round the cutter and the measured engagement is the wider one that
    gives (``tests/cadcam/test_verify_chip.py``, closed form). The edge's own speed, ``(r + R) / r`` the
    centre's, runs along the edge and adds no thickness to the chip, so it is not divided out again. The steps
    climb from the plunge feed up to the feed of the full chip (a slot's, the operation's feed); ``full``: the
    feed at which a full-width chip is fz [mm/min], as :func:`_raised` has it."""
    c, n = op.cutting, len(op.points)
    out = np.full(n, np.nan)
    step = np.diff(op.points, axis=0)
    across = np.linalg.norm(step[:, :2], axis=1)
    ramp = np.r_[False, (op.motion[1:] == Motion.PLUNGE) & (across > 1e-6) & (-step[:, 2] <= RAMP_SLOPE * across)]
    if not ramp.any():
        return out
    # the steps climb from the plunge feed, and the full chip's feed is a step too: a helix into the solid, its
    # chip the whole fz there, runs at a full-width cut's feed, not at the step under it (1.25 x slower at most)
    feed = _ladder(want, c.plunge_feed, max_feed)
    top = min(full, c.feed, max_feed)
    feed = np.where(want >= top * (1 - 1e-9), np.maximum(feed, top), feed)
    fast = ramp & (feed > c.plunge_feed * (1 + 1e-9))
    out[fast] = feed[fast]
    return out


def _nearby_max(points: np.ndarray, share: np.ndarray, reach: float) -> np.ndarray:
    """``share`` of each move raised to the largest of the moves within ``reach`` [mm] of it along the path.

    The model measures a move by the grid points its sweep newly reaches: a move shorter than a cell may reach
    none and read as air while it cuts between them what the moves beside it were measured cutting."""
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))]
    lo = np.searchsorted(s, s - reach, side="left")
    hi = np.searchsorted(s, s + reach, side="right")
    # the largest of share[lo:hi] for every move at once: the maxima of runs of 2**k moves (k up to the longest
    # window's), two of them covering each window
    width = hi - lo  # >= 1: each window holds its own move
    out, run, k = share.copy(), share, 0
    while (2 << k) <= width.max():
        run = np.maximum(run[:-(1 << k)], run[1 << k:])  # run[i]: the largest of share[i : i + 2**(k + 1)]
        k += 1
        at = np.flatnonzero(width >= (1 << k))
        top = np.floor(np.log2(width[at])).astype(np.int64) == k
        at = at[top]
        out[at] = np.maximum(run[lo[at]], run[hi[at] - (1 << k)])
    return out


def _shifted(setup: Setup, by: float) -> Setup:
    """``setup`` with its stock box moved ``by`` [mm] along X and Y: its grid's points (:func:`grid_over`) fall
    ``by`` from the setup's own. The box's sides move by ``by`` too; each move keeps the larger chip of the two
    grids, so what the moved sides miss is still read on the setup's own grid."""
    step = np.array([by, by, 0.0])
    return dataclasses.replace(setup, stock_min=np.asarray(setup.stock_min) + step,
                               stock_max=np.asarray(setup.stock_max) + step)


def _finer(stock: Simulation, setup: Setup, cell: float) -> FlippedStock | Simulation:
    """``stock`` on the grid of ``cell`` [mm] over ``setup``'s stock box: each point's top the highest of the
    four model points round it, its bottom the lowest (never less stock than the model may hold there); a model
    on that very grid as it is (its part top too: :func:`cadcam.stock.cut_stock` cuts on into it)."""
    g0, grid = stock.grid, grid_over(setup.stock_min, setup.stock_max, cell)
    if g0 == grid:
        return stock

    def around(at: np.ndarray, start: float, n: int) -> tuple[np.ndarray, np.ndarray]:
        i = np.clip(np.floor((at - start) / g0.cell).astype(np.int64), 0, n - 1)
        return i, np.minimum(i + 1, n - 1)

    (i0, i1), (j0, j1) = around(grid.xs, g0.x0, g0.nx), around(grid.ys, g0.y0, g0.ny)
    top0 = np.where(np.isfinite(stock.stock_top), stock.stock_top, -np.inf)
    top = np.maximum.reduce([top0[np.ix_(j, i)] for j in (j0, j1) for i in (i0, i1)])
    under = stock.stock_under
    if under is None:
        bottom = np.full(top.shape, stock.stock_bottom)
    else:
        low = np.where(np.isfinite(under), under, np.inf)
        bottom = np.minimum.reduce([low[np.ix_(j, i)] for j in (j0, j1) for i in (i0, i1)])
        bottom = np.where(np.isfinite(bottom), bottom, stock.stock_bottom)
    return FlippedStock(grid=grid, top=top, bottom=bottom)
