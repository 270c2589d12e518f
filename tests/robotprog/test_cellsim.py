"""Cell simulation: throughput matches the durations, nothing is lost, resources never double-booked."""

from pathlib import Path

import pytest
from hypothesis import given, settings, strategies as st

from factory.core.errors import SchedulerError
from robotprog.cellsim import (Activity, FaultModel, LogEntry, OrderOutcome, PartProcess, RunningSummary,
                               running_summary, simulate)
from robotprog.orders import Order
from robotprog.scheduler import SchedulerOptions, State

A, B = Path("a.stl"), Path("b.stl")
PROC_A = PartProcess(fetch_s=12.0, load_s=15.0, machining_s=300.0, unload_s=14.0, locate_s=2.0, inspect_s=2.5,
                     reject_s=5.0, regrasp_s=3.0)
PROC_B = PartProcess(fetch_s=10.0, load_s=16.0, machining_s=20.0, unload_s=15.0, locate_s=3.0, inspect_s=40.0,
                     reject_s=6.0, regrasp_s=2.0)


def _orders(n, part=A, quantity=1):
    return [Order(f"o{i + 1}", part, quantity, "aluminium", 0) for i in range(n)]


def _check_invariants(result):
    times = [e.time for e in result.log]
    assert times == sorted(times), "time went backwards"
    robot = [(a.start, a.end) for a in result.activities if a.resource == "robot"
             or (a.resource == "camera" and a.action == "locate")]  # the robot waits for the rack camera
    machine = [(a.start, a.end) for a in result.activities if a.resource == "machine"]
    for intervals in (robot, machine, [(s, e) for s, e, _ in result.machine_intervals]):
        spans = sorted(intervals)
        assert all(s <= e for s, e in spans)
        assert all(e0 <= s1 + 1e-9 for (_, e0), (s1, _) in zip(spans, spans[1:])), "resource double-booked"
    # the gripper holds one thing: a picked blank goes straight into the vise
    acts = sorted((a for a in result.activities if a.resource == "robot"), key=lambda a: a.start)
    for a, b in zip(acts, acts[1:]):
        if a.action == "fetch" and a.outcome == "fetched":
            assert b.action == "load" and b.job == a.job and b.start == pytest.approx(a.end)
    for a in result.activities:
        assert 0.0 <= a.fraction <= 1.0
    assert all(o.outcome in ("done", "rejected", "failed") and o.reason for o in result.outcomes)
    s = result.summary
    assert sum(s["faults"].values()) == s["recoveries"] + s["failures"]
    assert 0 <= s["robot_utilisation"] <= 1 and 0 <= s["machine_utilisation"] <= 1


@pytest.mark.parametrize("proc", [PROC_A, PROC_B], ids=["long-cut", "long-inspection"])
def test_no_faults_steady_state_cycle(proc):
    n = 12
    result = simulate(_orders(n), {A: proc})
    _check_invariants(result)
    s = result.summary
    assert s["parts_good"] == n and s["orders"] == {"done": n, "rejected": 0, "failed": 0}
    assert s["faults"] == {} and s["recoveries"] == s["failures"] == 0
    # parts leave one per cycle: pick, load, cut, unload; inspection overlaps the next cut
    ends = sorted(e.time for e in result.log if e.event == "sorted")
    gaps = [b - a for a, b in zip(ends, ends[1:])]
    assert gaps == pytest.approx([proc.cycle_s] * (n - 1))
    assert s["makespan_s"] == pytest.approx(n * proc.cycle_s + proc.inspect_s)
    assert s["machine_utilisation"] == pytest.approx(n * proc.machining_s / s["makespan_s"], abs=1e-4)
    assert s["robot_utilisation"] == pytest.approx(n * proc.robot_s / s["makespan_s"], abs=1e-4)
    assert s["parts_per_hour"] == pytest.approx(3600 * n / s["makespan_s"], rel=1e-3)


def test_machine_holds_part_from_load_to_unload():
    result = simulate(_orders(3), {A: PROC_A})
    holds = [e - s for s, e, _ in result.machine_intervals]
    assert holds == pytest.approx([PROC_A.machine_s] * 3)


def test_faults_seed_1_every_order_ends_with_reason():
    orders = [Order(f"o{i + 1}", A if i % 2 else B, 2, "aluminium", i % 3) for i in range(10)]
    faults = FaultModel(grasp_miss=0.2, stock_not_found=0.2, machine_alarm=0.2, inspect_fail=0.2, seed=1)
    result = simulate(orders, {A: PROC_A, B: PROC_B}, faults)
    _check_invariants(result)
    assert [o.order for o in result.outcomes] == [o.id for o in orders]
    assert sum(result.summary["faults"].values()) > 0
    again = simulate(orders, {A: PROC_A, B: PROC_B}, faults)
    assert again.to_dict() == result.to_dict()  # same seed, same run


def test_unplannable_and_missing_parts_fail_alone():
    orders = [Order("o1", A, 2, "steel", 0), Order("o2", Path("missing.stl"), 1, "steel", 0),
              Order("o3", B, 1, "steel", 0)]
    result = simulate(orders, {A: PROC_A, B: "part wider than the gripper opening"})
    by_id = {o.order: o for o in result.outcomes}
    assert by_id["o1"].outcome == "done" and by_id["o1"].good == 2
    assert by_id["o2"].outcome == "failed" and "missing.stl" in by_id["o2"].reason
    assert by_id["o3"].outcome == "failed" and "gripper" in by_id["o3"].reason


def test_timeout_fires_when_a_step_is_too_slow():
    opts = SchedulerOptions(timeouts={State.MACHINING: 100.0}, program_reruns=1, remakes=0)
    result = simulate(_orders(1), {A: PROC_A}, options=opts)
    _check_invariants(result)
    assert result.summary["faults"] == {"timeout": 2}
    assert result.outcomes[0].outcome == "rejected"


def test_always_missing_grasp_fails_every_order():
    result = simulate(_orders(3), {A: PROC_A}, FaultModel(grasp_miss=1.0))
    _check_invariants(result)
    assert [o.outcome for o in result.outcomes] == ["failed"] * 3
    assert result.summary["parts_good"] == 0 and result.summary["cycle_time_s"] is None


def test_bad_inputs():
    with pytest.raises(SchedulerError):
        simulate([], {})
    with pytest.raises(SchedulerError):
        FaultModel(grasp_miss=1.5)
    with pytest.raises(SchedulerError):
        PartProcess(fetch_s=-1, load_s=1, machining_s=1, unload_s=1, locate_s=1, inspect_s=1, reject_s=1)


_p = st.floats(0.0, 0.6)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31), grasp=_p, found=_p, alarm=_p, inspect=_p,
       quantities=st.lists(st.integers(1, 3), min_size=1, max_size=5))
def test_nothing_is_lost(seed, grasp, found, alarm, inspect, quantities):
    orders = [Order(f"o{i + 1}", A if i % 2 else B, q, "steel", i % 2) for i, q in enumerate(quantities)]
    faults = FaultModel(grasp, found, alarm, inspect, seed)
    result = simulate(orders, {A: PROC_A, B: PROC_B}, faults)
    _check_invariants(result)
    assert len(result.outcomes) == len(orders)
    for order, outcome in zip(orders, result.outcomes):
        if outcome.outcome == "done":
            assert outcome.good == order.quantity
        elif outcome.outcome == "rejected":
            # parts already under way when the limit is hit are still sorted, hence >=
            assert outcome.rejected >= SchedulerOptions().remakes + 1
    # every robot action and machine hold belongs to a job that appears in the log
    jobs = {e.job for e in result.log}
    assert {a.job for a in result.activities} <= jobs
    assert {j for *_, j in result.machine_intervals} <= jobs
    assert set(result.jobs) == jobs - {0}


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31), rate=st.floats(0.0, 0.5), quantities=st.lists(st.integers(1, 3), min_size=1,
                                                                                    max_size=4))
def test_the_sink_is_told_every_event_of_the_result_once(seed, rate, quantities):
    orders = [Order(f"o{i + 1}", A if i % 2 else B, q, "steel", 0) for i, q in enumerate(quantities)]
    orders.append(Order("ox", Path("missing.stl"), 1, "steel", 0))
    told = []
    result = simulate(orders, {A: PROC_A, B: PROC_B}, FaultModel(rate, rate, rate, rate, seed), sink=told.append)
    assert tuple(e for e in told if isinstance(e, LogEntry)) == result.log
    assert sorted((e for e in told if isinstance(e, Activity)), key=lambda a: (a.start, a.end)) == \
        list(result.activities)
    outcomes = [e for e in told if isinstance(e, OrderOutcome)]
    final = {o.order: o for o in outcomes}  # the last told is the final outcome
    assert sorted(final.values(), key=lambda o: o.order) == sorted(result.outcomes, key=lambda o: o.order)
    assert all(a != b for a, b in zip(outcomes, outcomes[1:]))  # told again only when it changed
    assert outcomes[0].order == "ox"  # the order that cannot run is told first
    # an outcome is told right after the transition of that order that decided it
    for i, e in enumerate(told):
        if isinstance(e, OrderOutcome):
            assert isinstance(told[i - 1], LogEntry) and told[i - 1].order == e.order
    # rack steps name their slot
    assert all((a.slot is not None) == (a.action in ("locate", "fetch", "missed_grasp")) for a in result.activities)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), rate=st.floats(0.0, 0.4),
       quantities=st.lists(st.integers(1, 3), min_size=1, max_size=4), share=st.floats(0.0, 1.0))
def test_the_running_summary_grows_into_the_final_one(seed, rate, quantities, share):
    """Counted from the log and activities as the run stood: at the end it agrees with the summary
    the simulation keeps itself; before, it never runs ahead of it."""
    orders = [Order(f"o{i + 1}", A if i % 2 else B, q, "steel", 0) for i, q in enumerate(quantities)]
    result = simulate(orders, {A: PROC_A, B: PROC_B}, FaultModel(rate, rate, rate, rate, seed))
    final = result.summary
    end = final["makespan_s"]
    last = running_summary(result, end)
    for key in ("parts_good", "parts_rejected", "faults", "orders", "recoveries", "failures", "makespan_s"):
        assert last[key] == final[key], key
    # both round to the same places, from a makespan exact or rounded to the millisecond
    for key, tol in (("robot_utilisation", 2e-4), ("machine_utilisation", 2e-4), ("parts_per_hour", 2e-3),
                     ("cycle_time_s", 2e-3)):
        assert last[key] == final[key] if final[key] is None else last[key] == pytest.approx(final[key], abs=tol), key
    early = running_summary(result, end * share)
    assert early["parts_good"] <= final["parts_good"] and early["parts_rejected"] <= final["parts_rejected"]
    assert all(early["faults"].get(k, 0) <= n for k, n in final["faults"].items())


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), rate=st.floats(0.0, 0.4),
       quantities=st.lists(st.integers(1, 3), min_size=1, max_size=4),
       shares=st.lists(st.floats(0.0, 1.2), min_size=1, max_size=12))
def test_one_pass_gives_what_each_time_alone_gives(seed, rate, quantities, shares):
    orders = [Order(f"o{i + 1}", A if i % 2 else B, q, "steel", 0) for i, q in enumerate(quantities)]
    result = simulate(orders, {A: PROC_A, B: PROC_B}, FaultModel(rate, rate, rate, rate, seed))
    walk = RunningSummary(result)
    times = sorted(result.summary["makespan_s"] * s for s in shares)
    for t in times:
        assert walk.at(t) == running_summary(result, t)
    with pytest.raises(ValueError):
        walk.at(times[-1] - 1.0)


#: A part in two setups: op 1 (300 s), the flip (25 s), op 2 (120 s).
PROC_TWO = PartProcess(fetch_s=12.0, load_s=15.0, machining_s=300.0, unload_s=14.0, locate_s=2.0, inspect_s=2.5,
                       reject_s=5.0, regrasp_s=3.0, flip_s=25.0, op2_machining_s=120.0)


def test_two_setups_run_op1_flip_op2_in_order_with_the_summary_durations():
    n = 5
    result = simulate(_orders(n), {A: PROC_TWO})
    _check_invariants(result)
    s = result.summary
    assert s["parts_good"] == n and s["faults"] == {}
    for job in set(result.jobs):
        acts = [a for a in result.activities if a.job == job and a.action in ("load", "cut", "flip", "unload")]
        assert [(a.action, a.op) for a in acts] == [("load", None), ("cut", 1), ("flip", None), ("cut", 2),
                                                    ("unload", None)]
        assert [a.end - a.start for a in acts] == pytest.approx([15.0, 300.0, 25.0, 120.0, 14.0])
        # each step starts when the one before ends: the robot is free while the part is cut
        assert all(b.start == pytest.approx(a.end) for a, b in zip(acts, acts[1:]))
        states = [e.state for e in result.log if e.job == job]
        k = states.index("FLIP")
        assert states[k - 1] == "MACHINING" and states[k + 1] == "MACHINING" and "UNLOAD" in states[k + 1:]
    ends = sorted(e.time for e in result.log if e.event == "sorted")
    assert [b - a for a, b in zip(ends, ends[1:])] == pytest.approx([PROC_TWO.cycle_s] * (n - 1))
    assert PROC_TWO.cycle_s == pytest.approx(2 + 12 + 15 + 300 + 25 + 120 + 14)
    # both cuts keep the machine busy; the flip keeps the robot busy
    assert s["machine_utilisation"] == pytest.approx(round(n * 420.0 / s["makespan_s"], 4), abs=1e-4)
    assert s["parts_per_hour"] < simulate(_orders(n), {A: PROC_A}).summary["parts_per_hour"]


def test_one_setup_has_no_flip_and_no_op_labels():
    result = simulate(_orders(3), {A: PROC_A})
    assert all(a.action != "flip" and a.op is None for a in result.activities)
    assert all(e.state != "FLIP" for e in result.log)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), alarm=st.floats(0, 0.6), quantities=st.lists(st.integers(1, 3), min_size=1,
                                                                                   max_size=4))
def test_two_setups_with_alarms_lose_nothing(seed, alarm, quantities):
    orders = [Order(f"o{i}", A, q, "aluminium", 0) for i, q in enumerate(quantities)]
    result = simulate(orders, {A: PROC_TWO}, FaultModel(machine_alarm=alarm, grasp_miss=0.1, seed=seed))
    _check_invariants(result)
    for job in set(result.jobs):
        ops = [a.op for a in result.activities if a.job == job and a.action == "cut"]
        assert ops == sorted(ops) and set(ops) <= {1, 2}
        flips = [a for a in result.activities if a.job == job and a.action == "flip"]
        assert len(flips) <= 1
        if flips:  # op 2 is cut only after the flip, op 1 only before
            assert all(a.start >= flips[0].end - 1e-9 for a in result.activities
                       if a.job == job and a.action == "cut" and a.op == 2)
            assert all(a.end <= flips[0].start + 1e-9 for a in result.activities
                       if a.job == job and a.action == "cut" and a.op == 1)
