"""The moves of a z-level roughing as they are emitted (:class:`LevelPath`), and the links of a level that stay
down on the paths it has cut (:class:`CutPaths`).

Z-level roughing (:mod:`cadcam.roughing`) goes from one loop of a region to the next by a short link where one
reaches; otherwise the tool lifts to the clearance height, rapids over the next loop's link and comes down
again. On a plate round bosses most links are of the second kind: the corners of stock the loops leave lie
apart, one to each side of the part, and every one of them costs a lift out of the level and back.

Every path a level has cut is clear at that level: the tool swept the stock over it, down to the level, for a
radius all round, and its centre kept off the part. So the tool may go from the end of one loop to the start of
the next *along* those paths, at the level, feeding through what it has cleared: the issue's "links that stay
down inside cleared regions". It does where that is quicker by the program's clock: the way fed at the air feed
(the machine's feed that :mod:`cadcam.chipfeed` gives moves that cut nothing) against the lift, the rapid across
and the way back down at :class:`cadcam.post.PostOptions`' rapid rate (:func:`down_budget`, which the deep cuts'
links round the stock through the air, :func:`round_the_box`, are held to as well). All lengths in millimetres.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from shapely.geometry import LineString, Point, Polygon
from shapely.ops import substring

from cadcam.model import Motion
from cadcam.post import PostOptions

#: Points this close are the same node of the cut paths [mm]; a link's start found on a loop by shapely lies
#: on it to rounding.
NODE_TOL = 1e-6
#: A move shorter than this goes nowhere and is not emitted [mm].
SAME_POINT = 1e-9


class LevelPath:
    """The moves of an operation as they are emitted.

    ``link_height(a, b)``, given, is the lowest tip height [mm] at which the tool may rapid straight from
    XY ``a`` to ``b`` clear of the stock known to be there (inf: not at all); links then lift only that
    high plus ``lead_gap``, not to the clearance height (:meth:`go_to`). The methods' ``p`` is the roughing's
    parameters (``cadcam.roughing._Params``: its clearance height, lead gap [mm])."""

    def __init__(self, link_height: Callable[[np.ndarray, np.ndarray], float] | None = None) -> None:
        self.points: list[np.ndarray] = []
        self.motion: list[int] = []
        self.link_height = link_height

    def add(self, xyz, kind: Motion) -> None:
        """A move to ``xyz`` [mm], unless the tool is there already (within :data:`SAME_POINT`)."""
        q = np.asarray(xyz, dtype=np.float64)
        if self.points and np.linalg.norm(self.points[-1] - q) < SAME_POINT:
            return
        self.points.append(q)
        self.motion.append(int(kind))

    def add_many(self, xyz: np.ndarray, kind: Motion | np.ndarray) -> None:
        """Moves to each point of ``xyz`` (n, 3) [mm] in turn as :meth:`add` makes them, of ``kind`` (one, or (n,)
        ints of :class:`cadcam.model.Motion`). A loop or a piece is thousands of points: a run of points each
        more than twice :data:`SAME_POINT` from the one before, the first one's predecessor the last point kept,
        goes in at once (none of it is skipped, whatever the rounding of the distance); the others one by one,
        until one is kept. (A ring begins where the tool stands: its first point alone used to send all of its
        points one by one, a sixth of the terraces' processor time on the relief, issue 35.)"""
        xyz = np.asarray(xyz, dtype=np.float64)
        kinds = np.broadcast_to(np.asarray(kind, dtype=np.int64), (len(xyz),))
        n = len(xyz)
        if not n:
            return
        step = np.diff(np.vstack([self.points[-1] if self.points else np.full(3, np.inf), xyz]), axis=0)
        close = np.flatnonzero(np.sqrt(np.einsum("ij,ij->i", step, step)) < 2.0 * SAME_POINT).tolist() + [n]
        i, c = 0, 0  # the next point; close[c] the next point near the one before it
        while i < n:
            while close[c] < i:
                c += 1
            if close[c] > i:  # points i.. up to the next close one: the last kept is point i - 1
                self.points.extend(xyz[i:close[c]])
                self.motion.extend(kinds[i:close[c]].tolist())
                i = close[c]
                continue
            kept = len(self.points)
            self.add(xyz[i], Motion(int(kinds[i])))
            i += 1
            while i < n and len(self.points) == kept:  # skipped: the last kept is no longer point i - 1
                self.add(xyz[i], Motion(int(kinds[i])))
                i += 1

    @property
    def here(self) -> np.ndarray:
        return self.points[-1]

    def go_to(self, xy, p) -> None:
        """Retract to clearance height and rapid over ``xy``; with ``link_height``, from below the clearance
        height, lift only ``lead_gap`` over the known stock along the straight way there (not lower than
        the tool is), and rapid across at that height: in rest machining most links run over stock
        already cleared, and a lift to the clearance and back costs more than the way across."""
        cur = self.here
        if self.link_height is not None and cur[2] < p.clear_z - 1e-9:
            low = max(float(cur[2]), self.link_height(cur[:2], np.asarray(xy, dtype=np.float64)) + p.lead_gap)
            if low < p.clear_z - 1e-9:
                self.add([cur[0], cur[1], low], Motion.RAPID)
                self.add([xy[0], xy[1], low], Motion.RAPID)
                return
        if cur[2] < p.clear_z - 1e-9:
            self.add([cur[0], cur[1], p.clear_z], Motion.RAPID)
        elif cur[2] > p.clear_z + 1e-9 and np.linalg.norm(cur[:2] - np.asarray(xy)) > 1e-9:
            # Leaving the start height: drop to the clearance plane first.
            self.add([cur[0], cur[1], p.clear_z], Motion.RAPID)
        self.add([xy[0], xy[1], p.clear_z], Motion.RAPID)

    def descend(self, xyz, air_z: float, p) -> None:
        """Go straight down to ``xyz``: by rapid to ``lead_gap`` above ``air_z``, then at plunge feed.

        ``air_z`` is the lowest height known to be clear under the whole tool here: every
        tool centre of a level lies inside the previous level's region, which was cleared
        to within R of every point (gap loops where the stepover is wider than R, ``roughing._gap_rings``),
        so everything within R of it is cut down to that level's floor.
        """
        cur = self.here
        rapid_to = air_z + p.lead_gap
        if rapid_to < cur[2] - 1e-9 and rapid_to > xyz[2] + 1e-9:
            self.add([cur[0], cur[1], rapid_to], Motion.RAPID)
        self.add(xyz, Motion.PLUNGE)

    def link_to(self, xy: np.ndarray, z: float, cut: CutPaths | None, air_feed: float | None, p) -> None:
        """From the end of a loop, down at ``z`` [mm], to ``xy`` on the paths cut at this level: along them at
        ``z`` where that is quicker (:meth:`CutPaths.stays_down`, ``air_feed`` [mm/min]; None: never), else
        lifted to the clearance height and down again there (air: the path was cut)."""
        way = cut.stays_down(self.here, xy, air_feed, p.clear_z, p.lead_gap) if cut is not None and air_feed else None
        if way is not None:
            self.add_many(np.column_stack([way[1:], np.full(len(way) - 1, z)]), Motion.CUT)
            return
        self.go_to(xy, p)
        self.descend([*xy, z], z, p)


class CutPaths:
    """The tool-centre paths one region has cut at its level so far [mm], as a graph: the loops and the links
    between them, each (n, 2). The tool's disc anywhere on them meets no stock at or over the level, nor the
    part: the way along them from one point of them to another is air (:meth:`way`)."""

    def __init__(self) -> None:
        self._lines: list[np.ndarray] = []

    def add(self, xy: np.ndarray) -> None:
        """A path the tool has cut at the level, (n, 2) [mm]."""
        xy = np.asarray(xy, dtype=np.float64)[:, :2]
        if len(xy) >= 2:
            self._lines.append(xy)

    def way(self, a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
        """The corners (k, 2) [mm] of the shortest way along the cut paths from XY ``a`` to ``b``, both on them
        (within :data:`NODE_TOL`), ``a`` first and ``b`` last; None where either is off them or no way joins
        them. A link's start lies on a loop, not always at one of its corners: the paths are joined where an
        end of one lies on another."""
        if not self._lines:
            return None
        a, b = np.asarray(a, dtype=np.float64)[:2], np.asarray(b, dtype=np.float64)[:2]
        seg = np.concatenate([np.stack([q[:-1], q[1:]], axis=1) for q in self._lines])  # (m, 2, 2)
        first = np.cumsum([0] + [len(q) - 1 for q in self._lines])  # each path's first segment
        ends = np.concatenate([[q[0] for q in self._lines], [q[-1] for q in self._lines], [a, b]])
        # every segment split at the ends that lie on it (a link's start on a loop; a and b): the graph's edges
        # run between the split points. Only the paths an end lies on are searched for the segment.
        tree = shapely.STRtree([LineString(q) for q in self._lines])
        e_at, line_at = tree.query(shapely.points(ends), predicate="dwithin", distance=NODE_TOL)
        m = len(seg)
        splits: list[list[tuple[float, int]]] = [[] for _ in range(m)]
        extra: list[np.ndarray] = []
        for e, li in zip(e_at, line_at):
            s = np.arange(first[li], first[li + 1])
            d = seg[s, 1] - seg[s, 0]
            dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
            t = np.clip(np.einsum("ij,ij->i", ends[e] - seg[s, 0], d) / dd, 0.0, 1.0)
            off = np.linalg.norm(seg[s, 0] + t[:, None] * d - ends[e], axis=1)
            for k in np.flatnonzero((off <= NODE_TOL) & (t > 0.0) & (t < 1.0)):
                splits[s[k]].append((float(t[k]), 2 * m + len(extra)))
                extra.append(ends[e])
        points = np.concatenate([seg[:, 0], seg[:, 1], np.array(extra).reshape(-1, 2), [a, b]])
        # points closer than the tolerance are one node
        _, node = np.unique(np.round(points / NODE_TOL).astype(np.int64), axis=0, return_inverse=True)
        node = node.ravel()
        whole = np.array([not q for q in splits])
        src, dst = list(np.flatnonzero(whole)), list(np.flatnonzero(whole) + m)
        for s in np.flatnonzero(~whole):
            chain = [s] + [i for _, i in sorted(splits[s])] + [m + s]
            src += chain[:-1]
            dst += chain[1:]
        src, dst = np.array(src, dtype=np.int64), np.array(dst, dtype=np.int64)
        src_n, dst_n = node[src], node[dst]
        w = np.linalg.norm(points[src] - points[dst], axis=1)
        n = int(node.max()) + 1
        ia, ib = node[len(points) - 2], node[len(points) - 1]
        if ia == ib:
            return np.array([a, b])
        graph = coo_matrix((np.r_[w, w] + 1e-12, (np.r_[src_n, dst_n], np.r_[dst_n, src_n])), shape=(n, n)).tocsr()
        dist, prev = dijkstra(graph, indices=int(ia), return_predecessors=True)
        if not np.isfinite(dist[ib]):
            return None
        # a and b must lie on the paths: a node of theirs with an edge (a point off them is a node alone)
        if graph[ia].nnz == 0 or graph[ib].nnz == 0:
            return None
        where = np.zeros((n, 2))
        where[node] = points
        chain = [int(ib)]
        while chain[-1] != ia:
            chain.append(int(prev[chain[-1]]))
        corners = where[chain[::-1]]
        corners[0], corners[-1] = a, b
        return corners

    def stays_down(self, here: np.ndarray, xy: np.ndarray, air_feed: float, clear_z: float, lead_gap: float
                   ) -> np.ndarray | None:
        """The way (k, 2) [mm] from the tool at ``here`` (x, y, z) [mm] to XY ``xy`` along the cut paths at its
        height, where it takes no longer fed at ``air_feed`` [mm/min] than the lift to ``clear_z`` [mm], the
        rapid across and the rapid back down to ``lead_gap`` [mm] over the level by the program's clock
        (:class:`cadcam.post.PostOptions`); else None."""
        way = self.way(here[:2], xy)
        if way is None:
            return None
        length = float(np.linalg.norm(np.diff(way, axis=0), axis=1).sum())
        rise = max(0.0, clear_z - float(here[2]))
        lift = float(np.linalg.norm(np.asarray(xy) - here[:2])) + 2.0 * rise - lead_gap
        return way if length <= down_budget(lift, air_feed) else None


def down_budget(lift: float, air_feed: float | None) -> float:
    """The longest way [mm] that, fed at ``air_feed`` [mm/min], takes no longer than ``lift`` [mm] of rapids (up,
    across and down again) by the program's clock (:class:`cadcam.post.PostOptions`' rapid rate); ``air_feed``
    None: ``lift`` itself."""
    return lift if not air_feed else lift * air_feed / PostOptions().rapid_rate


def round_the_box(a: np.ndarray, b: np.ndarray, box: Polygon, most: float) -> np.ndarray | None:
    """The corners (k, 2) [mm] of the shorter way from XY ``a`` to ``b`` along the outline of ``box`` (the stock grown
    by the tool radius and the air gap: the tool's disc anywhere on or outside it is clear of the stock, at any
    depth above the floor), with ``a`` and ``b`` going straight to their nearest points of it, where that is no
    longer than ``most`` [mm]; else None."""
    ring = box.exterior
    total = ring.length
    twice = LineString(np.vstack([np.asarray(ring.coords)[:-1]] * 2 + [ring.coords[0]]))
    sa, sb = ring.project(Point(a)), ring.project(Point(b))
    ways = [shapely.get_coordinates(substring(twice, sa, sa + (sb - sa) % total)),
            shapely.get_coordinates(substring(twice, sb, sb + (sa - sb) % total))[::-1]]
    best = min(ways, key=lambda w: LineString(np.vstack([a, w, b])).length)
    return best if LineString(np.vstack([a, best, b])).length <= most else None


def round_the_stock(loops: list[LineString], axis_box: tuple[float, float, float, float], radius: float
                    ) -> np.ndarray:
    """(n,) bool: each of ``loops`` (tool centres [mm]) keeps a tool of ``radius`` [mm] off the stock all along:
    no point of it nearer the stock box than the radius (less rounding). ``axis_box``: (x0, y0, x1, y1) [mm], the
    stock box grown by the radius (where z-level roughing's axis roams, ``cadcam.roughing._axis_rect``).

    Roughing from the block, a region's outer loop is that grown box: its disc only touches the stock's sides
    and cuts nothing, yet it was cut on every level (fed through the air). Such a loop is air."""
    if not loops:
        return np.zeros(0, bool)
    x0, y0, x1, y1 = axis_box
    stock = shapely.box(x0 + radius, y0 + radius, x1 - radius, y1 - radius)
    return shapely.distance(np.array(loops, dtype=object), stock) >= radius - NODE_TOL
