"""`factory robot` through typer's CliRunner: MCAP read back with rosbags, URScript, one-line errors."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml
from rosbags.highlevel import AnyReader
from typer.testing import CliRunner

from cli.main import app
from factory.core.resources import FIXTURES

SAMPLES = Path(__file__).resolve().parents[2] / "samples"
runner = CliRunner()


def _sheet(path: Path, part: Path, allowance: float = 2.0, top: float = 1.0) -> Path:
    """A setup sheet placing ``part`` in a stock box with ``allowance`` around and ``top`` above [mm]."""
    lo, hi = trimesh.load(part).bounds
    size = (hi - lo) + [2 * allowance, 2 * allowance, top]
    t = np.eye(4)
    t[:3, 3] = [allowance - lo[0], allowance - lo[1], -size[2] - lo[2]]
    path.write_text(json.dumps({
        "format": "factory.setup/1", "units": "mm", "work_origin": "top-front-left",
        "stock": {"min": [0, 0, -float(size[2])], "max": [float(size[0]), float(size[1]), 0],
                  "size": size.tolist()},
        "transform_mesh_to_work": t.tolist(), "mesh_scale": 1.0, "tools": []}))
    return path


def _cell(tmp: Path, edit) -> Path:
    data = yaml.safe_load((FIXTURES / "cell.yaml").read_text())
    edit(data)
    p = tmp / "cell.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("robot")
    part = SAMPLES / "bracket.stl"
    sheet = _sheet(tmp / "bracket.setup.json", part)
    out = tmp / "bracket.robot.mcap"
    script = tmp / "bracket.script"
    res = runner.invoke(app, ["robot", str(FIXTURES / "cell.yaml"), "--setup", str(sheet), "--part", str(part),
                              "-o", str(out), "--program", str(script), "--lang", "urscript", "--json"])
    return tmp, sheet, part, out, script, res


def test_robot_writes_mcap_and_urscript(run):
    tmp, sheet, part, out, script, res = run
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    assert summary["robot"] == "ur5" and len(summary["moves"]) == 18
    total = summary["duration_s"]
    assert total == pytest.approx(sum(m["duration_s"] for m in summary["moves"]), abs=0.01)
    text = script.read_text()
    assert text.startswith("def bracket():") and text.rstrip().endswith("end")
    assert text.count("set_standard_digital_out(0, True)") == 2
    # released in the vise, in the out-tray, and on the verdict's reject way in the bin
    assert text.count("set_standard_digital_out(0, False)") == 3
    assert text.count("if get_standard_digital_in(2) == True:") == 1
    # a movej to home, then the proven trajectory streamed, no unblended waypoints; except at the rack, where
    # the pick's three lines (over the blank, down, up) move at run time by the rack camera's correction and a
    # movej joins the planned retreat's end (robotprog.rackpick)
    assert text.count("movel(") == text.count("movel(pose_trans(rack_corr, ") == 3
    assert text.count("movej(") == 2 and "servoj(" in text
    assert summary["program_duration_s"] == pytest.approx(total, rel=0.05)
    assert f"controller {summary['program_duration_s']:.2f} s" in text

    with AnyReader([out]) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
        assert topics["/robot_description"] == "std_msgs/msg/String"
        assert topics["/joint_states"] == "sensor_msgs/msg/JointState"
        assert topics["/tf"] == "tf2_msgs/msg/TFMessage"
        assert topics["/tf_static"] == "tf2_msgs/msg/TFMessage"
        assert topics["/robot/trajectory"] == "trajectory_msgs/msg/JointTrajectory"
        assert topics["/cell/boxes"] == "visualization_msgs/msg/MarkerArray"
        assert topics["/robot/visuals"] == "foxglove_msgs/msg/SceneUpdate"
        by_topic: dict[str, list] = {}
        for conn, t, raw in reader.messages():
            by_topic.setdefault(conn.topic, []).append((t, reader.deserialize(raw, conn.msgtype)))
    urdf = by_topic["/robot_description"][0][1].data
    assert "<robot" in urdf
    # the vendor's package:// mesh URIs, never paths of the machine that wrote the log
    meshes = re.findall(r'<mesh filename="([^"]+)"', urdf)
    assert meshes and all(m.startswith("package://example-robot-data/") for m in meshes)
    # the meshes themselves travel in the log: one entity per link visual, locked to its link
    (scene,) = [m for _, m in by_topic["/robot/visuals"]]
    assert {e.frame_id for e in scene.entities} == {"base_link", "shoulder_link", "upper_arm_link", "forearm_link",
                                                    "wrist_1_link", "wrist_2_link", "wrist_3_link"}
    assert all(e.frame_locked and len(e.models) == 1 and e.models[0].media_type == "model/gltf-binary"
               and bytes(e.models[0].data[:4]) == b"glTF" and e.models[0].url == "" for e in scene.entities)
    states = by_topic["/joint_states"]
    assert len(states) == pytest.approx(total * 50, abs=20)
    times = [t for t, _ in states]
    assert times == sorted(times)
    home = [0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0]
    np.testing.assert_allclose(states[0][1].position, home, atol=1e-9)
    np.testing.assert_allclose(states[-1][1].position, home, atol=1e-9)
    assert list(states[0][1].name) == ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                                       "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
    tf = by_topic["/tf"]
    assert len(tf) == len(states)
    children = {x.child_frame_id for x in tf[0][1].transforms}
    assert {"shoulder_link", "forearm_link", "wrist_3_link", "tool0"} <= children
    static = {(x.header.frame_id, x.child_frame_id) for x in by_topic["/tf_static"][0][1].transforms}
    assert ("world", "base_link") in static and ("tool0", "tcp") in static
    trajs = by_topic["/robot/trajectory"]
    assert len(trajs) == 14
    last = trajs[-1][1].points[-1]
    np.testing.assert_allclose(last.positions, home, atol=1e-9)
    np.testing.assert_allclose(last.velocities, 0.0, atol=1e-9)
    tfs = [p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in trajs[0][1].points]
    assert tfs == sorted(tfs) and len(trajs[0][1].points[0].accelerations) == 6
    names = {m.text for m in by_topic["/cell/boxes"][0][1].markers}
    assert {"mill_table", "vise_body", "front_lower"} <= names


def test_existing_output_needs_overwrite(run):
    tmp, sheet, part, out, script, res = run
    before = out.read_bytes()
    again = runner.invoke(app, ["robot", str(FIXTURES / "cell.yaml"), "--setup", str(sheet), "-o", str(out)])
    assert again.exit_code == 1 and "error:" in again.output
    assert out.read_bytes() == before


def _fails(tmp: Path, cell: Path, sheet: Path, expect: str) -> None:
    out = tmp / "x.robot.mcap"
    prog = tmp / "x.script"
    res = runner.invoke(app, ["robot", str(cell), "--setup", str(sheet), "-o", str(out), "--program", str(prog)])
    assert res.exit_code == 1, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and expect in lines[0], res.output
    assert not out.exists() and not prog.exists()


def test_unknown_robot(tmp_path):
    sheet = _sheet(tmp_path / "p.setup.json", SAMPLES / "bracket.stl")
    cell = _cell(tmp_path, lambda d: d["robot"].update(model="ur99"))
    _fails(tmp_path, cell, sheet, "ur99")


def test_typo_in_cell_file(tmp_path):
    sheet = _sheet(tmp_path / "p.setup.json", SAMPLES / "bracket.stl")
    cell = _cell(tmp_path, lambda d: d["vise"].update(jaw_hieght=0.04))
    _fails(tmp_path, cell, sheet, "jaw_hieght")


@pytest.fixture
def no_roadmap(monkeypatch):
    """Fails the test if a plan asks for the cell's roadmap (building a new cell's takes minutes)."""
    import factory.tending

    def asked(*args, **kwargs):
        raise AssertionError("the cell's roadmap was asked for")

    monkeypatch.setattr(factory.tending, "cached_roadmap", asked)


def test_part_wider_than_gripper(tmp_path, no_roadmap):
    """Refused from the grasp, before the changed cell's roadmap would be built."""
    sheet = _sheet(tmp_path / "p.setup.json", SAMPLES / "bracket.stl")
    cell = _cell(tmp_path, lambda d: d["gripper"]["opening"].update(max=0.05))
    _fails(tmp_path, cell, sheet, "gripper.opening.max")


def test_unreachable_slot(tmp_path, no_roadmap):
    """Refused from the pose above the slot, before any transfer asks for the cell's roadmap."""
    sheet = _sheet(tmp_path / "p.setup.json", SAMPLES / "bracket.stl")
    cell = _cell(tmp_path, lambda d: d["rack"]["pose"].update(xyz=[1.6, -1.2, 0.8]))
    _fails(tmp_path, cell, sheet, "rack.pose")


def test_unknown_lang(tmp_path):
    sheet = _sheet(tmp_path / "p.setup.json", SAMPLES / "bracket.stl")
    res = runner.invoke(app, ["robot", str(FIXTURES / "cell.yaml"), "--setup", str(sheet), "-o",
                              str(tmp_path / "x.mcap"), "--program", str(tmp_path / "x.s"), "--lang", "cobol"])
    assert res.exit_code == 2
    assert not (tmp_path / "x.mcap").exists()


@pytest.mark.parametrize("lang, cell, files", [("rapid", "cell_abb.yaml", ["tending.mod"]),
                                               ("krl", "cell_kuka.yaml", ["tending.src", "tending.dat"])])
def test_rapid_and_krl_programs(run, tmp_path, lang, cell, files):
    """RAPID for the ABB sample cell, KRL for the KUKA one: each carries its own arm's joint values."""
    _tmp, sheet, _part, _out, _script, _res = run
    program = tmp_path / files[0]
    res = runner.invoke(app, ["robot", str(FIXTURES / cell), "--setup", str(sheet), "-o",
                              str(tmp_path / "t.mcap"), "--program", str(program), "--lang", lang, "--json"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    assert summary["robot"] == {"rapid": "abb_irb1200_5_90", "krl": "kuka_kr6_r900_sixx"}[lang]
    assert 0.95 * summary["duration_s"] <= summary["program_duration_s"] <= 1.05 * summary["duration_s"]
    texts = [(tmp_path / f).read_text() for f in files]
    if lang == "rapid":
        assert texts[0].startswith("MODULE tending") and texts[0].count("\\T:=") > 50
        assert texts[0].count("SetDO do0, 1;") == 2
    else:
        assert "DEF tending( )" in texts[0] and texts[0].count(" C_PTP") > 50
        assert texts[0].count("$OUT[1] = TRUE") == 2 and texts[1].startswith("&ACCESS RVP\nDEFDAT tending")


@pytest.mark.parametrize("lang, maker", [("rapid", "an ABB arm"), ("krl", "a KUKA arm")])
def test_rapid_and_krl_refused_for_the_ur5(run, tmp_path, lang, maker):
    """The UR5's joint values mean nothing to an ABB or KUKA controller: one line, nothing written."""
    _tmp, sheet, _part, _out, _script, _res = run
    out, prog = tmp_path / "x.robot.mcap", tmp_path / "x.prog"
    res = runner.invoke(app, ["robot", str(FIXTURES / "cell.yaml"), "--setup", str(sheet), "-o", str(out),
                              "--program", str(prog), "--lang", lang])
    assert res.exit_code == 1, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: robot.model: ") and maker in lines[0], res.output
    assert not out.exists() and not prog.exists()


@pytest.mark.parametrize("cell, lang, robot", [("cell_abb.yaml", "rapid", "abb_irb1200_5_90"),
                                               ("cell_kuka.yaml", "krl", "kuka_kr6_r900_sixx")])
def test_factory_plan_with_the_abb_and_kuka_cells(tmp_path, cell, lang, robot):
    """`factory plan --cell fixtures/cell_abb.yaml --lang rapid` (and the KUKA's with krl) plans the bracket's
    load and unload; the program is read by its consumer and runs the planned time within 5 %."""
    from tests.robotprog.parsers import parse_krl, rapid_errors

    res = runner.invoke(app, ["plan", str(SAMPLES / "bracket.stl"), "-o", str(tmp_path), "--cell", str(FIXTURES / cell),
                              "--lang", lang, "--scallop", "0.05", "--no-waterline", "--grid", "0.5", "--json"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    assert summary["robot"]["robot"] == robot
    assert summary["robot"]["program_s"] == pytest.approx(summary["robot"]["motion_s"], rel=0.05)
    if lang == "rapid":
        assert rapid_errors((tmp_path / "bracket.mod").read_text()) == []
    else:
        parse_krl((tmp_path / "bracket.src").read_text(), (tmp_path / "bracket.dat").read_text())
