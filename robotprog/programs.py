"""A tending plan as a robot program that runs the motion the planner proved.

The planner proves each move (TOPP-RA timing within the joint limits at 1 kHz, the timed
spline collision-checked). The program must drive *that* motion, not a new one the
controller invents between waypoints. Per language:

* **URScript** streams the proven trajectory: every motion move becomes a table of joint
  targets sampled from the timed trajectory every :data:`SERVO_PERIOD_S` (the CB3
  controller's 125 Hz cycle; an e-Series holds each for four of its 2 ms cycles), sent with
  ``servoj(q, 0, 0, t, lookahead_time, gain)`` in a loop. The controller reaches the
  targets at the plan's own times, so the program runs the planned duration (rounded up to
  whole periods per move), plus :data:`SERVO_LOOKAHEAD_S` of settle (the final target
  repeated) before each gripper action and at the end, where the arm must stand.
* **RAPID** and **KRL** have no servo stream without controller options (EGM, RSI), so they
  post *blended waypoints*: the proven trajectory sampled every ~:data:`SEGMENT_S`, each
  sample a joint move of that segment's time, blended into the next (RAPID ``MoveAbsJ ...
  vJoint\\T:=t, zBlend..``; KRL ``BAS(#VEL_PTP, pct)`` + ``PTP .. C_PTP``, the percentage
  that runs the segment in its time, rounded up), the last of each move exact (``fine`` /
  no ``C_PTP``) where the plan stops anyway.

Proof of the posted path: a URScript servo stream samples a move's timed path every
:data:`SERVO_PERIOD_S`; the planner proved that path with room for the chords between such samples
(:attr:`robotprog.planner.TimedMove.tube`), so the stream's polyline is proven by that bound, no
query of its own (where the room was not proven, as below). Otherwise
the controller drives the polyline through the posted targets,
cutting each blended corner within the triangle of the corner and its two segments' midpoints
(RAPID and KRL shrink a zone to at most half of its segments; a blend is a convex combination
of its two segments). :func:`check_posted_path` proves that polyline and every corner's
triangle free all along, not at samples (:mod:`robotprog.sweep`), with what the gripper holds
in that move; a move whose posted path collides is posted again with
segments half as long (down to :data:`MIN_SEGMENT_S`), hugging the proven trajectory closer. Each segment's speed is its joint travel over the
sample time of a trajectory proven within the limits, so it is within them too.

The pick at the rack takes the rack camera's correction at run time (:mod:`robotprog.rackpick`):
the program reads the blank's offset in its slot from the cell's controller (URScript: RTDE input
registers; RAPID: a ``PERS wobjdata``; KRL: a global ``FRAME``), stops on one beyond the slot
(:func:`correction_bounds`), and in a rack of several slots the slot the blank stands in (its row and
column, stopping on one outside the rack: :class:`robotprog.urscript.ReadCorrection`), then goes
straight (``movel`` / ``MoveL`` / ``LIN``) over the corrected grasp in that slot, down to it, grips,
straight up, and back to the end of the planned retreat over the plan's slot with a joint move; the
planned transfer to the vise goes on from there (:func:`robotprog.rackpick.corrected_pick` plans and
proves the same moves). With no correction (all zeros) that is
the plan's own path, proven here; each corrected pick is proven by the cell before the robot is
told to make it (:mod:`factory.rackloop`).

With ``cell.machine`` the program also drives the machine tool through its digital I/O, the
handshake :mod:`robotprog.machineio` defines once for programs and the cell simulation alike:
wait until it is idle, open the door, load; close the door, start the cycle, wait for it
to run and to finish, open the door; unload. The waits on inputs are the machine's time and
count nothing in the controller time. Where the cell wires the machine's verdict
(``part_ok``) and has a reject bin, the program reads it after the retreat from the vise and
branches: the rest of the unload to the out-tray, or the planned reject branch to the bin
(both proven like every move, both timed; the header states both).

Each program's header states the planned motion time and the controller's, timed by
:func:`robotprog.controller.program_duration` from the program's own steps.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from factory.core.errors import PlanningError
from robotprog.cell import Cell
from robotprog.collision import CollisionWorld, collision_world
from robotprog.controller import LANGS, program_duration
from robotprog.krl import krl_program
from robotprog.planner import CHORD_PERIOD_S, PlannerOptions, TimedMove
from robotprog.rapid import rapid_module
from robotprog.sweep import SweptMotion, swept_motion
from robotprog.robots import Robot
from robotprog.tending import TendingPlan
from robotprog.machineio import machine_cycle, machine_ready, number, to_steps, verdict
from robotprog.rackpick import slot_room
from robotprog.urscript import (Branch, Comment, MoveJ, MoveL, ReadCorrection, ServoJ, SetOutputs, Step, flat_steps,
                                urscript_program)

log = logging.getLogger(__name__)

#: servoj period [s]: the CB3 controller's cycle (125 Hz).
SERVO_PERIOD_S = CHORD_PERIOD_S
#: servoj lookahead [s] (the smallest the controller takes: least lag behind the table) and gain.
SERVO_LOOKAHEAD_S = 0.03
SERVO_GAIN = 300.0
#: The maker whose controller runs each language (a program carries that arm's joint values).
LANG_MAKER = {"urscript": "Universal Robots", "rapid": "ABB", "krl": "KUKA"}
LANG_NAME = {"urscript": "URScript", "rapid": "RAPID", "krl": "KRL"}
#: Longest segment [s] of a RAPID / KRL blended-waypoint move.
SEGMENT_S = 0.1
#: Shortest segment [s] a move is refined to when its posted path would collide (module docstring).
MIN_SEGMENT_S = 0.0125
#: RAPID zone radius of the blended samples [m] (the controller shrinks it to half a segment).
ZONE_M = 0.005
#: The rack pick's moves the program runs corrected by the rack camera (the module docstring).
RACK_APPROACH, RACK_RETREAT = "load: approach stock", "load: retreat from rack"
#: Speed [m/s] and acceleration [m/s^2] of the move over the located blank (a few mm); the lines
#: down to it and up from it run in the plan's time (:func:`line_speed`).
RACK_LINE_V, RACK_LINE_A = 0.1, 0.5
#: Largest turn of a blank in its slot the program takes from the camera [rad]: a box turned
#: further is not standing in a rack slot as a blank can.
RACK_MAX_YAW = math.radians(5.0)


def line_speed(distance: float, duration: float, a: float = RACK_LINE_A) -> tuple[float, float]:
    """(speed [m/s], acceleration [m/s^2]) of a rest-to-rest straight move of ``distance`` [m] whose
    trapezoid takes ``duration`` [s], the plan's time for it: at acceleration ``a``, or the higher
    one a triangle in that time needs."""
    if distance <= 0 or duration <= 0:
        return RACK_LINE_V, a
    if a * duration * duration < 4 * distance:  # too short to reach cruise at a: a triangle
        a = 4 * distance / (duration * duration)
        return a * duration / 2, a
    return (a * duration - math.sqrt(a * a * duration * duration - 4 * a * distance)) / 2, a


def tcp_of(cell: Cell, robot: Robot):
    """``q -> transform_base_link_to_tcp`` (4, 4) [m] of the cell's arm and gripper: what the
    controller's timer needs for a straight move after a joint move."""
    tcp = cell.gripper.tcp.matrix()
    return lambda q: robot.fk(np.asarray(q, dtype=float)) @ tcp


def correction_bounds(cell: Cell, size: np.ndarray) -> tuple[float, float, float]:
    """How far the rack camera's correction may move the grasp of a blank ``size`` (3,) [m]: x, y
    [m] as far as the blank can stand off its slot's centre (:func:`robotprog.rackpick.slot_room`,
    unturned) plus half the fingers' clearance (the camera's error), and :data:`RACK_MAX_YAW` [rad]."""
    room = slot_room(cell, size, 0.0)
    margin = cell.gripper.fingers.clearance / 2
    return room.dx + margin, room.dy + margin, RACK_MAX_YAW


@dataclass(frozen=True, eq=False)
class PostedProgram:
    """A posted robot program.

    Attributes
    ----------
    texts : dict of Path -> str
        File path -> text (KRL: the ``.src`` and its ``.dat``).
    steps : tuple of Step
    planned_s : float
        The plan's duration (motion and gripper settle) [s].
    predicted_s : float
        The controller's duration for the program, from the same start [s].
    targets : int
        Joint targets posted (servoj table rows, or blended waypoints), both branches counted.
    planned_reject_s, predicted_reject_s : float or None
        The same two durations for a rejected part (the program's verdict branch to the reject
        bin) [s]; ``None`` when the program does not branch (no ``part_ok`` input or no reject bin).
    """

    texts: dict[Path, str]
    steps: tuple[Step, ...]
    planned_s: float
    predicted_s: float
    targets: int
    planned_reject_s: float | None = None
    predicted_reject_s: float | None = None


def program_name(stem: str) -> str:
    """A program name from a file stem: letters, digits and underscores, not starting with a digit."""
    clean = "".join(c if c.isalnum() else "_" for c in stem) or "part"
    return ("p_" + clean) if clean[0].isdigit() else clean


def _samples(mv: TimedMove, dt: float, exact: bool) -> tuple[np.ndarray, float]:
    """Targets after the move's start, every ``dt`` [s] (``exact``: ``dt`` shrunk so the move is
    a whole number of segments), the last one the move's end; returns (targets, segment time)."""
    dur = mv.trajectory.duration
    n = max(1, math.ceil(dur / dt - 1e-9))
    step = dur / n if exact else dt
    t = np.minimum(np.arange(1, n + 1) * step, dur)
    q, _, _ = mv.trajectory.sample(t)
    return np.atleast_2d(q), step


#: The move after which the program reads the machine's verdict on the finished part (the
#: planned reject branch starts where it ends).
VERDICT_AFTER = "unload: retreat from vise"


def verdict_index(cell: Cell, plan: TendingPlan) -> int | None:
    """Index into ``plan.moves`` of the move after which the program branches on the verdict
    (``machine.io.inputs.part_ok``) to the out-tray or the planned reject branch; ``None`` when the
    cell wires no verdict or the plan has no reject branch."""
    if cell.machine is None or cell.machine.part_ok is None or not plan.reject:
        return None
    # the last such move: a part flipped between op 1 and op 2 leaves the vise twice, finished the second time
    return max((k for k, mv in enumerate(plan.moves) if mv.name == VERDICT_AFTER), default=None)


def posted_moves(cell: Cell, plan: TendingPlan) -> tuple[TimedMove, ...]:
    """The moves a program posts, in the order it writes them: the plan's, then the reject branch's
    when the program branches on the verdict."""
    return plan.moves + (plan.reject if verdict_index(cell, plan) is not None else ())


def reject_planned_s(cell: Cell, plan: TendingPlan) -> float | None:
    """The plan's duration [s] for a rejected part: its moves up to the verdict, then the reject
    branch; ``None`` when the program does not branch (:func:`verdict_index`)."""
    k = verdict_index(cell, plan)
    if k is None:
        return None
    return sum(mv.duration for mv in plan.moves[:k + 1]) + sum(mv.duration for mv in plan.reject)


def program_steps(cell: Cell, world: CollisionWorld, plan: TendingPlan, lang: str = "urscript",
                  segments: dict[int, float] | None = None, branch: bool = True) -> list[Step]:
    """The plan as program steps in ``lang``'s way of running the proven motion (module docstring).

    ``segments``: RAPID / KRL, longest segment [s] per move index (into :func:`posted_moves`) where
    it is not :data:`SEGMENT_S`. ``branch``: post the verdict's reject way where the cell wires it."""
    if lang not in LANGS:
        raise PlanningError(f"expected a program language of {', '.join(LANGS)}, got {lang!r}")
    robot = world.robot
    vmax = float(np.min(robot.v_max * cell.motion.speed_scaling))
    amax = float(np.min(np.asarray(cell.motion.acceleration_limits) * cell.motion.speed_scaling))
    # The plan starts at home; a program may start elsewhere, so it first goes there.
    steps: list[Step] = [MoveJ(tuple(float(v) for v in cell.robot.home), amax, vmax)]
    moves = plan.moves
    machine = cell.machine
    # the machine runs its cycle between load and unload (two setups: op 1 before the flip, op 2
    # after it), with the arm at home and the door shut
    phase = [mv.name.split(":")[0] for mv in moves]
    cycle_at = {k for k in range(1, len(moves)) if phase[k] in ("flip", "unload")
                and phase[k - 1] != phase[k]} if machine is not None else set()
    branch_at = verdict_index(cell, plan) if branch else None

    base_inv = np.linalg.inv(cell.robot.base.matrix())
    pose = tcp_of(cell, robot)  # the TCP pose (4, 4) at q [rad] in the robot's base frame [m]

    def line(mv: TimedMove) -> tuple[float, float]:
        """A straight move's TCP travel [m] and the plan's time for it [s]."""
        return float(np.linalg.norm(pose(mv.q_end)[:3, 3] - pose(mv.waypoints[0])[:3, 3])), mv.duration

    def move_steps(k: int, mv: TimedMove, stops: bool) -> list[Step]:
        out: list[Step] = [Comment(mv.name)]
        if mv.name == RACK_APPROACH:  # over the blank as the camera found it, then down to it
            size = np.asarray(plan.stock.size, dtype=float)
            return out + [ReadCorrection.at(base_inv @ cell.rack.slot_transform(0, 0), correction_bounds(cell, size),
                                            "the rack camera's correction of the blank in its slot",
                                            (cell.rack.rows, cell.rack.columns), cell.rack.pitch),
                          MoveL.to(pose(mv.waypoints[0]), RACK_LINE_A, RACK_LINE_V, corrected=True),
                          MoveL.to(pose(mv.q_end), *line_speed(*line(mv))[::-1], corrected=True, q_end=mv.q_end)]
        if mv.name == RACK_RETREAT:  # straight up, then to where the planned retreat ends
            return out + [MoveL.to(pose(mv.q_end), *line_speed(*line(mv))[::-1], corrected=True, q_end=mv.q_end),
                          MoveJ(tuple(float(v) for v in mv.q_end), amax, vmax)]
        if mv.kind == "gripper":
            out.append(SetOutputs(mv.outputs, mv.settle_s))
            return out
        if mv.trajectory.duration <= 0:
            return out
        if lang == "urscript":
            q, _ = _samples(mv, SERVO_PERIOD_S, exact=False)
            if stops:  # the arm must stand before the gripper switches: let the servo catch up
                q = np.vstack([q, np.repeat(q[-1:], math.ceil(SERVO_LOOKAHEAD_S / SERVO_PERIOD_S - 1e-9), 0)])
            out.append(ServoJ(q, SERVO_PERIOD_S, SERVO_LOOKAHEAD_S, SERVO_GAIN))
        else:
            q, seg = _samples(mv, (segments or {}).get(k, SEGMENT_S), exact=True)
            for j, row in enumerate(q):
                last = j + 1 == len(q)
                out.append(MoveJ(tuple(float(v) for v in row), amax, vmax, 0.0 if last else ZONE_M, seg))
        return out

    if machine is not None:
        steps += to_steps(machine_ready(), machine)
    then: list[Step] = []
    reject: list[Step] = []
    body = steps
    for k, mv in enumerate(moves):
        if k in cycle_at and machine is not None:
            body += to_steps(machine_cycle(), machine)
        stops = (k + 1 == len(moves) or moves[k + 1].kind == "gripper" or k + 1 in cycle_at
                 or moves[k + 1].name == RACK_APPROACH)  # the straight moves start from a standing arm
        body += move_steps(k, mv, stops)
        if k == branch_at:
            # The machine's verdict picks the way on: the rest of the unload to the out-tray, or the
            # planned reject branch to the bin; both end at home.
            for j, rv in enumerate(plan.reject):
                last = j + 1 == len(plan.reject) or plan.reject[j + 1].kind == "gripper"
                reject += move_steps(len(moves) + j, rv, last)
            body = then
    if branch_at is not None and machine is not None:
        op = verdict()
        steps.append(Branch(number(machine, op.signal), op.level, tuple(then), tuple(reject), op.label))
    return steps


def check_posted_path(world: CollisionWorld, plan: TendingPlan, steps: list[Step],
                      joint_resolution: float = PlannerOptions().joint_resolution) -> None:
    """Collision-check the path the controller drives for ``steps`` (module docstring).

    Raises
    ------
    PlanningError
        A posted segment or blended corner collides, naming the move and the contact.
    """
    hit = posted_collision(world, plan, steps, joint_resolution)
    if hit is not None:
        k, contact = hit
        raise PlanningError(f"{(plan.moves + plan.reject)[k].name}: the posted path collides ({contact})")


def posted_collision(world: CollisionWorld, plan: TendingPlan, steps: list[Step],
                     joint_resolution: float = PlannerOptions().joint_resolution,
                     sweep: SweptMotion | None = None, planned_world: bool = False) -> tuple[int, str] | None:
    """The first move (index into ``plan.moves``, then ``plan.reject`` where the steps branch on the
    verdict) whose posted path collides, and the contact. ``sweep``: ``world``'s continuous checker
    at ``joint_resolution``, when the caller checks several posts of one plan (made here if not).
    ``planned_world``: ``world`` is the one the plan was proven in (the cell, door open, with
    ``plan.obstacles``), so a servo stream within the room proven around its move
    (:func:`_servo_in_tube`) needs no proof of its own."""
    per_move: list[list[Step]] = []
    for st in flat_steps(steps):
        if isinstance(st, Comment):
            per_move.append([])
        elif per_move:
            per_move[-1].append(st)
    moves = plan.moves + plan.reject if any(isinstance(st, Branch) for st in steps) else plan.moves
    sweep = swept_motion(world, joint_resolution) if sweep is None else sweep
    for k, (mv, posted) in enumerate(zip(moves, per_move, strict=True)):
        if mv.kind == "gripper":
            continue
        pts = [mv.waypoints[0]]
        blended: list[bool] = [False]
        lines = False
        for st in posted:
            if isinstance(st, MoveL) and not lines:  # the plan's straight line: the correction zero
                lines = True
                pts += list(mv.waypoints[1:])
                blended += [False] * (len(mv.waypoints) - 1)
            elif isinstance(st, ServoJ):
                pts += list(np.asarray(st.targets, dtype=float))
                blended += [False] * len(st.targets)
            elif isinstance(st, MoveJ):
                pts.append(np.asarray(st.q, dtype=float))
                blended.append(st.r > 0)
        if planned_world and _servo_in_tube(mv, posted):
            continue
        qs = np.array(pts)
        hit = sweep.polyline_contact(qs, mv.held)
        if hit is not None:
            return k, hit[1]
        for i in range(1, len(qs) - 1):
            if blended[i]:  # the blend stays between the two segments' midpoints and the corner
                contact = sweep.corner_contact(0.5 * (qs[i - 1] + qs[i]), qs[i], 0.5 * (qs[i] + qs[i + 1]), mv.held)
                if contact is not None:
                    return k, contact
    return None


def _servo_in_tube(mv: TimedMove, posted: list[Step]) -> bool:
    """Whether ``posted``, the steps of ``mv``, are one servo stream of its timed path, sampled every
    period from its start (then its last target repeated), within the room the planner proved
    around that path (:attr:`TimedMove.tube`): each of its segments strays from the path between its
    two samples by at most the chord deviation (:meth:`robotprog.timing.Trajectory.chord_deviation`),
    so the polyline from the move's start through the targets is proven free without a query."""
    if mv.tube is None or len(posted) != 1 or not isinstance(posted[0], ServoJ):
        return False
    st = posted[0]
    q, _ = _samples(mv, st.t, exact=False)
    targets = np.asarray(st.targets, dtype=float)
    if len(targets) < len(q) or not np.array_equal(targets[:len(q)], q) or not (targets[len(q):] == q[-1]).all():
        return False
    start, _, _ = mv.trajectory.sample(0.0)
    return bool(np.array_equal(start, mv.waypoints[0])
                and (mv.trajectory.chord_deviation(st.t) <= mv.tube).all())


def check_language(lang: str, robot: Robot) -> None:
    """Refuse a program language for another maker's arm: the joint values are the model's, and
    only the maker's own controller reads them as its axes (URScript for a Universal Robots arm,
    RAPID for an ABB one, KRL for a KUKA one).

    Raises
    ------
    PlanningError
        ``lang`` is another maker's (source ``robot.model``).
    """
    maker = LANG_MAKER.get(lang)
    if maker is not None and robot.maker != maker:
        raise PlanningError(f"{LANG_NAME[lang]} needs {'an' if maker == 'ABB' else 'a'} {maker} arm, "
                            f"the cell has {robot.name}", source="robot.model")


def post_program(lang: str, program: Path, cell: Cell, world: CollisionWorld, plan: TendingPlan) -> PostedProgram:
    """The robot program in ``lang`` (``urscript``, ``rapid``, ``krl``) for ``plan``, its path
    collision-checked and its controller time measured.

    Raises
    ------
    PlanningError
        A language for another maker's arm (URScript needs a Universal Robots arm, RAPID an
        ABB one, KRL a KUKA one), or a posted path that collides.
    """
    robot = world.robot
    check_language(lang, robot)
    name = program_name(program.name.split(".")[0])
    # the world the plan was proven in: the cell plus the blanks and parts beside the slots used
    proven = collision_world(cell, robot, obstacles=plan.obstacles) if plan.obstacles else world
    # A move whose waypoints cut too close to an obstacle (an RRT transfer skirting the door frame)
    # is posted again with segments half as long, whose polyline and corners hug the proven
    # trajectory closer, down to MIN_SEGMENT_S; then the collision is the error.
    segments: dict[int, float] = {}
    branch = True
    sweep = swept_motion(proven, PlannerOptions().joint_resolution)  # one checker for every try
    # the plan's moves were proven in the cell, door open, with its obstacles: their proven room holds here
    planned = not proven.door_closed and proven.obstacles == plan.obstacles
    while True:
        steps = program_steps(cell, world, plan, lang, segments, branch)
        hit = posted_collision(proven, plan, steps, sweep=sweep, planned_world=planned)
        if hit is None:
            break
        k, contact = hit
        seg = segments.get(k, SEGMENT_S) / 2
        if lang == "urscript" or seg < MIN_SEGMENT_S:
            if k >= len(plan.moves):
                # The reject way's posted path grazes (its servoj polyline, or its finest segments): post
                # the program without the branch, every part to the out-tray, rather than refuse the part.
                log.warning("%s: the posted path collides (%s); the program does not branch on the verdict",
                            plan.reject[k - len(plan.moves)].name, contact)
                branch = False
                continue
            raise PlanningError(f"{(plan.moves + plan.reject)[k].name}: the posted path collides ({contact})")
        segments[k] = seg
    home = np.asarray(cell.robot.home, dtype=float)
    tcp_at = tcp_of(cell, robot)
    predicted = program_duration(steps, home, lang=lang, axis_speed=robot.v_max, tcp_of=tcp_at)
    planned_reject = reject_planned_s(cell, plan) if branch else None
    predicted_reject = (None if planned_reject is None else
                        program_duration(steps, home, lang=lang, axis_speed=robot.v_max, verdict=False, tcp_of=tcp_at))
    targets = sum(len(s.targets) if isinstance(s, ServoJ) else 1 for s in flat_steps(steps)[1:]
                  if isinstance(s, ServoJ | MoveJ))
    how = {"urscript": f"servoj stream at {1 / SERVO_PERIOD_S:.0f} Hz",
           "rapid": f"blended MoveAbsJ\\T, {SEGMENT_S:g} s segments",
           "krl": f"blended PTP C_PTP, {SEGMENT_S:g} s segments"}[lang]
    header = (f"factory robot: {cell.name}, {robot.name}",
              f"planned motion {plan.duration:.2f} s, controller {predicted:.2f} s ({how}, {targets} targets)")
    if planned_reject is not None and predicted_reject is not None:
        header += (f"reject branch: planned motion {planned_reject:.2f} s, controller {predicted_reject:.2f} s",)
    tcp = cell.gripper.tcp.matrix()
    texts: dict[Path, Any]
    if lang == "urscript":
        texts = {program: urscript_program(steps, name=name, transform_flange_to_tcp=tcp, header=header)}
    elif lang == "rapid":
        texts = {program: rapid_module(steps, name=name[:32], transform_flange_to_tcp=tcp, header=header)}
    else:
        src, dat = krl_program(steps, name=name[:24], transform_flange_to_tcp=tcp,
                               axis_percent=100.0 * cell.motion.speed_scaling, axis_speed=robot.v_max,
                               header=header)
        texts = {program: src, program.with_suffix(".dat"): dat}
    return PostedProgram(texts, tuple(steps), plan.duration, predicted, targets, planned_reject, predicted_reject)
