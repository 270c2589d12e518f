"""The verdict behind ``factory verify``: a program cut into the stock model, held against the part and the tools.

The program is cut into the stock model (:func:`cadcam.stock.cut_stock`), exact at the grid
points, which also measures what each move met. The verdict reads that: a gouge is the stock
left below the part beyond the tolerance, measured from the lowest part top within the
tolerance sideways, so a wall nicked within the tolerance does not read as a cut of the wall's
height; a rapid that reaches into the stock is a crash; shank or holder in the stock or the
part, a cut deeper than the flutes, a buried finishing tool, a drill fed sideways, a tip below
the stock bottom, a tool in the vise's jaws and a full-width cut deeper than the tool's axial limit
are faults (:data:`FAULT_KINDS`).

Engagement as a machinist reads it: per move, the radial engagement (the width of material across
the feed), the axial engagement and the engagement angle (the arc of the cutter meeting material),
and the deepest cut taken at full width (:class:`cadcam.engagement.MoveRecord`). Where the grid is
coarser than a tenth of a tool's diameter, that tool's moves are measured again on a finer grid
around them (:func:`_refined`), so a small end mill's corner engagement is seen.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage

from cadcam.corners import corners_left, inside_corners
from cadcam.engagement import ChipLoad, MoveRecord, chip_loads, move_chips
from cadcam.envelope import Segments
from cadcam.gouge import gouge_depths
from cadcam.heightmap import grid_over
from cadcam.model import Motion, ProgramMoves, Setup, Tool
from cadcam.relief import surface_footprint
from cadcam.cutahead import CutState, cut_ahead
from cadcam.stock import (ENGAGED_WIDTH, FOR_OP2, FULL_WIDTH_ANGLE, OUTSIDE_RELIEF, RAPID_RIM, FlippedStock,
                          Simulation, StockCut, Unreached, cut_stock, first_line_reaching, unreached, why_left)
from cadcam.workholding import fixture_contacts
from factory.core.errors import VerifyError

log = logging.getLogger(__name__)


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
    relief : bool
        The part is a relief's machining surface (:func:`cadcam.relief.machining_surface`): stock
        off its own surface is the uncut rim round it, named so in :attr:`VerifyReport.left`.
    full_width_angle : float
        A move whose cutter meets material over more than this arc cuts at full width [deg] (a
        slot is 180): held to the tool's axial limit (:attr:`cadcam.model.Tool.full_width_limit`).
    engagement_resolution : float or None
        Engagement is measured on a grid no coarser than this share of each tool's diameter:
        a tool narrower than ``cell / engagement_resolution`` has its moves cut again on a finer
        grid over their reach (the stock there from every move of the program). None: on ``cell``
        (for a caller that reads only rapids and contacts).
    chip_tolerance : float
        A move's chip may be this share thicker than the tool's feed per tooth before it is a ``chip``
        fault (:class:`cadcam.engagement.ChipLoad`). The chip is read from where the stock met the cutter, to half a grid
        cell (:func:`cadcam.engagement.engaged_depth`): a wall's 0.3 mm skin on a 0.2 mm grid reads
        0.2-0.4 mm wide, its chip 0.85-1.15 times the true one on a 10 mm end mill: 0.15.
    """

    cell: float = 0.2
    gouge_tolerance: float = 0.01
    rapid_tolerance: float = RAPID_RIM
    finish_depth: float = 1.0
    engaged_width: float = ENGAGED_WIDTH
    contact_tolerance: float = 0.01
    left_above: float = 0.1
    op2_follows: bool = False
    relief: bool = False
    full_width_angle: float = FULL_WIDTH_ANGLE
    engagement_resolution: float | None = 0.1
    chip_tolerance: float = 0.15


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
FAULT_KINDS = ("no_cut", "rapid", "holder", "flute", "full_width", "radial", "chip", "buried", "drill_side",
               "below_stock", "seam", "jaws")

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
        ``full_width`` a cut at full width (:attr:`VerifyOptions.full_width_angle`) deeper than
        the tool's axial limit (:attr:`cadcam.model.Tool.full_width_limit`); ``radial`` a side cut
        (not at full width) deeper than that limit and radially wider than the tool's radial limit
        (:attr:`cadcam.model.Tool.deep_radial_limit`, the library's ``radial_limit``); ``chip`` a move's
        chip (:attr:`ToolEngagement.max_chip`) thicker than the tool's feed per tooth by more than
        :attr:`VerifyOptions.chip_tolerance` (:class:`cadcam.engagement.ChipLoad`); ``buried`` a
        finishing tool engaged deeper than :attr:`VerifyOptions.finish_depth`;
        ``drill_side`` a drill fed sideways through stock (a drill's only engagement is
        axial, held to its flute length by ``flute``); ``below_stock`` the tool tip below the stock
        bottom; ``seam`` op 2's walls meet op 1's with a step over the finishing tolerance (op 2 after
        a depth split, :meth:`cadcam.seam.Seam.fault`); ``jaws`` the tool, shank or holder reaches into the vise's jaws or parallels
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


#: Bins of the engagement angle [deg] that :class:`ToolEngagement` counts moves in (the last holds 180).
ANGLE_BINS = (0.0, 30.0, 60.0, 90.0, 120.0, 150.0, 180.0)


@dataclass(frozen=True)
class Spread:
    """How a quantity is distributed over a tool's engaged moves: percentiles and the maximum."""

    p50: float
    p90: float
    p99: float
    max: float

    @classmethod
    def of(cls, values: np.ndarray) -> "Spread":
        """The spread of ``values`` (all zero when there are none)."""
        if len(values) == 0:
            return cls(0.0, 0.0, 0.0, 0.0)
        p = np.percentile(values, (50, 90, 99))
        return cls(float(p[0]), float(p[1]), float(p[2]), float(np.max(values)))

    def to_dict(self) -> dict[str, float]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class ToolEngagement:
    """How hard one tool worked, over its moves (lengths [mm], angles [deg]).

    Attributes
    ----------
    tool : int
    finishing : bool
        Its moves were held to the finishing limit.
    moves : int
        Its moves that came below the stock top.
    max_depth : float
        Deepest engagement of any move (:class:`cadcam.engagement.MoveRecord`; the skin of walls left out).
    max_depth_line : int
        Program line of that move (0 if it never engaged).
    max_width : float
        Widest radial engagement of any move.
    max_full_depth : float
        Deepest axial cut at full width (``MoveRecord.full_depth``: a slot, an inside corner).
    max_full_depth_line : int
        Program line of that move (0 if it never cut at full width).
    axial_limit : float
        What that was held to (:attr:`cadcam.model.Tool.full_width_limit`).
    cell : float
        Grid the tool's engagement was measured on [mm] (finer than the verify grid for small tools).
    engaged : int
        Its feed moves that took material off.
    depth, width, angle : Spread
        Axial engagement, radial engagement and engagement angle over those moves.
    angle_moves : tuple of int
        How many of them engaged an arc in each bin of :data:`ANGLE_BINS`.
    max_chip : float
        Thickest chip of any feed move [mm]: its feed per tooth (programmed feed over the spindle speed and
        the flutes) times the sine of its engagement angle, 1 past 90 deg (``MoveRecord.chip``); 0 where the
        tool's :class:`ChipLoad` is unknown.
    max_chip_line : int
        Program line of that move (0 if none).
    chip_load : float
        What that was held to, the library's feed per tooth [mm] (0: not judged).
    """

    tool: int
    finishing: bool
    moves: int
    max_depth: float
    max_depth_line: int
    max_width: float
    max_full_depth: float = 0.0
    max_full_depth_line: int = 0
    axial_limit: float = math.inf
    cell: float = 0.0
    engaged: int = 0
    depth: Spread = Spread(0.0, 0.0, 0.0, 0.0)
    width: Spread = Spread(0.0, 0.0, 0.0, 0.0)
    angle: Spread = Spread(0.0, 0.0, 0.0, 0.0)
    angle_moves: tuple[int, ...] = ()
    max_chip: float = 0.0
    max_chip_line: int = 0
    chip_load: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["angle_moves"] = list(self.angle_moves)
        d["angle_bins"] = list(ANGLE_BINS)
        return d

    def describe(self, engaged_width: float = ENGAGED_WIDTH, full_width_angle: float = FULL_WIDTH_ANGLE) -> str:
        """One line for people.

        The two depths are measured on different moves and need not be in order: "deepest" counts a cut
        only where it is at least ``engaged_width`` [mm] wide across the move (a wall's skin is not a cut),
        "at full width" any cut that meets the cutter over more than ``full_width_angle`` [deg], however
        narrow (a small end mill in a corner's sliver). The line names each one's move."""
        bins = ", ".join(f"{a:g}-{b:g}: {n}" for a, b, n in zip(ANGLE_BINS, ANGLE_BINS[1:], self.angle_moves))
        return (f"T{self.tool}: deepest {self.max_depth:.2f} mm where {engaged_width:g} mm wide or more"
                f"{_on_line(self.max_depth_line)}; at full width (over {full_width_angle:g} deg of the cutter) "
                f"up to {self.max_full_depth:.2f} mm{_on_line(self.max_full_depth_line)}, limit {self.axial_limit:g} mm; "
                f"widest {self.max_width:.2f} mm, angle p50/p90/max "
                f"{self.angle.p50:.0f}/{self.angle.p90:.0f}/{self.angle.max:.0f} deg over {self.engaged} moves "
                f"(deg: {bins}), grid {self.cell:g} mm{self._chip()}")

    def _chip(self) -> str:
        """``; chip up to ... against fz ...`` where the chip was judged, nothing where not."""
        if self.chip_load <= 0:
            return ""
        return (f"; chip up to {self.max_chip:.4f} mm{_on_line(self.max_chip_line)}, fz {self.chip_load:g} mm "
                f"({self.max_chip / self.chip_load:.0%})")


def _on_line(line: int) -> str:
    """`` (line N)`` for a program line, nothing for 0 (no such move)."""
    return f" (line {line})" if line > 0 else ""


@dataclass(frozen=True)
class VerifyReport:
    """What the simulation found.

    Attributes
    ----------
    max_gouge : float
        Deepest cut into the part over the grid points [mm], 0 if the part is untouched.
        A cut deeper than ``gouge_tolerance`` is measured from the lowest part top within
        ``gouge_tolerance`` sideways of the point, so a vertical wall nicked by less than
        the tolerance is no gouge of the wall's height (see :func:`cadcam.gouge.gouge_depths`).
    gouge_position : tuple of 3 float or None
        X, Y of that grid point and the stock top Z there [mm]; None without a gouge.
    gouge_line : int or None
        Source line of the first move that cut that deep there; None without a gouge.
    remaining_max, remaining_mean, remaining_p95 : float
        Stock left above the part over the grid points the part covers [mm] (max, mean,
        95th percentile; a gouge counts as negative), each point measured against the highest part
        top among it and its eight neighbours: a point a micrometre outside a facetted wall, which the
        finished wall passes beside, would otherwise count the wall's whole height as stock left. On a
        relief, over its own surface: not the uncut rim round it.
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
    def on_part(self) -> tuple[Unreached, ...]:
        """:attr:`left` on the part when this program is done: without a relief's uncut rim round its surface,
        which its boundary keeps the tools off by design (:data:`cadcam.stock.OUTSIDE_RELIEF`), nor what op 2
        machines from below (:data:`cadcam.stock.FOR_OP2`): that is op 2's to finish, and op 2's verdict says
        whether it did."""
        return tuple(u for u in self.left if u.why not in (OUTSIDE_RELIEF, FOR_OP2))

    @property
    def finished(self) -> bool:
        """No stock left on the part beyond ``left_above`` (the program may still be unsafe: :attr:`ok`)."""
        return not self.on_part

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
    resume: CutState | None = None,
    chips: Mapping[int, ChipLoad] | None = None,
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
    resume : CutState, optional
        The program's first moves cut already (:func:`verify_ahead`): the cut goes on from there where they
        are this program's (:func:`cadcam.stock.cut_stock`'s ``resume``); the result is the same.
    chips : mapping of int to ChipLoad, optional
        By tool number, what each tool's chip is held to (:func:`chip_loads` reads it from a setup sheet);
        the tools not in it are not judged on their chip.

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
    return _verify(moves, tools, setup, part_triangles, options, progress, finishing, None, resume, chips)


def verify_ahead(moves: ProgramMoves, tools: Mapping[int, Tool], setup: Setup, part_triangles: np.ndarray,
                 options: VerifyOptions, before: int, resume: CutState | None = None) -> CutState | None:
    """The first moves of a program known so far, cut as :func:`simulate` cuts them, for it to resume from (its
    ``resume``): only the moves before ``moves.points[before]`` are taken to be the whole program's
    (:func:`cadcam.cutahead.cut_ahead`). ``resume``: an earlier such state of fewer moves. VerifyError as simulate."""
    _check_options(options)
    return cut_ahead(moves, tools, setup, part_triangles, options.cell, before=before, resume=resume,
                     **_cut_options(options))


def _cut_options(options: VerifyOptions) -> dict[str, float]:
    """:func:`cadcam.stock.cut_stock`'s options as verify cuts the program (one place for both cuts)."""
    return dict(rapid_rim=options.rapid_tolerance, engaged_width=options.engaged_width,
                body_graze=options.contact_tolerance, full_width_angle=options.full_width_angle)


def simulate_flipped(
    moves: ProgramMoves,
    tools: Mapping[int, Tool],
    setup: Setup,
    part_triangles: np.ndarray,
    start: FlippedStock,
    options: VerifyOptions = VerifyOptions(),
    progress: Callable[[int, int], None] | None = None,
    finishing: np.ndarray | None = None,
    chips: Mapping[int, ChipLoad] | None = None,
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
    return _verify(moves, tools, setup, part_triangles, options, progress, finishing, start, chips=chips)


def _verify(moves: ProgramMoves, tools: Mapping[int, Tool], setup: Setup, part_triangles: np.ndarray,
            options: VerifyOptions, progress: Callable[[int, int], None] | None, finishing: np.ndarray | None,
            start: FlippedStock | None, resume: CutState | None = None,
            chips: Mapping[int, ChipLoad] | None = None) -> VerifyResult:
    """:func:`simulate` from the setup's stock box (``start`` None) or from a stock given per grid point."""
    _check_options(options)
    cut = cut_stock(moves, tools, setup, part_triangles, options.cell, start=start, progress=progress,
                    resume=resume, **_cut_options(options))
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
    measured = _refined(_measured(cut), cut, moves, tools, setup, part_triangles, options, start)
    crashes, faults, engagement = _judge(seg, cut.met, measured, moves, tools, finish, sim, options, chips or {})
    if setup.jaws:
        faults += _jaw_faults(a, b, cut.swept, moves, tools, setup, options)
    report = _report(
        sim, np.asarray(part_triangles, dtype=np.float64), moves, tools, options, crashes, int(known.sum()),
        float(length[~rapid].sum()), float(length[rapid].sum()), faults, engagement, int(np.count_nonzero(seg.rapid)),
    )
    return VerifyResult(simulation=sim, report=report)


@dataclass(frozen=True)
class RapidCheck:
    """What :func:`rapid_check` found: ``simulation``, the stock the program leaves; ``rapid_crashes``,
    the rapids into it, in program order; ``jaw_faults``, one ``jaws`` :class:`Fault` per tool that
    reaches into the vise's jaws or parallels (as :func:`simulate` reports them both)."""

    simulation: Simulation
    rapid_crashes: tuple[RapidCrash, ...]
    jaw_faults: tuple[Fault, ...]


def rapid_check(moves: ProgramMoves, tools: Mapping[int, Tool], setup: Setup, part_triangles: np.ndarray,
                cell: float, rapid_tolerance: float = RAPID_RIM, contact_tolerance: float = 0.01) -> RapidCheck:
    """Only the rapids and the jaws of :func:`simulate`: the same stock, the same rapid crashes and
    ``jaws`` faults, without measuring engagement, shank and holder contacts, gouges or the stock
    left (the planner's check of its own rapids reads nothing else). ``cell``, the tolerances [mm]
    as :class:`VerifyOptions` holds them.

    Raises
    ------
    VerifyError
        As :func:`simulate`.
    """
    options = VerifyOptions(cell=cell, rapid_tolerance=rapid_tolerance, contact_tolerance=contact_tolerance,
                            engagement_resolution=None)
    _check_options(options)
    cut = cut_stock(moves, tools, setup, part_triangles, cell, rapid_rim=rapid_tolerance, body_graze=contact_tolerance,
                    measure=False)
    faults = _jaw_faults(cut.starts, moves.points[1:], cut.swept, moves, tools, setup, options) if setup.jaws else []
    return RapidCheck(simulation=cut.simulation, rapid_crashes=_crashes(cut.segments, cut.met, moves, cut.simulation,
                                                                        rapid_tolerance), jaw_faults=tuple(faults))


def _check_options(options: VerifyOptions) -> None:
    """VerifyError naming the first option that is not a usable number of mm."""
    for name in ("cell", "gouge_tolerance", "rapid_tolerance", "finish_depth", "engaged_width", "contact_tolerance",
                 "full_width_angle", "engagement_resolution"):
        v = getattr(options, name)
        if v is None and name == "engagement_resolution":
            continue
        positive = name in ("cell", "finish_depth", "full_width_angle", "engagement_resolution")
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


@dataclass(frozen=True)
class _Measured:
    """Engagement per swept segment (rows of :attr:`StockCut.segments`), on the grid each tool needs.

    ``angle`` [deg], ``width`` (radial), ``full_depth`` (axial at full width) [mm] and ``chip`` (share) as
    :class:`cadcam.engagement.MoveRecord` holds them; ``full_x, full_y`` where the full-width depth
    was reached [mm] (NaN if nowhere); ``cell`` the grid it was measured on [mm].
    """

    angle: np.ndarray
    width: np.ndarray
    full_depth: np.ndarray
    chip: np.ndarray
    full_x: np.ndarray
    full_y: np.ndarray
    cell: np.ndarray


def _measured(cut: StockCut) -> _Measured:
    """The engagement of every segment of ``cut`` as its own grid saw it."""
    g, met = cut.simulation.grid, cut.met
    jj, ii = np.divmod(met.full_cell, g.nx)
    nowhere = met.full_cell < 0
    return _Measured(angle=met.angle.copy(), width=met.width.copy(), full_depth=met.full_depth.copy(),
                     chip=met.chip.copy(),
                     full_x=np.where(nowhere, np.nan, g.x0 + ii * g.cell),
                     full_y=np.where(nowhere, np.nan, g.y0 + jj * g.cell), cell=np.full(len(met.angle), g.cell))


def _refined(measured: _Measured, cut: StockCut, moves: ProgramMoves, tools: Mapping[int, Tool], setup: Setup,
             part_triangles: np.ndarray, options: VerifyOptions, start: FlippedStock | None) -> _Measured:
    """``measured`` with the moves of each tool narrower than ``cell / engagement_resolution`` measured
    again on a grid of ``engagement_resolution`` times its diameter, laid over their reach.

    Every move of the program is cut into that finer grid (a grid point's stock depends on every move
    that reached it), so the small tool meets the stock exactly as it is there: the sliver a wider tool
    left in a corner, which the coarse grid holds in a point or two. A flipped start stock is taken
    from its nearest coarse grid point. A tool whose reach would need more grid points than the stock
    model allows keeps the coarse measure (logged).
    """
    if options.engagement_resolution is None:
        return measured
    seg = cut.segments
    tool_of = moves.tool[seg.move]
    out = dataclasses.replace(measured, **{f.name: getattr(measured, f.name).copy()
                                          for f in dataclasses.fields(measured)})
    for t in np.unique(tool_of[~seg.rapid]).tolist():
        tool = tools.get(int(t))
        if tool is None or tool.is_drill:
            continue
        fine = tool.diameter * options.engagement_resolution
        if fine >= options.cell * (1 - 1e-9):
            continue
        mine = np.flatnonzero((tool_of == t) & ~seg.rapid)
        reach = tool.radius + 2 * fine
        xs = np.concatenate([seg.x[mine], seg.x[mine] + seg.dx[mine]])
        ys = np.concatenate([seg.y[mine], seg.y[mine] + seg.dy[mine]])
        lo = np.maximum(setup.stock_min[:2], [xs.min() - reach, ys.min() - reach])
        hi = np.minimum(setup.stock_max[:2], [xs.max() + reach, ys.max() + reach])
        if np.any(hi <= lo):
            continue
        crop = dataclasses.replace(setup, stock_min=np.array([lo[0], lo[1], setup.stock_min[2]]),
                                   stock_max=np.array([hi[0], hi[1], setup.stock_max[2]]))
        try:
            sub = cut_stock(moves, tools, crop, part_triangles, fine, start=_resampled(start, crop, fine),
                            **_cut_options(options))
        except VerifyError as e:
            log.warning("T%d's engagement stays measured on the %g mm grid: %s", t, options.cell, e.message)
            continue
        fine_m = _measured(sub)
        at = np.zeros(len(mine), np.int64)
        ok = np.zeros(len(mine), bool)
        if len(sub.segments):  # one row per move in both, in program order
            at = np.clip(np.searchsorted(sub.segments.move, seg.move[mine]), 0, len(sub.segments) - 1)
            ok = sub.segments.move[at] == seg.move[mine]
        rows, src = mine[ok], at[ok]
        for f in dataclasses.fields(out):
            getattr(out, f.name)[rows] = getattr(fine_m, f.name)[src]
        # moves the fine grid saw cut nothing (outside its stock): measured as not engaged there
        gone = mine[~ok]
        out.angle[gone] = out.width[gone] = out.full_depth[gone] = out.chip[gone] = 0.0
        out.cell[gone] = fine
    return out


def _resampled(start: FlippedStock | None, setup: Setup, cell: float) -> FlippedStock | None:
    """``start`` on the grid of ``cell`` [mm] over ``setup``'s stock, each point from the nearest old one."""
    if start is None:
        return None
    g0 = start.grid
    grid = grid_over(setup.stock_min, setup.stock_max, cell)
    i = np.clip(np.rint((grid.xs - g0.x0) / g0.cell).astype(np.int64), 0, g0.nx - 1)
    j = np.clip(np.rint((grid.ys - g0.y0) / g0.cell).astype(np.int64), 0, g0.ny - 1)
    return FlippedStock(grid=grid, top=start.top[np.ix_(j, i)], bottom=start.bottom[np.ix_(j, i)])


def _judge(seg: Segments, stats: MoveRecord, measured: _Measured, moves: ProgramMoves, tools: Mapping[int, Tool],
           finish: np.ndarray, sim: Simulation, options: VerifyOptions, chips: Mapping[int, ChipLoad]):
    """Rapid crashes, faults and per-tool engagement from the per-move results."""
    g = sim.grid

    def xy(cell: int) -> tuple[float, float]:
        jj, ii = divmod(int(cell), g.nx)
        return float(g.x0 + ii * g.cell), float(g.y0 + jj * g.cell)

    line = moves.line[seg.move].astype(np.int64)
    tool = moves.tool[seg.move].astype(np.int64)
    fin = finish[seg.move]
    crashes = _crashes(seg, stats, moves, sim, options.rapid_tolerance)
    faults: list[Fault] = []
    # A program whose feed moves take nothing off proves nothing (an empty or truncated file).
    if not np.any(stats.removed_max[~seg.rapid] > options.gouge_tolerance):
        faults.append(Fault("no_cut", 0, (), 0.0, 0.0, None, "the program removes no material"))

    flute = np.array([tools[t].flute_length if t in tools else np.inf for t in tool.tolist()], dtype=np.float64)
    # A drill never cuts across (drill_side): its flutes are its only limit.
    axial = np.array([np.inf if t not in tools else tools[t].flute_length if tools[t].is_drill
                      else tools[t].full_width_limit for t in tool.tolist()], dtype=np.float64)
    radial = np.array([np.inf if t not in tools or tools[t].is_drill else tools[t].deep_radial_limit
                       for t in tool.tolist()], dtype=np.float64)
    # Deeper than the full-width limit a move across the stock must be a side cut within the tool's radial limit
    # (a grid cell of slack on both, as for full width); one at full width that deep is a ``full_width`` fault
    # already, and a move straight down has no side cut to judge (its width is the crescent it bores).
    too_deep_slot = ~seg.rapid & (measured.full_depth > axial + measured.cell)
    across = np.hypot(seg.dx, seg.dy) > measured.cell
    deep_wide = (~seg.rapid & ~too_deep_slot & across & (stats.depth > axial + measured.cell)
                 & (measured.width > radial + measured.cell))
    # A drill only cuts along its axis: any feed move across the stock breaks it.
    drill = np.array([t in tools and tools[t].is_drill for t in tool.tolist()], dtype=bool)
    sideways = drill & ~seg.rapid & (seg.l2 > 1e-12) & (stats.removed_max > options.gouge_tolerance)
    chip, fz = move_chips(seg, measured.chip, moves, tool, tools, chips)
    checks = (
        ("rapid", seg.rapid & (stats.removed_max > options.rapid_tolerance), stats.removed_max, stats.removed_cell,
         np.full(len(seg), options.rapid_tolerance), "rapid with T{t} goes {w:.2f} mm into the stock"),
        ("holder", stats.contact > options.contact_tolerance, stats.contact, stats.contact_cell,
         np.full(len(seg), options.contact_tolerance), "shank or holder of T{t} reaches {w:.2f} mm into the stock or part"),
        ("flute", ~seg.rapid & (stats.depth > flute + options.contact_tolerance), stats.depth, stats.depth_cell,
         flute, "T{t} engaged {w:.2f} mm deep, beyond its {l:g} mm flutes"),
        # The grid's own step is no depth: a cut within a cell of the limit is taken as at it.
        ("full_width", too_deep_slot, measured.full_depth, _FINE,
         axial, "T{t} cuts {w:.2f} mm deep at full width near X{x:.1f} Y{y:.1f} Z{z:.1f}, beyond its "
         "{l:g} mm axial limit"),
        ("radial", deep_wide, measured.width, stats.depth_cell, radial,
         "T{t} cuts {w:.2f} mm wide below its full-width depth near X{x:.1f} Y{y:.1f} Z{z:.1f}, beyond its "
         "{l:g} mm radial limit"),
        ("chip", chip > fz * (1.0 + options.chip_tolerance), chip, stats.depth_cell, fz,
         "T{t} cuts a {w:.4f} mm chip, over its feed per tooth of {l:g} mm"),
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
            if where is _FINE:
                x, y = float(measured.full_x[k]), float(measured.full_y[k])
            elif where[k] >= 0:
                x, y = xy(where[k])
            else:
                x, y = float(seg.x[k] + (seg.dx[k] if seg.dz[k] < 0 else 0.0)), float(seg.y[k] + (seg.dy[k] if seg.dz[k] < 0 else 0.0))
            w = float(value[k])
            z = float(seg.zmin[k])
            faults.append(Fault(kind, int(t), tuple(sorted(set(line[ks].tolist()))), w, float(limit[k]),
                                (x, y, z), text.format(t=t, w=w, l=float(limit[k]), x=x, y=y, z=z)))

    engagement = []
    for t in np.unique(tool).tolist():
        ks = np.flatnonzero((tool == t) & ~seg.rapid)
        if len(ks) == 0:
            continue
        k = int(ks[np.argmax(stats.depth[ks])])
        f = int(ks[np.argmax(measured.full_depth[ks])])
        c = int(ks[np.argmax(chip[ks])])
        cutting = ks[measured.width[ks] > 0.0]  # moves that took material off
        counts = np.histogram(measured.angle[cutting], bins=ANGLE_BINS)[0]
        engagement.append(ToolEngagement(
            tool=int(t), finishing=bool(fin[ks].any()), moves=int(len(ks)), max_depth=float(stats.depth[k]),
            max_depth_line=int(line[k]) if stats.depth[k] > 0 else 0, max_width=float(measured.width[ks].max()),
            max_full_depth=float(measured.full_depth[f]),
            max_full_depth_line=int(line[f]) if measured.full_depth[f] > 0 else 0,
            axial_limit=float(axial[ks[0]]), cell=float(measured.cell[ks].min()), engaged=int(len(cutting)),
            depth=Spread.of(stats.depth[cutting]), width=Spread.of(measured.width[cutting]),
            angle=Spread.of(measured.angle[cutting]), angle_moves=tuple(int(c) for c in counts),
            max_chip=float(chip[c]), max_chip_line=int(line[c]) if chip[c] > 0 else 0,
            chip_load=float(np.nan_to_num(fz[ks[0]], posinf=0.0)),
        ))
    return crashes, faults, tuple(engagement)


def _crashes(seg: Segments, stats: MoveRecord, moves: ProgramMoves, sim: Simulation,
             rapid_tolerance: float) -> tuple[RapidCrash, ...]:
    """The rapids that removed more than ``rapid_tolerance`` [mm] of stock, in program order."""
    g = sim.grid
    crashes = []
    for k in np.flatnonzero(seg.rapid & (stats.removed_max > rapid_tolerance)).tolist():
        jj, ii = divmod(int(stats.removed_cell[k]), g.nx)
        crashes.append(RapidCrash(line=int(moves.line[seg.move[k]]), depth=float(stats.removed_max[k]),
                                  position=(float(g.x0 + ii * g.cell), float(g.y0 + jj * g.cell),
                                            float(stats.removed_env[k])), move=int(seg.move[k])))
    return tuple(crashes)


#: Stands for "the position :class:`_Measured` holds" among the grid cells of :func:`_judge`'s checks.
_FINE = np.zeros(0, np.int64)


def _report(
    sim: Simulation, tri: np.ndarray, moves: ProgramMoves, tools, options: VerifyOptions, crashes, n_moves,
    cut_length, rapid_length, faults=(), engagement=(), rapids_checked=0,
) -> VerifyReport:
    covered = np.isfinite(sim.part_top)
    # a relief's base plane covers the whole grid, and the uncut rim round its surface stands on it to the
    # stock's top: figures over the rim would say "stock over the grid max 9.9 mm" of a finished relief
    outside = ~surface_footprint(tri, sim.grid) if options.relief else None
    on_part = covered if outside is None else covered & ~outside
    rem = (sim.stock_top - np.where(covered, sim.part_top, 0.0))[covered]
    beside = ndimage.maximum_filter(np.where(covered, sim.part_top, -np.inf), size=3, mode="constant", cval=-np.inf)
    left = sim.stock_top[on_part] - beside[on_part]  # off the part both may be -inf
    gouge = gouge_depths(sim, tri, covered, rem, options.gouge_tolerance)
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
        remaining_max=float(left.max()),
        remaining_mean=float(left.mean()),
        remaining_p95=float(np.percentile(left, 95)),
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
        left=_left(sim, tri, tools, options, outside),
        left_above=options.left_above,
    )


def _left(sim: Simulation, tri: np.ndarray, tools: Mapping[int, Tool], options: VerifyOptions,
          outside: np.ndarray | None = None) -> tuple[Unreached, ...]:
    """Every region of stock left over ``options.left_above`` with its reason, deepest first: what
    :func:`cadcam.stock.unreached` finds on the grid, and the part's sharp inside corners that still
    hold stock (:func:`cadcam.corners.corners_left`; a relief has no walls of its own to corner).
    ``outside``: a relief's grid points off its own surface, where the uncut rim stands; stock on the surface
    within the roughing tool's radius of it is the boundary's (:data:`cadcam.stock.AT_BOUNDARY`)."""
    radius = _widest_mill_radius(tools)  # a relief's roughing tool, which the boundary keeps off its band
    found = why_left(unreached(sim, options.left_above, 0.0, outside, band=radius), sim, options.left_above, radius,
                     options.op2_follows)
    if options.relief:
        return found
    finest = min((t.radius for t in tools.values() if not t.is_drill), default=0.0)
    corners = corners_left(sim, inside_corners(tri), options.left_above, finest, found)
    return tuple(sorted(found + corners, key=lambda u: (-u.depth, u.x, u.y)))


def _widest_mill_radius(tools: Mapping[int, Tool]) -> float:
    """Radius of the widest end mill in ``tools`` [mm]: the largest corner one leaves; 0 with none."""
    return max((t.radius for t in tools.values() if not t.is_drill), default=0.0)


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


#: :attr:`cadcam.stock.Unreached.why` added to what op 1 left on the side op 2 holds down: op 2 cannot reach it.
FROM_OP1 = "left by op 1"


def with_op1_left(report: VerifyReport, op1: VerifyReport, sim: Simulation, flip: np.ndarray) -> VerifyReport:
    """Op 2's ``report`` with the regions op 1 left on the part (:attr:`VerifyReport.on_part`) that op 2's
    stock ``sim`` still holds: op 2 machines the other side, so what op 1 left (a sharp corner of a pocket
    in op 1's face) stays on the finished part, and op 2's grid, which sees only the stock's top, cannot
    see it. Each is moved into op 2's work coordinates by ``flip`` ((4, 4) op-1 -> op-2 [mm], a half turn
    about X) and says that op 1 left it; a region whose column op 2 cut through is gone."""
    t = np.asarray(flip, dtype=np.float64).reshape(4, 4)
    g = sim.grid
    carried = []
    for u in op1.on_part:
        x, y = u.x + t[0, 3], t[1, 3] - u.y
        i, j = int(round((x - g.x0) / g.cell)), int(round((y - g.y0) / g.cell))
        if 0 <= i < g.nx and 0 <= j < g.ny and not np.isfinite(sim.stock_top[j, i]):
            continue  # op 2 cut through it
        carried.append(dataclasses.replace(u, x=x, y=y, z_bottom=t[2, 3] - u.z_bottom,
                                           why=f"{u.why}, {FROM_OP1}" if u.why else FROM_OP1))
    left = tuple(sorted(report.left + tuple(carried), key=lambda u: (-u.depth, u.x, u.y)))
    return dataclasses.replace(report, left=left)
