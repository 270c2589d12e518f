"""Op 2: the part turned over in the vise, the holding allowance faced off, the bottom finished.

Op 1 cuts the part from the top down into the holding allowance under it, which the vise
grips. Then the part is turned over and held on its finished faces, and op 2 faces the
allowance off down to the part's original bottom face and finishes what only shows from
below.

The flip
    A half turn about the work X axis: the vise's jaw axis (X along the jaws, Y the
    clamping direction: :mod:`robotprog.frames`). The faces the jaws gripped in op 1 (the
    stock's Y faces) stay facing the jaws, front and back swapped; X stays X. In work
    coordinates ``(x, y, z) -> (x, y0 + y1 - y, z0 - z)`` with ``y0, y1`` the stock's Y
    extent and ``z0`` its bottom: the stock box lands on itself in X and Y, so the op-2
    grid of the verify simulation is op 1's with its rows reversed, and the old stock
    bottom (the face of the allowance the vise gripped) becomes the new top, ``z = 0``.
Op 2's work coordinates
    The same convention as op 1's (:class:`cadcam.model.Setup`): origin on the top of the
    flipped stock, at its front-left corner or its centre, whichever op 1 used. The program
    runs in its own work offset (G55, see :mod:`cadcam.post`), touched off on the flipped
    stock.
Facing
    Zigzag passes along X at ``stepover`` (80 % of the diameter) across the whole stock
    footprint, in as few even levels as the stepdown allows from the top down to the part's
    original bottom face: the last level's bottom is the face. Every level is entered outside the stock: the tool
    ramps down in the air beside it and enters the material sideways at depth, never by a
    plunge. Passes overhang the stock's Y faces by a tenth of the diameter, so no rim stays.
Features seen from below
    The op-2 stock is op 1's simulated stock turned over (:func:`cadcam.stock.flip_stock`),
    so what op 1 already cut is known. Where, after facing, more than the finishing limit is
    left over the turned-over part's upper envelope (a pocket or recess in the bottom face,
    which op 1 could not reach through the part), it is rest roughed with the library's flat
    end mills and finished with the finishing tool, only there (:func:`plan_op2`).
Depth split
    A part deeper than the tools reach from the top (:func:`cadcam.plan.split_depth`): op 1
    stopped at its reach, and op 2 machines from below down to op 1's floor (less the
    breakthrough, so the walls overlap), within its own reach and clear of the jaws: rest
    roughing, then flats and walls by the flank as op 1 finishes them. Where the walls meet,
    :func:`cadcam.seam.seams` measures the step from both jobs' toolpaths. Which face goes up first is the
    one that leaves the least no tool reaches from either side (:func:`choose_face_up`).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import trimesh

from cadcam.finishing import EngagementLimit, raster_finishing
from cadcam.model import CuttingData, FixtureBox, Job, Motion, Operation, Setup, Tool, ViseJaws
from cadcam.faces import classify_faces
from cadcam.gridregion import near_cells
from cadcam.heightmap import grid_over, upper_envelope
from cadcam.plan import PlanOptions, choose_tools, deepest_reach, flats_and_walls_from, rest_tools, split_depth
from cadcam.rest import safe_rapids
from cadcam.roughing import part_shadows, zlevel_roughing
from cadcam.setup import BREAKTHROUGH_MM, JAW_CLEARANCE_MM, MIN_HOLDING_LEFT_MM
from cadcam.workholding import jaw_keepout, lowest_beside_jaws
from cadcam.tools import ToolLibrary
from cadcam.seam import seams
from cadcam.stock import (FlippedStock, Simulation, clear_height, excess, flip_stock, stock_after, stock_after_flipped,
                          unreached)
from factory.core.errors import FactoryError, SetupError, ToolError, ToolpathError

log = logging.getLogger(__name__)

#: The axis the part is turned over about between op 1 and op 2: work X, the vise's jaw axis.
FLIP_AXIS = "X"
#: Work offset of each operation, as the post writes it (fixture 1: G54, fixture 2: G55).
WORK_OFFSET = {1: 1, 2: 2}
#: Where the work origin sits on the turned-over stock's top, for the program header.
_ORIGIN_WORDS = {"top-front-left": "front-left corner", "top-centre": "centre"}
#: Stock left over a face from below that counts as finished: the verify's residual target [mm].
_FINISHED = 0.02


def flip_transform(setup: Setup) -> np.ndarray:
    """(4, 4) op-1 work coordinates -> op-2 work coordinates [mm]: the half turn about X (module docstring)."""
    t = np.diag([1.0, -1.0, -1.0, 1.0])
    t[1, 3] = float(setup.stock_min[1] + setup.stock_max[1])
    t[2, 3] = float(setup.stock_min[2])
    return t


def op2_setup(setup: Setup) -> Setup:
    """The op-2 setup: op 1's stock box turned over in place, its top at ``z = 0``.

    The part's mesh -> work transform includes the flip; safe height and clearance above
    the (new) stock top are op 1's. No jaws yet and the floor at the stock bottom: they
    depend on the part (:func:`plan_op2` places them).
    """
    flip = flip_transform(setup)
    size = setup.stock_size
    stock_min = np.array([setup.stock_min[0], setup.stock_min[1], -size[2]])
    stock_max = np.array([setup.stock_max[0], setup.stock_max[1], 0.0])
    return dataclasses.replace(
        setup,
        stock_min=stock_min,
        stock_max=stock_max,
        transform_mesh_to_work=flip @ setup.transform_mesh_to_work,
        safe_z=float(setup.safe_z - setup.stock_max[2]),
        floor_z=float(stock_min[2]),
        jaws=None,  # op 1's jaws held the allowance; op 2's hold the part (op2_jaws)
    )


def op2_jaws(jaws: ViseJaws, setup: Setup, part: trimesh.Trimesh, face_z: float) -> tuple[FixtureBox, ...]:
    """The vise holding the turned-over part in op 2, as boxes in op-2 work coordinates [mm].

    The jaws grip the part's finished Y faces (its bounding box across the jaws), its old top
    resting on the parallels; they reach ``soft_jaws.depth`` up the part with soft jaws, the
    vise's grip depth without, and never closer than :data:`cadcam.setup.JAW_CLEARANCE_MM`
    under the face being cut (the facing passes over them), nor under a lower face op 2 cuts beside them
    (:func:`cadcam.workholding.lowest_beside_jaws`) while the part still stands ``MIN_HOLDING_LEFT_MM`` in them.

    Raises
    ------
    SetupError
        The part is too thin to grip below the face with that clearance.
    """
    lo, hi = np.asarray(part.bounds, dtype=np.float64)
    grip = jaws.soft_jaws.depth if jaws.soft_jaws is not None else jaws.grip_depth
    room = face_z - JAW_CLEARANCE_MM - float(lo[2])
    beside = lowest_beside_jaws(part, face_z) - JAW_CLEARANCE_MM - float(lo[2])
    if MIN_HOLDING_LEFT_MM - 1e-9 <= beside < min(grip, room):
        # a face op 2 cuts beside a jaw lies under the face: gripped to the face, the jaw would keep every
        # tool off a strip along it (the plate under the OCL sphere: 76 x 3 mm, 3.2 deep, left along each jaw)
        log.info("op 2 grips the part %.2f mm deep, under the face %.2f mm below its top beside the jaws",
                 beside, face_z - beside - JAW_CLEARANCE_MM - float(lo[2]))
        room = beside
    if room <= 0:
        raise SetupError(f"the part is {face_z - lo[2]:.2f} mm tall: op 2 cannot grip it {JAW_CLEARANCE_MM:g} mm "
                         f"below the face it cuts")
    if grip > room:
        log.info("op 2 grips the part %.2f mm deep, not the vise's %.2f mm: it stands only %.2f mm tall",
                 room, grip, face_z - lo[2])
        grip = room
    held = dataclasses.replace(jaws, jaw_height=jaws.parallels_height + grip)
    return held.place(np.array([setup.stock_min[0], lo[1], lo[2]]), np.array([setup.stock_max[0], hi[1], face_z]))


#: A face looks up in op 2 (down in op 1, so op 1's tools never cut it) when its normal's Z is over this [1].
_LOOKS_UP = 0.05


def check_op2_grip(part_work: trimesh.Trimesh, setup: Setup, jaws: ViseJaws, library: ToolLibrary) -> None:
    """Refuse, before any toolpath, a part whose op 2 must cut faces where the vise holds it.

    Op 1 cuts from above, so a face looking down (an undercut, a thread's flank, the cone under
    a countersunk head) is op 2's. Turned over, the part is held by its Y faces at its old top
    (:func:`op2_jaws`); a face op 2 must cut below the jaws' top, closer to a jaw than the radius
    of the library's narrowest end mill, cannot be cut without the tool running into that jaw.
    Verify finds it only after all the CAM work (the public M6 countersunk screw: 8 minutes).

    ``part_work``: the part in op-1 work coordinates [mm]; ``setup``: op 1's; ``jaws``: the
    cell's vise [mm].

    Raises
    ------
    SetupError
        Such faces: how deep the jaws grip, where the faces are (op-1 Z and Y), the tool; the fixes.
    """
    mills = [t for t in library.tools if t.shape in ("flat", "bull") and not t.is_drill]
    if not mills or not len(part_work.faces):
        return
    narrowest = min(mills, key=lambda t: t.diameter)
    op2 = op2_setup(setup)
    part = flip_part(part_work, setup)
    face_z = float(part.bounds[1][2])
    held = [b for b in op2_jaws(jaws, op2, part, face_z) if b.name != "parallels"]
    jaw_top = max(float(b.hi[2]) for b in held)
    lo, hi = np.asarray(part.bounds, dtype=np.float64)
    centre, normal = np.asarray(part.triangles_center), np.asarray(part.face_normals)
    to_jaw = np.minimum(centre[:, 1] - lo[1], hi[1] - centre[:, 1])
    clash = (normal[:, 2] > _LOOKS_UP) & (centre[:, 2] < min(jaw_top, face_z - 1e-6)) & (to_jaw < narrowest.radius)
    if not clash.any():
        return
    flip = flip_transform(setup)  # its own inverse: op-2 points back to op 1's
    z1 = centre[clash] @ flip[2, :3] + flip[2, 3]
    worst = int(np.argmin(to_jaw[clash]))
    y1 = float(centre[clash][worst] @ flip[1, :3] + flip[1, 3])
    raise SetupError(f"op 2 holds the turned-over part {jaw_top - lo[2]:.1f} mm deep in the jaws, where it must cut "
                     f"faces op 1 cannot see from above (Z{z1.min():.2f} to Z{z1.max():.2f} in op 1, "
                     f"{float(to_jaw[clash][worst]):.2f} mm from a jaw at Y{y1:.2f}, closer than the "
                     f"{narrowest.diameter:g} mm end mill's radius): plan op 1 only (--ops 1) and leave them, or give "
                     "a --cell whose soft jaws grip it less deep")


def flip_part(part_work: trimesh.Trimesh, setup: Setup) -> trimesh.Trimesh:
    """The part in op-1 work coordinates, turned over into op 2's (a new mesh)."""
    out = part_work.copy()
    out.apply_transform(flip_transform(setup))  # a proper rotation: the faces keep their outward normals
    return out


@dataclass(frozen=True)
class FacingOptions:
    """How to face the holding allowance off.

    Attributes
    ----------
    stepover : float
        Distance between passes as a share of the tool diameter, in ``(0, 0.9]``. Default 0.8: a flat end
        mill's bottom leaves no cusp, the passes still overlap by 0.2 D, and any width is within the
        full-width limit at the facing's depth (the stepdown is at most the limit); 0.7 took one pass more
        over the samples' 54-74 mm of stock.
    stepdown : float, optional
        Deepest level [mm]. Default: half the diameter, at most the flute length.
    finish_depth : float
        Depth of a separate last level, a light skim of the face [mm]; 0: none, the last level's
        bottom is the face. Default 0 (issue 32): the skim was cut by the same end mill at the same
        stepover and chip (above half the diameter the chip is the full ``fz`` at any depth), so it
        swept the whole footprint a second time for 0.2 mm, 19.5-21 s of every sample's op 2; the
        face's height is set by the tool's length offset either way, and verify holds it to size.
        The holding allowance (6.5 mm on the samples) is one level within a 16 mm end mill's
        full-width limit.
    ramp_angle : float
        Angle of the ramp down to each level beside the stock [deg], in ``(0, 45]``. Default 15.
    overhang : float
        How far the tool's edge passes beyond the stock's Y faces, as a share of the
        diameter, in ``[0, 0.5)``. Default 0.1.
    """

    stepover: float = 0.8
    stepdown: float | None = None
    finish_depth: float = 0.0
    ramp_angle: float = 15.0
    overhang: float = 0.1

    def check(self, tool: Tool) -> float:
        """The stepdown for ``tool`` [mm]; raises ToolpathError for an option out of range."""
        stepdown = tool.level_stepdown if self.stepdown is None else float(self.stepdown)
        bad = []
        if not 0 < self.stepover <= 0.9:
            bad.append(f"stepover {self.stepover:g} must lie in (0, 0.9] of the diameter")
        if not 0 < stepdown <= tool.flute_length:
            bad.append(f"stepdown {stepdown:g} mm must lie in (0, flute length {tool.flute_length:g}]")
        if not 0 <= self.finish_depth < stepdown:
            bad.append(f"finish depth {self.finish_depth:g} mm must lie in [0, stepdown {stepdown:g})")
        if not 0 < self.ramp_angle <= 45:
            bad.append(f"ramp angle {self.ramp_angle:g} deg must lie in (0, 45]")
        if not 0 <= self.overhang < 0.5:
            bad.append(f"overhang {self.overhang:g} must lie in [0, 0.5) of the diameter")
        if bad:
            raise ToolpathError("; ".join(bad), source="facing options")
        return stepdown


def facing_levels(top: float, face_z: float, stepdown: float, finish_depth: float) -> np.ndarray:
    """Heights of the facing levels from ``top`` down to ``face_z`` [mm], the last exactly ``face_z``.

    Even levels no deeper than ``stepdown`` down to ``face_z + finish_depth``, then the skim.
    """
    if not top > face_z:
        return np.zeros(0)
    skim = finish_depth >= 1e-6 and top - face_z > finish_depth + 1e-6  # a skim thinner than a micron is none
    rough_to = face_z + finish_depth if skim else face_z
    n = max(1, math.ceil((top - rough_to) / stepdown - 1e-9))
    levels = list(top - (top - rough_to) * np.arange(1, n + 1) / n)
    if skim:
        levels.append(face_z)
    levels[-1] = face_z
    return np.asarray(levels)


def facing_gap(setup: Setup) -> float:
    """How far the facing's passes end clear of the stock's X faces, the tool's edge beyond them
    [mm]: the ramps down to each level end there, in the air (:func:`factory.rackloop.facing_reach`)."""
    return max(float(setup.clearance), 0.5)


def facing(setup: Setup, face_z: float, tool: Tool, cutting: CuttingData,
           options: FacingOptions = FacingOptions()) -> Operation:
    """Face the whole stock top of ``setup`` down to ``face_z`` with a flat end mill.

    Parameters
    ----------
    setup : Setup
        The stock box (its top is where facing starts), safe height and clearance.
    face_z : float
        Height of the face to leave [mm]: the part's original bottom face in op 2.
    tool : Tool
        A flat end mill (a corner radius would leave a rim on the face).
    cutting : CuttingData
    options : FacingOptions

    Returns
    -------
    Operation
        ``kind="facing"``: zigzag passes along X, ``options.stepover`` apart in Y, starting
        and ending outside the stock; each level entered by a ramp beside the stock at the
        plunge feed. Empty when ``face_z`` is not below the stock top.

    Raises
    ------
    ToolError
        The tool is not a flat end mill, or its stick-out does not reach ``face_z``.
    ToolpathError
        An option is out of range.
    """
    if tool.shape != "flat":
        raise ToolError(f"T{tool.number} is a {tool.shape} end mill; facing needs a flat end mill")
    stepdown = options.check(tool)
    top = float(setup.stock_max[2])
    if top - face_z > tool.length:
        raise ToolError(f"T{tool.number} reaches {tool.length:g} mm below its holder but the face lies "
                        f"{top - face_z:g} mm below the stock top")
    levels = facing_levels(top, face_z, stepdown, options.finish_depth)
    if not len(levels):
        return Operation("face", "facing", tool, cutting, np.zeros((0, 3)), np.zeros(0, np.int8))
    R, D = tool.radius, tool.diameter
    x0, y0 = float(setup.stock_min[0]), float(setup.stock_min[1])
    x1, y1 = float(setup.stock_max[0]), float(setup.stock_max[1])
    gap = facing_gap(setup)
    # Pass ends: the tool clear of the stock's X faces by the clearance.
    xa, xb = x0 - R - gap, x1 + R + gap
    # Pass centres: the tool's edge overhangs each Y face by the overhang, passes evenly spaced.
    ya, yb = y0 + R - options.overhang * D, y1 - R + options.overhang * D
    if yb <= ya:
        ys = np.array([0.5 * (y0 + y1)])
    else:
        n = max(1, math.ceil((yb - ya) / (options.stepover * D) - 1e-9))
        ys = ya + (yb - ya) * np.arange(n + 1) / n
    tan = math.tan(math.radians(options.ramp_angle))

    pts: list[tuple[float, float, float]] = []
    mot: list[int] = []

    def add(x: float, y: float, z: float, m: Motion) -> None:
        pts.append((x, y, z))
        mot.append(int(m))

    z_prev = top + float(setup.clearance)
    side = 0  # 0: the level starts at xa, 1: at xb
    order = ys
    for k, z in enumerate(levels):
        x_in = xa if side == 0 else xb
        outward = -1.0 if side == 0 else 1.0
        # The ramp's last radius of run only: a holding block seated off along the jaws by up to the passes'
        # gap and a radius (factory.rackloop.facing_reach, which the robot's seat check holds it to) meets the
        # tool's side there, as on a ramp from higher up; the tool's edge above its start lies beyond that
        # reach, in the air, so it comes down by rapid (a 15 deg ramp from the clearance at the plunge feed
        # took 3.1 s of every op 2).
        run = min((z_prev - z) / tan, R)
        z_from = float(z) + run * tan
        if k == 0:
            add(x_in + outward * run, order[0], float(setup.safe_z), Motion.RAPID)
        else:
            add(x_in + outward * run, order[0], z_prev, Motion.RAPID)  # back out beside the stock, in the air
        if z_from < z_prev - 1e-9 or k == 0:
            add(x_in + outward * run, order[0], z_from, Motion.RAPID)
        add(x_in, order[0], float(z), Motion.PLUNGE)  # the ramp, ending beside the stock
        for i, y in enumerate(order):
            here = xa if (side + i) % 2 == 0 else xb
            there = xb if here == xa else xa
            if i:
                add(here, float(y), float(z), Motion.CUT)  # step over, beside the stock
            add(there, float(y), float(z), Motion.CUT)
        end_side = 1 if (side + len(order) - 1) % 2 == 0 else 0
        side = end_side  # the next level starts where this one ended, passes in reverse order
        order = order[::-1]
        z_prev = float(z)
    last = pts[-1]
    add(last[0], last[1], float(setup.safe_z), Motion.RAPID)
    return Operation("face holding allowance", "facing", tool, cutting, np.asarray(pts), np.asarray(mot, np.int8),
                     allowance=0.0)


def choose_facing_tool(library: ToolLibrary, depth: float, number: int | None = None) -> Tool:
    """The facing end mill: ``number``, or the widest flat end mill that reaches ``depth`` [mm].

    Raises
    ------
    ToolError
        The named tool is missing, not flat or too short; or no flat end mill reaches.
    """
    if number is not None:
        tool = library.tool(number)
        if tool.shape != "flat":
            raise ToolError(f"T{number} is a {tool.shape} end mill; facing needs a flat end mill",
                            source=library.source)
        if tool.length < depth:
            raise ToolError(f"T{number} reaches {tool.length:g} mm below its holder but op 2 faces "
                            f"{depth:g} mm deep", source=library.source)
        return tool
    flats = [t for t in library.tools if t.shape == "flat" and t.length >= depth]
    if not flats:
        raise ToolError(f"no flat end mill in the library reaches {depth:g} mm below its holder to face op 2",
                        source=library.source)
    return max(flats, key=lambda t: (t.diameter, t.length, -t.number))


@dataclass(frozen=True)
class Op2Options:
    """What op 2 cuts with and how.

    Attributes
    ----------
    facing_tool : int, optional
        Tool number of the facing end mill; None: the widest flat end mill that reaches.
    facing : FacingOptions
    plan : PlanOptions
        Rest roughing and finishing of features seen from below: tools, allowance and the
        finishing limit as for op 1.
    cell : float
        Grid of the in-process stock model the op-2 planning reads [mm]. Default 0.5.
    """

    facing_tool: int | None = None
    facing: FacingOptions = field(default_factory=FacingOptions)
    plan: PlanOptions = field(default_factory=PlanOptions)
    cell: float = 0.5

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def _left_from_below(sim: Simulation, allowance: float) -> np.ndarray:
    """(ny, nx) bool: grid points over the part with more than the finished residual left."""
    over = np.isfinite(sim.part_top) & np.isfinite(sim.stock_top)
    left = np.zeros(sim.grid.shape, bool)
    left[over] = sim.stock_top[over] - sim.part_top[over] > max(_FINISHED, allowance)
    return left


def plan_op2(
    part_work: trimesh.Trimesh,
    job1: Job,
    library: ToolLibrary,
    *,
    options: Op2Options = Op2Options(),
    op1_stock: Simulation | None = None,
    jaws: ViseJaws | None = None,
) -> tuple[Job, trimesh.Trimesh]:
    """The op-2 job: the part turned over, the holding allowance faced off, the bottom finished.

    Parameters
    ----------
    part_work : trimesh.Trimesh
        The part in op-1 work coordinates [mm] (``PlannedPart.part_work``).
    job1 : Job
        Op 1: its setup (the stock with the holding allowance under the part) and operations.
    library : ToolLibrary
    options : Op2Options
    op1_stock : Simulation, optional
        Op 1's stock model (its verify simulation will do, on any grid); None: simulated here
        from ``job1`` on ``options.cell``. Where stock is left over faces seen from below, it is
        simulated again on ``options.cell`` if its grid is another.
    jaws : ViseJaws, optional
        The vise (the cell file's, with its optional soft jaws): placed round the turned-over
        part (:func:`op2_jaws`) as the op-2 setup's ``jaws``. None: workholding unknown.

    Returns
    -------
    job : Job
        In op-2 work coordinates (:func:`op2_setup`). ``parameters``: ``op`` (2),
        ``work_offset`` (2: G55), ``flip`` (axis and the op-1 -> op-2 transform),
        ``face_z`` (the part's original bottom face in op 2 [mm]), ``holding_mm`` (the
        allowance faced off), ``unreached`` (stock from below no tool reaches) and ``rapids``; after a
        depth split (op 1 stopped short of the part's bottom), ``seams`` (:func:`cadcam.seam.seams`, as dicts).
    part_op2 : trimesh.Trimesh
        The part in op-2 work coordinates.

    Raises
    ------
    ToolError
        No flat end mill reaches the face, or a named tool is unfit.
    ToolpathError
        An operation cannot be computed.
    """
    setup1 = job1.setup
    setup = op2_setup(setup1)
    part = flip_part(part_work, setup1)
    triangles = np.asarray(part.triangles)
    face_z = float(part.bounds[1][2])
    top = float(setup.stock_max[2])
    # Nothing feeds below the part: under it are the parallels; nor deeper than the tools reach from this side.
    setup = dataclasses.replace(setup, floor_z=float(part.bounds[0][2]),
                                jaws=None if jaws is None else op2_jaws(jaws, setup, part, face_z))
    tool = choose_facing_tool(library, top - face_z, options.facing_tool)
    # (facing reads the stock box, not the floor: the floor follows from the stock it leaves)
    operations = [facing(setup, face_z, tool, library.cutting_data(tool, setup.material), options.facing)]

    def op1_model() -> Simulation:
        return stock_after(list(job1.operations), setup1, np.asarray(part_work.triangles), options.cell)

    if op1_stock is None:
        op1_stock = op1_model()
    start = flip_stock(op1_stock, flip_transform(setup1), setup)
    stock = stock_after_flipped(operations, setup, triangles, start, op1_stock.grid.cell)

    plan = options.plan
    allowance, limit = plan.roughing.allowance, plan.finish_engagement
    left = _left_from_below(stock, 0.0) | (excess(stock, allowance) > limit)
    # how deep op 2 goes: what op 1 left over the part, seen from below, down to the part's bottom
    setup = _reachable_floor(setup, setup1, library, part, plan, _deepest_left(stock, left))
    stock = dataclasses.replace(stock, floor_z=setup.floor_z)
    left = _left_from_below(stock, 0.0) | (excess(stock, allowance) > limit)
    if left.any() and op1_stock.grid.cell != options.cell:
        # Rest roughing reads the stock cell by cell: on the planning grid, not a finer verify grid.
        start = flip_stock(op1_model(), flip_transform(setup1), setup)
        stock = stock_after_flipped(operations, setup, triangles, start, options.cell)
        left = _left_from_below(stock, 0.0) | (excess(stock, allowance) > limit)
    if left.any():
        starts = {start.grid.cell: start}

        def start_at(cell: float) -> FlippedStock:
            """Op 1's stock turned over on a grid of ``cell`` [mm] (the flats and walls read a finer one)."""
            if cell not in starts:
                sim1 = stock_after(list(job1.operations), setup1, np.asarray(part_work.triangles), cell)
                starts[cell] = flip_stock(sim1, flip_transform(setup1), setup)
            return starts[cell]

        # Op 1 stopped short of the part's bottom (its tools do not reach so deep): the walls below are op 2's.
        walls = float(setup1.floor_z) > float(part_work.bounds[0][2]) + 1e-9
        operations, stock = _machine_from_below(part, triangles, setup, library, plan, operations, stock, start_at,
                                                options.cell, left, walls)
    seam = _seam_floor(setup1, part)
    # what neither side reaches: below op 2's floor, down to where op 1 stopped, is left too
    left_regions = unreached(stock if seam is None or seam >= float(setup.floor_z) - 1e-9
                             else dataclasses.replace(stock, floor_z=seam), limit, allowance)
    for u in left_regions:
        log.warning("op 2: no tool reaches %s from below; left uncut", u.describe())
    operations = [op for op in operations if len(op.points) >= 2]
    safe_ops, checked, fixed = safe_rapids(operations, setup, triangles) if operations else ((), 0, 0)
    parameters = _op2_parameters(setup1, setup, part_work, face_z, tool, jaws, options, left_regions, checked, fixed)
    job = Job(part_name=job1.part_name, setup=setup, operations=tuple(safe_ops), source_sha256=job1.source_sha256,
              parameters=parameters)
    if float(setup1.floor_z) > float(part_work.bounds[0][2]) + 1e-9:  # a depth split: where the walls meet
        # (op 2's verdict fails a step over the tolerance: :meth:`cadcam.seam.Seam.fault`,
        # :func:`cadcam.seam.seam_faults`)
        found = seams(part_work, job1, job)
        job = dataclasses.replace(job, parameters={**parameters, "seams": [s.to_dict() for s in found]})
    return job, part


#: The part turned over about work X before it is placed (:func:`choose_face_up`), as a (4, 4) transform.
TURN_OVER = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class SidesReach:
    """What the tools of one setup and of the one after the flip leave between them, on a heightmap.

    Attributes
    ----------
    unreached_volume : float
        Stock neither side reaches [mm^3]: above the part deeper than the reach from the top, below it
        higher than the reach from the bottom, and beside it between the two.
    reach : float
        Depth the tools reach from either side [mm] (:func:`cadcam.plan.deepest_reach`).
    """

    unreached_volume: float
    reach: float


def sides_reach(part_work: trimesh.Trimesh, setup: Setup, library: ToolLibrary, cell: float = 1.0) -> SidesReach:
    """The stock no tool reaches from the top (op 1) nor, turned over, from the bottom (op 2) [mm^3].

    A column-wise estimate on a grid of ``cell`` [mm]: it counts what lies beyond each side's reach and
    shadowed from the other by the part, not what a tool's width keeps it from (that is toolfit's).
    """
    top, bottom = float(setup.stock_max[2]), float(setup.stock_min[2])
    if top - bottom <= deepest_reach(library, freeform=True):  # either side reaches through: nothing left
        return SidesReach(0.0, deepest_reach(library))
    reach = deepest_reach(library, freeform=bool(classify_faces(part_work).freeform))
    grid = grid_over(setup.stock_min, setup.stock_max, cell)
    tri = np.asarray(part_work.triangles, dtype=np.float64)
    top_of_part = upper_envelope(tri, grid)
    bottom_of_part = -upper_envelope(tri * np.array([1.0, 1.0, -1.0]), grid)
    from_top, from_below = top - reach, bottom + reach  # the lowest op 1 reaches, the highest op 2 does
    part = np.isfinite(top_of_part)
    left = np.where(part, np.maximum(from_top - np.where(part, top_of_part, 0.0), 0.0)
                    + np.maximum(np.where(part, bottom_of_part, 0.0) - from_below, 0.0),
                    max(from_top - from_below, 0.0))
    return SidesReach(float(left.sum() * cell * cell), reach)


def choose_face_up(part: trimesh.Trimesh, place: Callable[[trimesh.Trimesh], tuple[Setup, trimesh.Trimesh]],
                   library: ToolLibrary) -> tuple[Setup, trimesh.Trimesh]:
    """The part placed (``place``: :func:`cadcam.setup.orient_setup` with its options) with the face up
    first that leaves the least stock no tool reaches from either side (:func:`sides_reach`).

    The file's orientation is kept unless turning the part over (:data:`TURN_OVER`, before placing it)
    leaves less unreached, by more than a cubic millimetre per square millimetre of the stock's footprint
    (a tenth of a cell in noise), and places at all. The setup's ``transform_mesh_to_work`` then includes
    the turn. Only a part deeper than the tools reach from one side is weighed: any other is placed as given.
    """
    setup, part_work = place(part)
    given = sides_reach(part_work, setup, library)
    if given.unreached_volume <= 0:
        return setup, part_work
    turned = part.copy()
    turned.apply_transform(TURN_OVER)
    try:
        setup_t, part_t = place(turned)
    except FactoryError:
        return setup, part_work
    other = sides_reach(part_t, setup_t, library)
    footprint = float(np.prod(setup.stock_size[:2]))
    if other.unreached_volume < given.unreached_volume - footprint:
        log.warning("turned over (about X) before op 1: its tools then leave %.0f mm^3 unreached from either side, "
                    "not %.0f mm^3 as given", other.unreached_volume, given.unreached_volume)
        return dataclasses.replace(setup_t, transform_mesh_to_work=setup_t.transform_mesh_to_work @ TURN_OVER), part_t
    return setup, part_work


def _seam_floor(setup1: Setup, part: trimesh.Trimesh) -> float | None:
    """Where op 2's work ends after a depth split, in op-2 work coordinates [mm]: op 1's floor turned over,
    less the breakthrough (the walls overlap there); None when op 1 reached the part's bottom. ``part``: the
    part turned over (op 2's)."""
    seam = float(setup1.stock_min[2]) - float(setup1.floor_z)  # op 1's floor in op-2 work coordinates
    if seam >= float(part.bounds[1][2]) - 1e-9:  # at or above the part's bottom face, turned over
        return None
    return max(seam - BREAKTHROUGH_MM, float(part.bounds[0][2]))


def _reachable_floor(setup: Setup, setup1: Setup, library: ToolLibrary, part: trimesh.Trimesh,
                     plan: PlanOptions, needed: float | None = None) -> Setup:
    """Op 2's setup with its floor where op 2's work ends when op 1 stopped short of the part's bottom
    (:func:`cadcam.plan.split_depth`): op 1's floor turned over, less the breakthrough (the walls overlap
    there, :func:`cadcam.seam.seams`), or deeper, down to ``needed`` [mm] (:func:`_deepest_left`: a pocket in the
    bottom face op 1 could not see, under a web, goes past op 1's floor), no deeper than the library reaches from
    the turned-over stock's top and clear of the jaws' top by :data:`cadcam.setup.JAW_CLEARANCE_MM` (the
    tool beside the part passes over them). Any other setup no deeper than the library reaches either (op 1
    went through; a feature from below deeper than that is left and reported)."""
    if plan.rough_tool is not None or plan.finish_tool is not None:
        return setup
    seam = _seam_floor(setup1, part)
    if seam is None:  # op 1 reached the part's bottom: op 2 goes no deeper than its tools reach
        if float(setup.stock_max[2] - setup.floor_z) <= deepest_reach(library, freeform=True):
            return setup  # (the usual op 2: every tool that might finish reaches)
        split = split_depth(setup, library, freeform=bool(classify_faces(part).freeform))
        if split.short > 0:
            log.info("op 2 machines from the top of the turned-over stock down to Z%.2f: its tools reach %.1f mm",
                     split.setup.floor_z, split.reach)
        return split.setup
    floor = max(float(setup.floor_z), seam if needed is None else min(seam, needed))
    split = split_depth(dataclasses.replace(setup, floor_z=floor), library,
                        freeform=bool(classify_faces(part).freeform))
    floor = float(split.setup.floor_z)
    jaws = [b for b in setup.jaws or () if b.name != "parallels"]
    if jaws:
        floor = max(floor, max(float(b.hi[2]) for b in jaws) + JAW_CLEARANCE_MM)
    log.info("op 2 machines from the top of the turned-over stock down to Z%.2f (op 1 stopped at Z%.2f)",
             floor, seam)
    return dataclasses.replace(setup, floor_z=floor)


def _deepest_left(stock: Simulation, left: np.ndarray) -> float | None:
    """The lowest op 2 must reach to take the stock of ``left`` ((ny, nx) bool grid points of ``stock``, op 1's
    stock turned over) [mm]: the part's top under it, only where there is part. None when none is left over it.

    After a depth split, op 1 finished every wall it saw down to its floor; but a pocket in the bottom face under
    a web (a wheel's rim under its spokes' plate) it never saw, and op 2 must finish it to its bottom, past the
    seam, or its walls meet op 1's with the whole pocket's depth as their step. Columns with no part (op 1's
    slivers in a through pocket's sharp inside corners) do not count: their stock ends where op 1's cut from the
    other side does, and reaching for it would pull op 2's floor to the bottom of the stock (wheel_in_box: -41.5
    where its pockets need -11.5)."""
    over_part = left & np.isfinite(stock.part_top)
    if not over_part.any():
        return None
    return float(stock.part_top[over_part].min())


def _machine_from_below(part: trimesh.Trimesh, triangles: np.ndarray, setup: Setup, library: ToolLibrary,
                        plan: PlanOptions, operations: list[Operation], stock: Simulation,
                        start_at: Callable[[float], FlippedStock], cell: float, left: np.ndarray,
                        walls: bool = False) -> tuple[list[Operation], Simulation]:
    """Rest rough, then finish, the stock left over faces seen from below (pockets and recesses in the
    bottom face), only there: ``operations`` with those appended, and the stock after them.

    ``stock``: the op-2 stock after ``operations``, from ``start_at(cell)`` (op 1's turned over) on a grid
    of ``cell`` [mm]; ``left``: its grid points with stock left (over faces seen from below, or beyond what
    op 1 reached from the top); ``walls``: op 1 stopped short of the part's bottom, so its walls and flats
    below are finished here too;
    ``triangles``: the part's, (m, 3, 3) [mm].
    """
    allowance, limit = plan.roughing.allowance, plan.finish_engagement
    log.info("op 2: %d grid points of stock left over faces seen from below; rest roughing and finishing",
             int(left.sum()))
    operations = list(operations)
    rough_tool, finish_tool = choose_tools(library, setup, plan)
    # op 2's jaws grip the part itself: keep every tool off them, but over the part's material standing clear
    # of their top (op2_jaws grips under the faces beside them) a tool may pass above them
    within = jaw_keepout(setup, library.tools, shadows=lambda heights: part_shadows(part, heights))
    for t in [rough_tool, *rest_tools(library, rough_tool, float(setup.stock_max[2] - setup.floor_z))]:
        if not (excess(stock, allowance) > limit).any():
            break
        opts = dataclasses.replace(plan.roughing, stepdown=None, stepover=None, helix_diameter=None,
                                   min_helix_diameter=None)
        op = zlevel_roughing(part, setup, t, library.cutting_data(t, setup.material), opts, rest=stock,
                             rest_above=limit, within=within)
        if len(op.points) > 1:
            operations.append(op)
            stock = stock_after_flipped(operations, setup, triangles, start_at(cell), cell)
    if walls:  # the walls and flats the roughing left at its allowance, by the flank as op 1 finishes them
        operations, stock = flats_and_walls_from(part, setup, library, plan, operations, start_at)
    raster = raster_finishing(part, setup, finish_tool, library.cutting_data(finish_tool, setup.material),
                              dataclasses.replace(plan.finishing, steep_angle=90.0), stock=stock,
                              limit=EngagementLimit(depth=limit, allowance=allowance), within=within)
    raster = _only_where(raster, _left_from_below(stock, 0.0), stock, setup)
    if len(raster.points) > 1:
        operations.append(raster)
        stock = stock_after_flipped(operations, setup, triangles, start_at(cell), cell)
    return operations, stock


def _op2_parameters(setup1: Setup, setup: Setup, part_work: trimesh.Trimesh, face_z: float, tool: Tool,
                    jaws: ViseJaws | None, options: Op2Options, left_regions: tuple, checked: int,
                    fixed: int) -> dict:
    """The op-2 job's ``parameters`` (see :func:`plan_op2`): what the post, the setup sheet and the
    operator need to know of the turn-over (``face_z`` [mm] in op-2 work coordinates)."""
    return {
        "op": 2,
        "work_offset": WORK_OFFSET[2],
        # the program's header comment (cadcam.post): what the operator sets up before cycle start
        "setup_note": (f"op 2: part turned over about X, held on its finished faces; G55 zero on the top of "
                       f"the turned-over stock, {_ORIGIN_WORDS[setup.origin]}; faces to Z{face_z:.3f}"),
        "flip": {"axis": FLIP_AXIS, "transform_op1_to_op2": flip_transform(setup1).tolist()},
        "face_z": face_z,
        "holding_mm": round(float(part_work.bounds[0][2] - setup1.stock_min[2]), 4),
        "facing_tool": tool.number,
        # what holds the part in op 2: the cell's soft jaws if it has them, else the plain vise jaws
        "held_in": None if jaws is None else ("vise jaws" if jaws.soft_jaws is None
                                              else f"soft jaws ({jaws.soft_jaws.kind})"),
        "options": options.to_dict(),
        "unreached": [u.to_dict() for u in left_regions],
        "rapids": {"checked": checked, "made_safe": fixed},
    }


def _only_where(op: Operation, left: np.ndarray, stock: Simulation, setup: Setup) -> Operation:
    """``op``'s feed moves within the tool radius of ``left`` grid points, each run reached from the safe height.

    A finishing pass over the whole turned-over part would drop the tool down the finished
    walls towards the vise; only where stock is left from below is it wanted.
    """
    g = stock.grid
    near = near_cells(left, math.ceil((op.tool.radius + g.cell) / g.cell))
    i = np.clip(np.rint((op.points[:, 0] - g.x0) / g.cell).astype(np.int64), 0, g.nx - 1)
    j = np.clip(np.rint((op.points[:, 1] - g.y0) / g.cell).astype(np.int64), 0, g.ny - 1)
    keep = near[j, i] & (op.motion != Motion.RAPID)
    pts: list[np.ndarray] = []
    mot: list[int] = []
    k = 0
    n = len(op.points)
    while k < n:
        if not keep[k]:
            k += 1
            continue
        e = k
        while e + 1 < n and keep[e + 1]:
            e += 1
        run = op.points[k:e + 1]
        if len(run) > 1:
            p0 = run[0]
            air = float(clear_height(stock, op.tool, p0[None, :2])[0]) + float(setup.clearance)
            air = min(max(air, float(p0[2])), float(setup.safe_z))
            pts += [np.array([p0[0], p0[1], setup.safe_z]), np.array([p0[0], p0[1], air])]
            mot += [int(Motion.RAPID), int(Motion.RAPID)]
            pts += list(run)
            mot += [int(Motion.PLUNGE)] + [int(Motion.CUT)] * (len(run) - 1)
            pts.append(np.array([run[-1][0], run[-1][1], setup.safe_z]))
            mot.append(int(Motion.RAPID))
        k = e + 1
    points = np.asarray(pts).reshape(-1, 3)
    return dataclasses.replace(op, name="finish from below", points=points, motion=np.asarray(mot, np.int8))


def op2_sheet_fields(job: Job, op1_program: str, op1_sheet: str) -> dict:
    """What an op-2 setup sheet adds to :func:`cadcam.sheet.setup_sheet` (JSON-ready).

    ``op`` (2), ``work_offset`` (``G55``), ``after`` (op 1's program and sheet file names:
    op 2 runs on what op 1 left, and ``factory verify`` simulates op 1 first), ``flip`` (the
    axis and the op-1 -> op-2 work transform [mm]), ``face_z`` (the part's original bottom
    face in op-2 work coordinates [mm]), ``holding_mm`` (the allowance faced off [mm]) and
    ``held_in`` (``"vise jaws"``, ``"soft jaws (pocket)"``, ...; None: workholding unknown).
    """
    p = job.parameters
    return {
        "op": 2,
        "work_offset": f"G{53 + int(p.get('work_offset', WORK_OFFSET[2]))}",
        "after": {"program": op1_program, "setup_sheet": op1_sheet},
        "flip": p["flip"],
        "face_z": p["face_z"],
        "holding_mm": p["holding_mm"],
        "held_in": p.get("held_in"),
    }


def op2_setup_image(job: Job, part: trimesh.Trimesh, width: int = 720) -> np.ndarray:
    """Op 2's setup as a machinist's sketch: the turned-over part in the vise, looking along X
    (across the jaws) and from the front, with the jaws, the parallels and the allowance to face.

    Parameters
    ----------
    job : Job
        The op-2 job (its setup's stock box, jaws and ``face_z``).
    part : trimesh.Trimesh
        The part in op-2 work coordinates [mm].
    width : int
        Picture width [px].

    Returns
    -------
    (H, W, 3) uint8
        RGB picture; the part grey, the allowance to face hatched orange, jaws and parallels
        dark blue, the work origin (G55) a red cross.
    """
    from PIL import Image, ImageDraw, ImageFont

    s = job.setup
    face_z = float(job.parameters["face_z"])
    boxes = list(s.jaws or ())
    lo = np.minimum.reduce([s.stock_min, *[b.lo for b in boxes]])
    hi = np.maximum.reduce([s.stock_max, *[b.hi for b in boxes]])
    margin, gap, caption = 16, 24, 40
    view_w = (width - 2 * margin - gap) / 2
    # One scale for both views: each shows a horizontal axis (Y, then X) against Z.
    scale = min(view_w / max(hi[1] - lo[1], 1e-6), view_w / max(hi[0] - lo[0], 1e-6),
                360.0 / max(hi[2] - lo[2], 1e-6))
    height = int(2 * margin + caption + (hi[2] - lo[2]) * scale)
    img = Image.new("RGB", (width, height), (255, 255, 255))
    draw = ImageDraw.Draw(img)
    font = ImageFont.load_default()
    tri = np.asarray(part.triangles)
    for v, (axis, name) in enumerate(((1, "looking along X (across the jaws)"), (0, "from the front"))):
        ox = margin + v * (view_w + gap)

        def px(h: float, z: float) -> tuple[float, float]:
            return ox + (h - lo[axis]) * scale, margin + (hi[2] - z) * scale

        sx0, sx1 = float(s.stock_min[axis]), float(s.stock_max[axis])
        # The holding allowance op 2 faces off: the stock top down to the part's bottom face.
        a, b = px(sx0, 0.0), px(sx1, face_z)
        draw.rectangle([a, b], fill=(253, 214, 170), outline=(200, 110, 20))
        for k in np.arange(a[0] - (b[1] - a[1]), b[0], 8.0):
            x_a, x_b = max(k, a[0]), min(k + (b[1] - a[1]), b[0])
            if x_b > x_a:
                draw.line([(x_a, a[1] + (x_a - k)), (x_b, a[1] + (x_b - k))], fill=(220, 140, 60))
        for t in tri:  # the part's silhouette
            draw.polygon([px(p[axis], p[2]) for p in t], fill=(150, 150, 150))
        for box in boxes:
            draw.rectangle([px(box.lo[axis], box.hi[2]), px(box.hi[axis], box.lo[2])], fill=(40, 60, 120),
                           outline=(20, 30, 60))
        cx, cy = px(float(s.stock_min[axis]) if s.origin == "top-front-left" else 0.0, 0.0)
        draw.line([(cx - 6, cy), (cx + 6, cy)], fill=(220, 0, 0), width=2)
        draw.line([(cx, cy - 6), (cx, cy + 6)], fill=(220, 0, 0), width=2)
        draw.text((ox, height - caption + 4), name, fill=(0, 0, 0), font=font)
    held = job.parameters.get("held_in") or "vise"
    text = (f"op 2 (G55): part turned over about X, held in the {held} on its finished faces; "
            f"face the allowance to Z{face_z:.3f}")
    draw.text((margin, height - caption / 2 + 2), text, fill=(0, 0, 0), font=font)
    return np.asarray(img, dtype=np.uint8).copy()
