"""Door and gripper key values read off the robot's activities (factory.diagnostics)."""

from __future__ import annotations

import pytest

from factory.diagnostics import door, gripper
from robotprog.cellsim import Activity


def robot(action: str, outcome: str, start: float = 10.0, end: float = 20.0) -> Activity:
    return Activity("robot", action, 1, start, end, outcome)


@pytest.mark.parametrize("action", ["load", "unload", "unload_reject", "flip"])
def test_the_door_is_open_while_the_robot_reaches_into_the_machine(action):
    a = robot(action, "loaded" if action == "load" else "unloaded")
    assert [door(a, t) for t in (9.0, 10.0, 19.9, 20.0)] == ["closed", "open", "open", "closed"]


@pytest.mark.parametrize("action", ["fetch", "missed_grasp"])
def test_the_door_stays_closed_for_work_outside_the_machine(action):
    assert door(robot(action, "fetched"), 15.0) == "closed"
    assert door(None, 0.0) == "closed"


def test_the_gripper_holds_the_blank_from_the_fetch_to_the_end_of_the_load():
    fetch = robot("fetch", "fetched")
    assert gripper(fetch, 15.0) == {"gripper": "open", "gripper_holds": ""}  # it grips at the end
    assert gripper(fetch, 25.0) == {"gripper": "closed", "gripper_holds": "blank"}  # waiting to load
    load = robot("load", "loaded", 30.0, 40.0)
    assert gripper(load, 35.0)["gripper_holds"] == "blank"
    assert gripper(load, 40.0) == {"gripper": "open", "gripper_holds": ""}  # let go in the vise


def test_a_missed_grasp_or_a_timed_out_fetch_leaves_the_gripper_open():
    assert gripper(robot("missed_grasp", "grasp_missed"), 25.0)["gripper"] == "open"
    assert gripper(robot("fetch", "timeout"), 25.0)["gripper"] == "open"


def test_the_gripper_holds_the_part_out_and_the_reject_to_the_bin():
    assert gripper(robot("unload", "unloaded"), 15.0) == {"gripper": "closed", "gripper_holds": "part"}
    assert gripper(robot("unload_reject", "inspect_fail"), 15.0) == {"gripper": "closed", "gripper_holds": "reject"}
    assert gripper(robot("unload", "unloaded"), 20.0)["gripper"] == "open"


def test_the_part_is_held_through_the_flip_between_op_1_and_op_2():
    assert gripper(robot("flip", "flipped"), 15.0) == {"gripper": "closed", "gripper_holds": "part"}
    assert gripper(robot("flip", "flipped"), 20.0)["gripper"] == "open"  # let go in the vise for op 2
