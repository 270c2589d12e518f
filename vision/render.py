"""Exact synthetic images of a planar picture seen by a distorting camera.

Each output pixel is the mean of ``s x s`` sub-pixel samples. A sample's viewing ray is
found by inverting the camera's projection (:meth:`CameraModel.rays`, converged
undistortion), intersected with the plane, and the plane's picture is sampled bilinearly
there. The image is therefore exact up to the sampling of the picture, with no
approximation of the lens, which is what calibration and pose tests need as ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from factory.core.errors import VisionError
from vision.board import PlanarTexture
from vision.camera import CameraModel


@dataclass(frozen=True)
class PixelRays:
    """Viewing rays of every sub-pixel sample of a camera, reusable across poses.

    Attributes
    ----------
    camera : CameraModel
    supersample : int
        Samples per pixel along each axis.
    rays : (h * s, w * s, 2) float32
        Ray directions ``(x, y, 1)`` in the camera frame, z = 1 left out (unitless).
    """

    camera: CameraModel
    supersample: int
    rays: np.ndarray


def pixel_rays(camera: CameraModel, supersample: int = 4) -> PixelRays:
    """The viewing rays of every sub-pixel sample (the costly part of rendering; reuse it).

    Parameters
    ----------
    camera : CameraModel
    supersample : int
        Samples per pixel along each axis, >= 1.
    """
    s = int(supersample)
    if s < 1:
        raise VisionError(f"supersample must be >= 1, got {supersample}")
    w, h = camera.image_size
    # Pixel i covers [i - 0.5, i + 0.5] (OpenCV: integer coordinates are pixel centres).
    offsets = (np.arange(s) + 0.5) / s - 0.5
    us = (np.arange(w)[:, None] + offsets[None, :]).reshape(-1)
    vs = (np.arange(h)[:, None] + offsets[None, :]).reshape(-1)
    uu, vv = np.meshgrid(us, vs)
    rays = camera.rays(np.stack([uu.ravel(), vv.ravel()], axis=1))
    return PixelRays(camera, s, rays[:, :2].reshape(h * s, w * s, 2).astype(np.float32))


def look_at_pose(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, -1.0, 0.0)) -> np.ndarray:
    """Plane-to-camera transform of a camera at ``eye`` looking at ``target``.

    Parameters
    ----------
    eye, target : (3,) float
        Camera position and aim point in the plane's frame [m].
    up : (3,) float
        Direction in the plane's frame that should appear up in the image.

    Returns
    -------
    (4, 4) float
        ``T`` with ``X_camera = T @ X_plane`` (translation [m]).
    """
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(-up, z)  # image y points down, so "up" is -y
    if np.linalg.norm(x) < 1e-9:
        raise VisionError("up is parallel to the viewing direction")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    r = np.stack([x, y, z])  # rows: camera axes in plane coordinates
    t = np.eye(4)
    t[:3, :3] = r
    t[:3, 3] = -r @ eye
    return t


def orbit_pose(target: np.ndarray, distance: float, tilt: float, azimuth: float, roll: float = 0.0) -> np.ndarray:
    """Plane-to-camera transform of a camera looking at ``target`` from a tilted direction.

    Parameters
    ----------
    target : (3,) float
        Aim point in the plane's frame [m].
    distance : float
        Camera to ``target`` [m].
    tilt : float
        Angle between the viewing direction and the plane normal [rad].
    azimuth : float
        Direction of the tilt around the plane normal [rad].
    roll : float
        Rotation of the image about the viewing direction [rad].

    Returns
    -------
    (4, 4) float
        ``X_camera = T @ X_plane`` (translation [m]); the camera is on the -z side of the
        plane (OpenCV board frames have z pointing away from the camera).
    """
    target = np.asarray(target, dtype=np.float64)
    direction = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), -np.cos(tilt)])
    eye = target + distance * direction
    up = np.array([-np.sin(roll), -np.cos(roll), 0.0])
    if abs(np.dot(up, direction)) > 0.999:
        up = np.array([1.0, 0.0, 0.0])
    return look_at_pose(eye, target, up)


def render(camera: CameraModel | PixelRays, pose: np.ndarray, texture: PlanarTexture, *,
           supersample: int = 4, noise_sigma: float = 0.0, background: float = 128.0,
           seed: int | None = None) -> np.ndarray:
    """The image a camera sees of a textured plane.

    Parameters
    ----------
    camera : CameraModel or PixelRays
        The camera; pass :func:`pixel_rays` to render many poses of one camera quickly.
    pose : (4, 4) float
        Plane-to-camera transform ``X_camera = pose @ X_plane`` (translation [m]); the
        plane is z = 0 of its frame.
    texture : PlanarTexture
        The plane's picture (grey or BGR) and its placement in the plane frame.
    supersample : int
        Samples per pixel along each axis (ignored when ``camera`` is a PixelRays).
    noise_sigma : float
        Standard deviation of additive Gaussian noise [grey levels of 255].
    background : float
        Grey level where the plane (or the picture) is not seen.
    seed : int, optional
        Seed of the noise.

    Returns
    -------
    (h, w) or (h, w, 3) uint8
    """
    pr = camera if isinstance(camera, PixelRays) else pixel_rays(camera, supersample)
    s = pr.supersample
    w, h = pr.camera.image_size
    t = np.asarray(pose, dtype=np.float64)
    if t.shape != (4, 4) or not np.isfinite(t).all():
        raise VisionError("pose must be a finite 4x4 matrix")
    r, trans = t[:3, :3], t[:3, 3]
    n = r[:, 2]  # plane normal in camera coordinates
    x, y = pr.rays[..., 0], pr.rays[..., 1]  # float32: ample for metres-sized scenes
    denom = x * np.float32(n[0]) + y * np.float32(n[1]) + np.float32(n[2])
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = np.float32(n @ trans) / denom
    seen = np.isfinite(lam) & (lam > 0)
    # Plane coordinates of the hit points, R^T (lam * ray - t), then picture coordinates.
    hx, hy, hz = lam * x - np.float32(trans[0]), lam * y - np.float32(trans[1]), lam - np.float32(trans[2])
    scale = 1.0 / texture.pixel_size
    maps = []
    for axis in (0, 1):
        plane = hx * np.float32(r[0, axis]) + hy * np.float32(r[1, axis]) + hz * np.float32(r[2, axis])
        m = plane * np.float32(scale) + np.float32(texture.origin[axis] - 0.5)
        maps.append(np.where(seen, m, np.float32(-10.0)).astype(np.float32))
    px, py = maps
    src = texture.image.astype(np.float32)
    channels = 1 if src.ndim == 2 else src.shape[2]
    # remap's bilinear weights are quantised to 1/32 px; the picture is sampled finely
    # enough (and averaged s x s) that this stays far below detection noise.
    big = cv2.remap(src, px, py, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                    borderValue=(background,) * 4)
    img = big.reshape(h, s, w, s, channels).mean(axis=(1, 3))
    if channels == 1:
        img = img[..., 0]
    if noise_sigma > 0:
        img = img + np.random.default_rng(seed).normal(0.0, noise_sigma, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class Box:
    """A box standing on the tray plane, for synthetic pictures of blanks on a tray.

    Attributes
    ----------
    x, y : float
        Centre of the box's footprint in the world frame [m].
    yaw : float
        Rotation of the box's x edge about the world z axis [rad].
    size : (float, float, float)
        Edges along its own x, y and its height above the tray [m].
    """

    x: float
    y: float
    yaw: float
    size: tuple[float, float, float]


#: Grey levels of a box's faces in :func:`render_boxes`: top, then the sides facing its +x, -x, +y, -y.
BOX_SHADES = (215.0, 170.0, 140.0, 155.0, 125.0)


def render_boxes(camera: CameraModel | PixelRays, world_to_camera: np.ndarray, boxes: list[Box], *,
                 plane_z: float = 0.0, tray: float = 40.0, shades: tuple[float, ...] = BOX_SHADES,
                 supersample: int = 3, noise_sigma: float = 0.0, background: float = 0.0,
                 seed: int | None = None) -> np.ndarray:
    """The image a camera sees of flat-shaded boxes on a uniform tray (the plane z = ``plane_z``).

    World frame: z up, the boxes stand on the tray and extend to ``plane_z + height``. Each
    sample ray is intersected with the tray and with every box (slab test); the nearest hit sets
    the sample's grey level. Pixels are the mean of their ``s x s`` samples (antialiased edges).

    Parameters
    ----------
    camera : CameraModel or PixelRays
    world_to_camera : (4, 4) float
        ``T_cam_world`` (``X_camera = T @ X_world``, translation [m]).
    boxes : list of Box
    plane_z : float
        Height of the tray in the world frame [m].
    tray, shades, background : float
        Grey levels of the tray, of the box faces (:data:`BOX_SHADES` order) and where no tray is seen.
    supersample : int
        Samples per pixel along each axis (ignored when ``camera`` is a PixelRays).
    noise_sigma : float
        Standard deviation of additive Gaussian noise [grey levels of 255].
    seed : int, optional

    Returns
    -------
    (h, w) uint8
    """
    pr = camera if isinstance(camera, PixelRays) else pixel_rays(camera, supersample)
    s = pr.supersample
    w, h = pr.camera.image_size
    t = np.asarray(world_to_camera, dtype=np.float64)
    if t.shape != (4, 4) or not np.isfinite(t).all():
        raise VisionError("pose must be a finite 4x4 matrix")
    r, trans = t[:3, :3], t[:3, 3]
    origin = -r.T @ trans
    x, y = pr.rays[..., 0], pr.rays[..., 1]
    # World direction of each ray, R^T (x, y, 1); the ray parameter is the camera depth.
    d = [x * np.float32(r[0, k]) + y * np.float32(r[1, k]) + np.float32(r[2, k]) for k in range(3)]
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.float32(plane_z - origin[2]) / d[2]
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.float32(np.inf)).astype(np.float32)
    value = np.where(np.isfinite(depth), np.float32(tray), np.float32(background)).astype(np.float32)
    for box in boxes:
        c, sn = np.cos(box.yaw), np.sin(box.yaw)
        lx, ly, hz = (float(v) for v in box.size)
        p = origin - np.array([box.x, box.y, plane_z])
        # Ray origin and direction in the box's own frame (rotate by -yaw about z).
        po = (c * p[0] + sn * p[1], -sn * p[0] + c * p[1], p[2])
        dd = (np.float32(c) * d[0] + np.float32(sn) * d[1], np.float32(-sn) * d[0] + np.float32(c) * d[1], d[2])
        lo, hi = (-lx / 2, -ly / 2, 0.0), (lx / 2, ly / 2, hz)
        near = np.full(x.shape, -np.inf, np.float32)
        far = np.full(x.shape, np.inf, np.float32)
        face = np.zeros(x.shape, np.int8)
        for k, (neg, pos) in enumerate(((2, 1), (4, 3), (-1, 0))):
            with np.errstate(divide="ignore", invalid="ignore"):
                t1 = (np.float32(lo[k] - po[k])) / dd[k]
                t2 = (np.float32(hi[k] - po[k])) / dd[k]
            entry = np.fmin(t1, t2)
            exit_ = np.fmax(t1, t2)
            # Entering through the low face means the face looks toward -axis.
            kind = np.where(t1 < t2, neg, pos).astype(np.int8)
            later = entry > near
            face = np.where(later, kind, face)
            near = np.where(later, entry, near)
            far = np.fmin(far, exit_)
        hit = (near <= far) & (near > 0) & (near < depth)
        shade = np.asarray(shades, np.float32)[np.clip(face, 0, 4)]
        value = np.where(hit, shade, value)
        depth = np.where(hit, near, depth)
    img = value.reshape(h, s, w, s).mean(axis=(1, 3))
    if noise_sigma > 0:
        img = img + np.random.default_rng(seed).normal(0.0, noise_sigma, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


#: Sub-pixel samples per side of the fine tiles, and fine tiles per side of the coarse tiles, that
#: :func:`render_mesh` bins triangles into before its exact test of each sample.
_TILE = 8
_GROUP = 8


def _tiles(a: np.ndarray, n: int) -> np.ndarray:
    """``(h / n * w / n, n * n)`` the ``n x n`` blocks of an ``(h, w)`` array, row by row of blocks."""
    h, w = a.shape
    return a.reshape(h // n, n, w // n, n).swapaxes(1, 2).reshape(-1, n * n)


def _may_cover(edges: np.ndarray, box: np.ndarray) -> np.ndarray:
    """``(p,)`` whether triangles may cover any point of boxes: each edge function's maximum over its box >= 0.

    ``edges`` (p, 3, 3) holds ``a, b, c`` of the three inward edge functions ``a x + b y + c``,
    ``box`` (p, 4) the boxes ``xmin, ymin, xmax, ymax`` (normalised image coordinates).
    """
    a, b, c = edges[..., 0], edges[..., 1], edges[..., 2]
    x = np.where(a > 0, box[:, None, 2], box[:, None, 0])
    y = np.where(b > 0, box[:, None, 3], box[:, None, 1])
    # Slack far below a sample spacing (~3e-4) but far above the float32 rounding of the exact
    # test, so a sample that test puts inside is never in a tile culled here.
    return (a * x + b * y + c >= -1e-6).all(axis=1)


def _nearest_triangles(x: np.ndarray, y: np.ndarray, tri: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """For every sample, the nearest triangle its ray hits in front of ``depth``, or -1.

    Exact: a sample is inside a triangle when its ray ``(x, y, 1)`` passes inside the triangle's
    projection, which is a straight-edged triangle in the normalised image plane whatever the lens
    distortion (the distortion is already in the rays). Triangles are binned into coarse, then fine
    tiles of samples by the tiles' exact bounds in that plane, so each triangle is only tested
    against the samples of the fine tiles it may cover.

    Parameters
    ----------
    x, y : (H, W) float32
        Normalised ray coordinates of the samples; H, W multiples of ``_TILE * _GROUP``.
    tri : (k, 3, 3) float
        Triangles in the camera frame, all in front of it [m].
    depth : (H, W) float
        Camera depth of what is seen so far (the tray; inf for nothing) [m].

    Returns
    -------
    (H, W) int
        Index into ``tri`` of the triangle seen by each sample, -1 where none is nearer than ``depth``.
    """
    big_h, big_w = x.shape
    hit = np.full(x.size, -1, np.int64)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    offset = np.einsum("kj,kj->k", normal, tri[:, 0])  # the plane: normal . X = offset
    uv = tri[..., :2] / tri[..., 2:3]
    nxt = np.roll(uv, -1, axis=1)
    # Edge i from vertex i to i+1: a x + b y + c >= 0 inside a counter-clockwise triangle. A shared edge
    # gets exactly negated coefficients in its two triangles, so no sample on it falls through a crack.
    edges = np.stack([uv[..., 1] - nxt[..., 1], nxt[..., 0] - uv[..., 0],
                      nxt[..., 1] * uv[..., 0] - nxt[..., 0] * uv[..., 1]], axis=-1)
    area2 = edges[..., 2].sum(axis=1)
    # Front faces only (their normal points at the camera): a closed mesh's back faces are never seen.
    keep = np.flatnonzero((offset < 0) & (area2 != 0))
    if len(keep) == 0:
        return hit.reshape(big_h, big_w)
    edges = edges[keep] * np.sign(area2[keep])[:, None, None]
    lo, hi = uv[keep].min(axis=1), uv[keep].max(axis=1)
    normal, offset = normal[keep], offset[keep]

    # Samples in tile order (each fine tile's TILE x TILE samples contiguous), and the tiles' bounds.
    xt, yt, zt = _tiles(x, _TILE), _tiles(y, _TILE), _tiles(depth, _TILE).copy()
    hf, wf = big_h // _TILE, big_w // _TILE
    fine = np.stack([xt.min(axis=1), yt.min(axis=1), xt.max(axis=1), yt.max(axis=1)], axis=1)
    grid = fine.reshape(hf, wf, 4)
    coarse = np.stack([_tiles(grid[..., 0], _GROUP).min(axis=1), _tiles(grid[..., 1], _GROUP).min(axis=1),
                       _tiles(grid[..., 2], _GROUP).max(axis=1), _tiles(grid[..., 3], _GROUP).max(axis=1)], axis=1)
    wc = wf // _GROUP
    pairs_t, pairs_c = [], []
    for start in range(0, len(keep), 4096):  # bounded memory: chunk x coarse tiles booleans
        sl = slice(start, start + 4096)
        overlap = ((lo[sl, None, 0] <= coarse[None, :, 2]) & (hi[sl, None, 0] >= coarse[None, :, 0])
                   & (lo[sl, None, 1] <= coarse[None, :, 3]) & (hi[sl, None, 1] >= coarse[None, :, 1]))
        t, c = np.nonzero(overlap)
        pairs_t.append(t + start)
        pairs_c.append(c)
    t, c = np.concatenate(pairs_t), np.concatenate(pairs_c)
    ok = _may_cover(edges[t], coarse[c])
    t, c = t[ok], c[ok]
    # Each coarse pair -> its GROUP x GROUP fine tiles.
    dy, dx = np.divmod(np.arange(_GROUP * _GROUP), _GROUP)
    f = (((c // wc) * _GROUP)[:, None] + dy) * wf + ((c % wc) * _GROUP)[:, None] + dx
    f, t = f.ravel(), np.repeat(t, _GROUP * _GROUP)
    ok = _may_cover(edges[t], fine[f])
    t, f = t[ok], f[ok]
    # Each fine pair: its TILE x TILE samples tested exactly, one row per pair (coefficients broadcast).
    px, py = xt[f], yt[f]
    e = edges[t].astype(np.float32)  # float32 keeps negated shared edges exact; 1e-8 << sample spacing
    inside = np.ones(px.shape, bool)
    for i in range(3):
        inside &= e[:, i, 0:1] * px + e[:, i, 1:2] * py + e[:, i, 2:3] >= 0
    row, col = np.nonzero(inside)
    tri_of = t[row]
    n = normal[tri_of]
    px, py = px[row, col], py[row, col]
    z = offset[tri_of] / (n[:, 0] * px + n[:, 1] * py + n[:, 2])  # camera depth of the hit on the plane
    sample = f[row] * (_TILE * _TILE) + col
    zt = zt.ravel()
    np.minimum.at(zt, sample, z)
    won = z <= zt[sample]  # ties (a shared edge) go to either triangle
    hit[sample[won]] = keep[tri_of[won]]
    return hit.reshape(hf, wf, _TILE, _TILE).swapaxes(1, 2).reshape(big_h, big_w)


def _face_shades(normals: np.ndarray, shades: tuple[float, ...]) -> np.ndarray:
    """``(k,)`` grey level of faces with unit world normals ``(k, 3)``: the :data:`BOX_SHADES` of the
    axis directions blended by the squared normal components (so a box's faces get exactly those)."""
    top, px, mx, py, my = (float(v) for v in shades[:5])
    nx, ny, nz = normals[:, 0], normals[:, 1], normals[:, 2]
    return (nx ** 2 * np.where(nx > 0, px, mx) + ny ** 2 * np.where(ny > 0, py, my)
            + nz ** 2 * np.where(nz > 0, top, min(px, mx, py, my)))


def render_mesh(camera: CameraModel | PixelRays, world_to_camera: np.ndarray, vertices: np.ndarray,
                faces: np.ndarray, *, plane_z: float = 0.0, tray: float = 40.0,
                shades: tuple[float, ...] = BOX_SHADES, supersample: int = 3, noise_sigma: float = 0.0,
                background: float = 0.0, seed: int | None = None) -> np.ndarray:
    """The image a camera sees of a flat-shaded triangle mesh on a uniform tray (the plane z = ``plane_z``).

    The conventions of :func:`render_boxes` (a box mesh renders the same picture), for any closed
    mesh: a machined part with pockets, thousands of triangles. Each sub-pixel sample's ray is
    tested exactly against the mesh's front faces (binned by tiles, see :func:`_nearest_triangles`)
    and the tray; the nearest hit sets its grey level. Faces are shaded by their world normal:
    up-facing faces get the top shade, side faces the shades of the axis directions they face,
    in between a blend. Pixels are the mean of their ``s x s`` samples (antialiased edges).

    Parameters
    ----------
    camera : CameraModel or PixelRays
    world_to_camera : (4, 4) float
        ``T_cam_world`` (``X_camera = T @ X_world``, translation [m]).
    vertices : (n, 3) float
        Mesh vertices in the world frame [m].
    faces : (m, 3) int
        Triangles, counter-clockwise seen from outside (outward normals); back faces are not drawn.
    plane_z : float
        Height of the tray in the world frame [m].
    tray, shades, background : float
        Grey levels of the tray, of faces facing up, +x, -x, +y, -y (:data:`BOX_SHADES` order), and
        where no tray is seen.
    supersample : int
        Samples per pixel along each axis (ignored when ``camera`` is a PixelRays).
    noise_sigma : float
        Standard deviation of additive Gaussian noise [grey levels of 255].
    seed : int, optional

    Returns
    -------
    (h, w) uint8

    Raises
    ------
    VisionError
        A pose that is not a finite 4x4 matrix, vertices or faces of the wrong shape, face indices out
        of range, or a vertex behind the camera.
    """
    pr = camera if isinstance(camera, PixelRays) else pixel_rays(camera, supersample)
    s = pr.supersample
    w, h = pr.camera.image_size
    t = np.asarray(world_to_camera, dtype=np.float64)
    if t.shape != (4, 4) or not np.isfinite(t).all():
        raise VisionError("pose must be a finite 4x4 matrix")
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
        raise VisionError(f"vertices must be finite (n, 3) coordinates, got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or (f.size and (not np.issubdtype(f.dtype, np.integer)
                                                      or f.min() < 0 or f.max() >= len(v))):
        raise VisionError(f"faces must be (m, 3) indices of the {len(v)} vertices")
    r, trans = t[:3, :3], t[:3, 3]
    origin = -r.T @ trans
    # Pad the sample grid to whole coarse tiles (edge copies, cropped again below).
    block = _TILE * _GROUP
    pad = ((0, -pr.rays.shape[0] % block), (0, -pr.rays.shape[1] % block))
    x, y = (np.pad(pr.rays[..., k], pad, mode="edge") for k in (0, 1))
    # The tray, as render_boxes: the ray parameter along (x, y, 1) is the camera depth.
    dz = x * np.float32(r[0, 2]) + y * np.float32(r[1, 2]) + np.float32(r[2, 2])
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.float32(plane_z - origin[2]) / dz
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.inf).astype(np.float64)
    value = np.where(np.isfinite(depth), np.float32(tray), np.float32(background)).astype(np.float32)
    if len(f):
        cam = v @ r.T + trans
        if (cam[:, 2] <= 1e-6).any():
            raise VisionError("mesh is (partly) behind the camera")
        tri = cam[f]
        hit = _nearest_triangles(x, y, tri, depth)
        world = v[f]
        normal = np.cross(world[:, 1] - world[:, 0], world[:, 2] - world[:, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        face_value = _face_shades(normal, shades).astype(np.float32)
        seen = hit >= 0
        value[seen] = face_value[hit[seen]]
    value = value.reshape(x.shape)[:h * s, :w * s]
    img = value.reshape(h, s, w, s).mean(axis=(1, 3))
    if noise_sigma > 0:
        img = img + np.random.default_rng(seed).normal(0.0, noise_sigma, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)
