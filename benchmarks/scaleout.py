"""Planning a parts catalog with the Snakemake workflow: speed-up with concurrent jobs, per-job overhead.

    python benchmarks/scaleout.py [--generated 4] [--fast] [--json]

Plans the sample parts plus ``--generated`` pocketed blocks (different sizes) with the workflow's
``plans`` target, first with 1 and then with 2 concurrent jobs (``--cores``; every job held to
one thread: the workflow sets ``FACTORY_THREADS`` to the job's threads), each into a fresh folder.
Every job's ``factory`` runs under ``/usr/bin/time``, so each job's own processor time is known. Reports:

- wall time of each run [s] and the speed-up of 2 jobs over 1;
- each job's peak resident memory [MB], what the plan rule's ``mem_mb`` must cover;
- processor time (user + sys) of each run's whole process tree [s], of every job, and the rest:
  the driver's own (Snakemake: parse, DAG, file checks, starting the jobs);
- the jobs' own compute: the sum of the stage times each ``factory plan`` reports in its summary;
- per-job overhead, as the issue defines it: (wall with 1 job - compute) / jobs, i.e. what
  Snakemake and starting a job cost, split into what each job's process spends outside its
  stages (start-up, exit) and what the driver spends between jobs (every stage of a plan is
  timed, so a plan's work is not counted as overhead); and the same in processor time: the driver's share per job
  plus one ``factory plan`` job's start-up (``benchmarks/startup.py``: interpreter, imports and
  option parsing up to the first stage, and the TOPP-RA a plan loads when it first times a move);
- what each job costs on a cluster besides its ``factory``: there every submission is a Snakemake
  process of its own on the node; measured through the cluster-generic executor with a stand-in
  ``factory`` that only touches a plan's outputs, one part per submission and ``--group`` parts
  per submission (Snakemake's job grouping, as the Slurm profile submits them);
- the speed-up the measured jobs allow on 2 cores: their processor times scheduled longest first
  on 2 slots (what an otherwise idle machine would give, less the driver);
- the driver as a fixed cost plus a cost per job, from dry runs over ``--dry-parts`` copies of a
  part and over the parts planned; and a paper estimate of 10,000 parts on 100 Slurm nodes.

Timings are single runs on whatever machine this is: on a shared machine the wall times carry
the other users' load, the processor times much less so. factory's own modules are byte-compiled
first, as an installed factory has them (pip compiles at install, Python on first import): with
``PYTHONDONTWRITEBYTECODE`` set and an editable install, every job would compile them again
(0.15 s). With ``--json`` the last line is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import yaml  # noqa: E402

from startup import measure as measure_startup  # noqa: E402  (benchmarks/startup.py)
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


def _tree_cpu() -> float:
    """Processor time [s] (user + sys) of every finished child process tree so far."""
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def _timed_factory(folder: Path) -> Path:
    """A ``factory`` that records its own processor time in ``folder/times/``, one file per job."""
    (folder / "times").mkdir(parents=True)
    wrapper = folder / "factory"
    wrapper.write_text(f'#!/bin/sh\nexec /usr/bin/time -f "%e %U %S %M" -o "{folder}/times/$$" {BIN / "factory"} "$@"\n')
    wrapper.chmod(0o755)
    return wrapper


def _run(folder: Path, parts: Path, cores: int, options: dict, *extra: str) -> tuple[float, float]:
    """(wall [s], processor time of the whole tree [s]) of one Snakemake run."""
    factory = _timed_factory(folder) if not (folder / "factory").exists() else folder / "factory"
    (folder / "config.yaml").write_text(yaml.safe_dump(
        {"parts": str(parts), "catalog": "catalog", "orders": str(ROOT / "samples" / "one_each.csv"),
         "out": "out", "factory": str(factory), "options": options}))
    cmd = [str(BIN / "snakemake"), "-s", str(SNAKEFILE), "--configfile", str(folder / "config.yaml"),
           "--directory", str(folder), "--cores", str(cores), *extra]
    cpu0, t0 = _tree_cpu(), time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - t0, _tree_cpu() - cpu0
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{r.stderr[-3000:]}")
    return wall, cpu


def _compute(folder: Path) -> float:
    return sum(sum(json.loads(p.read_text())["seconds"].values()) for p in folder.glob("catalog/*/*.plan.json"))


def _job_times(folder: Path) -> list[tuple[float, float, float]]:
    """(wall [s], processor time [s], peak resident memory [MB]) of each job's ``factory`` process,
    from the last line ``/usr/bin/time`` wrote (a line before it says when the job exited non-zero)."""
    out = []
    for p in sorted((folder / "times").iterdir()):
        wall, user, system, rss_kb = map(float, p.read_text().splitlines()[-1].split())
        out.append((wall, user + system, rss_kb / 1024))
    return out


# A stand-in `factory` for the cluster run: it only touches the files a plan writes, so what the
# job costs is what the workflow adds to a plan on a node.
_TOUCH_PLAN = """#!/bin/sh
[ "$1" = plan ] || exit 0
part=$(basename "$2"); part=${part%.*}; mkdir -p "$4"
for ext in nc setup.json mcap verify.json verify.png toolpath.png setup.png plan.json; do : > "$4/$part.$ext"; done
"""


def _cluster_node_cpu(folder: Path, parts: Path, options: dict, group: int = 1) -> tuple[list[float], int]:
    """(processor time [s] of each submission's own Snakemake on a "node", parts): every part planned
    through the cluster-generic executor, each submission a separate process under ``/usr/bin/time``,
    ``group`` parts to a submission (Snakemake's job grouping, as the Slurm profile does it), the plan
    itself a stand-in that only touches its outputs."""
    folder.mkdir()
    (folder / "times").mkdir()
    touch = folder / "touch_plan"
    touch.write_text(_TOUCH_PLAN)
    touch.chmod(0o755)
    submit = (f"bash -c 'echo >> {folder}/submitted; /usr/bin/time -f \"%U %S\" -o {folder}/times/$$ bash \"$1\" "
              ">/dev/null 2>&1 </dev/null & echo $!' submit")
    (folder / "config.yaml").write_text(yaml.safe_dump(
        {"parts": str(parts), "catalog": "catalog", "orders": str(ROOT / "samples" / "one_each.csv"),
         "out": "out", "factory": str(touch), "options": options}))
    cmd = [str(BIN / "snakemake"), "plans", "-s", str(SNAKEFILE), "--configfile", str(folder / "config.yaml"),
           "--directory", str(folder), "--executor", "cluster-generic", "--cluster-generic-submit-cmd", submit,
           "--jobs", "2", "--latency-wait", "5"]
    if group > 1:
        cmd += ["--groups", "plan=planning", "--group-components", f"planning={group}"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{r.stderr[-3000:]}")
    # A job's script marks it done just before its `time` writes the figure: wait for the last ones.
    submitted = len((folder / "submitted").read_text().splitlines())
    for _ in range(100):
        times = [p.read_text().split() for p in (folder / "times").iterdir()]
        if len(times) == submitted and all(len(t) >= 2 for t in times):
            return [float(t[-2]) + float(t[-1]) for t in times], len(list(parts.iterdir()))
        time.sleep(0.1)
    raise SystemExit(f"{folder}: {len(times)} of {submitted} cluster jobs timed")


def _compile_factory() -> None:
    """Byte-compile factory's own packages, as an installed factory has them (see the docstring)."""
    packages = [str(ROOT / name) for name in ("cadcam", "cli", "factory", "robotprog", "vision")]
    subprocess.run([sys.executable, "-m", "compileall", "-q", *packages], check=True, capture_output=True)


def _longest_first(jobs: list[float], slots: int) -> float:
    """Makespan [s] of ``jobs`` [s] scheduled longest first, each on the least loaded of ``slots``."""
    load = [0.0] * slots
    for t in sorted(jobs, reverse=True):
        load[load.index(min(load))] += t
    return max(load)


def estimate_s(job_cpu: list[float], driver_fixed_s: float, driver_per_job_s: float, parts: int,
               slots: int, node_job_s: float = 0.0) -> dict[str, float]:
    """Paper estimate [s] of ``parts`` jobs on ``slots`` cores, each job one thread on its own core.

    Each job takes what one of the measured jobs took in processor time (``job_cpu`` [s], its
    start-up included), plus ``node_job_s`` [s], what the job's own Snakemake costs on the node:
    on a core of its own that is its wall time. Scheduled as they come, the
    jobs end within their mean load per slot plus the longest job (Graham's bound for list
    scheduling). The driver adds its fixed cost and its cost per job (DAG, file checks); what it
    spends submitting to Slurm and polling it is not measured here.
    """
    mean = sum(job_cpu) / len(job_cpu) + node_job_s
    jobs = parts * mean / slots + max(job_cpu) + node_job_s
    driver = driver_fixed_s + driver_per_job_s * parts
    return {"jobs_s": jobs, "driver_s": driver, "wall_s": jobs + driver}


def _dry_parts(folder: Path, count: int) -> Path:
    """``count`` copies of one sample mesh: a catalog for dry runs (nothing is planned)."""
    folder.mkdir(parents=True)
    mesh = (ROOT / "samples" / "bracket.stl").read_bytes()
    for k in range(count):
        (folder / f"part{k:05d}.stl").write_bytes(mesh)
    return folder


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--generated", type=int, default=4, help="pocketed blocks added to the samples")
    ap.add_argument("--fast", action="store_true", help="coarse CAM options (scallop 0.05, verify grid 0.5)")
    ap.add_argument("--dry-parts", type=int, default=400, help="parts of the larger dry run (driver per job)")
    ap.add_argument("--nodes", type=int, default=100, help="Slurm nodes of the estimate")
    ap.add_argument("--cores-per-node", type=int, default=32, help="cores per node of the estimate")
    ap.add_argument("--group", type=int, default=8, help="parts per cluster submission (the Slurm profile's)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    options = {"scallop": 0.05, "grid": 0.5} if args.fast else {}
    _compile_factory()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        n = _parts(tmp / "parts", args.generated)
        t0 = time.perf_counter()
        subprocess.run([str(BIN / "factory"), "--help"], capture_output=True, check=True)
        startup = time.perf_counter() - t0
        startup_figures = measure_startup(repeat=3)
        startup_cpu = startup_figures["plan_job_startup"]
        walls, cpus, compute, jobs_cpu, jobs_wall, jobs_rss = {}, {}, {}, {}, {}, {}
        for cores in (1, 2):
            folder = tmp / f"cores{cores}"
            folder.mkdir()
            walls[cores], cpus[cores] = _run(folder, tmp / "parts", cores, options, "plans")
            compute[cores] = _compute(folder)
            times = _job_times(folder)
            jobs_wall[cores] = [t[0] for t in times]
            jobs_cpu[cores] = [t[1] for t in times]
            jobs_rss[cores] = [t[2] for t in times]
        dry_wall, dry_cpu = _run(tmp / "dry_small", tmp / "parts", 1, options, "plans", "--dry-run")
        big = _dry_parts(tmp / "dry_parts", args.dry_parts)
        dry_big_wall, dry_big_cpu = _run(tmp / "dry_big", big, 1, options, "plans", "--dry-run")
        node_jobs_cpu, _ = _cluster_node_cpu(tmp / "cluster", tmp / "parts", options)
        grouped_cpu, grouped_parts = _cluster_node_cpu(tmp / "cluster_grouped",
                                                       _dry_parts(tmp / "grouped_parts", 2 * args.group),
                                                       options, args.group)
    node_job_cpu = sum(node_jobs_cpu) / len(node_jobs_cpu)
    node_part_cpu_grouped = sum(grouped_cpu) / grouped_parts
    per_job_s = compute[1] / n
    overhead = (walls[1] - compute[1]) / n
    driver_cpu = cpus[1] - sum(jobs_cpu[1])
    overhead_cpu = driver_cpu / n + startup_cpu
    # The driver is a fixed cost (interpreter, Snakemake and the Snakefile's imports) plus a cost per
    # job (DAG, file checks): a line through the dry runs over n and over --dry-parts parts.
    driver_per_job_cpu = max(dry_big_cpu - dry_cpu, 0.0) / (args.dry_parts - n)
    driver_fixed_cpu = max(dry_cpu - driver_per_job_cpu * n, 0.0)
    # Paper estimate from processor times, not from this machine's (shared, loaded) wall times.
    parts = 10_000
    slots = args.nodes * args.cores_per_node
    paper = estimate_s(jobs_cpu[1], driver_fixed_cpu, driver_per_job_cpu, parts, slots, node_part_cpu_grouped)
    result = {
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "load_1min_at_end": round(os.getloadavg()[0], 1)},
        "parts": n, "fast_options": args.fast,
        "wall_s": {str(k): round(v, 1) for k, v in walls.items()},
        "speedup_2_jobs": round(walls[1] / walls[2], 2),
        "cpu_s": {str(k): round(v, 1) for k, v in cpus.items()},
        "jobs_cpu_s": {str(k): round(sum(v), 1) for k, v in jobs_cpu.items()},
        "job_cpu_s": [round(t, 1) for t in sorted(jobs_cpu[1], reverse=True)],
        # what the plan rule's mem_mb must cover: the largest peak resident memory of a job [MB]
        "job_peak_rss_mb": round(max(jobs_rss[1] + jobs_rss[2])),
        "speedup_2_jobs_from_cpu": round(sum(jobs_cpu[1]) / _longest_first(jobs_cpu[1], 2), 2),
        "compute_s": {str(k): round(v, 1) for k, v in compute.items()},
        "per_job_compute_s": round(per_job_s, 2),
        "per_job_overhead_s": round(overhead, 2),
        # ... split: inside each job's process but outside its stages (interpreter, imports, option
        # checks, exit), and outside the jobs (the driver: parse, DAG, file checks, starting jobs)
        "per_job_overhead_in_job_s": round((sum(jobs_wall[1]) - compute[1]) / n, 2),
        "per_job_overhead_driver_s": round((walls[1] - sum(jobs_wall[1])) / n, 2),
        "per_job_overhead_cpu_s": round(overhead_cpu, 2),
        # the same with the driver's fixed start-up (what its dry run costs) left out: per job at scale
        "per_job_overhead_cpu_marginal_s": round(max(driver_cpu - driver_fixed_cpu, 0.0) / n + startup_cpu, 2),
        "driver_cpu_s": round(driver_cpu, 2),
        "factory_startup_s": round(startup, 2),
        "factory_plan_startup_cpu_s": round(startup_cpu, 2),
        "factory_plan_help_cpu_s": round(startup_figures["plan_help"], 2),
        "cluster_node_job_cpu_s": round(node_job_cpu, 2),
        "per_job_overhead_cpu_on_a_cluster_s": round(node_job_cpu + startup_cpu, 2),
        # the Slurm profile's grouping: --group parts to a submission (2 x --group copies of a part)
        "cluster_group_parts": args.group, "cluster_submissions_grouped": len(grouped_cpu),
        "cluster_node_cpu_per_part_grouped_s": round(node_part_cpu_grouped, 2),
        "per_job_overhead_cpu_on_a_cluster_grouped_s": round(node_part_cpu_grouped + startup_cpu, 2),
        "driver_dry_run_s": round(dry_wall, 2),
        "driver_dry_run_cpu_s": {str(n): round(dry_cpu, 2), str(args.dry_parts): round(dry_big_cpu, 2)},
        "driver_cpu_fixed_s": round(driver_fixed_cpu, 2),
        "driver_cpu_per_job_ms": round(1000 * driver_per_job_cpu, 1),
        "estimate_10000_parts": {
            "nodes": args.nodes, "cores_per_node": args.cores_per_node, "jobs_s": round(paper["jobs_s"]),
            "driver_s": round(paper["driver_s"]), "wall_h": round(paper["wall_s"] / 3600, 3)},
    }
    for key, value in result.items():
        print(f"{key}: {value}", file=sys.stderr)
    if args.json:
        print(json.dumps(result))


if __name__ == "__main__":
    main()
