"""The blank's seat in the vise after a corrected pick: the camera's residual error, in the proof.

The rack camera's correction (:mod:`robotprog.rackpick`) moves the grasp to where the blank was
located, so the blank hangs in the fingers off by the camera's error only, and the planned transfer
sets it in the vise off by as much. The error is bounded by the located pose's reported
uncertainty (:class:`Residual`, a shift and a turn): the blank lies within its planned box grown
by :meth:`Residual.growth` along each of its axes (the bounding box of every pose within the
bound). What that does, in the order it happens:

1. **Setting it down.** The vise's jaws stand open :attr:`robotprog.cell.Vise.place_clearance`
   beside the blank's planned sides. A blank that may land further off than that across the jaws
   lands on a jaw: refused with the figures. Else the transfer to the vise and the place are proven
   carrying the grown blank, with the open jaws as obstacles.
2. **Letting go.** The open fingers go up from around the blank; the grown blank is an obstacle.
3. **Clamped.** The jaws close flat on the blank's sides across the vise (its Y): that takes out
   its offset across the jaws and its turn, and leaves its offset along the jaws (X), up to the
   growth along X (the shift, and what squaring a turned blank about a corner moves its centre
   along the jaws). Op 1's program cuts the part where the plan put it, so the part moves in the
   stock by that much along the jaws: the part must still lie inside the stock there
   (:attr:`SeatMoves.margin_along_jaws`, the stock's margin beyond the part's nearer end), or op 1
   would cut the part short at one end: refused with the figures. The jaws' top, which op 1's
   deepest feed keeps clear of by :data:`cadcam.setup.JAW_CLEARANCE_MM`, is a height: a shift
   along the floor does not bring a tool nearer to it.
4. **The unload** grips the finished part where op 1 cut it, where the plan grips it.

Frames and units: the vise frame of :attr:`robotprog.cell.Vise.pose`; metres, radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from factory.core.errors import PlanningError
from factory.core.units import MM_PER_M
from robotprog.cell import Box, Cell, Pose
from robotprog.collision import HeldBox, collision_world, finger_boxes
from robotprog.grasp import box_pose, open_fingers
from robotprog.planner import MotionPlanner, PlannerOptions
from robotprog.robots import Robot

#: The plan's moves the seat proof sweeps again with the grown blank (:class:`SeatMoves`).
CARRIED_MOVES = ("load: transfer to vise", "load: place in vise")
RELEASED_MOVES = ("load: retreat from vise",)


@dataclass(frozen=True)
class Residual:
    """How far the blank may sit off its planned place after a corrected pick: its centre up to
    ``shift`` [m] and turned up to ``turn`` [rad] (the located pose's reported uncertainty)."""

    shift: float
    turn: float

    def __post_init__(self) -> None:
        if not (self.shift >= 0 and self.turn >= 0 and math.isfinite(self.shift + self.turn)):
            raise PlanningError(f"a residual must be finite and >= 0, got {self.shift} m, {self.turn} rad",
                                source="rack.pose")

    def growth(self, size: np.ndarray) -> np.ndarray:
        """How far the bounding box of a blank of ``size`` (3,) [m] reaches beyond its planned one
        along the blank's x and y, (2,) [m]: the shift, plus what the turn swings each half-side
        out across the other axis (a box turned by t reaches ``hx cos t + hy sin t`` along x)."""
        swing = math.sin(min(self.turn, math.pi / 2))
        return self.shift + np.array([float(size[1]), float(size[0])]) / 2 * swing

    def describe(self) -> str:
        """``+-0.50 mm, +-0.60 deg``."""
        return f"+-{self.shift * MM_PER_M:.2f} mm, +-{math.degrees(self.turn):.2f} deg"


@dataclass(frozen=True, eq=False)
class SeatMoves:
    """What the plan does at the vise, and what the seat must tolerate.

    Attributes
    ----------
    carried : tuple of (n, dof) float
        Joint samples [rad] of :data:`CARRIED_MOVES`, the blank in the fingers; the last sample of
        the last is the place, the fingers closed on the blank as planned.
    released : tuple of (n, dof) float
        Joint samples [rad] of :data:`RELEASED_MOVES`, the fingers open around the blank.
    stock_size : (3,) float
        The blank [m]; it stands centred on the vise origin, edges along the vise axes.
    margin_along_jaws : float
        How far the stock reaches beyond the part along the jaws (vise X), at the part's nearer
        end [m]: the shift along the jaws op 1 tolerates.
    """

    carried: tuple[np.ndarray, ...]
    released: tuple[np.ndarray, ...]
    stock_size: np.ndarray
    margin_along_jaws: float


@dataclass(frozen=True)
class Seat:
    """A proven seat: the ``residual`` taken, how far the blank may land off ``across`` the jaws
    [m] (against the open jaws' ``place_clearance`` [m]) and sit off ``along`` them once clamped
    [m] (against the part's ``margin`` [m] in the stock there); the names of the moves proven with
    the grown blank."""

    residual: Residual
    across: float
    along: float
    place_clearance: float
    margin: float
    moves: tuple[str, ...]

    def describe(self) -> str:
        """One line for the log."""
        return (f"seat in the vise proven for {self.residual.describe()}: within {self.across * MM_PER_M:.2f} mm "
                f"across the jaws (open {self.place_clearance * MM_PER_M:.2f} mm) and {self.along * MM_PER_M:.2f} mm "
                f"along them (the part {self.margin * MM_PER_M:.2f} mm inside the stock)")


def open_jaws(cell: Cell, stock_size: np.ndarray) -> tuple[Box, ...]:
    """The vise's two jaws standing open :attr:`robotprog.cell.Vise.place_clearance` beside a blank
    of ``stock_size`` (3,) [m] set down on the vise origin: boxes in the world frame, bed to jaws'
    top, :attr:`robotprog.cell.Vise.jaw_width` along the jaws."""
    vise = cell.vise
    t_vise = vise.pose.matrix()
    yaw = float(math.atan2(t_vise[1, 0], t_vise[0, 0]))
    inner = float(stock_size[1]) / 2 + vise.place_clearance
    z = (vise.grip_depth - vise.parallels_height) / 2
    out = []
    for side, name in ((-1.0, "front"), (1.0, "back")):
        centre = t_vise @ np.array([0.0, side * (inner + vise.jaw_thickness / 2), z, 1.0])
        out.append(Box(f"vise_{name}_jaw_open", (vise.jaw_width, vise.jaw_thickness, vise.jaw_height),
                       Pose(tuple(float(v) for v in centre[:3]), (0.0, 0.0, yaw))))
    return tuple(out)


def check_seat(cell: Cell, moves: SeatMoves, residual: Residual) -> np.ndarray:
    """How far the blank may land off along the jaws and across them, (2,) [m] (vise X, Y), if the
    vise takes it (see the module docstring).

    Raises
    ------
    PlanningError
        The blank may land on an open jaw, or op 1 would cut the part past the stock's end along
        the jaws; the message gives the figures.
    """
    size = np.asarray(moves.stock_size, dtype=float)
    along, across = residual.growth(size)
    clearance = cell.vise.place_clearance
    why = f"the rack camera's {residual.describe()} on the {size[0] * MM_PER_M:.1f} x {size[1] * MM_PER_M:.1f} mm blank"
    if across > clearance:
        raise PlanningError(f"the blank may land {across * MM_PER_M:.2f} mm off its place across the jaws ({why}), "
                            f"more than the {clearance * MM_PER_M:.2f} mm the open jaws leave beside it",
                            source="vise.place_clearance")
    if along > moves.margin_along_jaws:
        raise PlanningError(f"the blank may sit {along * MM_PER_M:.2f} mm off along the jaws ({why}), more than the "
                            f"{moves.margin_along_jaws * MM_PER_M:.2f} mm of stock beyond the part there: op 1 "
                            "would cut the part past the stock's end", source="vise.pose")
    return np.array([along, across])


def prove_seat(cell: Cell, robot: Robot, moves: SeatMoves, residual: Residual,
               options: PlannerOptions = PlannerOptions()) -> Seat:
    """Prove the plan's place in the vise and the retreat from it for a blank off by up to
    ``residual`` (see the module docstring); the plan's motion is swept again, not changed.

    Parameters
    ----------
    cell : Cell
    robot : Robot
        Loaded with collision meshes.
    moves : SeatMoves
    residual : Residual
    options : PlannerOptions
        The plan's (joint resolution).

    Raises
    ------
    PlanningError
        :func:`check_seat` refuses, or a move collides with the blank grown by the residual (carried,
        or standing in the vise) or with the open jaws.
    """
    off = check_seat(cell, moves, residual)
    size = np.asarray(moves.stock_size, dtype=float)
    grow = np.array([off[0], off[1], 0.0])
    lo, hi = np.array([-size[0] / 2, -size[1] / 2, 0.0]) - grow, np.array([size[0] / 2, size[1] / 2, size[2]]) + grow
    t_vise = cell.vise.pose.matrix()
    placed = box_pose(t_vise, lo, hi)
    yaw = float(math.atan2(placed[1, 0], placed[0, 0]))
    grown = Box("blank_seated", tuple(float(v) for v in hi - lo), Pose(tuple(float(v) for v in placed[:3, 3]),
                                                                        (0.0, 0.0, yaw)))
    jaws = open_jaws(cell, size)
    p = MotionPlanner(cell, collision_world(cell, robot, obstacles=jaws), options)
    width = float(min(size[0], size[1]))
    place_tcp = p.tcp_world(moves.carried[-1][-1])
    carried = finger_boxes(cell, width) + (HeldBox.at(hi - lo, np.linalg.inv(place_tcp) @ placed),)
    for name, qs in zip(CARRIED_MOVES, moves.carried):
        hit = p.sweep.polyline_contact(qs, carried)
        if hit is not None:
            raise PlanningError(f"{name}: the blank off by up to {off.max() * MM_PER_M:.2f} mm collides ({hit[1]})",
                                source="vise.pose")
    around = MotionPlanner(cell, collision_world(cell, robot, obstacles=jaws + (grown,)), options)
    for name, qs in zip(RELEASED_MOVES, moves.released):
        hit = around.sweep.polyline_contact(qs, open_fingers(cell, width))
        if hit is not None:
            raise PlanningError(f"{name}: the open fingers hit the blank off by up to {off.max() * MM_PER_M:.2f} mm "
                                f"({hit[1]})", source="vise.pose")
    return Seat(residual, float(off[1]), float(off[0]), cell.vise.place_clearance, moves.margin_along_jaws,
                CARRIED_MOVES + RELEASED_MOVES)
