"""TOPP-RA timing: limits hold at 1 kHz, the end is reached at rest, near time-optimal."""

from __future__ import annotations

import numpy as np
import pytest
import toppra
import toppra.algorithm
import toppra.constraint
from hypothesis import given, settings
from hypothesis import strategies as st

from factory.core.errors import PlanningError
from robotprog.timing import LIMIT_SLACK, TimingOptions, Trajectory, peak_ratios, time_path

# UR5 URDF velocity limits at the default cell's 50 % speed scaling, and its acceleration limits.
VMAX = np.array([3.15, 3.15, 3.15, 3.2, 3.2, 3.2]) * 0.5
AMAX = np.array([3.0, 3.0, 3.0, 4.0, 4.0, 4.0]) * 0.5


def _assert_proven(traj: Trajectory, wp: np.ndarray, vmax=VMAX, amax=AMAX) -> None:
    s = traj.resample(1000.0)
    assert s.t[0] == 0.0 and s.t[-1] == traj.duration
    assert np.all(np.diff(s.t) <= 1e-3 * (1 + 1e-9))
    # Velocity and acceleration within limits at every 1 kHz sample (relative slack 1e-9).
    assert (np.abs(s.qd) <= vmax * (1 + LIMIT_SLACK)).all()
    assert (np.abs(s.qdd) <= amax * (1 + LIMIT_SLACK)).all()
    # Position: starts and ends on the waypoints, at rest.
    np.testing.assert_allclose(s.q[0], wp[0], atol=1e-12)
    np.testing.assert_allclose(s.q[-1], wp[-1], atol=1e-9)
    np.testing.assert_allclose(s.qd[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(s.qd[-1], 0.0, atol=1e-12)


def test_two_waypoints_straight_joint_move() -> None:
    wp = np.array([[0.0, -1.57, 1.57, -1.57, -1.57, 0.0], [1.2, -1.0, 1.9, -2.0, -1.57, 2.5]])
    traj = time_path(wp, VMAX, AMAX)
    _assert_proven(traj, wp)
    # A joint move is a straight line in joint space: every sample lies on the segment.
    s = traj.resample(1000.0)
    u = (s.q - wp[0]) @ (wp[1] - wp[0]) / np.dot(wp[1] - wp[0], wp[1] - wp[0])
    np.testing.assert_allclose(s.q, wp[0] + u[:, None] * (wp[1] - wp[0]), atol=1e-12)
    # Bang-bang-ish: duration no shorter than the slowest joint's rest-to-rest minimum time.
    d = np.abs(wp[1] - wp[0])
    t_min = np.where(d > VMAX**2 / AMAX, d / VMAX + VMAX / AMAX, 2 * np.sqrt(d / AMAX))
    assert traj.duration >= t_min.max() * (1 - 1e-9)
    assert traj.duration <= t_min.max() * 1.01


@settings(max_examples=12, deadline=None)
@given(
    n=st.integers(2, 6),
    seed=st.integers(0, 2**31 - 1),
)
def test_limits_hold_at_1khz_for_random_paths(n: int, seed: int) -> None:
    wp = np.random.default_rng(seed).uniform(-2.5, 2.5, (n, 6))
    _assert_proven(time_path(wp, VMAX, AMAX), wp)


def test_waypoints_are_passed_through() -> None:
    wp = np.array([[0.0, 0.0], [0.5, 0.2], [1.0, -0.3], [1.2, 0.4]])
    traj = time_path(wp, np.array([1.0, 1.0]), np.array([2.0, 2.0]))
    s = traj.resample(1000.0)
    for w in wp:
        assert np.linalg.norm(s.q - w, axis=1).min() < 2e-3  # within one 1 ms step at <= 1.4 rad/s


def test_near_time_optimal_vs_dense_grid() -> None:
    """The default grid plus the verification slow-down costs at most 1 % vs a 5000-point grid."""
    rng = np.random.default_rng(7)
    for n in (2, 4, 8):
        wp = rng.uniform(-2.0, 2.0, (n, 6))
        default = time_path(wp, VMAX, AMAX)
        dense = time_path(wp, VMAX, AMAX, options=TimingOptions(gridpoints=5000))
        assert default.duration / dense.duration <= 1.01


def test_matches_toppra_const_accel_parametrizer() -> None:
    """Our frozen trajectory evaluates exactly what toppra's ParametrizeConstAccel returns."""
    wp = np.array([[0.0, 0.0, 0.0], [0.4, -0.3, 0.8], [1.0, 0.2, 0.5]])
    vmax, amax = np.array([1.0, 1.0, 1.0]), np.array([2.0, 2.0, 2.0])
    ours = time_path(wp, vmax, amax, options=TimingOptions(gridpoints=300))
    ss = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(wp, axis=0), axis=1))])
    path = toppra.SplineInterpolator(ss, wp)
    algo = toppra.algorithm.TOPPRA(
        [toppra.constraint.JointVelocityConstraint(np.column_stack([-vmax, vmax])),
         toppra.constraint.JointAccelerationConstraint(np.column_stack([-amax, amax]))],
        path, gridpoints=np.linspace(0, ss[-1], 300), parametrizer="ParametrizeConstAccel",
    )
    ref = algo.compute_trajectory(0.0, 0.0)
    assert ours.duration == pytest.approx(ref.duration * ours.time_scale, rel=1e-12)
    t = np.linspace(0.0, ref.duration, 777)
    q, qd, qdd = ours.sample(t * ours.time_scale)
    np.testing.assert_allclose(q, ref(t), atol=1e-9)
    np.testing.assert_allclose(qd * ours.time_scale, ref(t, 1), atol=1e-6)


def test_sample_scalar_and_clamped() -> None:
    wp = np.array([[0.0, 0.0], [1.0, 0.5]])
    traj = time_path(wp, np.array([1.0, 1.0]), np.array([1.0, 1.0]))
    q, qd, qdd = traj.sample(0.5 * traj.duration)
    assert q.shape == qd.shape == qdd.shape == (2,)
    np.testing.assert_allclose(traj.sample(traj.duration + 5.0)[0], wp[-1], atol=1e-12)
    np.testing.assert_allclose(traj.sample(-1.0)[0], wp[0], atol=1e-12)


def test_single_waypoint_is_a_zero_length_move() -> None:
    wp = np.array([[0.1, 0.2, 0.3], [0.1, 0.2, 0.3]])
    traj = time_path(wp, np.ones(3), np.ones(3))
    assert traj.duration == 0.0
    s = traj.resample(1000.0)
    np.testing.assert_allclose(s.q, [[0.1, 0.2, 0.3]])
    assert peak_ratios(s, np.ones(3), np.ones(3)) == (0.0, 0.0)


def test_toppra_failure_becomes_planning_error(monkeypatch) -> None:
    monkeypatch.setattr(toppra.algorithm.TOPPRA, "compute_trajectory", lambda self, a, b: None)
    with pytest.raises(PlanningError, match="TOPP-RA found no time parametrization"):
        time_path(np.array([[0.0], [1.0]]), np.ones(1), np.ones(1))


def test_spline_leaving_position_limits() -> None:
    wp = np.array([[0.0], [0.95], [0.0], [0.95]])  # the cubic overshoots between waypoints
    with pytest.raises(PlanningError, match="leaves the limits of joint 0"):
        time_path(wp, np.ones(1), np.ones(1), q_lower=np.array([-0.01]), q_upper=np.array([0.96]))


@pytest.mark.parametrize(
    "wp, vmax, amax, message",
    [
        (np.zeros((2, 2)), np.ones(3), np.ones(2), "vmax must have 2 entries"),
        (np.zeros((2, 2)), np.ones(2), np.array([1.0, 0.0]), "amax must be finite and > 0"),
        (np.array([[0.0, np.nan], [1.0, 1.0]]), np.ones(2), np.ones(2), "NaN"),
        (np.zeros(3), np.ones(3), np.ones(3), r"must be \(n, dof\)"),
    ],
)
def test_bad_input(wp, vmax, amax, message) -> None:
    with pytest.raises(PlanningError, match=message):
        time_path(wp, vmax, amax)


@settings(max_examples=12, deadline=None)
@given(n=st.integers(2, 6), seed=st.integers(0, 2**31 - 1), period=st.sampled_from([0.004, 0.008, 0.05]))
def test_chords_of_samples_stay_within_the_chord_deviation(n: int, seed: int, period: float) -> None:
    """The straight segment between two samples ``period`` apart strays from the timed path between
    them by at most :meth:`Trajectory.chord_deviation`, joint by joint (what lets the posted servo
    stream be proven by the room proven around the path)."""
    wp = np.random.default_rng(seed).uniform(-2.5, 2.5, (n, 6))
    traj = time_path(wp, VMAX, AMAX)
    bound = traj.chord_deviation(period)
    starts = np.arange(0.0, traj.duration, period)
    f = np.linspace(0.0, 1.0, 41)
    worst = np.zeros(6)
    for t0 in starts:
        t1 = min(t0 + period, traj.duration)
        qa, _, _ = traj.sample(t0)
        qb, _, _ = traj.sample(t1)
        q, _, _ = traj.sample(t0 + f * (t1 - t0))
        worst = np.maximum(worst, np.abs(q - (qa + f[:, None] * (qb - qa))).max(axis=0))
    assert (worst <= bound).all()
    assert np.isfinite(bound).all() and worst.max() > 0
    assert (traj.chord_deviation(period / 2) <= bound / 4 + 1e-12).all()
