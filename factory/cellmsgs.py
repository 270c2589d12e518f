"""Typed messages of the cell log: detections, their image overlay, and health on /diagnostics.

Pure builders returning :data:`factory.rosmsgs.TYPESTORE` message objects:

* ``factory_msgs/DetectedObjectArray`` (``ros/factory_msgs``): what a camera station found in
  one image, each part with the perception seed's fields (class, image centre and radius,
  confidence) plus its pose in the robot base frame and how far it may be off, serial and
  inspection result with the narrowest burr it resolves;
* ``foxglove_msgs/ImageAnnotations``: a circle and a label per detection, which Foxglove's Image
  panel draws over the picture with the same stamp;
* ``diagnostic_msgs/DiagnosticArray``: one ``DiagnosticStatus`` per cell component (level OK,
  WARN, ERROR, STALE; key values), for Foxglove's Diagnostics panel and ``rqt_robot_monitor``;
* the cell's state as fields (``factory_msgs``): ``SchedulerState``, ``RobotState``,
  ``MachineState``, ``MachineSignal`` (the door and cycle handshake), ``OrderQueue`` of ``OrderStatus`` and ``CellSummary``, so Foxglove's Plot and
  State Transitions panels and ``ros2 topic echo --field`` reach every value.

Units: metres and radians for poses, pixels in the image, as each field's comment says.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from factory.core.errors import McapError
from factory.rosmsgs import TYPESTORE, ros_time

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
_SchedulerState = _T["factory_msgs/msg/SchedulerState"]
_RobotState = _T["factory_msgs/msg/RobotState"]
_MachineState = _T["factory_msgs/msg/MachineState"]
_MachineSignal = _T["factory_msgs/msg/MachineSignal"]
_OrderStatus = _T["factory_msgs/msg/OrderStatus"]
_OrderQueue = _T["factory_msgs/msg/OrderQueue"]
_CellSummary = _T["factory_msgs/msg/CellSummary"]

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
    position_uncertainty : float
        How far the located position may be off [m], >= 0 (:attr:`vision.locate.LocatedPart.sigma_xy`).
    yaw_uncertainty : float
        How far the located yaw may be off [rad], >= 0.
    smallest_burr : float
        The narrowest burr the inspection resolves at the part [m], >= 0; 0 when not inspected
        (:attr:`vision.inspect.Inspection.smallest_burr`).
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
    position_uncertainty: float = 0.0
    yaw_uncertainty: float = 0.0
    smallest_burr: float = 0.0


def _header(frame_id: str, stamp_ns: int) -> Any:
    return _Header(stamp=ros_time(stamp_ns), frame_id=frame_id)


def _check(d: Detection) -> None:
    sizes = (d.radius_px, d.position_uncertainty, d.yaw_uncertainty, d.smallest_burr)
    values = (*d.center_px, d.confidence, *d.xyz, d.yaw, d.max_deviation, d.tolerance, *sizes)
    if not np.isfinite(values).all() or min(sizes) < 0 or not 0 <= d.confidence <= 1:
        raise McapError(f"detection {d.serial}: non-finite value, negative radius, uncertainty or burr, "
                        "or confidence outside [0, 1]")


def detected_object_array(detections: Sequence[Detection], step: str, outcome: str, frame_id: str,
                          stamp_ns: int, base_frame: str) -> Any:
    """``factory_msgs/DetectedObjectArray`` sharing the image's header (``frame_id``, ``stamp_ns``).

    Raises
    ------
    McapError
        A detection with a non-finite value, a negative radius, uncertainty or smallest burr, or a
        confidence outside [0, 1].
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
            max_deviation=float(d.max_deviation), tolerance=float(d.tolerance),
            position_uncertainty=float(d.position_uncertainty), yaw_uncertainty=float(d.yaw_uncertainty),
            smallest_burr=float(d.smallest_burr)))
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


def scheduler_state(state: str, event: str, order: str, serial: str, message: str, stamp_ns: int) -> Any:
    """``factory_msgs/SchedulerState``: a job's new state and the event that moved it."""
    return _SchedulerState(header=_header("", stamp_ns), state=state, event=event, order=order, serial=serial,
                           message=message)


def robot_state(activity: str, order: str, serial: str, stamp_ns: int) -> Any:
    """``factory_msgs/RobotState``: the robot's activity (``"idle"`` with empty order and serial)."""
    return _RobotState(header=_header("", stamp_ns), activity=activity, order=order, serial=serial)


def machine_signal(operation: str, signal: str, direction: str, number: int, level: bool, order: str, serial: str,
                   stamp_ns: int) -> Any:
    """``factory_msgs/MachineSignal``: one operation of the machine handshake (:mod:`robotprog.machineio`)."""
    return _MachineSignal(header=_header("", stamp_ns), operation=operation, signal=signal, direction=direction,
                          number=int(number), level=bool(level), order=order, serial=serial)


def machine_state(state: str, order: str, serial: str, stamp_ns: int, *, tool: int = 0, spindle_rpm: float = 0.0,
                  spindle_load: float = 0.0, feed_mm_min: float = 0.0,
                  tool_position: Sequence[float] = (0.0, 0.0, 0.0), line: int = 0, progress: float = 0.0,
                  frame_id: str = "work") -> Any:
    """``factory_msgs/MachineState``.

    Parameters
    ----------
    tool_position : (3,) float
        Tool tip in ``frame_id`` [m].
    spindle_rpm : float
        [rev/min]; ``spindle_load`` [% of the rated power]; ``feed_mm_min`` [mm/min];
        ``progress`` in [0, 1].

    Raises
    ------
    McapError
        A non-finite value, a negative speed, load or feed, or progress outside [0, 1].
    """
    values = (spindle_rpm, spindle_load, feed_mm_min, *tool_position, progress)
    if not np.isfinite(values).all() or min(spindle_rpm, spindle_load, feed_mm_min) < 0 or not 0 <= progress <= 1:
        raise McapError(f"machine state of {serial or 'the machine'}: non-finite value, negative speed, load or "
                        f"feed, or progress {progress} outside [0, 1]")
    x, y, z = (float(v) for v in tool_position)
    return _MachineState(header=_header(frame_id, stamp_ns), state=state, order=order, serial=serial, tool=int(tool),
                         spindle_speed_rpm=float(spindle_rpm), spindle_load_percent=float(spindle_load),
                         feed_mm_per_min=float(feed_mm_min),
                         tool_position=_Point(x=x, y=y, z=z), program_line=int(line),
                         program_progress=float(progress))


@dataclass(frozen=True)
class OrderLine:
    """One order's status for :func:`order_queue` (counts of parts; ``state`` queued, running,
    done, rejected or failed)."""

    id: str
    part: str
    material: str
    quantity: int
    good: int
    rejected: int
    state: str
    reason: str = ""


def order_queue(lines: Iterable[OrderLine], stamp_ns: int) -> Any:
    """``factory_msgs/OrderQueue`` of every order, in the given (priority) order."""
    return _OrderQueue(header=_header("", stamp_ns), orders=[
        _OrderStatus(id=o.id, part=o.part, material=o.material, quantity=int(o.quantity), good=int(o.good),
                     rejected=int(o.rejected), state=o.state, reason=o.reason) for o in lines])


def cell_summary(summary: Mapping[str, Any], stamp_ns: int) -> Any:
    """``factory_msgs/CellSummary`` of a simulation's summary dict
    (:attr:`robotprog.cellsim.SimulationResult.summary`, with the OEE terms of
    :mod:`robotprog.oee`; figures that are ``None`` when no part was made become 0)."""
    good, rejected = int(summary["parts_good"]), int(summary["parts_rejected"])
    faults = dict(summary.get("faults", {}))
    orders = dict(summary.get("orders", {}))
    return _CellSummary(
        header=_header("", stamp_ns), makespan_s=float(summary["makespan_s"]), parts_good=good,
        parts_rejected=rejected, parts_per_hour=float(summary["parts_per_hour"]),
        robot_utilisation=float(summary["robot_utilisation"]),
        machine_utilisation=float(summary["machine_utilisation"]),
        availability=float(summary.get("availability") or 0.0),
        performance=float(summary.get("performance") or 0.0), quality=float(summary.get("quality") or 0.0),
        oee=float(summary.get("oee") or 0.0), downtime_s=float(summary.get("downtime_s") or 0.0),
        run_time_s=float(summary.get("run_time_s") or 0.0),
        cycle_time_s=float(summary.get("cycle_time_s") or 0.0),
        mean_flow_time_s=float(summary.get("mean_flow_time_s") or 0.0),
        orders_done=int(orders.get("done", 0)), orders_rejected=int(orders.get("rejected", 0)),
        orders_failed=int(orders.get("failed", 0)), fault_kinds=list(faults),
        fault_counts=np.array([int(n) for n in faults.values()], dtype=np.uint32),
        recoveries=int(summary.get("recoveries", 0)), failures=int(summary.get("failures", 0)))


__all__ = ["LEVELS", "ComponentStatus", "Detection", "OrderLine", "cell_summary", "detected_object_array",
           "diagnostic_array", "image_annotations", "machine_state", "order_queue", "robot_state", "scheduler_state"]
