"""The calibration report picture: corner coverage, magnified residuals, per-view errors.

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

from factory.errors import VisionError
from vision.calibrate import CalibrationResult

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
    x0, y0 = _PANEL_W + 50, top
    bar_h = height - top - 60
    errors = np.asarray(result.per_view_rms, dtype=np.float64)
    rms = result.camera.rms
    top_val = max(float(errors.max(initial=0.0)), rms) * 1.15 or 1.0
    n = len(errors)
    step = _BAR_W / max(n, 1)
    cv2.line(canvas, (x0, y0 + bar_h), (x0 + _BAR_W, y0 + bar_h), (0, 0, 0), 1)
    cv2.line(canvas, (x0, y0), (x0, y0 + bar_h), (0, 0, 0), 1)
    outliers = set(result.outliers)
    for i, (name, e) in enumerate(zip(result.views, errors)):
        bx = int(x0 + i * step + 0.15 * step)
        by = int(y0 + bar_h * (1 - e / top_val))
        colour = (40, 40, 220) if name in outliers else (180, 120, 40)
        cv2.rectangle(canvas, (bx, by), (int(bx + 0.7 * step), y0 + bar_h), colour, -1)
        stem = name.rsplit(".", 1)[0]
        label = stem if len(stem) <= 10 else stem[:9] + "~"
        org = (bx, y0 + bar_h + 12 + 11 * (i % 2))  # alternate rows so labels do not overlap
        cv2.putText(canvas, label, org, _FONT, 0.3, (0, 0, 0), 1, cv2.LINE_AA)
    ry = int(y0 + bar_h * (1 - rms / top_val))
    cv2.line(canvas, (x0, ry), (x0 + _BAR_W, ry), (0, 160, 0), 1, cv2.LINE_AA)
    cv2.putText(canvas, f"per-view RMS [px]; overall {rms:.3f} px (green), max {top_val / 1.15:.3f}",
                (x0, 28), _FONT, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    note = f"{len(result.views)} views used"
    if result.outliers:
        note += f"; outliers{' (rejected)' if result.rejected else ''}: {', '.join(result.outliers)}"
    if result.without_board:
        note += f"; no board: {len(result.without_board)}"
    cv2.putText(canvas, note, (10, height - 14), _FONT, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return canvas


def bgr_png_bytes(image: np.ndarray) -> bytes:
    """PNG file bytes of a uint8 OpenCV image (grey or BGR); RGB pictures go through factory.pictures."""
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise VisionError("PNG encoding failed")
    return buf.tobytes()
