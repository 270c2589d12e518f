"""The MCAP log every stage writes: ROS 2 messages for Foxglove and ``ros2 bag``.

Files follow the MCAP ``ros2`` profile the way rosbag2 writes them, so that Foxglove,
``ros2 bag info/play`` (Humble and Jazzy) and rosbags can open them without a ROS install:

* header profile ``ros2``; every channel ``cdr`` encoded, every schema ``ros2msg`` with the
  full concatenated definition text as rosbag2's ``LocalMessageDefinitionSource`` writes it:
  the top-level ``.msg`` text, then per dependency a line of 80 ``=``, a line
  ``MSG: pkg/Name`` naming the type exactly as the fields spell it, and its text (Foxglove's
  parser finds a dependency only under the name its field uses);
* channel metadata ``offered_qos_profiles`` with the QoS policies as rmw enum numbers and
  ``topic_type_hash`` (RIHS01). Humble's ``ros2 bag`` reads only numbers; Jazzy reads
  numbers when the file's ``rosbag2`` metadata record has no ``serialized_metadata``
  (it then takes the bag as metadata version 8), which is the record written here, the one
  Humble writes (``ROS_DISTRO`` only). Latched topics (``/tf_static``, a robot
  description, a static scene) offer ``transient_local`` durability, others ``volatile``;
* zstd-compressed chunks, message indexes, chunk indexes and a summary with statistics;
* a metadata record named ``factory`` (stage, version, input hashes, parameters) and
  attachments for the files the next stage reads back (the CAM job JSON).

The messages, their classes, CDR and definition texts are :mod:`factory.rosmsgs`' (rosbags' ROS 2
Jazzy typestore, :data:`factory.rosmsgs.TYPESTORE`); files are written by the ``mcap`` package's
writer through :func:`factory.core.atomic.atomic_output`, so a failed run leaves no file behind.
"""

from __future__ import annotations
from __future__ import annotations

import contextlib
import json
import logging
import struct
import sys
from collections.abc import Iterable, Mapping
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from mcap.exceptions import McapError as _McapLibError
from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType, Writer

import factory
from factory.core.atomic import atomic_output, check_writable
from factory.core.errors import McapError
from factory.rosmsgs import ROS_DISTRO, TYPESTORE, message_definition, serialize_cdr

# What the mcap reader raises on a file that is not MCAP or is cut short.
_READ_ERRORS = (_McapLibError, EOFError, OSError, ValueError, StopIteration, struct.error)

log = logging.getLogger(__name__)

#: Name of the metadata record that describes the run that wrote the file.
FACTORY_METADATA = "factory"

_UINT64_MAX = 2**64 - 1


#: Name of the metadata record ``ros2 bag`` reads the bag's distribution (and on Jazzy its
#: metadata version) from.
ROSBAG2_METADATA = "rosbag2"

# rmw enum numbers (rmw/types.h), the form both Humble and Jazzy read (see the module doc):
# history 1 keep_last; reliability 1 reliable; durability 1 transient_local, 2 volatile;
# liveliness 1 automatic. Durations are RMW_DURATION_INFINITE {sec: INT64_MAX // 1e9,
# nsec: INT64_MAX % 1e9}, as recorded from publishers that left deadline, lifespan and lease
# at their defaults.
_HISTORY_KEEP_LAST = 1
_RELIABILITY_RELIABLE = 1
_DURABILITY_TRANSIENT_LOCAL = 1
_DURABILITY_VOLATILE = 2
_LIVELINESS_AUTOMATIC = 1
_QOS_TEMPLATE = f"""\
- history: {_HISTORY_KEEP_LAST}
  depth: {{depth}}
  reliability: {_RELIABILITY_RELIABLE}
  durability: {{durability}}
  deadline:
    sec: 9223372036
    nsec: 854775807
  lifespan:
    sec: 9223372036
    nsec: 854775807
  liveliness: {_LIVELINESS_AUTOMATIC}
  liveliness_lease_duration:
    sec: 9223372036
    nsec: 854775807
  avoid_ros_namespace_conventions: false"""


def offered_qos_profiles(latched: bool) -> str:
    """The ``offered_qos_profiles`` channel metadata for a publisher, policies as rmw numbers.

    Parameters
    ----------
    latched : bool
        ``True``: keep-last 1, reliable, transient local (what ``/tf_static`` and
        ``/robot_description`` publishers offer, so late subscribers get the message on
        ``ros2 bag play``). ``False``: keep-last 10, reliable, volatile (rclcpp defaults).
    """
    if latched:
        return _QOS_TEMPLATE.format(depth=1, durability=_DURABILITY_TRANSIENT_LOCAL)
    return _QOS_TEMPLATE.format(depth=10, durability=_DURABILITY_VOLATILE)



def check_time(ns: int, what: str) -> int:
    """``ns`` as an int, or a McapError where it is not a log time [ns] an MCAP can hold."""
    if isinstance(ns, bool) or not isinstance(ns, (int, np.integer)):
        raise McapError(f"{what} must be an integer number of nanoseconds, got {ns!r}")
    ns = int(ns)
    if not 0 <= ns <= _UINT64_MAX:
        raise McapError(f"{what} {ns} ns is outside the MCAP time range [0, 2^64)")
    return ns


def check_channel(topic: str, typename: str, latched: bool, known: tuple[str, bool] | None, source: Any) -> bool:
    """Whether a message of ``typename`` (``latched`` or not) may go on ``topic``, which carries ``known`` (its
    type and latching; None: a topic not used yet): True on a known topic, False on a new one.

    Raises
    ------
    McapError
        (naming ``source``) The topic carries another type or latching, or a new topic is not absolute.
    """
    if known is not None:
        ktype, klatched = known
        if ktype != typename:
            raise McapError(f"topic {topic} carries {ktype}, not {typename}", source=source)
        if klatched != latched:
            raise McapError(f"topic {topic} was {'' if klatched else 'not '}latched before", source=source)
        return True
    if not topic.startswith("/"):
        raise McapError(f"topic {topic!r} must be absolute (start with '/')", source=source)
    return False


def check_attachment(name: str, data: bytes, log_time_ns: int, attached: set[str], source: Any) -> int:
    """The log time [ns] of attachment ``name``, new to ``attached`` (the names a log holds), with bytes ``data``.

    Raises
    ------
    McapError
        (naming ``source``) The name is attached already, ``data`` is not bytes, or the time is out of range.
    """
    if name in attached:
        raise McapError(f"attachment {name!r} written twice", source=source)
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise McapError(f"attachment {name!r} must be bytes, got {type(data).__name__}", source=source)
    return check_time(log_time_ns, "attachment log time")


class McapLog:
    """Writes one MCAP file of ROS 2 messages, atomically. Use as a context manager.

    The file appears at ``path`` only when the ``with`` block exits without an exception;
    otherwise nothing is left behind (not even the temporary file).

    Parameters
    ----------
    path : str or Path
        Destination ``.mcap`` file.
    stage : str
        The stage writing the file (``"toolpath"``, ``"verify"``, ``"plan"``, ...).
    overwrite : bool
        Replace an existing file. Without it :class:`OutputExistsError` is raised by the
        constructor, before anything is computed or written.
    inputs : mapping of str to str
        Input file name (or path) -> hex SHA-256 of its bytes, for traceability.
    parameters : mapping of str to object
        Run parameters. Strings are stored as they are, everything else JSON-encoded.

    Raises
    ------
    OutputExistsError
        ``path`` exists and ``overwrite`` is false.
    McapError
        A message cannot be serialised, a topic is reused with another type or QoS, an
        attachment name repeats, or parameters cannot be JSON-encoded.

    Examples
    --------
    >>> with McapLog("part.mcap", stage="toolpath", inputs={"part.stl": digest}) as log:
    ...     log.write("/tf_static", tf_message([transform_stamped("world", "work", np.eye(4), 0)]),
    ...               0, latched=True)
    ...     log.attach("factory.job.json", "application/json", job_bytes)
    """

    def __init__(
        self,
        path: str | Path,
        *,
        stage: str,
        overwrite: bool = False,
        inputs: Mapping[str, str] = {},
        parameters: Mapping[str, object] = {},
    ) -> None:
        self.path = Path(path)
        self.stage = stage
        self.overwrite = overwrite
        check_writable(self.path, overwrite)
        self._metadata = _factory_metadata(stage, inputs, parameters)
        self._stack: contextlib.ExitStack | None = None
        self._writer: Writer | None = None
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str, bool]] = {}  # topic -> (id, type, latched)
        self._sequence: dict[int, int] = {}
        self._attachments: set[str] = set()

    def __enter__(self) -> "McapLog":
        if self._stack is not None:
            raise McapError("McapLog is already open", source=self.path)
        stack = contextlib.ExitStack()
        f = stack.enter_context(atomic_output(self.path, overwrite=self.overwrite))
        try:
            writer = Writer(
                f,
                compression=CompressionType.ZSTD,
                index_types=IndexType.ALL,
                use_chunking=True,
                use_statistics=True,
                use_summary_offsets=True,
            )
            writer.start(profile="ros2", library=f"factory {factory.__version__}")
        except BaseException:
            stack.__exit__(*sys.exc_info())
            raise
        self._stack, self._writer = stack, writer
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> bool:
        stack, writer = self._stack, self._writer
        self._stack = self._writer = None
        if stack is None or writer is None:
            return False
        if exc_type is None:
            try:
                writer.add_metadata(ROSBAG2_METADATA, {"ROS_DISTRO": ROS_DISTRO})
                writer.add_metadata(FACTORY_METADATA, self._metadata)
                writer.finish()
            except BaseException as e:
                # The temporary file is removed by atomic_output on the way out.
                stack.__exit__(type(e), e, e.__traceback__)
                raise
            stack.__exit__(None, None, None)
            log.info("wrote %s (%d channels)", self.path, len(self._channels))
        else:
            stack.__exit__(exc_type, exc, tb)
        return False

    def _require_open(self) -> Writer:
        if self._writer is None:
            raise McapError("McapLog is not open; use it in a with block", source=self.path)
        return self._writer

    def _channel(self, topic: str, typename: str, latched: bool) -> int:
        writer = self._require_open()
        known = self._channels.get(topic)
        if check_channel(topic, typename, latched, None if known is None else known[1:], self.path):
            return known[0]
        sid = self._schemas.get(typename)
        if sid is None:
            try:
                text = message_definition(typename)
            except Exception as e:  # rosbags raises several kinds for unknown types
                raise McapError(f"no message definition for {typename}: {e}", source=self.path) from None
            sid = writer.register_schema(name=typename, encoding="ros2msg", data=text.encode())
            self._schemas[typename] = sid
        cid = writer.register_channel(
            topic=topic,
            message_encoding="cdr",
            schema_id=sid,
            metadata={
                "offered_qos_profiles": offered_qos_profiles(latched),
                "topic_type_hash": TYPESTORE.hash_rihs01(typename),
            },
        )
        self._channels[topic] = (cid, typename, latched)
        return cid

    def write(self, topic: str, msg: Any, log_time_ns: int, *, latched: bool = False) -> None:
        """Serialise ``msg`` to CDR and log it on ``topic``.

        Parameters
        ----------
        topic : str
            Absolute ROS topic name, e.g. ``"/cam/toolpath"``. Its schema and channel are
            registered on first use; later messages must have the same type and ``latched``.
        msg : rosbags message
            An instance of a :data:`TYPESTORE` class (see the builders in this module); its
            type name is taken from ``msg.__msgtype__``.
        log_time_ns : int
            Log (and publish) time [ns]; 0 for timeless views such as a toolpath.
        latched : bool
            Offer transient local durability (``/tf_static``, static scene topics).
        """
        typename, data = serialized(topic, msg, self.path)
        self.write_cdr(topic, typename, data, log_time_ns, latched=latched)

    def write_cdr(self, topic: str, typename: str, data: bytes, log_time_ns: int, make: Any = None, *,
                  latched: bool = False) -> None:
        """Log a message already serialised: ``data``, the CDR (encapsulation header included) of a
        message of type ``typename``, as :meth:`write` would have made it. ``make`` (which builds the
        message, for sinks that serialise themselves, see :class:`factory.live.Fanout`) is not needed."""
        t = check_time(log_time_ns, "log time")
        cid = self._channel(topic, typename, latched)
        seq = self._sequence.get(cid, 0)
        self._sequence[cid] = seq + 1
        self._require_open().add_message(
            channel_id=cid, log_time=t, data=data, publish_time=t, sequence=seq & 0xFFFFFFFF
        )

    def attach(self, name: str, media_type: str, data: bytes, log_time_ns: int = 0) -> None:
        """Store a file inside the log, e.g. the CAM job JSON that ``factory gcode`` reads.

        Parameters
        ----------
        name : str
            Unique attachment name, e.g. ``"factory.job.json"``.
        media_type : str
            MIME type, e.g. ``"application/json"``.
        data : bytes
        log_time_ns : int
            Log time of the attachment [ns].
        """
        writer = self._require_open()
        t = check_attachment(name, data, log_time_ns, self._attachments, self.path)
        writer.add_attachment(create_time=t, log_time=t, name=name, media_type=media_type, data=bytes(data))
        self._attachments.add(name)


def serialized(topic: str, msg: Any, source: Any) -> tuple[str, bytes]:
    """The type name and CDR of ``msg`` to log on ``topic``, or a McapError naming ``source``."""
    typename = getattr(msg, "__msgtype__", None)
    if not isinstance(typename, str):
        raise McapError(f"cannot log a {type(msg).__name__} on {topic}: not a ROS message", source=source)
    try:
        return typename, serialize_cdr(msg, typename)
    except Exception as e:  # struct.error, AttributeError, TypeError... from generated code
        raise McapError(f"cannot serialise {typename} on {topic}: {e}", source=source) from None


class LogBuffer:
    """What a pipeline logs, serialised now and written into a log later, in the same order.

    It takes :class:`McapLog`'s :meth:`~McapLog.write`, :meth:`~McapLog.write_cdr` and
    :meth:`~McapLog.attach`, so a function that logs into an open log logs into it as well: its work
    is done while something else is waited for (a plan's messages while verify runs in its own
    process); :meth:`replay` hands the same bytes to the log.
    """

    def __init__(self) -> None:
        self._calls: list[tuple[Any, ...]] = []

    def write(self, topic: str, msg: Any, log_time_ns: int, *, latched: bool = False) -> None:
        typename, data = serialized(topic, msg, None)
        self._calls.append((topic, typename, data, log_time_ns, latched))

    def write_cdr(self, topic: str, typename: str, data: bytes, log_time_ns: int, make: Any = None, *,
                  latched: bool = False) -> None:
        self._calls.append((topic, typename, data, log_time_ns, latched))

    def attach(self, name: str, media_type: str, data: bytes, log_time_ns: int = 0) -> None:
        self._calls.append((name, media_type, bytes(data), log_time_ns))

    def replay(self, log: McapLog) -> None:
        """Write everything logged here into ``log``, in order."""
        for call in self._calls:
            if len(call) == 5:
                topic, typename, data, t, latched = call
                log.write_cdr(topic, typename, data, t, latched=latched)
            else:
                log.attach(*call)


def _factory_metadata(stage: str, inputs: Mapping[str, str], parameters: Mapping[str, object]) -> dict[str, str]:
    """The string map of the ``factory`` metadata record.

    Keys: ``stage``, ``version``, ``ros_distro``, ``input:<name>`` (hex SHA-256) and
    ``param:<name>`` (strings as they are, anything else JSON).
    """
    meta = {"stage": str(stage), "version": factory.__version__, "ros_distro": ROS_DISTRO}
    for name, digest in inputs.items():
        meta[f"input:{name}"] = str(digest)
    for key, value in parameters.items():
        if isinstance(value, str):
            meta[f"param:{key}"] = value
            continue
        try:
            meta[f"param:{key}"] = json.dumps(value, sort_keys=True, default=_json_default)
        except (TypeError, ValueError) as e:
            raise McapError(f"parameter {key!r} cannot be stored as JSON: {e}") from None
    return meta


def _json_default(o: object) -> object:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


@contextlib.contextmanager
def _open_reader(path: str | Path):  # type: ignore[no-untyped-def]
    path = Path(path)
    try:
        f = open(path, "rb")
    except OSError as e:
        raise McapError(f"cannot open: {e.strerror}", source=path) from None
    with f:
        try:
            reader = make_reader(f)
            header = reader.get_header()
        except _READ_ERRORS as e:
            raise McapError(f"not an MCAP file ({e.__class__.__name__}: {e})", source=path) from None
        yield path, header, reader


def read_attachment(path: str | Path, name: str) -> bytes:
    """The bytes of attachment ``name`` in the MCAP file at ``path``.

    Raises
    ------
    McapError
        (``source=path``) The file cannot be opened, is not MCAP, or has no such attachment.
    """
    with _open_reader(path) as (p, _, reader):
        try:
            for a in reader.iter_attachments():
                if a.name == name:
                    return bytes(a.data)
        except _READ_ERRORS as e:
            raise McapError(f"corrupt MCAP file ({e.__class__.__name__}: {e})", source=p) from None
    raise McapError(f"no attachment named {name!r}", source=p)


def read_messages(path: str | Path, topics: Iterable[str]) -> list[tuple[str, int, Any]]:
    """``(topic, log_time [ns], message)`` of every message on ``topics``, in log-time order,
    decoded into rosbags message objects.

    Raises
    ------
    McapError
        (``source=path``) The file cannot be opened, is not MCAP, or a message does not decode.
    """
    wanted = set(topics)
    out = []
    with _open_reader(path) as (p, _, reader):
        try:
            for schema, channel, message in reader.iter_messages(topics=list(wanted), log_time_order=True):
                out.append((channel.topic, int(message.log_time),
                            TYPESTORE.deserialize_cdr(message.data, schema.name)))
        except _READ_ERRORS as e:
            raise McapError(f"corrupt MCAP file ({e.__class__.__name__}: {e})", source=p) from None
    return out


def read_metadata(path: str | Path, name: str = FACTORY_METADATA) -> dict[str, str]:
    """The key-value map of metadata record ``name`` (default: the ``factory`` record).

    Raises
    ------
    McapError
        (``source=path``) The file cannot be opened, is not MCAP, or has no such record.
    """
    with _open_reader(path) as (p, _, reader):
        try:
            for m in reader.iter_metadata():
                if m.name == name:
                    return dict(m.metadata)
        except _READ_ERRORS as e:
            raise McapError(f"corrupt MCAP file ({e.__class__.__name__}: {e})", source=p) from None
    raise McapError(f"no metadata record named {name!r}", source=p)


__all__ = [
    "FACTORY_METADATA", "ROSBAG2_METADATA", "LogBuffer", "McapLog", "offered_qos_profiles", "read_attachment",
    "read_messages", "read_metadata",
]
