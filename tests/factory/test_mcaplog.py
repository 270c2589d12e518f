"""The MCAP log: ros2-profile files that independent readers (mcap + mcap_ros2, rosbags) accept."""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import Writer
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosDurability
from scipy.spatial.transform import Rotation

import factory
from factory.core.errors import McapError, OutputExistsError
from factory.mcaplog import LogBuffer, McapLog, offered_qos_profiles, read_attachment, read_metadata
from factory.rosmsgs import (TYPESTORE, JointStateCdr, RestampedCdr, TfCdr, cube_marker, line_list_marker,
                             line_list_marker_array,
                             line_strip_marker, log_msg, marker_array, message_definition, ros_time, serialize_cdr,
                             string_msg, tf_message, transform_stamped, transform_values, transforms_stamped,
                             triangle_mesh_marker, triangle_mesh_marker_array)
from tests.mcapcheck import check_rosbag2_mcap

STRIP = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, -0.001], [0.01, 0.02, -0.001], [0.0, 0.02, 0.005]])
SEGMENTS = np.array([[0.0, 0.0, 0.01], [0.03, 0.0, 0.01], [0.03, 0.0, 0.01], [0.03, 0.03, 0.02]])
VERTICES = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]) * 0.05
FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
JOB_BYTES = json.dumps({"format": "factory.job/1", "operations": []}).encode()
INPUTS = {"parts/bracket.stl": "0123456789abcdef" * 4}
PARAMETERS = {"stepover": 1.5, "tools": {"rough": 1, "finish": [2, 3]}, "note": "plain text"}
WORK_IN_WORLD = np.array([[0.0, -1.0, 0.0, 0.1], [1.0, 0.0, 0.0, 0.2], [0.0, 0.0, 1.0, -0.05], [0, 0, 0, 1]])


def write_sample(path: Path) -> None:
    """Five messages on four topics, one attachment; the metadata comes from McapLog."""
    with McapLog(path, stage="test", inputs=INPUTS, parameters=PARAMETERS) as log:
        log_sample(log)


def log_sample(log: McapLog | LogBuffer) -> None:
    """:func:`write_sample`'s messages and attachment, into an open log or a buffer."""
    log.write("/tf_static", tf_message([transform_stamped("world", "work", WORK_IN_WORLD, 0)]), 0,
              latched=True)
    markers = marker_array([
        line_strip_marker("path", 0, STRIP, (0.0, 0.0, 1.0, 1.0), 0.0005, "work", 1_000),
        line_list_marker("path", 1, SEGMENTS, (1.0, 0.2, 0.0, 0.5), 0.0002, "work", 1_000),
        triangle_mesh_marker("part", 0, VERTICES, FACES, (0.6, 0.6, 0.6, 1.0), "work", 1_000),
        cube_marker("stock", 0, (0.05, 0.04, -0.01), (0.1, 0.08, 0.02), (0.8, 0.7, 0.5, 0.2), "work", 1_000),
    ])
    log.write("/cam/toolpath", markers, 1_000, latched=True)
    log.write("/status", string_msg("roughing done"), 2_000)
    log.write("/rosout", log_msg(logging.INFO, "factory.cam", "hello", 2_500), 2_500)
    log.write("/rosout", log_msg("error", "factory.cam", "bad", 3_000_000_001), 3_000_000_001)
    log.attach("factory.job.json", "application/json", JOB_BYTES)


@pytest.fixture(scope="module")
def sample(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("mcap") / "sample.mcap"
    write_sample(path)
    return path


def test_ros2_profile_encodings_statistics_and_zstd_chunks(sample: Path) -> None:
    with open(sample, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count == 5
    by_topic = {c.topic: c for c in summary.channels.values()}
    assert set(by_topic) == {"/tf_static", "/cam/toolpath", "/status", "/rosout"}
    assert summary.statistics.channel_message_counts[by_topic["/rosout"].id] == 2
    assert summary.statistics.message_start_time == 0
    assert summary.statistics.message_end_time == 3_000_000_001
    assert all(c.message_encoding == "cdr" for c in summary.channels.values())
    assert all(s.encoding == "ros2msg" for s in summary.schemas.values())
    assert {s.name for s in summary.schemas.values()} == {
        "tf2_msgs/msg/TFMessage", "visualization_msgs/msg/MarkerArray", "std_msgs/msg/String",
        "rcl_interfaces/msg/Log"}
    assert summary.chunk_indexes and all(c.compression == "zstd" for c in summary.chunk_indexes)
    assert all(c.message_index_offsets for c in summary.chunk_indexes)


def test_schema_is_the_concatenated_definition_text(sample: Path) -> None:
    with open(sample, "rb") as f:
        schemas = {s.name: s.data.decode() for s in make_reader(f).get_summary().schemas.values()}
    tf = schemas["tf2_msgs/msg/TFMessage"]
    sections = tf.split("=" * 80 + "\n")
    assert sections[0].startswith("geometry_msgs/TransformStamped[] transforms\n")
    deps = [s.split("\n", 1)[0] for s in sections[1:]]
    assert all(d.startswith("MSG: ") for d in deps)
    # Named as the fields spell them (rosbag2's LocalMessageDefinitionSource does the same);
    # Foxglove's parser finds a dependency only under that name.
    assert {"MSG: geometry_msgs/TransformStamped", "MSG: std_msgs/Header",
            "MSG: builtin_interfaces/Time", "MSG: geometry_msgs/Quaternion"} <= set(deps)
    assert len(deps) == len(set(deps))  # each dependency once
    assert "int32 LINE_STRIP=4" in schemas["visualization_msgs/msg/MarkerArray"]


def test_latched_topics_offer_transient_local(sample: Path) -> None:
    with open(sample, "rb") as f:
        channels = {c.topic: c for c in make_reader(f).get_summary().channels.values()}
    for topic, channel in channels.items():
        (qos,) = yaml.safe_load(channel.metadata["offered_qos_profiles"])
        latched = topic in ("/tf_static", "/cam/toolpath")
        # rmw enum numbers: durability 1 transient_local, 2 volatile; reliable 1; keep_last 1
        assert qos["durability"] == (1 if latched else 2)
        assert qos["reliability"] == 1 and qos["history"] == 1 and qos["liveliness"] == 1
        assert channel.metadata["topic_type_hash"].startswith("RIHS01_")


def test_factory_metadata_and_attachment(sample: Path) -> None:
    meta = read_metadata(sample)
    assert meta["stage"] == "test" and meta["version"] == factory.__version__
    assert meta["input:parts/bracket.stl"] == INPUTS["parts/bracket.stl"]
    assert meta["param:note"] == "plain text"
    assert json.loads(meta["param:tools"]) == PARAMETERS["tools"]
    assert json.loads(meta["param:stepover"]) == 1.5
    assert read_attachment(sample, "factory.job.json") == JOB_BYTES
    # Humble's record (no serialized_metadata): Jazzy then reads the QoS numbers as Humble does
    assert read_metadata(sample, "rosbag2") == {"ROS_DISTRO": "jazzy"}
    with open(sample, "rb") as f:
        (att,) = list(make_reader(f).iter_attachments())
    assert att.media_type == "application/json"


def test_mcap_ros2_decodes_what_was_written(sample: Path) -> None:
    with open(sample, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        decoded = [(ch.topic, m.log_time, d) for _, ch, m, d in reader.iter_decoded_messages(log_time_order=True)]
    topics = [t for t, _, _ in decoded]
    assert topics == ["/tf_static", "/cam/toolpath", "/status", "/rosout", "/rosout"]
    tf = decoded[0][2].transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id) == ("world", "work")
    t = tf.transform
    assert [t.translation.x, t.translation.y, t.translation.z] == [0.1, 0.2, -0.05]
    r = Rotation.from_quat([t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w]).as_matrix()
    np.testing.assert_allclose(r, WORK_IN_WORLD[:3, :3], atol=1e-12)

    strip, lst, mesh, cube = decoded[1][2].markers
    def pts(m: object) -> np.ndarray:
        return np.array([[p.x, p.y, p.z] for p in m.points]).reshape(-1, 3)
    assert (strip.type, lst.type, mesh.type, cube.type) == (4, 5, 11, 1)
    np.testing.assert_array_equal(pts(strip), STRIP)
    np.testing.assert_array_equal(pts(lst), SEGMENTS)
    np.testing.assert_array_equal(pts(mesh), VERTICES[FACES.reshape(-1)])
    assert strip.scale.x == 0.0005 and strip.header.frame_id == "work"
    assert (strip.header.stamp.sec, strip.header.stamp.nanosec) == (0, 1_000)
    assert (cube.pose.position.x, cube.scale.y) == (0.05, 0.08)
    assert cube.color.a == np.float32(0.2)  # ColorRGBA is float32
    assert decoded[2][2].data == "roughing done"
    late = decoded[4][2]
    assert (late.level, late.name, late.msg) == (40, "factory.cam", "bad")
    assert (late.stamp.sec, late.stamp.nanosec) == (3, 1)


def test_rosbags_anyreader_reads_bare_mcap(sample: Path) -> None:
    with AnyReader([sample]) as reader:
        conns = {c.topic: c for c in reader.connections}
        assert conns["/tf_static"].ext.offered_qos_profiles[0].durability == QosDurability.TRANSIENT_LOCAL
        assert conns["/status"].ext.offered_qos_profiles[0].durability == QosDurability.VOLATILE
        assert conns["/rosout"].msgcount == 2
        # The types rebuilt from our definition text hash like the ones we declared.
        with open(sample, "rb") as f:
            declared = {c.topic: c.metadata["topic_type_hash"] for c in make_reader(f).get_summary().channels.values()}
        for topic, conn in conns.items():
            assert reader.typestore.hash_rihs01(conn.msgtype) == declared[topic]
        msgs = [(c.topic, reader.deserialize(raw, c.msgtype)) for c, _, raw in reader.messages()]
    markers = dict(msgs)["/cam/toolpath"].markers
    np.testing.assert_array_equal([[p.x, p.y, p.z] for p in markers[1].points], SEGMENTS)
    assert dict(msgs)["/status"].data == "roughing done"


def test_failure_inside_block_leaves_nothing(tmp_path: Path) -> None:
    path = tmp_path / "out.mcap"
    with pytest.raises(RuntimeError):
        with McapLog(path, stage="test") as log:
            log.write("/status", string_msg("half"), 0)
            raise RuntimeError("stage failed")
    assert list(tmp_path.iterdir()) == []


def test_existing_file_needs_overwrite(tmp_path: Path) -> None:
    path = tmp_path / "out.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(OutputExistsError) as e:
        McapLog(path, stage="test")  # refused at construction, before any work
    assert e.value.source == str(path)
    assert path.read_bytes() == b"precious"
    with McapLog(path, stage="test", overwrite=True) as log:
        log.write("/status", string_msg("new"), 0)
    assert read_metadata(path)["stage"] == "test"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.mcap"]


def test_topic_type_conflict_is_an_error_and_writes_nothing(tmp_path: Path) -> None:
    path = tmp_path / "out.mcap"
    with pytest.raises(McapError, match="carries std_msgs/msg/String"):
        with McapLog(path, stage="test") as log:
            log.write("/status", string_msg("a"), 0)
            log.write("/status", marker_array([]), 1)
    assert not path.exists()


def test_bad_writes_raise_mcap_error(tmp_path: Path) -> None:
    with McapLog(tmp_path / "a.mcap", stage="test") as log:
        with pytest.raises(McapError):
            log.write("/status", "not a message", 0)
        with pytest.raises(McapError):
            log.write("/status", string_msg("x"), -1)
        with pytest.raises(McapError):
            log.write("relative", string_msg("x"), 0)
        log.write("/tf_static", tf_message([]), 0, latched=True)
        with pytest.raises(McapError, match="latched"):
            log.write("/tf_static", tf_message([]), 0)
        log.attach("a", "text/plain", b"1")
        with pytest.raises(McapError, match="twice"):
            log.attach("a", "text/plain", b"2")
    with pytest.raises(McapError):
        McapLog(tmp_path / "b.mcap", stage="test", parameters={"x": object()})


def test_read_attachment_errors_name_the_file(tmp_path: Path, sample: Path) -> None:
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"this is not an mcap file at all, just text" * 3)
    for path, name in ((junk, "factory.job.json"), (tmp_path / "missing.mcap", "x"), (sample, "nope.json")):
        with pytest.raises(McapError) as e:
            read_attachment(path, name)
        assert e.value.source == str(path)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1),
       st.lists(st.floats(-10, 10), min_size=3, max_size=3))
def test_transform_stamped_round_trips_rotation_and_translation(q: list[float], t: list[float]) -> None:
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(q).as_matrix()
    m[:3, 3] = t
    msg = transform_stamped("a", "b", m, 5)
    r = msg.transform.rotation
    back = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
    np.testing.assert_allclose(back, m[:3, :3], atol=1e-9)
    tr = msg.transform.translation
    assert [tr.x, tr.y, tr.z] == t


@settings(max_examples=100, deadline=None)
@given(st.lists(st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1),
                min_size=1, max_size=8))
def test_transforms_stamped_gives_scipys_quaternion_sign_included(qs: list[list[float]]) -> None:
    # the logged quaternion is the one scipy's Rotation.from_matrix gives, so logs keep their bytes;
    # the half-turns (trace -1, the largest diagonal element decides) are the delicate case
    r = np.concatenate([Rotation.from_quat(qs).as_matrix(), np.diag([1.0, -1, -1])[None],
                        np.diag([-1.0, 1, -1])[None], np.diag([-1.0, -1, 1])[None], np.eye(3)[None]])
    m = np.tile(np.eye(4), (len(r), 1, 1))
    m[:, :3, :3] = r
    msgs = transforms_stamped("a", [f"c{i}" for i in range(len(r))], m, 0)
    got = [[t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z, t.transform.rotation.w]
           for t in msgs]
    np.testing.assert_allclose(got, Rotation.from_matrix(r).as_quat(), atol=1e-12)


def test_transform_stamped_rejects_non_rigid() -> None:
    m = np.eye(4)
    m[0, 0] = 2.0
    with pytest.raises(McapError):
        transform_stamped("a", "b", m, 0)
    m = np.diag([1.0, 1.0, -1.0, 1.0])  # a mirror
    with pytest.raises(McapError):
        transform_stamped("a", "b", m, 0)


@given(st.integers(0, 2**31 * 10**9 - 1))
def test_ros_time_splits_nanoseconds(ns: int) -> None:
    t = ros_time(ns)
    assert t.sec * 10**9 + t.nanosec == ns and 0 <= t.nanosec < 10**9


def test_builders_reject_bad_geometry() -> None:
    with pytest.raises(McapError, match="even"):
        line_list_marker("a", 0, STRIP[:3], (1, 1, 1, 1), 0.001, "work", 0)
    with pytest.raises(McapError, match="non-finite"):
        line_strip_marker("a", 0, np.array([[0, 0, 0], [np.nan, 0, 0]]), (1, 1, 1, 1), 0.001, "work", 0)
    with pytest.raises(McapError, match="out of range"):
        triangle_mesh_marker("a", 0, VERTICES, FACES + 1, (1, 1, 1, 1), "work", 0)
    with pytest.raises(McapError, match="colour"):
        line_strip_marker("a", 0, STRIP, (255, 0, 0, 255), 0.001, "work", 0)


def test_log_levels_follow_python_logging() -> None:
    assert log_msg(logging.WARNING, "n", "t", 0).level == 30
    assert log_msg(logging.CRITICAL, "n", "t", 0).level == 50
    assert log_msg("debug", "n", "t", 0).level == 10


def test_qos_yaml_parses() -> None:
    (latched,) = yaml.safe_load(offered_qos_profiles(True))
    assert latched["durability"] == 1 and latched["depth"] == 1  # 1: transient_local
    assert latched["deadline"] == {"sec": 9223372036, "nsec": 854775807}


# --- the rosbag2 check every MCAP-writing test uses (tests/mcapcheck.py) ----------------------


def test_rosbag2_check_accepts_what_mcaplog_writes(sample: Path) -> None:
    counts = check_rosbag2_mcap(sample, latched_topics=("/tf_static", "/cam/toolpath"))
    assert counts == {"/tf_static": 1, "/cam/toolpath": 1, "/status": 1, "/rosout": 2}


def write_raw(path: Path, *, profile: str = "ros2", message_encoding: str = "cdr", qos: bool = True,
              latched: bool = True, statistics: bool = True, data: bytes | None = None,
              schema_text: str | None = None, trailing: bytes = b"", qos_text: str | None = None,
              rosbag2_record: dict[str, str] | None = {"ROS_DISTRO": "jazzy"}) -> None:
    """One /tf_static message written with the bare mcap writer, one requirement broken at a time."""
    if schema_text is None:
        schema_text = message_definition("tf2_msgs/msg/TFMessage")
    if data is None:
        msg = tf_message([transform_stamped("world", "work", WORK_IN_WORLD, 0)])
        data = bytes(TYPESTORE.serialize_cdr(msg, "tf2_msgs/msg/TFMessage"))
    data += trailing
    if qos_text is None:
        qos_text = offered_qos_profiles(latched)
    metadata = {"offered_qos_profiles": qos_text} if qos else {}
    with open(path, "wb") as f:
        w = Writer(f, use_statistics=statistics)
        w.start(profile=profile, library="test")
        sid = w.register_schema(name="tf2_msgs/msg/TFMessage", encoding="ros2msg", data=schema_text.encode())
        cid = w.register_channel(topic="/tf_static", message_encoding=message_encoding, schema_id=sid,
                                 metadata=metadata)
        w.add_message(channel_id=cid, log_time=5, publish_time=5, data=data, sequence=0)
        if rosbag2_record is not None:
            w.add_metadata("rosbag2", rosbag2_record)
        w.finish()


def test_rosbag2_check_accepts_the_bare_writer_when_nothing_is_broken(tmp_path: Path) -> None:
    path = tmp_path / "good.mcap"
    write_raw(path)
    assert check_rosbag2_mcap(path) == {"/tf_static": 1}


@pytest.mark.parametrize("broken, message", [
    ({"message_encoding": "json"}, "message encoding 'json', not 'cdr'"),
    ({"qos": False}, "no 'offered_qos_profiles' metadata"),
    ({"latched": False}, "not transient_local"),
    ({"profile": ""}, "profile is '', not 'ros2'"),
    ({"statistics": False}, "no Statistics record"),
    # Jazzy's own format: policy names, which Humble's ros2 bag cannot read
    ({"qos_text": offered_qos_profiles(True).replace("history: 1", "history: keep_last")
      .replace("reliability: 1", "reliability: reliable").replace("durability: 1", "durability: transient_local")
      .replace("liveliness: 1", "liveliness: automatic")}, "QoS history is 'keep_last'"),
    ({"qos_text": offered_qos_profiles(True).replace("liveliness: 1", "liveliness: 7")}, "QoS liveliness is 7"),
    # numbers without the Humble-style record: Jazzy reads them as names, i.e. unknown
    ({"rosbag2_record": None}, "metadata version 9"),
    ({"rosbag2_record": {"serialized_metadata": "rosbag2_bagfile_information:\n  version: 9\n"}},
     "metadata version 9"),
    ({"data": b"\x00\x01\x00\x00\xff\xff\xff\x7f"}, "cannot decode"),
])
def test_rosbag2_check_rejects_a_broken_file(tmp_path: Path, broken: dict, message: str) -> None:
    path = tmp_path / "bad.mcap"
    write_raw(path, **broken)
    with pytest.raises(AssertionError, match=re.escape(message)) as e:
        check_rosbag2_mcap(path)
    assert str(path) in str(e.value)


def test_transforms_stamped_matches_one_at_a_time_and_names_the_bad_one():
    from scipy.spatial.transform import Rotation

    from factory.rosmsgs import transforms_stamped

    rng = np.random.default_rng(4)
    mats = np.tile(np.eye(4), (5, 1, 1))
    mats[:, :3, :3] = Rotation.random(5, random_state=7).as_matrix()
    mats[:, :3, 3] = rng.normal(size=(5, 3))
    names = [f"f{i}" for i in range(5)]
    batch = transforms_stamped("base", names, mats, 123)
    for msg, name, m in zip(batch, names, mats):
        one = transform_stamped("base", name, m, 123)
        assert msg.child_frame_id == one.child_frame_id == name
        for a, b in ((msg.transform.translation, one.transform.translation),
                     (msg.transform.rotation, one.transform.rotation)):
            assert [getattr(a, k) for k in a.__dataclass_fields__] == [getattr(b, k) for k in b.__dataclass_fields__]
    mats[3, :3, :3] *= 1.1
    with pytest.raises(McapError, match="f3"):
        transforms_stamped("base", names, mats, 0)


_NAMES = st.text(st.characters(codec="utf-8", exclude_characters="\x00"), max_size=12)


@given(st.lists(_NAMES, max_size=7), _NAMES, st.integers(0, 2**31 * 10**9 - 1), st.booleans(), st.integers(0, 2**32 - 1))
@settings(max_examples=60, deadline=None)
def test_joint_states_are_written_as_rosbags_writes_them(names, frame_id, stamp_ns, effort, seed):
    """The joint states' CDR, written directly, is rosbags' byte for byte: every name length and
    every empty sequence moves the next field's alignment."""
    rng = np.random.default_rng(seed)
    k = len(names)
    msg = TYPESTORE.types["sensor_msgs/msg/JointState"](
        header=TYPESTORE.types["std_msgs/msg/Header"](stamp=ros_time(stamp_ns), frame_id=frame_id), name=names,
        position=rng.normal(size=k), velocity=rng.normal(size=k), effort=rng.normal(size=k if effort else 0))
    assert serialize_cdr(msg, msg.__msgtype__) == bytes(TYPESTORE.serialize_cdr(msg, msg.__msgtype__))


def _random_links(n: int, seed: int) -> np.ndarray:
    """(n, 4, 4) random link poses [m]: rotations and offsets drawn from ``seed``."""
    m = np.tile(np.eye(4), (n, 1, 1))
    if n:
        m[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
        m[:, :3, 3] = np.random.default_rng(seed).normal(size=(n, 3))
    return m


@given(st.lists(_NAMES, max_size=6), _NAMES, st.integers(0, 2**31 * 10**9 - 1), st.integers(0, 2**32 - 1))
@settings(max_examples=60, deadline=None)
def test_link_transforms_are_written_as_rosbags_writes_them(children, parent, stamp_ns, seed):
    """The links' /tf CDR, written directly, is rosbags' byte for byte, and reads back as written."""
    m = _random_links(len(children), seed)
    msg = tf_message(transforms_stamped(parent, children, m, stamp_ns))
    data = serialize_cdr(msg, msg.__msgtype__)
    assert data == bytes(TYPESTORE.serialize_cdr(msg, msg.__msgtype__))
    back = TYPESTORE.deserialize_cdr(data, msg.__msgtype__)
    assert [t.child_frame_id for t in back.transforms] == children


@given(st.lists(_NAMES, max_size=7), st.integers(0, 2**31 * 10**9 - 1), st.integers(0, 2**32 - 1))
@settings(max_examples=60, deadline=None)
def test_joint_states_from_their_template_are_the_messages_bytes(names, stamp_ns, seed):
    """A robot's joint states packed into their fixed layout (no message object) are the bytes of
    the message serialised, by rosbags too, whatever the names' lengths do to the alignment."""
    rng = np.random.default_rng(seed)
    q, qd = rng.normal(size=len(names)), rng.normal(size=len(names))
    msg = TYPESTORE.types["sensor_msgs/msg/JointState"](
        header=TYPESTORE.types["std_msgs/msg/Header"](stamp=ros_time(stamp_ns), frame_id=""), name=names,
        position=q, velocity=qd, effort=np.zeros(0))
    assert JointStateCdr(names).cdr(stamp_ns, q, qd) == bytes(TYPESTORE.serialize_cdr(msg, msg.__msgtype__))


@given(st.lists(_NAMES, max_size=6), _NAMES, st.integers(0, 2**31 * 10**9 - 1), st.integers(0, 2**32 - 1))
@settings(max_examples=60, deadline=None)
def test_link_transforms_from_their_template_are_the_messages_bytes(children, parent, stamp_ns, seed):
    """The links' /tf packed into their fixed layout (no message objects) are the bytes of
    :func:`transforms_stamped`'s message serialised by rosbags, quaternion signs included."""
    m = _random_links(len(children), seed)
    msg = tf_message(transforms_stamped(parent, children, m, stamp_ns))
    expected = bytes(TYPESTORE.serialize_cdr(msg, msg.__msgtype__))
    assert TfCdr(parent, children).cdr(stamp_ns, transform_values(m)) == expected


def _stamp_markers(array, stamp_ns):
    for mk in array.markers:
        mk.header.stamp = ros_time(stamp_ns)
    return array


@given(st.integers(1, 4), st.lists(st.integers(0, 2**31 * 10**9 - 1), min_size=1, max_size=4),
       st.integers(0, 2**32 - 1))
@settings(max_examples=30, deadline=None)
def test_a_marker_array_restamped_from_its_cdr_is_the_message_serialised_at_that_stamp(n_markers, stamps, seed):
    """A stock or toolpath marker array serialised once and restamped at each use is, at every
    stamp, the bytes of the message stamped so and serialised by rosbags; its maker gives the
    message at that stamp, for sinks that serialise themselves."""
    rng = np.random.default_rng(seed)
    array = marker_array([triangle_mesh_marker("stock", i, rng.normal(size=(5, 3)), np.array([[0, 1, 2], [2, 3, 4]]),
                                               (0.5, 0.5, 0.5, 1.0), "work", 0) if i % 2 else
                          line_strip_marker("toolpath", i, rng.normal(size=(int(rng.integers(2, 9)), 3)),
                                            (1.0, 0.0, 0.0, 1.0), 0.001, "work", 0) for i in range(n_markers)])
    cached = RestampedCdr(array, _stamp_markers)
    assert cached.pieces is not None  # the fast way, not the fallback
    for stamp in stamps:
        out = cached.at(stamp)
        expected = bytes(TYPESTORE.serialize_cdr(_stamp_markers(array, stamp), array.__msgtype__))
        assert (out.typename, out.cdr) == (array.__msgtype__, expected)
        _stamp_markers(array, 0)
        made = out.make()
        assert all(mk.header.stamp == ros_time(stamp) for mk in made.markers)


def test_a_sink_that_serialises_itself_gets_the_message_beside_one_that_takes_cdr(tmp_path):
    """Fanout.write_cdr gives the log the CDR as made and a live sink the message, made once."""
    from factory.live import Fanout

    got = []

    class Live:
        def write(self, topic, msg, log_time_ns, *, latched=False):
            got.append((topic, msg, log_time_ns, latched))

    m = np.tile(np.eye(4), (2, 1, 1))
    m[:, :3, 3] = [[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]]
    msg = tf_message(transforms_stamped("base", ["a", "bb"], m, 7))
    made = []
    with McapLog(tmp_path / "x.mcap", stage="test") as log:
        Fanout([log, Live()]).write_cdr("/tf", msg.__msgtype__, TfCdr("base", ["a", "bb"]).cdr(7, transform_values(m)),
                                        7, lambda: made.append(1) or msg)
    assert got == [("/tf", msg, 7, False)] and made == [1]
    with open(tmp_path / "x.mcap", "rb") as f:
        (_, _, message), = make_reader(f).iter_messages()
    assert message.data == bytes(TYPESTORE.serialize_cdr(msg, msg.__msgtype__))


def test_a_buffered_log_replays_into_the_same_file(sample, tmp_path):
    """Logged into a buffer first (a plan's messages while verify runs) and replayed, the file is the
    same to the byte: same order, channels, CDR and attachment; a joint state given as CDR too."""
    buffer = LogBuffer()
    log_sample(buffer)
    replayed = tmp_path / "replayed.mcap"
    with McapLog(replayed, stage="test", inputs=INPUTS, parameters=PARAMETERS) as log:
        buffer.replay(log)
    assert replayed.read_bytes() == sample.read_bytes()
    states, direct = LogBuffer(), tmp_path / "direct.mcap"
    cdr = JointStateCdr(["a", "b"]).cdr(5, np.array([0.1, 0.2]), np.zeros(2))
    states.write_cdr("/joint_states", "sensor_msgs/msg/JointState", cdr, 5)
    with McapLog(direct, stage="test") as log:
        log.write_cdr("/joint_states", "sensor_msgs/msg/JointState", cdr, 5)
    with McapLog(tmp_path / "again.mcap", stage="test") as log:
        states.replay(log)
    assert (tmp_path / "again.mcap").read_bytes() == direct.read_bytes()
    with pytest.raises(McapError, match="not a ROS message"):
        buffer.write("/status", "plain text", 0)


@settings(max_examples=25, deadline=None)
@given(ns=st.text(max_size=7), frame=st.sampled_from(["", "work", "world_"]), id_=st.integers(-5, 5),
       n=st.integers(0, 40), stamp=st.integers(0, 3_000_000_001), seed=st.integers(0, 2**16))
def test_a_mesh_marker_array_serialised_from_arrays_is_the_messages_bytes(ns, frame, id_, n, stamp, seed):
    """The verified stock's mesh marker, written from its arrays, is byte for byte what rosbags writes of
    the message it builds (string lengths that leave every alignment, no triangle, many)."""
    rng = np.random.default_rng(seed)
    vertices = rng.normal(size=(max(n, 3), 3))
    faces = rng.integers(0, len(vertices), size=(n, 3))
    color = tuple(rng.random(4))
    got = triangle_mesh_marker_array(ns, id_, vertices, faces, color, frame, stamp)
    msg = got.make()
    assert got.typename == "visualization_msgs/msg/MarkerArray"
    built = marker_array([triangle_mesh_marker(ns, id_, vertices, faces, color, frame, stamp)])
    assert got.cdr == bytes(TYPESTORE.serialize_cdr(msg, got.typename))
    assert got.cdr == bytes(TYPESTORE.serialize_cdr(built, got.typename))


def test_a_mesh_marker_array_refuses_what_the_marker_refuses():
    with pytest.raises(McapError, match="face index out of range"):
        triangle_mesh_marker_array("s", 0, VERTICES, FACES + 4, (1.0, 1.0, 1.0, 1.0), "work", 0)
    with pytest.raises(McapError, match="non-finite"):
        triangle_mesh_marker_array("s", 0, VERTICES * np.nan, FACES, (1.0, 1.0, 1.0, 1.0), "work", 0)
    with pytest.raises(McapError, match="colour"):
        triangle_mesh_marker_array("s", 0, VERTICES, FACES, (2.0, 1.0, 1.0, 1.0), "work", 0)


@settings(max_examples=40, deadline=None)
@given(lines=st.lists(st.tuples(st.text(max_size=9), st.integers(-3, 3), st.integers(0, 12),
                                st.floats(0.0, 0.01)), max_size=5),
       frame=st.sampled_from(["", "work", "world_"]), stamp=st.integers(0, 3_000_000_001), seed=st.integers(0, 2**16))
def test_line_lists_serialised_from_arrays_are_the_messages_bytes(lines, frame, stamp, seed):
    """A toolpath's LINE_LISTs, written from their arrays, are byte for byte what rosbags writes of the message
    they build (names that leave every alignment, no marker, markers without a segment, many segments)."""
    rng = np.random.default_rng(seed)
    given_lines = [(ns, id_, rng.normal(scale=0.1, size=(2 * k, 3)), tuple(rng.random(4)), width)
                   for ns, id_, k, width in lines]
    got = line_list_marker_array(given_lines, frame, stamp)
    built = marker_array([line_list_marker(*line, frame, stamp) for line in given_lines])
    assert got.typename == "visualization_msgs/msg/MarkerArray"
    assert got.cdr == bytes(TYPESTORE.serialize_cdr(built, got.typename))
    assert got.cdr == bytes(TYPESTORE.serialize_cdr(got.make(), got.typename))


def test_line_lists_from_arrays_refuse_what_the_marker_refuses():
    ok = ("a", 0, np.zeros((2, 3)), (1.0, 1.0, 1.0, 1.0), 0.001)
    for bad, match in ((("b", 1, np.zeros((3, 3)), (1.0, 1.0, 1.0, 1.0), 0.001), "even number"),
                       (("b", 1, np.full((2, 3), np.nan), (1.0, 1.0, 1.0, 1.0), 0.001), "non-finite"),
                       (("b", 1, np.zeros((2, 2)), (1.0, 1.0, 1.0, 1.0), 0.001), "shape"),
                       (("b", 1, np.zeros((2, 3)), (1.0, 2.0, 1.0, 1.0), 0.001), "colour")):
        with pytest.raises(McapError, match=match):
            line_list_marker_array([ok, bad], "work", 0)
        with pytest.raises(McapError, match=match):
            line_list_marker(*bad, "work", 0)
