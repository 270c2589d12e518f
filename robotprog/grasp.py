"""The top-down grasp of a box, and the fingers around it.

Top-down: the TCP's Z points down (world -Z), the fingers close along the TCP's Y across the
narrower horizontal side of the box (stock, part or holding block), centred on the box's top face.
The fingertips (at the TCP) reach ``min(height / 2, grip_depth)`` below the top, but stay
:attr:`GraspOptions.floor_clearance` above the surface the box stands on, and the gripper body
(where the fingers start, ``gripper.fingers.length`` above the tips) stays that far above the box's
top. Of the two yaws that satisfy this, the one nearer the home TCP orientation is used (less wrist
travel). The fingers ride on the TCP as boxes (:func:`robotprog.collision.finger_boxes`): open
``gripper.fingers.clearance`` beyond the box on the way to it and after letting it go
(:func:`open_fingers`), closed on it while holding it.

Boxes are given in an upright support frame (the vise's, a rack or tray slot's, the flip post's
top): ``[bmin, bmax]`` in that frame. Metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factory.core.errors import PlanningError
from factory.core.units import MM_PER_M
from robotprog.cell import Cell
from robotprog.collision import HeldBox, finger_boxes


@dataclass(frozen=True)
class GraspOptions:
    """How deep the fingers reach.

    Attributes
    ----------
    grip_depth : float
        How far the fingertips reach below the top of the box at most [m].
    min_grip_depth : float
        Shallowest grip accepted [m]; a thinner box raises :class:`PlanningError`.
    floor_clearance : float
        Gap kept between the gripper's collision box and the surface the box stands on [m].
    """

    grip_depth: float = 0.015
    min_grip_depth: float = 0.003
    floor_clearance: float = 0.002


@dataclass(frozen=True, eq=False)
class Grasp:
    """A box gripped from above.

    Attributes
    ----------
    transform_world_to_tcp : (4, 4) float
        TCP pose when the fingers close on the box [m].
    held : HeldBox
        The box as it rides on the TCP.
    """

    transform_world_to_tcp: np.ndarray
    held: HeldBox


def box_pose(t_support: np.ndarray, bmin: np.ndarray, bmax: np.ndarray) -> np.ndarray:
    """(4, 4) pose in the world of the centre of the box [bmin, bmax] of an upright support frame."""
    box = np.eye(4)
    box[:3, :3] = t_support[:3, :3]
    box[:3, 3] = (t_support @ np.append((np.asarray(bmin) + np.asarray(bmax)) / 2, 1.0))[:3]
    return box


def open_fingers(cell: Cell, width: float) -> tuple[HeldBox, ...]:
    """The fingers open a clearance beyond a box ``width`` [m] across (at most fully open)."""
    return finger_boxes(cell, min(cell.gripper.opening_max, width + 2 * cell.gripper.fingers.clearance))


def finger_room(cell: Cell, width: float) -> float:
    """How far each open finger stands off the side of a box ``width`` [m] across [m]: the fingers'
    clearance, or less where the gripper's stroke ends first (< 0 for a box wider than it opens)."""
    return (min(cell.gripper.opening_max, width + 2 * cell.gripper.fingers.clearance) - width) / 2


def top_grasp(cell: Cell, t_world_support: np.ndarray, bmin: np.ndarray, bmax: np.ndarray,
              r_home: np.ndarray, options: GraspOptions, what: str) -> Grasp:
    """The top-down grasp of the box [bmin, bmax] (3,) of the support frame ``t_world_support``
    (4, 4) [m]; of its two yaws the one nearer ``r_home`` (3, 3), the TCP orientation at home.

    Raises
    ------
    PlanningError
        ``what`` is wider than the gripper opens, narrower than it closes, or too thin to grip.
    """
    size = bmax - bmin
    g = cell.gripper
    narrow = 0 if size[0] <= size[1] else 1
    width = float(size[narrow])
    if width > g.opening_max:
        raise PlanningError(
            f"{what} {width * MM_PER_M:.1f} mm across its narrowest side is wider than the gripper opens "
            f"({g.opening_max * MM_PER_M:.1f} mm)", source="gripper.opening.max")
    if width < g.opening_min:
        raise PlanningError(
            f"{what} {width * MM_PER_M:.1f} mm is narrower than the gripper closes "
            f"({g.opening_min * MM_PER_M:.1f} mm)", source="gripper.opening.min")
    tcp_above = tcp_above_bottom(cell, float(size[2]), options, what)
    centre = np.array([(bmin[0] + bmax[0]) / 2, (bmin[1] + bmax[1]) / 2, bmin[2] + tcp_above, 1.0])
    t = np.eye(4)
    t[:3, :3] = _yaw_nearest(t_world_support, narrow, r_home)
    t[:3, 3] = (t_world_support @ centre)[:3]
    return Grasp(t, HeldBox.at(size, np.linalg.inv(t) @ box_pose(t_world_support, bmin, bmax)))


def tcp_above_bottom(cell: Cell, height: float, options: GraspOptions, what: str) -> float:
    """Height of the TCP (the fingertips) above the bottom of a box ``height`` tall [m].

    Raises PlanningError (``gripper.fingers``) when ``what`` is too thin to grip: the check
    :func:`top_grasp` makes, which ``factory plan`` also makes on the part before any CAM work.

    The fingertips must stay ``floor_clearance`` above the surface the box stands on; the body ends
    where the fingers start and must stay ``floor_clearance`` above the box's top, which bounds the
    grip depth by the finger length."""
    depth = min(height / 2, options.grip_depth, body_above_tips(cell) - options.floor_clearance)
    tcp_above = max(height - depth, options.floor_clearance)
    if height - tcp_above < options.min_grip_depth - 1e-9:
        raise PlanningError(
            f"{what} {height * MM_PER_M:.1f} mm tall is too thin to grip: the fingers would reach "
            f"{(height - tcp_above) * MM_PER_M:.2f} mm below its top, {options.min_grip_depth * MM_PER_M:.1f} mm "
            f"needed, fingertips {options.floor_clearance * MM_PER_M:.1f} mm above what it stands on",
            source="gripper.fingers")
    return tcp_above


def body_above_tips(cell: Cell) -> float:
    """How far the gripper body stands behind the fingertips along the tool axis [m]: where the
    fingers start, the deepest a box's face may come between them."""
    g = cell.gripper
    t_tcp_body = np.linalg.inv(g.tcp.matrix()) @ g.body.pose.matrix()
    corners = np.array([[sx, sy, sz] for sx in (-.5, .5) for sy in (-.5, .5) for sz in (-.5, .5)]) * g.body.size
    return -float(((corners @ t_tcp_body[:3, :3].T) + t_tcp_body[:3, 3])[:, 2].max())


def _yaw_nearest(t_world_support: np.ndarray, narrow: int, r_home: np.ndarray) -> np.ndarray:
    """The top-down TCP orientation (3, 3), fingers closing along the support frame's axis
    ``narrow`` (0: X, 1: Y), of the two such yaws the one nearer ``r_home``."""
    axis = t_world_support[:3, :3][:, narrow]
    axis = axis - axis[2] * np.array([0.0, 0.0, 1.0])
    axis /= np.linalg.norm(axis)
    best = None
    for s in (1.0, -1.0):
        y = s * axis
        z = np.array([0.0, 0.0, -1.0])
        x = np.cross(y, z)
        r = np.column_stack([x, y, z])
        score = np.trace(r_home.T @ r)
        if best is None or score > best[0]:
            best = (score, r)
    return best[1]
