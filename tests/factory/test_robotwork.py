"""factory.robotwork: the robot's share of a plan in a second process, and the progress it relays."""

from __future__ import annotations

import dataclasses
import multiprocessing

import numpy as np
import pytest

from factory.core.progress import ProgressRelay, Stopwatch
from factory.core.resources import FIXTURES
from factory.core.setupsheet import SetupSheet
from factory.robotwork import BackgroundRobot, RobotTask, robot_work, same_stock

needs_fork = pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(), reason="no fork here")


def _sheet(sx: float, sy: float, sz: float) -> SetupSheet:
    """A stock box (mm, top-front-left origin) with the part's mesh placed at the work origin."""
    return SetupSheet(stock_min=np.array([0.0, 0.0, -sz]), stock_max=np.array([sx, sy, 0.0]),
                      transform_mesh_to_work=np.eye(4), tools=())


def _task(sheet: SetupSheet, tmp_path) -> RobotTask:
    return RobotTask(FIXTURES / "cell.yaml", sheet, "part.setup.json", None, 1, False, "urscript",
                     tmp_path / "part.script")


@needs_fork
def test_a_forked_childs_reports_show_here_in_order_before_close_returns():
    heard = []
    relay = ProgressRelay(lambda *report: heard.append(report))
    relay("here", 0, 1)  # in this process: at once
    assert heard == [("here", 0, 1)]
    child = multiprocessing.get_context("fork").Process(
        target=lambda: [relay(f"stage {k}", k, 50) for k in range(50)])
    child.start()
    child.join()
    relay.close()
    assert heard[1:] == [(f"stage {k}", k, 50) for k in range(50)]
    assert ProgressRelay(None)("nobody", 0, 1) is None  # no callback: nothing reported, no thread


def test_a_relay_whose_callback_fails_raises_on_close_after_draining():
    def fails(stage, done, total):
        raise ValueError(stage)

    relay = ProgressRelay(fails)
    with pytest.raises(ValueError, match="direct"):
        relay("direct", 0, 1)  # in this process the callback's error is the caller's
    relay.close()


def test_the_stock_the_robot_reads_is_compared_field_by_field():
    a = _sheet(104, 64, 22.5)
    assert same_stock(a, dataclasses.replace(a, part="bracket", program="bracket.nc", estimated_cycle_s=60.0))
    assert not same_stock(a, _sheet(104, 64, 16))
    assert not same_stock(a, dataclasses.replace(a, mesh_scale=25.4))
    moved = np.eye(4)
    moved[0, 3] = 1.0
    assert not same_stock(a, dataclasses.replace(a, transform_mesh_to_work=moved))


def test_the_work_in_the_background_is_the_work_done_here_and_follows_the_posted_stock(tmp_path):
    """Taken for the stock it started with, the background's work is the serial answer, its stages
    heard from the other process and timed; taken for another stock (a stage changed the setup), it
    is planned again for that one."""
    heard = []
    watch = Stopwatch(lambda *report: heard.append(report))
    started = _task(_sheet(104, 64, 22.5), tmp_path)
    robot = BackgroundRobot(started, watch)
    work = robot.result(started.sheet)
    here = robot_work(robot.cell, robot.world, started)
    assert work.program.texts == here.program.texts and work.plan.durations == here.plan.durations
    assert work.dropped_op2 is None and len(work.visuals) == len(here.visuals) > 0  # read there, after the work
    assert all(np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
               for a, b in zip(work.visuals, here.visuals))
    for stage in ("cell", "robot plan", "robot program", "robot visuals"):
        assert (stage, 0, 1) in heard and (stage, 1, 1) in heard and watch.seconds[stage] > 0

    taller = _sheet(104, 64, 30.0)
    robot = BackgroundRobot(started, Stopwatch())
    again = robot.result(taller)
    np.testing.assert_allclose(again.plan.stock.size, [0.104, 0.064, 0.030])
    robot.cancel()  # taken: nothing left to end
