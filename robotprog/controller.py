"""How long a posted robot program runs on its controller: a timer with the controllers' semantics.

The plan's duration is what TOPP-RA proved; this module times the *program* the way the
controller runs it, from the numbers the program states, so the two can be compared:

* an unblended joint move (``movej`` / ``MoveAbsJ ... fine`` / ``PTP``, no blend radius)
  starts and ends at rest: a trapezoid (or triangle) on the leading joint's travel with the
  move's ``a`` [rad/s^2] and ``v`` [rad/s];
* a chain of blended joint moves (each but the last with a blend radius) accelerates once
  and decelerates once: one trapezoid on the summed leading-joint travel;
* a joint move with a time ``t`` (URScript ``t=``, RAPID ``\\T:=``) takes ``t``;
* a KRL PTP with a time ``t`` runs at the whole ``$VEL_AXIS`` percentage the program states
  (:func:`robotprog.krl.ptp_percent`); a blended chain of them cruises segment by segment and
  adds one ramp up at its start and one ramp down at its end (``v / (2 a)`` each);
* ``servoj`` counts its ``t`` per target;
* ``movel`` is a trapezoid on the TCP path length with its ``a`` [m/s^2] and ``v`` [m/s]
  (needs the TCP position, hence ``tcp_of``);
* gripper outputs wait their settle time, ``sleep`` / ``WaitTime`` / ``WAIT SEC`` their
  seconds; comments take no time;
* reading the rack camera's correction takes no time, and a corrected ``movel`` is timed to the
  pose the plan put it at (the correction is a few millimetres);
* a wait on a digital input (the machine's door, its cycle) counts nothing: that is the
  machine's time, which the plan does not contain either; the robot stands still meanwhile;
* a branch on an input (``if`` / ``IF``) runs one of its two ways, the one ``verdict`` names
  (the machine's verdict on the part: the out-tray or the reject bin); reading the input takes
  no time.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from factory.core.errors import PlanningError
from robotprog.krl import ptp_percent
from robotprog.urscript import Branch, Comment, MoveJ, MoveL, ReadCorrection, ServoJ, SetOutputs, Step, Wait, WaitInput

LANGS = ("urscript", "rapid", "krl")


def trapezoid_time(distance: float, v: float, a: float) -> float:
    """Rest-to-rest time [s] over ``distance`` at cruise speed ``v`` and acceleration ``a``
    (same unit of length): a trapezoid, or a triangle when the move is too short to cruise."""
    if distance <= 0:
        return 0.0
    if not (v > 0 and a > 0 and math.isfinite(v) and math.isfinite(a)):
        raise PlanningError(f"speed and acceleration must be finite and > 0, got v={v}, a={a}")
    if distance >= v * v / a:
        return distance / v + v / a
    return 2.0 * math.sqrt(distance / a)


def branch_taken(steps: Sequence[Step], verdict: bool) -> list[Step]:
    """The steps a run executes when every branch's input reads ``verdict``, branches replaced by
    the way they take (recursively)."""
    out: list[Step] = []
    for st in steps:
        if isinstance(st, Branch):
            out += branch_taken(st.then if verdict == st.level else st.otherwise, verdict)
        else:
            out.append(st)
    return out


def program_duration(
    steps: Sequence[Step],
    start: np.ndarray,
    *,
    lang: str = "urscript",
    axis_speed: np.ndarray | None = None,
    tcp_of: Callable[[np.ndarray], np.ndarray] | None = None,
    verdict: bool = True,
) -> float:
    """Time [s] the controller of ``lang`` takes to run ``steps`` from joint position ``start`` [rad].

    Parameters
    ----------
    steps : sequence of Step
    start : (dof,) float
        Where the arm stands when the program starts [rad].
    lang : str
        ``urscript``, ``rapid`` or ``krl`` (decides how a timed joint move runs).
    axis_speed : (dof,) float, optional
        The axes' 100 % speeds [rad/s]; KRL timed moves need them.
    tcp_of : callable, optional
        ``q -> transform_base_link_to_tcp`` (4, 4); ``movel`` after a joint move needs it.
    verdict : bool
        The level every branch's input reads (True: a good part, to the out-tray).

    Raises
    ------
    PlanningError
        Unknown language, a ``movel`` whose start is unknown, a KRL timed move without
        ``axis_speed``.
    """
    if lang not in LANGS:
        raise PlanningError(f"no controller model for {lang!r}: expected one of {', '.join(LANGS)}")
    q = np.asarray(start, dtype=float)
    pos: np.ndarray | None = None
    total = 0.0
    chain: list[tuple[float, float, float, float]] = []  # (distance, v, a, fixed time) of blended moves

    def flush() -> float:
        if not chain:
            return 0.0
        fixed = [c for c in chain if c[3] > 0]
        free = [c for c in chain if c[3] <= 0]
        t = sum(c[3] for c in fixed)
        if free:
            t += trapezoid_time(sum(c[0] for c in free), min(c[1] for c in free), min(c[2] for c in free))
        chain.clear()
        return t

    krl_chain: list[tuple[float, float, float]] = []  # (time, cruise speed of the lead axis, a)

    def flush_krl() -> float:
        if not krl_chain:
            return 0.0
        t = sum(c[0] for c in krl_chain)
        t += krl_chain[0][1] / (2 * krl_chain[0][2]) + krl_chain[-1][1] / (2 * krl_chain[-1][2])
        krl_chain.clear()
        return t

    for i, st in enumerate(branch_taken(steps, verdict)):
        if isinstance(st, MoveJ):
            target = np.asarray(st.q, dtype=float)
            d = float(np.max(np.abs(target - q))) if len(q) == len(target) else math.inf
            if not math.isfinite(d):
                raise PlanningError(f"step {i}: joint move from an unknown position")
            if st.t > 0 and lang == "krl":
                total += flush()
                if axis_speed is None:
                    raise PlanningError(f"step {i}: a timed KRL PTP needs the axis speeds")
                pct = ptp_percent(q, target, st.t, axis_speed)
                speeds = np.asarray(axis_speed, dtype=float) * pct / 100.0
                seg = float(np.max(np.abs(target - q) / speeds))
                lead = int(np.argmax(np.abs(target - q) / speeds))
                krl_chain.append((seg, float(speeds[lead]) if seg > 0 else 0.0, st.a))
                if st.r <= 0:
                    total += flush_krl()
            else:
                total += flush_krl()
                chain.append((d, st.v, st.a, st.t))
                if st.r <= 0:
                    total += flush()
            q = target
            pos = None
        elif isinstance(st, MoveL):
            total += flush() + flush_krl()
            p1 = np.asarray(st.pose, dtype=float)[:3, 3]
            if pos is None:
                if tcp_of is None:
                    raise PlanningError(f"step {i}: movel after a joint move needs the TCP position (tcp_of)")
                pos = np.asarray(tcp_of(q), dtype=float)[:3, 3]
            total += trapezoid_time(float(np.linalg.norm(p1 - pos)), st.v, st.a)
            pos = p1
            q = np.asarray(st.q_end, dtype=float) if len(st.q_end) == len(q) else np.full_like(q, math.nan)
        elif isinstance(st, ServoJ):
            total += flush() + flush_krl()
            total += len(st.targets) * st.t
            q = np.asarray(st.targets, dtype=float)[-1]
            pos = None
        elif isinstance(st, SetOutputs):
            total += flush() + flush_krl() + st.settle_s
        elif isinstance(st, Wait):
            total += flush() + flush_krl() + st.seconds
        elif isinstance(st, WaitInput):
            total += flush() + flush_krl()  # the machine's time (door, cycle), not the robot's
        elif isinstance(st, Comment | ReadCorrection):  # reading the rack camera's correction: no motion
            continue
        else:
            raise PlanningError(f"step {i}: not a program step: {type(st).__name__}")
    return total + flush() + flush_krl()
