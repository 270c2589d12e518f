"""URScript programs for Universal Robots controllers (CB3 / e-Series).

A program is a list of steps: joint moves (``movej``), straight-line tool moves
(``movel``), gripper actions (``set_standard_digital_out`` then a settle ``sleep``), waits
and comments. The text is deterministic: the same steps give byte-identical output
(fixed decimals, no time stamps), so programs can be diffed and golden-tested.

Frames and units: URScript speaks metres, radians and seconds. ``movel`` poses are
``p[x, y, z, rx, ry, rz]`` with the orientation as a rotation vector (axis times angle),
the TCP's pose in the *controller's* base frame. That frame is the URDF frame ``base``,
turned by pi about Z from ROS's ``base_link``; :class:`MoveL` takes the ROS pose
(``transform_base_link_to_tcp``) and this module converts it, the only place that does.
``set_tcp`` is given ``transform_flange_to_tcp`` (the controller's flange is ``tool0``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from factory.core.errors import PlanningError
from robotprog.ik import TRANSFORM_BASE_LINK_TO_UR_BASE

#: Decimals for lengths [m] (1 µm), angles [rad] (1 µrad) and rotation vectors.
DECIMALS = 6
#: Standard digital inputs and outputs of a UR controller (numbers 0..7).
UR_DIGITAL_IO = 8
#: RTDE input float registers (``input_double_register_<n>``) the cell's controller writes the rack
#: camera's correction to before each pick: x [m], y [m], yaw [rad] in the slot's frame. Registers
#: 0..23 are the general-purpose ones (24..47 belong to the fieldbus adapters).
RACK_REGISTERS = (0, 1, 2)
#: RTDE input integer registers (``input_int_register_<n>``) it writes the rack slot the blank stands
#: in to: its row and its column (from 0).
RACK_SLOT_REGISTERS = (0, 1)


@dataclass(frozen=True)
class MoveJ:
    """Joint move: ``q`` (6,) target [rad], ``a`` joint acceleration [rad/s^2], ``v`` speed [rad/s],
    ``r`` blend radius [m] (0 = stop at the target), ``t`` move time [s] (0 = as fast as ``a`` and
    ``v`` allow; > 0: the controller stretches the move to take ``t``, URScript's ``t``, RAPID's
    ``\\T``)."""

    q: tuple[float, ...]
    a: float
    v: float
    r: float = 0.0
    t: float = 0.0


@dataclass(frozen=True, eq=False)
class ServoJ:
    """A streamed joint trajectory: ``targets`` (n, 6) [rad], one every ``t`` [s], each sent with
    ``servoj(q, 0, 0, t, lookahead_time, gain)``: the controller reaches target ``k`` at ``(k + 1) t``
    after the first is sent (URScript posts it as a table and a loop). ``lookahead_time`` [s]
    smooths the stream (0.03..0.2 s), ``gain`` is the controller's proportional gain (100..2000)."""

    targets: np.ndarray
    t: float
    lookahead_time: float = 0.03
    gain: float = 300.0


@dataclass(frozen=True)
class MoveL:
    """Straight tool move to ``pose`` = ``transform_base_link_to_tcp`` (4, 4) [m], tool
    acceleration ``a`` [m/s^2], speed ``v`` [m/s], blend radius ``r`` [m]. ``corrected``: the pose
    is where the plan put it, and the program moves it by the correction the last
    :class:`ReadCorrection` read (the blank as the rack camera found it). ``q_end``: the joint
    position [rad] the plan reaches the pose at (empty: unknown), for a timer of a joint move after it."""

    pose: tuple[tuple[float, ...], ...]
    a: float
    v: float
    r: float = 0.0
    corrected: bool = False
    q_end: tuple[float, ...] = ()

    @staticmethod
    def to(pose: np.ndarray, a: float, v: float, r: float = 0.0, corrected: bool = False,
           q_end: np.ndarray | None = None) -> "MoveL":
        """A MoveL from a (4, 4) array."""
        return MoveL(tuple(tuple(float(x) for x in row) for row in np.asarray(pose, dtype=float)), a, v, r,
                     corrected, () if q_end is None else tuple(float(v) for v in q_end))


@dataclass(frozen=True)
class ReadCorrection:
    """Read the rack camera's correction from the cell's controller at run time: the blank's offset
    in its slot, ``x``, ``y`` [m] along the slot's axes and ``yaw`` [rad] about its z (URScript: the
    RTDE input registers :data:`RACK_REGISTERS`; RAPID: the ``PERS wobjdata`` whose object frame it
    is; KRL: the global ``FRAME`` ``RACK_CORR``), and stop the program on one beyond ``bounds``
    (x [m], y [m], yaw [rad]). ``slot`` is ``transform_base_link_to_slot`` (4, 4) [m] of the slot
    the plan picks from; the corrected :class:`MoveL` steps after it go to
    ``slot @ offset @ inv(slot) @ pose``.

    A rack of more than one slot (``grid``: rows, columns at ``pitch`` [m] along the slot's x and y)
    also reads the slot the blank stands in, its row and column (URScript: the RTDE integer
    registers :data:`RACK_SLOT_REGISTERS`; RAPID: ``PERS num`` ``nRackRow``, ``nRackColumn``; KRL:
    global ``INT`` ``RACK_ROW``, ``RACK_COLUMN``), stops on one outside the grid, and the corrected
    steps go to ``there @ offset @ inv(slot) @ pose``, ``there = slot @ (column * pitch[0],
    row * pitch[1], 0)``: the plan's pick moved to that slot."""

    slot: tuple[tuple[float, ...], ...]
    bounds: tuple[float, float, float]
    label: str = ""
    grid: tuple[int, int] = (1, 1)
    pitch: tuple[float, float] = (0.0, 0.0)

    @staticmethod
    def at(slot: np.ndarray, bounds: tuple[float, float, float], label: str = "", grid: tuple[int, int] = (1, 1),
           pitch: tuple[float, float] = (0.0, 0.0)) -> "ReadCorrection":
        """A ReadCorrection from a (4, 4) array."""
        return ReadCorrection(tuple(tuple(float(x) for x in row) for row in np.asarray(slot, dtype=float)),
                              tuple(float(b) for b in bounds), label, (int(grid[0]), int(grid[1])),
                              (float(pitch[0]), float(pitch[1])))

    @property
    def slots(self) -> bool:
        """Whether the program reads the slot too (a rack of more than one slot)."""
        return self.grid != (1, 1)

    def there(self, row: int, column: int) -> np.ndarray:
        """``transform_base_link_to_slot`` (4, 4) [m] of slot (``row``, ``column``)."""
        step = np.eye(4)
        step[:2, 3] = column * self.pitch[0], row * self.pitch[1]
        return np.asarray(self.slot, dtype=float) @ step


@dataclass(frozen=True)
class SetOutputs:
    """Switch digital outputs (the gripper's grip or release): ``outputs`` (number, level)
    pairs, then wait ``settle_s`` [s] for the fingers to move. ``label`` becomes a comment."""

    outputs: tuple[tuple[int, bool], ...]
    settle_s: float = 0.0
    label: str = ""


@dataclass(frozen=True)
class WaitInput:
    """Wait until digital input ``input`` reads ``level`` (the machine's door, its cycle);
    ``label`` becomes a comment. How long is the machine's business, not the robot's."""

    input: int
    level: bool
    label: str = ""


@dataclass(frozen=True)
class Wait:
    """Pause ``seconds`` [s]."""

    seconds: float


@dataclass(frozen=True)
class Comment:
    """A ``#`` comment line in the program (one line of text)."""

    text: str


@dataclass(frozen=True)
class Branch:
    """Read digital input ``input`` once: run ``then`` if it reads ``level``, else ``otherwise``
    (URScript ``if``, RAPID ``IF DInput``, KRL ``IF $IN``); ``label`` becomes a comment. The
    machine's verdict on a part picks the out-tray or the reject bin."""

    input: int
    level: bool
    then: tuple["Step", ...]
    otherwise: tuple["Step", ...]
    label: str = ""


Step = MoveJ | MoveL | ServoJ | SetOutputs | WaitInput | Wait | Comment | Branch | ReadCorrection


def flat_steps(steps: Sequence[Step]) -> list[Step]:
    """``steps`` with every :class:`Branch` replaced by its ``then`` steps and then its ``otherwise``
    steps (depth first): every step a program contains, in the order it is written."""
    out: list[Step] = []
    for st in steps:
        if isinstance(st, Branch):
            out += flat_steps(st.then) + flat_steps(st.otherwise)
        else:
            out.append(st)
    return out


@dataclass(frozen=True)
class FlowWords:
    """How one robot language writes the steps that are not motion: outputs, input waits, pauses,
    comments and the verdict's branch. Each gives its line(s) at the program body's indent."""

    comment: Callable[[str], str]
    set_output: Callable[[int, bool], str]
    sleep: Callable[[float], str]
    wait_input: Callable[[int, bool], list[str]]
    if_input: Callable[[int, bool], str]
    else_line: str
    end_if: str


def flow_lines(i: int, st: Step, words: FlowWords,
               way: Callable[[Sequence[Step], int], list[str]]) -> list[str] | None:
    """The lines of step ``i`` when it is an output, input wait, pause, comment or branch; None
    for a motion step. ``way(steps, first)`` writes one way of a branch (its steps numbered from
    ``first``), at the body's indent: its lines go one level in. A step's label is a comment above it."""
    label = [words.comment(st.label)] if isinstance(st, (SetOutputs, WaitInput, Branch)) and st.label else []
    if isinstance(st, SetOutputs):
        settle = [words.sleep(st.settle_s)] if st.settle_s > 0 else []
        return label + [words.set_output(n, level) for n, level in st.outputs] + settle
    if isinstance(st, WaitInput):
        return label + words.wait_input(st.input, st.level)
    if isinstance(st, Branch):
        then = way(st.then, i + 1)
        otherwise = way(st.otherwise, i + 1 + len(st.then))
        return [*label, words.if_input(st.input, st.level), *("  " + line for line in then), words.else_line,
                *("  " + line for line in otherwise), words.end_if]
    if isinstance(st, Wait):
        return [words.sleep(st.seconds)]
    if isinstance(st, Comment):
        return [words.comment(st.text)]
    return None


def check_io_step(i: int, st: Step, inputs: int | None = None, outputs: int | None = None) -> None:
    """The checks every language makes on an I/O or wait step (outputs, inputs, waits, branches),
    so URScript, RAPID and KRL refuse the same malformed steps with the same words.

    Parameters
    ----------
    i : int
        The step's index, for the message.
    st : Step
        Steps other than :class:`SetOutputs`, :class:`WaitInput`, :class:`Wait` and
        :class:`Branch` pass unchecked.
    inputs, outputs : int, optional
        How many digital inputs / outputs the controller has (numbers ``0..n - 1``);
        ``None``: any number >= 0.

    Raises
    ------
    PlanningError
        A negative (or too large) signal number, a non-finite or negative settle time, a wait
        that is not finite and > 0.
    """
    def signal(n: int, kind: str, count: int | None) -> None:
        if n < 0 or (count is not None and n >= count):
            span = "negative" if n < 0 else f"not in 0..{count - 1}"
            raise PlanningError(f"step {i}: digital {kind} {n} is {span}")

    if isinstance(st, SetOutputs):
        for n, _ in st.outputs:
            signal(n, "output", outputs)
        if not (math.isfinite(st.settle_s) and st.settle_s >= 0):
            raise PlanningError(f"step {i}: settle time must be finite and >= 0, got {st.settle_s}")
    elif isinstance(st, WaitInput | Branch):
        signal(st.input, "input", inputs)
    elif isinstance(st, Wait):
        if not (math.isfinite(st.seconds) and st.seconds > 0):
            raise PlanningError(f"step {i}: wait must be finite and > 0, got {st.seconds}")


def comment_text(text: str) -> str:
    """One line of comment text: the first line, without trailing blanks (controllers' checkers
    flag trailing spaces; a line break would end the comment)."""
    return text.splitlines()[0].rstrip() if text.strip() else ""


def _num(x: float) -> str:
    s = f"{round(float(x), DECIMALS):.{DECIMALS}f}"
    s = s.rstrip("0")
    if s.endswith("."):
        s += "0"
    return "0.0" if s in ("-0.0", "0.0") else s


def _positive(x: float, what: str) -> None:
    if not (math.isfinite(x) and x > 0):
        raise PlanningError(f"URScript {what} must be finite and > 0, got {x}")


def ur_pose(transform: np.ndarray) -> str:
    """``p[x, y, z, rx, ry, rz]`` of a (4, 4) transform [m] (rotation vector [rad])."""
    t = np.asarray(transform, dtype=float)
    if t.shape != (4, 4) or not np.isfinite(t).all():
        raise PlanningError(f"pose must be a finite 4x4 transform, got shape {t.shape}")
    rv = Rotation.from_matrix(t[:3, :3]).as_rotvec()
    return "p[" + ", ".join(_num(v) for v in (*t[:3, 3], *rv)) + "]"


def _ur_bool(level: bool) -> str:
    return "True" if level else "False"


_UR_WORDS = FlowWords(
    comment=lambda text: f"  # {comment_text(text)}".rstrip(),
    set_output=lambda n, level: f"  set_standard_digital_out({n}, {_ur_bool(level)})",
    sleep=lambda s: f"  sleep({_num(s)})",
    wait_input=lambda n, level: [f"  while get_standard_digital_in({n}) != {_ur_bool(level)}:", "    sync()", "  end"],
    if_input=lambda n, level: f"  if get_standard_digital_in({n}) == {_ur_bool(level)}:",
    else_line="  else:",
    end_if="  end",
)


def way_lines(emit: Callable[[Sequence[Step], list[str], int], None], seq: Sequence[Step], first: int) -> list[str]:
    """The lines ``emit`` writes for ``seq`` (one way of a branch), numbered from ``first``."""
    lines: list[str] = []
    emit(seq, lines, first)
    return lines


def urscript_program(
    steps: Sequence[Step],
    *,
    name: str = "factory_program",
    transform_flange_to_tcp: np.ndarray | None = None,
    header: Sequence[str] = (),
) -> str:
    """The URScript text of a program.

    Parameters
    ----------
    steps : sequence of MoveJ, MoveL, SetOutputs, Wait, Comment
    name : str
        Program (function) name: letters, digits, underscores.
    transform_flange_to_tcp : (4, 4) float, optional
        The gripper's TCP, emitted as ``set_tcp`` first; ``MoveL`` poses are TCP poses.
    header : sequence of str
        Comment lines at the top (no time stamps, to keep the text deterministic).

    Returns
    -------
    str
        ``def name(): ... end`` with a trailing newline.

    Raises
    ------
    PlanningError
        A malformed step (wrong joint count, non-finite or non-positive a/v, bad name).
    """
    if not name.replace("_", "a").isalnum() or name[0].isdigit():
        raise PlanningError(f"URScript program name must be letters, digits and underscores, got {name!r}")
    lines = [f"def {name}():"]
    lines += [f"  # {comment_text(h)}".rstrip() for h in header]
    if transform_flange_to_tcp is not None:
        lines.append(f"  set_tcp({ur_pose(transform_flange_to_tcp)})")
    to_ur = np.linalg.inv(TRANSFORM_BASE_LINK_TO_UR_BASE)
    n_tables = 0
    read = False

    def emit(seq: Sequence[Step], out: list[str], first: int) -> None:
        nonlocal n_tables, read
        for i, st in enumerate(seq, first):
            check_io_step(i, st, inputs=UR_DIGITAL_IO, outputs=UR_DIGITAL_IO)
            if isinstance(st, MoveJ):
                q = np.asarray(st.q, dtype=float)
                if q.shape != (6,) or not np.isfinite(q).all():
                    raise PlanningError(f"step {i}: movej needs 6 finite joint angles, got {st.q}")
                _positive(st.a, f"step {i} movej a")
                _positive(st.v, f"step {i} movej v")
                joints = "[" + ", ".join(_num(v) for v in q) + "]"
                timed = f", t={_num(st.t)}" if st.t > 0 else ""
                blend = f", r={_num(st.r)}" if st.r > 0 else ""
                out.append(f"  movej({joints}, a={_num(st.a)}, v={_num(st.v)}{timed}{blend})")
            elif isinstance(st, ServoJ):
                n_tables = _servoj_lines(st, i, n_tables, out)
            elif isinstance(st, MoveL):
                _positive(st.a, f"step {i} movel a")
                _positive(st.v, f"step {i} movel v")
                blend = f", r={_num(st.r)}" if st.r > 0 else ""
                pose = ur_pose(to_ur @ np.asarray(st.pose, dtype=float))
                if st.corrected:
                    if not read:
                        raise PlanningError(f"step {i}: a corrected movel before the correction is read")
                    pose = f"pose_trans(rack_corr, {pose})"
                out.append(f"  movel({pose}, a={_num(st.a)}, v={_num(st.v)}{blend})")
            elif isinstance(st, ReadCorrection):
                read = True
                out += _correction_lines(st, to_ur)
            else:
                lines_of = flow_lines(i, st, _UR_WORDS, lambda seq, first: way_lines(emit, seq, first))
                if lines_of is None:
                    raise PlanningError(f"step {i}: not a URScript step: {type(st).__name__}")
                out += lines_of

    emit(steps, lines, 0)
    lines.append("end")
    return "\n".join(lines) + "\n"


def check_bounds(st: ReadCorrection, i: int | None = None) -> None:
    """Refuse a correction step whose bounds are not finite and >= 0, or whose slot is not a pose."""
    slot = np.asarray(st.slot, dtype=float)
    if slot.shape != (4, 4) or not np.isfinite(slot).all():
        raise PlanningError(f"{'' if i is None else f'step {i}: '}the rack slot must be a finite 4x4 pose")
    if len(st.bounds) != 3 or not all(math.isfinite(b) and b >= 0 for b in st.bounds):
        raise PlanningError(f"{'' if i is None else f'step {i}: '}correction bounds must be 3 finite values >= 0, "
                            f"got {st.bounds}")
    if len(st.grid) != 2 or min(st.grid) < 1 or len(st.pitch) != 2 or \
            not all(math.isfinite(v) and v >= 0 for v in st.pitch):
        raise PlanningError(f"{'' if i is None else f'step {i}: '}the rack must have >= 1 row and column at a "
                            f"finite pitch >= 0, got {st.grid} at {st.pitch}")


def _correction_lines(st: ReadCorrection, to_ur: np.ndarray) -> list[str]:
    """Read the correction from the RTDE registers, stop on one beyond the bounds, and compose
    ``rack_corr`` = slot * offset * inverse(slot) in the controller's base frame."""
    check_bounds(st)
    lines = [f"  # {comment_text(st.label)}".rstrip()] if st.label else []
    names = ("rack_dx", "rack_dy", "rack_dyaw")
    lines += [f"  {n} = read_input_float_register({r})" for n, r in zip(names, RACK_REGISTERS)]
    for n, bound in zip(names, st.bounds):
        lines += [f"  if norm({n}) > {_num(bound)}:",
                  f'    popup("rack camera correction {n} beyond the slot", error=True, blocking=True)',
                  "    halt", "  end"]
    lines.append(f"  rack_slot = {ur_pose(to_ur @ np.asarray(st.slot, dtype=float))}")
    there = "rack_slot"
    if st.slots:  # the slot the blank stands in: the plan's slot moved by whole pitches
        slot_names = ("rack_row", "rack_column")
        lines += [f"  {n} = read_input_integer_register({r})" for n, r in zip(slot_names, RACK_SLOT_REGISTERS)]
        for n, count in zip(slot_names, st.grid):
            for test in ("< 0", f"> {count - 1}"):
                lines += [f"  if {n} {test}:", f'    popup("rack slot {n} beyond the rack", error=True, blocking=True)',
                          "    halt", "  end"]
        lines.append(f"  rack_there = pose_trans(rack_slot, p[rack_column * {_num(st.pitch[0])}, "
                     f"rack_row * {_num(st.pitch[1])}, 0, 0, 0, 0])")
        there = "rack_there"
    lines.append(f"  rack_corr = pose_trans(pose_trans({there}, p[rack_dx, rack_dy, 0, 0, 0, rack_dyaw]), "
                 "pose_inv(rack_slot))")
    return lines


#: Rows per servoj table: URScript lists are fixed-length values; short tables keep each
#: assignment small for the controller's parser.
SERVO_TABLE_ROWS = 250


def _servoj_lines(st: ServoJ, i: int, n_tables: int, lines: list[str]) -> int:
    """Append the table(s) and loop(s) streaming ``st``; returns the number of tables so far."""
    q = np.asarray(st.targets, dtype=float)
    if q.ndim != 2 or q.shape[1] != 6 or len(q) == 0 or not np.isfinite(q).all():
        raise PlanningError(f"step {i}: servoj needs (n, 6) finite joint targets, got shape {q.shape}")
    _positive(st.t, f"step {i} servoj t")
    if not 0.03 <= st.lookahead_time <= 0.2:
        raise PlanningError(f"step {i}: servoj lookahead_time must be in 0.03..0.2 s, got {st.lookahead_time}")
    if not 100 <= st.gain <= 2000:
        raise PlanningError(f"step {i}: servoj gain must be in 100..2000, got {st.gain}")
    lines.append(f"  # stream {len(q)} targets, one every {_num(st.t)} s")
    for k in range(0, len(q), SERVO_TABLE_ROWS):
        chunk = q[k:k + SERVO_TABLE_ROWS]
        n_tables += 1
        rows = ", ".join("[" + ", ".join(_num(v) for v in row) + "]" for row in chunk)
        lines.append(f"  table{n_tables} = [{rows}]")
        lines.append("  k = 0")
        lines.append(f"  while k < {len(chunk)}:")
        lines.append(f"    servoj(table{n_tables}[k], 0, 0, {_num(st.t)}, {_num(st.lookahead_time)}, "
                     f"{_num(st.gain)})")
        lines.append("    k = k + 1")
        lines.append("  end")
    return n_tables
