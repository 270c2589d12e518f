"""Speed and size of ``factory simulate``: the sample orders through the cell, once planned.

    python benchmarks/cell.py [--catalog build] [--orders samples/orders.yaml] [--faults 3] [--json]

Plans the sample parts into the catalog first if they are not there (``make demo`` does the
same into ``build/``; that time is reported apart and is not the simulation's). Then runs
``factory simulate`` twice through the CLI with ``--mcap``: the first run may take the camera
pictures (kept in the catalog), the second is the steady case. Reports wall time per stage
[s] (prepare = read plans, parse G-code, machine timeline, stock snapshots; simulate = the
discrete-event run; write = MCAP), simulated hours, the MCAP size [MB] and message counts.
Timings are single runs on whatever machine this is: compare runs on the same machine. With
``--json`` the last line is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from typer.testing import CliRunner  # noqa: E402

from cli.main import app  # noqa: E402


def _run(args: list[str]) -> tuple[dict, float]:
    t0 = time.perf_counter()
    r = CliRunner().invoke(app, [str(a) for a in args])
    wall = time.perf_counter() - t0
    if r.exit_code != 0:
        raise SystemExit(f"factory {' '.join(map(str, args))} failed:\n{r.output}")
    return json.loads(r.stdout), wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--catalog", type=Path, default=ROOT / "build")
    ap.add_argument("--orders", type=Path, default=ROOT / "samples" / "orders.yaml")
    ap.add_argument("--faults", type=int, default=None)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()

    out = Path(tempfile.mkdtemp(prefix="factory-cell-"))
    runs = []
    for k in range(2):
        args = ["simulate", a.orders, "--catalog", a.catalog, "--mcap", out / "cell.mcap", "--overwrite", "--json",
                "--quiet"]
        if a.faults is not None:
            args += ["--faults", str(a.faults)]
        doc, wall = _run(args)
        runs.append({"wall_s": round(wall, 2), "stages_s": doc["seconds"],
                     "planned_now": sum(1 for p in doc["parts"] if p.get("planned_now"))})
        print(f"run {k + 1}: {wall:.1f} s wall, stages {doc['seconds']}, parts planned now: "
              f"{runs[-1]['planned_now']}")
    s = doc["summary"]
    result = {
        "machine": platform.processor() or platform.machine(),
        "orders": len(doc["orders"]),
        "parts_good": s["parts_good"],
        "simulated_h": round(s["makespan_s"] / 3600, 3),
        "faults": s["faults"],
        "runs": runs,
        "mcap_mb": round(doc["mcap"]["bytes"] / 1e6, 2),
        "messages": doc["mcap"]["messages"],
    }
    print(f"{result['orders']} orders, {s['parts_good']} good parts, {result['simulated_h']} h simulated; "
          f"MCAP {result['mcap_mb']} MB, {sum(result['messages'].values())} messages")
    if a.json:
        print(json.dumps(result))


if __name__ == "__main__":
    main()
