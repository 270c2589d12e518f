"""Silhouette inspection: does the part in the picture have the outline its mesh says it should?

The part is located on the tray (:func:`vision.locate.locate_parts`, robust fit of its footprint
prism). Its whole mesh, placed at that pose, is projected through the camera (pinhole in the
normalised image plane; the picture's outline has its distortion removed instead) and the union
of its triangles is the expected silhouette. Each point of the picture's sub-pixel outline gets
its signed distance to that silhouette (positive outside: extra material or a burr; negative
inside: missing material), converted to millimetres by the pixel size at the part's distance.
The part passes when every point is within the tolerance.

Because the pose is fitted to the same outline, a defect pulls the pose a little (the robust
loss limits that); deviations are therefore a lower bound on the defect for large defects.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon

from factory.errors import VisionError
from vision.camera import CameraModel
from vision.locate import Footprint, LocatedPart, LocateOptions, locate_parts, mm_to_m


@dataclass(frozen=True)
class InspectOptions:
    """Tunables of :func:`inspect_part`.

    Attributes
    ----------
    tolerance : float
        Largest deviation of the outline from the expected silhouette that passes [m].
    """

    tolerance: float = 1e-3


@dataclass(frozen=True)
class Inspection:
    """The result of inspecting one part.

    Attributes
    ----------
    part : LocatedPart
        Where the part was found.
    deviation : (n,) float
        Signed deviation of each outline point (positive outside the expected silhouette) [m].
    silhouette_px : (m, 2) float
        The expected silhouette, closed ring, in (distorted) image coordinates [px].
    tolerance : float
        [m]
    """

    part: LocatedPart
    deviation: np.ndarray
    silhouette_px: np.ndarray
    tolerance: float

    @property
    def max_deviation(self) -> float:
        """Largest absolute deviation [m]."""
        return float(np.abs(self.deviation).max()) if len(self.deviation) else 0.0

    @property
    def passed(self) -> bool:
        """Whether every outline point is within the tolerance."""
        return self.max_deviation <= self.tolerance

    def to_dict(self) -> dict:
        """JSON-ready summary (deviations in mm, as machinists read them)."""
        d = np.abs(self.deviation) * 1e3
        return {"pass": self.passed, "tolerance_mm": self.tolerance * 1e3,
                "max_deviation_mm": float(d.max()) if len(d) else 0.0,
                "p95_deviation_mm": float(np.percentile(d, 95)) if len(d) else 0.0,
                "mean_deviation_mm": float(d.mean()) if len(d) else 0.0,
                "excess_mm": float(max(self.deviation.max(initial=0.0), 0.0) * 1e3),
                "missing_mm": float(max(-self.deviation.min(initial=0.0), 0.0) * 1e3),
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
        The part mesh [mm] whose silhouette is expected.

    Raises
    ------
    VisionError
        As :func:`vision.locate.locate_parts` (no part found, bad image).
    """
    # A defective part must still be found: no outline-fit limit here, the deviation judges it.
    found = locate_parts(image, camera, base_camera, part, tray_z, LocateOptions(max_rms_px=np.inf), source=source)
    cam_base = np.linalg.inv(np.asarray(base_camera, dtype=np.float64))
    out = []
    f = np.sqrt(camera.fx * camera.fy)
    for located in found:
        cam_part = cam_base @ part_transform(part, located)
        sil = expected_silhouette(vertices_mm, faces, cam_part)
        obs = camera.rays(located.outline)[:, :2]
        ring = shapely.geometry.LineString(sil.exterior.coords)
        dist = shapely.distance(shapely.points(obs), ring)
        inside = shapely.contains_xy(sil, obs[:, 0], obs[:, 1])
        deviation = np.where(inside, -dist, dist) * f * located.mm_per_px * 1e-3
        ring_px = camera.project(np.column_stack([np.array(sil.exterior.coords), np.ones(len(sil.exterior.coords))]),
                                 np.zeros(3), np.zeros(3))
        out.append(Inspection(part=located, deviation=deviation, silhouette_px=ring_px, tolerance=options.tolerance))
    return out


def inspection_image(image: np.ndarray, inspections: list[Inspection]) -> np.ndarray:
    """The picture with the expected silhouette (blue) and the outline coloured by deviation
    (green within tolerance, red beyond), and PASS/FAIL with the largest deviation per part.

    Returns
    -------
    (h, w, 3) uint8
        BGR picture.
    """
    img = np.asarray(image)
    canvas = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img.copy()
    for ins in inspections:
        ring = np.rint(ins.silhouette_px * 4).astype(np.int32)  # 2 fractional bits for a smooth line
        cv2.polylines(canvas, [ring.reshape(-1, 1, 2)], True, (255, 120, 0), 1, cv2.LINE_AA, shift=2)
        bad = np.abs(ins.deviation) > ins.tolerance
        for (u, v), b in zip(np.rint(ins.part.outline).astype(int), bad):
            canvas[np.clip(v, 0, canvas.shape[0] - 1), np.clip(u, 0, canvas.shape[1] - 1)] = \
                (0, 0, 255) if b else (0, 200, 0)
        u, v = (int(round(c)) for c in ins.part.pixel)
        label = f"{'PASS' if ins.passed else 'FAIL'} {ins.max_deviation * 1e3:.2f} mm"
        cv2.putText(canvas, label, (u - 40, v), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(canvas, label, (u - 40, v), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (0, 200, 0) if ins.passed else (0, 0, 255), 1, cv2.LINE_AA)
    return canvas
