"""CPU time of planning load + unload, per cell and stock: the cost of proving every move.

    python benchmarks/plan_time.py [--cells cell.yaml,cell_kuka.yaml] [--stock bracket,plate0] [--json]

Plans :func:`robotprog.tending.plan_tending` for each sample cell in ``fixtures/`` and each stock
(the four sample parts' and the tests' random 15 mm plates ``plate0``, ``plate1``) and prints the
process CPU time [s] (the figure to compare between versions on a shared machine: wall time [s]
is printed too, but it counts the other processes), and the planned motion time [s]. With
``--json`` the last line is one JSON object. Single runs: compare runs on the same machine.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from factory.core.resources import FIXTURES  # noqa: E402
from robotprog.cell import load_cell  # noqa: E402
from robotprog.collision import collision_world  # noqa: E402
from robotprog.tending import plan_tending  # noqa: E402
from tests.robotprog.test_programs import RANDOM_STOCK  # noqa: E402
from tests.robotprog.test_tending import SAMPLE_STOCK, sheet  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", default="cell.yaml,cell_kuka.yaml")
    ap.add_argument("--stock", default="bracket,plate_bosses,dome_mould,stepped_wall,plate0")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    stocks = {**SAMPLE_STOCK, **RANDOM_STOCK}
    rows = []
    print(f"{'cell':15} {'stock':13} {'cpu s':>7} {'wall s':>7} {'motion s':>8}")
    for name in args.cells.split(","):
        cell = load_cell(FIXTURES / name)
        world = collision_world(cell)
        for stock in args.stock.split(","):
            c0, t0 = time.process_time(), time.perf_counter()
            plan = plan_tending(cell, sheet(*stocks[stock]), world=world)
            row = {"cell": name, "stock": stock, "cpu_s": round(time.process_time() - c0, 2),
                   "wall_s": round(time.perf_counter() - t0, 2), "motion_s": round(plan.duration, 3)}
            rows.append(row)
            print(f"{name:15} {stock:13} {row['cpu_s']:7.2f} {row['wall_s']:7.2f} {row['motion_s']:8.3f}", flush=True)
    if args.json:
        print(json.dumps({"machine": platform.node(), "rows": rows}))


if __name__ == "__main__":
    main()
