"""Exact drop-cutter: how low a tool can go at (x, y) without entering a triangle mesh.

The cutter location (CL, the tool tip) at ``(x, y)`` is the highest of::

    floor_z,  max over mesh points p with |p_xy - c| <= R of  p_z - h(|p_xy - c|)

where ``h`` is :meth:`cadcam.model.Tool.profile_height` (flat, ball and bull-nose share it).
For one triangle, ``p -> p_z - h(|p_xy - c|)`` is concave (a plane minus a convex bowl) on a
convex domain, so its maximum is one of three kinds of contact, each computed exactly:

- **vertex**: closed form;
- **facet**: the point of the tool whose surface normal equals the facet normal ``n``: on the
  torus the ring centre ``(R - rc) n_xy/|n_xy|`` then the sphere of radius ``rc`` (the flat
  tool's rim, the ball's sphere as special cases); it counts when it lies inside the triangle;
- **edge**: the tool cut by the vertical plane through the edge; closed form for the ball
  (a circle) and flat (a chord); for the bull-nose the concave function along the edge is
  maximised by bisection on the sign of its derivative (to ~1e-10 mm).

Every candidate is evaluated at a genuine point of a triangle, so the result never exceeds
the exact answer by more than rounding, and equals it because the true maximiser is always
one of the candidates.

Vertices and edges are de-duplicated (a closed mesh shares each vertex among ~6 triangles),
and each primitive kind is bucketed in a uniform XY grid: vertices and edges in every bucket
within the tool radius of their box, facets by the triangle moved by the (tool-dependent)
contact offset, so a facet is a candidate only where its contact point can lie inside it.
Each bucket lists its primitives by decreasing upper bound on the contact they can give any
axis in it (vertices and edges: top z less the profile height at the bucket's distance), so
only a prefix above the best contact found so far is evaluated; edges are checked again
against a per-pair bound (highest point over the chord less the profile at the nearest XY
distance) before the exact contact. Each CL point's candidates are asked in one compiled pass
(:mod:`cadcam.dropcontacts`), the points in chunks (progress, threads). The bucket lists for the last few (index,
tool) pairs are kept, because finishing queries the same surface many times.
"""

from __future__ import annotations

import concurrent.futures
import logging
import math
import os
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from cadcam.model import Tool
from cadcam.parallel import MAX_WORKERS, processors
from factory.core.errors import MeshError, ToolpathError
from factory.core.kept import KeptAnswers, content_key

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]

#: Candidate vertices (before culling) of the CL points asked in one chunk: a progress report, a thread's share.
_PAIR_BUDGET = 400_000
#: Bisection steps for bull-nose edge contacts: 2R / 2**32 is ~1e-9 mm along the edge for
#: R = 10 mm; at an interior maximum of the concave contact height that is off by far less
#: in z (second order), and a maximum at an edge end is the end vertex's own exact contact.
_BISECT_STEPS = 32
#: Highest vertex candidates per point evaluated first, for a lower bound that culls the rest.
_HEAD = 24
#: Query bucket size as a share of the tool radius (smaller: tighter bounds, more entries). A
#: bucket's bound on a primitive takes the primitive as near as the bucket's nearest point: on a
#: steep wall, where most of a waterline's queries are, buckets of R/2 let in about twice the
#: candidates of buckets of R/8, each one a gathered and bounded pair.
_CELL_PER_RADIUS = 0.125
#: Bucket entries (a vertex or edge listed in a bucket within the tool's reach of it) at most per
#: prepared tool: each holds 12 B (~24 B while they are sorted), and finer buckets list each primitive
#: in more of them, so a big mesh gets coarser buckets (never coarser than before, R/2). On a 100k-triangle
#: solid (issue 35) 10M made the ball's buckets 1.14 mm for R = 3 mm, and 46 % of the waterline's edge pairs
#: lay beyond the tool's reach; 16M makes them 0.92 mm, the waterline's queries 20 % cheaper for 1 s more
#: bucketing, and the sort's peak lower than 10M's was before _bucket freed its temporaries early.
_MAX_ENTRIES = 16_000_000
#: ... and at most this many per vertex and edge: a small mesh (or a small tool on a wide one) would
#: otherwise spend the whole budget, and its memory, on buckets finer than its queries repay.
_ENTRIES_PER_PRIMITIVE = 100
#: Query buckets at most (the bucket pointers take 8 B each).
_MAX_BUCKETS = 4_000_000
#: A tool radius below this share of the index's bucket (about twice the median triangle) is a pin: its
#: query buckets are no finer than the index's divided as a tool's radius is (no milling tool is as fine).
_PIN_RADIUS = 1e-3
#: Entries made at once while bucketing (bounds the temporaries, ~150 B each).
_ENTRY_CHUNK = 1_000_000


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class TriangleIndex:
    """A triangle mesh prepared for drop-cutter queries (all arrays read-only).

    Attributes
    ----------
    triangles : (m, 3, 3) float
        The triangles in work coordinates [mm].
    vertices : (k, 3) float
        Distinct triangle corners [mm].
    edge_start : (e, 3) float
        First end of each distinct non-vertical edge [mm].
    edge_dir : (e, 2) float
        Unit XY direction of each edge.
    edge_length : (e,) float
        XY length of each edge [mm].
    edge_slope : (e,) float
        dz per mm of XY travel along each edge.
    facet_origin : (f, 3) float
        First corner of each non-vertical triangle [mm].
    facet_e1, facet_e2 : (f, 3) float
        Edge vectors from ``facet_origin`` to the other two corners [mm].
    facet_inverse : (f, 2, 2) float
        Inverse of the XY part of ``[e1 e2]``: barycentric coordinates from an XY offset.
    facet_normal : (f, 3) float
        Unit normal, oriented so ``n_z > 0`` (the contact does not depend on orientation).
    origin : (2,) float
        XY of the bucket grid's lower-left corner [mm].
    cell : float
        Bucket size [mm] (queries may merge buckets for large tools).
    shape : (2,) int
        Bucket count along X and Y.
    """

    triangles: np.ndarray
    vertices: np.ndarray
    edge_start: np.ndarray
    edge_dir: np.ndarray
    edge_length: np.ndarray
    edge_slope: np.ndarray
    facet_origin: np.ndarray
    facet_e1: np.ndarray
    facet_e2: np.ndarray
    facet_inverse: np.ndarray
    facet_normal: np.ndarray
    origin: np.ndarray
    cell: float
    shape: tuple[int, int]
    #: Query structures already prepared on this index, by (radius, corner radius) [mm].
    #: Finishing drops the same tool many times (refinement, iso-line bisection) and
    #: bucketing costs as much as a few thousand CL points. The index never changes, so
    #: nothing here goes stale.
    prepared: dict = field(default_factory=dict, repr=False, compare=False)


def build_index(triangles: np.ndarray, cell: float | None = None) -> TriangleIndex:
    """Prepare triangles for :func:`drop_cutter`.

    Parameters
    ----------
    triangles : (m, 3, 3) float
        Triangle corners in work coordinates [mm]; degenerate and vertical triangles are
        fine (their edges and corners still count). ``m`` may be 0.
    cell : float, optional
        Bucket size [mm]. Default: about twice the median triangle size, coarsened so the
        grid has at most ~1M buckets.

    Returns
    -------
    TriangleIndex

    Raises
    ------
    MeshError
        ``triangles`` is not ``(m, 3, 3)`` or holds non-finite values; ``cell`` <= 0.
    """
    tri = np.asarray(triangles, dtype=np.float64)
    if tri.ndim != 3 or tri.shape[1:] != (3, 3):
        raise MeshError(f"triangles must have shape (m, 3, 3), got {tri.shape}")
    if not np.all(np.isfinite(tri)):
        raise MeshError("triangles hold non-finite coordinates")
    if cell is not None and not (cell > 0 and math.isfinite(cell)):
        raise MeshError(f"bucket size must be positive, got {cell}")
    m = len(tri)

    corners = tri.reshape(-1, 3)
    if m:
        # Lexicographic row sort then run starts: np.unique(axis=0)'s result, several times faster.
        order = np.lexsort((corners[:, 2], corners[:, 1], corners[:, 0]))
        srt = corners[order]
        new = np.ones(len(srt), dtype=bool)
        new[1:] = np.any(srt[1:] != srt[:-1], axis=1)
        vertices = srt[new]
        inverse = np.empty(len(srt), dtype=np.int64)
        inverse[order] = np.cumsum(new) - 1
        inverse = inverse.reshape(m, 3)
    else:
        vertices, inverse = np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)

    # Distinct edges; vertical ones are covered by their end vertices.
    pairs = np.sort(np.concatenate([inverse[:, [0, 1]], inverse[:, [1, 2]], inverse[:, [2, 0]]]), axis=1)
    if len(pairs):
        code = np.unique(pairs[:, 0] * np.int64(len(vertices)) + pairs[:, 1])
        pairs = np.column_stack([code // len(vertices), code % len(vertices)])
    else:
        pairs = pairs.reshape(0, 2)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    p0 = vertices[pairs[:, 0]]
    p1 = vertices[pairs[:, 1]]
    dxy = p1[:, :2] - p0[:, :2]
    length = np.hypot(dxy[:, 0], dxy[:, 1])
    scale = max(1.0, float(np.abs(corners).max(initial=0.0)))
    keep = length > 1e-12 * scale
    p0, p1, dxy, length = p0[keep], p1[keep], dxy[keep], length[keep]
    edge_dir = dxy / length[:, None]
    edge_slope = (p1[:, 2] - p0[:, 2]) / length

    # Facets: only non-vertical ones have an interior contact.
    e1 = tri[:, 1] - tri[:, 0]
    e2 = tri[:, 2] - tri[:, 0]
    normal = np.cross(e1, e2)
    nlen = np.linalg.norm(normal, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        normal = normal / nlen[:, None]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    good = (nlen > 0) & (np.abs(normal[:, 2]) > 1e-12) & (det != 0)
    normal = normal[good] * np.sign(normal[good, 2])[:, None]
    e1g, e2g, detg = e1[good], e2[good], det[good]
    inv = np.empty((len(detg), 2, 2))
    inv[:, 0, 0] = e2g[:, 1] / detg
    inv[:, 0, 1] = -e2g[:, 0] / detg
    inv[:, 1, 0] = -e1g[:, 1] / detg
    inv[:, 1, 1] = e1g[:, 0] / detg

    if m:
        lo = corners[:, :2].min(axis=0)
        hi = corners[:, :2].max(axis=0)
    else:
        lo = hi = np.zeros(2)
    span = np.maximum(hi - lo, 1e-9)
    if cell is None:
        size = np.ptp(tri[:, :, :2], axis=1).max(axis=1) if m else np.ones(1)
        cell = 2.0 * float(np.median(size)) if m else 1.0
        cell = max(cell, 1e-6 * float(span.max()), 1e-9)
    cell = max(float(cell), float(np.sqrt(span[0] * span[1] / 1e6)))
    shape = (int(span[0] // cell) + 1, int(span[1] // cell) + 1)

    return TriangleIndex(
        triangles=_readonly(tri),
        vertices=_readonly(vertices),
        edge_start=_readonly(p0),
        edge_dir=_readonly(edge_dir),
        edge_length=_readonly(length),
        edge_slope=_readonly(edge_slope),
        facet_origin=_readonly(tri[good, 0]),
        facet_e1=_readonly(e1g),
        facet_e2=_readonly(e2g),
        facet_inverse=_readonly(inv),
        facet_normal=_readonly(normal),
        origin=_readonly(lo),
        cell=float(cell),
        shape=shape,
    )


#: The last part's index: only one, so a part's buckets live no longer than the next part's are made.
_LAST_INDEX: KeptAnswers[bytes, TriangleIndex] = KeptAnswers(kept=1)


def shared_index(triangles: np.ndarray) -> TriangleIndex:
    """:func:`build_index` of ``triangles`` (m, 3, 3) [mm], the very same index again while they are the same.

    The waterline and the raster drop the same ball on the same part: the second reuses the
    index and its prepared buckets (a few seconds on a 100k-triangle part) instead of making
    equal ones (:data:`_LAST_INDEX`). Raises as :func:`build_index`.
    """
    tri = np.ascontiguousarray(triangles, dtype=np.float64)
    return _LAST_INDEX.get(content_key(tri), lambda: build_index(tri))


# --------------------------------------------------------------------------- buckets


@dataclass(frozen=True)
class _Grid:
    origin: np.ndarray
    cell: float
    nx: int
    ny: int

    def cells(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ix = np.clip(np.floor((x - self.origin[0]) / self.cell), 0, self.nx - 1).astype(np.int64)
        iy = np.clip(np.floor((y - self.origin[1]) / self.cell), 0, self.ny - 1).astype(np.int64)
        return ix, iy


def _query_grid(index: TriangleIndex, radius: float, lo: np.ndarray, hi: np.ndarray) -> _Grid:
    """Buckets of about :data:`_CELL_PER_RADIUS` x ``radius`` [mm] over the index's extent, coarser where
    the vertices' and edges' boxes ``lo``, ``hi`` (k, 2) [mm] listed within ``radius`` of them would make
    more than :data:`_MAX_ENTRIES` entries, or :data:`_ENTRIES_PER_PRIMITIVE` per box (or the grid more
    than :data:`_MAX_BUCKETS` buckets), up to the index's buckets merged to half the radius at most."""
    extent = np.array(index.shape, dtype=np.float64) * index.cell
    coarsest = index.cell * max(1, int(math.ceil(0.5 * radius / index.cell)))
    lo, hi = lo - index.origin - radius, hi - index.origin + radius
    cell = max(_CELL_PER_RADIUS * radius, math.sqrt(float(extent[0] * extent[1]) / _MAX_BUCKETS))
    if radius < _PIN_RADIUS * index.cell:
        # A pin far finer than the triangles (cadcam.relief reads which facets are seen from above with
        # one): buckets finer than a share of a triangle list the same few primitives again and again,
        # and making millions of them cost a relief's intake 1 s (issue 35). Heights do not depend on it.
        cell = max(cell, index.cell * _CELL_PER_RADIUS)

    def entries(c: float) -> float:  # the buckets each grown box spans (a few more than _bucket keeps)
        return float(np.sum(np.prod(np.floor(hi / c) - np.floor(lo / c) + 1.0, axis=1)))

    budget = min(_MAX_ENTRIES, _ENTRIES_PER_PRIMITIVE * len(lo))
    while cell < coarsest and entries(cell) > budget:
        cell *= 1.25
    cell = min(cell, coarsest)
    nx = int(extent[0] // cell) + 1
    ny = int(extent[1] // cell) + 1
    return _Grid(index.origin, cell, nx, ny)


@dataclass(frozen=True)
class _Buckets:
    """Primitives per bucket, each bucket's list sorted by descending top z.

    ``key[j] = bucket + fraction`` with the fraction growing as the top z falls, so one
    ``searchsorted`` finds, for any bucket and height, the prefix of primitives that reach
    above that height (:func:`cadcam.dropcontacts._stop`): the others cannot raise a CL point
    already known to be that high.
    """

    ptr: np.ndarray
    items: np.ndarray
    key: np.ndarray
    z_hi: float
    z_span: float


def _bucket(grid: _Grid, lo: np.ndarray, hi: np.ndarray, top: np.ndarray,
            radius: float = 0.0, corner: float = 0.0) -> _Buckets:
    """Boxes ``[lo, hi]`` (k, 2) with top heights ``top`` (k,) [mm] listed per bucket.

    With ``radius > 0`` each box is listed in every bucket within ``radius`` of it, ranked
    not by ``top`` but by ``top - h(d)``, ``d`` the least XY distance from the bucket to the
    box and ``h`` the profile: no tool axis in that bucket can get a higher contact from a
    primitive inside the box, and most primitives far from a bucket drop out of its prefix.
    """
    ix0, iy0 = grid.cells(lo[:, 0] - radius, lo[:, 1] - radius)
    ix1, iy1 = grid.cells(hi[:, 0] + radius, hi[:, 1] + radius)
    wx = ix1 - ix0 + 1
    counts = wx * (iy1 - iy0 + 1)
    # In chunks of boxes: the temporaries of a fine grid's entries would outweigh the lists kept.
    ends = np.cumsum(counts)
    cuts = np.unique(np.searchsorted(ends, np.arange(_ENTRY_CHUNK, int(ends[-1]) if len(ends) else 0, _ENTRY_CHUNK)))
    pieces = [_entries(grid, lo, hi, top, radius, corner, ix0, iy0, wx, counts, a, b)
              for a, b in zip([0, *cuts.tolist()], [*cuts.tolist(), len(lo)]) if b > a]
    items, buckets, values = (list(q) for q in zip(*pieces)) if pieces else ([], [], [])
    del pieces  # each column's pieces go as soon as it is joined
    item = _joined(items, np.int32)
    bucket = _joined(buckets, np.int32)
    value = _joined(values, np.float64)
    z_hi = float(value.max(initial=0.0)) + 1.0
    z_span = z_hi - float(value.min(initial=0.0)) + 1.0
    # The key made in the ranking values' own array, and the bucket numbers let go before the sort: a fine
    # grid's entries are many, and the peak while they are sorted is what bounds them (_MAX_ENTRIES).
    # The same operations in the same order as bucket + (z_hi - value) / z_span, so the same keys.
    key = np.subtract(z_hi, value, out=value)
    key /= z_span
    key += bucket
    ptr = np.zeros(grid.nx * grid.ny + 1, dtype=np.int64)
    np.cumsum(np.bincount(bucket, minlength=grid.nx * grid.ny), out=ptr[1:])
    del bucket
    # One float sort (not lexsort): the key itself must be sorted for searchsorted in stop(). The keys are
    # gathered in the order argsort put them, not sorted again: the same numbers (equal keys are equal numbers),
    # for a gather's cost instead of a sort's (a third of the buckets' time, issue 35).
    order = np.argsort(key)
    item = item[order]
    key = key[order]
    del order
    return _Buckets(ptr, item, key, z_hi, z_span)


def _joined(pieces: list[np.ndarray], dtype) -> np.ndarray:
    """The pieces end to end, emptying the list (so each piece is freed once copied)."""
    out = np.concatenate(pieces) if pieces else np.zeros(0, dtype)
    pieces.clear()
    return out


def _entries(grid: _Grid, lo: np.ndarray, hi: np.ndarray, top: np.ndarray, radius: float, corner: float,
             ix0: np.ndarray, iy0: np.ndarray, wx: np.ndarray, counts: np.ndarray, a: int, b: int
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_bucket`'s entries of boxes ``a:b``: (box, bucket, ranking value), (k,) int32, int32, float64.

    Compiled (:func:`cadcam.dropcontacts.bucket_entries`, the same numbers as the numpy pairs it replaced): those
    made every entry's bucket, bounds and distance as temporaries, most of a tool's preparation (issue 35).
    Border buckets also hold every axis beyond the grid (:meth:`_Grid.cells` clamps): open sides. The margin
    covers rounding in the bucket of an axis; it only ever lowers the distance. 32-bit: a fine grid lists each
    primitive many times (the index and the grid stay far below 2**31)."""
    from cadcam.dropcontacts import bucket_entries

    return bucket_entries(a, b, ix0, iy0, wx, counts, np.ascontiguousarray(lo, dtype=np.float64),
                          np.ascontiguousarray(hi, dtype=np.float64), np.ascontiguousarray(top, dtype=np.float64),
                          float(grid.origin[0]), float(grid.origin[1]), float(grid.cell), grid.nx, grid.ny,
                          float(radius), float(corner), 1e-9 * (1.0 + grid.cell * max(grid.nx, grid.ny)))


# --------------------------------------------------------------------------- kernels


def _height(r: np.ndarray, radius: float, corner: float) -> np.ndarray:
    """Profile height for ``0 <= r <= radius`` (callers clamp r)."""
    if corner <= 0.0:
        return np.zeros_like(r)
    d = np.maximum(r - (radius - corner), 0.0)
    return corner - np.sqrt(np.maximum(corner * corner - d * d, 0.0))


@dataclass(frozen=True)
class _Tables:
    """Per-query primitive data packed for single-gather access."""

    offsets: np.ndarray  # (f, 2) facet contact offsets [mm]
    edges: np.ndarray  # (e, 7) x0, y0, z0, ux, uy, length, slope


def _facet_offsets(index: TriangleIndex, radius: float, corner: float) -> np.ndarray:
    """XY offset from the tool axis to the facet contact point, per facet (f, 2) [mm]."""
    n = index.facet_normal
    nxy = np.hypot(n[:, 0], n[:, 1])
    a = radius - corner
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(nxy > 1e-15, a / nxy + corner, 0.0)
    return -n[:, :2] * scale[:, None]


def _prepared(index: TriangleIndex, radius: float, corner_radius: float) -> tuple:
    key = (float(radius), float(corner_radius))
    if key not in index.prepared:
        index.prepared[key] = _prepare(index, radius, corner_radius)
    return index.prepared[key]


def _prepare(index: TriangleIndex, radius: float, corner_radius: float) -> tuple:
    """Query grid, the three bucket lists and packed tables for one tool on one index."""
    v = index.vertices
    p0 = index.edge_start
    p1 = np.concatenate([p0[:, :2] + index.edge_dir * index.edge_length[:, None],
                         (p0[:, 2] + index.edge_slope * index.edge_length)[:, None]], axis=1)
    elo = np.minimum(p0[:, :2], p1[:, :2])
    ehi = np.maximum(p0[:, :2], p1[:, :2])
    grid = _query_grid(index, radius, np.concatenate([v[:, :2], elo]), np.concatenate([v[:, :2], ehi]))
    vbuckets = _bucket(grid, v[:, :2], v[:, :2], v[:, 2], radius, corner_radius)
    ebuckets = _bucket(grid, elo, ehi, np.maximum(p0[:, 2], p1[:, 2]), radius, corner_radius)
    offsets = _facet_offsets(index, radius, corner_radius)
    tables = _Tables(offsets, np.column_stack([p0, index.edge_dir, index.edge_length, index.edge_slope]))
    corners = np.stack(
        [index.facet_origin, index.facet_origin + index.facet_e1, index.facet_origin + index.facet_e2], axis=1
    )
    # A facet can only be touched where axis + offset lies inside it.
    pad = 1e-9 * (1.0 + np.abs(corners).max(initial=0.0))
    fxy = corners[:, :, :2]
    fbuckets = _bucket(grid, fxy.min(axis=1) - offsets - pad, fxy.max(axis=1) - offsets + pad,
                       corners[:, :, 2].max(axis=1))
    return grid, vbuckets, ebuckets, fbuckets, tables


def drop_profile(
    index: TriangleIndex,
    radius: float,
    corner_radius: float,
    xy: np.ndarray,
    floor_z: float | np.ndarray,
    progress: Progress | None = None,
) -> np.ndarray:
    """:func:`drop_cutter` for a tool given by its radii (e.g. grown by an allowance).

    Parameters
    ----------
    radius : float
        Cutting radius R [mm], > 0.
    corner_radius : float
        Corner radius rc [mm], 0 <= rc <= R.
    floor_z : float or (n,) float
        The floor [mm], or each point's own: a caller that only compares the heights with a threshold
        passes one just under it, and every primitive that cannot reach it is culled unseen (the
        heights above it are exact all the same).

    See :func:`drop_cutter` for the rest.
    """
    if not (radius > 0 and 0 <= corner_radius <= radius):
        raise ToolpathError(f"drop-cutter needs 0 <= corner radius <= radius > 0, got {corner_radius}, {radius}")
    pts = np.asarray(xy, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ToolpathError(f"CL points must have shape (n, 2), got {pts.shape}")
    n = len(pts)
    floor = np.asarray(floor_z, dtype=np.float64)
    if floor.shape not in ((), (n,)):
        raise ToolpathError(f"the floor must be one height or one per CL point ({n}), got shape {floor.shape}")
    if not np.all(np.isfinite(pts)) or not np.all(np.isfinite(floor)):
        raise ToolpathError("CL points and floor must be finite")
    out = np.broadcast_to(floor, (n,)).copy()
    if n == 0:
        return out

    # Imported here: numba and LLVM cost a process about 110 MB and 0.2 s, paid only by one that drops a cutter
    # (the cell's simulation imports the planner, through op 2, for a plan it need not make).
    from cadcam.dropcontacts import drop_points

    grid, vbuckets, ebuckets, fbuckets, tables = _prepared(index, radius, corner_radius)

    # Sorting by bucket keeps gathers local; results are scattered back at the end.
    ix, iy = grid.cells(pts[:, 0], pts[:, 1])
    cell = iy * grid.nx + ix
    order = np.argsort(cell, kind="stable")
    cell = cell[order]
    cx = pts[order, 0]
    cy = pts[order, 1]
    res = out[order]
    # Chunks of points by their (unculled) vertex candidates; culled work is split again.
    cum = np.cumsum(vbuckets.ptr[cell + 1] - vbuckets.ptr[cell])
    lists = tuple((b.ptr, b.items, b.key, b.z_hi, b.z_span) for b in (vbuckets, fbuckets, ebuckets))

    def drop_range(lo: int, hi: int, report: Progress | None) -> None:
        """Points ``lo:hi`` (in bucket order) into ``res[lo:hi]``; touches nothing else."""
        start = lo
        while start < hi:
            base = cum[start - 1] if start else 0
            stop = int(np.searchsorted(cum, base + _PAIR_BUDGET, side="right"))
            stop = min(max(stop, start + 1), hi)
            # The highest few vertices, then facets, the other vertices and edges, each point's in turn
            # (cadcam.dropcontacts: compiled, the kernels' temporaries were most of a query).
            drop_points(cx[start:stop], cy[start:stop], cell[start:stop], res[start:stop], lists[0], lists[1],
                        lists[2], index.vertices, index.facet_origin, index.facet_e1, index.facet_e2,
                        index.facet_inverse, tables.offsets, tables.edges, radius, corner_radius, _HEAD,
                        _BISECT_STEPS)
            start = stop
            if report is not None:
                report(start - lo)

    workers = _threads_for(int(cum[-1]))
    if workers == 1:
        drop_range(0, n, None if progress is None else (lambda done: progress(done, n)))
    else:
        # Each point's CL z depends on nothing but its own candidates, so disjoint ranges of
        # points run in threads (numpy releases the GIL in the array work) with identical results.
        # Ranges split the candidate count evenly, not the points.
        cuts = [0, *(int(np.searchsorted(cum, cum[-1] * k / workers)) for k in range(1, workers)), n]
        done = [0] * workers
        lock = threading.Lock()

        def report_for(k: int) -> Callable[[int], None] | None:
            if progress is None:
                return None

            def report(d: int) -> None:
                with lock:  # one caller at a time, totals in order
                    done[k] = d
                    progress(sum(done), n)
            return report

        futures = [_pool().submit(drop_range, cuts[k], cuts[k + 1], report_for(k)) for k in range(workers)]
        for f in futures:
            f.result()
    out[order] = res
    return out


#: Candidate vertices (before culling) below which a query runs in the calling thread alone:
#: a thread hand-off (~0.1 ms) is worth it from a few tens of milliseconds of work.
_THREAD_MIN_CANDIDATES = _PAIR_BUDGET // 2
_POOL: concurrent.futures.ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()


def _forget_pool() -> None:
    global _POOL
    _POOL = None  # a forked child has none of the parent's threads: it makes its own pool


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool)


def _threads_for(candidates: int) -> int:
    threads = processors()  # one drop-cutter query's threads
    if threads < 2 or candidates < _THREAD_MIN_CANDIDATES:
        return 1
    return int(min(threads, max(1, candidates // (_THREAD_MIN_CANDIDATES // 2))))


def _pool() -> concurrent.futures.ThreadPoolExecutor:
    """One pool for the process, made on first use (worker threads are daemon-like: idle ones cost nothing)."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = concurrent.futures.ThreadPoolExecutor(max_workers=MAX_WORKERS, thread_name_prefix="dropcutter")
        return _POOL


def drop_cutter(
    index: TriangleIndex,
    tool: Tool,
    xy: np.ndarray,
    floor_z: float,
    progress: Progress | None = None,
) -> np.ndarray:
    """Lowest gouge-free tool tip height at each XY position.

    Parameters
    ----------
    index : TriangleIndex
        From :func:`build_index`.
    tool : Tool
        Flat, ball or bull-nose end mill (profile from ``radius`` and ``corner_radius``).
    xy : (n, 2) float
        Tool axis positions [mm].
    floor_z : float
        The tip never goes below this [mm] (e.g. the stock bottom).
    progress : callable, optional
        ``progress(done, total)`` in CL points, called after each batch.

    Returns
    -------
    (n,) float
        CL (tool tip) z [mm]: the exact contact height, or ``floor_z`` where the tool
        touches nothing.

    Raises
    ------
    ToolpathError
        ``xy`` is not ``(n, 2)`` or not finite, or ``floor_z`` is not finite; ``tool`` is a
        drill (drills only drill: :mod:`cadcam.drilling`).
    """
    if tool.is_drill:
        raise ToolpathError(f"T{tool.number} is a drill: drills are never used for surface milling")
    return drop_profile(index, tool.radius, tool.corner_radius, xy, floor_z, progress)
