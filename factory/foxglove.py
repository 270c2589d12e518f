"""A Foxglove layout for the cell-simulation log: one JSON file that opens the log ready to watch.

The file is what Foxglove's "Export layout" writes and "Import layout" reads: a JSON object

* ``configById``: panel id -> that panel's config. A panel id is ``"<PanelType>!<suffix>"``;
  Foxglove reads the panel type from the part before ``!`` and treats the suffix as opaque
  (it makes random base-36 ones; ours are fixed words so the file is deterministic);
* ``layout``: a react-mosaic tree whose leaves are panel ids and whose inner nodes are
  ``{"first", "second", "direction": "row" | "column", "splitPercentage": 0..100}``
  (``row`` puts ``first`` left of ``second``, ``column`` above it);
* ``globalVariables``, ``userNodes`` (user scripts), ``playbackConfig`` (``{"speed": 1.0}``).

Panel types and config fields follow Foxglove Studio 1.87, the last open-source release
(github.com/foxglove/studio, ``packages/studio-base/src``), as continued unchanged in its fork
Lichtblick (github.com/Lichtblick-Suite/lichtblick, ``packages/suite-base/src``). Later, closed
Foxglove releases import layouts exported by 1.x; that was not tried here. Fields a config leaves
out take the panel's defaults.

* ``3D``: ``RendererConfig`` (``panels/ThreeDeeRender/IRenderer.ts``): ``cameraState``
  (``camera.ts``: distance [m], phi and thetaOffset [deg], targetOffset [m], near/far [m]),
  ``followTf`` + ``followMode``, ``scene``, ``transforms`` (``"frame:<id>"`` -> visibility),
  ``topics`` (topic -> ``{"visible": ...}`` plus per-type settings) and ``layers`` (custom
  layers by instance id: ``foxglove.Grid`` in ``renderables/Grids.ts``). The robot is drawn
  from the ``foxglove_msgs/SceneUpdate`` of its link meshes (:mod:`factory.scene`), not from
  the URDF, whose ``package://`` meshes only a ROS install resolves.
* ``Image``: the same renderer in image mode; ``imageMode`` holds ``imageTopic``,
  ``calibrationTopic`` and ``annotations`` (topic -> ``{"visible": ...}``).
* ``StateTransitions``: ``paths`` of ``{"value": message path, "timestampMethod":
  "receiveTime" | "headerStamp", "label"}`` and ``isSynced`` (``panels/StateTransitions/types.ts``).
* ``RosOut`` (the Log panel, legacy type name): ``searchTerms``, ``minLogLevel`` (1 debug, 2 info,
  4 warn, 8 error, 16 fatal; ROS 2 levels are mapped onto these), ``topicToRender``.
* ``DiagnosticSummary``: ``topicToRender``, ``minLevel`` (0 OK .. 3 STALE), ``pinnedIds``,
  ``hardwareIdFilter``, ``sortByLevel`` (``panels/diagnostics/DiagnosticSummary.tsx``).
* ``Plot``: ``paths`` of ``{"value": message path, "enabled", "timestampMethod", "label"}``,
  ``xAxisVal`` ``"timestamp"``, legend and axis switches (``panels/Plot/types.ts``).
* ``RawMessages``: ``topicPath``, ``diffEnabled``, ``diffMethod``, ``diffTopicPath``,
  ``showFullMessageForDiff`` (``panels/RawMessages/types.ts``).

Units: lengths in the 3D view are metres (the ROS frames of the log), angles of the view degrees.
The library builds the dict; writing the file is the CLI's job.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, fields
from typing import Any

from factory.core.errors import McapError

#: Panel ids of the layout, ``"<PanelType>!<suffix>"``.
PANEL_3D = "3D!cell"
PANEL_IMAGE = "Image!camera"
PANEL_STATES = "StateTransitions!cell"
PANEL_LOG = "RosOut!rosout"
PANEL_ORDERS = "RawMessages!orders"
PANEL_DIAGNOSTICS = "DiagnosticSummary!cell"
PANEL_PLOT = "Plot!machine"

# Instance ids of the 3D panel's custom layers (Foxglove makes UUIDs; any unique key works as
# long as ``instanceId`` repeats it).
_GRID_LAYER = "grid"

# Log panel levels (foxglove LogLevel): 1 debug, 2 info, 4 warn, 8 error, 16 fatal.
_LOG_DEBUG = 1


@dataclass(frozen=True)
class CellTopics:
    """Topic names of the cell-simulation log that the layout shows.

    The defaults are what ``factory simulate`` writes. ``/tf``, ``/tf_static`` and
    ``/joint_states`` are not named: the 3D panel subscribes to every transform topic by its
    schema, and the robot's links are posed from ``/tf``.

    Attributes
    ----------
    robot_description : str
        ``std_msgs/String`` with the robot URDF (latched); hidden in the 3D view.
    robot_visuals : str
        ``foxglove_msgs/SceneUpdate``: the robot's link meshes, embedded, each locked to its
        link frame (latched).
    boxes : str
        ``visualization_msgs/MarkerArray``: the cell's static boxes, frame ``world``.
    toolpath, stock : str
        ``MarkerArray``: the part's toolpath and the stock mesh, frame ``work``.
    image : str
        ``sensor_msgs/CompressedImage``: annotated camera frames.
    annotations : str
        ``foxglove_msgs/ImageAnnotations``: each detection's circle and label over ``image``.
    diagnostics : str
        ``diagnostic_msgs/DiagnosticArray``: health of the machine, robot, camera and scheduler.
    camera_info : str
        ``sensor_msgs/CameraInfo`` of ``image``.
    state, robot, machine : str
        ``factory_msgs/SchedulerState`` (``state``: ``IDLE``, ``FETCH_RAW``, ... ``RECOVER``),
        ``RobotState`` (``activity``), ``MachineState`` (``state``: ``idle``, ``cutting``,
        ``reset``, ``alarm``; tool position, feed, spindle speed and load, program line and progress).
    orders : str
        ``factory_msgs/OrderQueue``: every order's status.
    rosout : str
        ``rcl_interfaces/msg/Log``.
    """

    robot_description: str = "/robot_description"
    robot_visuals: str = "/robot/visuals"
    boxes: str = "/cell/boxes"
    toolpath: str = "/machine/toolpath"
    stock: str = "/machine/stock"
    image: str = "/camera/image/compressed"
    annotations: str = "/camera/annotations"
    diagnostics: str = "/diagnostics"
    camera_info: str = "/camera/camera_info"
    state: str = "/cell/state"
    robot: str = "/cell/robot"
    machine: str = "/cell/machine"
    orders: str = "/cell/orders"
    rosout: str = "/rosout"

    def names(self) -> tuple[str, ...]:
        """Every topic name, in field order."""
        return tuple(getattr(self, f.name) for f in fields(self))


@dataclass(frozen=True)
class CellView:
    """Where the 3D view looks from when the layout opens (an orbit camera around a target).

    Attributes
    ----------
    follow_frame : str
        Frame the view renders in and follows (``followTf``).
    target : (3,) float
        Orbit centre in ``follow_frame`` [m]. Default: between the robot base and the vise
        of ``fixtures/cell.yaml``, at table height.
    distance : float
        Camera distance from ``target`` [m], > 0.
    phi_deg : float
        Polar angle of the camera from +Z [deg], in [0, 180]: 0 looks straight down.
    theta_deg : float
        Azimuth of the camera about Z [deg].
    frames : tuple of str
        Frames whose axes are switched on explicitly (the others keep Foxglove's default).
    """

    follow_frame: str = "world"
    target: tuple[float, float, float] = (0.4, 0.0, 0.9)
    distance: float = 3.0
    phi_deg: float = 60.0
    theta_deg: float = 45.0
    frames: tuple[str, ...] = ("world", "vise", "work", "tool")


def _check(topics: CellTopics, view: CellView) -> None:
    for f in fields(topics):
        name = getattr(topics, f.name)
        if not isinstance(name, str) or not name.startswith("/") or len(name) < 2:
            raise McapError(f"layout topic {f.name} must be an absolute topic name, got {name!r}")
    if not isinstance(view.follow_frame, str) or not view.follow_frame:
        raise McapError(f"layout follow frame must be a frame id, got {view.follow_frame!r}")
    if not all(isinstance(f, str) and f for f in view.frames):
        raise McapError(f"layout frames must be frame ids, got {list(view.frames)!r}")
    numbers = (*view.target, view.distance, view.phi_deg, view.theta_deg)
    if (len(view.target) != 3 or not all(math.isfinite(float(v)) for v in numbers)
            or not view.distance > 0 or not 0 <= view.phi_deg <= 180):
        raise McapError("layout view needs a finite 3-vector target [m], a positive distance [m], "
                        f"phi in [0, 180] deg and a finite theta, got {view}")


def _three_d(topics: CellTopics, view: CellView) -> dict[str, Any]:
    """The 3D panel: robot, cell, toolpath and stock, following ``view.follow_frame``."""
    return {
        "cameraState": {
            "distance": float(view.distance),
            "perspective": True,
            "phi": float(view.phi_deg),
            "thetaOffset": float(view.theta_deg),
            # target is where the follow frame puts the orbit centre; the offset moves it.
            "target": [0.0, 0.0, 0.0],
            "targetOffset": [float(v) for v in view.target],
            "targetOrientation": [0.0, 0.0, 0.0, 1.0],
            "fovy": 45.0,
            # Foxglove's default near plane (0.5 m) clips a tabletop cell seen from close by.
            "near": 0.01,
            "far": 100.0,
        },
        "followTf": view.follow_frame,
        "followMode": "follow-pose",
        "scene": {"transforms": {"showLabel": True, "editable": False}},
        "transforms": {f"frame:{f}": {"visible": True} for f in view.frames},
        "topics": {
            # The robot is drawn from its embedded meshes; the URDF's package:// meshes would
            # only load on a machine with ROS (and draw the robot twice there).
            topics.robot_description: {"visible": False},
            topics.robot_visuals: {"visible": True},
            topics.boxes: {"visible": True},
            topics.toolpath: {"visible": True},
            topics.stock: {"visible": True},
            # The camera frustum, 0.3 m deep: shows where the inspection camera looks.
            topics.camera_info: {"visible": True, "distance": 0.3},
        },
        "layers": {
            _GRID_LAYER: {
                "layerId": "foxglove.Grid",
                "instanceId": _GRID_LAYER,
                "label": "Floor 4 m, 0.25 m squares",
                "visible": True,
                "frameLocked": True,
                "frameId": view.follow_frame,
                "size": 4.0,
                "divisions": 16,
                "lineWidth": 1.0,
                "color": "#248eff",
                "position": [0.0, 0.0, 0.0],
                "rotation": [0.0, 0.0, 0.0],
                "order": 1,
            },
        },
        "imageMode": {},
    }


def _image(topics: CellTopics) -> dict[str, Any]:
    """The Image panel (the 3D renderer in image mode) on the camera topic."""
    return {
        "imageMode": {
            "imageTopic": topics.image,
            "calibrationTopic": topics.camera_info,
            # The frames carry the fitted outlines drawn in; the overlay adds class, serial,
            # confidence and the inspection verdict per detection.
            "annotations": {topics.annotations: {"visible": True}},
            "synchronize": False,
        },
    }


def _plot(topics: CellTopics) -> dict[str, Any]:
    """Tool tip height [m] and spindle load [% of the rated power] of the machine against time
    (``factory_msgs/MachineState`` fields ``tool_position.z`` and ``spindle_load_percent``)."""
    rows = ((f"{topics.machine}.tool_position.z", "tool Z [m]"),
            (f"{topics.machine}.spindle_load_percent", "spindle load [%]"))
    return {
        "paths": [{"value": value, "enabled": True, "timestampMethod": "headerStamp", "label": label}
                  for value, label in rows],
        "showLegend": True, "legendDisplay": "floating", "showPlotValuesInLegend": True,
        "showXAxisLabels": True, "showYAxisLabels": True, "isSynced": True, "xAxisVal": "timestamp",
    }


def _state_transitions(topics: CellTopics) -> dict[str, Any]:
    """One State Transitions row each for the scheduler state, robot activity and machine state."""
    rows = ((topics.state, "state", "scheduler"), (topics.robot, "activity", "robot"),
            (topics.machine, "state", "machine"))
    return {
        "paths": [{"value": f"{topic}.{field}", "timestampMethod": "headerStamp", "label": label}
                  for topic, field, label in rows],
        "isSynced": True,
        "showPoints": True,
    }


def cell_layout(topics: CellTopics = CellTopics(), view: CellView = CellView()) -> dict[str, Any]:
    """The Foxglove layout of a cell-simulation log, as a JSON-ready dict.

    A large 3D view on the left (the robot from ``topics.robot_visuals``, cell boxes,
    toolpath, stock, transforms, following ``view.follow_frame``), the state timelines and a
    plot of the tool's height and the spindle load under it; on the right the camera image with its
    detections above the ``/rosout`` log, the components' health (``/diagnostics``) and the
    orders' status.

    Parameters
    ----------
    topics : CellTopics
        Topic names; the defaults are what ``factory simulate`` writes.
    view : CellView
        Initial 3D view: follow frame, orbit target [m], distance [m], angles [deg].

    Returns
    -------
    dict
        ``configById``, ``layout``, ``globalVariables``, ``userNodes``, ``playbackConfig``;
        only str, float, int, bool, list and dict inside. A new dict on every call.

    Raises
    ------
    McapError
        A topic name is not absolute, a frame id is empty, or the view is degenerate.
    """
    _check(topics, view)
    config_by_id = {
        PANEL_3D: _three_d(topics, view),
        PANEL_IMAGE: _image(topics),
        PANEL_STATES: _state_transitions(topics),
        PANEL_PLOT: _plot(topics),
        PANEL_LOG: {"searchTerms": [], "minLogLevel": _LOG_DEBUG, "topicToRender": topics.rosout},
        PANEL_ORDERS: {"topicPath": topics.orders, "diffEnabled": False, "diffMethod": "custom",
                       "diffTopicPath": "", "showFullMessageForDiff": False},
        PANEL_DIAGNOSTICS: {"topicToRender": topics.diagnostics, "minLevel": 0, "pinnedIds": [],
                            "hardwareIdFilter": "", "sortByLevel": True},
    }
    layout = {
        "direction": "row",
        "splitPercentage": 62,
        "first": {"direction": "column", "splitPercentage": 64, "first": PANEL_3D,
                  "second": {"direction": "row", "splitPercentage": 50, "first": PANEL_STATES,
                             "second": PANEL_PLOT}},
        "second": {
            "direction": "column",
            "splitPercentage": 45,
            "first": PANEL_IMAGE,
            "second": {"direction": "column", "splitPercentage": 55, "first": PANEL_LOG,
                       "second": {"direction": "row", "splitPercentage": 50, "first": PANEL_DIAGNOSTICS,
                                  "second": PANEL_ORDERS}},
        },
    }
    return {
        "configById": config_by_id,
        "layout": layout,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1.0},
    }


def layout_json(topics: CellTopics = CellTopics(), view: CellView = CellView()) -> str:
    """:func:`cell_layout` as JSON text: keys sorted, 2-space indent, newline at the end.

    The same arguments give the same bytes, so a regenerated layout diffs clean.
    """
    return json.dumps(cell_layout(topics, view), indent=2, sort_keys=True, allow_nan=False) + "\n"


__all__ = ["PANEL_3D", "PANEL_DIAGNOSTICS", "PANEL_IMAGE", "PANEL_LOG", "PANEL_ORDERS", "PANEL_PLOT", "PANEL_STATES",
           "CellTopics", "CellView", "cell_layout", "layout_json"]
