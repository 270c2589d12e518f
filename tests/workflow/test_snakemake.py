"""The Snakemake workflow, run by Snakemake itself: locally, through a detached-job executor, and
after its driver was killed.

Two of the sample parts are planned, with coarse options: the workflow, not the parts or their
finish, is under test (tests/cadcam and tests/gallery plan every sample and gallery part).
Every run's deterministic outputs (G-code, setup sheets, verify reports, robot programs, the plan
summaries, and the cell's order outcomes) must equal a clean run's.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from tests.conftest import ROOT, SAMPLES

SNAKEFILE = ROOT / "workflow" / "Snakefile"
PROFILES = ROOT / "workflow" / "profiles"
BIN = Path(sys.executable).parent
PARTS = sorted(p.stem for p in SAMPLES.glob("*.stl"))
# The real runs plan the two quickest samples: enough for two jobs at once and a driver killed between
# them (one done while the other is held under way), at a fifth of the five samples' time.
PLANNED = ("bracket", "stepped_wall")
FAST = {"scallop": 0.05, "grid": 0.5}


def _config(folder: Path, options: dict | None = None, parts: Path = SAMPLES) -> Path:
    """Write the workflow's config into ``folder``: the meshes of ``parts`` (a folder with the
    orders ``one_each.csv``), planned with ``options``."""
    config = {"parts": str(parts), "catalog": "catalog", "orders": str(parts / "one_each.csv"), "out": "out",
              "factory": str(BIN / "factory"), "options": options or FAST}
    path = folder / "config.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def _snakemake(folder: Path, *args: str, **kwargs) -> subprocess.CompletedProcess:
    cmd = [str(BIN / "snakemake"), "-s", str(SNAKEFILE), "--configfile", str(folder / "config.yaml"),
           "--directory", str(folder), *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=1800, **kwargs)


def _outputs(folder: Path) -> dict[str, object]:
    """What a run of :data:`PLANNED` made that must not depend on how it was run."""
    out: dict[str, object] = {}
    for part in PLANNED:
        d = folder / "catalog" / part
        for ext in ("nc", "setup.json", "verify.json", "script"):
            out[f"{part}.{ext}"] = (d / f"{part}.{ext}").read_bytes()
        summary = json.loads((d / f"{part}.plan.json").read_text())
        summary.pop("seconds")
        summary["outputs"] = {k: Path(v).name for k, v in summary["outputs"].items()}
        out[f"{part}.plan.json"] = summary
    # The cell's times include the camera steps' measured processing: outcomes, not times, must agree.
    cell = json.loads((folder / "out" / "cell.json").read_text())
    out["cell"] = [(o["order"], o["outcome"], o["good"], o["rejected"]) for o in cell["orders"]]
    return out


@pytest.fixture(scope="module")
def planned(tmp_path_factory) -> Path:
    """A folder of the :data:`PLANNED` samples and one order of each, shared by every real run (the
    plans name their mesh's path, so every run must read the same one)."""
    folder = tmp_path_factory.mktemp("parts")
    for part in PLANNED:
        shutil.copyfile(SAMPLES / f"{part}.stl", folder / f"{part}.stl")
    (folder / "one_each.csv").write_text("part,quantity,material,priority\n"
                                         + "".join(f"{part}.stl,1,aluminium,0\n" for part in PLANNED))
    return folder


@pytest.fixture(scope="module")
def clean(tmp_path_factory, planned) -> tuple[Path, dict[str, object]]:
    folder = tmp_path_factory.mktemp("clean")
    _config(folder, parts=planned)
    r = _snakemake(folder, "--profile", str(PROFILES / "local"))
    assert r.returncode == 0, r.stderr[-3000:]
    return folder, _outputs(folder)


def test_plans_every_sample_then_runs_the_orders(clean):
    """Every part is planned; the cell makes each part whose plan verifies, and refuses the others
    with the reason (a plan whose verify fails is written whole, its verdict in its summary)."""
    folder, outputs = clean
    verified = {part: json.loads((folder / "catalog" / part / f"{part}.plan.json").read_text())["verify"]["ok"]
                for part in PLANNED}
    assert sum(verified.values()) >= len(PLANNED) - 1, verified
    cell = json.loads((folder / "out" / "cell.json").read_text())
    assert len(cell["orders"]) == len(PLANNED)
    for o in cell["orders"]:
        if verified[Path(o["part"]).stem]:
            assert (o["outcome"], o["good"]) == ("done", 1), o
        else:
            assert o["outcome"] == "failed" and "does not verify" in o["reason"], o
    # No plan was made by the simulation: every one came from the workflow's jobs.
    cell = json.loads((folder / "out" / "cell.json").read_text())
    assert not any(p.get("planned_now") for p in cell["parts"]), cell["parts"]


def test_a_rerun_skips_unchanged_parts_and_replans_changed_options(clean):
    folder, _ = clean
    r = _snakemake(folder, "--cores", "2", "--dry-run")
    assert r.returncode == 0 and "Nothing to be done" in r.stdout + r.stderr, r.stdout[-2000:]
    config = yaml.safe_load((folder / "config.yaml").read_text())
    config["part_options"] = {PLANNED[0]: {"allowance": 0.4}}
    (folder / "config.yaml").write_text(yaml.safe_dump(config))
    r = _snakemake(folder, "--cores", "2", "--dry-run", "--quiet", "rules")
    assert r.returncode == 0, r.stderr[-2000:]
    counts = {line.split()[0]: int(line.split()[1]) for line in (r.stdout + r.stderr).splitlines()
              if len(line.split()) == 2 and line.split()[1].isdigit()}
    assert counts.get("plan") == 1 and counts.get("simulate") == 1, r.stdout + r.stderr


def test_unknown_option_names_are_refused_before_any_job(tmp_path):
    _config(tmp_path, {"scallop": 0.05, "rough-tol": 2})
    r = _snakemake(tmp_path, "--cores", "1")
    assert r.returncode != 0 and "has no option --rough-tol" in r.stdout + r.stderr
    assert not (tmp_path / "catalog").exists()


def test_detached_jobs_make_what_a_local_run_makes(clean, planned, tmp_path):
    _config(tmp_path, parts=planned)
    r = _snakemake(tmp_path, "--profile", str(PROFILES / "detached"))
    assert r.returncode == 0, r.stderr[-3000:]
    assert "Submitted job" in r.stdout + r.stderr and "external jobid" in r.stdout + r.stderr
    assert _outputs(tmp_path) == clean[1]


# The real `factory`, with one part's plan held until a file named `hold` beside it is gone: the driver
# is killed with one plan done and the other surely under way, however the two parts' times compare on
# a loaded machine (unheld, the two samples can finish within one poll of each other).
_HOLD_ONE_PART = """#!/bin/sh
case "$*" in *{held}*) while [ -e "$(dirname "$0")/hold" ]; do sleep 0.1; done;; esac
exec {factory} "$@"
"""


def test_a_driver_killed_mid_run_reruns_to_a_clean_result(clean, planned, tmp_path):
    """SIGKILL to the driver and every job it started (a lost login node), in the middle of the
    plan jobs; then `--unlock` and the same command again finish with a clean run's outputs."""
    first, held = PLANNED
    gate = tmp_path / "factory"
    gate.write_text(_HOLD_ONE_PART.format(held=held, factory=BIN / "factory"))
    gate.chmod(0o755)
    (tmp_path / "hold").touch()
    _config(tmp_path, parts=planned)
    config = yaml.safe_load((tmp_path / "config.yaml").read_text())
    (tmp_path / "config.yaml").write_text(yaml.safe_dump({**config, "factory": str(gate)}))
    cmd = [str(BIN / "snakemake"), "-s", str(SNAKEFILE), "--configfile", str(tmp_path / "config.yaml"),
           "--directory", str(tmp_path), "--profile", str(PROFILES / "local")]
    driver = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 600
    # Kill once the first part is planned while the other's job is under way (held).
    while not (tmp_path / "catalog" / first / f"{first}.plan.json").exists() and time.monotonic() < deadline:
        assert driver.poll() is None, "the workflow ended before it could be killed"
        time.sleep(0.2)
    os.killpg(driver.pid, signal.SIGKILL)
    driver.wait()
    done = sorted(p.name for p in (tmp_path / "catalog").glob("*/*.plan.json"))
    assert done == [f"{first}.plan.json"], done
    assert not (tmp_path / "out" / "cell.json").exists()

    (tmp_path / "hold").unlink()
    assert _snakemake(tmp_path, "--unlock").returncode == 0
    r = _snakemake(tmp_path, "--profile", str(PROFILES / "local"))
    assert r.returncode == 0, r.stderr[-3000:]
    assert _outputs(tmp_path) == clean[1]
    leftovers = [p for p in (tmp_path / "catalog").rglob(".*") if ".snakemake" not in p.parts]
    assert not leftovers, leftovers


# A stand-in `factory`: notes which part its plan job started (in order, in started.log beside it),
# records the FACTORY_THREADS the job was given, and touches the plan's files.
_RECORD_THREADS = """#!/bin/sh
[ "$1" = plan ] || exit 0
part=$(basename "$2"); part=${part%.*}; mkdir -p "$4"
echo "$part" >> "$(dirname "$0")/started.log"
for ext in nc setup.json mcap verify.json verify.png toolpath.png setup.png; do : > "$4/$part.$ext"; done
echo "${FACTORY_THREADS:-unset}" > "$4/$part.plan.json"
"""


def _stand_in_config(folder: Path) -> None:
    stand_in = folder / "factory"
    stand_in.write_text(_RECORD_THREADS)
    stand_in.chmod(0o755)
    _config(folder)
    config = yaml.safe_load((folder / "config.yaml").read_text())
    (folder / "config.yaml").write_text(yaml.safe_dump({**config, "factory": str(stand_in)}))


def test_the_largest_meshes_are_planned_first(tmp_path):
    """Longest first keeps a long part from starting last while other cores idle: with one core the
    jobs start in the order of their meshes' sizes, largest first."""
    _stand_in_config(tmp_path)
    r = _snakemake(tmp_path, "plans", "--cores", "1")
    assert r.returncode == 0, r.stderr[-3000:]
    started = (tmp_path / "started.log").read_text().split()
    assert started == sorted(PARTS, key=lambda p: -(SAMPLES / f"{p}.stl").stat().st_size)


def test_the_slurm_profiles_grouping_plans_several_parts_per_submission(tmp_path):
    """The Slurm profile sends parts to the queue in groups (one submission, one Snakemake start-up on
    the node per group), each part still its own job with its own outputs and one thread."""
    slurm = yaml.safe_load((PROFILES / "slurm" / "config.yaml").read_text())
    group, size = slurm["group-components"].split("=")
    assert slurm["groups"] == f"plan={group}"
    _stand_in_config(tmp_path)
    log = tmp_path / "submitted"
    submit = (f"bash -c 'echo \"$1\" >> {log}; setsid nohup bash \"$1\" >\"$1.out\" 2>&1 </dev/null & echo $!' "
              "submit")
    r = _snakemake(tmp_path, "plans", "--executor", "cluster-generic", "--cluster-generic-submit-cmd", submit,
                   "--jobs", "2", "--latency-wait", "5", "--groups", slurm["groups"],
                   "--group-components", slurm["group-components"])
    assert r.returncode == 0, r.stderr[-3000:]
    assert len(log.read_text().splitlines()) == -(-len(PARTS) // int(size))
    seen = {part: (tmp_path / "catalog" / part / f"{part}.plan.json").read_text().strip() for part in PARTS}
    assert seen == {part: "1" for part in PARTS}


@pytest.mark.parametrize("threads", [None, 2])
def test_each_plan_job_is_held_to_its_threads(tmp_path, threads):
    """A job uses the threads it declares, no more: factory's own workers follow FACTORY_THREADS,
    which the workflow sets to the job's threads (1 unless --set-threads says otherwise)."""
    _stand_in_config(tmp_path)
    extra = [] if threads is None else ["--set-threads", f"plan={threads}"]
    r = _snakemake(tmp_path, "plans", "--cores", "2", *extra)
    assert r.returncode == 0, r.stderr[-3000:]
    seen = {part: (tmp_path / "catalog" / part / f"{part}.plan.json").read_text().strip() for part in PARTS}
    assert seen == {part: str(threads or 1) for part in PARTS}
