"""The grasp of a blank that does not sit where the plan put it: the pick corrected by where the camera found it.

A blank stands in its rack slot a few millimetres and degrees off the slot's centre
(:class:`SlotOffset`, drawn by :func:`draw_offset` within :func:`slot_room`). The plan picks it at
the slot's centre (:mod:`robotprog.tending`); the rack camera locates it, and
:func:`corrected_pick` moves the grasp by the located offset and plans the pick again around it,
proven like every move of the plan (:class:`robotprog.planner.MotionPlanner`: straight lines and
joint moves checked all along, TOPP-RA timed, the timed path proven):

1. ``load: align over blank``: a straight TCP line, turning as it goes, from the planned pose above
   the slot to the pose above the located blank (fingers open);
2. ``load: approach stock``: straight down to the corrected grasp;
3. ``load: grip stock``;
4. ``load: retreat from rack``: straight up, the blank in hand;
5. ``load: back over rack``: a straight joint move back to where the planned retreat ends. The
   blank now hangs in the fingers as the plan has it (off by the camera's error only), so the
   planned transfer to the vise and everything after it run unchanged.

The moves are the paths the robot programs drive with the correction they read at run time
(:mod:`robotprog.programs`): straight TCP lines (``movel``, ``MoveL``, ``LIN``) to the corrected
poses, and a joint move (``movej``, ``MoveAbsJ``, ``PTP``) back; what is proven here is what the
controller drives.

The true blank is an obstacle while the open fingers go down around it: a located pose off by
more than the fingers' clearance fails the proof instead of hitting the blank. The neighbouring
blanks are obstacles throughout, as in the plan.

Frames and units: the slot frame of :meth:`robotprog.cell.SlotGrid.slot_transform` (a blank
stands centred on its origin, edges along its axes); metres, radians, seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from factory.core.errors import PlanningError
from robotprog.cell import Box, Cell, Pose
from robotprog.collision import HeldBox, collision_world, finger_boxes
from robotprog.grasp import box_pose, open_fingers
from robotprog.ik import ik_continuous
from robotprog.planner import LINE_FLIP_RAD, MotionPlanner, PlannerOptions, TimedMove, raise_up
from robotprog.robots import Robot
from robotprog.tending import _neighbours

#: The moves of the corrected pick, in order (the middle three keep the plan's names).
CORRECTED_MOVES = ("load: align over blank", "load: approach stock", "load: grip stock",
                   "load: retreat from rack", "load: back over rack")


@dataclass(frozen=True)
class SlotOffset:
    """Where a blank stands in its slot: its centre ``dx``, ``dy`` [m] from the slot's origin along
    the slot's axes, turned ``dyaw`` [rad] about the slot's z."""

    dx: float = 0.0
    dy: float = 0.0
    dyaw: float = 0.0

    def transform(self, t_world_slot: np.ndarray) -> np.ndarray:
        """(4, 4) world transform that takes the blank from the slot's centre to this offset."""
        c, s = math.cos(self.dyaw), math.sin(self.dyaw)
        d = np.array([[c, -s, 0.0, self.dx], [s, c, 0.0, self.dy], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
        return t_world_slot @ d @ np.linalg.inv(t_world_slot)

    def minus(self, other: "SlotOffset") -> "SlotOffset":
        """This offset less ``other`` (position [m] and yaw [rad], yaw wrapped to (-pi, pi])."""
        d = (self.dyaw - other.dyaw + math.pi) % (2 * math.pi) - math.pi
        return SlotOffset(self.dx - other.dx, self.dy - other.dy, d)

    @property
    def shift_m(self) -> float:
        """Length of the shift [m]."""
        return math.hypot(self.dx, self.dy)

    def describe(self) -> str:
        """``x +1.20 y -0.80 mm yaw +2.10 deg``."""
        return f"x {self.dx * 1e3:+.2f} y {self.dy * 1e3:+.2f} mm yaw {math.degrees(self.dyaw):+.2f} deg"


@dataclass(frozen=True)
class BlankScatter:
    """How far blanks stand off their slot's centre: uniform within ``max_shift`` [m] along each
    slot axis and ``max_yaw`` [rad], each bounded by the slot (:func:`slot_room`); ``seed`` makes
    a run's offsets reproducible (the blank of job j in slot s always stands the same)."""

    max_shift: float = 0.003
    max_yaw: float = math.radians(3.0)
    seed: int = 0

    def __post_init__(self) -> None:
        if not (self.max_shift >= 0 and self.max_yaw >= 0 and math.isfinite(self.max_shift + self.max_yaw)):
            raise PlanningError(f"blank scatter must be finite and >= 0, got {self.max_shift} m, "
                                f"{self.max_yaw} rad", source="blank offsets")


def slot_room(cell: Cell, size: np.ndarray, max_yaw: float) -> SlotOffset:
    """How far a blank of ``size`` (3,) [m] can stand off its slot's centre and stay within its
    slot, the rack's pitch cell, when turned by up to ``max_yaw`` [rad]: the largest ``dx``, ``dy``
    [m] (0 where the turned blank fills the pitch) and the yaw allowed (0 when no turn fits)."""
    pitch = np.asarray(cell.rack.pitch, dtype=float)
    half = np.asarray(size[:2], dtype=float) / 2
    for yaw in (max_yaw, 0.0):
        c, s = abs(math.cos(yaw)), abs(math.sin(yaw))
        extent = np.array([c * half[0] + s * half[1], s * half[0] + c * half[1]])
        room = pitch / 2 - extent
        if (room >= 0).all():
            return SlotOffset(float(room[0]), float(room[1]), yaw)
    return SlotOffset(0.0, 0.0, 0.0)


def draw_offset(scatter: BlankScatter, room: SlotOffset, job: int, slot: int) -> SlotOffset:
    """The offset of the blank job ``job`` takes from rack slot ``slot``: uniform within the
    scatter and the slot's ``room``, seeded by (scatter seed, job, slot)."""
    rng = np.random.default_rng([scatter.seed, job, slot + 1])
    lim = np.array([min(scatter.max_shift, room.dx), min(scatter.max_shift, room.dy),
                    min(scatter.max_yaw, room.dyaw)])
    x, y, yaw = rng.uniform(-1.0, 1.0, 3) * lim
    return SlotOffset(float(x), float(y), float(yaw))


@dataclass(frozen=True, eq=False)
class CorrectedPick:
    """The pick of one blank, corrected by where it was located (:func:`corrected_pick`).

    Attributes
    ----------
    correction : SlotOffset
        What the grasp was moved by: the located offset.
    moves : tuple of TimedMove
        :data:`CORRECTED_MOVES`, each timed and proven.
    """

    correction: SlotOffset
    moves: tuple[TimedMove, ...]

    @property
    def duration(self) -> float:
        """Time of the moves [s]."""
        return float(sum(m.duration for m in self.moves))


@dataclass(frozen=True, eq=False)
class PlannedPick:
    """What the plan does at the rack, read back from its joint motion: the configurations above
    the slot (``q_above``, the end of ``load: home to above rack``), at the grasp (``q_grasp``, the
    end of ``load: approach stock``) and lifted (``q_lifted``, the end of ``load: retreat from
    rack``) [rad], the blank's ``size`` (3,) [m], and the rack ``slot`` (row, column) the plan picks
    from."""

    q_above: np.ndarray
    q_grasp: np.ndarray
    q_lifted: np.ndarray
    size: np.ndarray
    slot: tuple[int, int] = (0, 0)


def corrected_pick(cell: Cell, robot: Robot, planned: PlannedPick, located: SlotOffset, true: SlotOffset,
                   options: PlannerOptions = PlannerOptions(), slot: tuple[int, int] = (0, 0),
                   neighbours: tuple[Box, ...] | None = None) -> CorrectedPick:
    """Plan the pick of the blank in rack ``slot`` at the ``located`` offset, proven against the
    blank where it ``true``-ly stands (see the module docstring). A slot other than the plan's
    (:attr:`PlannedPick.slot`) is reached the same way: the line over the located blank runs from
    above the plan's slot to above this one, and the joint move back ends where the plan's retreat
    does, over the plan's slot.

    Parameters
    ----------
    cell : Cell
    robot : Robot
        Loaded with collision meshes (:attr:`robotprog.collision.CollisionWorld.robot`).
    planned : PlannedPick
    located, true : SlotOffset
        Where the camera found the blank, and where it stands.
    options : PlannerOptions
        The plan's (line step, joint resolution, seed).
    slot : (int, int)
        (row, column) of the rack slot the blank stands in.
    neighbours : tuple of Box, optional
        The blanks standing in the rack beside it (:meth:`robotprog.rack.RackSlot.box`); default, as
        the plan has them, one of the same size in every slot that can hold one beside it.

    Raises
    ------
    PlanningError
        The corrected grasp is out of reach, its lines flip the arm, or a move collides (the open
        fingers with the true blank, or anything with the cell or the neighbouring blanks).
    """
    t_slot = cell.rack.slot_transform(*slot)
    size = np.asarray(planned.size, dtype=float)
    bmin, bmax = np.array([-size[0] / 2, -size[1] / 2, 0.0]), np.array([size[0] / 2, size[1] / 2, size[2]])
    if neighbours is None:
        neighbours = _neighbours(cell.rack, slot, size, "rack_blank")
    true_box = true.transform(t_slot) @ box_pose(t_slot, bmin, bmax)
    yaw = float(math.atan2(true_box[1, 0], true_box[0, 0]))
    blank = Box("picked_blank", tuple(float(v) for v in size), Pose(tuple(float(v) for v in true_box[:3, 3]),
                                                                     (0.0, 0.0, yaw)))
    around = MotionPlanner(cell, collision_world(cell, robot, obstacles=neighbours + (blank,)), options)
    clear = MotionPlanner(cell, collision_world(cell, robot, obstacles=neighbours), options)
    grasp = clear.tcp_world(planned.q_grasp)
    height = float(clear.tcp_world(planned.q_above)[2, 3] - grasp[2, 3])
    grasp = t_slot @ np.linalg.inv(cell.rack.slot_transform(*planned.slot)) @ grasp  # the same grasp in this slot
    grasp_c = located.transform(t_slot) @ grasp
    width = float(min(size[0], size[1]))
    open_ = open_fingers(cell, width)
    carried = finger_boxes(cell, width) + (HeldBox.at(size, np.linalg.inv(grasp_c) @ true_box),)
    above_c = raise_up(grasp_c, height)
    align = turning_line(around, clear.tcp_world(planned.q_above), above_c, planned.q_above, open_,
                         "over the located blank")
    down = around.line(above_c, grasp_c, align[-1], open_, "corrected approach to the blank", "rack.pose")
    up = clear.line(grasp_c, above_c, down[-1], carried, "corrected retreat from the rack", "rack.pose")
    back = np.array([up[-1], planned.q_lifted])  # straight in joint space, as the controller's joint move
    hit = clear.sweep.polyline_contact(back, carried)
    if hit is not None:
        raise PlanningError(f"back over the rack slot collides ({hit[1]})", source="rack.pose")
    names = dict(enumerate(CORRECTED_MOVES))
    moves = (around.timed(names[0], "linear", align, open_),
             around.timed(names[1], "linear", down, open_),
             clear.gripper(names[2], down[-1], cell.gripper.io.grip, open_),
             clear.timed(names[3], "linear", up, carried),
             clear.timed(names[4], "joint", back, carried))
    return CorrectedPick(located, moves)


def turning_line(p: MotionPlanner, t_a: np.ndarray, t_b: np.ndarray, q_a: np.ndarray, held, what: str) -> np.ndarray:
    """The TCP's straight line from pose ``t_a`` to ``t_b`` (4, 4), its orientation turning evenly
    (slerp) on the way, from ``q_a``: (n, dof) joint samples [rad] every ``line_step`` of travel
    (at least 2 and one per degree turned), proven free all along (a controller's ``movel``;
    :meth:`MotionPlanner.prove_line`).

    Raises
    ------
    PlanningError
        A sample has no IK solution continuous with the last, the arm flips, or the line collides.
    """
    turn = Rotation.from_matrix(t_b[:3, :3]) * Rotation.from_matrix(t_a[:3, :3]).inv()
    d = float(np.linalg.norm(t_b[:3, 3] - t_a[:3, 3]))
    n = max(2, int(math.ceil(max(d / p.options.line_step, math.degrees(turn.magnitude())))) + 1)
    slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.array([t_a[:3, :3], t_b[:3, :3]])))
    qs = [np.asarray(q_a, dtype=float)]
    for f in np.linspace(0.0, 1.0, n)[1:]:
        t = np.eye(4)
        t[:3, :3] = slerp([f]).as_matrix()[0]
        t[:3, 3] = (1 - f) * t_a[:3, 3] + f * t_b[:3, 3]
        try:
            q = ik_continuous(p.robot, p.flange(t), qs[-1])
        except PlanningError as e:
            raise PlanningError(f"{what}: {e}", source="rack.pose") from None
        if np.abs(q - qs[-1]).max() > LINE_FLIP_RAD:
            raise PlanningError(f"{what}: the arm flips configuration along the line", source="rack.pose")
        qs.append(q)
    out = np.array(qs)
    p.prove_line(out, held, what, "rack.pose")
    return out
