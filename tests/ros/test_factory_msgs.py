"""factory's ROS 2 interfaces (``ros/factory_msgs``) and the typed topics of the cell log.

Read by readers we did not write: rosbags builds the message classes from the shipped ``.msg``
files alone and deserialises every message of a cell log with them; the schema text in the log
must be those files' fields. A small faulty run (``--faults``) checks that detections share
their image's header and that every injected fault shows on ``/diagnostics`` at ERROR.
"""

from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from typer.testing import CliRunner

from cli.main import app
from factory.rosmsgs import MSG_DIRS
from factory.core.resources import ROS_INTERFACES
from tests.cli.expect import simulate_exit
from tests.conftest import copy_block_catalog

PACKAGE = ROS_INTERFACES / "factory_msgs"
runner = CliRunner()


def shipped_typestore():
    """A Jazzy typestore plus every shipped .msg file, built here, not by factory."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for root in MSG_DIRS:
        for path in Path(root).glob("*/msg/*.msg"):
            types.update(get_types_from_msg(path.read_text(), f"{path.parent.parent.name}/msg/{path.stem}"))
    store.register(types)
    return store


def fields_of(text: str) -> tuple[list[str], list[str]]:
    """(constants, fields) of a .msg text, each in order; comments, blank lines and extra spaces
    dropped (where constants stand among the fields carries no meaning)."""
    lines = (re.sub(r"\s+", " ", line.split("#", 1)[0]).strip() for line in text.splitlines())
    lines = [line for line in lines if line]
    return [line for line in lines if "=" in line], [line for line in lines if "=" not in line]


@pytest.fixture(scope="module")
def cell_log(shared_work, tmp_path_factory) -> Path:
    """A cell run with faults, logged, from the module's copy of the run's pocketed block plan (fast options)."""
    d = tmp_path_factory.mktemp("cell")
    catalog, part = copy_block_catalog(d)
    orders = d / "orders.csv"
    orders.write_text(f"part,quantity,material,priority\n{part},3,aluminium,0\n")
    mcap = d / "cell.mcap"
    r = runner.invoke(app, [str(a) for a in ("simulate", orders, "--catalog", catalog, "--mcap", mcap,
                                             "--faults", "3", "--fault-rate", "0.3", "--quiet", "--json")])
    assert r.exit_code == simulate_exit(json.loads(r.stdout)), r.output
    (mcap.parent / "run.json").write_text(r.stdout)
    return mcap


def messages(path: Path, store) -> list[tuple[str, str, int, object]]:
    """(topic, type, log time [ns], message) of every message, decoded with ``store`` by type name."""
    out = []
    with open(path, "rb") as f:
        for schema, channel, msg in make_reader(f).iter_messages(log_time_order=True):
            out.append((channel.topic, schema.name, msg.log_time, store.deserialize_cdr(msg.data, schema.name)))
    return out


def test_the_package_builds_every_message_file():
    """package.xml names the package and its dependencies; CMakeLists generates every .msg file."""
    root = ET.parse(PACKAGE / "package.xml").getroot()
    assert root.findtext("name") == "factory_msgs" == PACKAGE.name
    assert root.findtext("member_of_group") == "rosidl_interface_packages"
    depends = {e.text for e in root.findall("depend")}
    cmake = (PACKAGE / "CMakeLists.txt").read_text()
    files = sorted(p.name for p in (PACKAGE / "msg").glob("*.msg"))
    listed = re.findall(r'"msg/([A-Za-z0-9]+\.msg)"', cmake)
    assert files and sorted(listed) == files
    assert "rosidl_generate_interfaces(${PROJECT_NAME}" in cmake
    used = {t.split("/")[0] for p in (PACKAGE / "msg").glob("*.msg") for t in re.findall(r"^(\w+/\w+)", p.read_text(),
                                                                                          re.M)}
    assert used - {"factory_msgs"} <= depends, used - depends
    assert set(re.search(r"DEPENDENCIES ([\w ]+)", cmake)[1].split()) == depends


def test_colcons_package_parser_accepts_the_package():
    # catkin_pkg is what colcon-ros and bloom read package.xml with: format 3, and every
    # maintainer with a well-formed address (a build stops on a package it calls invalid).
    from catkin_pkg.package import parse_package

    warnings: list[str] = []
    package = parse_package(str(PACKAGE / "package.xml"), warnings=warnings)
    package.validate(warnings=warnings)
    assert warnings == []
    assert package.name == "factory_msgs" and package.package_format == 3
    assert package.get_build_type() == "ament_cmake"
    assert [m.name for m in package.maintainers] == ["factory maintainers"]
    assert "example.com" not in package.maintainers[0].email  # no made-up person's address


def test_every_message_deserialises_from_the_shipped_msg_files(cell_log):
    store = shipped_typestore()
    msgs = messages(cell_log, store)
    types = {topic: name for topic, name, _, _ in msgs}
    assert types["/camera/detections"] == "factory_msgs/msg/DetectedObjectArray"
    assert types["/camera/annotations"] == "foxglove_msgs/msg/ImageAnnotations"
    assert types["/diagnostics"] == "diagnostic_msgs/msg/DiagnosticArray"
    assert len(msgs) > 100


def test_schemas_in_the_log_are_the_msg_files(cell_log):
    """Each factory_msgs / foxglove_msgs schema, and each such dependency inside any schema, has
    exactly the fields of its .msg file."""
    files = {f"{p.parent.parent.name}/msg/{p.stem}": p for root in MSG_DIRS for p in Path(root).glob("*/msg/*.msg")}
    with open(cell_log, "rb") as f:
        schemas = make_reader(f).get_summary().schemas.values()
    checked = set()
    for schema in schemas:
        sections = schema.data.decode().split("=" * 80 + "\n")
        named = [(schema.name, sections[0])]
        for section in sections[1:]:
            head, _, body = section.partition("\n")
            pkg, name = head.removeprefix("MSG: ").split("/")
            named.append((f"{pkg}/msg/{name}", body))
        for name, body in named:
            if name in files:
                assert fields_of(body) == fields_of(files[name].read_text()), name
                checked.add(name)
    assert {"factory_msgs/msg/DetectedObjectArray", "factory_msgs/msg/DetectedObject",
            "foxglove_msgs/msg/ImageAnnotations", "foxglove_msgs/msg/SceneUpdate"} <= checked


def test_the_schema_check_sees_a_changed_field():
    text = (PACKAGE / "msg" / "DetectedObject.msg").read_text()
    assert fields_of(text) != fields_of(text.replace("float32 radius", "float64 radius"))
    assert fields_of(text) == fields_of(text.replace("\n", "\n\n# a comment\n"))


def test_detections_share_the_image_header_and_carry_the_seed_fields(cell_log):
    msgs = messages(cell_log, shipped_typestore())
    images = {(t, m.header.frame_id) for topic, _, t, m in msgs if topic == "/camera/image/compressed"}
    detections = [(t, m) for topic, _, t, m in msgs if topic == "/camera/detections"]
    assert detections and len(detections) == len(images)
    steps = set()
    for t, m in detections:
        stamp = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        assert (stamp, m.header.frame_id) in images and stamp == t
        steps.add((m.step, m.outcome))
        assert (len(m.objects) == 0) == (m.outcome == "stock_not_found")
        for obj in m.objects:
            assert obj.header == m.header and obj.base_frame == "base_link"
            assert re.fullmatch(r"o\d+-\d+", obj.serial)
            assert 0 < obj.confidence <= 1 and 20 < obj.radius < 400
            assert 0 <= obj.center_x < 2000 and 0 <= obj.center_y < 2000
            assert obj.class_name == ("part" if m.step == "inspect" else "blank")
            assert obj.inspected == (m.step == "inspect")
            # What the camera can promise: the pose to within a few tenths of a millimetre and a
            # degree or so, and (inspected) no burr under a size beyond the tolerance.
            assert 0 < obj.position_uncertainty < 3e-3 and 0 < obj.yaw_uncertainty < 0.05
            if obj.inspected:
                assert obj.inspection_passed == (m.outcome == "inspect_pass")
                assert obj.tolerance > 0 and (obj.max_deviation <= obj.tolerance) == obj.inspection_passed
                assert obj.tolerance < obj.smallest_burr < 5e-3
            else:
                assert obj.smallest_burr == 0
    assert ("locate", "done") in steps and ("inspect", "inspect_pass") in steps
    annotations = [(t, m) for topic, _, t, m in msgs if topic == "/camera/annotations"]
    assert [(t, len(m.circles)) for t, m in annotations] == [(t, len(m.objects)) for t, m in detections]


def test_every_injected_fault_is_an_error_on_diagnostics_until_recovered(cell_log):
    msgs = messages(cell_log, shipped_typestore())
    faults = [(t, m.msg) for topic, _, t, m in msgs if topic == "/rosout" and "-> FAULT" in m.msg]
    failed = [t for topic, _, t, m in msgs if topic == "/rosout" and "inspect_fail ->" in m.msg]
    assert faults, "the seed and rate should inject faults"
    diagnostics = [(t, {s.name: s for s in m.status}) for topic, _, t, m in msgs if topic == "/diagnostics"]
    assert {name for _, d in diagnostics for name in d} == {"cell/machine", "cell/robot", "cell/camera",
                                                           "cell/scheduler"}
    at = dict(diagnostics)  # the last status at each stamp
    for t, text in faults:
        code = re.search(r": (\w+) -> FAULT", text)[1]
        scheduler = at[t]["cell/scheduler"]
        assert scheduler.level == 2 and code in {kv.key: kv.value for kv in scheduler.values}["fault"]
        assert any(s.level == 2 and s.name != "cell/scheduler" for s in at[t].values())
    for t in failed:
        assert at[t]["cell/machine"].level == 2  # the machine's verdict
    # all recovered by the end of the run
    assert all(s.level == 0 for s in diagnostics[-1][1].values())
    # key values of the machine and the robot, as they were at each change
    machine = [{kv.key: kv.value for kv in d["cell/machine"].values} for _, d in diagnostics]
    assert {"state", "tool", "spindle_speed_rpm", "spindle_load_percent", "program_line", "fault"} <= set(machine[0])
    cutting = [v for v in machine if v["state"] == "cutting"]
    assert cutting and all(int(v["tool"]) > 0 and float(v["spindle_speed_rpm"]) > 1000 for v in cutting)
    assert all(float(v["spindle_load_percent"]) == 0 for v in machine if v["state"] != "cutting")
    assert all(0 <= float(v["spindle_load_percent"]) < 100 for v in machine)
    robot = [{kv.key: kv.value for kv in d["cell/robot"].values} for _, d in diagnostics]
    assert {v["activity"] for v in robot} >= {"idle", "load", "unload"}


def test_diagnostics_carry_the_door_and_the_gripper(cell_log):
    msgs = messages(cell_log, shipped_typestore())
    rows = [({kv.key: kv.value for kv in d["cell/machine"].values}, {kv.key: kv.value for kv in d["cell/robot"].values})
            for d in ({s.name: s for s in m.status} for topic, _, _, m in msgs if topic == "/diagnostics")]
    # the door is open exactly while the robot reaches into the machine, so never while it cuts
    assert {m["door"] for m, _ in rows} == {"open", "closed"}
    assert all((m["door"] == "open") == (r["activity"] in ("load", "unload")) for m, r in rows)
    assert all(m["door"] == "closed" for m, _ in rows if m["state"] == "cutting")
    # the gripper is closed exactly when it holds something: the blank into the vise, the part out
    assert all((r["gripper"] == "closed") == bool(r["gripper_holds"]) for _, r in rows)
    assert all(r["gripper_holds"] == "blank" for _, r in rows if r["activity"] == "load")
    assert all(r["gripper_holds"] == "part" for _, r in rows if r["activity"] == "unload")
    assert all(r["gripper"] == "open" for _, r in rows if r["activity"] in ("fetch", "missed_grasp"))


def test_no_json_in_strings_the_cell_state_is_fields(cell_log):
    msgs = messages(cell_log, shipped_typestore())
    types = {topic: name for topic, name, _, _ in msgs}
    strings = {topic for topic, name in types.items() if name == "std_msgs/msg/String"}
    assert strings == {"/robot_description"}
    assert types["/cell/state"] == "factory_msgs/msg/SchedulerState"
    assert types["/cell/robot"] == "factory_msgs/msg/RobotState"
    assert types["/cell/machine"] == "factory_msgs/msg/MachineState"
    assert types["/cell/io"] == "factory_msgs/msg/MachineSignal"
    assert types["/cell/orders"] == "factory_msgs/msg/OrderQueue"
    assert types["/cell/summary"] == "factory_msgs/msg/CellSummary"


def test_machine_state_follows_the_program(cell_log):
    msgs = messages(cell_log, shipped_typestore())
    sheet = json.loads((cell_log.parent / "catalog" / "block.setup.json").read_text())
    rpm = {op["tool"]: op["spindle_rpm"] for op in sheet["operations"]}
    cutting = [m for topic, _, _, m in msgs if topic == "/cell/machine" and m.state == "cutting"]
    assert len(cutting) > 20
    for m in cutting:
        assert m.header.frame_id == "work" and re.fullmatch(r"o\d+-\d+", m.serial)
        assert m.tool in rpm and m.spindle_speed_rpm == pytest.approx(rpm[m.tool])
        assert 0 <= m.program_progress <= 1 and m.program_line > 0 and m.feed_mm_per_min >= 0
        assert -0.05 < m.tool_position.z < 0.1  # [m] around the work's top face, not millimetres
    assert max(m.feed_mm_per_min for m in cutting) > 100
    # the spindle load: a number, 0 with the spindle stopped, positive while it cuts, below 100 %
    machine = [m for topic, _, _, m in msgs if topic == "/cell/machine"]
    assert all(math.isfinite(m.spindle_load_percent) and 0 <= m.spindle_load_percent < 100 for m in machine)
    assert all(m.spindle_load_percent == 0 for m in machine if m.spindle_speed_rpm == 0)
    assert sum(m.spindle_load_percent > 0.1 for m in cutting) >= 5
    # roughing loads the spindle more than finishing the same part: the mean load of the samples of each kind of
    # operation, a sample belonging to the operation whose "(op N: ...)" comment last precedes its program line (a
    # tool may rough and finish: the 6 mm end mill rest-roughs, then finishes the walls). Pooled by kind, not
    # the first roughing alone: one operation holds a handful of samples, and a z-level roughing whose links run
    # along the paths it has cut (cadcam.levelpath) may have them all land on a link, in air.
    program = (cell_log.parent / "catalog" / sheet["program"]).read_text().splitlines()
    starts = [k for k, line in enumerate(program, start=1) if line.startswith("(op ")]
    assert len(starts) == len(sheet["operations"])
    loads: dict[int, list[float]] = {}
    for m in cutting:
        loads.setdefault(int(np.searchsorted(starts, m.program_line, side="right")) - 1, []).append(m.spindle_load_percent)
    kind = [op["kind"] for op in sheet["operations"]]
    pooled = {c: [x for k, v in loads.items() if kind[k] == c for x in v] for c in ("roughing", "finishing")}
    rough, finish = (float(np.mean(pooled[c])) for c in ("roughing", "finishing"))
    assert rough > finish > 0, ({k: (kind[k], len(v), float(np.mean(v))) for k, v in loads.items()})
    # the tool position is the one on /tf (work -> tool) at the same stamp
    tips = {t: x.transform.translation for topic, _, t, msg in msgs if topic == "/tf" for x in msg.transforms
            if x.child_frame_id == "tool"}
    for m in cutting:
        stamp = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        assert tips[stamp].z == pytest.approx(m.tool_position.z)
    last = [m for topic, _, _, m in msgs if topic == "/cell/machine"][-1]
    assert last.state in ("idle", "alarm") and last.serial == ""


def test_order_queue_and_summary_end_as_the_run_reports(cell_log):
    run = json.loads((cell_log.parent / "run.json").read_text())
    msgs = messages(cell_log, shipped_typestore())
    queues = [m for topic, _, _, m in msgs if topic == "/cell/orders"]
    assert [o.state for o in queues[0].orders] == ["queued"]
    final = {o.id: o for o in queues[-1].orders}
    for o in run["orders"]:
        assert (final[o["order"]].state, final[o["order"]].good) == (o["outcome"], o["good"])
    goods = [q.orders[0].good for q in queues]
    assert goods == sorted(goods)  # parts are only ever added
    summaries = [m for topic, _, _, m in msgs if topic == "/cell/summary"]
    # the running figures as parts reach the trays, then the run's own summary
    made = [m.parts_good + m.parts_rejected for m in summaries]
    assert made == sorted(made) and len(summaries) == made[-1] + 1
    summary = summaries[-1]
    s = run["summary"]
    assert summary.parts_good == s["parts_good"] and summary.makespan_s == pytest.approx(s["makespan_s"])
    assert summary.orders_done == s["orders"]["done"]
    assert dict(zip(summary.fault_kinds, summary.fault_counts.tolist())) == s["faults"]
    # the OEE terms of the run's summary (robotprog.oee); the faults stopped the cell
    for key in ("availability", "performance", "quality", "oee", "downtime_s", "run_time_s"):
        # times are rounded to the millisecond, the running figures' and the run's separately
        assert getattr(summary, key) == pytest.approx(s[key], abs=2e-3 if key.endswith("_s") else 1e-6), key
    assert s["downtime_s"] > 0 and 0 < summary.availability < 1
    assert summary.oee == pytest.approx(summary.availability * summary.performance * summary.quality, abs=1e-4)
    assert all(0 <= m.availability <= 1 and 0 <= m.performance <= 1 and 0 <= m.quality <= 1 for m in summaries)
    states = [m for topic, _, _, m in msgs if topic == "/cell/state"]
    assert {m.state for m in states} >= {"FETCH_RAW", "LOAD", "MACHINING", "UNLOAD", "INSPECT", "SORT", "IDLE"}
    assert all(re.fullmatch(r"o\d+-\d+", m.serial) for m in states)


def test_the_machine_handshake_is_on_cell_io(cell_log):
    """/cell/io carries the handshake the posted programs run (robotprog.machineio), with the
    cell file's numbers: per part that was cut without an alarm, exactly the program's sequence."""
    from robotprog.cell import load_cell
    from factory.core.resources import FIXTURES
    from robotprog.machineio import part_signals

    io = load_cell(FIXTURES / "cell.yaml", check_robot=False).machine
    msgs = [m for topic, name, _, m in messages(cell_log, shipped_typestore()) if topic == "/cell/io"]
    assert msgs and all(m.number == getattr(io, m.signal) for m in msgs)
    want = [o.key[:2] for o in part_signals()]
    by_part: dict[str, list] = {}
    for m in msgs:
        by_part.setdefault(m.serial, []).append(m)
    clean = 0
    for serial, ms in by_part.items():
        ops = [(m.operation, m.signal) for m in ms]
        assert ops[:4] == want[:4], serial  # ready: wait idle, open the door, wait until open
        if ops == want:
            clean += 1
            assert [m.level for m in ms][:-1] == [o.level for o in part_signals()][:-1]
    assert clean >= 1
