"""An independent material-removal probe for tests and benchmarks: how deep each move cuts.

It shares nothing with :mod:`cadcam.stock` but the grid: each move is swept by sampling
the tool's position along it (at most a quarter cell apart) and taking, at every grid
point within reach, the lowest point of the tool's surface over the samples. A move's
*engagement* is the deepest it reaches below the stock as every earlier move left it
(the axial depth of material it cuts); a rapid's engagement is a crash. Its *buried*
depth counts only material more than :data:`EDGE` inside the tool's edge (radial
immersion over ``EDGE``): a finishing pass taking a thin skin off a tall wall engages
deep but is not buried; a ball dropped into an uncut hole is.

Asked for, it also reads each move's *full-width depth* the way a machinist pictures it, with
nothing of :mod:`cadcam.stock`'s engagement angle: at every sampled position the cutter's
leading half is probed at :data:`PROBES` angles, a cell and a half inside its edge, against the
stock as the earlier moves left it; the deepest column that more than half of the probes (more
than 90 deg of the arc) all reach is the axial depth the tool takes at full width there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cadcam.heightmap import grid_over
from cadcam.model import Motion, Setup, Tool

#: Radial immersion [mm] from which material counts as burying the tool.
EDGE = 1.0
#: Probes over the leading half of the cutter, 5 deg apart, for the full-width depth.
PROBES = 37
#: A column thinner than this is no material to the probes [mm].
FILM = 0.05


@dataclass(frozen=True)
class Sweep:
    """Per move (aligned with the moves' points; entry 0 is meaningless).

    engagement : (n,) float
        Depth of stock the move cuts [mm]; 0 where it cuts nothing.
    buried : (n,) float
        The same, counting only material more than ``EDGE`` inside the tool's edge [mm].
    lowest : (n,) float
        Lowest tip height of the move [mm].
    full_width : (n,) float
        Deepest column more than 90 deg of the cutter's leading half meets at once [mm]; all 0
        unless asked for.
    """

    engagement: np.ndarray
    buried: np.ndarray
    lowest: np.ndarray
    full_width: np.ndarray


def sweep_moves(points: np.ndarray, motion: np.ndarray, tools: np.ndarray, library: dict[int, Tool],
                setup: Setup, cell: float = 0.5, full_width: bool = False) -> Sweep:
    """Sweep ``points`` (tool tips [mm]) in order through the stock of ``setup``.

    ``motion`` as :class:`cadcam.model.Motion` per point, ``tools`` the tool number per point;
    ``full_width``: probe each feed move's full-width depth too (module docstring).
    """
    g = grid_over(setup.stock_min, setup.stock_max, cell)
    top = float(setup.stock_max[2])
    stock = np.full(g.shape, top)
    n = len(points)
    eng = np.zeros(n)
    buried = np.zeros(n)
    lowest = np.full(n, np.nan)
    full = np.zeros(n)
    for i in range(1, n):
        a, b = points[i - 1], points[i]
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            continue
        lowest[i] = min(a[2], b[2])
        if lowest[i] >= top:
            continue
        tool = library[int(tools[i])]
        r = tool.radius
        length = float(np.hypot(*(b[:2] - a[:2])))
        ns = max(2, int(math.ceil(length / (0.25 * cell))) + 1)
        t = np.linspace(0.0, 1.0, ns)
        p = a[None] + t[:, None] * (b - a)[None]
        i0 = max(int(math.floor((min(a[0], b[0]) - r - g.x0) / g.cell)), 0)
        i1 = min(int(math.ceil((max(a[0], b[0]) + r - g.x0) / g.cell)), g.nx - 1)
        j0 = max(int(math.floor((min(a[1], b[1]) - r - g.y0) / g.cell)), 0)
        j1 = min(int(math.ceil((max(a[1], b[1]) + r - g.y0) / g.cell)), g.ny - 1)
        if i1 < i0 or j1 < j0:
            continue
        xs = g.x0 + g.cell * np.arange(i0, i1 + 1)
        ys = g.y0 + g.cell * np.arange(j0, j1 + 1)
        env = np.full((len(ys), len(xs)), np.inf)
        for chunk in np.array_split(np.arange(ns), max(1, ns // 64)):
            # Only the cells within the tool's reach of this chunk's samples: the profile is inf beyond
            # its radius, so the rest of the move's window would take nothing (a long move's window is
            # hundreds of times a chunk's reach).
            q = p[chunk]
            c0 = max(int(math.floor((q[:, 0].min() - r - g.x0) / g.cell)) - i0, 0)
            c1 = min(int(math.ceil((q[:, 0].max() + r - g.x0) / g.cell)) - i0, len(xs) - 1)
            r0 = max(int(math.floor((q[:, 1].min() - r - g.y0) / g.cell)) - j0, 0)
            r1 = min(int(math.ceil((q[:, 1].max() + r - g.y0) / g.cell)) - j0, len(ys) - 1)
            if c1 < c0 or r1 < r0:
                continue
            d = np.hypot(xs[None, None, c0:c1 + 1] - q[:, 0, None, None], ys[None, r0:r1 + 1, None] - q[:, 1, None, None])
            if a[2] == b[2]:
                # A level move: the profile rises with the distance, so its lowest over the samples is
                # at the nearest one (the same number, to the bit, as taking the profile at each).
                low = a[2] + tool.profile_height(d.min(axis=0))
            else:
                low = (q[:, 2, None, None] + tool.profile_height(d)).min(axis=0)
            window = env[r0:r1 + 1, c0:c1 + 1]
            np.minimum(window, low, out=window)
        if full_width and motion[i] != Motion.RAPID and not tool.is_drill:
            full[i] = _full_width_depth(stock, g, p, tool)
        block = stock[j0:j1 + 1, i0:i1 + 1]
        depth = block - env
        eng[i] = max(float(depth.max()), 0.0)
        # Distance of each cell from the move's XY path: the tool's axis sweeps that segment.
        dxy = b[:2] - a[:2]
        l2 = float(dxy @ dxy)
        cx, cy = xs[None, :] - a[0], ys[:, None] - a[1]
        s = np.clip((cx * dxy[0] + cy * dxy[1]) / l2, 0.0, 1.0) if l2 > 0 else 0.0
        axis = np.hypot(cx - s * dxy[0], cy - s * dxy[1])
        core = axis <= max(r - EDGE, 0.5 * r)
        buried[i] = max(float(depth[core].max()), 0.0) if core.any() else 0.0
        np.minimum(block, env, out=block)
    return Sweep(eng, buried, lowest, full)


def _full_width_depth(stock: np.ndarray, g, p: np.ndarray, tool: Tool) -> float:
    """Deepest column [mm] more than half of the leading probes meet at once, over the positions ``p``."""
    feed = p[-1, :2] - p[0, :2]
    if float(np.hypot(*feed)) < 1e-9:
        return 0.0
    heading = math.atan2(feed[1], feed[0])
    rho = tool.radius - 1.5 * g.cell  # inside the edge: a wall the cutter rides is no material
    if rho <= 0.0:
        return 0.0
    angles = heading + np.radians(np.linspace(-90.0, 90.0, PROBES))
    qx = p[1:, 0, None] + rho * np.cos(angles)[None]
    qy = p[1:, 1, None] + rho * np.sin(angles)[None]
    i = np.rint((qx - g.x0) / g.cell).astype(np.int64)
    j = np.rint((qy - g.y0) / g.cell).astype(np.int64)
    inside = (i >= 0) & (i < g.nx) & (j >= 0) & (j < g.ny)
    top = np.where(inside, stock[np.clip(j, 0, g.ny - 1), np.clip(i, 0, g.nx - 1)], -np.inf)
    column = top - (p[1:, 2, None] + float(tool.profile_height(rho)))
    column = np.where(column > FILM, column, 0.0)
    need = PROBES // 2 + 1  # more than half the arc
    return float(np.sort(column, axis=1)[:, -need].max())


def rapid_hits(sw: Sweep, motion: np.ndarray, tol: float = 0.05) -> np.ndarray:
    """Indices of rapids that cut more than ``tol`` [mm] of stock."""
    return np.flatnonzero((np.asarray(motion) == Motion.RAPID) & (sw.engagement > tol))


def past_axial_limit(sw: Sweep, tools: np.ndarray, library: dict[int, Tool], slack: float) -> dict[int, float]:
    """Tool number -> its deepest full-width depth [mm], for each tool whose ``sw.full_width`` passes its
    axial limit (:attr:`Tool.full_width_limit`) by more than ``slack`` [mm] (a probe's grid step)."""
    out = {}
    for t in np.unique(tools).tolist():
        if t in library and not library[t].is_drill:
            deepest = float(sw.full_width[np.asarray(tools) == t].max(initial=0.0))
            if deepest > library[t].full_width_limit + slack:
                out[int(t)] = deepest
    return out
