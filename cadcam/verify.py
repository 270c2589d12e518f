"""The verdict behind ``factory verify``: a program cut into the stock model, held against the part and the tools.

The program is cut into the stock model (:func:`cadcam.stock.cut_stock`), exact at the grid
points, which also measures what each move met. The verdict reads that: a gouge is the stock
left below the part beyond the tolerance, measured from the lowest part top within the
tolerance sideways, so a wall nicked within the tolerance does not read as a cut of the wall's
height; a rapid that reaches into the stock is a crash; shank or holder in the stock or the
part, a cut deeper than the flutes, a buried finishing tool, a drill fed sideways, a tip below
the stock bottom and a tool in the vise's jaws are faults (:data:`FAULT_KINDS`).
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cadcam.envelope import Segments
from cadcam.heightmap import Grid, upper_envelope
from cadcam.model import Motion, ProgramMoves, Setup, Tool
from cadcam.stock import (ENGAGED_WIDTH, RAPID_RIM, FlippedStock, MoveRecord, Simulation, Unreached, cut_stock,
                          first_line_reaching, unreached, why_left)
from cadcam.workholding import fixture_contacts
from factory.core.errors import VerifyError


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
        walls left out, as :mod:`cadcam.stock` measures it).
    engaged_width : float
        A cut counts as engagement only where it is at least this wide across the move
        [mm] (as :mod:`cadcam.stock` measures it): a thinner band is a skin shaved off a wall.
    contact_tolerance : float
        Shank or holder reaching this far into the stock or the part, or a tool tip this
        far below the stock bottom, is a fault [mm].
    left_above : float
        Stock more than this above the part is *left*, listed by region (:attr:`VerifyReport.left`)
        [mm]; beside a wall the part counts grown by a cell diagonal, so the cells a finished wall
        passes through are not taken for stock (:func:`cadcam.stock.excess`). Stock under op 1's
        floor (the holding allowance) is never left: it is op 2's.
    op2_follows : bool
        Op 2 machines the part from below after this program: stock left down to the floor is
        left for it (:func:`cadcam.stock.why_left`).
    """

    cell: float = 0.2
    gouge_tolerance: float = 0.01
    rapid_tolerance: float = RAPID_RIM
    finish_depth: float = 1.0
    engaged_width: float = ENGAGED_WIDTH
    contact_tolerance: float = 0.01
    left_above: float = 0.1
    op2_follows: bool = False


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
        Deepest engagement of any move (:class:`cadcam.stock.MoveRecord`).
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
    left : tuple of Unreached
        The regions where more than ``left_above`` [mm] of stock stays on the part after the
        program, deepest first: a sharp inside corner, what no tool reached, what the program
        skipped. Empty: the part is finished to ``left_above``.
    left_above : float
        [mm], see :class:`VerifyOptions`.
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
    left: tuple[Unreached, ...] = ()
    left_above: float = 0.1

    @property
    def gouged(self) -> bool:
        """True if the program cuts deeper into the part than the gouge tolerance."""
        return self.max_gouge > self.gouge_tolerance

    @property
    def ok(self) -> bool:
        """No gouge beyond tolerance, no rapid into the stock and no other :class:`Fault`."""
        return not self.gouged and not self.rapid_crashes and not self.faults

    @property
    def finished(self) -> bool:
        """No stock left above the part beyond ``left_above`` (the program may still be unsafe: :attr:`ok`)."""
        return not self.left

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
            "finished": self.finished,
            "left_above": self.left_above,
            "left": [u.to_dict() for u in self.left],
        }


@dataclass(frozen=True)
class VerifyResult:
    """A program verified (:func:`simulate`): ``simulation``, the stock model it leaves (as
    :attr:`cadcam.stock.StockCut.simulation`), and ``report``, the verdict on it (a :class:`VerifyReport`)."""

    simulation: Simulation
    report: VerifyReport


def simulate(
    moves: ProgramMoves,
    tools: Mapping[int, Tool],
    setup: Setup,
    part_triangles: np.ndarray,
    options: VerifyOptions = VerifyOptions(),
    progress: Callable[[int, int], None] | None = None,
    finishing: np.ndarray | None = None,
) -> VerifyResult:
    """Cut the stock with every move of a program and compare the result with the part.

    Parameters
    ----------
    moves, tools, setup, part_triangles, progress
        As :func:`cadcam.stock.cut_stock` takes them (the program, its tools by number, the
        stock box and the part in work coordinates [mm], ``progress(done, total)`` in moves).
    options : VerifyOptions
    finishing : (n,) bool, optional
        True for moves (indexed like ``moves.points``) a finishing operation makes, held
        to :attr:`VerifyOptions.finish_depth` (see :func:`finishing_moves`); default none.

    Returns
    -------
    VerifyResult
        The stock the program leaves and the verdict.

    Raises
    ------
    VerifyError
        If a feed move runs with no tool, or any move with a tool not in ``tools``
        (``source`` names the G-code line, ``data["line"]`` holds it); if the part, stock
        or options are unusable.
    """
    return _verify(moves, tools, setup, part_triangles, options, progress, finishing, None)


def simulate_flipped(
    moves: ProgramMoves,
    tools: Mapping[int, Tool],
    setup: Setup,
    part_triangles: np.ndarray,
    start: FlippedStock,
    options: VerifyOptions = VerifyOptions(),
    progress: Callable[[int, int], None] | None = None,
    finishing: np.ndarray | None = None,
) -> VerifyResult:
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
    return _verify(moves, tools, setup, part_triangles, options, progress, finishing, start)


def _verify(moves: ProgramMoves, tools: Mapping[int, Tool], setup: Setup, part_triangles: np.ndarray,
            options: VerifyOptions, progress: Callable[[int, int], None] | None, finishing: np.ndarray | None,
            start: FlippedStock | None) -> VerifyResult:
    """:func:`simulate` from the setup's stock box (``start`` None) or from a stock given per grid point."""
    _check_options(options)
    cut = cut_stock(moves, tools, setup, part_triangles, options.cell, start=start, progress=progress,
                    rapid_rim=options.rapid_tolerance, engaged_width=options.engaged_width,
                    body_graze=options.contact_tolerance)
    sim, seg = cut.simulation, cut.segments
    pts = moves.points
    finish = np.zeros(len(pts), bool) if finishing is None else np.asarray(finishing, bool).reshape(-1)
    if len(finish) != len(pts):
        raise VerifyError(f"finishing flags: expected {len(pts)}, got {len(finish)}", source="finishing")
    a, b = cut.starts, pts[1:]
    known = np.all(np.isfinite(b), axis=1)
    rapid = moves.motion[1:] == Motion.RAPID
    length = np.zeros(len(a))
    length[known] = np.linalg.norm(b[known] - a[known], axis=1)
    crashes, faults, engagement = _judge(seg, cut.met, moves, tools, finish, sim, options)
    if setup.jaws:
        faults += _jaw_faults(a, b, cut.swept, moves, tools, setup, options)
    report = _report(
        sim, np.asarray(part_triangles, dtype=np.float64), moves, tools, options, crashes, int(known.sum()),
        float(length[~rapid].sum()), float(length[rapid].sum()), faults, engagement, int(np.count_nonzero(seg.rapid)),
    )
    return VerifyResult(simulation=sim, report=report)


def _check_options(options: VerifyOptions) -> None:
    """VerifyError naming the first option that is not a usable number of mm."""
    for name in ("cell", "gouge_tolerance", "rapid_tolerance", "finish_depth", "engaged_width", "contact_tolerance"):
        v = getattr(options, name)
        positive = name in ("cell", "finish_depth")
        if not (math.isfinite(v) and (v > 0 if positive else v >= 0)):
            kind = "positive" if positive else "non-negative"
            raise VerifyError(f"{name} must be a {kind} number of mm, got {v}", source=name)


def _jaw_faults(a: np.ndarray, b: np.ndarray, use: np.ndarray, moves: ProgramMoves, tools: Mapping[int, Tool],
                setup: Setup, options: VerifyOptions) -> list[Fault]:
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


def _judge(seg: Segments, stats: MoveRecord, moves: ProgramMoves, tools: Mapping[int, Tool], finish: np.ndarray,
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
        gouge_line = first_line_reaching(moves, tools, x, y, z)
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
        left=why_left(unreached(sim, options.left_above, 0.0), sim, options.left_above, _widest_mill_radius(tools),
                      options.op2_follows),
        left_above=options.left_above,
    )


def _widest_mill_radius(tools: Mapping[int, Tool]) -> float:
    """Radius of the widest end mill in ``tools`` [mm]: the largest corner one leaves; 0 with none."""
    return max((t.radius for t in tools.values() if not t.is_drill), default=0.0)


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


#: The comment the post-processor writes at the start of each operation (cadcam.post):
#: ``(op 2: finish raster [raster] T3 6 mm ball 2FL carbide)``; in op 2's program ``(op 2.1: ...)``.
_OP_COMMENT = re.compile(r"\(\s*op\s+\d+(?:\.\d+)?\s*:.*\[([^\]]+)\]\s*T(\d+)\b", re.IGNORECASE)


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
