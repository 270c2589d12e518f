"""Find blanks or parts lying on a tray: position and yaw in the robot base frame from one image.

The part is its mesh standing on the tray plane ``z = tray_z`` of the base frame, turned about z;
the camera pose ``T_base_cam`` comes from the hand-eye file. :func:`locate_parts`:

1. Tray model: the picture over a smooth model of the empty tray (vignetting, uneven light);
   what departs from it or is dense with edges makes the candidate blobs (part and shadow).
2. Coarse search per blob: the mesh's visible edges (top outline, steps, bosses, holes at their
   real heights) against the distance map of the picture's edges, every 10 deg of yaw; then a
   local search every degree and pixel against the distance to picture edges of the same
   direction (thinned to their ridge), so the fit starts within a pixel of the part.
3. Edge fit: each visible model edge takes the nearest sub-pixel gradient peak along its image
   normal, and x, y, yaw are fitted to them (soft-L1) in rounds of narrowing search; symmetric
   turns of the outline are tried and the edges inside it decide (in glare, which turn explains
   the picture's edges inside the outline).
4. Judge: the share of the outline's edges found within a pixel must reach a minimum, in both
   of the outline's main directions, and so must the share of all visible edges (steps, bosses,
   holes), else the blob gets no pose and the refusal says which was short; under a key light, also
   when edges beside it lie outside the part and its shadow (:mod:`vision.stray_edges`). A shadow, a box or
   glare do not have the part's edges; a wall as bright as the tray still has its crease with
   the top face, which the model has as well.

The pose returned is ``T_base_part = Trans(x, y, z) Rz(yaw) Trans(-cx, -cy, -zmin)``: ``(cx, cy)`` is
the centroid of the mesh's footprint and ``zmin`` its lowest point (mesh coordinates), ``z`` the tray.
A mesh with symmetry gives one of the equivalent yaws.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
import shapely
import trimesh
from scipy.ndimage import map_coordinates
from scipy.optimize import least_squares
from shapely.geometry import MultiPolygon, Polygon

from factory.core.errors import VisionError
from factory.core.units import MM_PER_M
from vision.camera import CameraModel, bin_image, binned_camera
from vision.locate_search import (FIT_SAMPLES, chamfer_starts, hidden_by_glare, oriented_distances, refined_starts,
                                  thin_edges)
from vision.mesh_edges import MeshEdges, edge_model, yaw_rotation
from vision.picture_edges import blob_outline, find_edges, gradients, tray_ratio
from vision.pose_uncertainty import pose_covariance
from vision.key_light import LightAt, lights_at
from vision.shadow import shadow_evidence, unseen_edges
from vision.stray_edges import MAX_STRAY, explained_inside, stray_edges

log = logging.getLogger(__name__)


#: Systematic error of a sub-pixel edge on real pictures (blur, lighting, the iso-line level),
#: added to the fit's statistical uncertainty in the expected error [px].
EDGE_BIAS_PX = 0.25


#: Outline points further than this from the silhouette count less and less in the fit
#: (soft-L1 loss): a chipped corner or a burr must not drag the pose [px].
ROBUST_SCALE_PX = 1.0


def mm_to_m(value_mm: np.ndarray | float) -> np.ndarray | float:
    """Lengths from the CAM side [mm] in vision units [m]."""
    return np.asarray(value_mm, dtype=np.float64) / MM_PER_M if np.ndim(value_mm) else float(value_mm) / MM_PER_M


@dataclass(frozen=True)
class LocateOptions:
    """Tunables of :func:`locate_parts`.

    Attributes
    ----------
    min_area_ratio : float
        A blob is a candidate when its area is at least this factor of the part's top face
        projected at the blob; no upper bound, a shadow or a neighbour may join it (unitless).
    max_rms_px : float
        A fit whose edges miss the picture's by more RMS than this is rejected [px].
    min_coverage : float
        Share of the part's visible outline edges the picture must show within a pixel of the
        fit (0..1); below it no pose is reported (a box, a shadow, a different part). On the
        benchmark gallery boxes reach at most 0.40 and correct poses mostly 0.5-1 (with the two
        gallery shapes, a box fitted as the hexagonal boss reached 0.51, and 0.26 of all its edges,
        so ``min_found`` refuses it); a glare dome 1.6 mm off reached 0.41.
    min_axis_coverage : float
        The same share in the worse of the outline's two main edge directions (0..1): a long
        part's ends must be seen too, or the pose may be slid along it. Fits seen weakly along one
        direction are slid along the outline first (:func:`_slid`), which brought stepped walls
        slid 2-2.5 mm (0.47-0.58) back. Below 0.5 wrong poses remain: a glare stepped wall turned
        180 deg (0.47, not slid in glare) and a blank located on a tray plane 30 mm too high
        (about 0.5: it finds one of each pair of opposite sides), so 0.5 stands. Under a key light all the seen
        edges (steps, bosses, holes, the cast shadow's edge) may reach it instead (:attr:`_EdgeFit.edges_axis`):
        the outline's lit side beside lit tray is often faint there.
    min_found : float
        Share of all visible model edges (outline, steps, bosses, holes) found within a pixel
        (0..1): the edges inside the outline tell a pose turned or shifted onto a look-alike
        outline (wrong poses on the gallery reach 0.49, correct ones mostly 0.55-0.86).
    min_contrast : float
        Least departure from the tray model that makes a pixel part of a candidate blob
        (natural log of the brightness ratio; 0.1 is about 10 %).
    refine : bool
        The chosen pose is refined past the fit that judged it: in even light (no key light, nothing
        clipped) settled (:func:`_settled`: the walls' feet that took their tops' edges leave it), in
        glare drawn in by its walls' outward shift (:data:`GLARE_WALL_SHIFT`). Inspection turns it off.
    """

    min_area_ratio: float = 0.3
    max_rms_px: float = 1.5
    min_coverage: float = 0.5
    min_axis_coverage: float = 0.5
    min_found: float = 0.5
    min_contrast: float = 0.1
    refine: bool = True


@dataclass(frozen=True)
class Footprint:
    """A part as a prism for locating it.

    Attributes
    ----------
    outline : (k, 2) float
        Footprint outline around its centroid, counter-clockwise, not closed [m].
    height : float
        Prism height [m].
    centroid : (2,) float
        Footprint centroid in mesh coordinates [m].
    zmin : float
        Lowest mesh z [m].
    symmetry : int
        Rotational symmetry order the outline is tested for (1: none, 2: 180 deg, 4: 90 deg).
    vertices : (n, 3) float
        The mesh the footprint was made from, in mesh coordinates [m] (empty: a bare prism).
    faces : (m, 3) int
        Its triangles.
    """

    outline: np.ndarray
    height: float
    centroid: np.ndarray
    zmin: float
    symmetry: int
    vertices: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), repr=False, compare=False)
    faces: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64), repr=False, compare=False)

    @property
    def convex(self) -> bool:
        """Whether the outline is convex (within 0.1 % of its hull's area)."""
        poly = Polygon(self.outline)
        return poly.area >= 0.999 * poly.convex_hull.area


def footprint_from_mesh(vertices_mm: np.ndarray, faces: np.ndarray, *, source: str = "part") -> Footprint:
    """The footprint prism of a mesh in millimetres (CAM units), in metres.

    Parameters
    ----------
    vertices_mm : (n, 3) float
        Mesh vertices [mm].
    faces : (m, 3) int
        Triangles.

    Raises
    ------
    VisionError
        (``source``) Empty mesh, a flat mesh (no height), or a footprint of more than one piece.
    """
    v = mm_to_m(np.asarray(vertices_mm, dtype=np.float64))
    f = np.asarray(faces, dtype=np.int64)
    if len(v) == 0 or len(f) == 0:
        raise VisionError("mesh has no triangles", source=source)
    tri = v[f][:, :, :2]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    area2 = np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    tri = tri[area2 > 1e-14]
    # Shapely unions triangles exactly; a tiny buffer closes the slivers between
    # float-rounded neighbours without moving the outline measurably (1 nm).
    union = shapely.union_all(shapely.polygons(np.concatenate([tri, tri[:, :1]], axis=1))).buffer(1e-9)
    if isinstance(union, MultiPolygon):
        raise VisionError(f"footprint is {len(union.geoms)} separate pieces; locate needs one part outline",
                          source=source)
    poly = shapely.geometry.polygon.orient(Polygon(union.exterior), 1.0).simplify(1e-6)
    height = float(v[:, 2].max() - v[:, 2].min())
    if height <= 0 or poly.area <= 0:
        raise VisionError("mesh is flat: no height or no footprint", source=source)
    c = np.array(poly.centroid.coords[0])
    outline = np.array(poly.exterior.coords)[:-1] - c
    v.setflags(write=False)
    f.setflags(write=False)
    return Footprint(outline=outline, height=height, centroid=c, zmin=float(v[:, 2].min()),
                     symmetry=_symmetry(outline), vertices=v, faces=f)


def _symmetry(outline: np.ndarray) -> int:
    """Largest of 4, 2, 1 whose rotation maps the outline onto itself (IoU > 0.999)."""
    poly = Polygon(outline)
    for n in (4, 2):
        a = 2 * np.pi / n
        r = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        turned = Polygon(outline @ r.T)
        if poly.intersection(turned).area >= 0.999 * poly.union(turned).area:
            return n
    return 1


@dataclass(frozen=True)
class LocatedPart:
    """One part found on the tray.

    Attributes
    ----------
    x, y, z : float
        Footprint centroid on the tray in the base frame [m] (z = tray height).
    yaw : float
        Rotation of the part's x axis about base z [rad], in (-pi, pi].
    score : float
        Share of the part's outline edges (the footprint's outline at every height) the picture
        shows within 1 px of the fitted pose (0..1).
    rms_px : float
        RMS distance of the picture's edges to the fitted model edges (inliers within 1.5 px) [px].
    mm_per_px : float
        Size of one pixel on the part at its distance [mm/px].
    sigma_xy : float
        Position uncertainty [m]: :data:`COVERAGE_FACTOR` standard deviations of the fit (larger
        axis, residuals counted as correlated) and the edge bias, so that the true error is within
        it in at least 90 % of pictures (95 % on the benchmark gallery).
    sigma_yaw : float
        Yaw uncertainty, the same way [rad].
    pixel : (float, float)
        Where the part's centroid is in the image [px].
    outline : (n, 2) float
        The sub-pixel outline of the part's blob in the picture, for inspection [px].
    """

    x: float
    y: float
    z: float
    yaw: float
    score: float
    rms_px: float
    mm_per_px: float
    sigma_xy: float
    sigma_yaw: float
    pixel: tuple[float, float]
    outline: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)), repr=False, compare=False)

    def to_dict(self) -> dict:
        """JSON-ready: metres, radians, pixels; the error figures in mm and deg for people."""
        return {"x": self.x, "y": self.y, "z": self.z, "yaw": self.yaw, "score": self.score,
                "rms_px": self.rms_px, "mm_per_px": self.mm_per_px,
                "expected_error_mm": self.sigma_xy * 1e3, "expected_error_deg": float(np.degrees(self.sigma_yaw)),
                "pixel": list(self.pixel)}


def grey_picture(image: np.ndarray, source: str) -> np.ndarray:
    """The picture as (h, w) uint8 grey (BGR or BGRA converted); VisionError for any other or under 16 x 16 px."""
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or min(img.shape[:2]) < 16:
        raise VisionError(f"not an 8-bit image of at least 16x16 pixels (shape {img.shape}, {img.dtype})",
                          source=source)
    if img.ndim == 3:
        return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    return img


#: Share of the visible edges hidden in clipped highlights above which a symmetric turn that fits
#: as well makes the pose ambiguous (unitless).
AMBIGUOUS_HIDDEN = 0.1
#: ... and "fits nearly as well" is a share of outline and of all edges found within this of the best.
AMBIGUOUS_SHARE = 0.2
#: Fits of two turns whose centroids lie within this of each other lie on the same outline [m].
SAME_OUTLINE_M = 3e-3
#: ... unless the share of the picture's edges inside the outline one turn explains beats every
#: other's by this much (:func:`vision.stray_edges.explained_inside`) (unitless).
TURN_MARGIN = 0.15
#: Share of a fitted bloom [px] that counts as systematic edge error in the uncertainty (unitless): a
#: clipped top blooms unevenly (parts of its outline not clipped, parallax). With the walls' feet out of
#: the fit (:meth:`vision.mesh_edges.MeshEdges.unresolved`) glare poses no longer lie outward by a share of the walls'
#: width, and 0.2 of the bloom (1-1.6 px) covers 29 of 30 glare poses of held-out seeds 15-19.
BLOOM_BIAS = 0.2
#: Grey level from which a pixel counts as clipped by the sensor (8-bit) [grey].
SATURATED_GREY = 250
#: Search half-widths of the edge fit's rounds, widest first [px].
SEARCH_PX = (8.0, 4.0, 2.0, 2.0)
#: Neighbouring edge samples see the same blur and texture: the fit's residuals count as this
#: many times fewer independent ones when the uncertainty is estimated (unitless).
CORRELATED_SAMPLES = 4.0
#: The reported uncertainty is this many fit standard deviations, so the true error lies within
#: it in at least 90 % of pictures (calibrated on benchmarks/locate_real_light.py) (unitless).
COVERAGE_FACTOR = 2.5


@dataclass(frozen=True)
class _EdgeFit:
    """A fitted pose; ``coverage``: share of the outline's edges found (``axis_coverage``: in the worse
    of its two main directions), ``found``: of all visible edges not hidden in a clipped highlight,
    ``hidden``: share of the visible edges so hidden; ``ambiguous``: a symmetric turn of the outline,
    not a symmetry of the mesh, fits as well and the edges that would tell them apart are hidden;
    ``bloom_px``: how far a clipped highlight spills past its edges [px]; ``samples``: the model sample
    (:class:`vision.mesh_edges.MeshEdges`) of each of ``residuals`` and ``jac``'s rows; ``light``: the key
    light it was judged under (unit (3,), base frame; None without one); ``stray``: the picture's edges beside
    it that neither the part nor its shadow explains, per outline sample (:func:`vision.stray_edges.stray_edges`;
    0 without a key light); ``edges_axis``: under a key light, the share of all seen edges (outline, steps,
    bosses, holes and the cast shadow's edge) found in the worse of their two main directions (0 without one)."""

    pose: np.ndarray
    coverage: float
    axis_coverage: float
    found: float
    rms_px: float
    cost: float
    jac: np.ndarray
    residuals: np.ndarray
    hidden: float = 0.0
    ambiguous: bool = False
    bloom_px: float = 0.0
    samples: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False, compare=False)
    light: np.ndarray | None = field(default=None, repr=False, compare=False)
    stray: float = 0.0
    edges_axis: float = 0.0

    @property
    def evidence(self) -> float:
        """What the picture shows of the part at this pose: the outline found, in its worse direction,
        and all edges found, summed (0..3)."""
        return self.coverage + self.axis_coverage + self.found


def _clipped(saturated: np.ndarray | None, uv: np.ndarray, normal: np.ndarray, off: np.ndarray,
             gx: np.ndarray, gy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which found edges have a saturated bright side, and the direction (+1/-1 along the normal) of that side.

    A clipped highlight (glare) blurred by the optics spills past its edge: the gradient peak of
    the clipped profile lies towards the dark side by a common amount (the bloom, fitted).
    Returns ``(k,)`` bool and ``(k,)`` float (0 where no edge was found).
    """
    k = len(uv)
    ok = np.isfinite(off)
    edge = uv + np.nan_to_num(off)[:, None] * normal
    g = map_coordinates(gx, [edge[:, 1], edge[:, 0]], order=1, mode="nearest") * normal[:, 0] + \
        map_coordinates(gy, [edge[:, 1], edge[:, 0]], order=1, mode="nearest") * normal[:, 1]
    side = np.where(ok, np.sign(g), 0.0)
    if saturated is None or not saturated.any():
        return np.zeros(k, bool), side
    clipped = np.zeros(k, bool)
    for step in (1.0, 2.0, 3.0):
        q = edge + (side * step)[:, None] * normal
        clipped |= map_coordinates(saturated, [q[:, 1], q[:, 0]], order=0, mode="nearest") > 0
    return clipped & ok, side


def _hidden(saturated: np.ndarray | None, uv: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """``(k,)`` bool: the picture is clipped on both sides of these model edges, so it cannot show them."""
    if saturated is None or not saturated.any():
        return np.zeros(len(uv), bool)
    both = np.ones(len(uv), bool)
    for step in (-1.5, 1.5):
        q = uv + step * normal
        both &= map_coordinates(saturated, [q[:, 1], q[:, 0]], order=0, mode="nearest") > 0
    return both


def _edge_fit(model: MeshEdges, gx: np.ndarray, gy: np.ndarray, threshold: float, start: np.ndarray,
              reaches: tuple[float, ...] = SEARCH_PX, saturated: np.ndarray | None = None,
              light: np.ndarray | None = None, dark: np.ndarray | None = None, settle: bool = False
              ) -> _EdgeFit | None:
    """Fit x, y and yaw so the model's visible edges lie on the picture's edges (rounds of search and fit).

    Edges beside a clipped highlight (``saturated``, (h, w) uint8) are measured with a common
    bloom [px] fitted with the pose; edges inside the outline that lie in a clipped area on both
    sides cannot show and are left out of the share found. Under a key light (``light``, unit (3,)
    towards it, base frame; :func:`vision.shadow.estimate_light`) the edges dark on both sides are
    left out as well (of the fit too: what they find nearby is another edge, often the shadow's),
    and the edge of the shadow the part casts on the tray counts with its outline. ``dark``: those
    edges when known already (:func:`_dark_edges` at a pose nearby). ``settle`` (even light, for the
    chosen pose only, :func:`_settled`): a wall's foot whose found edge is its top's leaves the fit, and
    the last round is repeated until the edges stop moving.
    """
    p = np.asarray(start, dtype=np.float64)
    bloom = 0.0
    sol = None
    unknown = _dark_edges(model, p, light) if dark is None else dark
    # Only where a clipped top can bloom over its thin walls (glare) do the feet go: under a key light
    # the shading tells a wall from its top (left out, an L under a low light turned 1.9 deg), and
    # in even light the feet found by inspection's tests stay where they were.
    glare = light is None and saturated is not None and bool(saturated.any())
    rounds, extra = list(reaches), 0
    while rounds:
        reach = rounds.pop(0)
        idx = model.visible(p)
        idx = idx[~unknown[idx]]
        if len(idx) < 12:
            return None
        uv, normal = model.project(p, idx)
        # Which feet lie beside their tops matters only in glare (they go) and settling (TOOK_TOP_PX).
        partner = model.beside(uv, normal, idx) if glare or settle else np.full(len(idx), -1)
        keep = partner < 0 if glare else np.ones(len(idx), bool)
        # Where the higher edge beside a foot lies, along the foot's normal [px].
        top = np.where(partner >= 0, np.einsum("nj,nj->n", uv[partner] - uv, normal), np.nan)
        idx, uv, normal, top = (a[keep][:: max(1, int(keep.sum()) // FIT_SAMPLES)] for a in (idx, uv, normal, top))
        off = find_edges(gx, gy, threshold, uv, normal, reach)
        ok = np.isfinite(off)
        if settle:
            # A foot whose found edge lies on its top's (within TOOK_TOP_PX, nearer it than its own
            # place) took the top's edge: a stepped wall beside a box turned 1.16 deg on such feet.
            took = np.abs(off - top)
            ok &= ~((took < TOOK_TOP_PX) & (took < np.abs(off)))
        if ok.sum() < 12:
            return None
        target = uv[ok] + off[ok, None] * normal[ok]
        pts, nrm = idx[ok], normal[ok]
        clipped, side = _clipped(saturated, uv, normal, off, gx, gy)
        # The bloom moves a clipped edge towards its dark side (-side): it is a parameter only when
        # enough edges are clipped to fix it.
        spill = np.where(clipped, side, 0.0)[ok] if clipped.sum() >= 12 else np.zeros(int(ok.sum()))

        sol = _pulled(model, model.points[pts], nrm, target, spill, np.r_[p, bloom])
        # Each round fits to the edges found from where it began: settling, the last reach is repeated
        # until the edges no longer move (the stepped wall above stopped 0.9 deg off, a round short of 0.46).
        if settle and not rounds and extra < EXTRA_ROUNDS and \
                float(np.abs(model.project(sol.x[:3], idx)[0] - uv).max()) > SETTLED_PX:
            rounds.append(reach)
            extra += 1
        p, bloom = sol.x[:3], float(sol.x[3])
    # Judge the final pose: the share of the visible edges found within a pixel of where they should be.
    idx = model.visible(p)
    uv, normal = model.project(p, idx)
    off = find_edges(gx, gy, threshold, uv, normal, 1.5 + bloom)
    clipped, side = _clipped(saturated, uv, normal, off, gx, gy)
    off = off + bloom * np.where(clipped, side, 0.0)
    near = np.abs(np.nan_to_num(off, nan=np.inf)) <= 1.0
    outer = model.outer[idx]
    # Edges inside the outline within a clipped highlight are unknown, neither found nor missed;
    # the outline against the tray always counts.
    seen = outer | ~_hidden(saturated, uv, normal)
    inliers = np.abs(sol.fun) <= 1.5
    rms = float(np.sqrt(np.mean(sol.fun[inliers] ** 2))) if inliers.any() else np.inf
    outer_near, outer_normal = near[outer], normal[outer]
    found = near[seen]
    if light is not None:
        eye, towards = model.in_part_frame(p, light)
        shade = shadow_evidence(model.field, model.points, model.direction, model.n1, model.n2, idx, eye, towards,
                                lambda pts, d: model.image_of(p, pts, d),
                                lambda uv, n, reach: find_edges(gx, gy, threshold, uv, n, reach),
                                lambda pts: model.pixels(p, pts))
        outer_near = np.r_[near[outer & ~shade.unknown], shade.near]
        outer_normal = np.vstack([normal[outer & ~shade.unknown], shade.normal])
        found = np.r_[near[seen & ~shade.unknown], shade.near]
        # Under a key light the outline's side towards it is a lit top beside lit tray, often faint: the edges
        # inside it and the shadow's fix the position across that side as well (:attr:`_EdgeFit.edges_axis`).
        edges_axis = _axis_coverage(found, np.vstack([normal[seen & ~shade.unknown], shade.normal]))
    coverage = float(outer_near.mean()) if len(outer_near) else float(near.mean())
    axis = _axis_coverage(outer_near, outer_normal) if len(outer_near) else _axis_coverage(near, normal)
    return _EdgeFit(pose=p, coverage=coverage, axis_coverage=axis, found=float(found.mean()) if len(found) else 0.0,
                    rms_px=rms, edges_axis=edges_axis if light is not None else 0.0,
                    cost=float(sol.cost), jac=sol.jac[inliers][:, :3], residuals=sol.fun[inliers],
                    hidden=float(1.0 - seen.mean()), bloom_px=bloom, samples=pts[inliers], light=light)


def _pulled(model: MeshEdges, points: np.ndarray, normal: np.ndarray, target: np.ndarray, spill: np.ndarray,
            start: np.ndarray):
    """One round's least-squares fit (soft-L1) of ``q = (x, y, yaw, bloom)`` [m, m, rad, px] from ``start``: each
    model edge sample (part-frame ``points`` (k, 3) [m]) onto its found edge ``target`` (k, 2) [px] along its
    image ``normal`` (k, 2), less the bloom on the clipped ones (``spill`` (k,): +-1 towards a clipped side,
    else 0) [px]. Returns scipy's result over all four (``x``, ``fun``, ``jac``, ``cost``).

    The Jacobian is the projection's own (finite differences took four projections per step). Without a
    clipped edge the bloom is no parameter: held at its bound (0) it slowed every step of the bounded
    solver (about 19 evaluations a fit), so x, y and yaw are fitted alone and unbounded.
    """

    def residuals(q: np.ndarray) -> np.ndarray:
        uv = model.camera.project(model.world(q[:3], points), model.rvec, model.tvec)
        return np.einsum("nj,nj->n", uv - target, normal) - (q[3] * spill if len(q) > 3 else 0.0)

    def jacobian(q: np.ndarray) -> np.ndarray:
        by_pose = np.einsum("nj,njk->nk", normal, model.placed(q[:3], points)[1])
        return np.column_stack([by_pose, -spill]) if len(q) > 3 else by_pose

    if spill.any():
        return least_squares(residuals, start, jac=jacobian, x_scale=np.array([1e-3, 1e-3, 1e-2, 1.0]),
                             bounds=([-np.inf] * 3 + [0.0], [np.inf] * 3 + [4.0]), xtol=FIT_XTOL, ftol=FIT_XTOL,
                             method="trf", loss="soft_l1", f_scale=ROBUST_SCALE_PX)
    sol = least_squares(residuals, start[:3], jac=jacobian, x_scale=np.array([1e-3, 1e-3, 1e-2]), xtol=FIT_XTOL,
                        ftol=FIT_XTOL, method="trf", loss="soft_l1", f_scale=ROBUST_SCALE_PX)
    sol.x = np.r_[sol.x, start[3]]
    sol.jac = np.column_stack([sol.jac, np.zeros(len(sol.jac))])
    return sol


#: The edge fit's steps stop below this share of the pose (x, y, yaw [m, rad]: a fraction of a micrometre)
#: and of the cost (unitless).
FIT_XTOL = 1e-6


def _dark_edges(model: MeshEdges, p: np.ndarray, light: np.ndarray | None) -> np.ndarray:
    """``(n,)`` bool over the model's samples: visible at pose ``p`` and dark on both sides under the key
    light ``light`` (none without one), so a picture cannot show them."""
    unknown = np.zeros(len(model.points), bool)
    if light is not None:
        idx = model.visible(p)
        eye, towards = model.in_part_frame(p, light)
        unknown[idx] = unseen_edges(model.field, model.points[idx], model.n1[idx], model.n2[idx], eye, towards)
    return unknown


def _axis_coverage(near: np.ndarray, normal: np.ndarray) -> float:
    """Share of edge samples found, in the worse of the two main directions of their image normals.

    A long part's sides fix it across its length only; its ends alone fix it along. Counted
    together, the sides hide missing ends, and a pose slid along the part by a few millimetres
    still finds 80 % of its outline. Each sample counts towards both directions by the square of
    its normal's component along them (unitless, 0..1).
    """
    if len(near) == 0:
        return 0.0
    _, axes = np.linalg.eigh(normal.T @ normal)
    weight = (normal @ axes) ** 2  # (k, 2): each sample's share in each direction
    found = near.astype(float) @ weight
    return float(np.min(found / np.maximum(weight.sum(axis=0), 1e-12)))


def locate_parts(image: np.ndarray, camera: CameraModel, base_camera: np.ndarray, part: Footprint,
                 tray_z: float, options: LocateOptions = LocateOptions(), *, source: str = "image"
                 ) -> list[LocatedPart]:
    """Every copy of ``part`` lying on the tray in one image, best score first.

    1. Tray model: the picture over a smooth model of the empty tray (:func:`tray_ratio`), so
       vignetting and uneven light cancel; what departs from it, brighter (metal, glare) or
       darker (walls, shadows), makes the candidate blobs.
    2. Coarse search per blob: the mesh's visible edges (:class:`vision.mesh_edges.MeshEdges`: top outline,
       steps, bosses at their real heights) against the distance map of the picture's edges,
       every 10 deg of yaw, then every degree and pixel near the best three (:func:`vision.locate_search.refine_start`).
    3. Edge fit: each visible model edge looks along its image normal for the nearest edge of
       the picture (sub-pixel gradient peak), and x, y, yaw are fitted to them (soft-L1), in
       rounds of narrowing search. A shadow has edges too, but not the model's shape; a wall as
       bright as the tray leaves its crease with the top face, which the model has as well.
    4. Judge: the share of the outline's edges the picture has within a pixel (``score``) must
       reach ``options.min_coverage``, in both main edge directions ``options.min_axis_coverage``,
       and of all visible edges ``options.min_found``, else no pose is given for the blob; with
       no pose at all, the VisionError gives the best candidate's reason.

    Parameters
    ----------
    image : (h, w) or (h, w, 3) uint8
        The picture, taken by ``camera`` (same size as its calibration).
    camera : CameraModel
    base_camera : (4, 4) float
        ``T_base_cam`` of the picture (translation [m]).
    part : Footprint
        With its mesh (:func:`footprint_from_mesh`); a bare footprint is located as its prism.
    tray_z : float
        Height of the tray plane in the base frame [m].

    Raises
    ------
    VisionError
        (``source``) Not an 8-bit image, a size other than the camera's, a camera not above the tray, or no part found.
    """
    grey = grey_picture(image, source)
    if (grey.shape[1], grey.shape[0]) != camera.image_size:
        w, h = camera.image_size
        raise VisionError(f"image is {grey.shape[1]}x{grey.shape[0]} px, the camera was calibrated at {w}x{h} px",
                          source=source)
    base_camera = np.asarray(base_camera, dtype=np.float64)
    cam_base = np.linalg.inv(base_camera)
    cam_pos = base_camera[:3, 3]
    if cam_pos[2] <= tray_z + part.height:
        raise VisionError(f"camera is at z {cam_pos[2]:.3f} m, not above the parts on the tray "
                          f"(z {tray_z:.3f} m + {part.height:.3f} m)", source=source)
    if len(part.faces) == 0:
        part = _prism_mesh(part)
    # The search's steps and the judgement's "within a pixel" are in pixels: a fine camera is
    # searched and judged on its binned picture, about as coarse as the cell camera's, and each
    # pose is then refined on the full picture (:func:`_refined`).
    if (binning := int(SEARCH_PIXEL_M / ((cam_pos[2] - tray_z) / np.sqrt(camera.fx * camera.fy)))) >= 2:
        return [_refined(p, grey, camera, base_camera, part, tray_z, binning, options.refine) for p in
                locate_parts(bin_image(grey, binning), binned_camera(camera, binning), base_camera, part, tray_z,
                             options, source=source)]
    ratio, spread = tray_ratio(grey)
    log_ratio = np.log(ratio)
    level = max(2.5 * spread, options.min_contrast)
    gx, gy, threshold = gradients(grey)
    edges = (np.hypot(gx, gy) > threshold).astype(np.uint8)
    # Clipped pixels (glare) say only "at least this bright": where an edge lies in them is unknown (``hidden``).
    saturated = (grey >= SATURATED_GREY).astype(np.uint8)
    # Candidates: what departs from the tray, or is dense with edges (a top face as bright as the tray).
    fg = ((np.abs(log_ratio) > level) | (edges > 0)).astype(np.uint8)
    fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, np.ones((2, 2), np.uint8))
    fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, np.ones((9, 9), np.uint8))
    fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, np.ones((5, 5), np.uint8))
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(fg, connectivity=8)
    maps, hidden = oriented_distances(gx, gy, thin := thin_edges(gx, gy, edges)), hidden_by_glare(saturated)
    model = edge_model(part, camera, cam_base, tray_z)
    f, (w, h) = np.sqrt(camera.fx * camera.fy), camera.image_size
    top_area = Polygon(part.outline).area
    radius_px = 0.5 * float(np.ptp(part.outline, axis=0).max()) * f / (cam_pos[2] - tray_z)

    def ground(pixel: np.ndarray) -> np.ndarray:
        ray = base_camera[:3, :3] @ camera.rays(pixel[None])[0]
        return cam_pos[:2] + (tray_z - cam_pos[2]) / ray[2] * ray[:2]

    found: list[LocatedPart] = []
    refusals: list[str] = []
    for i in np.argsort(-stats[1:, cv2.CC_STAT_AREA]) + 1:
        bx, by, bw, bh, area = stats[i]
        ray = base_camera[:3, :3] @ camera.rays(centroids[i][None])[0]
        if ray[2] >= 0:
            continue
        depth = (tray_z + part.height - cam_pos[2]) / ray[2]
        expected = top_area * camera.fx * camera.fy / depth ** 2
        if area < (least := options.min_area_ratio * expected):
            log.info("blob of %d px at (%.0f, %.0f) px: expected at least %.0f px, left out", area, *centroids[i], least)
            continue
        if any(np.hypot(p.pixel[0] - centroids[i][0], p.pixel[1] - centroids[i][1]) < radius_px for p in found):
            continue
        box = (max(bx, 0), max(by, 0), min(bx + bw, w), min(by + bh, h))
        starts, spare = chamfer_starts(model, edges, _hull(labels == i), box, ground(centroids[i]), ground, maps,
                                       spare=LIT_SPARE, hidden=hidden)
        light = lights_at(model, starts, log_ratio, box)
        best = _best_fit(model, gx, gy, threshold, starts, part.symmetry, saturated, thin, light, options,
                         lambda spare=spare: refined_starts(model, maps, spare, ground, hidden))
        if best is None:
            log.info("blob at (%.0f, %.0f) px: no edge fit", *centroids[i])
            continue
        refusal = _refusal(best, options)
        if refusal:
            refusals.append(f"candidate at ({centroids[i][0]:.0f}, {centroids[i][1]:.0f}) px: {refusal}")
            log.info("blob at (%.0f, %.0f) px: %s", *centroids[i], refusal)
            continue
        located = _located(best, model, camera, base_camera, part, tray_z, f,
                           glare=options.refine and light is None and bool(saturated.any()))
        if any(np.hypot(p.x - located.x, p.y - located.y) < 0.5 * radius_px * located.mm_per_px * 1e-3
               for p in found):
            continue
        found.append(replace(located, outline=blob_outline(log_ratio, (labels == i).astype(np.uint8), level)))
    if not found:
        # The best refused candidate says why: a wrong pose never leaves here, a reason does.
        why = f"; {refusals[0]}" if refusals else "; nothing on the tray departs from it like a part"
        raise VisionError("no part found on the tray (check the tray height, the extrinsics and the part file)"
                          + why, source=source)
    return sorted(found, key=lambda p: -p.score)


def _hull(blob: np.ndarray) -> np.ndarray:
    """``(h, w)`` bool: the convex hull of a blob (``blob`` (h, w) bool), where the coarse search puts the part.

    Under a low light a part's lit top can be as grey as the tray and show few edges: the blob is its
    shadow and its outline, and the point under the part's centroid lies outside it (a stepped wall's
    coarse starts then all lay 15-70 mm off, on the shadow's stepped edge). The hull holds it.
    """
    hull = np.zeros(blob.shape, np.uint8)
    cv2.fillConvexPoly(hull, cv2.convexHull(cv2.findNonZero(blob.astype(np.uint8))), 1)
    return hull > 0


#: Slides of a fitted pose along each main direction of the outline, refitted from (:func:`_slid`) [m].
SLIDES_M = (-3e-3, -1.5e-3, 1.5e-3, 3e-3)
#: ... and under a key light [m] ...
LIT_SLIDES_M = (-1.5e-3, 1.5e-3)
#: ... and when the first fit under a key light was refused (:func:`_best_fit`) [m]: a stepped wall whose fit
#: stopped 0.75 mm along itself, its outline seen across at 0.42, came back from 1.5 mm either way onto the
#: same wrong place; from 0.75 mm back it found 0.56.
LIT_RETRY_SLIDES_M = (-1.5e-3, -0.75e-3, 0.75e-3, 1.5e-3)
#: ... of which the shorter, for a first fit that passes fixed across its outline by its other edges (:func:`_best_fit`) [m].
LIT_SHORT_SLIDES_M = (-0.75e-3, 0.75e-3)


def _best_fit(model: MeshEdges, gx: np.ndarray, gy: np.ndarray, threshold: float, starts: list[np.ndarray],
              symmetry: int, saturated: np.ndarray | None = None, thin: np.ndarray | None = None,
              light: LightAt | None = None, options: LocateOptions = LocateOptions(),
              spare: Callable[[], list[np.ndarray]] | None = None) -> _EdgeFit | None:
    """The edge fit of one blob from its coarse starts (x, y [m], yaw [rad]); None when none converges.
    ``light``: the key light's unit direction (base frame) at each pose (:class:`vision.key_light.LightAt`),
    None for diffuse light. Every start is fitted under the light estimated at the first (:func:`_fitted`);
    only when that fit is refused are they fitted again, with the ``spare`` starts (more of the coarse
    search's), each under the light its own pose explains, and slid 0.75 mm as well
    (:data:`LIT_RETRY_SLIDES_M`): a low light's long shadow can win the first starts, and the light
    estimated at a wrong pose leaves out the wrong edges (vision/key_light.py). A fit that passes is
    not refitted, so its pose stays the one the first light gave. A first fit whose outline is seen along one
    direction only, fixed across it by its other edges alone (:attr:`_EdgeFit.edges_axis`), is slid 0.75 mm as
    well (:data:`LIT_SHORT_SLIDES_M`): a low-light stepped wall came back from 0.75 mm off (beyond its +-0.74 mm)."""
    known = _BlobFits()  # the fits made, for the second try
    best = _fitted(model, gx, gy, threshold, starts, symmetry, saturated, thin, light and light.first, options,
                   known=known)
    if light is None or spare is None or (best is not None and not _refusal(best, options, outline_axis=True)):
        return best
    if best is not None and not _refusal(best, options):
        # Fixed across its outline by its other edges alone: slid the second try's shorter way, not fitted again
        # from every start (a second try cost such pictures 0.6-1 s more).
        return _with_stray(model, _slid(model, gx, gy, threshold, best, saturated, LIT_SHORT_SLIDES_M), thin)
    again = _fitted(model, gx, gy, threshold, starts + spare(), symmetry, saturated, thin, light, options,
                    LIT_RETRY_SLIDES_M, known)
    if again is not None and not _refusal(again, options, outline_axis=True):
        return again
    # The second try's first: its starts and lights are the wider search.
    return next((fit for fit in (again, best) if fit is not None and not _refusal(fit, options)), best)


def _fitted(model: MeshEdges, gx: np.ndarray, gy: np.ndarray, threshold: float, starts: list[np.ndarray],
            symmetry: int, saturated: np.ndarray | None, thin: np.ndarray | None, light: LightAt | np.ndarray | None,
            options: LocateOptions, slides: tuple[float, ...] = LIT_SLIDES_M, known: _BlobFits | None = None
            ) -> _EdgeFit | None:
    """:func:`_best_fit` under one light (``light``: a unit direction, base frame, or one per pose; None
    without a key light): the fit chosen among the starts and turns (:func:`_chosen_fit`) slid along the
    outline (:func:`_slid`, under a key light by ``slides`` [m]), and in even light (no key light, nothing
    clipped) settled (:func:`_settled`, ``options.refine``); ``known``: the blob's fits made already."""
    best = _chosen_fit(model, gx, gy, threshold, starts, symmetry, saturated, thin, light, options.min_coverage,
                       known)
    if best is None or best.ambiguous:
        return best
    # The second try's slides rescue a fit that stopped beside the part (:data:`LIT_RETRY_SLIDES_M`); one that passes
    # is not slid (on the gallery no slide of the second try moved a fit, and the eight fits cost 0.3 s).
    if slides != LIT_RETRY_SLIDES_M or _refusal(best, options, outline_axis=True):
        best = _slid(model, gx, gy, threshold, best, saturated, slides)
    best = _with_stray(model, best, thin)
    even = light is None and (saturated is None or not saturated.any())
    return _settled(model, gx, gy, threshold, best, options) if options.refine and even else best


def _slid(model: MeshEdges, gx: np.ndarray, gy: np.ndarray, threshold: float, best: _EdgeFit,
          saturated: np.ndarray | None, lit_slides: tuple[float, ...] = LIT_SLIDES_M) -> _EdgeFit:
    """``best``, or a fit started from it slid along the outline's main directions (:data:`SLIDES_M`)
    that shows clearly more of the part (:attr:`_EdgeFit.evidence`, :data:`SLIDE_GAIN`).

    A fit can settle on a look-alike a few millimetres along the part: a stepped wall slid along its
    length with its ends faint (2-2.5 mm, its outline seen along one direction only), an L turned about
    its upright onto the lit edge of its base under a low light (1.6 mm, 2 deg). The slides reach the
    pose that shows more of the part. Only a fit that nearly passes and whose outline is weakly seen
    along one direction is slid (the slides cost some 8 edge fits), and not in glare: a clipped top
    blooms over the walls, and a slid dome found more of its blooming outline 2 mm off.
    """
    if (best.hidden > AMBIGUOUS_HIDDEN or best.coverage < SLIDE_COVERAGE
            or best.axis_coverage >= SLIDE_AXIS_COVERAGE or max(best.axis_coverage, best.edges_axis) < SLIDE_ACROSS):
        return best
    # Under a key light the edges dark on both sides at the fitted pose are left out of every slide (the
    # same ones, found once), and each slide's judgement counts the cast shadow: some 8 times the cost
    # of a fit without a light, so there the slides go 1.5 mm each way at most (:data:`LIT_SLIDES_M`).
    light = best.light  # the slides are judged under the light ``best`` was
    dark = _dark_edges(model, best.pose, light) if light is not None else None
    r = yaw_rotation(best.pose[2])
    fits = [best]
    for axis in model.axes.T:
        for d in SLIDES_M if light is None else lit_slides:
            start = best.pose + np.r_[r @ axis * d, 0.0]
            fit = _edge_fit(model, gx, gy, threshold, start, SEARCH_PX[-2:], saturated, light, dark)
            if fit is not None and fit.hidden <= AMBIGUOUS_HIDDEN:
                fits.append(fit)
    slid = max(fits, key=lambda fit: fit.evidence)
    # Neighbouring poses find nearly the same edges: a slide must show clearly more to move the pose
    # (a plate with bosses went from 0.28 to 0.69 mm off for 0.02 more).
    return slid if slid.evidence > best.evidence + SLIDE_GAIN else best


def _settled(model: MeshEdges, gx: np.ndarray, gy: np.ndarray, threshold: float, best: _EdgeFit,
             options: LocateOptions) -> _EdgeFit:
    """The chosen fit in even light settled (:func:`_edge_fit` ``settle``): refitted from its pose with the
    walls' feet that took their tops' edges out and rounds until the edges stop moving; ``best`` when
    the settled fit would be refused (the judgement is ``best``'s to make, settling only refines).

    Only the chosen pose: settling every start and turn changed which fit was chosen and turned a dim
    plate with bosses 0.87 mm off (against 0.28 mm). Inspection keeps the unsettled pose
    (:attr:`LocateOptions.refine`): its defects' depths were measured against it.
    """
    if _refusal(best, options):
        return best
    settled = _edge_fit(model, gx, gy, threshold, best.pose, SEARCH_PX[-1:], settle=True)
    return best if settled is None or _refusal(settled, options) else settled


#: A settling fit (:func:`_settled`) repeats its last round while the model's edges move more than
#: this in the picture [px] ...
SETTLED_PX = 0.1
#: ... this many times at most.
EXTRA_ROUNDS = 3
#: A wall's foot whose found edge lies this close to its top's edge took the top's (settling only) [px].
TOOK_TOP_PX = 0.5
#: Only a fit that finds at least this share of its outline ... (unitless)
SLIDE_COVERAGE = 0.4
#: ... and less than this in the outline's worse direction is slid (unitless) ...
SLIDE_AXIS_COVERAGE = 0.75
#: ... but at least this across it, in its outline or (under a key light) all its edges (unitless): no fit seen
#: across at less (every distractor's box, a low-light L beside its shadow) was ever brought to pass by a slide on
#: the benchmark (432 pictures, 373 slid fits: 30 below it, none passed slid; those that did were 0.38-0.47 across
#: before), and each such fit's slides cost 4-8 edge fits.
SLIDE_ACROSS = 0.3
#: Coarse starts beyond the best three that a blob under a key light is fitted from as well (a low light's
#: long shadow took the first three places of a stepped wall's coarse search; its fourth lay 1.5 mm off it).
LIT_SPARE = 3
#: A slide replaces the fit when its :attr:`_EdgeFit.evidence` is more by this (unitless, of 3; the
#: corrected L gained 0.07, the slid stepped walls 0.4-0.5).
SLIDE_GAIN = 0.05


def _chosen_fit(model: MeshEdges, gx: np.ndarray, gy: np.ndarray, threshold: float, starts: list[np.ndarray],
                symmetry: int, saturated: np.ndarray | None = None, thin: np.ndarray | None = None,
                light: LightAt | np.ndarray | None = None, min_coverage: float = LocateOptions.min_coverage,
                known: _BlobFits | None = None) -> _EdgeFit | None:
    """The edge fit of one blob from its coarse starts and the turns of the outline (see :func:`_best_fit`).
    ``min_coverage``: the share of the outline a reported pose finds (:attr:`LocateOptions.min_coverage`);
    ``known``: the fits made already for this blob."""
    known = _BlobFits() if known is None else known

    def fit_from(start: np.ndarray, reaches: tuple[float, ...] = SEARCH_PX) -> _EdgeFit | None:
        return known.fit(model, gx, gy, threshold, start, reaches, saturated, _light_at(light, start))

    fits = [fit for fit in (fit_from(s) for s in starts) if fit is not None]
    if not fits:
        return None
    # A symmetric outline fits turned as well as not: the edges inside it (steps, bosses) decide.
    first = max(fits, key=lambda fit: fit.found)
    turns = [first.pose + np.array([0.0, 0.0, 2 * np.pi * k / symmetry]) for k in range(1, symmetry)]
    # A first fit that misses most of its outline sits on a turn that does not fit, its yaw left
    # where the coarse search put it (a glare stepped wall's, 6 deg off): its turn is fitted from as
    # wide a reach as a start, else it stays those degrees off the part.
    reaches = SEARCH_PX if first.coverage < min_coverage else SEARCH_PX[-2:]
    fits += [fit for fit in (fit_from(t, reaches) for t in turns) if fit is not None]
    # A fit that leaves edges beside it unexplained lies beside the part or turned onto its shadow: the others
    # are chosen from while there are any (:mod:`vision.stray_edges`).
    fits = [_with_stray(model, fit, thin) for fit in fits]
    fits = [fit for fit in fits if fit.stray <= MAX_STRAY] or fits
    # Of the fits that find (nearly) as many edges as the best, the one that lies closest on them.
    most = max(fit.found for fit in fits)
    close = [fit for fit in fits if fit.found >= most - 0.05]
    best = min(close, key=lambda fit: fit.cost / max(len(fit.residuals), 1))
    # Glare hides the steps and bosses that tell a turn of the outline from the pose itself (and
    # the turn that hides more of them finds a larger share of the rest): when a turn that is no
    # symmetry of the mesh fits nearly as well, the choice is a guess, and a guess must not reach
    # the robot.
    # In glare the shares of all edges of different turns are not comparable (each hides other edges
    # inside the outline), so every turn fitted onto the same outline is a rival, unless it finds
    # clearly less of the outline itself, which always counts: a stepped part's outline at its real
    # heights tells the turns apart where its clipped top cannot (a turned stepped wall found 0.73 of
    # it against 0.99).
    glare = best.hidden > AMBIGUOUS_HIDDEN
    rivals = [fit for fit in fits if _turn(fit.pose[2] - best.pose[2], symmetry)
              and ((glare and np.hypot(*(fit.pose[:2] - best.pose[:2])) < SAME_OUTLINE_M
                    and fit.coverage >= best.coverage - AMBIGUOUS_SHARE)
                   or (fit.coverage >= best.coverage - AMBIGUOUS_SHARE and fit.found >= best.found - AMBIGUOUS_SHARE))
              and not model.same_turned(_turn(fit.pose[2] - best.pose[2], symmetry), symmetry)]
    if glare and rivals:
        # What the picture shows inside the outline may still tell them apart: the turn whose edges
        # explain clearly more of it is the part's, else the yaw is a guess.
        if thin is None:
            return replace(best, ambiguous=True)
        by_turn: dict[int, _EdgeFit] = {}
        for fit in sorted([best, *rivals], key=lambda fit: -fit.found):
            by_turn.setdefault(_turn(fit.pose[2] - best.pose[2], symmetry), fit)
        bloom = max(fit.bloom_px for fit in by_turn.values())
        told = sorted(((explained_inside(model, fit.pose, thin, bloom), turn) for turn, fit in by_turn.items()), reverse=True)
        log.info("turns of the outline explain %s of the edges inside it", [round(e, 2) for e, _ in told])
        if told[0][0] - told[1][0] < TURN_MARGIN:
            return replace(best, ambiguous=True)
        return by_turn[told[0][1]]
    return best


@dataclass
class _BlobFits:
    """The edge fits made for one blob (:func:`_edge_fit`), each by its start, reaches and light: the second try
    (:func:`_best_fit`) starts again from the first's starts, and where the light estimated at a start is the
    first's (a distractor's box: all of them) the fit is the same. Only for one blob's picture and model."""

    made: dict[tuple[bytes, tuple[float, ...], bytes | None], _EdgeFit | None] = field(default_factory=dict)

    def fit(self, model: MeshEdges, gx: np.ndarray, gy: np.ndarray, threshold: float, start: np.ndarray,
            reaches: tuple[float, ...], saturated: np.ndarray | None, light: np.ndarray | None) -> _EdgeFit | None:
        """:func:`_edge_fit` from ``start`` under ``light``, made once."""
        key = (np.asarray(start, np.float64).tobytes(), tuple(reaches), None if light is None else light.tobytes())
        if key not in self.made:
            self.made[key] = _edge_fit(model, gx, gy, threshold, start, reaches, saturated, light)
        return self.made[key]


def _with_stray(model: MeshEdges, fit: _EdgeFit, thin: np.ndarray | None) -> _EdgeFit:
    """``fit`` with its stray edges (:attr:`_EdgeFit.stray`) counted under the key light it was judged under
    (``thin``: the picture's edges, :func:`vision.locate_search.thin_edges`); as it is without a light."""
    if fit.light is None or thin is None:
        return fit
    return replace(fit, stray=stray_edges(model, fit.pose, fit.light, thin))


def _light_at(light: LightAt | np.ndarray | None, pose: np.ndarray) -> np.ndarray | None:
    """The key light (unit (3,), base frame) a fit from ``pose`` is judged under: one for every pose, or
    the one estimated at it (:class:`vision.key_light.LightAt`)."""
    return light(pose) if isinstance(light, LightAt) else light


def _turn(dyaw: float, symmetry: int) -> int:
    """Which of the outline's symmetric turns (0..symmetry-1) a yaw difference [rad] is nearest."""
    return int(np.rint(((dyaw % (2 * np.pi)) / (2 * np.pi / symmetry)))) % symmetry


def _refusal(fit: _EdgeFit, options: LocateOptions, outline_axis: bool = False) -> str:
    """Why a fit is not confident enough to report, or '' when it is; ``outline_axis``: the outline alone must be
    seen across (:attr:`LocateOptions.min_axis_coverage`), not fixed by the other edges under a key light."""
    if fit.ambiguous:
        return (f"the outline fits turned as well, and {100 * fit.hidden:.0f} % of the edges that tell the turns "
                "apart are hidden in glare: the yaw is not fixed")
    if fit.coverage < options.min_coverage:
        return (f"the part's outline is not there ({100 * fit.coverage:.0f} % of its edges found, "
                f"{100 * options.min_coverage:.0f} % needed)")
    # Under a key light the edges inside the outline and the shadow's may fix what the faint lit outline does not.
    if fit.axis_coverage < options.min_axis_coverage and (outline_axis or fit.edges_axis < options.min_axis_coverage):
        inside = f", {100 * fit.edges_axis:.0f} % of all its edges" if fit.light is not None else ""
        return (f"the outline is seen along one direction only ({100 * fit.axis_coverage:.0f} % across it{inside}, "
                f"{100 * options.min_axis_coverage:.0f} % needed): the position along it is not fixed")
    if fit.found < options.min_found:
        return (f"the steps, bosses and holes inside the outline are not there ({100 * fit.found:.0f} % of all "
                f"edges found, {100 * options.min_found:.0f} % needed): the pose may be turned or shifted")
    if fit.rms_px > options.max_rms_px:
        return f"the edges fit loosely (RMS {fit.rms_px:.2f} px, {options.max_rms_px:.2f} px allowed)"
    if fit.stray > MAX_STRAY:
        return (f"edges beside the fit that neither the part nor its shadow explains ({100 * fit.stray:.0f} % of its "
                f"outline, {100 * MAX_STRAY:.0f} % allowed): the part may lie turned or beside it")
    return ""


def _located(fit: _EdgeFit, model: MeshEdges, camera: CameraModel, base_camera: np.ndarray, part: Footprint,
             tray_z: float, f: float, glare: bool = False) -> LocatedPart:
    """The fitted pose as a LocatedPart, with an uncertainty that covers the true error (see COVERAGE_FACTOR
    and :func:`vision.pose_uncertainty.pose_covariance`). In ``glare`` (the walls' feet left the fit) the
    pose is drawn in towards the point under the camera by :data:`GLARE_WALL_SHIFT` of the walls' seen width."""
    p = fit.pose.copy()
    metres_per_px = (np.linalg.inv(base_camera) @ np.array([*p[:2], tray_z + 0.5 * part.height, 1.0]))[2] / f
    if glare:
        out = p[:2] - base_camera[:2, 3]
        p[:2] -= GLARE_WALL_SHIFT * model.feet_width(p) * metres_per_px * out / max(float(np.linalg.norm(out)), 1e-9)
    idx = model.visible(fit.pose)
    unresolved = np.isin(fit.samples, idx[model.unresolved(*model.project(fit.pose, idx), idx)])
    cov = pose_covariance(fit.jac, fit.residuals, model.edge[fit.samples], unresolved, CORRELATED_SAMPLES)
    middle = np.linalg.inv(base_camera) @ np.array([p[0], p[1], tray_z + 0.5 * part.height, 1.0])
    half_length = 0.5 * float(np.ptp(part.outline, axis=0).max())
    # A bloom spills unevenly (parallax, parts of the outline not clipped): a share of it counts as
    # edge bias as well.
    bias_m = float(np.hypot(EDGE_BIAS_PX, BLOOM_BIAS * fit.bloom_px)) * metres_per_px
    sigma_xy = COVERAGE_FACTOR * float(np.hypot(np.sqrt(np.linalg.eigvalsh(cov[:2, :2]).max()), bias_m))
    sigma_yaw = COVERAGE_FACTOR * float(np.hypot(np.sqrt(cov[2, 2]), bias_m / half_length))
    pixel = camera.project(middle[None, :3], np.zeros(3), np.zeros(3))[0]
    return LocatedPart(x=float(p[0]), y=float(p[1]), z=float(tray_z), yaw=float(np.angle(np.exp(1j * p[2]))),
                       score=fit.coverage, rms_px=fit.rms_px, mm_per_px=float(metres_per_px * 1e3),
                       sigma_xy=sigma_xy, sigma_yaw=sigma_yaw, pixel=(float(pixel[0]), float(pixel[1])))


#: In glare a pose lies outward from the point under the camera by this share of its walls' seen width
#: (:meth:`vision.mesh_edges.MeshEdges.feet_width`, on the tray) (unitless). With the feet out of the fit
#: the tops carry the outline, and a clipped top blooms over the walls the camera sees from the side
#: (those turned to its axis) more than the fitted common bloom: the slope of the outward error on the
#: width over the glare tuning seeds 0-4 (29 poses, correlation 0.56) was 0.142. A plate with bosses
#: (stacked walls: 2-3.6 px of them per outline sample) 137 mm off the axis lay 0.83 mm out, 0.49 after.
GLARE_WALL_SHIFT = 0.142
#: A camera whose pixel on the tray is smaller than half this is searched on its binned picture, with
#: pixels of about this size [m] (the cell camera's 0.82 mm; 0.58 mm for the 5 MP camera, 4 x 4).
SEARCH_PIXEL_M = 6e-4


def _refined(coarse: LocatedPart, grey: np.ndarray, camera: CameraModel, base_camera: np.ndarray, part: Footprint,
             tray_z: float, binning: int, refine: bool = True) -> LocatedPart:
    """A pose found on the ``binning`` x ``binning`` binned picture, refined on the full picture ``grey``.

    The edge fit starts from the coarse pose (within a binned pixel or so) and runs its narrowing
    rounds on the full picture; the pose, RMS and uncertainty are then the full picture's. A fit that
    wanders further than a binned pixel from its start found other edges: the coarse pose stands.
    The judgement (score, refusals) is the binned picture's. ``refine``: a glare pose's outward shift
    is taken off (:func:`_located`), as :attr:`LocateOptions.refine`.
    """
    model = edge_model(part, camera, np.linalg.inv(base_camera), tray_z)
    gx, gy, threshold = gradients(grey)
    start = np.array([coarse.x, coarse.y, coarse.yaw])
    fit = _edge_fit(model, gx, gy, threshold, start, saturated=(grey >= SATURATED_GREY).astype(np.uint8))
    outline = (coarse.outline + 0.5) * binning - 0.5  # binned pixel centres on the full picture
    if fit is None or np.hypot(*(fit.pose[:2] - start[:2])) > coarse.mm_per_px * 1e-3:
        return replace(coarse, outline=outline)
    glare = refine and bool(grey.max() >= SATURATED_GREY)
    fine = _located(fit, model, camera, base_camera, part, tray_z, np.sqrt(camera.fx * camera.fy), glare)
    return replace(fine, score=coarse.score, outline=outline)


def _prism_mesh(part: Footprint) -> Footprint:
    """A bare footprint's prism as a closed mesh (mesh coordinates [m]), for the edge model."""
    poly = Polygon(part.outline + part.centroid)
    mesh = trimesh.creation.extrude_polygon(poly, part.height)
    mesh.apply_translation([0.0, 0.0, part.zmin])
    return replace(part, vertices=np.asarray(mesh.vertices), faces=np.asarray(mesh.faces))
