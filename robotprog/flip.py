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
and timed with :func:`robotprog.timing.time_path` (:meth:`robotprog.tending._Planner.timed`).

Frames: the vise frame and the post's top frame (:meth:`FlipStation.transform_world_to_top`)
are both upright with the piece's box coordinates in them the same (centred, bottom on the
surface), so a TCP pose moves from one to the other by ``t_top @ inv(t_vise)``. Metres, radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factory.core.errors import CellError, PlanningError
from robotprog.cell import Box, Cell, Pose
from robotprog.collision import HeldBox, collision_world, finger_boxes
from robotprog.frames import MM_PER_M

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
    """

    part_min: np.ndarray
    part_max: np.ndarray
    block_min: np.ndarray
    block_max: np.ndarray

    @staticmethod
    def after_op1(stock_min: np.ndarray, stock_max: np.ndarray, part_min: np.ndarray,
                  part_max: np.ndarray) -> "Piece":
        """The part on what is left of the stock below it (the stock's footprint, from its bottom
        up to the part's bottom)."""
        smin, smax = np.asarray(stock_min, float), np.asarray(stock_max, float)
        pmin, pmax = np.asarray(part_min, float), np.asarray(part_max, float)
        bmax = smax.copy()
        bmax[2] = max(pmin[2], smin[2])
        return Piece(pmin, pmax, smin.copy(), bmax)

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
        return Piece(pmin, pmax, bmin, bmax)

    def boxes(self) -> tuple[tuple[str, np.ndarray, np.ndarray], ...]:
        """(name, min, max) of the part and, if any, the holding block."""
        out = [("part", self.part_min, self.part_max)]
        if self.has_block:
            out.append(("holding_block", self.block_min, self.block_max))
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


def box_pose(t_support: np.ndarray, bmin: np.ndarray, bmax: np.ndarray) -> np.ndarray:
    """(4, 4) pose in the world of the centre of the box [bmin, bmax] of an upright support frame."""
    box = np.eye(4)
    box[:3, :3] = t_support[:3, :3]
    box[:3, 3] = (t_support @ np.append((np.asarray(bmin) + np.asarray(bmax)) / 2, 1.0))[:3]
    return box


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


def _ik_seeded(p, t_world_tcp: np.ndarray, q_ref: np.ndarray, held, what: str) -> np.ndarray:
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
            found.append(p.pick_ik(t_world_tcp, seed, held, what, "flip_station.pose"))
        except PlanningError:
            continue
    if not found:
        raise PlanningError(f"{what} is out of reach or only reachable in collision", source="flip_station.pose")
    return min(found, key=lambda q: float(np.linalg.norm(q - q_ref)))


def plan_flip(p, cell: Cell, piece: Piece, q_start: np.ndarray, r_home: np.ndarray, obstacles: tuple[Box, ...],
              grasp, raise_up) -> tuple[list, Piece]:
    """The flip phase: from ``q_start`` (home, after op 1) to home with the piece turned over in
    the vise for op 2.

    Parameters
    ----------
    p : robotprog.tending._Planner
        The planner of the tending plan (its world: the cell, door open, with ``obstacles``).
    cell : Cell
        Must have a ``flip_station``.
    piece : Piece
        The piece after op 1, in the vise frame.
    q_start : (dof,) float
        Configuration the phase starts at [rad].
    r_home : (3, 3) float
        TCP orientation at home (the top-down grasp's yaw nearest to it is used).
    obstacles : tuple of Box
        The plan's other obstacles (blanks in the rack, parts in the tray).
    grasp, raise_up : callables
        :func:`robotprog.tending._grasp` and ``_raise_up`` (passed in: that module imports this one).

    Returns
    -------
    (list of TimedMove, Piece)
        The moves (names ``flip: ...``) and the turned piece in the vise frame (op 2's).

    Raises
    ------
    PlanningError
        No flip station, the piece does not fit the gripper across the side it is gripped on,
        its holding block is too thin to grip, or no reachable, collision-free way was found
        (``flip_station.pose``).
    """
    from robotprog.tending import PickPlaceNames, Station, _Planner  # they live with the tending plan

    if cell.flip_station is None:
        raise PlanningError("the part has two setups but the cell has no flip_station to turn it over on",
                            source="flip_station")
    o = p.o
    up = o.approach_height
    t_vise = cell.vise.pose.matrix()
    t_post = cell.flip_station.transform_world_to_top()
    io = cell.gripper.io
    clear = cell.gripper.fingers.clearance
    omax = cell.gripper.opening_max

    def fingers(width: float, open_: bool) -> tuple[HeldBox, ...]:
        return finger_boxes(cell, min(omax, width + 2 * clear) if open_ else width)

    def planner(extra: tuple[Box, ...]):
        world = collision_world(cell, p.robot, obstacles=obstacles + extra)
        return _Planner(cell, p.robot, world, o)

    turned_axis = TURNOVER_AXIS
    turned = piece.turned(turned_axis)
    width = float(turned.part_max[1] - turned.part_min[1])
    if not cell.vise.jaw_opening_min <= width <= cell.vise.jaw_opening_max:
        raise CellError(f"the part {width * MM_PER_M:.1f} mm wide does not fit the vise jaw opening "
                        f"{cell.vise.jaw_opening_min * MM_PER_M:.1f}..{cell.vise.jaw_opening_max * MM_PER_M:.1f} mm "
                        "for op 2", source="vise.jaw_opening")

    def flip_at(t_top: np.ndarray) -> list:
        vise_to_top = t_top @ np.linalg.inv(t_vise)
        on_post = planner(piece_obstacles(piece, t_top, "flip_piece"))
        turned_on_post = planner(piece_obstacles(turned, t_top, "flip_piece"))
        moves = []

        # 1. the part out of the vise (gripped from above like the one-setup unload), onto the post
        g_vise, _ = grasp(cell, t_vise, piece.part_min, piece.part_max, r_home, o, "part")
        part_w = float(min(np.ptp([piece.part_min[:2], piece.part_max[:2]], axis=0)))
        open_part = fingers(part_w, True)
        holding = fingers(part_w, False) + held_piece(piece, t_vise, g_vise)
        to_post = p.pick_and_place(
            q_start, Station(g_vise, "vise.pose", "above vise", "approach to part", "retreat from vise"),
            Station(vise_to_top @ g_vise, "flip_station.pose", "above flip station", "set down on flip station",
                    "retreat from flip station"),
            PickPlaceNames("flip: home to above vise", "flip: approach part", "flip: grip part",
                           "flip: lift part from vise", "flip: transfer to flip station",
                           "flip: set down on flip station", "flip: release part", "flip: retreat from flip station",
                           "home to vise", "vise to flip station"),
            open_=open_part, carried=holding, placed=holding, at_place=on_post)
        moves += to_post.moves
        off = to_post.moves[-1].waypoints

        # 2. grip the holding block from the side, lift, turn over, set down, back off
        other = 1 - turned_axis
        block_w = float(piece.block_max[other] - piece.block_min[other])
        if block_w > omax:
            raise PlanningError(f"the holding block is {block_w * MM_PER_M:.1f} mm across, wider than the gripper "
                                f"opens ({omax * MM_PER_M:.1f} mm)", source="gripper.opening.max")
        depth = min(o.grip_depth, float(piece.block_max[turned_axis] - piece.block_min[turned_axis]) / 2)
        open_side = fingers(block_w, True)
        flip_t = turnover(turned_axis, piece.top)
        side = None
        problems = []
        for end in (-1.0, 1.0):
            for closing in (1.0, -1.0):
                g_side = t_top @ side_grasp(piece, turned_axis, end, closing, depth)
                g_turned = t_top @ flip_t @ np.linalg.inv(t_top) @ g_side
                try:
                    carried = fingers(block_w, False) + held_piece(piece, t_top, g_side)
                    q_back = _ik_seeded(on_post, _backed_off(g_side, up), off[-1], open_side,
                                        "beside the piece on the flip station")
                    into = on_post.line(_backed_off(g_side, up), g_side, q_back, open_side, "approach to the "
                                        "holding block", "flip_station.pose")
                    lift = p.line(g_side, raise_up(g_side, up), into[-1], carried, "lift from flip station",
                                  "flip_station.pose")
                    # the wrist's own half turn first: seeded with the last joint turned either way
                    q_over = _ik_seeded(p, raise_up(g_turned, up), lift[-1], carried,
                                        "above flip station, turned over")
                    lower = p.line(raise_up(g_turned, up), g_turned, q_over, carried, "set down turned over",
                                   "flip_station.pose")
                    back = turned_on_post.line(g_turned, _backed_off(g_turned, up), lower[-1], open_side,
                                               "back off from the turned piece", "flip_station.pose")
                    turn = p.transfer(lift[-1], q_over, carried, "turn over")
                except PlanningError as e:
                    problems.append(str(e))
                    continue
                side = (q_back, into, lift, carried, turn, lower, back)
                break
            if side is not None:
                break
        if side is None:
            raise PlanningError("no side grip: " + "; ".join(dict.fromkeys(problems)), source="flip_station.pose")
        q_back, into, lift, carried, turn, lower, back = side
        moves.append(on_post.timed("flip: to the side of the piece", "joint",
                                   on_post.transfer(off[-1], q_back, open_side, "flip station to its side"), open_side))
        moves.append(on_post.timed("flip: approach holding block", "linear", into, open_side))
        moves.append(p.gripper("flip: grip holding block", into[-1], io.grip, open_side))
        moves.append(p.timed("flip: lift", "linear", lift, carried))
        moves.append(p.timed("flip: turn over", "joint", turn, carried))
        moves.append(p.timed("flip: set down turned over", "linear", lower, carried))
        moves.append(p.gripper("flip: release turned piece", lower[-1], io.release, carried))
        moves.append(turned_on_post.timed("flip: back off", "linear", back, open_side))

        # 3. the holding block, now on top, gripped from above; the piece into the vise for op 2
        g_top, _ = grasp(cell, t_top, turned.block_min, turned.block_max, r_home, o, "holding block")
        top_w = float(min(np.ptp([turned.block_min[:2], turned.block_max[:2]], axis=0)))
        open_top = fingers(top_w, True)
        lifted = fingers(top_w, False) + held_piece(turned, t_top, g_top)
        to_vise = p.pick_and_place(
            back[-1], Station(g_top, "flip_station.pose", "above the turned piece", "approach to the turned piece",
                              "lift turned piece"),
            Station(np.linalg.inv(vise_to_top) @ g_top, "vise.pose", "above vise", "place in vise turned over",
                    "retreat from vise"),
            PickPlaceNames("flip: above turned piece", "flip: approach turned piece", "flip: grip turned piece",
                           "flip: lift turned piece", "flip: transfer to vise", "flip: place in vise",
                           "flip: release in vise", "flip: retreat from vise", "to above the turned piece",
                           "flip station to vise"),
            open_=open_top, carried=lifted, placed=lifted, at_pick=turned_on_post)
        moves += to_vise.moves
        moves.append(p.timed("flip: return home", "joint",
                             p.transfer(to_vise.moves[-1].q_end, np.asarray(cell.robot.home, float), open_top,
                                        "vise to home"), open_top))
        return moves

    # The piece may stand on the post turned any quarter turn: the first way that plans is used
    # (the side grip along the post's X suits one arm, along its Y another).
    problems = []
    for quarter in range(4):
        yaw = np.eye(4)
        c, s_ = np.cos(quarter * np.pi / 2), np.sin(quarter * np.pi / 2)
        yaw[:2, :2] = [[c, -s_], [s_, c]]
        try:
            return flip_at(t_post @ yaw), turned
        except PlanningError as e:
            problems.append(str(e))
    raise PlanningError("cannot turn the piece over on the flip station: " + "; ".join(dict.fromkeys(problems)),
                        source="flip_station.pose")
