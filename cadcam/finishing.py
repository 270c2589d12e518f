"""3D finishing: raster (zigzag drop-cutter) on shallow areas, waterline loops on steep walls.

Every cutter location comes from the exact drop-cutter (:mod:`cadcam.dropcutter`), so every
point is gouge-free by construction; straight moves between points are refined until they
stay within ``tolerance`` of the exact CL surface.

Stepover from scallop height ``h`` (used for raster line spacing and waterline level spacing):

- ball, radius ``R``: ``2 sqrt(2 R h - h^2)`` (the cusp between two passes on a plane);
- bull-nose: the same with the corner radius ``rc`` in place of ``R`` (conservative: it
  ignores the flat bottom, which only helps on near-flat areas);
- flat: ``diameter / 10`` (a flat end mill leaves no scallop on a plane and a staircase on
  slopes whatever the stepover; a tenth of the diameter is a customary finishing stepover).

Allowance is applied exactly: the drop-cutter runs with a tool grown by the allowance
(radius ``R + a``, corner radius ``rc + a``), whose tip lies ``a`` below the real tool's
tip when both share the corner centres, so the real CL is the grown tool's CL raised by ``a``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import contourpy
import numpy as np
import trimesh
from scipy import ndimage
from shapely.geometry.base import BaseGeometry

from cadcam.dropcutter import TriangleIndex, drop_profile, shared_index
from cadcam.entries import ramp_entries
from cadcam.isoline import onto_iso, tighten_chords, z_near
from cadcam.model import CuttingData, Motion, Operation, Setup, Tool
from cadcam.relief import clip_chains
from cadcam.rest import deep_stock, engagement_ok
from cadcam.stock import Simulation, clear_height
from factory.core.errors import ToolpathError

#: ``within(radius)``: the XY region [mm] the axis of a tool of ``radius`` [mm] stays in.
Within = Callable[[float], "BaseGeometry"]

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]

#: Share of ``tolerance`` allowed to the chord test while refining (the rest to merging).
_REFINE_SHARE = 0.4
_MERGE_SHARE = 0.2
#: Shortest segment the adaptive refinement splits [mm]; below it a jump is a cliff.
_MIN_SEGMENT = 0.01


@dataclass(frozen=True)
class FinishingOptions:
    """How finely to finish.

    Attributes
    ----------
    scallop : float
        Target scallop height [mm]; the raster stepover and waterline stepdown follow from
        it and the tool (see module docstring).
    step_along : float, optional
        Initial CL spacing along a raster line [mm]; default ``min(R / 8, 0.25)``. Refined
        adaptively where the CL surface bends.
    tolerance : float
        Largest vertical deviation of a straight move from the exact CL surface [mm].
    steep_angle : float
        CL surface slope [deg] from which the raster leaves a region to waterline (90: the
        raster covers everything).
    allowance : float
        Stock to leave on the part [mm].
    angle : float
        Raster direction [deg] from +X, counter-clockwise.
    """

    scallop: float = 0.005
    step_along: float | None = None
    tolerance: float = 0.002
    steep_angle: float = 50.0
    allowance: float = 0.0
    angle: float = 0.0


def stepover_for(tool: Tool, scallop: float) -> float:
    """Distance between passes that leaves ``scallop`` [mm] on a plane (module docstring).

    Returns
    -------
    float
        Stepover [mm], at most the tool diameter.
    """
    if tool.corner_radius <= 0.0:
        return tool.diameter / 10.0
    rho = tool.corner_radius
    h = min(scallop, rho)
    return float(min(2.0 * math.sqrt(2.0 * rho * h - h * h), tool.diameter))


def _check(options: FinishingOptions) -> None:
    o = options
    bad = []
    if not o.scallop > 0:
        bad.append(f"scallop must be > 0, got {o.scallop}")
    if not o.tolerance > 0:
        bad.append(f"tolerance must be > 0, got {o.tolerance}")
    if o.step_along is not None and not o.step_along > 0:
        bad.append(f"step_along must be > 0, got {o.step_along}")
    if not 0 < o.steep_angle <= 90:
        bad.append(f"steep_angle must be in (0, 90], got {o.steep_angle}")
    if not o.allowance >= 0:
        bad.append(f"allowance must be >= 0, got {o.allowance}")
    if bad:
        raise ToolpathError("; ".join(bad), source="finishing options")


@dataclass(frozen=True)
class _Surface:
    """The exact CL surface of the real tool (allowance included) over one part."""

    index: TriangleIndex
    radius: float
    corner: float
    allowance: float
    floor: float

    def z(self, xy: np.ndarray, progress: Progress | None = None, *, floor: np.ndarray | None = None) -> np.ndarray:
        """CL z [mm] at ``xy`` (n, 2) [mm]. ``floor`` (n,) [mm]: the caller needs the heights only above it;
        there they are exact, elsewhere they come back as ``floor`` (to a rounding of the allowance)."""
        a = self.allowance
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        low = self.floor if floor is None else np.maximum(self.floor, floor)
        return drop_profile(self.index, self.radius + a, self.corner + a, xy, low - a, progress) + a


def _surface(part: trimesh.Trimesh, setup: Setup, tool: Tool, options: FinishingOptions) -> _Surface:
    tris = np.asarray(part.triangles, dtype=np.float64)
    if len(tris) == 0:
        raise ToolpathError("part mesh has no triangles")
    if tool.is_drill:
        raise ToolpathError(f"T{tool.number} is a drill: finishing needs an end mill")
    # workholding: the tool drops no lower than the setup's floor (the holding allowance stays)
    return _Surface(shared_index(tris), tool.radius, tool.corner_radius, options.allowance, float(setup.floor_z))


def _work_box(part: trimesh.Trimesh, setup: Setup, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """XY box the tool can touch the part from, clipped to the stock [mm]."""
    b = np.asarray(part.bounds, dtype=np.float64)
    lo = np.maximum(b[0, :2] - reach, setup.stock_min[:2])
    hi = np.minimum(b[1, :2] + reach, setup.stock_max[:2])
    if np.any(hi <= lo):
        raise ToolpathError("the part does not overlap the stock in XY", source="setup")
    return lo, hi


# --------------------------------------------------------------------------- refinement


def _refine(surface: _Surface, xy: np.ndarray, z: np.ndarray, joined: np.ndarray, tol: float):
    """Split segments until their quarter points are within ``tol`` of the exact CL surface.

    Parameters
    ----------
    xy, z : (n, 2), (n,) float
        Polyline points with exact CL z [mm].
    joined : (n - 1,) bool
        Which consecutive points are joined by a move (False between separate chains).

    Returns
    -------
    xy, z : (k, 2), (k,) float
        Refined points, in order [mm].
    forced : (k,) bool
        Points merging must keep: the ends of vertical steps at cliffs (jumps of the CL
        surface narrower than the shortest segment), where a corner point is inserted so the
        tool goes over then down (or up then over), never through.
    source : (k,) int
        Index of the input point each output point follows (itself for input points).
    """
    n = len(xy)
    keys = [np.stack([np.arange(n, dtype=np.float64), np.zeros(n), np.zeros(n)], axis=1)]
    forced_ids: list[np.ndarray] = []
    total = n
    seg = np.flatnonzero(joined)
    ia, ib = seg.copy(), seg + 1
    t0, t1 = np.zeros(len(seg)), np.ones(len(seg))
    allp = np.column_stack([xy, z])
    # A height only tested against its chord is asked from just under the chord less tol (z_near): one lower
    # is a deviation over tol whatever it is, and most primitives are culled unseen. The heights a split
    # carries on (the new points, the children's midpoints) are made exact where they came back that low.
    a, b = allp[ia], allp[ib]
    under = 0.5 * (a[:, 2] + b[:, 2]) - tol  # zm came back floored where it is under this
    zm = z_near(surface, 0.5 * (a[:, :2] + b[:, :2]), under) if len(seg) else np.zeros(0)
    while len(seg):
        a, b = allp[ia], allp[ib]
        # Chord test at the quarter points too: an S-bend can hide from the midpoint alone.
        # Computed exactly as the children's midpoints will be: a point's z must belong to
        # its own XY to the last bit (the CL surface can jump).
        mid = 0.5 * (a[:, :2] + b[:, :2])
        q = np.concatenate([0.5 * (a[:, :2] + mid), 0.5 * (mid + b[:, :2])])
        chord_q = np.concatenate([0.75 * a[:, 2] + 0.25 * b[:, 2], 0.25 * a[:, 2] + 0.75 * b[:, 2]])
        zq = z_near(surface, q, chord_q - tol)
        zq1, zq3 = zq[: len(seg)], zq[len(seg):]
        dev = np.maximum.reduce([
            np.abs(zm - 0.5 * (a[:, 2] + b[:, 2])),
            np.abs(zq1 - chord_q[: len(seg)]),
            np.abs(zq3 - chord_q[len(seg):]),
        ])
        length = np.hypot(*(b[:, :2] - a[:, :2]).T)
        bad = dev > tol
        split = bad & (length > _MIN_SEGMENT)
        cliff = bad & ~split
        if np.any(cliff):
            ca, cb = ia[cliff], ib[cliff]
            za, zb = allp[ca, 2], allp[cb, 2]
            down = za > zb
            corner = np.where(down[:, None], np.column_stack([allp[cb, :2], za]), np.column_stack([allp[ca, :2], zb]))
            key = np.column_stack([seg[cliff], np.where(down, t1[cliff], t0[cliff]), np.where(down, -1.0, 1.0)])
            ids = np.arange(total, total + len(ca))
            total += len(ca)
            keys.append(key)
            allp = np.concatenate([allp, corner])
            forced_ids += [ca, cb, ids]
        if not np.any(split):
            break
        tm = 0.5 * (t0 + t1)
        new = np.column_stack([mid[split], zm[split] if under is None else
                               _exact_under(surface, mid[split], zm[split], under[split])])
        ids = np.arange(total, total + len(new))
        total += len(new)
        keys.append(np.column_stack([seg[split], tm[split], np.zeros(len(new))]))
        allp = np.concatenate([allp, new])
        seg = np.concatenate([seg[split], seg[split]])
        ia, ib = np.concatenate([ia[split], ids]), np.concatenate([ids, ib[split]])
        t0, t1 = np.concatenate([t0[split], tm[split]]), np.concatenate([tm[split], t1[split]])
        both = np.concatenate([split, split])
        zm = _exact_under(surface, q[both], zq[both], chord_q[both] - tol)
        under = None
    key = np.concatenate(keys)
    # Points are keyed by (segment, t, side); segment i's end (t = 1) is point i + 1 at t = 0.
    key[:, 0] += np.floor(key[:, 1])
    key[:, 1] -= np.floor(key[:, 1])
    order = np.lexsort((key[:, 2], key[:, 1], key[:, 0]))
    forced = np.zeros(total, dtype=bool)
    if forced_ids:
        forced[np.concatenate(forced_ids)] = True
    return allp[order, :2], allp[order, 2], forced[order], key[order, 0].astype(np.int64)


def _exact_under(surface: _Surface, xy: np.ndarray, z: np.ndarray, threshold: np.ndarray) -> np.ndarray:
    """``z`` (n,) [mm] from :func:`cadcam.isoline.z_near` at ``xy`` (n, 2) [mm] with ``threshold`` (n,) [mm],
    the exact CL z where it came back under the threshold (those may be the floor it was asked from)."""
    low = np.flatnonzero(z < threshold)
    if not len(low):
        return z
    z = z.copy()
    z[low] = surface.z(xy[low])
    return z


def _simplify(p: np.ndarray, keep: np.ndarray, tol: float) -> np.ndarray:
    """Douglas-Peucker by vertical deviation, all chains at once.

    ``p`` (n, 3) points; between consecutive ``keep`` points the points must lie on one XY
    line (raster lines, links); returns the keep mask.
    """
    keep = keep.copy()
    while True:
        k = np.flatnonzero(keep)
        free = np.flatnonzero(~keep)
        if not len(free):
            return keep
        j = np.searchsorted(k, free) - 1
        a, b = p[k[j]], p[k[j + 1]]
        dxy = b[:, :2] - a[:, :2]
        l2 = np.einsum("ij,ij->i", dxy, dxy)
        with np.errstate(invalid="ignore", divide="ignore"):
            s = np.where(l2 > 0, np.einsum("ij,ij->i", p[free, :2] - a[:, :2], dxy) / l2, 0.0)
        dev = np.abs(p[free, 2] - (a[:, 2] + s * (b[:, 2] - a[:, 2])))
        worst = np.full(len(k), -1.0)
        np.maximum.at(worst, j, dev)
        pick = (dev == worst[j]) & (dev > tol)
        if not np.any(pick):
            return keep
        _, first = np.unique(j[pick], return_index=True)
        keep[free[np.flatnonzero(pick)[first]]] = True


# --------------------------------------------------------------------------- assembly


def _only_where(chains: list[np.ndarray], where: Callable[[np.ndarray], np.ndarray] | None) -> list[np.ndarray]:
    """Chains cut down to their runs of points ``where`` accepts (all of them without ``where``)."""
    if where is None or not chains:
        return chains
    ok = where(np.concatenate(chains)[:, :2])
    out, start = [], 0
    for c in chains:
        edges = np.diff(np.concatenate([[0], ok[start:start + len(c)].astype(np.int8), [0]]))
        out += [c[s:e] for s, e in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)) if e - s >= 2]
        start += len(c)
    return out



def _assemble(chains: list[np.ndarray], setup: Setup, name: str, kind: str, tool: Tool,
              cutting: CuttingData, allowance: float, stock: Simulation | None = None,
              limit: EngagementLimit | None = None, within: Within | None = None) -> Operation:
    """Chains of CL points cut in order; retract, rapid, descend between them.

    A chain whose start lies under the stock is entered down a ramp along itself
    (:func:`cadcam.entries.ramp_entries`), never by a plunge.

    Links between chains rapid low through the air the stock model knows (:func:`_link_heights`;
    ``safe_z`` without one). Descents rapid down to ``setup.clearance`` above the highest stock under the tool
    (from ``stock``, the material earlier operations left) and feed only the rest: at the cutting feed down to
    :data:`DESCENT_MARGIN` over that stock, at the plunge feed below; without a stock model the whole descent
    from ``safe_z`` is fed at the plunge feed. With ``limit`` (and ``stock``)
    the chains are cut where a move would cut deeper than the limit (see
    :class:`EngagementLimit`).
    """
    safe_z = setup.safe_z
    if within is not None:
        chains = clip_chains(chains, within(tool.radius))
    if limit is not None and stock is not None:
        deep = deep_stock(stock, limit.depth, limit.allowance, limit.grid_slack)
        chains = _clip_engagement(chains, tool, deep, limit.depth)
    # A chain starting under stock is entered down a ramp along itself, never by a plunge.
    chains = ramp_entries(chains, stock, tool).chains
    points: list[np.ndarray] = []
    motion: list[np.ndarray] = []
    starts = np.array([c[0, :2] for c in chains]).reshape(-1, 2)
    high = clear_height(stock, tool, starts) if stock is not None else np.full(len(chains), np.inf)
    air = high + setup.clearance
    links = _link_heights(chains, stock, tool, setup) if stock is not None else np.full(len(chains), safe_z)
    for k, (c, air_z, high_z) in enumerate(zip(chains, air, high)):
        top_z = safe_z if k == 0 else links[k]
        points.append(np.array([[c[0, 0], c[0, 1], top_z]]))
        motion.append(np.array([Motion.RAPID]))
        if c[0, 2] < air_z < top_z:
            points.append(np.array([[c[0, 0], c[0, 1], air_z]]))
            motion.append(np.array([Motion.RAPID]))
        # The rapid's clearance over the stock is air: fed at the cutting feed, not the plunge feed (which
        # holds only for the last DESCENT_MARGIN over the stock, where the model may be short of it).
        fast_to = max(high_z + DESCENT_MARGIN, c[0, 2])
        if fast_to < min(air_z, top_z) - _MIN_SEGMENT and fast_to > c[0, 2] + _MIN_SEGMENT:
            points.append(np.array([[c[0, 0], c[0, 1], fast_to]]))
            motion.append(np.array([Motion.CUT]))
        leave_z = links[k + 1] if k + 1 < len(chains) else safe_z
        points += [c, np.array([[c[-1, 0], c[-1, 1], leave_z]])]
        motion += [
            np.concatenate([[Motion.PLUNGE], np.full(len(c) - 1, Motion.CUT)]),
            np.array([Motion.RAPID]),
        ]
    if not points:
        return Operation(name, kind, tool, cutting, np.zeros((0, 3)), np.zeros(0), allowance)
    pts = np.concatenate(points)
    if np.max(pts[:, 2]) > safe_z + 1e-9:
        raise ToolpathError(f"safe height {safe_z:g} mm is below the part ({np.max(pts[:, 2]):g} mm)", source="setup")
    return Operation(name, kind, tool, cutting, pts, np.concatenate(motion).astype(np.int8), allowance)


def _link_heights(chains: list[np.ndarray], stock: Simulation, tool: Tool, setup: Setup) -> np.ndarray:
    """(n,) height of the rapid into each chain from the end of the one before [mm].

    Low through the air the stock model knows: ``setup.clearance`` above the highest stock
    under the tool along the straight line between them (sampled a grid cell apart), never
    below either end nor above ``setup.safe_z``; the first chain is entered from ``safe_z``.
    The stock is the one before this operation, which only loses material while it runs.
    """
    out = np.full(len(chains), float(setup.safe_z))
    if len(chains) < 2:
        return out
    ends = np.array([c[-1] for c in chains[:-1]])
    starts = np.array([c[0] for c in chains[1:]])
    length = np.hypot(*(starts[:, :2] - ends[:, :2]).T)
    n = np.maximum(np.ceil(length / stock.grid.cell).astype(np.int64), 1) + 1
    seg = np.repeat(np.arange(len(ends)), n)
    t = (np.arange(len(seg)) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n - 1, n)
    xy = ends[seg, :2] + t[:, None] * (starts[seg, :2] - ends[seg, :2])
    high = np.full(len(ends), -np.inf)
    np.maximum.at(high, seg, clear_height(stock, tool, xy))
    z = np.maximum(high + setup.clearance, np.maximum(ends[:, 2], starts[:, 2]))
    out[1:] = np.minimum(z, setup.safe_z)
    return out


@dataclass(frozen=True)
class EngagementLimit:
    """Keep finishing out of stock earlier operations could not clear.

    Attributes
    ----------
    depth : float
        Deepest a finishing move may cut into the stock model it is given [mm].
    allowance : float
        Stock the earlier operations left on walls and floors on purpose [mm] (not rest
        material: see :mod:`cadcam.rest`).
    grid_slack : bool
        Also grow the part by a grid cell diagonal when telling that stock from rest
        material (roughing stopped short of the walls); False after an operation finished
        the walls (see :func:`cadcam.rest.excess`).
    """

    depth: float = 3.0
    allowance: float = 0.3
    grid_slack: bool = True


def _clip_engagement(chains: list[np.ndarray], tool: Tool, deep: Simulation, depth: float) -> list[np.ndarray]:
    """Chains split where a move would cut more than ``depth`` [mm] of the ``deep`` stock.

    Every move is tested at its ends and at samples at most a grid cell apart; a move
    failing anywhere is dropped with the runs of moves on either side kept as chains.
    """
    if not chains or not np.isfinite(deep.stock_top).any():
        return chains
    step = deep.grid.cell
    out: list[np.ndarray] = []
    sizes = np.array([len(c) for c in chains])
    p = np.concatenate(chains)
    a, b = p[:-1], p[1:]
    n_s = np.maximum(np.ceil(np.linalg.norm(b[:, :2] - a[:, :2], axis=1) / step).astype(np.int64), 1) + 1
    seg = np.repeat(np.arange(len(a)), n_s)
    t = (np.arange(len(seg)) - np.repeat(np.cumsum(n_s) - n_s, n_s)) / np.repeat(n_s - 1, n_s)
    q = a[seg] + t[:, None] * (b[seg] - a[seg])
    ok_q = engagement_ok(deep, tool, q, depth)
    seg_ok = np.ones(len(a), dtype=bool)
    np.logical_and.at(seg_ok, seg, ok_q)
    start = 0
    dropped = 0
    for n in sizes:
        good = seg_ok[start:start + n - 1] if n > 1 else np.zeros(0, dtype=bool)
        edges = np.diff(np.concatenate([[0], good.astype(np.int8), [0]]))
        for s0, e0 in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
            out.append(p[start + s0:start + e0 + 1])
        dropped += int((~good).sum())
        start += n
    if dropped:
        log.info("finishing: %d moves left out, they would cut more than %.1f mm", dropped, depth)
    return out


# --------------------------------------------------------------------------- raster


def raster_finishing(
    part: trimesh.Trimesh,
    setup: Setup,
    tool: Tool,
    cutting: CuttingData,
    options: FinishingOptions = FinishingOptions(),
    progress: Progress | None = None,
    stock: Simulation | None = None,
    limit: EngagementLimit | None = None,
    within: Within | None = None,
    where: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Operation:
    """Zigzag drop-cutter finishing of the shallow areas of ``part``.

    Lines run at ``options.angle`` over the part's footprint grown by the tool radius (cells
    where the tool touches the part, plus one sample around), within the stock; the tip
    never goes below the setup's floor (``Setup.floor_z``). Points on CL-surface slopes of ``steep_angle`` or
    more are left to waterline; a steep gap shorter than the tool diameter is cut through
    along the CL surface, a longer one is crossed at ``setup.safe_z``. Consecutive lines are
    joined by a cut along the CL surface when their ends are within a tool diameter.

    Parameters
    ----------
    part : trimesh.Trimesh
        Watertight part in work coordinates [mm].
    setup : Setup
    tool : Tool
    cutting : CuttingData
    options : FinishingOptions
    progress : callable, optional
        ``progress(done, total)`` over the initial CL grid.
    stock : Simulation, optional
        The stock earlier operations left (:func:`cadcam.stock.stock_after`); descents
        rapid through the air above it instead of feeding down from ``safe_z``.
    limit : EngagementLimit, optional
        With ``stock``: leave out every move that would cut deeper into it than this.
    within : callable, optional
        ``within(radius)``: the XY region the tool axis stays in (a relief's boundary,
        :meth:`cadcam.relief.Boundary.centre_region`); moves are cut where they leave it.
    where : callable, optional
        ``where(xy) -> (m,) bool``: cut only at these cutter locations (the faces this tool
        is to finish, :meth:`cadcam.faces.FaceClasses.near`); chains are split elsewhere.

    Returns
    -------
    Operation
        ``kind="raster"``; starts and ends at ``setup.safe_z``; empty if nothing is shallow.

    Raises
    ------
    ToolpathError
        Bad options, an empty part, a part outside the stock, or ``safe_z`` below the part.
    """
    _check(options)
    surface = _surface(part, setup, tool, options)
    stepover = stepover_for(tool, options.scallop)
    step = options.step_along if options.step_along is not None else min(tool.radius / 8.0, 0.25)
    # One step beyond the tool's reach: a line exactly one radius from a vertical wall would
    # run along the jump of the CL surface, where rounding decides which side a point is on.
    lo, hi = _work_box(part, setup, tool.radius + options.allowance + step)

    th = math.radians(options.angle)
    u_dir = np.array([math.cos(th), math.sin(th)])
    v_dir = np.array([-math.sin(th), math.cos(th)])
    box = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    bu, bv = box @ u_dir, box @ v_dir
    nv = max(int(math.ceil((bv.max() - bv.min()) / stepover)) + 1, 1)
    nu = max(int(math.ceil((bu.max() - bu.min()) / step)) + 1, 2)
    vs = np.linspace(bv.min(), bv.max(), nv) if nv > 1 else np.array([0.5 * (bv.min() + bv.max())])
    us = np.linspace(bu.min(), bu.max(), nu)
    du = us[1] - us[0]
    gxy = us[None, :, None] * u_dir + vs[:, None, None] * v_dir  # (nv, nu, 2)
    eps = 1e-9
    inside = np.all((gxy >= lo - eps) & (gxy <= hi + eps), axis=2)
    gz = np.full(inside.shape, np.nan)
    gz[inside] = surface.z(gxy[inside], progress)

    touched = inside & (gz > surface.floor + 1e-9)
    region = ndimage.binary_dilation(touched, structure=np.ones((3, 3), bool)) & inside
    if options.steep_angle >= 90.0:
        shallow = region
    else:
        slope = _slope(gz, du, vs[1] - vs[0] if nv > 1 else du)
        shallow = region & (slope < math.tan(math.radians(options.steep_angle)))

    chains_xy: list[np.ndarray] = []
    # The exact CL z of each chain point where the grid above already has it (NaN on the step-over
    # bridges): the same XY to the last bit, so the same z, and no second query for it.
    chains_z: list[np.ndarray] = []
    last_line = -1
    link = tool.diameter
    for j in range(nv):
        runs = _runs(shallow[j], inside[j], max(int(link / du), 0))
        for s, e in runs if j % 2 == 0 else reversed(runs):
            idx = np.arange(s, e + 1) if j % 2 == 0 else np.arange(e, s - 1, -1)
            line = gxy[j, idx]
            if chains_xy and last_line != j and np.hypot(*(chains_xy[-1][-1] - line[0])) <= link:
                # Step over to the next line along the CL surface rather than retracting.
                gap = line[0] - chains_xy[-1][-1]
                k = max(int(math.ceil(np.hypot(*gap) / step)), 1)
                bridge = chains_xy[-1][-1] + gap * (np.arange(1, k) / k)[:, None]
                chains_xy[-1] = np.concatenate([chains_xy[-1], bridge, line])
                chains_z[-1] = np.concatenate([chains_z[-1], np.full(len(bridge), np.nan), gz[j, idx]])
            else:
                chains_xy.append(line)
                chains_z.append(gz[j, idx])
            last_line = j

    chains = _finish_chains(surface, chains_xy, chains_z, options.tolerance)
    return _assemble(_only_where(chains, where), setup, "finish raster", "raster", tool, cutting,
                     options.allowance, stock, limit, within)


def _slope(gz: np.ndarray, du: float, dv: float) -> np.ndarray:
    """|grad z| from one-sided differences, the gentler side per axis (a jump next door
    must not make a flat point look steep)."""
    def gentle(axis: int, d: float) -> np.ndarray:
        diff = np.abs(np.diff(gz, axis=axis)) / d
        pad = [(0, 0), (0, 0)]
        pad[axis] = (1, 0)
        back = np.pad(diff, pad, constant_values=np.nan)
        pad[axis] = (0, 1)
        fwd = np.pad(diff, pad, constant_values=np.nan)
        return np.nan_to_num(np.fmin(back, fwd), nan=0.0)

    return np.hypot(gentle(1, du), gentle(0, dv))


def _runs(keep: np.ndarray, inside: np.ndarray, max_gap: int) -> list[tuple[int, int]]:
    """Index ranges [s, e] of kept samples along one line, short inside gaps bridged."""
    k = np.flatnonzero(keep)
    if len(k) < 2:
        return []
    breaks = np.flatnonzero(np.diff(k) > 1)
    starts = np.concatenate([[k[0]], k[breaks + 1]])
    ends = np.concatenate([k[breaks], [k[-1]]])
    runs = [[int(starts[0]), int(ends[0])]]
    for s, e in zip(starts[1:], ends[1:]):
        gap = s - runs[-1][1] - 1
        if gap <= max_gap and np.all(inside[runs[-1][1]:s]):
            runs[-1][1] = int(e)
        else:
            runs.append([int(s), int(e)])
    return [(s, e) for s, e in runs if e > s]


def _finish_chains(surface: _Surface, chains_xy: list[np.ndarray], chains_z: list[np.ndarray],
                   tolerance: float) -> list[np.ndarray]:
    """Exact z, adaptive refinement and merging for polylines cut along the CL surface.

    ``chains_z``: each point's exact CL z [mm] where already known, NaN where not (only
    those are queried).
    """
    if not chains_xy:
        return []
    sizes = np.array([len(c) for c in chains_xy])
    xy = np.concatenate(chains_xy)
    z = np.concatenate(chains_z)
    unknown = np.isnan(z)
    if np.any(unknown):
        z[unknown] = surface.z(xy[unknown])
    joined = np.ones(len(xy) - 1, dtype=bool)
    ends = np.cumsum(sizes)[:-1]
    joined[ends - 1] = False
    chain_id = np.repeat(np.arange(len(sizes)), sizes)
    rxy, rz, forced, source = _refine(surface, xy, z, joined, _REFINE_SHARE * tolerance)
    p = np.column_stack([rxy, rz])
    cid = chain_id[source]
    bounds = np.concatenate([[0], np.flatnonzero(np.diff(cid)) + 1, [len(p)]])
    first = bounds[:-1]
    keep = forced.copy()
    keep[first] = True
    keep[bounds[1:] - 1] = True
    # Direction changes (links between lines) must stay.
    d = np.diff(p[:, :2], axis=0)
    cross = d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0]
    dot = np.einsum("ij,ij->i", d[:-1], d[1:])
    turn = np.abs(cross) > 1e-9 * (np.hypot(*d[:-1].T) * np.hypot(*d[1:].T) + 1e-30)
    keep[1:-1] |= turn | (dot < 0)
    keep = _simplify(p, keep, _MERGE_SHARE * tolerance)
    return [p[a:b][keep[a:b]] for a, b in zip(bounds[:-1], bounds[1:])]


# --------------------------------------------------------------------------- waterline



def waterline_finishing(
    part: trimesh.Trimesh,
    setup: Setup,
    tool: Tool,
    cutting: CuttingData,
    options: FinishingOptions = FinishingOptions(),
    progress: Progress | None = None,
    stock: Simulation | None = None,
    limit: EngagementLimit | None = None,
    within: Within | None = None,
    where: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Operation:
    """Constant-z loops around the part, levels spaced for ``options.scallop`` on walls.

    The CL height map on a grid (spacing R/4) is contoured at each level with contourpy;
    each contour vertex is then moved onto the exact iso-line by bisection along its grid
    edge with the exact drop-cutter (keeping the gouge-free end). Where the CL surface
    jumps (a vertical wall: the tool's side touches it) the vertex is moved out by half the
    tolerance, so chords around convex corners do not cut into the wall. Chords that rise
    above ``level + tolerance/2`` anywhere (sampled finely, see :func:`cadcam.isoline.tighten_chords`)
    get a new vertex pushed out onto the iso-line. Only the steep portions of the loops are
    kept (CL slope of at least ``steep_angle`` less a small overlap with the raster, judged
    by the steepest side, so the foot of a vertical wall counts as steep); shallow gaps
    shorter than the tool diameter are bridged rather than retracted over. Loops are cut
    top level first, nearest loop next, with a retract to
    ``setup.safe_z``, a rapid, and a descent to each loop's start: straight down through the
    air, down a ramp along the loop where stock lies over its start (:func:`_assemble`).

    Parameters, returns and raises as :func:`raster_finishing` (``kind="waterline"``).
    """
    _check(options)
    surface = _surface(part, setup, tool, options)
    reach = tool.radius + options.allowance
    g = max(min(tool.radius / 4.0, 2.0), 0.02)
    lo, hi = _work_box(part, setup, reach + g)
    nx = int(math.ceil((hi[0] - lo[0]) / g)) + 1
    ny = int(math.ceil((hi[1] - lo[1]) / g)) + 1
    gx = np.linspace(lo[0], hi[0], nx)
    gy = np.linspace(lo[1], hi[1], ny)
    X, Y = np.meshgrid(gx, gy)
    Z = surface.z(np.column_stack([X.ravel(), Y.ravel()]), progress).reshape(ny, nx)

    floor = surface.floor
    top = float(Z.max())
    step = stepover_for(tool, options.scallop)
    levels = top - step * np.arange(1, int((top - floor) / step) + 1)
    levels = levels[levels > floor + 1e-3]
    if not len(levels):
        return _assemble([], setup, "finish waterline", "waterline", tool, cutting, options.allowance)

    gen = contourpy.contour_generator(gx, gy, Z, line_type="Separate")
    lines: list[np.ndarray] = []
    line_level: list[float] = []
    for level in levels:
        for line in gen.lines(float(level)):
            if len(line) >= 3:
                lines.append(np.asarray(line, dtype=np.float64))
                line_level.append(float(level))
    if not lines:
        return _assemble([], setup, "finish waterline", "waterline", tool, cutting, options.allowance)

    sizes = np.array([len(c) for c in lines])
    xy = np.concatenate(lines)
    lev = np.repeat(np.array(line_level), sizes)
    closed = np.array([np.allclose(c[0], c[-1]) for c in lines])
    xy, outward = onto_iso(surface, xy, lev, gx, gy, Z, options.tolerance)
    loops = np.split(np.column_stack([xy, lev]), np.cumsum(sizes)[:-1])
    outs = np.split(outward, np.cumsum(sizes)[:-1])
    loops = tighten_chords(surface, loops, outs, options.tolerance)
    p = np.concatenate(loops)
    high = int(np.sum(z_near(surface, p[:, :2], p[:, 2] + 1e-9) > p[:, 2] + 1e-9))
    if high:
        log.warning("waterline: %d loop vertices sit below the exact CL surface", high)
    # The raster owns slopes below steep_angle; overlap it by _SEAM_OVERLAP so the seam is cut.
    min_slope = math.tan(math.radians(max(options.steep_angle - _SEAM_OVERLAP, 0.0)))
    loops, closed = _steep_portions(loops, closed, _steepest_slope(Z, g), gx, gy, min_slope, bridge=tool.diameter)
    if not loops:
        return _assemble([], setup, "finish waterline", "waterline", tool, cutting, options.allowance)
    chains = _only_where(_order_loops(loops, closed), where)
    return _assemble(chains, setup, "finish waterline", "waterline", tool, cutting, options.allowance, stock,
                     limit, within)


#: Height [mm] over the stock model (:func:`cadcam.stock.clear_height`, already conservative between its grid
#: points) from which a descent into a chain is fed at the plunge feed; above it the descent is in air and fed at
#: the cutting feed (issue 32: a 1 mm clearance at the ball's plunge feed was 17 s of the dome's raster).
DESCENT_MARGIN = 0.25

#: Overlap [deg] of the waterline's slope range with the raster's, so their seam gets cut.
_SEAM_OVERLAP = 5.0


def _steepest_slope(gz: np.ndarray, g: float) -> np.ndarray:
    """|grad z| per grid node from its steeper one-sided differences (a cliff next door counts)."""
    dx = np.abs(np.diff(gz, axis=1)) / g
    dy = np.abs(np.diff(gz, axis=0)) / g
    sx = np.zeros_like(gz)
    sy = np.zeros_like(gz)
    sx[:, :-1] = dx
    sx[:, 1:] = np.maximum(sx[:, 1:], dx)
    sy[:-1, :] = dy
    sy[1:, :] = np.maximum(sy[1:, :], dy)
    return np.hypot(sx, sy)


def _steep_portions(loops, closed, slope, gx, gy, min_slope: float, bridge: float):
    """Cut waterline loops down to their steep stretches.

    A vertex is steep when any node of its grid cell has ``slope >= min_slope``. Each kept
    stretch takes one shallow neighbour at either end (its chord was verified with the
    loop), and shallow gaps shorter than ``bridge`` [mm] are kept rather than retracted
    over. Returns the pieces and whether each is still a closed loop.
    """
    g = gx[1] - gx[0]
    ny, nx = slope.shape
    out, out_closed = [], []
    for c, is_closed in zip(loops, closed):
        i = np.clip(((c[:, 0] - gx[0]) / g).astype(np.int64), 0, nx - 2)
        j = np.clip(((c[:, 1] - gy[0]) / g).astype(np.int64), 0, ny - 2)
        m = np.maximum.reduce([slope[j, i], slope[j, i + 1], slope[j + 1, i], slope[j + 1, i + 1]]) >= min_slope
        if not m.any():
            continue
        if is_closed:
            body, mb = c[:-1], m[:-1]
            if mb.all():
                out.append(c)
                out_closed.append(True)
                continue
            r = int(np.argmin(mb))  # start the walk on a shallow vertex
            body, mb = np.roll(body, -r, axis=0), np.roll(mb, -r)
            c, m = np.concatenate([body, body[:1]]), np.concatenate([mb, [False]])
        along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(c[:, :2], axis=0).T))])
        steep = np.flatnonzero(m)
        if is_closed and along[-1] - along[steep[-1]] + along[steep[0]] < bridge:
            out.append(c)  # only a short shallow gap: cut the whole loop
            out_closed.append(True)
            continue
        gaps = np.flatnonzero(np.diff(steep) > 1)
        for a, b in zip(steep[gaps], steep[gaps + 1]):
            if along[b] - along[a] < bridge:
                m[a:b] = True
        edges = np.diff(np.concatenate([[0], m.astype(np.int8), [0]]))
        for s0, e0 in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1):
            s0, e0 = max(s0 - 1, 0), min(e0 + 1, len(c) - 1)
            if e0 > s0:
                out.append(c[s0:e0 + 1])
                out_closed.append(False)
    return out, np.array(out_closed, dtype=bool)


def _order_loops(loops, closed) -> list[np.ndarray]:
    """Top level first; within a level the nearest loop next, closed loops entered nearest."""
    levels = np.array([c[0, 2] for c in loops])
    remaining = list(np.argsort(-levels, kind="stable"))
    pos = None
    out = []
    while remaining:
        lvl = levels[remaining[0]]
        same = [i for i in remaining if levels[i] == lvl]
        if pos is None:
            pick = same[0]
        else:
            pick = min(same, key=lambda i: float(np.min(np.hypot(*(loops[i][:, :2] - pos).T))))
        remaining.remove(pick)
        c = loops[pick]
        if closed[pick] and pos is not None:
            body = c[:-1]
            s = int(np.argmin(np.hypot(*(body[:, :2] - pos).T)))
            body = np.roll(body, -s, axis=0)
            c = np.concatenate([body, body[:1]])
        elif pos is not None and np.hypot(*(c[-1, :2] - pos)) < np.hypot(*(c[0, :2] - pos)):
            c = c[::-1]
        out.append(c)
        pos = c[-1, :2]
    return out
