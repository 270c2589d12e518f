"""The pinhole camera model with lens distortion, and its ROS ``camera_info`` YAML file.

Image coordinates are pixels with OpenCV's convention (the centre of the top-left pixel is
(0, 0), x right, y down); camera frame x right, y down, z forward [m].

The YAML file is the one ROS ``camera_calibration_parsers`` reads and writes
(``camera_info_manager`` loads it at ``camera_info_url``)::

    image_width: 640
    image_height: 480
    camera_name: camera
    camera_matrix: {rows: 3, cols: 3, data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]}
    distortion_model: plumb_bob
    distortion_coefficients: {rows: 1, cols: 5, data: [k1, k2, p1, p2, k3]}
    rectification_matrix: {rows: 3, cols: 3, data: [identity for a monocular camera]}
    projection_matrix: {rows: 3, cols: 4, data: [fx', 0, cx', 0, 0, fy', cy', 0, 0, 0, 1, 0]}
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from factory.core.errors import VisionError, shown
from factory.core.yamlfile import load_yaml

#: Distortion models we read and write -> number of coefficients (OpenCV order).
DISTORTION_MODELS = {"plumb_bob": 5, "rational_polynomial": 8}


def _frozen(a: Any, shape: tuple[int, ...] | None = None) -> np.ndarray:
    arr = np.array(a, dtype=np.float64)
    if shape is not None:
        arr = arr.reshape(shape)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics and distortion of one camera.

    Attributes
    ----------
    K : (3, 3) float
        Camera matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` [px].
    dist : (k,) float
        Distortion coefficients in OpenCV order (``k1 k2 p1 p2 k3 [k4 k5 k6]``), unitless.
    model : str
        ``"plumb_bob"`` (5 coefficients) or ``"rational_polynomial"`` (8).
    image_size : (int, int)
        Width, height [px].
    rms : float
        RMS reprojection error of the calibration [px]; NaN when unknown.
    name : str
        ``camera_name`` in the YAML file.
    P : (3, 4) float
        Projection matrix of the rectified image [px]; defaults to ``[K | 0]``.
    """

    K: np.ndarray
    dist: np.ndarray
    model: str = "plumb_bob"
    image_size: tuple[int, int] = (640, 480)
    rms: float = float("nan")
    name: str = "camera"
    P: np.ndarray | None = field(default=None)

    def __post_init__(self) -> None:
        k = _frozen(self.K)
        if k.shape != (3, 3) or not np.isfinite(k).all():
            raise VisionError(f"camera matrix must be a finite 3x3 matrix, got shape {k.shape}")
        if k[0, 0] <= 0 or k[1, 1] <= 0:
            raise VisionError(f"focal lengths must be positive, got fx={k[0, 0]}, fy={k[1, 1]}")
        n = DISTORTION_MODELS.get(self.model)
        if n is None:
            raise VisionError(f"distortion model {shown(self.model)} is not one of {', '.join(DISTORTION_MODELS)}")
        d = np.zeros(n)
        given = np.asarray(self.dist, dtype=np.float64).reshape(-1)
        if given.size > n or not np.isfinite(given).all():
            raise VisionError(f"{self.model} takes {n} finite distortion coefficients, got {given.size}")
        d[:given.size] = given
        w, h = (int(v) for v in self.image_size)
        if w <= 0 or h <= 0:
            raise VisionError(f"image size must be positive, got {w}x{h}")
        p = np.hstack([k, np.zeros((3, 1))]) if self.P is None else np.asarray(self.P, dtype=np.float64)
        if p.shape != (3, 4) or not np.isfinite(p).all():
            raise VisionError(f"projection matrix must be a finite 3x4 matrix, got shape {p.shape}")
        object.__setattr__(self, "K", k)
        object.__setattr__(self, "dist", _frozen(d))
        object.__setattr__(self, "image_size", (w, h))
        object.__setattr__(self, "rms", float(self.rms))
        object.__setattr__(self, "P", _frozen(p))

    @property
    def fx(self) -> float:
        """Focal length along x [px]."""
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        """Focal length along y [px]."""
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        """Principal point x [px]."""
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        """Principal point y [px]."""
        return float(self.K[1, 2])

    def project(self, points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
        """Image positions of 3D points.

        Parameters
        ----------
        points : (n, 3) float
            Points in the object frame [m].
        rvec, tvec : (3,) float
            Object-to-camera rotation (Rodrigues vector) [rad] and translation [m].

        Returns
        -------
        (n, 2) float
            Pixel positions [px].
        """
        p = np.asarray(points, dtype=np.float64).reshape(-1, 1, 3)
        if len(p) == 0:
            return np.zeros((0, 2))
        uv, _ = cv2.projectPoints(p, np.asarray(rvec, np.float64).reshape(3, 1),
                                  np.asarray(tvec, np.float64).reshape(3, 1), self.K, self.dist)
        return uv.reshape(-1, 2)

    def project_with_jacobian(self, points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray
                              ) -> tuple[np.ndarray, np.ndarray]:
        """Image positions of 3D points (as :meth:`project`) and how they move with the points.

        Returns ``(n, 2)`` pixel positions [px] and ``(n, 2, 3)`` their derivatives by the points'
        object-frame coordinates [px/m] (OpenCV's derivative by ``tvec`` is the one by the point in the
        camera frame; the object frame's is that times the rotation).
        """
        p = np.asarray(points, dtype=np.float64).reshape(-1, 1, 3)
        if len(p) == 0:
            return np.zeros((0, 2)), np.zeros((0, 2, 3))
        r = np.asarray(rvec, np.float64).reshape(3, 1)
        uv, jac = cv2.projectPoints(p, r, np.asarray(tvec, np.float64).reshape(3, 1), self.K, self.dist)
        by_camera = jac[:, 3:6].reshape(-1, 2, 3)
        return uv.reshape(-1, 2), by_camera @ cv2.Rodrigues(r)[0]

    def rays(self, pixels: np.ndarray) -> np.ndarray:
        """Normalised viewing rays ``(x, y, 1)`` through pixel positions, distortion removed.

        Parameters
        ----------
        pixels : (n, 2) float
            Pixel positions [px].

        Returns
        -------
        (n, 3) float
            Ray directions in the camera frame with z = 1 (unitless).
        """
        uv = np.ascontiguousarray(np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2))
        # OpenCV's default of 5 fixed-point iterations leaves ~0.01 px errors at the image
        # edge with strong distortion; iterate to convergence for exact synthetic images.
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
        if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x spelling
            xy = cv2.undistortPointsIter(uv, self.K, self.dist, None, None, criteria)
        else:
            xy = cv2.undistortPoints(uv, self.K, self.dist, criteria=criteria)
        xy = xy.reshape(-1, 2)
        return np.hstack([xy, np.ones((len(xy), 1))])

    def to_camera_info_yaml(self) -> str:
        """The ROS ``camera_info`` YAML text of this camera (see the module docstring)."""

        def matrix(name: str, a: np.ndarray, rows: int, cols: int) -> str:
            data = ", ".join(repr(float(v)) for v in np.asarray(a).reshape(-1))
            return f"{name}:\n  rows: {rows}\n  cols: {cols}\n  data: [{data}]\n"

        w, h = self.image_size
        return (f"image_width: {w}\nimage_height: {h}\ncamera_name: {_yaml_scalar(self.name)}\n"
                + matrix("camera_matrix", self.K, 3, 3)
                + f"distortion_model: {self.model}\n"
                + matrix("distortion_coefficients", self.dist, 1, len(self.dist))
                + matrix("rectification_matrix", np.eye(3), 3, 3)
                + matrix("projection_matrix", self.P, 3, 4))

    @classmethod
    def from_camera_info_yaml(cls, text: str, *, source: str | Path = "camera_info") -> "CameraModel":
        """Read a ROS ``camera_info`` YAML text.

        Raises
        ------
        VisionError
            (``source`` = the file, the message names the field) Not YAML, a field missing,
            of the wrong shape or type, or an unknown distortion model.
        """
        doc = load_yaml(text, source=source, error=VisionError)
        if not isinstance(doc, dict):
            raise VisionError("not a camera_info YAML mapping", source=source)

        def need(key: str) -> Any:
            if key not in doc:
                raise VisionError(f"field {shown(key)} is missing", source=source)
            return doc[key]

        def integer(key: str) -> int:
            v = need(key)
            if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
                raise VisionError(f"field {shown(key)} must be a positive integer, got {shown(v)}", source=source)
            return v

        def matrix(key: str, rows: int | None, cols: int | None) -> np.ndarray:
            m = need(key)
            if not isinstance(m, dict) or not {"rows", "cols", "data"} <= m.keys():
                raise VisionError(f"field {shown(key)} must have rows, cols and data", source=source)
            r, c, data = m["rows"], m["cols"], m["data"]
            if any(isinstance(n, bool) or not isinstance(n, int) for n in (r, c)):  # True == 1 would pass as a count
                raise VisionError(f"field {shown(key)}: rows and cols must be integers, got {shown(r)}x{shown(c)}",
                                  source=source)
            if (rows is not None and r != rows) or (cols is not None and c != cols):
                raise VisionError(f"field {shown(key)} must be {rows or 'n'}x{cols or 'n'}, got {shown(r)}x{shown(c)}", source=source)
            try:
                a = np.array(data, dtype=np.float64)
            except (TypeError, ValueError):
                raise VisionError(f"field {shown(key)}: data must be numbers", source=source) from None
            if a.shape != (r * c,):
                raise VisionError(f"field {shown(key)}: data must hold rows*cols = {shown(r)}*{shown(c)} numbers", source=source)
            if not np.isfinite(a).all():
                raise VisionError(f"field {shown(key)}: data must be finite", source=source)
            return a.reshape(r, c)

        w, h = integer("image_width"), integer("image_height")
        name = need("camera_name")
        model = need("distortion_model")
        if not isinstance(model, str) or model not in DISTORTION_MODELS:  # a list or mapping is no name
            raise VisionError(f"field 'distortion_model': {shown(model)} is not one of {', '.join(DISTORTION_MODELS)}",
                              source=source)
        k = matrix("camera_matrix", 3, 3)
        d = matrix("distortion_coefficients", 1, None).reshape(-1)
        if d.size not in (DISTORTION_MODELS[model], 0) and not (model == "plumb_bob" and d.size in (4, 5)):
            raise VisionError(f"field 'distortion_coefficients': {model} takes {DISTORTION_MODELS[model]} "
                              f"coefficients, got {d.size}", source=source)
        r = matrix("rectification_matrix", 3, 3)
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-6):
            raise VisionError("field 'rectification_matrix' is not a rotation", source=source)
        p = matrix("projection_matrix", 3, 4)
        if k[0, 0] <= 0 or k[1, 1] <= 0 or not np.allclose(k[2], [0, 0, 1]) or k[1, 0] != 0:
            raise VisionError("field 'camera_matrix' is not [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0",
                              source=source)
        return cls(K=k, dist=d, model=model, image_size=(w, h), name=str(name), P=p)

    @classmethod
    def read(cls, path: str | Path) -> "CameraModel":
        """Read a ROS ``camera_info`` YAML file.

        Raises
        ------
        VisionError
            (``source=path``) The file cannot be read or is not a valid camera_info file.
        """
        try:
            text = Path(path).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as e:
            raise VisionError(f"cannot read camera file: {getattr(e, 'strerror', None) or e}", source=path) from None
        return cls.from_camera_info_yaml(text, source=path)


def _yaml_scalar(text: str) -> str:
    """``text`` as a YAML scalar that reads back as the same string."""
    dumped = yaml.safe_dump(str(text), default_flow_style=True, width=math.inf)
    return dumped.removesuffix("\n...\n").strip()


def binned_camera(camera: CameraModel, n: int) -> CameraModel:
    """The camera in its ``n`` x ``n`` binning mode: a pixel is the mean of ``n`` x ``n`` sensor pixels,
    so focal lengths and the principal point scale by 1/n (pixel centres: (c + 0.5) / n - 0.5) and
    the distortion, a function of the normalised image point, is unchanged."""
    if n == 1:
        return camera
    k = np.array(camera.K, dtype=float)
    k[:2, :3] /= n
    k[:2, 2] += (1.0 / n - 1.0) / 2
    w, h = camera.image_size
    return CameraModel(K=k, dist=np.asarray(camera.dist), model=camera.model, image_size=(w // n, h // n),
                       name=f"{camera.name}_bin{n}")


def bin_image(image: np.ndarray, n: int) -> np.ndarray:
    """Mean of each ``n`` x ``n`` block of a grey picture (uint8), edges that do not fill a block dropped."""
    if n == 1:
        return image
    h, w = (image.shape[0] // n) * n, (image.shape[1] // n) * n
    blocks = image[:h, :w].reshape(h // n, n, w // n, n).astype(np.float64)
    return np.clip(np.rint(blocks.mean(axis=(1, 3))), 0, 255).astype(np.uint8)
