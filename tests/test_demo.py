"""`make demo`'s report: one line per part as it finishes, and a table, both within 100 columns."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_demo_summary_fits_100_columns_and_says_the_verdict(block_catalog):
    catalog, part = block_catalog
    summary = catalog / f"{part.stem}.plan.json"
    doc = json.loads(summary.read_text())
    run = [sys.executable, str(ROOT / "samples" / "summarize.py")]
    line = subprocess.run([*run, "--line", str(summary)], check=True, capture_output=True, text=True).stdout
    assert line.count("\n") == 1 and len(line.rstrip("\n")) <= 100, line
    # the finished part's regions: op 2's verdict carries what op 1 left on the part
    last = doc.get("verify_op2") or doc["verify"]
    left = sum(u.get("why") not in ("left for op 2", "outside the relief's surface") for u in last["left"])
    verdict = ("verify FAILED" if not doc["verify"]["ok"] else f"stock left in {left} region" if left else
               "verify OK, finished")
    assert line.startswith(f"{part.stem}: {verdict}"), line
    ops = len(doc["setups"])
    assert (f"{ops} ops" if ops > 1 else "1 op,") in line and f"left max {doc['verify']['remaining_max']:.3f} mm" in line
    table = subprocess.run([*run, str(summary), str(summary)], check=True, capture_output=True, text=True).stdout
    rows = table.splitlines()
    assert len(rows) == 3 and all(len(r) <= 100 for r in rows), table
    assert rows[0].split()[:2] == ["part", "ops"] and rows[1].split()[0] == part.stem


def test_the_demo_starts_the_largest_sample_first(tmp_path):
    """`make -j` starts the plans in the order `plans` lists them: the longest first, so that no long plan
    starts last and runs alone on one core at the end."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / ".installed").touch()  # newer than pyproject.toml: nothing to install
    dry = subprocess.run(["make", "-n", "plans", f"BIN={bin_dir}", f"OUT={tmp_path / 'out'}"], cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout
    planned = [line.split(" plan samples/", 1)[1].split(".stl", 1)[0] for line in dry.splitlines()
               if " plan samples/" in line]
    by_size = sorted(ROOT.glob("samples/*.stl"), key=lambda p: -p.stat().st_size)
    assert planned == [p.stem for p in by_size] and planned[0] == "relief", dry


def test_the_demo_told_not_to_install_never_installs_and_warms_the_cell_first(tmp_path):
    """`make -o STAMP demo` with a stamp older than pyproject.toml: neither make nor the plans' sub-make
    (which is not passed `-o`) installs into the venv; the cell's roadmap is warmed before the plans."""
    import os

    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    stamp = bin_dir / ".installed"
    stamp.touch()
    os.utime(stamp, (0, 0))  # older than pyproject.toml: a reinstall is due, but -o says never
    dry = subprocess.run(["make", "-n", "-o", str(stamp), "demo", f"BIN={bin_dir}", f"OUT={tmp_path / 'out'}"],
                         cwd=ROOT, check=True, capture_output=True, text=True).stdout
    assert "pip install" not in dry and " -m venv " not in dry, dry
    commands = [line for line in dry.splitlines() if line.startswith(str(bin_dir / "factory"))]
    assert commands[0].endswith("factory cell warm fixtures/cell.yaml"), dry
    assert sum(" plan samples/" in c for c in commands) == len(list(ROOT.glob("samples/*.stl"))), dry
