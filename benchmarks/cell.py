"""Speed and size of ``factory simulate``: the sample orders through the cell, once planned.

    python benchmarks/cell.py [--catalog build] [--orders samples/orders.yaml] [--faults 3] [--json]
    python benchmarks/cell.py --catalog CAT --generate 10,100,1000 [--robot-rate 25] [--db] [--json]

Plans the sample parts into the catalog first if they are not there (``make demo`` does the
same into ``build/``; that time is reported apart and is not the simulation's). Then runs
``factory simulate`` twice through the CLI with ``--mcap``: the first run may take the camera
pictures (kept in the catalog), the second is the steady case. Reports wall time per stage
[s] (prepare = read plans, parse G-code, machine timeline, stock snapshots; simulate = the
discrete-event run; write = MCAP), simulated hours, the MCAP size [MB] and message counts.
Timings are single runs on whatever machine this is: compare runs on the same machine. With
``--json`` the last line is one JSON object.

``--generate N,...``: scale-out instead. For each N, an orders file of N orders (one part each,
the sample parts in turn, aluminium) runs once through ``factory simulate --mcap`` in its own
process under ``/usr/bin/time``, which reports its processor time and peak resident memory; printed
per N: wall and processor time [s], peak RSS [MB], MCAP size [MB], simulated hours. Plan the sample
parts into the catalog first (the first run would plan them inside the timing). With ``--db`` each run also appends to a fresh
SQLite process record (``factory simulate --mcap --db``: the log and the record users keep).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
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


SAMPLE_PARTS = ("bracket.stl", "plate_bosses.stl", "dome_mould.stl", "stepped_wall.stl")


def scale_out(catalog: Path, counts: list[int], robot_rate: float | None, faults: int | None,
              db: bool = False) -> list[dict]:
    """One ``factory simulate --mcap`` (``--db``: and a fresh SQLite record) process per order count: wall [s],
    peak RSS [MB], MCAP [MB], record [MB]."""
    out = Path(tempfile.mkdtemp(prefix="factory-cell-"))
    rows = []
    for n in counts:
        orders = out / f"orders-{n}.csv"
        orders.write_text("part,quantity,material,priority\n" + "".join(
            f"{ROOT / 'samples' / SAMPLE_PARTS[i % len(SAMPLE_PARTS)]},1,aluminium,0\n" for i in range(n)))
        mcap = out / f"cell-{n}.mcap"
        args = [sys.executable, "-c", "from cli.main import main; main()", "simulate", str(orders),
                "--catalog", str(catalog), "--mcap", str(mcap), "--overwrite", "--json", "--quiet"]
        if robot_rate is not None:
            args += ["--robot-rate", str(robot_rate)]
        if faults is not None:
            args += ["--faults", str(faults)]
        record = out / f"cell-{n}.sqlite"
        if db:
            args += ["--db", str(record)]
        rss_file = out / "rss.txt"
        t0 = time.perf_counter()
        r = subprocess.run(["/usr/bin/time", "-f", "%U %S %M", "-o", str(rss_file), *args], capture_output=True,
                           text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
        wall = time.perf_counter() - t0
        if r.returncode != 0:
            raise SystemExit(f"simulate of {n} orders failed:\n{r.stderr[-2000:]}")
        doc = json.loads(r.stdout)
        # GNU time's %U %S: processor seconds (user, system), steadier than wall on a shared machine;
        # %M: peak resident set [KiB]
        user_s, system_s, peak_kb = rss_file.read_text().split()[-3:]
        row = {"orders": n, "wall_s": round(wall, 1), "cpu_s": round(float(user_s) + float(system_s), 1),
               "peak_rss_mb": round(int(peak_kb) / 1024),
               "mcap_mb": round(mcap.stat().st_size / 1e6, 1),
               "simulated_h": round(doc["summary"]["makespan_s"] / 3600, 1),
               "db_mb": round(record.stat().st_size / 1e6, 1) if db else None,
               "parts_good": doc["summary"]["parts_good"], "oee": doc["summary"]["oee"],
               "parts_per_hour": doc["summary"]["parts_per_hour"], "stages_s": doc["seconds"],
               "planned_now": sum(1 for p in doc["parts"] if p.get("planned_now"))}
        rows.append(row)
        print(f"{n} orders: {row['wall_s']} s wall, {row['cpu_s']} s processor, peak RSS {row['peak_rss_mb']} MB, MCAP {row['mcap_mb']} MB, "
              f"{row['simulated_h']} h simulated, {row['parts_good']} good; stages {row['stages_s']}", flush=True)
        mcap.unlink()
        record.unlink(missing_ok=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--catalog", type=Path, default=ROOT / "build")
    ap.add_argument("--orders", type=Path, default=ROOT / "samples" / "orders.yaml")
    ap.add_argument("--faults", type=int, default=None)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--generate", default=None, help="order counts to scale out to, e.g. 10,100,1000")
    ap.add_argument("--robot-rate", type=float, default=None, help="with --generate: simulate --robot-rate [Hz]")
    ap.add_argument("--db", action="store_true", help="with --generate: also record each run (simulate --db)")
    a = ap.parse_args()
    if a.generate:
        rows = scale_out(a.catalog, [int(n) for n in a.generate.split(",")], a.robot_rate, a.faults, a.db)
        if a.json:
            print(json.dumps({"machine": platform.processor() or platform.machine(), "robot_rate_hz": a.robot_rate,
                              "db": a.db, "load_avg": os.getloadavg()[0], "runs": rows}))
        return

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
