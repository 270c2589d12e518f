"""One check that an MCAP file is what rosbag2 (``ros2 bag info/play``) and Foxglove need.

Independent of :mod:`factory.mcaplog`: it reads with the ``mcap`` reader, decodes every message
with both mcap-ros2-support and rosbags, and parses the QoS YAML itself, so a bug in the writer
cannot hide behind the same bug in the check. Raises ``AssertionError`` (explicitly, so it also
works under ``python -O``) with a message that names the file, channel and what is wrong.
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Iterable
from pathlib import Path

import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

#: Topics that must offer transient_local durability (when the file has them).
LATCHED_TOPICS = ("/tf_static", "/robot_description")

# rosbag2 resolves a schema name to a type support library: it must be pkg/msg/Name.
_TYPE_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*/msg/[A-Za-z][A-Za-z0-9_]*$")
# How ``ros2 bag`` reads offered_qos_profiles (rosbag2_storage qos.cpp): Humble takes each
# policy as an int (yaml-cpp ``as<int>``: a name throws); Jazzy takes history as an int or a name,
# and reliability, durability and liveliness as ints when the bag's metadata version is <= 8 but
# as names from 9 on (a number then reads as "unknown"). Jazzy's MCAP plugin takes version 8
# from a "rosbag2" metadata record without serialized_metadata, the version inside it when it has
# one, and 9 when there is no such record. So both read a file only with rmw enum numbers and a
# version <= 8. Allowed numbers (rmw/types.h): 0 system default; history 1 keep_last, 2 keep_all;
# reliability 1 reliable, 2 best_effort; durability 1 transient_local, 2 volatile; liveliness
# 1 automatic, 3 manual_by_topic.
_POLICIES = {"history": {0, 1, 2}, "reliability": {0, 1, 2}, "durability": {0, 1, 2}, "liveliness": {0, 1, 3}}
_DURATIONS = ("deadline", "lifespan", "liveliness_lease_duration")
_TRANSIENT_LOCAL = 1
_JAZZY_DEFAULT_VERSION = 9


def _require(ok: object, path: Path, message: str) -> None:
    if not ok:
        raise AssertionError(f"{path}: {message}")


def _jazzy_metadata_version(reader, path: Path) -> int:
    """The metadata version Jazzy's MCAP storage plugin assumes for the file (see above)."""
    version = _JAZZY_DEFAULT_VERSION
    for record in reader.iter_metadata():
        if record.name != "rosbag2":
            continue
        serialized = record.metadata.get("serialized_metadata", "")
        if not serialized:
            version = 8
            continue
        try:
            version = int(yaml.safe_load(serialized)["rosbag2_bagfile_information"]["version"])
        except (yaml.YAMLError, KeyError, TypeError, ValueError) as e:
            raise AssertionError(f"{path}: rosbag2 serialized_metadata has no readable version: {e}") from None
    return version


def _check_profile(profile: dict, path: Path, where: str) -> None:
    """One QoS profile as Humble's and Jazzy's ``ros2 bag`` (metadata version <= 8) decode it."""
    for policy, allowed in _POLICIES.items():
        value = profile.get(policy)
        _require(type(value) is int and value in allowed, path,
                 f"{where} QoS {policy} is {value!r}; Humble's ros2 bag reads only the rmw enum numbers "
                 f"{sorted(allowed)}")
    _require(type(profile.get("depth")) is int and profile["depth"] >= 0, path,
             f"{where} QoS depth is {profile.get('depth')!r}, not a count")
    for name in _DURATIONS:
        d = profile.get(name)
        _require(isinstance(d, dict) and all(type(d.get(k)) is int and d[k] >= 0 for k in ("sec", "nsec")),
                 path, f"{where} QoS {name} is {d!r}, not {{sec: int, nsec: int}}")
    _require(type(profile.get("avoid_ros_namespace_conventions")) is bool, path,
             f"{where} QoS avoid_ros_namespace_conventions is not a boolean")


def check_rosbag2_mcap(path: str | Path, latched_topics: Iterable[str] = LATCHED_TOPICS) -> dict[str, int]:
    """Check ``path`` against rosbag2's MCAP requirements; return the message count per topic.

    Checked:

    * header profile ``ros2``;
    * every channel ``cdr``-encoded with a ``ros2msg`` schema named ``pkg/msg/Name``;
    * every channel has ``offered_qos_profiles`` metadata, a YAML list of profiles that both
      Humble's and Jazzy's ``ros2 bag`` decode (rmw enum numbers, and a ``rosbag2`` metadata
      record that makes Jazzy read numbers), and those of ``latched_topics`` present in the
      file offer ``transient_local`` durability;
    * a summary with a Statistics record whose message count, per-channel counts and
      message start/end times agree with the messages actually read;
    * every message decodes with ``mcap_ros2.decoder`` and with rosbags' ``AnyReader``, and
      both see the same number of messages per topic.

    Not checked: log times non-decreasing per channel (rosbag2 does not need it).

    Parameters
    ----------
    path : str or Path
        The MCAP file.
    latched_topics : iterable of str
        Topics that must offer ``transient_local`` durability when present.

    Returns
    -------
    dict of str to int
        Topic -> number of messages, for every topic with at least one message.

    Raises
    ------
    AssertionError
        The first requirement the file breaks, with the file name in the message.
    """
    path = Path(path)
    latched = set(latched_topics)
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        _require(header.profile == "ros2", path, f"header profile is {header.profile!r}, not 'ros2'")
        summary = reader.get_summary()
        _require(summary is not None, path, "no summary section (rosbag2 reads channels and counts from it)")
        schemas, channels, stats = summary.schemas, summary.channels, summary.statistics
        version = _jazzy_metadata_version(reader, path)
        _require(version <= 8, path,
                 f"Jazzy's ros2 bag would read the QoS as metadata version {version} (policy names, not the "
                 f"numbers Humble needs): write a 'rosbag2' metadata record without serialized_metadata")
        for cid, ch in sorted(channels.items()):
            where = f"channel {cid} ({ch.topic})"
            _require(ch.message_encoding == "cdr", path,
                     f"{where} has message encoding {ch.message_encoding!r}, not 'cdr'")
            schema = schemas.get(ch.schema_id)
            _require(schema is not None, path, f"{where} has no schema (schema id {ch.schema_id})")
            _require(schema.encoding == "ros2msg", path,
                     f"{where} schema {schema.name!r} has encoding {schema.encoding!r}, not 'ros2msg'")
            _require(_TYPE_NAME.match(schema.name), path,
                     f"{where} schema name {schema.name!r} is not a ROS 2 type name pkg/msg/Name")
            _require("offered_qos_profiles" in ch.metadata, path,
                     f"{where} has no 'offered_qos_profiles' metadata (keys: {sorted(ch.metadata)})")
            try:
                profiles = yaml.safe_load(ch.metadata["offered_qos_profiles"])
            except yaml.YAMLError as e:
                raise AssertionError(f"{path}: {where} offered_qos_profiles is not YAML: {e}") from None
            _require(isinstance(profiles, list) and profiles and all(isinstance(p, dict) for p in profiles),
                     path, f"{where} offered_qos_profiles is not a list of QoS profiles: {profiles!r}")
            for profile in profiles:
                _check_profile(profile, path, where)
            if ch.topic in latched:
                durability = [p.get("durability") for p in profiles]
                _require(all(d == _TRANSIENT_LOCAL for d in durability), path,
                         f"{where} is latched but offers durability {durability}, not transient_local (1)")
        _require(stats is not None, path, "no Statistics record in the summary")

        counts: Counter[str] = Counter()
        per_channel: Counter[int] = Counter()
        try:
            for _, ch, msg, _decoded in reader.iter_decoded_messages():
                counts[ch.topic] += 1
                per_channel[ch.id] += 1
                _require(stats.message_start_time <= msg.log_time <= stats.message_end_time, path,
                         f"{ch.topic} message at log time {msg.log_time} ns is outside the Statistics range "
                         f"[{stats.message_start_time}, {stats.message_end_time}] ns")
        except AssertionError:
            raise
        except Exception as e:  # the decoder raises several kinds for bad CDR or definitions
            raise AssertionError(f"{path}: mcap_ros2 cannot decode a message: {type(e).__name__}: {e}") from None

    total = sum(counts.values())
    _require(stats.message_count == total, path,
             f"Statistics message_count is {stats.message_count}, but {total} messages were read")
    stated = {cid: n for cid, n in stats.channel_message_counts.items() if n}
    _require(stated == dict(per_channel), path,
             f"Statistics channel_message_counts {stated} differ from the messages read {dict(per_channel)}")

    seen: Counter[str] = Counter()
    try:
        with AnyReader([path]) as bag:
            for conn, _, raw in bag.messages():
                bag.deserialize(raw, conn.msgtype)
                seen[conn.topic] += 1
    except Exception as e:  # rosbags raises its own error classes per reader and type system
        raise AssertionError(f"{path}: rosbags AnyReader cannot read it: {type(e).__name__}: {e}") from None
    _require(seen == counts, path, f"rosbags read {dict(seen)} messages per topic, mcap_ros2 {dict(counts)}")
    return dict(counts)
