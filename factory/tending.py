"""The robot half of the plan pipeline: machine tending for one part, its log and its program.

Loads the stock from the rack into the vise and unloads the finished part to the out-tray (a part
in two setups is turned over on the flip station between them: the ``flip: ...`` moves),
collision-checked against the cell, timed within the joint limits (:func:`plan_cell`); logs the
plan as MCAP (robot description, joint states, TF, trajectories, the cell's boxes); the robot
program is :func:`robotprog.programs.post_program`. ``factory robot`` and ``factory plan`` call it.
"""

from __future__ import annotations

import collections
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from factory.core.errors import CellError
from factory.mcaplog import LogBuffer, McapLog
from factory.rosmsgs import (TYPESTORE, JointStateCdr, TfCdr, cube_marker, marker_array, ros_time, string_msg,
                             tf_message, transform_stamped, transform_values, transforms_stamped)
from factory.core.progress import Stopwatch, stage_callback
from factory.core.setupsheet import SetupSheet
from factory.roadmaps import cached_roadmap, roadmap_path
from factory.scene import visuals_scene
from robotprog.cell import Cell, load_cell
from robotprog.collision import CollisionWorld, cell_static_boxes, collision_world
from robotprog.frames import setup_sheet_to_cell
from robotprog.roadmap import Roadmap, RoadmapOnDemand
from robotprog.tending import TendingPlan, part_box_in_vise, plan_tending
from robotprog.visuals import LinkVisual, robot_visuals

log = logging.getLogger(__name__)

_T = TYPESTORE.types
_JointState = _T["sensor_msgs/msg/JointState"]
_JointTrajectory = _T["trajectory_msgs/msg/JointTrajectory"]
_JointTrajectoryPoint = _T["trajectory_msgs/msg/JointTrajectoryPoint"]
_Pose = _T["geometry_msgs/msg/Pose"]
_Point = _T["geometry_msgs/msg/Point"]
_Quaternion = _T["geometry_msgs/msg/Quaternion"]
_Duration = _T["builtin_interfaces/msg/Duration"]
_Header = _T["std_msgs/msg/Header"]

#: Rate of /joint_states and /tf [Hz].
STATE_RATE_HZ = 50.0
#: Rate of the points of each /robot/trajectory message [Hz].
TRAJECTORY_RATE_HZ = 50.0


def _ns(t: float) -> int:
    return int(round(t * 1e9))


def _duration(t: float) -> Any:
    sec, nanosec = divmod(_ns(t), 1_000_000_000)
    return _Duration(sec=int(sec), nanosec=int(nanosec))


def link_frames(world: CollisionWorld) -> list[tuple[str, int]]:
    """(name, frame id) of every link (body frame) to publish on /tf, relative to the base frame."""
    robot = world.robot
    out = []
    for i, f in enumerate(robot.model.frames):
        if f.type == pin.FrameType.BODY and f.name not in (robot.base_frame, "world", "universe"):
            out.append((f.name, i))
    return out


def write_robot_mcap(path: Path, cell: Cell, world: CollisionWorld, plan: TendingPlan, *, overwrite: bool,
                     inputs: dict[str, str]) -> int:
    """Write the plan's MCAP log; returns the number of joint-state samples."""
    with McapLog(path, stage="robot", overwrite=overwrite, inputs=inputs,
                 parameters={"cell": cell.name, "robot": world.robot.name,
                             "durations_s": {n: round(d, 4) for n, d in plan.durations}}) as m:
        return log_tending(m, cell, world, plan)


def read_urdf(world: CollisionWorld) -> str:
    """The robot's URDF text, for /robot_description, as its vendor wrote it.

    Mesh URIs stay ``package://`` (ROS resolves them); they are never turned into paths of this
    machine. Viewers without ROS draw the robot from /robot/visuals, which carries the meshes."""
    try:
        return Path(world.robot.urdf).read_text(encoding="utf-8")
    except OSError as e:
        raise CellError(f"cannot read URDF: {e.strerror}", source=world.robot.urdf) from None


def log_cell(m: McapLog | LogBuffer, cell: Cell, world: CollisionWorld,
             visuals: tuple[LinkVisual, ...] | None = None) -> None:
    """The cell at time 0: /robot_description, /robot/visuals (the links' meshes: ``visuals``, read
    from the robot's URDF when None), /tf_static (robot base, TCP, vise, rack, out-tray) and
    /cell/boxes, all latched."""
    robot = world.robot
    m.write("/robot_description", string_msg(read_urdf(world)), 0, latched=True)
    m.write("/robot/visuals", visuals_scene(robot_visuals(robot) if visuals is None else visuals, 0), 0,
            latched=True)
    static = [
        transform_stamped("world", robot.base_frame, cell.robot.base.matrix(), 0),
        transform_stamped(robot.flange_frame, "tcp", cell.gripper.tcp.matrix(), 0),
        transform_stamped("world", "vise", cell.vise.pose.matrix(), 0),
        transform_stamped("world", "rack", cell.rack.pose.matrix(), 0),
        transform_stamped("world", "out_tray", cell.out_tray.pose.matrix(), 0),
    ]
    m.write("/tf_static", tf_message(static), 0, latched=True)
    markers = []
    for k, b in enumerate(cell_static_boxes(cell, door_closed=False)):
        mk = cube_marker("cell", k, b.pose.xyz, b.size, (0.6, 0.6, 0.65, 0.5), "world", 0)
        qx, qy, qz, qw = _quat(b.pose.matrix())
        mk.pose = _Pose(position=_Point(x=b.pose.xyz[0], y=b.pose.xyz[1], z=b.pose.xyz[2]),
                        orientation=_Quaternion(x=qx, y=qy, z=qz, w=qw))
        mk.text = b.name
        markers.append(mk)
    m.write("/cell/boxes", marker_array(markers), 0, latched=True)


#: Joint paths whose link poses :class:`LinkPoses` keeps [-]: a cell run repeats each part's few moves for every
#: order, so a handful per part serve them all.
POSE_PATHS_KEPT = 64


class LinkPoses:
    """The robot's links in its base frame by forward kinematics, as /tf logs them at each state.

    :meth:`poses` keeps its last :data:`POSE_PATHS_KEPT` answers by the joint positions' bytes: a cell
    simulation logs the same planned moves, sampled alike, once per order (the forward kinematics were
    most of writing its log), and the same positions give the same poses."""

    def __init__(self, world: CollisionWorld):
        robot = world.robot
        self.model, self.data = robot.model, robot.model.createData()
        self.base_frame = robot.base_frame
        self.base_id = robot.model.getFrameId(robot.base_frame)
        self.frames = link_frames(world)
        self.names = [name for name, _ in self.frames]
        self._kept: collections.OrderedDict[bytes, np.ndarray] = collections.OrderedDict()

    def matrices(self, q: np.ndarray) -> np.ndarray:
        """(k, 4, 4) float: each link's pose in the base frame [m] at joint positions ``q`` (dof,) [rad]."""
        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        ob = self.data.oMf[self.base_id].actInv
        return np.array([ob(self.data.oMf[i]).homogeneous for _, i in self.frames])

    def poses(self, q: np.ndarray) -> np.ndarray:
        """(n, k, 7) float: each link's translation [m] and quaternion (x, y, z, w) in the base frame
        at each of the joint positions ``q`` (n, dof) [rad], converted in one pass."""
        q = np.asarray(q, dtype=float).reshape(-1, self.model.nq)
        if not len(q):
            return np.zeros((0, len(self.frames), 7))
        key = q.tobytes()
        poses = self._kept.get(key)
        if poses is None:
            poses = transform_values(np.array([self.matrices(qi) for qi in q]))
            poses.flags.writeable = False  # shared by every caller that asks for these positions
            self._kept[key] = poses
            if len(self._kept) > POSE_PATHS_KEPT:
                self._kept.popitem(last=False)
        else:
            self._kept.move_to_end(key)
        return poses


class RobotStateLog:
    """Writes /joint_states and the links' /tf for configurations of one robot.

    ``m`` is a log (:class:`McapLog`) or :class:`factory.live.Fanout`: both take the messages'
    CDR made directly (:class:`JointStateCdr`, :class:`TfCdr`), the same bytes as the messages
    serialised, without building message objects at every state; sinks that serialise
    themselves get the messages."""

    def __init__(self, m: Any, world: CollisionWorld):
        self.m = m
        self.links = LinkPoses(world)
        self.names = list(world.robot.joint_names)
        self.joint_cdr = JointStateCdr(self.names)
        self.tf_cdr = TfCdr(self.links.base_frame, self.links.names)

    def write(self, q: np.ndarray, qd: np.ndarray, stamp_ns: int, poses: np.ndarray | None = None) -> None:
        """One sample: q [rad], qd [rad/s] at ``stamp_ns``; ``poses``: the links' (k, 7) at ``q``
        (:meth:`LinkPoses.poses`) when made beforehand for a whole move."""
        q, qd = np.asarray(q, dtype=float), np.asarray(qd, dtype=float)
        self.m.write_cdr("/joint_states", "sensor_msgs/msg/JointState", self.joint_cdr.cdr(stamp_ns, q, qd), stamp_ns,
                         lambda: _JointState(header=_Header(stamp=ros_time(stamp_ns), frame_id=""), name=self.names,
                                             position=q, velocity=qd, effort=np.zeros(0)))
        links = self.links
        if poses is None:
            poses = links.poses(q[None])[0]
        self.m.write_cdr("/tf", "tf2_msgs/msg/TFMessage", self.tf_cdr.cdr(stamp_ns, poses), stamp_ns,
                         lambda: tf_message(transforms_stamped(links.base_frame, links.names, links.matrices(q),
                                                               stamp_ns)))


def log_tending(m: McapLog | LogBuffer, cell: Cell, world: CollisionWorld, plan: TendingPlan,
                visuals: tuple[LinkVisual, ...] | None = None) -> int:
    """Write the cell (the robot's meshes ``visuals``, read when None: :func:`log_cell`) and the plan's
    motion (from time 0) into an open log; returns the number of joint-state samples."""
    log_cell(m, cell, world, visuals)
    return log_motion(m, world, plan)


def log_motion(m: McapLog | LogBuffer, world: CollisionWorld, plan: TendingPlan) -> int:
    """Write the plan's motion (from time 0) into an open log, after its cell (:func:`log_cell`): each move's
    trajectory and event, the robot's joint states and link poses; returns the number of joint-state
    samples."""
    robot = world.robot
    names = list(robot.joint_names)
    base = robot.base_frame
    states = RobotStateLog(m, world)
    t0 = 0.0
    n_states = 0
    for mv in plan.moves:
        traj = mv.trajectory
        if mv.kind != "gripper":
            ts = np.arange(0.0, traj.duration, 1.0 / TRAJECTORY_RATE_HZ)
            ts = np.append(ts, traj.duration)
            q, qd, qdd = traj.sample(ts)
            pts = [_JointTrajectoryPoint(positions=q[i].astype(float), velocities=qd[i].astype(float),
                                         accelerations=qdd[i].astype(float), effort=np.zeros(0),
                                         time_from_start=_duration(float(ts[i]))) for i in range(len(ts))]
            m.write("/robot/trajectory", _JointTrajectory(
                header=_Header(stamp=ros_time(_ns(t0)), frame_id=base), joint_names=names, points=pts),
                _ns(t0))
        m.write("/robot/events", string_msg(mv.name), _ns(t0))
        dur = mv.duration
        ts = np.arange(0.0, dur, 1.0 / STATE_RATE_HZ)
        if mv is plan.moves[-1]:
            ts = np.append(ts, dur)
        # the move's states and its links' poses at once: the same numbers as one by one
        qs, qds, _ = traj.sample(np.minimum(ts, traj.duration))
        if mv.kind == "gripper":
            qds = np.zeros_like(qds)
        poses = states.links.poses(qs)
        for t, q, qd, pose in zip(ts, qs, qds, poses):
            states.write(q, qd, _ns(t0 + float(t)), pose)
            n_states += 1
        t0 += dur
    return n_states


def _quat(t: np.ndarray) -> tuple[float, float, float, float]:
    from scipy.spatial.transform import Rotation

    return tuple(float(v) for v in Rotation.from_matrix(t[:3, :3]).as_quat())  # type: ignore[return-value]


@dataclass(frozen=True)
class CellPlan:
    """The robot's load and unload of one part, planned in its cell (:func:`plan_cell`).

    Attributes
    ----------
    cell : Cell
        The cell as loaded from its file.
    world : CollisionWorld
        Its collision world, with the robot model loaded (reused to post and log the plan).
    plan : TendingPlan
        The timed moves [s], in the vise frame's metres.
    """

    cell: Cell
    world: CollisionWorld
    plan: TendingPlan


def plan_cell(cell_path: Path, sheet: SetupSheet | Mapping[str, Any], sheet_source: str,
              part_vertices: np.ndarray | None, watch: Stopwatch | None = None, setups: int = 1) -> CellPlan:
    """Load the cell and plan loading and unloading the part a setup sheet (or its JSON) describes.

    ``part_vertices`` are the part mesh's vertices in mesh file units (the sheet's
    ``mesh_scale`` turns them into mm); without them unload grips the stock box. Wall times
    go into ``watch`` (stages ``cell``, then those of :func:`plan_in_cell`). ``setups`` 2: the part is
    turned over on the cell's flip station between op 1 (``sheet``, the op-1 setup sheet) and op 2
    (:func:`robotprog.tending.plan_tending`).

    Raises
    ------
    CellError
        The cell file is malformed.
    PlanningError
        A move cannot be planned (unreachable pose, collision, timing).
    """
    watch = watch if watch is not None else Stopwatch()
    with watch("cell"):
        cell = load_cell(cell_path)
        world = collision_world(cell)
    return CellPlan(cell, world, plan_in_cell(cell, world, cell_path, sheet, sheet_source, part_vertices, watch,
                                              setups))


def plan_in_cell(cell: Cell, world: CollisionWorld, cell_path: Path, sheet: SetupSheet | Mapping[str, Any],
                 sheet_source: str, part_vertices: np.ndarray | None, watch: Stopwatch, setups: int = 1) -> TendingPlan:
    """:func:`plan_cell` in a cell already loaded from ``cell_path`` (named in messages), with its
    collision world: stage ``robot plan``, and within it, when a transfer first needs the cell's
    roadmap, ``roadmap``, or ``building the cell's roadmap`` when none is cached yet
    (:mod:`factory.roadmaps`); each second is counted in one stage."""
    part_box = None
    if part_vertices is not None:
        part_box = part_box_in_vise(setup_sheet_to_cell(sheet, sheet_source), part_vertices)

    def roadmap() -> Roadmap | None:
        # A cell nobody warmed (`factory cell warm`) has its roadmap built by its first plan that needs
        # it, under a stage that says so (a progress bar, the plan's stage times); not a warning line,
        # which would stand before the one line of a plan that then fails. A part the gripper cannot
        # take, or a slot out of reach, fails before: it never waits minutes for a roadmap.
        stage = "roadmap" if roadmap_path(cell).exists() else "building the cell's roadmap"
        with watch(stage):
            try:
                return cached_roadmap(cell, world, progress=stage_callback(watch.progress, stage)).roadmap
            except CellError as e:  # the planner names what is wrong with the cell in its own words
                log.info("%s: no roadmap (%s); planning without", cell_path, e)
                return None

    with watch("robot plan"):
        return plan_tending(cell, sheet, part_box=part_box, world=world, source=sheet_source, setups=setups,
                            roadmap=RoadmapOnDemand(roadmap))
