"""The controller-semantics timer: stops, blended chains, timed moves, servoj, movel, waits."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from factory.core.errors import PlanningError
from robotprog.controller import program_duration, trapezoid_time
from robotprog.urscript import Branch, Comment, MoveJ, MoveL, ServoJ, SetOutputs, Wait, WaitInput

Q0 = np.zeros(6)


def _q(lead: float) -> tuple[float, ...]:
    return (lead, lead / 2, 0.0, 0.0, 0.0, 0.0)


def test_trapezoid_and_triangle():
    assert trapezoid_time(2.0, 1.0, 2.0) == pytest.approx(2.0 / 1.0 + 1.0 / 2.0)
    # too short to reach v: a triangle, 2 sqrt(d / a)
    assert trapezoid_time(0.1, 1.0, 2.0) == pytest.approx(2 * math.sqrt(0.05))
    assert trapezoid_time(0.0, 1.0, 2.0) == 0.0
    with pytest.raises(PlanningError):
        trapezoid_time(1.0, 0.0, 1.0)


@settings(max_examples=50, deadline=None)
@given(st.floats(1e-3, 5.0), st.floats(0.1, 3.0), st.floats(0.1, 5.0))
def test_trapezoid_is_continuous_and_no_faster_than_cruise(d, v, a):
    t = trapezoid_time(d, v, a)
    assert t >= d / v - 1e-12 and t >= 2 * math.sqrt(d / a) - 1e-12
    assert trapezoid_time(v * v / a * (1 + 1e-12), v, a) == pytest.approx(trapezoid_time(v * v / a, v, a))


def test_unblended_moves_stop_blended_chain_accelerates_once():
    stops = [MoveJ(_q(1.0), 2.0, 1.0), MoveJ(_q(2.0), 2.0, 1.0), MoveJ(_q(3.0), 2.0, 1.0)]
    blended = [MoveJ(_q(1.0), 2.0, 1.0, r=0.05), MoveJ(_q(2.0), 2.0, 1.0, r=0.05), MoveJ(_q(3.0), 2.0, 1.0)]
    assert program_duration(stops, Q0) == pytest.approx(3 * (1.0 + 0.5))
    assert program_duration(blended, Q0) == pytest.approx(3.0 + 0.5)


def test_timed_moves_take_their_time_krl_runs_its_percentages():
    steps = [MoveJ(_q(0.1), 2.0, 1.0, r=0.01, t=0.25), MoveJ(_q(0.2), 2.0, 1.0, t=0.25)]
    assert program_duration(steps, Q0, lang="rapid") == pytest.approx(0.5)
    speed = np.full(6, 2.0)
    # 0.1 rad in 0.25 s is 20 % of 2 rad/s: each segment 0.25 s, plus a ramp of 0.4 / (2 * 2) at each end
    assert program_duration(steps, Q0, lang="krl", axis_speed=speed) == pytest.approx(0.5 + 2 * 0.1)
    with pytest.raises(PlanningError, match="axis speeds"):
        program_duration(steps, Q0, lang="krl")
    with pytest.raises(PlanningError, match="no controller model"):
        program_duration(steps, Q0, lang="cobol")


def test_servoj_counts_its_t_outputs_and_waits_count():
    targets = np.linspace(0.0, 0.5, 40)[:, None] * np.ones(6)
    steps = [Comment("x"), ServoJ(targets, 0.008), SetOutputs(((0, True),), 0.4), Wait(1.5), WaitInput(1, True)]
    # waiting on the machine's input is the machine's time, not the robot's
    assert program_duration(steps, Q0) == pytest.approx(40 * 0.008 + 0.4 + 1.5)


def test_movel_is_a_trapezoid_on_the_tcp_path():
    def tcp_of(q):
        t = np.eye(4)
        t[:3, 3] = [0.4, 0.0, 0.3]
        return t

    pose = np.eye(4)
    pose[:3, 3] = [0.4, 0.0, 0.1]
    steps = [MoveL.to(pose, 0.5, 0.1)]
    assert program_duration(steps, Q0, tcp_of=tcp_of) == pytest.approx(0.2 / 0.1 + 0.1 / 0.5)
    with pytest.raises(PlanningError, match="tcp_of"):
        program_duration(steps, Q0)
    with pytest.raises(PlanningError, match="unknown position"):
        program_duration(steps + [MoveJ(_q(1.0), 1.0, 1.0)], Q0, tcp_of=tcp_of)


def test_a_branch_runs_the_way_its_input_reads():
    """The verdict picks the way: the out-tray way's time or the reject way's, never both; each
    way starts where the arm stands at the branch."""
    q0 = np.zeros(6)
    tray = (MoveJ((0.5,) * 6, 1.0, 1.0, 0.0, 2.0), Wait(0.5))
    reject = (MoveJ((-0.5,) * 6, 1.0, 1.0, 0.0, 3.0), SetOutputs(((0, True),), 0.25))
    steps = [Wait(1.0), Branch(2, True, tray, reject, "verdict"), MoveJ((0.0,) * 6, 1.0, 1.0, 0.0, 1.0)]
    assert program_duration(steps, q0) == pytest.approx(1.0 + 2.5 + 1.0)
    assert program_duration(steps, q0, verdict=False) == pytest.approx(1.0 + 3.25 + 1.0)
    # a branch taken on a low input runs its `then` way when the input reads low
    low = [Branch(2, False, reject, tray)]
    assert program_duration(low, q0, verdict=False) == pytest.approx(3.25)
    # the untimed joint move after the branch starts from the way's end
    after = [Branch(2, True, tray, reject), MoveJ((0.5,) * 6, 1.0, 1.0)]
    assert program_duration(after, q0) == pytest.approx(2.5)
    assert program_duration(after, q0, verdict=False) == pytest.approx(3.25 + trapezoid_time(1.0, 1.0, 1.0))
