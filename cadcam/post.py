"""Post-processors: write a :class:`~cadcam.model.Job` as a G-code program for a controller.

Three dialects share one writer and differ where the controllers differ; each is one
:class:`Dialect` value (its words and capabilities) in :data:`DIALECTS`, and the writer reads
the table, never the dialect's name:

``linuxcnc``
    RS274/NGC as LinuxCNC reads it: ``G64 P<tol>`` path blending, ``T<n> M6`` + ``G43 H<n>``
    tool length offset, ``G91.1`` (incremental arc centres, the default, said explicitly),
    ends with ``G53 G0 Z0`` (machine top) and ``M30``. Checked with LinuxCNC's own
    interpreter (``rs274``) in the tests.
``fanuc``
    Fanuc / Haas style: ``%`` first and last line, ``O<number> (PART)``, every coordinate
    with a decimal point (``X10.``: Fanuc reads ``X10`` as 10 *microns* on many
    machines), ``G28 G91 Z0.`` to send Z home before each tool change and at the end,
    ``G43 H<n> Z<safe>`` on the first Z move after the change, ``M30``.
``grbl``
    Grbl 1.1 has no tool changer (``M6`` is an unsupported command there), no ``G43``
    table offsets (only the dynamic ``G43.1``), no ``G64``, no ``O`` words and no ``%``.
    A tool change is written as ``M5 M9``, a comment naming the tool, ``T<n>`` (grbl
    accepts and ignores the T word) and ``M0``: the operator changes the tool, touches
    off Z and resumes. The first tool is named in the header and is assumed loaded and
    touched off before the start. The program ends at the safe height with ``M30``:
    machine coordinates mean nothing on a grbl machine without homing, so no ``G53``.

Drilling operations (those with a :class:`~cadcam.model.DrillCycle`) are written as
canned cycles on LinuxCNC and Fanuc: ``G99 G81``/``G83 X Y Z R [Q] F`` on the first
hole, ``X Y [Z]`` on each further one, ``G80`` after the last. Grbl has none: there the
operation's points, the same motion expanded, are written as ``G0``/``G1`` moves.

Every program starts with the modal states it relies on (``G21 G90 G17 G40 G49 G80 G94``,
and its work offset: ``G54`` unless ``PostOptions.work_offset`` says another), writes the
feed only when it changes, omits axis words that did not change, and
is deterministic: no dates, the same job gives byte-identical text.

Moves are first passed through :func:`cadcam.arcs.fit_segments` (unless
``PostOptions.arcs`` is false), so circles and helices come out as ``G2``/``G3``.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass
from typing import Callable, Iterable, Literal

import numpy as np

from cadcam.arcs import FitOptions, SegmentKind, Segments, fit_segments
from cadcam.model import Job, Motion, Operation, Tool
from cadcam.parallel import Background, process_map
from factory.core.errors import GcodeError

log = logging.getLogger(__name__)

#: The controller dialects by name, as ``--post`` takes them (:data:`DIALECTS` holds each one's words).
DialectName = Literal["linuxcnc", "grbl", "fanuc"]


@dataclass(frozen=True)
class PostOptions:
    """How to write the program.

    Attributes
    ----------
    dialect : {"linuxcnc", "grbl", "fanuc"}
        Controller family; see the module docstring for what differs.
    arc_tolerance : float
        Largest distance between the written lines/arcs and the job's cutter-location
        polyline [mm]. Default 0.002. Also LinuxCNC's ``G64 P`` blending tolerance.
    arcs : bool
        Fit ``G2``/``G3`` arcs; ``False`` writes only lines (collinear runs still merge).
    coolant : bool
        Switch flood coolant on (``M8``) for each operation.
    program_number : int
        Fanuc ``O`` number, 1..9999. Default 1000.
    decimals : int
        Digits after the decimal point of coordinates [mm], 3..6. Default 4.
    rapid_rate : float
        Rapid traverse rate for time estimates [mm/min]. Default 5000.
    tool_change_time : float
        Time one tool change takes, for time estimates [s]. Default 8.
    work_offset : int
        Fixture (work coordinate system) the program runs in, 1..6: ``G54`` .. ``G59``, which
        LinuxCNC, Fanuc and grbl 1.1 all accept. Default 1 (``G54``); op 2 of a part turned
        over runs in 2 (``G55``), touched off on the turned-over stock.
    """

    dialect: DialectName = "linuxcnc"
    arc_tolerance: float = 0.002
    arcs: bool = True
    coolant: bool = True
    program_number: int = 1000
    decimals: int = 4
    rapid_rate: float = 5000.0
    tool_change_time: float = 8.0
    work_offset: int = 1

    def __post_init__(self) -> None:
        if self.dialect not in DIALECTS:
            raise GcodeError(f"unknown dialect {self.dialect!r}; choose one of {', '.join(DIALECTS)}")
        if not (self.arc_tolerance > 0 and math.isfinite(self.arc_tolerance)):
            raise GcodeError(f"arc_tolerance must be a positive number of mm, got {self.arc_tolerance}")
        if not 3 <= self.decimals <= 6:
            raise GcodeError(f"decimals must lie in 3..6, got {self.decimals}")
        if not 1 <= self.program_number <= 9999:
            raise GcodeError(f"program_number must lie in 1..9999, got {self.program_number}")
        if not (self.rapid_rate > 0 and math.isfinite(self.rapid_rate)):
            raise GcodeError(f"rapid_rate must be positive [mm/min], got {self.rapid_rate}")
        if not (self.tool_change_time >= 0 and math.isfinite(self.tool_change_time)):
            raise GcodeError(f"tool_change_time must be >= 0 [s], got {self.tool_change_time}")
        if self.work_offset not in range(1, 7):
            raise GcodeError(f"work_offset must lie in 1..6 (G54..G59), got {self.work_offset}")

    @property
    def work_offset_code(self) -> str:
        """The G word of :attr:`work_offset`: ``G54`` .. ``G59``."""
        return f"G{53 + self.work_offset}"

    @property
    def controller(self) -> Dialect:
        """The words and capabilities of :attr:`dialect`'s controller."""
        return DIALECTS[self.dialect]


@dataclass(frozen=True)
class OperationEstimate:
    """What one operation costs.

    Attributes
    ----------
    name : str
    tool_number : int
    cut_length : float
        Length of feed moves (cutting and plunging), arcs by arc length [mm].
    rapid_length : float
        Length of rapids, including the approach from the safe height and the retract [mm].
    cut_time : float
        Sum of each feed move's length over its feed [s].
    rapid_time : float
        Rapid length at ``PostOptions.rapid_rate`` [s].
    lines : int
        G-code lines written for the operation (tool change and approach included).
    """

    name: str
    tool_number: int
    cut_length: float
    rapid_length: float
    cut_time: float
    rapid_time: float
    lines: int


@dataclass(frozen=True)
class Program:
    """A posted G-code program.

    Attributes
    ----------
    text : str
        The program, ``\\n`` line ends, ending with a newline.
    dialect : str
    estimates : tuple of OperationEstimate
    total_time : float
        Estimated cycle time: cuts, rapids and tool changes [s].
    line_count : int
        Lines in ``text``.
    moves_before_fitting : int
        Moves in the job's operations before merging lines and fitting arcs.
    """

    text: str
    dialect: DialectName
    estimates: tuple[OperationEstimate, ...]
    total_time: float
    line_count: int
    moves_before_fitting: int


# --------------------------------------------------------------------------- time model


def move_seconds(length: np.ndarray | float, feed: np.ndarray | float, rapid_rate: float) -> np.ndarray:
    """Time the cycle-time estimate gives moves: length over rate, constant speed, no acceleration.

    The one time model for the post's estimate and :func:`cadcam.timeline.machine_timeline`.

    Parameters
    ----------
    length : (n,) float or float
        Path length of each move [mm].
    feed : (n,) float or float
        Feed of each move [mm/min]; NaN for a rapid.
    rapid_rate : float
        Rapid traverse rate [mm/min] (``PostOptions.rapid_rate``).

    Returns
    -------
    (n,) float or 0-d float array
        Duration of each move [s].
    """
    rate = np.where(np.isnan(feed), rapid_rate, feed)
    return np.asarray(length, dtype=np.float64) / rate * 60.0


def operation_move_seconds(op: Operation, rapid_rate: float) -> np.ndarray:
    """(n - 1,) the time [s] of each move of ``op`` by :func:`move_seconds` (its moves unfitted): feed moves at
    their feeds (:meth:`cadcam.model.Operation.move_feeds`), plunges at its plunge feed, rapids at ``rapid_rate`` [mm/min]. For planners that weigh
    one way of cutting against another by the program's clock."""
    if len(op.points) < 2:
        return np.zeros(0)
    return move_seconds(np.linalg.norm(np.diff(op.points, axis=0), axis=1), op.move_feeds()[1:], rapid_rate)


def tool_change_seconds(first_load: bool, options: PostOptions) -> float:
    """Time the cycle-time estimate gives one tool change [s].

    Every change costs ``options.tool_change_time``, the program's first load too, except on
    grbl: there the first tool is loaded and touched off before the start.
    """
    return 0.0 if first_load and not options.controller.tool_changer else options.tool_change_time


# --------------------------------------------------------------------------- formatting

_COMMENT_BAD = re.compile(r"[^ -~]")  # anything but printable ASCII


def _comment(text: str, dialect: Dialect) -> str:
    """A comment block that every dialect reads as a comment and nothing else."""
    t = _COMMENT_BAD.sub("?", text).replace("(", "[").replace(")", "]").replace(";", ",").strip()
    if dialect.upper_case_comments:
        t = t.upper()
    return f"({t})"


class _Numbers:
    """Fixed-decimal number words: trailing zeros trimmed, no ``-0``, Fanuc's decimal point."""

    def __init__(self, decimals: int, point: bool):
        self.decimals = decimals
        self.point = point
        # Words by value: a program repeats its values (a raster's Y, a level's Z) many times over.
        self._words: dict[float, str] = {}

    def __call__(self, v: float) -> str:
        w = self._words.get(v)
        if w is None:
            if len(self._words) >= _WORDS_KEPT:
                self._words.clear()
            s = f"{v:.{self.decimals}f}"
            if float(s) == 0.0:  # no "-0.0000" (and -0.0 == 0.0 as a key: the same word)
                s = f"{0.0:.{self.decimals}f}"
            s = s.rstrip("0")
            w = self._words[v] = s if self.point else s.rstrip(".")
        return w

    def rounded(self, v: float) -> float:
        """The value the controller will read for ``v``."""
        return float(self(v))


#: Number words :class:`_Numbers` keeps for reuse (about 100 bytes each).
_WORDS_KEPT = 1 << 20


#: Longest tool comment LinuxCNC keeps (``CANON_TOOL_COMMENT_SIZE`` - 1); it truncates longer ones with a warning.
_TBL_COMMENT_CHARS = 39


def linuxcnc_tool_table(tools: Iterable[Tool]) -> str:
    """A LinuxCNC tool table (``.tbl``) for the tools, pocket = tool number.

    The figures are in mm: LinuxCNC reads a tool table in the machine's units, so the table
    is for a machine configured in mm (``[TRAJ] LINEAR_UNITS = mm``), as the programs are.

    Parameters
    ----------
    tools : iterable of Tool
        The tools of every program the table serves (one job's operations, or op 1's and
        op 2's together); a tool listed twice is written once.

    Returns
    -------
    str
        One line per tool, ``T<n> P<n> D<diameter> Z<length> ;<name>`` [mm], sorted by number.
        The length is the tool length offset ``G43 H<n>`` applies (:attr:`Tool.length`); the
        name is cut to the 39 characters LinuxCNC keeps.

    Raises
    ------
    GcodeError
        One number names two tools of different names, diameters or lengths: one table
        cannot serve both.
    """
    num = _Numbers(4, point=False)
    seen: dict[int, Tool] = {}
    for t in tools:
        first = seen.setdefault(t.number, t)
        if (first.name, num(first.diameter), num(first.length)) != (t.name, num(t.diameter), num(t.length)):
            raise GcodeError(f"T{t.number} names two tools ({first.name!r}, {t.name!r}): "
                             "one tool table cannot serve both")
    out = []
    for n in sorted(seen):
        t = seen[n]
        name = _COMMENT_BAD.sub("?", t.name)[:_TBL_COMMENT_CHARS].rstrip()
        out.append(f"T{n} P{n} D{num(t.diameter)} Z{num(t.length)} ;{name}")
    return "\n".join(out) + ("\n" if out else "")


def tool_table_file(options: PostOptions, tools: Iterable[Tool]) -> str | None:
    """The text of the tool table file the controller of ``options`` reads, for ``tools`` (LinuxCNC's
    ``.tbl``, :func:`linuxcnc_tool_table`); None for a controller that reads none (grbl has no tool
    table; Fanuc keeps its offsets in the control, set at the machine)."""
    table = options.controller.tool_table
    return None if table is None else table(tools)


# --------------------------------------------------------------------------- controllers


@dataclass(frozen=True)
class Dialect:
    """What one controller family reads where controllers differ: the words and capabilities the
    writer looks up (as :class:`robotprog.urscript.FlowWords` is per robot language).

    Attributes
    ----------
    name : str
        The name ``--post`` takes and the program's header states.
    decimal_point : bool
        Every coordinate and feed carries a decimal point (``X10.``): Fanuc reads ``X10`` as
        10 least increments (microns) on many machines.
    upper_case_comments : bool
        Comments in capitals, as Fanuc controls show them.
    tape : bool
        The program is a tape: ``%`` first and last line, ``O<number> (PART)`` as its title.
    arc_centres : str
        The block that says arc centres are incremental (``G91.1``); "" where no other mode exists.
    blending : bool
        ``G64 P<arc tolerance>`` path blending.
    tool_changer : bool
        ``T<n> M6`` changes the tool. Without one (grbl: ``M6`` is unsupported there) the
        operator changes it at an ``M0`` pause, and the first tool is loaded and touched off
        before the start.
    home_before_change : tuple of str
        Blocks that send Z home before each tool change (Fanuc ``G28 G91 Z0.``, ``G90``).
    length_offset : {"after_change", "first_z", "none"}
        Where ``G43 H<n>`` goes: its own block after ``M6`` (LinuxCNC), on the first Z move
        after the change, to the safe height (Fanuc), nowhere (grbl has no offset table).
    canned_cycles : bool
        Drilling is written as ``G81``/``G83`` cycles; without them, as the moves they make.
    end : tuple of str
        Blocks after the spindle and coolant stop, before ``M30``: where Z goes at the end.
    tool_table : callable or None
        The text of the tool table file the controller reads, from the job's tools
        (LinuxCNC's ``.tbl``); None where the controller keeps its tool data itself.
    """

    name: DialectName
    decimal_point: bool
    upper_case_comments: bool
    tape: bool
    arc_centres: str
    blending: bool
    tool_changer: bool
    home_before_change: tuple[str, ...]
    length_offset: Literal["after_change", "first_z", "none"]
    canned_cycles: bool
    end: tuple[str, ...]
    tool_table: Callable[[Iterable[Tool]], str] | None


#: Z home in machine coordinates, on Fanuc (incremental zero move to the reference point).
_FANUC_HOME_Z = ("G28 G91 Z0.", "G90")

#: Every controller the post writes for, by name.
DIALECTS: dict[str, Dialect] = {
    "linuxcnc": Dialect(
        name="linuxcnc", decimal_point=False, upper_case_comments=False, tape=False, arc_centres="G91.1",
        blending=True, tool_changer=True, home_before_change=(), length_offset="after_change",
        canned_cycles=True, end=("G53 G0 Z0",), tool_table=linuxcnc_tool_table),
    "grbl": Dialect(
        name="grbl", decimal_point=False, upper_case_comments=False, tape=False, arc_centres="G91.1",
        blending=False, tool_changer=False, home_before_change=(), length_offset="none",
        # machine coordinates mean nothing on a grbl machine without homing: no G53
        canned_cycles=False, end=(), tool_table=None),
    "fanuc": Dialect(
        name="fanuc", decimal_point=True, upper_case_comments=True, tape=True, arc_centres="",
        blending=False, tool_changer=True, home_before_change=_FANUC_HOME_Z, length_offset="first_z",
        canned_cycles=True, end=_FANUC_HOME_Z, tool_table=None),
}


def _check_operation(op: Operation, k: int) -> None:
    src = f"operation {k + 1} ({op.name})"
    if len(op.points) == 0:
        raise GcodeError("operation has no cutter locations", source=src)
    if not np.isfinite(op.points).all():
        raise GcodeError("cutter locations contain NaN or infinity", source=src)
    c = op.cutting
    for what, v in (("spindle speed", c.spindle_rpm), ("feed", c.feed), ("plunge feed", c.plunge_feed)):
        if not (v > 0 and math.isfinite(v)):
            raise GcodeError(f"{what} must be positive, got {v}", source=src)
    if op.tool.number < 1:
        raise GcodeError(f"tool number must be >= 1, got {op.tool.number}", source=src)
    if not np.isin(op.motion[1:], [m.value for m in Motion]).all():
        raise GcodeError("motion kinds must be RAPID, CUT or PLUNGE", source=src)


class _Writer:
    """Accumulates lines and the modal state a controller keeps between blocks."""

    def __init__(self, opt: PostOptions):
        self.opt = opt
        self.dialect = opt.controller
        self.num = _Numbers(opt.decimals, point=self.dialect.decimal_point)
        self.feed_num = _Numbers(1, point=self.dialect.decimal_point)
        self.lines: list[str] = []
        self.tool: int | None = None  # in the spindle
        self.change_seconds = 0.0  # tool changes so far, for the estimate [s]
        self.forget()

    def forget(self) -> None:
        """After a tool change the position is unknown."""
        self.motion: int | None = None
        self.words: dict[str, str] = {}
        self.pos = [math.nan, math.nan, math.nan]  # what the controller holds, after rounding
        self.feed: str | None = None
        self.end_xy: tuple[float, float] | None = None  # where the last operation ended [mm], unrounded

    def emit(self, line: str) -> None:
        self.lines.append(line)

    def comment(self, text: str) -> None:
        self.emit(_comment(text, self.dialect))

    def move(self, code: int, xyz: np.ndarray, feed: float | None = None,
             centre: np.ndarray | None = None) -> bool:
        """Write a G0/G1/G2/G3 block; returns False when nothing would move (skipped)."""
        parts: list[str] = []
        axes = []
        for i, a in enumerate("XYZ"):
            if math.isnan(xyz[i]):
                continue
            w = self.num(float(xyz[i]))
            if self.words.get(a) != w:
                axes.append((i, a, w))
        if not axes and centre is None:
            return False
        if code != self.motion or centre is not None:
            parts.append(f"G{code}")
        start_xy = (self.pos[0], self.pos[1])
        for i, a, w in axes:
            parts.append(a + w)
        if centre is not None:
            # Relative to the start the controller holds (rounded), so start and end
            # radius agree as closely as the rounding allows.
            parts.append("I" + self.num(float(centre[0]) - start_xy[0]))
            parts.append("J" + self.num(float(centre[1]) - start_xy[1]))
        if feed is not None:
            f = self.feed_num(feed)
            if f != self.feed:
                parts.append("F" + f)
                self.feed = f
        self.emit(" ".join(parts))
        self.motion = code
        for i, a, w in axes:
            self.words[a] = w
            self.pos[i] = self.num.rounded(float(xyz[i]))
        return True


@dataclass(frozen=True)
class _Cutting:
    """What writing an operation's cutting motion (its moves or its canned cycle) did.

    Attributes
    ----------
    cut_length : float
        Feed moves [mm].
    cut_time : float
        Feed moves at their feeds [s].
    rapids : tuple of float
        Length of each rapid among them, in order [mm].
    end : (3,) float
        Where the tool stopped [mm].
    """

    cut_length: float
    cut_time: float
    rapids: tuple[float, ...]
    end: np.ndarray


def _write_cycle(w: _Writer, op: Operation) -> _Cutting:
    """Write a drilling operation as its canned cycle (G81/G83, G98/G99, G80), from over its first hole.

    The figures are those of the motion the cycle makes (the operation's points are that motion);
    its rapids as one length.
    """
    cyc = op.cycle
    num = w.num
    feed = op.cutting.feed
    f = w.feed_num(feed)
    last_z: str | None = None
    for k, (x, y, z) in enumerate(cyc.holes.tolist()):
        words = [f"X{num(x)}", f"Y{num(y)}"]
        if num(z) != last_z:
            words.append(f"Z{num(z)}")
            last_z = num(z)
        if k == 0:
            head = ["G98" if cyc.retract == "initial" else "G99", f"G{cyc.code}"]
            words += [f"R{num(cyc.r_plane)}"] + ([f"Q{num(cyc.peck)}"] if cyc.code == 83 else [])
            if f != w.feed:
                words.append(f"F{f}")
                w.feed = f
            w.emit(" ".join(head + words))
        else:
            w.emit(" ".join(words))
    w.emit("G80")
    # The controller is at the retract level over the last hole, no motion mode in force.
    x, y, _ = cyc.holes[-1]
    clear = cyc.r_plane if cyc.retract == "r" else max(cyc.initial_z, cyc.r_plane)
    w.motion = None
    for i, (a, v) in enumerate(zip("XYZ", (x, y, clear))):
        w.words[a] = num(float(v))
        w.pos[i] = num.rounded(float(v))
    seg = np.linalg.norm(np.diff(op.points, axis=0), axis=1)
    kinds = op.motion[1:]
    cut = kinds != Motion.RAPID
    cut_len = float(seg[cut].sum())
    return _Cutting(cut_len, float(move_seconds(cut_len, feed, w.opt.rapid_rate)), (float(seg[~cut].sum()),),
                    op.points[-1])


#: Input moves of a job from which arc fitting runs in worker processes (one operation each).
_PARALLEL_FIT_MOVES = 20_000


def _fit_options(opt: PostOptions) -> FitOptions:
    return FitOptions(tolerance=opt.arc_tolerance, arcs=opt.arcs, min_chord=max(0.01, 200 * 10.0 ** -opt.decimals))


def _fit_one(points: np.ndarray, motion: np.ndarray, fit: FitOptions) -> Segments:
    return fit_segments(points, motion, fit)


class FitAhead:
    """Arc fitting of operations started before the job is posted, each in a forked process of its own
    (:class:`cadcam.parallel.Background`), while the planner plans the next ones.

    :func:`post_process` takes a fit made here only for an operation whose cutter locations and motion
    are equal, value for value, to the ones fitted, under the same :class:`PostOptions`'s fitting: the
    text is the one posting without it gives. An operation offered that the job does not hold as it
    was offered (the rapid check changed it) is fitted again when posted. Where processes cannot be
    had, :meth:`take` fits here (:class:`~cadcam.parallel.Background`'s fallback).
    """

    def __init__(self, options: PostOptions):
        self.fit = _fit_options(options)
        self._started: list[tuple[np.ndarray, np.ndarray, Background | None]] = []  # None: known (know)
        self._taken: dict[int, Segments] = {}  # by index into _started

    def offer(self, operations: Iterable[Operation]) -> None:
        """Start fitting each of ``operations`` not offered before (one equal in points and motion was)."""
        # Fits already made are taken now: a child that has answered ends, and holds no memory meanwhile.
        for k, (_, _, job) in enumerate(self._started):
            if k not in self._taken and job.ready():
                self._taken[k] = job.result()
        for op in operations:
            if len(op.points) < 2 or self._find(op) is not None:
                continue
            pts, mot = np.array(op.points), np.array(op.motion)  # copies: what was fitted stays as it was
            self._started.append((pts, mot, Background(_fit_one, pts, mot, self.fit)))

    def know(self, op: Operation, segments: Segments) -> None:
        """Keep ``segments``, the fit of ``op`` (its cutter locations and motion as they are now) under this
        fitting, made elsewhere (:class:`factory.verify.VerifyAhead`): it is not fitted again."""
        if self._find(op) is None:
            self._taken[len(self._started)] = segments
            self._started.append((np.array(op.points), np.array(op.motion), None))

    def started(self, op: Operation) -> bool:
        """Whether a fit of ``op`` was started (or is known)."""
        return self._find(op) is not None

    def fitted(self, op: Operation) -> Segments | None:
        """The fit of ``op`` if one has been made (never waiting for one), else None."""
        k = self._find(op)
        if k is not None and k not in self._taken and self._started[k][2].ready():
            self._taken[k] = self._started[k][2].result()
        return None if k is None else self._taken.get(k)

    def take(self, op: Operation, fit: FitOptions) -> Segments | None:
        """The fit of ``op`` under ``fit`` if one was started (waiting for it), else None."""
        k = self._find(op) if fit == self.fit else None
        if k is None:
            return None
        if k not in self._taken:
            self._taken[k] = self._started[k][2].result()
        return self._taken[k]

    def cancel(self) -> None:
        """End the fits still running (the plan failed, or they were not wanted)."""
        for _, _, job in self._started:
            if job is not None:
                job.cancel()

    def _find(self, op: Operation) -> int | None:
        for k, (pts, mot, _) in enumerate(self._started):
            if (pts.shape == op.points.shape and pts.dtype == op.points.dtype and mot.dtype == op.motion.dtype
                    and np.array_equal(pts, op.points) and np.array_equal(mot, op.motion)):
                return k
        return None


def _fitted(job: Job, opt: PostOptions, progress: Callable[[int, int], None] | None,
            total: int, ahead: FitAhead | None = None) -> dict[int, Segments]:
    """Segments of every operation written as moves (all but the canned cycles the controller makes),
    by operation index, fitted in parallel when large.

    Arc fitting is pure Python per operation and operations are independent, so a large
    job's are fitted in forked processes (:func:`cadcam.parallel.process_map`); the result
    is the serial one. Progress then advances an operation at a time. Operations ``ahead``
    fitted already (:class:`FitAhead`) are taken from there."""
    fit = _fit_options(opt)
    todo = [k for k, op in enumerate(job.operations) if op.cycle is None or not opt.controller.canned_cycles]
    known = {k: ahead.take(job.operations[k], fit) for k in todo} if ahead is not None else {}
    known = {k: seg for k, seg in known.items() if seg is not None}
    todo = [k for k in todo if k not in known]
    moves = [max(len(job.operations[k].points) - 1, 0) for k in todo]
    finished = [sum(max(len(job.operations[k].points) - 1, 0) for k in known)]

    def done(i: int) -> None:
        finished[0] += moves[i]
        if progress is not None:
            progress(finished[0], total)

    segs = process_map(_fit_one, [(job.operations[k].points, job.operations[k].motion, fit) for k in todo],
                       moves, _PARALLEL_FIT_MOVES, done)
    return {**known, **dict(zip(todo, segs))}



#: The job's parameters a program's text depends on (op 2's numbering of its operations, its setup note); the
#: text depends on nothing else of the job but its name, source digest, setup and operations.
POSTED_PARAMETERS = ("op", "setup_note")


def post_process(job: Job, options: PostOptions = PostOptions(), *,
                 progress: Callable[[int, int], None] | None = None, ahead: FitAhead | None = None) -> Program:
    """Write a job as a G-code program.

    Parameters
    ----------
    job : Job
        Operations in cutting order; each starts at ``points[0]``, reached by a rapid at
        the safe height, straight down.
    options : PostOptions
    progress : callable, optional
        Called as ``progress(moves_done, moves_total)``.
    ahead : FitAhead, optional
        Operations whose arc fitting started earlier: their fits are taken where they are the
        job's operations as they stand (the text is the same either way).

    Returns
    -------
    Program
        The text and time estimates. The safe height is the larger of
        ``job.setup.safe_z`` and the highest cutter location in the job.

    Raises
    ------
    GcodeError
        A job with no operations, non-finite cutter locations, non-positive feeds or
        spindle speeds, tool numbers < 1.
    """
    _check_job(job)
    safe_z = max(float(job.setup.safe_z), max(float(op.points[:, 2].max()) for op in job.operations))
    w = _Writer(options)
    moves_before = sum(max(len(op.points) - 1, 0) for op in job.operations)
    fitted = _fitted(job, options, progress, moves_before, ahead)
    setup = job.parameters.get("op")
    estimates = [_write_operation(w, k, op, fitted.get(k), safe_z, setup) for k, op in enumerate(job.operations)]
    if progress is not None:
        progress(moves_before, moves_before)
    total = sum(e.cut_time + e.rapid_time for e in estimates) + w.change_seconds
    lines = _header(job, options, w.num, total) + w.lines + _tail(options)
    text = "\n".join(lines) + "\n"
    log.info("posted %s program: %d lines from %d moves, %.0f s estimated", options.dialect, len(lines),
             moves_before, total)
    return Program(text=text, dialect=options.dialect, estimates=tuple(estimates), total_time=total,
                   line_count=len(lines), moves_before_fitting=moves_before)


def _check_job(job: Job) -> None:
    if not job.operations:
        raise GcodeError("job has no operations", source=job.part_name or None)
    for k, op in enumerate(job.operations):
        _check_operation(op, k)


def _write_operation(w: _Writer, k: int, op: Operation, seg: Segments | None, safe_z: float,
                     setup: int | None = None) -> OperationEstimate:
    """Write operation ``k``: its comment, tool change, spindle, approach, cuts and retract to ``safe_z`` [mm].

    ``seg``: its fitted moves; None for a canned cycle the controller makes. ``setup``: the job's
    ``parameters["op"]`` (2 for the turned-over part), numbering its operations ``op 2.1``, ``op 2.2``,
    ... so that no comment of op 2's program reads as op 1's."""
    first_line = len(w.lines)
    t = op.tool.number
    number = f"{k + 1}" if setup is None or int(setup) == 1 else f"{int(setup)}.{k + 1}"
    w.comment(f"op {number}: {op.name} [{op.kind}] T{t} {op.tool.name}")
    _write_tool_change(w, op)
    w.emit(f"S{max(1, int(round(op.cutting.spindle_rpm)))} M3")
    if w.opt.coolant:
        w.emit("M8")
    rapid_len = _write_approach(w, op, safe_z)
    if seg is None:
        cutting = _write_cycle(w, op)
    else:
        if op.cycle is not None:
            w.comment(f"G{op.cycle.code} cycle written out as moves: {w.dialect.name} has no canned cycles")
        cutting = _write_moves(w, op, seg)
    for r in cutting.rapids:  # summed in the order they run, as the estimate always was
        rapid_len += r
    end = cutting.end
    w.move(0, np.array([math.nan, math.nan, safe_z]))
    rapid_len += safe_z - float(end[2])
    w.end_xy = (float(end[0]), float(end[1]))
    return OperationEstimate(
        name=op.name, tool_number=t, cut_length=cutting.cut_length, rapid_length=rapid_len,
        cut_time=cutting.cut_time, rapid_time=float(move_seconds(rapid_len, math.nan, w.opt.rapid_rate)),
        lines=len(w.lines) - first_line,
    )


def _stops(opt: PostOptions) -> list[str]:
    """Spindle off, and coolant off when the program switches it on."""
    return ["M5", "M9"] if opt.coolant else ["M5"]


def _write_tool_change(w: _Writer, op: Operation) -> None:
    """Load ``op``'s tool unless it is in the spindle: by the changer, or by the operator at a pause."""
    t = op.tool.number
    if t == w.tool:
        return
    d = w.dialect
    first = w.tool is None
    w.change_seconds += tool_change_seconds(first, w.opt)
    if not first:
        w.lines += _stops(w.opt)
    if d.tool_changer:
        w.lines += [*d.home_before_change, f"T{t} M6"]
        if d.length_offset == "after_change":
            w.emit(f"G43 H{t}")
    elif first:
        w.emit(f"T{t}")  # loaded and touched off before the start (the header says so)
    else:
        w.comment(f"change to T{t} {op.tool.name}, set Z zero, then resume")
        w.lines += [f"T{t}", "M0"]
    w.forget()
    w.tool = t


def _write_approach(w: _Writer, op: Operation, safe_z: float) -> float:
    """Rapid to the safe height [mm], over the operation's start, straight down to it.

    Returns the rapid length [mm]: from where the last operation ended (when known), and down."""
    p0 = op.points[0]
    if w.dialect.length_offset == "first_z" and math.isnan(w.pos[2]):
        # The length offset comes in with the first Z move after the change, to the safe height.
        w.move(0, np.array([p0[0], p0[1], math.nan]))
        w.emit(f"G43 H{op.tool.number} Z{w.num(safe_z)}")
        w.words["Z"] = w.num(safe_z)
        w.pos[2] = w.num.rounded(safe_z)
    else:
        w.move(0, np.array([math.nan, math.nan, safe_z]))
        w.move(0, np.array([p0[0], p0[1], math.nan]))
    rapid_len = 0.0
    if w.end_xy is not None:
        rapid_len += math.hypot(p0[0] - w.end_xy[0], p0[1] - w.end_xy[1])
    w.move(0, p0)
    rapid_len += safe_z - float(p0[2])
    return rapid_len


def _write_moves(w: _Writer, op: Operation, seg: Segments) -> _Cutting:
    """Write an operation's fitted segments as G0/G1/G2/G3 blocks."""
    lengths = seg.lengths()
    feeds = segment_feeds(op, seg)
    seconds = move_seconds(lengths, feeds, w.opt.rapid_rate)
    cut_len = 0.0
    cut_time = 0.0
    rapids: list[float] = []
    # As Python numbers, once: the same values, without a numpy scalar per word.
    ends, centres, kinds = seg.end.tolist(), seg.centre.tolist(), seg.kind.tolist()
    for i, (m, length, feed, time) in enumerate(zip(seg.motion.tolist(), lengths.tolist(), feeds.tolist(),
                                                    seconds.tolist())):
        if m == Motion.RAPID:
            w.move(0, ends[i])
            rapids.append(length)
            continue
        cut_len += length
        cut_time += time
        if kinds[i] == SegmentKind.LINE:
            w.move(1, ends[i], feed)
        else:
            w.move(kinds[i], ends[i], feed, centre=centres[i])
    return _Cutting(cut_len, cut_time, tuple(rapids), seg.end[-1] if len(seg) else op.points[0])


def segment_feeds(op: Operation, seg: Segments) -> np.ndarray:
    """(m,) the feed of each fitted segment of ``op`` [mm/min], NaN for rapids: the slowest of the moves it
    replaces (``seg.source_end``), so an arc over moves of different feeds never runs one faster than planned."""
    per_move = op.move_feeds()[1:]  # the move ending at point j + 1
    if not len(seg) or not len(per_move):
        return np.full(len(seg), np.nan)
    first = np.minimum(np.r_[0, seg.source_end[:-1]], len(per_move) - 1)
    return np.where(seg.motion == Motion.RAPID, np.nan, np.fmin.reduceat(per_move, first))


def operations_end(program: Program, options: PostOptions) -> int:
    """Lines of ``program`` (posted with ``options``) up to the end of its last operation: all but the tail
    that ends the program (spindle off, park, program end), whose moves a longer job would not make there."""
    return program.line_count - len(_tail(options))


def _header(job: Job, opt: PostOptions, num: _Numbers, total: float) -> list[str]:
    """The program's title, the comments a machinist reads first, and the modal states it relies on.

    ``total``: the estimated cycle time [s]."""
    d = opt.controller
    if d.tape:
        head = ["%", f"O{opt.program_number:04d} " + _comment(job.part_name or "part", d)]
    else:
        head = [_comment(f"part {job.part_name}", d)]
    head.append(_comment(f"posted by factory for {d.name}, units mm", d))
    if job.source_sha256:
        head.append(_comment(f"source sha256 {job.source_sha256}", d))
    head.append(_comment(f"estimated cycle time {_hms(total)}", d))
    for tool in job.tools:
        head.append(_comment(f"T{tool.number} {tool.name} D{num(tool.diameter)} length {num(tool.length)}", d))
    if not d.tool_changer:
        head.append(_comment(f"load T{job.operations[0].tool.number} and set Z zero before starting", d))
    head.append("G21 G90 G17 G40 G49 G80 G94")
    if d.arc_centres:
        head.append(d.arc_centres)
    if job.parameters.get("setup_note"):
        head.append(_comment(str(job.parameters["setup_note"]), d))
    head.append(opt.work_offset_code)
    if d.blending:
        head.append(f"G64 P{num(opt.arc_tolerance)}")
    return head


def _tail(opt: PostOptions) -> list[str]:
    """Spindle and coolant off, Z where the controller parks it, program end."""
    d = opt.controller
    return [*_stops(opt), *d.end, "M30", *(["%"] if d.tape else [])]


def _hms(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}h {s % 3600 // 60:02d}m {s % 60:02d}s"
