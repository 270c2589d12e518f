"""A G-code parser: program text to the tool-tip moves a machine would make.

It reads what factory's posts write (:mod:`cadcam.post`) and what hand-written and other
CAM programs for 3-axis mills commonly contain, and refuses everything else with a
:class:`~factory.core.errors.GcodeError` naming the line, rather than guessing.

Read
    Comments ``( )`` and ``;``; ``%`` lines; ``N`` line numbers; an ``O`` program number
    alone on its line; block delete ``/`` (the block runs: the switch is off, as
    LinuxCNC starts; pass ``block_delete=True`` to skip such blocks); spaces anywhere
    and lower case letters. ``G0 G1 G2 G3`` (arcs in the XY plane, ``I J`` centre or
    ``R`` radius, helical with ``Z``, ``P`` turns), ``G4 P`` dwell, ``G17``, ``G20``/``G21``,
    ``G90``/``G91``, ``G90.1``/``G91.1``, ``G94``, ``G40``, ``G43 [H]``/``G49``, ``G54``-``G59``,
    ``G61``/``G61.1``/``G64 [P Q]``, ``G80``, ``G53`` and ``G28`` Z retracts; ``M0 M1 M2 M3
    M4 M5 M6 M7 M8 M9 M30``, ``T S F``.
Not read (error)
    ``G81``/``G83`` drilling cycles with ``G98``/``G99`` retract (absolute mode, no ``L``).
    Other planes (``G18``/``G19``), cutter compensation (``G41``/``G42``), other canned cycles,
    inverse-time feed, ``G92``/``G10`` offsets, parameters and expressions (``#``, ``[ ]``),
    subroutines, axes other than X Y Z.

Semantics chosen where a machine's would depend on its configuration:

* ``G54``-``G59`` all mean "the work frame": positions are reported in work coordinates.
* ``G53 Z..`` and ``G28 Z..`` move to machine coordinates the parser cannot know. Both are
  taken as what they are used for, a retract to the top: a straight-up move to the highest
  tool-tip Z the program has reached so far (after ``G28``'s intermediate point). X or Y
  with ``G53``/``G28`` is an error.
* Tool length: reported positions are tool *tip* positions. Without ``tool_lengths`` the
  parser assumes the program's length compensation matches the tool in the spindle (as
  factory's programs do with the tool table the post writes), so tip = programmed
  position. With ``tool_lengths`` (tool number -> length [mm]) it applies them as a
  controller does: tip Z = programmed Z + (length of ``H`` when ``G43`` is on, else 0) -
  length of the tool in the spindle.
* The tool in the spindle is the one the last ``M6`` loaded; in a program with no ``M6``
  at all (grbl style, manual changes) the last ``T`` word.
* ``F`` is stored as written and read in the units in force at each move.
* Arcs whose start and end radius differ are accepted by LinuxCNC's rule (in mm: the
  difference must not exceed 0.0283 mm unless it is within 0.1 % of the radius, and never
  2.83 mm) and moved as LinuxCNC moves them: the radius changes linearly along the arc.
* Parsing stops at ``M2``/``M30``, as a controller stops reading.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from cadcam.arcs import arc_sweep, discretize_arc
from cadcam.model import Motion, ProgramMoves
from factory.core.errors import GcodeError

log = logging.getLogger(__name__)

MM_PER_INCH = 25.4
#: LinuxCNC's arc radius rules [mm] (interp_internal.hh: RADIUS_TOLERANCE_MM,
#: CENTER_ARC_RADIUS_TOLERANCE_MM, SPIRAL_RELATIVE_TOLERANCE).
ZERO_RADIUS_TOLERANCE = 0.00005 * MM_PER_INCH
SPIRAL_ABS_TOLERANCE = 2 * 0.01 * math.sqrt(2.0)
SPIRAL_REL_TOLERANCE = 0.001
#: Largest coordinate magnitude accepted [mm]: 100 m, beyond any milling machine.
MAX_COORDINATE = 1.0e5
#: Largest magnitude of any number word (feeds, speeds, codes) before unit conversion.
MAX_NUMBER = 1.0e9

# G codes as round(10 * number) -> modal group (LinuxCNC's numbering; 0 = non-modal).
_G_GROUP = {
    0: 1, 10: 1, 20: 1, 30: 1, 800: 1, 810: 1, 830: 1,
    980: 10, 990: 10,
    40: 0, 280: 0, 530: 0,
    170: 2,
    200: 6, 210: 6,
    400: 7,
    430: 8, 490: 8,
    540: 12, 550: 12, 560: 12, 570: 12, 580: 12, 590: 12,
    610: 13, 611: 13, 640: 13,
    900: 3, 910: 3,
    901: 4, 911: 4,
    940: 5,
}
_G_REFUSED = {
    180: "only XY-plane arcs supported (G18 selects the XZ plane)",
    190: "only XY-plane arcs supported (G19 selects the YZ plane)",
    410: "cutter radius compensation (G41) not supported",
    420: "cutter radius compensation (G42) not supported",
    411: "cutter radius compensation (G41.1) not supported",
    421: "cutter radius compensation (G42.1) not supported",
    431: "dynamic tool length offset (G43.1) not supported",
    930: "inverse time feed (G93) not supported",
    950: "feed per revolution (G95) not supported",
    920: "coordinate offsets (G92) not supported",
    100: "G10 offset setting not supported",
    300: "G30 not supported",
    380: "probing (G38) not supported",
    330: "spindle-synchronized motion (G33) not supported",
}
_M_GROUP = {0: 4, 1: 4, 2: 4, 30: 4, 6: 6, 3: 7, 4: 7, 5: 7, 7: 8, 8: 8, 9: 8}

# A word: letter then a number (no exponents, as in RS274/NGC).
_WORD = re.compile(r"([A-Z])([+-]?(?:\d+\.?\d*|\.\d+))")
_LETTERS_OK = set("GMTSFXYZIJKRPQHN")


@dataclass
class _State:
    scale: float = 1.0  # mm per program unit
    absolute: bool = True
    ijk_absolute: bool = False
    motion: int | None = None  # 0..3, None after G80 / at start
    feed_raw: float | None = None
    selected_tool: int = 0
    spindle_tool: int = 0
    tlo_on: bool = False
    tlo_h: int = 0
    ended: bool = False
    pos: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))  # programmed, mm
    top: float = -math.inf  # highest tip Z reached [mm]
    # Canned drilling cycles (G81, G83): sticky words [mm] and the retract mode.
    retract_to_r: bool = False  # G99 (True) or G98 (False, LinuxCNC's default)
    cycle_z: float = math.nan
    cycle_r: float = math.nan
    cycle_q: float = math.nan
    cycle_clear: float = math.nan  # G98's retract height: Z where the cycles began


def _err(msg: str, source: str | None, line: int) -> GcodeError:
    return GcodeError(f"line {line}: {msg}", source=source, line=line)


def _strip_comments(text: str, source: str | None, line: int) -> str:
    """Remove ``( )`` and ``;`` comments; refuse unclosed or nested parentheses."""
    if "(" not in text and ")" not in text:
        return text.split(";", 1)[0]
    out = []
    i = 0
    n = len(text)
    while i < n:
        ch = text[i]
        if ch == ";":
            break
        if ch == "(":
            j = text.find(")", i + 1)
            if j < 0:
                raise _err("comment opened with '(' is not closed", source, line)
            if "(" in text[i + 1:j]:
                raise _err("nested comment", source, line)
            i = j + 1
            continue
        if ch == ")":
            raise _err("')' without '('", source, line)
        out.append(ch)
        i += 1
    return "".join(out)


@dataclass
class _Block:
    g: list[int]
    m: list[int]
    words: dict[str, float]


def _tokenize(raw: str, source: str | None, line: int, block_delete: bool) -> _Block | None:
    """One line to a block, or None for a line without words."""
    s = raw.strip()
    if s.startswith("%"):
        if _strip_comments(s[1:], source, line).strip():
            raise _err("text after '%'", source, line)
        return None
    if s.startswith("/"):
        if block_delete:
            return None
        s = s[1:]
    s = _strip_comments(s, source, line)
    s = "".join(s.split()).upper()
    if not s:
        return None
    for bad, what in (("#", "parameters (#)"), ("[", "expressions ([ ])"), ("]", "expressions ([ ])")):
        if bad in s:
            raise _err(f"{what} not supported", source, line)
    if s[0] == "O":
        if re.fullmatch(r"O\d+", s):
            return None  # program number
        raise _err("O words (subroutines, program control) not supported", source, line)
    pos = 0
    g: list[int] = []
    m: list[int] = []
    words: dict[str, float] = {}
    first = True
    for mt in _WORD.finditer(s):
        if mt.start() != pos:
            break
        pos = mt.end()
        letter, num = mt.group(1), mt.group(2)
        if letter not in _LETTERS_OK:
            raise _err(f"unsupported word {letter}{num}", source, line)
        v = float(num)
        if not abs(v) <= MAX_NUMBER:
            raise _err(f"number out of range in {letter}{num[:20]}", source, line)
        if letter == "N":
            if not first:
                raise _err("N line number must be the first word", source, line)
            first = False
            continue
        first = False
        if letter == "G":
            code = round(v * 10)
            if abs(v * 10 - code) > 1e-6:
                raise _err(f"unknown code G{num}", source, line)
            g.append(code)
        elif letter == "M":
            if v != int(v):
                raise _err(f"unknown code M{num}", source, line)
            m.append(int(v))
        else:
            if letter in words:
                raise _err(f"word {letter} appears twice in one block", source, line)
            words[letter] = v
    if pos != len(s):
        rest = s[pos:pos + 12]
        raise _err(f"cannot read {rest!r}", source, line)
    return _Block(g, m, words)


class _Out:
    """Growing move arrays: point chunks plus one (motion, tool, feed, line) per chunk."""

    def __init__(self) -> None:
        self.points: list[np.ndarray] = [np.full((1, 3), np.nan)]
        self.motion: list[int] = [0]
        self.tool: list[int] = [0]
        self.feed: list[float] = [math.nan]
        self.line: list[int] = [0]
        self.count: list[int] = [1]

    def add(self, pts: np.ndarray, motion: int, tool: int, feed: float, line: int) -> None:
        self.points.append(pts)
        self.motion.append(int(motion))
        self.tool.append(tool)
        self.feed.append(feed)
        self.line.append(line)
        self.count.append(len(pts))

    def add_each(self, pts: np.ndarray, motion: np.ndarray, tool: int, feed: np.ndarray, line: np.ndarray) -> None:
        """One point per block: ``pts`` (k, 3) [mm] with each block's motion, feed [mm/min] and line."""
        k = len(pts)
        self.points.append(pts)
        self.motion.extend(motion.tolist())
        self.tool.extend([tool] * k)
        self.feed.extend(feed.tolist())
        self.line.extend(line.tolist())
        self.count.extend([1] * k)

    def result(self, source: str | None) -> ProgramMoves:
        count = np.asarray(self.count)
        motion, tool, feed, line = (np.repeat(np.asarray(col), count)
                                    for col in (self.motion, self.tool, self.feed, self.line))
        return ProgramMoves(points=np.vstack(self.points), motion=motion, tool=tool, feed=feed, line=line,
                            source=source)


# The blocks most programs are made of, a straight move of G0/G1 and X Y Z words and a feed: read all at once
# and moved together (:func:`_plain_run`), each as the general path (:func:`_tokenize`, :func:`_execute`) would.
# Anything else on the line (a comment, N, lower case, other words or order) takes the general path.
_NUM = r"[+-]?(?:\d+\.?\d*|\.\d+)"
_PLAIN = re.compile(rf"[ \t]*(?:G0?([01])[ \t]*)?(?:X({_NUM})[ \t]*)?(?:Y({_NUM})[ \t]*)?(?:Z({_NUM})[ \t]*)?"
                    rf"(?:F(\d+\.?\d*|\.\d+)[ \t]*)?")


@dataclass(frozen=True)
class _PlainBlocks:
    """The program's plain straight moves (:data:`_PLAIN`), in line order.

    line : (k,) int, 1-based.
    words : (k, 5) float, the G (0 or 1), X, Y, Z and F words as written, NaN where absent (program units).
    last : (k, 5) int, for each word the block at or before this one that last had it, -1 before any.
    """

    line: np.ndarray
    words: np.ndarray
    last: np.ndarray


def _plain_blocks(lines: list[str]) -> _PlainBlocks:
    """The lines that are plain straight moves with at least one axis word and every number in range."""
    found = [(i, m.group(1, 2, 3, 4, 5)) for i, m in enumerate(map(_PLAIN.fullmatch, lines), start=1)
             if m is not None and (m.group(2) or m.group(3) or m.group(4))]
    line = np.fromiter((i for i, _ in found), np.int64, len(found))
    words = np.array(list(map(float, (w or "nan" for _, g in found for w in g))), dtype=np.float64).reshape(-1, 5)
    # a number out of range is refused where the line is read (:func:`_tokenize`): those lines take that path
    ok = ~(np.abs(words) > MAX_NUMBER).any(axis=1)
    line, words = line[ok], words[ok]
    last = np.where(np.isnan(words), -1, np.arange(len(words))[:, None])
    np.maximum.accumulate(last, axis=0, out=last)
    return _PlainBlocks(line, words, last)


def _plain_block(p: _PlainBlocks, j: int) -> _Block:
    """Block ``j`` of ``p`` as :func:`_tokenize` reads it."""
    g, *axes = p.words[j].tolist()
    return _Block([] if math.isnan(g) else [int(g) * 10], [],
                  {a: v for a, v in zip("XYZF", axes) if not math.isnan(v)})


_WORD_COLUMNS = np.arange(5)


def _plain_run(p: _PlainBlocks, a: int, b: int, st: _State, out: _Out,
               tool_lengths: Mapping[int, float] | None) -> bool:
    """Blocks ``a:b`` of ``p``, consecutive in the program, moved as :func:`_execute` moves them one by one (the
    same points, feeds, state); False, having done nothing, where one of them needs more than a straight
    move in absolute mode, or is refused: :func:`_execute` then takes them one by one and says why."""
    if not st.absolute:
        return False
    last = p.last[a:b]
    # each block's modal values: its words (X Y Z scaled to mm), else the last block's in the run, else the state's
    held = p.words[last, _WORD_COLUMNS] * [1.0, st.scale, st.scale, st.scale, 1.0]
    before = [math.nan if st.motion is None else float(st.motion), *st.pos.tolist(),
              math.nan if st.feed_raw is None else st.feed_raw]
    held = np.where(last < a, before, held)
    motion, tgt, feed_raw = held[:, 0], held[:, 1:4], held[:, 4]
    cut = motion == 1.0
    if (not ((motion == 0.0) | cut).all()  # no motion mode yet, or an arc's or a cycle's
            or not (feed_raw[cut] > 0).all()  # a feed move without a feed: refused
            or (np.abs(tgt) > MAX_COORDINATE).any()):
        return False
    try:
        shift = _tip_shift(st, tool_lengths)
    except GcodeError:
        return False
    pts = tgt + [0.0, 0.0, shift]
    out.add_each(pts, cut.astype(np.int64) * int(Motion.CUT), st.spindle_tool,
                 np.where(cut, feed_raw * st.scale, math.nan), p.line[a:b])
    z = pts[:, 2]
    top = np.nanmax(z) if np.isfinite(z).any() else math.nan
    if top > st.top:  # the first block at that height, as one by one
        st.top = float(z[np.flatnonzero(z == top)[0]])
    st.motion = int(motion[-1])
    st.feed_raw = None if math.isnan(feed_raw[-1]) else float(feed_raw[-1])
    st.pos = tgt[-1].copy()
    return True


def parse_gcode(text: str, *, source: str | None = None, arc_tolerance: float = 0.001,
                tool_lengths: Mapping[int, float] | None = None,
                block_delete: bool = False,
                progress: Callable[[int, int], None] | None = None) -> ProgramMoves:
    """Parse a G-code program into tool-tip moves, arcs broken into chords.

    Parameters
    ----------
    text : str
        The program.
    source : str, optional
        File name for error messages.
    arc_tolerance : float
        Largest distance between an arc and the chords that replace it [mm] (> 0).
    tool_lengths : mapping of int to float, optional
        Tool number -> length offset [mm]; see the module docstring. None: the program's
        length compensation is taken to match the tool in the spindle.
    block_delete : bool
        Skip blocks starting with ``/`` (the machine's block delete switch on).
    progress : callable, optional
        Called as ``progress(lines_done, lines_total)`` every few thousand lines.

    Returns
    -------
    ProgramMoves
        ``points[0]`` all NaN; axes never programmed stay NaN. Positions in mm.

    Raises
    ------
    GcodeError
        Anything the parser does not read, or reads as wrong; the message starts
        ``line N:`` and ``error.data["line"]`` is N.
    """
    if not (isinstance(arc_tolerance, (int, float)) and arc_tolerance > 0 and math.isfinite(arc_tolerance)):
        raise GcodeError(f"arc_tolerance must be a positive number of mm, got {arc_tolerance}", source=source)
    lines = text.splitlines()
    plain = _plain_blocks(lines)
    is_plain = np.zeros(len(lines) + 1, dtype=bool)
    is_plain[plain.line] = True
    blocks: list[tuple[int, _Block]] = []
    for i, raw in enumerate(lines, start=1):
        if is_plain[i]:
            continue
        try:
            b = _tokenize(raw, source, i, block_delete)
        except (ArithmeticError, ValueError) as e:
            raise _err(f"cannot read block: {e}", source, i) from e
        if b is not None:
            blocks.append((i, b))
    any_m6 = any(6 in b.m for _, b in blocks)
    st = _State()
    out = _Out()
    total = len(lines)
    # the plain blocks before each other block, and after the last
    runs = np.searchsorted(plain.line, [ln for ln, _ in blocks]).tolist() + [len(plain.line)]
    done = 0  # plain blocks moved
    shown = -1  # the last progress reported, in 5000s of blocks

    def execute(b: _Block, ln: int) -> None:
        try:
            _execute(b, st, out, ln, any_m6, arc_tolerance, tool_lengths)
        except GcodeError as e:
            if e.source is None and source is not None:
                e.source = source
            if "line" not in e.data:
                e.message = f"line {ln}: {e.message}"
                e.args = (e.message,)
                e.data["line"] = ln
            raise
        except (ArithmeticError, ValueError) as e:
            # Not expected; still a bad program must not surface as a crash.
            raise _err(f"cannot execute block: {e}", source, ln) from e

    for k, end in enumerate(runs):
        if end > done and not _plain_run(plain, done, end, st, out, tool_lengths):
            for j in range(done, end):  # one by one: the general path says which is refused, and why
                execute(_plain_block(plain, j), int(plain.line[j]))
        done = end
        if k == len(blocks):
            break
        ln, b = blocks[k]
        if progress is not None and (k + done) // 5000 != shown:
            shown = (k + done) // 5000
            progress(ln - 1, total)
        execute(b, ln)
        if st.ended:
            break
    if progress is not None:
        progress(total, total)
    return out.result(source)


def _execute(b: _Block, st: _State, out: _Out, ln: int, any_m6: bool, tol: float,
             tool_lengths: Mapping[int, float] | None) -> None:
    # --- classify codes and check modal group conflicts
    groups: dict[int, int] = {}
    for code in b.g:
        if code in _G_REFUSED:
            raise GcodeError(_G_REFUSED[code])
        if code not in _G_GROUP:
            c = f"{code / 10:g}"
            if code == 730 or 810 <= code <= 890:
                raise GcodeError(f"canned cycle G{c} not supported")
            raise GcodeError(f"unsupported code G{c}")
        grp = _G_GROUP[code]
        if grp in groups:
            if grp == 1:
                raise GcodeError("two motion codes in one block")
            raise GcodeError(f"G{groups[grp] / 10:g} and G{code / 10:g} in one block are of the same modal group")
        groups[grp] = code
    mgroups: dict[int, int] = {}
    for code in b.m:
        if code not in _M_GROUP:
            raise GcodeError(f"unsupported code M{code}")
        grp = _M_GROUP[code]
        if grp in mgroups and not {mgroups[grp], code} <= {7, 8}:
            raise GcodeError(f"M{mgroups[grp]} and M{code} in one block are of the same modal group")
        mgroups[grp] = code
    w = b.words
    used: set[str] = set()

    # --- F S T, tool change (RS274/NGC order of execution)
    if "F" in w:
        if w["F"] < 0:
            raise GcodeError("negative feed rate")
        st.feed_raw = w["F"]
        used.add("F")
    if "S" in w:
        if w["S"] < 0:
            raise GcodeError("negative spindle speed")
        used.add("S")
    if "T" in w:
        t = w["T"]
        if t < 0 or t != int(t):
            raise GcodeError(f"tool number must be a whole number >= 0, got T{t:g}")
        st.selected_tool = int(t)
        if not any_m6:
            st.spindle_tool = st.selected_tool
        used.add("T")
    if 6 in b.m:
        st.spindle_tool = st.selected_tool

    # --- dwell
    if 40 in b.g:
        if "P" not in w or w["P"] < 0:
            raise GcodeError("G4 dwell needs P >= 0 (seconds)")
        used.add("P")

    # --- modal settings
    if groups.get(6) is not None:
        st.scale = MM_PER_INCH if groups[6] == 200 else 1.0
    if groups.get(8) == 430:
        h = w.get("H", float(st.spindle_tool))
        if h < 0 or h != int(h):
            raise GcodeError(f"H must be a whole number >= 0, got H{h:g}")
        if tool_lengths is not None and int(h) != 0 and int(h) not in tool_lengths:
            raise GcodeError(f"G43 H{int(h)}: no length known for tool {int(h)}")
        st.tlo_on, st.tlo_h = True, int(h)
        used.add("H")
    elif groups.get(8) == 490:
        st.tlo_on, st.tlo_h = False, 0
    if "H" in w and groups.get(8) != 430:
        raise GcodeError("H word without G43")
    if groups.get(13) == 640:
        used.update({"P", "Q"} & w.keys())
        if any(w.get(k, 0.0) < 0 for k in "PQ"):
            raise GcodeError("G64 P and Q must be >= 0")
    if groups.get(3) is not None:
        st.absolute = groups[3] == 900
    if groups.get(4) is not None:
        st.ijk_absolute = groups[4] == 901
    if groups.get(10) is not None:
        st.retract_to_r = groups[10] == 990
    if groups.get(1) is not None:
        if groups[1] in (810, 830) and st.motion not in (81, 83):
            st.cycle_clear = math.nan  # entering canned cycles: G98 remembers this block's start Z
        st.motion = None if groups[1] == 800 else groups[1] // 10

    axes = [a for a in "XYZ" if a in w]
    nonmodal = groups.get(0)
    if nonmodal in (280, 530):
        _retract(b, st, out, ln, nonmodal, axes, tool_lengths)
        used.update(axes)
    elif axes:
        if st.motion is None:
            raise GcodeError("axis words without a motion mode (G0, G1, G2 or G3)")
        if st.motion in (81, 83):
            _cycle(w, st, out, ln, tool_lengths, used)
        elif st.motion in (2, 3):
            _arc(w, st, out, ln, tol, tool_lengths, used)
        else:
            _line(w, st, out, ln, tool_lengths)
        used.update(axes)

    for k in ("I", "J", "R"):
        if k in w and k not in used:
            raise GcodeError(f"{k} word with no G2 or G3 arc to use it")
    if "K" in w:
        raise GcodeError("K word not allowed: only XY-plane arcs (G17) supported")
    if "P" in w and "P" not in used:
        raise GcodeError("P word with nothing to use it (G4, G64 or an arc)")
    if "Q" in w and "Q" not in used:
        raise GcodeError("Q word with nothing to use it (G64)")

    if mgroups.get(4) in (2, 30):
        st.ended = True


def _tip_shift(st: _State, tool_lengths: Mapping[int, float] | None) -> float:
    """Tip Z minus programmed Z [mm]."""
    if tool_lengths is None:
        return 0.0
    cur = st.spindle_tool
    if cur != 0 and cur not in tool_lengths:
        raise GcodeError(f"no length known for tool {cur} in the spindle")
    if st.tlo_on and st.tlo_h != 0 and st.tlo_h not in tool_lengths:
        raise GcodeError(f"no length known for H{st.tlo_h}")
    comp = float(tool_lengths[st.tlo_h]) if st.tlo_on and st.tlo_h != 0 else 0.0
    return comp - (float(tool_lengths[cur]) if cur != 0 else 0.0)


def _target(w: Mapping[str, float], st: _State) -> np.ndarray:
    """Programmed end point [mm] of a move with the block's X Y Z words."""
    tgt = st.pos.copy()
    for i, a in enumerate("XYZ"):
        if a not in w:
            continue
        v = w[a] * st.scale
        if st.absolute:
            tgt[i] = v
        else:
            if math.isnan(tgt[i]):
                raise GcodeError(f"incremental {a} move (G91) from an unknown position")
            tgt[i] = tgt[i] + v
        if not abs(tgt[i]) <= MAX_COORDINATE:
            raise GcodeError(f"{a} {tgt[i]:.6g} mm is out of range (|{a}| <= {MAX_COORDINATE:g} mm)")
    return tgt


def _feed(st: _State) -> float:
    if st.feed_raw is None or st.feed_raw <= 0:
        raise GcodeError(f"G{st.motion} without a feed rate (F)")
    return st.feed_raw * st.scale


def _record(out: _Out, pts: np.ndarray, motion: int, st: _State, feed: float, ln: int) -> None:
    out.add(pts, motion, st.spindle_tool, feed, ln)
    if len(pts) == 1:
        z = float(pts[0, 2])
        if z > st.top:  # False for NaN
            st.top = z
    elif np.isfinite(pts[:, 2]).any():
        st.top = max(st.top, float(np.nanmax(pts[:, 2])))


def _line(w: Mapping[str, float], st: _State, out: _Out, ln: int,
          tool_lengths: Mapping[int, float] | None) -> None:
    tgt = _target(w, st)
    if st.motion == 0:
        motion, feed = Motion.RAPID, math.nan
    else:
        motion, feed = Motion.CUT, _feed(st)
    shift = _tip_shift(st, tool_lengths)
    st.pos = tgt
    _record(out, (tgt + [0.0, 0.0, shift])[None, :], motion, st, feed, ln)


def _arc(w: Mapping[str, float], st: _State, out: _Out, ln: int, tol: float,
         tool_lengths: Mapping[int, float] | None, used: set[str]) -> None:
    if "X" not in w and "Y" not in w:
        raise GcodeError(f"G{st.motion} arc needs an X or Y word")
    feed = _feed(st)
    start = st.pos
    if np.isnan(start[:2]).any():
        raise GcodeError("arc from an unknown X/Y position")
    tgt = _target(w, st)
    if "Z" in w and math.isnan(start[2]):
        raise GcodeError("helical arc from an unknown Z position")
    cw = st.motion == 2
    has_ij = "I" in w or "J" in w
    turns = 1
    if "P" in w:
        p = w["P"]
        if p < 1 or p != int(p):
            raise GcodeError(f"arc P (turns) must be a whole number >= 1, got P{p:g}")
        turns = int(p)
        used.add("P")
    sx, sy = float(start[0]), float(start[1])
    ex, ey = float(tgt[0]), float(tgt[1])
    if "R" in w:
        if has_ij:
            raise GcodeError("arc with both R and I/J")
        used.add("R")
        r = w["R"] * st.scale
        half = 0.5 * math.hypot(ex - sx, ey - sy)
        if half < ZERO_RADIUS_TOLERANCE:
            raise GcodeError("R-format arc with the end point equal to the start point")
        if abs(r) < ZERO_RADIUS_TOLERANCE:
            raise GcodeError("zero-radius arc")
        if abs(r) < half - ZERO_RADIUS_TOLERANCE:
            raise GcodeError(f"arc radius R{abs(r):.4f} mm too small to reach the end point")
        h = math.sqrt(max(r * r - half * half, 0.0))
        ux, uy = (ex - sx) / (2 * half), (ey - sy) / (2 * half)
        # Short arc (R > 0): the centre lies right of the chord for G2, left for G3.
        sign = (1.0 if cw else -1.0) * (1.0 if r > 0 else -1.0)
        cx = 0.5 * (sx + ex) + sign * h * uy
        cy = 0.5 * (sy + ey) - sign * h * ux
    elif has_ij:
        used.update({"I", "J"} & w.keys())
        i = w.get("I", 0.0) * st.scale
        j = w.get("J", 0.0) * st.scale
        if st.ijk_absolute:
            cx, cy = i, j  # as LinuxCNC: a centre word left out is 0
        else:
            cx, cy = sx + i, sy + j
        if not (abs(cx) <= MAX_COORDINATE and abs(cy) <= MAX_COORDINATE):
            raise GcodeError("arc centre out of range")
        r1 = math.hypot(sx - cx, sy - cy)
        r2 = math.hypot(ex - cx, ey - cy)
        if r1 < ZERO_RADIUS_TOLERANCE or r2 < ZERO_RADIUS_TOLERANCE:
            raise GcodeError("zero-radius arc")
        err = abs(r1 - r2)
        if err > SPIRAL_ABS_TOLERANCE * 100.0 or (err / max(r1, r2) > SPIRAL_REL_TOLERANCE and err > SPIRAL_ABS_TOLERANCE):
            raise GcodeError(f"radius to end of arc differs from radius to start: r1={r1:.4f} r2={r2:.4f} mm")
    else:
        raise GcodeError(f"G{st.motion} arc needs I/J or R")
    centre = np.array([cx, cy])
    sweep = float(arc_sweep(np.array([sx, sy]), np.array([ex, ey]), centre, cw, turns))
    shift = _tip_shift(st, tool_lengths)
    sh = np.array([0.0, 0.0, shift])
    pts = discretize_arc(start + sh, tgt + sh, centre, sweep, tol)
    st.pos = tgt
    _record(out, pts, Motion.CUT, st, feed, ln)


#: How far above the previous peck's depth G83 rapids back down [mm] (LinuxCNC: 0.010 inch).
PECK_CLEARANCE = 0.254


def _cycle(w: Mapping[str, float], st: _State, out: _Out, ln: int,
           tool_lengths: Mapping[int, float] | None, used: set[str]) -> None:
    """One hole of a G81 (drill) or G83 (peck drill) cycle, moved as LinuxCNC moves it.

    Rapid over the hole at the higher of the current Z and the retract height, rapid down
    to R, feed to Z (G83: in pecks of Q, rapid out to R after each and back down to
    :data:`PECK_CLEARANCE` above the last depth), rapid out to R (G99) or to the Z the
    cycles began at (G98). Z, R and Q are sticky; incremental (G91) cycles and L repeats
    are refused.
    """
    if not st.absolute:
        raise GcodeError("canned cycles in incremental distance mode (G91) not supported")
    for k, name in (("Z", "cycle_z"), ("R", "cycle_r"), ("Q", "cycle_q")):
        if k in w:
            setattr(st, name, w[k] * st.scale)
            used.add(k)
    if math.isnan(st.cycle_z) or math.isnan(st.cycle_r):
        raise GcodeError(f"G{st.motion} needs Z (hole bottom) and R (retract plane)")
    if st.cycle_z > st.cycle_r:
        raise GcodeError(f"G{st.motion}: hole bottom Z{st.cycle_z:g} above the R plane R{st.cycle_r:g}")
    if st.motion == 83 and not st.cycle_q > 0:
        raise GcodeError("G83 needs a peck depth Q > 0")
    if st.motion == 81 and "Q" in w:
        raise GcodeError("Q word with G81 (pecks are G83)")
    if np.isnan(st.pos).any():
        raise GcodeError(f"G{st.motion} from an unknown position")
    feed = _feed(st)
    sh = np.array([0.0, 0.0, _tip_shift(st, tool_lengths)])
    x = w["X"] * st.scale if "X" in w else st.pos[0]
    y = w["Y"] * st.scale if "Y" in w else st.pos[1]
    r, bottom = st.cycle_r, st.cycle_z
    pts: list[tuple[np.ndarray, int, float]] = []

    def go(z: float, motion: int, xy=None) -> None:
        p = np.array([*(xy if xy is not None else (x, y)), z])
        pts.append((p, motion, feed if motion == Motion.CUT else math.nan))

    z = float(st.pos[2])
    if math.isnan(st.cycle_clear):
        if z < r:  # preliminary move up to the R plane
            pts.append((np.array([st.pos[0], st.pos[1], r]), Motion.RAPID, math.nan))
            z = r
        st.cycle_clear = z
    clear = r if st.retract_to_r else max(st.cycle_clear, r)
    over = max(z, clear)
    go(over, Motion.RAPID)
    if over != r:
        go(r, Motion.RAPID)
    if st.motion == 81:
        go(bottom, Motion.CUT)
    else:
        depth = r
        while depth > bottom:
            if depth < r:
                go(r, Motion.RAPID)
                go(depth + PECK_CLEARANCE, Motion.RAPID)
            depth -= st.cycle_q
            # a peck that ends within rounding of the bottom ends on it: no zero-depth peck after it
            if depth < bottom + 1e-9:
                depth = bottom
            go(depth, Motion.CUT)
    go(clear, Motion.RAPID)
    for p, motion, f in pts:
        st.pos = p
        _record(out, (p + sh)[None, :], motion, st, f, ln)


def _retract(b: _Block, st: _State, out: _Out, ln: int, code: int, axes: list[str],
             tool_lengths: Mapping[int, float] | None) -> None:
    """G53 / G28 with Z only: a straight-up move to the highest tip Z reached so far."""
    name = "G53" if code == 530 else "G28"
    if "X" in axes or "Y" in axes:
        raise GcodeError(f"{name} supported only for a Z retract (machine X/Y positions are unknown)")
    if not axes:
        raise GcodeError(f"{name} without Z: would move X and Y to an unknown machine position")
    for k in ("I", "J", "R", "K"):
        if k in b.words:
            raise GcodeError(f"{k} word not allowed with {name}")
    shift = _tip_shift(st, tool_lengths)
    sh = np.array([0.0, 0.0, shift])
    if code == 530:
        if st.motion not in (0, 1):
            raise GcodeError("G53 needs G0 or G1 motion")
        motion = Motion.RAPID if st.motion == 0 else Motion.CUT
        feed = math.nan if st.motion == 0 else _feed(st)
    else:
        motion, feed = Motion.RAPID, math.nan
        # G28 first goes to its intermediate point, in the current distance mode.
        # A zero increment from an unknown position (Fanuc's "G28 G91 Z0." at the
        # start of a program) is no move at all.
        words = {a: v for a, v in b.words.items() if a in "XYZ" and (st.absolute or v != 0.0)}
        mid = _target(words, st)
        if not np.array_equal(mid, st.pos, equal_nan=True) and not math.isnan(mid[2]):
            st.pos = mid
            _record(out, (mid + sh)[None, :], Motion.RAPID, st, feed, ln)
    if math.isfinite(st.top):
        tip_z = st.pos[2] + shift
        top = st.top if math.isnan(tip_z) else max(st.top, float(tip_z))
        pos = st.pos.copy()
        pos[2] = top - shift
        st.pos = pos
        _record(out, (pos + sh)[None, :], motion, st, feed, ln)
