"""The vise's jaws and parallels as obstacles: how far a tool's swept body reaches into them.

The jaws are boxes in work coordinates (:attr:`cadcam.model.Setup.jaws`, placed by
:meth:`cadcam.model.ViseJaws.place`), beside and under the stock, so outside the stock's
height field: the material-removal simulation never sees them. Here every straight move is
swept against each box exactly.

The tool is taken as the cutter's cylinder from the tip up (its corner profile ignored: on
the safe side) and its shank and holder cylinders (:meth:`cadcam.model.Tool.body`), each
reaching up forever, as in the simulation. A cylinder of radius ``r`` whose bottom is ``h``
above the tip meets a box where the tip is at most ``box top - h`` high and the tool axis
within ``r`` of the box's XY rectangle. Its depth into the box is the lesser of the two
deepest overlaps along the part of the move that comes low enough (radial: ``r`` minus the
least distance; vertical: box top minus the cylinder's lowest bottom): positive exactly
where the swept body meets the box, and never less than the depth at any one point.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import shapely
import trimesh
from shapely.geometry import box as rectangle
from shapely.geometry.base import BaseGeometry

from cadcam.heightmap import grid_over, upper_envelope
from cadcam.model import FixtureBox, Setup, Tool

#: Gap the planner keeps between a tool's body and the jaws or parallels [mm]: verify's
#: tolerance for a fixture contact is far below it.
KEEPOUT_CLEARANCE_MM = 0.5


@dataclass(frozen=True)
class FixtureContacts:
    """How deep each move's tool reaches into the workholding.

    Attributes
    ----------
    depth : (n,) float
        Deepest reach of the move's tool into any box [mm]; 0 where it stays clear.
    box : (n,) int
        Index into the boxes of that deepest reach; -1 where clear.
    position : (n, 3) float
        Tool tip where the move comes lowest into that box [mm]; NaN where clear.
    """

    depth: np.ndarray
    box: np.ndarray
    position: np.ndarray


def tool_cylinders(tool: Tool) -> tuple[tuple[float, float], ...]:
    """``(height of the bottom above the tip, radius)`` [mm] of the tool's cylinders: the cutter, then
    shank and holder (each reaching up forever)."""
    return ((0.0, float(tool.radius)),) + tuple(tool.body())


def _point_rect_distance(p: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(n,) distance of 2-D points (n, 2) to the rectangle [lo, hi] (0 inside)."""
    d = np.maximum(np.maximum(lo - p, p - hi), 0.0)
    return np.hypot(d[:, 0], d[:, 1])


def _point_segment_distance(q: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """(n,) distance of one 2-D point ``q`` to each segment p0 -> p1 (n, 2)."""
    d = p1 - p0
    l2 = np.einsum("ij,ij->i", d, d)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(l2 > 0, np.einsum("ij,ij->i", q - p0, d) / np.where(l2 > 0, l2, 1.0), 0.0)
    c = p0 + np.clip(t, 0.0, 1.0)[:, None] * d
    return np.hypot(*(q - c).T)


def _segment_crosses_rect(p0: np.ndarray, p1: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(n,) bool: the segment p0 -> p1 meets the rectangle [lo, hi] (Liang-Barsky clipping)."""
    d = p1 - p0
    t0 = np.zeros(len(p0))
    t1 = np.ones(len(p0))
    ok = np.ones(len(p0), dtype=bool)
    for axis in (0, 1):
        for sign, bound in ((-1.0, lo[axis]), (1.0, hi[axis])):
            # sign * (p + t d) <= sign * bound
            num = sign * (bound - p0[:, axis])
            den = sign * d[:, axis]
            parallel = den == 0
            ok &= ~(parallel & (num < 0))
            with np.errstate(divide="ignore", invalid="ignore"):
                t = num / np.where(parallel, 1.0, den)
            t1 = np.where(~parallel & (den > 0), np.minimum(t1, t), t1)
            t0 = np.where(~parallel & (den < 0), np.maximum(t0, t), t0)
    return ok & (t0 <= t1)


def fixture_contacts(start: np.ndarray, end: np.ndarray, tool: np.ndarray, tools: Mapping[int, Tool],
                     boxes: Sequence[FixtureBox]) -> FixtureContacts:
    """Sweep each move's tool against the workholding boxes.

    Parameters
    ----------
    start, end : (n, 3) float
        Tool tip at the start and end of each straight move [mm], finite.
    tool : (n,) int
        Tool number of each move; numbers missing from ``tools`` (an empty spindle) never
        touch anything.
    tools : mapping of int to Tool
    boxes : sequence of FixtureBox
        In the same work coordinates [mm].

    Returns
    -------
    FixtureContacts
    """
    a = np.asarray(start, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(end, dtype=np.float64).reshape(-1, 3)
    tool = np.asarray(tool, dtype=np.int64).reshape(-1)
    n = len(a)
    depth = np.zeros(n)
    which = np.full(n, -1, dtype=np.int64)
    where = np.full((n, 3), np.nan)
    for t in np.unique(tool).tolist():
        if t not in tools:
            continue
        mine = np.flatnonzero(tool == t)
        sa, sb = a[mine], b[mine]
        dz = sb[:, 2] - sa[:, 2]
        for h, r in tool_cylinders(tools[t]):
            for k, box in enumerate(boxes):
                lo, hi = box.lo, box.hi
                # the part of the move where the cylinder's bottom is below the box top
                limit = hi[2] - h
                with np.errstate(divide="ignore", invalid="ignore"):
                    tz = np.where(dz != 0, (limit - sa[:, 2]) / np.where(dz != 0, dz, 1.0), 0.0)
                t0 = np.where(dz < 0, np.clip(tz, 0.0, 1.0), 0.0)
                t1 = np.where(dz > 0, np.clip(tz, 0.0, 1.0), 1.0)
                low = np.where(dz == 0, sa[:, 2] <= limit,
                               np.where(dz > 0, sa[:, 2] <= limit, sb[:, 2] <= limit))
                if not low.any():
                    continue
                p0 = sa + t0[:, None] * (sb - sa)
                p1 = sa + t1[:, None] * (sb - sa)
                lo2, hi2 = lo[:2], hi[:2]
                dist = np.minimum(_point_rect_distance(p0[:, :2], lo2, hi2), _point_rect_distance(p1[:, :2], lo2, hi2))
                for corner in ((lo2[0], lo2[1]), (lo2[0], hi2[1]), (hi2[0], lo2[1]), (hi2[0], hi2[1])):
                    dist = np.minimum(dist, _point_segment_distance(np.array(corner), p0[:, :2], p1[:, :2]))
                dist = np.where(_segment_crosses_rect(p0[:, :2], p1[:, :2], lo2, hi2), 0.0, dist)
                zlow = np.minimum(p0[:, 2], p1[:, 2])
                d = np.where(low, np.minimum(r - dist, limit - zlow), 0.0)
                better = d > depth[mine]
                if better.any():
                    idx = mine[better]
                    depth[idx] = d[better]
                    which[idx] = k
                    where[idx] = np.where((p0[:, 2] <= p1[:, 2])[:, None], p0, p1)[better]
    return FixtureContacts(depth, which, where)


#: ``shadows(heights)``: for each height [mm], the XY area over which the part's material reaches that
#: height or higher (:func:`cadcam.roughing.part_shadows`).
Shadows = Callable[[Sequence[float]], Mapping[float, BaseGeometry]]


def _under_boxes(cylinders: Sequence[tuple[float, float]], point_length: float, boxes: Sequence[FixtureBox],
                 floor: float) -> tuple[tuple[int, float, float], ...]:
    """``(box index, keep-off distance, height)`` [mm] for each of a tool's ``cylinders`` whose bottom can
    come below a box's top at the ``floor``: the axis keeps the cylinder's radius plus
    :data:`KEEPOUT_CLEARANCE_MM` off the box, except over the part where its material reaches ``height``,
    where the tip (never below the part's top at the axis, less a drill's ``point_length``) holds the
    cylinder's bottom that clearance above the box's top."""
    return tuple((k, r + KEEPOUT_CLEARANCE_MM, float(b.hi[2]) - h + KEEPOUT_CLEARANCE_MM + point_length)
                 for h, r in cylinders for k, b in enumerate(boxes) if b.hi[2] > floor + h + 1e-9)


#: How far in from the part's Y faces op 2's jaws (:func:`cadcam.op2.op2_jaws`) keep a tool off when they stand
#: above what it cuts there [mm]: the widest end mill's radius (the 16 mm) plus the keep-out's clearance, with room.
BESIDE_JAWS_MM = 10.0


def lowest_beside_jaws(part: trimesh.Trimesh, face_z: float, cell: float = 0.5) -> float:
    """The lowest face of the turned-over ``part`` that op 2 sees from above within :data:`BESIDE_JAWS_MM` of
    its Y faces (where the jaws grip) [mm, op-2 work Z], ``face_z`` at the most; where nothing of the part but
    its bottom lies under a grid point (a through hole, the outline's corners) it is not counted."""
    lo, hi = np.asarray(part.bounds, dtype=np.float64)
    grid = grid_over(lo, hi, cell)
    top = upper_envelope(np.asarray(part.triangles), grid)
    ys = grid.ys
    near = (ys - lo[1] <= BESIDE_JAWS_MM) | (hi[1] - ys <= BESIDE_JAWS_MM)
    seen = top[near]
    seen = seen[np.isfinite(seen) & (seen > lo[2] + 1e-6)]
    return min(float(seen.min()), face_z) if seen.size else face_z


def jaw_keepout(setup: Setup, tools: Sequence[Tool], shadows: Shadows | None = None
                ) -> Callable[[float], BaseGeometry] | None:
    """Where the planner may put a tool's axis so that no cutter, shank or holder enters the jaws or
    parallels (``setup.jaws``), as ``within(radius)`` for every operation's machining region.

    A cylinder of a tool (:func:`tool_cylinders`) whose bottom can come below a box's top, with the tip
    at the setup's floor (``setup.floor_z``, the lowest any operation feeds), keeps its axis its radius
    plus :data:`KEEPOUT_CLEARANCE_MM` off the box's XY rectangle, except where the tool cannot get that
    low. A tool's tip never comes below the part's highest material on its axis (the body above the
    tip would be in the part: a gouge), less a drill's point: over the part's ``shadows`` at the height
    that holds the cylinder's bottom :data:`KEEPOUT_CLEARANCE_MM` above the box's top, the axis may go
    (a shallow hole or pocket beside a jaw whose top lies well below it). Without ``shadows`` every tool
    is taken at the floor everywhere. The stock left in the keep-out stays for the stock model, which
    reports it as unreached (op 2 takes what lies in its reach). ``tools``: the tools the plan may use,
    matched by radius [mm] (a radius none of them has keeps off by the cutter alone). Each radius's region
    is computed once.

    Returns None when no tool can reach any box (the jaws' top under the floor, the usual op 1):
    the regions are then the operations' own.
    """
    boxes = setup.jaws or ()
    floor = float(setup.floor_z)
    if not any(b.hi[2] > floor + 1e-9 for b in boxes):  # every cylinder's bottom is at the tip or above
        return None
    by_tool = [(float(t.radius), _under_boxes(tool_cylinders(t), t.point_length, boxes, floor)) for t in tools]
    heights = sorted({z for _, under in by_tool for _, _, z in under})
    high = shadows(heights) if shadows is not None and heights else {}
    lo, hi = np.asarray(setup.stock_min, dtype=np.float64), np.asarray(setup.stock_max, dtype=np.float64)
    grow = float(np.ptp([lo[:2], hi[:2]], axis=0).max())  # beyond any tool's reach over the stock edge
    everywhere = rectangle(lo[0] - grow, lo[1] - grow, hi[0] + grow, hi[1] + grow)
    regions: dict[float, BaseGeometry] = {}

    def within(radius: float) -> BaseGeometry:
        key = round(float(radius), 9)
        if key not in regions:
            mine = [u for r, u in by_tool if abs(r - radius) < 1e-9] or [
                _under_boxes(((0.0, float(radius)),), 0.0, boxes, floor)]
            zones = []
            for k, off, z in sorted({c for under in mine for c in under}):
                b = boxes[k]
                zone = rectangle(b.lo[0], b.lo[1], b.hi[0], b.hi[1]).buffer(off, quad_segs=16)
                zones.append(zone.difference(high[z]) if z in high else zone)
            regions[key] = everywhere.difference(shapely.unary_union(zones)) if zones else everywhere
        return regions[key]

    return within


Region = Callable[[float], BaseGeometry]


def within_both(a: Region | None, b: Region | None) -> Region | None:
    """The region ``within(radius)`` both ``a`` and ``b`` allow (either None: the other)."""
    if a is None or b is None:
        return a if b is None else b
    return lambda radius: a(radius).intersection(b(radius))
