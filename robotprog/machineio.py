"""The machine tool's digital interface, defined once: its signals and the handshake on them.

A tending cell talks to the mill through a few digital signals (the numbers are the cell file's
``machine.io``, :class:`robotprog.cell.MachineIO`). This module is the one definition of
*which* signals there are, which way each goes, and in what order the robot sets and waits on
them. Both consumers read it:

* :mod:`robotprog.programs` posts the operations as program steps (:func:`to_steps`) in
  URScript, RAPID and KRL;
* the cell simulation's log shows the same operations at the times its machine and robot
  reach them (:func:`signal_timeline` over :class:`robotprog.cellsim.Activity`), so a program
  and the simulation cannot disagree on the handshake; :func:`posted_signals` reads the
  operations back out of posted steps, so a test can compare the two.

The handshake for one part (:func:`part_signals`):

1. **ready** (before the first load): wait until the machine is idle (``cycle_done`` high),
   open the door, wait until it is open;
2. **cycle** (after each load; twice for a part flipped between op 1 and op 2): close the
   door, wait until it is closed, raise ``cycle_start``, wait until the machine runs
   (``cycle_done`` low), lower ``cycle_start``, wait for ``cycle_done``, open the door, wait
   until it is open;
3. **verdict** (after the retreat from the vise with the finished part): read ``part_ok`` once
   and take the part to the out-tray (high) or to the reject bin (low).

``part_ok`` is the machine's in-process verdict (probing, tool-breakage check), valid while
``cycle_done`` is high; the out-tray camera's inspection is a second, later check.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from factory.core.errors import PlanningError

OUTPUT = "output"
INPUT = "input"


@dataclass(frozen=True)
class Signal:
    """One digital signal between the robot controller and the machine.

    Attributes
    ----------
    name : str
        The field of :class:`robotprog.cell.MachineIO` holding its number.
    direction : str
        :data:`OUTPUT` (the robot sets it) or :data:`INPUT` (the robot reads it).
    meaning : str
        What a high level means.
    """

    name: str
    direction: str
    meaning: str


#: Every signal of the machine interface, by name.
SIGNALS: Mapping[str, Signal] = MappingProxyType({s.name: s for s in (
    Signal("open_door", OUTPUT, "held high to open the door"),
    Signal("close_door", OUTPUT, "held high to close the door"),
    Signal("cycle_start", OUTPUT, "raised to start the cycle, lowered once the machine runs"),
    Signal("door_open", INPUT, "the door is fully open (low: closed)"),
    Signal("cycle_done", INPUT, "the machine is idle with its cycle finished (low: running)"),
    Signal("part_ok", INPUT, "the finished part passed the machine's inspection (valid while cycle_done is high)"),
)})

SET, WAIT, READ = "set", "wait", "read"


@dataclass(frozen=True)
class IoOp:
    """One operation on a signal: ``set`` an output to ``level``, ``wait`` until an input reads
    ``level``, or ``read`` an input once and branch on it (``level``: the reading that takes the
    usual way, the out-tray). ``label`` becomes the program's comment."""

    op: str
    signal: str
    level: bool
    label: str = ""

    @property
    def key(self) -> tuple[str, str, bool]:
        """What the operation does, without its label (for comparing sequences)."""
        return (self.op, self.signal, self.level)


def door(open_: bool) -> tuple[IoOp, ...]:
    """Drive the door open (or closed) and wait until it is."""
    if open_:
        return (IoOp(SET, "close_door", False, "machine: open the door"), IoOp(SET, "open_door", True),
                IoOp(WAIT, "door_open", True, "machine: wait for the door open"))
    return (IoOp(SET, "open_door", False, "machine: close the door"), IoOp(SET, "close_door", True),
            IoOp(WAIT, "door_open", False, "machine: wait for the door closed"))


def machine_ready() -> tuple[IoOp, ...]:
    """Wait for the machine to be idle, then open its door and wait until it is open."""
    return (IoOp(WAIT, "cycle_done", True, "machine: wait until idle"), *door(True))


#: How many operations of :func:`machine_cycle` happen when the cycle starts; the rest when it ends.
CYCLE_START_OPS = 5
#: Outcomes of a simulated cut that never raise ``cycle_done`` (any other, ``cycle_done`` or op 1's
#: ``op_done`` of a part in two setups, ends the cycle).
UNFINISHED_CUT = frozenset({"machine_alarm", "timeout"})


def machine_cycle() -> tuple[IoOp, ...]:
    """Close the door, start the cycle (raised until the machine runs), wait for it to finish, open
    the door: the handshake waits on the machine's inputs, never on a guessed time."""
    return (*door(False),
            IoOp(SET, "cycle_start", True, "machine: start the cycle"),
            IoOp(WAIT, "cycle_done", False, "machine: wait until it runs"),
            IoOp(SET, "cycle_start", False),
            IoOp(WAIT, "cycle_done", True, "machine: wait for the cycle done"),
            *door(True))


def verdict() -> IoOp:
    """Read the machine's verdict on the finished part: high to the out-tray, low to the reject bin."""
    return IoOp(READ, "part_ok", True, "inspection: a good part goes to the out-tray, a bad one to the reject bin")


def part_signals(cycles: int = 1, with_verdict: bool = True) -> tuple[IoOp, ...]:
    """The handshake for one part: ready, ``cycles`` machine cycles (2 for a part flipped between
    op 1 and op 2), and the verdict read before the part leaves the machine."""
    if cycles < 1:
        raise PlanningError(f"a part needs at least one machine cycle, got {cycles}")
    return (*machine_ready(), *(machine_cycle() * cycles), *((verdict(),) if with_verdict else ()))


def number(io: Any, signal: str) -> int:
    """The controller's number of ``signal`` in ``io`` (a :class:`robotprog.cell.MachineIO`).

    Raises
    ------
    PlanningError
        An unknown signal, or one the cell file does not wire (``machine.io``).
    """
    if signal not in SIGNALS:
        raise PlanningError(f"no machine signal {signal!r}; the signals are {', '.join(SIGNALS)}")
    n = getattr(io, signal, None)
    if n is None:
        raise PlanningError(f"the cell wires no {SIGNALS[signal].direction} {signal!r}",
                            source=f"machine.io.{SIGNALS[signal].direction}s.{signal}")
    return int(n)


def to_steps(ops: Iterable[IoOp], io: Any) -> list[Any]:
    """Program steps for ``ops`` with the cell's signal numbers: consecutive ``set`` operations
    become one :class:`~robotprog.urscript.SetOutputs` (labelled by the first), each ``wait`` a
    :class:`~robotprog.urscript.WaitInput`. A ``read`` branches, so :mod:`robotprog.programs` posts it."""
    from robotprog.urscript import SetOutputs, WaitInput

    steps: list[Any] = []
    group: list[IoOp] = []

    def flush() -> None:
        if group:
            steps.append(SetOutputs(tuple((number(io, o.signal), o.level) for o in group), 0.0, group[0].label))
            group.clear()

    for o in ops:
        if o.op == SET:
            group.append(o)
            continue
        flush()
        if o.op == WAIT:
            steps.append(WaitInput(number(io, o.signal), o.level, o.label))
        else:
            raise PlanningError(f"a {o.op!r} of {o.signal} is a branch, not a step")
    flush()
    return steps


def posted_signals(steps: Sequence[Any], io: Any, *, verdict_level: bool = True) -> tuple[IoOp, ...]:
    """The machine operations in posted ``steps``, in program order (outputs the gripper drives are
    left out; a branch on an input is a ``read`` and the run goes on in the branch taken when it
    reads ``verdict_level``)."""
    from robotprog.urscript import Branch, SetOutputs, WaitInput

    outs = {number(io, s.name): s.name for s in SIGNALS.values()
            if s.direction == OUTPUT and getattr(io, s.name, None) is not None}
    ins = {number(io, s.name): s.name for s in SIGNALS.values()
           if s.direction == INPUT and getattr(io, s.name, None) is not None}
    out: list[IoOp] = []
    for st in steps:
        if isinstance(st, SetOutputs):
            out += [IoOp(SET, outs[n], level) for n, level in st.outputs if n in outs]
        elif isinstance(st, WaitInput) and st.input in ins:
            out.append(IoOp(WAIT, ins[st.input], st.level))
        elif isinstance(st, Branch) and st.input in ins:
            out.append(IoOp(READ, ins[st.input], verdict_level))
            taken = st.then if verdict_level == st.level else st.otherwise
            out += posted_signals(taken, io, verdict_level=verdict_level)
    return tuple(out)


#: The simulation's robot activities that take a finished part out of the vise: to the out-tray
#: (the verdict read high) and to the reject bin (low).
UNLOADS = ("unload", "unload_reject")


@dataclass(frozen=True)
class SignalEvent:
    """A machine-interface operation at a simulated time: ``time`` [s], the ``job`` (part) it is for."""

    time: float
    job: int
    op: IoOp


def signal_timeline(activities: Iterable[Any]) -> tuple[SignalEvent, ...]:
    """The handshake of :func:`part_signals` at the times a cell simulation reaches it, from its
    activities (:class:`robotprog.cellsim.Activity`, any order):

    * *ready* when the robot starts a job's first ``load``;
    * a *cycle*'s first :data:`CYCLE_START_OPS` operations when the machine starts a ``cut``, the
      rest when the cut ends with its program done (an alarm or a timeout leaves the robot waiting);
      a part in two setups has two cuts, op 1's before the flip and op 2's before the unload;
    * the *verdict* when the robot starts a job's last ``unload`` (``part_ok`` high: on to the
      out-tray) or ``unload_reject`` (low: the reject branch to the bin).

    Returns the events sorted by time (operations of one instant in handshake order).
    """
    acts = sorted(activities, key=lambda a: (a.start, a.end))
    loaded: set[int] = set()
    unloads = {a.job: a for a in acts if a.resource == "robot" and a.action in UNLOADS}
    out: list[tuple[float, int, SignalEvent]] = []
    cycle = machine_cycle()

    def add(t: float, job: int, ops: Iterable[IoOp]) -> None:
        for o in ops:
            out.append((t, len(out), SignalEvent(t, job, o)))

    for a in acts:
        if a.resource == "robot" and a.action == "load" and a.job not in loaded:
            loaded.add(a.job)
            add(a.start, a.job, machine_ready())
        elif a.resource == "machine" and a.action == "cut":
            add(a.start, a.job, cycle[:CYCLE_START_OPS])
            if a.outcome not in UNFINISHED_CUT and math.isfinite(a.end):
                add(a.end, a.job, cycle[CYCLE_START_OPS:])
        elif a.resource == "robot" and a.action in UNLOADS and unloads.get(a.job) is a:
            v = verdict()
            add(a.start, a.job, (IoOp(READ, v.signal, a.action == "unload", v.label),))
    return tuple(e for _, _, e in sorted(out, key=lambda x: (x[0], x[1])))
