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

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from cadcam.heightmap import grid_over, upper_envelope
from cadcam.model import Setup, Tool

#: Grid spacing of the estimate [mm]: features narrower than this do not change the choice.
_CELL = 0.5


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
    """

    tool: Tool
    reach_volume: float
    removal_volume: float

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


def tool_fits(triangles: np.ndarray, setup: Setup, tools: list[Tool], allowance: float = 0.3) -> list[ToolFit]:
    """The stock each of ``tools`` (flat or bull-nose, taken as flat) can reach and enter [mm^3].

    Parameters
    ----------
    triangles : (n, 3, 3) float
        The part in work coordinates [mm].
    setup : Setup
    tools : list of Tool
    allowance : float
        Roughing allowance [mm].

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
    out = []
    for tool in tools:
        disc = _disc(entry_radius(tool, allowance))
        # Outside the stock there is air: the tool may stand there down to the floor.
        stop = ndimage.maximum_filter(part, footprint=disc, mode="constant", cval=bottom)
        reached = ndimage.minimum_filter(stop, footprint=disc, mode="constant", cval=bottom)
        out.append(ToolFit(tool, float(np.sum(top - np.maximum(reached, part)) * area), removal))
    return out


def removal_rate(tool: Tool, feed: float) -> float:
    """Metal removal rate of z-level roughing with ``tool`` at its default engagement [mm^3/min].

    Stepover 0.4 D and stepdown min(0.5 D, flute length), as :class:`cadcam.roughing.RoughingOptions`.
    """
    return feed * 0.4 * tool.diameter * min(0.5 * tool.diameter, tool.flute_length)

