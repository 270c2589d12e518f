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

Proof of the posted path: the controller drives the polyline through the posted targets,
cutting each blended corner no further than the chord between the two segments' midpoints
(RAPID and KRL shrink a zone to at most half of its segments). :func:`check_posted_path`
collision-checks that polyline and every corner chord at the planner's joint resolution,
with what the gripper holds in that move; a move whose posted path collides is posted again with
segments half as long (down to :data:`MIN_SEGMENT_S`), hugging the proven trajectory closer. Each segment's speed is its joint travel over the
sample time of a trajectory proven within the limits, so it is within them too.

With ``cell.machine`` the program also drives the machine tool through its digital I/O:
wait until it is idle, open the door, load; close the door, start the cycle, wait for it
to run and to finish, open the door; unload (:func:`machine_cycle`). The waits on inputs
are the machine's time and count nothing in the controller time.

Each program's header states the planned motion time and the controller's, timed by
:func:`robotprog.controller.program_duration` from the program's own steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from factory.errors import PlanningError
from robotprog.cell import Cell, MachineIO
from robotprog.collision import CollisionWorld, collision_world
from robotprog.controller import LANGS, program_duration
from robotprog.krl import krl_program
from robotprog.rapid import rapid_module
from robotprog.tending import TendingOptions, TendingPlan, TimedMove
from robotprog.urscript import Comment, MoveJ, ServoJ, SetOutputs, Step, WaitInput, urscript_program

#: servoj period [s]: the CB3 controller's cycle (125 Hz).
SERVO_PERIOD_S = 0.008
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
        Joint targets posted (servoj table rows, or blended waypoints).
    """

    texts: dict[Path, str]
    steps: tuple[Step, ...]
    planned_s: float
    predicted_s: float
    targets: int


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


def program_steps(cell: Cell, world: CollisionWorld, plan: TendingPlan, lang: str = "urscript",
                  segments: dict[int, float] | None = None) -> list[Step]:
    """The plan as program steps in ``lang``'s way of running the proven motion (module docstring).

    ``segments``: RAPID / KRL, longest segment [s] per move index where it is not :data:`SEGMENT_S`."""
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
    if machine is not None:
        steps += machine_ready(machine)
    for k, mv in enumerate(moves):
        if k in cycle_at and machine is not None:
            steps += machine_cycle(machine)
        steps.append(Comment(mv.name))
        if mv.kind == "gripper":
            steps.append(SetOutputs(mv.outputs, mv.settle_s))
            continue
        if mv.trajectory.duration <= 0:
            continue
        if lang == "urscript":
            q, _ = _samples(mv, SERVO_PERIOD_S, exact=False)
            stops = k + 1 == len(moves) or moves[k + 1].kind == "gripper" or k + 1 in cycle_at
            if stops:  # the arm must stand before the gripper switches: let the servo catch up
                q = np.vstack([q, np.repeat(q[-1:], math.ceil(SERVO_LOOKAHEAD_S / SERVO_PERIOD_S - 1e-9), 0)])
            steps.append(ServoJ(q, SERVO_PERIOD_S, SERVO_LOOKAHEAD_S, SERVO_GAIN))
        else:
            q, seg = _samples(mv, (segments or {}).get(k, SEGMENT_S), exact=True)
            for j, row in enumerate(q):
                last = j + 1 == len(q)
                steps.append(MoveJ(tuple(float(v) for v in row), amax, vmax, 0.0 if last else ZONE_M, seg))
    return steps


def machine_ready(io: MachineIO) -> list[Step]:
    """Wait for the machine to be idle, then open its door and wait until it is open."""
    return [WaitInput(io.cycle_done, True, "machine: wait until idle"), *_door(io, True)]


def machine_cycle(io: MachineIO) -> list[Step]:
    """Close the door, start the cycle (raised until the machine runs), wait for it to finish,
    open the door: the handshake waits on the machine's inputs, never on a guessed time."""
    return [*_door(io, False),
            SetOutputs(((io.cycle_start, True),), 0.0, "machine: start the cycle"),
            WaitInput(io.cycle_done, False, "machine: wait until it runs"),
            SetOutputs(((io.cycle_start, False),), 0.0),
            WaitInput(io.cycle_done, True, "machine: wait for the cycle done"),
            *_door(io, True)]


def _door(io: MachineIO, open_: bool) -> list[Step]:
    if open_:
        return [SetOutputs(((io.close_door, False), (io.open_door, True)), 0.0, "machine: open the door"),
                WaitInput(io.door_open, True, "machine: wait for the door open")]
    return [SetOutputs(((io.open_door, False), (io.close_door, True)), 0.0, "machine: close the door"),
            WaitInput(io.door_open, False, "machine: wait for the door closed")]


def check_posted_path(world: CollisionWorld, plan: TendingPlan, steps: list[Step],
                      joint_resolution: float = TendingOptions().joint_resolution) -> None:
    """Collision-check the path the controller drives for ``steps`` (module docstring).

    Raises
    ------
    PlanningError
        A posted segment or blended corner collides, naming the move and the contact.
    """
    hit = posted_collision(world, plan, steps, joint_resolution)
    if hit is not None:
        k, contact = hit
        raise PlanningError(f"{plan.moves[k].name}: the posted path collides ({contact})")


def posted_collision(world: CollisionWorld, plan: TendingPlan, steps: list[Step],
                     joint_resolution: float = TendingOptions().joint_resolution) -> tuple[int, str] | None:
    """The first move (index into ``plan.moves``) whose posted path collides, and the contact."""
    per_move: list[list[Step]] = []
    for st in steps:
        if isinstance(st, Comment):
            per_move.append([])
        elif per_move:
            per_move[-1].append(st)
    for k, (mv, posted) in enumerate(zip(plan.moves, per_move, strict=True)):
        if mv.kind == "gripper":
            continue
        pts = [mv.waypoints[0]]
        blended: list[bool] = [False]
        for st in posted:
            if isinstance(st, ServoJ):
                pts += list(np.asarray(st.targets, dtype=float))
                blended += [False] * len(st.targets)
            elif isinstance(st, MoveJ):
                pts.append(np.asarray(st.q, dtype=float))
                blended.append(st.r > 0)
        qs = np.array(pts)
        paths = [qs]
        corners = [i for i in range(1, len(qs) - 1) if blended[i]]
        if corners:
            c = np.array(corners)
            a = 0.5 * (qs[c - 1] + qs[c])
            b = 0.5 * (qs[c] + qs[c + 1])
            paths += [np.array([x, y]) for x, y in zip(a, b)]
        for path in paths:
            dense = _densify(path, joint_resolution)
            bad = world.path_free(dense, mv.held)
            if bad is not None:
                return k, str(world.first_contact(dense[bad], mv.held))
    return None


def _densify(qs: np.ndarray, resolution: float) -> np.ndarray:
    out = [qs[:1]]
    for a, b in zip(qs[:-1], qs[1:]):
        n = max(1, math.ceil(float(np.abs(b - a).max()) / resolution))
        out.append(a + np.linspace(0.0, 1.0, n + 1)[1:, None] * (b - a))
    return np.concatenate(out)


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
    # The joint values are the model's: only the maker's own controller reads them as its axes.
    maker = LANG_MAKER[lang] if lang in LANG_MAKER else None
    if maker is not None and robot.maker != maker:
        raise PlanningError(f"{LANG_NAME[lang]} needs {'an' if maker == 'ABB' else 'a'} {maker} arm, "
                            f"the cell has {robot.name}", source="robot.model")
    name = program_name(program.name.split(".")[0])
    # the world the plan was proven in: the cell plus the blanks and parts beside the slots used
    proven = collision_world(cell, robot, obstacles=plan.obstacles) if plan.obstacles else world
    # A move whose waypoints cut too close to an obstacle (an RRT transfer skirting the door frame)
    # is posted again with segments half as long, whose polyline and corners hug the proven
    # trajectory closer, down to MIN_SEGMENT_S; then the collision is the error.
    segments: dict[int, float] = {}
    while True:
        steps = program_steps(cell, world, plan, lang, segments)
        hit = posted_collision(proven, plan, steps)
        if hit is None:
            break
        k, contact = hit
        seg = segments.get(k, SEGMENT_S) / 2
        if lang == "urscript" or seg < MIN_SEGMENT_S:
            raise PlanningError(f"{plan.moves[k].name}: the posted path collides ({contact})")
        segments[k] = seg
    home = np.asarray(cell.robot.home, dtype=float)
    predicted = program_duration(steps, home, lang=lang, axis_speed=robot.v_max)
    targets = sum(len(s.targets) if isinstance(s, ServoJ) else 1 for s in steps[1:]
                  if isinstance(s, ServoJ | MoveJ))
    how = {"urscript": f"servoj stream at {1 / SERVO_PERIOD_S:.0f} Hz",
           "rapid": f"blended MoveAbsJ\\T, {SEGMENT_S:g} s segments",
           "krl": f"blended PTP C_PTP, {SEGMENT_S:g} s segments"}[lang]
    header = (f"factory robot: {cell.name}, {robot.name}",
              f"planned motion {plan.duration:.2f} s, controller {predicted:.2f} s ({how}, {targets} targets)")
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
    return PostedProgram(texts, tuple(steps), plan.duration, predicted, targets)
