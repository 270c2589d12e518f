"""Turning the part over between op 1 and op 2: vise → flip station → turned over → vise.

After op 1 the piece is the finished part standing on the uncut holding block (the stock's
footprint, from the stock's bottom to the part's bottom): :class:`Piece`. Op 2 holds the part
on its finished faces, upside down, and faces the block off. The robot turns it over on the
cell's flip station (:class:`robotprog.cell.FlipStation`, a post narrower than the piece):

1. grip the part from above in the vise (as the one-setup unload does), set the piece down on
   the post, the holding block on the post's top, and let go;
2. grip the holding block from the side where it overhangs the post (tool axis horizontal,
   along the vise's X, :data:`TURNOVER_AXIS`; fingers closing across Y), lift it, turn the wrist
   half a turn about the tool axis (the piece rolls over about that axis), set it down on the
   part's finished top, and back off along the tool axis;
3. grip the holding block, now on top, from above, and place the piece in the vise on the
   part's finished top, centred on the jaw gap like the stock in op 1 (:mod:`robotprog.frames`).

Every move is collision-checked like the tending moves (arm, gripper body, the fingers at their
opening, the piece as its two boxes while held and as obstacles while it stands on the post)
and timed with :func:`robotprog.timing.time_path` (:meth:`robotprog.planner.MotionPlanner.timed`).

Frames: the vise frame and the post's top frame (:meth:`FlipStation.transform_world_to_top`)
are both upright with the piece's box coordinates in them the same (centred, bottom on the
surface), so a TCP pose moves from one to the other by ``t_top @ inv(t_vise)``. Metres, radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factory.core.errors import CellError, PlanningError
from factory.core.units import MM_PER_M
from robotprog.cell import Box, Pose
from robotprog.collision import HeldBox, Payload, finger_boxes
from robotprog.grasp import GraspOptions, box_pose, open_fingers, top_grasp
from robotprog.planner import MotionPlanner, PickPlace, PickPlaceNames, Station, TimedMove, raise_up

#: Below this height [m] the stock has no holding block (its bottom is the part's bottom).
NO_BLOCK_M = 1e-6


@dataclass(frozen=True)
class Piece:
    """The piece after op 1 in an upright frame (the vise's or the post's top): the finished
    part's box on the holding block's box.

    Attributes
    ----------
    part_min, part_max : (3,) float
        Finished part box [m].
    block_min, block_max : (3,) float
        Holding block box [m] (zero height when the stock has no holding allowance).
    slack : float
        How far the holding block may sit off along x [m], the part where the plan has it: the
        blank is seated in the vise only up to the part's margin in the stock along the jaws
        (:func:`robotprog.seat.check_seat`), and op 1 cuts the part where the plan put it. The
        block's boxes (:meth:`boxes`) reach that much further at both ends, so every move of the
        flip keeps that room from it.
    """

    part_min: np.ndarray
    part_max: np.ndarray
    block_min: np.ndarray
    block_max: np.ndarray
    slack: float = 0.0

    @staticmethod
    def after_op1(stock_min: np.ndarray, stock_max: np.ndarray, part_min: np.ndarray,
                  part_max: np.ndarray) -> "Piece":
        """The part on what is left of the stock below it (the stock's footprint, from its bottom
        up to the part's bottom), which may sit off along x by the part's margin in the stock there
        (at its nearer end)."""
        smin, smax = np.asarray(stock_min, float), np.asarray(stock_max, float)
        pmin, pmax = np.asarray(part_min, float), np.asarray(part_max, float)
        bmax = smax.copy()
        bmax[2] = max(pmin[2], smin[2])
        slack = max(0.0, min(float(pmin[0] - smin[0]), float(smax[0] - pmax[0])))
        return Piece(pmin, pmax, smin.copy(), bmax, slack)

    @property
    def has_block(self) -> bool:
        return float(self.block_max[2] - self.block_min[2]) > NO_BLOCK_M

    @property
    def top(self) -> float:
        """Height of the part's top face [m]."""
        return float(self.part_max[2])

    def turned(self, axis: int) -> "Piece":
        """The piece rolled over half a turn about ``axis`` (0: X, 1: Y) and set down on the
        part's top face (which comes to z = 0)."""
        t = turnover(axis, self.top)
        pmin, pmax = _box_through(t, self.part_min, self.part_max)
        bmin, bmax = _box_through(t, self.block_min, self.block_max)
        return Piece(pmin, pmax, bmin, bmax, self.slack)

    def boxes(self) -> tuple[tuple[str, np.ndarray, np.ndarray], ...]:
        """(name, min, max) of the part and, if any, the holding block (reaching its :attr:`slack`
        further at both ends along x)."""
        out = [("part", self.part_min, self.part_max)]
        if self.has_block:
            grow = np.array([self.slack, 0.0, 0.0])
            out.append(("holding_block", self.block_min - grow, self.block_max + grow))
        return tuple(out)


def turnover(axis: int, top: float) -> np.ndarray:
    """(4, 4) rigid transform of an upright frame: half a turn about ``axis`` (0: X, 1: Y), then
    up by ``top`` [m], so what was at height ``top`` comes to z = 0."""
    t = np.eye(4)
    t[:3, :3] = np.diag([1.0, -1.0, -1.0]) if axis == 0 else np.diag([-1.0, 1.0, -1.0])
    t[2, 3] = top
    return t


#: The axis the piece is turned over about: the vise's X (work X, along the jaws), as op 2's
#: setup turns the part (``cadcam.op2.FLIP_AXIS``); the fingers grip the holding block across Y.
TURNOVER_AXIS = 0


def _box_through(t: np.ndarray, bmin: np.ndarray, bmax: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    corners = np.array([[x, y, z] for x in (bmin[0], bmax[0]) for y in (bmin[1], bmax[1])
                        for z in (bmin[2], bmax[2])])
    p = corners @ t[:3, :3].T + t[:3, 3]
    return p.min(axis=0), p.max(axis=0)


def piece_obstacles(piece: Piece, t_support: np.ndarray, name: str) -> tuple[Box, ...]:
    """The piece standing on a surface, as static boxes of the world (its boxes' yaw is the
    support frame's; the frame is upright)."""
    yaw = float(np.arctan2(t_support[1, 0], t_support[0, 0]))
    out = []
    for what, bmin, bmax in piece.boxes():
        c = box_pose(t_support, bmin, bmax)[:3, 3]
        out.append(Box(f"{name}_{what}", tuple(float(v) for v in np.asarray(bmax) - np.asarray(bmin)),
                       Pose(tuple(float(v) for v in c), (0.0, 0.0, yaw))))
    return tuple(out)


def held_piece(piece: Piece, t_support: np.ndarray, t_world_tcp: np.ndarray) -> tuple[HeldBox, ...]:
    """The piece's boxes riding on the TCP at ``t_world_tcp`` while it stands in ``t_support``."""
    inv = np.linalg.inv(t_world_tcp)
    return tuple(HeldBox.at(np.asarray(bmax) - np.asarray(bmin), inv @ box_pose(t_support, bmin, bmax),
                            name=f"held_{what}") for what, bmin, bmax in piece.boxes())


def side_grasp(piece: Piece, axis: int, end: float, closing: float, depth: float) -> np.ndarray:
    """TCP pose (4, 4) in the support frame gripping the holding block from its side: the tool
    axis horizontal along ``axis`` pointing into the block from its ``end`` (+1: the max end,
    -1: the min end), the fingertips ``depth`` [m] in, centred on the block's height and across
    it, fingers closing along ``closing`` (+1 / -1) times the other horizontal axis."""
    other = 1 - axis
    bmin, bmax = piece.block_min, piece.block_max
    p = np.zeros(3)
    p[axis] = bmax[axis] - depth if end > 0 else bmin[axis] + depth
    p[other] = (bmin[other] + bmax[other]) / 2
    p[2] = (bmin[2] + bmax[2]) / 2
    z = np.zeros(3)
    z[axis] = -end
    y = np.zeros(3)
    y[other] = closing
    t = np.eye(4)
    t[:3, :3] = np.column_stack([np.cross(y, z), y, z])
    t[:3, 3] = p
    return t


def _backed_off(t: np.ndarray, distance: float) -> np.ndarray:
    """The TCP pose ``distance`` [m] back along its own tool axis."""
    out = t.copy()
    out[:3, 3] -= distance * t[:3, 2]
    return out


def _ik_seeded(p: MotionPlanner, t_world_tcp: np.ndarray, q_ref: np.ndarray, held: Payload, what: str) -> np.ndarray:
    """A collision-free IK solution of a pose, nearest ``q_ref``: for an arm whose IK is numeric
    (one solution near its seed) the seed is also turned a quarter and a half turn at the wrist
    (joints 4 and 6) and taken from home, so a side grip is not missed for the seed's branch."""
    q_ref = np.asarray(q_ref, float)
    seeds = [q_ref]
    for j, turn in ((-1, np.pi), (-1, -np.pi), (3, np.pi / 2), (3, -np.pi / 2), (-1, np.pi / 2), (-1, -np.pi / 2)):
        seed = q_ref.copy()
        seed[j] += turn
        if p.robot.q_lower[j] <= seed[j] <= p.robot.q_upper[j]:
            seeds.append(seed)
    seeds.append(np.asarray(p.cell.robot.home, float))
    found = []
    for seed in seeds:
        try:
            found.append(p.ik(t_world_tcp, seed, held, what, "flip_station.pose"))
        except PlanningError:
            continue
    if not found:
        raise PlanningError(f"{what} is out of reach or only reachable in collision", source="flip_station.pose")
    return min(found, key=lambda q: float(np.linalg.norm(q - q_ref)))


@dataclass(frozen=True, eq=False)
class FlipPlan:
    """The flip phase planned.

    Attributes
    ----------
    moves : tuple of TimedMove
        From the start (home, after op 1) to home with the piece turned over in the vise; names
        ``flip: ...``.
    turned : Piece
        The piece turned over, in the vise frame (op 2's).
    """

    moves: tuple[TimedMove, ...]
    turned: Piece


def plan_flip(planner: MotionPlanner, piece: Piece, q_start: np.ndarray, r_home: np.ndarray,
              grasp: GraspOptions) -> FlipPlan:
    """The flip phase: from ``q_start`` (home, after op 1) to home with the piece turned over in
    the vise for op 2.

    The piece may stand on the post turned any quarter turn: the first way that plans is used
    (the side grip along the post's X suits one arm, along its Y another).

    Parameters
    ----------
    planner : MotionPlanner
        The planner of the tending plan (its world: the cell, door open, with the plan's other
        obstacles: blanks in the rack, parts in the tray). Its cell must have a ``flip_station``.
    piece : Piece
        The piece after op 1, in the vise frame.
    q_start : (dof,) float
        Configuration the phase starts at [rad].
    r_home : (3, 3) float
        TCP orientation at home (the top-down grasp's yaw nearest to it is used).
    grasp : GraspOptions

    Raises
    ------
    CellError
        The turned part does not fit the vise jaws for op 2.
    PlanningError
        No flip station, the piece does not fit the gripper across the side it is gripped on,
        its holding block is too thin to grip, or no reachable, collision-free way was found
        (``flip_station.pose``).
    """
    cell = planner.cell
    if cell.flip_station is None:
        raise PlanningError("the part has two setups but the cell has no flip_station to turn it over on",
                            source="flip_station")
    turned = piece.turned(TURNOVER_AXIS)
    width = float(turned.part_max[1] - turned.part_min[1])
    if not cell.vise.jaw_opening_min <= width <= cell.vise.jaw_opening_max:
        raise CellError(f"the part {width * MM_PER_M:.1f} mm wide does not fit the vise jaw opening "
                        f"{cell.vise.jaw_opening_min * MM_PER_M:.1f}..{cell.vise.jaw_opening_max * MM_PER_M:.1f} mm "
                        "for op 2", source="vise.jaw_opening")
    t_post = cell.flip_station.transform_world_to_top()
    problems = []
    for quarter in range(4):
        try:
            site = _site(planner, piece, turned, t_post @ _quarter_turn(quarter), r_home, grasp)
            to_post = _onto_post(site, q_start)
            off = to_post.moves[-1].waypoints
            side = _side_grip(site, off[-1])
            over = _turn_over(site, side, off[-1])
            return FlipPlan(to_post.moves + over + _into_vise(site, side.back[-1]), turned)
        except PlanningError as e:
            problems.append(str(e))
    raise PlanningError("cannot turn the piece over on the flip station: " + "; ".join(dict.fromkeys(problems)),
                        source="flip_station.pose")


def _quarter_turn(quarter: int) -> np.ndarray:
    """(4, 4) rotation by ``quarter`` quarter turns about Z."""
    yaw = np.eye(4)
    c, s_ = np.cos(quarter * np.pi / 2), np.sin(quarter * np.pi / 2)
    yaw[:2, :2] = [[c, -s_], [s_, c]]
    return yaw


@dataclass(frozen=True, eq=False)
class _Site:
    """The flip with the piece standing on the post one way: its frames, and planners of the three
    worlds it passes through.

    Attributes
    ----------
    planner : MotionPlanner
        The tending plan's (the piece in hand, nothing on the post).
    on_post, turned_on_post : MotionPlanner
        With the piece standing on the post as it comes from op 1, and turned over.
    piece, turned : Piece
        The piece after op 1 and turned over (upright frames).
    t_top : (4, 4) float
        The post's top frame, turned as the piece stands on it [m].
    vise_to_top : (4, 4) float
        Moves a TCP pose on the piece in the vise to the same grip on it on the post.
    r_home : (3, 3) float
    grasp : GraspOptions
    """

    planner: MotionPlanner
    on_post: MotionPlanner
    turned_on_post: MotionPlanner
    piece: Piece
    turned: Piece
    t_top: np.ndarray
    vise_to_top: np.ndarray
    r_home: np.ndarray
    grasp: GraspOptions


def _site(planner: MotionPlanner, piece: Piece, turned: Piece, t_top: np.ndarray, r_home: np.ndarray,
          grasp: GraspOptions) -> _Site:
    """The flip's site with the post's top frame ``t_top`` (the piece's boxes stand as obstacles in
    the worlds of ``on_post`` and ``turned_on_post``)."""
    vise_to_top = t_top @ np.linalg.inv(planner.cell.vise.pose.matrix())
    return _Site(planner, planner.among(piece_obstacles(piece, t_top, "flip_piece")),
                 planner.among(piece_obstacles(turned, t_top, "flip_piece")), piece, turned, t_top, vise_to_top,
                 r_home, grasp)


#: The moves of step 1, the part from the vise onto the post.
TO_POST = PickPlaceNames("flip: home to above vise", "flip: approach part", "flip: grip part",
                         "flip: lift part from vise", "flip: transfer to flip station",
                         "flip: set down on flip station", "flip: release part", "flip: retreat from flip station",
                         "home to vise", "vise to flip station")
#: The moves of step 3, the turned piece from the post into the vise.
TO_VISE = PickPlaceNames("flip: above turned piece", "flip: approach turned piece", "flip: grip turned piece",
                         "flip: lift turned piece", "flip: transfer to vise", "flip: place in vise",
                         "flip: release in vise", "flip: retreat from vise", "to above the turned piece",
                         "flip station to vise")


def _onto_post(site: _Site, q_start: np.ndarray) -> PickPlace:
    """Step 1: the part out of the vise (gripped from above like the one-setup unload), set down on
    the post, the holding block on the post's top."""
    p, piece, cell = site.planner, site.piece, site.planner.cell
    g_vise = top_grasp(cell, cell.vise.pose.matrix(), piece.part_min, piece.part_max, site.r_home, site.grasp,
                       "part").transform_world_to_tcp
    part_w = float(min(np.ptp([piece.part_min[:2], piece.part_max[:2]], axis=0)))
    holding = finger_boxes(cell, part_w) + held_piece(piece, cell.vise.pose.matrix(), g_vise)
    return p.pick_and_place(
        q_start, Station(g_vise, "vise.pose", "above vise", "approach to part", "retreat from vise"),
        Station(site.vise_to_top @ g_vise, "flip_station.pose", "above flip station", "set down on flip station",
                "retreat from flip station"),
        TO_POST, open_=open_fingers(cell, part_w), carried=holding, placed=holding, at_place=site.on_post)


@dataclass(frozen=True, eq=False)
class _SideGrip:
    """Step 2 solved, not yet timed: the holding block gripped from the side, lifted, turned over
    and set down. Joint waypoints (n, dof) [rad].

    Attributes
    ----------
    q_back : (dof,) float
        Beside the piece on the post, backed off along the tool axis.
    into, lift, lower, back : (n, dof) float
        The lines into the grip, up, down turned over, and back off along the tool axis.
    turn : (n, dof) float
        The transfer that turns the piece over (the wrist's half turn).
    open_, carried : Payload
        The fingers open around the block; the fingers closed on it with the piece.
    """

    q_back: np.ndarray
    into: np.ndarray
    lift: np.ndarray
    turn: np.ndarray
    lower: np.ndarray
    back: np.ndarray
    open_: Payload
    carried: Payload


def _side_grip(site: _Site, q_from: np.ndarray) -> _SideGrip:
    """Step 2 solved from ``q_from`` [rad] (the arm backed off the piece on the post): the first
    of the block's ends and the fingers' two ways to close that the arm reaches, free.

    Raises
    ------
    PlanningError
        The block is wider than the gripper opens, or no side grip works.
    """
    p, piece, cell, t_top = site.planner, site.piece, site.planner.cell, site.t_top
    up = p.options.approach_height
    axis = TURNOVER_AXIS
    other = 1 - axis
    omax = cell.gripper.opening_max
    block_w = float(piece.block_max[other] - piece.block_min[other])
    if block_w > omax:
        raise PlanningError(f"the holding block is {block_w * MM_PER_M:.1f} mm across, wider than the gripper "
                            f"opens ({omax * MM_PER_M:.1f} mm)", source="gripper.opening.max")
    depth = min(site.grasp.grip_depth, float(piece.block_max[axis] - piece.block_min[axis]) / 2)
    open_side = open_fingers(cell, block_w)
    flip_t = turnover(axis, piece.top)
    problems = []
    for end in (-1.0, 1.0):
        for closing in (1.0, -1.0):
            g_side = t_top @ side_grasp(piece, axis, end, closing, depth)
            g_turned = t_top @ flip_t @ np.linalg.inv(t_top) @ g_side
            try:
                carried = finger_boxes(cell, block_w) + held_piece(piece, t_top, g_side)
                q_back = _ik_seeded(site.on_post, _backed_off(g_side, up), q_from, open_side,
                                    "beside the piece on the flip station")
                into = site.on_post.line(_backed_off(g_side, up), g_side, q_back, open_side, "approach to the "
                                         "holding block", "flip_station.pose")
                lift = p.line(g_side, raise_up(g_side, up), into[-1], carried, "lift from flip station",
                              "flip_station.pose")
                # the wrist's own half turn first: seeded with the last joint turned either way
                q_over = _ik_seeded(p, raise_up(g_turned, up), lift[-1], carried, "above flip station, turned over")
                lower = p.line(raise_up(g_turned, up), g_turned, q_over, carried, "set down turned over",
                               "flip_station.pose")
                back = site.turned_on_post.line(g_turned, _backed_off(g_turned, up), lower[-1], open_side,
                                                "back off from the turned piece", "flip_station.pose")
                turn = p.transfer(lift[-1], q_over, carried, "turn over").waypoints
            except PlanningError as e:
                problems.append(str(e))
                continue
            return _SideGrip(q_back, into, lift, turn, lower, back, open_side, carried)
    raise PlanningError("no side grip: " + "; ".join(dict.fromkeys(problems)), source="flip_station.pose")


#: Step 2's first move, to the side of the piece; its gripper actions: the fingers close on the
#: holding block from its side, and let the turned piece go.
SIDE_START = "flip: to the side of the piece"
SIDE_GRIP = "flip: grip holding block"
SIDE_RELEASE = "flip: release turned piece"


def _turn_over(site: _Site, side: _SideGrip, q_from: np.ndarray) -> tuple[TimedMove, ...]:
    """Step 2 timed from ``q_from`` [rad]: to the side of the piece, grip the holding block, lift,
    turn over, set down, release, back off."""
    p, io = site.planner, site.planner.cell.gripper.io
    return (site.on_post.joint_move(SIDE_START, q_from, side.q_back, side.open_,
                                    "flip station to its side"),
            site.on_post.timed("flip: approach holding block", "linear", side.into, side.open_),
            p.gripper(SIDE_GRIP, side.into[-1], io.grip, side.open_),
            p.timed("flip: lift", "linear", side.lift, side.carried),
            p.timed("flip: turn over", "joint", side.turn, side.carried),
            p.timed("flip: set down turned over", "linear", side.lower, side.carried),
            p.gripper(SIDE_RELEASE, side.lower[-1], io.release, side.carried),
            site.turned_on_post.timed("flip: back off", "linear", side.back, side.open_))


def _into_vise(site: _Site, q_from: np.ndarray) -> tuple[TimedMove, ...]:
    """Step 3 from ``q_from`` [rad]: the holding block, now on top, gripped from above; the piece
    into the vise for op 2, then home."""
    p, turned, cell = site.planner, site.turned, site.planner.cell
    g_top = top_grasp(cell, site.t_top, turned.block_min, turned.block_max, site.r_home, site.grasp,
                      "holding block").transform_world_to_tcp
    top_w = float(min(np.ptp([turned.block_min[:2], turned.block_max[:2]], axis=0)))
    open_top = open_fingers(cell, top_w)
    lifted = finger_boxes(cell, top_w) + held_piece(turned, site.t_top, g_top)
    to_vise = p.pick_and_place(
        q_from, Station(g_top, "flip_station.pose", "above the turned piece", "approach to the turned piece",
                        "lift turned piece"),
        Station(np.linalg.inv(site.vise_to_top) @ g_top, "vise.pose", "above vise", "place in vise turned over",
                "retreat from vise"),
        TO_VISE, open_=open_top, carried=lifted, placed=lifted, at_pick=site.turned_on_post)
    home = np.asarray(cell.robot.home, float)
    return to_vise.moves + (p.joint_move("flip: return home", to_vise.moves[-1].q_end, home, open_top,
                                         "vise to home"),)
