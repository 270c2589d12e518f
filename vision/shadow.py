"""Where a part lying on the tray is in shadow: the key light's direction from the picture, and which of
the part's edges lie in shadow on both sides, so that a picture cannot show them.

Under a low, hard light the wall turned away from it is dark, and so is the tray at its foot, in the
wall's own cast shadow: the crease between them shows nothing. A boss's shadow falls across the
plate's edge the same way. These edges are not missing from the picture, they are unknowable there,
and :func:`vision.locate.locate_parts` leaves them out of the shares it judges a pose by, as it
leaves out edges inside a clipped highlight. Which edges they are follows from the mesh at the
hypothesised pose and the light, not from how dark the picture happens to be there, so a wrong pose
cannot excuse its missing edges by lying on a shadow.

Everything here is in the part's frame of :class:`vision.mesh_edges.MeshEdges` (footprint centroid at
x = y = 0, lowest point at z = 0; metres) unless a name says otherwise.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import functools

import cv2
import numpy as np
from scipy.optimize import least_squares

#: Cell size of the part's height field [m].
TEXEL_M = 5e-4
#: A point is shadowed only by what stands this far above the line to the light (the height field's
#: cells take their triangle's highest point) [m].
SHADOW_BIAS_M = 4e-4
#: Points an edge's sides are looked at, this far off the edge into the open air [m].
SIDE_M = 6e-4
#: A face lit at a smaller cosine than this is counted dark (grazing light) (unitless).
GRAZING_COS = 0.15
#: Log brightness under the tray model below which a pixel is in a hard shadow (about 35 % darker).
DARK_LOG = -0.45
#: Fewer dark pixels around the part than this share of its own area: no hard shadow, no key light
#: to account for (diffuse or overhead light) (unitless).
MIN_DARK_SHARE = 0.08
#: A key light higher than this [rad] is not taken into account: its shadows are short, and the
#: room's light shows the walls turned away from it (on the benchmark, from 50 deg up the outline
#: is found as well without; with, polished parts in glare came out 1.5 mm off instead of refused).
LOW_LIGHT = np.radians(40.0)
#: Tray points the light is estimated from, at most, and the step of the look towards the light [m].
LIGHT_POINTS = 600
LIGHT_STEP_M = 1e-3


@dataclass(frozen=True)
class HeightField:
    """The part seen from straight above: the height of its highest point in each cell.

    Attributes
    ----------
    heights : (rows, cols) float32
        Height above the part's lowest point [m]; 0 where there is no part (the tray).
    origin : (2,) float
        x, y of the centre of cell (0, 0) [m].
    """

    heights: np.ndarray
    origin: np.ndarray

    @functools.cached_property
    def ringed(self) -> np.ndarray:
        """(rows + 2, cols + 2) ``heights`` in a ring of tray (0) [m], for :meth:`at`: made once per field."""
        return np.pad(self.heights, 1)

    def at(self, xy: np.ndarray) -> np.ndarray:
        """``(n,)`` heights [m] at ``xy`` (n, 2) [m]; 0 outside the field."""
        q = np.rint((np.asarray(xy) - self.origin) / TEXEL_M)
        rows, cols = self.heights.shape
        # The field with a ring of tray (0) around it: every cell outside reads the ring.
        ring = self.ringed
        col = np.clip(q[:, 0], -1, cols).astype(np.int64) + 1
        row = np.clip(q[:, 1], -1, rows).astype(np.int64) + 1
        return ring.ravel()[row * (cols + 2) + col]


def height_field(vertices: np.ndarray, faces: np.ndarray) -> HeightField:
    """The height field of a mesh (vertices (n, 3) [m], part frame; faces (m, 3) int).

    Each triangle is drawn at its highest vertex, lowest first, so every cell keeps the highest
    triangle over it (a wall, seen edge-on, draws its top line). Good to a cell's size on freeform
    faces, exact on the flat tops and walls of prismatic parts.
    """
    v = np.asarray(vertices, dtype=np.float64)
    tri = v[np.asarray(faces)]
    origin = v[:, :2].min(axis=0) - 2 * TEXEL_M
    size = np.ceil((v[:, :2].max(axis=0) + 2 * TEXEL_M - origin) / TEXEL_M).astype(int) + 1
    heights = np.zeros((size[1], size[0]), np.float32)
    top = tri[:, :, 2].max(axis=1)
    # Sub-cell vertex positions (4 fractional bits) so thin walls land where they stand.
    pts = np.rint((tri[:, :, :2] - origin) / TEXEL_M * 16).astype(np.int32)
    for k in np.argsort(top):
        cv2.fillConvexPoly(heights, pts[k], float(top[k]), lineType=cv2.LINE_8, shift=4)
    heights.setflags(write=False)
    return HeightField(heights=heights, origin=origin)


def shadowed(field: HeightField, points: np.ndarray, light: np.ndarray, bias: float = SHADOW_BIAS_M) -> np.ndarray:
    """``(n,)`` bool: the part stands between each point (n, 3) [m] and the light (unit, z > 0), by more
    than ``bias`` [m] above the line to it.

    ``light`` is one direction (3,) or one per point (n, 3) (towards the camera's eye, the same
    test says whether the part hides a point from it). March from each point towards the
    light, a cell at a time, until the line to the light is above the part's highest point.
    """
    p = np.asarray(points, dtype=np.float64)
    d = np.broadcast_to(np.asarray(light, dtype=np.float64), p.shape)
    flat = np.hypot(d[:, 0], d[:, 1])
    out = np.zeros(len(p), bool)
    if len(p) == 0:
        return out
    steep = flat < 1e-6
    rise = d[:, 2] / np.where(steep, 1.0, flat)  # height gained per metre along the tray
    ahead = d[:, :2] / np.where(steep, 1.0, flat)[:, None]
    top = float(field.heights.max())
    # Straight up: only the point's own column can cover it.
    out[steep] = field.at(p[steep, :2]) > p[steep, 2] + bias
    live = ~steep & (p[:, 2] < top)
    # Past the field's box (or never crossing it) a line above the tray meets only tray: its march ends
    # there, not only once it rises above the part's top (a low light's lines rose for 15 cm).
    enter, leave = _crossing(field, p[:, :2], ahead)
    above = p[:, 2] + bias >= 0
    live &= ~above | ((leave >= np.maximum(enter, 0.0)) & (enter < np.inf))
    # A block of cells per look: once a line is above the part's top nothing further hides it, so
    # the cells a block looks at past that point change nothing. Block j looks at distances ``blocks[j]``, each
    # block's the last one's plus MARCH_BLOCK cells, made once for every line.
    blocks = [TEXEL_M * np.arange(1, MARCH_BLOCK + 1)]
    # A line above the tray starts at its first block that reaches the field's box: before it, it meets only
    # tray (the shadows of tall parts on the tray are marched from centimetres away).
    start = np.where(above & live, np.maximum(enter, 0.0), 0.0)
    while blocks[-1][-1] < start.max():
        blocks.append(blocks[-1] + MARCH_BLOCK * TEXEL_M)
    block = np.searchsorted(np.array([b[-1] for b in blocks]), start)
    while live.any():
        i = np.flatnonzero(live)
        while len(blocks) <= block[i].max():
            blocks.append(blocks[-1] + MARCH_BLOCK * TEXEL_M)
        s = np.array(blocks)[block[i]]  # (k, MARCH_BLOCK)
        z = p[i, 2, None] + s * rise[i, None]
        q = p[i, None, :2] + s[:, :, None] * ahead[i, None, :]
        hit = (field.at(q.reshape(-1, 2)).reshape(z.shape) > z + bias).any(axis=1)
        out[i[hit]] = True
        live[i[hit | (z[:, -1] >= top) | (above[i] & (s[:, -1] >= leave[i]))]] = False
        block[i] += 1
    return out


def _crossing(field: HeightField, xy: np.ndarray, ahead: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(n,)`` and ``(n,)``: how far [m] the looks from ``xy`` (n, 2) [m] along ``ahead`` (2,) or (n, 2) (unit)
    enter and leave the box the field's cells lie in (a cell beyond its edge, for the rounding); enter is
    inf for a look that never crosses it. Outside that box every height is 0."""
    rows, cols = field.heights.shape
    lo = field.origin - 1.5 * TEXEL_M
    hi = field.origin + TEXEL_M * (np.array([cols, rows]) + 0.5)
    ahead = np.broadcast_to(ahead, xy.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (lo - xy) / ahead, (hi - xy) / ahead
    # Along an axis the look does not move, it is within the box's slab for good or never.
    within = (xy >= lo) & (xy <= hi)
    a = np.where(ahead == 0, np.where(within, -np.inf, np.inf), a)
    b = np.where(ahead == 0, np.inf, b)
    enter = np.minimum(a, b).max(axis=1)
    leave = np.maximum(a, b).min(axis=1)
    return np.where(leave >= enter, enter, np.inf), leave


#: Cells :func:`shadowed` looks at per step of its march towards the light.
MARCH_BLOCK = 16


def _lit(field: HeightField, points: np.ndarray, normals: np.ndarray, light: np.ndarray) -> np.ndarray:
    """``(n,)`` bool: a surface at ``points`` (n, 3) [m] with ``normals`` (n, 3) gets the key light (unit (3,)).
    Only the surfaces turned to it are marched towards it (:func:`shadowed`)."""
    lit = normals @ light > GRAZING_COS
    lit[lit] = ~shadowed(field, points[lit], light)
    return lit


def _horizontal(v: np.ndarray) -> np.ndarray:
    """Unit horizontal part of each vector (n, 3) (zero where it has none)."""
    h = np.column_stack([v[:, 0], v[:, 1], np.zeros(len(v))])
    n = np.linalg.norm(h, axis=1, keepdims=True)
    return np.where(n > 1e-6, h / np.maximum(n, 1e-12), 0.0)


def landing(field: HeightField, start: np.ndarray, eye: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(n, 3)`` where each line of sight from ``eye`` (3,) [m] through ``start`` (n, 3) [m], beyond
    it, first meets the part or the tray (z = 0), and ``(n,)`` bool whether it met a face turned up
    there (the tray, a step's top, a bore's floor), not a wall.

    The march takes steps of at most a cell across or down, so a line of sight that meets a face
    turned up ends at most a cell below it; one that meets a wall (a bore's far side) ends deep
    below the wall's cells, which the height field keeps at the wall's top.
    """
    p = np.asarray(start, dtype=np.float64).copy()
    d = p - eye
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    dt = TEXEL_M / np.maximum(np.hypot(d[:, 0], d[:, 1]), -d[:, 2])
    live = (p[:, 2] > 0) & (field.at(p[:, :2]) <= p[:, 2])
    # A block of steps per look, each the running sum of the ones before (the same sums, to the bit, as
    # stepping one at a time); each line stops at its block's first step that meets something.
    while live.any():
        i = np.flatnonzero(live)
        walk = np.empty((len(i), MARCH_BLOCK + 1, 3))
        walk[:, 0], walk[:, 1:] = p[i], (dt[i, None] * d[i])[:, None, :]
        q = np.cumsum(walk, axis=1)[:, 1:]
        z = q[..., 2]
        stop = (z <= 0) | (field.at(q[..., :2].reshape(-1, 2)).reshape(z.shape) >= z)
        met = stop.any(axis=1)
        q = q[np.arange(len(i)), np.where(met, stop.argmax(axis=1), MARCH_BLOCK - 1)]
        q[:, 2] = np.maximum(q[:, 2], 0.0)
        p[i] = q
        live[i[met]] = False
    top = field.at(p[:, :2])
    flat = top - p[:, 2] <= 1.5 * TEXEL_M
    p[:, 2] = np.maximum(p[:, 2], top)
    return p, flat


def dark_both_sides(field: HeightField, points: np.ndarray, n1: np.ndarray, n2: np.ndarray, eye: np.ndarray,
                    light: np.ndarray) -> np.ndarray:
    """``(k,)`` bool: the surfaces the camera sees on both sides of each edge sample are dark.

    ``points`` (k, 3) are edge samples between faces of normals ``n1``, ``n2`` (k, 3); ``eye`` (3,) the
    camera and ``light`` (3,) the unit direction towards the key light, all in the part's frame [m].
    A side is a face turned to the camera, or, where only one is, what the line of sight meets beyond
    the edge (the tray past a wall turned away, the tray at a wall's foot, a lower step). A side is
    dark when the light grazes or misses its face, or the part stands between it and the light.
    """
    return _sides(field, points, n1, n2, eye, light).dark


def unseen_edges(field: HeightField, points: np.ndarray, n1: np.ndarray, n2: np.ndarray, eye: np.ndarray,
                 light: np.ndarray) -> np.ndarray:
    """``(k,)`` bool: edge samples a picture cannot show under the key light (arguments as :func:`dark_both_sides`).

    Dark on both sides (:func:`dark_both_sides`), or shaded alike: the two sides the camera sees are
    flat faces of the part itself (both facing up) at different heights, both lit or both dark, with the
    wall between them hidden from the camera. Under a low light a stepped wall's steps are such edges:
    each step's top is lit as brightly as the next one's (seed 4 of the low-angle gallery found 0.46 of
    its edges at its true pose with them judged). A lit top beside lit tray is not left out: taken as
    alike too, it found 4 more hexagonal bosses but passed a stepped wall 1.8 mm off (held-out seed 21).
    """
    sides = _sides(field, points, n1, n2, eye, light)
    return sides.dark | (sides.flat & sides.on_part & (sides.lit_a == sides.lit_b))


@dataclass(frozen=True)
class _Sides:
    """What the camera sees on either side of edge samples (:func:`_sides`), each ``(k,)`` bool.

    ``lit_a``, ``lit_b``: the key light reaches each side; ``flat``: both sides face straight up (a
    horizontal face and what lies beyond the edge); ``on_part``: both sides are the part's surfaces
    (the line of sight past the edge meets the part, not the tray).
    """

    lit_a: np.ndarray
    lit_b: np.ndarray
    flat: np.ndarray
    on_part: np.ndarray

    @property
    def dark(self) -> np.ndarray:
        """``(k,)`` bool: the key light reaches neither side."""
        return ~self.lit_a & ~self.lit_b


#: A face whose normal's z is above this faces up (within 8 deg) (unitless).
FLAT_COS = 0.99
#: A line of sight that lands higher than this above the tray met the part [m].
ON_PART_M = 5e-4


def _sides(field: HeightField, points: np.ndarray, n1: np.ndarray, n2: np.ndarray, eye: np.ndarray,
           light: np.ndarray) -> _Sides:
    """The two sides the camera sees of each edge sample and whether the key light reaches them (see
    :func:`dark_both_sides` for the arguments and what a side is)."""
    x = np.asarray(points, dtype=np.float64)
    view = eye - x
    s1, s2 = (np.einsum("nj,nj->n", n, view) > 0 for n in (n1, n2))
    both = s1 & s2
    # One face turned away: the other side is what the line of sight meets past the edge, looked at
    # just beyond the hidden face (or beyond the visible one, when the hidden face is the bottom).
    hidden = np.where(s1[:, None], n2, n1)
    shown = np.where(s1[:, None], n1, n2)
    away = _horizontal(hidden)
    away = np.where(np.linalg.norm(away, axis=1, keepdims=True) > 0, away, _horizontal(shown))
    one = ~both  # only these look beyond the edge
    beyond = np.zeros_like(x)
    flat_beyond = np.zeros(len(x), bool)
    beyond[one], flat_beyond[one] = landing(field, x[one] + SIDE_M * away[one], eye)
    up = np.tile([0.0, 0.0, 1.0], (len(x), 1))
    # Each side is marched towards the light only where the answer uses it, all in one march: the marches
    # cost a low-angle locate a third.
    use = (s1, s2 | ~s1, one)
    where = np.r_[(x + SIDE_M * n1)[s1], (x + SIDE_M * n2)[use[1]], (beyond + 0.5 * SIDE_M * up)[one]]
    lit = np.split(_lit(field, where, np.r_[n1[s1], n2[use[1]], up[one]], light), np.cumsum([u.sum() for u in use])[:2])
    l1, l2, l_beyond = (np.zeros(len(x), bool) for _ in range(3))
    l1[s1], l2[use[1]], l_beyond[one] = lit
    flat = np.where(both, (n1[:, 2] > FLAT_COS) & (n2[:, 2] > FLAT_COS), (shown[:, 2] > FLAT_COS) & flat_beyond)
    return _Sides(lit_a=np.where(both, l1, np.where(s1, l1, l2)), lit_b=np.where(both, l2, l_beyond), flat=flat,
                  on_part=both | (beyond[:, 2] > ON_PART_M))


def estimate_light(field: HeightField, tray: np.ndarray, dark: np.ndarray, eye: np.ndarray, *,
                   min_dark: int) -> np.ndarray | None:
    """The key light's direction (unit (3,), part frame) from the part's cast shadow on the tray, or None.

    ``tray`` (n, 2) [m] are tray points around the part (z = 0), ``dark`` (n,) bool those in a hard
    shadow in the picture, ``eye`` (3,) the camera [m]. Tray points the part hides from the camera
    are left out. A tray point lies in the part's shadow when, looking from it towards the light's
    azimuth, the part rises above the line to the light somewhere: at the steepest slope ``m`` of the
    part seen from it, ``m >= tan(elevation)``. Every azimuth (15 deg, then 3 deg around the best)
    is tried with the elevation that best tells the dark points from the others; the one that tells
    them apart best wins. None when fewer than ``min_dark`` seen points are dark (diffuse light),
    the best light explains less than half of them (the dark is not this part's shadow), or the
    light is higher than :data:`LOW_LIGHT`.
    """
    t = np.column_stack([tray, np.zeros(len(tray))])
    to_eye = eye - t
    seen = ~shadowed(field, t, to_eye / np.linalg.norm(to_eye, axis=1, keepdims=True))
    t, dark = t[seen], np.asarray(dark)[seen]
    if dark.sum() < min_dark:
        return None
    # Enough points to measure a shadow by, evenly taken.
    keep = slice(None, None, max(1, len(t) // LIGHT_POINTS))
    t, dark = t[keep], dark[keep]
    rows, cols = field.heights.shape
    corner = np.abs(np.r_[field.origin, field.origin + TEXEL_M * np.array([cols, rows])]).max()
    reach = float(np.linalg.norm(t[:, :2], axis=1).max() + np.sqrt(2) * corner)
    steps = np.arange(0.5 * TEXEL_M, reach, LIGHT_STEP_M)

    def steepest(az: float) -> np.ndarray:
        # A look that never crosses the field's box sees only tray, slope 0 (heights are never below it):
        # only the looks that cross it are marched, over the steps where they do (all of them cost a
        # locate a quarter).
        ahead = np.array([np.cos(az), np.sin(az)])
        enter, leave = _crossing(field, t[:, :2], ahead)
        cross = np.flatnonzero((leave >= np.maximum(enter, 0.0)) & (enter <= steps[-1]))
        m = np.zeros(len(t))
        if len(cross) == 0:
            return m
        span = (steps >= enter[cross].min() - TEXEL_M) & (steps <= leave[cross].max() + TEXEL_M)
        s = steps[span]
        q = t[None, cross, :2] + s[:, None, None] * ahead  # (steps, n, 2)
        h = field.at(q.reshape(-1, 2)).reshape(len(s), len(cross))
        m[cross] = (h / s[:, None]).max(axis=0) if len(s) else 0.0
        return m

    def told(az: float) -> tuple[float, float, float]:
        m = steepest(az)
        order = np.argsort(-m)
        gain = np.cumsum(np.where(dark[order], 1.0, -1.0))
        k = int(np.argmax(gain))
        return float(gain[k]), float(m[order[k]]), float(dark[order[:k + 1]].sum())

    coarse = max((told(az) + (az,) for az in np.radians(np.arange(0.0, 360.0, 15.0))), key=lambda r: r[0])
    fine = max((told(az) + (az,) for az in coarse[3] + np.radians(np.arange(-12.0, 12.1, 3.0))),
               key=lambda r: r[0])
    _, slope, explained, az = fine
    if slope <= 0 or explained < 0.5 * dark.sum():
        return None
    el = np.arctan(slope)
    if el > LOW_LIGHT:
        return None
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def shadow_edges(field: HeightField, points: np.ndarray, direction: np.ndarray, n1: np.ndarray, n2: np.ndarray,
                 eye: np.ndarray, light: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The edge of the part's cast shadow on the tray that the camera sees, from the mesh's edges.

    ``points``, ``direction``, ``n1``, ``n2`` (k, 3): the mesh's edge samples, their unit directions and
    the normals of their two faces; ``eye`` (3,) the camera and ``light`` (3,) the unit direction
    towards the key light, all in the part's frame [m]. The shadow's edge is cast by the edges
    between a face the light reaches and one it does not; each is followed along the light to the
    tray (z = 0), and kept where the tray beside it is lit on one side and shadowed on the other,
    outside the part and not hidden from the camera. Returns the indices into ``points`` (s,) of
    the casting samples, their shadows on the tray (s, 3) [m] and the shadow edge's unit directions
    (s, 3).
    """
    p = np.asarray(points, dtype=np.float64)
    casting = np.flatnonzero((n1 @ light > 0) != (n2 @ light > 0))
    x = p[casting]
    cast = x - (x[:, 2] / light[2])[:, None] * light
    ahead = x + 1e-3 * direction[casting]
    tangent = (ahead - (ahead[:, 2] / light[2])[:, None] * light) - cast
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    across = np.column_stack([-tangent[:, 1], tangent[:, 0], np.zeros(len(tangent))])
    # Only shadows that fall outside the part are kept: the others (a boss's or a bore's, on the part) are not
    # marched (they were half of a low light's casting samples).
    outside = np.flatnonzero((field.at((cast + SIDE_M * across)[:, :2]) <= 0)
                             & (field.at((cast - SIDE_M * across)[:, :2]) <= 0))
    casting, cast, tangent, across = casting[outside], cast[outside], tangent[outside], across[outside]
    to_eye = eye - cast
    # Both sides towards the light and the shadow towards the eye in one march.
    k = len(cast)
    towards = np.r_[np.broadcast_to(light, (2 * k, 3)), to_eye / np.linalg.norm(to_eye, axis=1, keepdims=True)]
    one, other, hid = np.split(shadowed(field, np.r_[cast + SIDE_M * across, cast - SIDE_M * across, cast], towards),
                               [k, 2 * k])
    keep = (one != other) & ~hid
    return casting[keep], cast[keep], tangent[keep]


@dataclass(frozen=True)
class ShadowEvidence:
    """What the key light explains at one pose.

    Attributes
    ----------
    unknown : (k,) bool
        The visible edge samples dark on both sides or shaded alike (:func:`unseen_edges`): a picture
        cannot show them.
    near : (s,) bool
        The samples of the cast shadow's edge on the tray (:func:`shadow_edges`) the picture shows
        within a pixel, at the light fitted to them.
    normal : (s, 2) float
        Their unit image normals.
    light : (3,) float
        The fitted unit direction towards the key light, part frame.
    """

    unknown: np.ndarray
    near: np.ndarray
    normal: np.ndarray
    light: np.ndarray


#: Search half-widths [px] of the rounds that fit the light to the shadow's edge, widest first.
LIGHT_SEARCH_PX = (3.0, 1.5)
#: How far the fit may turn the estimated light's azimuth and tilt its elevation [rad].
LIGHT_TURN = np.radians(6.0)
LIGHT_TILT = np.radians(4.0)
#: ... and never below this elevation [rad].
LOWEST_LIGHT = np.radians(5.0)
#: A fitted light that explains this share of the shadow's edge is taken without comparing (unitless).
SHADOW_FOUND = 0.85
#: Fewest shadow edge samples that make the shadow evidence.
MIN_SHADOW_SAMPLES = 12


def _towards(az: float, el: float) -> np.ndarray:
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def shadow_evidence(field: HeightField, points: np.ndarray, direction: np.ndarray, n1: np.ndarray,
                    n2: np.ndarray, visible: np.ndarray, eye: np.ndarray, light: np.ndarray,
                    to_image: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
                    find: Callable[[np.ndarray, np.ndarray, float], np.ndarray],
                    to_pixels: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None) -> ShadowEvidence:
    """The edges a pose leaves in the dark and the cast shadow's edge it explains, under the key light.

    ``points``, ``direction``, ``n1``, ``n2`` (k, 3) are all the mesh's edge samples (part frame [m]),
    ``visible`` (v,) the indices of those the camera can see, ``eye`` (3,) the camera and ``light``
    (3,) the estimated key light (:func:`estimate_light`), part frame. ``to_image(points, directions)``
    gives the image positions (n, 2) [px] and unit image normals (n, 2) of part-frame points and
    directions at the pose; ``find(uv, normal, reach)`` the signed offset [px] of the nearest picture
    edge along each normal within ``reach`` (NaN where none); ``to_pixels(points)`` the image positions
    (n, 2) [px] alone (the light's fit needs no normals) and their derivatives (n, 2, 3) by the part-frame
    points [px/m], for the light fit's Jacobian (finite differences when not given).

    A shadow's length grows with the cotangent of the light's elevation (a degree at 19 deg moves
    a 48 mm upright's shadow 9 mm), so the light is first fitted: azimuth and elevation such that
    the cast shadow's edge lies on the picture's edges, in rounds of narrowing search.
    """
    casting = np.flatnonzero((n1 @ light > 0) != (n2 @ light > 0))
    az, el = float(np.arctan2(light[1], light[0])), float(np.arcsin(np.clip(light[2], -1, 1)))
    x, d = points[casting], direction[casting]

    def cast(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lq = _towards(*q)
        on = x - (x[:, 2] / lq[2])[:, None] * lq
        ahead = x + 1e-3 * d
        t = ahead - (ahead[:, 2] / lq[2])[:, None] * lq - on
        return on, t / np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)

    # The fit stays near the estimate, and above LOWEST_LIGHT; an estimate below that (4.7 deg at a low-angle
    # stepped wall's true pose, held-out seed 22) starts the fit from it, not outside its bounds (a ValueError).
    lo = np.array([az - LIGHT_TURN, max(el - LIGHT_TILT, LOWEST_LIGHT)])
    hi = np.array([az + LIGHT_TURN, min(el + LIGHT_TILT, np.radians(89.0))])
    q = np.clip(np.array([az, el]), lo, np.maximum(hi, lo))
    at_estimate = shadow_edges(field, points, direction, n1, n2, eye, light)  # made once, used twice
    if len(casting) >= MIN_SHADOW_SAMPLES:
        # Only the samples that cast the edge the camera sees at the estimate take part.
        use = np.isin(casting, at_estimate[0])
        for reach in LIGHT_SEARCH_PX:
            if use.sum() < MIN_SHADOW_SAMPLES:
                break
            on, t = cast(q)
            uv, normal = to_image(on[use], t[use])
            off = find(uv, normal, reach)
            ok = np.isfinite(off)
            if ok.sum() < MIN_SHADOW_SAMPLES:
                break
            target, nrm, sub = uv[ok] + off[ok, None] * normal[ok], normal[ok], np.flatnonzero(use)[ok]

            residuals, jacobian = _light_residuals(x[sub], d[sub], target, nrm, to_image, to_pixels)
            q = least_squares(residuals, q, jac=jacobian, x_scale=np.array([0.01, 0.01]), diff_step=1e-6,
                              bounds=(lo, np.maximum(hi, lo + 1e-9)), loss="soft_l1", f_scale=1.0).x
    # The fit may run off onto other edges (a tall wall's shadow moves centimetres with the
    # elevation): the estimate stands unless the fitted light explains more of the shadow's edge.
    fitted = _evidence(field, points, direction, n1, n2, visible, eye, _towards(*q), to_image, find)
    if len(fitted.near) and fitted.near.mean() >= SHADOW_FOUND:
        return fitted
    estimated = _evidence(field, points, direction, n1, n2, visible, eye, light, to_image, find, at_estimate)
    return max((fitted, estimated), key=lambda e: e.near.mean() if len(e.near) else -1.0)


def _light_residuals(x: np.ndarray, d: np.ndarray, target: np.ndarray, normal: np.ndarray,
                     to_image: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
                     to_pixels: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None
                     ) -> tuple[Callable[[np.ndarray], np.ndarray], Callable[[np.ndarray], np.ndarray] | str]:
    """The light fit's residuals [px] of ``q = (azimuth, elevation)`` [rad]: how far the shadows on the tray
    of the casting samples ``x`` (k, 3) (their directions ``d``, part frame [m]) lie from their found
    edges ``target`` (k, 2) [px] along the edges' image normals ``normal`` (k, 2); and their Jacobian (k, 2)
    [px/rad], the projection's own through ``to_pixels`` (else "2-point", finite differences).

    A sample's shadow is ``on = x - x_z (l / l_z)`` with ``l / l_z = (cot el cos az, cot el sin az, 1)``.
    """
    z = x[:, 2, None]
    last: dict[str, np.ndarray] = {}

    def on(q: np.ndarray) -> np.ndarray:
        lq = _towards(*q)
        return x - (x[:, 2] / lq[2])[:, None] * lq

    def residuals(q: np.ndarray) -> np.ndarray:
        if to_pixels is None:
            uv = to_image(on(q), d)[0]
        else:
            uv, last["jac"] = to_pixels(on(q))
            last["q"] = np.array(q)
        return np.einsum("nj,nj->n", uv - target, normal)

    def jacobian(q: np.ndarray) -> np.ndarray:
        if "q" not in last or not np.array_equal(last["q"], q):
            residuals(q)
        az, el = q
        cot, csc2 = np.cos(el) / np.sin(el), 1.0 / np.sin(el) ** 2
        by_q = np.zeros((len(x), 3, 2))
        by_q[:, :2, 0] = -z * np.array([-cot * np.sin(az), cot * np.cos(az)])
        by_q[:, :2, 1] = -z * np.array([-csc2 * np.cos(az), -csc2 * np.sin(az)])
        return np.einsum("nj,njk,nkq->nq", normal, last["jac"], by_q)

    return residuals, (jacobian if to_pixels is not None else "2-point")


def _evidence(field: HeightField, points: np.ndarray, direction: np.ndarray, n1: np.ndarray, n2: np.ndarray,
              visible: np.ndarray, eye: np.ndarray, light: np.ndarray,
              to_image: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
              find: Callable[[np.ndarray, np.ndarray, float], np.ndarray],
              edges: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> ShadowEvidence:
    """:class:`ShadowEvidence` under one light (arguments as :func:`shadow_evidence`; ``edges``: its
    :func:`shadow_edges` when made already)."""
    unknown = unseen_edges(field, points[visible], n1[visible], n2[visible], eye, light)
    _, on, t = shadow_edges(field, points, direction, n1, n2, eye, light) if edges is None else edges
    if len(on) < MIN_SHADOW_SAMPLES:
        return ShadowEvidence(unknown=unknown, near=np.zeros(0, bool), normal=np.zeros((0, 2)), light=light)
    uv, normal = to_image(on, t)
    off = find(uv, normal, 1.5)
    near = np.abs(np.nan_to_num(off, nan=np.inf)) <= 1.0
    return ShadowEvidence(unknown=unknown, near=near, normal=normal, light=light)
