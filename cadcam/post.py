"""Post-processors: write a :class:`~cadcam.model.Job` as a G-code program for a controller.

Three dialects share one writer and differ where the controllers differ:

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
from cadcam.parallel import process_map
from factory.core.errors import GcodeError

log = logging.getLogger(__name__)

Dialect = Literal["linuxcnc", "grbl", "fanuc"]
DIALECTS: tuple[str, ...] = ("linuxcnc", "grbl", "fanuc")


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

    dialect: Dialect = "linuxcnc"
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
    dialect: Dialect
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


def tool_change_seconds(first_load: bool, options: PostOptions) -> float:
    """Time the cycle-time estimate gives one tool change [s].

    Every change costs ``options.tool_change_time``, the program's first load too, except on
    grbl: there the first tool is loaded and touched off before the start.
    """
    return 0.0 if first_load and options.dialect == "grbl" else options.tool_change_time


# --------------------------------------------------------------------------- formatting

_COMMENT_BAD = re.compile(r"[^ -~]")  # anything but printable ASCII


def _comment(text: str, dialect: str) -> str:
    """A comment block that every dialect reads as a comment and nothing else."""
    t = _COMMENT_BAD.sub("?", text).replace("(", "[").replace(")", "]").replace(";", ",").strip()
    if dialect == "fanuc":
        t = t.upper()
    return f"({t})"


class _Numbers:
    """Fixed-decimal number words: trailing zeros trimmed, no ``-0``, Fanuc's decimal point."""

    def __init__(self, decimals: int, point: bool):
        self.decimals = decimals
        self.point = point

    def __call__(self, v: float) -> str:
        s = f"{v:.{self.decimals}f}"
        if float(s) == 0.0:  # no "-0.0000"
            s = f"{0.0:.{self.decimals}f}"
        s = s.rstrip("0")
        return s if self.point else s.rstrip(".")

    def rounded(self, v: float) -> float:
        """The value the controller will read for ``v``."""
        return float(self(v))


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
        self.dialect = opt.dialect
        self.num = _Numbers(opt.decimals, point=opt.dialect == "fanuc")
        self.feed_num = _Numbers(1, point=opt.dialect == "fanuc")
        self.lines: list[str] = []
        self.forget()

    def forget(self) -> None:
        """After a tool change or machine-coordinate move the position is unknown."""
        self.motion: int | None = None
        self.words: dict[str, str] = {}
        self.pos = [math.nan, math.nan, math.nan]  # what the controller holds, after rounding
        self.feed: str | None = None

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


def _write_cycle(w: _Writer, op: Operation) -> tuple[float, float, float]:
    """Write a drilling operation as its canned cycle (G81/G83, G98/G99, G80), from over its first hole.

    Returns the feed length [mm], feed time [s] and rapid length [mm] of the motion the
    cycle makes (the operation's points are that motion).
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
    return cut_len, float(move_seconds(cut_len, feed, w.opt.rapid_rate)), float(seg[~cut].sum())


#: Input moves of a job from which arc fitting runs in worker processes (one operation each).
_PARALLEL_FIT_MOVES = 20_000


def _fit_options(opt: PostOptions) -> FitOptions:
    return FitOptions(tolerance=opt.arc_tolerance, arcs=opt.arcs, min_chord=max(0.01, 200 * 10.0 ** -opt.decimals))


def _fit_one(points: np.ndarray, motion: np.ndarray, fit: FitOptions) -> Segments:
    return fit_segments(points, motion, fit)


def _fitted(job: Job, opt: PostOptions, progress: Callable[[int, int], None] | None,
            total: int) -> dict[int, Segments]:
    """Segments of every operation written as moves, by operation index, fitted in parallel when large.

    Arc fitting is pure Python per operation and operations are independent, so a large
    job's are fitted in forked processes (:func:`cadcam.parallel.process_map`); the result
    is the serial one. Progress then advances an operation at a time."""
    fit = _fit_options(opt)
    todo = [k for k, op in enumerate(job.operations) if op.cycle is None or opt.dialect == "grbl"]
    moves = [max(len(job.operations[k].points) - 1, 0) for k in todo]
    finished = [0]

    def done(i: int) -> None:
        finished[0] += moves[i]
        if progress is not None:
            progress(finished[0], total)

    segs = process_map(_fit_one, [(job.operations[k].points, job.operations[k].motion, fit) for k in todo],
                       moves, _PARALLEL_FIT_MOVES, done)
    return dict(zip(todo, segs))


def post_process(job: Job, options: PostOptions = PostOptions(), *,
                 progress: Callable[[int, int], None] | None = None) -> Program:
    """Write a job as a G-code program.

    Parameters
    ----------
    job : Job
        Operations in cutting order; each starts at ``points[0]``, reached by a rapid at
        the safe height, straight down.
    options : PostOptions
    progress : callable, optional
        Called as ``progress(moves_done, moves_total)``.

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
    opt = options
    d = opt.dialect
    if not job.operations:
        raise GcodeError("job has no operations", source=job.part_name or None)
    for k, op in enumerate(job.operations):
        _check_operation(op, k)
    safe_z = max(float(job.setup.safe_z), max(float(op.points[:, 2].max()) for op in job.operations))

    w = _Writer(opt)
    estimates: list[OperationEstimate] = []
    change_time = 0.0  # [s]
    current_tool: int | None = None
    last_xy: tuple[float, float] | None = None
    moves_before = sum(max(len(op.points) - 1, 0) for op in job.operations)
    moves_done = 0
    fitted = _fitted(job, opt, progress, moves_before)

    for k, op in enumerate(job.operations):
        first_line = len(w.lines)
        t = op.tool.number
        c = op.cutting
        w.comment(f"op {k + 1}: {op.name} [{op.kind}] T{t} {op.tool.name}")
        rapid_len = 0.0
        if t != current_tool:
            change_time += tool_change_seconds(current_tool is None, opt)
            if d == "grbl":
                if current_tool is not None:
                    w.emit("M5")
                    if opt.coolant:
                        w.emit("M9")
                    w.comment(f"change to T{t} {op.tool.name}, set Z zero, then resume")
                    w.emit(f"T{t}")
                    w.emit("M0")
                else:
                    w.emit(f"T{t}")
            else:
                if current_tool is not None:
                    w.emit("M5")
                    if opt.coolant:
                        w.emit("M9")
                if d == "fanuc":
                    w.emit("G28 G91 Z0.")
                    w.emit("G90")
                w.emit(f"T{t} M6")
                if d == "linuxcnc":
                    w.emit(f"G43 H{t}")
            w.forget()
            last_xy = None  # the tool change moves the spindle somewhere we do not know
        current_tool = t
        w.emit(f"S{max(1, int(round(c.spindle_rpm)))} M3")
        if opt.coolant:
            w.emit("M8")
        p0 = op.points[0]
        # Approach: safe height, over the start, straight down.
        if d == "fanuc" and math.isnan(w.pos[2]):
            w.move(0, np.array([p0[0], p0[1], math.nan]))
            w.emit(f"G43 H{t} Z{w.num(safe_z)}")
            w.words["Z"] = w.num(safe_z)
            w.pos[2] = w.num.rounded(safe_z)
        else:
            w.move(0, np.array([math.nan, math.nan, safe_z]))
            w.move(0, np.array([p0[0], p0[1], math.nan]))
        if last_xy is not None:
            rapid_len += math.hypot(p0[0] - last_xy[0], p0[1] - last_xy[1])
        w.move(0, p0)
        rapid_len += safe_z - float(p0[2])

        if op.cycle is not None and d != "grbl":
            moves_done += max(len(op.points) - 1, 0)
            cut_len, cut_time, cycle_rapid = _write_cycle(w, op)
            rapid_len += cycle_rapid
            end = op.points[-1]
        else:
            if op.cycle is not None:
                w.comment(f"G{op.cycle.code} cycle written out as moves: grbl has no canned cycles")
            seg = fitted[k]
            moves_done += max(len(op.points) - 1, 0)
            lengths = seg.lengths()
            feeds = np.select([seg.motion == Motion.CUT, seg.motion == Motion.PLUNGE], [c.feed, c.plunge_feed], np.nan)
            seconds = move_seconds(lengths, feeds, opt.rapid_rate)
            cut_len = 0.0
            cut_time = 0.0
            for i in range(len(seg)):
                m = int(seg.motion[i])
                if m == Motion.RAPID:
                    w.move(0, seg.end[i])
                    rapid_len += float(lengths[i])
                    continue
                feed = c.feed if m == Motion.CUT else c.plunge_feed
                cut_len += float(lengths[i])
                cut_time += float(seconds[i])
                kind = int(seg.kind[i])
                if kind == SegmentKind.LINE:
                    w.move(1, seg.end[i], feed)
                else:
                    w.move(kind, seg.end[i], feed, centre=seg.centre[i])
            end = seg.end[-1] if len(seg) else p0
        w.move(0, np.array([math.nan, math.nan, safe_z]))
        rapid_len += safe_z - float(end[2])
        last_xy = (float(end[0]), float(end[1]))
        estimates.append(OperationEstimate(
            name=op.name, tool_number=t, cut_length=cut_len, rapid_length=rapid_len,
            cut_time=cut_time, rapid_time=float(move_seconds(rapid_len, math.nan, opt.rapid_rate)),
            lines=len(w.lines) - first_line,
        ))

    if progress is not None:
        progress(moves_before, moves_before)
    body = w.lines
    total = sum(e.cut_time + e.rapid_time for e in estimates) + change_time

    head: list[str] = []
    if d == "fanuc":
        head += ["%", f"O{opt.program_number:04d} " + _comment(job.part_name or "part", d)]
    else:
        head.append(_comment(f"part {job.part_name}", d))
    head.append(_comment(f"posted by factory for {d}, units mm", d))
    if job.source_sha256:
        head.append(_comment(f"source sha256 {job.source_sha256}", d))
    head.append(_comment(f"estimated cycle time {_hms(total)}", d))
    for tool in job.tools:
        head.append(_comment(f"T{tool.number} {tool.name} D{w.num(tool.diameter)} length {w.num(tool.length)}", d))
    if d == "grbl":
        head.append(_comment(f"load T{job.operations[0].tool.number} and set Z zero before starting", d))
    head.append("G21 G90 G17 G40 G49 G80 G94")
    if d in ("linuxcnc", "grbl"):
        head.append("G91.1")
    if job.parameters.get("setup_note"):
        head.append(_comment(str(job.parameters["setup_note"]), d))
    head.append(opt.work_offset_code)
    if d == "linuxcnc":
        head.append(f"G64 P{w.num(opt.arc_tolerance)}")

    tail = ["M5"]
    if opt.coolant:
        tail.append("M9")
    if d == "linuxcnc":
        tail.append("G53 G0 Z0")
    elif d == "fanuc":
        tail += ["G28 G91 Z0.", "G90"]
    tail.append("M30")
    if d == "fanuc":
        tail.append("%")

    lines = head + body + tail
    text = "\n".join(lines) + "\n"
    log.info("posted %s program: %d lines from %d moves, %.0f s estimated", d, len(lines), moves_before, total)
    return Program(text=text, dialect=d, estimates=tuple(estimates), total_time=total,
                   line_count=len(lines), moves_before_fitting=moves_before)


def _hms(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}h {s % 3600 // 60:02d}m {s % 60:02d}s"


def linuxcnc_tool_table(tools: Iterable[Tool]) -> str:
    """A LinuxCNC tool table (``.tbl``) for the tools, pocket = tool number.

    Parameters
    ----------
    tools : iterable of Tool
        Duplicates by number keep the first.

    Returns
    -------
    str
        One line per tool, ``T1 P1 Z<length> D<diameter> ;<name>`` [mm], sorted by number.
    """
    num = _Numbers(4, point=False)
    seen: dict[int, Tool] = {}
    for t in tools:
        seen.setdefault(t.number, t)
    out = []
    for n in sorted(seen):
        t = seen[n]
        name = _COMMENT_BAD.sub("?", t.name)
        out.append(f"T{n} P{n} Z{num(t.length)} D{num(t.diameter)} ;{name}")
    return "\n".join(out) + ("\n" if out else "")
