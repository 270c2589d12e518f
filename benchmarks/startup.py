"""Start-up of a ``factory plan`` job: processor time spent before, and beside, the planning itself.

    python benchmarks/startup.py [--repeat 7] [--root CHECKOUT] [--json]

Every job of the Snakemake workflow is one ``factory plan`` process, so what the process spends
on importing libraries and parsing its command line is paid once per part. Measures, each as
the least of ``--repeat`` runs of a fresh process (the least is the figure least disturbed by
other users of a shared machine), processor time (user + sys) [s] of:

- ``factory --help``: the command group alone;
- ``factory plan --help``: the plan command's module and everything it imports;
- ``factory plan PART`` up to its first stage: interpreter, imports, option parsing and checks,
  stopped where :func:`factory.plan.plan_part` would start planning (samples/bracket.stl);
- the imports a plan run makes later, when it first times a robot move (TOPP-RA, through
  :func:`robotprog.toppra_loader.load_toppra`): ``import cli.plan`` and loading TOPP-RA, less
  ``import cli.plan``.

The sum of the last two is one job's start-up as the workflow pays it. With ``--json`` the last
line is one JSON object. ``--root`` measures another checkout of factory (say, a ``git worktree``
of an older commit) with this interpreter and its libraries: every process starts in that folder
and imports factory from it.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# `factory ARGS` as its console script runs it, with factory imported from the working folder.
_FACTORY = "import sys\nfrom cli.main import main\nsys.argv = ['factory', *sys.argv[1:]]\nmain()"

# Runs `factory plan ARGS` in this process, but stops it where planning would begin.
_UNTIL_FIRST_STAGE = """
import sys
import cli.main, cli.plan

class _FirstStage(Exception):
    pass

def _stop(*args, **kwargs):
    raise _FirstStage

cli.plan.plan_part = _stop
sys.argv = ["factory", *sys.argv[1:]]
try:
    cli.main.main()
except _FirstStage:
    sys.exit(0)
sys.exit("factory plan ended before its first stage")
"""


# What a plan run has imported once it has timed its first robot move; a checkout older than the
# loader imported toppra itself (decided by its files: the editable install would find this one's).
_WITH_TOPPRA = "import cli.plan\nfrom robotprog.toppra_loader import load_toppra\nload_toppra()"
_WITH_TOPPRA_BEFORE_LOADER = "import cli.plan, toppra.algorithm, toppra.constraint"


def _cpu_s(cmd: list[str], repeat: int, root: Path) -> float:
    """Least processor time [s] (user + sys) of ``repeat`` runs of ``cmd``, each a fresh process."""
    best = float("inf")
    for _ in range(repeat):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        r = subprocess.run(cmd, capture_output=True, text=True, cwd=root)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if r.returncode != 0:
            raise SystemExit(f"{' '.join(cmd)} failed:\n{r.stderr[-2000:]}")
        best = min(best, after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return best


def measure(repeat: int, root: Path = ROOT) -> dict[str, float]:
    """Processor time [s] of each start-up figure (see the module docstring) of the checkout ``root``."""
    py = sys.executable
    with_toppra = _WITH_TOPPRA if (root / "robotprog" / "toppra_loader.py").exists() else _WITH_TOPPRA_BEFORE_LOADER
    with tempfile.TemporaryDirectory() as tmp:
        until_stage = [py, "-c", _UNTIL_FIRST_STAGE, "plan", str(root / "samples" / "bracket.stl"), "-o", tmp,
                       "--quiet"]
        figures = {
            "factory_help": _cpu_s([py, "-c", _FACTORY, "--help"], repeat, root),
            "plan_help": _cpu_s([py, "-c", _FACTORY, "plan", "--help"], repeat, root),
            "plan_until_first_stage": _cpu_s(until_stage, repeat, root),
            "import_cli_plan": _cpu_s([py, "-c", "import cli.plan"], repeat, root),
            "import_cli_plan_toppra": _cpu_s([py, "-c", with_toppra], repeat, root),
        }
    figures["later_imports_toppra"] = max(figures["import_cli_plan_toppra"] - figures["import_cli_plan"], 0.0)
    figures["plan_job_startup"] = figures["plan_until_first_stage"] + figures["later_imports_toppra"]
    return figures


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7, help="runs of each command; the least counts")
    ap.add_argument("--root", type=Path, default=ROOT, help="checkout of factory to measure (default: this one)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    figures = {k: round(v, 3) for k, v in measure(args.repeat, args.root.resolve()).items()}
    for key, value in figures.items():
        print(f"{key}: {value} s", file=sys.stderr)
    if args.json:
        print(json.dumps(figures))


if __name__ == "__main__":
    main()
