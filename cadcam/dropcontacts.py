"""The drop-cutter's contacts, compiled: each CL point's vertices, facets and edges in one pass.

:func:`cadcam.dropcutter.drop_profile` buckets a mesh's primitives and asks, per CL point, the
candidates of its bucket in four rounds: the highest few vertices (a first lower bound), the facets
whose top reaches over it, the other vertices that still can, then the edges. Done with numpy over
(point, candidate) pairs, every round gathers and writes a dozen temporaries per pair, which cost
more than the arithmetic (half of a 100k-triangle relief's waterline and raster, issue 35). Here
one point at a time runs the same rounds with the same formulas, in the same order of operations,
so every contact height is the same number to the bit; no fastmath, so nothing is contracted or
reordered. A choice between two numbers is written as numpy 2's ``maximum``, ``minimum`` and ``clip``
make it (``a if a > b else b``: the second on a tie), so even a zero's sign is theirs.

The only thing that differs is how much is culled: the numpy rounds compared an edge's upper bound
with the point's best contact at the start of its batch, this compares it with the best so far. A
culled edge's bound is under that best by more than its rounding (``_CULL_MARGIN``), so it could not
have given the maximum: the CL heights do not change.
"""

from __future__ import annotations

import math

import numba
import numpy as np

#: An edge whose upper bound is not over the best contact by this much [mm] is not evaluated.
_CULL_MARGIN = 1e-12
#: A bucket prefix is asked down to this share of its list's height span under the best contact.
_STOP_MARGIN = 1e-7
#: The highest bucket fraction a prefix search asks for (keys of the next bucket start at 1).
_STOP_MAX = 0.999999


@numba.njit(cache=True, nogil=True)
def _height(r: float, radius: float, corner: float) -> float:
    """The tool's profile height [mm] at ``0 <= r <= radius`` from its axis."""
    if corner <= 0.0:
        return 0.0
    d = r - (radius - corner)
    d = d if d > 0.0 else 0.0
    k = corner * corner - d * d
    return corner - math.sqrt(k if k > 0.0 else 0.0)


@numba.njit(cache=True, nogil=True)
def _stop(key: np.ndarray, first: int, last: int, bucket: int, below: float, z_hi: float, z_span: float) -> int:
    """End of the prefix of ``key[first:last]`` (bucket ``bucket``'s list) whose top exceeds ``below`` [mm],
    maybe a few more: ``np.searchsorted(key, bucket + frac, "left")`` searched within the bucket's range."""
    z = below - _STOP_MARGIN * z_span
    frac = (z_hi - z) / z_span
    if frac < 0.0:
        frac = 0.0
    if frac > _STOP_MAX:
        frac = _STOP_MAX
    v = float(bucket) + frac
    lo, hi = first, last
    while lo < hi:
        mid = (lo + hi) >> 1
        if key[mid] < v:
            lo = mid + 1
        else:
            hi = mid
    return lo


@numba.njit(cache=True, nogil=True)
def _vertices(vertices, items, first, last, x, y, best, radius, corner):
    """``best`` [mm] raised by the vertex contacts of ``items[first:last]`` at the axis ``x``, ``y`` [mm]."""
    r2 = radius * radius
    for j in range(first, last):
        v = items[j]
        dx = vertices[v, 0] - x
        dy = vertices[v, 1] - y
        d2 = dx * dx + dy * dy
        if d2 <= r2:
            z = vertices[v, 2] - _height(math.sqrt(d2), radius, corner)
            if z > best or z != z:
                best = z
    return best


@numba.njit(cache=True, nogil=True)
def _facets(origin, e1, e2, inverse, offsets, items, first, last, x, y, best, radius, corner):
    """``best`` [mm] raised by the facet contacts of ``items[first:last]``: where the axis moved by a facet's
    contact offset lies inside it, the contact point rebuilt from its barycentrics (a point of the triangle)."""
    for j in range(first, last):
        f = items[j]
        dx = x + offsets[f, 0] - origin[f, 0]
        dy = y + offsets[f, 1] - origin[f, 1]
        b1 = inverse[f, 0, 0] * dx + inverse[f, 0, 1] * dy
        b2 = inverse[f, 1, 0] * dx + inverse[f, 1, 1] * dy
        if b1 >= 0.0 and b2 >= 0.0 and b1 + b2 <= 1.0:
            px = origin[f, 0] + b1 * e1[f, 0] + b2 * e2[f, 0]
            py = origin[f, 1] + b1 * e1[f, 1] + b2 * e2[f, 1]
            pz = origin[f, 2] + b1 * e1[f, 2] + b2 * e2[f, 2]
            r = math.hypot(px - x, py - y)
            r = r if r < radius else radius
            z = pz - _height(r, radius, corner)
            if z > best or z != z:
                best = z
    return best


@numba.njit(cache=True, nogil=True)
def _bull_argmax(s, d2, lo, hi, radius, corner, steps, m):
    """``lo[:m]`` [mm] made the argmax over t in [lo, hi] of s t - h(sqrt(d2 + t^2)) (concave), by bisection on
    its slope, for each of ``m`` edges at once: the steps outside, the edges inside, so the loop runs on
    vectors as numpy's did (one edge's 32 dependent steps after another were slower than numpy)."""
    a = radius - corner
    c2 = corner * corner
    w = hi  # hi is not needed after: its room holds each edge's step
    for q in range(m):
        w[q] = hi[q] - lo[q]
    for _ in range(steps):
        for q in range(m):
            wq = w[q] * 0.5
            w[q] = wq
            mid = lo[q] + wq
            r = math.sqrt(mid * mid + d2[q])
            e = r - a
            e = e if e > 0.0 else 0.0
            k = c2 - e * e
            k = math.sqrt(k if k > 0.0 else 0.0)
            k = k * r
            k = k * s[q]
            # d/dt [s t - h] > 0  <=>  s r k > e t  (h' = e / k, dr/dt = t / r; multiplied out)
            lo[q] = lo[q] + wq if k > e * mid else lo[q]
    for q in range(m):
        lo[q] = lo[q] + 0.5 * w[q]


@numba.njit(cache=True, nogil=True)
def _edge_height(z0, s, tc, t, lo, hi, d2, radius, corner):
    """The contact height [mm] of an edge from its start height ``z0``, slope ``s`` and the axis's foot ``tc`` on
    it, at ``t`` along it from the foot clipped to its chord ``lo``..``hi`` [mm]."""
    t = t if t > lo else lo
    t = t if t < hi else hi
    z = z0 + s * (tc + t)
    r = math.sqrt(d2 + t * t)
    r = r if r < radius else radius
    return z - _height(r, radius, corner)


@numba.njit(cache=True, nogil=True)
def _edges(edges, items, first, last, x, y, best, radius, corner, steps, kept):
    """``best`` [mm] raised by the edge contacts of ``items[first:last]``, each ``edges`` row x0, y0, z0, ux, uy,
    length, slope: the tool cut by the edge's vertical plane, the edge's highest point under it. A bull nose's
    edges are gathered into ``kept`` (8, k) float, bisected together, then evaluated."""
    r2 = radius * radius
    bull = 0.0 < corner < radius
    m = 0
    for j in range(first, last):
        i = items[j]
        wx = x - edges[i, 0]
        wy = y - edges[i, 1]
        tc = wx * edges[i, 3] + wy * edges[i, 4]  # foot of the perpendicular from the axis, along the edge
        d2 = wx * wx + wy * wy - tc * tc
        d2 = d2 if d2 > 0.0 else 0.0
        rho2 = r2 - d2
        if not rho2 >= 0.0:
            continue
        rho = math.sqrt(rho2 if rho2 > 0.0 else 0.0)
        lo = -rho if -rho > -tc else -tc
        hi = rho if rho < edges[i, 5] - tc else edges[i, 5] - tc
        s = edges[i, 6]
        if not lo <= hi:
            continue
        # Upper bound: the edge's highest point over the chord less the profile at the nearest distance.
        top = edges[i, 2] + s * (tc + (hi if s >= 0.0 else lo))
        if corner >= radius:
            top += rho
            top -= radius
        elif corner > 0.0:
            top -= _height(math.sqrt(d2), radius, corner)
        if not top > best - _CULL_MARGIN:
            continue
        if bull:
            kept[0, m], kept[1, m], kept[2, m], kept[3, m] = lo, hi, s, d2
            kept[4, m], kept[5, m], kept[6, m], kept[7, m] = edges[i, 2], tc, lo, hi
            m += 1
            continue
        if corner <= 0.0:  # flat: the edge height is linear over the chord under the flat bottom
            t = rho if s >= 0.0 else -rho
        else:  # ball: the plane cuts a circle of radius rho; its tangent of slope s
            t = s * rho / math.sqrt(1.0 + s * s)
        z = _edge_height(edges[i, 2], s, tc, t, lo, hi, d2, radius, corner)
        if z > best or z != z:
            best = z
    if m:
        _bull_argmax(kept[2], kept[3], kept[0], kept[1], radius, corner, steps, m)
        for q in range(m):
            z = _edge_height(kept[4, q], kept[2, q], kept[5, q], kept[0, q], kept[6, q], kept[7, q], kept[3, q],
                             radius, corner)
            if z > best or z != z:
                best = z
    return best


@numba.njit(cache=True, nogil=True)
def drop_points(cx, cy, cell, best, vertex_lists, facet_lists, edge_lists, vertices, facet_origin, facet_e1,
                facet_e2, facet_inverse, offsets, edges, radius, corner, head, steps):
    """Raise ``best`` (n,) [mm] to each CL point's highest contact, the point at ``cx``, ``cy`` (n,) [mm] in query
    bucket ``cell`` (n,) int.

    ``*_lists`` are each primitive kind's bucket lists as (ptr, items, key, z_hi, z_span) (see
    :class:`cadcam.dropcutter._Buckets`); the rows are :class:`cadcam.dropcutter.TriangleIndex`'s and
    :class:`cadcam.dropcutter._Tables`' arrays. ``head``: vertices asked first per point; ``steps``: the
    bull-nose bisection's.
    """
    vptr, vitems, vkey, vz_hi, vz_span = vertex_lists
    fptr, fitems, fkey, fz_hi, fz_span = facet_lists
    eptr, eitems, ekey, ez_hi, ez_span = edge_lists
    kept = np.empty((8, 256))  # a bull nose's edges to bisect, grown to the longest prefix asked
    for p in range(len(cx)):
        c = cell[p]
        x = cx[p]
        y = cy[p]
        b = best[p]
        first = vptr[c]
        end = vptr[c + 1]
        top_few = min(first + head, end)
        # The highest few vertices give a good lower bound that culls most other candidates.
        b = _vertices(vertices, vitems, first, top_few, x, y, b, radius, corner)
        # Facets are few per point and on smooth meshes nearly exact: a tight bound for the rest.
        stop = _stop(fkey, fptr[c], fptr[c + 1], c, b, fz_hi, fz_span)
        b = _facets(facet_origin, facet_e1, facet_e2, facet_inverse, offsets, fitems, fptr[c], stop, x, y, b,
                    radius, corner)
        stop = max(_stop(vkey, first, end, c, b, vz_hi, vz_span), top_few)
        b = _vertices(vertices, vitems, top_few, stop, x, y, b, radius, corner)
        stop = _stop(ekey, eptr[c], eptr[c + 1], c, b, ez_hi, ez_span)
        if stop - eptr[c] > kept.shape[1]:
            kept = np.empty((8, 2 * (stop - eptr[c])))
        b = _edges(edges, eitems, eptr[c], stop, x, y, b, radius, corner, steps, kept)
        best[p] = b


@numba.njit(cache=True, nogil=True)
def bucket_entries(a, b, ix0, iy0, wx, counts, lo, hi, top, ox, oy, cell, nx, ny, radius, corner, margin):
    """:func:`cadcam.dropcutter._entries` compiled: the (box, bucket, ranking value) entries of boxes ``a:b``,
    box by box, each box's buckets row by row from ``(ix0, iy0)`` over ``wx`` columns (``counts`` in all).

    With ``radius > 0`` only the buckets within ``radius`` [mm] of the box (less ``margin``, the rounding
    allowance) are kept, each ranked by the box's ``top`` less the profile height at that distance; border
    buckets are open beyond the grid. Same formulas in the same order as the numpy entries they replace, so
    the same numbers to the bit; (k,) int32, (k,) int32, (k,) float64.
    """
    total = 0
    for t in range(a, b):
        total += counts[t]
    item = np.empty(total, dtype=np.int32)
    bucket = np.empty(total, dtype=np.int32)
    value = np.empty(total, dtype=np.float64)
    m = 0
    for t in range(a, b):
        w = wx[t]
        for local in range(counts[t]):
            bx = ix0[t] + local % w
            by = iy0[t] + local // w
            v = top[t]
            if radius > 0.0:
                x0 = -np.inf if bx == 0 else ox + bx * cell
                x1 = np.inf if bx == nx - 1 else ox + (bx + 1) * cell
                y0 = -np.inf if by == 0 else oy + by * cell
                y1 = np.inf if by == ny - 1 else oy + (by + 1) * cell
                p = x0 - hi[t, 0]
                q = lo[t, 0] - x1
                dx = p if p > q else q
                dx = dx if dx > 0.0 else 0.0
                p = y0 - hi[t, 1]
                q = lo[t, 1] - y1
                dy = p if p > q else q
                dy = dy if dy > 0.0 else 0.0
                d = math.hypot(dx, dy) - margin
                d = d if d > 0.0 else 0.0
                if not d <= radius:
                    continue
                v = v - _height(d, radius, corner)
            item[m] = t
            bucket[m] = by * nx + bx
            value[m] = v
            m += 1
    return item[:m], bucket[:m], value[:m]
