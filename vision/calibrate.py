"""Camera calibration from views of a planar board: corner detection and intrinsics.

Chessboard corners come from :func:`cv2.findChessboardCorners` refined by
:func:`cv2.cornerSubPix`, with a search window sized from the corner spacing of the view
(a fixed window larger than about a third of the spacing reaches the neighbouring corners
and pulls the estimate toward them), and :func:`cv2.findChessboardCornersSB` where the
classic detector finds nothing. ChArUco corners come from :class:`cv2.aruco.CharucoDetector`
and the board's ``matchImagePoints``.

Calibration is :func:`cv2.calibrateCameraExtended` (flags 0 for ``plumb_bob``,
``CALIB_RATIONAL_MODEL`` for ``rational_polynomial``), which also gives per-view RMS
reprojection errors and the standard deviations of the intrinsics.

Outlier rule (:func:`outlier_views`): a view is an outlier when its RMS reprojection error
exceeds ``median + 3 * 1.4826 * MAD`` of the per-view RMS values (a robust 3-sigma bound)
**and** exceeds twice the median. The second condition keeps uniformly good sets (tiny MAD)
from flagging views that are only marginally worse than the rest.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from factory.core.errors import CalibrationError
from vision.board import BoardSpec
from vision.camera import CameraModel

log = logging.getLogger(__name__)

#: Fewest views with the board found that a calibration accepts.
MIN_VIEWS = 3
#: Fewest ChArUco corners a view must show to be used (a homography needs 4, and
#: 6 keeps nearly collinear partial views out).
MIN_CHARUCO_CORNERS = 6

#: cornerSubPix half-window = this x the smallest spacing of neighbouring corners [px/px].
#: The whole window (2 w + 1) is then about a third of the spacing, so it never reaches
#: the next corner. On OpenCV's left/ views factors 0.16-0.20 reproduce OpenCV's published
#: calibration (the distortion tolerance is the tight one); 0.4 gives RMS 0.21 px and
#: drifts k2/k3 out of it.
SUBPIX_WINDOW_FACTOR = 0.18
#: Bounds of the cornerSubPix half-window [px].
SUBPIX_WINDOW_RANGE = (2, 11)

_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
_CALIB_FLAGS = {"plumb_bob": 0, "rational_polynomial": cv2.CALIB_RATIONAL_MODEL}


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class Detection:
    """The board corners found in one image.

    Attributes
    ----------
    name : str
        The image's name (file name), for reports.
    image_size : (int, int)
        Width, height [px].
    image_points : (n, 2) float
        Corner positions in the image [px].
    object_points : (n, 3) float
        The same corners in the board frame [m] (z = 0).
    ids : (n,) int
        Corner ids (index into :attr:`BoardSpec.object_points`).
    method : str
        ``"classic"``, ``"sb"`` or ``"charuco"``.
    subpix_window : int
        cornerSubPix half-window used [px] (0 when not refined by cornerSubPix).
    """

    name: str
    image_size: tuple[int, int]
    image_points: np.ndarray
    object_points: np.ndarray
    ids: np.ndarray
    method: str = "classic"
    subpix_window: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "image_points", _frozen(np.asarray(self.image_points).reshape(-1, 2)))
        object.__setattr__(self, "object_points", _frozen(np.asarray(self.object_points).reshape(-1, 3)))
        ids = np.array(self.ids, dtype=np.int64).reshape(-1)
        ids.setflags(write=False)
        object.__setattr__(self, "ids", ids)


def _grey(image: np.ndarray, name: str) -> np.ndarray:
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or min(img.shape[:2]) < 8:
        raise CalibrationError(f"not an 8-bit image of at least 8x8 pixels (shape {img.shape}, {img.dtype})",
                               source=name)
    if img.ndim == 3:
        return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    return img


def subpix_half_window(corners: np.ndarray, cols: int, rows: int) -> int:
    """cornerSubPix half-window for one view of a chessboard [px].

    Parameters
    ----------
    corners : (cols * rows, 2) float
        Corners in row-major board order [px].

    Returns
    -------
    int
        ``SUBPIX_WINDOW_FACTOR`` x the smallest distance between neighbouring corners,
        rounded, clamped to ``SUBPIX_WINDOW_RANGE``.
    """
    grid = np.asarray(corners, dtype=np.float64).reshape(rows, cols, 2)
    spacing = min(np.linalg.norm(np.diff(grid, axis=0), axis=2).min(),
                  np.linalg.norm(np.diff(grid, axis=1), axis=2).min())
    lo, hi = SUBPIX_WINDOW_RANGE
    return int(np.clip(round(SUBPIX_WINDOW_FACTOR * spacing), lo, hi))


def detect(image: np.ndarray, board: BoardSpec, name: str, *, subpix_window: int | None = None) -> Detection:
    """Find the board's corners in one image.

    Parameters
    ----------
    image : (h, w) or (h, w, 3) uint8
        Grey or BGR image.
    board : BoardSpec
    name : str
        The image's name, used in the result and in errors.
    subpix_window : int, optional
        Fixed cornerSubPix half-window [px] instead of the one sized from the corner spacing
        (chessboards only; e.g. 5 reproduces OpenCV's regression test).

    Raises
    ------
    CalibrationError
        (``source=name``) Not an 8-bit image, or the board is not found in it.
    """
    grey = _grey(image, name)
    if subpix_window is not None and subpix_window < 1:
        raise CalibrationError(f"cornerSubPix half-window must be >= 1 px, got {subpix_window}", source=name)
    size = (grey.shape[1], grey.shape[0])
    if board.kind == "charuco":
        return _detect_charuco(grey, board, name, size)
    pattern = (board.cols, board.rows)
    found, corners = cv2.findChessboardCorners(
        grey, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if found:
        corners = corners.reshape(-1, 1, 2).astype(np.float32)
        win = subpix_window or subpix_half_window(corners.reshape(-1, 2), board.cols, board.rows)
        corners = cv2.cornerSubPix(grey, corners, (win, win), (-1, -1), _SUBPIX_CRITERIA)
        method = "classic"
    else:
        # The sector-based detector is more robust to blur and noise and is already sub-pixel.
        found, corners = cv2.findChessboardCornersSB(grey, pattern, flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not found:
            raise CalibrationError(f"no {board.cols}x{board.rows} chessboard (inner corners) found", source=name)
        win, method = 0, "sb"
    ids = np.arange(board.corner_count)
    return Detection(name, size, corners.reshape(-1, 2), board.object_points, ids, method, win)


def _detect_charuco(grey: np.ndarray, board: BoardSpec, name: str, size: tuple[int, int]) -> Detection:
    cv_board = board.charuco_board()
    detector = cv2.aruco.CharucoDetector(cv_board)
    corners, ids, _, marker_ids = detector.detectBoard(grey)
    n = 0 if ids is None else len(ids)
    if n < MIN_CHARUCO_CORNERS:
        markers = 0 if marker_ids is None else len(marker_ids)
        raise CalibrationError(f"only {n} ChArUco corners ({markers} markers) of {board} found; "
                               f"need {MIN_CHARUCO_CORNERS}", source=name)
    ids = ids.reshape(-1)
    win = _charuco_half_window(corners.reshape(-1, 2), ids, board)
    # CharucoDetector's own refinement leaves 0.2-0.3 px errors on synthetic views; a
    # window kept inside the white gap between the corner and the markers does better.
    corners = cv2.cornerSubPix(grey, corners.reshape(-1, 1, 2).astype(np.float32), (win, win), (-1, -1),
                               _SUBPIX_CRITERIA)
    obj, img = cv_board.matchImagePoints(corners, ids.reshape(-1, 1))
    return Detection(name, size, img.reshape(-1, 2), obj.reshape(-1, 3), ids, "charuco", win)


def _charuco_half_window(corners: np.ndarray, ids: np.ndarray, board: BoardSpec) -> int:
    """cornerSubPix half-window for ChArUco corners [px]: as for chessboards, but also kept
    inside the white gap between a corner and its markers (0.8 of it)."""
    per_row = board.cols - 1
    where = {int(i): k for k, i in enumerate(ids)}
    spacing = np.inf
    for i, k in where.items():
        right = i + 1 if (i + 1) % per_row else -1
        for nb in (right, i + per_row):
            if nb in where:
                spacing = min(spacing, float(np.linalg.norm(corners[k] - corners[where[nb]])))
    if not np.isfinite(spacing):
        spacing = 10.0  # no two neighbouring corners seen: a small, safe window
    gap = (board.square - board.marker) / (2.0 * board.square)
    lo, hi = SUBPIX_WINDOW_RANGE
    return int(np.clip(round(min(SUBPIX_WINDOW_FACTOR, 0.8 * gap) * spacing), lo, hi))


@dataclass(frozen=True)
class CalibrationResult:
    """A calibrated camera and how well its views agree with it.

    Attributes
    ----------
    camera : CameraModel
        Intrinsics, distortion and overall RMS reprojection error [px].
    views : tuple of str
        Names of the views used, in order.
    per_view_rms : (m,) float
        RMS reprojection error of each used view [px].
    std_K : (4,) float
        Standard deviations of fx, fy, cx, cy [px].
    std_dist : (k,) float
        Standard deviations of the distortion coefficients (unitless).
    rvecs, tvecs : (m, 3) float
        Board-to-camera rotation (Rodrigues) [rad] and translation [m] of each used view.
    residuals : tuple of (n_i, 2) float
        Observed minus reprojected corner positions per used view [px].
    detections : tuple of Detection
        The detections of the used views.
    outliers : tuple of str
        Views that break the outlier rule (see the module docstring); when ``rejected``
        they were removed before this calibration.
    rejected : bool
        Whether ``outliers`` were left out of this calibration.
    without_board : tuple of str
        Views in which the board was not found (never used).
    """

    camera: CameraModel
    views: tuple[str, ...]
    per_view_rms: np.ndarray
    std_K: np.ndarray
    std_dist: np.ndarray
    rvecs: np.ndarray
    tvecs: np.ndarray
    residuals: tuple[np.ndarray, ...]
    detections: tuple[Detection, ...]
    outliers: tuple[str, ...] = ()
    rejected: bool = False
    without_board: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        """JSON-ready summary (pixels, metres, radians)."""
        cam = self.camera
        return {
            "rms_px": cam.rms,
            "image_size": list(cam.image_size),
            "distortion_model": cam.model,
            "fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy,
            "dist": cam.dist.tolist(),
            "std": {"fx": float(self.std_K[0]), "fy": float(self.std_K[1]), "cx": float(self.std_K[2]),
                    "cy": float(self.std_K[3]), "dist": self.std_dist.tolist()},
            "views": [{"name": n, "rms_px": float(e), "corners": len(d.ids), "method": d.method}
                      for n, e, d in zip(self.views, self.per_view_rms, self.detections)],
            "outliers": list(self.outliers),
            "rejected": self.rejected,
            "without_board": list(self.without_board),
        }


def outlier_views(per_view_rms: np.ndarray) -> np.ndarray:
    """Which views break the outlier rule (module docstring): ``(m,) bool``.

    Parameters
    ----------
    per_view_rms : (m,) float
        RMS reprojection error per view [px].
    """
    e = np.asarray(per_view_rms, dtype=np.float64).reshape(-1)
    if e.size < MIN_VIEWS:
        return np.zeros(e.size, dtype=bool)
    med = np.median(e)
    mad = np.median(np.abs(e - med))
    return (e > med + 3.0 * 1.4826 * mad) & (e > 2.0 * med)


def _calibrate_once(detections: Sequence[Detection], model: str, image_size: tuple[int, int]):
    obj = [d.object_points.astype(np.float32).reshape(-1, 1, 3) for d in detections]
    img = [d.image_points.astype(np.float32).reshape(-1, 1, 2) for d in detections]
    try:
        rms, k, dist, rvecs, tvecs, std_in, _, per_view = cv2.calibrateCameraExtended(
            obj, img, image_size, None, None, flags=_CALIB_FLAGS[model])
    except cv2.error as e:
        raise CalibrationError(f"OpenCV calibration failed: {str(e).strip().splitlines()[-1]}") from None
    return rms, k, dist.reshape(-1), np.array(rvecs).reshape(-1, 3), np.array(tvecs).reshape(-1, 3), \
        np.asarray(std_in).reshape(-1), np.asarray(per_view).reshape(-1)


def calibrate(detections: Sequence[Detection], model: str = "plumb_bob", image_size: tuple[int, int] | None = None,
              *, reject: bool = False, without_board: Sequence[str] = (), name: str = "camera",
              progress: Callable[[int, int], None] | None = None) -> CalibrationResult:
    """Intrinsics and distortion from detected board views.

    Parameters
    ----------
    detections : sequence of Detection
        One per view with the board found; all of the same image size.
    model : str
        ``"plumb_bob"`` (k1 k2 p1 p2 k3) or ``"rational_polynomial"`` (adds k4 k5 k6).
    image_size : (int, int), optional
        Width, height [px]; defaults to the detections'.
    reject : bool
        Recalibrate without the views that break the outlier rule (when at least
        :data:`MIN_VIEWS` remain).
    without_board : sequence of str
        Names of views in which no board was found, carried into the result.
    name : str
        Camera name for the model.
    progress : callable, optional
        ``progress(done, total)`` over the (one or two) calibration passes.

    Raises
    ------
    CalibrationError
        Fewer than :data:`MIN_VIEWS` views, mixed image sizes, an unknown model, or OpenCV fails.
    """
    if model not in _CALIB_FLAGS:
        raise CalibrationError(f"unknown distortion model {model!r}; use {' or '.join(_CALIB_FLAGS)}",
                               source="--model")
    dets = list(detections)
    if len(dets) < MIN_VIEWS:
        raise CalibrationError(f"board found in {len(dets)} view(s); calibration needs at least {MIN_VIEWS}")
    size = tuple(int(v) for v in (image_size or dets[0].image_size))
    for d in dets:
        if tuple(d.image_size) != size:
            raise CalibrationError(f"image is {d.image_size[0]}x{d.image_size[1]}, the others "
                                   f"{size[0]}x{size[1]}", source=d.name)
    passes = 2 if reject else 1
    rms, k, dist, rvecs, tvecs, std_in, per_view = _calibrate_once(dets, model, size)
    if progress:
        progress(1, passes)
    flagged = outlier_views(per_view)
    outliers = tuple(d.name for d, f in zip(dets, flagged) if f)
    rejected = False
    if reject and outliers and len(dets) - len(outliers) >= MIN_VIEWS:
        log.info("recalibrating without %d outlier view(s): %s", len(outliers), ", ".join(outliers))
        dets = [d for d, f in zip(dets, flagged) if not f]
        rms, k, dist, rvecs, tvecs, std_in, per_view = _calibrate_once(dets, model, size)
        rejected = True
    elif reject and outliers:
        log.warning("not rejecting %d outlier view(s): fewer than %d views would remain", len(outliers), MIN_VIEWS)
    if progress:
        progress(passes, passes)
    n_dist = 5 if model == "plumb_bob" else 8
    dist = dist[:n_dist]
    p, _ = cv2.getOptimalNewCameraMatrix(k, dist, size, 0.0)  # alpha 0, as ROS camera_calibration
    camera = CameraModel(K=k, dist=dist, model=model, image_size=size, rms=rms, name=name,
                         P=np.hstack([p, np.zeros((3, 1))]))
    residuals = tuple(
        _frozen(d.image_points - camera.project(d.object_points, r, t)) for d, r, t in zip(dets, rvecs, tvecs))
    return CalibrationResult(
        camera=camera, views=tuple(d.name for d in dets), per_view_rms=_frozen(per_view),
        std_K=_frozen(std_in[:4]), std_dist=_frozen(std_in[4:4 + n_dist]), rvecs=_frozen(rvecs),
        tvecs=_frozen(tvecs), residuals=residuals, detections=tuple(dets), outliers=outliers,
        rejected=rejected, without_board=tuple(without_board))
