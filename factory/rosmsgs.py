"""ROS 2 messages of factory's logs: the typestore, the message builders, and the CDR of the messages logged most.

Message classes, CDR serialisation and definition texts come from rosbags' ROS 2 Jazzy
typestore (:data:`TYPESTORE`), with the ``.msg`` files under :data:`MSG_DIRS` registered into
it (``foxglove_msgs``: Foxglove's scene and image-annotation messages, checked field by field
against Foxglove's own definitions in ``tests/foxglove``; ``factory_msgs``: the cell's own, from
the ROS 2 interface package in ``ros/``). The file that carries them is :mod:`factory.mcaplog`'s.

Units: ROS speaks metres, seconds and radians. The builders below take metres (and a
4x4 homogeneous transform with its translation in metres); the millimetre-to-metre
conversion of CAM values happens in the views that call them (:mod:`factory.views`).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from factory.core.errors import McapError
from factory.core.resources import FOXGLOVE_INTERFACES, ROS_INTERFACES

#: ROS 2 distribution whose message definitions and bag conventions the files follow.
ROS_DISTRO = "jazzy"
#: rosbags typestore with every message type we log (visualization_msgs, sensor_msgs,
#: tf2_msgs, trajectory_msgs, std_msgs, rcl_interfaces, geometry_msgs, ...).
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
#: Folders of ROS interface packages (``PKG/msg/NAME.msg``) registered into :data:`TYPESTORE`:
#: Foxglove's scene and image-annotation messages, and factory's own (``ros/factory_msgs``).
MSG_DIRS = (FOXGLOVE_INTERFACES, ROS_INTERFACES)


def register_msg_files(typestore: Any, roots: Iterable[Path]) -> list[str]:
    """Register every ``ROOT/PKG/msg/NAME.msg`` into ``typestore``; return the type names.

    Raises
    ------
    McapError
        A file cannot be read or parsed as a ROS 2 message definition.
    """
    types: dict[str, Any] = {}
    for root in roots:
        for path in sorted(Path(root).glob("*/msg/*.msg")):
            name = f"{path.parent.parent.name}/msg/{path.stem}"
            try:
                types.update(get_types_from_msg(path.read_text(encoding="utf-8"), name))
            except Exception as e:  # rosbags raises its own parse errors
                raise McapError(f"cannot read message definition: {e}", source=path) from None
    typestore.register(types)
    return sorted(types)


register_msg_files(TYPESTORE, MSG_DIRS)

RGBA = tuple[float, float, float, float]

_T = TYPESTORE.types
_Time = _T["builtin_interfaces/msg/Time"]
_Duration = _T["builtin_interfaces/msg/Duration"]
_Header = _T["std_msgs/msg/Header"]
_ColorRGBA = _T["std_msgs/msg/ColorRGBA"]
_String = _T["std_msgs/msg/String"]
_Point = _T["geometry_msgs/msg/Point"]
_Vector3 = _T["geometry_msgs/msg/Vector3"]
_Quaternion = _T["geometry_msgs/msg/Quaternion"]
_Pose = _T["geometry_msgs/msg/Pose"]
_Transform = _T["geometry_msgs/msg/Transform"]
_TransformStamped = _T["geometry_msgs/msg/TransformStamped"]
_TFMessage = _T["tf2_msgs/msg/TFMessage"]
_Marker = _T["visualization_msgs/msg/Marker"]
_MarkerArray = _T["visualization_msgs/msg/MarkerArray"]
_MeshFile = _T["visualization_msgs/msg/MeshFile"]
_CompressedImage = _T["sensor_msgs/msg/CompressedImage"]
_Log = _T["rcl_interfaces/msg/Log"]

_INT32_MAX = 2**31 - 1

def message_definition(typename: str) -> str:
    """The ``ros2msg`` schema text of ``typename`` as rosbag2 stores it.

    The top-level definition, then for every type it depends on (once, recursively) a line
    of 80 ``=``, a line ``MSG: pkg/Name`` with the type named as its fields spell it (not
    ``pkg/msg/Name``: Foxglove's parser would not find it) and that type's definition.
    """
    text, _ = TYPESTORE.generate_msgdef(typename, ros_version=2)
    return text


# --- CDR of the messages logged most, written directly ------------------------------------
# A run logs a joint state and the links' transforms per robot sample: most of its messages.
# rosbags' generic serialiser packs them field by field; these write the same bytes (little-endian
# plain CDR, each primitive aligned to its size counted after the 4-byte encapsulation header) with
# one pack per message part. tests/factory/test_mcaplog.py holds them to rosbags' bytes.

_CDR_LE = b"\x00\x01\x00\x00"
_UINT32, _STAMP, _SEVEN_DOUBLES = struct.Struct("<I"), struct.Struct("<iI"), struct.Struct("<7d")
_THREE_INT32, _TEN_DOUBLES, _FOUR_FLOATS = struct.Struct("<3i"), struct.Struct("<10d"), struct.Struct("<4f")


class _Cdr:
    """A little-endian CDR buffer with its encapsulation header."""

    def __init__(self) -> None:
        self.buf = bytearray(_CDR_LE)

    def align(self, n: int) -> None:
        pad = -(len(self.buf) - 4) % n
        if pad:
            self.buf += bytes(pad)

    def uint32(self, v: int) -> None:
        self.align(4)
        self.buf += _UINT32.pack(v)

    def stamp(self, t: Any) -> None:
        self.align(4)
        self.buf += _STAMP.pack(t.sec, t.nanosec)

    def string(self, v: str) -> None:
        data = v.encode()
        self.uint32(len(data) + 1)
        self.buf += data + b"\x00"

    def float64s(self, values: Any) -> None:
        """A sequence of float64 values [any unit]: its length, then the values."""
        a = np.asarray(values, dtype="<f8").reshape(-1)
        self.uint32(len(a))
        if len(a):
            self.align(8)
            self.buf += a.tobytes()


def _joint_state_cdr(msg: Any) -> bytes:
    """CDR of a ``sensor_msgs/JointState``."""
    w = _Cdr()
    w.stamp(msg.header.stamp)
    w.string(msg.header.frame_id)
    w.uint32(len(msg.name))
    for name in msg.name:
        w.string(name)
    for values in (msg.position, msg.velocity, msg.effort):
        w.float64s(values)
    return bytes(w.buf)


def _tf_message_cdr(msg: Any) -> bytes:
    """CDR of a ``tf2_msgs/TFMessage``."""
    w = _Cdr()
    w.uint32(len(msg.transforms))
    for t in msg.transforms:
        w.stamp(t.header.stamp)
        w.string(t.header.frame_id)
        w.string(t.child_frame_id)
        v, r = t.transform.translation, t.transform.rotation
        w.align(8)
        w.buf += _SEVEN_DOUBLES.pack(v.x, v.y, v.z, r.x, r.y, r.z, r.w)
    return bytes(w.buf)


class CdrTemplate(_Cdr):
    """The CDR of a message whose layout is fixed (its strings and sequence lengths known ahead),
    written once with :class:`_Cdr`'s own alignment, with holes for the values that change
    (stamps, numbers): :meth:`fill` joins the constant pieces and the holes' bytes, for messages
    made many times (a robot's joint states and link transforms at every logged state)."""

    def __init__(self) -> None:
        super().__init__()
        self.pieces: list[bytes] = []
        self.sizes: list[int] = []
        self._cut = 0

    def hole(self, nbytes: int, align: int) -> None:
        """Leave ``nbytes`` bytes to fill, aligned to ``align`` bytes."""
        self.align(align)
        self.pieces.append(bytes(self.buf[self._cut:]))
        self.sizes.append(nbytes)
        self.buf += bytes(nbytes)
        self._cut = len(self.buf)

    def fill(self, holes: Sequence[bytes]) -> bytes:
        """The message's bytes, ``holes`` (as many as :meth:`hole` made, each of its size) in place."""
        out = [None] * (2 * len(holes) + 1)
        out[0:-1:2] = self.pieces
        out[1::2] = holes
        out[-1] = bytes(self.buf[self._cut:])
        return b"".join(out)


class JointStateCdr:
    """CDR of ``sensor_msgs/JointState`` messages of fixed joint ``names`` and empty frame id and
    effort, as :func:`serialize_cdr` writes them, from the stamp and the numbers alone."""

    def __init__(self, names: Sequence[str]) -> None:
        self.n = len(names)
        t = CdrTemplate()
        t.hole(_STAMP.size, 4)
        t.string("")
        t.uint32(self.n)
        for name in names:
            t.string(name)
        for _ in range(2):  # position, velocity
            t.uint32(self.n)
            if self.n:
                t.hole(8 * self.n, 8)
        t.uint32(0)  # effort
        self.template = t

    def cdr(self, stamp_ns: int, position: np.ndarray, velocity: np.ndarray) -> bytes:
        """``position`` and ``velocity`` (n,) float [rad, rad/s] at ``stamp_ns`` [ns]."""
        time = ros_time(stamp_ns)
        stamp = _STAMP.pack(time.sec, time.nanosec)
        values = [np.asarray(v, dtype="<f8").reshape(self.n).tobytes() for v in (position, velocity)]
        return self.template.fill([stamp, *values] if self.n else [stamp])


class TfCdr:
    """CDR of ``tf2_msgs/TFMessage`` messages placing fixed ``children`` in one ``parent`` frame at
    one stamp, as :func:`serialize_cdr` writes :func:`transforms_stamped`'s, from the stamp and the
    matrices alone (no message objects: a robot's links at each logged state)."""

    def __init__(self, parent: str, children: Sequence[str]) -> None:
        self.k = len(children)
        t = CdrTemplate()
        t.uint32(self.k)
        for child in children:
            t.hole(_STAMP.size, 4)
            t.string(parent)
            t.string(child)
            t.hole(_SEVEN_DOUBLES.size, 8)
        self.template = t

    def cdr(self, stamp_ns: int, poses: np.ndarray) -> bytes:
        """``poses`` (k, 7) float: each child's pose in the parent, translation [m] and unit
        quaternion (x, y, z, w) as :func:`transform_values` gives them, at ``stamp_ns`` [ns]."""
        time = ros_time(stamp_ns)
        stamp = _STAMP.pack(time.sec, time.nanosec)
        values = np.asarray(poses, dtype="<f8").reshape(self.k, 7).tobytes()
        holes: list[bytes] = []
        for i in range(self.k):
            holes += (stamp, values[56 * i:56 * (i + 1)])
        return self.template.fill(holes)


def transform_values(matrices: np.ndarray) -> np.ndarray:
    """(..., 7) float: translation [m] and unit quaternion (x, y, z, w) of rigid transforms
    ``matrices`` (..., 4, 4), as :func:`transforms_stamped` logs them (not checked: for transforms
    made by forward kinematics). Vectorised over all of them: a whole move's link transforms at once."""
    m = np.asarray(matrices, dtype=np.float64)
    flat = m.reshape(-1, 4, 4)
    values = np.concatenate([flat[:, :3, 3], _quaternions(flat[:, :3, :3])], axis=1)
    return values.reshape(*m.shape[:-2], 7)


@dataclass(frozen=True)
class Serialized:
    """A message already serialised: ``cdr`` of type ``typename``, for
    :meth:`McapLog.write_cdr`; ``make`` builds the message itself, for sinks that serialise
    themselves (:meth:`factory.live.Fanout.write_cdr`)."""

    typename: str
    cdr: bytes
    make: Callable[[], Any]


# Two stamps none of whose eight bytes agree: where two serialisations of one message at these
# stamps differ is exactly where its stamps are.
_STAMP_A, _STAMP_B = (0x12345678, 0x1A2B3C4D), (0x23456789, 0x2B3C4D5E)


class RestampedCdr:
    """The CDR of one large message logged again and again at new stamps (a part's stock and
    toolpath markers at every load): serialised once, and only its stamps packed at each use.

    ``restamp(msg, stamp_ns)`` sets the stamps that change, in place, and returns the message. It
    is serialised at two stamps; the bytes that differ must be exactly the stamps' (checked, else
    each use serialises the message whole), and they are the holes filled at :meth:`at`."""

    def __init__(self, msg: Any, restamp: Callable[[Any, int], Any]) -> None:
        self.msg, self.restamp = msg, restamp
        self.typename: str = msg.__msgtype__
        a, b = (_STAMP.pack(*s) for s in (_STAMP_A, _STAMP_B))
        data_a = serialize_cdr(restamp(msg, _STAMP_A[0] * 1_000_000_000 + _STAMP_A[1]), self.typename)
        data_b = serialize_cdr(restamp(msg, _STAMP_B[0] * 1_000_000_000 + _STAMP_B[1]), self.typename)
        where, i = [], data_a.find(a)
        while i >= 0:
            where.append(i)
            i = data_a.find(a, i + len(a))
        swapped = bytearray(data_a)
        for i in where:
            swapped[i:i + len(b)] = b
        self.pieces: list[bytes] | None = None
        if len(data_a) == len(data_b) and bytes(swapped) == data_b:
            cuts = [0, *(j for i in where for j in (i, i + len(a))), len(data_a)]
            self.pieces = [data_a[cuts[k]:cuts[k + 1]] for k in range(0, len(cuts), 2)]

    def at(self, stamp_ns: int) -> Serialized:
        """The message at ``stamp_ns`` [ns], serialised."""

        def make() -> Any:
            return self.restamp(self.msg, stamp_ns)

        if self.pieces is None:
            return Serialized(self.typename, serialize_cdr(make(), self.typename), make)
        t = ros_time(stamp_ns)
        return Serialized(self.typename, _STAMP.pack(t.sec, t.nanosec).join(self.pieces), make)


#: Serialisers written directly, by type name; every other type goes through rosbags.
_FAST_CDR = {"sensor_msgs/msg/JointState": _joint_state_cdr, "tf2_msgs/msg/TFMessage": _tf_message_cdr}


def serialize_cdr(msg: Any, typename: str) -> bytes:
    """CDR bytes of ``msg``, a :data:`TYPESTORE` message of type ``typename`` (what rosbags' would write)."""
    fast = _FAST_CDR.get(typename)
    return fast(msg) if fast is not None else bytes(TYPESTORE.serialize_cdr(msg, typename))


# --- message builders: pure functions returning rosbags message objects (SI units) -------


def ros_time(ns: int) -> Any:
    """``builtin_interfaces/Time`` for a time in nanoseconds (``sec`` must fit int32)."""
    ns = int(ns)
    sec, nanosec = divmod(ns, 1_000_000_000)
    if not -(2**31) <= sec <= _INT32_MAX:
        raise McapError(f"time {ns} ns does not fit builtin_interfaces/Time")
    return _Time(sec=sec, nanosec=nanosec)


def _header(frame_id: str, stamp_ns: int) -> Any:
    return _Header(stamp=ros_time(stamp_ns), frame_id=frame_id)


def _color(rgba: Sequence[float]) -> Any:
    c = np.asarray(rgba, dtype=np.float64).reshape(-1)
    if c.shape != (4,) or not np.all((c >= 0) & (c <= 1)):
        raise McapError(f"colour must be 4 values r, g, b, a in [0, 1], got {list(rgba)}")
    return _ColorRGBA(r=float(c[0]), g=float(c[1]), b=float(c[2]), a=float(c[3]))


def _checked_points(points: np.ndarray, what: str) -> np.ndarray:
    """(n, 3) float64 ``points``, or a McapError naming ``what``: not (n, 3), or not finite."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise McapError(f"{what}: points must have shape (n, 3), got {p.shape}")
    if not np.isfinite(p).all():
        raise McapError(f"{what}: {int((~np.isfinite(p)).any(axis=1).sum())} non-finite points")
    return p


def _points(points: np.ndarray, what: str) -> list[Any]:
    p = _checked_points(points, what)
    # rosbags serialises sequences of structs from objects; map() keeps the loop in C.
    return list(map(_Point, *p.T.tolist())) if len(p) else []


def _identity_pose(position: Sequence[float] = (0.0, 0.0, 0.0)) -> Any:
    x, y, z = (float(v) for v in position)
    return _Pose(position=_Point(x=x, y=y, z=z), orientation=_Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))


def _marker(ns: str, id: int, type_: int, frame_id: str, stamp_ns: int, *, color: Sequence[float],
            scale: Sequence[float], points: list[Any], pose: Any | None = None) -> Any:
    header = _header(frame_id, stamp_ns)
    return _Marker(
        header=header,
        ns=ns,
        id=int(id),
        type=type_,
        action=_Marker.ADD,
        pose=pose if pose is not None else _identity_pose(),
        scale=_Vector3(x=float(scale[0]), y=float(scale[1]), z=float(scale[2])),
        color=_color(color),
        lifetime=_Duration(sec=0, nanosec=0),  # 0: forever
        frame_locked=False,
        points=points,
        colors=[],
        texture_resource="",
        texture=_CompressedImage(header=_header("", 0), format="", data=np.zeros(0, np.uint8)),
        uv_coordinates=[],
        text="",
        mesh_resource="",
        mesh_file=_MeshFile(filename="", data=np.zeros(0, np.uint8)),
        mesh_use_embedded_materials=False,
    )


def transform_stamped(parent: str, child: str, matrix: np.ndarray, stamp_ns: int) -> Any:
    """``geometry_msgs/TransformStamped`` placing frame ``child`` in frame ``parent``.

    Parameters
    ----------
    parent, child : str
        Frame ids (``header.frame_id`` and ``child_frame_id``).
    matrix : (4, 4) float
        Homogeneous transform from ``child`` to ``parent`` coordinates; translation in
        **metres**; the 3x3 block a proper rotation.
    stamp_ns : int
        Header stamp [ns].

    Raises
    ------
    McapError
        Wrong shape, non-finite values, or a 3x3 block that is not a rotation.
    """
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4):
        raise McapError(f"transform {parent} -> {child} must be a finite 4x4 matrix")
    return transforms_stamped(parent, [child], m[None], stamp_ns)[0]


def _quaternions(r: np.ndarray) -> np.ndarray:
    """Unit quaternions (x, y, z, w) of rotation matrices ``r`` (k, 3, 3), by Markley's method
    (the largest of the four candidate forms, so no division by a small number): what scipy's
    ``Rotation.from_matrix`` gives, sign included, without its per-call overhead (the robot's
    link transforms are converted at every logged state)."""
    m00, m11, m22 = r[:, 0, 0], r[:, 1, 1], r[:, 2, 2]
    trace = m00 + m11 + m22
    a, b, c = r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]
    d, e, f = r[:, 0, 1] + r[:, 1, 0], r[:, 0, 2] + r[:, 2, 0], r[:, 1, 2] + r[:, 2, 1]
    # the four forms (x, y, z, w), by which of m00, m11, m22, trace is largest
    forms = np.array([[1.0 - trace + 2.0 * m00, d, e, a],
                      [d, 1.0 - trace + 2.0 * m11, f, b],
                      [e, f, 1.0 - trace + 2.0 * m22, c],
                      [a, b, c, 1.0 + trace]])  # (form, component, k)
    choice = np.argmax(np.array([m00, m11, m22, trace]), axis=0)
    q = forms[choice, :, np.arange(len(r))]
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def transforms_stamped(parent: str, children: Sequence[str], matrices: np.ndarray, stamp_ns: int) -> list[Any]:
    """:func:`transform_stamped` for many children of one parent at one stamp, checked and
    converted in one vectorised pass (``matrices`` (k, 4, 4), translations in metres)."""
    m = np.asarray(matrices, dtype=np.float64)
    if m.ndim != 3 or m.shape[1:] != (4, 4) or len(m) != len(children) or not np.isfinite(m).all():
        raise McapError(f"transforms {parent} -> {', '.join(children)} must be finite 4x4 matrices")
    r = m[:, :3, :3]
    bad = ((np.abs(m[:, 3] - [0, 0, 0, 1]) > 1e-9).any(axis=1)
           | (np.abs(r @ r.transpose(0, 2, 1) - np.eye(3)) > 1e-6).any(axis=(1, 2))
           | (np.linalg.det(r) < 0))
    if bad.any():
        raise McapError(f"transform {parent} -> {children[int(np.argmax(bad))]} is not a rigid motion")
    quats = _quaternions(r).tolist()
    header = _header(parent, stamp_ns)
    out = []
    for child, (qx, qy, qz, qw), (tx, ty, tz) in zip(children, quats, m[:, :3, 3].tolist()):
        out.append(_TransformStamped(
            header=header,
            child_frame_id=child,
            transform=_Transform(
                translation=_Vector3(x=tx, y=ty, z=tz),
                rotation=_Quaternion(x=qx, y=qy, z=qz, w=qw),
            ),
        ))
    return out


def tf_message(transforms: Iterable[Any]) -> Any:
    """``tf2_msgs/TFMessage`` for ``/tf`` or ``/tf_static`` (log the latter latched)."""
    return _TFMessage(transforms=list(transforms))


def line_strip_marker(ns: str, id: int, points: np.ndarray, color: RGBA, width: float,
                      frame_id: str, stamp_ns: int) -> Any:
    """``visualization_msgs/Marker`` LINE_STRIP: one polyline through ``points``.

    Parameters
    ----------
    ns, id : str, int
        Marker namespace and id (together they name the marker; Foxglove toggles by ns).
    points : (n, 3) float
        Polyline vertices in ``frame_id`` [m].
    color : (r, g, b, a) float
        In [0, 1].
    width : float
        Line width [m].
    frame_id : str
    stamp_ns : int
        Header stamp [ns].
    """
    return _marker(ns, id, _Marker.LINE_STRIP, frame_id, stamp_ns, color=color,
                   scale=(width, 0.0, 0.0), points=_points(points, f"marker {ns}/{id}"))


def line_list_marker(ns: str, id: int, points: np.ndarray, color: RGBA, width: float,
                     frame_id: str, stamp_ns: int) -> Any:
    """``visualization_msgs/Marker`` LINE_LIST: separate segments ``points[2k] -> points[2k+1]``.

    Same parameters as :func:`line_strip_marker`; ``points`` is ``(2k, 3)`` [m].
    """
    p = np.asarray(points)
    if p.ndim == 2 and len(p) % 2:
        raise McapError(f"marker {ns}/{id}: LINE_LIST needs an even number of points, got {len(p)}")
    return _marker(ns, id, _Marker.LINE_LIST, frame_id, stamp_ns, color=color,
                   scale=(width, 0.0, 0.0), points=_points(p, f"marker {ns}/{id}"))


def triangle_mesh_marker(ns: str, id: int, vertices: np.ndarray, faces: np.ndarray, color: RGBA,
                         frame_id: str, stamp_ns: int) -> Any:
    """``visualization_msgs/Marker`` TRIANGLE_LIST of an indexed triangle mesh.

    Parameters
    ----------
    vertices : (n, 3) float
        Vertex positions in ``frame_id`` [m].
    faces : (m, 3) int
        Vertex indices per triangle, counter-clockwise seen from outside. TRIANGLE_LIST
        has no index buffer, so the message carries ``3 m`` points.
    color : (r, g, b, a) float
    """
    # scale 1: RViz multiplies TRIANGLE_LIST points by scale.
    return _marker(ns, id, _Marker.TRIANGLE_LIST, frame_id, stamp_ns, color=color, scale=(1.0, 1.0, 1.0),
                   points=_points(_triangle_corners(ns, id, vertices, faces), f"marker {ns}/{id}"))


def _triangle_corners(ns: str, id: int, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(3 m, 3) float: each of the ``faces``' (m, 3) corners of ``vertices`` (n, 3) [m], in order; a
    McapError naming marker ``ns``/``id`` for faces that are not (m, 3) integers in range."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if f.size == 0:
        f = f.reshape(0, 3)
    if f.ndim != 2 or f.shape[1] != 3 or (f.size and not np.issubdtype(f.dtype, np.integer)):
        raise McapError(f"marker {ns}/{id}: faces must be (m, 3) integers, got {f.shape} {f.dtype}")
    if v.ndim != 2 or v.shape[1] != 3:
        raise McapError(f"marker {ns}/{id}: vertices must have shape (n, 3), got {v.shape}")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise McapError(f"marker {ns}/{id}: face index out of range [0, {len(v)})")
    return v[f.reshape(-1)]


def triangle_mesh_marker_array(ns: str, id: int, vertices: np.ndarray, faces: np.ndarray, color: RGBA,
                               frame_id: str, stamp_ns: int) -> Serialized:
    """``visualization_msgs/MarkerArray`` of the one :func:`triangle_mesh_marker`, serialised from the
    arrays: the message's bytes without an object per corner (a verified stock's mesh has hundreds of
    thousands); its ``make`` builds the message. Same parameters as :func:`triangle_mesh_marker`."""
    corners = _checked_points(_triangle_corners(ns, id, vertices, faces), f"marker {ns}/{id}")
    w = _Cdr()
    w.uint32(1)  # one marker
    _marker_cdr(w, ns, id, _Marker.TRIANGLE_LIST, frame_id, stamp_ns, color, (1.0, 1.0, 1.0), corners)
    return Serialized("visualization_msgs/msg/MarkerArray", bytes(w.buf), lambda: marker_array(
        [triangle_mesh_marker(ns, id, vertices, faces, color, frame_id, stamp_ns)]))


#: One LINE_LIST of :func:`line_list_marker_array`: namespace, id, its (2k, 3) points [m], colour, width [m].
LineList = tuple[str, int, np.ndarray, RGBA, float]


def line_list_marker_array(lines: Sequence[LineList], frame_id: str, stamp_ns: int) -> Serialized:
    """``visualization_msgs/MarkerArray`` of one :func:`line_list_marker` per entry of ``lines``, serialised from
    the arrays (a finishing toolpath has hundreds of thousands of points: an object each cost more than the
    rest of its log); its ``make`` builds the message. The same bytes as the message's, the same errors."""
    w = _Cdr()
    w.uint32(len(lines))
    for ns, id, points, color, width in lines:
        p = np.asarray(points)
        if p.ndim == 2 and len(p) % 2:
            raise McapError(f"marker {ns}/{id}: LINE_LIST needs an even number of points, got {len(p)}")
        p = _checked_points(p, f"marker {ns}/{id}")
        _marker_cdr(w, ns, id, _Marker.LINE_LIST, frame_id, stamp_ns, color, (float(width), 0.0, 0.0), p)
    return Serialized("visualization_msgs/msg/MarkerArray", bytes(w.buf), lambda: marker_array(
        [line_list_marker(*line, frame_id, stamp_ns) for line in lines]))


def _marker_cdr(w: _Cdr, ns: str, id: int, type_: int, frame_id: str, stamp_ns: int, color: RGBA,
                scale: Sequence[float], points: np.ndarray) -> None:
    """One ``visualization_msgs/Marker`` into ``w`` as :func:`_marker` makes it (identity pose, no colours per
    point, texture, text or mesh), its ``points`` (n, 3) [m] checked already: the bytes rosbags writes."""
    stamp = ros_time(stamp_ns)
    rgba = _color(color)  # checked as the message's, after its stamp
    w.stamp(stamp)
    w.string(frame_id)
    w.string(ns)
    w.align(4)
    w.buf += _THREE_INT32.pack(int(id), type_, _Marker.ADD)
    w.align(8)
    w.buf += _TEN_DOUBLES.pack(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, *(float(v) for v in scale))  # pose: identity
    w.buf += _FOUR_FLOATS.pack(rgba.r, rgba.g, rgba.b, rgba.a)
    w.buf += _STAMP.pack(0, 0) + b"\x00"  # lifetime 0 (forever); frame_locked false
    w.uint32(len(points))
    if len(points):
        w.align(8)
        w.buf += np.ascontiguousarray(points, dtype="<f8").tobytes()
    w.uint32(0)  # colors
    w.string("")  # texture_resource
    w.stamp(ros_time(0))  # texture: header, format, data
    w.string("")
    w.string("")
    w.uint32(0)
    w.uint32(0)  # uv_coordinates
    w.string("")  # text
    w.string("")  # mesh_resource
    w.string("")  # mesh_file: filename, data
    w.uint32(0)
    w.buf += b"\x00"  # mesh_use_embedded_materials false


def cube_marker(ns: str, id: int, center: Sequence[float], size: Sequence[float], color: RGBA,
                frame_id: str, stamp_ns: int) -> Any:
    """``visualization_msgs/Marker`` CUBE: an axis-aligned box.

    Parameters
    ----------
    center : (3,) float
        Box centre in ``frame_id`` [m].
    size : (3,) float
        Edge lengths x, y, z [m], all > 0.
    """
    c = np.asarray(center, dtype=np.float64).reshape(-1)
    s = np.asarray(size, dtype=np.float64).reshape(-1)
    if c.shape != (3,) or s.shape != (3,) or not (np.isfinite(c).all() and np.isfinite(s).all()) or (s <= 0).any():
        raise McapError(f"marker {ns}/{id}: cube needs a finite centre and positive size")
    return _marker(ns, id, _Marker.CUBE, frame_id, stamp_ns, color=color, scale=s.tolist(), points=[],
                   pose=_identity_pose(c.tolist()))


def marker_array(markers: Iterable[Any]) -> Any:
    """``visualization_msgs/MarkerArray`` of ``markers``."""
    return _MarkerArray(markers=list(markers))


def string_msg(text: str) -> Any:
    """``std_msgs/String``."""
    return _String(data=str(text))


_LOG_LEVELS = {"debug": _Log.DEBUG, "info": _Log.INFO, "warn": _Log.WARN, "warning": _Log.WARN,
               "error": _Log.ERROR, "fatal": _Log.FATAL, "critical": _Log.FATAL}


def log_msg(level: int | str, name: str, text: str, stamp_ns: int, *, file: str = "",
            function: str = "", line: int = 0) -> Any:
    """``rcl_interfaces/Log`` for ``/rosout``.

    Parameters
    ----------
    level : int or str
        10 debug, 20 info, 30 warn, 40 error, 50 fatal: the same numbers as Python's
        :mod:`logging` levels, so ``record.levelno`` can be passed as is. Names accepted too.
    name : str
        Logger (node) name.
    text : str
    stamp_ns : int
        [ns]
    """
    if isinstance(level, str):
        if level.lower() not in _LOG_LEVELS:
            raise McapError(f"unknown log level {level!r}")
        lv = _LOG_LEVELS[level.lower()]
    else:
        # Round to the rcl level at or below, so logging.NOTSET-like values stay valid.
        lv = int(np.clip(int(level) // 10 * 10, _Log.DEBUG, _Log.FATAL))
    return _Log(stamp=ros_time(stamp_ns), level=lv, name=name, msg=text, file=file,
                function=function, line=int(line))


__all__ = [
    "MSG_DIRS", "RGBA", "ROS_DISTRO", "TYPESTORE", "CdrTemplate", "JointStateCdr", "RestampedCdr", "Serialized",
    "LineList", "TfCdr", "cube_marker", "line_list_marker", "line_list_marker_array", "line_strip_marker", "log_msg",
    "marker_array", "message_definition",
    "register_msg_files", "ros_time", "serialize_cdr", "string_msg", "tf_message", "transform_stamped",
    "transform_values", "transforms_stamped", "triangle_mesh_marker", "triangle_mesh_marker_array",
]
