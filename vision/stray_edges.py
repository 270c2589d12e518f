"""Picture edges beside a pose that neither the part nor its cast shadow explains, under a key light.

Under a low light an L's upright casts a shadow as wide as its base and as long: the L turned half a
turn about its upright puts its base into that shadow, where the base's hidden edges are dark on both
sides (:func:`vision.shadow.unseen_edges`) and its sides lie on the shadow's, and it found more of its
edges there (0.82 of its outline) than the true pose does on its faint lit base (0.58): low-angle
l_bracket seed 21 was reported 80 mm off. What that pose cannot explain is the lit base beside it, its
bores and brushed streaks: picture edges outside the part and outside its shadow. A pose that lies
where the part is explains every edge around it but the tray's own texture, which has few.

:func:`stray_edges` counts them, against the part's visible outline so that the share does not depend
on the part's size; :func:`vision.locate.locate_parts` refuses a pose that leaves more than
:data:`MAX_STRAY` and prefers among its fits those that do not. The other way round, :func:`explained_inside` is the
share of the picture's edges inside a pose's outline that its model edges explain: in glare it tells a symmetric
outline's turns apart.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial import cKDTree

from vision.mesh_edges import MeshEdges

#: The shadow's hull is drawn as long as a light this high above the tray casts it [rad], and turned this much
#: either way from the estimated light [rad]: the estimate at a pose can be 10 deg too high (a stepped wall's true
#: pose under 23 deg was judged under 30-36 deg, its shadow's end lying past the hull of the estimate's own), and a
#: longer shadow only covers more tray away from the light, where a part turned about its upright puts its base,
#: not where it leaves the true one.
SHADOW_ELEVATION = np.radians(5.0)
TURN_RAD = np.radians(10.0)
#: Picture edges this close to the hull of part and shadow are its own (blur, penumbra) [px] ...
COVER_PX = 3
#: ... and only those within this of the part's own hull count (a neighbour further away is another blob's) [px].
BESIDE_PX = 20
#: Most stray edge pixels a reported pose may leave, per visible outline sample (about one per pixel) (unitless).
#: The 132 low-angle gallery pictures (seeds 0-21) at their true poses, under the light estimated there, left at
#: most 0.0064 (the tray's texture); the L turned about its upright above left 0.10.
MAX_STRAY = 0.05


def stray_edges(model: MeshEdges, pose: np.ndarray, light: np.ndarray, thin: np.ndarray) -> float:
    """Share of the picture's edge pixels within :data:`BESIDE_PX` of the part at ``pose`` (x, y [m], yaw [rad]) that
    lie outside the convex hull of the part and its shadow under the key light ``light`` (unit (3,) towards it,
    base frame), per visible outline sample of the model (unitless, 0 when all are explained).

    ``thin`` (h, w) bool are the picture's edges on their ridge (:func:`vision.locate_search.thin_edges`).
    The shadow is drawn long and a little turned (:data:`SHADOW_ELEVATION`, :data:`TURN_RAD`): its length is the
    estimate's least certain figure, and only the edges towards the light and beside the part tell a pose.
    """
    points = model.hull_points
    _, towards = model.in_part_frame(pose, light)
    az = float(np.arctan2(towards[1], towards[0]))
    drawn = [points]
    for turn in (-TURN_RAD, 0.0, TURN_RAD):
        lq = np.array([np.cos(SHADOW_ELEVATION) * np.cos(az + turn), np.cos(SHADOW_ELEVATION) * np.sin(az + turn),
                       np.sin(SHADOW_ELEVATION)])
        drawn.append(points - (points[:, 2] / lq[2])[:, None] * lq)  # each point's shadow on the tray
    uv = model.camera.project(model.world(pose, np.vstack(drawn)), model.rvec, model.tvec)
    h, w = thin.shape
    part = uv[:len(points)]
    # Only the picture around the part itself is looked at: the long shadow's flanks are the tray's.
    x0, y0 = np.maximum(np.floor(part.min(axis=0)).astype(int) - BESIDE_PX - COVER_PX, 0)
    x1, y1 = np.minimum(np.ceil(part.max(axis=0)).astype(int) + BESIDE_PX + COVER_PX + 1, (w, h))
    if x1 <= x0 or y1 <= y0:
        return 0.0
    own, beside = (np.zeros((y1 - y0, x1 - x0), np.uint8) for _ in range(2))
    for mask, drawn_uv, reach in ((own, uv, COVER_PX), (beside, part, COVER_PX + BESIDE_PX)):
        hull = cv2.convexHull(drawn_uv.astype(np.float32))[:, 0]
        cv2.fillConvexPoly(mask, np.rint((hull - (x0, y0)) * 16).astype(np.int32), 1, shift=4)
        mask[:] = cv2.dilate(mask, np.ones((2 * reach + 1,) * 2, np.uint8))
    stray = int((thin[y0:y1, x0:x1] & (beside > 0) & (own == 0)).sum())
    outline = int(model.outer[model.visible(pose)].sum())
    return stray / max(outline, 1)


def explained_inside(model: MeshEdges, pose: np.ndarray, thin: np.ndarray, bloom: float = 0.0) -> float:
    """Share of the picture's edge pixels inside the part's outline that lie on a model edge at ``pose``.

    ``thin`` (h, w) bool are the picture's edges (:func:`vision.locate_search.thin_edges`). Only the pixels more than
    :data:`EXPLAIN_PX` inside the outline count, and they count as explained within that (and the
    ``bloom`` [px]) of any edge the model shows there. Turns of a symmetric outline share it, so this
    compares what lies inside: a boss's bore seen in glare is explained by the pose that has it there,
    not by its turn (which hides its own bosses in the clipped top and so finds a larger share of its
    fewer edges) (0..1).

    Any edge, the outline's too: a tall upright's top edge is outline, but seen off the camera's axis
    it lies well inside the outline's hull, and a glare L's true pose explained 0.30 of the picture
    (its turn 0.27) until it counted. And with the bloom: a clipped top blooms into its dark bores,
    their edges lie a bloom inside the model's rims.
    """
    idx = model.visible(pose)
    uv, _ = model.project(pose, idx)
    outer = uv[model.outer[idx]]
    if len(outer) < 3 or len(uv) == len(outer):
        return 0.0
    hull = cv2.convexHull(outer.astype(np.float32))
    x, y, w, h = cv2.boundingRect(hull)
    vs, us = np.nonzero(thin[max(y, 0):y + h, max(x, 0):x + w])
    pix = np.column_stack([us + max(x, 0), vs + max(y, 0)]).astype(np.float64)
    if len(pix) == 0:
        return 0.0
    inside = np.array([cv2.pointPolygonTest(hull, (float(u), float(v)), True) > EXPLAIN_PX for u, v in pix])
    pix = pix[inside]
    if len(pix) == 0:
        return 0.0
    d, _ = cKDTree(uv).query(pix)
    return float(np.mean(d <= EXPLAIN_PX + bloom))


#: A picture edge pixel this close to a model edge [px] is explained by it (:func:`explained_inside`).
EXPLAIN_PX = 2.0
