"""Machine tending: load a stock blank from the rack into the vise, unload the part to the out-tray.

The plan is a list of :class:`robotprog.planner.TimedMove`: joint-space *transfers* between "above"
poses, straight-line Cartesian *approach* / *retreat* moves between an above pose and the grasp or
place pose, and *gripper* actions (digital outputs, then the settle time). Each phase is a
pick-and-place of :class:`robotprog.planner.MotionPlanner` (:mod:`robotprog.planner` says how the
moves are planned, timed and proven); a part in two setups is turned over between them
(:mod:`robotprog.flip`).

Grasp
-----
Top-down (:func:`robotprog.grasp.top_grasp`), centred on the box's top face, the fingers closing
across its narrower side: open a clearance beyond the box on the way to it and after letting it
go, closed on it while holding it. The blanks beside the picked one in the rack and the parts in
the other out-tray slots are obstacles.

Stock and part placement: in the rack and out-tray the box stands centred on the slot
origin, its edges along the slot axes, bottom at slot height; in the vise per
:mod:`robotprog.frames` (centred on the jaw gap, bottom on the parallels).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from factory.core.errors import CellError, PlanningError
from factory.core.units import MM_PER_M
from robotprog.cell import Box, Cell, Pose, SlotGrid
from robotprog.collision import CollisionWorld, HeldBox, Payload, collision_world, finger_boxes
from robotprog.flip import TURNOVER_AXIS, Piece, held_piece, plan_flip
from robotprog.frames import StockInVise, setup_sheet_to_cell
from robotprog.grasp import GraspOptions, box_pose, open_fingers, top_grasp
from robotprog.roadmap import Roadmap, RoadmapOnDemand
from robotprog.planner import MotionPlanner, PickPlace, PickPlaceNames, PlannerOptions, Station, TimedMove

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TendingOptions:
    """Tending planner settings.

    Attributes
    ----------
    planner : PlannerOptions
        The motion planner's (approach height, IK line step, collision resolution, RRT, seed).
    grasp : GraspOptions
        How deep the fingers reach.
    rack_slot, tray_slot : (int, int)
        (row, column) of the rack slot the stock comes from and the out-tray slot the part goes to.
    reject_drop : float
        Height of a rejected part's bottom above the reject bin's rim when it is let go [m].
    """

    planner: PlannerOptions = field(default_factory=PlannerOptions)
    grasp: GraspOptions = field(default_factory=GraspOptions)
    rack_slot: tuple[int, int] = (0, 0)
    tray_slot: tuple[int, int] = (0, 0)
    reject_drop: float = 0.03


@dataclass(frozen=True, eq=False)
class TendingPlan:
    """Load then unload, as a sequence of moves from home back to home.

    Attributes
    ----------
    moves : tuple of TimedMove
    stock : StockInVise
    part_min, part_max : (3,) float
        Finished part box in the vise frame [m].
    planning_s : float
        Wall time spent planning [s].
    obstacles : tuple of Box
        Boxes the plan avoided besides the cell's: the blanks beside the one picked, the
        parts already in the out-tray (:func:`robotprog.collision.collision_world` ``obstacles``).
    reject : tuple of TimedMove
        The planned alternative to the tray for a rejected part (empty without
        ``cell.reject_bin``): from the end of ``unload: retreat from vise`` to above the
        reject bin, release, home.
    """

    moves: tuple[TimedMove, ...]
    stock: StockInVise
    part_min: np.ndarray
    part_max: np.ndarray
    planning_s: float
    obstacles: tuple[Box, ...] = ()
    reject: tuple[TimedMove, ...] = ()

    @property
    def durations(self) -> tuple[tuple[str, float], ...]:
        """(move name, duration [s]) in order."""
        return tuple((m.name, m.duration) for m in self.moves)

    @property
    def duration(self) -> float:
        """Total time [s]."""
        return float(sum(m.duration for m in self.moves))

    def phase(self, prefix: str) -> tuple[TimedMove, ...]:
        """Moves whose name starts with ``prefix`` (``"load"`` or ``"unload"``)."""
        return tuple(m for m in self.moves if m.name.startswith(prefix))


@dataclass(frozen=True)
class PartBox:
    """The finished part's axis-aligned bounding box in the vise frame: corners ``low`` and ``high``, (3,) [m]."""

    low: np.ndarray
    high: np.ndarray


def part_box_in_vise(stock: StockInVise, vertices: np.ndarray) -> PartBox:
    """Bounding box of the part mesh in the vise frame [m].

    Parameters
    ----------
    stock : StockInVise
    vertices : (n, 3) float
        Mesh vertices in mesh file units (as the setup sheet's ``mesh_scale`` reads them).
    """
    v = np.asarray(vertices, dtype=float) * stock.mesh_scale_m
    t = stock.transform_vise_to_work @ stock.transform_mesh_to_work
    p = v @ t[:3, :3].T + t[:3, 3]
    return PartBox(p.min(axis=0), p.max(axis=0))


def _slot(grid: SlotGrid, slot: tuple[int, int], field_name: str) -> np.ndarray:
    try:
        return grid.slot_transform(*slot)
    except CellError as e:
        raise CellError(str(e.args[0]) if e.args else str(e), source=field_name) from None


def plan_tending(
    cell: Cell,
    sheet: dict[str, Any],
    *,
    part_box: PartBox | None = None,
    world: CollisionWorld | None = None,
    options: TendingOptions = TendingOptions(),
    source: str | None = None,
    setups: int = 1,
    roadmap: Roadmap | RoadmapOnDemand | None = None,
) -> TendingPlan:
    """Plan loading the stock of ``sheet`` into the vise and unloading the finished part; with
    two setups, turning the part over on the flip station between them (:mod:`robotprog.flip`).

    Parameters
    ----------
    cell : Cell
    sheet : dict
        The part's ``factory.setup/1`` setup sheet.
    part_box : PartBox, optional
        Finished part box in the vise frame [m] (:func:`part_box_in_vise`); default the stock box.
    world : CollisionWorld, optional
        Its loaded robot is reused; the plan's world is the cell (door open) plus the
        neighbouring blanks and tray parts (``TendingPlan.obstacles``).
    options : TendingOptions
    source : str, optional
        Setup sheet file name for errors.
    setups : int
        1: the part is machined in one operation; 2: op 1 leaves the part on its holding
        block (the stock below ``part_box``), the robot turns it over on the cell's
        ``flip_station`` (moves ``flip: ...``) and op 2 faces the block off.
    roadmap : Roadmap or RoadmapOnDemand, optional
        The cell's roadmap (:func:`robotprog.roadmap.cell_roadmap`): transfers the straight
        joint segment cannot make are looked up in it before they are searched; every move is
        proven all the same.

    Returns
    -------
    TendingPlan
        Home → rack → vise → home (``load``), with two setups home → vise → flip station →
        vise → home (``flip``), then home → vise → out-tray → home (``unload``).

    Raises
    ------
    SetupError
        Malformed setup sheet.
    CellError
        The stock does not fit the vise jaws, or no such rack / tray slot.
    PlanningError
        The box is wider than the gripper opens (``gripper.opening.max``), a slot or the
        vise is out of reach (``rack.pose``, ``vise.pose``, ``out_tray.pose``,
        ``flip_station.pose``), or no collision-free path exists.
    """
    t0 = time.perf_counter()
    if setups not in (1, 2):
        raise PlanningError(f"expected 1 or 2 setups, got {setups}", source="setups")
    stock = setup_sheet_to_cell(sheet, source)
    width = float(stock.size[1])
    if not cell.vise.jaw_opening_min <= width <= cell.vise.jaw_opening_max:
        raise CellError(
            f"stock {width * MM_PER_M:.1f} mm wide does not fit the vise jaw opening "
            f"{cell.vise.jaw_opening_min * MM_PER_M:.1f}..{cell.vise.jaw_opening_max * MM_PER_M:.1f} mm",
            source="vise.jaw_opening")
    pmin, pmax = (stock.stock_min, stock.stock_max) if part_box is None else (
        np.asarray(part_box.low, dtype=float), np.asarray(part_box.high, dtype=float))
    piece = Piece.after_op1(stock.stock_min, stock.stock_max, pmin, pmax)
    leaves = dataclasses.replace(piece, slack=0.0)  # what the unload takes out: with one setup, the piece
    if setups == 2:
        # op 2 holds the part upside down, on its finished faces, and faced the block off; unload grips it there
        turned = piece.turned(TURNOVER_AXIS)
        pmin, pmax = turned.part_min, turned.part_max
        leaves = Piece(pmin, pmax, pmin.copy(), np.append(pmax[:2], pmin[2]))
    # The blanks beside the one picked and the parts already in the out-tray are obstacles.
    obstacles = (_neighbours(cell.rack, options.rack_slot, stock.size, "rack_blank")
                 + _neighbours(cell.out_tray, options.tray_slot, _whole(leaves)[1] - _whole(leaves)[0], "tray_part"))
    world = collision_world(cell, world.robot if world is not None else None, obstacles=obstacles)
    p = MotionPlanner(cell, world, options.planner, roadmap)
    home = np.asarray(cell.robot.home, dtype=float)
    r_home = p.tcp_world(home)[:3, :3]
    t_rack = _slot(cell.rack, options.rack_slot, "rack")
    t_tray = _slot(cell.out_tray, options.tray_slot, "out_tray")
    # Every grasp is solved before anything moves: a box the gripper cannot take fails fast.
    load = _load_trip(cell, stock, t_rack, r_home, options.grasp)
    unload = _unload_trip(cell, leaves, t_tray, r_home, options.grasp)

    moves = list(_trip_moves(p, home, load, LOAD, "load: return home", "vise to home").moves)
    if setups == 2:
        moves += plan_flip(p, piece, home, r_home, options.grasp).moves
    unloaded = _trip_moves(p, home, unload, UNLOAD, "unload: return home", "out-tray to home")
    moves += unloaded.moves
    reject = (_reject_moves(p, unload, unloaded.q_lifted, _whole(leaves)[0], options) if cell.reject_bin is not None
              else ())
    for m in moves + list(reject):
        m.waypoints.setflags(write=False)
    pmin = pmin.copy()
    pmax = pmax.copy()
    pmin.setflags(write=False)
    pmax.setflags(write=False)
    dt = time.perf_counter() - t0
    log.info("tending plan: %d moves, %.2f s of motion, planned in %.2f s", len(moves),
             sum(m.duration for m in moves), dt)
    return TendingPlan(tuple(moves), stock, pmin, pmax, dt, obstacles, reject)


#: The moves of the load: rack to vise.
LOAD = PickPlaceNames("load: home to above rack", "load: approach stock", "load: grip stock",
                      "load: retreat from rack", "load: transfer to vise", "load: place in vise",
                      "load: release stock", "load: retreat from vise", "home to rack", "rack to vise")
#: The moves of the unload: vise to out-tray.
UNLOAD = PickPlaceNames("unload: home to above vise", "unload: approach part", "unload: grip part",
                        "unload: retreat from vise", "unload: transfer to out-tray", "unload: place in out-tray",
                        "unload: release part", "unload: retreat from out-tray", "home to vise", "vise to out-tray")


@dataclass(frozen=True, eq=False)
class _Trip:
    """A pick-and-place of the plan before it is planned: its two stations, and what rides on the
    TCP with the fingers open (``open_``), carrying the box (``carried``) and setting it down
    (``placed``)."""

    pick: Station
    place: Station
    open_: Payload
    carried: Payload
    placed: Payload


#: A box stands in a rack or tray slot centred on the slot, bottom at slot height.
_ON_SLOT = np.array([0.5, 0.5, 0.0])


def _load_trip(cell: Cell, stock: StockInVise, t_rack: np.ndarray, r_home: np.ndarray,
               options: GraspOptions) -> _Trip:
    """The stock from its rack slot ``t_rack`` (4, 4) into the vise, held from above."""
    s_size = stock.size
    t_vise = cell.vise.pose.matrix()
    rack = top_grasp(cell, t_rack, -_ON_SLOT * s_size, s_size - _ON_SLOT * s_size, r_home, options, "stock")
    vise = top_grasp(cell, t_vise, stock.stock_min, stock.stock_max, r_home, options, "stock")
    stock_width = float(min(s_size[0], s_size[1]))
    closed = finger_boxes(cell, stock_width)
    return _Trip(
        Station(rack.transform_world_to_tcp, "rack.pose", "above rack slot", "approach to rack slot",
                "retreat from rack slot"),
        Station(vise.transform_world_to_tcp, "vise.pose", "above vise", "place in vise", "retreat from vise"),
        open_fingers(cell, stock_width), closed + (rack.held,), closed + (vise.held,))


def _whole(piece: Piece) -> tuple[np.ndarray, np.ndarray]:
    """The bounding box (min, max) (3,) [m] of the piece's boxes."""
    boxes = piece.boxes()
    return np.min([b[1] for b in boxes], axis=0), np.max([b[2] for b in boxes], axis=0)


def _unload_trip(cell: Cell, piece: Piece, t_tray: np.ndarray, r_home: np.ndarray, options: GraspOptions) -> _Trip:
    """What leaves the vise, ``piece`` in the vise frame [m], to its out-tray slot ``t_tray`` (4, 4),
    the finished part held from above: a part in one setup leaves on its holding block (the stock
    op 1 left under it), which rides under it and stands on the tray; the piece centred on the slot."""
    pmin, pmax = piece.part_min, piece.part_max
    psize = pmax - pmin
    t_vise = cell.vise.pose.matrix()
    vise = top_grasp(cell, t_vise, pmin, pmax, r_home, options, "part")
    tray_min, tray_max = -_ON_SLOT * psize, psize - _ON_SLOT * psize
    if piece.has_block:
        low, high = _whole(piece)
        shift = -_ON_SLOT * (high - low) - low  # the piece's box centred on the slot, bottom on it
        tray_min, tray_max = pmin + shift, pmax + shift
    g_tray = top_grasp(cell, t_tray, tray_min, tray_max, r_home, options, "part").transform_world_to_tcp
    part_width = float(min(psize[0], psize[1]))
    closed = finger_boxes(cell, part_width)
    held_vise, held_tray = (vise.held,), (HeldBox.at(psize, np.linalg.inv(g_tray) @ box_pose(t_tray, tray_min,
                                                                                             tray_max)),)
    if piece.has_block:
        in_tray = Piece(tray_min, tray_max, piece.block_min + shift, piece.block_max + shift)
        held_vise = held_piece(piece, t_vise, vise.transform_world_to_tcp)
        held_tray = held_piece(in_tray, t_tray, g_tray)
    return _Trip(
        Station(vise.transform_world_to_tcp, "vise.pose", "above vise", "approach to part", "retreat from vise"),
        Station(g_tray, "out_tray.pose", "above out-tray slot", "place in out-tray", "retreat from out-tray"),
        open_fingers(cell, part_width), closed + held_vise, closed + held_tray)


def _trip_moves(p: MotionPlanner, home: np.ndarray, trip: _Trip, names: PickPlaceNames, home_name: str,
                home_what: str) -> PickPlace:
    """The trip from ``home`` [rad] and back home (that move called ``home_name``, and ``home_what``
    in errors)."""
    done = p.pick_and_place(home, trip.pick, trip.place, names,
                            open_=trip.open_, carried=trip.carried, placed=trip.placed)
    home_again = p.joint_move(home_name, done.moves[-1].q_end, home, trip.open_, home_what)
    return PickPlace(done.moves + (home_again,), done.q_lifted)


def _reject_moves(p: MotionPlanner, unload: _Trip, q_lifted: np.ndarray, pmin: np.ndarray,
                  options: TendingOptions) -> tuple[TimedMove, ...]:
    """The alternative to the tray for a rejected part: from ``q_lifted`` [rad] (the part lifted
    out of the vise, its box's bottom at ``pmin[2]`` of the vise frame [m]) to above the reject bin,
    let go with its bottom ``reject_drop`` above the rim, then home."""
    cell = p.cell
    t_vise = cell.vise.pose.matrix()
    g_vise = unload.pick.grasp
    t_bin = cell.reject_bin.pose.matrix()
    g_bin = g_vise.copy()
    part_below_tcp = g_vise[2, 3] - (t_vise @ np.append(pmin, 1.0))[2]
    g_bin[:3, 3] = (t_bin[0, 3], t_bin[1, 3],
                    t_bin[2, 3] + cell.reject_bin.size[2] / 2 + options.reject_drop + part_below_tcp)
    q_bin = p.ik(g_bin, q_lifted, unload.carried, "above reject bin", "reject_bin.pose")
    home = np.asarray(cell.robot.home, dtype=float)
    return (p.joint_move("reject: transfer to bin", q_lifted, q_bin, unload.carried, "vise to reject bin"),
            p.gripper("reject: release part", q_bin, cell.gripper.io.release, unload.carried),
            p.joint_move("reject: return home", q_bin, home, unload.open_, "bin to home"))


def _neighbours(grid: SlotGrid, taken: tuple[int, int], size: np.ndarray, name: str) -> tuple[Box, ...]:
    """A box of ``size`` [m] in every slot of ``grid`` but ``taken`` (the blanks waiting in the
    rack, the parts already in the tray), each centred on its slot, bottom at slot height.
    A slot closer than the box's own size to ``taken`` cannot hold one beside it and stays empty."""
    out = []
    pitch = np.array(grid.pitch)
    for r in range(grid.rows):
        for c in range(grid.columns):
            if (r, c) == tuple(taken):
                continue
            offset = np.abs(np.array([c - taken[1], r - taken[0]], dtype=float)) * pitch
            if (offset < np.asarray(size[:2]) - 1e-9).all():
                continue
            t = grid.slot_transform(r, c)
            centre = (t @ np.array([0.0, 0.0, size[2] / 2, 1.0]))[:3]
            yaw = float(np.arctan2(t[1, 0], t[0, 0]))
            out.append(Box(f"{name}_r{r}c{c}", tuple(float(v) for v in size),
                           Pose(tuple(float(v) for v in centre), (0.0, 0.0, yaw))))
    return tuple(out)
