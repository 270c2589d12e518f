"""The coarse search of :func:`vision.locate.locate_parts`: where in a blob, and turned how, the part's
edges lie closest on the picture's edges, to within a pixel and a degree, so that the edge fit
starts there.

1. :func:`chamfer_starts`: the model's visible edges against the distance map of the picture's
   edges, every 10 deg of yaw, at every pixel of the blob (one correlation per yaw);
2. :func:`refine_start`: around each of the best few, every degree and pixel against the distance
   to picture edges of the same direction (:func:`oriented_distances`), thinned to their ridge
   (:func:`thin_edges`).

Where the picture is clipped white all round (:func:`hidden_by_glare`) it cannot show an edge: a model edge inside
the outline that falls there is unknown, not missed, in both (as in the judgement, ``vision.locate._hidden``). Counted
missing, a glare stepped wall's steps and thin wall, all hidden in its clipped top, ranked first a start slid 15 mm
along the part, where the thin wall's two edges lay on one end of the picture's outline.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import cv2
import numpy as np

from vision.camera import CameraModel


class EdgeModel(Protocol):
    """What the search needs of :class:`vision.mesh_edges.MeshEdges`: the camera and the tray, and the
    model's visible edge samples at a pose (x, y [m], yaw [rad]) and where they fall in the image."""

    camera: CameraModel
    tray_z: float
    rvec: np.ndarray
    tvec: np.ndarray

    def visible(self, p: np.ndarray) -> np.ndarray: ...

    @property
    def points(self) -> np.ndarray: ...

    @property
    def outer(self) -> np.ndarray: ...

    def world(self, p: np.ndarray, points: np.ndarray) -> np.ndarray: ...

    def project(self, p: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

#: Most edge samples a round of the edge fit uses (evenly thinned; the final judgement uses all).
FIT_SAMPLES = 400
#: A pixel is hidden by glare when the picture is clipped within this of it every way [px]: an edge there would
#: have a clipped side at 1.5 px either way, as the judgement asks (``vision.locate._hidden``), rounded up.
HIDDEN_REACH_PX = 2


def hidden_by_glare(saturated: np.ndarray) -> np.ndarray:
    """``(h, w)`` bool: where the picture is clipped (``saturated`` (h, w) uint8, 1 where clipped) within
    :data:`HIDDEN_REACH_PX` of a pixel every way, so it cannot show an edge there."""
    reach = 2 * HIDDEN_REACH_PX + 1
    return cv2.erode(saturated.astype(np.uint8), np.ones((reach, reach), np.uint8), borderValue=0) > 0


def chamfer_starts(model: EdgeModel, edges: np.ndarray, inside: np.ndarray, box: tuple[int, int, int, int],
                    centre: np.ndarray, ground: Callable[[np.ndarray], np.ndarray], maps: np.ndarray,
                    yaw_steps: int = 36, keep: int = 3, spare: int = 0, hidden: np.ndarray | None = None
                    ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The best few (x, y, yaw) of a coarse search: model edges against the picture's edge distance map.

    ``box`` (x0, y0, x1, y1) [px] is the window searched (only where ``inside`` (h, w) is set),
    ``centre`` a pose (x, y) [m] inside it where the model's image is drawn once per yaw and
    shifted (a mean distance map value per shift, by ``cv2.filter2D``), ``ground`` maps pixels to
    tray (x, y) [m]. Edge distances are capped at 6 px, so missing edges cost a bounded amount.
    Each start is then brought within a pixel and a degree on the oriented distances ``maps``
    (:func:`refine_start`), best first. Returns those ``keep`` starts and the next ``spare`` distinct ones
    of the coarse search as they are (:func:`refined_starts` brings them in where they are wanted: a
    low light's shadow wins the first few, and refining them always cost every picture). ``hidden`` (h, w) bool
    (:func:`hidden_by_glare`): where a model edge inside the outline is unknown, at no distance, here and in the
    refinement.
    """
    x0, y0, x1, y1 = box
    dist = cv2.distanceTransform((edges == 0).astype(np.uint8), cv2.DIST_L2, 3)
    dist = np.minimum(dist, 6.0).astype(np.float32)
    hidden = hidden if hidden is not None and hidden.any() else None
    # The edges inside the outline read a map on which glare's hidden pixels are no distance away.
    maps_read = [dist] if hidden is None else [dist, np.where(hidden, np.float32(0.0), dist)]
    h, w = dist.shape
    ref = model.camera.project(np.array([[centre[0], centre[1], model.tray_z]]), model.rvec, model.tvec)[0]
    results = []
    pads: dict[int, list[np.ndarray]] = {}
    for yaw in np.arange(yaw_steps) * 2 * np.pi / yaw_steps:
        p = np.array([centre[0], centre[1], yaw])
        idx = model.visible(p)
        if len(idx) == 0:
            continue
        # Where the samples fall is all the correlation needs (their normals are not).
        uv = model.camera.project(model.world(p, model.points[idx]), model.rvec, model.tvec)
        off = np.rint(uv - ref).astype(int)
        lo, hi = off.min(axis=0), off.max(axis=0)
        # The window's scores need the distance map from (x0, y0) + lo to (x1, y1) + hi.
        rx0, ry0 = x0 + lo[0], y0 + lo[1]
        # padded by the kernel's reach at least (a fine camera's kernels span more than 200 px)
        m = int(max(200, np.abs(lo).max(), np.abs(hi).max()) + 1)
        if m not in pads:
            pads[m] = [cv2.copyMakeBorder(d, m, m, m, m, cv2.BORDER_CONSTANT, value=6.0) for d in maps_read]
        # The mean distance of the model's samples' pixels: one kernel over the one map, or in glare the outline's
        # over the picture's distances and the others' over the map where the hidden pixels are none.
        rows, cols = off[:, 1] - lo[1], off[:, 0] - lo[0]
        pixels = len(np.unique(rows * (hi[0] - lo[0] + 1) + cols))
        score = np.zeros((y1 - y0, x1 - x0), np.float32)
        for which, pad in zip([slice(None)] if hidden is None else [model.outer[idx], ~model.outer[idx]], pads[m]):
            kernel = np.zeros((hi[1] - lo[1] + 1, hi[0] - lo[0] + 1), np.float32)
            kernel[rows[which], cols[which]] = 1.0
            kernel /= np.float32(pixels)
            roi = pad[ry0 + m:y1 + hi[1] + m + 1, rx0 + m:x1 + hi[0] + m + 1]
            # filter2D correlates: anchor (0, 0) puts kernel[0, 0] (offset lo) at each output pixel.
            score += cv2.filter2D(roi, -1, kernel, anchor=(0, 0), borderType=cv2.BORDER_CONSTANT)[:y1 - y0, :x1 - x0]
        score = np.where(inside[y0:y1, x0:x1] > 0, score, np.inf)
        # The best few only (ties by position): a full sort of the window cost as much as the correlation.
        best = np.argpartition(score, keep, axis=None)[:keep] if score.size > keep else np.arange(score.size)
        for flat in best[np.lexsort((best, score.ravel()[best]))]:
            v, u = divmod(int(flat), score.shape[1])
            results.append((float(score[v, u]), np.array([u + x0, v + y0]), yaw))
    results.sort(key=lambda r: r[0])
    starts: list[np.ndarray] = []
    for score, pixel, yaw in results:
        xy = ground(pixel.astype(float))
        if all(np.hypot(*(xy - s[:2])) > 4e-3 or abs(np.angle(np.exp(1j * (yaw - s[2])))) > 0.3 for s in starts):
            starts.append(np.r_[xy, yaw])
        if len(starts) == keep + spare:
            break
    return refined_starts(model, maps, starts[:keep], ground, hidden), starts[keep:]


def refined_starts(model: EdgeModel, maps: np.ndarray, starts: list[np.ndarray],
                   ground: Callable[[np.ndarray], np.ndarray], hidden: np.ndarray | None = None) -> list[np.ndarray]:
    """Coarse ``starts`` (x, y [m], yaw [rad]) each brought within a pixel and a degree (:func:`refine_start`
    on the oriented distances ``maps``; ``hidden`` as there), best first."""
    ringed = _ringed(maps, hidden)
    return [pose for _, pose in sorted((_refined_start(model, ringed, s, ground) for s in starts), key=lambda r: r[0])]


#: Edge directions are told apart in this many bins of the half turn (an edge counts in its own
#: and the two neighbouring bins, so within about 34 deg) for the oriented distance maps.
ORIENTATION_BINS = 8
#: The local search around each coarse start: yaw steps [deg] either side, and shifts [px] either side.
REFINE_YAW_DEG = (1.0, 6)
REFINE_SHIFT_PX = 8


def oriented_distances(gx: np.ndarray, gy: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """``(ORIENTATION_BINS, h, w)`` float32 distance [px, capped at 6] to the nearest (thin) edge pixel whose
    gradient direction (modulo a half turn) lies in or beside each bin.

    A model edge only matches a picture edge that runs the same way: the texture, a shadow's
    penumbra or a boss nearby rarely do, so the local search is not pulled onto them.
    """
    angle = np.mod(np.arctan2(gy, gx), np.pi)
    b = np.minimum((angle / np.pi * ORIENTATION_BINS).astype(np.int64), ORIENTATION_BINS - 1)
    maps = np.empty((ORIENTATION_BINS, *edges.shape), np.float32)
    for k in range(ORIENTATION_BINS):
        near = (edges > 0) & ((b == k) | (b == (k + 1) % ORIENTATION_BINS) | (b == (k - 1) % ORIENTATION_BINS))
        maps[k] = np.minimum(cv2.distanceTransform((~near).astype(np.uint8), cv2.DIST_L2, 3), 6.0)
    return maps


def thin_edges(gx: np.ndarray, gy: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """``(h, w)`` bool: the edge pixels on their ridge (non-maximum suppression across the edge).

    A strong edge's band is 3-5 px wide; a band leaves a distance map flat over its width.
    """
    angle = np.arctan2(gy, gx)
    mag = np.hypot(gx, gy)
    near_x = np.rint(np.cos(angle)).astype(np.int64)
    near_y = np.rint(np.sin(angle)).astype(np.int64)
    h, w = mag.shape
    vv, uu = np.mgrid[0:h, 0:w]
    ahead = mag[(vv + near_y).clip(0, h - 1), (uu + near_x).clip(0, w - 1)]
    behind = mag[(vv - near_y).clip(0, h - 1), (uu - near_x).clip(0, w - 1)]
    return (edges > 0) & (mag >= ahead) & (mag >= behind)


def refine_start(model: EdgeModel, maps: np.ndarray, start: np.ndarray, ground: Callable[[np.ndarray], np.ndarray],
                 hidden: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """The pose near a coarse start (x, y [m], yaw [rad]) whose edges lie closest on picture edges of
    the same direction: every :data:`REFINE_YAW_DEG` step and pixel shift within reach, scored by the
    mean oriented distance (``maps``, :func:`oriented_distances`). Returns (score [px], pose).

    The coarse search's 10 deg yaw grid leaves a 100 mm part's ends 5-8 px off; from there the
    edge fit's nearest-peak search can lock onto a boss or a shadow. This brings the start within
    a pixel and a degree first. ``hidden`` (h, w) bool (:func:`hidden_by_glare`): where a model edge inside the
    outline is unknown, at no distance.
    """
    return _refined_start(model, _ringed(maps, hidden), start, ground)


def _ringed(maps: np.ndarray, hidden: np.ndarray | None = None) -> np.ndarray:
    """The oriented distance maps (k, h, w) in a ring of one pixel of the cap (6 px), for :func:`_refined_start`:
    (1, k, h + 2, w + 2), or with glare's ``hidden`` pixels (h, w) bool (2, k, h + 2, w + 2), the second the maps
    the edges inside the outline read, where the hidden pixels are no distance away."""
    planes = [maps] if hidden is None or not hidden.any() else [maps, np.where(hidden[None], np.float32(0.0), maps)]
    return np.pad(np.stack(planes), ((0, 0), (0, 0), (1, 1), (1, 1)), constant_values=6.0)


def _refined_start(model: EdgeModel, ringed: np.ndarray, start: np.ndarray, ground: Callable[[np.ndarray], np.ndarray]
                   ) -> tuple[float, np.ndarray]:
    """:func:`refine_start` on the maps in their ring (:func:`_ringed`): every look outside the picture reads
    the ring's cap, one flat gather per yaw (indexing the three axes with bounds masks cost half the search); in
    glare the edges inside the outline look on the second plane."""
    step, n = np.radians(REFINE_YAW_DEG[0]), REFINE_YAW_DEG[1]
    r = REFINE_SHIFT_PX
    shifts = np.stack(np.meshgrid(np.arange(-r, r + 1), np.arange(-r, r + 1)), axis=-1).reshape(-1, 2)
    planes, bins, hr, wr = ringed.shape
    h, w = hr - 2, wr - 2
    flat = ringed.ravel()
    shift_at = shifts[:, 1:] * wr + shifts[:, :1]  # (s, 1) flat offsets of the shifts
    ref = model.camera.project(np.array([[start[0], start[1], model.tray_z]]), model.rvec, model.tvec)[0]
    best = (np.inf, start)
    for dyaw in np.arange(-n, n + 1) * step:
        p = np.array([start[0], start[1], start[2] + dyaw])
        idx = model.visible(p)
        if len(idx) < 12:
            continue
        idx = idx[:: max(1, len(idx) // FIT_SAMPLES)]
        uv, normal = model.project(p, idx)
        # The picture's gradient runs along the model edge's image normal.
        b = np.minimum((np.mod(np.arctan2(normal[:, 1], normal[:, 0]), np.pi) / np.pi * ORIENTATION_BINS)
                       .astype(np.int64), ORIENTATION_BINS - 1)
        if planes > 1:
            b = b + bins * ~model.outer[idx]  # the bin of the hidden pixels' plane
        u = np.rint(uv[:, 0]).astype(np.int64)
        v = np.rint(uv[:, 1]).astype(np.int64)
        # Samples within the reach of the picture's edge look inside the ring; any further out read the cap.
        near = (u >= -r) & (v >= -r) & (u < w + r) & (v < h + r)
        inner = (u >= r) & (v >= r) & (u < w - r) & (v < h - r)
        at = (b * hr + v + 1) * wr + u + 1
        d = np.full((len(shifts), len(u)), 6.0, np.float32)
        d[:, inner] = flat[at[inner][None, :] + shift_at]
        edge = near & ~inner
        if edge.any():
            uu = (u[edge][None, :] + shifts[:, :1]).clip(-1, w) + 1
            vv = (v[edge][None, :] + shifts[:, 1:]).clip(-1, h) + 1
            d[:, edge] = flat[(b[edge][None, :] * hr + vv) * wr + uu]
        score = d.mean(axis=1)
        k = int(np.argmin(score))
        if score[k] < best[0]:
            xy = start[:2] + ground(ref + shifts[k]) - ground(ref)
            best = (float(score[k]), np.r_[xy, start[2] + dyaw])
    return best
