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
4. **After op 1** (:func:`prove_after_seat`) the part is where the plan put it, but what op 1 left
   of the stock, its own faces (the holding block under the part; a relief's whole block), sits off
   along the jaws by up to the seat's figure there. The flip (grip, turn-over on the post, re-place
   for op 2) and the unload are swept again with that piece, followed through the plan's gripper
   actions; op 2's facing ramps must not meet the block with the tool's centre. The flip is planned with the
   block off along the jaws by the part's margin in the stock (:attr:`robotprog.flip.Piece.slack`),
   the most a seat is accepted for.

Frames and units: the vise frame of :attr:`robotprog.cell.Vise.pose`; metres, radians.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from scipy.spatial.transform import Rotation

from factory.core.errors import PlanningError
from factory.core.units import MM_PER_M
from robotprog.cell import Box, Cell, Pose
from robotprog.collision import HeldBox, collision_world, finger_boxes
from robotprog.flip import SIDE_GRIP, SIDE_RELEASE, SIDE_START, TO_POST, TO_VISE, TURNOVER_AXIS, Piece
from robotprog.grasp import GraspOptions, body_above_tips, box_pose, open_fingers
from robotprog.planner import MotionPlanner, PlannerOptions
from robotprog.robots import Robot
from robotprog.tending import UNLOAD

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


def reach(size: np.ndarray, shift: np.ndarray, turn: float) -> np.ndarray:
    """How far a blank of ``size`` (3,) [m], its centre off by ``shift`` (2,) [m] along its own x and
    y and turned by ``turn`` [rad], reaches beyond its planned box along x and y, (2,) [m]: the
    bounding box of that one pose, which :meth:`Residual.growth` bounds for every pose within a
    shift and a turn. For a simulation, which knows the camera's true error: whether the seat's
    proof, which rests on the reported uncertainty, covered the blank as it truly came."""
    hx, hy = float(size[0]) / 2, float(size[1]) / 2
    c, s = math.cos(turn), abs(math.sin(turn))
    return np.abs(np.asarray(shift, dtype=float)) + np.array([hx * c + hy * s - hx, hy * c + hx * s - hy])


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


# --- after op 1: the flip and the unload ------------------------------------------------------------

#: The plan's gripper actions after op 1: the fingers close on the piece (flip: from above in the
#: vise, from the side on the post, from above turned over; the unload) or let it go.
GRIPS = (TO_POST.grip, SIDE_GRIP, TO_VISE.grip, UNLOAD.grip)
RELEASES = (TO_POST.release, SIDE_RELEASE, TO_VISE.release, UNLOAD.release)
#: The first move of each trip to a grip: from there the fingers open for the box they will grip.
TRIP_STARTS = (TO_POST.to_pick, SIDE_START, TO_VISE.to_pick, UNLOAD.to_pick)


@dataclass(frozen=True, eq=False)
class AfterMoves:
    """What the plan does with the piece after op 1.

    Attributes
    ----------
    moves : tuple of (str, (n, dof) float)
        The flip's and the unload's moves in the plan's order, each with its recorded joint
        samples [rad], its ends included.
    stock_min, stock_max : (3,) float
        The stock in the vise frame [m].
    part_min, part_max : (3,) float
        The finished part's box in the vise frame as op 1 leaves it [m] (a relief: its block).
    setups : int
        2: the flip turns the piece over and op 2 faces the holding block off before the unload.
    facing_reach : float
        How far the holding block may reach beyond its planned ends along the jaws before op 2's
        facing ramps meet it with the tool's centre [m] (:func:`factory.rackloop.facing_reach`: the
        passes' clearance beyond the stock plus the tool's radius; inf: op 2 faces nothing).
    """

    moves: tuple[tuple[str, np.ndarray], ...]
    stock_min: np.ndarray
    stock_max: np.ndarray
    part_min: np.ndarray
    part_max: np.ndarray
    setups: int
    facing_reach: float = math.inf


@dataclass(frozen=True)
class AfterSeat:
    """The flip and the unload proven for a blank seated up to ``along`` [m] off along the jaws:
    the stock's own faces (the holding block, a relief's block) that far off, the part where op 1
    cut it, or ``part_off`` [m] off where the fingers squared the piece up on the block; the
    ``moves`` proven with them."""

    along: float
    part_off: float
    moves: tuple[str, ...]

    def describe(self) -> str:
        """One line for the log."""
        return (f"flip and unload proven with the stock's faces up to {self.along * MM_PER_M:.2f} mm off along "
                f"the jaws (the part {self.part_off * MM_PER_M:.2f} mm)")


@dataclass
class _Body:
    """One box of the piece as the proof follows it: true ``size`` (3,) [m], the ``pose`` (4, 4) of
    its centre in the world, and how far it may sit ``off`` along its own x [m] (the vise's X as op 1
    left it: the piece is carried rigidly, so that axis stays the piece's)."""

    name: str
    size: np.ndarray
    pose: np.ndarray
    off: float

    def grown(self) -> np.ndarray:
        return self.size + np.array([2 * self.off, 0.0, 0.0])

    def box(self) -> Box:
        rpy = Rotation.from_matrix(self.pose[:3, :3]).as_euler("xyz")
        return Box(f"piece_{self.name}", tuple(float(v) for v in self.grown()),
                   Pose(tuple(float(v) for v in self.pose[:3, 3]), tuple(float(v) for v in rpy)))

    def holds(self, point: np.ndarray) -> bool:
        """Whether ``point`` (3,) [m] of the world lies within the true box (1 mm slack)."""
        local = np.linalg.inv(self.pose) @ np.append(point, 1.0)
        return bool((np.abs(local[:3]) <= self.size / 2 + 1e-3).all())


def after_op1(moves: AfterMoves, along: float, t_vise: np.ndarray) -> list[_Body]:
    """The piece in the vise after op 1 (:class:`robotprog.flip.Piece`): the part where the plan put
    it, unless it is the stock's own box along the jaws (a relief's block), and the holding block
    ``along`` [m] off with the blank."""
    piece = Piece.after_op1(moves.stock_min, moves.stock_max, moves.part_min, moves.part_max)
    uncut = (float(piece.part_min[0]) <= float(moves.stock_min[0]) + 1e-6
             and float(piece.part_max[0]) >= float(moves.stock_max[0]) - 1e-6)
    true = dataclasses.replace(piece, slack=0.0)  # the boxes as they are; the proof grows them by ``along``
    return [_Body(name, np.asarray(hi, float) - np.asarray(lo, float), box_pose(t_vise, lo, hi),
                  along if (name != "part" or uncut) else 0.0) for name, lo, hi in true.boxes()]


def prove_after_seat(cell: Cell, robot: Robot, moves: AfterMoves, seat: Seat,
                     options: PlannerOptions = PlannerOptions(), grasp: GraspOptions = GraspOptions()) -> AfterSeat:
    """Prove the plan's flip and unload for a blank seated as ``seat`` says; the plan's motion is
    swept again, not changed.

    The jaws square the blank up across them, and op 1 cuts the part where the plan put it, so
    what is left off is what op 1 did not cut, the stock's faces, up to ``seat.along`` along the
    jaws: the holding block under the part, or a relief's whole block. The proof follows the piece
    through the plan's gripper actions, carried rigidly: each box grown along its own x by how far
    it may sit off, riding on the fingers (closed on the box they grip) while held, and standing as
    an obstacle for the open fingers where it was let go (the vise with its jaws open beside it,
    the flip station, the out-tray). Fingers that close along a box's offset square it up in them:
    it is then where the plan has it, and the rest of the piece off by ``seat.along``. A grip along
    the offset (the side grip of the flip) must keep the grip depth and stay clear of the gripper
    body at both ends of it, and with two setups op 2's facing ramps must not meet the block with
    the tool's centre, and op 2 must cut the part where the plan put it.

    Raises
    ------
    PlanningError
        A move collides with the grown piece, or a figure above does not hold; the message names the
        move and gives the figures.
    """
    t_vise = cell.vise.pose.matrix()
    along = float(seat.along)
    bodies = after_op1(moves, along, t_vise)
    stock_y = float(moves.stock_max[1] - moves.stock_min[1])
    jaws = open_jaws(cell, np.array([0.0, stock_y, 0.0]))
    planners: dict[tuple, MotionPlanner] = {}

    def planner(standing: tuple[_Body, ...]) -> MotionPlanner:
        key = (id(jaws),) + tuple((b.name, tuple(np.round(b.pose, 9).ravel()), b.off) for b in standing)
        if key not in planners:
            planners[key] = MotionPlanner(cell, collision_world(cell, robot, obstacles=jaws + tuple(
                b.box() for b in standing)), options)
        return planners[key]

    base = planner(())
    held: list[tuple[_Body, np.ndarray]] = []
    width = 0.0  # the opening of the fingers is the plan's: the box of their trip's grip
    faced = moves.setups == 1
    proven = []
    for i, (name, qs) in enumerate(moves.moves):
        if not faced and name.startswith("unload"):
            bodies = _op2(bodies, moves)
            faced = True
        if name in TRIP_STARTS:
            grip = next(((n, q) for n, q in moves.moves[i:] if n in GRIPS), None)
            if grip is not None:
                width = _gripped(bodies, base.tcp_world(grip[1][-1]), grip[0])[1]
        if name in GRIPS:
            tcp = base.tcp_world(qs[-1])
            gripped, width = _gripped(bodies, tcp, name)
            _check_grip(cell, name, gripped, tcp, grasp)
            if abs(float(gripped.pose[:3, 0] @ tcp[:3, 1])) > 0.5 and gripped.off > 0:
                # the fingers close along the gripped box's offset and square it up; the rest moves with it
                for b in bodies:
                    b.off = 0.0 if b is gripped else along
            held = [(b, np.linalg.inv(tcp) @ b.pose) for b in bodies]
        if held:
            payload = finger_boxes(cell, width) + tuple(
                HeldBox.at(b.grown(), rel, name=f"held_{b.name}") for b, rel in held)
            hit = base.sweep.polyline_contact(qs, payload)
        else:
            hit = planner(tuple(bodies)).sweep.polyline_contact(qs, open_fingers(cell, width) if width else None)
        if hit is not None:
            off = max(b.off for b in bodies)
            raise PlanningError(f"{name}: with the piece off by up to {off * MM_PER_M:.2f} mm along the jaws "
                                f"(the blank seated {seat.residual.describe()} off) it collides ({hit[1]})",
                                source="vise.pose")
        proven.append(name)
        if name in RELEASES:
            tcp = base.tcp_world(qs[-1])
            for b, rel in held:
                b.pose = tcp @ rel
            held = []
            if name == TO_POST.release and moves.setups == 2:  # the vise opens beside the part for op 2
                turned = Piece.after_op1(moves.stock_min, moves.stock_max, moves.part_min,
                                         moves.part_max).turned(TURNOVER_AXIS)
                jaws = open_jaws(cell, turned.part_max - turned.part_min)
                planners.clear()
                base = planner(())
    part_off = max((b.off for b in bodies if b.name == "part"), default=0.0)
    return AfterSeat(along, part_off, tuple(proven))


def _gripped(bodies: list[_Body], tcp: np.ndarray, name: str) -> tuple[_Body, float]:
    """The box of the piece the fingers close on at the TCP pose ``tcp`` (4, 4), and its width
    across them [m].

    Raises
    ------
    PlanningError
        The fingertips are in no box of the piece: the plan grips something else.
    """
    gripped = next((b for b in bodies if b.holds(tcp[:3, 3])), None)
    if gripped is None:
        raise PlanningError(f"{name}: the fingers close on no box of the piece", source="vise.pose")
    return gripped, float(np.abs(gripped.pose[:3, :3].T @ tcp[:3, 1]) @ gripped.size)


def _check_grip(cell: Cell, name: str, gripped: _Body, tcp: np.ndarray, grasp: GraspOptions) -> None:
    """A grip whose tool axis lies along the box's offset (the flip's side grip) reaches into the
    box by its planned depth less or more the offset: at least the shallowest grip, and its face
    clear of the gripper body where the fingers start.

    Raises
    ------
    PlanningError
        With the figures.
    """
    axis = gripped.pose[:3, 0]
    if abs(float(axis @ tcp[:3, 2])) < 0.5 or gripped.off <= 0:
        return
    local = (np.linalg.inv(gripped.pose) @ np.append(tcp[:3, 3], 1.0))[0]
    # the face the tool axis enters by: the end of the box's x nearest the gripper body
    entering = -float(np.sign(axis @ tcp[:3, 2]))
    depth = gripped.size[0] / 2 - entering * local
    room = body_above_tips(cell) - grasp.floor_clearance
    if depth - gripped.off < grasp.min_grip_depth - 1e-9:
        raise PlanningError(f"{name}: the fingers reach {depth * MM_PER_M:.2f} mm into the {gripped.name} as planned, "
                            f"{(depth - gripped.off) * MM_PER_M:.2f} mm where it sits {gripped.off * MM_PER_M:.2f} mm "
                            f"off along the jaws: under the {grasp.min_grip_depth * MM_PER_M:.1f} mm grip",
                            source="gripper.fingers")
    if depth + gripped.off > room + 1e-9:
        raise PlanningError(f"{name}: the {gripped.name} sitting {gripped.off * MM_PER_M:.2f} mm off along the jaws "
                            f"comes {(depth + gripped.off) * MM_PER_M:.2f} mm between the fingers, the gripper body "
                            f"{room * MM_PER_M:.2f} mm behind the tips less the clearance", source="gripper.fingers")


def _op2(bodies: list[_Body], moves: AfterMoves) -> list[_Body]:
    """Op 2 faces the holding block off: its ramps must not meet a block off along the jaws with the
    tool's centre, and the part must sit where op 2 cuts it.

    Raises
    ------
    PlanningError
        With the figures.
    """
    block = next((b for b in bodies if b.name == "holding_block"), None)
    if block is not None and block.off > moves.facing_reach:
        raise PlanningError(f"op 2: the holding block may reach {block.off * MM_PER_M:.2f} mm further along the jaws "
                            f"than planned, op 2's facing ramps meet it with the tool's centre past "
                            f"{moves.facing_reach * MM_PER_M:.2f} mm", source="vise.pose")
    part = next(b for b in bodies if b.name == "part")
    if part.off > 0:
        raise PlanningError(f"op 2: the fingers squared the holding block up and moved the part up to "
                            f"{part.off * MM_PER_M:.2f} mm along the jaws off where op 2 cuts it", source="vise.pose")
    return [part]
