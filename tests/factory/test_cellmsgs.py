"""Typed cell messages: the builders check their inputs and fill the fields the readers use."""

from __future__ import annotations

import math

import pytest

from factory.cellmsgs import ComponentStatus, Detection, detected_object_array, diagnostic_array, image_annotations
from factory.core.errors import McapError
from factory.rosmsgs import TYPESTORE

PART = Detection(class_name="part", center_px=(320.0, 240.0), radius_px=40.0, confidence=0.93,
                 xyz=(0.15, 0.4, 0.78), yaw=math.pi / 2, serial="o1-3", inspected=True, passed=False,
                 max_deviation=0.0017, tolerance=0.001, position_uncertainty=4e-4, yaw_uncertainty=0.002,
                 smallest_burr=0.0019)


def roundtrip(msg):
    return TYPESTORE.deserialize_cdr(TYPESTORE.serialize_cdr(msg, msg.__msgtype__), msg.__msgtype__)


def test_detection_carries_the_image_header_and_the_pose_in_the_base_frame():
    msg = roundtrip(detected_object_array([PART], "inspect", "inspect_fail", "tray_camera", 2_500_000_000,
                                          "base_link"))
    assert (msg.header.frame_id, msg.header.stamp.sec, msg.header.stamp.nanosec) == ("tray_camera", 2, 500_000_000)
    (obj,) = msg.objects
    assert obj.header == msg.header and obj.base_frame == "base_link" and obj.serial == "o1-3"
    assert (obj.center_x, obj.center_y, obj.radius) == (320.0, 240.0, 40.0)
    assert obj.confidence == pytest.approx(0.93) and obj.inspected and not obj.inspection_passed
    q = obj.pose.orientation
    assert (q.x, q.y) == (0.0, 0.0) and q.z == pytest.approx(math.sqrt(0.5)) and q.w == pytest.approx(math.sqrt(0.5))
    assert obj.pose.position.z == 0.78
    # How far the pose may be off [m, rad] and the narrowest burr the inspection resolves [m].
    assert (obj.position_uncertainty, obj.yaw_uncertainty, obj.smallest_burr) == pytest.approx((4e-4, 0.002, 0.0019))


@pytest.mark.parametrize("change", [{"confidence": 1.5}, {"radius_px": -1.0}, {"xyz": (0.0, math.nan, 0.0)},
                                    {"position_uncertainty": -1e-4}, {"yaw_uncertainty": math.inf},
                                    {"smallest_burr": -1e-3}])
def test_bad_detections_are_refused(change):
    import dataclasses

    bad = dataclasses.replace(PART, **change)
    with pytest.raises(McapError, match="o1-3"):
        detected_object_array([bad], "inspect", "inspect_fail", "tray_camera", 0, "base_link")
    with pytest.raises(McapError, match="o1-3"):
        image_annotations([bad], 0)


def test_annotations_circle_each_detection_red_when_it_failed():
    msg = roundtrip(image_annotations([PART], 7))
    (circle,) = msg.circles
    assert (circle.position.x, circle.position.y, circle.diameter) == (320.0, 240.0, 80.0)
    assert circle.outline_color.r > 0.9 and circle.outline_color.g < 0.2
    (text,) = msg.texts
    assert "o1-3" in text.text and "FAIL" in text.text


def test_diagnostics_levels():
    msg = roundtrip(diagnostic_array([ComponentStatus("cell/machine", "ERROR", "alarm", {"fault": "machine_alarm"}),
                                      ComponentStatus("cell/robot", "OK", "ok", {})], 0))
    assert [(s.name, s.level, s.hardware_id) for s in msg.status] == [("cell/machine", 2, "cell/machine"),
                                                                       ("cell/robot", 0, "cell/robot")]
    assert [(kv.key, kv.value) for kv in msg.status[0].values] == [("fault", "machine_alarm")]
    with pytest.raises(McapError, match="unknown level"):
        diagnostic_array([ComponentStatus("cell/robot", "FINE", "", {})], 0)
