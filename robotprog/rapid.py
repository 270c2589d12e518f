"""ABB RAPID programs (one ``.mod`` module) from the same steps as :mod:`robotprog.urscript`.

RAPID speaks millimetres and degrees. ``MoveJ`` steps become ``MoveAbsJ`` to a
``jointtarget`` (the model's joint values in degrees: the cell must use the URDF of the
robot the program runs on, whose joint zeros match the controller's), ``MoveL`` steps a
``MoveL`` to a ``robtarget`` (TCP position [mm] and orientation quaternion ``[q1, q2, q3,
q4] = [w, x, y, z]`` in the robot's base frame, ``base_link``), with the configuration
``[cf1, cf4, cf6, cfx]`` left to the controller (``ConfL\\Off`` before the moves).
Digital outputs ``n`` are the signals ``do<n>``, inputs ``di<n>`` (named in the controller's
I/O configuration). The TCP is ``tGripper`` built from ``transform_flange_to_tcp``.

The rack camera's correction (:class:`robotprog.urscript.ReadCorrection`) is the object frame of the
work object ``wRack`` (``PERS wobjdata``: its user frame the rack slot, fixed; its object frame the
blank's offset in the slot, written by the cell's controller before each pick, e.g. over Robot Web
Services); a corrected ``MoveL`` goes to a robtarget in the slot's frame ``\\WObj:=wRack``. In a rack
of several slots the controller also writes the slot the blank stands in (``PERS num`` ``nRackRow``,
``nRackColumn``); the program stops on one outside the rack and sets the user frame to the plan's
slot ``pRackSlot`` moved by whole pitches to it.

Speeds: joint moves run at ``vJoint`` (TCP 1000 mm/s, the controller's axis limits govern),
or take the step's time ``t`` (``vJoint\\T:=t``: the controller stretches the move to last ``t``
seconds), and lines at their ``v`` [m/s] (``vLine<k>``), all ``fine`` (stop at each point) unless a
blend radius is given (``z<mm>`` zonedata, declared). Output is deterministic: fixed
decimals, no time stamps.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from factory.core.errors import PlanningError
from factory.core.units import MM_PER_M
from robotprog.urscript import (FlowWords, MoveJ, MoveL, ReadCorrection, Step, check_bounds, check_io_step,
                                comment_text, flow_lines, way_lines)

#: Decimals of millimetres and degrees (1 µm, 1e-4 deg) and quaternions.
DECIMALS_MM = 3
DECIMALS_DEG = 4
DECIMALS_QUAT = 6
_EXT = "[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]"


def _f(x: float, d: int) -> str:
    s = f"{round(float(x), d):.{d}f}"
    return "0" if float(s) == 0 else s.rstrip("0").rstrip(".")


def _name_ok(name: str) -> None:
    if not name or not name.replace("_", "a").isalnum() or name[0].isdigit() or len(name) > 32:
        raise PlanningError(f"RAPID module name must be letters, digits and underscores (<= 32), got {name!r}")


def _quat_wxyz(r: np.ndarray) -> list[float]:
    x, y, z, w = Rotation.from_matrix(r).as_quat()
    q = np.array([w, x, y, z])
    return list(-q if q[0] < 0 else q)


def rapid_pose(t: np.ndarray) -> str:
    """``[[x, y, z], [q1, q2, q3, q4]]`` of a (4, 4) transform (translation [m] -> [mm])."""
    t = np.asarray(t, dtype=float)
    if t.shape != (4, 4) or not np.isfinite(t).all():
        raise PlanningError(f"pose must be a finite 4x4 transform, got shape {t.shape}")
    p = ",".join(_f(v * MM_PER_M, DECIMALS_MM) for v in t[:3, 3])
    q = ",".join(_f(v, DECIMALS_QUAT) for v in _quat_wxyz(t[:3, :3]))
    return f"[[{p}],[{q}]]"


_RAPID_WORDS = FlowWords(
    comment=lambda text: f"    ! {comment_text(text)}".rstrip(),
    set_output=lambda n, level: f"    SetDO do{n}, {int(level)};",
    sleep=lambda s: f"    WaitTime {_f(s, 3)};",
    wait_input=lambda n, level: [f"    WaitDI di{n}, {int(level)};"],
    if_input=lambda n, level: f"    IF DInput(di{n}) = {int(level)} THEN",
    else_line="    ELSE",
    end_if="    ENDIF",
)


def rapid_module(
    steps: Sequence[Step],
    *,
    name: str = "factory_program",
    transform_flange_to_tcp: np.ndarray | None = None,
    tool_mass_kg: float = 1.0,
    header: Sequence[str] = (),
) -> str:
    """The RAPID module text of a program with a ``main`` procedure.

    Parameters
    ----------
    steps : sequence of MoveJ, MoveL, SetOutputs, WaitInput, Wait, Comment, Branch
        Joint angles [rad] (6 per MoveJ), poses base_link -> TCP [m].
    name : str
        Module name.
    transform_flange_to_tcp : (4, 4) float, optional
        The TCP (default: the flange).
    tool_mass_kg : float
        Tool load mass for ``tooldata`` [kg] (centre of gravity at the TCP's half height).
    header : sequence of str
        Comment lines.

    Raises
    ------
    PlanningError
        A malformed step or name.
    """
    _name_ok(name)
    tcp = np.eye(4) if transform_flange_to_tcp is None else np.asarray(transform_flange_to_tcp, dtype=float)
    decl: list[str] = []
    body: list[str] = []
    speeds: dict[str, str] = {}
    zones: dict[str, str] = {}
    nj = nl = 0
    rack: list[str] = []  # the wRack declaration, once the correction is read
    slot_of: list[np.ndarray] = []

    def emit(seq: Sequence[Step], out: list[str], first: int) -> None:
        nonlocal nj, nl
        for i, st in enumerate(seq, first):
            check_io_step(i, st)
            if isinstance(st, MoveJ):
                q = np.asarray(st.q, dtype=float)
                if q.shape != (6,) or not np.isfinite(q).all():
                    raise PlanningError(f"step {i}: MoveAbsJ needs 6 finite joint angles, got {st.q}")
                nj += 1
                deg = ",".join(_f(math.degrees(v), DECIMALS_DEG) for v in q)
                decl.append(f"  CONST jointtarget j{nj} := [[{deg}],{_EXT}];")
                if st.t > 0:
                    if not math.isfinite(st.t):
                        raise PlanningError(f"step {i}: MoveAbsJ time must be finite, got {st.t}")
                    speed = f"vJoint\\T:={_f(st.t, 4)}"
                else:
                    speed = "vJoint"
                out.append(f"    MoveAbsJ j{nj}\\NoEOffs, {speed}, {_zone(st.r, zones)}, tGripper;")
            elif isinstance(st, MoveL):
                if not (math.isfinite(st.v) and st.v > 0):
                    raise PlanningError(f"step {i}: MoveL speed must be finite and > 0, got {st.v}")
                nl += 1
                pose = np.asarray(st.pose, dtype=float)
                if st.corrected:
                    if not slot_of:
                        raise PlanningError(f"step {i}: a corrected MoveL before the correction is read")
                    pose = np.linalg.inv(slot_of[-1]) @ pose  # in the rack slot's frame, wRack's user frame
                decl.append(f"  CONST robtarget p{nl} := [{rapid_pose(pose)[1:-1]},[0,0,0,0],{_EXT}];")
                v = _f(st.v * MM_PER_M, 1)
                sname = f"vLine{v.replace('.', '_')}"
                speeds[sname] = f"  CONST speeddata {sname} := [{v},500,5000,1000];"
                wobj = "\\WObj:=wRack" if st.corrected else ""
                out.append(f"    MoveL p{nl}, {sname}, {_zone(st.r, zones)}, tGripper{wobj};")
            elif isinstance(st, ReadCorrection):
                check_bounds(st, i)
                slot_of.append(np.asarray(st.slot, dtype=float))
                rack[:] = [f"  PERS wobjdata wRack := [FALSE,TRUE,\"\",{rapid_pose(slot_of[-1])},[[0,0,0],[1,0,0,0]]];"]
                bx, by = (_f(b * MM_PER_M, DECIMALS_MM) for b in st.bounds[:2])
                byaw = _f(math.degrees(st.bounds[2]), DECIMALS_DEG)
                out += [f"    ! {comment_text(st.label)}".rstrip()] if st.label else []
                out += [f"    IF Abs(wRack.oframe.trans.x) > {bx} OR Abs(wRack.oframe.trans.y) > {by} "
                        f"OR Abs(EulerZYX(\\Z, wRack.oframe.rot)) > {byaw} THEN",
                        '      ErrWrite "rack camera", "correction beyond the rack slot";',
                        "      Stop;", "    ENDIF"]
                if st.slots:  # the user frame: the plan's slot moved to the one the blank stands in
                    rows, columns = st.grid
                    rack.extend(["  PERS num nRackRow := 0;", "  PERS num nRackColumn := 0;",
                                 f"  CONST pose pRackSlot := {rapid_pose(slot_of[-1])};"])
                    px, py = (_f(v * MM_PER_M, DECIMALS_MM) for v in st.pitch)
                    out += [f"    IF nRackRow < 0 OR nRackRow > {rows - 1} OR nRackColumn < 0 "
                            f"OR nRackColumn > {columns - 1} THEN",
                            '      ErrWrite "rack camera", "rack slot beyond the rack";', "      Stop;", "    ENDIF",
                            f"    wRack.uframe := PoseMult(pRackSlot, [[nRackColumn * {px}, nRackRow * {py}, 0], "
                            "[1, 0, 0, 0]]);"]
            else:
                lines_of = flow_lines(i, st, _RAPID_WORDS, lambda seq, first: way_lines(emit, seq, first))
                if lines_of is None:
                    raise PlanningError(f"step {i}: not a program step: {type(st).__name__}")
                out += lines_of

    emit(steps, body, 0)
    cog = _f(tcp[2, 3] * 500.0, DECIMALS_MM)
    lines = [f"MODULE {name}"]
    lines += [f"  ! {comment_text(h)}".rstrip() for h in header]
    lines.append(f"  PERS tooldata tGripper := [TRUE,{rapid_pose(tcp)},[{_f(tool_mass_kg, 3)},[0,0,{cog}],"
                 "[1,0,0,0],0,0,0]];")
    lines.append("  CONST speeddata vJoint := [1000,500,5000,1000];")
    lines += rack
    lines += [speeds[k] for k in sorted(speeds)]
    lines += [zones[k] for k in sorted(zones)]
    lines += decl
    lines += ["", "  PROC main()", "    ConfJ\\Off;", "    ConfL\\Off;"] + body + ["  ENDPROC", "ENDMODULE"]
    return "\n".join(lines) + "\n"


def _zone(r: float, zones: dict[str, str]) -> str:
    if not r > 0:
        return "fine"
    mm = _f(r * MM_PER_M, 1)
    name = f"zBlend{mm.replace('.', '_')}"
    zones[name] = f"  CONST zonedata {name} := [FALSE,{mm},{mm},{mm},{_f(r * 100.0, 2)},{mm},{_f(r * 100.0, 2)}];"
    return name
