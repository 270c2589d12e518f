"""Collision checking of the arm, its gripper and the part it holds against the cell.

A :class:`CollisionWorld` is built once from a robot (loaded with its collision geometry)
and a cell. It holds one Pinocchio ``GeometryModel`` (coal underneath) with

* the robot's link collision meshes from the URDF;
* the gripper body's box (``cell.gripper.body``, in the flange frame);
* the cell's static boxes: the enclosure walls and mill table, the door (only when
  ``door_closed``; tending runs with the door open), and boxes the cell file implies
  but does not list (see :func:`cell_static_boxes`): the vise body under the parallels,
  the stock rack and out-tray stands, and the robot's pedestal.

Pairs checked: every link and the gripper against every static box (except the robot's
base link against its own pedestal), and self-collision between link pairs the vendor's
SRDF does not disable (:func:`robot_srdf`: example-robot-data ships
``ur_description/srdf/ur5.srdf`` etc.; for robots without one, all pairs of geometries on
non-adjacent joints). Pairs already in
contact at the home configuration (e.g. the gripper box against the wrist links it is
bolted next to) are dropped, and :attr:`CollisionWorld.dropped_pairs` lists them.

The fingers (at the opening of the move, :func:`finger_boxes`) and a held box (the stock or
finished part, :class:`HeldBox`) ride on the TCP (a :data:`Payload`). Each is shrunk by
:attr:`HeldBox.clearance` per face so that a part resting on a surface (stock on the vise
parallels, in its rack slot) is not a contact, and checked against the static boxes and the
arm's links except those on the flange's joint (the last wrist link, which carries the gripper
holding it). For that the world's geometry is copied once per payload with the riding boxes as
objects of their own on the flange's joint and those pairs added after the world's
(:meth:`CollisionWorld.riding`), so one coal pass checks everything, pair by pair.

Frames: everything is placed in the Pinocchio model's root frame; the cell's world frame
enters through ``cell.robot.base`` (``transform_world_to_base``). Units: metres, radians.
"""

from __future__ import annotations

import logging
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import coal
import numpy as np
import pinocchio as pin

from factory.core.errors import CellError, PlanningError
from robotprog.cell import Box, Cell, Pose
from robotprog.robots import Robot, load_robot

log = logging.getLogger(__name__)

#: Height of the vise body below the parallels [m] (to the mill table top in the default cell).
VISE_BODY_HEIGHT = 0.06
#: Vise body length along the jaws [m].
VISE_BODY_LENGTH = 0.15
#: Extra width of the vise body beyond the largest jaw opening [m].
VISE_BODY_MARGIN = 0.12
#: Margin of the rack / out-tray stands around the slot grid [m].
STAND_MARGIN = 0.05
#: Pedestal footprint under the robot base [m] (square).
PEDESTAL_SIZE = 0.25
#: A pair whose broad-phase bound keeps it this much farther apart than its margin is not asked of
#: coal [m] (beyond rounding: the bound is exact for spheres and boxes).
BROAD_PHASE_SLACK = 1e-6


@dataclass(frozen=True)
class HeldBox:
    """A box held by the gripper: the stock or the finished part.

    Attributes
    ----------
    size : (3,) float
        Edge lengths [m].
    transform_tcp_to_box : (4, 4) float
        Pose of the box centre in the TCP frame [m].
    clearance : float
        Shrink per face when checking [m], so a part resting on a surface is free.
    name : str
        What it is in contact messages (``held``, ``finger``).
    """

    size: tuple[float, float, float]
    transform_tcp_to_box: tuple[tuple[float, ...], ...]
    clearance: float = 0.001
    name: str = "held"

    @staticmethod
    def at(size: np.ndarray, transform_tcp_to_box: np.ndarray, clearance: float = 0.001,
           name: str = "held") -> "HeldBox":
        """A HeldBox from arrays."""
        return HeldBox(tuple(float(s) for s in size),
                       tuple(tuple(float(x) for x in row) for row in np.asarray(transform_tcp_to_box)), clearance,
                       name)


#: What rides on the TCP during a move: nothing, one box, or several (the fingers at their
#: opening and the box they hold).
Payload = HeldBox | tuple[HeldBox, ...] | None


def finger_boxes(cell: Cell, opening: float) -> tuple[HeldBox, ...]:
    """The gripper's two fingers at ``opening`` [m] as boxes riding on the TCP (checked exactly,
    no clearance: a finger beside a blank must not touch the surface it stands on)."""
    return tuple(HeldBox.at(size, t, 0.0, "finger") for size, t in cell.gripper.fingers.boxes(opening))


def _riding(held: Payload) -> tuple[HeldBox, ...]:
    if held is None:
        return ()
    return held if isinstance(held, tuple) else (held,)


def _grid_stand(name: str, grid, top_offset: float = 0.0) -> Box:
    """A stand box under a slot grid: covers the slots plus a margin, floor to slot height."""
    t = grid.pose.matrix()
    nx = (grid.columns - 1) * grid.pitch[0]
    ny = (grid.rows - 1) * grid.pitch[1]
    centre_local = np.array([nx / 2, ny / 2, 0.0, 1.0])
    c = t @ centre_local
    top = float(c[2]) + top_offset
    size = (nx + 2 * STAND_MARGIN, ny + 2 * STAND_MARGIN, top)
    return Box(name, size, Pose((float(c[0]), float(c[1]), top / 2), _yaw_only(t)))


def _yaw_only(t: np.ndarray) -> tuple[float, float, float]:
    return (0.0, 0.0, float(np.arctan2(t[1, 0], t[0, 0])))


def cell_static_boxes(cell: Cell, *, door_closed: bool = False) -> tuple[Box, ...]:
    """Every static collision box of the cell, poses in the cell's world frame.

    The enclosure walls (and the door when ``door_closed``), plus boxes the cell file
    implies: ``vise_body`` (:data:`VISE_BODY_LENGTH` along the jaws, the largest jaw opening
    plus :data:`VISE_BODY_MARGIN` across, :data:`VISE_BODY_HEIGHT` below the parallels; the
    moving jaws are not modelled), ``rack_stand`` and ``out_tray_stand`` (floor to slot
    height, grid plus :data:`STAND_MARGIN`), ``pedestal`` (floor to the robot base), and the
    reject bin and the flip station's post where the cell has them.
    """
    boxes = list(cell.enclosure.walls)
    if door_closed:
        boxes.append(cell.enclosure.door)
    tv = cell.vise.pose.matrix()
    body = np.eye(4)
    body[2, 3] = -VISE_BODY_HEIGHT / 2
    c = (tv @ body)[:3, 3]
    boxes.append(Box("vise_body", (VISE_BODY_LENGTH, cell.vise.jaw_opening_max + VISE_BODY_MARGIN,
                                   VISE_BODY_HEIGHT), Pose(tuple(float(v) for v in c), _yaw_only(tv))))
    boxes.append(_grid_stand("rack_stand", cell.rack))
    boxes.append(_grid_stand("out_tray_stand", cell.out_tray))
    if cell.reject_bin is not None:
        boxes.append(cell.reject_bin)
    if cell.flip_station is not None:
        boxes.append(cell.flip_station.post)
    base = np.array(cell.robot.base.xyz, dtype=float)
    boxes.append(Box("pedestal", (PEDESTAL_SIZE, PEDESTAL_SIZE, float(base[2])),
                     Pose((float(base[0]), float(base[1]), float(base[2]) / 2))))
    return tuple(boxes)


def robot_srdf(robot: Robot) -> Path | None:
    """The SRDF shipped beside the robot's URDF (``<pkg>/srdf/<name>.srdf``, the
    example-robot-data layout), or ``None``."""
    p = Path(robot.urdf).parent.parent / "srdf" / f"{robot.name}.srdf"
    return p if p.is_file() else None


@dataclass(frozen=True, eq=False)
class CollisionWorld:
    """The robot, gripper and cell as collision geometry. Build with :func:`collision_world`.

    Queries reuse one Pinocchio data buffer: a world is not thread-safe (build one per thread).

    Attributes
    ----------
    robot : Robot
    geometry : pinocchio.GeometryModel
        Links, gripper and static boxes with the active collision pairs. Read-only.
    static_names : tuple of str
        Names of the static boxes.
    dropped_pairs : tuple of (str, str)
        Self-collision pairs dropped because they touch at the home configuration.
    transform_model_to_world : (4, 4) float
        The cell world frame in the Pinocchio model's root frame [m].
    transform_flange_to_tcp : (4, 4) float
    obstacles : tuple of Box
        The static boxes beyond the cell's own (:func:`cell_static_boxes`): what stands beside the
        box being moved (world frame).
    door_closed : bool
        Whether the enclosure door is an obstacle.
    """

    robot: Robot
    geometry: pin.GeometryModel
    static_names: tuple[str, ...]
    dropped_pairs: tuple[tuple[str, str], ...]
    transform_model_to_world: np.ndarray
    transform_flange_to_tcp: np.ndarray
    _data: pin.Data = field(repr=False)
    _gdata: pin.GeometryData = field(repr=False)
    _static: tuple[tuple[str, coal.Box, coal.Transform3s], ...] = field(repr=False)
    _flange_id: int = field(repr=False)
    _arm_links: tuple[tuple[str, int], ...] = field(repr=False, default=())
    #: geometry index of each static box, in the order of ``_static``
    _static_ids: tuple[int, ...] = field(repr=False, default=())
    obstacles: tuple[Box, ...] = ()
    door_closed: bool = False
    _riders: dict = field(repr=False, default_factory=dict)
    _bounds: "PairBounds" = field(repr=False, default=None)

    def _update(self, q: np.ndarray) -> None:
        q = np.asarray(q, dtype=float)
        if q.shape != (self.robot.dof,) or not np.isfinite(q).all():
            raise PlanningError(f"configuration must be {self.robot.dof} finite joint angles, got {q.tolist()}")
        pin.framesForwardKinematics(self.robot.model, self._data, q)
        pin.updateGeometryPlacements(self.robot.model, self._data, self.geometry, self._gdata)

    def riding(self, held: Payload) -> "RidingGeometry":
        """The world's geometry with the boxes of ``held`` riding on the TCP (made once per payload)."""
        key = _riding(held)
        got = self._riders.get(key)
        if got is None:
            got = self._riders[key] = _riding_geometry(self, key)
        return got

    def in_collision(self, q: np.ndarray, held: Payload = None) -> bool:
        """Whether configuration ``q`` (dof,) [rad] (holding ``held``) touches anything."""
        return self.first_contact(q, held) is not None

    def first_contact(self, q: np.ndarray, held: Payload = None) -> str | None:
        """``"body_a <-> body_b"`` for the first colliding pair at ``q``, or ``None`` when free.

        Robot bodies are named by their geometry (``forearm_link_0``, ``gripper``,
        ``held``), static ones by the cell's box name (``mill_table``, ``vise_body``).
        """
        self._update(q)
        if held is None:
            gm, gd, bounds = self.geometry, self._gdata, self._bounds
        else:
            rider = self.riding(held)
            gm, gd, bounds = rider.geometry, rider.data, rider.bounds
            pin.updateGeometryPlacements(self.robot.model, self._data, gm, gd)
        # only the pairs the broad phase cannot keep apart are asked of coal, in order
        for k in np.flatnonzero(bounds.lower(self._data) <= BROAD_PHASE_SLACK):
            if pin.computeCollision(gm, gd, int(k)):
                return pair_name(gm, int(k))
        return None

    def path_free(self, qs: np.ndarray, held: Payload = None) -> int | None:
        """Index of the first colliding configuration of ``qs`` (n, dof) [rad], ``None`` if all are free."""
        qs = np.asarray(qs, dtype=float).reshape(-1, self.robot.dof)
        for i, q in enumerate(qs):
            if self.in_collision(q, held):
                return i
        return None


def collision_world(cell: Cell, robot: Robot | None = None, *, door_closed: bool = False,
                    obstacles: tuple[Box, ...] = ()) -> CollisionWorld:
    """Build the collision world of ``cell`` once (loads the robot's collision meshes).

    Parameters
    ----------
    cell : Cell
    robot : Robot, optional
        Loaded with ``collision=True``; by default loaded from ``cell.robot``.
    door_closed : bool
        Include the enclosure door as an obstacle.
    obstacles : tuple of Box
        More static boxes (world frame): the blanks beside the one picked, the parts already
        in the out-tray.

    Raises
    ------
    CellError
        The robot has no collision geometry, or its home configuration collides with the cell.
    """
    if robot is None or robot.collision is None:
        robot = load_robot(cell.robot.model, flange_frame=cell.robot.flange_frame, collision=True)
    if robot.collision is None:
        raise CellError("robot has no collision geometry", source=cell.source)
    model = robot.model
    data = model.createData()
    gm = robot.collision.copy()
    links = list(range(gm.ngeoms))
    pin.framesForwardKinematics(model, data, pin.neutral(model))
    t_model_base = data.oMf[model.getFrameId(robot.base_frame)].homogeneous
    t_model_world = t_model_base @ np.linalg.inv(cell.robot.base.matrix())
    fid = model.getFrameId(robot.flange_frame)
    gripper = _add_gripper(gm, model, fid, cell)
    boxes = cell_static_boxes(cell, door_closed=door_closed) + tuple(obstacles)
    static = _add_static(gm, links, gripper, boxes, t_model_world)
    home = np.asarray(cell.robot.home, dtype=float)
    dropped = _add_self_pairs(gm, robot, data, links + [gripper], home)
    if dropped:
        log.info("self-collision pairs in contact at home, not checked: %s", dropped)

    gdata = pin.GeometryData(gm)
    t_model_world.setflags(write=False)
    tcp = cell.gripper.tcp.matrix()
    tcp.setflags(write=False)
    # The held box is checked against the links that do not move with the flange (those
    # on the flange's joint carry the gripper that holds it).
    flange_joint = model.frames[fid].parentJoint
    arm_links = tuple((gm.geometryObjects[i].name, i) for i in links
                      if gm.geometryObjects[i].parentJoint != flange_joint)
    static_ids = tuple(range(gripper + 1, gripper + 1 + len(boxes)))
    world = CollisionWorld(robot, gm, tuple(b.name for b in boxes), tuple(dropped), t_model_world, tcp,
                           data, gdata, tuple(static), fid, arm_links, static_ids, tuple(obstacles), door_closed,
                           _bounds=pair_bounds(gm, static_ids, model.njoints))
    contact = world.first_contact(home)
    if contact is not None:
        raise CellError(f"robot.home: the home configuration collides ({contact})", source=cell.source)
    return world


def _add_gripper(gm: pin.GeometryModel, model: pin.Model, flange_id: int, cell: Cell) -> int:
    """Add the gripper body's box on the flange frame to ``gm``; its geometry index."""
    fr = model.frames[flange_id]
    g = cell.gripper.body
    gripper_placement = fr.placement.homogeneous @ g.pose.matrix()
    return gm.addGeometryObject(pin.GeometryObject(
        "gripper", fr.parentJoint, flange_id, pin.SE3(gripper_placement), coal.Box(*g.size)))


def _add_static(gm: pin.GeometryModel, links: list[int], gripper: int, boxes: tuple[Box, ...],
                t_model_world: np.ndarray) -> list[tuple[str, coal.Box, coal.Transform3s]]:
    """Add ``boxes`` (world frame) to ``gm`` and pair each with every link and the gripper (but
    the robot's base links with its own pedestal); (name, shape, pose in the model frame) of each."""
    static: list[tuple[str, coal.Box, coal.Transform3s]] = []
    static_ids = []
    for b in boxes:
        t = t_model_world @ b.pose.matrix()
        shape = coal.Box(*b.size)
        static_ids.append(gm.addGeometryObject(pin.GeometryObject(b.name, 0, 0, pin.SE3(t), shape)))
        static.append((b.name, coal.Box(*b.size), coal.Transform3s(t[:3, :3], t[:3, 3])))
    base_geoms = {i for i in links if gm.geometryObjects[i].parentJoint == 0}
    for i in links + [gripper]:
        for s, b in zip(static_ids, boxes):
            if b.name == "pedestal" and i in base_geoms:
                continue
            gm.addCollisionPair(pin.CollisionPair(i, s))
    return static


def _srdf_disabled(robot: Robot) -> set[frozenset[str]]:
    """The link pairs whose collisions the vendor's SRDF disables (none without one)."""
    srdf = robot_srdf(robot)
    disabled: set[frozenset[str]] = set()
    if srdf is not None:
        try:
            root = ET.parse(srdf).getroot()
        except (OSError, ET.ParseError) as e:
            raise CellError(f"cannot read SRDF: {e}", source=srdf) from None
        for e in root.iter("disable_collisions"):
            disabled.add(frozenset((e.get("link1"), e.get("link2"))))
    return disabled


def _add_self_pairs(gm: pin.GeometryModel, robot: Robot, data: pin.Data, robot_geoms: list[int],
                    home: np.ndarray) -> list[tuple[str, str]]:
    """Add the self-collision pairs to ``gm``: link / gripper pairs on different, non-adjacent
    joints that the SRDF does not disable and that are apart at ``home`` [rad]; the names of the
    pairs dropped because they touch there."""
    model = robot.model
    self_pairs = []
    for a in range(len(robot_geoms)):
        for b in range(a + 1, len(robot_geoms)):
            ia, ib = robot_geoms[a], robot_geoms[b]
            ja, jb = gm.geometryObjects[ia].parentJoint, gm.geometryObjects[ib].parentJoint
            if ja == jb or model.parents[ja] == jb or model.parents[jb] == ja:
                continue
            self_pairs.append((ia, ib))
    disabled = _srdf_disabled(robot)

    def link_of(i: int) -> str:
        f = gm.geometryObjects[i].parentFrame
        return model.frames[f].name if gm.geometryObjects[i].name != "gripper" else "gripper"

    candidates = [(a, b) for a, b in self_pairs if frozenset((link_of(a), link_of(b))) not in disabled]
    probe = pin.GeometryModel()
    for o in gm.geometryObjects:
        probe.addGeometryObject(o)
    for a, b in candidates:
        probe.addCollisionPair(pin.CollisionPair(a, b))
    pdata = pin.GeometryData(probe)
    pin.computeCollisions(model, data, probe, pdata, home, False)
    dropped = []
    for k, res in enumerate(pdata.collisionResults):
        a, b = candidates[k]
        if res.isCollision():
            dropped.append((gm.geometryObjects[a].name, gm.geometryObjects[b].name))
        else:
            gm.addCollisionPair(pin.CollisionPair(a, b))
    return dropped


def pair_name(gm: pin.GeometryModel, k: int) -> str:
    """``"body_a <-> body_b"`` of collision pair ``k`` of ``gm``."""
    pair = gm.collisionPairs[k]
    return f"{gm.geometryObjects[pair.first].name} <-> {gm.geometryObjects[pair.second].name}"


@dataclass(frozen=True, eq=False)
class PairBounds:
    """The broad phase of a geometry model's collision pairs: a lower bound on each pair's distance
    from a bounding sphere of each body that moves with a joint (its local bounding box's, in its
    joint's frame) and the static boxes themselves. A pair the bound keeps farther apart than its
    margin needs no coal query.

    Attributes
    ----------
    joints : (nm,) int
        Each moving body's joint (0 for the robot's base links).
    centres : (nm, 4) float
        Each moving body's sphere centre in its joint's frame (homogeneous) [m].
    radii : (nm,) float
        Its radius [m].
    near_pairs, near_a, near_b : (k,) int
        The pairs of two moving bodies and their two bodies.
    box_pairs, box_body : (k,) int
        The pairs of a moving body and a static box, and the moving body.
    box_rotation, box_centre, box_half : (k, 3, 3), (k, 3), (k, 3) float
        That pair's static box in the model frame [m].
    npairs : int
    njoints : int
        Joints of the model (with the universe).
    """

    joints: np.ndarray
    centres: np.ndarray
    radii: np.ndarray
    near_pairs: np.ndarray
    near_a: np.ndarray
    near_b: np.ndarray
    box_pairs: np.ndarray
    box_body: np.ndarray
    box_rotation: np.ndarray
    box_centre: np.ndarray
    box_half: np.ndarray
    npairs: int
    njoints: int

    def lower(self, data: pin.Data) -> np.ndarray:
        """(npairs,) lower bounds [m] on every pair's distance with the joints placed as in ``data``
        (after forward kinematics); negative where the bounds overlap."""
        t = np.array([data.oMi[j].homogeneous[:3] for j in range(self.njoints)])[self.joints]
        c = np.einsum("kij,kj->ki", t, self.centres)
        out = np.empty(self.npairs)
        d = c[self.near_a] - c[self.near_b]
        out[self.near_pairs] = np.sqrt((d * d).sum(axis=1)) - self.radii[self.near_a] - self.radii[self.near_b]
        local = np.abs(np.einsum("kji,kj->ki", self.box_rotation, c[self.box_body] - self.box_centre)) - self.box_half
        gap = np.maximum(local, 0.0)
        out[self.box_pairs] = np.sqrt((gap * gap).sum(axis=1)) - self.radii[self.box_body]
        return out


def pair_bounds(gm: pin.GeometryModel, static_ids: tuple[int, ...], njoints: int) -> PairBounds:
    """The broad phase of ``gm``'s pairs (:class:`PairBounds`); ``static_ids`` are its static boxes."""
    static = set(static_ids)
    moving: dict[int, int] = {}
    joints, centres, radii = [], [], []
    near, near_a, near_b, box, box_body, rot, centre, half = [], [], [], [], [], [], [], []

    def body(i: int) -> int:
        if i not in moving:
            g = gm.geometryObjects[i]
            g.geometry.computeLocalAABB()
            lo, hi = np.asarray(g.geometry.aabb_local.min_), np.asarray(g.geometry.aabb_local.max_)
            moving[i] = len(joints)
            joints.append(int(g.parentJoint))
            centres.append(g.placement.homogeneous @ np.append((lo + hi) / 2, 1.0))
            radii.append(float(np.linalg.norm(hi - lo)) / 2)
        return moving[i]

    for k, pair in enumerate(gm.collisionPairs):
        a, b = pair.first, pair.second
        if a in static or b in static:
            s, m = (a, b) if a in static else (b, a)
            g = gm.geometryObjects[s]
            box.append(k)
            box_body.append(body(m))
            rot.append(g.placement.rotation)
            centre.append(g.placement.translation)
            half.append(np.asarray(g.geometry.halfSide))
        else:
            near.append(k)
            near_a.append(body(a))
            near_b.append(body(b))
    ints = lambda v: np.array(v, dtype=np.int64)  # noqa: E731
    return PairBounds(ints(joints), np.array(centres).reshape(-1, 4), np.array(radii), ints(near), ints(near_a),
                      ints(near_b), ints(box), ints(box_body), np.array(rot).reshape(-1, 3, 3),
                      np.array(centre).reshape(-1, 3), np.array(half).reshape(-1, 3), len(gm.collisionPairs),
                      njoints)


@dataclass(frozen=True, eq=False)
class RidingGeometry:
    """A world's geometry with the boxes riding on the TCP added (:meth:`CollisionWorld.riding`).

    Attributes
    ----------
    geometry : pinocchio.GeometryModel
        The world's objects and pairs first, at the same indices; then one object per riding box
        (on the flange's joint, named as the box); then, box by box, its pair with each arm link
        (``CollisionWorld._arm_links``, in order) and each static box (in order). Read-only.
    data : pinocchio.GeometryData
    boxes : tuple of HeldBox
        The riding boxes checked (a box its clearance shrinks to nothing is not), in order.
    placements : tuple of (4, 4) float
        Each box's centre in the flange frame [m].
    bounds : PairBounds
        The broad phase of ``geometry``'s pairs.
    """

    geometry: pin.GeometryModel
    data: pin.GeometryData
    boxes: tuple[HeldBox, ...]
    placements: tuple[np.ndarray, ...]
    bounds: PairBounds


def _riding_geometry(world: CollisionWorld, riding: tuple[HeldBox, ...]) -> RidingGeometry:
    """The riding boxes ``riding`` added to a copy of ``world``'s geometry (:class:`RidingGeometry`)."""
    gm = world.geometry.copy()
    model = world.robot.model
    fr = model.frames[world._flange_id]
    t_joint_flange = fr.placement.homogeneous
    boxes, placements, objects = [], [], []
    for box in riding:
        size = np.asarray(box.size) - 2 * box.clearance
        if (size <= 0).any():
            continue
        t_flange_box = world.transform_flange_to_tcp @ np.asarray(box.transform_tcp_to_box)
        objects.append(gm.addGeometryObject(pin.GeometryObject(
            box.name, fr.parentJoint, world._flange_id, pin.SE3(t_joint_flange @ t_flange_box), coal.Box(*size))))
        boxes.append(box)
        placements.append(t_flange_box)
    for i in objects:
        for _, link in world._arm_links:
            gm.addCollisionPair(pin.CollisionPair(i, link))
        for s in world._static_ids:
            gm.addCollisionPair(pin.CollisionPair(i, s))
    return RidingGeometry(gm, pin.GeometryData(gm), tuple(boxes), tuple(placements),
                          pair_bounds(gm, world._static_ids, model.njoints))
