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

from factory.errors import VisionError
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
