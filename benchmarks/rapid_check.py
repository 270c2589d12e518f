"""The planner's rapid check: the whole verify it ran before (`simulate`, report discarded) against
`rapid_check` (only the rapids and the jaws), on each sample's planned operations; CPU seconds.

    python benchmarks/rapid_check.py [bracket dome_mould ...] [--repeat 2]

Prints one JSON line per part: the CPU seconds of each way (the best of ``--repeat``), and that both
found the same rapid crashes, jaw faults and stock (else it exits 1).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from cadcam.rest import from_and_to_safe_height, _grown  # noqa: E402
from cadcam.stock import operation_moves  # noqa: E402
from cadcam.verify import VerifyOptions, rapid_check, simulate  # noqa: E402
from factory.cam import CamRequest, compute_job  # noqa: E402


def best_cpu(run, repeat: int):
    """(least CPU seconds over ``repeat`` runs, the last result)."""
    best, out = math.inf, None
    for _ in range(repeat):
        c0 = time.process_time()
        out = run()
        best = min(best, time.process_time() - c0)
    return best, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("parts", nargs="*", default=["bracket", "plate_bosses", "dome_mould", "stepped_wall", "relief"])
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    bad = False
    for name in args.parts:
        path = Path(name) if name.endswith(".stl") else ROOT / "samples" / f"{name}.stl"
        req = CamRequest.defaults(path)
        planned = compute_job(req)
        setup, cell = planned.job.setup, req.rapid_cell
        ops = tuple(from_and_to_safe_height(op, setup.safe_z) for op in planned.job.operations)
        tools = {op.tool.number: _grown(op.tool, 0.5 * cell * math.sqrt(2.0)) for op in ops}
        moves = operation_moves(ops)
        tri = np.asarray(planned.part_work.triangles)
        old_s, old = best_cpu(lambda: simulate(moves, tools, setup, tri,
                                               VerifyOptions(cell=cell, engagement_resolution=None)), args.repeat)
        new_s, new = best_cpu(lambda: rapid_check(moves, tools, setup, tri, cell), args.repeat)
        same = (new.rapid_crashes == old.report.rapid_crashes
                and new.jaw_faults == tuple(f for f in old.report.faults if f.kind == "jaws")
                and np.array_equal(new.simulation.stock_top, old.simulation.stock_top))
        bad |= not same
        print(json.dumps({"part": path.stem, "moves": int(len(moves.points)), "cell_mm": cell,
                          "whole_verify_cpu_s": round(old_s, 3), "rapid_check_cpu_s": round(new_s, 3),
                          "saved": round(1.0 - new_s / old_s, 3), "same_findings": same,
                          "load": "%.2f %.2f %.2f" % os.getloadavg()}), flush=True)
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
