"""OEE of a simulated run: availability x performance x quality, as the run stood at any time.

The definitions are those ``factory report`` applies to a process record (:mod:`factory.report`),
so the simulation's summary and the report of the same run agree (times in simulated [s]):

- **Planned production time** *P*: the time the cell was to produce: the run's makespan so far.
- **Downtime** *D*: time lost to faults (stops). For each fault that stopped a job (its state
  went to ``FAULT``), the time of the attempt it ended: from the start of the first activity the
  job began after its previous transition (the rack camera's look and the missed grasp, the
  program an alarm cut short, a timed-out step) to the fault; plus every machine reset after an
  alarm. A failed inspection loses quality, not time.
- **Availability** = run time / planned production time, run time *O* = *P* - *D*.
- **Performance** = ideal cycle time x parts made / run time: the sum, over every part *made*
  (its program ran to the end, then it was inspected and sorted: good or rejected), of its
  ideal cycle, the cell's fault-free steady-state cycle on that part
  (:attr:`robotprog.cellsim.PartProcess.ideal_cycle_s`: locate, fetch, load, machining, the faster way out), over
  *O*. What performance loses is slow running: the program an alarm cut short, waiting, the
  last part's inspection. A part scrapped after machine alarms is not made.
- **Quality** = good parts / parts made.
- **OEE** = availability x performance x quality (= ideal time of the good parts / *P* when every
  part has the same ideal cycle).

A term whose denominator is 0 (nothing planned or made yet) is None.

:class:`DowntimeLedger` is an event sink (:data:`robotprog.cellsim.EventSink`): told every
transition and activity in the order the simulation decides them, as the process record is,
it keeps each loss. :class:`OeeCounter` then walks the log once for figures at increasing times.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

#: The job state a stopping fault puts a job in, and the machine action that costs time after an alarm.
FAULT_STATE = "FAULT"
RESET = "reset"
#: Events of the log the counter reads: a part sorted to a tray; a part failed inspection or was
#: scrapped after machine alarms (the recovery ``scrap``, then ``unloaded_scrap``).
SORTED, INSPECT_FAIL, SCRAPPED = "sorted", "inspect_fail", ("scrap", "unloaded_scrap")


@dataclass(frozen=True)
class Loss:
    """Time one fault cost.

    Attributes
    ----------
    kind : str
        The fault (``grasp_missed``, ``stock_not_found``, ``machine_alarm``, ``timeout``, ...) or
        ``"reset"`` (a machine reset after an alarm).
    job : int
    start, end : float
        The time lost [s]: the attempt the fault ended (known when it is raised, at ``end``),
        or the reset.
    """

    kind: str
    job: int
    start: float
    end: float

    def lost_by(self, t: float) -> float:
        """Time [s] this loss had cost by ``t`` [s]: a fault's whole attempt once raised, a reset so far."""
        if self.kind == RESET:
            return max(min(self.end, t) - self.start, 0.0)
        return self.end - self.start if self.end <= t else 0.0


class DowntimeLedger:
    """Each loss of a run, told its events in the simulation's order (an event sink).

    Activities are told when they start, transitions when they happen; a job's attempt starts
    at the first activity (other than a reset) it begins after its last transition.
    """

    def __init__(self) -> None:
        self.losses: list[Loss] = []
        self._attempt: dict[int, float] = {}  # job -> start of its current attempt [s]

    def __call__(self, event: Any) -> None:
        """Take one :class:`~robotprog.cellsim.LogEntry` or :class:`~robotprog.cellsim.Activity`
        (anything else, an order's outcome, is ignored)."""
        if hasattr(event, "resource"):  # an activity
            if event.action == RESET:
                self.losses.append(Loss(RESET, event.job, event.start, event.end))
            else:
                self._attempt.setdefault(event.job, event.start)
        elif hasattr(event, "state"):  # a transition
            if event.state == FAULT_STATE:
                start = self._attempt.get(event.job, event.time)
                self.losses.append(Loss(event.event, event.job, min(start, event.time), event.time))
            if event.job:
                self._attempt.pop(event.job, None)


def _ratio(a: float, b: float) -> float | None:
    return round(a / b, 4) if b > 0 else None


def oee_terms(planned_s: float, downtime_s: float, ideal_s: float, made: int, good: int) -> dict[str, Any]:
    """The OEE terms from their counts (see the module docstring).

    Parameters
    ----------
    planned_s, downtime_s : float
        Planned production time and downtime [s].
    ideal_s : float
        Sum of the ideal cycles of the parts made [s].
    made, good : int
        Parts made (good or rejected) and good parts.

    Returns
    -------
    dict
        ``availability``, ``performance``, ``quality``, ``oee`` (each in [0, 1] or None when its
        denominator is 0), ``downtime_s`` and ``run_time_s`` [s].
    """
    run = planned_s - downtime_s
    availability, performance, quality = _ratio(run, planned_s), _ratio(ideal_s, run), _ratio(good, made)
    terms = (availability, performance, quality)
    oee = round(availability * performance * quality, 4) if None not in terms else None
    return {"availability": availability, "performance": performance, "quality": quality, "oee": oee,
            "downtime_s": round(downtime_s, 3), "run_time_s": round(run, 3)}


class OeeCounter:
    """The OEE terms at increasing times, in one pass over a run's log.

    Parameters
    ----------
    ideal_cycle_s : mapping of job id to float
        Each job's ideal cycle [s].
    losses : iterable of Loss
        The run's losses (:attr:`DowntimeLedger.losses`).
    """

    def __init__(self, ideal_cycle_s: Mapping[int, float], losses: Iterable[Loss]) -> None:
        self.ideal_cycle_s = ideal_cycle_s
        self.losses = tuple(losses)
        self.made = self.good = 0
        self.ideal = 0.0
        self._failed: set[int] = set()
        self._scrapped: set[int] = set()

    def take(self, entry: Any) -> None:
        """Count one log entry (:class:`~robotprog.cellsim.LogEntry`), in log order."""
        if entry.event == INSPECT_FAIL:
            self._failed.add(entry.job)
        elif entry.event in SCRAPPED:
            self._scrapped.add(entry.job)
        elif entry.event == SORTED:
            if entry.job in self._scrapped:
                self._scrapped.discard(entry.job)
                return
            self.made += 1
            self.ideal += float(self.ideal_cycle_s.get(entry.job, 0.0))
            if entry.job in self._failed:
                self._failed.discard(entry.job)
            else:
                self.good += 1

    def at(self, t: float, horizon: float | None = None) -> dict[str, Any]:
        """:func:`oee_terms` with ``t`` [s] the planned production time and the entries taken so
        far; losses counted up to ``horizon`` [s] (default ``t``; ``math.inf``: all of them)."""
        until = t if horizon is None else horizon
        downtime = sum(loss.lost_by(until) for loss in self.losses)
        return oee_terms(t, downtime, self.ideal, self.made, self.good)


def run_oee(log: Iterable[Any], ideal_cycle_s: Mapping[int, float], losses: Iterable[Loss],
            makespan_s: float) -> dict[str, Any]:
    """The OEE terms of a whole run: every entry of ``log`` and every loss, over ``makespan_s`` [s]."""
    counter = OeeCounter(ideal_cycle_s, losses)
    for entry in log:
        counter.take(entry)
    return counter.at(makespan_s, math.inf)


__all__ = ["DowntimeLedger", "Loss", "OeeCounter", "oee_terms", "run_oee"]
