"""The motion planner of the cell: joint transfers, straight TCP lines, timing, and the proof.

:class:`MotionPlanner` plans the robot's moves in one :class:`robotprog.collision.CollisionWorld`
and returns each as a :class:`TimedMove`; the tending plan (:mod:`robotprog.tending`) and the flip
(:mod:`robotprog.flip`) are made of its moves, most of them by :meth:`MotionPlanner.pick_and_place`
between two :class:`Station`.

Moves
-----
* *Approach* and *retreat* (:meth:`MotionPlanner.line`) are straight lines of the TCP, IK-sampled
  every :attr:`PlannerOptions.line_step` with :func:`robotprog.ik.ik_continuous` (the branch
  continuous with the previous sample), and proven collision-free all along (:mod:`robotprog.sweep`)
  before anything is timed, so that a line that cannot be made fails fast
  (:meth:`MotionPlanner.prove_line`): the motion that runs, the timed spline through the samples, is
  proven there, as :meth:`MotionPlanner.timed` would prove it, and kept for it (a line is proven once);
  only where that spline cannot be timed or touches is the polyline of the samples proven instead,
  and the spline is then timed and proven by :meth:`MotionPlanner.timed` as any other.
* *Transfers* (:meth:`MotionPlanner.transfer`) are straight in joint space when that is
  collision-free at :attr:`PlannerOptions.joint_resolution`; otherwise an RRT-Connect in joint space
  finds a path, which is then shortcut (random pairs of path points joined when the straight joint
  segment between them is free at that resolution). The result is a :class:`JointPath` that says
  which of the two found it. The transfer is then proven free all along, not only at the checks
  (else it is planned again): its timed spline, and its polyline where the spline touches.
* Each move is timed with :func:`robotprog.timing.time_path` (:meth:`MotionPlanner.timed`) and the
  timed spline, the path the controller drives, is proven free all along too (the cubic spline
  through the waypoints need not follow the polyline); where it is not, the waypoints are densified
  and the move re-timed. A transfer's timed spline is proven first: where it is free, the polyline
  it was timed through is never driven and needs no proof; only where it touches is the polyline
  proven, to tell a path to plan again from a spline to pin down.
* The timed spline is proven with room around it (:attr:`TimedMove.tube`): every configuration
  within the chord deviation of its samples every :data:`CHORD_PERIOD_S` is free too, so the posted
  servo stream, the polyline through those samples, is proven by that bound
  (:func:`robotprog.programs.posted_collision`) instead of being proven again.
* *Gripper* actions (:meth:`MotionPlanner.gripper`) set digital outputs and wait the settle time.

Reproducible plans
------------------
A planner owns one :class:`numpy.random.Generator` seeded with :attr:`PlannerOptions.seed`; the RRT
samples and the shortcut pairs are drawn from it in the order the moves are planned, so the same
calls on a planner built the same way give the same moves to the bit. A planner for a world with
more boxes (:meth:`MotionPlanner.among`) starts its own generator from the same seed.

The roadmap
-----------
:meth:`MotionPlanner.transfer` is the one place a joint path between two configurations is
searched. The cell is static but for the stock, the part in hand and what stands beside them
(:attr:`robotprog.collision.CollisionWorld.obstacles`), and its trips repeat (home, rack, vise, flip
station, out-tray, the "above" poses of the :class:`Station`). A planner given the cell's
:class:`robotprog.roadmap.Roadmap` looks a transfer that is not straight up there first: the ends
joined to the roadmap, its segments checked in this planner's world with what is held, the path
shortcut and pulled taut (deterministic, no random draws), then timed and proven like any other;
the RRT-Connect is the fall-back (no path through the roadmap, or one the proof refuses).

Frames and units: world frame of the cell; metres, radians, seconds.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import PPoly

from factory.core.errors import PlanningError
from robotprog.cell import Box, Cell
from robotprog.collision import CollisionWorld, Payload, _riding, collision_world
from robotprog.ik import ik_continuous, ik_solutions
from robotprog.roadmap import Roadmap, RoadmapOnDemand, joint_box
from robotprog.sweep import monotone_breaks, swept_motion
from robotprog.timing import Trajectory, time_path

log = logging.getLogger(__name__)

#: The timed path is proven with room for the chords between its samples this far apart [s]: the
#: URScript servo stream's period (:data:`robotprog.programs.SERVO_PERIOD_S`), whose polyline is then
#: proven by that bound (:attr:`TimedMove.tube`).
CHORD_PERIOD_S = 0.008

#: Largest joint step between two IK samples of a straight line before it counts as the arm
#: flipping its configuration [rad].
LINE_FLIP_RAD = 0.25


@dataclass(frozen=True)
class PlannerOptions:
    """Motion planner settings.

    Attributes
    ----------
    approach_height : float
        Height of a station's "above" pose over its grasp pose [m].
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
        Seed of the planner's random generator (RRT samples, shortcut pairs): the same seed
        gives the same plan.
    """

    approach_height: float = 0.10
    line_step: float = 0.005
    joint_resolution: float = 0.02
    rrt_step: float = 0.15
    rrt_iterations: int = 4000
    shortcut_attempts: int = 60
    seed: int = 0


@dataclass(frozen=True, eq=False)
class TimedMove:
    """One move of a plan.

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
    tube : (dof,) float or None
        Room [rad] proven free around the timed path, joint by joint (with ``held``, in the world
        the move was planned in): at least the chord deviation of its samples every
        :data:`CHORD_PERIOD_S` (:meth:`robotprog.timing.Trajectory.chord_deviation`). None: the
        path alone is proven.
    """

    name: str
    trajectory: Trajectory
    kind: str
    waypoints: np.ndarray
    held: Payload = None
    outputs: tuple[tuple[int, bool], ...] = ()
    settle_s: float = 0.0
    transform_world_to_tcp: np.ndarray = field(default_factory=lambda: np.eye(4))
    tube: np.ndarray | None = None

    @property
    def duration(self) -> float:
        """Time of the move [s] (a gripper action: its settle time)."""
        return self.settle_s if self.kind == "gripper" else self.trajectory.duration

    @property
    def q_end(self) -> np.ndarray:
        """Last configuration [rad]."""
        return self.waypoints[-1]


@dataclass(frozen=True, eq=False)
class JointPath:
    """A joint transfer's path, checked every ``joint_resolution`` (:meth:`MotionPlanner.transfer`).

    Attributes
    ----------
    waypoints : (n, dof) float
        From the start to the goal configuration [rad].
    search : str
        How it was found: ``"straight"`` (the direct joint segment is free), ``"roadmap"``
        (through the cell's roadmap, then shortcut) or ``"rrt-connect"`` (sampled, then shortcut).
    """

    waypoints: np.ndarray
    search: str


@dataclass(frozen=True, eq=False)
class Station:
    """One end of a pick-and-place (:meth:`MotionPlanner.pick_and_place`): where a box is taken or left.

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


def raise_up(t: np.ndarray, dz: float) -> np.ndarray:
    """The pose (4, 4) ``t`` moved up the world's Z by ``dz`` [m] (a station's "above" pose)."""
    out = t.copy()
    out[2, 3] += dz
    return out


class MotionPlanner:
    """Plans and proves the robot's moves in one collision world.

    Parameters
    ----------
    cell : Cell
    world : CollisionWorld
        The cell with the boxes this plan avoids; its robot is the one planned for.
    options : PlannerOptions
    roadmap : Roadmap or RoadmapOnDemand, optional
        The cell's roadmap (:func:`robotprog.roadmap.cell_roadmap`), looked up before a transfer is searched
        (on demand: got when the first transfer needs it).

    Attributes
    ----------
    vmax, amax : (dof,) float
        Joint velocity [rad/s] and acceleration [rad/s^2] limits, scaled by the cell's speed scaling.
    lo, hi : (dof,) float
        The joint box RRT samples are drawn from [rad]: the joint limits, at most half a turn from home.
    """

    def __init__(self, cell: Cell, world: CollisionWorld, options: PlannerOptions = PlannerOptions(),
                 roadmap: Roadmap | RoadmapOnDemand | None = None):
        robot = world.robot
        self.cell, self.robot, self.world, self.options = cell, robot, world, options
        self.roadmap = roadmap
        self.t_base_world = np.linalg.inv(cell.robot.base.matrix())
        self.t_tcp_flange = np.linalg.inv(cell.gripper.tcp.matrix())
        self.vmax = robot.v_max * cell.motion.speed_scaling
        self.amax = np.asarray(cell.motion.acceleration_limits, dtype=float) * cell.motion.speed_scaling
        self.rng = np.random.default_rng(options.seed)
        self.lo, self.hi = joint_box(robot.q_lower, robot.q_upper, np.asarray(cell.robot.home))
        self.sweep = swept_motion(world, options.joint_resolution)
        #: lines proven by :meth:`prove_line`, by their samples and payload: (timed path, its room)
        self._lines: dict[tuple[bytes, tuple], tuple[Trajectory, np.ndarray | None]] = {}

    def among(self, obstacles: tuple[Box, ...]) -> "MotionPlanner":
        """A planner with the same options for this world plus ``obstacles`` (world frame), its
        random generator started afresh from the seed."""
        world = collision_world(self.cell, self.robot, door_closed=self.world.door_closed,
                                obstacles=self.world.obstacles + obstacles)
        return MotionPlanner(self.cell, world, self.options, self.roadmap)

    # --- poses -----------------------------------------------------------------------------

    def flange(self, t_world_tcp: np.ndarray) -> np.ndarray:
        """The flange pose (4, 4) in the robot's base frame that puts the TCP at ``t_world_tcp`` [m]."""
        return self.t_base_world @ t_world_tcp @ self.t_tcp_flange

    def tcp_world(self, q: np.ndarray) -> np.ndarray:
        """The TCP pose (4, 4) in the world at configuration ``q`` [rad] [m]."""
        return self.cell.robot.base.matrix() @ self.robot.fk(q) @ self.cell.gripper.tcp.matrix()

    def ik(self, t_world_tcp: np.ndarray, q_ref: np.ndarray, held: Payload, what: str,
           field_name: str) -> np.ndarray:
        """The collision-free IK solution (dof,) [rad] of the TCP pose nearest ``q_ref``.

        Raises
        ------
        PlanningError
            ``what`` is out of reach or only reachable in collision (blamed on ``field_name``).
        """
        sols = ik_solutions(self.robot, self.flange(t_world_tcp), q_ref)
        sols = [q for q in sols if not self.world.in_collision(q, held)]
        if not sols:
            raise PlanningError(f"{what} is out of reach or only reachable in collision", source=field_name)
        return min(sols, key=lambda q: float(np.linalg.norm(q - q_ref)))

    # --- straight lines of the TCP ---------------------------------------------------------

    def line(self, t_a: np.ndarray, t_b: np.ndarray, q_a: np.ndarray, held: Payload,
             what: str, field_name: str) -> np.ndarray:
        """The TCP's straight line from pose ``t_a`` to ``t_b`` (orientation of ``t_a``) from ``q_a``:
        (n, dof) joint samples [rad], every ``line_step``, proven free all along (:meth:`prove_line`).

        Raises
        ------
        PlanningError
            A sample has no IK solution continuous with the last, the arm flips configuration,
            or the line collides (blamed on ``field_name``).
        """
        d = float(np.linalg.norm(t_b[:3, 3] - t_a[:3, 3]))
        n = max(2, int(math.ceil(d / self.options.line_step)) + 1)
        qs = [q_a]
        for f in np.linspace(0.0, 1.0, n)[1:]:
            t = t_a.copy()
            t[:3, 3] = (1 - f) * t_a[:3, 3] + f * t_b[:3, 3]
            try:
                q = ik_continuous(self.robot, self.flange(t), qs[-1])
            except PlanningError as e:
                raise PlanningError(f"{what}: {e}", source=field_name) from None
            if np.abs(q - qs[-1]).max() > LINE_FLIP_RAD:
                raise PlanningError(f"{what}: the arm flips configuration along the line", source=field_name)
            qs.append(q)
        qs = np.array(qs)
        self.prove_line(qs, held, what, field_name)
        return qs

    def prove_line(self, qs: np.ndarray, held: Payload, what: str, field_name: str) -> None:
        """Proves the TCP line through the joint samples ``qs`` (n, dof) [rad] free all along, before it
        is timed: the timed spline through them (the motion that runs, proven exactly as :meth:`timed`
        proves it, which then takes it as it is), else, where that spline cannot be timed or touches,
        the polyline of the samples (the spline is then pinned down by :meth:`timed`).

        Raises
        ------
        PlanningError
            The polyline collides (blamed on ``field_name``).
        """
        try:
            traj = self._time(qs)
        except PlanningError:  # the spline overshoots a joint limit: timed() pins it down
            traj = None
        if traj is not None:
            tube, hit = self._proven(traj, held)
            if hit is None:
                self._lines[self._line_key(qs, held)] = (traj, tube)
                return
        hit = self.sweep.polyline_contact(qs, held)
        if hit is not None:
            raise PlanningError(f"{what} collides ({hit[1]})", source=field_name)

    @staticmethod
    def _line_key(qs: np.ndarray, held: Payload) -> tuple[bytes, tuple]:
        """What a line's proof depends on besides this planner's world: its samples and what rides."""
        q = np.ascontiguousarray(qs, dtype=float)
        return q.tobytes() + repr(q.shape).encode(), _riding(held)

    # --- joint transfers -------------------------------------------------------------------

    def densify(self, qs: np.ndarray, resolution: float | None = None) -> np.ndarray:
        """The polyline through ``qs`` (n, dof) [rad] with points at most ``resolution`` [rad]
        apart in every joint (default ``joint_resolution``)."""
        step = self.options.joint_resolution if resolution is None else resolution
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

    def transfer(self, q_a: np.ndarray, q_b: np.ndarray, held: Payload, what: str) -> JointPath:
        """A joint path from ``q_a`` to ``q_b`` [rad]: straight when that is free, else through the
        roadmap (if any), else searched.

        Raises
        ------
        PlanningError
            No path found (``what`` names the transfer).
        """
        if self.edge_free(q_a, q_b, held):
            return JointPath(np.array([q_a, q_b]), "straight")
        if self.roadmap is not None:
            found = self.roadmap.path(q_a, q_b, lambda a, b: self.edge_free(a, b, held))
            if found is not None:
                return JointPath(self.shortcut_greedy(found, held), "roadmap")
            log.debug("%s: no path through the roadmap; searching", what)
        return JointPath(self._search(q_a, q_b, held, what), "rrt-connect")

    def joint_move(self, name: str, q_a: np.ndarray, q_b: np.ndarray, held: Payload, what: str) -> TimedMove:
        """The transfer from ``q_a`` to ``q_b`` [rad], timed and proven (:meth:`transfer`, :meth:`timed`)."""
        return self.timed(name, "joint", self.transfer(q_a, q_b, held, what).waypoints, held)

    def _search(self, q_a: np.ndarray, q_b: np.ndarray, held: Payload, what: str) -> np.ndarray:
        """An RRT-Connect path, shortcut: (n, dof) [rad]."""
        return self.shortcut(self.rrt_connect(q_a, q_b, held, what), held)

    def rrt_connect(self, q_a: np.ndarray, q_b: np.ndarray, held: Payload, what: str) -> np.ndarray:
        """RRT-Connect from ``q_a`` to ``q_b``: (n, dof) [rad], edges free at ``joint_resolution``.

        Raises
        ------
        PlanningError
            No path in ``rrt_iterations`` iterations.
        """
        trees = [([q_a], [-1]), ([q_b], [-1])]
        step = self.options.rrt_step

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

        for it in range(self.options.rrt_iterations):
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
        raise PlanningError(
            f"{what}: no collision-free joint path found in {self.options.rrt_iterations} RRT iterations")

    def shortcut(self, path: np.ndarray, held: Payload) -> np.ndarray:
        """``path`` (n, dof) [rad] with random pairs of its points joined where the straight joint
        segment between them is free at ``joint_resolution`` (``shortcut_attempts`` tries)."""
        pts = list(path)
        for _ in range(self.options.shortcut_attempts):
            if len(pts) < 3:
                break
            i, j = sorted(self.rng.choice(len(pts), 2, replace=False))
            if j - i < 2:
                continue
            if self.edge_free(pts[i], pts[j], held):
                pts = pts[: i + 1] + pts[j:]
        return np.array(pts)

    def shortcut_greedy(self, path: np.ndarray, held: Payload) -> np.ndarray:
        """``path`` (n, dof) [rad] with each point joined to the farthest later one the straight
        joint segment reaches free at ``joint_resolution`` (deterministic: no random pairs)."""
        out, i = [path[0]], 0
        while i < len(path) - 1:
            j = len(path) - 1
            while j > i + 1 and not self.edge_free(path[i], path[j], held):
                j -= 1
            out.append(path[j])
            i = j
        return self.tighten(np.array(out), held, rounds=10)

    def tighten(self, path: np.ndarray, held: Payload, rounds: int = 6) -> np.ndarray:
        """``path`` (n, dof) [rad] pulled taut: each inner point moved half way to the midpoint of
        its neighbours where both its segments stay free at ``joint_resolution`` (``rounds`` passes;
        a roadmap path's corners sit where the sampled nodes happened to be)."""
        pts = np.array(path, dtype=float)
        for _ in range(rounds):
            moved = False
            for k in range(1, len(pts) - 1):
                mid = 0.5 * (pts[k - 1] + pts[k + 1])
                for f in (0.5, 0.25):  # a smaller pull where the half one grazes something
                    target = pts[k] + f * (mid - pts[k])
                    if self.edge_free(pts[k - 1], target, held) and self.edge_free(target, pts[k + 1], held):
                        pts[k] = target
                        moved = True
                        break
            if not moved:
                break
        return pts

    # --- timing and the proof --------------------------------------------------------------

    def timed(self, name: str, kind: str, qs: np.ndarray, held: Payload) -> TimedMove:
        """Time the path through ``qs`` (n, dof) [rad] and prove the timed path free all along.

        A joint transfer's timed path is proven first, as it is timed; where it touches, its
        polyline is proven (its RRT edges and shortcuts were only checked every joint_resolution):
        a transfer whose polyline or timed path still touches something (a graze between those
        checks) is planned again, up to three times (the seeded generator has moved on, so the new
        path differs and plans stay reproducible). The timed path is proven with room for the
        chords of its samples (:attr:`TimedMove.tube`) where it has that room.

        Raises
        ------
        PlanningError
            The path cannot be timed within the joint limits or proven free.
        """
        qs = np.asarray(qs, dtype=float)
        if kind == "linear":
            proven = self._lines.pop(self._line_key(qs, held), None)
            if proven is not None:  # its timed path was proven as it was solved (prove_line)
                return TimedMove(name, proven[0], kind, qs, held, transform_world_to_tcp=self.tcp_world(qs[-1]),
                                 tube=proven[1])
        if kind == "joint":
            # The motion that runs is the timed spline: proven as it is, the polyline it was timed
            # through needs no proof of its own; only where it touches is the polyline asked, to
            # tell a graze of the search's path from the spline straying off a free one.
            try:
                return self._timed_once(name, kind, qs, held, attempts=1)
            except PlanningError:
                pass
        for _ in range(3):
            if kind == "joint":
                hit = self.sweep.polyline_contact(qs, held)
                if hit is not None:
                    log.debug("%s: the path collides between its checks (%s); planning it again", name, hit[1])
                    qs = self._search(qs[0], qs[-1], held, name)
                    continue
            try:
                return self._timed_once(name, kind, qs, held, proven=kind == "joint")
            except PlanningError as e:
                if kind != "joint":
                    raise
                log.debug("%s: %s; planning the transfer again", name, e)
                qs = self._search(qs[0], qs[-1], held, name)
        hit = self.sweep.polyline_contact(qs, held)
        if hit is not None:
            raise PlanningError(f"{name}: the path collides ({hit[1]})")
        return self._timed_once(name, kind, qs, held)

    def _proven(self, traj: Trajectory, held: Payload) -> tuple[np.ndarray | None, tuple[float, str] | None]:
        """Proves the timed path of ``traj`` free all along, with room for the chords of its samples
        every :data:`CHORD_PERIOD_S` (that tube), else the path alone (tube None: only a graze
        closer than the tube); returns (tube, None), or (None, the contact) where it touches."""
        path = PPoly(traj.coefficients, traj.breakpoints)
        # The whole driven path, not samples of it: cut where a joint turns, then proven piece by
        # piece (robotprog.sweep).
        breaks = monotone_breaks(traj.breakpoints, traj.coefficients)
        tube = traj.chord_deviation(CHORD_PERIOD_S)
        if self.sweep.first_contact(path, breaks, held, tube) is None:
            return tube, None
        return None, self.sweep.first_contact(path, breaks, held)

    def _timed_once(self, name: str, kind: str, qs: np.ndarray, held: Payload, proven: bool = False,
                    attempts: int = 4) -> TimedMove:
        """Time ``qs`` and prove the timed path, pinned down by denser waypoints where it strays, in up to
        ``attempts`` tries; ``proven``: the polyline through ``qs`` is (so a spline that is one straight
        segment, as through two waypoints, needs no second proof)."""
        wp = np.asarray(qs, dtype=float)
        problem = ""
        for attempt in range(attempts):
            if attempt:
                # The spline strayed from the checked polyline: pin it down with waypoints on the
                # polyline, every joint_resolution, then twice and four times as dense (a spline
                # through dense points of a free polyline stays within a shrinking distance of it).
                wp = self.densify(wp, self.options.joint_resolution / 2 ** (attempt - 2) if attempt > 1 else None)
            try:
                traj = self._time(wp)
            except PlanningError as e:  # the spline overshot a joint limit between waypoints
                problem = str(e)
                continue
            straight = proven and traj.coefficients.shape[1] == 1 and not np.any(traj.coefficients[:2])
            tube, hit = (None, None) if straight else self._proven(traj, held)
            if hit is None:
                return TimedMove(name, traj, kind, wp, held, transform_world_to_tcp=self.tcp_world(wp[-1]),
                                 tube=tube)
            problem = f"the timed path collides ({hit[1]})"
        raise PlanningError(f"{name}: {problem}")

    def _time(self, wp: np.ndarray) -> Trajectory:
        """The time-optimal timing of the path through ``wp`` (n, dof) [rad] within the joint limits."""
        return time_path(wp, self.vmax, self.amax, q_lower=self.robot.q_lower, q_upper=self.robot.q_upper)

    def gripper(self, name: str, q: np.ndarray, outputs, held: Payload) -> TimedMove:
        """A gripper action at ``q`` [rad]: set ``outputs`` ((int, bool) pairs), wait the settle time."""
        traj = time_path(q[None, :], self.vmax, self.amax)
        return TimedMove(name, traj, "gripper", q[None, :].copy(), held, tuple(outputs),
                         self.cell.gripper.io.settle_s, self.tcp_world(q))

    # --- the step every tending phase is made of -------------------------------------------

    def pick_and_place(self, q_start: np.ndarray, pick: Station, place: Station, names: PickPlaceNames, *,
                       open_: Payload, carried: Payload, placed: Payload, at_pick: "MotionPlanner | None" = None,
                       at_place: "MotionPlanner | None" = None) -> PickPlace:
        """From ``q_start`` [rad] to above ``pick``, straight down, grip, straight up, across to above
        ``place``, straight down, release, straight up.

        Every pose and line is solved and checked before anything is timed (an unreachable place
        fails fast). ``open_`` rides on the TCP on the way to the pick and after the release (the
        fingers open), ``carried`` from the grip to above the place, ``placed`` on the way down and
        at the release (the box as it is set down). ``at_pick`` plans the way to the pick and the
        approach, ``at_place`` the line up after the release (planners whose worlds hold what stands
        there then; default this one).
        """
        a = self if at_pick is None else at_pick
        b = self if at_place is None else at_place
        h = self.options.approach_height
        q_above_pick = a.ik(raise_up(pick.grasp, h), q_start, open_, pick.above, pick.field)
        down = a.line(raise_up(pick.grasp, h), pick.grasp, q_above_pick, open_, pick.down, pick.field)
        lift = self.line(pick.grasp, raise_up(pick.grasp, h), down[-1], carried, pick.up, pick.field)
        q_above_place = self.ik(raise_up(place.grasp, h), lift[-1], placed, place.above, place.field)
        lower = self.line(raise_up(place.grasp, h), place.grasp, q_above_place, placed, place.down, place.field)
        leave = b.line(place.grasp, raise_up(place.grasp, h), lower[-1], open_, place.up, place.field)
        io = self.cell.gripper.io
        moves = [a.joint_move(names.to_pick, q_start, q_above_pick, open_, names.to_pick_what),
                 a.timed(names.approach, "linear", down, open_),
                 self.gripper(names.grip, down[-1], io.grip, open_),
                 self.timed(names.lift, "linear", lift, carried),
                 self.joint_move(names.transfer, lift[-1], q_above_place, carried, names.transfer_what),
                 self.timed(names.place, "linear", lower, placed),
                 self.gripper(names.release, lower[-1], io.release, placed),
                 b.timed(names.leave, "linear", leave, open_)]
        return PickPlace(tuple(moves), lift[-1])
