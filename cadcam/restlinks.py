"""The order and the links of rest machining's regions (:func:`cadcam.roughing.zlevel_roughing` with a known stock).

Rest machining cuts a few regions round the part's features on many levels: the terraces on a boss's
flanks, the skin on a wall. Level by level the tool goes round every feature on each level and lifts to the
clearance height between them. Here the regions are cut stack by stack (:func:`stacked`) and linked as low
as the stock allows (:class:`Links`): across at the level where it is cut (:func:`stays_down`), else lifted
only a little over the stock known along the straight way.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from collections.abc import Sequence
from typing import Any

import numpy as np
import shapely
from scipy import ndimage
from shapely.geometry import LineString, Point
from shapely.geometry.base import BaseGeometry

from cadcam.model import Motion, Tool
from cadcam.post import PostOptions
from cadcam.stock import Simulation, clear_height

#: Slack when checking that a link lies in the space the axis may go [mm] (the loops lie on its outline).
COVER_TOL = 1e-5
#: Segments a quarter circle in a piece's footprint (:attr:`Piece.footprint`).
FOOTPRINT_QUAD_SEGS = 4
#: Shares of the grow distance within which a footprint surely reaches from its way, and beyond which it
#: surely does not (:meth:`Piece.meets`). Its arcs' chords come within cos(pi / 16) = 0.981 of it, and GEOS
#: first simplifies the line by 1 % of the distance (``BufferParameters`` simplify factor 0.01), either way.
SURELY_MEETS = 0.95
SURELY_APART = 1.02
#: Samples of a link's way whose clearance :meth:`Links.height` asks first, those under the highest bounds: the
#: others only where their bound lies over the highest clearance these gave.
FIRST_ASKED = 32


def nearest_tour(starts: np.ndarray, start: np.ndarray, ends: np.ndarray | None = None) -> np.ndarray:
    """Visiting order of items that begin at XY ``starts`` (k, 2) [mm], nearest first from ``start``: each
    next item is the one whose start is nearest to where the last ended (``ends`` (k, 2); points, which end
    where they begin, by default). A greedy tour: the holes of a drill, the runs of a deep cut."""
    starts = np.asarray(starts, dtype=np.float64)
    ends = starts if ends is None else np.asarray(ends, dtype=np.float64)
    left = list(range(len(starts)))
    order = []
    at = np.asarray(start, dtype=np.float64)
    while left:
        d = [float(np.hypot(*(starts[i] - at))) for i in left]
        i = left.pop(int(np.argmin(d)))
        order.append(i)
        at = ends[i]
    return np.array(order, dtype=np.int64)


@dataclass(frozen=True)
class Piece:
    """One region's moves at one level, cut on their own.

    ``z`` [mm]: its level; ``start_xy`` [mm]: where the tool stands over at the clearance height before
    ``points`` (the descent, the entry and the loops, as :func:`cadcam.roughing._cut_region` emits them;
    ``motion`` theirs); ``way``: the XY axis of its feed moves (a line, or a point); ``reach`` [mm]: the
    tool radius and a little more, so :attr:`footprint`, the XY area its tool sweeps while feeding, is
    ``way`` grown by ``reach``."""

    level: int
    z: float
    start_xy: np.ndarray
    points: np.ndarray
    motion: np.ndarray
    way: BaseGeometry
    reach: float

    @functools.cached_property
    def footprint(self) -> BaseGeometry:
        """``way`` grown by ``reach``, in :data:`FOOTPRINT_QUAD_SEGS` segments a quarter circle."""
        return self.way.buffer(self.reach, quad_segs=FOOTPRINT_QUAD_SEGS)

    @classmethod
    def of(cls, level: int, z: float, points: np.ndarray, motion: np.ndarray, clear_z: float,
           radius: float) -> Piece | None:
        """The piece of a region cut at level ``z`` [mm] on a path of its own that starts at the clearance
        height ``clear_z`` [mm] over its entry (``points``, ``motion``), for a tool of ``radius`` [mm]; the
        rapids there to the entry are left out (the pieces are linked anew). None: it holds nothing else."""
        lead = 1
        while lead < len(points) and points[lead, 2] >= clear_z - 1e-9:
            lead += 1
        if lead >= len(points):
            return None
        fed = np.flatnonzero(motion[lead:] != int(Motion.RAPID)) + lead  # feed moves points[i - 1] -> points[i]
        feeding = points[np.unique(np.concatenate([fed - 1, fed]))][:, :2]
        way = LineString(feeding) if len(feeding) > 1 else Point(feeding[0] if len(feeding) else points[lead, :2])
        return cls(level, z, points[lead - 1, :2], points[lead:], motion[lead:], way, radius + 1e-5)

    def meets(self, other: Piece) -> bool:
        """Whether the two footprints intersect. Two ways nearer than :data:`SURELY_MEETS` of their reaches
        together, or farther than :data:`SURELY_APART`, decide without growing either (growing a terrace's
        long loops was most of the time its pieces took, issue 35); between, the footprints are compared."""
        reach = self.reach + other.reach
        shapely.prepare(self.way)
        if shapely.dwithin(self.way, other.way, SURELY_MEETS * reach):
            return True
        if not shapely.dwithin(self.way, other.way, SURELY_APART * reach):
            return False
        return self.footprint.intersects(other.footprint)


def stacked(pieces: list[Piece]) -> list[Piece]:
    """``pieces`` (in the level-by-level order they were planned) stack by stack: pieces whose tool sweeps
    meet (:meth:`Piece.meets`), directly or through others, form a stack, cut top down in their planned order
    before the next stack (ordered by its first piece). No feed move meets other stock than it did level by
    level: a piece's stock is changed only by the pieces whose sweeps meet its own, all of its stack, which
    keep their order. The tool descends a stack's levels instead of going round every stack on each level."""
    if len(pieces) < 2:
        return list(pieces)
    parent = list(range(len(pieces)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    # Pairs whose footprints' boxes meet, each judged only while the two are in different stacks.
    ways = [q.way for q in pieces]
    grow = np.array([[-1.0, -1.0, 1.0, 1.0]]) * SURELY_APART * np.array([[q.reach for q in pieces]]).T
    boxes = shapely.box(*(shapely.bounds(ways) + grow).T)
    a, b = shapely.STRtree(boxes).query(boxes, predicate="intersects")
    for i, j in zip(a.tolist(), b.tolist()):
        ri, rj = root(i), root(j)
        if ri != rj and pieces[i].meets(pieces[j]):
            parent[max(ri, rj)] = min(ri, rj)  # a stack's root is its first piece
    return [pieces[i] for i in sorted(range(len(pieces)), key=lambda i: (root(i), i))]


class Links:
    """How low the tool may link across: the stock known before the operation, lowered where the pieces
    cut so far took it (:meth:`cut`).

    ``height(a, b)`` is the lowest tip height [mm] at which the tool may rapid straight from XY ``a`` to
    ``b`` touching none of that stock, inf where the way leaves ``rect`` (where the axis may go: outside it
    lie the jaws). The way is sampled every quarter cell, each sample's height :func:`cadcam.stock.clear_height`
    (which takes a grid point's stock as reaching a cell diagonal round it), so the tool between two samples
    lies within an eighth of a cell of one of them; the rapid check of the whole program runs after."""

    def __init__(self, known: Simulation, tool: Tool, rect: BaseGeometry, spaces: Sequence[BaseGeometry]) -> None:
        self.top = np.array(known.stock_top, dtype=np.float64)  # lowered as the pieces cut
        self.stock = dataclasses.replace(known, stock_top=self.top)
        self.tool, self.rect, self.spaces = tool, rect, spaces
        self._covering: dict[int, BaseGeometry] = {}  # spaces[level] grown by COVER_TOL, made when first asked
        self._bound: np.ndarray | None = None  # (:meth:`_bounds`), made when first asked
        shapely.prepare(rect)

    def _way(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(n, 2) samples of the straight way from ``a`` to ``b``, a quarter cell apart at most [mm]."""
        length = float(np.linalg.norm(b - a))
        t = np.linspace(0.0, 1.0, max(2, int(math.ceil(length / (0.25 * self.stock.grid.cell))) + 1))
        return a + t[:, None] * (b - a)

    def _within(self, a: np.ndarray, b: np.ndarray) -> bool:
        return float(np.linalg.norm(b - a)) <= 1e-9 or self.rect.covers(LineString([a, b]))

    def height(self, a: np.ndarray, b: np.ndarray) -> float:
        if not self._within(a, b):
            return math.inf
        # The highest clearance along the way, asked only where it can be: first under the highest bounds, then
        # under those over what they gave (the others give no more). The same maximum of the same numbers.
        xy = self._way(a, b)
        bound = self._bounds(xy)
        order = np.argsort(-bound, kind="stable")
        high = np.max(clear_height(self.stock, self.tool, xy[order[:FIRST_ASKED]]))
        more = order[FIRST_ASKED:][bound[order[FIRST_ASKED:]] > high]
        if len(more):
            high = np.max(np.r_[high, clear_height(self.stock, self.tool, xy[more])])
        return float(high)

    def _bounds(self, xy: np.ndarray) -> np.ndarray:
        """(n,) a height [mm] at or over :func:`cadcam.stock.clear_height` at each axis position ``xy`` (n, 2) [mm]:
        the highest stock within the tool's radius and three cells of the grid point it rounds to, on the stock
        known when first asked (the pieces only lower it). That height reads the stock within the radius and a
        cell diagonal of the axis, less the tool's profile height (never negative), and the axis lies within half
        a diagonal of that point. Off the grid by more than the padding: its edge, whose disc holds as much."""
        g, top = self.stock.grid, self.top
        k = int(math.ceil(self.tool.radius / g.cell)) + 3
        if self._bound is None:
            d = np.arange(-k, k + 1)
            disk = np.hypot(*np.meshgrid(d, d)) <= k
            held = np.pad(np.where(np.isnan(top), np.inf, top), k, constant_values=-np.inf)  # NaN: always asked
            self._bound = ndimage.maximum_filter(held, footprint=disk, mode="constant", cval=-np.inf)
        i = np.clip(np.rint((xy[:, 0] - g.x0) / g.cell).astype(np.int64) + k, 0, self._bound.shape[1] - 1)
        j = np.clip(np.rint((xy[:, 1] - g.y0) / g.cell).astype(np.int64) + k, 0, self._bound.shape[0] - 1)
        return self._bound[j, i]

    def stays_down(self, a: np.ndarray, b: np.ndarray, z: float, level: int) -> bool:
        """Whether the tool may feed straight from XY ``a`` to ``b`` [mm] at tip height ``z`` [mm] meeting
        nothing: the way lies in ``spaces[level]`` (where the axis may go at that level, at or under ``z``:
        off the part by the allowance, exactly, between the grid points too), and no grid point strictly
        within its radius of the way holds stock above ``z``. A feed move, not a rapid: it may graze what its
        last loop grazed (the skin on a wall), and what stock lies between the grid points is no more than the
        slivers every cut of the model leaves. (Without the space, a chord across a wall's outside corner cut
        into the part between grid points: long_turned's 16 mm end mill 0.14 mm into a corner, 8 mm deep.)"""
        if not self._in_space(a, b, level):
            return False
        g, r = self.stock.grid, self.tool.radius - 1e-6
        xy = self._way(a, b)
        k = int(math.ceil(r / g.cell)) + 1
        di, dj = (d.ravel() for d in np.meshgrid(np.arange(-k, k + 1), np.arange(-k, k + 1)))
        i = np.rint((xy[:, 0, None] - g.x0) / g.cell).astype(np.int64) + di
        j = np.rint((xy[:, 1, None] - g.y0) / g.cell).astype(np.int64) + dj
        inside = (i >= 0) & (i < g.nx) & (j >= 0) & (j < g.ny)
        ii, jj = np.clip(i, 0, g.nx - 1), np.clip(j, 0, g.ny - 1)
        near = inside & (np.hypot(g.x0 + ii * g.cell - xy[:, 0, None], g.y0 + jj * g.cell - xy[:, 1, None]) < r)
        return bool(np.all(self.top[jj[near], ii[near]] <= z + 1e-6)) and self._within(a, b)

    def _in_space(self, a: np.ndarray, b: np.ndarray, level: int) -> bool:
        covering = self._covering.get(level)
        if covering is None:
            covering = self._covering[level] = self.spaces[level].buffer(COVER_TOL)
            shapely.prepare(covering)
        return bool(covering.covers(LineString([a, b]) if float(np.linalg.norm(b - a)) > 1e-9 else Point(a)))

    def cut(self, piece: Piece) -> None:
        """Lower the stock to the piece's level wherever a feed move of it at that level swept the tool's
        flat end (the grid points within the radius of the moves): there nothing is left above it."""
        pts, z = piece.points, piece.z
        at = ((np.abs(pts[1:, 2] - z) < 1e-9) & (np.abs(pts[:-1, 2] - z) < 1e-9)
              & (piece.motion[1:] != int(Motion.RAPID)))
        if not at.any():
            return
        # the runs of such moves, each one line
        edges = np.flatnonzero(np.diff(np.r_[0, at.astype(np.int8), 0]))
        lines = [LineString(pts[s:e + 1, :2]) for s, e in zip(edges[::2], edges[1::2])]
        swept = shapely.union_all(shapely.buffer(lines, self.tool.radius - 1e-6, quad_segs=4))
        g = self.stock.grid
        x0, y0, x1, y1 = swept.bounds
        i0, i1 = max(0, int(math.floor((x0 - g.x0) / g.cell))), min(g.nx, int(math.ceil((x1 - g.x0) / g.cell)) + 1)
        j0, j1 = max(0, int(math.floor((y0 - g.y0) / g.cell))), min(g.ny, int(math.ceil((y1 - g.y0) / g.cell)) + 1)
        if i0 >= i1 or j0 >= j1:
            return
        X, Y = np.meshgrid(g.x0 + g.cell * np.arange(i0, i1), g.y0 + g.cell * np.arange(j0, j1))
        inside = shapely.contains_xy(swept, X, Y)
        sub = self.top[j0:j1, i0:i1]
        sub[inside] = np.minimum(sub[inside], z)


def stays_down(links: Links, here: np.ndarray, xy: np.ndarray, feed: float, clear_z: float, lead_gap: float,
               level: int) -> bool:
    """Whether the tool at ``here`` [mm], at or over level ``level``, goes on to XY ``xy`` [mm] at its height,
    at the cutting ``feed`` [mm/min] (:meth:`Links.stays_down`), rather than lifting ``lead_gap`` [mm] over the
    stock (no higher than ``clear_z`` [mm]) and rapiding across: where it may, and where the feed across takes
    no longer than the lift, the rapid across and the way back down by the program's clock
    (:class:`cadcam.post.PostOptions`)."""
    z, length = float(here[2]), float(np.linalg.norm(xy - here[:2]))
    if not links.stays_down(here[:2], xy, z, level):
        return False
    lift = min(clear_z, max(z, links.height(here[:2], xy) + lead_gap)) - z
    return length / feed <= (length + 2.0 * lift) / PostOptions().rapid_rate


def cut_stacked(path: Any, pieces: list[Piece], links: Links, feed: float, p: Any) -> None:
    """The ``pieces`` of a rest machining onto ``path`` (:class:`cadcam.levelpath.LevelPath`, with its
    parameters ``p``) stack by stack (:func:`stacked`), each linked to the next low (:class:`Links`): fed
    across at its level where that is quicker (:func:`stays_down`, at the cutting ``feed`` [mm/min]), else
    lifted only over the stock along the way (``path.go_to`` with ``path.link_height``)."""
    path.link_height = links.height
    last: Piece | None = None
    for piece in stacked(pieces):
        first = 0
        if not path.points:
            path.add([*piece.start_xy, p.safe_z], Motion.RAPID)
            path.add([*piece.start_xy, p.clear_z], Motion.RAPID)
        elif last is not None and piece.z <= path.here[2] + 1e-9 and stays_down(
                links, path.here, piece.start_xy, feed, p.clear_z, p.lead_gap, last.level):
            # Over what is cut at this height: feed across and go on down, no lift and back.
            path.add([*piece.start_xy, path.here[2]], Motion.CUT)
            while (first < len(piece.points) and piece.motion[first] == Motion.RAPID
                   and piece.points[first, 2] >= path.here[2] - 1e-9):
                first += 1  # the piece's rapid down to its descent, from higher up
        else:
            path.go_to(piece.start_xy, p)
        path.add_many(piece.points[first:], piece.motion[first:])
        links.cut(piece)
        last = piece
