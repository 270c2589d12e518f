"""Discrete-event simulation of the tending cell, much faster than real time.

Orders run through :mod:`robotprog.scheduler`'s state machine; this module decides *when*
each event happens. Time is simulated seconds, kept in a ``heapq`` of pending events.
Durations come from a :class:`PartProcess` per part (the CLI fills them from ``factory plan``:
robot moves timed with TOPP-RA, machining from the setup sheet's ``estimated_cycle_s``,
camera steps from locate and inspect on rendered frames).

The cell modelled is the one ``factory plan`` programs: one robot with one gripper, a rack of
blanks, the machine's vise, an out-tray, and two fixed cameras, one over the rack (locate)
and one over the out-tray (inspect). There is no staging nest, so a blank the robot picks
goes straight into the vise.

Resources and actions
---------------------
- **Robot** (one action at a time): ``locate_and_pick`` (the rack camera locates the blank,
  then the robot picks it: the load phase up to the retreat from the rack), ``load`` (the
  rest of the load phase: into the vise and back home), ``flip`` (a part in two setups, between
  op 1 and op 2: vise → flip station, turned over → vise, home), ``unload`` (the unload phase:
  vise → out-tray and home), ``unload_reject`` (a part the machine's verdict fails, or scrap: the
  unload up to the verdict, then the posted program's reject branch, vise → reject bin → home).
- **Machine**: holds one part from the start of its load to the end of its unload and cuts it
  in between (a part in two setups: op 1, the flip, op 2; each cut is one activity, its
  :attr:`Activity.op` the operation).
- **Inspection camera**: inspects a good part in the out-tray while the robot works on; it
  stays where it is (``sort_good`` takes no time). A rejected part never reaches the out-tray:
  the verdict was read before it left the vise (``in_bin`` takes no time either).

A new blank is picked only when the machine is empty (the gripper cannot hold a blank and
unload a part), so in steady state a part leaves every ``locate_s + fetch_s + load_s +
machining_s + unload_s`` seconds (two setups: ``+ flip_s + op2_machining_s``), and inspection and rejects overlap the next cut.

Faults are drawn from a seeded RNG (:class:`FaultModel`), so a run is reproducible.
"""

from __future__ import annotations

import heapq
import math
import logging
import random
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from factory.core.errors import SchedulerError

from .machineio import SignalEvent, signal_timeline
from .oee import DowntimeLedger, Loss, OeeCounter, run_oee
from .orders import Order
from .scheduler import CellState, Event, Fault, SchedulerOptions, State, admit, initial_state, step

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PartProcess:
    """Durations [s] of every step for one part.

    Attributes
    ----------
    fetch_s : float
        Robot: home → pick the blank in the rack → retreat from the rack (load phase, first part).
    load_s : float
        Robot: the rest of the load phase: into the vise, release, back home.
    machining_s : float
        Machine: the program (setup sheet ``estimated_cycle_s``).
    unload_s : float
        Robot: the unload phase: home → vise → out-tray → home.
    locate_s : float
        Rack camera: one picture and locate of the blank.
    inspect_s : float
        Out-tray camera: one picture and inspection of the part.
    reject_s : float
        Robot: a rejected part's unload, the posted program's reject way: the unload phase up to
        the verdict (after the retreat from the vise), then vise → reject bin → home.
    regrasp_s : float
        Robot: back from above the rack to home after a missed grasp (the retry starts at home).
    flip_s : float
        Robot: the flip phase between op 1 and op 2 (0 for a part in one setup).
    op2_machining_s : float or None
        Machine: the op-2 program; ``None``: the part is machined in one setup (``machining_s``).
    """

    fetch_s: float
    load_s: float
    machining_s: float
    unload_s: float
    locate_s: float
    inspect_s: float
    reject_s: float
    regrasp_s: float = 0.0
    flip_s: float = 0.0
    op2_machining_s: float | None = None

    def __post_init__(self):
        for name in ("fetch_s", "load_s", "machining_s", "unload_s", "locate_s", "inspect_s", "reject_s",
                     "regrasp_s", "flip_s") + (("op2_machining_s",) if self.op2_machining_s is not None else ()):
            value = getattr(self, name)
            if not (value >= 0 and value != float("inf")):
                raise SchedulerError(f"{name} must be a finite duration >= 0 s, got {value}", source=name)

    @property
    def setups(self) -> int:
        """Operations per part: 1, or 2 (op 1, flip, op 2)."""
        return 1 if self.op2_machining_s is None else 2

    def machining(self, op: int) -> float:
        """Program time [s] of operation ``op`` (1 or 2)."""
        return self.machining_s if op == 1 or self.op2_machining_s is None else self.op2_machining_s

    @property
    def robot_s(self) -> float:
        """Robot busy time [s] per good part without faults (waiting for the rack camera included)."""
        return self.locate_s + self.fetch_s + self.load_s + self.flip_s + self.unload_s

    @property
    def machine_s(self) -> float:
        """Time [s] the machine holds one part: load + machining (op 1, flip, op 2) + unload."""
        return self.load_s + self.machining_s + self.flip_s + (self.op2_machining_s or 0.0) + self.unload_s

    @property
    def cycle_s(self) -> float:
        """Time [s] between finished parts in steady state without faults."""
        return self.locate_s + self.fetch_s + self.machine_s

    @property
    def ideal_cycle_s(self) -> float:
        """The OEE ideal cycle [s]: the steady-state cycle by the faster of the part's two ways out
        of the vise (to the out-tray, or a rejected part's way to the bin). A part made by either
        way takes at least this long, so the performance term never exceeds 1."""
        return self.cycle_s - self.unload_s + min(self.unload_s, self.reject_s)


@dataclass(frozen=True)
class FaultModel:
    """Per-attempt probabilities of each injected fault, in [0, 1].

    Attributes
    ----------
    grasp_miss : float
        Per grasp of a blank in the rack.
    stock_not_found : float
        Per camera locate of a blank.
    machine_alarm : float
        Per program run (the alarm stops the program at a uniformly drawn point).
    inspect_fail : float
        Per finished part: the machine's verdict (``part_ok``) fails it, read on unloading.
    seed : int
        RNG seed: the same seed gives the same run.
    """

    grasp_miss: float = 0.0
    stock_not_found: float = 0.0
    machine_alarm: float = 0.0
    inspect_fail: float = 0.0
    seed: int = 0

    def __post_init__(self):
        for name in ("grasp_miss", "stock_not_found", "machine_alarm", "inspect_fail"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise SchedulerError(f"{name} must be a probability in [0, 1]", source=name)

    @classmethod
    def default(cls, seed: int) -> "FaultModel":
        """The ``--faults SEED`` model: 5 % missed grasps, 5 % stock not found, 3 % alarms, 5 % rejects."""
        return cls(grasp_miss=0.05, stock_not_found=0.05, machine_alarm=0.03, inspect_fail=0.05, seed=seed)


NO_FAULTS = FaultModel()


@dataclass(frozen=True)
class LogEntry:
    """One line of the event log: ``state`` is the job's state after ``event``."""

    time: float
    job: int
    order: str
    state: str
    event: str
    message: str = ""


@dataclass(frozen=True)
class Activity:
    """One stretch of work by one resource.

    Attributes
    ----------
    resource : str
        ``"robot"``, ``"machine"`` or ``"camera"``.
    action : str
        Robot: ``fetch``, ``missed_grasp``, ``load``, ``flip``, ``unload``, ``unload_reject``;
        machine: ``cut``, ``reset``; camera: ``locate``, ``inspect``.
    job : int
    start, end : float
        Simulated time [s].
    outcome : str
        The event the activity ended with (``fetched``, ``machine_alarm``, ``inspect_fail``, …).
    fraction : float
        Share of the step's nominal motion or program carried out (a cut stopped by an alarm,
        a timed-out move), in [0, 1].
    slot : int or None
        The rack slot the step works at (``locate``, ``fetch``, ``missed_grasp``), else None.
    op : int or None
        The operation of a part in two setups a ``cut`` (1 or 2) or its ``reset`` belongs to;
        None for a part in one setup and for the other actions.
    pick : int or None
        With a :data:`PickSource`: the :attr:`PickStep.index` of the located blank a ``locate``,
        ``fetch`` or ``missed_grasp`` works on, else None.
    """

    resource: str
    action: str
    job: int
    start: float
    end: float
    outcome: str
    fraction: float = 1.0
    slot: int | None = None
    op: int | None = None
    pick: int | None = None


@dataclass(frozen=True)
class PickStep:
    """What the rack camera made of one blank, and the grasp it leads to (a :data:`PickSource`'s answer).

    Attributes
    ----------
    index : int
        The source's number for this picture of this blank (:attr:`Activity.pick`).
    fetch_s : float
        Robot: home → the corrected pick → back over the slot [s] (instead of :attr:`PartProcess.fetch_s`).
    refusal : str
        Why no grasp is attempted (the blank not located confidently, or its corrected pick not
        proven); '' when the grasp goes ahead.
    message : str
        What the fetch's log entry says (the offset, the located pose, the correction).
    """

    index: int
    fetch_s: float
    refusal: str = ""
    message: str = ""


#: Asked at each locate of a blank with (job, the part's process key, rack slot): the closed loop
#: of the rack camera and the grasp (:mod:`factory.rackloop`). A refusal stops the robot with a
#: ``stock_not_found`` fault and its reason; no grasp is attempted.
PickSource = Callable[[int, Any, int], PickStep]


@dataclass(frozen=True)
class OrderOutcome:
    order: str
    part: str
    quantity: int
    good: int
    rejected: int
    outcome: str
    reason: str


#: What the simulation tells an :data:`EventSink`, in the order it decides them: a transition
#: (:class:`LogEntry`), a stretch of work with its end already known (:class:`Activity`, told when
#: it starts), an order's outcome (:class:`OrderOutcome`, told when the order ends, and again with
#: new counts when a part still under way then is sorted: the last one told is the final one).
CellEvent = LogEntry | Activity | OrderOutcome
#: Called once per :data:`CellEvent` as the simulation goes (a process record, a live view); what it
#: raises stops the simulation.
EventSink = Callable[[CellEvent], None]


@dataclass(frozen=True)
class SimulationResult:
    """What a simulation produced.

    Attributes
    ----------
    log : tuple of LogEntry
        Every transition, in time order.
    outcomes : tuple of OrderOutcome
        One per order, each ``done``, ``rejected`` or ``failed`` with a reason.
    summary : dict
        See :meth:`to_dict`.
    activities : tuple of Activity
        What the robot, the machine and the cameras did, in start order.
    machine_intervals : tuple of (start, end, job)
        When the machine held a part, from load start to unload end [s].
    jobs : mapping job id → order id
    losses : tuple of Loss
        The time each fault and machine reset cost (:mod:`robotprog.oee`).
    ideal_cycle_s : mapping job id → float
        The OEE ideal cycle of each job's part [s] (:attr:`PartProcess.ideal_cycle_s`).
    """

    log: tuple[LogEntry, ...]
    outcomes: tuple[OrderOutcome, ...]
    summary: Mapping[str, object]
    activities: tuple[Activity, ...] = ()
    machine_intervals: tuple[tuple[float, float, int], ...] = ()
    jobs: Mapping[int, str] = field(default_factory=dict)
    losses: tuple[Loss, ...] = ()
    ideal_cycle_s: Mapping[int, float] = field(default_factory=dict)

    @property
    def signals(self) -> tuple[SignalEvent, ...]:
        """The machine's door and cycle handshake at the times the run reached it: the same
        operations the posted programs run (:func:`robotprog.machineio.signal_timeline`)."""
        return signal_timeline(self.activities)

    @property
    def robot_intervals(self) -> tuple[tuple[float, float, int], ...]:
        """(start, end, job) of every robot activity [s]."""
        return tuple((a.start, a.end, a.job) for a in self.activities if a.resource == "robot")

    def to_dict(self) -> dict:
        """JSON-ready: ``{summary, orders: [...], events: n}``.

        Summary keys: ``makespan_s``, ``parts_good``, ``parts_rejected``, ``parts_per_hour``,
        ``robot_utilisation`` and ``machine_utilisation`` (busy fraction of the makespan; the
        machine is busy while cutting), ``cycle_time_s`` (makespan / good parts),
        ``mean_flow_time_s`` (fetch start to sort end per good part), ``orders`` (counts per
        outcome), ``faults`` (per kind), ``recoveries``, ``failures``, and the OEE terms
        ``availability``, ``performance``, ``quality``, ``oee`` (None while undefined),
        ``downtime_s``, ``run_time_s`` (:mod:`robotprog.oee`).
        """
        return {
            "summary": dict(self.summary),
            "orders": [o.__dict__.copy() for o in self.outcomes],
            "events": len(self.log),
        }


#: Robot actions of the state machine, most urgent first (unload frees the machine).
_ROBOT_PRIORITY = {"unload": 0, "flip": 0, "load": 1, "locate_and_pick": 2}
_MACHINE_ACTIONS = {"run_program", "reset_and_rerun"}
#: States whose action occupies the robot until its event arrives.
_ROBOT_STATES = {State.FETCH_RAW, State.LOAD, State.FLIP, State.UNLOAD}
_AHEAD = (State.IDLE, State.FETCH_RAW, State.LOAD)


def simulate(
    orders: Sequence[Order],
    processes: Mapping[Path, PartProcess | str | Exception],
    faults: FaultModel = NO_FAULTS,
    options: SchedulerOptions = SchedulerOptions(),
    progress: Callable[[int, int], None] | None = None,
    sink: EventSink | None = None,
    picks: PickSource | None = None,
) -> SimulationResult:
    """Run orders through the cell until every order has ended.

    Parameters
    ----------
    orders : sequence of Order
        From :func:`robotprog.orders.read_orders`.
    processes : mapping (part path, material) or part path → PartProcess, or the reason it cannot run
        Looked up by ``(order.part, order.material)`` first, then by ``order.part``. An order
        whose part is missing from the mapping, or maps to a str/exception (the planning
        error), ends ``failed`` with that reason; the others run.
    faults : FaultModel
        Injected faults (default none).
    options : SchedulerOptions
    progress : callable(done, total), optional
        Called as orders end.
    sink : EventSink, optional
        Called with every event as it is decided (see :data:`CellEvent`): first the orders that
        cannot run (their ``order_failed`` entry, then their outcome), then the run.
    picks : PickSource, optional
        The rack camera's closed loop: asked at every locate the injected faults let through; its
        answer times the fetch or refuses the grasp. Without it every blank stands where the plan
        put it and the fetch takes :attr:`PartProcess.fetch_s`.

    Returns
    -------
    SimulationResult

    Raises
    ------
    SchedulerError
        No orders, or duplicate order ids.
    """
    if not orders:
        raise SchedulerError("no orders to simulate", source="orders")
    if len({o.id for o in orders}) != len(orders):
        raise SchedulerError("duplicate order ids", source="orders")
    failed: dict[str, str] = {}
    for o in orders:
        proc = process_of(processes, o)
        if proc is None:
            failed[o.id] = f"{o.part}: no plan for this part"
        elif not isinstance(proc, PartProcess):
            failed[o.id] = f"{o.part}: cannot be planned: {proc}"
    return _Sim(orders, processes, faults, options, failed, progress, sink, picks).run()


def running_summary(result: SimulationResult, t: float) -> dict[str, Any]:
    """The run's figures over its first ``t`` seconds, with the keys of ``result.summary``.

    Parts sorted by ``t`` (good after a passed inspection, rejected after a failed one or a
    scrapped part), the robot's and machine's busy share of ``t``, parts per hour, cycle time and
    faults by kind, all as the run stood at ``t`` [s]. Order counts, recoveries, failures and the
    mean flow time are known when the run ends: before ``t`` reaches the makespan they are 0 (or
    None), from then on the simulation's own. For many times, :class:`RunningSummary` walks the
    run once.
    """
    return RunningSummary(result).at(t)


def _busy_kind(a: Activity) -> str | None:
    """What an activity keeps busy in the summary's terms: the robot (its moves and locating), the
    machine (cutting), or neither."""
    if a.resource == "robot" or (a.resource == "camera" and a.action == "locate"):
        return "robot"
    if a.resource == "machine" and a.action == "cut":
        return "machine"
    return None


class RunningSummary:
    """:func:`running_summary` at increasing times, in one pass over the log and the activities
    (the cell log asks at every part sorted: rescanning the run each time is quadratic)."""

    def __init__(self, result: SimulationResult) -> None:
        self.result = result
        self._log = 0
        self._verdict: dict[int, bool] = {}  # job -> good, for the part now on its way to the trays
        self._good = self._rejected = 0
        self._faults: dict[str, int] = {}
        self._kinds = {f.value for f in Fault}
        self._activities = sorted(((a.start, a.end, k) for a in result.activities
                                   if (k := _busy_kind(a)) is not None), key=lambda a: a[0])
        self._started = 0
        self._open: list[tuple[float, float, str]] = []
        self._busy = {"robot": 0.0, "machine": 0.0}  # of activities ended by the last time asked
        self._t = -math.inf
        self._oee = OeeCounter(result.ideal_cycle_s, result.losses)

    def at(self, t: float) -> dict[str, Any]:
        """The figures at ``t`` [s], no earlier than the last time asked."""
        if t < self._t:
            raise ValueError(f"running summary asked for {t} s after {self._t} s")
        self._t = t
        result = self.result
        ended = t >= float(result.summary["makespan_s"])
        # the summary's makespan is rounded to the millisecond: at the end, count everything
        horizon = math.inf if ended else t
        log = result.log
        while self._log < len(log) and log[self._log].time <= horizon:
            e = log[self._log]
            self._log += 1
            self._oee.take(e)
            if e.event == Event.INSPECT_PASS.value:
                self._verdict[e.job] = True
            elif e.event in (Event.INSPECT_FAIL.value, Event.UNLOADED_SCRAP.value):
                self._verdict[e.job] = False
            elif e.event == Event.SORTED.value:
                if self._verdict.pop(e.job, True):
                    self._good += 1
                else:
                    self._rejected += 1
            if e.event in self._kinds:
                self._faults[e.event] = self._faults.get(e.event, 0) + 1
        while self._started < len(self._activities) and self._activities[self._started][0] <= horizon:
            self._open.append(self._activities[self._started])
            self._started += 1
        still_open = []
        for start, end, kind in self._open:
            if end <= horizon:
                self._busy[kind] += end - start
            else:
                still_open.append((start, end, kind))
        self._open = still_open
        busy = {k: v + sum(horizon - s for s, _, kind in still_open if kind == k) for k, v in self._busy.items()}
        good = self._good
        return {
            "makespan_s": round(t, 3),
            "parts_good": good,
            "parts_rejected": self._rejected,
            "parts_per_hour": round(3600.0 * good / t, 3) if t > 0 else 0.0,
            "robot_utilisation": round(busy["robot"] / t, 4) if t > 0 else 0.0,
            "machine_utilisation": round(busy["machine"] / t, 4) if t > 0 else 0.0,
            "cycle_time_s": round(t / good, 3) if good else None,
            "mean_flow_time_s": result.summary["mean_flow_time_s"] if ended else None,
            "orders": dict(result.summary["orders"]) if ended else {"done": 0, "rejected": 0, "failed": 0},
            "faults": dict(self._faults),
            "recoveries": result.summary["recoveries"] if ended else 0,
            "failures": result.summary["failures"] if ended else 0,
            **self._oee.at(t, horizon),
        }


def process_of(processes: Mapping, order: Order) -> PartProcess | str | Exception | None:
    """The process entry for an order: by (part, material), else by part."""
    found = processes.get((order.part, order.material))
    return processes.get(order.part) if found is None else found


def _key(order: Order) -> tuple[Path, str]:
    """The (part, material) key of an order's process (:func:`process_of` looks it up first)."""
    return (order.part, order.material)


def _outcome(p) -> OrderOutcome:
    return OrderOutcome(p.order.id, str(p.order.part), p.order.quantity, p.good, p.rejected,
                        p.outcome or "failed", p.reason)


class _Sim:
    def __init__(self, orders, processes, faults, options, failed, progress, sink, picks=None):
        self.picks = picks
        self.orders = {o.id: o for o in orders}
        self.rank = {o.id: i for i, o in enumerate(orders)}
        self.processes = processes
        self.rng = random.Random(faults.seed)
        self.faults = faults
        self.options = options
        self.progress = progress
        self.sink = sink or (lambda event: None)
        self.cell: CellState = initial_state(orders, failed)
        self.now = 0.0
        self.heap: list = []
        self.seq = 0
        self.waiting: list[tuple[int, str, int]] = []  # (job, action, arrival seq) needing the robot
        self.robot_job: int | None = None
        self.machine_job: int | None = None
        self.activities: list[Activity] = []
        self.jobs: dict[int, str] = {}
        self.machine_hold: list[tuple[float, float, int]] = []
        self.hold_start = 0.0
        self.cutting = 0.0
        self.started: dict[int, float] = {}
        self.flow: list[float] = []
        self.told: dict[str, OrderOutcome] = {}  # the last outcome the sink had of each order
        self.log: list[LogEntry] = []
        self.ledger = DowntimeLedger()  # told every event as the sink is, for the OEE terms

    def note(self, entry: LogEntry) -> None:
        self.log.append(entry)
        self.ledger(entry)
        self.sink(entry)

    def tell(self, outcome: OrderOutcome) -> None:
        """Tell the sink an order's outcome when it is decided, and again whenever a part still under
        way when it ended is sorted (the counts change)."""
        if self.told.get(outcome.order) != outcome:
            self.told[outcome.order] = outcome
            self.sink(outcome)

    def add_activity(self, activity: Activity) -> None:
        self.activities.append(activity)
        self.ledger(activity)
        self.sink(activity)

    def proc(self, job_id: int) -> PartProcess:
        return process_of(self.processes, self.orders[self.cell.job(job_id).order])

    def push(self, delay: float, job: int, event: Event, message: str = "") -> None:
        self.seq += 1
        heapq.heappush(self.heap, (self.now + delay, self.seq, job, event, message))

    def deliver(self, job_id: int, event: Event, message: str = "") -> None:
        order = self.cell.job(job_id).order
        self.cell, effects = step(self.cell, job_id, event, self.options)
        for eff in effects:
            state = next((j.state.name for j in self.cell.jobs if j.id == job_id), "IDLE")
            text = "; ".join(m for m in (eff.message, message) if m)
            self.note(LogEntry(self.now, job_id, order, state, event.value, text))
            self.apply(job_id, eff.action, eff.event)

    def apply(self, job_id: int, action: str, chosen: Event | None) -> None:
        if action in _ROBOT_PRIORITY:
            self.seq += 1
            self.waiting.append((job_id, action, self.seq))
        elif action in _MACHINE_ACTIONS:
            self.start_machining(job_id, action == "reset_and_rerun")
        elif action == "inspect":  # a good part: the verdict sent the bad ones to the bin
            self.activity("camera", "inspect", job_id, State.INSPECT, self.proc(job_id).inspect_s,
                          Event.INSPECT_PASS)
        elif action in ("sort_good", "in_bin"):  # the part already lies in the out-tray / the bin
            self.push(0.0, job_id, Event.SORTED)
        elif action == "recover":
            self.push(0.0, job_id, chosen)
        elif action in ("stop_robot", "hold_machine"):
            self.push(0.0, job_id, Event.RECOVER)
        elif action in ("fail_part", "finish_part"):
            if self.machine_job == job_id:
                self.release_machine(job_id)
            if action == "finish_part" and self.cell.finished[-1].reason == "good":
                self.flow.append(self.now - self.started.get(job_id, self.now))
            p = self.cell.progress(self.cell.finished[-1].order)
            if p.outcome:
                self.tell(_outcome(p))
            if self.progress:
                ended = sum(1 for p in self.cell.orders if p.outcome)
                self.progress(ended, len(self.cell.orders))

    def release_machine(self, job_id: int) -> None:
        self.machine_hold.append((self.hold_start, self.now, job_id))
        self.machine_job = None

    def activity(self, resource: str, action: str, job_id: int, state: State, duration: float,
                 event: Event | None, message: str = "", *, start_after: float = 0.0, share: float = 1.0,
                 slot: int | None = None, op: int | None = None, pick: int | None = None) -> float:
        """Record an activity starting ``start_after`` seconds from now and schedule ``event`` at its
        end (none for ``None``: a later activity ends the step), or TIMEOUT if the state's timeout,
        counted from now, comes first. ``share`` scales the recorded fraction (a cut an alarm stops
        part way). Returns the activity's length [s]."""
        limit = self.options.timeout(state) - start_after
        start = self.now + start_after
        if duration > limit:
            used = max(limit, 0.0)
            self.push(start_after + used, job_id, Event.TIMEOUT,
                      f"{state.name} took over {self.options.timeout(state):g} s")
            outcome = Event.TIMEOUT.value
        else:
            used = duration
            if event is not None:
                self.push(start_after + used, job_id, event, message)
            outcome = event.value if event is not None else "done"
        fraction = used / duration if duration > 0 else 1.0
        self.add_activity(Activity(resource, action, job_id, start, start + used, outcome, share * fraction, slot,
                                   op, pick))
        return used

    def start_machining(self, job_id: int, rerun: bool) -> None:
        p = self.proc(job_id)
        op = self.cell.job(job_id).op
        label = op if p.setups > 1 else None
        machining = p.machining(op)
        # op 1 of a part in two setups ends with the flip, the last operation with the unload
        done = Event.OP_DONE if op < p.setups else Event.CYCLE_DONE
        reset = self.options.machine_reset_s if rerun else 0.0
        if reset:
            self.add_activity(Activity("machine", "reset", job_id, self.now, self.now + reset, "reset", op=label))
        if self.rng.random() < self.faults.machine_alarm:
            share = self.rng.random()
            used = self.activity("machine", "cut", job_id, State.MACHINING, share * machining,
                                 Event.MACHINE_ALARM, "machine alarm", start_after=reset, share=share, op=label)
        else:
            used = self.activity("machine", "cut", job_id, State.MACHINING, machining, done,
                                 start_after=reset, op=label)
        self.cutting += used

    def start_robot(self, job_id: int, action: str) -> None:
        p = self.proc(job_id)
        job = self.cell.job(job_id)
        self.robot_job = job_id
        if action == "locate_and_pick":
            self.started.setdefault(job_id, self.now)
            if self.rng.random() < self.faults.stock_not_found:
                self.activity("camera", "locate", job_id, job.state, p.locate_s, Event.STOCK_NOT_FOUND,
                              f"no stock in rack slot {job.slot}", slot=job.slot)
                return
            pick = None if self.picks is None else self.picks(job_id, _key(self.orders[job.order]), job.slot)
            if pick is not None and pick.refusal:
                self.activity("camera", "locate", job_id, job.state, p.locate_s, Event.STOCK_NOT_FOUND,
                              pick.refusal, slot=job.slot, pick=pick.index)
                return
            seen = self.activity("camera", "locate", job_id, job.state, p.locate_s, None, slot=job.slot,
                                 pick=None if pick is None else pick.index)
            if self.activities[-1].outcome == Event.TIMEOUT.value:
                return
            fetch_s = p.fetch_s if pick is None else pick.fetch_s
            index = None if pick is None else pick.index
            if self.rng.random() < self.faults.grasp_miss:
                self.activity("robot", "missed_grasp", job_id, job.state, fetch_s + p.regrasp_s,
                              Event.GRASP_MISSED, f"grasp missed at rack slot {job.slot}", start_after=seen,
                              slot=job.slot, pick=index)
            else:
                self.activity("robot", "fetch", job_id, job.state, fetch_s, Event.FETCHED,
                              "" if pick is None else pick.message, start_after=seen, slot=job.slot, pick=index)
        elif action == "load":
            self.machine_job, self.hold_start = job_id, self.now
            self.activity("robot", "load", job_id, job.state, p.load_s, Event.LOADED)
        elif action == "flip":
            self.activity("robot", "flip", job_id, job.state, p.flip_s, Event.FLIPPED)
        else:  # unload: the machine's verdict, read with the part above the vise, picks the way on
            if job.scrap:
                self.activity("robot", "unload_reject", job_id, job.state, p.reject_s, Event.UNLOADED_SCRAP)
            elif self.rng.random() < self.faults.inspect_fail:
                self.activity("robot", "unload_reject", job_id, job.state, p.reject_s, Event.INSPECT_FAIL,
                              "machine verdict: part_ok low")
            else:
                self.activity("robot", "unload", job_id, job.state, p.unload_s, Event.UNLOADED)

    def dispatch(self) -> None:
        """Give the free robot its next action; pick a new blank when the machine is empty."""
        if self.robot_job is not None:
            return
        ready = [w for w in self.waiting if w[1] != "load" or self.machine_job is None]
        if ready:
            job_id, action, seq = min(ready, key=lambda w: (_ROBOT_PRIORITY[w[1]], w[2]))
            self.waiting.remove((job_id, action, seq))
            self.start_robot(job_id, action)
            return
        # one gripper and no staging nest: a blank is picked only when it can go into the vise
        ahead = [j for j in self.cell.jobs if j.state in _AHEAD
                 or (j.state in (State.FAULT, State.RECOVER) and j.fault_state in _AHEAD)]
        if self.cell.queue and not ahead and self.machine_job is None:
            self.cell, job_id = admit(self.cell)
            self.jobs[job_id] = self.cell.job(job_id).order
            self.deliver(job_id, Event.START)
            self.dispatch()

    def run(self) -> SimulationResult:
        for p in self.cell.orders:
            if p.outcome:  # cannot run at all (no plan)
                self.note(LogEntry(0.0, 0, p.order.id, "-", "order_failed", p.reason))
                self.tell(_outcome(p))
        self.dispatch()
        while self.heap:
            t, _, job_id, event, message = heapq.heappop(self.heap)
            self.now = t
            if self.robot_job == job_id and self.cell.job(job_id).state in _ROBOT_STATES:
                self.robot_job = None
            if event in (Event.UNLOADED, Event.UNLOADED_SCRAP, Event.INSPECT_FAIL):  # out of the vise
                self.release_machine(job_id)
            self.deliver(job_id, event, message)
            self.dispatch()
        if not self.cell.all_ended:  # a bug, not bad input: say what is stuck
            raise SchedulerError(f"simulation stopped with work left: jobs {self.cell.jobs}, "
                                 f"queue {self.cell.queue}", source="scheduler")
        return self.result()

    def result(self) -> SimulationResult:
        makespan = self.now
        good = sum(p.good for p in self.cell.orders)
        robot = sum(a.end - a.start for a in self.activities if a.resource == "robot"
                    or (a.resource == "camera" and a.action == "locate"))
        outcomes = tuple(_outcome(p) for p in sorted(self.cell.orders, key=lambda p: self.rank[p.order.id]))
        counts = {k: sum(1 for o in outcomes if o.outcome == k) for k in ("done", "rejected", "failed")}
        summary = {
            "makespan_s": round(makespan, 3),
            "parts_good": good,
            "parts_rejected": sum(p.rejected for p in self.cell.orders),
            "parts_per_hour": round(3600.0 * good / makespan, 3) if makespan > 0 else 0.0,
            "robot_utilisation": round(robot / makespan, 4) if makespan > 0 else 0.0,
            "machine_utilisation": round(self.cutting / makespan, 4) if makespan > 0 else 0.0,
            "cycle_time_s": round(makespan / good, 3) if good else None,
            "mean_flow_time_s": round(sum(self.flow) / len(self.flow), 3) if self.flow else None,
            "orders": counts,
            "faults": dict(self.cell.faults),
            "recoveries": self.cell.recoveries,
            "failures": self.cell.failures,
        }
        ideal = {j: process_of(self.processes, self.orders[o]).ideal_cycle_s for j, o in self.jobs.items()}
        summary.update(run_oee(self.log, ideal, self.ledger.losses, summary["makespan_s"]))
        activities = tuple(sorted(self.activities, key=lambda a: (a.start, a.end)))
        return SimulationResult(tuple(self.log), outcomes, summary, activities, tuple(self.machine_hold),
                                dict(self.jobs), tuple(self.ledger.losses), ideal)
