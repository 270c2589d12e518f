"""A live view of a run for the Foxglove app: the log's own channels over Foxglove's WebSocket protocol.

:class:`LiveView` takes the same ``write(topic, msg, log_time_ns, latched=...)`` calls as
:class:`factory.mcaplog.McapLog` and publishes each message, CDR-encoded with its ``ros2msg`` schema,
on a server of the ``foxglove-sdk`` (``foxglove.start_server``): the Foxglove app connected to
``ws://HOST:PORT`` shows what the MCAP file holds, while it is produced. Messages are paced to
``speed`` times the log's own clock, and the server's time follows the log's. Publishing never
waits for a client: with nobody connected the messages are simply dropped. Latched messages (the
robot description, static transforms, the cell's boxes) are sent again to each new subscriber.

The server binds 127.0.0.1 unless told otherwise.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any, Protocol

import foxglove

from factory.core.errors import LiveError
from factory.rosmsgs import TYPESTORE, message_definition

log = logging.getLogger(__name__)


class LiveSink(Protocol):
    """Where a run's messages go as they are written: the MCAP log, the Foxglove live view, the ROS 2
    graph (:class:`factory.ros2.Ros2Graph`). A context manager; leaving it closes the sink."""

    def write(self, topic: str, msg: Any, log_time_ns: int, *, latched: bool = False) -> None: ...

    def __enter__(self) -> Any: ...

    def __exit__(self, *exc: object) -> None: ...


class Fanout:
    """``write(topic, msg, log_time_ns, latched=...)`` to every sink in turn; leaving it leaves each."""

    def __init__(self, sinks: list[Any]) -> None:
        self.sinks = sinks

    def write(self, topic: str, msg: Any, log_time_ns: int, *, latched: bool = False) -> None:
        for sink in self.sinks:
            sink.write(topic, msg, log_time_ns, latched=latched)

    def write_cdr(self, topic: str, typename: str, data: bytes, log_time_ns: int, make: Any = None, *,
                  latched: bool = False) -> None:
        """A message already serialised (``data``, CDR of type ``typename``) to the sinks that take it
        so (:meth:`factory.mcaplog.McapLog.write_cdr`); the others get the message ``make()`` builds."""
        msg = None
        for sink in self.sinks:
            if hasattr(sink, "write_cdr"):  # a log, or a fanout of its own: it passes ``make`` on
                sink.write_cdr(topic, typename, data, log_time_ns, make, latched=latched)
            else:
                msg = make() if msg is None else msg
                sink.write(topic, msg, log_time_ns, latched=latched)

    def __enter__(self) -> "Fanout":
        return self

    def __exit__(self, *exc: object) -> None:
        for sink in self.sinks:
            sink.__exit__(*exc)


class Pacer:
    """Plays log time at ``speed`` times real time: :meth:`wait` returns once the wall clock has
    reached a message's log time, counted from the first message waited for.

    Several pacers over one stream (a live view and the ROS 2 graph together) agree: the first
    sleeps, the others find the time already come. Once ``cancel`` (an event) is set, nothing
    waits any more: the rest of the stream goes out at once.
    """

    def __init__(self, speed: float, *, cancel: threading.Event | None = None) -> None:
        if not speed > 0:
            raise LiveError(f"speed must be positive, got {speed}", source="--speed")
        self.speed = float(speed)
        self._cancel = cancel
        self._start: tuple[float, int] | None = None  # (wall [s], log time [ns]) of the first message

    def wait(self, log_time_ns: int) -> None:
        """Sleep until log time ``log_time_ns`` [ns] is due; ``speed`` inf: never sleep."""
        if self._start is None:
            self._start = (time.monotonic(), log_time_ns)
        wall0, t0 = self._start
        if self.speed != float("inf"):
            delay = wall0 + (log_time_ns - t0) * 1e-9 / self.speed - time.monotonic()
            if delay > 0:
                if self._cancel is None:
                    time.sleep(delay)
                else:
                    self._cancel.wait(delay)


class _Subscriptions(foxglove.ServerListener):
    """Replays the latched messages of a channel to whoever subscribes to it."""

    def __init__(self, view: "LiveView") -> None:
        self.view = view

    def on_subscribe(self, client: Any, channel: Any) -> None:
        self.view._resend_latched(channel.topic)


class LiveView:
    """A Foxglove WebSocket server that publishes a log's messages as they are written.

    Parameters
    ----------
    port : int
        TCP port to listen on (0: any free port, see :attr:`port`).
    host : str
        Address to bind; 127.0.0.1 (this machine only) unless told otherwise.
    speed : float
        Messages are published at ``speed`` times the log's clock: a message logged at t [s]
        goes out ``t / speed`` [s] of wall time after the first one. ``inf``: no pacing.
    name : str
        Server name shown in the Foxglove app.

    Raises
    ------
    LiveError
        The server cannot listen on ``host:port``.
    """

    def __init__(self, port: int, *, host: str = "127.0.0.1", speed: float = 1.0, name: str = "factory") -> None:
        self._pacer = Pacer(speed)
        self.speed = self._pacer.speed
        self._context = foxglove.Context()
        self._channels: dict[str, Any] = {}
        self._latched: dict[str, bytes] = {}
        self._lock = threading.Lock()
        try:
            # Time: the app's clock follows the log's (broadcast_time), not the wall clock.
            self._server = foxglove.start_server(name=name, host=host, port=port, context=self._context,
                                                 capabilities=[foxglove.Capability.Time],
                                                 server_listener=_Subscriptions(self))
        except Exception as e:  # the SDK raises its own error types for bind failures
            raise LiveError(f"cannot serve on {host}:{port}: {e}", source="--serve") from None
        self.host = host
        self.port = int(self._server.port)
        log.info("live view on ws://%s:%d", host, self.port)

    def write(self, topic: str, msg: Any, log_time_ns: int, *, latched: bool = False) -> None:
        """Publish ``msg`` on ``topic`` at its time in the log [ns], waiting for that time to come."""
        typename = msg.__msgtype__
        data = bytes(TYPESTORE.serialize_cdr(msg, typename))
        with self._lock:
            channel = self._channels.get(topic)
            if channel is None:
                schema = foxglove.Schema(name=typename, encoding="ros2msg",
                                         data=message_definition(typename).encode())
                channel = foxglove.Channel(topic, schema=schema, message_encoding="cdr", context=self._context)
                self._channels[topic] = channel
            if latched:
                self._latched[topic] = data
        if log_time_ns > 0:
            self._pacer.wait(log_time_ns)
            self._server.broadcast_time(int(log_time_ns))
        channel.log(data, log_time=int(log_time_ns))

    def _resend_latched(self, topic: str) -> None:
        with self._lock:
            data, channel = self._latched.get(topic), self._channels.get(topic)
        if data is not None and channel is not None:
            channel.log(data)

    def close(self) -> None:
        """Stop the server; connected clients see it close."""
        self._server.stop()

    def __enter__(self) -> "LiveView":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
