"""The cell runs orders, much faster than real time: ``factory simulate`` as a library.

For every part the orders name, the plan comes from the part catalog (see
:mod:`factory.catalog`), or :func:`factory.plan.plan_part` runs with its defaults and puts it there. From each
plan: the robot's load and unload motion (TOPP-RA timed, read back from the plan's MCAP), the
program's time estimate and toolpath, and camera steps: the rack camera locates a rendered
blank, the out-tray camera inspects the rendered part (and a damaged one, for rejects); those
results are kept in the catalog beside the plan. :func:`robotprog.cellsim.simulate` then runs
the orders (``--faults SEED`` injects missed grasps, missing stock, machine alarms and failed
inspections) in :func:`run_cell`, and :func:`write_cell_log` logs the run to one MCAP.
"""

from __future__ import annotations

import bisect
import contextlib
import dataclasses
import functools
import heapq
import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import trimesh

from cadcam.cutting_power import SpindleLoad, program_spindle_load
from cadcam.gcode import parse_gcode
from cadcam.mesh import load_planned_part
from cadcam.model import Setup
from cadcam.relief import block_corners
from cadcam.timeline import MachineTimeline, machine_timeline, stock_snapshots
from cadcam.tools import ToolLibrary, load_tool_library
from cadcam.verify import VerifyOptions
from factory.camera_msgs import camera_info_msg, compressed_image_msg
from factory.cellinputs import CellInputs
from factory.catalog import CatalogEntry, catalog_record, find_entry, sha256_file
from factory.cellcameras import Shot, Stations, camera_shots, cell_stations
from factory.rackloop import BlankPart, RackLoop, RackPick, blank_part, facing_reach
from factory.cellmsgs import (ComponentStatus, Detection, OrderLine, cell_summary, detected_object_array,
                              diagnostic_array, image_annotations, machine_signal, machine_state, order_queue,
                              robot_state, scheduler_state)
from factory.diagnostics import door, gripper
from factory.core.errors import CellError, FactoryError, McapError
from factory.core.setupsheet import SetupSheet
from factory.live import Fanout, LiveSink
from factory.mcapfork import big_log
from factory.mcaplog import read_messages
from factory.rosmsgs import (TYPESTORE, RestampedCdr, Serialized, TfCdr, cube_marker, log_msg, marker_array, ros_time,
                             tf_message, transform_stamped, triangle_mesh_marker)
from factory.plan import PlanRequest, plan_part
from factory.core.progress import Progress, Stopwatch, stage_callback
from factory.core.resources import FIXTURES
from factory.core.units import MM_PER_M
from factory.tending import LinkPoses, RobotStateLog, log_cell
from factory.verify import flip_of, part_triangles, read_sheet, run_verify_after
from factory.views import heightfield_mesh
from robotprog.cell import Cell, load_cell
from robotprog.cellsim import EventSink, PartProcess, RunningSummary, SimulationResult, simulate as run_simulation
from robotprog.collision import CollisionWorld, collision_world
from robotprog.frames import setup_sheet_to_cell
from robotprog.seat import AfterMoves
from robotprog.tending import part_box_in_vise
from robotprog.machineio import SIGNALS, UNLOADS
from robotprog.programs import VERDICT_AFTER
from robotprog.orders import Order
from vision.camera import CameraModel
from vision.handeye import invert

log = logging.getLogger(__name__)

_T = TYPESTORE.types
_Marker = _T["visualization_msgs/msg/Marker"]

#: Exposure and image transfer of one camera picture [s], added to the measured processing time.
CAMERA_OVERHEAD_S = 0.1
#: Rates of the logged robot state and machine tool position [Hz of simulated time].
ROBOT_RATE_HZ = 25.0
TOOL_RATE_HZ = 0.2
#: Stock snapshots per program, and triangles per snapshot (decimated height field).
STOCK_SNAPSHOTS = 8
STOCK_TRIANGLES = 3000
#: Verify grid of the stock snapshots [mm].
STOCK_GRID_MM = 1.0
#: Split of the load phase: the moves up to this one pick the blank (FETCH_RAW), the rest load it.
LAST_FETCH_MOVE = "load: retreat from rack"
FIRST_FETCH_MOVE = "load: home to above rack"
#: The flip phase of a part in two setups: its first and last moves (:mod:`robotprog.flip`).
FIRST_FLIP_MOVE = "flip: home to above vise"
LAST_FLIP_MOVE = "flip: return home"


# --- robot motion of a plan --------------------------------------------------------------


@dataclass(frozen=True)
class RobotMotion:
    """The joint samples of a plan's load + unload motion, read back from its MCAP.

    Attributes
    ----------
    moves : tuple of (name, start, end)
        Each move and its time span in the plan [s].
    t : (n,) float
        Sample times [s].
    q : (n, dof) float
        Joint positions [rad].
    """

    moves: tuple[tuple[str, float, float], ...]
    t: np.ndarray
    q: np.ndarray

    def span(self, first: str, last: str) -> tuple[float, float]:
        """Time span [s] from the start of move ``first`` to the end of move ``last``."""
        names = [m[0] for m in self.moves]
        for name in (first, last):
            if name not in names:
                raise CellError(f"the plan has no move {name!r}", source="robot plan")
        return self.moves[names.index(first)][1], self.moves[names.index(last)][2]

    def duration(self, first: str, last: str) -> float:
        t0, t1 = self.span(first, last)
        return t1 - t0

    def samples(self, t0: float, t1: float, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions at ``rate_hz`` over [t0, t1] of the plan (ends included): (times [s], q [rad])."""
        ts = np.append(np.arange(t0, t1, 1.0 / rate_hz), t1)
        q = np.column_stack([np.interp(ts, self.t, self.q[:, j]) for j in range(self.q.shape[1])])
        return ts, q


def read_motion(mcap: Path) -> RobotMotion:
    """The robot motion a ``factory plan`` MCAP holds (``/robot/events`` and ``/joint_states``)."""
    events, t, q = [], [], []
    for topic, stamp, msg in read_messages(mcap, ["/robot/events", "/joint_states"]):
        if topic == "/robot/events":
            events.append((msg.data, stamp * 1e-9))
        else:
            t.append(stamp * 1e-9)
            q.append(np.asarray(msg.position, dtype=float))
    if not events or len(t) < 2:
        raise McapError("no robot motion in the plan (planned with --no-robot?)", source=mcap)
    ends = [s for _, s in events[1:]] + [t[-1]]
    moves = tuple((name, start, end) for (name, start), end in zip(events, ends))
    return RobotMotion(moves, np.asarray(t), np.asarray(q))


# --- per-part assets ----------------------------------------------------------------------


@dataclass(frozen=True)
class PartAssets:
    """Everything the simulation and its log need of one planned part."""

    part: Path
    material: str
    entry: CatalogEntry
    process: PartProcess
    motion: RobotMotion
    transform_vise_to_work: np.ndarray
    toolpath: Any
    timeline: MachineTimeline
    stock: tuple[tuple[float, np.ndarray, np.ndarray], ...]
    shots: dict[str, Shot]
    planned_now: bool
    #: The op-2 program's timeline of a part in two setups (None: one setup).
    timeline_op2: MachineTimeline | None = None
    #: Cutting power along op 1's program, and op 2's (None: one setup), from the volume each
    #: move removed in the stock model (:mod:`cadcam.cutting_power`).
    spindle: SpindleLoad | None = None
    spindle_op2: SpindleLoad | None = None
    #: Its blank and the plan's pick, for the rack camera's closed loop (:mod:`factory.rackloop`).
    blank: BlankPart | None = None

    def timeline_of(self, op: int | None) -> MachineTimeline:
        """The program timeline of operation ``op`` (None or 1: op 1's)."""
        return self.timeline_op2 if op == 2 and self.timeline_op2 is not None else self.timeline

    def spindle_of(self, op: int | None) -> SpindleLoad:
        """The cutting power along operation ``op``'s program (None or 1: op 1's)."""
        return self.spindle_op2 if op == 2 and self.spindle_op2 is not None else self.spindle


def part_process(motion: RobotMotion, machining_s: float, shots: dict[str, Shot],
                 op2_machining_s: float | None = None, reject_s: Sequence[float] = ()) -> PartProcess:
    """Step durations of one part from its plan (see :class:`robotprog.cellsim.PartProcess`).

    A rejected part takes the posted program's way: the unload up to the verdict
    (:data:`robotprog.programs.VERDICT_AFTER`), then the planned reject branch, whose move
    durations [s] are ``reject_s`` (the plan summary's ``robot.reject_moves``); without one the
    program does not branch and a rejected part goes to the out-tray like any other.
    ``op2_machining_s`` [s]: the op-2 program of a part in two setups, whose robot plan turns it
    over (the ``flip:`` moves).
    """
    load = [m for m in motion.moves if m[0].startswith("load:")]
    unload = [m for m in motion.moves if m[0].startswith("unload:")]
    flip = [m for m in motion.moves if m[0].startswith("flip:")]
    if not load or not unload:
        raise CellError("the plan has no load or no unload moves", source="robot plan")
    if (op2_machining_s is not None) != bool(flip):
        raise CellError("the plan has two setups but its robot plan does not turn the part over" if not flip
                        else "the robot plan turns the part over but the plan has one setup", source="robot plan")
    fetch_s = motion.duration(FIRST_FETCH_MOVE, LAST_FETCH_MOVE)
    unload_s = unload[-1][2] - unload[0][1]
    return PartProcess(
        fetch_s=fetch_s,
        load_s=load[-1][2] - load[0][1] - fetch_s,
        machining_s=machining_s,
        unload_s=unload_s,
        locate_s=CAMERA_OVERHEAD_S + shots["locate"].processing_s,
        inspect_s=CAMERA_OVERHEAD_S + shots["inspect"].processing_s,
        reject_s=(motion.duration(unload[0][0], VERDICT_AFTER) + float(sum(reject_s))) if len(reject_s) else unload_s,
        regrasp_s=motion.duration(FIRST_FETCH_MOVE, FIRST_FETCH_MOVE),
        flip_s=motion.duration(FIRST_FLIP_MOVE, LAST_FLIP_MOVE) if flip else 0.0,
        op2_machining_s=op2_machining_s,
    )


def reject_moves(summary: dict[str, Any]) -> tuple[float, ...]:
    """Durations [s] of the planned reject branch in a plan summary (empty: the program does not branch).

    Raises
    ------
    CellError
        The summary has no robot plan, or was written before plans carried their reject branch.
    """
    robot = summary.get("robot") or {}
    if "reject_moves" not in robot:
        raise CellError("the plan summary has no reject branch (robot.reject_moves): plan the part again",
                        source="robot plan")
    return tuple(float(m["duration_s"]) for m in robot["reject_moves"])


def op2_of(summary: dict[str, Any]) -> dict[str, Any] | None:
    """The op-2 entry of a plan summary's ``setups`` (None: the part is machined in one setup)."""
    return next((s for s in summary.get("setups") or () if s.get("op") == 2), None)


def seen_part(part: Path, setup: Setup, sheet: SetupSheet, source: str) -> trimesh.Trimesh:
    """What the cameras see of a planned part, in the part file's axes [mm]: the part read as its
    setup sheet says (:func:`cadcam.mesh.load_planned_part`, already in mm), or for a relief, which
    leaves the machine in its block, that block."""
    loaded = load_planned_part(part, setup.mesh_scale, sheet.intake, source=source)
    if loaded.surface is None:
        return loaded.mesh.copy()
    corners = block_corners(setup) * float(setup.mesh_scale)  # block_corners: file units
    return trimesh.creation.box(bounds=[corners.min(axis=0), corners.max(axis=0)])


def margin_along_jaws(part: Path, setup: Setup, sheet: SetupSheet, source: str) -> float:
    """How far the stock reaches beyond the part along the vise's jaws (work X) at the part's nearer
    end [mm]: how far the blank may sit off along the jaws before op 1 cuts the part past the stock's
    end. The part as its file has it (a relief: its surface, not the base verify puts under it)."""
    loaded = load_planned_part(part, setup.mesh_scale, sheet.intake, source=source)
    xs = trimesh.transform_points(np.asarray(loaded.mesh.vertices), setup.transform_mesh_to_work)[:, 0]
    return float(max(0.0, min(xs.min() - setup.stock_min[0], setup.stock_max[0] - xs.max())))


def prepare_part(part: Path, material: str, entry: CatalogEntry, stations: Stations, camera_sha256: str,
                 planned_now: bool, library: ToolLibrary | None = None) -> PartAssets:
    """Read a catalog plan and derive what the simulation needs (see :class:`PartAssets`);
    ``library``: the tool library the plan was made with (default ``fixtures/tools.yaml``), for
    the material's specific cutting energy and the spindle's rated power."""
    library = library if library is not None else load_tool_library()
    summary = entry.summary
    if not summary.get("verify", {}).get("ok", True):
        raise FactoryError("its plan does not verify (gouge or rapid crash)", source=entry.summary_path)
    sheet_path = entry.output("setup_sheet")
    read = read_sheet(sheet_path)
    setup, tools, sheet = read.setup, read.tools, read.sheet
    program_path = entry.output("program")
    moves = parse_gcode(program_path.read_text(encoding="utf-8"), source=str(program_path))
    timeline = machine_timeline(moves)
    triangles = part_triangles(part, setup, summary["catalog"]["mesh_sha256"], sheet.intake)
    times = np.linspace(0.0, timeline.duration, STOCK_SNAPSHOTS + 1)
    stock = []
    for t, sim in stock_snapshots(moves, tools, setup, triangles, times, cell=STOCK_GRID_MM,
                                     timeline=timeline):
        vertices, faces = heightfield_mesh(sim.grid.xs, sim.grid.ys, sim.stock_top, max_triangles=STOCK_TRIANGLES)
        stock.append((float(t), vertices / 1000.0, faces, sim.removed_volume))
        last_sim = sim
    mcap = entry.output("mcap")
    motion = read_motion(mcap)
    op2 = op2_of(summary)
    spindle = program_spindle_load(timeline, stock[-1][3], library, material)
    timeline_op2 = spindle_op2 = None
    if op2 is not None:
        program2 = entry.output("program_op2")
        text2 = program2.read_text(encoding="utf-8")
        timeline_op2 = machine_timeline(parse_gcode(text2, source=str(program2)))
        # op 2 cuts op 1's stock turned over: its engagement from the same stock model
        sheet2_path = entry.output("setup_sheet_op2")
        op2_sheet = read_sheet(sheet2_path)
        verified2 = run_verify_after(last_sim, flip_of(op2_sheet.sheet, sheet2_path), text2, str(program2),
                                     op2_sheet.setup, op2_sheet.tools,
                                     part_triangles(part, op2_sheet.setup, summary["catalog"]["mesh_sha256"],
                                                    op2_sheet.sheet.intake),
                                     VerifyOptions(cell=STOCK_GRID_MM))
        spindle_op2 = program_spindle_load(timeline_op2, verified2.simulation.removed_volume, library, material)
    toolpath = next((m for topic, _, m in read_messages(mcap, ["/cam/toolpath"])), None)
    in_vise = setup_sheet_to_cell(sheet, str(sheet_path))
    seen = seen_part(part, setup, sheet, str(sheet_path))
    shots = camera_shots(entry, seen, np.asarray(setup.stock_size), stations, camera_sha256)
    box = part_box_in_vise(in_vise, np.asarray(seen.vertices) / float(setup.mesh_scale))  # as the plan's robot had it
    reach = None if op2 is None else facing_reach(op2_sheet.setup, op2_sheet.sheet.operations, op2_sheet.tools)
    after = AfterMoves((), in_vise.stock_min, in_vise.stock_max, box.low, box.high, 1 if op2 is None else 2,
                       math.inf if reach is None else reach / MM_PER_M)
    return PartAssets(
        part=part, material=material, entry=entry,
        process=part_process(motion, float(sheet.estimated_cycle_s), shots,
                             None if op2 is None else float(op2["estimated_cycle_s"]), reject_moves(summary)),
        motion=motion, transform_vise_to_work=in_vise.transform_vise_to_work, toolpath=toolpath,
        timeline=timeline, stock=tuple((t, v, f) for t, v, f, _ in stock), shots=shots, planned_now=planned_now,
        timeline_op2=timeline_op2, spindle=spindle, spindle_op2=spindle_op2,
        blank=blank_part(np.asarray(setup.stock_size, dtype=float), motion, margin_along_jaws(part, setup, sheet,
                                                                                               str(sheet_path)), after))


def plan_parts(orders: tuple[Order, ...], catalog: Path, cell_path: Path, tools: Path | None, stations: Stations,
               camera_sha256: str, progress: Progress | None = None,
               watch: Stopwatch | None = None) -> dict[tuple[Path, str], PartAssets | str]:
    """Assets of every (part, material) the orders name, planning what the catalog lacks;
    a part that cannot be had maps to the one-line reason.

    A part missing from the catalog is planned into the catalog's own folder for it,
    ``CATALOG/PART-MATERIAL-KEY8/``. The catalog owns that folder: what an interrupted run left
    there (files without their summary, see :mod:`factory.plan`) is replaced."""
    watch = watch if watch is not None else Stopwatch()
    report = progress or (lambda stage, done, total: None)
    wanted = list(dict.fromkeys((o.part, o.material) for o in orders))
    cell_sha = sha256_file(cell_path)
    tools_sha = sha256_file(tools or FIXTURES / "tools.yaml")
    library = load_tool_library(tools)
    out: dict[tuple[Path, str], PartAssets | str] = {}
    for i, (part, material) in enumerate(wanted):
        report("parts", i, len(wanted))
        if not part.is_file():
            out[(part, material)] = f"{part}: part file not found"
            continue
        key = catalog_record(sha256_file(part), material, cell_sha, tools_sha)["key"]
        try:
            entry = find_entry(catalog, key)
            planned_now = entry is None
            if entry is None:
                folder = catalog / f"{part.stem}-{material}-{key[:8]}"
                with watch("plan"):
                    planned = plan_part(PlanRequest.defaults(part, material, cell_path, tools), progress)
                    summary = planned.write(folder, overwrite=True)
                entry = CatalogEntry(folder / f"{part.stem}.plan.json", summary)
            with watch("prepare"):
                out[(part, material)] = prepare_part(part, material, entry, stations, camera_sha256, planned_now,
                                                     library)
        except FactoryError as e:
            out[(part, material)] = f"{part}: {e}"
    report("parts", len(wanted), len(wanted))
    return out


@dataclass(frozen=True)
class CellRun:
    """A simulated run of orders through the cell (see :func:`run_cell`).

    Attributes
    ----------
    orders : tuple of Order
    cell : Cell
    world : CollisionWorld
    stations : Stations
    assets : dict
        (part, material) -> its :class:`PartAssets`, or the one-line reason it cannot be made.
    result : SimulationResult
        The scheduler's log, activities, order outcomes and summary figures.
    seconds : dict
        Wall time per stage [s].
    picks : tuple of RackPick
        With blank offsets: every picture of a blank the rack camera took, what it located and the
        grasp it led to (:mod:`factory.rackloop`), in the order taken.
    """

    orders: tuple[Order, ...]
    cell: Cell
    world: CollisionWorld
    stations: Stations
    assets: dict[tuple[Path, str], PartAssets | str]
    result: SimulationResult
    seconds: dict[str, float]
    picks: tuple[RackPick, ...] = ()

    @property
    def ready(self) -> dict[tuple[Path, str], PartAssets]:
        """The parts that could be made."""
        return {k: v for k, v in self.assets.items() if isinstance(v, PartAssets)}


def run_cell(orders: tuple[Order, ...], inputs: CellInputs = CellInputs(), *, progress: Progress | None = None,
             events: Callable[[dict[tuple[Path, str], PartAssets | str]], EventSink] | None = None) -> CellRun:
    """Run ``orders`` through the cell ``inputs`` name: plans from their catalog (planning what it lacks
    into it), camera steps, then the discrete-event simulation with their faults. Writes nothing but
    the catalog (and what ``events`` writes).

    ``events``, if given, is called once the parts are planned, with what :class:`CellRun` ``assets``
    holds, and returns the sink the simulation tells every event as it goes (for example
    :meth:`factory.record.RunRecorder.begin`).

    With the inputs' blank offsets each blank stands off its slot's centre and the loop is closed: the
    rack camera locates it, the pick is corrected and proven, or the grasp refused (:mod:`factory.rackloop`);
    with their rack light the rack camera's pictures are taken in that real light (:mod:`vision.lit`).

    Raises
    ------
    CellError, VisionError
        The cell or camera file is malformed. A part that cannot be planned fails its orders
        only (see :class:`CellRun` ``assets``).
    FactoryError
        A fault rate without a seed of faults.
    """
    faults, scatter = inputs.fault_model(), inputs.scatter()
    watch = Stopwatch(progress)
    with watch("cell"):
        cell = load_cell(inputs.cell)
        world = collision_world(cell)
        camera = CameraModel.read(inputs.camera)
        stations = cell_stations(cell, camera)
    assets = plan_parts(orders, inputs.catalog, inputs.cell, inputs.tools, stations, sha256_file(inputs.camera),
                        progress, watch)
    processes = {k: (v.process if isinstance(v, PartAssets) else v) for k, v in assets.items()}
    loop = None if scatter is None else RackLoop(
        cell, world.robot, stations, {k: v.blank for k, v in assets.items() if isinstance(v, PartAssets)}, scatter,
        light=inputs.rack_condition())
    with watch("simulate"):
        sink = events(assets) if events is not None else None
        result = run_simulation(orders, processes, faults, progress=stage_callback(progress, "orders"), sink=sink,
                                picks=loop)
    return CellRun(orders, cell, world, stations, assets, result, dict(watch.seconds),
                   () if loop is None else tuple(loop.picks))


# --- the log --------------------------------------------------------------------------------


def _ns(t: float) -> int:
    return int(round(t * 1e9))


def _delete_all(ns: str, frame: str, t: float) -> Any:
    """A marker that clears every marker of the topic (DELETEALL)."""
    marker = cube_marker(ns, 0, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (0.0, 0.0, 0.0, 0.0), frame, _ns(t))
    marker.action = _Marker.DELETEALL
    return marker


def _restamp(array: Any, stamp_ns: int) -> Any:
    """Stamp every header of a MarkerArray ``stamp_ns`` [ns], in place: call it just before writing
    (the same message is logged at each load)."""
    for mk in array.markers:
        mk.header.stamp = ros_time(stamp_ns)
    return array


class _PartMarkers:
    """Parts' stock snapshots and toolpaths as logged: each serialised once per part and restamped
    at each use (:class:`RestampedCdr`; a stock snapshot is thousands of points). The few parts
    under way at once stay cached, not every part the orders name."""

    def __init__(self, assets: dict[tuple[Path, str], PartAssets]) -> None:
        self._stock = functools.lru_cache(maxsize=4 * (STOCK_SNAPSHOTS + 1))(
            lambda key, k: RestampedCdr(_stock_msg(assets[key], k, 0.0), _restamp))
        self._toolpath = functools.lru_cache(maxsize=4)(lambda key: RestampedCdr(assets[key].toolpath, _restamp))

    def stock_at(self, p: PartAssets, k: int, t: float) -> Serialized:
        """Stock snapshot ``k`` of part ``p`` at ``t`` [s]."""
        return self._stock((p.part, p.material), k).at(_ns(t))

    def toolpath_at(self, p: PartAssets, t: float) -> Serialized:
        """Part ``p``'s toolpath at ``t`` [s] (``p.toolpath`` is not None)."""
        return self._toolpath((p.part, p.material)).at(_ns(t))


class _Queue:
    """Every order's status as the scheduler's log goes: queued, running (good parts sorted and
    rejects so far), then its outcome with the final counts and reason."""

    def __init__(self, orders: tuple[Order, ...]) -> None:
        self.lines = {o.id: OrderLine(o.id, o.part.name, o.material, o.quantity, 0, 0, "queued") for o in orders}
        self.failed_inspection: set[int] = set()

    def update(self, e: Any, outcome: Any | None) -> bool:
        """Take one log entry (``outcome``: the order's outcome when this is its last entry);
        True when the order's line changed."""
        line = before = self.lines[e.order]
        if e.event == "inspect_fail":
            self.failed_inspection.add(e.job)
        if outcome is not None:
            line = dataclasses.replace(line, good=outcome.good, rejected=outcome.rejected, state=outcome.outcome,
                                       reason=outcome.reason)
        elif e.event == "sorted":
            bad = e.job in self.failed_inspection
            line = dataclasses.replace(line, good=line.good + (not bad), rejected=line.rejected + bad,
                                       state="running")
        elif e.job:
            line = dataclasses.replace(line, state="running")
        self.lines[e.order] = line
        return line != before

    def message(self, t: float) -> Any:
        return order_queue(self.lines.values(), _ns(t))


def _program_state(timeline: MachineTimeline, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tool number, G-code line and feed [mm/min] at program times ``t`` [s] (feed 0 while the
    tool stands still, e.g. during a tool change)."""
    n = len(timeline.end)
    i = np.clip(np.searchsorted(timeline.end, t, side="left"), 1, n - 1) if n > 1 else np.zeros(len(t), int)
    span = timeline.end - timeline.start
    length = np.r_[0.0, np.linalg.norm(np.diff(timeline.points, axis=0), axis=1)]
    moving = (timeline.start[i] <= t) & (span[i] > 0)
    feed = np.where(moving, 60.0 * length[i] / np.where(span[i] > 0, span[i], 1.0), 0.0)
    return timeline.tool[i], timeline.line[i], feed


def _spindle_load(p: PartAssets, op: int | None, t: np.ndarray, rpm: np.ndarray) -> np.ndarray:
    """Spindle load [% of rated power] at program times ``t`` [s] of operation ``op``, 0 where
    the spindle stands (``rpm`` [rev/min] 0): the mean over the :data:`TOOL_RATE_HZ` sample
    period before each time, so the samples together account for every joule the cut spent."""
    return np.where(rpm > 0, p.spindle_of(op).load_percent_at(t, window_s=1.0 / TOOL_RATE_HZ), 0.0)


def spindle_speeds(p: PartAssets, op: int | None = None) -> dict[int, float]:
    """Spindle speed [rev/min] of each tool of the part's program (op 2: the op-2 program's), from
    its setup sheet."""
    path = p.entry.output("setup_sheet_op2" if op == 2 and p.timeline_op2 is not None else "setup_sheet")
    try:
        sheet = json.loads(path.read_text(encoding="utf-8"))
        return {int(op["tool"]): float(op["spindle_rpm"]) for op in sheet["operations"]}
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise McapError(f"cannot read the spindle speeds: {e}", source=path) from None


def _detections(shot: Shot, p: PartAssets, step: str, serial: str) -> list[Detection]:
    """The station's detections as message values. The circle around the footprint is the blank's
    (locate) or the finished stock's (inspect) bounding rectangle seen at the fit's scale."""
    verts = p.stock[0][1] if step == "locate" else p.stock[-1][1]  # [m]
    radius_mm = 500.0 * float(np.hypot(*np.ptp(np.asarray(verts)[:, :2], axis=0)))
    out = []
    for d in shot.detections:
        inspected = "pass" in d
        out.append(Detection(
            class_name="part" if step == "inspect" else "blank", center_px=(d["pixel"][0], d["pixel"][1]),
            radius_px=radius_mm / d["mm_per_px"], confidence=float(np.clip(d["score"], 0.0, 1.0)),
            xyz=(d["x"], d["y"], d["z"]), yaw=d["yaw"], serial=serial, inspected=inspected,
            passed=bool(d.get("pass", False)), max_deviation=d.get("max_deviation_mm", 0.0) / 1000.0,
            tolerance=d.get("tolerance_mm", 0.0) / 1000.0, position_uncertainty=d["expected_error_mm"] / 1000.0,
            yaw_uncertainty=np.radians(d["expected_error_deg"]), smallest_burr=d.get("smallest_burr_mm", 0.0) / 1000.0))
    return out


#: Which component a fault code belongs to (timeouts: the machine while machining, else the robot; a
#: failed inspection is the machine's verdict, read as the robot takes the part out of the vise).
_FAULT_COMPONENT = {"grasp_missed": "robot", "stock_not_found": "camera", "machine_alarm": "machine",
                    "inspect_fail": "machine"}
_COMPONENTS = ("machine", "robot", "camera", "scheduler")
#: Events of a job still working off its fault: the recovery decision and the retry it starts.
_RETRYING = ("recover", "retry_fetch", "rerun")


class _Resources:
    """What the machine and the robot are doing at a time, from the simulation's activities, as
    diagnostic key values (units in the keys)."""

    def __init__(self, result: SimulationResult, part_of: Any, spindle: Any) -> None:
        self.by = {r: sorted((a for a in result.activities if a.resource == r), key=lambda a: a.start)
                   for r in ("machine", "robot")}
        self.starts = {r: [a.start for a in acts] for r, acts in self.by.items()}
        self.jobs, self.part_of, self.spindle = result.jobs, part_of, spindle

    def _last(self, resource: str, t: float) -> Any | None:
        k = bisect.bisect_right(self.starts[resource], t)
        return self.by[resource][k - 1] if k else None

    def at(self, t: float) -> dict[str, dict[str, str]]:
        m, r = self._last("machine", t), self._last("robot", t)
        machine = {"state": "idle", "serial": "", "tool": "0", "spindle_speed_rpm": "0", "spindle_load_percent": "0",
                   "program_line": "0"}
        if m is not None and t < m.end:
            machine.update(state="cutting" if m.action == "cut" else "reset",
                           serial=f"{self.jobs.get(m.job, '?')}-{m.job}")
            if m.action == "cut":
                p = self.part_of(m.job)
                program_t = np.array([t - m.start])
                tool, line, _ = _program_state(p.timeline_of(m.op), program_t)
                rpm = self.spindle(p, m.op).get(int(tool[0]), 0.0)
                load = _spindle_load(p, m.op, program_t, np.array([rpm]))[0]
                machine.update(tool=str(int(tool[0])), program_line=str(int(line[0])),
                               spindle_speed_rpm=f"{rpm:.0f}", spindle_load_percent=f"{load:.2f}")
        elif m is not None and m.outcome in ("machine_alarm", "timeout"):
            machine["state"] = "alarm"
        robot = {"activity": "idle", "serial": ""}
        if r is not None and t < r.end:
            robot = {"activity": r.action, "serial": f"{self.jobs.get(r.job, '?')}-{r.job}"}
        machine["door"] = door(r, t)
        robot.update(gripper(r, t))
        return {"machine": machine, "robot": robot}


class _Health:
    """Each component's health as the scheduler's log goes: a fault is ERROR on its component and
    on the scheduler from the entry that raised it until it is recovered: until the retried step
    succeeds (the stock fetched, the program run), the part is scrapped or abandoned, or, for a
    failed inspection, sorted to the reject bin."""

    def __init__(self, resources: "_Resources") -> None:
        self.faults: dict[int, tuple[str, str, str, str]] = {}  # job -> (component, code, order, message)
        self.state: dict[int, tuple[str, str]] = {}  # job -> (order, state) of running jobs
        self.resources = resources
        self.values: dict[str, dict[str, str]] = resources.at(0.0)

    def update(self, e: Any) -> bool:
        """Take one log entry; True when a status changed."""
        before = self.statuses()
        self.values = self.resources.at(e.time)
        # A failed inspection sends the part to SORT, not FAULT; it stays an error until sorted.
        if e.state == "FAULT" or e.event == "inspect_fail":
            where = _FAULT_COMPONENT.get(e.event)
            if where is None:
                where = "machine" if self.state.get(e.job, ("", ""))[1] == "MACHINING" else "robot"
            self.faults[e.job] = (where, e.event, e.order, e.message)
        elif e.event not in _RETRYING:
            self.faults.pop(e.job, None)
        if e.state == "IDLE":  # sorted, scrapped or abandoned: the job is over
            self.state.pop(e.job, None)
        else:
            self.state[e.job] = (e.order, e.state)
        return self.statuses() != before

    def statuses(self) -> list[ComponentStatus]:
        out = []
        for name in _COMPONENTS:
            faults = [(job, f) for job, f in sorted(self.faults.items()) if name == "scheduler" or f[0] == name]
            values = {"fault": ", ".join(f[1] for _, f in faults), "jobs_in_fault": str(len(faults)),
                      **self.values.get(name, {})}
            if name == "scheduler":
                values["jobs_running"] = str(len(self.state))
                values["states"] = ", ".join(f"{o}-{j}: {st}" for j, (o, st) in sorted(self.state.items()))
            message = "; ".join(f"{f[2]}-{job} {f[1]}: {f[3]}" for job, f in faults) or "ok"
            out.append(ComponentStatus(f"cell/{name}", "ERROR" if faults else "OK", message, values))
        return out


def write_cell_log(path: Path | None, result: SimulationResult, assets: dict[tuple[Path, str], PartAssets],
                   orders: tuple[Order, ...], cell: Cell, world: CollisionWorld, stations: Stations, *,
                   overwrite: bool, inputs: dict[str, str], parameters: dict[str, Any],
                   live: LiveSink | None = None, robot_rate_hz: float = ROBOT_RATE_HZ,
                   picks: Sequence[RackPick] = ()) -> dict[str, int]:
    """Write the simulation to MCAP (``path``) and/or stream it to a live sink (the Foxglove live view,
    the ROS 2 graph, or both through :class:`factory.live.Fanout`), in log time;
    returns message counts per topic.

    The log streams: each activity and the scheduler's log are generators of their messages in
    time order, merged as the clock reaches them, and a message is made only when it is written,
    so memory stays flat however many orders ran. ``robot_rate_hz`` [Hz of simulated time] is the
    rate of the robot's joint states and link transforms (the ends of each motion always logged):
    lower it for long runs. ``picks``: the run's :attr:`CellRun.picks`; a corrected fetch is logged
    as it moved, each rack picture as taken, and each decision on ``/cell/rack_pick``.
    """
    if not robot_rate_hz > 0:
        raise CellError(f"the robot state rate must be positive, got {robot_rate_hz} Hz", source="--robot-rate")
    order_of = {o.id: o for o in orders}

    def part_of(job: int) -> PartAssets:
        o = order_of[result.jobs[job]]
        return assets[(o.part, o.material)]

    spindle: dict[tuple[Path, str, int | None], dict[int, float]] = {}

    def rpm_of(p: PartAssets, op: int | None = None) -> dict[int, float]:
        """Spindle speed [rev/min] per tool of a part's operation, read once."""
        if (p.part, p.material, op) not in spindle:
            spindle[(p.part, p.material, op)] = spindle_speeds(p, op)
        return spindle[(p.part, p.material, op)]

    # Program time [s] each cut of a job had already done before it (a rerun after an alarm
    # does not log the stock snapshots again): one float per activity.
    cut_before: list[float] = []
    cut_so_far: dict[tuple[int, int | None], float] = {}  # per job and operation
    for a in result.activities:
        done = cut_so_far.get((a.job, a.op), 0.0)
        cut_before.append(done)
        if a.resource == "machine" and a.action == "cut":
            cut_so_far[(a.job, a.op)] = max(done, a.end - a.start)

    markers = _PartMarkers(assets)
    links = LinkPoses(world)
    home = np.asarray(cell.robot.home, dtype=float)
    makespan = float(result.summary["makespan_s"])
    activity_events = (functools.partial(_activity_events, k, a, part_of, cut_before[k], rpm_of, markers,
                                         stations, links, result, robot_rate_hz, picks)
                       for k, a in enumerate(result.activities))
    streams = _staggered(((_ns(a.start), make) for a, make in zip(result.activities, activity_events)),
                         [iter([(0, -1, -1, 0, "", (home, None), False)]),
                          _scheduler_events(result, orders, part_of, rpm_of),
                          _signal_events(result, cell),
                          # its own stream: the makespan is rounded to the millisecond, so the
                          # whole run's summary may come before the last entries' messages
                          iter([(_ns(makespan), 2, 0, 0, "/cell/summary",
                                 functools.partial(cell_summary, result.summary, _ns(makespan)), False)])])
    counts: dict[str, int] = {}
    n_states = 0
    with contextlib.ExitStack() as stack:
        sinks: list[Any] = []
        if path is not None:
            sinks.append(stack.enter_context(
                big_log(path, stage="simulate", overwrite=overwrite, inputs=inputs, parameters=parameters)))
        if live is not None:
            sinks.append(live)
        m = Fanout(sinks)
        log_cell(m, cell, world)
        cams = []
        for name, st in (("rack_camera", stations.rack), ("tray_camera", stations.tray)):
            cams.append(transform_stamped("world", name, invert(st.world_to_camera), 0))
        m.write("/tf_static", tf_message(cams), 0, latched=True)
        states = RobotStateLog(m, world)
        # One stream in log time, robot state and events interleaved: a live view plays it as it goes.
        for stamp, _, _, _, topic, msg, latched in streams:
            if not topic:
                q, poses = msg
                states.write(q, np.zeros_like(q), stamp, poses)
                n_states += 1
                continue
            msg = msg() if callable(msg) else msg
            if isinstance(msg, Serialized):
                m.write_cdr(topic, msg.typename, msg.cdr, stamp, msg.make, latched=latched)
            else:
                m.write(topic, msg, stamp, latched=latched)
            counts[topic] = counts.get(topic, 0) + 1
    counts["/joint_states"] = n_states
    return counts


#: One logged item: (stamp [ns], group, index, position, topic, message or its maker, latched).
#: Sorting on the first four is log-time order; at one stamp, robot states (group -1) come
#: first, then the activities' messages (0) in activity order, then the scheduler's (1). A robot
#: state's topic is "" and its message (joint positions [rad], the links' poses or None).
_Item = tuple[int, int, int, int, str, Any, bool]


def _staggered(pending: Any, running: list[Any]) -> Any:
    """Merge item streams into one in log-time order. ``running`` streams are merged from the
    start; ``pending`` yields (start [ns], maker) sorted by start, and a maker's stream (none of
    whose items is stamped before its start) is made only once the merge reaches its start: the
    streams open at once are the activities under way, not all of the run's."""
    heap: list[tuple[tuple[int, int, int, int], int, _Item, Any]] = []
    serial = 0

    def push(stream: Any) -> None:
        nonlocal serial
        item = next(stream, None)
        if item is not None:
            heapq.heappush(heap, (item[:4], serial, item, stream))
            serial += 1

    for s in running:
        push(iter(s))
    pending = iter(pending)
    upcoming = next(pending, None)
    while heap or upcoming is not None:
        while upcoming is not None and (not heap or upcoming[0] <= heap[0][0][0]):
            push(iter(upcoming[1]()))
            upcoming = next(pending, None)
        if not heap:
            continue
        _, _, item, stream = heapq.heappop(heap)
        yield item
        push(stream)


def _activity_events(k: int, a: Any, part_of: Callable[[int], PartAssets], cut_before: float, rpm_of: Any,
                     markers: _PartMarkers, stations: Stations,
                     links: LinkPoses, result: SimulationResult, robot_rate_hz: float,
                     picks: Sequence[RackPick] = ()) -> Any:
    """The messages of activity number ``k`` (and its robot states), in log-time order, each made
    when it is written; the robot's link poses of the whole activity are made at once."""
    order = result.jobs.get(a.job, "?")
    serial = f"{order}-{a.job}"
    out: list[tuple[float, str, Any]] = []  # (time [s], topic, maker), in the order logged before
    robot: list[_Item] = []
    p = part_of(a.job) if a.resource != "machine" or a.action == "cut" else None

    def add(t: float, topic: str, make: Any) -> None:
        out.append((t, topic, make))

    if a.resource == "robot":
        add(a.start, "/cell/robot", functools.partial(robot_state, a.action, order, serial, _ns(a.start)))
        add(a.end, "/cell/robot", functools.partial(robot_state, "idle", "", "", _ns(a.end)))
        spans = {"fetch": [(FIRST_FETCH_MOVE, LAST_FETCH_MOVE, False)],
                 "missed_grasp": [(FIRST_FETCH_MOVE, LAST_FETCH_MOVE, False),
                                  (FIRST_FETCH_MOVE, FIRST_FETCH_MOVE, True)],
                 "load": [("load: transfer to vise", "load: return home", False)],
                 "flip": [(FIRST_FLIP_MOVE, LAST_FLIP_MOVE, False)],
                 "unload": [("unload: home to above vise", "unload: return home", False)],
                 # the plan's log holds the out-tray way only: the reject way shows up to the verdict
                 "unload_reject": [("unload: home to above vise", VERDICT_AFTER, False)]}.get(a.action, [])
        corrected = picks[a.pick].pick if a.pick is not None and a.action == "fetch" else None
        t = a.start
        for dt_q in (_motion_samples(p, spans, robot_rate_hz) if corrected is None
                     else corrected_samples(p, corrected, robot_rate_hz)):
            for dt, qi in zip(*dt_q):
                if t + dt <= a.end + 1e-9:  # a timed-out move stops where it was
                    robot.append((_ns(t + dt), -1, k, len(robot), "", qi, False))
            t += dt_q[0][-1]
        poses = links.poses(np.array([item[5] for item in robot]))
        robot = [(*item[:5], (item[5], pose), item[6]) for item, pose in zip(robot, poses)]
        if a.action == "load":
            add(a.start, "/tf", functools.partial(_vise_tf, p, a.start))
            if p.toolpath is not None:
                add(a.start, "/machine/toolpath", functools.partial(markers.toolpath_at, p, a.start))
        if a.action == "load" and a.outcome == "loaded":
            add(a.end, "/machine/stock", functools.partial(markers.stock_at, p, 0, a.end))
        if a.action in UNLOADS:
            add(a.end, "/machine/stock", lambda: marker_array([_delete_all("stock", "work", a.end)]))
            add(a.end, "/machine/toolpath", lambda: marker_array([_delete_all("toolpath", "work", a.end)]))
    elif a.resource == "machine":
        after = "alarm" if a.outcome in ("machine_alarm", "timeout") else "idle"
        if a.action != "cut":
            add(a.start, "/cell/machine", functools.partial(machine_state, "reset", order, serial, _ns(a.start)))
            add(a.end, "/cell/machine", functools.partial(machine_state, after, "", "", _ns(a.end)))
        else:
            timeline = p.timeline_of(a.op)
            program_t = np.append(np.arange(0.0, a.end - a.start, 1.0 / TOOL_RATE_HZ), a.end - a.start)
            positions = timeline.position_at(program_t) / 1000.0
            tools, lines, feeds = _program_state(timeline, program_t)
            rpm = rpm_of(p, a.op)
            speeds = np.array([rpm.get(int(tool), 0.0) for tool in tools])
            loads = _spindle_load(p, a.op, program_t, speeds)
            duration = float(timeline.end[-1]) or 1.0
            for dt, xyz, tool, line, feed, speed, load in zip(program_t, positions, tools, lines, feeds, speeds, loads):
                stamp = _ns(a.start + dt)
                add(a.start + dt, "/tf", functools.partial(_tool_tf, xyz, stamp))
                add(a.start + dt, "/cell/machine", functools.partial(
                    machine_state, "cutting", order, serial, stamp, tool=int(tool), spindle_rpm=float(speed),
                    spindle_load=float(load), feed_mm_min=float(feed), tool_position=xyz, line=int(line),
                    progress=min(dt / duration, 1.0)))
            add(a.end, "/cell/machine", functools.partial(machine_state, after, "", "", _ns(a.end)))
            # the stock snapshots are op 1's (op 2 faces the turned-over piece)
            for j, (snap_t, _, _) in enumerate(p.stock if a.op in (None, 1) else ()):
                if cut_before < snap_t <= a.end - a.start:
                    add(a.start + snap_t, "/machine/stock", functools.partial(markers.stock_at, p, j, a.start + snap_t))
    else:
        taken = picks[a.pick] if a.pick is not None and a.action == "locate" else None
        if taken is not None:
            shot = Shot(taken.png or p.shots["empty"].png, [taken.detection] if taken.detection else [], 0.0,
                        not taken.refusal)
            frame = "rack_camera"
            add(a.end, "/cell/rack_pick", functools.partial(rack_pick_msg, taken, serial, _ns(a.end)))
        elif a.action == "locate":
            shot = p.shots["locate" if a.outcome != "stock_not_found" else "empty"]
            frame = "rack_camera"
        else:
            shot = p.shots["reject" if a.outcome == "inspect_fail" else "inspect"]
            frame = "tray_camera"
        stamp = _ns(a.end)
        found = _detections(shot, p, a.action, serial)
        add(a.end, "/camera/image/compressed",
            functools.partial(compressed_image_msg, shot.png, "shot.png", np.zeros(0), stamp, frame))
        add(a.end, "/camera/camera_info", functools.partial(camera_info_msg, stations.rack.camera, stamp, frame))
        add(a.end, "/camera/detections", functools.partial(detected_object_array, found, a.action, a.outcome,
                                                           frame, stamp, links.base_frame))
        add(a.end, "/camera/annotations", functools.partial(image_annotations, found, stamp))
    items = [(_ns(t), 0, k, i, topic, make, False) for i, (t, topic, make) in enumerate(out)]
    return heapq.merge(robot, sorted(items, key=lambda i: i[:4]), key=lambda i: i[:4])


def _motion_samples(p: PartAssets, spans: list[tuple[str, str, bool]], rate_hz: float) -> Any:
    """(times from the span's start [s], joint positions [rad]) of each planned span, at ``rate_hz``."""
    for first, last, backwards in spans:
        t0, t1 = p.motion.span(first, last)
        ts, q = p.motion.samples(t0, t1, rate_hz)
        yield ts - t0, (q[::-1] if backwards else q)


def corrected_samples(p: PartAssets, corrected: Any, rate_hz: float) -> Any:
    """The corrected fetch as it moved: the planned move from home to above the rack, then each of
    the corrected pick's moves (:class:`robotprog.rackpick.CorrectedPick`), at ``rate_hz``."""
    yield from _motion_samples(p, [(FIRST_FETCH_MOVE, FIRST_FETCH_MOVE, False)], rate_hz)
    for m in corrected.moves:
        ts = np.append(np.arange(0.0, m.duration, 1.0 / rate_hz), m.duration)
        q = (np.repeat(m.waypoints[-1:], len(ts), axis=0) if m.kind == "gripper"
             else m.trajectory.sample(np.minimum(ts, m.trajectory.duration))[0])
        yield ts, q


def rack_pick_msg(pick: RackPick, serial: str, stamp: int) -> Any:
    """One decision of the rack camera's closed loop as a ``DiagnosticArray`` of one status
    (``cell/rack_pick``, ERROR when refused; values in mm and deg, units in the keys)."""
    values = {"serial": serial, "slot": str(pick.slot), "attempt": str(pick.attempt)}
    doc = pick.to_dict()
    if doc["rack_slot"] is not None:
        values["rack_row"], values["rack_column"] = (str(v) for v in doc["rack_slot"])
        values["rack_load"] = str(doc["rack_load"])
    for name in ("seat_across_mm", "seat_along_mm"):
        if doc[name] is not None:
            values[name] = f"{doc[name]:.3f}"
    for name in ("offset", "located", "correction"):
        for axis, v in (doc[name] or {}).items():
            values[f"{name}_{axis}"] = f"{v:.3f}"
    for name in ("error_mm", "error_deg", "reported_mm", "reported_deg"):
        if doc[name] is not None:
            values[name] = f"{doc[name]:.3f}"
    values["proven"] = "yes" if pick.pick is not None else "no"
    values["fetch_s"] = f"{pick.fetch_s:.3f}"
    status = ComponentStatus("cell/rack_pick", "ERROR" if pick.refusal else "OK", pick.message(), values)
    return diagnostic_array([status], stamp)


def _signal_events(result: SimulationResult, cell: Cell) -> Any:
    """The machine handshake on /cell/io (:attr:`SimulationResult.signals`, the programs' own
    operations), each message made when written."""
    io = cell.machine
    for n, e in enumerate(result.signals):
        sig = SIGNALS[e.op.signal]
        number = getattr(io, sig.name, None) if io is not None else None
        order = result.jobs.get(e.job, "?")
        stamp = _ns(e.time)
        yield (stamp, 3, n, 0, "/cell/io", functools.partial(
            machine_signal, e.op.op, sig.name, sig.direction, -1 if number is None else number, e.op.level,
            order, f"{order}-{e.job}", stamp), False)


def _scheduler_events(result: SimulationResult, orders: tuple[Order, ...], part_of: Any, rpm_of: Any) -> Any:
    """The scheduler's log as messages (/rosout, /cell/state, the order queue, diagnostics, the
    running summary), in log-time order (the run's own summary apart)."""
    queue = _Queue(orders)
    items: list[tuple[float, str, Any]] = [(0.0, "/cell/orders", queue.message(0.0))]
    last_entry = {e.order: i for i, e in enumerate(result.log)}
    ended = {o.order: o for o in result.outcomes}
    health = _Health(_Resources(result, part_of, rpm_of))
    figures = RunningSummary(result)
    items.append((0.0, "/diagnostics", diagnostic_array(health.statuses(), 0)))
    n = 0
    for i, e in enumerate(result.log):
        if health.update(e):
            items.append((e.time, "/diagnostics", diagnostic_array(health.statuses(), _ns(e.time))))
        level = "info"
        if e.state in ("FAULT", "RECOVER") or e.event in ("inspect_fail", "timeout"):
            level = "warn"
        if e.event == "order_failed" or "operator" in e.message:
            level = "error"
        text = f"{e.order} job {e.job}: {e.event} -> {e.state}" + (f": {e.message}" if e.message else "")
        items.append((e.time, "/rosout", log_msg(level, "cell.scheduler", text, _ns(e.time))))
        if e.job:
            items.append((e.time, "/cell/state", scheduler_state(e.state, e.event, e.order, f"{e.order}-{e.job}",
                                                                 e.message, _ns(e.time))))
        if queue.update(e, ended[e.order] if last_entry[e.order] == i else None):
            items.append((e.time, "/cell/orders", queue.message(e.time)))
        if e.event == "sorted":  # the running figures, as each part reaches a tray
            items.append((e.time, "/cell/summary", cell_summary(figures.at(e.time), _ns(e.time))))
        # the log is in time order: what one entry made goes out before the next is read
        for t, topic, msg in items:
            yield (_ns(t), 1, n, 0, topic, msg, False)
            n += 1
        items.clear()


def _vise_tf(p: PartAssets, t: float) -> Any:
    return tf_message([transform_stamped("vise", "work", p.transform_vise_to_work, _ns(t))])


#: The tool's /tf in the work frame, written straight into its CDR at every tool sample.
_TOOL_TF = TfCdr("work", ["tool"])


def _tool_tf(xyz: np.ndarray, stamp: int) -> Serialized:
    """The tool at ``xyz`` (3,) [m] in the work frame, unrotated, at ``stamp`` [ns]."""
    pose = np.eye(4)
    pose[:3, 3] = xyz
    return Serialized("tf2_msgs/msg/TFMessage", _TOOL_TF.cdr(stamp, np.append(pose[:3, 3], (0.0, 0.0, 0.0, 1.0))),
                      lambda: tf_message([transform_stamped("work", "tool", pose, stamp)]))


def _stock_msg(p: PartAssets, k: int, t: float) -> Any:
    _, vertices, faces = p.stock[k]
    return marker_array([triangle_mesh_marker("stock", 0, vertices, faces, (0.75, 0.75, 0.8, 1.0), "work", _ns(t))])


