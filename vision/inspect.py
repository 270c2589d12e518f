"""Silhouette inspection: does the part in the picture have the outline its mesh says it should?

The part is located on the tray (:func:`vision.locate.locate_parts`, robust fit of its footprint
prism). Its whole mesh, placed at a pose, is projected through the camera (pinhole in the
normalised image plane; the picture's outline has its distortion removed instead) and the union
of its triangles is the expected silhouette.

The prism is the full height everywhere, so a part whose top is stepped (lower tops look smaller
in perspective) is located off by a millimetre or two. The pose is therefore refined against the
mesh's own silhouette (:func:`refine_pose`): each piece of the silhouette ring is the projection of
one mesh edge, so the outline is fitted (x, y, yaw on the tray, robust soft-L1 loss) to those
edges' projections, then the silhouette is recomputed at the new pose and the fit repeated until
the pose stops moving (a few rounds, like ICP).

Each point of the picture's sub-pixel outline then gets its signed distance to the silhouette
(positive outside: extra material or a burr; negative inside: missing material), converted to
millimetres by the pixel size at the part's distance. The part passes when every point is within
the tolerance.

Because the pose is fitted to the same outline, a defect pulls the pose a little (the robust
loss limits that); deviations are therefore a lower bound on the defect for large defects.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
import shapely
from scipy.optimize import least_squares
from shapely.geometry import MultiPolygon, Polygon

from factory.core.errors import VisionError
from vision.camera import CameraModel
from vision.locate import ROBUST_SCALE_PX, Footprint, LocatedPart, LocateOptions, locate_parts, mm_to_m

#: A ring piece lies on a mesh edge when its midpoint is this close to the edge's projection
#: (normalised image units; ~1e-4 px, far above the 1e-9 the silhouette is buffered by).
_ON_EDGE = 1e-7
#: Refinement stops when a round moves the part less than these [m], [rad].
_STILL_M, _STILL_RAD = 1e-7, 1e-6


@dataclass(frozen=True)
class InspectOptions:
    """Tunables of :func:`inspect_part`.

    Attributes
    ----------
    tolerance : float
        Largest deviation of the outline from the expected silhouette that passes [m].
    refine_rounds : int
        Most rounds of :func:`refine_pose` (refit to the mesh's silhouette, recompute it); 0 keeps
        the prism pose of :func:`vision.locate.locate_parts`.
    """

    tolerance: float = 1e-3
    refine_rounds: int = 8


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
    uv = _project(mm_to_m(np.asarray(vertices_mm, dtype=np.float64)), cam_part)
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


def _project(points_m: np.ndarray, cam_part: np.ndarray) -> np.ndarray:
    """``(n, 2)`` points of the part [m] in the normalised image plane; VisionError if behind the camera."""
    v = points_m @ cam_part[:3, :3].T + cam_part[:3, 3]
    if (v[..., 2] <= 1e-6).any():
        raise VisionError("part is (partly) behind the camera")
    return v[..., :2] / v[..., 2:3]


def _mesh_edges(faces: np.ndarray) -> np.ndarray:
    """``(e, 2)`` int: every edge of the triangles once."""
    f = np.asarray(faces, dtype=np.int64)
    return np.unique(np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)


def _ring_edges(ring: np.ndarray, uv: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh edge each piece of a silhouette ring lies on.

    Parameters
    ----------
    ring : (m, 2) float
        Closed silhouette ring (normalised image plane).
    uv : (n, 2) float
        Projected mesh vertices (same plane).
    edges : (e, 2) int

    Returns
    -------
    pieces : (k,) int
        Ring pieces (``ring[i]`` to ``ring[i + 1]``) that lie on a mesh edge.
    edge : (k,) int
        The (most nearly parallel) edge each of them lies on.
    """
    a, b = ring[:-1], ring[1:]
    d = b - a
    length = np.hypot(d[:, 0], d[:, 1])
    # The silhouette's 1e-9 buffer rounds convex corners with arcs of that size: not edges.
    pieces = np.flatnonzero(length > 100 * _ON_EDGE)
    tree = shapely.STRtree(shapely.linestrings(uv[edges]))
    piece, edge = tree.query(shapely.points(0.5 * (a + b)[pieces]), predicate="dwithin", distance=_ON_EDGE)
    e = uv[edges[edge, 1]] - uv[edges[edge, 0]]
    u = d[pieces[piece]] / length[pieces[piece], None]
    sine = np.abs(u[:, 0] * e[:, 1] - u[:, 1] * e[:, 0]) / np.maximum(np.hypot(e[:, 0], e[:, 1]), 1e-300)
    # Per piece, the edge most nearly along it; edges that merely cross the midpoint are not it.
    order = np.lexsort((sine, piece))
    first = order[np.r_[True, piece[order][1:] != piece[order][:-1]]]
    first = first[sine[first] < 1e-3]
    return pieces[piece[first]], edge[first]


def refine_pose(camera: CameraModel, cam_base: np.ndarray, part: Footprint, located: LocatedPart,
                vertices_mm: np.ndarray, faces: np.ndarray, rounds: int = 8) -> LocatedPart:
    """The located pose refitted to the mesh's own silhouette instead of the footprint prism.

    Each round computes :func:`expected_silhouette` at the current pose, finds the mesh edge every
    piece of its ring lies on, pairs each outline point with its nearest piece and fits x, y and yaw
    (:func:`scipy.optimize.least_squares`, soft-L1 loss at :data:`vision.locate.ROBUST_SCALE_PX`,
    so missing material of a defective part does not drag the pose) to minimise the outline points'
    distances to their edges' projected lines [px]. Rounds stop when the pose stops moving.
    A footprint with symmetry leaves the mesh's yaw open: each symmetric yaw gets a first round
    and the one the outline fits best is carried on.

    Parameters
    ----------
    camera : CameraModel
    cam_base : (4, 4) float
        ``T_cam_base`` [m].
    part : Footprint
    located : LocatedPart
        The starting pose, with the sub-pixel ``outline`` [px] it was found by.
    vertices_mm : (n, 3) float
        Mesh vertices [mm].
    faces : (m, 3) int
    rounds : int
        Most rounds (0 returns ``located`` unchanged).

    Returns
    -------
    LocatedPart
        ``located`` with the refined ``x``, ``y`` [m], ``yaw`` [rad] and ``rms_px`` [px] (the robust
        fit's RMS); its score, uncertainties and pixel stay those of the prism fit.

    Raises
    ------
    VisionError
        Part (partly) behind the camera.
    """
    return _refine(camera, cam_base, part, located, vertices_mm, faces, rounds)[0]


def _refine(camera: CameraModel, cam_base: np.ndarray, part: Footprint, located: LocatedPart,
            vertices_mm: np.ndarray, faces: np.ndarray, rounds: int) -> tuple[LocatedPart, Polygon | None]:
    """:func:`refine_pose`, and :func:`expected_silhouette` at the refined pose when the last round
    computed it there (the pose stood still after it), so :func:`inspect_part` need not compute it again.
    """
    vertices = mm_to_m(np.asarray(vertices_mm, dtype=np.float64))
    edges = _mesh_edges(faces)
    obs = camera.rays(located.outline)[:, :2]
    if rounds <= 0 or len(obs) < 3:
        return located, None
    f = np.sqrt(camera.fx * camera.fy)
    p = np.array([located.x, located.y, located.yaw])

    def cam_part(q: np.ndarray) -> np.ndarray:
        return cam_base @ part_transform(part, replace(located, x=q[0], y=q[1], yaw=q[2]))

    def fit_round(p: np.ndarray):
        """One round from pose ``p``: (new pose, robust cost, RMS [px], step, silhouette at ``p``) or None."""
        uv = _project(vertices, cam_part(p))
        sil = expected_silhouette(vertices_mm, faces, cam_part(p))
        ring = np.array(sil.exterior.coords)
        pieces, edge = _ring_edges(ring, uv, edges)
        if len(pieces) == 0:
            return None
        nearest = shapely.STRtree(shapely.linestrings(np.stack([ring[pieces], ring[pieces + 1]], axis=1)))
        _, which = nearest.query_nearest(shapely.points(obs), all_matches=False)
        ends = vertices[edges[edge[which]]]  # (n, 2, 3) the mesh edge of each outline point [m]

        def residuals(q: np.ndarray) -> np.ndarray:
            uv_ends = _project(ends, cam_part(q))
            d = uv_ends[:, 1] - uv_ends[:, 0]
            w = obs - uv_ends[:, 0]
            return f * (d[:, 0] * w[:, 1] - d[:, 1] * w[:, 0]) / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-300)

        sol = least_squares(residuals, p, x_scale=np.array([1e-3, 1e-3, 1e-2]), method="trf",
                            loss="soft_l1", f_scale=ROBUST_SCALE_PX)
        return sol.x, float(sol.cost), float(np.sqrt(np.mean(sol.fun ** 2))), sol.x - p, sil

    def still(step: np.ndarray) -> bool:
        return np.hypot(step[0], step[1]) < _STILL_M and abs(step[2]) < _STILL_RAD

    # The prism knows the yaw only modulo its footprint's symmetry; the mesh need not share it
    # (a stepped top): one round from each symmetric yaw, then the best one is carried on.
    turns = 2 * np.pi * np.arange(part.symmetry) / part.symmetry
    tried = [r for r in (fit_round(p + np.array([0.0, 0.0, t])) for t in turns) if r is not None]
    if not tried:
        return located, None
    p, _, rms, step, sil = min(tried, key=lambda r: r[1])
    for _ in range(rounds - 1):
        if still(step):
            break
        again = fit_round(p)
        if again is None:
            break
        p, _, rms, step, sil = again
    refined = replace(located, x=float(p[0]), y=float(p[1]), yaw=float(np.angle(np.exp(1j * p[2]))), rms_px=rms)
    return refined, sil if still(step) else None


def inspect_part(image: np.ndarray, camera: CameraModel, base_camera: np.ndarray, part: Footprint,
                 vertices_mm: np.ndarray, faces: np.ndarray, tray_z: float,
                 options: InspectOptions = InspectOptions(), *, source: str = "image") -> list[Inspection]:
    """Inspect every copy of the part on the tray (best located first).

    Each copy's prism pose from :func:`vision.locate.locate_parts` is refined to the mesh's own
    silhouette (:func:`refine_pose`, ``options.refine_rounds``) before its outline is judged.

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
    # A defective part must still be found: no outline-fit limit here, and no share of the inner
    # edges (a missing boss or hole takes them away); the deviation judges it.
    found = locate_parts(image, camera, base_camera, part, tray_z, LocateOptions(max_rms_px=np.inf, min_found=0.0),
                         source=source)
    cam_base = np.linalg.inv(np.asarray(base_camera, dtype=np.float64))
    out = []
    f = np.sqrt(camera.fx * camera.fy)
    for located in found:
        located, sil = _refine(camera, cam_base, part, located, vertices_mm, faces, options.refine_rounds)
        if sil is None:
            sil = expected_silhouette(vertices_mm, faces, cam_base @ part_transform(part, located))
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
