"""Both operations of every sample part: cycle estimates, op 2's wall time, and the two verifies.

    python benchmarks/two_ops.py [PART.stl ...] [--grid 0.2] [--json]

For each part, ``factory plan`` as a library (no robot): op 1's and op 2's estimated cycle
time [s], the wall time op 2 adds to the plan (planning, post, verify from op 1's stock
turned over) [s], and each verify's verdict, deepest gouge and stock left over its faces
(p95) [mm]. With ``--json`` the last line is one JSON object ``{"rows": [...]}``. Timings are
single runs on whatever machine this is: compare runs on the same machine.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from factory.plan import PlanRequest, plan_part  # noqa: E402


def bench_part(path: Path, grid: float) -> dict:
    plan = plan_part(dataclasses.replace(PlanRequest.defaults(path, "aluminium"), grid=grid, robot=False))
    op2 = plan.op2
    r1, r2 = plan.report, op2.report
    return {
        "part": path.stem,
        "op1_cycle_s": round(plan.program.total_time, 1),
        "op2_cycle_s": round(op2.program.total_time, 1),
        "op2_wall_s": round(sum(v for k, v in plan.seconds.items() if k.startswith("op 2")), 2),
        "holding_mm": op2.job.parameters["holding_mm"],
        "op2_operations": [op.name for op in op2.job.operations],
        "op1_verify": {"ok": r1.ok, "max_gouge": round(r1.max_gouge, 4), "p95": round(r1.remaining_p95, 4)},
        "op2_verify": {"ok": r2.ok, "max_gouge": round(r2.max_gouge, 4), "p95": round(r2.remaining_p95, 4)},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("parts", nargs="*", type=Path, default=sorted((ROOT / "samples").glob("*.stl")))
    ap.add_argument("--grid", type=float, default=0.2, help="verify grid [mm]")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows = []
    print(f"# {platform.processor() or platform.machine()}, python {platform.python_version()}")
    print(f"{'part':14s} {'op 1 [s]':>9s} {'op 2 [s]':>9s} {'op 2 wall [s]':>13s}  op 1 verify / op 2 verify")
    for path in args.parts:
        row = bench_part(path, args.grid)
        rows.append(row)
        v1, v2 = row["op1_verify"], row["op2_verify"]
        print(f"{row['part']:14s} {row['op1_cycle_s']:9.1f} {row['op2_cycle_s']:9.1f} {row['op2_wall_s']:13.2f}  "
              f"{'OK' if v1['ok'] else 'FAILED'} p95 {v1['p95']:.3f} / {'OK' if v2['ok'] else 'FAILED'} "
              f"p95 {v2['p95']:.3f} gouge {v2['max_gouge']:.3f} mm", flush=True)
    if args.json:
        print(json.dumps({"rows": rows}))


if __name__ == "__main__":
    main()
