"""KUKA KRL programs (a ``.src`` and its ``.dat``) from the same steps as :mod:`robotprog.urscript`.

KRL speaks millimetres and degrees. ``MoveJ`` steps become ``PTP`` to an ``E6AXIS``
(the model's joint values in degrees as A1..A6: the cell must use the URDF of the robot
the program runs on), ``MoveL`` steps ``LIN`` to an ``E6POS``: the TCP position [mm] and
orientation as KUKA's A, B, C (intrinsic Z, Y', X'' Euler angles [deg]) in the robot's
base frame (``base_link``; ``$BASE`` is ``$NULLFRAME``), without Status/Turn (the
controller keeps the current configuration on a LIN). Digital output ``n`` is KRL's
``$OUT[n + 1]`` (KRL numbers outputs from 1). The TCP is written to ``$TOOL``.

Speeds: PTP moves at ``$VEL_AXIS`` / ``$ACC_AXIS`` percentages (``axis_percent``),
LIN at ``$VEL.CP`` = the step's ``v`` [m/s]; all moves stop exactly (no ``C_DIS``).
Output is deterministic: fixed decimals, no time stamps.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from factory.errors import PlanningError
from robotprog.urscript import Comment, MoveJ, MoveL, SetOutputs, Step, Wait

DECIMALS_MM = 3
DECIMALS_DEG = 4


def _f(x: float, d: int) -> str:
    s = f"{round(float(x), d):.{d}f}"
    return "0.0" if float(s) == 0 else (s.rstrip("0") + "0" if s.rstrip("0").endswith(".") else s.rstrip("0"))


def krl_frame(t: np.ndarray) -> str:
    """``X .., Y .., Z .., A .., B .., C ..`` of a (4, 4) transform (translation [m] -> [mm])."""
    t = np.asarray(t, dtype=float)
    if t.shape != (4, 4) or not np.isfinite(t).all():
        raise PlanningError(f"pose must be a finite 4x4 transform, got shape {t.shape}")
    a, b, c = Rotation.from_matrix(t[:3, :3]).as_euler("ZYX", degrees=True)
    x, y, z = (v * 1000.0 for v in t[:3, 3])
    vals = [("X", x, DECIMALS_MM), ("Y", y, DECIMALS_MM), ("Z", z, DECIMALS_MM),
            ("A", a, DECIMALS_DEG), ("B", b, DECIMALS_DEG), ("C", c, DECIMALS_DEG)]
    return ",".join(f"{k} {_f(v, d)}" for k, v, d in vals)


def krl_program(
    steps: Sequence[Step],
    *,
    name: str = "factory_program",
    transform_flange_to_tcp: np.ndarray | None = None,
    axis_percent: float = 50.0,
    header: Sequence[str] = (),
) -> tuple[str, str]:
    """The ``.src`` and ``.dat`` texts of a KRL program.

    Parameters
    ----------
    steps : sequence of MoveJ, MoveL, SetOutputs, Wait, Comment
        Joint angles [rad] (6 per MoveJ), poses base_link -> TCP [m].
    name : str
        Program name (the ``DEF`` and ``DEFDAT`` name; KRL allows 24 characters).
    transform_flange_to_tcp : (4, 4) float, optional
        The TCP (default: the flange).
    axis_percent : float
        ``$VEL_AXIS`` and ``$ACC_AXIS`` for PTP moves [%], in (0, 100].
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
    src += [f"; {h}" for h in header]
    pct = _f(axis_percent, 1)
    src += ["  BAS(#INITMOV, 0)", f"  $TOOL = {{{krl_frame(tcp)}}}", "  $BASE = $NULLFRAME",
            "  FOR I = 1 TO 6", f"    $VEL_AXIS[I] = {pct}", f"    $ACC_AXIS[I] = {pct}", "  ENDFOR"]
    nj = nl = 0
    for i, st in enumerate(steps):
        if isinstance(st, MoveJ):
            q = np.asarray(st.q, dtype=float)
            if q.shape != (6,) or not np.isfinite(q).all():
                raise PlanningError(f"step {i}: PTP needs 6 finite joint angles, got {st.q}")
            nj += 1
            axes = ",".join(f"A{k + 1} {_f(math.degrees(v), DECIMALS_DEG)}" for k, v in enumerate(q))
            dat.append(f"  DECL E6AXIS XJ{nj}={{{axes},E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}}")
            src.append(f"  PTP XJ{nj}")
        elif isinstance(st, MoveL):
            if not (math.isfinite(st.v) and st.v > 0):
                raise PlanningError(f"step {i}: LIN speed must be finite and > 0, got {st.v}")
            nl += 1
            dat.append(f"  DECL E6POS XP{nl}={{{krl_frame(np.asarray(st.pose))},"
                       "E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}")
            src.append(f"  $VEL.CP = {_f(st.v, 4)}")
            src.append(f"  LIN XP{nl}")
        elif isinstance(st, SetOutputs):
            if st.label:
                src.append(f"  ; {st.label}")
            for n, level in st.outputs:
                if n < 0:
                    raise PlanningError(f"step {i}: digital output {n} is negative")
                src.append(f"  $OUT[{n + 1}] = {'TRUE' if level else 'FALSE'}")
            if st.settle_s > 0:
                src.append(f"  WAIT SEC {_f(st.settle_s, 3)}")
        elif isinstance(st, Wait):
            if not (math.isfinite(st.seconds) and st.seconds > 0):
                raise PlanningError(f"step {i}: wait must be finite and > 0, got {st.seconds}")
            src.append(f"  WAIT SEC {_f(st.seconds, 3)}")
        elif isinstance(st, Comment):
            src.append(f"  ; {st.text.splitlines()[0] if st.text else ''}")
        else:
            raise PlanningError(f"step {i}: not a program step: {type(st).__name__}")
    src.append("END")
    dat.append("ENDDAT")
    return "\n".join(src) + "\n", "\n".join(dat) + "\n"
