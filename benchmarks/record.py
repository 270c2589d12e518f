"""Cost of the process record: the cell simulation with and without ``--db``, on many orders.

    python benchmarks/record.py [--orders 1000] [--db URL] [--faults 1] [--json]

Runs :func:`robotprog.cellsim.simulate` on ``--orders`` synthetic orders of two parts (durations
of the order of the sample parts', no planning, no MCAP) once bare and once telling every event to
a :class:`factory.record.RunRecorder` (one transaction per event) on a fresh SQLite file, or on
``--db``. Reports wall times [s], events, events per second of recording, the per-event cost
[ms] and the record's size. Single runs on whatever machine this is: compare on the same machine.
With ``--json`` the last line is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from factory.record import OperationPlan, Record  # noqa: E402
from robotprog.cellsim import FaultModel, PartProcess, simulate  # noqa: E402
from robotprog.orders import Order  # noqa: E402

PARTS = {
    Path("a.stl"): PartProcess(fetch_s=12.0, load_s=15.0, machining_s=1900.0, unload_s=14.0, locate_s=0.2,
                               inspect_s=0.2, reject_s=14.0, regrasp_s=3.0),
    Path("b.stl"): PartProcess(fetch_s=10.0, load_s=16.0, machining_s=2800.0, unload_s=15.0, locate_s=0.2,
                               inspect_s=0.2, reject_s=15.0, regrasp_s=2.0),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--orders", type=int, default=1000)
    ap.add_argument("--faults", type=int, default=1)
    ap.add_argument("--db", help="database URL (default: a fresh SQLite file)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    parts = list(PARTS)
    orders = [Order(f"o{i + 1}", parts[i % 2], 1, "aluminium", 0) for i in range(args.orders)]
    faults = FaultModel.default(args.faults)
    t0 = time.perf_counter()
    bare = simulate(orders, PARTS, faults)
    bare_s = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        target = args.db or str(Path(tmp) / "cell.sqlite")
        with Record(target) as record:
            recorder = record.recorder(cell="bench", orders=orders, orders_file="synthetic", orders_sha256="0" * 64,
                                       faults_seed=args.faults)
            plans = {(p, "aluminium"): OperationPlan(str(p), "0" * 64, proc.machining_s, proc.ideal_cycle_s,
                                                     {"inspect_pass": {"tolerance_mm": 1.0, "max_deviation_mm": 0.5},
                                                      "inspect_fail": {"tolerance_mm": 1.0, "max_deviation_mm": 2.0}},
                                                     "0" * 64) for p, proc in PARTS.items()}
            t0 = time.perf_counter()
            sink = recorder.begin(plans)
            recorded = simulate(orders, PARTS, faults, sink=sink)
            recorder.finish(recorded)
            recorded_s = time.perf_counter() - t0
            events = recorder.seq
            counts = record.counts(recorder.run_id)
        size = sum(f.stat().st_size for f in Path(tmp).glob("cell.sqlite*")) if not args.db else None
    assert recorded.summary == bare.summary  # the sink changes nothing
    record_s = recorded_s - bare_s
    doc = {"orders": args.orders, "events": events, "simulated_h": round(bare.summary["makespan_s"] / 3600, 1),
           "bare_s": round(bare_s, 2), "recorded_s": round(recorded_s, 2),
           "record_ms_per_event": round(1000 * record_s / events, 3),
           "events_per_s": round(events / recorded_s, 1), "db_bytes": size, "rows": counts,
           "machine": platform.machine(), "python": platform.python_version()}
    print(f"{args.orders} orders, {events} events ({doc['simulated_h']} h simulated): bare {bare_s:.2f} s, "
          f"with the record {recorded_s:.2f} s ({doc['record_ms_per_event']} ms per event, "
          f"{doc['events_per_s']} events/s)" + (f", record {size / 1e6:.1f} MB" if size else ""))
    if args.json:
        print(json.dumps(doc))


if __name__ == "__main__":
    main()
