"""ABB RAPID and KUKA KRL posts: golden files, pose round trips, malformed steps."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from factory.core.errors import PlanningError
from robotprog.krl import krl_frame, krl_program, ptp_percent
from robotprog.rapid import rapid_module, rapid_pose
from robotprog.urscript import Comment, MoveJ, MoveL, SetOutputs, Wait

GOLDEN = Path(__file__).parent / "golden"


def _pose(xyz, rotvec) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    t[:3, 3] = xyz
    return t


def _steps():
    down = _pose([0.45, -0.12, 0.3], [math.pi, 0.0, 0.0])
    return [
        MoveJ((0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0), 1.5, 1.0),
        Comment("load: approach stock"),
        MoveL.to(down, 0.5, 0.1),
        SetOutputs(((0, True),), 0.4, "grip"),
        MoveL.to(_pose([0.45, -0.12, 0.4], [math.pi, 0.0, 0.3]), 0.5, 0.25, r=0.01),
        MoveJ((0.5, -1.2, 1.4, -1.7, -1.5708, 0.25), 1.5, 1.0, r=0.02),
        MoveJ((0.55, -1.15, 1.35, -1.7, -1.5708, 0.3), 1.5, 1.0, r=0.005, t=0.25),
        MoveJ((0.6, -1.1, 1.3, -1.7, -1.5708, 0.35), 1.5, 1.0, t=0.25),
        Wait(1.5),
        SetOutputs(((0, False), (3, True)), 0.0),
    ]


#: 100 % axis speeds of the golden KRL program [rad/s].
AXIS_SPEED = np.full(6, 3.15)


def _tcp() -> np.ndarray:
    return _pose([0.0, 0.0, 0.15], [0.0, 0.0, 0.0])


def test_rapid_golden():
    text = rapid_module(_steps(), name="tending", transform_flange_to_tcp=_tcp(), header=("golden test",))
    assert text == (GOLDEN / "tending.mod").read_text()
    assert text == rapid_module(_steps(), name="tending", transform_flange_to_tcp=_tcp(), header=("golden test",))


def test_krl_golden():
    src, dat = krl_program(_steps(), name="tending", transform_flange_to_tcp=_tcp(), axis_percent=50.0,
                           axis_speed=AXIS_SPEED, header=("golden test",))
    assert src == (GOLDEN / "tending.src").read_text()
    assert dat == (GOLDEN / "tending.dat").read_text()


def test_krl_every_point_used_is_declared():
    src, dat = krl_program(_steps(), name="tending", axis_speed=AXIS_SPEED)
    used = set(re.findall(r"^\s*(?:PTP|LIN) (\w+)(?: C_PTP)?$", src, re.M))
    declared = set(re.findall(r"DECL E6(?:AXIS|POS) (\w+)=", dat))
    assert used == declared and len(used) == 6
    assert src.count("$OUT[1] = TRUE") == 1 and "$OUT[4] = TRUE" in src


def test_rapid_every_target_declared():
    text = rapid_module(_steps(), name="tending")
    used = set(re.findall(r"Move(?:AbsJ|L) (\w+)[\\,]", text))
    declared = set(re.findall(r"CONST (?:jointtarget|robtarget) (\w+) :=", text))
    assert used == declared and len(used) == 6
    for z in re.findall(r", (z\w+), tGripper", text):
        assert f"CONST zonedata {z} :=" in text
    for v in re.findall(r", (v\w+)(?:\\T:=[\d.]+)?, (?:fine|z\w+), tGripper", text):
        assert f"CONST speeddata {v} :=" in text


_rot = st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3)
_pos = st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3)


@settings(max_examples=60, deadline=None)
@given(_pos, _rot)
def test_rapid_pose_round_trip(xyz, rotvec):
    t = _pose(xyz, rotvec)
    nums = [float(v) for v in re.findall(r"-?\d+(?:\.\d+)?", rapid_pose(t))]
    p, (w, x, y, z) = np.array(nums[:3]) / 1000.0, nums[3:]
    np.testing.assert_allclose(p, t[:3, 3], atol=1e-6)
    assert w >= 0
    np.testing.assert_allclose(Rotation.from_quat([x, y, z, w]).as_matrix(), t[:3, :3], atol=1e-5)


@settings(max_examples=60, deadline=None)
@given(_pos, _rot)
def test_krl_frame_round_trip(xyz, rotvec):
    t = _pose(xyz, rotvec)
    vals = dict((k, float(v)) for k, v in re.findall(r"([XYZABC]) (-?\d+(?:\.\d+)?)", krl_frame(t)))
    np.testing.assert_allclose([vals["X"], vals["Y"], vals["Z"]], t[:3, 3] * 1000.0, atol=1e-3)
    r = Rotation.from_euler("ZYX", [vals["A"], vals["B"], vals["C"]], degrees=True).as_matrix()
    np.testing.assert_allclose(r, t[:3, :3], atol=1e-5)


def test_malformed_steps_raise():
    with pytest.raises(PlanningError):
        rapid_module([MoveJ((0.0,) * 5, 1.0, 1.0)])
    with pytest.raises(PlanningError):
        krl_program([MoveJ((0.0,) * 5, 1.0, 1.0)])
    with pytest.raises(PlanningError):
        rapid_module([MoveL.to(np.eye(4), 0.5, 0.0)])
    with pytest.raises(PlanningError):
        krl_program([Wait(-1.0)])
    with pytest.raises(PlanningError):
        rapid_module([], name="9bad")
    with pytest.raises(PlanningError):
        krl_program([], name="a" * 25)
    with pytest.raises(PlanningError):
        krl_program([], axis_percent=0.0)
    with pytest.raises(PlanningError):
        rapid_module(["movej"])  # type: ignore[list-item]


def test_timed_moves_state_their_time():
    text = rapid_module(_steps(), name="tending")
    assert text.count("vJoint\\T:=0.25, zBlend5, tGripper;") == 1
    assert text.count("vJoint\\T:=0.25, fine, tGripper;") == 1
    src, _ = krl_program(_steps(), name="tending", axis_speed=AXIS_SPEED)
    # 0.05 rad in 0.25 s of 3.15 rad/s is 6.3 %: KRL takes whole percents, rounded up
    assert src.count("BAS(#VEL_PTP, 7)") == 1 and "$APO.CPTP = 50" in src
    with pytest.raises(PlanningError, match="axis speeds"):
        krl_program(_steps(), name="tending")


def test_krl_ptp_percent_never_slower():
    a, b = np.zeros(6), np.array([0.3, -0.1, 0.0, 0.0, 0.0, 0.0])
    assert ptp_percent(a, b, 1.0, np.full(6, 3.0)) == 10
    assert ptp_percent(a, b, 0.999, np.full(6, 3.0)) == 11
    assert ptp_percent(a, a, 1.0, np.full(6, 3.0)) == 1
    assert ptp_percent(a, b, 0.01, np.full(6, 3.0)) == 100
