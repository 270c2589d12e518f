"""XY regions made of stock-model grid cells, built fast.

The stock model (:class:`cadcam.stock.Simulation`) marks rest material cell by cell. As a
polygon that is the union of the marked cells' squares; rest roughing grows it by the tool
radius. Both are exact set operations on up to tens of thousands of squares, and GEOS
pays per vertex and per intersection:

- the union is built from *row runs* (one rectangle per run of marked cells in a grid
  row), a few hundred rectangles instead of thousands of squares: 5-10x faster;
- the grown region is the union of the runs each grown by the radius (a rounded
  rectangle each), not the staircase outline grown at once, whose offset curve crosses
  itself at every step: 5x faster, the same set to floating-point noise (the arcs are
  centred on the same cell corners with the same segments per quarter circle);
- levels whose mask is the same as an earlier level's (the stock top is a grid of
  heights, so many consecutive levels select the same cells) reuse its region.
"""

from __future__ import annotations


import numpy as np
import shapely
from scipy import ndimage
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry

from cadcam.heightmap import Grid
from factory.core.kept import KeptAnswers


def near_cells(mask: np.ndarray, reach: float, cell: float = 1.0) -> np.ndarray:
    """(ny, nx) bool: the points of a grid of ``cell`` [mm] within ``reach`` [mm] of a True point of ``mask``,
    points off the grid counting as False: ``ndimage.binary_dilation`` by the disc of offsets
    ``hypot(di, dj) * cell <= reach``, exactly.

    The dilation pays per point of the disc (a 16 mm end mill on a 0.5 mm grid: 1,100 of them, for every
    level of every roughing pass); the Euclidean distance transform does not. The nearest True point's
    offset is read back as integers, so the disc's edge is decided exactly as the dilation decides it.
    """
    mask = np.asarray(mask, dtype=bool)
    if not mask.any():
        return np.zeros(mask.shape, dtype=bool)
    k = int(np.floor(reach / cell)) + 1
    offsets = np.arange(-k, k + 1)
    di, dj = np.meshgrid(offsets, offsets)
    inside = np.hypot(di, dj) * cell <= reach
    farthest = int((di[inside] ** 2 + dj[inside] ** 2).max(initial=-1))  # the disc holds exactly d2 <= this
    rows, cols = ndimage.distance_transform_edt(~mask, return_distances=False, return_indices=True)
    jj, ii = np.indices(mask.shape)
    return (jj - rows) ** 2 + (ii - cols) ** 2 <= farthest


#: The last few :func:`highest_near` answers, by the id of the read-only map they were made from (the answer
#: holds that map, so its id is not reused while kept), each at most :data:`_HIGHEST_NEAR_BYTES`.
_HIGHEST_NEAR: KeptAnswers[tuple[int, float, float], tuple[np.ndarray, np.ndarray]] = KeptAnswers(kept=4)
_HIGHEST_NEAR_BYTES = 16 << 20


def highest_near(top: np.ndarray, cell: float, reach: float) -> np.ndarray:
    """(ny, nx) the highest finite value of the height map ``top`` (on a grid of ``cell`` [mm]) within ``reach``
    [mm] of each point (``-inf``: none), points off the grid counting as none. Read-only.

    A read-only ``top`` (the part's :func:`cadcam.heightmap.upper_envelope`, which gives the same array for the
    same part and grid) is answered again from the last few maps: every stock model that measures engagement
    on one grid (the chip feeds' models, verify's) asks for the same part's, and each answer costs one pass over
    the grid per point of the disc."""
    if not top.flags.writeable and top.nbytes <= _HIGHEST_NEAR_BYTES:
        return _HIGHEST_NEAR.get((id(top), cell, reach), lambda: (top, _highest_near(top, cell, reach)))[1]
    return _highest_near(top, cell, reach)


def _highest_near(top: np.ndarray, cell: float, reach: float) -> np.ndarray:
    """:func:`highest_near`, made afresh."""
    finite = np.where(np.isfinite(top), top, -np.inf)
    out = finite.copy()
    k = int(reach // cell)
    ny, nx = finite.shape
    for dj in range(-k, k + 1):
        for di in range(-k, k + 1):
            if (di or dj) and (di * di + dj * dj) * cell**2 <= reach * reach + 1e-12:
                src = finite[max(0, dj):ny + min(0, dj), max(0, di):nx + min(0, di)]
                dst = out[max(0, -dj):ny + min(0, -dj), max(0, -di):nx + min(0, -di)]
                np.maximum(dst, src, out=dst)
    out.setflags(write=False)
    return out


def cell_runs(mask: np.ndarray, grid: Grid) -> np.ndarray:
    """(k,) shapely rectangles, one per run of True cells along a grid row.

    mask : (ny, nx) bool over ``grid`` (row j at y0 + j * cell); cell (j, i) is the square
    of side ``cell`` centred on its grid point [mm]. Edges are computed from cell indices
    alone, so adjacent rectangles share edge coordinates exactly.
    """
    m = np.asarray(mask, dtype=bool)
    d = np.diff(np.pad(m, ((0, 0), (1, 1))).view(np.int8), axis=1)
    j, i0 = np.nonzero(d == 1)
    _, i1 = np.nonzero(d == -1)  # row-major order pairs each run's end with its start
    c = grid.cell
    return shapely.box(grid.x0 + (i0 - 0.5) * c, grid.y0 + (j - 0.5) * c,
                       grid.x0 + (i1 - 0.5) * c, grid.y0 + (j + 0.5) * c)


def cells_region(mask: np.ndarray, grid: Grid) -> BaseGeometry:
    """Union of the squares of the True cells of ``mask`` (see :func:`cell_runs`); empty Polygon if none."""
    runs = cell_runs(mask, grid)
    return shapely.union_all(runs) if len(runs) else Polygon()


def grown_cells_region(mask: np.ndarray, grid: Grid, radius: float, quad_segs: int = 8) -> BaseGeometry:
    """``cells_region(mask, grid).buffer(radius, quad_segs=quad_segs)``, computed run by run.

    radius : float, >= 0 [mm].
    """
    runs = cell_runs(mask, grid)
    if not len(runs):
        return Polygon()
    if radius <= 0:
        return shapely.union_all(runs)
    return shapely.union_all(shapely.buffer(runs, radius, quad_segs=quad_segs))


class GrownMaskCache:
    """:func:`grown_cells_region` remembered per distinct mask (one grid, radius and quad_segs).

    Rest roughing asks for the grown rest material at every level; the masks repeat from
    level to level, and a mask's bytes identify it.
    """

    def __init__(self, grid: Grid, radius: float, quad_segs: int = 8):
        self.grid, self.radius, self.quad_segs = grid, float(radius), int(quad_segs)
        self._seen: dict[bytes, BaseGeometry] = {}

    def __call__(self, mask: np.ndarray) -> BaseGeometry:
        key = np.packbits(np.asarray(mask, dtype=bool)).tobytes()
        region = self._seen.get(key)
        if region is None:
            region = grown_cells_region(mask, self.grid, self.radius, self.quad_segs)
            self._seen[key] = region
        return region
