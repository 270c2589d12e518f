"""The Foxglove layout of the cell-simulation log: valid JSON, a consistent panel tree, only our topics."""

from __future__ import annotations

import dataclasses
import json
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from factory.core.errors import McapError
from factory.foxglove import CellTopics, CellView, cell_layout, layout_json

# Panel types a layout may use, and the topics `factory simulate` writes (decided by the lead).
PANEL_TYPES = {"3D", "Image", "StateTransitions", "RosOut", "RawMessages", "DiagnosticSummary", "Plot"}
SIMULATION_TOPICS = {
    "/robot_description", "/robot/visuals", "/tf", "/tf_static", "/joint_states", "/cell/boxes", "/machine/toolpath",
    "/machine/stock", "/camera/image/compressed", "/camera/camera_info", "/cell/state", "/cell/robot",
    "/cell/machine", "/cell/orders", "/rosout", "/camera/annotations", "/diagnostics",
}


def leaves(node: Any) -> list[str]:
    """Panel ids of a react-mosaic tree, checking the shape of every inner node on the way."""
    if isinstance(node, str):
        return [node]
    assert set(node) == {"first", "second", "direction", "splitPercentage"}, node
    assert node["direction"] in ("row", "column")
    assert 0 < node["splitPercentage"] < 100
    return leaves(node["first"]) + leaves(node["second"])


def named_topics(config: Any) -> set[str]:
    """Every topic a panel config names: string keys and values that start with '/', with a
    message path (``/topic.field``) cut back to its topic (topic names hold no '.')."""
    found: set[str] = set()

    def visit(x: Any) -> None:
        if isinstance(x, dict):
            for k, v in x.items():
                visit(k)
                visit(v)
        elif isinstance(x, list):
            for v in x:
                visit(v)
        elif isinstance(x, str) and x.startswith("/"):
            found.add(x.split(".", 1)[0])

    visit(config)
    return found


def test_layout_json_is_valid_deterministic_and_sorted() -> None:
    text = layout_json()
    assert text == layout_json() and text.endswith("}\n")
    doc = json.loads(text)
    assert doc == cell_layout()
    assert set(doc) == {"configById", "layout", "globalVariables", "userNodes", "playbackConfig"}
    assert doc["playbackConfig"] == {"speed": 1.0}
    # keys sorted at every level, so a regenerated file diffs clean
    assert json.dumps(doc, indent=2, sort_keys=True) + "\n" == text


def test_every_panel_in_the_tree_has_a_config_and_every_config_a_panel() -> None:
    doc = cell_layout()
    ids = leaves(doc["layout"])
    assert len(ids) == len(set(ids))
    assert set(ids) == set(doc["configById"])
    types = [i.split("!", 1)[0] for i in ids]
    assert sorted(types) == sorted(PANEL_TYPES)  # one of each panel the lead asked for


def test_layout_names_only_simulation_topics_and_shows_the_ones_asked_for() -> None:
    doc = cell_layout()
    named = named_topics(doc["configById"])
    assert named <= SIMULATION_TOPICS, named - SIMULATION_TOPICS
    by_type = {i.split("!", 1)[0]: c for i, c in doc["configById"].items()}
    three_d = by_type["3D"]
    # the robot from its embedded meshes, never from the URDF's package:// files
    assert three_d["topics"]["/robot/visuals"]["visible"] and not three_d["topics"]["/robot_description"]["visible"]
    assert not [layer for layer in three_d["layers"].values() if layer["layerId"] == "foxglove.Urdf"]
    assert three_d["followTf"] == "world"
    assert all(three_d["topics"][t]["visible"] for t in ("/cell/boxes", "/machine/toolpath", "/machine/stock"))
    assert three_d["transforms"]["frame:tool"]["visible"]
    assert all(k == layer["instanceId"] for k, layer in three_d["layers"].items())
    assert by_type["Image"]["imageMode"]["imageTopic"] == "/camera/image/compressed"
    assert [p["value"] for p in by_type["StateTransitions"]["paths"]] == [
        "/cell/state.state", "/cell/robot.activity", "/cell/machine.state"]
    assert [p["value"] for p in by_type["Plot"]["paths"]] == ["/cell/machine.tool_position.z",
                                                              "/cell/machine.spindle_load_percent"]
    assert by_type["Plot"]["xAxisVal"] == "timestamp"
    assert all(p["timestampMethod"] in ("receiveTime", "headerStamp") for p in by_type["StateTransitions"]["paths"])
    assert by_type["RosOut"]["topicToRender"] == "/rosout"
    assert by_type["DiagnosticSummary"]["topicToRender"] == "/diagnostics"
    assert by_type["Image"]["imageMode"]["annotations"] == {"/camera/annotations": {"visible": True}}
    assert by_type["RawMessages"]["topicPath"] == "/cell/orders"


topic_names = st.from_regex(r"/[a-z][a-z0-9_]{0,8}(/[a-z][a-z0-9_]{0,8}){0,2}", fullmatch=True)


@settings(max_examples=40, deadline=None)
@given(st.lists(topic_names, min_size=len(dataclasses.fields(CellTopics)),
                max_size=len(dataclasses.fields(CellTopics)), unique=True))
def test_given_topic_names_are_the_only_ones_named(names: list[str]) -> None:
    topics = CellTopics(*names)
    doc = json.loads(layout_json(topics))
    named = named_topics(doc["configById"])
    assert named == set(names) == set(topics.names())  # every given topic is used, no default leaks in
    assert set(leaves(doc["layout"])) == set(doc["configById"])


def test_view_reaches_the_camera_state() -> None:
    view = CellView(follow_frame="base_link", target=(1.0, 2.0, 0.5), distance=1.5, phi_deg=30.0,
                    theta_deg=-90.0, frames=("base_link", "tool0"))
    three_d = cell_layout(view=view)["configById"]["3D!cell"]
    cam = three_d["cameraState"]
    assert (cam["distance"], cam["phi"], cam["thetaOffset"], cam["targetOffset"]) == (1.5, 30.0, -90.0, [1.0, 2.0, 0.5])
    assert cam["near"] < 0.1 < cam["distance"] < cam["far"]
    assert three_d["followTf"] == "base_link"
    assert set(three_d["transforms"]) == {"frame:base_link", "frame:tool0"}


@pytest.mark.parametrize("topics, view", [
    (CellTopics(image="camera/image"), CellView()),
    (CellTopics(rosout=""), CellView()),
    (CellTopics(), CellView(distance=0.0)),
    (CellTopics(), CellView(phi_deg=200.0)),
    (CellTopics(), CellView(target=(0.0, float("nan"), 0.0))),
    (CellTopics(), CellView(follow_frame="")),
])
def test_bad_names_or_views_raise_mcap_error(topics: CellTopics, view: CellView) -> None:
    with pytest.raises(McapError):
        cell_layout(topics, view)


def test_plotted_and_state_paths_are_fields_of_the_logged_messages() -> None:
    """Each Plot path is a number and each State Transitions path a string of the message its topic
    carries, as the builders make them from the shipped .msg files."""
    from factory.cellmsgs import machine_state, robot_state, scheduler_state

    sample = {"/cell/machine": machine_state("cutting", "o1", "o1-1", 0, tool=1, spindle_rpm=9000.0, spindle_load=12.5),
              "/cell/robot": robot_state("load", "o1", "o1-1", 0),
              "/cell/state": scheduler_state("LOAD", "fetched", "o1", "o1-1", "", 0)}

    def value(path: str) -> Any:
        topic, _, fields = path.partition(".")
        out = sample[topic]
        for name in fields.split("."):
            out = getattr(out, name)
        return out

    by_type = {i.split("!", 1)[0]: c for i, c in cell_layout()["configById"].items()}
    plotted = [value(p["value"]) for p in by_type["Plot"]["paths"]]
    assert all(isinstance(v, float) for v in plotted) and plotted[1] == 12.5
    assert all(isinstance(value(p["value"]), str) for p in by_type["StateTransitions"]["paths"])

