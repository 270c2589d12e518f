"""The cell's state machine, as data plus pure transition functions.

Each blank the cell works on is a *job*, one unit of an order. A job walks through
:class:`State` by :class:`Event`; :data:`TRANSITIONS` maps ``(state, event)`` to
``(next state, action)``, and :func:`step` applies one transition to a frozen
:class:`CellState` and returns the *effects* (actions) the cell must carry out. Nothing here
knows about time or resources: :mod:`robotprog.cellsim` decides when events happen, and
runs several jobs at once (the robot fetches the next blank while the machine cuts).

Blank flow: ``FETCH_RAW`` = the rack camera locates the blank in its slot and the robot picks
it; ``LOAD`` = into the vise; ``MACHINING`` = the program runs; ``UNLOAD`` = the robot takes the
part out of the vise and reads the machine's verdict on it (``part_ok``), as the posted program does
(:data:`robotprog.programs.VERDICT_AFTER`): a good part goes on to the out-tray (``UNLOADED``), a
failed or scrapped one straight to the reject bin (``INSPECT_FAIL`` / ``UNLOADED_SCRAP``, the
program's reject branch); ``INSPECT`` = the out-tray camera checks a good part; ``SORT`` = the part
is where it belongs (the out-tray or the bin). A part machined in two setups ends op 1 with ``OP_DONE``
instead: ``FLIP`` = vise → flip station, turned over → vise, then ``MACHINING`` again runs op 2
(:attr:`Job.op` counts the operation), which ends with ``CYCLE_DONE``.

Faults and their recoveries (each fault ends as exactly one recovery or one failure):

- **Missed grasp** (gripper sensor after closing, or a ``FETCH_RAW`` timeout): the blank
  is still in its slot, so the robot retries the grasp, up to
  :attr:`SchedulerOptions.grasp_retries` times; then the blank is left in the slot for the
  operator and the job fails (the order fails: a cell that cannot grasp needs a person).
- **Stock not found** by the camera: re-image the slot up to
  :attr:`SchedulerOptions.reimage_retries` times, then skip to the next rack slot, up to
  :attr:`SchedulerOptions.slot_skips` times, then fail the order.
- **Machine alarm** during the program (or a ``MACHINING`` timeout): reset the machine
  and re-run the program, :attr:`SchedulerOptions.program_reruns` times; then the part is
  unloaded to the reject bin as scrap (and re-made if the order allows).
- **Inspection failure** (the machine's verdict read on unloading): the part goes to the reject
  bin; the order re-makes it while it
  has re-makes left (:attr:`SchedulerOptions.remakes` per order), else the order ends
  ``rejected``.
- A timeout in ``LOAD``, ``UNLOAD``, ``INSPECT`` or ``SORT`` means the part's position is
  unknown: the job is abandoned (the operator clears the cell) and the order fails.

Every order ends ``done``, ``rejected`` or ``failed``, with a reason.
"""

from __future__ import annotations

import enum
import logging
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Mapping, Sequence

from factory.core.errors import SchedulerError

from .orders import Order

log = logging.getLogger(__name__)


class State(enum.Enum):
    IDLE = "IDLE"
    FETCH_RAW = "FETCH_RAW"
    LOAD = "LOAD"
    MACHINING = "MACHINING"
    UNLOAD = "UNLOAD"
    FLIP = "FLIP"
    INSPECT = "INSPECT"
    SORT = "SORT"
    FAULT = "FAULT"
    RECOVER = "RECOVER"


class Event(enum.Enum):
    START = "start"
    FETCHED = "fetched"
    GRASP_MISSED = "grasp_missed"
    STOCK_NOT_FOUND = "stock_not_found"
    LOADED = "loaded"
    CYCLE_DONE = "cycle_done"
    OP_DONE = "op_done"
    FLIPPED = "flipped"
    MACHINE_ALARM = "machine_alarm"
    UNLOADED = "unloaded"
    UNLOADED_SCRAP = "unloaded_scrap"
    INSPECT_PASS = "inspect_pass"
    INSPECT_FAIL = "inspect_fail"
    SORTED = "sorted"
    TIMEOUT = "timeout"
    RECOVER = "recover"
    RETRY_FETCH = "retry_fetch"
    RERUN = "rerun"
    SCRAP = "scrap"
    ABANDON = "abandon"


class Fault(enum.Enum):
    GRASP_MISSED = "grasp_missed"
    STOCK_NOT_FOUND = "stock_not_found"
    MACHINE_ALARM = "machine_alarm"
    INSPECT_FAIL = "inspect_fail"
    TIMEOUT = "timeout"


S, E = State, Event
#: (state, event) → (next state, action). The only legal moves of a job.
TRANSITIONS: Mapping[tuple[State, Event], tuple[State, str]] = MappingProxyType({
    (S.IDLE, E.START): (S.FETCH_RAW, "locate_and_pick"),
    (S.FETCH_RAW, E.FETCHED): (S.LOAD, "load"),
    (S.FETCH_RAW, E.GRASP_MISSED): (S.FAULT, "stop_robot"),
    (S.FETCH_RAW, E.STOCK_NOT_FOUND): (S.FAULT, "stop_robot"),
    (S.FETCH_RAW, E.TIMEOUT): (S.FAULT, "stop_robot"),
    (S.LOAD, E.LOADED): (S.MACHINING, "run_program"),
    (S.LOAD, E.TIMEOUT): (S.FAULT, "stop_robot"),
    (S.MACHINING, E.CYCLE_DONE): (S.UNLOAD, "unload"),
    (S.MACHINING, E.OP_DONE): (S.FLIP, "flip"),
    (S.FLIP, E.FLIPPED): (S.MACHINING, "run_program"),
    (S.FLIP, E.TIMEOUT): (S.FAULT, "stop_robot"),
    (S.MACHINING, E.MACHINE_ALARM): (S.FAULT, "hold_machine"),
    (S.MACHINING, E.TIMEOUT): (S.FAULT, "hold_machine"),
    (S.UNLOAD, E.UNLOADED): (S.INSPECT, "inspect"),
    (S.UNLOAD, E.UNLOADED_SCRAP): (S.SORT, "in_bin"),
    (S.UNLOAD, E.INSPECT_FAIL): (S.SORT, "in_bin"),
    (S.UNLOAD, E.TIMEOUT): (S.FAULT, "stop_robot"),
    (S.INSPECT, E.INSPECT_PASS): (S.SORT, "sort_good"),
    (S.INSPECT, E.TIMEOUT): (S.FAULT, "stop_robot"),
    (S.SORT, E.SORTED): (S.IDLE, "finish_part"),
    (S.SORT, E.TIMEOUT): (S.FAULT, "stop_robot"),
    (S.FAULT, E.RECOVER): (S.RECOVER, "recover"),
    (S.RECOVER, E.RETRY_FETCH): (S.FETCH_RAW, "locate_and_pick"),
    (S.RECOVER, E.RERUN): (S.MACHINING, "reset_and_rerun"),
    (S.RECOVER, E.SCRAP): (S.UNLOAD, "unload"),
    (S.RECOVER, E.ABANDON): (S.IDLE, "fail_part"),
})
del S, E

_FAULT_OF_EVENT = {Event.GRASP_MISSED: Fault.GRASP_MISSED, Event.STOCK_NOT_FOUND: Fault.STOCK_NOT_FOUND,
                   Event.MACHINE_ALARM: Fault.MACHINE_ALARM, Event.TIMEOUT: Fault.TIMEOUT}


@dataclass(frozen=True)
class SchedulerOptions:
    """Timeouts and retry limits of the cell.

    Attributes
    ----------
    timeouts : mapping State → float
        Longest time [s] an action of that state may take before ``TIMEOUT``; counted from
        the action's start (waiting for the robot or the machine does not count). Defaults:
        FETCH_RAW 120, LOAD 120, MACHINING 14400 (4 h, each operation), FLIP 180, UNLOAD 120,
        INSPECT 60, SORT 60.
    grasp_retries : int
        Grasp attempts after the first miss, per job (default 2).
    reimage_retries : int
        Re-images of one rack slot when the camera does not find the blank (default 1).
    slot_skips : int
        Further rack slots tried per job once re-imaging gave up (default 1).
    program_reruns : int
        Reset-and-rerun of the program after a machine alarm, per job (default 1).
    remakes : int
        Extra parts an order may start to replace rejected ones (default 2).
    machine_reset_s : float
        Time [s] to reset the machine after an alarm, before the re-run (default 60).
    seed : int
        Seed of the fault-injection RNG (default 0).
    """

    timeouts: Mapping[State, float] = field(default_factory=lambda: MappingProxyType({
        State.FETCH_RAW: 120.0, State.LOAD: 120.0, State.MACHINING: 14400.0,
        State.UNLOAD: 120.0, State.FLIP: 180.0, State.INSPECT: 60.0, State.SORT: 60.0}))
    grasp_retries: int = 2
    reimage_retries: int = 1
    slot_skips: int = 1
    program_reruns: int = 1
    remakes: int = 2
    machine_reset_s: float = 60.0
    seed: int = 0

    def __post_init__(self):
        for name in ("grasp_retries", "reimage_retries", "slot_skips", "program_reruns", "remakes"):
            if getattr(self, name) < 0:
                raise SchedulerError(f"{name} must be >= 0", source=name)
        for state, limit in self.timeouts.items():
            if not limit > 0:
                raise SchedulerError(f"timeout of {state.name} must be > 0 s", source="timeouts")
        if self.machine_reset_s < 0:
            raise SchedulerError("machine_reset_s must be >= 0", source="machine_reset_s")

    def timeout(self, state: State) -> float:
        """Timeout [s] of ``state`` (infinite when not listed)."""
        return float(self.timeouts.get(state, float("inf")))


@dataclass(frozen=True)
class Job:
    """One blank on its way through the cell (one unit of an order); ``op`` is the operation
    (setup) it is in or last ran: 1, then 2 once turned over for op 2."""

    id: int
    order: str
    state: State = State.IDLE
    slot: int = 0
    grasp_misses: int = 0
    reimages: int = 0
    slot_skips: int = 0
    reruns: int = 0
    fault: Fault | None = None
    fault_state: State | None = None
    scrap: bool = False
    inspect_failed: bool = False
    reason: str = ""
    op: int = 1


@dataclass(frozen=True)
class OrderProgress:
    """How far an order has come. ``outcome`` is None while it runs, then done/rejected/failed."""

    order: Order
    good: int = 0
    rejected: int = 0
    remakes: int = 0
    outcome: str | None = None
    reason: str = ""


@dataclass(frozen=True)
class Effect:
    """What the cell must do after a transition. ``event`` is set for ``recover`` (the chosen recovery)."""

    action: str
    job: int
    event: Event | None = None
    message: str = ""


@dataclass(frozen=True)
class CellState:
    """Everything the scheduler knows; replaced, never mutated.

    Attributes
    ----------
    orders : tuple of OrderProgress
        Priority order (lower priority number first, ties in file order).
    queue : tuple of str
        Order ids of units not yet started, in run order.
    jobs : tuple of Job
        Jobs in the cell now.
    finished : tuple of Job
        Jobs that left the cell (reason says how).
    faults : mapping Fault name → int
    recoveries, failures : int
        Each fault is resolved as exactly one recovery or one failure.
    next_job : int
    next_slot : int
        Next untouched rack slot.
    """

    orders: tuple[OrderProgress, ...]
    queue: tuple[str, ...]
    jobs: tuple[Job, ...] = ()
    finished: tuple[Job, ...] = ()
    faults: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))
    recoveries: int = 0
    failures: int = 0
    next_job: int = 1
    next_slot: int = 0

    def job(self, job_id: int) -> Job:
        for job in self.jobs:
            if job.id == job_id:
                return job
        raise SchedulerError(f"no job {job_id} in the cell", source=f"job {job_id}")

    def progress(self, order_id: str) -> OrderProgress:
        for p in self.orders:
            if p.order.id == order_id:
                return p
        raise SchedulerError(f"no order {order_id}", source=order_id)

    @property
    def all_ended(self) -> bool:
        """True when every order has an outcome and no job is in the cell."""
        return not self.jobs and not self.queue and all(p.outcome for p in self.orders)


def initial_state(orders: Sequence[Order], failed: Mapping[str, str] | None = None) -> CellState:
    """The cell before the first event: every unit of every order queued by priority.

    Parameters
    ----------
    orders : sequence of Order
    failed : mapping order id → reason, optional
        Orders that cannot run at all (missing part, part that cannot be planned): they end
        ``failed`` with that reason and are not queued; the rest run.
    """
    failed = dict(failed or {})
    ranked = sorted(orders, key=lambda o: o.priority)  # sorted() is stable: ties keep file order
    progress = tuple(OrderProgress(o, outcome="failed", reason=failed[o.id]) if o.id in failed
                     else OrderProgress(o) for o in ranked)
    queue = tuple(o.id for o in ranked if o.id not in failed for _ in range(o.quantity))
    return CellState(orders=progress, queue=queue)


def admit(cell: CellState) -> tuple[CellState, int]:
    """Take the next queued unit into the cell as an IDLE job (a fresh rack slot); returns its id.

    Raises SchedulerError when the queue is empty.
    """
    if not cell.queue:
        raise SchedulerError("no order waiting", source="queue")
    job = Job(id=cell.next_job, order=cell.queue[0], slot=cell.next_slot)
    return replace(cell, queue=cell.queue[1:], jobs=cell.jobs + (job,), next_job=cell.next_job + 1,
                   next_slot=cell.next_slot + 1), job.id


def _put(cell: CellState, job: Job) -> CellState:
    return replace(cell, jobs=tuple(job if j.id == job.id else j for j in cell.jobs))


def _set_order(cell: CellState, p: OrderProgress) -> CellState:
    return replace(cell, orders=tuple(p if q.order.id == p.order.id else q for q in cell.orders))


def _end_order(cell: CellState, order_id: str, outcome: str, reason: str) -> CellState:
    """Give an order its outcome (first outcome wins) and drop its queued units."""
    p = cell.progress(order_id)
    if p.outcome is None:
        cell = _set_order(cell, replace(p, outcome=outcome, reason=reason))
    return replace(cell, queue=tuple(q for q in cell.queue if q != order_id))


def plan_recovery(job: Job, options: SchedulerOptions) -> tuple[Event, Job, str]:
    """Choose the recovery for a job in FAULT: (recovery event, job with counters updated, message)."""
    kind, where = job.fault, job.fault_state
    if kind is Fault.TIMEOUT and where is State.FETCH_RAW:
        kind = Fault.GRASP_MISSED
    if kind is Fault.TIMEOUT and where is State.MACHINING:
        kind = Fault.MACHINE_ALARM
    if kind is Fault.GRASP_MISSED:
        if job.grasp_misses < options.grasp_retries:
            return (Event.RETRY_FETCH, replace(job, grasp_misses=job.grasp_misses + 1),
                    f"retry grasp {job.grasp_misses + 1}/{options.grasp_retries} at slot {job.slot}")
        return (Event.ABANDON, job, f"grasp missed {job.grasp_misses + 1} times at rack slot {job.slot}; "
                "blank left in the slot for the operator")
    if kind is Fault.STOCK_NOT_FOUND:
        if job.reimages < options.reimage_retries:
            return (Event.RETRY_FETCH, replace(job, reimages=job.reimages + 1),
                    f"re-image slot {job.slot} ({job.reimages + 1}/{options.reimage_retries})")
        if job.slot_skips < options.slot_skips:
            return (Event.RETRY_FETCH, replace(job, slot_skips=job.slot_skips + 1, reimages=0, slot=-1),
                    f"stock not found in slot {job.slot}; skip to the next rack slot")
        return (Event.ABANDON, job, f"camera found no stock in {job.slot_skips + 1} rack slots")
    if kind is Fault.MACHINE_ALARM:
        if job.reruns < options.program_reruns:
            return (Event.RERUN, replace(job, reruns=job.reruns + 1),
                    f"reset machine and re-run program ({job.reruns + 1}/{options.program_reruns})")
        return (Event.SCRAP, replace(job, scrap=True),
                f"machine alarm after {job.reruns} re-run(s); part scrapped")
    return (Event.ABANDON, job, f"timeout in {where.name if where else '?'}: part position unknown, "
            "operator must clear the cell")


def step(cell: CellState, job_id: int, event: Event,
         options: SchedulerOptions = SchedulerOptions()) -> tuple[CellState, tuple[Effect, ...]]:
    """Apply one event to one job: the only way the cell state changes.

    Parameters
    ----------
    cell : CellState
    job_id : int
        A job in the cell (see :func:`admit`).
    event : Event
    options : SchedulerOptions

    Returns
    -------
    (CellState, tuple of Effect)
        The new state and the actions to carry out, first the transition's own action.

    Raises
    ------
    SchedulerError
        Unknown job, or ``event`` is not accepted in the job's state (not in
        :data:`TRANSITIONS`).
    """
    job = cell.job(job_id)
    key = (job.state, event)
    if key not in TRANSITIONS:
        raise SchedulerError(f"event {event.value} is not accepted in state {job.state.name}",
                             source=f"job {job_id}")
    nxt, action = TRANSITIONS[key]
    message = ""
    if nxt is State.FAULT:
        fault = _FAULT_OF_EVENT[event]
        counts = dict(cell.faults)
        counts[fault.value] = counts.get(fault.value, 0) + 1
        cell = replace(cell, faults=MappingProxyType(counts))
        job = replace(job, fault=fault, fault_state=job.state)
        message = f"{fault.value} in {job.fault_state.name}"
    elif event is Event.INSPECT_FAIL:
        counts = dict(cell.faults)
        counts[Fault.INSPECT_FAIL.value] = counts.get(Fault.INSPECT_FAIL.value, 0) + 1
        cell = replace(cell, faults=MappingProxyType(counts))
        job = replace(job, inspect_failed=True)
        message = "part failed inspection"
    if event is Event.FLIPPED:
        job = replace(job, op=job.op + 1)
    job = replace(job, state=nxt)
    effects = [Effect(action, job.id, message=message)]

    if action == "recover":
        chosen, job, message = plan_recovery(job, options)
        if chosen in (Event.ABANDON, Event.SCRAP):
            cell = replace(cell, failures=cell.failures + 1)
        else:
            cell = replace(cell, recoveries=cell.recoveries + 1)
        if job.slot == -1:  # skip to a fresh rack slot
            job = replace(job, slot=cell.next_slot)
            cell = replace(cell, next_slot=cell.next_slot + 1)
        effects = [Effect(action, job.id, event=chosen, message=message)]
        cell = _put(cell, replace(job, reason=message))
    elif action == "fail_part":
        cell = replace(cell, jobs=tuple(j for j in cell.jobs if j.id != job.id), finished=cell.finished + (job,))
        cell = _end_order(cell, job.order, "failed", job.reason)
    elif action == "finish_part":
        cell = _finish(cell, job, options)
    else:
        cell = _put(cell, job)
    return cell, tuple(effects)


def _finish(cell: CellState, job: Job, options: SchedulerOptions) -> CellState:
    good = not (job.scrap or job.inspect_failed)
    job = replace(job, reason="good" if good else ("scrap after machine alarm" if job.scrap
                                                   else "failed inspection"))
    cell = replace(cell, jobs=tuple(j for j in cell.jobs if j.id != job.id), finished=cell.finished + (job,))
    p = cell.progress(job.order)
    if good:
        p = replace(p, good=p.good + 1)
        cell = _set_order(cell, p)
        if p.outcome is None and p.good >= p.order.quantity:
            cell = _set_order(cell, replace(p, outcome="done", reason=f"{p.good} good part(s)"))
        return cell
    p = replace(p, rejected=p.rejected + 1)
    if p.outcome is not None:
        # the order already ended: a stray part is sorted but changes nothing
        if job.inspect_failed:
            cell = replace(cell, failures=cell.failures + 1)
        return _set_order(cell, p)
    if p.remakes < options.remakes:
        p = replace(p, remakes=p.remakes + 1)
        cell = _set_order(cell, p)
        if job.inspect_failed:
            cell = replace(cell, recoveries=cell.recoveries + 1)
        # the re-make goes to the head of the queue: the order is already under way
        return replace(cell, queue=(job.order,) + cell.queue)
    if job.inspect_failed:
        cell = replace(cell, failures=cell.failures + 1)
    cell = _set_order(cell, p)
    return _end_order(cell, job.order, "rejected",
                      f"{p.rejected} part(s) rejected ({job.reason}); re-make limit {options.remakes} reached")
