"""Waterline loops put exactly on their level of a drop-cutter CL surface.

A contour of the CL height map on a grid is only as good as the grid. These functions move
each contour vertex onto the exact iso-line (the gouge-free side of it), and split the chords
between vertices until none rises more than half the tolerance above its level, so a
waterline loop is gouge-free and within tolerance by construction, not by sampling luck.
Lengths are in millimetres.
"""

from __future__ import annotations

import logging
import math
from typing import Protocol

import numpy as np

log = logging.getLogger(__name__)


class ClSurface(Protocol):
    """An exact CL surface: the drop-cutter height [mm] of a tool of ``radius`` [mm] at XY."""

    radius: float

    def z(self, xy: np.ndarray, *, floor: np.ndarray | None = None) -> np.ndarray:
        """CL z [mm] at ``xy`` (n, 2) [mm]; where it is below ``floor`` (n,) [mm], ``floor`` to a rounding."""
        ...


#: Bracket length [mm] at which a loop vertex counts as located on its iso-line: 1/100 of
#: the G-code's 0.0001 mm (40 plain bisections of the grid step went to sub-nm, for nothing).
_ISO_RESOLUTION = 1e-6
#: A bracket whose ends' CL z are both within this of the level is done sooner [mm].
_ISO_Z_RESOLUTION = 1e-7
#: CL z step across a located bracket [mm] that counts as a jump of the surface (a wall).
_ISO_JUMP = 1e-4
#: A height compared with a threshold is made exact from this far under it [mm] (:func:`z_near`): far over
#: the rounding of a floor less and plus the allowance, far under any tolerance.
_CULL_MARGIN = 1e-9
#: Steps of :func:`onto_level` at most (a bracket halves at least every other step).
_ISO_MAX_STEPS = 60
#: Rounds of chord checking; each halves the chords that still cut in.
_CHORD_ROUNDS = 14


def z_near(surface: ClSurface, xy: np.ndarray, threshold: np.ndarray) -> np.ndarray:
    """The CL z [mm] at ``xy`` (n, 2) [mm] for comparing with ``threshold`` (n,) [mm]: exact from
    :data:`_CULL_MARGIN` under it up, elsewhere that floor (to a rounding), so every comparison
    with the threshold comes out as with the exact heights. The drop-cutter culls every primitive
    that cannot reach the floor: most of them, where the threshold lies near the surface.
    """
    return surface.z(xy, floor=threshold - _CULL_MARGIN)


def onto_iso(surface: ClSurface, xy, lev, gx, gy, Z, tolerance):
    """Move contour vertices onto the exact iso-lines; also return each one's outward direction."""
    g = gx[1] - gx[0]
    fx = (xy[:, 0] - gx[0]) / (gx[1] - gx[0])
    fy = (xy[:, 1] - gy[0]) / (gy[1] - gy[0])
    on_col = np.abs(fx - np.round(fx)) < 1e-7
    # A vertex on a column lies on a vertical grid edge, otherwise on a horizontal one.
    i0 = np.where(on_col, np.round(fx), np.floor(fx)).astype(np.int64)
    j0 = np.where(on_col, np.floor(fy), np.round(fy)).astype(np.int64)
    i0 = np.clip(i0, 0, len(gx) - 1)
    j0 = np.clip(j0, 0, len(gy) - 1)
    i1 = np.clip(np.where(on_col, i0, i0 + 1), 0, len(gx) - 1)
    j1 = np.clip(np.where(on_col, j0 + 1, j0), 0, len(gy) - 1)
    pa = np.column_stack([gx[i0], gy[j0]])
    pb = np.column_stack([gx[i1], gy[j1]])
    za, zb = Z[j0, i0], Z[j1, i1]
    a_in = za >= lev
    bracket = a_in != (zb >= lev)
    p_in = np.where(a_in[:, None], pa, pb)
    p_out = np.where(a_in[:, None], pb, pa)
    sel = np.flatnonzero(bracket)
    z_in, z_out = np.where(a_in, za, zb)[sel], np.where(a_in, zb, za)[sel]
    pi, po, lv = onto_level(surface, p_in[sel], p_out[sel], lev[sel], zi=z_in, zo=z_out)
    out = xy.copy()
    out[sel] = po
    outward = np.zeros_like(xy)
    d = po - pi
    outward[sel] = d / np.maximum(np.hypot(*d.T), 1e-300)[:, None]
    # Where the surface jumps across the bracket, step out a little: the tool side is on a wall.
    jump = z_near(surface, pi, lv + _ISO_JUMP) - lv > _ISO_JUMP
    if np.any(jump):
        k = sel[jump]
        pushed = po[jump] + 0.5 * tolerance * outward[k]
        free = z_near(surface, pushed, lv[jump]) <= lv[jump]
        out[k[free]] = pushed[free]
    unbracketed = np.flatnonzero(~bracket)
    if len(unbracketed):
        log.warning("%d contour vertices without a bracketing grid edge", len(unbracketed))
    return out, outward


def onto_level(surface: ClSurface, pi, po, lv, zi=None, zo=None):
    """Shrink each bracket [pi, po] onto the point where the CL surface crosses its level.

    Parameters
    ----------
    pi, po : (n, 2) float
        Bracket ends [mm]: the CL z at ``pi`` is above ``lv``, at ``po`` at or below it.
    lv : (n,) float
        Levels [mm].
    zi, zo : (n,) float, optional
        The exact CL z at ``pi`` and ``po`` if known [mm] (saves two evaluations).

    Returns
    -------
    pi, po, lv : (n, 2), (n, 2), (n,) float
        The shrunk brackets, the same invariant kept: ``po`` is exactly where the CL z was
        found at or below the level (the gouge-free end), ``pi`` where it was above.

    Safeguarded false position (the Illinois variant): a step interpolates the CL z linearly
    between the two ends; a step that did not halve the bracket is followed by a
    bisection, so where the surface jumps (the tool's side on a vertical wall) the
    bracket still halves at least every other step. A bracket is done when it is shorter
    than ``_ISO_RESOLUTION`` or both ends are within ``_ISO_Z_RESOLUTION`` of the level.
    Each step evaluates only the brackets still open.
    """
    pi = np.array(pi, dtype=np.float64).reshape(-1, 2)
    po = np.array(po, dtype=np.float64).reshape(-1, 2)
    lv = np.asarray(lv, dtype=np.float64).reshape(-1)
    n = len(pi)
    if n == 0:
        return pi, po, lv
    fi = (surface.z(pi) if zi is None else np.asarray(zi, dtype=np.float64)) - lv
    fo = (surface.z(po) if zo is None else np.asarray(zo, dtype=np.float64)) - lv
    true_fi, true_fo = fi.copy(), fo.copy()  # fi, fo are scaled by the Illinois rule
    # The ends as found; the step parameter runs along the original bracket.
    p0, d = pi.copy(), po - pi
    length = np.hypot(d[:, 0], d[:, 1])
    ti, to = np.zeros(n), np.ones(n)
    last = np.zeros(n, dtype=np.int8)  # +1: pi moved last step, -1: po moved, 0: neither yet
    bisect = np.zeros(n, dtype=bool)
    active = np.flatnonzero(length > _ISO_RESOLUTION)
    for _ in range(_ISO_MAX_STEPS):
        if not len(active):
            break
        a = active
        a_ti, a_to, a_fi, a_fo = ti[a], to[a], fi[a], fo[a]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = a_ti + (a_to - a_ti) * a_fi / (a_fi - a_fo)
        # Interpolated steps keep a little off the ends (no stalling on a bracket end).
        w = a_to - a_ti
        t = np.clip(np.where(np.isfinite(t), t, 0.5 * (a_ti + a_to)), a_ti + 1e-3 * w, a_to - 1e-3 * w)
        t = np.where(bisect[a], 0.5 * (a_ti + a_to), t)
        m = p0[a] + t[:, None] * d[a]
        fm = surface.z(m) - lv[a]
        inside = fm > 0.0
        # Illinois: an end kept twice in a row has its value halved, so it moves next time.
        keep_o = inside & (last[a] == 1)
        keep_i = ~inside & (last[a] == -1)
        fo[a[keep_o]] *= 0.5
        fi[a[keep_i]] *= 0.5
        ai, ao = a[inside], a[~inside]
        ti[ai], fi[ai], true_fi[ai], pi[ai] = t[inside], fm[inside], fm[inside], m[inside]
        to[ao], fo[ao], true_fo[ao], po[ao] = t[~inside], fm[~inside], fm[~inside], m[~inside]
        last[a] = np.where(inside, 1, -1)
        w_new = to[a] - ti[a]
        bisect[a] = w_new > 0.5 * w
        on_level = (true_fo[a] >= -_ISO_Z_RESOLUTION) & (true_fi[a] <= _ISO_Z_RESOLUTION)
        active = a[(w_new * length[a] > _ISO_RESOLUTION) & ~on_level]
    return pi, po, lv


def tighten_chords(surface: ClSurface, loops, outs, tolerance):
    """Insert pushed-out vertices where a chord rises above ``level + tolerance/2``.

    Chords are sampled ``s = sqrt(R * tolerance)`` apart and each sample is tested ``m``
    inside the chord, ``m = R - sqrt(R^2 - s^2/4)`` the sagitta of an arc of radius ``R``
    over ``s`` (about ``s^2 / 8R = tolerance / 8``). Where the CL surface jumps (vertical
    walls) any intrusion is a gouge, and the boundary of the region the tool must avoid
    bends with radius >= R, so it cannot reach the chord between two samples that pass.
    Elsewhere the chord rises at most ``m`` above the samples' bound between two that pass
    (below), so a chord that passes stays within ``tolerance/2 + tolerance/8`` of its level.
    The new vertex goes where the chord cuts in deepest, moved along the chord's normal onto
    the iso-line (and off a wall, see :func:`onto_iso`). Only chords made in the previous
    round are checked again.
    """
    tol = 0.5 * tolerance
    # Why any s < 2R keeps the argument, and why this one. The CL surface is the upper
    # envelope over the part's points p of z_p(x) = p_z - h(|x - p_xy|), h the tool's bottom
    # profile (ball: h(d) = R - sqrt(R^2 - d^2); no contact beyond R; with an allowance the
    # grown tool's R + a > R only shrinks the sagitta below m). Where one z_p exceeds
    # level + tol is a disc of radius rho <= R, centred on the part's side of the chord (a
    # centre beyond it would sit in the thin cap between chord and loop, nearer the loop than
    # rho). To reach the chord yet miss every sample on the line m inside it, the centre must
    # lie e from that line with e > sqrt(rho^2 - s^2/4) and e + m < rho. A wall (rho = R,
    # h jumps at R) then needs sqrt(R^2 - s^2/4) + m < R, which the exact sagitta rules out. A smaller disc rises over the chord by at most
    # h(sqrt(e^2 + s^2/4)) - h(e + m), for the ball largest at e = 0:
    # sqrt(R^2 - m^2) - (R - m) < m (a bull nose rises less, a flat end mill not at all).
    # So s sets only the margin's size: sqrt(R * tolerance) keeps it at tolerance/8, the
    # vertical slack a passing chord may add to tol and the outward nudge of _clear_margin.
    # (A 0.05 mm cap here sampled a 3 mm ball at tolerance 0.002 1.5x finer than needed.)
    R = surface.radius
    spacing = min(math.sqrt(R * tolerance), R)  # at most R: the sagitta needs s < 2R
    half = 0.5 * spacing
    margin = half * half / (R + math.sqrt(R * R - half * half))  # R - sqrt(R^2 - half^2), without cancelling
    sizes = np.array([len(c) for c in loops])
    p = np.concatenate(loops)
    o = np.concatenate(outs)
    p[:, :2] = _clear_margin(surface, p[:, :2], o, p[:, 2], margin, tol)
    ends = np.cumsum(sizes)
    dirty = np.ones(len(p), dtype=bool)  # chord from point i to i + 1 not yet verified
    dirty[ends - 1] = False
    for _ in range(_CHORD_ROUNDS):
        ia = np.flatnonzero(dirty)
        if not len(ia):
            break
        ib = ia + 1
        a, b = p[ia], p[ib]
        lv = a[:, 2]
        length = np.hypot(*(b[:, :2] - a[:, :2]).T)
        n_s = np.maximum(np.ceil(length / spacing).astype(np.int64), 2)
        chord = np.repeat(np.arange(len(ia)), n_s - 1)
        first = np.cumsum(n_s - 1) - (n_s - 1)
        t = (np.arange(len(chord)) - first[chord] + 1) / n_s[chord]
        q = a[chord, :2] + t[:, None] * (b[chord, :2] - a[chord, :2])
        d = b[:, :2] - a[:, :2]
        nrm = np.column_stack([-d[:, 1], d[:, 0]]) / np.maximum(length, 1e-300)[:, None]
        side = np.sign(np.einsum("ij,ij->i", nrm, o[ia] + o[ib]))
        nrm *= np.where(side == 0, 1.0, side)[:, None]
        # Samples are tested a little inside the chord: a wall the tool rounds with radius
        # >= R cannot then reach the chord between two samples that pass.
        # only the samples over the limit need their height (the deepest is where the new vertex goes)
        over = z_near(surface, q - margin * nrm[chord], lv[chord] + tol) - lv[chord]
        worst = np.full(len(ia), -np.inf)
        np.maximum.at(worst, chord, over)
        dirty[ia] = False
        bad = (worst > tol) & (length > 1e-4)
        log.debug("chord round: %d checked, %d bad, %d points", len(ia), int(bad.sum()), len(p))
        if not np.any(bad):
            break
        k = np.flatnonzero(bad)
        # Deepest sample of each bad chord.
        hit = np.flatnonzero(over == worst[chord])
        _, firsthit = np.unique(chord[hit], return_index=True)
        deepest = np.full(len(ia), -1)
        deepest[chord[hit[firsthit]]] = hit[firsthit]
        start = q[deepest[k]]
        n = nrm[k]
        lvk = lv[k]
        # Search outward for a free point, then bisect back onto the iso-line.
        po = np.full_like(start, np.nan)
        for s in (0.25, 0.5, 1.0, 2.0, 4.0):
            todo = np.isnan(po[:, 0])
            if not np.any(todo):
                break
            cand = start[todo] + n[todo] * (s * length[k][todo, None] + tolerance)
            ok = z_near(surface, cand, lvk[todo]) <= lvk[todo]
            po[np.flatnonzero(todo)[ok]] = cand[ok]
        found = ~np.isnan(po[:, 0])
        if not np.all(found):
            log.warning("waterline: %d chords could not be pushed off the part", int(np.sum(~found)))
        if not np.any(found):
            break
        pi, po, lvf, nf = start[found], po[found], lvk[found], n[found]
        pi, po, lvf = onto_level(surface, pi, po, lvf)
        jump = z_near(surface, pi, lvf + _ISO_JUMP) - lvf > _ISO_JUMP
        pushed = po + 0.5 * tolerance * nf
        use = jump & (z_near(surface, pushed, lvf) <= lvf)
        po[use] = pushed[use]
        po = _clear_margin(surface, po, nf, lvf, margin, tol)
        after = ia[k[found]]
        at = after + 1
        p = np.insert(p, at, np.column_stack([po, lvf]), axis=0)
        o = np.insert(o, at, nf, axis=0)
        # Both new chords (before and after each new vertex) need checking.
        dirty = np.insert(dirty, at, True)
        dirty[after + np.arange(len(after))] = True
        counts = np.bincount(np.searchsorted(ends, after, side="right"), minlength=len(sizes))
        sizes = sizes + counts
        ends = np.cumsum(sizes)
    else:
        if np.any(dirty):
            log.warning("waterline: %d chords still unverified after %d rounds", int(dirty.sum()), _CHORD_ROUNDS)
    return np.split(p, np.cumsum(sizes)[:-1])


def _clear_margin(surface: ClSurface, xy, outward, level, margin, tol):
    """Move vertices out by ``margin`` where the CL surface is too steep for the chord test.

    The chord test probes ``margin`` inside the chord; on a near-vertical CL slope (the tool
    rolling over a wall's top edge) that probe would fail beside a vertex exactly on the
    iso-line, and splitting would never end.
    """
    steep = z_near(surface, xy - margin * outward, level + tol) > level + tol
    if not np.any(steep):
        return xy
    moved = xy[steep] + margin * outward[steep]
    free = z_near(surface, moved, level[steep]) <= level[steep]
    out = xy.copy()
    out[np.flatnonzero(steep)[free]] = moved[free]
    return out
