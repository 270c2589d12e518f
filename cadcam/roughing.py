"""Z-level roughing: clear the stock around the part level by level with a flat end mill.

At each level the *tool-centre region* (where the axis of the end mill may go without
coming closer than the allowance to the part) is computed in the plane with shapely, then
cleared with contour-parallel offset loops. The pieces:

* **Levels** go from the stock top down to the setup's floor (``Setup.floor_z``: the part's
  bottom less a breakthrough, above the holding allowance) at most ``stepdown`` apart, and every upward-facing
  flat face of the part (pocket floor, step top, boss top) at height ``f`` gets a level at exactly ``f + allowance``,
  so floors are left with an even allowance; such a level within ``stepdown`` of the last whole level above the
  next one is cut only round what that one cannot reach (:func:`cadcam.levelskim.local_levels`).
* **Shadow**: at level ``z`` the part blocks the tool wherever it has material at or above
  ``z`` (the end mill is a cylinder going up forever from its tip). The XY shadow is the
  union of the projections of the part's upward-facing triangles clipped to ``z' >= z``:
  exact for any watertight mesh, undercuts included (every vertical line through the
  solid leaves it through an upward-facing face), not just at sampled section heights
  (:mod:`cadcam.shadow`).
* **Forbidden region**: material at depth ``t * allowance`` below the tip must stay at
  least ``R + allowance * sqrt(1 - t^2)`` away from the axis (the tool grown by a ball of
  radius ``allowance``); this is approximated conservatively by a small staircase of
  buffered shadows. Buffers are polygonal, with the distance enlarged so that the chords
  (not only the vertices) lie outside the true offset: the tool never comes closer than the
  allowance because of the polygonisation; at most ``arc_tolerance`` more stock is left.
* **Region** = stock rectangle grown by the tool radius ``R`` minus the forbidden region.
  Growing by less would keep the tool out of margins narrower than ``R + allowance``
  between part and stock edge; the price is that the outermost loop along the stock edge
  only touches the stock (it doubles as the path the tool feeds in on).
* **Loops**: each connected region is eroded by ``k * stepover`` (k = 0, 1, ...) until
  empty; every ring of every erosion is one closed loop. With ``stepover <= R`` every
  point of the region is within ``R`` of a loop, so the whole region and its
  ``R``-neighbourhood is cleared: the next level can rely on that. A wider stepover (up to
  just under ``D``: finishing floors at 85 %) leaves cusps between loops, in corners and
  along the middle of narrow parts more than ``R`` from every loop; those gaps get loops of
  their own (:func:`_gap_rings`), so the property holds for any stepover.
* **Entry**: a region touching the outside of the stock is entered from the air: the tool
  descends outside the stock and feeds in horizontally. A closed pocket is entered by a
  helix (``ramp_angle``, shrunk down to ``min_helix_diameter`` if need be) from the
  previous level's floor, or by a ramp along one of its loops if no helix fits; a pocket
  that fits neither is skipped with a warning (and stays skipped on the levels below).
  The tool never plunges vertically into material. In rest machining the stock model tells
  where the air is: rest material with air beside it down to the level (a terrace on a
  bowl's side, the skin roughing left on a wall) is entered from there like an open region,
  descending in the air and feeding across (:func:`_side_entry`); otherwise a helix or ramp
  starts where the stock lets the tool lowest, just above it, not at the previous level, and
  where the stock under the helix centre is already gone the tool goes straight down
  there; a skipped pocket bars only its own neighbourhood (``2 R``) on the levels below.
* **Order and links**: closed pockets are cut inside-out from the helix, regions open to
  the stock edge outside-in; each next loop is the uncut loop nearest to what is already
  cut, linked by a short horizontal cut that is checked to stay inside the region. When
  the tool is not already there it retracts to the clearance height, rapids, and descends
  vertically on a path already cut at this level (air all the way down). Rest machining cuts
  its regions stack by stack and links them low (:mod:`cadcam.restlinks`).
* **Descents** run by rapid to ``lead_gap`` above the deepest floor known to be cleared under the whole tool (the
  last whole level's, this level's on a cut path, the level itself outside the stock's side), and at the
  plunge feed only for the last ``lead_gap``: the cleared-neighbourhood property above makes that air.
* **Climb milling** (M3, clockwise spindle seen from above): the uncut stock is kept on
  the *left* of the direction of travel. Each loop is oriented at the point where the link
  reaches it: the link arrives from the cleared side, so the far side is the uncut one. In
  the usual inside-out pocket this makes pocket walls clockwise and loops around islands
  counter-clockwise; helices turn clockwise.

A bull-nose end mill is treated as a flat one of the same diameter: its body lies inside
that cylinder, so there is no gouge; it leaves a little more stock at its corners.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import shapely
import trimesh
from shapely.geometry import LineString, MultiLineString, Point, Polygon, box
from shapely.geometry.base import BaseGeometry
from shapely.geometry.polygon import orient
from shapely.ops import nearest_points

from cadcam.levelpath import CutPaths, LevelPath, round_the_stock
from cadcam.model import CuttingData, Motion, Operation, Setup, Tool
from cadcam.restlinks import COVER_TOL, Links, Piece, cut_stacked
from cadcam.ringorder import LoopOrder, open_lead, rest_targets
from cadcam.gridregion import near_cells
from cadcam.levelskim import local_levels, top_skin, without_skimmed
from cadcam.rest import rest_levels, rooms_round, without_holder
from cadcam.shadow import part_shadows
from cadcam.stock import Simulation, clear_height
from factory.core.errors import MeshError, ToolError, ToolpathError

log = logging.getLogger(__name__)

#: Material less than this above ``z - allowance`` counts as the floor itself [mm].
_FLOOR_EPS = 1e-3
#: Depths below the tip, in units of the allowance, of the forbidden-region staircase.
_CORNER_T = (0.0, 0.5, 0.75, 0.9, 1.0)
#: Floor levels closer than this are merged, keeping the higher one [mm].
_LEVEL_MERGE = 0.02
#: Angular step of helix cutter locations [deg].
_HELIX_STEP_DEG = 5.0
#: Regions smaller than this are numerical slivers [mm^2].
_MIN_AREA = 1e-6
#: A ramp loop shorter than this many tool diameters is too short to enter on.
_MIN_RAMP_DIAMETERS = 2.0


@dataclass(frozen=True)
class RoughingOptions:
    """How to rough.

    Attributes
    ----------
    stepdown : float, optional
        Maximum depth of one level [mm]. Default :attr:`Tool.level_stepdown` (``min(0.5 * D, axial limit)``): contour
        offsets cannot avoid some full-width cuts (the first loop after a helix, the first
        loop along a wall in an open region), and half a diameter is a safe slotting depth
        for carbide in aluminium.
    stepover : float, optional
        Radial step between offset loops [mm], in ``(0, D)``. Default :attr:`Tool.level_stepover` (0.7 D).
        Above the tool radius, the islands of stock that would survive between loops are
        cut by extra loops (module docstring).
    allowance : float
        Stock left on the part, radially on walls and vertically on floors [mm], >= 0.
    ramp_angle : float
        Maximum descent angle of helix and ramp entries [deg], in ``(0, 45]``.
    helix_diameter : float, optional
        Diameter of the circle the tool centre follows in a helix entry [mm]. Default
        ``0.8 * D``: smaller than ``D`` so no post is left in the middle. In a pocket too
        small for it the helix shrinks, down to ``min_helix_diameter``; below that the
        pocket is entered by a ramp along one of its loops instead.
    min_helix_diameter : float, optional
        Smallest helix diameter [mm]. Default ``0.3 * D``: the helix must stay well
        outside the end mill's non-cutting core (typically 0.1 to 0.2 D across) or the
        core would plunge.
    arc_tolerance : float
        Maximum chord error of the polygonal buffers [mm]. The buffers are enlarged so the
        error only ever leaves stock (never cuts into the allowance); keep it far below the
        allowance. Default 0.002 mm.
    spring_pass : bool
        Cut the outermost loop of every region at every level a second time, after the
        region (a spring pass: the walls to size where the tool deflected). Default off.
    skim : float
        The top floor's level, no more than this below the stock top [mm], is left to the finishing where
        :func:`cadcam.levelskim.without_skimmed` allows; the next level is then up to ``skim`` deeper than the
        stepdown, never past :attr:`~cadcam.model.Tool.full_width_limit`. Default 0: every floor's level.
    air_feed : float, optional
        The feed moves that cut nothing run at [mm/min] (the machine's, which :mod:`cadcam.chipfeed` gives them):
        a link from loop to loop of a region goes along the paths cut at its level where that is quicker than
        the lift (:meth:`cadcam.levelpath.CutPaths.stays_down`). Default None: it lifts.
    """

    stepdown: float | None = None
    stepover: float | None = None
    allowance: float = 0.3
    ramp_angle: float = 3.0
    helix_diameter: float | None = None
    min_helix_diameter: float | None = None
    arc_tolerance: float = 0.002
    spring_pass: bool = False
    skim: float = 0.0
    air_feed: float | None = None


@dataclass(frozen=True)
class _Params:
    radius: float
    stepdown: float
    stepover: float
    allowance: float
    tan_ramp: float
    helix_radius: float
    min_helix_radius: float
    arc_tolerance: float
    clear_z: float
    safe_z: float
    lead_gap: float
    link_max: float
    min_ramp_length: float
    spring_pass: bool = False
    skim: float = 0.0
    air_feed: float | None = None


def _resolve(options: RoughingOptions, tool: Tool, setup: Setup) -> _Params:
    d = tool.diameter
    if tool.shape not in ("flat", "bull"):
        raise ToolError(f"T{tool.number} is a {'drill' if tool.is_drill else 'ball end mill'}; "
                        "z-level roughing needs a flat or bull-nose end mill")
    if not (d > 0 and math.isfinite(d)):
        raise ToolError(f"T{tool.number} has diameter {d}")
    stepdown = tool.level_stepdown if options.stepdown is None else float(options.stepdown)
    stepover = tool.level_stepover if options.stepover is None else float(options.stepover)
    helix_d = 0.8 * d if options.helix_diameter is None else float(options.helix_diameter)
    min_helix_d = 0.3 * d if options.min_helix_diameter is None else float(options.min_helix_diameter)
    if not 0 < stepdown <= tool.flute_length:
        raise ToolpathError(f"stepdown {stepdown:g} mm must lie in (0, flute length {tool.flute_length:g}]",
                            source="roughing.stepdown")
    if not 0 < stepover < d:
        raise ToolpathError(f"stepover {stepover:g} mm must lie in (0, tool diameter {d:g})",
                            source="roughing.stepover")
    if not 0 <= options.allowance < 1e3:
        raise ToolpathError(f"allowance {options.allowance:g} mm must be >= 0", source="roughing.allowance")
    if not 0 < options.ramp_angle <= 45:
        raise ToolpathError(f"ramp angle {options.ramp_angle:g} deg must lie in (0, 45]",
                            source="roughing.ramp_angle")
    if not 0 < helix_d < 2 * d:
        raise ToolpathError(f"helix diameter {helix_d:g} mm must lie in (0, {2 * d:g})",
                            source="roughing.helix_diameter")
    if not 0 < min_helix_d <= helix_d:
        raise ToolpathError(f"min helix diameter {min_helix_d:g} mm must lie in (0, {helix_d:g}]",
                            source="roughing.min_helix_diameter")
    if not 0 < options.arc_tolerance <= 0.1:
        raise ToolpathError(f"arc tolerance {options.arc_tolerance:g} mm must lie in (0, 0.1]",
                            source="roughing.arc_tolerance")
    if not options.skim >= 0:
        raise ToolpathError(f"skim {options.skim:g} mm must be >= 0", source="roughing.skim")
    top = float(setup.stock_max[2])
    clear_z = top + float(setup.clearance)
    if setup.safe_z < clear_z:
        raise ToolpathError(f"safe_z {setup.safe_z:g} lies below the clearance height {clear_z:g}",
                            source="setup.safe_z")
    return _Params(
        radius=tool.radius,
        stepdown=stepdown,
        stepover=stepover,
        allowance=float(options.allowance),
        tan_ramp=math.tan(math.radians(options.ramp_angle)),
        helix_radius=helix_d / 2,
        min_helix_radius=min_helix_d / 2,
        arc_tolerance=float(options.arc_tolerance),
        clear_z=clear_z,
        safe_z=float(setup.safe_z),
        lead_gap=max(float(setup.clearance), 0.5),
        link_max=max(1.5 * stepover, tool.radius),
        min_ramp_length=_MIN_RAMP_DIAMETERS * d,
        spring_pass=bool(options.spring_pass),
        skim=max(0.0, min(float(options.skim), tool.full_width_limit - stepdown)),
        air_feed=options.air_feed,
    )


# --------------------------------------------------------------------------- levels


def _levels(part: trimesh.Trimesh, setup: Setup, p: _Params) -> np.ndarray:
    """Level heights, top down, ending at the setup's floor [mm]."""
    # workholding: the last level breaks out just below the part (Setup.floor_z), never into the vise
    top, bottom = float(setup.stock_max[2]), float(setup.floor_z)
    nz = part.face_normals[:, 2]
    flat_up = nz > 1.0 - 1e-6
    floors = np.unique(np.round(part.triangles_center[flat_up, 2], 6))
    wanted = floors + p.allowance
    wanted = wanted[(wanted < top - 1e-6) & (wanted > bottom + 1e-6)]
    mandatory: list[float] = []
    for z in sorted(wanted, reverse=True):
        # Two floors within _LEVEL_MERGE: keep the higher level, the lower floor gets a
        # hair more stock rather than less.
        if not mandatory or mandatory[-1] - z > _LEVEL_MERGE:
            mandatory.append(float(z))
    mandatory.append(bottom)
    levels: list[float] = []
    hi = top
    for m in mandatory:
        if hi - m <= 1e-9:
            continue
        n = max(1, math.ceil((hi - m) / p.stepdown - 1e-9))
        levels.extend(hi - (hi - m) * i / n for i in range(1, n + 1))
        levels[-1] = m
        hi = m
    return np.array(levels)


def _buffer(geom: BaseGeometry, distance: float, tol: float) -> BaseGeometry:
    """Outward buffer whose polygon never comes closer than ``distance`` to ``geom``.

    Vertices of shapely's round buffers lie on the arc and chords cut inside it; the
    distance is enlarged so the chord midpoints lie on the true offset, at the cost of
    leaving at most ``tol`` more.
    """
    if distance <= 0:
        return geom
    half_step = math.acos(max(1.0 - tol / distance, 0.0))  # half the angle of one chord
    quad_segs = max(2, math.ceil((math.pi / 2) / (2 * half_step)))
    step = (math.pi / 2) / quad_segs
    return geom.buffer(distance / math.cos(step / 2), quad_segs=quad_segs)


def _forbidden_terms(z: float, p: _Params) -> list[tuple[float, float]]:
    """(shadow height, buffer distance) pairs whose union is the forbidden region at z."""
    a = p.allowance
    if a <= _FLOOR_EPS:
        return [(z + _FLOOR_EPS, p.radius)]
    terms = []
    for t0, t1 in zip(_CORNER_T[:-1], _CORNER_T[1:]):
        zq = z - a * t1 + (_FLOOR_EPS if t1 == 1.0 else 0.0)
        terms.append((zq, p.radius + a * math.sqrt(1.0 - t0 * t0)))
    return terms


# --------------------------------------------------------------------------- geometry helpers


def _polygons(geom: BaseGeometry) -> list[Polygon]:
    if geom.is_empty:
        return []
    if isinstance(geom, Polygon):
        return [geom]
    return [g for g in getattr(geom, "geoms", []) if isinstance(g, Polygon) and not g.is_empty]


@dataclass
class _Ring:
    coords: np.ndarray  # (n+1, 2) closed
    k: float  # erosion index (order of cutting); a gap's loops lie half-way between two
    line: LineString


#: A point this much less than the tool radius from a loop counts as cut [mm]: gaps are found
#: conservatively, and a gap within it of the cut area everywhere is no gap.
_GAP_TOL = 0.01


def _rings(region: Polygon, p: _Params) -> list[_Ring]:
    """Contour-parallel loops of a region: the rings of its erosions by k * stepover, and with a
    stepover above the tool radius the loops of the gaps they leave (:func:`_gap_rings`)."""
    rings: list[_Ring] = []
    k = 0
    while True:
        eroded = region if k == 0 else region.buffer(-k * p.stepover, quad_segs=16)
        polys = [q for q in _polygons(eroded) if q.area > _MIN_AREA]
        if not polys:
            break
        for poly in polys:
            poly = orient(poly, 1.0)
            for ring in [poly.exterior, *poly.interiors]:
                c = np.asarray(ring.coords)[:, :2]
                if len(c) >= 4 and ring.length > 1e-3:
                    rings.append(_Ring(c, k, LineString(c)))
        k += 1
    if rings and p.stepover > p.radius + 1e-12:
        rings += _gap_rings(region, rings, p)
    return rings


def _gap_rings(region: Polygon, rings: list[_Ring], p: _Params) -> list[_Ring]:
    """Loops over the parts of ``region`` farther than the tool radius from every loop of ``rings``.

    Each gap is cleared like a region of its own at a stepover of the radius (which leaves none);
    its loops lie inside ``region``, so links to them are checked as any other. They take the
    erosion index of the nearest loop plus a half: cut between that loop and the next.
    """
    reach = shapely.union_all([r.line.buffer(p.radius - _GAP_TOL, quad_segs=8) for r in rings])
    narrow = dataclasses.replace(p, stepover=p.radius)
    out: list[_Ring] = []
    lines = np.array([r.line for r in rings], dtype=object)
    for gap in _polygons(region.difference(reach)):
        if gap.buffer(-_GAP_TOL).is_empty:
            continue  # within the tolerance of the cut area: cut
        k = rings[int(np.argmin(shapely.distance(lines, gap)))].k + 0.5
        out += [_Ring(r.coords, k, r.line) for r in _rings(gap, narrow)]
    return out


def _dedupe(c: np.ndarray) -> np.ndarray:
    keep = np.ones(len(c), bool)
    keep[1:] = np.linalg.norm(np.diff(c, axis=0), axis=1) > 1e-9
    return c[keep]


def _ring_from(c: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The closed ring ``c`` re-started at its point ``q``."""
    seg = np.linalg.norm(np.diff(c, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    d = LineString(c).project(Point(q))
    n = len(c) - 1
    i = int(np.clip(np.searchsorted(cum, d, side="right") - 1, 0, n - 1))
    out = np.vstack([q[None], c[i + 1 : n + 1], c[1 : i + 1], q[None]])
    return _dedupe(out)


def _climb(ring: np.ndarray, uncut_dir: np.ndarray | None, inside_out: bool) -> np.ndarray:
    """Orient a ring (starting and ending at its entry) so the uncut side is on the left.

    ``ring`` comes oriented as shapely's ``orient(poly, 1)`` (exteriors counter-clockwise,
    holes clockwise: the region on the left). ``uncut_dir`` points from the cleared side
    across the ring; without it, inside-out cutting has the uncut stock outside the region
    (reverse), outside-in inside it (keep).
    """
    t = ring[1] - ring[0]
    if uncut_dir is not None and np.linalg.norm(uncut_dir) > 1e-6 and np.linalg.norm(t) > 1e-12:
        left = np.array([-t[1], t[0]])
        return ring if left @ uncut_dir >= 0 else ring[::-1].copy()
    return ring[::-1].copy() if inside_out else ring


# --------------------------------------------------------------------------- path building


def _helix(centre: np.ndarray, r: float, p: _Params, z_top: float, z: float,
           start_angle: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Clockwise helix from ``z_top`` down to ``z`` then one full turn at ``z``, starting at
    ``start_angle`` [rad] from +X around ``centre``.

    Returns (descent points (n,3), flat turn points (m,3)); the first descent point is the
    helix start at ``z_top``.
    """
    dth = math.radians(_HELIX_STEP_DEG)
    chord = 2 * r * math.sin(dth / 2)
    n = max(1, math.ceil((z_top - z) / (chord * p.tan_ramp) - 1e-9))
    m = round(2 * math.pi / dth)
    th = start_angle - dth * np.arange(n + m + 1)
    xy = centre[None] + r * np.column_stack([np.cos(th), np.sin(th)])
    zz = np.maximum(z_top - (z_top - z) * np.arange(n + m + 1) / n, z)
    pts = np.column_stack([xy, zz])
    return pts[: n + 1], pts[n + 1 :]


def _lowest_air(xy: np.ndarray, air_at: Callable[[np.ndarray], np.ndarray] | None) -> int:
    """Index of the point of ``xy`` (n, 2) where the known stock lets the tool lowest (0 without one)."""
    if air_at is None:
        return 0
    return int(np.argmin(air_at(np.asarray(xy).reshape(-1, 2))))


def _ramp(ring: np.ndarray, p: _Params, z_top: float, z: float) -> tuple[np.ndarray, np.ndarray]:
    """Ramp along a closed ring from ``z_top`` down to ``z``, then one full loop at ``z``."""
    length = LineString(ring).length
    need = (z_top - z) / p.tan_ramp
    reps = math.ceil((need + length) / length) + 1
    path = np.vstack([ring] + [ring[1:]] * reps)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    cut_at = [need, need + length]
    s_all = np.unique(np.concatenate([s[s < need + length], cut_at]))
    xy = np.column_stack([np.interp(s_all, s, path[:, 0]), np.interp(s_all, s, path[:, 1])])
    zz = np.maximum(z_top - s_all * p.tan_ramp, z)
    pts = np.column_stack([xy, zz])
    i = int(np.searchsorted(s_all, need))
    return pts[: i + 1], pts[i + 1 :]


# --------------------------------------------------------------------------- regions


@dataclass
class _Entry:
    kind: str  # "air", "helix", "ramp"
    start_xy: np.ndarray
    air_xy: np.ndarray | None = None  # for "air": where to descend
    ring_index: int = -1  # for "air" and "ramp": the first ring cut
    centre: np.ndarray | None = None  # for "helix"
    helix_radius: float = 0.0


def _open_entry(region: Polygon, rings: list[_Ring], rect: tuple[float, float, float, float],
                g: float, p: _Params) -> _Entry | None:
    """Entry from outside the stock: a point of the region's outline on the grown stock box."""
    x0, y0, x1, y1 = rect
    ext = np.asarray(region.exterior.coords)[:, :2]
    tol = 1e-7
    sides = [
        (np.abs(ext[:, 0] - x0) < tol, np.array([-1.0, 0.0])),
        (np.abs(ext[:, 0] - x1) < tol, np.array([1.0, 0.0])),
        (np.abs(ext[:, 1] - y0) < tol, np.array([0.0, -1.0])),
        (np.abs(ext[:, 1] - y1) < tol, np.array([0.0, 1.0])),
    ]
    best = None
    for on, normal in sides:
        both = on[:-1] & on[1:]
        if not both.any():
            continue
        seg = np.linalg.norm(np.diff(ext, axis=0), axis=1) * both
        i = int(np.argmax(seg))
        if seg[i] > 1e-6 and (best is None or seg[i] > best[0]):
            best = (seg[i], 0.5 * (ext[i] + ext[i + 1]), normal)
    if best is None:
        return None
    _, s, normal = best
    lead = open_lead([r.line for r in rings], region, s, normal)
    if lead is None:
        return None
    idx, q = lead  # straight in from the air outside the stock's side: through s, onto the loop
    air = q + normal * (float(np.dot(s - q, normal)) + p.radius - g + p.lead_gap)
    return _Entry("air", q, air_xy=air, ring_index=idx)


def _closed_entry(region: Polygon, rings: list[_Ring], p: _Params) -> _Entry | None:
    mic = shapely.maximum_inscribed_circle(region, tolerance=0.01)
    centre = np.asarray(mic.coords[0])
    radius = mic.length
    # 0.02 mm margin: the inscribed circle is found to within 0.01 mm.
    r = min(p.helix_radius, radius - 0.02)
    if r >= p.min_helix_radius:
        return _Entry("helix", centre + np.array([r, 0.0]), centre=centre, helix_radius=r)
    order = sorted(range(len(rings)), key=lambda j: (-rings[j].k, -rings[j].line.length))
    for j in order:
        if rings[j].line.length >= p.min_ramp_length:
            return _Entry("ramp", rings[j].coords[0].copy(), ring_index=j)
    return None


#: Distances [grid cells] beside a rest region at which an entry from the air is looked for.
_SIDE_ENTRY_CELLS = (1.0, 2.0, 4.0)
#: Most candidate points tested per distance for an entry from the air.
_SIDE_ENTRY_POINTS = 400


def _clear_down_to(known: Simulation, tool: Tool, z: float) -> Callable[[np.ndarray], np.ndarray]:
    """``clear(xy) -> (n,) bool``: ``tool`` (taken as a flat end mill) standing at ``xy`` with its tip
    at ``z`` [mm] touches none of the ``known`` stock.

    One dilation of the stock above ``z`` per call, then a look-up per point: at least as
    cautious as :func:`cadcam.stock.clear_height` (which takes the stock as reaching up to a
    grid point's height within a cell diagonal of it), with half a cell diagonal more for
    rounding the point to its nearest grid point.
    """
    g = known.grid
    reach = tool.radius + g.cell * math.sqrt(2.0) + 0.5 * g.cell * math.sqrt(2.0)
    blocked = near_cells(known.stock_top > z + 1e-9, reach, g.cell)

    def clear(xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        i = np.rint((xy[:, 0] - g.x0) / g.cell).astype(np.int64)
        j = np.rint((xy[:, 1] - g.y0) / g.cell).astype(np.int64)
        inside = (i >= 0) & (i < g.nx) & (j >= 0) & (j < g.ny)
        out = np.empty(len(xy), dtype=bool)
        out[inside] = ~blocked[j[inside], i[inside]]
        if not inside.all():  # off the grid: the exact test
            out[~inside] = clear_height(known, tool, xy[~inside]) <= z + 1e-9
        return out

    return clear


def _side_entry(region: Polygon, rings: list[_Ring], space: BaseGeometry,
                clear: Callable[[np.ndarray], np.ndarray], p: _Params, cell: float = 0.5) -> _Entry | None:
    """Entry into a closed rest region from the air beside it: the tool descends where the known
    stock leaves it clear down to the level (``clear``, :func:`_clear_down_to`), outside the region
    but where the tool may go (``space``), and feeds straight across onto the region's outer loop.
    None if there is no such place.

    ``cell`` [mm] is the stock model's grid spacing: the air is only known a cell or so away from
    the rest material the region was grown from.
    """
    outer = [j for j, r in enumerate(rings) if r.k == 0]
    if not outer:
        return None
    covered = space.buffer(COVER_TOL)
    shapely.prepare(covered)
    for cells in _SIDE_ENTRY_CELLS:
        d = cells * cell
        around = region.buffer(d, quad_segs=8).boundary
        if around.is_empty:
            continue
        step = max(around.length / _SIDE_ENTRY_POINTS, 0.25 * cell)
        cand = shapely.get_coordinates(shapely.segmentize(around, step))
        cand = cand[shapely.contains_xy(covered, cand[:, 0], cand[:, 1])]
        if not len(cand):
            continue
        cand = cand[clear(cand)]
        for xy in cand:
            j = min(outer, key=lambda j: rings[j].line.distance(Point(xy)))
            q = np.asarray(nearest_points(rings[j].line, Point(xy))[0].coords[0])
            if covered.covers(LineString([xy, q])):
                return _Entry("air", q, air_xy=np.asarray(xy, dtype=np.float64), ring_index=j)
    return None


def _cut_region(path: LevelPath, region: Polygon, rings: list[_Ring], entry: _Entry, z: float,
                z_prev: float, inside_out: bool, p: _Params,
                air_at: Callable[[np.ndarray], np.ndarray] | None = None) -> bool:
    """Emit the moves clearing one region at level z. Returns False if loops were left.

    ``air_at(xy)`` is the lowest tip height clear of the known stock at tool positions: an
    entry starts no higher than needed, down to the level itself (no helix through air)."""

    def air_over(xy: np.ndarray) -> float:
        if air_at is None:
            return z_prev
        return min(z_prev, max(float(np.max(air_at(np.asarray(xy).reshape(-1, 2)))), z))
    covered = region.buffer(COVER_TOL)
    shapely.prepare(covered)
    cut: list[LineString] = []
    paths = CutPaths()  # what the tool went along at z: the links may stay down on it
    uncut = list(range(len(rings)))
    outer: list[np.ndarray] = []  # the outermost loops as cut, for a spring pass

    def emit_ring(j: int, q: np.ndarray, uncut_dir: np.ndarray | None) -> None:
        ring = _climb(_ring_from(rings[j].coords, q), uncut_dir, inside_out)
        path.add_many(np.column_stack([ring, np.full(len(ring), z)]), Motion.CUT)
        paths.add(ring)
        cut.append(rings[j].line)
        uncut.remove(j)
        if rings[j].k == 0:
            outer.append(ring)

    if entry.kind == "air":
        path.go_to(entry.air_xy, p)
        # a lead gap outside the stock's side: air down to the level, whatever the levels above cut
        path.descend([*entry.air_xy, z], z if air_at is None else air_over(entry.air_xy), p)
        path.add([*entry.start_xy, z], Motion.CUT)
        paths.add(np.array([entry.air_xy, entry.start_xy]))
        emit_ring(entry.ring_index, entry.start_xy, entry.start_xy - entry.air_xy)
    elif entry.kind == "helix":
        th = np.linspace(0.0, 2 * math.pi, 24, endpoint=False)
        # The helix starts where the known stock lets the tool lowest (a pocket roughed before,
        # its wall's skin beside part of the circle): from there it ramps into whatever is left,
        # never deeper than the previous level, instead of circling down through air. Where the
        # narrowest helix the tool may take starts lower (the skin on a roughed pocket's wall within
        # reach of the wider one only), it takes that one: less ramp at the same angle.
        radius, start, z_top = entry.helix_radius, 0, math.inf
        # (the entry's radius is never below the narrowest: _closed_entry takes a helix only where it fits)
        for r in (entry.helix_radius, p.min_helix_radius) if air_at is not None else (entry.helix_radius,):
            circle = entry.centre + r * np.column_stack([np.cos(th), np.sin(th)])
            i = _lowest_air(circle, air_at)
            z_start = air_over(circle[i])
            if z_start < z_top - 1e-6:
                radius, start, z_top = r, i, z_start
            if z_top <= z:
                break
        descent, turn = _helix(entry.centre, radius, p, z_top, z, float(th[start]))
        if z_top > z and air_over(entry.centre) <= z:
            # Air under the centre (a hole roughed before, with its skin left): straight down
            # there and out onto the circle, not a helix through the air.
            path.go_to(entry.centre, p)
            path.descend([*entry.centre, z], z, p)
            path.add(descent[-1], Motion.CUT)
        else:
            path.go_to(descent[0, :2], p)
            path.descend(descent[0], z_top, p)  # down to the previous floor (or the known stock): air
            path.add_many(descent[1:], Motion.PLUNGE)
        path.add_many(turn, Motion.CUT)
        paths.add(turn)
        cut.append(LineString(turn[:, :2]))
    else:  # ramp
        j = entry.ring_index
        coords = rings[j].coords
        # As the helix: the ramp starts where the known stock lets the tool lowest.
        candidates = coords[:-1:max(1, (len(coords) - 1) // 64)]
        ring = _climb(_ring_from(coords, candidates[_lowest_air(candidates, air_at)]), None, inside_out)
        z_top = air_over(ring[:1])
        descent, rest = _ramp(ring, p, z_top, z)
        path.go_to(descent[0, :2], p)
        path.descend(descent[0], z_top, p)
        path.add_many(descent[1:], Motion.PLUNGE)
        path.add_many(rest, Motion.CUT)
        cut.append(rings[j].line)
        uncut.remove(j)

    order = LoopOrder.of([r.line for r in rings], np.array([r.k for r in rings], dtype=np.float64), inside_out,
                         2 * p.radius)
    while uncut:
        link = order.next(uncut, MultiLineString(cut), covered, path.here, p.link_max)
        if link is None:
            log.warning("z=%.3f: %d loop(s) of a region could not be linked safely; left uncut", z, len(uncut))
            return False
        j, src, q = link
        cur = path.here
        direct = LineString([cur[:2], q])
        at_src = np.linalg.norm(cur[:2] - src) < 1e-7
        if not at_src and direct.length <= p.link_max and covered.covers(direct):
            src = cur[:2]  # a short link straight from here stays in the region
        elif not at_src:
            path.link_to(src, z, paths, p.air_feed, p)  # on a path already cut at this level: air
        path.add([*q, z], Motion.CUT)
        paths.add(np.array([src, q]))
        emit_ring(j, q, q - src)
    if p.spring_pass:
        # The outer loops again, in the same direction: the tool springs back less with no
        # stock left to push it, so the walls come to size. The loops were cut: air all the way.
        for ring in outer:
            if np.linalg.norm(path.here[:2] - ring[0]) > 1e-9:
                path.go_to(ring[0], p)
                path.descend([*ring[0], z], z, p)
            path.add_many(np.column_stack([ring, np.full(len(ring), z)]), Motion.CUT)
    return True


# --------------------------------------------------------------------------- main


def zlevel_roughing(
    part: trimesh.Trimesh,
    setup: Setup,
    tool: Tool,
    cutting: CuttingData,
    options: RoughingOptions = RoughingOptions(),
    progress: Callable[[int, int], None] | None = None,
    rest: Simulation | None = None,
    rest_above: float = 0.0,
    within: Callable[[float], BaseGeometry] | None = None,
    air: Simulation | None = None,
    cut_before: Callable[[float], BaseGeometry] | None = None,
    exclude: Callable[[int], BaseGeometry | None] | None = None,
) -> Operation:
    """Clear the stock around ``part`` level by level, leaving ``options.allowance``.

    With ``rest`` (the stock earlier operations left) this is *rest roughing*: at each level only the regions
    within the tool radius of material that ``rest`` still holds at that level, more than ``rest_above`` [mm]
    above the part (or the stock bottom where there is no part), are cleared, and no level lies deeper than
    the tool's stick-out below the stock top (what it cannot reach stays, for the caller to report). A level
    also clears the stock a deeper level's cut would meet more than the tool's axial limit of at once
    (:func:`cadcam.rest.rest_level_masks`): a corner's sliver is taken a level at a time, not at full width.

    Parameters
    ----------
    part : trimesh.Trimesh
        Watertight part in work coordinates [mm], inside the stock of ``setup``.
    setup : Setup
        Stock box, ``safe_z`` (start and end height) and ``clearance`` (links rapid at ``stock top + clearance``).
    tool : Tool
        Flat or bull-nose end mill.
    cutting : CuttingData
        Feeds: ``plunge_feed`` applies to PLUNGE moves (helices, ramps, descents).
    options : RoughingOptions
    progress : callable, optional
        ``progress(done, total)`` after each level.
    rest : Simulation, optional
        The stock to rest-rough (see above).
    rest_above : float
        Rest material thinner than this over the part is left [mm].
    air : Simulation, optional
        The stock known to be there before this operation, default ``rest``: entries start
        just above it rather than at the previous level (no helix through air), and below the
        tool's reach its holder keeps off it (:func:`cadcam.rest.without_holder`).
    within : callable, optional
        ``within(radius)``: the XY region the tool axis must stay in (a relief's
        :meth:`cadcam.relief.Boundary.centre_region`); None: anywhere around the stock.
    cut_before : callable, optional
        ``cut_before(z)``: the XY area earlier operations cut down to level ``z`` [mm] (holes cut to size,
        :meth:`cadcam.drilling.HolePlan.cut_at`): a pocket there too small to enter is not warned about.
    exclude : callable, optional
        ``exclude(i)``: the area (tool centres) level ``i`` leaves to deep cuts (:mod:`cadcam.adaptive`) or None.

    Returns
    -------
    Operation
        ``kind="roughing"``, ``allowance=options.allowance``; points are tool tip positions
        [mm]. Starts and ends at ``setup.safe_z``; empty (no points) if nothing is to cut.

    Raises
    ------
    MeshError
        The part mesh is empty.
    ToolError
        The tool is a ball end mill.
    ToolpathError
        An option is out of range.
    """
    if part is None or len(part.faces) == 0:
        raise MeshError("part mesh is empty")
    p = _resolve(options, tool, setup)
    levels, deep, top = _levels(part, setup, p), 0, float(setup.stock_max[2])
    if rest is not None:  # the last ``deep`` levels lie below its reach: only where its holder clears the stock
        levels, deep = rest_levels(levels, top, tool.length)
    shadow = part_shadows(part, [zq for z in levels for zq, _ in _forbidden_terms(float(z), p)])
    rect_xy, rect = _axis_rect(setup, p, within)
    known = rest if air is None else air  # the holder kept off all the stock, not only this operation's target
    spaces = without_holder([_level_space(float(z), rect, shadow, p) for z in levels], levels, deep, known, tool)
    levels, spaces = without_skimmed(part, levels, spaces, top, p.skim, p.allowance, p.radius, _FLOOR_EPS)
    if rest is not None:  # per level the rest material, grown by the radius; the loops that meet stock
        rest_grown, masks, choice = rest_targets(rest, known, levels, spaces, p.radius, rest_above, p.allowance, tool)
    skin = top_skin(part, levels, top, p.skim, p.allowance, _FLOOR_EPS)  # the finishing's, on the top floor
    reach = local_levels(levels, spaces, top, p.stepdown, p.radius, exclude, skin) if rest is None else None
    air_at = None if known is None else (lambda xy: clear_height(known, tool, xy))
    path = LevelPath()
    cleared: BaseGeometry | None = None  # None: nothing was ever skipped
    # rest machining knows the air (entries use it): a skipped pocket bars the levels below it, nothing more
    blocked: list[BaseGeometry] = []
    z_prev, skipped, here = top, 0, setup.stock_min[:2]
    pieces: list[Piece] | None = [] if known is not None else None  # rest machining's, cut stack by stack
    for li, z in enumerate(levels):
        z, z_prev = float(z), z_prev if reach is None else reach.floor_above[li]  # a local level's: the last whole
        space = _bounded(spaces[li] if reach is None else reach.spaces[li], cleared, blocked,
                         exclude(li) if exclude is not None else None)
        allowed = space if rest is None else space.intersection(rest_grown(masks[li]))
        plans, missed = _plan_entries(allowed, space, z, rect_xy, p, tool, known, air_at,
                                      None if cut_before is None else (lambda z=z: cut_before(z)),
                                      None if rest is None else choice.at(masks[li], z))
        done_regions, failed, here = (_cut_pieces(pieces, li, plans, z, z_prev, p, air_at, here) if pieces is not None
                                      else (*_cut_nearest_first(path, plans, z, z_prev, p, air_at, here), here))
        skipped += len(missed) + len(failed)
        if rest is not None:
            blocked += [region.buffer(2 * p.radius, quad_segs=4) for region in missed + failed]
        if reach is not None and (skipped or cleared is not None) and not reach.local[li]:
            cleared = shapely.union_all(done_regions) if done_regions else Polygon()
        if path.points:
            path.go_to(path.here[:2], p)
        z_prev = z
        if progress is not None:
            progress(li + 1, len(levels))
    if pieces:  # linked low (cadcam.restlinks)
        cut_stacked(path, pieces, Links(known, tool, rect, spaces), cutting.feed, p)
    if path.points:
        path.add([*path.here[:2], p.safe_z], Motion.RAPID)
    return Operation(name="rough z-level" if rest is None else f"rest rough T{tool.number}", kind="roughing",
                     tool=tool, cutting=cutting, points=np.array(path.points).reshape(-1, 3),
                     motion=np.array(path.motion, dtype=np.int8), allowance=p.allowance)


def _axis_rect(setup: Setup, p: _Params, within: Callable[[float], BaseGeometry] | None
               ) -> tuple[tuple[float, float, float, float], BaseGeometry]:
    """The box the tool axis may roam in [mm]: the stock grown by the tool radius (so the outer loops
    clear the stock's sides), as bounds and as a region, cut to ``within`` where it is given."""
    (sx0, sy0), (sx1, sy1), g = setup.stock_min[:2], setup.stock_max[:2], p.radius
    rect_xy = (float(sx0) - g, float(sy0) - g, float(sx1) + g, float(sy1) + g)
    rect = box(*rect_xy)
    return rect_xy, rect if within is None else rect.intersection(within(p.radius))


def _level_space(z: float, rect: BaseGeometry, shadow: dict, p: _Params) -> BaseGeometry:
    """Where the tool axis may go at level ``z`` [mm]: the stock rectangle less the part's shadows
    grown by the tool (:func:`_forbidden_terms`)."""
    forbidden = shapely.union_all(
        [_buffer(shadow[zq], dist, p.arc_tolerance) for zq, dist in _forbidden_terms(z, p)]
    )
    return rect.difference(forbidden)


def _bounded(allowed: BaseGeometry, cleared: BaseGeometry | None, blocked: list[BaseGeometry],
             taken: BaseGeometry | None = None) -> BaseGeometry:
    """``allowed`` within what the levels above cleared (None: no bound), outside the regions ``blocked``
    below pockets that could not be entered and outside what deep cuts take (``taken``, None: nothing)."""
    if cleared is not None:
        allowed = allowed.intersection(cleared)
    if blocked or taken is not None:
        allowed = allowed.difference(shapely.union_all([*blocked, *([] if taken is None else [taken])]))
    return allowed


def _plan_entries(allowed: BaseGeometry, space: BaseGeometry, z: float, rect_xy: tuple[float, float, float, float],
                  p: _Params, tool: Tool, known: Simulation | None,
                  air_at: Callable[[np.ndarray], np.ndarray] | None,
                  cut_here: Callable[[], BaseGeometry] | None = None,
                  cuts: Callable[[list[LineString]], np.ndarray] | None = None) -> tuple[list[tuple], list[Polygon]]:
    """How to enter each region of level ``z`` to cut: ``(region, rings, entry, inside_out)`` each,
    and the regions no entry fits (left uncut; warned about unless within ``cut_here()``, what earlier
    operations cut at this level). In rest machining only the loops that meet rest material (``cuts``,
    :class:`cadcam.ringorder.LoopChoice`) are cut.

    An open region is entered from outside the stock; with a known stock (rest machining), a
    closed one from the air beside it (``space``: where the tool may go at this level); else by
    a helix or ramp inside it, or in rest machining in the room round it (:func:`cadcam.rest.rooms_round`).
    """
    regions = [r for r in _polygons(allowed) if r.area > _MIN_AREA]
    plans, missed = [], []
    clear_here = None  # where the known stock lets the tool down to this level, when first needed
    for region in regions:
        rings = _rings(region, p)
        if rings and cuts is not None:
            rings = [r for r, c in zip(rings, cuts([r.line for r in rings])) if c]
        elif rings:  # from the block: the loop round the stock's sides cuts nothing
            rings = [r for r, a in zip(rings, round_the_stock([r.line for r in rings], rect_xy, p.radius)) if not a]
        if not rings:
            continue
        entry = _open_entry(region, rings, rect_xy, p.radius, p)
        inside_out = entry is None
        if entry is None and air_at is not None:
            # Rest machining: rest material (a terrace, the skin on a wall) with air beside it
            # is entered from there, as an open region is from outside the stock: no helix or
            # ramp at the plunge feed, and none at all where a strip is too narrow for one.
            if clear_here is None:
                clear_here = _clear_down_to(known, tool, z)
            entry = _side_entry(region, rings, space, clear_here, p, known.grid.cell)
            inside_out = entry is None
        if entry is None:
            entry = _closed_entry(region, rings, p)
        if entry is None:
            missed.append(region)
            continue
        plans.append((region, rings, entry, inside_out))
    # inside a hole already drilled or helixed to size: nothing is left there to enter or warn about
    holes = [m for m in missed if cut_here is not None and cut_here().contains(m)]
    if air_at is not None and len(holes) < len(missed):
        # Rest machining: a region too small for a helix or ramp of its own (the corner a wider tool left in
        # a narrow pocket) is cut with the room round it, a diameter wide, entered by a ramp along that.
        for room in rooms_round([m for m in missed if m not in holes], space, 2 * p.radius):
            rings = _rings(room, p)
            entry = _closed_entry(room, rings, p) if rings else None
            if entry is not None:
                plans.append((room, rings, entry, True))
                missed = [m for m in missed if m in holes or not room.buffer(COVER_TOL).contains(m)]
    for region in missed:
        c = region.representative_point()
        log.log(logging.DEBUG if region in holes else logging.WARNING,
                "z=%.3f: pocket near (%.2f, %.2f) is too small to enter with a helix or ramp; skipped%s",
                z, c.x, c.y, " (a hole cut before)" if region in holes else "")
    return plans, missed


def _nearest(plans: list[tuple], here: np.ndarray) -> int:
    """The index of the planned region (:func:`_plan_entries`) whose entry is nearest to XY ``here`` [mm]."""
    return min(range(len(plans)), key=lambda i: np.linalg.norm(
        (plans[i][2].air_xy if plans[i][2].air_xy is not None else plans[i][2].start_xy) - here))


def _cut_nearest_first(path: LevelPath, plans: list[tuple], z: float, z_prev: float, p: _Params,
                       air_at: Callable[[np.ndarray], np.ndarray] | None,
                       start_xy: np.ndarray) -> tuple[list[Polygon], list[Polygon]]:
    """Cut the planned regions of level ``z`` (:func:`_plan_entries`) onto ``path``, each time the
    one whose entry is nearest to the tool (``start_xy`` [mm] before the first move); returns the
    regions cut and those :func:`_cut_region` could not cut."""
    done, failed = [], []
    while plans:
        region, rings, entry, inside_out = plans.pop(_nearest(plans, path.here[:2] if path.points else start_xy))
        if not path.points:
            first = entry.air_xy if entry.air_xy is not None else entry.start_xy
            path.add([first[0], first[1], p.safe_z], Motion.RAPID)
        if _cut_region(path, region, rings, entry, z, z_prev, inside_out, p, air_at):
            done.append(region)
        else:
            failed.append(region)
    return done, failed


def _cut_pieces(pieces: list[Piece], level: int, plans: list[tuple], z: float, z_prev: float, p: _Params,
                air_at: Callable[[np.ndarray], np.ndarray] | None,
                start_xy: np.ndarray) -> tuple[list[Polygon], list[Polygon], np.ndarray]:
    """As :func:`_cut_nearest_first`, each region onto a path of its own, appended to ``pieces`` for
    :func:`cadcam.restlinks.stacked` to order; also returns where the tool ends [mm]. The regions are taken in the
    same order and cut with the same moves: each starts at the clearance height over its entry, as
    every region there does."""
    done, failed = [], []
    here = np.asarray(start_xy, dtype=np.float64)
    while plans:
        region, rings, entry, inside_out = plans.pop(_nearest(plans, here))
        first = entry.air_xy if entry.air_xy is not None else entry.start_xy
        own = LevelPath()
        own.add([first[0], first[1], p.clear_z], Motion.RAPID)
        if _cut_region(own, region, rings, entry, z, z_prev, inside_out, p, air_at):
            done.append(region)
        else:
            failed.append(region)
        here = own.here[:2]
        piece = Piece.of(level, z, np.array(own.points), np.array(own.motion, dtype=np.int8), p.clear_z, p.radius)
        if piece is not None:
            pieces.append(piece)
    return done, failed, here


