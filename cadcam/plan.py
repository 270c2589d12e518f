"""From a part in work coordinates to a :class:`~cadcam.model.Job`: choose tools, order operations.

The strategy is the one a machinist would program by hand for a single top-side setup:
z-level roughing with a flat end mill, leaving an even allowance, rest roughing with
narrower flat end mills where it could not go, then finishing by the kind of face
(:mod:`cadcam.faces`): flat faces at their exact heights and walls by the flank, with the
widest flat end mill and then narrower ones where it did not fit (:mod:`cadcam.flatfinish`);
a ball end mill only on freeform surfaces, waterline loops on steep ones and a raster
(zigzag) drop-cutter pass on shallow ones. The roughing end mill is the one that clears the
stock soonest with rest roughing counted (:mod:`cadcam.toolfit`). Finishing never enters
stock the roughing left deeper than a set engagement; what no tool reaches is reported.
Every rapid is checked against the in-process stock.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np
import trimesh

from cadcam.adaptive import AdaptiveOptions, adaptive_roughing
from cadcam.adaptive_rest import adaptive_rest_roughing
from cadcam.drilling import DrillingOptions, Hole, HolePlan, plan_holes
from cadcam.faces import SHALLOW, STEEP, FaceClasses, classify_faces
from cadcam.finishing import EngagementLimit, FinishingOptions, raster_finishing, waterline_finishing
from cadcam.chipfeed import CHIP_CELL, chip_fed, chip_feeds
from cadcam.flatfinish import WALL_HAIR, FlatFinishOptions, flat_wall_finishing, left_on_flats_and_walls
from cadcam.model import CuttingData, Job, Operation, Setup, Tool
from cadcam.relief import Boundary, keep_outside
from cadcam.rest import safe_rapids
from cadcam.roughing import RoughingOptions, part_shadows, zlevel_roughing
from cadcam.shank_clearance import upper_raster
from cadcam.toolfit import removal_rate, tool_fits
from cadcam.tools import ToolLibrary
from cadcam.stock import (FlippedStock, OperationsCut, Simulation, Unreached, excess, stock_after, stock_after_flipped,
                          unreached)
from cadcam.workholding import jaw_keepout, within_both
from factory.core.errors import ToolError
from factory.core.progress import held_open

T = TypeVar("T")

log = logging.getLogger(__name__)

#: ``progress(stage, done, total)``: which operation is being computed and how far it is.
StageProgress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class PlanOptions:
    """What to cut with and how.

    Attributes
    ----------
    rough_tool : int, optional
        Tool number of the roughing end mill (must be flat or bull-nose). None: chosen from
        the library by reach and size (:func:`choose_tools`).
    finish_tool : int, optional
        Tool number of the finishing end mill (ball, bull-nose or flat). None: chosen.
    roughing : RoughingOptions
    adaptive : AdaptiveOptions or None
        Deep constant-engagement cuts where they are faster than levels (:func:`cadcam.adaptive.adaptive_roughing`);
        None: levels only.
    finishing : FinishingOptions
    waterline : bool
        Finish steep walls with waterline loops (otherwise the raster covers everything).
    rest_roughing : bool
        Rough what the roughing tool could not reach (narrow slots, small pockets and holes)
        with the next smaller flat end mills of the library, from the in-process stock.
    finish_engagement : float
        Deepest a finishing move may cut into the stock earlier operations left [mm]:
        finishing never descends where more than this is left above the part; such places
        are reported as unreached (``Job.parameters["unreached"]``).
    terrace_stepdown : float
        Z-level roughing leaves terraces up to a stepdown high on shallow surfaces. Where more
        than ``finish_engagement`` is left, the roughing tool steps down again between its levels
        by this much [mm], so that the finishing tool meets at most about this plus the allowance.
    holes : bool
        Drill round holes (spot, G81/G83) and helix those no drill and no roughing tool
        fits, before roughing (:func:`cadcam.drilling.plan_holes`).
    drilling : DrillingOptions
    by_faces : bool
        Finish by the kind of face (:mod:`cadcam.faces`): flats and walls with flat end mills
        (:mod:`cadcam.flatfinish`), the ball only on freeform surfaces. False: the ball finishes
        everything.
    flat_finish : FlatFinishOptions
    freeform_scallop : float, optional
        With ``by_faces``: the scallop the ball leaves on freeform surfaces [mm] (its raster
        stepover and waterline stepdown follow from it), half the 0.02 mm a finished surface
        may keep; None: ``finishing.scallop``.
    """

    rough_tool: int | None = None
    finish_tool: int | None = None
    roughing: RoughingOptions = field(default_factory=RoughingOptions)
    adaptive: AdaptiveOptions | None = field(default_factory=AdaptiveOptions)
    finishing: FinishingOptions = field(default_factory=FinishingOptions)
    waterline: bool = True
    rest_roughing: bool = True
    finish_engagement: float = 1.5
    terrace_stepdown: float = 0.7
    holes: bool = True
    drilling: DrillingOptions = field(default_factory=DrillingOptions)
    by_faces: bool = True
    flat_finish: FlatFinishOptions = field(default_factory=FlatFinishOptions)
    freeform_scallop: float | None = 0.01

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class PlanTimings:
    """Wall time per operation computed [s], in cutting order."""

    seconds: tuple[tuple[str, float], ...]


def _checked_tool(library: ToolLibrary, number: int, part_depth: float, role: str) -> Tool:
    tool = library.tool(number)
    if tool.is_drill:
        raise ToolError(f"T{number} is a drill; {role} needs an end mill", source=library.source)
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


#: A roughing end mill wider than this share of the stock's narrower side leaves most of the
#: part's detail to rest roughing; below it, the widest end mill removes stock fastest.
_ROUGH_SHARE_OF_WIDTH = 0.1


def choose_tools(library: ToolLibrary, setup: Setup, options: PlanOptions,
                 part_triangles: np.ndarray | None = None) -> tuple[Tool, Tool]:
    """The roughing and finishing tools: the options' numbers, or chosen by reach and size.

    Every tool must reach from the stock top down to the floor (``setup.floor_z``) with its
    stick-out (``Tool.length``), or the holder would hit the part; of those that do, a long-reach
    end mill only when no standard one does (:func:`by_need`). Roughing, given the part: the
    end mill that roughs it soonest (:func:`_pick_rough_by_fit`); without it, the
    widest flat (else bull-nose) end mill no wider than a tenth of the stock's narrower side, or
    the narrowest one that reaches if all are wider.
    Finishing: the widest ball end mill that reaches and is no wider than the roughing tool
    (so it fits wherever roughing went), else the narrowest reaching ball, else a reaching
    bull-nose, else a flat end mill.

    Raises
    ------
    ToolError
        A named tool is missing, unfit or too short; or no tool in the library reaches the
        depth for a role (naming the depth and the longest tool there is).
    """
    # the deepest feed: down to the setup's floor (the holding allowance below it stays uncut)
    depth = float(setup.stock_max[2] - setup.floor_z)
    if options.rough_tool is not None:
        rough = _checked_tool(library, options.rough_tool, depth, "roughing")
    elif part_triangles is not None:
        rough = _pick_rough_by_fit(library, setup, depth, part_triangles, options)
    else:
        rough = _pick_rough(library, setup, depth)
    if options.finish_tool is not None:
        finish = _checked_tool(library, options.finish_tool, depth, "finishing")
    else:
        finish = _pick_finish(library, depth, rough)
    return rough, finish


def deepest_reach(library: ToolLibrary, freeform: bool = False) -> float:
    """How deep below the stock top one setup can machine with ``library`` [mm]: the longest stick-out
    (``Tool.length``, holder clear of the stock top) of a flat or bull-nose end mill, which roughs and
    finishes flats and walls; with ``freeform`` surfaces to finish, no deeper than the longest ball
    reaches too (when the library has a ball). 0 when it has no flat or bull-nose end mill."""
    mills = [t.length for t in library.tools if t.shape in ("flat", "bull")]
    reach = max(mills, default=0.0)
    balls = [t.length for t in library.tools if t.shape == "ball"]
    if freeform and balls:
        reach = min(reach, max(balls))
    return float(reach)


@dataclass(frozen=True)
class DepthSplit:
    """How the depth of a setup divides between what its tools reach from the top and what is left below.

    Attributes
    ----------
    setup : Setup
        The setup with its floor (``floor_z``) no deeper than the tools reach [mm].
    reach : float
        Deepest reach below the stock top [mm] (:func:`deepest_reach`).
    wanted_floor : float
        The floor the setup asked for [mm]; ``setup.floor_z`` above it when the tools fall short.
    """

    setup: Setup
    reach: float
    wanted_floor: float

    @property
    def short(self) -> float:
        """How much of the asked depth the tools do not reach [mm]; 0 when they reach it all."""
        return float(self.setup.floor_z - self.wanted_floor)


def split_depth(setup: Setup, library: ToolLibrary, freeform: bool = False) -> DepthSplit:
    """``setup`` with its floor raised to what the library reaches from the top (:func:`deepest_reach`).

    A part deeper than the longest tool is machined from the top down to that reach; what lies below is
    left for the other side (op 2, turned over, :mod:`cadcam.op2`). A setup whose floor the tools reach
    is returned unchanged.
    """
    wanted = float(setup.floor_z)
    reach = deepest_reach(library, freeform)
    top = float(setup.stock_max[2])
    if reach <= 0 or top - wanted <= reach + 1e-9:
        return DepthSplit(setup, reach, wanted)
    return DepthSplit(dataclasses.replace(setup, floor_z=top - reach), reach, wanted)


def _missing(library: ToolLibrary, what: str, depth: float, tools: list[Tool]) -> ToolError:
    longest = max(tools, key=lambda t: t.length, default=None)
    have = f"; the longest is T{longest.number} with {longest.length:g} mm" if longest else ""
    return ToolError(f"no {what} in the library reaches the stock depth {depth:g} mm below its holder{have}",
                     source=library.source)


def _pick_rough(library: ToolLibrary, setup: Setup, depth: float) -> Tool:
    mills = [t for t in library.tools if t.shape in ("flat", "bull")]
    reach = by_need(library, [t for t in mills if t.length >= depth])
    if not reach:
        raise _missing(library, "flat or bull-nose end mill for roughing", depth, mills)
    width = float(min(setup.stock_size[0], setup.stock_size[1]))
    fit = [t for t in reach if t.diameter <= _ROUGH_SHARE_OF_WIDTH * width]
    if fit:
        return max(fit, key=lambda t: (t.diameter, t.shape == "flat", -t.number))
    return min(reach, key=lambda t: (t.diameter, t.shape != "flat", t.number))


#: How much faster [share] a roughing end mill's estimate must be than a narrower one's to be chosen over it.
_WIDER_MARGIN = 0.1
#: Widest roughing end mill by fit, as a share of the stock's narrower side: a wider one leaves the part's
#: every corner to rest tools and terraces, more than the estimate sees.
_ROUGH_MOST_OF_WIDTH = 0.4


def _pick_rough_by_fit(library: ToolLibrary, setup: Setup, depth: float, triangles: np.ndarray,
                       options: PlanOptions) -> Tool:
    """The flat (else bull-nose) end mill that roughs the part soonest, rest roughing included.

    Each candidate clears the stock it reaches (:func:`cadcam.toolfit.tool_fits`) at its removal
    rate; what only narrower flat end mills get to falls to them in turn, widest first, each at
    its own rate (rest roughing). The least total wins, unless a flat one, or a narrower one,
    comes within :data:`_WIDER_MARGIN` of it.
    """
    mills = [t for t in library.tools if t.shape in ("flat", "bull")]  # a drill does not rough
    reach = by_need(library, [t for t in mills if t.length >= depth])
    if not reach:
        raise _missing(library, "flat or bull-nose end mill for roughing", depth, mills)
    width = float(min(setup.stock_size[0], setup.stock_size[1]))
    reach = [t for t in reach if t.diameter <= _ROUGH_MOST_OF_WIDTH * width] or [min(reach, key=lambda t: t.diameter)]
    fits = {f.tool.number: f for f in tool_fits(triangles, setup, reach, options.roughing.allowance,
                                                terrace_above=options.finish_engagement,
                                                terrace_stepdown=options.terrace_stepdown)}
    cutting = {t.number: library.cutting_data(t, setup.material) for t in reach}

    def minutes(tool: Tool) -> float:
        # its own levels, then what only the narrower ones reach at their removal rates
        done, total = fits[tool.number].reach_volume, fits[tool.number].roughing_minutes(cutting[tool.number])
        for t in [r for r in rest_tools(library, tool, depth) if r.number in fits]:
            more = max(fits[t.number].reach_volume - done, 0.0)
            total += more / removal_rate(t, cutting[t.number].feed)
            done += more
        return total

    took = {t.number: minutes(t) for t in reach}
    fastest = min(took.values())
    # A wider tool leaves more in corners to terrace and rest passes than the estimate counts, a bull-nose
    # more on floors and in corners than a flat one: either has to win clearly; within the margin the
    # narrower flat one roughs.
    near = [t for t in reach if took[t.number] <= (1.0 + _WIDER_MARGIN) * fastest]
    return min(near, key=lambda t: (t.shape != "flat", t.diameter, round(took[t.number], 3), t.number))


def flat_finish_tool(library: ToolLibrary, depth: float, rough: Tool | None = None,
                     widest: float | None = None) -> Tool | None:
    """The flat end mill for flats and walls: the roughing end mill ``rough`` when it is a flat one that
    reaches (no tool change), else the widest that reaches ``depth`` [mm], no wider than ``widest`` [mm]
    if one is (narrower ones follow where it does not fit, :func:`rest_tools`); None if there is none."""
    if rough is not None and rough.shape == "flat" and rough.length >= depth:
        return rough
    fit = by_need(library, [t for t in library.tools if t.shape == "flat" and t.length >= depth])
    if widest is not None and any(t.diameter <= widest for t in fit):
        fit = [t for t in fit if t.diameter <= widest]
    return max(fit, key=lambda t: (t.diameter, t.length, -t.number)) if fit else None


def _pick_finish(library: ToolLibrary, depth: float, rough: Tool) -> Tool:
    reach = [t for t in library.tools if t.length >= depth]
    for shape in ("ball", "bull", "flat"):
        cands = by_need(library, [t for t in reach if t.shape == shape])
        fit = [t for t in cands if t.diameter <= rough.diameter]
        if fit:
            return max(fit, key=lambda t: (t.diameter, -t.number))
        if cands:
            return min(cands, key=lambda t: (t.diameter, t.number))
    raise _missing(library, "end mill for finishing", depth, list(library.tools))


def rest_tools(library: ToolLibrary, rough: Tool, depth: float | None = None) -> list[Tool]:
    """Flat end mills narrower than ``rough``, widest first: one per diameter, the longest.

    Given the ``depth`` [mm] to reach below the stock top: one per diameter that reaches most of it, of
    those the fastest (:meth:`ToolLibrary.feed_factor`), and a long-reach end mill (feed factor under 1)
    only where it reaches deeper than every standard one no wider than it (:func:`by_need`)."""
    flats = [t for t in library.tools if t.shape == "flat" and t.diameter < rough.diameter - 1e-9]
    if depth is not None:
        flats = [t for t in flats if _needed(library, t, depth, flats)]

    def rank(t: Tool) -> tuple[float, ...]:
        if depth is None:
            return (t.length,)
        return (min(t.length, depth), library.feed_factor(t), t.length)

    by_d: dict[float, Tool] = {}
    for t in flats:
        if t.diameter not in by_d or rank(t) > rank(by_d[t.diameter]):
            by_d[t.diameter] = t
    return [by_d[d] for d in sorted(by_d, reverse=True)]


def by_need(library: ToolLibrary, tools: list[Tool]) -> list[Tool]:
    """Of ``tools`` (all reaching what is asked), the standard-reach ones; the long-reach ones (feed
    factor under 1: slower, :meth:`ToolLibrary.feed_factor`) only when no standard one is among them."""
    standard = [t for t in tools if library.feed_factor(t) >= 1.0]
    return standard or tools


def _needed(library: ToolLibrary, tool: Tool, depth: float, tools: list[Tool]) -> bool:
    """A standard tool always; a long-reach one when, within ``depth`` [mm], it reaches deeper than every
    standard one of ``tools`` no wider than it (which could go wherever it goes)."""
    if library.feed_factor(tool) >= 1.0:
        return True
    standard = max((t.length for t in tools if library.feed_factor(t) >= 1.0 and t.diameter <= tool.diameter + 1e-9),
                   default=0.0)
    return min(tool.length, depth) > standard + 1e-9


@dataclass(frozen=True)
class PlanJobResult:
    """What :func:`plan_job` computed.

    Attributes
    ----------
    job : Job
        The operations in cutting order (see :func:`plan_job`).
    timings : PlanTimings
        Wall time spent computing each operation [s].
    """

    job: Job
    timings: PlanTimings


def plan_job(
    part: trimesh.Trimesh,
    setup: Setup,
    library: ToolLibrary,
    *,
    part_name: str,
    source_sha256: str = "",
    options: PlanOptions = PlanOptions(),
    progress: StageProgress | None = None,
    boundary: Boundary | None = None,
    holes: tuple[Hole, ...] | None = None,
    rapid_cell: float = 0.5,
    on_operations: Callable[[list[Operation], Setup], None] | None = None,
    on_planned: Callable[[list[Operation], Setup], None] | None = None,
) -> PlanJobResult:
    """Compute the operations that cut ``part`` out of the stock described by ``setup``.

    A part deeper than the library reaches (with neither tool named) is machined down to that reach
    (:func:`split_depth`): ``job.setup.floor_z`` is raised there, and op 2 machines the rest from below
    (:func:`cadcam.op2.plan_op2`).

    The steps, in cutting order: holes and roughing (:func:`_holes_and_roughing`), the roughing tool's terraces
    (:func:`_terraces`), all of them then fed at their chip (:func:`_feed_roughing`), rest roughing with narrower
    tools (:func:`_rest_roughing`), what no tool reaches (:func:`_unreached`), flats and walls
    (:func:`_flats_and_walls`), freeform surfaces with the ball (:func:`_freeform_finishing`),
    then every rapid made safe (:func:`_finished`).

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
    boundary : Boundary, optional
        A relief's boundary (:mod:`cadcam.relief`): every tool stays within it, and the stock
        outside what it lets the roughing tool cut counts as no excess (nothing unreached there).
    holes : tuple of Hole, optional
        The part's round holes in work coordinates when they are known exactly (a STEP file's
        B-rep, :mod:`cadcam.features`); None: drilling finds them in the mesh.
    rapid_cell : float
        Grid [mm] of the stock model every rapid is checked against with its whole cutter
        (:func:`cadcam.rest.safe_rapids`); a re-plan after verify found a rapid in stock gives verify's.
    on_operations : callable, optional
        ``on_operations(operations, setup)`` with the operations planned so far, in cutting order,
        and the setup they cut, each time more are planned and once with them all before the rapid
        check: to start work on them (their arc fitting) while the next are planned.
    on_planned : callable, optional
        Told instead of ``on_operations`` of them all before the rapid check (none follow).

    Returns
    -------
    PlanJobResult
        ``job``: roughing, rest roughing with narrower flat end mills where roughing left more
        than ``options.finish_engagement``, then waterline (if any steep walls) and raster
        finishing, which never cut deeper than ``options.finish_engagement`` into what the
        roughing left. Every rapid below the safe height clears the in-process stock with
        the whole tool (:func:`cadcam.rest.safe_rapids`). ``job.parameters["unreached"]``
        lists the stock no tool could reach (:class:`cadcam.rest.Unreached` as dicts);
        ``job.parameters["rapids"]`` how many rapids were checked and made safe.
        ``timings``: wall time spent computing each operation [s].

    Raises
    ------
    ToolError
        A named tool is missing, unfit for its role, or too short for the stock; or no
        tool in the library can rough or finish a stock this deep.
    ToolpathError
        An operation cannot be computed.
    """
    plan = _Planning.start(part, setup, library, options, progress, boundary)
    plan.on_operations, plan.on_planned = on_operations, on_planned
    holes, operations, unfed, stock = _holes_and_roughing(plan, holes)
    stock = _terraces(plan, operations, stock)
    _feed_roughing(plan, operations, unfed)
    before_rest = _BeforeRest(len(operations), stock, dict(plan.models))
    stock = _rest_roughing(plan, operations, stock)
    left = _unreached(plan, stock)
    if plan.faces is not None and stock is not None:
        stock = _flats_and_walls(plan, operations, stock, before_rest)
        if not plan.faces.freeform:
            return _finished(plan, part_name, operations, source_sha256, left, holes, rapid_cell)
    _freeform_finishing(plan, operations, stock)
    return _finished(plan, part_name, operations, source_sha256, left, holes, rapid_cell)


@dataclass
class _Planning:
    """One :func:`plan_job` call: its inputs, the tools chosen, and the clock every step reports to.

    ``seconds`` collects (stage, wall time [s]) in the order the stages ran: every stage is timed,
    so that what a plan reports is all the work it did."""

    part: trimesh.Trimesh
    setup: Setup
    library: ToolLibrary
    options: PlanOptions
    progress: StageProgress | None
    boundary: Boundary | None
    triangles: np.ndarray
    rough_tool: Tool
    finish_tool: Tool
    rough_cutting: CuttingData
    finish_cutting: CuttingData
    faces: FaceClasses | None
    #: Where roughing may go, and every tool after it (None: anywhere): see :func:`_Planning.start`.
    rough_within: Callable[[float], Any] | None
    within: Callable[[float], Any] | None
    seconds: list[tuple[str, float]]
    #: The stock an earlier setup left, turned over, on a grid of the given cell [mm]; None: a fresh block.
    turned_stock: Callable[[float], FlippedStock] | None = None
    #: ``cut_before(z)``: the XY area the holes were cut to size down to ``z`` (set once they are
    #: planned, :meth:`cadcam.drilling.HolePlan.cut_at`): a pocket there too small to enter is no loss.
    cut_before: Callable[[float], Any] | None = None
    #: The top floor's skin [mm over the allowance] the roughing may leave to the finishing (``RoughingOptions.skim``).
    skim: float = 0.0
    #: Where a tool's axis may go clear of the jaws and parallels (:func:`cadcam.workholding.jaw_keepout`,
    #: also inside ``within``): the holes and flats and walls keep to it. None: no tool can reach them.
    keepout: Callable[[float], Any] | None = None
    #: The last stock model per grid cell [mm] (before a relief's outside is kept): the next model on that
    #: grid cuts only the operations added since into it (:func:`cadcam.stock.stock_after`).
    models: dict[float, OperationsCut] = field(default_factory=dict)
    #: Where the ball finishes (:meth:`ball_finishes`), built on first use.
    _ball_area: Callable[[np.ndarray], np.ndarray] | None = None
    #: Told of the operations each time more are planned (see :func:`plan_job`); None: nobody listens.
    on_operations: Callable[[list[Operation], Setup], None] | None = None
    #: Told of them all before the rapid check (see :func:`plan_job`); None: ``on_operations`` is.
    on_planned: Callable[[list[Operation], Setup], None] | None = None

    @classmethod
    def start(cls, part: trimesh.Trimesh, setup: Setup, library: ToolLibrary, options: PlanOptions,
              progress: StageProgress | None, boundary: Boundary | None) -> "_Planning":
        """Choose the tools and classify the faces (timed as ``tools and faces``, shown as :meth:`timed` does)."""
        if progress is not None:
            progress("tools and faces", 0, 1)
        t_start = time.perf_counter()
        triangles = np.asarray(part.triangles)
        # A relief's flats include the base plane outside its boundary: the ball finishes reliefs.
        faces = classify_faces(part) if options.by_faces and boundary is None else None
        if options.rough_tool is None and options.finish_tool is None:
            # Deeper than the tools reach: down to their reach, the rest is op 2's from below.
            split = split_depth(setup, library, freeform=faces is None or bool(faces.freeform))
            if split.short > 0:
                log.warning("the stock is %.1f mm deep but the tools reach %.1f mm below their holders: op 1 "
                            "machines down to Z%.2f, op 2 the rest from below",
                            float(setup.stock_max[2]) - split.wanted_floor, split.reach, split.setup.floor_z)
            setup = split.setup
        rough_tool, finish_tool = choose_tools(library, setup, options, triangles)
        rough_cutting = library.cutting_data(rough_tool, setup.material)
        finish_cutting = library.cutting_data(finish_tool, setup.material)
        rough_within = boundary.centre_region if boundary is not None else None
        # Every later tool keeps off the wall of uncut stock the roughing tool leaves at the boundary.
        within = boundary.after_roughing(rough_tool.radius) if boundary is not None else None
        # and every tool, shank and holder off the jaws (None where none can reach them)
        keepout = jaw_keepout(setup, library.tools, shadows=lambda heights: part_shadows(part, heights))
        rough_within, within = within_both(rough_within, keepout), within_both(within, keepout)
        plan = cls(part, setup, library, options, progress, boundary, triangles, rough_tool, finish_tool,
                   rough_cutting, finish_cutting, faces, rough_within, within,
                   [("tools and faces", time.perf_counter() - t_start)], keepout=keepout)
        if progress is not None:
            progress("tools and faces", 1, 1)
        return plan

    def stage_progress(self, stage: str) -> Callable[[int, int], None] | None:
        """``progress(done, total)`` for the finer steps of ``stage`` inside :meth:`timed`: they never end
        it (:func:`factory.core.progress.held_open`), :meth:`timed` does, when all its work is done."""
        progress = held_open(self.progress)
        if progress is None:
            return None
        return lambda done, total: progress(stage, done, total)

    def timed(self, stage: str, compute: Callable[[], T]) -> T:
        """``compute()``, timed as ``stage``, which shows as it starts and ends (as a ``Stopwatch``
        stage does), also when ``compute`` reports nothing finer."""
        if self.progress is not None:
            self.progress(stage, 0, 1)
        t0 = time.perf_counter()
        result = compute()
        self.seconds.append((stage, time.perf_counter() - t0))
        if self.progress is not None:
            self.progress(stage, 1, 1)
        return result

    def ball_finishes(self) -> Callable[[np.ndarray], np.ndarray]:
        """``inside(xy) -> (m,) bool``: where the finishing ball finishes, near the freeform surfaces
        (:func:`_ball_finishes`): the short flat end mills keep off it, the ball's passes keep to it. The union
        of the faces takes seconds on a big part, so it is built once, as a stage of its own."""
        if self._ball_area is None:
            self._ball_area = self.timed("freeform area", lambda: _ball_finishes(self.faces, self.finish_tool))
        return self._ball_area

    def model(self, ops: list[Operation], cell: float | None = None) -> Simulation | None:
        """The stock ``ops`` leave on a grid of ``cell`` [mm] (default the planning model's), None before
        any cut; a relief's stock outside its boundary kept uncut."""
        cell = _MODEL_CELL if cell is None else cell
        if self.on_operations is not None:  # every stock model follows new operations
            self.on_operations(list(ops), self.setup)
        return self.timed("stock model", lambda: self._model(ops, cell))

    def _model(self, ops: list[Operation], cell: float) -> Simulation | None:
        earlier = self.models.get(cell)
        if self.turned_stock is not None:
            sim = stock_after_flipped(ops, self.setup, self.triangles, self.turned_stock(cell), cell, earlier)
        else:
            sim = (stock_after(ops, self.setup, self.triangles, cell, earlier) if any(len(op.points) > 1 for op in ops)
                   else None)
        if sim is not None:
            self.models[cell] = OperationsCut(tuple(ops), sim)
        if sim is not None and self.boundary is not None:
            sim = keep_outside(sim, self.boundary, self.rough_tool.radius)
        return sim

    def feeds_changed(self, old: list[Operation], new: list[Operation]) -> None:
        """``old`` operations are ``new`` now: the same moves at other feeds. The stock models cut on from the ones
        they hold with these in their place (feeds do not move the tool: the stock they left is the same), not
        from the block again (:func:`cadcam.stock.stock_after` cuts on only from the same objects)."""
        swap = {id(a): b for a, b in zip(old, new)}
        self.models = {cell: OperationsCut(tuple(swap.get(id(op), op) for op in cut.operations), cut.simulation)
                       for cell, cut in self.models.items()}


def _holes_and_roughing(plan: _Planning, exact: tuple[Hole, ...] | None = None
                        ) -> tuple[HolePlan | None, list[Operation], _Unfed, Simulation | None]:
    """Drilled and helixed holes, then z-level roughing; the operations (the bores and the roughing at their
    library feeds, from ``_Unfed.first`` on: :func:`_feed_roughing`) and the stock they leave.

    ``exact``: the round holes when the part came with them (work coordinates), else found in the mesh."""
    options, setup, part = plan.options, plan.setup, plan.part
    holes = plan.timed("holes", lambda: plan_holes(
        part, setup, plan.library, plan.rough_tool, options.drilling, options.roughing.min_helix_diameter,
        options.roughing.allowance, exact, within=plan.keepout) if options.holes else None)
    plan.cut_before = holes.cut_at if holes is not None else None
    # Where flat end mills finish the flats, a skin on the top floor within their engagement is theirs whole:
    # their facing pass takes 1 mm at the feed it takes 0.3 mm, and a roughing level there costs a full level.
    roughing = options.roughing if plan.faces is None else dataclasses.replace(
        options.roughing, skim=options.finish_engagement - options.roughing.allowance)
    # its links stay down on the paths cut where that is quicker: _feed_roughing feeds them through the air
    roughing = dataclasses.replace(roughing, air_feed=plan.library.max_feed)
    plan.skim = roughing.skim
    if options.adaptive is None:
        rough = plan.timed("roughing", lambda: (zlevel_roughing(
            part, setup, plan.rough_tool, plan.rough_cutting, roughing,
            progress=plan.stage_progress("roughing"), within=plan.rough_within, cut_before=plan.cut_before),))
    else:
        rough = plan.timed("roughing", lambda: adaptive_roughing(
            part, setup, plan.rough_tool, plan.rough_cutting, plan.library.max_feed, roughing,
            options.adaptive, progress=plan.stage_progress("roughing"), within=plan.rough_within,
            cut_before=plan.cut_before))
    # Drilled and helixed holes come first: the stock model below sees them. Their bores and the roughing
    # stay at their library feeds until the terraces are planned (_feed_roughing raises them all in one go).
    holes_ops = [*(holes.operations if holes is not None else ())]
    first = next((i for i, op in enumerate(holes_ops) if op.cycle is None and not op.tool.is_drill), len(holes_ops))
    # on the chip feeds' own grid: they cut on into it as it is, and the stock they leave is the planning model
    # on that grid after the roughing (_feed_roughing)
    before = plan.model(holes_ops[:first], CHIP_CELL) if first else None
    operations = [*holes_ops, *rough]
    # What roughing left lets finishing descend by rapid through air instead of feeding from safe_z.
    return holes, operations, _Unfed(first, before), plan.model(operations)


@dataclass(frozen=True)
class _Unfed:
    """Where the operations still at their library feeds begin (:func:`_feed_roughing` raises them).

    Attributes
    ----------
    first : int
        Index of the first of them in the plan's operations: the first bore (a helix after the drills), else
        the roughing.
    before : Simulation or None
        The stock the operations before ``first`` leave (the drills'), on the grid of
        :data:`cadcam.chipfeed.CHIP_CELL`; None: the block.
    """

    first: int
    before: Simulation | None


def _feed_roughing(plan: _Planning, operations: list[Operation], unfed: _Unfed) -> None:
    """Each move of the bores, the roughing and its terraces (``operations[unfed.first:]``) at the feed its chip
    allows, measured from the stock the drills leave (:func:`cadcam.chipfeed.chip_fed`), in place.

    One call for them all, once the terraces are planned (from the planning model, which feeds do not change):
    the stock it cuts them into on its grid is the planning model there after them, which the flats and walls'
    finer model cuts on from. A bore's helix round a drilled hole is a side cut, fed by
    :func:`cadcam.drilling.helix_cutting` as a slot from solid (dome_mould's 10 mm bores round 8.5 mm holes at
    F935); the roughing's links and levels run through stock the holes or the level above took, its light cuts
    round the rings faster (the full-width ones keep the library's feed); the terraces cut a terrace's skin,
    mostly narrower than the tool's full width."""
    unfed_ops = operations[unfed.first:]
    if not unfed_ops:
        return
    fed = plan.timed("chip feeds", lambda: chip_fed(unfed_ops, unfed.before, plan.setup, plan.triangles,
                                                    plan.library.max_feed))
    operations[unfed.first:] = fed.operations
    plan.feeds_changed(unfed_ops, fed.operations)
    if fed.stock is not None and plan.boundary is None:
        # the chip feeds cut them all into the drills' model on their grid (the rapid from the drills to the first
        # bore, over the stock, cuts nothing): the flats and walls' finer model cuts on from there
        plan.models[CHIP_CELL] = OperationsCut(tuple(operations), fed.stock)


def _terraces(plan: _Planning, operations: list[Operation], stock: Simulation | None) -> Simulation | None:
    """Where roughing left more than the finishing engagement: the roughing tool again between its levels, at
    a finer stepdown (the terraces), at its library feed (:func:`_feed_roughing` raises it). Appends to
    ``operations``; the stock after."""
    options, setup, part = plan.options, plan.setup, plan.part
    if not options.rest_roughing or stock is None:
        return stock
    if (excess(stock, options.roughing.allowance) > options.finish_engagement).any():
        # the terraces of the roughing levels, at a finer stepdown where more than the limit is left; not the
        # top floor's skin the roughing left to the finishing (else every terrace level contours the part to
        # meet its edge: the pocketed block of tests/cadcam/test_rest.py, -0.7 to -11.5 mm round the part)
        terraces = dataclasses.replace(options.roughing, stepdown=options.terrace_stepdown)
        op = plan.timed("terraces", lambda: zlevel_roughing(part, setup, plan.rough_tool, plan.rough_cutting, terraces,
                                                             progress=plan.stage_progress("terraces"), rest=stock,
                                                             rest_above=max(options.terrace_stepdown, plan.skim),
                                                             within=plan.within,
                                                             cut_before=plan.cut_before))
        if len(op.points) > 1:
            held = dict(plan.models)
            after = plan.model([*operations, op])
            if after is not None and bool(np.any(after.stock_top < stock.stock_top - 1e-9)):
                operations.append(op)
                return after
            # They cut nothing the model holds (plate_bosses: the 16 mm end mill grazing the gaps between its
            # bosses, which only the rest tool enters, on 20 levels: 12 s): no operation, the models as they were.
            plan.models = held
    return stock


def _rest_roughing(plan: _Planning, operations: list[Operation], stock: Simulation | None) -> Simulation | None:
    """Where roughing and its terraces left more than the finishing engagement: each narrower flat end mill in
    turn. Appends to ``operations``; the stock after."""
    options, setup, part, library = plan.options, plan.setup, plan.part, plan.library
    if not options.rest_roughing or stock is None:
        return stock
    allowance = options.roughing.allowance
    limit = options.finish_engagement
    within = plan.within
    for tool in rest_tools(library, plan.rough_tool, float(setup.stock_max[2] - setup.floor_z)):
        if not (excess(stock, allowance) > limit).any():
            break
        # The rest tool's own default stepdown and stepover (they scale with its diameter).
        rest_options = dataclasses.replace(options.roughing, stepdown=None, stepover=None, helix_diameter=None,
                                           min_helix_diameter=None)
        cutting = library.cutting_data(tool, setup.material)

        def levels(stock: Simulation) -> Operation:
            return plan.timed(f"rest T{tool.number}", lambda: zlevel_roughing(
                part, setup, tool, cutting, rest_options, progress=plan.stage_progress(f"rest T{tool.number}"),
                rest=stock, rest_above=limit, within=within, cut_before=plan.cut_before))

        op = levels(stock)
        if options.adaptive is not None and within is None and len(op.points) > 1:
            # the adaptive engine where it beats the levels (cadcam.adaptive_rest); the levels take what it leaves
            fronts = plan.timed(f"rest adaptive T{tool.number}", lambda: adaptive_rest_roughing(
                part, setup, tool, cutting, library.max_feed, stock, limit, op, rest_options, options.adaptive))
            if fronts is not None:
                operations.append(fronts)
                stock = plan.model(operations)
                op = levels(stock)
        if len(op.points) > 1:
            # its helices at the chip they cut (round a drilled hole, a side cut), its light cuts faster
            operations.append(_at_chip(plan, op, stock))
            stock = plan.model(operations)
    return stock


def _unreached(plan: _Planning, stock: Simulation | None) -> tuple[Unreached, ...]:
    """The stock no tool reaches (finishing leaves it alone), each warned of."""
    t0 = time.perf_counter()
    options = plan.options
    left = unreached(stock, options.finish_engagement, options.roughing.allowance) if stock is not None else ()
    plan.seconds.append(("unreached", time.perf_counter() - t0))
    for u in left:
        log.warning("no tool reaches %s; finishing leaves it alone", u.describe())
    return tuple(left)


@dataclass(frozen=True)
class _BeforeRest:
    """The plan as the narrower tools' rest roughing (:func:`_rest_roughing`) found it.

    Attributes
    ----------
    first : int
        Index of the first rest roughing operation in the plan's operations (their number then).
    stock : Simulation or None
        The planning model before them.
    models : dict of float to OperationsCut
        The planning models' cache then (:attr:`_Planning.models`).
    """

    first: int
    stock: Simulation | None
    models: dict[float, OperationsCut]


def _flats_and_walls(plan: _Planning, operations: list[Operation], stock: Simulation,
                     before_rest: _BeforeRest | None = None) -> Simulation:
    """Flats and walls with flat end mills (:func:`_finish_flats_and_walls`); the stock the ball starts
    from after them (modelled again only if there are freeform surfaces left to finish).

    Where the roughing tool finishes them too and narrower tools rough what it left (``before_rest``: the plan
    before their rest roughing), its finishing runs before their rest roughing, planned on the stock before it:
    the roughing tool is loaded once, and each narrower tool's rest roughing and finishing follow each other. It
    keeps off the stock they rough (deeper than the finishing engagement there, as off what no tool reaches);
    their rest roughing, planned before it, meets only less stock after it (the finished skin lies under the
    allowance they leave)."""
    setup = plan.setup
    flat = flat_finish_tool(plan.library, float(setup.stock_max[2] - setup.floor_z), plan.rough_tool,
                            _ROUGH_MOST_OF_WIDTH * float(min(setup.stock_size[0], setup.stock_size[1])))
    if flat is not None:
        before = len(operations)
        if (before_rest is not None and flat is plan.rough_tool and before_rest.stock is not None
                and len(operations) > before_rest.first):
            rest = operations[before_rest.first:]
            del operations[before_rest.first:]
            plan.models = dict(before_rest.models)
            _finish_flats_and_walls(plan, flat, before_rest.stock, operations, narrower=False)
            operations.extend(rest)
            _finish_flats_and_walls(plan, flat, plan.model(operations), operations, widest=False, unreached_in=stock)
        else:
            _finish_flats_and_walls(plan, flat, stock, operations)
        if len(operations) > before and plan.faces is not None and plan.faces.freeform:
            stock = plan.model(operations)
    return stock


def flats_and_walls_from(part: trimesh.Trimesh, setup: Setup, library: ToolLibrary, options: PlanOptions,
                         operations: list[Operation], start: Callable[[float], FlippedStock]
                         ) -> tuple[list[Operation], Simulation]:
    """Flats and walls finished with flat end mills (as op 1's, :func:`_finish_flats_and_walls`) on stock an
    earlier setup left: op 2 from below. ``start(cell)`` is that stock turned over on a grid of ``cell`` [mm];
    ``operations`` those this setup ran before. Returns ``operations`` with the finishing appended and the
    stock after them (on the planning grid)."""
    plan = dataclasses.replace(_Planning.start(part, setup, library, options, None, None), turned_stock=start)
    operations = list(operations)
    stock = plan.model(operations)
    if plan.faces is not None:
        stock = _flats_and_walls(plan, operations, stock)
        stock = plan.model(operations)
    return operations, stock


def _freeform_finishing(plan: _Planning, operations: list[Operation], stock: Simulation | None) -> None:
    """The ball: waterline loops on steep surfaces, then the raster; without waterline, the tops of tall
    walls first (:func:`cadcam.shank_clearance.upper_raster`). Appends to ``operations``."""
    options, setup, part, faces, tool = plan.options, plan.setup, plan.part, plan.faces, plan.finish_tool
    within, cutting = plan.within, plan.finish_cutting
    limit = options.finish_engagement
    engagement = EngagementLimit(depth=limit, allowance=options.roughing.allowance)
    raster_options = options.finishing
    if not options.waterline:
        # Without waterline the raster must cover steep walls too.
        raster_options = dataclasses.replace(raster_options, steep_angle=90.0)
    where = None if faces is None else plan.ball_finishes()
    ball_options = options.finishing
    if faces is not None and options.freeform_scallop is not None:
        ball_options = dataclasses.replace(ball_options, scallop=options.freeform_scallop)
        raster_options = dataclasses.replace(raster_options, scallop=options.freeform_scallop)
    if options.waterline:
        operations.append(plan.timed("waterline", lambda: waterline_finishing(
            part, setup, tool, cutting, ball_options,
            progress=plan.stage_progress("waterline"), stock=stock, limit=engagement, within=within, where=where)))
        operations[-1] = _at_chip(plan, operations[-1], stock)
        # The raster comes after the waterline: where that left a wall's skin (a hole too small
        # for its loops), the raster must not take it in one deep pass either.
        if stock is not None and len(operations[-1].points) > 1:
            stock = plan.model(operations)
            engagement = EngagementLimit(depth=limit, allowance=options.finishing.allowance, grid_slack=False)
    if not options.waterline and stock is not None:
        # Every raster pass goes to full depth at once: first finish the tops of walls taller than the flutes.
        op = plan.timed("upper raster", lambda: upper_raster(part, setup, tool, cutting, raster_options,
                                                             stock, engagement, plan.stage_progress("upper raster"),
                                                             within=within))
        if op is not None:
            operations.append(op)
            stock = plan.model(operations)
    operations.append(_at_chip(plan, plan.timed("raster", lambda: raster_finishing(
        part, setup, tool, cutting, raster_options, progress=plan.stage_progress("raster"), stock=stock,
        limit=engagement, within=within, where=where)), stock))


def _at_chip(plan: _Planning, op: Operation, stock: Simulation | None) -> Operation:
    """``op`` at the feed each move's chip allows on ``stock`` (:func:`cadcam.chipfeed.chip_feeds`), as the
    flats and walls run; ``op`` itself without a stock model."""
    if stock is None or len(op.points) < 2:
        return op
    return plan.timed("chip feeds", lambda: chip_feeds(op, stock, plan.setup, plan.triangles, plan.library.max_feed))


def _ball_finishes(faces: FaceClasses, ball: Tool) -> Callable[[np.ndarray], np.ndarray]:
    """``inside(xy) -> (m,) bool``: where the ball ``ball`` finishes, near the freeform surfaces [mm]."""
    return faces.near((STEEP, SHALLOW), ball.radius + 0.5)


#: Grid spacing of the in-process stock model the operations are planned from [mm].
_MODEL_CELL = 0.5
#: Finest stock model the flats and walls are planned from [mm] (verify's default grid).
_FINEST_SKIN_CELL = 0.2


def _skin_cell(allowance: float) -> float:
    """Grid spacing [mm] at which a skin ``allowance`` [mm] thick beside a wall always holds a grid
    point outside the hair next to the wall (:data:`cadcam.flatfinish.WALL_HAIR`): a little under
    the rest of the skin's thickness, no finer than verify's grid, no coarser than the planning model's."""
    return float(min(_MODEL_CELL, max(_FINEST_SKIN_CELL, 0.8 * (allowance - WALL_HAIR))))


def _finish_flats_and_walls(plan: _Planning, flat: Tool, stock: Simulation, operations: list[Operation], *,
                            widest: bool = True, narrower: bool = True, unreached_in: Simulation | None = None) -> None:
    """Flats and walls with ``flat`` (``widest``), then with each narrower flat end mill where stock is left
    (``narrower``).

    The narrower ones that reach the whole depth first; then those shorter than the stock is deep, each
    within its stick-out (a 4 mm slot only a small end mill enters), but only on the skin the reaching
    tools left: not beside the freeform surfaces, which the ball finishes after them.
    Appends the operations to ``operations``; ``stock`` is the model before them, ``unreached_in`` the one the
    deep stock every tool keeps off is read from (default ``stock``): the one :func:`_unreached` read, or, for the
    roughing tool finishing before the narrower tools' rest roughing, the stock before it (what they rough too)."""
    setup, library, options, faces = plan.setup, plan.library, plan.options, plan.faces
    ff = options.flat_finish
    depth = float(setup.stock_max[2] - setup.floor_z)
    skin = _skin_cell(options.roughing.allowance)
    # What no tool reaches (:func:`_unreached` reads ``unreached_in``): every flat end mill leaves it alone.
    limit = EngagementLimit(depth=options.finish_engagement, allowance=options.roughing.allowance)
    unreached_in = stock if unreached_in is None else unreached_in
    stale = False  # an operation was appended since ``stock`` was modelled
    thinner = rest_tools(library, flat, depth) if narrower else []
    short = [t for t in thinner if t.length < depth]
    # Where a ball finishes anyway, a shorter tool's pass would only add a tool change and its cycle
    # (dome_mould: +127 s of a 2 mm end mill round the cavity's rim, the same verdict after).
    ball = plan.ball_finishes() if faces.freeform else None
    for tool in [flat] * widest + [t for t in thinner if t not in short] + short:
        if stale:
            stock, stale = plan.model(operations, stock.grid.cell), False
        # A short tool keeps off the skin the ball finishes; off a pocket no tool entered it keeps by
        # ``limit`` below, as every flat end mill does (what no tool reaches is left alone).
        leave = ball if tool in short else None
        # A tool whose flutes are shorter than the part is deep takes a wall in steps, at levels
        # where the stock model shows the skin roughing left on it; if the model missed it, the
        # flank pass at the floor would take the whole wall at once, shank in the skin. And below
        # a depth split (op 2) its walls meet op 1's: a skin the planning grid passes by between
        # its points would stay there, a step at the seam (issue 34: 0.3 mm on a block's long sides),
        # so op 2 looks for that skin on the finer model too, not only cuts it there.
        cell = _MODEL_CELL if tool.flute_length >= depth and plan.turned_stock is None else skin
        if plan.turned_stock is not None and abs(stock.grid.cell - cell) > 1e-9:
            stock = plan.model(operations, cell)
        # (In op 1, a skin only the finer model below shows, with nothing else left beside it, is no
        # danger: no pass goes there.)
        if not plan.timed("rest check", lambda: left_on_flats_and_walls(stock, faces, tool.radius, ff.allowance,
                                                                         ff.rest_above, leave)).any():
            break
        if abs(stock.grid.cell - cell) > 1e-9:
            stock = plan.model(operations, cell)
        cutting = library.cutting_data(tool, setup.material)
        stage = f"flats+walls T{tool.number}"
        # After a wider tool, what is left is mostly the inside corners it could not enter, met at full width.
        stepdown = None if tool is flat else tool.full_width_limit
        op = plan.timed(stage, lambda: flat_wall_finishing(plan.part, setup, tool, cutting, faces, stock,
                                                           ff, progress=plan.stage_progress(stage),
                                                           cut_before=plan.cut_before, stepdown=stepdown,
                                                           within=plan.keepout, limit=limit,
                                                           unreached_in=unreached_in, leave=leave))
        if len(op.points) > 1:
            # each move at the feed its chip allows on the stock before it: walls' skins and air faster
            operations.append(_at_chip(plan, op, stock))
            stale = True


def _finished(plan: _Planning, part_name: str, operations: list[Operation], source_sha256: str,
              left: tuple[Unreached, ...], holes: HolePlan | None, rapid_cell: float) -> PlanJobResult:
    """The job from its operations: empty ones dropped, every rapid made safe."""
    dropped = [op.kind for op in operations if len(op.points) < 2]
    if dropped:
        log.info("nothing to cut for %s: dropped", ", ".join(dropped))
    operations = [op for op in operations if len(op.points) >= 2]
    told = plan.on_planned if plan.on_planned is not None else plan.on_operations
    if told is not None:
        told(list(operations), plan.setup)
    safe_ops, checked, fixed = plan.timed("rapid check", lambda: safe_rapids(operations, plan.setup, plan.triangles,
                                                                             rapid_cell))

    job = Job(
        part_name=part_name,
        setup=plan.setup,
        operations=safe_ops,
        source_sha256=source_sha256,
        parameters={
            **plan.options.to_dict(),
            "rough_tool": plan.rough_tool.number,
            "finish_tool": plan.finish_tool.number,
            "unreached": [u.to_dict() for u in left],
            "rapids": {"checked": checked, "made_safe": fixed},
            "holes": holes.to_dict() if holes is not None else {},
            "faces": None if plan.faces is None else plan.faces.summary(),
        },
    )
    return PlanJobResult(job, PlanTimings(tuple(plan.seconds)))
