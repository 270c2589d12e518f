"""The cell state machine, state by state: every table entry, every illegal event, retries and timeouts."""

from dataclasses import replace
from pathlib import Path

import pytest

from factory.core.errors import SchedulerError
from robotprog.orders import Order
from robotprog.scheduler import (TRANSITIONS, CellState, Event, Fault, Job, SchedulerOptions, State, admit,
                                 initial_state, plan_recovery, step)

OPTS = SchedulerOptions()
ORDER = Order("o1", Path("a.stl"), 2, "steel", 0)


def _cell(job: Job, orders=(ORDER,)) -> CellState:
    return replace(initial_state(orders), queue=(), jobs=(job,), next_job=job.id + 1, next_slot=job.slot + 1)


def _job(state: State, **kw) -> Job:
    if state in (State.FAULT, State.RECOVER):
        kw.setdefault("fault", Fault.GRASP_MISSED)
        kw.setdefault("fault_state", State.FETCH_RAW)
    return Job(id=1, order="o1", state=state, **kw)


@pytest.mark.parametrize("key", sorted(TRANSITIONS, key=lambda k: (k[0].value, k[1].value)),
                         ids=lambda k: f"{k[0].name}-{k[1].name}")
def test_every_table_entry(key):
    state, event = key
    nxt, action = TRANSITIONS[key]
    cell, effects = step(_cell(_job(state)), 1, event, OPTS)
    assert effects[0].action == action and effects[0].job == 1
    if action in ("fail_part", "finish_part"):
        assert not cell.jobs and cell.finished[-1].id == 1 and cell.finished[-1].state is State.IDLE
    else:
        assert cell.job(1).state is nxt
    if nxt is State.FAULT:
        assert sum(cell.faults.values()) == 1 and cell.job(1).fault_state is state
    if action == "recover":
        assert effects[0].event is not None and (state, effects[0].event) != key
        assert (State.RECOVER, effects[0].event) in TRANSITIONS
        assert cell.recoveries + cell.failures == 1


@pytest.mark.parametrize("state", list(State))
def test_illegal_events_rejected(state):
    cell = _cell(_job(state))
    for event in Event:
        if (state, event) not in TRANSITIONS:
            with pytest.raises(SchedulerError, match=state.name):
                step(cell, 1, event, OPTS)
    assert cell.job(1).state is state  # frozen: nothing changed


def test_every_non_idle_working_state_has_a_timeout_and_a_way_out():
    for state in (State.FETCH_RAW, State.LOAD, State.MACHINING, State.UNLOAD, State.INSPECT, State.SORT):
        assert (state, Event.TIMEOUT) in TRANSITIONS and OPTS.timeout(state) < float("inf")
    assert OPTS.timeout(State.IDLE) == float("inf")


def _fault_and_recover(cell, event):
    cell, _ = step(cell, 1, event, OPTS)
    cell, effects = step(cell, 1, Event.RECOVER, OPTS)
    return cell, effects[0].event


def test_grasp_retries_then_order_fails():
    cell = _cell(_job(State.FETCH_RAW))
    for attempt in range(OPTS.grasp_retries):
        cell, chosen = _fault_and_recover(cell, Event.GRASP_MISSED)
        assert chosen is Event.RETRY_FETCH and cell.job(1).slot == 0
        cell, _ = step(cell, 1, chosen, OPTS)
        assert cell.job(1).state is State.FETCH_RAW
    cell, chosen = _fault_and_recover(cell, Event.GRASP_MISSED)
    assert chosen is Event.ABANDON
    cell, _ = step(cell, 1, chosen, OPTS)
    p = cell.progress("o1")
    assert p.outcome == "failed" and "grasp missed 3 times" in p.reason and "operator" in p.reason
    assert cell.faults["grasp_missed"] == 3 and cell.recoveries == 2 and cell.failures == 1


def test_stock_not_found_reimages_then_skips_slot_then_fails():
    cell = _cell(_job(State.FETCH_RAW))
    cell, chosen = _fault_and_recover(cell, Event.STOCK_NOT_FOUND)
    assert chosen is Event.RETRY_FETCH and cell.job(1).slot == 0  # re-image the same slot
    cell, _ = step(cell, 1, chosen, OPTS)
    cell, chosen = _fault_and_recover(cell, Event.STOCK_NOT_FOUND)
    assert chosen is Event.RETRY_FETCH and cell.job(1).slot == 1 and cell.next_slot == 2  # next slot
    cell, _ = step(cell, 1, chosen, OPTS)
    cell, chosen = _fault_and_recover(cell, Event.STOCK_NOT_FOUND)  # re-image the new slot
    assert chosen is Event.RETRY_FETCH and cell.job(1).slot == 1
    cell, _ = step(cell, 1, chosen, OPTS)
    cell, chosen = _fault_and_recover(cell, Event.STOCK_NOT_FOUND)
    assert chosen is Event.ABANDON
    cell, _ = step(cell, 1, chosen, OPTS)
    assert cell.progress("o1").outcome == "failed" and "no stock" in cell.progress("o1").reason


def test_machine_alarm_reruns_once_then_scraps_and_remakes():
    cell = _cell(_job(State.MACHINING))
    cell, chosen = _fault_and_recover(cell, Event.MACHINE_ALARM)
    assert chosen is Event.RERUN
    cell, effects = step(cell, 1, chosen, OPTS)
    assert effects[0].action == "reset_and_rerun" and cell.job(1).state is State.MACHINING
    cell, chosen = _fault_and_recover(cell, Event.MACHINE_ALARM)
    assert chosen is Event.SCRAP and cell.job(1).scrap
    cell, _ = step(cell, 1, chosen, OPTS)
    assert cell.job(1).state is State.UNLOAD
    cell, effects = step(cell, 1, Event.UNLOADED_SCRAP, OPTS)
    assert effects[0].action == "in_bin"  # the reject branch took it from the vise to the bin
    cell, _ = step(cell, 1, Event.SORTED, OPTS)
    p = cell.progress("o1")
    assert p.rejected == 1 and p.remakes == 1 and p.outcome is None and cell.queue == ("o1",)
    assert cell.recoveries == 1 and cell.failures == 1 and cell.faults["machine_alarm"] == 2


def test_timeout_in_machining_is_an_alarm_and_in_unload_abandons():
    cell, chosen = _fault_and_recover(_cell(_job(State.MACHINING)), Event.TIMEOUT)
    assert chosen is Event.RERUN
    for state in (State.LOAD, State.UNLOAD, State.INSPECT, State.SORT):
        cell, chosen = _fault_and_recover(_cell(_job(state)), Event.TIMEOUT)
        assert chosen is Event.ABANDON and state.name in cell.job(1).reason
    cell, chosen = _fault_and_recover(_cell(_job(State.FETCH_RAW)), Event.TIMEOUT)
    assert chosen is Event.RETRY_FETCH


def _run_inspection(cell, job_id, passed):
    """A good part: unloaded to the out-tray, inspected there; a failed one: the verdict read on
    unloading sends it from the vise to the reject bin, as the posted program's branch does."""
    events = ((Event.UNLOADED, Event.INSPECT_PASS) if passed else (Event.INSPECT_FAIL,))
    for event in (Event.START, Event.FETCHED, Event.LOADED, Event.CYCLE_DONE, *events, Event.SORTED):
        cell, effects = step(cell, job_id, event, OPTS)
        if event is Event.INSPECT_FAIL:
            assert effects[0].action == "in_bin" and cell.job(job_id).state is State.SORT
    return cell


def test_a_part_in_the_out_tray_is_not_sorted_again():
    """No way from the out-tray to the bin: the program has none (the verdict comes before the tray)."""
    with pytest.raises(SchedulerError, match="inspect_fail is not accepted in state INSPECT"):
        step(_cell(_job(State.INSPECT)), 1, Event.INSPECT_FAIL, OPTS)


def test_happy_path_and_remake_limit():
    opts_remakes = OPTS.remakes
    cell = initial_state([ORDER])
    assert cell.queue == ("o1", "o1")
    cell, j = admit(cell)
    cell = _run_inspection(cell, j, True)
    assert cell.progress("o1").good == 1 and cell.progress("o1").outcome is None
    for _ in range(opts_remakes + 1):
        cell, j = admit(cell)
        cell = _run_inspection(cell, j, False)
    p = cell.progress("o1")
    assert p.outcome == "rejected" and "re-make limit" in p.reason and not cell.queue
    assert cell.faults["inspect_fail"] == cell.recoveries + cell.failures == opts_remakes + 1
    assert cell.all_ended


def test_done_after_quantity_and_priority_order():
    orders = [Order("o1", Path("a.stl"), 1, "steel", 2), Order("o2", Path("b.stl"), 1, "steel", 0),
              Order("o3", Path("c.stl"), 1, "steel", 2)]
    cell = initial_state(orders, failed={"o3": "b.stl: no plan"})
    assert cell.queue == ("o2", "o1") and cell.progress("o3").outcome == "failed"
    while cell.queue:
        cell, j = admit(cell)
        cell = _run_inspection(cell, j, True)
    assert all(p.outcome for p in cell.orders) and cell.progress("o1").outcome == "done"


def test_failed_order_drops_its_queue_but_others_run():
    orders = [Order("o1", Path("a.stl"), 3, "steel", 0), Order("o2", Path("b.stl"), 1, "steel", 1)]
    cell, j = admit(initial_state(orders))
    cell, _ = step(cell, j, Event.START, OPTS)
    cell, _ = step(cell, j, Event.TIMEOUT, OPTS)
    cell = replace(cell, jobs=(replace(cell.job(j), fault_state=State.LOAD),))
    cell, effects = step(cell, j, Event.RECOVER, OPTS)
    cell, _ = step(cell, j, effects[0].event, OPTS)
    assert cell.progress("o1").outcome == "failed" and cell.queue == ("o2",)


def test_options_validation_and_admit_empty():
    with pytest.raises(SchedulerError):
        SchedulerOptions(grasp_retries=-1)
    with pytest.raises(SchedulerError):
        SchedulerOptions(timeouts={State.LOAD: 0.0})
    with pytest.raises(SchedulerError):
        admit(replace(initial_state([ORDER]), queue=()))
    with pytest.raises(SchedulerError):
        step(initial_state([ORDER]), 7, Event.START, OPTS)


def test_plan_recovery_is_pure():
    job = _job(State.FAULT, fault=Fault.MACHINE_ALARM, fault_state=State.MACHINING)
    assert plan_recovery(job, OPTS) == plan_recovery(job, OPTS) and job.reruns == 0
