"""How deep and how wide a cutter meets the stock: a move's engagement, as verify and the stock model read it.

The stock model (:mod:`cadcam.stock`) cuts a program's moves into a z-map; for every move it hands the
columns the move took off here, which say how deep the cutter was buried (its axial depth of cut), over
what arc of its circumference (the engagement angle) and how deep the deepest full-width cut was.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cadcam.envelope import Segments, reach_interval
from cadcam.model import ProgramMoves, Tool


class MoveRecord:
    """What each swept move met, filled batch by batch as the stock is cut (all lengths [mm]).

    Arrays of one row per :class:`Segments` row, read-only once the cut is done.
    ``depth``: deepest *engaged* depth of the move (see :func:`engaged_depth`);
    ``width``: lateral extent of the material it removed; ``removed_max``: thickest column
    it took off one grid point, ``removed_env``: the tool's lowest point there; ``contact``:
    deepest reach of its shank or holder into the stock or the part, ``contact_z``: the body's
    lowest point there; ``*_cell``: flat grid index where that happened, -1 if nowhere;
    ``volume``: stock it removed above ``bottom`` (the stock's bottom) [mm³]; ``angle``: its
    engagement angle [deg], the arc of the cutter's circumference that met material moving
    sideways, wall skins included; ``full_depth``: the deepest axial cut it took over at least
    the full-width angle (``full_cell``: where), 0 if it never cut at full width; ``chip``: the thickest
    chip it cut as a share of its feed per tooth, ``sin`` of the engagement angle up to 90 deg and 1 past it
    (:func:`_engaged_arc`), 0 if it met nothing sideways.
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
        self.angle = np.zeros(n)
        self.full_depth = np.zeros(n)
        self.full_cell = np.full(n, -1, np.int64)
        self.chip = np.zeros(n)

    def freeze(self) -> None:
        """Make every array read-only: the cut is done."""
        for value in vars(self).values():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)


#: A cut counts as engagement only where it is at least this wide across the move [mm] (see
#: :func:`engaged_depth`), unless told otherwise (:attr:`cadcam.verify.VerifyOptions.engaged_width`).
ENGAGED_WIDTH = 1.0

#: A move is a full-width cut (a slot, an inside corner) where its cutter meets material over more
#: than this arc of its circumference [deg] (the engagement angle, :func:`engaged_depth`), unless told
#: otherwise (:attr:`cadcam.verify.VerifyOptions.full_width_angle`). A slot is 180 deg; a side cut of
#: half the diameter, the widest carbide makers' charts give side-milling data for, 90 deg; this is
#: halfway, a side cut of 0.75 D. A tool running along a wall into the corner a tool three times wider
#: left meets 135 deg of it, one twice as wide about 130 deg; a tool in a corner of its own radius,
#: taking the skin of both walls at once, about 90-100 deg (a side cut, as the charts have it).
FULL_WIDTH_ANGLE = 120.0


def record_max(best: np.ndarray, where: np.ndarray, owner: np.ndarray, value: np.ndarray, cell: np.ndarray,
                extra: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """``best[k] = max(value)`` over entries of owner ``k``, with the cell (and ``extra``) where it is reached."""
    np.maximum.at(best, owner, value)
    at = np.flatnonzero(value >= best[owner])
    where[owner[at]] = cell[at]
    if extra is not None:
        extra[0][owner[at]] = extra[1][at]


#: A grid point counts towards a move's width once the move takes more than this off it [mm].
_ENGAGED_FILM = 0.02


def engaged_depth(seg: Segments, o: np.ndarray, s: int, qx: np.ndarray, qy: np.ndarray, before: np.ndarray,
                   env: np.ndarray, cells: np.ndarray, cell: float, min_width: float, stats: MoveRecord,
                   skin: np.ndarray | None = None, full_width: float = math.radians(FULL_WIDTH_ANGLE)) -> None:
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

    Grid points ``skin`` (within :data:`cadcam.stock._SKIN` of a part wall at least as tall as the
    material on them, less that distance) are left out: the allowance on a wall is
    taken off by finishing whatever its height, a raster pass meeting it head-on.

    The engagement angle (``stats.angle``) is read from the same sideways columns, skins
    included (:func:`_engaged_arc`); ``stats.full_depth`` is the deepest cut that still
    meets material over ``full_width`` [rad] of the cutter: the axial depth of a full-width
    cut, a slot or an inside corner.
    """
    R = seg.radius[o]
    removed = before - env
    plunge = _plunged(seg, o, qx, qy, removed)
    side = removed - plunge
    met_side = side  # skins included: what the flutes meet, for the engagement angle
    if skin is not None:  # the skin of a wall: taken off, but no engagement
        plunge = np.where(skin, 0.0, plunge)
        side = np.where(skin, 0.0, side)

    lat, has = _across(seg, o, qx, qy)
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
        order = _thickest_first(o, side, sel)
        spread = _running_spread(o[order], lat[order], lat[order], 2.0 * float(np.max(seg.radius)))
        wide = np.flatnonzero(spread + cell >= min_width)
        if len(wide):
            record_max(stats.depth, stats.depth_cell, o[order][wide] + s, side[order][wide], cells[order][wide])
    # The arc of the cutter meeting material, and how deep that stays at full width (moves across only).
    sel = np.flatnonzero((met_side > _ENGAGED_FILM) & has)
    if len(sel):
        _side_chip(seg, o[sel], qx[sel], qy[sel], lat[sel], before[sel], env[sel], cell, s, stats)
        _engaged_arc(o[sel], lat[sel], R[sel], met_side[sel], cells[sel], cell, s, full_width, stats)
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
            record_max(stats.depth, stats.depth_cell, os_[at] + s, plunge[order][at], cells[order][at])


def side_chip(seg: Segments, o: np.ndarray, s: int, qx: np.ndarray, qy: np.ndarray, before: np.ndarray,
              env: np.ndarray, cell: float, stats: MoveRecord) -> None:
    """Only the chip of each move (``stats.chip``), as :func:`engaged_depth` reads it from the same columns,
    none of the rest: for a caller that reads nothing else (:mod:`cadcam.chipfeed`). Arguments as
    :func:`engaged_depth`'s. The pairs that take more than :data:`_ENGAGED_FILM` off sideways (:func:`_across`,
    less :func:`_plunged`), each read as :func:`_side_chip` reads it, in one compiled loop
    (:func:`cadcam.toolsweep.side_chip_pairs`)."""
    from cadcam import toolsweep

    toolsweep.side_chip_pairs(o, qx, qy, before, env, cell, s, stats.chip, _ENGAGED_FILM, seg.x, seg.y, seg.z, seg.dx,
                              seg.dy, seg.dz, seg.l2, seg.radius, seg.rc, seg.shape)


def _plunged(seg: Segments, o: np.ndarray, qx: np.ndarray, qy: np.ndarray, removed: np.ndarray) -> np.ndarray:
    """(k,) of the column ``removed`` [mm] a move ``o`` takes off each grid point ``(qx, qy)``, what it takes
    while it descends over the point, as a plunge (from above); the rest it meets moving sideways. Moves that
    do not descend plunge nowhere (their reach along the move is not needed)."""
    plunge = np.zeros(len(o))
    down = np.flatnonzero(seg.dz[o] < 0.0)
    if len(down):
        od = o[down]
        ta, tb, _ = reach_interval(seg, od, qx[down], qy[down])
        plunge[down] = np.minimum(removed[down], -seg.dz[od] * np.maximum(tb - ta, 0.0))
    return plunge


def _across(seg: Segments, o: np.ndarray, qx: np.ndarray, qy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(k,) signed distance [mm] of each grid point ``(qx, qy)`` across move ``o`` (along X for a move with no
    length across), and (k,) bool whether the move has a length across (:func:`cadcam.toolsweep.across`)."""
    from cadcam import toolsweep

    return toolsweep.across(o, qx, qy, seg.x, seg.y, seg.dx, seg.dy, seg.l2)


def _side_chip(seg: Segments, o: np.ndarray, qx: np.ndarray, qy: np.ndarray, w: np.ndarray, before: np.ndarray,
               env: np.ndarray, cell: float, s: int, stats: MoveRecord) -> None:
    """The chip of moves ``s + o`` (``stats.chip``, as a share of the feed per tooth) from the grid points
    ``(qx, qy)`` they met sideways, at lateral offset ``w`` [mm] from the move's line, the stock there standing
    from ``env`` (the cutter's lowest point over it) up to ``before`` [mm].

    A tooth meeting the material at ``w`` on the cutter's circle of radius ``rho`` cuts a chip
    ``fz * sqrt(1 - (w / rho)^2)`` thick across its edge, thickest at the point nearest the move's line, taken
    half a cell nearer it as :func:`_engaged_arc` takes it: on the flutes (``rho`` the tool's radius) and for a side
    cut of width ``ae``, ``fz`` times the sine of its engagement angle ``acos(1 - ae / r)`` (``2 sqrt(ae (D -
    ae)) / D``, the rule of :func:`cadcam.adaptive.chip_thinned_feed`); 1 where the material reaches the line (a
    slot, a side cut of half the diameter or more).

    Stock whose top stands below the top of a bull nose's or ball's corner radius on a level move is met by the
    corner only: at that height the corner's circle is smaller (``rho`` < radius) and its edge leans (the chip
    is thinned by the sine of the lead angle, 0 on the flat bottom, 1 on the flutes), so the chip there is ``fz *
    sin(lead) * sqrt(1 - (w / rho)^2)``. Read with the tool's radius instead, the fillet a bull nose's corner
    leaves at the foot of the wall before, met again by the next pass's flat bottom, reads as a chip 1.15 times fz
    where the wall itself makes fz (the dome's adaptive rings). The height is the stock's top above the tip, not
    the column this move cuts: a point ahead of a move's end (a pass in short moves) loses its top to the
    cutter's front, which meets it at that height.

    A ball on a sloped move meets each point where its sphere's front first reaches it: a tooth there cuts ``fz``
    times the cosine between the move's direction and the sphere's normal, ``sqrt(1 - (d / R)^2)`` for ``d`` the
    distance from the ball's centre line to the nearest stock of the column (the level rule in 3-D: on a level
    move ``d^2 = w^2 + (R - H)^2``). A flat or bull nose on a sloped move, and a drill's point, are read on the
    tool's radius (the thicker chip). Compiled (:func:`cadcam.toolsweep.side_chips`)."""
    from cadcam import toolsweep

    toolsweep.side_chips(o, qx, qy, w, before, env, cell, s, stats.chip, seg.x, seg.y, seg.z, seg.dx, seg.dy, seg.dz,
                         seg.l2, seg.radius, seg.rc, seg.shape)


#: The leading half of the cutter is read in this many arcs of equal angle (5 deg each).
_ARC_BINS = 36


def _engaged_arc(o: np.ndarray, w: np.ndarray, r: np.ndarray, depth: np.ndarray, cells: np.ndarray, cell: float,
                 s: int, full_width: float, stats: MoveRecord) -> None:
    """Engagement angle and full-width depth of moves ``s + o`` from the points they met sideways.

    A point at lateral offset ``w`` [mm] from a straight move is met by the leading half of the
    cutter (radius ``r``) at the angle ``asin(w / r)`` from the feed direction; standing for
    its cell, it covers the angles of ``w`` +- half a cell (a whole cell outwards). Each move's half circle is read in
    :data:`_ARC_BINS` arcs, each holding the thickest column ``depth`` [mm] met there: the
    engagement angle is the arc whose columns are more than a film thick (a slot 180 deg, a
    side cut of width ``ae`` ``acos(1 - ae / r)``, a skin met head-on the chord its thickness
    cuts, two thin skins either side of a slot two small arcs), and the full-width depth is
    the deepest column that arcs adding up to more than ``full_width`` [rad] all reach.

    The chip (``stats.chip``) is read from the same points by :func:`_side_chip`.
    """
    step = math.pi / _ARC_BINS
    n = int(o.max()) + 1
    # Half a cell towards the axis, a whole one away from it: the band of a cell's width along the
    # cutter's side may hold no grid point, yet it spans a wide arc (asin is steep there).
    lo = np.arcsin(np.clip((w - np.where(w < 0, 1.0, 0.5) * cell) / r, -1.0, 1.0)) + 0.5 * math.pi
    hi = np.arcsin(np.clip((w + np.where(w > 0, 1.0, 0.5) * cell) / r, -1.0, 1.0)) + 0.5 * math.pi
    b0 = np.clip(np.floor(lo / step).astype(np.int64), 0, _ARC_BINS - 1)
    b1 = np.clip(np.ceil(hi / step).astype(np.int64) - 1, b0, _ARC_BINS - 1)
    best = np.zeros(n * _ARC_BINS)
    where = np.full(n * _ARC_BINS, -1, np.int64)
    for m in range(int((b1 - b0).max()) + 1):
        k = np.flatnonzero(b0 + m <= b1)
        record_max(best, where, o[k] * _ARC_BINS + b0[k] + m, depth[k], cells[k])
    moves = np.unique(o)
    best = best.reshape(n, _ARC_BINS)[moves]
    where = where.reshape(n, _ARC_BINS)[moves]
    arc = np.degrees(np.count_nonzero(best > _ENGAGED_FILM, axis=1) * step)
    stats.angle[moves + s] = np.maximum(stats.angle[moves + s], arc)
    need = int(math.floor(full_width / step + 1e-9)) + 1  # more than the full-width arc
    if need > _ARC_BINS:
        return
    kth = np.argsort(-best, axis=1, kind="stable")[:, need - 1]
    rows = np.arange(len(moves))
    deep, at = best[rows, kth], where[rows, kth]
    better = deep > stats.full_depth[moves + s]
    stats.full_depth[moves[better] + s] = deep[better]
    stats.full_cell[moves[better] + s] = at[better]


def _thickest_first(o: np.ndarray, value: np.ndarray, sel: np.ndarray) -> np.ndarray:
    """The entries ``sel``, grouped by move ``o`` (ascending) and thickest ``value`` first within each."""
    return sel[np.argsort(o[sel] * (float(value[sel].max()) + 1.0) - value[sel], kind="stable")]


def _running_spread(group: np.ndarray, lo: np.ndarray, hi: np.ndarray, span: float) -> np.ndarray:
    """``max(hi) - min(lo)`` over each entry and the ones before it in its run of equal ``group``
    (sorted), every value within ``span`` of the others: a cummax with each run lifted above the last."""
    shift = group * (4.0 * span + 4.0)
    top = np.maximum.accumulate(hi + shift) - shift
    bottom = shift - np.maximum.accumulate(shift - lo)
    return top - bottom


@dataclass(frozen=True)
class ChipLoad:
    """What one tool's chip is held to: the library's feed per tooth ``fz`` [mm] in the job's material, the
    tool run at ``spindle_rpm`` [rev/min] (its feed per tooth is the programmed feed over ``rpm * flutes``)."""

    fz: float
    spindle_rpm: float


def chip_loads(operations: Sequence[Mapping[str, Any]]) -> dict[int, ChipLoad]:
    """Each tool's :class:`ChipLoad` from a setup sheet's ``operations`` (``tool``, ``spindle_rpm`` and
    ``chip_load_mm``, :func:`cadcam.sheet.setup_sheet`): the smallest of both over the tool's operations (the
    slower spindle makes the thicker chip of a feed). A tool no operation gives a chip load for is not judged."""
    out: dict[int, ChipLoad] = {}
    for op in operations:
        try:
            tool, fz, rpm = int(op["tool"]), float(op["chip_load_mm"]), float(op["spindle_rpm"])
        except (KeyError, TypeError, ValueError):
            continue
        if not (fz > 0 and rpm > 0 and math.isfinite(fz) and math.isfinite(rpm)):
            continue
        had = out.get(tool)
        out[tool] = ChipLoad(fz, rpm) if had is None else ChipLoad(min(had.fz, fz), min(had.spindle_rpm, rpm))
    return out


def move_chips(seg: Segments, share: np.ndarray, moves: ProgramMoves, tool: np.ndarray, tools: Mapping[int, Tool],
               chips: Mapping[int, ChipLoad]) -> tuple[np.ndarray, np.ndarray]:
    """Per segment (``tool`` its tool number), the thickest chip it cut [mm]: its programmed feed per tooth
    times ``share``, the chip as a share of it (``MoveRecord.chip``); 0 for rapids, drills and tools not in
    ``chips``. And the feed per tooth it is held to [mm] (inf where not judged)."""
    per_tooth = np.zeros(len(seg))
    fz = np.full(len(seg), np.inf)
    for t, load in chips.items():
        if t not in tools or tools[t].is_drill:
            continue
        mine = (tool == t) & ~seg.rapid
        per_tooth[mine] = np.nan_to_num(moves.feed[seg.move[mine]]) / (load.spindle_rpm * tools[t].flutes)
        fz[mine] = load.fz
    return per_tooth * share, fz
