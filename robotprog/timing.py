"""Time-optimal timing of a joint-space path with TOPP-RA, proven within limits at 1 kHz.

A move runs stop to stop: zero joint velocity at its first and last waypoint. The
geometric path is a cubic spline through the waypoints (``toppra.SplineInterpolator``),
parametrized by joint-space chord length ``s`` [rad]. TOPP-RA finds the fastest path
speed ``sd(s)`` on a grid of ``s`` under joint velocity and acceleration limits; between
grid points the path acceleration ``sdd`` is held constant (TOPP-RA's
``ParametrizeConstAccel``), so ``s(t)`` is piecewise quadratic and exact to evaluate.

TOPP-RA enforces the limits only at the grid points. Between them the velocity
``q'(s) sd`` and acceleration ``q''(s) sd^2 + q'(s) sdd`` can overshoot slightly, so the
result is re-sampled at :attr:`TimingOptions.verify_rate_hz` and, if any joint exceeds a
limit, the whole trajectory is slowed by a uniform time scale
``k = max(max|qd|/vmax, sqrt(max|qdd|/amax))`` (velocity scales by 1/k, acceleration by
1/k^2), which puts every sample back within the limits. The overshoot on the default grid
is well under 1 %, so the cost in duration is too.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PPoly

from factory.core.errors import PlanningError
from robotprog.toppra_loader import load_toppra

log = logging.getLogger(__name__)

# toppra logs every solve at INFO and a failure at WARNING; we raise instead.
logging.getLogger("toppra").setLevel(logging.ERROR)

#: Relative slack of the limit check: samples may exceed a limit by this fraction of it
#: (float round-off in evaluating the spline and the time scale).
LIMIT_SLACK = 1e-9
_MAX_RESCALES = 8
#: Extra relative slow-down per round beyond the measured overshoot (0.01 %).
_RESCALE_MARGIN = 1e-4


@dataclass(frozen=True)
class TimingOptions:
    """TOPP-RA settings.

    Attributes
    ----------
    gridpoints : int or None
        Number of TOPP-RA grid points; ``None`` lets toppra propose a grid from the
        path's curvature (at least ``min_gridpoints``).
    min_gridpoints : int
        Lower bound on the proposed grid.
    verify_rate_hz : float
        Rate at which the result is re-sampled to check (and enforce) the limits [Hz].
    """

    gridpoints: int | None = None
    min_gridpoints: int = 200
    verify_rate_hz: float = 1000.0


@dataclass(frozen=True)
class Samples:
    """A trajectory sampled at fixed rate: ``t`` (k,) [s], ``q``, ``qd``, ``qdd`` (k, dof) [rad, rad/s, rad/s^2]."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A timed joint-space move, stop to stop.

    The path ``q(s)`` is a cubic piecewise polynomial (``breakpoints`` (p+1,),
    ``coefficients`` (4, p, dof)) in the path parameter ``s`` [rad of joint-space chord];
    the timing is piecewise constant path acceleration: on grid interval ``i`` (from time
    ``ts[i]``) ``s = ss[i] + sd[i] tau + sdd[i] tau^2 / 2``.

    Attributes
    ----------
    ss, ts, sd : (m+1,) float
        Grid points of ``s`` [rad], times [s], path speeds [rad/s].
    sdd : (m,) float
        Path acceleration per interval [rad/s^2].
    breakpoints, coefficients
        The spline path.
    time_scale : float
        Uniform slow-down applied after verification (1 = none).
    """

    ss: np.ndarray
    ts: np.ndarray
    sd: np.ndarray
    sdd: np.ndarray
    breakpoints: np.ndarray
    coefficients: np.ndarray
    time_scale: float = 1.0

    @property
    def duration(self) -> float:
        """Move time [s]."""
        return float(self.ts[-1])

    @property
    def dof(self) -> int:
        return int(self.coefficients.shape[2])

    def sample(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint position, velocity, acceleration at time(s) ``t`` [s] (clamped to [0, duration]).

        Returns
        -------
        q, qd, qdd : (dof,) or (k, dof) float
            [rad], [rad/s], [rad/s^2]; shape (dof,) for a scalar ``t``.
        """
        scalar = np.ndim(t) == 0
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.duration)
        m = len(self.sdd)
        if m == 0:  # a move of zero length
            q = np.broadcast_to(self.coefficients[3, 0], (len(t), self.dof)).copy()
            z = np.zeros_like(q)
            return (q[0], z[0], z[0]) if scalar else (q, z, z.copy())
        i = np.clip(np.searchsorted(self.ts, t, side="right") - 1, 0, m - 1)
        tau = t - self.ts[i]
        s = np.clip(self.ss[i] + self.sd[i] * tau + 0.5 * self.sdd[i] * tau * tau, self.ss[0], self.ss[-1])
        sdot = np.maximum(self.sd[i] + self.sdd[i] * tau, 0.0)
        path = PPoly(self.coefficients, self.breakpoints, extrapolate=True)
        q = path(s)
        dq = path(s, 1)
        ddq = path(s, 2)
        qd = dq * sdot[:, None]
        qdd = ddq * (sdot * sdot)[:, None] + dq * self.sdd[i][:, None]
        if scalar:
            return q[0], qd[0], qdd[0]
        return q, qd, qdd

    def chord_deviation(self, period: float) -> np.ndarray:
        """(dof,) bound [rad] per joint on how far the straight segment between two samples at most
        ``period`` [s] apart strays from the path between them.

        ``q(t) = path(s(t))`` has a continuous first derivative (the spline is C2 in ``s``, the path
        speed continuous in ``t``) and ``q'' = path''(s) sd^2 + path'(s) sdd``; a function with
        ``|q''| <= a`` strays from its chord over ``h`` by at most ``a h^2 / 8``. ``a`` is bounded
        from the spline's pieces (``path''`` is linear on each, ``path'`` quadratic: their largest
        values exactly) and the largest path speed and acceleration."""
        if len(self.sdd) == 0:
            return np.zeros(self.dof)
        c = np.asarray(self.coefficients, dtype=float)
        h = np.diff(self.breakpoints)[:, None]
        # path'' = 6 c0 u + 2 c1 on [0, h]: largest at an end
        second = np.maximum(np.abs(2 * c[1]), np.abs(6 * c[0] * h + 2 * c[1])).max(axis=0)
        # path' = 3 c0 u^2 + 2 c1 u + c2: at the ends and at its vertex where that is inside
        ends = np.maximum(np.abs(c[2]), np.abs(3 * c[0] * h * h + 2 * c[1] * h + c[2]))
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.where(c[0] != 0, -c[1] / (3 * c[0]), -1.0)
        inside = (u > 0) & (u < h)
        vertex = np.where(inside, np.abs(3 * c[0] * u * u + 2 * c[1] * u + c[2]), 0.0)
        first = np.maximum(ends, vertex).max(axis=0)
        a = second * float(np.max(self.sd)) ** 2 + first * float(np.max(np.abs(self.sdd)))
        # a hair more for the rounding of the samples themselves (the bound is exact on a straight move)
        return a * period * period / 8 * (1 + 1e-9) + 1e-12

    def resample(self, rate_hz: float = 1000.0) -> Samples:
        """Samples at ``rate_hz`` [Hz] from t = 0, plus the final instant (so the end is included)."""
        if rate_hz <= 0:
            raise PlanningError(f"resample rate must be > 0 Hz, got {rate_hz}")
        n = int(math.floor(self.duration * rate_hz + 1e-9)) + 1
        t = np.arange(n) / rate_hz
        if t[-1] < self.duration:
            t = np.append(t, self.duration)
        q, qd, qdd = self.sample(t)
        return Samples(t, q, qd, qdd)

    def scaled(self, k: float) -> "Trajectory":
        """The same path run ``k`` times slower (k >= 1): velocity / k, acceleration / k^2."""
        return Trajectory(
            self.ss, _frozen(self.ts * k), _frozen(self.sd / k), _frozen(self.sdd / (k * k)),
            self.breakpoints, self.coefficients, self.time_scale * k,
        )


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=float)
    a.setflags(write=False)
    return a


def _check_inputs(waypoints: np.ndarray, vmax: np.ndarray, amax: np.ndarray) -> None:
    if waypoints.ndim != 2 or len(waypoints) < 1:
        raise PlanningError(f"waypoints must be (n, dof), got shape {waypoints.shape}")
    dof = waypoints.shape[1]
    if not np.isfinite(waypoints).all():
        raise PlanningError("waypoints contain NaN or infinite values")
    for name, lim in (("vmax", vmax), ("amax", amax)):
        if lim.shape != (dof,):
            raise PlanningError(f"{name} must have {dof} entries, got shape {lim.shape}")
        if not (np.isfinite(lim).all() and (lim > 0).all()):
            raise PlanningError(f"{name} must be finite and > 0, got {lim.tolist()}")


@functools.lru_cache(maxsize=16)
def _limits(vmax: tuple[float, ...], amax: tuple[float, ...]) -> tuple[object, object]:
    """TOPP-RA's joint velocity and acceleration constraints for limits ``vmax`` [rad/s] and ``amax`` [rad/s^2],
    built once per robot: building them formats their limits into text (0.4 ms), a plan times a hundred moves
    with the same limits, and TOPP-RA only reads them."""
    toppra = load_toppra()
    return (toppra.constraint.JointVelocityConstraint(np.column_stack([-np.array(vmax), np.array(vmax)])),
            toppra.constraint.JointAccelerationConstraint(np.column_stack([-np.array(amax), np.array(amax)])))


def peak_ratios(samples: Samples, vmax: np.ndarray, amax: np.ndarray) -> tuple[float, float]:
    """Largest ``|qd| / vmax`` and ``|qdd| / amax`` over all samples and joints."""
    rv = float(np.max(np.abs(samples.qd) / vmax)) if len(samples.t) else 0.0
    ra = float(np.max(np.abs(samples.qdd) / amax)) if len(samples.t) else 0.0
    return rv, ra


def time_path(
    waypoints: np.ndarray,
    vmax: np.ndarray,
    amax: np.ndarray,
    *,
    q_lower: np.ndarray | None = None,
    q_upper: np.ndarray | None = None,
    options: TimingOptions = TimingOptions(),
) -> Trajectory:
    """Time-optimal stop-to-stop trajectory through joint-space waypoints.

    Parameters
    ----------
    waypoints : (n, dof) float
        Joint positions the path passes through, in order [rad]; n >= 1 (repeated
        consecutive waypoints are dropped).
    vmax : (dof,) float
        Joint velocity limits [rad/s] (the URDF's, times the cell's speed scaling).
    amax : (dof,) float
        Joint acceleration limits [rad/s^2].
    q_lower, q_upper : (dof,) float, optional
        Joint position limits [rad]: the spline between waypoints must stay within them.
    options : TimingOptions

    Returns
    -------
    Trajectory
        Zero velocity at start and end; re-sampled at ``options.verify_rate_hz`` every
        joint stays within ``vmax`` and ``amax`` (relative slack :data:`LIMIT_SLACK`).

    Raises
    ------
    PlanningError
        Malformed input, a path leaving the position limits, or TOPP-RA finding no
        parametrization (toppra returned None).
    """
    wp = np.asarray(waypoints, dtype=float)
    vmax = np.asarray(vmax, dtype=float)
    amax = np.asarray(amax, dtype=float)
    _check_inputs(wp, vmax, amax)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(wp, axis=0), axis=1) > 1e-12])
    wp = wp[keep]
    dof = wp.shape[1]
    if len(wp) == 1:
        coeffs = np.zeros((4, 1, dof))
        coeffs[3, 0] = wp[0]
        z1, z0 = np.zeros(1), np.zeros(0)
        return Trajectory(_frozen(z1), _frozen(z1), _frozen(z1), _frozen(z0), _frozen(np.array([0.0, 1.0])),
                          _frozen(coeffs))
    ss_wp = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(wp, axis=0), axis=1))])
    # Loaded here, not at the top: every `factory` process that never times a move (help, verify,
    # a workflow driver) would pay for it; and loaded without the matplotlib toppra imports.
    toppra = load_toppra()

    path = toppra.SplineInterpolator(ss_wp, wp, bc_type="not-a-knot")
    spline = path.cspl

    if q_lower is not None or q_upper is not None:
        s_check = np.linspace(0.0, ss_wp[-1], max(200, 20 * len(wp)))
        q_check = spline(s_check)
        lo = -np.inf if q_lower is None else np.asarray(q_lower, dtype=float)
        hi = np.inf if q_upper is None else np.asarray(q_upper, dtype=float)
        bad = np.argwhere((q_check < lo - 1e-12) | (q_check > hi + 1e-12))
        if len(bad):
            k, j = bad[0]
            raise PlanningError(
                f"path leaves the limits of joint {j} ({q_check[k, j]:.4f} rad) between waypoints"
            )

    if options.gridpoints is not None:
        if options.gridpoints < 2:
            raise PlanningError(f"gridpoints must be >= 2, got {options.gridpoints}")
        grid = np.linspace(0.0, ss_wp[-1], options.gridpoints)
    else:
        grid = None
    constraints = list(_limits(tuple(vmax.tolist()), tuple(amax.tolist())))
    algo = toppra.algorithm.TOPPRA(
        constraints, path, gridpoints=grid, parametrizer="ParametrizeConstAccel",
        gridpt_min_nb_points=options.min_gridpoints,
    )
    if algo.compute_trajectory(0.0, 0.0) is None:
        raise PlanningError(
            f"TOPP-RA found no time parametrization ({algo.problem_data.return_code}) for a "
            f"{len(wp)}-waypoint path from {np.round(wp[0], 4).tolist()} to {np.round(wp[-1], 4).tolist()}"
        )
    ss = np.asarray(algo.problem_data.gridpoints, dtype=float)
    sd = np.maximum(np.asarray(algo.problem_data.sd_vec, dtype=float), 0.0)
    ds = np.diff(ss)
    vsum = sd[:-1] + sd[1:]
    if np.any(vsum <= 0):
        raise PlanningError("TOPP-RA returned a path speed of zero inside the path")
    ts = np.concatenate([[0.0], np.cumsum(2 * ds / vsum)])
    sdd = (sd[1:] ** 2 - sd[:-1] ** 2) / (2 * ds)
    traj = Trajectory(
        _frozen(ss), _frozen(ts), _frozen(sd), _frozen(sdd), _frozen(spline.x), _frozen(spline.c)
    )
    # Re-check after each slow-down: the 1 kHz samples of the slower trajectory fall at
    # other path points than before, so one scaling is not a proof; two or three are.
    for _ in range(_MAX_RESCALES):
        rv, ra = peak_ratios(traj.resample(options.verify_rate_hz), vmax, amax)
        k = max(rv, math.sqrt(ra))
        if k <= 1.0:
            return traj
        # Slow a little beyond the measured overshoot: the slower trajectory's samples land
        # on other path points, and slowing by exactly the overshoot lets the sampled peak
        # creep back over the limit (hypothesis found 8 rounds stuck at a = 1.000005).
        k *= 1 + _RESCALE_MARGIN
        log.debug("limits overshot between grid points (v %.6f, a %.6f): slowing by %.6f", rv, ra, k)
        traj = traj.scaled(k)
    raise PlanningError(f"trajectory still exceeds limits after {_MAX_RESCALES} slow-downs (v {rv}, a {ra})")
