"""From a part in work coordinates to a :class:`~cadcam.model.Job`: choose tools, order operations.

The strategy is the one a machinist would program by hand for a single top-side setup:
z-level roughing with a flat end mill, leaving an even allowance, then finishing with a
ball end mill: waterline loops on steep walls and a raster (zigzag) drop-cutter pass on
shallow areas.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import trimesh

from cadcam.finishing import FinishingOptions, raster_finishing, waterline_finishing
from cadcam.model import Job, Operation, Setup, Tool
from cadcam.roughing import RoughingOptions, zlevel_roughing
from cadcam.tools import ToolLibrary
from cadcam.verify import stock_after
from factory.errors import ToolError

log = logging.getLogger(__name__)

#: ``progress(stage, done, total)``: which operation is being computed and how far it is.
StageProgress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class PlanOptions:
    """What to cut with and how.

    Attributes
    ----------
    rough_tool : int
        Tool number of the roughing end mill (must be flat or bull-nose).
    finish_tool : int
        Tool number of the finishing end mill (ball, bull-nose or flat).
    roughing : RoughingOptions
    finishing : FinishingOptions
    waterline : bool
        Finish steep walls with waterline loops (otherwise the raster covers everything).
    """

    rough_tool: int = 1
    finish_tool: int = 3
    roughing: RoughingOptions = field(default_factory=RoughingOptions)
    finishing: FinishingOptions = field(default_factory=FinishingOptions)
    waterline: bool = True

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class PlanTimings:
    """Wall time per operation computed [s], in cutting order."""

    seconds: tuple[tuple[str, float], ...]


def _checked_tool(library: ToolLibrary, number: int, part_depth: float, role: str) -> Tool:
    tool = library.tool(number)
    if role == "roughing" and tool.shape == "ball":
        raise ToolError(
            f"T{number} is a ball end mill; roughing needs a flat or bull-nose end mill",
            source=library.source,
        )
    if tool.length < part_depth:
        raise ToolError(
            f"T{number} reaches {tool.length:g} mm below the holder but the stock is "
            f"{part_depth:g} mm deep: the holder would hit the part",
            source=library.source,
        )
    return tool


def plan_job(
    part: trimesh.Trimesh,
    setup: Setup,
    library: ToolLibrary,
    *,
    part_name: str,
    source_sha256: str = "",
    options: PlanOptions = PlanOptions(),
    progress: StageProgress | None = None,
) -> tuple[Job, PlanTimings]:
    """Compute the operations that cut ``part`` out of the stock described by ``setup``.

    Parameters
    ----------
    part : trimesh.Trimesh
        Watertight part mesh in work coordinates [mm] (see :func:`cadcam.setup.make_setup`).
    setup : Setup
    library : ToolLibrary
        Tools and cutting data; ``setup.material`` selects the cutting data.
    part_name : str
        Name for the program and comments.
    options : PlanOptions
    progress : callable, optional
        ``progress(stage, done, total)`` for long operations.

    Returns
    -------
    job : Job
        Roughing, then waterline (if any steep walls) and raster finishing.
    timings : PlanTimings
        Wall time spent computing each operation [s].

    Raises
    ------
    ToolError
        A named tool is missing, unfit for its role, or too short for the stock.
    ToolpathError
        An operation cannot be computed.
    """
    depth = float(setup.stock_size[2])
    rough_tool = _checked_tool(library, options.rough_tool, depth, "roughing")
    finish_tool = _checked_tool(library, options.finish_tool, depth, "finishing")

    def stage_progress(stage: str):
        if progress is None:
            return None
        return lambda done, total: progress(stage, done, total)

    rough_cutting = library.cutting_data(rough_tool, setup.material)
    finish_cutting = library.cutting_data(finish_tool, setup.material)
    raster_options = options.finishing
    if not options.waterline:
        # Without waterline the raster must cover steep walls too.
        raster_options = dataclasses.replace(raster_options, steep_angle=90.0)

    seconds: list[tuple[str, float]] = []

    def timed(stage: str, compute: Callable[[], Operation]) -> Operation:
        t0 = time.perf_counter()
        op = compute()
        seconds.append((stage, time.perf_counter() - t0))
        return op

    rough = timed("roughing", lambda: zlevel_roughing(part, setup, rough_tool, rough_cutting, options.roughing,
                                                       progress=stage_progress("roughing")))
    # What roughing left lets finishing descend by rapid through air instead of feeding from safe_z.
    t0 = time.perf_counter()
    stock = stock_after([rough], setup, np.asarray(part.triangles)) if len(rough.points) > 1 else None
    seconds.append(("stock model", time.perf_counter() - t0))
    operations = [rough]
    if options.waterline:
        operations.append(timed("waterline", lambda: waterline_finishing(
            part, setup, finish_tool, finish_cutting, options.finishing,
            progress=stage_progress("waterline"), stock=stock)))
    operations.append(timed("raster", lambda: raster_finishing(
        part, setup, finish_tool, finish_cutting, raster_options, progress=stage_progress("raster"), stock=stock)))
    dropped = [op.kind for op in operations if len(op.points) < 2]
    if dropped:
        log.info("nothing to cut for %s: dropped", ", ".join(dropped))
    operations = [op for op in operations if len(op.points) >= 2]

    job = Job(
        part_name=part_name,
        setup=setup,
        operations=tuple(operations),
        source_sha256=source_sha256,
        parameters=options.to_dict(),
    )
    return job, PlanTimings(tuple(seconds))
