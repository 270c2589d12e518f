"""Collision world of the default cell: home free, arm into the table/enclosure collides."""

from __future__ import annotations


import numpy as np
import pytest

from factory.core.errors import PlanningError
from robotprog.collision import HeldBox, cell_static_boxes




def test_home_is_free(world, cell):
    home = np.array(cell.robot.home)
    assert not world.in_collision(home)
    assert world.first_contact(home) is None
    assert world.path_free(np.array([home, home])) is None


def test_static_boxes_named(cell):
    names = {b.name for b in cell_static_boxes(cell)}
    assert {"mill_table", "vise_body", "rack_stand", "out_tray_stand", "pedestal", "front_lower"} <= names
    assert "door" not in {b.name for b in cell_static_boxes(cell)}
    assert cell.enclosure.door.name in {b.name for b in cell_static_boxes(cell, door_closed=True)}


def test_arm_driven_into_table_collides_and_names_bodies(world, cell):
    q = np.array(cell.robot.home)
    q[1] = -0.6  # shoulder lowered towards the mill
    assert world.in_collision(q)
    contact = world.first_contact(q)
    assert contact is not None and "mill_table" in contact and "_link" in contact


def test_arm_into_enclosure_front(world, cell):
    q = np.array(cell.robot.home)
    q[1] = 0.3
    contact = world.first_contact(q)
    assert contact is not None and "front_lower" in contact


def test_path_free_reports_first_colliding_index(world, cell):
    home = np.array(cell.robot.home)
    bad = home.copy()
    bad[1] = -0.6
    qs = np.array([home, home, bad, home, bad])
    assert world.path_free(qs) == 2


def test_held_box_collides_when_driven_through_table(world, cell):
    home = np.array(cell.robot.home)
    held = HeldBox.at((0.1, 0.06, 0.02), np.eye(4))
    assert not world.in_collision(home, held)
    # A long bar reaching down from the TCP to the floor hits the pedestal or a stand.
    bar = np.eye(4)
    bar[2, 3] = 0.5
    contact = world.first_contact(home, HeldBox.at((0.02, 0.02, 1.0), bar))
    assert contact is not None and contact.startswith("held <-> ")
    assert world.in_collision(home, HeldBox.at((0.02, 0.02, 1.0), bar))


def test_self_collision_detected(world, cell):
    q = np.array(cell.robot.home)
    q[2] = 3.0  # elbow folded back onto the upper arm
    q[0] = 1.5
    assert world.in_collision(q)


def test_bad_configuration_raises(world):
    with pytest.raises(PlanningError):
        world.in_collision(np.zeros(3))


def test_held_box_against_arm_links(world, cell):
    home = np.array(cell.robot.home)
    robot = world.robot
    # A small box around the elbow (forearm link origin), expressed in the TCP frame.
    t_base_tcp = robot.fk(home) @ cell.gripper.tcp.matrix()
    t_base_elbow = robot.frame_transform(home, robot.base_frame, "forearm_link")
    held = HeldBox.at((0.05, 0.05, 0.05), np.linalg.inv(t_base_tcp) @ t_base_elbow)
    contact = world.first_contact(home, held)
    assert contact is not None and contact.startswith("held <-> ") and "link" in contact
