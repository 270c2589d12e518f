"""The flip between op 1 and op 2: its motion per arm, and what it costs the cell's throughput.

    python benchmarks/flip.py [--cells cell.yaml,cell_abb.yaml,cell_kuka.yaml] [--json]
    python benchmarks/flip.py --catalog CAT [--orders samples/orders.yaml] [--json]

Without ``--catalog``: for each sample cell, plans the bracket's tending with one setup and with
two (the flip), the bracket after op 1 being its 100 x 60 x 16 mm part on a 6 mm holding block of
the 104 x 64 mm stock, and prints the flip phase's motion [s] (home → vise → flip station, turned
over → vise → home, TOPP-RA timed), the load and unload [s] and the planning wall time [s].

With ``--catalog``: the sample orders run through the cell as ``factory simulate`` runs them (the
plans from the catalog, planned into it if missing: :func:`factory.simulation.run_cell`), then
again with every part in two setups: the flip phase measured here on the default cell's arm added,
and each part's op-2 program time from its plan summary's ``setups`` (0 s, said so, for a plan that
has no op 2 yet). Prints parts per hour and cycle time before and after. Single runs on whatever
machine this is; the simulated figures do not depend on the machine.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from factory.core.resources import FIXTURES  # noqa: E402
from robotprog.cell import load_cell  # noqa: E402
from robotprog.collision import collision_world  # noqa: E402
from robotprog.tending import PartBox, plan_tending  # noqa: E402

STOCK_MM = (104.0, 64.0, 22.0)
PART_M = PartBox(np.array([-0.05, -0.03, 0.006]), np.array([0.05, 0.03, 0.022]))


def _sheet(sx: float, sy: float, sz: float) -> dict:
    return {"format": "factory.setup/1", "units": "mm", "work_origin": "top-front-left",
            "stock": {"min": [0, 0, -sz], "max": [sx, sy, 0], "size": [sx, sy, sz]},
            "transform_mesh_to_work": np.eye(4).tolist(), "mesh_scale": 1.0, "tools": []}


def flip_motion(cell_file: str) -> dict:
    """One- and two-setup tending of the bracket in one sample cell: durations [s], planning [s]."""
    cell = load_cell(FIXTURES / cell_file)
    world = collision_world(cell)
    t0 = time.perf_counter()
    one = plan_tending(cell, _sheet(*STOCK_MM), part_box=PART_M, world=world)
    t1 = time.perf_counter()
    two = plan_tending(cell, _sheet(*STOCK_MM), part_box=PART_M, world=world, setups=2)
    t2 = time.perf_counter()

    def phase(plan, name):
        return round(sum(m.duration for m in plan.phase(name)), 3)

    return {"cell": cell_file, "robot": world.robot.name, "flip_s": phase(two, "flip"),
            "flip_moves": len(two.phase("flip")), "load_s": phase(two, "load"), "unload_s": phase(two, "unload"),
            "one_setup_motion_s": round(one.duration, 3), "two_setup_motion_s": round(two.duration, 3),
            "plan_one_s": round(t1 - t0, 1), "plan_two_s": round(t2 - t1, 1)}


def throughput(catalog: Path, orders_path: Path, flip_s: float) -> dict:
    """Parts per hour of the sample orders, one setup (as planned) and two (flip + op 2 added)."""
    from factory.cellinputs import CellInputs
    from factory.simulation import PartAssets, op2_of, run_cell
    from robotprog.cellsim import simulate
    from robotprog.orders import read_orders

    orders = read_orders(orders_path)
    run = run_cell(orders, CellInputs(catalog=catalog))
    before = run.result.summary
    processes, op2 = {}, {}
    for key, asset in run.assets.items():
        if not isinstance(asset, PartAssets):
            processes[key] = asset
            continue
        entry = op2_of(asset.entry.summary)
        op2[str(key[0].name)] = None if entry is None else float(entry["estimated_cycle_s"])
        processes[key] = dataclasses.replace(asset.process, flip_s=flip_s,
                                             op2_machining_s=op2[str(key[0].name)] or 0.0)
    after = simulate(orders, processes).summary
    keys = ("parts_good", "parts_per_hour", "cycle_time_s", "makespan_s", "robot_utilisation", "machine_utilisation")
    return {"before": {k: before[k] for k in keys}, "after": {k: after[k] for k in keys}, "flip_s": flip_s,
            "op2_machining_s": op2}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", default="cell.yaml,cell_abb.yaml,cell_kuka.yaml")
    ap.add_argument("--catalog", type=Path)
    ap.add_argument("--orders", type=Path, default=ROOT / "samples" / "orders.yaml")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    if args.catalog is None:
        rows = [flip_motion(c) for c in args.cells.split(",")]
        for r in rows:
            print(f"{r['robot']:>20}  flip {r['flip_s']:6.2f} s ({r['flip_moves']} moves)  load {r['load_s']:5.2f} s  "
                  f"unload {r['unload_s']:5.2f} s  motion 1 setup {r['one_setup_motion_s']:6.2f} s, 2 setups "
                  f"{r['two_setup_motion_s']:6.2f} s  planned in {r['plan_one_s']:.1f} / {r['plan_two_s']:.1f} s")
        if args.json:
            print(json.dumps(rows))
        return
    flip_s = flip_motion("cell.yaml")["flip_s"]
    out = throughput(args.catalog, args.orders, flip_s)
    for k in ("before", "after"):
        s = out[k]
        print(f"{k:>6}: {s['parts_good']} good in {s['makespan_s'] / 3600:.2f} h: {s['parts_per_hour']:.3f} parts/h, "
              f"cycle {s['cycle_time_s']:.1f} s, robot {100 * s['robot_utilisation']:.1f} %, machine "
              f"{100 * s['machine_utilisation']:.1f} %")
    print(f"flip {flip_s:.2f} s per part; op 2 program [s] per part: "
          + ", ".join(f"{p}: {'not planned (0)' if v is None else v}" for p, v in out["op2_machining_s"].items()))
    if args.json:
        print(json.dumps(out))


if __name__ == "__main__":
    main()
