"""The drop-cutter's contacts in numpy, as main asked them before they were compiled (issue 35): the
reference :mod:`cadcam.dropcontacts` must give to the bit.

Each of the four rounds (the highest few vertices, facets, the other vertices, edges) works over every
(CL point, candidate) pair of a chunk at once, with the same formulas, in the same order of operations.
"""

from __future__ import annotations

import numpy as np

from cadcam import dropcutter as dc
from cadcam.dropcutter import _height


def numpy_drop_profile(index: dc.TriangleIndex, radius: float, corner: float, xy: np.ndarray,
                       floor: float) -> np.ndarray:
    """:func:`cadcam.dropcutter.drop_profile` (one thread, one floor [mm]) over the same prepared buckets."""
    grid, vbuckets, ebuckets, fbuckets, tables = dc._prepared(index, radius, corner)
    pts = np.asarray(xy, dtype=np.float64)
    ix, iy = grid.cells(pts[:, 0], pts[:, 1])
    c = iy * grid.nx + ix
    best = np.full(len(pts), float(floor))
    cx, cy = pts[:, 0], pts[:, 1]
    first = vbuckets.ptr[c]
    head = np.minimum(first + dc._HEAD, vbuckets.ptr[c + 1])
    _run(_vertex_contacts, index, radius, corner, tables, cx, cy, vbuckets.items, first, head, best)
    _run(_facet_contacts, index, radius, corner, tables, cx, cy, fbuckets.items, fbuckets.ptr[c],
         _stop(fbuckets, c, best), best)
    tail = np.maximum(_stop(vbuckets, c, best), head)
    _run(_vertex_contacts, index, radius, corner, tables, cx, cy, vbuckets.items, head, tail, best)
    _run(_edge_contacts, index, radius, corner, tables, cx, cy, ebuckets.items, ebuckets.ptr[c],
         _stop(ebuckets, c, best), best)
    return best


def _stop(buckets: dc._Buckets, cell: np.ndarray, below: np.ndarray) -> np.ndarray:
    """End of the prefix of each ``cell``'s list whose top z exceeds ``below`` [mm] (maybe a few more), with
    main's margins written out (not the compiled module's constants, which the test checks)."""
    z = below - 1e-7 * buckets.z_span
    frac = np.clip((buckets.z_hi - z) / buckets.z_span, 0.0, 0.999999)
    return np.searchsorted(buckets.key, cell + frac, side="left")


def _run(kernel, index, radius, corner, tables, cx, cy, items, first, last, best) -> None:
    """``kernel`` over every pair of a point and one of its candidates ``items[first:last]``."""
    counts = np.maximum(last - first, 0)
    point = np.repeat(np.arange(len(first)), counts)
    offset = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
    if len(point):
        kernel(index, radius, corner, tables, cx, cy, point, items[np.repeat(first, counts) + offset], best)


def _vertex_contacts(index, radius, corner, tables, cx, cy, point, vi, out) -> None:
    v = index.vertices[vi]
    d2 = (v[:, 0] - cx[point]) ** 2 + (v[:, 1] - cy[point]) ** 2
    ok = d2 <= radius * radius
    point, v, d2 = point[ok], v[ok], d2[ok]
    z = v[:, 2] - _height(np.sqrt(d2), radius, corner)
    np.maximum.at(out, point, z)


def _facet_contacts(index, radius, corner, tables, cx, cy, point, fi, out) -> None:
    offsets = tables.offsets
    dx = cx[point] + offsets[fi, 0] - index.facet_origin[fi, 0]
    dy = cy[point] + offsets[fi, 1] - index.facet_origin[fi, 1]
    inv = index.facet_inverse[fi]
    b1 = inv[:, 0, 0] * dx + inv[:, 0, 1] * dy
    b2 = inv[:, 1, 0] * dx + inv[:, 1, 1] * dy
    ok = (b1 >= 0.0) & (b2 >= 0.0) & (b1 + b2 <= 1.0)
    point, fi, b1, b2 = point[ok], fi[ok], b1[ok], b2[ok]
    p = index.facet_origin[fi] + b1[:, None] * index.facet_e1[fi] + b2[:, None] * index.facet_e2[fi]
    r = np.minimum(np.hypot(p[:, 0] - cx[point], p[:, 1] - cy[point]), radius)
    np.maximum.at(out, point, p[:, 2] - _height(r, radius, corner))


def _edge_contacts(index, radius, corner, tables, cx, cy, point, ei, out) -> None:
    e = tables.edges[ei]
    wx = cx[point] - e[:, 0]
    wy = cy[point] - e[:, 1]
    tc = wx * e[:, 3] + wy * e[:, 4]
    d2 = np.maximum(wx * wx + wy * wy - tc * tc, 0.0)
    rho2 = radius * radius - d2
    ok = rho2 >= 0.0
    rho = np.sqrt(np.maximum(rho2, 0.0))
    lo = np.maximum(-rho, -tc)
    hi = np.minimum(rho, e[:, 5] - tc)
    s = e[:, 6]
    top = e[:, 2] + s * (tc + np.where(s >= 0.0, hi, lo))
    if corner >= radius:
        top += rho
        top -= radius
    elif corner > 0.0:
        top -= _height(np.sqrt(d2), radius, corner)
    ok &= lo <= hi
    ok &= top > out[point] - 1e-12
    keep = np.flatnonzero(ok)
    if not len(keep):
        return
    z0 = e[keep, 2]
    point, tc, d2, rho, lo, hi, s = (a[keep] for a in (point, tc, d2, rho, lo, hi, s))
    if corner <= 0.0:
        t = np.where(s >= 0.0, rho, -rho)
    elif corner >= radius:
        t = s * rho / np.sqrt(1.0 + s * s)
    else:
        t = _bull_edge_argmax(s, d2, lo, hi, radius, corner)
    t = np.clip(t, lo, hi)
    z = z0 + s * (tc + t)
    r = np.minimum(np.sqrt(d2 + t * t), radius)
    np.maximum.at(out, point, z - _height(r, radius, corner))


def _bull_edge_argmax(s, d2, lo, hi, radius, corner):
    a = radius - corner
    c2 = corner * corner
    lo = np.array(lo, dtype=np.float64)
    w = np.asarray(hi, dtype=np.float64) - lo
    for _ in range(dc._BISECT_STEPS):
        w *= 0.5
        mid = lo + w
        r = np.sqrt(mid * mid + d2)
        e = np.maximum(r - a, 0.0)
        k = np.sqrt(np.maximum(c2 - e * e, 0.0))
        k *= r
        k *= s
        lo = np.where(k > e * mid, lo + w, lo)
    return lo + 0.5 * w


def numpy_entries(grid: dc._Grid, lo: np.ndarray, hi: np.ndarray, top: np.ndarray, radius: float, corner: float,
                  ix0: np.ndarray, iy0: np.ndarray, wx: np.ndarray, counts: np.ndarray, a: int, b: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`cadcam.dropcutter._entries` as numpy made them before they were compiled (issue 35): every
    (box, bucket) pair of boxes ``a:b`` at once."""
    total = int(counts[a:b].sum())
    item = a + np.repeat(np.arange(b - a), counts[a:b])
    local = np.arange(total) - np.repeat(np.cumsum(counts[a:b]) - counts[a:b], counts[a:b])
    w = wx[item]
    bx = ix0[item] + local % w
    by = iy0[item] + local // w
    value = top[item]
    if radius > 0.0:
        x0 = np.where(bx == 0, -np.inf, grid.origin[0] + bx * grid.cell)
        x1 = np.where(bx == grid.nx - 1, np.inf, grid.origin[0] + (bx + 1) * grid.cell)
        y0 = np.where(by == 0, -np.inf, grid.origin[1] + by * grid.cell)
        y1 = np.where(by == grid.ny - 1, np.inf, grid.origin[1] + (by + 1) * grid.cell)
        dx = np.maximum(np.maximum(x0 - hi[item, 0], lo[item, 0] - x1), 0.0)
        dy = np.maximum(np.maximum(y0 - hi[item, 1], lo[item, 1] - y1), 0.0)
        d = np.maximum(np.hypot(dx, dy) - 1e-9 * (1.0 + grid.cell * max(grid.nx, grid.ny)), 0.0)
        near = d <= radius
        item, bx, by, value, d = item[near], bx[near], by[near], value[near], d[near]
        value = value - _height(d, radius, corner)
    return item.astype(np.int32), (by * grid.nx + bx).astype(np.int32), value
