"""Per generated test surface (tests/cadcam/reliefs.py) and the sample relief: triangles, shells,
plan time, cycle estimate and the largest gouge, planned with defaults as `factory plan --no-robot` does.

    .venv/bin/python benchmarks/relief_surfaces.py [--sample] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from factory.cam import CamRequest  # noqa: E402
from factory.plan import PlanRequest, plan_part  # noqa: E402
from tests.cadcam.test_relief import SURFACES, _write  # noqa: E402


def measure(path: Path) -> dict:
    t0 = time.perf_counter()
    plan = plan_part(PlanRequest(CamRequest.defaults(path), robot=False))
    seconds = time.perf_counter() - t0
    loaded = plan.planned.loaded
    return {"surface": path.stem, "triangles": int(len(loaded.mesh.faces)),
            "shells": loaded.surface.shells if loaded.surface else None,
            "plan_s": round(seconds, 1), "cycle_min": round(plan.program.total_time / 60.0, 2),
            "max_gouge_mm": round(float(plan.report.max_gouge), 4), "verify_ok": bool(plan.report.ok)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sample", action="store_true", help="also samples/relief.stl")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        paths = [_write(Path(tmp), name, make()) for name, make in SURFACES.items()]
        if args.sample:
            paths.append(ROOT / "samples" / "relief.stl")
        for p in paths:
            rows.append(measure(p))
            print(json.dumps(rows[-1]) if args.json else rows[-1], flush=True)
    if args.json:
        print(json.dumps(rows))


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
