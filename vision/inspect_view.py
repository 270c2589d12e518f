"""What the camera can see of a part's expected edges, whatever the light (:mod:`vision.inspect`).

An edge sample the picture cannot show is *unknown* to the inspection: neither found nor missing,
and no deviation is read there. Beside glare and deep shadow (judged in :mod:`vision.inspect`) two
things of the view itself hide one: the end of the picture, and the part's own taller faces
standing between the edge and the camera.
"""

from __future__ import annotations

import numpy as np

from vision.mesh_edges import MeshEdges
from vision.shadow import shadowed

#: The edge filter's reach: an edge this close to the picture's border cannot be told [px].
FRAME_PX = 1.0
#: A taller face hides an edge where it stands this far above the line of sight [m]: clear of the
#: height field's rounding at the edge's own face (a texel, 0.5 mm, on a face's rim).
OVER_SIGHT_M = 5e-4


def in_picture(shape: tuple[int, ...], uv: np.ndarray, normal: np.ndarray, t: float) -> np.ndarray:
    """``(k,)`` bool: each edge sample ``uv`` (k, 2) [px], and the points ``t`` [px] along and against
    its image ``normal``, lie at least :data:`FRAME_PX` inside a picture of ``shape`` (h, w, ...)."""
    h, w = shape[:2]
    inside = np.ones(len(uv), bool)
    for step in (-t, 0.0, t):
        q = uv + step * normal
        inside &= (q[:, 0] >= FRAME_PX) & (q[:, 0] <= w - 1 - FRAME_PX) & \
            (q[:, 1] >= FRAME_PX) & (q[:, 1] <= h - 1 - FRAME_PX)
    return inside


def behind_part(model: MeshEdges, p: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``(k,)`` bool: the samples ``idx`` of ``model`` whose line of sight to the camera passes
    through the part itself at pose ``p`` (x, y [m], yaw [rad]): a wall standing between them and a
    camera looking down at it from the side. Its top shows where the hidden edge should be.

    The part's shadow with the eye as the light (:func:`vision.shadow.shadowed`, over its height field),
    standing :data:`OVER_SIGHT_M` above the line of sight.
    """
    points = model.points[idx]
    if len(idx) == 0:
        return np.zeros(0, bool)
    eye, _ = model.in_part_frame(p, np.zeros(3))
    to_eye = eye[None, :] - points
    return shadowed(model.field, points, to_eye / np.linalg.norm(to_eye, axis=1, keepdims=True), bias=OVER_SIGHT_M)


def unseen(model: MeshEdges, p: np.ndarray, idx: np.ndarray, uv: np.ndarray, normal: np.ndarray,
           shape: tuple[int, ...], reach: float) -> np.ndarray:
    """``(k,)`` bool over the visible samples ``idx`` (pixels ``uv``, image normals ``normal``) at pose ``p``:
    those the view hides from the edge search ``reach`` [px] either side.

    A part at the edge of the view: where the picture (``shape``) ends nothing shows, and the search
    clamped to its border reads the border's pixels (an outline 1.2 mm out, a hole missing on a good
    5 MP dome, benchmarks/inspect_real_light.py seed 1). An outline edge behind a taller face of the
    part (a step's rim behind a thin wall seen from the side): the wall's top lies where it should be
    (1.6 mm out on a good glare stepped wall). Features keep their far-side edges: a boss's foot behind
    it shows with its top's edge, and the shares of a loop found (``min_whole_found``,
    ``vision.inspect_features._least_loop``) were set counting them.
    """
    hidden = ~in_picture(shape, uv, normal, reach)
    rim = model.outer[idx]
    hidden[rim] |= behind_part(model, p, idx[rim])
    return hidden
