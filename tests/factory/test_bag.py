"""`--bag DIR`: a run as a rosbag2 folder (factory.bag), read back by rosbags' own rosbag2 reader, message for
message the MCAP log of the same run."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader
from rosbags.interfaces import QosDurability
from rosbags.rosbag2 import Reader

from factory.bag import BagLog
from factory.cellmsgs import OrderLine, order_queue
from factory.rosmsgs import TYPESTORE

BIN = Path(sys.executable).parent


def _mcap_messages(path: Path) -> list[tuple[str, int, bytes]]:
    with open(path, "rb") as f:
        return [(c.topic, m.log_time, bytes(m.data)) for _, c, m in make_reader(f).iter_messages(log_time_order=True)]


def _bag_messages(path: Path) -> tuple[list[tuple[str, int, bytes]], dict]:
    with Reader(path) as reader:
        got = [(c.topic, t, bytes(data)) for c, t, data in reader.messages()]
        conns = {c.topic: c for c in reader.connections}
        assert reader.message_count == len(got)
    return got, conns


def test_simulate_bag_holds_every_message_of_the_log(block_catalog, tmp_path):
    catalog, part = block_catalog
    orders = tmp_path / "orders.csv"
    orders.write_text(f"part,quantity,material,priority\n{part},1,aluminium,0\n")
    bag, mcap = tmp_path / "run_bag", tmp_path / "run.mcap"
    cmd = [str(BIN / "factory"), "simulate", str(orders), "--catalog", str(catalog), "--quiet"]
    r = subprocess.run([*cmd, "--bag", str(bag), "--mcap", str(mcap)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in bag.iterdir()) == ["metadata.yaml", "run_bag.mcap"]
    got, conns = _bag_messages(bag)
    logged = _mcap_messages(mcap)
    # the same messages, bytes and log times; per topic in the same order (ties between topics may differ)
    assert len(got) == len(logged) > 100
    for topic in conns:
        assert [x for x in got if x[0] == topic] == [x for x in logged if x[0] == topic], topic
    # types with their hashes, latched topics replayed transient local, the others volatile
    for topic, c in conns.items():
        assert c.digest == TYPESTORE.hash_rihs01(c.msgtype)
        qos, = c.ext.offered_qos_profiles
        latched = topic in ("/robot_description", "/tf_static")
        if latched or topic in ("/joint_states", "/tf"):
            assert qos.durability == (QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE), topic
    assert {"/robot_description", "/tf_static", "/tf", "/joint_states", "/cell/orders"} <= set(conns)
    # a second run does not replace it unasked: one line, nothing written beside
    again = subprocess.run([*cmd, "--bag", str(bag)], capture_output=True, text=True, timeout=600)
    assert again.returncode == 1 and again.stderr.strip().splitlines() == \
        [f"error: {bag}: exists; pass --overwrite to replace it"], again.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["orders.csv", "run_bag", "run.mcap", "run.layout.json"])


def test_an_interrupted_bag_leaves_nothing(tmp_path):
    msg = order_queue([OrderLine("o1", "block.stl", "aluminium", 1, 0, 0, "queued")], 0)
    with pytest.raises(KeyboardInterrupt):
        with BagLog(tmp_path / "b") as log:
            log.write("/cell/orders", msg, 1)
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []
    with BagLog(tmp_path / "b") as log:
        log.write("/cell/orders", msg, 5)
    got, conns = _bag_messages(tmp_path / "b")
    assert got == [("/cell/orders", 5, bytes(TYPESTORE.serialize_cdr(msg, msg.__msgtype__)))]
    assert [p.name for p in tmp_path.iterdir()] == ["b"]
