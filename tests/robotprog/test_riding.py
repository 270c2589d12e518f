"""The riding geometry and the broad phase of the collision world (robotprog.collision): a box on
the TCP is paired with everything it can hit, and the broad phase's bound never exceeds a distance."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from hypothesis import given, settings
from hypothesis import strategies as st

from robotprog.collision import HeldBox, finger_boxes, pair_name


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-2.5, 2.5), min_size=6, max_size=6), st.floats(0.0, 0.1))
def test_the_broad_phase_never_keeps_apart_a_pair_closer_than_its_bound(world, cell, offsets, opening):
    """The broad phase skips a pair whose bound says it is farther apart than its margin, so the
    bound must never exceed coal's distance: every pair of the cell and of the fingers and a held box
    riding on the TCP, at a configuration anywhere round home (a pair in contact may go either way)."""
    q = np.asarray(cell.robot.home) + np.array(offsets)
    rider = world.riding(finger_boxes(cell, opening) + (HeldBox.at((0.1, 0.06, 0.02), np.eye(4)),))
    world.first_contact(q, rider.boxes)  # places the arm and the riding geometry at q
    lower = rider.bounds.lower(world._data)
    for k in range(len(rider.geometry.collisionPairs)):
        pin.computeDistance(rider.geometry, rider.data, k)
        distance = rider.data.distanceResults[k].min_distance
        if distance > 0:
            assert lower[k] <= distance + 1e-9, pair_name(rider.geometry, k)


def test_a_held_box_is_checked_against_every_static_box_and_arm_link(world, cell):
    """The riding geometry pairs each box on the TCP with each static box and each arm link not on
    the flange's joint, after the world's own pairs, which keep their indices."""
    held = finger_boxes(cell, 0.05) + (HeldBox.at((0.1, 0.06, 0.02), np.eye(4)),)
    rider = world.riding(held)
    n = len(world.geometry.collisionPairs)
    assert [(p.first, p.second) for p in rider.geometry.collisionPairs][:n] == [
        (p.first, p.second) for p in world.geometry.collisionPairs]
    names = [pair_name(rider.geometry, k) for k in range(n, len(rider.geometry.collisionPairs))]
    targets = [name for name, _ in world._arm_links] + list(world.static_names)
    assert names == [f"{box.name} <-> {t}" for box in held for t in targets]
    assert world.riding(held) is rider  # made once per payload
