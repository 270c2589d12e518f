"""What every command shares: options, error reporting, progress bars, JSON output.

Exit codes: 0 success; 1 bad input or a failed stage (``error: <file>: <problem>`` on
stderr, no traceback, no output file); 2 command-line usage; 3 the command ran and wrote its
outputs, with findings: ``verify`` (and ``plan``) found the program gouges the part or crashes a
rapid, ``inspect`` failed a part, ``simulate`` ended an order ``failed`` or ``rejected``.
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import re
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Annotated, Any, TypeVar

import typer
from rich.console import Console

if TYPE_CHECKING:
    from rich.progress import Progress

from factory.core.errors import FactoryError

EXIT_ERROR = 1
#: Done, outputs written, with findings (a gouge, a failed part, an order not done).
EXIT_FINDINGS = 3
EXIT_VERIFY_FAILED = EXIT_FINDINGS

# soft_wrap: a line is never broken inside a figure (``p95 \n0.005 mm``) when stderr is a pipe or a
# log, where rich would otherwise wrap at 80 columns; a terminal wraps long lines itself.
stderr = Console(stderr=True, soft_wrap=True)

Overwrite = Annotated[bool, typer.Option("--overwrite", help="Replace output files that exist.")]
JsonFlag = Annotated[bool, typer.Option("--json", help="Print a JSON summary on stdout.")]
Quiet = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bars or summaries on stderr.")]

F = TypeVar("F", bound=Callable[..., Any])


def reports_errors(fn: F) -> F:
    """Turn a :class:`FactoryError` into one line on stderr and exit code 1."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except FactoryError as e:
            # markup=False: file names may contain brackets.
            stderr.print(f"error: {e}", markup=False, highlight=False, soft_wrap=True)
            raise typer.Exit(EXIT_ERROR) from None

    return wrapper  # type: ignore[return-value]


def setup_logging(quiet: bool) -> None:
    """Library warnings to stderr; only the CLI configures logging."""
    logging.basicConfig(
        level=logging.ERROR if quiet else logging.WARNING,
        format="%(levelname)s: %(name)s: %(message)s",
        stream=sys.stderr,
    )


class StageProgress:
    """Rich progress bars on stderr, one per named stage, fed by library callbacks."""

    def __init__(self, progress: Progress | None):
        self._progress = progress
        self._tasks: dict[str, Any] = {}

    def __call__(self, stage: str, done: int, total: int) -> None:
        if self._progress is None:
            return
        if stage not in self._tasks:
            self._tasks[stage] = self._progress.add_task(stage, total=max(total, 1))
        self._progress.update(self._tasks[stage], completed=done, total=max(total, 1))

    def stage(self, name: str) -> Callable[[int, int], None]:
        """A ``progress(done, total)`` callback for one stage."""
        return lambda done, total: self(name, done, total)


#: A line :class:`StageLines` writes: ``[  12.3 s] waterline ...`` as a stage starts, ``[  20.1 s]
#: waterline done in 7.8 s`` as it ends (seconds since the command started).
STAGE_LINE = re.compile(r"^\[ *\d+\.\d s\] \S.*( \.\.\.| done in \d+\.\d s)$")

#: How long [s] a command runs before its stage lines show. Bad input fails within it and says only its
#: one ``error:`` line (the slowest, a STEP file with no geometry, takes 2 s loaded: OpenCASCADE's
#: start-up); a command that runs on shows the lines held back, then each as it comes. A plan of the
#: smallest sample takes 5 s.
STAGE_LINES_AFTER_S = 3.0


class StageLines(StageProgress):
    """Stages as plain lines on stderr (:data:`STAGE_LINE`), for a pipe or a log, where bars cannot show.

    A stage shows when it first reports and when it reaches its total; once ended, it shows again
    only when it starts over from 0 (a stage timed twice), so a stage that reports its end more than
    once, or steps on after it, adds no lines. A stage that fails shows no end: the error says why.

    The lines are held back for the command's first ``after`` seconds [s] (a timer then prints them,
    with the times they happened at); :meth:`close` prints those still held when the command succeeded
    sooner, and drops them when it failed, so a quick failure leaves its ``error:`` line alone.
    """

    def __init__(self, after: float = STAGE_LINES_AFTER_S) -> None:
        super().__init__(None)
        self._t0 = time.perf_counter()
        self._open: dict[str, float] = {}  # running stage -> when it started
        self._ended: set[str] = set()
        # Printing under the lock keeps the lines in order when the timer releases them as a stage reports.
        self._lock = threading.Lock()
        self._held: list[str] | None = []  # None once released
        self._timer = threading.Timer(after, self._release)
        self._timer.daemon = True  # never keeps a finished command alive
        self._timer.start()

    def __call__(self, stage: str, done: int, total: int) -> None:
        now = time.perf_counter()
        if stage not in self._open and (stage not in self._ended or done == 0):
            self._ended.discard(stage)
            self._open[stage] = now
            self._line(now, f"{stage} ...")
        if stage in self._open and done >= total:
            self._line(now, f"{stage} done in {now - self._open.pop(stage):.1f} s")
            self._ended.add(stage)

    def close(self, failed: bool) -> None:
        """The command's stages are over: print the lines still held back, or drop them if it ``failed``."""
        self._timer.cancel()
        if failed:
            with self._lock:
                self._held = None
        else:
            self._release()

    def _line(self, now: float, text: str) -> None:
        line = f"[{now - self._t0:6.1f} s] {text}"
        with self._lock:
            if self._held is not None:
                self._held.append(line)
            else:
                stderr.print(line, highlight=False, markup=False)

    def _release(self) -> None:
        with self._lock:
            for line in self._held or ():
                stderr.print(line, highlight=False, markup=False)
            self._held = None


@contextlib.contextmanager
def progress_bars(quiet: bool, lines_when_piped: bool = False) -> Iterator[StageProgress]:
    """Progress bars on stderr (nothing when ``quiet``; when stderr is not a terminal, where a
    transient bar leaves only a blank line, nothing, or with ``lines_when_piped`` one line as each
    stage starts and ends, :class:`StageLines`, for a command that can run for minutes)."""
    if quiet or not stderr.is_terminal:
        if not (lines_when_piped and not quiet):
            yield StageProgress(None)
            return
        lines = StageLines()
        try:
            yield lines
        except typer.Exit as e:  # a command's own exit: it ran (3: with findings), or was told to stop
            lines.close(failed=e.exit_code not in (0, EXIT_FINDINGS))
            raise
        except BaseException:
            lines.close(failed=True)
            raise
        lines.close(failed=False)
        return
    # Here, not at the top: a quiet run (every workflow job) draws no bars.
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(
        TextColumn("{task.description:>10}"),
        BarColumn(),
        TextColumn("{task.percentage:>3.0f}%"),
        TimeElapsedColumn(),
        console=stderr,
        transient=True,
    ) as p:
        yield StageProgress(p)


def print_json(data: Any) -> None:
    """One JSON document on stdout, for scripts."""
    sys.stdout.write(json.dumps(data, indent=2, sort_keys=False) + "\n")


def parse_triple(text: str | None, name: str) -> tuple[float, float, float] | None:
    """``"100,60,25"`` → ``(100.0, 60.0, 25.0)``; a usage error names the option."""
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(v > 0 for v in values):
        raise typer.BadParameter(f"expected three positive sizes in mm like 100,60,25, got {text!r}", param_hint=name)
    return values  # type: ignore[return-value]
