"""An MCAP log written by a second process, for logs that are big enough to keep one processor busy.

Writing a cell run's log is two kinds of work: making the messages (sampling motion, forward
kinematics, CDR) and the file's own (the ``mcap`` writer's records and indexes, zstd on every chunk).
The second was about a third of ``factory simulate --mcap`` (issue 35), and it needs nothing from the
first but the bytes. :class:`ForkedMcapLog` takes :class:`factory.mcaplog.McapLog`'s calls here,
checks them as it would (topics, types, latching, log times), and hands them in batches to a forked
process that replays them into a :class:`~factory.mcaplog.McapLog`: the same calls in the same order,
so the same file. The file appears only when both ends finish cleanly, as with one process: a writer
that fails, or a caller that fails or dies (the writer sees its end of the pipe close), leaves nothing.
"""

from __future__ import annotations

import contextlib
import glob
import multiprocessing
from pathlib import Path
from types import TracebackType
from typing import Any, Mapping

from cadcam.parallel import processors
from factory.core.atomic import check_writable, part_prefix
from factory.core.errors import McapError
from factory.mcaplog import LogBuffer, McapLog, check_attachment, check_channel, check_time, serialized

#: Message bytes gathered before a batch goes to the writer [bytes]: few enough sends that the
#: pipe's cost is small, small enough that the two processes overlap.
BATCH_BYTES = 4 << 20


class ForkedMcapLog:
    """:class:`factory.mcaplog.McapLog`, written by a forked process. Use as a context manager.

    Takes :meth:`write`, :meth:`write_cdr` and :meth:`attach` as McapLog does, with the same
    parameters; errors in the calls are raised at the call, the writer's own (a full disk) on leaving
    the block.
    """

    def __init__(self, path: str | Path, *, stage: str, overwrite: bool = False, inputs: Mapping[str, str] = {},
                 parameters: Mapping[str, object] = {}) -> None:
        self.path = Path(path)
        check_writable(self.path, overwrite)  # before anything is computed, as McapLog does
        self._log = dict(path=self.path, stage=stage, overwrite=overwrite, inputs=dict(inputs),
                         parameters=dict(parameters))
        self._channels: dict[str, tuple[str, bool]] = {}
        self._attachments: set[str] = set()
        self._batch, self._bytes = LogBuffer(), 0
        self._proc: Any = None
        self._conn: Any = None

    def __enter__(self) -> "ForkedMcapLog":
        if self._proc is not None:
            raise McapError("the log is already open", source=self.path)
        ctx = multiprocessing.get_context("fork")
        self._conn, theirs = ctx.Pipe()
        self._proc = ctx.Process(target=_write, args=(theirs, self._conn, self._log), daemon=True)
        self._proc.start()
        theirs.close()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> bool:
        if self._proc is None:
            return False
        failure = None
        try:
            if exc_type is None:
                self._send()
                self._conn.send(None)  # the end: the writer finishes the file
                failure = self._conn.recv()
        except (EOFError, OSError) as e:
            failure = f"the log's writer process ended early: {e}"
        finally:
            self._conn.close()  # without the end, the writer leaves no file
            self._proc.join()
            if self._proc.exitcode != 0:  # killed, it could not remove its temporary file: we do
                _remove_parts(self.path, self._proc.pid)
            self._proc = self._conn = None
        if exc_type is None and failure is not None:
            raise McapError(failure, source=self.path)
        return False

    def write(self, topic: str, msg: Any, log_time_ns: int, *, latched: bool = False) -> None:
        """As :meth:`factory.mcaplog.McapLog.write`."""
        typename, data = serialized(topic, msg, self.path)
        self.write_cdr(topic, typename, data, log_time_ns, latched=latched)

    def write_cdr(self, topic: str, typename: str, data: bytes, log_time_ns: int, make: Any = None, *,
                  latched: bool = False) -> None:
        """As :meth:`factory.mcaplog.McapLog.write_cdr`."""
        self._require_open()
        check_time(log_time_ns, "log time")
        if not check_channel(topic, typename, latched, self._channels.get(topic), self.path):
            self._channels[topic] = (typename, latched)
        self._batch.write_cdr(topic, typename, data, log_time_ns, latched=latched)
        self._gathered(len(data))

    def attach(self, name: str, media_type: str, data: bytes, log_time_ns: int = 0) -> None:
        """As :meth:`factory.mcaplog.McapLog.attach`."""
        self._require_open()
        check_attachment(name, data, log_time_ns, self._attachments, self.path)
        self._attachments.add(name)
        self._batch.attach(name, media_type, data, log_time_ns)
        self._gathered(len(data))

    def _require_open(self) -> None:
        if self._conn is None:
            raise McapError("the log is not open; use it in a with block", source=self.path)

    def _gathered(self, size: int) -> None:
        self._bytes += size
        if self._bytes >= BATCH_BYTES:
            self._send()

    def _send(self) -> None:
        try:
            self._conn.send(self._batch)
        except OSError as e:  # the writer died: its error, if it sent one, is the one to give
            try:
                failure = self._conn.recv() if self._conn.poll() else None
            except EOFError:
                failure = None
            raise McapError(failure or f"the log's writer process ended early: {e}", source=self.path) from None
        self._batch, self._bytes = LogBuffer(), 0


def _remove_parts(path: Path, pid: int) -> None:
    """Remove the temporary files the writer process ``pid`` left for ``path``
    (:func:`factory.core.atomic.part_prefix`)."""
    for part in path.parent.glob(f"{glob.escape(part_prefix(path, pid))}*.part"):
        with contextlib.suppress(FileNotFoundError):
            part.unlink()


def _write(conn: Any, callers: Any, log: dict[str, Any]) -> None:
    """The writer: batches from ``conn`` replayed into the log until the end (None), then None sent
    back, or the error's text; a pipe closed before the end fails the log, which then leaves no file.
    ``callers``: the caller's end of the pipe, which the fork copied: closed, so that the caller's
    closing it is seen here."""
    callers.close()
    try:
        with McapLog(**log) as m:
            while (batch := conn.recv()) is not None:
                batch.replay(m)
        conn.send(None)
    except BaseException as e:  # noqa: BLE001 - any failure is the caller's to report
        try:
            conn.send(e.message if isinstance(e, McapError) else f"{type(e).__name__}: {e}")
        except OSError:
            pass  # the caller is gone
    finally:
        conn.close()


def big_log(path: str | Path, *, stage: str, overwrite: bool = False, inputs: Mapping[str, str] = {},
            parameters: Mapping[str, object] = {}) -> McapLog | ForkedMcapLog:
    """The log for ``path`` (McapLog's parameters), written by a second process where one can be had
    (:func:`cadcam.parallel.processors`, ``FACTORY_THREADS``) and here otherwise: the same file either way."""
    forked = processors() > 1 and "fork" in multiprocessing.get_all_start_methods()
    return (ForkedMcapLog if forked else McapLog)(path, stage=stage, overwrite=overwrite, inputs=inputs,
                                                  parameters=parameters)
