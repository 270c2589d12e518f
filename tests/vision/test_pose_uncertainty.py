"""The pose's covariance from an edge fit's own residuals (vision/pose_uncertainty.py), on fits built by hand:
a rectangle's four sides, each a mesh edge of samples, with residuals along their normals."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vision.pose_uncertainty import feet_shift, pose_covariance

#: Pixels per metre of the hand-made fit (about the cell camera's: 0.82 mm per pixel).
PX_PER_M = 1.0 / 8.2e-4


def rectangle(half_u: float = 40.0, half_v: float = 10.0, per_side: int = 40, pieces: int = 5):
    """Samples on a 2*half_u x 2*half_v px rectangle whose sides are ``pieces`` mesh edges each: the Jacobian
    (n, 3) of their residuals by x, y [m] and yaw [rad], and the mesh edge of each (side * pieces + piece)."""
    rows, edge = [], []
    for side, (normal, centre, along) in enumerate([((1, 0), (half_u, 0), (0, 1)), ((-1, 0), (-half_u, 0), (0, 1)),
                                                     ((0, 1), (0, half_v), (1, 0)), ((0, -1), (0, -half_v), (1, 0))]):
        n, c, a = map(np.array, (normal, centre, along))
        reach = half_v if side < 2 else half_u
        for k, t in enumerate(np.linspace(-reach, reach, per_side)):
            q = c + t * a
            # A residual along n moves with x, y by n [px per px] and with yaw by n . (z x q).
            rows.append([n[0] * PX_PER_M, n[1] * PX_PER_M, n @ np.array([-q[1], q[0]])])
            edge.append(side * pieces + k * pieces // per_side)
    return np.array(rows, dtype=float), np.array(edge)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 16), bias=st.floats(-1.0, 1.0))
def test_the_covariance_is_never_below_the_independent_residuals_one(seed, bias):
    """Whatever the residuals, the reported covariance is at least the one of independent residuals
    (the edges' pull only adds), in position and in yaw."""
    jac, edge = rectangle()
    residuals = np.random.default_rng(seed).normal(0.0, 0.3, len(jac)) + bias * (edge < 5)
    cov = pose_covariance(jac, residuals, edge, np.zeros(len(jac), bool), 4.0)
    n = len(residuals)
    independent = np.linalg.inv(jac.T @ jac) * max(np.sum(residuals ** 2) / (n - 3), 0.05 ** 2) * 4.0
    assert np.linalg.eigvalsh(cov[:2, :2]).max() >= np.linalg.eigvalsh(independent[:2, :2]).max() * (1 - 1e-9)
    assert cov[2, 2] >= independent[2, 2] * (1 - 1e-9)


def test_two_halves_of_an_edge_that_disagree_count_in_yaw():
    """The long sides' halves pull the yaw apart (+0.8 px on one half, -0.8 on the other, as a wall's feet
    taking its top's edge along part of it): the yaw's deviation by edges is larger than with the same
    residuals scattered at random over the samples."""
    jac, edge = rectangle(pieces=6)
    rng = np.random.default_rng(1)
    side, piece = edge // 6, edge % 6
    residuals = np.where(side >= 2, 0.8 * np.where(piece < 3, 1, -1) * np.where(side == 2, 1, -1), 0.0)
    residuals = residuals + rng.normal(0, 0.1, len(jac))
    held = pose_covariance(jac, residuals, edge, np.zeros(len(jac), bool), 4.0)
    scattered = pose_covariance(jac, rng.permutation(residuals), edge, np.zeros(len(jac), bool), 4.0)
    assert np.sqrt(held[2, 2]) > 1.5 * np.sqrt(scattered[2, 2])
    # Over fewer mesh edges than MIN_EDGES their pulls do not count: the independent residuals' covariance.
    few = pose_covariance(jac, residuals, side, np.zeros(len(jac), bool), 4.0)
    assert few[2, 2] < held[2, 2] and np.sqrt(few[2, 2]) < 1.5 * np.sqrt(scattered[2, 2])


def test_feet_that_pull_the_pose_add_their_turn():
    """Half of one long side's samples are feet (unresolved) 0.6 px off the rest: leaving them out moves
    the pose across that side and turns it, and the yaw's variance grows by that turn squared."""
    jac, edge = rectangle()
    feet = (edge // 5 == 2) & (np.arange(len(jac)) % 40 >= 20)
    residuals = np.where(feet, 0.6, 0.0)
    # The fit balances its residuals: take them relative to the least-squares pose.
    residuals = residuals - jac @ np.linalg.lstsq(jac, residuals, rcond=None)[0]
    shift = feet_shift(jac, residuals, feet)
    assert abs(shift[1]) * PX_PER_M > 0.1  # across the side [px]
    assert abs(shift[2]) * 40 > 0.1  # at the side's end, 40 px from the middle [px]
    without = pose_covariance(jac, residuals, edge, np.zeros(len(jac), bool), 4.0)
    with_feet = pose_covariance(jac, residuals, edge, feet, 4.0)
    assert with_feet[2, 2] == pytest.approx(without[2, 2] + shift[2] ** 2)
    assert with_feet[1, 1] == without[1, 1]


def test_no_feet_no_shift():
    jac, edge = rectangle()
    residuals = np.random.default_rng(0).normal(0, 0.3, len(jac))
    assert not feet_shift(jac, residuals, np.zeros(len(jac), bool)).any()
    # Too few samples would remain without them.
    assert not feet_shift(jac, residuals, np.arange(len(jac)) > 5).any()
