"""Independent pieces of CAM work on the machine's other processors.

Some stages are many independent Python-heavy jobs (arc fitting, one per operation) that
threads cannot share out (the interpreter lock). Forked worker processes can: they start
with everything the parent imported and built, so only each job's arguments and result
cross over (pickled). Work too small to pay for a fork (~20 ms) runs here, in order.
"""

from __future__ import annotations

import concurrent.futures
import logging
import multiprocessing
import os
import time
from collections.abc import Callable, Sequence
from typing import Any

from factory.core.errors import FactoryError, shown

log = logging.getLogger(__name__)

#: Environment variable: how many processors factory may use, a batch job's share of a node
#: (the workflow sets it to Snakemake's ``{threads}``). Unset, factory uses what it may run on.
THREADS_ENV = "FACTORY_THREADS"
#: Worker processes or threads of one stage at most: more buys little for the work's size.
MAX_WORKERS = 4


def processors() -> int:
    """Processors one stage may use for its workers or threads: ``FACTORY_THREADS`` when set,
    else the processors this process may run on (its CPU affinity: a Slurm job's allocation, a
    ``taskset``); at most :data:`MAX_WORKERS`. 1 means everything runs in the calling thread.

    Raises
    ------
    FactoryError
        ``FACTORY_THREADS`` is set but is not a whole number of at least 1.
    """
    text = os.environ.get(THREADS_ENV, "").strip()
    if text:
        try:
            n = int(text)
        except ValueError:
            n = 0
        if n < 1:
            raise FactoryError(f"expected a whole number of processors, at least 1, got {shown(text)}",
                               source=THREADS_ENV)
    else:
        n = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(MAX_WORKERS, n))


def idle_processors() -> float:
    """Processors of the whole machine that no runnable process uses now: its processor count less its
    one-minute load average (the runnable processes, this one included) [processors]; :func:`processors`
    where the system keeps no load average. Work begun on speculation (it may be thrown away) waits for an
    idle processor: on a machine a test suite's workers or a workflow's jobs keep busy it would only slow
    the work that counts. :class:`IdleMeter` reads the last seconds instead of the last minute."""
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):
        return float(processors())
    return (os.cpu_count() or 1) - load


#: The kernel's processor-time counters of the whole machine (Linux).
PROC_STAT = "/proc/stat"
#: Shortest span :class:`IdleMeter` judges [s]: below it the kernel's clock ticks (10 ms) are too few.
MIN_SPAN = 0.25


def _machine_times() -> tuple[float, float] | None:
    """(idle, all) processor time of the whole machine since boot [clock ticks, all processors]: idle
    counts waiting on I/O too. None where the system has no ``/proc/stat``."""
    try:
        with open(PROC_STAT, "rb") as f:
            fields = f.readline().split()
    except OSError:
        return None
    if not fields or fields[0] != b"cpu" or len(fields) < 5:
        return None
    ticks = [float(v) for v in fields[1:9]]  # user nice system idle iowait irq softirq steal (no guest: in user)
    return ticks[3] + ticks[4], sum(ticks)


class IdleMeter:
    """Processors the whole machine left idle over a span just past, read from the kernel's counters.

    :func:`idle_processors` reads the one-minute load average: it lags a minute behind, and counts this
    process's own second thread and processes (a plan's robot, its forked workers) as load for that minute
    after they end, so on a quiet two-processor machine it hardly ever says one is idle. This reads what
    happened between two of its own readings (:meth:`idle`), a stage or two of a plan:
    a processor the plan's other work left idle then shows.
    """

    def __init__(self) -> None:
        self._mark = _machine_times()
        self._at = time.monotonic()

    def idle(self, own: float = 0.0) -> float | None:
        """Processors idle on average since the span began [processors, 0 .. the machine's count], and a new
        span begun; None while the span is shorter than :data:`MIN_SPAN` (too short to tell: it goes on).
        ``own``: processor time the owner's work of lower priority took in the span [s], counted idle (it
        gave way to everything else). Without the kernel's counters, :func:`idle_processors`."""
        if self._mark is None:
            return idle_processors()
        at = time.monotonic()
        span = at - self._at
        if span < MIN_SPAN:
            return None
        now = _machine_times()
        if now is None:
            return idle_processors()
        (idle0, all0), (idle1, all1) = self._mark, now
        self._mark, self._at = now, at
        if all1 <= all0:
            return None
        count = os.cpu_count() or 1
        return min(float(count), count * (idle1 - idle0) / (all1 - all0) + own / span)


def process_map(fn: Callable[..., Any], jobs: Sequence[tuple], weights: Sequence[float], min_total: float,
                done: Callable[[int], None] | None = None) -> list[Any]:
    """``[fn(*args) for args in jobs]``, in forked worker processes when the work is worth it.

    Parameters
    ----------
    fn : callable
        A module-level function (workers find it by name); ``fn(*args)`` must depend on
        nothing but its arguments, which and whose result must pickle.
    jobs : sequence of tuple
        Arguments of each call.
    weights : sequence of float
        Rough cost of each job (e.g. its point count): the heaviest start first, and below
        ``min_total`` in all, or with one job, everything runs in this process.
    done : callable, optional
        ``done(i)`` in this process as job ``i`` finishes.

    Returns
    -------
    list
        Results in the order of ``jobs``: the same as the serial loop's. An exception of a
        job is raised here as it would be in the loop. If processes cannot be had (no
        ``fork``, a broken pool), the jobs run here.
    """
    n = len(jobs)
    workers = min(processors(), n)
    if workers < 2 or sum(weights) < min_total or "fork" not in multiprocessing.get_all_start_methods():
        return _serial(fn, jobs, done)
    order = sorted(range(n), key=lambda i: -weights[i])
    results: list[Any] = [None] * n
    try:
        with concurrent.futures.ProcessPoolExecutor(max_workers=workers,
                                                    mp_context=multiprocessing.get_context("fork")) as pool:
            futures = {pool.submit(fn, *jobs[i]): i for i in order}
            for f in concurrent.futures.as_completed(futures):
                i = futures[f]
                results[i] = f.result()
                if done is not None:
                    done(i)
    except (concurrent.futures.process.BrokenProcessPool, OSError) as e:
        log.info("worker processes unavailable (%s): running %d jobs here", e, n)
        return _serial(fn, jobs, done)
    return results


def _serial(fn, jobs, done):
    out = []
    for i, args in enumerate(jobs):
        out.append(fn(*args))
        if done is not None:
            done(i)
    return out


class Background:
    """``fn(*args)`` started in a forked process now, its result taken later with :meth:`result`.

    For a stage that overlaps another in this process (the program's verification while the
    robot's moves are planned). Where processes cannot be had, or the child fails in any
    way, :meth:`result` computes ``fn(*args)`` here: the answer, or the error, is then
    exactly the serial one. :meth:`cancel` ends the child (the parent failed meanwhile).
    """

    def __init__(self, fn: Callable[..., Any], *args: Any):
        self._fn, self._args = fn, args
        self._proc = None
        self._conn = None
        if processors() < 2 or "fork" not in multiprocessing.get_all_start_methods():
            return
        ctx = multiprocessing.get_context("fork")
        try:
            self._conn, send = ctx.Pipe(duplex=False)
            self._proc = ctx.Process(target=_child, args=(send, fn, args), daemon=True)
            self._proc.start()
            send.close()
        except OSError as e:
            log.info("no worker process (%s): %s runs here", e, getattr(fn, "__name__", fn))
            self.cancel()

    def ready(self, wait: float = 0.0) -> bool:
        """Whether the child has answered, so that :meth:`result` returns at once, having waited up to ``wait``
        [s] for it. False while it works, for a child that ended without an answer, and with no child
        (:meth:`result` does the work here then)."""
        if self._proc is None:
            return False
        try:
            return bool(self._conn.poll(wait))
        except (EOFError, OSError):
            return False

    def processor_time(self) -> float | None:
        """Processor time the child has had so far, all its threads [s]; None with no child, or where the
        system does not say (no ``/proc``)."""
        if self._proc is None or self._proc.pid is None:
            return None
        try:
            with open(f"/proc/{self._proc.pid}/stat", "rb") as f:
                fields = f.read().rsplit(b")", 1)[1].split()  # after the command's name, which may hold spaces
            return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime
        except (OSError, IndexError, ValueError):
            return None

    def outcome(self) -> tuple[bool, Any]:
        """``(True, value)`` of the child, waiting for it; ``(False, None)`` with no child or one that failed:
        nothing is run here (for work only worth doing meanwhile, :class:`factory.verify.VerifyAhead`)."""
        ok, value = False, None
        if self._proc is not None:
            try:
                ok, value = self._conn.recv()
            except (EOFError, OSError):
                pass
        self.cancel()
        return ok, value

    def result(self) -> Any:
        if self._proc is not None:
            ok, value = False, None
            try:
                ok, value = self._conn.recv()  # before join: a large result fills the pipe
            except (EOFError, OSError):
                pass
            self.cancel()
            if ok:
                return value
            log.info("%s failed in its worker process; running it here", getattr(self._fn, "__name__", self._fn))
        return self._fn(*self._args)

    def cancel(self) -> None:
        if self._proc is not None:
            if self._proc.is_alive():
                self._proc.terminate()
            self._proc.join()
            self._proc = None
        if self._conn is not None:
            self._conn.close()
            self._conn = None


def _child(conn, fn, args) -> None:
    try:
        value = fn(*args)
    except BaseException:  # noqa: BLE001 - the parent reruns it and raises the error itself
        conn.send((False, None))
    else:
        conn.send((True, value))
    finally:
        conn.close()
