"""The rack camera closes the loop: perception, decision, control, for every blank the cell picks.

With ``factory simulate --blank-offsets SEED`` each blank stands in its rack slot off the slot's
centre (:func:`robotprog.rackpick.draw_offset`). At each locate the rack camera takes a picture of
the blank where it truly stands (:func:`vision.station.locate_shot`: rendered, exactly or with
``--rack-light`` in real light, then the real ``locate``), and :class:`RackLoop` decides:

- not located, or located with more uncertainty than the open fingers' clearance allows, or
  further off the slot's centre than the slot leaves room for: no grasp; the robot stops with a
  ``stock_not_found`` fault and the reason (the scheduler re-images, then skips to the next slot);
- else the grasp and its approach move by the located offset and the pick is planned again and
  proven (:func:`robotprog.rackpick.corrected_pick`, against the blank where it truly stands);
  a pick the proof refuses is a fault as above.

Each decision is a :class:`RackPick`: the true offset, the located one, the camera's error, the
correction and the corrected moves; the cell log and the run's output carry them.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import trimesh

from factory.core.errors import PlanningError, VisionError
from factory.cellcameras import Stations
from robotprog.cell import Cell
from robotprog.cellsim import PickStep
from robotprog.planner import PlannerOptions
from robotprog.rackpick import BlankScatter, CorrectedPick, PlannedPick, SlotOffset, corrected_pick, draw_offset, \
    slot_room
from robotprog.robots import Robot
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
    the origin) and what the plan does at the rack; ``to_above_s`` [s] is the planned move from
    home to above the slot, which the corrected pick starts after."""

    vertices_mm: np.ndarray
    faces: np.ndarray
    planned: PlannedPick
    to_above_s: float


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

    @property
    def error(self) -> SlotOffset | None:
        """The camera's error: located less true (None when not found)."""
        return None if self.located is None else self.located.minus(self.offset)

    def step(self) -> PickStep:
        """The simulation's view of it."""
        return PickStep(self.index, self.fetch_s, self.refusal, self.message())

    def message(self) -> str:
        """One line: the offset, the located pose and its error, the correction or the refusal."""
        text = f"blank offset {self.offset.describe()}"
        if self.located is not None:
            err = self.error
            text += (f"; located {self.located.describe()} (error {err.shift_m * 1e3:.2f} mm, "
                     f"{abs(math.degrees(err.dyaw)):.2f} deg; reported +-{self.sigma_mm:.2f} mm, "
                     f"+-{self.sigma_deg:.2f} deg)")
        if self.pick is not None:
            text += f"; grasp corrected by {self.pick.correction.describe()}, proven"
        return text + (f"; {self.refusal}" if self.refusal else "")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, in mm and degrees for people."""
        def mmdeg(o: SlotOffset | None) -> dict[str, float] | None:
            return None if o is None else {"x_mm": round(o.dx * 1e3, 4), "y_mm": round(o.dy * 1e3, 4),
                                           "yaw_deg": round(math.degrees(o.dyaw), 4)}
        err = self.error
        return {"job": self.job, "slot": self.slot, "attempt": self.attempt, "offset": mmdeg(self.offset),
                "located": mmdeg(self.located),
                "error_mm": None if err is None else round(err.shift_m * 1e3, 4),
                "error_deg": None if err is None else round(abs(math.degrees(err.dyaw)), 4),
                "reported_mm": None if self.located is None else round(self.sigma_mm, 4),
                "reported_deg": None if self.located is None else round(self.sigma_deg, 4),
                "correction": mmdeg(None if self.pick is None else self.pick.correction),
                "proven": self.pick is not None, "fetch_s": round(self.fetch_s, 4), "refusal": self.refusal}


def planned_pick(motion: Any, size_m: np.ndarray) -> tuple[PlannedPick, float]:
    """The plan's pick, read from a part's :class:`factory.simulation.RobotMotion`, and the time [s]
    of its move from home to above the slot."""
    def end(name: str) -> np.ndarray:
        _, t1 = motion.span(name, name)
        return np.array([np.interp(t1, motion.t, motion.q[:, j]) for j in range(motion.q.shape[1])])
    planned = PlannedPick(end("load: home to above rack"), end("load: approach stock"),
                          end("load: retreat from rack"), np.asarray(size_m, dtype=float))
    return planned, motion.duration("load: home to above rack", "load: home to above rack")


def blank_part(stock_mm: np.ndarray, motion: Any) -> BlankPart:
    """The :class:`BlankPart` of a part whose stock is ``stock_mm`` (3,) [mm]."""
    box = trimesh.creation.box(stock_mm)
    box.apply_translation(np.asarray(stock_mm, dtype=float) / 2)
    planned, to_above = planned_pick(motion, np.asarray(stock_mm, dtype=float) / 1000.0)
    return BlankPart(np.asarray(box.vertices), np.asarray(box.faces), planned, to_above)


@dataclass
class RackLoop:
    """The :data:`robotprog.cellsim.PickSource` of a run: locates each blank, decides, corrects and
    proves its pick; :attr:`picks` keeps every decision in the order taken. ``light``: the rack
    camera's pictures are taken in this real light (:data:`vision.lit.CONDITIONS`); None: exact."""

    cell: Cell
    robot: Robot
    stations: Stations
    parts: dict[Any, BlankPart]
    scatter: BlankScatter
    options: PlannerOptions = field(default_factory=PlannerOptions)
    picks: list[RackPick] = field(default_factory=list)
    light: Condition | None = None

    def __call__(self, job: int, key: Any, slot: int) -> PickStep:
        part = self.parts[key]
        attempt = sum(1 for p in self.picks if p.job == job and p.slot == slot)
        room = slot_room(self.cell, part.planned.size, self.scatter.max_yaw)
        offset = draw_offset(self.scatter, room, job, slot)
        pick = self._decide(len(self.picks), job, slot, attempt, part, room, offset)
        self.picks.append(pick)
        log.info("job %d slot %d: %s", job, slot, pick.message())
        return pick.step()

    def _decide(self, index: int, job: int, slot: int, attempt: int, part: BlankPart, room: SlotOffset,
                offset: SlotOffset) -> RackPick:
        rx, ry = self.stations.rack_xy
        footprint = footprint_from_mesh(part.vertices_mm, part.faces, source="blank")
        seed = int(np.random.default_rng([self.scatter.seed, job, slot + 1, attempt]).integers(2 ** 31))

        def refused(reason: str, located: SlotOffset | None = None, sigma: tuple[float, float] = (math.nan,) * 2,
                    png: bytes = b"", detection: dict | None = None) -> RackPick:
            return RackPick(index, job, slot, attempt, offset, located, sigma[0], sigma[1], reason, None, 0.0, png,
                            detection)

        try:
            shot = locate_shot(self.stations.rack, part.vertices_mm, part.faces,
                               (rx + offset.dx, ry + offset.dy, offset.dyaw), seed=seed, light=self.light)
        except VisionError as e:
            return refused(f"the rack camera did not locate the blank: {e.message}")
        d = shot.detections[0]
        period = 2 * math.pi / footprint.symmetry  # a box's yaw is known modulo its symmetry
        yaw = (float(d["yaw"]) + period / 2) % period - period / 2
        located = SlotOffset(float(d["x"]) - rx, float(d["y"]) - ry, yaw)
        sigma = (float(d["expected_error_mm"]), float(d["expected_error_deg"]))
        png = bgr_png_bytes(shot.annotated)
        half = float(max(part.planned.size[:2])) / 2
        # how far a finger may find the blank's side off where the correction puts it [m]
        spread = sigma[0] / 1e3 + half * math.radians(sigma[1])
        allowed = UNCERTAINTY_SHARE * self.cell.gripper.fingers.clearance
        if spread > allowed:
            return refused(f"located too loosely: +-{spread * 1e3:.2f} mm at the blank's sides, the open fingers "
                           f"allow {allowed * 1e3:.2f} mm", located, sigma, png, d)
        if abs(located.dx) > room.dx + spread or abs(located.dy) > room.dy + spread:
            return refused(f"located {located.describe()}, further off the slot's centre than the slot leaves room "
                           f"for (x {room.dx * 1e3:.2f} y {room.dy * 1e3:.2f} mm)", located, sigma, png, d)
        try:
            pick = corrected_pick(self.cell, self.robot, part.planned, located, offset, self.options)
        except PlanningError as e:
            return refused(f"the corrected pick is not proven: {e}", located, sigma, png, d)
        return RackPick(index, job, slot, attempt, offset, located, sigma[0], sigma[1], "", pick,
                        part.to_above_s + pick.duration, png, d)
