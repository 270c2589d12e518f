"""Camera steps of the simulated cell: a fixed camera over a station renders a part and runs the real vision on it.

A :class:`CameraStation` is a calibrated camera at a known pose over a flat surface (the stock
rack, the out-tray). For each part the cell takes, once, a picture of the raw blank to *locate*
it (:func:`locate_shot`) and pictures of the finished part to *inspect* it, good or with a corner
broken off (:func:`inspect_shot`). The pictures are rendered exactly (:func:`vision.render.render_mesh`,
the camera's distortion included, sensor noise added), or the blank's in real light
(:func:`vision.lit.render_lit`: aluminium, shadows, exposure, noise), and handed to the same
:func:`vision.locate.locate_parts` and :func:`vision.inspect.inspect_part` a real cell runs; the
wall time of that call is the step's processing time. Because the truth is known, each shot also
says how far the located pose is from where the part was put.

Units: metres and radians in the world frame (z up, the surface at ``plane_z``); meshes come in
millimetres from the CAM side and cross over through :func:`vision.locate.mm_to_m`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np
import trimesh
from shapely.geometry import Polygon
from trimesh.intersections import slice_mesh_plane

from factory.core.errors import VisionError
from vision.camera import CameraModel
from vision.handeye import invert
from vision.inspect import InspectOptions, inspect_part, inspection_image, part_transform
from vision.lit import TRAY_ALBEDO, Condition, key_light, metal, render_lit
from vision.locate import Footprint, LocatedPart, footprint_from_mesh, locate_parts, mm_to_m
from vision.render import PixelRays, look_at_pose, pixel_rays, render_mesh

#: Sub-pixel samples per pixel side of the rendered pictures.
SUPERSAMPLE = 3
#: Sensor noise of the rendered pictures [grey levels of 255].
NOISE_SIGMA = 2.0
#: Rays per pixel side of the pictures in real light (:func:`vision.lit.render_lit`; 2 as its test gallery).
LIT_SUPERSAMPLE = 2
#: A located part is where it was put when its position and yaw are within these [m], [rad].
LOCATE_TOLERANCE_M = 1e-3
LOCATE_TOLERANCE_RAD = float(np.radians(1.0))
#: Share of the footprint's width along each axis that :func:`cut_corner` cuts off (unitless).
CORNER_CUT = 0.18


@dataclass(frozen=True)
class CameraStation:
    """A fixed camera looking at a flat surface parts lie on.

    Attributes
    ----------
    camera : CameraModel
    world_to_camera : (4, 4) float
        ``T_cam_world`` (``X_camera = T @ X_world``, translation [m]); read-only.
    plane_z : float
        Height of the surface in the world frame [m] (world z up).
    surface_albedo : float
        Diffuse reflectance of the surface in pictures in real light (0..1; the exact pictures of
        :func:`vision.render.render_mesh` have their own flat grey): by default the satin grey tray
        of :mod:`vision.lit`, about as bright as brushed aluminium under a low light.
    """

    camera: CameraModel
    world_to_camera: np.ndarray
    plane_z: float
    surface_albedo: float = TRAY_ALBEDO

    def __post_init__(self) -> None:
        t = np.array(self.world_to_camera, dtype=np.float64)
        if t.shape != (4, 4) or not np.isfinite(t).all():
            raise VisionError(f"world_to_camera must be a finite 4x4 transform, got shape {t.shape}")
        r = t[:3, :3]
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0 or \
                not np.allclose(t[3], [0, 0, 0, 1]):
            raise VisionError("world_to_camera is not a rigid transform")
        if not np.isfinite(self.plane_z):
            raise VisionError(f"plane_z must be finite, got {self.plane_z}")
        if not 0.0 < self.surface_albedo <= 1.0:
            raise VisionError(f"surface_albedo must be in (0, 1], got {self.surface_albedo}")
        t.setflags(write=False)
        object.__setattr__(self, "world_to_camera", t)
        object.__setattr__(self, "plane_z", float(self.plane_z))

    @property
    def camera_pose(self) -> np.ndarray:
        """``T_world_cam`` (4, 4), the camera's pose in the world [m] (what locate calls ``base_camera``)."""
        return invert(self.world_to_camera)

    @cached_property
    def rays(self) -> PixelRays:
        """The camera's sub-pixel viewing rays, computed once per station (about a second)."""
        return pixel_rays(self.camera, SUPERSAMPLE)


def station_above(camera: CameraModel, target_xyz: np.ndarray, height: float, *, tilt: float = 0.0,
                  surface_albedo: float = TRAY_ALBEDO) -> CameraStation:
    """A camera ``height`` above a point of the surface, looking at it (image x = world x, image up = world +y).

    Parameters
    ----------
    camera : CameraModel
    target_xyz : (3,) float
        The point looked at, on the surface (its z is the surface height) [m].
    height : float
        Camera height above the surface [m], > 0.
    tilt : float
        Angle of the viewing direction from straight down [rad]; the camera moves toward world -y.
    surface_albedo : float
        The surface's diffuse reflectance in real light (:attr:`CameraStation.surface_albedo`).

    Raises
    ------
    VisionError
        A height that is not positive, a tilt of 80 deg or more, or a target that is not 3 finite numbers.
    """
    target = np.asarray(target_xyz, dtype=np.float64).reshape(-1)
    if target.shape != (3,) or not np.isfinite(target).all():
        raise VisionError(f"target must be 3 finite coordinates [m], got {target_xyz!r}")
    if not height > 0:
        raise VisionError(f"camera height must be positive, got {height} m")
    if not abs(tilt) < np.radians(80):
        raise VisionError(f"camera tilt must be below 80 deg, got {np.degrees(tilt):.1f} deg")
    eye = target + np.array([0.0, -height * np.tan(tilt), height])
    return CameraStation(camera, look_at_pose(eye, target, up=np.array([0.0, 1.0, 0.0])), float(target[2]),
                         float(surface_albedo))


@dataclass(frozen=True)
class CameraShot:
    """One picture of a camera step, what the vision made of it, and how that compares to the truth.

    Attributes
    ----------
    image : (h, w) uint8
        The grey picture as rendered (read-only).
    annotated : (h, w, 3) uint8
        BGR picture with the detections drawn (read-only).
    detections : tuple of dict
        JSON-ready, one per part found (here: the one nearest the truth): ``x, y, z`` [m], ``yaw``
        [rad], ``score`` and the rest of :meth:`LocatedPart.to_dict`; for inspection also the keys of
        :meth:`Inspection.to_dict` (``pass``, ``max_deviation_mm``, ...) but its nested pose.
    processing_s : float
        Wall time of the vision call (locate or inspect) on the picture [s].
    passed : bool
        Locate: found within :data:`LOCATE_TOLERANCE_M` and :data:`LOCATE_TOLERANCE_RAD` of the truth.
        Inspect: the inspection's verdict.
    error_mm : float
        Distance of the located footprint centroid from the true one [mm].
    """

    image: np.ndarray
    annotated: np.ndarray
    detections: tuple[dict, ...]
    processing_s: float
    passed: bool
    error_mm: float

    def __post_init__(self) -> None:
        for name in ("image", "annotated"):
            a = np.asarray(getattr(self, name))
            a.setflags(write=False)
            object.__setattr__(self, name, a)


def _truth(footprint: Footprint, pose: tuple[float, float, float], plane_z: float) -> LocatedPart:
    """Where the part is put, as a LocatedPart (so :func:`part_transform` places its mesh)."""
    x, y, yaw = (float(v) for v in pose)
    if not np.isfinite([x, y, yaw]).all():
        raise VisionError(f"part pose must be finite (x [m], y [m], yaw [rad]), got {pose!r}")
    return LocatedPart(x=x, y=y, z=plane_z, yaw=yaw, score=1.0, rms_px=0.0, mm_per_px=float("nan"),
                       sigma_xy=0.0, sigma_yaw=0.0, pixel=(float("nan"), float("nan")))


def _picture(station: CameraStation, footprint: Footprint, truth: LocatedPart, vertices_mm: np.ndarray,
             faces: np.ndarray, seed: int, light: Condition | None = None) -> np.ndarray:
    """The rendered picture of a mesh [mm, its own frame] placed at ``truth``: exact
    (:func:`vision.render.render_mesh`), or in real light ``light`` (:func:`vision.lit.render_lit`:
    aluminium, shadows, exposure, noise, the key light drawn from ``seed``)."""
    t = part_transform(footprint, truth)
    world = mm_to_m(np.asarray(vertices_mm, dtype=np.float64)) @ t[:3, :3].T + t[:3, 3]
    if light is None:
        return render_mesh(station.rays, station.world_to_camera, world, faces, plane_z=station.plane_z,
                           noise_sigma=NOISE_SIGMA, seed=seed)
    rng = np.random.default_rng(seed)
    sun = key_light(light, rng, np.array([truth.x, truth.y, station.plane_z]), station.camera_pose[:3, 3])
    mesh = trimesh.Trimesh(world, np.asarray(faces, dtype=np.int64), process=False)
    return render_lit(station, [(mesh, metal(light, t))], light, sun, rng, supersample=LIT_SUPERSAMPLE,
                      tray_albedo=station.surface_albedo)


def _nearest(found: list, truth: LocatedPart, part_of=lambda p: p):
    """The detection whose part is nearest the truth, and that part's distance from it [m]."""
    best = min(found, key=lambda d: np.hypot(part_of(d).x - truth.x, part_of(d).y - truth.y))
    return best, float(np.hypot(part_of(best).x - truth.x, part_of(best).y - truth.y))


def _not_found(e: VisionError, what: str, truth: LocatedPart) -> VisionError:
    return VisionError(f"{what} put at x {truth.x:.4f} m, y {truth.y:.4f} m, yaw {np.degrees(truth.yaw):.1f} deg "
                       f"was not found in the rendered picture: {e.message}", source=e.source)


def locate_shot(station: CameraStation, vertices_mm: np.ndarray, faces: np.ndarray,
                pose: tuple[float, float, float], *, seed: int = 0, light: Condition | None = None) -> CameraShot:
    """Render a part (a raw blank) lying on the station's surface and locate it.

    Parameters
    ----------
    station : CameraStation
    vertices_mm : (n, 3) float
        The part's mesh in its own frame [mm] (CAM units); closed, outward normals.
    faces : (m, 3) int
    pose : (float, float, float)
        Where the part is put: its footprint centroid at ``x, y`` [m] on the surface, turned by
        ``yaw`` [rad] about world z.
    seed : int
        Seed of the picture's noise (and, in real light, of its key light and textures).
    light : Condition, optional
        Take the picture in this real light (:data:`vision.lit.CONDITIONS`: brushed aluminium,
        shadows, exposure, noise); None: the exact picture of :func:`vision.render.render_mesh`.

    Raises
    ------
    VisionError
        The mesh cannot be a footprint (see :func:`footprint_from_mesh`), is partly behind the camera,
        or the part is not found in the picture (e.g. put outside the camera's view).
    """
    footprint = footprint_from_mesh(vertices_mm, faces, source="locate shot")
    truth = _truth(footprint, pose, station.plane_z)
    image = _picture(station, footprint, truth, vertices_mm, faces, seed, light)
    start = time.perf_counter()
    try:
        found = locate_parts(image, station.camera, station.camera_pose, footprint, station.plane_z,
                             source="locate shot")
    except VisionError as e:
        raise _not_found(e, "the blank", truth) from None
    processing = time.perf_counter() - start
    part, error = _nearest(found, truth)
    period = 2 * np.pi / footprint.symmetry  # a rectangle's yaw is only known modulo 180 deg
    turn = (part.yaw - truth.yaw) % period
    yaw_error = min(turn, period - turn)
    passed = error <= LOCATE_TOLERANCE_M and yaw_error <= LOCATE_TOLERANCE_RAD
    return CameraShot(image=image, annotated=_located_image(image, station, footprint, part, passed),
                      detections=(part.to_dict(),), processing_s=processing, passed=bool(passed),
                      error_mm=error * 1e3)


def _located_image(image: np.ndarray, station: CameraStation, footprint: Footprint, part: LocatedPart,
                   passed: bool) -> np.ndarray:
    """BGR picture with the fitted outline (green), the part's axes at its centroid and its pose."""
    canvas = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    ring = np.rint(part.outline * 4).astype(np.int32)  # 2 fractional bits for a smooth line
    cv2.polylines(canvas, [ring.reshape(-1, 1, 2)], True, (0, 200, 0), 1, cv2.LINE_AA, shift=2)
    # The part's x (red) and y (green) axes on its top face, a third of its length long.
    top = station.plane_z + footprint.height
    arm = float(np.ptp(footprint.outline, axis=0).max()) / 3
    c, s = np.cos(part.yaw), np.sin(part.yaw)
    points = np.array([[part.x, part.y, top], [part.x + arm * c, part.y + arm * s, top],
                       [part.x - arm * s, part.y + arm * c, top]])
    rvec = cv2.Rodrigues(station.world_to_camera[:3, :3])[0]
    uv = np.rint(station.camera.project(points, rvec, station.world_to_camera[:3, 3]) * 4).astype(np.int32)
    for end, colour in ((uv[1], (0, 0, 255)), (uv[2], (0, 200, 0))):
        cv2.line(canvas, tuple(uv[0]), tuple(end), colour, 2, cv2.LINE_AA, shift=2)
    label = f"{'FOUND' if passed else 'OFF'} x {part.x:.4f} y {part.y:.4f} m yaw {np.degrees(part.yaw):.1f} deg"
    (w, h), base = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.55, 1)
    cv2.rectangle(canvas, (6, 24 - h - 4), (14 + w, 24 + base + 2), (0, 0, 0), cv2.FILLED)
    cv2.putText(canvas, label, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 200, 0) if passed else (0, 0, 255),
                1, cv2.LINE_AA)
    return canvas


def cut_corner(vertices_mm: np.ndarray, faces: np.ndarray, share: float = CORNER_CUT
               ) -> tuple[np.ndarray, np.ndarray]:
    """The part with one corner broken off by a vertical cut, for a part that must fail inspection.

    The cut goes through the points ``share`` of the footprint's width and of its depth from a
    corner of the footprint's bounding box, at the corner where it removes most footprint area.

    Parameters
    ----------
    vertices_mm : (n, 3) float
        Closed mesh [mm].
    faces : (m, 3) int
    share : float
        Share of the footprint's extent along x and along y that the cut takes off (0 < share < 0.5).

    Returns
    -------
    vertices : (k, 3) float
        [mm]
    faces : (l, 3) int
        The cut mesh, closed again (the cut face capped).

    Raises
    ------
    VisionError
        A share out of range, a mesh that is not closed, or a cut that removes nothing.
    """
    if not 0 < share < 0.5:
        raise VisionError(f"corner cut share must be in (0, 0.5), got {share}")
    footprint = footprint_from_mesh(vertices_mm, faces, source="cut corner")
    outline = (footprint.outline + footprint.centroid) * 1e3  # footprint in mesh coordinates [mm]
    poly = Polygon(outline)
    lo, hi = outline.min(axis=0), outline.max(axis=0)
    leg = share * (hi - lo)
    best = None
    for cx, sx in ((lo[0], 1), (hi[0], -1)):
        for cy, sy in ((lo[1], 1), (hi[1], -1)):
            p, q = np.array([cx + sx * leg[0], cy]), np.array([cx, cy + sy * leg[1]])
            removed = poly.intersection(Polygon([(cx, cy), p, q])).area
            if best is None or removed > best[0]:
                best = (removed, p, q, np.array([cx, cy]))
    removed, p, q, corner = best
    if removed <= 0:
        raise VisionError("cutting a corner removes nothing of this part", source="cut corner")
    d = q - p
    normal = np.array([d[1], -d[0], 0.0])
    if normal[:2] @ (corner - p) > 0:
        normal = -normal  # keep the side away from the corner
    mesh = trimesh.Trimesh(np.asarray(vertices_mm, dtype=np.float64), np.asarray(faces, dtype=np.int64))
    if not mesh.is_watertight:
        raise VisionError("the part mesh is not closed; its cut corner cannot be capped", source="cut corner")
    cut = slice_mesh_plane(mesh, normal / np.linalg.norm(normal), np.r_[p, 0.0], cap=True)
    return np.asarray(cut.vertices), np.asarray(cut.faces)


def inspect_shot(station: CameraStation, vertices_mm: np.ndarray, faces: np.ndarray,
                 pose: tuple[float, float, float], *, defect: bool, seed: int = 0) -> CameraShot:
    """Render a finished part lying on the station's surface (good, or with a corner broken off) and inspect it.

    The inspection expects the given mesh; with ``defect`` the picture shows :func:`cut_corner` of it.

    Parameters
    ----------
    station, vertices_mm, faces, pose, seed
        As :func:`locate_shot`.
    defect : bool
        Render the part with a corner cut off (it must then fail inspection).

    Raises
    ------
    VisionError
        As :func:`locate_shot`; with ``defect``, also as :func:`cut_corner`.
    """
    footprint = footprint_from_mesh(vertices_mm, faces, source="inspect shot")
    truth = _truth(footprint, pose, station.plane_z)
    shown_v, shown_f = cut_corner(vertices_mm, faces) if defect else (vertices_mm, faces)
    # Placed by the whole part's footprint: the cut part lies where the good one would.
    image = _picture(station, footprint, truth, shown_v, shown_f, seed)
    start = time.perf_counter()
    try:
        # The exact renderer shades flat: a boss seen from straight above shows no edge against the
        # face it stands on, so features seen so are not judged here (a camera's real light shows them).
        found = inspect_part(image, station.camera, station.camera_pose, footprint, vertices_mm, faces,
                             station.plane_z, InspectOptions(judge_from_above=False), source="inspect shot")
    except VisionError as e:
        raise _not_found(e, "the damaged part" if defect else "the part", truth) from None
    processing = time.perf_counter() - start
    inspection, error = _nearest(found, truth, part_of=lambda ins: ins.part)
    summary = {k: v for k, v in inspection.to_dict().items() if k != "pose"}
    return CameraShot(image=image, annotated=inspection_image(image, [inspection]),
                      detections=({**inspection.part.to_dict(), **summary},), processing_s=processing,
                      passed=bool(inspection.passed), error_mm=error * 1e3)
