"""Which of a region's contour-parallel loops z-level clearing cuts, and in what order
(:func:`cadcam.roughing._cut_region`).

Rest machining's region at a level is where the tool's axis may go within its radius of the rest material: a
skin on a wall gives a band whose outer edge lies a radius off the skin, so the loop round that edge sweeps
air beside the one along the wall, which takes the whole skin (the flank pass round a part, twice). A loop that
passes within the tool radius of no rest material and of no stock at all is not cut (:class:`LoopChoice`): the
stock each other loop meets is the same. An open region is entered from outside the stock onto the outermost loop
cut (:func:`open_lead`), which is not the region's outline when that loop, round the stock's side, sweeps air.

Outside-in clearing cuts every loop of one erosion index before any of the next, so on a region round several
features (a floor between bosses) the tool goes round the first loop of each feature, then the second of each,
crossing the part between them every time. A machinist finishes round one feature before going to the next.
What the strict order guarantees is only that a loop meets the stock its outer neighbours leave: so a loop
here waits only for the loops of the lower index (outside-in; higher, inside-out) that its tool sweep can touch,
those less than a diameter away (:meth:`LoopOrder.of`). Any two loops whose sweeps overlap are then cut in the
same order as before, so each loop meets the same stock; among the loops ready, the tool takes the one it
reaches soonest from where it stands (:meth:`LoopOrder.next`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import shapely
from scipy.spatial import cKDTree
from shapely.geometry import LineString, Point, Polygon
from shapely.geometry.base import BaseGeometry

from cadcam.gridregion import GrownMaskCache, near_cells
from cadcam.model import Tool
from cadcam.rest import rest_level_masks
from cadcam.restlinks import COVER_TOL
from cadcam.stock import Simulation, excess

#: Slack on "less than a diameter away" [mm]: loops a hair farther apart cannot touch each other's sweep.
_WAIT_TOL = 1e-3
#: Stock less than this above a level, or over the part and its allowance, is none the level cuts [mm].
_STANDING_EPS = 1e-3
#: Segments per quarter circle of the rest material's cells grown by the radius (the rest region).
_QUAD_SEGS = 8
#: Share of the radius by which the rest region's outline comes inside it at its arcs (their chords' sagitta): a
#: loop on that outline, tangent to the stock's cells, sweeps into them no deeper than this.
_ARC_SAG = 1.0 - math.cos(math.pi / (4 * _QUAD_SEGS))
#: Slack on a sure "farther than" between a point and a line's samples [mm]: far over their rounding.
_SURE_TOL = 1e-6
#: A loop's samples for :func:`_near`, this share of a cell apart at most: the band of points GEOS is asked
#: about is half of it wide.
_SAMPLE_STEP = 0.25


@dataclass(frozen=True)
class LoopChoice:
    """Which of a region's loops rest machining cuts (:meth:`at`), over ``known`` (all the stock known before
    the operation, not only its target), with a tool of ``radius`` [mm]; ``over`` ((ny, nx) bool) marks the grid
    points whose stock stands over the part grown by the operation's allowance."""

    known: Simulation
    over: np.ndarray
    radius: float

    @classmethod
    def of(cls, known: Simulation, allowance: float, radius: float) -> LoopChoice:
        """The choice for an operation leaving ``allowance`` [mm] with a tool of ``radius`` [mm]."""
        over = excess(known, allowance, grid_slack=False) > _STANDING_EPS
        over.setflags(write=False)
        return cls(known, over, radius)

    def at(self, mask: np.ndarray, z: float) -> Callable[[list[LineString]], np.ndarray]:
        """``cuts(lines) -> (n,) bool``: which of a region's loops (tool axis paths at level ``z`` [mm]) are cut:
        those that pass within the radius of a grid point of the rest material (``mask``, (ny, nx) bool on the
        known stock's grid) or of any stock standing above ``z`` over the part and the allowance.

        A loop off the rest material may still meet stock thinner than the rest threshold: the rim round a rest
        pocket (gallery relief_to_edge: without the outer loop of the bowl T6 rest-roughs, 0.35 mm stood on the
        bowl's rim, deeper than finishing takes). A loop that meets no stock at all changes nothing another loop
        meets, whereas one left out whose stock another loop would take widens that loop's cut. The loop round a
        wall's skin band, a radius and half a cell off the skin's points, meets none of them: that loop is left
        out. So may an open region's outline be, round the stock's side: its entry goes onto a loop cut
        (:func:`open_lead`).

        A grid point's stock stands on its cell (as the rest region is grown from the cells): a loop passing
        within the radius of a cell, off its point by up to the radius and half the cell's diagonal, meets it.
        One tangent to the cells (the region's outline, inside them at its arcs' chords by :data:`_ARC_SAG` of
        the radius) does not. Only the stock within two radii and a cell's diagonal of the rest material's
        points is asked: the loops lie within the radius of its cells."""
        g, radius = self.known.grid, self.radius
        reach = 2.0 * radius + g.cell * math.sqrt(2.0) + _WAIT_TOL
        stock: list[tuple[np.ndarray, cKDTree]] = []  # the stock's points (m, 2) [mm] and their tree, when asked

        def points() -> tuple[np.ndarray, cKDTree]:
            if not stock:
                near = near_cells(mask, reach, g.cell) if mask.any() else mask
                j, i = np.nonzero(near & (mask | (self.over & (self.known.stock_top > z + _STANDING_EPS))))
                xy = np.column_stack([g.x0 + g.cell * i, g.y0 + g.cell * j])
                stock.append((xy, cKDTree(xy)))
            return stock[0]

        def cuts(lines: list[LineString]) -> np.ndarray:
            out = np.zeros(len(lines), dtype=bool)
            if not len(lines) or not len(points()[0]):
                return out
            for n, line in enumerate(lines):
                out[n] = _meets_cells(line, *points(), radius, g.cell)
            return out

        return cuts


def _samples(line: LineString, step: float) -> cKDTree:
    """A k-d tree of ``line``'s points every ``step`` [mm] or closer (its vertices and points between), for
    :func:`_near`: each point of the line lies within half a step of one of them."""
    return cKDTree(shapely.get_coordinates(shapely.segmentize(line, step) if line.length > 0 else line))


def _near(line: LineString, xy: np.ndarray, tree: cKDTree, distance: float, step: float, samples: cKDTree,
          first: bool = False) -> np.ndarray:
    """Indices (ascending) of the points ``xy`` (m, 2) [mm] (``tree``: their k-d tree) within ``distance`` [mm] of
    ``line`` as GEOS decides it (the STRtree's ``dwithin``); ``first``: one such point, if any, found soonest.

    GEOS is asked only about the points that might be: ``samples`` (:func:`_samples`, every ``step`` [mm] or
    closer) lie within half a step of each of the line's points, so a point farther than the distance and half a
    step from all of them is surely not within the distance of the line, and one within the distance of one of
    them surely is. The points near the samples are found from the samples, in the points' tree made once for a
    level's loops (each loop's few hundred samples asked, not the thousands of points round it: issue 35); a
    point-to-sample distance is the same number asked either way round, so the same points are found."""
    near = distance + 0.5 * step + _SURE_TOL
    if first:
        gap, at = tree.query(samples.data, distance_upper_bound=near)
        if np.any(gap <= distance - _SURE_TOL):
            return at[[int(np.argmin(gap))]]
    found = tree.query_ball_point(samples.data, near, return_sorted=False)
    if not any(found):
        return np.zeros(0, dtype=np.int64)
    maybe = np.unique(np.concatenate([np.asarray(f, dtype=np.int64) for f in found]))
    shapely.prepare(line)  # as the STRtree's query prepares it: the same predicate, to the bit
    try:
        return maybe[shapely.dwithin(line, shapely.points(xy[maybe]), distance)]
    finally:
        shapely.destroy_prepared(line)


def _meets_cells(line: LineString, xy: np.ndarray, tree: cKDTree, radius: float, cell: float) -> bool:
    """Whether ``line`` passes within ``radius`` [mm] of a grid point of ``xy`` (m, 2) [mm] (``tree``: their k-d
    tree), or into its cell (a square of ``cell`` [mm] round it) by more than the rest region's chords do
    (:meth:`LoopChoice.at`)."""
    half, step = 0.5 * cell, _SAMPLE_STEP * cell
    samples = _samples(line, step)  # once for both questions
    if len(_near(line, xy, tree, radius, step, samples, first=True)):
        return True
    # off every point by more than the radius: their cells, near a corner
    b = _near(line, xy, tree, radius + half * math.sqrt(2.0), step, samples)
    if not len(b):
        return False
    x, y = xy[b, 0], xy[b, 1]
    cells = shapely.box(x - half, y - half, x + half, y + half)
    return bool(np.any(shapely.distance(line, cells) < radius * (1.0 - _ARC_SAG) - 1e-6))


def rest_targets(rest: Simulation, known: Simulation, levels: np.ndarray, spaces: list[BaseGeometry], radius: float,
                 above: float, allowance: float, tool: Tool) -> tuple[GrownMaskCache, list[np.ndarray], LoopChoice]:
    """For rest machining with ``tool`` of ``radius`` [mm] at ``levels`` [mm]: the rest material's cells grown by
    the radius (remembered per distinct mask), the masks per level (:func:`cadcam.rest.rest_level_masks`, more
    than ``above`` [mm] of excess over ``allowance`` [mm]), and which loops meet stock in ``known``."""
    grown = GrownMaskCache(rest.grid, radius, quad_segs=_QUAD_SEGS)
    masks = rest_level_masks(rest, levels, spaces, radius, above, allowance, tool.full_width_limit, grown)
    return grown, masks, LoopChoice.of(known, allowance, radius)


def open_lead(lines: list[LineString], region: Polygon, side: np.ndarray, normal: np.ndarray
              ) -> tuple[int, np.ndarray] | None:
    """Where an open region's entry from outside the stock goes: ``(index, q)``, the loop of ``lines`` (those cut)
    nearest ``side`` [mm], a point of the region's outline on the stock box grown by the radius, and the point
    ``q`` [mm] on it that a straight lead along the side's outward ``normal`` (unit) meets. None: that lead leaves
    the region.

    The region's outline is the loop through ``side``, unless :class:`LoopChoice` left it out (it goes round the
    stock's side a radius off, through air). The lead then crosses the air it would have swept and stops on the
    loop cut: an entry onto a point off that loop would cut the loop from that point, a chord through the air
    short of its side (op 2's stock round a random block: 1.7 mm of a wall's stock left at its full height, which
    the finishing end mill then met 4.81 mm deep)."""
    at = Point(side)
    j = int(np.argmin(shapely.distance(np.array(lines, dtype=object), at)))
    side = np.asarray(side, dtype=np.float64)
    q = np.asarray(shapely.get_coordinates(shapely.shortest_line(lines[j], at))[0])
    if np.linalg.norm(q - side) <= 1e-9:  # the outline was cut: the lead ends on the side
        return j, side
    start = q + normal * float(np.dot(side - q, normal))  # on the side, straight out from ``q``
    return (j, q) if region.buffer(COVER_TOL).covers(LineString([start, q])) else None


@dataclass(frozen=True)
class LoopOrder:
    """How a region's loops follow each other: ``lines`` the loops (closed, [mm]), ``ks`` their erosion indices,
    ``inside_out`` whether the higher index goes first, ``waits`` per loop the loops it must wait for
    (:meth:`of`)."""

    lines: list[LineString]
    ks: np.ndarray
    inside_out: bool
    waits: list[np.ndarray]

    @classmethod
    def of(cls, lines: list[LineString], ks: np.ndarray, inside_out: bool, diameter: float) -> LoopOrder:
        """Each loop waits for those of a lower erosion index ``ks`` (higher when cutting ``inside_out``) less
        than ``diameter`` [mm] (the tool's) from it, whose sweeps its own may meet."""
        if len(lines) < 2:
            return cls(lines, ks, inside_out, [np.zeros(0, np.int64)] * len(lines))
        a, b = shapely.STRtree(lines).query(lines, predicate="dwithin", distance=diameter + _WAIT_TOL)
        before = ks[b] > ks[a] if inside_out else ks[b] < ks[a]
        a, b = a[before], b[before]
        order = np.argsort(a, kind="stable")
        a, b = a[order], b[order]
        cuts = np.searchsorted(a, np.arange(len(lines) + 1))
        return cls(lines, ks, inside_out, [b[cuts[i]:cuts[i + 1]] for i in range(len(lines))])

    def next(self, uncut: list[int], cut_geom: BaseGeometry, covered: BaseGeometry, here: np.ndarray,
             max_len: float) -> tuple[int, np.ndarray, np.ndarray] | None:
        """The next loop to cut and its link ``(index, src, q)``: from ``src`` [mm] on the loops cut so far
        (``cut_geom``) straight to ``q`` on the loop, inside the region (``covered``).

        Among the loops whose waits are all cut, the one the tool at XY ``here`` [mm] gets to along the shortest
        way (to ``src``, then the link), with a link no longer than ``max_len`` [mm]. Else, as the strict order
        had it, the nearest loop of the next erosion index within ``max_len``, else the nearest of any that a
        straight link reaches (the globally nearest uncut loop is linkable in theory: the segment cannot leave
        the region without crossing a loop that is nearer). None: none can be linked."""
        pending = set(uncut)
        ready = [j for j in uncut if not any(int(i) in pending for i in self.waits[j])]
        link = self._shortest_way(ready, cut_geom, covered, here, max_len) if ready else None
        if link is None:
            ks = self.ks[uncut]
            k_next = ks.max() if self.inside_out else ks.min()
            link = self._nearest(np.array(uncut)[ks == k_next], cut_geom, covered, max_len)
        return self._nearest(np.array(uncut), cut_geom, covered, math.inf) if link is None else link

    def _links(self, cands: list[int] | np.ndarray, cut_geom: BaseGeometry) -> np.ndarray:
        """(m, 2, 2): per candidate loop its nearest point ``q`` and the nearest point ``src`` of the cut [mm]."""
        lines = shapely.shortest_line(np.array([self.lines[j] for j in cands], dtype=object), cut_geom)
        return shapely.get_coordinates(lines).reshape(-1, 2, 2)

    def _shortest_way(self, ready: list[int], cut_geom: BaseGeometry, covered: BaseGeometry, here: np.ndarray,
                      max_len: float) -> tuple[int, np.ndarray, np.ndarray] | None:
        ends = self._links(ready, cut_geom)
        length = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
        way = np.linalg.norm(ends[:, 1] - np.asarray(here, dtype=np.float64)[:2], axis=1) + length
        for i in np.argsort(way, kind="stable"):
            q, src = ends[i, 0], ends[i, 1]
            if length[i] <= max_len and (length[i] < 1e-9 or covered.covers(LineString([src, q]))):
                return ready[i], src, q
        return None

    def _nearest(self, cands: np.ndarray, cut_geom: BaseGeometry, covered: BaseGeometry, max_len: float
                 ) -> tuple[int, np.ndarray, np.ndarray] | None:
        """Nearest candidate loop reachable from the cut by a segment inside the region; within a finite
        ``max_len`` only the nearest one is worth a short link."""
        ends = self._links(cands, cut_geom)
        dist = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
        for i in np.argsort(dist, kind="stable"):
            if dist[i] > max_len:
                return None
            q, src = ends[i, 0], ends[i, 1]
            if dist[i] < 1e-9 or covered.covers(LineString([src, q])):
                return int(cands[i]), src, q
            if math.isfinite(max_len):
                return None
        return None
