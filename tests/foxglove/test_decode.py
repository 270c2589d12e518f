"""Every MCAP factory writes, opened with the Foxglove app's own parsers (``tests/foxglovecheck.py``).

One small pocketed block goes through every stage that logs (toolpath, verify, plan, robot,
simulate with faults) and rendered board views through calibrate and handeye, once per module;
each log must have every schema parsed and every message decoded by ``@foxglove/rosmsg`` and
``@foxglove/rosmsg2-serialization``, as many messages as the file's statistics count.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from mcap.reader import make_reader
from typer.testing import CliRunner

from cli.main import app
from factory.rosmsgs import MSG_DIRS, message_definition
from factory.core.resources import FIXTURES
from tests.cli.expect import simulate_exit
from tests.cli.test_handeye import BOARD, args, scene  # noqa: F401  (scene is a fixture)
from tests.conftest import BLOCK_PLAN, copy_block_catalog
from tests.foxglovecheck import check_foxglove_decodes, foxglove_decode, foxglove_schema_differences

runner = CliRunner()
FAST = list(BLOCK_PLAN)


def run(*argv) -> None:
    r = runner.invoke(app, [str(a) for a in argv], catch_exceptions=False)
    assert r.exit_code == 0, r.output


@pytest.fixture(scope="module")
def logs(shared_work, tmp_path_factory, scene) -> dict[str, Path]:  # noqa: F811
    """stage -> the MCAP it wrote. The plan is the module's copy of the run's plan of the block (the same
    options as :data:`FAST`, :data:`tests.conftest.BLOCK_PLAN`)."""
    d = tmp_path_factory.mktemp("logs")
    catalog, part = copy_block_catalog(d)
    out = {"toolpath": d / "block.toolpath.mcap", "verify": d / "verify.mcap", "plan": catalog / "block.mcap",
           "robot": d / "robot.mcap", "simulate": d / "cell.mcap", "calibrate": d / "calibrate.mcap",
           "handeye": d / "handeye.mcap"}
    run("toolpath", part, "-o", out["toolpath"], *FAST[:-3])
    run("gcode", out["toolpath"], "-o", d / "block.nc", "--quiet")
    run("verify", d / "block.nc", "--setup", d / "block.setup.json", "--part", part, "--mcap", out["verify"],
        "--quiet")
    run("robot", FIXTURES / "cell.yaml", "--setup", catalog / "block.setup.json", "--part", part,
        "-o", out["robot"], "--quiet")
    orders = d / "orders.csv"
    orders.write_text(f"part,quantity,material,priority\n{part},2,aluminium,0\n")
    r = runner.invoke(app, [str(a) for a in ("simulate", orders, "--catalog", catalog, "--mcap",
                                             out["simulate"], "--faults", "3", "--fault-rate", "0.3", "--quiet",
                                             "--json")], catch_exceptions=False)
    assert r.exit_code == simulate_exit(json.loads(r.stdout)), r.output  # 3: an order not done
    run("calibrate", scene["images"], "--board", str(BOARD), "-o", d / "camera.yaml", "--mcap", out["calibrate"],
        "--quiet")
    run("handeye", *args(scene, "poses.yaml", d / "handeye.yaml", "--mcap", out["handeye"], "--quiet"))
    return out


def _counts(path: Path) -> dict[str, int]:
    """Topic -> message count from the file's Statistics record (read with the Python mcap reader)."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    topics = {cid: ch.topic for cid, ch in summary.channels.items()}
    return {topics[cid]: n for cid, n in summary.statistics.channel_message_counts.items() if n}


@pytest.mark.parametrize("stage", ["toolpath", "verify", "plan", "robot", "simulate", "calibrate", "handeye"])
def test_foxglove_decodes_every_message(logs, stage):
    path = logs[stage]
    decoded = check_foxglove_decodes(path)
    assert decoded == _counts(path) and decoded


def test_foxglove_reads_the_spindle_load_and_the_oee_terms(logs):
    """The fields Foxglove's parsers decode from the cell log's own schemas: the spindle load on
    /cell/machine, the OEE terms on /cell/summary, numbers in range and never NaN."""
    topics = foxglove_decode(logs["simulate"])[str(logs["simulate"])]["topics"]
    machine, summary = topics["/cell/machine"], topics["/cell/summary"]
    assert {"spindle_speed_rpm", "spindle_load_percent", "feed_mm_per_min"} <= set(machine["fields"])
    assert 0 < machine["max"]["spindle_load_percent"] < 100  # a NaN would read null
    assert {"availability", "performance", "quality", "oee", "downtime_s", "run_time_s"} <= set(summary["fields"])
    assert all(0 < summary["max"][k] <= 1 for k in ("availability", "performance", "quality", "oee"))


@pytest.mark.parametrize("stage", ["plan", "robot", "simulate"])
def test_the_robot_travels_in_the_log_as_valid_gltf(logs, stage):
    """The robot's link meshes: one valid glTF binary model per UR5 link, nothing loaded by URL."""
    report = foxglove_decode(logs[stage])[str(logs[stage])]
    assert report["topics"]["/robot/visuals"]["models"] == 7


FOXGLOVE_MSGS = next(d / "foxglove_msgs" / "msg" for d in MSG_DIRS if (d / "foxglove_msgs").is_dir())


def test_foxglove_msgs_we_ship_are_foxgloves_own():
    differences = foxglove_schema_differences(FOXGLOVE_MSGS)
    assert {"SceneUpdate", "SceneEntity", "ModelPrimitive", "ImageAnnotations"} <= set(differences)
    assert differences == dict.fromkeys(differences)


def test_the_schema_comparison_sees_a_changed_field(tmp_path):
    text = (FOXGLOVE_MSGS / "ModelPrimitive.msg").read_text()
    (tmp_path / "ModelPrimitive.msg").write_text(text.replace("string media_type", "string mime_type"))
    (tmp_path / "Color.msg").write_text("float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n")
    differences = foxglove_schema_differences(tmp_path)
    assert differences["ModelPrimitive"] and "mime_type" in differences["ModelPrimitive"]
    assert differences["Color"] and "float32" in differences["Color"]


def test_the_check_rejects_what_foxglove_cannot_read(tmp_path):
    """A dependency header naming the type unlike its field (``MSG: pkg/msg/Name`` for a field
    ``pkg/Name``) fails the parser; a message with bytes left over fails the reader."""
    from tests.factory.test_mcaplog import write_raw

    good = message_definition("tf2_msgs/msg/TFMessage")
    renamed = re.sub(r"^MSG: (\w+)/(\w+)$", r"MSG: \1/msg/\2", good, flags=re.M)
    assert renamed != good
    bad_schema, long_message = tmp_path / "schema.mcap", tmp_path / "long.mcap"
    write_raw(bad_schema, schema_text=renamed)
    write_raw(long_message, trailing=b"\0" * 8)
    report = foxglove_decode(bad_schema, long_message)
    assert "Expected 1 top level type definition for 'geometry_msgs/TransformStamped'" in \
        report[str(bad_schema)]["schemas"]["tf2_msgs/msg/TFMessage"]["error"]
    assert "8 of" in report[str(long_message)]["topics"]["/tf_static"]["error"]
    for path in (bad_schema, long_message):
        with pytest.raises(AssertionError, match="Foxglove cannot decode it"):
            check_foxglove_decodes(path)


def test_the_check_rejects_a_model_that_is_not_gltf(tmp_path):
    import numpy as np
    import trimesh

    from factory.mcaplog import McapLog
    from factory.scene import model_entity, scene_update

    box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    entity = model_entity("box", "world", np.eye(4), box.vertices, box.faces, (1, 1, 1, 1), 0)
    entity.models[0].data = entity.models[0].data[:100]  # cut short
    path = tmp_path / "bad_model.mcap"
    with McapLog(path, stage="test") as m:
        m.write("/scene", scene_update([entity]), 0)
    report = foxglove_decode(path)[str(path)]
    assert report["topics"]["/scene"]["failed"] == 1
    assert "not valid glTF" in report["topics"]["/scene"]["error"]
