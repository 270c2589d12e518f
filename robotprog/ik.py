"""Inverse kinematics: closed form for UR arms, damped least squares for any arm.

Targets are ``transform_base_to_flange``: the flange frame (``tool0`` on a UR) in the
robot's base frame (``base_link`` on a UR), 4x4 homogeneous, translation in metres. The
gripper's TCP offset is taken off by the caller (``T_base_flange = T_base_tcp @ inv(T_flange_tcp)``).

UR closed form
--------------
The UR arms follow standard Denavit–Hartenberg parameters (Universal Robots' published
d1, a2, a3, d4, d5, d6). The example-robot-data URDFs (ROS-Industrial ``ur_description``)
differ from the DH chain only by fixed transforms, found by comparing both forward
kinematics (see ``tests/robotprog/test_ik.py``):

* the DH base frame is the URDF frame ``base``: ``base_link`` turned by pi about Z
  (:data:`TRANSFORM_BASE_LINK_TO_UR_BASE`; this is also the UR controller's base frame
  that URScript poses are expressed in);
* the DH flange frame is the URDF frame ``tool0`` (identity), and joint zero positions agree.

A reachable pose has up to 8 solutions: shoulder left/right x wrist up/down x elbow
up/down. Each solution's joints are then wrapped by multiples of 2 pi into the joint limits,
choosing per joint the value nearest a reference configuration.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from factory.core.errors import PlanningError
from robotprog.robots import Robot

log = logging.getLogger(__name__)

#: ``base_link`` (ROS) → ``base`` (UR controller / DH base frame): rotation by pi about Z.
TRANSFORM_BASE_LINK_TO_UR_BASE = np.array(
    [[-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)
TRANSFORM_BASE_LINK_TO_UR_BASE.setflags(write=False)

#: Below this |sin(q5)| the wrist is singular (joints 4 and 6 aligned); q6 is then taken
#: from the reference configuration.
_WRIST_SINGULAR = 1e-10
#: An acos argument this far outside [-1, 1] may still be round-off (a stretched arm near
#: the wrist singularity loses digits); such branches are kept, clipped, and polished.
_ARG_SLACK = 1e-5
#: Branches with an acos argument within this of +-1, or |sin q5| below it, are
#: ill-conditioned: :func:`ik_solutions` polishes them with damped least squares.
_ILL_CONDITIONED = 1e-4


@dataclass(frozen=True)
class UrDh:
    """Denavit–Hartenberg parameters of a UR arm [m] (a2, a3 negative as UR publishes them)."""

    d1: float
    a2: float
    a3: float
    d4: float
    d5: float
    d6: float


#: Universal Robots' published DH parameters (CB3 series), matching example-robot-data.
UR_DH: dict[str, UrDh] = {
    "ur3": UrDh(0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819),
    "ur5": UrDh(0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823),
    "ur10": UrDh(0.1273, -0.612, -0.5723, 0.163941, 0.1157, 0.0922),
}


@dataclass(frozen=True)
class DlsOptions:
    """Damped-least-squares IK settings.

    Attributes
    ----------
    damping : float
        Damping factor lambda of ``J^T (J J^T + lambda^2 I)^-1`` [-].
    tolerance : float
        Stop when the pose error (log6 norm: metres and radians mixed) is below this.
    accept : float
        After ``max_iterations``, a seed whose best pose error is below this still counts
        as converged (near singularities the last digits come slowly).
    max_iterations : int
        Iterations per seed.
    restarts : int
        Extra seeds (deterministic pseudo-random within limits) after the reference.
    """

    damping: float = 1e-4
    tolerance: float = 1e-11
    accept: float = 1e-9
    max_iterations: int = 200
    restarts: int = 20


def _dh(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    ct, st = math.cos(theta), math.sin(theta)
    ca, sa = math.cos(alpha), math.sin(alpha)
    return np.array(
        [[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]]
    )


def _inv(t: np.ndarray) -> np.ndarray:
    r = t[:3, :3]
    out = np.eye(4)
    out[:3, :3] = r.T
    out[:3, 3] = -r.T @ t[:3, 3]
    return out


def _chain(dh: UrDh) -> tuple[tuple[float, float, float], ...]:
    # (d, a, alpha) per joint
    h = math.pi / 2
    return (
        (dh.d1, 0.0, h), (0.0, dh.a2, 0.0), (0.0, dh.a3, 0.0), (dh.d4, 0.0, h), (dh.d5, 0.0, -h), (dh.d6, 0.0, 0.0)
    )


def ur_fk(dh: UrDh, q: np.ndarray) -> np.ndarray:
    """Forward kinematics of the DH chain: ``transform_base_link_to_tool0`` (4, 4) [m]."""
    t = TRANSFORM_BASE_LINK_TO_UR_BASE.copy()
    for qi, (d, a, al) in zip(np.asarray(q, dtype=float), _chain(dh)):
        t = t @ _dh(qi, d, a, al)
    return t


def _wrap(a: float) -> float:
    """Angle in (-pi, pi]."""
    return math.pi - ((math.pi - a) % (2 * math.pi))


def ur_ik(dh: UrDh, transform_base_link_to_tool0: np.ndarray, q6_singular: float = 0.0) -> np.ndarray:
    """All closed-form solutions of a UR arm (joint limits not applied).

    Parameters
    ----------
    dh : UrDh
    transform_base_link_to_tool0 : (4, 4) float
        Flange pose in ``base_link`` [m].
    q6_singular : float
        Value of q6 used when the wrist is singular (sin q5 = 0) [rad].

    Returns
    -------
    (k, 6) float
        k <= 8 solutions, angles in (-pi, pi] [rad]; k = 0 when the pose is out of reach.
        Branch order: shoulder (+, -) x wrist (+, -) x elbow (+, -). Near a singularity
        (stretched arm, sin q5 ~ 0) a branch can be off by up to ~1e-6; use
        :func:`ik_solutions` for solutions verified to 1e-9.
    """
    return _ur_ik(dh, transform_base_link_to_tool0, q6_singular)[0]


def _ur_ik(
    dh: UrDh, transform_base_link_to_tool0: np.ndarray, q6_singular: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ur_ik` plus a (k,) mask of ill-conditioned branches that need polishing."""
    t06 = _inv(TRANSFORM_BASE_LINK_TO_UR_BASE) @ np.asarray(transform_base_link_to_tool0, dtype=float)
    d1, a2, a3, d4, d5, d6 = dh.d1, dh.a2, dh.a3, dh.d4, dh.d5, dh.d6
    p06 = t06[:3, 3]
    p05 = p06 - d6 * t06[:3, 2]
    r = math.hypot(p05[0], p05[1])
    out: list[list[float]] = []
    rough: list[bool] = []
    if r < abs(d4) * (1 - _ARG_SLACK) or r == 0.0:
        return np.zeros((0, 6)), np.zeros(0, dtype=bool)
    phi = math.acos(min(1.0, d4 / r))
    psi = math.atan2(p05[1], p05[0])
    t60 = _inv(t06)
    xv, yv = t60[:3, 0], t60[:3, 1]
    for s_sh in (1.0, -1.0):
        q1 = psi + s_sh * phi + math.pi / 2
        s1, c1 = math.sin(q1), math.cos(q1)
        c5 = (p06[0] * s1 - p06[1] * c1 - d4) / d6
        if abs(c5) > 1 + _ARG_SLACK:
            continue
        base5 = math.acos(max(-1.0, min(1.0, c5)))
        for s_wr in (1.0, -1.0):
            q5 = s_wr * base5
            s5 = math.sin(q5)
            if abs(s5) < _WRIST_SINGULAR:
                q6 = q6_singular
            else:
                q6 = math.atan2((-xv[1] * s1 + yv[1] * c1) / s5, (xv[0] * s1 - yv[0] * c1) / s5)
            t01 = _dh(q1, d1, 0.0, math.pi / 2)
            t45 = _dh(q5, d5, 0.0, -math.pi / 2)
            t56 = _dh(q6, d6, 0.0, 0.0)
            t14 = _inv(t01) @ t06 @ _inv(t45 @ t56)
            p13 = t14[:3, 3] - d4 * t14[:3, 1]
            n13 = math.hypot(p13[0], p13[1])
            c3 = (n13 * n13 - a2 * a2 - a3 * a3) / (2 * a2 * a3)
            if abs(c3) > 1 + _ARG_SLACK:
                continue
            base3 = math.acos(max(-1.0, min(1.0, c3)))
            for s_el in (1.0, -1.0):
                q3 = s_el * base3
                q2 = -math.atan2(p13[1], -p13[0]) + math.asin(max(-1.0, min(1.0, a3 * math.sin(q3) / n13)))
                t13 = _dh(q2, 0.0, a2, 0.0) @ _dh(q3, 0.0, a3, 0.0)
                t34 = _inv(t13) @ t14
                q4 = math.atan2(t34[1, 0], t34[0, 0])
                out.append([_wrap(q1), _wrap(q2), _wrap(q3), _wrap(q4), _wrap(q5), _wrap(q6)])
                rough.append(
                    abs(s5) < _ILL_CONDITIONED or 1 - abs(c3) < _ILL_CONDITIONED or 1 - abs(c5) < _ILL_CONDITIONED
                    or abs(r - abs(d4)) < _ILL_CONDITIONED * r
                )
    return np.array(out).reshape(-1, 6), np.array(rough, dtype=bool)


def wrap_to_limits(q: np.ndarray, q_ref: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray | None:
    """Shift each joint by multiples of 2 pi to the value within limits nearest ``q_ref``.

    Returns ``None`` when some joint has no such value (this solution violates the limits).
    """
    out, ok = _wrap_many(np.asarray(q, dtype=float)[None, :], q_ref, lower, upper)
    return out[0] if ok[0] else None


def _wrap_many(
    qs: np.ndarray, q_ref: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`wrap_to_limits` for (k, dof) solutions: wrapped values and a (k,) mask of valid rows."""
    best = qs + 2 * np.pi * np.round((q_ref - qs) / (2 * np.pi))
    ok = (best >= lower - 1e-12) & (best <= upper + 1e-12)
    # The nearest wrap may fall outside the limits while the next one out fits.
    for shift in (2 * np.pi, -2 * np.pi):
        c = best + shift
        take = ~ok & (c >= lower - 1e-12) & (c <= upper + 1e-12)
        best = np.where(take, c, best)
        ok |= take
    return np.clip(best, lower, upper), ok.all(axis=1)


def _closed_form(robot: Robot) -> UrDh | None:
    """The DH parameters when ``robot`` is a known UR arm solved base_link → tool0."""
    if robot.base_frame == "base_link" and robot.flange_frame == "tool0":
        return UR_DH.get(robot.name)
    return None


def _pose_text(t: np.ndarray) -> str:
    p = np.asarray(t)[:3, 3]
    return f"pose xyz=({p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}) m"


def ik_solutions(
    robot: Robot, transform_base_to_flange: np.ndarray, q_ref: np.ndarray | None = None
) -> np.ndarray:
    """Every IK solution within the joint limits, wrapped towards ``q_ref``.

    Parameters
    ----------
    robot : Robot
    transform_base_to_flange : (4, 4) float
        Flange pose in the robot's base frame [m].
    q_ref : (dof,) float, optional
        Reference configuration for joint wrapping (default: zeros) [rad].

    Returns
    -------
    (k, dof) float
        UR arms: up to 8 closed-form branches (k may be 0); ill-conditioned branches
        near singularities are polished with damped least squares. Other arms (or a UR
        with other base/flange frames): the one damped-least-squares solution.

    Raises
    ------
    PlanningError
        Other arms only: the DLS solver found no solution within limits.
    """
    q_ref = np.zeros(robot.dof) if q_ref is None else np.asarray(q_ref, dtype=float)
    dh = _closed_form(robot)
    if dh is None:
        return ik_dls(robot, transform_base_to_flange, q_ref)[None, :]
    sols, rough = _ur_ik(dh, transform_base_to_flange, q6_singular=float(q_ref[5]))
    if rough.any():
        polish = DlsOptions(max_iterations=100, restarts=0)
        keep = np.ones(len(sols), dtype=bool)
        for i in np.flatnonzero(rough):
            try:
                sols[i] = ik_dls(robot, transform_base_to_flange, sols[i], polish, clamp=False)
            except PlanningError:
                keep[i] = False
        sols = sols[keep]
    wrapped, ok = _wrap_many(sols, q_ref, robot.q_lower, robot.q_upper)
    return wrapped[ok]


def ik_continuous(robot: Robot, transform_base_to_flange: np.ndarray, q_prev: np.ndarray) -> np.ndarray:
    """The IK solution continuous with ``q_prev``: the branch nearest it (Euclidean, joint space).

    UR arms use the closed form; when it yields nothing within limits (a stretched arm at
    the wrist singularity), and for every other arm, damped least squares from ``q_prev``.

    Parameters
    ----------
    robot : Robot
    transform_base_to_flange : (4, 4) float
        Flange pose in the robot's base frame [m].
    q_prev : (dof,) float
        The previous configuration along the motion [rad].

    Returns
    -------
    (dof,) float
        Joint positions within limits [rad].

    Raises
    ------
    PlanningError
        The pose is out of reach, or reachable only outside the joint limits.
    """
    q_prev = np.asarray(q_prev, dtype=float)
    sols = ik_solutions(robot, transform_base_to_flange, q_prev)
    if len(sols) == 0 and _closed_form(robot) is not None:
        # At the wrist singularity (q5 = 0) joints 2, 3, 4 and 6 are parallel and q6 is
        # free; taking it from q_prev can leave the elbow short of a stretched pose.
        # Damped least squares from q_prev finds a member of that family.
        try:
            return ik_dls(robot, transform_base_to_flange, q_prev, DlsOptions(restarts=0))
        except PlanningError:
            pass
    if len(sols) == 0:
        raise PlanningError(
            f"{_pose_text(transform_base_to_flange)} is out of reach or outside joint limits",
            source=f"{robot.name} IK",
        )
    return sols[int(np.argmin(np.linalg.norm(sols - q_prev, axis=1)))]


def ik_dls(
    robot: Robot,
    transform_base_to_flange: np.ndarray,
    q_seed: np.ndarray,
    options: DlsOptions = DlsOptions(),
    *,
    clamp: bool = True,
) -> np.ndarray:
    """Damped-least-squares IK (Pinocchio) for any arm, joints clamped to limits.

    ``clamp=False`` lets joints leave their limits while iterating (for polishing a
    closed-form branch that is wrapped into the limits afterwards).

    Starts from ``q_seed``, then tries ``options.restarts`` deterministic pseudo-random
    seeds in turn; returns the first solution that converges (from ``q_seed`` when it can,
    which keeps a motion continuous).

    Raises
    ------
    PlanningError
        No seed converged within tolerance and limits.
    """
    model = robot.model
    data = model.createData()
    fid = model.getFrameId(robot.flange_frame)
    bid = model.getFrameId(robot.base_frame)
    target = pin.SE3(np.asarray(transform_base_to_flange, dtype=float))
    lo, hi = (robot.q_lower, robot.q_upper) if clamp else (np.full(robot.dof, -np.inf), np.full(robot.dof, np.inf))
    # Continuous joints report huge limits; seeds are drawn within +-pi there.
    slo, shi = np.maximum(robot.q_lower, -np.pi), np.minimum(robot.q_upper, np.pi)
    rng = np.random.default_rng(12345)
    seeds = [np.clip(np.asarray(q_seed, dtype=float), lo, hi)]
    seeds += [slo + (shi - slo) * rng.random(robot.dof) for _ in range(options.restarts)]
    eye6 = np.eye(6)
    found: list[np.ndarray] = []
    def error(q: np.ndarray) -> tuple[pin.SE3, np.ndarray, float]:
        pin.framesForwardKinematics(model, data, q)
        err_m = data.oMf[bid].actInv(data.oMf[fid]).actInv(target)
        err = pin.log6(err_m).vector
        return err_m, err, float(np.linalg.norm(err))

    for q in seeds:
        q = q.copy()
        err_m, err, norm = error(q)
        best_err, best_q = norm, q
        # Levenberg-Marquardt: the damping grows while a step makes the error worse (far from
        # the target, or pushing a joint into its limit) and shrinks back to options.damping
        # while steps succeed, so a seed far from the solution (a wrist to turn over) still
        # converges and the last steps near it are Gauss-Newton's.
        damping = options.damping
        for _ in range(options.max_iterations):
            if norm < options.tolerance:
                break
            pin.computeJointJacobians(model, data, q)
            jac = pin.getFrameJacobian(model, data, fid, pin.ReferenceFrame.LOCAL)
            # The base frame moves with no joint, so the LOCAL flange Jacobian is the one
            # of the base-relative pose; Jlog6 maps it to the log6 error's tangent space.
            jac = pin.Jlog6(err_m.inverse()) @ jac
            dq = jac.T @ np.linalg.solve(jac @ jac.T + damping**2 * eye6, err)
            q_new = np.clip(pin.integrate(model, q, dq), lo, hi)
            m_new, e_new, n_new = error(q_new)
            if n_new < norm:
                q, err_m, err, norm = q_new, m_new, e_new, n_new
                damping = max(options.damping, damping / 3.0)
                if norm < best_err:
                    best_err, best_q = norm, q
            else:
                damping *= 10.0
                if damping > 1e3:  # stuck (a joint limit in the way): next seed
                    break
        if best_err < options.accept:
            found.append(best_q)
            break
    if not found:
        raise PlanningError(
            f"{_pose_text(transform_base_to_flange)} is out of reach or outside joint limits",
            source=f"{robot.name} IK",
        )
    return found[0]
