"""KUKA KRL programs (a ``.src`` and its ``.dat``) from the same steps as :mod:`robotprog.urscript`.

KRL speaks millimetres and degrees. ``MoveJ`` steps become ``PTP`` to an ``E6AXIS``
(the model's joint values in degrees as A1..A6: the cell must use the URDF of the robot
the program runs on), ``MoveL`` steps ``LIN`` to an ``E6POS``: the TCP position [mm] and
orientation as KUKA's A, B, C (intrinsic Z, Y', X'' Euler angles [deg]) in the robot's
base frame (``base_link``; ``$BASE`` is ``$NULLFRAME``), without Status/Turn (the
controller keeps the current configuration on a LIN). Digital output ``n`` is KRL's
``$OUT[n + 1]``, input ``n`` is ``$IN[n + 1]`` (KRL numbers them from 1). The TCP is written to ``$TOOL``.

The rack camera's correction (:class:`robotprog.urscript.ReadCorrection`) is the global ``FRAME``
``RACK_CORR`` the ``.dat`` declares (``DECL GLOBAL``: the cell's controller writes it before each
pick, e.g. through the KUKA.Ethernet KRL or a PLC's variable server): X, Y [mm] and A [deg] of the
blank in its slot. A corrected ``LIN`` runs with ``$BASE = RACK_SLOT : RACK_CORR`` to a point in the
slot's frame; ``$BASE`` goes back to ``$NULLFRAME`` for the next uncorrected one. In a rack of
several slots the controller also writes the slot the blank stands in (global ``INT`` ``RACK_ROW``,
``RACK_COLUMN``); the program halts on one outside the rack and runs the corrected ``LIN`` s with
``$BASE = RACK_SLOT : RACK_STEP : RACK_CORR``, ``RACK_STEP`` the whole pitches to that slot.

Speeds: PTP moves at ``$VEL_AXIS`` / ``$ACC_AXIS`` percentages (``axis_percent``), a
timed step (``t`` > 0) at the percentage that runs it in ``t`` (``BAS(#VEL_PTP, pct)``),
LIN at ``$VEL.CP`` = the step's ``v`` [m/s]. A step with a blend radius is approximated
(``C_PTP``, ``$APO.CPTP``), the rest stop exactly.
Output is deterministic: fixed decimals, no time stamps.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from factory.core.errors import PlanningError
from factory.core.units import MM_PER_M
from robotprog.urscript import (Branch, FlowWords, MoveJ, MoveL, ReadCorrection, Step, check_bounds, check_io_step,
                                comment_text, flat_steps, flow_lines, way_lines)

DECIMALS_MM = 3
DECIMALS_DEG = 4
#: ``$APO.CPTP`` [%] for blended (``C_PTP``) PTP moves: approximation starts this far (as a
#: percentage of the largest axis travel, at most half the move) before the point.
APPROXIMATION_PERCENT = 50


def ptp_percent(q_from: np.ndarray, q_to: np.ndarray, t: float, axis_speed: np.ndarray) -> int:
    """The whole ``$VEL_AXIS`` percentage (1..100) at which a PTP from ``q_from`` to ``q_to``
    [rad] takes at most ``t`` [s] at cruise: the leading axis needs ``|dq| / t`` of its 100 %
    speed ``axis_speed`` [rad/s]; rounded up (KRL takes whole percents), so never slower."""
    need = float(np.max(np.abs(np.asarray(q_to, float) - np.asarray(q_from, float)) / (t * np.asarray(axis_speed))))
    return int(min(100, max(1, math.ceil(100.0 * need - 1e-9))))


def _f(x: float, d: int) -> str:
    s = f"{round(float(x), d):.{d}f}"
    return "0.0" if float(s) == 0 else (s.rstrip("0") + "0" if s.rstrip("0").endswith(".") else s.rstrip("0"))


def krl_frame(t: np.ndarray) -> str:
    """``X .., Y .., Z .., A .., B .., C ..`` of a (4, 4) transform (translation [m] -> [mm])."""
    t = np.asarray(t, dtype=float)
    if t.shape != (4, 4) or not np.isfinite(t).all():
        raise PlanningError(f"pose must be a finite 4x4 transform, got shape {t.shape}")
    a, b, c = Rotation.from_matrix(t[:3, :3]).as_euler("ZYX", degrees=True)
    x, y, z = (v * MM_PER_M for v in t[:3, 3])
    vals = [("X", x, DECIMALS_MM), ("Y", y, DECIMALS_MM), ("Z", z, DECIMALS_MM),
            ("A", a, DECIMALS_DEG), ("B", b, DECIMALS_DEG), ("C", c, DECIMALS_DEG)]
    return ",".join(f"{k} {_f(v, d)}" for k, v, d in vals)


def _krl_input(n: int, level: bool) -> str:
    return f"{'' if level else 'NOT '}$IN[{n + 1}]"


_KRL_WORDS = FlowWords(
    comment=lambda text: f"  ; {comment_text(text)}".rstrip(),
    set_output=lambda n, level: f"  $OUT[{n + 1}] = {'TRUE' if level else 'FALSE'}",
    sleep=lambda s: f"  WAIT SEC {_f(s, 3)}",
    wait_input=lambda n, level: [f"  WAIT FOR {_krl_input(n, level)}"],
    if_input=lambda n, level: f"  IF {_krl_input(n, level)} THEN",
    else_line="  ELSE",
    end_if="  ENDIF",
)


def _lin_pose(st: MoveL, i: int, reads: list[ReadCorrection]) -> np.ndarray:
    """A LIN's point (4, 4) [m]: in the robot's base frame, or a corrected one in the rack slot's frame
    (``reads``: the corrections read so far)."""
    if not st.corrected:
        return np.asarray(st.pose, dtype=float)
    if not reads:
        raise PlanningError(f"step {i}: a corrected LIN before the correction is read")
    return np.linalg.inv(np.asarray(reads[-1].slot, dtype=float)) @ np.asarray(st.pose, dtype=float)


#: The frame the corrected LINs run in: the plan's rack slot, moved to the slot the blank stands in
#: when the rack has more than one (``RACK_STEP``), then the camera's correction.
_RACK_BASE = ("  $BASE = RACK_SLOT : RACK_CORR", "  $BASE = RACK_SLOT : RACK_STEP : RACK_CORR")


def _correction_decl(st: ReadCorrection) -> list[str]:
    """The ``.dat`` lines of the rack camera's correction: the global frame the cell's controller
    writes, the rack slot's frame, and with more than one slot the global row and column it writes
    and the step to that slot."""
    out = ["  DECL GLOBAL FRAME RACK_CORR={X 0.0,Y 0.0,Z 0.0,A 0.0,B 0.0,C 0.0}",
           f"  DECL FRAME RACK_SLOT={{{krl_frame(np.asarray(st.slot, dtype=float))}}}"]
    if st.slots:
        out += ["  DECL GLOBAL INT RACK_ROW=0", "  DECL GLOBAL INT RACK_COLUMN=0",
                "  DECL FRAME RACK_STEP={X 0.0,Y 0.0,Z 0.0,A 0.0,B 0.0,C 0.0}"]
    return out


def _correction_check(st: ReadCorrection) -> list[str]:
    """The ``.src`` lines that stop the program on a correction beyond the step's bounds (and on a
    slot outside the rack, then step to that slot)."""
    out = [f"  ; {comment_text(st.label)}".rstrip()] if st.label else []
    bounds = (_f(st.bounds[0] * MM_PER_M, DECIMALS_MM), _f(st.bounds[1] * MM_PER_M, DECIMALS_MM),
              _f(math.degrees(st.bounds[2]), DECIMALS_DEG))
    for axis, bound in zip("XYA", bounds):
        out += [f"  IF ABS(RACK_CORR.{axis}) > {bound} THEN", "    HALT", "  ENDIF"]
    if st.slots:
        for name, count in zip(("RACK_ROW", "RACK_COLUMN"), st.grid):
            for test in ("< 0", f"> {count - 1}"):
                out += [f"  IF {name} {test} THEN", "    HALT", "  ENDIF"]
        out += [f"  RACK_STEP.X = RACK_COLUMN * {_f(st.pitch[0] * MM_PER_M, DECIMALS_MM)}",
                f"  RACK_STEP.Y = RACK_ROW * {_f(st.pitch[1] * MM_PER_M, DECIMALS_MM)}"]
    return out


def krl_program(
    steps: Sequence[Step],
    *,
    name: str = "factory_program",
    transform_flange_to_tcp: np.ndarray | None = None,
    axis_percent: float = 50.0,
    axis_speed: np.ndarray | None = None,
    header: Sequence[str] = (),
) -> tuple[str, str]:
    """The ``.src`` and ``.dat`` texts of a KRL program.

    Parameters
    ----------
    steps : sequence of MoveJ, MoveL, SetOutputs, WaitInput, Wait, Comment, Branch
        Joint angles [rad] (6 per MoveJ), poses base_link -> TCP [m].
    name : str
        Program name (the ``DEF`` and ``DEFDAT`` name; KRL allows 24 characters).
    transform_flange_to_tcp : (4, 4) float, optional
        The TCP (default: the flange).
    axis_percent : float
        ``$VEL_AXIS`` and ``$ACC_AXIS`` for PTP moves [%], in (0, 100].
    axis_speed : (6,) float, optional
        The axes' 100 % speeds [rad/s]; needed by timed ``MoveJ`` steps (``t`` > 0), each of
        which gets the ``$VEL_AXIS`` percentage (:func:`ptp_percent`) that runs it in ``t``.
    header : sequence of str

    Raises
    ------
    PlanningError
        A malformed step, name or percentage.
    """
    if not name or not name.replace("_", "a").isalnum() or name[0].isdigit() or len(name) > 24:
        raise PlanningError(f"KRL program name must be letters, digits and underscores (<= 24), got {name!r}")
    if not 0 < axis_percent <= 100:
        raise PlanningError(f"axis_percent must be in (0, 100], got {axis_percent}")
    tcp = np.eye(4) if transform_flange_to_tcp is None else np.asarray(transform_flange_to_tcp, dtype=float)
    dat = ["&ACCESS RVP", f"DEFDAT {name} PUBLIC"]
    src = ["&ACCESS RVP", f"DEF {name}( )", "  DECL INT I"]
    src += [f"; {comment_text(h)}".rstrip() for h in header]
    pct_text = _f(axis_percent, 1)
    src += ["  BAS(#INITMOV, 0)", f"  $TOOL = {{{krl_frame(tcp)}}}", "  $BASE = $NULLFRAME",
            "  FOR I = 1 TO 6", f"    $VEL_AXIS[I] = {pct_text}", f"    $ACC_AXIS[I] = {pct_text}", "  ENDFOR"]
    if any(isinstance(st, MoveJ) and st.r > 0 for st in flat_steps(steps)):
        src.append(f"  $APO.CPTP = {APPROXIMATION_PERCENT}")
    nj = nl = 0
    q_prev: np.ndarray | None = None
    current_pct: int | None = None
    reads: list[ReadCorrection] = []
    in_slot = False  # $BASE is the corrected rack slot

    def emit(seq: Sequence[Step], out: list[str], first: int) -> None:
        nonlocal nj, nl, q_prev, current_pct, in_slot
        for i, st in enumerate(seq, first):
            check_io_step(i, st)
            if isinstance(st, MoveJ):
                q = np.asarray(st.q, dtype=float)
                if q.shape != (6,) or not np.isfinite(q).all():
                    raise PlanningError(f"step {i}: PTP needs 6 finite joint angles, got {st.q}")
                if in_slot:  # the corrected moves are over: back to the robot's base
                    out.append("  $BASE = $NULLFRAME")
                    in_slot = False
                nj += 1
                axes = ",".join(f"A{k + 1} {_f(math.degrees(v), DECIMALS_DEG)}" for k, v in enumerate(q))
                dat.append(f"  DECL E6AXIS XJ{nj}={{{axes},E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}}")
                if st.t > 0:
                    if q_prev is None or axis_speed is None:
                        raise PlanningError(f"step {i}: a timed PTP needs the axis speeds and a previous PTP")
                    percent = ptp_percent(q_prev, q, st.t, axis_speed)
                    if percent != current_pct:
                        out.append(f"  BAS(#VEL_PTP, {percent})")
                        current_pct = percent
                elif current_pct is not None:  # back to the program's axis speed after timed moves
                    out.append(f"  BAS(#VEL_PTP, {pct_text})")
                    current_pct = None
                out.append(f"  PTP XJ{nj}" + (" C_PTP" if st.r > 0 else ""))
                q_prev = q
            elif isinstance(st, MoveL):
                if not (math.isfinite(st.v) and st.v > 0):
                    raise PlanningError(f"step {i}: LIN speed must be finite and > 0, got {st.v}")
                nl += 1
                if st.corrected != in_slot:
                    out.append(_RACK_BASE[reads[-1].slots] if st.corrected and reads else "  $BASE = $NULLFRAME")
                    in_slot = st.corrected
                dat.append(f"  DECL E6POS XP{nl}={{{krl_frame(_lin_pose(st, i, reads))},"
                           "E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}")
                out.append(f"  $VEL.CP = {_f(st.v, 4)}")
                out.append(f"  LIN XP{nl}")
            elif isinstance(st, ReadCorrection):
                check_bounds(st, i)
                if not reads:
                    dat[2:2] = _correction_decl(st)
                reads.append(st)
                out += _correction_check(st)
            elif isinstance(st, Branch):
                at, pct = q_prev, current_pct
                ends: list[tuple[np.ndarray | None, int | None]] = []

                def way(seq: Sequence[Step], first: int) -> list[str]:
                    # each way starts from where the arm stands at the IF, at the speed stated there
                    nonlocal q_prev, current_pct
                    q_prev, current_pct = at, pct
                    lines = way_lines(emit, seq, first)
                    ends.append((q_prev, current_pct))
                    return lines

                out += flow_lines(i, st, _KRL_WORDS, way)
                (then_end, then_pct), _ = ends
                # after the ENDIF the speed is whichever way ran: state it again before the next timed PTP
                q_prev = then_end if then_end is not None else q_prev
                current_pct = then_pct if then_pct == current_pct else -1
            else:
                lines_of = flow_lines(i, st, _KRL_WORDS, lambda seq, first: way_lines(emit, seq, first))
                if lines_of is None:
                    raise PlanningError(f"step {i}: not a program step: {type(st).__name__}")
                out += lines_of

    emit(steps, src, 0)
    src.append("END")
    dat.append("ENDDAT")
    return "\n".join(src) + "\n", "\n".join(dat) + "\n"
