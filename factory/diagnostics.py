"""Key values of the cell's health on ``/diagnostics`` that follow from what the robot is doing.

The simulation records activities, not IO signals, so the machine door and the gripper are read
off the robot's activities the way the cell's robot programs drive them (``robotprog.programs``):

- The door opens before the robot reaches into the machine and closes behind it: it is open
  through a ``load`` or an ``unload`` and closed otherwise, so never while the spindle cuts.
- The gripper closes on the blank at the end of a ``fetch`` (a missed grasp leaves it open) and
  holds it until the ``load`` ends in the vise; it grips the finished part through the ``unload``
  to the out-tray, and a rejected part through the ``unload_reject`` from the vise to the bin.
"""

from __future__ import annotations

from typing import Any

#: Robot activities that reach into the machine: its door is open through them.
THROUGH_THE_DOOR = ("load", "unload", "unload_reject", "flip")
#: What the gripper holds through each robot activity. The flip (vise -> post -> vise, see
#: :mod:`robotprog.flip`) lets go only to regrasp on the post, so it counts as holding the part.
HOLDS = {"load": "blank", "unload": "part", "flip": "part", "unload_reject": "reject"}


def door(robot_activity: Any | None, t: float) -> str:
    """``"open"`` or ``"closed"``: the machine door at time ``t`` [s], given the robot's current or
    last activity (anything with ``action``, ``start``, ``end`` [s]; None before the first)."""
    a = robot_activity
    return "open" if a is not None and a.start <= t < a.end and a.action in THROUGH_THE_DOOR else "closed"


def gripper(robot_activity: Any | None, t: float) -> dict[str, str]:
    """``{"gripper": "open" | "closed", "gripper_holds": "blank" | "part" | "reject" | ""}`` at time
    ``t`` [s], given the robot's current or last activity (``action``, ``start``, ``end`` [s] and
    ``outcome``: a fetch that ended ``fetched`` leaves the blank in the gripper until the load)."""
    a, holds = robot_activity, ""
    if a is not None and a.start <= t < a.end:
        holds = HOLDS.get(a.action, "")
    elif a is not None and t >= a.end and a.action == "fetch" and a.outcome == "fetched":
        holds = "blank"
    return {"gripper": "closed" if holds else "open", "gripper_holds": holds}
