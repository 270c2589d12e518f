"""Robot planning time per sample part: today's search, and through the cell's roadmap, cold and warm.

    python benchmarks/robot_roadmap.py [--stock bracket,plate_bosses,dome_mould,stepped_wall] [--setups 1,2]

For each sample stock (and with ``--setups 2`` its part after op 1 on a 6 mm holding block, turned
over on the flip station) plans the default cell's tending (:func:`robotprog.tending.plan_tending`):

* ``before``: without a roadmap (the RRT-Connect for every transfer that is not straight),
* ``warm``: through the cell's roadmap read from the cache (:func:`factory.roadmaps.cached_roadmap`),
* ``cold``: ``warm`` plus building, proving and writing the roadmap (the first plan in a cell
  nobody warmed: ``roadmap_build`` once per cell file, in a fresh temporary cache).

Prints CPU [s] (the figure to compare on a shared machine), wall [s] and the planned motion [s]
per part and mode, the machine's load average with them; the last line is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from factory.core.resources import FIXTURES  # noqa: E402
from factory.roadmaps import cached_roadmap  # noqa: E402
from robotprog.cell import load_cell  # noqa: E402
from robotprog.collision import collision_world  # noqa: E402
from robotprog.tending import PartBox, plan_tending  # noqa: E402
from tests.robotprog.test_tending import SAMPLE_STOCK, sheet  # noqa: E402

#: Holding block under the part after op 1, and the part's allowance on each side [m].
BLOCK_M, SIDE_M = 0.006, 0.002


def part_box(size_mm) -> PartBox:
    """The part inside the stock in the vise frame [m]: the stock less its sides and holding block."""
    sx, sy, sz = (v / 1000 for v in size_mm)
    return PartBox(np.array([-sx / 2 + SIDE_M, -sy / 2 + SIDE_M, BLOCK_M]), np.array([sx / 2 - SIDE_M, sy / 2 - SIDE_M, sz]))


def timed(fn):
    c0, t0 = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.process_time() - c0, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stock", default=",".join(SAMPLE_STOCK))
    ap.add_argument("--setups", default="1,2")
    args = ap.parse_args()
    cell = load_cell(FIXTURES / "cell.yaml")
    world = collision_world(cell)
    with tempfile.TemporaryDirectory() as cache:
        os.environ["FACTORY_CACHE_DIR"] = cache
        got, build_cpu, build_wall = timed(lambda: cached_roadmap(cell, world))
        _, read_cpu, read_wall = timed(lambda: cached_roadmap(cell, world))
    roadmap = got.roadmap
    rows = []
    print(f"roadmap build: cpu {build_cpu:.2f} s wall {build_wall:.2f} s ({len(roadmap.nodes)} nodes, "
          f"{len(roadmap.edges)} segments); read: {read_wall * 1000:.1f} ms; load {os.getloadavg()[0]:.1f}")
    print(f"{'stock':13} {'setups':>6} {'mode':7} {'cpu s':>7} {'wall s':>7} {'motion s':>8} {'load':>5}")
    for stock in args.stock.split(","):
        for setups in (int(s) for s in args.setups.split(",")):
            box = part_box(SAMPLE_STOCK[stock]) if setups == 2 else None
            for mode, rm in (("before", None), ("warm", roadmap)):
                plan, cpu, wall = timed(lambda: plan_tending(cell, sheet(*SAMPLE_STOCK[stock]), part_box=box,
                                                            world=world, setups=setups, roadmap=rm))
                if mode == "warm":
                    cpu, wall = cpu + read_cpu, wall + read_wall
                modes = [(mode, cpu, wall)] + ([("cold", cpu + build_cpu, wall + build_wall)] if mode == "warm" else [])
                for name, c, w in modes:
                    row = {"stock": stock, "setups": setups, "mode": name, "cpu_s": round(c, 2), "wall_s": round(w, 2),
                           "motion_s": round(plan.duration, 3), "load": round(os.getloadavg()[0], 1)}
                    rows.append(row)
                    print(f"{stock:13} {setups:6d} {name:7} {c:7.2f} {w:7.2f} {plan.duration:8.3f} {row['load']:5.1f}",
                          flush=True)
    print(json.dumps({"cores": os.cpu_count(), "roadmap_build_cpu_s": round(build_cpu, 2),
                      "roadmap_build_wall_s": round(build_wall, 2), "rows": rows}))


if __name__ == "__main__":
    main()
