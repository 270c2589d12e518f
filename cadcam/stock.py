"""The stock model: a z-map of the material a program leaves, cut move by move.

The stock is a heightfield: one top height per grid point (:func:`cadcam.heightmap.grid_over`).
Every move lowers it to the tool's swept lower envelope there (:mod:`cadcam.envelope`), exact at
the grid points: the remaining stock and the depth a move cuts are true values there, and what
the grid can miss is detail *between* points (cost grows as ``1 / cell**2``).

(grid point, move) pairs from consecutive moves are evaluated in vectorised batches. A cheap
lower bound (lowest tip height plus the profile at the nearest approach) skips the exact
evaluation wherever the move cannot go below the stock. Cuts within a batch commute (the stock
keeps the minimum); what each move *met* (the column it took off, its engaged depth and width,
its shank and holder's reach into stock or part) is measured against the stock exactly as every
earlier move left it, for the verdict (:mod:`cadcam.verify`).

The CAM stages plan on it: what earlier operations left (:func:`stock_after`), how low a tool
may come without touching it (:func:`clear_height`), and op 2's stock, op 1's turned over
(:func:`flip_stock`).
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage

from cadcam.engagement import ENGAGED_WIDTH, FULL_WIDTH_ANGLE, MoveRecord, engaged_depth, record_max, side_chip
from cadcam.envelope import BatchPairs, Segments, grid_pairs, pair_envelope, reach_interval
from cadcam.envelope import SpanTops as _SpanTops
from cadcam.gridregion import highest_near
from cadcam.heightmap import Grid, grid_over, upper_envelope
from cadcam.model import Motion, Operation, ProgramMoves, Setup, Tool
from cadcam.parallel import processors
from factory.core.errors import VerifyError

#: (grid point, move) pairs per vectorised batch: small enough for the work arrays to stay in cache.
_PAIR_BUDGET = 1 << 16

#: Largest grid the stock model accepts (two float64 maps of this size plus work arrays).
_MAX_CELLS = 60_000_000

#: Rapids are swept with the cutter's rim drawn in by this much [mm] unless told otherwise: a
#: rapid whose rim only grazes a wall's skin (a contour's arcs and the posted coordinates'
#: rounding leave a skin microns thick beside the line a descent comes down on) leaves it.
#: :attr:`cadcam.verify.VerifyOptions.rapid_tolerance` defaults to it, so the stock a CAM stage
#: plans on is the stock verify finds.
RAPID_RIM = 0.01



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
    #: not stand on one plane (op 2's turned-over part: :func:`cut_stock` from a :class:`FlippedStock`);
    #: a column cut through is empty and its ``stock_top`` is ``-inf``; ``stock_bottom`` is the
    #: lowest of them. None: every column stands on ``stock_bottom``.
    stock_under: np.ndarray | None = None
    #: (n,) float or None: the stock volume each move removed [mm³] (grid cell area times the
    #: height of stock it took off each grid point, down to the stock's bottom), indexed like
    #: ``ProgramMoves.points`` (0 for ``points[0]`` and for moves that cut nothing): the
    #: engagement the cutting-power model reads (:mod:`cadcam.cutting_power`). None: not recorded.
    removed_volume: np.ndarray | None = None


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


@dataclass(frozen=True)
class StockCut:
    """A program cut into the stock model, and what each of its moves met on the way.

    Attributes
    ----------
    simulation : Simulation
        The stock after every move, and the part on the same grid.
    snapshots : tuple of (ny, nx) float
        Stock top at each snapshot asked for [mm] (read-only), on ``simulation.grid``.
    segments : Segments
        The moves that came below the stock top, in program order, as swept: ``move`` is the
        index of each one's end point in :attr:`ProgramMoves.points`; rapids with the cutter's
        rim drawn in by the ``rapid_rim`` of :func:`cut_stock`.
    met : MoveRecord
        What each of ``segments`` met, row for row.
    starts : (n - 1, 3) float
        Where each move (to ``points[1:]``) starts [mm]: the point before it, or its own end
        where that is unknown (the move that first makes the position known is checked
        standing at its end).
    swept : (n - 1,) bool
        Moves with both ends known and a tool in the spindle.
    """

    simulation: Simulation
    snapshots: tuple[np.ndarray, ...]
    segments: Segments
    met: MoveRecord
    starts: np.ndarray
    swept: np.ndarray


def cut_stock(
    moves: ProgramMoves,
    tools: Mapping[int, Tool],
    setup: Setup,
    part_triangles: np.ndarray,
    cell: float,
    *,
    snapshot_moves: Sequence[int] = (),
    start: FlippedStock | Simulation | None = None,
    progress: Callable[[int, int], None] | None = None,
    rapid_rim: float = RAPID_RIM,
    engaged_width: float = ENGAGED_WIDTH,
    body_graze: float = 0.0,
    full_width_angle: float = FULL_WIDTH_ANGLE,
    measure: bool | str = True,
    resume: Any = None,
    skip: np.ndarray | None = None,
    part_top: np.ndarray | None = None,
) -> StockCut:
    """Cut the stock with every move of a program, measuring what each move meets.

    Parameters
    ----------
    moves : ProgramMoves
        The program's moves (tool tip positions in work coordinates [mm]); moves ending at
        an unknown (NaN) coordinate are skipped, a move from an unknown start is cut as the
        tool standing at its end; rapids with an empty spindle (tool 0) are skipped too.
    tools : mapping of int to Tool
        Tools by number, for every tool the program uses.
    setup : Setup
        The stock box (``stock_min``, ``stock_max``) in work coordinates [mm].
    part_triangles : (m, 3, 3) float
        The part's triangles in work coordinates [mm].
    cell : float
        Grid spacing [mm], > 0 (:attr:`cadcam.verify.VerifyOptions.cell`).
    snapshot_moves : (s,) sequence of int
        Indices into ``moves.points``: snapshot ``k`` is the stock once every move up to
        and including the one ending at ``points[snapshot_moves[k]]`` has cut (0: the
        uncut stock). Any order; repeats allowed.
    start : FlippedStock or Simulation, optional
        The stock an earlier operation left, turned over (:func:`flip_stock`), on this setup's
        grid at ``cell``; each column keeps its bottom (``Simulation.stock_under``): a move
        that cuts a column down to it empties it. Or the stock earlier moves of this program left
        (a :class:`Simulation` of this setup and part at ``cell``): these moves cut on into it,
        its part top is taken as it is, and the stock they leave is the one cutting all the moves
        would leave (cuts commute: each grid point keeps the lowest). None: the setup's stock box.
    progress : callable, optional
        ``progress(done, total)`` in moves.
    rapid_rim : float
        Rapids are swept with the cutter's rim drawn in by this much [mm] (:data:`RAPID_RIM`).
    engaged_width : float
        A cut counts as engagement only where it is at least this wide across the move [mm].
    body_graze : float
        A shank or holder reaching sideways into stock or part by no more than this is no
        contact [mm] (a shank as wide as the cutter rides a finished wall at its radius).
    full_width_angle : float
        A move meeting material over this arc of the cutter or more cuts at full width [deg]
        (:data:`FULL_WIDTH_ANGLE`; ``MoveRecord.full_depth``).
    measure : bool or "chip"
        False: only the stock and what each move removed (``MoveRecord.removed_*``, the volume)
        are recorded; the engagement (depth, width, angle) and the shank and holder contacts are
        not measured, and stay zero. The stock is the same either way. For a caller that reads only
        rapids (:func:`cadcam.verify.rapid_check`), this saves most of the work beside the cut.
        ``"chip"``: only the stock and each move's chip (``MoveRecord.chip``, as True measures it; nothing
        removed is recorded), for a caller that reads only those (:mod:`cadcam.chipfeed`).
    resume : cadcam.cutahead.CutState, optional
        The first moves of this program cut already (:func:`cadcam.cutahead.cut_ahead`, in another process
        meanwhile): the cut goes on from there when they are this program's first moves, swept alike, into
        this stock and part with these options (:class:`cadcam.cutahead.CutState`), else it starts at the
        first move; the result is the same. Not read with ``snapshot_moves`` or ``skip``.
    skip : (n,) bool, optional
        Over ``moves.points``: the move ending at each point marked is not swept (it meets and removes
        nothing, ``StockCut.swept`` False), for a caller that knows it takes nothing off (:mod:`cadcam.chipfeed`:
        a move run again along an earlier one). None: none skipped.
    part_top : (ny, nx) float, optional
        The part's :func:`upper_envelope` on this grid if made already (a worker's parent's); else ``start``'s or made.

    Raises
    ------
    VerifyError
        If a feed move runs with no tool, or any move with a tool not in ``tools``
        (``source`` names the G-code line, ``data["line"]`` holds it); if the part, stock,
        cell or snapshot indices are unusable, or ``start`` lies on another grid.
    """
    snap = np.asarray(snapshot_moves, dtype=np.int64).reshape(-1)
    if len(snap) and (snap.min() < 0 or snap.max() >= len(moves.points)):
        raise VerifyError(f"snapshot move indices must lie in 0..{len(moves.points) - 1}", source="snapshot_moves")
    cut = _Cut(moves, tools, setup, part_triangles, cell, start, rapid_rim, engaged_width, body_graze,
               full_width_angle, measure, snap, skip, part_top)
    grid, stock, under, seg, met = cut.grid, cut.stock, cut.under, cut.seg, cut.met
    part_top, stock_bottom, starts, swept = cut.part_top, cut.stock_bottom, cut.starts, cut.swept
    first, tops = (0, None) if resume is None or len(snap) or skip is not None else resume.restore(cut)
    stocks = _run(cut, progress, cut.bounds, first, tops)
    met.freeze()

    stock_top = stock.reshape(grid.shape)
    stock_top.setflags(write=False)
    part_top.setflags(write=False)
    removed_volume = np.zeros(len(moves.points))
    np.add.at(removed_volume, seg.move, met.volume)
    removed_volume.setflags(write=False)
    sim = Simulation(grid=grid, stock_top=stock_top, part_top=part_top, stock_bottom=float(setup.stock_min[2]),
                     floor_z=setup.floor_z, removed_volume=removed_volume)
    if under is not None:
        stock_under = under.reshape(grid.shape)
        stock_under.setflags(write=False)
        sim = dataclasses.replace(sim, stock_bottom=stock_bottom, stock_under=stock_under)
    snapshots = tuple(flat.reshape(grid.shape) for flat in stocks)
    for top in snapshots:
        top.setflags(write=False)
    starts.setflags(write=False)
    swept.setflags(write=False)
    return StockCut(simulation=sim, snapshots=snapshots, segments=seg, met=met, starts=starts, swept=swept)


def _starting_stock(setup: Setup, grid: Grid, start: FlippedStock | Simulation | None
                    ) -> tuple[np.ndarray, np.ndarray | None, float, float]:
    """The stock before the first move, flat on ``grid``: its top and (a flipped stock only) its
    bottom per grid point, its highest top and its lowest bottom [mm]."""
    if start is None:
        top_z = float(setup.stock_max[2])
        return np.full(grid.size, top_z), None, top_z, float(setup.stock_min[2])
    if start.grid != grid:
        raise VerifyError(f"the starting stock's grid {start.grid} is not this setup's {grid}", source="stock")
    if isinstance(start, Simulation):
        stock = np.array(start.stock_top, dtype=np.float64).reshape(-1)
        if start.stock_under is None:  # the setup's block, cut: moves over its top cut nothing, as from the block
            return stock, None, float(setup.stock_max[2]), start.stock_bottom
        under = np.array(start.stock_under, dtype=np.float64).reshape(-1)
        finite = stock[np.isfinite(stock)]
        return stock, under, float(finite.max()) if len(finite) else float(setup.stock_max[2]), start.stock_bottom
    stock = np.array(start.top, dtype=np.float64).reshape(-1)
    under = np.array(start.bottom, dtype=np.float64).reshape(-1)
    stock[~(stock > under)] = -np.inf  # empty columns hold nothing to cut
    finite = stock[np.isfinite(stock)]
    top_z = float(finite.max()) if len(finite) else float(setup.stock_max[2])
    stock_bottom = float(under[np.isfinite(stock)].min()) if len(finite) else float(setup.stock_min[2])
    return stock, under, top_z, stock_bottom


def _swept_moves(moves: ProgramMoves, tools: Mapping[int, Tool], top_z: float, rapid_rim: float,
                 skip: np.ndarray | None = None) -> tuple[Segments, np.ndarray, np.ndarray, np.ndarray]:
    """The moves to sweep, as :class:`Segments`: those with a tool whose tip comes below ``top_z``, less those
    ``skip`` marks (:func:`cut_stock`'s).

    Returns the segments, each move's start and the moves swept (as :class:`StockCut` holds
    them) and the moves whose end is known.
    """
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
    radius, rc, cone = _tool_table(moves, tools, known)
    # "Reaches more than rapid_tolerance into the stock" holds sideways too: a rapid whose rim
    # only grazes a wall's skin is not a crash, so rapids are swept with the rim drawn in.
    radius[rapid] -= rapid_rim
    rc[rapid] = np.minimum(rc[rapid], radius[rapid])
    swept = known & np.isfinite(radius)
    if skip is not None:
        swept &= ~np.asarray(skip, dtype=bool)[1:]
    # A move whose tip never comes below the stock top cannot touch the stock.
    use = swept.copy()
    use[use] &= np.minimum(a[use, 2], b[use, 2]) < top_z
    idx = np.flatnonzero(use)
    seg = Segments.between(a[idx], b[idx], radius[idx], rc[idx], rapid[idx], idx + 1, cone[idx])
    return seg, a, swept, known


def _check_inputs(setup: Setup, cell: float, tri: Any) -> np.ndarray:
    """The part's triangles as float; VerifyError for an unusable cell, part or stock box."""
    if not (math.isfinite(cell) and cell > 0):
        raise VerifyError(f"cell must be a positive number of mm, got {cell}", source="cell")
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
    check_grid_size(setup, cell)
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


#: Material within this sideways of a part wall at least as tall (less this), over part
#: lower than that, is the wall's skin [mm]: a finishing tool takes it off whatever its
#: height (raster passes meet walls head-on).
_SKIN = 1.0


class _Body:
    """The shank and holder of the tool making each segment, as flat cylinders to sweep.

    ``levels[t]``: ``(height above the tip, radius)`` of tool ``t``'s body cylinders
    (:meth:`Tool.body`), radii growing with height.
    """

    def __init__(self, tools: Mapping[int, Tool], tool_of_seg: np.ndarray, part_flat: np.ndarray,
                 engaged_width: float, graze: float = 0.0):
        self.tool_of_seg = np.asarray(tool_of_seg, dtype=np.int64)
        self.levels = {t: tools[t].body() for t in np.unique(self.tool_of_seg).tolist() if t in tools}
        self.flute_of_seg = np.full(len(self.tool_of_seg), np.inf)
        for t in self.levels:  # a mask a tool, not a lookup a move
            self.flute_of_seg[self.tool_of_seg == t] = tools[t].flute_length
        finite = part_flat[np.isfinite(part_flat)]
        self.part_max = float(finite.max()) if len(finite) else -np.inf
        self.part = part_flat
        self.engaged_width = engaged_width
        self.full_width = math.radians(FULL_WIDTH_ANGLE)  # [rad]
        # A shank as wide as the cutter rides a finished wall at exactly its radius: a
        # graze sideways within the contact tolerance is no contact.
        self.graze = graze
        # measure False: only the cut itself (see cut_stock's ``measure``); "chip": and the chip, no body.
        # _tops: pairs'.
        self.measure, self._tops = True, None

    def pairs(self, seg: Segments, s: int, e: int, grid: Grid, stock: np.ndarray, ceiling: float, tops=None):
        """(segment in batch, flat grid index, body envelope) for body parts below ``ceiling``, near stock or part."""
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
        lifted = Segments(seg.x[k], seg.y[k], seg.z[k] + h, seg.dx[k], seg.dy[k], seg.dz[k],
                          np.concatenate(radii), np.zeros(len(k)), seg.rapid[k], seg.move[k])
        # with the batch's ``tops``, no runs where the body stays over stock and part (bounds made once per tops)
        if tops is not None and (self._tops is None or self._tops[0] is not tops):
            self._tops = (tops, _SpanTops(np.maximum(stock, self.part), grid))
        owner, flat, col, row = grid_pairs(lifted, grid, None if tops is None else self._tops[1].above)
        bound = np.maximum(stock[flat], self.part[flat])
        env = pair_envelope(grid.x0 + col * grid.cell, grid.y0 + row * grid.cell, owner, lifted, bound)
        hit = np.flatnonzero(np.isfinite(env))
        return k[owner[hit]], flat[hit], env[hit]


class _Cut:
    """A program being cut into the stock model: its moves as swept, the stock, the part, what each move
    met, the batches (:func:`cut_stock`'s, and :func:`cadcam.cutahead.cut_ahead`'s)."""

    def __init__(self, moves: ProgramMoves, tools: Mapping[int, Tool], setup: Setup, part_triangles: np.ndarray,
                 cell: float, start: FlippedStock | Simulation | None, rapid_rim: float, engaged_width: float,
                 body_graze: float, full_width_angle: float, measure: bool | str, snap: np.ndarray,
                 skip: np.ndarray | None = None, part_top: np.ndarray | None = None):
        tri = _check_inputs(setup, cell, part_triangles)
        grid = grid_over(setup.stock_min, setup.stock_max, cell)
        if part_top is None:  # cutting on from earlier moves: the part was rasterised on this grid then
            part_top = (start.part_top if isinstance(start, Simulation) and start.grid == grid
                        else upper_envelope(tri, grid))
        if not np.isfinite(part_top).any():
            raise VerifyError("the part does not overlap the stock's footprint", source="part")
        stock, under, top_z, stock_bottom = _starting_stock(setup, grid, start)
        seg, starts, swept, known = _swept_moves(moves, tools, top_z, rapid_rim, skip)
        part_flat = np.where(np.isfinite(part_top), part_top, -np.inf).reshape(-1)
        body = _Body(tools, moves.tool[seg.move], part_flat, engaged_width, body_graze)
        body.full_width = math.radians(full_width_angle)
        body.measure = measure
        if measure is True:  # the skin of walls is no engagement: only engagement reads it
            body.wall_near = highest_near(part_top, grid.cell, _SKIN).reshape(-1)
        self.grid, self.part_top, self.part = grid, part_top, part_flat
        self.stock, self.under, self.stock_bottom = stock, under, stock_bottom
        self.seg, self.starts, self.swept, self.body, self.tools = seg, starts, swept, body, tools
        self.n_moves = int(known.sum())
        done = np.cumsum(known)  # simulated moves up to and including each move, for progress
        self.done = done[seg.move - 1] if len(seg) else done[:0]
        # Segments applied by each snapshot (seg.move is increasing).
        self.snapshot_at = np.searchsorted(seg.move, snap, side="right")
        self.bounds = _batch_bounds(seg, grid, self.snapshot_at)
        self.met = MoveRecord(len(seg), bottom=float(setup.stock_min[2]))
        # what the cut depends on besides its moves and tools (cadcam.cutahead.CutState.key)
        self.options = (grid, float(setup.stock_min[2]), rapid_rim, engaged_width, body_graze, full_width_angle,
                        measure)

def _batch_bounds(seg: Segments, grid: Grid, snapshot_at: np.ndarray) -> np.ndarray:
    """The segment indices the batches start at, and ``len(seg)`` last: from an estimate of each move's grid
    points (its stadium's area), and split at ``snapshot_at`` (cuts commute, so the final stock is the same).
    The batches of a program's first moves do not depend on the moves after them."""
    L = np.sqrt(seg.l2)
    est = (L + 2 * seg.radius + 2 * grid.cell) * (2 * seg.radius + 2 * grid.cell) / grid.cell**2
    cum = np.cumsum(est)
    bucket = ((cum - est) // _PAIR_BUDGET).astype(np.int64)
    bounds = np.concatenate([[0], np.flatnonzero(np.diff(bucket)) + 1, [len(seg)]]).astype(np.int64)
    return np.union1d(bounds, snapshot_at)


def _run(cut: _Cut, progress, bounds: np.ndarray, first: int = 0, tops: "_SpanTops | None" = None,
         last: int | None = None) -> list[np.ndarray]:
    """Apply batches ``first`` to ``last`` (default: to the end) of ``cut`` to its stock (in place), filling its
    records; return the snapshots (taken only when run from the first batch to the end). ``tops``: the stock
    bounds batch ``first`` uses unless it makes them afresh. ``done[k]`` of the cut is the progress count once
    segment ``k`` is applied; ``snapshot_at[i]`` a number of segments: a copy of the stock is taken once that
    many are applied (the batches are split there)."""
    seg, body, grid, stock, part, stats, under = cut.seg, cut.body, cut.grid, cut.stock, cut.part, cut.met, cut.under
    snapshot_at = cut.snapshot_at
    wanted = set(snapshot_at.tolist())
    taken = {0: stock.copy()} if 0 in wanted else {}  # segments applied -> stock then
    last = len(bounds) - 1 if last is None else last
    # each batch's pairs made in a second thread while the one before cuts (envelope.BatchPairs): the same cut
    coming = None  # (batch, its pairs being made)
    with (concurrent.futures.ThreadPoolExecutor(1) if processors() > 1 and last - first > 1
          else contextlib.nullcontext()) as ahead:
        for c in range(first, last):
            s, e = int(bounds[c]), int(bounds[c + 1])
            if e > s:
                if tops is None or c % _SPAN_TOPS_EVERY == 0:
                    tops = _SpanTops(stock, grid)  # the stock only falls: older tops stay upper bounds
                pairs, coming = coming[1].result() if coming is not None and coming[0] == c else None, None
                if ahead is not None and c + 1 < last and bounds[c + 2] > bounds[c + 1]:
                    # the stock read there as this batch cuts it: each value is one it held, so above what it
                    # will be when batch c + 1 cuts (it only falls)
                    coming = (c + 1, ahead.submit(BatchPairs.of, seg.sub(int(bounds[c + 1]), int(bounds[c + 2])),
                                                  grid, tops.above, grid_pairs, stock))
                _run_batch(seg, body, s, e, grid, stock, part, stats, under, tops, pairs)
                if progress is not None:
                    progress(int(cut.done[e - 1]), cut.n_moves)
            if e in wanted:
                taken[e] = stock.copy()
    cut.tops = tops
    if progress is not None and last == len(bounds) - 1:
        progress(cut.n_moves, cut.n_moves)
    return [taken[k] for k in snapshot_at.tolist()] if first == 0 and last == len(bounds) - 1 else []


def _run_batch(seg_all: Segments, body: "_Body", s: int, e: int, grid: Grid, stock: np.ndarray, part: np.ndarray,
               stats: MoveRecord, under: np.ndarray | None = None, tops: "_SpanTops | None" = None,
               pairs: BatchPairs | None = None) -> None:
    """Cut segments ``s:e`` into ``stock`` and record what each met.

    Each move is judged against the stock exactly as every earlier move left it (also the earlier moves of
    this batch): the pairs cut in turn, move by move (:func:`cadcam.toolsweep.cut_in_turn`; with shank and
    holder pairs, a running minimum over the pairs sorted by point and move, :func:`_cut_with_body`).
    ``under`` (flat, per grid point): the bottom of a stock whose columns do not all stand
    on one plane (a flipped part); a column cut down to it is empty (``-inf``) from then on.
    ``tops``: upper bounds of the stock on runs of grid columns (:class:`_SpanTops`, made from this
    stock or an earlier state of it): the runs of a move's grid points it provably cannot cut are
    not paired at all (:func:`cadcam.envelope.grid_pairs`), which changes nothing else. ``pairs``: the batch's
    pairs made already (from these or older ``tops``), else made here.
    """
    from cadcam import toolsweep  # numba loads with the first cut, not with every command importing this

    seg = seg_all.sub(s, e)
    pairs = pairs or BatchPairs.of(seg, grid, None if tops is None else tops.above, grid_pairs, stock)
    owner, flat, col, row = pairs.owner, pairs.flat, pairs.col, pairs.row
    env = pairs.envelope(seg, stock[flat])
    # Shank and holder: the same sweep with the body's cylinders, only where they can
    # come below the highest stock or part there is (the tops' highest: older, so no lower; a body part
    # under it but over the stock comes nowhere below the stock or part, so it meets nothing all the same).
    b_flat = ()
    if body.measure is True:
        highest = float(stock.max()) if tops is None else tops.highest()
        b_owner, b_flat, b_env = body.pairs(seg, s, e, grid, stock, max(highest, body.part_max), tops)
    if not len(b_flat):  # the cutter's pairs alone, move by move: each cuts what the ones before it left
        cut, before = toolsweep.cut_in_turn(flat, env, stock, stock if under is None else under, under is not None)
    else:
        cut, before = _cut_with_body(seg, body, s, e, grid, stock, part, stats, under, (owner, flat, env),
                                     (b_owner, b_flat, b_env))
    if len(cut):
        o, f, env = owner[cut], flat[cut], env[cut]
        qx, qy = grid.x0 + col[cut] * grid.cell, grid.y0 + row[cut] * grid.cell
        if body.measure == "chip":  # the chip feeds read the chip and the stock, not what was removed
            side_chip(seg, o, s, qx, qy, before, env, grid.cell, stats)
        else:  # what the cut took off, counted down to the stock's bottom (a through cut goes on into air)
            record_max(stats.removed_max, stats.removed_cell, o + s, before - env, f, extra=(stats.removed_env, env))
            floor = stats.bottom if under is None else under[f]
            np.add.at(stats.volume, o + s, np.maximum(before - np.maximum(env, floor), 0.0) * grid.cell**2)
        # A wall's skin is no engagement (see _SKIN); it is still cut, and still counts for rapids and the width.
        # Only beside a wall: floor allowance (the part right below) is engagement as usual.
        if body.measure is True:
            skin = (body.wall_near[f] >= before - _SKIN) & (part[f] < before - _SKIN)
            engaged_depth(seg, o, s, qx, qy, before, env, f, grid.cell, body.engaged_width, stats, skin,
                          body.full_width)
        if under is not None:
            through = f[~(stock[f] > under[f])]
            stock[through] = -np.inf


def _cut_with_body(seg: Segments, body: "_Body", s: int, e: int, grid: Grid, stock: np.ndarray, part: np.ndarray,
                   stats: MoveRecord, under: np.ndarray | None, cutter: tuple, shank: tuple) -> tuple:
    """:func:`cadcam.toolsweep.cut_in_turn`'s ``cut, before`` (the stock lowered) of the cutter's pairs ``cutter``
    with the shank's and holder's ``shank`` (owner, flat, envelope each) between them, whose contacts it records."""
    from cadcam import toolsweep

    (owner, flat, env), (b_owner, b_flat, b_env) = cutter, shank
    touch = np.flatnonzero(env < stock[flat])
    owner, flat, env = owner[touch], flat[touch], env[touch]
    n_c = len(flat)
    cells = np.concatenate([flat, b_flat])
    # At a grid point, every earlier move's cut counts, and for this move's own
    # shank, not its own cutter (which takes that material off no higher than its flutes).
    value = np.concatenate([env, np.full(len(b_flat), np.inf)])
    # Distinct keys (move, point, kind): any sort's order; stable takes the pairs' sorted runs whole (8x quicksort).
    order = np.argsort(cells * (2 * (e - s) + 2) + np.concatenate([owner * 2 + 1, b_owner * 2]), kind="stable")
    earlier = np.empty(len(cells))
    earlier[order] = toolsweep.segmented_exclusive_min(cells[order], value[order])
    found = np.minimum(stock[cells], earlier)
    if under is not None:  # a column cut through by an earlier move holds nothing
        found[~(found > under[cells])] = -np.inf
    # This move's own flutes take off what they reach first (the tool descends or
    # moves on into it), up to the flute length above the highest tip position
    # from which they reach the point; material above that meets the body.
    qx = grid.x0 + (b_flat % grid.nx) * grid.cell
    qy = grid.y0 + (b_flat // grid.nx) * grid.cell
    ta, tb, _ = reach_interval(seg, b_owner, qx, qy)
    z0, dz = seg.z[b_owner], seg.dz[b_owner]
    flute_top = np.where(ta <= tb, np.maximum(z0 + dz * ta, z0 + dz * tb) + body.flute_of_seg[b_owner + s], -np.inf)
    standing = found[n_c:]
    standing = np.where(standing > flute_top, standing, -np.inf)
    met = np.maximum(standing, part[b_flat]) - b_env
    hit = np.flatnonzero(met > 0.0)
    if len(hit):
        record_max(stats.contact, stats.contact_cell, b_owner[hit] + s, met[hit], b_flat[hit],
                   extra=(stats.contact_z, b_env[hit]))
    before = found[:n_c]
    cut = np.flatnonzero(before - env > 0.0)
    np.minimum.at(stock, flat[cut], env[cut])
    return touch[cut], before[cut]


#: Batches between fresh :class:`_SpanTops` (the stock only falls, so older ones are upper bounds, only looser).
_SPAN_TOPS_EVERY = 16


def first_line_reaching(moves: ProgramMoves, tools: Mapping[int, Tool], x: float, y: float, z: float) -> int | None:
    """Source line of the first move whose tool reaches down to ``z`` at ``(x, y)`` [mm]; None if no move does."""
    a, b = moves.points[:-1], moves.points[1:]
    known = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    radius, rc, cone = _tool_table(moves, tools, known)
    sel = np.flatnonzero(known & np.isfinite(radius))
    seg = Segments.between(a[sel], b[sel], radius[sel], rc[sel], cone=cone[sel])
    k = len(sel)
    env = pair_envelope(np.full(k, x), np.full(k, y), np.arange(k), seg)
    hit = np.flatnonzero(env <= z + 1e-9)
    return int(moves.line[sel[hit[0]] + 1]) if len(hit) else None


def operation_moves(operations: Sequence[Operation]) -> ProgramMoves:
    """The moves of operations as a controller would run them, without posting G-code.

    PLUNGE moves become feed moves (the simulation does not tell feeds apart); each
    operation's first point is reached by a rapid from the previous one's last.
    """
    points = np.concatenate([op.points for op in operations])
    motion = np.concatenate([op.motion for op in operations]).astype(np.int8)
    motion[motion == Motion.PLUNGE] = Motion.CUT
    tool = np.concatenate([np.full(len(op.points), op.tool.number) for op in operations])
    # plunges at the cutting feed, as the planners' estimates have always counted them
    feed = np.concatenate([np.where(op.motion == Motion.PLUNGE, op.cutting.feed, op.move_feeds()) for op in operations])
    return ProgramMoves(points, motion, tool, feed, np.zeros(len(points), dtype=np.int32))


@dataclass(frozen=True)
class OperationsCut:
    """Operations cut into the stock model (:func:`stock_after`), kept so that the operations planned after
    them are cut into the stock they left instead of simulating them all again (``earlier`` of :func:`stock_after`).

    Attributes
    ----------
    operations : tuple of Operation
        The operations cut, in order.
    simulation : Simulation
        The stock they left (what :func:`stock_after` of them returned).
    """

    operations: tuple[Operation, ...]
    simulation: Simulation


def stock_after(operations: Sequence[Operation], setup: Setup, part_triangles: np.ndarray,
                cell: float = 0.5, earlier: OperationsCut | None = None) -> Simulation:
    """The stock left by ``operations``, on a grid of ``cell`` [mm], for planning later ones.

    ``earlier``: the stock the first of ``operations`` left, on this grid, of this setup and part: only
    the operations after them (and the rapid to the first of them) are cut, into that stock. The result
    is the same to the bit as cutting every operation (each grid point keeps its lowest cut)."""
    return _stock_after(operations, setup, part_triangles, cell, None, earlier)


def stock_after_flipped(operations: Sequence[Operation], setup: Setup, part_triangles: np.ndarray, start: FlippedStock,
                        cell: float, earlier: OperationsCut | None = None) -> Simulation:
    """:func:`stock_after` from ``start``, the stock an earlier setup left turned over (:func:`flip_stock`):
    op 2's stock for planning its later operations. ``cell`` [mm] must be the one ``start`` was made on;
    operations of a single point cut nothing and are left out. ``earlier``: as :func:`stock_after`'s,
    from the same ``start``."""
    cutting = [op for op in operations if len(op.points) > 1]
    if not cutting:
        grid = start.grid
        present = np.isfinite(start.top)
        lowest = float(start.bottom[present].min()) if present.any() else float(setup.stock_min[2])
        return Simulation(grid=grid, stock_top=start.top, part_top=upper_envelope(part_triangles, grid),
                          stock_bottom=lowest, stock_under=start.bottom)
    if earlier is not None:  # the operations it cut, as this list holds them
        earlier = OperationsCut(tuple(op for op in earlier.operations if len(op.points) > 1), earlier.simulation)
    return _stock_after(cutting, setup, part_triangles, cell, start, earlier)


def _stock_after(operations: Sequence[Operation], setup: Setup, part_triangles: np.ndarray, cell: float,
                 start: FlippedStock | None, earlier: OperationsCut | None) -> Simulation:
    """:func:`stock_after` (from ``start`` when given): cut on from ``earlier`` when it holds the first of
    ``operations`` (the same objects, with the same tools) on this grid, else every operation from the start."""
    tools = {op.tool.number: op.tool for op in operations}
    moves = operation_moves(operations)
    done = () if earlier is None else earlier.operations
    first = sum(len(op.points) for op in done)  # points of the operations already cut
    if (earlier is None or first == 0 or len(done) > len(operations) or earlier.simulation.grid.cell != cell
            or any(a is not b or tools[a.tool.number] is not a.tool for a, b in zip(done, operations))):
        # Only the stock is kept: the engagement and body contacts cut_stock would measure are not.
        return cut_stock(moves, tools, setup, part_triangles, cell, start=start, measure=False).simulation
    if len(done) == len(operations):
        return earlier.simulation
    # The moves from the last point already cut: the rapid to the next operation is the first one cut.
    rest = ProgramMoves(moves.points[first - 1:], moves.motion[first - 1:], moves.tool[first - 1:],
                        moves.feed[first - 1:], moves.line[first - 1:])
    sim = cut_stock(rest, tools, setup, part_triangles, cell, start=earlier.simulation, measure=False).simulation
    before = earlier.simulation.removed_volume
    if before is None:
        return dataclasses.replace(sim, removed_volume=None)
    volume = np.concatenate([before, sim.removed_volume[1:]])
    volume.setflags(write=False)
    return dataclasses.replace(sim, removed_volume=volume)


def clear_height(sim: Simulation, tool: Tool, xy: np.ndarray, within: float | None = None) -> np.ndarray:
    """Lowest tool tip height at each ``xy`` that touches none of the stock in ``sim`` [mm].

    Conservative between grid points: the stock is taken as reaching up to a grid point's
    height anywhere within a cell diagonal of it.

    Parameters
    ----------
    sim : Simulation
    tool : Tool
    xy : (n, 2) float
        Tool axis positions [mm].
    within : float, optional
        Only the tool's surface this close to its axis must clear the stock [mm] (its core:
        the rim beyond may cut); default the whole tool.

    Returns
    -------
    (n,) float
        ``-inf`` where no stock lies under the tool.
    """
    g = sim.grid
    slack = g.cell * math.sqrt(2.0)
    reach = (tool.radius if within is None else min(within, tool.radius)) + slack
    k = int(math.ceil(reach / g.cell))
    di, dj = np.meshgrid(np.arange(-k, k + 1), np.arange(-k, k + 1))
    # An axis lies within half a cell diagonal of the grid point it rounds to, so a point further
    # than that beyond the reach from it is never near (it would only add -inf to the maximum).
    can = np.hypot(di, dj) * g.cell <= reach + g.cell
    di, dj = di[can], dj[can]
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    i0 = np.rint((xy[:, 0] - g.x0) / g.cell).astype(np.int64)
    j0 = np.rint((xy[:, 1] - g.y0) / g.cell).astype(np.int64)
    out = np.full(len(xy), -np.inf)
    # Compiled, one axis at a time over the same offsets with the same numbers as the numpy pairs it replaces
    # (cadcam.clearheight); imported here, as numba is only where a process needs it.
    from cadcam.clearheight import clear_heights

    clear_heights(np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]), i0, j0,
                  np.ascontiguousarray(di, dtype=np.int64), np.ascontiguousarray(dj, dtype=np.int64),
                  np.ascontiguousarray(sim.stock_top, dtype=np.float64), float(g.x0), float(g.y0), float(g.cell),
                  float(slack), float(reach), float(tool.radius), float(tool.corner_radius),
                  float(tool.point_slope), out)
    return out


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


# What is left: the stock above the part grown sideways by an allowance plus a cell diagonal, so the
# skin a finished wall leaves in the cells beside it (the grid cannot tell it from stock) is not counted.
# Where there is no part (through holes, outside it) the floor (Setup.floor_z) is the part: the holding
# allowance under it stays for the vise.


def excess(sim: Simulation, allowance: float, grid_slack: bool = True) -> np.ndarray:
    """(ny, nx) float: stock above the part grown by ``allowance`` + a cell diagonal [mm] (see above).

    ``grid_slack=False`` grows the part by ``allowance`` only: right for stock a tool has
    finished against the walls (its side reached them), where a cell beside a wall holds
    only what the tool's corner could not reach.
    """
    g = sim.grid
    reach = allowance + (g.cell * math.sqrt(2.0) if grid_slack else 0.0)
    k = int(math.ceil(reach / g.cell))
    di, dj = np.meshgrid(np.arange(-k, k + 1), np.arange(-k, k + 1))
    disc = np.hypot(di, dj) * g.cell <= reach
    part = np.where(np.isfinite(sim.part_top), sim.part_top, -np.inf)
    grown = ndimage.maximum_filter(part, footprint=disc, mode="constant", cval=-np.inf)
    return sim.stock_top - np.maximum(grown, sim.floor)


@dataclass(frozen=True)
class Unreached:
    """Stock no operation could remove and finishing leaves alone.

    Attributes
    ----------
    x, y : float
        Centre of the region's bounding box [mm], work coordinates.
    size_x, size_y : float
        Bounding box size [mm].
    depth : float
        Most stock left above the part there [mm].
    z_bottom : float
        Lowest part surface (or stock bottom) under it [mm].
    why : str
        Why it is left (:func:`why_left`): :data:`SHARP_CORNER`, :data:`NO_TOOL`, :data:`FOR_OP2`, a
        relief's :data:`OUTSIDE_RELIEF` or :data:`AT_BOUNDARY`; ``""``: not judged.
    band : float or None
        Stock along a relief's boundary (:data:`AT_BOUNDARY`): how far in from it it reaches [mm]; else None.
    """

    x: float
    y: float
    size_x: float
    size_y: float
    depth: float
    z_bottom: float
    why: str = ""
    band: float | None = None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {k: round(v, 2) for k, v in dataclasses.asdict(self).items()
                               if k != "why" and v is not None}
        if self.why:
            out["why"] = self.why
        return out

    def describe(self) -> str:
        where = f"{self.size_x:.1f} x {self.size_y:.1f} mm near X{self.x:.1f} Y{self.y:.1f}"
        if self.band is not None:  # a ring round the surface has the surface's box: how far in it is says where
            where += f" up to {self.band:.1f} mm in from the boundary"
        return (f"{where}, {self.depth:.1f} mm of stock down to Z{self.z_bottom:.1f}"
                + (f": {self.why}" if self.why else ""))


#: Why a region of stock is left (:attr:`Unreached.why`): it fits in the corner the narrowest end mill's
#: radius leaves; no tool of the program reaches it (too narrow or too deep); it goes down through the
#: part to op 1's floor, where op 2 machines it from below.
SHARP_CORNER = "sharp inside corner"
NO_TOOL = "no tool reaches"
FOR_OP2 = "left for op 2"
#: ... and a relief's: outside its own surface, the uncut rim; on the surface along the boundary, which keeps
#: the roughing tool's radius off its corners and every later tool a clearance off the rim's wall.
OUTSIDE_RELIEF = "outside the relief's surface"
AT_BOUNDARY = "at the relief's boundary, which keeps the tools off"


def why_left(left: tuple[Unreached, ...], sim: Simulation, above: float, radius: float,
             op2_follows: bool = False) -> tuple[Unreached, ...]:
    """``left`` (:func:`unreached` of ``sim`` over ``above`` [mm]) with each region's reason.

    A region whose bottom is op 1's floor (no part face under it: a slot or hole through the part) is
    left for op 2 when ``op2_follows``. One no wider than ``radius`` [mm] (the widest end mill that
    cut, and a grid cell each side) that fills less than :data:`_CORNER_FILL` of its box is the
    curved triangle a round tool leaves in a sharper inside corner (it fills ``1 - pi/4`` of it).
    Anything else no tool reached: too narrow or too deep for every tool. A region that has its reason
    already (a relief's uncut rim, :func:`unreached` with ``outside``) keeps it.
    """
    g = sim.grid
    deep = excess(sim, 0.0) > above
    out = []
    for u in left:
        i0, i1 = (int(round((c - g.x0) / g.cell)) for c in (u.x - u.size_x / 2 + g.cell / 2, u.x + u.size_x / 2))
        j0, j1 = (int(round((c - g.y0) / g.cell)) for c in (u.y - u.size_y / 2 + g.cell / 2, u.y + u.size_y / 2))
        box = np.s_[max(j0, 0):j1, max(i0, 0):i1]
        if u.why:
            why = u.why
        elif op2_follows and u.z_bottom <= sim.floor + g.cell:
            why = FOR_OP2
        else:
            fill = float(deep[box].mean()) if j1 > j0 and i1 > i0 else 1.0
            small = max(u.size_x, u.size_y) <= radius + 2 * g.cell
            why = SHARP_CORNER if small and fill < _CORNER_FILL else NO_TOOL
        out.append(dataclasses.replace(u, why=why))
    return tuple(out)


#: A region filling less of its box than this is a corner's curved triangle, not a pocket (a round or
#: square pocket fills 0.79 to 1 of it).
_CORNER_FILL = 0.6


def unreached(sim: Simulation, above: float, allowance: float, outside: np.ndarray | None = None,
              band: float = 0.0) -> tuple[Unreached, ...]:
    """Connected regions where more than ``above`` [mm] of stock is left over the part.

    ``outside``: (ny, nx) bool, a relief's grid points off its own surface. The uncut rim there
    (:data:`OUTSIDE_RELIEF`), the surface within ``band`` [mm] of it (:data:`AT_BOUNDARY`) and the rest are
    labelled apart: joined, the relief sample's rim, corners and pockets read "124 x 84 mm near X62 Y42, 9.9 mm".
    """
    ex = excess(sim, allowance)
    deep = ex > above
    if outside is None:
        return _regions(sim, ex, deep, "")
    inward = ndimage.distance_transform_edt(~outside) * sim.grid.cell  # from the boundary into the surface [mm]
    near = ~outside & (inward <= band)
    rim = _regions(sim, ex, deep & outside, OUTSIDE_RELIEF)
    edge = _regions(sim, ex, deep & near, AT_BOUNDARY, inward)
    rest = _regions(sim, ex, deep & ~outside & ~near, "")
    return tuple(sorted(rim + edge + rest, key=lambda u: (-u.depth, u.x, u.y)))


def _regions(sim: Simulation, ex: np.ndarray, deep: np.ndarray, why: str,
             band: np.ndarray | None = None) -> tuple[Unreached, ...]:
    """The regions of ``deep`` ((ny, nx) bool) named ``why`` (``ex``: :func:`excess` [mm]; ``band``: (ny, nx)
    float [mm], its largest value over each region is :attr:`Unreached.band`)."""
    labels, _ = ndimage.label(deep, structure=np.ones((3, 3), dtype=bool))
    g = sim.grid
    floor = np.maximum(np.where(np.isfinite(sim.part_top), sim.part_top, -np.inf), sim.floor)
    out = []
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        m = labels[sl] == k
        js, is_ = sl
        x0, x1 = g.x0 + (is_.start - 0.5) * g.cell, g.x0 + (is_.stop - 0.5) * g.cell
        y0, y1 = g.y0 + (js.start - 0.5) * g.cell, g.y0 + (js.stop - 0.5) * g.cell
        out.append(Unreached(
            x=0.5 * (x0 + x1), y=0.5 * (y0 + y1), size_x=x1 - x0, size_y=y1 - y0,
            depth=float(ex[sl][m].max()), z_bottom=float(floor[sl][m].min()), why=why,
            band=None if band is None else float(band[sl][m].max()),
        ))
    return tuple(sorted(out, key=lambda u: (-u.depth, u.x, u.y)))
