"""How safely `factory plan`'s programs cut: engagement per tool, rapids through stock, cycle time.

    python benchmarks/safe_cutting.py [PART.stl ...] [--scallop 0.005] [--cell 0.5] [--json]

For each part (default: samples/*.stl) the job is planned as `factory plan` plans it
(tools chosen from fixtures/tools.yaml), posted for LinuxCNC, parsed back, and every move
swept in order through the stock by the independent probe in tests/cadcam/sweep.py:

- max engagement per tool: the deepest any feed move of that tool cuts below the stock as
  the earlier moves left it [mm]; max buried: the same counting only material more than
  1 mm inside the tool's edge (a thin skin off a tall wall is not a buried tool);
- rapids checked / hitting: G0 moves below the safe plane, and those cutting > 0.05 mm;
- lowest cut vs the stock bottom [mm];
- the post's cycle-time estimate [s] and the plan's wall time [s].
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cadcam.finishing import FinishingOptions  # noqa: E402
from cadcam.gcode import parse_gcode  # noqa: E402
from cadcam.mesh import load_part  # noqa: E402
from cadcam.model import Motion  # noqa: E402
from cadcam.plan import PlanOptions, plan_job  # noqa: E402
from cadcam.post import PostOptions, post_process  # noqa: E402
from cadcam.setup import make_setup  # noqa: E402
from cadcam.tools import load_tool_library  # noqa: E402
from tests.cadcam.sweep import rapid_hits, sweep_moves  # noqa: E402


def bench_part(path: Path, scallop: float, cell: float) -> dict:
    lib = load_tool_library()
    setup, part = make_setup(load_part(path).mesh)
    options = PlanOptions(finishing=FinishingOptions(scallop=scallop))
    t0 = time.perf_counter()
    job = plan_job(part, setup, lib, part_name=path.stem, options=options).job
    plan_s = time.perf_counter() - t0
    program = post_process(job, PostOptions())
    moves = parse_gcode(program.text)
    tools = {t.number: t for t in job.tools}
    t0 = time.perf_counter()
    sw = sweep_moves(moves.points, moves.motion, moves.tool, tools, setup, cell)
    sweep_s = time.perf_counter() - t0
    feed = moves.motion != Motion.RAPID
    per_tool, buried = {}, {}
    for t in tools:
        sel = feed & (moves.tool == t)
        per_tool[f"T{t}"] = round(float(sw.engagement[sel].max()) if sel.any() else 0.0, 2)
        buried[f"T{t}"] = round(float(sw.buried[sel].max()) if sel.any() else 0.0, 2)
    below = np.flatnonzero((moves.motion == Motion.RAPID) & (moves.points[:, 2] < setup.safe_z - 1e-6))
    hits = rapid_hits(sw, moves.motion)
    lowest_cut = float(np.nanmin(np.where(feed, sw.lowest, np.nan)))
    unreached = job.parameters.get("unreached", [])
    return {
        "part": path.stem,
        "operations": [f"{op.kind}:T{op.tool.number}" for op in job.operations],
        "max_engagement_mm": per_tool,
        "max_buried_mm": buried,
        "rapids_checked": int(len(below)),
        "rapids_hitting": int(len(hits)),
        "worst_rapid_mm": round(float(sw.engagement[hits].max()) if len(hits) else 0.0, 2),
        "below_stock_mm": round(max(0.0, float(setup.stock_min[2]) - lowest_cut), 3),
        "unreached": len(unreached),
        "cycle_s": round(program.total_time, 1),
        "plan_s": round(plan_s, 1),
        "sweep_s": round(sweep_s, 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("parts", nargs="*", type=Path)
    ap.add_argument("--scallop", type=float, default=0.005)
    ap.add_argument("--cell", type=float, default=0.5)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    parts = args.parts or sorted((ROOT / "samples").glob("*.stl"))
    rows = []
    for p in parts:
        row = bench_part(p, args.scallop, args.cell)
        rows.append(row)
        print(json.dumps(row), flush=True)
    if args.json:
        print(json.dumps({"rows": rows}))


if __name__ == "__main__":
    main()
