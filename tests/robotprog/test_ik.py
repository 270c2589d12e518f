"""IK: closed-form UR branches against Pinocchio FK of the example-robot-data URDF; DLS fallback."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from factory.core.errors import PlanningError
from robotprog.ik import UR_DH, ik_continuous, ik_dls, ik_solutions, ur_fk, ur_ik, wrap_to_limits
from robotprog.robots import load_robot


def _pose_error(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Position error [m] and rotation angle error [rad] between two transforms."""
    dp = float(np.linalg.norm(a[:3, 3] - b[:3, 3]))
    c = (np.trace(a[:3, :3].T @ b[:3, :3]) - 1) / 2
    # arccos loses precision near 1; use the skew part instead.
    r = a[:3, :3].T @ b[:3, :3]
    s = np.linalg.norm([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / 2
    return dp, float(np.arctan2(s, c))


@pytest.mark.parametrize("name", ["ur3", "ur5", "ur10"])
def test_dh_chain_matches_urdf(name: str) -> None:
    """The URDF differs from DH only by base_link→base (pi about Z) and tool0 = DH flange."""
    robot = load_robot(name)
    rng = np.random.default_rng(1)
    for q in rng.uniform(-np.pi, np.pi, (50, 6)):
        dp, dr = _pose_error(ur_fk(UR_DH[name], q), robot.fk(q))
        assert dp < 1e-9 and dr < 1e-9


@pytest.mark.parametrize("name", ["ur5", "ur10"])
def test_all_branches_reach_the_pose(name: str) -> None:
    robot = load_robot(name)
    dh = UR_DH[name]
    rng = np.random.default_rng(2)
    n_branches = []
    for q in rng.uniform(-np.pi, np.pi, (200, 6)):
        target = robot.fk(q)
        sols = ur_ik(dh, target)
        n_branches.append(len(sols))
        for s in sols:
            dp, dr = _pose_error(robot.fk(s), target)
            assert dp < 1e-9 and dr < 1e-9
        # The configuration we started from is one of the branches (mod 2 pi).
        if abs(np.sin(q[4])) > 1e-3:
            diff = np.abs((sols - q + np.pi) % (2 * np.pi) - np.pi).max(axis=1)
            assert diff.min() < 1e-6
    # Most random poses have all 8 branches; all are found.
    assert max(n_branches) == 8 and np.mean(np.equal(n_branches, 8)) > 0.5


def test_branches_are_distinct() -> None:
    """Eight branches of one pose are eight different configurations (the wrist-flipped
    ones move the wrist centre, so some poses have only 4 or 2 reachable branches)."""
    robot = load_robot("ur5")
    q = np.array([-1.5, -1.27, 1.97, -2.56, 0.63, 1.44])
    sols = ur_ik(UR_DH["ur5"], robot.fk(q))
    assert len(sols) == 8
    d = np.linalg.norm(sols[:, None] - sols[None], axis=2) + np.eye(8)
    assert d.min() > 1e-3


@settings(max_examples=60, deadline=None)
@given(
    q=st.lists(st.floats(-3.0, 3.0), min_size=6, max_size=6),
    dq=st.lists(st.floats(-0.02, 0.02), min_size=6, max_size=6),
)
def test_ik_continuous_follows_the_previous_configuration(q: list[float], dq: list[float]) -> None:
    robot = load_robot("ur5")
    q_prev = np.array(q)
    q_new = q_prev + np.array(dq)
    target = robot.fk(q_new)
    sol = ik_continuous(robot, target, q_prev)
    dp, dr = _pose_error(robot.fk(sol), target)
    # Away from the wrist (sin q5 = 0), elbow (sin q3 = 0) and shoulder (wrist centre on the
    # base axis) singularities the branch is the one we came from.
    dh = UR_DH["ur5"]
    wrist_centre = target[:3, 3] - dh.d6 * target[:3, 2]
    regular = (
        abs(np.sin(q_new[4])) > 0.05 and abs(np.sin(q_new[2])) > 0.05
        and np.hypot(wrist_centre[0], wrist_centre[1]) > dh.d4 + 0.02
    )
    if regular:
        assert dp < 1e-9 and dr < 1e-9
        assert np.abs(sol - q_new).max() < 1e-6
    else:
        # At the elbow singularity (arm stretched) acos loses half the digits.
        assert dp < 1e-6 and dr < 1e-6
    assert (sol >= robot.q_lower).all() and (sol <= robot.q_upper).all()


def test_stretched_wrist_singular_pose_falls_back_to_dls() -> None:
    """q5 = 0 makes q6 free; with the arm stretched only q6 = 0.0156 reaches, not q_prev's 0."""
    robot = load_robot("ur5")
    q = np.array([0.0, 0.0, 0.0, -0.015625, 0.0, 0.015625])
    assert len(ik_solutions(robot, robot.fk(q), np.zeros(6))) == 0
    sol = ik_continuous(robot, robot.fk(q), np.zeros(6))
    dp, dr = _pose_error(robot.fk(sol), robot.fk(q))
    assert dp < 1e-9 and dr < 1e-9


def test_joint_wrap_picks_the_turn_nearest_the_previous() -> None:
    robot = load_robot("ur5")
    q = np.array([5.5, -1.0, 1.2, -1.5, -1.4, -5.9])  # beyond +-pi on joints 1 and 6
    sol = ik_continuous(robot, robot.fk(q), q + 0.01)
    np.testing.assert_allclose(sol, q, atol=1e-7)


def test_wrap_respects_limits() -> None:
    lo, hi = np.full(2, -np.pi), np.full(2, np.pi)
    assert wrap_to_limits(np.array([3.0, -3.0]), np.array([4.0, -4.0]), lo, hi) is not None
    w = wrap_to_limits(np.array([3.0, -3.0]), np.array([4.0, -4.0]), lo, hi)
    assert (w >= lo).all() and (w <= hi).all()
    lo2, hi2 = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    assert wrap_to_limits(np.array([2.0, 0.0]), np.zeros(2), lo2, hi2) is None


def test_elbow_limit_removes_branches() -> None:
    """ur5's elbow is limited to +-pi, the others to +-2 pi: every solution returned obeys them."""
    robot = load_robot("ur5")
    rng = np.random.default_rng(3)
    for q in rng.uniform(-np.pi, np.pi, (30, 6)):
        sols = ik_solutions(robot, robot.fk(q), q)
        assert ((sols >= robot.q_lower) & (sols <= robot.q_upper)).all()


def test_unreachable_pose_names_the_pose() -> None:
    robot = load_robot("ur5")
    target = np.eye(4)
    target[:3, 3] = [1.5, 0.2, 0.3]
    with pytest.raises(PlanningError, match=r"xyz=\(1\.5000, 0\.2000, 0\.3000\)"):
        ik_continuous(robot, target, np.zeros(6))


def test_dls_fallback_panda_within_limits() -> None:
    robot = load_robot("panda")
    rng = np.random.default_rng(4)
    for _ in range(5):
        q = robot.q_lower + (robot.q_upper - robot.q_lower) * rng.uniform(0.1, 0.9, 7)
        target = robot.fk(q)
        sol = ik_continuous(robot, target, np.clip(q + 0.3, robot.q_lower, robot.q_upper))
        dp, dr = _pose_error(robot.fk(sol), target)
        assert dp < 1e-9 and dr < 1e-9
        assert (sol >= robot.q_lower).all() and (sol <= robot.q_upper).all()


def test_dls_unreachable_raises() -> None:
    robot = load_robot("panda")
    target = np.eye(4)
    target[:3, 3] = [2.0, 0.0, 0.5]
    with pytest.raises(PlanningError, match="out of reach"):
        ik_dls(robot, target, np.zeros(7))


def test_singular_configurations_are_still_solved() -> None:
    """Wrist (q5 = 0), elbow (q3 = 0) and both at once: a solution meeting the pose to 1e-9."""
    robot = load_robot("ur5")
    rng = np.random.default_rng(8)
    for i in range(300):
        q = rng.uniform(-3.0, 3.0, 6)
        if i % 3 == 0:
            q[4] = rng.choice([0.0, 1e-9, 1e-6, -1e-7])
        if i % 3 == 1:
            q[2] = 0.0
        if i % 3 == 2:
            q[2], q[4] = 0.0, rng.choice([0.0, 1e-6])
        target = robot.fk(q)
        sol = ik_continuous(robot, target, q + rng.uniform(-0.02, 0.02, 6))
        dp, dr = _pose_error(robot.fk(sol), target)
        assert dp < 1e-9 and dr < 1e-9


def test_other_flange_frame_uses_dls() -> None:
    """A UR loaded with another flange frame is not solved by the tool0 closed form."""
    robot = load_robot("ur5", flange_frame="ee_link")
    q = np.array([0.3, -1.2, 1.4, -1.5, -1.3, 0.6])
    target = robot.fk(q)
    sol = ik_continuous(robot, target, q + 0.05)
    dp, dr = _pose_error(robot.fk(sol), target)
    assert dp < 1e-9 and dr < 1e-9
    assert ik_solutions(robot, target, q).shape == (1, 6)


ARM_URDFS = {
    "abb_irb1200_5_90": "robots/abb_irb1200_5_90/abb_irb1200_5_90.urdf",
    "kuka_kr6_r900_sixx": "robots/kuka_kr6_r900_sixx/kuka_kr6_r900_sixx.urdf",
}


@pytest.mark.parametrize("name", sorted(ARM_URDFS))
def test_numerical_ik_of_the_abb_and_kuka_arms_reproduces_the_pose(name: str) -> None:
    """No closed form for these arms: damped least squares from a seed 0.5 rad away on every
    joint (a wrist to turn, an elbow to bend) reaches the pose within 1e-6 m and 1e-6 rad,
    within the datasheet's axis ranges, the same answer every time (seeded restarts)."""
    from factory.core.resources import FIXTURES

    robot = load_robot(FIXTURES / ARM_URDFS[name], flange_frame="tool0")
    assert robot.name == name and robot.dof == 6
    rng = np.random.default_rng(7)
    lo, hi = np.maximum(robot.q_lower, -np.pi), np.minimum(robot.q_upper, np.pi)
    worst = (0.0, 0.0)
    for _ in range(40):
        q = lo + (hi - lo) * rng.random(6)
        target = robot.fk(q)
        seed = np.clip(q + rng.choice([-0.5, 0.5], 6), robot.q_lower, robot.q_upper)
        sols = ik_solutions(robot, target, seed)
        assert len(sols) == 1
        sol = sols[0]
        assert (sol >= robot.q_lower).all() and (sol <= robot.q_upper).all()
        dp, dr = _pose_error(robot.fk(sol), target)
        worst = (max(worst[0], dp), max(worst[1], dr))
        np.testing.assert_array_equal(ik_solutions(robot, target, seed)[0], sol)
    assert worst[0] < 1e-6 and worst[1] < 1e-6, worst
