"""Typed messages of the cell log: detections, their image overlay, and health on /diagnostics.

Pure builders returning :data:`factory.mcaplog.TYPESTORE` message objects:

* ``factory_msgs/DetectedObjectArray`` (``ros/factory_msgs``): what a camera station found in
  one image, each part with the perception seed's fields (class, image centre and radius,
  confidence) plus its pose in the robot base frame, serial and inspection result;
* ``foxglove_msgs/ImageAnnotations``: a circle and a label per detection, which Foxglove's Image
  panel draws over the picture with the same stamp;
* ``diagnostic_msgs/DiagnosticArray``: one ``DiagnosticStatus`` per cell component (level OK,
  WARN, ERROR, STALE; key values), for Foxglove's Diagnostics panel and ``rqt_robot_monitor``.

Units: metres and radians for poses, pixels in the image, as each field's comment says.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from factory.errors import McapError
from factory.mcaplog import TYPESTORE, ros_time

_T = TYPESTORE.types
_Header = _T["std_msgs/msg/Header"]
_Pose = _T["geometry_msgs/msg/Pose"]
_Point = _T["geometry_msgs/msg/Point"]
_Quaternion = _T["geometry_msgs/msg/Quaternion"]
_DetectedObject = _T["factory_msgs/msg/DetectedObject"]
_DetectedObjectArray = _T["factory_msgs/msg/DetectedObjectArray"]
_ImageAnnotations = _T["foxglove_msgs/msg/ImageAnnotations"]
_CircleAnnotation = _T["foxglove_msgs/msg/CircleAnnotation"]
_TextAnnotation = _T["foxglove_msgs/msg/TextAnnotation"]
_Point2 = _T["foxglove_msgs/msg/Point2"]
_Color = _T["foxglove_msgs/msg/Color"]
_DiagnosticArray = _T["diagnostic_msgs/msg/DiagnosticArray"]
_DiagnosticStatus = _T["diagnostic_msgs/msg/DiagnosticStatus"]
_KeyValue = _T["diagnostic_msgs/msg/KeyValue"]

#: DiagnosticStatus levels by name (diagnostic_msgs: OK 0, WARN 1, ERROR 2, STALE 3).
LEVELS = {"OK": 0, "WARN": 1, "ERROR": 2, "STALE": 3}


@dataclass(frozen=True)
class Detection:
    """One part a camera station found, in the units of the message fields.

    Attributes
    ----------
    class_name : str
        ``"blank"`` or ``"part"``.
    center_px : (float, float)
        Centre in the image [px].
    radius_px : float
        Radius of the circle around the footprint in the image [px], >= 0.
    confidence : float
        Match score in [0, 1].
    xyz : (float, float, float)
        Footprint centroid in the robot base frame [m].
    yaw : float
        Rotation about base z [rad].
    serial : str
    inspected, passed : bool
    max_deviation, tolerance : float
        [m]; 0 when not inspected.
    """

    class_name: str
    center_px: tuple[float, float]
    radius_px: float
    confidence: float
    xyz: tuple[float, float, float]
    yaw: float
    serial: str
    inspected: bool = False
    passed: bool = False
    max_deviation: float = 0.0
    tolerance: float = 0.0


def _header(frame_id: str, stamp_ns: int) -> Any:
    return _Header(stamp=ros_time(stamp_ns), frame_id=frame_id)


def _check(d: Detection) -> None:
    values = (*d.center_px, d.radius_px, d.confidence, *d.xyz, d.yaw, d.max_deviation, d.tolerance)
    if not np.isfinite(values).all() or d.radius_px < 0 or not 0 <= d.confidence <= 1:
        raise McapError(f"detection {d.serial}: non-finite value, negative radius or confidence outside [0, 1]")


def detected_object_array(detections: Sequence[Detection], step: str, outcome: str, frame_id: str,
                          stamp_ns: int, base_frame: str) -> Any:
    """``factory_msgs/DetectedObjectArray`` sharing the image's header (``frame_id``, ``stamp_ns``).

    Raises
    ------
    McapError
        A detection with a non-finite value, a negative radius or a confidence outside [0, 1].
    """
    header = _header(frame_id, stamp_ns)
    objects = []
    for d in detections:
        _check(d)
        half = 0.5 * float(d.yaw)
        objects.append(_DetectedObject(
            header=header, class_name=d.class_name, center_x=float(d.center_px[0]), center_y=float(d.center_px[1]),
            radius=float(d.radius_px), confidence=float(d.confidence),
            pose=_Pose(position=_Point(x=float(d.xyz[0]), y=float(d.xyz[1]), z=float(d.xyz[2])),
                       orientation=_Quaternion(x=0.0, y=0.0, z=float(np.sin(half)), w=float(np.cos(half)))),
            base_frame=base_frame, serial=d.serial, inspected=bool(d.inspected), inspection_passed=bool(d.passed),
            max_deviation=float(d.max_deviation), tolerance=float(d.tolerance)))
    return _DetectedObjectArray(header=header, step=step, outcome=outcome, objects=objects)


def _color(r: float, g: float, b: float, a: float = 1.0) -> Any:
    return _Color(r=r, g=g, b=b, a=a)


_GREEN, _RED, _BLUE = _color(0.1, 0.85, 0.2), _color(0.95, 0.15, 0.1), _color(0.1, 0.5, 1.0)


def image_annotations(detections: Sequence[Detection], stamp_ns: int) -> Any:
    """``foxglove_msgs/ImageAnnotations`` over the image stamped ``stamp_ns``: per detection a circle
    (green: passed inspection, red: failed, blue: located) and a label with class, serial and
    confidence above it [px]."""
    stamp = ros_time(stamp_ns)
    circles, texts = [], []
    for d in detections:
        _check(d)
        colour = (_GREEN if d.passed else _RED) if d.inspected else _BLUE
        cx, cy = float(d.center_px[0]), float(d.center_px[1])
        circles.append(_CircleAnnotation(timestamp=stamp, position=_Point2(x=cx, y=cy),
                                         diameter=2.0 * float(d.radius_px), thickness=2.0,
                                         fill_color=_color(0.0, 0.0, 0.0, 0.0), outline_color=colour, metadata=[]))
        verdict = (" pass" if d.passed else " FAIL") if d.inspected else ""
        texts.append(_TextAnnotation(timestamp=stamp, position=_Point2(x=cx - float(d.radius_px),
                                                                       y=cy - float(d.radius_px) - 6.0),
                                     text=f"{d.class_name} {d.serial} {d.confidence:.2f}{verdict}", font_size=14.0,
                                     text_color=colour, background_color=_color(0.0, 0.0, 0.0, 0.5), metadata=[]))
    return _ImageAnnotations(timestamp=stamp, circles=circles, points=[], texts=texts, metadata=[])


@dataclass(frozen=True)
class ComponentStatus:
    """The health of one cell component at one time.

    Attributes
    ----------
    name : str
        ``"cell/machine"``, ``"cell/robot"``, ``"cell/camera"``, ``"cell/scheduler"``.
    level : str
        ``"OK"``, ``"WARN"``, ``"ERROR"`` or ``"STALE"``.
    message : str
    values : mapping of str to str
        Key values (units in the key names).
    """

    name: str
    level: str
    message: str
    values: Mapping[str, str]


def diagnostic_array(statuses: Iterable[ComponentStatus], stamp_ns: int) -> Any:
    """``diagnostic_msgs/DiagnosticArray`` of ``statuses`` (``hardware_id`` = the name).

    Raises
    ------
    McapError
        An unknown level.
    """
    out = []
    for s in statuses:
        if s.level not in LEVELS:
            raise McapError(f"diagnostic {s.name}: unknown level {s.level!r}; use {', '.join(LEVELS)}")
        out.append(_DiagnosticStatus(level=LEVELS[s.level], name=s.name, message=s.message, hardware_id=s.name,
                                     values=[_KeyValue(key=k, value=str(v)) for k, v in s.values.items()]))
    return _DiagnosticArray(header=_header("", stamp_ns), status=out)


__all__ = ["LEVELS", "ComponentStatus", "Detection", "detected_object_array", "diagnostic_array",
           "image_annotations"]
