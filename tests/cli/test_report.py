"""`factory report`: its figures recounted independently from the record with plain `sqlite3` SQL.

Two runs of the small pocketed block (one with many faults) go into one record; the report's
throughput, OEE factors, cycle times, alarm Pareto and part histories must equal what SQL over the
file gives, by the definitions in :mod:`factory.report`.
"""

from __future__ import annotations

import json
import shutil
import statistics
import subprocess
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.main import app
from tests.cli.expect import assert_one_line_error, simulate_exit

runner = CliRunner()
pytestmark = pytest.mark.skipif(shutil.which("sqlite3") is None, reason="the sqlite3 client is not installed")


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def sql(db: Path, query: str) -> list[list[str]]:
    out = subprocess.run(["sqlite3", "-batch", str(db), query], check=True, capture_output=True, text=True).stdout
    return [line.split("|") for line in out.splitlines()]


def num(db: Path, query: str) -> float:
    value = sql(db, query)[0][0]
    return float(value) if value else 0.0


@pytest.fixture(scope="module")
def record(block_catalog, tmp_path_factory) -> Path:
    folder, part = block_catalog
    out = tmp_path_factory.mktemp("report")
    orders = out / "orders.csv"
    orders.write_text(f"part,quantity,material,priority\n{part},4,aluminium,0\n{part},2,aluminium,1\n")
    db = out / "cell.sqlite"
    for seed, rate in (("3", "0.3"), ("7", "0.2")):
        r = run("simulate", orders, "--catalog", folder, "--faults", seed, "--fault-rate", rate, "--db", db, "--quiet",
                "--json")
        assert r.exit_code == simulate_exit(json.loads(r.stdout)), r.output
    return db


@pytest.fixture(scope="module")
def report(record) -> dict:
    r = run("report", record, "--json")
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout)


def test_throughput_and_oee_match_a_recount_in_sql(record, report):
    db = record
    planned = num(db, "SELECT sum(makespan_s) FROM run")
    good = num(db, "SELECT count(*) FROM part_unit WHERE outcome = 'good'")
    made = num(db, "SELECT count(*) FROM part_unit WHERE outcome IN ('good', 'rejected')")
    downtime = num(db, "SELECT sum(lost_s) FROM alarm") + \
        num(db, "SELECT sum(machine_time_s) FROM job_response WHERE kind = 'reset'")
    ideal = num(db, "SELECT sum(o.ideal_cycle_s) FROM part_unit u JOIN operation o ON o.work_order_id = u.work_order_id "
                    "WHERE u.outcome IN ('good', 'rejected')")
    assert [r["id"] for r in report["runs"]] == [1, 2] and all(r["complete"] for r in report["runs"])
    t, o = report["throughput"], report["oee"]
    assert t["parts_good"] == good > 0
    assert t["parts_per_hour"] == pytest.approx(3600 * good / planned, abs=1e-3)
    assert o["planned_s"] == pytest.approx(planned, abs=1e-3)
    assert o["downtime_s"] == pytest.approx(downtime, abs=1e-3) and downtime > 0
    availability, performance, quality = (planned - downtime) / planned, ideal / (planned - downtime), good / made
    assert o["availability"] == pytest.approx(availability, abs=1e-4)
    assert o["performance"] == pytest.approx(performance, abs=1e-4)
    assert o["quality"] == pytest.approx(quality, abs=1e-4)
    assert o["oee"] == pytest.approx(availability * performance * quality, abs=2e-4)
    assert 0 < o["availability"] < 1 and 0 < o["performance"] <= 1 and 0 < o["quality"] <= 1
    # each run's throughput as simulate reported it
    for r in report["runs"]:
        summary = json.loads(sql(db, f"SELECT summary FROM run WHERE id = {r['id']}")[0][0])
        assert r["parts_good"] == summary["parts_good"]
        assert r["parts_per_hour"] == pytest.approx(summary["parts_per_hour"], abs=1e-3)


def test_cycle_times_and_alarm_pareto_match_a_recount_in_sql(record, report):
    db = record
    cycles = [float(c) for (c,) in sql(db, "SELECT ended_s - started_s FROM part_unit "
                                           "WHERE outcome IN ('good', 'rejected', 'scrap')")]
    c = report["cycle_time"]
    assert c["count"] == len(cycles)
    assert c["median_s"] == pytest.approx(statistics.median(cycles), abs=1e-3)
    assert c["min_s"] == pytest.approx(min(cycles), abs=1e-3) and c["max_s"] == pytest.approx(max(cycles), abs=1e-3)
    assert sum(c["histogram"]["counts"]) == len(cycles)
    by_kind = {k: (int(n), float(lost)) for k, n, lost in sql(db, "SELECT kind, count(*), sum(lost_s) FROM alarm "
                                                                  "GROUP BY kind")}
    pareto = report["alarms"]
    assert {a["kind"]: (a["count"], a["lost_s"]) for a in pareto} == \
        {k: (n, pytest.approx(lost, abs=1e-3)) for k, (n, lost) in by_kind.items()}
    assert [a["count"] for a in pareto] == sorted((a["count"] for a in pareto), reverse=True)
    assert pareto[-1]["cumulative"] == 1.0


def test_every_part_has_its_history_by_serial(record, report):
    db = record
    serials = [s for (s,) in sql(db, "SELECT serial FROM part_unit ORDER BY run_id, job")]
    assert [p["serial"] for p in report["parts"]] == serials and len(set(serials)) == len(serials)
    part = next(p for p in report["parts"] if p["alarms"])
    steps = sql(db, "SELECT s.event, s.state FROM job_state s JOIN part_unit u ON u.id = s.part_unit_id "
                    f"WHERE u.serial = '{part['serial']}' ORDER BY s.id")
    assert [[h["event"], h["state"]] for h in part["history"]] == steps
    r = run("report", record, "--serial", part["serial"])
    assert r.exit_code == 0, r.output
    assert f"part {part['serial']}" in r.stdout and part["alarms"][0]["kind"] in r.stdout
    assert r.stdout.count(" -> ") == len(steps)


def test_text_png_url_and_one_run(record, report, tmp_path):
    png = tmp_path / "dashboard.png"
    r = run("report", f"sqlite:///{record}", "--png", png, "--run", "2")
    assert r.exit_code == 0, r.output
    assert "throughput" in r.stdout and "OEE" in r.stdout and "run 2" in r.stdout and "run 1 " not in r.stdout
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    from PIL import Image
    with Image.open(png) as img:
        assert img.size == (1200, 900)
    one = json.loads(run("report", record, "--run", "2", "--json").stdout)
    assert one["throughput"]["parts_good"] == num(record, "SELECT count(*) FROM part_unit WHERE run_id = 2 "
                                                          "AND outcome = 'good'")
    assert_one_line_error(run("report", record, "--png", png), str(png), "--overwrite")


def test_errors_are_one_line(record, tmp_path):
    assert_one_line_error(run("report", tmp_path / "none.sqlite"), "none.sqlite", "no such record")
    assert_one_line_error(run("report", record, "--run", "9"), "no run 9")
    assert_one_line_error(run("report", record, "--serial", "R999999-00001"), "R999999-00001")
    r = run("report", "postgresql+psycopg://cell:hunter2@127.0.0.1:1/plant")
    assert_one_line_error(r, "postgresql+psycopg://cell:***@127.0.0.1:1/plant")
    assert "hunter2" not in r.output
