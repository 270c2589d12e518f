"""Camera pictures and camera models as ROS 2 messages, for every stage that logs a camera."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from factory.core.errors import McapError
from factory.rosmsgs import TYPESTORE, ros_time
from vision.camera import CameraModel
from vision.report import bgr_png_bytes

#: Default camera frame id in the MCAP logs.
FRAME = "camera"

_T = TYPESTORE.types


def header(stamp_ns: int, frame_id: str = FRAME) -> Any:
    """``std_msgs/Header`` at ``stamp_ns`` [ns] in ``frame_id``."""
    return _T["std_msgs/msg/Header"](stamp=ros_time(stamp_ns), frame_id=frame_id)


def compressed_image_msg(data: bytes, name: str, image: np.ndarray, stamp_ns: int, frame_id: str = FRAME) -> Any:
    """``sensor_msgs/CompressedImage``: the file's own JPEG/PNG bytes, or PNG re-encoded."""
    suffix = Path(name).suffix.lower()
    if suffix in (".jpg", ".jpeg"):
        fmt = "jpeg"
    elif suffix == ".png":
        fmt = "png"
    else:
        fmt, data = "png", bgr_png_bytes(image)
    return _T["sensor_msgs/msg/CompressedImage"](header=header(stamp_ns, frame_id), format=fmt,
                                                 data=np.frombuffer(data, np.uint8).copy())


def camera_info_msg(cam: CameraModel, stamp_ns: int, frame_id: str = FRAME) -> Any:
    """``sensor_msgs/CameraInfo`` of a camera."""
    roi = _T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return _T["sensor_msgs/msg/CameraInfo"](
        header=header(stamp_ns, frame_id), height=cam.image_size[1], width=cam.image_size[0],
        distortion_model=cam.model, d=np.array(cam.dist, dtype=np.float64), k=cam.K.reshape(-1).copy(),
        r=np.eye(3).reshape(-1), p=cam.P.reshape(-1).copy(), binning_x=0, binning_y=0, roi=roi)


def image_msg(image: np.ndarray, stamp_ns: int, frame_id: str = FRAME) -> Any:
    """``sensor_msgs/Image`` of a picture: ``image`` (h, w) uint8 as ``mono8``, (h, w, 3) uint8 BGR as
    ``bgr8`` (OpenCV's order, which ROS's cv_bridge reads as is), rows packed (``step`` = w * channels)."""
    a = np.ascontiguousarray(image)
    if a.dtype != np.uint8 or not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3)):
        raise McapError(f"an image must be (h, w) or (h, w, 3) uint8, got {a.shape} {a.dtype}")
    channels = 1 if a.ndim == 2 else 3
    return _T["sensor_msgs/msg/Image"](header=header(stamp_ns, frame_id), height=a.shape[0], width=a.shape[1],
                                       encoding="mono8" if channels == 1 else "bgr8", is_bigendian=0,
                                       step=a.shape[1] * channels, data=a.reshape(-1).copy())
