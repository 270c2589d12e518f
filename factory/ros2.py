"""The cell on a live ROS 2 graph: the log's messages published over DDS as ROS 2 nodes publish them.

:class:`Ros2Graph` takes the same ``write(topic, msg, log_time_ns, latched=...)`` calls as
:class:`factory.mcaplog.McapLog` and :class:`factory.live.LiveView` and publishes each message with
an ordinary DDS participant (Eclipse Cyclone DDS, one of ROS 2's own middlewares, through its Python
binding) that follows ROS 2's conventions, so ``ros2 topic list``, RViz and any rclpy or rclcpp node
on the same domain see the cell with no ROS installation on this side:

* topic ``/a/b`` is the DDS topic ``rt/a/b``; type ``pkg/msg/Name`` is ``pkg::msg::dds_::Name_``;
* the payload is the CDR the MCAP log holds, byte for byte: rosbags' serialiser
  (:data:`factory.rosmsgs.TYPESTORE`) makes it once; the DDS type declared for discovery is built
  from the same message definitions;
* QoS as :func:`factory.mcaplog.offered_qos_profiles` records it: latched topics (``/robot_description``,
  ``/tf_static``, the cell's boxes) reliable and transient local, as ``robot_state_publisher`` offers
  them, so a subscriber that comes late still gets them (kept 100 deep, as tf2's static listener asks:
  ``/tf_static`` is sent more than once); the others keep-last 10, reliable, volatile (rclcpp's defaults);
* one ``ros_discovery_info`` sample names the nodes that own the writers (:data:`NODES`), in the
  layout of the chosen distribution (``rmw_dds_common/Gid`` is 24 bytes on Humble, 16 on Jazzy);
  on Jazzy each writer also carries ``typehash=RIHS01_...;`` in its user data, as rmw does.

Messages are paced to ``speed`` times log time (:class:`factory.live.Pacer`). A DDS writer is made
on a topic's first message; with ``wait_for`` the first message of each named topic waits until a
subscriber has matched it (discovery takes a moment; volatile data sent before is not delivered), and
the next until the subscriber has acknowledged the first (a reader that matched the writer late may
take that first one as history and drop it; from then on it gets everything).
:meth:`Ros2Graph.close` waits (bounded) until every matched reliable reader has acknowledged
everything, then leaves the graph.

``/camera/image_raw`` (``sensor_msgs/Image``) is published beside ``/camera/image/compressed``, decoded
from it, as ``image_transport``'s republisher would: RViz's image display takes raw images.

Domain: ``ROS_DOMAIN_ID`` (0 unless set), as ROS 2 reads it. ``localhost``: a Cyclone configuration
that keeps every packet on the loopback interface (unicast discovery of the participants on
127.0.0.1; ROS 2 nodes on this machine find it with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, or
Humble's ``ROS_LOCALHOST_ONLY=1``).
"""

from __future__ import annotations

import functools
import logging
import os
import time
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from cyclonedds._clayer import ddspy_take, ddspy_write  # the binding's own take and write of serialised bytes
from cyclonedds.core import DDSException, InstanceState, SampleState, ViewState
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import make_idl_struct
from cyclonedds.idl import types as idl
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.base import Nodetype

from factory.camera_msgs import image_msg
from factory.core.errors import LiveError
from factory.live import Pacer
from factory.rosmsgs import TYPESTORE

log = logging.getLogger(__name__)

#: The ROS 2 distributions whose graph conventions :class:`Ros2Graph` follows.
DISTROS = ("humble", "jazzy")

#: Node owning each topic's writer, by the topic's first name segment (the longest prefix that
#: matches wins); what is not listed belongs to the scheduler, which runs the cell.
NODES = {
    "/camera": "vision_node",
    "/robot": "robot_node", "/robot_description": "robot_node", "/joint_states": "robot_node",
    "/tf": "robot_node", "/tf_static": "robot_node", "/cell/robot": "robot_node",
    "/machine": "machine_node", "/cell/machine": "machine_node", "/cell/io": "machine_node",
}
#: The node that owns every other topic (the cell's state, orders, summary, diagnostics, /rosout).
SCHEDULER_NODE = "scheduler_node"

#: Live topic derived from another: ``image_transport``'s raw image beside the compressed one.
IMAGE_RAW = "/camera/image_raw"
_COMPRESSED = "/camera/image/compressed"

#: With ``keep_all``, a write waits at most this long [s] for the slowest reader to make room.
KEEP_ALL_BLOCKING_S = 60.0

#: At most this long [s] for :meth:`Ros2Graph.close` to see every reliable reader acknowledge.
ACK_TIMEOUT_S = 10.0

# Keep-last depths. Volatile topics: 10, as mcaplog.offered_qos_profiles records them. Latched: 100, as
# tf2's static listener asks, where the log records 1: the run sends /tf_static more than once (the cell,
# then the cameras), and a late joiner must get every message, not the last alone.
_DEPTH_LATCHED, _DEPTH = 100, 10


def node_of(topic: str) -> str:
    """The node whose writer publishes ``topic``: :data:`NODES` by longest prefix, else the scheduler."""
    best = ""
    for prefix in NODES:
        if (topic == prefix or topic.startswith(prefix + "/")) and len(prefix) > len(best):
            best = prefix
    return NODES[best] if best else SCHEDULER_NODE


def dds_topic(topic: str) -> str:
    """The DDS topic name of ROS topic ``topic``: ``/a/b`` -> ``rt/a/b``."""
    return "rt" + topic


def dds_typename(typename: str) -> str:
    """The DDS type name of ROS type ``pkg/msg/Name``: ``pkg::msg::dds_::Name_``."""
    pkg, kind, name = typename.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


_BASE = {"bool": bool, "byte": idl.byte, "char": idl.uint8, "int8": idl.int8, "uint8": idl.uint8,
         "int16": idl.int16, "uint16": idl.uint16, "int32": idl.int32, "uint32": idl.uint32,
         "int64": idl.int64, "uint64": idl.uint64, "float32": idl.float32, "float64": idl.float64}


def idl_type(typename: str, typestore: Any = TYPESTORE) -> type:
    """The Cyclone IDL struct of ROS type ``typename``, built from ``typestore``'s definition, so the
    type that discovery announces is the message's real layout (its fields, nested types, bounds).

    Raises
    ------
    LiveError
        The type is unknown or has a field kind DDS cannot declare here (``wstring``).
    """
    return _idl_type(typename, typestore)


@functools.cache  # one class per type and typestore: DDS takes one declaration per type name
def _idl_type(typename: str, typestore: Any) -> type:
    try:
        _, fields = typestore.fielddefs[typename]
    except KeyError:
        raise LiveError(f"no message definition for {typename}") from None

    def member(desc: Any) -> Any:
        kind, detail = desc
        if kind == Nodetype.BASE:
            base, bound = detail
            if base == "string":
                return idl.bounded_str[bound] if bound else str
            if base not in _BASE:
                raise LiveError(f"{typename}: a {base} field has no DDS declaration here")
            return _BASE[base]
        if kind == Nodetype.NAME:
            return _idl_type(detail, typestore)
        sub, length = detail
        if kind == Nodetype.ARRAY:
            return idl.array[member(sub), length]
        return idl.sequence[member(sub), length] if length else idl.sequence[member(sub)]

    # rosidl gives an empty message one octet, so that DDS can declare it
    members = {name: member(desc) for name, desc in fields} or {"structure_needs_at_least_one_member": idl.uint8}
    return make_idl_struct(dds_typename(typename).rsplit("::", 1)[-1], dds_typename(typename), members)


def localhost_config(domain_id: int) -> str:
    """Cyclone DDS configuration that keeps all traffic on 127.0.0.1: no multicast (the loopback
    interface has none), participants found by unicast on the ports of participant indices 0-32,
    where ROS 2's localhost-only nodes also look."""
    return (f'<CycloneDDS><Domain Id="{domain_id}"><General><Interfaces>'
            '<NetworkInterface address="127.0.0.1"/></Interfaces><AllowMulticast>false</AllowMulticast>'
            '</General><Discovery><ParticipantIndex>auto</ParticipantIndex>'
            '<MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>'
            '<Peers><Peer address="127.0.0.1"/></Peers></Discovery></Domain></CycloneDDS>')


@functools.cache
def localhost_domain(domain_id: int) -> Domain:
    """The loopback-only Cyclone domain ``domain_id`` of this process (:func:`localhost_config`), made
    once: DDS takes one configuration per domain and process, and refuses a second."""
    return Domain(domain_id, localhost_config(domain_id))


def domain_id_from_env(environ: Any = os.environ) -> int:
    """``ROS_DOMAIN_ID`` as ROS 2 reads it: unset or empty is 0.

    Raises
    ------
    LiveError
        (``source="ROS_DOMAIN_ID"``) Not an integer in 0..232 (the RTPS ports of higher ids overflow).
    """
    text = environ.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    try:
        value = int(text)
    except ValueError:
        raise LiveError(f"not an integer: {text!r}", source="ROS_DOMAIN_ID") from None
    if not 0 <= value <= 232:
        raise LiveError(f"{value} is outside 0..232", source="ROS_DOMAIN_ID")
    return value


@dataclass(frozen=True)
class Received:
    """One message a subscription of :class:`Ros2Graph` took.

    Attributes
    ----------
    topic, typename : str
        ROS topic and type (``pkg/msg/Name``).
    msg : object or None
        The message (:data:`factory.rosmsgs.TYPESTORE` type); None when its bytes did not decode.
    error : str
        Why they did not decode; empty otherwise.
    """

    topic: str
    typename: str
    msg: Any
    error: str = ""


@dataclass(frozen=True)
class _Writer:
    writer: DataWriter
    typename: str
    latched: bool
    node: str


class Ros2Graph:
    """One DDS participant publishing a run's messages as the cell's ROS 2 nodes. Use as a context manager.

    Parameters
    ----------
    domain_id : int or None
        DDS domain; None: ``ROS_DOMAIN_ID`` (:func:`domain_id_from_env`).
    localhost : bool
        Keep all traffic on the loopback interface (:func:`localhost_config`).
    distro : str
        ``"humble"`` or ``"jazzy"``: the ``ros_discovery_info`` layout, and type hashes on Jazzy.
    speed : float
        Publish at ``speed`` times log time; ``inf``: as fast as the graph takes them.
    wait_for : tuple of str
        Topics whose first message waits until a subscriber has matched the topic.
    wait_s : float
        At most this long [s] to wait for each of them.
    keep_all : bool
        Keep every message until every matched reliable reader has it, the run waiting for the slowest
        (what a recording or a test needs), instead of the last 10 per topic, which lets a slow
        subscriber (RViz on a busy machine) miss messages but never holds the cell up.

    Raises
    ------
    LiveError
        Bad domain id, distro or speed, or the participant cannot be created (no usable interface).
    """

    def __init__(self, *, domain_id: int | None = None, localhost: bool = False, distro: str = "jazzy",
                 speed: float = 1.0, wait_for: tuple[str, ...] = (), wait_s: float = 60.0,
                 keep_all: bool = False) -> None:
        if distro not in DISTROS:
            raise LiveError(f"unknown ROS 2 distribution {distro!r}: one of {', '.join(DISTROS)}",
                            source="--ros-distro")
        self.domain_id = domain_id_from_env() if domain_id is None else int(domain_id)
        self.distro = distro
        self.localhost = localhost
        self._pacer = Pacer(speed)
        self._wait_for = set(wait_for)
        self._wait_s = float(wait_s)
        self._keep_all = keep_all
        self._acked: set[str] = set()  # topics of wait_for whose first message was acknowledged
        self._writers: dict[str, _Writer] = {}
        self._readers: dict[tuple[str, str], DataReader] = {}  # (topic, type) -> reader, the scheduler's
        # the discovery info's types are the distribution's own (rmw_dds_common/Gid differs)
        self._graph_types = TYPESTORE if distro == "jazzy" else get_typestore(Stores.ROS2_HUMBLE)
        try:
            if localhost:
                localhost_domain(self.domain_id)
            self._participant = DomainParticipant(self.domain_id, qos=Qos(Policy.Userdata(b"enclave=/;")))
            info = "rmw_dds_common/msg/ParticipantEntitiesInfo"
            topic = Topic(self._participant, "ros_discovery_info", idl_type(info, self._graph_types))
            self._info = DataWriter(self._participant, topic, self._qos(True, depth=1))
        except DDSException as e:
            raise LiveError(f"cannot join DDS domain {self.domain_id}: {e}", source="--ros2") from None
        self._info_type = info
        self._publish_graph()
        log.info("ROS 2 graph: domain %d%s", self.domain_id, ", localhost only" if localhost else "")

    def _qos(self, latched: bool, *, depth: int | None = None, user_data: bytes = b"") -> Qos:
        keep_all = self._keep_all and not latched and depth is None
        # a full history blocks a write until readers acknowledge: 100 ms is rmw's default; keeping all,
        # as long as a reader that stopped answering stays matched (its lease)
        blocking = KEEP_ALL_BLOCKING_S if keep_all else 0.1
        history = Policy.History.KeepAll if keep_all else \
            Policy.History.KeepLast(depth or (_DEPTH_LATCHED if latched else _DEPTH))
        policies = [Policy.Reliability.Reliable(max_blocking_time=int(blocking * 1e9)),
                    Policy.Durability.TransientLocal if latched else Policy.Durability.Volatile, history,
                    # ROS 2 speaks plain (XCDR1) CDR, the encapsulation rosbags writes
                    Policy.DataRepresentation(use_cdrv0_representation=True)]
        if latched:  # what a late joiner is sent comes from this history (Cyclone's default keeps 1), as rmw sets it
            policies.append(Policy.DurabilityService(cleanup_delay=0, history=history, max_samples=-1,
                                                     max_instances=-1, max_samples_per_instance=-1))
        if user_data:
            policies.append(Policy.Userdata(user_data))
        return Qos(*policies)

    def _gid(self, guid: Any) -> Any:
        """``rmw_dds_common/Gid`` of an entity: its 16-byte DDS GUID, zero-padded to Humble's 24."""
        gid_type = self._graph_types.types["rmw_dds_common/msg/Gid"]
        size = 16 if self.distro == "jazzy" else 24
        return gid_type(data=np.frombuffer(guid.bytes.ljust(size, b"\0"), np.uint8).copy())

    def _publish_graph(self) -> None:
        """Tell the graph which node owns which writer (rmw publishes this on every change)."""
        t = self._graph_types.types
        nodes: dict[str, list[Any]] = {n: [] for n in (*sorted(set(NODES.values())), SCHEDULER_NODE)}
        for w in self._writers.values():
            nodes[w.node].append(self._gid(w.writer.guid))
        readers = [self._gid(r.guid) for r in self._readers.values()]
        msg = t[self._info_type](
            gid=self._gid(self._participant.guid),
            node_entities_info_seq=[t["rmw_dds_common/msg/NodeEntitiesInfo"](
                node_namespace="/", node_name=name, reader_gid_seq=readers if name == SCHEDULER_NODE else [],
                writer_gid_seq=gids)
                for name, gids in nodes.items()])
        _write(self._info, bytes(self._graph_types.serialize_cdr(msg, self._info_type)))

    def advertise(self, topic: str, typename: str, *, latched: bool = False) -> None:
        """Make ``topic``'s writer now, before its first message, so that subscribers can match it
        early (with ``wait_for``, this waits for one)."""
        self._writer(topic, typename, latched)

    def _writer(self, topic: str, typename: str, latched: bool) -> _Writer:
        known = self._writers.get(topic)
        if known is not None:
            if known.typename != typename or known.latched != latched:
                raise LiveError(f"topic {topic} carries {known.typename}{' latched' if known.latched else ''}, "
                                f"not {typename}{' latched' if latched else ''}", source="--ros2")
            return known
        user_data = f"typehash={TYPESTORE.hash_rihs01(typename)};".encode() if self.distro == "jazzy" else b""
        try:
            dds = Topic(self._participant, dds_topic(topic), idl_type(typename))
            writer = DataWriter(self._participant, dds, self._qos(latched, user_data=user_data))
        except DDSException as e:
            raise LiveError(f"cannot publish {topic}: {e}", source="--ros2") from None
        w = self._writers[topic] = _Writer(writer, typename, latched, node_of(topic))
        self._publish_graph()
        if topic in self._wait_for:
            self._wait_matched(topic, writer)
        return w

    def _wait_matched(self, topic: str, writer: DataWriter) -> None:
        deadline = time.monotonic() + self._wait_s
        while not writer.get_matched_subscriptions():
            if time.monotonic() > deadline:
                raise LiveError(f"no subscriber matched {topic} within {self._wait_s:g} s", source="--ros2-wait")
            time.sleep(0.01)  # polled: matching is a status, not an event the binding can wait on here
        log.info("a subscriber matched %s", topic)

    def write(self, topic: str, msg: Any, log_time_ns: int, *, latched: bool = False) -> None:
        """Publish ``msg`` on ``topic`` once log time ``log_time_ns`` [ns] is due (0: at once)."""
        typename = msg.__msgtype__
        data = bytes(TYPESTORE.serialize_cdr(msg, typename))
        if log_time_ns > 0:
            self._pacer.wait(log_time_ns)
        self.publish(topic, typename, data, latched=latched)
        if topic == _COMPRESSED:
            picture = cv2.imdecode(np.asarray(msg.data, np.uint8), cv2.IMREAD_UNCHANGED)
            if picture is not None:
                raw = image_msg(picture, 0, msg.header.frame_id)
                raw.header = msg.header
                self.publish(IMAGE_RAW, raw.__msgtype__, bytes(TYPESTORE.serialize_cdr(raw, raw.__msgtype__)))

    def publish(self, topic: str, typename: str, data: bytes, *, latched: bool = False) -> None:
        """Publish CDR bytes ``data`` (encapsulation header included) of ROS type ``typename`` on ``topic``."""
        writer = self._writer(topic, typename, latched).writer
        _write(writer, data)
        if topic in self._wait_for and topic not in self._acked:
            # Each end matches on its own: a Fast DDS reader may have matched this writer only after
            # its first messages went out, and takes them as history a volatile reader never asked for.
            # Once the first message is acknowledged, the reader follows this writer: nothing after is lost.
            self._acked.add(topic)
            if not writer.wait_for_acks(int(self._wait_s * 1e9)):
                raise LiveError(f"the subscriber of {topic} did not acknowledge within {self._wait_s:g} s",
                                source="--ros2-wait")

    def subscribe(self, topic: str, typename: str) -> None:
        """Take ``topic``'s messages of type ``typename`` from now on, as the scheduler node
        (reliable, volatile, keep-all: what is sent once matched is never dropped); :meth:`take`
        returns them. A topic may be subscribed with several types (``/order``: a work order or a
        part's name), each its own reader.

        Raises
        ------
        LiveError
            Unknown type, or DDS refuses the reader.
        """
        if (topic, typename) in self._readers:
            return
        user_data = f"typehash={TYPESTORE.hash_rihs01(typename)};".encode() if self.distro == "jazzy" else b""
        qos = [Policy.Reliability.Reliable(0), Policy.Durability.Volatile, Policy.History.KeepAll,
               Policy.DataRepresentation(use_cdrv0_representation=True)]
        try:
            dds = Topic(self._participant, dds_topic(topic), idl_type(typename))
            reader = DataReader(self._participant, dds, Qos(*qos, *([Policy.Userdata(user_data)] if user_data else [])))
        except DDSException as e:
            raise LiveError(f"cannot subscribe {topic}: {e}", source="--ros2") from None
        self._readers[(topic, typename)] = reader
        self._publish_graph()

    def take(self) -> list[Received]:
        """Every message the subscriptions got since the last call, per reader in arrival order."""
        out = []
        for (topic, typename), reader in self._readers.items():
            for data, info in ddspy_take(reader._ref, SampleState.Any | ViewState.Any | InstanceState.Any, 256):
                if not info.valid_data:  # a writer left: no message
                    continue
                try:
                    out.append(Received(topic, typename, TYPESTORE.deserialize_cdr(bytes(data), typename)))
                except Exception as e:  # rosbags raises several kinds for bytes that are not the type
                    out.append(Received(topic, typename, None, f"not a {typename}: {e}"))
        return out

    @property
    def topics(self) -> dict[str, str]:
        """ROS type of every topic published so far."""
        return {t: w.typename for t, w in self._writers.items()}

    @property
    def latched(self) -> frozenset[str]:
        """The topics published so far that are latched (transient local)."""
        return frozenset(t for t, w in self._writers.items() if w.latched)

    def close(self) -> None:
        """Wait (at most :data:`ACK_TIMEOUT_S`) until every matched reliable reader has acknowledged
        every message, then leave the graph."""
        deadline = time.monotonic() + ACK_TIMEOUT_S
        for topic, w in self._writers.items():
            left = max(deadline - time.monotonic(), 0.0)
            if not w.writer.wait_for_acks(int(left * 1e9)):
                log.warning("ROS 2: a reader of %s did not acknowledge everything within %g s", topic, ACK_TIMEOUT_S)
        self._writers.clear()
        self._readers.clear()
        self._info = self._participant = None  # type: ignore[assignment]  # deleted with the last reference

    def __enter__(self) -> "Ros2Graph":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _write(writer: DataWriter, data: bytes) -> None:
    # the binding hands DDS whole 4-byte units, as its own DataWriter.write pads them
    ret = ddspy_write(writer._ref, data.ljust((len(data) + 3) & ~3, b"\0"))
    if ret < 0:
        raise LiveError(f"DDS write failed on {writer.topic.name} ({DDSException(ret, 'write')})", source="--ros2")


__all__ = ["DISTROS", "IMAGE_RAW", "NODES", "Received", "Ros2Graph", "SCHEDULER_NODE", "domain_id_from_env", "dds_topic",
           "dds_typename", "idl_type", "localhost_config", "localhost_domain", "node_of"]
