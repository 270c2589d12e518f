"""What a picture shows of a part, before any pose: its ratio to the empty tray and its edges.

:func:`tray_ratio` divides out a smooth model of the empty tray (vignetting, uneven light);
:func:`gradients` gives the smoothed gradients and the strength an edge must beat, and
:func:`find_edges` the nearest sub-pixel gradient peak across each model edge sample.
:mod:`vision.locate` fits poses to them and :mod:`vision.inspect` judges edges with them;
:func:`blob_outline` is a blob's sub-pixel outline, which locate hands to inspection.
"""

from __future__ import annotations

import cv2
import numpy as np
from contourpy import LineType, contour_generator
from scipy.ndimage import map_coordinates


def tray_ratio(grey: np.ndarray) -> tuple[np.ndarray, float]:
    """The picture over a model of the empty tray, and the tray's own spread in that ratio.

    The tray model is a quadratic surface in ``log(grey)`` (vignetting, uneven light) fitted to
    medians of 16 x 16 px cells, re-fitted without the cells it misses by more than 3 robust
    standard deviations (the parts and their shadows). Returns ``(h, w)`` float32 ratio (1 on
    the tray) and the robust standard deviation of the log ratio over the tray cells (unitless).
    """
    h, w = grey.shape
    cell = 16
    hh, ww = h // cell, w // cell
    med = np.median(grey[:hh * cell, :ww * cell].reshape(hh, cell, ww, cell).swapaxes(1, 2).reshape(hh, ww, -1),
                    axis=2)
    vs, us = np.mgrid[0:hh, 0:ww]
    u = ((us + 0.5) * cell / w - 0.5).ravel()
    v = ((vs + 0.5) * cell / h - 0.5).ravel()
    design = np.column_stack([np.ones_like(u), u, v, u * u, u * v, v * v])
    z = np.log(np.maximum(med.ravel(), 1.0))
    keep = np.ones(len(z), bool)
    spread = 0.1
    for _ in range(4):
        coef = np.linalg.lstsq(design[keep], z[keep], rcond=None)[0]
        res = z - design @ coef
        spread = max(1.4826 * float(np.median(np.abs(res[keep] - np.median(res[keep])))), 0.01)
        keep = np.abs(res) < 3 * spread
    vv, uu = np.mgrid[0:h, 0:w]
    uu = (uu + 0.5) / w - 0.5
    vv = (vv + 0.5) / h - 0.5
    model = coef[0] + coef[1] * uu + coef[2] * vv + coef[3] * uu * uu + coef[4] * uu * vv + coef[5] * vv * vv
    ratio = (np.maximum(grey, 0.5) / np.exp(model)).astype(np.float32)
    # Pixel spread: the cells' median hides the tray's fine grain and the sensor noise.
    pixel_spread = 1.4826 * float(np.median(np.abs(np.log(ratio[::4, ::4]))))
    return ratio, max(spread, pixel_spread)


def gradients(grey: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Smoothed image gradients ``gx, gy`` [grey/px] and the gradient magnitude an edge must beat."""
    g = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), 1.0)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8
    mag = np.hypot(gx, gy)
    # Most of the picture is tray: its median gradient is texture and noise.
    return gx, gy, max(4.0 * float(np.median(mag)), 1.0)


def edge_peaks(gx: np.ndarray, gy: np.ndarray, threshold: float, uv: np.ndarray, normal: np.ndarray,
                reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The picture's edges across each model edge sample: ``steps`` (s,) offsets along the normal
    every half pixel within ``reach`` [px], ``resp`` (k, s) the gradient across the normal [grey/px]
    and ``peak`` (k, s) bool, its local maxima above ``threshold``."""
    steps = np.arange(-reach, reach + 1e-9, 0.5)
    q = uv[:, None, :] + steps[None, :, None] * normal[:, None, :]
    coords = [q[..., 1].ravel(), q[..., 0].ravel()]
    gxs = map_coordinates(gx, coords, order=1, mode="nearest").reshape(q.shape[:2])
    gys = map_coordinates(gy, coords, order=1, mode="nearest").reshape(q.shape[:2])
    resp = np.abs(gxs * normal[:, 0:1] + gys * normal[:, 1:2])
    peak = np.zeros_like(resp, bool)
    peak[:, 1:-1] = (resp[:, 1:-1] >= resp[:, :-2]) & (resp[:, 1:-1] > resp[:, 2:]) & (resp[:, 1:-1] > threshold)
    return steps, resp, peak


def peak_offset(steps: np.ndarray, resp: np.ndarray, j: np.ndarray) -> np.ndarray:
    """``(k,)`` sub-pixel offset [px] of the peak at column ``j`` (k,) of each row of ``resp`` (parabola)."""
    jj = np.clip(j, 1, len(steps) - 2)
    rows = np.arange(len(jj))
    r0, r1, r2 = (resp[rows, jj + d] for d in (-1, 0, 1))
    denom = r0 - 2 * r1 + r2
    frac = np.where(np.abs(denom) > 1e-9, 0.5 * (r0 - r2) / np.where(np.abs(denom) > 1e-9, denom, 1), 0.0)
    return steps[jj] + 0.5 * np.clip(frac, -1, 1)


def find_edges(gx: np.ndarray, gy: np.ndarray, threshold: float, uv: np.ndarray, normal: np.ndarray,
                reach: float) -> np.ndarray:
    """``(k,)`` signed offset [px] along each normal of the nearest edge within ``reach``, NaN where none."""
    steps, resp, peak = edge_peaks(gx, gy, threshold, uv, normal, reach)
    # The nearest strong peak: a shadow's or a texture's edge further out must not pull the fit.
    dist = np.where(peak, np.abs(steps)[None, :], np.inf)
    j = np.argmin(dist, axis=1)
    found = np.isfinite(dist[np.arange(len(j)), j])
    return np.where(found, peak_offset(steps, resp, j), np.nan)


def blob_outline(log_ratio: np.ndarray, mask: np.ndarray, level: float) -> np.ndarray:
    """The outline of a blob (``mask`` (h, w) uint8) for inspection [px]: the iso-line of ``log_ratio`` a
    quarter of the way from the tray to the part's typical brightness (as far from the sensor noise as
    from dim side faces), ``level`` at least; (0, 2) when there is none."""
    inside = log_ratio[(mask > 0) & (np.abs(log_ratio) > level)]
    typical = float(np.median(inside)) if len(inside) else level
    iso = np.sign(typical) * max(abs(typical) / 4, level)
    outline = _subpixel_outline(log_ratio, mask, iso, typical > 0)
    return outline if outline is not None else np.zeros((0, 2))


def _subpixel_outline(grey: np.ndarray, mask: np.ndarray, level: float, bright: bool) -> np.ndarray | None:
    """The longest closed iso-line at ``level`` around one blob [px], or None."""
    x, y, w, h = cv2.boundingRect(mask)
    x0, y0 = max(x - 3, 0), max(y - 3, 0)
    x1, y1 = min(x + w + 3, grey.shape[1]), min(y + h + 3, grey.shape[0])
    roi = grey[y0:y1, x0:x1].astype(np.float64)
    # Keep other blobs in the window out: outside this blob's (dilated) mask, the tray level.
    keep = cv2.dilate(mask[y0:y1, x0:x1], np.ones((5, 5), np.uint8)) > 0
    tray_value = level - 1e3 if bright else level + 1e3
    roi = np.where(keep, roi, tray_value)
    lines = contour_generator(z=roi, line_type=LineType.Separate).lines(level)
    closed = [ln for ln in lines if len(ln) > 8 and np.allclose(ln[0], ln[-1])]
    if not closed:
        return None
    best = max(closed, key=len)
    return best[:-1] + (x0, y0)
