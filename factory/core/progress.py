"""Progress and wall-time bookkeeping for pipelines a Python user calls (no terminal, no rich).

A pipeline reports progress through a plain callback ``progress(stage, done, total)``; the CLI
draws it as progress bars, a script may log it or pass ``None``.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import threading
import time
from collections.abc import Callable, Iterator

#: ``progress(stage, done, total)``: which stage is running and how far it is.
Progress = Callable[[str, int, int], None]


def stage_callback(progress: Progress | None, stage: str) -> Callable[[int, int], None] | None:
    """A ``progress(done, total)`` callback for one stage of ``progress`` (None stays None)."""
    if progress is None:
        return None
    return lambda done, total: progress(stage, done, total)


def held_open(progress: Progress | None) -> Progress | None:
    """``progress`` for the finer steps of stages timed around them: each of its stages counts to one
    more than the total it is given, so the counted steps never end the stage. The timer around
    them (a :class:`Stopwatch` stage of the same name) ends it, after the work that follows the
    counted steps (a finishing pass counts its grid, then links and checks its moves uncounted), so
    a pipe's line ``... done in`` comes when the stage is done. None stays None."""
    if progress is None:
        return None
    return lambda stage, done, total: progress(stage, done, total + 1)


class Stopwatch:
    """Wall time per named stage [s], in the order the stages ran.

    A stage begun inside another (on the same thread: the roadmap a robot plan asks for on its way)
    has its seconds counted in its own name only, not in the enclosing stage's too, so the stages'
    seconds add up to the run's.

    With ``progress``, every stage also says when it starts (``progress(name, 0, 1)``) and, unless it
    raised, when it ends (``progress(name, 1, 1)``), so a stage that reports nothing finer (the robot's
    planning) still shows which stage is running, and for how long; one that does report finer steps
    under the same name fills in between.
    """

    def __init__(self, progress: Progress | None = None, clock: Callable[[], float] = time.perf_counter) -> None:
        self.seconds: dict[str, float] = {}
        self._progress = progress
        self._clock = clock  # [s]
        self._open = threading.local()  # per thread: seconds spent in stages begun inside each open one

    @contextlib.contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        if self._progress is not None:
            self._progress(name, 0, 1)
        inner: list[float] = self._open.__dict__.setdefault("inner", [])
        inner.append(0.0)
        t0 = self._clock()
        try:
            yield
        finally:
            took = self._clock() - t0
            self.seconds[name] = self.seconds.get(name, 0.0) + took - inner.pop()
            if inner:
                inner[-1] += took
        # Only a stage that got through ends: a failed one is not "done", its error says what happened.
        if self._progress is not None:
            self._progress(name, 1, 1)

    @property
    def progress(self) -> Progress | None:
        """The ``progress`` callback the stages report to (None: nobody listens)."""
        return self._progress

    def rounded(self) -> dict[str, float]:
        """Seconds per stage, rounded to the millisecond."""
        return {k: round(v, 3) for k, v in self.seconds.items()}


class ProgressRelay:
    """``progress`` for work in a forked process, shown here as it happens.

    Call the relay as a :data:`Progress` in the child (it inherits the relay when forked): each report
    crosses a pipe and a thread here hands it to ``progress`` at once, so a stage running beside this
    process's own says when it starts and ends. Called in this process (the work run here after all),
    it reports directly. :meth:`close` returns when every report sent before it has been shown.
    With ``progress`` None it reports nothing and starts no thread.
    """

    def __init__(self, progress: Progress | None) -> None:
        self._progress = progress
        self._pid = os.getpid()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        if progress is not None:
            self._recv, self._send = multiprocessing.Pipe(duplex=False)
            self._thread = threading.Thread(target=self._show, name="progress relay", daemon=True)
            self._thread.start()

    def __call__(self, stage: str, done: int, total: int) -> None:
        if self._progress is None:
            return
        if os.getpid() == self._pid:
            self._progress(stage, done, total)
        else:  # one small message: one write to the pipe, whole even beside other writers
            self._send.send((stage, done, total))

    def _show(self) -> None:
        while True:
            try:
                report = self._recv.recv()
            except (EOFError, OSError):
                return
            if report is None:
                return
            try:
                self._progress(*report)  # type: ignore[misc]
            except Exception as e:  # noqa: BLE001 - raised by close(); the pipe is drained meanwhile
                self._error = self._error or e

    def close(self) -> None:
        """Show what the child sent (it has finished or been ended) and stop the thread."""
        if self._thread is None:
            return
        # after everything the child wrote before it finished: the pipe keeps the order of writes
        self._send.send(None)
        self._thread.join()
        self._thread = None
        self._send.close()
        self._recv.close()
        if self._error is not None:
            raise self._error
