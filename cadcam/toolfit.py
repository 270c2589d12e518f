"""Which roughing end mill fits the part: the stock each one can reach, and the time it takes.

A flat end mill of radius ``r`` going down a vertical line stops on the highest part
material within ``r`` of its axis: on a height map that is a grey dilation of the part's
top by a disc. The stock the tool can remove anywhere is what lies above the lowest of
those stops among the placements covering a point: the grey *opening* of the part's top.
A pocket is only roughed if the tool can enter it, by a helix of at least
``0.15 D`` radius around an axis kept ``allowance`` off the walls: the disc tested is grown by
both (:func:`entry_radius`). With that, a machinist's choice is a sum: the widest tool clears what it reaches at its
own removal rate, and the narrowest reaching tool clears the rest at its rate (rest
roughing); the tool with the least total is the one to rough with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from cadcam.heightmap import grid_over, upper_envelope
from cadcam.model import CuttingData, Setup, Tool

#: Grid spacing of the estimate [mm]: features narrower than this do not change the choice.
_CELL = 0.5
#: Helix entry angle of z-level roughing [deg] (:class:`cadcam.roughing.RoughingOptions` default).
_RAMP_DEG = 3.0


@dataclass(frozen=True)
class ToolFit:
    """How much of the stock one end mill reaches.

    Attributes
    ----------
    tool : Tool
    reach_volume : float
        Stock volume the tool can remove without touching the part [mm^3].
    removal_volume : float
        All the stock above the part (and above the stock bottom where there is no part) [mm^3].
    level_area : float
        The area the tool clears summed over its z-level roughing levels [mm^2]: the levels one
        stepdown (min(0.5 D, flute length)) apart from the stock top to the floor, and one at each
        flat face of the part (plus the allowance), as :func:`cadcam.roughing.zlevel_roughing` cuts.
    entry_depth : float
        The depth the tool descends by helix over all levels [mm]: at each level, each region it clears
        there that does not reach the stock's side (where it comes in from the air), the level's depth.
    terrace_area : float
        The area the tool clears again between its levels [mm^2]: where a level leaves more than
        ``terrace_above`` over the part, one pass per ``terrace_stepdown`` of it (:func:`tool_fits`).
    """

    tool: Tool
    reach_volume: float
    removal_volume: float
    level_area: float = 0.0
    entry_depth: float = 0.0
    terrace_area: float = 0.0

    def roughing_minutes(self, cutting: CuttingData) -> float:
        """Z-level roughing time of this tool's share [min]: every level's area cleared at the default
        stepover (:attr:`~cadcam.model.Tool.level_stepover`), at the cutting feed (so a level the part's
        flats add costs as much as one of the stepdown's), and every closed region entered by a helix at the
        default 3 degrees at the plunge feed (:class:`cadcam.roughing.RoughingOptions`): a wide tool's deep
        levels take long to enter."""
        cutting_min = (self.level_area + self.terrace_area) / (self.tool.level_stepover * cutting.feed)
        return cutting_min + self.entry_depth / math.tan(math.radians(_RAMP_DEG)) / cutting.plunge_feed

    @property
    def share(self) -> float:
        """Share of the stock to remove that this tool reaches, in [0, 1]."""
        return self.reach_volume / self.removal_volume if self.removal_volume > 0 else 1.0


def entry_radius(tool: Tool, allowance: float) -> float:
    """Radius of the narrowest round pocket z-level roughing enters with ``tool`` [mm]:
    the tool, the allowance and the smallest helix (:class:`cadcam.roughing.RoughingOptions`)."""
    return tool.radius + allowance + 0.15 * tool.diameter


def _disc(radius: float) -> np.ndarray:
    k = max(int(np.ceil(radius / _CELL)), 0)
    di, dj = np.meshgrid(np.arange(-k, k + 1), np.arange(-k, k + 1))
    return np.hypot(di, dj) * _CELL <= radius + 1e-9


def tool_fits(triangles: np.ndarray, setup: Setup, tools: list[Tool], allowance: float = 0.3, *,
              terrace_above: float = 1.5, terrace_stepdown: float = 0.7) -> list[ToolFit]:
    """The stock each of ``tools`` (flat or bull-nose, taken as flat) can reach and enter [mm^3].

    Parameters
    ----------
    triangles : (n, 3, 3) float
        The part in work coordinates [mm].
    setup : Setup
    tools : list of Tool
    allowance : float
        Roughing allowance [mm].
    terrace_above, terrace_stepdown : float
        Where a level leaves more than ``terrace_above`` over the part, the roughing tool steps down
        again between its levels by ``terrace_stepdown`` [mm] (:class:`cadcam.plan.PlanOptions`'s
        ``finish_engagement`` and ``terrace_stepdown``).

    Returns
    -------
    list of ToolFit
        In the order of ``tools``.
    """
    grid = grid_over(setup.stock_min, setup.stock_max, _CELL)
    # op 1 removes nothing below its floor: the holding allowance stays for op 2
    bottom = float(setup.floor_z)
    top = float(setup.stock_max[2])
    part = upper_envelope(np.asarray(triangles, dtype=np.float64), grid)
    part = np.maximum(np.where(np.isfinite(part), part, bottom), bottom)
    area = _CELL * _CELL
    removal = float(np.sum(top - part) * area)
    flats = _flat_levels(np.asarray(triangles, dtype=np.float64), allowance, bottom, top)
    out = []
    for tool in tools:
        disc = _disc(entry_radius(tool, allowance))
        # Outside the stock there is air: the tool may stand there down to the floor.
        stop = ndimage.maximum_filter(part, footprint=disc, mode="constant", cval=bottom)
        reached = np.maximum(ndimage.minimum_filter(stop, footprint=disc, mode="constant", cval=bottom), part)
        stepdown = tool.level_stepdown
        levels = np.union1d(top - stepdown * np.arange(1, int(np.ceil((top - bottom) / stepdown - 1e-9)) + 1), flats)
        levels = np.unique(np.maximum(levels, bottom))[::-1]
        cleared, entries = 0, 0.0
        above = top
        for z in levels:
            at = reached <= z + 1e-6  # the columns the tool goes down to this level in
            cleared += int(at.sum())
            labels, n = ndimage.label(at)
            side = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
            entries += (n - int(np.count_nonzero(side))) * (above - z)
            above = z
        # what the levels leave over each column, and the terrace passes that takes
        ascending = levels[::-1]
        k = np.searchsorted(ascending, reached + allowance - 1e-6)
        cut_at = np.where(k < len(ascending), ascending[np.minimum(k, len(ascending) - 1)], top)
        left = cut_at - (reached + allowance)
        passes = np.where(left > terrace_above, np.floor(left / terrace_stepdown), 0.0)
        out.append(ToolFit(tool, float(np.sum(top - reached) * area), removal, float(cleared * area), entries,
                           float(passes.sum() * area)))
    return out


def _flat_levels(triangles: np.ndarray, allowance: float, bottom: float, top: float) -> np.ndarray:
    """Heights of the part's upward flat faces plus ``allowance``, between ``bottom`` and ``top`` [mm]."""
    if not len(triangles):
        return np.zeros(0)
    n = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    length = np.linalg.norm(n, axis=1)
    up = length > 0
    up[up] = n[up, 2] / length[up] > 1.0 - 1e-6
    z = np.unique(np.round(triangles[up, :, 2].mean(axis=1) + allowance, 3))
    return z[(z > bottom + 1e-6) & (z < top - 1e-6)]


def removal_rate(tool: Tool, feed: float) -> float:
    """Metal removal rate of z-level roughing with ``tool`` at its default engagement [mm^3/min].

    The tool's :attr:`~cadcam.model.Tool.level_stepover` and :attr:`~cadcam.model.Tool.level_stepdown`, as
    :class:`cadcam.roughing.RoughingOptions`.
    """
    return feed * tool.level_stepover * tool.level_stepdown

