"""The key light a pose hypothesis sees: for :func:`vision.locate.locate_parts`, the light's direction from
the hard shadow around a blob, estimated at each pose the edge fit starts from.

The light is one for the whole picture, but its estimate is not: :func:`vision.shadow.estimate_light`
asks which direction makes *this* part, at *this* pose, cast the dark it sees. At a coarse start turned
half a turn or 15 mm off (a low light's long shadow wins the coarse search's first places), a stepped
wall's shadow was explained by a light 15-59 deg off the true one, and the fit from a start on the part
then left out the wrong edges and was refused (0.31 of its outline found under that light, 0.71 under
the light estimated where it lies). So when the fits under the first estimate are refused, each start
gets the light estimated at its own pose (:class:`LightAt`), and a fit is judged under the light of the
pose it began from (:func:`vision.locate._best_fit`).
"""

from __future__ import annotations

import cv2
import numpy as np

from vision.mesh_edges import MeshEdges, yaw_rotation, yaw_rotation_3d
from vision.shadow import DARK_LOG, estimate_light

#: The tray around a blob is looked at every this many pixels for the light (:func:`key_light`).
LIGHT_PIXEL_STEP = 3
#: Fewest dark tray pixels (of those looked at) that make a hard shadow to take the light from.
MIN_DARK_PIXELS = 40
#: Poses this close (position [m] and yaw [rad]) share one estimate of the light (:class:`LightAt`): the
#: coarse search's refined starts and an edge fit's turn land within a few millimetres of each other.
SAME_LIGHT_M = 3e-3
SAME_LIGHT_RAD = np.radians(3.0)


def key_light(model: MeshEdges, pose: np.ndarray, log_ratio: np.ndarray, box: tuple[int, int, int, int]
              ) -> np.ndarray | None:
    """The key light's unit direction (base frame) from the shadow around a blob's part at ``pose``, or None.

    The tray's pixels every :data:`LIGHT_PIXEL_STEP` px of the blob's box ``box`` (x0, y0, x1, y1)
    and a margin of the part's size, hard shadow where ``log_ratio`` (the picture over the tray
    model) is below :data:`vision.shadow.DARK_LOG` (:func:`vision.shadow.estimate_light`).
    """
    h, w = log_ratio.shape
    x0, y0, x1, y1 = box
    margin = max(x1 - x0, y1 - y0) // 2
    vs, us = np.mgrid[max(y0 - margin, 0):min(y1 + margin, h):LIGHT_PIXEL_STEP,
                      max(x0 - margin, 0):min(x1 + margin, w):LIGHT_PIXEL_STEP]
    pix = np.column_stack([us.ravel(), vs.ravel()]).astype(np.float64)
    rays = model.camera.rays(pix) @ cv2.Rodrigues(model.rvec)[0]  # base frame: R_base_cam @ ray
    eye = model.eye
    tray = eye[:2] + ((model.tray_z - eye[2]) / rays[:, 2])[:, None] * rays[:, :2]
    eye_part, _ = model.in_part_frame(pose, np.zeros(3))
    tray_part = (tray - pose[:2]) @ yaw_rotation(pose[2])
    dark = log_ratio[vs.ravel(), us.ravel()] < DARK_LOG
    light = estimate_light(model.field, tray_part, dark, eye_part, min_dark=MIN_DARK_PIXELS)
    if light is None:
        return None
    return yaw_rotation_3d(pose[2]) @ light


class LightAt:
    """The key light (unit (3,), base frame) estimated at a pose (x, y [m], yaw [rad]) of one blob's part
    (:func:`key_light`), each estimate made once for poses within :data:`SAME_LIGHT_M` and
    :data:`SAME_LIGHT_RAD` of each other. Where a pose explains no hard shadow the light ``first``
    (estimated at the blob's best coarse start) stands: the picture has a key light, this pose only
    fails to explain it.
    """

    def __init__(self, model: MeshEdges, log_ratio: np.ndarray, box: tuple[int, int, int, int], first_pose: np.ndarray,
                 first: np.ndarray):
        self._model, self._log_ratio, self._box = model, log_ratio, box
        self.first = first
        self._known: list[tuple[np.ndarray, np.ndarray]] = [(np.asarray(first_pose, dtype=np.float64), first)]

    def __call__(self, pose: np.ndarray) -> np.ndarray:
        p = np.asarray(pose, dtype=np.float64)
        for q, light in self._known:
            if np.hypot(*(p[:2] - q[:2])) < SAME_LIGHT_M and abs(np.angle(np.exp(1j * (p[2] - q[2])))) < SAME_LIGHT_RAD:
                return light
        light = key_light(self._model, p, self._log_ratio, self._box)
        light = self.first if light is None else light
        self._known.append((p, light))
        return light


def lights_at(model: MeshEdges, starts: list[np.ndarray], log_ratio: np.ndarray, box: tuple[int, int, int, int]
              ) -> LightAt | None:
    """The key light at each pose of a blob (:class:`LightAt`), or None when the blob's best coarse start
    (``starts[0]``) sees none (diffuse or high light: no hard shadow to take it from)."""
    if not starts:
        return None
    first = key_light(model, starts[0], log_ratio, box)
    return None if first is None else LightAt(model, log_ratio, box, starts[0], first)
