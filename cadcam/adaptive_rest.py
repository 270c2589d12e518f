"""Rest roughing with the adaptive engine (issue 32): a smaller end mill takes a bigger one's leftovers by fronts.

The rest a bigger tool leaves beside vertical walls is a column in every inside corner narrower than its radius,
from the top of the wall down to the floor. Rest roughing by levels (:func:`cadcam.roughing.zlevel_roughing` with
``rest``) takes such a column a level at a time, each level's corner entered by a ramp at the plunge feed. Here the
same column is taken by :mod:`cadcam.adaptive`'s engine instead, in as few bands as the part's flats and the tool's
axial depth allow, at the tool's own held radial engagement and its chip-thinned feed:

* **Bands.** Their floors are the rest tool's levels with a step-down of the engine's axial depth
  (:attr:`cadcam.adaptive.AdaptiveOptions.axial_depth` diameters, never past the flutes): every flat of the part
  still gets its own floor (:func:`cadcam.roughing._levels`), and none lies deeper than the tool reaches
  (:func:`cadcam.rest.levels_within_reach`). They are taken top down.
* **Material.** A band's material is the rest the stock model holds above its floor (more than
  ``rest_above`` over the part grown by the allowance), as the cells' squares grown by a cell diagonal: it holds
  the true edge of what the bigger tool cut, which the grid only samples, so the engagement the engine reads and
  replays is not less than the cut's (the engine keeps its cuts off the part grown by the allowance itself).
  Stock thinner than ``rest_above`` (the skin on the walls) is left to finishing, as the levels leave it.
* **Where.** Each connected piece of the level's tool-centre region within a radius and a tool diameter of the
  material (:data:`_ROOM`): the air round the rest is where the fronts grow from and link in. Rest reaching above
  the band's top that the band above did not take keeps the tool a radius and the air gap away: a band never
  cuts under stock still standing over it.
* **How.** :func:`cadcam.adaptive.deep_cut_moves` (wall offsets, led in from the air) where it holds the band,
  else :func:`cadcam.adaptive.front_cut_moves` (fronts growing out of the air round the rest, links down in
  cleared stock, a helix at the ramp angle where no air is); both replay their moves and refuse a cut that passes
  the tool's band.
* **When.** A piece is taken only where the engine's time (the program timer's model) is less than what rest
  roughing by levels spends there: the time of the levels' own moves in the band within the piece, entries and
  links included, and only where the engine leaves no grid point of rest within its reach, which the levels would
  come back for; it is tried only where the levels spend :data:`_WORTH` or more and its least time (the rest at
  its step and feed, a helix where no air is) is less. What the engine refuses the levels take after it, on the
  stock model that knows what it cut.
  Rest is narrow by its nature (the next tool down is the widest that fits), and there a full-width level at half a
  diameter removes more per minute than a side cut at 15 % of D, whose fronts in a slot advance by tenths of a
  millimetre to hold the band: on the samples the levels win every piece.

:func:`adaptive_rest_roughing` returns the operation, or None where it takes nothing. All lengths in millimetres,
feeds in mm/min.
"""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np
import shapely
import trimesh
from shapely.geometry import LineString, Polygon
from shapely.geometry.base import BaseGeometry

from cadcam import roughing
from cadcam.adaptive import (AdaptiveOptions, BandGeometry, chip_thinned_feed, deep_cut_moves, engine_minutes,
                             front_cut_moves)
from cadcam.gridregion import grown_cells_region
from cadcam.heightmap import Grid
from cadcam.model import CuttingData, Motion, Operation, Setup, Tool
from cadcam.post import operation_move_seconds
from cadcam.rest import levels_within_reach
from cadcam.shadow import part_shadows
from cadcam.stock import Simulation, excess
from factory.core.errors import MeshError

log = logging.getLogger(__name__)

#: Room round the rest, beyond the tool's radius, where the fronts grow from [tool diameters].
_ROOM = 1.0
#: Air between the tool and rest still standing over a band [mm] (as the engine's lead-ins keep from stock).
_AIR_GAP = 0.5
#: Rest smaller than this is a numerical sliver [mm^2].
_SLIVER = 1e-3
#: Rapid rate the time comparison assumes [mm/min] (as :mod:`cadcam.adaptive`'s).
_RAPID_ESTIMATE = 5000.0
#: Least time the levels spend in a piece for the engine to be tried there [min]: below it the most it could save
#: is seconds, and trying costs a planning second or more.
_WORTH = 0.1
#: Material less than this above a level counts as the level itself [mm] (:mod:`cadcam.rest`'s).
_LEVEL_EPS = 1e-3


@dataclasses.dataclass(frozen=True)
class RestCut:
    """One piece of rest taken by the engine: its tool-centre ``region`` [mm] from ``z_top`` down to ``z``, its
    moves (``points`` tool tip [mm], ``motion``), the largest radial engagement measured [mm] and the XY area its
    cutter swept at ``z`` (``swept``)."""

    region: Polygon
    z_top: float
    z: float
    points: np.ndarray
    motion: np.ndarray
    engagement: float
    swept: BaseGeometry


def adaptive_rest_roughing(
    part: trimesh.Trimesh,
    setup: Setup,
    tool: Tool,
    cutting: CuttingData,
    max_feed: float,
    rest: Simulation,
    rest_above: float,
    levels: Operation | None,
    options: roughing.RoughingOptions = roughing.RoughingOptions(),
    adaptive: AdaptiveOptions = AdaptiveOptions(),
) -> Operation | None:
    """The rest ``rest`` holds (more than ``rest_above`` [mm] over the part grown by the allowance) taken by the
    adaptive engine with ``tool``, where that is faster than levels (module docstring).

    ``cutting``: the tool's cutting data; the operation runs at its feed thinned for the largest engagement
    measured, capped at ``max_feed`` [mm/min]. ``levels``: the same rest roughed by levels, whose time in a piece
    the engine must beat (None: every piece the engine holds the band in is taken). ``options``: the rest roughing's (allowance, ramp angle; step-down
    and step-over are the tool's own). Returns ``"rest adaptive T<n>"`` (kind ``roughing``), starting and ending at
    ``setup.safe_z``, or None where no piece pays. Raises as :func:`cadcam.roughing.zlevel_roughing`.
    """
    if part is None or len(part.faces) == 0:
        raise MeshError("part mesh is empty")
    cuts = plan_rest_cuts(part, setup, tool, cutting, max_feed, rest, rest_above, levels, options, adaptive)
    if not cuts:
        return None
    feed = chip_thinned_feed(cutting, tool, max(c.engagement for c in cuts), max_feed)
    first = cuts[0].points[0]
    points = np.vstack([[[first[0], first[1], setup.safe_z]], *[c.points for c in cuts]])
    motion = np.concatenate([[int(Motion.RAPID)], *[c.motion for c in cuts]]).astype(np.int8)
    last = points[-1]
    points = np.vstack([points, [[last[0], last[1], setup.safe_z]]])
    motion = np.append(motion, np.int8(Motion.RAPID))
    return Operation(name=f"rest adaptive T{tool.number}", kind="roughing", tool=tool, cutting=feed, points=points,
                     motion=motion, allowance=options.allowance)


def plan_rest_cuts(part: trimesh.Trimesh, setup: Setup, tool: Tool, cutting: CuttingData, max_feed: float,
                   rest: Simulation, rest_above: float, levels: Operation | None,
                   options: roughing.RoughingOptions = roughing.RoughingOptions(),
                   adaptive: AdaptiveOptions = AdaptiveOptions()) -> list[RestCut]:
    """The pieces of rest the engine takes, band by band top down (:func:`adaptive_rest_roughing`); ``levels`` is
    the same rest roughed by levels (:func:`cadcam.roughing.zlevel_roughing`), whose moves within a piece are the
    time the engine has to beat."""
    p = roughing._resolve(options, tool, setup)
    max_depth = min(adaptive.axial_depth * tool.diameter, float(tool.flute_length))
    top = float(setup.stock_max[2])
    floors = levels_within_reach(roughing._levels(part, setup, dataclasses.replace(p, stepdown=max_depth)), top,
                                 tool.length)
    spent = None if levels is None else _move_minutes(levels)
    # the rest: more than ``rest_above`` over the part grown by the allowance alone (not rest.rest_mask, which grows
    # it a cell diagonal more and so does not see the rest that near the walls: the engine would read its side cuts
    # there too thin)
    over = excess(rest, options.allowance, grid_slack=False) > rest_above
    shadow = None  # the part's shadows at the floors, when a band first needs them
    _, rect = roughing._axis_rect(setup, p, None)
    grid = rest.grid
    grow = grid.cell * math.sqrt(2.0)
    r = tool.radius
    target = chip_thinned_feed(cutting, tool, adaptive.target(tool), max_feed).feed
    cuts: list[RestCut] = []
    z_top = top
    swept: BaseGeometry = Polygon()  # what the band above cut down to its floor
    for z in (float(q) for q in floors):
        if z_top - z > max_depth + 1e-9:  # the first band below a reach cut short
            z_top, swept = z, Polygon()
            continue
        here = (rest.stock_top > z + _LEVEL_EPS) & over
        in_band = None if levels is None else _within(levels.points, None, z, z_top)
        if not here.any() or (in_band is not None and float(spent[in_band].sum()) < _WORTH):
            # no rest, or too little of the levels' time to try the engine on: the band stays the levels'
            z_top, swept = z, Polygon()
            continue
        material = grown_cells_region(here, grid, grow, quad_segs=4)
        # rest standing over the band's top that the band above did not sweep (judged at the cells' centres)
        standing = (rest.stock_top > z_top + _LEVEL_EPS) & over
        if standing.any() and not swept.is_empty:
            jj, ii = np.nonzero(standing)
            taken = shapely.contains_xy(swept, grid.xs[ii], grid.ys[jj])
            standing[jj[taken], ii[taken]] = False
        still = grown_cells_region(standing, grid, grow, quad_segs=4) if standing.any() else Polygon()
        if shadow is None:
            shadow = part_shadows(part, [zq for f in floors for zq, _ in roughing._forbidden_terms(float(f), p)])
        space = roughing._level_space(z, rect, shadow, p)
        zone = space.intersection(grown_cells_region(here, grid, grow + r + _ROOM * tool.diameter, quad_segs=4))
        if not still.is_empty:
            zone = zone.difference(still.buffer(r + _AIR_GAP, quad_segs=8))
        g = BandGeometry(levels=(z,), spaces=(zone,), top=z_top, stock=material, axis_box=rect,
                         allowance=p.allowance, clear_z=p.clear_z, lead_gap=p.lead_gap, tan_ramp=p.tan_ramp,
                         helix_radius=p.helix_radius, min_helix_radius=p.min_helix_radius)
        band: list[BaseGeometry] = []
        for region in roughing._polygons(zone):
            if region.area < _SLIVER or material.intersection(region.buffer(r, quad_segs=8)).area < _SLIVER:
                continue
            levels_min = math.inf if levels is None else float(spent[_within(levels.points, region, z, z_top)].sum())
            cut = _rest_cut(region, g, z, z_top, tool, cutting, max_feed, adaptive, target, levels_min, here, grid)
            if cut is not None:
                cuts.append(cut)
                band.append(cut.swept)
        z_top, swept = z, shapely.union_all(band) if band else Polygon()
    return cuts


def _within(points: np.ndarray, region: Polygon | None, z: float, z_top: float) -> np.ndarray:
    """(n - 1,) bool: the moves between ``points`` (n, 3) [mm] that lie in the band from ``z_top`` down to ``z`` and
    start and end in ``region`` (None: anywhere)."""
    zs = points[:, 2]
    low = (zs < z_top - 1e-9) & (zs > z - 1e-9)
    if region is not None:
        low &= shapely.contains_xy(region.buffer(1e-3), points[:, 0], points[:, 1])
    return low[:-1] & low[1:]


def _move_minutes(op: Operation) -> np.ndarray:
    """(n - 1,) the time [min] of each move of ``op`` by the program timer's model
    (:func:`cadcam.post.operation_move_seconds`:
    feed moves at the cutting feed, plunges at the plunge feed, rapids at :data:`_RAPID_ESTIMATE`)."""
    return operation_move_seconds(op, _RAPID_ESTIMATE) / 60.0


def _rest_cut(region: Polygon, g: BandGeometry, z: float, z_top: float, tool: Tool, cutting: CuttingData,
              max_feed: float, adaptive: AdaptiveOptions, target: float, levels_min: float, rest: np.ndarray,
              grid: Grid) -> RestCut | None:
    """The engine's cut of one piece, or None where it refuses it, is no faster than ``levels_min`` [min] (the
    levels' time in the piece), or leaves rest the levels would come back for: a grid point of ``rest`` (the
    band's rest mask over ``grid``) within the tool's reach from the piece that its cutter did not sweep."""
    if levels_min < _WORTH:
        return None
    # the engine's least time already no faster, not tried: the piece's rest at the target step and thinned feed,
    # and where no air is beside it, the helix down the band at the ramp angle and the plunge feed
    material = g.stock.intersection(region.buffer(tool.radius, quad_segs=8))
    least = material.area / (adaptive.target(tool) * target)
    if region.difference(material.buffer(tool.radius + _AIR_GAP, quad_segs=8)).area < _SLIVER:
        least += (z_top - z) / g.tan_ramp / cutting.plunge_feed
    if least >= levels_min:
        return None
    moves = deep_cut_moves(region, g, z, z_top, tool, adaptive)
    if moves is None:
        moves = front_cut_moves(region, g, z, z_top, tool, adaptive, budget=levels_min * target,
                                rapid_share=target / _RAPID_ESTIMATE)
    if moves is None:
        return None
    points, motion, engagement, _ = moves
    minutes = engine_minutes(moves, tool, cutting, max_feed)
    if math.isfinite(levels_min) and minutes >= levels_min:
        log.debug("rest piece at z=%.3f: %.2f min by the engine, %.2f by levels", z, minutes, levels_min)
        return None
    swept = _swept(points, motion, z, tool.radius)
    jj, ii = np.nonzero(rest)
    xs, ys = grid.xs[ii], grid.ys[jj]
    reach = region.buffer(tool.radius - 0.01, quad_segs=8)
    left = shapely.contains_xy(reach, xs, ys) & ~shapely.contains_xy(swept.buffer(1e-3, quad_segs=4), xs, ys)
    if left.any():
        log.debug("rest piece at z=%.3f: the engine leaves %d grid points of rest", z, int(left.sum()))
        return None
    return RestCut(region=region, z_top=z_top, z=z, points=points, motion=motion, engagement=engagement,
                   swept=swept)


def _swept(points: np.ndarray, motion: np.ndarray, z: float, r: float) -> BaseGeometry:
    """The XY area the cutter's disc (radius ``r`` [mm]) swept along the feed moves at ``z``, a hair inside."""
    at = (np.abs(points[:-1, 2] - z) < 1e-9) & (np.abs(points[1:, 2] - z) < 1e-9) & (motion[1:] != Motion.RAPID)
    lines = [LineString([a[:2], b[:2]]) if np.linalg.norm(b[:2] - a[:2]) > 1e-9 else shapely.Point(a[:2])
             for a, b in zip(points[:-1][at], points[1:][at])]
    if not lines:
        return Polygon()
    return shapely.union_all(shapely.buffer(np.array(lines, dtype=object), r - 1e-3, quad_segs=8))
