"""Keeping a finishing tool's shank out of the stock when every pass goes to full depth.

A raster (zigzag) finishing pass goes down to the part wherever it is, at once. Beside a wall
taller than the tool's flutes, the tip reaches the floor while the roughing allowance is still
on the wall's upper part, and the shank rubs it (``factory verify`` fails ``holder``).
Waterline finishing works from the top down and never meets it; without waterline,
:func:`upper_raster` finishes the upper parts of such walls first.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import trimesh
from scipy import ndimage

from cadcam.finishing import EngagementLimit, FinishingOptions, Within, raster_finishing
from cadcam.model import CuttingData, Operation, Setup, Tool
from cadcam.stock import Simulation

#: The upper raster stops this far short of the flutes' reach from the stock top [mm].
SHANK_CLEARANCE = 0.5


def tall_walls(stock: Simulation, tool: Tool, reach: float) -> tuple[np.ndarray, np.ndarray] | None:
    """XY box [mm] of the tool positions where a tool down on the part has stock ``reach`` over its tip.

    The lowest tip at each grid point is the drop of the tool's profile onto the part (the
    stock bottom where there is none), on the stock model's grid; the shank (the cutting
    diameter wide) meets the highest stock within its radius. The box is grown by the tool
    diameter; None where no position has stock that high.
    """
    g = stock.grid
    floor = np.where(np.isfinite(stock.part_top), stock.part_top, stock.stock_bottom)
    k = int(math.ceil(tool.radius / g.cell))
    off = np.hypot(*np.meshgrid(np.arange(-k, k + 1), np.arange(-k, k + 1))) * g.cell
    disk = off <= tool.radius
    drop = -tool.profile_height(np.minimum(off, tool.radius))
    tip = ndimage.grey_dilation(floor, footprint=disk, structure=np.where(disk, drop, 0.0), mode="nearest")
    over = ndimage.maximum_filter(stock.stock_top, footprint=disk, mode="nearest")
    tall = over - tip > reach
    if not tall.any():
        return None
    rows, cols = np.nonzero(tall)
    lo = np.array([g.x0 + cols.min() * g.cell, g.y0 + rows.min() * g.cell]) - tool.diameter
    hi = np.array([g.x0 + cols.max() * g.cell, g.y0 + rows.max() * g.cell]) + tool.diameter
    return lo, hi


def upper_raster(part: trimesh.Trimesh, setup: Setup, tool: Tool, cutting: CuttingData,
                 options: FinishingOptions, stock: Simulation, limit: EngagementLimit | None = None,
                 progress: Callable[[int, int], None] | None = None, within: Within | None = None
                 ) -> Operation | None:
    """A raster round the walls taller than ``tool``'s flutes, its tip within their reach from the stock top.

    Run before the full-depth raster, it finishes those walls' upper parts, so the full
    raster's shank meets finished walls only. None where no wall is that tall (nothing to do).

    Parameters
    ----------
    stock : Simulation
        The stock the earlier operations left (:func:`cadcam.stock.stock_after`).
    options, limit, progress, within
        As for :func:`cadcam.finishing.raster_finishing` (``within``: the jaws' keep-out).
    """
    upper = float(setup.stock_max[2]) - tool.flute_length + SHANK_CLEARANCE
    walls = tall_walls(stock, tool, tool.flute_length - SHANK_CLEARANCE)
    if walls is None or upper <= float(setup.floor_z):
        return None
    lo, hi = walls
    # The raster's work box is the stock's: the walls' box, its floor at ``upper``.
    # (the drop-cutter's floor is the setup's floor_z, so that goes up to ``upper`` too)
    shallow = dataclasses.replace(setup, stock_min=np.array([*np.maximum(lo, setup.stock_min[:2]), upper]),
                                  stock_max=np.array([*np.minimum(hi, setup.stock_max[:2]), setup.stock_max[2]]),
                                  floor_z=max(upper, float(setup.floor_z)))
    op = raster_finishing(part, shallow, tool, cutting, options, progress=progress, stock=stock, limit=limit,
                          within=within)
    return dataclasses.replace(op, name="finish raster upper") if len(op.points) > 1 else None
