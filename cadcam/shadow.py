"""The part's shadow seen from above: where a flat tool's tip cannot come lower than a height.

At height ``z`` the part blocks a tool (a cylinder going up forever from its tip) wherever it has
material at or above ``z``. That XY area is the union of the projections of the part's upward-facing
triangles clipped to ``z' >= z``: exact for any watertight mesh, undercuts included (every vertical
line through the solid leaves it through an upward-facing face), and for a relief's open,
overlapping shells.

The union is the costly part: a general polygon union of tens of thousands of small triangles. Most
of them come from *sheets*, connected up-facing surfaces whose projection covers no point twice (a
heightfield, a solid's top seen from above). Their clipped projections form a polygon coverage (no
overlaps, shared edges match exactly), and dissolving the edges a coverage shares gives its union
at a fraction of the cost (:func:`_dissolved`, which proves the coverage before it trusts the
result). A general union remains only to join the pieces: the triangles wholly above a height
with those it cuts, and sheets that overlap one another (undercuts, a relief's shells).

Shared edges match exactly because each edge's clip point is computed from its ends in a fixed
order, whichever triangle it is taken from, and a corner lying exactly on the height is a corner of
the clipped polygon, not also a crossing. (Computing it per triangle, as before, gave two points an
ulp apart on every cut edge; GEOS's floating-point union then dropped whole triangles now and then,
libgeos/geos#965 and #1344: 1.4 of 3.0 mm^2 on the fixed example in tests/cadcam/test_shadow.py.)
The general unions are snap-rounded to :data:`_GRID`, which is robust.
"""

from __future__ import annotations

import collections
import concurrent.futures
import math
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import shapely
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry

from cadcam.parallel import processors
from factory.core.kept import KeptAnswers, content_key

#: A clipped projection smaller than this is dropped [mm^2]: a triangle seen edge-on.
_MIN_AREA = 1e-12
#: A coverage's union must have the area of its pieces to this fraction (float rounding); an
#: overlap counts twice in the difference (see :func:`_dissolved`).
_AREA_RTOL = 1e-9
#: The grid the general unions snap to [mm]: they move the outline by at most half of it.
_GRID = 1e-9
#: An overlap of two clipped pieces of a slab that proves it no coverage, as a share of the slab's area.
_PROVEN_OVERLAP = 1e3 * _AREA_RTOL
#: Pairs of a triangle and its witness tried per slab (:class:`_Overlaps`).
_TRIED = 16


def part_shadows(part: trimesh.Trimesh, heights: Sequence[float]) -> dict[float, BaseGeometry]:
    """XY shadow of the part's material at or above each height [mm]: where a tool's tip cannot come lower.

    Computed top down, each height adding only the triangles reaching into the slab
    below the previous one, so many heights cost little more than one. Each slab's pieces are
    made in threads (GEOS runs without the interpreter lock) while this thread joins them in
    order: the same calls on the same geometry as one after another, so the same shadows.

    A plan asks for one part's shadows many times (roughing, terraces, each rest tool, the jaws),
    and many of its lists of heights begin alike (a solid's levels all start under its top). Each
    height's shadow depends only on the part and the heights above it in its list, so the heights
    walked once are kept (:class:`_Ladder`) and a later list that begins with the same heights takes
    their shadows and goes on from there: the very geometries it would have made again.
    """
    up = part.face_normals[:, 2] > 1e-9
    tri = np.ascontiguousarray(np.asarray(part.triangles)[up], dtype=np.float64)
    levels = sorted(set(heights), reverse=True)
    ladder = _ladder(tri)
    with ladder.lock:
        node, k = ladder.root, 0
        path: list[_Rung] = []
        while k < len(levels) and levels[k] in node.below:
            node = node.below[levels[k]]
            path.append(node)
            k += 1
        if k < len(levels):
            path += _walk(ladder, node, levels[k - 1] if k else math.inf, levels[k:])
        return {z: rung.shadow for z, rung in zip(levels, path)}


def _walk(ladder: _Ladder, start: _Rung, z_start: float, levels: list[float]) -> list[_Rung]:
    """The rungs of ``levels`` (descending [mm]) below ``start``, the rung of height ``z_start`` (inf: the
    top, nothing above), each made and hung below the one before."""
    zmin, zmax = ladder.zmin, ladder.zmax

    def slab(k: int) -> tuple[BaseGeometry | None, BaseGeometry | None]:
        """The union of the triangles of height ``k``'s slab wholly above it, and of those it cuts (None: none)."""
        z, z_last = levels[k], levels[k - 1] if k else z_start
        if (z, z_last) not in ladder.above:
            ladder.above[z, z_last] = _pieces(ladder, np.flatnonzero((zmin >= z) & (zmin < z_last)), z)
        if z not in ladder.cut:
            ladder.cut[z] = _pieces(ladder, np.flatnonzero((zmax >= z) & (zmin < z)), z)
        return ladder.above[z, z_last], ladder.cut[z]

    # The triangles wholly above the last height, united; each height adds the ones it cuts to a
    # copy. Uniting into the last height's shadow instead would keep every earlier cut's points on
    # straight outline edges: the outline, and each union with it, would grow with every height.
    whole = start.whole
    join = _Join(start.dissolving)
    workers = processors() if len(levels) > 1 else 1
    with concurrent.futures.ThreadPoolExecutor(max_workers=workers, thread_name_prefix="shadow") as pool:
        made: list[tuple[BaseGeometry, bool, BaseGeometry | concurrent.futures.Future]] = []
        for above, cut in _in_order(slab, len(levels), pool if workers > 1 else None, 2 * workers):
            if above is not None:
                whole = join(whole, above)
            if cut is None:
                shadow: BaseGeometry | concurrent.futures.Future = whole
            elif join.dissolving or workers == 1:
                shadow = join(whole, cut)
            else:  # no state left to change: this height's union is on its own
                shadow = pool.submit(_joined, whole, cut)
            made.append((whole, join.dissolving, shadow))
    rungs, node = [], start
    for z, (whole, dissolving, shadow) in zip(levels, made):
        node = node.below.setdefault(z, _Rung(whole, dissolving, shadow.result() if isinstance(
            shadow, concurrent.futures.Future) else shadow))
        rungs.append(node)
    return rungs


def _pieces(ladder: _Ladder, sel: np.ndarray, z: float) -> BaseGeometry | None:
    """The union of the projections of the ladder's triangles ``sel`` (k,) int clipped to ``z' >= z`` [mm]
    (None: no piece is left). Each triangle's piece depends on it and ``z`` alone, so the slab of
    heights ``z``..``z_last`` splits into those wholly above ``z`` (the same for any list with those two
    heights next to each other) and those ``z`` cuts (the same for any list with ``z``)."""
    polys, kept = _clip_projections(ladder.tri[sel], z)
    if not len(polys):
        return None
    proven = ladder.overlaps.proven(polys, sel[kept])
    union = None if proven else _dissolved(polys)
    if union is None:  # the slab's sheets overlap: dissolve each sheet on its own
        if not proven:
            ladder.overlaps.refused()
        union = _by_sheet(polys, ladder.sheets()[sel[kept]])
    return union


@dataclass
class _Rung:
    """One height of a list walked top down, and what the heights above it and it left."""

    whole: BaseGeometry  #: the union of the triangles wholly above this height
    dissolving: bool  #: whether the joins so far still dissolve (:class:`_Join`)
    shadow: BaseGeometry  #: the part's shadow at this height
    below: dict[float, _Rung] = field(default_factory=dict)  #: the next height down of each list walked


@dataclass
class _Ladder:
    """The heights walked on one part's upward triangles ``tri`` (m, 3, 3) [mm], from the top (``root``)."""

    tri: np.ndarray
    zmin: np.ndarray
    zmax: np.ndarray
    sheets: _Sheets
    overlaps: _Overlaps
    root: _Rung
    #: The union of the triangles wholly within ``z``..``z_last``, by (z, z_last) [mm] (None: none).
    above: dict[tuple[float, float], BaseGeometry | None] = field(default_factory=dict)
    #: The union of the triangles ``z`` cuts, clipped to it, by z [mm] (None: none).
    cut: dict[float, BaseGeometry | None] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)


#: The last few parts' ladders by their triangles' digest: a plan's op 1 and op 2 parts, no more.
_LADDERS: KeptAnswers[bytes, _Ladder] = KeptAnswers(kept=2)


def _ladder(tri: np.ndarray) -> _Ladder:
    """The ladder of the part whose upward triangles are ``tri`` (m, 3, 3) [mm], a new one if none is kept."""

    def made() -> _Ladder:
        held = tri.copy()
        held.setflags(write=False)
        zs = held[:, :, 2]
        sheets = _Sheets(held)
        return _Ladder(held, zs.min(axis=1), zs.max(axis=1), sheets, _Overlaps(held, sheets),
                       _Rung(Polygon(), True, Polygon()))

    return _LADDERS.get(content_key(tri), made)


def _in_order(fn: Callable[[int], Any], n: int, pool: concurrent.futures.Executor | None, ahead: int
              ) -> Iterator[Any]:
    """``fn(0), fn(1), ... fn(n - 1)`` in order, worked out up to ``ahead`` calls ahead in ``pool`` (None: here,
    one by one). ``fn`` must depend on nothing another call changes."""
    if pool is None:
        yield from (fn(k) for k in range(n))
        return
    pending = collections.deque(pool.submit(fn, k) for k in range(min(n, ahead)))
    try:
        for k in range(n):
            result = pending.popleft().result()
            if k + ahead < n:
                pending.append(pool.submit(fn, k + ahead))
            yield result
    finally:
        for f in pending:
            f.cancel()


class _Sheets:
    """``sheets()``: :func:`_sheets` of ``tri``, worked out on first call (once, whichever thread asks)."""

    def __init__(self, tri: np.ndarray) -> None:
        self._tri = tri
        self._sheet: np.ndarray | None = None
        self._lock = threading.Lock()

    def __call__(self) -> np.ndarray:
        with self._lock:
            if self._sheet is None:
                self._sheet = _sheets(self._tri)
            return self._sheet


class _Overlaps:
    """``proven(polys, tri)``: whether the clipped projections ``polys`` (k,) of the ladder's triangles ``tri``
    (k,) int surely do not form a coverage, so that :func:`_dissolved` would refuse them.

    A relief's shells overlap in every slab that reaches their common strips, and finding that out by a
    coverage union of the whole slab cost 13 % of its shadows (issue 35). Once a slab was refused
    (:meth:`refused`), each triangle gets a witness: a triangle of another sheet whose projection holds its
    centroid. A slab holding a triangle and its witness is refused when their clipped pieces overlap by more
    than :data:`_PROVEN_OVERLAP` of the slab's area, a thousand times :data:`_AREA_RTOL`, the share over which
    :func:`_dissolved`'s area check refuses a union (an overlap counts twice there). Anything less proves
    nothing, and the coverage is tried as before: the same union either way.
    """

    def __init__(self, tri: np.ndarray, sheets: _Sheets) -> None:
        self._tri, self._sheets = tri, sheets
        self._witness: np.ndarray | None = None  # (m,) int, -1: none; None: no slab refused yet
        self._lock = threading.Lock()

    def refused(self) -> None:
        """A slab of sheets was refused: from now on look for witnesses."""
        with self._lock:
            if self._witness is None:
                sheet = self._sheets()
                xy = shapely.polygons(self._tri[:, :, :2])
                i, j = shapely.STRtree(xy).query(shapely.points(self._tri[:, :, :2].mean(axis=1)), predicate="within")
                other = sheet[i] != sheet[j]
                witness = np.full(len(sheet), -1, dtype=np.int64)
                witness[i[other]] = j[other]
                self._witness = witness

    def proven(self, polys: np.ndarray, tri: np.ndarray) -> bool:
        if self._witness is None or len(polys) < 2:
            return False
        at = np.full(len(self._tri), -1, dtype=np.int64)
        at[tri] = np.arange(len(tri))
        witness = self._witness[tri]
        mine = np.flatnonzero((witness >= 0) & (at[np.maximum(witness, 0)] >= 0))[:_TRIED]
        if not len(mine):
            return False
        lap = shapely.area(shapely.intersection(polys[mine], polys[at[witness[mine]]]))
        return bool(lap.max() > _PROVEN_OVERLAP * float(shapely.area(polys).sum()))


class _Join:
    """``join(a, b)``: the union of two pieces made of different triangles. While the pieces so far
    formed coverages (one sheet, or sheets that do not overlap) it dissolves them; after the first
    that did not (sheets overlap), the general union. ``dissolving``: whether the joins so far did."""

    def __init__(self, dissolving: bool = True) -> None:
        self.dissolving = dissolving

    def __call__(self, a: BaseGeometry, b: BaseGeometry) -> BaseGeometry:
        if self.dissolving and not (a.is_empty or b.is_empty):
            union = _dissolved(np.array([a, b], dtype=object))
            if union is not None:
                return union
            self.dissolving = False
        return _joined(a, b)


def _joined(a: BaseGeometry, b: BaseGeometry) -> BaseGeometry:
    """The general union of two pieces (either alone if the other is empty)."""
    if a.is_empty or b.is_empty:
        return b if a.is_empty else a
    return _union([a, b])


def _union(geoms) -> BaseGeometry:
    """The union of ``geoms`` snap-rounded to :data:`_GRID`."""
    return shapely.union_all([g for g in geoms if not g.is_empty], grid_size=_GRID)


def _by_sheet(polys: np.ndarray, sheet: np.ndarray) -> BaseGeometry:
    """The union of ``polys`` (k,), each sheet's dissolved on its own (``sheet`` (k,) int), then joined."""
    order = np.argsort(sheet, kind="stable")
    groups = np.split(order, np.flatnonzero(np.diff(sheet[order])) + 1)
    return _union([_dissolved(polys[g]) or _union(polys[g]) for g in groups])


def _sheets(tri: np.ndarray) -> np.ndarray:
    """The sheet (connected surface) of each triangle of ``tri`` (m, 3, 3), joined across shared edges: (m,) int.

    Edges are matched by their ends' coordinates, so a mesh whose vertices were never merged
    still joins.
    """
    m = len(tri)
    a, b = tri.reshape(-1, 3), np.roll(tri, -1, axis=1).reshape(-1, 3)
    _, edge = np.unique(_keys(a, b), return_inverse=True)
    # triangles and edges as nodes of one graph; a triangle is linked to its three edges
    graph = coo_matrix((np.ones(3 * m, dtype=np.int8), (np.repeat(np.arange(m), 3), m + edge.ravel())),
                       shape=(m + int(edge.max()) + 1,) * 2)
    return connected_components(graph, directed=False)[1][:m]


def _before(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether each point of ``a`` comes before the one of ``b`` in lexicographic order. (n, d) -> (n,) bool."""
    first = np.zeros(len(a), dtype=bool)
    tied = np.ones(len(a), dtype=bool)
    for k in range(a.shape[1]):
        first |= tied & (a[:, k] < b[:, k])
        tied &= a[:, k] == b[:, k]
    return first


def _keys(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """One hashable key per segment ``a``-``b`` (n, d), the same for ``b``-``a``: (n,) void."""
    ends = np.where(_before(a, b)[:, None], np.hstack([a, b]), np.hstack([b, a]))
    ends = np.ascontiguousarray(ends + 0.0)  # -0.0 and 0.0 alike
    return ends.view(np.dtype((np.void, ends.dtype.itemsize * ends.shape[1]))).ravel()


def _clip_projections(tri: np.ndarray, z: float) -> tuple[np.ndarray, np.ndarray]:
    """XY projections of triangles clipped to ``z' >= z``, as shapely polygons, and which triangles gave them.

    tri : (m, 3, 3) float, each triangle reaching at least up to ``z``. Returns (k,) polygons
    and the (k,) int indices into ``tri`` of their triangles (the ones not clipped away entirely
    or to less than ``_MIN_AREA``).
    """
    m = len(tri)
    a = tri
    b = np.roll(tri, -1, axis=1)
    ha, hb = a[:, :, 2], b[:, :, 2]
    above_a = ha >= z
    cross = ((ha > z) & (hb < z)) | ((ha < z) & (hb > z))  # a corner on the height is no crossing
    # the crossing from the edge's first end in (x, y, z) order: the same point from both triangles
    first = _before(a.reshape(-1, 3), b.reshape(-1, 3)).reshape(m, 3)
    lo = np.where(first[..., None], a, b)
    hi = np.where(first[..., None], b, a)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(cross, (z - lo[:, :, 2]) / np.where(cross, hi[:, :, 2] - lo[:, :, 2], 1.0), 0.0)
    x = lo[:, :, :2] + t[..., None] * (hi[:, :, :2] - lo[:, :, :2])
    cand = np.stack([a[:, :, :2], x], axis=2).reshape(m, 6, 2)
    valid = np.stack([above_a, cross], axis=2).reshape(m, 6)
    counts = valid.sum(axis=1)
    keep = np.flatnonzero(counts >= 3)
    if not len(keep):
        return np.empty(0, dtype=object), keep
    coords = cand[keep][valid[keep]]
    idx = np.repeat(np.arange(len(keep)), counts[keep])
    polys = shapely.polygons(shapely.linearrings(coords, indices=idx))
    big = shapely.area(polys) > _MIN_AREA
    return polys[big], keep[big]


def _segments(geoms, by_part: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The segments of the polygons ``geoms``, each with its polygon on its left: start (n, 2), end (n, 2)
    and which ring (n,) int; zero-length ones left out. ``by_part``: take every part's rings as geometries of
    their own, as any geometry needs; else Polygons without holes (the clipped triangles) are read directly,
    each its one ring (making the parts and rings first was most of a coverage proof's time, issue 35)."""
    geoms = np.asarray(geoms, dtype=object)
    if not by_part and (shapely.get_type_id(geoms) == shapely.GeometryType.POLYGON).all() \
            and not shapely.get_num_interior_rings(geoms).any():
        shell = np.ones(len(geoms), dtype=bool)
        xy, ring = shapely.get_coordinates(geoms, return_index=True)
    else:
        parts = shapely.get_parts(geoms)
        holes = shapely.get_num_interior_rings(parts)
        shell = np.ones(len(parts) + int(holes.sum()), dtype=bool)  # get_rings: each part's shell, then its holes
        shell[1:] = False
        shell[np.cumsum(holes[:-1] + 1)] = True
        xy, ring = shapely.get_coordinates(shapely.get_rings(parts), return_index=True)
    same = ring[1:] == ring[:-1]  # each ring is closed: its last point repeats its first
    a, b, r = xy[:-1][same], xy[1:][same], ring[:-1][same]
    real = (a != b).any(axis=1)
    a, b, r = a[real], b[real], r[real]
    # a shell turning clockwise, or a hole turning counter-clockwise, has its polygon on its right
    turn = np.bincount(r, weights=a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], minlength=len(shell))
    flip = ((turn > 0) != shell)[r]
    return np.where(flip[:, None], b, a), np.where(flip[:, None], a, b), r


def _dissolved(polys: np.ndarray) -> BaseGeometry | None:
    """The union of polygons ``polys`` (k,) that form a coverage, or None if they do not.

    The coverage union only dissolves the edges two polygons share, so it is checked. Let ``d`` count
    the polygons over a point: crossing a segment changes it by the segment's signed multiplicity
    (+1 for each polygon on its left). The union ``P`` is kept if every multiplicity is -1, 0 or 1,
    ``P`` is valid and its boundary is exactly the segments of multiplicity +-1, and its area is the
    sum of the polygons'. Then ``d`` and ``P``'s indicator change together across every boundary
    segment, so ``d`` - ``1_P`` is even everywhere and nowhere negative; equal integrals make it zero:
    no overlap, and ``P`` is the union.
    """
    if len(polys) == 1:
        return polys[0]
    a, b, _ = _segments(polys)
    sign = np.where(_before(a, b), 1, -1)
    edges, edge = np.unique(_keys(a, b), return_inverse=True)
    mult = np.bincount(edge.ravel(), weights=sign, minlength=len(edges))
    if (np.abs(mult) > 1).any():
        return None  # two polygons on the same side of a segment: they overlap
    try:
        union = shapely.coverage_union_all(polys)
    except shapely.errors.GEOSException:
        return None
    total = float(shapely.area(polys).sum())
    if abs(union.area - total) > _AREA_RTOL * total or not union.is_valid:
        return None
    ua, ub, _ = _segments([union])
    outline = np.unique(_keys(ua, ub))
    boundary = edges[mult != 0]
    if len(outline) != len(ua) or len(outline) != len(boundary) or (outline != boundary).any():
        return None
    return union
