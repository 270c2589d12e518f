"""`factory simulate --serve`: the run streamed to a Foxglove WebSocket client, on 127.0.0.1.

The client here speaks Foxglove's WebSocket protocol (subprotocol ``foxglove.sdk.v1``, the one foxglove-sdk servers speak) with
the `websockets` library: it reads the server's advertisements, subscribes to ``/joint_states`` and
decodes what arrives with the advertised schema.
"""

from __future__ import annotations

import json
import re
import struct
import subprocess
import sys
import time
from pathlib import Path

from websockets.sync.client import connect

from factory.rosmsgs import TYPESTORE

BIN = Path(sys.executable).parent


def _orders(folder: Path, part: Path) -> Path:
    path = folder / "orders.csv"
    # four parts: at --speed 20 the run streams for about a minute, time for a slow client to subscribe
    path.write_text(f"part,quantity,material,priority\n{part},4,aluminium,0\n")
    return path


def _start(args: list[str]) -> tuple[subprocess.Popen, int]:
    """Start `factory simulate ... --serve 0` and read the port it bound from its stderr."""
    proc = subprocess.Popen([str(BIN / "factory"), "simulate", *args, "--serve", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stderr.readline()
    m = re.search(r"ws://127\.0\.0\.1:(\d+)", line)
    assert m, line + proc.stderr.read()
    return proc, int(m.group(1))


def _listening_addresses(port: int) -> set[str]:
    """Local addresses of the TCP sockets listening on ``port`` (from /proc/net/tcp and tcp6)."""
    found = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for row in Path(table).read_text().splitlines()[1:]:
            local, state = row.split()[1], row.split()[3]
            addr, hexport = local.split(":")
            if state == "0A" and int(hexport, 16) == port:
                found.add(addr)
    return found


def test_a_client_sees_the_cell_live(block_catalog, tmp_path):
    catalog, part = block_catalog
    proc, port = _start([str(_orders(tmp_path, part)), "--catalog", str(catalog), "--speed", "20",
                         "--mcap", str(tmp_path / "cell.mcap")])
    try:
        assert _listening_addresses(port) == {"0100007F"}  # 127.0.0.1 only
        with connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"], open_timeout=60,
                     max_size=None) as ws:
            channels: dict[str, dict] = {}
            info = None
            deadline = time.monotonic() + 300
            wanted = {"/joint_states", "/cell/machine", "/cell/summary"}
            while not wanted <= set(channels) and time.monotonic() < deadline:
                msg = ws.recv(timeout=300)
                if isinstance(msg, str):
                    doc = json.loads(msg)
                    if doc["op"] == "serverInfo":
                        info = doc
                    elif doc["op"] == "advertise":
                        channels.update({c["topic"]: c for c in doc["channels"]})
            assert info is not None and "time" in info["capabilities"]
            js = channels["/joint_states"]
            assert js["encoding"] == "cdr" and js["schemaEncoding"] == "ros2msg"
            # the typed cell state with the fields of the log: spindle load, the OEE terms
            assert channels["/cell/machine"]["schemaName"] == "factory_msgs/msg/MachineState"
            assert "float32 spindle_load_percent" in channels["/cell/machine"]["schema"]
            assert "float64 availability" in channels["/cell/summary"]["schema"]
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": js["id"]}]}))
            samples, times, t0 = [], [], time.monotonic()
            while len(samples) < 30:
                try:
                    msg = ws.recv(timeout=120)
                except Exception:
                    raise AssertionError(f"the stream ended after {len(samples)} joint states") from None
                if isinstance(msg, bytes) and msg[0] == 0x01:  # message data
                    sub, stamp = struct.unpack_from("<IQ", msg, 1)
                    assert sub == 7
                    samples.append(TYPESTORE.deserialize_cdr(msg[13:], "sensor_msgs/msg/JointState"))
                    times.append(stamp)
            rate = len(samples) / (time.monotonic() - t0)
        assert all(len(s.position) == 6 for s in samples)
        assert times == sorted(times) and times[-1] > times[0]
        print(f"/joint_states live: {rate:.0f} msg/s at --speed 20")
        assert proc.wait(timeout=600) == 0, proc.stderr.read()
        assert (tmp_path / "cell.mcap").is_file()
    finally:
        proc.kill()


def test_nobody_connected_never_blocks(block_catalog, tmp_path):
    catalog, part = block_catalog
    proc, port = _start([str(_orders(tmp_path, part)), "--catalog", str(catalog), "--speed", "1e6"])
    try:
        assert proc.wait(timeout=600) == 0, proc.stderr.read()
    finally:
        proc.kill()


def test_a_port_in_use_is_one_line(block_catalog, tmp_path):
    import socket

    catalog, part = block_catalog
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        r = subprocess.run([str(BIN / "factory"), "simulate", str(_orders(tmp_path, part)), "--catalog",
                            str(catalog), "--serve", str(port)], capture_output=True, text=True, timeout=300)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 1 and len(lines) == 1 and lines[0].startswith("error: --serve: cannot serve"), r.stderr
