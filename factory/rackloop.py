"""The rack camera closes the loop: perception, decision, control, for every blank the cell picks.

With ``factory simulate --blank-offsets SEED`` each blank stands in its rack slot off the slot's
centre (:func:`robotprog.rackpick.draw_offset`). At each locate the rack camera takes a picture of
the blank where it truly stands (:func:`vision.station.locate_shot`: rendered, exactly or with
``--rack-light`` in real light, then the real ``locate``), and :class:`RackLoop` decides:

- not located, or located with more uncertainty than the open fingers' room beside it allows (their
  clearance, or less where the gripper's stroke ends first: :func:`robotprog.grasp.finger_room`), or
  further off the slot's centre than the slot leaves room for: no grasp; the robot stops with a
  ``stock_not_found`` fault and the reason (the scheduler re-images, then skips to the next slot);
- else the grasp and its approach move by the located offset and the pick is planned again and
  proven (:func:`robotprog.rackpick.corrected_pick`, against the blank where it truly stands);
  a pick the proof refuses is a fault as above;
- the blank then sits in the vise off by the camera's error, up to the located pose's reported
  uncertainty: the plan's place in the vise and the retreat from it are proven again for a blank
  that far off, and the seat refused where the open jaws or the part's margin in the stock along
  the jaws cannot take it (:func:`robotprog.seat.prove_seat`), a fault as above;
- what op 1 leaves of the stock then sits off along the jaws as the seat allows: the plan's flip
  (grip, turn-over, re-place) and unload are proven again with it, or refused with the figures
  (:func:`robotprog.seat.prove_after_seat`), a fault as above.

Each decision is a :class:`RackPick`: the true offset, the located one, the camera's error, the
correction and the corrected moves; the cell log and the run's output carry them.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import trimesh

from cadcam.model import Setup, Tool
from cadcam.op2 import facing_gap
from factory.core.errors import CellError, PlanningError, VisionError
from factory.cellcameras import Stations, rack_slots_seen
from robotprog.cell import Box, Cell
from robotprog.cellsim import PickStep
from robotprog.grasp import finger_room
from robotprog.planner import PlannerOptions
from robotprog.rackpick import BlankScatter, CorrectedPick, PlannedPick, SlotOffset, corrected_pick, draw_offset, \
    slot_room
from robotprog.rack import RackSlot, next_slot, slot_refusal
from robotprog.robots import Robot
from robotprog.seat import CARRIED_MOVES, RELEASED_MOVES, AfterMoves, AfterSeat, Residual, Seat, SeatMoves, \
    prove_after_seat, prove_seat, reach
from vision.lit import Condition
from vision.locate import footprint_from_mesh
from vision.report import bgr_png_bytes
from vision.station import locate_shot

log = logging.getLogger(__name__)

#: Share of the fingers' clearance the located pose's reported uncertainty may take: the rest is
#: margin for an uncertainty that is itself only an estimate.
UNCERTAINTY_SHARE = 0.5


@dataclass(frozen=True)
class BlankPart:
    """What the closed loop needs of one planned part: its blank's mesh [mm] (a box, corner at
    the origin), what the plan does at the rack, at the vise (``seat``) and after op 1 (``after``:
    the flip and the unload); ``to_above_s`` [s] is the planned move from home to above the slot,
    which the corrected pick starts after."""

    vertices_mm: np.ndarray
    faces: np.ndarray
    planned: PlannedPick
    to_above_s: float
    seat: SeatMoves
    after: AfterMoves


@dataclass(frozen=True, eq=False)
class RackPick:
    """One picture of one blank and what came of it.

    Attributes
    ----------
    index : int
        Its number in the run (:attr:`robotprog.cellsim.Activity.pick`).
    job, slot, attempt : int
        The job, the rack slot, and which picture of this blank (0: the first; a re-image adds one).
    offset : SlotOffset
        Where the blank truly stands.
    located : SlotOffset or None
        Where the camera found it (None: not found).
    sigma_mm, sigma_deg : float
        The located pose's reported uncertainty [mm], [deg] (nan when not found).
    refusal : str
        Why no grasp was attempted ('' when it was).
    pick : CorrectedPick or None
        The corrected, proven pick (None when refused).
    seat : Seat or None
        Its seat in the vise, proven for the located pose's uncertainty (None when refused).
    after : AfterSeat or None
        The flip and the unload, proven for that seat (None when refused).
    rack : RackSlot or None
        Where the blank stands in the rack (None: it fits no slot the camera sees).
    fetch_s : float
        Home to the corrected pick and back over the slot [s] (0 when refused).
    png : bytes
        The annotated picture.
    detection : dict or None
        The located pose as :meth:`vision.locate.LocatedPart.to_dict` gives it.
    """

    index: int
    job: int
    slot: int
    attempt: int
    offset: SlotOffset
    located: SlotOffset | None
    sigma_mm: float
    sigma_deg: float
    refusal: str
    pick: CorrectedPick | None
    fetch_s: float
    png: bytes
    detection: dict[str, Any] | None
    seat: Seat | None = None
    rack: RackSlot | None = None
    after: AfterSeat | None = None

    @property
    def error(self) -> SlotOffset | None:
        """The camera's error: located less true (None when not found)."""
        return None if self.located is None else self.located.minus(self.offset)

    def step(self) -> PickStep:
        """The simulation's view of it."""
        return PickStep(self.index, self.fetch_s, self.refusal, self.message())

    def message(self) -> str:
        """One line: the rack slot, the offset, the located pose and its error, the correction or the refusal."""
        text = "" if self.rack is None else f"rack slot {self.rack.cell}: "
        text += f"blank offset {self.offset.describe()}"
        if self.located is not None:
            err = self.error
            text += (f"; located {self.located.describe()} (error {err.shift_m * 1e3:.2f} mm, "
                     f"{abs(math.degrees(err.dyaw)):.2f} deg; reported +-{self.sigma_mm:.2f} mm, "
                     f"+-{self.sigma_deg:.2f} deg)")
        if self.pick is not None:
            text += f"; grasp corrected by {self.pick.correction.describe()}, proven"
        if self.seat is not None:
            text += f"; {self.seat.describe()}"
        if self.after is not None:
            text += f"; {self.after.describe()}"
        if self.seat_holds() is False:
            true = self.true_reach()
            text += (f"; the blank truly lands {true[0] * 1e3:.2f} mm off along the jaws and {true[1] * 1e3:.2f} mm "
                     "across them: beyond what its seat was proven for, the reported uncertainty did not hold")
        return text + (f"; {self.refusal}" if self.refusal else "")

    def true_reach(self) -> np.ndarray | None:
        """How far the blank truly lands off its place in the vise along the jaws and across them,
        (2,) [m], by the camera's true error (:func:`robotprog.seat.reach`; the error taken along
        the blank's own axes); None when no seat was proven."""
        err = self.error
        if self.seat is None or err is None or self.rack is None:
            return None
        c, s = math.cos(self.offset.dyaw), math.sin(self.offset.dyaw)
        along_blank = np.array([c * err.dx + s * err.dy, -s * err.dx + c * err.dy])
        return reach(np.asarray(self.rack.size), along_blank, err.dyaw)

    def seat_holds(self) -> bool | None:
        """Whether the blank as it truly came lies within what its seat was proven for (None when
        no seat was proven): the proof rests on the reported uncertainty, which may not hold."""
        true = self.true_reach()
        return None if true is None else bool(true[0] <= self.seat.along + 1e-9
                                                and true[1] <= self.seat.across + 1e-9)

    def _seat_audit(self) -> dict[str, Any]:
        true = self.true_reach()
        return {"seat_true_along_mm": None if true is None else round(float(true[0]) * 1e3, 4),
                "seat_true_across_mm": None if true is None else round(float(true[1]) * 1e3, 4),
                "seat_holds": self.seat_holds()}

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, in mm and degrees for people."""
        def mmdeg(o: SlotOffset | None) -> dict[str, float] | None:
            return None if o is None else {"x_mm": round(o.dx * 1e3, 4), "y_mm": round(o.dy * 1e3, 4),
                                           "yaw_deg": round(math.degrees(o.dyaw), 4)}
        err = self.error
        return {"job": self.job, "slot": self.slot, "attempt": self.attempt,
                "rack_slot": None if self.rack is None else list(self.rack.cell),
                "rack_load": None if self.rack is None else self.rack.load,
                "rack_passed_over": [] if self.rack is None else list(self.rack.passed_over),
                "offset": mmdeg(self.offset),
                "located": mmdeg(self.located),
                "error_mm": None if err is None else round(err.shift_m * 1e3, 4),
                "error_deg": None if err is None else round(abs(math.degrees(err.dyaw)), 4),
                "reported_mm": None if self.located is None else round(self.sigma_mm, 4),
                "reported_deg": None if self.located is None else round(self.sigma_deg, 4),
                # whether the camera's true error lay within what it reported: the bound the seat's proof rests on
                "error_within_reported": None if err is None else bool(
                    err.shift_m * 1e3 <= self.sigma_mm and abs(math.degrees(err.dyaw)) <= self.sigma_deg),
                "correction": mmdeg(None if self.pick is None else self.pick.correction),
                "proven": self.pick is not None,
                **self._seat_audit(),
                "seat_across_mm": None if self.seat is None else round(self.seat.across * 1e3, 4),
                "seat_along_mm": None if self.seat is None else round(self.seat.along * 1e3, 4),
                "after_proven": [] if self.after is None else list(self.after.moves),
                "unload_part_off_mm": None if self.after is None else round(self.after.part_off * 1e3, 4),
                "fetch_s": round(self.fetch_s, 4), "refusal": self.refusal}


def planned_pick(motion: Any, size_m: np.ndarray) -> tuple[PlannedPick, float]:
    """The plan's pick, read from a part's :class:`factory.simulation.RobotMotion`, and the time [s]
    of its move from home to above the slot."""
    def end(name: str) -> np.ndarray:
        _, t1 = motion.span(name, name)
        return np.array([np.interp(t1, motion.t, motion.q[:, j]) for j in range(motion.q.shape[1])])
    planned = PlannedPick(end("load: home to above rack"), end("load: approach stock"),
                          end("load: retreat from rack"), np.asarray(size_m, dtype=float))
    return planned, motion.duration("load: home to above rack", "load: home to above rack")


def move_samples(motion: Any, name: str) -> np.ndarray:
    """The recorded joint samples (n, dof) [rad] of the move ``name`` of a part's
    :class:`factory.simulation.RobotMotion`, its ends included."""
    t0, t1 = motion.span(name, name)
    inside = (motion.t > t0) & (motion.t < t1)
    ends = np.array([[np.interp(t, motion.t, motion.q[:, j]) for j in range(motion.q.shape[1])] for t in (t0, t1)])
    return np.vstack([ends[:1], motion.q[inside], ends[1:]])


def seat_moves(motion: Any, size_m: np.ndarray, margin_along_jaws_m: float) -> SeatMoves:
    """The plan's moves at the vise, read from a part's :class:`factory.simulation.RobotMotion`."""
    return SeatMoves(tuple(move_samples(motion, n) for n in CARRIED_MOVES),
                     tuple(move_samples(motion, n) for n in RELEASED_MOVES),
                     np.asarray(size_m, dtype=float), float(margin_along_jaws_m))


def facing_reach(setup: Setup, operations: Sequence[Mapping[str, Any]], tools: Mapping[int, Tool]) -> float | None:
    """How far op 2's stock may reach beyond its planned X faces before a facing ramp meets it with
    the tool's centre [mm]: :func:`cadcam.op2.facing_gap` plus the facing tool's radius, of op 2's
    ``setup``, ``operations`` (the setup sheet's records) and ``tools`` by number; None: op 2 faces
    nothing. A holding block seated off along the jaws that reaches less far meets the ramp's end
    and the step-overs beside it with the tool's side, a cut narrower than the passes' own; further,
    the end mill's centre would meet it on the ramp."""
    number = next((int(op["tool"]) for op in operations if op.get("kind") == "facing"), None)
    return None if number is None else facing_gap(setup) + float(tools[number].radius)


def after_moves(motion: Any, after: AfterMoves) -> AfterMoves:
    """``after`` (what op 1 leaves in the vise; its moves not read yet) with the plan's flip and
    unload, read from a part's :class:`factory.simulation.RobotMotion`."""
    names = [m[0] for m in motion.moves if m[0].startswith(("flip:", "unload:"))]
    return dataclasses.replace(after, moves=tuple((n, move_samples(motion, n)) for n in names))


def blank_part(stock_mm: np.ndarray, motion: Any, margin_along_jaws_mm: float, after: AfterMoves) -> BlankPart:
    """The :class:`BlankPart` of a part whose stock is ``stock_mm`` (3,) [mm], reaches
    ``margin_along_jaws_mm`` [mm] beyond the part along the jaws (work X) at its nearer end, and
    leaves op 1 as ``after`` says."""
    box = trimesh.creation.box(stock_mm)
    box.apply_translation(np.asarray(stock_mm, dtype=float) / 2)
    size_m = np.asarray(stock_mm, dtype=float) / 1000.0
    planned, to_above = planned_pick(motion, size_m)
    return BlankPart(np.asarray(box.vertices), np.asarray(box.faces), planned, to_above,
                     seat_moves(motion, size_m, margin_along_jaws_mm / 1000.0), after_moves(motion, after))


@dataclass
class RackLoop:
    """The :data:`robotprog.cellsim.PickSource` of a run: puts each blank in its rack slot, locates it,
    decides, corrects and proves its pick; :attr:`picks` keeps every decision in the order taken.
    ``light``: the rack camera's pictures are taken in this real light (:data:`vision.lit.CONDITIONS`);
    None: exact.

    The scheduler's slot numbers count blanks; :attr:`slots` says where each stands in the rack
    (:func:`robotprog.rack.next_slot`: the first slot, row by row, the camera sees whole and the
    blank fits beside the blanks of the same filling; the rack refilled when full). While a blank is
    picked, the blanks of its filling not yet picked stand beside it, and each slot still free holds,
    for the proof, the largest blank of the run that fits there (the operator fills the rack before
    the robot picks from it)."""

    cell: Cell
    robot: Robot
    stations: Stations
    parts: dict[Any, BlankPart]
    scatter: BlankScatter
    options: PlannerOptions = field(default_factory=PlannerOptions)
    picks: list[RackPick] = field(default_factory=list)
    light: Condition | None = None
    slots: dict[int, RackSlot] = field(default_factory=dict)

    def __call__(self, job: int, key: Any, slot: int) -> PickStep:
        part = self.parts[key]
        attempt = sum(1 for p in self.picks if p.job == job and p.slot == slot)
        room = slot_room(self.cell, part.planned.size, self.scatter.max_yaw)
        offset = draw_offset(self.scatter, room, job, slot)
        try:
            where = self._put(slot, part)
        except CellError as e:
            pick = RackPick(len(self.picks), job, slot, attempt, offset, None, math.nan, math.nan,
                            f"no rack slot for the blank: {e.message}", None, 0.0, b"", None)
        else:
            pick = self._decide(len(self.picks), job, where, attempt, part, room, offset)
        self.picks.append(pick)
        log.info("job %d slot %d: %s", job, slot, pick.message())
        return pick.step()

    def _put(self, index: int, part: BlankPart) -> RackSlot:
        """The rack slot of the scheduler's slot number ``index`` (put there on first asking)."""
        if index not in self.slots:
            size = part.planned.size
            seen = rack_slots_seen(self.stations, self.cell, size, self._reach(size))
            self.slots[index] = next_slot(self.cell.rack, index, size, tuple(self.slots.values()), seen)
        return self.slots[index]

    def _reach(self, size: np.ndarray) -> float:
        """How far any point of a blank of ``size`` (3,) [m] stands off its slot's place at most [m]."""
        room = slot_room(self.cell, size, self.scatter.max_yaw)
        return float(Residual(math.hypot(min(room.dx, self.scatter.max_shift), min(room.dy, self.scatter.max_shift)),
                              min(room.dyaw, self.scatter.max_yaw)).growth(size).max())

    def _beside(self, where: RackSlot) -> tuple[Box, ...]:
        """The blanks standing in the rack while ``where``'s is picked (see the class docstring)."""
        taken = {p.slot for p in self.picks if p.pick is not None}
        load = [s for s in self.slots.values() if s.load == where.load]
        standing = [s for s in load if s.index != where.index and s.index not in taken]
        grid = self.cell.rack
        largest = sorted({tuple(float(v) for v in b.planned.size) for b in self.parts.values()},
                         key=lambda v: -v[0] * v[1])
        free = []
        for r in range(grid.rows):
            for c in range(grid.columns):
                if any(s.cell == (r, c) for s in load):
                    continue
                size = next((v for v in largest if not slot_refusal(grid, (r, c), v, load)), None)
                if size is not None:
                    free.append(RackSlot(-1, r, c, where.load, size))
        return tuple(s.box(grid) for s in standing + free)

    def _decide(self, index: int, job: int, where: RackSlot, attempt: int, part: BlankPart, room: SlotOffset,
                offset: SlotOffset) -> RackPick:
        slot = where.index
        t_slot = self.cell.rack.slot_transform(*where.cell)
        slot_yaw = math.atan2(t_slot[1, 0], t_slot[0, 0])
        footprint = footprint_from_mesh(part.vertices_mm, part.faces, source="blank")
        seed = int(np.random.default_rng([self.scatter.seed, job, slot + 1, attempt]).integers(2 ** 31))

        def refused(reason: str, located: SlotOffset | None = None, sigma: tuple[float, float] = (math.nan,) * 2,
                    png: bytes = b"", detection: dict | None = None) -> RackPick:
            return RackPick(index, job, slot, attempt, offset, located, sigma[0], sigma[1], reason, None, 0.0, png,
                            detection, rack=where)

        true_xy = (t_slot @ np.array([offset.dx, offset.dy, 0.0, 1.0]))[:2]
        try:
            shot = locate_shot(self.stations.rack, part.vertices_mm, part.faces,
                               (float(true_xy[0]), float(true_xy[1]), slot_yaw + offset.dyaw), seed=seed,
                               light=self.light)
        except VisionError as e:
            return refused(f"the rack camera did not locate the blank in rack slot {where.cell}: {e.message}")
        d = shot.detections[0]
        period = 2 * math.pi / footprint.symmetry  # a box's yaw is known modulo its symmetry
        yaw = (float(d["yaw"]) - slot_yaw + period / 2) % period - period / 2
        in_slot = np.linalg.inv(t_slot) @ np.array([float(d["x"]), float(d["y"]), t_slot[2, 3], 1.0])
        located = SlotOffset(float(in_slot[0]), float(in_slot[1]), yaw)
        sigma = (float(d["expected_error_mm"]), float(d["expected_error_deg"]))
        png = bgr_png_bytes(shot.annotated)
        residual = Residual(sigma[0] / 1e3, math.radians(sigma[1]))
        # how far a finger may find the blank's side off where the correction puts it [m]: along the
        # axis the fingers close on, the blank's narrower (robotprog.grasp.top_grasp)
        spread = float(residual.growth(part.planned.size)[int(np.argmin(part.planned.size[:2]))])
        width = float(min(part.planned.size[:2]))
        fingers = finger_room(self.cell, width)
        allowed = UNCERTAINTY_SHARE * fingers
        if spread > allowed:
            stroke = "" if fingers >= self.cell.gripper.fingers.clearance else (
                f" (the gripper opens {self.cell.gripper.opening_max * 1e3:.1f} mm, {fingers * 1e3:.2f} mm beyond the "
                f"blank's {width * 1e3:.1f} mm on each side)")
            return refused(f"located too loosely: +-{spread * 1e3:.2f} mm at the blank's sides, the open fingers "
                           f"allow {allowed * 1e3:.2f} mm{stroke}", located, sigma, png, d)
        if abs(located.dx) > room.dx + spread or abs(located.dy) > room.dy + spread:
            return refused(f"located {located.describe()}, further off the slot's centre than the slot leaves room "
                           f"for (x {room.dx * 1e3:.2f} y {room.dy * 1e3:.2f} mm)", located, sigma, png, d)
        try:
            pick = corrected_pick(self.cell, self.robot, part.planned, located, offset, self.options,
                                  slot=where.cell, neighbours=self._beside(where))
        except PlanningError as e:
            return refused(f"the corrected pick is not proven: {e}", located, sigma, png, d)
        try:
            seat = prove_seat(self.cell, self.robot, part.seat, residual, self.options)
        except PlanningError as e:
            return refused(f"the blank's seat in the vise is not proven: {e}", located, sigma, png, d)
        try:
            after = prove_after_seat(self.cell, self.robot, part.after, seat, self.options)
        except PlanningError as e:
            return refused(f"the part's way out of the vise is not proven for the blank's seat: {e}", located, sigma,
                           png, d)
        return RackPick(index, job, slot, attempt, offset, located, sigma[0], sigma[1], "", pick,
                        part.to_above_s + pick.duration, png, d, seat, where, after)
