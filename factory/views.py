"""Views: CAM values (millimetres) turned into ROS 2 messages (metres) for the MCAP log.

This is the one place where units change: every CAM value is in millimetres in work
coordinates, every ROS message in metres (REP 103), so points are divided by 1000 here
and nowhere else. Frames: ``work`` is the work-coordinate frame the G-code is written in;
it hangs under ``world`` on ``/tf_static`` (identity for now, so that later stages can
place the machine, the vise and the robot cell around it without touching these views).

Topics written by :func:`job_messages` (all latched: they describe a static scene and
a late subscriber on ``ros2 bag play`` should still get them):

``/tf_static``      tf2_msgs/TFMessage: ``world`` -> ``work``
``/cam/toolpath``   visualization_msgs/MarkerArray: per operation one LINE_LIST each for
                    cutting moves, plunge/ramp moves and rapids (see :func:`toolpath_markers`)
``/cam/part``       visualization_msgs/MarkerArray: the part mesh, TRIANGLE_LIST
``/cam/stock``      visualization_msgs/MarkerArray: the stock box, translucent CUBE
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from cadcam.model import Job, Motion, Operation
from factory.core.errors import McapError
from factory.core.units import MM_PER_M
from factory.rosmsgs import (RGBA, LineList, Serialized, cube_marker, line_list_marker, line_list_marker_array,
                             marker_array, serialize_cdr, tf_message, transform_stamped, triangle_mesh_marker_array)

#: Frame of work coordinates, and the frame it is placed in.
WORK_FRAME = "work"
WORLD_FRAME = "world"


@dataclass(frozen=True)
class ViewStyle:
    """Colours and line widths of the CAM views.

    Attributes
    ----------
    feed_width : float
        Displayed width of cutting and plunge moves [mm].
    rapid_width : float
        Displayed width of rapids [mm].
    roughing, finishing, plunge, rapid, part, stock : (r, g, b, a) float
        Colours in [0, 1]. Roughing is any operation of kind ``"roughing"``, finishing
        every other kind. Rapids are translucent so that they read as "air".
    """

    feed_width: float = 0.2
    rapid_width: float = 0.1
    roughing: RGBA = (0.15, 0.4, 1.0, 1.0)
    finishing: RGBA = (0.1, 0.75, 0.25, 1.0)
    plunge: RGBA = (1.0, 0.8, 0.0, 1.0)
    rapid: RGBA = (1.0, 0.25, 0.1, 0.5)
    part: RGBA = (0.62, 0.62, 0.65, 1.0)
    stock: RGBA = (0.85, 0.7, 0.45, 0.2)


def _segments(op: Operation, kinds: tuple[Motion, ...]) -> np.ndarray:
    """Endpoint pairs of the moves of ``kinds``: ``(2k, 3)`` [mm], LINE_LIST order."""
    if len(op.points) < 2:
        return np.zeros((0, 3))
    moving = np.isin(op.motion[1:], np.array([int(k) for k in kinds], dtype=np.int8))
    pairs = np.stack([op.points[:-1][moving], op.points[1:][moving]], axis=1)
    return pairs.reshape(-1, 3)


def toolpath_markers(job: Job, stamp_ns: int = 0, style: ViewStyle = ViewStyle()) -> list[object]:
    """Markers of every operation's cutter locations, in frame ``work`` [m].

    Per operation ``i`` (namespace ``"NN <operation name>"``, NN = i + 1 zero-padded):
    id 0 the CUT moves, id 1 the PLUNGE moves (ramps, helices, entries), id 2 the RAPIDs,
    each a LINE_LIST (omitted when empty). ``motion[i]`` colours the segment ending at
    ``points[i]``, exactly as the post reads it.

    Why LINE_LIST and not LINE_STRIP: a strip is one continuous polyline, so feed runs
    separated by rapids would need one strip per run, i.e. thousands of markers for a
    roughing operation, and Foxglove/RViz pay per marker (one scene object each). A LINE_LIST
    keeps one marker per kind and operation at any path length and never draws a
    connecting line that is not a move; the price is every interior point sent twice
    (48 bytes per segment before zstd, which removes most of the repetition).
    """
    return [line_list_marker(*line, WORK_FRAME, stamp_ns) for line in _toolpath_lines(job, style)]


def _toolpath_lines(job: Job, style: ViewStyle) -> list[LineList]:
    """The LINE_LISTs of :func:`toolpath_markers`: namespace, id, points [m], colour, width [m]."""
    out: list[LineList] = []
    for i, op in enumerate(job.operations):
        ns = f"{i + 1:02d} {op.name}"
        feed_color = style.roughing if op.kind == "roughing" else style.finishing
        for mid, kinds, color, width in (
            (0, (Motion.CUT,), feed_color, style.feed_width),
            (1, (Motion.PLUNGE,), style.plunge, style.feed_width),
            (2, (Motion.RAPID,), style.rapid, style.rapid_width),
        ):
            seg = _segments(op, kinds)
            if len(seg):
                out.append((ns, mid, seg / MM_PER_M, color, width / MM_PER_M))
    return out


def job_messages(
    job: Job,
    part_work_vertices: np.ndarray,
    part_faces: np.ndarray,
    stamp_ns: int = 0,
    style: ViewStyle = ViewStyle(),
    transform_world_to_work: np.ndarray | None = None,
) -> list[tuple[str, object, bool]]:
    """The messages that show a CAM job in Foxglove: ``(topic, message, latched)`` tuples.

    Parameters
    ----------
    job : Job
        Setup and operations, work coordinates [mm].
    part_work_vertices : (n, 3) float
        Part mesh vertices in work coordinates [mm].
    part_faces : (m, 3) int
        Vertex indices per triangle.
    stamp_ns : int
        Header stamp of every message [ns] (0 for a timeless plan).
    style : ViewStyle
    transform_world_to_work : (4, 4) float, optional
        Pose of the work frame in ``world`` [m] (the part in the vise of a robot cell);
        default identity.

    Returns
    -------
    list of (str, message, bool)
        ``/tf_static``, ``/cam/toolpath``, ``/cam/part`` (only if the mesh has faces) and
        ``/cam/stock``, all latched, all points in metres in frame ``work``.
    """
    messages = [work_frame_message(transform_world_to_work, stamp_ns),
                *job_scene_messages(job, part_work_vertices, part_faces, stamp_ns, style)]
    return [(topic, message.make(), latched) for topic, message, latched in messages]


def work_frame_message(transform_world_to_work: np.ndarray | None = None,
                       stamp_ns: int = 0) -> tuple[str, Serialized, bool]:
    """The first of :func:`job_messages`, serialised: ``/tf_static`` placing ``work`` in ``world`` (the pose [m],
    default identity; with a robot, in the cell's vise: known once the robot's share is planned)."""
    pose = np.eye(4) if transform_world_to_work is None else transform_world_to_work
    world_work = transform_stamped(WORLD_FRAME, WORK_FRAME, pose, stamp_ns)
    return "/tf_static", _serialized(tf_message([world_work])), True


def job_scene_messages(job: Job, part_work_vertices: np.ndarray, part_faces: np.ndarray, stamp_ns: int = 0,
                       style: ViewStyle = ViewStyle()) -> list[tuple[str, Serialized, bool]]:
    """The rest of :func:`job_messages` (toolpath, part, stock), serialised for a log: the toolpath's and the
    part's straight from their arrays (no object per point: most of a plan's log was making and serialising
    them). The same bytes as the messages'; the same parameters and errors. They need no robot."""
    msgs: list[tuple[str, Serialized, bool]] = [
        ("/cam/toolpath", line_list_marker_array(_toolpath_lines(job, style), WORK_FRAME, stamp_ns), True),
    ]
    v = np.asarray(part_work_vertices, dtype=np.float64)
    f = np.asarray(part_faces)
    if f.size:
        msgs.append(("/cam/part", triangle_mesh_marker_array("part", 0, v / MM_PER_M, f, style.part, WORK_FRAME,
                                                             stamp_ns), True))
    s = job.setup
    stock = cube_marker("stock", 0, (s.stock_min + s.stock_max) / 2 / MM_PER_M, s.stock_size / MM_PER_M,
                        style.stock, WORK_FRAME, stamp_ns)
    msgs.append(("/cam/stock", _serialized(marker_array([stock])), True))
    return msgs


def _serialized(msg: Any) -> Serialized:
    """``msg`` (a :data:`factory.rosmsgs.TYPESTORE` message) serialised, and itself to ``make``."""
    return Serialized(msg.__msgtype__, serialize_cdr(msg, msg.__msgtype__), lambda: msg)


def heightfield_mesh(
    xs: np.ndarray, ys: np.ndarray, z: np.ndarray, max_triangles: int = 200_000
) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate the top surface of a heightfield, decimated to at most ``max_triangles``.

    Cells are skipped where ``z`` is not finite (``-inf``: no material in that column).
    Decimation keeps every ``s``-th row and column (plus the last ones, so the outline is
    kept) with the smallest stride ``s`` that fits: a display aid, not a measurement.

    Parameters
    ----------
    xs : (nx,) float
        Grid x coordinates [mm], monotonic.
    ys : (ny,) float
        Grid y coordinates [mm], monotonic.
    z : (ny, nx) float
        Height at ``(ys[j], xs[i])`` [mm]; ``-inf`` (or NaN) where there is nothing.
    max_triangles : int
        Upper bound on the triangles returned (default 200 000, about 14 MB as a
        TRIANGLE_LIST marker).

    Returns
    -------
    vertices : (k, 3) float
        [mm], only vertices some face uses.
    faces : (m, 3) int64
        Counter-clockwise seen from +Z (normals up), m <= max_triangles.

    Raises
    ------
    McapError
        Shapes that do not match, or ``max_triangles < 2``.
    """
    xs = np.asarray(xs, dtype=np.float64).reshape(-1)
    ys = np.asarray(ys, dtype=np.float64).reshape(-1)
    z = np.asarray(z, dtype=np.float64)
    if z.shape != (len(ys), len(xs)):
        raise McapError(f"heightfield z has shape {z.shape}, expected (len(ys), len(xs)) = {(len(ys), len(xs))}")
    if max_triangles < 2:
        raise McapError(f"max_triangles must be >= 2, got {max_triangles}")
    nx, ny = len(xs), len(ys)
    empty = (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    if nx < 2 or ny < 2:
        return empty

    def n_tri(s: int) -> int:
        return 2 * math.ceil((nx - 1) / s) * math.ceil((ny - 1) / s)

    stride = max(1, int(math.sqrt(n_tri(1) / max_triangles)))
    while n_tri(stride) > max_triangles:
        stride += 1
    ix = np.unique(np.append(np.arange(0, nx, stride), nx - 1))
    iy = np.unique(np.append(np.arange(0, ny, stride), ny - 1))
    zz = z[np.ix_(iy, ix)]
    gx, gy = np.meshgrid(xs[ix], ys[iy])
    vertices = np.column_stack([gx.ravel(), gy.ravel(), zz.ravel()])
    valid = np.isfinite(zz).ravel()

    w = len(ix)
    j, i = np.meshgrid(np.arange(len(iy) - 1), np.arange(w - 1), indexing="ij")
    a = (j * w + i).ravel()
    b, c, d = a + 1, a + w + 1, a + w  # (i+1, j), (i+1, j+1), (i, j+1)
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    # a -> b -> c runs counter-clockwise seen from +Z when x and y both increase.
    if (xs[-1] - xs[0]) * (ys[-1] - ys[0]) < 0:
        faces = faces[:, ::-1]
    faces = faces[valid[faces].all(axis=1)]
    if not len(faces):
        return empty
    used, remap = np.unique(faces, return_inverse=True)
    return vertices[used], remap.reshape(-1, 3).astype(np.int64)
