"""URScript: deterministic text, golden file, poses in the controller's base frame."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from factory.core.errors import PlanningError
from factory.core.resources import FIXTURES
from robotprog.cell import load_cell
from robotprog.ik import TRANSFORM_BASE_LINK_TO_UR_BASE
from robotprog.robots import load_robot
from robotprog.urscript import (SERVO_TABLE_ROWS, Comment, MoveJ, MoveL, ServoJ, SetOutputs, Wait, ur_pose,
                                urscript_program)

GOLDEN = Path(__file__).parent / "golden"


def _pick_from_rack_program() -> str:
    """Home → above rack slot (0, 1) → down → grip → up → home, from the default cell."""
    cell = load_cell(FIXTURES / "cell.yaml", check_robot=False)
    t_base_world = np.linalg.inv(cell.robot.base.matrix())
    down = np.diag([1.0, -1.0, -1.0, 1.0])
    slot = cell.rack.slot_transform(0, 1) @ down

    def above(h: float) -> np.ndarray:
        t = slot.copy()
        t[2, 3] += h
        return t_base_world @ t

    io = cell.gripper.io
    steps = [
        Comment("pick blank from rack slot (0, 1)"),
        MoveJ(cell.robot.home, a=1.4, v=1.05),
        SetOutputs(io.release, io.settle_s, "open gripper"),
        MoveL.to(above(0.15), a=1.2, v=0.25, r=0.01),
        MoveL.to(above(0.03), a=0.5, v=0.05),
        SetOutputs(io.grip, io.settle_s, "grip"),
        Wait(0.2),
        MoveL.to(above(0.15), a=0.5, v=0.1),
        MoveJ(cell.robot.home, a=1.4, v=1.05),
    ]
    return urscript_program(
        steps, name="pick_blank", transform_flange_to_tcp=cell.gripper.tcp.matrix(),
        header=["factory robot program", "units: m, rad, s"],
    )


def test_golden_pick_program() -> None:
    text = _pick_from_rack_program()
    golden = GOLDEN / "pick_blank.script"
    if os.environ.get("FACTORY_UPDATE_GOLDEN"):
        golden.write_text(text)
    assert text == golden.read_text()


def test_program_text_is_deterministic() -> None:
    assert _pick_from_rack_program() == _pick_from_rack_program()


def test_movel_pose_is_in_the_controller_base_frame() -> None:
    """A ROS base_link pose is turned by pi about Z; URScript's rotation vector is axis * angle."""
    t = np.eye(4)
    t[:3, :3] = Rotation.from_euler("xyz", [0.3, -0.2, 1.1]).as_matrix()
    t[:3, 3] = [0.4, 0.1, 0.3]
    line = urscript_program([MoveL.to(t, a=1.0, v=0.1)]).splitlines()[1]
    nums = [float(x) for x in re.search(r"p\[(.*?)\]", line).group(1).split(",")]
    ur = np.linalg.inv(TRANSFORM_BASE_LINK_TO_UR_BASE) @ t
    np.testing.assert_allclose(nums[:3], [-0.4, -0.1, 0.3], atol=1e-6)
    np.testing.assert_allclose(Rotation.from_rotvec(nums[3:]).as_matrix(), ur[:3, :3], atol=5e-6)


def test_movel_matches_ur_controller_forward_kinematics() -> None:
    """The TCP pose URScript receives equals the DH (controller) pose of the UR5 at the same joints."""
    robot = load_robot("ur5")
    q = np.array([0.2, -1.3, 1.6, -1.8, -1.5, 0.4])
    t_base_link_tool0 = robot.fk(q)
    t_ur_base_tool0 = robot.frame_transform(q, "base", "tool0")
    line = urscript_program([MoveL.to(t_base_link_tool0, a=1.0, v=0.1)]).splitlines()[1]
    assert ur_pose(t_ur_base_tool0) in line


def test_gripper_io_and_waits() -> None:
    text = urscript_program([SetOutputs(((0, True), (1, False)), 0.4, "grip"), Wait(1.5)])
    assert text.splitlines()[1:-1] == [
        "  # grip",
        "  set_standard_digital_out(0, True)",
        "  set_standard_digital_out(1, False)",
        "  sleep(0.4)",
        "  sleep(1.5)",
    ]


def test_negative_zero_is_printed_as_zero() -> None:
    text = urscript_program([MoveJ((-0.0, -1e-9, 0.0, 0.0, 0.0, 0.0), a=1.0, v=1.0)])
    assert "movej([0.0, 0.0, 0.0, 0.0, 0.0, 0.0], a=1.0, v=1.0)" in text


@pytest.mark.parametrize(
    "steps, message",
    [
        ([MoveJ((0.0,) * 5, a=1.0, v=1.0)], "6 finite joint angles"),
        ([MoveJ((0.0,) * 6, a=0.0, v=1.0)], "movej a must be finite and > 0"),
        ([MoveL.to(np.eye(4), a=1.0, v=float("nan"))], "movel v"),
        ([SetOutputs(((9, True),))], "output 9 is not in 0..7"),
        (["movej"], "not a URScript step"),
        ([ServoJ(np.zeros((3, 5)), 0.008)], r"\(n, 6\) finite joint targets"),
        ([ServoJ(np.zeros((3, 6)), 0.0)], "servoj t must be finite"),
        ([ServoJ(np.zeros((3, 6)), 0.008, lookahead_time=0.01)], "lookahead_time"),
        ([ServoJ(np.zeros((3, 6)), 0.008, gain=50.0)], "gain"),
    ],
)
def test_bad_steps(steps, message) -> None:
    with pytest.raises(PlanningError, match=message):
        urscript_program(steps)


def test_bad_program_name() -> None:
    with pytest.raises(PlanningError, match="program name"):
        urscript_program([], name="1 bad-name")


def test_servoj_tables_stream_every_target_in_order() -> None:
    n = SERVO_TABLE_ROWS + 17
    targets = np.linspace(-1.0, 1.0, n)[:, None] * np.arange(1, 7) / 7.0
    text = urscript_program([ServoJ(targets, 0.008, 0.05, 400.0)])
    tables = re.findall(r"^  (table\d+) = (\[.*\])$", text, re.M)
    assert [t for t, _ in tables] == ["table1", "table2"]
    rows = np.concatenate([np.array(eval(body), dtype=float) for _, body in tables])  # noqa: S307
    np.testing.assert_allclose(rows, targets, atol=5e-7)
    assert re.findall(r"while k < (\d+):", text) == [str(SERVO_TABLE_ROWS), "17"]
    assert text.count("servoj(table1[k], 0, 0, 0.008, 0.05, 400.0)") == 1


def test_timed_movej_states_t_before_r() -> None:
    text = urscript_program([MoveJ((0.0,) * 6, a=1.0, v=1.0, r=0.01, t=0.25)])
    assert "movej([0.0, 0.0, 0.0, 0.0, 0.0, 0.0], a=1.0, v=1.0, t=0.25, r=0.01)" in text
