"""Regular XY grids over the stock and the part's upper envelope sampled on them.

A 3-axis cutter only ever sees the part from above, so both the material-removal
simulation and the gouge check work on *heightfields* (z-maps): one height per grid
point. :func:`upper_envelope` samples the highest part surface exactly at the grid
points (no cell averaging), so comparing it with a simulated stock surface sampled at the
same points never reports a gouge that is an artefact of the grid.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from factory.core.errors import MeshError, SetupError
from factory.core.kept import KeptAnswers, content_key

log = logging.getLogger(__name__)

#: Distance within which a grid point counts as lying on a triangle's edge [mm]. Points on
#: an edge shared by two triangles must be claimed by at least one of them.
EDGE_TOLERANCE = 1e-7

#: Grid point / triangle pairs evaluated per vectorised batch (bounds peak memory).
_PAIR_BUDGET = 1 << 21
#: Above this many grid points per triangle's box (on average over a batch) a triangle is rasterised row by
#: row over the span it covers (:func:`_row_spans`), below it over its box: a fine mesh's triangles cover
#: a few points each, where working out the spans costs more than it saves (relief: 0.08 -> 0.10 s).
_SPAN_POINTS = 16

#: The last upper envelopes computed, by the triangles' content and the grid: one plan rasterises the
#: same part on the same grid for choosing tools, the stock models, the rapid check, verify and op 2's
#: model and verify. Keyed by content, not passed along, because those are five modules' calls.
#: At most :data:`_ENVELOPES_KEPT_BYTES` of them (the oldest go first); a larger grid than half of it is not kept.
_ENVELOPES_KEPT_BYTES = 64 << 20
_ENVELOPES: KeptAnswers[tuple[bytes, Grid], np.ndarray] = KeptAnswers(kept_bytes=_ENVELOPES_KEPT_BYTES,
                                                                      size=lambda top: top.nbytes)


@dataclass(frozen=True)
class Grid:
    """A regular grid of sample points in the XY plane.

    Point ``(i, j)`` (column ``i``, row ``j``) sits at ``(x0 + i * cell, y0 + j * cell)``.
    Arrays sampled on the grid have shape ``(ny, nx)``: row index = y.

    Attributes
    ----------
    x0, y0 : float
        Position of the first grid point [mm].
    cell : float
        Spacing between neighbouring points in X and Y [mm].
    nx, ny : int
        Number of points along X and Y.
    """

    x0: float
    y0: float
    cell: float
    nx: int
    ny: int

    @property
    def xs(self) -> np.ndarray:
        """(nx,) float X of each grid column [mm]."""
        return self.x0 + self.cell * np.arange(self.nx, dtype=np.float64)

    @property
    def ys(self) -> np.ndarray:
        """(ny,) float Y of each grid row [mm]."""
        return self.y0 + self.cell * np.arange(self.ny, dtype=np.float64)

    @property
    def shape(self) -> tuple[int, int]:
        """``(ny, nx)``: the shape of arrays sampled on this grid."""
        return (self.ny, self.nx)

    @property
    def size(self) -> int:
        """Number of grid points."""
        return self.nx * self.ny

    def column_range(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First and last column whose X lies in ``[lo, hi]``, clipped to the grid.

        Parameters
        ----------
        lo, hi : (k,) float
            X interval per query [mm].

        Returns
        -------
        first, last : (k,) int64
            ``last < first`` where no column falls in the interval.
        """
        return _index_range(lo, hi, self.x0, self.cell, self.nx)

    def row_range(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First and last row whose Y lies in ``[lo, hi]``, clipped to the grid (see :meth:`column_range`)."""
        return _index_range(lo, hi, self.y0, self.cell, self.ny)


def _index_range(lo: np.ndarray, hi: np.ndarray, origin: float, cell: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    # The 1e-9 slack keeps a point that sits exactly on the interval's end inside it
    # despite rounding in (lo - origin) / cell.
    first = np.ceil((np.asarray(lo) - origin) / cell - 1e-9)
    last = np.floor((np.asarray(hi) - origin) / cell + 1e-9)
    first = np.clip(first, 0, n).astype(np.int64)
    last = np.clip(last, -1, n - 1).astype(np.int64)
    return first, last


def grid_over(stock_min: np.ndarray, stock_max: np.ndarray, cell: float) -> Grid:
    """The grid of cell centres covering the stock's XY footprint.

    Points are spaced ``cell`` apart and centred in the footprint, so every point lies
    strictly inside the stock (a part wall flush with the stock side is never sampled
    right on the wall). When the footprint is not a whole number of cells the margins
    grow symmetrically, each staying below one cell.

    Parameters
    ----------
    stock_min, stock_max : (3,) float
        Stock box corners [mm].
    cell : float
        Grid spacing [mm], > 0.

    Raises
    ------
    SetupError
        If the cell is not positive and finite or the stock footprint is empty.
    """
    lo = np.asarray(stock_min, dtype=np.float64).reshape(-1)[:2]
    hi = np.asarray(stock_max, dtype=np.float64).reshape(-1)[:2]
    if not (math.isfinite(cell) and cell > 0):
        raise SetupError(f"grid cell must be a positive number of mm, got {cell}", source="cell")
    size = hi - lo
    if not (np.all(np.isfinite(size)) and np.all(size > 0)):
        raise SetupError(f"stock footprint is empty: min {lo.tolist()}, max {hi.tolist()}", source="stock")
    n = np.maximum(np.ceil(size / cell - 1e-9), 1).astype(np.int64)
    origin = lo + (size - (n - 1) * cell) / 2
    return Grid(x0=float(origin[0]), y0=float(origin[1]), cell=float(cell), nx=int(n[0]), ny=int(n[1]))


def upper_envelope(triangles: np.ndarray, grid: Grid) -> np.ndarray:
    """Highest surface z of a triangle soup above each grid point.

    Each triangle's XY projection is rasterised onto the grid points it covers, with the
    z of the triangle's plane at the point. A point within :data:`EDGE_TOLERANCE` of an
    edge counts as covered, so a point on an edge shared by two triangles is never missed.
    Vertical (and nearly vertical) triangles project to a segment: points on it get the
    highest z of the triangle above them.

    Parameters
    ----------
    triangles : (m, 3, 3) float
        Triangle corners [mm], e.g. ``mesh.triangles`` of a part in work coordinates.
        Orientation and watertightness do not matter.
    grid : Grid

    Returns
    -------
    (ny, nx) float
        Highest z at each grid point [mm]; ``-inf`` where no triangle covers the point
        (outside the part, inside through holes). Read-only: the same triangles on the same
        grid give the same array again (the last ones are kept, :data:`_ENVELOPES`).

    Raises
    ------
    MeshError
        If ``triangles`` is not ``(m, 3, 3)`` or holds non-finite values.
    """
    tri = _checked(triangles)

    def made() -> np.ndarray:
        top = _rasterised(tri, grid)
        top.setflags(write=False)
        return top

    if grid.size * 8 > _ENVELOPES_KEPT_BYTES // 2:
        return made()
    return _ENVELOPES.get((content_key(tri), grid), made)


def upper_envelope_at(triangles: np.ndarray, grid: Grid, cells: np.ndarray, tile: int = 8) -> np.ndarray:
    """:func:`upper_envelope` at some of the grid's points only: ``(k,)`` heights [mm] at the flat
    (row-major) indices ``cells``, the very values the whole envelope holds there.

    Only the ``tile`` x ``tile`` blocks of the grid that hold some of ``cells`` are rasterised, with
    each node placed as the whole grid places it: a few scattered points (verify's look beside the
    cells it found cut too deep) cost a few blocks, not the grid.
    """
    tri = _checked(triangles)
    cells = np.asarray(cells, dtype=np.int64).reshape(-1)
    top = np.full(grid.size, -np.inf)
    if len(tri) == 0 or len(cells) == 0:
        return top[cells]
    jj, ii = np.divmod(cells, grid.nx)
    per_row = grid.nx // tile + 1  # blocks numbered row by row
    blocks = np.unique((jj // tile) * per_row + ii // tile)
    if len(blocks) * tile * tile >= grid.size // 4:  # most of the grid: one pass over it is cheaper
        return _rasterised(tri, grid).reshape(-1)[cells]
    cover = _Coverage(tri, grid)
    for bj, bi in zip(*np.divmod(blocks, per_row)):
        cover.raster(tri, grid, top, (bi * tile, min(bi * tile + tile, grid.nx) - 1),
                     (bj * tile, min(bj * tile + tile, grid.ny) - 1))
    return top[cells]


def _checked(triangles: np.ndarray) -> np.ndarray:
    """``triangles`` as a contiguous (m, 3, 3) float array; :class:`MeshError` if they are not that or not finite."""
    tri = np.ascontiguousarray(triangles, dtype=np.float64)
    if tri.ndim != 3 or tri.shape[1:] != (3, 3):
        raise MeshError(f"triangles must have shape (m, 3, 3), got {tri.shape}")
    if not np.all(np.isfinite(tri)):
        raise MeshError("triangles hold non-finite coordinates")
    return tri


class _Coverage:
    """Which grid points each triangle may cover (its XY box grown by :data:`EDGE_TOLERANCE`), and
    what rasterising it needs, for :func:`_rasterised` and :func:`upper_envelope_at`."""

    def __init__(self, tri: np.ndarray, grid: Grid):
        tol = EDGE_TOLERANCE
        xy = tri[:, :, :2]
        self.i0, self.i1 = grid.column_range(xy[:, :, 0].min(1) - tol, xy[:, :, 0].max(1) + tol)
        self.j0, self.j1 = grid.row_range(xy[:, :, 1].min(1) - tol, xy[:, :, 1].max(1) + tol)
        e1 = xy[:, 1] - xy[:, 0]
        e2 = xy[:, 2] - xy[:, 0]
        self.area2 = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        self.edge_len = np.linalg.norm(xy[:, [1, 2, 0]] - xy, axis=2)  # edge k runs from corner k to k+1
        longest = self.edge_len.max(1)
        # Thinner than the edge tolerance in XY: barycentric coordinates are ill-conditioned,
        # treat the triangle as the vertical wall it (nearly) is.
        self.vertical = np.abs(self.area2) <= tol * np.maximum(longest, tol)

    def raster(self, tri: np.ndarray, grid: Grid, top: np.ndarray, columns: tuple[int, int] | None = None,
               rows: tuple[int, int] | None = None) -> None:
        """Raise ``top`` (flat, the grid's size) to every triangle over the grid's points, only those
        in the ``columns`` and ``rows`` (first, last) given."""
        i0, i1, j0, j1 = self.i0, self.i1, self.j0, self.j1
        if columns is not None:
            i0, i1 = np.maximum(i0, columns[0]), np.minimum(i1, columns[1])
        if rows is not None:
            j0, j1 = np.maximum(j0, rows[0]), np.minimum(j1, rows[1])
        ni = np.maximum(i1 - i0 + 1, 0)
        nj = np.maximum(j1 - j0 + 1, 0)
        counts = ni * nj
        flat_sel = np.flatnonzero(~self.vertical & (counts > 0))
        wall_sel = np.flatnonzero(self.vertical & (counts > 0))
        if len(flat_sel):
            _raster_triangles(tri, flat_sel, self.area2, self.edge_len, i0, j0, ni, counts, grid, top)
        if len(wall_sel):
            _raster_walls(tri, wall_sel, i0, j0, ni, counts, grid, top)


def _rasterised(tri: np.ndarray, grid: Grid) -> np.ndarray:
    """:func:`upper_envelope` of checked triangles, computed: a new (ny, nx) array [mm]."""
    top = np.full(grid.size, -np.inf)
    if len(tri) == 0:
        return top.reshape(grid.shape)
    _Coverage(tri, grid).raster(tri, grid, top)
    return top.reshape(grid.shape)


def _batches(sel: np.ndarray, counts: np.ndarray):
    """Split the triangle indices ``sel`` into runs of about ``_PAIR_BUDGET`` grid points."""
    cum = np.cumsum(counts[sel])
    start_cum = cum - counts[sel]
    bucket = start_cum // _PAIR_BUDGET
    cuts = np.flatnonzero(np.diff(bucket)) + 1
    yield from np.split(sel, cuts)


def _runs(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Runs of ``n[k]`` entries each, laid end to end: each entry's run ``k`` and its place in the run."""
    owner = np.repeat(np.arange(len(n)), n)
    return owner, np.arange(int(n.sum()), dtype=np.int64) - np.repeat(np.cumsum(n) - n, n)


def _pairs(batch: np.ndarray, i0, j0, ni, counts, grid: Grid):
    """Expand triangles into (triangle position in batch, flat grid index, x, y) pairs."""
    c = counts[batch]
    owner, local = _runs(c)
    nib = np.repeat(ni[batch], c)
    ii = np.repeat(i0[batch], c) + local % nib
    jj = np.repeat(j0[batch], c) + local // nib
    return owner, jj * grid.nx + ii, grid.x0 + ii * grid.cell, grid.y0 + jj * grid.cell


def _raster_triangles(tri, sel, area2, edge_len, i0, j0, ni, counts, grid, top) -> None:
    tol = EDGE_TOLERANCE
    for batch in _batches(sel, counts):
        t = tri[batch]
        a2 = area2[batch]
        # Barycentric weight of corner k is an affine function of (x, y): the signed
        # distance to the opposite edge over the corner's height above that edge.
        p1, p2 = t[:, [1, 2, 0], :2], t[:, [2, 0, 1], :2]  # opposite edge of corner k: p1 -> p2
        gx = -(p2[:, :, 1] - p1[:, :, 1]) / a2[:, None]
        gy = (p2[:, :, 0] - p1[:, :, 0]) / a2[:, None]
        g0 = -(gx * p1[:, :, 0] + gy * p1[:, :, 1])
        # A weight of -tol / height is a distance of tol outside that edge.
        opp_len = edge_len[batch][:, [1, 2, 0]]
        slack = tol * opp_len / np.abs(a2)[:, None]
        z = t[:, :, 2]
        zlo, zhi = z.min(1), z.max(1)

        if counts[batch].mean() > _SPAN_POINTS:  # big ones: their rows' spans; small ones: their boxes
            owner, flat, qx, qy = _row_spans(batch, i0, j0, ni, counts, grid, gx, gy, g0 + slack)
        else:
            owner, flat, qx, qy = _pairs(batch, i0, j0, ni, counts, grid)
        inside = np.ones(len(owner), dtype=bool)
        zq = np.zeros(len(owner))
        for k in range(3):
            lam = g0[owner, k] + gx[owner, k] * qx + gy[owner, k] * qy
            inside &= lam >= -slack[owner, k]
            zq += lam * z[owner, k]
        # Clamping to the triangle's own z range keeps a point that is "inside" only by the
        # tolerance from picking up an extrapolated height on a steep triangle.
        zq = np.clip(zq, zlo[owner], zhi[owner])
        np.maximum.at(top, flat[inside], zq[inside])


def _row_spans(batch: np.ndarray, i0, j0, ni, counts, grid: Grid, gx, gy, reach):
    """:func:`_pairs` of a batch of triangles, only the grid points of each row that may lie inside.

    A long thin triangle across the grid covers a few per cent of its box (a plate's top face in two
    triangles: 7.3 million pairs in the boxes, 0.3 million inside). Per row, the three weights
    ``reach + gx x + gy y >= 0`` (``reach``: the offset and the edge slack, (b, 3)) bound x; the span
    keeps a column more each side, so float rounding in the bounds loses no point the exact test
    (which the caller still makes) would take. Returns the same arrays as :func:`_pairs`.
    """
    nj = counts[batch] // np.maximum(ni[batch], 1)
    row_owner, row = _runs(nj)
    jj = np.repeat(j0[batch], nj) + row
    y = grid.y0 + jj * grid.cell
    c = reach[row_owner] + gy[row_owner] * y[:, None]
    a = gx[row_owner]
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = -c / a
    lower = np.where(a > 0, bound, -np.inf).max(axis=1)
    upper = np.where(a < 0, bound, np.inf).min(axis=1)
    lo_col = np.repeat(i0[batch], nj)
    hi_col = lo_col + np.repeat(ni[batch], nj) - 1
    first = np.clip(np.ceil((lower - grid.x0) / grid.cell) - 1, lo_col, hi_col + 1).astype(np.int64)
    last = np.clip(np.floor((upper - grid.x0) / grid.cell) + 1, lo_col - 1, hi_col).astype(np.int64)
    n = np.maximum(last - first + 1, 0)
    span, column = _runs(n)
    owner = row_owner[span]
    ii = first[span] + column
    jj = jj[span]
    return owner, jj * grid.nx + ii, grid.x0 + ii * grid.cell, grid.y0 + jj * grid.cell


def _raster_walls(tri, sel, i0, j0, ni, counts, grid, top) -> None:
    tol = EDGE_TOLERANCE
    for batch in _batches(sel, counts):
        t = tri[batch]
        owner, flat, qx, qy = _pairs(batch, i0, j0, ni, counts, grid)
        best = np.full(len(owner), -np.inf)
        # The highest point of a (near) vertical triangle above a point lies on one of its
        # edges: evaluate every edge that passes within tol of the point.
        for k in range(3):
            a = t[:, k]
            b = t[:, (k + 1) % 3]
            d = b - a
            l2 = d[:, 0] ** 2 + d[:, 1] ** 2
            ax, ay, az = a[owner, 0], a[owner, 1], a[owner, 2]
            dx, dy, dz = d[owner, 0], d[owner, 1], d[owner, 2]
            l2o = l2[owner]
            steep = l2o <= tol * tol
            with np.errstate(invalid="ignore", divide="ignore"):
                s = np.where(steep, 0.0, ((qx - ax) * dx + (qy - ay) * dy) / np.where(steep, 1.0, l2o))
            s = np.clip(s, 0.0, 1.0)
            dist2 = (qx - ax - s * dx) ** 2 + (qy - ay - s * dy) ** 2
            zk = np.where(steep, az + np.maximum(dz, 0.0), az + s * dz)
            best = np.where(dist2 <= tol * tol, np.maximum(best, zk), best)
        hit = best > -np.inf
        np.maximum.at(top, flat[hit], best[hit])
