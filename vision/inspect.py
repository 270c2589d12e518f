"""Inspection: does the part in the picture have the edges its mesh says it should, where it says?

The part is located on the tray first (:func:`vision.locate.locate_parts`: the mesh's visible
edges fitted to the picture's, with locate's refusals). A part locate cannot place confidently is
not judged: its pose could be wrong, and so would the verdict; the refusal and its reason come
back instead (:class:`factory.core.errors.VisionError`).

At the located pose every visible edge of the mesh (its outline at every height, steps, bosses,
holes) is looked for in the picture along its image normal, as locate looks for it: gradient
peaks across the edge (:func:`vision.picture_edges.edge_peaks`). Edges are judged by what light cannot
fake, and never by a threshold of brightness (a side wall as bright as the tray, a shadow darker
than it, a clipped highlight moved such an outline by millimetres):

- **The outline**, where a face turned up meets the side (the top edge of each wall and step; at
  a wall's foot the tray may lie in the part's own shadow, as dark as the wall). Every sample,
  signed outward: the picture's edge within :data:`OWN_PX` of the expected one (inside it: there,
  a narrow wall's blur pushes it in), else the nearest edge along the normal out to ``reach``
  (a burr) or in to ``depth`` (a broken corner) that no other expected edge explains, else
  unseen. Each is taken against the level of its straight line (the pose's error and the blur
  shift a whole side alike; a burr or a broken corner only a stretch of it), and the deviation is
  the median over ``window`` along the outline, so one noisy sample neither passes nor fails a part:
  material sticking out (+) or missing (-). A whole side off by less than ``reach`` is not seen.
  A narrow wall turned to the camera shows as one band about the top edge: one polarity of its two
  sides is taken along each side. A side with no edge at its place takes the level the pose's
  error fitted to the other sides gives it (:func:`_pose_level`).
- **The outline's grey profile**: a burr moves the top edge by about a pixel, often beside a
  stronger wall edge it does not move, which the peaks follow. Each sample's whole profile across
  the edge is compared with the median profile of the rest of its side (shifted, with the greys'
  level and contrast free: a shadow along the side), and the shift against the side's trend,
  a median over ``window``, is extra material (:func:`_profile_shift`); only on sides whose
  contrast stands well above the picture's noise and texture.
- **Features inside it** (each set of connected mesh edges: a hole, a boss, a pocket): the share
  of the feature's visible edges the picture shows within :data:`OWN_PX`. A feature whose edges
  are nearly all absent is missing (a hole not drilled, a boss not there); its deviation is the
  whole ``reach`` (its edges are at least that far from where they should be). With
  ``judge_from_above`` a feature seen from straight above (its walls edge-on) is judged by all its
  edges and by each loop of its creases on its own (a through-hole's foot, where the tray shows
  through, when its rim lies beside a counterbore's floor; not a wall's foot, which soft light shades); one whose edges mostly show is there. Edges found where the mesh puts them say *there* whatever hides the rest; a
  through-hole's rim is judged from every side (straight down a hole its wall is seen edge-on),
  and white over it in glare is material where the hole should be
  (:func:`vision.inspect_features.judge_features`).

An edge beyond the own one says *defect* only when the greys agree (:mod:`vision.inspect_material`):
between the line and a burr's edge lies something like the part's face, between the line and a
broken corner's edge something like the tray; a shadow's or a boss's edge, or the far side of a
lit rim, leave a band like neither. Glare (a clipped highlight) hides an edge only where it lies
on both sides of it (a pocket in a white top), but on the outline of a top in glare white on both
sides is white where the tray should be: material as white as the top (a burr's lip), judged by the
edge where it ends; beside one side the edge shows, pushed out by the optics' spill (the bloom),
which the side's level absorbs like a pose error. Deep shadow on both
sides (well below the tray model) hides an edge as well.

When too little of the outline or a feature can be judged the part is refused with the reason,
not passed; but with its top in glare (pockets hidden in the white, the rest in sharp contrast) a
window of its outline or a feature off by more than the tolerance fails it all the same.
Otherwise it passes when no window of its outline and no feature is off by more than the tolerance. The thresholds were set on
``benchmarks/inspect_real_light.py``'s pictures (seeds 0-1).
A pass says nothing of a burr narrower than the picture resolves (:attr:`Inspection.smallest_burr`:
1.85 mm at the cell camera's 0.82 mm per pixel, so its 1 mm burrs may pass); each verdict states it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np
import shapely
from scipy.ndimage import map_coordinates
from scipy.spatial import cKDTree
from shapely.geometry import MultiPolygon, Polygon

from factory.core.errors import VisionError
from vision.camera import CameraModel
from vision.inspect_features import BESIDE_PX, Feature, SeenEdges, judge_features
from vision.inspect_material import OWN_PX, defect_edge
from vision.inspect_options import InspectOptions
from vision.inspect_view import FRAME_PX, unseen
from vision.locate import SATURATED_GREY, Footprint, LocatedPart, grey_picture, locate_parts, mm_to_m
from vision.mesh_edges import MeshEdges, edge_model
from vision.picture_edges import edge_peaks, gradients, peak_offset, tray_ratio
from vision.shadow import DARK_LOG

#: A picture edge this close to another expected edge is that edge, not a defect [px].
EXPLAINED_PX = 1.0
#: Edges within this of a clipped pixel are unknown, and a clipped face's spill reaches this far [px].
GLARE_PX = 3
#: An edge with deep shadow this far on both sides cannot show [px].
SHADOW_SIDE_PX = 2.5
#: Share of the part's silhouette clipped white from which its top is in glare (0..1).
TOP_GLARE = 0.3
#: Outline samples this close to a corner of the footprint are not judged [m].
CORNER_M = 1.5e-3
#: A short line of the outline takes the level of the fitted lines this close [m] (:func:`_line_level`).
NEIGHBOUR_M = 5e-3
#: A wall this wide in the picture [px] or narrower shows as one band with the top edge (:func:`_wall_width`).
NARROW_WALL_PX = 1.0
#: Grey profiles across the outline are compared over this span either side of the edge [px].
SHIFT_SPAN_PX = 3.0
#: A side's grey profile is compared when it spans this many times the picture's edge threshold:
#: below it the tray's texture and the light along a low-contrast side move it by most of a pixel
#: (set on benchmarks/inspect_real_light.py seeds 0-1: good parts' sides read up to 0.72 mm at 5.2).
SHIFT_CONTRAST = 5.5
#: A profile is the line's when its contrast is at least this share of the line's median profile's ...
SHIFT_GAIN = 0.35
#: ... and what the shifted median profile leaves is at most this share of that contrast (RMS): a
#: highlight along the rim changes the profile's shape, not where it lies, and a fit that leaves 0.1-0.15
#: read a good dim plate's side 1 px out (seed 5); burrs' shifted profiles fit within 0.1 (seeds 8-9).
SHIFT_RESIDUAL = 0.10
#: A side's trend of profile shifts is fitted to those within this of it: a burr's stretch lies further [px].
SHIFT_BAND_PX = 0.5
#: A window of the outline runs along one side: samples whose edge turns more than this from its own are another side's [deg].
SIDE_TURN_DEG = 20.0
#: ... as the cosine between their directions (unitless).
_SIDE_TURN_COS = np.cos(np.radians(SIDE_TURN_DEG))
#: Outline edges whose direction is steeper than this are the part's vertical corners: no outward side.
_STEEP = 0.7
#: The sides a level is fitted to fix the pose's error (:func:`_pose_level`) when the least singular value of
#: its derivatives, each scaled to unit length, is at least this share of the largest (unitless).
FIXED_POSE_SV = 0.05
#: Good parts' outlines read up to this much extra material [px] (benchmarks/inspect_real_light.py, every
#: light: 0.54 mm = 0.65 px at the cell camera's 0.82 mm/px, seeds 0-1 and 8-9; 0.19 mm = 1.37 px at 5 MP's
#: 0.14, seeds 0-1, a low-angle bracket's grey profile): the noise a burr's reading must clear the
#: tolerance by (:attr:`Inspection.smallest_burr`), the larger of the two cameras' in pixels.
GOOD_SPREAD_PX = 1.4


@dataclass(frozen=True)
class Inspection:
    """The result of inspecting one part.

    Attributes
    ----------
    part : LocatedPart
        Where the part was found.
    outline_px : (n, 2) float
        The expected outline's edge samples in the image [px].
    deviation : (n,) float
        Signed deviation of the outline there, a median over ``InspectOptions.window`` (positive
        outside the expected outline: extra material, a burr; negative inside: missing material);
        NaN where the picture does not show enough of the outline to tell [m].
    features : tuple of Feature
        The features inside the outline, and whether each is there.
    reach : float
        Deviation counted for a missing feature [m].
    silhouette_px : (m, 2) float
        The expected silhouette, closed ring, in (distorted) image coordinates [px].
    tolerance : float
        [m]
    refusal : str
        Why the part is not judged ('' when it is): too little of its outline or of a feature shows
        (unless its top is in glare and what does show is out of tolerance: then it fails).
    hidden : str
        What could not be judged (glare, an edge lost in shadow), also when the part fails on what
        shows ('' when everything was judged).
    excess : (n,) float or None
        Extra material outside the outline from the grey profile across it, a median over
        ``InspectOptions.window`` like ``deviation`` (:func:`_profile_shift`: a burr moves the top
        edge, often beside a stronger wall edge it does not move); NaN where a side's profile
        cannot tell [m].
    smallest_burr : float
        The narrowest extra material along the outline (a burr's lip) this picture resolves at the
        part [m]; a narrower one may pass. A lip within :data:`OWN_PX` of the top edge is taken for
        that edge (its reading shrinks with the blur), and a reading must clear the tolerance by the
        noise of good parts' (:data:`GOOD_SPREAD_PX`): the larger of the two, in metres at the
        part's pixel size. The cell camera (0.82 mm/px) promises 1.85 mm, not the 1 mm burr it
        catches in 3 of 4 pictures; the 5 MP camera (0.14 mm/px) 0.90 mm.
    """

    part: LocatedPart
    outline_px: np.ndarray
    deviation: np.ndarray
    features: tuple[Feature, ...]
    reach: float
    silhouette_px: np.ndarray
    tolerance: float
    refusal: str = ""
    hidden: str = ""
    excess: np.ndarray | None = None
    smallest_burr: float = 0.0

    @property
    def missing_features(self) -> tuple[Feature, ...]:
        return tuple(f for f in self.features if not f.present)

    @property
    def profile_excess(self) -> float:
        """Largest extra material the outline's grey profiles show (0 when none) [m]."""
        if self.excess is None:
            return 0.0
        return float(np.clip(self.excess[np.isfinite(self.excess)], 0.0, None).max(initial=0.0))

    @property
    def max_deviation(self) -> float:
        """Largest absolute deviation of the outline (its edges or its profile's extra material) or of
        a feature (a missing one: ``reach``) [m]."""
        seen = np.abs(self.deviation[np.isfinite(self.deviation)])
        return max(float(seen.max(initial=0.0)), self.profile_excess, self.reach if self.missing_features else 0.0)

    @property
    def passed(self) -> bool:
        """Whether the part was judged and its outline and every feature are within the tolerance."""
        return not self.refusal and self.max_deviation <= self.tolerance

    def to_dict(self) -> dict:
        """JSON-ready summary (deviations in mm, as machinists read them)."""
        d = self.deviation[np.isfinite(self.deviation)] * 1e3
        return {"pass": self.passed, "refusal": self.refusal, "hidden": self.hidden,
                "tolerance_mm": self.tolerance * 1e3,
                "max_deviation_mm": self.max_deviation * 1e3,
                "p95_deviation_mm": float(np.percentile(np.abs(d), 95)) if len(d) else 0.0,
                "excess_mm": float(max(d.max(initial=0.0), 0.0)),
                "profile_excess_mm": self.profile_excess * 1e3,
                "missing_mm": float(max(-d.min(initial=0.0), 0.0)),
                "outline_seen": float(np.isfinite(self.deviation).mean()) if len(self.deviation) else 0.0,
                "smallest_burr_mm": self.smallest_burr * 1e3,
                "missing_features": [{"pixel": list(f.pixel), "found": f.found} for f in self.missing_features],
                "pose": self.part.to_dict()}


def part_transform(part: Footprint, located: LocatedPart) -> np.ndarray:
    """``T_base_part`` (mesh in metres → base frame) of a located part [m]."""
    c, s = np.cos(located.yaw), np.sin(located.yaw)
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    t = np.eye(4)
    t[:3, :3] = rz
    t[:3, 3] = np.array([located.x, located.y, located.z]) - rz @ np.r_[part.centroid, part.zmin]
    return t


def expected_silhouette(vertices_mm: np.ndarray, faces: np.ndarray, cam_part: np.ndarray) -> Polygon:
    """The projected silhouette of a mesh in the normalised image plane (x/z, y/z).

    Parameters
    ----------
    vertices_mm : (n, 3) float
        Mesh vertices [mm] (converted with :func:`vision.locate.mm_to_m`).
    faces : (m, 3) int
    cam_part : (4, 4) float
        ``T_cam_part`` [m].

    Raises
    ------
    VisionError
        Part (partly) behind the camera.
    """
    v = mm_to_m(np.asarray(vertices_mm, dtype=np.float64)) @ cam_part[:3, :3].T + cam_part[:3, 3]
    if (v[:, 2] <= 1e-6).any():
        raise VisionError("part is (partly) behind the camera")
    uv = v[:, :2] / v[:, 2:3]
    tri = uv[np.asarray(faces, dtype=np.int64)]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    cross = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    # A closed mesh's front faces alone cover its silhouette; skip back faces and slivers.
    keep = np.abs(cross) > 1e-14
    front = keep & (cross > 0)
    tri = tri[front if front.sum() >= keep.sum() // 4 else keep]
    shape = shapely.union_all(shapely.polygons(np.concatenate([tri, tri[:, :1]], axis=1))).buffer(1e-9)
    if isinstance(shape, MultiPolygon):
        shape = max(shape.geoms, key=lambda g: g.area)
    return Polygon(shape.exterior)


def inspect_part(image: np.ndarray, camera: CameraModel, base_camera: np.ndarray, part: Footprint,
                 vertices_mm: np.ndarray, faces: np.ndarray, tray_z: float,
                 options: InspectOptions = InspectOptions(), *, source: str = "image") -> list[Inspection]:
    """Inspect every copy of the part on the tray (best located first).

    Parameters
    ----------
    image, camera, base_camera, part, tray_z
        As :func:`vision.locate.locate_parts` (``base_camera`` = ``T_base_cam`` [m], ``tray_z`` [m]).
    vertices_mm, faces
        The part mesh [mm] whose edges are expected.

    Raises
    ------
    VisionError
        As :func:`vision.locate.locate_parts` with ``options.locate`` (bad image, or no part located
        confidently, with the reason): a part locate refuses is refused here too, never judged at a
        pose that may be wrong.
    """
    found = locate_parts(image, camera, base_camera, part, tray_z, options.locate, source=source)
    grey = grey_picture(image, source)
    gx, gy, threshold = gradients(grey)
    saturated = (grey >= SATURATED_GREY).astype(np.uint8)
    # Deep shadow (well below the tray model): an edge with it on both sides cannot show.
    dark = (np.log(tray_ratio(grey)[0]) < DARK_LOG).astype(np.uint8)
    cam_base = np.linalg.inv(np.asarray(base_camera, dtype=np.float64))
    mesh = replace(part, vertices=mm_to_m(np.asarray(vertices_mm, dtype=np.float64)),
                   faces=np.asarray(faces, dtype=np.int64))
    model = edge_model(mesh, camera, cam_base, tray_z)  # once per mesh: its feet are asked for once
    out = []
    for located in found:
        sil = expected_silhouette(vertices_mm, faces, cam_base @ part_transform(part, located))
        ring = np.array(sil.exterior.coords)
        ring_px = camera.project(np.column_stack([ring, np.ones(len(ring))]), np.zeros(3), np.zeros(3))
        out.append(_judge(model, part, located, grey, (gx, gy, threshold), (saturated, dark), options, ring_px))
    return out


def _judge(model: MeshEdges, part: Footprint, located: LocatedPart, grey: np.ndarray,
           gradients: tuple[np.ndarray, np.ndarray, float], masks: tuple[np.ndarray, np.ndarray],
           options: InspectOptions, ring_px: np.ndarray) -> Inspection:
    """The inspection of one located part: its outline's windowed deviations and its features
    (``grey`` the picture, ``gradients`` its ``gx, gy, threshold`` as :func:`vision.picture_edges.gradients`,
    ``masks`` its clipped pixels and its deep shadow, uint8 1/0, ``ring_px`` its expected silhouette)."""
    gx, gy, threshold = gradients
    saturated = masks[0]
    inside = np.zeros_like(saturated)
    cv2.fillPoly(inside, [np.rint(ring_px).astype(np.int32).reshape(-1, 1, 2)], 1)
    # Glare on the top: a good share of the part's silhouette clipped white (not a lit wall's band).
    top_glare = saturated[inside > 0].mean() >= TOP_GLARE if inside.any() else False
    p = np.array([located.x, located.y, located.yaw])
    idx = model.visible(p)
    uv, normal = model.project(p, idx)
    px_m = located.mm_per_px * 1e-3  # metres per pixel at the part
    steps, resp, peak = edge_peaks(gx, gy, threshold, uv, normal, max(options.reach, options.depth) / px_m)
    offset = np.where(peak, steps[None, :], np.nan)
    unknown, bloom, white, cause = _hidden(model, p, idx, uv, normal, masks, top_glare)
    # The outline is judged where a face turned up meets the side (the top of a wall, a step): the
    # part's own face lies inside. At a wall's foot the tray beside it may lie in the part's own
    # shadow, and the wall may be as dark as that shadow; no edge there says anything.
    up = np.maximum(model.n1[idx, 2], model.n2[idx, 2]) > 0.5
    outer = model.outer[idx] & (np.abs(model.direction[idx, 2]) < _STEEP) & up & \
        ~_near_corner(part.outline, model.points[idx, :2])
    sign = np.ones(len(idx))
    sign[outer] = _outward(model, part, p, idx[outer], uv[outer], normal[outer])
    # With the top in glare, an outline edge white on both sides past the spill has white where the
    # tray should be: material as white as the top (a burr's lip), judged by the edge where it ends.
    unknown[outer] &= ~white[outer]
    lo = -OWN_PX - GLARE_PX * bloom[:, 1]
    hi = OWN_PX + GLARE_PX * bloom[:, 0]
    # A wall turned to the camera shows beyond its top edge out to its foot: a narrow one as one
    # band whose far side the blur pushes just beyond OWN_PX, so the own edge is looked for that
    # much further out (up to NARROW_WALL_PX, not out to a wide wall's foot).
    width = _wall_width(model, p, idx[outer], uv[outer], normal[outer] * sign[outer, None])
    wall = np.clip(width, 0.0, NARROW_WALL_PX)
    lo[outer] -= np.where(sign[outer] < 0, wall, 0.0)
    hi[outer] += np.where(sign[outer] > 0, wall, 0.0)
    # The own edge: the strongest peak within OWN_PX. Where two edges lie that close (a lit rim,
    # a narrow wall's two sides) the nearer one flips from sample to sample with the noise; the
    # stronger one stays the same along a side, and the side's level absorbs where it lies.
    near = np.where(peak & (steps[None, :] >= lo[:, None]) & (steps[None, :] <= hi[:, None]), resp, -np.inf)
    own_j = np.argmax(near, axis=1)
    own = np.isfinite(near[np.arange(len(idx)), own_j])
    # On the outline the two are a narrow wall's sides (a lit wall under a low light: bright between
    # a greyer top and tray) of opposite polarity: along each straight side, the polarity its
    # samples show stronger on average is taken, so the level does not flip between them.
    line, along = _lines(model.points[idx[outer]], model.direction[idx[outer]])
    rising = _rising(gx, gy, uv[outer], normal[outer] * sign[outer, None], steps * sign[outer, None])
    own_j[outer] = _one_polarity(near[outer], rising, line)
    # Peaks further out that lie on another expected edge are that edge: they say nothing here.
    spots = uv[:, None, :] + np.nan_to_num(offset)[..., None] * normal[:, None, :]
    dist, _ = cKDTree(uv).query(spots.reshape(-1, 2), distance_upper_bound=EXPLAINED_PX)
    explained = np.isfinite(dist.reshape(peak.shape))
    # Beyond the own window, out to ``reach`` (a burr; shadows lie further out) or in to ``depth`` (a
    # broken corner), an edge is a defect's unless it is another expected edge (then the material is
    # there up to it) and only if what lies between is the other side's: the part's face out to a
    # burr's edge, the tray in to a broken corner's (vision.inspect_material.defect_edge).
    out_steps = steps[None, :] * sign[:, None]
    beyond = peak & ((steps[None, :] < lo[:, None]) | (steps[None, :] > hi[:, None])) & \
        (out_steps <= options.reach / px_m) & (out_steps >= -options.depth / px_m) & ~unknown[:, None]
    measured = np.where(own & ~unknown, peak_offset(steps, resp, own_j), np.nan)
    signed = sign[outer] * measured[outer]
    # An edge within OWN_PX inside the expected one is there: a narrow wall between the top and the
    # tray blurs into one dark band whose two edges the blur pushes apart by up to a pixel.
    signed = np.where(own[outer] & (signed < 0), 0.0, signed)
    # Against the rest of its own straight edge: the pose's error (a few tenths of a millimetre)
    # and the blur of a narrow wall shift a whole side alike, a burr or a broken corner only a stretch.
    pose_cols = _pose_columns(model, p, idx[outer], uv[outer], normal[outer] * sign[outer, None])
    level = _line_level(model.points[idx[outer]], model.direction[idx[outer]], np.where(own[outer], signed, np.nan),
                        rigid=lambda lv, fitted: _pose_level(pose_cols, lv, fitted),
                        foot=width)
    found, over = defect_edge(grey, uv[outer], normal[outer] * sign[outer, None], steps, sign[outer], resp[outer],
                              beyond[outer], explained[outer], level, threshold, line, own[outer], own_j[outer],
                              silhouette=width <= 0.0)
    signed = np.where(own[outer] & ~over, signed, found) - level
    deviation = _windowed(model.points[idx[outer]], signed, options.window, model.direction[idx[outer]]) * px_m
    # Extra material along the outline from the whole grey profile across it (a burr moves the top
    # edge by a pixel, often beside a stronger wall edge it does not move, which the peaks follow).
    shift = _profile_shift(grey, uv[outer], normal[outer] * sign[outer, None], line, along, threshold, options.window)
    shift[(unknown | white)[outer]] = np.nan  # a clipped profile has no shape to compare
    # A feature's edge within the compared span (a hole 2.5 mm inside the outline) is not the side's.
    inside_uv = uv[~model.outer[idx]]
    if len(inside_uv):
        shift[cKDTree(inside_uv).query(uv[outer])[0] < SHIFT_SPAN_PX + 1.0] = np.nan
    # Each shift is against the rest of its side already: the trend (a yaw error tilting the side)
    # starts at 0, not at the median, which a burr along half a short side would be.
    trend = _line_level(model.points[idx[outer]], model.direction[idx[outer]], shift, band=SHIFT_BAND_PX, start=0.0)
    excess = _windowed(model.points[idx[outer]], shift - trend, options.window, model.direction[idx[outer]]) * px_m

    features = []
    refusals = []
    seen = float(np.isfinite(deviation).mean()) if len(deviation) else 0.0
    if seen < options.min_seen:
        refusals.append(f"{100 * seen:.0f} % of the outline can be judged, {100 * options.min_seen:.0f} % needed")
    # How often the picture's texture alone puts an edge within OWN_PX of a spot: beside each sample,
    # BESIDE_PX either way (1.0 or 0.0; NaN where another expected edge lies near the spot: that one's).
    tree = cKDTree(uv)
    beside = np.stack([np.where(tree.query(uv + c * normal)[0] <= OWN_PX + EXPLAINED_PX, np.nan,
                                (peak & (np.abs(steps[None, :] - c) <= OWN_PX)).any(axis=1))
                       for c in (BESIDE_PX, -BESIDE_PX)], axis=1)
    features, hidden_features = judge_features(SeenEdges(model=model, pose=p, idx=idx, uv=uv, own=own, unknown=unknown,
                                                         cause=cause, beside=beside, top_glare=top_glare,
                                                         clipped=saturated), options)
    refusals += hidden_features
    hidden = "; ".join(refusals)
    judged = Inspection(part=located, outline_px=uv[outer], deviation=deviation, features=tuple(features),
                        reach=options.reach, silhouette_px=ring_px, tolerance=options.tolerance, hidden=hidden,
                        excess=excess, smallest_burr=max(OWN_PX * px_m, options.tolerance + GOOD_SPREAD_PX * px_m))
    # Glare on the top hides pockets in the white, but the rest shows in sharp contrast: what shows
    # and fails, fails the part. Otherwise (low-angle light: lit walls, a hole's wall clipped) what
    # is hidden may be what misleads the rest: no verdict, with the reason.
    fails = top_glare and judged.max_deviation > options.tolerance
    return judged if fails or not hidden else replace(judged, refusal=hidden)


def _clipped_sides(saturated: np.ndarray, uv: np.ndarray, normal: np.ndarray, top_glare: bool
                   ) -> tuple[np.ndarray, np.ndarray]:
    """How glare lies about each edge sample: ``unknown`` (k,) bool, the edge cannot show, and
    ``bloom`` (k, 2) bool, the side against the image ``normal`` (column 0) or along it (column 1)
    is clipped and the edge shows, pushed by the optics' spill into the other side.

    With ``top_glare`` (the part's top mirrors the light: broad white faces) the sides are looked
    at just beyond the bloom (:data:`GLARE_PX` + 1 and + 2 px): clipped on both (a pocket in a
    white top) is unknown, on one the edge shows. Otherwise a clipped pixel within
    :data:`GLARE_PX` of the edge (a lit wall's narrow band, a rim's highlight, low-angle light)
    leaves where the edge lies untold: unknown.
    """
    def clipped(t: float, dilated: np.ndarray = saturated) -> np.ndarray:
        q = uv + t * normal
        return map_coordinates(dilated, [q[:, 1], q[:, 0]], order=0, mode="nearest") > 0

    if not top_glare:
        dilated = cv2.dilate(saturated, np.ones((2 * GLARE_PX + 1, 2 * GLARE_PX + 1), np.uint8))
        return clipped(0.0, dilated), np.zeros((len(uv), 2), bool)
    side = np.zeros((len(uv), 2), bool)
    for col, sign in enumerate((-1.0, 1.0)):
        for t in (GLARE_PX + 1, GLARE_PX + 2):
            side[:, col] |= clipped(sign * t)
    unknown = side.all(axis=1)
    return unknown, side & ~unknown[:, None]


def _hidden(model: MeshEdges, p: np.ndarray, idx: np.ndarray, uv: np.ndarray, normal: np.ndarray,
            masks: tuple[np.ndarray, np.ndarray], top_glare: bool
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Which edge samples ``idx`` at pose ``p`` (``uv``, ``normal`` (k, 2) in the image) the picture
    cannot show (``masks`` its clipped pixels and deep shadow): ``unknown`` (k,) bool, ``bloom`` (k, 2)
    as :func:`_clipped_sides`, ``white`` (k,) bool those unknown only for glare on both sides, and
    ``cause`` (k,) int why each is unknown (a key of :data:`vision.inspect_features.HIDDEN_BY`; 0 where it is not)."""
    # A clipped highlight on both sides of an edge (a pocket in a white top) hides it: unknown,
    # neither found nor missed. On one side only, the edge shows, pushed into the other side by
    # the optics' spill (the bloom, up to GLARE_PX): its own edge is looked for that much further.
    saturated, dark = masks
    clipped, bloom = _clipped_sides(saturated, uv, normal, top_glare)
    # Deep shadow on both sides (a hole at the foot of a counterbore under a low light) hides an
    # edge as glare does: unknown, not missing.
    shadowed = _both_sides(dark, uv, normal, SHADOW_SIDE_PX)
    # Beyond the picture, or an outline edge behind the part's own taller faces: unknown, as glare is.
    out_of_view = unseen(model, p, idx, uv, normal, dark.shape, OWN_PX + FRAME_PX)
    unknown = shadowed | out_of_view
    white = clipped & ~unknown if top_glare else np.zeros(len(idx), bool)
    cause = np.select([out_of_view, shadowed, clipped], [3, 2, 1], 0)
    return unknown | clipped, bloom, white, cause


def _both_sides(mask: np.ndarray, uv: np.ndarray, normal: np.ndarray, t: float) -> np.ndarray:
    """``(k,)`` bool: ``mask`` (h, w) uint8 is set ``t`` [px] along and against each edge sample's image normal."""
    both = np.ones(len(uv), bool)
    for step in (-t, t):
        q = uv + step * normal
        both &= map_coordinates(mask, [q[:, 1], q[:, 0]], order=0, mode="nearest") > 0
    return both


def _profile_shift(grey: np.ndarray, uv: np.ndarray, outward: np.ndarray, line: np.ndarray, along: np.ndarray,
                   contrast: float, window: float) -> np.ndarray:
    """``(k,)`` how far outward [px] each outline sample's grey profile across its edge lies from the
    median profile of the rest of its straight ``line`` (k,) int: the least-squares shift over
    :data:`SHIFT_SPAN_PX` either side, whatever the profile's shape (a silhouette's step, a narrow lit
    or dark wall's band). The rest is the line's samples more than ``window`` / 2 + 1 mm away along
    it (``along`` (k,) [m]), so a burr along half a short side is not its own reference (the whole
    line where fewer than 8 are). NaN on a line of fewer than 8 samples, whose median profile spans
    less than :data:`SHIFT_CONTRAST` times ``contrast`` (the picture's edge threshold [grey/px]: its
    noise and texture), or where the profile is not the line's.
    ``uv`` (k, 2) [px] and unit ``outward`` (k, 2).
    """
    t = np.arange(-SHIFT_SPAN_PX - 1.5, SHIFT_SPAN_PX + 1.5 + 1e-9, 0.25)
    q = uv[:, None, :] + t[None, :, None] * outward[:, None, :]
    profile = map_coordinates(grey.astype(np.float32), [q[..., 1].ravel(), q[..., 0].ravel()], order=1,
                              mode="nearest").reshape(q.shape[:2]).astype(np.float64)
    span = np.abs(t) <= SHIFT_SPAN_PX + 1e-9
    out = np.full(len(uv), np.nan)
    for e in np.unique(line):
        on = np.flatnonzero(line == e)
        if len(on) < 8:
            continue
        whole = np.median(profile[on], axis=0)
        apart = np.abs(along[on][:, None] - along[on][None, :]) > 0.5 * window + 1e-3
        apart[apart.sum(axis=1) < 8] = True
        ref = np.nanmedian(np.where(apart[..., None], profile[on][None, :, :], np.nan), axis=1)  # (n, t)
        slope = np.gradient(ref, t, axis=1)
        if np.ptp(whole[span]) < SHIFT_CONTRAST * contrast:
            continue
        seen = profile[on][:, span]
        d = np.zeros(len(on))
        for _ in range(10):  # Gauss-Newton on P(t) = a + b R(t - d): a shadow or the light along the side
            at = t[span][None, :] - d[:, None]  # changes the greys' level and contrast, not where the edge is
            r = _rows_interp(at, t, ref)
            g = _rows_interp(at, t, slope)
            rc = r - r.mean(axis=1, keepdims=True)
            b = np.sum(rc * (seen - seen.mean(axis=1, keepdims=True)), axis=1) / np.maximum(np.sum(rc * rc, axis=1), 1e-9)
            a = seen.mean(axis=1) - b * r.mean(axis=1)
            res = seen - a[:, None] - b[:, None] * r
            bg = b[:, None] * g
            d = np.clip(d - np.sum(res * bg, axis=1) / np.maximum(np.sum(bg * bg, axis=1), 1e-9), -SHIFT_SPAN_PX, SHIFT_SPAN_PX)
        # Where the profile is not the line's (its contrast a third or less, reversed, or another shape
        # left over), the shift says nothing.
        fits = (b > SHIFT_GAIN) & (np.sqrt(np.mean(res * res, axis=1)) < SHIFT_RESIDUAL * b * np.ptp(ref[:, span], axis=1))
        d[~fits] = np.nan
        out[on] = d
    return out


def _rows_interp(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """``(n, m)``: each row of ``fp`` (n, len(xp)), sampled on the increasing, evenly spaced ``xp``,
    linearly interpolated at that row of ``x`` (n, m) (held at the ends)."""
    pos = np.clip((x - xp[0]) / (xp[1] - xp[0]), 0, len(xp) - 1 - 1e-9)
    i = np.floor(pos).astype(int)
    w = pos - i
    rows = np.arange(len(fp))[:, None]
    return fp[rows, i] * (1 - w) + fp[rows, np.minimum(i + 1, len(xp) - 1)] * w


def _wall_width(model: MeshEdges, p: np.ndarray, idx: np.ndarray, uv: np.ndarray, outward: np.ndarray) -> np.ndarray:
    """``(k,)`` how far beyond each outline sample ``idx`` (at ``uv`` (k, 2) [px], ``outward`` (k, 2)
    unit) its wall's foot on the tray lies in the picture at pose ``p`` [px]: the wall shows that
    wide; at most 0 where it is turned away and the top edge is the silhouette."""
    pts = model.points[idx] * np.array([1.0, 1.0, 0.0])
    at = model.camera.project(model.world(p, pts), model.rvec, model.tvec)
    return np.einsum("nj,nj->n", at - uv, outward)


def _rising(gx: np.ndarray, gy: np.ndarray, uv: np.ndarray, outward: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """``(k, s)`` bool: the grey rises outward at each of the ``steps`` (k, s) [px] along each sample's
    normal from ``uv`` (k, 2) [px]; ``outward`` (k, 2) the unit image directions away from the part
    (the steps are taken along the normal, ``steps * outward`` alike)."""
    q = uv[:, None, :] + steps[..., None] * outward[:, None, :]
    coords = [q[..., 1].ravel(), q[..., 0].ravel()]
    g = map_coordinates(gx, coords, order=1, mode="nearest").reshape(q.shape[:2]) * outward[:, 0:1] + \
        map_coordinates(gy, coords, order=1, mode="nearest").reshape(q.shape[:2]) * outward[:, 1:2]
    return g > 0


def _one_polarity(near: np.ndarray, rising: np.ndarray, line: np.ndarray) -> np.ndarray:
    """``(k,)`` column of each outline sample's own edge: the strongest peak of ``near`` (k, s)
    (its strength, -inf where no peak lies within reach), but where peaks of both polarities lie
    there (``rising`` (k, s) bool: the grey rises outward), the strongest of the polarity that the
    samples of its straight ``line`` (k,) int with both show stronger on average."""
    rows = np.arange(len(near))
    up, down = np.where(rising, near, -np.inf), np.where(rising, -np.inf, near)
    j_up, j_down = np.argmax(up, axis=1), np.argmax(down, axis=1)
    s_up, s_down = up[rows, j_up], down[rows, j_down]
    j = np.argmax(near, axis=1)
    both = np.isfinite(s_up) & np.isfinite(s_down)
    for e in np.unique(line[both]):
        on = both & (line == e)
        j[on] = j_up[on] if s_up[on].mean() >= s_down[on].mean() else j_down[on]
    return j


def _pose_columns(model: MeshEdges, p: np.ndarray, idx: np.ndarray, uv: np.ndarray, outward: np.ndarray
                  ) -> np.ndarray:
    """``(k, 4)`` how far [px] along each outline sample's ``outward`` (k, 2) image direction (from ``uv``
    (k, 2) [px]) it moves per unit of one push common to every edge, and of the pose ``p``'s x, y [m] and
    yaw [rad]: made once per located part, as each side's level is asked of the rest (:func:`_pose_level`)."""
    cols = [np.ones(len(idx))]
    for k, eps in enumerate((1e-4, 1e-4, 1e-3)):  # [m, m, rad]: well within the fit's linear range
        q = p.copy()
        q[k] += eps
        cols.append(np.einsum("nj,nj->n", model.project(q, idx)[0] - uv, outward) / eps)
    return np.column_stack(cols)


def _pose_level(a: np.ndarray, level: np.ndarray, fitted: np.ndarray) -> np.ndarray | None:
    """``(k,)`` the offset [px] along each outline sample's outward image direction that a small error of
    the pose (x, y, yaw) and one push common to every edge (blur, bloom) give (``a`` (k, 4) their
    derivatives, :func:`_pose_columns`), fitted to the ``level`` (k,) [px] of the samples whose straight
    line the picture shows (``fitted`` (k,) bool); None where too few are, or where they do not fix the
    pose's error. A side whose edges lie beyond OWN_PX of the located pose (its yaw a little off) takes
    its level from the rest of the part, not from a neighbouring side's nor from none."""
    if fitted.sum() < 12:
        return None
    # The sides given must fix the pose's error: two parallel sides, or two that meet, leave a shift
    # (or a push against a shift) free, and the least-squares level elsewhere is then arbitrary. The
    # columns scaled alike, their least singular value is under 0.001 of the largest then, and 0.47-0.97
    # with three sides or more across both directions (the four sample parts at 5 MP).
    cols_unit = a[fitted] / np.maximum(np.linalg.norm(a[fitted], axis=0), 1e-12)
    sv = np.linalg.svd(cols_unit, compute_uv=False)
    if sv[-1] < FIXED_POSE_SV * sv[0]:
        return None
    use = fitted.copy()
    for _ in range(2):  # once more without the sides the first fit leaves more than OWN_PX off
        c = np.linalg.lstsq(a[use], level[use], rcond=None)[0]
        keep = fitted & (np.abs(a @ c - level) <= OWN_PX)
        if keep.sum() < 12:
            break
        use = keep
    return a @ c


def _outward(model: MeshEdges, part: Footprint, p: np.ndarray, idx: np.ndarray, uv: np.ndarray,
             normal: np.ndarray) -> np.ndarray:
    """``(k,)`` +1 or -1: the sign that turns each outline sample's image normal outward (away from the part)."""
    d = model.direction[idx, :2]
    n = np.column_stack([d[:, 1], -d[:, 0]]) / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    step = 3e-4  # [m]: well inside the thinnest wall, well beyond float noise
    probe = model.points[idx, :2] + step * n
    inside = shapely.contains_xy(Polygon(part.outline), probe[:, 0], probe[:, 1])
    n = np.where(inside[:, None], -n, n)
    pushed = model.camera.project(model.world(p, model.points[idx] + step * np.column_stack([n, np.zeros(len(n))])),
                                  model.rvec, model.tvec)
    return np.where(np.einsum("nj,nj->n", pushed - uv, normal) >= 0, 1.0, -1.0)


def _near_corner(outline: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``(k,)`` bool: points (x, y) [m] within :data:`CORNER_M` of a corner of the footprint ``outline``
    (a turn of more than 20 deg): along a normal there the picture has two edges blurred into one."""
    a, b = np.roll(outline, 1, axis=0), np.roll(outline, -1, axis=0)
    u, v = outline - a, b - outline
    turn = np.abs(np.arctan2(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0], np.einsum("ij,ij->i", u, v)))
    corners = outline[turn > np.radians(20.0)]
    if len(corners) == 0 or len(points) == 0:
        return np.zeros(len(points), bool)
    return cKDTree(corners).query(points)[0] < CORNER_M


def _lines(points: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(k,)`` int: which straight line of the outline each sample is on (collinear samples of the
    many mesh edges a straight side is triangulated into share one), and ``(k,)`` its place along
    it [m]; ``points`` [m] and unit ``direction`` (k, 3)."""
    angle = np.mod(np.arctan2(direction[:, 1], direction[:, 0]), np.pi)
    along = points[:, 0] * np.cos(angle) + points[:, 1] * np.sin(angle)  # [m]
    across = points[:, 1] * np.cos(angle) - points[:, 0] * np.sin(angle)  # the line's offset [m]
    key = np.column_stack([np.rint(np.degrees(angle)) % 180, np.rint(across / 5e-4), np.rint(points[:, 2] / 5e-4)])
    return np.unique(key, axis=0, return_inverse=True)[1].ravel(), along


def _line_level(points: np.ndarray, direction: np.ndarray, values: np.ndarray, least: int = 8,
                rigid: Callable[[np.ndarray, np.ndarray], np.ndarray | None] | None = None, band: float = OWN_PX,
                start: float | None = None, foot: np.ndarray | None = None) -> np.ndarray:
    """``(k,)`` the level of each sample's straight line at the sample: a straight line fitted to the
    finite ``values`` [px] along it (twice, the second time without those more than :data:`OWN_PX`
    off the one before, starting flat at their median). A line with fewer than ``least`` of them (an
    arc's many short chords, a short step) takes the median level of the fitted samples within
    :data:`NEIGHBOUR_M` (the sides it joins: a bloom or a pose shift moves them alike), else 0;
    with ``rigid`` (the levels of the pose's error fitted to those of the fitted lines, ``(level,
    fitted) -> (k,)`` or None, :func:`_pose_level`), a long side of ``least`` samples or more takes its
    level from there, as does a short one with no fitted neighbour, and a side fitted beyond ``band``
    of it is fitted again from it (a defect's stretch set it), unless it lies at its wall's ``foot``
    (k,) [px] outward (a wall turned to the camera shows that wide). Only values within ``band``
    [px] of the fit count, starting flat at ``start`` [px] (None: their median).

    A yaw error of the pose tilts a side's deviations, a shift moves them all: neither is the part's.
    The caller passes only the samples whose edge the picture shows at its place, so a defect's
    stretch does not set the level. ``points`` [m] and unit ``direction`` (k, 3): collinear samples
    of the many mesh edges a straight side is triangulated into share one line.
    """
    line, along = _lines(points, direction)
    out = np.zeros(len(values))
    fitted = np.zeros(len(values), bool)
    for e in np.unique(line):
        on = line == e
        s, v = along[on], values[on]
        ok = np.isfinite(v)
        if ok.sum() < least or np.ptp(s[ok]) < 1e-3:
            continue
        fit = np.array([0.0, np.median(v[ok]) if start is None else start])  # flat first: a stretch must not tilt it
        for _ in range(2):
            near = ok & (np.abs(np.polyval(fit, s) - np.nan_to_num(v, nan=np.inf)) <= band)
            if near.sum() < least:
                break
            fit = np.polyfit(s[near], v[near], 1)
        out[on] = np.polyval(fit, s)
        fitted[on] = True
    if not fitted.any():
        return out
    if rigid is not None:
        # A side whose own edges lie beyond ``band`` of the level the rest of the part's sides give it
        # was fitted to a defect's stretch, not to the side: a lip along most of a short side, or along
        # the only stretch of it that a lit wall clipped white beyond it does not hide, shows its inner
        # crease 2-2.5 px out, within the own window (held-out 5 MP low-angle stepped_wall 8, seeds 0-1
        # low-angle plate_bosses 1: the lip then read 0 mm). The rest, without the side: with it the
        # pose's error bends towards it (stepped_wall 8's 2.2 px side was given 0.8-1.2 px). Such a side
        # is fitted again from that level, to its samples within ``band`` of it, or takes it. Sides
        # farthest from the located pose first: two opposite sides disagree alike (either a lip on one
        # or a shift of the other), and locate fitted the pose to every edge, so a shift is the smaller.
        sides = np.unique(line[fitted])
        for e in sides[np.argsort([-np.abs(np.median(out[line == e])) for e in sides], kind="stable")]:
            on = line == e
            if not (fitted & ~on).any():
                continue
            others = rigid(out, fitted & ~on)
            # A wall turned to the camera a few pixels wide shows as one band: its foot may be the
            # side's edge (the exact renderer's stepped wall at the cell camera: 2.6 px out, its foot 2.9).
            if others is None or np.abs(out[on] - others[on]).min() <= band or \
                    (foot is not None and np.abs(out[on] - others[on] - foot[on]).min() <= band):
                continue
            s, v = along[on], values[on]
            near = np.abs(others[on] - np.nan_to_num(v, nan=np.inf)) <= band
            out[on] = np.polyval(np.polyfit(s[near], v[near], 1), s) if near.sum() >= least and \
                np.ptp(s[near]) >= 1e-3 else others[on]
    from_pose = rigid(out, fitted) if rigid is not None else None
    if fitted.all():
        return out
    # A long side the picture does not show at its place (its edge beyond OWN_PX: the located yaw
    # a little off) takes the level the rest of the part's sides give it, not a neighbouring side's.
    rest = ~fitted
    if from_pose is not None:
        long_side = np.bincount(line)[line] >= least
        out[rest & long_side] = from_pose[rest & long_side]
        rest &= ~long_side
    for i, near in zip(np.flatnonzero(rest), cKDTree(points[fitted]).query_ball_point(points[rest], NEIGHBOUR_M)):
        out[i] = np.median(out[fitted][near]) if near else (0.0 if from_pose is None else from_pose[i])
    return out


def _windowed(points: np.ndarray, values: np.ndarray, window: float, direction: np.ndarray | None = None
              ) -> np.ndarray:
    """``(k,)`` median of the finite ``values`` of the samples within ``window / 2`` of each point [m]
    (3D, so the top and the foot of a wall stay apart); NaN where fewer than half are finite.

    With ``direction`` (k, 3) (each sample's edge direction) whether a window tells is counted
    along the sample's own side: the samples whose direction is within :data:`SIDE_TURN_DEG` of
    its own (an arc's chords are, the side round a corner is not) must be at least 5 and half
    finite. Near a corner whose one side is hidden (a lit wall clipped white) the few samples of it
    that show must not borrow the other side's count; the median is still over the whole window.
    """
    out = np.full(len(points), np.nan)
    if len(points) == 0:
        return out
    flat = None
    if direction is not None:
        flat = np.asarray(direction, dtype=np.float64)[:, :2]
        flat = flat / np.maximum(np.linalg.norm(flat, axis=1, keepdims=True), 1e-12)
    for i, near in enumerate(cKDTree(points).query_ball_point(points, 0.5 * window)):
        v = values[near]
        ok = np.isfinite(v)
        told = ok
        if flat is not None:
            told = ok[np.abs(flat[near] @ flat[i]) >= _SIDE_TURN_COS]
        if ok.sum() >= 5 and ok.mean() >= 0.5 and told.sum() >= 5 and told.mean() >= 0.5:
            out[i] = np.median(v[ok])
    return out


def inspection_image(image: np.ndarray, inspections: list[Inspection]) -> np.ndarray:
    """The picture with the expected silhouette (blue), the outline coloured by deviation (green
    within tolerance, red beyond, grey unseen), missing features ringed red, and PASS/FAIL with the
    largest deviation per part.

    Returns
    -------
    (h, w, 3) uint8
        BGR picture.
    """
    img = np.asarray(image)
    canvas = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img.copy()
    h, w = canvas.shape[:2]
    for ins in inspections:
        ring = np.rint(ins.silhouette_px * 4).astype(np.int32)  # 2 fractional bits for a smooth line
        cv2.polylines(canvas, [ring.reshape(-1, 1, 2)], True, (255, 120, 0), 1, cv2.LINE_AA, shift=2)
        extra = ins.excess if ins.excess is not None else np.full(len(ins.deviation), np.nan)
        for (u, v), dev, more in zip(np.rint(ins.outline_px).astype(int), ins.deviation, extra):
            colour = (160, 160, 160) if not np.isfinite(dev) else \
                (0, 0, 255) if abs(dev) > ins.tolerance or more > ins.tolerance else (0, 200, 0)
            canvas[np.clip(v, 0, h - 1), np.clip(u, 0, w - 1)] = colour
        radius = max(int(round(3.0 / max(ins.part.mm_per_px, 1e-3))), 4)  # a ring about 6 mm across
        for f in ins.missing_features:
            cv2.circle(canvas, (int(round(f.pixel[0])), int(round(f.pixel[1]))), radius, (0, 0, 255), 2, cv2.LINE_AA)
        u, v = (int(round(c)) for c in ins.part.pixel)
        label = f"{'PASS' if ins.passed else 'FAIL'} {ins.max_deviation * 1e3:.2f} mm"
        cv2.putText(canvas, label, (u - 40, v), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(canvas, label, (u - 40, v), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (0, 200, 0) if ins.passed else (0, 0, 255), 1, cv2.LINE_AA)
    return canvas
