"""OEE terms of a simulated run (robotprog.oee): exact without faults, lower availability with them,
and the same figures `factory report` computes from the process record of the same run."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings, strategies as st

from robotprog.cellsim import Activity, FaultModel, LogEntry, RunningSummary, running_summary, simulate
from robotprog.oee import DowntimeLedger, Loss, oee_terms
from robotprog.orders import Order
from tests.robotprog.test_cellsim import A, B, PROC_A, PROC_B, PROC_TWO

OEE_KEYS = ("availability", "performance", "quality", "oee", "downtime_s", "run_time_s")


def _orders(quantities, parts=(A, B)):
    return [Order(f"o{i + 1}", parts[i % len(parts)], q, "aluminium", 0) for i, q in enumerate(quantities)]


def _check_terms(s):
    a, p, q, oee = (s[k] for k in ("availability", "performance", "quality", "oee"))
    assert 0 < a <= 1 and 0 < p <= 1 and 0 <= q <= 1
    assert oee == pytest.approx(a * p * q, abs=1e-4)
    assert s["run_time_s"] == pytest.approx(s["makespan_s"] - s["downtime_s"], abs=2e-3)


@pytest.mark.parametrize("proc", [PROC_A, PROC_B, PROC_TWO], ids=["long-cut", "long-inspection", "two-setups"])
def test_without_faults_only_the_last_inspection_is_lost(proc):
    n = 6
    s = simulate(_orders([1] * n, (A,)), {A: proc}).summary
    assert s["availability"] == 1.0 and s["downtime_s"] == 0.0 and s["quality"] == 1.0
    # a part every cycle, then the last one's inspection; the ideal is the faster way out of the vise
    assert s["performance"] == pytest.approx(n * proc.ideal_cycle_s / (n * proc.cycle_s + proc.inspect_s), abs=1e-4)
    assert s["oee"] == s["performance"]
    _check_terms(s)


def test_faults_seed_1_lose_availability():
    """As ``factory simulate --faults 1``: the stops' time is downtime, the rejects quality."""
    s = simulate(_orders([2, 1, 1, 2, 1, 1, 1, 1, 1, 1]), {A: PROC_A, B: PROC_B}, FaultModel.default(1)).summary
    stops = {k: n for k, n in s["faults"].items() if k != "inspect_fail"}
    assert stops, "seed 1 should stop the cell at least once"
    assert s["downtime_s"] > 0 and s["availability"] < 1
    # rejects lose quality (a part scrapped after alarms is not made: it counts in parts_rejected only)
    assert s["parts_good"] / (s["parts_good"] + s["parts_rejected"]) - 1e-4 <= s["quality"] <= 1
    _check_terms(s)


def test_a_fault_loses_the_attempt_it_ended_and_a_reset_its_time():
    ledger = DowntimeLedger()
    for event in (LogEntry(0.0, 1, "o1", "FETCH_RAW", "start"),
                  Activity("camera", "locate", 1, 0.0, 2.0, "done"),
                  Activity("robot", "missed_grasp", 1, 2.0, 17.0, "grasp_missed"),
                  LogEntry(17.0, 1, "o1", "FAULT", "grasp_missed"),
                  LogEntry(17.0, 1, "o1", "RECOVER", "recover"),
                  Activity("camera", "locate", 1, 17.0, 19.0, "done"),
                  LogEntry(40.0, 1, "o1", "LOAD", "fetched"),
                  Activity("machine", "reset", 1, 100.0, 160.0, "reset"),
                  Activity("machine", "cut", 1, 160.0, 200.0, "machine_alarm"),
                  LogEntry(200.0, 1, "o1", "FAULT", "machine_alarm")):
        ledger(event)
    assert ledger.losses == [Loss("grasp_missed", 1, 0.0, 17.0), Loss("reset", 1, 100.0, 160.0),
                             Loss("machine_alarm", 1, 160.0, 200.0)]
    # by a time: a fault once raised, a reset as far as it went
    assert [sum(x.lost_by(t) for x in ledger.losses) for t in (10.0, 17.0, 130.0, 199.0, 200.0)] == \
        [0.0, 17.0, 47.0, 77.0, 117.0]


def test_terms_are_none_until_defined():
    assert oee_terms(0.0, 0.0, 0.0, 0, 0)["availability"] is None
    t = oee_terms(100.0, 10.0, 0.0, 0, 0)
    assert (t["availability"], t["performance"], t["quality"], t["oee"]) == (0.9, 0.0, None, None)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31), rate=st.floats(0.0, 0.4),
       quantities=st.lists(st.integers(1, 3), min_size=1, max_size=4), shares=st.lists(st.floats(0.0, 1.0),
                                                                                        min_size=1, max_size=6))
def test_running_terms_end_as_the_run_s(seed, rate, quantities, shares):
    result = simulate(_orders(quantities), {A: PROC_A, B: PROC_B}, FaultModel(rate, rate, rate, rate, seed))
    final = result.summary
    last = running_summary(result, final["makespan_s"])
    for key in OEE_KEYS:
        assert last[key] == final[key], key
    if final["oee"] is not None:
        _check_terms(final)
    walk = RunningSummary(result)
    for t in sorted(final["makespan_s"] * s for s in shares):
        now = walk.at(t)
        assert now["downtime_s"] <= final["downtime_s"] + 1e-9
        assert now["availability"] is None or 0 <= now["availability"] <= 1


def test_the_summary_is_what_factory_report_makes_of_the_record(tmp_path):
    """An independent computation: the process record of the same run, read back with SQL."""
    from factory.record import OperationPlan, Record
    from factory.report import cell_report

    orders = _orders([3, 2, 2, 1])
    processes = {A: PROC_A, B: PROC_B}
    record = Record(tmp_path / "cell.sqlite")
    recorder = record.recorder(cell="test", orders=orders, orders_file="orders.csv", orders_sha256="0" * 64,
                               faults_seed=5)
    plans = {(part, "aluminium"): OperationPlan(f"{part.stem}.nc", "0" * 64, p.machining_s, p.ideal_cycle_s,
                                                {"inspect_pass": {}, "inspect_fail": {}}, "0" * 64)
             for part, p in processes.items()}
    try:
        result = simulate(orders, {(part, "aluminium"): p for part, p in processes.items()},
                          FaultModel(0.2, 0.2, 0.2, 0.2, seed=5), sink=recorder.begin(plans))
        recorder.finish(result)
    finally:
        recorder.close()
    report = cell_report(record)["oee"]
    record.close()
    s = result.summary
    assert s["downtime_s"] > 0
    for key in ("availability", "performance", "quality", "oee", "downtime_s"):
        assert s[key] == pytest.approx(report[key], abs=2e-4), key
    assert s["run_time_s"] == pytest.approx(report["operating_s"], abs=2e-3)


def test_a_part_in_two_setups_counts_its_whole_cycle_once():
    s = simulate(_orders([2], (Path("two.stl"),)), {Path("two.stl"): PROC_TWO}).summary
    assert s["performance"] == pytest.approx(2 * PROC_TWO.ideal_cycle_s / s["makespan_s"], abs=1e-4)
