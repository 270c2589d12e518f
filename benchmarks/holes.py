"""Round holes on the sample parts: found, drilled, helixed, and how long finding and planning them takes.

    python benchmarks/holes.py [PART.stl ...] [--json]

For each part (default: samples/*.stl) placed as `factory plan` places it, with the roughing
tool it would choose: the holes :func:`cadcam.drilling.find_holes` reads from the mesh (size,
bottom, depth), what :func:`cadcam.drilling.plan_holes` does with them, the hole operations
with their tools and cycles, and the wall time of each step [s]. Single runs: compare on one machine.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cadcam.drilling import find_holes, plan_holes  # noqa: E402
from cadcam.mesh import load_part  # noqa: E402
from cadcam.plan import PlanOptions, choose_tools  # noqa: E402
from cadcam.setup import make_setup  # noqa: E402
from cadcam.tools import load_tool_library  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("parts", nargs="*", type=Path)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    parts = args.parts or sorted((ROOT / "samples").glob("*.stl"))
    library = load_tool_library()
    options = PlanOptions()
    rows = []
    for path in parts:
        setup, part = make_setup(load_part(path).mesh)
        rough, _ = choose_tools(library, setup, options)
        t0 = time.perf_counter()
        holes = find_holes(part, options.drilling)
        t1 = time.perf_counter()
        plan = plan_holes(part, setup, library, rough, options.drilling, options.roughing.min_helix_diameter,
                          options.roughing.allowance)
        t2 = time.perf_counter()
        rows.append({
            "part": path.stem, "rough_tool": rough.number, "found": len(holes), "drilled": len(plan.drilled),
            "undersize": len(plan.undersize), "helixed": len(plan.helixed), "left": len(plan.left),
            "holes": [h.describe() for h in holes],
            "operations": [f"{op.name} T{op.tool.number}" + (f" G{op.cycle.code}" if op.cycle else "")
                           for op in plan.operations],
            "find_s": round(t1 - t0, 4), "plan_s": round(t2 - t1, 4),
        })
        r = rows[-1]
        print(f"{r['part']:14s} found {r['found']}  drilled {r['drilled']} (undersize {r['undersize']})  "
              f"helixed {r['helixed']}  left to roughing T{r['rough_tool']} {r['left']}  "
              f"find {r['find_s']:.3f} s  plan {r['plan_s']:.3f} s")
        for h in r["holes"]:
            print(f"    {h}")
        for op in r["operations"]:
            print(f"    op: {op}")
    if args.json:
        print(json.dumps({"rows": rows}))


if __name__ == "__main__":
    main()
