"""Report pictures: camera calibration (corner coverage, magnified residuals, per-view errors)
and hand-eye calibration (per-view pose residuals).

Drawn with OpenCV on a white canvas (no plotting library):

* left: the image frame with every used corner as a dot coloured by view and its
  residual (observed minus reprojected) as a line magnified so the largest is 4 % of the
  image width;
* right: one bar per view of its RMS reprojection error [px], outliers in red, with the
  overall RMS as a horizontal line.
"""

from __future__ import annotations

import cv2
import numpy as np

from factory.core.errors import VisionError
from vision.calibrate import CalibrationResult
from vision.handeye import FRAMES, HandEyeResult

_PANEL_W = 640
_BAR_W = 420
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def _view_colours(n: int) -> np.ndarray:
    """``(n, 3) uint8`` distinct BGR colours."""
    hues = (np.arange(n) * 180 // max(n, 1)).astype(np.uint8)
    hsv = np.stack([hues, np.full(n, 220, np.uint8), np.full(n, 200, np.uint8)], axis=1).reshape(-1, 1, 3)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR).reshape(-1, 3)


def report_image(result: CalibrationResult) -> np.ndarray:
    """The report picture of a calibration.

    Returns
    -------
    (h, w, 3) uint8
        BGR image, about 1100 px wide.
    """
    w, h = result.camera.image_size
    scale = _PANEL_W / w
    panel_h = int(round(h * scale))
    height = max(panel_h, 360) + 70
    canvas = np.full((height, _PANEL_W + _BAR_W + 60, 3), 255, np.uint8)
    top = 40
    cv2.rectangle(canvas, (10, top), (10 + _PANEL_W, top + panel_h), (0, 0, 0), 1)
    residuals = result.residuals
    biggest = max((float(np.linalg.norm(r, axis=1).max()) for r in residuals if len(r)), default=0.0)
    magnify = 0.04 * w / biggest if biggest > 0 else 1.0
    colours = _view_colours(len(residuals))
    for det, res, col in zip(result.detections, residuals, colours):
        c = tuple(int(v) for v in col)
        p = det.image_points * scale + (10, top)
        q = (det.image_points + magnify * res) * scale + (10, top)
        for a, b in zip(np.rint(p).astype(int), np.rint(q).astype(int)):
            cv2.line(canvas, tuple(a.tolist()), tuple(b.tolist()), c, 1, cv2.LINE_AA)
            cv2.circle(canvas, tuple(a.tolist()), 2, c, -1, cv2.LINE_AA)
    cv2.putText(canvas, f"corners and residuals x{magnify:.0f}  ({w}x{h} px)", (10, 28), _FONT, 0.55,
                (0, 0, 0), 1, cv2.LINE_AA)

    # Per-view RMS bars.
    _bar_panel(canvas, (_PANEL_W + 50, top, _BAR_W, height - top - 60), result.views, result.per_view_rms,
               overall=result.camera.rms, outliers=set(result.outliers),
               title="per-view RMS [px]; overall {overall:.3f} px (green), max {top:.3f}")
    note = f"{len(result.views)} views used"
    if result.outliers:
        note += f"; outliers{' (rejected)' if result.rejected else ''}: {', '.join(result.outliers)}"
    if result.without_board:
        note += f"; no board: {len(result.without_board)}"
    cv2.putText(canvas, note, (10, height - 14), _FONT, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return canvas


def _bar_panel(canvas: np.ndarray, box: tuple[int, int, int, int], names: list[str], values: np.ndarray, *,
               overall: float, title: str, outliers: set[str] = frozenset()) -> None:
    """Draw one bar per view into ``canvas`` (in place), with ``overall`` as a green line.

    ``box`` is (x, y, width, height) [px] of the plot area; labels go below it and ``title``
    (formatted with ``overall`` and ``top``, the largest value) above. Views in ``outliers``
    are red.
    """
    x0, y0, width, bar_h = box
    errors = np.asarray(values, dtype=np.float64)
    top_val = max(float(errors.max(initial=0.0)), overall) * 1.15 or 1.0
    step = width / max(len(errors), 1)
    cv2.line(canvas, (x0, y0 + bar_h), (x0 + width, y0 + bar_h), (0, 0, 0), 1)
    cv2.line(canvas, (x0, y0), (x0, y0 + bar_h), (0, 0, 0), 1)
    for i, (name, e) in enumerate(zip(names, errors)):
        bx = int(x0 + i * step + 0.15 * step)
        by = int(y0 + bar_h * (1 - e / top_val))
        colour = (40, 40, 220) if name in outliers else (180, 120, 40)
        cv2.rectangle(canvas, (bx, by), (int(bx + 0.7 * step), y0 + bar_h), colour, -1)
        stem = name.rsplit(".", 1)[0]
        label = stem if len(stem) <= 10 else stem[:9] + "~"
        org = (bx, y0 + bar_h + 12 + 11 * (i % 2))  # alternate rows so labels do not overlap
        cv2.putText(canvas, label, org, _FONT, 0.3, (0, 0, 0), 1, cv2.LINE_AA)
    ry = int(y0 + bar_h * (1 - overall / top_val))
    cv2.line(canvas, (x0, ry), (x0 + width, ry), (0, 160, 0), 1, cv2.LINE_AA)
    cv2.putText(canvas, title.format(overall=overall, top=top_val / 1.15), (x0, y0 - 12), _FONT, 0.5, (0, 0, 0), 1,
                cv2.LINE_AA)


def handeye_report_image(result: HandEyeResult, views: list[str], reprojection_px: list[float]) -> np.ndarray:
    """The report picture of a hand-eye calibration: per view, how far the board pose it implies
    lies from the fitted one (position [mm], angle [deg]) and the corners' reprojection error [px].

    Parameters
    ----------
    result : HandEyeResult
    views : list of str
        Image names of the views used, in the order of the residuals.
    reprojection_px : list of float
        RMS reprojection error of each view's corners under its solvePnP pose [px].

    Returns
    -------
    (h, w, 3) uint8
        BGR image, three bar panels side by side.
    """
    n = len(views)
    if not (n == len(result.translation_residuals) == len(result.rotation_residuals) == len(reprojection_px)):
        raise VisionError(f"{n} views but {len(result.translation_residuals)} residuals and "
                          f"{len(reprojection_px)} reprojection errors")
    panel_w, top, plot_h = 360, 60, 320
    canvas = np.full((top + plot_h + 50, 3 * (panel_w + 40) + 20, 3), 255, np.uint8)
    rms = lambda v: float(np.sqrt(np.mean(np.square(v)))) if len(v) else 0.0  # noqa: E731
    panels = [
        (result.translation_residuals * 1e3, "board position [mm]: RMS {overall:.2f} (green), max {top:.2f}"),
        (np.degrees(result.rotation_residuals), "board angle [deg]: RMS {overall:.3f} (green), max {top:.3f}"),
        (np.asarray(reprojection_px, dtype=np.float64), "corner reprojection [px]: RMS {overall:.3f}, max {top:.3f}"),
    ]
    for k, (values, title) in enumerate(panels):
        _bar_panel(canvas, (30 + k * (panel_w + 40), top, panel_w, plot_h), views, values, overall=rms(values),
                   title=title)
    parent, child = FRAMES[result.mode]
    xyz = result.transform[:3, 3]
    cv2.putText(canvas, f"{result.mode}: T_{parent}_{child} xyz " + " ".join(f"{v:.4f}" for v in xyz)
                + f" m; {n} views; condition {result.condition:.2f}", (30, 24), _FONT, 0.55, (0, 0, 0), 1,
                cv2.LINE_AA)
    return canvas


def bgr_png_bytes(image: np.ndarray) -> bytes:
    """PNG file bytes of a uint8 OpenCV image (grey or BGR); RGB pictures go through factory.pictures."""
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise VisionError("PNG encoding failed")
    return buf.tobytes()
