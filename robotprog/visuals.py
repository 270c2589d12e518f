"""What a robot looks like: the visual meshes of its URDF, per link, as plain arrays.

A log that names mesh files (a URDF's ``package://`` or ``file://`` URIs) shows no robot on a
machine without those files; a log that carries the triangles does. Pinocchio reads the URDF's
``<visual>`` elements (meshes through assimp, at the URDF's ``scale``; boxes, cylinders and
spheres as shapes), so the geometry is the one the robot's vendor describes.

Units: metres. Each visual's pose is given in its link's frame (the frames factory logs on
``/tf``), as URDF ``<visual><origin>`` places it.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
import trimesh

from factory.core.errors import CellError
from robotprog.robots import Robot, example_robot_data_dir

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class LinkVisual:
    """One ``<visual>`` of a link: a triangle mesh placed in the link's frame.

    Attributes
    ----------
    link : str
        Link (frame) name, as on ``/tf``.
    name : str
        Unique name of the visual (Pinocchio's geometry name, ``<link>_<k>``).
    pose : (4, 4) float
        The mesh's placement in the link frame (translation [m]), read-only.
    vertices : (n, 3) float
        Vertex positions in the mesh's own frame [m], read-only.
    faces : (m, 3) int
        Vertex indices per triangle, read-only.
    rgba : (4,) float
        The URDF material colour in [0, 1] (Pinocchio's default grey when the URDF has none).
    """

    link: str
    name: str
    pose: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    rgba: tuple[float, float, float, float]


def _frozen(a: np.ndarray, dtype: type) -> np.ndarray:
    out = np.ascontiguousarray(a, dtype=dtype)
    out.setflags(write=False)
    return out


def _shape_mesh(geometry: object) -> tuple[np.ndarray, np.ndarray]:
    """Vertices [m] and faces of a coal geometry: a mesh (BVH model) or a primitive shape."""
    kind = type(geometry).__name__
    if kind.startswith("BVHModel"):
        faces = np.array([[t[0], t[1], t[2]] for t in map(geometry.tri_indices, range(geometry.num_tris))],
                         dtype=np.int64).reshape(-1, 3)
        return np.asarray(geometry.vertices(), dtype=np.float64).reshape(-1, 3), faces
    if kind == "Box":
        mesh = trimesh.creation.box(extents=2 * np.asarray(geometry.halfSide, dtype=np.float64))
    elif kind == "Cylinder":
        mesh = trimesh.creation.cylinder(radius=geometry.radius, height=2 * geometry.halfLength, sections=32)
    elif kind == "Sphere":
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=geometry.radius)
    else:
        raise CellError(f"visual geometry of type {kind} is not supported (meshes, boxes, cylinders, spheres)")
    return mesh.vertices, mesh.faces


def robot_visuals(robot: Robot) -> tuple[LinkVisual, ...]:
    """The visual meshes of ``robot``'s URDF, one per ``<visual>``, in the model's order.

    Loaded once per URDF and cached: the meshes of an arm are ~10^5 triangles (1 s to read).

    Raises
    ------
    CellError
        (``source`` = the URDF) A visual mesh cannot be found or read, or a shape is unsupported.
    """
    return _visuals(str(robot.urdf), robot)


@functools.lru_cache(maxsize=8)
def _visuals(urdf: str, robot: Robot) -> tuple[LinkVisual, ...]:
    model = robot.model
    package_dirs = [str(example_robot_data_dir()), str(Path(urdf).parent)]
    try:
        geom = pin.buildGeomFromUrdf(model, urdf, pin.GeometryType.VISUAL, package_dirs=package_dirs)
    except (RuntimeError, ValueError) as e:
        raise CellError(f"cannot load visual geometry: {e}", source=urdf) from None
    out = []
    for obj in geom.geometryObjects:
        frame = model.frames[obj.parentFrame]
        # Pinocchio places geometry in its parent joint's frame; the link frame sits at
        # frame.placement in that joint frame, so link <- visual = frame^-1 * joint <- visual.
        pose = (frame.placement.inverse() * obj.placement).homogeneous
        try:
            vertices, faces = _shape_mesh(obj.geometry)
        except CellError as e:
            raise CellError(f"{obj.name}: {e.message}", source=urdf) from None
        out.append(LinkVisual(link=frame.name, name=obj.name, pose=_frozen(pose, np.float64),
                              vertices=_frozen(vertices, np.float64), faces=_frozen(faces, np.int64),
                              rgba=tuple(float(c) for c in np.clip(obj.meshColor, 0.0, 1.0))))
    log.debug("read %d visuals (%d triangles) of %s", len(out), sum(len(v.faces) for v in out), urdf)
    return tuple(out)


__all__ = ["LinkVisual", "robot_visuals"]
