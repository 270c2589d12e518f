"""What publishing the cell on a ROS 2 graph costs: ``factory simulate --ros2`` against the MCAP log alone.

    python benchmarks/ros2_publish.py [--catalog build] [--orders samples/orders.yaml] [--json]

Runs the orders through the cell once (planning the parts into the catalog first if they are not
there; that time is not counted), then streams the run three times as fast as it goes
(``speed`` inf): into the MCAP log alone, into the log and a :class:`factory.ros2.Ros2Graph` with no
subscriber, and into both with a subscriber (a plain DDS reader of every topic in this process,
on 127.0.0.1, domain 0 unless ROS_DOMAIN_ID says otherwise; keep-all, so every message reaches it).
Reports for each the wall and processor time of the stream [s] (processor time counts every thread
of this process, the subscriber's included), and for the graph the messages and MB published and the
rate sustained (messages/s, MB/s of CDR payload, over the stream's wall time); the added processor time
is the run with the graph less the log alone. Single runs: compare runs on the same machine. With
``--json`` the last line is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from factory.cellinputs import CellInputs  # noqa: E402
from factory.simulation import run_cell, write_cell_log  # noqa: E402
from factory.ros2 import Ros2Graph, domain_id_from_env, localhost_domain  # noqa: E402
from robotprog.orders import read_orders  # noqa: E402


class _Counting(Ros2Graph):
    """The graph, counting what it publishes (messages, CDR bytes)."""

    messages = 0
    payload = 0

    def publish(self, topic: str, typename: str, data: bytes, *, latched: bool = False) -> None:
        self.messages += 1
        self.payload += len(data)
        super().publish(topic, typename, data, latched=latched)


class _EveryTopic:
    """A subscriber to every topic the graph publishes, as a recorder would be."""

    def __init__(self, domain: int) -> None:
        from cyclonedds.domain import DomainParticipant

        localhost_domain(domain)
        self.participant = DomainParticipant(domain)
        self.readers: dict[str, object] = {}

    def follow(self, graph: Ros2Graph) -> None:
        """Subscribe, keep-all and reliable, to each of the graph's topics."""
        from cyclonedds.qos import Policy, Qos
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        from factory.ros2 import dds_topic, idl_type

        for topic, typename in graph.topics.items():
            if topic not in self.readers:
                qos = Qos(Policy.Reliability.Reliable(0), Policy.History.KeepAll,
                          Policy.Durability.TransientLocal if topic in graph.latched else Policy.Durability.Volatile)
                self.readers[topic] = DataReader(self.participant, Topic(self.participant, dds_topic(topic),
                                                                         idl_type(typename)), qos)

    def matched(self) -> bool:
        return all(r.get_matched_publications() for r in self.readers.values())


def _stream(run, orders, mcap: Path, graph: Ros2Graph | None) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    write_cell_log(mcap, run.result, run.ready, orders, run.cell, run.world, run.stations, overwrite=True,
                   inputs={}, parameters={}, live=graph)
    if graph is not None:
        graph.close()
    return time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--catalog", type=Path, default=ROOT / "build")
    ap.add_argument("--orders", type=Path, default=ROOT / "samples" / "orders.yaml")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    orders = read_orders(args.orders)
    run = run_cell(orders, CellInputs(catalog=args.catalog))
    mcap = Path(os.environ.get("TMPDIR", "/tmp")) / f"ros2-publish-{os.getpid()}.mcap"
    domain = domain_id_from_env()
    rows = {}
    try:
        rows["mcap"] = _stream(run, orders, mcap, None)
        bare = _Counting(domain_id=domain, localhost=True, speed=float("inf"))
        rows["mcap+ros2"] = _stream(run, orders, mcap, bare)
        # a subscriber from the start: the same writers made ahead, every reader matched before the stream
        followed = _Counting(domain_id=domain, localhost=True, speed=float("inf"), keep_all=True)
        for topic, typename in bare.topics.items():
            followed.advertise(topic, typename, latched=topic in bare.latched)
        sub = _EveryTopic(domain)
        sub.follow(followed)
        deadline = time.monotonic() + 60
        while not sub.matched() and time.monotonic() < deadline:
            time.sleep(0.01)
        rows["mcap+ros2+subscriber"] = _stream(run, orders, mcap, followed)
    finally:
        mcap.unlink(missing_ok=True)
    base_wall, base_cpu = rows["mcap"]
    doc = {"orders": str(args.orders), "parts": sum(o.quantity for o in orders),
           "simulated_h": round(run.result.summary["makespan_s"] / 3600, 2),
           "messages": bare.messages, "mb": round(bare.payload / 1e6, 1), "load": os.getloadavg()[0]}
    for name, (wall, cpu) in rows.items():
        doc[name] = {"wall_s": round(wall, 2), "cpu_s": round(cpu, 2)}
        if name != "mcap":
            doc[name]["added_cpu_s"] = round(cpu - base_cpu, 2)
            doc[name]["msgs_per_s"] = round(bare.messages / wall)
            doc[name]["mb_per_s"] = round(bare.payload / 1e6 / wall, 1)
    if not args.json:
        print(f"{doc['parts']} parts, {doc['simulated_h']} h simulated: {doc['messages']} messages, {doc['mb']} MB "
              f"of CDR on the graph (load {doc['load']:.1f})")
        for name, (wall, cpu) in rows.items():
            extra = "" if name == "mcap" else (f"; +{doc[name]['added_cpu_s']} s processor, "
                                               f"{doc[name]['msgs_per_s']} msg/s, {doc[name]['mb_per_s']} MB/s")
            print(f"  {name:<22} wall {wall:6.2f} s, processor {cpu:6.2f} s{extra}")
    print(json.dumps(doc))


if __name__ == "__main__":
    main()
