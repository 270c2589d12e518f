"""Foxglove scene messages (``foxglove_msgs/msg/SceneUpdate``) that carry their own meshes.

A ``SceneEntity`` with a ``ModelPrimitive`` whose ``data`` holds a glTF binary (GLB) file is
drawn by Foxglove's 3D panel from the log alone: on any machine and in the web app, with no
mesh files beside the log and no ROS package path. factory uses it for the robot's links
(:func:`visuals_scene`); each entity is *frame locked* to its link frame, so the model moves
with the link's ``/tf``.

glTF is Y-up (glTF 2.0 spec, "Coordinate System and Units"); ROS and factory are Z-up. The
vertices are turned Z-up -> Y-up when encoded, and Foxglove turns every glTF model Y-up -> Z-up
when it loads it (``ModelCache.loadGltf``: ``rotateX(pi/2)``), so the mesh shows in its ROS
frame. Units: metres throughout (glTF's unit too).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from factory.core.errors import McapError
from factory.rosmsgs import TYPESTORE, ros_time

if TYPE_CHECKING:
    from robotprog.visuals import LinkVisual

#: Media type of the embedded models (what Foxglove's ModelPrimitive documentation names).
GLB_MEDIA_TYPE = "model/gltf-binary"

#: Z-up (ROS) -> Y-up (glTF): x stays, y <- z, z <- -y.
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])

_T = TYPESTORE.types
_SceneUpdate = _T["foxglove_msgs/msg/SceneUpdate"]
_SceneEntity = _T["foxglove_msgs/msg/SceneEntity"]
_ModelPrimitive = _T["foxglove_msgs/msg/ModelPrimitive"]
_Color = _T["foxglove_msgs/msg/Color"]
_Pose = _T["geometry_msgs/msg/Pose"]
_Point = _T["geometry_msgs/msg/Point"]
_Quaternion = _T["geometry_msgs/msg/Quaternion"]
_Vector3 = _T["geometry_msgs/msg/Vector3"]
_Duration = _T["builtin_interfaces/msg/Duration"]


def glb_bytes(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """A glTF binary file of one triangle mesh given Z-up, written Y-up (see the module doc).

    Parameters
    ----------
    vertices : (n, 3) float
        Positions [m], Z up.
    faces : (m, 3) int
        Vertex indices per triangle, counter-clockwise seen from outside; m >= 1.

    Raises
    ------
    McapError
        Wrong shapes, non-finite positions, no triangles, or an index out of range.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
        raise McapError(f"mesh vertices must be finite (n, 3), got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0 or not np.issubdtype(f.dtype, np.integer):
        raise McapError(f"mesh faces must be (m, 3) integers with m >= 1, got {f.shape} {f.dtype}")
    if f.min() < 0 or f.max() >= len(v):
        raise McapError(f"mesh face index out of range [0, {len(v)})")
    mesh = trimesh.Trimesh(v @ Z_UP_TO_Y_UP.T, f, process=False)
    # No normals: three.js then shades flat, which is right for machined, faceted parts.
    return bytes(mesh.export(file_type="glb", include_normals=False))


def _pose(matrix: np.ndarray) -> Any:
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise McapError("model pose must be a finite 4x4 matrix")
    qx, qy, qz, qw = Rotation.from_matrix(m[:3, :3]).as_quat()
    x, y, z = m[:3, 3]
    return _Pose(position=_Point(x=float(x), y=float(y), z=float(z)),
                 orientation=_Quaternion(x=float(qx), y=float(qy), z=float(qz), w=float(qw)))


def model_entity(id: str, frame_id: str, pose: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                 rgba: Sequence[float], stamp_ns: int, *, frame_locked: bool = True) -> Any:
    """``foxglove_msgs/SceneEntity`` holding one mesh as an embedded GLB ``ModelPrimitive``.

    Parameters
    ----------
    id : str
        Entity id; a later entity with the same id on the topic replaces it.
    frame_id : str
        Frame the mesh is placed in.
    pose : (4, 4) float
        The mesh's placement in ``frame_id`` (translation [m]).
    vertices, faces
        As :func:`glb_bytes` ([m], Z up).
    rgba : (4,) float
        Colour in [0, 1]; drawn instead of any material (``override_color``).
    stamp_ns : int
        Entity timestamp [ns].
    frame_locked : bool
        Follow ``frame_id`` as it moves (True), or stay where the frame was at ``stamp_ns``.
    """
    c = np.asarray(rgba, dtype=np.float64).reshape(-1)
    if c.shape != (4,) or not np.all((c >= 0) & (c <= 1)):
        raise McapError(f"entity {id}: colour must be 4 values r, g, b, a in [0, 1], got {list(rgba)}")
    model = _ModelPrimitive(
        pose=_pose(pose), scale=_Vector3(x=1.0, y=1.0, z=1.0),
        color=_Color(r=float(c[0]), g=float(c[1]), b=float(c[2]), a=float(c[3])), override_color=True,
        url="", media_type=GLB_MEDIA_TYPE, data=np.frombuffer(glb_bytes(vertices, faces), np.uint8).copy())
    return _SceneEntity(timestamp=ros_time(stamp_ns), frame_id=frame_id, id=id,
                        lifetime=_Duration(sec=0, nanosec=0), frame_locked=bool(frame_locked), metadata=[],
                        arrows=[], cubes=[], spheres=[], cylinders=[], lines=[], triangles=[], texts=[],
                        models=[model])


def scene_update(entities: Iterable[Any]) -> Any:
    """``foxglove_msgs/SceneUpdate`` adding (or replacing) ``entities``, deleting none."""
    return _SceneUpdate(deletions=[], entities=list(entities))


def visuals_scene(visuals: Iterable["LinkVisual"], stamp_ns: int) -> Any:
    """The robot as Foxglove draws it from the log: a ``SceneUpdate`` with one frame-locked
    entity per link visual (:func:`robotprog.visuals.robot_visuals`), in the link's frame."""
    return scene_update(model_entity(v.name, v.link, v.pose, v.vertices, v.faces, v.rgba, stamp_ns)
                        for v in visuals)


__all__ = ["GLB_MEDIA_TYPE", "Z_UP_TO_Y_UP", "glb_bytes", "model_entity", "scene_update", "visuals_scene"]
