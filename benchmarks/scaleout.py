"""Planning a parts catalog with the Snakemake workflow: speed-up with concurrent jobs, per-job overhead.

    python benchmarks/scaleout.py [--generated 4] [--fast] [--json]

Plans the sample parts plus ``--generated`` pocketed blocks (different sizes) with the workflow's
``plans`` target, first with 1 and then with 2 concurrent jobs (``--cores``; every job pinned to
one thread), each into a fresh folder. Reports:

- wall time of each run [s] and the speed-up of 2 jobs over 1;
- the jobs' own compute: the sum of the stage times each ``factory plan`` reports in its summary;
- per-job overhead: (wall with 1 job - compute) / jobs, i.e. what Snakemake and starting a job
  cost (driver, DAG, process and interpreter start-up, imports, file checks), and apart from it
  the start-up of one ``factory`` process (``factory --help``) and of the driver (a dry run);
- a paper estimate of 10,000 parts on 100 Slurm nodes from those figures.

Timings are single runs on whatever machine this is. With ``--json`` the last line is one JSON
object.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import yaml  # noqa: E402

from tests.conftest import pocket_block  # noqa: E402

BIN = Path(sys.executable).parent
SNAKEFILE = ROOT / "workflow" / "Snakefile"


def _parts(folder: Path, generated: int) -> int:
    folder.mkdir(parents=True)
    for p in sorted((ROOT / "samples").glob("*.stl")):
        shutil.copy(p, folder / p.name)
    for k in range(generated):
        size = (30.0 + 6 * k, 22.0 + 3 * k, 16.0 + k)
        pocket_block(size=size, pocket=(size[0] / 2, size[1] / 2, 4.0)).export(folder / f"block{k}.stl")
    return len(list(folder.glob("*.stl")))


def _run(folder: Path, parts: Path, cores: int, options: dict, *extra: str) -> float:
    (folder / "config.yaml").write_text(yaml.safe_dump(
        {"parts": str(parts), "catalog": "catalog", "orders": str(ROOT / "samples" / "one_each.csv"),
         "out": "out", "factory": str(BIN / "factory"), "options": options}))
    cmd = [str(BIN / "snakemake"), "-s", str(SNAKEFILE), "--configfile", str(folder / "config.yaml"),
           "--directory", str(folder), "--cores", str(cores), *extra]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{r.stderr[-3000:]}")
    return wall


def _compute(folder: Path) -> float:
    return sum(sum(json.loads(p.read_text())["seconds"].values()) for p in folder.glob("catalog/*/*.plan.json"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--generated", type=int, default=4, help="pocketed blocks added to the samples")
    ap.add_argument("--fast", action="store_true", help="coarse CAM options (scallop 0.05, verify grid 0.5)")
    ap.add_argument("--nodes", type=int, default=100, help="Slurm nodes of the estimate")
    ap.add_argument("--cores-per-node", type=int, default=32, help="cores per node of the estimate")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    options = {"scallop": 0.05, "grid": 0.5} if args.fast else {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        n = _parts(tmp / "parts", args.generated)
        t0 = time.perf_counter()
        subprocess.run([str(BIN / "factory"), "--help"], capture_output=True, check=True)
        startup = time.perf_counter() - t0
        walls, compute = {}, {}
        for cores in (1, 2):
            folder = tmp / f"cores{cores}"
            folder.mkdir()
            walls[cores] = _run(folder, tmp / "parts", cores, options, "plans")
            compute[cores] = _compute(folder)
        dry = _run(tmp / "cores1", tmp / "parts", 1, options, "plans", "--dry-run")
    per_job_s = compute[1] / n
    overhead = (walls[1] - compute[1]) / n
    # Paper estimate: jobs run in waves of nodes x cores; each job costs its compute plus the
    # measured overhead; the driver adds its DAG time, scaled linearly with the number of jobs.
    parts = 10_000
    slots = args.nodes * args.cores_per_node
    waves = -(-parts // slots)
    driver_s = dry / n * parts
    estimate_s = waves * (per_job_s + overhead) + driver_s
    result = {
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "parts": n, "fast_options": args.fast,
        "wall_s": {str(k): round(v, 1) for k, v in walls.items()},
        "speedup_2_jobs": round(walls[1] / walls[2], 2),
        "compute_s": {str(k): round(v, 1) for k, v in compute.items()},
        "per_job_compute_s": round(per_job_s, 2),
        "per_job_overhead_s": round(overhead, 2),
        "factory_startup_s": round(startup, 2),
        "driver_dry_run_s": round(dry, 2),
        "estimate_10000_parts": {
            "nodes": args.nodes, "cores_per_node": args.cores_per_node, "waves": waves,
            "driver_s": round(driver_s), "wall_h": round(estimate_s / 3600, 2)},
    }
    for key, value in result.items():
        print(f"{key}: {value}", file=sys.stderr)
    if args.json:
        print(json.dumps(result))


if __name__ == "__main__":
    main()
