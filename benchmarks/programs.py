"""Planned against controller-predicted time of every posted robot program, per arm and sample.

    python benchmarks/programs.py [--langs urscript,rapid,krl] [--json]

For each language's sample cell (URScript: ``fixtures/cell.yaml``, the UR5; RAPID:
``cell_abb.yaml``, the ABB IRB 1200-5/0.9; KRL: ``cell_kuka.yaml``, the KUKA KR 6 R900 sixx) and
the four sample parts' stock sizes: plans load and unload (:func:`robotprog.tending.plan_tending`),
posts the program (:func:`robotprog.programs.post_program`: the posted path collision-checked), and
prints the planned motion time and the controller's (:func:`robotprog.controller.program_duration`)
[s] for both ways of the verdict (out-tray, reject bin), their ratio, the joint targets posted, and
the wall time of planning and posting [s]. Goal: every ratio within 1 +- 0.05. With ``--json`` the
last line is one JSON object. Timings are single runs on whatever machine this is.
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
from robotprog.programs import post_program  # noqa: E402
from robotprog.tending import plan_tending  # noqa: E402
from tests.robotprog.test_tending import SAMPLE_STOCK, sheet  # noqa: E402

CELLS = {"urscript": "cell.yaml", "rapid": "cell_abb.yaml", "krl": "cell_kuka.yaml"}
FILES = {"urscript": "part.script", "rapid": "part.mod", "krl": "part.src"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--langs", default="urscript,rapid,krl")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows = []
    print(f"{'lang':9} {'arm':22} {'sample':13} {'planned':>8} {'predicted':>9} {'ratio':>6} "
          f"{'reject pl':>9} {'reject pr':>9} {'ratio':>6} {'targets':>7} {'plan s':>6} {'post s':>6}")
    for lang in args.langs.split(","):
        cell = load_cell(FIXTURES / CELLS[lang])
        world = collision_world(cell)
        for name, stock in SAMPLE_STOCK.items():
            t0 = time.perf_counter()
            plan = plan_tending(cell, sheet(*stock), world=world)
            t1 = time.perf_counter()
            p = post_program(lang, Path(FILES[lang]), cell, world, plan)
            t2 = time.perf_counter()
            row = {"lang": lang, "arm": world.robot.name, "sample": name, "planned_s": round(p.planned_s, 3),
                   "predicted_s": round(p.predicted_s, 3), "ratio": round(p.predicted_s / p.planned_s, 4),
                   "reject_planned_s": None if p.planned_reject_s is None else round(p.planned_reject_s, 3),
                   "reject_predicted_s": None if p.predicted_reject_s is None else round(p.predicted_reject_s, 3),
                   "reject_ratio": (None if not p.planned_reject_s or p.predicted_reject_s is None
                                    else round(p.predicted_reject_s / p.planned_reject_s, 4)),
                   "targets": p.targets, "plan_wall_s": round(t1 - t0, 1), "post_wall_s": round(t2 - t1, 1)}
            rows.append(row)
            print(f"{lang:9} {row['arm'][:22]:22} {name:13} {row['planned_s']:8.3f} {row['predicted_s']:9.3f} "
                  f"{row['ratio']:6.4f} {row['reject_planned_s'] or 0:9.3f} {row['reject_predicted_s'] or 0:9.3f} "
                  f"{row['reject_ratio'] or 0:6.4f} {row['targets']:7d} {row['plan_wall_s']:6.1f} "
                  f"{row['post_wall_s']:6.1f}", flush=True)
    if args.json:
        print(json.dumps({"machine": platform.node(), "rows": rows}))


if __name__ == "__main__":
    main()
