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
from collections.abc import Callable, Sequence
from typing import Any

log = logging.getLogger(__name__)

#: Processes at most: the processors this process may run on, at most 4.
WORKERS = max(1, min(4, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)))


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
    workers = min(WORKERS, n)
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
