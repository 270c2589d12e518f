"""A program's first moves cut into the stock model ahead of the whole program, for the cut to go on from.

``factory plan`` posts op 1's program only once every operation is planned; its verify cuts the program into
the stock model move by move (:func:`cadcam.stock.cut_stock`). The first operations' moves can be cut while
the later ones are planned (:class:`factory.verify.VerifyAhead`): :func:`cut_ahead` cuts a program known so
far and stops at a boundary between two of the cut's batches, and :func:`cadcam.stock.cut_stock` resumes
from that :class:`CutState` when the whole program begins with the same moves. What a cut depends on besides
its moves (the grid, the part, the starting stock, the options, the tools) is held as a digest and checked too:
a state that is not the program's beginning is not used, and the result is the same either way.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from cadcam.engagement import ENGAGED_WIDTH, FULL_WIDTH_ANGLE
from cadcam.envelope import Segments, SpanTops
from cadcam.model import ProgramMoves, Setup, Tool
from cadcam.stock import RAPID_RIM, FlippedStock, Simulation, _Cut, _run


@dataclass(frozen=True)
class CutState:
    """A program's first moves cut into the stock model, stopped at a boundary between two of the cut's
    batches (:func:`cut_ahead`): :func:`cadcam.stock.cut_stock` given it as ``resume`` starts there instead of at the
    first move, when the program it cuts begins with exactly these moves, swept alike, cut into the same
    stock and part on the same grid with the same options; else it starts at the first move. Either way
    its result is the same to the bit.

    Why only at a batch boundary: a batch's moves are measured together, and the engagement orders them
    by a key scaled to the batch (:func:`cadcam.engagement.engaged_depth`): a cut split inside a batch
    would not be the cut made in one go.

    Attributes
    ----------
    segments : Segments
        The moves cut, as swept: rows ``0 .. n`` of the program's (:attr:`cadcam.stock.StockCut.segments`).
    tool_of_seg : (n,) int
        The tool making each.
    bounds : (b + 1,) int
        The batch boundaries up to ``n``, the last.
    stock : (ny * nx,) float
        Stock top after them [mm], flat.
    under : (ny * nx,) float or None
        A flipped stock's column bottoms after them [mm] (None: the stock stands on its bottom plane).
    met : dict of str to (n,) array
        What each of them met (the arrays of :class:`cadcam.engagement.MoveRecord`).
    tops : (levels, ny, blocks) float
        The upper bounds of the stock the next batch pairs its moves with (:class:`cadcam.envelope.SpanTops`).
    key : str
        SHA-256 of everything else the cut depends on: grid, part, starting stock, options and the tools.
    """

    segments: Segments
    tool_of_seg: np.ndarray
    bounds: np.ndarray
    stock: np.ndarray
    under: np.ndarray | None
    met: dict[str, np.ndarray]
    tops: np.ndarray
    key: str

    @property
    def moves(self) -> int:
        """Moves of the program (:attr:`ProgramMoves.points` after the first) up to the last one cut."""
        return int(self.segments.move[-1]) if len(self.segments) else 0

    def restore(self, cut: _Cut) -> tuple[int, SpanTops | None]:
        """Go on from here where this is ``cut``'s beginning (before any of its moves is cut: its stock and
        records are taken from here): the batch to start at and the stock bounds it uses; ``(0, None)``
        where this is not its beginning."""
        c, n = len(self.bounds) - 1, len(self.segments)
        if (c < 1 or len(cut.bounds) <= c or not np.array_equal(cut.bounds[:c + 1], self.bounds)
                or not np.array_equal(cut.body.tool_of_seg[:n], self.tool_of_seg)
                or (cut.under is None) != (self.under is None)
                or any(not np.array_equal(getattr(cut.seg, f.name)[:n], getattr(self.segments, f.name))
                       for f in dataclasses.fields(Segments))
                or _key(cut, self.tool_of_seg) != self.key):
            return 0, None
        cut.stock[:] = self.stock
        if cut.under is not None:
            cut.under[:] = self.under
        for name, value in self.met.items():
            getattr(cut.met, name)[:n] = value
        return c, SpanTops.of_table(self.tops)


def cut_ahead(
    moves: ProgramMoves,
    tools: Mapping[int, Tool],
    setup: Setup,
    part_triangles: np.ndarray,
    cell: float,
    *,
    before: int,
    start: FlippedStock | Simulation | None = None,
    rapid_rim: float = RAPID_RIM,
    engaged_width: float = ENGAGED_WIDTH,
    body_graze: float = 0.0,
    full_width_angle: float = FULL_WIDTH_ANGLE,
    measure: bool = True,
    resume: CutState | None = None,
) -> CutState | None:
    """The first moves of a program cut as :func:`cadcam.stock.cut_stock` cuts them, for it to go on from
    (its ``resume``).

    For a program known only so far: ``moves`` ends with moves the whole program will not have (the end of
    a program posted from its first operations), and only its moves before ``points[before]`` are taken
    to be the whole program's. The cut stops at the last batch boundary among them.

    Parameters
    ----------
    moves, tools, setup, part_triangles, cell, start, rapid_rim, engaged_width, body_graze, full_width_angle, measure
        As :func:`cadcam.stock.cut_stock` takes them.
    before : int
        Index into ``moves.points``: the moves ending there and after it are not cut.
    resume : CutState, optional
        An earlier state of this cut (of fewer moves), to go on from, as :func:`cadcam.stock.cut_stock`'s.

    Returns
    -------
    CutState or None
        None where not one batch ends before ``points[before]``.

    Raises
    ------
    VerifyError
        As :func:`cadcam.stock.cut_stock`.
    """
    cut = _Cut(moves, tools, setup, part_triangles, cell, start, rapid_rim, engaged_width, body_graze,
               full_width_angle, measure, np.zeros(0, np.int64))
    # the batches that end at or before the first segment of a move not taken (seg.move is increasing); the
    # end of these moves is no boundary of the whole program's batches (the last may go on past it)
    stable = int(np.searchsorted(cut.seg.move, before, side="left"))
    last = int(np.searchsorted(cut.bounds[:-1], stable, side="right")) - 1
    key = _key(cut, cut.body.tool_of_seg[:int(cut.bounds[max(last, 0)])])  # before anything is cut
    first, tops = (0, None) if resume is None else resume.restore(cut)
    if last <= first:  # nothing more to cut: the state given holds as much as is known
        return resume if first > 0 else None
    _run(cut, None, cut.bounds, first, tops, last)
    n = int(cut.bounds[last])
    met = {name: value[:n].copy() for name, value in vars(cut.met).items() if isinstance(value, np.ndarray)}
    seg = cut.seg.sub(0, n)
    seg = Segments(*(np.array(getattr(seg, f.name)) for f in dataclasses.fields(Segments)))
    return CutState(seg, cut.body.tool_of_seg[:n].copy(), cut.bounds[:last + 1].copy(), cut.stock.copy(),
                    None if cut.under is None else cut.under.copy(), met, cut.tops.table.copy(), key)


def _key(cut: _Cut, tool_numbers: np.ndarray) -> str:
    """:attr:`CutState.key` of ``cut`` before it goes on, for a state whose moves use these tools."""
    h = hashlib.sha256(repr(cut.options).encode())
    for a in (cut.part, cut.stock, cut.under):
        h.update(b"-" if a is None else np.ascontiguousarray(a).tobytes())
    used = sorted(set(np.asarray(tool_numbers).tolist()))
    h.update(repr([(t, cut.tools[t].body(), cut.tools[t].flute_length) if t in cut.tools else (t,)
                   for t in used]).encode())
    return h.hexdigest()
