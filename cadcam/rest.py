"""What earlier operations left to rest machining, and rapids made safe over it.

Both work from the in-process stock model (:func:`cadcam.stock.stock_after`), a heightfield of the
stock top on a grid, and the part's upper envelope on the same grid. Rest material is the stock's
*excess* (:func:`cadcam.stock.excess`): stock above the part grown sideways by the roughing allowance
plus a cell diagonal. What no tool reaches is :func:`cadcam.stock.unreached`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Sequence

import numpy as np
import shapely
from scipy import ndimage
from shapely.geometry.base import BaseGeometry

from cadcam.gridregion import cells_region, grown_cells_region
from cadcam.heightmap import Grid
from cadcam.model import Motion, Operation, Setup, Tool
from cadcam.stock import Simulation, clear_height, cut_stock, excess, operation_moves
from cadcam.verify import rapid_check
from factory.core.errors import ToolpathError

log = logging.getLogger(__name__)

#: Material less than this above a level counts as the level itself [mm].
_LEVEL_EPS = 1e-3


def rest_mask(sim: Simulation, z: float, above: float, allowance: float) -> np.ndarray:
    """(ny, nx) bool: the grid cells whose stock reaches above ``z`` with more than ``above`` [mm] of excess."""
    return (sim.stock_top > z + _LEVEL_EPS) & (excess(sim, allowance) > above)


def rest_material(sim: Simulation, z: float, above: float, allowance: float) -> BaseGeometry:
    """XY area of the grid cells whose stock reaches above ``z`` with more than ``above`` [mm] of excess."""
    return cells_region(rest_mask(sim, z, above, allowance), sim.grid)


def rest_level_masks(sim: Simulation, levels: Sequence[float], spaces: Sequence[BaseGeometry], radius: float,
                     above: float, allowance: float, column: float,
                     grown: Callable[[np.ndarray], BaseGeometry]) -> list[np.ndarray]:
    """(ny, nx) bool per level (top down): the grid cells a rest tool of ``radius`` [mm] cuts there.

    The rest material of the level (:func:`rest_mask`, more than ``above`` [mm] of excess), and the
    stock that a deeper level's cut would take more than ``column`` [mm] of at once (the tool's
    axial limit at full width). A flat end mill at a level takes everything above it within its
    radius, and the rest material of a deep level reaches into stock the excess does not count:
    the sliver a wider tool left in an inside corner lies within the cell diagonal of both walls.
    Entering that corner at the deep level only would cut the sliver's whole height at full
    width; this way every level in between cuts it too, no more than the levels' spacing at a time.

    ``spaces`` are the levels' tool axis regions (where the axis may go, rest material or not);
    ``grown(mask)`` the True cells grown by ``radius`` (:class:`cadcam.gridregion.GrownMaskCache`).
    """
    g = sim.grid
    # Stock over the part by more than the allowance with no grid slack: the allowance the earlier
    # tools left on the walls is no sliver to step down through.
    solid = (excess(sim, allowance, grid_slack=False) > allowance + _LEVEL_EPS) & np.isfinite(sim.stock_top)
    reach = np.full(g.shape, np.inf)  # the deepest level whose cut meets each cell [mm]
    masks: list[np.ndarray] = [np.zeros(g.shape, dtype=bool)] * len(levels)
    for k in reversed(range(len(levels))):
        z = float(levels[k])
        tall = solid & (sim.stock_top > z + _LEVEL_EPS) & (sim.stock_top - reach > column + _LEVEL_EPS)
        masks[k] = rest_mask(sim, z, above, allowance) | tall
        if not masks[k].any():
            continue
        cut = spaces[k].intersection(grown(masks[k]))
        if cut.is_empty:
            continue
        met = _cells_within(cut.buffer(radius, quad_segs=8), g)
        reach[met] = np.minimum(reach[met], z)
    return masks


def levels_within_reach(levels: np.ndarray, top: float, stick_out: float) -> np.ndarray:
    """The ``levels`` [mm] (top down) a rest tool reaches with its ``stick_out`` [mm] below the stock's ``top``,
    ending at that reach where the levels pass it by: it goes as deep as it reaches (a long-neck end mill's
    last millimetres in a deep pocket), never deeper (its holder would meet the stock)."""
    reach = top - stick_out
    kept = levels[levels >= reach - 1e-9]
    if len(kept) < len(levels) and (not len(kept) or kept[-1] > reach + _LEVEL_EPS):
        kept = np.append(kept, reach)
    return kept


#: How far a rest tool's holder keeps off the stock below its reach [mm]: the jaws' keep-out clearance.
HOLDER_CLEARANCE_MM = 0.5


def rest_levels(levels: np.ndarray, top: float, stick_out: float) -> tuple[np.ndarray, int]:
    """A rest tool's levels [mm] (top down): those it reaches with its ``stick_out`` [mm] below the stock's
    ``top`` (:func:`levels_within_reach`), then the deeper ones, and how many those are. It cuts at a deeper
    level only where its holder clears the stock (:func:`without_holder`): a hole in a leg beside a tall
    upright, once roughing opened the leg (issue 34's l_bracket)."""
    deep = levels[levels < top - stick_out - _LEVEL_EPS]
    return np.concatenate([levels_within_reach(levels, top, stick_out), deep]), len(deep)


def without_holder(spaces: list[BaseGeometry], levels: np.ndarray, deep: int, sim: Simulation | None,
                   tool: Tool) -> list[BaseGeometry]:
    """``spaces`` (where the axis may go at each of ``levels`` [mm]), the last ``deep`` of them less
    :func:`holder_keepout` at their level."""
    n = len(levels) - deep
    if sim is None or not deep:
        return spaces
    return spaces[:n] + [s.difference(holder_keepout(sim, tool, float(z))) for s, z in zip(spaces[n:], levels[n:])]


def holder_keepout(sim: Simulation, tool: Tool, z: float) -> BaseGeometry:
    """Where ``tool``'s axis may not go with its tip at ``z`` [mm]: its holder (from :attr:`Tool.length` above
    the tip up, :meth:`Tool.body`) would come within :data:`HOLDER_CLEARANCE_MM` of stock in ``sim`` (the stock
    before the operation: the cut only lowers it, so the region is on the safe side).

    The model knows the stock at its grid points only. Between them, and in the half cell between the outer
    rows and the stock's edge, a rim can stand that no point sees: where a round cut grazes a row, the stock
    it left runs on past the point that reads it cut (the 100k-triangle relief's 8 mm roughing left such a
    rim at the block's corner, which verify's finer grid found under T6's holder, 2.3 mm deep). So each point
    counts as high as the highest of its 3 x 3 neighbours, and the region grows by a cell more, which also
    keeps the path's chords across the region's round edge off."""
    g = sim.grid
    top = np.where(np.isfinite(sim.stock_top), sim.stock_top, -np.inf)
    top = ndimage.maximum_filter(top, size=3, mode="nearest")
    cylinders = [(h, r) for h, r in tool.body() if h >= float(tool.length) - 1e-9]
    zones = [grown_cells_region(top > z + h - HOLDER_CLEARANCE_MM, g, r + HOLDER_CLEARANCE_MM + g.cell, quad_segs=8)
             for h, r in cylinders]
    return shapely.union_all(zones) if zones else shapely.Polygon()


def rooms_round(regions: Sequence[BaseGeometry], space: BaseGeometry, by: float) -> list[BaseGeometry]:
    """The room round rest regions too small to enter on their own: the polygons of ``space`` (where the
    tool axis may go at the level) within ``by`` [mm] of ``regions`` that hold some of them.

    The corners a wider tool left in a narrow pocket are slivers a helix or a ramp of their own does not
    fit; the pocket round them, which that tool cleared, has room for a ramp along it (issue 34).
    """
    grown = shapely.union_all([r.buffer(by, quad_segs=8) for r in regions]).intersection(space)
    rooms = [q for q in shapely.get_parts(grown) if q.geom_type == "Polygon" and q.area > 0.0]
    return [q for q in rooms if any(q.intersects(r) for r in regions)]


def _cells_within(region: BaseGeometry, grid: Grid) -> np.ndarray:
    """(ny, nx) bool: the grid points inside ``region``."""
    out = np.zeros(grid.shape, dtype=bool)
    x0, y0, x1, y1 = region.bounds
    (i0,), (i1,) = grid.column_range(np.array([x0]), np.array([x1]))
    (j0,), (j1,) = grid.row_range(np.array([y0]), np.array([y1]))
    if i1 >= i0 and j1 >= j0:
        xs, ys = np.meshgrid(grid.xs[i0:i1 + 1], grid.ys[j0:j1 + 1])
        out[j0:j1 + 1, i0:i1 + 1] = shapely.contains_xy(region, xs, ys)
    return out


def deep_stock(sim: Simulation, above: float, allowance: float, grid_slack: bool = True) -> Simulation:
    """``sim`` with only the stock that lies more than ``above`` [mm] over the part; elsewhere ``-inf``."""
    top = np.where(excess(sim, allowance, grid_slack) > above, sim.stock_top, -np.inf)
    top.setflags(write=False)
    return dataclasses.replace(sim, stock_top=top)


def engagement_ok(deep: Simulation, tool: Tool, points: np.ndarray, limit: float) -> np.ndarray:
    """(n,) bool: a tool tip at each of ``points`` cuts at most ``limit`` [mm] of the ``deep`` stock.

    ``deep`` comes from :func:`deep_stock`; only tips near its stock are tested.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    ok = np.ones(len(pts), dtype=bool)
    present = np.isfinite(deep.stock_top)
    if not present.any() or not len(pts):
        return ok
    g = deep.grid
    k = int(math.ceil((tool.radius + 2 * g.cell * math.sqrt(2.0)) / g.cell))
    near = ndimage.binary_dilation(present, structure=np.ones((2 * k + 1, 2 * k + 1), dtype=bool))
    i = np.clip(np.rint((pts[:, 0] - g.x0) / g.cell).astype(np.int64), 0, g.nx - 1)
    j = np.clip(np.rint((pts[:, 1] - g.y0) / g.cell).astype(np.int64), 0, g.ny - 1)
    test = np.flatnonzero(near[j, i])
    if len(test):
        ok[test] = pts[test, 2] >= clear_height(deep, tool, pts[test, :2]) - limit
    return ok


def _grown(tool: Tool, by: float) -> Tool:
    """The tool made ``by`` [mm] wider all round (same shape): conservative for a sampled stock."""
    d = tool.diameter + 2 * by
    rc = d / 2 if tool.shape == "ball" else tool.corner_radius
    return dataclasses.replace(tool, diameter=d, corner_radius=rc)


def from_and_to_safe_height(op: Operation, safe_z: float) -> Operation:
    """``op`` starting and ending at ``safe_z`` [mm]: a rapid straight up or down added where it does
    not (a canned cycle's motion is the controller's: left as it is)."""
    pts = op.points
    if op.cycle is not None or not len(pts) or (pts[0, 2] >= safe_z - 1e-9 and pts[-1, 2] >= safe_z - 1e-9):
        return op
    mot, feeds = op.motion, op.feeds
    if pts[0, 2] < safe_z - 1e-9:
        pts = np.vstack([[pts[0, 0], pts[0, 1], safe_z], pts])
        mot = np.concatenate([[Motion.RAPID], mot]).astype(op.motion.dtype)
        feeds = None if feeds is None else np.r_[np.nan, feeds]
    if pts[-1, 2] < safe_z - 1e-9:
        pts = np.vstack([pts, [pts[-1, 0], pts[-1, 1], safe_z]])
        mot = np.concatenate([mot, [Motion.RAPID]]).astype(op.motion.dtype)
        feeds = None if feeds is None else np.r_[feeds, np.nan]
    return dataclasses.replace(op, points=pts, motion=mot, feeds=feeds)


def safe_rapids(operations: Sequence[Operation], setup: Setup, part_triangles: np.ndarray,
                cell: float = 0.5) -> tuple[tuple[Operation, ...], int, int]:
    """Make every rapid of ``operations`` clear the in-process stock with the whole tool, and check
    that no move of any tool reaches the vise's jaws or parallels (``setup.jaws``). Each operation
    starts and ends at ``setup.safe_z`` (a rapid straight down and up added where it would not), so
    the links between operations run above the stock and every descent is one of the rapids checked.

    The operations are simulated in order with each tool grown by half a cell diagonal (the
    stock is only known at grid points). A rapid that would touch the stock as the earlier
    moves left it is split: a vertical descent rapids down to ``setup.clearance`` above
    the highest stock under the (grown) tool and feeds the rest at the plunge feed; any
    other such rapid becomes a plunge-feed move.

    Returns
    -------
    operations : tuple of Operation
    checked : int
        Rapids below ``setup.safe_z`` that were tested.
    fixed : int
        Rapids that touched the stock and were split or slowed.

    Raises
    ------
    ToolpathError
        A move's tool, shank or holder reaches into the jaws or parallels.
    """
    # Every link between operations runs at the safe height: an operation that starts or ends
    # lower gets the rapid up or down there, which is then checked like any other.
    ops = tuple(from_and_to_safe_height(op, setup.safe_z) for op in operations)
    if not ops:
        return ops, 0, 0
    by = 0.5 * cell * math.sqrt(2.0)
    tools = {op.tool.number: _grown(op.tool, by) for op in ops}
    moves = operation_moves(ops)
    starts = np.cumsum([0] + [len(op.points) for op in ops])
    first = np.zeros(len(moves.points), dtype=bool)
    first[starts[:-1]] = True
    below = (moves.motion == Motion.RAPID) & ~first & (moves.points[:, 2] < setup.safe_z - 1e-9)
    checked = int(below.sum())
    # Only rapids and the jaws are read here: no engagement, contacts, gouges or stock left.
    found = rapid_check(moves, tools, setup, part_triangles, cell)
    final = found.simulation
    for f in found.jaw_faults:  # no speed makes a move into the vise safe: the planner is wrong
        x, y, z = f.position or (math.nan,) * 3
        raise ToolpathError(f"{f.message} near X{x:.1f} Y{y:.1f} Z{z:.1f}: the toolpath would hit the vise")
    bad = sorted({c.move for c in found.rapid_crashes if not first[c.move]})
    if not bad:
        return ops, checked, 0
    # the stock each bad rapid found: only the stock, nothing measured
    snaps = cut_stock(moves, tools, setup, part_triangles, cell, snapshot_moves=[m - 1 for m in bad],
                      measure=False).snapshots
    edits: dict[int, list[tuple[int, float | None]]] = {}
    for m, snap in zip(bad, snaps):
        k = int(np.searchsorted(starts, m, side="right") - 1)
        if ops[k].cycle is not None:  # a canned cycle's motion is the controller's: verify reports it
            log.warning("rapid %d of drilling operation %r touches the stock", m, ops[k].name)
            continue
        i = m - int(starts[k])
        a, b = moves.points[m - 1], moves.points[m]
        split = None
        if np.hypot(*(b[:2] - a[:2])) < 1e-9 and b[2] < a[2]:
            stock_sim = dataclasses.replace(final, stock_top=snap)
            air = float(clear_height(stock_sim, tools[ops[k].tool.number], b[None, :2])[0]) + setup.clearance
            if b[2] < air < a[2]:
                split = air
        edits.setdefault(k, []).append((i, split))
    out = list(ops)
    for k, changes in edits.items():
        op = ops[k]
        pts, mot = op.points.copy(), op.motion.copy()
        feeds = None if op.feeds is None else op.feeds.copy()
        inserts = []
        for i, split in changes:
            mot[i] = Motion.PLUNGE
            if split is not None:
                inserts.append((i, np.array([pts[i, 0], pts[i, 1], split])))
        for i, p in sorted(inserts, key=lambda t: -t[0]):
            pts = np.insert(pts, i, p, axis=0)
            mot = np.insert(mot, i, Motion.RAPID)
            feeds = None if feeds is None else np.insert(feeds, i, np.nan)
        out[k] = dataclasses.replace(op, points=pts, motion=mot, feeds=feeds)
    log.info("%d of %d rapids below the safe plane would touch the stock: split or slowed", len(bad), checked)
    return tuple(out), checked, len(bad)
