"""The continuous collision proof's share of robot planning: a part's tending planned and posted.

    python benchmarks/robot_proof.py [--stock bracket,plate_bosses] [--setups 2] [--repeat 1] [--plan DIR]

For each sample stock plans the default cell's tending through the cell's roadmap (cached
beforehand, its build not counted: ``factory cell warm`` does it once per cell file), then posts
the URScript program, whose servo path is proven again (:func:`robotprog.programs.post_program`):
the polyline through its servo targets is not the planned spline, so it is its own motion to prove.
Prints CPU [s] (the figure to compare on a shared machine) and wall [s] of each, the planned
motion [s] (unchanged by a faster proof) and the machine's load average; the last line is one JSON
object. Run it from a checkout with ``PYTHONPATH`` at that checkout to compare two versions.

``--plan DIR`` (a ``factory plan`` output folder) also plans each part there as ``factory plan``'s robot
stages do: its setup sheet's stock (with the holding allowance, 22.5 mm tall for the bracket where
``--stock`` takes 16 mm) and the box of the part's own mesh, in as many setups as the plan has. Reliefs
(the robot holds the block) are left out.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.robot_roadmap import part_box, timed  # noqa: E402
from factory.core.resources import FIXTURES  # noqa: E402
from factory.roadmaps import cached_roadmap  # noqa: E402
from robotprog.cell import load_cell  # noqa: E402
from robotprog.collision import collision_world  # noqa: E402
from robotprog.programs import post_program  # noqa: E402
from robotprog.tending import PartBox, part_box_in_vise, plan_tending  # noqa: E402
from robotprog.frames import setup_sheet_to_cell  # noqa: E402
from cadcam.mesh import load_part  # noqa: E402
import numpy as np  # noqa: E402
from tests.robotprog.test_tending import SAMPLE_STOCK, sheet  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stock", default="bracket,plate_bosses")
    ap.add_argument("--setups", default="2")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--plan", type=Path, action="append", default=[],
                    help="a `factory plan` output folder: its parts as the plan's robot stages plan them")
    args = ap.parse_args()
    cell = load_cell(FIXTURES / "cell.yaml")
    world = collision_world(cell)
    roadmap = cached_roadmap(cell, world).roadmap
    rows = []
    print(f"{'stock':13} {'setups':>6} {'plan cpu':>8} {'plan wall':>9} {'post cpu':>8} {'post wall':>9} "
          f"{'motion s':>8} {'load':>5}")
    cases = [(stock, setups, sheet(*SAMPLE_STOCK[stock]), part_box(SAMPLE_STOCK[stock]) if setups == 2 else None)
             for stock in args.stock.split(",") if stock for setups in (int(s) for s in args.setups.split(","))]
    cases += [case for folder in args.plan for case in planned_cases(folder)]
    with tempfile.TemporaryDirectory() as out:
        for stock, setups, stock_sheet, box in cases:
            for _ in range(args.repeat):
                plan, pc, pw = timed(lambda: plan_tending(cell, stock_sheet, part_box=box,
                                                          world=world, setups=setups, roadmap=roadmap))
                _, qc, qw = timed(lambda: post_program("urscript", Path(out) / f"{stock}.script", cell, world,
                                                       plan))
                row = {"stock": stock, "setups": setups, "plan_cpu_s": round(pc, 2), "plan_wall_s": round(pw, 2),
                       "post_cpu_s": round(qc, 2), "post_wall_s": round(qw, 2),
                       "motion_s": round(plan.duration, 3), "load": round(os.getloadavg()[0], 1)}
                rows.append(row)
                print(f"{stock:13} {setups:6d} {pc:8.2f} {pw:9.2f} {qc:8.2f} {qw:9.2f} {plan.duration:8.3f} "
                      f"{row['load']:5.1f}", flush=True)
    print(json.dumps({"cores": os.cpu_count(), "rows": rows}))


def planned_cases(folder: Path) -> list[tuple[str, int, dict, PartBox]]:
    """(part, setups, op 1's setup sheet, the part's box in the vise [m]) of each solid part ``factory plan``
    wrote into ``folder``, as its robot stages plan it."""
    cases = []
    for summary in sorted(folder.glob("*.plan.json")):
        doc = json.loads(summary.read_text())
        if doc.get("relief") or not doc.get("robot"):
            continue
        stem = summary.name.removesuffix(".plan.json")
        op1 = json.loads((folder / f"{stem}.setup.json").read_text())
        part = load_part(Path(doc["part"]))
        box = part_box_in_vise(setup_sheet_to_cell(op1), np.asarray(part.mesh.vertices) / float(op1["mesh_scale"]))
        cases.append((stem, len(doc["setups"]), op1, box))
    return cases


if __name__ == "__main__":
    main()
