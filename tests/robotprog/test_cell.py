"""The cell file: frozen dataclasses, errors that name the field, a plausible default cell."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

from factory.core.errors import CellError
from factory.core.resources import FIXTURES
from robotprog.cell import Cell, load_cell, read_cell, rpy_matrix
from robotprog.ik import ik_continuous
from robotprog.robots import load_robot

DEFAULT = FIXTURES / "cell.yaml"


@pytest.fixture(scope="module")
def raw() -> dict:
    return yaml.safe_load(DEFAULT.read_text())


def test_default_cell_loads() -> None:
    cell = load_cell(DEFAULT)
    assert isinstance(cell, Cell)
    assert cell.robot.model == "ur5" and len(cell.robot.home) == 6
    assert cell.gripper.io.grip == ((0, True),) and cell.gripper.io.release == ((0, False),)
    assert cell.rack.rows * cell.rack.columns == 6
    with pytest.raises(AttributeError):
        cell.name = "other"  # frozen


def test_rpy_is_fixed_axis_xyz() -> None:
    """R = Rz(yaw) Ry(pitch) Rx(roll): yaw pi/2 turns X into Y; roll pi/2 turns Y into Z."""
    np.testing.assert_allclose(rpy_matrix((0, 0, np.pi / 2)) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(rpy_matrix((np.pi / 2, 0, 0)) @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    r = rpy_matrix((0.3, -0.7, 1.9))
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-15)


def _mutate(raw: dict, path: str, value) -> dict:
    data = copy.deepcopy(raw)
    keys = path.split(".")
    node = data
    for k in keys[:-1]:
        node = node[k]
    if value is _DELETE:
        del node[keys[-1]]
    else:
        node[keys[-1]] = value
    return data


_DELETE = object()


@pytest.mark.parametrize(
    "path, value, message",
    [
        ("vise.pose.xyz", [0.6, 0.0], r"vise\.pose\.xyz: expected 3 numbers"),
        ("vise.pose.xyz", [0.6, "a", 0.9], r"vise\.pose\.xyz\[1\]: expected a number"),
        ("vise.pose.rpz", [0, 0, 0], r"vise\.pose\.rpz: unknown key"),
        ("vise.jaw_heigth", 0.04, r"vise\.jaw_heigth: unknown key"),
        ("vise.jaw_height", _DELETE, r"vise\.jaw_height: missing"),
        ("vise.jaw_width", 0, r"vise\.jaw_width: must be > 0, got 0"),
        ("vise.parallels_height", -0.01, r"vise\.parallels_height: must be >= 0"),
        ("vise.parallels_height", 0.05, r"vise\.parallels_height: 0\.05 m reaches the jaws' top \(0\.0445 m above the "
                                        r"bed\): the jaws would grip nothing"),
        ("vise.soft_jaws.kind", "magnet", r"vise\.soft_jaws\.kind: expected one of pocket, parallels, got 'magnet'"),
        ("vise.soft_jaws.depth", 0, r"vise\.soft_jaws\.depth: must be > 0"),
        ("vise.soft_jaws.shape", 1, r"vise\.soft_jaws\.shape: unknown key"),
        ("rack.rows", 0, r"rack\.rows: must be >= 1"),
        ("rack.pitch", [0.08, -0.08], r"rack\.pitch\[1\]: must be > 0"),
        ("motion.speed_scaling", 1.5, r"motion\.speed_scaling: must be in \(0, 1\]"),
        ("motion.acceleration_limits", [3, 3, 3], r"motion\.acceleration_limits: expected 6 numbers"),
        ("gripper.io.grip", {0: "yes"}, r"gripper\.io\.grip\.0: expected true or false"),
        ("gripper.opening.max", -0.01, r"gripper\.opening\.max: must be > 0"),
        ("enclosure.walls", [], r"enclosure\.walls: expected a list of boxes"),
        ("enclosure.door.size", [0.02, 0.7, 0], r"enclosure\.door\.size\[2\]: must be > 0"),
        ("format", "factory.cell/9", r"format: expected 'factory.cell/1'"),
        ("robotz", {}, r"robotz: unknown key"),
        ("gripper.fingers.length", 0, r"gripper\.fingers\.length: must be > 0"),
        ("gripper.fingers.stroke", 0.02, r"gripper\.fingers\.stroke: two fingers of 0\.02 m stroke cannot open"),
        ("gripper.body.size", [0.09, 0.12, 0.16], r"gripper\.body: reaches 27\.5 mm past the fingers' root"),
        ("gripper.collision", {}, r"gripper\.collision: unknown key"),
        ("machine.io.outputs.open_door", 0, r"machine\.io\.outputs\.open_door: output 0 already drives the gripper"),
        ("machine.io.outputs.cycle_start", 1, r"machine\.io\.outputs\.open_door: output 1 is also cycle_start|"
                                              r"machine\.io\.outputs\.cycle_start: output 1 is also open_door"),
        ("machine.io.inputs.cycle_done", 0, r"machine\.io\.inputs\.cycle_done: input 0 is also door_open"),
        ("reject_bin.size", [0.3, 0.3], r"reject_bin\.size: expected 3 numbers"),
        ("robot.payload", 0, r"robot\.payload: must be > 0"),
        ("gripper.mass", 5.0, r"gripper\.mass: 5 kg leaves nothing of the robot's 5 kg payload"),
    ],
)
def test_errors_name_the_field(raw: dict, path: str, value, message: str) -> None:
    with pytest.raises(CellError, match=message) as e:
        read_cell(_mutate(raw, path, value), source="cell.yaml")
    assert str(e.value).startswith("cell.yaml: ") and "\n" not in str(e.value)


def test_default_vise_grips_5_mm_and_old_vise_sections_still_read(raw: dict) -> None:
    vise = read_cell(raw).vise
    assert vise.grip_depth == pytest.approx(0.005) and vise.jaw_width == pytest.approx(0.1524)
    assert vise.soft_jaws is not None and vise.soft_jaws.kind == "parallels"
    old = copy.deepcopy(raw)
    for k in ("jaw_width", "jaw_thickness", "parallels_height", "soft_jaws"):
        del old["vise"][k]
    v = read_cell(old).vise
    # Before parallels were written down, the jaws' height was measured from the stock's bottom.
    assert v.grip_depth == v.jaw_height and v.soft_jaws is None


def test_home_is_checked_against_the_robot(raw: dict, tmp_path: Path) -> None:
    bad = _mutate(raw, "robot.home", [0.0, 0.0, 4.0, 0.0, 0.0, 0.0])
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(bad))
    with pytest.raises(CellError, match=r"robot\.home\[2\]: 4\.0 rad outside the joint limits"):
        load_cell(path)
    short = _mutate(raw, "robot.home", [0.0] * 7)
    short["motion"]["acceleration_limits"] = [3.0] * 7
    path.write_text(yaml.safe_dump(short))
    with pytest.raises(CellError, match=r"robot\.home: expected 6 numbers for ur5"):
        load_cell(path)


def test_unknown_robot_in_cell(raw: dict, tmp_path: Path) -> None:
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(_mutate(raw, "robot.model", "ur55")))
    with pytest.raises(CellError, match="unknown robot 'ur55'"):
        load_cell(path)


def test_unreadable_files(tmp_path: Path) -> None:
    with pytest.raises(CellError, match="cannot read"):
        load_cell(tmp_path / "missing.yaml")
    (tmp_path / "bad.yaml").write_text("robot: [unclosed\n")
    with pytest.raises(CellError, match="not valid YAML"):
        load_cell(tmp_path / "bad.yaml")


def test_slots_outside_the_grid() -> None:
    cell = load_cell(DEFAULT, check_robot=False)
    with pytest.raises(CellError, match=r"no slot \(2, 0\)"):
        cell.rack.slot_transform(2, 0)


SAMPLE_CELLS = ["cell.yaml", "cell_abb.yaml", "cell_kuka.yaml"]


@pytest.mark.parametrize("name", SAMPLE_CELLS)
def test_default_cell_is_reachable(name: str) -> None:
    """With the gripper pointing down, the UR5 (and the ABB and KUKA arms of the sample cells)
    reaches every rack and tray slot and the vise, at grasp height and 15 cm above (the approach)."""
    cell = load_cell(FIXTURES / name)
    robot = load_robot(cell.robot.model, flange_frame=cell.robot.flange_frame)
    t_world_base = cell.robot.base.matrix()
    t_flange_tcp = cell.gripper.tcp.matrix()
    down = np.diag([1.0, -1.0, -1.0, 1.0])
    targets = [cell.vise.pose.matrix()]
    targets += [
        g.slot_transform(r, c) for g in (cell.rack, cell.out_tray) for r in range(g.rows) for c in range(g.columns)
    ]
    q = np.array(cell.robot.home)
    for t_world_place in targets:
        for lift in (0.03, 0.15):
            t = t_world_place @ down
            t[2, 3] += lift
            t_base_flange = np.linalg.inv(t_world_base) @ t @ np.linalg.inv(t_flange_tcp)
            q = ik_continuous(robot, t_base_flange, q)  # raises PlanningError if out of reach
            np.testing.assert_allclose(t_world_base @ robot.fk(q) @ t_flange_tcp, t, atol=1e-9)


def test_default_cell_layout_is_consistent() -> None:
    """The vise sits inside the enclosure, behind the door; rack and tray outside it."""
    cell = load_cell(DEFAULT, check_robot=False)
    boxes = [*cell.enclosure.walls, cell.enclosure.door]
    lo = np.min([np.array(b.pose.xyz) - np.array(b.size) / 2 for b in boxes], axis=0)
    hi = np.max([np.array(b.pose.xyz) + np.array(b.size) / 2 for b in boxes], axis=0)
    vise = np.array(cell.vise.pose.xyz)
    assert (vise > lo).all() and (vise < hi).all()
    door = cell.enclosure.door
    assert door.pose.xyz[0] < vise[0]
    for g in (cell.rack, cell.out_tray):
        far = g.slot_transform(g.rows - 1, g.columns - 1)[:3, 3]
        assert far[0] < lo[0] and g.pose.xyz[0] < lo[0]
    # Every place the gripper goes lies within the UR5's 0.85 m reach of its shoulder.
    shoulder = np.array(cell.robot.base.xyz) + [0, 0, 0.089159]
    for p in [vise, *(g.slot_transform(r, c)[:3, 3] for g in (cell.rack, cell.out_tray)
                     for r in range(g.rows) for c in range(g.columns))]:
        assert np.linalg.norm(p - shoulder) < 0.85


@pytest.mark.parametrize("name, robot, maker", [("cell_abb.yaml", "abb_irb1200_5_90", "ABB"),
                                                ("cell_kuka.yaml", "kuka_kr6_r900_sixx", "KUKA")])
def test_abb_and_kuka_sample_cells(name: str, robot: str, maker: str) -> None:
    """The sample cells name their arm by a URDF beside them and keep cell.yaml's layout."""
    cell = load_cell(FIXTURES / name)
    arm = load_robot(cell.robot.model, flange_frame=cell.robot.flange_frame)
    assert arm.name == robot and arm.maker == maker and arm.dof == 6
    assert Path(cell.robot.model).is_file() and Path(cell.robot.model).parent.parent.name == "robots"
    default = load_cell(DEFAULT, check_robot=False)
    for part in ("gripper", "rack", "vise", "enclosure", "out_tray", "reject_bin", "machine"):
        assert getattr(cell, part) == getattr(default, part), part


def test_robot_urdf_key(raw: dict, tmp_path: Path) -> None:
    path = tmp_path / "cell.yaml"
    urdf = str(FIXTURES / "robots/abb_irb1200_5_90/abb_irb1200_5_90.urdf")
    both = _mutate(raw, "robot.urdf", urdf)
    path.write_text(yaml.safe_dump(both))
    with pytest.raises(CellError, match=r"robot: expected one of model .* or urdf"):
        load_cell(path)
    neither = _mutate(raw, "robot.model", _DELETE)
    path.write_text(yaml.safe_dump(neither))
    with pytest.raises(CellError, match=r"robot: expected one of model"):
        load_cell(path)
    path.write_text(yaml.safe_dump(_mutate(neither, "robot.urdf", "arm.xacro")))
    with pytest.raises(CellError, match=r"robot\.urdf: expected a path to a \.urdf file"):
        load_cell(path)
    path.write_text(yaml.safe_dump(_mutate(neither, "robot.urdf", "missing/arm.urdf")))
    with pytest.raises(CellError, match="URDF file not found") as e:
        load_cell(path)
    assert "\n" not in str(e.value)
    ok = _mutate(_mutate(neither, "robot.urdf", urdf), "robot.home", [0.0, 0.0, 0.0, 0.0, 1.5708, 0.0])
    ok["robot"]["flange_frame"] = "tool0"
    path.write_text(yaml.safe_dump(ok))
    assert load_cell(path).robot.model == urdf


def test_empty_document() -> None:
    with pytest.raises(CellError, match="cell: expected a mapping"):
        read_cell(None, source="empty.yaml")


def test_gripper_machine_io_and_reject_bin_are_read(raw: dict) -> None:
    cell = read_cell(raw)
    f = cell.gripper.fingers
    assert (f.length, f.width, f.thickness, f.stroke) == (0.045, 0.02, 0.008, 0.0425)
    assert 2 * f.stroke >= cell.gripper.opening_max - cell.gripper.opening_min
    (size_a, t_a), (size_b, t_b) = f.boxes(0.06)
    # inner faces 60 mm apart, tips in the TCP plane, reaching the finger length up
    assert t_a[1, 3] - f.thickness / 2 == pytest.approx(0.03) and t_b[1, 3] + f.thickness / 2 == pytest.approx(-0.03)
    assert t_a[2, 3] + size_a[2] / 2 == pytest.approx(0.0) and size_a[2] == f.length
    io = cell.machine
    assert (io.open_door, io.close_door, io.cycle_start, io.door_open, io.cycle_done) == (1, 2, 3, 0, 1)
    assert cell.reject_bin is not None and cell.reject_bin.name == "reject_bin"
    bare = {k: v for k, v in raw.items() if k not in ("machine", "reject_bin")}
    assert read_cell(bare).machine is None and read_cell(bare).reject_bin is None
