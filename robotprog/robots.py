"""Robot models: a name from example-robot-data (``ur5``, ``panda``, ...) or a URDF file.

The PyPI wheel ``example-robot-data`` installs its URDFs and meshes under
``site-packages/cmeel.prefix/share/example-robot-data/robots/`` and does not always ship
the Python loader, so the share folder is found here from the wheel's metadata. Mesh
URIs in those files read ``package://example-robot-data/robots/...``: Pinocchio resolves
them against the package directories we pass (the ``share`` folder that holds
``example-robot-data``).

Units follow URDF: metres, radians, rad/s. The models are never edited by hand: factory
loads the vendor's description and, for robots with fingers (panda), locks the finger
joints so that the arm's configuration vector holds only the arm joints.
"""

from __future__ import annotations

import functools
import importlib.metadata
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from factory.core.errors import CellError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class _Known:
    urdf: str  # relative to .../share/example-robot-data/robots
    base_frame: str
    flange_frame: str
    locked_joints: tuple[str, ...] = ()


#: Robots known by name: URDF file, base frame, flange (tool mounting) frame, and joints
#: that are locked at zero because they are not part of the arm (gripper fingers).
KNOWN_ROBOTS: dict[str, _Known] = {
    "ur3": _Known("ur_description/urdf/ur3_robot.urdf", "base_link", "tool0"),
    "ur5": _Known("ur_description/urdf/ur5_robot.urdf", "base_link", "tool0"),
    "ur10": _Known("ur_description/urdf/ur10_robot.urdf", "base_link", "tool0"),
    "panda": _Known(
        "panda_description/urdf/panda.urdf", "panda_link0", "panda_link8",
        ("panda_finger_joint1", "panda_finger_joint2"),
    ),
    "xarm7": _Known("xarm_description/urdf/xarm7.urdf", "link_base", "link_eef"),
}


@dataclass(frozen=True, eq=False)
class Robot:
    """A loaded robot arm.

    Attributes
    ----------
    name : str
        The example-robot-data name (``"ur5"``) or the URDF file's stem.
    urdf : Path
        The URDF file the model was built from.
    model : pinocchio.Model
        Kinematic model; ``model.nq == dof`` (fingers locked). Treat as read-only.
    collision : pinocchio.GeometryModel or None
        Collision geometry of the links (``None`` when not asked for).
    base_frame, flange_frame : str
        Frame the arm is mounted by, and the tool flange frame (where the gripper sits).
    q_lower, q_upper : (dof,) float
        Joint position limits [rad].
    v_max : (dof,) float
        Joint velocity limits from the URDF [rad/s].
    """

    name: str
    urdf: Path
    model: pin.Model
    collision: pin.GeometryModel | None
    base_frame: str
    flange_frame: str
    q_lower: np.ndarray
    q_upper: np.ndarray
    v_max: np.ndarray

    @property
    def maker(self) -> str | None:
        """The arm's maker, whose controller language its joint values are meant for:
        ``"Universal Robots"`` (``ur3``, ``ur5e``...), ``"ABB"`` (a URDF named ``abb_*``) or
        ``"KUKA"`` (``kuka_*``), from :attr:`name`; ``None`` for any other arm."""
        return maker_of(self.name)

    @property
    def dof(self) -> int:
        """Number of arm joints."""
        return int(self.model.nq)

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Arm joint names in configuration order."""
        return tuple(self.model.names[1:])

    def fk(self, q: np.ndarray) -> np.ndarray:
        """Transform base frame → flange frame at configuration ``q``.

        Parameters
        ----------
        q : (dof,) float
            Joint positions [rad].

        Returns
        -------
        (4, 4) float
            ``transform_base_to_flange``, translation in metres.
        """
        return self.frame_transform(q, self.base_frame, self.flange_frame)

    def frame_transform(self, q: np.ndarray, frame_a: str, frame_b: str) -> np.ndarray:
        """``transform_a_to_b`` between two model frames at configuration ``q`` [m]."""
        data = self.model.createData()
        pin.framesForwardKinematics(self.model, data, np.asarray(q, dtype=float))
        a = data.oMf[self.model.getFrameId(frame_a)]
        b = data.oMf[self.model.getFrameId(frame_b)]
        return (a.actInv(b)).homogeneous


def maker_of(name: str) -> str | None:
    """The maker named by a robot model name (see :attr:`Robot.maker`)."""
    low = name.lower()
    if low.startswith("ur") and low[2:3].isdigit():
        return "Universal Robots"
    if low.startswith("abb_"):
        return "ABB"
    if low.startswith("kuka_"):
        return "KUKA"
    return None


@functools.cache
def example_robot_data_dir() -> Path:
    """The ``share`` folder that holds ``example-robot-data/robots`` (a package dir for Pinocchio).

    Raises
    ------
    CellError
        The example-robot-data wheel is not installed.
    """
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        raise CellError(
            "the example-robot-data package is not installed (pip install example-robot-data)"
        ) from None
    for f in dist.files or ():
        parts = Path(str(f)).parts
        if "example-robot-data" in parts and "robots" in parts:
            i = parts.index("example-robot-data")
            share = Path(dist.locate_file(Path(*parts[:i])))
            if (share / "example-robot-data" / "robots").is_dir():
                return share
    raise CellError("example-robot-data is installed but its robots folder was not found")


def robot_urdf(name: str) -> Path:
    """The URDF file of a robot known by name.

    Raises
    ------
    CellError
        Unknown name (the message lists the known ones).
    """
    known = KNOWN_ROBOTS.get(name)
    if known is None:
        raise CellError(
            f"unknown robot {name!r}; known robots: {', '.join(sorted(KNOWN_ROBOTS))}, "
            "or give a path to a .urdf file",
            source="robot.model",
        )
    return example_robot_data_dir() / "example-robot-data" / "robots" / known.urdf


def load_robot(
    model: str | Path,
    *,
    base_frame: str | None = None,
    flange_frame: str | None = None,
    collision: bool = False,
) -> Robot:
    """Load a robot by example-robot-data name or URDF path.

    Parameters
    ----------
    model : str or Path
        A name from :data:`KNOWN_ROBOTS` (``"ur5"``) or a path to a ``.urdf`` file.
    base_frame, flange_frame : str, optional
        Override the base / flange frame names. For a URDF path they default to the
        root link's first child frame and the last frame of the model.
    collision : bool
        Also build the collision :class:`pinocchio.GeometryModel` (loads meshes, slower).

    Raises
    ------
    CellError
        Unknown name, missing or unreadable URDF, or frame names not in the model.
    """
    return _load_robot_cached(str(model), base_frame, flange_frame, collision)


@functools.lru_cache(maxsize=16)
def _load_robot_cached(
    model: str, base_frame: str | None, flange_frame: str | None, collision: bool
) -> Robot:
    locked: tuple[str, ...] = ()
    if model in KNOWN_ROBOTS:
        known = KNOWN_ROBOTS[model]
        urdf = robot_urdf(model)
        base_frame = base_frame or known.base_frame
        flange_frame = flange_frame or known.flange_frame
        locked = known.locked_joints
        name = model
    elif model.lower().endswith(".urdf") or Path(model).exists():
        urdf = Path(model)
        name = urdf.stem
        if not urdf.is_file():
            raise CellError("URDF file not found", source=urdf)
    else:
        urdf = robot_urdf(model)  # raises the "unknown robot" error listing the known names
        name = model
    package_dirs = [str(example_robot_data_dir())] if model in KNOWN_ROBOTS else [str(urdf.parent)]
    try:
        full = pin.buildModelFromUrdf(str(urdf))
    except (RuntimeError, ValueError) as e:
        raise CellError(f"cannot read URDF: {e}", source=urdf) from None
    geom = None
    if collision:
        try:
            geom = pin.buildGeomFromUrdf(full, str(urdf), pin.GeometryType.COLLISION, package_dirs=package_dirs)
        except (RuntimeError, ValueError) as e:
            raise CellError(f"cannot load collision geometry: {e}", source=urdf) from None
    if locked:
        ids = [full.getJointId(j) for j in locked]
        q0 = pin.neutral(full)
        if geom is not None:
            arm, geom = pin.buildReducedModel(full, geom, ids, q0)
        else:
            arm = pin.buildReducedModel(full, ids, q0)
    else:
        arm = full
    if any(arm.joints[i].nq != 1 for i in range(1, arm.njoints)):
        raise CellError("only arms of revolute/prismatic joints are supported", source=urdf)
    frames = {f.name for f in arm.frames}
    if base_frame is None:
        base_frame = arm.frames[1].name if len(arm.frames) > 1 else arm.frames[0].name
    if flange_frame is None:
        flange_frame = arm.frames[len(arm.frames) - 1].name
    for what, f in (("base_frame", base_frame), ("flange_frame", flange_frame)):
        if f not in frames:
            raise CellError(f"{what} {f!r} is not a frame of the model", source=urdf)
    log.debug("loaded robot %s from %s (%d dof)", name, urdf, arm.nq)
    lower = np.array(arm.lowerPositionLimit, dtype=float)
    upper = np.array(arm.upperPositionLimit, dtype=float)
    vmax = np.array(arm.velocityLimit, dtype=float)
    for a in (lower, upper, vmax):
        a.setflags(write=False)
    return Robot(name, urdf, arm, geom, base_frame, flange_frame, lower, upper, vmax)
