"""Pictures in real light: a ray caster of meshes on a tray, independent of :mod:`vision.render`.

:mod:`vision.render` draws exact pictures (flat shading, no shadows) for calibration and the
cell's exact camera steps. This one draws what a real cell's camera sees, so that locate and
inspection are tried on pictures they were not built around (issue 33):

- every sub-pixel sample's ray is undistorted with OpenCV (``cv2.undistortPoints``, iterated to
  convergence), meets the scene's triangles (a z-buffer in the undistorted image plane) or the
  tray plane, and is shaded with a Blinn-Phong model;
- brushed aluminium: Lambert with streaks along the part's x axis, a specular lobe (broad for
  brushed, tight and strong for polished), smooth normals on freeform faces;
- a satin grey tray with a random texture and a faint specular lobe;
- one directional light of finite angular size (every sample jitters it, so shadows have
  penumbras), shadow maps for self-shadows and the cast shadow, and a fill light from above;
- vignetting (cos^2: about 30 % in the corners), auto-exposure to a mean grey, defocus (Gaussian),
  shot and read noise, 8-bit clipping.

It shares nothing with :mod:`vision.render` but the camera file: lens distortion, shading,
visibility and shadows are its own, so a flaw of one is not repeated by the other. The five light
conditions of issue 33 are :data:`CONDITIONS`; :func:`key_light` draws the key light of one.
The test gallery (``tests/vision/lit.py``) and the cell simulation's rack camera
(:func:`vision.station.locate_shot` with ``light``) take their pictures with :func:`render_lit`.

Units: metres and radians in the world frame (z up, the tray at the station's ``plane_z``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import cv2
import numpy as np
import trimesh
from scipy.ndimage import map_coordinates

from vision.camera import CameraModel


class Station(Protocol):
    """What a picture needs of a camera station (:class:`vision.station.CameraStation`, which
    takes its pictures in real light from here): the camera, ``camera_pose`` ``T_world_cam`` and
    ``world_to_camera`` ``T_cam_world`` (4, 4) [m], the tray's height ``plane_z`` [m]."""

    camera: CameraModel
    camera_pose: np.ndarray
    world_to_camera: np.ndarray
    plane_z: float

@dataclass(frozen=True)
class Condition:
    """Light, material and exposure of one picture condition.

    Attributes
    ----------
    elevation_deg : (float, float)
        Range of the key light's elevation above the tray [deg]; its azimuth is random.
    size_deg : float
        Angular radius of the key light (penumbra) [deg].
    fill : float
        Fill light from above, relative to the key light (unitless).
    mean_grey : float
        Auto-exposure target: mean grey level of the picture (0..255).
    specular, shininess : float
        Metal's specular strength (relative to the key light) and Blinn-Phong exponent.
    glare : bool
        Put the key light at the top face's mirror direction seen from the camera.
    distractor : bool
        Put a plain matte box beside the part.
    """

    elevation_deg: tuple[float, float]
    size_deg: float
    fill: float
    mean_grey: float
    specular: float = 0.35
    shininess: float = 25.0
    glare: bool = False
    distractor: bool = False


#: Diffuse reflectance of the satin grey tray (0..1): a little darker than brushed aluminium.
TRAY_ALBEDO = 0.45

CONDITIONS: dict[str, Condition] = {
    "diffuse": Condition((60.0, 80.0), 12.0, 0.6, 120.0),
    "low_angle": Condition((14.0, 22.0), 0.5, 0.12, 115.0),
    "dim": Condition((50.0, 75.0), 8.0, 0.4, 60.0),
    "glare": Condition((72.0, 82.0), 3.0, 0.3, 115.0, specular=2.5, shininess=400.0, glare=True),
    "distractor": Condition((55.0, 75.0), 10.0, 0.5, 120.0, distractor=True),
}

@dataclass(frozen=True)
class Material:
    """How one mesh of a lit scene reflects light.

    Attributes
    ----------
    albedo : float
        Diffuse reflectance (0..1).
    brushed : float
        Strength of the brushing streaks along the part's x axis (0: none; relative).
    specular, shininess : float
        Specular strength (relative to the key light) and Blinn-Phong exponent.
    frame : (4, 4) float
        ``T_world_part`` [m]: the part's frame, along whose x axis the streaks run.
    """

    albedo: float
    brushed: float
    specular: float
    shininess: float
    frame: np.ndarray = field(default_factory=lambda: np.eye(4))


def metal(condition: Condition, frame: np.ndarray) -> Material:
    """Aluminium as the cell's parts and blanks are: brushed (streaks along the part frame ``frame``'s
    x axis, (4, 4) ``T_world_part`` [m]), or polished and darker in diffuse light under glare."""
    polished = condition.glare
    return Material(albedo=0.35 if polished else 0.55, brushed=0.0 if polished else 0.12,
                    specular=condition.specular, shininess=condition.shininess,
                    frame=np.asarray(frame, dtype=np.float64))


def key_light(condition: Condition, rng: np.random.Generator, point: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """``(3,)`` unit direction toward the key light of ``condition`` [world frame], drawn from ``rng``.

    Under glare the light stands where the top face at ``point`` [m] mirrors it into the camera at
    ``eye`` [m], a few degrees off; otherwise at a random azimuth and an elevation in the condition's range.
    """
    if condition.glare:
        to_cam = np.asarray(eye, dtype=np.float64) - np.asarray(point, dtype=np.float64)
        to_cam /= np.linalg.norm(to_cam)
        mirror = np.array([-to_cam[0], -to_cam[1], to_cam[2]])
        return _jitter(mirror, np.radians(4.0), rng, 1)[0]
    el = np.radians(rng.uniform(*condition.elevation_deg))
    az = rng.uniform(0, 2 * np.pi)
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])

def _rays(camera: CameraModel, s: int) -> np.ndarray:
    """``(h*s, w*s, 3)`` unit viewing rays of the sub-pixel samples in the camera frame."""
    w, h = camera.image_size
    off = (np.arange(s) + 0.5) / s - 0.5
    uu, vv = np.meshgrid((np.arange(w)[:, None] + off).ravel(), (np.arange(h)[:, None] + off).ravel())
    pts = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64)[:, None, :]
    xy = cv2.undistortPoints(pts, np.asarray(camera.K), np.asarray(camera.dist), None, None, None,
                             (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-12))[:, 0, :]
    d = np.column_stack([xy, np.ones(len(xy))])
    return (d / np.linalg.norm(d, axis=1, keepdims=True)).reshape(h * s, w * s, 3)


_RAYS: dict = {}


def _camera_rays(camera: CameraModel, s: int) -> np.ndarray:
    key = (camera.K.tobytes(), camera.dist.tobytes(), camera.image_size, s)
    if key not in _RAYS:
        _RAYS[key] = _rays(camera, s)
    return _RAYS[key]


def _smooth_noise(rng: np.random.Generator, shape: tuple[int, int], sigma: float) -> np.ndarray:
    """Gaussian-filtered white noise scaled to unit standard deviation."""
    n = cv2.GaussianBlur(rng.normal(size=shape).astype(np.float32), (0, 0), sigma)
    return n / max(float(n.std()), 1e-9)


def _sample(grid: np.ndarray, origin: np.ndarray, step: float, xy: np.ndarray) -> np.ndarray:
    """Bilinear lookup of a texture grid laid on the tray (``origin`` [m] at grid[0, 0], ``step`` [m])."""
    q = (xy - origin) / step
    return map_coordinates(grid, [q[:, 1], q[:, 0]], order=1, mode="reflect")


def _jitter(direction: np.ndarray, radius: float, rng: np.random.Generator, n: int) -> np.ndarray:
    """``(n, 3)`` unit directions uniformly within a cone of ``radius`` [rad] around ``direction``."""
    a = np.cross(direction, [0.0, 0.0, 1.0] if abs(direction[2]) < 0.9 else [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(direction, a)
    r = radius * np.sqrt(rng.uniform(size=n))
    t = rng.uniform(0, 2 * np.pi, n)
    d = direction + np.tan(r)[:, None] * (np.cos(t)[:, None] * a + np.sin(t)[:, None] * b)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def render_lit(station: Station, meshes: list[tuple[trimesh.Trimesh, Material]], condition: Condition,
               light: np.ndarray, rng: np.random.Generator, *, supersample: int = 2,
               tray_albedo: float = TRAY_ALBEDO) -> np.ndarray:
    """The grey picture of meshes [m, world frame] lying on the station's tray under ``condition``.

    Parameters
    ----------
    meshes : list of (Trimesh, Material)
        Each mesh [m, world frame] with its material.
    light : (3,) float
        Unit direction toward the key light (world frame, :func:`key_light`).
    rng : numpy Generator
        Draws the light's jitter, the textures, the defocus and the noise.
    supersample : int
        Rays per pixel side.
    tray_albedo : float
        Diffuse reflectance of the surface the meshes lie on (0..1), its texture on top.

    Returns
    -------
    (h, w) uint8
        The grey picture.
    """
    cam = station.camera
    w, h = cam.image_size
    s = supersample
    t_wc = station.camera_pose
    eye = t_wc[:3, 3]
    d = (_camera_rays(cam, s).reshape(-1, 3) @ t_wc[:3, :3].T)
    n_rays = len(d)
    tray_t = (station.plane_z - eye[2]) / d[:, 2]
    point = eye + tray_t[:, None] * d
    normal = np.tile([0.0, 0.0, 1.0], (n_rays, 1))
    which = np.full(n_rays, -1)  # -1: tray, else the mesh index
    scene = trimesh.util.concatenate([m for m, _ in meshes])
    owner = np.concatenate([np.full(len(m.faces), i) for i, (m, _) in enumerate(meshes)])
    # Visibility: a z-buffer of the scene's triangles in the undistorted image plane (where their
    # edges are straight), 3 grid points per sample along each axis, says which triangle each
    # sample's ray meets; the point is the exact intersection of the ray with that triangle's plane.
    verts, faces = np.asarray(scene.vertices), np.asarray(scene.faces)
    vc = verts @ station.world_to_camera[:3, :3].T + station.world_to_camera[:3, 3]
    xn = vc[:, :2] / vc[:, 2:3]
    step = 1.0 / (3 * s * np.sqrt(cam.fx * cam.fy))
    x0 = xn.min(axis=0) - 4 * step
    size = np.ceil((xn.max(axis=0) + 4 * step - x0) / step).astype(int) + 1
    _, grid = _zbuffer((xn - x0) / step, -1.0 / vc[:, 2], faces, (size[1], size[0]))
    ray_cam = _camera_rays(cam, s).reshape(-1, 3)
    q = np.rint((ray_cam[:, :2] / ray_cam[:, 2:3] - x0) / step).astype(np.int64)
    inside = (q >= 0).all(axis=1) & (q[:, 0] < size[0]) & (q[:, 1] < size[1])
    tri_at = np.full(n_rays, -1)
    tri_at[inside] = grid[q[inside, 1], q[inside, 0]]
    hit = np.flatnonzero(tri_at >= 0)
    tri_i = tri_at[hit]
    fn = scene.face_normals[tri_i]
    p0 = scene.vertices[scene.faces[tri_i, 0]]
    t_hit = np.einsum("nj,nj->n", p0 - eye, fn) / np.einsum("nj,nj->n", d[hit], fn)
    loc = eye + t_hit[:, None] * d[hit]
    point[hit] = loc
    which[hit] = owner[tri_i]
    # Smooth normals on freeform faces, flat on flat ones: each corner's normal is the mean of the
    # faces at its vertex that meet the corner's own face under SMOOTH_BELOW_DEG, so a flat top
    # beside a rim stays flat (its corners see only the top's faces) and a freeform face is smooth.
    bary = trimesh.triangles.points_to_barycentric(scene.triangles[tri_i], loc)
    smooth = np.einsum("nk,nkj->nj", bary, corner_normals(scene)[tri_i])
    smooth /= np.linalg.norm(smooth, axis=1, keepdims=True)
    normal[hit] = smooth

    # Shadows: one shadow map per direction within the light's disc; a point's visibility is the
    # share of them that see it (soft penumbras from an extended light).
    n_dirs = 6 if condition.size_deg > 1 else 2
    lights = _jitter(light, np.radians(condition.size_deg), rng, n_dirs)
    # Only the parts and the tray around them can be in a shadow.
    reach = np.ptp(verts[:, 2]) / max(np.tan(np.radians(min(condition.elevation_deg) - condition.size_deg)), 0.05)
    near = ((point[:, :2] > verts[:, :2].min(axis=0) - reach - 0.01) &
            (point[:, :2] < verts[:, :2].max(axis=0) + reach + 0.01)).all(axis=1) | (which >= 0)
    if condition.glare:
        near[:] = True
    idx = np.flatnonzero(near)
    seen = np.ones(n_rays)
    seen[idx] = 0.0
    for ld in lights:
        seen[idx] += _lit_by(verts, faces, ld, point[idx], normal[idx])
    seen[idx] /= n_dirs
    n_dot_l = normal @ light
    vis = seen * np.maximum(n_dot_l, 0)
    lights = np.tile(light, (n_rays, 1))

    view = eye - point
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    half = lights + view
    half /= np.linalg.norm(half, axis=1, keepdims=True)
    n_dot_h = np.maximum(np.einsum("nj,nj->n", normal, half), 0)
    fill = condition.fill * (0.55 + 0.45 * normal[:, 2])  # a bright ceiling, a darker floor

    radiance = np.empty(n_rays)
    # The tray: satin grey with blotchy texture and fine grain.
    tray = which < 0
    extent = 0.5
    origin = station.camera_pose[:2, 3] - extent / 2
    tex = (0.06 * _smooth_noise(rng, (500, 500), 6.0) + 0.03 * _smooth_noise(rng, (500, 500), 1.0))
    albedo = tray_albedo * (1 + _sample(tex, origin, extent / 500, point[tray, :2]))
    radiance[tray] = albedo * (fill[tray] + vis[tray]) + 0.06 * seen[tray] * n_dot_h[tray] ** 8
    for i, (_, mat) in enumerate(meshes):
        on = which == i
        if not on.any():
            continue
        local = (point[on] - mat.frame[:3, 3]) @ mat.frame[:3, :3]  # part frame [m]
        # Brushing streaks run along the part's x axis: a texture of y (and a little of z) only.
        grain = _smooth_noise(rng, (1, 4000), 0.7)[0]
        streaks = np.interp(local[:, 1] + 0.1 * local[:, 2], np.linspace(-0.1, 0.1, 4000), grain)
        a = mat.albedo * (1 + mat.brushed * streaks)
        spec = mat.specular * seen[on] * (n_dot_l[on] > 0) * n_dot_h[on] ** mat.shininess * \
            (mat.shininess + 8) / 60
        radiance[on] = a * (fill[on] + vis[on]) + spec
    return _exposed(radiance.reshape(h, s, w, s).mean(axis=(1, 3)), cam, condition, rng)



def _exposed(img: np.ndarray, cam: CameraModel, condition: Condition, rng: np.random.Generator) -> np.ndarray:
    """The radiance ``img`` (h, w) through the lens (fall-off, defocus) onto the sensor (exposure to
    the condition's mean grey, shot and read noise, 8-bit clipping): the (h, w) uint8 picture."""
    ray_z = _camera_rays(cam, 1)[..., 2]
    # A lens whose cos^4 law is partly compensated: about 30 % darker in the corners.
    img = img * ray_z ** 2
    img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), rng.uniform(0.55, 0.9)).astype(np.float64)
    gain = condition.mean_grey / np.mean(np.minimum(img / np.median(img) * condition.mean_grey, 255))
    grey = img / np.median(img) * condition.mean_grey * gain
    grey = grey + rng.normal(size=grey.shape) * np.sqrt(0.25 * np.maximum(grey, 0) + 1.5 ** 2)
    return np.clip(np.rint(grey), 0, 255).astype(np.uint8)


def _zbuffer(xy: np.ndarray, depth: np.ndarray, faces: np.ndarray, shape: tuple[int, int]
             ) -> tuple[np.ndarray, np.ndarray]:
    """Nearest triangle at every grid point: depth map and triangle index (-1: none).

    ``xy`` (n, 2) vertex positions in grid units (grid point (i, j) at x = j, y = i), ``depth`` (n,)
    per vertex, interpolated linearly over the grid. Triangles are scanned row by row, so a long
    sliver costs its covered points, not its bounding box.
    """
    rows, cols = shape
    best = np.full(rows * cols, np.inf)
    index = np.full(rows * cols, -1)
    tri, tz = xy[faces], depth[faces]
    # depth = p x + q y + r over each triangle's plane
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    ok = np.abs(det) > 1e-12
    det = np.where(ok, det, 1.0)
    dz1, dz2 = tz[:, 1] - tz[:, 0], tz[:, 2] - tz[:, 0]
    gp = (dz1 * e2[:, 1] - dz2 * e1[:, 1]) / det
    gq = (dz2 * e1[:, 0] - dz1 * e2[:, 0]) / det
    y_lo = np.maximum(np.ceil(tri[:, :, 1].min(axis=1)), 0).astype(np.int64)
    y_hi = np.minimum(np.floor(tri[:, :, 1].max(axis=1)), rows - 1).astype(np.int64)
    nrow = np.where(ok, y_hi - y_lo + 1, 0).clip(0)
    k = np.repeat(np.arange(len(faces)), nrow)
    y = (y_lo[k] + np.arange(nrow.sum()) - np.repeat(np.cumsum(nrow) - nrow, nrow)).astype(np.float64)
    x_min = np.full(len(k), np.inf)
    x_max = np.full(len(k), -np.inf)
    for i in range(3):
        a, b = tri[k, i], tri[k, (i + 1) % 3]
        dy = b[:, 1] - a[:, 1]
        t = (y - a[:, 1]) / np.where(dy != 0, dy, 1.0)
        on = (dy != 0) & (t >= 0) & (t <= 1)
        x = a[:, 0] + t * (b[:, 0] - a[:, 0])
        x_min = np.where(on, np.minimum(x_min, x), x_min)
        x_max = np.where(on, np.maximum(x_max, x), x_max)
    x_lo = np.maximum(np.ceil(x_min), 0)
    x_hi = np.minimum(np.floor(x_max), cols - 1)
    n = np.where(np.isfinite(x_lo) & np.isfinite(x_hi), x_hi - x_lo + 1, 0).clip(0).astype(np.int64)
    keep = n > 0
    k, y, x_lo, n = k[keep], y[keep].astype(np.int64), x_lo[keep].astype(np.int64), n[keep]
    for part in np.array_split(np.arange(len(k)), max(1, int(n.sum() // 4_000_000) + 1)):
        m = n[part]
        kk = np.repeat(k[part], m)
        px = np.repeat(x_lo[part], m) + np.arange(m.sum()) - np.repeat(np.cumsum(m) - m, m)
        py = np.repeat(y[part], m)
        z = tz[kk, 0] + gp[kk] * (px - tri[kk, 0, 0]) + gq[kk] * (py - tri[kk, 0, 1])
        lin = py * cols + px
        order = np.lexsort((z, lin))
        first = order[np.r_[True, lin[order][1:] != lin[order][:-1]]]
        closer = z[first] < best[lin[first]]
        best[lin[first][closer]] = z[first][closer]
        index[lin[first][closer]] = kk[first][closer]
    return best.reshape(shape), index.reshape(shape)


#: Shadow map texel [m] and the depth margin that keeps a lit face from shadowing itself [m].
SHADOW_TEXEL_M = 2.5e-4
SHADOW_BIAS_M = 6e-4


#: Faces meeting under this angle [deg] are one smooth surface in :func:`corner_normals`; sharper is an edge.
SMOOTH_BELOW_DEG = 12.0


def corner_normals(mesh: trimesh.Trimesh) -> np.ndarray:
    """Each face corner's shading normal, (n_faces, 3, 3) unit vectors.

    The angle-weighted mean of the normals of the faces at the corner's vertex whose normal is
    within :data:`SMOOTH_BELOW_DEG` of the corner's own face's: an edge sharper than that is drawn
    as an edge, on both of its sides, and a face is never tilted by a neighbour across one.
    """
    faces = np.asarray(mesh.faces)
    fn = np.asarray(mesh.face_normals)
    weight = np.nan_to_num(np.asarray(mesh.face_angles)).ravel()  # degenerate faces weigh nothing
    corner_face = np.repeat(np.arange(len(faces)), 3)
    vertex = faces.ravel()
    # Every pair of corners at one vertex (the corner itself included): corners sorted by vertex,
    # each paired with every corner of its vertex's run.
    order = np.argsort(vertex, kind="stable")
    runs_start = np.flatnonzero(np.r_[True, np.diff(vertex[order]) != 0])
    runs_len = np.diff(np.r_[runs_start, len(order)])
    run_of = np.repeat(np.arange(len(runs_start)), runs_len)
    reps = runs_len[run_of]
    a = np.repeat(order, reps)
    offset = np.arange(len(a)) - np.repeat(np.cumsum(reps) - reps, reps)
    b = order[np.repeat(runs_start[run_of], reps) + offset]
    same = np.einsum("nj,nj->n", fn[corner_face[a]], fn[corner_face[b]]) > np.cos(np.radians(SMOOTH_BELOW_DEG))
    acc = np.zeros((len(vertex), 3))
    np.add.at(acc, a[same], fn[corner_face[b[same]]] * weight[b[same], None])
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    out = np.where(norm > 0, acc / np.where(norm > 0, norm, 1.0), fn[corner_face])
    return out.reshape(-1, 3, 3)


def _lit_by(verts: np.ndarray, faces: np.ndarray, light: np.ndarray, point: np.ndarray, normal: np.ndarray
            ) -> np.ndarray:
    """``(n,)`` 1 where a point sees the directional light ``light`` past the triangles, else 0."""
    a = np.cross(light, [1.0, 0.0, 0.0] if abs(light[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(light, a)
    basis = np.stack([a, b])
    vxy = verts @ basis.T
    origin = vxy.min(axis=0) - 2 * SHADOW_TEXEL_M
    size = np.ceil((vxy.max(axis=0) - origin) / SHADOW_TEXEL_M).astype(int) + 3
    depth_map, _ = _zbuffer((vxy - origin) / SHADOW_TEXEL_M, -(verts @ light), faces, (size[1], size[0]))
    q = np.rint((point @ basis.T - origin) / SHADOW_TEXEL_M).astype(np.int64)
    inside = (q[:, 0] >= 0) & (q[:, 1] >= 0) & (q[:, 0] < size[0]) & (q[:, 1] < size[1])
    blocker = np.full(len(point), np.inf)
    blocker[inside] = depth_map[q[inside, 1], q[inside, 0]]
    # Slope-scaled margin: faces at a grazing angle to the light need more.
    cos = np.clip(np.abs(normal @ light), 0.05, 1.0)
    margin = SHADOW_BIAS_M + SHADOW_TEXEL_M * np.sqrt(1 - cos ** 2) / cos
    return (-(point @ light) <= blocker + margin).astype(np.float64)
