"""One machine handshake for programs and simulation: the I/O operations every posted program runs
(URScript, RAPID, KRL, read back from their text) are the simulation's signal sequence per part."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from factory.core.errors import PlanningError
from factory.cellcameras import Shot
from factory.simulation import RobotMotion, part_process
from robotprog.cellsim import Activity, FaultModel, PartProcess, simulate
from robotprog.krl import krl_program
from robotprog.machineio import (CYCLE_START_OPS, INPUT, OUTPUT, READ, SET, SIGNALS, WAIT, IoOp, machine_cycle,
                                 part_signals, posted_signals, signal_timeline, to_steps)
from robotprog.orders import Order
from robotprog.programs import VERDICT_AFTER, post_program, program_steps
from robotprog.scheduler import SchedulerOptions
from robotprog.rapid import rapid_module
from robotprog.urscript import Branch, urscript_program
from tests.robotprog.test_tending import SAMPLE_STOCK, sheet

PROC = PartProcess(fetch_s=12.0, load_s=15.0, machining_s=300.0, unload_s=14.0, locate_s=2.0, inspect_s=2.5,
                   reject_s=5.0, regrasp_s=3.0)


def keys(ops):
    return [o.key for o in ops]


@pytest.fixture(scope="module")
def bracket_plan(tending):
    return tending("cell.yaml", sheet(*SAMPLE_STOCK["bracket"]))


@pytest.fixture(scope="module")
def bracket_steps(cell, world, bracket_plan):
    return {lang: program_steps(cell, world, bracket_plan, lang) for lang in ("urscript", "rapid")}


def test_signals_have_one_direction_each_and_the_handshake_uses_them_so():
    for o in part_signals(cycles=2):
        sig = SIGNALS[o.signal]
        assert sig.direction == (OUTPUT if o.op == SET else INPUT)
    # every signal the cell file wires is in the model, and every input the handshake waits on is read somewhere
    assert {o.signal for o in part_signals()} == set(SIGNALS)
    with pytest.raises(PlanningError):
        part_signals(cycles=0)


def test_posted_program_runs_the_part_handshake(cell, bracket_steps):
    for lang, steps in bracket_steps.items():
        assert keys(posted_signals(steps, cell.machine)) == keys(part_signals())
        # the reject way runs the same handshake, reading the verdict low
        rejected = posted_signals(steps, cell.machine, verdict_level=False)
        assert keys(rejected) == keys(part_signals())[:-1] + [(READ, "part_ok", False)]
        assert sum(isinstance(s, Branch) for s in steps) == 1, lang


def _io_lines(lang: str, text: str) -> list[tuple[str, int, bool]]:
    """(set | wait | read, number from 0, level) of every I/O line of a program text, in order."""
    pats = {"urscript": [(r"set_standard_digital_out\((\d+), (True|False)\)", SET, 0),
                         (r"while get_standard_digital_in\((\d+)\) != (True|False)", WAIT, 0),
                         (r"if get_standard_digital_in\((\d+)\) == (True|False)", READ, 0)],
            "rapid": [(r"SetDO do(\d+), ([01]);", SET, 0), (r"WaitDI di(\d+), ([01]);", WAIT, 0),
                      (r"IF DInput\(di(\d+)\) = ([01]) THEN", READ, 0)],
            "krl": [(r"\$OUT\[(\d+)\] = (TRUE|FALSE)", SET, 1), (r"WAIT FOR (NOT )?\$IN\[(\d+)\]", WAIT, 1),
                    (r"IF (NOT )?\$IN\[(\d+)\] THEN", READ, 1)]}[lang]
    out = []
    for line in text.splitlines():
        for pat, op, base in pats:
            m = re.search(pat, line)
            if not m:
                continue
            if lang == "krl" and op != SET:
                out.append((op, int(m.group(2)) - base, m.group(1) is None))
            else:
                out.append((op, int(m.group(1)) - base, m.group(2) in ("True", "1", "TRUE")))
    return out


def test_program_texts_state_the_handshake(cell, bracket_steps):
    """What each language writes is the model's operations with the cell's numbers (gripper outputs
    aside), so the controller runs the sequence the simulation logs."""
    grip = {n for n, _ in cell.gripper.io.grip + cell.gripper.io.release}
    want = [(o.op, getattr(cell.machine, o.signal), o.level) for o in part_signals()]
    texts = {"urscript": urscript_program(bracket_steps["urscript"]),
             "rapid": rapid_module(bracket_steps["rapid"]),
             "krl": krl_program(bracket_steps["rapid"], axis_speed=[6.0] * 6)[0]}
    for lang, text in texts.items():
        got = [x for x in _io_lines(lang, text) if not (x[0] == SET and x[1] in grip)]
        assert got == want, lang


def test_simulation_logs_the_programs_handshake_per_part(cell, bracket_steps):
    orders = [Order(f"o{i}", Path("a.stl"), 2, "aluminium", 0) for i in range(3)]
    result = simulate(orders, {Path("a.stl"): PROC})
    posted = keys(posted_signals(bracket_steps["urscript"], cell.machine))
    jobs = sorted({e.job for e in result.signals})
    assert len(jobs) == 6
    for job in jobs:
        assert keys(e.op for e in result.signals if e.job == job) == posted
    # in time: the door shuts when the cut starts and opens when it ends; the verdict comes at the unload
    cuts = {a.job: a for a in result.activities if a.action == "cut"}
    for e in result.signals:
        if e.op.key == (SET, "cycle_start", True):
            assert e.time == cuts[e.job].start
        if e.op.key == (WAIT, "cycle_done", True) and e.time > cuts[e.job].start:
            assert e.time == cuts[e.job].end
    times = [e.time for e in result.signals]
    assert times == sorted(times)


def test_scrapped_part_reads_the_verdict_low_like_the_reject_way(cell, bracket_steps):
    """A part the simulation scraps (alarms past the reruns) is unloaded reading the verdict low: the
    program's reject way. Up to the alarm the handshake is the program's; the alarm leaves the robot
    waiting for the cycle done (the machine's reset is the operator's)."""
    faults = FaultModel(machine_alarm=1.0, seed=3)
    result = simulate([Order("o1", Path("a.stl"), 1, "aluminium", 0)], {Path("a.stl"): PROC}, faults=faults)
    rejected = keys(posted_signals(bracket_steps["urscript"], cell.machine, verdict_level=False))
    assert rejected[-1] == (READ, "part_ok", False)
    start = len(keys(part_signals())) - len(machine_cycle()) - 1 + CYCLE_START_OPS  # ready + the cycle started
    jobs = sorted({e.job for e in result.signals})
    assert jobs
    for job in jobs:
        ops = keys(e.op for e in result.signals if e.job == job)
        assert ops[:start] == rejected[:start]
        assert ops[-1] == rejected[-1]


def test_a_rejected_part_takes_the_programs_reject_branch(cell, world, bracket_plan):
    """A part the machine's verdict fails goes from the vise straight to the reject bin in the
    simulation, as the posted program's branch takes it: the same handshake (the verdict read low
    as the unload starts), the same robot way (no out-tray, no camera), and the same planned time
    (the step durations read from the plan as ``factory simulate`` reads them)."""
    plan = bracket_plan
    posted = post_program("urscript", Path("part.script"), cell, world, plan)
    t, moves = 0.0, []
    for m in plan.moves:
        moves.append((m.name, t, t + m.duration))
        t += m.duration
    motion = RobotMotion(tuple(moves), np.array([0.0, t]), np.zeros((2, world.robot.dof)))
    shots = {n: Shot(b"", [], 0.5, True) for n in ("locate", "inspect")}
    proc = part_process(motion, 300.0, shots, None, [m.duration for m in plan.reject])
    result = simulate([Order("o1", Path("a.stl"), 1, "aluminium", 0)], {Path("a.stl"): proc},
                      faults=FaultModel(inspect_fail=1.0, seed=1), options=SchedulerOptions(remakes=0))
    assert result.summary["parts_rejected"] == 1 and result.summary["parts_good"] == 0
    robot = [a for a in result.activities if a.resource == "robot"]
    assert [a.action for a in robot] == ["fetch", "load", "unload_reject"]
    assert robot[-1].outcome == "inspect_fail"
    assert not [a for a in result.activities if a.action == "inspect"]  # it never reaches the out-tray
    # the robot's time for the rejected part is the program's planned reject way, move for move
    names = [m.name for m in plan.moves]
    to_verdict = plan.moves[names.index("unload: home to above vise"):names.index(VERDICT_AFTER) + 1]
    assert robot[-1].end - robot[-1].start == pytest.approx(
        sum(m.duration for m in to_verdict + plan.reject), abs=1e-9)
    assert sum(a.end - a.start for a in robot) == pytest.approx(posted.planned_reject_s, abs=1e-9)
    assert 0.95 <= posted.predicted_reject_s / posted.planned_reject_s <= 1.05
    # the handshake: the program's reject way, the verdict read low as the reject way starts
    want = keys(posted_signals(program_steps(cell, world, plan, "urscript"), cell.machine, verdict_level=False))
    assert keys(e.op for e in result.signals) == want
    read = next(e for e in result.signals if e.op.op == READ)
    assert read.time == robot[-1].start
    # the part leaves the machine with the robot: the next blank may go in once the reject way ends
    assert result.machine_intervals[-1][1] == robot[-1].end


def test_two_machine_cycles_per_part():
    """A part flipped between op 1 and op 2 runs the cycle twice before its verdict."""
    acts = [Activity("robot", "load", 1, 0.0, 10.0, "loaded"),
            Activity("machine", "cut", 1, 10.0, 100.0, "op_done"),  # op 1; the flip follows
            Activity("robot", "flip", 1, 100.0, 120.0, "flipped"),
            Activity("machine", "cut", 1, 120.0, 200.0, "cycle_done"),
            Activity("robot", "unload", 1, 200.0, 215.0, "unloaded")]
    events = signal_timeline(acts)
    assert keys(e.op for e in events) == keys(part_signals(cycles=2))
    assert [e.time for e in events if e.op.key == (SET, "cycle_start", True)] == [10.0, 120.0]
    assert CYCLE_START_OPS == 1 + next(i for i, o in enumerate(machine_cycle()) if o.key == (WAIT, "cycle_done", False))


def test_to_steps_groups_outputs_and_refuses_a_branch_as_a_step(cell):
    steps = to_steps(machine_cycle(), cell.machine)
    assert len(steps) == 8  # 4 output groups (door, start, stop, door) and 4 waits
    with pytest.raises(PlanningError):
        to_steps([IoOp(READ, "part_ok", True)], cell.machine)
