"""When the machine makes each move of a program: the tool's position over time, and the stock as it is cut.

For playing a program back (``factory simulate`` logs it to Foxglove). The clock is the
post's cycle-time model (:func:`cadcam.post.move_seconds`, :func:`cadcam.post.tool_change_seconds`):
every move at constant speed, its programmed feed or the rapid rate, no acceleration; a
tool change is a pause. So a posted program's timeline lasts what
:func:`cadcam.post.post_process` estimated, up to what the G-code text rounds (coordinates,
feeds) and the chords the parser breaks arcs into (a little shorter than the arcs).

Two rules of that estimate shape the timeline:

* Coordinates the program has not yet set are taken to be where it first sets them: the
  tool starts there, and a move from an unknown position takes no time.
* A tool change sends the spindle somewhere the program does not say. The traverse that
  follows it, the rapids at constant Z up to the first move that changes Z, is counted in
  the change's time: it takes no time of its own.

``G4`` dwells and spindle or coolant switching take no time (the parser keeps no record of
them, and the estimate counts none).
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from cadcam.model import Motion, ProgramMoves, Setup, Tool, frozen_array
from cadcam.post import PostOptions, move_seconds, tool_change_seconds
from cadcam.stock import Simulation, cut_stock
from factory.core.errors import GcodeError, VerifyError

log = logging.getLogger(__name__)


class TimelineSamples(NamedTuple):
    """The tool sampled at a fixed rate.

    Attributes
    ----------
    times : (k,) float
        Sample times [s], from 0 to the end of the program (included).
    positions : (k, 3) float
        Tool tip position at each time, work coordinates [mm].
    tools : (k,) int
        Tool in the spindle at each time (0: none).
    """

    times: np.ndarray
    positions: np.ndarray
    tools: np.ndarray


@dataclass(frozen=True)
class MachineTimeline:
    """The moves of a program laid out in time.

    Move ``i`` goes from ``points[i - 1]`` to ``points[i]`` during ``[start[i], end[i]]``,
    at constant speed. Between ``end[i - 1]`` and ``start[i]`` the tool stands still (a
    tool change). Built by :func:`machine_timeline`.

    Attributes
    ----------
    points : (n, 3) float
        Tool tip after each move, work coordinates [mm], as :attr:`ProgramMoves.points`
        with the coordinates not yet programmed filled in (read-only).
    start, end : (n,) float
        Time each move begins and ends [s], non-decreasing; ``start[0] == end[0] == 0``
        for the position before the first move (read-only).
    tool : (n,) int32
        Tool in the spindle during each move (0: none) (read-only).
    line : (n,) int32
        1-based source line of each move (0 for ``points[0]``) (read-only).
    """

    points: np.ndarray
    start: np.ndarray
    end: np.ndarray
    tool: np.ndarray
    line: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "points", frozen_array(self.points, (3,)).reshape(-1, 3))
        for name in ("start", "end"):
            object.__setattr__(self, name, frozen_array(getattr(self, name)).reshape(-1))
        for name in ("tool", "line"):
            object.__setattr__(self, name, frozen_array(getattr(self, name), dtype=np.int32).reshape(-1))
        n = len(self.points)
        if n == 0 or not all(len(a) == n for a in (self.start, self.end, self.tool, self.line)):
            raise ValueError("MachineTimeline arrays must have the same, non-zero length")

    @property
    def duration(self) -> float:
        """Time from the start of the program to the end of its last move [s]."""
        return float(self.end[-1])

    @functools.cached_property
    def _knots(self) -> tuple[np.ndarray, np.ndarray]:
        """Times [s] and positions [mm] of the path's corners: (0, p0), (start1, p0), (end1, p1), ..."""
        t = np.empty(2 * len(self.points) - 1)
        t[0] = 0.0
        t[1::2] = self.start[1:]
        t[2::2] = self.end[1:]
        p = np.empty((len(t), 3))
        p[0] = self.points[0]
        p[1::2] = self.points[:-1]
        p[2::2] = self.points[1:]
        return t, p

    def move_at(self, t: np.ndarray | Sequence[float] | float) -> np.ndarray:
        """Index of the move under way at each time: the last one started by then.

        Parameters
        ----------
        t : (k,) float
            Times [s]; clamped to ``[0, duration]``.

        Returns
        -------
        (k,) int
            Index into :attr:`points` (0 before the first move starts). During a pause
            (tool change) the move before it.
        """
        t = np.clip(np.asarray(t, dtype=np.float64).reshape(-1), 0.0, self.duration)
        return np.maximum(np.searchsorted(self.start, t, side="right") - 1, 0)

    def position_at(self, t: np.ndarray | Sequence[float] | float) -> np.ndarray:
        """Tool tip position at each time, interpolated along the moves.

        Parameters
        ----------
        t : (k,) float
            Times [s]; clamped to ``[0, duration]``.

        Returns
        -------
        (k, 3) float
            Positions [mm]. Where moves take no time (see the module docstring) the
            position jumps; at that instant it is the one after the jump.
        """
        t = np.clip(np.asarray(t, dtype=np.float64).reshape(-1), 0.0, self.duration)
        kt, kp = self._knots
        if len(kt) == 1:
            return np.repeat(kp, len(t), axis=0)
        k = np.clip(np.searchsorted(kt, t, side="right") - 1, 0, len(kt) - 2)
        t0, t1 = kt[k], kt[k + 1]
        span = t1 - t0
        f = np.where(span > 0, (t - t0) / np.where(span > 0, span, 1.0), 1.0)
        f = np.clip(f, 0.0, 1.0)[:, None]
        a, b = kp[k], kp[k + 1]
        # Exact at the corners and while standing still.
        return np.where(f < 1.0, a + f * (b - a), b)

    def tool_at(self, t: np.ndarray | Sequence[float] | float) -> np.ndarray:
        """Tool in the spindle at each time.

        Parameters
        ----------
        t : (k,) float
            Times [s]; clamped to ``[0, duration]``.

        Returns
        -------
        (k,) int
            Tool number (0: none). During a tool change, the tool being replaced.
        """
        return self.tool[self.move_at(t)]

    def sample(self, rate_hz: float) -> TimelineSamples:
        """The tool at a fixed rate, from 0 to the end of the program.

        Parameters
        ----------
        rate_hz : float
            Samples per second [Hz], > 0.

        Returns
        -------
        TimelineSamples
            Samples at ``i / rate_hz`` before ``duration``, then one at ``duration``.

        Raises
        ------
        ValueError
            ``rate_hz`` not a positive finite number.
        """
        if not (np.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be a positive number of samples per second, got {rate_hz}")
        times = np.arange(int(np.ceil(self.duration * rate_hz)) + 1) / rate_hz
        times = np.append(times[times < self.duration], self.duration)
        return TimelineSamples(times, self.position_at(times), self.tool_at(times))


def _filled(points: np.ndarray) -> np.ndarray:
    """Each unknown (NaN) coordinate set to the axis's previous known value, else its next one."""
    out = np.array(points, dtype=np.float64)
    n = len(out)
    idx = np.arange(n)
    for axis, name in enumerate("XYZ"):
        known = np.isfinite(out[:, axis])
        if not known.any():
            raise GcodeError(f"the program never sets {name}: the tool's position is unknown")
        prev = np.maximum.accumulate(np.where(known, idx, -1))
        nxt = np.minimum.accumulate(np.where(known, idx, n)[::-1])[::-1]
        out[:, axis] = out[np.where(prev >= 0, prev, nxt), axis]
    return out


def machine_timeline(moves: ProgramMoves, options: PostOptions = PostOptions()) -> MachineTimeline:
    """Lay a program's moves out in time by the post's cycle-time model.

    Parameters
    ----------
    moves : ProgramMoves
        From :func:`cadcam.gcode.parse_gcode` [mm].
    options : PostOptions
        ``rapid_rate`` [mm/min], ``tool_change_time`` [s] and ``dialect`` (grbl's first
        tool is loaded before the start): pass the ones the program was posted with.

    Returns
    -------
    MachineTimeline
        Lasting, for a program :func:`cadcam.post.post_process` wrote, its
        ``Program.total_time`` (see the module docstring for what differs).

    Raises
    ------
    GcodeError
        The program never sets one of X, Y, Z; a feed move without a positive feed.
    """
    points = _filled(moves.points)
    motion = moves.motion[1:]
    rapid = motion == Motion.RAPID
    feed = np.where(rapid, np.nan, moves.feed[1:])
    bad = ~rapid & ~(feed > 0)
    if bad.any():
        line = int(moves.line[1 + int(np.flatnonzero(bad)[0])])
        raise GcodeError(f"line {line}: feed move without a positive feed", source=moves.source, line=line)
    step = np.diff(points, axis=0)
    seconds = move_seconds(np.linalg.norm(step, axis=1), feed, options.rapid_rate)

    pause = np.zeros(len(seconds))
    changes = np.flatnonzero(moves.tool[1:] != moves.tool[:-1])  # move i + 1 runs with a new tool
    level = step[:, 2] == 0.0
    for k, i in enumerate(changes.tolist()):
        pause[i] = tool_change_seconds(k == 0, options)
        # The traverse after the change: rapids at constant Z, up to the first Z move.
        stop = i
        while stop < len(seconds) and rapid[stop] and level[stop]:
            stop += 1
        seconds[i:stop] = 0.0

    # start[i] = end[i - 1] + pause, end[i] = start[i] + duration, as one running sum.
    steps = np.empty(2 * len(seconds))
    steps[0::2] = pause
    steps[1::2] = seconds
    clock = np.concatenate([[0.0], np.cumsum(steps)])
    start = np.concatenate([[0.0], clock[1::2]])
    end = clock[0::2]
    log.debug("timeline: %d moves, %d tool changes, %.1f s", len(seconds), len(changes), end[-1])
    return MachineTimeline(points=points, start=start, end=end, tool=moves.tool, line=moves.line)


def stock_snapshots(
    moves: ProgramMoves,
    tools: Mapping[int, Tool],
    setup: Setup,
    part_triangles: np.ndarray,
    times_s: Sequence[float],
    cell: float = 1.0,
    *,
    timeline: MachineTimeline | None = None,
) -> tuple[tuple[float, Simulation], ...]:
    """The stock as the program leaves it at each of several times, in one simulation pass.

    Parameters
    ----------
    moves : ProgramMoves
        The program [mm].
    tools : mapping of int to Tool
        Tools by number, for every tool the program uses.
    setup : Setup
        The stock box in work coordinates [mm].
    part_triangles : (m, 3, 3) float
        The part in work coordinates [mm].
    times_s : (s,) sequence of float
        Times on the timeline [s], any order.
    cell : float
        Grid spacing [mm] (:attr:`cadcam.verify.VerifyOptions.cell`).
    timeline : MachineTimeline, optional
        The program's timeline; default :func:`machine_timeline` with default post options.

    Returns
    -------
    tuple of s (time [s], Simulation)
        In the order of ``times_s``: the stock after every move that has started by that
        time (a move under way counts as done), with the volume each of those moves removed
        (:attr:`Simulation.removed_volume`). All share one grid and ``part_top``.

    Raises
    ------
    VerifyError
        As :func:`cadcam.stock.cut_stock`; a timeline of another program; a time that is
        not finite.
    GcodeError
        As :func:`machine_timeline`.
    """
    if timeline is None:
        timeline = machine_timeline(moves)
    elif len(timeline.points) != len(moves.points):
        raise VerifyError(f"the timeline has {len(timeline.points)} points, the program {len(moves.points)}",
                          source="timeline")
    times = np.asarray(times_s, dtype=np.float64).reshape(-1)
    if not np.isfinite(times).all():
        raise VerifyError("snapshot times must be finite numbers of seconds", source="times_s")
    at = timeline.move_at(times)
    cut = cut_stock(moves, tools, setup, part_triangles, cell, snapshot_moves=at)
    sim, tops = cut.simulation, cut.snapshots
    out = []
    for t, top, last in zip(times.tolist(), tops, at.tolist()):
        # the volume each move removed, of the moves done by then
        removed = np.where(np.arange(len(sim.removed_volume)) <= last, sim.removed_volume, 0.0)
        removed.setflags(write=False)
        out.append((float(t), Simulation(grid=sim.grid, stock_top=top, part_top=sim.part_top,
                                         stock_bottom=sim.stock_bottom, floor_z=sim.floor_z,
                                         removed_volume=removed)))
    return tuple(out)
