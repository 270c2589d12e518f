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
        d = a * dx[o]
        d += b * dy[o]
        t = min(max(d * inv_l2[o], 0.0), 1.0)
        ex = a - t * dx[o]
        ey = b - t * dy[o]
        dist2 = ex * ex
        dist2 += ey * ey
        low = zmin[o]
        if profiled:
            dist = math.sqrt(dist2)
            low += _profile(dist, flat_radius[o], rc[o])
            if coned:
                low += cone[o] * min(dist, radius[o])
        lower[i] = low
        reach[i] = dist2 <= reach2[o]
        wx[i] = a
        wy[i] = b
        wd[i] = d
    return lower, reach, wx, wy, wd


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


_told = False


def say_if_compiling() -> None:
    """Log once per process, before the first cut, that the kernel is not in numba's cache yet: the first plan
    after an install compiles it (about 2 s of processor time, longer on a loaded machine); later ones load it."""
    global _told
    if _told:
        return
    _told = True
    try:
        # every cut starts with the nearest approach, and its compiling is most of the wait (numba's compiler
        # starts with it): cold when its index holds no code for this very source (numba drops one whose stamp
        # differs). The others compile when first needed, in under a second of processor time each.
        cold = not nearest_approach._cache._cache_file._load_index()
    except AttributeError:  # another numba's cache layout: say nothing rather than guess
        return
    if cold:
        log.warning("compiling the cut's kernel (cadcam.toolsweep) once for this install: a few seconds")
