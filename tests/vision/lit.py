"""Pictures of parts on a tray in real light, rendered independently of :mod:`vision.render`.

A small ray caster over trimesh meshes (metres, world frame, z up): every sub-pixel sample's ray
is undistorted with OpenCV (``cv2.undistortPoints``, iterated to convergence), hits the scene meshes (trimesh's ray
intersector) or the tray plane, and is shaded with a Blinn-Phong model:

- brushed aluminium: Lambert with streaks along the part's x axis, a specular lobe (broad for
  brushed, tight and strong for polished), smooth normals on freeform faces;
- a satin grey tray with a random texture and a faint specular lobe;
- one directional light of finite angular size (every sample jitters it, so shadows have
  penumbras), shadow rays for self-shadows and the cast shadow, and a fill light from above;
- vignetting (cos^2: about 30 % in the corners), auto-exposure to a mean grey, defocus (Gaussian),
  shot and read noise, 8-bit clipping.

It shares nothing with the project's renderer but the camera file: lens distortion, shading,
visibility and shadows are its own, so a flaw of one is not repeated by the other.
The five conditions of issue 33 are :data:`CONDITIONS`; :func:`gallery_scene` draws one seeded
picture of one sample part in one of them, with the truth.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
import trimesh
from scipy.ndimage import map_coordinates

from vision.camera import CameraModel
from vision.locate import Footprint, footprint_from_mesh, mm_to_m
from vision.station import CameraStation, station_above

ROOT = Path(__file__).resolve().parents[2]
SAMPLE_PARTS = ("bracket", "stepped_wall", "plate_bosses", "dome_mould")
#: Shapes beyond the samples, from the parts gallery (tests/gallery/parts.py): an L standing on its
#: long leg (a 48 mm upright far above the tray, a long shadow, an outline whose turn its upright tells)
#: and a hexagonal boss with a bore on a round-cornered base (a freeform-cornered outline).
OWN_PARTS = ("l_bracket", "hex_boss")
#: Height of the cell's camera over the out-tray [m] (factory.cellcameras.CAMERA_HEIGHT_M).
CAMERA_HEIGHT_M = 0.5
TRAY_Z = 0.78


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


CONDITIONS: dict[str, Condition] = {
    "diffuse": Condition((60.0, 80.0), 12.0, 0.6, 120.0),
    "low_angle": Condition((14.0, 22.0), 0.5, 0.12, 115.0),
    "dim": Condition((50.0, 75.0), 8.0, 0.4, 60.0),
    "glare": Condition((72.0, 82.0), 3.0, 0.3, 115.0, specular=2.5, shininess=400.0, glare=True),
    "distractor": Condition((55.0, 75.0), 10.0, 0.5, 120.0, distractor=True),
}


@dataclass(frozen=True)
class LitScene:
    """One rendered picture and where the part really is.

    Attributes
    ----------
    image : (h, w) uint8
    x, y : float
        The part's footprint centroid on the tray [m].
    yaw : float
        The part's turn about z [rad].
    symmetry : int
        Turns of the whole mesh (not only its footprint) that map it onto itself (1, 2 or 4).
    """

    image: np.ndarray
    x: float
    y: float
    yaw: float
    symmetry: int


@lru_cache(maxsize=None)
def sample_mesh(name: str) -> tuple[trimesh.Trimesh, Footprint, int]:
    """A sample part's (or one of :data:`OWN_PARTS`') mesh [mm], its footprint and its mesh symmetry order."""
    if name in OWN_PARTS:
        from tests.gallery import parts as gallery  # manifold3d builds them; only the own shapes need it

        mesh = next(p for p in gallery.PARTS if p.name == name).make()
    else:
        mesh = trimesh.load(ROOT / "samples" / f"{name}.stl")
    return mesh, footprint_from_mesh(mesh.vertices, mesh.faces, source=name), mesh_symmetry(mesh)


def mesh_symmetry(mesh: trimesh.Trimesh) -> int:
    """Largest of 4, 2, 1 whose turn about the footprint's vertical centre axis maps the mesh onto itself."""
    fp = footprint_from_mesh(mesh.vertices, mesh.faces)
    pts = mesh.sample(3000, seed=0) if "seed" in mesh.sample.__code__.co_varnames else mesh.sample(3000)
    centre = np.r_[fp.centroid * 1e3, 0.0]
    for n in (4, 2):
        a = 2 * np.pi / n
        r = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        turned = (pts - centre) @ r.T + centre
        _, dist, _ = trimesh.proximity.closest_point(mesh, turned)
        if np.percentile(dist, 99) < 0.05:
            return n
    return 1


def cell_station(camera: CameraModel | None = None) -> CameraStation:
    """The sample cell's out-tray camera: ``fixtures/camera.yaml`` 0.5 m straight above the tray."""
    camera = camera or CameraModel.read(ROOT / "fixtures" / "camera.yaml")
    return station_above(camera, np.array([0.05, 0.40, TRAY_Z]), CAMERA_HEIGHT_M)


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


def render_lit(station: CameraStation, meshes: list[tuple[trimesh.Trimesh, dict]], condition: Condition,
               light: np.ndarray, rng: np.random.Generator, *, supersample: int = 2) -> np.ndarray:
    """The grey picture of meshes [m, world frame] lying on the station's tray under ``condition``.

    Parameters
    ----------
    meshes : list of (Trimesh, dict)
        Each mesh with its material: ``albedo``, ``specular``, ``shininess``, ``brushed`` (streak
        strength) and ``frame`` (4x4 part-to-world, for the streak direction).
    light : (3,) float
        Unit direction toward the key light (world frame).
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
    # Smooth normals on freeform faces (vertex normals of faces that meet at small angles), flat elsewhere.
    bary = trimesh.triangles.points_to_barycentric(scene.triangles[tri_i], loc)
    vn = scene.vertex_normals[scene.faces[tri_i]]
    smooth = np.einsum("nk,nkj->nj", bary, vn)
    smooth /= np.linalg.norm(smooth, axis=1, keepdims=True)
    normal[hit] = np.where((np.einsum("nj,nj->n", smooth, fn) > np.cos(np.radians(12)))[:, None], smooth, fn)

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
    albedo = 0.45 * (1 + _sample(tex, origin, extent / 500, point[tray, :2]))
    radiance[tray] = albedo * (fill[tray] + vis[tray]) + 0.06 * seen[tray] * n_dot_h[tray] ** 8
    for i, (_, mat) in enumerate(meshes):
        on = which == i
        if not on.any():
            continue
        local = (point[on] - mat["frame"][:3, 3]) @ mat["frame"][:3, :3]  # part frame [m]
        # Brushing streaks run along the part's x axis: a texture of y (and a little of z) only.
        grain = _smooth_noise(rng, (1, 4000), 0.7)[0]
        streaks = np.interp(local[:, 1] + 0.1 * local[:, 2], np.linspace(-0.1, 0.1, 4000), grain)
        a = mat["albedo"] * (1 + mat["brushed"] * streaks)
        spec = mat["specular"] * seen[on] * (n_dot_l[on] > 0) * n_dot_h[on] ** mat["shininess"] * \
            (mat["shininess"] + 8) / 60
        radiance[on] = a * (fill[on] + vis[on]) + spec
    img = radiance.reshape(h, s, w, s).mean(axis=(1, 3))

    # Lens: fall-off, defocus; sensor: exposure to the target mean, shot and read noise.
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


def _placed(mesh_mm: trimesh.Trimesh, fp: Footprint, x: float, y: float, yaw: float, z: float
            ) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The mesh in metres with its footprint centroid at (x, y) on the tray, turned by yaw; and its frame."""
    c, s = np.cos(yaw), np.sin(yaw)
    t = np.eye(4)
    t[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    t[:3, 3] = np.array([x, y, z]) - t[:3, :3] @ np.r_[fp.centroid, fp.zmin]
    m = trimesh.Trimesh(mm_to_m(mesh_mm.vertices), mesh_mm.faces, process=False)
    m.apply_transform(t)
    return m, t


#: Where parts are put: within this of the point under the camera, in x and y [m].
SPREAD_M = (0.13, 0.09)


def gallery_scene(station: CameraStation, part: str, condition: str, seed: int, *,
                  supersample: int = 2, shown: trimesh.Trimesh | None = None) -> LitScene:
    """One seeded picture of a sample part at a random pose under one of :data:`CONDITIONS`.

    ``shown`` (a mesh [mm] in the sample's own frame, e.g. a defective copy of it) is drawn in the
    sample's place: same pose, light and noise as the sample's picture of that seed.
    """
    cond = CONDITIONS[condition]
    parts = SAMPLE_PARTS + OWN_PARTS
    rng = np.random.default_rng([seed, parts.index(part) if part in parts else 9,
                                 list(CONDITIONS).index(condition)])
    mesh, fp, symmetry = sample_mesh(part)
    mesh = mesh if shown is None else shown
    centre = station.camera_pose[:2, 3]
    x, y = centre + rng.uniform(-1, 1, 2) * SPREAD_M
    yaw = rng.uniform(-np.pi, np.pi)
    placed, frame = _placed(mesh, fp, x, y, yaw, station.plane_z)
    polished = cond.glare
    meshes = [(placed, {"albedo": 0.55 if not polished else 0.35, "brushed": 0.0 if polished else 0.12,
                        "specular": cond.specular, "shininess": cond.shininess, "frame": frame})]
    if cond.distractor:
        size = rng.uniform([0.05, 0.035, 0.02], [0.08, 0.06, 0.045])
        for _ in range(200):
            a = rng.uniform(0, 2 * np.pi)
            bx, by = np.array([x, y]) + 0.115 * np.array([np.cos(a), np.sin(a)])
            if abs(bx - centre[0]) < SPREAD_M[0] + 0.04 and abs(by - centre[1]) < SPREAD_M[1] + 0.04:
                break
        box = trimesh.creation.box(size)
        bt = np.eye(4)
        byaw = rng.uniform(-np.pi, np.pi)
        bt[:3, :3] = [[np.cos(byaw), -np.sin(byaw), 0], [np.sin(byaw), np.cos(byaw), 0], [0, 0, 1]]
        bt[:3, 3] = [bx, by, station.plane_z + size[2] / 2]
        box.apply_transform(bt)
        meshes.append((box, {"albedo": 0.7, "brushed": 0.0, "specular": 0.05, "shininess": 5.0, "frame": bt}))
    if cond.glare:
        # The key light where the top face mirrors it into the camera, a few degrees off.
        to_cam = station.camera_pose[:3, 3] - np.array([x, y, station.plane_z])
        to_cam /= np.linalg.norm(to_cam)
        mirror = np.array([-to_cam[0], -to_cam[1], to_cam[2]])
        light = _jitter(mirror, np.radians(4.0), rng, 1)[0]
    else:
        el = np.radians(rng.uniform(*cond.elevation_deg))
        az = rng.uniform(0, 2 * np.pi)
        light = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    image = render_lit(station, meshes, cond, light, rng, supersample=supersample)
    return LitScene(image=image, x=float(x), y=float(y), yaw=float(yaw), symmetry=symmetry)
