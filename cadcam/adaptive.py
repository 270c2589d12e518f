"""Deep constant-engagement roughing of the walls (issue 32): fewer, deeper levels at a low, held radial engagement.

Z-level roughing (:mod:`cadcam.roughing`) takes its levels no deeper than the tool's full-width limit, because
contour offsets cannot avoid full-width cuts. Where the stock left beside a wall is thin, the tool can instead
take it in one deep pass at a small radial engagement: carbide makers run trochoidal and side cuts at 5-15 % of
D radially (WIDIA, High-Performance Solid Carbide End Mills, "Trochoidal Milling", WIDIA catalogue 2020 p. B55
ff.: ae/D 5-15 %, engagement angle 26-53 deg) with the axial depth far past the 1 x D they allow a slot.
This module plans such passes and lets the z-level strategy keep everything else.

* **Where.** A *deep cut* takes one connected tool-centre region ``C`` of a level (the region
  :func:`cadcam.roughing.zlevel_roughing` would clear there) through a band of levels, from the floor
  above ``z_top`` down to ``z``, when the region is the same (within :data:`_SAME`) on every level of the
  band: vertical walls, no floor in between. Bands are grown bottom-up, as deep as the part allows and no
  deeper than :attr:`AdaptiveOptions.axial_depth` diameters (nor the flutes); a region is taken deep only
  if every region below it that touches it is taken deep as well (the z-level pass never cuts under a deep
  one), and only if the estimated time is less than its levels' (:func:`plan_deep_cuts`).
* **How.** Offsets of the walls (the region's edge against the part, ``F``) at ``j * s``, ``j = J .. 0``
  (``s`` = :attr:`AdaptiveOptions.engagement` x D), outermost first: each pass takes the strip of width
  ``s`` the one before left beside the wall, so on straight runs the engagement is ``s`` and around the
  part's convex corners less. ``J`` is the fewest passes reaching all the stock. The skin of a block
  (a stock margin thinner than ``s``) is one pass round the part.
* **Entry.** The tool goes down beside the stock, in the air, and comes in along the pass sideways: the
  lead-in follows the pass shifted away from the wall, the shift shrinking to nothing over a length that
  keeps the lead-in's slant within the engagement band. No plunge and no ramp into stock.
* **Checked.** Before a deep cut is accepted its moves are replayed on a raster of the band's material
  (the stock less the part grown by the allowance) and the radial engagement measured at every sample of
  every move at depth: the width across the direction of travel of the cutter's leading half that meets
  material (:func:`engagement_profile`). A cut measured above ``(engagement + band) x D`` anywhere is refused and
  its region roughed by levels.
* **Feed.** At a radial engagement ``ae < D/2`` the chip is thinner than the feed per tooth; the deep cut
  runs at ``fz * D / (2 sqrt(ae (D - ae)))`` with ``ae`` the largest measured engagement
  (:func:`chip_thinned_feed`), capped by the machine's feed.
* **Climb milling** (M3): the uncut stock, on the wall's side, is on the left of the travel.
* **Links.** From one run to the next the tool feeds straight across at depth where its disc meets no stock
  left and keeps off the part (and the link is short); otherwise it lifts to the clearance height.

:func:`adaptive_roughing` is the plan's roughing (:class:`cadcam.plan.PlanOptions` ``adaptive``; None keeps
levels only): the levels' operation first, the deep cuts after it. All lengths in millimetres, feeds in mm/min.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import shapely
import trimesh
from scipy.spatial import cKDTree
from shapely.geometry import LineString, MultiLineString, Point, Polygon, box
from shapely.geometry.base import BaseGeometry
from shapely.geometry.polygon import orient
from shapely.ops import linemerge

from cadcam import roughing
from cadcam.levelpath import down_budget, round_the_box
from cadcam.levelskim import without_skimmed
from cadcam.model import CuttingData, Motion, Operation, Setup, Tool
from cadcam.restlinks import nearest_tour
from cadcam.roughing import RoughingOptions, zlevel_roughing
from factory.core.errors import MeshError

log = logging.getLogger(__name__)

#: A region of a level counts as the same as the band floor's when it is no more than this wider [mm].
_SAME = 0.05
#: Regions and stock smaller than this are numerical slivers [mm^2].
_SLIVER = 1e-4
#: Clearance of the lead-in's first point from the stock, beyond touching it [mm].
_AIR_GAP = 0.5
#: Most wall offsets of one deep cut: a region wider than this many steps is left to the levels.
_MAX_PASSES = 12
#: Raster pitch of the engagement check, as a share of the tool radius.
_CELL_SHARE = 0.025
#: Spacing of the engagement check's samples along a move, in raster cells.
_SAMPLE_CELLS = 2.0
#: Longest link fed at depth from one run to the next [mm]; farther, the tool lifts and rapids.
_LINK_MAX = 40.0
#: Deviation allowed when a run's points are thinned to its corners [mm]: under the 1e-4 mm the walls are
#: checked with, so a thinned arc never cuts into them.
_SIMPLIFY = 5e-5
#: Longest segment of a pass's chain [mm]: where the stock is met is judged point by point.
_RESAMPLE = 0.5
#: Samples over the cutter's leading half for the engagement angle.
_ARC_SAMPLES = 180
#: Rapid rate the choice between a deep cut and levels assumes [mm/min]: the post's default timer's.
_RAPID_ESTIMATE = 5000.0
#: Most fronts of one pocket: a pocket needing more is left to the levels.
_MAX_FRONTS = 150
#: Smallest step of a front, as a share of the target's: where even that would pass the band, levels.
_MIN_STEP_SHARE = 0.15
#: Angular step of a helix entry [deg].
_HELIX_STEP_DEG = 5.0
#: Samples over the cutter's leading half when a front's engagement is read.
_FRONT_ARC = 48
#: A front's lead-ins start this far clear of the stock [mm]: they come from the cleared side, where the tool
#: already is, not from the air beside the stock (:data:`_AIR_GAP`); the lead-in stays short.
_FRONT_GAP = 0.05
#: Radii a front's convex corners are rounded with, as shares of the tool radius, tried in turn: the largest
#: that still lets the front advance (a narrow slot takes a small one) and holds the band.
_FRONT_ROUNDING = (0.4, 0.15)
#: Fronts in a row gaining less than a quarter step squared before the fronts stop (creeping into a cusp or a
#: corner, each front dearer than the stock it takes).
_CREEP = 3
#: What a front's reading may pass the target by, as shares of the band, tried in turn.
_FRONT_READINGS = (0.0, 0.25, 0.5)


@dataclass(frozen=True)
class AdaptiveOptions:
    """How deep cuts engage the tool.

    Attributes
    ----------
    engagement : float or None
        Target radial engagement, as a share of D: the wall offsets' step. None (the default): the
        tool's own, from the tool library (:attr:`cadcam.model.Tool.engagement_share`, 0.15 unless the
        library says otherwise; WIDIA's trochoidal range is 5-15 %).
    band : float
        Tolerance over the target, as a share of D: no sample of a deep cut may engage more than
        ``target + band * D``, nor more than the tool's radial limit (:meth:`ceiling`). Default 0.05.
    axial_depth : float
        Deepest band, in diameters (never past the flutes). Default 2: side cuts at a small radial
        engagement run to about twice the diameter (high-efficiency milling practice, well inside the
        30 mm flutes of the library's 10 mm end mill).
    """

    engagement: float | None = None
    band: float = 0.05
    axial_depth: float = 2.0

    def share(self, tool: Tool) -> float:
        """The radial engagement to hold with ``tool`` [share of D]: :attr:`engagement`, else the tool's own."""
        return tool.engagement_share if self.engagement is None else self.engagement

    def target(self, tool: Tool) -> float:
        """The radial engagement to hold with ``tool`` [mm]."""
        return self.share(tool) * tool.diameter

    def ceiling(self, tool: Tool) -> float:
        """The most radial engagement any sample of a deep cut with ``tool`` may take [mm]: the target and
        the band, never past the tool's radial limit for cuts deeper than its full-width limit
        (:attr:`cadcam.model.Tool.deep_radial_limit`, which ``factory verify`` holds it to)."""
        return min((self.share(tool) + self.band) * tool.diameter, tool.deep_radial_limit)


@dataclass(frozen=True)
class DeepCut:
    """One region taken deep: ``region`` (tool-centre region [mm]) from the floor at ``z_top`` down to ``z``.

    ``levels``: the indices of the z-level strategy's levels it replaces. ``points``/``motion``: its moves
    (tool tip [mm]), from the first descent in the air to the last cut; ``engagement``: the largest radial
    engagement measured [mm]; ``length``: its feed length [mm]."""

    region: Polygon
    z_top: float
    z: float
    levels: tuple[int, ...]
    points: np.ndarray
    motion: np.ndarray
    engagement: float
    length: float


@dataclass(frozen=True)
class DeepPlan:
    """The deep cuts of one roughing, top down, and per z-level level the area they take from it."""

    cuts: tuple[DeepCut, ...]
    taken: tuple[BaseGeometry | None, ...]

    def excluded(self, index: int) -> BaseGeometry | None:
        """What the z-level strategy leaves out at level ``index`` (None: nothing)."""
        return self.taken[index] if 0 <= index < len(self.taken) else None


def chip_thinned_feed(cutting: CuttingData, tool: Tool, engagement: float, max_feed: float) -> CuttingData:
    """``cutting`` with its feed raised for a radial engagement of ``engagement`` [mm] (< D/2), so the chip at
    the edge stays the feed per tooth: ``feed * D / (2 sqrt(ae (D - ae)))``, at most ``max_feed`` [mm/min].

    The plunge feed is kept (entries are not thinned). At ``ae >= D/2`` (or 0) the feed is unchanged."""
    d = tool.diameter
    if not 0 < engagement < d / 2:
        return cutting
    factor = d / (2.0 * math.sqrt(engagement * (d - engagement)))
    return dataclasses.replace(cutting, feed=min(max_feed, max(cutting.feed, cutting.feed * factor)))


def adaptive_roughing(
    part: trimesh.Trimesh,
    setup: Setup,
    tool: Tool,
    cutting: CuttingData,
    max_feed: float,
    options: RoughingOptions = RoughingOptions(),
    adaptive: AdaptiveOptions = AdaptiveOptions(),
    progress: Callable[[int, int], None] | None = None,
    within: Callable[[float], BaseGeometry] | None = None,
    cut_before: Callable[[float], BaseGeometry] | None = None,
) -> tuple[Operation, ...]:
    """Roughing by levels, with deep constant-engagement cuts where they are faster (module docstring).

    The levels' operation (:func:`cadcam.roughing.zlevel_roughing`, less the regions taken deep) comes
    first, then ``"rough adaptive"``: the deep cuts top down, at the chip-thinned feed of their largest
    engagement, capped at ``max_feed`` [mm/min]. Inside a relief's boundary or beside the jaws (``within``)
    only levels. Parameters and errors as :func:`cadcam.roughing.zlevel_roughing`; returns the levels'
    operation (empty where the deep cuts took everything) and the deep cuts' if there are any.
    """
    if part is None or len(part.faces) == 0:
        raise MeshError("part mesh is empty")
    plan = None
    if within is None:
        p = roughing._resolve(options, tool, setup)
        levels = roughing._levels(part, setup, p)
        shadow = roughing.part_shadows(part, [zq for z in levels for zq, _ in roughing._forbidden_terms(float(z), p)])
        _, rect = roughing._axis_rect(setup, p, None)
        spaces = tuple(roughing._level_space(float(z), rect, shadow, p) for z in levels)
        levels, spaces = without_skimmed(part, levels, spaces, float(setup.stock_max[2]), p.skim, p.allowance,
                                         p.radius, roughing._FLOOR_EPS)  # as the levels' own roughing does
        geometry = BandGeometry(
            levels=tuple(float(z) for z in levels), spaces=spaces, top=float(setup.stock_max[2]),
            stock=box(*setup.stock_min[:2], *setup.stock_max[:2]), axis_box=rect, allowance=p.allowance,
            clear_z=p.clear_z, lead_gap=p.lead_gap, tan_ramp=p.tan_ramp, helix_radius=p.helix_radius,
            min_helix_radius=p.min_helix_radius, block=True, air_feed=p.air_feed)
        plan = plan_deep_cuts(geometry, tool, cutting, max_feed,
                              lambda region: sum(r.line.length for r in roughing._rings(region, p)), adaptive)
    exclude = plan.excluded if plan is not None and plan.cuts else None
    ops = [zlevel_roughing(part, setup, tool, cutting, options, progress=progress, within=within,
                           cut_before=cut_before, exclude=exclude)]
    if exclude is not None:
        feed = chip_thinned_feed(cutting, tool, max(c.engagement for c in plan.cuts), max_feed)
        first = plan.cuts[0].points[0]
        points = np.vstack([[[first[0], first[1], setup.safe_z]], *[c.points for c in plan.cuts]])
        motion = np.concatenate([[int(Motion.RAPID)], *[c.motion for c in plan.cuts]]).astype(np.int8)
        last = points[-1]
        points = np.vstack([points, [[last[0], last[1], setup.safe_z]]])
        motion = np.append(motion, np.int8(Motion.RAPID))
        ops.append(Operation(name="rough adaptive", kind="roughing", tool=tool, cutting=feed, points=points,
                             motion=motion, allowance=options.allowance))
    return tuple(ops)


# --------------------------------------------------------------------------- choosing the regions


@dataclass(frozen=True)
class BandGeometry:
    """What :func:`plan_deep_cuts` needs of a roughing (all [mm]).

    ``levels``: level heights, top down; ``spaces``: the tool-centre region of each level; ``top``: the
    stock top; ``stock``: the stock's XY rectangle; ``axis_box``: the box the tool axis roams in (the
    stock grown by the radius); ``allowance``: stock left on the part; ``clear_z``: the links' height;
    ``lead_gap``: the height above a floor where descents slow to the plunge feed; ``tan_ramp``: the slope
    of a helix entry (the roughing's ramp angle); ``helix_radius``/``min_helix_radius``: the radius of the
    circle a helix entry's centre follows, as large as the pocket allows up to the first, at least the second
    (None: 0.4 D and 0.15 D, the roughing's defaults); ``block``: ``stock`` is the setup's whole block, air
    all round it at any depth of the band, so a deep cut's runs may link round it (False: a rest's material,
    the part may lie beside it); ``air_feed``: the feed moves in the air run at [mm/min] (None: the rapid rate), so a
    link round the stock stays down where that beats the lift by the clock."""

    levels: tuple[float, ...]
    spaces: tuple[BaseGeometry, ...]
    top: float
    stock: Polygon
    axis_box: Polygon
    allowance: float
    clear_z: float
    lead_gap: float
    tan_ramp: float = math.tan(math.radians(3.0))
    helix_radius: float | None = None
    min_helix_radius: float | None = None
    block: bool = False
    air_feed: float | None = None


def plan_deep_cuts(g: BandGeometry, tool: Tool, cutting: CuttingData, max_feed: float,
                   levels_length: Callable[[Polygon], float], options: AdaptiveOptions = AdaptiveOptions()
                   ) -> DeepPlan:
    """The regions to take deep, and their moves (module docstring).

    ``levels_length(region)``: the feed length [mm] the z-level strategy spends on ``region`` at one level,
    for the time comparison (at the tool's feed, against the deep cut's at its thinned feed)."""
    n = len(g.levels)
    max_depth = min(options.axial_depth * tool.diameter, float(tool.flute_length))
    comps = [[c for c in roughing._polygons(s) if c.area > _SLIVER] for s in g.spaces]
    deep: list[list[Polygon]] = [[] for _ in range(n)]  # per level: regions taken deep
    shallow: list[list[Polygon]] = [[] for _ in range(n)]  # per level: regions left to the levels
    cuts: list[DeepCut] = []
    claimed: list[set[int]] = [set() for _ in range(n)]  # indices of comps already part of a deep band
    for i in range(n - 1, -1, -1):
        for ci, c in enumerate(comps[i]):
            if ci in claimed[i]:
                continue
            cut = _band_cut(g, i, c, comps, claimed, shallow, tool, cutting, max_feed, levels_length, max_depth,
                            options)
            if cut is None:
                shallow[i].append(c)
                continue
            cuts.append(cut)
            for li in cut.levels:
                deep[li].append(cut.region)
    cuts.sort(key=lambda c: (-c.z_top, -c.z))
    # a little wider than the regions' own tolerance: no sliver of a deep region is left to the levels
    taken = tuple(shapely.union_all([r.buffer(2 * _SAME, quad_segs=4) for r in deep[li]]) if deep[li] else None
                  for li in range(n))
    return DeepPlan(cuts=tuple(cuts), taken=taken)


def _band_cut(g: BandGeometry, i: int, c: Polygon, comps: list[list[Polygon]], claimed: list[set[int]],
              shallow: list[list[Polygon]], tool: Tool, cutting: CuttingData,
              max_feed: float, levels_length: Callable[[Polygon], float], max_depth: float,
              options: AdaptiveOptions) -> DeepCut | None:
    """The deep cut of region ``c`` of level ``i`` up through the levels above where the region stays the same,
    or None where it does not pay or is not safe. A region with no air beside it (a closed pocket) finds no
    lead-in (:func:`deep_cut_moves`) and stays with the levels. Marks the levels it takes in ``claimed``."""
    # Everything under it that it overlaps must be deep as well: the z-level pass comes first and must
    # never cut below stock a deep cut has still to take.
    below = i + 1
    if below < len(g.levels):
        grown = c.buffer(tool.radius)
        if any(s.intersects(grown) for s in shallow[below]):
            return None
    z = g.levels[i]
    top_index = i
    for k in range(i - 1, -1, -1):
        above = g.levels[k - 1] if k > 0 else g.top
        if above - z > max_depth + 1e-9 or _same_region(c, comps[k]) is None:
            break
        top_index = k
    # the band's top: the floor of the level above it (the stock top above the first)
    z_top = g.levels[top_index - 1] if top_index > 0 else g.top
    if z_top - z > max_depth + 1e-9:
        return None
    levels = tuple(range(top_index, i + 1))
    levels_min = len(levels) * levels_length(c) / cutting.feed
    moves = deep_cut_moves(c, g, z, z_top, tool, options)
    if moves is None:
        # no lead-in from the air beside the walls (a pocket, a slot, a neck): fronts from a helix or the air,
        # tried only where they can pay (their feed length is at least the stock's area over the step)
        target = chip_thinned_feed(cutting, tool, options.target(tool), max_feed).feed
        moves = front_cut_moves(c, g, z, z_top, tool, options, budget=levels_min * target,
                                rapid_share=target / _RAPID_ESTIMATE)
    if moves is None:
        return None
    points, motion, engagement, length = moves
    if engine_minutes(moves, tool, cutting, max_feed) >= levels_min:
        return None
    for k in levels:
        if k != i:
            claimed[k].add(next(j for j, q in enumerate(comps[k]) if q.intersects(c)))
    return DeepCut(region=c, z_top=z_top, z=z, levels=levels, points=points, motion=motion,
                   engagement=engagement, length=length)


def _same_region(c: Polygon, level_comps: list[Polygon]) -> Polygon | None:
    """The region of a level above that is ``c`` again (at most :data:`_SAME` wider), else None."""
    hits = [q for q in level_comps if q.intersects(c)]
    if len(hits) != 1:
        return None
    q = hits[0]
    if q.difference(c.buffer(_SAME, quad_segs=4)).area > _SLIVER:
        return None
    return q


def engine_minutes(moves: tuple[np.ndarray, np.ndarray, float, float], tool: Tool, cutting: CuttingData,
                   max_feed: float) -> float:
    """Minutes the engine's ``moves`` (``deep_cut_moves``/``front_cut_moves``' points, motion, engagement [mm]
    and feed length [mm]) take: cuts at the chip-thinned feed, plunges at the plunge feed, rapids at
    :data:`_RAPID_ESTIMATE` [mm/min]. The engine is kept only where this beats the levels it would replace."""
    points, motion, engagement, length = moves
    feed = chip_thinned_feed(cutting, tool, engagement, max_feed).feed
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    rapid = float(seg[motion[1:] == Motion.RAPID].sum())
    plunge = float(seg[motion[1:] == Motion.PLUNGE].sum())
    return (length - plunge) / feed + plunge / cutting.plunge_feed + rapid / _RAPID_ESTIMATE


# --------------------------------------------------------------------------- one deep cut


def deep_cut_moves(region: Polygon, g: BandGeometry, z: float, z_top: float, tool: Tool,
                   options: AdaptiveOptions = AdaptiveOptions()
                   ) -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """The moves taking ``region`` from ``z_top`` down to ``z`` by wall offsets, outermost first.

    Pass ``j`` follows the walls at ``j`` steps. Pass 0 (along the walls) is cut wherever it meets stock;
    an outer pass only beside the places where the pass inside it would meet more than the target
    engagement plus half the band (the stock's corners beyond a rounded part corner, a margin wider than a
    step), each run of it from the air to the air. Returns (points (n, 3) tool tip [mm], motion (n,) int8,
    largest measured radial engagement [mm], feed length [mm]), or None where the region has no wall, needs
    more than :data:`_MAX_PASSES` passes, a lead-in would cross the part, or the replay measures more than
    the band allows. Each run starts at ``g.clear_z`` over its descent and ends back there."""
    r = tool.radius
    step = options.target(tool)
    limit = options.ceiling(tool)
    planned = min((options.share(tool) + 0.5 * options.band) * tool.diameter, limit)
    walls = g.axis_box.difference(region)  # the part grown by the tool and the allowance, within the box
    if walls.is_empty or walls.area < _SLIVER:
        return None  # no wall: a face, the z-level strategy's
    # the band's stock beside this region: the part grown by the allowance is the walls less the radius
    material = g.stock.intersection(region.buffer(r, quad_segs=16)).difference(walls.buffer(-r, quad_segs=16))
    if material.area < _SLIVER:
        return None
    # beyond ``reach`` the tool is in the air; passes may run out there, past the box the levels keep to
    reach = g.stock.buffer(r + _AIR_GAP, join_style="mitre").difference(walls.buffer(-1e-6))
    passes: list[list[tuple[np.ndarray, np.ndarray]]] = []  # per pass: (chain (n, 2), kept (n,) bool)
    wanted: np.ndarray | None = None  # the inner pass's overloaded points
    for j in range(_MAX_PASSES + 1):
        edge = (walls.buffer(j * step, quad_segs=16) if j else walls).boundary
        lines = _lines(edge.intersection(reach))
        chains = [_oriented(q, walls) for q in lines]
        ring = []
        for chain in chains:
            kept = np.ones(len(chain), bool) if wanted is None else _near(chain, wanted, 1.5 * step)
            ring.append((chain, kept))
        passes.append(ring)
        over = [chain[kept & (_penetration(chain, material, r) > planned)] for chain, kept in ring]
        over = [q for q in over if len(q)]
        if not over:
            break
        wanted = np.vstack(over)
    else:
        log.debug("deep cut at z=%.3f: more than %d passes", z, _MAX_PASSES)
        return None
    left = material
    pts: list[np.ndarray] = []
    mot: list[int] = []
    beta = max(math.radians(0.5), 0.5 * (math.acos(1 - min(limit, tool.diameter) / r)
                                         - math.acos(1 - min(step, tool.diameter) / r)))
    inside = walls.buffer(-1e-4)
    # a tool centre on or outside it is in the air (round a rest's material, the part may be)
    air_box = g.stock.buffer(r + _AIR_GAP, join_style="mitre") if g.block else None
    for ring in passes[::-1]:
        for chain, kept in ring:
            routes = _runs(chain, kept, left, r, beta)
            if routes is None:
                log.debug("deep cut at z=%.3f: no lead-in from the air", z)
                return None
            for route in _nearest_first(routes, pts):
                # the chains are sampled finely to judge them; the moves need only their corners
                route = shapely.get_coordinates(LineString(route).simplify(_SIMPLIFY, preserve_topology=False))
                if inside.intersects(LineString(route)):
                    log.debug("deep cut at z=%.3f: a lead-in crosses the part", z)
                    return None
                _emit(pts, mot, route, z, g, _stays_down(pts, route, left, inside, r, around=air_box,
                                                         rise=2 * (g.clear_z - z), air_feed=g.air_feed))
                left = left.difference(LineString(route).buffer(r, quad_segs=16))
    if not pts:
        return None
    points = np.array(pts)
    motion = np.array(mot, dtype=np.int8)
    engagement = measure_engagement(points, motion, z, material, g.stock, r)
    if engagement > limit + 1e-6:
        log.debug("deep cut at z=%.3f: engagement %.3f mm over %.3f", z, engagement, limit)
        return None
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    length = float(seg[motion[1:] != Motion.RAPID].sum())
    return points, motion, engagement, length


# --------------------------------------------------------------------------- fronts: pockets, slots, necks


def front_cut_moves(region: Polygon, g: BandGeometry, z: float, z_top: float, tool: Tool,
                    options: AdaptiveOptions = AdaptiveOptions(), budget: float = math.inf, rapid_share: float = 0.0
                    ) -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """The moves taking ``region`` from ``z_top`` down to ``z`` by fronts growing out of what is cleared.

    Where the walls' offsets find no lead-in from the air (a closed pocket, a slot, a neck between islands, a
    pocket open on one side only), the cut starts from the air the region holds (the tool-centre places
    whose disc meets no stock) or, with none, from a helix at the roughing's ramp angle down the whole band
    at the place farthest from the walls (its radius as :attr:`BandGeometry.helix_radius` allows, at least
    :attr:`BandGeometry.min_helix_radius`), followed by one lap at the floor (and so again beyond a neck the
    fronts cannot pass). Each next front is the
    cleared tool-centre region closed by the radius (its inside corners rounded, where an offset would bury
    the tool), grown by a step, within the region: the step is the target engagement, smaller where the
    front's engagement, read along its leading half, would pass the target plus half the band (tight turns,
    the first laps round the helix). Only the stretches of a front that meet stock are cut, climb, each
    led in sideways from the cleared side (in a slot, the front's two ends: trochoidal arcs); links stay down.

    Returns as :func:`deep_cut_moves` (the engagement measured with the helix's bore taken as cleared: the
    helix itself is the one place the band does not hold), or None where no helix fits, a step below
    :data:`_MIN_STEP_SHARE` of the target would still pass the band, a lead-in crosses the part, the cut
    needs more than :data:`_MAX_FRONTS` fronts or more than ``budget`` [mm] of feed (rapids counted at
    ``rapid_share`` of their length: the feed over the rapid rate), or the replay measures more than the band
    allows."""
    r = tool.radius
    step = options.target(tool)
    limit = options.ceiling(tool)
    planned = min((options.share(tool) + 0.5 * options.band) * tool.diameter, limit)
    walls = g.axis_box.difference(region)
    material = g.stock.intersection(region.buffer(r, quad_segs=16)).difference(walls.buffer(-r, quad_segs=16))
    if material.area < _SLIVER or material.area / step > budget:
        return None
    inside = walls.buffer(-1e-4)
    left = material
    pts: list[np.ndarray] = []
    mot: list[int] = []
    # a pocket open on a side grows from the air there: the region, with a strip past the box the levels keep
    # to (where the tool's disc clears the stock by the air gap), beside it
    strip = g.stock.buffer(r + 2 * _AIR_GAP, join_style="mitre").difference(walls).intersection(
        region.buffer(2 * _AIR_GAP, quad_segs=4))
    region = region.union(strip)
    air = region.difference(material.buffer(r + _AIR_GAP, quad_segs=16))
    bore: BaseGeometry = Polygon()
    cleared: BaseGeometry = air if air.area > _SLIVER else Polygon()

    def enter(space: Polygon) -> bool:
        """A helix in ``space``, where it fits: its moves emitted, its bore cleared."""
        nonlocal cleared, bore, left
        helix = _helix(space, g, z, z_top, tool)
        if helix is None:
            return False
        centre, radius, h_points, h_motion = helix
        pts.extend(h_points)
        mot.extend(int(m) for m in h_motion)
        cleared = cleared.union(shapely.Point(*centre).buffer(radius, quad_segs=32))
        hole = shapely.Point(*centre).buffer(radius + r, quad_segs=32)
        bore = bore.union(hole)
        left = left.difference(hole)
        return True

    if cleared.is_empty and not enter(region):
        return None
    beta = max(math.radians(0.5), 0.5 * (math.acos(1 - min(limit, tool.diameter) / r)
                                         - math.acos(1 - min(step, tool.diameter) / r)))
    cost, counted = 0.0, 0  # feed length so far [mm], rapids at their share; points counted
    creeping = 0  # fronts in a row that gained less than a quarter step squared
    for _ in range(_MAX_FRONTS):
        if left.area < _SLIVER:
            break
        last = region.difference(cleared).area < _SLIVER  # the front is the walls: this lap is the last
        # the front's reading is a little short of the replay's at tight turns: the strictest that a step holds
        front = _next_front(cleared, region, left, r, step,
                            tuple(step + share * options.band * tool.diameter for share in _FRONT_READINGS))
        if front is None:
            log.debug("deep cut at z=%.3f: no front holds the band", z)
            return None
        creeping = creeping + 1 if front[1] and front[0].area - cleared.area < 0.25 * step * step else 0
        if not front[1] or creeping > _CREEP:
            # the front reaches no farther: what is left lies in corners sharper than its rounding, or beyond a
            # neck narrower than it, which gets a helix of its own; fronts that only creep into a cusp stop too
            creeping = 0
            rest = sorted((q for q in roughing._polygons(region.difference(cleared))
                           if q.area > step * step), key=lambda q: -q.area)
            if not any(enter(q) for q in rest):
                break
            continue
        cleared, chains = front
        for chain in chains:
            routes = _runs(chain, np.ones(len(chain), bool), left, r, beta, gap=_FRONT_GAP)
            if routes is None:
                log.debug("deep cut at z=%.3f: a front finds no lead-in", z)
                return None
            for route in routes:
                route = shapely.get_coordinates(LineString(route).simplify(_SIMPLIFY, preserve_topology=False))
                line = LineString(route)
                if inside.intersects(line):
                    log.debug("deep cut at z=%.3f: a lead-in crosses the part", z)
                    return None
                _emit(pts, mot, route, z, g, _stays_down(pts, route, left, inside, r, gap=-_FRONT_GAP))
                left = left.difference(line.buffer(r, quad_segs=16))
        cost += _feed_cost(pts[max(counted - 1, 0):], mot[max(counted, 1):], rapid_share)
        counted = len(pts)
        if cost > budget:
            log.debug("deep cut at z=%.3f: fronts slower than the levels", z)
            return None
        if last:
            break
    else:
        log.debug("deep cut at z=%.3f: more than %d fronts", z, _MAX_FRONTS)
        return None
    if not pts:
        return None
    points, motion = np.array(pts).reshape(-1, 3), np.array(mot, dtype=np.int8)
    engagement = measure_engagement(points, motion, z, material.difference(bore), g.stock, r)
    # within two raster cells of the band: the raster reads a front's tight turns up to that much deep
    if engagement > limit + 2 * _CELL_SHARE * r:
        log.debug("deep cut at z=%.3f: engagement %.3f mm over %.3f", z, engagement, limit)
        return None
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return points, motion, engagement, float(seg[motion[1:] != Motion.RAPID].sum())


def _feed_cost(pts: list[np.ndarray], mot: list[int], rapid_share: float) -> float:
    """Feed length [mm] of the moves from ``pts[0]`` on (``mot``: the motion of each move), rapids counted at
    ``rapid_share`` of their length."""
    if len(pts) < 2:
        return 0.0
    seg = np.linalg.norm(np.diff(np.array(pts), axis=0), axis=1)
    rapid = np.array(mot[-len(seg):]) == Motion.RAPID
    return float(seg[~rapid].sum() + rapid_share * seg[rapid].sum())


def _helix(region: Polygon, g: BandGeometry, z: float, z_top: float, tool: Tool
           ) -> tuple[np.ndarray, float, np.ndarray, np.ndarray] | None:
    """The helix entry of a pocket with no air: its centre (2,), radius [mm], points (n, 3) and motion (n,) (rapid over its start at
    ``g.clear_z``, rapid down to :data:`_AIR_GAP` over ``z_top`` (cleared by the levels above), the helix turning
    clockwise (climb) at ``g.tan_ramp`` down to ``z``, one lap at ``z``, the lift back to ``g.clear_z``); None
    where the widest circle in the region is smaller than the least helix."""
    r = tool.radius
    centre = shapely.get_coordinates(shapely.maximum_inscribed_circle(region, 1e-3))[0]
    room = float(region.exterior.distance(shapely.Point(*centre)))
    if region.interiors:
        room = min(room, min(float(shapely.LinearRing(q).distance(shapely.Point(*centre))) for q in region.interiors))
    most = 0.4 * tool.diameter if g.helix_radius is None else g.helix_radius
    least = 0.15 * tool.diameter if g.min_helix_radius is None else g.min_helix_radius
    radius = min(most, room - 1e-3)
    if radius < least:
        return None
    z0 = min(z_top + _AIR_GAP, g.clear_z)
    turn = radius * g.tan_ramp  # descent per radian [mm]
    span = (z0 - z) / turn
    n = max(2, int(math.ceil(math.degrees(span) / _HELIX_STEP_DEG)))
    theta = -np.linspace(0.0, span, n + 1)  # clockwise
    lap = -span - np.linspace(0.0, 2 * math.pi, 73)[1:]
    ring = np.column_stack([centre[0] + radius * np.cos(theta), centre[1] + radius * np.sin(theta),
                            z0 - turn * np.linspace(0.0, span, n + 1)])
    ring[-1, 2] = z
    flat = np.column_stack([centre[0] + radius * np.cos(lap), centre[1] + radius * np.sin(lap), np.full(len(lap), z)])
    points = np.vstack([[[ring[0, 0], ring[0, 1], g.clear_z]], ring, flat, [[flat[-1, 0], flat[-1, 1], g.clear_z]]])
    motion = np.array([Motion.RAPID, Motion.RAPID, *[Motion.PLUNGE] * (len(ring) - 1), *[Motion.CUT] * len(flat),
                       Motion.RAPID], dtype=np.int8)
    return centre, radius, points, motion


def _next_front(cleared: BaseGeometry, region: Polygon, left: BaseGeometry, r: float, step: float,
                limits: tuple[float, ...]) -> tuple[BaseGeometry, list[np.ndarray]] | None:
    """The next front from the ``cleared`` tool-centre region: closed by ``r`` (its inside corners rounded),
    grown by a step from ``step`` down (by 0.7 each time, to :data:`_MIN_STEP_SHARE` of it), its convex
    corners rounded (:data:`_FRONT_ROUNDING`), within ``region``: the first whose reading (:func:`_reading`)
    against the stock ``left`` is within ``limits[0]`` [mm], else within the next limit, and so on. Returns
    the new cleared region and its rings (:func:`_front_chains`); ``(cleared, [])`` where no step advances
    it and the walls' lap does not hold either; None where steps advance but none holds."""
    base = cleared.buffer(r, quad_segs=16).buffer(-r, quad_segs=16)
    shapely.prepare(left)
    tried: list[tuple[float, BaseGeometry, list[np.ndarray]]] = []
    s = step
    while s >= _MIN_STEP_SHARE * step:
        raw = base.buffer(s, quad_segs=16).intersection(region)
        for rounding in _FRONT_ROUNDING:
            # the front's convex corners rounded (where it meets the walls): the tool turns onto the front's
            # end gradually instead of ploughing along the wall into it
            grown = raw.buffer(-rounding * r, quad_segs=16).buffer(rounding * r, quad_segs=16)
            grown = grown.intersection(region).union(cleared)
            if grown.area - cleared.area < _SLIVER:
                continue  # a channel narrower than the rounding: less rounding
            chains = _front_chains(grown)
            reading = _reading(chains, left, r, limits[-1])
            if reading <= limits[0]:
                return grown, chains
            tried.append((reading, grown, chains))
        s *= 0.7
    for limit in limits[1:]:
        for reading, grown, chains in tried:
            if reading <= limit:
                return grown, chains
    if tried:
        return None
    # the rounded fronts reach no farther: the last lap follows the walls into the corners and the cusps beside
    # the islands, where that holds the band; else the corners keep their stock
    grown = region.union(cleared)
    if grown.area - cleared.area >= _SLIVER:
        chains = _front_chains(grown)
        if _reading(chains, left, r, limits[-1]) <= limits[-1]:
            return grown, chains
    return cleared, []


def _reading(chains: list[np.ndarray], left: BaseGeometry, r: float, most: float) -> float:
    """How deep [mm] the fronts ``chains`` take the tool into the stock ``left``: the larger of the disc's
    deepest reach into it (a front that would bury the tool where its leading half reads little: the start of
    a run) and the leading half's engagement (:func:`_front_engagement`, read only where the reach is within
    ``most``); inf with no chains."""
    if not chains:
        return math.inf
    reach = max(float(_penetration(c, left, r).max()) for c in chains)
    if reach > most:
        return reach
    return max(reach, max(_front_engagement(c, left, r) for c in chains))


def _front_chains(front: BaseGeometry) -> list[np.ndarray]:
    """The rings of ``front`` as chains (n, 2) at most :data:`_RESAMPLE` apart, oriented for climb: the stock
    outside on the left (the outer rings clockwise, the holes' counter-clockwise)."""
    chains = []
    for poly in roughing._polygons(front):
        poly = orient(poly, sign=-1.0)
        for ring in (poly.exterior, *poly.interiors):
            c = shapely.get_coordinates(shapely.segmentize(ring, _RESAMPLE))
            keep = np.ones(len(c), bool)
            keep[1:] = np.linalg.norm(np.diff(c, axis=0), axis=1) > 1e-9
            if keep.sum() > 3:
                chains.append(c[keep])
    return chains


def _front_engagement(chain: np.ndarray, left: BaseGeometry, r: float) -> float:
    """Largest radial engagement [mm] along ``chain`` (n, 2) into the stock ``left`` (prepared): at each point,
    the share of the cutter's leading half (travel to the next point) in the stock, as the side cut making that
    angle, ``R (1 - cos angle)``. Only what the front meets before it is cut: a front turning back on itself
    reads a little more than it will cut (the replay, :func:`measure_engagement`, is the judge)."""
    u = np.diff(chain, axis=0)
    u /= np.linalg.norm(u, axis=1)[:, None]
    normal = np.column_stack([-u[:, 1], u[:, 0]])
    psi = (np.arange(_FRONT_ARC) + 0.5) * math.pi / _FRONT_ARC
    rr = r * (1 - 1e-3)
    arc = rr * (np.cos(psi)[None, :, None] * normal[:, None, :] + np.sin(psi)[None, :, None] * u[:, None, :])
    q = chain[:-1, None, :] + arc
    hits = shapely.contains_xy(left, q[..., 0].ravel(), q[..., 1].ravel()).reshape(len(u), _FRONT_ARC)
    angle = math.pi * hits.mean(axis=1)
    return float((r - r * np.cos(angle)).max()) if len(angle) else 0.0


def _lines(geom: BaseGeometry) -> list[LineString]:
    if geom.is_empty:
        return []
    if isinstance(geom, LineString):
        return [geom]
    parts = [q for q in getattr(geom, "geoms", []) if isinstance(q, LineString) and not q.is_empty]
    if not parts:
        return []
    merged = linemerge(MultiLineString(parts))
    out = [merged] if isinstance(merged, LineString) else list(merged.geoms)
    return [q for q in out if q.length > 1e-3]


def _oriented(line: LineString, walls: BaseGeometry) -> np.ndarray:
    """The chain's points (n, 2), at most :data:`_RESAMPLE` apart, ordered so the wall (the uncut stock beside
    it) is on the left: climb milling."""
    c = shapely.get_coordinates(shapely.segmentize(line, _RESAMPLE))
    keep = np.ones(len(c), bool)
    keep[1:] = np.linalg.norm(np.diff(c, axis=0), axis=1) > 1e-9
    c = c[keep]
    k = int(np.argmax(np.linalg.norm(np.diff(c, axis=0), axis=1)))
    mid = 0.5 * (c[k] + c[k + 1])
    t = (c[k + 1] - c[k]) / np.linalg.norm(c[k + 1] - c[k])
    left = np.array([-t[1], t[0]])
    eps = 1e-3
    if walls.distance(shapely.Point(*(mid + eps * left))) > walls.distance(shapely.Point(*(mid - eps * left))):
        c = c[::-1].copy()
    return c


def _emit(pts: list[np.ndarray], mot: list[int], route: np.ndarray, z: float, g: BandGeometry,
          link: np.ndarray | None = None) -> None:
    """One run at ``z``: fed on from where the last one ended through the corners ``link`` (k, 2) [mm] (none: straight
    on), or with ``link`` None from a rapid over its start down in the air; it ends back up at ``g.clear_z`` (taken
    back off when the next run links on)."""
    if link is not None:
        pts.pop()  # stay down: the last run's lift
        mot.pop()
        for q in (*link, route[0]):
            pts.append(np.array([*q, z]))
            mot.append(int(Motion.CUT))
    else:
        pts.append(np.array([*route[0], g.clear_z]))
        mot.append(int(Motion.RAPID))
        air = z + g.lead_gap
        if air < g.clear_z:
            pts.append(np.array([*route[0], air]))
            mot.append(int(Motion.RAPID))
        pts.append(np.array([*route[0], z]))
        mot.append(int(Motion.PLUNGE))
    for q in route[1:]:
        pts.append(np.array([*q, z]))
        mot.append(int(Motion.CUT))
    pts.append(np.array([*route[-1], g.clear_z]))
    mot.append(int(Motion.RAPID))


def _stays_down(pts: list[np.ndarray], route: np.ndarray, left: BaseGeometry, inside: BaseGeometry,
                r: float, gap: float = _AIR_GAP, around: Polygon | None = None, rise: float = 0.0,
                air_feed: float | None = None) -> np.ndarray | None:
    """How the tool, down at the end of the last run, feeds to ``route``'s start: straight (no corners, (0, 2)),
    a short link whose disc meets none of the stock ``left`` (with ``gap`` [mm] to spare) and that keeps off
    the part; else round ``around`` (:func:`cadcam.levelpath.round_the_box`), fed at ``air_feed`` [mm/min] no slower than the
    lift's way at the rapid rate (the link and ``rise`` [mm], up to the clearance and down again; None: no longer
    than it); else None (the tool lifts)."""
    if len(pts) < 2:
        return None
    here = pts[-2][:2]  # the last run's end, before its lift
    if np.linalg.norm(route[0] - here) <= 1e-9:
        return np.empty((0, 2))
    link = LineString([here, route[0]])
    if link.length <= _LINK_MAX and not inside.intersects(link) and (left.is_empty or link.distance(left) >= r + gap):
        return np.empty((0, 2))
    way = None if around is None else round_the_box(here, route[0], around, down_budget(link.length + rise, air_feed))
    if way is None or not len(way):
        return None
    # each end goes straight to the outline and the disc meets no stock on the way but what it meets at the end
    # itself (the last run ends just beside the stock it cut; the next one's lead-in starts in the air)
    ends = [LineString([here, way[0]]), LineString([way[-1], route[0]])]
    swept = shapely.union_all([e.buffer(r, quad_segs=16).difference(Point(q).buffer(r, quad_segs=16))
                               for e, q in zip(ends, (here, route[0]))])
    return way if not inside.intersects(MultiLineString(ends)) and swept.intersection(left).area < _SLIVER else None


def _nearest_first(routes: list[np.ndarray], pts: list[np.ndarray]) -> list[np.ndarray]:
    """The runs ``routes`` ((m, 2) each, led in from the air and out to it) of one chain in a nearest-neighbour
    tour from where the moves ``pts`` left the tool (the last run's end, before its lift); each run keeps its
    direction (the climb's). The runs of a chain are apart and the whole deep cut is replayed for its engagement
    after, so only the rapids between them change (bracket: the pass beside its corners began at the far side
    from where the corners' pass ended, 117 mm away, and crossed the part three times more)."""
    if len(routes) < 2 or len(pts) < 2:
        return routes
    order = nearest_tour([route[0] for route in routes], pts[-2][:2], [route[-1] for route in routes])
    return [routes[i] for i in order]


def _near(chain: np.ndarray, points: np.ndarray, distance: float) -> np.ndarray:
    """(n,) bool: the chain's points within ``distance`` [mm] of any of ``points`` (m, 2)."""
    d, _ = cKDTree(points).query(chain, distance_upper_bound=distance)
    return np.isfinite(d)


def _penetration(xy: np.ndarray, material: BaseGeometry, r: float) -> np.ndarray:
    """(n,) how far the tool's disc at each point reaches into ``material`` [mm]: ``r - distance`` outside it,
    more than ``r`` inside; <= 0 where the disc is clear of it."""
    pts = shapely.points(xy)
    if material.is_empty:
        return np.full(len(xy), -np.inf)
    out = r - shapely.distance(pts, material)
    inside = shapely.contains(material, pts)
    if inside.any():
        out[inside] = r + shapely.distance(pts[inside], material.boundary)
    return out


def _runs(chain: np.ndarray, kept: np.ndarray, left: BaseGeometry, r: float, beta: float,
          gap: float = _AIR_GAP) -> list[np.ndarray] | None:
    """The stretches of a pass to cut: where it is kept and meets the stock ``left``; each starting in the air or
    led in from it (:func:`_lead_in`, clear of the stock by ``gap`` [mm]); a closed chain that meets stock all
    round as one lap. (n, 2) point routes; None where a lead-in finds no air."""
    pen = _penetration(chain, left, r)
    cutting = kept & (pen > 0)
    if not cutting.any():
        return []
    closed = len(chain) > 3 and np.linalg.norm(chain[0] - chain[-1]) < 1e-6
    if closed:
        ring = chain[:-1]
        if cutting[:-1].all():
            k = int(np.argmin(pen[:-1]))  # one lap from the point nearest the air
            lap = np.vstack([ring[k:], ring[:k + 1]])
            lead = _lead_in(np.vstack([ring[k::-1], ring[:k:-1], ring[k:k + 1]]), left, r, beta, gap)
            return None if lead is None else [np.vstack([lead, lap[1:]])]
        k = int(np.flatnonzero(~cutting[:-1])[0])  # walk from a point not cut: no run wraps
        order = np.concatenate([np.arange(k, len(ring)), np.arange(0, k)])
    else:
        order = np.arange(len(chain))
    routes = []
    flags = cutting[order]
    starts = np.flatnonzero(flags & ~np.concatenate([[False], flags[:-1]]))
    for i in starts:
        j = i
        while j + 1 < len(order) and flags[j + 1]:
            j += 1
        idx = order[i:j + 1]
        # back along the chain from the run's start (wrapping round a closed one) for the lead-in
        back = np.concatenate([order[i::-1], order[:i:-1]]) if closed else order[i::-1]
        lead = _lead_in(chain[back], left, r, beta, gap)
        if lead is None:
            return None
        routes.append(np.vstack([lead, chain[idx[1:]]]) if len(idx) > 1 else lead)
    return routes


def _lead_in(back: np.ndarray, left: BaseGeometry, r: float, beta: float,
             gap: float = _AIR_GAP) -> np.ndarray | None:
    """The lead-in onto a run starting at ``back[0]``, ``back`` (n, 2) the chain behind it (nearest first): from
    the air beside the stock ``left``, the chain shifted to its right (away from the wall), the shift shrinking
    linearly to nothing (slant ``beta`` [rad]), its first point ``gap`` [mm] clear of it; just the start where
    it is that clear. (m, 2) points ending at
    the start; None where the chain behind is too short to reach the air."""
    start = back[0]
    depth = float(_penetration(start[None], left, r)[0])
    if depth <= -gap:
        return back[:1].copy()
    seg = np.linalg.norm(np.diff(back, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    if cum[-1] < 1e-9:
        return None
    # shift far enough to clear the deepest stock along the way (a lead-in passing a corner's)
    need = depth + 2 * gap
    for _ in range(4):
        length = need / math.tan(beta)
        span = min(length, float(cum[-1]))
        s = np.unique(np.concatenate([cum[cum < span], np.linspace(0, span, max(2, int(span / _RESAMPLE) + 1))]))
        base = np.column_stack([np.interp(s, cum, back[:, 0]), np.interp(s, cum, back[:, 1])])
        deepest = max(depth, float(_penetration(base, left, r).max()))
        if deepest + 2 * gap <= need + 1e-6:
            break
        need = deepest + 2 * gap
    idx = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    # travel runs from back[k + 1] to back[k]: its right-hand side, away from the wall
    travel = (back[idx] - back[idx + 1]) / np.maximum(seg[idx], 1e-12)[:, None]
    right = np.column_stack([travel[:, 1], -travel[:, 0]])
    shifted = base + (need * s / length)[:, None] * right
    if _penetration(shifted[-1:], left, r)[0] > -0.5 * gap:
        return None
    return shifted[::-1].copy()


# --------------------------------------------------------------------------- engagement replay


def measure_engagement(points: np.ndarray, motion: np.ndarray, z: float, material: BaseGeometry,
                       stock: Polygon, r: float) -> float:
    """Largest radial engagement [mm] of the moves at depth ``z`` through ``material`` (:func:`engagement_profile`)."""
    profile = engagement_profile(points, motion, z, material, stock, r)
    return float(profile[:, 2].max()) if len(profile) else 0.0


def engagement_profile(points: np.ndarray, motion: np.ndarray, z: float, material: BaseGeometry,
                       stock: Polygon, r: float) -> np.ndarray:
    """Radial engagement [mm] at every sample of the moves at depth ``z`` through ``material`` (XY, [mm]):
    (m, 3) float rows ``x, y, ae``.

    The material is rasterised; along every feed move at ``z`` the tool's disc clears it, a sample's
    engagement read against what the positions more than half a radius back left (the cutter meets what
    its leading edge reaches, not the sliver of its last revolution). The engagement angle is the arc of the
    cutter's leading half in contact with material; the radial engagement reported is the side cut's that
    makes that angle, ``R (1 - cos angle)`` (a slot: D)."""
    cell = _CELL_SHARE * r
    x0, y0, x1, y1 = stock.buffer(r + 2 * cell).bounds
    nx, ny = int(math.ceil((x1 - x0) / cell)), int(math.ceil((y1 - y0) / cell))
    gx = x0 + cell * (np.arange(nx) + 0.5)
    gy = y0 + cell * (np.arange(ny) + 0.5)
    xx, yy = np.meshgrid(gx, gy)
    solid = shapely.contains_xy(material, xx, yy)
    k = int(math.ceil(r / cell)) + 1
    psi = (np.arange(_ARC_SAMPLES) + 0.5) * math.pi / _ARC_SAMPLES
    rr = r - 0.5 * cell
    lag = 0.5 * r

    def clear(p: np.ndarray) -> None:
        i = int(math.floor((p[1] - y0) / cell))
        j = int(math.floor((p[0] - x0) / cell))
        i0, i1, j0, j1 = max(i - k, 0), min(i + k + 1, ny), max(j - k, 0), min(j + k + 1, nx)
        if i0 >= i1 or j0 >= j1:
            return
        cx, cy = xx[i0:i1, j0:j1], yy[i0:i1, j0:j1]
        solid[i0:i1, j0:j1] &= (cx - p[0]) ** 2 + (cy - p[1]) ** 2 > r * r

    def hit(q: np.ndarray) -> np.ndarray:
        i = np.floor((q[:, 1] - y0) / cell).astype(int)
        j = np.floor((q[:, 0] - x0) / cell).astype(int)
        ok = (i >= 0) & (j >= 0) & (i < ny) & (j < nx)
        out = np.zeros(len(q), bool)
        out[ok] = solid[i[ok], j[ok]]
        return out

    rows: list[tuple[float, float, float]] = []
    pending: list[tuple[float, np.ndarray]] = []
    arc = 0.0
    for a, b, m in zip(points[:-1], points[1:], motion[1:]):
        at_depth = abs(a[2] - z) < 1e-9 and abs(b[2] - z) < 1e-9
        if m == Motion.RAPID or not at_depth:
            for _, q in pending:
                clear(q)
            pending.clear()
            continue
        d = float(np.linalg.norm(b[:2] - a[:2]))
        if d < 1e-12:
            continue
        u = (b[:2] - a[:2]) / d
        left = np.array([-u[1], u[0]])
        ring = rr * (np.cos(psi)[:, None] * left + np.sin(psi)[:, None] * u)
        n = max(1, int(math.ceil(d / (_SAMPLE_CELLS * cell))))
        for t in np.linspace(0, 1, n + 1)[1:]:
            p = a[:2] + t * (b[:2] - a[:2])
            arc += d / n
            while pending and arc - pending[0][0] >= lag:
                clear(pending.pop(0)[1])
            # the engagement angle is the arc of the leading half in contact; the radial engagement that
            # makes it on a straight cut is R - rr cos(angle) (exact on the raster's ring of radius rr)
            angle = math.pi * float(np.count_nonzero(hit(p[None] + ring))) / len(psi)
            ae = r - rr * math.cos(angle) if angle > 0 else 0.0
            rows.append((float(p[0]), float(p[1]), ae))
            pending.append((arc, p))
    return np.array(rows, dtype=np.float64).reshape(-1, 3)
