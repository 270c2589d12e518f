"""Find blanks or parts lying on a tray: position and yaw in the robot base frame from one image.

The part is a prism: its footprint (the XY outline of its mesh) extruded by its height, standing
on the tray plane ``z = tray_z`` of the base frame. The camera pose ``T_base_cam`` comes from the
hand-eye file.

1. Segment: the tray is the grey level class (Otsu) holding most of the image border; parts are
   the other class. Blobs touching the border or far from the part's expected image area are left out.
2. Outline: the sub-pixel iso-line (marching squares, :mod:`contourpy`) of each blob at the level
   halfway between the tray and the Otsu threshold, so dim side faces stay inside it.
3. Fit: the outline's pixels become viewing rays (distortion removed); the prism's silhouette in
   the normalised image plane is the convex hull of its projected corners (convex footprints) or
   the union of its projected faces (others). :func:`scipy.optimize.least_squares` fits x, y and
   yaw to minimise each outline point's distance to the silhouette boundary [px]; the starting
   yaw comes from the principal axes of the outline on the tray, tried in every symmetric variant.

The pose returned is ``T_base_part = Trans(x, y, z) Rz(yaw) Trans(-cx, -cy, -zmin)``: ``(cx, cy)`` is
the centroid of the mesh's footprint and ``zmin`` its lowest point (mesh coordinates), ``z`` the tray.
A footprint with symmetry (a rectangle: 180 deg) gives one of the equivalent yaws.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import cv2
import numpy as np
import shapely
from contourpy import LineType, contour_generator
from scipy.optimize import least_squares
from scipy.spatial import ConvexHull
from shapely.geometry import MultiPolygon, Polygon

from factory.core.errors import VisionError
from vision.camera import CameraModel

log = logging.getLogger(__name__)

#: Millimetres to metres; the one door through which CAM sizes enter vision.
MM_PER_M = 1000.0


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
    min_area_ratio, max_area_ratio : float
        A blob is a candidate when its area is within these factors of the part's top face
        projected at the blob (side faces add area; touching parts double it) (unitless).
    max_rms_px : float
        A fit whose outline misses the model silhouette by more RMS than this is rejected [px].
    border_px : int
        Blobs closer than this to the image border are cut off and left out [px].
    """

    min_area_ratio: float = 0.6
    max_area_ratio: float = 1.8
    max_rms_px: float = 1.5
    border_px: int = 2


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
    """

    outline: np.ndarray
    height: float
    centroid: np.ndarray
    zmin: float
    symmetry: int

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
    return Footprint(outline=outline, height=height, centroid=c, zmin=float(v[:, 2].min()),
                     symmetry=_symmetry(outline))


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
        Share of outline points within 1 px of the fitted silhouette times the area agreement (0..1).
    rms_px : float
        RMS distance of the outline to the fitted silhouette [px].
    mm_per_px : float
        Size of one pixel on the part at its distance [mm/px].
    sigma_xy : float
        1-sigma position uncertainty from the fit (larger axis) [m].
    sigma_yaw : float
        1-sigma yaw uncertainty from the fit [rad].
    pixel : (float, float)
        Where the part's centroid is in the image [px].
    outline : (n, 2) float
        The sub-pixel outline the pose was fitted to [px].
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


def _rz(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s], [s, c]])


def _grey(image: np.ndarray, source: str) -> np.ndarray:
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or min(img.shape[:2]) < 16:
        raise VisionError(f"not an 8-bit image of at least 16x16 pixels (shape {img.shape}, {img.dtype})",
                          source=source)
    if img.ndim == 3:
        return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    return img


class _Model:
    """The prism seen by the camera, in the normalised image plane (x/z, y/z)."""

    def __init__(self, part: Footprint, cam_base: np.ndarray, tray_z: float):
        self.part, self.tray_z = part, tray_z
        self.r, self.t = cam_base[:3, :3], cam_base[:3, 3]
        self.convex = part.convex

    def corners(self, p: np.ndarray) -> np.ndarray:
        """``(2, k, 3)`` bottom and top outline in the base frame [m]."""
        xy = self.part.outline @ _rz(p[2]).T + p[:2]
        k = len(xy)
        bottom = np.column_stack([xy, np.full(k, self.tray_z)])
        top = np.column_stack([xy, np.full(k, self.tray_z + self.part.height)])
        return np.stack([bottom, top])

    def silhouette(self, p: np.ndarray) -> np.ndarray:
        """``(m, 2)`` closed-ring vertices of the projected silhouette (normalised coordinates)."""
        c = self.corners(p) @ self.r.T + self.t
        if (c[..., 2] <= 1e-6).any():
            raise VisionError("part would be behind the camera")
        uv = c[..., :2] / c[..., 2:3]
        if self.convex:
            pts = uv.reshape(-1, 2)
            hull = pts[ConvexHull(pts).vertices]
            return np.vstack([hull, hull[:1]])
        b, t = uv
        k = len(b)
        quads = [Polygon([b[i], b[(i + 1) % k], t[(i + 1) % k], t[i]]) for i in range(k)]
        shape = shapely.union_all([Polygon(b), Polygon(t), *[q for q in quads if q.is_valid and q.area > 0]])
        if isinstance(shape, MultiPolygon):
            shape = max(shape.geoms, key=lambda g: g.area)
        return np.array(shape.exterior.coords)


def _distance_to_ring(points: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """``(n,)`` distance of each point to a closed polyline ``(m, 2)`` (same units)."""
    a, b = ring[:-1], ring[1:]
    ab = b - a
    ap = points[:, None, :] - a[None]
    t = np.clip(np.einsum("nmk,mk->nm", ap, ab) / np.maximum(np.einsum("mk,mk->m", ab, ab), 1e-30), 0, 1)
    d = ap - t[..., None] * ab[None]
    return np.sqrt(np.einsum("nmk,nmk->nm", d, d).min(axis=1))


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


def locate_parts(image: np.ndarray, camera: CameraModel, base_camera: np.ndarray, part: Footprint,
                 tray_z: float, options: LocateOptions = LocateOptions(), *, source: str = "image"
                 ) -> list[LocatedPart]:
    """Every copy of ``part`` lying on the tray in one image, best score first.

    Parameters
    ----------
    image : (h, w) or (h, w, 3) uint8
        The picture, taken by ``camera`` (same size as its calibration).
    camera : CameraModel
    base_camera : (4, 4) float
        ``T_base_cam`` of the picture (translation [m]).
    part : Footprint
    tray_z : float
        Height of the tray plane in the base frame [m].

    Raises
    ------
    VisionError
        (``source``) Not an 8-bit image, a size other than the camera's, a camera that does not
        look at the tray, or no part found.
    """
    grey = _grey(image, source)
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

    otsu, binary = cv2.threshold(grey, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    border = np.concatenate([binary[0], binary[-1], binary[:, 0], binary[:, -1]])
    bright = (border > 0).mean() < 0.5  # the tray is the class that fills the border
    tray_level = float(np.median(grey[binary == 0] if bright else grey[binary > 0]))
    level = 0.5 * (tray_level + otsu)
    fg = (grey > level) if bright else (grey < level)
    fg = cv2.morphologyEx(fg.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(fg, connectivity=8)

    model = _Model(part, cam_base, tray_z)
    found: list[LocatedPart] = []
    w, h = camera.image_size
    top_area = Polygon(part.outline).area
    for i in range(1, n):
        bx, by, bw, bh, area = stats[i]
        b = options.border_px
        if bx < b or by < b or bx + bw > w - b or by + bh > h - b:
            log.info("blob at (%d, %d) px touches the image border: left out", bx, by)
            continue
        ray = camera.rays(centroids[i][None])[0]
        ray_base = base_camera[:3, :3] @ ray
        if ray_base[2] >= 0:
            continue
        depth = (tray_z + part.height - cam_pos[2]) / ray_base[2]  # along the z = 1 ray: camera depth [m]
        expected = top_area * camera.fx * camera.fy / depth ** 2
        if not options.min_area_ratio * expected <= area <= options.max_area_ratio * expected:
            log.info("blob of %d px at (%.0f, %.0f) px: expected about %.0f px, left out", area, *centroids[i],
                     expected)
            continue
        outline = _subpixel_outline(grey, (labels == i).astype(np.uint8), level, bright)
        if outline is None:
            continue
        fit = _fit(camera, base_camera, model, outline, tray_z, part)
        if fit is None or fit.rms_px > options.max_rms_px:
            log.info("blob at (%.0f, %.0f) px does not fit the part outline", *centroids[i])
            continue
        found.append(fit)
    if not found:
        raise VisionError("no part found on the tray (check the tray height, the extrinsics and the part file)",
                          source=source)
    return sorted(found, key=lambda p: -p.score)


def _principal_yaw(points: np.ndarray) -> tuple[float, float]:
    """Direction of the major axis of a closed polygon's area [rad] and its anisotropy (0..1)."""
    m = cv2.moments(points.astype(np.float32))
    mu20, mu02, mu11 = m["mu20"], m["mu02"], m["mu11"]
    ang = 0.5 * np.arctan2(2 * mu11, mu20 - mu02)
    spread = np.hypot(2 * mu11, mu20 - mu02) / max(mu20 + mu02, 1e-30)
    return float(ang), float(spread)


def _fit(camera: CameraModel, base_camera: np.ndarray, model: _Model, outline: np.ndarray, tray_z: float,
         part: Footprint) -> LocatedPart | None:
    rays = camera.rays(outline)
    obs = rays[:, :2]
    # Starting point: the outline's rays on the plane halfway up the part.
    d = rays @ base_camera[:3, :3].T
    mid = tray_z + 0.5 * part.height
    lam = (mid - base_camera[2, 3]) / d[:, 2]
    on_plane = base_camera[:2, 3] + lam[:, None] * d[:, :2]
    # Relative to the mean and in mm, so cv2.moments (float32) keeps its precision.
    cxy = on_plane.mean(axis=0)
    local_mm = (on_plane - cxy) * 1e3
    obs_yaw, obs_spread = _principal_yaw(local_mm)
    part_yaw, part_spread = _principal_yaw(part.outline * 1e3)
    m = cv2.moments(local_mm.astype(np.float32))
    centre = cxy + (np.array([m["m10"], m["m01"]]) / m["m00"] * 1e-3 if m["m00"] else 0.0)
    base = obs_yaw - part_yaw
    # Principal axes fix yaw up to 180 deg; a nearly isotropic outline (a square) fixes nothing.
    steps = 2 if min(obs_spread, part_spread) > 0.05 else 8
    starts = [base + k * 2 * np.pi / steps for k in range(steps)]
    f = np.sqrt(camera.fx * camera.fy)

    def residuals(p: np.ndarray) -> np.ndarray:
        return f * _distance_to_ring(obs, model.silhouette(p))

    best = None
    for yaw in starts:
        try:
            sol = least_squares(residuals, np.r_[centre, yaw], x_scale=np.array([1e-3, 1e-3, 1e-2]),
                                diff_step=np.array([1e-5, 1e-5, 1e-5]), method="trf",
                                loss="soft_l1", f_scale=ROBUST_SCALE_PX)
        except VisionError:
            continue
        if best is None or sol.cost < best.cost:
            best = sol
    if best is None:
        return None
    p = best.x
    res = best.fun
    rms = float(np.sqrt(np.mean(res ** 2)))
    jtj = best.jac.T @ best.jac
    try:
        cov = np.linalg.inv(jtj) * max(rms, 0.05) ** 2  # never claim better than 0.05 px noise
    except np.linalg.LinAlgError:
        return None
    middle = np.linalg.inv(base_camera) @ np.array([p[0], p[1], tray_z + 0.5 * part.height, 1.0])
    metres_per_px = middle[2] / f  # camera depth of the part's middle over the focal length
    half_length = 0.5 * float(np.ptp(part.outline, axis=0).max())
    sigma_xy = float(np.hypot(np.sqrt(np.linalg.eigvalsh(cov[:2, :2]).max()), EDGE_BIAS_PX * metres_per_px))
    sigma_yaw = float(np.hypot(np.sqrt(cov[2, 2]), EDGE_BIAS_PX * metres_per_px / half_length))
    sil = model.silhouette(p)
    area_obs = Polygon(obs).area
    area_model = Polygon(sil).area
    agreement = min(area_obs, area_model) / max(area_obs, area_model) if area_obs > 0 else 0.0
    score = float(np.mean(np.abs(res) < 1.0) * agreement)
    pixel = camera.project(middle[None, :3], np.zeros(3), np.zeros(3))[0]
    yaw = float(np.angle(np.exp(1j * p[2])))
    return LocatedPart(x=float(p[0]), y=float(p[1]), z=float(tray_z), yaw=yaw, score=score, rms_px=rms,
                       mm_per_px=float(metres_per_px * 1e3), sigma_xy=sigma_xy, sigma_yaw=sigma_yaw,
                       pixel=(float(pixel[0]), float(pixel[1])), outline=outline)
