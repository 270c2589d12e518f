"""The tool's sweep over (grid point, move) pairs, compiled: each pair's nearest approach and exact envelope, and
the running minimum that gives each move the stock it finds (:mod:`cadcam.envelope`, :mod:`cadcam.stock`).

One pair at a time in a compiled loop, where numpy made a temporary array of every pair for every operation
(issue 35: those temporaries were the cut's cost). Every value is worked out with the same formulas in the same
order as the numpy code these loops replaced (no fast-math: no reordering, no fused multiply-add), so the stock
comes out the same to the bit. ``nogil``: the pairs of the next batch (:class:`cadcam.envelope.BatchPairs`) are
made on the second processor while the main thread cuts. ``cache``: compiled once per install, beside this file
(or in numba's user cache where that is not writable).

The moves' arrays are :class:`cadcam.envelope.Segments`' fields, one row per move, all in mm (``inv_l2`` in
1/mm^2, ``cone`` a drill point's rise per mm of radius); ``owner`` is each pair's move row and ``pick`` the pairs
(indices) to evaluate.
"""

from __future__ import annotations

import logging
import math

import numba
import numpy as np

from cadcam.model import BALL, BULL, CONE  # the kernels read them as constants

log = logging.getLogger(__name__)


_jit = numba.njit(cache=True, nogil=True)


@_jit
def _profile(r, flat_radius, rc):
    """:meth:`Tool.profile_height` at distance ``r`` from the axis [mm], clamped at the radius (no inf)."""
    d = min(max(r - flat_radius, 0.0), rc)
    return rc - math.sqrt(max(rc * rc - d * d, 0.0))


@_jit
def nearest_approach(qx, qy, owner, x, y, dx, dy, inv_l2, zmin, flat_radius, rc, cone, radius, reach2,
                     profiled, coned):
    """Each pair's nearest approach (:class:`cadcam.envelope._Approach`): ``lower, reach, wx, wy, wd``, (k,) each.

    ``qx, qy``: (k,) the grid points [mm]. ``profiled``: add the profile at the nearest approach (False only when
    every move is a flat end mill's, whose profile is 0 there); ``coned``: add the drill point's cone too."""
    k = len(qx)
    lower = np.empty(k)
    reach = np.empty(k, np.bool_)
    wx = np.empty(k)
    wy = np.empty(k)
    wd = np.empty(k)
    for i in range(k):
        o = owner[i]
        a = qx[i] - x[o]
        b = qy[i] - y[o]
        low, dist2, d = _approach(a, b, dx[o], dy[o], inv_l2[o], zmin[o], flat_radius[o], rc[o], cone[o], radius[o],
                                  profiled, coned)
        lower[i] = low
        reach[i] = dist2 <= reach2[o]
        wx[i] = a
        wy[i] = b
        wd[i] = d
    return lower, reach, wx, wy, wd


@_jit
def _approach(a, b, dx, dy, inv_l2, zmin, flat_radius, rc, cone, radius, profiled, coned):
    """One pair's nearest approach, the grid point ``a, b`` from the move's start [mm]: ``lower`` [mm], the squared
    distance [mm^2] and the dot product with the move [mm^2] (:func:`nearest_approach`)."""
    d = a * dx
    d += b * dy
    t = min(max(d * inv_l2, 0.0), 1.0)
    ex = a - t * dx
    ey = b - t * dy
    dist2 = ex * ex
    dist2 += ey * ey
    low = zmin
    if profiled:
        dist = math.sqrt(dist2)
        low += _profile(dist, flat_radius, rc)
        if coned:
            low += cone * min(dist, radius)
    return low, dist2, d


@_jit
def kept_pairs(run_owner, run_row, first, count, nx, x0, y0, cell, stock, x, y, dx, dy, inv_l2, zmin, flat_radius,
               rc, cone, radius, reach2, profiled, coned, table, block, piece):
    """The pairs of the runs ``run_owner, run_row, first, count`` (:func:`row_spans`') that can cut ``stock``
    (ny * nx,) [mm]: within the radius, their nearest approach's ``lower`` under the stock there; in the runs'
    order. ``owner, flat, col, row`` (k,) int64 and ``lower, wx, wy, wd`` (k,) float, each value as
    :func:`run_pairs` then :func:`nearest_approach` on the grid points ``x0 + col * cell, y0 + row * cell`` [mm]
    give it (the same formulas in the same order); the pairs that cannot cut are never written out.

    ``table``: a :class:`cadcam.envelope.SpanTops`' (levels, ny, blocks of ``block`` columns), bounds of the stock
    (no levels: none). With it a run, then each of its pieces of ``piece`` columns (on multiples of it), is
    walked only where the move can come under them (:func:`row_lower`'s bound, as
    :func:`cadcam.envelope.grid_runs` judges them): a pair of a run left out has its ``lower`` at or over the
    stock, so it would not be kept either, and the pairs are the same whatever the bounds."""
    total = 0
    for i in range(len(count)):
        total += max(count[i], 0)
    ints = np.empty((4, total), np.int64)  # owner, flat, col, row
    floats = np.empty((4, total))  # lower, wx, wy, wd
    culled = table.shape[0] > 0
    k = 0
    for r in range(len(count)):
        if count[r] <= 0:
            continue
        o = run_owner[r]
        j = run_row[r]
        yr = y0 + j * cell
        ya = y[o]
        yb = ya + dy[o]
        gap = max(max(min(ya, yb) - yr, yr - max(ya, yb)), 0.0)
        stop = first[r] + count[r]
        if culled and _lower_at(gap, zmin[o], flat_radius[o], rc[o], cone[o], radius[o]) >= _top(
                table, block, j, first[r], count[r]):
            continue
        b = yr - y[o]
        p = first[r] // piece
        while p * piece < stop:
            a = max(p * piece, first[r])
            e = min((p + 1) * piece, stop)
            p += 1
            if culled:
                xs = x[o]
                xe = xs + dx[o]
                across = max(max(min(xs, xe) - (x0 + (e - 1) * cell), (x0 + a * cell) - max(xs, xe)), 0.0)
                if _lower_at(math.hypot(gap, across), zmin[o], flat_radius[o], rc[o], cone[o], radius[o]) >= _top(
                        table, block, j, a, e - a):
                    continue
            for c in range(a, e):
                f = j * nx + c
                if not zmin[o] < stock[f]:  # the profile and the cone only add to the lowest tip height: never kept
                    continue
                a_ = (x0 + c * cell) - x[o]
                low, dist2, d = _approach(a_, b, dx[o], dy[o], inv_l2[o], zmin[o], flat_radius[o], rc[o], cone[o],
                                          radius[o], profiled, coned)
                if dist2 <= reach2[o] and low < stock[f]:
                    ints[0, k], ints[1, k], ints[2, k], ints[3, k] = o, f, c, j
                    floats[0, k], floats[1, k], floats[2, k], floats[3, k] = low, a_, b, d
                    k += 1
    return (ints[0, :k], ints[1, :k], ints[2, :k], ints[3, :k],
            floats[0, :k], floats[1, :k], floats[2, :k], floats[3, :k])


@_jit
def _lower_at(gap, zmin, flat_radius, rc, cone, radius):
    """:func:`row_lower`'s bound of one move [mm] at ``gap`` [mm] from the box round its XY segment."""
    dist = max(gap - 1e-7, 0.0)
    low = zmin
    low += _profile(dist, flat_radius, rc)
    low += cone * min(dist, radius)
    return low


@_jit
def _top(table, block, row, first, count):
    """:func:`span_tops_above` of one run."""
    b0 = first // block
    b1 = (first + count - 1) // block
    k = 0
    while (2 << k) <= b1 - b0 + 1:  # floor(log2(b1 - b0 + 1))
        k += 1
    return max(table[k, row, b0], table[k, row, b1 - (1 << k) + 1])


@_jit
def _reach_along(wx, wy, wd, dx, dy, l2, R):
    """``cross, s, ta, tb``: the interval of t where r(t) <= R, the roots of l2 t^2 - 2 wd t + |w|^2 - R^2
    clipped to the move (the discriminant ``s`` written with the cross product avoids cancellation)."""
    cross = wx * dy - wy * dx
    s = math.sqrt(max(l2 * R * R - cross * cross, 0.0))
    ta = min(max((wd - s) / l2, 0.0), 1.0)
    tb = max(min(max((wd + s) / l2, 0.0), 1.0), ta)
    return cross, s, ta, tb


@_jit
def bisected_lengths(wx, wy, wd, owner, pick, dx, dy, dz, l2, radius):
    """(len(pick),) how long the stretch of each picked pair's move is that its bull-nose bisection searches [mm]."""
    out = np.empty(len(pick))
    for j in range(len(pick)):
        i = pick[j]
        o = owner[i]
        _, _, ta, tb = _reach_along(wx[i], wy[i], wd[i], dx[o], dy[o], l2[o], radius[o])
        out[j] = (tb - ta) * math.sqrt(dx[o] * dx[o] + dy[o] * dy[o] + dz[o] * dz[o])
    return out


@_jit
def _at(t, wx, wy, dx, dy, z0, dz, a, rc):
    """The bull-nose's lowest point over the grid point with the tip at ``t`` along the move [mm]."""
    ex = wx - t * dx
    ey = wy - t * dy
    return z0 + dz * t + _profile(math.sqrt(ex * ex + ey * ey), a, rc)


#: Bull-nose pairs bisected together: each step's arrays stay in the processor's nearest cache, and the step's
#: loop over them has no branch, so the compiler runs it on several pairs per instruction (sqrt and division
#: give the same bits there as one at a time).
_BISECT_BLOCK = 256


#: Bull-nose pairs bisected together, a step at a time over the block: its arrays stay in the processor's nearest
#: cache and the steps of different pairs overlap in the pipeline (a quarter less time than each pair's steps in
#: turn, measured on 344k pairs; each pair's arithmetic is the same).
_BISECT_BLOCK = 256


@_jit
def _bisect(out, put, wx, wy, dx, dy, z0, dz, a, rc, ta, tb, steps):
    """``out[put[j]]``: the minimum of the convex ``f(t) = z0 + dz t + h(r(t))`` on ``[ta[j], tb[j]]`` for every
    bull-nose pair ``j`` (``a`` its flat radius [mm]; (n,) arrays each).

    ``f`` is C1 inside the interval (the profile is flat at ``r = 0`` and tangent where the corner starts), so
    its minimum is an end or a zero of the non-decreasing ``f'``, found by ``steps`` halvings on its sign."""
    n = len(put)
    lo = ta.copy()
    hi = tb.copy()
    for s in range(0, n, _BISECT_BLOCK):
        e = min(s + _BISECT_BLOCK, n)
        for _ in range(steps):
            for j in range(s, e):
                mid = (lo[j] + hi[j]) * 0.5
                ex = wx[j] - mid * dx[j]
                ey = wy[j] - mid * dy[j]
                r = ex * ex
                r += ey * ey
                r = math.sqrt(r)
                d = min(max(r - a[j], 0.0), rc[j])
                # f' = dz + h'(r) r'(t), h' = d / sqrt(rc^2 - d^2), r' = -(e . d) / r; the tiny floors only
                # matter where h' is 0 (d = 0) or the tool rim is reached
                num = ex * dx[j]
                num += ey * dy[j]
                num *= d
                den = math.sqrt(max(rc[j] * rc[j] - d * d, 1e-300))
                den *= max(r, 1e-300)
                right = dz[j] - num / den < 0.0
                lo[j] = mid if right else lo[j]
                hi[j] = hi[j] if right else mid
    for j in range(n):
        args = (wx[j], wy[j], dx[j], dy[j], z0[j], dz[j], a[j], rc[j])
        out[put[j]] = min(_at(0.5 * (lo[j] + hi[j]), *args), min(_at(ta[j], *args), _at(tb[j], *args)))


@_jit
def _cone(wx, wy, dx, dy, z0, dz, l2, wd, cross, R, k, ta, tb):
    """Minimum of the convex ``f(t) = z0 + dz t + k r(t)`` on ``[ta, tb]`` (a drill's cone).

    With ``u = t - wd / l2`` the distance is ``r = sqrt(p^2 + l2 u^2)``, ``p`` the perpendicular distance from
    the line; ``f' = 0`` where ``sqrt(l2) u / r = -dz / (k sqrt(l2))``. Convex, so the stationary point clipped
    to the interval is the minimum; without one (the move is steeper than the flank) an end is."""
    L = math.sqrt(l2)
    p = abs(cross) / L
    sgn = -dz / (k * L)
    if abs(sgn) < 1.0:
        u = sgn * p / (L * math.sqrt(max(1.0 - sgn * sgn, 1e-300)))
    else:
        u = math.inf if sgn > 0.0 else -math.inf
    t = min(max(wd / l2 + u, ta), tb)
    r = min(math.hypot(wx - t * dx, wy - t * dy), R)
    return z0 + dz * t + k * r


@_jit
def sloped_envelope(wx, wy, wd, owner, pick, z, dx, dy, dz, l2, radius, rc, cone, shape, steps):
    """(len(pick),) the exact envelope [mm] of picked pairs whose moves climb or descend while moving sideways.

    ``steps``: the bull-nose's bisection steps (:func:`cadcam.envelope._bisect_steps`)."""
    n = len(pick)
    out = np.empty(n)
    # the bull-nose pairs, gathered for :func:`_bisect`: where in ``out``, then its arguments
    nb = 0
    put = np.empty(n, np.int64)
    bull = np.empty((10, n))
    for j in range(n):
        i = pick[j]
        o = owner[i]
        a, b, d = wx[i], wy[i], wd[i]
        z0, ddz, L2, R = z[o], dz[o], l2[o], radius[o]
        cross, s, ta, tb = _reach_along(a, b, d, dx[o], dy[o], L2, R)
        # Flat end mill: linear in t on the interval, so one of its ends. Also the fallback for ball points
        # right at the reach limit (below).
        env = z0 + min(ddz * ta, ddz * tb)
        kind = shape[o]
        if kind == BALL:
            R2 = R * R
            # Lowest entry of the vertical line through q into the capsule swept by the ball centre: the
            # infinite cylinder round the centre's path if the entry's foot lies on the move, else one of the
            # end spheres (both are inside the capsule, so the minimum of all valid candidates is the entry).
            D2 = L2 + ddz * ddz
            u = (ddz * d - math.sqrt(D2) * s) / L2
            t = (d + ddz * u) / D2
            best = z0 + R + u if t >= 0.0 and t <= 1.0 else math.inf
            w2 = a * a + b * b
            ex = a - dx[o]
            ey = b - dy[o]
            e2 = ex * ex + ey * ey
            if w2 <= R2:
                best = min(best, z0 + R - math.sqrt(max(R2 - w2, 0.0)))
            if e2 <= R2:
                best = min(best, z0 + ddz + R - math.sqrt(max(R2 - e2, 0.0)))
            # Rounding can leave a point right at the reach limit without a valid candidate; the tool
            # touches it only with its rim there, at the interval end's height + R.
            env = best if math.isfinite(best) else env + R
        elif kind == BULL:
            put[nb] = j
            bull[0, nb], bull[1, nb], bull[2, nb], bull[3, nb], bull[4, nb] = a, b, dx[o], dy[o], z0
            bull[5, nb], bull[6, nb], bull[7, nb], bull[8, nb], bull[9, nb] = ddz, R - rc[o], rc[o], ta, tb
            nb += 1
        elif kind == CONE:
            env = _cone(a, b, dx[o], dy[o], z0, ddz, L2, d, cross, R, cone[o], ta, tb)
        out[j] = env
    if nb:
        g = bull[:, :nb].copy()
        _bisect(out, put[:nb], g[0], g[1], g[2], g[3], g[4], g[5], g[6], g[7], g[8], g[9], steps)
    return out


@_jit
def segmented_exclusive_min(group, value):
    """Running minimum of ``value`` within each run of equal ``group`` (sorted), excluding the entry itself.

    ``inf`` starts each run and stands for ``inf`` in ``value``. Each run is lifted below every earlier one by a
    multiple of the values' span and one running minimum goes through all of them; the minimum is then read
    back from the entry that holds it (the last entry at or below it), so it is one of the values, whatever
    the lift rounded, and does not depend on how moves are batched."""
    n = len(value)
    out = np.full(n, np.inf)
    lo = np.inf
    hi = -np.inf
    for i in range(n):
        v = value[i]
        if math.isfinite(v):
            lo = min(lo, v)
            hi = max(hi, v)
    if not lo <= hi:
        return out
    span = hi - lo + 1.0
    runs = 0
    for i in range(1, n):
        if group[i] != group[i - 1]:
            runs += 1
    run = 0
    running = np.inf
    holder = 0
    for i in range(n):
        if i > 0 and group[i] != group[i - 1]:
            run += 1
        elif i > 0:
            out[i] = value[holder]
        v = value[i]
        lifted = (v - lo if math.isfinite(v) else span) + (runs - run) * (2.0 * span)
        running = min(running, lifted)
        if lifted <= running:
            holder = i
    return out


@_jit
def cut_in_turn(flat, env, stock, under, has_under):
    """Each pair in its turn cuts the stock the pairs before it left: ``stock[flat[i]]`` lowered to ``env[i]`` where
    that is lower [mm], in place. Returns ``cut, before``: the pairs that took something off (indices, in order)
    and the stock each of them found [mm].

    The pairs come move by move, each grid point once a move, so the stock a pair finds is the batch's stock less
    every earlier move's cut there: :func:`segmented_exclusive_min`'s answer over pairs sorted by point, without
    the sort (for a batch with no shank or holder pairs, :func:`cadcam.stock._run_batch`). ``has_under``: a column
    at or below ``under`` [mm] (cut through) holds nothing (found as ``-inf``); the caller empties those after."""
    n = len(flat)
    cut = np.empty(n, np.int64)
    before = np.empty(n)
    k = 0
    for i in range(n):
        f = flat[i]
        found = stock[f]
        if has_under and not found > under[f]:
            found = -np.inf
        if found - env[i] > 0.0:  # the test of removed > 0, on the same difference
            cut[k] = i
            before[k] = found
            stock[f] = env[i]
            k += 1
    return cut[:k], before[:k]


@_jit
def _index(v, origin, cell, n, first):
    """:func:`cadcam.heightmap._index_range`'s first (``first``) or last index of one value ``v`` [mm]."""
    if first:
        return int(min(max(np.ceil((v - origin) / cell - 1e-9), 0.0), float(n)))
    return int(min(max(np.floor((v - origin) / cell + 1e-9), -1.0), float(n - 1)))


@_jit
def row_spans(x, y, dx, dy, radius, x0, y0, cell, nx, ny):
    """:func:`cadcam.envelope._row_spans` on a grid of ``nx`` by ``ny`` points from ``(x0, y0)``, ``cell`` apart
    [mm]: ``owner, row, first, count`` (r,) int64, each move's rows in order, each row's run of columns."""
    m = len(x)
    reach = np.empty(m)
    j0 = np.empty(m, np.int64)
    nj = np.empty(m, np.int64)
    total = 0
    for i in range(m):
        R = radius[i] * (1 + 1e-9) + 1e-9  # the exact reach test comes later; never lose a point here
        y1 = y[i] + dy[i]
        j0[i] = _index(min(y[i], y1) - R, y0, cell, ny, True)
        nj[i] = max(_index(max(y[i], y1) + R, y0, cell, ny, False) - j0[i] + 1, 0)
        reach[i] = R
        total += nj[i]
    owner = np.empty(total, np.int64)
    row = np.empty(total, np.int64)
    first = np.empty(total, np.int64)
    count = np.empty(total, np.int64)
    k = 0
    for i in range(m):
        Ro, ax, ay, ddx, ddy = reach[i], x[i], y[i], dx[i], dy[i]
        l2 = ddx * ddx + ddy * ddy
        L = math.sqrt(l2)
        for j in range(j0[i], j0[i] + nj[i]):
            yr = y0 + j * cell
            lo, hi = np.inf, -np.inf
            for cx, cy in ((ax, ay), (ax + ddx, ay + ddy)):  # the end disks
                h2 = Ro * Ro - (yr - cy) * (yr - cy)
                if h2 >= 0:
                    half = math.sqrt(max(h2, 0.0))
                    lo, hi = min(lo, cx - half), max(hi, cx + half)
            if l2 > 1e-18:  # the band: 0 <= (p - a).d <= |d|^2 and |(p - a) x d| <= R |d|, each linear in x
                ey = yr - ay
                if ddx != 0:
                    u_lo, u_hi = -ey * ddy / ddx, (l2 - ey * ddy) / ddx
                    lo_u, hi_u = min(u_lo, u_hi), max(u_lo, u_hi)
                elif ey * ddy >= 0 and ey * ddy <= l2:
                    lo_u, hi_u = -np.inf, np.inf
                else:
                    lo_u, hi_u = np.inf, -np.inf
                if ddy != 0:
                    v_lo, v_hi = (ey * ddx - Ro * L) / ddy, (ey * ddx + Ro * L) / ddy
                    lo_v, hi_v = min(v_lo, v_hi), max(v_lo, v_hi)
                elif abs(ey * ddx) <= Ro * L:
                    lo_v, hi_v = -np.inf, np.inf
                else:
                    lo_v, hi_v = np.inf, -np.inf
                lo, hi = min(lo, ax + max(lo_u, lo_v)), max(hi, ax + min(hi_u, hi_v))
            owner[k], row[k] = i, j
            first[k] = _index(lo, x0, cell, nx, True)
            count[k] = max(_index(hi, x0, cell, nx, False) - first[k] + 1, 0)
            k += 1
    return owner, row, first, count


@_jit
def run_pieces(owner, row, first, count, piece):
    """The live runs (``count`` > 0) of :func:`row_spans` cut into pieces at the multiples of ``piece`` columns,
    in order: ``owner, row, start, count`` (p,) int64 (:func:`cadcam.envelope._live_pieces`)."""
    total = 0
    for i in range(len(count)):
        if count[i] > 0:
            total += (first[i] + count[i] - 1) // piece - first[i] // piece + 1
    out = np.empty((4, total), np.int64)  # owner, row, start, count
    k = 0
    for i in range(len(count)):
        stop = first[i] + count[i]
        b = first[i] // piece
        while count[i] > 0 and b * piece < stop:
            a = max(b * piece, first[i])
            out[0, k], out[1, k], out[2, k], out[3, k] = owner[i], row[i], a, min((b + 1) * piece, stop) - a
            k += 1
            b += 1
    return out[0], out[1], out[2], out[3]


@_jit
def run_pairs(owner, row, first, count, nx):
    """Every grid point of the runs ``owner, row, first, count``, in order: ``owner, flat, col, row`` (k,) int64
    (:func:`cadcam.envelope.grid_pairs`)."""
    total = 0
    for i in range(len(count)):
        total += max(count[i], 0)
    out = np.empty((4, total), np.int64)  # owner, flat, col, row
    k = 0
    for i in range(len(count)):
        for c in range(first[i], first[i] + count[i]):
            out[0, k], out[1, k], out[2, k], out[3, k] = owner[i], row[i] * nx + c, c, row[i]
            k += 1
    return out[0], out[1], out[2], out[3]


@_jit
def row_lower(owner, yr, xa, xb, x, y, dx, dy, zmin, flat_radius, rc, cone, radius, across):
    """:func:`cadcam.envelope.row_lower`, (k,): ``across`` False reads ``xa, xb`` not (the whole row)."""
    k = len(owner)
    lower = np.empty(k)
    for i in range(k):
        o = owner[i]
        y0 = y[o]
        y1 = y0 + dy[o]
        gap = max(max(min(y0, y1) - yr[i], yr[i] - max(y0, y1)), 0.0)
        if across:
            x0 = x[o]
            x1 = x0 + dx[o]
            gap = math.hypot(gap, max(max(min(x0, x1) - xb[i], xa[i] - max(x0, x1)), 0.0))
        lower[i] = _lower_at(gap, zmin[o], flat_radius[o], rc[o], cone[o], radius[o])
    return lower


@_jit
def span_tops_above(table, block, row, first, count):
    """:meth:`cadcam.envelope.SpanTops.above` of its ``table`` and ``block``: (r,) the larger of the two entries
    covering each run of ``count`` columns from ``first`` on ``row``."""
    out = np.empty(len(row))
    for i in range(len(row)):
        out[i] = _top(table, block, row[i], first[i], count[i])
    return out


@_jit
def block_tops(top, block):
    """(ny, ceil(nx / block)) the highest of each run of ``block`` columns of each row of ``top`` (ny, nx) [mm], as
    ``np.max`` over them gives it (NaN wins): :class:`cadcam.envelope.SpanTops`' first level."""
    ny, nx = top.shape
    nb = -(-nx // block)
    out = np.empty((ny, nb))
    for j in range(ny):
        for b in range(nb):
            m = -np.inf
            for i in range(b * block, min((b + 1) * block, nx)):
                v = top[j, i]
                if m == m and (v != v or v > m):
                    m = v
            out[j, b] = m
    return out


@_jit
def across(o, qx, qy, x, y, dx, dy, l2):
    """:func:`cadcam.engagement._across`: (k,) the signed distance [mm] of each grid point across its move ``o``
    (along X for a move with no length across), and (k,) bool whether the move has a length across."""
    k = len(o)
    lat = np.empty(k)
    has = np.empty(k, np.bool_)
    for i in range(k):
        m = o[i]
        L = math.sqrt(l2[m])
        has[i] = L > 1e-9
        wx = qx[i] - x[m]
        wy = qy[i] - y[m]
        lat[i] = wx * (dy[m] / L) - wy * (dx[m] / L) if has[i] else wx
    return lat, has


@_jit
def _clip(v, lo, hi):
    """``np.clip`` of one value (NaN stays NaN)."""
    return v if v != v else min(max(v, lo), hi)


#: The chip kernels: a division by zero gives inf or NaN, as numpy's.
_chip_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_chip_jit
def side_chips(o, qx, qy, w, before, env, cell, s, chip, x, y, z, dx, dy, dz, l2, radius, rc, shape):
    """:func:`cadcam.engagement._side_chip`: each pair's chip share, the largest per move kept in ``chip[o + s]``
    (NaN kept, as ``np.maximum``)."""
    for i in range(len(o)):
        m = o[i]
        c = _chip_share(qx[i] - x[m], qy[i] - y[m], w[i], before[i], env[i], cell, z[m], dx[m], dy[m], dz[m], l2[m],
                        radius[m], rc[m], shape[m])
        cur = chip[m + s]
        if cur == cur and not c <= cur:
            chip[m + s] = c


@_chip_jit
def side_chip_pairs(o, qx, qy, before, env, cell, s, chip, film, x, y, z, dx, dy, dz, l2, radius, rc, shape):
    """:func:`cadcam.engagement.side_chip`: of the pairs whose move takes more than ``film`` [mm] off the point
    sideways (a move with a length across, less what it takes descending over the point: :func:`across`,
    :func:`cadcam.engagement._plunged`), the chip share, the largest per move kept in ``chip[o + s]``; each value
    as those functions and :func:`side_chips` give it (the same formulas in the same order)."""
    for i in range(len(o)):
        m = o[i]
        removed = before[i] - env[i]
        L = math.sqrt(l2[m])
        wx = qx[i] - x[m]
        wy = qy[i] - y[m]
        if not (removed > film and L > 1e-9):
            continue
        plunge = 0.0
        if dz[m] < 0.0:  # cadcam.envelope.reach_interval's ends, as numpy works them out
            R = radius[m]
            has = l2[m] > 1e-18
            cross = wx * dy[m] - wy * dx[m]
            root = math.sqrt(max(l2[m] * R * R - cross * cross, 0.0))
            wd = wx * dx[m] + wy * dy[m]
            ta = _clip((wd - root) / (l2[m] if has else 1.0), 0.0, 1.0) if has else 0.0
            tb = _clip((wd + root) / (l2[m] if has else 1.0), 0.0, 1.0) if has else 1.0
            if l2[m] * R * R * (1 + 1e-12) < cross * cross or (not has and math.hypot(wx, wy) > R * (1 + 1e-12)):
                ta, tb = 1.0, 0.0
            plunge = _nan_min(removed, -dz[m] * _nan_max(tb - ta, 0.0))
        if not removed - plunge > film:
            continue
        lat = wx * (dy[m] / L) - wy * (dx[m] / L)
        c = _chip_share(wx, wy, lat, before[i], env[i], cell, z[m], dx[m], dy[m], dz[m], l2[m], radius[m], rc[m],
                        shape[m])
        cur = chip[m + s]
        if cur == cur and not c <= cur:  # NaN kept, as np.maximum
            chip[m + s] = c


@_jit
def _nan_min(a, b):
    """``np.minimum`` of two values (NaN wins)."""
    return a if a != a else (b if b != b or b < a else a)


@_jit
def _nan_max(a, b):
    """``np.maximum`` of two values (NaN wins)."""
    return a if a != a else (b if b != b or b > a else a)


@_chip_jit
def _chip_share(ax, ay, w, before, env, cell, z, dx, dy, dz, l2, r, rc, shape):
    """The chip share of one pair: a move from ``z`` by ``dx, dy, dz`` (``l2`` its length across squared) [mm] with a
    tool of radius ``r``, corner ``rc`` [mm] and ``shape``, at the grid point ``ax, ay`` from its start [mm], ``w``
    [mm] across its line, the stock there from ``env`` up to ``before`` [mm] (:func:`cadcam.engagement._side_chip`).
    Scalars only: no array's reference count taken for every pair."""
    level = dz == 0.0
    if shape == BALL and not level:
        # the ball on a slope: the column's point at height h is a + h e_z from the centre's start; its squared
        # distance from the line is quadratic in h, least at h0, taken within the column (``env`` to ``before``)
        length = math.sqrt(l2 + dz * dz)
        ux, uy, uz = dx / length, dy / length, dz / length
        az = -(z + r)
        au = ax * ux + ay * uy + az * uz
        h = min(max(-(az - au * uz) / max(1.0 - uz * uz, 1e-12), env), before)
        vz = az + h
        vu = au + h * uz
        d = math.sqrt(max(ax * ax + ay * ay + vz * vz - vu * vu, 0.0))
        near = _clip((d - 0.5 * cell) / r, 0.0, 1.0)
        return math.sqrt(1.0 - near * near)
    c_r = 0.0 if (shape == CONE or not level) else rc
    below = max(c_r - (before - z), 0.0)  # how far under the corner's centre the stock's top stands
    reach = math.sqrt(max(c_r * c_r - below * below, 0.0))  # c_r on the flutes
    rho = (r - c_r) + reach
    lead = reach / c_r if c_r > 0.0 else 1.0
    near = _clip((abs(w) - 0.5 * cell) / rho, 0.0, 1.0)
    return lead * math.sqrt(1.0 - near * near)


_told = False


def say_if_compiling() -> None:
    """Log once per process, before the first cut, that the kernel is not in numba's cache yet: the first plan
    after an install compiles it (about 2 s of processor time, longer on a loaded machine); later ones load it."""
    global _told
    if _told:
        return
    _told = True
    try:
        # every cut starts with the pairs that can cut, and its compiling is most of the wait (numba's compiler
        # starts with it): cold when its index holds no code for this very source (numba drops one whose stamp
        # differs). The others compile when first needed, in under a second of processor time each.
        cold = not kept_pairs._cache._cache_file._load_index()
    except AttributeError:  # another numba's cache layout: say nothing rather than guess
        return
    if cold:
        log.warning("compiling the cut's kernel (cadcam.toolsweep) once for this install: a few seconds")
