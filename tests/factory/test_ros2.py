"""The cell on a live ROS 2 graph (`factory.ros2`, `factory simulate --ros2`), checked by a real ROS 2 node.

A second process (tests/ros2node.py, in the ROS environment ``make test`` installs into .venv-ros2)
runs rclpy from the ``ros-jazzy-*`` wheels over Fast DDS, a different DDS implementation from the
Cyclone participant that publishes, as a ROS 2 user's node would be. It must see the topics, types and
node names, decode what it subscribes to field for field equal to what the MCAP log written in the same
run holds, and get the latched topics when it subscribes late. The types no wheel carries (tf2_msgs,
factory_msgs) are taken here by a plain DDS reader and decoded by rosbags from the ``.msg`` files in
ros/. Each test has its own domain id and keeps all traffic on 127.0.0.1; every wait is for a match or
a message, bounded.

A volatile reader gets what is written once it has matched the writer, and each end matches on its own:
Fast DDS may report a match before it follows the writer, and then counts what came before as history it
never asked for. The graph's ``wait_for`` holds each topic until its first message is acknowledged; what
rclpy receives is checked to be the log's messages from some point on (the first may be the one lost), in
order, none missing after it, and always the last.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from cyclonedds._clayer import ddspy_take  # noqa: E402
from cyclonedds.core import InstanceState, SampleState, ViewState  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.qos import Policy, Qos  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

from factory.camera_msgs import image_msg  # noqa: E402
from factory.core.errors import LiveError  # noqa: E402
from factory.mcaplog import read_messages
from factory.rosmsgs import TYPESTORE  # noqa: E402
from factory.ros2 import IMAGE_RAW, Ros2Graph, _write, domain_id_from_env, idl_type, localhost_domain, node_of  # noqa: E402
from factory.cellinputs import CellInputs  # noqa: E402
from factory.simulation import run_cell, write_cell_log  # noqa: E402
from robotprog.orders import read_orders  # noqa: E402
from tests.ros2node import plain  # noqa: E402

BIN = Path(sys.executable).parent
ROOT = Path(__file__).resolve().parent.parent.parent
#: The ROS environment's interpreter (make test installs it; FACTORY_ROS2_PYTHON names another).
ROS2_PYTHON = Path(os.environ.get("FACTORY_ROS2_PYTHON", ROOT / ".venv-ros2" / "bin" / "python"))
if not ROS2_PYTHON.exists():
    pytest.skip(f"no ROS 2 environment at {ROS2_PYTHON}: `make test` installs tests/ros2node-requirements.txt there",
                allow_module_level=True)
NODES = {"vision_node", "scheduler_node", "robot_node", "machine_node"}

# what the rclpy node subscribes through the wheels' message classes, and through a raw DDS reader
ROS = {"/joint_states": "sensor_msgs/msg/JointState", "/camera/camera_info": "sensor_msgs/msg/CameraInfo",
       IMAGE_RAW: "sensor_msgs/msg/Image", "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray"}
RAW = {"/tf": "tf2_msgs/msg/TFMessage", "/cell/machine": "factory_msgs/msg/MachineState",
       "/camera/detections": "factory_msgs/msg/DetectedObjectArray", "/cell/orders": "factory_msgs/msg/OrderQueue"}
LATE_ROS = {"/robot_description": "std_msgs/msg/String"}
LATE_RAW = {"/tf_static": "tf2_msgs/msg/TFMessage"}


def _msg_types() -> object:
    """rosbags' Jazzy types with factory_msgs read from the shipped ``.msg`` files (not factory's typestore)."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict = {}
    for path in sorted((ROOT / "ros").glob("*/msg/*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"{path.parent.parent.name}/msg/{path.stem}"))
    store.register(types)
    return store


class _RawReaders:
    """Plain DDS readers (Cyclone, on 127.0.0.1) of the types no ROS wheel carries: bytes decoded by rosbags."""

    def __init__(self, domain: int) -> None:
        self.store = _msg_types()
        localhost_domain(domain)
        self._participant = DomainParticipant(domain)
        self._readers: dict[str, tuple[DataReader, str]] = {}

    def subscribe(self, topic: str, typename: str, latched: bool = False) -> None:
        qos = Qos(Policy.Reliability.Reliable(0), Policy.Durability.TransientLocal, Policy.History.KeepLast(100)) \
            if latched else Qos(Policy.Reliability.Reliable(0), Policy.Durability.Volatile, Policy.History.KeepAll)
        topic_ = Topic(self._participant, "rt" + topic, idl_type(typename, self.store))
        self._readers[topic] = (DataReader(self._participant, topic_, qos), typename)

    def matched(self) -> bool:
        return all(r.get_matched_publications() for r, _ in self._readers.values())

    def take(self, topic: str, until: int, seconds: float = 60.0) -> list:
        """The messages on ``topic``, waiting (at most ``seconds``) until there are ``until``."""
        reader, typename = self._readers[topic]
        out: list = []
        deadline = time.monotonic() + seconds
        while len(out) < until and time.monotonic() < deadline:
            for data, info in ddspy_take(reader._ref, SampleState.Any | ViewState.Any | InstanceState.Any, 10000):
                if info.valid_data:
                    out.append(plain(self.store.deserialize_cdr(bytes(data), typename)))
            if len(out) < until:
                time.sleep(0.01)  # polled: the reader's data arrives on Cyclone's own threads
        return out


def _suffix_of(came: list, sent: list) -> bool:
    """``came`` is ``sent`` from some point on: in order, nothing missing after its first, and the last."""
    return bool(came) and came == sent[len(sent) - len(came):]


def _domain(k: int) -> int:
    """A domain id of this test run's own (ROS_DOMAIN_ID 1..101 keeps every RTPS port valid)."""
    return 1 + (os.getpid() * 7 + k) % 100


def _orders(folder: Path, part: Path) -> Path:
    path = folder / "orders.csv"
    path.write_text(f"part,quantity,material,priority\n{part},1,aluminium,0\n")
    return path


def _observer(domain: int, spec: dict) -> subprocess.Popen:
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
           "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp"}
    env.pop("PYTHONPATH", None)  # its own environment: nothing of this one
    proc = subprocess.Popen([str(ROS2_PYTHON), "-m", "tests.ros2node", json.dumps(spec)], env=env, text=True,
                            cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    line = proc.stdout.readline()
    assert line and json.loads(line) == {"ready": True}, line + proc.stderr.read()
    return proc


def _tell(proc: subprocess.Popen, order: dict) -> None:
    proc.stdin.write(json.dumps(order) + "\n")
    proc.stdin.flush()


def _seen(proc: subprocess.Popen, order: dict) -> dict:
    _tell(proc, order)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    seen = json.loads(out.strip().splitlines()[-1])
    assert seen["timed_out"] == [], (seen["timed_out"], {t: len(m) for t, m in seen["messages"].items()})
    return seen


def _image_raw(compressed: list) -> list:
    """The raw images the graph derives from the log's compressed ones, made here from the log."""
    out = []
    for _, _, m in compressed:
        raw = image_msg(cv2.imdecode(np.asarray(m.data, np.uint8), cv2.IMREAD_UNCHANGED), 0, m.header.frame_id)
        raw.header = m.header
        out.append(raw)
    return out


def test_a_ros2_node_sees_decodes_and_joins_late(block_catalog, tmp_path):
    catalog, part = block_catalog
    orders = read_orders(_orders(tmp_path, part))
    run = run_cell(orders, CellInputs(catalog=catalog))
    domain = _domain(0)
    proc = _observer(domain, {"ros": ROS, "late": LATE_ROS})
    raw = _RawReaders(domain)
    for topic, typename in RAW.items():
        raw.subscribe(topic, typename)
    mcap = tmp_path / "cell.mcap"
    try:
        with Ros2Graph(domain_id=domain, localhost=True, speed=float("inf"), keep_all=True, wait_for=tuple(ROS)) as graph:
            # the writers first, then every reader matched (rclpy's matched events, Cyclone's status)
            for topic, typename in {**ROS, **RAW}.items():
                graph.advertise(topic, typename)
            _tell(proc, {"wait_matched": True})
            assert json.loads(proc.stdout.readline()) == {"matched": True}
            deadline = time.monotonic() + 60
            while not raw.matched() and time.monotonic() < deadline:
                time.sleep(0.01)
            write_cell_log(mcap, run.result, run.ready, orders, run.cell, run.world, run.stations,
                           overwrite=False, inputs={}, parameters={}, live=graph)
            published = graph.topics
            logged = read_messages(mcap, [*published, "/camera/image/compressed"])
            expected = {t: [plain(m) for topic, _, m in logged if topic == t] for t in published}
            expected[IMAGE_RAW] = [plain(m) for m in _image_raw([x for x in logged if x[0] == "/camera/image/compressed"])]
            assert all(expected[t] for t in (*ROS, *RAW, *LATE_ROS, *LATE_RAW)), {t: len(v) for t, v in expected.items()}
            came = {t: raw.take(t, len(expected[t])) for t in RAW}
            raw.subscribe("/tf_static", LATE_RAW["/tf_static"], latched=True)  # late, as the rclpy node below
            came["/tf_static"] = raw.take("/tf_static", len(expected["/tf_static"]))
            seen = _seen(proc, {"last": {t: expected[t][-1] for t in ROS}})
    finally:
        proc.kill()
    # the graph: every topic with its type, owned by its node, with the QoS of its kind
    assert NODES <= set(seen["nodes"])
    for topic, typename in published.items():
        assert seen["topics"].get(topic) == [typename], topic
    for topic, infos in seen["publishers"].items():
        assert [(i["node"], i["type"], i["reliability"], i["durability"]) for i in infos] == \
               [(node_of(topic), published[topic], "RELIABLE",
                 "TRANSIENT_LOCAL" if topic in LATE_ROS else "VOLATILE")], topic
    assert node_of("/joint_states") == "robot_node" and node_of(IMAGE_RAW) == "vision_node"
    assert node_of("/diagnostics") == "scheduler_node" and node_of("/cell/machine") == "machine_node"
    # field for field, in order: rclpy's decoding of the ROS types, rosbags' (from the .msg files) of the others
    for topic in ROS:
        assert _suffix_of(seen["messages"][topic], expected[topic]), topic
    for topic in RAW:
        assert came[topic] == expected[topic], topic
    assert all(len(m["position"]) == 6 and len(m["name"]) == 6 for m in seen["messages"]["/joint_states"])
    image = seen["messages"][IMAGE_RAW][-1]
    assert image["encoding"] in ("bgr8", "mono8") and image["step"] * image["height"] == image["data"]["len"]
    # late joiners get what is latched: the robot's URDF, and every static transform message
    assert seen["messages"]["/robot_description"] == expected["/robot_description"][-1:]
    assert "<robot" in seen["messages"]["/robot_description"][0]["data"]
    assert came["/tf_static"] == expected["/tf_static"] and len(expected["/tf_static"]) > 1


def test_simulate_ros2_same_figures_and_a_node_receives(block_catalog, tmp_path):
    catalog, part = block_catalog
    orders = _orders(tmp_path, part)
    domain = _domain(1)
    base = [str(BIN / "factory"), "simulate", str(orders), "--catalog", str(catalog), "--json"]
    plain_run = subprocess.run(base, capture_output=True, text=True, timeout=600)
    assert plain_run.returncode == 0, plain_run.stderr
    proc = _observer(domain, {"ros": {"/joint_states": ROS["/joint_states"]}})
    raw = _RawReaders(domain)
    raw.subscribe("/cell/summary", "factory_msgs/msg/CellSummary")
    try:
        live = subprocess.run([*base, "--ros2", "--ros2-localhost", "--ros2-keep-all", "--ros2-wait", "/joint_states",
                               "--ros2-wait", "/cell/summary", "--speed", "1e6", "--mcap", str(tmp_path / "cell.mcap")],
                              capture_output=True, text=True, timeout=600, env={**os.environ, "ROS_DOMAIN_ID": str(domain)})
        assert live.returncode == 0, live.stderr
        logged = read_messages(tmp_path / "cell.mcap", ["/joint_states", "/cell/summary"])
        want = {t: [plain(m) for topic, _, m in logged if topic == t] for t in ("/joint_states", "/cell/summary")}
        seen = _seen(proc, {"last": {"/joint_states": want["/joint_states"][-1]}})
        summaries = raw.take("/cell/summary", len(want["/cell/summary"]))
    finally:
        proc.kill()
    # --ros2-wait held each topic's first message until a reader matched it: the run came whole
    assert summaries == want["/cell/summary"]
    assert _suffix_of(seen["messages"]["/joint_states"], want["/joint_states"])
    # the simulation's figures do not depend on publishing
    a, b = json.loads(plain_run.stdout), json.loads(live.stdout)
    assert a["summary"] == b["summary"] and a["summary"]["parts_good"] == 1
    assert a["summary"]["oee"] == b["summary"]["oee"] and a["summary"]["parts_per_hour"] == b["summary"]["parts_per_hour"]


def test_bad_domain_and_options_are_one_line(block_catalog, tmp_path):
    catalog, part = block_catalog
    assert domain_id_from_env({}) == 0 and domain_id_from_env({"ROS_DOMAIN_ID": " 42 "}) == 42
    for bad in ("x", "-1", "233"):
        with pytest.raises(LiveError, match="ROS_DOMAIN_ID"):
            domain_id_from_env({"ROS_DOMAIN_ID": bad})
    r = subprocess.run([str(BIN / "factory"), "simulate", str(_orders(tmp_path, part)), "--catalog", str(catalog),
                        "--ros2"], capture_output=True, text=True, timeout=300,
                       env={**os.environ, "ROS_DOMAIN_ID": "lab"})
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 1 and lines == ["error: ROS_DOMAIN_ID: not an integer: 'lab'"], r.stderr
    with pytest.raises(LiveError, match="ros-distro"):
        Ros2Graph(distro="iron")


def test_humble_discovery_layout():
    """Humble's rmw_dds_common/Gid is 24 bytes (the GUID, zero-padded), Jazzy's 16: the graph writes the one asked."""
    from rosbags.typesys import Stores, get_typestore

    for distro, store, size in (("humble", get_typestore(Stores.ROS2_HUMBLE), 24), ("jazzy", TYPESTORE, 16)):
        graph = Ros2Graph(domain_id=_domain(2), localhost=True, distro=distro)
        try:
            assert graph._gid(graph._participant.guid).data.shape == (size,)
            assert bytes(graph._gid(graph._participant.guid).data[:16]) == graph._participant.guid.bytes
            assert store.types["rmw_dds_common/msg/Gid"] is not None
        finally:
            graph.close()


def _raw_writer(raw: _RawReaders, topic: str, typename: str) -> DataWriter:
    """A plain DDS writer (reliable, volatile) of ``typename`` on ``topic``, in the readers' participant."""
    return DataWriter(raw._participant, Topic(raw._participant, "rt" + topic, idl_type(typename, raw.store)),
                      Qos(Policy.Reliability.Reliable(int(1e9)), Policy.Durability.Volatile, Policy.History.KeepAll,
                          Policy.DataRepresentation(use_cdrv0_representation=True)))


def _until(done, seconds: float = 120.0) -> bool:
    deadline = time.monotonic() + seconds
    while not done():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)  # polled: DDS statuses and the service's answers come on other threads and processes
    return True


def test_cell_takes_orders_from_a_ros2_node_and_stops_cleanly_on_sigint(block_catalog, tmp_path):
    """`factory cell --ros2`: a real rclpy node sends a catalog part's name (std_msgs/String), a plain DDS
    writer a factory_msgs/WorkOrder and a malformed one; /order_status answers each (queued, then done;
    refused with the reason, the cell running on), the run is published (/joint_states reach rclpy), the
    graph shows the scheduler's /order subscription with both types; then SIGINT: exit 0, the session's
    log and record whole."""
    catalog, part = block_catalog
    domain = _domain(4)
    mcap, db, bag = tmp_path / "cell.mcap", tmp_path / "cell.sqlite", tmp_path / "cell_bag"
    proc = _observer(domain, {"ros": {"/joint_states": ROS["/joint_states"]}})
    raw = _RawReaders(domain)
    raw.subscribe("/order_status", "factory_msgs/msg/OrderStatus")
    work = _raw_writer(raw, "/order", "factory_msgs/msg/WorkOrder")
    cell = subprocess.Popen([str(BIN / "factory"), "cell", "--ros2", "--ros2-localhost", "--ros2-keep-all",
                             "--catalog", str(catalog), "--speed", "1e4", "--mcap", str(mcap), "--db", str(db),
                             "--bag", str(bag)],
                            env={**os.environ, "ROS_DOMAIN_ID": str(domain)}, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    statuses: list = []

    def heard(pred) -> bool:
        statuses.extend(raw.take("/order_status", 1, seconds=0.05))
        return any(pred(s) for s in statuses)

    def answered(order_id: str, state: str) -> bool:
        return heard(lambda s: s["id"] == order_id and s["state"] == state)

    def probe(s: dict) -> bool:
        return s["state"] == "refused" and s["part"] == ""

    try:
        # the cell is up once its /order reader and /order_status writer matched ours
        assert _until(lambda: work.get_matched_subscriptions() and raw.matched()), cell.stderr
        types = raw.store.types
        WorkOrder = types["factory_msgs/msg/WorkOrder"]
        _write(work, bytes(raw.store.serialize_cdr(WorkOrder(id="bad", part="no_such_part", material="", quantity=1,
                                                             priority=0), "factory_msgs/msg/WorkOrder")))
        assert _until(lambda: answered("bad", "refused"))
        _write(work, bytes(raw.store.serialize_cdr(WorkOrder(id="w1", part="block", material="", quantity=1,
                                                             priority=0), "factory_msgs/msg/WorkOrder")))
        # Each end matches on its own: rclpy's writer may see the cell's reader before the reader follows it, and
        # what it sends before is lost. Empty names (malformed: refused) go first until one is answered; from
        # then on the reader follows this writer, and the part's name cannot be lost.
        probes = 0
        while not heard(probe):
            assert probes < 60, statuses
            _tell(proc, {"publish": {"topic": "/order", "type": "std_msgs/msg/String", "fields": {"data": ""}}})
            assert json.loads(proc.stdout.readline()) == {"published": True}
            probes += 1
            _until(lambda: heard(probe), 2.0)  # not asserted: an unanswered probe is sent again
        _tell(proc, {"publish": {"topic": "/order", "type": "std_msgs/msg/String", "fields": {"data": "block"}}})
        assert json.loads(proc.stdout.readline()) == {"published": True}
        # the cell numbers orders without an id (r1, r2, ...): the part's name is the one for the block
        assert _until(lambda: answered("w1", "done") and heard(lambda s: s["id"] != "w1" and s["state"] == "done")), \
            statuses
        named, = {s["id"] for s in statuses if s["part"] == part.name and s["id"] != "w1"}
        seen = _seen(proc, {"expect": {"/joint_states": 1}})
        assert cell.poll() is None  # still serving
        cell.send_signal(signal.SIGINT)
        out, err = cell.communicate(timeout=120)
    finally:
        proc.kill()
        if cell.poll() is None:
            cell.kill()
    assert cell.returncode == 0, err
    # each order answered in turn: queued, running, done; the malformed one refused with why
    bad = [s for s in statuses if s["id"] == "bad"]
    assert [s["state"] for s in bad] == ["refused"] and "no part 'no_such_part' in the catalog" in bad[0]["reason"]
    assert all("no part named" in s["reason"] for s in statuses if s["part"] == "" and s["id"] != "bad")
    for order_id in ("w1", named):
        states = [s["state"] for s in statuses if s["id"] == order_id]
        assert states[0] == "queued" and states[-1] == "done" and set(states) <= {"queued", "running", "done"}, states
        last = [s for s in statuses if s["id"] == order_id][-1]
        assert (last["part"], last["material"], last["quantity"], last["good"]) == (part.name, "aluminium", 1, 1)
    # the graph as rclpy saw it: the cell's nodes, /order taken in both types, the run's joint states
    assert NODES <= set(seen["nodes"])
    assert sorted(seen["topics"]["/order"]) == ["factory_msgs/msg/WorkOrder", "std_msgs/msg/String"]
    assert seen["topics"]["/order_status"] == ["factory_msgs/msg/OrderStatus"]
    assert seen["messages"]["/joint_states"] and len(seen["messages"]["/joint_states"][0]["position"]) == 6
    # SIGINT closed the session: the log holds every status sent, on one clock that never goes back
    logged = read_messages(mcap, ["/order_status", "/joint_states"])
    assert [plain(m) for t, _, m in logged if t == "/order_status"] == statuses
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for t, _, m in logged if t == "/joint_states"]
    assert stamps == sorted(stamps) and len(stamps) > 1
    # ... and the rosbag2 folder, read by rosbags' reader, every message the log's
    from rosbags.rosbag2 import Reader

    with Reader(bag) as reader:
        bagged = [(c.topic, t, bytes(d)) for c, t, d in reader.messages()]
    with open(mcap, "rb") as f:
        from mcap.reader import make_reader

        in_log = [(c.topic, m.log_time, bytes(m.data)) for _, c, m in make_reader(f).iter_messages(log_time_order=True)]
    assert sorted(bagged) == sorted(in_log) and len(bagged) > 100
    from factory.record import Record
    record = Record(str(db), write=False)
    try:
        runs = record.counts()["run"]
    finally:
        record.close()
    assert 1 <= runs <= 2  # the two good orders ran in one run or two, as they came
    assert not list(tmp_path.glob("*.tmp*")) and not list(tmp_path.glob(".*"))
