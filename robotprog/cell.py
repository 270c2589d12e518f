"""The robot cell as data: robot, gripper, stock rack, vise, enclosure, out-tray.

A cell file is YAML (format ``factory.cell/1``; the default is ``fixtures/cell.yaml``).
Units follow ROS: metres, radians, seconds.

Poses
-----
Every pose is written ``{xyz: [x, y, z], rpy: [roll, pitch, yaw]}``: the translation [m]
and the orientation as fixed-axis roll about X, then pitch about Y, then yaw about Z [rad]
(the URDF convention, ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``). A pose is the transform
from its parent frame to the named frame, ``transform_parent_to_frame``; the parent is
``world`` (floor, Z up) unless the field says otherwise:

* ``robot.base``: ``transform_world_to_base`` (the robot's base frame, ``base_link`` on a UR);
* ``gripper.tcp``: ``transform_flange_to_tcp`` (TCP: the point between the fingertips,
  Z out of the flange, the gripper's fingers close along Y);
* ``gripper.body.pose``: the gripper body's box in the flange frame (the fingers hang below
  it, their tips at the TCP: :class:`Fingers`);
* ``rack.pose`` / ``out_tray.pose``: the frame of slot (row 0, column 0); slot (r, c) sits
  at ``(c * pitch[0], r * pitch[1], 0)`` in it, Z up out of the slot;
* ``vise.pose``: ``transform_world_to_vise``, origin at the centre of the jaw gap on the
  top of the parallels (where the stock's bottom rests), X along the jaws, Y the
  clamping direction, Z up (see :mod:`robotprog.frames`);
* ``enclosure`` boxes and ``reject_bin``: the pose of each box's centre (the reject bin is
  open at its top; rejected parts are dropped into it from above);
* ``flip_station``: the pose of the centre of the post the robot turns a part over on between
  op 1 and op 2 (:class:`FlipStation`; the part stands on the post's top face, the post's X
  and Y axes the part's, and hangs over the post's ends so the fingers can grip it from the side).

Unknown keys are errors (typos must not be silently ignored), and every error names
its field: ``vise.pose.xyz: expected 3 numbers``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from factory.core.errors import CellError, field_name, shown
from factory.core.yamlfile import load_yaml

FORMAT = "factory.cell/1"


def rpy_matrix(rpy: tuple[float, float, float] | np.ndarray) -> np.ndarray:
    """Rotation matrix ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (3, 3) from roll, pitch, yaw [rad]."""
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


@dataclass(frozen=True)
class Pose:
    """A frame's pose in its parent: translation ``xyz`` [m], orientation ``rpy`` [rad]."""

    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def matrix(self) -> np.ndarray:
        """``transform_parent_to_frame`` as a (4, 4) homogeneous matrix [m]."""
        t = np.eye(4)
        t[:3, :3] = rpy_matrix(self.rpy)
        t[:3, 3] = self.xyz
        return t


@dataclass(frozen=True)
class Box:
    """A collision box: edge lengths ``size`` [m] and the pose of its centre."""

    name: str
    size: tuple[float, float, float]
    pose: Pose


@dataclass(frozen=True)
class RobotSpec:
    """The arm: model, mounting, home configuration.

    Attributes
    ----------
    model : str
        example-robot-data name (``ur5``, ``ur10``, ``panda``) or a URDF path (the cell file's
        ``robot.model`` or ``robot.urdf``; relative paths are relative to the cell file).
        RAPID and KRL programs need an ABB or KUKA arm: a URDF whose file name starts with
        ``abb_`` or ``kuka_`` and whose joint zeros and directions are the controller's axes
        (``fixtures/robots/`` has an IRB 1200-5/0.9 and a KR 6 R900 sixx).
    base : Pose
        ``transform_world_to_base``.
    home : tuple of float
        Home configuration [rad], one per joint.
    flange_frame : str or None
        Override of the model's flange frame (needed for a URDF path).
    payload : float or None
        Rated payload at the flange [kg], the gripper's mass included; None: not given (the
        stock's mass is then not checked).
    """

    model: str
    base: Pose
    home: tuple[float, ...]
    flange_frame: str | None = None
    payload: float | None = None


@dataclass(frozen=True)
class Motion:
    """Motion limits the URDF does not give.

    Attributes
    ----------
    acceleration_limits : tuple of float
        Per joint [rad/s^2] (URDFs carry no acceleration limits).
    speed_scaling : float
        Fraction in (0, 1] of the URDF velocity limits and of ``acceleration_limits``
        that planned motions use.
    """

    acceleration_limits: tuple[float, ...]
    speed_scaling: float = 1.0


@dataclass(frozen=True)
class GripperIO:
    """How the controller drives the gripper.

    Attributes
    ----------
    grip, release : tuple of (int, bool)
        Digital outputs to set (output number, level) to close / open the fingers.
    settle_s : float
        Time to wait after switching before the fingers are known closed/open [s].
    """

    grip: tuple[tuple[int, bool], ...]
    release: tuple[tuple[int, bool], ...]
    settle_s: float = 0.5


@dataclass(frozen=True)
class MachineIO:
    """The machine tool's interface: the robot controller's digital outputs it sets and the
    inputs it waits on (numbers 0-based, as URScript's standard digital I/O; RAPID ``do<n>`` /
    ``di<n>``, KRL ``$OUT[n + 1]`` / ``$IN[n + 1]``).

    Attributes
    ----------
    open_door, close_door : int
        Outputs held high to open / to close the machine's door.
    cycle_start : int
        Output raised to start the machine's cycle, lowered once the machine runs.
    door_open : int
        Input high while the door is fully open (low: closed).
    cycle_done : int
        Input high while the machine is idle with its cycle finished (low: running).
    part_ok : int or None
        Input high when the finished part passed the machine's inspection (valid while
        ``cycle_done`` is high): the program takes it to the out-tray, else to the reject bin.
        ``None``: no verdict, every part goes to the out-tray.

    The signals' meanings and the handshake on them are :mod:`robotprog.machineio`'s.
    """

    open_door: int
    close_door: int
    cycle_start: int
    door_open: int
    cycle_done: int
    part_ok: int | None = None


@dataclass(frozen=True)
class Fingers:
    """The two parallel fingers: boxes whose tips end in the TCP's XY plane, closing along the
    TCP's Y axis, hanging from the gripper body along the tool axis.

    Attributes
    ----------
    length : float
        Along the tool axis (Z), from the body to the tip [m]: how deep the fingers reach
        below the body, so the deepest grip.
    width : float
        Across the closing direction (X) [m].
    thickness : float
        Along the closing direction (Y) [m].
    stroke : float
        Travel of each finger [m]; the two together cover ``opening.max - opening.min``.
    clearance : float
        How far each finger opens beyond the box it goes to grip, or stays off the box it
        let go [m] (the fingers are never wider open than that: neighbours stand close).
    """

    length: float
    width: float
    thickness: float
    stroke: float
    clearance: float = 0.008

    def boxes(self, opening: float) -> tuple[tuple[tuple[float, float, float], np.ndarray], ...]:
        """(size [m], ``transform_tcp_to_finger`` (4, 4)) of both fingers at ``opening`` [m]
        (the gap between their inner faces)."""
        out = []
        for side in (1.0, -1.0):
            t = np.eye(4)
            t[:3, 3] = (0.0, side * (opening + self.thickness) / 2, -self.length / 2)
            out.append(((self.width, self.thickness, self.length), t))
        return tuple(out)


@dataclass(frozen=True)
class Gripper:
    """Parallel gripper on the flange: a body and two fingers.

    Attributes
    ----------
    tcp : Pose
        ``transform_flange_to_tcp``: between the fingertips.
    opening_min, opening_max : float
        Finger opening range [m]: what the gripper can hold.
    io : GripperIO
    body : Box
        The gripper body (actuator, housing), pose in the flange frame; it must end at or
        above the fingers' root (``fingers.length`` above the TCP).
    fingers : Fingers
    mass : float
        The gripper's own mass [kg], taken off the robot's payload. Default 0.
    """

    tcp: Pose
    opening_min: float
    opening_max: float
    io: GripperIO
    body: Box
    fingers: Fingers
    mass: float = 0.0


@dataclass(frozen=True)
class SlotGrid:
    """A grid of slots (stock rack, out-tray): ``rows`` x ``columns`` at ``pitch`` [m]."""

    pose: Pose
    rows: int
    columns: int
    pitch: tuple[float, float]

    def slot_transform(self, row: int, column: int) -> np.ndarray:
        """``transform_world_to_slot`` (4, 4) [m] of slot (row, column), 0-based.

        Raises
        ------
        CellError
            No such slot.
        """
        if not (0 <= row < self.rows and 0 <= column < self.columns):
            raise CellError(f"no slot ({row}, {column}) in a {self.rows} x {self.columns} grid")
        t = np.eye(4)
        t[:3, 3] = (column * self.pitch[0], row * self.pitch[1], 0.0)
        return self.pose.matrix() @ t


#: Soft-jaw kinds for op 2 (the part flipped, held on its finished faces): ``pocket`` jaws
#: milled to the part's outline, or plain ``parallels`` under the finished faces.
SOFT_JAW_KINDS = ("pocket", "parallels")


@dataclass(frozen=True)
class SoftJaws:
    """How op 2 holds the flipped part (data only: op 1 never uses it).

    Attributes
    ----------
    kind : {"pocket", "parallels"}
        ``pocket``: soft jaws with a pocket shaped like the part's outline; ``parallels``:
        plain jaws, the part's finished top face resting on parallels.
    depth : float
        How deep the part sits in the pocket, or how far the jaws grip the part above the
        parallels [m].
    """

    kind: str
    depth: float


#: Default gap between each open jaw and the blank's side as the robot sets it down [m]: the jaws
#: of a vise a robot loads stand open a few millimetres beyond the blank (an automatic vise's
#: stroke per jaw is 2.5-6 mm), and close on it once the robot has let go.
PLACE_CLEARANCE = 0.003


@dataclass(frozen=True)
class Vise:
    """The machine vise and how it holds the stock in op 1.

    Heights are measured up from the vise bed (the floor of the jaw gap); the vise frame's
    origin is on top of the parallels, where the stock's bottom rests.

    Attributes
    ----------
    pose : Pose
        ``transform_world_to_vise`` (origin: centre of the jaw gap on the parallels).
    jaw_opening_min, jaw_opening_max : float
        Stock widths (along vise Y) the vise can clamp [m].
    jaw_height : float
        Top of the jaws above the vise bed [m].
    jaw_width : float
        Length of the jaws along vise X [m].
    parallels_height : float
        Top of the parallels above the vise bed [m]: the stock's bottom rests there (0: the
        stock rests on the bed).
    jaw_thickness : float
        Thickness of each jaw plate along vise Y [m] (drawn and checked as an obstacle).
    soft_jaws : SoftJaws or None
        Soft jaws for op 2; None: op 2 uses the plain jaws on parallels.
    place_clearance : float
        How far each open jaw stands off the blank's side when the robot sets the blank down
        between them [m] (:mod:`robotprog.seat`): a blank set down further off than this lands
        on a jaw. Default :data:`PLACE_CLEARANCE`.
    """

    pose: Pose
    jaw_opening_min: float
    jaw_opening_max: float
    jaw_height: float
    jaw_width: float = 0.15
    parallels_height: float = 0.0
    jaw_thickness: float = 0.02
    soft_jaws: SoftJaws | None = None
    place_clearance: float = PLACE_CLEARANCE

    @property
    def grip_depth(self) -> float:
        """How far up the stock the jaws reach and grip: jaw top above the parallels [m]. The
        holding allowance under the part must exceed it, or the tool would reach the jaws."""
        return self.jaw_height - self.parallels_height


@dataclass(frozen=True)
class FlipStation:
    """The post the robot turns a part over on between op 1 and op 2 (a regrasp table).

    Attributes
    ----------
    post : Box
        The post, floor to its top face (a collision box); the part is set down centred on
        its top face, edges along its X and Y, and gripped from the side where it overhangs.
    """

    post: Box

    def transform_world_to_top(self) -> np.ndarray:
        """(4, 4) frame on the centre of the post's top face, axes the post's [m]."""
        t = self.post.pose.matrix()
        t[:3, 3] += t[:3, 2] * self.post.size[2] / 2
        return t


@dataclass(frozen=True)
class Enclosure:
    """The machine enclosure: fixed walls and the door (a collision box while closed)."""

    walls: tuple[Box, ...]
    door: Box


@dataclass(frozen=True)
class Cell:
    """A robot cell. See the module docstring for frames and units."""

    name: str
    robot: RobotSpec
    motion: Motion
    gripper: Gripper
    rack: SlotGrid
    vise: Vise
    enclosure: Enclosure
    out_tray: SlotGrid
    source: str | None = None
    #: Open bin rejected parts are dropped into (its box is an obstacle); ``None``: no reject move.
    reject_bin: Box | None = None
    #: The machine tool's door and cycle signals; ``None``: programs do not drive the machine.
    machine: MachineIO | None = None
    #: Where the part is turned over between op 1 and op 2; ``None``: the cell runs one operation.
    flip_station: FlipStation | None = None


# --- parsing ---------------------------------------------------------------------------


class _Reader:
    """Field access with error messages that name the field's path."""

    def __init__(self, source: str | None):
        self.source = source

    def fail(self, field: str, message: str) -> CellError:
        return CellError(f"{field or 'cell'}: {message}", source=self.source)

    def mapping(self, value: Any, field: str, required: set[str], optional: set[str] = frozenset()) -> Mapping:
        if not isinstance(value, Mapping):
            raise self.fail(field, "expected a mapping")
        prefix = f"{field}." if field else ""
        unknown = sorted(str(k) for k in value if k not in required | optional)
        if unknown:
            allowed = ", ".join(sorted(required | optional))
            raise self.fail(f"{prefix}{field_name(unknown[0])}", f"unknown key (allowed: {allowed})")
        for k in sorted(required):
            if k not in value:
                raise self.fail(f"{prefix}{k}", "missing")
        return value

    def number(self, value: Any, field: str, *, positive: bool = False, nonneg: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(field, f"expected a number, got {shown(value)}")
        if positive and value <= 0:
            raise self.fail(field, f"must be > 0, got {value}")
        if nonneg and value < 0:
            raise self.fail(field, f"must be >= 0, got {value}")
        return float(value)

    def integer(self, value: Any, field: str, *, minimum: int = 0) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(field, f"expected an integer, got {shown(value)}")
        if value < minimum:
            raise self.fail(field, f"must be >= {minimum}, got {value}")
        return value

    def numbers(self, value: Any, field: str, n: int | None = None, **kw: bool) -> tuple[float, ...]:
        if not isinstance(value, (list, tuple)) or (n is not None and len(value) != n) or len(value) == 0:
            raise self.fail(field, f"expected {n if n is not None else 'a list of'} numbers")
        return tuple(self.number(v, f"{field}[{i}]", **kw) for i, v in enumerate(value))

    def string(self, value: Any, field: str) -> str:
        if not isinstance(value, str) or not value:
            raise self.fail(field, f"expected a non-empty string, got {shown(value)}")
        return value

    def pose(self, value: Any, field: str) -> Pose:
        m = self.mapping(value, field, {"xyz"}, {"rpy"})
        xyz = self.numbers(m["xyz"], f"{field}.xyz", 3)
        rpy = self.numbers(m.get("rpy", [0.0, 0.0, 0.0]), f"{field}.rpy", 3)
        return Pose(xyz, rpy)  # type: ignore[arg-type]

    def box(self, value: Any, field: str, default_name: str) -> Box:
        m = self.mapping(value, field, {"size", "pose"}, {"name"})
        name = self.string(m.get("name", default_name), f"{field}.name")
        size = self.numbers(m["size"], f"{field}.size", 3, positive=True)
        return Box(name, size, self.pose(m["pose"], f"{field}.pose"))  # type: ignore[arg-type]

    def outputs(self, value: Any, field: str) -> tuple[tuple[int, bool], ...]:
        if not isinstance(value, Mapping) or not value:
            raise self.fail(field, "expected a mapping of output number to level, e.g. {0: true}")
        out = []
        for k, v in value.items():
            self.integer(k, f"{field}.{k}")
            if not isinstance(v, bool):
                raise self.fail(f"{field}.{k}", f"expected true or false, got {shown(v)}")
            out.append((int(k), v))
        return tuple(sorted(out))

    def grid(self, value: Any, field: str) -> SlotGrid:
        m = self.mapping(value, field, {"pose", "rows", "columns", "pitch"})
        return SlotGrid(
            self.pose(m["pose"], f"{field}.pose"),
            self.integer(m["rows"], f"{field}.rows", minimum=1),
            self.integer(m["columns"], f"{field}.columns", minimum=1),
            self.numbers(m["pitch"], f"{field}.pitch", 2, positive=True),  # type: ignore[arg-type]
        )


def read_cell(data: Any, source: str | Path | None = None) -> Cell:
    """Parse and validate a cell document (the YAML already loaded).

    Raises
    ------
    CellError
        Wrong format, missing or unknown key, or a malformed value; the message names the field.
    """
    src = None if source is None else str(source)
    rd = _Reader(src)
    top = rd.mapping(
        data, "", {"format", "robot", "motion", "gripper", "rack", "vise", "enclosure", "out_tray"},
        {"name", "reject_bin", "machine", "flip_station"},
    )
    if top["format"] != FORMAT:
        raise rd.fail("format", f"expected {FORMAT!r}, got {shown(top['format'])}")
    name = rd.string(top.get("name", "cell"), "name")

    r = rd.mapping(top["robot"], "robot", {"base", "home"}, {"model", "urdf", "flange_frame", "payload"})
    if ("model" in r) == ("urdf" in r):
        raise rd.fail("robot", "expected one of model (a known robot's name) or urdf (a .urdf path)")
    if "urdf" in r:
        model = rd.string(r["urdf"], "robot.urdf")
        if not model.lower().endswith(".urdf"):
            raise rd.fail("robot.urdf", f"expected a path to a .urdf file, got {shown(model)}")
    else:
        model = rd.string(r["model"], "robot.model")
    if src is not None and model.lower().endswith(".urdf") and not Path(model).is_absolute():
        model = str(Path(src).parent / model)
    flange = None if r.get("flange_frame") is None else rd.string(r["flange_frame"], "robot.flange_frame")
    payload = rd.number(r["payload"], "robot.payload", positive=True) if "payload" in r else None
    robot = RobotSpec(model, rd.pose(r["base"], "robot.base"), rd.numbers(r["home"], "robot.home"), flange, payload)

    mo = rd.mapping(top["motion"], "motion", {"acceleration_limits"}, {"speed_scaling"})
    accel = rd.numbers(mo["acceleration_limits"], "motion.acceleration_limits", positive=True)
    if len(accel) != len(robot.home):
        raise rd.fail(
            "motion.acceleration_limits", f"expected {len(robot.home)} numbers (one per joint of robot.home)"
        )
    scaling = rd.number(mo.get("speed_scaling", 1.0), "motion.speed_scaling", positive=True)
    if scaling > 1:
        raise rd.fail("motion.speed_scaling", f"must be in (0, 1], got {scaling}")
    motion = Motion(accel, scaling)

    g = rd.mapping(top["gripper"], "gripper", {"tcp", "opening", "io", "body", "fingers"}, {"mass"})
    op = rd.mapping(g["opening"], "gripper.opening", {"min", "max"})
    omin = rd.number(op["min"], "gripper.opening.min", nonneg=True)
    omax = rd.number(op["max"], "gripper.opening.max", positive=True)
    if omax <= omin:
        raise rd.fail("gripper.opening", f"max ({omax}) must exceed min ({omin})")
    io = rd.mapping(g["io"], "gripper.io", {"grip", "release"}, {"settle_s"})
    gio = GripperIO(
        rd.outputs(io["grip"], "gripper.io.grip"),
        rd.outputs(io["release"], "gripper.io.release"),
        rd.number(io.get("settle_s", 0.5), "gripper.io.settle_s", nonneg=True),
    )
    fm = rd.mapping(g["fingers"], "gripper.fingers", {"length", "width", "thickness", "stroke"}, {"clearance"})
    fingers = Fingers(
        rd.number(fm["length"], "gripper.fingers.length", positive=True),
        rd.number(fm["width"], "gripper.fingers.width", positive=True),
        rd.number(fm["thickness"], "gripper.fingers.thickness", positive=True),
        rd.number(fm["stroke"], "gripper.fingers.stroke", positive=True),
        rd.number(fm.get("clearance", 0.008), "gripper.fingers.clearance", nonneg=True),
    )
    if 2 * fingers.stroke < omax - omin - 1e-9:
        raise rd.fail("gripper.fingers.stroke", f"two fingers of {fingers.stroke} m stroke cannot open "
                      f"from opening.min {omin} to opening.max {omax}")
    tcp = rd.pose(g["tcp"], "gripper.tcp")
    body = rd.box(g["body"], "gripper.body", "gripper")
    corners = np.array([[x, y, z] for x in (-.5, .5) for y in (-.5, .5) for z in (-.5, .5)]) * body.size
    t_tcp_body = np.linalg.inv(tcp.matrix()) @ body.pose.matrix()
    reach = float((corners @ t_tcp_body[:3, :3].T + t_tcp_body[:3, 3])[:, 2].max())
    if reach > -fingers.length + 1e-9:
        raise rd.fail("gripper.body", f"reaches {(reach + fingers.length) * 1000:.1f} mm past the fingers' root "
                      f"({fingers.length * 1000:.1f} mm above the TCP): the fingers would not reach below it")
    mass = rd.number(g.get("mass", 0.0), "gripper.mass", nonneg=True)
    if payload is not None and mass >= payload:
        raise rd.fail("gripper.mass", f"{mass:g} kg leaves nothing of the robot's {payload:g} kg payload")
    gripper = Gripper(tcp, omin, omax, gio, body, fingers, mass)

    vise = _vise(rd, top["vise"])

    e = rd.mapping(top["enclosure"], "enclosure", {"walls", "door"})
    if not isinstance(e["walls"], list) or not e["walls"]:
        raise rd.fail("enclosure.walls", "expected a list of boxes")
    walls = tuple(rd.box(w, f"enclosure.walls[{i}]", f"wall{i}") for i, w in enumerate(e["walls"]))
    enclosure = Enclosure(walls, rd.box(e["door"], "enclosure.door", "door"))

    return Cell(
        name, robot, motion, gripper, rd.grid(top["rack"], "rack"), vise, enclosure,
        rd.grid(top["out_tray"], "out_tray"), src,
        None if top.get("reject_bin") is None else rd.box(top["reject_bin"], "reject_bin", "reject_bin"),
        None if top.get("machine") is None else _machine_io(rd, top["machine"], gio),
        None if top.get("flip_station") is None else _flip_station(rd, top["flip_station"]),
    )


def _vise(rd: _Reader, value: Any) -> Vise:
    v = rd.mapping(value, "vise", {"pose", "jaw_opening", "jaw_height"},
                   {"jaw_width", "jaw_thickness", "parallels_height", "soft_jaws", "place_clearance"})
    jo = rd.mapping(v["jaw_opening"], "vise.jaw_opening", {"min", "max"})
    jmin = rd.number(jo["min"], "vise.jaw_opening.min", nonneg=True)
    jmax = rd.number(jo["max"], "vise.jaw_opening.max", positive=True)
    if jmax <= jmin:
        raise rd.fail("vise.jaw_opening", f"max ({jmax}) must exceed min ({jmin})")
    jaw_height = rd.number(v["jaw_height"], "vise.jaw_height", positive=True)
    parallels = rd.number(v.get("parallels_height", 0.0), "vise.parallels_height", nonneg=True)
    if parallels >= jaw_height:
        raise rd.fail("vise.parallels_height", f"{parallels} m reaches the jaws' top ({jaw_height} m above the "
                      "bed): the jaws would grip nothing")
    soft = None
    if v.get("soft_jaws") is not None:
        sj = rd.mapping(v["soft_jaws"], "vise.soft_jaws", {"kind", "depth"})
        kind = rd.string(sj["kind"], "vise.soft_jaws.kind")
        if kind not in SOFT_JAW_KINDS:
            raise rd.fail("vise.soft_jaws.kind", f"expected one of {', '.join(SOFT_JAW_KINDS)}, got {shown(kind)}")
        soft = SoftJaws(kind, rd.number(sj["depth"], "vise.soft_jaws.depth", positive=True))
    return Vise(rd.pose(v["pose"], "vise.pose"), jmin, jmax, jaw_height,
                rd.number(v.get("jaw_width", 0.15), "vise.jaw_width", positive=True), parallels,
                rd.number(v.get("jaw_thickness", 0.02), "vise.jaw_thickness", positive=True), soft,
                rd.number(v.get("place_clearance", PLACE_CLEARANCE), "vise.place_clearance", nonneg=True))


def _machine_io(rd: _Reader, value: Any, gripper: GripperIO) -> MachineIO:
    m = rd.mapping(value, "machine", {"io"})
    io = rd.mapping(m["io"], "machine.io", {"outputs", "inputs"})
    outs = rd.mapping(io["outputs"], "machine.io.outputs", {"open_door", "close_door", "cycle_start"})
    ins = rd.mapping(io["inputs"], "machine.io.inputs", {"door_open", "cycle_done"}, {"part_ok"})
    o = {k: rd.integer(outs[k], f"machine.io.outputs.{k}", minimum=0) for k in sorted(outs)}
    i = {k: rd.integer(ins[k], f"machine.io.inputs.{k}", minimum=0) for k in sorted(ins)}
    taken = {n for n, _ in gripper.grip + gripper.release}
    seen: dict[int, str] = {}
    for k, n in o.items():
        if n in taken:
            raise rd.fail(f"machine.io.outputs.{k}", f"output {n} already drives the gripper")
        if n in seen:
            raise rd.fail(f"machine.io.outputs.{k}", f"output {n} is also {seen[n]}")
        seen[n] = k
    wired: dict[int, str] = {}
    for k in (k for k in ("door_open", "cycle_done", "part_ok") if k in i):
        if i[k] in wired:
            raise rd.fail(f"machine.io.inputs.{k}", f"input {i[k]} is also {wired[i[k]]}")
        wired[i[k]] = k
    return MachineIO(o["open_door"], o["close_door"], o["cycle_start"], i["door_open"], i["cycle_done"],
                     i.get("part_ok"))


def _flip_station(rd: _Reader, value: Any) -> FlipStation:
    post = rd.box(value, "flip_station", "flip_station")
    rpy = post.pose.rpy
    if abs(rpy[0]) > 1e-9 or abs(rpy[1]) > 1e-9:
        raise rd.fail("flip_station.pose.rpy", f"the post must stand upright (roll and pitch 0), got {list(rpy)}")
    return FlipStation(post)


def load_cell(path: str | Path, *, check_robot: bool = True) -> Cell:
    """Read a cell YAML file; with ``check_robot`` also load the robot and check the
    home configuration against its joint count and limits.

    Raises
    ------
    CellError
        Unreadable file, malformed cell (message names the field), unknown robot, or a
        home configuration the robot cannot take.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise CellError(f"cannot read cell file: {e.strerror}", source=path) from None
    except UnicodeDecodeError:
        raise CellError("cannot read cell file: not UTF-8 text", source=path) from None
    data = load_yaml(text, source=path, error=CellError)
    cell = read_cell(data, path)
    if check_robot:
        check_cell_robot(cell)
    return cell


def check_cell_robot(cell: Cell) -> None:
    """Check the cell's joint-space data against its robot model.

    Raises
    ------
    CellError
        Unknown robot, wrong number of joints in ``robot.home``, or home outside the limits.
    """
    from robotprog.robots import load_robot  # Pinocchio only when the robot is needed

    try:
        robot = load_robot(cell.robot.model, flange_frame=cell.robot.flange_frame)
    except CellError as e:
        raise e.with_source(cell.source or "cell") from None
    home = np.array(cell.robot.home)
    if len(home) != robot.dof:
        raise CellError(f"robot.home: expected {robot.dof} numbers for {robot.name}", source=cell.source)
    bad = np.flatnonzero((home < robot.q_lower) | (home > robot.q_upper))
    if len(bad):
        j = int(bad[0])
        raise CellError(
            f"robot.home[{j}]: {home[j]} rad outside the joint limits "
            f"[{robot.q_lower[j]:.4f}, {robot.q_upper[j]:.4f}] of {robot.joint_names[j]}",
            source=cell.source,
        )
