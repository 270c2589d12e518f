"""Machine tending: load a stock blank from the rack into the vise, unload the part to the out-tray.

The plan is a list of :class:`TimedMove`: joint-space *transfers* between "above" poses,
straight-line Cartesian *approach* / *retreat* moves between an above pose and the
grasp or place pose, and *gripper* actions (digital outputs, then the settle time).

Grasp
-----
Top-down: the TCP's Z points down (world -Z), the fingers close along the TCP's Y across
the narrower horizontal side of the box (stock or part), centred on the box's top face.
The fingertips (at the TCP) reach ``min(height / 2, grip_depth)`` below the top, but stay
:attr:`TendingOptions.floor_clearance` above the surface the box stands on, and the gripper
body (where the fingers start, ``gripper.fingers.length`` above the tips) stays that far
above the box's top. Of the two yaws that satisfy this, the one nearer the home TCP
orientation is used (less wrist travel). The fingers ride on the TCP as boxes
(:func:`robotprog.collision.finger_boxes`): open ``gripper.fingers.clearance`` beyond the
box on the way to it and after letting it go, closed on it while holding it. The blanks
beside the picked one in the rack and the parts in the other out-tray slots are obstacles.

Stock and part placement: in the rack and out-tray the box stands centred on the slot
origin, its edges along the slot axes, bottom at slot height; in the vise per
:mod:`robotprog.frames` (centred on the jaw gap, bottom on the parallels).

Motion
------
Approach and retreat are straight lines of the TCP, IK-sampled every
:attr:`TendingOptions.line_step` with :func:`robotprog.ik.ik_continuous` (the branch
continuous with the previous sample), and proven collision-free all along
(:mod:`robotprog.sweep`). Transfers are straight in joint space when that is
collision-free at :attr:`TendingOptions.joint_resolution`; otherwise an RRT-Connect in
joint space (seeded :class:`numpy.random.Generator`, so plans are reproducible) finds a
path, which is then shortcut (random pairs of path points joined when the straight joint
segment between them is free at that resolution). The transfer's polyline is then proven
free all along, not only at the checks (else it is planned again). Each move is timed with
:func:`robotprog.timing.time_path` and the timed spline, the path the controller drives, is
proven free all along too (the cubic spline through the waypoints need not follow the
polyline); where it is not, the waypoints are densified and the move re-timed.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.interpolate import PPoly

from factory.core.errors import CellError, PlanningError
from robotprog.cell import Box, Cell, Pose, SlotGrid
from robotprog.collision import CollisionWorld, HeldBox, Payload, collision_world, finger_boxes
from robotprog.frames import StockInVise, setup_sheet_to_cell, MM_PER_M
from robotprog.ik import ik_continuous, ik_solutions
from robotprog.robots import Robot
from robotprog.sweep import monotone_breaks, swept_motion
from robotprog.timing import Trajectory, time_path

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TendingOptions:
    """Tending planner settings.

    Attributes
    ----------
    approach_height : float
        Height of the "above" poses over the grasp / place pose [m].
    grip_depth : float
        How far the fingertips reach below the top of the box at most [m].
    min_grip_depth : float
        Shallowest grip accepted [m]; a thinner box raises :class:`PlanningError`.
    floor_clearance : float
        Gap kept between the gripper's collision box and the surface the box stands on [m].
    line_step : float
        IK sample spacing along approach / retreat lines [m].
    joint_resolution : float
        Largest joint step between collision-checked configurations [rad].
    rrt_step : float
        RRT-Connect extension step [rad].
    rrt_iterations : int
        RRT-Connect iterations before giving up.
    shortcut_attempts : int
        Random shortcut attempts on an RRT path.
    seed : int
        Seed of the RRT random generator.
    rack_slot, tray_slot : (int, int)
        (row, column) of the rack slot the stock comes from and the out-tray slot the part goes to.
    reject_drop : float
        Height of a rejected part's bottom above the reject bin's rim when it is let go [m].
    """

    approach_height: float = 0.10
    grip_depth: float = 0.015
    min_grip_depth: float = 0.003
    floor_clearance: float = 0.002
    line_step: float = 0.005
    joint_resolution: float = 0.02
    rrt_step: float = 0.15
    rrt_iterations: int = 4000
    shortcut_attempts: int = 60
    seed: int = 0
    rack_slot: tuple[int, int] = (0, 0)
    tray_slot: tuple[int, int] = (0, 0)
    reject_drop: float = 0.03


@dataclass(frozen=True, eq=False)
class TimedMove:
    """One step of the plan.

    Attributes
    ----------
    name : str
        ``"load: approach rack"`` etc.
    trajectory : Trajectory
        The timed joint motion (zero length for a gripper action).
    kind : str
        ``"joint"`` (transfer), ``"linear"`` (straight TCP line) or ``"gripper"``.
    waypoints : (n, dof) float
        The joint waypoints the trajectory passes through [rad].
    held : HeldBox or None
        What the gripper holds during the move.
    outputs : tuple of (int, bool)
        Digital outputs a gripper action sets.
    settle_s : float
        Wait after a gripper action [s].
    transform_world_to_tcp : (4, 4) float
        TCP pose at the end of the move [m].
    """

    name: str
    trajectory: Trajectory
    kind: str
    waypoints: np.ndarray
    held: Payload = None
    outputs: tuple[tuple[int, bool], ...] = ()
    settle_s: float = 0.0
    transform_world_to_tcp: np.ndarray = field(default_factory=lambda: np.eye(4))

    @property
    def duration(self) -> float:
        """Time of the move [s] (a gripper action: its settle time)."""
        return self.settle_s if self.kind == "gripper" else self.trajectory.duration

    @property
    def q_end(self) -> np.ndarray:
        """Last configuration [rad]."""
        return self.waypoints[-1]


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


def part_box_in_vise(stock: StockInVise, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
    return p.min(axis=0), p.max(axis=0)


# --- geometry helpers --------------------------------------------------------------------


def _grasp(cell: Cell, t_world_support: np.ndarray, bmin: np.ndarray, bmax: np.ndarray,
           r_home: np.ndarray, options: TendingOptions, what: str) -> tuple[np.ndarray, HeldBox]:
    """TCP grasp pose (world) and the held box, for a box [bmin, bmax] in the support frame."""
    size = bmax - bmin
    g = cell.gripper
    narrow = 0 if size[0] <= size[1] else 1
    width = float(size[narrow])
    if width > g.opening_max:
        raise PlanningError(
            f"{what} {width * MM_PER_M:.1f} mm across its narrowest side is wider than the gripper opens "
            f"({g.opening_max * MM_PER_M:.1f} mm)", source="gripper.opening.max")
    if width < g.opening_min:
        raise PlanningError(
            f"{what} {width * MM_PER_M:.1f} mm is narrower than the gripper closes "
            f"({g.opening_min * MM_PER_M:.1f} mm)", source="gripper.opening.min")
    # The fingertips end at the TCP: they must stay floor_clearance above the surface the box
    # stands on. The body ends where the fingers start: it must stay floor_clearance above
    # the box's top, which bounds the grip depth by the finger length.
    t_tcp_body = np.linalg.inv(g.tcp.matrix()) @ g.body.pose.matrix()
    corners = np.array([[sx, sy, sz] for sx in (-.5, .5) for sy in (-.5, .5) for sz in (-.5, .5)]) * g.body.size
    body_above = -float(((corners @ t_tcp_body[:3, :3].T) + t_tcp_body[:3, 3])[:, 2].max())
    height = float(size[2])
    depth = min(height / 2, options.grip_depth, body_above - options.floor_clearance)
    tcp_above = max(height - depth, options.floor_clearance)
    if height - tcp_above < options.min_grip_depth - 1e-9:
        raise PlanningError(
            f"{what} {height * MM_PER_M:.1f} mm tall is too thin to grip: the fingers would reach "
            f"{(height - tcp_above) * MM_PER_M:.2f} mm below its top, {options.min_grip_depth * MM_PER_M:.1f} mm "
            f"needed, fingertips {options.floor_clearance * MM_PER_M:.1f} mm above what it stands on",
            source="gripper.fingers")
    centre = np.array([(bmin[0] + bmax[0]) / 2, (bmin[1] + bmax[1]) / 2, bmin[2] + tcp_above, 1.0])
    p = (t_world_support @ centre)[:3]
    axis = t_world_support[:3, :3][:, narrow]
    axis = axis - axis[2] * np.array([0.0, 0.0, 1.0])
    axis /= np.linalg.norm(axis)
    best = None
    for s in (1.0, -1.0):
        y = s * axis
        z = np.array([0.0, 0.0, -1.0])
        x = np.cross(y, z)
        r = np.column_stack([x, y, z])
        score = np.trace(r_home.T @ r)
        if best is None or score > best[0]:
            best = (score, r)
    t = np.eye(4)
    t[:3, :3] = best[1]
    t[:3, 3] = p
    box = np.eye(4)
    box[:3, :3] = t_world_support[:3, :3]
    box[:3, 3] = (t_world_support @ np.append((bmin + bmax) / 2, 1.0))[:3]
    return t, HeldBox.at(size, np.linalg.inv(t) @ box)


@dataclass(frozen=True, eq=False)
class Station:
    """One end of a pick-and-place (:meth:`_Planner.pick_and_place`): where the box is taken or left.

    Attributes
    ----------
    grasp : (4, 4) float
        TCP pose when the fingers close on (or let go of) the box, world frame [m].
    field : str
        The cell-file field blamed when it cannot be reached (``rack.pose``).
    above, down, up : str
        What the pose ``approach_height`` above, the line down to the grasp and the line back up
        are called in errors (``above rack slot``, ``approach to rack slot``, ``retreat from rack slot``).
    """

    grasp: np.ndarray
    field: str
    above: str
    down: str
    up: str


@dataclass(frozen=True)
class PickPlaceNames:
    """The plan's names of the eight moves of a pick-and-place (programs, logs and the cell
    simulation read them), and what its two transfers are called in errors."""

    to_pick: str
    approach: str
    grip: str
    lift: str
    transfer: str
    place: str
    release: str
    leave: str
    to_pick_what: str
    transfer_what: str


@dataclass(frozen=True, eq=False)
class PickPlace:
    """The moves of a pick-and-place and where the arm was when it had lifted the box [rad]."""

    moves: tuple[TimedMove, ...]
    q_lifted: np.ndarray


class _Planner:
    def __init__(self, cell: Cell, robot: Robot, world: CollisionWorld, options: TendingOptions):
        self.cell, self.robot, self.world, self.o = cell, robot, world, options
        self.t_base_world = np.linalg.inv(cell.robot.base.matrix())
        self.t_tcp_flange = np.linalg.inv(cell.gripper.tcp.matrix())
        self.vmax = robot.v_max * cell.motion.speed_scaling
        self.amax = np.asarray(cell.motion.acceleration_limits, dtype=float) * cell.motion.speed_scaling
        self.rng = np.random.default_rng(options.seed)
        self.lo = np.maximum(robot.q_lower, np.asarray(cell.robot.home) - np.pi)
        self.hi = np.minimum(robot.q_upper, np.asarray(cell.robot.home) + np.pi)
        self.sweep = swept_motion(world, options.joint_resolution)

    def flange(self, t_world_tcp: np.ndarray) -> np.ndarray:
        return self.t_base_world @ t_world_tcp @ self.t_tcp_flange

    def tcp_world(self, q: np.ndarray) -> np.ndarray:
        return self.cell.robot.base.matrix() @ self.robot.fk(q) @ self.cell.gripper.tcp.matrix()

    def pick_ik(self, t_world_tcp: np.ndarray, q_ref: np.ndarray, held: Payload, what: str,
                field_name: str) -> np.ndarray:
        sols = ik_solutions(self.robot, self.flange(t_world_tcp), q_ref)
        sols = [q for q in sols if not self.world.in_collision(q, held)]
        if not sols:
            raise PlanningError(f"{what} is out of reach or only reachable in collision", source=field_name)
        return min(sols, key=lambda q: float(np.linalg.norm(q - q_ref)))

    def line(self, t_a: np.ndarray, t_b: np.ndarray, q_a: np.ndarray, held: Payload,
             what: str, field_name: str) -> np.ndarray:
        d = float(np.linalg.norm(t_b[:3, 3] - t_a[:3, 3]))
        n = max(2, int(math.ceil(d / self.o.line_step)) + 1)
        qs = [q_a]
        for f in np.linspace(0.0, 1.0, n)[1:]:
            t = t_a.copy()
            t[:3, 3] = (1 - f) * t_a[:3, 3] + f * t_b[:3, 3]
            try:
                q = ik_continuous(self.robot, self.flange(t), qs[-1])
            except PlanningError as e:
                raise PlanningError(f"{what}: {e}", source=field_name) from None
            if np.abs(q - qs[-1]).max() > 0.25:
                raise PlanningError(f"{what}: the arm flips configuration along the line", source=field_name)
            qs.append(q)
        qs = np.array(qs)
        hit = self.sweep.polyline_contact(qs, held)
        if hit is not None:
            raise PlanningError(f"{what} collides ({hit[1]})", source=field_name)
        return qs

    def densify(self, qs: np.ndarray, resolution: float | None = None) -> np.ndarray:
        step = self.o.joint_resolution if resolution is None else resolution
        out = [qs[:1]]
        for a, b in zip(qs[:-1], qs[1:]):
            n = max(1, int(math.ceil(np.abs(b - a).max() / step)))
            f = np.linspace(0.0, 1.0, n + 1)[1:, None]
            out.append(a + f * (b - a))
        return np.concatenate(out)

    def edge_free(self, a: np.ndarray, b: np.ndarray, held: Payload) -> bool:
        """Whether the straight joint segment a -> b is free at every joint_resolution (the quick
        check of RRT edges and shortcuts; the path they make is then proven all along, :meth:`timed`)."""
        return self.world.path_free(self.densify(np.array([a, b])), held) is None

    def transfer(self, q_a: np.ndarray, q_b: np.ndarray, held: Payload, what: str) -> np.ndarray:
        if self.edge_free(q_a, q_b, held):
            return np.array([q_a, q_b])
        path = self.rrt_connect(q_a, q_b, held, what)
        return self.shortcut(path, held)

    def rrt_connect(self, q_a: np.ndarray, q_b: np.ndarray, held: Payload, what: str) -> np.ndarray:
        trees = [([q_a], [-1]), ([q_b], [-1])]
        step = self.o.rrt_step

        def extend(tree, target):
            nodes, parents = tree
            arr = np.array(nodes)
            i = int(np.argmin(np.linalg.norm(arr - target, axis=1)))
            d = target - nodes[i]
            n = float(np.linalg.norm(d))
            new = target if n <= step else nodes[i] + d * (step / n)
            if not self.edge_free(nodes[i], new, held):
                return None
            nodes.append(new)
            parents.append(i)
            return len(nodes) - 1

        def branch(tree, i):
            nodes, parents = tree
            out = []
            while i != -1:
                out.append(nodes[i])
                i = parents[i]
            return out

        for it in range(self.o.rrt_iterations):
            sample = self.lo + (self.hi - self.lo) * self.rng.random(self.robot.dof)
            ta, tb = trees if it % 2 == 0 else trees[::-1]
            ia = extend(ta, sample)
            if ia is None:
                continue
            target = ta[0][ia]
            while True:  # connect
                ib = extend(tb, target)
                if ib is None:
                    break
                if np.allclose(tb[0][ib], target):
                    pa, pb = branch(ta, ia), branch(tb, ib)
                    path = pa[::-1] + pb[1:]
                    if ta is not trees[0]:
                        path = path[::-1]
                    log.debug("RRT-Connect: %s in %d iterations", what, it + 1)
                    return np.array(path)
        raise PlanningError(f"{what}: no collision-free joint path found in {self.o.rrt_iterations} RRT iterations")

    def shortcut(self, path: np.ndarray, held: Payload) -> np.ndarray:
        pts = list(path)
        for _ in range(self.o.shortcut_attempts):
            if len(pts) < 3:
                break
            i, j = sorted(self.rng.choice(len(pts), 2, replace=False))
            if j - i < 2:
                continue
            if self.edge_free(pts[i], pts[j], held):
                pts = pts[: i + 1] + pts[j:]
        return np.array(pts)

    def timed(self, name: str, kind: str, qs: np.ndarray, held: Payload) -> TimedMove:
        """Time the path through ``qs`` and prove the timed path free all along.

        A joint transfer's polyline is proven first (its RRT edges and shortcuts were only checked
        every joint_resolution); a transfer whose polyline or timed path still touches something
        (a graze between those checks) is planned again, up to three times (the seeded generator
        has moved on, so the new path differs and plans stay reproducible)."""
        qs = np.asarray(qs, dtype=float)
        for _ in range(3):
            if kind == "joint":
                hit = self.sweep.polyline_contact(qs, held)
                if hit is not None:
                    log.debug("%s: the path collides between its checks (%s); planning it again", name, hit[1])
                    qs = self.shortcut(self.rrt_connect(qs[0], qs[-1], held, name), held)
                    continue
            try:
                return self._timed_once(name, kind, qs, held, proven=kind == "joint")
            except PlanningError as e:
                if kind != "joint":
                    raise
                log.debug("%s: %s; planning the transfer again", name, e)
                qs = self.shortcut(self.rrt_connect(qs[0], qs[-1], held, name), held)
        hit = self.sweep.polyline_contact(qs, held)
        if hit is not None:
            raise PlanningError(f"{name}: the path collides ({hit[1]})")
        return self._timed_once(name, kind, qs, held)

    def _timed_once(self, name: str, kind: str, qs: np.ndarray, held: Payload, proven: bool = False) -> TimedMove:
        """Time ``qs`` and prove the timed path; ``proven``: the polyline through ``qs`` is (so a
        spline that is one straight segment, as through two waypoints, needs no second proof)."""
        wp = np.asarray(qs, dtype=float)
        problem = ""
        for attempt in range(4):
            try:
                traj = time_path(wp, self.vmax, self.amax, q_lower=self.robot.q_lower, q_upper=self.robot.q_upper)
            except PlanningError as e:  # the spline overshot a joint limit between waypoints
                problem = str(e)
            else:
                path = PPoly(traj.coefficients, traj.breakpoints)
                # The whole driven path, not samples of it: cut where a joint turns, then proven
                # piece by piece (robotprog.sweep).
                breaks = monotone_breaks(traj.breakpoints, traj.coefficients)
                straight = proven and traj.coefficients.shape[1] == 1 and not np.any(traj.coefficients[:2])
                hit = None if straight else self.sweep.first_contact(path, breaks, held)
                if hit is None:
                    return TimedMove(name, traj, kind, wp, held, transform_world_to_tcp=self.tcp_world(wp[-1]))
                problem = f"the timed path collides ({hit[1]})"
            # The spline strayed from the checked polyline: pin it down with waypoints on the
            # polyline, every joint_resolution, then twice and four times as dense (a spline
            # through dense points of a free polyline stays within a shrinking distance of it).
            wp = self.densify(wp, self.o.joint_resolution / 2 ** max(0, attempt - 1) if attempt else None)
        raise PlanningError(f"{name}: {problem}")

    def pick_and_place(self, q_start: np.ndarray, pick: Station, place: Station, names: PickPlaceNames, *,
                       open_: Payload, carried: Payload, placed: Payload, at_pick: "_Planner | None" = None,
                       at_place: "_Planner | None" = None) -> PickPlace:
        """The step every tending phase is made of: from ``q_start`` to above ``pick``, straight down,
        grip, straight up, across to above ``place``, straight down, release, straight up.

        Every pose and line is solved and checked before anything is timed (an unreachable place
        fails fast). ``open_`` rides on the TCP on the way to the pick and after the release (the
        fingers open), ``carried`` from the grip to above the place, ``placed`` on the way down and
        at the release (the box as it is set down). ``at_pick`` plans the way to the pick and the
        approach, ``at_place`` the line up after the release (planners whose worlds hold what stands
        there then; default this one).
        """
        a = self if at_pick is None else at_pick
        b = self if at_place is None else at_place
        h = self.o.approach_height
        q_above_pick = a.pick_ik(_raise_up(pick.grasp, h), q_start, open_, pick.above, pick.field)
        down = a.line(_raise_up(pick.grasp, h), pick.grasp, q_above_pick, open_, pick.down, pick.field)
        lift = self.line(pick.grasp, _raise_up(pick.grasp, h), down[-1], carried, pick.up, pick.field)
        q_above_place = self.pick_ik(_raise_up(place.grasp, h), lift[-1], placed, place.above, place.field)
        lower = self.line(_raise_up(place.grasp, h), place.grasp, q_above_place, placed, place.down, place.field)
        leave = b.line(place.grasp, _raise_up(place.grasp, h), lower[-1], open_, place.up, place.field)
        io = self.cell.gripper.io
        moves = [a.timed(names.to_pick, "joint", a.transfer(q_start, q_above_pick, open_, names.to_pick_what), open_),
                 a.timed(names.approach, "linear", down, open_),
                 self.gripper(names.grip, down[-1], io.grip, open_),
                 self.timed(names.lift, "linear", lift, carried)]
        moves.append(self.timed(names.transfer, "joint",
                                self.transfer(lift[-1], q_above_place, carried, names.transfer_what), carried))
        moves += [self.timed(names.place, "linear", lower, placed),
                  self.gripper(names.release, lower[-1], io.release, placed),
                  b.timed(names.leave, "linear", leave, open_)]
        return PickPlace(tuple(moves), lift[-1])

    def gripper(self, name: str, q: np.ndarray, outputs, held: Payload) -> TimedMove:
        traj = time_path(q[None, :], self.vmax, self.amax)
        return TimedMove(name, traj, "gripper", q[None, :].copy(), held, tuple(outputs),
                         self.cell.gripper.io.settle_s, self.tcp_world(q))


def _raise_up(t: np.ndarray, dz: float) -> np.ndarray:
    out = t.copy()
    out[2, 3] += dz
    return out


def _slot(grid: SlotGrid, slot: tuple[int, int], field_name: str) -> np.ndarray:
    try:
        return grid.slot_transform(*slot)
    except CellError as e:
        raise CellError(str(e.args[0]) if e.args else str(e), source=field_name) from None


def plan_tending(
    cell: Cell,
    sheet: dict[str, Any],
    *,
    part_box: tuple[np.ndarray, np.ndarray] | None = None,
    world: CollisionWorld | None = None,
    options: TendingOptions = TendingOptions(),
    source: str | None = None,
    setups: int = 1,
) -> TendingPlan:
    """Plan loading the stock of ``sheet`` into the vise and unloading the finished part; with
    two setups, turning the part over on the flip station between them (:mod:`robotprog.flip`).

    Parameters
    ----------
    cell : Cell
    sheet : dict
        The part's ``factory.setup/1`` setup sheet.
    part_box : ((3,), (3,)) float, optional
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
        np.asarray(part_box[0], dtype=float), np.asarray(part_box[1], dtype=float))
    piece = None
    if setups == 2:
        from robotprog.flip import TURNOVER_AXIS, Piece  # noqa: PLC0415 (flip imports this module)

        piece = Piece.after_op1(stock.stock_min, stock.stock_max, pmin, pmax)
        # op 2 holds the part upside down, on its finished faces; unload grips it there
        turned = piece.turned(TURNOVER_AXIS)
        pmin, pmax = turned.part_min, turned.part_max
    psize = pmax - pmin
    s_size = stock.size
    # The blanks beside the one picked and the parts already in the out-tray are obstacles.
    obstacles = (_neighbours(cell.rack, options.rack_slot, s_size, "rack_blank")
                 + _neighbours(cell.out_tray, options.tray_slot, psize, "tray_part"))
    world = collision_world(cell, world.robot if world is not None else None, obstacles=obstacles)
    robot = world.robot
    p = _Planner(cell, robot, world, options)
    home = np.asarray(cell.robot.home, dtype=float)
    r_home = p.tcp_world(home)[:3, :3]
    t_vise = cell.vise.pose.matrix()
    t_rack = _slot(cell.rack, options.rack_slot, "rack")
    t_tray = _slot(cell.out_tray, options.tray_slot, "out_tray")
    # In rack and tray the box is centred on the slot, bottom at slot height.
    half = np.array([0.5, 0.5, 0.0])
    g_rack, held_stock = _grasp(cell, t_rack, -half * s_size, s_size - half * s_size, r_home, options, "stock")
    g_vise_in, held_vise = _grasp(cell, t_vise, stock.stock_min, stock.stock_max, r_home, options, "stock")
    g_vise_out, held_part = _grasp(cell, t_vise, pmin, pmax, r_home, options, "part")
    g_tray, _ = _grasp(cell, t_tray, -half * psize, psize - half * psize, r_home, options, "part")
    # The fingers: open a clearance beyond the box on the way to it and after letting it go,
    # closed on it while holding it.
    fingers = cell.gripper.fingers
    stock_width = float(min(s_size[0], s_size[1]))
    part_width = float(min(psize[0], psize[1]))
    open_stock = finger_boxes(cell, min(cell.gripper.opening_max, stock_width + 2 * fingers.clearance))
    open_part = finger_boxes(cell, min(cell.gripper.opening_max, part_width + 2 * fingers.clearance))
    closed_stock = finger_boxes(cell, stock_width)
    closed_part = finger_boxes(cell, part_width)
    held_tray = HeldBox.at(psize, np.linalg.inv(g_tray) @ _box_pose(t_tray, -half * psize, psize - half * psize))
    with_stock = closed_stock + (held_stock,)
    in_vise = closed_stock + (held_vise,)
    with_part = closed_part + (held_part,)
    to_tray = closed_part + (held_tray,)

    moves: list[TimedMove] = []
    io = cell.gripper.io
    load = p.pick_and_place(
        home, Station(g_rack, "rack.pose", "above rack slot", "approach to rack slot", "retreat from rack slot"),
        Station(g_vise_in, "vise.pose", "above vise", "place in vise", "retreat from vise"),
        PickPlaceNames("load: home to above rack", "load: approach stock", "load: grip stock", "load: retreat from rack",
                       "load: transfer to vise", "load: place in vise", "load: release stock", "load: retreat from vise",
                       "home to rack", "rack to vise"),
        open_=open_stock, carried=with_stock, placed=in_vise)
    moves += load.moves
    moves.append(p.timed("load: return home", "joint", p.transfer(load.moves[-1].q_end, home, open_stock,
                                                                  "vise to home"), open_stock))
    if piece is not None:
        from robotprog.flip import plan_flip  # noqa: PLC0415

        flip, _ = plan_flip(p, cell, piece, home, r_home, obstacles, _grasp, _raise_up)
        moves.extend(flip)
    unload = p.pick_and_place(
        home, Station(g_vise_out, "vise.pose", "above vise", "approach to part", "retreat from vise"),
        Station(g_tray, "out_tray.pose", "above out-tray slot", "place in out-tray", "retreat from out-tray"),
        PickPlaceNames("unload: home to above vise", "unload: approach part", "unload: grip part",
                       "unload: retreat from vise", "unload: transfer to out-tray", "unload: place in out-tray",
                       "unload: release part", "unload: retreat from out-tray", "home to vise", "vise to out-tray"),
        open_=open_part, carried=with_part, placed=to_tray)
    moves += unload.moves
    moves.append(p.timed("unload: return home", "joint",
                         p.transfer(unload.moves[-1].q_end, home, open_part, "out-tray to home"), open_part))
    reject: list[TimedMove] = []
    if cell.reject_bin is not None:
        # A rejected part goes from above the vise to above the bin instead of the tray and
        # is let go there, its bottom reject_drop above the rim; then home.
        t_bin = cell.reject_bin.pose.matrix()
        g_bin = g_vise_out.copy()
        part_below_tcp = g_vise_out[2, 3] - (t_vise @ np.append(pmin, 1.0))[2]
        g_bin[:3, 3] = (t_bin[0, 3], t_bin[1, 3],
                        t_bin[2, 3] + cell.reject_bin.size[2] / 2 + options.reject_drop + part_below_tcp)
        q_bin = p.pick_ik(g_bin, unload.q_lifted, with_part, "above reject bin", "reject_bin.pose")
        reject.append(p.timed("reject: transfer to bin", "joint",
                              p.transfer(unload.q_lifted, q_bin, with_part, "vise to reject bin"), with_part))
        reject.append(p.gripper("reject: release part", q_bin, io.release, with_part))
        reject.append(p.timed("reject: return home", "joint", p.transfer(q_bin, home, open_part, "bin to home"),
                              open_part))
    for m in moves + reject:
        m.waypoints.setflags(write=False)
    pmin = pmin.copy()
    pmax = pmax.copy()
    pmin.setflags(write=False)
    pmax.setflags(write=False)
    dt = time.perf_counter() - t0
    log.info("tending plan: %d moves, %.2f s of motion, planned in %.2f s", len(moves),
             sum(m.duration for m in moves), dt)
    return TendingPlan(tuple(moves), stock, pmin, pmax, dt, obstacles, tuple(reject))


def _box_pose(t_support: np.ndarray, bmin: np.ndarray, bmax: np.ndarray) -> np.ndarray:
    box = np.eye(4)
    box[:3, :3] = t_support[:3, :3]
    box[:3, 3] = (t_support @ np.append((bmin + bmax) / 2, 1.0))[:3]
    return box


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
