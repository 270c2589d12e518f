"""Finish the flat faces and the walls of a part with a flat end mill, at their exact heights.

What a machinist does on prismatic work instead of running a ball over everything: each
flat face (pocket floor, step top, boss top) is cleared by a flat end mill standing on it,
at wide stepover, and each wall is cut by the flank of the same tool in a contour pass,
with as few passes down the wall as the flute length allows.

The passes are z-level clearing (:func:`cadcam.roughing.zlevel_roughing`) run as rest
machining over the stock earlier operations left, with:

* **levels** at every flat face's height (plus a hair, :attr:`FlatFinishOptions.allowance`,
  so that the face itself does not block the tool) and at most a flute length apart down
  the walls;
* **stepover** :data:`FLOOR_STEPOVER` of the diameter on the floors (the loops z-level clearing adds where that
  would leave islands cut them) and no allowance on walls: the outermost loop of each level's
  region follows the walls above it at exactly the tool radius, a flank pass over the whole
  height between two levels;
* **where**: only within reach of the flat and wall faces (:mod:`cadcam.faces`), and only
  where the stock still holds more than ``rest_above`` over the part. Freeform surfaces are
  left to the ball end mill, and what this tool cannot reach to a narrower one;
* **not** into what no tool reaches: with an engagement limit, no level comes nearer the stock
  left deeper than the limit over the part (a sharp inside corner the narrowest tool could not
  rest-rough, which the planner reports unreached) than it may cut of it. The flank pass would
  otherwise take that sliver's whole height at once.

The operation's kind is ``finishing``: ``factory verify`` holds it to the finishing depth.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh
from shapely.geometry.base import BaseGeometry

from cadcam import roughing
from cadcam.faces import FLAT, WALL, FaceClasses
from cadcam.finishing import EngagementLimit
from cadcam.gridregion import grown_cells_region
from cadcam.model import CuttingData, Operation, Setup, Tool
from cadcam.rest import deep_stock
from cadcam.roughing import RoughingOptions, zlevel_roughing
from cadcam.stock import Simulation, excess
from factory.core.errors import ToolError


#: Default stepover of floor finishing, a share of the diameter. A flat end mill's flat bottom leaves no cusp
#: at any step under its diameter; 0.85 still overlaps the last loop by 0.15 D (1.5 mm on a 10 mm tool) and takes
#: a floor in fewer loops than a machinist's customary 60-75 % (issue 32: bracket's floors 33.6 -> 31.9 s, its
#: finishing rapids 18.0 -> 15.8 s). A shallow cut, so any width of it is within the library's limits.
FLOOR_STEPOVER = 0.85
#: Stock closer than this beside a wall [mm] is the hair the finishing allowance and the stock
#: model's sampling leave (a grid point a micron off a finished wall reads as the whole wall's
#: height), not a skin to finish: well under roughing's allowance, well over the finishing one.
WALL_HAIR = 0.05
#: Widest stepover taken, a share of the diameter: the gaps between loops grow towards a full diameter.
_MOST_STEPOVER = 0.9


@dataclass(frozen=True)
class FlatFinishOptions:
    """How the flats and walls are finished.

    Attributes
    ----------
    allowance : float
        Stock left on floors and walls [mm]: a hair above zero so that a floor does not
        shadow the tool standing on it; well below any finishing tolerance.
    rest_above : float
        Stock over the part thinner than this is taken as finished [mm].
    stepover : float, optional
        Radial step between loops [mm]; default :data:`FLOOR_STEPOVER` of the diameter, at most 90 %
        of it.
    ramp_angle : float
        Helix and ramp entries [deg].
    spring_pass : bool
        Run each level's wall (outermost) loops a second time at the same size, so the walls
        come to size where the tool deflected. Default off.
    """

    allowance: float = 0.005
    rest_above: float = 0.02
    stepover: float | None = None
    ramp_angle: float = 3.0
    spring_pass: bool = False


def left_on_flats_and_walls(stock: Simulation, faces: FaceClasses, reach: float, allowance: float,
                            above: float, leave: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """(ny, nx) bool: grid points within ``reach`` [mm] of a flat or a wall where ``stock`` holds
    more than ``above`` [mm] over the part grown by ``allowance`` [mm].

    Without the grid slack of :func:`cadcam.rest.excess`: the skin roughing leaves on a wall is
    thinner than a cell diagonal, and it is what this finishing is for. Grid points within
    :data:`WALL_HAIR` of a wall are not counted: what they hold is the finishing allowance; nor
    those ``leave(xy) -> (m,) bool`` holds (another tool finishes there), given ``leave``.
    """
    g = stock.grid
    x = g.x0 + g.cell * np.arange(g.nx)
    y = g.y0 + g.cell * np.arange(g.ny)
    X, Y = np.meshgrid(x, y)
    xy = np.column_stack([X.ravel(), Y.ravel()])
    near = faces.near((FLAT, WALL), reach)(xy).reshape(X.shape)
    near &= ~faces.near((WALL,), WALL_HAIR)(xy).reshape(X.shape)
    if leave is not None:
        near &= ~leave(xy).reshape(X.shape)
    return near & (excess(stock, allowance, grid_slack=False) > above)


def _target(stock: Simulation, left: np.ndarray) -> Simulation:
    """A stand-in stock whose rest material (:func:`cadcam.rest.rest_material`) is exactly ``left``.

    The part is taken away (its top ``-inf``) so that the rest test sees every such point as
    excess; the real stock and part still bound the cutting (the mesh) and the entries (``air``).
    """
    top = np.where(left, stock.stock_top, -np.inf)
    part = np.full_like(top, -np.inf)
    top.setflags(write=False)
    part.setflags(write=False)
    return dataclasses.replace(stock, stock_top=top, part_top=part)


def flat_wall_finishing(
    part: trimesh.Trimesh,
    setup: Setup,
    tool: Tool,
    cutting: CuttingData,
    faces: FaceClasses,
    stock: Simulation,
    options: FlatFinishOptions = FlatFinishOptions(),
    progress: Callable[[int, int], None] | None = None,
    cut_before: Callable[[float], BaseGeometry] | None = None,
    stepdown: float | None = None,
    within: Callable[[float], BaseGeometry] | None = None,
    limit: EngagementLimit | None = None,
    unreached_in: Simulation | None = None,
    leave: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Operation:
    """Floors at their heights and walls by the flank, with the flat end mill ``tool``.

    Parameters
    ----------
    part : trimesh.Trimesh
        Watertight part in work coordinates [mm].
    setup : Setup
    tool : Tool
        A flat end mill.
    cutting : CuttingData
    faces : FaceClasses
        The part's faces by kind (:func:`cadcam.faces.classify_faces`).
    stock : Simulation
        The stock the earlier operations left.
    options : FlatFinishOptions
    progress : callable, optional
    cut_before : callable, optional
        The holes cut to size by level (:func:`cadcam.roughing.zlevel_roughing`'s): no warning there.
    stepdown : float, optional
        Most a level may lie below the one above it [mm]; default the flute length (a wall's skin
        is a side cut). A tool after a wider one meets the inside corners that one left at full
        width: the planner steps it down by its axial limit (:attr:`cadcam.model.Tool.full_width_limit`).
    within : callable, optional
        ``within(radius)``: where the tool's axis may go (the jaws' keep-out,
        :func:`cadcam.workholding.jaw_keepout`); what lies outside it is left.
    limit : EngagementLimit, optional
        With it, no level's tool comes within reach of the stock that lies more than ``limit.depth``
        [mm] over the part (:func:`cadcam.rest.deep_stock`) and reaches more than that above the level:
        what no tool reaches (:func:`cadcam.stock.unreached`, which the planner warns of) is left alone.
    unreached_in : Simulation, optional
        The stock model that deep stock is read from; default ``stock``. The planner gives the model it
        reported the unreached stock from, so that what it says finishing leaves alone is what it leaves.
    leave : callable, optional
        ``leave(xy) -> (m,) bool``: XY [mm] where another tool finishes (a ball on the freeform
        surfaces): the skin there is not this tool's (:func:`left_on_flats_and_walls`).

    Returns
    -------
    Operation
        ``kind="finishing"``, empty if no flat or wall is left to finish.

    Raises
    ------
    ToolError
        The tool is not a flat end mill.
    """
    if tool.shape != "flat":
        raise ToolError(f"T{tool.number} is a {tool.shape} end mill; flats and walls need a flat one")
    wide = FLOOR_STEPOVER * tool.diameter if options.stepover is None else float(options.stepover)
    stepover = min(wide, _MOST_STEPOVER * tool.diameter)
    level = tool.flute_length if stepdown is None else min(float(stepdown), tool.flute_length)
    rough = RoughingOptions(stepdown=level, stepover=stepover, allowance=options.allowance,
                            ramp_angle=options.ramp_angle, spring_pass=options.spring_pass)
    # A grid cell of margin: the stock beside a wall lies in the cells next to it.
    left = left_on_flats_and_walls(stock, faces, tool.radius + 2 * stock.grid.cell, options.allowance,
                                   options.rest_above, leave)
    if not left.any():
        return Operation(f"finish flats+walls T{tool.number}", "finishing", tool, cutting, np.zeros((0, 3)),
                         np.zeros(0), options.allowance)
    keep_off = None
    if limit is not None:
        deep = deep_stock(stock if unreached_in is None else unreached_in, limit.depth, limit.allowance,
                          limit.grid_slack)
        keep_off = _keep_off(deep, part, setup, tool, rough, limit.depth)
    op = zlevel_roughing(part, setup, tool, cutting, rough, progress=progress, rest=_target(stock, left),
                         rest_above=0.0, air=stock, cut_before=cut_before, within=within, exclude=keep_off)
    return dataclasses.replace(op, name=f"finish flats+walls T{tool.number}", kind="finishing")


def _keep_off(deep: Simulation, part: trimesh.Trimesh, setup: Setup, tool: Tool, options: RoughingOptions,
              depth: float) -> Callable[[int], BaseGeometry | None] | None:
    """``exclude(i)`` for :func:`cadcam.roughing.zlevel_roughing`: the tool axis positions [mm] where its
    level ``i`` would cut more than ``depth`` [mm] of the ``deep`` stock; None when there is none.

    A grid point's stock may reach anywhere within a cell diagonal of it (as
    :func:`cadcam.stock.clear_height` takes it), so the axis keeps the tool radius and a diagonal off.
    The levels are the ones z-level clearing computes (rest machining keeps a prefix of them), as
    :mod:`cadcam.adaptive` reads them too.
    """
    present = np.isfinite(deep.stock_top)
    if not present.any():
        return None
    levels = roughing._levels(part, setup, roughing._resolve(options, tool, setup))
    grow = tool.radius + deep.grid.cell * math.sqrt(2.0)
    regions: dict[bytes, BaseGeometry] = {}  # levels under the same deep stock share a region

    def excluded(index: int) -> BaseGeometry | None:
        if not 0 <= index < len(levels):
            return None
        mask = present & (deep.stock_top > float(levels[index]) + depth)
        if not mask.any():
            return None
        key = np.packbits(mask).tobytes()
        if key not in regions:
            regions[key] = grown_cells_region(mask, deep.grid, grow)
        return regions[key]

    return excluded
